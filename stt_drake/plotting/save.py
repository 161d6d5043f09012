"""All figures of a run written as PNG files (:func:`save_run_figures`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from functools import partial
from pathlib import Path
from typing import Any

from stt_drake.plotting.arm import plot_joint_torques
from stt_drake.plotting.margins import plot_margins
from stt_drake.plotting.run2d import plot_snapshots, plot_tube_3d
from stt_drake.plotting.run3d import plot_snapshots_3d
from stt_drake.runlog import RunLog


def save_run_figures(
    log: Mapping[str, Any],
    out_dir: str | Path,
    dpi: int = 120,
    invariants: Mapping[str, Mapping[str, Any]] | None = None,
    snapshot_times: Sequence[float] | None = None,
) -> list[Path]:
    """Write the run's figures as PNGs into `out_dir` (created if needed).

    2D runs: ``snapshots.png``, ``tube_3d.png`` and ``margins.png``; 3D runs:
    ``snapshots.png`` (:func:`plot_snapshots_3d`) and ``margins.png``; other dimensions:
    ``margins.png`` only. Runs of the arm (logs with `requested_torque`) also get
    ``joint_torques.png`` (:func:`plot_joint_torques`).

    The snapshots are taken at `snapshot_times` (s) when given, else at the start, each
    guarantee's worst-margin time (from `invariants`, ``metrics.json``'s record, or the
    logged margins without it) and the end.

    Returns:
        The paths written, in that order.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    run = RunLog.of(log)  # once: an npz re-reads every member from its zip on each access
    builders: list[tuple[str, Any]] = []
    chosen = {"times": snapshot_times, "invariants": invariants}
    if run.dimension == 2:
        builders += [
            ("snapshots.png", partial(plot_snapshots, **chosen)),
            ("tube_3d.png", plot_tube_3d),
        ]
    elif run.dimension == 3:
        builders.append(("snapshots.png", partial(plot_snapshots_3d, **chosen)))
    builders.append(("margins.png", plot_margins))
    if "requested_torque" in run:  # a torque-controlled arm
        builders.append(("joint_torques.png", plot_joint_torques))
    written = []
    for filename, build in builders:
        path = out / filename
        build(run).savefig(path, dpi=dpi)
        written.append(path)
    return written
