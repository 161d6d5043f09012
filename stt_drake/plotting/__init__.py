"""Matplotlib figures from a run log, a campaign, a comparison and the benchmark (pure
numpy/matplotlib; no Drake).

A *run log* is any mapping with the members of ``log.npz`` (a dict, ``np.load("log.npz")``
or a :class:`stt_drake.runlog.RunLog`); its layout is documented once, in
:mod:`stt_drake.runlog`. The figures read it through :class:`~stt_drake.runlog.RunLog`
(``r_max``, when present, is drawn as a reference in :func:`plot_margins`).

Every function returns a :class:`matplotlib.figure.Figure` built without pyplot, so it
works headless (no backend is touched) and displays in notebooks as-is. All figures share
one visual language, :data:`PALETTE`.

The figures live in submodules — :mod:`~stt_drake.plotting.run2d`,
:mod:`~stt_drake.plotting.run3d`, :mod:`~stt_drake.plotting.margins` (with its
per-obstacle panels in :mod:`~stt_drake.plotting.obstacles`),
:mod:`~stt_drake.plotting.arm`, with the shared palette, σ colours and obstacle level
sets in :mod:`~stt_drake.plotting.style`, the snapshot times (the worst-margin times) in
:mod:`~stt_drake.plotting.instants` and :func:`save_run_figures` in
:mod:`~stt_drake.plotting.save` — and are re-exported here. The figures of the
commands above a run are drawn here too, from plain data (their callers sit above plotting
in the import layers): :mod:`~stt_drake.plotting.campaign` (one per campaign kind),
:mod:`~stt_drake.plotting.compare` (``comparison.png``), both with the intervals and
verdicts of :mod:`~stt_drake.plotting.certify`, and :mod:`~stt_drake.plotting.bench` (the
tube step's scaling).
"""

from __future__ import annotations

from stt_drake.plotting.arm import plot_joint_torques
from stt_drake.plotting.instants import snapshot_times, worst_margin_times
from stt_drake.plotting.margins import plot_margins
from stt_drake.plotting.run2d import plot_snapshots, plot_tube_3d
from stt_drake.plotting.run3d import plot_snapshots_3d
from stt_drake.plotting.save import save_run_figures
from stt_drake.plotting.style import (
    PALETTE,
    level_set_radius,
    obstacle_colors,
    reach_time,
)

__all__ = [
    "PALETTE",
    "level_set_radius",
    "obstacle_colors",
    "plot_joint_torques",
    "plot_margins",
    "plot_snapshots",
    "plot_snapshots_3d",
    "plot_tube_3d",
    "reach_time",
    "save_run_figures",
    "snapshot_times",
    "worst_margin_times",
]
