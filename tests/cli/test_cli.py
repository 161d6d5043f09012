"""The `stt-drake` command: summary, files, the metrics.json contract and exit codes."""

from __future__ import annotations

import json
import math
import os
import platform
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from stt_drake.cli.main import main
from tests.conftest import INVARIANT_KEYS

ROOT = Path(__file__).resolve().parents[2]
CASE1 = ROOT / "diagrams" / "omni_hardware_case1.yaml"


def _console_script() -> str:
    script = Path(sys.executable).parent / "stt-drake"
    assert script.exists(), "the stt-drake console script is not installed next to python"
    return str(script)


@pytest.mark.slow
def test_run_default_scenario_writes_contract_files(tmp_path):
    """`stt-drake run` from the project root: default scenario, default out folder."""
    work = tmp_path / "project"
    shutil.copytree(ROOT / "diagrams", work / "diagrams")
    completed = subprocess.run(
        [_console_script(), "run"],
        cwd=work,
        capture_output=True,
        text=True,
        env={**os.environ, "MPLBACKEND": "Agg"},
        timeout=600,
        check=False,
    )
    assert completed.returncode == 0, completed.stdout + completed.stderr
    out = work / "results" / "omni_hardware_case1"
    for name in ("metrics.json", "log.npz", "snapshots.png", "tube_3d.png", "margins.png"):
        assert (out / name).stat().st_size > 0, name
    assert "reached the target set: yes" in completed.stdout
    for key in INVARIANT_KEYS:
        assert key in completed.stdout
    assert "real-time factor" in completed.stdout

    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["scenario"] == "omni_hardware_case1"
    assert metrics["reached"] is True
    t_c = metrics["t_tube_in_target"]
    assert isinstance(t_c, float) and 0 < t_c < metrics["sim_time_s"]
    assert metrics["sim_time_s"] == pytest.approx(25.0)
    assert metrics["wall_time_s"] > 0
    assert set(metrics["invariants"]) == INVARIANT_KEYS
    for record in metrics["invariants"].values():
        assert set(record) == {"holds", "worst_margin", "t_worst"}
        assert record["holds"] is True and math.isfinite(record["worst_margin"])
    assert len(metrics["obstacles"]) == 4
    assert all(o["min_distance_to_mean"] > 0 for o in metrics["obstacles"])
    # A normal end: no stop reason, one entry into the target set, nothing broken or jumping.
    assert metrics["stop_reason"] is None
    assert metrics["reach"] == {
        "first_entry_s": metrics["t_tube_in_target"],
        "entries_s": [metrics["t_tube_in_target"]],
        "exits_s": [],
        "final_entry_s": metrics["t_tube_in_target"],
    }
    for key in ("warnings", "assumptions", "belief_discontinuities", "recovery", "stalls"):
        assert metrics[key] == [], key

    log = np.load(out / "log.npz")
    assert log["output"].shape == (len(log["t"]), 2)
    assert log["t"][-1] == pytest.approx(25.0)
    # The output's final entry: the first logged time from which ‖y − η‖ ≤ R_T holds to the
    # end; y stays in the tube, so it is inside no later than the tube.
    inside = np.linalg.norm(log["output"] - log["target"], axis=1) <= log["target_set_radius"]
    assert inside[-1] and not inside[0]
    entry = log["t"][np.flatnonzero(~inside)[-1] + 1]
    assert metrics["t_output_in_target"] == entry <= metrics["t_tube_in_target"]
    assert f"tube inside the target set at t_c = {metrics['t_tube_in_target']:.2f} s" in (
        completed.stdout
    )


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "scenario.yaml"
    path.write_text(text)
    return path


def _case1_with(**replacements: str) -> str:
    text = CASE1.read_text()
    for old, new in replacements.items():
        assert old in text
        text = text.replace(old, new)
    return text


@pytest.mark.slow
def test_bad_scenario_exits_2_with_named_field_and_no_traceback(tmp_path):
    bad = _write(tmp_path, _case1_with(**{"r_min: 0.21": "r_min: 0.5"}))
    completed = subprocess.run(
        [_console_script(), "run", str(bad), "--out", str(tmp_path / "out")],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert completed.returncode == 2
    assert "scenario.tube.r_max" in completed.stderr and "r_min" in completed.stderr
    assert "Traceback" not in completed.stderr + completed.stdout
    assert not (tmp_path / "out").exists()


def test_missing_scenario_file_exits_2(tmp_path, capsys):
    assert main(["run", str(tmp_path / "nope.yaml")]) == 2
    assert "no such scenario file" in capsys.readouterr().err


def test_unreached_target_exits_1(tmp_path, capsys):
    short = _write(tmp_path, _case1_with(**{"duration: 25.0": "duration: 2.0"}))
    code = main(["run", str(short), "--out", str(tmp_path / "out"), "--no-figures"])
    out = capsys.readouterr().out
    assert code == 1
    assert "reached the target set: NO" in out and "FAILURE" in out
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics["reached"] is False and metrics["t_tube_in_target"] is None
    assert all(record["holds"] for record in metrics["invariants"].values())


#: Parked far away, then at t = 3 s on the centre's path (case 1's c(3 s) ≈ (2.73, 2.11)).
JUMPING_OBSTACLE = """  - motion: !Waypoints
      times: [0.0, 3.0, 3.0, 25.0]
      positions: [[4.5, 0.5], [4.5, 0.5], [2.6, 2.45], [2.6, 2.45]]
    radius: 0.15
    sigma: 0.1
    epsilon: 0.9
    p_d: 0.9999
"""


@pytest.mark.slow
def test_violated_guarantee_exits_1_and_strict_mode_stops_at_it(tmp_path, capsys):
    """A belief that jumps onto the tube at t = 3 s (a Waypoints step: an obstacle first
    seen late): the radius drops at once, y is left outside Γ and the centre inside the ε
    set until it recovers. Strict mode stops the Simulator at the first violation and
    names the invariant, time and margin."""
    weak = _write(tmp_path, _case1_with(**{"obstacles:\n": "obstacles:\n" + JUMPING_OBSTACLE}))
    code = main(["run", str(weak), "--out", str(tmp_path / "lax"), "--no-figures"])
    assert code == 1
    lax = json.loads((tmp_path / "lax" / "metrics.json").read_text())
    assert lax["invariants"]["output_in_tube"]["holds"] is False
    assert lax["invariants"]["output_in_tube"]["worst_margin"] < 0
    assert lax["stop_reason"] is None
    # The step is the run's one belief discontinuity; the tube recovers from it.
    (jump,) = lax["belief_discontinuities"]
    assert jump["obstacle"] == 0 and jump["t"] == pytest.approx(3.0, abs=0.02)
    assert jump["mean_jump_m"] == pytest.approx(np.hypot(1.9, 1.95), rel=1e-6)
    assert jump["q_before"] > 0.9 > jump["q_after"]  # ε = 0.9
    (episode,) = [e for e in lax["recovery"] if e["obstacle"] == 0]
    assert episode["start_s"] == pytest.approx(jump["t"]) and episode["end_s"] > jump["t"]
    assert episode["worst_margin"] < 0
    out = capsys.readouterr().out
    assert "VIOLATED" in out
    assert "belief discontinuities: 1" in out and "recovery episodes: " in out

    code = main(["run", str(weak), "--out", str(tmp_path / "strict"), "--no-figures", "--strict"])
    assert code == 1
    strict = json.loads((tmp_path / "strict" / "metrics.json").read_text())
    assert "output_in_tube" in strict["strict_stop"] and "t = " in strict["strict_stop"]
    assert strict["stop_reason"].startswith("strict mode stopped the run")
    assert strict["strict_stop"] in strict["stop_reason"]
    # The centre's margin is the worst: the jump put it deep inside obstacle 0's ε set.
    worst = strict["invariants"]["center_avoid_probability"]
    assert strict["stop_reason"].endswith(
        f"worst margin so far: center_avoid_probability {worst['worst_margin']:+.2e} at "
        f"t = {worst['t_worst']:.2f} s"
    )
    assert strict["sim_time_s"] < lax["sim_time_s"]
    t_first = strict["invariants"]["output_in_tube"]["t_worst"]
    assert strict["sim_time_s"] == pytest.approx(t_first, abs=0.05)


def test_version_names_the_package_drake_numba_and_python(capsys):
    from importlib.metadata import version

    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    line = capsys.readouterr().out.strip()
    assert line.startswith(f"stt-drake {version('stt-drake')} (drake {version('drake')}, ")
    assert f"numba {version('numba')}" in line and f"Python {platform.python_version()}" in line


def test_a_command_says_when_it_compiles_the_kernels(tmp_path):
    """With numba's cache folder empty (NUMBA_CACHE_DIR pointing at a new folder) the CLI
    says it is compiling before it starts; with the kernels cached it says nothing."""
    code = "from stt_drake.cli.main import announce_compilation; announce_compilation()"

    def stderr_of(env: dict[str, str]) -> str:
        completed = subprocess.run(
            [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120
        )
        assert completed.returncode == 0, completed.stderr
        return completed.stderr

    fresh = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba")}
    assert "compiling the numba kernels (first run only" in stderr_of(fresh)
    from stt_drake.core.backend import warm_up

    warm_up(2)  # this process's kernels, in its cache folder (the same environment's)
    assert stderr_of(dict(os.environ)) == ""
