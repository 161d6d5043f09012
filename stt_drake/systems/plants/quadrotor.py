"""UAV (case study 2): a quadrotor as a second-order point mass in 3D.

State x = [p (3), v (3)] (the stage states x_1 = p, x_2 = v of Eq. (1), N = 2):

    ṗ = v,
    m·v̇ = u − m·g·e_z − c_d·v + w(t),

where u ∈ R³ is the commanded force (N) — the thrust vector an attitude loop realises — and
w(t) a bounded wind force (N). In the pure-feedback form of Eq. (1): f_1 = 0,
g_1 = I, f_2 = −g e_z − (c_d/m) v, g_2 = I/m (positive definite, Assumption 2), w_2 = w/m.
The true mass m, drag coefficient c_d and gravity g live only here: the STT controller
reads the measured stage states [p, v] and nothing else.
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import Adder, AffineSystem, MatrixGain


class Quadrotor(Diagram):
    """Second-order UAV. Inputs `control` (force u, 3, N) and `disturbance` (wind force w,
    3, N); outputs `output` = y = p (3), `plant_state` = [p, v] (6, the stacked stage
    states the controller measures) and `state` = [p, v] (6).

    Built from Drake's compiled primitives, so the simulation never calls Python for it: an
    `Adder` (u + w) feeds an `AffineSystem` ẋ = A x + B (u + w) + f₀ with
    A = [[0, I], [0, −(c_d/m) I]], B = [0; I/m], f₀ = [0; −g e_z] and output x, and a
    `MatrixGain` [I 0] selects p."""

    def __init__(
        self,
        mass: float,
        drag: float,
        gravity: float,
        initial_position: np.ndarray,
        initial_velocity: np.ndarray,
    ) -> None:
        super().__init__()
        if mass <= 0.0 or drag < 0.0 or gravity < 0.0:
            raise ValueError(
                f"Quadrotor: need mass > 0, drag ≥ 0, gravity ≥ 0 (got {mass}, {drag}, {gravity})"
            )
        initial = np.concatenate(
            [np.asarray(initial_position, dtype=float), np.asarray(initial_velocity, dtype=float)]
        )
        if initial.shape != (6,):
            raise ValueError("Quadrotor: initial position and velocity need 3 entries each")
        identity, zero = np.eye(3), np.zeros((3, 3))
        dynamics = np.block([[zero, identity], [zero, -(float(drag) / float(mass)) * identity]])
        input_gain = np.vstack([zero, identity / float(mass)])
        constant = np.array([0.0, 0.0, 0.0, 0.0, 0.0, -float(gravity)])
        builder = DiagramBuilder()
        force = builder.AddNamedSystem("force", Adder(2, 3))
        body = builder.AddNamedSystem(
            "point_mass",
            AffineSystem(dynamics, input_gain, constant, np.eye(6), np.zeros((6, 3)), np.zeros(6)),
        )
        body.configure_default_state(initial)
        position = builder.AddNamedSystem("position", MatrixGain(np.hstack([identity, zero])))
        builder.Connect(force.get_output_port(), body.get_input_port())
        builder.Connect(body.get_output_port(), position.get_input_port())
        builder.ExportInput(force.get_input_port(0), "control")
        builder.ExportInput(force.get_input_port(1), "disturbance")
        builder.ExportOutput(position.get_output_port(), "output")
        builder.ExportOutput(body.get_output_port(), "plant_state")
        builder.ExportOutput(body.get_output_port(), "state")
        builder.BuildInto(self)
