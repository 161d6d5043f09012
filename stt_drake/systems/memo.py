"""A one-entry memo for a system's pure computations, keyed by the exact values they read.

Drake's integrators start every step by restoring the context they step from, which
invalidates every cache entry: the tube evaluation the invariant monitor made at the end of
step k (at t_k, x_k) is recomputed by the first stage of step k + 1 at the same time and
state (with Runge-Kutta 3 that is one evaluation in four). A system whose cache entry is a
pure function of a few arrays keeps the last result in a :class:`LastResult` and returns it
when those arrays are bit-for-bit the same; any change, in any array, is a miss. It is a
per-system memo, not state: the result is the one the calculation would produce, so a
second context (or a Simulator sharing the system) only costs a miss.
"""

from __future__ import annotations

from typing import Any

import numpy as np


class LastResult:
    """The last result of a pure computation and the exact bytes of what it read."""

    def __init__(self) -> None:
        self._key: tuple[bytes, ...] | None = None
        self._result: Any = None

    def lookup(self, *inputs: np.ndarray | float | None) -> tuple[tuple[bytes, ...], Any]:
        """(key, result): the key of `inputs` and the stored result when the stored key
        equals it, else None (store the new result with :meth:`store`)."""
        key = tuple(
            b"" if value is None else np.asarray(value, dtype=float).tobytes() for value in inputs
        )
        return key, (self._result if key == self._key else None)

    def store(self, key: tuple[bytes, ...], result: Any) -> Any:
        """Remember `result` under `key`; returns `result`."""
        self._key, self._result = key, result
        return result
