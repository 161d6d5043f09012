"""The rules of the paper's constants, one place for each: the core objects check them when
they are made (:class:`~stt_drake.core.tube.TubeLaw`,
:class:`~stt_drake.core.belief.ObstacleTask`, :class:`~stt_drake.core.control.BoxFunnel`,
:class:`~stt_drake.core.control.FunnelController`; :func:`stt_drake.assembly.AddStt` and
:class:`stt_drake.systems.tube.SpatiotemporalTube` the rules that need the obstacle count or
the start), and the scenario loader (:mod:`stt_drake.config.validate`) checks a file against
the same functions. So the Python API refuses exactly what a scenario file is refused for,
with the same rule text.

A broken rule raises :class:`RuleError` (a ValueError) carrying the field name relative
to what was checked (``nu``, ``epsilon``, ``k2[3]``), the rule and the value. Who checked
adds where (:func:`checked_by`): a constructor its name and argument, ``TubeLaw: nu must be
finite and > 0 (1/m) (got -1.0)``, ``AddStt: obstacles[2].epsilon must lie in (0, 1] (got
1.5)``; the loader the full field path, ``scenario.obstacles[2].epsilon: must lie in (0, 1]
(got 1.5)``.

The rules:

* tube constants (:func:`check_tube_constants`): k1 > 0, k2 > 0, k3 ≥ 0 (each scalar or
  one per obstacle), 0 < r_min < r_max, linear_zone ≥ 0, η finite; ν > 0 and finite
  (:func:`check_nu`); max_center_speed ≥ 0 (:func:`check_center_speed`; ∞ means no bound:
  no boundary layer and no finite recovery speed — a scenario file must give a finite one);
* ν against the obstacle count, ν > ln(n_o + 1)/r_min (:func:`check_nu_for_count`; the
  soft-min radius stays > 0, Theorem 3.2 (iii)), once the count is known;
* full covariance ⇒ continuous time (:func:`check_continuous_for_covariance`): the
  fixed-rate tube's period bounds hold for isotropic beliefs only;
* an obstacle's task numbers (:func:`check_obstacle_task`): r_o > 0, ε ∈ (0, 1],
  p_d ∈ (ε, 1) — p_d = 1 can never hold for a Gaussian centre (:data:`GAUSSIAN_P_D_RULE`);
* the funnel controller: κ_k > 0 per stage (:func:`check_kappa`), box funnels 0 < q < p and
  μ ≥ 0 per axis (:func:`check_box_funnel`);
* every number finite;
* the initial avoidance condition q_j(s, 0) > ε_j at the start s (Definition 2.3; J(0) > 0
  in the proof of Theorem 3.2 (ii)), :func:`check_initial_avoidance`, raising
  :class:`InitialConditionError`.
"""

from __future__ import annotations

import math
import reprlib
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import Any, Protocol

import numpy as np

from stt_drake.core import anisotropic
from stt_drake.core.probability import avoid_probability

#: Why p_d = 1 is refused (an obstacle's and a random field's): Assumption 3 can never hold.
GAUSSIAN_P_D_RULE = (
    "must be below 1: Assumption 3 asks P(‖c − O_j‖ ≥ r_o + r_min) ≥ p_d, and a Gaussian "
    "centre has unbounded support, so that probability is below 1 everywhere and p_d = 1 "
    "can never hold"
)

_REPR = reprlib.Repr()
_REPR.maxlevel = 3
_REPR.maxlist = _REPR.maxtuple = _REPR.maxset = 8
_REPR.maxdict = 6
_REPR.maxstring = _REPR.maxother = 60
_REPR.maxlong = 40

#: Longest echo of a value in a message (characters).
ECHO_LIMIT = 80


def short_repr(value: Any, limit: int = ECHO_LIMIT) -> str:
    """repr(value) cut to at most `limit` characters, computed without ever forming the
    whole repr (a list is cut after a few items, nesting after a few levels)."""
    text = _REPR.repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def echo(value: Any) -> str:
    """A short repr of `value` for a message: numpy arrays and scalars as Python lists and
    numbers, at most :data:`ECHO_LIMIT` characters."""
    if isinstance(value, np.ndarray):
        value = value.ravel()[:16].tolist() if value.size > 16 else value.tolist()
    elif isinstance(value, np.generic):
        value = value.item()
    return short_repr(value)


def join_field(prefix: str, field: str) -> str:
    """`field` inside `prefix`: ``obstacles[2]`` + ``epsilon`` → ``obstacles[2].epsilon``,
    ``k2`` + ``[3]`` → ``k2[3]``."""
    if not prefix:
        return field
    if not field:
        return prefix
    return prefix + field if field.startswith("[") else f"{prefix}.{field}"


class RuleError(ValueError):
    """A value breaks a rule of this module.

    Attributes:
        field: the field's name relative to what was checked (``nu``, ``epsilon``,
            ``obstacles[2].epsilon`` once a caller added where).
        rule: the rule, a phrase that follows the field (``must lie in (0, 1]``).
        value: the value that breaks it.
        owner: who checked (``TubeLaw``, ``AddStt``), or "".
        hint: what the owner adds to the rule (how to get a valid value there), or "".
    """

    def __init__(self, field: str, rule: str, value: Any, owner: str = "", hint: str = ""):
        self.field, self.rule, self.value, self.owner, self.hint = field, rule, value, owner, hint
        super().__init__(self.text())

    def text(self) -> str:
        """``<owner>: <field> <rule> (got <value>)``, or ``<field>: <rule> (got <value>)``
        without an owner; the hint in parentheses after the rule."""
        rule = f"{self.rule} ({self.hint})" if self.hint else self.rule
        where = f"{self.owner}: {self.field}" if self.owner else f"{self.field}:"
        return f"{where} {rule} (got {echo(self.value)})"

    def at(self, owner: str = "", prefix: str = "", hint: str = "") -> RuleError:
        """This error (of the same class) with `owner`, inside `prefix`, with `hint`."""
        return type(self)(
            join_field(prefix, self.field),
            self.rule,
            self.value,
            owner or self.owner,
            hint or self.hint,
        )


class InitialConditionError(RuleError):
    """The initial avoidance condition q_j(s, 0) > ε_j fails: an assumption of the theorem,
    not a malformed number (the scenario loader raises it as an AssumptionError)."""


@contextmanager
def checked_by(owner: str, prefix: str = "", hint: str = "") -> Iterator[None]:
    """Re-raise a :class:`RuleError` of the block naming `owner` (and the field inside
    `prefix`, with `hint`): the constructors' way of saying which argument is wrong."""
    try:
        yield
    except RuleError as error:
        raise error.at(owner, prefix, hint) from None


def require(condition: bool, field: str, rule: str, value: Any) -> None:
    """Raise :class:`RuleError` (`field`, `rule`, `value`) unless `condition`."""
    if not condition:
        raise RuleError(field, rule, value)


def _values(value: Any, field: str) -> np.ndarray:
    """`value` (a number or an array of them) as a flat float array; RuleError if it is
    not numbers."""
    try:
        return np.asarray(value, dtype=float).ravel()
    except (TypeError, ValueError):
        raise RuleError(field, "must be a number or an array of numbers", value) from None


def check_finite(value: Any, field: str) -> np.ndarray:
    """Every number of `value` finite; returns them as a flat float array."""
    if isinstance(value, float | int) and not isinstance(value, bool):  # the common case
        require(math.isfinite(value), field, "must be finite", value)
        return np.array([value], dtype=float)
    values = _values(value, field)
    require(bool(np.all(np.isfinite(values))), field, "must be finite", value)
    return values


def check_vector(value: Sequence[float], field: str, length: int) -> None:
    """`value` has `length` entries, all finite (a point or a velocity in R^n)."""
    require(len(value) == length, field, f"must have {length} entries", value)
    require(all(math.isfinite(v) for v in value), field, "must be finite", value)


def check_step_times(times: Sequence[float], field: str) -> None:
    """Times (s) of a piecewise-linear model: finite, non-decreasing, each at most twice (a
    repeated time is a step, see :mod:`stt_drake.core.motion`)."""
    require(all(math.isfinite(t) for t in times), field, "must be finite", times)
    steps = np.diff(np.asarray(times, dtype=float))
    require(
        bool(np.all(steps >= 0.0)) and not bool(np.any((steps[1:] == 0.0) & (steps[:-1] == 0.0))),
        field,
        "must increase (a time may be repeated once: a step)",
        times,
    )


def _check_each(value: Any, field: str, good: np.ndarray, rule: str) -> None:
    """`good` per entry of `value` (a scalar or an array): the first bad entry is named
    ``field[j]`` in an array, ``field`` for a scalar."""
    if np.all(good):
        return
    if np.ndim(value) == 0:
        raise RuleError(field, rule, value)
    j = int(np.flatnonzero(~good)[0])
    raise RuleError(f"{field}[{j}]", rule, np.asarray(value, dtype=float).ravel()[j])


def minimum_nu(obstacle_count: int, r_min: float) -> float:
    """Smallest ν for which the soft-min radius is provably positive (Theorem 3.2 (iii)).

    Every d̂_j > r_min while q_j > ε_j, so r ≥ r_min − ln(n_o + 1)/ν.
    """
    return float(np.log(obstacle_count + 1) / r_min)


def check_tube_constants(
    k1: float,
    k2: Any,
    k3: Any,
    r_min: float,
    r_max: float,
    linear_zone: float = 0.0,
    target: Any = None,
) -> None:
    """The tube law's gains and radii (Eqs. (4), (14)): 0 < r_min < r_max, k1 > 0, k2 > 0,
    k3 ≥ 0 (scalars or one per obstacle), linear_zone ≥ 0, every one finite, and η finite
    (when given)."""
    check_finite(r_min, "r_min")
    require(r_min > 0.0, "r_min", "must be > 0 (metres)", r_min)
    check_finite(r_max, "r_max")
    require(r_max > r_min, "r_max", f"must be > r_min = {r_min}", r_max)
    check_finite(k1, "k1")
    require(k1 > 0.0, "k1", "must be > 0", k1)
    _check_each(k2, "k2", check_finite(k2, "k2") > 0.0, "must be > 0")
    _check_each(k3, "k3", check_finite(k3, "k3") >= 0.0, "must be ≥ 0")
    check_finite(linear_zone, "linear_zone")
    require(
        linear_zone >= 0.0,
        "linear_zone",
        "must be ≥ 0 (metres; 0: the exact cube root)",
        linear_zone,
    )
    if target is not None:
        check_finite(target, "target")


def check_tube_law(
    target: Any,
    k1: float,
    k2: Any,
    k3: Any,
    r_min: float,
    r_max: float,
    nu: float,
    linear_zone: float = 0.0,
    max_center_speed: float = math.inf,
) -> None:
    """Every constant of a :class:`~stt_drake.core.tube.TubeLaw`:
    :func:`check_tube_constants`, :func:`check_nu`, :func:`check_center_speed` (∞ allowed);
    the arguments in the order of its fields."""
    check_tube_constants(k1, k2, k3, r_min, r_max, linear_zone, target)
    check_nu(nu)
    check_center_speed(max_center_speed)


def check_nu(nu: float) -> None:
    """ν > 0 and finite (the soft-min sharpness, 1/m)."""
    require(0.0 < nu < math.inf, "nu", "must be finite and > 0 (1/m)", nu)


#: What the constructors add to a broken :func:`check_nu_for_count`.
NU_HINT = "default_nu(n_o, r_min) gives twice the bound"


def check_nu_for_count(nu: float, r_min: float, obstacle_count: int) -> None:
    """ν > ln(n_o + 1)/r_min for n_o = `obstacle_count` (obstacle slots), or the soft-min
    radius can go negative (Theorem 3.2 (iii))."""
    bound = minimum_nu(obstacle_count, r_min)
    require(
        nu > bound,
        "nu",
        f"must exceed ln(n_o + 1)/r_min = {bound:.4g} for {obstacle_count} "
        f"obstacle{'' if obstacle_count == 1 else 's'}, or the soft-min radius can go negative",
        nu,
    )


#: Why a belief with full covariances Σ_j runs the continuous-time tube.
ISOTROPIC_PERIOD_RULE = (
    "the fixed-rate tube's period guarantee (stt_drake.core.fixed_rate) is derived for "
    "isotropic beliefs (sigma) only"
)


def check_continuous_for_covariance(
    full_covariance: bool, fixed_rate: bool, field: str, value: Any, continuous: str
) -> None:
    """Full covariance ⇒ continuous time: a tube whose belief has full covariances Σ_j must
    not run at a fixed rate (:data:`ISOTROPIC_PERIOD_RULE`). `field` is the caller's switch
    of the fixed rate, `value` its value and `continuous` the value that selects continuous
    time (a scenario's ``update_rate_hz`` 0, the system's ``update_period`` None, the law's
    period ``inflation`` None)."""
    require(
        not (full_covariance and fixed_rate),
        field,
        f"must be {continuous} (continuous time) when the belief has full covariances: "
        + ISOTROPIC_PERIOD_RULE,
        value,
    )


def check_center_speed(speed: float, finite: bool = False) -> None:
    """max_center_speed v_c ≥ 0 (m/s). Infinite is allowed unless `finite` (a scenario
    file's): it means no bound, so no boundary layer and no finite recovery speed."""
    if finite:
        require(0.0 <= speed < math.inf, "max_center_speed", "must be finite and ≥ 0 (m/s)", speed)
    else:
        require(
            speed >= 0.0,
            "max_center_speed",
            "must be ≥ 0 (m/s; inf: no bound, and a recovery has no finite speed)",
            speed,
        )


def check_obstacle_task(radius: float, epsilon: float, p_d: float) -> None:
    """One obstacle's task numbers: r_o > 0 (m), ε ∈ (0, 1] (Definition 2.3), p_d ∈ (ε, 1)
    (Assumption 3; p_d = 1 can never hold, :data:`GAUSSIAN_P_D_RULE`), all finite."""
    check_finite(radius, "radius")
    require(radius > 0.0, "radius", "must be > 0 (metres)", radius)
    check_finite(epsilon, "epsilon")
    require(0.0 < epsilon <= 1.0, "epsilon", "must lie in (0, 1]", epsilon)
    check_finite(p_d, "p_d")
    require(epsilon < p_d <= 1.0, "p_d", f"must lie in (epsilon, 1] = ({epsilon}, 1]", p_d)
    require(p_d < 1.0, "p_d", GAUSSIAN_P_D_RULE, p_d)


def check_task_slots(radius: Any, epsilon: Any, p_d: Any, as_obstacles: bool = False) -> None:
    """:func:`check_obstacle_task` for every slot j of the arrays (fields ``radius[j]``,
    ``epsilon[j]``, ``p_d[j]``, or ``obstacles[j].radius``, ... `as_obstacles`), which must
    have one entry per slot; vectorised, the first bad slot checked alone for its
    message."""
    radius, epsilon, p_d = (
        _values(v, name) for v, name in ((radius, "radius"), (epsilon, "epsilon"), (p_d, "p_d"))
    )
    for name, values in (("epsilon", epsilon), ("p_d", p_d)):
        require(
            values.size == radius.size,
            name,
            f"needs one entry per obstacle slot ({radius.size} radii)",
            values,
        )
    with np.errstate(invalid="ignore"):
        good = (
            np.isfinite(radius)
            & np.isfinite(epsilon)
            & np.isfinite(p_d)
            & (radius > 0.0)
            & (epsilon > 0.0)
            & (epsilon <= 1.0)
            & (p_d > epsilon)
            & (p_d < 1.0)
        )
    for j in np.flatnonzero(~good):
        try:
            check_obstacle_task(float(radius[j]), float(epsilon[j]), float(p_d[j]))
        except RuleError as error:
            field = f"obstacles[{j}].{error.field}" if as_obstacles else f"{error.field}[{j}]"
            raise RuleError(field, error.rule, error.value) from None


def check_obstacles(obstacles: Sequence[Any]) -> None:
    """:func:`check_obstacle_task` for each obstacle model (anything with radius, epsilon,
    p_d), fields ``obstacles[j].<name>``."""
    check_task_slots(
        [o.radius for o in obstacles],
        [o.epsilon for o in obstacles],
        [o.p_d for o in obstacles],
        as_obstacles=True,
    )


def check_kappa(kappa: Sequence[float]) -> None:
    """At least one stage gain κ_k, every one finite and > 0."""
    require(len(kappa) >= 1, "kappa", "needs at least one stage gain", kappa)
    values = check_finite(kappa, "kappa")
    require(bool(np.all(values > 0.0)), "kappa", "must all be > 0", kappa)


def check_box_funnel(start: Any, end: Any, rate: Any) -> None:
    """A box funnel γ(t) = (p − q)e^{−μt} + q: finite, 0 < q < p and μ ≥ 0 per axis."""
    p, q = check_finite(start, "start"), check_finite(end, "end")
    mu = check_finite(rate, "rate")
    try:
        inside = np.all((q > 0.0) & (q < p))
    except ValueError:  # shapes that do not broadcast
        raise RuleError("end", f"must have the shape of start ({p.size} entries)", end) from None
    require(bool(inside), "end", "must satisfy 0 < end < start per axis", end)
    require(bool(np.all(mu >= 0.0)), "rate", "must be ≥ 0", rate)


class _Belief(Protocol):
    """What :func:`check_initial_avoidance` reads of an obstacle belief
    (:class:`stt_drake.core.belief.ObstacleBelief`)."""

    mean: np.ndarray
    sigma: np.ndarray
    radius: np.ndarray
    epsilon: np.ndarray
    covariance: np.ndarray | None


def initial_avoidance(
    start: Any, belief: _Belief, r_min: float, exact: Sequence[bool] | None = None
) -> np.ndarray:
    """q_j(s, 0) = P(‖s − O_j‖ ≥ r_o_j + r_min) per obstacle of `belief` (the belief at
    t = 0): with σ_j (:func:`stt_drake.core.probability.avoid_probability`), and exactly with
    Σ_j (:func:`stt_drake.core.anisotropic.avoid_probability`) for the obstacles `exact`
    marks (None: all, when the belief has covariances)."""
    start = np.asarray(start, dtype=float)
    safety = np.asarray(belief.radius, dtype=float) + r_min
    q = np.array(avoid_probability(start, belief.mean, belief.sigma, safety), dtype=float)
    if belief.covariance is not None:
        marks = np.ones(q.size, dtype=bool) if exact is None else np.asarray(exact, dtype=bool)
        for j in np.flatnonzero(marks):  # exact with Σ_j (belief.sigma is √λ_max)
            q[j] = anisotropic.avoid_probability(
                start, belief.mean[j], belief.covariance[j], safety[j]
            )
    return q


def check_initial_avoidance(
    start: Any, belief: _Belief, r_min: float, exact: Sequence[bool] | None = None
) -> None:
    """q_j(s, 0) > ε_j for every obstacle (:func:`initial_avoidance`): the start s must not
    begin inside an obstacle's ε level set (Definition 2.3; J(0) > 0 in the proof of
    Theorem 3.2 (ii)); :class:`InitialConditionError` (field ``start``) naming the first
    obstacle that breaks it."""
    if len(belief.epsilon) == 0:
        return
    q = initial_avoidance(start, belief, r_min, exact)
    for j in np.flatnonzero(~(q > belief.epsilon)):
        raise InitialConditionError(
            "start",
            "must meet the initial avoidance condition q_j(s, 0) > epsilon_j for every "
            f"obstacle: obstacle {j} has q_{j}(s, 0) = {q[j]:.6g}, not above epsilon = "
            f"{float(belief.epsilon[j])} (move the start or the obstacle)",
            np.asarray(start, dtype=float).tolist(),
        )
