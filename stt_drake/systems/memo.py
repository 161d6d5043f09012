"""A one-entry memo for a system's pure computations, keyed by the exact values they read.

Drake's integrators start every step by restoring the context they step from, which
invalidates every cache entry: the tube evaluation the invariant monitor made at the end of
step k (at t_k, x_k) is recomputed by the first stage of step k + 1 at the same time and
state (with Runge-Kutta 3 that is one evaluation in four). A system whose cache entry is a
pure function of a few arrays keeps the last result in a :class:`LastResult` and returns it
when those arrays are bit-for-bit the same; any change, in any array, is a miss, unless the
caller re-files the result under the new inputs (:meth:`LastResult.rekey`) because it knows
the computation gives the same result there. It is a
per-system memo, not state: the result is the one the calculation would produce, so a
second context (or a Simulator sharing the system) only costs a miss.
"""

from __future__ import annotations

import struct
from typing import Any

import numpy as np

_DOUBLE = struct.Struct("d").pack  # a float's bytes, as np.asarray(value).tobytes() gives them
_FLOAT64 = np.dtype(float)


def _key_part(value: np.ndarray | float | None) -> bytes:
    """The exact bytes of one input (as float64 values); b"" for None."""
    # The common types first, without a numpy conversion: a time, a port's float64 vector.
    if type(value) is float:
        return _DOUBLE(value)
    if value is None:
        return b""
    if type(value) is np.ndarray and value.dtype is _FLOAT64:
        return value.tobytes()
    return np.asarray(value, dtype=float).tobytes()


class LastResult:
    """The last result of a pure computation and the exact bytes of what it read."""

    def __init__(self) -> None:
        self._key: tuple[bytes, ...] | None = None
        self._result: Any = None

    @staticmethod
    def key(*inputs: np.ndarray | float | None) -> tuple[bytes, ...]:
        """The key of `inputs`: their exact bytes."""
        return tuple([_key_part(value) for value in inputs])

    def lookup(self, *inputs: np.ndarray | float | None) -> tuple[tuple[bytes, ...], Any]:
        """(key, result): the key of `inputs` and the stored result when the stored key
        equals it, else None (store the new result with :meth:`store`)."""
        key = self.key(*inputs)
        return key, (self._result if key == self._key else None)

    def rekey(self, key: tuple[bytes, ...], new_key: tuple[bytes, ...]) -> bool:
        """File the result stored under `key` under `new_key` instead, for a caller that
        knows the computation gives that same result on the new inputs; False (nothing
        changed) when `key` is not the stored key."""
        if key != self._key:
            return False
        self._key = new_key
        return True

    def store(self, key: tuple[bytes, ...], result: Any) -> Any:
        """Remember `result` under `key`; returns `result`."""
        self._key, self._result = key, result
        return result
