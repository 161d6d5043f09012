"""Three-wheel omnidirectional robot (case study 1) and its drive interface.

The STT controller outputs a world-frame velocity u ∈ R² (N = 1 stage). A real base exposes
a velocity (twist) interface; :class:`OmniDriveInterface` is that interface: it maps u to
wheel speeds with the *nominal* wheel and base radii, and holds the heading with its own
proportional stabiliser (the heading is not part of the output space). The plant
:class:`OmniRobot` integrates the *true* kinematics, which differ from the nominal ones, plus
an additive velocity disturbance. The closed loop therefore sees ẏ = g·u + w with an
unknown g (= true/nominal wheel radius ratio) and unknown w — the pure-feedback form of
Eq. (1) that the controller must handle without knowing either.
"""

from __future__ import annotations

import numpy as np
from pydrake.symbolic import Expression, MakeVectorVariable, atan2, cos, sin
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import MatrixGain, Multiplexer, SymbolicVectorSystem

#: Wheel mounting angles around the base (rad).
WHEEL_ANGLES = np.array([0.0, 2.0 * np.pi / 3.0, 4.0 * np.pi / 3.0])


def wheel_matrix(wheel_radius: float, base_radius: float) -> np.ndarray:
    """M with wheel speeds ω = M [v_bx, v_by, ψ̇]: rim speed −sin α v_x + cos α v_y + L ψ̇."""
    return (
        np.column_stack([-np.sin(WHEEL_ANGLES), np.cos(WHEEL_ANGLES), np.full(3, base_radius)])
        / wheel_radius
    )


def _times(matrix: np.ndarray, values: list) -> list[Expression]:
    """`matrix` (floats) times symbolic `values`, in Python arithmetic: numpy's object-dtype
    operations report the floating-point flags Drake's symbolic arithmetic leaves set, as
    an 'invalid value' warning (an error under the tests' warning filter)."""
    return [
        sum(weight * value for weight, value in zip(row, values, strict=True))
        for row in matrix.tolist()
    ]


def _inputs_of(
    builder: DiagramBuilder, sizes: list[int], names: list[str]
) -> tuple[Multiplexer, list[np.ndarray]]:
    """A `Multiplexer` named "inputs" of vector inputs exported as `names`, and a vector of
    symbolic variables for each (a SymbolicVectorSystem has one input port)."""
    inputs = builder.AddNamedSystem("inputs", Multiplexer(sizes))
    for index, name in enumerate(names):
        builder.ExportInput(inputs.get_input_port(index), name)
    return inputs, [MakeVectorVariable(size, name) for size, name in zip(sizes, names, strict=True)]


class OmniRobot(Diagram):
    """The true kinematics: state [x, y, ψ] less the initial pose; inputs `wheel_speeds` (3,
    rad/s) and `disturbance` (2, world-frame velocity, m/s); outputs `output` = y = (x, y),
    `plant_state` = x_1 = (x, y) (the stage states the controller measures) and `pose` =
    (x, y, ψ).

    Every part is a Drake primitive evaluated in C++, so a derivative evaluation or a reading
    of the position never calls Python: a `Multiplexer` of the two inputs, the kinematics
    ẋ = R(ψ) T ω + w (T = M⁻¹ of the true wheels) as a `SymbolicVectorSystem` named
    "kinematics", and a `MatrixGain` selecting (x, y). Its state is the displacement from the
    initial pose (a SymbolicVectorSystem's default state is zero; its output adds the pose
    back), so the default context starts at the initial pose."""

    def __init__(
        self,
        wheel_radius: float,
        base_radius: float,
        initial_position: np.ndarray,
        initial_heading: float = 0.0,
    ) -> None:
        super().__init__()
        builder = DiagramBuilder()
        inputs, (wheel_speeds, disturbance) = _inputs_of(
            builder, [3, 2], ["wheel_speeds", "disturbance"]
        )
        displacement = MakeVectorVariable(3, "displacement")
        start = [*np.asarray(initial_position, dtype=float).tolist(), float(initial_heading)]
        pose = [moved + value for moved, value in zip(displacement, start, strict=True)]
        twist_from_wheels = np.linalg.inv(wheel_matrix(wheel_radius, base_radius))
        v_x, v_y, yaw_rate = _times(twist_from_wheels, list(wheel_speeds))
        c, s = cos(pose[2]), sin(pose[2])  # world velocity = R(ψ) body velocity
        rate = [c * v_x - s * v_y + disturbance[0], s * v_x + c * v_y + disturbance[1], yaw_rate]
        kinematics = builder.AddNamedSystem(
            "kinematics",
            SymbolicVectorSystem(
                state=displacement,
                input=np.concatenate([wheel_speeds, disturbance]),
                dynamics=rate,
                output=pose,
            ),
        )
        position = builder.AddNamedSystem("position", MatrixGain(np.eye(2, 3)))
        builder.Connect(inputs.get_output_port(), kinematics.get_input_port())
        builder.Connect(kinematics.get_output_port(), position.get_input_port())
        builder.ExportOutput(position.get_output_port(), "output")
        builder.ExportOutput(position.get_output_port(), "plant_state")
        builder.ExportOutput(kinematics.get_output_port(), "pose")
        builder.BuildInto(self)


class OmniDriveInterface(Diagram):
    """The base's twist interface: inputs `velocity_command` (2, world frame, m/s) and
    `pose` (3); output `wheel_speeds` (3) from the nominal kinematics, with the heading held
    at `heading_reference` by ψ̇ = −heading_gain·wrap(ψ − heading_reference).

    Drake primitives evaluated in C++: a `Multiplexer` of the inputs and the map as a
    `SymbolicVectorSystem` named "wheels". That system carries one constant state (its
    derivative is 0): Drake asks every subsystem of a continuous Diagram for its time
    derivatives, and a SymbolicVectorSystem without dynamics aborts the process there (a
    DRAKE_DEMAND, not an exception)."""

    def __init__(
        self,
        nominal_wheel_radius: float,
        nominal_base_radius: float,
        heading_gain: float,
        heading_reference: float = 0.0,
    ) -> None:
        super().__init__()
        builder = DiagramBuilder()
        inputs, (command, pose) = _inputs_of(builder, [2, 3], ["velocity_command", "pose"])
        difference = pose[2] - heading_reference
        heading_error = atan2(sin(difference), cos(difference))  # wrapped to (−π, π]
        c, s = cos(pose[2]), sin(pose[2])  # body velocity = R(ψ)ᵀ command
        twist = [
            c * command[0] + s * command[1],
            -s * command[0] + c * command[1],
            -heading_gain * heading_error,
        ]
        constant = MakeVectorVariable(1, "constant")
        wheels = builder.AddNamedSystem(
            "wheels",
            SymbolicVectorSystem(
                state=constant,
                input=np.concatenate([command, pose]),
                dynamics=[Expression(0.0)],
                output=_times(wheel_matrix(nominal_wheel_radius, nominal_base_radius), twist),
            ),
        )
        builder.Connect(inputs.get_output_port(), wheels.get_input_port())
        builder.ExportOutput(wheels.get_output_port(), "wheel_speeds")
        builder.BuildInto(self)
