"""The controller's half: the scenario's plant replaced by the LCM link to its station.

:func:`remote_scenario` gives a scenario whose plant config is a ``Remote*`` subclass of
its own (same fields; :data:`~stt_drake.assembly.diagram.PLANT_BUILDERS` maps it to
:func:`add_remote_plant`), so ``build_diagram`` and ``simulate`` build and run the
controller exactly as ``stt-drake run`` does: tube, controller, the arm's sequencer and
the invariant monitor, on the state received from the station. metrics.json gains the
link's `lcm` record (:func:`link_report`): controller tick and status age p50/p99/max,
and the messages accepted and dropped.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np
from drake import lcmt_panda_command, lcmt_panda_status
from pydrake.manipulation import PandaCommandSender, PandaStatusReceiver
from pydrake.systems.framework import BasicVector, Context, DiagramBuilder, LeafSystem
from pydrake.systems.lcm import PySerializer
from pydrake.systems.primitives import Multiplexer

from stt_drake.assembly.checks import initial_stage_states
from stt_drake.assembly.diagram import (
    JERK_SETTLE_TIME,
    PLANT_BUILDERS,
    SEQUENCER_PERIOD,
    PlantHandles,
)
from stt_drake.assembly.laws import make_arm_law
from stt_drake.config import FrankaArm, OmniRobot, Quadrotor, Scenario, ScenarioError
from stt_drake.config.lcm import LcmConfig, validate_lcm
from stt_drake.core.arm import ArmLimits, JerkWindow, arm_metrics, summarize_arm
from stt_drake.robot.halves import (
    PANDA_MODE,
    Link,
    add_bus,
    add_station,
    channels,
    link_clock,
    panda_command_bytes,
    panda_status_bytes,
    safe_command,
)
from stt_drake.robot.messages import CommandEncoder, StateDecoder, command_message, state_message
from stt_drake.robot.stt_lcm import robot_command, robot_state
from stt_drake.robot.transport import (
    FilteredSubscriber,
    TickTimer,
    cpp_serializer,
    percentiles,
)
from stt_drake.systems.plants.franka import (
    FR3_JOINTS,
    ArmKinematics,
    ArmRobotInterface,
    ArmSTTController,
    make_fr3_plant,
)
from stt_drake.systems.sequencer import TargetSequencer


@dataclass
class RemoteOmniRobot(OmniRobot):
    """An omni robot on the other end of the LCM link (`station_in_process`: its station
    is built into the same diagram, on an in-process ``memq://`` bus)."""

    station_in_process: bool = False


@dataclass
class RemoteQuadrotor(Quadrotor):
    """A quadrotor on the other end of the LCM link (see :class:`RemoteOmniRobot`)."""

    station_in_process: bool = False


@dataclass
class RemoteFrankaArm(FrankaArm):
    """An FR3 on the other end of the LCM link (see :class:`RemoteOmniRobot`)."""

    station_in_process: bool = False


#: The remote config of each plant config.
REMOTE_PLANTS = {OmniRobot: RemoteOmniRobot, Quadrotor: RemoteQuadrotor, FrankaArm: RemoteFrankaArm}


def remote_scenario(scenario: Scenario, in_process: bool = False) -> Scenario:
    """`scenario` with its plant behind the LCM link (a ``Remote*`` config); `in_process`
    builds the station into the controller's diagram on a ``memq://`` bus (one Simulator
    for both halves: deterministic, and the order of the two halves' events is Drake's).

    Raises:
        ScenarioError: a bad `lcm:` section, or a scenario the split does not carry (its
            obstacles must be scripted: a tracker's detections are not routed over LCM).
    """
    config = scenario.lcm or LcmConfig()
    validate_lcm(config)
    for name in ("perception", "crowd"):
        if getattr(scenario, name) is not None:
            raise ScenarioError(
                f"scenario.{name}: the station/controller split carries scripted obstacles "
                f"only (a {name} section's detections do not reach the controller's tracker "
                "over LCM yet); run it with `stt-drake run`"
            )
    if in_process:
        config = dataclasses.replace(config, lcm_url="memq://")
    plant = scenario.plant
    fields = {f.name: getattr(plant, f.name) for f in dataclasses.fields(plant)}
    remote = REMOTE_PLANTS[type(plant)](**fields, station_in_process=in_process)
    return dataclasses.replace(scenario, plant=remote, lcm=config)


def link_report(
    subscriber: FilteredSubscriber, timer: TickTimer, period: float, log: Any
) -> dict[str, Any]:
    """The `lcm` record of metrics.json: the control period, the controller's tick and the
    status age (s, p50/p99/max) and the status messages accepted and dropped."""
    return {
        "lcm": {
            "status_channel": subscriber.channel,
            "clock_epoch_s": subscriber.clock.epoch,
            "control_period_s": period,
            "tick_s": percentiles(timer.ticks),
            **subscriber.statistics.summary(np.asarray(log["link"])[-1]),
        }
    }


def _link(builder: DiagramBuilder, scenario: Scenario) -> Link:
    """The controller's end of the link (and, in process, the station built beside it)."""
    config = scenario.lcm or LcmConfig()
    lcm = add_bus(builder, config)
    if scenario.plant.station_in_process:
        clock = link_clock(scenario, two_processes=False)  # the one Simulator's
        add_station(builder, scenario, Link(lcm, config, clock))
        return Link(lcm, config, clock)
    return Link(lcm, config, link_clock(scenario, two_processes=True))


def add_remote_plant(builder: DiagramBuilder, scenario: Scenario) -> PlantHandles:
    """The plant's ports over LCM: the status subscriber (a :class:`FilteredSubscriber`
    whose stale link publishes the safe command) decoded into y and the stage states, and
    the command encoded and published every control period. Logs the `link` signal."""
    link = _link(builder, scenario)
    if isinstance(scenario.plant, FrankaArm):
        return _add_remote_fr3(builder, scenario, link)
    status, command = channels(scenario)
    n, states = scenario.dimension, initial_stage_states(scenario).ravel()
    safe = safe_command(scenario)

    def publish_safe(t: float) -> None:
        message = command_message(link.clock.now(t), -1, safe)
        link.lcm.Publish(command, message.encode(), None)

    subscriber = link.add_subscriber(
        builder,
        "status_subscriber",
        status,
        PySerializer(robot_state),
        state_message(0.0, scenario.initial_output(), states).encode(),
        on_stale=publish_safe,
    )
    decoder = builder.AddNamedSystem("state_decoder", StateDecoder(n, states.size))
    timer = builder.AddNamedSystem("controller_tick", TickTimer(n))
    encoder = builder.AddNamedSystem("command_encoder", CommandEncoder(n, link.clock))
    publisher = link.add_publisher(builder, "command_publisher", command, robot_command)
    builder.Connect(subscriber.GetOutputPort("message"), decoder.GetInputPort("robot_state"))
    builder.Connect(subscriber.GetOutputPort("link"), encoder.GetInputPort("link"))
    builder.Connect(timer.GetOutputPort("y"), encoder.GetInputPort("control"))
    builder.Connect(encoder.GetOutputPort("robot_command"), publisher.get_input_port())
    return PlantHandles(
        plant=decoder,
        control_input=timer.GetInputPort("u"),
        output=decoder.GetOutputPort("output"),
        plant_state=decoder.GetOutputPort("plant_state"),
        logged={"link": subscriber.GetOutputPort("link")},
        report=partial(link_report, subscriber, timer, link.config.period),
    )


class ArmStatusMeasurement(LeafSystem):
    """The arm's measurement from a received status: input `state` ([q, q̇], 14); outputs
    `output` = y, the TCP position (3, forward kinematics of the robot's model) and
    `plant_state` = [y, q, q̇] (17), as :class:`~stt_drake.systems.plants.franka.ArmMeasurement`
    computes them from the simulated plant."""

    def __init__(self, kinematics: ArmKinematics) -> None:
        super().__init__()
        self._kinematics = kinematics
        self._state = self.DeclareVectorInputPort("state", 2 * FR3_JOINTS)
        self.DeclareVectorOutputPort("output", 3, self._calc_output)
        self.DeclareVectorOutputPort("plant_state", 3 + 2 * FR3_JOINTS, self._calc_state)

    def _position(self, context: Context) -> np.ndarray:
        return self._kinematics.position(self._state.Eval(context)[:FR3_JOINTS])

    def _calc_output(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(self._position(context))

    def _calc_state(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(np.concatenate([self._position(context), self._state.Eval(context)]))


def _arm_report(link: Callable[[Any], dict], arm: Callable[[Any], dict], log: Any) -> dict:
    """The arm's metrics (:func:`stt_drake.core.arm.arm_metrics`) and the link's record."""
    return {**arm(log), **link(log)}


def _add_remote_fr3(builder: DiagramBuilder, scenario: Scenario, link: Link) -> PlantHandles:
    """The FR3 over the driver's messages: ``lcmt_panda_status`` through Drake's
    PandaStatusReceiver into the TCP measurement, the arm's STT controller and its task
    sequencer, and its torque through PandaCommandSender (torque mode) as
    ``lcmt_panda_command``. `requested_torque` is logged as the robot's interface would
    form it (command + gravity compensation of the robot's model), for the limits report."""
    config: FrankaArm = scenario.plant
    status, command = channels(scenario)
    q0 = np.asarray(config.initial_configuration, dtype=float)
    zero = np.zeros(FR3_JOINTS)

    def publish_safe(t: float) -> None:
        link.lcm.Publish(command, panda_command_bytes(t, zero), None)

    subscriber = link.add_subscriber(
        builder,
        "status_subscriber",
        status,
        cpp_serializer(lcmt_panda_status),
        panda_status_bytes(q0),
        on_stale=publish_safe,
    )
    receiver = builder.AddNamedSystem("panda_status_receiver", PandaStatusReceiver(FR3_JOINTS))
    joined = builder.AddNamedSystem("joint_state", Multiplexer([FR3_JOINTS, FR3_JOINTS]))
    kinematics = ArmKinematics()
    measurement = builder.AddNamedSystem("fr3_measurement", ArmStatusMeasurement(kinematics))
    model = make_fr3_plant()
    limits = ArmLimits.of(model)
    controller = builder.AddNamedSystem(
        "arm_stt_controller", ArmSTTController(make_arm_law(scenario, limits), kinematics)
    )
    timer = builder.AddNamedSystem("controller_tick", TickTimer(FR3_JOINTS))
    sender = builder.AddNamedSystem(
        "panda_command_sender", PandaCommandSender(FR3_JOINTS, PANDA_MODE)
    )
    publisher = link.add_publisher(
        builder, "command_publisher", command, lcmt_panda_command, cpp=True
    )
    interface = builder.AddNamedSystem(
        "fr3_interface_model", ArmRobotInterface(model, config.gravity_compensation)
    )
    builder.Connect(subscriber.GetOutputPort("message"), receiver.get_input_port())
    builder.Connect(receiver.get_position_measured_output_port(), joined.get_input_port(0))
    builder.Connect(receiver.get_velocity_measured_output_port(), joined.get_input_port(1))
    builder.Connect(joined.get_output_port(), measurement.GetInputPort("state"))
    builder.Connect(timer.GetOutputPort("y"), sender.get_torque_input_port())
    builder.Connect(sender.get_output_port(), publisher.get_input_port())
    builder.Connect(timer.GetOutputPort("y"), interface.GetInputPort("torque_command"))
    builder.Connect(joined.get_output_port(), interface.GetInputPort("state"))
    targets = scenario.task_targets()
    sequencer = None
    if len(targets) > 1:
        sequencer = builder.AddNamedSystem(
            "target_sequencer",
            TargetSequencer(
                targets, scenario.target_set_radius, config.hold_time, SEQUENCER_PERIOD
            ),
        )
    jerks = [JerkWindow(jerk.time, jerk.time + jerk.duration) for jerk in config.jerks]
    arm = partial(
        arm_metrics,
        limits=limits,
        jerks=jerks,
        settle=JERK_SETTLE_TIME,
        targets=targets,
        target_set_radius=scenario.target_set_radius,
    )
    return PlantHandles(
        plant=measurement,
        control_input=timer.GetInputPort("u"),
        output=measurement.GetOutputPort("output"),
        plant_state=measurement.GetOutputPort("plant_state"),
        controller=controller,
        sequencer=sequencer,
        logged={
            "joint_state": joined.get_output_port(),
            "requested_torque": interface.GetOutputPort("requested_torque"),
            "funnel_errors": controller.GetOutputPort("funnel_errors"),
            "joint_velocity_reference": controller.GetOutputPort("joint_velocity_reference"),
            "link": subscriber.GetOutputPort("link"),
        },
        log_constants={
            "position_lower": limits.position_lower,
            "position_upper": limits.position_upper,
            "velocity_limit": limits.velocity,
            "effort_limit": limits.effort,
        },
        report=partial(
            _arm_report, partial(link_report, subscriber, timer, link.config.period), arm
        ),
        summary=summarize_arm,
    )


for _config, _remote in REMOTE_PLANTS.items():
    PLANT_BUILDERS[_remote] = add_remote_plant
