"""The Python API refuses what a scenario file is refused for, with the same rule text
(issue 25): the rules live once, in stt_drake.core.rules, and both the constructors of the
core objects (TubeLaw, ObstacleTask, BoxFunnel, FunnelController, SpatiotemporalTube,
AddStt) and the scenario loader check them.

The three cases that were found first — an obstacle with ε = 1.5 through AddStt (it built,
then stopped at t = 2.13 s with "tube law produced a non-finite value"), a start inside an
obstacle (the same at t = 0), and ``TubeLaw(nu=1.0)`` with an obstacle — are refused when
the objects are made, naming the argument and the rule. Then, rule by rule, the same bad
value is written into a scenario file and given to the constructors, and the rule texts
of both refusals are compared.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from pydrake.systems.framework import DiagramBuilder

from stt_drake import AddStt, FunnelController, ObstacleTask, SpatiotemporalTube, TubeLaw
from stt_drake.assembly import parse_scenario
from stt_drake.config import AssumptionError, Obstacle, ScenarioError
from stt_drake.core import anisotropic
from stt_drake.core.control import BoxFunnel
from stt_drake.core.motion import ConstantVelocity
from stt_drake.core.probability import avoid_probability
from stt_drake.core.rules import InitialConditionError, RuleError

R_MIN, R_MAX = 0.1, 0.3
START, TARGET = [0.5, 0.5], [4.5, 4.5]
CENTRES = ([2.5, 2.5], [1.5, 3.5], [3.5, 1.2])

#: The values both the file and the API are built from; a case changes one of them.
GOOD = {
    "r_min": R_MIN,
    "r_max": R_MAX,
    "k1": 0.5,
    "k2": 0.4,
    "k3": 0.4,
    "nu": 20.0,  # > ln(3 + 1)/0.1 = 13.86
    "kappa": 2.0,
    "radius": 0.2,  # obstacle 2's task numbers
    "epsilon": 0.9,
    "p_d": 0.9999,
    "start": START,
}

SCENARIO = """
name: api_rules
start: {start}
initial_set_radius: 0.5
target: [4.5, 4.5]
target_set_radius: 0.5
duration: 10.0
tube: {{r_min: {r_min}, r_max: {r_max}, k1: {k1}, k2: {k2}, k3: {k3}, nu: {nu},
        max_center_speed: 0.1}}
controller: {{kappa: [{kappa}]}}
plant: {{disturbance_amplitude: [0.0, 0.0]}}
obstacles:
  - motion: !ConstantVelocity {{start: [2.5, 2.5], velocity: [0.0, 0.0]}}
    radius: 0.2
    sigma: 0.1
    epsilon: 0.9
    p_d: 0.9999
  - motion: !ConstantVelocity {{start: [1.5, 3.5], velocity: [0.0, 0.0]}}
    radius: 0.2
    sigma: 0.1
    epsilon: 0.9
    p_d: 0.9999
  - motion: !ConstantVelocity {{start: [3.5, 1.2], velocity: [0.0, 0.0]}}
    radius: {radius}
    sigma: 0.1
    epsilon: {epsilon}
    p_d: {p_d}
"""


def obstacle(centre, radius=0.2, epsilon=0.9, p_d=0.9999, **uncertainty) -> Obstacle:
    uncertainty.setdefault("sigma", 0.1)
    return Obstacle(
        motion=ConstantVelocity(start=list(centre), velocity=[0.0, 0.0]),
        radius=radius,
        epsilon=epsilon,
        p_d=p_d,
        **uncertainty,
    )


def law(**changes) -> TubeLaw:
    constants = dict(
        target=np.array(TARGET), k1=0.5, k2=0.4, k3=0.4, r_min=R_MIN, r_max=R_MAX, nu=20.0
    )
    constants.update(changes)
    return TubeLaw(max_center_speed=0.1, **constants)


def file_text(values: dict) -> str:
    return SCENARIO.format(**values)


def build_with_api(values: dict) -> None:
    """The scenario of :data:`SCENARIO` made with the API: the law, the controller and
    AddStt with the three obstacles."""
    obstacles = [obstacle(c) for c in CENTRES[:2]]
    obstacles.append(obstacle(CENTRES[2], values["radius"], values["epsilon"], values["p_d"]))
    tube_law = law(**{name: values[name] for name in ("r_min", "r_max", "k1", "k2", "k3", "nu")})
    controller = FunnelController(kappa=[values["kappa"]])
    AddStt(DiagramBuilder(), tube_law, controller, values["start"], obstacles=obstacles)


def rule_part(message: str, where: str) -> str:
    """The rule of `message` "<where> <rule> (got <value>)" (the loader's "<path>:")."""
    assert message.startswith(where), f"expected {where!r} at the start of: {message}"
    return message[len(where) :].lstrip(":").strip().rsplit(" (got ", 1)[0]


# --------------------------------------------------------------------------- found cases


def test_an_epsilon_above_one_is_refused_by_the_obstacle_and_by_addstt():
    """It built and then stopped at t = 2.13 s ("tube law produced a non-finite value").
    Now the Obstacle refuses it when made, and AddStt refuses an obstacle changed
    afterwards, naming it, before anything is added to the builder."""
    with pytest.raises(RuleError) as made:
        obstacle(CENTRES[2], epsilon=1.5)
    assert str(made.value) == "Obstacle: epsilon must lie in (0, 1] (got 1.5)"
    changed = obstacle(CENTRES[2])
    changed.epsilon = 1.5
    obstacles = [obstacle(CENTRES[0]), obstacle(CENTRES[1]), changed]
    builder = DiagramBuilder()
    with pytest.raises(ValueError) as info:
        AddStt(builder, law(), FunnelController(kappa=[2.0]), START, obstacles=obstacles)
    assert str(info.value) == "AddStt: obstacles[2].epsilon must lie in (0, 1] (got 1.5)"
    assert isinstance(info.value, RuleError) and info.value.field == "obstacles[2].epsilon"
    assert builder.GetSystems() == []


def test_addstt_refuses_a_start_inside_an_obstacle():
    """The initial avoidance condition q_j(s, 0) > ε_j (Definition 2.3) at the start: it
    used to fail at t = 0 with a non-finite recovery."""
    start = [2.5, 2.35]  # 0.15 m from obstacle 0's mean: inside r_o + r_min = 0.3
    q = avoid_probability(np.array(start), np.array([CENTRES[0]]), np.array([0.1]), 0.3)[0]
    assert q <= 0.9
    builder = DiagramBuilder()
    with pytest.raises(InitialConditionError) as info:
        AddStt(
            builder,
            law(),
            FunnelController(kappa=[2.0]),
            start,
            obstacles=[obstacle(c) for c in CENTRES],
        )
    message = str(info.value)
    assert message.startswith("AddStt: start must meet the initial avoidance condition")
    assert f"obstacle 0 has q_0(s, 0) = {q:.6g}, not above epsilon = 0.9" in message
    assert message.endswith("(got [2.5, 2.35])")
    assert builder.GetSystems() == []


def test_a_nu_too_small_for_the_obstacle_count_is_refused_when_the_count_is_known():
    """TubeLaw(nu=1.0) is a law (ν > 0), but not for one obstacle with r_min = 0.1:
    ln 2/0.1 = 6.93. AddStt and SpatiotemporalTube know the count and refuse it."""
    weak = law(nu=1.0)
    bound = math.log(2.0) / R_MIN
    with pytest.raises(ValueError) as info:
        AddStt(
            DiagramBuilder(),
            weak,
            FunnelController(kappa=[2.0]),
            START,
            obstacles=[obstacle(CENTRES[0])],
        )
    assert str(info.value).startswith(
        f"AddStt: law.nu must exceed ln(n_o + 1)/r_min = {bound:.4g} for 1 obstacle, "
        "or the soft-min radius can go negative"
    )
    assert str(info.value).endswith("(got 1.0)")
    task = ObstacleTask(np.array([0.2]), np.array([0.9]), np.array([0.9999]))
    with pytest.raises(ValueError, match=r"^SpatiotemporalTube: law\.nu must exceed .* = 6\.931"):
        SpatiotemporalTube(weak, np.array(START), task)
    # A belief port's slots count: three slots need ν > ln 4/0.1 = 13.86.
    slots = ObstacleTask(np.full(3, 0.2), np.full(3, 0.9), np.full(3, 0.9999))
    source = AddStt(DiagramBuilder(), law(), FunnelController(kappa=[2.0]), START, obstacles=[])
    with pytest.raises(ValueError, match=r"^AddStt: law\.nu must exceed .* = 13\.86 for 3"):
        AddStt(
            DiagramBuilder(),
            law(nu=13.0),
            FunnelController(kappa=[2.0]),
            START,
            belief=source.belief,
            task=slots,
        )
    SpatiotemporalTube(law(nu=20.0), np.array(START), slots)  # above the bound: accepted


# --------------------------------------------------------------------------- constructors


@pytest.mark.parametrize(
    ("changes", "expected"),
    [
        ({"nu": 0.0}, "TubeLaw: nu must be finite and > 0 (1/m) (got 0.0)"),
        ({"nu": math.inf}, "TubeLaw: nu must be finite and > 0 (1/m) (got inf)"),
        ({"k1": math.nan}, "TubeLaw: k1 must be finite (got nan)"),
        ({"k2": np.array([0.4, 0.0, 0.3])}, "TubeLaw: k2[1] must be > 0 (got 0.0)"),
        ({"k3": -0.1}, "TubeLaw: k3 must be ≥ 0 (got -0.1)"),
        ({"r_min": 0.0}, "TubeLaw: r_min must be > 0 (metres) (got 0.0)"),
        ({"r_max": 0.1}, "TubeLaw: r_max must be > r_min = 0.1 (got 0.1)"),
        ({"linear_zone": -1e-3}, "TubeLaw: linear_zone must be ≥ 0"),
        ({"target": np.array([1.0, math.nan])}, "TubeLaw: target must be finite"),
        ({"max_center_speed": -1.0}, "TubeLaw: max_center_speed must be ≥ 0 (m/s; inf"),
    ],
)
def test_tube_law_checks_its_constants(changes, expected):
    constants = dict(target=np.array(TARGET), k1=0.5, k2=0.4, k3=0.4, r_min=R_MIN, r_max=R_MAX)
    constants.update({"nu": 20.0, "max_center_speed": 0.1, **changes})
    with pytest.raises(RuleError) as info:
        TubeLaw(**constants)
    assert str(info.value).startswith(expected)


def test_tube_law_needs_its_center_speed_and_checks_replaced_copies():
    """No default v_c: an infinite one (no boundary layer, no recovery speed) must be asked
    for, so the recovery is never switched off silently."""
    with pytest.raises(TypeError, match="max_center_speed"):
        TubeLaw(np.array(TARGET), 0.5, 0.4, 0.4, R_MIN, R_MAX, 20.0)
    unbounded = TubeLaw(
        np.array(TARGET), 0.5, 0.4, 0.4, R_MIN, R_MAX, 20.0, max_center_speed=math.inf
    )
    assert unbounded.max_center_speed == math.inf
    moved = unbounded.with_target(np.array([1.0, 1.0]))
    np.testing.assert_array_equal(moved.target, [1.0, 1.0])
    with pytest.raises(RuleError, match=r"^TubeLaw: r_min must be > 0"):
        dataclasses.replace(unbounded, r_min=-0.1)


def test_obstacle_task_checks_every_slot():
    with pytest.raises(RuleError) as info:
        ObstacleTask(np.full(3, 0.2), np.array([0.9, 0.8, 1.5]), np.full(3, 0.9999))
    assert str(info.value) == "ObstacleTask: epsilon[2] must lie in (0, 1] (got 1.5)"
    with pytest.raises(RuleError, match=r"^ObstacleTask: p_d\[0\] must be below 1: .*can never"):
        ObstacleTask(np.array([0.2]), np.array([0.9]), np.array([1.0]))
    with pytest.raises(RuleError, match=r"^ObstacleTask: p_d\[0\] must lie in \(epsilon, 1\]"):
        ObstacleTask(np.array([0.2]), np.array([0.9]), np.array([0.9]))
    with pytest.raises(RuleError, match=r"^ObstacleTask: radius\[1\] must be finite"):
        ObstacleTask(np.array([0.2, math.nan]), np.full(2, 0.9), np.full(2, 0.99))
    with pytest.raises(RuleError, match=r"^ObstacleTask: p_d needs one entry per obstacle slot"):
        ObstacleTask(np.full(2, 0.2), np.full(2, 0.9), np.full(3, 0.99))
    flat = obstacle(CENTRES[1])
    flat.radius = 0.0  # changed after it was made (which would refuse it)
    with pytest.raises(RuleError, match=r"^ObstacleTask\.of: obstacles\[1\]\.radius must be > 0"):
        ObstacleTask.of([obstacle(CENTRES[0]), flat])
    assert ObstacleTask(np.empty(0), np.empty(0), np.empty(0)).count == 0


def test_funnel_controller_and_box_funnels_check_theirs():
    with pytest.raises(RuleError, match=r"^FunnelController: kappa must all be > 0 \(got \[2\.0, "):
        FunnelController(kappa=[2.0, -1.0], funnels=[BoxFunnel(1.0, 0.5, 1.0)])
    with pytest.raises(RuleError, match=r"^FunnelController: kappa needs at least one stage gain"):
        FunnelController(kappa=[])
    with pytest.raises(RuleError, match=r"^FunnelController: kappa must be finite"):
        FunnelController(kappa=[math.inf])
    with pytest.raises(RuleError, match=r"^BoxFunnel: end must satisfy 0 < end < start per axis"):
        BoxFunnel(start=np.array([1.0, 1.0]), end=np.array([0.5, 1.0]), rate=1.0)
    with pytest.raises(RuleError, match=r"^BoxFunnel: end must satisfy 0 < end < start"):
        BoxFunnel(start=1.0, end=0.0, rate=1.0)
    with pytest.raises(RuleError, match=r"^BoxFunnel: rate must be ≥ 0 \(got -0\.5\)"):
        BoxFunnel(start=1.0, end=0.5, rate=-0.5)
    with pytest.raises(RuleError, match=r"^BoxFunnel: start must be finite"):
        BoxFunnel(start=np.array([math.nan, 1.0]), end=0.5, rate=0.5)
    BoxFunnel(start=2.0, end=0.5, rate=0.0)  # μ = 0: a constant box, valid


def test_the_initial_condition_uses_a_full_covariance_exactly():
    """A start 0.4 m from an obstacle across its thin axis (σ = 0.02 m; 0.3 m along the
    other): with √λ_max isotropically it would be inside the ε level set, with Σ it is
    clear. AddStt uses Σ where the tube will (full_covariance None or True)."""
    covariance = [[0.3**2, 0.0], [0.0, 0.02**2]]
    start = np.array([2.5, 2.1])
    mean, safety = np.array(CENTRES[0]), 0.2 + R_MIN
    exact = anisotropic.avoid_probability(start, mean, np.array(covariance), safety)
    isotropic = avoid_probability(start, mean[None], np.array([0.3]), safety)[0]
    assert isotropic <= 0.9 < exact
    thin = [obstacle(CENTRES[0], sigma=0.3, covariance=covariance)]
    controller = FunnelController(kappa=[2.0])
    for full in (None, True):
        AddStt(DiagramBuilder(), law(), controller, start, obstacles=thin, full_covariance=full)
    with pytest.raises(InitialConditionError):  # the λ_max reading the tube would then use
        AddStt(DiagramBuilder(), law(), controller, start, obstacles=thin, full_covariance=False)


# --------------------------------------------------------------------------- same rule text

#: (case, changed value, the file's field path, the API's "<owner>: <argument>",
#: what the loader adds to the rule, what the API adds).
SAME_RULE = [
    ("epsilon", {"epsilon": 1.5}, "scenario.obstacles[2].epsilon", "Obstacle: epsilon"),
    ("epsilon_zero", {"epsilon": 0.0}, "scenario.obstacles[2].epsilon", "Obstacle: epsilon"),
    ("p_d_one", {"p_d": 1.0}, "scenario.obstacles[2].p_d", "Obstacle: p_d"),
    ("p_d_below_epsilon", {"p_d": 0.5}, "scenario.obstacles[2].p_d", "Obstacle: p_d"),
    ("radius", {"radius": 0.0}, "scenario.obstacles[2].radius", "Obstacle: radius"),
    ("r_min", {"r_min": -0.1}, "scenario.tube.r_min", "TubeLaw: r_min"),
    ("r_max", {"r_max": 0.05}, "scenario.tube.r_max", "TubeLaw: r_max"),
    ("k1", {"k1": 0.0}, "scenario.tube.k1", "TubeLaw: k1"),
    ("k2", {"k2": -0.4}, "scenario.tube.k2", "TubeLaw: k2"),
    ("k3", {"k3": -0.1}, "scenario.tube.k3", "TubeLaw: k3"),
    ("nu_negative", {"nu": -5.0}, "scenario.tube.nu", "TubeLaw: nu"),
    ("nu_count", {"nu": 1.0}, "scenario.tube.nu", "AddStt: law.nu"),
    ("kappa", {"kappa": 0.0}, "scenario.controller.kappa", "FunnelController: kappa"),
    ("start", {"start": [2.5, 2.35]}, "scenario.start", "AddStt: start"),
]

#: The loader's and the constructors' own words after the shared rule (how to get a valid
#: value in each).
HINTS = {
    "nu_negative": (" (0 derives it)", ""),
    "nu_count": (" (0 derives it)", " (default_nu(n_o, r_min) gives twice the bound)"),
}


@pytest.mark.parametrize(
    ("changes", "path", "argument"),
    [pytest.param(changes, path, argument, id=case) for case, changes, path, argument in SAME_RULE],
)
def test_the_file_loader_and_the_constructor_give_the_same_rule(request, changes, path, argument):
    values = {**GOOD, **changes}
    with pytest.raises(ScenarioError) as from_file:
        parse_scenario(file_text(values))
    with pytest.raises(RuleError) as from_api:
        build_with_api(values)
    file_hint, api_hint = HINTS.get(request.node.callspec.id, ("", ""))
    rule = from_api.value.rule
    assert rule_part(str(from_file.value), path) == rule + file_hint
    assert rule_part(str(from_api.value), argument) == rule + api_hint
    # the same value echoed, and an assumption of the theorem stays one in both
    assert str(from_file.value).rsplit(" (got ", 1)[1] == str(from_api.value).rsplit(" (got ", 1)[1]
    initial = isinstance(from_api.value, InitialConditionError)
    assert isinstance(from_file.value, AssumptionError) == initial


def test_the_good_values_pass_both_ways():
    """The base of the cases above is valid for the loader and for the API alike."""
    assert len(parse_scenario(file_text(GOOD)).obstacles) == 3
    build_with_api(GOOD)
