"""AddStt: the STT loop's systems added to a DiagramBuilder and connected, Drake style (like
``AddMultibodyPlantSceneGraph``).

The loop is belief → tube → controller, with the invariant monitor reading the belief,
the tube and the plant's output (`stt-drake diagram` draws it). The caller owns the plant: it
connects the returned `plant_state` input and `control` output, and the plant's output
into `output` (the monitor's y).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from pydrake.systems.framework import DiagramBuilder, InputPort, LeafSystem, OutputPort

from stt_drake.core.belief import (
    ObstacleModel,
    ObstacleTask,
    has_full_covariance,
    obstacle_belief,
)
from stt_drake.core.control import FunnelController
from stt_drake.core.motion import MotionTable
from stt_drake.core.obstacle import check_obstacle
from stt_drake.core.rules import (
    NU_HINT,
    check_initial_avoidance,
    check_nu_for_count,
    checked_by,
)
from stt_drake.core.tube import BeliefRateBounds, TubeLaw
from stt_drake.systems.belief_source import ObstacleBeliefSource
from stt_drake.systems.controller import STTController
from stt_drake.systems.monitor import InvariantMonitor
from stt_drake.systems.tube import SpatiotemporalTube


@dataclass
class SttHandles:
    """The systems AddStt added (or was given) and the ports a caller connects.

    `belief_source` is None when the belief came in as a port. `plant_state` (the
    controller's input) and `control` (its output) connect to the plant; `output` is the
    monitor's input for the plant output y; `tube` is the tube's [c, r] output and `belief`
    the belief port the loop reads; `task` the obstacles' r_o, ε, p_d per slot, and
    `full_covariance` whether the tube and monitor use each Σ_j exactly."""

    belief_source: ObstacleBeliefSource | None
    tube_system: SpatiotemporalTube
    controller: LeafSystem
    monitor: InvariantMonitor
    belief: OutputPort
    task: ObstacleTask
    full_covariance: bool
    tube: OutputPort
    plant_state: InputPort
    control: OutputPort
    output: InputPort


def AddStt(  # noqa: N802 (Drake's naming of builder functions)
    builder: DiagramBuilder,
    law: TubeLaw,
    controller: FunnelController | LeafSystem,
    start: Sequence[float] | np.ndarray,
    *,
    obstacles: Sequence[ObstacleModel] | None = None,
    belief: OutputPort | None = None,
    task: ObstacleTask | None = None,
    full_covariance: bool | None = None,
    update_period: float | None = None,
    rate_bounds: BeliefRateBounds | None = None,
    target_input: bool = False,
    name: str = "",
) -> SttHandles:
    """Add the STT loop for one robot to `builder` and connect it.

    Args:
        builder: the DiagramBuilder.
        law: the tube law (Sec. 3; its r_min is also the monitor's).
        controller: a :class:`FunnelController` (an :class:`STTController` is added), or a
            controller system already in `builder` with inputs `tube`, `plant_state` and
            output `control` (e.g. the arm's).
        start: the tube's initial centre s (n).
        obstacles: obstacle models (anything with motion, sigma, sigma_schedule, radius,
            epsilon, p_d: a scenario's obstacles); an :class:`ObstacleBeliefSource` is
            added. Give either this or `belief`.
        belief: an `obstacle_belief` output port already in `builder` (a tracker: mean,
            covariance, active per slot), with `task` (r_o, ε, p_d per slot).
        full_covariance: the tube and the monitor use each Σ_j exactly (continuous tube
            only); None: whether some of `obstacles` has a full covariance (False with a
            `belief` port: σ_j² = λ_max(Σ_j), exact only for isotropic Σ_j).
        update_period: None for the continuous-time tube, else the fixed update period h (s);
            then `rate_bounds` is required (:class:`SpatiotemporalTube`).
        target_input: the tube reads η from an input port `target` (a task sequencer).
        name: prefix of the added systems' names ("" gives obstacle_belief_source,
            spatiotemporal_tube, stt_controller, invariant_monitor; "left" gives
            left_spatiotemporal_tube, ...), so several loops fit in one diagram.

    Returns:
        the :class:`SttHandles`.

    Raises:
        ValueError: (a :class:`stt_drake.core.rules.RuleError`) before anything is added,
            naming the argument and the rule a scenario file is checked against: an
            obstacle's rules in R^n (:func:`stt_drake.core.obstacle.check_obstacle`: its
            motion's dimension, σ, task numbers, e.g. ``AddStt: obstacles[2].epsilon must
            lie in (0, 1]``),
            ν against the obstacle count (``law.nu``), and, with `obstacles`, the initial
            avoidance condition q_j(s, 0) > ε_j at `start` (Definition 2.3).
    """
    if (obstacles is None) == (belief is None):
        raise ValueError("AddStt: give exactly one of `obstacles` and `belief`")
    start = np.asarray(start, dtype=float)
    n = start.shape[0]
    if obstacles is None and task is None:
        raise ValueError("AddStt: a `belief` port needs the obstacles' `task` (r_o, ε, p_d)")
    for j, obstacle in enumerate(obstacles or ()):  # a scenario file's rules, with n
        with checked_by("AddStt", f"obstacles[{j}]"):
            check_obstacle(obstacle, n)
    with checked_by("AddStt", "law", NU_HINT):
        check_nu_for_count(law.nu, law.r_min, task.count if obstacles is None else len(obstacles))
    if obstacles is not None:
        _check_initial_avoidance(law, start, obstacles, full_covariance)
    prefix = f"{name}_" if name else ""
    source = None
    if obstacles is not None:
        source = builder.AddNamedSystem(
            f"{prefix}obstacle_belief_source", ObstacleBeliefSource(obstacles, n)
        )
        belief = source.GetOutputPort("obstacle_belief")
        task = ObstacleTask.of(obstacles)
        if full_covariance is None:
            full_covariance = source.full_covariance
    full_covariance = bool(full_covariance)
    tube = builder.AddNamedSystem(
        f"{prefix}spatiotemporal_tube",
        SpatiotemporalTube(
            law,
            start,
            task,
            update_period=update_period,
            target_input=target_input,
            rate_bounds=rate_bounds,
            full_covariance=full_covariance,
        ),
    )
    if isinstance(controller, FunnelController):
        controller = builder.AddNamedSystem(f"{prefix}stt_controller", STTController(controller, n))
    monitor = builder.AddNamedSystem(
        f"{prefix}invariant_monitor",
        InvariantMonitor(n, task, law.r_min, full_covariance=full_covariance),
    )
    tube_output = tube.GetOutputPort("tube")
    builder.Connect(belief, tube.GetInputPort("obstacle_belief"))
    builder.Connect(tube_output, controller.GetInputPort("tube"))
    builder.Connect(tube_output, monitor.GetInputPort("tube"))
    builder.Connect(belief, monitor.GetInputPort("obstacle_belief"))
    builder.Connect(tube.GetOutputPort("recovery"), monitor.GetInputPort("recovery"))
    return SttHandles(
        belief_source=source,
        tube_system=tube,
        controller=controller,
        monitor=monitor,
        belief=belief,
        task=task,
        full_covariance=full_covariance,
        tube=tube_output,
        plant_state=controller.GetInputPort("plant_state"),
        control=controller.GetOutputPort("control"),
        output=monitor.GetInputPort("output"),
    )


def _check_initial_avoidance(
    law: TubeLaw,
    start: np.ndarray,
    obstacles: Sequence[ObstacleModel],
    full_covariance: bool | None,
) -> None:
    """q_j(s, 0) > ε_j at the start for scripted obstacles (the rule of a scenario file,
    :func:`stt_drake.core.rules.check_initial_avoidance`) — with Σ_j exactly where the tube
    will use it; an obstacle absent at t = 0 (a recorded track that starts later) gets
    ε = −1, which every q passes."""
    initial = obstacle_belief(obstacles, start.shape[0], 0.0)
    present = MotionTable([o.motion for o in obstacles], start.shape[0]).active(0.0)
    initial = replace(initial, epsilon=np.where(present, initial.epsilon, -1.0))
    exact = [full_covariance is not False and has_full_covariance(o) for o in obstacles]
    with checked_by("AddStt"):
        check_initial_avoidance(start, initial, law.r_min, exact)
