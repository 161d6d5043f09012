"""`stt-drake bench`, the workloads: obstacle fields around a valid tube centre
(:func:`obstacle_field`, :func:`anisotropic_field`) and the baseline the tube step is
measured against (:func:`baseline_tube_step`, the authors' per-obstacle scipy loop)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from scipy.special import ndtri

from stt_drake.core.belief import ObstacleBelief
from stt_drake.core.probability import avoid_probability
from stt_drake.core.tube import TubeLaw, default_nu

#: Obstacle fields with the density, σ and ε ranges of the shipped cluttered scenarios:
#: omni_cluttered_50 (50 obstacles in 28 m × 28 m) and uav_cluttered (40 in a 10 m cube).
FIELDS = {
    2: {
        "side": 28.0,
        "count": 50,
        "sigma": (0.1, 1.0),
        "epsilon": (0.7, 0.99),
        "r_min": 0.1,
        "r_max": 0.8,
        "k": (0.35, 0.4, 0.8),
    },
    3: {
        "side": 10.0,
        "count": 40,
        "sigma": (0.05, 0.45),
        "epsilon": (0.7, 0.95),
        "r_min": 0.3,
        "r_max": 0.9,
        "k": (0.31, 0.03, 0.03),
    },
}
OBSTACLE_RADIUS, P_D = 0.4, 0.9999


def obstacle_field(
    count: int, dimension: int, worst_case: bool = False, seed: int = 0
) -> tuple[TubeLaw, np.ndarray, ObstacleBelief]:
    """A tube law, a valid centre (every q_j > ε_j) and a belief of `count` obstacles.

    typical: means uniform in a cube centred on the centre whose side grows as
    count^{1/n}, so the density stays that of the shipped scenario; draws with q_j ≤ ε_j
    are redrawn. worst case: every obstacle inside its avoidance layer ε_j < q_j ≤ p_d and
    close enough that no quantile can be pruned (the most work a tube step can do).
    """
    spec = FIELDS[dimension]
    rng = np.random.default_rng(seed + 1000 * dimension + count)
    r_min = spec["r_min"]
    law = TubeLaw(
        target=np.full(dimension, 0.35 * spec["side"]),
        k1=spec["k"][0],
        k2=spec["k"][1],
        k3=spec["k"][2],
        r_min=r_min,
        r_max=spec["r_max"],
        nu=default_nu(count, r_min),
        max_center_speed=math.inf,  # the paper's law: no boundary layer
    )
    center = np.zeros(dimension)
    side = spec["side"] * (count / spec["count"]) ** (1.0 / dimension)
    rows: list[tuple[np.ndarray, float, float]] = []
    while len(rows) < count:
        sigma = rng.uniform(*spec["sigma"])
        epsilon = rng.uniform(*spec["epsilon"])
        if worst_case:
            direction = rng.normal(size=dimension)
            distance = OBSTACLE_RADIUS + r_min + sigma * rng.uniform(1.0, 4.0)
            mean = center + distance * direction / np.linalg.norm(direction)
            # The pruning bound σ(a − Φ⁻¹(ε)) − r_o must stay below the threshold.
            prunable = distance - sigma * ndtri(epsilon) - OBSTACLE_RADIUS > law.prune_above
        else:
            mean = center + rng.uniform(-0.5, 0.5, dimension) * side
            prunable = False
        q = avoid_probability(center, mean[None], np.array([sigma]), OBSTACLE_RADIUS + r_min)[0]
        if q > epsilon and (not worst_case or (q <= P_D and not prunable)):
            rows.append((mean, sigma, epsilon))
    belief = ObstacleBelief(
        mean=np.array([row[0] for row in rows]),
        sigma=np.array([row[1] for row in rows]),
        radius=np.full(count, OBSTACLE_RADIUS),
        epsilon=np.array([row[2] for row in rows]),
        p_d=np.full(count, P_D),
    )
    return law, center, belief


def anisotropic_field(
    count: int, dimension: int, seed: int = 0
) -> tuple[TubeLaw, np.ndarray, ObstacleBelief]:
    """:func:`obstacle_field`'s typical field with full covariances: Σ_j = R_j diag(λ) R_jᵀ,
    the largest standard deviation the σ_j drawn there, the eigenvalue ratio log-uniform in
    [1, 100], R_j a random rotation; a draw with q_j ≤ ε_j at the centre gets a new one."""
    from scipy.spatial.transform import Rotation

    from stt_drake.core import anisotropic

    law, center, belief = obstacle_field(count, dimension, seed=seed)
    rng = np.random.default_rng(seed + 7 * dimension + count)
    covariances = []
    for j in range(count):
        while True:
            ratio = 10.0 ** rng.uniform(0.0, 2.0)
            variances = belief.sigma[j] ** 2 * np.geomspace(1.0 / ratio, 1.0, dimension)
            rotation = Rotation.random(random_state=rng).as_matrix()
            if dimension == 2:
                angle = rng.uniform(0.0, np.pi)
                rotation = np.array(
                    [[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]]
                )
            covariance = rotation @ np.diag(variances) @ rotation.T
            q = anisotropic.avoid_probability(
                center, belief.mean[j], covariance, belief.radius[j] + law.r_min
            )
            if q > belief.epsilon[j]:
                covariances.append(covariance)
                break
    return law, center, replace(belief, covariance=np.array(covariances))


def baseline_tube_step(
    law: TubeLaw, center: np.ndarray, belief: ObstacleBelief
) -> tuple[np.ndarray, float, np.ndarray, np.ndarray, np.ndarray]:
    """The tube step as the authors' MATLAB code does it: a loop over obstacles calling
    ``scipy.stats.ncx2.cdf`` and ``.ppf`` once each (q_j as 1 − cdf, no pruning).

    Returns:
        (ċ, r, q, d̂, θ), comparable with :class:`stt_drake.core.tube.TubeEvaluation`.
    """
    from scipy.stats import ncx2

    n = len(center)
    goal = law.target - center
    rate = law.k1 * np.cbrt(goal)
    count = belief.count
    q, d_hat, theta = np.zeros(count), np.zeros(count), np.zeros(count)
    for j in range(count):
        offset = center - belief.mean[j]
        lam = float(offset @ offset) / belief.sigma[j] ** 2
        threshold = ((belief.radius[j] + law.r_min) / belief.sigma[j]) ** 2
        q[j] = 1.0 - ncx2.cdf(threshold, n, lam)
        d_hat[j] = (
            belief.sigma[j] * np.sqrt(ncx2.ppf(1.0 - belief.epsilon[j], n, lam)) - belief.radius[j]
        )
        if q[j] <= belief.p_d[j]:
            theta[j] = 1.0 / q[j] - 1.0 / belief.p_d[j]
            m = offset / max(q[j] - belief.epsilon[j], 1e-12)
            if n == 2:
                v = np.array([-m[1], m[0]])
            else:
                v = goal - (goal @ m) / (m @ m) * m
                v = v / np.linalg.norm(v) * np.linalg.norm(m)
            rate = rate + (law.k2 * m + law.k3 * v) * theta[j]
    values = np.append(d_hat, law.r_max)
    smallest = values.min()
    radius = smallest - np.log(np.sum(np.exp(-law.nu * (values - smallest)))) / law.nu
    return rate, float(radius), q, d_hat, theta
