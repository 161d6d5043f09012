"""The randomisation campaign's runs: redraw the scenario's random field, simulate, check.

A run loads the scenario with its own seed; a draw that breaks the paper's assumptions
(the loader raises :class:`stt_drake.config.AssumptionError`) is a rejected draw, not a
failure. A failing draw is kept as scenario YAML that replays it alone.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from stt_drake.campaign.crowd_metrics import crowd_record, is_crowd_record
from stt_drake.campaign.folder import is_number
from stt_drake.core.crowd_metrics import DEFAULT_COMFORT_DISTANCE
from stt_drake.core.invariants import INVARIANT_NAMES

if TYPE_CHECKING:
    from stt_drake.config import Scenario, ScenarioText

FAILURES_DIR = "failures"


def randomisation_run(
    schema: Scenario, index: int, seed: int, comfort_distance: float = DEFAULT_COMFORT_DISTANCE
) -> dict[str, Any]:
    """Complete the parsed scenario `schema` with `seed` (redrawing its random field),
    simulate, check.

    Record: ``{"run", "seed", "status"}`` with status ``rejected`` (the draw breaks the
    paper's assumptions; `reason`), ``error`` (the simulation raised; `reason`) or
    ``simulated`` (then `obstacles`, `reached`, `t_tube_in_target`, `holds`, `success`,
    `stop_reason`, `stalls` and `invariants` as in metrics.json, and the crowd metrics
    against the draw's true obstacles, :data:`stt_drake.campaign.crowd_metrics.CROWD_KEYS`, with
    comfort distance `comfort_distance` m).
    """
    from stt_drake.assembly import prepare_scenario
    from stt_drake.config import AssumptionError
    from stt_drake.run import simulate

    record: dict[str, Any] = {"run": index, "seed": seed}
    try:
        scenario = prepare_scenario(schema, seed)
    except AssumptionError as error:
        return {**record, "status": "rejected", "reason": str(error)}
    try:
        result = simulate(scenario)
    except Exception as error:  # a crash on one draw is a finding, not the end of the campaign
        return {**record, "status": "error", "reason": f"{type(error).__name__}: {error}"}
    metrics = result.metrics
    return {
        **record,
        "status": "simulated",
        "obstacles": len(scenario.obstacles),
        "reached": metrics.reached,
        "t_tube_in_target": metrics.t_tube_in_target,
        "holds": metrics.holds,
        "success": result.success,
        "stop_reason": metrics.stop_reason,
        "stalls": metrics.stalls,
        "invariants": metrics.invariants,
        **crowd_record(result.log, comfort_distance),
    }


def randomisation_task(
    source: ScenarioText, guide: bool, comfort_distance: float, runs: Sequence[tuple[int, int]]
) -> list[dict[str, Any]]:
    """One executor task: the records of a batch of (run index, seed), the YAML parsed once
    for the batch (the schema holds Drake objects that do not pickle, so the text travels);
    `guide` False drops the scenario's guide section."""
    schema = source.parse(guide)
    return [randomisation_run(schema, index, seed, comfort_distance) for index, seed in runs]


def is_stall_record(stall: Any) -> bool:
    """Whether `stall` has the shape of a metrics.json `stalls` entry
    (:func:`stt_drake.core.progress.find_stalls`)."""
    return (
        isinstance(stall, dict)
        and all(is_number(stall.get(key)) for key in ("start_s", "detected_s", "distance_m"))
        and (stall.get("end_s") is None or is_number(stall.get("end_s")))
        and isinstance(stall.get("position"), list)
        and all(is_number(x) for x in stall["position"])
        and isinstance(stall.get("ended"), str)
    )


def has_run_story(record: dict[str, Any]) -> bool:
    """Whether a simulated run's record has a valid `stop_reason` (str or None) and
    `stalls` (a list of stall entries); a record written before they existed has neither
    and passes (read them with :func:`stalls_of` and ``record.get("stop_reason")``)."""
    reason = record.get("stop_reason")
    stalls = record.get("stalls", [])
    return (
        (reason is None or isinstance(reason, str))
        and isinstance(stalls, list)
        and all(is_stall_record(stall) for stall in stalls)
    )


def stalls_of(record: dict[str, Any]) -> list[dict[str, Any]]:
    """A simulated run's stalls ([] for a record written before they were recorded)."""
    return record.get("stalls") or []


def stalled_to_end(record: dict[str, Any]) -> bool:
    """Whether a simulated run has a stall that lasts to the end of the run."""
    return any(stall["end_s"] is None for stall in stalls_of(record))


def is_randomisation_record(record: dict[str, Any]) -> bool:
    """Whether a record read back from ``runs.jsonl`` has the shape
    :func:`randomisation_run` gives (its status and that status's keys and types;
    `stop_reason`, `stalls` and the crowd keys may be missing, as in records of older
    versions)."""
    status = record.get("status")
    if status in ("rejected", "error"):
        return isinstance(record.get("reason"), str)
    if status != "simulated":
        return False
    invariants = record.get("invariants")
    if not (isinstance(invariants, dict) and set(invariants) == set(INVARIANT_NAMES)):
        return False
    for entry in invariants.values():
        if not (
            isinstance(entry, dict)
            and isinstance(entry.get("holds"), bool)
            and is_number(entry.get("worst_margin"))
            and is_number(entry.get("t_worst"))
        ):
            return False
    t_c = record.get("t_tube_in_target", "missing")  # a record from an older version: redone
    return (
        type(record.get("obstacles")) is int
        and all(isinstance(record.get(key), bool) for key in ("reached", "holds", "success"))
        and (t_c is None or is_number(t_c))
        and has_run_story(record)
        and is_crowd_record(record, record["obstacles"])
    )


def draw_failed(record: dict[str, Any]) -> bool:
    """Whether a run is a failure: the simulation raised, or a guarantee or the goal failed
    (a rejected draw is not a failure)."""
    return record["status"] == "error" or (
        record["status"] == "simulated" and not record["success"]
    )


def failing_draw_yaml(
    source: ScenarioText, seed: int, campaign_seed: int, index: int, guide: bool = True
) -> str:
    """The scenario text that reproduces one draw: its own `seed` (and `name`) set; the
    replay command says ``--no-guide`` when the campaign dropped the guide. Recorded track
    files stay named as in the scenario: the header says in which folder they are."""
    text, name = source.text, source.name
    replay = "stt-drake run <this file>" + ("" if guide else " --no-guide")
    header = (
        f"# Failing draw: run {index} of a randomisation campaign (campaign seed "
        f"{campaign_seed}). Replay: {replay}\n"
    )
    if "!Recorded" in text:
        header += f"# Its recorded track files are named relative to {source.base}\n"
    body = text if text.endswith("\n") else text + "\n"
    seed_line = re.compile(r"^seed:[^\n]*$", re.MULTILINE)
    if seed_line.search(body):
        body = seed_line.sub(f"seed: {seed}", body)
    else:
        body += f"seed: {seed}\n"
    if not re.search(r"^name:", body, re.MULTILINE):
        body += f"name: {name}\n"
    return header + body


def failure_name(index: int) -> str:
    """Where run `index`'s failing draw is kept, relative to the campaign folder."""
    return f"{FAILURES_DIR}/run_{index:06d}.yaml"
