"""The controller's half: the scenario's plant replaced by the LCM link to its station.

:func:`remote_scenario` gives a scenario whose plant config is a ``Remote*`` subclass of
its own (same fields; :data:`~stt_drake.assembly.diagram.PLANT_BUILDERS` maps it to
:func:`add_remote_plant`), so ``build_diagram`` and ``simulate`` build and run the
controller exactly as ``stt-drake run`` does: the tracker (on the station's detections,
with perception), tube, controller, the arm's sequencer and the invariant monitor, on the
state received from the station. metrics.json gains the link's `lcm` record
(:func:`link_report`): controller tick and status age p50/p99/max, and the messages
accepted and dropped (status, and detections).
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
from stt_drake.assembly.diagram import PLANT_BUILDERS, PlantHandles, add_arm_controller
from stt_drake.config import FrankaArm, OmniRobot, Quadrotor, Scenario
from stt_drake.config.lcm import LcmConfig
from stt_drake.config.validate_lcm import validate_lcm
from stt_drake.core.arm import ArmLimits
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
from stt_drake.robot.messages import (
    CommandEncoder,
    DetectionsDecoder,
    StateDecoder,
    command_message,
    state_message,
)
from stt_drake.robot.stt_lcm import obstacle_detections, robot_command, robot_state
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
    make_fr3_plant,
)


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
        ScenarioError: a bad `lcm:` section.
    """
    config = scenario.lcm or LcmConfig()
    validate_lcm(config)
    if in_process:
        config = dataclasses.replace(config, lcm_url="memq://")
    plant = scenario.plant
    fields = {f.name: getattr(plant, f.name) for f in dataclasses.fields(plant)}
    remote = REMOTE_PLANTS[type(plant)](**fields, station_in_process=in_process)
    return dataclasses.replace(scenario, plant=remote, lcm=config)


def link_report(
    subscriber: FilteredSubscriber,
    timer: TickTimer,
    period: float,
    log: Any,
    detections: FilteredSubscriber | None = None,
) -> dict[str, Any]:
    """The `lcm` record of metrics.json: the control period, the controller's tick and the
    status age (s, p50/p99/max) and the status messages accepted and dropped; with
    `detections`, their channel's record (`detections`: ages, accepted, dropped, and the
    silences longer than the tracker's track timeout)."""
    record = {
        "status_channel": subscriber.channel,
        "clock_epoch_s": subscriber.clock.epoch,
        "control_period_s": period,
        "tick_s": percentiles(timer.ticks),
        **subscriber.statistics.summary(np.asarray(log["link"])[-1]),
    }
    if detections is not None:
        record["detections"] = {
            "channel": detections.channel,
            **detections.statistics.summary(np.asarray(log["detections_link"])[-1]),
        }
    return {"lcm": record}


def _merged_report(reports: tuple[Callable[[Any], dict], ...], log: Any) -> dict:
    """The records of several reports of one run log in one dict."""
    merged: dict[str, Any] = {}
    for report in reports:
        merged.update(report(log))
    return merged


def _link(builder: DiagramBuilder, scenario: Scenario) -> tuple[Link, PlantHandles | None]:
    """The controller's end of the link, and in process the station built beside it."""
    config = scenario.lcm or LcmConfig()
    lcm = add_bus(builder, config)
    if scenario.plant.station_in_process:
        clock = link_clock(scenario, two_processes=False)  # the one Simulator's
        station = add_station(builder, scenario, Link(lcm, config, clock))
        return Link(lcm, config, clock), station
    return Link(lcm, config, link_clock(scenario, two_processes=True)), None


def add_remote_plant(builder: DiagramBuilder, scenario: Scenario) -> PlantHandles:
    """The plant's ports over LCM: the status subscriber (a :class:`FilteredSubscriber`
    whose stale link publishes the safe command) decoded into y and the stage states, and
    the command encoded and published every control period; with perception, the
    station's detections (:func:`add_remote_detections`). Logs the `link` signal; its
    report is the link's `lcm` record (and the arm's metrics)."""
    link, station = _link(builder, scenario)
    add_half = _add_remote_fr3 if isinstance(scenario.plant, FrankaArm) else _add_remote_mobile
    handles, subscriber, timer = add_half(builder, scenario, link)
    detections = None
    if scenario.perception is not None:
        handles, detections = add_remote_detections(builder, scenario, link, handles, station)
    report = partial(link_report, subscriber, timer, link.config.period, detections=detections)
    if handles.report is not None:
        report = partial(_merged_report, (handles.report, report))
    return dataclasses.replace(handles, report=report)


def add_remote_detections(
    builder: DiagramBuilder,
    scenario: Scenario,
    link: Link,
    handles: PlantHandles,
    station: PlantHandles | None,
) -> tuple[PlantHandles, FilteredSubscriber]:
    """The station's detections as the tracker's input: a :class:`FilteredSubscriber` on
    `lcm.detections_channel` draining at the tracker's update times (every sensor period
    from its latency: a sample published at its delivery is read by the tracker at that
    same time, as in process), newer utimes only, and a silence longer than the tracker's
    `track_timeout` counted, not stopping the run (the tracker loses those tracks); then
    decoded (:class:`DetectionsDecoder`). Returns `handles` with `detections` (logged, with
    `detections_link`) and, from an in-process `station`, the truth to log."""
    config = scenario.perception
    count, n = len(scenario.obstacles), scenario.dimension
    subscriber = builder.AddNamedSystem(
        "detections_subscriber",
        FilteredSubscriber(
            link.config.detections_channel,
            PySerializer(obstacle_detections),
            link.lcm,
            config.sensor_period,
            config.track_timeout,
            clock=link.clock,
            offset=config.latency,
            stop_when_stale=False,
        ),
    )
    decoder = builder.AddNamedSystem("detections_decoder", DetectionsDecoder(count, n, link.clock))
    builder.Connect(
        subscriber.GetOutputPort("message"), decoder.GetInputPort("obstacle_detections")
    )
    detections = decoder.GetOutputPort("detections")
    logged = {"detections": detections, "detections_link": subscriber.GetOutputPort("link")}
    truth = None
    if station is not None:
        truth = station.true_obstacle_position
        if "pedestrian_active" in station.logged:
            logged["pedestrian_active"] = station.logged["pedestrian_active"]
    handles = dataclasses.replace(
        handles,
        logged={**handles.logged, **logged},
        detections=detections,
        true_obstacle_position=truth,
    )
    return handles, subscriber


def _add_remote_mobile(
    builder: DiagramBuilder, scenario: Scenario, link: Link
) -> tuple[PlantHandles, FilteredSubscriber, TickTimer]:
    """The omni robot's or the quadrotor's remote plant, on robot_state/robot_command."""
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
    handles = PlantHandles(
        plant=decoder,
        control_input=timer.GetInputPort("u"),
        output=decoder.GetOutputPort("output"),
        plant_state=decoder.GetOutputPort("plant_state"),
        logged={"link": subscriber.GetOutputPort("link")},
    )
    return handles, subscriber, timer


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


def _add_remote_fr3(
    builder: DiagramBuilder, scenario: Scenario, link: Link
) -> tuple[PlantHandles, FilteredSubscriber, TickTimer]:
    """The FR3 over the driver's messages: ``lcmt_panda_status`` through Drake's
    PandaStatusReceiver into the TCP measurement and the arm's controller side
    (:func:`~stt_drake.assembly.diagram.add_arm_controller`), and its torque through
    PandaCommandSender (torque mode) as ``lcmt_panda_command``. `requested_torque` is
    logged as the robot's interface would form it (command + gravity compensation of the
    robot's model), for the limits report."""
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
    measured = PlantHandles(
        plant=measurement,
        control_input=timer.GetInputPort("u"),
        output=measurement.GetOutputPort("output"),
        plant_state=measurement.GetOutputPort("plant_state"),
        logged={
            "joint_state": joined.get_output_port(),
            "requested_torque": interface.GetOutputPort("requested_torque"),
            "link": subscriber.GetOutputPort("link"),
        },
    )
    limits = ArmLimits.of(model)
    return add_arm_controller(builder, scenario, limits, kinematics, measured), subscriber, timer


for _config, _remote in REMOTE_PLANTS.items():
    PLANT_BUILDERS[_remote] = add_remote_plant
