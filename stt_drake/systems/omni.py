"""Three-wheel omnidirectional robot (case study 1) and its drive interface.

The STT controller outputs a world-frame velocity u ∈ R² (N = 1 stage). A real base exposes
a velocity (twist) interface; :class:`OmniDriveInterface` is that interface: it maps u to
wheel speeds with the *nominal* wheel and base radii, and holds the heading with its own
proportional stabiliser (the heading is not part of the output space). The plant
:class:`OmniRobot` integrates the *true* kinematics, which differ from the nominal ones, plus
an additive velocity disturbance. The closed loop therefore sees ẏ = g·u + w with an
unknown g (= true/nominal wheel radius ratio) and unknown w — the pure-feedback form of
eq. (sysdyn) that the controller must handle without knowing either.
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import (
    BasicVector,
    Context,
    ContinuousState,
    ContinuousStateIndex,
    LeafSystem,
)

#: Wheel mounting angles around the base (rad).
WHEEL_ANGLES = np.array([0.0, 2.0 * np.pi / 3.0, 4.0 * np.pi / 3.0])


def wheel_matrix(wheel_radius: float, base_radius: float) -> np.ndarray:
    """M with wheel speeds ω = M [v_bx, v_by, ψ̇]: rim speed −sin α v_x + cos α v_y + L ψ̇."""
    return (
        np.column_stack([-np.sin(WHEEL_ANGLES), np.cos(WHEEL_ANGLES), np.full(3, base_radius)])
        / wheel_radius
    )


def rotation(heading: float) -> np.ndarray:
    """2D rotation from body to world frame."""
    c, s = np.cos(heading), np.sin(heading)
    return np.array([[c, -s], [s, c]])


class OmniRobot(LeafSystem):
    """State [x, y, ψ]; inputs `wheel_speeds` (3, rad/s) and `disturbance` (2, world-frame
    velocity, m/s); outputs `output` = y = (x, y), `plant_state` = x_1 = (x, y) (the stage
    states the controller measures) and `pose` = (x, y, ψ)."""

    def __init__(
        self,
        wheel_radius: float,
        base_radius: float,
        initial_position: np.ndarray,
        initial_heading: float = 0.0,
    ) -> None:
        super().__init__()
        self.set_name("omni_robot")
        self._twist_from_wheels = np.linalg.inv(wheel_matrix(wheel_radius, base_radius))
        self.DeclareContinuousState(BasicVector(np.append(initial_position, initial_heading)))
        self.DeclareVectorInputPort("wheel_speeds", 3)
        self.DeclareVectorInputPort("disturbance", 2)
        state_only = {self.xc_ticket()}
        for name, size in (("output", 2), ("plant_state", 2)):
            self.DeclareVectorOutputPort(
                name, size, self._calc_position, prerequisites_of_calc=state_only
            )
        self.DeclareStateOutputPort("pose", ContinuousStateIndex(0))

    def _calc_position(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(context.get_continuous_state_vector().CopyToVector()[:2])

    def DoCalcTimeDerivatives(  # noqa: N802 (Drake API)
        self, context: Context, derivatives: ContinuousState
    ) -> None:
        pose = context.get_continuous_state_vector().CopyToVector()
        twist = self._twist_from_wheels @ self.get_input_port(0).Eval(context)
        velocity = rotation(pose[2]) @ twist[:2] + self.get_input_port(1).Eval(context)
        derivatives.get_mutable_vector().SetFromVector(np.append(velocity, twist[2]))


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
        self.set_name("omni_drive_interface")
        self._wheels_from_twist = wheel_matrix(nominal_wheel_radius, nominal_base_radius)
        self._heading_gain = heading_gain
        self._heading_reference = heading_reference
        self.DeclareVectorInputPort("velocity_command", 2)
        self.DeclareVectorInputPort("pose", 3)
        self.DeclareVectorOutputPort("wheel_speeds", 3, self._calc_wheel_speeds)

    def _calc_wheel_speeds(self, context: Context, output: BasicVector) -> None:
        command = self.get_input_port(0).Eval(context)
        heading = self.get_input_port(1).Eval(context)[2]
        heading_error = np.angle(np.exp(1j * (heading - self._heading_reference)))
        body_velocity = rotation(heading).T @ command
        twist = np.append(body_velocity, -self._heading_gain * heading_error)
        output.SetFromVector(self._wheels_from_twist @ twist)
