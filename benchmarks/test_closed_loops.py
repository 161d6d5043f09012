"""The benchmark history's closed-loop rows: a packaged scenario's Diagram simulated for
:data:`DURATION` seconds with the invariant monitor on (every guarantee checked at every
step), loaded and built as `stt-drake bench` does (:mod:`stt_drake.bench.loops`). One
round is one whole simulation from a fresh Diagram (built outside the timing), five rounds
per row. A row's time divided into its simulated seconds is the inverse of
the real-time factor `stt-drake run` prints."""

from __future__ import annotations

import pytest

from stt_drake.bench.loops import closed_loop_scenario, ready_simulator

#: Simulated seconds per round (the scenarios are cut there).
DURATION = 5.0
#: (packaged scenario, tube update rate in Hz: None keeps the file's, 0 is continuous).
LOOPS = [
    ("omni_cluttered_50", 0.0),
    ("omni_cluttered_50", 100.0),
    ("uav_cluttered", 0.0),
    ("uav_cluttered", 100.0),
    ("omni_hardware_case1", None),
    ("omni_tracked", None),
    ("liveness_clutter_2d", None),
    ("franka_pick_place_case1", None),
]


@pytest.mark.parametrize(
    ("name", "rate_hz"), LOOPS, ids=[f"{n}-{'file' if r is None else f'{r:g}hz'}" for n, r in LOOPS]
)
def test_closed_loop(benchmark, name, rate_hz):
    scenario = closed_loop_scenario(name, DURATION, rate_hz)
    trackers = []

    def fresh_simulator() -> tuple[tuple, dict]:
        simulator, tracker = ready_simulator(scenario)
        trackers.append(tracker)
        return (simulator,), {}

    benchmark.pedantic(
        lambda simulator: simulator.AdvanceTo(scenario.duration),
        setup=fresh_simulator,
        rounds=5,
        iterations=1,
    )
    assert all(tracker.holds for tracker in trackers)
