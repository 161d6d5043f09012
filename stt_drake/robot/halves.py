"""The scenario split at the robot's interface into a *station* and a *controller*.

The station (:func:`add_station`) is the plant and its drive interface (the omni base's
wheel interface, the quadrotor, the FR3's MultibodyPlant with its torque interface and the
external jerks), publishing the measured state and applying the received command, and with
perception the obstacles' truth and the sensor, publishing their detections. The split is
at the detections: the controller is the scenario's usual loop
(:func:`stt_drake.assembly.diagram.build_diagram`: tracker, tube, controller, monitor, the
arm's sequencer) around a *remote plant*: a plant builder
(:func:`add_remote_plant`) whose ports are the LCM link instead of a simulated robot. It
is registered in :data:`~stt_drake.assembly.diagram.PLANT_BUILDERS` for the
``Remote*`` plant configs of :func:`remote_scenario`, so the monitor, the run log and
metrics.json are exactly those of ``stt-drake run``.

Channels (plus the `lcm.channel_suffix`): omni robot and quadrotor ``STT_STATUS``
(:class:`stt_lcm.robot_state`) and ``STT_COMMAND`` (:class:`stt_lcm.robot_command`); the
FR3 ``PANDA_STATUS``/``PANDA_COMMAND`` (Drake's ``lcmt_panda_status``/``lcmt_panda_command``,
torque mode, through ``pydrake.manipulation``'s Panda senders and receivers), what
drake-franka-driver speaks; with perception ``STT_DETECTIONS``
(:class:`stt_lcm.obstacle_detections`) at the sensor's rate.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import numpy as np
from drake import lcmt_panda_command, lcmt_panda_status
from pydrake.lcm import DrakeLcm, DrakeLcmInterface, DrakeLcmParams
from pydrake.manipulation import (
    PandaCommandReceiver,
    PandaControlMode,
    PandaStatusSender,
)
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.lcm import (
    LcmInterfaceSystem,
    LcmPublisherSystem,
    PySerializer,
    SerializerInterface,
)
from pydrake.systems.primitives import Demultiplexer

from stt_drake.assembly.checks import initial_stage_states
from stt_drake.assembly.diagram import PlantHandles, add_fr3_robot, add_omni_robot, add_quadrotor
from stt_drake.assembly.perception import add_obstacle_sensing
from stt_drake.config import FrankaArm, Quadrotor, Scenario
from stt_drake.config.lcm import LcmConfig
from stt_drake.robot.messages import (
    CommandDecoder,
    DetectionsEncoder,
    StateEncoder,
    command_message,
    state_message,
)
from stt_drake.robot.stt_lcm import obstacle_detections, robot_command, robot_state
from stt_drake.robot.transport import (
    FilteredSubscriber,
    LinkClock,
    cpp_serializer,
)
from stt_drake.systems.crowd import CrowdSimulator
from stt_drake.systems.plants.franka import FR3_JOINTS, ArmMeasurement

#: Default channels per plant kind: (status, command).
DEFAULT_CHANNELS = {
    "stt": ("STT_STATUS", "STT_COMMAND"),
    "panda": ("PANDA_STATUS", "PANDA_COMMAND"),
}
#: How long a process waits for the other end's first message (s, wall clock).
STARTUP_TIMEOUT = 60.0
#: The arm's control mode: torque (the driver adds gravity compensation, as our interface).
PANDA_MODE = PandaControlMode.kTorque


def channels(scenario: Scenario) -> tuple[str, str]:
    """The (status, command) channel names of the scenario (its `lcm:` section's, else the
    plant's defaults: the FR3 driver's for the arm)."""
    config = scenario.lcm or LcmConfig()
    status, command = DEFAULT_CHANNELS["panda" if isinstance(scenario.plant, FrankaArm) else "stt"]
    return config.status_channel or status, config.command_channel or command


def add_bus(builder: DiagramBuilder, config: LcmConfig) -> DrakeLcm:
    """The LCM bus of `config` (a ``DrakeLcm`` of its ``DrakeLcmParams``: URL, channel
    suffix), pumped by an ``LcmInterfaceSystem`` added to `builder` (what
    ``ApplyLcmBusConfig`` does, whose bus object pydrake does not expose as a
    ``DrakeLcmInterface`` for Python subscribers)."""
    lcm = DrakeLcm(DrakeLcmParams(lcm_url=config.lcm_url, channel_suffix=config.channel_suffix))
    builder.AddNamedSystem("lcm_interface", LcmInterfaceSystem(lcm))
    return lcm


def link_clock(scenario: Scenario, two_processes: bool) -> LinkClock:
    """The clock of a link: the shared Simulator's in one process; between processes the
    wall clock, except for the FR3, whose Panda senders stamp utime with their Simulator's
    time (as the driver stamps the robot's): its ages are then this end's time minus the
    utime, the two clocks aligned within the start-up handshake (the station starts at
    the controller's first command)."""
    return LinkClock(wall=two_processes and not isinstance(scenario.plant, FrankaArm))


@dataclass
class Link:
    """One end of the link: the bus and its config, the clock its utimes are read on, and
    how long it waits at initialization for the other process (0: it does not)."""

    lcm: DrakeLcmInterface
    config: LcmConfig
    clock: LinkClock
    startup_timeout: float = 0.0

    def add_publisher(
        self,
        builder: DiagramBuilder,
        name: str,
        channel: str,
        lcm_type: type,
        cpp: bool = False,
        period: float | None = None,
        offset: float = 0.0,
    ) -> LcmPublisherSystem:
        """An ``LcmPublisherSystem`` of `lcm_type` on `channel`, every `period` seconds from
        `offset` (default: every control period; `cpp`: Drake's C++ serializer, for the
        Panda systems' messages)."""
        publisher = LcmPublisherSystem.Make(
            channel,
            lcm_type,
            self.lcm,
            publish_period=self.config.period if period is None else period,
            use_cpp_serializer=cpp,
            publish_offset=offset,
        )
        return builder.AddNamedSystem(name, publisher)

    def add_subscriber(
        self,
        builder: DiagramBuilder,
        name: str,
        channel: str,
        serializer: SerializerInterface,
        default: bytes,
        **actions: Callable,
    ) -> FilteredSubscriber:
        """A :class:`FilteredSubscriber` on `channel` ticking every control period, stale
        after the link's timeout, starting from the encoded `default` (`actions`: its
        `on_stale` and `announce`)."""
        subscriber = FilteredSubscriber(
            channel,
            serializer,
            self.lcm,
            self.config.period,
            self.config.stale_timeout,
            clock=self.clock,
            default=default,
            startup_timeout=self.startup_timeout,
            **actions,
        )
        return builder.AddNamedSystem(name, subscriber)


def safe_command(scenario: Scenario) -> np.ndarray:
    """What a stale link commands: zero velocity (omni), the weight held (quadrotor)."""
    plant = scenario.plant
    if isinstance(plant, Quadrotor):
        return np.array([0.0, 0.0, plant.mass * plant.gravity])
    return np.zeros(scenario.dimension)


def panda_status_bytes(q: np.ndarray) -> bytes:
    """An encoded lcmt_panda_status of the arm at rest at `q` (utime 0): what the
    controller starts from, and what the station announces until the first command."""
    message = lcmt_panda_status()
    message.num_joints = FR3_JOINTS
    for name in (
        "joint_position",
        "joint_position_desired",
        "joint_velocity",
        "joint_velocity_desired",
        "joint_acceleration_desired",
        "joint_torque",
        "joint_torque_desired",
        "joint_torque_external",
    ):
        setattr(message, name, [0.0] * FR3_JOINTS)
    message.joint_position = [float(v) for v in q]
    message.control_mode = PANDA_MODE
    return message.encode()


def panda_command_bytes(t: float, torque: np.ndarray) -> bytes:
    """An encoded torque-mode lcmt_panda_command of `torque` (N·m) stamped `t` (s)."""
    message = lcmt_panda_command()
    message.utime = round(t * 1e6)
    message.num_joint_torque, message.joint_torque = FR3_JOINTS, [float(v) for v in torque]
    message.control_mode_expected = PANDA_MODE
    return message.encode()


def add_station(builder: DiagramBuilder, scenario: Scenario, link: Link) -> PlantHandles:
    """The station: the scenario's plant and its interface, publishing its status every
    control period on the status channel and applying the newest command accepted from
    the command channel (a safe command before the first). With a `startup_timeout` the
    station announces its initial status until the controller's first command arrives.
    With `perception`, it also holds the truth and the sensor
    (:func:`~stt_drake.assembly.perception.add_obstacle_sensing`, ranging from its plant's
    output; the interactive crowd sees its robot) and publishes their detections on the
    detections channel at each delivery (:func:`add_detections_publisher`)."""
    status_channel, command_channel = channels(scenario)
    if isinstance(scenario.plant, FrankaArm):
        station = _add_fr3_station(builder, scenario, link, status_channel, command_channel)
    else:
        station = _add_mobile_station(builder, scenario, link, status_channel, command_channel)
    if scenario.perception is None:
        return station
    return add_detections_publisher(builder, scenario, link, station)


def add_detections_publisher(
    builder: DiagramBuilder, scenario: Scenario, link: Link, station: PlantHandles
) -> PlantHandles:
    """The station's truth and sensor, their detections published as
    ``stt_lcm.obstacle_detections`` on `lcm.detections_channel` every sensor period at
    its deliveries (offset: the sensor's latency), so a tracker updating at the same
    times reads each sample as it would in process. Returns `station` with the
    `detections` and `true_obstacle_position` ports, both (and a crowd's
    `pedestrian_active`) logged."""
    config = scenario.perception
    count, n = len(scenario.obstacles), scenario.dimension
    truth, sensor = add_obstacle_sensing(builder, scenario, station.output)
    encoder = builder.AddNamedSystem("detections_encoder", DetectionsEncoder(count, n, link.clock))
    publisher = link.add_publisher(
        builder,
        "detections_publisher",
        link.config.detections_channel,
        obstacle_detections,
        period=config.sensor_period,
        offset=config.latency,
    )
    detections = sensor.GetOutputPort("detections")
    builder.Connect(detections, encoder.GetInputPort("detections"))
    builder.Connect(encoder.GetOutputPort("obstacle_detections"), publisher.get_input_port())
    truth_port = truth.GetOutputPort("true_obstacle_position")
    logged = {"detections": detections, "true_obstacle_position": truth_port}
    if isinstance(truth, CrowdSimulator):
        logged["pedestrian_active"] = truth.GetOutputPort("pedestrian_active")
    return dataclasses.replace(
        station,
        logged={**station.logged, **logged},
        detections=detections,
        true_obstacle_position=truth_port,
    )


def _add_mobile_station(
    builder: DiagramBuilder, scenario: Scenario, link: Link, status: str, command: str
) -> PlantHandles:
    """The omni robot's or the quadrotor's station, on our robot_state/robot_command."""
    add_plant = add_quadrotor if isinstance(scenario.plant, Quadrotor) else add_omni_robot
    plant = add_plant(builder, scenario)
    y0, x0 = scenario.initial_output(), initial_stage_states(scenario).ravel()

    def announce() -> None:
        message = state_message(link.clock.idle(), y0, x0)
        link.lcm.Publish(status, message.encode(), None)

    encoder = builder.AddNamedSystem(
        "state_encoder", StateEncoder(scenario.dimension, plant.plant_state.size(), link.clock)
    )
    publisher = link.add_publisher(builder, "status_publisher", status, robot_state)
    subscriber = link.add_subscriber(
        builder,
        "command_subscriber",
        command,
        PySerializer(robot_command),
        command_message(0.0, -1, safe_command(scenario)).encode(),
        announce=announce,
    )
    decoder = builder.AddNamedSystem("command_decoder", CommandDecoder(scenario.dimension))
    builder.Connect(plant.output, encoder.GetInputPort("output"))
    builder.Connect(plant.plant_state, encoder.GetInputPort("plant_state"))
    builder.Connect(encoder.GetOutputPort("robot_state"), publisher.get_input_port())
    builder.Connect(subscriber.GetOutputPort("message"), decoder.GetInputPort("robot_command"))
    builder.Connect(decoder.GetOutputPort("control"), plant.control_input)
    received = {"control": decoder.GetOutputPort("control")}
    return dataclasses.replace(plant, logged={**plant.logged, **received})


def _add_fr3_station(
    builder: DiagramBuilder, scenario: Scenario, link: Link, status: str, command: str
) -> PlantHandles:
    """The FR3 station: the robot (:func:`~stt_drake.assembly.diagram.add_fr3_robot`:
    MultibodyPlant + SceneGraph, torque interface, external jerks) with the Panda status
    sender and command receiver (torque mode) on the driver's channels; its output is the
    TCP position (what a sensor on the station ranges from)."""
    robot = add_fr3_robot(builder, scenario)
    plant, interface = robot.plant, robot.interface
    q0 = np.asarray(scenario.plant.initial_configuration, dtype=float)
    split = builder.AddNamedSystem("joint_state_split", Demultiplexer([FR3_JOINTS, FR3_JOINTS]))
    sender = builder.AddNamedSystem("panda_status_sender", PandaStatusSender(FR3_JOINTS))
    publisher = link.add_publisher(builder, "status_publisher", status, lcmt_panda_status, cpp=True)
    subscriber = link.add_subscriber(
        builder,
        "command_subscriber",
        command,
        cpp_serializer(lcmt_panda_command),
        panda_command_bytes(0.0, np.zeros(FR3_JOINTS)),
        announce=partial(link.lcm.Publish, status, panda_status_bytes(q0), None),
    )
    receiver = builder.AddNamedSystem(
        "panda_command_receiver", PandaCommandReceiver(FR3_JOINTS, PANDA_MODE)
    )
    measurement = builder.AddNamedSystem("fr3_tcp", ArmMeasurement(plant))
    state = plant.get_state_output_port()
    builder.Connect(state, split.get_input_port())
    builder.Connect(state, measurement.GetInputPort("state"))
    builder.Connect(plant.get_body_poses_output_port(), measurement.GetInputPort("body_poses"))
    builder.Connect(split.get_output_port(0), sender.get_position_measured_input_port())
    builder.Connect(split.get_output_port(1), sender.get_velocity_measured_input_port())
    builder.Connect(split.get_output_port(0), receiver.get_position_measured_input_port())
    builder.Connect(
        receiver.get_commanded_torque_output_port(), sender.get_torque_commanded_input_port()
    )
    builder.Connect(interface.GetOutputPort("actuation"), sender.get_torque_measured_input_port())
    builder.Connect(sender.get_output_port(), publisher.get_input_port())
    builder.Connect(subscriber.GetOutputPort("message"), receiver.get_message_input_port())
    builder.Connect(
        receiver.get_commanded_torque_output_port(), interface.GetInputPort("torque_command")
    )
    return PlantHandles(
        plant=plant,
        control_input=receiver.get_message_input_port(),
        output=measurement.GetOutputPort("output"),
        plant_state=state,
        logged=robot.logged,
    )
