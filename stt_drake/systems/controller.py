"""STTController: the closed-form funnel law of Sec. 4 as a stateless Drake system."""

from __future__ import annotations

from pydrake.systems.framework import BasicVector, Context, LeafSystem

from stt_drake.core.control import FunnelController


class STTController(LeafSystem):
    """Inputs `tube` = [c, r] and `plant_state` = [x_1; ...; x_N] (measured stage states);
    output `control` = u (n). Direct feedthrough, no state, no plant parameter."""

    def __init__(self, controller: FunnelController, dimension: int) -> None:
        super().__init__()
        self._controller = controller
        self._dimension = dimension
        self._tube_port = self.DeclareVectorInputPort("tube", dimension + 1)
        self._state_port = self.DeclareVectorInputPort("plant_state", controller.stages * dimension)
        self.DeclareVectorOutputPort("control", dimension, self._calc_control)

    def _calc_control(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(
            self._controller.control_from_tube(
                context.get_time(), self._state_port.Eval(context), self._tube_port.Eval(context)
            )
        )
