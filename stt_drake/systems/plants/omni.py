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

import math

import numpy as np
from pydrake.systems.framework import (
    BasicVector,
    Context,
    ContinuousState,
    ContinuousStateIndex,
    Diagram,
    DiagramBuilder,
    LeafSystem,
)
from pydrake.systems.primitives import MatrixGain

#: Wheel mounting angles around the base (rad).
WHEEL_ANGLES = np.array([0.0, 2.0 * np.pi / 3.0, 4.0 * np.pi / 3.0])


def wheel_matrix(wheel_radius: float, base_radius: float) -> np.ndarray:
    """M with wheel speeds ω = M [v_bx, v_by, ψ̇]: rim speed −sin α v_x + cos α v_y + L ψ̇."""
    return (
        np.column_stack([-np.sin(WHEEL_ANGLES), np.cos(WHEEL_ANGLES), np.full(3, base_radius)])
        / wheel_radius
    )


def _rows_times(
    rows: tuple[tuple[float, ...], ...], x: float, y: float, z: float
) -> tuple[float, float, float]:
    """The 3 × 3 matrix `rows` times (x, y, z) in Python floats: for 3-vectors, cheaper than
    numpy's per-call overhead (the plant's and the drive interface's hot paths)."""
    (a0, a1, a2), (b0, b1, b2), (c0, c1, c2) = rows
    return a0 * x + a1 * y + a2 * z, b0 * x + b1 * y + b2 * z, c0 * x + c1 * y + c2 * z


def rotation(heading: float) -> np.ndarray:
    """2D rotation from body to world frame."""
    c, s = np.cos(heading), np.sin(heading)
    return np.array([[c, -s], [s, c]])


class OmniKinematics(LeafSystem):
    """The true kinematics: state [x, y, ψ]; inputs `wheel_speeds` (3, rad/s) and
    `disturbance` (2, world-frame velocity, m/s); output `pose` = (x, y, ψ)."""

    def __init__(
        self,
        wheel_radius: float,
        base_radius: float,
        initial_position: np.ndarray,
        initial_heading: float = 0.0,
    ) -> None:
        super().__init__()
        twist_from_wheels = np.linalg.inv(wheel_matrix(wheel_radius, base_radius))
        self._twist_rows = tuple(tuple(row) for row in twist_from_wheels.tolist())
        self.DeclareContinuousState(BasicVector(np.append(initial_position, initial_heading)))
        self._wheel_port = self.DeclareVectorInputPort("wheel_speeds", 3)
        self._disturbance_port = self.DeclareVectorInputPort("disturbance", 2)
        self.DeclareStateOutputPort("pose", ContinuousStateIndex(0))

    def DoCalcTimeDerivatives(  # noqa: N802 (Drake API)
        self, context: Context, derivatives: ContinuousState
    ) -> None:
        # Scalar Python arithmetic on 3-vectors, and as few pybind calls as can be: cheaper
        # than numpy's per-call overhead.
        heading = context.get_continuous_state_vector()[2]
        v_x, v_y, yaw_rate = _rows_times(self._twist_rows, *self._wheel_port.Eval(context).tolist())
        d_x, d_y = self._disturbance_port.Eval(context).tolist()
        c, s = math.cos(heading), math.sin(heading)  # world velocity = R(ψ) body velocity
        derivatives.SetFromVector([c * v_x - s * v_y + d_x, s * v_x + c * v_y + d_y, yaw_rate])


class OmniRobot(Diagram):
    """State [x, y, ψ]; inputs `wheel_speeds` (3, rad/s) and `disturbance` (2, world-frame
    velocity, m/s); outputs `output` = y = (x, y), `plant_state` = x_1 = (x, y) (the stage
    states the controller measures) and `pose` = (x, y, ψ).

    :class:`OmniKinematics` holds the state; (x, y) is selected from its pose by Drake's
    compiled `MatrixGain`, so reading the position never calls Python."""

    def __init__(
        self,
        wheel_radius: float,
        base_radius: float,
        initial_position: np.ndarray,
        initial_heading: float = 0.0,
    ) -> None:
        super().__init__()
        builder = DiagramBuilder()
        kinematics = builder.AddNamedSystem(
            "kinematics",
            OmniKinematics(wheel_radius, base_radius, initial_position, initial_heading),
        )
        position = builder.AddNamedSystem("position", MatrixGain(np.eye(2, 3)))
        pose = kinematics.GetOutputPort("pose")
        builder.Connect(pose, position.get_input_port())
        for name in ("wheel_speeds", "disturbance"):
            builder.ExportInput(kinematics.GetInputPort(name), name)
        builder.ExportOutput(position.get_output_port(), "output")
        builder.ExportOutput(position.get_output_port(), "plant_state")
        builder.ExportOutput(pose, "pose")
        builder.BuildInto(self)


class OmniDriveInterface(LeafSystem):
    """The base's twist interface: inputs `velocity_command` (2, world frame, m/s) and
    `pose` (3); output `wheel_speeds` (3) from the nominal kinematics, with the heading held
    at `heading_reference` by ψ̇ = −heading_gain·wrap(ψ − heading_reference)."""

    def __init__(
        self,
        nominal_wheel_radius: float,
        nominal_base_radius: float,
        heading_gain: float,
        heading_reference: float = 0.0,
    ) -> None:
        super().__init__()
        self._wheels_from_twist = wheel_matrix(nominal_wheel_radius, nominal_base_radius)
        self._wheel_rows = tuple(tuple(row) for row in self._wheels_from_twist.tolist())
        self._heading_gain = heading_gain
        self._heading_reference = heading_reference
        self._command_port = self.DeclareVectorInputPort("velocity_command", 2)
        self._pose_port = self.DeclareVectorInputPort("pose", 3)
        self.DeclareVectorOutputPort("wheel_speeds", 3, self._calc_wheel_speeds)

    def _calc_wheel_speeds(self, context: Context, output: BasicVector) -> None:
        # Scalar Python arithmetic on Python floats: cheaper than numpy's per-call overhead.
        u_x, u_y = self._command_port.Eval(context).tolist()
        heading = self._pose_port.Eval(context).tolist()[2]
        difference = heading - self._heading_reference
        heading_error = math.atan2(math.sin(difference), math.cos(difference))  # to (−π, π]
        c, s = math.cos(heading), math.sin(heading)  # body velocity = R(ψ)ᵀ command
        v_x, v_y = c * u_x + s * u_y, -s * u_x + c * u_y
        yaw_rate = -self._heading_gain * heading_error
        output.SetFromVector(_rows_times(self._wheel_rows, v_x, v_y, yaw_rate))
