"""The rules of an obstacle's or a sensor's uncertainty: a standard deviation σ of at
least :data:`SIGMA_MIN`, and a full covariance Σ that is n×n, finite, symmetric, positive
definite, conditioned to at most :data:`MAX_CONDITION` and with every standard deviation
√λ ≥ :data:`SIGMA_MIN` (:func:`require_covariance`; a schedule's matrices all at once,
:func:`require_covariances`). Re-exported by :mod:`stt_drake.config.validate`.
"""

import math

import numpy as np

from stt_drake.config.limits import require
from stt_drake.core import anisotropic

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


def require_sigma(value: float, path: str) -> None:
    """σ ≥ :data:`SIGMA_MIN` (see there why)."""
    require(
        value >= SIGMA_MIN,
        path,
        f"must be ≥ {SIGMA_MIN:g} (a standard deviation in metres; below 1 mm the tube "
        "law's level sets are too thin to integrate and its probabilities too costly to "
        "evaluate: treat such an obstacle as certain with sigma 0.001)",
        value,
    )


#: Largest eigenvalue ratio λ_max/λ_min of a covariance in a scenario file. A larger one is
#: numerically singular for this tool: eigh determines λ_min only to ~1e-16·λ_max (at 1e8,
#: to 1e-8 of itself), the exact probabilities are tested up to ratios of 1e4
#: (``tests/core/test_anisotropic.py``), and σ ≥ 1 mm with |x| ≤ 1e6 m needs no more. (The
#: numerical core accepts up to :data:`stt_drake.core.anisotropic.MAX_CONDITION`, 1e12, for
#: a tracker's covariances.)
MAX_CONDITION = 1e8


def distinct_format(value: float, bound: float) -> str:
    """`value` with as many significant digits (3 or more) as it takes to differ from
    `bound` written the same way (a ratio of 1.00000001e8 is not "1e+08 exceeds 1e+08")."""
    for digits in range(3, 18):
        text = f"{value:.{digits}g}"
        if text != f"{bound:.{digits}g}":
            return text
    return repr(value)


def require_covariance(matrix: list[list[float]], n: int, path: str) -> None:
    """A covariance Σ (m²) the anisotropic law can use: n×n, finite, symmetric (within
    :data:`stt_drake.core.anisotropic.SYMMETRY_RTOL` relative), positive definite, with
    λ_max/λ_min ≤ :data:`MAX_CONDITION`, and its smallest standard deviation
    √λ_min ≥ :data:`SIGMA_MIN` (the rule of :func:`require_sigma`)."""
    require(
        len(matrix) == n and all(hasattr(row, "__len__") and len(row) == n for row in matrix),
        path,
        f"must be a {n}x{n} matrix ({n} rows of {n} entries, m²) in this {n}D scenario",
        matrix,
    )
    values = np.asarray(matrix, dtype=float)
    require(bool(np.all(np.isfinite(values))), path, "must be finite", matrix)
    asymmetry = float(np.max(np.abs(values - values.T)))
    allowed = anisotropic.SYMMETRY_RTOL * float(np.max(np.abs(values)))
    require(
        asymmetry <= allowed,
        path,
        f"must be symmetric: max |Σ − Σᵀ| = {asymmetry:.3g} exceeds "
        f"{anisotropic.SYMMETRY_RTOL:g} × max |Σ|",
        matrix,
    )
    eigenvalues = np.linalg.eigvalsh(0.5 * (values + values.T))
    smallest, largest = float(eigenvalues[0]), float(eigenvalues[-1])
    require(
        smallest > 0.0,
        path,
        f"must be symmetric positive definite: smallest eigenvalue {smallest:.3g}",
        matrix,
    )
    ratio = largest / smallest
    require(
        ratio <= MAX_CONDITION,
        path,
        f"must be well conditioned: eigenvalue ratio λ_max/λ_min = "
        f"{distinct_format(ratio, MAX_CONDITION)} exceeds {MAX_CONDITION:g} (numerically "
        "singular)",
        matrix,
    )
    require(
        math.sqrt(smallest) >= SIGMA_MIN,
        path,
        f"must have every standard deviation ≥ {SIGMA_MIN:g} m: the smallest, √λ_min, is "
        f"{math.sqrt(smallest):.3g} m (the rule of sigma: below 1 mm the tube law's level "
        "sets are too thin to integrate)",
        matrix,
    )


def require_covariances(matrices: list, n: int, path: str) -> None:
    """:func:`require_covariance` for every matrix of `matrices` (named
    ``<path>[k]``), batched: the shapes in one pass, then every other rule on the stacked
    array with one batched eigendecomposition (a 10 000-matrix schedule takes ~10 ms, not
    seconds); the first matrix that breaks a rule is checked alone for its message."""
    for k, matrix in enumerate(matrices):
        if not (
            hasattr(matrix, "__len__")
            and len(matrix) == n
            and all(hasattr(row, "__len__") and len(row) == n for row in matrix)
        ):
            require_covariance(matrix, n, f"{path}[{k}]")
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
        require_covariance(matrices[int(k)], n, f"{path}[{int(k)}]")
