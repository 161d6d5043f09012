"""The command line a newcomer meets: `compare` and `campaign` defaults and progress lines
(on a terminal only, off with --quiet), the verdict words, comparison.md's heading and
legend, `list`'s whole first sentences and every subcommand's exit codes in its help."""

from __future__ import annotations

import io
import re
import sys
import textwrap
from pathlib import Path

import pytest

from stt_drake.campaign.summaries import verdict_table_lines
from stt_drake.cli import main as main_module
from stt_drake.cli import progress as progress_module
from stt_drake.cli.list import first_sentence, header_paragraph
from stt_drake.cli.main import main, packaged_scenarios
from stt_drake.cli.progress import CountProgress
from stt_drake.compare import comparison_markdown, comparison_table, row_verdict
from stt_drake.compare_draws import draws_markdown
from tests.conftest import DIAGRAMS

CASE1 = DIAGRAMS / "omni_hardware_case1.yaml"


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


@pytest.fixture
def renamed_scenario(tmp_path) -> Path:
    """Case 1 under a file name that differs from its `name` field."""
    path = tmp_path / "file_stem.yaml"
    path.write_text(CASE1.read_text().replace("name: omni_hardware_case1", "name: renamed"))
    assert "name: renamed" in path.read_text()
    return path


# ----------------------------------------------------------------------- compare's defaults


@pytest.fixture
def fake_compare(monkeypatch):
    """stt_drake.compare.compare replaced by a recorder: the command's wiring, no work."""
    calls = []

    def compare(scenario, controllers, runs, out_dir, **options):
        calls.append({"controllers": controllers, "out": out_dir, **options})
        return {"rows": []}

    monkeypatch.setattr("stt_drake.compare.compare", compare)
    return calls


@pytest.mark.parametrize(
    ("terminal", "flags", "progress"),
    [(True, [], True), (True, ["--quiet"], False), (False, [], False)],
)
def test_compare_defaults_and_progress(
    fake_compare, renamed_scenario, monkeypatch, tmp_path, capsys, terminal, flags, progress
):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "stderr", Terminal() if terminal else io.StringIO())
    assert main(["compare", str(renamed_scenario), "--runs", "10", *flags]) == 0
    (call,) = fake_compare
    assert call["controllers"] == ["stt", "cbf", "apf"]
    assert call["out"] == Path("results") / "renamed_compare"  # the name field, as `run`
    assert isinstance(call["progress"], CountProgress) is progress


def test_compare_help_names_the_defaults(capsys):
    with pytest.raises(SystemExit):
        main(["compare", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "default: stt cbf apf" in text
    assert "results/<scenario name>_compare/" in text


# ---------------------------------------------------------------------- campaign's defaults


@pytest.mark.parametrize(
    ("terminal", "flags", "progress"),
    [
        (True, [], True),
        (True, ["--quiet"], False),
        (True, ["--no-progress"], False),
        (False, [], False),
    ],
)
def test_campaign_defaults_and_progress(
    renamed_scenario, monkeypatch, tmp_path, terminal, flags, progress
):
    calls = []

    def run_campaign(spec, out_dir, **options):
        calls.append({"out": out_dir, **options})
        raise KeyboardInterrupt  # stop there: the command reports it, exit 1

    monkeypatch.setattr("stt_drake.cli.campaign.run_campaign", run_campaign)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "stderr", Terminal() if terminal else io.StringIO())
    assert main(["campaign", str(renamed_scenario), "--runs", "10", *flags]) == 1
    (call,) = calls
    assert call["out"] == Path("results") / "renamed" / "campaign_true-obstacles"
    assert call["progress"] is progress


def test_campaign_kind_help_explains_every_kind(capsys):
    with pytest.raises(SystemExit):
        main(["campaign", "--help"])
    text = re.sub(r"-\n\s+", "-", capsys.readouterr().out)  # argparse wraps after a hyphen
    text = " ".join(text.split())
    for kind, words in (
        ("true-obstacles", "against one simulated closed loop"),
        ("randomisation", "redraw the scenario's random_obstacles per run"),
        ("end-to-end", "sensor, tracker and controller per run"),
    ):
        assert re.search(rf"{kind}( \(default\))?: [^;]*{re.escape(words)}", text), kind


# ------------------------------------------------------------------------------ progress


def test_count_progress_says_done_elapsed_rate_and_time_left(monkeypatch):
    clock = iter([0.0, 0.0, 4.0, 10.0])  # start, then one reading per call
    monkeypatch.setattr(progress_module.time, "perf_counter", lambda: next(clock))
    stream = io.StringIO()
    progress = CountProgress("compare", "draw runs", stream, period=0.0)
    progress(2, 10)  # 2 done before this session (a resumed comparison)
    progress(4, 10, "next: cbf")
    progress(10, 10)
    assert stream.getvalue().splitlines() == [
        "compare: 2/10 draw runs, 0 s elapsed",
        "compare: 4/10 draw runs, 4 s elapsed, 0.5/s, about 12 s left; next: cbf",
        "compare: 10/10 draw runs, 10 s elapsed, 0.8/s",
    ]


def test_count_progress_prints_at_most_every_period_and_always_the_end(monkeypatch):
    clock = iter([0.0, 0.5, 1.0, 1.5, 2.0, 3.0])
    monkeypatch.setattr(progress_module.time, "perf_counter", lambda: next(clock))
    stream = io.StringIO()
    progress = CountProgress("compare", "closed loops", stream, period=2.0)
    for done in range(5):
        progress(done, 4)
    assert stream.getvalue().splitlines() == [
        "compare: 0/4 closed loops, 0 s elapsed",  # the first call, at 0.5 s
        "compare: 4/4 closed loops, 3 s elapsed, 1.33/s",  # the end, though < 2 s later
    ]


# --------------------------------------------------------------------------- verdict words


def _obstacle(verdict: str, runs_to_certify: int | None) -> dict:
    return {"verdict": verdict, "runs_to_certify": runs_to_certify}


def test_the_row_verdict_is_the_campaigns_word():
    certified, inconclusive = _obstacle("certified", None), _obstacle("inconclusive", 1444)
    assert row_verdict([certified, certified]) == ("certified", None)
    assert row_verdict([certified, inconclusive, _obstacle("inconclusive", 300)]) == (
        "inconclusive",
        1444,
    )
    assert row_verdict([inconclusive, _obstacle("inconclusive", None)]) == ("inconclusive", None)
    assert row_verdict([inconclusive, _obstacle("violated", None)]) == ("violated", None)


ROW = {
    "controller": "stt",
    "model_error": None,
    "success_rate": 1.0,
    "worst_collision_frequency": 0.002,
    "clopper_pearson_lower_99": 1e-5,
    "clopper_pearson_upper_99": 0.03,
    "verdict": "inconclusive",
    "runs_to_certify": 1444,
    "t_output_in_target_s": 6.64,
    "path_length_m": 6.8,
    "min_clearance_m": 0.28,
    "step_us_median": 10.5,
    "qp_infeasible_count": None,
    "collision_rate": 0.0,
    "min_distance_m": 0.3,
    "comfort_violation_s": 0.0,
}


def test_the_comparison_table_prints_verdict_words_and_needed_runs():
    rows = [ROW, {**ROW, "controller": "apf", "verdict": "certified", "runs_to_certify": None}]
    table = comparison_table(rows)
    header, _, stt, apf = table.splitlines()
    assert "| verdict | output in target (s) |" in header and "certified" not in header
    assert "| inconclusive (needs ≈1,444 runs) | 6.64 |" in stt
    assert "| certified | 6.64 |" in apf
    assert "| yes |" not in table and "| no |" not in table


def test_the_campaign_report_says_how_many_runs_an_inconclusive_verdict_needs():
    record = {
        "allowed_collision_probability": 0.1,
        "worst_collision_frequency": 0.002,
        "t_worst": 1.72,
        "clopper_pearson_lower_99": 1e-5,
        "clopper_pearson_upper_99": 0.12,
    }
    summary = {
        "procedure": {"family_size": 2},
        "obstacles": [
            {
                "index": 0,
                "epsilon": 0.9,
                **record,
                "verdict": "inconclusive",
                "runs_to_certify": 1444,
                "tube": {**record, "verdict": "violated", "runs_to_certify": None},
            }
        ],
    }
    output, tube = verdict_table_lines(summary)[2:]
    assert output.endswith(" inconclusive (needs ≈1,444 runs)")
    assert tube.endswith(" violated")


# ------------------------------------------------------------------------- comparison.md


def test_comparison_md_has_a_heading_the_scenario_the_runs_and_a_legend():
    document = {"scenario": "case", "scenario_path": "diagrams/case.yaml", "runs": 20000}
    text = comparison_markdown({**document, "rows": [ROW]})
    lines = text.splitlines()
    assert lines[0] == "# Controller comparison: case"
    assert "`case` (diagrams/case.yaml)" in text and "20,000 runs" in text
    assert "Generated by `stt-drake compare`" in text
    assert not re.search(r"\d{4}-\d\d-\d\d", text)  # no date: the same runs, the same file
    table = [line for line in lines if line.startswith("| ")]
    headers = [h.strip() for h in table[0].strip("|").split("|")]
    legend = [line for line in lines if line.startswith("- **")]
    assert [line[4 : line.index("**:")] for line in legend] == headers
    assert "inconclusive (needs ≈1,444 runs)" in table[1]


def test_draws_comparison_md_has_a_heading_and_a_legend():
    row = {
        "controller": "stt",
        "draws": 40,
        "success_rate": 0.9,
        "stall_rate": 0.1,
        "timeout_rate": 0.0,
        "unsafe_rate": 0.0,
        "t_output_in_target_p50_s": 7.0,
        "t_output_in_target_p90_s": 9.0,
        "path_length_mean_m": 12.0,
        "min_clearance_m": 0.2,
        "step_us_median": 11.0,
        "collision_rate": 0.0,
        "min_distance_m": 0.4,
        "comfort_violation_s": 0.0,
    }
    document = {"scenario": "crowd", "scenario_path": "crowd.yaml", "draws": 40, "seed": 3}
    text = draws_markdown({**document, "rejected_draws": 2, "rows": [row]})
    assert text.startswith("# Controller comparison over draws: crowd\n")
    assert "same 40 randomised draws (seed 3, 2 rejected)" in text
    assert "- **output in target p50 (s)**: median over the reached draws" in text


# ---------------------------------------------------------------------------------- list


def test_a_sentence_ends_at_a_full_stop_before_a_capital():
    paragraph = header_paragraph(
        "# Paper Sec. 6.1, case 1: e.g. balls a person\n# holds (main3D.m in it). Then more.\n"
        "#\n# Not this paragraph.\nname: x\n"
    )
    assert paragraph == "Paper Sec. 6.1, case 1: e.g. balls a person holds (main3D.m in it). " \
        "Then more."
    assert first_sentence(paragraph) == "Paper Sec. 6.1, case 1: e.g. balls a person holds " \
        "(main3D.m in it)."
    assert first_sentence("No full stop") == "No full stop"
    assert header_paragraph("name: x\n# a comment later\n") == ""


def test_list_prints_whole_first_sentences_one_line_each_to_a_pipe(capsys):
    assert main(["list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    scenarios = packaged_scenarios()
    listed = {line.split()[0]: line for line in lines[: len(scenarios)]}
    assert list(listed) == list(scenarios)
    for name, line in listed.items():
        summary = line[len(name) :].strip()
        assert summary[-1] in ".)", (name, summary)  # a whole sentence, not cut
        header = header_paragraph(scenarios[name].read_text())
        assert header.startswith(summary)
        assert not re.search(r"\bissue \d", header, re.IGNORECASE), name
    assert "case 2:" in listed["omni_hardware_case2"]  # the three cases tell apart


def test_list_wraps_to_the_terminal(monkeypatch, capsys):
    monkeypatch.setenv("COLUMNS", "72")
    terminal = Terminal()
    monkeypatch.setattr(sys, "stdout", terminal)
    assert main(["list"]) == 0
    lines = terminal.getvalue().splitlines()
    width = max(len(name) for name in packaged_scenarios())
    for line in lines:  # within the width, but a long file name is not cut
        assert len(line) <= 71 or len(line[width + 2 :].split()) == 1, line
    text = " ".join(terminal.getvalue().split())
    sentence = first_sentence(header_paragraph(CASE1.read_text()))
    assert "omni_hardware_case1 " + sentence in text
    continued = [line for line in lines if line.startswith(" ")]
    assert continued and all(line.startswith(" " * (width + 2)) for line in continued)


# ----------------------------------------------------------------------- exit codes in help


def _subcommands() -> list[str]:
    parser = main_module._parser()
    (commands,) = [a for a in parser._actions if a.dest == "command"]
    return list(commands.choices)


@pytest.mark.parametrize("command", _subcommands())
def test_every_subcommand_help_gives_its_exit_codes(command, capsys):
    with pytest.raises(SystemExit) as stopped:
        main([command, "--help"])
    assert stopped.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert re.search(r"Exit code (0|s)", text), textwrap.shorten(text, 200)
