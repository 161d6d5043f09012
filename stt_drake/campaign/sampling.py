"""Seeds and true-obstacle sampling of the Monte Carlo campaigns.

Run i's seed is :func:`run_seed` (campaign seed, i). A true-obstacle run draws the
standardised offsets ξ (:func:`sample_xi`) and samples the true obstacles
O_j(t) = μ_j(t) + σ_j(t)·ξ_j (μ_j(t) + L_j(t)·ξ_j, Σ_j = L_j L_jᵀ, with full covariances)
against one logged :class:`ClosedLoop` (:func:`sample_true_obstacles`).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from stt_drake.runlog import RunLog, write_json

MOTIONS = ("static", "ou")
#: The two collision checks of a true-obstacle campaign.
CHECKS = ("output", "tube")
#: Where a true-obstacle campaign keeps the closed loop it samples against.
CLOSED_LOOP_FILE = "closed_loop.npz"


def run_seed(campaign_seed: int, index: int) -> int:
    """Seed of run `index`: ``SeedSequence(campaign_seed, spawn_key=(index,))``'s first word.

    Equal to ``SeedSequence(campaign_seed).spawn(index + 1)[index].generate_state(1)[0]``,
    a 32-bit integer; independent of how runs are chunked or scheduled.
    """
    sequence = np.random.SeedSequence(campaign_seed, spawn_key=(index,))
    return int(sequence.generate_state(1)[0])


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
    covariance: np.ndarray | None = None  # (T, m, n, n) full Σ_j(t) (m²), None: σ_j² I
    # (T, m) whether obstacle j exists at t (a recorded track's span, a tracker's track);
    # an absent obstacle never collides. None: every obstacle at every time.
    active: np.ndarray | None = None

    @property
    def count(self) -> int:
        """Number of obstacles m."""
        return self.sigma.shape[1]

    @classmethod
    def from_log(cls, log: Mapping[str, Any], epsilon: Sequence[float] | None = None) -> ClosedLoop:
        """The closed loop of a run log (a :func:`stt_drake.run.simulate` log, a
        ``log.npz``: see :mod:`stt_drake.runlog`); `epsilon` defaults to the logged ε at
        the first sample."""
        run = RunLog.of(log)
        checked = run.epsilon[0] if epsilon is None else epsilon
        return cls(
            t=run.t,
            output=run.output,
            center=run.center,
            radius=run.radius,
            mean=run.mean.copy(),
            sigma=run.sigma.copy(),
            obstacle_radius=run.obstacle_radius.copy(),
            epsilon=np.asarray(checked, dtype=float).reshape(run.count).copy(),
            covariance=None if run.covariance is None else run.covariance.copy(),
            active=None if bool(np.all(run.active)) else run.active.copy(),
        )

    def save(self, path: Path) -> None:
        """Write every field to an ``.npz`` file (an isotropic loop has no covariance)."""
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        np.savez_compressed(path, **{k: v for k, v in values.items() if v is not None})

    @classmethod
    def load(cls, path: Path) -> ClosedLoop:
        """Read a closed loop written by :meth:`save`."""
        with np.load(path) as data:
            return cls(**{f.name: data[f.name] for f in fields(cls) if f.name in data.files})

    def collision_probability(self) -> dict[str, np.ndarray]:
        """The belief's own collision probabilities (T, m) per check (noncentral χ², or
        the generalized chi-square of :mod:`stt_drake.core.anisotropic` with full Σ_j)."""
        from stt_drake.core.probability import avoid_probability

        if self.covariance is not None:
            return self._absent_never_collide(self._anisotropic_collision_probability())
        output = avoid_probability(
            self.output[:, None, :], self.mean, self.sigma, self.obstacle_radius
        )
        tube = avoid_probability(
            self.center[:, None, :],
            self.mean,
            self.sigma,
            self.obstacle_radius + np.maximum(self.radius, 0.0)[:, None],
        )
        return self._absent_never_collide({"output": 1.0 - output, "tube": 1.0 - tube})

    def _absent_never_collide(self, probability: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        if self.active is None:
            return probability
        return {check: np.where(self.active, p, 0.0) for check, p in probability.items()}

    def _anisotropic_collision_probability(self) -> dict[str, np.ndarray]:
        from stt_drake.core import anisotropic

        steps, count = self.sigma.shape
        output, tube = np.empty((steps, count)), np.empty((steps, count))
        for k in range(steps):
            for j in range(count):
                mean, covariance = self.mean[k, j], self.covariance[k, j]
                r_o = float(self.obstacle_radius[k, j])
                output[k, j] = anisotropic.collision_probability(
                    self.output[k], mean, covariance, r_o
                )
                tube[k, j] = anisotropic.collision_probability(
                    self.center[k], mean, covariance, r_o + max(float(self.radius[k]), 0.0)
                )
        return {"output": output, "tube": tube}


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
    (output) or ‖c − O_j‖ < r_o_j + r (tube), with O_j = μ_j + σ_j·ξ_j, or
    O_j = μ_j + L_j·ξ_j with L_j the Cholesky factor of a full Σ_j = L_j L_jᵀ (so
    O_j ~ N(μ_j, Σ_j)).
    """
    seeds = [seed for _, seed in runs]
    xi = sample_xi(seeds, loop.t, loop.mean.shape[1:], motion, tau)
    if loop.covariance is None:
        scaled = loop.sigma[None, :, :, None] * xi  # σ_j ξ_j: (R, T, m, n)
    else:
        factor = np.linalg.cholesky(loop.covariance)  # (T, m, n, n)
        scaled = np.einsum("tjab,rtjb->rtja", factor, xi)
    reach = {
        "output": (loop.output, loop.obstacle_radius),
        "tube": (loop.center, loop.obstacle_radius + np.maximum(loop.radius, 0.0)[:, None]),
    }
    ranges = {}
    for check, (point, limit) in reach.items():
        gap = (point[:, None, :] - loop.mean)[None] - scaled  # point − O_j: (R, T, m, n)
        hit = np.einsum("rtjk,rtjk->rjt", gap, gap) < (limit**2).T[None]
        if loop.active is not None:  # an absent obstacle is nowhere
            hit &= loop.active.T[None]
        ranges[check] = hit_intervals(hit)
    return [
        {"run": index, "seed": seed, **{check: ranges[check][r] for check in CHECKS}}
        for r, (index, seed) in enumerate(runs)
    ]


def is_true_obstacle_record(record: dict[str, Any], count: int, steps: int) -> bool:
    """Whether a record read back from ``runs.jsonl`` has the shape
    :func:`sample_true_obstacles` gives a closed loop of `count` obstacles and `steps`
    logged times: per check, `count` lists of [start, stop) with 0 ≤ start < stop ≤ steps."""
    for check in CHECKS:
        per_obstacle = record.get(check)
        if not (isinstance(per_obstacle, list) and len(per_obstacle) == count):
            return False
        for ranges in per_obstacle:
            if not isinstance(ranges, list):
                return False
            for pair in ranges:
                if not (
                    isinstance(pair, list)
                    and len(pair) == 2
                    and all(type(k) is int for k in pair)
                    and 0 <= pair[0] < pair[1] <= steps
                ):
                    return False
    return True


def output_collided(record: dict[str, Any]) -> bool:
    """Whether a true-obstacle run's output hit any obstacle."""
    return any(record["output"])


def closed_loop_of(
    scenario: Any, out_dir: Path, given: ClosedLoop | None, resume: bool
) -> tuple[ClosedLoop, dict[str, Any]]:
    """The closed loop a true-obstacle campaign samples against, kept in `out_dir` as
    :data:`CLOSED_LOOP_FILE` with its summary (``closed_loop.json``): the scenario simulated
    once, or the `given` closed loop, or (resuming) the saved one — so a resumed campaign
    samples against exactly the trajectory it started with. Returns (the closed loop, the
    summary campaign.json keeps as ``closed_loop``)."""
    path = out_dir / CLOSED_LOOP_FILE
    summary_path = out_dir / "closed_loop.json"
    if resume and given is None and path.exists() and summary_path.exists():
        try:
            saved = json.loads(summary_path.read_text())
            # a folder written by an older version names the tube's reach time t_reach
            renamed = {"t_reach": "t_tube_in_target"}
            return ClosedLoop.load(path), {renamed.get(k, k): v for k, v in saved.items()}
        except (OSError, ValueError, KeyError, AttributeError) as error:  # re-simulated below
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
            "holds": result.metrics.holds,
            "reached": result.metrics.reached,
            "t_tube_in_target": result.metrics.t_tube_in_target,
            "wall_time_s": result.metrics.wall_time_s,
        }
    else:
        summary = {"simulations": 0, "given": True}
    given.save(path)
    write_json(summary_path, summary)
    return given, summary
