"""Live Meshcat drawing of the tube and the obstacle belief: :class:`TubeVisualizer`.

The system reads the tube Γ(t) = B(c, r) (port ``tube``, [c, r]) and the obstacle belief
(port ``obstacle_belief``, layout of :mod:`stt_drake.core.belief`) and, at initialisation
and every `publish_period`, poses geometry it created once in its constructor:

* ``{prefix}/tube`` (posed) and ``{prefix}/tube/ball`` (scaled) — the tube ball (3D) or
  disc (2D, in the plane z = 0);
* ``{prefix}/obstacles/{j}`` (posed at the mean; hidden while slot j is inactive) with
  ``.../body`` — obstacle j's r_o ball;
* ``{prefix}/obstacles/{j}/epsilon_set`` and ``.../p_d_set`` — the level sets
  {q̂_j ≤ ε_j} and {q̂_j ≤ p_d_j} (balls around the mean for an isotropic belief), drawn
  translucent, at least r_o (an unbounded set is drawn at r_o); with full covariances
  (``full_covariance=True``) ellipsoids (ellipses in 2D): the
  obstacle node is also turned to Σ_j's principal axes, and each semi-axis is the level
  set's exact extent along that axis (:func:`stt_drake.core.anisotropic.level_set_radii`);
* ``{prefix}/robot`` — with a ``output`` port (`robot_radius` given): the robot at y.

Shapes are unit spheres / discs scaled with the ``scale`` property, so a publish only
sends transforms and (changed) scales, never geometry. Every call passes the context time
as ``time_in_recording``: while the Meshcat records (``Meshcat.StartRecording``), the
frames go into its animation, whose time slider is the replay's time display. Live, the
simulation time is shown by Meshcat's own realtime-rate panel (``SetSimulationTime``) and a
read-only ``sim time (s)`` slider (pydrake 1.51.1 has no text overlay).
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache

import numpy as np
from pydrake.geometry import Cylinder, Meshcat, Rgba, Sphere
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import (
    Context,
    DiagramBuilder,
    EventStatus,
    LeafSystem,
    OutputPort,
)

from stt_drake.core.anisotropic import eigen_decomposition, level_set_radii
from stt_drake.core.belief import ObstacleBelief, ObstacleTask, belief_size
from stt_drake.core.probability import level_set_radius

#: Default publish period of the live view (s): 30 frames per second.
PUBLISH_PERIOD = 1.0 / 30.0
#: Thickness of the 2D discs (m).
DISC_THICKNESS = 0.02
#: Name of the live view's time slider.
TIME_SLIDER = "sim time (s)"

TUBE_COLOR = Rgba(0.12, 0.47, 0.71, 0.3)
OBSTACLE_COLOR = Rgba(0.84, 0.1, 0.11, 0.9)
EPSILON_COLOR = Rgba(0.84, 0.1, 0.11, 0.18)
P_D_COLOR = Rgba(1.0, 0.5, 0.05, 0.12)
ROBOT_COLOR = Rgba(0.15, 0.15, 0.15, 1.0)
START_COLOR = Rgba(0.17, 0.63, 0.17, 0.2)
TARGET_COLOR = Rgba(0.8, 0.65, 0.0, 0.2)


#: Level-set radii by (level, σ, r_o, n): the belief's σ, r_o, ε, p_d rarely change
#: between publishes, and each is a root find.
_level_set_radius = lru_cache(maxsize=4096)(level_set_radius)


class TubeVisualizer(LeafSystem):
    """Draws the tube and the obstacle belief into a :class:`Meshcat` (module docstring).

    Args:
        meshcat: where to draw.
        dimension: n (2 or 3).
        task: r_o, ε, p_d of each obstacle slot on the belief port (inactive slots are
            hidden).
        publish_period: seconds between publishes.
        prefix: Meshcat path everything is drawn under.
        robot_radius: when given, an input port ``output`` (y) and the robot drawn there.
        full_covariance: draw each Σ_j's exact level sets as ellipsoids (else balls of
            σ_j² = λ_max(Σ_j)).
    """

    def __init__(
        self,
        meshcat: Meshcat,
        dimension: int,
        task: ObstacleTask,
        publish_period: float = PUBLISH_PERIOD,
        prefix: str = "/stt",
        robot_radius: float | None = None,
        full_covariance: bool = False,
    ) -> None:
        super().__init__()
        if dimension not in (2, 3):
            raise ValueError(f"TubeVisualizer draws 2D or 3D scenes (got dimension {dimension})")
        self._meshcat = meshcat
        self._n = dimension
        self._task = task
        self._full_covariance = full_covariance
        count = self._count = task.count
        self._prefix = prefix
        self._tube = self.DeclareVectorInputPort("tube", dimension + 1)
        self._belief = self.DeclareVectorInputPort("obstacle_belief", belief_size(count, dimension))
        self._output = None
        if robot_radius is not None:
            self._output = self.DeclareVectorInputPort("output", dimension)
        # Principal axes and semi-axes by (Σ bytes, r_o, ε, p_d): Σ rarely changes.
        self._ellipsoids: dict[tuple, tuple[np.ndarray, list[list[float]]]] = {}
        self.DeclareInitializationPublishEvent(self._initialize)
        self.DeclarePeriodicPublishEvent(publish_period, 0.0, self._publish)
        # Last scale and visibility sent per path: a recording keeps them until they change.
        self._scales: dict[str, float] = {}
        self._visible: dict[str, bool] = {}

        self._shape(f"{prefix}/tube/ball", TUBE_COLOR, layer=3)
        for j in range(count):
            base = f"{prefix}/obstacles/{j}"
            self._shape(f"{base}/body", OBSTACLE_COLOR, layer=2)
            self._shape(f"{base}/epsilon_set", EPSILON_COLOR, layer=1)
            self._shape(f"{base}/p_d_set", P_D_COLOR, layer=0)
        if robot_radius is not None:
            self._shape(f"{prefix}/robot/body", ROBOT_COLOR, layer=4)
            meshcat.SetProperty(f"{prefix}/robot/body", "scale", self._scale(robot_radius))
        meshcat.AddSlider(TIME_SLIDER, 0.0, 1e9, 1e-3, 0.0)

    def _shape(self, path: str, color: Rgba, layer: int) -> None:
        """A unit ball (3D), or a unit disc a little above z = 0 by `layer` (2D), at
        `path`/shape. `path` itself only gets a ``scale``: Meshcat's set_transform resets
        a node's scale, so poses go to its parent."""
        if self._n == 3:
            self._meshcat.SetObject(f"{path}/shape", Sphere(1.0), color)
        else:
            self._meshcat.SetObject(f"{path}/shape", Cylinder(1.0, DISC_THICKNESS), color)
            lift = RigidTransform([0.0, 0.0, 0.5 * DISC_THICKNESS * (layer + 1)])
            self._meshcat.SetTransform(f"{path}/shape", lift)

    def _scale(self, radius: float | Sequence[float]) -> list[float]:
        """Meshcat scale of a unit shape: a radius, or n semi-axes (in 2D the disc keeps
        its thickness)."""
        radii = np.broadcast_to(np.maximum(np.asarray(radius, dtype=float), 1e-6), (self._n,))
        return [*map(float, radii), *([] if self._n == 3 else [1.0])]

    def _lift(self, point: np.ndarray) -> np.ndarray:
        return np.append(point, 0.0) if self._n == 2 else np.asarray(point, dtype=float)

    def _set_scale(self, path: str, radius: float | Sequence[float], t: float) -> None:
        scale = self._scale(radius)
        if self._scales.get(path) != scale:
            self._scales[path] = scale
            self._meshcat.SetProperty(path, "scale", scale, t)

    def _ellipsoid(
        self, covariance: np.ndarray, r_o: float, levels: Sequence[float]
    ) -> tuple[np.ndarray, list[list[float]]]:
        """(R, [semi-axes per level]): R (3×3, det +1) turns the node to Σ's principal
        axes; the semi-axes are the level sets' extents along them, at least r_o."""
        key = (covariance.tobytes(), r_o, *levels)
        if key not in self._ellipsoids:
            _variances, axes = eigen_decomposition(covariance)
            if np.linalg.det(axes) < 0.0:
                axes[:, -1] *= -1.0
            rotation = np.eye(3)
            rotation[: self._n, : self._n] = axes
            semi_axes = []
            for level in levels:
                extents = level_set_radii(axes.T, covariance, r_o, float(level))
                semi_axes.append([max(float(e), r_o) for e in extents])
            self._ellipsoids[key] = (rotation, semi_axes)
        return self._ellipsoids[key]

    def _set_visible(self, path: str, visible: bool, t: float) -> None:
        if self._visible.get(path, True) != visible:
            self._visible[path] = visible
            self._meshcat.SetProperty(path, "visible", visible, t)

    def _initialize(self, context: Context, event: object = None) -> EventStatus:
        self._scales.clear()
        self._visible.clear()
        return self._publish(context)

    def _publish(self, context: Context, event: object = None) -> EventStatus:
        t = context.get_time()
        meshcat, prefix = self._meshcat, self._prefix
        tube = self._tube.Eval(context)
        meshcat.SetTransform(f"{prefix}/tube", RigidTransform(self._lift(tube[:-1])), t)
        self._set_scale(f"{prefix}/tube/ball", float(tube[-1]), t)
        belief = ObstacleBelief.from_port(
            self._belief.Eval(context), self._n, self._task, self._full_covariance
        )
        k = 0  # obstacle k of the belief is the k-th active slot
        for j, active in enumerate(belief.slots.active.tolist()):
            self._set_visible(f"{prefix}/obstacles/{j}", active, t)
            if active:
                self._draw_obstacle(f"{prefix}/obstacles/{j}", belief, k, t)
                k += 1
        if self._output is not None:
            y = self._output.Eval(context)
            meshcat.SetTransform(f"{prefix}/robot", RigidTransform(self._lift(y)), t)
        meshcat.SetSimulationTime(t)
        meshcat.SetSliderValue(TIME_SLIDER, t)
        return EventStatus.Succeeded()

    def _draw_obstacle(self, base: str, belief: ObstacleBelief, k: int, t: float) -> None:
        """Pose and scale obstacle k of `belief` at the node `base`: its r_o ball and its
        ε and p_d level sets (ellipsoids with full covariances)."""
        meshcat = self._meshcat
        r_o = float(belief.radius[k])
        names = ("epsilon_set", "p_d_set")
        levels = (float(belief.epsilon[k]), float(belief.p_d[k]))
        if belief.covariance is not None:
            rotation, semi_axes = self._ellipsoid(belief.covariance[k], r_o, levels)
            pose = RigidTransform(RotationMatrix(rotation), self._lift(belief.mean[k]))
            meshcat.SetTransform(base, pose, t)
            self._set_scale(f"{base}/body", r_o, t)
            for name, axes in zip(names, semi_axes, strict=True):
                self._set_scale(f"{base}/{name}", axes, t)
        else:
            meshcat.SetTransform(base, RigidTransform(self._lift(belief.mean[k])), t)
            self._set_scale(f"{base}/body", r_o, t)
            sigma = float(belief.sigma[k])
            for name, level in zip(names, levels, strict=True):
                d = _level_set_radius(level, sigma, r_o, self._n) if sigma > 0 else r_o
                self._set_scale(f"{base}/{name}", max(d, r_o) if np.isfinite(d) else r_o, t)


def AddTubeVisualizer(  # noqa: N802 (Drake's naming of builder functions)
    builder: DiagramBuilder,
    meshcat: Meshcat,
    tube: OutputPort,
    belief: OutputPort,
    dimension: int,
    task: ObstacleTask,
    output: OutputPort | None = None,
    robot_radius: float | None = None,
    publish_period: float = PUBLISH_PERIOD,
    prefix: str = "/stt",
    full_covariance: bool = False,
) -> TubeVisualizer:
    """Add a :class:`TubeVisualizer` named "tube_visualizer" to `builder` and connect it:
    the tube and every obstacle's ε and p_d level sets drawn live in Meshcat (and recorded
    while ``meshcat.StartRecording()`` runs).

    With the handles of :func:`stt_drake.assembly.stt.AddStt`::

        meshcat = StartMeshcat()
        AddTubeVisualizer(builder, meshcat, stt.tube, stt.belief, 2, stt.task)

    Args:
        builder: the DiagramBuilder.
        meshcat: the Meshcat to draw in.
        tube: the tube's [c, r] output port (``stt.tube``).
        belief: the `obstacle_belief` port the tube reads (``stt.belief``).
        dimension: n, 2 (drawn in the plane z = 0) or 3.
        task: the obstacles' r_o, ε, p_d per slot (``stt.task``).
        output: the plant's output y, drawn as the robot when `robot_radius` is given.
        robot_radius: the robot's radius (m); None draws no robot.
        publish_period: seconds between frames (default 1/30).
        prefix: the Meshcat path everything is drawn under.
        full_covariance: draw each Σ_j's level sets as ellipsoids (``stt.full_covariance``).

    Returns:
        the added :class:`TubeVisualizer`.
    """
    visualizer = builder.AddNamedSystem(
        "tube_visualizer",
        TubeVisualizer(
            meshcat,
            dimension,
            task,
            publish_period,
            prefix,
            robot_radius,
            full_covariance,
        ),
    )
    builder.Connect(tube, visualizer.GetInputPort("tube"))
    builder.Connect(belief, visualizer.GetInputPort("obstacle_belief"))
    if robot_radius is not None:
        if output is None:
            raise ValueError("AddTubeVisualizer: robot_radius needs the output port y")
        builder.Connect(output, visualizer.GetInputPort("output"))
    return visualizer


def draw_task_sets(
    meshcat: Meshcat,
    start: np.ndarray,
    start_radius: float,
    targets: Sequence[np.ndarray],
    target_radius: float,
    prefix: str = "/stt",
) -> None:
    """Static translucent balls (3D) or discs (2D) for the initial set and every target
    set, and a camera aimed at them from above and to the side."""
    start = np.asarray(start, dtype=float)
    n = start.size
    points = []
    for path, center, radius, color in [
        (f"{prefix}/start", start, start_radius, START_COLOR),
        *[
            (f"{prefix}/target/{i}", np.asarray(c, dtype=float), target_radius, TARGET_COLOR)
            for i, c in enumerate(targets)
        ],
    ]:
        center = np.append(center, 0.0) if n == 2 else center
        shape = Sphere(radius) if n == 3 else Cylinder(radius, DISC_THICKNESS)
        meshcat.SetObject(path, shape, color)
        meshcat.SetTransform(path, RigidTransform(center))
        points.append(center)
    points = np.array(points)
    low, high = points.min(axis=0), points.max(axis=0)
    middle, span = 0.5 * (low + high), float(np.max(high - low)) + 1.0
    meshcat.SetCameraPose(middle + np.array([0.0, -0.9 * span, 1.1 * span]), middle)
