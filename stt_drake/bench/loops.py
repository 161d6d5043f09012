"""`stt-drake bench`, the closed-loop rows: real-time factors of packaged scenarios in
Drake's Simulator with the invariant monitor on, continuous against fixed-rate tube in
interleaved pairs, and a cProfile of one loop."""

from __future__ import annotations

import statistics
import time
from importlib.resources import files
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from pydrake.systems.analysis import Simulator

    from stt_drake.config import Scenario
    from stt_drake.core.invariants import InvariantTracker

#: Closed loops (scenario files under diagrams/).
SCENARIOS = ("omni_cluttered_50", "uav_cluttered")
#: The fixed-rate (real-time) tube's update rate the closed loops are also timed at (Hz).
FIXED_RATE_HZ = 100.0
#: The packaged scenarios (``stt_drake.diagrams``, the repository's diagrams/ folder).
DIAGRAMS = Path(str(files("stt_drake.diagrams")))


def closed_loop_scenario(
    name: str, duration: float | None, update_rate_hz: float | None
) -> Scenario | None:
    """diagrams/<name>.yaml loaded, cut to `duration`, with `update_rate_hz` replacing its
    tube update rate (0: continuous; validated like a rate written in the file); None when
    the file does not exist."""
    path = DIAGRAMS / f"{name}.yaml"
    if not path.exists():
        return None
    from stt_drake.assembly import load_scenario

    scenario = load_scenario(path)
    if duration is not None:
        scenario.duration = min(scenario.duration, duration)
    if update_rate_hz is not None:
        from stt_drake.assembly.feasibility import validate_real_time

        scenario.tube.update_rate_hz = update_rate_hz
        validate_real_time(scenario)
    return scenario


def ready_simulator(scenario: Scenario) -> tuple[Simulator, InvariantTracker]:
    """A Simulator of a freshly built Diagram of `scenario`, initialised, with the invariant
    monitor on (every guarantee, every step) folding into the returned tracker."""
    from stt_drake.assembly.diagram import build_diagram
    from stt_drake.core.invariants import InvariantTracker
    from stt_drake.run import make_simulator

    tracker = InvariantTracker()
    simulator = make_simulator(build_diagram(scenario), scenario, tracker)
    simulator.Initialize()
    return simulator, tracker


def time_closed_loop(scenario: Scenario) -> dict[str, Any]:
    """One simulation of `scenario` (:func:`ready_simulator`), timed by wall clock and
    process CPU time."""
    simulator, tracker = ready_simulator(scenario)
    wall, cpu = time.perf_counter(), time.process_time()
    simulator.AdvanceTo(scenario.duration)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    sim_time = simulator.get_context().get_time()
    evaluations = simulator.get_integrator().get_num_derivative_evaluations()
    return {
        "wall_s": wall,
        "cpu_s": cpu,
        "realtime_factor": sim_time / wall,
        "realtime_factor_cpu": sim_time / cpu if cpu > 0.0 else None,
        "steps": simulator.get_num_steps_taken(),
        "derivative_evaluations": evaluations,
        "derivative_evaluations_per_s": evaluations / wall,
        "holds": tracker.holds,
    }


def _closed_loop_summary(scenario: Scenario, runs: list[dict[str, Any]]) -> dict[str, Any]:
    def median(key: str) -> float:
        return statistics.median(run[key] for run in runs)

    return {
        "available": True,
        "sim_time_s": scenario.duration,
        "repeats": len(runs),
        "realtime_factor": median("realtime_factor"),
        "realtime_factor_min": min(run["realtime_factor"] for run in runs),
        "realtime_factor_max": max(run["realtime_factor"] for run in runs),
        "realtime_factor_cpu": median("realtime_factor_cpu"),
        "wall_s": median("wall_s"),
        "steps": runs[0]["steps"],
        "derivative_evaluations": runs[0]["derivative_evaluations"],
        "derivative_evaluations_per_s": median("derivative_evaluations_per_s"),
        "holds": all(run["holds"] for run in runs),
    }


def bench_closed_loop(
    name: str, repeats: int, duration: float | None = None, update_rate_hz: float | None = None
) -> dict[str, Any]:
    """Simulate diagrams/<name>.yaml `repeats` times with the invariant monitor on; real-time
    factors. `update_rate_hz` replaces the scenario's tube update rate (0: continuous).

    Returns ``{"available": False, ...}`` when the scenario file does not exist.
    """
    scenario = closed_loop_scenario(name, duration, update_rate_hz)
    if scenario is None:
        return {"available": False, "reason": f"{name}.yaml not found"}
    return _closed_loop_summary(scenario, [time_closed_loop(scenario) for _ in range(repeats)])


def bench_fixed_rate_against_continuous(
    name: str, repeats: int, duration: float | None = None
) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any]]:
    """The continuous and the fixed-rate (FIXED_RATE_HZ) loop of diagrams/<name>.yaml, run
    in interleaved pairs (continuous first in even pairs, fixed-rate first in odd ones), so
    that the machine's load drifts into both alike: a shared machine's load moves the
    real-time factor of one loop by ±20 % within minutes, as much as the difference.

    Returns:
        (continuous, fixed-rate) :func:`bench_closed_loop`-like summaries, and the ratio
        fixed-rate / continuous of the real-time factor: `median`, `min`, `max` over the
        pairs and `cpu_median` (of the CPU-time factors).
    """
    continuous = closed_loop_scenario(name, duration, 0.0)
    fixed = closed_loop_scenario(name, duration, FIXED_RATE_HZ)
    if continuous is None or fixed is None:
        missing = {"available": False, "reason": f"{name}.yaml not found"}
        return missing, missing, {}
    pairs = []
    for k in range(repeats):
        if k % 2 == 0:
            first = time_closed_loop(continuous)
            pairs.append((first, time_closed_loop(fixed)))
        else:
            first = time_closed_loop(fixed)
            pairs.append((time_closed_loop(continuous), first))
    ratios = [f["realtime_factor"] / c["realtime_factor"] for c, f in pairs]
    cpu_ratios = [f["realtime_factor_cpu"] / c["realtime_factor_cpu"] for c, f in pairs]
    ratio = {
        "median": statistics.median(ratios),
        "min": min(ratios),
        "max": max(ratios),
        "cpu_median": statistics.median(cpu_ratios),
    }
    return (
        _closed_loop_summary(continuous, [c for c, _ in pairs]),
        _closed_loop_summary(fixed, [f for _, f in pairs]),
        ratio,
    )


def profile_closed_loop(name: str, duration: float = 10.0, top: int = 25) -> dict[str, Any]:
    """cProfile of `duration` simulated seconds of diagrams/<name>.yaml (monitor on): the
    `top` functions by own time. cProfile slows Python calls down, so read the shares, not
    the absolute times."""
    import cProfile
    import pstats

    path = DIAGRAMS / f"{name}.yaml"
    if not path.exists():
        return {"available": False, "reason": f"{path.name} not found"}
    from stt_drake.assembly import load_scenario
    from stt_drake.assembly.diagram import build_diagram
    from stt_drake.core.invariants import InvariantTracker
    from stt_drake.run import make_simulator

    scenario = load_scenario(path)
    built = build_diagram(scenario)
    simulator = make_simulator(built, scenario, InvariantTracker())
    simulator.Initialize()
    simulator.AdvanceTo(min(0.1, duration))  # warm-up: kernels loaded, caches allocated
    profiler = cProfile.Profile()
    profiler.enable()
    simulator.AdvanceTo(duration)
    profiler.disable()
    stats = pstats.Stats(profiler)
    total = sum(entry[2] for entry in stats.stats.values())  # type: ignore[attr-defined]
    rows = []
    for (filename, line, function), entry in stats.stats.items():  # type: ignore[attr-defined]
        calls, tottime, cumtime = entry[1], entry[2], entry[3]
        where = f"{Path(filename).name}:{line}" if line else filename
        rows.append(
            {
                "function": f"{function} ({where})",
                "calls": calls,
                "own_share": tottime / total if total else 0.0,
                "own_s": tottime,
                "cumulative_s": cumtime,
            }
        )
    rows.sort(key=lambda row: -row["own_s"])
    return {
        "available": True,
        "scenario": name,
        "sim_time_s": duration,
        "total_s": total,
        "top": rows[:top],
    }


def fixed_rate_name(name: str) -> str:
    """The closed-loop key of scenario `name` run with the fixed-rate tube."""
    return f"{name}_fixed_rate_{FIXED_RATE_HZ:g}hz"
