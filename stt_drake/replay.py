"""A self-contained HTML replay of a run (Meshcat), written from its log.

:func:`write_meshcat_replay` starts a Meshcat server bound to 127.0.0.1 (no network beyond
the loopback unless another host is asked for), draws the scene — obstacles as spheres of
radius r_o coloured by σ with a translucent sphere for their {q̂_j ≤ ε_j} set, the tube
Γ(t) = B(c, r) as a translucent sphere, the robot, the start and target sets and the
output path — animates it from the logged samples with a
:class:`pydrake.geometry.MeshcatAnimation`, and saves ``Meshcat.StaticHtml()``: one HTML
file that plays the run in a browser, offline.

A 2D run is drawn in the plane z = 0 (spheres cut by it). The UAV (n = 3) is drawn as a
quadrotor whose body axis follows the commanded force u (the thrust direction an attitude
loop would track); the omni robot as a disc. A run of the FR3 arm (its log holds
`joint_state`) is drawn as the arm itself, posed from the logged joint positions.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.colors import to_rgba
from pydrake.geometry import (
    Box,
    Cylinder,
    Meshcat,
    MeshcatAnimation,
    MeshcatParams,
    Rgba,
    Sphere,
)
from pydrake.math import RigidTransform, RotationMatrix

from stt_drake.plotting import PALETTE, level_set_radius, obstacle_colors
from stt_drake.runlog import RunLog

#: Default cap on the number of animation frames (samples are strided to fit).
MAX_FRAMES = 600
#: Robot radius drawn when the caller gives none (m).
DEFAULT_BODY_RADIUS = 0.2
_ROOT = "/stt"
#: Where the replay's Meshcat server listens unless told otherwise: the loopback only.
LOCALHOST = "127.0.0.1"


def start_meshcat(host: str = LOCALHOST) -> Meshcat:
    """A Meshcat server on `host` (default the loopback interface, never the network unless
    asked: pydrake's own default is every interface) at an ephemeral port, so parallel
    replays never collide."""
    return Meshcat(MeshcatParams(host=host, port=0))


def body_radius(plant: object) -> float | None:
    """The robot radius to draw for a scenario's plant config: the UAV's `body_radius`,
    the omni base's `base_radius` (None when the plant has neither)."""
    for name in ("body_radius", "base_radius"):
        if hasattr(plant, name):
            return float(getattr(plant, name))
    return None


def _rgba(color: Any, alpha: float) -> Rgba:
    r, g, b, _ = to_rgba(color)
    return Rgba(r, g, b, alpha)


def _lift(points: np.ndarray) -> np.ndarray:
    """(..., n) points as (..., 3): a 2D run lives in the plane z = 0."""
    points = np.asarray(points, dtype=float)
    if points.shape[-1] == 3:
        return points
    pad = np.zeros((*points.shape[:-1], 3 - points.shape[-1]))
    return np.concatenate([points, pad], axis=-1)


def _tilt(force: np.ndarray) -> RotationMatrix:
    """The smallest rotation taking e_z to the direction of `force` (identity for u = 0)."""
    norm = float(np.linalg.norm(force))
    if norm < 1e-9:
        return RotationMatrix()
    direction = force / norm
    axis = np.cross([0.0, 0.0, 1.0], direction)
    sine, cosine = float(np.linalg.norm(axis)), float(direction[2])
    if sine < 1e-12:
        return RotationMatrix() if cosine > 0 else RotationMatrix.MakeXRotation(np.pi)
    k = axis / sine
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return RotationMatrix(np.eye(3) + sine * cross + (1.0 - cosine) * cross @ cross)


def _draw_robot(meshcat: Meshcat, dimension: int, body_radius: float) -> None:
    color = _rgba(PALETTE["trajectory"], 1.0)
    if dimension == 3:  # a quadrotor: a flat body and four rotor discs at the arm tips
        meshcat.SetObject(
            f"{_ROOT}/robot/body",
            Box(0.8 * body_radius, 0.8 * body_radius, 0.15 * body_radius),
            color,
        )
        rotor = Cylinder(0.35 * body_radius, 0.04 * body_radius)
        for i, angle in enumerate(np.pi / 4.0 + np.arange(4) * np.pi / 2.0):
            path = f"{_ROOT}/robot/rotor{i}"
            meshcat.SetObject(path, rotor, _rgba(PALETTE["tube"], 0.8))
            offset = body_radius * np.array([0.75 * np.cos(angle), 0.75 * np.sin(angle), 0.08])
            meshcat.SetTransform(path, RigidTransform(offset))
    else:
        meshcat.SetObject(f"{_ROOT}/robot/body", Cylinder(body_radius, 0.1), color)


def _frame_camera(meshcat: Meshcat, run: RunLog) -> None:
    """Aim the camera at the middle of start, target and path, from above and to the side,
    far enough to see all of them."""
    points = np.vstack([_lift(run.output), _lift(run.start[None, :]), _lift(run.target[None, :])])
    low, high = points.min(axis=0), points.max(axis=0)
    middle, span = 0.5 * (low + high), float(np.max(high - low)) + 1.0
    meshcat.SetCameraPose(middle + np.array([0.0, -0.9 * span, 1.1 * span]), middle)


def write_meshcat_replay(
    log: Mapping[str, Any],
    path: str | Path,
    body_radius: float | None = None,
    max_frames: int = MAX_FRAMES,
    host: str = LOCALHOST,
) -> Path:
    """Write an offline HTML replay of a run (2D or 3D) to `path`.

    Args:
        log: a run log (the `log.npz` layout, see :mod:`stt_drake.runlog`); its `control`
            (T, n), when logged, tilts the UAV body along the commanded force.
        path: the HTML file to write (its folder is created).
        body_radius: robot radius in metres (the UAV's rotor-tip radius, the omni base
            radius); default :data:`DEFAULT_BODY_RADIUS`.
        max_frames: the animation keeps at most this many logged samples (evenly strided),
            played back at the logged time scale.
        host: the interface the (short-lived) Meshcat server listens on while the scene
            is drawn; default :data:`LOCALHOST` (``"*"``: every interface).

    Returns:
        The path written.
    """
    run = RunLog.of(log)
    n = run.dimension
    if n not in (2, 3):
        raise ValueError(f"write_meshcat_replay draws 2D or 3D runs; this run has dimension {n}")
    body_radius = DEFAULT_BODY_RADIUS if body_radius is None else float(body_radius)
    control = run.control
    stride = max(1, int(np.ceil(run.t.size / max(max_frames, 1))))
    picks = np.arange(0, run.t.size, stride)
    if picks[-1] != run.t.size - 1:
        picks = np.append(picks, run.t.size - 1)
    duration = float(run.t[-1] - run.t[0])
    frames_per_second = (picks.size - 1) / duration if duration > 0.0 else 1.0

    meshcat = start_meshcat(host)
    try:
        meshcat.Delete()
        norm, cmap = obstacle_colors(run)
        for key, center, radius in (
            ("start", run.start, run.initial_set_radius),
            ("target", run.target, run.target_set_radius),
        ):
            meshcat.SetObject(f"{_ROOT}/{key}", Sphere(radius), _rgba(PALETTE[key], 0.15))
            meshcat.SetTransform(f"{_ROOT}/{key}", RigidTransform(_lift(center)))
        meshcat.SetLine(
            f"{_ROOT}/output_path",
            _lift(run.output).T.copy(),
            2.0,
            _rgba(PALETTE["trajectory"], 1.0),
        )
        meshcat.SetObject(f"{_ROOT}/tube", Sphere(1.0), _rgba(PALETTE["tube"], 0.25))
        arm = None
        if "joint_state" in run:  # the FR3 arm: its links, posed from the logged joints
            from stt_drake.systems.plants.franka import FR3_JOINTS, Fr3Drawing

            arm = Fr3Drawing(meshcat, f"{_ROOT}/arm")
            joints = run.rows("joint_state")[:, :FR3_JOINTS]
        else:
            _draw_robot(meshcat, n, body_radius)
        level_cache: dict[tuple[float, float, float], float] = {}

        def epsilon_radius(k: int, j: int) -> float:
            key = (
                float(run.epsilon[k, j]),
                float(run.sigma[k, j]),
                float(run.obstacle_radius[k, j]),
            )
            if key not in level_cache:
                level_cache[key] = level_set_radius(*key, n)
            return level_cache[key]

        # Sphere sizes per obstacle and frame: r_o, and the {q̂ ≤ ε} radius (≥ r_o; an
        # unbounded set — q̂ < ε everywhere — is drawn at r_o).
        sizes: dict[str, np.ndarray] = {}
        for j in range(run.count):
            base = f"{_ROOT}/obstacles/{j}"
            color = cmap(norm(float(np.mean(run.sigma[:, j]))))
            meshcat.SetObject(f"{base}/body", Sphere(1.0), _rgba(color, 0.9))
            meshcat.SetObject(f"{base}/epsilon_set", Sphere(1.0), _rgba(color, 0.18))
            r_o = run.obstacle_radius[picks, j]
            level = np.array([epsilon_radius(k, j) for k in picks])
            sizes[f"{base}/body"] = r_o
            sizes[f"{base}/epsilon_set"] = np.where(np.isfinite(level), np.maximum(level, r_o), r_o)
        animated = {}
        for name, size in sizes.items():
            if np.ptp(size) == 0.0:  # constant: a static scale keeps the file small
                meshcat.SetProperty(name, "scale", [float(size[0])] * 3)
            else:
                animated[name] = size

        animation = MeshcatAnimation(frames_per_second=frames_per_second)
        centers, means = _lift(run.center), _lift(run.mean)
        outputs = _lift(run.output)
        for frame, k in enumerate(picks):
            radius = max(float(run.radius[k]), 1e-6)
            animation.SetTransform(frame, f"{_ROOT}/tube", RigidTransform(centers[k]))
            animation.SetProperty(frame, f"{_ROOT}/tube", "scale", [radius] * 3)
            if arm is not None:
                for name, pose in arm.body_poses(joints[k]).items():
                    animation.SetTransform(frame, name, pose)
            else:
                tilt = _tilt(control[k]) if control is not None and n == 3 else RotationMatrix()
                animation.SetTransform(frame, f"{_ROOT}/robot", RigidTransform(tilt, outputs[k]))
            for j in range(run.count):
                animation.SetTransform(frame, f"{_ROOT}/obstacles/{j}", RigidTransform(means[k, j]))
            for name, size in animated.items():
                animation.SetProperty(frame, name, "scale", [float(size[frame])] * 3)
        meshcat.SetAnimation(animation)
        _frame_camera(meshcat, run)
        html = meshcat.StaticHtml()
    finally:
        del meshcat
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(html)
    return path
