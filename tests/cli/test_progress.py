"""`stt-drake run`'s progress lines: printed on a terminal only, not with --quiet, and
saying the simulated time, the real-time factor and the worst margin so far."""

from __future__ import annotations

import dataclasses
import io
import re

from stt_drake.assembly import load_scenario
from stt_drake.cli import progress as progress_module
from stt_drake.cli.progress import RunProgress, wants_progress
from stt_drake.run import simulate
from tests.conftest import DIAGRAMS


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_only_on_a_terminal_and_not_quiet():
    assert wants_progress(quiet=False, stream=Terminal())
    assert not wants_progress(quiet=True, stream=Terminal())
    assert not wants_progress(quiet=False, stream=io.StringIO())  # a pipe or a file


def test_a_run_prints_time_rate_and_worst_margin(monkeypatch):
    monkeypatch.setattr(progress_module, "PERIOD_S", 0.0)  # a line after every step
    scenario = dataclasses.replace(
        load_scenario(DIAGRAMS / "omni_hardware_case1.yaml"), duration=0.5
    )
    stream = Terminal()
    result = simulate(scenario, progress=RunProgress(scenario.duration, stream))
    lines = stream.getvalue().splitlines()
    assert len(lines) > 10
    pattern = r"  t = (\d+\.\d\d) / 0\.5 s  \((\d+\.\d)× real time\)  worst margin (\w+) ([+-]\S+)"
    parsed = [re.fullmatch(pattern, line) for line in lines]
    assert all(parsed), lines[:3]
    times = [float(match.group(1)) for match in parsed]
    assert times == sorted(times) and times[-1] >= 0.49
    worst = min(result.metrics.invariants.items(), key=lambda item: item[1]["worst_margin"])
    assert parsed[-1].group(3) == worst[0]
    assert float(parsed[-1].group(4)) == float(f"{worst[1]['worst_margin']:+.3g}")
