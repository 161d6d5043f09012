"""`stt-drake compare`: STT against the chance-constrained CBF-QP and the potential field
(:mod:`stt_drake.assembly.baselines`) on one scenario.

Per controller: one closed-loop simulation of the scenario (same plant, disturbance and
obstacles; STT through :func:`stt_drake.run.simulate`: ``stt`` is the paper's reactive tube
(a guide section of the file is dropped), ``stt-guided`` the tube under the guide (the
file's section, or :class:`~stt_drake.config.GuideConfig`'s defaults)), then a
true-obstacle Monte Carlo campaign (:func:`stt_drake.campaign.run_campaign`) of `runs`
draws against that closed loop in ``out_dir/<controller>/``. A baseline has no tube: its
closed loop has c = y and r = 0, and only the campaign's output check is reported.

``comparison.json`` has one row per controller (:data:`ROW_KEYS`):

* `success_rate`: 1.0 when the simulation ended normally, the *output* reached the target
  set and stayed in it to the end (:func:`output_reach_time`, the same rule for every
  controller) and no plant limit was exceeded, else 0.0 (one simulation);
* `worst_collision_frequency`, `clopper_pearson_lower_99`, `clopper_pearson_upper_99`: the
  campaign's output check at the worst obstacle (highest worst-time collision frequency),
  with its simultaneous 99 % Clopper-Pearson interval; `verdict` over every obstacle's
  output verdict (:func:`row_verdict`: ``certified``, ``inconclusive`` or ``violated``) and
  `runs_to_certify` (inconclusive: about how many runs would certify it at the frequencies
  seen, null otherwise or when no run count would);
* `t_output_in_target_s` (s, null if never: the output's final entry into the target set),
  `path_length_m`, `min_clearance_m` = min over time and obstacles of ‖y − μ_j‖ − r_o_j;
* `step_us_median`: the controller's cost per control step (µs, median, this process): STT,
  the tube law's :meth:`~stt_drake.core.tube.TubeLaw.evaluate` on the belief as the tube
  prepares it (:meth:`~stt_drake.core.belief.ObstacleBelief.from_port`) plus
  :meth:`~stt_drake.core.control.FunnelController.control_from_tube` on the logged samples;
  CBF, the controller's own timing of its updates (belief, rows, QP); APF, the controller
  system's `control` port evaluated on the logged samples (Drake's port overhead included);
* `qp_infeasible_count`: the CBF's updates whose hard QP was infeasible (null otherwise);
* `model_error`: null, or the name of the perturbation of the plant's true parameters
  (:data:`MODEL_ERRORS`) the row's simulations ran with (``--model-error``);
* against the TRUE obstacles of the simulation (:mod:`stt_drake.campaign.crowd_metrics`: the
  logged ``true_obstacle_position`` with perception, else the scripted means):
  `collision_rate` (1.0 if ‖y − O_j‖ < r_o_j at some logged time, else 0.0),
  `min_distance_m` (min of ‖y − O_j‖ − r_o_j), `comfort_violation_s` (seconds closer than
  the comfort distance, ``--comfort-distance``) and `obstacle_collision_frequency` (per
  obstacle, against 1 − ε_j; :func:`~stt_drake.campaign.crowd_metrics.obstacle_frequencies`);
  the document's `comfort_distance_m` is the comfort distance used.

Plus ``comparison.md`` (the table) and ``comparison.png`` (paths and metrics). The out
folder is locked for the whole comparison and refused when it already holds one, unless
resumed (:mod:`stt_drake.compare_checks`).
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from stt_drake.assembly.baselines import (
    BASELINES,
    SOLVERS,
    BaselineError,
    build_baseline_diagram,
    nominal_plant,
)
from stt_drake.assembly.laws import make_funnel_controller, make_tube_law
from stt_drake.campaign import (
    CampaignError,
    CampaignSpec,
    ClosedLoop,
    run_campaign,
)
from stt_drake.campaign.backends import check_scheduler_address
from stt_drake.campaign.crowd_metrics import crowd_record, obstacle_frequencies
from stt_drake.campaign.spec import check_runs
from stt_drake.compare_checks import (
    COMPARISON_FILE,
    DRAWS_FILE,
    CompareError,
    check_common,
    check_out,
    check_resumed_loop,
    comparison_folder,
)
from stt_drake.config import GuideConfig, OmniRobot, Quadrotor, Scenario
from stt_drake.core.belief import ObstacleBelief
from stt_drake.core.crowd_metrics import (
    DEFAULT_COMFORT_DISTANCE,
    check_comfort_distance,
    output_reach_time,
)
from stt_drake.core.rules import RuleError
from stt_drake.core.statistics import CERTIFIED, INCONCLUSIVE, VIOLATED, verdict_words
from stt_drake.run import scenario_simulator, simulate
from stt_drake.runlog import RunLog, write_json
from stt_drake.systems.baselines import PotentialFieldController

#: Every controller `compare` knows, in table order: the paper's reactive tube, the tube
#: under the guide (:mod:`stt_drake.core.guide`), the baselines.
CONTROLLERS = ("stt", "stt-guided", *BASELINES)
#: The keys of every row of comparison.json.
ROW_KEYS = (
    "controller",
    "model_error",
    "success_rate",
    "worst_collision_frequency",
    "clopper_pearson_lower_99",
    "clopper_pearson_upper_99",
    "verdict",
    "runs_to_certify",
    "t_output_in_target_s",
    "path_length_m",
    "min_clearance_m",
    "step_us_median",
    "qp_infeasible_count",
    "collision_rate",
    "min_distance_m",
    "comfort_violation_s",
    "obstacle_collision_frequency",
)
#: The plant-parameter perturbations of ``--model-error``, per plant config type:
#: (name, {field: factor}) applied to the scenario's true values.
MODEL_ERRORS: dict[type, tuple[tuple[str, dict[str, float]], ...]] = {
    OmniRobot: (("wheel_radius x0.9", {"wheel_radius": 0.9}),),
    Quadrotor: (
        ("mass x0.5", {"mass": 0.5}),
        ("mass x2", {"mass": 2.0}),
        ("drag x2", {"drag": 2.0}),
    ),
}
TABLE_FILE, FIGURE_FILE = "comparison.md", "comparison.png"


@dataclass
class ControllerRun:
    """One controller's simulation: its log (the :mod:`stt_drake.runlog` layout; a
    baseline's has c = y, r = 0), whether it ended normally with every plant limit kept,
    its median step time (µs) and the CBF's infeasible-update count."""

    log: RunLog
    finished: bool
    step_us: float
    qp_infeasible_count: int | None = None


def min_clearance(log: RunLog) -> float:
    """min over samples and active obstacles of ‖y − μ_j‖ − r_o_j (m); +∞ without any."""
    gap = log.mean_clearance[log.active]
    return float(gap.min()) if gap.size else math.inf


def _plant_states(log: RunLog, stages: int) -> np.ndarray:
    """(T, stages·n) the controller's stacked states: y, and for two stages ẏ estimated
    from the logged output (only for timing: the kernels' cost does not depend on it)."""
    if stages == 1:
        return log.output
    return np.hstack([log.output, np.gradient(log.output, log.t, axis=0)])


def stt_step_time_us(scenario: Scenario, log: RunLog) -> float:
    """Median µs of one STT control step on the logged samples: the tube law
    (``evaluate`` on the prepared belief, as the tube system does) and the funnel controller
    (``control_from_tube``)."""
    law, controller = make_tube_law(scenario), make_funnel_controller(scenario)
    vectors = log.rows("belief")
    states = _plant_states(log, controller.stages)
    axes = np.zeros((log.count, 3)) if log.dimension == 3 else None
    times = np.empty(log.samples)
    for k in range(log.samples):
        tube = np.append(log.center[k], log.radius[k])
        start = time.perf_counter()
        belief = ObstacleBelief.from_port(vectors[k], log.dimension, log.task)
        law.evaluate(log.center[k], belief, circulation=axes)
        controller.control_from_tube(log.t[k], states[k], tube)
        times[k] = time.perf_counter() - start
    return float(1e6 * np.median(times))


def _port_step_time_us(system: PotentialFieldController, log: RunLog, order: int) -> float:
    """Median µs of evaluating `system`'s `control` output on each logged sample (its
    `plant_state` and `obstacle_belief` inputs fixed to the sample)."""
    context = system.CreateDefaultContext()
    state_port = system.GetInputPort("plant_state")
    belief_port = system.GetInputPort("obstacle_belief")
    control = system.GetOutputPort("control")
    states, vectors = _plant_states(log, order), log.rows("belief")
    times = np.empty(log.samples)
    for k in range(log.samples):
        state_port.FixValue(context, states[k])
        belief_port.FixValue(context, vectors[k])
        start = time.perf_counter()
        control.Eval(context)
        times[k] = time.perf_counter() - start
    return float(1e6 * np.median(times))


def simulate_stt(scenario: Scenario) -> ControllerRun:
    """The STT closed loop (:func:`stt_drake.run.simulate`) and its step time."""
    result = simulate(scenario)
    limits = result.metrics.plant.get("limits", {}).values()
    finished = result.metrics.stop_reason is None and all(r["holds"] for r in limits)
    return ControllerRun(result.log, finished, stt_step_time_us(scenario, result.log))


def simulate_baseline(scenario: Scenario, controller: str, solver: str = "osqp") -> ControllerRun:
    """The baseline `controller`'s closed loop for `scenario.duration` (the scenario's
    SimulatorConfig); a run the Simulator stops with an exception keeps what was logged."""
    built = build_baseline_diagram(scenario, controller, solver)
    simulator = scenario_simulator(built.diagram, scenario)
    finished = True
    try:
        simulator.Initialize()
        simulator.AdvanceTo(scenario.duration)
    except Exception:  # a failed run is a result of the comparison, not an error
        finished = False
    context = simulator.get_context()
    logs = {name: sink.FindLog(context) for name, sink in built.loggers.items()}
    samples = min(log.num_samples() for log in logs.values())
    data = {name: log.data()[:, :samples].T.copy() for name, log in logs.items()}
    log = RunLog(
        {
            "name": np.array(scenario.name),
            "t": logs["output"].sample_times()[:samples].copy(),
            "output": data["output"],
            "center": data["output"],
            "radius": np.zeros(samples),
            "belief": data["belief"],
            "control": data["control"],
            "dimension": np.array(scenario.dimension),
            "start": np.asarray(scenario.start, dtype=float),
            "initial_set_radius": np.array(scenario.initial_set_radius),
            "target": np.asarray(scenario.target, dtype=float),
            "target_set_radius": np.array(scenario.target_set_radius),
            "obstacle_radius": built.task.radius,
            "epsilon": built.task.epsilon,
            "p_d": built.task.p_d,
            "full_covariance": np.array(built.belief_source.full_covariance),
        }
    )
    system = built.controller
    if controller == "cbf":
        controller_context = system.GetMyContextFromRoot(context)
        return ControllerRun(
            log, finished, system.median_step_time_us(), system.infeasible_count(controller_context)
        )
    order = system.GetInputPort("plant_state").size() // scenario.dimension
    return ControllerRun(log, finished, _port_step_time_us(system, log, order))


def _worst_obstacle(summary: dict[str, Any]) -> dict[str, Any]:
    """The campaign's obstacle entry with the highest worst-time output collision
    frequency (ties: the highest upper bound)."""
    return max(
        summary["obstacles"],
        key=lambda o: (o["worst_collision_frequency"], o["clopper_pearson_upper_99"]),
    )


def row_verdict(obstacles: Sequence[dict[str, Any]]) -> tuple[str, int | None]:
    """The verdict of a campaign's output check over all its obstacles and, when it is
    ``inconclusive``, about how many runs would certify every obstacle (the largest of
    their `runs_to_certify`; None when one of them has none): ``violated`` if any obstacle
    is violated, else ``inconclusive`` if any is, else ``certified``."""
    verdicts = {o["verdict"] for o in obstacles}
    if VIOLATED in verdicts:
        return VIOLATED, None
    if INCONCLUSIVE not in verdicts:
        return CERTIFIED, None
    needed = [o["runs_to_certify"] for o in obstacles if o["verdict"] == INCONCLUSIVE]
    return INCONCLUSIVE, None if None in needed else max(needed)


def comparison_row(
    controller: str,
    run: ControllerRun,
    campaign: dict[str, Any],
    model_error: str | None,
    comfort_distance: float = DEFAULT_COMFORT_DISTANCE,
) -> dict[str, Any]:
    """The comparison.json row of one controller (:data:`ROW_KEYS`, module docstring)."""
    log = run.log
    crowd = crowd_record(log, comfort_distance)
    t_in = output_reach_time(log.t, log.output, log.target, log.target_set_radius)
    worst = _worst_obstacle(campaign)
    verdict, runs_to_certify = row_verdict(campaign["obstacles"])
    steps = np.linalg.norm(np.diff(log.output, axis=0), axis=1)
    row = {
        "controller": controller,
        "model_error": model_error,
        "success_rate": 1.0 if run.finished and t_in is not None else 0.0,
        "worst_collision_frequency": worst["worst_collision_frequency"],
        "clopper_pearson_lower_99": worst["clopper_pearson_lower_99"],
        "clopper_pearson_upper_99": worst["clopper_pearson_upper_99"],
        "verdict": verdict,
        "runs_to_certify": runs_to_certify,
        "t_output_in_target_s": t_in,
        "path_length_m": float(steps.sum()),
        "min_clearance_m": min_clearance(log),
        "step_us_median": run.step_us,
        "qp_infeasible_count": run.qp_infeasible_count,
        "collision_rate": 1.0 if crowd["collided"] else 0.0,
        "min_distance_m": crowd["min_distance_m"],
        "comfort_violation_s": crowd["comfort_violation_s"],
        "obstacle_collision_frequency": obstacle_frequencies([crowd]),
    }
    return {key: row[key] for key in ROW_KEYS}


def _check_input(
    scenario: Scenario,
    controllers: Sequence[str],
    runs: int,
    out_dir: Path,
    options: dict[str, Any],
) -> None:
    """Refuse bad input before any work (:class:`CompareError`, naming the parameter);
    `options`: ``workers``, ``scheduler``, ``model_error``, ``solver``,
    ``comfort_distance``."""
    unknown = [c for c in controllers if c not in CONTROLLERS]
    if not controllers or unknown:
        raise CompareError(
            f"`controllers`: each must be one of {', '.join(CONTROLLERS)} (got "
            f"{', '.join(map(repr, unknown or controllers)) or 'none'})"
        )
    if len(set(controllers)) != len(controllers):
        raise CompareError(f"`controllers`: each controller once (got {', '.join(controllers)})")
    if any(c in BASELINES for c in controllers):
        try:
            nominal_plant(scenario)
        except BaselineError as error:
            raise CompareError(str(error)) from None
    check_common(scenario, controllers, options["workers"])
    if options["model_error"] and type(scenario.plant) not in MODEL_ERRORS:
        raise CompareError(
            f"`model_error`: no model-error variants for the {type(scenario.plant).__name__} "
            f"plant of scenario {scenario.name!r} (only for "
            f"{', '.join(plant.__name__ for plant in MODEL_ERRORS)}); drop `model_error`"
        )
    try:
        check_runs(runs)
        if options["scheduler"] is not None:
            check_scheduler_address(options["scheduler"])
    except CampaignError as error:
        raise CompareError(str(error)) from None
    try:
        check_comfort_distance(options["comfort_distance"], "`comfort_distance`")
    except RuleError as error:
        raise CompareError(str(error)) from None
    if options["solver"] not in SOLVERS:
        raise CompareError(
            f"`solver`: must be one of {', '.join(SOLVERS)} (got {options['solver']!r})"
        )
    check_out(out_dir)


def _variants(scenario: Scenario, model_error: bool) -> list[tuple[str | None, Scenario]]:
    """The nominal scenario, then (with `model_error`) each perturbation of its plant."""
    variants: list[tuple[str | None, Scenario]] = [(None, scenario)]
    if model_error:
        for name, factors in MODEL_ERRORS[type(scenario.plant)]:
            changes = {
                key: factor * getattr(scenario.plant, key) for key, factor in factors.items()
            }
            variants.append((name, replace(scenario, plant=replace(scenario.plant, **changes))))
    return variants


def _folder_name(model_error: str) -> str:
    """A model-error name as a folder name ("mass x0.5" → "mass_x0.5")."""
    return model_error.replace(" ", "_")


def compare(
    scenario_path: str | Path,
    controllers: Sequence[str],
    runs: int,
    out_dir: Path,
    workers: int | None = None,
    scheduler: str | None = None,
    model_error: bool = False,
    solver: str = "osqp",
    progress: Callable[[int, int, str], None] | None = None,
    resume: bool = False,
    comfort_distance: float = DEFAULT_COMFORT_DISTANCE,
) -> dict[str, Any]:
    """Compare `controllers` on the scenario file `scenario_path` (module docstring) and
    write comparison.json, comparison.md and comparison.png into `out_dir`; return the
    comparison.json document.

    `out_dir` is locked for the whole comparison. With `resume`, every closed loop is
    simulated again (one simulation per controller and variant; it must equal the one its
    campaign sampled against) and each campaign continues from its ``runs.jsonl``;
    without, a folder that already holds a comparison is refused. `progress`, if given,
    is called with (closed loops done, closed loops in all, what comes next) before each
    controller's closed loop and at the end; each campaign then shows its progress bar.

    Raises:
        CompareError: bad input (an option, the scenario, the folder: locked, or holding a
            comparison without `resume`), before any simulation.
        CampaignStoppedError: a campaign could not finish.
    """
    from stt_drake.assembly import load_scenario
    from stt_drake.config import ScenarioError

    path = Path(scenario_path)
    try:
        scenario = load_scenario(path)
    except ScenarioError as error:
        raise CompareError(f"`scenario_path`: bad scenario {path}: {error}") from None
    options = {"workers": workers, "scheduler": scheduler, "model_error": model_error}
    more = {"solver": solver, "comfort_distance": comfort_distance}
    _check_input(scenario, controllers, runs, out_dir, {**options, **more})
    ordered = [c for c in CONTROLLERS if c in controllers]
    variants = [
        (name, variant, out_dir if name is None else out_dir / "model_error" / _folder_name(name))
        for name, variant in _variants(scenario, model_error)
    ]
    folders = [folder / c for _, _, folder in variants for c in ordered]
    with comparison_folder(out_dir, resume, folders):
        if resume and (out_dir / DRAWS_FILE).exists():
            raise CompareError(
                f"`resume`: {out_dir} holds a comparison over draws ({DRAWS_FILE}); resume "
                "it with `draws`, or choose another `out_dir`"
            )
        if resume:
            print(
                "stt-drake compare: --resume: each controller's closed loop is simulated again "
                "(one simulation per controller and variant); its campaign continues from its "
                "runs.jsonl",
                file=sys.stderr,
            )
        rows, figure_runs = [], {}
        total = len(variants) * len(ordered)
        for name, variant, folder in variants:
            for controller in ordered:
                if progress is not None:
                    what = controller if name is None else f"{controller} ({name})"
                    progress(len(rows), total, f"next: {what}")
                run = _simulate(variant, controller, solver)
                loop = ClosedLoop.from_log(run.log)
                if resume:
                    check_resumed_loop(folder / controller, loop, controller)
                outcome = run_campaign(
                    CampaignSpec(scenario=str(path), runs=runs),
                    folder / controller,
                    workers=workers,
                    scheduler=scheduler,
                    resume=resume,
                    progress=progress is not None,
                    closed_loop=loop,
                )
                rows.append(
                    comparison_row(controller, run, outcome.summary, name, comfort_distance)
                )
                if name is None:
                    figure_runs[controller] = run.log
        if progress is not None:
            progress(total, total, "done")
        document = {
            "scenario": scenario.name,
            "scenario_path": str(path),
            "runs": runs,
            "solver": solver,
            "comfort_distance_m": comfort_distance,
            "controllers": ordered,
            "model_errors": [name for name, _, _ in variants[1:]],
            "rows": rows,
        }
        write_json(out_dir / COMPARISON_FILE, document)
        (out_dir / TABLE_FILE).write_text(comparison_markdown(document))
        from stt_drake.plotting.compare import plot_comparison

        plot_comparison(figure_runs, rows, runs).savefig(out_dir / FIGURE_FILE, dpi=120)
    return document


def _simulate(scenario: Scenario, controller: str, solver: str) -> ControllerRun:
    """`controller`'s closed loop on `scenario` (``stt``: the guide section dropped;
    ``stt-guided``: the file's guide, or the defaults)."""
    if controller == "stt":
        return simulate_stt(replace(scenario, guide=None))
    if controller == "stt-guided":
        return simulate_stt(replace(scenario, guide=scenario.guide or GuideConfig()))
    return simulate_baseline(scenario, controller, solver)


def cell(value: Any, digits: int = 3) -> str:
    """A table cell: — for None, yes/no, floats to `digits` significant digits."""
    if value is None:
        return "—"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.{digits}g}" if math.isfinite(value) else str(value)
    return str(value)


#: A column of a markdown table: (header, row key, meaning).
Column = tuple[str, str, str]
#: The columns both comparison tables have.
CONTROLLER_COLUMN: Column = (
    "controller",
    "controller",
    "stt: the reactive tube; stt-guided: the tube under the guide; cbf: chance-constrained "
    "CBF-QP; apf: potential field",
)
STEP_COLUMN: Column = ("step (µs)", "step_us_median", "median cost of one control step")
#: The table's columns (comparison.md's legend says what each means).
_COLUMNS: tuple[Column, ...] = (
    CONTROLLER_COLUMN,
    ("model error", "model_error", "the perturbation of the plant's true parameters (— none)"),
    ("success", "success_rate", "1 if the run ended normally and the output reached the "
     "target set and stayed"),
    ("worst collision freq.", "worst_collision_frequency", "the campaign's output collision "
     "frequency at the worst obstacle and time"),
    ("99 % CP lower", "clopper_pearson_lower_99", "its simultaneous 99 % Clopper-Pearson "
     "lower bound"),
    ("99 % CP upper", "clopper_pearson_upper_99", "and upper bound"),
    ("verdict", "verdict", "certified: every obstacle's upper bound ≤ 1 − ε_j; violated: a "
     "lower bound > 1 − ε_j; inconclusive: neither (needs ≈N runs: a campaign that size "
     "would certify at the frequencies seen)"),
    ("output in target (s)", "t_output_in_target_s", "the output's final entry into the "
     "target set (— never)"),
    ("path (m)", "path_length_m", "length of the output's path"),
    ("min clearance (m)", "min_clearance_m", "min over time and obstacles of ‖y − μ_j‖ − "
     "r_o_j (the belief's means)"),
    STEP_COLUMN,
    ("QP infeasible", "qp_infeasible_count", "the CBF's updates whose hard QP was infeasible"),
    ("true collision", "collision_rate", "1 if the output came within r_o_j of a true "
     "obstacle"),
    ("min distance (m)", "min_distance_m", "min of ‖y − O_j‖ − r_o_j to the true obstacles"),
    ("comfort violation (s)", "comfort_violation_s", "seconds closer than the comfort "
     "distance to a true obstacle"),
)


def markdown_table(rows: Sequence[dict[str, Any]], columns: Sequence[Column]) -> str:
    """`rows` as a markdown table of `columns`."""
    lines = [
        "| " + " | ".join(header for header, _, _ in columns) + " |",
        "|" + "|".join("---" for _ in columns) + "|",
    ]
    for row in rows:
        lines.append("| " + " | ".join(cell(row[key]) for _, key, _ in columns) + " |")
    return "\n".join(lines)


def markdown_document(
    title: str, facts: Sequence[str], table: str, columns: Sequence[Column]
) -> str:
    """A comparison.md: the `title` heading, the `facts` (one line each), the table and a
    legend of the `columns`' meanings."""
    legend = [f"- **{header}**: {meaning}" for header, _, meaning in columns]
    return "\n".join(
        [f"# {title}", "", *facts, "", table, "", "Columns:", "", *legend, ""]
    )


def comparison_table(rows: Sequence[dict[str, Any]]) -> str:
    """The rows as a markdown table (what the command prints, and comparison.md's body)."""
    worded = [
        {**row, "verdict": verdict_words(row["verdict"], row["runs_to_certify"])} for row in rows
    ]
    return markdown_table(worded, _COLUMNS)


def comparison_markdown(document: dict[str, Any]) -> str:
    """comparison.md of a comparison.json `document`: heading, scenario, runs, the table
    and what its columns mean."""
    facts = [
        f"Scenario `{document['scenario']}` ({document['scenario_path']}); one simulation per "
        f"controller, then a true-obstacle campaign of {document['runs']:,} runs against it.",
        "",
        "Generated by `stt-drake compare`; every number is in comparison.json.",
    ]
    title = f"Controller comparison: {document['scenario']}"
    return markdown_document(title, facts, comparison_table(document["rows"]), _COLUMNS)
