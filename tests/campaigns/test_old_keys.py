"""A folder written before the reach times were renamed (`t_reach` → `t_tube_in_target`,
`t_reach_s` → `t_output_in_target_s`) resumes cleanly: its run and draw records are redone
(the record checks refuse them, and say so), the saved closed loop's summary is read with
the new name, and nothing crashes."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from stt_drake.campaign.folder import CHECKSUM_KEY, record_line
from stt_drake.cli.main import main

ROOT = Path(__file__).resolve().parents[2]
RANDOM = ROOT / "tests" / "data" / "random_small.yaml"
CASE1 = ROOT / "diagrams" / "omni_hardware_case1.yaml"


def _rename_in_lines(path: Path, old: str, new: str) -> None:
    """Rewrite a .jsonl file as an older version wrote it: key `new` named `old`, each line
    with a right checksum (so only the record check can refuse it)."""
    lines = []
    for line in path.read_text().splitlines():
        record = json.loads(line)
        del record[CHECKSUM_KEY]
        record = {(old if key == new else key): value for key, value in record.items()}
        lines.append(record_line(record))
    path.write_text("\n".join(lines) + "\n")


def _records(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


@pytest.mark.slow
def test_a_randomisation_campaign_redoes_runs_recorded_with_the_old_key(tmp_path, capsys):
    out = tmp_path / "out"
    args = ["campaign", str(RANDOM), "--kind", "randomisation", "--runs", "2", "--workers", "1"]
    args += ["--quiet", "--no-figures", "--out", str(out)]
    main(args)
    before = json.loads((out / "campaign.json").read_text())
    assert before["t_tube_in_target"]["median"] is not None
    _rename_in_lines(out / "runs.jsonl", "t_reach", "t_tube_in_target")
    capsys.readouterr()
    main([*args, "--resume"])
    err = capsys.readouterr().err
    assert "2 malformed line(s) skipped" in err and "Traceback" not in err
    after = json.loads((out / "campaign.json").read_text())
    assert after["t_tube_in_target"] == before["t_tube_in_target"]  # the same runs, redone
    assert after["t_tube_in_target_percentiles"] == before["t_tube_in_target_percentiles"]
    assert all("t_reach" not in r for r in _records(out / "runs.jsonl")[-2:])


@pytest.mark.slow
def test_a_true_obstacle_campaign_reads_an_old_closed_loop_summary(tmp_path, capsys):
    scenario = tmp_path / "short.yaml"
    scenario.write_text(CASE1.read_text().replace("duration: 25.0", "duration: 8.0"))
    out = tmp_path / "out"
    args = ["campaign", str(scenario), "--runs", "20", "--workers", "1", "--quiet"]
    args += ["--no-figures", "--out", str(out)]
    main(args)
    saved = json.loads((out / "closed_loop.json").read_text())
    assert saved["t_tube_in_target"] is not None
    old = {("t_reach" if k == "t_tube_in_target" else k): v for k, v in saved.items()}
    (out / "closed_loop.json").write_text(json.dumps(old))
    capsys.readouterr()
    main([*args, "--resume"])
    assert "Traceback" not in capsys.readouterr().err
    loop = json.loads((out / "campaign.json").read_text())["closed_loop"]
    assert loop == saved


@pytest.mark.slow
def test_a_draws_comparison_redoes_draws_recorded_with_the_old_key(tmp_path, capsys):
    out = tmp_path / "out"
    args = ["compare", str(RANDOM), "--controllers", "stt", "--draws", "2", "--workers", "1"]
    args += ["--quiet", "--out", str(out)]
    assert main(args) == 0
    before = json.loads((out / "comparison.json").read_text())["rows"]
    assert before[0]["t_output_in_target_p50_s"] is not None
    _rename_in_lines(out / "draws.jsonl", "t_reach_s", "t_output_in_target_s")
    capsys.readouterr()
    assert main([*args, "--resume"]) == 0
    err = capsys.readouterr().err
    assert err.count("not a draw record of this comparison; redone") == 2
    after = json.loads((out / "comparison.json").read_text())["rows"]
    assert [r["t_output_in_target_p50_s"] for r in after] == [
        r["t_output_in_target_p50_s"] for r in before
    ]
    assert "# Controller comparison over draws: random_small" in (out / "comparison.md").read_text()
