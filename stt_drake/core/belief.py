"""The Gaussian obstacle belief of Definition 2.1, and its layout on a Drake vector port.

Obstacle j is the ball B(O_j, r_o_j) with an uncertain centre O_j ~ N(mean_j, sigma_j² I), or
O_j ~ N(mean_j, Σ_j) with a full covariance Σ_j (:func:`obstacle_covariance`).
Each obstacle also carries its own task numbers: the minimum avoidance probability
epsilon_j (Definition 2.3) and the separation level p_d_j of Assumption 3.

The belief is what a tracker knows; the task numbers are the tube's. One type per boundary:

* on the `obstacle_belief` port, the belief of `count` obstacle slots in dimension n is
  one vector, slot-major: ``[mean (n), covariance (n², row-major), active]`` for slot 0,
  then slot 1, ... (:class:`GaussianBelief`); active is 1.0 for a slot holding a track,
  else 0.0. The task numbers r_o, ε, p_d of each slot are parameters (:class:`ObstacleTask`);
* the tube law, the invariant monitor and the visualizer read an :class:`ObstacleBelief`:
  the obstacles' arrays with their task numbers. A system makes it once from its input
  (:meth:`ObstacleBelief.from_port`, a :class:`PortBelief`); what is computed from it is
  per slot (:meth:`ObstacleBelief.in_slots`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Protocol

import numpy as np
from scipy import special

from stt_drake.core.motion import CovarianceSchedule, Motion, MotionTable, SigmaSchedule
from stt_drake.core.rules import check_obstacles, check_task_slots, checked_by


def record_size(dimension: int) -> int:
    """Length of one obstacle slot's record on the belief port: mean (n), covariance (n²),
    active (1)."""
    return dimension + dimension * dimension + 1


def belief_size(count: int, dimension: int) -> int:
    """Length of the belief port vector for `count` obstacle slots in R^dimension."""
    return count * record_size(dimension)


def slot_active(vector: np.ndarray, dimension: int) -> np.ndarray:
    """Whether each slot of a belief port `vector` is active (its record's flag > 0.5),
    read off the vector in place (nothing unpacked)."""
    return vector[record_size(dimension) - 1 :: record_size(dimension)] > 0.5


def check_vector_length(length: int, dimension: int) -> None:
    """ValueError unless a port vector of `length` is a whole number of slot records."""
    n = dimension
    if length % record_size(n):
        raise ValueError(
            f"obstacle_belief: a vector of length {length} is not a whole number of "
            f"{record_size(n)}-long slot records [mean ({n}), covariance ({n * n}), "
            f"active] for dimension {n}"
        )


def _check_slot_count(slots: int, task: ObstacleTask) -> None:
    if task.count != slots:
        raise ValueError(
            f"obstacle_belief: {slots} slots on the port but {task.count} "
            "obstacles' task numbers (radius, epsilon, p_d)"
        )


@dataclass(frozen=True)
class GaussianBelief:
    """What a tracker knows of every obstacle slot at one instant: the `obstacle_belief`
    port's value (layout in the module docstring).

    Attributes:
        mean: (m, n) mean of each obstacle centre, metres.
        covariance: (m, n, n) covariance Σ_j of each centre, m² (symmetric positive
            definite in an active slot).
        active: (m,) bool, whether slot j holds a track; an inactive slot's mean and
            covariance mean nothing and never reach the tube.
    """

    mean: np.ndarray
    covariance: np.ndarray
    active: np.ndarray

    @property
    def count(self) -> int:
        return self.mean.shape[0]

    @property
    def dimension(self) -> int:
        return self.mean.shape[1]

    def per_slot(self, values: np.ndarray, fill: float) -> np.ndarray:
        """`values` of the active slots (in slot order) spread over every slot, `fill` in
        the inactive ones."""
        spread = np.full(self.count, fill)
        spread[self.active] = values
        return spread

    def to_vector(self) -> np.ndarray:
        """Pack into the port layout of the module docstring."""
        count, n = self.mean.shape
        table = np.empty((count, record_size(n)))
        table[:, :n] = self.mean
        table[:, n:-1] = np.reshape(self.covariance, (count, n * n))
        table[:, -1] = np.asarray(self.active, dtype=float)
        return table.reshape(-1)

    @classmethod
    def from_vector(cls, vector: np.ndarray, dimension: int) -> GaussianBelief:
        """Unpack a port vector (mean and covariance are views of it)."""
        n = dimension
        vector = np.asarray(vector, dtype=float)
        check_vector_length(vector.size, n)
        table = vector.reshape(-1, record_size(n))
        return cls(
            mean=table[:, :n],
            covariance=table[:, n:-1].reshape(-1, n, n),
            active=table[:, -1] > 0.5,
        )


@dataclass(frozen=True)
class ObstacleTask:
    """The task numbers of every obstacle slot (arrays over slots j): parameters of the
    tube, not of the belief (a tracker does not know them).

    Attributes:
        radius: (m,) obstacle radius r_o, metres (> 0).
        epsilon: (m,) required avoidance probability ε_j (Definition 2.3), in (0, 1].
        p_d: (m,) separation probability of Assumption 3, in (ε_j, 1) (1 can never hold
            for a Gaussian centre).

    Checked per slot when made (:func:`stt_drake.core.rules.check_task_slots`).
    """

    radius: np.ndarray
    epsilon: np.ndarray
    p_d: np.ndarray

    def __post_init__(self) -> None:
        with checked_by("ObstacleTask"):
            check_task_slots(self.radius, self.epsilon, self.p_d)

    @property
    def count(self) -> int:
        return self.radius.shape[0]

    def table(self) -> np.ndarray:
        """(m, 4) rows [r_o, ε, p_d, Φ⁻¹(ε)] per slot: the compiled kernels' layout, made once."""
        return self._table

    @cached_property
    def _table(self) -> np.ndarray:
        columns = [self.radius, self.epsilon, self.p_d, special.ndtri(self.epsilon)]
        return np.column_stack(columns).astype(float)

    @classmethod
    def of(cls, obstacles: Sequence[ObstacleModel]) -> ObstacleTask:
        """The task numbers of scenario obstacles, one slot each, in order (checked per
        obstacle, ``obstacles[j].epsilon`` naming a bad one)."""
        with checked_by("ObstacleTask.of"):
            check_obstacles(obstacles)
        return cls(
            radius=np.array([o.radius for o in obstacles], dtype=float),
            epsilon=np.array([o.epsilon for o in obstacles], dtype=float),
            p_d=np.array([o.p_d for o in obstacles], dtype=float),
        )


@dataclass(frozen=True)
class ObstacleBelief:
    """What the tube law, the invariant monitor and the visualizer read for every obstacle
    at one instant (arrays over obstacles j): the belief with its task numbers, ready for
    the kernels. Made by :func:`obstacle_belief` (scripted obstacles, one per slot), by
    :meth:`of` (the active slots of a :class:`GaussianBelief`) or, at a system's input, by
    :meth:`from_port` (the same, unpacked on first use).

    Attributes:
        mean: (m, n) mean of each obstacle centre, metres.
        sigma: (m,) standard deviation of each centre per axis, metres (not a variance):
            σ_j² = λ_max(Σ_j), the largest eigenvalue of the covariance (exactly σ_j
            for Σ_j = σ_j² I; see :func:`largest_sigma` for other Σ_j).
        radius: (m,) obstacle radius r_o, metres.
        epsilon: (m,) required avoidance probability, in (0, 1].
        p_d: (m,) separation probability of Assumption 3, in (epsilon, 1].
        covariance: (m, n, n) full covariance Σ_j of each centre (m², symmetric positive
            definite), or None: the law uses σ_j² I (:mod:`stt_drake.core.tube`); given,
            the law uses Σ_j exactly (:mod:`stt_drake.core.anisotropic_tube`).
    """

    mean: np.ndarray
    sigma: np.ndarray
    radius: np.ndarray
    epsilon: np.ndarray
    p_d: np.ndarray
    covariance: np.ndarray | None = None

    @property
    def count(self) -> int:
        return self.mean.shape[0]

    @property
    def dimension(self) -> int:
        return self.mean.shape[1]

    @property
    def task(self) -> ObstacleTask:
        """The task numbers r_o, ε, p_d of these obstacles."""
        return ObstacleTask(radius=self.radius, epsilon=self.epsilon, p_d=self.p_d)

    def gaussian(self) -> GaussianBelief:
        """The belief as a tracker would give it: Σ_j (σ_j² I without `covariance`), every
        slot active."""
        covariance = self.covariance
        if covariance is None:
            covariance = self.sigma[:, None, None] ** 2 * np.eye(self.dimension)
        return GaussianBelief(self.mean, covariance, np.ones(self.count, dtype=bool))

    def to_vector(self) -> np.ndarray:
        """The `obstacle_belief` port value of this belief (:meth:`gaussian`)."""
        return self.gaussian().to_vector()

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(μ, σ, r_o, ε, p_d): the isotropic kernels' per-obstacle arguments, in order."""
        return self.mean, self.sigma, self.radius, self.epsilon, self.p_d

    @property
    def packed(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(port vector, task rows) for the compiled kernels that read the port themselves
        (σ_j = √λ_max(Σ_j) computed in the kernel); None: not made from a port, or the
        law uses each Σ_j (see :attr:`port_arrays`)."""
        return None

    @property
    def port_arrays(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(port vector, task rows) of a belief made from a port, whichever way its
        covariances are read; None: not made from a port."""
        return None

    @property
    def all_active(self) -> bool:
        """Whether every port slot holds an obstacle: here always."""
        return True

    def in_slots(self, values: np.ndarray, fill: float) -> np.ndarray:
        """Per-obstacle `values` over the port slots this belief was made from, `fill` in an
        inactive slot; here obstacle j is slot j, so `values` itself."""
        return values

    def of_obstacles(self, rows: np.ndarray | None) -> np.ndarray | None:
        """Per-slot `rows` (e.g. circulation axes) at the obstacles of this belief; here
        obstacle j is slot j, so `rows` itself."""
        return rows

    def obstacles(self) -> ObstacleBelief:
        """This belief with its arrays made: itself (a :class:`PortBelief` unpacks)."""
        return self

    @classmethod
    def from_port(
        cls, vector: np.ndarray, dimension: int, task: ObstacleTask, full_covariance: bool = False
    ) -> PortBelief:
        """The belief a system reads from its `obstacle_belief` input: the active slots of the
        port `vector` with their `task` numbers (:meth:`of`), unpacked on first use; Σ_j
        kept when `full_covariance`."""
        return PortBelief(vector, dimension, task, full_covariance)

    @classmethod
    def of(
        cls, belief: GaussianBelief, task: ObstacleTask, full_covariance: bool = False
    ) -> ObstacleBelief:
        """The active slots of `belief` with their task numbers, in slot order; σ_j =
        √λ_max(Σ_j), and Σ_j kept when `full_covariance`."""
        _check_slot_count(belief.count, task)
        active = np.flatnonzero(belief.active)
        covariance = belief.covariance[active]
        arrays = {
            "mean": belief.mean[active],
            "radius": task.radius[active],
            "epsilon": task.epsilon[active],
            "p_d": task.p_d[active],
        }
        if full_covariance:
            return CovarianceBelief(**arrays, covariance=covariance)
        return cls(**arrays, sigma=largest_sigma(covariance))


class CovarianceBelief(ObstacleBelief):
    """An :class:`ObstacleBelief` with full covariances Σ_j whose σ_j = √λ_max(Σ_j) is
    computed on first read (:meth:`ObstacleBelief.of` with `full_covariance`): the exact law
    and the monitor read Σ_j only (an eigen-decomposition per evaluation costs more)."""

    def __init__(
        self,
        mean: np.ndarray,
        radius: np.ndarray,
        epsilon: np.ndarray,
        p_d: np.ndarray,
        covariance: np.ndarray,
        sigma: np.ndarray | None = None,
    ) -> None:
        # frozen, as every ObstacleBelief: the fields set once, in one step
        self.__dict__.update(
            mean=mean, radius=radius, epsilon=epsilon, p_d=p_d, covariance=covariance
        )
        if sigma is not None:  # given (dataclasses.replace passes every field)
            self.__dict__["sigma"] = sigma

    @cached_property
    def sigma(self) -> np.ndarray:  # type: ignore[override]
        """σ_j = √λ_max(Σ_j), m (a standard deviation), computed once on first read."""
        return largest_sigma(self.covariance)


def _unpacked(name: str) -> property:
    """A :class:`PortBelief` field, read from its unpacked arrays."""
    return property(
        lambda self: getattr(self.obstacles(), name),
        doc=f"{name} of the active slots (:class:`ObstacleBelief`), unpacked on first use",
    )


class PortBelief(ObstacleBelief):
    """An :class:`ObstacleBelief` made from an `obstacle_belief` port value
    (:meth:`ObstacleBelief.from_port`): the active slots with the task's r_o, ε, p_d
    (:meth:`ObstacleBelief.of`). Nothing is unpacked until a field is read: the compiled
    kernels of the isotropic law and of the margins read the port vector and the task rows
    themselves (:attr:`packed`), so the hot path pays one compiled call. What is computed
    from it is spread back over the slots (:meth:`in_slots`).

    Attributes:
        vector: the port vector (layout in the module docstring).
        slot_task: r_o, ε, p_d of every slot.
        full_covariance: whether the law uses each Σ_j exactly (`covariance` is then Σ_j of
            the active slots), else σ_j² = λ_max(Σ_j) (`covariance` None).
    """

    mean = _unpacked("mean")
    sigma = _unpacked("sigma")
    radius = _unpacked("radius")
    epsilon = _unpacked("epsilon")
    p_d = _unpacked("p_d")

    def __init__(
        self, vector: np.ndarray, dimension: int, task: ObstacleTask, full_covariance: bool
    ) -> None:
        vector = np.asarray(vector, dtype=float)
        check_vector_length(vector.size, dimension)
        _check_slot_count(vector.size // record_size(dimension), task)
        # frozen, as every ObstacleBelief: the fields set once, in one step (a tube
        # evaluation makes one of these)
        self.__dict__.update(
            vector=vector,
            slot_task=task,
            full_covariance=bool(full_covariance),
            _dimension=dimension,
        )

    @property
    def dimension(self) -> int:
        return self._dimension

    @property
    def covariance(self) -> np.ndarray | None:  # type: ignore[override]
        """Σ_j of the active slots with `full_covariance` (unpacked on first use), else None."""
        return self.obstacles().covariance if self.full_covariance else None

    @property
    def packed(self) -> tuple[np.ndarray, np.ndarray] | None:
        return None if self.full_covariance else self.port_arrays

    @property
    def port_arrays(self) -> tuple[np.ndarray, np.ndarray] | None:
        return self.vector, self.slot_task.table()

    @cached_property
    def all_active(self) -> bool:
        """Whether every slot is active (:func:`slot_active`: nothing unpacked)."""
        return bool(slot_active(self.vector, self._dimension).all())

    @cached_property
    def slots(self) -> GaussianBelief:
        """The port value, unpacked (views of :attr:`vector`)."""
        return GaussianBelief.from_vector(self.vector, self._dimension)

    def in_slots(self, values: np.ndarray, fill: float) -> np.ndarray:
        """Per-obstacle `values` spread over the slots, `fill` in the inactive ones."""
        slots = self.slots
        return values if slots.active.all() else slots.per_slot(values, fill)

    def of_obstacles(self, rows: np.ndarray | None) -> np.ndarray | None:
        """Per-slot `rows` at the active slots."""
        if rows is None:
            return None
        return np.asarray(rows).reshape(self.slots.count, -1)[self.slots.active]

    def obstacles(self) -> ObstacleBelief:
        """The active slots' arrays (:meth:`ObstacleBelief.of`), made once."""
        return self._obstacles

    @cached_property
    def _obstacles(self) -> ObstacleBelief:
        return ObstacleBelief.of(self.slots, self.slot_task, self.full_covariance)


class ObstacleModel(Protocol):
    """What the belief of one obstacle is made from: the mean's motion model, the centre's
    uncertainty and the task numbers r_o, ε, p_d (a scenario's ``Obstacle`` is one).

    The uncertainty is isotropic, σ (m, constant, or `sigma_schedule`), unless one of the
    full-covariance forms is given (see :func:`obstacle_covariance`): `covariance` (n×n,
    m²), `axes_sigma` (n standard deviations, m, along principal axes turned by
    `rotation`, rad) or `covariance_schedule`.
    """

    motion: Motion
    radius: float
    sigma: float
    sigma_schedule: SigmaSchedule | None
    covariance: list[list[float]] | None
    axes_sigma: list[float] | None
    rotation: list[float] | None
    covariance_schedule: CovarianceSchedule | None
    epsilon: float
    p_d: float


def rotation_matrix(angles: Sequence[float] | None, dimension: int) -> np.ndarray:
    """R (n, n) from rotation angles (rad): 2D ``[angle]``, R = [[cos, −sin], [sin, cos]];
    3D ``[roll, pitch, yaw]``, R = Rz(yaw)·Ry(pitch)·Rx(roll) (Drake's RollPitchYaw). None or
    empty: no rotation (I)."""
    if angles is None or len(angles) == 0:
        return np.eye(dimension)
    a = np.asarray(angles, dtype=float)
    if dimension == 2 and a.shape == (1,):
        c, s = np.cos(a[0]), np.sin(a[0])
        return np.array([[c, -s], [s, c]])
    if dimension == 3 and a.shape == (3,):
        (cr, cp, cy), (sr, sp, sy) = np.cos(a), np.sin(a)
        rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
        ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
        rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
        return rz @ ry @ rx
    raise ValueError(
        f"rotation: give 1 angle in 2D or [roll, pitch, yaw] in 3D (rad), got {list(a)} "
        f"for dimension {dimension}"
    )


def axes_covariance(
    axes_sigma: Sequence[float], rotation: Sequence[float] | None, dimension: int
) -> np.ndarray:
    """Σ = R diag(axes_sigma²) Rᵀ (m²): standard deviations `axes_sigma` (m) along the
    principal axes, the columns of R = :func:`rotation_matrix` (`rotation` in rad)."""
    r = rotation_matrix(rotation, dimension)
    matrix = (r * np.asarray(axes_sigma, dtype=float) ** 2) @ r.T
    return 0.5 * (matrix + matrix.T)


def has_full_covariance(obstacle: ObstacleModel) -> bool:
    """Whether the obstacle gives a full covariance (`covariance`, `axes_sigma` or
    `covariance_schedule`) rather than σ; a model without these attributes is isotropic."""
    return any(
        getattr(obstacle, name, None) is not None
        for name in ("covariance_schedule", "covariance", "axes_sigma")
    )


def obstacle_covariance(obstacle: ObstacleModel, t: float, dimension: int) -> np.ndarray | None:
    """Σ_j(t) (n, n), m², symmetrised; None for an isotropic obstacle (σ or a σ schedule).

    One form is used, first given of: `covariance_schedule` (Σ(t)), `covariance`,
    `axes_sigma` with `rotation` (:func:`axes_covariance`). The scenario loader refuses a
    file that gives more than one, and checks each matrix
    (:mod:`stt_drake.config.validate`); a matrix that is not n×n raises ValueError."""
    matrix = _full_covariance(obstacle, t)
    if matrix is not None and matrix.shape != (dimension, dimension):
        raise ValueError(
            f"covariance: must be {dimension}x{dimension} for dimension {dimension}, "
            f"got shape {matrix.shape}"
        )
    return matrix


def _full_covariance(obstacle: ObstacleModel, t: float) -> np.ndarray | None:
    """:func:`obstacle_covariance` in the matrix's own dimension (axes: len(axes_sigma))."""
    schedule = getattr(obstacle, "covariance_schedule", None)
    if schedule is not None:
        matrix = schedule.covariance(t)
    elif getattr(obstacle, "covariance", None) is not None:
        matrix = np.asarray(obstacle.covariance, dtype=float)
    elif getattr(obstacle, "axes_sigma", None) is not None:
        axes = obstacle.axes_sigma
        return axes_covariance(axes, getattr(obstacle, "rotation", None), len(axes))
    else:
        return None
    return 0.5 * (matrix + matrix.T)


def obstacle_belief(obstacles: Sequence[ObstacleModel], dimension: int, t: float) -> ObstacleBelief:
    """The belief of every obstacle in `obstacles` at time t.

    When any obstacle has a full covariance the belief carries `covariance` (m, n, n): Σ_j(t)
    for those, σ_j(t)²·I for the isotropic ones, and sigma_j = √λ_max(Σ_j(t)) for the full
    ones (σ_j(t) for the others). Otherwise `covariance` is None."""
    covariances = [obstacle_covariance(o, t, dimension) for o in obstacles]
    covariance = None
    if any(matrix is not None for matrix in covariances):
        covariance = np.empty((len(obstacles), dimension, dimension))
        sigma = np.empty(len(obstacles))
        for j, (obstacle, matrix) in enumerate(zip(obstacles, covariances, strict=True)):
            if matrix is None:
                sigma[j] = obstacle_sigma(obstacle, t)
                covariance[j] = sigma[j] ** 2 * np.eye(dimension)
            else:
                sigma[j] = largest_sigma(matrix)
                covariance[j] = matrix
    else:
        sigma = np.array([obstacle_sigma(o, t) for o in obstacles])
    return ObstacleBelief(
        mean=MotionTable([o.motion for o in obstacles], dimension).positions(t),
        sigma=sigma,
        radius=np.array([o.radius for o in obstacles]),
        epsilon=np.array([o.epsilon for o in obstacles]),
        p_d=np.array([o.p_d for o in obstacles]),
        covariance=covariance,
    )


def largest_sigma(covariance: np.ndarray) -> np.ndarray | float:
    """√λ_max(Σ): the largest standard deviation (m) of a covariance (m²), or of each of a
    stack (..., n, n) of them.

    The isotropic tube law reads N(μ, Σ) as N(μ, λ_max(Σ) I). That is exact for
    Σ = σ² I (a scripted σ, or a tracker whose noise models are isotropic: its position
    covariance stays σ² I). For any other Σ it is NOT conservative everywhere: inflating a
    Gaussian moves mass away from its mean, so at points near μ the probability of
    hitting the obstacle falls (O_λ = O_Σ + W, W ~ N(0, λI − Σ), smooths the ball
    probability; Anderson's inequality bounds it by its value at μ, not at x). It is
    conservative only far out in the tails. So a belief that may carry a full Σ is run with
    the exact law (``full_covariance``, :mod:`stt_drake.core.anisotropic_tube`) and checked
    with the exact probabilities (:mod:`stt_drake.core.invariants`); the λ_max reading
    remains only where it is exact."""
    values = np.linalg.eigvalsh(np.asarray(covariance, dtype=float))[..., -1]
    root = np.sqrt(values)
    return float(root) if root.ndim == 0 else root


def obstacle_rate_bounds(obstacles: Sequence[ObstacleModel]) -> tuple[np.ndarray, np.ndarray]:
    """Per obstacle, sup ‖μ̇_j‖ and sup |σ̇_j| (m/s) from its motion model and σ schedule,
    steps excluded (a step is a belief discontinuity, see :mod:`stt_drake.core.motion`).

    For a covariance schedule σ_j is √λ_max(Σ_j(t)), and its bound is
    :meth:`stt_drake.core.motion.CovarianceSchedule.sigma_rate_bound`: at least every
    segment's |Δ√λ_max|/Δt, and a bound on the rate inside the segments too (Σ_j is linear
    there, √λ_max of it is not). A constant covariance gives 0."""
    mean_speed = np.array([o.motion.speed_bound() for o in obstacles], dtype=float)
    sigma_rate = np.array([_sigma_rate_bound(o) for o in obstacles], dtype=float)
    return mean_speed, sigma_rate


def _sigma_rate_bound(obstacle: ObstacleModel) -> float:
    schedule = getattr(obstacle, "covariance_schedule", None)
    if schedule is not None:
        return schedule.sigma_rate_bound()
    if has_full_covariance(obstacle) or obstacle.sigma_schedule is None:
        return 0.0
    return obstacle.sigma_schedule.rate_bound()


def obstacle_sigma(obstacle: ObstacleModel, t: float) -> float:
    """σ_j(t) (m): the schedule where given, else the constant `sigma`; for an obstacle
    with a full covariance, √λ_max(Σ_j(t))."""
    matrix = _full_covariance(obstacle, t)
    if matrix is not None:
        return largest_sigma(matrix)
    if obstacle.sigma_schedule is not None:
        return obstacle.sigma_schedule.sigma(t)
    return obstacle.sigma


def obstacle_sigma_bounds(obstacle: ObstacleModel) -> tuple[float, float]:
    """(low, high) (m) with low ≤ σ_j(t) ≤ high for every t: the constant σ, the range of a
    σ schedule's values, √λ_max of a constant covariance, or
    :meth:`stt_drake.core.motion.CovarianceSchedule.sigma_bounds`."""
    schedule = getattr(obstacle, "covariance_schedule", None)
    if schedule is not None:
        return schedule.sigma_bounds()
    matrix = _full_covariance(obstacle, 0.0)
    if matrix is not None:
        sigma = largest_sigma(matrix)
        return sigma, sigma
    if obstacle.sigma_schedule is not None:
        values = obstacle.sigma_schedule.values
        return float(min(values)), float(max(values))
    return float(obstacle.sigma), float(obstacle.sigma)
