"""Load every compiled kernel once before any row is timed, so no row pays numba's load;
the header names the stt_drake being timed (``make bench-compare`` times two)."""

from __future__ import annotations

import pytest

import stt_drake
from stt_drake.core import backend


def pytest_report_header() -> str:
    return f"stt_drake timed: {stt_drake.__file__}"


@pytest.fixture(scope="session", autouse=True)
def compiled_kernels() -> None:
    for dimension in (2, 3):
        backend.warm_up(dimension)
