"""Which implementation the hot path uses: the compiled kernels or the numpy reference.

The choice is made here and only here. A caller asks :func:`compiled` for a kernel by name
(and, for the dimension-specific ones, the output dimension n) and runs its numpy reference
when it gets None::

    kernel = backend.compiled("tube_step", n)
    if kernel is None:
        ...  # numpy reference

:data:`KERNELS` lists every kernel the library dispatches to, :data:`SIGNATURES` the
argument types its callers pass, and :func:`warm_up` compiles (or loads) them all before a
run's clock starts. The compiled modules (numba) are loaded on first use, so importing
:mod:`stt_drake` stays fast and never compiles anything. ``STT_DRAKE_PURE_NUMPY=1`` in the
environment selects the pure numpy/scipy reference path for the whole process; tests switch
per block with :func:`pure_numpy`.

numba's on-disk cache (``cache=True``) keys a compiled function on its own file only: a
kernel calling a kernel of another file, or reading a constant of
:mod:`stt_drake.core.constants`, would load its stale compiled code after that other file
changed. :func:`jit_options`, which every compiled module calls before defining a kernel,
therefore points numba's cache at a folder named by a hash of all the compiled sources
(:data:`CACHED_SOURCES`) and numba's version: a change to any of them is a new folder,
compiled afresh. A ``NUMBA_CACHE_DIR`` set by the user is respected (the keyed folder is
made beneath it).
"""

from __future__ import annotations

import hashlib
import importlib
import os
import sys
import time
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from types import ModuleType
from typing import Any

#: Environment variable that selects the pure numpy/scipy path when set to a non-empty
#: value other than "0".
PURE_NUMPY_ENV = "STT_DRAKE_PURE_NUMPY"

#: Output dimensions n the dimension-specific kernels are compiled for; any other n always
#: takes the numpy reference path.
COMPILED_DIMENSIONS = (1, 2, 3)

#: The compiled kernels the library dispatches to: name of the function in the module
#: :data:`KERNEL_MODULES` names → the output dimensions it covers (:data:`COMPILED_DIMENSIONS`,
#: for which the caller passes n to :func:`compiled`; None: any n, no dimension passed).
#: The comment names the function whose numpy reference each one replaces.
KERNELS: dict[str, tuple[int, ...] | None] = {
    "chi_sf_array": COMPILED_DIMENSIONS,  # probability.noncentral_chi_sf
    "chi_isf_array": COMPILED_DIMENSIONS,  # probability.noncentral_chi_isf
    "level_set_offsets": COMPILED_DIMENSIONS,  # probability.level_set_radius (guide's table)
    "tube_step": COMPILED_DIMENSIONS,  # tube.TubeLaw.evaluate / switching_gains
    "tube_step_packed": COMPILED_DIMENSIONS,  # tube.TubeLaw.evaluate (a belief from a port)
    "tube_step_obstacles": COMPILED_DIMENSIONS,  # tube.TubeLaw.evaluate (σ_j arrays, plain)
    "tube_advance": COMPILED_DIMENSIONS,  # tube.TubeLaw.advance
    "tube_advance_packed": COMPILED_DIMENSIONS,  # tube.TubeLaw.advance (a belief from a port)
    "invariant_margins": COMPILED_DIMENSIONS,  # invariants.evaluate_invariants
    "invariant_margins_packed": COMPILED_DIMENSIONS,  # invariants.evaluate_invariants (port belief)
    "carry_circulation": None,  # circulation.carry_circulation (3D by construction)
    "funnel_control": None,  # control.FunnelController.evaluate
    "funnel_control_packed": None,  # control.FunnelController.control_from_tube
    "belief_table": None,  # systems.belief_source.ObstacleBeliefSource.belief_vector
    "ball_probabilities_array": (2, 3),  # anisotropic.ball_probabilities
    "avoid_gradient_array": (2, 3),  # anisotropic.avoid_gradient
    "quantile_radius_array": (2, 3),  # anisotropic.quantile_radius
    "exact_tube_step": (2, 3),  # tube.TubeLaw.evaluate with covariances
    "exact_tube_step_packed": (2, 3),  # tube.TubeLaw.evaluate (covariances from a port)
    "track_update": COMPILED_DIMENSIONS,  # tracking.update
    "track_update_monitored": COMPILED_DIMENSIONS,  # tracking.monitored_update
    "track_belief": COMPILED_DIMENSIONS,  # tracking.KalmanTracker.belief_vector
    "anisotropic_invariants": (2, 3),  # invariants.evaluate_invariants with covariances
    "anisotropic_invariants_packed": (2, 3),  # the same, covariances from a port
    "route_search": None,  # route_search.search_route (the guide's A*)
    "arm_control": None,  # arm.ArmFunnelLaw.evaluate
}

#: The compiled module (in :mod:`stt_drake.core`) of each kernel of :data:`KERNELS`.
KERNEL_MODULES: dict[str, str] = {
    "chi_sf_array": "_kernels",
    "chi_isf_array": "_kernels",
    "level_set_offsets": "_kernels",
    "tube_step": "_tube",
    "tube_step_packed": "_tube",
    "tube_step_obstacles": "_tube",
    "tube_advance": "_tube",
    "tube_advance_packed": "_tube",
    "invariant_margins": "_kernels",
    "invariant_margins_packed": "_kernels",
    "carry_circulation": "_kernels",
    "funnel_control": "_kernels",
    "funnel_control_packed": "_kernels",
    "belief_table": "_kernels",
    "ball_probabilities_array": "_anisotropic",
    "avoid_gradient_array": "_anisotropic",
    "quantile_radius_array": "_anisotropic",
    "exact_tube_step": "_tube",
    "exact_tube_step_packed": "_tube",
    "track_update": "_tracking",
    "track_update_monitored": "_tracking",
    "track_belief": "_tracking",
    "anisotropic_invariants": "_invariants",
    "anisotropic_invariants_packed": "_invariants",
    "route_search": "_guide",
    "arm_control": "_arm",
}

_VECTOR = "float64[::1]"
_MATRIX = "float64[:, ::1]"
_CUBE = "float64[:, :, ::1]"
_VIEW = "Array(float64, {}, 'A', readonly=True)"
_READONLY_MATRIX = "Array(float64, 2, 'C', readonly=True)"
_FORTRAN_MATRIX = "float64[::1, :]"


def _signature(*arguments: str) -> str:
    return f"({', '.join(arguments)})"


#: The tube step on a port: centre, port vector, task rows, k2, k3, circulation, constants.
_PORT_STEP = _signature(_VECTOR, _VECTOR, _MATRIX, _VECTOR, _VECTOR, _MATRIX, _VECTOR)
#: The fixed-rate update's arguments after the obstacles' and the gains: circulation,
#: constants, prune_above, duration, start radius, max_attempts.
_ADVANCE_TAIL = (_MATRIX, _VECTOR, "float64", "float64", "float64", "int64")


#: The argument types (numba type strings) each kernel of :data:`KERNELS` is called with by
#: the library's callers — numba compiles one specialisation per combination of types
#: (array layouts included), so :func:`warm_up` compiles exactly these. A caller passing
#: other types still works (numba compiles it then, inside the run's clock); the test
#: ``tests/core/test_compile_time.py`` checks that a run compiles nothing after warm_up.
SIGNATURES: dict[str, tuple[str, ...]] = {
    "chi_sf_array": (_signature(_VECTOR, _VECTOR, "int64"),),
    "chi_isf_array": (_signature(_VECTOR, _VECTOR, "int64"),),
    "level_set_offsets": (_signature(_VECTOR, "float64", "int64"),),
    "tube_step": (
        _signature(
            _VECTOR, _MATRIX, *[_VECTOR] * 3, "none", *[_VECTOR] * 5, _MATRIX, *[_VECTOR] * 2
        ),
    ),
    "tube_step_packed": (_PORT_STEP,),
    "tube_step_obstacles": (_signature(_VECTOR, _MATRIX, *[_VECTOR] * 5),),
    "exact_tube_step_packed": (_PORT_STEP,),
    "tube_advance": (_signature(_VECTOR, _MATRIX, *[_VECTOR] * 8, *_ADVANCE_TAIL),),
    "tube_advance_packed": (_signature(_VECTOR, _VECTOR, _MATRIX, *[_VECTOR] * 4, *_ADVANCE_TAIL),),
    "invariant_margins": (
        _signature(_VECTOR, _VECTOR, "float64", _MATRIX, _VECTOR, _VECTOR, _VECTOR, "float64"),
    ),
    "invariant_margins_packed": (_signature(_VECTOR, _VECTOR, _VECTOR, _MATRIX, "float64"),),
    "carry_circulation": (
        _signature(_MATRIX, _VECTOR, _MATRIX, "boolean[::1]", _VECTOR),
        _signature(_MATRIX, _VECTOR, "float64[:, :]", "boolean[::1]", _VECTOR),
    ),
    "funnel_control": (
        _signature(
            "float64", _VECTOR, _VECTOR, "float64", _VECTOR, _MATRIX, _MATRIX, _MATRIX, "float64"
        ),
    ),
    "funnel_control_packed": (_signature("float64", _VECTOR, _VECTOR, _VECTOR),),
    "belief_table": (_signature(_MATRIX, "float64", _VECTOR, "int64[::1]"),),
    "ball_probabilities_array": (_signature(_VECTOR, _MATRIX, "float64"),),
    "avoid_gradient_array": (_signature(_VECTOR, _MATRIX, "float64"),),
    "quantile_radius_array": (_signature(_VECTOR, _MATRIX, "float64"),),
    "exact_tube_step": (_signature(_VECTOR, _MATRIX, _CUBE, *[_VECTOR] * 5, _MATRIX, _VECTOR),),
    "track_update": (_signature(_MATRIX, _CUBE, _VECTOR, _MATRIX, "float64", _MATRIX),),
    "track_update_monitored": (
        _signature(
            _MATRIX,
            _CUBE,
            _VECTOR,
            _MATRIX,
            "float64",
            _MATRIX,
            _VECTOR,
            _MATRIX,
            *[_VECTOR] * 3,
            *["float64"] * 4,
        ),
        _signature(
            _VIEW.format(2),
            _VIEW.format(3),
            _VECTOR,
            _MATRIX,
            "float64",
            _MATRIX,
            _VIEW.format(1),
            _VIEW.format(2),
            _VIEW.format(1),
            _VECTOR,
            _VECTOR,
            *["float64"] * 4,
        ),
    ),
    # The tracker's discrete state, read-only views of Drake's vectors.
    "track_belief": (_signature(*[_READONLY_MATRIX] * 2, *["float64"] * 3, "int64", "int64"),),
    "anisotropic_invariants": (
        _signature(_VECTOR, _VECTOR, "float64", _MATRIX, _CUBE, _VECTOR, *["float64"] * 3),
    ),
    "anisotropic_invariants_packed": (
        _signature(_VECTOR, _VECTOR, _VECTOR, _MATRIX, *["float64"] * 3),
    ),
    "route_search": (
        _signature(
            _VECTOR,
            "float64",
            "int64[::1]",
            _VECTOR,
            _VECTOR,
            "float64",
            "float64",
            _CUBE,
            _MATRIX,
            _MATRIX,
            "float64",
            "int64",
            "float64",
            "float64",
            _MATRIX,
            _VECTOR,
            "float64",
            "float64",
            "int64",
        ),
    ),
    # Drake's Jacobian is column-major (Eigen).
    "arm_control": (
        _signature(
            "float64",
            *[_VECTOR] * 3,
            _FORTRAN_MATRIX,
            _VECTOR,
            "float64",
            *[_VECTOR] * 4,
            *["float64"] * 2,
            _VECTOR,
            "float64",
            *[_VECTOR] * 2,
            *["float64"] * 2,
        ),
    ),
}

#: The sources whose compiled code numba caches (modules of :mod:`stt_drake.core`): the
#: compiled modules, the plain-Python function :mod:`stt_drake.core._guide` compiles, the
#: contour table :mod:`stt_drake.core._anisotropic` freezes (from
#: :mod:`stt_drake.core.anisotropic_contour`), and the constants they read. Their hash (with
#: :data:`JIT_OPTIONS`) keys the cache folder (:func:`jit_options`).
CACHED_SOURCES = (
    "_kernels",
    "_tube",
    "_anisotropic",
    "_anisotropic_tube",
    "_invariants",
    "_tracking",
    "_guide",
    "_arm",
    "route_search",
    "anisotropic_contour",
    "constants",
)

#: Options of every compiled kernel (``numba.njit(**JIT_OPTIONS)``), after :func:`jit_options`.
JIT_OPTIONS: dict[str, Any] = {"cache": True, "error_model": "numpy", "nogil": True}

_state: dict[str, object] = {
    "pure_numpy": os.environ.get(PURE_NUMPY_ENV, "") not in ("", "0"),
    "modules": {},
    "cache": None,
    "warm": set(),  # the output dimensions whose kernels this process has loaded
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
    module = _module(KERNEL_MODULES[name])
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


def cache_key() -> str:
    """Hex digest (16 characters) of the sources of :data:`CACHED_SOURCES`, numba's version,
    Python's and :data:`JIT_OPTIONS`: the name of numba's cache folder for this code."""
    import numba

    digest = hashlib.sha256(f"{numba.__version__} {sys.version_info[:2]} {JIT_OPTIONS}".encode())
    folder = Path(__file__).parent
    for name in CACHED_SOURCES:
        digest.update(name.encode())
        digest.update((folder / f"{name}.py").read_bytes())
    return digest.hexdigest()[:16]


def jit_options() -> dict[str, Any]:
    """:data:`JIT_OPTIONS`, with numba's on-disk cache pointed (once per process, before the
    first kernel is defined: every compiled module calls this first) at a folder keyed by
    :func:`cache_key`: ``<NUMBA_CACHE_DIR>/stt_drake-<key>`` when the user set numba's
    cache folder, else ``stt_drake/core/__pycache__/numba-<key>`` (or, where the package is
    not writable, ``~/.cache/stt_drake/numba-<key>``). Returns the options for
    ``numba.njit``."""
    if _state["cache"] is None:
        from numba.core import config

        key = cache_key()
        if config.CACHE_DIR:
            folder = Path(config.CACHE_DIR) / f"stt_drake-{key}"
        else:
            package = Path(__file__).parent
            base = package / "__pycache__" if os.access(package, os.W_OK) else None
            base = base or Path.home() / ".cache" / "stt_drake"
            folder = base / f"numba-{key}"
        config.CACHE_DIR = str(folder)
        _state["cache"] = folder
    return dict(JIT_OPTIONS)


def kernels_cached() -> bool:
    """Whether numba's cache folder for this code (:func:`jit_options`) holds compiled
    kernels already; False: the first run compiles them (tens of seconds), or the numpy
    path is selected (True: nothing to compile)."""
    if _state["pure_numpy"]:
        return True
    jit_options()
    folder: Path = _state["cache"]  # type: ignore[assignment]
    return folder.is_dir() and any(folder.rglob("*.nbi"))


def warm_up(dimension: int) -> float:
    """Compile, or load from numba's on-disk cache, every kernel of :data:`KERNELS` that
    covers output dimension `dimension`, for the argument types of :data:`SIGNATURES`
    (a run calls this before its clock starts). Returns the seconds it took: 0.0 on the
    numpy path and once this process has loaded them (a run of a campaign worker need not
    parse the signatures again)."""
    warm: set[int] = _state["warm"]  # type: ignore[assignment]
    if _state["pure_numpy"] or dimension in warm:  # loaded kernels stay loaded
        return 0.0
    start = time.perf_counter()
    for name, dimensions in KERNELS.items():
        if dimensions is not None and dimension not in dimensions:
            continue
        kernel = compiled(name, dimension if dimensions is not None else None)
        if kernel is None:  # numba cannot be imported: the numpy path from now on
            return 0.0
        for signature in SIGNATURES[name]:
            kernel.compile(signature)
    warm.add(dimension)
    return time.perf_counter() - start
