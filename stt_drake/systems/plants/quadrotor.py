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
from pydrake.systems.framework import (
    BasicVector,
    Context,
    ContinuousState,
    ContinuousStateIndex,
    LeafSystem,
)


class Quadrotor(LeafSystem):
    """Second-order UAV. Inputs `control` (force u, 3, N) and `disturbance` (wind force w,
    3, N); outputs `output` = y = p (3), `plant_state` = [p, v] (6, the stacked stage
    states the controller measures) and `state` = [p, v] (6)."""

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
        self._mass = float(mass)
        self._drag = float(drag)
        self._weight = np.array([0.0, 0.0, self._mass * float(gravity)])
        initial = np.concatenate(
            [np.asarray(initial_position, dtype=float), np.asarray(initial_velocity, dtype=float)]
        )
        if initial.shape != (6,):
            raise ValueError("Quadrotor: initial position and velocity need 3 entries each")
        self.DeclareContinuousState(BasicVector(initial), num_q=3, num_v=3, num_z=0)
        self._control_port = self.DeclareVectorInputPort("control", 3)
        self._disturbance_port = self.DeclareVectorInputPort("disturbance", 3)
        self.DeclareVectorOutputPort(
            "output", 3, self._calc_position, prerequisites_of_calc={self.xc_ticket()}
        )
        self.DeclareStateOutputPort("plant_state", ContinuousStateIndex(0))
        self.DeclareStateOutputPort("state", ContinuousStateIndex(0))

    def _calc_position(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(context.get_continuous_state_vector().CopyToVector()[:3])

    def DoCalcTimeDerivatives(  # noqa: N802 (Drake API)
        self, context: Context, derivatives: ContinuousState
    ) -> None:
        state = context.get_continuous_state_vector().CopyToVector()
        velocity = state[3:]
        force = (
            self._control_port.Eval(context)
            + self._disturbance_port.Eval(context)
            - self._weight
            - self._drag * velocity
        )
        derivatives.get_mutable_vector().SetFromVector(
            np.concatenate([velocity, force / self._mass])
        )
