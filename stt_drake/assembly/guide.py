"""Scenario → the guide above the tube (its `guide:` section): the numbers derived once,
the :class:`~stt_drake.systems.guide.TubeGuide` added and connected."""

from __future__ import annotations

import math

import numpy as np
from pydrake.systems.framework import DiagramBuilder, OutputPort

from stt_drake.assembly.stt import SttHandles
from stt_drake.config import Scenario
from stt_drake.config.validate_guide import MAX_GRID_CELLS
from stt_drake.core.guide import GuideSettings, RoutePlanner, ScriptedForecast
from stt_drake.core.progress import DEFAULT_STALL_RULE, StallRule
from stt_drake.core.tracking import KalmanTracker
from stt_drake.core.tube import TubeLaw
from stt_drake.systems.guide import TubeGuide

#: Cells across the derived grid's box in 2D and 3D (the derived resolution).
DERIVED_CELLS = {2: 120, 3: 40}
#: The derived planning speed as a fraction of the tube's max_center_speed.
SPEED_FRACTION = 0.8
#: The longest derived look-ahead (m).
MAX_LOOKAHEAD = 3.0


def guide_settings(scenario: Scenario, law: TubeLaw) -> GuideSettings:
    """The `guide:` section with every derived number filled in.

    Resolution: the box of start and target grown by the grid margin, split in
    :data:`DERIVED_CELLS` cells along its longest side, at least r_min. Speed and
    look-ahead: the centre follows a point d ahead at k1·d^{1/3} per axis (Eq. (4)), so
    a point moving at v is followed at a lag (v/k1)³; the look-ahead is twice that lag
    (at most :data:`MAX_LOOKAHEAD`), the speed :data:`SPEED_FRACTION` of max_center_speed
    and no more than the lag allows. Clearance: r_max − r_min, so the whole tube fits.
    Avoid level: each obstacle's p_d. A stall marks a region of twice r_max plus a cell."""
    config, n = scenario.guide, scenario.dimension
    start, target = np.asarray(scenario.start, float), np.asarray(scenario.target, float)
    margin = max(3.0, 4.0 * law.r_max, 0.5 * float(np.linalg.norm(target - start)))
    side = float(np.max(np.abs(target - start))) + 2.0 * margin
    resolution = config.resolution or max(law.r_min, side / DERIVED_CELLS.get(n, 40))
    speed = config.speed or SPEED_FRACTION * _finite_speed(law)
    lookahead = config.lookahead
    if not lookahead:
        lookahead = min(max(2.0 * (speed / law.k1) ** 3, 2.0 * resolution), MAX_LOOKAHEAD)
        speed = min(speed, law.k1 * (lookahead / 2.0) ** (1.0 / 3.0))
    levels = [config.avoid_level or o.p_d for o in scenario.obstacles]
    clearance = law.r_max - law.r_min if config.clearance is None else config.clearance
    return GuideSettings(
        resolution=resolution,
        horizon=config.horizon,
        time_step=config.time_step,
        speed=speed,
        max_wait=config.max_wait,
        lookahead=lookahead,
        clearance=clearance,
        avoid_level=np.array(levels, dtype=float),
        stall_radius=2.0 * (law.r_max + resolution),
        margin=margin,
        # a derived grid stays small; a given resolution is the user's (validated ≤ 4e6 cells)
        max_cells=MAX_GRID_CELLS if config.resolution else 3 * DERIVED_CELLS.get(n, 40) ** n,
    )


def _finite_speed(law: TubeLaw) -> float:
    """max_center_speed, or where it is unbounded the attraction's speed 2 m from η."""
    if math.isfinite(law.max_center_speed):
        return law.max_center_speed
    return law.k1 * 2.0 ** (1.0 / 3.0)


def stall_rule(scenario: Scenario) -> StallRule:
    """The stall rule of a run: the `guide:` section's, else the default."""
    if scenario.guide is None:
        return DEFAULT_STALL_RULE
    config = scenario.guide
    return StallRule(config.stall_time, config.stall_progress or scenario.tube.r_min)


def add_guide(
    builder: DiagramBuilder,
    scenario: Scenario,
    law: TubeLaw,
    stt: SttHandles,
    tracks: OutputPort | None = None,
    tracker: KalmanTracker | None = None,
    goal: OutputPort | None = None,
) -> TubeGuide:
    """Add the scenario's :class:`TubeGuide` and connect it: the tube and the belief in,
    `target` into the tube's `target` input (the tube must have been added with
    ``target_input=True``). `tracks`/`tracker`: forecast with the tracker's own prediction
    (else the scripted motion); `goal`: a task sequencer's target port (else the
    scenario's target)."""
    settings = guide_settings(scenario, law)
    task = stt.task
    n = scenario.dimension
    planner = RoutePlanner(settings, task.radius, task.epsilon, law.r_min, n)
    scripted = ScriptedForecast(scenario.obstacles, n) if tracker is None else None
    guide = builder.AddNamedSystem(
        "tube_guide",
        TubeGuide(
            planner,
            settings,
            task.count,
            n,
            period=1.0 / scenario.guide.rate_hz,
            replan_period=scenario.guide.replan_period,
            stall_rule=stall_rule(scenario),
            arrived=scenario.target_set_radius,
            goal=None if goal is not None else np.asarray(scenario.target, dtype=float),
            forecast=scripted,
            tracker=tracker,
        ),
    )
    builder.Connect(stt.tube, guide.GetInputPort("tube"))
    builder.Connect(stt.belief, guide.GetInputPort("obstacle_belief"))
    if tracker is not None:
        builder.Connect(tracks, guide.GetInputPort("tracks"))
    if goal is not None:
        builder.Connect(goal, guide.GetInputPort("goal"))
    builder.Connect(guide.GetOutputPort("target"), stt.tube_system.GetInputPort("target"))
    return guide
