"""Math of the baselines STT is compared with: a chance-constrained CBF-QP and an
artificial potential field (APF). Pure numpy/scipy; the Drake systems are in
:mod:`stt_drake.systems.baselines`.

Both baselines reduce obstacle j's Gaussian belief O_j ~ N(μ_j, Σ_j) to a deterministic
ball around μ_j, of the *inflated radius*

    ρ_j = r_o_j + κ_j σ_j,   κ_j = √(χ²_n⁻¹(ε_j))  (:func:`chance_margin`),
    σ_j = √λ_max(Σ_j)        (a standard deviation, m; :func:`largest_sigma`),

and keep the output y outside it. Unlike STT, both use a *nominal* model of the plant
(:class:`NominalPlant`): the STT controller reads none.

Notation: y output (m), ẏ its velocity, d_j = ‖y − μ_j‖, n̂_j = (y − μ_j)/d_j,
v_j = ẏ − μ̇_j the velocity relative to obstacle j, μ̇_j and ρ̇_j the rates of the belief.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.stats import chi2

#: Distances (m) below which a direction y − μ_j is treated as undefined (taken as 0).
_TINY = 1e-12


def chance_margin(epsilon: ArrayLike, dimension: int) -> np.ndarray:
    """κ = √(χ²_n⁻¹(ε)): the tightening factor of the chance constraint.

    Claim: if O ~ N(μ, σ² I) in R^n and ‖y − μ‖ ≥ r_o + κσ, then P(‖y − O‖ ≥ r_o) ≥ ε.
    Proof: ‖O − μ‖²/σ² ~ χ²_n, so the ball B(μ, κσ) holds O with probability exactly ε.
    For O in that ball, ‖y − O‖ ≥ ‖y − μ‖ − ‖O − μ‖ ≥ r_o + κσ − κσ = r_o (triangle
    inequality), so the obstacle misses y on an event of probability ε.

    This is the standard conservative deterministic reformulation: it gives up the
    probability mass of the ball's outside that also misses y (the exact level set is a
    noncentral-χ² quantile, the one STT's d̂_j uses), in exchange for a margin that does not
    depend on y — which makes the constraint a plain distance ‖y − μ‖ ≥ ρ, smooth and easy
    to put in a CBF or a potential field.

    With a full covariance Σ the baselines use σ = √λ_max(Σ)
    (:func:`stt_drake.core.belief.largest_sigma`); the claim still holds: Σ ⪯ σ² I, so the
    isotropic variable is the anisotropic one plus independent Gaussian noise of covariance
    σ² I − Σ, which by Anderson's inequality only moves mass out of the centred ball
    B(μ, κσ): N(μ, Σ) puts at least probability ε in it.

    Args:
        epsilon: required avoidance probability ε in (0, 1) (scalar or per obstacle);
            ε = 1 gives κ = ∞ (no finite ball holds a Gaussian centre surely).
        dimension: n, the dimension of the output space.

    Returns:
        κ (dimensionless), the shape of `epsilon`.
    """
    return np.sqrt(chi2.ppf(np.asarray(epsilon, dtype=float), dimension))


def _directions(y: np.ndarray, mean: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """d_j = ‖y − μ_j‖ (k,) and n̂_j = (y − μ_j)/d_j (k, n) (0 where d_j = 0)."""
    offset = y - mean
    distance = np.linalg.norm(offset, axis=1)
    return distance, offset / np.maximum(distance, _TINY)[:, None]


@dataclass(frozen=True)
class NominalPlant:
    """What a baseline believes the plant is; the true parameters may differ.

    order 1 (omni robot, velocity interface): ẏ = u, u a velocity (m/s).
    order 2 (quadrotor): m ÿ = u − m g e_n − c_d ẏ, u a force (N), e_n the last axis
    (up); m = 1, c_d = 0, g = 0 is a double integrator commanded in acceleration (m/s²).
    Written as ÿ = u/m + f(ẏ), f(ẏ) = −g e_n − (c_d/m) ẏ.

    Attributes:
        order: 1 or 2.
        mass: nominal m (kg), order 2.
        drag: nominal linear drag c_d (N·s/m), order 2.
        gravity: nominal g (m/s²), order 2.
    """

    order: int
    mass: float = 1.0
    drag: float = 0.0
    gravity: float = 0.0

    def __post_init__(self) -> None:
        if self.order not in (1, 2):
            raise ValueError(f"NominalPlant: order must be 1 or 2, got {self.order}")
        if self.mass <= 0.0 or self.drag < 0.0 or self.gravity < 0.0:
            raise ValueError(
                f"NominalPlant: need mass > 0, drag ≥ 0, gravity ≥ 0 (got {self.mass}, "
                f"{self.drag}, {self.gravity})"
            )

    def drift(self, velocity: np.ndarray) -> np.ndarray:
        """f(ẏ) = −g e_n − (c_d/m) ẏ (m/s²), order 2."""
        acceleration = -(self.drag / self.mass) * velocity
        acceleration[-1] -= self.gravity
        return acceleration

    def command_for_acceleration(
        self, acceleration: np.ndarray, velocity: np.ndarray
    ) -> np.ndarray:
        """The order-2 input u = m (a − f(ẏ)) that gives ÿ = a in the nominal model."""
        return self.mass * (acceleration - self.drift(velocity))

    def command_for_velocity(
        self, desired_velocity: np.ndarray, velocity: np.ndarray, velocity_gain: float
    ) -> np.ndarray:
        """The input that tracks a desired velocity v_d: order 1, u = v_d; order 2,
        a = k_v (v_d − ẏ) (k_v = `velocity_gain`, 1/s) and u = m (a − f(ẏ))."""
        if self.order == 1:
            return desired_velocity
        return self.command_for_acceleration(
            velocity_gain * (desired_velocity - velocity), velocity
        )


def saturate_norm(vector: np.ndarray, limit: float) -> np.ndarray:
    """v scaled down to ‖v‖ ≤ limit (direction kept)."""
    norm = float(np.linalg.norm(vector))
    return vector if norm <= limit else vector * (limit / norm)


@dataclass(frozen=True)
class GoalSeeking:
    """The nominal controller of the CBF-QP: a saturated proportional velocity towards
    the goal η, v_d = sat_{v_max}(−k_p (y − η)), tracked through the nominal plant
    (:meth:`NominalPlant.command_for_velocity`).

    Attributes:
        goal: η (n,), m.
        position_gain: k_p (1/s).
        max_speed: v_max (m/s).
        velocity_gain: k_v (1/s), order 2 only.
    """

    goal: np.ndarray
    position_gain: float = 1.0
    max_speed: float = 1.0
    velocity_gain: float = 4.0

    def command(self, plant: NominalPlant, y: np.ndarray, velocity: np.ndarray) -> np.ndarray:
        """u_nom for output y and velocity ẏ (ignored for order 1)."""
        desired = saturate_norm(-self.position_gain * (y - self.goal), self.max_speed)
        return plant.command_for_velocity(desired, velocity, self.velocity_gain)


def first_order_cbf_rows(
    y: np.ndarray,
    mean: np.ndarray,
    mean_velocity: np.ndarray,
    rho: np.ndarray,
    rho_rate: np.ndarray,
    rate: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CBF rows A u ≥ b for ẏ = u, one per obstacle given (k of them).

    h_j = d_j − ρ_j, ∇_y h_j = n̂_j, and along the motion
    ḣ_j = n̂_j·(u − μ̇_j) − ρ̇_j. The CBF condition ḣ_j + α h_j ≥ 0 (α = `rate`, 1/s) is

        n̂_j·u ≥ n̂_j·μ̇_j + ρ̇_j − α h_j.

    Args:
        y: (n,) output, m. mean: (k, n) μ_j, m. mean_velocity: (k, n) μ̇_j, m/s.
        rho: (k,) ρ_j, m. rho_rate: (k,) ρ̇_j, m/s. rate: α > 0, 1/s.

    Returns:
        A (k, n), b (k,) and h (k,) (m).
    """
    distance, normal = _directions(y, mean)
    h = distance - rho
    b = np.einsum("kn,kn->k", normal, mean_velocity) + rho_rate - rate * h
    return normal, b, h


def second_order_cbf_rows(
    y: np.ndarray,
    velocity: np.ndarray,
    mean: np.ndarray,
    mean_velocity: np.ndarray,
    rho: np.ndarray,
    rho_rate: np.ndarray,
    rate: float,
    plant: NominalPlant,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exponential-CBF rows A u ≥ b for ÿ = u/m + f(ẏ) (:class:`NominalPlant`).

    With h_j = d_j − ρ_j and v_j = ẏ − μ̇_j, treating μ̇_j and ρ̇_j as constant over the
    step (μ̈_j = ρ̈_j = 0):

        ḣ_j = n̂_j·v_j − ρ̇_j,
        ḧ_j = n̂_j·(ÿ − μ̈_j) + (‖v_j‖² − (n̂_j·v_j)²)/d_j − ρ̈_j,

    the second term the exact curvature of the distance function (d/dt n̂_j =
    (v_j − (n̂_j·v_j) n̂_j)/d_j). The exponential CBF ḧ_j + k1 ḣ_j + k0 h_j ≥ 0 with a
    double pole at −p (p = `rate`, 1/s: k1 = 2p, k0 = p²) keeps h_j ≥ 0 when it holds
    and ḣ_j(0) + p h_j(0) ≥ 0 at the start. Linear in u:

        (n̂_j/m)·u ≥ −n̂_j·f(ẏ) − (‖v_j‖² − (n̂_j·v_j)²)/d_j − k1 ḣ_j − k0 h_j.

    Args:
        y, velocity: (n,) output (m) and its velocity (m/s). mean, mean_velocity: (k, n).
        rho, rho_rate: (k,). rate: p > 0, 1/s. plant: the nominal model (order 2).

    Returns:
        A (k, n), b (k,) and h (k,) (m).
    """
    distance, normal = _directions(y, mean)
    h = distance - rho
    relative = velocity - mean_velocity
    along = np.einsum("kn,kn->k", normal, relative)
    h_dot = along - rho_rate
    curvature = (np.einsum("kn,kn->k", relative, relative) - along**2) / np.maximum(distance, _TINY)
    b = -normal @ plant.drift(velocity) - curvature - 2.0 * rate * h_dot - rate**2 * h
    return normal / plant.mass, b, h


@dataclass(frozen=True)
class PotentialField:
    """Artificial potential field (Khatib 1986) around the inflated balls B(μ_j, ρ_j).

    U(y) = U_att(y) + Σ_j U_rep,j(y), with e = y − η and d_j = ‖y − μ_j‖ − ρ_j:

        U_att = ½ k_att ‖e‖²                         for ‖e‖ ≤ d_s,
              = k_att d_s ‖e‖ − ½ k_att d_s²          beyond (conic: the attraction
                                                      −k_att e saturated at k_att d_s),
        U_rep,j = ½ k_rep (1/d_j − 1/d0)²             for d_j < d0, else 0,

    and the field is F = −∇U:

        −∇U_att = −k_att e · min(1, d_s/‖e‖),
        −∇U_rep,j = k_rep (1/d_j − 1/d0) (1/d_j²) n̂_j   (d_j < d0).

    Inside an inflated ball (d_j ≤ d_min) U is infinite; the field then uses d_j = d_min
    (the largest push, away from μ_j) so the controller still has a command.

    Attributes:
        goal: η (n,), m.
        attraction_gain: k_att (1/s when F is read as a velocity).
        attraction_distance: d_s (m).
        repulsion_gain: k_rep (m⁴/s when F is a velocity).
        influence_distance: d0 (m).
        minimum_distance: d_min (m).
    """

    goal: np.ndarray
    attraction_gain: float = 1.0
    attraction_distance: float = 1.0
    repulsion_gain: float = 0.05
    influence_distance: float = 1.0
    minimum_distance: float = 1e-3

    def potential(self, y: np.ndarray, mean: np.ndarray, rho: np.ndarray) -> float:
        """U(y) (for d_j > 0); mean (k, n), rho (k,)."""
        k, d_s = self.attraction_gain, self.attraction_distance
        error = float(np.linalg.norm(y - self.goal))
        attraction = 0.5 * k * error**2 if error <= d_s else k * d_s * error - 0.5 * k * d_s**2
        distance = np.linalg.norm(y - mean, axis=1) - rho
        near = distance < self.influence_distance
        excess = 1.0 / distance[near] - 1.0 / self.influence_distance
        return attraction + 0.5 * self.repulsion_gain * float(np.sum(excess**2))

    def field(self, y: np.ndarray, mean: np.ndarray, rho: np.ndarray) -> np.ndarray:
        """F = −∇U(y) (n,), with d_j floored at d_min; mean (k, n), rho (k,)."""
        error = y - self.goal
        attraction = -self.attraction_gain * saturate_norm(error, self.attraction_distance)
        center_distance, normal = _directions(y, mean)
        distance = np.maximum(center_distance - rho, self.minimum_distance)
        magnitude = np.where(
            distance < self.influence_distance,
            self.repulsion_gain * (1.0 / distance - 1.0 / self.influence_distance) / distance**2,
            0.0,
        )
        return attraction + magnitude @ normal
