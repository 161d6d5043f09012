"""Crowd scenes: where N pedestrians start, how fast they want to walk and where they go.

Each scene is a function of (pedestrians N, seed S, speed range, area, radius) returning a
:class:`CrowdSetup`, everything JuPedSim needs to build its simulation
(:func:`stt_drake.crowd.engine.CrowdEngine`): the walkable area (a rectangle), the exit
polygons, each pedestrian's start, exit and desired speed, and the agents' radius. Drawn
with numpy only, so a set-up (and the obstacle slots a scenario makes of it) needs no
JuPedSim; the same (N, S, speed range, area, radius) always give the same set-up.

Scenes (w × h the area's size, its lower left corner (x0, y0)):

* ``crossing``: two flows at right angles. ⌈N/2⌉ start in the left quarter, in the middle
  half of the height, and walk to an exit strip on the right edge; the others start in the
  bottom quarter, in the middle half of the width, and walk to the top edge.
* ``circle``: the N pedestrians stand evenly spaced (a random turn of the whole ring) on
  the circle of radius min(w, h)/2 − 2·radius − START_GAP around the area's centre, and
  each walks to the antipode of its start (an exit square of side 2·radius there).
* ``corridor``: one flow, starting in the left third, to the right edge.
* ``bidirectional``: ⌈N/2⌉ from the left third to the right edge, the others from the
  right third to the left edge.

Starts are drawn uniformly in the start regions, kept only at least 2·radius +
:data:`START_GAP` from every other start and radius + :data:`START_GAP` from the walls
(JuPedSim refuses agents that overlap each other or a wall). Desired speeds are uniform in
the speed range (m/s). Bad arguments raise :class:`stt_drake.core.rules.RuleError` naming
the argument (``pedestrians``, ``speed_range``, ``area``, ``radius``, ``seed``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from stt_drake.core.rules import RuleError

#: The scenes, in help order.
SCENE_NAMES = ("crossing", "circle", "corridor", "bidirectional")
#: Default area per scene, [x_min, y_min, x_max, y_max] (m).
DEFAULT_AREAS: dict[str, tuple[float, float, float, float]] = {
    "crossing": (0.0, 0.0, 10.0, 10.0),
    "circle": (0.0, 0.0, 10.0, 10.0),
    "corridor": (0.0, 0.0, 20.0, 3.0),
    "bidirectional": (0.0, 0.0, 20.0, 4.0),
}
#: Default desired-speed range (m/s): free walking speeds of adults.
DEFAULT_SPEED_RANGE = (1.0, 1.4)
#: Default pedestrian radius (m; JuPedSim's default agent radius).
DEFAULT_RADIUS = 0.2
#: Clearance added between drawn starts, and between a start and a wall (m).
START_GAP = 0.05
#: Draws in a row that do not fit before a start region is refused as full.
MAX_REJECTIONS = 2000
#: Most pedestrians one scene holds.
MAX_PEDESTRIANS = 5000
#: Fastest desired speed accepted (m/s).
MAX_SPEED = 5.0
#: Largest pedestrian radius accepted (m).
MAX_RADIUS = 1.0
#: Largest seed (numpy's generators take seeds in [0, 2^63 − 1] here, as a scenario's).
MAX_SEED = 2**63 - 1


@dataclass(frozen=True)
class CrowdSetup:
    """What JuPedSim needs to simulate one crowd (module docstring).

    Attributes:
        scene: the scene's name.
        area: (x_min, y_min, x_max, y_max) of the walkable rectangle, m.
        starts: (N, 2) start positions, m.
        desired_speeds: (N,) desired walking speeds, m/s.
        exits: exit polygons, each a (k, 2) array of vertices (m); a pedestrian that
            reaches its exit leaves the scene.
        exit_of: (N,) index into `exits` of each pedestrian's exit.
        radius: the agents' radius, m.
    """

    scene: str
    area: tuple[float, float, float, float]
    starts: np.ndarray
    desired_speeds: np.ndarray
    exits: tuple[np.ndarray, ...]
    exit_of: np.ndarray
    radius: float

    @property
    def count(self) -> int:
        """Number of pedestrians N."""
        return len(self.starts)

    def goals(self) -> np.ndarray:
        """(N, 2) the centre of each pedestrian's exit, m (the end of its free path)."""
        centres = np.array([polygon.mean(axis=0) for polygon in self.exits])
        return centres[self.exit_of]

    def free_walk_times(self) -> np.ndarray:
        """(N,) seconds each pedestrian needs to walk straight to its goal alone at its
        desired speed."""
        distance = np.linalg.norm(self.goals() - self.starts, axis=1)
        return distance / self.desired_speeds


def _box(x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)


def check_scene_arguments(
    pedestrians: int,
    seed: int,
    speed_range: Sequence[float],
    area: Sequence[float],
    radius: float,
) -> None:
    """The rules every scene's arguments meet; RuleError naming the argument."""
    if isinstance(pedestrians, bool) or not isinstance(pedestrians, int | np.integer):
        raise RuleError("pedestrians", "must be an integer", pedestrians)
    if not 1 <= pedestrians <= MAX_PEDESTRIANS:
        raise RuleError("pedestrians", f"must lie in [1, {MAX_PEDESTRIANS}]", pedestrians)
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise RuleError("seed", "must be an integer ≥ 0", seed)
    if seed > MAX_SEED:
        raise RuleError("seed", "must be at most 2^63 − 1", seed)
    speeds = list(speed_range)
    if len(speeds) != 2 or not all(math.isfinite(v) for v in speeds):
        raise RuleError("speed_range", "must be [low, high], finite (m/s)", speeds)
    if not 0.0 < speeds[0] <= speeds[1] <= MAX_SPEED:
        raise RuleError("speed_range", f"must satisfy 0 < low ≤ high ≤ {MAX_SPEED} m/s", speeds)
    if not (math.isfinite(radius) and 0.0 < radius <= MAX_RADIUS):
        raise RuleError("radius", f"must lie in (0, {MAX_RADIUS}] m", radius)
    box = list(area)
    if len(box) != 4 or not all(math.isfinite(v) for v in box):
        raise RuleError("area", "must be [x_min, y_min, x_max, y_max], finite (m)", box)
    smallest = 8.0 * radius
    if not (box[2] - box[0] >= smallest and box[3] - box[1] >= smallest):
        raise RuleError(
            "area",
            f"must be at least 8·radius = {smallest:g} m wide and high (x_max − x_min, "
            "y_max − y_min)",
            box,
        )


def _place(
    rng: np.random.Generator,
    regions: Sequence[np.ndarray],
    counts: Sequence[int],
    radius: float,
) -> np.ndarray:
    """Draw counts[k] starts uniformly in the rectangle regions[k] ((2, 2): low, high
    corners, already shrunk by the wall clearance), each at least 2·radius + START_GAP from
    every other one; a region refuses after :data:`MAX_REJECTIONS` draws in a row that do
    not fit (it is full)."""
    spacing = 2.0 * radius + START_GAP
    placed = np.empty((sum(counts), 2))
    done = 0
    for region, count in zip(regions, counts, strict=True):
        if np.any(region[1] < region[0]):
            raise RuleError(
                "area",
                f"leaves no start region for pedestrians of radius {radius:g} m (enlarge it)",
                "too small",
            )
        target, misses = done + count, 0
        while done < target:
            candidate = rng.uniform(region[0], region[1])
            gaps = np.linalg.norm(placed[:done] - candidate, axis=1)
            if done and gaps.min() < spacing:
                misses += 1
                if misses < MAX_REJECTIONS:
                    continue
                size = region[1] - region[0]
                raise RuleError(
                    "pedestrians",
                    f"do not fit: {count} pedestrians of radius {radius:g} m, "
                    f"{spacing:g} m apart, in a start region of {size[0]:.3g} × {size[1]:.3g} m "
                    "(lower the count or the radius, or enlarge the area)",
                    sum(counts),
                )
            placed[done], done, misses = candidate, done + 1, 0
    return placed


def _shrunk(x0: float, y0: float, x1: float, y1: float, margin: float) -> np.ndarray:
    return np.array([[x0 + margin, y0 + margin], [x1 - margin, y1 - margin]])


def _speeds(rng: np.random.Generator, count: int, speed_range: Sequence[float]) -> np.ndarray:
    return rng.uniform(speed_range[0], speed_range[1], size=count)


def _exit_depth(area: Sequence[float]) -> float:
    """Depth of an exit strip along an edge (m)."""
    return min(0.5, 0.1 * min(area[2] - area[0], area[3] - area[1]))


def _frame(
    pedestrians: int,
    seed: int,
    speed_range: Sequence[float],
    area: Sequence[float],
    radius: float,
) -> tuple[tuple[float, float, float, float], float, float, np.random.Generator]:
    """What every scene starts from, after :func:`check_scene_arguments`: the area
    (x0, y0, x1, y1) as floats (m), the exit strips' depth (m), the start regions' margin
    (radius + :data:`START_GAP`, m) and the scene's random generator (from `seed`)."""
    check_scene_arguments(pedestrians, seed, speed_range, area, radius)
    x0, y0, x1, y1 = (float(v) for v in area)
    return (x0, y0, x1, y1), _exit_depth(area), radius + START_GAP, np.random.default_rng(seed)


def _halves(pedestrians: int) -> tuple[int, int]:
    """The two flows' counts: the first has the odd pedestrian."""
    first = math.ceil(pedestrians / 2)
    return first, pedestrians - first


def crossing(
    pedestrians: int,
    seed: int,
    speed_range: Sequence[float] = DEFAULT_SPEED_RANGE,
    area: Sequence[float] = DEFAULT_AREAS["crossing"],
    radius: float = DEFAULT_RADIUS,
) -> CrowdSetup:
    """Two flows at right angles (module docstring)."""
    (x0, y0, x1, y1), depth, margin, rng = _frame(pedestrians, seed, speed_range, area, radius)
    w, h = x1 - x0, y1 - y0
    counts = _halves(pedestrians)
    regions = (
        _shrunk(x0, y0 + h / 4, x0 + w / 4, y1 - h / 4, margin),
        _shrunk(x0 + w / 4, y0, x1 - w / 4, y0 + h / 4, margin),
    )
    starts = _place(rng, regions, counts, radius)
    exits = (
        _box(x1 - depth, y0 + h / 4, x1, y1 - h / 4),
        _box(x0 + w / 4, y1 - depth, x1 - w / 4, y1),
    )
    exit_of = np.repeat([0, 1], counts)
    return CrowdSetup(
        "crossing", (x0, y0, x1, y1), starts, _speeds(rng, pedestrians, speed_range),
        exits, exit_of, float(radius),
    )  # fmt: skip


def circle(
    pedestrians: int,
    seed: int,
    speed_range: Sequence[float] = DEFAULT_SPEED_RANGE,
    area: Sequence[float] = DEFAULT_AREAS["circle"],
    radius: float = DEFAULT_RADIUS,
) -> CrowdSetup:
    """Pedestrians evenly spaced on a circle, each walking to its antipode (module
    docstring)."""
    (x0, y0, x1, y1), _, _, rng = _frame(pedestrians, seed, speed_range, area, radius)
    centre = np.array([(x0 + x1) / 2.0, (y0 + y1) / 2.0])
    ring = 0.5 * min(x1 - x0, y1 - y0) - 2.0 * radius - START_GAP
    spacing = 2.0 * radius + START_GAP
    if pedestrians > 1 and 2.0 * ring * math.sin(math.pi / pedestrians) < spacing:
        fit = max(1, math.floor(math.pi / math.asin(min(1.0, spacing / (2.0 * ring)))))
        raise RuleError(
            "pedestrians",
            f"do not fit on the circle of radius {ring:.3g} m {spacing:g} m apart (at most "
            f"{fit}; lower the count or the radius, or enlarge the area)",
            pedestrians,
        )
    angles = rng.uniform(0.0, 2.0 * np.pi) + 2.0 * np.pi * np.arange(pedestrians) / pedestrians
    unit = np.column_stack([np.cos(angles), np.sin(angles)])
    starts = centre + ring * unit
    exits = tuple(_box(*(p - radius), *(p + radius)) for p in centre - ring * unit)
    return CrowdSetup(
        "circle", (x0, y0, x1, y1), starts, _speeds(rng, pedestrians, speed_range),
        exits, np.arange(pedestrians), float(radius),
    )  # fmt: skip


def corridor(
    pedestrians: int,
    seed: int,
    speed_range: Sequence[float] = DEFAULT_SPEED_RANGE,
    area: Sequence[float] = DEFAULT_AREAS["corridor"],
    radius: float = DEFAULT_RADIUS,
) -> CrowdSetup:
    """One flow along the corridor, left to right (module docstring)."""
    (x0, y0, x1, y1), depth, margin, rng = _frame(pedestrians, seed, speed_range, area, radius)
    w = x1 - x0
    starts = _place(rng, (_shrunk(x0, y0, x0 + w / 3, y1, margin),), (pedestrians,), radius)
    return CrowdSetup(
        "corridor", (x0, y0, x1, y1), starts, _speeds(rng, pedestrians, speed_range),
        (_box(x1 - depth, y0, x1, y1),), np.zeros(pedestrians, dtype=int), float(radius),
    )  # fmt: skip


def bidirectional(
    pedestrians: int,
    seed: int,
    speed_range: Sequence[float] = DEFAULT_SPEED_RANGE,
    area: Sequence[float] = DEFAULT_AREAS["bidirectional"],
    radius: float = DEFAULT_RADIUS,
) -> CrowdSetup:
    """Two opposite flows in a corridor (module docstring)."""
    (x0, y0, x1, y1), depth, margin, rng = _frame(pedestrians, seed, speed_range, area, radius)
    w = x1 - x0
    counts = _halves(pedestrians)
    regions = (
        _shrunk(x0, y0, x0 + w / 3, y1, margin),
        _shrunk(x1 - w / 3, y0, x1, y1, margin),
    )
    starts = _place(rng, regions, counts, radius)
    exits = (_box(x1 - depth, y0, x1, y1), _box(x0, y0, x0 + depth, y1))
    return CrowdSetup(
        "bidirectional", (x0, y0, x1, y1), starts, _speeds(rng, pedestrians, speed_range),
        exits, np.repeat([0, 1], counts), float(radius),
    )  # fmt: skip


#: The scene functions by name.
SCENES: dict[str, Callable[..., CrowdSetup]] = {
    "crossing": crossing,
    "circle": circle,
    "corridor": corridor,
    "bidirectional": bidirectional,
}


def make_scene(
    scene: str,
    pedestrians: int,
    seed: int,
    speed_range: Sequence[float] | None = None,
    area: Sequence[float] | None = None,
    radius: float | None = None,
) -> CrowdSetup:
    """The set-up of the scene named `scene` (None or empty: that argument's default)."""
    if scene not in SCENES:
        raise RuleError("scene", f"must be one of {', '.join(SCENE_NAMES)}", scene)
    return SCENES[scene](
        pedestrians,
        seed,
        speed_range=tuple(speed_range) if speed_range else DEFAULT_SPEED_RANGE,
        area=tuple(area) if area else DEFAULT_AREAS[scene],
        radius=DEFAULT_RADIUS if radius is None else radius,
    )
