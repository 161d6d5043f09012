"""The progress lines a long command prints on stderr while it works, every few seconds of
wall time, only when stderr is a terminal and not ``--quiet``: `stt-drake run`'s simulated
time, real-time factor and worst margin so far (:class:`RunProgress`); `stt-drake compare`'s
closed loops and draws done, elapsed time, rate and time left (:class:`CountProgress`).
`stt-drake campaign` shows a progress bar (runs done, failures, runs/s, time left) under
the same rule."""

from __future__ import annotations

import math
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


def duration_text(seconds: float) -> str:
    """A duration as a person reads it: ``42 s``, ``3.5 min``, ``2.1 h``."""
    if seconds < 100.0:
        return f"{seconds:.0f} s"
    if seconds < 6000.0:
        return f"{seconds / 60.0:.1f} min"
    return f"{seconds / 3600.0:.1f} h"


class CountProgress:
    """Progress through a count of items (:func:`stt_drake.compare.compare`'s closed loops,
    :func:`stt_drake.compare_draws.compare_draws`' runs): called with (done, total) and
    optionally what comes next, prints ``compare: 12/40 draw runs, 31 s elapsed, 0.39/s,
    about 72 s left`` at most every `period` s of wall time (and always when all are done).
    The rate counts only the items done since the first call (a resumed comparison starts
    with some done)."""

    def __init__(
        self, label: str, unit: str, stream: TextIO | None = None, period: float | None = None
    ) -> None:
        self._label, self._unit = label, unit
        self._stream = sys.stderr if stream is None else stream
        self._period = PERIOD_S if period is None else period
        self._start = time.perf_counter()
        self._last = -math.inf
        self._first: int | None = None

    def __call__(self, done: int, total: int, note: str = "") -> None:
        now = time.perf_counter()
        if self._first is None:
            self._first = done
        if now - self._last < self._period and done < total:
            return
        self._last = now
        elapsed = now - self._start
        text = f"{self._label}: {done}/{total} {self._unit}, {duration_text(elapsed)} elapsed"
        new = done - self._first
        if new > 0 and elapsed > 0.0:
            rate = new / elapsed
            text += f", {rate:.3g}/s"
            if done < total:
                text += f", about {duration_text((total - done) / rate)} left"
        print(text + (f"; {note}" if note else ""), file=self._stream, flush=True)
