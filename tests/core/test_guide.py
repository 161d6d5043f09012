"""The guide's core (:mod:`stt_drake.core.guide`, :mod:`stt_drake.core.route_search`):
level-set radii against scipy, routes that keep every obstacle's avoidance probability at
the times the tube would be there, waits for crossing obstacles, the tracker's forecast
against its own belief, and the compiled search against the plain-Python one."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import optimize, stats

from stt_drake.config import Obstacle
from stt_drake.core import backend
from stt_drake.core.consistency import Adaptation
from stt_drake.core.guide import (
    GuideSettings,
    LevelSetRadii,
    Route,
    RoutePlanner,
    ScriptedForecast,
    attraction_point,
    tracked_forecast,
)
from stt_drake.core.motion import ConstantVelocity, SigmaSchedule
from stt_drake.core.tracking import KalmanTracker


def scipy_avoid_probability(distance, sigma, radius, n):
    """P(‖x − O‖ ≥ radius) for O ~ N(μ, σ² I), ‖x − μ‖ = distance: scipy's ncx2."""
    return stats.ncx2.sf((radius / sigma) ** 2, n, (distance / sigma) ** 2)


def static(position, radius=0.3, sigma=0.1, epsilon=0.9, p_d=0.99, velocity=None):
    velocity = velocity if velocity is not None else [0.0] * len(position)
    motion = ConstantVelocity(start=list(position), velocity=list(velocity))
    return Obstacle(motion=motion, radius=radius, sigma=sigma, epsilon=epsilon, p_d=p_d)


def settings(count, level=0.99, **overrides):
    values = dict(
        resolution=0.1,
        horizon=20.0,
        time_step=0.1,
        speed=0.5,
        max_wait=3.0,
        lookahead=1.0,
        clearance=0.1,
        avoid_level=np.full(count, level),
    )
    values.update(overrides)
    return GuideSettings(**values)


def planner_for(obstacles, guide, r_min=0.1, n=2):
    radius = np.array([o.radius for o in obstacles])
    epsilon = np.array([o.epsilon for o in obstacles])
    return RoutePlanner(guide, radius, epsilon, r_min, n)


@pytest.mark.parametrize("n", [2, 3])
@pytest.mark.parametrize("level", [0.8, 0.99, 0.9999])
def test_level_set_radii_match_scipy(n, level):
    """D with P(‖x − O‖ ≥ r_s) = level at ‖x − μ‖ = D, for σ from 0.02 to 3 m, against a
    root of scipy's noncentral χ² survival function (interpolation: < 0.5 % of D)."""
    radii = LevelSetRadii(n)
    sigma = np.array([[0.02, 0.1, 0.37, 1.0, 3.0]])
    r_s = 0.45
    got = radii(sigma, np.full(5, r_s), np.full(5, level))[0]
    for d, s in zip(got, sigma[0], strict=True):
        if scipy_avoid_probability(0.0, s, r_s, n) >= level:
            assert d == 0.0  # even the mean keeps the level: the set is empty
            continue
        exact = optimize.brentq(
            lambda x, s=s: scipy_avoid_probability(x, s, r_s, n) - level, 0.0, r_s + 20 * s
        )
        assert d == pytest.approx(exact, rel=5e-3)


def test_inactive_and_zero_sigma_never_block():
    radii = LevelSetRadii(2)
    assert np.all(radii(np.zeros((2, 3)), np.ones(3), np.full(3, 0.9)) == 0.0)


def route_is_free(route, forecast_of, obstacles, level, clearance, r_min, n):
    """Every route point keeps P(‖x − O_j(t)‖ ≥ r_o + r_min + clearance) ≥ level at its time
    (scipy), checked at the points themselves."""
    worst = np.inf
    for point, t in zip(route.points[1:-1], route.times[1:-1], strict=True):
        f = forecast_of(np.array([t]))
        for j, o in enumerate(obstacles):
            d = np.linalg.norm(point - f.means[0, j])
            p = scipy_avoid_probability(d, f.sigma[0, j], o.radius + r_min + clearance, n)
            worst = min(worst, p - level)
    return worst


def test_route_goes_around_a_pocket():
    """Three obstacles in a U around the straight line, open towards the start: the route
    leaves the line, every point keeps the avoid level (scipy), and it ends at the goal."""
    obstacles = [static((4.0, 0.0), 0.6), static((3.2, 1.0), 0.6), static((3.2, -1.0), 0.6)]
    guide = settings(3)
    forecast = ScriptedForecast(obstacles, 2)
    route = planner_for(obstacles, guide).plan(
        np.zeros(2), np.array([8.0, 0.0]), 0.0, forecast(guide.knots)
    )
    assert route.reached
    assert np.array_equal(route.points[-1], [8.0, 0.0])
    assert np.max(np.abs(route.points[:, 1])) > 1.5  # around the U, not through it
    # cell centres lie within half a diagonal of the exact free set: allow that rounding
    assert route_is_free(route, forecast, obstacles, 0.99, 0.1 - 0.08, 0.1, 2) >= 0.0


def test_route_waits_for_a_crossing_obstacle():
    """An obstacle crossing the straight line at the time the tube would get there, with
    walls of static obstacles closing the way around: the route waits, then crosses behind
    it; at its own times every point keeps the avoid level."""
    crossing = static((3.0, -6.0), 0.4, sigma=0.05, velocity=(0.0, 1.0))
    wall = [static((3.0, y), 0.4, sigma=0.05) for y in (-2.6, 2.6, -3.4, 3.4)]
    obstacles = [crossing, *wall]
    guide = settings(5, margin=1.0)
    forecast = ScriptedForecast(obstacles, 2)
    route = planner_for(obstacles, guide).plan(
        np.zeros(2), np.array([6.0, 0.0]), 0.0, forecast(guide.knots)
    )
    assert route.reached
    straight = 6.0 / guide.speed
    assert route.times[-1] > straight + 1.0  # it waited
    assert route_is_free(route, forecast, obstacles, 0.99, 0.1 - 0.08, 0.1, 2) >= 0.0


def test_compiled_search_is_the_python_search():
    obstacles = [static((4.0, 0.0), 0.6), static((3.2, 1.0), 0.6), static((3.2, -1.0), 0.6)]
    guide = settings(3, resolution=0.25)
    forecast = ScriptedForecast(obstacles, 2)(guide.knots)
    planner = planner_for(obstacles, guide)
    compiled = planner.plan(np.zeros(2), np.array([8.0, 0.0]), 0.0, forecast)
    with backend.pure_numpy():
        reference = planner.plan(np.zeros(2), np.array([8.0, 0.0]), 0.0, forecast)
    assert np.array_equal(compiled.points, reference.points)
    assert np.allclose(compiled.times, reference.times, rtol=0, atol=1e-12)


def test_budget_gives_the_best_partial_route():
    obstacles = [static((4.0, 0.0), 0.6)]
    guide = settings(1, max_expansions=20)
    route = planner_for(obstacles, guide).plan(
        np.zeros(2), np.array([8.0, 0.0]), 0.0, ScriptedForecast(obstacles, 2)(guide.knots)
    )
    assert not route.reached
    assert 0 < np.linalg.norm(route.points[-1]) < 8.0


def test_stalled_regions_are_avoided():
    guide = settings(1)
    obstacles = [static((50.0, 50.0))]  # far away: a free field
    planner = planner_for(obstacles, guide)
    forecast = ScriptedForecast(obstacles, 2)(guide.knots)
    free = planner.plan(np.zeros(2), np.array([6.0, 0.0]), 0.0, forecast)
    assert np.max(np.abs(free.points[:, 1])) < 0.2
    avoided = planner.plan(
        np.zeros(2), np.array([6.0, 0.0]), 0.0, forecast, avoid=np.array([[3.0, 0.0, 1.0]])
    )
    distance = np.linalg.norm(avoided.points - [3.0, 0.0], axis=1)
    assert np.min(distance) >= 1.0 - 0.1


def test_scripted_forecast_follows_motion_and_schedule():
    obstacle = static((0.0, 0.0), velocity=(1.0, 0.5))
    obstacle.sigma_schedule = SigmaSchedule(times=[0.0, 2.0], values=[0.1, 0.3])
    f = ScriptedForecast([obstacle], 2)(np.array([0.0, 1.0, 4.0]))
    assert np.allclose(f.means[:, 0], [[0, 0], [1, 0.5], [4, 2]])
    assert np.allclose(f.sigma[:, 0], [0.1, 0.2, 0.3])


@pytest.mark.parametrize("adaptive", [False, True])
def test_tracked_forecast_is_the_trackers_own_prediction(adaptive):
    """... with the track's own process density: an adaptive tracker's raised one too."""
    adaptation = Adaptation(2) if adaptive else None
    tracker = KalmanTracker(2, 0.05, 0.01 * np.eye(2), 1.0, 1.0, adaptation=adaptation)
    tracks = tracker.empty(2)
    state = tracks.state.copy()
    state[0] = [1.0, 2.0, 0.5, -0.2]
    covariance = tracks.covariance.copy()
    covariance[0] = np.diag([0.01, 0.02, 0.3, 0.1])
    tracks = dataclasses.replace(
        tracks,
        state=state,
        covariance=covariance,
        detection_time=np.array([1.0, -np.inf]),
        active=np.array([True, False]),
    )
    if adaptive:  # a track whose noise was raised 40-fold by a manoeuvre
        tracks = dataclasses.replace(tracks, scale=np.array([40.0, 1.0]))
    times = np.array([1.5, 3.0, 10.0])
    f = tracked_forecast(tracker, tracks, times)
    for k, t in enumerate(times):
        belief = tracker.belief(tracks, t)
        assert np.allclose(f.means[k, 0], belief.mean[0])
        assert f.sigma[k, 0] == pytest.approx(np.sqrt(np.linalg.eigvalsh(belief.covariance[0])[-1]))
    assert np.all(f.sigma[:, 1] == 0.0) and not f.active[1]
    assert np.all(np.diff(f.sigma[:, 0]) > 0)  # the prediction grows less certain


def test_attraction_point_leads_waits_and_ends_at_the_goal():
    points = np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 3.0]])
    times = np.array([0.0, 6.0, 12.0])  # 0.5 m/s
    route = Route(points, times, True, 0)
    guide = settings(1, lookahead=1.0, speed=0.5)  # η leads by (1/2)/0.5 = 1 s of route
    eta, nearest = attraction_point(route, np.zeros(2), 0.0, guide, 0.0)
    assert np.allclose(eta, [0.5, 0.0]) and nearest == 0.0
    # far behind the route's clock: no more than one look-ahead ahead of the tube
    eta, _ = attraction_point(route, np.array([0.2, 0.0]), 5.0, guide, 0.0)
    assert np.allclose(eta, [1.2, 0.0])
    # ahead of the route's clock: η waits where the route is (the nearest point)
    eta, _ = attraction_point(route, np.array([2.0, 0.0]), 0.0, guide, 0.0)
    assert np.allclose(eta, [2.0, 0.0])
    # never back along the route, even if the centre is pushed back
    eta, nearest = attraction_point(route, np.array([2.5, 0.3]), 5.5, guide, 0.0)
    eta_back, _ = attraction_point(route, np.array([1.0, 0.5]), 5.5, guide, nearest)
    assert eta_back[0] >= 1.0
    # at the end: the goal itself
    eta, _ = attraction_point(route, np.array([3.0, 2.9]), 20.0, guide, 5.9)
    assert np.array_equal(eta, [3.0, 3.0])


def test_attraction_point_on_the_last_leg_is_the_goal_unless_ahead_of_the_clock():
    """On the route's last straight leg to the goal η is the goal (the centre runs at its
    own speed, as without a guide), except when the centre is ahead of the route's clock:
    then it waits where the route is, as on every other leg."""
    route = Route(np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 3.0]]), np.array([0.0, 6, 12]), True, 0)
    guide = settings(1, lookahead=1.0, speed=0.5)
    eta, _ = attraction_point(route, np.array([3.0, 1.0]), 9.0, guide, 4.0)  # behind
    assert np.array_equal(eta, [3.0, 3.0])
    eta, _ = attraction_point(route, np.array([3.0, 2.0]), 6.0, guide, 5.0)  # ahead
    assert np.allclose(eta, [3.0, 2.0])
    unreached = Route(route.points, route.times, False, 0)  # a route that stops short
    eta, _ = attraction_point(unreached, np.array([3.0, 1.0]), 9.0, guide, 4.0)
    assert np.allclose(eta, [3.0, 2.0])


def test_attraction_point_turns_at_corners_only_near_them():
    """η stops at the route's next corner until the centre is within the corner radius:
    a point beyond it would pull the centre across what the route went around."""
    route = Route(np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0]]), np.array([0.0, 4, 8]), True, 0)
    guide = settings(1, lookahead=1.5, speed=0.5, resolution=0.1)
    eta, _ = attraction_point(route, np.array([1.5, 0.0]), 3.0, guide, 1.5)
    assert np.allclose(eta, [2.0, 0.0])
    eta, _ = attraction_point(route, np.array([1.95, 0.0]), 3.9, guide, 1.9)
    assert eta[1] > 0.5 and eta[0] == pytest.approx(2.0)
