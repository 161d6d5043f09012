"""Loading a scenario completely: read and validate it (:mod:`stt_drake.config`), then
the checks that need the built laws (:mod:`stt_drake.build.checks`)."""

from __future__ import annotations

from pathlib import Path

from stt_drake.build.checks import check_buildable
from stt_drake.config import Scenario, complete_scenario, read_scenario, read_scenario_text
from stt_drake.config.assumptions import check_target_separation


def load_scenario(path: str | Path, seed: int | None = None, strict: bool = False) -> Scenario:
    """Load, expand and validate a scenario file; raises ScenarioError on any bad input.

    `seed`, when given, replaces the file's `seed` before anything random is drawn, so a
    run is reproduced from (file, seed) alone. `strict` (``stt-drake run --strict``) makes
    the scenario strict, as `strict: true` in the file does: a broken assumption of the
    theorem that the run would otherwise record is refused
    (:func:`stt_drake.config.assumptions.check_target_separation`).
    """
    scenario = read_scenario(path, seed)
    if strict:
        scenario.strict = True
        check_target_separation(scenario)
    check_buildable(scenario)
    return scenario


def parse_scenario(text: str, default_name: str = "scenario", seed: int | None = None) -> Scenario:
    """Parse and validate scenario YAML text (see :func:`load_scenario`)."""
    scenario = read_scenario_text(text, default_name, seed)
    check_buildable(scenario)
    return scenario


def prepare_scenario(schema: Scenario, seed: int | None = None) -> Scenario:
    """A scenario from a parsed schema (:func:`stt_drake.config.parse_schema`) with `seed`:
    its random field drawn and every rule checked, as :func:`parse_scenario` would; the
    YAML is not parsed again (a campaign's runs)."""
    scenario = complete_scenario(schema, seed)
    check_buildable(scenario)
    return scenario
