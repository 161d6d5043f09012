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
from stt_drake.campaign.kinds import CAMPAIGN_KINDS, CampaignInput, CampaignKind, validate_spec
from stt_drake.campaign.report import write_summary
from stt_drake.campaign.sampling import CLOSED_LOOP_FILE, ClosedLoop, run_seed
from stt_drake.campaign.spec import CampaignError, CampaignSpec, CampaignStoppedError
from stt_drake.runlog import unwritable_reason

if TYPE_CHECKING:
    from stt_drake.config import ScenarioText

__all__ = ["CLOSED_LOOP_FILE", "RUNS_FILE", "SPEC_FILE", "CampaignOutcome", "run_campaign"]

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
    """The scenario as the campaign sees it (the file's seed; a kind that redraws: run 0's
    draw, only to reject bad input up front, None when that draw is rejected). The YAML is
    parsed once; what the kind needs of the scenario (a random field, a perception section,
    obstacles: :meth:`~stt_drake.campaign.kinds.CampaignKind.scenario_problem`) is checked
    on the parsed file, before anything is drawn."""
    from stt_drake.assembly import prepare_scenario
    from stt_drake.config import AssumptionError, ScenarioError, draws_obstacles

    kind = CAMPAIGN_KINDS[spec.kind]
    try:
        schema = source.parse(spec.guide)
        problem = kind.scenario_problem(schema, draws_obstacles(schema))
        if problem is not None:
            raise CampaignError(problem)
        return prepare_scenario(schema, run_seed(spec.seed, 0) if kind.redraws else None)
    except ScenarioError as error:
        if kind.redraws and isinstance(error, AssumptionError):
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
    validate_spec(spec)
    if chunk_size is not None and chunk_size < 1:
        raise CampaignError(f"`chunk_size`: must be ≥ 1 (got {chunk_size})")
    check_workers(workers)
    if not 0.0 < dask_timeout < float("inf"):
        raise CampaignError(f"`dask_timeout`: must be a finite time > 0 s (got {dask_timeout})")
    if scheduler is not None:
        check_scheduler_address(scheduler)
    reason = unwritable_reason(out_dir)
    if reason is not None:
        raise CampaignError(f"`out_dir`: {out_dir} {reason}")
    path = Path(spec.scenario)
    from stt_drake.config import ScenarioText

    text = _scenario_text(path)
    scenario_text = ScenarioText(text, path.stem, str(path.resolve().parent))
    scenario = _load_checked_scenario(spec, scenario_text)
    text_hash = hashlib.sha256(text.encode()).hexdigest()
    simulating = CAMPAIGN_KINDS[spec.kind].simulates_runs
    preload = ["stt_drake.campaign", *(["stt_drake.run"] if simulating else [])]
    kernels = scenario.dimension if simulating and scenario is not None else None
    backend = open_backend(workers, scheduler, preload, dask_timeout, kernels)
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
    kind: CampaignKind = CAMPAIGN_KINDS[spec.kind]
    given = CampaignInput(spec, scenario, scenario_text, out_dir, closed_loop, resume)
    prepared = kind.prepare(given)
    size, label = chunk_size or kind.chunk_size, kind.failure_label

    from tqdm import tqdm

    runs_path = out_dir / RUNS_FILE
    if resume:
        found = scan_runs(
            runs_path,
            lambda r: r["seed"] == run_seed(spec.seed, r["run"]) and prepared.shaped(r),
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
    failures = sum(kind.failed(r) for r in done)
    bar.set_postfix({label: failures})

    with runs_path.open("a") as stream:

        def on_records(batch: list[Record]) -> None:
            nonlocal failures
            for record in batch:
                if kind.failed(record):
                    failures += 1
                    kind.keep_failure(record, spec, scenario_text, out_dir)  # before its record
                stream.write(record_line(record) + "\n")
                records[record["run"]] = record
            stream.flush()
            bar.update(len(batch))
            bar.set_postfix({label: failures})

        def run(batches: Iterator[list[tuple[int, int]]]) -> None:
            execute(backend, prepared.task, prepared.task_args, batches, on_records)

        try:
            _run_pending(backend, spec, records, size, run)
        finally:
            bar.close()

    finished = [records[i] for i in range(spec.runs)]
    name = scenario.name if scenario is not None else scenario_text.name
    summary = write_summary(spec, name, finished, out_dir, start, prepared, figures, malformed)
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
