"""numba's on-disk cache can never hand back a stale compiled kernel: a changed callee in
another file, or a changed constant of stt_drake.core.constants, is compiled afresh
(stt_drake.core.backend.jit_options keys the cache folder on every compiled source).

Each case runs in a fresh process on a copy of the package, with the cache folder in a
temporary NUMBA_CACHE_DIR (so the user's setting is honoured, and nothing is shared with
the working tree's cache)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from stt_drake.core import backend
from tests.conftest import printed_json

PACKAGE = Path(backend.__file__).resolve().parents[1]

#: Two kernels of stt_drake.core._tube whose values depend on other files: the boundary
#: layer weight reads constants.BOUNDARY_LAYER; period_avoid_probability calls
#: _kernels.chi_sf.
PROBE = """
import json
from stt_drake.core import _tube, backend
print(json.dumps({
    "file": _tube.__file__,
    "cache": str(backend._state["cache"]),
    "weight": _tube._layer_weight(0.905, 0.9, 1.0),
    "probability": _tube.period_avoid_probability(2.0, 0.3, 0.5, 0.1, 0.01, 2),
}))
"""


def _probe(root: Path, cache: Path) -> dict:
    environment = {
        key: value for key, value in os.environ.items() if not key.startswith("NUMBA_")
    }
    environment.update(
        PYTHONPATH=str(root), NUMBA_CACHE_DIR=str(cache), STT_DRAKE_PURE_NUMPY=""
    )
    return printed_json(PROBE, environment, root, timeout=600)


def _replace(path: Path, old: str, new: str) -> None:
    text = path.read_text(encoding="utf-8")
    assert text.count(old) == 1, old
    path.write_text(text.replace(old, new), encoding="utf-8")


@pytest.mark.slow
def test_a_changed_constant_or_callee_is_recompiled_not_loaded_stale(tmp_path):
    root = tmp_path / "tree"
    shutil.copytree(PACKAGE, root / "stt_drake", ignore=shutil.ignore_patterns("__pycache__"))
    cache = tmp_path / "numba-cache"
    core = root / "stt_drake" / "core"

    first = _probe(root, cache)
    assert Path(first["file"]).is_relative_to(root)
    assert Path(first["cache"]).parent == cache  # beneath the user's NUMBA_CACHE_DIR
    assert first["weight"] == pytest.approx(0.5)
    assert _probe(root, cache) == first  # unchanged sources: the same cache folder, reused

    _replace(core / "constants.py", "BOUNDARY_LAYER = 0.1\n", "BOUNDARY_LAYER = 0.2\n")
    second = _probe(root, cache)
    assert second["weight"] == pytest.approx(0.75)
    assert second["cache"] != first["cache"]

    _replace(  # the callee: chi_sf now answers 1/4 wherever it computes
        core / "_kernels.py", "    return chi_sf_pdf(b, a, n)[0]\n", "    return 0.25\n"
    )
    third = _probe(root, cache)
    assert first["probability"] != 0.25
    assert third["probability"] == 0.25
    assert {path.name for path in cache.iterdir()} == {
        Path(result["cache"]).name for result in (first, second, third)
    }
