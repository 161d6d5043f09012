"""Crowds of pedestrians from JuPedSim (the `crowd` extra): scenes (:mod:`.scenes`, numpy
only), the JuPedSim stepping (:mod:`.engine`, JuPedSim imported lazily) and offline tracks
with their CSV file (:mod:`.tracks`). The interactive crowd inside a Drake Diagram is
:class:`stt_drake.systems.crowd.CrowdSimulator`."""

from stt_drake.crowd.engine import MISSING_MESSAGE, CrowdEngine, CrowdUnavailableError
from stt_drake.crowd.scenes import SCENE_NAMES, SCENES, CrowdSetup, make_scene
from stt_drake.crowd.tracks import CSV_HEADER, Tracks, run_tracks, write_tracks_csv

__all__ = [
    "CSV_HEADER",
    "MISSING_MESSAGE",
    "SCENES",
    "SCENE_NAMES",
    "CrowdEngine",
    "CrowdSetup",
    "CrowdUnavailableError",
    "Tracks",
    "make_scene",
    "run_tracks",
    "write_tracks_csv",
]
