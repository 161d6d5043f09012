"""A bound on the piecewise-linear schedules of a scenario file: the `times` of every
``!Waypoints`` motion, `sigma_schedule` and `covariance_schedule`, with their positions,
values and covariances.

Each schedule is evaluated from its lists at every integrator step (a list of N entries
costs O(N) per evaluation), and validated entry by entry, so the entries of all schedules
of one file are bounded by :data:`MAX_SCHEDULE_ENTRIES`. The bound is checked twice: on
the YAML node graph, before any Python data is made from it and before Drake's typed
loader reads the file (:func:`check_schedule_nodes`; a 100 000-entry covariance schedule
took minutes there and then hung in validation), and on the loaded scenario
(:func:`check_schedules`, which also sees schedules a YAML merge key brought in).
"""

from __future__ import annotations

from collections.abc import Iterator

import yaml

from stt_drake.config.schema import Scenario, ScenarioError

#: Most entries all schedules of one file may hold together. A schedule recorded at 100 Hz
#: for 100 s has 10 000; at this bound a 3D covariance schedule is 140 000 values (within
#: :data:`stt_drake.config.source.MAX_EXPANDED_NODES`), a 2D one loads and validates in
#: ~3 s (batched eigenvalues), and its O(N) evaluation costs ~11 ms per integrator step
#: (the omni base over 10 s: 11.5 s of wall time instead of 0.6 s), which the work budget
#: counts (:data:`stt_drake.config.limits.SCHEDULE_ENTRY_STEP_SECONDS`).
MAX_SCHEDULE_ENTRIES = 10_000

#: Per obstacle field: the lists of its schedule (a motion counts only when it has them).
SCHEDULE_LISTS = {
    "motion": ("times", "positions"),
    "sigma_schedule": ("times", "values"),
    "covariance_schedule": ("times", "covariances"),
}


def _check_total(schedules: list[tuple[str, int]]) -> None:
    """Refuse `schedules` ((field path, entries) each) holding more than
    :data:`MAX_SCHEDULE_ENTRIES` entries in all, naming the longest."""
    total = sum(entries for _path, entries in schedules)
    if total <= MAX_SCHEDULE_ENTRIES:
        return
    path, entries = max(schedules, key=lambda item: item[1])
    raise ScenarioError(
        f"{path}: the schedules of this file hold {total} entries in all, more than "
        f"{MAX_SCHEDULE_ENTRIES} (this one, the longest, {entries}): each is evaluated from "
        "its lists at every integrator step, so the schedules may not be longer; resample "
        f"them (got {entries} entries)"
    )


def _mapping_items(node: yaml.Node) -> Iterator[tuple[str, yaml.Node]]:
    if isinstance(node, yaml.MappingNode):
        for key, value in node.value:
            if isinstance(key, yaml.ScalarNode):
                yield str(key.value), value


def check_schedule_nodes(root: yaml.Node) -> None:
    """:data:`MAX_SCHEDULE_ENTRIES` on the composed YAML node graph of a scenario file (an
    obstacle listed twice through an alias counts twice, as Drake's loader expands it); a
    field that is not where the schema puts it is left to the later checks.

    Raises:
        ScenarioError: naming the schedule that goes over the bound.
    """
    obstacles = dict(_mapping_items(root)).get("obstacles")
    if not isinstance(obstacles, yaml.SequenceNode):
        return
    schedules = []
    for i, item in enumerate(obstacles.value):
        for name, schedule in _mapping_items(item):
            lists = SCHEDULE_LISTS.get(name)
            if lists is None:
                continue
            fields = dict(_mapping_items(schedule))
            lengths = [
                len(fields[key].value)
                for key in lists
                if isinstance(fields.get(key), yaml.SequenceNode)
            ]
            schedules.append((f"scenario.obstacles[{i}].{name}", max(lengths, default=0)))
    _check_total(schedules)


def schedule_entries(scenario: Scenario) -> list[tuple[str, int]]:
    """(field path, entries) of every schedule of a loaded scenario's obstacles."""
    schedules = []
    for i, obstacle in enumerate(scenario.obstacles):
        for name, lists in SCHEDULE_LISTS.items():
            schedule = getattr(obstacle, name, None)
            if schedule is None:
                continue
            entries = max((len(getattr(schedule, key, None) or []) for key in lists), default=0)
            if entries:
                schedules.append((f"scenario.obstacles[{i}].{name}", entries))
    return schedules


def check_schedules(scenario: Scenario) -> None:
    """:data:`MAX_SCHEDULE_ENTRIES` on a loaded scenario's obstacles.

    Raises:
        ScenarioError: naming the longest schedule.
    """
    _check_total(schedule_entries(scenario))
