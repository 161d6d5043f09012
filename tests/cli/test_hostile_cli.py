"""Hostile input, round two (issue 25): the command line, the campaigns and `compare`.
Each case is what a user ran and got a traceback, unbounded work, a silent accept, a
misleading result or a leak from; each now ends with a clean refusal (exit 2, one line
naming the option or field) or the right result."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

import stt_drake.campaign.kinds
import stt_drake.compare
from stt_drake.campaign import CampaignSpec, ClosedLoop, run_campaign
from stt_drake.campaign.folder import load_runs, record_line
from stt_drake.cli.main import BadInputError, main, packaged_scenarios, resolve_scenario
from tests import faulty_tasks
from tests.campaigns.test_compare import SHORT

ROOT = Path(__file__).resolve().parents[2]
CASE1 = ROOT / "diagrams" / "omni_hardware_case1.yaml"
TRACKED = ROOT / "diagrams" / "omni_tracked.yaml"
RANDOM = ROOT / "tests" / "data" / "random_small.yaml"
BIN = Path(sys.executable).parent
ENVIRONMENT = {**os.environ, "MPLBACKEND": "Agg"}


def _refused(capsys, *args: str) -> str:
    """Run the command in-process; it must exit 2 with one line on stderr, no traceback.
    Returns that line."""
    assert main(list(args)) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err
    return err


@pytest.fixture
def short_scenario(tmp_path) -> Path:
    path = tmp_path / "short.yaml"
    path.write_text(SHORT)
    return path


# --------------------------------------------------------------------------- tracebacks


def test_model_error_on_the_arm_names_the_plants_that_have_variants(tmp_path, capsys):
    out = tmp_path / "out"
    err = _refused(
        capsys, "compare", "franka_pick_place_case1", "--controllers", "stt", "--runs", "5",
        "--model-error", "--out", str(out),
    )  # fmt: skip
    assert "--model-error" in err and "FrankaArm" in err
    assert "OmniRobot" in err and "Quadrotor" in err
    assert not out.exists()


def test_a_meshcat_host_that_cannot_be_bound_is_refused_before_the_run(tmp_path, capsys):
    """203.0.113.7 (TEST-NET-3) is no address of this machine: binding fails locally,
    nothing is sent anywhere."""
    out = tmp_path / "out"
    err = _refused(
        capsys, "run", str(CASE1), "--meshcat", "--meshcat-host", "203.0.113.7",
        "--out", str(out), "--no-figures",
    )  # fmt: skip
    assert "--meshcat-host" in err and "203.0.113.7" in err
    assert not out.exists()
    err = _refused(capsys, "run", str(CASE1), "--meshcat-host", "127.0.0.1", "--out", str(out))
    assert "--meshcat-host: applies only with --meshcat" in err


@pytest.mark.slow
def test_a_closed_output_pipe_ends_the_command_quietly():
    """`stt-drake list | head -3`: the reader is gone before the command writes."""
    process = subprocess.Popen(
        [str(BIN / "stt-drake"), "list"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=ENVIRONMENT,
    )
    process.stdout.close()  # the reader went away
    stderr = process.stderr.read().decode()
    assert process.wait(timeout=120) == 1
    assert stderr == "", stderr  # no BrokenPipeError traceback, no "Exception ignored"


# --------------------------------------------------------------------------- unbounded work


@pytest.mark.parametrize(
    "args",
    [
        ["campaign", str(CASE1)],
        ["campaign", str(RANDOM), "--kind", "randomisation"],
        ["campaign", str(TRACKED), "--kind", "end-to-end"],
        ["compare", str(CASE1), "--controllers", "stt", "cbf"],
    ],
)
def test_a_huge_run_count_is_refused_at_once(args, tmp_path, capsys):
    out = tmp_path / "out"
    started = time.monotonic()
    err = _refused(capsys, *args, "--runs", "100000000000", "--out", str(out))
    assert time.monotonic() - started < 30
    assert "--runs: must be ≥ 1 and ≤ 10,000,000 (got 100000000000)" in err
    assert not out.exists()


def test_a_huge_draw_count_or_worker_count_is_refused_at_once(tmp_path, capsys):
    out = tmp_path / "out"
    draws = ["compare", str(RANDOM), "--controllers", "stt", "--out", str(out)]
    err = _refused(capsys, *draws, "--draws", "100000000000")
    assert "--draws: must be ≥ 1 and ≤ 1,000,000 (got 100000000000)" in err
    err = _refused(capsys, *draws, "--draws", "2", "--workers", "100000000")
    assert "--workers: must be in [1, " in err
    err = _refused(
        capsys, "campaign", str(CASE1), "--runs", "5", "--workers", "100000000", "--out", str(out)
    )
    assert "--workers: must be in [1, " in err and "per core" in err
    assert not out.exists()


# --------------------------------------------------------------------------- silent accepts


def test_a_campaign_whose_runs_raised_does_not_hold(tmp_path, capsys, monkeypatch):
    """Every end-to-end run raises (the task swapped for one that fails like a broken
    simulation): 2 runs are too few for any verdict to be `violated`, and the campaign
    used to print `result: HOLDS` and exit 0."""
    monkeypatch.setattr(
        stt_drake.campaign.kinds, "end_to_end_task", faulty_tasks.raising_end_to_end_task
    )
    out = tmp_path / "out"
    args = ["campaign", str(TRACKED), "--kind", "end-to-end", "--runs", "2", "--workers", "1"]
    assert main([*args, "--out", str(out), "--no-progress", "--no-figures"]) == 1
    printed = capsys.readouterr().out
    assert "2 run(s) raised: first error (run 0, seed " in printed
    assert "RuntimeError: the simulation of run 0 raised" in printed
    assert "result: DOES NOT HOLD" in printed and "HOLDS\n" not in printed
    summary = json.loads((out / "campaign.json").read_text())
    assert summary["holds"] is False and summary["error_runs"] == 2
    assert summary["first_error"]["run"] == 0
    assert all(o["verdict"] != "violated" for o in summary["obstacles"])  # no verdict says so


def test_every_kind_reports_its_error_runs(tmp_path):
    """A true-obstacle campaign's runs cannot raise: it says so with 0 and null."""
    from stt_drake.runlog import RunLog
    from tests.outputs.test_plotting import make_log

    loop = ClosedLoop.from_log(RunLog(make_log()))
    spec = CampaignSpec(scenario=str(CASE1), runs=10)
    outcome = run_campaign(spec, tmp_path / "out", workers=1, progress=False, closed_loop=loop)
    assert outcome.summary["error_runs"] == 0 and outcome.summary["first_error"] is None


@pytest.mark.parametrize("controllers", [["stt", "cbf"], ["apf"]])
def test_compare_refuses_a_perception_scenario_with_a_baseline(controllers, tmp_path, capsys):
    out = tmp_path / "out"
    err = _refused(
        capsys, "compare", str(TRACKED), "--controllers", *controllers, "--runs", "5",
        "--out", str(out),
    )  # fmt: skip
    assert "scenario.perception" in err and "same obstacle belief" in err
    assert not out.exists()


@pytest.mark.parametrize(
    ("kind", "scenario", "option", "value"),
    [
        ("end-to-end", TRACKED, "--true-obstacle-motion", "ou"),
        ("end-to-end", TRACKED, "--true-obstacle-motion", "static"),
        ("end-to-end", TRACKED, "--ou-tau", "3"),
        ("randomisation", RANDOM, "--true-obstacle-motion", "ou"),
        ("randomisation", RANDOM, "--ou-tau", "3"),
        ("true-obstacles", CASE1, "--ou-tau", "3"),  # with static motion: τ means nothing
    ],
)
def test_true_obstacle_options_are_refused_where_they_do_not_apply(
    kind, scenario, option, value, tmp_path, capsys
):
    out = tmp_path / "out"
    err = _refused(
        capsys, "campaign", str(scenario), "--kind", kind, "--runs", "3", option, value,
        "--out", str(out),
    )  # fmt: skip
    assert f"{option}: applies only" in err
    expected = "--true-obstacle-motion ou" if kind == "true-obstacles" else "--kind true-obstacles"
    assert expected in err
    assert not out.exists()


@pytest.mark.parametrize(
    ("words", "message"),
    [
        (["--runs", "5", "--seed", "3"], "--seed: applies only with --draws"),
        (["--runs", "5", "--draws", "2"], "--runs: not with --draws"),
        (["--draws", "2", "--seed", "-1"], "--seed: must be ≥ 0"),
    ],
)
def test_compare_refuses_options_it_would_ignore(words, message, tmp_path, capsys):
    out = tmp_path / "out"
    words = ["compare", str(RANDOM), "--controllers", "stt", *words, "--out", str(out)]
    err = _refused(capsys, *words)
    assert message in err
    assert not out.exists()


def test_compare_checks_the_scheduler_before_any_simulation(tmp_path, capsys, monkeypatch):
    def no_simulation(*args, **kwargs):
        raise AssertionError("simulated before --scheduler was checked")

    monkeypatch.setattr(stt_drake.compare, "simulate_stt", no_simulation)
    monkeypatch.setattr(stt_drake.compare, "simulate_baseline", no_simulation)
    out = tmp_path / "out"
    err = _refused(
        capsys, "compare", str(CASE1), "--controllers", "stt", "cbf", "--runs", "5",
        "--scheduler", "bogus://127.0.0.1:8786", "--out", str(out),
    )  # fmt: skip
    assert "--scheduler: unknown scheme 'bogus'" in err
    assert not out.exists()


def test_a_local_folder_does_not_hide_a_packaged_scenario(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "omni_hardware_case1").mkdir()
    (tmp_path / "omni_hardware_case2.yaml").mkdir()
    packaged = packaged_scenarios()
    assert resolve_scenario("omni_hardware_case1") == packaged["omni_hardware_case1"]
    assert resolve_scenario("omni_hardware_case2.yaml") == packaged["omni_hardware_case2"]
    (tmp_path / "mine").mkdir()
    with pytest.raises(BadInputError, match="mine: is a folder, not a scenario file"):
        resolve_scenario("mine")
    err = _refused(capsys, "campaign", "mine", "--runs", "3")
    assert "is a folder, not a scenario file" in err


# --------------------------------------------------------------------------- faults


def _descendants(pid: int) -> list[psutil.Process]:
    return psutil.Process(pid).children(recursive=True)


def _alive(processes: list[psutil.Process]) -> list[psutil.Process]:
    alive = []
    for process in processes:
        try:
            if process.is_running() and process.status() != psutil.STATUS_ZOMBIE:
                alive.append(process)
        except psutil.NoSuchProcess:
            pass
    return alive


def _wait_for(condition, process: subprocess.Popen, timeout: float = 180.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert process.poll() is None, process.communicate()[1]
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.05)


def _lines(path: Path) -> int:
    return path.read_bytes().count(b"\n") if path.exists() else 0


@pytest.mark.slow
@pytest.mark.parametrize(
    ("command", "records"),
    [
        (["campaign", str(RANDOM), "--kind", "randomisation", "--runs", "400"], "runs.jsonl"),
        (["compare", str(RANDOM), "--controllers", "stt", "--draws", "400"], "draws.jsonl"),
    ],
)
def test_a_sigkilled_command_takes_its_worker_processes_with_it(command, records, tmp_path):
    """Its forkserver and workers used to stay, reparented, ~730 MB, for good."""
    out = tmp_path / "out"
    process = subprocess.Popen(
        [str(BIN / "stt-drake"), *command, "--workers", "2", "--out", str(out)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        start_new_session=True,
        env=ENVIRONMENT,
    )
    try:
        _wait_for(lambda: _lines(out / records) >= 2, process)
        tree = _descendants(process.pid)
        workers = [p for p in tree if p.ppid() != process.pid]
        assert len(workers) >= 2, tree  # the forkserver's children: the pool's workers
        process.send_signal(signal.SIGKILL)  # the main process only, not its group
        process.wait()
        deadline = time.monotonic() + 15
        while _alive(tree) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not _alive(tree), [(p.pid, p.cmdline()[:3]) for p in _alive(tree)]
    finally:
        with contextlib.suppress(ProcessLookupError):  # whatever is left of the test's tree
            os.killpg(process.pid, signal.SIGKILL)
        process.wait()


def _compare(scenario: Path, out: Path, *more: str) -> list[str]:
    return ["compare", str(scenario), "--controllers", "stt", "--workers", "1",
            "--out", str(out), *more]  # fmt: skip


@pytest.mark.slow
def test_compare_resumes_and_refuses_a_rerun_without_resume(short_scenario, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(_compare(short_scenario, out, "--runs", "30")) == 0
    first = (out / "stt" / "runs.jsonl").read_bytes()
    capsys.readouterr()
    started = time.monotonic()
    err = _refused(capsys, *_compare(short_scenario, out, "--runs", "30"))
    assert time.monotonic() - started < 30  # at once: nothing simulated
    assert f"--out: {out} already holds a comparison; pass --resume" in err
    assert main(_compare(short_scenario, out, "--runs", "50", "--resume")) == 0
    captured = capsys.readouterr()
    assert "closed loop is simulated again" in captured.err
    assert "pass --resume" not in captured.err and "| stt |" in captured.out
    after = (out / "stt" / "runs.jsonl").read_bytes()
    assert after.startswith(first) and after.count(b"\n") == 50  # 20 more, none redone
    assert json.loads((out / "comparison.json").read_text())["runs"] == 50
    assert json.loads((out / "stt" / "campaign.json").read_text())["runs"] == 50


@pytest.mark.slow
def test_a_second_compare_on_a_locked_folder_is_refused_at_once(short_scenario, tmp_path, capsys):
    out = tmp_path / "locked"
    first = subprocess.Popen(
        [str(BIN / "stt-drake"), *_compare(short_scenario, out, "--runs", "5000000")],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
        env=ENVIRONMENT,
    )
    try:
        lock = out / ".lock"
        _wait_for(lambda: lock.exists() and f"pid {first.pid} " in lock.read_text(), first)
        started = time.monotonic()
        for more in ([], ["--resume"]):
            err = _refused(capsys, *_compare(short_scenario, out, "--runs", "5", *more))
            assert f"--out: {out} is in use by another comparison (pid {first.pid} " in err
        assert time.monotonic() - started < 30
    finally:
        os.killpg(first.pid, signal.SIGKILL)
        first.wait()


def _toggle_collision(record: dict) -> None:
    """A hand edit: obstacle 0's output collisions erased, or one added."""
    record["output"][0] = [] if record["output"][0] else [[0, 1]]


def _flip(line: str, edit) -> str:
    record = json.loads(line)
    edit(record)
    return json.dumps(record)


def test_a_tampered_or_unsigned_run_record_is_named_and_redone(tmp_path, capsys):
    """A hand-edited record keeps its old checksum; a record without one is what an older
    version wrote: both are redone on resume, each named on stderr."""
    from stt_drake.runlog import RunLog
    from tests.outputs.test_plotting import make_log

    loop = ClosedLoop.from_log(RunLog(make_log()))
    spec = CampaignSpec(scenario=str(CASE1), runs=20, seed=2)
    options = {"workers": 1, "chunk_size": 5, "progress": False, "figures": False}
    reference = run_campaign(spec, tmp_path / "reference", closed_loop=loop, **options)
    out = tmp_path / "edited"
    run_campaign(spec, out, closed_loop=loop, **options)
    runs = out / "runs.jsonl"
    lines = runs.read_text().splitlines()
    assert all(json.loads(line)["sha256"] == json.loads(record_line(json.loads(line)))["sha256"]
               for line in lines)  # fmt: skip
    by_run = {json.loads(line)["run"]: k for k, line in enumerate(lines)}
    lines[by_run[3]] = _flip(lines[by_run[3]], _toggle_collision)  # its checksum kept
    lines[by_run[11]] = _flip(lines[by_run[11]], lambda r: r.pop("sha256"))
    runs.write_text("\n".join(lines) + "\n")
    capsys.readouterr()

    args = ["campaign", str(CASE1), "--runs", "20", "--seed", "2", "--chunk-size", "5"]
    code = main([*args, "--out", str(out), "--resume", "--no-progress", "--no-figures"])
    assert code == (0 if reference.summary["holds"] else 1)
    err = capsys.readouterr().err
    assert "run 3: checksum mismatch, redone" in err
    assert "run 11: no checksum, redone" in err
    assert "2 malformed line(s) skipped" in err
    records, malformed = load_runs(runs)
    assert malformed == 2 and [records[i] for i in range(20)] == reference.records
    summary = json.loads((out / "campaign.json").read_text())
    assert summary["malformed_lines"] == 2
    assert summary["obstacles"] == reference.summary["obstacles"]


@pytest.mark.slow
def test_compare_over_draws_resumes_its_draws_and_redoes_a_tampered_one(tmp_path, capsys):
    out = tmp_path / "draws"
    words = ["compare", str(RANDOM), "--controllers", "stt", "--workers", "2", "--out", str(out)]
    assert main([*words, "--draws", "2"]) == 0
    draws = out / "draws.jsonl"
    lines = draws.read_text().splitlines()
    assert len(lines) == 2 and all("sha256" in json.loads(line) for line in lines)
    assert _refused(capsys, *words, "--draws", "2")  # no --resume: refused
    tampered = json.loads(lines[0])
    tampered["reached"] = not tampered["reached"]
    draws.write_text("\n".join([json.dumps(tampered), lines[1]]) + "\n")
    capsys.readouterr()
    assert main([*words, "--draws", "3", "--resume"]) == 0
    err = capsys.readouterr().err
    assert f"(stt, draw {tampered['draw']}): checksum mismatch; redone" in err
    after = draws.read_text().splitlines()
    assert after[1] == lines[1] and len(after) == 4  # the tampered draw and draw 2 added
    redone = next(r for r in map(json.loads, after[2:]) if r["draw"] == tampered["draw"])

    def same(record: dict) -> dict:  # the step time is measured again: the rest is equal
        return {k: v for k, v in record.items() if k not in ("step_us", "sha256")}

    assert same(redone) == same(json.loads(lines[0]))
    document = json.loads((out / "comparison.json").read_text())
    assert document["draws"] == 3 and document["rows"][0]["draws"] + document["rejected_draws"] == 3
    err = _refused(capsys, *words, "--draws", "3", "--resume", "--seed", "1")
    assert "--resume: seed differs" in err


def test_a_scenario_without_obstacles_is_refused_by_compare_and_true_obstacle_campaigns(
    tmp_path, capsys
):
    """Nothing to check against true obstacles: refused up front (it raised after the runs)."""
    path = tmp_path / "empty.yaml"
    path.write_text(SHORT[: SHORT.index("obstacles:")] + "obstacles: []\n")
    code = main(["compare", str(path), "--controllers", "stt", "--runs", "5", "--out",
                 str(tmp_path / "c")])  # fmt: skip
    assert code == 2
    assert "scenario.obstacles" in capsys.readouterr().err
    assert main(["campaign", str(path), "--runs", "5", "--out", str(tmp_path / "k")]) == 2
    assert "scenario.obstacles" in capsys.readouterr().err
