"""stt-drake: Spatiotemporal Tube control among uncertain, moving obstacles, on Drake.

The public API, importable from here (loaded on first use, so ``import stt_drake`` stays
fast and imports no Drake):

* the math core: :class:`TubeLaw`, :class:`FunnelController`, :class:`ObstacleBelief`
  (what the law reads), :class:`GaussianBelief` (the belief port), :class:`ObstacleTask`;
* the Drake systems: :class:`ObstacleBeliefSource`, :class:`SpatiotemporalTube`,
  :class:`STTController`, :class:`InvariantMonitor`;
* building: :func:`AddStt` (the STT loop added to a DiagramBuilder), :func:`build_diagram`
  (a scenario's whole diagram), :func:`load_scenario`, :func:`parse_scenario`;
* running: :func:`make_simulator`, :func:`simulate`, and the run log :class:`RunLog`.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

_PUBLIC = {
    "TubeLaw": "stt_drake.core.tube",
    "FunnelController": "stt_drake.core.control",
    "ObstacleBelief": "stt_drake.core.belief",
    "GaussianBelief": "stt_drake.core.belief",
    "ObstacleTask": "stt_drake.core.belief",
    "ObstacleBeliefSource": "stt_drake.systems.belief_source",
    "SpatiotemporalTube": "stt_drake.systems.tube",
    "STTController": "stt_drake.systems.controller",
    "InvariantMonitor": "stt_drake.systems.monitor",
    "AddStt": "stt_drake.assembly.stt",
    "SttHandles": "stt_drake.assembly.stt",
    "build_diagram": "stt_drake.assembly.diagram",
    "load_scenario": "stt_drake.assembly.load",
    "parse_scenario": "stt_drake.assembly.load",
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
