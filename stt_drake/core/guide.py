"""The guide above the tube: a route over the obstacles' predicted beliefs, and the moving
point η(t) on it that the tube is attracted to.

Why the guarantees do not change
--------------------------------
Theorem 3.2 has three claims. Claims (ii) (q_j(c(t), t) > ε_j and r(t) ≤ min_j d̂_j, so
P(‖c − O_j‖ ≥ r_o_j + r) ≥ ε_j) and (iii) (r(t) > 0) never use the attraction point: in
the proof of (ii), part 1, the attraction term k1·(η − c)^{1/3} is one of the bounded terms
of J̇_j, dominated by the repulsion k2_j m_j θ_j whose factor 1/(q_j − ε_j) grows without
bound as q_j → ε_j; part 2 and claim (iii) are statements about the soft-min radius at the
current centre. So they hold for *any* η(t) that is bounded and measurable — a point that
jumps at every replan, lies inside an obstacle's level set, or runs ahead of the tube — and
the tube, the controller and the monitor are unchanged. The guide only chooses η(t); the
tube law keeps the centre out of every ε set on its own, and the monitor checks it at every
step (``tests/core/test_guide.py`` places η inside level sets and checks (ii)/(iii) hold).

Claim (i) (reach in finite time) does depend on η: its proof needs θ_j = 0 for t ≥ t₁
(Assumption 3) and η fixed at the task's target. With a guide, η(t) equals the task's
target once the route's end is within the look-ahead, and from then on the proof applies
unchanged: claim (i) becomes "the tube reaches the task's target set in finite time *if*
the guide's route gets it within the look-ahead of the target with the field clear after
t₁". The guide cannot promise a route: the future beliefs are predictions (the scripted
motion exactly, a tracker's constant-velocity prediction approximately), a crowd can close
every gap, and the search is a grid search with a bounded budget. What it removes are the
equilibria of Eq. (4) that a purely reactive tube walks into — pockets, walls, gaps closing
from both sides — because its η goes around them instead of through them, and a stall is
detected and planned around.

The route
---------
A point x is *free* at time t for obstacle j when q̂_j(x, t) = P(‖x − O_j(t)‖ ≥ r_o_j +
r_min + clearance) ≥ the avoid level (default p_d_j: the tube is then not pushed at all and
its whole ball fits), and *forbidden* when q̂_j with r_o_j + r_min is below ε_j (the tube's
centre can never be there). For N(μ_j, σ_j² I) both sets are balls about μ_j
(:func:`stt_drake.core.probability.level_set_radius`); a full covariance is read as
σ_j² = λ_max(Σ_j) here (the guide's choice of route, not a safety statement). The route is
the space-time A* of :mod:`stt_drake.core.route_search` on the predicted beliefs at the
times the tube, moving at the planning speed, would be at each cell.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from stt_drake.core import backend
from stt_drake.core.belief import ObstacleModel, has_full_covariance, obstacle_covariance
from stt_drake.core.motion import MotionTable
from stt_drake.core.probability import level_set_radius
from stt_drake.core.route_search import REACHED, search_route
from stt_drake.core.tracking import KalmanTracker, TrackTable, predicted_position

#: Relative spacing of the log-β grid the level-set radii are interpolated on (β = r_s/σ).
BETA_SPACING = 0.01


@dataclass(frozen=True)
class GuideSettings:
    """The guide's numbers (derived from a scenario by
    :func:`stt_drake.assembly.guide.guide_settings`).

    Attributes:
        resolution: grid cell side (m).
        horizon: how far ahead the beliefs are predicted (s).
        time_step: spacing of the prediction knots (s).
        speed: the tube's planning speed along the route (m/s).
        max_wait: longest wait before one move (s).
        lookahead: how far η may run ahead of the tube along the route (m).
        clearance: extra radius of the free test beyond r_o + r_min (m).
        avoid_level: (m,) the avoidance probability a free point keeps per obstacle.
        stall_radius: the radius of the region a stall marks to be avoided (m).
        margin: how far the grid reaches beyond the box of the tube and the goal (m).
        max_cells: the largest grid (the cell side grows beyond it).
        max_expansions: the search's budget of expanded cells.
        greed: the weight (≥ 1) of the A* heuristic: a route costs at most that factor
            more than the best one, for far fewer expansions.
        soft_cost, hard_cost: extra cost per second inside an avoid-level set, an ε set.
        avoid_cost: extra cost per second inside a region where the tube stalled.
    """

    resolution: float
    horizon: float
    time_step: float
    speed: float
    max_wait: float
    lookahead: float
    clearance: float
    avoid_level: np.ndarray
    stall_radius: float = 1.0
    margin: float = 3.0
    max_cells: int = 40_000
    max_expansions: int = 20_000
    greed: float = 1.5
    soft_cost: float = 4.0
    hard_cost: float = 50.0
    avoid_cost: float = 8.0

    @property
    def corner_radius(self) -> float:
        """How close the tube's centre comes to a route corner before η turns it (m)."""
        return self.resolution

    @property
    def knots(self) -> np.ndarray:
        """Prediction knot offsets from the plan's time, 0 … horizon (s)."""
        count = math.ceil(self.horizon / self.time_step - 1e-9) + 1
        return self.time_step * np.arange(count)


class LevelSetRadii:
    """The radius D of the ball {x : q̂(x) < level} for N(μ, σ² I) and a ball of radius r_s,
    for many (σ, r_s, level) at once: D = σ·ρ(r_s/σ; level), with ρ computed exactly
    (:func:`stt_drake.core.probability.level_set_radius`, compiled as
    :func:`stt_drake.core._kernels.level_set_offsets`) on a log grid of β = r_s/σ of
    relative spacing :data:`BETA_SPACING`, kept per level as a table that grows to cover
    the β asked for, and interpolated linearly in log β (relative error ≪ 1 %: a route,
    not a certificate)."""

    def __init__(self, dimension: int) -> None:
        self.dimension = dimension
        #: level → (first grid index, ρ at the grid indices from it on)
        self._tables: dict[float, tuple[int, np.ndarray]] = {}

    def _table(self, level: float, low: int, high: int) -> tuple[int, np.ndarray]:
        """The table of `level` covering grid indices low … high."""
        first, values = self._tables.get(level, (low, np.zeros(0)))
        last = first + len(values) - 1
        if values.size and first <= low and high <= last:
            return first, values
        new_first, new_last = min(first, low), max(last, high)
        indices = np.arange(new_first, new_last + 1)
        missing = (indices < first) | (indices > last)  # all of them for a new table
        grown = np.empty(indices.size)
        grown[first - new_first : last - new_first + 1] = values  # an empty slice if new
        grown[missing] = self._radii(level, np.exp(indices[missing] * math.log1p(BETA_SPACING)))
        self._tables[level] = (new_first, grown)
        return new_first, grown

    def _radii(self, level: float, beta: np.ndarray) -> np.ndarray:
        """ρ(β; level) for σ = 1 at each β: one call of the compiled
        :func:`stt_drake.core._kernels.level_set_offsets` (unless the numpy path is selected),
        else :func:`stt_drake.core.probability.level_set_radius` one by one."""
        kernel = backend.compiled("level_set_offsets", self.dimension)
        if kernel is not None:
            return kernel(np.ascontiguousarray(beta, dtype=float), float(level), self.dimension)
        return np.array([level_set_radius(level, 1.0, b, self.dimension) for b in beta])

    def __call__(self, sigma: np.ndarray, radius: np.ndarray, level: np.ndarray) -> np.ndarray:
        """D (metres) for σ (K, m), r_s (m,) and level (m,); 0 where σ is not > 0."""
        sigma = np.asarray(sigma, dtype=float)
        radius = np.broadcast_to(np.asarray(radius, dtype=float), sigma.shape)
        valid = sigma > 0.0
        beta = np.where(valid, radius / np.where(valid, sigma, 1.0), 1.0)
        position = np.log(beta) / math.log1p(BETA_SPACING)
        low = np.floor(position).astype(int)
        weight = position - low
        rho = np.zeros(sigma.shape)
        levels = np.asarray(level, dtype=float)
        for value in np.unique(levels):
            columns = levels == value
            indices = low[:, columns]
            first, table = self._table(float(value), int(indices.min()), int(indices.max()) + 1)
            below = table[indices - first]
            above = table[indices + 1 - first]
            rho[:, columns] = below + weight[:, columns] * (above - below)
        return np.where(valid, sigma * rho, 0.0)


@dataclass(frozen=True)
class Forecast:
    """Predicted beliefs at knot times: ``means`` (K, m, n) m, ``sigma`` (K, m) m (the
    isotropic reading σ = √λ_max(Σ)), ``active`` (m,) bool, or (K, m) when a slot exists at
    some knots only (a recorded track's span)."""

    means: np.ndarray
    sigma: np.ndarray
    active: np.ndarray


class ScriptedForecast:
    """The scripted beliefs of `obstacles` ahead of time: their motion models and σ
    schedules are the prediction, exactly (a recorded track is absent outside its span)."""

    def __init__(self, obstacles: Sequence[ObstacleModel], dimension: int) -> None:
        self._obstacles = list(obstacles)
        self._motions = MotionTable([o.motion for o in self._obstacles], dimension)
        self._dimension = dimension

    def __call__(self, times: np.ndarray) -> Forecast:
        means = self._motions.positions_at(times)
        sigma = np.column_stack([self._sigma(o, times) for o in self._obstacles])
        sigma = sigma.reshape(len(times), len(self._obstacles))
        return Forecast(means, sigma, self._motions.active_at(times))

    def _sigma(self, obstacle: ObstacleModel, times: np.ndarray) -> np.ndarray:
        if has_full_covariance(obstacle):
            matrices = [obstacle_covariance(obstacle, float(t), self._dimension) for t in times]
            return np.sqrt(np.linalg.eigvalsh(np.array(matrices))[:, -1])
        if obstacle.sigma_schedule is not None:
            schedule = obstacle.sigma_schedule
            return np.interp(times, schedule.times, schedule.values)
        return np.full(len(times), float(obstacle.sigma))


def tracked_forecast(tracker: KalmanTracker, tracks: TrackTable, times: np.ndarray) -> Forecast:
    """A tracker's own prediction of its tracks at `times`: each active slot's posterior
    predicted in closed form (:func:`stt_drake.core.tracking.predicted_position`), its
    covariance growing with the prediction time at the track's own process density (the
    adapted one of a monitored tracker, :meth:`~stt_drake.core.tracking.KalmanTracker.
    densities`: the belief's own); inactive slots never block."""
    knots, count = len(times), len(tracks.active)
    elapsed = np.asarray(times, dtype=float)[:, None] - tracks.detection_time[None, :]
    elapsed = np.where(tracks.active[None, :], elapsed, 0.0)
    state = np.broadcast_to(tracks.state, (knots, *tracks.state.shape))
    covariance = np.broadcast_to(tracks.covariance, (knots, *tracks.covariance.shape))
    mean, position = predicted_position(
        state.reshape(knots * count, -1),
        covariance.reshape(knots * count, *tracks.covariance.shape[1:]),
        elapsed.ravel(),
        np.tile(np.broadcast_to(tracker.densities(tracks), (count,)), knots),
    )
    sigma = np.sqrt(np.linalg.eigvalsh(position)[:, -1]).reshape(knots, count)
    sigma[:, ~tracks.active] = 0.0
    return Forecast(mean.reshape(knots, count, -1), sigma, tracks.active.copy())


@dataclass(frozen=True)
class Route:
    """A planned route: ``points`` (L, n) m from the tube's centre at the plan's time to the
    goal (or towards it), ``times`` (L,) s when the tube would be at each, ``reached``
    whether it ends at the goal, ``expansions`` the search's work."""

    points: np.ndarray
    times: np.ndarray
    reached: bool
    expansions: int

    @property
    def arc_length(self) -> np.ndarray:
        """(L,) distance along the route from its start (m)."""
        steps = np.linalg.norm(np.diff(self.points, axis=0), axis=1)
        return np.concatenate([[0.0], np.cumsum(steps)])


class RoutePlanner:
    """Plans a :class:`Route` over predicted beliefs (module docstring).

    Args:
        settings: the guide's numbers.
        radius, epsilon: (m,) each obstacle's r_o and ε (its task).
        r_min: the tube's minimum radius (m).
        dimension: n.
    """

    def __init__(
        self,
        settings: GuideSettings,
        radius: np.ndarray,
        epsilon: np.ndarray,
        r_min: float,
        dimension: int,
    ) -> None:
        self.settings = settings
        self._soft_radius = np.asarray(radius, dtype=float) + r_min + settings.clearance
        self._hard_radius = np.asarray(radius, dtype=float) + r_min
        self._epsilon = np.asarray(epsilon, dtype=float)
        self._radii = LevelSetRadii(dimension)
        self._dimension = dimension

    def blocking_radii(self, forecast: Forecast) -> tuple[np.ndarray, np.ndarray]:
        """(soft, hard) (K, m): the radii of each obstacle's avoid-level and ε sets at each
        knot (0 for an inactive slot)."""
        soft = self._radii(forecast.sigma, self._soft_radius, self.settings.avoid_level)
        hard = self._radii(forecast.sigma, self._hard_radius, self._epsilon)
        inactive = np.broadcast_to(~np.asarray(forecast.active, dtype=bool), soft.shape)
        soft[inactive] = 0.0
        hard[inactive] = 0.0
        return soft, hard

    def plan(
        self,
        start: np.ndarray,
        goal: np.ndarray,
        t0: float,
        forecast: Forecast,
        avoid: np.ndarray | None = None,
    ) -> Route:
        """The route from `start` (the tube's centre at time t0) to `goal` over `forecast`
        (at knots t0 + :attr:`GuideSettings.knots`), avoiding the stalled regions `avoid`
        ((p, n + 1) rows [centre, radius]; None: none)."""
        s, n = self.settings, self._dimension
        start, goal = np.asarray(start, dtype=float), np.asarray(goal, dtype=float)
        low = np.minimum(start, goal) - s.margin
        high = np.maximum(start, goal) + s.margin
        cell = max(s.resolution, float(np.prod(high - low) / s.max_cells) ** (1.0 / n))
        shape = np.maximum(np.ceil((high - low) / cell), 1).astype(np.int64)
        soft, hard = self.blocking_radii(forecast)
        avoid = np.zeros((0, n + 1)) if avoid is None else np.asarray(avoid, dtype=float)
        search = backend.compiled("route_search") or search_route
        points, times, status, expansions = search(
            low,
            cell,
            shape,
            start,
            goal,
            float(t0),
            s.time_step,
            np.ascontiguousarray(forecast.means, dtype=float),
            soft,
            hard,
            s.speed,
            round(s.max_wait / s.time_step),
            s.soft_cost,
            s.hard_cost,
            np.ascontiguousarray(avoid[:, :n]),
            np.ascontiguousarray(avoid[:, n]),
            s.avoid_cost,
            s.greed,
            s.max_expansions,
        )
        reached = status == REACHED
        points[0] = start  # the route starts at the centre itself
        if reached:
            points[-1] = goal
        return Route(points, times, reached, int(expansions))


def attraction_point(
    route: Route, center: np.ndarray, t: float, settings: GuideSettings, progress: float
) -> tuple[np.ndarray, float]:
    """η(t) on `route` and the arc length of the tube's nearest route point.

    The tube's centre follows η at a lag of about (speed/k1)³ (Eq. (4)): η is the route's
    point at the time t + (lookahead/2)/speed — so where the route waits, η waits — kept
    between the route point nearest the centre and `lookahead` metres beyond it, and not
    past the route's next corner until the centre is within :attr:`GuideSettings.
    corner_radius` of it (the centre moves straight at η: a point beyond a corner would
    pull it across the corner, into what the route went around). The nearest point is
    searched from `progress` (the last one's arc length) minus one look-ahead, so the tube
    never turns back along its route. On a route's last straight leg to the goal, η is the
    goal itself unless the centre is ahead of the route's clock: the centre then runs at
    its own speed, as without a guide (a centre that follows a point at a lag is never
    saturated, and costs the integrator about twice the steps of one that is). At the
    route's end η is the route's last point (the goal itself when the route reached it)."""
    s = route.arc_length
    points = route.points
    ahead = max(progress - settings.lookahead, 0.0)
    first = int(np.searchsorted(s, ahead, side="right")) - 1
    nearest = _nearest_arc_length(points[first:], s[first:], np.asarray(center, dtype=float))
    timed = float(np.interp(t + 0.5 * settings.lookahead / settings.speed, route.times, s))
    target = min(max(timed, nearest), nearest + settings.lookahead, float(s[-1]))
    corner = int(np.searchsorted(s, nearest + 1e-9, side="right"))
    if route.reached and corner >= len(s) - 1 and timed >= nearest:
        return points[-1].copy(), nearest  # the last leg, not ahead of the clock: go
    turn = corner < len(s) - 1 and np.linalg.norm(points[corner] - center) > settings.corner_radius
    if turn:
        target = min(target, float(s[corner]))
    if target >= s[-1]:
        return points[-1].copy(), nearest
    k = int(np.searchsorted(s, target, side="right")) - 1
    fraction = (target - s[k]) / (s[k + 1] - s[k]) if s[k + 1] > s[k] else 0.0
    return points[k] + fraction * (points[k + 1] - points[k]), nearest


def _nearest_arc_length(points: np.ndarray, s: np.ndarray, center: np.ndarray) -> float:
    """Arc length of the point of the polyline `points` (arc lengths `s`) nearest `center`."""
    if len(points) == 1:
        return float(s[0])
    start, step = points[:-1], np.diff(points, axis=0)
    squared = np.einsum("ij,ij->i", step, step)
    fraction = np.clip(
        np.einsum("ij,ij->i", center - start, step) / np.where(squared > 0, squared, 1.0), 0, 1
    )
    closest = start + fraction[:, None] * step
    k = int(np.argmin(np.linalg.norm(closest - center, axis=1)))
    return float(s[k] + fraction[k] * math.sqrt(squared[k]))
