"""Campaign faults, each reproduced for real: corrupt lines in runs.jsonl, a second campaign
on a locked folder, a local worker process killed mid-run, and a Dask cluster that is
unreachable, has no worker, loses its last worker or its scheduler (real processes on
127.0.0.1). Every fault ends with nothing recorded lost, and the campaign either finishes
or says exactly how to resume; never a traceback."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shlex
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest
from distributed import LocalCluster

from stt_drake.campaign import CampaignSpec, ClosedLoop, run_campaign, run_seed
from stt_drake.campaign.folder import (
    load_runs,
    read_records,
    record_checksum,
    record_line,
    scan_runs,
)
from stt_drake.cli.main import main
from stt_drake.runlog import RunLog
from tests.outputs.test_plotting import make_log

ROOT = Path(__file__).resolve().parents[2]
CASE1 = ROOT / "diagrams" / "omni_hardware_case1.yaml"
RANDOM = ROOT / "tests" / "data" / "random_small.yaml"
BIN = Path(sys.executable).parent


def _without(summary: dict, *keys: str) -> dict:
    return {k: v for k, v in summary.items() if k not in ("wall_time_s", *keys)}


def _summary(out: Path) -> dict:
    return json.loads((out / "campaign.json").read_text())


def _lines(out: Path) -> int:
    path = out / "runs.jsonl"
    return path.read_bytes().count(b"\n") if path.exists() else 0


def _wait_for(condition, process: subprocess.Popen | None = None, timeout: float = 120.0):
    deadline = time.monotonic() + timeout
    while not condition():
        assert process is None or process.poll() is None, "the campaign ended too early"
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.05)


def _random_args(out: Path, runs: int, *extra: str) -> list[str]:
    return [
        "campaign", str(RANDOM), "--kind", "randomisation", "--runs", str(runs),
        "--out", str(out), "--no-progress", "--no-figures", *extra,
    ]  # fmt: skip


def _start(args: list[str]) -> subprocess.Popen:
    return subprocess.Popen(
        [str(BIN / "stt-drake"), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        env={**os.environ, "MPLBACKEND": "Agg"},
    )


def _resume_command(stderr: str) -> list[str]:
    """The command the message says resumes the campaign, as argv without the program."""
    lines = stderr.splitlines()
    command = lines[lines.index(next(x for x in lines if x.endswith("resume with:"))) + 1]
    words = shlex.split(command)
    assert words[:2] == ["stt-drake", "campaign"] and words[-1] == "--resume"
    return words[1:]


# --------------------------------------------------------------------------- runs.jsonl


def test_load_runs_skips_and_counts_every_kind_of_garbage(tmp_path):
    path = tmp_path / "runs.jsonl"
    good = [{"run": i, "seed": run_seed(0, i), "x": [1.0, i]} for i in range(3)]
    good[2]["x"] = [math.inf, -math.inf]  # written as null, named in "non_finite", restored
    nowhere = {"run": 8, "seed": 1, "non_finite": {"/nowhere/deep": "inf"}}
    garbage = [
        b"garbage {", b"[1, 2]", b"{}", b'{"run": -1, "seed": 3}', b'{"run": true, "seed": 3}',
        b'{"run": 7, "seed": "s"}', b"\xff\xfe not utf-8", b"[" * 100_000,
        json.dumps({**nowhere, "sha256": record_checksum(nowhere)}).encode(),
        json.dumps(good[0]).encode(),  # no checksum: an older version's line, or edited
        record_line(good[1]).replace("1.0", "2.0").encode(),  # edited: checksum mismatch
    ]  # fmt: skip
    lines = [record_line(good[0]).encode(), *garbage[:5], record_line(good[1]).encode()]
    lines += [*garbage[5:], record_line(good[2]).encode(), b'{"run": 1, "seed": 9']
    path.write_bytes(b"\n".join(lines))  # the last line is torn: no newline
    records, malformed = load_runs(path)
    assert records == {r["run"]: r for r in good} and malformed == len(garbage)
    found = scan_runs(path)
    assert found.tampered == {0: "no checksum", 1: "checksum mismatch"}
    refused, malformed = load_runs(path, valid=lambda r: r["run"] != 1)
    assert sorted(refused) == [0, 2] and malformed == len(garbage) + 1
    assert path.read_bytes().endswith(record_line(good[2]).encode() + b"\n")  # torn line cut
    assert b"Infinity" not in path.read_bytes()
    assert sorted(read_records(path)) == [0, 1, 2]  # for reading results: unchecked


def test_malformed_lines_are_skipped_counted_and_their_runs_redone(tmp_path, capsys):
    """Against a synthetic closed loop: the reference campaign, then a copy whose
    runs.jsonl has garbage in the middle, a record missing a key, a record with the wrong
    seed and a corrupt last line that ends in a newline, resumed by the command."""
    loop = ClosedLoop.from_log(RunLog(make_log()))
    loop = dataclasses.replace(loop, sigma=8.0 * loop.sigma)  # wide enough to collide
    spec = CampaignSpec(scenario=str(CASE1), runs=40, seed=5)
    options = {"workers": 1, "chunk_size": 10, "progress": False, "figures": False}
    reference = run_campaign(spec, tmp_path / "reference", closed_loop=loop, **options)
    out = tmp_path / "corrupt"
    run_campaign(spec, out, closed_loop=loop, **options)
    lines = (out / "runs.jsonl").read_text().splitlines()
    missing = json.loads(lines[7])
    del missing["tube"]
    wrong_seed = json.loads(lines[12])
    wrong_seed["seed"] += 1
    lines[3] = "garbage {"
    lines[7], lines[12] = json.dumps(missing), json.dumps(wrong_seed)
    lines[-1] = lines[-1][: len(lines[-1]) // 2]
    (out / "runs.jsonl").write_text("\n".join(lines) + "\n")
    capsys.readouterr()

    args = ["campaign", str(CASE1), "--runs", "40", "--seed", "5", "--chunk-size", "10"]
    code = main([*args, "--out", str(out), "--resume", "--no-progress", "--no-figures"])
    assert code == (0 if reference.summary["holds"] else 1)
    captured = capsys.readouterr()
    assert "4 malformed line(s) skipped" in captured.err and "Traceback" not in captured.err
    assert "4 malformed line(s) skipped; their runs were redone" in captured.out
    summary = _summary(out)
    assert summary["malformed_lines"] == 4 and reference.summary["malformed_lines"] == 0
    assert _without(summary, "malformed_lines") == _without(reference.summary, "malformed_lines")
    keys = {"run", "seed", "output", "tube"}
    records, malformed = load_runs(
        out / "runs.jsonl", valid=lambda r: set(r) == keys and r["seed"] == run_seed(5, r["run"])
    )
    assert malformed == 4
    assert [records[i] for i in range(40)] == reference.records
    assert any(any(r["tube"]) for r in reference.records)  # the runs differ: some collide


# --------------------------------------------------------------------------- the lock


@pytest.mark.slow
def test_a_second_campaign_on_a_locked_folder_stops_at_once_and_sigkill_frees_it(tmp_path, capsys):
    out = tmp_path / "locked"
    first = _start(_random_args(out, 3, "--workers", "1"))
    try:
        _wait_for(lambda: f"pid {first.pid} " in _read(out / ".lock"), first)
        _wait_for((out / "runs.jsonl").exists, first)
        started = time.monotonic()
        assert main(_random_args(out, 3, "--workers", "1", "--resume")) == 2
        assert time.monotonic() - started < 30  # the scenario's check, then the lock: no run
        err = capsys.readouterr().err
        assert f"--out: {out} is in use by another campaign (pid {first.pid} " in err
        assert "stt-drake campaign" in err.split("in use by another campaign", 1)[1]
    finally:
        os.killpg(first.pid, signal.SIGKILL)
        first.wait()
    kept = (out / "runs.jsonl").read_bytes()
    assert main(_random_args(out, 3, "--workers", "1", "--resume")) in (0, 1)
    assert _summary(out)["runs"] == 3
    assert (out / "runs.jsonl").read_bytes().startswith(kept)


def _read(path: Path) -> str:
    return path.read_text() if path.exists() else ""


# --------------------------------------------------------------------------- local workers


@pytest.mark.slow
def test_a_killed_local_worker_is_replaced_and_its_runs_redone(tmp_path):
    out = tmp_path / "killed"
    process = _start(_random_args(out, 6, "--workers", "2"))
    _wait_for(lambda: _lines(out) >= 1, process)
    campaign = psutil.Process(process.pid)
    workers = [p for p in campaign.children(recursive=True) if p.ppid() != process.pid]
    assert workers, "no worker process of the pool found"
    workers[0].send_signal(signal.SIGKILL)
    kept = (out / "runs.jsonl").read_bytes()
    _, stderr = process.communicate(timeout=300)
    assert process.returncode in (0, 1), stderr  # 1: some draws of this scenario fail
    assert "a worker process died" in stderr and "go to a fresh pool" in stderr
    assert "Traceback" not in stderr
    assert (out / "runs.jsonl").read_bytes().startswith(kept)  # nothing recorded is lost
    records, malformed = load_runs(out / "runs.jsonl")
    assert sorted(records) == list(range(6)) and malformed == 0
    assert _lines(out) == 6  # every run once: the killed ones were redone, none twice
    assert _summary(out)["runs"] == 6


# --------------------------------------------------------------------------- Dask


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.mark.parametrize(
    ("scheduler", "message"),
    [
        ("bogus://127.0.0.1:8786", "--scheduler: unknown scheme 'bogus'"),
        ("tcp://127.0.0.1:{port}", "--scheduler: no Dask scheduler answered"),
    ],
)
def test_a_bad_scheduler_is_bad_input_before_anything_is_written(
    scheduler, message, tmp_path, capsys
):
    out = tmp_path / "out"
    address = scheduler.format(port=_free_port())
    args = ["campaign", str(CASE1), "--runs", "5", "--scheduler", address, "--dask-timeout", "1"]
    assert main([*args, "--out", str(out), "--no-progress"]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


def test_no_dask_worker_times_out_before_any_simulation(tmp_path, capsys):
    out = tmp_path / "out"
    with LocalCluster(n_workers=0, host="127.0.0.1", dashboard_address=None) as cluster:
        address = cluster.scheduler_address
        args = ["campaign", str(CASE1), "--runs", "5", "--scheduler", address]
        assert main([*args, "--dask-timeout", "1", "--out", str(out), "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert f"no Dask worker joined the scheduler {address} within 1 s (--dask-timeout)" in err
    assert not out.exists()  # nothing simulated, nothing written


def _dask(*args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [str(BIN / "dask"), *args],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )


@pytest.mark.slow
def test_a_lost_dask_worker_and_a_lost_scheduler_stop_with_the_resume_command(tmp_path):
    """A real scheduler and worker (separate processes on 127.0.0.1). The last worker is
    killed: the campaign stops after --dask-timeout with the resume command. Resumed on a
    new worker, the scheduler is killed: it stops again, with the command. Resumed on
    local processes: it finishes, nothing recorded lost."""
    out = tmp_path / "dask"
    port = _free_port()
    scheduler = _dask("scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard")
    address = f"tcp://127.0.0.1:{port}"
    spawned = [scheduler]
    try:
        worker = _dask("worker", address, "--nthreads", "1", "--no-nanny", "--no-dashboard")
        spawned.append(worker)
        campaign = _start(_random_args(out, 5, "--scheduler", address, "--dask-timeout", "3"))
        _wait_for(lambda: _lines(out) >= 1, campaign)
        worker.kill()
        _, stderr = campaign.communicate(timeout=120)
        assert campaign.returncode == 1 and "Traceback" not in stderr, stderr
        assert f"no Dask worker at {address} for 3 s (--dask-timeout)" in stderr
        command = _resume_command(stderr)
        assert command[command.index("--scheduler") + 1] == address
        first = (out / "runs.jsonl").read_bytes()

        spawned.append(_dask("worker", address, "--nthreads", "1", "--no-nanny", "--no-dashboard"))
        campaign = _start(command)
        _wait_for(lambda: _lines(out) > first.count(b"\n"), campaign)
        scheduler.kill()
        _, stderr = campaign.communicate(timeout=120)
        assert campaign.returncode == 1 and "Traceback" not in stderr, stderr
        assert f"lost the Dask scheduler {address}" in stderr
        second = (out / "runs.jsonl").read_bytes()
        assert second.startswith(first)
    finally:
        for process in spawned:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    command = _resume_command(stderr)
    at = command.index("--scheduler")
    local = [*command[:at], *command[at + 2 :], "--workers", "2"]
    assert main(local) in (0, 1)
    assert (out / "runs.jsonl").read_bytes().startswith(second)
    records, malformed = load_runs(out / "runs.jsonl")
    assert sorted(records) == list(range(5)) and malformed == 0
    assert _summary(out)["runs"] == 5
