"""Which implementation the hot path uses: the compiled kernels or the numpy reference.

:mod:`stt_drake.core._kernels` (numba) is loaded on first use, so importing :mod:`stt_drake` stays
fast and never compiles anything. ``STT_DRAKE_PURE_NUMPY=1`` in the environment selects the
pure numpy/scipy reference path for the whole process; tests switch per block with
:func:`pure_numpy`.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from types import ModuleType

#: Environment variable that selects the pure numpy/scipy path when set to a non-empty
#: value other than "0".
PURE_NUMPY_ENV = "STT_DRAKE_PURE_NUMPY"

_state: dict[str, object] = {
    "pure_numpy": os.environ.get(PURE_NUMPY_ENV, "") not in ("", "0"),
    "module": None,
}


def kernels() -> ModuleType | None:
    """The compiled kernel module, or None when the numpy reference path is selected (or
    numba cannot be imported, which is warned about once)."""
    if _state["pure_numpy"]:
        return None
    module = _state["module"]
    if module is None:
        try:
            from stt_drake.core import _kernels as module
        except ImportError as error:  # pragma: no cover - numba is a pinned dependency
            warnings.warn(
                f"stt_drake: compiled kernels unavailable ({error}); using numpy",
                RuntimeWarning,
                stacklevel=2,
            )
            _state["pure_numpy"] = True
            return None
        _state["module"] = module
    return module  # type: ignore[return-value]


def using_compiled() -> bool:
    """True when the compiled kernels are selected."""
    return not _state["pure_numpy"]


@contextmanager
def pure_numpy(enabled: bool = True) -> Iterator[None]:
    """Within the block, use the numpy reference path (``enabled=False``: the compiled one)."""
    previous = _state["pure_numpy"]
    _state["pure_numpy"] = enabled
    try:
        yield
    finally:
        _state["pure_numpy"] = previous
