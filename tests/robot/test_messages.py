"""Our LCM messages: generated code that needs only the standard library, encoder/decoder
round trips, and the Panda status/command round trip through Drake's Panda systems."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
from drake import lcmt_panda_command, lcmt_panda_status
from pydrake.lcm import DrakeLcm
from pydrake.manipulation import PandaCommandReceiver, PandaStatusReceiver
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from stt_drake.robot.halves import PANDA_MODE, panda_command_bytes, panda_status_bytes
from stt_drake.robot.messages import (
    command_message,
    detections_message,
    detections_vector,
    state_message,
)
from stt_drake.robot.stt_lcm import obstacle_detections, robot_command, robot_state
from stt_drake.robot.transport import FilteredSubscriber, LinkClock, cpp_serializer, message_utime

ROOT = Path(__file__).resolve().parents[2]
GENERATED = ROOT / "stt_drake" / "robot" / "stt_lcm"


def test_generated_messages_import_only_the_standard_library():
    """The lcm-gen output (committed) imports io and struct and its own package only, so
    the runtime needs no `lcm` package; one .lcm file per generated type."""
    imported = set()
    for path in GENERATED.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                imported |= {alias.name.split(".")[0] for alias in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                imported.add(node.module.split(".")[0])
    assert imported <= {"io", "struct"}
    types = {p.stem for p in GENERATED.glob("*.py")} - {"__init__"}
    sources = {p.stem.removeprefix("stt_lcm_") for p in (ROOT / "lcmtypes").glob("*.lcm")}
    assert types == sources == {"robot_state", "robot_command", "obstacle_detections"}


def test_messages_round_trip_and_carry_their_utime():
    state = state_message(1.25, np.array([0.5, -1.0]), np.array([0.5, -1.0, 2.0, 3.0]))
    decoded = robot_state.decode(state.encode())
    assert decoded.utime == message_utime(state.encode()) == 1_250_000
    assert list(decoded.plant_state) == [0.5, -1.0, 2.0, 3.0]
    command = robot_command.decode(command_message(2.0, 1_990_000, np.array([0.1, 0.2])).encode())
    assert (command.utime, command.status_utime, list(command.control)) == (
        2_000_000,
        1_990_000,
        [0.1, 0.2],
    )


def test_detections_round_trip_the_sensor_vector():
    """[position (n), detected, stamp] per slot → obstacle_detections → the same vector
    (−inf stamps of slots never sampled included)."""
    count, n = 3, 2
    vector = np.array([1.0, 2.0, 1.0, 0.4, 0.0, 0.0, 0.0, -np.inf, -3.0, 0.5, 1.0, 0.45])
    message = obstacle_detections.decode(detections_message(0.5, vector, count, n).encode())
    assert message.utime == 500_000 and list(message.id) == [0, 1, 2]
    np.testing.assert_array_equal(detections_vector(message, count, n), vector)


def test_panda_status_and_command_round_trip_through_the_panda_systems():
    """lcmt_panda_status/command bytes (the FR3 driver's) through our filtered subscriber
    with Drake's C++ serializer into PandaStatusReceiver and PandaCommandReceiver."""
    lcm = DrakeLcm("memq://")
    q = np.linspace(-0.3, 0.3, 7)
    builder = DiagramBuilder()
    status = builder.AddSystem(
        FilteredSubscriber(
            "PANDA_STATUS", cpp_serializer(lcmt_panda_status), lcm, 0.01, 1.0, clock=LinkClock()
        )
    )
    command = builder.AddSystem(
        FilteredSubscriber(
            "PANDA_COMMAND", cpp_serializer(lcmt_panda_command), lcm, 0.01, 1.0, clock=LinkClock()
        )
    )
    status_receiver = builder.AddSystem(PandaStatusReceiver(7))
    command_receiver = builder.AddSystem(PandaCommandReceiver(7, PANDA_MODE))
    builder.Connect(status.GetOutputPort("message"), status_receiver.get_input_port())
    builder.Connect(command.GetOutputPort("message"), command_receiver.get_message_input_port())
    builder.ExportInput(command_receiver.get_position_measured_input_port(), "q")
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    diagram.get_input_port().FixValue(context, q)
    simulator.Initialize()
    lcm.Publish("PANDA_STATUS", panda_status_bytes(q), None)
    lcm.Publish("PANDA_COMMAND", panda_command_bytes(0.005, np.arange(7.0)), None)
    simulator.AdvanceTo(0.011)
    position = status_receiver.get_position_measured_output_port().Eval(
        status_receiver.GetMyContextFromRoot(context)
    )
    torque = command_receiver.get_commanded_torque_output_port().Eval(
        command_receiver.GetMyContextFromRoot(context)
    )
    np.testing.assert_array_equal(position, q)
    np.testing.assert_array_equal(torque, np.arange(7.0))
