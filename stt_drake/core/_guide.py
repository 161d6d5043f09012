"""Compiled (numba) kernel of the guide's route search: :func:`stt_drake.core.route_search.
search_route` under ``numba.njit`` (the one source of the search; the numpy path runs it as
plain Python). A test compares the two."""

from __future__ import annotations

from numba import njit

from stt_drake.core.route_search import search_route

route_search = njit(cache=True, error_model="numpy", nogil=True)(search_route)
