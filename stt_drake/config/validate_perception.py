"""The rules of the scenario's `perception:` section (:class:`stt_drake.config.schema.Perception`),
checked by :func:`stt_drake.config.validate.validate` after the obstacles: at least one
obstacle to perceive; finite, non-negative densities, range and latency; periods > 0; one
noise model per pair (:func:`check_noise_fields`); valid noise covariances; a sensor that
can get a detection to the tracker before the run ends; a track timeout longer than a
detection's way to the tracker; a boolean `adaptive`, an integer `nis_window` in
[1, MAX_NIS_WINDOW] and `nis_confidence` in (0, 1); and a continuous-time tube. Every
broken rule raises :class:`stt_drake.config.schema.ScenarioError` naming
``scenario.perception.<field>``, the rule and the value. What the chain allocates and
costs is bounded before anything is drawn, by :func:`stt_drake.config.limits.check_limits`
(:mod:`stt_drake.config.perception_budget`).
"""

import math

from stt_drake.config.covariance import require_covariance
from stt_drake.config.limits import require
from stt_drake.config.schema import Perception, Scenario, ScenarioError

#: The pairs of fields that describe one noise model two ways: a file may write one of each.
NOISE_PAIRS = (
    ("noise_sigma", "noise_covariance"),
    ("tracker_noise_sigma", "tracker_noise_covariance"),
)

#: The largest NIS window (values kept per track in the tracker's discrete state).
MAX_NIS_WINDOW = 1000


def check_noise_fields(given: list[str], path: str) -> None:
    """Of each pair of :data:`NOISE_PAIRS`, at most one among the fields `given` (the names
    the file wrote with a value): with both, the covariance would win silently.

    Raises:
        ScenarioError: naming the second field of the pair and both names.
    """
    for sigma, covariance in NOISE_PAIRS:
        if sigma in given and covariance in given:
            raise ScenarioError(
                f"{path}.{covariance}: {sigma} and {covariance} are both given: give one "
                f"of them (one model of the noise; with both, {covariance} would be used "
                f"and {sigma} ignored)"
            )


def first_tracked_time(perception: Perception) -> float:
    """The earliest time (s) a detection can reach a track: the sample taken at t = 0 is
    delivered at t = latency, and the tracker updates at the delivery times
    (:class:`stt_drake.systems.perception.ObstacleTracker` with offset = latency), so it
    is tracked from t = latency on."""
    return perception.latency


def validate_perception(perception: Perception, scenario: Scenario) -> None:
    """The `perception:` section (module docstring); raise ScenarioError."""
    path = "scenario.perception"
    n = scenario.dimension
    require(
        len(scenario.obstacles) > 0,
        path,
        "perception needs at least one obstacle (its sensor and tracker have nothing to "
        "perceive: drop the perception section for a scenario without obstacles)",
        f"{len(scenario.obstacles)} obstacles",
    )
    for name in ("process_noise_density", "sensing_range", "latency"):
        value = getattr(perception, name)
        require(0.0 <= value < math.inf, f"{path}.{name}", "must be finite and ≥ 0", value)
    for name in ("truth_period", "sensor_period", "initial_velocity_sigma", "track_timeout"):
        value = getattr(perception, name)
        require(0.0 < value < math.inf, f"{path}.{name}", "must be finite and > 0", value)
    require(
        0.0 <= perception.dropout_probability < 1.0,
        f"{path}.dropout_probability",
        "must be in [0, 1) (1 would never detect anything)",
        perception.dropout_probability,
    )
    duration = scenario.duration
    require(
        perception.sensor_period < duration,
        f"{path}.sensor_period",
        f"must be below duration = {duration:g} s: a longer period takes one sample, at "
        "t = 0, and the track is lost after track_timeout, so the tube would run blind past "
        "every true obstacle",
        perception.sensor_period,
    )
    first = first_tracked_time(perception)
    require(
        first < duration,
        f"{path}.latency",
        f"must let a detection reach the tracker before the end: the first one, taken at "
        f"t = 0, is delivered and tracked at t = latency = {first:g} s, not before "
        f"duration = {duration:g} s, so no track would ever be born",
        perception.latency,
    )
    density = perception.tracker_process_density
    require(
        density is None or 0.0 <= density < math.inf,
        f"{path}.tracker_process_density",
        "must be finite and ≥ 0 (m²/s³)",
        density,
    )
    given = [
        name for pair in NOISE_PAIRS[1:] for name in pair if getattr(perception, name) is not None
    ]
    check_noise_fields(given, path)
    for name in ("noise_sigma", "tracker_noise_sigma"):
        value = getattr(perception, name)
        if value is not None:
            require(0.0 < value < math.inf, f"{path}.{name}", "must be finite and > 0 (m)", value)
    for name in ("noise_covariance", "tracker_noise_covariance"):
        matrix = getattr(perception, name)
        if matrix is not None:
            require_covariance(matrix, n, f"{path}.{name}")
    require(
        0.0 <= perception.blend_time <= perception.sensor_period,
        f"{path}.blend_time",
        f"must be in [0, sensor_period = {perception.sensor_period:g}] s (a blend ends "
        "before the next correction)",
        perception.blend_time,
    )
    way = perception.sensor_period + perception.latency
    require(
        perception.track_timeout > way,
        f"{path}.track_timeout",
        f"must exceed sensor_period + latency = {way:g} s (the time between two deliveries "
        "of a track's detections), or every new track is lost at once",
        perception.track_timeout,
    )
    require(
        isinstance(perception.adaptive, bool),
        f"{path}.adaptive",
        "must be true or false",
        perception.adaptive,
    )
    window = perception.nis_window
    require(
        isinstance(window, int) and not isinstance(window, bool) and 1 <= window <= MAX_NIS_WINDOW,
        f"{path}.nis_window",
        f"must be an integer in [1, {MAX_NIS_WINDOW}] (the corrections the NIS test sums; "
        "each is kept per track in the tracker's state)",
        window,
    )
    confidence = perception.nis_confidence
    require(
        0.0 < confidence < 1.0,
        f"{path}.nis_confidence",
        "must be in (0, 1) (the probability of the NIS test's two-sided χ² interval)",
        confidence,
    )
    require(
        scenario.tube.update_rate_hz == 0.0,
        "scenario.tube.update_rate_hz",
        "must be 0 (continuous time) with perception: the fixed-rate tube's period guarantee "
        "needs bounds on how fast the belief moves, which a tracker's corrections do not have",
        scenario.tube.update_rate_hz,
    )
