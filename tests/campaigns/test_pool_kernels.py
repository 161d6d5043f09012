"""A local pool whose runs simulate has its forkserver load the scenario dimension's
compiled kernels once: its workers start with them loaded (they do not load them again)."""

from __future__ import annotations

import importlib
import os
from pathlib import Path

import pytest

from stt_drake.core import backend
from tests.conftest import printed_json

ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "MPLBACKEND": "Agg", "DRAKE_ALLOW_NETWORK": "meshcat:package_map"}


def kernels_without_signature(dimension: int) -> list[str]:
    """The kernels :func:`stt_drake.core.backend.warm_up` loads for `dimension` that have
    no compiled signature in this process yet (in a pool worker: what it would load)."""
    return [
        name
        for name, dimensions in backend.KERNELS.items()
        if dimensions is None or dimension in dimensions
        if not getattr(
            importlib.import_module(f"stt_drake.core.{backend.KERNEL_MODULES[name]}"), name
        ).signatures
    ]


#: A fresh process (its own forkserver) asks its pool's worker which kernels it lacks.
PROBE = """
import json
from stt_drake.campaign.backends import LocalPool
from stt_drake.core import backend
from tests.campaigns.test_pool_kernels import kernels_without_signature

pool = LocalPool(1, ["stt_drake.run"], kernels={kernels})
try:
    missing = pool.executor.submit(kernels_without_signature, 2).result()
finally:
    pool.close()
print(json.dumps({{"compiled": backend.using_compiled(), "missing": missing}}))
"""


@pytest.mark.parametrize("kernels", [2, None])
def test_the_forkserver_loads_the_kernels_its_workers_start_with(kernels):
    report = printed_json(PROBE.format(kernels=kernels), ENV, ROOT, timeout=600)
    every = [name for name, dims in backend.KERNELS.items() if dims is None or 2 in dims]
    loaded = kernels is not None and report["compiled"]  # the numpy path loads nothing
    assert report["missing"] == ([] if loaded else every)
