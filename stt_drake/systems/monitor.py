"""InvariantMonitor: evaluates every guarantee during a run, and the Simulator hook (which
also runs the step-rate watchdog)."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import (
    BasicVector,
    Context,
    EventStatus,
    LeafSystem,
    ValueProducer,
)

from stt_drake.core.belief import ObstacleBelief, ObstacleTask, PortBelief, belief_size
from stt_drake.core.invariants import (
    INVARIANT_NAMES,
    InvariantTracker,
    RecoveryTracker,
    center_avoid_probability,
    evaluate_tube_invariants,
    port_invariants,
)

#: Default step-rate limit L (integrator steps per simulated second) of the watchdog, used
#: when a scenario's ``max_steps_per_second`` is 0. Chosen so that no scenario here runs
#: slower than 0.05× real time: L × (worst wall cost of one step) ≤ 20 s of wall time per
#: simulated second. Measured with drake 1.51.1 on a shared 2-core machine (load ≈ 2), as
#: wall time per step over 500-step windows: the arm is the most expensive plant, worst
#: window 3.1 ms/step in franka_disturbance (2.8 ms in franka_pick_place_case1, mean 2.4),
#: omni_cluttered_50 0.8 ms/step; a stalling integrator costs more per step (rejected trial
#: steps): 4.7 ms/step for the arm, 1.0 ms for the omni base (chattering plant inputs).
#: 20 s / 4.7 ms ≈ 4250, rounded down to 4000. In normal operation no scenario in
#: diagrams/ exceeds 500 steps per simulated second in any window (worst: uav_paper, 494
#: in its second window; all others 167-246), so the limit leaves a factor of 8.
DEFAULT_MAX_STEPS_PER_SECOND = 4000.0

#: The watchdog judges the step rate over windows of at least this many steps...
WATCHDOG_WINDOW_STEPS = 500
#: ...and of at least this much simulated time (s): a short burst of small steps (an
#: obstacle grazing the tube, a recovery) is normal, only a sustained rate is a stall.
#: Found by the 3D corpus: a 3.6 m/s crosser made uav runs take 500 steps in 0.07 s
#: (7.6e3 steps/s) and then go on normally at ~300 steps/s.
WATCHDOG_WINDOW_SECONDS = 1.0


def step_rate_limit(max_steps_per_second: float) -> float:
    """The watchdog limit for a scenario's validated ``max_steps_per_second`` (0: the
    default)."""
    return float(max_steps_per_second) or DEFAULT_MAX_STEPS_PER_SECOND


class StepRateWatchdog:
    """Ends a run whose integrator stalls: too many steps per simulated second.

    :meth:`step` is called after every Simulator step (and once at initialisation). Steps
    are counted in a window; once it holds ≥ `window_steps` steps, the run is stopped as
    soon as the count exceeds `limit`·max(elapsed, `window_seconds`), elapsed the simulated
    time the window spans (so steps of 1e-13 s trip it after limit·window_seconds steps, a
    zero `window_seconds` after `window_steps`). A window that spans ≥ `window_seconds` and
    ≥ `window_steps` closes (its rate is recorded) and the next one opens. Pure Python: the
    Drake side is :meth:`InvariantMonitor.attach`.

    Attributes:
        limit: the largest admissible sustained rate, steps per simulated second.
        window_steps: the number of steps a window needs before it is judged.
        window_seconds: the simulated time a window spans at least.
        last_time: the simulated time of the last completed step (None before the first).
        max_rate: the highest rate of any closed window so far (0 before the first).
        message: why the watchdog tripped, None while it has not.
    """

    def __init__(
        self,
        limit: float,
        window_steps: int = WATCHDOG_WINDOW_STEPS,
        window_seconds: float = WATCHDOG_WINDOW_SECONDS,
    ) -> None:
        if not limit > 0.0 or window_steps < 1 or not window_seconds >= 0.0:
            raise ValueError(
                f"StepRateWatchdog: need limit > 0, window_steps ≥ 1 and window_seconds ≥ 0 "
                f"(got {limit}, {window_steps}, {window_seconds})"
            )
        self.limit = float(limit)
        self.window_steps = int(window_steps)
        self.window_seconds = float(window_seconds)
        self.last_time: float | None = None
        self.max_rate = 0.0
        self.message: str | None = None
        self._window_start = 0.0
        self._window_count = 0

    def step(self, t: float) -> str | None:
        """Count a step that ended at simulated time t; return the stop message if the
        window's count is too high for the limit."""
        t = float(t)
        if self.last_time is None:  # the initialisation call: the first window opens here
            self.last_time = self._window_start = t
            return None
        self.last_time = t
        self._window_count += 1
        if self._window_count < self.window_steps:
            return None
        elapsed = t - self._window_start
        rate = self._window_count / elapsed if elapsed > 0.0 else math.inf
        if self._window_count > self.limit * max(elapsed, self.window_seconds):
            self.max_rate = max(self.max_rate, rate)
            self.message = (
                f"step-rate watchdog: the integrator took {self._window_count} steps in "
                f"{elapsed:.3g} s of simulated time ({rate:.4g} steps/s > limit "
                f"{self.limit:g}) at t = {t:.6g} s"
            )
            return self.message
        if elapsed >= self.window_seconds:
            self.max_rate = max(self.max_rate, rate)
            self._window_start, self._window_count = t, 0
        return None


class InvariantMonitor(LeafSystem):
    """Inputs `tube`, `obstacle_belief`, `output` (y) and `recovery` (m, the tube's flags);
    outputs `margins` (one per name in :data:`stt_drake.core.invariants.INVARIANT_NAMES`),
    `output_avoid_probability` (m) and `tube_avoid_probability` (m). Recomputes every
    probability itself rather than trusting the tube's diagnostics, so a bug in the tube
    cannot hide from it.

    `task` holds each slot's r_o, ε, p_d. The belief input is read as the tube reads its
    own (:meth:`ObstacleBelief.from_port`). The margins use the active
    slots only (an inactive slot's probabilities read 1); with `full_covariance` they use
    each Σ_j exactly, else σ_j² = λ_max(Σ_j) (exact for Σ_j = σ_j² I)."""

    def __init__(
        self, dimension: int, task: ObstacleTask, r_min: float, full_covariance: bool = False
    ) -> None:
        super().__init__()
        self._dimension = dimension
        self._r_min = r_min
        self._task = task
        self._task_table = task.table()
        self._full_covariance = full_covariance
        count = task.count
        self._tube_port = self.DeclareVectorInputPort("tube", dimension + 1)
        self._belief_port = self.DeclareVectorInputPort(
            "obstacle_belief", belief_size(count, dimension)
        )
        self._output_port = self.DeclareVectorInputPort("output", dimension)
        self._recovery_port = self.DeclareVectorInputPort("recovery", count)
        self._sample = self.DeclareCacheEntry(
            description="invariant margins",
            value_producer=ValueProducer(
                allocate=AbstractValue.Make(object()).Clone, calc=self._calc_sample
            ),
            prerequisites_of_calc={self.all_input_ports_ticket()},
        )
        depends = {self._sample.ticket()}
        self.margins_port = self.DeclareVectorOutputPort(
            "margins",
            len(INVARIANT_NAMES),
            lambda context, output: output.SetFromVector(self._sample.Eval(context).margins),
            prerequisites_of_calc=depends,
        )
        self.DeclareVectorOutputPort(
            "output_avoid_probability",
            count,
            self._calc_output_avoid,
            prerequisites_of_calc=depends,
        )
        self.DeclareVectorOutputPort(
            "tube_avoid_probability",
            count,
            self._calc_tube_avoid,
            prerequisites_of_calc=depends,
        )

    def belief(self, context: Context) -> PortBelief:
        """The `obstacle_belief` input with the task numbers, as the margins read it (made
        at each call: no cache entry of its own, one Python callback less per step)."""
        return ObstacleBelief.from_port(
            self._belief_port.Eval(context), self._dimension, self._task, self._full_covariance
        )

    def _calc_sample(self, context: Context, value: AbstractValue) -> None:
        output = self._output_port.Eval(context)
        tube = self._tube_port.Eval(context)
        vector = self._belief_port.Eval(context)
        # The port vector straight to the kernel: no belief made at each step (the port's
        # size is fixed, so its checks cannot fail here).
        sample = port_invariants(
            output, tube, vector, self._task_table, self._full_covariance, self._r_min
        )
        if sample is None:  # numpy path, or a Σ_j that breaks a rule (named there)
            belief = ObstacleBelief.from_port(
                vector, self._dimension, self._task, self._full_covariance
            )
            sample = evaluate_tube_invariants(output, tube, belief, self._r_min)
        value.set_value(sample)

    def _calc_output_avoid(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(self._sample.Eval(context).output_avoid_probability)

    def _calc_tube_avoid(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(self._sample.Eval(context).tube_avoid_probability)

    def center_margins(self, context: Context) -> np.ndarray:
        """q_j(c) − ε_j per slot at the tube centre (buffered radius r_o_j + r_min); an
        inactive slot reads 1 − ε_j (no obstacle there)."""
        tube = self._tube_port.Eval(context)
        q = center_avoid_probability(tube[:-1], self.belief(context), self._r_min)
        return q - self._task.epsilon

    def attach(
        self,
        simulator: Simulator,
        tracker: InvariantTracker,
        strict: bool = False,
        watchdog: StepRateWatchdog | None = None,
        recoveries: RecoveryTracker | None = None,
        progress: Callable[[float, InvariantTracker], None] | None = None,
        *,
        also: Callable[[Context], EventStatus] | None = None,
    ) -> Callable[[Context], EventStatus]:
        """Install a Simulator monitor that folds every step's margins into `tracker`, the
        tube's recovery flags into `recoveries` (with the centre margins, computed only
        while some flag is set or an episode is open) and counts the step in `watchdog`.

        Drake's Simulator has one monitor slot: `also`, a monitor of one's own, runs at
        every step as well (:func:`combine_monitors`, the most severe status wins: its
        ``EventStatus.ReachedTermination`` ends the run, its ``Failed`` fails it). A
        monitor already installed is not kept unless passed as `also`.

        In strict mode the first violation stops the run: ``AdvanceTo`` raises a
        RuntimeError whose message names the invariant, the time and the margin. A tripped
        watchdog ends the run early: ``AdvanceTo`` returns a status whose reason is
        ``kReachedTerminationCondition``, with `watchdog.message`. `progress`, if given,
        is called after every step with the time and the tracker (a command's progress
        lines).
        """

        nothing = EventStatus.DidNothing()  # made once: returned at almost every step

        def monitor(root_context: Context) -> EventStatus:
            context = self.GetMyContextFromRoot(root_context)
            t = context.get_time()
            # The cache entry, not the `margins` port: no Python callback copying them out.
            message = tracker.update(t, self._sample.Eval(context).margins)
            if progress is not None:
                progress(t, tracker)
            if recoveries is not None:
                flags = self._recovery_port.Eval(context) > 0.5
                # count_nonzero: a third of any()'s cost, whatever the number of slots
                if recoveries.active or np.count_nonzero(flags):
                    recoveries.update(t, flags, self.center_margins(context))
            if strict and message is not None:
                # Failed(None, ...): passing a Python LeafSystem here segfaults (pydrake 1.51).
                return EventStatus.Failed(None, message)
            if watchdog is not None:
                stop = watchdog.step(t)
                if stop is not None:  # None as the system: see above
                    return EventStatus.ReachedTermination(None, stop)
            return nothing

        installed = monitor if also is None else combine_monitors(monitor, also)
        simulator.set_monitor(installed)
        return installed


def combine_monitors(
    *monitors: Callable[[Context], EventStatus],
) -> Callable[[Context], EventStatus]:
    """One Simulator monitor that calls every one of `monitors` at every step, in order,
    and returns the most severe of their statuses (Drake's order: DidNothing < Succeeded <
    ReachedTermination < Failed; the first of equal severity), so each one's termination
    or failure still ends the run with its message. Drake's Simulator holds one monitor
    (``Simulator.set_monitor``): this is how the invariant monitor and one's own share it.
    A monitor returning None counts as DidNothing."""
    if not monitors:
        raise ValueError("combine_monitors: give at least one monitor")

    def combined(root_context: Context) -> EventStatus:
        worst = EventStatus.DidNothing()
        for monitor in monitors:
            status = monitor(root_context)
            if status is not None and status.severity().value > worst.severity().value:
                worst = status
        return worst

    return combined
