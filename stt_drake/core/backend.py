"""Which implementation the hot path uses: the compiled kernels or the numpy reference.

The choice is made here and only here. A caller asks :func:`compiled` for a kernel by name
(and, for the dimension-specific ones, the output dimension n) and runs its numpy reference
when it gets None::

    kernel = backend.compiled("tube_step", n)
    if kernel is None:
        ...  # numpy reference

:data:`KERNELS` lists every kernel the library dispatches to. :mod:`stt_drake.core._kernels`
(numba) is loaded on first use, so importing :mod:`stt_drake` stays fast and never compiles
anything. ``STT_DRAKE_PURE_NUMPY=1`` in the environment selects the pure numpy/scipy
reference path for the whole process; tests switch per block with :func:`pure_numpy`.
"""

from __future__ import annotations

import importlib
import os
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import ModuleType
from typing import Any

#: Environment variable that selects the pure numpy/scipy path when set to a non-empty
#: value other than "0".
PURE_NUMPY_ENV = "STT_DRAKE_PURE_NUMPY"

#: Output dimensions n the dimension-specific kernels are compiled for; any other n always
#: takes the numpy reference path.
COMPILED_DIMENSIONS = (1, 2, 3)

#: The compiled kernels the library dispatches to: name of the function in
#: :mod:`stt_drake.core._kernels` (or the module :data:`KERNEL_MODULES` names) → the output
#: dimensions it covers (:data:`COMPILED_DIMENSIONS`,
#: for which the caller passes n to :func:`compiled`; None: any n, no dimension passed).
#: The comment names the function whose numpy reference each one replaces.
KERNELS: dict[str, tuple[int, ...] | None] = {
    "chi_sf_array": COMPILED_DIMENSIONS,  # probability.noncentral_chi_sf
    "chi_isf_array": COMPILED_DIMENSIONS,  # probability.noncentral_chi_isf
    "tube_step": COMPILED_DIMENSIONS,  # tube.TubeLaw.evaluate / switching_gains
    "tube_step_packed": COMPILED_DIMENSIONS,  # tube.TubeLaw.evaluate_packed
    "tube_advance": COMPILED_DIMENSIONS,  # tube.TubeLaw.advance
    "invariant_margins": COMPILED_DIMENSIONS,  # invariants.evaluate_invariants
    "invariant_margins_packed": COMPILED_DIMENSIONS,  # invariants.evaluate_invariants_packed
    "carry_circulation": None,  # circulation.carry_circulation (3D by construction)
    "funnel_control": None,  # control.FunnelController.evaluate
    "funnel_control_packed": None,  # control.FunnelController.control_from_tube
    "belief_table": None,  # systems.belief_source.ObstacleBeliefSource.belief_vector
    "ball_probabilities_array": (2, 3),  # anisotropic.ball_probabilities
    "avoid_gradient_array": (2, 3),  # anisotropic.avoid_gradient
    "quantile_radius_array": (2, 3),  # anisotropic.quantile_radius
    "anisotropic_tube_step": (2, 3),  # tube.TubeLaw.evaluate with covariances
    "track_update": COMPILED_DIMENSIONS,  # tracking.update
    "route_search": None,  # route_search.search_route (the guide's A*)
}

#: Kernels that live in another compiled module than :mod:`stt_drake.core._kernels`.
KERNEL_MODULES: dict[str, str] = {
    "ball_probabilities_array": "_anisotropic",
    "avoid_gradient_array": "_anisotropic",
    "quantile_radius_array": "_anisotropic",
    "anisotropic_tube_step": "_anisotropic_tube",
    "track_update": "_tracking",
    "route_search": "_guide",
}

_state: dict[str, object] = {
    "pure_numpy": os.environ.get(PURE_NUMPY_ENV, "") not in ("", "0"),
    "modules": {},
}


def compiled(name: str, dimension: int | None = None) -> Callable[..., Any] | None:
    """The compiled kernel `name` (a key of :data:`KERNELS`), or None when the caller must run
    its numpy reference: the numpy path is selected, `dimension` is not one the kernel is
    compiled for, or numba cannot be imported (warned about once; the numpy path is then
    selected for the rest of the process).

    Raises:
        KeyError: `name` is not in :data:`KERNELS` (on either path: a typo must not select
            the numpy path silently).
        TypeError: a dimension-specific kernel was asked for without `dimension`.
    """
    try:
        dimensions = KERNELS[name]
    except KeyError:
        raise KeyError(
            f"unknown compiled kernel {name!r}; the kernels are {', '.join(KERNELS)}"
        ) from None
    if dimensions is not None and dimension is None:
        raise TypeError(f"compiled kernel {name!r} is per dimension {dimensions}: pass dimension")
    if _state["pure_numpy"]:
        return None
    if dimensions is not None and dimension not in dimensions:
        return None
    module = _module(KERNEL_MODULES.get(name, "_kernels"))
    return None if module is None else getattr(module, name)


def _module(name: str) -> ModuleType | None:
    """The compiled module ``stt_drake.core.<name>``, imported on first need (None, after
    one warning, if numba cannot be imported)."""
    modules: dict[str, ModuleType] = _state["modules"]  # type: ignore[assignment]
    if name not in modules:
        try:
            modules[name] = importlib.import_module(f"stt_drake.core.{name}")
        except ImportError as error:  # pragma: no cover - numba is a pinned dependency
            warnings.warn(
                f"stt_drake: compiled kernels unavailable ({error}); using numpy",
                RuntimeWarning,
                stacklevel=3,  # the function that asked compiled() for a kernel
            )
            _state["pure_numpy"] = True
            return None
    return modules[name]


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
