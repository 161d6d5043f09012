"""The metrics of one run: :class:`RunMetrics`, the typed record behind ``metrics.json``.

One schema: the fields of :class:`RunMetrics`, in order, then the plant's own keys
(`plant`), are the keys of ``metrics.json`` (:meth:`RunMetrics.as_dict`). The record is
also a read-only mapping of those keys (``metrics["holds"]`` is ``metrics.holds``), so a
reader of metrics.json and a reader of a fresh run read the same names. Times in s,
lengths in m; a margin is in m for ``output_in_tube`` and ``radius_positive`` and a
probability for the others.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, fields
from typing import Any


@dataclass(eq=False)
class RunMetrics(Mapping[str, Any]):
    """What a run measured (:func:`stt_drake.run.simulate`), field by field.

    Attributes:
        scenario: the scenario's name.
        reached: the tube reached the target set and stayed to the end (the final task's,
            for a task sequence; every task completed), and the run ended normally.
        t_tube_in_target: t_c, the tube's final entry into the target set: from then on
            Γ(t) ⊂ T (‖c − η‖ + r ≤ R_T) to the end (s); None if never.
        t_output_in_target: the output's final entry into the target set: from then on
            ‖y − η‖ ≤ R_T to the end (s; :func:`stt_drake.core.crowd_metrics.output_reach_time`,
            the rule `stt-drake compare` uses); None if never. At most `t_tube_in_target`
            while y stays in Γ(t).
        holds: every guarantee held at every step (margins ≥ −`holds_tolerance`).
        sim_time_s: simulated time reached (s; the last good step after an exception).
        wall_time_s: wall-clock time of the simulation (s), kernel loading excluded.
        compile_time_s: time to load or compile the compiled kernels before the clock
            started (s; 0.0 on the numpy path).
        realtime_factor: `sim_time_s` / `wall_time_s`; None when the wall time is 0.
        steps: integrator steps taken.
        holds_tolerance: the slack a margin may go below 0 and still hold.
        stop_reason: why the run ended early or stalled to the end (a sentence naming the
            worst margin so far); None for a run that ended normally.
        strict_stop: the first violation that stopped a strict run; None otherwise.
        first_violation: the first violated guarantee (name, time, margin); None if none.
        invariants: per guarantee name (:data:`stt_drake.core.invariants.INVARIANT_NAMES`):
            `holds`, `worst_margin`, `t_worst` (s), and `note` for an obstacle guarantee of
            a scenario without obstacles (vacuous, margin 1).
        reach: the tube's reach story (:class:`stt_drake.core.invariants.ReachStory`):
            `first_entry_s`, `entries_s`, `exits_s`, `final_entry_s` (s, None if never).
        warnings: the scenario's feasibility warnings (sentences).
        assumptions: broken assumptions (before the run and Assumption 3 after entry,
            :mod:`stt_drake.story`): `assumption`, `obstacle`, `t`, `value`, `required`,
            `claim`, `message`.
        belief_discontinuities: belief jumps the motion model cannot make, or a tracker's
            track changes (:func:`stt_drake.story.belief_discontinuities`): `obstacle`,
            `t`, `kind`, `mean_jump_m`, `sigma_jump_m`, `q_before`, `q_after`.
        recovery: recovery episodes (:class:`stt_drake.core.invariants.RecoveryTracker`):
            `obstacle`, `start_s`, `end_s` (None while still recovering), `worst_margin`.
        stalls: stall episodes (:func:`stt_drake.core.progress.find_stalls`): `start_s`,
            `end_s` (None: to the end), `detected_s`, `position`, `distance_m`, `ended`.
        step_rate: the step-rate watchdog (:class:`stt_drake.systems.monitor.StepRateWatchdog`):
            `limit_steps_per_s` (None: no limit), `window_steps`, `max_window_steps_per_s`.
        obstacles: per obstacle: `index`, `min_distance_to_mean` (m, of y to μ_j),
            `t_min_distance` (s), `sigma` (m, σ_j then), `radius` (r_o_j, m), `epsilon`
            (ε_j), `min_output_avoid_probability`.
        tracks: per tracked obstacle, the tracker's consistency
            (:func:`stt_drake.story.track_consistency`); [] without a monitored tracker.
        plant: the plant's own keys, written after the others (the arm: `segments`,
            `limits`, `jerks`, :func:`stt_drake.core.arm.arm_metrics`); {} for the others.
    """

    scenario: str
    reached: bool
    t_tube_in_target: float | None
    t_output_in_target: float | None
    holds: bool
    sim_time_s: float
    wall_time_s: float
    compile_time_s: float
    realtime_factor: float | None
    steps: int
    holds_tolerance: float
    stop_reason: str | None
    strict_stop: str | None
    first_violation: str | None
    invariants: dict[str, dict[str, Any]]
    reach: dict[str, Any]
    warnings: list[str]
    assumptions: list[dict[str, Any]]
    belief_discontinuities: list[dict[str, Any]]
    recovery: list[dict[str, Any]]
    stalls: list[dict[str, Any]]
    step_rate: dict[str, Any]
    obstacles: list[dict[str, Any]]
    tracks: list[dict[str, Any]]
    plant: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        """The metrics.json document: every field but `plant` in order, then `plant`'s
        keys."""
        document = {name: getattr(self, name) for name in _KEYS}
        return {**document, **self.plant}

    def __getitem__(self, key: str) -> Any:
        if key in _KEYS:
            return getattr(self, key)
        return self.plant[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self.as_dict())

    def __len__(self) -> int:
        return len(self.as_dict())


#: The keys of metrics.json that are fields of :class:`RunMetrics` (all but `plant`), in order.
_KEYS = tuple(f.name for f in fields(RunMetrics) if f.name != "plant")

