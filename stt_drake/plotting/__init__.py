"""Matplotlib figures from a run log (pure numpy/matplotlib; no Drake).

A *run log* is any mapping (a dict, or ``np.load("log.npz")``) with the keys

========================== =============================================================
key                        contents (T samples, m obstacles, n = dimension)
========================== =============================================================
t                          (T,) seconds
output, center             (T, n) robot output y and tube centre c
radius                     (T,) tube radius r
belief                     (T, m·(n+4)) obstacle-major records [mean, σ, r_o, ε, p_d]
avoid_probability          (T, m) q_j at the centre
quantile_distance, theta   (T, m)
control                    (T, n)
margins                    (T, 5) in ``stt_drake.core.invariants.INVARIANT_NAMES`` order
output_avoid_probability   (T, m) P(‖y − O_j‖ ≥ r_o_j)
dimension, start, target,  scalars / (n,) arrays describing the task
initial_set_radius,
target_set_radius, r_min
name                       str (a 0-d array in an npz)
r_max                      optional: drawn as a reference in :func:`plot_margins`
========================== =============================================================

Every function returns a :class:`matplotlib.figure.Figure` built without pyplot, so it
works headless (no backend is touched) and displays in notebooks as-is. All figures share
one visual language, :data:`PALETTE`.

The figures live in submodules — :mod:`~stt_drake.plotting.run2d`,
:mod:`~stt_drake.plotting.run3d`, :mod:`~stt_drake.plotting.margins`,
:mod:`~stt_drake.plotting.arm`, with the shared palette, log decoding and obstacle level
sets in :mod:`~stt_drake.plotting.style` and :func:`save_run_figures` in
:mod:`~stt_drake.plotting.save` — and are re-exported here.
"""

from __future__ import annotations

from stt_drake.plotting.arm import plot_joint_torques
from stt_drake.plotting.margins import plot_margins
from stt_drake.plotting.run2d import plot_snapshots, plot_tube_3d
from stt_drake.plotting.run3d import plot_snapshots_3d
from stt_drake.plotting.save import save_run_figures
from stt_drake.plotting.style import (
    PALETTE,
    decode_log,
    level_set_radius,
    obstacle_colors,
    reach_time,
)

__all__ = [
    "PALETTE",
    "decode_log",
    "level_set_radius",
    "obstacle_colors",
    "plot_joint_torques",
    "plot_margins",
    "plot_snapshots",
    "plot_snapshots_3d",
    "plot_tube_3d",
    "reach_time",
    "save_run_figures",
]
