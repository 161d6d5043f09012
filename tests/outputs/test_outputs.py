"""What the package writes: strict JSON (no NaN/Infinity tokens, non-finite values as null
named in "non_finite"), and output folders checked before any work (`run --out`, the
folder derived from a scenario's name, `campaign --out`)."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import stt_drake.run
from stt_drake.cli.main import BadInputError, main, results_folder
from stt_drake.metrics import RunMetrics
from stt_drake.run import RunResult, write_outputs
from stt_drake.runlog import RunLog, restore_non_finite, strict_json, unwritable_reason
from tests.outputs.test_plotting import make_log

ROOT = Path(__file__).resolve().parents[2]
CASE1 = ROOT / "diagrams" / "omni_hardware_case1.yaml"


def _strict_load(text: str) -> dict:
    """json.loads that refuses the NaN/Infinity tokens Python's json accepts by default."""

    def refuse(token: str) -> None:
        raise AssertionError(f"non-standard JSON token {token}")

    return json.loads(text, parse_constant=refuse)


def _non_finite_metrics() -> RunMetrics:
    """A metrics record as a run with σ = ∞ or a run that evaluated nothing would give."""
    return RunMetrics(
        scenario="hostile",
        reached=False,
        t_tube_in_target=None,
        t_output_in_target=None,
        holds=False,
        sim_time_s=1.5,
        wall_time_s=0.0,
        compile_time_s=0.0,
        realtime_factor=math.inf,
        steps=0,
        holds_tolerance=1e-9,
        stop_reason=None,
        strict_stop=None,
        first_violation=None,
        invariants={
            "output_in_tube": {"holds": True, "worst_margin": math.inf, "t_worst": 0.0},
            "radius_positive": {"holds": False, "worst_margin": -math.inf, "t_worst": 1.5},
        },
        reach={},
        warnings=[],
        assumptions=[],
        belief_discontinuities=[],
        recovery=[],
        stalls=[],
        step_rate={"max_window_steps_per_s": float("nan"), "window_steps": np.int64(7)},
        obstacles=[{"index": 0, "sigma": np.float64(np.inf), "epsilon": 0.9}],
        tracks=[],
        plant={"shape": np.array([1.0, np.inf])},
    )


def test_metrics_record_is_the_metrics_json_document():
    """One schema: the record's keys are its fields in order, then the plant's keys; it
    reads as a mapping of those keys."""
    metrics = _non_finite_metrics()
    document = metrics.as_dict()
    assert list(document)[:4] == ["scenario", "reached", "t_tube_in_target", "t_output_in_target"]
    assert list(document)[-2:] == ["tracks", "shape"]
    assert list(metrics) == list(document) and len(metrics) == len(document)
    assert metrics["holds"] is metrics.holds is False
    assert metrics["shape"] is metrics.plant["shape"]
    assert metrics.get("limits") is None and "plant" not in metrics


def test_metrics_json_is_strict_and_names_each_non_finite_value(tmp_path):
    metrics = _non_finite_metrics()
    result = RunResult(metrics=metrics, log=RunLog(make_log()))
    write_outputs(result, tmp_path, figures=False)
    text = (tmp_path / "metrics.json").read_text()
    assert "Infinity" not in text and "NaN" not in text
    written = _strict_load(text)
    assert written["realtime_factor"] is None
    assert written["invariants"]["output_in_tube"]["worst_margin"] is None
    assert written["obstacles"][0]["sigma"] is None
    assert written["step_rate"] == {"max_window_steps_per_s": None, "window_steps": 7}
    assert written["t_tube_in_target"] is None  # a plain null: not a non-finite number
    assert written["t_output_in_target"] is None
    assert written["non_finite"] == {
        "/realtime_factor": "inf",
        "/invariants/output_in_tube/worst_margin": "inf",
        "/invariants/radius_positive/worst_margin": "-inf",
        "/obstacles/0/sigma": "inf",
        "/step_rate/max_window_steps_per_s": "nan",
        "/shape/1": "inf",
    }
    restored = restore_non_finite(written)
    assert restored["invariants"]["radius_positive"]["worst_margin"] == -math.inf
    assert restored["obstacles"][0]["sigma"] == math.inf
    assert math.isnan(restored["step_rate"]["max_window_steps_per_s"])
    assert "non_finite" not in restored
    assert np.load(tmp_path / "log.npz")["t"].shape == (50,)


def test_a_finite_document_has_no_non_finite_key_and_json_pointers_are_escaped():
    assert "non_finite" not in json.loads(strict_json({"a": [1.0, 2], "b": None}))
    odd = json.loads(strict_json({"a/b": {"c~d": math.inf}}))
    assert odd["non_finite"] == {"/a~1b/c~0d": "inf"}
    assert restore_non_finite(odd) == {"a/b": {"c~d": math.inf}}


# --------------------------------------------------------------------------- output folders


def test_unwritable_reason_finds_a_file_in_the_way_and_writes_nothing(tmp_path):
    assert unwritable_reason(tmp_path / "new" / "deeper") is None
    assert list(tmp_path.iterdir()) == []  # the probe leaves nothing behind
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    assert "is not a folder" in unwritable_reason(blocker)
    assert f"{blocker} is in the way" in unwritable_reason(blocker / "sub")


def test_run_refuses_an_unwritable_out_before_simulating(tmp_path, capsys, monkeypatch):
    def no_simulation(*args, **kwargs):
        raise AssertionError("the simulation ran before --out was checked")

    monkeypatch.setattr(stt_drake.run, "simulate", no_simulation)
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    assert main(["run", str(CASE1), "--out", str(blocker / "out"), "--no-figures"]) == 2
    err = capsys.readouterr().err
    assert "--out" in err and str(blocker) in err and "is in the way" in err


@pytest.mark.parametrize("name", ["../escape", "/tmp/escape", "a/b", "..", ".", "", "a\\b"])
def test_a_name_that_is_not_a_plain_folder_name_cannot_leave_results(name):
    with pytest.raises(BadInputError, match="cannot name a folder inside results/"):
        results_folder(name, "name")


def test_results_folder_of_a_plain_name():
    assert results_folder("omni_hardware_case1", "name") == Path("results/omni_hardware_case1")


@pytest.mark.slow
def test_a_scenario_named_like_a_path_writes_nothing_outside_results(tmp_path):
    """Refused (by the scenario's validation or the CLI's own check), exit 2, no traceback."""
    work = tmp_path / "project"
    work.mkdir()
    scenario = work / "escape.yaml"
    text = CASE1.read_text().replace("name: omni_hardware_case1", "name: ../../escaped")
    scenario.write_text(text.replace("duration: 25.0", "duration: 0.2"))
    completed = subprocess.run(
        [str(Path(sys.executable).parent / "stt-drake"), "run", str(scenario), "--no-figures"],
        cwd=work,
        capture_output=True,
        text=True,
        env={**os.environ, "MPLBACKEND": "Agg"},
        timeout=120,
        check=False,
    )
    assert completed.returncode == 2, completed.stdout + completed.stderr
    assert "name" in completed.stderr and "Traceback" not in completed.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["project"]
    assert sorted(p.name for p in work.iterdir()) == ["escape.yaml"]


def test_campaign_refuses_an_unwritable_out_before_any_work(tmp_path, capsys):
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    args = ["campaign", str(CASE1), "--runs", "5", "--out", str(blocker / "c"), "--no-progress"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "--out" in err and "is in the way" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file.txt"]
