"""Running a campaign: the local process pool or Dask cluster the runs go to, resuming
from ``runs.jsonl`` (only by the same spec, kept in ``campaign_spec.json``; the spec is
:class:`stt_drake.campaign.spec.CampaignSpec`), and :func:`run_campaign`.

Runs go through a :class:`concurrent.futures.Executor`: a local process pool, or a Dask
``distributed`` client. Each finished run is appended to ``runs.jsonl``; ``--resume`` skips
the runs already there.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import hashlib
import json
import multiprocessing
import os
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from stt_drake.campaign.randomisation import (
    FAILURES_DIR,
    draw_failed,
    failing_draw_yaml,
    failure_name,
    randomisation_task,
)
from stt_drake.campaign.report import write_summary
from stt_drake.campaign.sampling import (
    ClosedLoop,
    output_collided,
    run_seed,
    sample_true_obstacles,
)
from stt_drake.campaign.spec import CampaignError, CampaignSpec

RUNS_FILE, SPEC_FILE, CLOSED_LOOP_FILE = "runs.jsonl", "campaign_spec.json", "closed_loop.npz"


def default_workers() -> int:
    """Cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not on Linux
        return os.cpu_count() or 1


@contextlib.contextmanager
def campaign_executor(
    workers: int | None = None,
    scheduler: str | None = None,
    preload: Sequence[str] = ("stt_drake.campaign",),
) -> Iterator[tuple[cf.Executor, int]]:
    """(executor, parallel slots): a Dask client's executor when `scheduler` is given, else
    a local process pool of `workers` (default: every core).

    The pool uses the "forkserver" start method with `preload` imported once in the
    server: workers fork from a clean process that has imported pydrake but never run a
    simulation or started a thread (plain "fork" from the campaign process would copy a
    process that has simulated; "spawn" re-imports pydrake in every worker, ~2-3 s each).
    """
    if scheduler is not None:
        from distributed import Client

        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as error:
            raise CampaignError(f"--scheduler: cannot reach {scheduler}: {error}") from None
        with client:
            slots = sum(w["nthreads"] for w in client.scheduler_info()["workers"].values())
            yield client.get_executor(pure=False), max(slots, 1)
        return
    workers = default_workers() if workers is None else workers
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(list(preload))
    with cf.ProcessPoolExecutor(max_workers=workers, mp_context=context) as executor:
        yield executor, workers


def read_records(path: Path) -> dict[int, dict[str, Any]]:
    """Runs already in `runs.jsonl` by index; a torn last line (a kill mid-write) is cut off."""
    if not path.exists():
        return {}
    data = path.read_bytes()
    keep = data.rfind(b"\n") + 1
    if keep < len(data):
        with path.open("r+b") as stream:
            stream.truncate(keep)
    records: dict[int, dict[str, Any]] = {}
    for line in data[:keep].decode().splitlines():
        if line.strip():
            record = json.loads(line)
            records.setdefault(record["run"], record)
    return records


def _chunks(pending: list[int], size: int) -> Iterator[list[int]]:
    for start in range(0, len(pending), size):
        yield pending[start : start + size]


def execute(
    executor: cf.Executor,
    slots: int,
    task: Callable[..., list[dict[str, Any]]],
    task_args: tuple[Any, ...],
    batches: Iterable[list[tuple[int, int]]],
    on_records: Callable[[list[dict[str, Any]]], None],
) -> None:
    """Submit ``task(*task_args, batch)`` per batch, at most 2·slots in flight, and hand
    each finished batch's records to `on_records` (in completion order)."""
    batches = iter(batches)
    in_flight: set[cf.Future] = set()
    try:
        while True:
            while len(in_flight) < 2 * slots:
                batch = next(batches, None)
                if batch is None:
                    break
                in_flight.add(executor.submit(task, *task_args, batch))
            if not in_flight:
                return
            done, in_flight = cf.wait(in_flight, return_when=cf.FIRST_COMPLETED)
            for future in done:
                on_records(future.result())
    finally:
        for future in in_flight:
            future.cancel()


@dataclass
class CampaignOutcome:
    """A finished campaign: its summary (the campaign.json contract) and where it lives."""

    summary: dict[str, Any]
    out_dir: Path
    records: list[dict[str, Any]]


def _check_resumable(out_dir: Path, spec: CampaignSpec, text_hash: str, resume: bool) -> None:
    spec_path = out_dir / SPEC_FILE
    wanted = {**asdict(spec), "scenario_sha256": text_hash}
    if spec_path.exists() and (out_dir / RUNS_FILE).exists():
        if not resume:
            raise CampaignError(
                f"--out: {out_dir} already holds a campaign; pass --resume to continue it "
                "or choose another --out"
            )
        stored = json.loads(spec_path.read_text())
        for key, value in wanted.items():
            if key not in ("runs", "scenario") and stored.get(key) != value:
                raise CampaignError(
                    f"--resume: {key} differs from the campaign in {out_dir} "
                    f"({stored.get(key)!r} there, {value!r} now)"
                )
    out_dir.mkdir(parents=True, exist_ok=True)
    spec_path.write_text(json.dumps(wanted, indent=2) + "\n")


def _load_checked_scenario(spec: CampaignSpec, text: str, name: str) -> Any:
    """The scenario as the campaign sees it (kind 1: the file's seed; kind 2: run 0's draw,
    only to reject bad input up front, None when that draw is rejected). The YAML is parsed
    once; a randomisation campaign must have a random field (checked on the parsed file,
    before anything is drawn)."""
    from stt_drake.build import prepare_scenario
    from stt_drake.config import AssumptionError, ScenarioError, has_random_field, parse_schema

    randomising = spec.kind == "randomisation"
    try:
        schema = parse_schema(text, name)
        if randomising and not has_random_field(schema.random_obstacles):
            raise CampaignError(
                "scenario.random_obstacles: a randomisation campaign needs a random_obstacles "
                "section with count > 0 or a count_range"
            )
        return prepare_scenario(schema, run_seed(spec.seed, 0) if randomising else None)
    except ScenarioError as error:
        if randomising and isinstance(error, AssumptionError):
            return None
        raise CampaignError(f"bad scenario {spec.scenario}: {error}") from None


def run_campaign(
    spec: CampaignSpec,
    out_dir: Path,
    workers: int | None = None,
    scheduler: str | None = None,
    resume: bool = False,
    chunk_size: int | None = None,
    progress: bool = True,
    figures: bool = True,
    closed_loop: ClosedLoop | None = None,
) -> CampaignOutcome:
    """Run (or resume) a campaign and write runs.jsonl, campaign.json and the figure.

    `closed_loop` (true-obstacle campaigns) replaces the simulation of the scenario: pass
    a trajectory simulated with a different tube to test the check itself.
    """
    spec.validate()
    if chunk_size is not None and chunk_size < 1:
        raise CampaignError(f"--chunk-size: must be ≥ 1 (got {chunk_size})")
    if workers is not None and workers < 1:
        raise CampaignError(f"--workers: must be ≥ 1 (got {workers})")
    path = Path(spec.scenario)
    if not path.is_file():
        raise CampaignError(f"{path}: no such scenario file")
    text, name = path.read_text(), path.stem
    scenario = _load_checked_scenario(spec, text, name)
    text_hash = hashlib.sha256(text.encode()).hexdigest()
    _check_resumable(out_dir, spec, text_hash, resume)
    start = time.perf_counter()
    runs_path = out_dir / RUNS_FILE
    records = read_records(runs_path) if resume else {}
    if not resume:
        runs_path.write_text("")
    pending = [i for i in range(spec.runs) if i not in records]

    closed_loop_summary: dict[str, Any] | None = None
    randomising = spec.kind == "randomisation"
    if not randomising:
        closed_loop, closed_loop_summary = _closed_loop(scenario, out_dir, closed_loop, resume)
        task: Callable[..., list[dict[str, Any]]] = sample_true_obstacles
        task_args: tuple[Any, ...] = (closed_loop, spec.motion, spec.tau)
        size, failed, label = chunk_size or 250, output_collided, "collided"
    else:
        task, task_args = randomisation_task, (text, name)
        size, failed, label = chunk_size or 1, draw_failed, "failures"
        (out_dir / FAILURES_DIR).mkdir(exist_ok=True)

    from tqdm import tqdm

    done = [records[i] for i in range(spec.runs) if i in records]
    bar = tqdm(
        total=spec.runs,
        initial=len(done),
        unit="run",
        desc=f"{spec.kind} campaign",
        file=sys.stderr,
        disable=not progress,
        dynamic_ncols=True,
    )
    failures = sum(failed(r) for r in done)
    bar.set_postfix({label: failures})

    with runs_path.open("a") as stream:

        def on_records(batch: list[dict[str, Any]]) -> None:
            nonlocal failures
            for record in batch:
                if failed(record):
                    failures += 1
                    if randomising:  # written before its record: a record
                        # in runs.jsonl always has its YAML, even after a kill
                        (out_dir / failure_name(record["run"])).write_text(
                            failing_draw_yaml(text, name, record["seed"], spec.seed, record["run"])
                        )
                stream.write(json.dumps(record) + "\n")
                records[record["run"]] = record
            stream.flush()
            bar.update(len(batch))
            bar.set_postfix({label: failures})

        batches = ([(i, run_seed(spec.seed, i)) for i in chunk] for chunk in _chunks(pending, size))
        try:
            preload = ["stt_drake.campaign", *(["stt_drake.run"] if randomising else [])]
            with campaign_executor(workers, scheduler, preload) as (executor, slots):
                execute(executor, slots, task, task_args, batches, on_records)
        finally:
            bar.close()

    finished = [records[i] for i in range(spec.runs)]
    summary = write_summary(
        spec,
        scenario.name if scenario is not None else name,
        finished,
        out_dir,
        start,
        closed_loop,
        closed_loop_summary,
        figures,
    )
    return CampaignOutcome(summary, out_dir, finished)


def _closed_loop(
    scenario: Any, out_dir: Path, given: ClosedLoop | None, resume: bool
) -> tuple[ClosedLoop, dict[str, Any]]:
    """Simulate the scenario once, or take the given closed loop, or (resuming) the saved
    one — so a resumed campaign samples against exactly the trajectory it started with."""
    path = out_dir / CLOSED_LOOP_FILE
    summary_path = out_dir / "closed_loop.json"
    if resume and given is None and path.exists() and summary_path.exists():
        return ClosedLoop.load(path), json.loads(summary_path.read_text())
    if given is None:
        from stt_drake.run import simulate

        result = simulate(scenario)
        given = ClosedLoop.from_log(result.log)
        summary = {
            "simulations": 1,
            "holds": result.metrics["holds"],
            "reached": result.metrics["reached"],
            "t_reach": result.metrics["t_reach"],
            "wall_time_s": result.metrics["wall_time_s"],
        }
    else:
        summary = {"simulations": 0, "given": True}
    given.save(path)
    summary_path.write_text(json.dumps(summary, indent=2) + "\n")
    return given, summary
