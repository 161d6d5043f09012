"""`stt-drake bench`, the timing harness: :func:`time_call`."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import numpy as np


def time_call(function: Callable[[], object], repeats: int, min_time: float = 0.02) -> dict:
    """Median and spread of one call (µs, wall clock): warm up, calibrate the loop count so
    one repeat lasts ≥ `min_time`, then time `repeats` repeats. `cpu_median` is the same per
    CPU second of this process (close to the wall figure on an idle machine; on a loaded
    one it shows what the wall clock lost to other processes)."""
    function()
    number = 1
    while True:
        start = time.perf_counter()
        for _ in range(number):
            function()
        elapsed = time.perf_counter() - start
        if elapsed >= min_time or number >= 1 << 20:
            break
        number *= max(2, min(10, int(min_time / max(elapsed, 1e-9)) + 1))
    samples, cpu_samples = [], []
    for _ in range(repeats):
        start, cpu_start = time.perf_counter(), time.process_time()
        for _ in range(number):
            function()
        samples.append((time.perf_counter() - start) / number * 1e6)
        cpu_samples.append((time.process_time() - cpu_start) / number * 1e6)
    quartiles = np.percentile(samples, [25, 75])
    return {
        "median": statistics.median(samples),
        "min": min(samples),
        "max": max(samples),
        "iqr": float(quartiles[1] - quartiles[0]),
        "cpu_median": statistics.median(cpu_samples),
        "repeats": repeats,
        "calls_per_repeat": number,
    }
