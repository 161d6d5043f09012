"""The scenario schema: the dataclasses one YAML file is loaded into (``diagrams/*.yaml``).
An obstacle is the core's :class:`stt_drake.core.obstacle.Obstacle` (the type the Python API
builds obstacles with), re-exported here.

Loaded by :mod:`stt_drake.config.load` with ``pydrake.common.yaml.yaml_load_typed`` and
checked by :mod:`stt_drake.config.validate`; the rules that need the built laws or the
arm model are in :mod:`stt_drake.assembly.checks`.
"""

import math
from dataclasses import dataclass, field
from typing import Union

import numpy as np
from pydrake.systems.analysis import SimulatorConfig

from stt_drake.config.lcm import LcmConfig
from stt_drake.core.belief import ObstacleBelief, obstacle_belief
from stt_drake.core.consistency import Adaptation, density_bounds
from stt_drake.core.obstacle import Obstacle
from stt_drake.core.tube import default_nu


class ScenarioError(ValueError):
    """A scenario file breaks a rule; the message names the field path and the rule.

    The message is always one line (line breaks in it, e.g. from a YAML parser, become
    spaces) and at most :data:`MAX_MESSAGE_LENGTH` characters."""

    def __init__(self, message: object = "") -> None:
        text = " ".join(part.strip() for part in str(message).splitlines() if part.strip())
        if len(text) > MAX_MESSAGE_LENGTH:
            text = text[: MAX_MESSAGE_LENGTH - 3] + "..."
        super().__init__(text)


#: Longest :class:`ScenarioError` message (characters).
MAX_MESSAGE_LENGTH = 2000


class AssumptionError(ScenarioError):
    """The file is well formed, but what it describes breaks one of the paper's assumptions
    (random obstacles that cannot be placed clear of start and target, an initial
    avoidance condition q_j(s, 0) > ε_j that fails): a randomisation campaign counts such a
    draw as rejected, not as a failure."""


@dataclass
class RandomObstacles:
    """A field of oscillating obstacles drawn from a seeded generator.

    Means are uniform in [region_min, region_max]; sigma, epsilon, oscillation amplitude
    (per axis) and frequency are uniform in their [low, high] ranges. A draw is kept only
    if its whole path stays clear of the start and the target with probability ≥ p_d
    (checked with the buffered radius r_o + r_min; Assumption 3 and the initial
    condition of Definition 2.3). `count_range` = [low, high], when given instead of `count`,
    draws the number of obstacles uniformly from those integers (randomisation campaigns).
    A file that draws obstacles must give `sigma_range`, `epsilon_range` and `p_d` (no
    invented uncertainty or risk level; the defaults only serve Drake's loader).
    """

    count: int = 0
    count_range: list[int] = field(default_factory=list)
    seed: int = 0
    region_min: list[float] = field(default_factory=list)
    region_max: list[float] = field(default_factory=list)
    radius: float = 0.3
    sigma_range: list[float] = field(default_factory=lambda: [0.1, 1.0])
    epsilon_range: list[float] = field(default_factory=lambda: [0.7, 0.99])
    p_d: float = 0.9999
    amplitude_range: list[float] = field(default_factory=lambda: [0.0, 1.0])
    frequency_range_hz: list[float] = field(default_factory=lambda: [0.01, 0.05])


@dataclass
class TubeConfig:
    """Tube law constants (Eqs. (4) and (14)). `nu` = 0 means "derive it":
    ν = 2 ln(n_o + 1)/r_min, which keeps r ≥ r_min/2 (without obstacles, where r = r_max
    whatever ν, as for one obstacle: 2 ln 2/r_min). `update_rate_hz` = 0 integrates the
    centre in continuous time; > 0 runs the fixed-rate (real-time) discrete update.
    `max_center_speed` (m/s) bounds |ċ| always, and is the speed of a recovery (0 derives
    it from what the plant can follow, see
    :func:`stt_drake.assembly.feasibility.following_speed`)."""

    r_min: float = 0.1
    r_max: float = 0.3
    k1: float = 0.5
    k2: float = 0.4
    k3: float = 0.4
    nu: float = 0.0
    update_rate_hz: float = 0.0
    max_center_speed: float = 0.0


@dataclass
class FunnelConfig:
    """Box funnel γ(t) = (start − end)e^{−rate t} + end of one stage k ≥ 2 (per axis)."""

    start: list[float] = field(default_factory=list)
    end: list[float] = field(default_factory=list)
    rate: list[float] = field(default_factory=list)


@dataclass
class ControllerConfig:
    """Funnel controller gains κ_1..κ_N and the box funnels of stages 2..N."""

    kappa: list[float] = field(default_factory=lambda: [1.0])
    funnels: list[FunnelConfig] = field(default_factory=list)


@dataclass
class OmniRobot:
    """Three-wheel omnidirectional base. True wheel and base radii differ from the nominal
    ones its drive interface uses; the STT controller knows neither. `disturbance_amplitude`
    (m/s per world axis) and `disturbance_frequency_hz` set an additive sinusoidal
    velocity disturbance. `initial_position` defaults to the scenario's start."""

    wheel_radius: float = 0.052
    base_radius: float = 0.21
    nominal_wheel_radius: float = 0.05
    nominal_base_radius: float = 0.2
    heading_gain: float = 2.0
    initial_heading: float = 0.0
    initial_position: list[float] = field(default_factory=list)
    disturbance_amplitude: list[float] = field(default_factory=lambda: [0.0, 0.0])
    disturbance_frequency_hz: float = 0.2


@dataclass
class Quadrotor:
    """UAV as a second-order point mass in 3D (case study 2): m·v̇ = u − m·g·e_z − c_d·v + w.

    `mass` (kg), `drag` (linear drag c_d, N·s/m) and `gravity` (m/s²) are the true values;
    the STT controller knows none of them. `initial_position` defaults to the start;
    `initial_velocity` (m/s) must lie inside stage 2's first box funnel. The wind is a
    bounded force (N): per axis i, w_i(t) = A_i/K · Σ_k sin(2π f_k t + φ_ik) over the K
    `wind_frequencies_hz`, so |w_i| ≤ A_i = `wind_amplitude[i]`; the phases φ_ik are drawn
    from the scenario seed. `body_radius` (m) only sizes the Meshcat visual.
    """

    mass: float = 1.0
    drag: float = 0.2
    gravity: float = 9.81
    initial_position: list[float] = field(default_factory=list)
    initial_velocity: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    wind_amplitude: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    wind_frequencies_hz: list[float] = field(default_factory=lambda: [0.1])
    body_radius: float = 0.25


@dataclass
class ArmJerk:
    """One impulsive external push on an arm link: a half-sine force pulse of peak `force`
    (N, world frame) at `point` (m, in the link frame) on `link`, from `time` for `duration`
    seconds. `link` is one of fr3_link1..fr3_link7 or fr3_hand."""

    time: float = 0.0
    duration: float = 0.1
    link: str = "fr3_link7"
    force: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    point: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])


#: libfranka's start ("ready") configuration of the FR3, rad.
_FR3_READY = (0.0, -math.pi / 4, 0.0, -3 * math.pi / 4, 0.0, math.pi / 2, math.pi / 4)


@dataclass
class FrankaArm:
    """Franka Research 3 arm with a welded Franka Hand (case study 3); y = the hand's TCP.

    Robot: `initial_configuration` q(0) (rad, at rest); `gravity_compensation`: the robot
    interface adds g(q) of the robot's own model to the commanded torque, as the real FR3
    does (false: the STT controller alone carries the arm's weight); `jerks`: external
    pushes. Task: the tube visits the `waypoints` (m, in order) and then the scenario's
    `target`, one reach-avoid-stay task each; a task is done when Γ(t) ⊂ B(η_k,
    target_set_radius) held for `hold_time` seconds. Controller mapping (kinematics only):
    damped least squares with `jacobian_damping` λ (m), and a null-space term pulling to the
    home posture with `posture_gain` (1/s) and away from joint limits within `limit_margin`
    (rad) at up to `limit_gain` (rad/s).
    """

    initial_configuration: list[float] = field(default_factory=lambda: list(_FR3_READY))
    gravity_compensation: bool = True
    waypoints: list[list[float]] = field(default_factory=list)
    hold_time: float = 0.3
    jacobian_damping: float = 0.02
    posture_gain: float = 1.0
    limit_margin: float = 0.25
    limit_gain: float = 1.0
    jerks: list[ArmJerk] = field(default_factory=list)


# OmniRobot first: an untagged `plant:` mapping is an OmniRobot (Drake's yaml takes the
# first variant); a UAV is written `plant: !Quadrotor {...}`, the arm `plant: !FrankaArm`.
Plant = Union[OmniRobot, Quadrotor, FrankaArm]  # noqa: UP007 (drake yaml needs typing.Union)

#: Output-space dimension each plant works in.
PLANT_DIMENSION = {OmniRobot: 2, Quadrotor: 3, FrankaArm: 3}

#: Number of stages N of Eq. (1) each plant has: the controller needs N gains κ and
#: N − 1 box funnels.
PLANT_STAGES = {OmniRobot: 1, Quadrotor: 2, FrankaArm: 2}

#: Size of the box funnels of stages 2..N where it is not n: the arm's stage 2 is on its
#: 7 joint velocities.
PLANT_FUNNEL_DIMENSION = {FrankaArm: 7}


@dataclass
class Perception:
    """Perception in the loop (:mod:`stt_drake.systems.perception`): the obstacles' true
    centres, a sensor and a Kalman tracker replace the scripted belief.

    Truth: O_j(t) = (the obstacle's `motion`)(t) + δ_j(t), δ driven by white acceleration
    noise of spectral density `process_noise_density` (m²/s³ per axis; 0: the motion
    exactly), drawn on a grid of `truth_period` seconds. Sensor: every `sensor_period`
    seconds, each obstacle within `sensing_range` metres of the robot (0: everywhere) is
    detected unless dropped (probability `dropout_probability`), at its true centre plus
    Gaussian noise of standard deviation `noise_sigma` (m, isotropic) or covariance
    `noise_covariance` (n×n, m²) — a file writes one of the two (the loader refuses both:
    :func:`stt_drake.config.validate_perception.check_noise_fields`) —, delivered `latency`
    seconds later (the first detection must reach the tracker before the run ends). Tracker: one
    constant-velocity Kalman filter per obstacle with white-acceleration density
    `tracker_process_density` (m²/s³) and measurement noise `tracker_noise_sigma` (m) or
    `tracker_noise_covariance` (m²; one of the two) — by default the true ones (a
    calibrated tracker) —
    new tracks with velocity standard deviation `initial_velocity_sigma` (m/s), lost after
    `track_timeout` seconds without a detection; after a correction the published belief
    moves to the new track over `blend_time` seconds (≤ sensor_period; 0: it jumps, and the
    tube recovers from the jump). `full_covariance`: the tube uses each
    track's Σ exactly (else σ² = λ_max(Σ), exact only for isotropic noise models).
    Consistency (:mod:`stt_drake.core.consistency`): at each correction the tracker takes the
    track's normalised innovation squared ν = yᵀS⁻¹y and tests the sum of the last
    `nis_window` values (W ≥ 1) against the two-sided χ² interval of W·n degrees of freedom
    with probability `nis_confidence` (in (0, 1)); a run reports per track the NIS mean,
    the episodes above the interval (the track overconfident) and the calibration against
    the true centres, and warns when a track was inconsistent. With `adaptive` (the
    default) each track's white-acceleration density is scaled up when its NIS is high
    and relaxes back to the model's own when it is consistent again (a model density of 0
    is scaled from a small floor); `adaptive: false` is the constant-velocity filter
    exactly. Draws come from the scenario's `seed`. At least one obstacle is needed; what the chain
    draws and holds counts in the memory budget (:mod:`stt_drake.config.perception_budget`)."""

    process_noise_density: float = 0.0
    truth_period: float = 0.01
    sensor_period: float = 0.1
    noise_sigma: float = 0.05
    noise_covariance: list[list[float]] | None = None
    dropout_probability: float = 0.0
    sensing_range: float = 0.0
    latency: float = 0.0
    tracker_process_density: float | None = None
    tracker_noise_sigma: float | None = None
    tracker_noise_covariance: list[list[float]] | None = None
    initial_velocity_sigma: float = 1.0
    track_timeout: float = 1.0
    blend_time: float = 0.1
    full_covariance: bool = True
    adaptive: bool = True
    nis_window: int = 10
    nis_confidence: float = 0.95

    def noise(self, dimension: int) -> np.ndarray:
        """The sensor's true noise covariance R (n×n, m²)."""
        if self.noise_covariance is not None:
            return np.asarray(self.noise_covariance, dtype=float)
        return self.noise_sigma**2 * np.eye(dimension)

    def tracker_noise(self, dimension: int) -> np.ndarray:
        """The noise covariance the tracker assumes (m²; default: the true one)."""
        if self.tracker_noise_covariance is not None:
            return np.asarray(self.tracker_noise_covariance, dtype=float)
        if self.tracker_noise_sigma is not None:
            return self.tracker_noise_sigma**2 * np.eye(dimension)
        return self.noise(dimension)

    def adaptation(self, dimension: int) -> Adaptation:
        """The tracker's NIS test and adaptive process noise (`adaptive`, `nis_window`,
        `nis_confidence`; the density range from the tracker's noise and the sensor period,
        :func:`stt_drake.core.consistency.density_bounds`)."""
        floor, ceiling = density_bounds(self.tracker_noise(dimension), self.sensor_period)
        return Adaptation(
            dimension,
            window=self.nis_window,
            confidence=self.nis_confidence,
            adaptive=self.adaptive,
            density_floor=floor,
            density_ceiling=ceiling,
        )

    def tracker_density(self) -> float:
        """The process density the tracker assumes (m²/s³; default: the true one)."""
        if self.tracker_process_density is None:
            return self.process_noise_density
        return self.tracker_process_density


@dataclass
class GuideConfig:
    """The guide above the tube (:class:`stt_drake.systems.guide.TubeGuide`): a route over
    the obstacles' predicted beliefs whose moving point η(t) the tube is attracted to, while
    the task's target set stays `target`/`target_set_radius`.

    `planner`: ``grid`` (a compiled space-time A* search on a grid of `resolution` metres;
    0 derives it from the arena). The plan is redone every `replan_period` seconds, when a
    track is born or lost and when the tube stalls; η moves every 1/`rate_hz` seconds.
    Predictions reach `horizon` seconds ahead on knots `time_step` seconds apart (later
    times use the last knot). A route point is free at the time the tube would be there when
    every obstacle's avoidance probability P(‖x − O_j‖ ≥ r_o_j + r_min + `clearance`) is at
    least `avoid_level` (0: each obstacle's own p_d); `clearance` (m) defaults to the tube's
    r_max − r_min, so the whole tube fits. The tube is assumed to travel at `speed` (m/s; 0
    derives it from k1 and max_center_speed) and may wait up to `max_wait` seconds at a
    point; η runs `lookahead` metres ahead of the tube along the route at most (0 derives
    it). A stall (the centre makes no progress of `stall_progress` metres toward η for
    `stall_time` seconds; 0 derives the distance: r_min) triggers a replan that avoids the
    stalled region."""

    planner: str = "grid"
    rate_hz: float = 10.0
    replan_period: float = 1.0
    horizon: float = 20.0
    time_step: float = 0.2
    resolution: float = 0.0
    avoid_level: float = 0.0
    clearance: float | None = None
    speed: float = 0.0
    max_wait: float = 2.0
    lookahead: float = 0.0
    stall_time: float = 4.0
    stall_progress: float = 0.0


@dataclass
class CrowdConfig:
    """A crowd of JuPedSim pedestrians (the `crowd` extra) as the obstacles, drawn afresh
    for every seed (a campaign's runs, ``compare --draws``):

    * `interactive: true`: the crowd steps inside the Diagram
      (:class:`stt_drake.systems.crowd.CrowdSimulator`) as the obstacles' truth, in front
      of the perception chain's sensor (a `perception:` section is required: the belief
      comes from the tracker), and the pedestrians walk around the robot;
    * `interactive: false`: the crowd is simulated at load without the robot, and each
      pedestrian is a recorded track over its time in the scene (as if read from a track
      file of ``stt-drake crowd``): the scripted belief N(track, sigma²I), or a tracker's
      with `perception:`. Every controller of ``stt-drake compare`` can run it.

    `scene`: ``crossing``, ``circle``, ``corridor`` or ``bidirectional``
    (:mod:`stt_drake.crowd.scenes`), with `pedestrians` N, drawn from (`seed`, the
    scenario's seed), desired speeds uniform in `speed_range` (m/s), in `area`
    [x_min, y_min, x_max, y_max] (m; empty: the scene's default), agents of `radius` (m).
    The pedestrians avoid the robot as a disc of `robot_radius` (m; 0: they do not see it);
    the crowd is stepped (or sampled) every `period` seconds. The N pedestrians are the
    scenario's obstacles: N slots with r_o = `radius` + `robot_radius` (a point robot's
    collision disc: the pedestrian's grown by the robot's), the standard deviation `sigma`
    (m; interactive: of the load-time prior only), `epsilon`, `p_d`; `sigma`, `epsilon`
    and `p_d` are required."""

    scene: str = "crossing"
    pedestrians: int = 20
    seed: int = 0
    interactive: bool = True
    area: list[float] = field(default_factory=list)
    radius: float = 0.2
    robot_radius: float = 0.3
    speed_range: list[float] = field(default_factory=lambda: [1.0, 1.4])
    sigma: float | None = None
    epsilon: float | None = None
    p_d: float | None = None
    period: float = 0.05


def default_simulator_config() -> SimulatorConfig:
    """A scenario run's SimulatorConfig when its file gives none: runge_kutta3 with error
    control, accuracy 1e-6, steps of at most 0.01 s."""
    return SimulatorConfig(
        integration_scheme="runge_kutta3",
        max_step_size=0.01,
        accuracy=1e-6,
        use_error_control=True,
    )


@dataclass
class Scenario:
    """One PrT-RAS experiment: task, obstacles, tube, controller, plant, simulation.

    `max_memory_gb` (> 0) replaces the memory budget a run is checked against
    (:mod:`stt_drake.config.limits`; 0: the default or the environment's)."""

    name: str = ""
    start: list[float] = field(default_factory=list)
    initial_set_radius: float = 0.5
    target: list[float] = field(default_factory=list)
    target_set_radius: float = 0.5
    duration: float = 30.0
    seed: int = 0
    obstacles: list[Obstacle] = field(default_factory=list)
    random_obstacles: RandomObstacles | None = None
    tube: TubeConfig = field(default_factory=TubeConfig)
    controller: ControllerConfig = field(default_factory=ControllerConfig)
    plant: Plant = field(default_factory=OmniRobot)
    simulator: SimulatorConfig = field(default_factory=default_simulator_config)
    log_period: float = 0.02
    strict: bool = False
    max_steps_per_second: float = 0.0
    max_memory_gb: float = 0.0
    perception: Perception | None = None
    guide: GuideConfig | None = None
    crowd: CrowdConfig | None = None
    lcm: LcmConfig | None = None  # the LCM bus of `stt-drake station`/`controller`

    @property
    def dimension(self) -> int:
        return len(self.start)

    @property
    def nu(self) -> float:
        """The soft-min sharpness in use (the given one, or the derived default)."""
        if self.tube.nu > 0.0:
            return self.tube.nu
        return default_nu(len(self.obstacles), self.tube.r_min)

    def belief_at(self, t: float) -> ObstacleBelief:
        """The belief of every obstacle at time t."""
        return obstacle_belief(self.obstacles, self.dimension, t)

    def task_targets(self) -> list[np.ndarray]:
        """The reach-avoid-stay targets in order: the arm's waypoints, then `target`."""
        waypoints = getattr(self.plant, "waypoints", [])
        return [np.asarray(p, dtype=float) for p in [*waypoints, self.target]]

    def initial_output(self) -> np.ndarray:
        """y(0): the plant's initial position where given, else the start point s."""
        position = getattr(self.plant, "initial_position", None)
        return np.asarray(position if position else self.start, dtype=float)
