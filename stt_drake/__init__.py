"""stt-drake: Spatiotemporal Tube control among uncertain, moving obstacles, on Drake.

The public API, importable from here (loaded on first use, so ``import stt_drake`` stays
fast and imports no Drake):

* the task: :class:`Obstacle` (one uncertain obstacle) with its motion model
  (:class:`ConstantVelocity`, :class:`Oscillation`, :class:`Waypoints`, :class:`Recorded`)
  and uncertainty schedules (:class:`SigmaSchedule`, :class:`CovarianceSchedule`);
* the math core: :class:`TubeLaw` (with :func:`default_nu`, :func:`linear_zone_for_step`),
  :class:`FunnelController` with its :class:`BoxFunnel` s, :class:`ObstacleBelief` (what
  the law reads), :class:`GaussianBelief` (the belief port), :class:`ObstacleTask`;
* the Drake systems: :class:`ObstacleBeliefSource`, :class:`SpatiotemporalTube`,
  :class:`STTController`, :class:`InvariantMonitor`, and :func:`AddTubeVisualizer`
  (Meshcat);
* building: :func:`AddStt` (the STT loop added to a DiagramBuilder, returning
  :class:`SttHandles`), :func:`build_diagram` (a scenario's whole diagram),
  :func:`load_scenario` (a file or a packaged scenario's name, :func:`packaged_scenarios`),
  :func:`parse_scenario`, :class:`ScenarioError`;
* running one's own Diagram: :func:`make_diagram_simulator` (a scenario run's Simulator
  set-up, every guarantee checked at every step into an :class:`InvariantTracker`, names
  :data:`INVARIANT_NAMES`), :func:`combine_monitors` (one's own Simulator monitor next to
  the invariant monitor), :func:`guarantees_report`, :func:`tube_reach_time`;
* running a scenario: :func:`make_simulator`, :func:`simulate`, and the run log
  :class:`RunLog`.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

_PUBLIC = {
    "Obstacle": "stt_drake.core.obstacle",
    "ConstantVelocity": "stt_drake.core.motion",
    "Oscillation": "stt_drake.core.motion",
    "Waypoints": "stt_drake.core.motion",
    "Recorded": "stt_drake.core.motion",
    "SigmaSchedule": "stt_drake.core.motion",
    "CovarianceSchedule": "stt_drake.core.motion",
    "TubeLaw": "stt_drake.core.tube",
    "default_nu": "stt_drake.core.tube",
    "linear_zone_for_step": "stt_drake.core.tube",
    "FunnelController": "stt_drake.core.control",
    "BoxFunnel": "stt_drake.core.control",
    "ObstacleBelief": "stt_drake.core.belief",
    "GaussianBelief": "stt_drake.core.belief",
    "ObstacleTask": "stt_drake.core.belief",
    "INVARIANT_NAMES": "stt_drake.core.invariants",
    "InvariantTracker": "stt_drake.core.invariants",
    "tube_reach_time": "stt_drake.core.invariants",
    "ObstacleBeliefSource": "stt_drake.systems.belief_source",
    "SpatiotemporalTube": "stt_drake.systems.tube",
    "STTController": "stt_drake.systems.controller",
    "InvariantMonitor": "stt_drake.systems.monitor",
    "combine_monitors": "stt_drake.systems.monitor",
    "AddTubeVisualizer": "stt_drake.systems.visualizer",
    "AddStt": "stt_drake.assembly.stt",
    "SttHandles": "stt_drake.assembly.stt",
    "build_diagram": "stt_drake.assembly.diagram",
    "load_scenario": "stt_drake.assembly.load",
    "parse_scenario": "stt_drake.assembly.load",
    "packaged_scenarios": "stt_drake.diagrams",
    "ScenarioError": "stt_drake.config.schema",
    "make_diagram_simulator": "stt_drake.run",
    "guarantees_report": "stt_drake.run",
    "make_simulator": "stt_drake.run",
    "simulate": "stt_drake.run",
    "RunLog": "stt_drake.runlog",
}

__all__ = sorted(_PUBLIC)


def __getattr__(name: str) -> Any:
    """Load a public name from its module on first use (PEP 562)."""
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f"module 'stt_drake' has no attribute {name!r}")
    return getattr(import_module(module), name)


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])
