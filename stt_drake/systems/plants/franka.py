"""Franka Research 3 arm (case study 3): model loading and the arm's Drake systems.

The simulated robot is a continuous-time ``MultibodyPlant`` (joint torque actuation) built
from ``models/franka_fr3.urdf``. Around it:

* :class:`ArmRobotInterface` — the FR3's torque interface: like the real robot, which
  compensates gravity internally (libfranka's torque commands exclude gravity), it adds
  g(q) from the *robot's own* model to the commanded torque and saturates at the effort
  limits. Compensation can be switched off: the STT controller does not rely on it.
* :class:`ArmMeasurement` — the measured TCP position y (the tube's output space) and the
  stacked controller input [y, q, q̇].
* :class:`ArmSTTController` — the funnel law of :mod:`stt_drake.core.arm`; the only model
  it holds is the arm's kinematics (:class:`ArmKinematics`, for the Jacobian).
* :class:`ExternalJerks` — short impulsive wrenches on arm links at given times.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from importlib.resources import files
from pathlib import Path

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.multibody.math import SpatialForce
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import (
    ExternallyAppliedSpatialForce_,
    MultibodyPlant,
)
from pydrake.multibody.tree import BodyIndex, JacobianWrtVariable, ModelInstanceIndex
from pydrake.systems.framework import (
    BasicVector,
    Context,
    LeafSystem,
    ValueProducer,
)

from stt_drake.core.arm import ArmFunnelLaw

#: The FR3 description written for this project (see the header of the file for sources),
#: shipped in the package as ``stt_drake.models`` (the repository's models/ folder). An
#: installed wheel is unpacked, so the resource is a file Drake's Parser can open.
FR3_MODEL = Path(str(files("stt_drake.models") / "franka_fr3.urdf"))
#: libfranka's start ("ready") configuration, rad.
FR3_HOME = np.array([0.0, -np.pi / 4, 0.0, -3 * np.pi / 4, 0.0, np.pi / 2, np.pi / 4])
#: Frame whose origin is the end-effector point y: the Franka Hand's TCP.
FR3_TCP = "fr3_hand_tcp"
FR3_JOINTS = 7
#: Links an external jerk may act on.
FR3_LINKS = (*(f"fr3_link{i}" for i in range(1, 8)), "fr3_hand")


def add_fr3(plant: MultibodyPlant) -> ModelInstanceIndex:
    """Parse the FR3 (welded to the world at its base) into `plant` (not finalised)."""
    if not FR3_MODEL.is_file():
        raise FileNotFoundError(f"FR3 model not found at {FR3_MODEL}")
    (instance,) = Parser(plant).AddModels(str(FR3_MODEL))
    return instance


def make_fr3_plant() -> MultibodyPlant:
    """A finalised stand-alone continuous-time FR3 plant (no SceneGraph): the robot's own
    model for its gravity compensation, or a kinematic model for the controller."""
    plant = MultibodyPlant(time_step=0.0)
    add_fr3(plant)
    plant.Finalize()
    return plant


class ArmKinematics:
    """TCP position and translational Jacobian of the arm for a configuration q.

    Uses only the kinematic tree of the model (frames and joint axes), on a private scratch
    context that every call overwrites (so one instance serves one thread).
    """

    def __init__(self, plant: MultibodyPlant | None = None) -> None:
        self._plant = plant if plant is not None else make_fr3_plant()
        self._context = self._plant.CreateDefaultContext()
        self._tcp = self._plant.GetFrameByName(FR3_TCP)
        self._world = self._plant.world_frame()
        self._origin = np.zeros(3)

    @property
    def plant(self) -> MultibodyPlant:
        """The model (used for its kinematics only)."""
        return self._plant

    def position(self, q: np.ndarray) -> np.ndarray:
        """TCP position in the world (m)."""
        self._plant.SetPositions(self._context, q)
        return self._plant.CalcPointsPositions(
            self._context, self._tcp, self._origin, self._world
        ).ravel()

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """(3, 7) J(q) with ẏ = J(q) q̇ (TCP translational velocity in the world)."""
        self._plant.SetPositions(self._context, q)
        return self._plant.CalcJacobianTranslationalVelocity(
            self._context, JacobianWrtVariable.kV, self._tcp, self._origin, self._world, self._world
        )


def fr3_lever_arm_bounds() -> np.ndarray:
    """ℓ_i (m), i = 1..7: upper bounds of the distance from joint i's axis to the TCP in any
    configuration, so ‖J(q) e‖ ≤ Σ_i ℓ_i |e_i| for every q: the sum of the fixed distances
    along the chain from joint i's origin to the next joint origins and on to the TCP."""
    plant = make_fr3_plant()
    context = plant.CreateDefaultContext()
    origins = [
        plant.GetJointByName(f"fr3_joint{i}")
        .frame_on_child()
        .CalcPoseInWorld(context)
        .translation()
        for i in range(1, FR3_JOINTS + 1)
    ]
    origins.append(plant.GetFrameByName(FR3_TCP).CalcPoseInWorld(context).translation())
    hops = np.linalg.norm(np.diff(np.array(origins), axis=0), axis=1)
    return np.cumsum(hops[::-1])[::-1]


def _cache(system: LeafSystem, description: str, calc: object, tickets: set) -> object:
    """Declare a cache entry holding any Python object, computed by `calc`."""
    return system.DeclareCacheEntry(
        description=description,
        value_producer=ValueProducer(allocate=AbstractValue.Make(object()).Clone, calc=calc),
        prerequisites_of_calc=tickets,
    )


class ArmRobotInterface(LeafSystem):
    """The robot side of the torque interface.

    Inputs `torque_command` (7, N·m, what the controller sends) and `state` ([q, q̇], 14).
    Outputs `actuation` = sat(τ_cmd + g_c(q)) for the plant and `requested_torque` =
    τ_cmd + g_c(q) before saturation (what the limits are checked on), where g_c(q) =
    −(generalised gravity force) of the robot's own model when `gravity_compensation`,
    else 0. Saturation is at ± the effort limits.
    """

    def __init__(self, model: MultibodyPlant, gravity_compensation: bool) -> None:
        super().__init__()
        self._model = model
        self._model_context = model.CreateDefaultContext()
        self._compensate = gravity_compensation
        self._effort = model.GetEffortUpperLimits()
        self._lower = -self._effort
        self._command = self.DeclareVectorInputPort("torque_command", FR3_JOINTS)
        self._state = self.DeclareVectorInputPort("state", 2 * FR3_JOINTS)
        self._requested = _cache(
            self, "requested torque", self._calc_requested, {self.all_input_ports_ticket()}
        )
        depends = {self._requested.ticket()}
        self.DeclareVectorOutputPort(
            "actuation",
            FR3_JOINTS,
            # the array's clip method: a third of np.clip's call cost, same values
            lambda context, output: output.SetFromVector(
                self._requested.Eval(context).clip(self._lower, self._effort)
            ),
            prerequisites_of_calc=depends,
        )
        self.DeclareVectorOutputPort(
            "requested_torque",
            FR3_JOINTS,
            lambda context, output: output.SetFromVector(self._requested.Eval(context)),
            prerequisites_of_calc=depends,
        )

    def gravity_torque(self, q: np.ndarray) -> np.ndarray:
        """g_c(q): the torque that holds the arm still against gravity (robot's model)."""
        self._model.SetPositions(self._model_context, q)
        return -self._model.CalcGravityGeneralizedForces(self._model_context)

    def _calc_requested(self, context: Context, value: AbstractValue) -> None:
        torque = self._command.Eval(context)  # a fresh array (Eval copies)
        if self._compensate:
            torque = torque + self.gravity_torque(self._state.Eval(context)[:FR3_JOINTS])
        value.set_value(torque)


class ArmMeasurement(LeafSystem):
    """What the robot measures. Inputs `state` ([q, q̇], 14) and `body_poses` (the plant's
    body poses). Outputs `output` = y, the TCP position (3), and `plant_state` = [y, q, q̇]
    (17), the controller's input."""

    def __init__(self, plant: MultibodyPlant) -> None:
        super().__init__()
        tcp = plant.GetFrameByName(FR3_TCP)
        self._body = int(tcp.body().index())
        self._offset = tcp.GetFixedPoseInBodyFrame()
        self._state = self.DeclareVectorInputPort("state", 2 * FR3_JOINTS)
        self._poses = self.DeclareAbstractInputPort(
            "body_poses", AbstractValue.Make([RigidTransform()])
        )
        self.DeclareVectorOutputPort(
            "output",
            3,
            self._calc_output,
            prerequisites_of_calc={self.input_port_ticket(self._poses.get_index())},
        )
        self.DeclareVectorOutputPort(
            "plant_state",
            3 + 2 * FR3_JOINTS,
            self._calc_plant_state,
            prerequisites_of_calc={self.all_input_ports_ticket()},
        )

    def _position(self, context: Context) -> np.ndarray:
        return (self._poses.Eval(context)[self._body] @ self._offset).translation()

    def _calc_output(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(self._position(context))

    def _calc_plant_state(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(np.concatenate([self._position(context), self._state.Eval(context)]))


class ArmSTTController(LeafSystem):
    """The two-space funnel law as a Drake system (no state, no dynamic parameter).

    Inputs `tube` = [c, r] (4) and `plant_state` = [y, q, q̇] (17). Outputs `control` = τ
    (7, N·m, to the robot interface), `funnel_errors` = [e₁, e₂ (7)] and
    `joint_velocity_reference` = q̇_ref (7).
    """

    def __init__(self, law: ArmFunnelLaw, kinematics: ArmKinematics | None = None) -> None:
        super().__init__()
        self._law = law
        self._kinematics = kinematics if kinematics is not None else ArmKinematics()
        self._tube = self.DeclareVectorInputPort("tube", 4)
        self._state = self.DeclareVectorInputPort("plant_state", 3 + 2 * FR3_JOINTS)
        self._evaluation = _cache(
            self,
            "arm funnel law",
            self._calc_evaluation,
            {self.time_ticket(), self.all_input_ports_ticket()},
        )
        depends = {self._evaluation.ticket()}
        for name, size, field in (
            ("control", FR3_JOINTS, "torque"),
            ("funnel_errors", 1 + FR3_JOINTS, "normalized_errors"),
            ("joint_velocity_reference", FR3_JOINTS, "joint_velocity"),
        ):
            self.DeclareVectorOutputPort(
                name,
                size,
                lambda context, output, field=field: output.SetFromVector(
                    getattr(self._evaluation.Eval(context), field)
                ),
                prerequisites_of_calc=depends,
            )

    @property
    def law(self) -> ArmFunnelLaw:
        return self._law

    def _calc_evaluation(self, context: Context, value: AbstractValue) -> None:
        tube = self._tube.Eval(context)
        state = self._state.Eval(context)
        q = state[3 : 3 + FR3_JOINTS]
        value.set_value(
            self._law.evaluate(
                context.get_time(),
                state[:3],
                q,
                state[3 + FR3_JOINTS :],
                self._kinematics.jacobian(q),
                tube[:3],
                float(tube[3]),
            )
        )


@dataclass(frozen=True)
class Jerk:
    """One impulsive push: a half-sine force pulse F(t) = F sin(π (t − start)/duration) on
    `body` at `point` (in the body frame), for start ≤ t ≤ start + duration.

    Attributes:
        start, duration: seconds.
        body: the body index in the plant.
        force: (3,) peak force in the world frame (N).
        point: (3,) application point in the body frame (m).
    """

    start: float
    duration: float
    body: int
    force: np.ndarray
    point: np.ndarray

    def force_at(self, t: float) -> np.ndarray:
        """The force at time t (zero outside the pulse)."""
        phase = (t - self.start) / self.duration
        if 0.0 <= phase <= 1.0:
            return np.sin(np.pi * phase) * np.asarray(self.force, dtype=float)
        return np.zeros(3)


class ExternalJerks(LeafSystem):
    """Outputs `spatial_forces` (list of ExternallyAppliedSpatialForce, for the plant's
    applied-spatial-force input) and `force` (3, the sum of the active forces, N, for
    logging). Both depend on time only."""

    def __init__(self, jerks: Sequence[Jerk]) -> None:
        super().__init__()
        self._jerks = tuple(jerks)
        self.DeclareAbstractOutputPort(
            "spatial_forces",
            lambda: AbstractValue.Make([ExternallyAppliedSpatialForce_[float]()]),
            self._calc_spatial_forces,
            prerequisites_of_calc={self.time_ticket()},
        )
        self.DeclareVectorOutputPort(
            "force", 3, self._calc_force, prerequisites_of_calc={self.time_ticket()}
        )

    @property
    def jerks(self) -> tuple[Jerk, ...]:
        return self._jerks

    def _calc_spatial_forces(self, context: Context, value: AbstractValue) -> None:
        t = context.get_time()
        forces = []
        for jerk in self._jerks:
            force = jerk.force_at(t)
            if np.any(force):
                applied = ExternallyAppliedSpatialForce_[float]()
                applied.body_index = BodyIndex(jerk.body)
                applied.p_BoBq_B = np.asarray(jerk.point, dtype=float)
                applied.F_Bq_W = SpatialForce(np.zeros(3), force)
                forces.append(applied)
        value.set_value(forces)

    def _calc_force(self, context: Context, output: BasicVector) -> None:
        t = context.get_time()
        output.SetFromVector(sum((jerk.force_at(t) for jerk in self._jerks), np.zeros(3)))
