"""Compiled (numba) kernel of the guide's route search: :func:`stt_drake.core.route_search.
search_route` under ``numba.njit`` (the one source of the search; the numpy path runs it as
plain Python). A test compares the two.

The kernel is compiled from a copy of the function object that names this module as its
own (as every kernel of :mod:`stt_drake.core.backend` does); its code and globals stay
those of :mod:`stt_drake.core.route_search`, whose source is among those that key numba's
on-disk cache (:func:`stt_drake.core.backend.jit_options`)."""

from __future__ import annotations

import types

from numba import njit

from stt_drake.core.backend import jit_options
from stt_drake.core.route_search import search_route

_source = types.FunctionType(
    search_route.__code__, search_route.__globals__, "route_search", search_route.__defaults__
)
_source.__module__ = __name__
route_search = njit(**jit_options())(_source)
