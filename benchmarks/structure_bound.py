"""The structure bound of a closed loop: how fast a scenario's Diagram runs when its
arithmetic costs nothing.

A scenario is simulated as ``stt-drake bench`` simulates its closed loops (the monitor
checking every guarantee at every step, the loggers on), then again with each compiled
computation on the hot path replaced by a stand-in that returns a result the real one
made: the belief source's and the tracker's port vector, the tube law's evaluation, the
fixed-rate tube's update, the controller's control (the arm's law and its Jacobian) and the
monitor's margins (:data:`STAND_INS`). What the stand-in run costs per derivative evaluation is the
Diagram's structure: Drake's framework, the calls into Python and back, the ports and
cache entries, and the Python around each computation. No speed-up of the arithmetic can
take a loop below it. The stand-in run's dynamics differ (its tube and control are
constant), so the bound is also given at the real run's number of derivative evaluations.

The stand-ins return the last result each computation made in a real run of the first
`capture` seconds, and count their calls: a computation the scenario does not call reads 0.
What has no stand-in stays real: the plants, a crowd simulator, the guide, the sensor.

Usage: ``python benchmarks/structure_bound.py [SCENARIO ...] [--rate HZ] [--repeats N]``
(default: the closed loops of ``stt-drake bench``; each scenario's own tube rate unless
``--rate`` is given).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

#: (module, owner, attribute) of each replaced computation: `owner` is a class of
#: `module`, or None for a function the module imported by name (its caller reads it there).
STAND_INS = (
    ("stt_drake.systems.belief_source", "ObstacleBeliefSource", "belief_vector"),
    ("stt_drake.systems.perception", "ObstacleTracker", "belief_vector"),
    ("stt_drake.core.tube", "TubeLaw", "evaluate_port"),
    ("stt_drake.systems.tube", None, "advance_port"),
    ("stt_drake.core.control", "FunnelController", "control_from_tube"),
    ("stt_drake.systems.monitor", None, "port_invariants"),
    ("stt_drake.core.arm", "ArmFunnelLaw", "evaluate"),
    ("stt_drake.systems.plants.franka", "ArmKinematics", "jacobian"),
)


def _targets() -> list[tuple[str, object, str]]:
    """(label, object holding the attribute, attribute) per entry of :data:`STAND_INS`."""
    import importlib

    targets = []
    for module_name, owner, attribute in STAND_INS:
        module = importlib.import_module(module_name)
        holder = module if owner is None else getattr(module, owner)
        label = f"{owner or module_name.rsplit('.', 1)[-1]}.{attribute}"
        targets.append((label, holder, attribute))
    return targets


@contextmanager
def _replaced(make: Callable[[str, Callable[..., Any]], Callable[..., Any]]) -> Iterator[None]:
    """Each target's attribute replaced by ``make(label, original)`` while inside, restored
    after."""
    saved = []
    try:
        for label, holder, attribute in _targets():
            original = getattr(holder, attribute)
            saved.append((holder, attribute, original))
            setattr(holder, attribute, make(label, original))
        yield
    finally:
        for holder, attribute, original in reversed(saved):
            setattr(holder, attribute, original)


def captured_results(scenario: Any, capture: float) -> dict[str, Any]:
    """The last result of each replaced computation in a real run of `scenario`'s first
    `capture` simulated seconds (a computation it never calls is absent)."""
    from stt_drake.bench.loops import ready_simulator

    last: dict[str, Any] = {}

    def recorder(label: str, original: Callable[..., Any]) -> Callable[..., Any]:
        def record(*args: Any, **kwargs: Any) -> Any:
            last[label] = original(*args, **kwargs)
            return last[label]

        return record

    with _replaced(recorder):
        simulator, _ = ready_simulator(scenario)
        simulator.AdvanceTo(min(capture, scenario.duration))
    return last


@contextmanager
def stand_ins(results: dict[str, Any], calls: dict[str, int]) -> Iterator[None]:
    """Every computation in `results` replaced by one returning its result there, counted
    in `calls`; the others stay real."""

    def stand_in(label: str, original: Callable[..., Any]) -> Callable[..., Any]:
        if label not in results:
            return original
        result = results[label]

        def constant(*args: Any, **kwargs: Any) -> Any:
            calls[label] += 1
            return result

        return constant

    with _replaced(stand_in):
        yield


def structure_bound(scenario: Any, repeats: int = 3, capture: float = 2.0) -> dict[str, Any]:
    """The real loop and the stand-in loop of `scenario`, timed in turn `repeats` times
    each (best of each): wall µs per derivative evaluation, the real-time factors, and the
    stand-in loop's cost at the real loop's evaluation count (its structure bound). Each
    run is :func:`stt_drake.bench.loops.time_closed_loop`, as `stt-drake bench` times it."""
    from stt_drake.bench.loops import time_closed_loop

    results = captured_results(scenario, capture)
    calls = {label: 0 for label, _, _ in _targets()}
    real, hollow = [], []
    for _ in range(repeats):
        real.append(time_closed_loop(scenario))
        with stand_ins(results, calls):
            hollow.append(time_closed_loop(scenario))

    def per_evaluation(run: dict[str, Any]) -> float:
        return 1e6 * run["wall_s"] / run["derivative_evaluations"]

    best_real, best_hollow = min(real, key=per_evaluation), min(hollow, key=per_evaluation)
    bound_wall = per_evaluation(best_hollow) * 1e-6 * best_real["derivative_evaluations"]
    return {
        "real_us_per_evaluation": per_evaluation(best_real),
        "real_realtime_factor": scenario.duration / best_real["wall_s"],
        "real_evaluations": best_real["derivative_evaluations"],
        "structure_us_per_evaluation": per_evaluation(best_hollow),
        "structure_evaluations": best_hollow["derivative_evaluations"],
        "structure_realtime_factor": scenario.duration / bound_wall,
        "stand_in_calls": {label: count // repeats for label, count in calls.items()},
    }


def main(argv: list[str] | None = None) -> int:
    from stt_drake.bench.loops import SCENARIOS, closed_loop_scenario
    from stt_drake.core.backend import warm_up

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scenarios", nargs="*", default=list(SCENARIOS))
    parser.add_argument(
        "--rate",
        type=float,
        default=None,
        help="tube update rate, Hz (0: continuous; default: the scenario's own)",
    )
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--duration", type=float, default=None, help="cut each run (s)")
    args = parser.parse_args(argv)
    for name in args.scenarios:
        scenario = closed_loop_scenario(name, args.duration, args.rate)
        if scenario is None:
            print(f"structure_bound: no packaged scenario named {name!r}", file=sys.stderr)
            return 2
        warm_up(len(scenario.start))
        started = time.perf_counter()
        bound = structure_bound(scenario, args.repeats)
        rate = (
            f"{scenario.tube.update_rate_hz:g} Hz" if scenario.tube.update_rate_hz else "continuous"
        )
        print(
            f"{name} ({rate}): real {bound['real_us_per_evaluation']:.1f} µs per derivative "
            f"evaluation ({bound['real_realtime_factor']:.1f}× real time); structure "
            f"{bound['structure_us_per_evaluation']:.1f} µs, so at most "
            f"{bound['structure_realtime_factor']:.1f}× at the real loop's "
            f"{bound['real_evaluations']} evaluations  [{time.perf_counter() - started:.0f} s]"
        )
        used = ", ".join(f"{label} {count}" for label, count in bound["stand_in_calls"].items())
        print(f"  stand-in calls per run: {used}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
