"""`stt-drake compare --draws K`: every controller on the same K randomised draws of a
scenario with a ``random_obstacles`` section — compared on *arriving*, not on one layout.

Draw i loads the scenario with the seed ``SeedSequence(seed, spawn_key=(i,))``
(:func:`stt_drake.campaign.run_seed`, as a randomisation campaign does), so every
controller meets the same obstacles; a draw that breaks the paper's assumptions is
rejected for all. Controllers: ``stt`` (the paper's reactive tube: the file's guide
section dropped), ``stt-guided`` (the tube under the guide: the file's section, or the
defaults of :class:`~stt_drake.config.GuideConfig` when it has none), ``cbf`` and ``apf``
(:mod:`stt_drake.compare`).

A draw's record (``draws.jsonl``, one line each): `controller`, `draw`, `seed`, `status`
(``simulated`` or ``rejected``) and, simulated: `reached` (the run ended normally and the
output reached the target set and stayed, :func:`stt_drake.compare.output_reach_time`),
`stalled` (not reached and a stall lasting to the end: the rule of
:mod:`stt_drake.core.progress` on the logged centre — the output for a baseline — and
attraction point), `unsafe` (at some logged time the belief's exact probability that the
output collides with obstacle j exceeds 1 − ε_j: the PrT-RAS task broken, Definition 2.3),
`t_output_in_target_s` (the output's final entry into the target set, null if not
reached), `path_length_m`, `min_clearance_m` (min of ‖y − μ_j‖ − r_o_j), `step_us`;
and against the draw's TRUE obstacles (:mod:`stt_drake.campaign.crowd_metrics`; without perception
the scripted means): `collided` (‖y − O_j‖ < r_o_j at some logged time),
`first_collision_s`, `obstacle_collisions` and `obstacle_epsilon` (per obstacle),
`min_distance_m` (min of ‖y − O_j‖ − r_o_j) and `comfort_violation_s` (seconds with that
surface distance below the comfort distance, ``--comfort-distance``,
:mod:`stt_drake.core.crowd_metrics`).

Each line also holds its ``sha256`` checksum (:func:`stt_drake.campaign.folder.record_line`)
and is appended as its draw finishes; ``--resume`` keeps the lines whose checksum, seed and
shape are right (a line that fails is named on stderr and its draw redone: so is a line
written before the crowd keys existed), the spec of the draws (``draws_spec.json``:
scenario file hash, seed, solver, comfort distance) must match, and `draws` may grow.

A row of ``comparison.json`` (:data:`DRAW_ROW_KEYS`) per controller, over its simulated
draws: `success_rate` (reached), `stall_rate`, `timeout_rate` (neither reached nor
stalled: still moving at the end, or stopped), `unsafe_rate`, `t_output_in_target_p50_s` /
`t_output_in_target_p90_s` over the reached draws, `path_length_mean_m`, `min_clearance_m` (the
smallest over draws) and `step_us_median`; against the true obstacles: `collision_rate`
(draws with a collision), `min_distance_m` (the mean over draws of each draw's minimum),
`min_distance_worst_m` (the smallest), `comfort_violation_s` (mean over draws),
`obstacle_collision_frequency` (per obstacle index: draws that collided with it, against
the mean 1 − ε_j; :func:`stt_drake.campaign.crowd_metrics.obstacle_frequencies`) and
`collision_within_allowed` (every obstacle's frequency within its 1 − ε_j).
"""

from __future__ import annotations

import hashlib
import json
import statistics
import sys
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from stt_drake.campaign.crowd_metrics import (
    CROWD_KEYS,
    collision_check,
    crowd_record,
    is_crowd_record,
)
from stt_drake.campaign.folder import (
    CHECKSUM_KEY,
    check_same_spec,
    is_number,
    record_checksum,
    record_line,
)
from stt_drake.campaign.spec import CampaignError, CampaignStoppedError
from stt_drake.compare import (
    CONTROLLER_COLUMN,
    STEP_COLUMN,
    Column,
    CompareError,
    markdown_document,
    markdown_table,
    min_clearance,
    simulate_baseline,
    simulate_stt,
)
from stt_drake.compare_checks import DRAWS_FILE, check_common, check_out, comparison_folder
from stt_drake.core.crowd_metrics import (
    DEFAULT_COMFORT_DISTANCE,
    check_comfort_distance,
    output_reach_time,
)
from stt_drake.core.rules import RuleError
from stt_drake.runlog import restore_non_finite, write_json

if TYPE_CHECKING:
    from stt_drake.config import ScenarioText

#: The controllers a draws comparison knows, in table order.
DRAW_CONTROLLERS = ("stt", "stt-guided", "cbf", "apf")
#: The keys of every row of a draws comparison.json.
DRAW_ROW_KEYS = (
    "controller",
    "draws",
    "success_rate",
    "stall_rate",
    "timeout_rate",
    "unsafe_rate",
    "t_output_in_target_p50_s",
    "t_output_in_target_p90_s",
    "path_length_mean_m",
    "min_clearance_m",
    "step_us_median",
    "collision_rate",
    "min_distance_m",
    "min_distance_worst_m",
    "comfort_violation_s",
    "obstacle_collision_frequency",
    "collision_within_allowed",
)
#: The crowd keys of a draw record (those of the campaigns' runs but path length and the
#: reach time, which the record has already as `path_length_m` and `t_output_in_target_s`).
DRAW_CROWD_KEYS = tuple(k for k in CROWD_KEYS if k not in ("path_length_m", "time_to_goal_s"))
DRAWS_SPEC_FILE = "draws_spec.json"
#: Draws-spec keys added later, with the value an older ``draws_spec.json`` meant.
_SPEC_DEFAULTS = {"comfort_distance": DEFAULT_COMFORT_DISTANCE}
#: The most draws a comparison may ask for (every record is kept in memory).
MAX_DRAWS = 1_000_000


def draw_record(
    source: ScenarioText,
    controller: str,
    draw: int,
    seed: int,
    solver: str = "osqp",
    comfort_distance: float = DEFAULT_COMFORT_DISTANCE,
) -> dict[str, Any]:
    """Simulate `controller` on draw `draw` (scenario seed `seed`); the record of the
    module docstring."""
    from stt_drake.assembly import prepare_scenario
    from stt_drake.assembly.guide import stall_rule
    from stt_drake.campaign import ClosedLoop
    from stt_drake.config import AssumptionError, GuideConfig
    from stt_drake.core.progress import find_stalls

    record: dict[str, Any] = {"controller": controller, "draw": draw, "seed": seed}
    schema = source.parse(guide=controller == "stt-guided")
    if controller == "stt-guided" and schema.guide is None:
        schema.guide = GuideConfig()
    try:
        scenario = prepare_scenario(schema, seed)
    except AssumptionError as error:
        return {**record, "status": "rejected", "reason": str(error)}
    if controller.startswith("stt"):
        run = simulate_stt(scenario)
    else:
        run = simulate_baseline(scenario, controller, solver)
    log = run.log
    t_in = output_reach_time(log.t, log.output, log.target, log.target_set_radius)
    reached = run.finished and t_in is not None
    stalls = find_stalls(
        log.t, log.center, log.attraction_point, stall_rule(scenario), log.target_set_radius
    )
    collision = ClosedLoop.from_log(log).collision_probability()["output"]
    unsafe = bool(np.any(collision > 1.0 - log.epsilon + 1e-9))
    steps = np.linalg.norm(np.diff(log.output, axis=0), axis=1)
    crowd = crowd_record(log, comfort_distance)
    return {
        **record,
        "status": "simulated",
        "reached": reached,
        "stalled": not reached and bool(stalls) and stalls[-1]["end_s"] is None,
        "unsafe": unsafe,
        "t_output_in_target_s": t_in if reached else None,
        "path_length_m": float(steps.sum()),
        "min_clearance_m": min_clearance(log),
        "step_us": run.step_us,
        **{key: crowd[key] for key in DRAW_CROWD_KEYS},
    }


def draws_task(
    source: ScenarioText,
    solver: str,
    comfort_distance: float,
    batch: Sequence[tuple[str, int, int]],
) -> list[dict[str, Any]]:
    """One executor task: the records of a batch of (controller, draw, seed)."""
    return [
        draw_record(source, c, draw, seed, solver, comfort_distance) for c, draw, seed in batch
    ]


def _is_draw_record(record: Any, seed: int) -> bool:
    """Whether a record read back from draws.jsonl has :func:`draw_record`'s shape and
    the seed of its draw."""
    from stt_drake.campaign import run_seed

    if not isinstance(record, dict) or record.get("controller") not in DRAW_CONTROLLERS:
        return False
    draw = record.get("draw")
    if type(draw) is not int or draw < 0 or record.get("seed") != run_seed(seed, draw):
        return False
    if record.get("status") == "rejected":
        return isinstance(record.get("reason"), str)
    t_in = record.get("t_output_in_target_s", "missing")  # an older version's record: redone
    return (
        record.get("status") == "simulated"
        and all(isinstance(record.get(k), bool) for k in ("reached", "stalled", "unsafe"))
        and (t_in is None or is_number(t_in))
        and all(is_number(record.get(k)) for k in ("path_length_m", "min_clearance_m", "step_us"))
        and all(k in record for k in DRAW_CROWD_KEYS)
        and is_crowd_record({**record, "time_to_goal_s": t_in})
    )


def read_draws(path: Path, seed: int) -> tuple[dict[tuple[str, int], dict[str, Any]], list[str]]:
    """(the valid records of draws.jsonl by (controller, draw), what was skipped: one line
    per skipped line). A line is skipped when it is not JSON, its checksum is missing or
    wrong, or it is not a draw record of `seed`; the first valid line of a draw wins; a torn
    last line (no newline) is cut off."""
    records: dict[tuple[str, int], dict[str, Any]] = {}
    skipped: list[str] = []
    if not path.exists():
        return records, skipped
    data = path.read_bytes()
    keep = data.rfind(b"\n") + 1
    if keep < len(data):
        with path.open("r+b") as stream:
            stream.truncate(keep)
    for number, line in enumerate(data[:keep].split(b"\n")[:-1], start=1):
        try:
            record = json.loads(line)
            checksum = record.pop(CHECKSUM_KEY, None) if isinstance(record, dict) else None
            good = checksum is not None and checksum == record_checksum(record)
            record = restore_non_finite(record) if good else record
        except (ValueError, RecursionError, LookupError, TypeError, AttributeError):
            skipped.append(f"line {number}: not a draw record")
            continue
        where = f"line {number}"
        if isinstance(record, dict) and "controller" in record and "draw" in record:
            where += f" ({record['controller']}, draw {record['draw']})"
        if not good:
            skipped.append(f"{where}: {'no checksum' if checksum is None else 'checksum mismatch'}")
        elif not _is_draw_record(record, seed):
            skipped.append(f"{where}: not a draw record of this comparison")
        else:
            records.setdefault((record["controller"], record["draw"]), record)
    return records, skipped


def draw_row(controller: str, records: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The row of one controller over its simulated draws (module docstring)."""
    simulated = [r for r in records if r["status"] == "simulated"]
    count = len(simulated)

    def rate(key: str) -> float | None:
        return sum(r[key] for r in simulated) / count if count else None

    times = [r["t_output_in_target_s"] for r in simulated if r["reached"]]
    timeout = sum(not r["reached"] and not r["stalled"] for r in simulated)
    return {
        "controller": controller,
        "draws": count,
        "success_rate": rate("reached"),
        "stall_rate": rate("stalled"),
        "timeout_rate": timeout / count if count else None,
        "unsafe_rate": rate("unsafe"),
        "t_output_in_target_p50_s": float(np.percentile(times, 50)) if times else None,
        "t_output_in_target_p90_s": float(np.percentile(times, 90)) if times else None,
        "path_length_mean_m": statistics.fmean(r["path_length_m"] for r in simulated)
        if count
        else None,
        "min_clearance_m": min((r["min_clearance_m"] for r in simulated), default=None),
        "step_us_median": statistics.median(r["step_us"] for r in simulated) if count else None,
        "collision_rate": rate("collided"),
        "min_distance_m": statistics.fmean(r["min_distance_m"] for r in simulated)
        if count
        else None,
        "min_distance_worst_m": min((r["min_distance_m"] for r in simulated), default=None),
        "comfort_violation_s": statistics.fmean(r["comfort_violation_s"] for r in simulated)
        if count
        else None,
        **collision_check(simulated),
    }


def _check_spec(out_dir: Path, spec: dict[str, Any], resume: bool) -> None:
    """On resume, refuse a draws spec that differs from the one in `out_dir` (the number
    of draws may grow); then write it."""
    path = out_dir / DRAWS_SPEC_FILE
    if resume and path.exists():
        try:
            check_same_spec(path, spec, "comparison", defaults=_SPEC_DEFAULTS)
        except CampaignError as error:
            raise CompareError(str(error)) from None
    write_json(path, spec)


def compare_draws(
    scenario_path: str | Path,
    controllers: Sequence[str],
    draws: int,
    out_dir: Path,
    seed: int = 0,
    workers: int | None = None,
    solver: str = "osqp",
    resume: bool = False,
    comfort_distance: float = DEFAULT_COMFORT_DISTANCE,
    progress: Callable[[int, int], None] | None = None,
) -> dict[str, Any]:
    """Run every controller on `draws` draws (module docstring) on `workers` local
    processes; write ``draws.jsonl``, ``comparison.json`` and ``comparison.md`` into
    `out_dir` (locked meanwhile); return the comparison.json document. With `resume`, the
    draws already in ``draws.jsonl`` are kept. `progress`, if given, is called with (runs
    done, runs in all; a run is one controller on one draw) before the first run and as
    each batch finishes.

    Raises:
        CompareError: bad input (an option, the scenario without a random field, the
            folder: locked, holding a comparison without `resume`, another spec), before
            any simulation.
        CampaignStoppedError: a worker process died (the finished draws are kept).
    """
    from stt_drake.campaign import run_seed
    from stt_drake.campaign.backends import LocalPool, execute
    from stt_drake.config import (
        ScenarioError,
        ScenarioText,
        draws_obstacles,
        read_scenario_file,
    )

    path = Path(scenario_path)
    unknown = [c for c in controllers if c not in DRAW_CONTROLLERS]
    if not controllers or unknown or len(set(controllers)) != len(controllers):
        raise CompareError(
            f"`controllers`: each once, and each one of {', '.join(DRAW_CONTROLLERS)} (got "
            f"{', '.join(controllers) or 'none'})"
        )
    if not 1 <= draws <= MAX_DRAWS:
        raise CompareError(f"`draws`: must be ≥ 1 and ≤ {MAX_DRAWS:,} (got {draws})")
    if seed < 0:
        raise CompareError(f"`seed`: must be ≥ 0 (got {seed})")
    try:
        check_comfort_distance(comfort_distance, "`comfort_distance`")
    except RuleError as error:
        raise CompareError(str(error)) from None
    try:
        text = read_scenario_file(path)
        source = ScenarioText(text, path.stem, str(path.resolve().parent))
        schema = source.parse()
    except ScenarioError as error:
        raise CompareError(f"`scenario_path`: bad scenario {path}: {error}") from None
    if not draws_obstacles(schema):
        raise CompareError(
            "`draws`: the scenario needs a random_obstacles section (count > 0 or a "
            "count_range) or a crowd section to draw from"
        )
    check_common(schema, controllers, workers)
    check_out(out_dir)
    ordered = [c for c in DRAW_CONTROLLERS if c in controllers]
    spec = {"scenario_sha256": hashlib.sha256(text.encode()).hexdigest(), "seed": seed}
    with comparison_folder(out_dir, resume):
        _check_spec(
            out_dir, {**spec, "solver": solver, "comfort_distance": comfort_distance}, resume
        )
        done, skipped = read_draws(out_dir / DRAWS_FILE, seed) if resume else ({}, [])
        for line in skipped:
            print(f"stt-drake compare: {out_dir / DRAWS_FILE}: {line}; redone", file=sys.stderr)
        pending: Iterator[list[tuple[str, int, int]]] = (
            [(c, i, run_seed(seed, i))] for i in range(draws) for c in ordered if (c, i) not in done
        )
        backend = LocalPool(workers, ["stt_drake.compare_draws"])
        total, finished = draws * len(ordered), sum(c in ordered and i < draws for c, i in done)
        if progress is not None:
            progress(finished, total)
        try:
            with (out_dir / DRAWS_FILE).open("a" if resume else "w") as stream:

                def on_records(batch: list[dict[str, Any]]) -> None:
                    nonlocal finished
                    finished += len(batch)
                    for record in batch:
                        stream.write(record_line(record) + "\n")
                        done[(record["controller"], record["draw"])] = record
                    stream.flush()
                    if progress is not None:
                        progress(finished, total)

                arguments = (source, solver, comfort_distance)
                execute(backend, draws_task, arguments, pending, on_records)
        except BrokenProcessPool:
            raise CampaignStoppedError(
                "a worker process died (killed, out of memory or a crash in native code); "
                f"the finished draws are kept in {out_dir / DRAWS_FILE}: resume with `resume`"
            ) from None
        finally:
            backend.close()
        records = [done[(c, i)] for i in range(draws) for c in ordered]
        rows = [draw_row(c, [r for r in records if r["controller"] == c]) for c in ordered]
        document = {
            "scenario": schema.name,
            "scenario_path": str(path),
            "mode": "draws",
            "draws": draws,
            "seed": seed,
            "comfort_distance_m": comfort_distance,
            "rejected_draws": sum(r["status"] == "rejected" for r in records) // len(ordered),
            "controllers": ordered,
            "rows": rows,
        }
        write_json(out_dir / "comparison.json", document)
        (out_dir / "comparison.md").write_text(draws_markdown(document))
    return document


#: The draws table's columns (comparison.md's legend says what each means).
_COLUMNS: tuple[Column, ...] = (
    CONTROLLER_COLUMN,
    ("draws", "draws", "draws simulated (the rejected ones left out)"),
    ("success", "success_rate", "fraction of draws whose output reached the target set and "
     "stayed"),
    ("stall", "stall_rate", "fraction that stalled to the end"),
    ("timeout", "timeout_rate", "fraction neither reached nor stalled (still moving at the "
     "end, or stopped)"),
    ("unsafe", "unsafe_rate", "fraction where the belief's collision probability exceeded "
     "1 − ε_j at some logged time"),
    ("output in target p50 (s)", "t_output_in_target_p50_s", "median over the reached draws "
     "of the output's final entry into the target set"),
    ("output in target p90 (s)", "t_output_in_target_p90_s", "its 90th percentile"),
    ("path (m, mean)", "path_length_mean_m", "mean length of the output's path"),
    ("min clearance (m)", "min_clearance_m", "smallest ‖y − μ_j‖ − r_o_j over the draws "
     "(the belief's means)"),
    STEP_COLUMN,
    ("true collision", "collision_rate", "fraction of draws whose output came within r_o_j "
     "of a true obstacle"),
    ("min distance (m, mean)", "min_distance_m", "mean over draws of min ‖y − O_j‖ − r_o_j "
     "to the true obstacles"),
    ("comfort violation (s, mean)", "comfort_violation_s", "mean seconds closer than the "
     "comfort distance to a true obstacle"),
)


def draws_table(rows: Sequence[dict[str, Any]]) -> str:
    """The rows as a markdown table (what the command prints, and comparison.md's body)."""
    return markdown_table(rows, _COLUMNS)


def draws_markdown(document: dict[str, Any]) -> str:
    """comparison.md of a draws comparison.json `document`: heading, scenario, draws, the
    table and what its columns mean."""
    facts = [
        f"Scenario `{document['scenario']}` ({document['scenario_path']}); every controller on "
        f"the same {document['draws']:,} randomised draws (seed {document['seed']}, "
        f"{document['rejected_draws']:,} rejected).",
        "",
        "Generated by `stt-drake compare --draws`; every number is in comparison.json, every "
        "draw in draws.jsonl.",
    ]
    title = f"Controller comparison over draws: {document['scenario']}"
    return markdown_document(title, facts, draws_table(document["rows"]), _COLUMNS)
