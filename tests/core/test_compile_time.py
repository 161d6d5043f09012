"""Kernel compilation (or loading numba's on-disk cache) is done before a run's clock starts
and reported apart as `compile_time_s`: the real-time factor is simulated time over the
simulation's own wall time. No wall-clock speed is asserted."""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import pytest

from stt_drake import run as run_module
from stt_drake.assembly import load_scenario
from stt_drake.core import backend
from stt_drake.run import simulate
from tests.conftest import printed_json

ROOT = Path(__file__).resolve().parents[2]
CASE1 = ROOT / "diagrams" / "omni_hardware_case1.yaml"
ENV = {**os.environ, "MPLBACKEND": "Agg", "DRAKE_ALLOW_NETWORK": "meshcat:package_map"}

#: (scenario, fixed update rate in Hz or None for the scenario's own).
CLOSED_LOOPS = (
    ("omni_hardware_case1", None),
    ("uav_cluttered", 100.0),
    ("omni_anisotropic", None),
    ("uav_anisotropic", None),
    ("omni_tracked", None),
    ("liveness_clutter_2d", None),
    ("franka_pick_place_case1", None),
)

#: Two short runs in one fresh process; prints their metrics and whether numba compiles.
TWO_RUNS = f"""
import json
import numba
from stt_drake.assembly import load_scenario
from stt_drake.core import backend
from stt_drake.run import simulate

scenario = load_scenario({str(CASE1)!r})
scenario.duration = 0.5
metrics = [simulate(scenario).metrics for _ in range(2)]
keys = ("compile_time_s", "wall_time_s", "sim_time_s", "realtime_factor")
print(json.dumps({{
    "compiled": backend.using_compiled() and not numba.config.DISABLE_JIT,
    "runs": [{{key: m[key] for key in keys}} for m in metrics],
}}))
"""


#: Short runs of every kind of loop (2D and 3D, continuous and fixed-rate, full covariance,
#: tracker, guide) in one fresh process after backend.warm_up: prints the kernels that
#: gained a specialisation (argument types) during the runs, i.e. that warm_up missed.
AFTER_WARM_UP = f"""
import importlib, json
from stt_drake.assembly import load_scenario
from stt_drake.core import backend
from stt_drake.run import simulate

def signatures():
    return {{
        name: len(getattr(importlib.import_module(f"stt_drake.core.{{module}}"), name).signatures)
        for name, module in backend.KERNEL_MODULES.items()
    }}

for n in backend.COMPILED_DIMENSIONS:
    backend.warm_up(n)
before = signatures()
for name, rate in {CLOSED_LOOPS!r}:
    scenario = load_scenario({str(ROOT / "diagrams")!r} + f"/{{name}}.yaml")
    scenario.duration = min(scenario.duration, 1.0)
    if rate is not None:
        scenario.tube.update_rate_hz = rate
    simulate(scenario)
gained = {{name: count - before[name] for name, count in signatures().items()}}
print(json.dumps({{name: count for name, count in gained.items() if count}}))
"""


def _printed_json(code: str) -> Any:
    """The JSON object printed last by `code`, run in a fresh Python process."""
    return printed_json(code, ENV, ROOT, timeout=900)


def _assert_factor_is_sim_over_wall(metrics: dict) -> None:
    assert metrics["wall_time_s"] > 0.0
    assert metrics["realtime_factor"] == metrics["sim_time_s"] / metrics["wall_time_s"]


@pytest.mark.slow
def test_first_run_of_a_process_loads_the_kernels_before_its_clock():
    report = _printed_json(TWO_RUNS)
    first, second = report["runs"]
    for metrics in (first, second):
        assert metrics["compile_time_s"] >= 0.0
        _assert_factor_is_sim_over_wall(metrics)
    if report["compiled"]:
        # The first run loads (or compiles) every kernel (backend.warm_up); the second finds
        # them loaded and does not even parse their signatures again.
        assert first["compile_time_s"] > 0.0
        assert second["compile_time_s"] == 0.0
    else:  # the numpy path compiles nothing
        assert first["compile_time_s"] == second["compile_time_s"] == 0.0


def test_wall_time_excludes_the_kernel_loading(monkeypatch):
    """A kernel loading that takes 1000 s on the run's clock is reported as compile time
    and is not in wall_time_s."""
    offset = [0.0]
    real_clock = time.perf_counter
    monkeypatch.setattr(run_module.time, "perf_counter", lambda: real_clock() + offset[0])
    load_kernels = run_module.load_kernels

    def slow_load_kernels(scenario, built):
        seconds = load_kernels(scenario, built)
        offset[0] += 1000.0
        return seconds + 1000.0

    monkeypatch.setattr(run_module, "load_kernels", slow_load_kernels)
    scenario = load_scenario(CASE1)
    scenario.duration = 0.2
    metrics = simulate(scenario).metrics
    assert metrics["compile_time_s"] >= 1000.0
    assert metrics["wall_time_s"] < 1000.0
    _assert_factor_is_sim_over_wall(metrics)


def test_the_numpy_path_reports_no_compile_time():
    scenario = load_scenario(CASE1)
    scenario.duration = 0.2
    with backend.pure_numpy():
        metrics = simulate(scenario).metrics
    assert metrics["compile_time_s"] == 0.0
    _assert_factor_is_sim_over_wall(metrics)


@pytest.mark.slow
def test_warm_up_compiles_every_specialisation_a_run_calls():
    """backend.SIGNATURES lists the argument types the callers pass: after backend.warm_up,
    short runs of every kind of loop compile nothing more inside their clock."""
    assert _printed_json(AFTER_WARM_UP) == {}
