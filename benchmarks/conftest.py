"""Load every compiled kernel once before any row is timed, so no row pays numba's load;
the header names the stt_drake being timed (``make bench-compare`` times two)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

import stt_drake
from stt_drake.core import backend


def pytest_report_header() -> str:
    return f"stt_drake timed: {stt_drake.__file__}"


def pytest_sessionstart(session: pytest.Session) -> None:
    """With ``STT_DRAKE_BENCH_TREE`` set (``make bench-compare``), stop unless the stt_drake
    imported is that tree's: pytest puts the folder it runs from first on ``sys.path``, so
    a run from another folder would silently time that folder's code."""
    tree = os.environ.get("STT_DRAKE_BENCH_TREE")
    imported = Path(stt_drake.__file__).resolve()
    if tree and not imported.is_relative_to(Path(tree).resolve()):
        pytest.exit(f"benchmarks: asked to time {tree}, but imported {imported}", returncode=2)


@pytest.fixture(scope="session", autouse=True)
def compiled_kernels() -> None:
    for dimension in (2, 3):
        backend.warm_up(dimension)
