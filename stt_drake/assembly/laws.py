"""Scenario → the core objects, built once: the tube law, the funnel controller, the
arm's two-space law."""

from __future__ import annotations

import numpy as np

from stt_drake.assembly.feasibility import center_speed
from stt_drake.config import FrankaArm, Scenario
from stt_drake.core.arm import ArmFunnelLaw, ArmLimits, JointSpaceMapping
from stt_drake.core.control import BoxFunnel, FunnelController
from stt_drake.core.tube import TubeLaw, linear_zone_for_step
from stt_drake.systems.plants.franka import FR3_HOME, make_fr3_plant


def make_tube_law(scenario: Scenario) -> TubeLaw:
    """The tube law with the scenario's constants (ν and max_center_speed derived when not
    given, :func:`stt_drake.assembly.feasibility.center_speed`).

    The attraction gets the linear zone δ = (k1·h)^{3/2} of the longest step h that
    integrates it — the simulator's max step in continuous time, the update period at a
    fixed rate — so no step of h overshoots η (see
    :func:`stt_drake.core.tube.signed_cube_root_attraction`).
    """
    config = scenario.tube
    rate = config.update_rate_hz
    step = 1.0 / rate if rate > 0.0 else scenario.simulator.max_step_size
    return TubeLaw(
        target=np.asarray(scenario.target, dtype=float),
        k1=config.k1,
        k2=config.k2,
        k3=config.k3,
        r_min=config.r_min,
        r_max=config.r_max,
        nu=scenario.nu,
        linear_zone=linear_zone_for_step(config.k1, step),
        max_center_speed=center_speed(scenario),
    )


def make_funnel_controller(scenario: Scenario) -> FunnelController:
    """The funnel controller with the scenario's gains and box funnels."""
    config = scenario.controller
    return FunnelController(
        kappa=list(config.kappa),
        funnels=[
            BoxFunnel(start=np.array(f.start), end=np.array(f.end), rate=np.array(f.rate))
            for f in config.funnels
        ],
    )


def make_arm_law(scenario: Scenario, limits: ArmLimits | None = None) -> ArmFunnelLaw:
    """The arm's two-space funnel law: the scenario's κ and joint-velocity funnel, and the
    task → joint mapping (posture: the FR3 home configuration; limits: the model's)."""
    config: FrankaArm = scenario.plant
    limits = limits if limits is not None else ArmLimits.of(make_fr3_plant())
    return ArmFunnelLaw(
        controller=make_funnel_controller(scenario),
        mapping=JointSpaceMapping(
            damping=config.jacobian_damping,
            posture=FR3_HOME,
            posture_gain=config.posture_gain,
            position_lower=limits.position_lower,
            position_upper=limits.position_upper,
            limit_margin=config.limit_margin,
            limit_gain=config.limit_gain,
        ),
    )
