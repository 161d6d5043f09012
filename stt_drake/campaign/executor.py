"""Running a campaign: :func:`run_campaign`, in the order that keeps a folder consistent
whatever goes wrong.

1. Every option, the output folder (writable: :func:`stt_drake.runlog.unwritable_reason`)
   and the scenario are checked, and the runs' backend is opened — a Dask scheduler
   reached and a worker awaited (:mod:`stt_drake.campaign.backends`) — before anything is
   written or simulated.
2. The folder is locked (:func:`stt_drake.campaign.folder.folder_lock`), checked to hold
   no other campaign (resume only by the same spec, kept in ``campaign_spec.json``), and
   the closed loop is simulated (true-obstacle campaigns).
3. Each finished run is appended to ``runs.jsonl`` (strict JSON, one line, with its
   checksum: :func:`stt_drake.campaign.folder.record_line`); a resume skips the runs
   already there, counts malformed lines (``malformed_lines`` in ``campaign.json``; a line
   whose checksum is missing or wrong is one, and its run is named on stderr) and redoes
   their runs. A local worker process that dies is replaced by a fresh pool and its runs
   redone; a lost Dask scheduler, no Dask worker for the timeout, or local workers dying
   again and again stop the campaign with
   :class:`~stt_drake.campaign.spec.CampaignStoppedError`, everything recorded kept.
"""

from __future__ import annotations

import hashlib
import json
import sys
import time
from collections.abc import Callable, Iterator
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from stt_drake.campaign.backends import (
    DASK_TIMEOUT_S,
    Backend,
    check_scheduler_address,
    check_workers,
    execute,
    open_backend,
)
from stt_drake.campaign.end_to_end import (
    end_to_end_failed,
    end_to_end_task,
    is_end_to_end_record,
    logged_times,
)
from stt_drake.campaign.folder import (
    RUNS_FILE,
    SPEC_FILE,
    Record,
    check_resumable,
    folder_lock,
    record_line,
    scan_runs,
    tampered_lines,
)
from stt_drake.campaign.randomisation import (
    FAILURES_DIR,
    draw_failed,
    failing_draw_yaml,
    failure_name,
    is_randomisation_record,
    randomisation_task,
)
from stt_drake.campaign.report import write_summary
from stt_drake.campaign.sampling import (
    ClosedLoop,
    is_true_obstacle_record,
    output_collided,
    run_seed,
    sample_true_obstacles,
)

if TYPE_CHECKING:
    from stt_drake.config import ScenarioText
from stt_drake.campaign.spec import CampaignError, CampaignSpec, CampaignStoppedError
from stt_drake.runlog import unwritable_reason, write_json

__all__ = ["CLOSED_LOOP_FILE", "RUNS_FILE", "SPEC_FILE", "CampaignOutcome", "run_campaign"]

CLOSED_LOOP_FILE = "closed_loop.npz"
#: A local pool broken this many times in a row without a run finishing stops the campaign.
MAX_POOL_RESTARTS = 3


def _chunks(pending: list[int], size: int) -> Iterator[list[int]]:
    for start in range(0, len(pending), size):
        yield pending[start : start + size]


@dataclass
class CampaignOutcome:
    """A finished campaign: its summary (the campaign.json contract) and where it lives."""

    summary: dict[str, Any]
    out_dir: Path
    records: list[dict[str, Any]]


def _load_checked_scenario(spec: CampaignSpec, source: ScenarioText) -> Any:
    """The scenario as the campaign sees it (kind 1: the file's seed; kind 2: run 0's draw,
    only to reject bad input up front, None when that draw is rejected). The YAML is parsed
    once; a randomisation campaign must have a random field (checked on the parsed file,
    before anything is drawn)."""
    from stt_drake.build import prepare_scenario
    from stt_drake.config import AssumptionError, ScenarioError, draws_obstacles

    randomising = spec.kind == "randomisation"
    try:
        schema = source.parse(spec.guide)
        if randomising and not draws_obstacles(schema):
            raise CampaignError(
                "scenario.random_obstacles: a randomisation campaign needs a random_obstacles "
                "section with count > 0 or a count_range, or a crowd section"
            )
        if spec.kind == "end-to-end" and schema.perception is None:
            raise CampaignError(
                "scenario.perception: an end-to-end campaign needs a perception section "
                "(true obstacles, sensor, tracker; see diagrams/omni_tracked.yaml)"
            )
        if spec.kind == "true-obstacles" and not schema.obstacles and not draws_obstacles(
            schema
        ):
            raise CampaignError(
                "scenario.obstacles: a true-obstacle campaign draws the true centres of the "
                "obstacles; the scenario has none (nothing to check)"
            )
        return prepare_scenario(schema, run_seed(spec.seed, 0) if randomising else None)
    except ScenarioError as error:
        if randomising and isinstance(error, AssumptionError):
            return None
        raise CampaignError(f"bad scenario {spec.scenario}: {error}") from None


def _scenario_text(path: Path) -> str:
    """The scenario file's text, size and UTF-8 checked
    (:func:`stt_drake.config.read_scenario_file`)."""
    from stt_drake.config import ScenarioError, read_scenario_file

    try:
        return read_scenario_file(path)
    except ScenarioError as error:
        raise CampaignError(str(error)) from None


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
    dask_timeout: float = DASK_TIMEOUT_S,
) -> CampaignOutcome:
    """Run (or resume) a campaign and write runs.jsonl, campaign.json and the figure.

    `closed_loop` (true-obstacle campaigns) replaces the simulation of the scenario: pass
    a trajectory simulated with a different tube to test the check itself. `dask_timeout`
    bounds the wait for the scheduler, for a first worker and any time without a worker.

    Raises:
        CampaignError: bad input (an option, the scenario, the folder, the scheduler's
            address; the folder locked by another campaign), found before any work.
        CampaignStoppedError: the campaign could not finish; the runs recorded are kept.
    """
    spec.validate()
    if chunk_size is not None and chunk_size < 1:
        raise CampaignError(f"--chunk-size: must be ≥ 1 (got {chunk_size})")
    check_workers(workers)
    if not 0.0 < dask_timeout < float("inf"):
        raise CampaignError(f"--dask-timeout: must be a finite time > 0 s (got {dask_timeout})")
    if scheduler is not None:
        check_scheduler_address(scheduler)
    reason = unwritable_reason(out_dir)
    if reason is not None:
        raise CampaignError(f"--out: {out_dir} {reason}")
    path = Path(spec.scenario)
    from stt_drake.config import ScenarioText

    text = _scenario_text(path)
    scenario_text = ScenarioText(text, path.stem, str(path.resolve().parent))
    scenario = _load_checked_scenario(spec, scenario_text)
    text_hash = hashlib.sha256(text.encode()).hexdigest()
    simulating = spec.kind in ("randomisation", "end-to-end")
    preload = ["stt_drake.campaign", *(["stt_drake.run"] if simulating else [])]
    backend = open_backend(workers, scheduler, preload, dask_timeout)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        with folder_lock(out_dir):
            check_resumable(out_dir, spec, text_hash, resume)
            source = (scenario_text, scenario)
            options = (resume, chunk_size, progress, figures)
            return _run_locked(spec, out_dir, backend, source, closed_loop, *options)
    finally:
        backend.close()


def _run_locked(
    spec: CampaignSpec,
    out_dir: Path,
    backend: Backend,
    source: tuple[ScenarioText, Any],
    closed_loop: ClosedLoop | None,
    resume: bool,
    chunk_size: int | None,
    progress: bool,
    figures: bool,
) -> CampaignOutcome:
    """The campaign in its locked folder, the backend open: simulate the closed loop (or
    reuse it), read the runs done, run the rest, summarise."""
    scenario_text, scenario = source
    start = time.perf_counter()
    closed_loop_summary: dict[str, Any] | None = None
    randomising = spec.kind == "randomisation"
    if spec.kind == "end-to-end":
        steps, count = logged_times(scenario), len(scenario.obstacles)
        task, task_args = end_to_end_task, (scenario_text, steps, spec.guide, spec.comfort_distance)
        size, failed, label = chunk_size or 1, end_to_end_failed, "collided"

        def shaped(record: Record) -> bool:
            return is_end_to_end_record(record, count, steps)
    elif not randomising:
        closed_loop, closed_loop_summary = _closed_loop(scenario, out_dir, closed_loop, resume)
        task: Callable[..., list[Record]] = sample_true_obstacles
        task_args: tuple[Any, ...] = (closed_loop, spec.motion, spec.tau)
        size, failed, label = chunk_size or 250, output_collided, "collided"
        count, steps = closed_loop.count, len(closed_loop.t)

        def shaped(record: Record) -> bool:
            return is_true_obstacle_record(record, count, steps)
    else:
        task, task_args = randomisation_task, (scenario_text, spec.guide, spec.comfort_distance)
        size, failed, label = chunk_size or 1, draw_failed, "failures"
        shaped = is_randomisation_record
        (out_dir / FAILURES_DIR).mkdir(exist_ok=True)

    from tqdm import tqdm

    runs_path = out_dir / RUNS_FILE
    if resume:
        found = scan_runs(
            runs_path, lambda r: r["seed"] == run_seed(spec.seed, r["run"]) and shaped(r)
        )
        records, malformed = found.records, found.malformed
        if found.tampered:
            for line in tampered_lines(found.tampered, records).splitlines():
                tqdm.write(f"stt-drake campaign: {runs_path}: {line}", file=sys.stderr)
    else:
        runs_path.write_text("")
        records, malformed = {}, 0
    if malformed:
        tqdm.write(
            f"stt-drake campaign: {runs_path}: {malformed} malformed line(s) skipped "
            "(not a run record of this campaign, or its checksum failed); their runs are redone",
            file=sys.stderr,
        )
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

        def on_records(batch: list[Record]) -> None:
            nonlocal failures
            for record in batch:
                if failed(record):
                    failures += 1
                    if randomising:  # written before its record: a record
                        # in runs.jsonl always has its YAML, even after a kill
                        (out_dir / failure_name(record["run"])).write_text(
                            failing_draw_yaml(
                                scenario_text, record["seed"], spec.seed, record["run"], spec.guide
                            )
                        )
                stream.write(record_line(record) + "\n")
                records[record["run"]] = record
            stream.flush()
            bar.update(len(batch))
            bar.set_postfix({label: failures})

        def run(batches: Iterator[list[tuple[int, int]]]) -> None:
            execute(backend, task, task_args, batches, on_records)

        try:
            _run_pending(backend, spec, records, size, run)
        finally:
            bar.close()

    finished = [records[i] for i in range(spec.runs)]
    summary = write_summary(
        spec,
        scenario.name if scenario is not None else scenario_text.name,
        finished,
        out_dir,
        start,
        closed_loop,
        closed_loop_summary,
        figures,
        malformed,
        scenario if spec.kind == "end-to-end" else None,
    )
    return CampaignOutcome(summary, out_dir, finished)


def _run_pending(
    backend: Backend,
    spec: CampaignSpec,
    records: dict[int, Record],
    size: int,
    run: Callable[[Iterator[list[tuple[int, int]]]], None],
) -> None:
    """Run every run of `spec` not in `records` (which `run`'s records fill), in batches
    of `size`; a broken local pool is replaced and its runs redone, up to
    :data:`MAX_POOL_RESTARTS` times in a row without a run finishing."""
    stalls = 0
    while True:
        pending = [i for i in range(spec.runs) if i not in records]
        before = len(records)
        batches = ([(i, run_seed(spec.seed, i)) for i in chunk] for chunk in _chunks(pending, size))
        try:
            run(batches)
            return
        except BrokenProcessPool:
            stalls = 0 if len(records) > before else stalls + 1
            recorded = f"{len(records)} of {spec.runs} runs are recorded"
            if stalls >= MAX_POOL_RESTARTS or not backend.restartable:
                raise CampaignStoppedError(
                    f"a local worker process died {stalls} times in a row before any run "
                    f"finished (killed, out of memory or a crash in native code); {recorded}"
                ) from None
            from tqdm import tqdm

            tqdm.write(
                "stt-drake campaign: a worker process died (killed, out of memory or a crash "
                f"in native code); {recorded}, the other {spec.runs - len(records)} go to a "
                "fresh pool",
                file=sys.stderr,
            )
            backend.restart()


def _closed_loop(
    scenario: Any, out_dir: Path, given: ClosedLoop | None, resume: bool
) -> tuple[ClosedLoop, dict[str, Any]]:
    """Simulate the scenario once, or take the given closed loop, or (resuming) the saved
    one — so a resumed campaign samples against exactly the trajectory it started with."""
    path = out_dir / CLOSED_LOOP_FILE
    summary_path = out_dir / "closed_loop.json"
    if resume and given is None and path.exists() and summary_path.exists():
        try:
            return ClosedLoop.load(path), json.loads(summary_path.read_text())
        except (OSError, ValueError, KeyError) as error:  # re-simulated below
            print(
                f"stt-drake campaign: {path} or {summary_path} unreadable ({error}); "
                "simulating the closed loop again",
                file=sys.stderr,
            )
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
    write_json(summary_path, summary)
    return given, summary
