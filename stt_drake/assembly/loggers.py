"""The run's logging: every logged signal in one Drake logger, read back per signal.

One `VectorLogSink` on a `Multiplexer` of all the signals records exactly what one sink per
signal would (the same samples at the same times), but the simulation pays a logger's
per-step and per-evaluation cost in Drake once instead of once per signal (about 4 µs per
derivative evaluation of the closed loop with ten signals).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from pydrake.systems.framework import DiagramBuilder, OutputPort
from pydrake.systems.primitives import LogVectorOutput, Multiplexer, VectorLogSink


class SignalLog:
    """One signal's rows of the combined log: what ``VectorLogSink.FindLog`` returns for a
    sink of its own (`num_samples`, `sample_times`, `data` as (size, samples))."""

    def __init__(self, log: Any, rows: slice) -> None:
        self._log = log
        self._rows = rows

    def num_samples(self) -> int:
        return self._log.num_samples()

    def sample_times(self) -> np.ndarray:
        return self._log.sample_times()

    def data(self) -> np.ndarray:
        return self._log.data()[self._rows]


class LoggedSignal:
    """A logged signal: :meth:`FindLog` reads its log from the simulation's root context, as
    a ``VectorLogSink`` of its own does. `sink` is the Drake logger it shares and `rows`
    its rows there."""

    def __init__(self, sink: VectorLogSink, rows: slice) -> None:
        self.sink = sink
        self.rows = rows

    def FindLog(self, root_context: Any) -> SignalLog:  # noqa: N802 (Drake's name)
        return SignalLog(self.sink.FindLog(root_context), self.rows)


def add_loggers(
    builder: DiagramBuilder, ports: Mapping[str, OutputPort], period: float
) -> dict[str, LoggedSignal]:
    """Log each of `ports` every `period` seconds: a `Multiplexer` named "logged_signals"
    stacks them in the given order into one `LogVectorOutput` named "logger"."""
    if not ports:
        return {}
    sizes = [port.size() for port in ports.values()]
    stacked = builder.AddNamedSystem("logged_signals", Multiplexer(sizes))
    for index, port in enumerate(ports.values()):
        builder.Connect(port, stacked.get_input_port(index))
    sink = LogVectorOutput(stacked.get_output_port(0), builder, period)
    sink.set_name("logger")
    ends = np.cumsum(sizes).tolist()
    return {
        name: LoggedSignal(sink, slice(end - size, end))
        for name, size, end in zip(ports, sizes, ends, strict=True)
    }
