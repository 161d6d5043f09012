"""The STT controller of a torque-controlled arm (case study 3), and its post-run checks.

Pure numpy: the Drake systems in :mod:`stt_drake.systems.plants.franka` feed it measured signals and
the kinematic Jacobian. The output space is the end-effector (TCP) position y ∈ R³.

The arm q̈ = M(q)⁻¹(τ − C(q, q̇)q̇ − g(q) − D q̇ + τ_ext) is not in the pure-feedback form
of Eq. (1) in the task-space coordinates, so the law runs in two spaces:

* **Stage 1** (task space, n = 3, the ball funnel of Sec. 4, reused from
  :class:`stt_drake.core.control.FunnelController`): v_ref = −κ₁ ρ₁ (y − c).
* **Mapping** (kinematics only): q̇_ref = J⁺_λ v_ref + N z(q), with the damped least-squares
  inverse J⁺_λ = V diag(s/(s² + λ²)) Uᵀ of the translational Jacobian J = U diag(s) Vᵀ and the
  exact null-space projector N = I − V Vᵀ (J N = 0, so the posture term z never moves the
  end effector). Then ẏ = J q̇ = (J J⁺_λ) v_ref + J (q̇ − q̇_ref), and J J⁺_λ =
  U diag(s²/(s² + λ²)) Uᵀ is positive definite wherever J has full rank: the task-space
  system has the positive-definite input gain of Assumption 2, and the joint-velocity error
  enters as a disturbance bounded by the stage-2 funnel.
* **Stage 2** (joint space, 7 box funnels on q̇ − q̇_ref, reused from
  :func:`stt_drake.core.control.box_funnel_stage`): τ = −κ₂ ξ₂ ρ₂.

No mass matrix, Coriolis, gravity or friction term: the law never reads a dynamic parameter.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from stt_drake.core import backend
from stt_drake.core.control import BoxFunnel, FunnelController, box_funnel_stage
from stt_drake.core.invariants import tube_in_target


@dataclass(frozen=True)
class ArmLimits:
    """Joint limits of the arm (rad, rad/s, N·m), one entry per joint."""

    position_lower: np.ndarray
    position_upper: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray

    @classmethod
    def of(cls, plant: Any) -> ArmLimits:
        """The limits loaded into a (Drake MultibodyPlant-like) `plant`."""
        return cls(
            position_lower=np.asarray(plant.GetPositionLowerLimits(), dtype=float),
            position_upper=np.asarray(plant.GetPositionUpperLimits(), dtype=float),
            velocity=np.asarray(plant.GetVelocityUpperLimits(), dtype=float),
            effort=np.asarray(plant.GetEffortUpperLimits(), dtype=float),
        )


@dataclass(frozen=True)
class JointSpaceMapping:
    """Task-space velocity reference → joint-velocity reference (kinematics only).

    Attributes:
        damping: λ of the damped least-squares inverse (m/s per rad/s, i.e. metres).
        posture: (7,) the posture the null-space term pulls toward (rad).
        posture_gain: k_p ≥ 0 (1/s): z = −k_p (q − posture) + limit term.
        position_lower, position_upper: (7,) joint position limits (rad).
        limit_margin: width of the band inside each limit where the repulsion acts (rad).
        limit_gain: peak repulsion speed at a limit (rad/s); it ramps linearly from 0 at
            `limit_margin` inside the limit.
    """

    damping: float
    posture: np.ndarray
    posture_gain: float
    position_lower: np.ndarray
    position_upper: np.ndarray
    limit_margin: float
    limit_gain: float

    def null_space_velocity(self, q: np.ndarray) -> np.ndarray:
        """z(q): pull toward the posture, pushed away from joint limits (rad/s)."""
        below = np.clip((self.limit_margin - (q - self.position_lower)) / self.limit_margin, 0, 1)
        above = np.clip((self.limit_margin - (self.position_upper - q)) / self.limit_margin, 0, 1)
        return -self.posture_gain * (q - self.posture) + self.limit_gain * (below - above)

    def reference(
        self, jacobian: np.ndarray, task_velocity: np.ndarray, q: np.ndarray
    ) -> np.ndarray:
        """q̇_ref = J⁺_λ v_ref + (I − V Vᵀ) z(q) for the (3, 7) translational Jacobian."""
        u, s, vt = np.linalg.svd(jacobian, full_matrices=False)
        task = vt.T @ ((s / (s * s + self.damping**2)) * (u.T @ task_velocity))
        z = self.null_space_velocity(q)
        return task + z - vt.T @ (vt @ z)


@dataclass(frozen=True)
class ArmControlEvaluation:
    """One evaluation of the arm's funnel law.

    Attributes:
        torque: (7,) stage-2 joint torque τ (N·m), before any robot-side compensation.
        task_velocity: (3,) stage-1 reference v_ref (m/s).
        joint_velocity: (7,) mapped joint-velocity reference q̇_ref (rad/s).
        normalized_errors: (8,) [e₁, e₂ (7)], before saturation; |e| < 1 inside a funnel.
    """

    torque: np.ndarray
    task_velocity: np.ndarray
    joint_velocity: np.ndarray
    normalized_errors: np.ndarray


@dataclass(frozen=True)
class ArmFunnelLaw:
    """Stage 1 in task space, the Jacobian mapping, stage 2 in joint space.

    Attributes:
        controller: the two-stage funnel controller of the scenario: κ = (κ₁, κ₂) and the
            one box funnel of stage 2 (7 joint-velocity axes).
        mapping: the task → joint velocity mapping.
    """

    controller: FunnelController
    mapping: JointSpaceMapping

    def __post_init__(self) -> None:
        if self.controller.stages != 2:
            raise ValueError(f"the arm law has 2 stages, got {self.controller.stages}")

    @cached_property
    def stage_one(self) -> FunnelController:
        """Stage 1 alone: the ball funnel of the task space with κ₁."""
        return FunnelController(kappa=list(self.controller.kappa[:1]))

    @property
    def funnel(self) -> BoxFunnel:
        return self.controller.funnels[0]

    @cached_property
    def _kernel(self) -> Callable[..., tuple] | None:
        """The compiled arm_control, looked up once (read while it is selected)."""
        return backend.compiled("arm_control")

    @cached_property
    def _kernel_arguments(self) -> tuple[np.ndarray | float, ...]:
        """arm_control's last arguments: κ, the stage-2 funnel's p, q, μ per joint and the
        saturation (the controller's), then the mapping's parameters as float arrays."""
        mapping = self.mapping
        joints = np.asarray(mapping.posture).shape[0]
        kappa, start, end, rate, saturation = self.controller.compiled_arguments(joints)
        return (
            kappa,
            start[0],
            end[0],
            rate[0],
            saturation,
            float(mapping.damping),
            np.ascontiguousarray(mapping.posture, dtype=float),
            float(mapping.posture_gain),
            np.ascontiguousarray(mapping.position_lower, dtype=float),
            np.ascontiguousarray(mapping.position_upper, dtype=float),
            float(mapping.limit_margin),
            float(mapping.limit_gain),
        )

    def evaluate(
        self,
        t: float,
        position: np.ndarray,
        q: np.ndarray,
        v: np.ndarray,
        jacobian: np.ndarray,
        center: np.ndarray,
        radius: float,
    ) -> ArmControlEvaluation:
        """The torque at time t from the measured TCP position y, q, q̇, J(q) and the tube.

        One call of the compiled :func:`stt_drake.core._arm.arm_control` (unless the numpy
        path is selected); non-finite or mis-shaped inputs go on to the reference below.
        """
        kernel = self._kernel if backend.using_compiled() else None
        if kernel is not None:
            torque, task, joint, errors, valid = kernel(
                float(t),
                *(np.asarray(x, dtype=float) for x in (position, q, v, jacobian, center)),
                float(radius),
                *self._kernel_arguments,
            )
            if valid:
                return ArmControlEvaluation(torque, task, joint, errors)
        stage_one = self.stage_one.evaluate(t, position, center, radius)
        joint_velocity = self.mapping.reference(jacobian, stage_one.control, q)
        torque, e2 = box_funnel_stage(t, v, joint_velocity, self.funnel, self.controller.kappa[1])
        return ArmControlEvaluation(
            torque=torque,
            task_velocity=stage_one.control,
            joint_velocity=joint_velocity,
            normalized_errors=np.concatenate([stage_one.normalized_errors[0], e2]),
        )


# --------------------------------------------------------------------------- post-run checks


def _worst(t: np.ndarray, margin: np.ndarray) -> dict[str, Any]:
    """Worst entry of a (T, k) margin table: value, time, column; holds if ≥ 0."""
    index = np.unravel_index(int(np.argmin(margin)), margin.shape)
    worst = float(margin[index])
    return {
        "holds": bool(worst >= 0.0),
        "worst_margin": worst,
        "t_worst": float(t[index[0]]),
        "joint": int(index[1]) + 1,
    }


def limit_report(
    t: np.ndarray, q: np.ndarray, v: np.ndarray, torque: np.ndarray, limits: ArmLimits
) -> dict[str, dict[str, Any]]:
    """Worst margins to the joint position, velocity and torque limits over a run.

    Margins are min(q − q_lo, q_hi − q) (rad), v_max − |q̇| (rad/s) and τ_max − |τ| (N·m),
    with τ the torque the robot was asked for (before its saturation), per joint and sample;
    `joint` is 1-based. Arrays are (T, 7).
    """
    return {
        "joint_position": _worst(
            t, np.minimum(q - limits.position_lower, limits.position_upper - q)
        ),
        "joint_velocity": _worst(t, limits.velocity - np.abs(v)),
        "joint_torque": _worst(t, limits.effort - np.abs(torque)),
    }


@dataclass(frozen=True)
class JerkWindow:
    """When one external jerk acts and how long after it its effect is measured (s)."""

    start: float
    end: float


def jerk_report(
    t: np.ndarray,
    funnel_errors: np.ndarray,
    output: np.ndarray,
    center: np.ndarray,
    jerks: Sequence[JerkWindow],
    settle: float,
) -> list[dict[str, Any]]:
    """Per jerk: peak funnel errors and distance to the tube centre from its start until
    `settle` seconds after it ends (or the next jerk starts), next to the values just before.

    Args:
        t: (T,) sample times; funnel_errors: (T, 8) [e₁, e₂]; output, center: (T, 3).
        jerks: the jerk windows in time order.
        settle: how long after a jerk ends its window extends (s).
    """
    report = []
    offset = np.linalg.norm(output - center, axis=1)
    stage_two = np.max(np.abs(funnel_errors[:, 1:]), axis=1)
    for k, jerk in enumerate(jerks):
        stop = jerk.end + settle
        if k + 1 < len(jerks):
            stop = min(stop, jerks[k + 1].start)
        after = (t >= jerk.start) & (t <= stop)
        before = np.flatnonzero(t < jerk.start)
        if not np.any(after):
            continue
        prior = before[-1] if before.size else np.flatnonzero(after)[0]
        peak = np.flatnonzero(after)[int(np.argmax(funnel_errors[after, 0]))]
        report.append(
            {
                "index": k,
                "t_start": jerk.start,
                "t_end": jerk.end,
                "peak_stage1_error": float(funnel_errors[peak, 0]),
                "t_peak_stage1_error": float(t[peak]),
                "stage1_error_before": float(funnel_errors[prior, 0]),
                "peak_stage2_error": float(np.max(stage_two[after])),
                "peak_offset_from_center": float(np.max(offset[after])),
                "offset_before": float(offset[prior]),
            }
        )
    return report


def arm_metrics(
    log: Mapping[str, np.ndarray],
    limits: ArmLimits,
    jerks: Sequence[JerkWindow],
    settle: float,
    targets: Sequence[np.ndarray],
    target_set_radius: float,
) -> dict[str, Any]:
    """The arm's extra metrics from a run log: `segments` (:func:`segment_report`, when the
    log has the sequencer's `task_target`), `limits` (:func:`limit_report` on the logged
    `joint_state` and `requested_torque`) and `jerks` (:func:`jerk_report`)."""
    joints = limits.effort.size
    state = np.asarray(log["joint_state"])
    metrics: dict[str, Any] = {}
    if "task_target" in log:
        metrics["segments"] = segment_report(
            log["t"],
            log["task_target"],
            log["center"],
            log["radius"],
            target_set_radius,
            targets,
        )
    metrics["limits"] = limit_report(
        log["t"], state[:, :joints], state[:, joints:], log["requested_torque"], limits
    )
    metrics["jerks"] = jerk_report(
        log["t"], log["funnel_errors"], log["output"], log["center"], jerks, settle
    )
    return metrics


def segment_report(
    t: np.ndarray,
    task_target: np.ndarray,
    center: np.ndarray,
    radius: np.ndarray,
    target_set_radius: float,
    targets: Sequence[np.ndarray],
) -> list[dict[str, Any]]:
    """Reach-and-stay per task segment, recomputed from the logged target η(t) and tube.

    A segment is a maximal run of samples with one target. Its `t_tube_in_target` is the
    first sample from which Γ(t) ⊂ T_k (‖c − η_k‖ + r ≤ R_T) holds until the segment ends; a
    segment is completed when that time exists. Targets that never became active are listed as not
    completed, so the list always has one entry per target in `targets`.
    """
    inside = tube_in_target(center, radius, task_target, target_set_radius)
    change = np.flatnonzero(np.any(np.diff(task_target, axis=0) != 0.0, axis=1)) + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change, [len(t)]])
    report: list[dict[str, Any]] = []
    for k, target in enumerate(targets):
        entry: dict[str, Any] = {"index": k, "target": np.asarray(target, float).tolist()}
        if k >= len(starts):
            never = {"t_start": None, "t_end": None, "t_tube_in_target": None, "completed": False}
            report.append({**entry, **never})
            continue
        first, stop = int(starts[k]), int(ends[k])
        segment_inside = inside[first:stop]
        reach = None
        if segment_inside[-1]:
            outside = np.flatnonzero(~segment_inside)
            reach = float(t[first + (0 if outside.size == 0 else outside[-1] + 1)])
        same_target = bool(np.allclose(task_target[first], target))
        report.append(
            {
                **entry,
                "t_start": float(t[first]),
                "t_end": float(t[stop - 1]),
                "t_tube_in_target": reach,
                "completed": reach is not None and same_target,
            }
        )
    return report


def summarize_arm(metrics: Mapping[str, Any]) -> list[str]:
    """Summary lines for the arm's extra metrics (segments, limits, jerks), under a heading;
    none without them."""
    lines = []
    for segment in metrics.get("segments", []):
        reach = segment["t_tube_in_target"]
        lines.append(
            f"    segment {segment['index']} → {np.round(segment['target'], 3).tolist()}: "
            + (f"t_c = {reach:.2f} s" if reach is not None else "NOT completed")
        )
    for name, record in metrics.get("limits", {}).items():
        verdict = "holds" if record["holds"] else "VIOLATED"
        lines.append(
            f"    {name:<16} {verdict:<8} worst margin {record['worst_margin']:+.3f} "
            f"(joint {record['joint']}, t = {record['t_worst']:.2f} s)"
        )
    for jerk in metrics.get("jerks", []):
        lines.append(
            f"    jerk {jerk['index']} at {jerk['t_start']:.2f} s: peak e₁ = "
            f"{jerk['peak_stage1_error']:.3f} (before {jerk['stage1_error_before']:.3f}), "
            f"peak max|e₂| = {jerk['peak_stage2_error']:.3f}, "
            f"peak ‖y − c‖ = {jerk['peak_offset_from_center'] * 100:.1f} cm"
        )
    return ["  tasks, joint limits and jerks:", *lines] if lines else []
