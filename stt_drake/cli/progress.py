"""The progress lines a long command prints on stderr while it works: `stt-drake run`'s
simulated time, real-time factor and worst margin so far, every few seconds of wall time,
only when stderr is a terminal and not ``--quiet``."""

from __future__ import annotations

import sys
import time
from typing import TextIO

from stt_drake.core.invariants import InvariantTracker

#: Wall-clock seconds between two progress lines.
PERIOD_S = 2.0


def wants_progress(quiet: bool, stream: TextIO | None = None) -> bool:
    """Whether to print progress: not ``--quiet`` and `stream` (stderr) is a terminal."""
    stream = sys.stderr if stream is None else stream
    return not quiet and stream.isatty()


class RunProgress:
    """Called after every simulation step (:func:`stt_drake.run.simulate`'s `progress`);
    prints ``t = 4.20 / 25 s  (31.2× real time)  worst margin center_avoid_probability
    +0.012`` at most every :data:`PERIOD_S` s of wall time."""

    def __init__(self, duration: float, stream: TextIO | None = None) -> None:
        self._duration = duration
        self._stream = sys.stderr if stream is None else stream
        self._start = self._last = time.perf_counter()

    def __call__(self, t: float, tracker: InvariantTracker) -> None:
        now = time.perf_counter()
        if now - self._last < PERIOD_S:
            return
        self._last = now
        name, record = min(tracker.records.items(), key=lambda item: item[1].worst_margin)
        rate = t / (now - self._start)
        print(
            f"  t = {t:.2f} / {self._duration:g} s  ({rate:.1f}× real time)  worst margin "
            f"{name} {record.worst_margin:+.3g}",
            file=self._stream,
            flush=True,
        )
