"""The campaign kinds, one object each (:data:`CAMPAIGN_KINDS`), and what a kind is.

**What a campaign kind needs** — every question the runner
(:mod:`~stt_drake.campaign.executor`), the report (:mod:`~stt_drake.campaign.report`), the
spec's checks (:mod:`~stt_drake.campaign.spec`) and the command
(:mod:`stt_drake.cli.campaign`) ask of one, as the attributes and methods of
:class:`CampaignKind`:

* its `name` (``--kind``), and the sentence saying where its `true_obstacles` come from;
* which options apply: `samples_belief` (the true obstacles are sampled around the belief:
  ``motion`` and ``tau``), `crowd` (its runs are simulated against their true obstacles:
  ``comfort_distance`` and the crowd keys of the summary);
* what its scenario must hold (:meth:`~CampaignKind.scenario_problem`) and whether each
  run redraws the scenario's random field (`redraws`);
* **what a run is**: :meth:`~CampaignKind.prepare` gives the executor task (a picklable
  function of a batch of (run index, seed)), its arguments and the check a record read
  back from ``runs.jsonl`` must pass (:class:`Prepared`); `chunk_size` runs per task by
  default; `simulates_runs`: the workers preload :mod:`stt_drake.run`;
* **what counts as a failure**: :meth:`~CampaignKind.failed` (counted on the progress bar
  as `failure_label`), and what is kept of one (:meth:`~CampaignKind.keep_failure`);
* **how it is summarised**: :meth:`~CampaignKind.summarise` (the kind's keys of
  ``campaign.json``) and :meth:`~CampaignKind.report_lines` (its lines of the printed
  report);
* **how it is drawn**: :meth:`~CampaignKind.figure`, written as `figure_file`.

The summaries and printed lines are :mod:`~stt_drake.campaign.summaries`, the runs
:mod:`~stt_drake.campaign.sampling`, :mod:`~stt_drake.campaign.randomisation` and
:mod:`~stt_drake.campaign.end_to_end`, the figures :mod:`stt_drake.plotting.campaign`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from stt_drake.campaign.end_to_end import (
    end_to_end_failed,
    end_to_end_task,
    is_end_to_end_record,
    logged_times,
)
from stt_drake.campaign.randomisation import (
    FAILURES_DIR,
    draw_failed,
    failing_draw_yaml,
    failure_name,
    is_randomisation_record,
    randomisation_task,
)
from stt_drake.campaign.sampling import (
    CHECKS,
    MOTIONS,
    ClosedLoop,
    closed_loop_of,
    is_true_obstacle_record,
    output_collided,
    sample_true_obstacles,
)
from stt_drake.campaign.spec import (
    DEFAULT_MOTION,
    DEFAULT_TAU,
    CampaignError,
    CampaignSpec,
    check_runs,
)
from stt_drake.campaign.summaries import (
    CONFIDENCE,
    collision_counts,
    end_to_end_lines,
    randomisation_lines,
    summarise_end_to_end,
    summarise_randomisation,
    summarise_true_obstacles,
    true_obstacle_lines,
)
from stt_drake.core.crowd_metrics import DEFAULT_COMFORT_DISTANCE, check_comfort_distance
from stt_drake.core.rules import RuleError
from stt_drake.core.statistics import family_confidence

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from stt_drake.config import Scenario, ScenarioText

#: A run record (one line of runs.jsonl).
Record = dict[str, Any]


@dataclass(frozen=True)
class CampaignInput:
    """What the runner hands a kind to prepare a campaign (:meth:`CampaignKind.prepare`):
    the `spec`; the prepared `scenario` (None: a randomisation campaign's run 0 was
    rejected) and its text `source`; the locked folder `out_dir`; the `closed_loop` that
    replaces a true-obstacle campaign's simulation (None: simulate it); `resume`."""

    spec: CampaignSpec
    scenario: Any
    source: ScenarioText
    out_dir: Path
    closed_loop: ClosedLoop | None
    resume: bool


@dataclass
class Prepared:
    """What a kind prepared for one campaign (:meth:`CampaignKind.prepare`).

    `task` is called by the executor as ``task(*task_args, batch)`` with a batch of (run
    index, seed) and returns their records; `shaped` says whether a record read back from
    ``runs.jsonl`` has the kind's shape. The rest is what the summary and figure need:
    `closed_loop` and its summary (true-obstacles), `epsilon` (m,) ε_j and `times` (T,)
    the logged times in s (end-to-end).
    """

    task: Callable[..., list[Record]]
    task_args: tuple[Any, ...]
    shaped: Callable[[Record], bool]
    closed_loop: ClosedLoop | None = None
    closed_loop_summary: dict[str, Any] | None = None
    epsilon: np.ndarray | None = None
    times: np.ndarray | None = None


class CampaignKind:
    """One kind of campaign (module docstring: what a kind needs). Subclasses set the
    attributes and implement the methods that raise NotImplementedError."""

    #: The kind's name (``CampaignSpec.kind``, ``--kind``).
    name: str
    #: Where its true obstacles come from, as "a campaign of `kind` NAME <true_obstacles>".
    true_obstacles: str
    #: Its runs sample the true obstacles around the belief (``motion``, ``tau`` apply).
    samples_belief: bool = False
    #: Its runs are simulated against their true obstacles and record the crowd keys
    #: (``comfort_distance`` applies; the summary has the crowd keys).
    crowd: bool = False
    #: Each run redraws the scenario's random field from its seed.
    redraws: bool = False
    #: Its runs simulate (the workers preload :mod:`stt_drake.run`).
    simulates_runs: bool = True
    #: Runs per executor task unless the campaign says otherwise.
    chunk_size: int = 1
    #: What the progress bar calls the failures it counts.
    failure_label: str = "collided"
    #: The figure's file name in the campaign folder.
    figure_file: str

    def scenario_problem(self, schema: Scenario, draws_obstacles: bool) -> str | None:
        """Why the parsed scenario `schema` cannot have a campaign of this kind (naming the
        scenario's section), or None; `draws_obstacles`: it has a random field."""
        raise NotImplementedError

    def prepare(self, given: CampaignInput) -> Prepared:
        """The campaign's task and what its summary needs (:class:`Prepared`)."""
        raise NotImplementedError

    def failed(self, record: Record) -> bool:
        """Whether the run of `record` is a failure."""
        raise NotImplementedError

    def keep_failure(
        self, record: Record, spec: CampaignSpec, source: ScenarioText, out_dir: Path
    ) -> None:
        """Keep what replays a failed run in `out_dir`, before its record is written
        (nothing by default)."""

    def summarise(
        self, spec: CampaignSpec, records: list[Record], prepared: Prepared
    ) -> dict[str, Any]:
        """The kind's keys of campaign.json over the finished `records`."""
        raise NotImplementedError

    def report_lines(self, summary: dict[str, Any]) -> list[str]:
        """The kind's lines of the printed report of `summary`."""
        raise NotImplementedError

    def figure(self, summary: dict[str, Any], records: list[Record], prepared: Prepared) -> Figure:
        """The campaign's figure (written as :attr:`figure_file`)."""
        raise NotImplementedError


class TrueObstacles(CampaignKind):
    """Sample the true obstacles around the belief against one simulated closed loop
    (:func:`stt_drake.campaign.sampling.sample_true_obstacles`)."""

    name = "true-obstacles"
    true_obstacles = "samples the obstacles against one closed loop"
    samples_belief = True
    simulates_runs = False
    chunk_size = 250
    figure_file = "collision_frequency.png"

    def scenario_problem(self, schema: Scenario, draws_obstacles: bool) -> str | None:
        if schema.obstacles or draws_obstacles:
            return None
        return (
            "scenario.obstacles: a true-obstacle campaign draws the true centres of the "
            "obstacles; the scenario has none (nothing to check)"
        )

    def prepare(self, given: CampaignInput) -> Prepared:
        loop, summary = closed_loop_of(
            given.scenario, given.out_dir, given.closed_loop, given.resume
        )
        count, steps = loop.count, len(loop.t)

        def shaped(record: Record) -> bool:
            return is_true_obstacle_record(record, count, steps)

        arguments = (loop, given.spec.motion, given.spec.tau)
        return Prepared(sample_true_obstacles, arguments, shaped, loop, summary)

    def failed(self, record: Record) -> bool:
        return output_collided(record)

    def summarise(
        self, spec: CampaignSpec, records: list[Record], prepared: Prepared
    ) -> dict[str, Any]:
        body = summarise_true_obstacles(prepared.closed_loop, records)
        body["true_obstacle_motion"] = spec.motion
        body["ou_tau_s"] = spec.tau if spec.motion == "ou" else None
        body["closed_loop"] = prepared.closed_loop_summary
        return body

    def report_lines(self, summary: dict[str, Any]) -> list[str]:
        return true_obstacle_lines(summary)

    def figure(self, summary: dict[str, Any], records: list[Record], prepared: Prepared) -> Figure:
        from stt_drake.plotting.campaign import plot_collision_frequency

        loop = prepared.closed_loop
        steps = len(loop.t)
        counts = collision_counts(records, loop.count, steps)
        member = family_confidence(CONFIDENCE, len(CHECKS) * loop.count * steps)
        model = loop.collision_probability()
        ordered = {check: model[check] for check in CHECKS}
        return plot_collision_frequency(
            loop.t, loop.epsilon, counts, len(records), member, ordered, summary["obstacles"]
        )


class Randomisation(CampaignKind):
    """Redraw the scenario's random field per run, simulate it, check every guarantee
    (:func:`stt_drake.campaign.randomisation.randomisation_run`)."""

    name = "randomisation"
    true_obstacles = "simulates each draw's scripted obstacles"
    crowd = True
    redraws = True
    failure_label = "failures"
    figure_file = "randomisation.png"

    def scenario_problem(self, schema: Scenario, draws_obstacles: bool) -> str | None:
        if draws_obstacles:
            return None
        return (
            "scenario.random_obstacles: a randomisation campaign needs a random_obstacles "
            "section with count > 0 or a count_range, or a crowd section"
        )

    def prepare(self, given: CampaignInput) -> Prepared:
        (given.out_dir / FAILURES_DIR).mkdir(exist_ok=True)
        arguments = (given.source, given.spec.guide, given.spec.comfort_distance)
        return Prepared(randomisation_task, arguments, is_randomisation_record)

    def failed(self, record: Record) -> bool:
        return draw_failed(record)

    def keep_failure(
        self, record: Record, spec: CampaignSpec, source: ScenarioText, out_dir: Path
    ) -> None:
        """The failing draw as scenario YAML (a record in runs.jsonl always has its YAML,
        even after a kill: this is written first)."""
        yaml = failing_draw_yaml(source, record["seed"], spec.seed, record["run"], spec.guide)
        (out_dir / failure_name(record["run"])).write_text(yaml)

    def summarise(
        self, spec: CampaignSpec, records: list[Record], prepared: Prepared
    ) -> dict[str, Any]:
        return summarise_randomisation(records)

    def report_lines(self, summary: dict[str, Any]) -> list[str]:
        return randomisation_lines(summary)

    def figure(self, summary: dict[str, Any], records: list[Record], prepared: Prepared) -> Figure:
        from stt_drake.plotting.campaign import plot_randomisation

        simulated = [r for r in records if r["status"] == "simulated"]
        names = [n for n in summary["guarantees"] if n != "reach_and_stay"]
        title = (
            f"randomisation campaign: {summary['runs']} runs, {summary['rejected_draws']} "
            f"rejected, {summary['failed_runs']} failed"
        )
        return plot_randomisation(simulated, [draw_failed(r) for r in simulated], names, title)


class EndToEnd(CampaignKind):
    """Simulate truth, sensor, tracker, tube, controller and plant per run and count
    collisions with the TRUE obstacles (:mod:`stt_drake.campaign.end_to_end`)."""

    name = "end-to-end"
    true_obstacles = "simulates its own true obstacles (perception: process noise)"
    crowd = True
    figure_file = "end_to_end.png"

    def scenario_problem(self, schema: Scenario, draws_obstacles: bool) -> str | None:
        if schema.perception is not None:
            return None
        return (
            "scenario.perception: an end-to-end campaign needs a perception section "
            "(true obstacles, sensor, tracker; see diagrams/omni_tracked.yaml)"
        )

    def prepare(self, given: CampaignInput) -> Prepared:
        scenario, spec = given.scenario, given.spec
        steps, count = logged_times(scenario), len(scenario.obstacles)

        def shaped(record: Record) -> bool:
            return is_end_to_end_record(record, count, steps)

        arguments = (given.source, steps, spec.guide, spec.comfort_distance)
        epsilon = np.array([o.epsilon for o in scenario.obstacles], dtype=float)
        times = scenario.log_period * np.arange(steps)
        return Prepared(end_to_end_task, arguments, shaped, epsilon=epsilon, times=times)

    def failed(self, record: Record) -> bool:
        return end_to_end_failed(record)

    def summarise(
        self, spec: CampaignSpec, records: list[Record], prepared: Prepared
    ) -> dict[str, Any]:
        return summarise_end_to_end(records, prepared.epsilon, prepared.times)

    def report_lines(self, summary: dict[str, Any]) -> list[str]:
        return end_to_end_lines(summary)

    def figure(self, summary: dict[str, Any], records: list[Record], prepared: Prepared) -> Figure:
        from stt_drake.plotting.campaign import plot_end_to_end

        epsilon, times = prepared.epsilon, prepared.times
        counts = collision_counts(records, len(epsilon), len(times))
        member = summary["procedure"]["member_confidence"]
        calibration = [o["calibration_95"] for o in summary["obstacles"]]
        return plot_end_to_end(
            times, epsilon, counts, len(records), member, calibration, summary["obstacles"]
        )


#: Every campaign kind by name, in the order of ``--kind``'s choices.
CAMPAIGN_KINDS: dict[str, CampaignKind] = {
    kind.name: kind for kind in (TrueObstacles(), Randomisation(), EndToEnd())
}
#: The kinds' names.
KINDS = tuple(CAMPAIGN_KINDS)
#: The kinds whose runs sample the true obstacles around the belief (``motion`` and
#: ``tau`` apply to them only).
SAMPLING_KINDS = tuple(name for name, kind in CAMPAIGN_KINDS.items() if kind.samples_belief)
#: The kinds whose runs simulate and record the crowd metrics against the true obstacles
#: (:mod:`stt_drake.campaign.crowd_metrics`; ``comfort_distance`` applies to them only).
CROWD_KINDS = tuple(name for name, kind in CAMPAIGN_KINDS.items() if kind.crowd)


def validate_spec(spec: CampaignSpec) -> None:
    """Raise CampaignError naming the parameter of the first bad value of `spec`."""
    if spec.kind not in KINDS:
        raise CampaignError(f"`kind`: must be one of {', '.join(KINDS)} (got {spec.kind!r})")
    check_runs(spec.runs)
    if spec.seed < 0:
        raise CampaignError(f"`seed`: must be ≥ 0 (got {spec.seed})")
    if spec.motion not in MOTIONS:
        raise CampaignError(
            f"`motion`: must be one of {', '.join(MOTIONS)} (got {spec.motion!r})"
        )
    if not (spec.tau > 0.0 and math.isfinite(spec.tau)):
        raise CampaignError(f"`tau`: must be a finite time > 0 s (got {spec.tau})")
    if spec.kind not in SAMPLING_KINDS and spec.motion != DEFAULT_MOTION:
        raise CampaignError(sampling_only("motion", spec.kind))
    if spec.tau != DEFAULT_TAU and (spec.kind not in SAMPLING_KINDS or spec.motion != "ou"):
        raise CampaignError(sampling_only("tau", spec.kind, spec.motion))
    try:
        check_comfort_distance(spec.comfort_distance, "`comfort_distance`")
    except RuleError as error:
        raise CampaignError(str(error)) from None
    if spec.kind not in CROWD_KINDS and spec.comfort_distance != DEFAULT_COMFORT_DISTANCE:
        raise CampaignError(
            f"`comfort_distance`: applies only to `kind` {' or '.join(CROWD_KINDS)} (the "
            f"runs that are simulated against their true obstacles); a campaign of `kind` "
            f"{spec.kind} {CAMPAIGN_KINDS[spec.kind].true_obstacles}"
        )


def sampling_only(parameter: str, kind: str, motion: str | None = None) -> str:
    """Why the spec's `parameter` (``motion`` or ``tau``) does not apply to a campaign of
    `kind` (and `motion`)."""
    if kind not in SAMPLING_KINDS:
        return (
            f"`{parameter}`: applies only to `kind` {' or '.join(SAMPLING_KINDS)} (the true "
            f"obstacles sampled around the belief); a campaign of `kind` {kind} "
            + CAMPAIGN_KINDS[kind].true_obstacles
        )
    return f"`{parameter}`: applies only with `motion` ou (got {motion})"
