"""Scenario → a Drake Diagram of a baseline controller (chance-constrained CBF-QP or
artificial potential field, :mod:`stt_drake.systems.baselines`) closing the loop around the
scenario's plant, for the comparison with STT (`stt-drake compare`).

The plant, its disturbance and the obstacles' belief are exactly those of the STT diagram
(:data:`stt_drake.assembly.diagram.PLANT_BUILDERS`, an :class:`ObstacleBeliefSource` of the
scenario's obstacles); only the controller differs. The omni robot and the quadrotor are
supported; the FR3 arm has no baseline (its controller is the arm's own STT law).

Nominal models (what the baselines believe the plant is; STT reads none):

* omni robot: order 1, ẏ = u with u the commanded world velocity (m/s). The command goes
  through the plant's drive interface, which maps it to wheel speeds with the *nominal*
  wheel and base radii: the true radii differ, so the model mismatch is the plant's, the
  same as for STT.
* quadrotor: order 2, m ÿ = u − m g e_z − c_d ẏ with the nominal m = 1.0 kg,
  c_d = 0.2 N·s/m, g = 9.81 m/s² (the defaults of the scenario schema's
  :class:`stt_drake.config.Quadrotor`), whatever the scenario's true values.

The gains below were tuned once, on ``diagrams/omni_hardware_case2.yaml`` (omni robot) and
``diagrams/uav_cluttered.yaml`` (quadrotor), and are used unchanged on every scenario.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem

from stt_drake.assembly.diagram import PLANT_BUILDERS
from stt_drake.assembly.loggers import LoggedSignal, add_loggers
from stt_drake.config import OmniRobot as OmniRobotConfig
from stt_drake.config import Quadrotor as QuadrotorConfig
from stt_drake.config import Scenario
from stt_drake.core.baselines import GoalSeeking, NominalPlant, PotentialField
from stt_drake.core.belief import ObstacleTask
from stt_drake.systems.baselines import ChanceConstrainedCbfController, PotentialFieldController
from stt_drake.systems.belief_source import ObstacleBeliefSource

#: The baseline controllers, by their `--controllers` name.
BASELINES = ("cbf", "apf")
#: The QP solvers of the CBF baseline (`--solver`).
SOLVERS = ("osqp", "clarabel")

# Omni robot (order 1), tuned on diagrams/omni_hardware_case2.yaml (a small grid: the
# fastest reach whose worst belief collision probability stayed ≤ 10 % of 1 − ε_j).
#: |u_i| ≤ this commanded speed per axis (m/s): the STT tube's max_center_speed there.
OMNI_SPEED_LIMIT = 1.0
#: Goal seeking (CBF nominal): k_p (1/s) and v_max (m/s, the speed limit).
OMNI_POSITION_GAIN = 2.0
OMNI_MAX_SPEED = 1.0
#: CBF rate α (1/s).
OMNI_CBF_RATE = 2.0
#: APF: k_att (1/s), d_s (m) (k_att·d_s = the saturated attraction speed, m/s), k_rep
#: (m⁴/s), d0 (m).
OMNI_ATTRACTION_GAIN = 2.0
OMNI_ATTRACTION_DISTANCE = 0.5
OMNI_REPULSION_GAIN = 0.05
OMNI_INFLUENCE_DISTANCE = 0.6

# Quadrotor (order 2), tuned on diagrams/uav_cluttered.yaml (same rule as the omni robot;
# v_max = the STT tube's max_center_speed there).
#: |u_i| ≤ this force per axis (N): about three times the nominal weight.
QUADROTOR_FORCE_LIMIT = 30.0
#: Goal seeking (CBF nominal): k_p (1/s), v_max (m/s), k_v (1/s).
QUADROTOR_POSITION_GAIN = 1.0
QUADROTOR_MAX_SPEED = 2.5
QUADROTOR_VELOCITY_GAIN = 3.0
#: CBF double pole p (1/s).
QUADROTOR_CBF_RATE = 1.5
#: APF: k_att (1/s), d_s (m), k_rep (m⁴/s), d0 (m); its velocity tracking uses the goal
#: seeking's v_max and k_v above.
QUADROTOR_ATTRACTION_GAIN = 1.0
QUADROTOR_ATTRACTION_DISTANCE = 2.5
QUADROTOR_REPULSION_GAIN = 0.2
QUADROTOR_INFLUENCE_DISTANCE = 1.0

#: The CBF's control period (s): a zero-order hold, as on hardware.
CBF_PERIOD = 0.01


class BaselineError(ValueError):
    """A scenario or option the baselines cannot run; the message names the option."""


@dataclass
class BaselineDiagram:
    """A built baseline loop: the Diagram, the controller system (its step timing and, for
    the CBF, its infeasible-step count), the belief source, the plant, and the loggers of
    ``output``, ``belief`` and ``control``."""

    diagram: Diagram
    controller: ChanceConstrainedCbfController | PotentialFieldController
    belief_source: ObstacleBeliefSource
    plant: LeafSystem
    task: ObstacleTask
    loggers: dict[str, LoggedSignal] = field(default_factory=dict)


def nominal_plant(scenario: Scenario) -> NominalPlant:
    """The baselines' model of the scenario's plant (module docstring).

    Raises:
        BaselineError: for a plant without a baseline (the FR3 arm).
    """
    if isinstance(scenario.plant, OmniRobotConfig):
        return NominalPlant(order=1)
    if isinstance(scenario.plant, QuadrotorConfig):
        nominal = QuadrotorConfig()
        return NominalPlant(order=2, mass=nominal.mass, drag=nominal.drag, gravity=nominal.gravity)
    raise BaselineError(
        f"--controllers: the baselines (cbf, apf) support the omni robot and the quadrotor, "
        f"not the {type(scenario.plant).__name__} plant of scenario {scenario.name!r}; "
        "compare it with --controllers stt only"
    )


def _make_controller(
    scenario: Scenario, controller: str, solver: str, task: ObstacleTask, plant: NominalPlant
) -> ChanceConstrainedCbfController | PotentialFieldController:
    n = scenario.dimension
    goal = np.asarray(scenario.target, dtype=float)
    omni = plant.order == 1
    limit = OMNI_SPEED_LIMIT if omni else QUADROTOR_FORCE_LIMIT
    if controller == "cbf":
        seeking = (
            GoalSeeking(goal, OMNI_POSITION_GAIN, OMNI_MAX_SPEED)
            if omni
            else GoalSeeking(
                goal, QUADROTOR_POSITION_GAIN, QUADROTOR_MAX_SPEED, QUADROTOR_VELOCITY_GAIN
            )
        )
        rate = OMNI_CBF_RATE if omni else QUADROTOR_CBF_RATE
        return ChanceConstrainedCbfController(
            task, n, plant, seeking, limit, period=CBF_PERIOD, rate=rate, solver=solver
        )
    if omni:
        potential = PotentialField(
            goal,
            OMNI_ATTRACTION_GAIN,
            OMNI_ATTRACTION_DISTANCE,
            OMNI_REPULSION_GAIN,
            OMNI_INFLUENCE_DISTANCE,
        )
        return PotentialFieldController(task, n, plant, potential, limit)
    potential = PotentialField(
        goal,
        QUADROTOR_ATTRACTION_GAIN,
        QUADROTOR_ATTRACTION_DISTANCE,
        QUADROTOR_REPULSION_GAIN,
        QUADROTOR_INFLUENCE_DISTANCE,
    )
    return PotentialFieldController(
        task, n, plant, potential, limit, QUADROTOR_MAX_SPEED, QUADROTOR_VELOCITY_GAIN
    )


def build_baseline_diagram(
    scenario: Scenario, controller: str, solver: str = "osqp"
) -> BaselineDiagram:
    """The scenario's plant (:data:`PLANT_BUILDERS`), an :class:`ObstacleBeliefSource` of
    its obstacles and the baseline `controller` ("cbf" or "apf", with the QP `solver` for
    "cbf") wired to it, and loggers on the plant output, the belief and the control at
    ``scenario.log_period``.

    Raises:
        BaselineError: an unknown controller or solver, or a plant without a baseline.
    """
    if controller not in BASELINES:
        raise BaselineError(
            f"--controllers: a baseline is one of {', '.join(BASELINES)} (got {controller!r})"
        )
    if solver not in SOLVERS:
        raise BaselineError(f"--solver: must be one of {', '.join(SOLVERS)} (got {solver!r})")
    plant_model = nominal_plant(scenario)
    builder = DiagramBuilder()
    plant = PLANT_BUILDERS[type(scenario.plant)](builder, scenario)
    n = scenario.dimension
    source = builder.AddNamedSystem(
        "obstacle_belief_source", ObstacleBeliefSource(scenario.obstacles, n)
    )
    task = ObstacleTask.of(scenario.obstacles)
    system = builder.AddNamedSystem(
        f"{controller}_controller",
        _make_controller(scenario, controller, solver, task, plant_model),
    )
    belief = source.GetOutputPort("obstacle_belief")
    builder.Connect(plant.plant_state, system.GetInputPort("plant_state"))
    builder.Connect(belief, system.GetInputPort("obstacle_belief"))
    builder.Connect(system.GetOutputPort("control"), plant.control_input)
    logged = {"output": plant.output, "belief": belief, "control": system.GetOutputPort("control")}
    loggers = add_loggers(builder, logged, scenario.log_period)
    diagram = builder.Build()
    diagram.set_name(f"{scenario.name}_{controller}")
    return BaselineDiagram(diagram, system, source, plant.plant, task, loggers)
