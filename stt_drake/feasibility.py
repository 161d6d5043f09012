"""What a scenario asks of the plant and of the fixed-rate tube, checked before a run.

Pure numpy, no Drake. Filled in by the real-time safety work: the speed the plant can
follow under the controller's saturation, the rates the tube may demand, and the longest
admissible update period.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from stt_drake.scenario import Scenario


def scenario_warnings(scenario: Scenario) -> list[str]:
    """Validation warnings: what the scenario allows but the guarantees cannot cover."""
    return []
