"""The adversarial 2D corpus (issue 10: the real-time path must keep the guarantees).

Every ``tests/scenarios/omni_*.yaml`` states its required outcome in one ``# expect:`` line
(syntax and the shared checks: ``tests/adversarial.py``). Each file is loaded, simulated once
and checked against it; the guarantees are recomputed from the raw log with scipy, and the
admissible period of a refused file is recomputed from the file's own numbers. Bounded time
is checked as integrator steps per simulated second, never as wall time.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from stt_drake.assembly import load_scenario
from stt_drake.run import RunResult, simulate
from tests import adversarial

CORPUS = adversarial.corpus("omni_")

#: The update rates (Hz) the issue asks the holding files to cover; 0 = continuous time.
RATES_TO_COVER = (10.0, 20.0, 50.0, 100.0, 0.0)

OUTCOMES = ("holds", "refused", "recovers", "warns", "stops", "stalls")


def test_corpus_covers_the_issue():
    assert len(CORPUS) >= 15, [p.name for p in CORPUS]
    expectations = {path: adversarial.expectation(path) for path in CORPUS}
    kinds = {e.outcome for e in expectations.values()}
    assert kinds == set(OUTCOMES), f"missing outcomes: {set(OUTCOMES) - kinds}"
    data = {path: adversarial.scenario_data(path) for path in CORPUS}
    holding_rates = {
        adversarial.update_rate(data[p]) for p, e in expectations.items() if e.outcome == "holds"
    }
    missing = [rate for rate in RATES_TO_COVER if rate not in holding_rates]
    assert not missing, f"no holding file at update_rate_hz {missing}"
    for path, expected in expectations.items():
        assert data[path].get("name") == path.stem, f"{path.name}: name must be the file stem"
        if expected.outcome in ("refused", "warns", "stops", "stalls"):
            assert expected.detail, f"{path.name}: '{expected.outcome}' needs its text"


def run(path: Path) -> RunResult:
    return simulate(load_scenario(path))


@pytest.mark.slow
@pytest.mark.parametrize("path", CORPUS, ids=[p.stem for p in CORPUS])
def test_corpus_file_meets_its_expectation(path):
    adversarial.check_file(path, run)
