"""Shared fixtures: closed-loop runs are expensive, so each scenario is simulated once per
test session (tests run with `--dist loadfile`, so one worker owns each test file)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from stt_drake.assembly import load_scenario
from stt_drake.run import RunResult, simulate

DIAGRAMS = Path(__file__).resolve().parent.parent / "diagrams"

#: The guarantee keys of the `metrics.json` contract (issue text), written out here rather
#: than imported from the code under test.
INVARIANT_KEYS = {
    "output_in_tube",
    "center_avoid_probability",
    "tube_avoid_probability",
    "output_avoid_probability",
    "radius_positive",
}


@pytest.fixture(scope="session")
def run_scenario():
    """Simulate diagrams/<name>.yaml once and cache the RunResult."""
    cache: dict[str, RunResult] = {}

    def run(name: str) -> RunResult:
        if name not in cache:
            cache[name] = simulate(load_scenario(DIAGRAMS / f"{name}.yaml"))
        return cache[name]

    return run


def printed_json(code: str, env: dict[str, str], cwd: Path, timeout: float) -> Any:
    """The JSON value printed on the last line by `code`, run in a fresh Python process with
    environment `env` in folder `cwd`; the process must exit 0 within `timeout` seconds."""
    completed = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        env=env,
        cwd=cwd,
        timeout=timeout,
        check=False,
    )
    assert completed.returncode == 0, completed.stderr
    return json.loads(completed.stdout.strip().splitlines()[-1])
