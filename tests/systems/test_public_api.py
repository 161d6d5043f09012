"""The public API of ``stt_drake``: enough to build, run and check one's own Diagram.

Every name of ``stt_drake.__all__`` imports and is documented; ``import stt_drake`` (and the
core names) pulls in no Drake; the README's example of AddStt in one's own Diagram runs;
the Simulator helper for a Diagram applies a scenario run's set-up and reports the
guarantees; the invariant monitor composes with a monitor of one's own; load_scenario
resolves packaged names; the obstacle and motion constructors refuse what a scenario file
is refused for, with the loader's rule.
"""

from __future__ import annotations

import inspect
import math
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from pydrake.systems.analysis import SimulatorConfig, SimulatorStatus
from pydrake.systems.framework import DiagramBuilder, EventStatus
from pydrake.systems.primitives import Integrator

import stt_drake
from stt_drake import (
    INVARIANT_NAMES,
    AddStt,
    ConstantVelocity,
    FunnelController,
    InvariantTracker,
    Obstacle,
    Oscillation,
    ScenarioError,
    SigmaSchedule,
    TubeLaw,
    Waypoints,
    combine_monitors,
    default_nu,
    guarantees_report,
    load_scenario,
    make_diagram_simulator,
    packaged_scenarios,
    parse_scenario,
)
from stt_drake.config import Obstacle as SchemaObstacle
from stt_drake.core.rules import RuleError

ROOT = Path(__file__).resolve().parents[2]
#: The README's example, read from README.md (its first Python block).
README_EXAMPLE = re.search(
    r"^```python\n(.*?)^```", (ROOT / "README.md").read_text(encoding="utf-8"), re.M | re.S
)[1]

EPSILON = 0.9


def own_diagram():
    """The README's Diagram: a first-order robot (Drake's Integrator) and one crossing
    obstacle; returns the Diagram and AddStt's handles."""
    builder = DiagramBuilder()
    robot = builder.AddSystem(Integrator(2))
    crosser = Obstacle(
        motion=ConstantVelocity(start=[1.5, 1.0], velocity=[0.0, -0.25]),
        radius=0.3,
        sigma=0.1,
        epsilon=EPSILON,
        p_d=0.999,
    )
    stt = AddStt(
        builder, readme_law(), FunnelController(kappa=[5.0]), [0.0, 0.0], obstacles=[crosser]
    )
    builder.Connect(stt.control, robot.get_input_port())
    builder.Connect(robot.get_output_port(), stt.plant_state)
    builder.Connect(robot.get_output_port(), stt.output)
    return builder.Build(), stt


def readme_law() -> TubeLaw:
    """The README's tube law (one obstacle)."""
    return TubeLaw(
        target=[3.0, 0.0],
        k1=0.6,
        k2=0.4,
        k3=0.4,
        r_min=0.15,
        r_max=0.4,
        nu=default_nu(1, 0.15),
        max_center_speed=1.0,
    )


# --------------------------------------------------------------------------- the names


@pytest.mark.parametrize("name", stt_drake.__all__)
def test_every_public_name_imports_and_is_documented(name):
    value = getattr(stt_drake, name)
    assert name in dir(stt_drake)
    if name == "INVARIANT_NAMES":  # a constant: documented by its #: comment
        source = inspect.getsource(sys.modules[stt_drake._PUBLIC[name]])
        assert "#: The guarantees, in the order of the invariant monitor's `margins`" in source
        return
    doc = inspect.getdoc(value) or ""
    # A dataclass without a docstring gets "Name(field, ...)": not documentation.
    assert doc and not doc.startswith(f"{name}("), f"{name} has no docstring"


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="has no attribute 'Nope'"):
        stt_drake.Nope  # noqa: B018


def test_import_and_the_core_names_pull_in_no_drake():
    code = textwrap.dedent(
        """
        import sys
        import stt_drake
        assert not [m for m in sys.modules if m.startswith("pydrake")], "import stt_drake"
        from stt_drake import (BoxFunnel, ConstantVelocity, InvariantTracker, Obstacle,
                               Oscillation, TubeLaw, default_nu, linear_zone_for_step)
        assert not [m for m in sys.modules if m.startswith("pydrake")], "core names"
        from stt_drake import AddStt
        assert "pydrake" in sys.modules
        """
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


def test_the_schema_obstacle_is_the_core_obstacle_and_loads_equal():
    assert SchemaObstacle is Obstacle  # the loader's type is the core's
    scenario = parse_scenario(scenario_text())
    expected = Obstacle(
        motion=ConstantVelocity(start=[1.5, 1.0], velocity=[0.0, -0.25]),
        radius=0.3,
        sigma=0.1,
        epsilon=0.9,
        p_d=0.999,
    )
    assert scenario.obstacles == [expected]


# --------------------------------------------------------------------------- own Diagram


@pytest.mark.slow
def test_the_readme_example_runs_and_every_guarantee_holds(capsys):
    exec(compile(README_EXAMPLE, "README example", "exec"), {})
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0].startswith("guarantees (worst margin, at time; holds if ≥ −")
    assert [line.split()[0] for line in lines[1:]] == list(INVARIANT_NAMES)
    assert all(line.split()[1] == "holds" for line in lines[1:])
    # The obstacle mattered: the centre came within the avoidance layer's reach
    # (q − ε below its free value 1 − ε).
    center = next(line for line in lines if line.split()[0] == "center_avoid_probability")
    assert float(center.split()[2]) < 1.0 - EPSILON - 0.01


def test_the_diagram_simulator_applies_a_scenario_runs_set_up():
    diagram, stt = own_diagram()
    scenario = load_scenario("omni_hardware_case1")  # a scenario file's defaults
    simulator = make_diagram_simulator(diagram)
    integrator = simulator.get_integrator()
    assert type(integrator).__name__.startswith("RungeKutta3Integrator")
    assert integrator.get_target_accuracy() == scenario.simulator.accuracy == 1e-6
    assert integrator.get_maximum_step_size() == pytest.approx(0.01, rel=1e-8)
    assert integrator.get_fixed_step_mode() is False
    changed = make_diagram_simulator(diagram, accuracy=1e-4, max_step_size=0.005)
    assert changed.get_integrator().get_target_accuracy() == 1e-4
    assert changed.get_integrator().get_maximum_step_size() == pytest.approx(0.005, rel=1e-8)
    config = SimulatorConfig(integration_scheme="runge_kutta2", max_step_size=0.002)
    own = make_diagram_simulator(diagram, config=config)
    assert type(own.get_integrator()).__name__.startswith("RungeKutta2Integrator")
    assert config.max_step_size == 0.002  # the caller's config is not changed
    with pytest.raises(ValueError, match="give `monitor` and `tracker` together"):
        make_diagram_simulator(diagram, stt.monitor)


def test_the_diagram_simulator_checks_every_guarantee_and_reports_them():
    diagram, stt = own_diagram()
    tracker = InvariantTracker()
    simulator = make_diagram_simulator(diagram, stt.monitor, tracker)
    simulator.AdvanceTo(1.0)
    assert simulator.get_num_steps_taken() > 50
    assert tracker.holds
    records = tracker.as_dict()
    # every guarantee was evaluated (a tracker starts at +inf, t = 0)
    assert all(math.isfinite(record["worst_margin"]) for record in records.values())
    assert all(record["t_worst"] <= 1.0 for record in records.values())
    report = guarantees_report(tracker).splitlines()
    assert len(report) == len(INVARIANT_NAMES) + 1
    for name, line in zip(INVARIANT_NAMES, report[1:], strict=True):
        words = line.split()
        assert words[:2] == [name, "holds"]
        assert float(words[2]) == pytest.approx(records[name]["worst_margin"], rel=1e-3)


# --------------------------------------------------------------------------- monitors


def test_a_users_monitor_runs_next_to_the_invariant_monitor_and_can_stop_the_run():
    diagram, stt = own_diagram()
    tracker, seen = InvariantTracker(), []

    def stop_at_one_second(root_context):
        seen.append(root_context.get_time())
        if root_context.get_time() >= 1.0:
            return EventStatus.ReachedTermination(None, "mine: one second is enough")
        return EventStatus.DidNothing()

    simulator = make_diagram_simulator(diagram, stt.monitor, tracker, also=stop_at_one_second)
    status = simulator.AdvanceTo(5.0)
    assert status.reason() == SimulatorStatus.ReturnReason.kReachedTerminationCondition
    assert "one second is enough" in status.FormatMessage()
    t_end = simulator.get_context().get_time()
    assert 1.0 <= t_end < 1.1
    assert len(seen) > 50 and seen[-1] == t_end  # every step, up to the stop
    # The invariant monitor ran at the same steps: every guarantee evaluated, inside the run.
    records = tracker.as_dict().values()
    assert all(math.isfinite(r["worst_margin"]) and r["t_worst"] <= t_end for r in records)


def test_attach_keeps_a_users_monitor_given_as_also():
    diagram, stt = own_diagram()
    calls = []
    simulator = make_diagram_simulator(diagram)
    tracker = InvariantTracker()
    stt.monitor.attach(simulator, tracker, also=lambda context: calls.append(1))
    simulator.AdvanceTo(0.2)
    assert len(calls) > 5
    assert all(math.isfinite(record["worst_margin"]) for record in tracker.as_dict().values())


def test_combine_monitors_calls_all_and_returns_the_most_severe_status():
    calls = []

    def returning(status):
        def monitor(context):
            calls.append(status)
            return None if status is None else status()

        return monitor

    def stop():
        return EventStatus.ReachedTermination(None, "stop")

    def fail():
        return EventStatus.Failed(None, "fail")

    combined = combine_monitors(returning(stop), returning(fail), returning(None))
    status = combined(None)
    assert status.severity() == EventStatus.Severity.kFailed
    assert status.message() == "fail"
    assert calls == [stop, fail, None]  # every one, in order
    first = combine_monitors(returning(EventStatus.Succeeded), returning(stop))(None)
    assert first.severity() == EventStatus.Severity.kReachedTermination
    quiet = combine_monitors(returning(None), returning(EventStatus.DidNothing))(None)
    assert quiet.severity() == EventStatus.Severity.kDidNothing
    with pytest.raises(ValueError, match="at least one monitor"):
        combine_monitors()


# --------------------------------------------------------------------------- packaged names


def test_load_scenario_resolves_packaged_names(tmp_path, monkeypatch):
    packaged = packaged_scenarios()
    assert "omni_hardware_case1" in packaged
    by_name = load_scenario("omni_hardware_case1")
    by_path = load_scenario(packaged["omni_hardware_case1"])
    assert by_name.name == by_path.name == "omni_hardware_case1"
    assert by_name.obstacles == by_path.obstacles
    assert load_scenario("omni_hardware_case2.yaml").name == "omni_hardware_case2"
    # An existing file wins over a packaged name.
    text = (
        packaged["omni_hardware_case1"]
        .read_text()
        .replace("name: omni_hardware_case1", "name: mine")
    )
    assert "name: mine" in text
    (tmp_path / "omni_hardware_case1.yaml").write_text(text)
    monkeypatch.chdir(tmp_path)
    assert load_scenario("omni_hardware_case1.yaml").name == "mine"


def test_an_unknown_name_lists_the_closest_packaged_names():
    with pytest.raises(ScenarioError) as info:
        load_scenario("omni_hardwre_case1")
    message = str(info.value)
    assert message.startswith("omni_hardwre_case1: no such scenario file")
    close = message.split("close packaged names: ", 1)[1].split(" (", 1)[0].split(", ")
    assert close[0] == "omni_hardware_case1"
    assert set(close) <= set(packaged_scenarios())
    assert message.endswith("(stt_drake.packaged_scenarios() lists them all)")


# --------------------------------------------------------------------------- constructors


@pytest.mark.parametrize(
    ("make", "expected"),
    [
        (
            lambda: ConstantVelocity(start=[0.0, 0.0], velocity=[1.0]),
            "ConstantVelocity: velocity must have 2 entries (got [1.0])",
        ),
        (
            lambda: ConstantVelocity(start=[0.0, math.nan], velocity=[1.0, 0.0]),
            "ConstantVelocity: start must be finite (got [0.0, nan])",
        ),
        (
            lambda: Oscillation(center=[0.0, 0.0], amplitude=[1.0, 0.0], frequency_hz=-0.1),
            "Oscillation: frequency_hz must be ≥ 0 (got -0.1)",
        ),
        (
            lambda: Oscillation(center=[0.0, 0.0], amplitude=[1.0]),
            "Oscillation: amplitude must have 2 entries (got [1.0])",
        ),
        (
            lambda: Waypoints(times=[0.0, 1.0], positions=[[0.0, 0.0]]),
            "Waypoints: positions needs one position per time (got [[0.0, 0.0]])",
        ),
        (
            lambda: Waypoints(times=[1.0, 0.0], positions=[[0.0, 0.0], [1.0, 1.0]]),
            "Waypoints: times must increase (a time may be repeated once: a step) (got [1.0, 0.0])",
        ),
        (
            lambda: Obstacle(sigma=0.0),
            "Obstacle: sigma must be > 0 (a standard deviation in metres) (got 0.0)",
        ),
        (lambda: Obstacle(radius=-0.2), "Obstacle: radius must be > 0 (metres) (got -0.2)"),
        (lambda: Obstacle(epsilon=0.95, p_d=0.9), "Obstacle: p_d must lie in (epsilon, 1]"),
        (
            lambda: Obstacle(covariance=[[0.04, 0.05], [0.05, 0.04]]),
            "Obstacle: covariance must be symmetric positive definite",
        ),
        (
            lambda: Obstacle(covariance=[[0.04, 0.0], [0.0, 0.04]], axes_sigma=[0.2, 0.2]),
            "Obstacle: axes_sigma must not be given too: covariance and axes_sigma are both given",
        ),
        (
            lambda: Obstacle(rotation=[0.3]),
            "Obstacle: rotation turns the principal axes of axes_sigma",
        ),
        (
            lambda: Obstacle(sigma_schedule=SigmaSchedule(times=[0.0, 1.0], values=[0.1])),
            "Obstacle: sigma_schedule needs as many values as times (≥ 1)",
        ),
        (
            lambda: Obstacle(sigma_schedule=SigmaSchedule(times=[0.0], values=[1e-4])),
            "Obstacle: sigma_schedule.values[0] must be ≥ 0.001",
        ),
    ],
)
def test_the_constructors_name_the_argument_and_the_rule(make, expected):
    with pytest.raises(RuleError) as info:
        make()
    assert str(info.value).startswith(expected)


def scenario_text(
    start: str = "[1.5, 1.0]", velocity: str = "[0.0, -0.25]", sigma: str = "0.1"
) -> str:
    """A 2D scenario with one obstacle moving from `start` at `velocity`, with `sigma`."""
    return f"""
name: api_obstacle
start: [0.0, 0.0]
initial_set_radius: 0.5
target: [3.0, 0.0]
target_set_radius: 0.5
duration: 8.0
tube: {{r_min: 0.15, r_max: 0.4, k1: 0.6, k2: 0.4, k3: 0.4, max_center_speed: 1.0}}
controller: {{kappa: [5.0]}}
plant: {{disturbance_amplitude: [0.0, 0.0]}}
obstacles:
  - motion: !ConstantVelocity {{start: {start}, velocity: {velocity}}}
    radius: 0.3
    sigma: {sigma}
    epsilon: 0.9
    p_d: 0.999
"""


@pytest.mark.parametrize(
    ("file_change", "api_obstacle", "file_field", "api_field"),
    [
        (
            ("[1.5, 1.0, 0.0]", "[0.0, -0.25, 0.0]", "0.1"),
            lambda: Obstacle(motion=ConstantVelocity([1.5, 1.0, 0.0], [0.0, -0.25, 0.0])),
            "scenario.obstacles[0].motion.start",
            "AddStt: obstacles[0].motion.start",
        ),
        (
            ("[1.5, 1.0]", "[0.0, -0.25]", "0.0001"),
            lambda: Obstacle(motion=ConstantVelocity([1.5, 1.0], [0.0, -0.25]), sigma=1e-4),
            "scenario.obstacles[0].sigma",
            "Obstacle: sigma",
        ),
    ],
    ids=["dimension", "sigma_min"],
)
def test_the_loader_and_the_api_refuse_an_obstacle_with_the_same_rule(
    file_change, api_obstacle, file_field, api_field
):
    """A 3D motion in a 2D scenario (checked where n is known: the loader, AddStt) and a σ
    below 1 mm (checked when the obstacle is made)."""
    with pytest.raises(ScenarioError) as from_file:
        parse_scenario(scenario_text(*file_change))
    with pytest.raises(RuleError) as from_api:
        obstacles = [api_obstacle()]
        AddStt(
            DiagramBuilder(),
            readme_law(),
            FunnelController(kappa=[5.0]),
            [0, 0],
            obstacles=obstacles,
        )
    file_message, api_message = str(from_file.value), str(from_api.value)
    assert file_message.startswith(file_field + ": ")
    assert api_message.startswith(api_field + " ")
    assert file_message[len(file_field) + 2 :] == api_message[len(api_field) + 1 :]


def test_tube_law_needs_an_explicit_center_speed():
    constants = dict(target=[3.0, 0.0], k1=0.6, k2=0.4, k3=0.4, r_min=0.15, r_max=0.4, nu=20.0)
    with pytest.raises(TypeError, match="max_center_speed"):
        TubeLaw(**constants)
    assert TubeLaw(**constants, max_center_speed=math.inf).max_center_speed == math.inf
    np.testing.assert_array_equal(TubeLaw(**constants, max_center_speed=1.0).target, [3.0, 0.0])
