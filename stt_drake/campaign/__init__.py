"""`stt-drake campaign`: Monte Carlo verification of the probabilistic guarantee.

Two kinds of campaign:

``true-obstacles``
    Sample the *true* obstacle centres from the belief, O_j(t) = μ_j(t) + σ_j(t)·ξ_j, and
    count actual collisions of the robot's output (‖y − O_j‖ < r_o_j) and of the tube
    (‖c − O_j‖ < r_o_j + r) per obstacle and time. ξ_j ~ N(0, I) is drawn once per run
    (``static``), or is an Ornstein-Uhlenbeck path with the same N(0, I) marginal (``ou``).
    The closed loop (y, c, r) depends only on the belief and the plant's (deterministic)
    disturbance, never on ξ, so it is **simulated once** and every run is a cheap,
    vectorised draw of ξ against the logged trajectory.
``randomisation``
    Each run loads the scenario with its own seed, which redraws the `random_obstacles`
    field (draws breaking the paper's assumptions are rejected by the loader and counted),
    simulates it and checks every guarantee. Failing draws are kept as scenario YAML.

Runs go through a :class:`concurrent.futures.Executor`: a local process pool, or a Dask
``distributed`` client. Each finished run is appended to ``runs.jsonl``; ``--resume`` skips
the runs already there. Summaries are order-independent functions of the set of runs.

Run i uses the seed :func:`run_seed` (campaign seed, i); ``stt-drake run SCENARIO --seed S``
replays a randomisation run alone. The statistics are in :mod:`stt_drake.core.statistics`.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import contextlib
import hashlib
import json
import math
import multiprocessing
import os
import re
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from stt_drake.cli.main import EXIT_BAD_INPUT, EXIT_FAILURE, EXIT_SUCCESS
from stt_drake.core.belief import ObstacleBelief
from stt_drake.core.statistics import (
    VIOLATED,
    clopper_pearson,
    family_confidence,
    simultaneous_verdict,
)

KINDS = ("true-obstacles", "randomisation")
MOTIONS = ("static", "ou")
#: Confidence of every reported interval (jointly, over the whole family of tests).
CONFIDENCE = 0.99
#: The two collision checks of a true-obstacle campaign.
CHECKS = ("output", "tube")
#: Loader messages (stt_drake.config) that mean "this draw breaks the paper's
#: assumptions" — counted as rejected draws, not as failures.
REJECTION_MARKERS = (
    "scenario.random_obstacles.count: could not place",
    "the initial avoidance condition fails",
)
RUNS_FILE, SPEC_FILE, SUMMARY_FILE = "runs.jsonl", "campaign_spec.json", "campaign.json"
CLOSED_LOOP_FILE, FAILURES_DIR = "closed_loop.npz", "failures"

PROCEDURE = (
    "Simultaneous two-sided Clopper-Pearson intervals, Bonferroni over the whole family "
    "fixed before sampling: every (check in {output, tube}) x (obstacle) x (logged time). "
    "Each interval has level 1 - alpha/F (alpha = 0.01, F = family_size), so with "
    "probability >= 99 % all of them cover their collision probability at once. No "
    "pilot set, no data-driven choice of times: the worst time is reported, but it is "
    "tested at the simultaneous level, so taking the worst of many times causes no bias. "
    "certified: upper bound <= 1 - epsilon_j at every logged time; violated: lower bound "
    "> 1 - epsilon_j at some logged time; the claim covers the logged times only."
)


class CampaignError(ValueError):
    """Bad campaign input; the message names the option or field."""


def run_seed(campaign_seed: int, index: int) -> int:
    """Seed of run `index`: ``SeedSequence(campaign_seed, spawn_key=(index,))``'s first word.

    Equal to ``SeedSequence(campaign_seed).spawn(index + 1)[index].generate_state(1)[0]``,
    a 32-bit integer; independent of how runs are chunked or scheduled.
    """
    sequence = np.random.SeedSequence(campaign_seed, spawn_key=(index,))
    return int(sequence.generate_state(1)[0])


# --------------------------------------------------------------------------- true obstacles


@dataclass(frozen=True)
class ClosedLoop:
    """The logged closed loop a true-obstacle campaign samples against.

    `epsilon` is what the campaign checks against; it defaults to the belief's ε but can
    differ from the ε the tube was simulated with (to test the check itself).
    """

    t: np.ndarray  # (T,) s
    output: np.ndarray  # (T, n) robot output y
    center: np.ndarray  # (T, n) tube centre c
    radius: np.ndarray  # (T,) tube radius r
    mean: np.ndarray  # (T, m, n) belief means μ_j(t)
    sigma: np.ndarray  # (T, m) belief standard deviations σ_j(t)
    obstacle_radius: np.ndarray  # (T, m) r_o_j
    epsilon: np.ndarray  # (m,) ε_j checked against

    @property
    def count(self) -> int:
        """Number of obstacles m."""
        return self.sigma.shape[1]

    @classmethod
    def from_log(cls, log: dict[str, Any], epsilon: Sequence[float] | None = None) -> ClosedLoop:
        """Decode a :func:`stt_drake.run.simulate` log (or a ``log.npz``)."""
        n = int(np.asarray(log["dimension"]))
        t = np.asarray(log["t"], dtype=float)
        samples = len(t)
        belief = ObstacleBelief.from_vector(np.asarray(log["belief"]).ravel(), n)
        m = belief.count // samples
        checked = belief.epsilon.reshape(samples, m)[0] if epsilon is None else epsilon
        return cls(
            t=t,
            output=np.asarray(log["output"], dtype=float).reshape(samples, n),
            center=np.asarray(log["center"], dtype=float).reshape(samples, n),
            radius=np.asarray(log["radius"], dtype=float).reshape(samples),
            mean=belief.mean.reshape(samples, m, n).copy(),
            sigma=belief.sigma.reshape(samples, m).copy(),
            obstacle_radius=belief.radius.reshape(samples, m).copy(),
            epsilon=np.asarray(checked, dtype=float).reshape(m).copy(),
        )

    def save(self, path: Path) -> None:
        """Write every field to an ``.npz`` file."""
        np.savez_compressed(path, **{f.name: getattr(self, f.name) for f in fields(self)})

    @classmethod
    def load(cls, path: Path) -> ClosedLoop:
        """Read a closed loop written by :meth:`save`."""
        with np.load(path) as data:
            return cls(**{f.name: data[f.name] for f in fields(cls)})

    def collision_probability(self) -> dict[str, np.ndarray]:
        """The belief's own collision probabilities (T, m) per check (noncentral χ²)."""
        from stt_drake.core.probability import avoid_probability

        output = avoid_probability(
            self.output[:, None, :], self.mean, self.sigma, self.obstacle_radius
        )
        tube = avoid_probability(
            self.center[:, None, :],
            self.mean,
            self.sigma,
            self.obstacle_radius + np.maximum(self.radius, 0.0)[:, None],
        )
        return {"output": 1.0 - output, "tube": 1.0 - tube}


def sample_xi(
    seeds: Sequence[int], times: np.ndarray, shape: tuple[int, int], motion: str, tau: float
) -> np.ndarray:
    """Standardised true-obstacle offsets ξ for each run: (R, T, m, n), marginally N(0, I).

    Run r's draws come from ``default_rng(seeds[r])`` alone. ``static``: one N(0, I) draw
    per obstacle, held over time. ``ou``: per axis dξ = −ξ/τ dt + √(2/τ) dW started in its
    stationary law N(0, 1), discretised exactly on the time grid:
    ξ_k = a_k ξ_{k−1} + √(1 − a_k²) w_k, a_k = exp(−(t_k − t_{k−1})/τ).
    """
    runs = len(seeds)
    steps = len(times)
    if motion == "static":
        draws = np.array([np.random.default_rng(s).standard_normal(shape) for s in seeds])
        return np.broadcast_to(draws[:, None], (runs, steps, *shape))
    if motion != "ou":
        raise ValueError(f"motion must be one of {MOTIONS} (got {motion!r})")
    noise = np.array([np.random.default_rng(s).standard_normal((steps, *shape)) for s in seeds])
    decay = np.exp(-np.diff(times) / tau)
    gain = np.sqrt(-np.expm1(-2.0 * np.diff(times) / tau))
    for k in range(1, steps):
        noise[:, k] = decay[k - 1] * noise[:, k - 1] + gain[k - 1] * noise[:, k]
    return noise


def hit_intervals(hit: np.ndarray) -> list[list[list[list[int]]]]:
    """Collision index ranges of a boolean (R, m, T) array: per run, per obstacle, the list
    of [start, stop) ranges of t-indices where `hit` is true."""
    runs, count, _ = hit.shape
    ranges: list[list[list[list[int]]]] = [[[] for _ in range(count)] for _ in range(runs)]
    padded = np.zeros((runs, count, hit.shape[2] + 2), dtype=np.int8)
    padded[:, :, 1:-1] = hit
    edges = np.diff(padded, axis=2)
    # nonzero() walks in C order, so the k-th start and k-th stop belong to one range.
    starts, stops = np.nonzero(edges == 1), np.nonzero(edges == -1)[2]
    for r, j, start, stop in zip(*starts, stops, strict=True):
        ranges[r][j].append([int(start), int(stop)])
    return ranges


def sample_true_obstacles(
    loop: ClosedLoop, motion: str, tau: float, runs: Sequence[tuple[int, int]]
) -> list[dict[str, Any]]:
    """One record per (run index, seed): where the output and the tube hit each true obstacle.

    Record: ``{"run", "seed", "output": [[[start, stop), ...] per obstacle], "tube": ...}``
    (time-index ranges of the closed loop's log). A collision is ‖y − O_j‖ < r_o_j
    (output) or ‖c − O_j‖ < r_o_j + r (tube), with O_j = μ_j + σ_j·ξ_j.
    """
    seeds = [seed for _, seed in runs]
    xi = sample_xi(seeds, loop.t, loop.mean.shape[1:], motion, tau)
    scaled = loop.sigma[None, :, :, None] * xi  # σ_j ξ_j: (R, T, m, n)
    reach = {
        "output": (loop.output, loop.obstacle_radius),
        "tube": (loop.center, loop.obstacle_radius + np.maximum(loop.radius, 0.0)[:, None]),
    }
    ranges = {}
    for check, (point, limit) in reach.items():
        gap = (point[:, None, :] - loop.mean)[None] - scaled  # point − O_j: (R, T, m, n)
        hit = np.einsum("rtjk,rtjk->rjt", gap, gap) < (limit**2).T[None]
        ranges[check] = hit_intervals(hit)
    return [
        {"run": index, "seed": seed, **{check: ranges[check][r] for check in CHECKS}}
        for r, (index, seed) in enumerate(runs)
    ]


def collision_counts(records: Iterable[dict[str, Any]], count: int, steps: int) -> np.ndarray:
    """Per check, obstacle and time, how many runs collided: (len(CHECKS), m, T) ints."""
    edges = np.zeros((len(CHECKS), count, steps + 1), dtype=np.int64)
    for record in records:
        for c, check in enumerate(CHECKS):
            for j, ranges in enumerate(record[check]):
                for start, stop in ranges:
                    edges[c, j, start] += 1
                    edges[c, j, stop] -= 1
    return np.cumsum(edges, axis=2)[:, :, :steps]


def _collided(record: dict[str, Any]) -> bool:
    return any(record["output"])


def summarise_true_obstacles(loop: ClosedLoop, records: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Per obstacle and check: worst-time frequency, simultaneous CP bounds and verdict."""
    runs = len(records)
    steps = len(loop.t)
    counts = collision_counts(records, loop.count, steps)
    family = len(CHECKS) * loop.count * steps
    member = family_confidence(CONFIDENCE, family)
    model = loop.collision_probability()
    obstacles = []
    for j in range(loop.count):
        allowed = 1.0 - float(loop.epsilon[j])
        entry: dict[str, Any] = {"index": j}
        for c, check in enumerate(CHECKS):
            verdict = simultaneous_verdict(counts[c, j], runs, allowed, member, model[check][:, j])
            record = {
                "epsilon": float(loop.epsilon[j]),
                "allowed_collision_probability": allowed,
                "worst_collision_frequency": verdict.frequency,
                "collisions_at_worst": int(counts[c, j, verdict.index]),
                "t_worst": float(loop.t[verdict.index]),
                "clopper_pearson_upper_99": verdict.upper,
                "clopper_pearson_lower_99": verdict.lower,
                "verdict": verdict.verdict,
                "runs_to_certify": verdict.runs_to_certify,
                "model_collision_probability_at_t_worst": float(model[check][verdict.index, j]),
                "model_worst_collision_probability": float(np.max(model[check][:, j])),
            }
            if check == "output":
                entry.update(record)
            else:
                entry["tube"] = record
        obstacles.append(entry)
    holds = not any(o["verdict"] == VIOLATED or o["tube"]["verdict"] == VIOLATED for o in obstacles)
    return {
        "holds": holds,
        "procedure": {
            "name": "simultaneous-clopper-pearson-bonferroni",
            "confidence": CONFIDENCE,
            "family_size": family,
            "member_confidence": member,
            "logged_times": steps,
            "description": PROCEDURE,
        },
        "runs_with_output_collision": sum(_collided(r) for r in records),
        "runs_with_tube_collision": sum(any(r["tube"]) for r in records),
        "obstacles": obstacles,
    }


# --------------------------------------------------------------------------- randomisation


def is_rejection(message: str) -> bool:
    """Whether a loader error means the draw breaks the paper's assumptions."""
    return any(marker in message for marker in REJECTION_MARKERS)


def randomisation_run(text: str, name: str, index: int, seed: int) -> dict[str, Any]:
    """Load the scenario with `seed` (redrawing its random field), simulate, check.

    Record: ``{"run", "seed", "status"}`` with status ``rejected`` (the draw breaks the
    paper's assumptions; `reason`), ``error`` (the simulation raised; `reason`) or
    ``simulated`` (then `obstacles`, `reached`, `t_reach`, `holds`, `success` and
    `invariants` as in metrics.json).
    """
    from stt_drake.config import ScenarioError, parse_scenario
    from stt_drake.run import simulate

    record: dict[str, Any] = {"run": index, "seed": seed}
    try:
        scenario = parse_scenario(text, default_name=name, seed=seed)
    except ScenarioError as error:
        if not is_rejection(str(error)):
            raise
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
        "reached": metrics["reached"],
        "t_reach": metrics["t_reach"],
        "holds": metrics["holds"],
        "success": result.success,
        "invariants": metrics["invariants"],
    }


def _randomisation_task(
    text: str, name: str, runs: Sequence[tuple[int, int]]
) -> list[dict[str, Any]]:
    return [randomisation_run(text, name, index, seed) for index, seed in runs]


def _failed(record: dict[str, Any]) -> bool:
    return record["status"] == "error" or (
        record["status"] == "simulated" and not record["success"]
    )


def failing_draw_yaml(text: str, name: str, seed: int, campaign_seed: int, index: int) -> str:
    """The scenario text that reproduces one draw: its own `seed` (and `name`) set."""
    header = (
        f"# Failing draw: run {index} of a randomisation campaign (campaign seed "
        f"{campaign_seed}). Replay: stt-drake run <this file>\n"
    )
    body = text if text.endswith("\n") else text + "\n"
    seed_line = re.compile(r"^seed:[^\n]*$", re.MULTILINE)
    if seed_line.search(body):
        body = seed_line.sub(f"seed: {seed}", body)
    else:
        body += f"seed: {seed}\n"
    if not re.search(r"^name:", body, re.MULTILINE):
        body += f"name: {name}\n"
    return header + body


def _distribution(values: Sequence[float]) -> dict[str, float | None]:
    if not values:
        return dict.fromkeys(("min", "p05", "median", "p95", "max", "mean"))
    data = np.asarray(values, dtype=float)
    quantiles = np.quantile(data, [0.0, 0.05, 0.5, 0.95, 1.0])
    keys = ("min", "p05", "median", "p95", "max")
    return {
        **{k: float(v) for k, v in zip(keys, quantiles, strict=True)},
        "mean": float(data.mean()),
    }


def summarise_randomisation(records: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Fraction of simulated draws where each guarantee held, t_c, worst margins, failures."""
    simulated = [r for r in records if r["status"] == "simulated"]
    failed = sorted((r for r in records if _failed(r)), key=lambda r: r["run"])
    guarantees: dict[str, Any] = {}
    names = list(simulated[0]["invariants"]) if simulated else []
    for name in names:
        worst = min(simulated, key=lambda r: (r["invariants"][name]["worst_margin"], r["run"]))
        held = sum(r["invariants"][name]["holds"] for r in simulated)
        guarantees[name] = {
            "held_runs": held,
            "held_fraction": held / len(simulated),
            "worst_margin": worst["invariants"][name]["worst_margin"],
            "t_worst": worst["invariants"][name]["t_worst"],
            "worst_run": worst["run"],
            "worst_seed": worst["seed"],
        }
    reached = sum(r["reached"] for r in simulated)
    guarantees["reach_and_stay"] = {
        "held_runs": reached,
        "held_fraction": reached / len(simulated) if simulated else None,
    }
    valid = len(simulated) + sum(r["status"] == "error" for r in records)  # not rejected
    upper = float(clopper_pearson(len(failed), valid, CONFIDENCE)[1]) if valid else None
    return {
        "holds": bool(simulated) and not failed,
        "simulated_runs": len(simulated),
        "rejected_draws": sum(r["status"] == "rejected" for r in records),
        "error_runs": sum(r["status"] == "error" for r in records),
        "failed_runs": len(failed),
        "failure_rate_clopper_pearson_upper_99": upper,
        "guarantees": guarantees,
        "t_reach": _distribution([r["t_reach"] for r in simulated if r["t_reach"] is not None]),
        "failures": [
            {"run": r["run"], "seed": r["seed"], "yaml": _failure_name(r["run"])} for r in failed
        ],
        "obstacles": [],
    }


def _failure_name(index: int) -> str:
    return f"{FAILURES_DIR}/run_{index:06d}.yaml"


# --------------------------------------------------------------------------- execution


@dataclass(frozen=True)
class CampaignSpec:
    """What a campaign is; `runs.jsonl` of one spec can be resumed only by the same spec
    (up to `runs`)."""

    scenario: str  # path as given
    kind: str = "true-obstacles"
    runs: int = 1000
    seed: int = 0
    motion: str = "static"
    tau: float = 2.0

    def validate(self) -> None:
        """Raise CampaignError naming the option of the first bad value."""
        if self.kind not in KINDS:
            raise CampaignError(f"--kind: must be one of {', '.join(KINDS)} (got {self.kind!r})")
        if self.runs < 1:
            raise CampaignError(f"--runs: must be ≥ 1 (got {self.runs})")
        if self.seed < 0:
            raise CampaignError(f"--seed: must be ≥ 0 (got {self.seed})")
        if self.motion not in MOTIONS:
            raise CampaignError(
                f"--true-obstacle-motion: must be one of {', '.join(MOTIONS)} (got {self.motion!r})"
            )
        if not (self.tau > 0.0 and math.isfinite(self.tau)):
            raise CampaignError(f"--ou-tau: must be a finite time > 0 s (got {self.tau})")


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
    only to reject bad input up front)."""
    from stt_drake.config import ScenarioError, parse_scenario

    seed = run_seed(spec.seed, 0) if spec.kind == "randomisation" else None
    try:
        scenario = parse_scenario(text, default_name=name, seed=seed)
    except ScenarioError as error:
        if spec.kind == "randomisation" and is_rejection(str(error)):
            return None
        raise CampaignError(f"bad scenario {spec.scenario}: {error}") from None
    if spec.kind == "randomisation" and (
        scenario.random_obstacles is None or scenario.random_obstacles.count == 0
    ):
        raise CampaignError(
            "scenario.random_obstacles: a randomisation campaign needs a random_obstacles "
            "section with count > 0"
        )
    return scenario


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
        size, failed, label = chunk_size or 250, _collided, "collided"
    else:
        task, task_args = _randomisation_task, (text, name)
        size, failed, label = chunk_size or 1, _failed, "failures"
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
                        (out_dir / _failure_name(record["run"])).write_text(
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
    if not randomising:
        body = summarise_true_obstacles(closed_loop, finished)
        body["true_obstacle_motion"] = spec.motion
        body["ou_tau_s"] = spec.tau if spec.motion == "ou" else None
        body["closed_loop"] = closed_loop_summary
    else:
        body = summarise_randomisation(finished)
    summary = {
        "scenario": scenario.name if scenario is not None else name,
        "scenario_path": str(path),
        "kind": spec.kind,
        "runs": spec.runs,
        "seed": spec.seed,
        "run_seed": "SeedSequence(seed, spawn_key=(i,)).generate_state(1)[0]",
        "wall_time_s": time.perf_counter() - start,
        **body,
    }
    (out_dir / SUMMARY_FILE).write_text(json.dumps(summary, indent=2) + "\n")
    if figures:
        _save_figure(summary, closed_loop, finished, out_dir)
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


# --------------------------------------------------------------------------- report


def _save_figure(
    summary: dict[str, Any],
    loop: ClosedLoop | None,
    records: Sequence[dict[str, Any]],
    out_dir: Path,
) -> Path:
    if loop is not None:
        figure = plot_collision_frequency(loop, records)
        path = out_dir / "collision_frequency.png"
    else:
        figure = plot_randomisation(summary, records)
        path = out_dir / "randomisation.png"
    figure.savefig(path, dpi=120)
    return path


def plot_collision_frequency(loop: ClosedLoop, records: Sequence[dict[str, Any]]) -> Any:
    """Empirical collision frequency over time per obstacle (output and tube) with its
    simultaneous 99 % Clopper-Pearson band, against 1 − ε_j and the belief's prediction."""
    from matplotlib.figure import Figure

    from stt_drake.plotting import PALETTE

    runs, steps = len(records), len(loop.t)
    counts = collision_counts(records, loop.count, steps)
    member = family_confidence(CONFIDENCE, len(CHECKS) * loop.count * steps)
    model = loop.collision_probability()
    figure = Figure(figsize=(8.0, 1.9 * loop.count + 0.8), layout="constrained")
    axes = figure.subplots(loop.count, 1, sharex=True, squeeze=False)[:, 0]
    styles = {"output": (PALETTE["trajectory"], "output y"), "tube": (PALETTE["tube"], "tube Γ")}
    for j, ax in enumerate(axes):
        allowed = 1.0 - loop.epsilon[j]
        for c, check in enumerate(CHECKS):
            colour, label = styles[check]
            lower, upper = clopper_pearson(counts[c, j], runs, member)
            ax.fill_between(loop.t, lower, upper, color=colour, alpha=0.15, linewidth=0)
            ax.plot(loop.t, counts[c, j] / runs, color=colour, lw=1.2, label=f"{label}: frequency")
            ax.plot(
                loop.t, model[check][:, j], color=colour, lw=0.8, ls=":", label=f"{label}: belief"
            )
        ax.axhline(allowed, color=PALETTE["violation"], ls="--", lw=1.0, label="1 − ε_j")
        ax.set_ylim(0.0, max(1.6 * allowed, 1.1 * float(np.max(counts[:, j])) / runs))
        ax.set_ylabel(f"obstacle {j}\nP(collision)")
        ax.set_title(f"obstacle {j}: ε = {loop.epsilon[j]:.3g}", fontsize=9, loc="left")
    axes[0].legend(fontsize=7, ncols=3, loc="upper right")
    axes[-1].set_xlabel("t (s)")
    figure.suptitle(f"true-obstacle campaign, {runs} runs (bands: simultaneous 99 % CP)")
    return figure


def plot_randomisation(summary: dict[str, Any], records: Sequence[dict[str, Any]]) -> Any:
    """t_c histogram and every run's worst margin per guarantee (red: failed runs)."""
    from matplotlib.figure import Figure

    from stt_drake.plotting import PALETTE

    simulated = [r for r in records if r["status"] == "simulated"]
    figure = Figure(figsize=(10.0, 3.6), layout="constrained")
    left, right = figure.subplots(1, 2, width_ratios=[1, 2])
    reach = [r["t_reach"] for r in simulated if r["t_reach"] is not None]
    left.hist(reach, bins=max(5, int(np.sqrt(len(reach) or 1))), color=PALETTE["tube"])
    left.set_xlabel("t_c (s)")
    left.set_ylabel("runs")
    left.set_title(f"reached: {len(reach)} / {len(simulated)} simulated", fontsize=9)
    names = [n for n in summary["guarantees"] if n != "reach_and_stay"]
    for k, name in enumerate(names):
        margins = np.array([r["invariants"][name]["worst_margin"] for r in simulated])
        colours = [PALETTE["violation"] if _failed(r) else PALETTE["margin"] for r in simulated]
        jitter = np.linspace(-0.25, 0.25, len(margins)) if len(margins) > 1 else [0.0]
        right.scatter(k + np.asarray(jitter), margins, c=colours, s=8)
    right.axhline(0.0, color=PALETTE["reference"], lw=0.8)
    right.set_yscale("symlog", linthresh=1e-3)
    right.set_xticks(range(len(names)), [n.replace("_", "\n") for n in names], fontsize=7)
    right.set_ylabel("worst margin per run")
    figure.suptitle(
        f"randomisation campaign: {summary['runs']} runs, {summary['rejected_draws']} rejected, "
        f"{summary['failed_runs']} failed"
    )
    return figure


def report(summary: dict[str, Any]) -> str:
    """The printed campaign summary (per-obstacle table for true-obstacle campaigns)."""
    lines = [
        f"{summary['kind']} campaign on {summary['scenario']}: {summary['runs']} runs, "
        f"seed {summary['seed']}, {summary['wall_time_s']:.1f} s wall"
    ]
    if summary["kind"] == "true-obstacles":
        loop = summary["closed_loop"]
        lines.append(
            f"  closed loop simulated {loop['simulations']} time(s); true obstacles: "
            f"{summary['true_obstacle_motion']}"
            + (f" (OU, τ = {summary['ou_tau_s']:g} s)" if summary["ou_tau_s"] else "")
        )
        lines.append(
            f"  simultaneous 99 % Clopper-Pearson over {summary['procedure']['family_size']} "
            "(check × obstacle × time) intervals"
        )
        lines.append(
            "  obst  check   ε      1−ε      worst freq  t_worst   CP99 lower  CP99 upper  verdict"
        )
        for o in summary["obstacles"]:
            for check, record in (("output", o), ("tube", o["tube"])):
                more = ""
                if record["runs_to_certify"] is not None:
                    more = f" (≈{record['runs_to_certify']} runs would certify)"
                lines.append(
                    f"  #{o['index']:<3} {check:<7} {o['epsilon']:<6.3g} "
                    f"{record['allowed_collision_probability']:<8.4g} "
                    f"{record['worst_collision_frequency']:<11.5f} {record['t_worst']:<8.2f}  "
                    f"{record['clopper_pearson_lower_99']:<11.5f} "
                    f"{record['clopper_pearson_upper_99']:<11.5f} {record['verdict']}{more}"
                )
    else:
        lines.append(
            f"  simulated {summary['simulated_runs']}, rejected draws {summary['rejected_draws']}, "
            f"errors {summary['error_runs']}, failed {summary['failed_runs']}"
        )
        for name, g in summary["guarantees"].items():
            fraction = g["held_fraction"]
            text = "n/a" if fraction is None else f"{fraction:.3f}"
            worst = (
                f", worst margin {g['worst_margin']:+.3e} (run {g['worst_run']})"
                if "worst_margin" in g
                else ""
            )
            lines.append(f"    {name:<26} held in {text} of runs{worst}")
        t_reach = summary["t_reach"]
        if t_reach["median"] is not None:
            lines.append(
                f"  t_c: median {t_reach['median']:.2f} s, 5-95 % [{t_reach['p05']:.2f}, "
                f"{t_reach['p95']:.2f}] s, max {t_reach['max']:.2f} s"
            )
        for failure in summary["failures"]:
            lines.append(
                f"  failing draw: run {failure['run']} seed {failure['seed']} → {failure['yaml']}"
            )
    lines.append("  result: " + ("HOLDS" if summary["holds"] else "DOES NOT HOLD"))
    return "\n".join(lines)


# --------------------------------------------------------------------------- CLI


def add_parser(commands: Any) -> None:
    """Register `stt-drake campaign`."""
    parser = commands.add_parser(
        "campaign",
        help="Monte Carlo verification of the probabilistic guarantee",
        description="Exit code 0: no obstacle's guarantee is violated (true-obstacle) / every "
        "draw held every guarantee (randomisation); 1 otherwise; 2: bad input.",
    )
    parser.add_argument("scenario", type=Path, help="scenario YAML")
    parser.add_argument("--runs", type=int, required=True, help="number of runs")
    parser.add_argument(
        "--kind",
        choices=KINDS,
        default="true-obstacles",
        help="true-obstacles: sample true obstacle positions against one simulated closed "
        "loop; randomisation: redraw random_obstacles per run and simulate each",
    )
    parser.add_argument("--seed", type=int, default=0, help="campaign seed (default 0)")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=None, help="local processes (default: cores)")
    where.add_argument("--scheduler", default=None, help="Dask scheduler, e.g. tcp://host:8786")
    parser.add_argument("--out", type=Path, default=None, help="output folder")
    parser.add_argument("--resume", action="store_true", help="continue the campaign in --out")
    parser.add_argument(
        "--true-obstacle-motion",
        choices=MOTIONS,
        default="static",
        help="static: ξ drawn once per run; ou: Ornstein-Uhlenbeck ξ(t), same N(0, I) marginal",
    )
    parser.add_argument("--ou-tau", type=float, default=2.0, help="OU time constant τ (s)")
    parser.add_argument("--chunk-size", type=int, default=None, help="runs per task")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--no-figures", action="store_true", help="skip the PNG figure")
    parser.set_defaults(handler=_handle)


def _handle(args: argparse.Namespace) -> int:
    spec = CampaignSpec(
        scenario=str(args.scenario),
        kind=args.kind,
        runs=args.runs,
        seed=args.seed,
        motion=args.true_obstacle_motion,
        tau=args.ou_tau,
    )
    out_dir = args.out
    if out_dir is None:
        out_dir = Path("results") / Path(args.scenario).stem / f"campaign_{args.kind}"
    try:
        outcome = run_campaign(
            spec,
            out_dir,
            workers=args.workers,
            scheduler=args.scheduler,
            resume=args.resume,
            chunk_size=args.chunk_size,
            progress=not args.no_progress,
            figures=not args.no_figures,
        )
    except CampaignError as error:
        print(f"stt-drake campaign: {error}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print(
            f"stt-drake campaign: interrupted; finished runs are in {out_dir / RUNS_FILE}, "
            "continue with --resume",
            file=sys.stderr,
        )
        return EXIT_FAILURE
    print(report(outcome.summary))
    print(f"  wrote {out_dir / SUMMARY_FILE}")
    return EXIT_SUCCESS if outcome.summary["holds"] else EXIT_FAILURE
