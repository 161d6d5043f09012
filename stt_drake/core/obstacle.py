"""One uncertain obstacle (:class:`Obstacle`, Definition 2.1) and the rules of its
uncertainty: a standard deviation σ of at least :data:`SIGMA_MIN`, and a full covariance Σ
that is n×n, finite, symmetric, positive definite, conditioned to at most
:data:`MAX_CONDITION` and with every standard deviation √λ ≥ :data:`SIGMA_MIN`.

:func:`check_obstacle` holds every rule of one obstacle; its constructor checks them, and
so does the scenario loader (:mod:`stt_drake.config.validate`, through
:func:`stt_drake.config.limits.rule_path`), so both refuse the same values with the same
rule text. Pure numpy, no Drake.
"""

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from stt_drake.core import anisotropic
from stt_drake.core.belief import axes_covariance
from stt_drake.core.motion import (
    ConstantVelocity,
    CovarianceSchedule,
    Motion,
    SigmaSchedule,
    check_motion,
)
from stt_drake.core.rules import (
    check_obstacle_task,
    check_step_times,
    check_vector,
    checked_by,
    require,
)

#: Smallest standard deviation σ of an obstacle centre (m). Below it the obstacle is, for
#: the numerics, a knife edge: the tube law's switching band around the ε level set is
#: about 5σ wide, so the error-controlled integrator needs steps of ~σ/|ċ| s (omni case 1
#: with one obstacle's σ changed runs in 4 845 steps at σ = 1 mm and is stopped by the
#: step-rate watchdog at 0.1 mm, 6.6e4 steps/s; at 1e-6 the UAV paper scenario even
#: breaks center_avoid_probability between steps); the 2D avoidance probability (Marcum Q
#: series) costs O(distance/σ) per evaluation (1 000× its normal cost at σ = 0.01 mm);
#: and the numpy reference's noncentral-χ² series returned NaN from distance/σ ≈ 2e5 on
#: ("the tube law produced a non-finite value"; it now switches to large-offset forms,
#: :data:`stt_drake.core.probability.LARGE_OFFSET`). An obstacle known to better than
#: 1 mm is a deterministic obstacle for this tool: give σ = 0.001.
SIGMA_MIN = 1e-3

#: Largest eigenvalue ratio λ_max/λ_min of a covariance. A larger one is numerically
#: singular for this tool: eigh determines λ_min only to ~1e-16·λ_max (at 1e8, to 1e-8 of
#: itself), the exact probabilities are tested up to ratios of 1e4
#: (``tests/core/test_anisotropic.py``), and σ ≥ 1 mm with |x| ≤ 1e6 m needs no more.
MAX_CONDITION = 1e8

#: The forms of an obstacle centre's uncertainty (:class:`Obstacle`): an obstacle gives one
#: of them; sigma may come with sigma_schedule, which replaces it.
UNCERTAINTY_FIELDS = ("sigma", "sigma_schedule", "covariance", "axes_sigma", "covariance_schedule")


@dataclass
class Obstacle:
    """One uncertain obstacle (Definition 2.1): a ball of `radius` (r_o, m) around a
    Gaussian centre whose mean moves by `motion` (:class:`~stt_drake.core.motion.ConstantVelocity`,
    :class:`~stt_drake.core.motion.Oscillation`, ...), with the risk level `epsilon` (ε: the
    tube keeps P(avoid) ≥ ε) and `p_d` (Assumption 3: the target set stays clear with
    probability ≥ p_d).

    The centre's uncertainty is given in one of these forms:

    * `sigma`: the standard deviation of the centre per axis in metres (σ, not σ²),
      Σ = σ²I; `sigma_schedule`, when given, replaces it with a piecewise-linear σ(t);
    * `covariance`: a full covariance Σ (n×n, m², symmetric positive definite), a list of
      n rows;
    * `axes_sigma`: n standard deviations (m) along the principal axes, turned by
      `rotation` (rad; 2D: ``[angle]``, 3D: ``[roll, pitch, yaw]`` with Drake's RollPitchYaw
      R = Rz(yaw)·Ry(pitch)·Rx(roll); none: no rotation): Σ = R diag(axes_sigma²) Rᵀ;
    * `covariance_schedule`: a piecewise-linear Σ(t)
      (:class:`~stt_drake.core.motion.CovarianceSchedule`).

    With a full covariance the tube law uses Σ exactly and the belief's sigma is
    √λ_max(Σ) (:func:`stt_drake.core.belief.obstacle_belief`).

    Checked when made (:func:`check_obstacle`, the rules of a scenario file), e.g.
    ``Obstacle: epsilon must lie in (0, 1] (got 1.5)``; the dimension n is checked where it
    is known (:func:`stt_drake.assembly.AddStt`). A scenario file must give one of the
    uncertainty forms, `epsilon` and `p_d`: a safety tool does not invent an uncertainty
    or a risk level (the loader refuses a file without them,
    :mod:`stt_drake.config.load`). The defaults here only serve Drake's loader.
    """

    motion: Motion = field(default_factory=ConstantVelocity)
    radius: float = 0.15
    sigma: float = 0.1
    sigma_schedule: SigmaSchedule | None = None
    covariance: list[list[float]] | None = None
    axes_sigma: list[float] | None = None
    rotation: list[float] | None = None
    covariance_schedule: CovarianceSchedule | None = None
    epsilon: float = 0.9
    p_d: float = 0.9999

    def __post_init__(self) -> None:
        with checked_by("Obstacle"):
            check_obstacle(self)


def check_obstacle(obstacle: Any, dimension: int | None = None) -> None:
    """Every rule of one obstacle (an :class:`Obstacle` or anything with its fields) in
    R^n, `dimension` = n (None: n from the obstacle's own vectors): its motion
    (:func:`stt_drake.core.motion.check_motion`), σ > 0 and ≥ :data:`SIGMA_MIN`, a σ
    schedule, the full-covariance forms (:func:`check_full_covariance`), and the task
    numbers r_o, ε, p_d (:func:`stt_drake.core.rules.check_obstacle_task`). A broken rule
    raises :class:`~stt_drake.core.rules.RuleError` naming the field (``motion.start``,
    ``sigma_schedule.values[2]``)."""
    with checked_by("", "motion"):
        check_motion(obstacle.motion, dimension)
    require(
        obstacle.sigma > 0.0,
        "sigma",
        "must be > 0 (a standard deviation in metres)",
        obstacle.sigma,
    )
    check_sigma(obstacle.sigma, "sigma")
    schedule = getattr(obstacle, "sigma_schedule", None)
    if schedule is not None:
        _check_schedule(schedule, schedule.values, "sigma_schedule", "values")
        require(
            all(v > 0.0 for v in schedule.values),
            "sigma_schedule.values",
            "must all be > 0 (standard deviations in metres)",
            schedule.values,
        )
        for k, value in enumerate(schedule.values):
            check_sigma(value, f"sigma_schedule.values[{k}]")
    check_full_covariance(obstacle, dimension)
    check_obstacle_task(obstacle.radius, obstacle.epsilon, obstacle.p_d)


def check_one_uncertainty(given: Sequence[str]) -> None:
    """Of the uncertainty forms `given` (names of :data:`UNCERTAINTY_FIELDS`, in that order)
    at most one, sigma with sigma_schedule counting as one: RuleError naming the second
    field of the first pair that breaks it, and the first."""
    for k, second in enumerate(given):
        for first in given[:k]:
            require(
                {first, second} == {"sigma", "sigma_schedule"},
                second,
                f"must not be given too: {first} and {second} are both given; give only one of "
                f"{', '.join(UNCERTAINTY_FIELDS)} (one description of the centre's "
                "uncertainty; sigma may come with sigma_schedule, which replaces it)",
                list(given),
            )


def check_full_covariance(obstacle: Any, dimension: int | None = None) -> None:
    """The full-covariance forms of an obstacle: one at most (with no σ schedule), each a
    valid covariance (:func:`check_covariance`); `rotation` only with `axes_sigma`. A
    model without these attributes is isotropic
    (:func:`stt_drake.core.belief.has_full_covariance`)."""
    forms = {name: getattr(obstacle, name, None) for name in UNCERTAINTY_FIELDS[1:]}
    check_one_uncertainty([name for name, value in forms.items() if value is not None])
    covariance, axes = forms["covariance"], forms["axes_sigma"]
    if covariance is not None:
        n = len(covariance) if dimension is None else dimension
        check_covariance(covariance, n, "covariance")
    rotation = getattr(obstacle, "rotation", None)
    require(
        rotation is None or axes is not None,
        "rotation",
        "turns the principal axes of axes_sigma: give it with axes_sigma only",
        rotation,
    )
    if axes is not None:
        _check_axes(axes, rotation, dimension)
    schedule = forms["covariance_schedule"]
    if schedule is not None:
        _check_schedule(schedule, schedule.covariances, "covariance_schedule", "covariances")
        n = len(schedule.covariances[0]) if dimension is None else dimension
        check_covariances(schedule.covariances, n, "covariance_schedule.covariances")


def _check_schedule(schedule: Any, samples: Sequence[Any], name: str, what: str) -> None:
    """A piecewise-linear schedule: as many `samples` as times (≥ 1), at step times."""
    require(
        len(schedule.times) >= 1 and len(schedule.times) == len(samples),
        name,
        f"needs as many {what} as times (≥ 1)",
        schedule,
    )
    check_step_times(schedule.times, f"{name}.times")


def _check_axes(axes: list[float], rotation: list[float] | None, dimension: int | None) -> None:
    """`axes_sigma` (n standard deviations, m) and its `rotation` (rad)."""
    n = len(axes) if dimension is None else dimension
    check_vector(axes, "axes_sigma", n)
    for k, value in enumerate(axes):
        where = f"axes_sigma[{k}]"
        require(value > 0.0, where, "must be > 0 (a standard deviation in metres)", value)
        check_sigma(value, where)
    if rotation is not None:
        angles = "1 entry in 2D: [angle]" if n == 2 else "3 entries in 3D: [roll, pitch, yaw]"
        require(
            len(rotation) == (1 if n == 2 else 3), "rotation", f"must have {angles} (rad)", rotation
        )
        require(all(math.isfinite(a) for a in rotation), "rotation", "must be finite", rotation)
    check_covariance(axes_covariance(axes, rotation, n).tolist(), n, "axes_sigma")


def check_sigma(value: float, name: str) -> None:
    """σ ≥ :data:`SIGMA_MIN` (see there why)."""
    require(
        value >= SIGMA_MIN,
        name,
        f"must be ≥ {SIGMA_MIN:g} (a standard deviation in metres; below 1 mm the tube "
        "law's level sets are too thin to integrate and its probabilities too costly to "
        "evaluate: treat such an obstacle as certain with sigma 0.001)",
        value,
    )


def distinct_format(value: float, bound: float) -> str:
    """`value` with as many significant digits (3 or more) as it takes to differ from
    `bound` written the same way (a ratio of 1.00000001e8 is not "1e+08 exceeds 1e+08")."""
    for digits in range(3, 18):
        text = f"{value:.{digits}g}"
        if text != f"{bound:.{digits}g}":
            return text
    return repr(value)


def check_covariance(matrix: list[list[float]], n: int, name: str) -> None:
    """A covariance Σ (m²) the anisotropic law can use: n×n, finite, symmetric (within
    :data:`stt_drake.core.anisotropic.SYMMETRY_RTOL` relative), positive definite, with
    λ_max/λ_min ≤ :data:`MAX_CONDITION`, and its smallest standard deviation
    √λ_min ≥ :data:`SIGMA_MIN` (the rule of :func:`check_sigma`)."""
    require(
        len(matrix) == n and all(hasattr(row, "__len__") and len(row) == n for row in matrix),
        name,
        f"must be a {n}x{n} matrix ({n} rows of {n} entries, m²) in this {n}D scenario",
        matrix,
    )
    values = np.asarray(matrix, dtype=float)
    require(bool(np.all(np.isfinite(values))), name, "must be finite", matrix)
    asymmetry = float(np.max(np.abs(values - values.T)))
    allowed = anisotropic.SYMMETRY_RTOL * float(np.max(np.abs(values)))
    require(
        asymmetry <= allowed,
        name,
        f"must be symmetric: max |Σ − Σᵀ| = {asymmetry:.3g} exceeds "
        f"{anisotropic.SYMMETRY_RTOL:g} × max |Σ|",
        matrix,
    )
    eigenvalues = np.linalg.eigvalsh(0.5 * (values + values.T))
    smallest, largest = float(eigenvalues[0]), float(eigenvalues[-1])
    require(
        smallest > 0.0,
        name,
        f"must be symmetric positive definite: smallest eigenvalue {smallest:.3g}",
        matrix,
    )
    ratio = largest / smallest
    require(
        ratio <= MAX_CONDITION,
        name,
        f"must be well conditioned: eigenvalue ratio λ_max/λ_min = "
        f"{distinct_format(ratio, MAX_CONDITION)} exceeds {MAX_CONDITION:g} (numerically "
        "singular)",
        matrix,
    )
    require(
        math.sqrt(smallest) >= SIGMA_MIN,
        name,
        f"must have every standard deviation ≥ {SIGMA_MIN:g} m: the smallest, √λ_min, is "
        f"{math.sqrt(smallest):.3g} m (the rule of sigma: below 1 mm the tube law's level "
        "sets are too thin to integrate)",
        matrix,
    )


def check_covariances(matrices: list, n: int, name: str) -> None:
    """:func:`check_covariance` for every matrix of `matrices` (named ``<name>[k]``),
    batched: the shapes in one pass, then every other rule on the stacked array with one
    batched eigendecomposition (a 10 000-matrix schedule takes ~10 ms, not seconds); the
    first matrix that breaks a rule is checked alone for its message."""
    for k, matrix in enumerate(matrices):
        if not (
            hasattr(matrix, "__len__")
            and len(matrix) == n
            and all(hasattr(row, "__len__") and len(row) == n for row in matrix)
        ):
            check_covariance(matrix, n, f"{name}[{k}]")
    if not matrices:
        return
    values = np.asarray(matrices, dtype=float)
    finite = np.all(np.isfinite(values), axis=(1, 2))
    safe = np.where(finite[:, None, None], values, 1.0)
    asymmetry = np.max(np.abs(safe - np.swapaxes(safe, 1, 2)), axis=(1, 2))
    allowed = anisotropic.SYMMETRY_RTOL * np.max(np.abs(safe), axis=(1, 2))
    eigenvalues = np.linalg.eigvalsh(0.5 * (safe + np.swapaxes(safe, 1, 2)))
    smallest, largest = eigenvalues[:, 0], eigenvalues[:, -1]
    positive = smallest > 0.0
    tiny = np.where(positive, smallest, 1.0)
    good = (
        finite
        & (asymmetry <= allowed)
        & positive
        & (largest / tiny <= MAX_CONDITION)
        & (np.sqrt(tiny) >= SIGMA_MIN)
    )
    for k in np.flatnonzero(~good):  # the same rules one by one: the first raises
        check_covariance(matrices[int(k)], n, f"{name}[{int(k)}]")
