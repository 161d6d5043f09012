"""The rules of an obstacle's or a sensor's uncertainty, as a scenario file is checked
against them: a standard deviation σ of at least :data:`SIGMA_MIN`, and a full covariance
Σ that is n×n, finite, symmetric, positive definite, conditioned to at most
:data:`MAX_CONDITION` and with every standard deviation √λ ≥ :data:`SIGMA_MIN`. The rules
are :mod:`stt_drake.core.obstacle`'s (which :class:`~stt_drake.core.obstacle.Obstacle`
checks when made); here they raise ScenarioError naming the field path. Re-exported by
:mod:`stt_drake.config.validate`.
"""

from stt_drake.config.limits import rule_path
from stt_drake.core.obstacle import (
    MAX_CONDITION,
    SIGMA_MIN,
    check_covariance,
    check_covariances,
    check_sigma,
    distinct_format,
)

__all__ = [
    "MAX_CONDITION",
    "SIGMA_MIN",
    "distinct_format",
    "require_covariance",
    "require_covariances",
    "require_sigma",
]


def require_sigma(value: float, path: str) -> None:
    """σ ≥ :data:`SIGMA_MIN` (:func:`stt_drake.core.obstacle.check_sigma`) at `path`."""
    with rule_path(path):
        check_sigma(value, "")


def require_covariance(matrix: list[list[float]], n: int, path: str) -> None:
    """A valid n×n covariance at `path` (:func:`stt_drake.core.obstacle.check_covariance`)."""
    with rule_path(path):
        check_covariance(matrix, n, "")


def require_covariances(matrices: list, n: int, path: str) -> None:
    """A valid n×n covariance at each ``<path>[k]``
    (:func:`stt_drake.core.obstacle.check_covariances`, batched)."""
    with rule_path(path):
        check_covariances(matrices, n, "")
