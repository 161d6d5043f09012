"""AddStt, the Drake-style composite: two STT loops in one diagram, a loop that reads
another system's belief port, the names it gives, and its argument errors.

The plants are Drake's own ``Integrator`` (ẏ = u, a first-order plant the funnel controller
does not know); every guarantee is checked at every step by each loop's monitor, and the
final positions are checked against the targets with numpy.
"""

from __future__ import annotations

import numpy as np
import pytest
from pydrake.systems.analysis import ApplySimulatorConfig, Simulator, SimulatorConfig
from pydrake.systems.framework import DiagramBuilder, EventStatus
from pydrake.systems.primitives import Integrator

from stt_drake import AddStt, FunnelController, TubeLaw
from stt_drake.config import Obstacle
from stt_drake.core.invariants import InvariantTracker
from stt_drake.core.motion import ConstantVelocity
from stt_drake.core.tube import default_nu, linear_zone_for_step

R_MIN, R_MAX, MAX_STEP = 0.1, 0.4, 0.01


def law_to(target: list[float], count: int) -> TubeLaw:
    return TubeLaw(
        target=np.array(target),
        k1=1.0,
        k2=0.4,
        k3=0.4,
        r_min=R_MIN,
        r_max=R_MAX,
        nu=default_nu(count, R_MIN),
        linear_zone=linear_zone_for_step(1.0, MAX_STEP),
        max_center_speed=1.0,
    )


OBSTACLES = [
    Obstacle(
        motion=ConstantVelocity(start=[1.5, 1.5], velocity=[0.0, 0.0]),
        radius=0.2,
        sigma=0.05,
        epsilon=0.95,
        p_d=0.9999,
    )
]


def connect(builder: DiagramBuilder, stt, plant: Integrator) -> None:
    builder.Connect(plant.get_output_port(), stt.plant_state)
    builder.Connect(stt.control, plant.get_input_port())
    builder.Connect(plant.get_output_port(), stt.output)


@pytest.mark.slow
def test_two_stt_loops_fit_in_one_diagram_and_both_keep_every_guarantee():
    builder = DiagramBuilder()
    starts = {"left": [0.0, 0.0], "right": [3.0, 0.0]}
    targets = {"left": [3.0, 3.0], "right": [0.0, 3.0]}
    loops, plants = {}, {}
    for name in ("left", "right"):
        plants[name] = builder.AddNamedSystem(f"{name}_robot", Integrator(2))
        controller = FunnelController(kappa=[4.0], funnels=[])
        if name == "left":
            loops[name] = AddStt(
                builder,
                law_to(targets[name], 1),
                controller,
                starts[name],
                obstacles=OBSTACLES,
                name=name,
            )
        else:  # the second loop reads the first loop's belief port (one tracker, two robots)
            loops[name] = AddStt(
                builder,
                law_to(targets[name], 1),
                controller,
                starts[name],
                belief=loops["left"].belief,
                task=loops["left"].task,
                name=name,
            )
        connect(builder, loops[name], plants[name])
    diagram = builder.Build()  # unique names: no "Non-unique name" failure
    names = {system.get_name() for system in diagram.GetSystems()}
    for expected in (
        "left_obstacle_belief_source",
        "left_spatiotemporal_tube",
        "left_stt_controller",
        "left_invariant_monitor",
        "right_spatiotemporal_tube",
        "right_stt_controller",
        "right_invariant_monitor",
    ):
        assert expected in names
    assert loops["right"].belief_source is None

    simulator = Simulator(diagram)
    ApplySimulatorConfig(
        SimulatorConfig(
            integration_scheme="runge_kutta3",
            accuracy=1e-6,
            max_step_size=MAX_STEP,
            use_error_control=True,
        ),
        simulator,
    )
    context = simulator.get_mutable_context()
    for name in ("left", "right"):
        plants[name].set_integral_value(
            plants[name].GetMyMutableContextFromRoot(context), np.array(starts[name])
        )
    trackers = {name: InvariantTracker() for name in loops}
    monitors = {
        name: loops[name].monitor.attach(simulator, trackers[name], False) for name in loops
    }

    def both(root_context):  # one Simulator monitor: each loop's check in turn
        for monitor in monitors.values():
            monitor(root_context)
        return EventStatus.DidNothing()

    simulator.set_monitor(both)
    simulator.AdvanceTo(12.0)
    for name in loops:
        assert trackers[name].holds, (name, trackers[name].as_dict())
        y = plants[name].get_output_port().Eval(plants[name].GetMyContextFromRoot(context))
        # The tube settles at η (exponentially under the linear zone) and y stays inside it.
        assert np.linalg.norm(y - np.array(targets[name])) < R_MAX, (name, y)


def test_add_stt_needs_exactly_one_belief_and_a_task_with_a_port():
    builder = DiagramBuilder()
    controller = FunnelController(kappa=[4.0], funnels=[])
    with pytest.raises(ValueError, match="exactly one of `obstacles` and `belief`"):
        AddStt(builder, law_to([1.0, 1.0], 1), controller, [0.0, 0.0])
    first = AddStt(builder, law_to([1.0, 1.0], 1), controller, [0.0, 0.0], obstacles=OBSTACLES)
    with pytest.raises(ValueError, match="`task`"):
        AddStt(builder, law_to([1.0, 1.0], 1), controller, [0.0, 0.0], belief=first.belief)


def test_default_names_are_the_single_loop_names():
    builder = DiagramBuilder()
    stt = AddStt(
        builder,
        law_to([1.0, 1.0], 1),
        FunnelController(kappa=[4.0], funnels=[]),
        [0.0, 0.0],
        obstacles=OBSTACLES,
    )
    assert stt.tube_system.get_name() == "spatiotemporal_tube"
    assert stt.controller.get_name() == "stt_controller"
    assert stt.monitor.get_name() == "invariant_monitor"
    assert stt.belief_source.get_name() == "obstacle_belief_source"
