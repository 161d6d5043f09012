"""The tube law with full obstacle covariances (stt_drake.core.anisotropic_tube): its
reduction to the paper's law for Σ = σ²I, its direction against finite differences of the
exact probability, the pruning bounds, the level-set escape, and compiled against numpy."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from stt_drake.core import anisotropic, backend
from stt_drake.core._anisotropic_tube import symmetric_eigen
from stt_drake.core.anisotropic_tube import isotropic_variance, pruning_bounds
from stt_drake.core.belief import GaussianBelief, ObstacleBelief
from stt_drake.core.constants import ISOTROPIC_RTOL
from stt_drake.core.rules import ISOTROPIC_PERIOD_RULE
from stt_drake.core.tube import TubeLaw

SEED = 20261123


def random_covariance(rng: np.random.Generator, n: int, ratio: float, scale: float) -> np.ndarray:
    """Σ = R diag(λ) Rᵀ with λ_max/λ_min = ratio, λ_max = scale², a random rotation R."""
    variances = scale**2 * np.geomspace(1.0 / ratio, 1.0, n)
    rng.shuffle(variances)
    if n == 2:
        angle = rng.uniform(0, np.pi)
        rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    else:
        rotation = Rotation.random(random_state=rng).as_matrix()
    return rotation @ np.diag(variances) @ rotation.T


def field(rng: np.random.Generator, n: int, count: int, covariance: bool, ratio: float = 30.0):
    mean = rng.uniform(0.0, 4.0, (count, n))
    sigma = rng.uniform(0.05, 0.4, count)
    covariances = np.array([random_covariance(rng, n, ratio, s) for s in sigma])
    return ObstacleBelief(
        mean=mean,
        sigma=sigma,
        radius=rng.uniform(0.1, 0.3, count),
        epsilon=rng.uniform(0.7, 0.95, count),
        p_d=np.full(count, 0.9999),
        covariance=covariances if covariance else None,
    )


def isotropic_with_covariance(belief: ObstacleBelief, perturbation: float = 0.0) -> ObstacleBelief:
    """Σ_j = σ_j²(I + perturbation·e₀e₀ᵀ)."""
    n = belief.dimension
    shape = np.eye(n)
    shape[0, 0] += perturbation
    covariance = belief.sigma[:, None, None] ** 2 * shape[None]
    return ObstacleBelief(
        belief.mean, belief.sigma, belief.radius, belief.epsilon, belief.p_d, covariance
    )


def make_law(n: int, **overrides) -> TubeLaw:
    settings = dict(
        target=np.full(n, 4.0),
        k1=0.4,
        k2=0.3,
        k3=0.2,
        r_min=0.1,
        r_max=0.8,
        nu=20.0,
        max_center_speed=2.0,
    )
    settings.update(overrides)
    return TubeLaw(**settings)


def test_symmetric_eigen_against_lapack():
    rng = np.random.default_rng(SEED)
    for n in (2, 3):
        for ratio in (1.0, 3.0, 1e2, 1e4):
            matrix = random_covariance(rng, n, ratio, rng.uniform(0.01, 2.0))
            variances, axes = symmetric_eigen(matrix)
            reference = np.linalg.eigvalsh(matrix)
            # Jacobi to 1e-17 off-diagonal: eigenvalues to a few ulps of λ_max.
            np.testing.assert_allclose(
                np.sort(variances), reference, rtol=0, atol=1e-14 * reference[-1]
            )
            np.testing.assert_allclose(
                axes @ np.diag(variances) @ axes.T, matrix, atol=1e-14 * reference[-1]
            )
            np.testing.assert_allclose(axes.T @ axes, np.eye(n), atol=1e-14)


@pytest.mark.parametrize("n", [2, 3])
def test_pruning_bounds_are_below_the_exact_values(n):
    """q ≥ Φ((‖c − μ‖ − R)/s) and d̂ ≥ max(‖c − μ‖ − sΦ⁻¹(ε), 0) − r_o, s² = uᵀΣu, against
    the exact generalized chi-square values, eigenvalue ratios up to 1e4."""
    rng = np.random.default_rng(SEED + n)
    for _ in range(300):
        covariance = random_covariance(rng, n, 10 ** rng.uniform(0, 4), rng.uniform(0.05, 1.0))
        mean = np.zeros(n)
        center = rng.normal(size=n) * rng.uniform(0.0, 4.0)
        radius, epsilon, r_min = rng.uniform(0.05, 0.5), rng.uniform(0.6, 0.99), 0.1
        _distance, q_lower, d_lower = pruning_bounds(
            center, mean, covariance, radius, epsilon, r_min
        )
        q = anisotropic.avoid_probability(center, mean, covariance, radius + r_min)
        d_hat = anisotropic.quantile_distance(center, mean, covariance, radius, epsilon)
        assert q_lower <= q + 1e-12
        assert d_lower <= d_hat + 1e-9


@pytest.mark.slow
@pytest.mark.parametrize("perturbation", [0.0, 4 * ISOTROPIC_RTOL])
@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("n", [2, 3])
def test_reduces_to_the_isotropic_law_for_sigma_squared_identity(n, compiled, perturbation):
    """Σ_j = σ_j²I: the same ċ, r, θ and (where not pruned) q and d̂ as the paper's law,
    over points outside, inside the boundary layer and in recovery. Exactly σ²I takes the
    noncentral χ law; σ²(I + δe₀e₀ᵀ) with δ just above ISOTROPIC_RTOL takes the contour
    integral, whose probabilities may then differ by the total-variation bound 1.5δ."""
    q_tolerance = 1e-12 + 1.5 * perturbation
    rng = np.random.default_rng(SEED + 10 * n)
    law = make_law(n)
    checked_active = 0
    with backend.pure_numpy(not compiled):
        for _ in range(60):
            belief = field(rng, n, 6, covariance=False)
            with_covariance = isotropic_with_covariance(belief, perturbation)
            taken = [isotropic_variance(covariance) for covariance in with_covariance.covariance]
            assert all((variance is None) == (perturbation > 0.0) for variance in taken)
            center = rng.uniform(0.0, 4.0, n)
            axes = None
            if n == 3:
                axes = np.zeros((6, 3))
                axes[:, 2] = 1.0
            # Every d̂_j exact on both sides (the two laws prune at different headrooms).
            iso = law.evaluate(center, belief, prune=False, circulation=axes)
            aniso = law.evaluate(center, with_covariance, prune=False, circulation=axes)
            exact = aniso.avoid_probability <= belief.p_d  # computed, not a pruning bound
            # q: two exact methods (noncentral χ and the contour integral), 1e-12 apart.
            np.testing.assert_allclose(
                aniso.avoid_probability[exact],
                iso.avoid_probability[exact],
                rtol=0,
                atol=q_tolerance,
            )
            assert np.all(
                aniso.avoid_probability[~exact] <= iso.avoid_probability[~exact] + q_tolerance
            )
            np.testing.assert_allclose(
                aniso.quantile_distance, iso.quantile_distance, rtol=1e-9, atol=1e-9
            )
            np.testing.assert_allclose(aniso.theta, iso.theta, rtol=1e-9, atol=1e-12)
            np.testing.assert_allclose(aniso.radius, iso.radius, rtol=1e-9)
            # ċ: m_j carries 1/(q_j − ε_j), so a change δq of q_j moves it by ~δq/gap².
            gap = np.min(np.abs(iso.avoid_probability - belief.epsilon))
            tolerance = 1e-9 + 10 * q_tolerance / max(gap, 1e-3) ** 2
            np.testing.assert_allclose(aniso.center_rate, iso.center_rate, rtol=0, atol=tolerance)
            checked_active += int(np.any(iso.theta > 0))
            # Pruned at r_max + 25/ν, r is lower by at most n_o·e^{−25}/ν, never higher.
            pruned = law.evaluate(center, with_covariance, circulation=axes).radius
            assert aniso.radius - 6 * np.exp(-25.0) / law.nu - 1e-12 <= pruned
            assert pruned <= aniso.radius + 1e-12
    assert checked_active > 10  # the law's obstacle terms were exercised, not only pruned


@pytest.mark.parametrize("n", [2, 3])
def test_repulsion_is_along_the_gradient_of_q(n):
    """One obstacle, no attraction, no circulation: ċ = k2·θ·m with m along ∇q, checked
    against central differences of the exact probability (an independent evaluation)."""
    rng = np.random.default_rng(SEED + 20 * n)
    unattracted = make_law(n, k3=0.0, max_center_speed=np.inf)  # k1 > 0 in every law
    found = 0
    for _ in range(600):
        covariance = random_covariance(rng, n, 50.0, 0.4)
        belief = ObstacleBelief(
            np.zeros((1, n)),
            np.array([0.4]),
            np.array([0.2]),
            np.array([0.8]),
            np.array([0.9999]),
            covariance[None],
        )
        center = rng.normal(size=n) * 1.2
        law = unattracted.with_target(center)  # η = c: the attraction k1·cbrt(η − c) is 0
        evaluation = law.evaluate(center, belief)
        q = evaluation.avoid_probability[0]
        if not (0.8 + 0.01 < q < 0.999):
            continue
        found += 1
        step = 1e-6
        gradient = np.array(
            [
                (
                    anisotropic.avoid_probability(center + step * e, np.zeros(n), covariance, 0.3)
                    - anisotropic.avoid_probability(center - step * e, np.zeros(n), covariance, 0.3)
                )
                / (2 * step)
                for e in np.eye(n)
            ]
        )
        rate = evaluation.center_rate
        cosine = rate @ gradient / (np.linalg.norm(rate) * np.linalg.norm(gradient))
        assert cosine > 1 - 1e-6
        # the magnitude of the paper's term: k2·θ·‖c − μ‖/(q − ε)
        expected = 0.3 * (1 / q - 1 / 0.9999) * np.linalg.norm(center) / (q - 0.8)
        np.testing.assert_allclose(np.linalg.norm(rate), expected, rtol=1e-9)
    assert found > 20


@pytest.mark.parametrize("n", [2, 3])
def test_the_centre_leaves_an_epsilon_level_set_with_q_increasing(n):
    """On the ε level set of an elongated obstacle (q = ε exactly), with the goal straight
    through the obstacle, the recovery's ċ raises q: ∇q·ċ > 0 (claim (ii) at its edge)."""
    covariance = np.diag([0.6**2] + [0.05**2] * (n - 1))
    mean = np.zeros(n)
    belief = ObstacleBelief(
        mean[None],
        np.array([0.6]),
        np.array([0.2]),
        np.array([0.9]),
        np.array([0.9999]),
        covariance[None],
    )
    rng = np.random.default_rng(SEED + 30 * n)
    for _ in range(20):
        direction = rng.normal(size=n)
        direction /= np.linalg.norm(direction)
        # the point along `direction` where q = ε (bisection on the exact probability)
        low, high = 0.0, 5.0
        for _ in range(80):
            middle = 0.5 * (low + high)
            q = anisotropic.avoid_probability(middle * direction, mean, covariance, 0.3)
            low, high = (middle, high) if q < 0.9 else (low, middle)
        center = high * direction
        law = make_law(n, target=-3.0 * direction)  # the goal lies behind the obstacle
        for compiled in (True, False):
            with backend.pure_numpy(not compiled):
                rate = law.evaluate(center, belief).center_rate
            gradient = anisotropic.avoid_probability_gradient(center, mean, covariance, 0.3)
            assert gradient @ rate > 0.0
            np.testing.assert_allclose(np.linalg.norm(rate), 2.0, rtol=1e-12)  # at v_c


@pytest.mark.slow
@pytest.mark.parametrize("n", [2, 3])
def test_compiled_and_numpy_agree_on_anisotropic_fields(n):
    rng = np.random.default_rng(SEED + 40 * n)
    law = make_law(n)
    for _ in range(40):
        belief = field(rng, n, 8, covariance=True, ratio=10 ** rng.uniform(0, 3))
        center = rng.uniform(0.0, 4.0, n)
        for mode in ("pruned", "exact"):
            compiled = law.evaluate(center, belief, prune=mode == "pruned")
            with backend.pure_numpy():
                reference = law.evaluate(center, belief, prune=mode == "pruned")
            np.testing.assert_allclose(
                compiled.avoid_probability, reference.avoid_probability, rtol=0, atol=1e-12
            )
            np.testing.assert_allclose(
                compiled.quantile_distance, reference.quantile_distance, rtol=1e-10, atol=1e-10
            )
            np.testing.assert_allclose(compiled.theta, reference.theta, rtol=1e-9, atol=1e-12)
            gap = np.min(np.abs(reference.avoid_probability - belief.epsilon))
            np.testing.assert_allclose(
                compiled.center_rate,
                reference.center_rate,
                rtol=0,
                atol=1e-9 + 1e-11 / max(gap, 1e-3) ** 2,
            )
            np.testing.assert_allclose(compiled.radius, reference.radius, rtol=1e-10)


def test_fixed_rate_inflation_is_refused_for_covariances():
    """Full covariance ⇒ continuous time: one rule (stt_drake.core.rules), asked by the law,
    the Drake system (below) and the scenario loader (tests/config)."""
    rng = np.random.default_rng(SEED)
    belief = field(rng, 2, 3, covariance=True)
    law = make_law(2)
    with pytest.raises(ValueError, match=r"^inflation: must be None \(continuous time\)") as info:
        law.evaluate(np.zeros(2), belief, inflation=(np.zeros(3), np.zeros(3)))
    assert ISOTROPIC_PERIOD_RULE in str(info.value)


# --------------------------------------------------------------------------------------
# The Drake systems with full covariances on the belief port
# --------------------------------------------------------------------------------------
def test_tube_and_monitor_systems_use_the_full_covariance():
    """With full_covariance the tube's ċ and diagnostics are the law's with Σ (not with the
    isotropic σ² = λ_max), and the monitor's margins are the exact anisotropic ones."""
    from stt_drake.core.invariants import evaluate_invariants
    from stt_drake.systems.monitor import InvariantMonitor
    from stt_drake.systems.tube import SpatiotemporalTube

    rng = np.random.default_rng(SEED + 50)
    belief = field(rng, 2, 3, covariance=True, ratio=100.0)
    law = make_law(2)
    center = np.array([2.0, 2.0])
    # a centre where every q_j > ε_j and some obstacle acts (θ_j > 0): the law's terms matter
    while True:
        evaluation = law.evaluate(center, belief)
        if np.all(evaluation.avoid_probability > belief.epsilon) and np.any(evaluation.theta > 0):
            break
        center = belief.mean[0] + rng.normal(size=2) * 0.6
    tube = SpatiotemporalTube(law, center, belief.task, full_covariance=True)
    context = tube.CreateDefaultContext()
    tube.GetInputPort("obstacle_belief").FixValue(context, belief.to_vector())
    expected = law.evaluate(center, belief)
    isotropic = law.evaluate(center, replace(belief, covariance=None))
    derivatives = tube.AllocateTimeDerivatives()
    tube.CalcTimeDerivatives(context, derivatives)
    np.testing.assert_allclose(derivatives.CopyToVector(), expected.center_rate, rtol=1e-12)
    np.testing.assert_allclose(
        tube.GetOutputPort("diagnostics").Eval(context)[:3], expected.avoid_probability, rtol=1e-12
    )
    assert np.max(np.abs(expected.center_rate - isotropic.center_rate)) > 1e-3

    monitor = InvariantMonitor(2, belief.task, law.r_min, full_covariance=True)
    monitor_context = monitor.CreateDefaultContext()
    tube_value = np.append(center, 0.2)
    output = center + np.array([0.05, -0.02])
    monitor.GetInputPort("tube").FixValue(monitor_context, tube_value)
    monitor.GetInputPort("obstacle_belief").FixValue(monitor_context, belief.to_vector())
    monitor.GetInputPort("output").FixValue(monitor_context, output)
    monitor.GetInputPort("recovery").FixValue(monitor_context, np.zeros(3))
    margins = monitor.GetOutputPort("margins").Eval(monitor_context)
    # the center margin from the public probability function, one obstacle at a time
    center_q = [
        anisotropic.avoid_probability(
            center, belief.mean[j], belief.covariance[j], belief.radius[j] + law.r_min
        )
        for j in range(3)
    ]
    np.testing.assert_allclose(margins[1], np.min(np.array(center_q) - belief.epsilon), atol=1e-13)
    reference = evaluate_invariants(output, center, 0.2, belief, law.r_min)
    np.testing.assert_allclose(margins, reference.margins, atol=1e-13)


def test_fixed_rate_tube_with_covariances_is_refused():
    from stt_drake.core.belief import ObstacleTask
    from stt_drake.core.fixed_rate import BeliefRateBounds
    from stt_drake.systems.tube import SpatiotemporalTube

    task = ObstacleTask(np.full(2, 0.2), np.full(2, 0.9), np.full(2, 0.99))
    with pytest.raises(
        ValueError, match=r"^SpatiotemporalTube: update_period must be None \(continuous time\)"
    ) as info:
        SpatiotemporalTube(
            make_law(2),
            np.zeros(2),
            task,
            update_period=0.01,
            rate_bounds=BeliefRateBounds.still(2),
            full_covariance=True,
        )
    assert ISOTROPIC_PERIOD_RULE in str(info.value)


@pytest.mark.parametrize("n", [2, 3])
def test_level_set_radii_reduce_to_the_isotropic_radius(n):
    """Σ = σ²I: the boundary of {q̂ ≤ level} is the sphere of core.probability's
    level_set_radius (a separate root find on the noncentral chi law) in every direction."""
    from stt_drake.core.probability import level_set_radius

    rng = np.random.default_rng(SEED + 60 + n)
    directions = rng.normal(size=(50, n))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    for sigma, level in ((0.3, 0.95), (0.05, 0.9999), (1.0, 0.7)):
        radii = anisotropic.level_set_radii(directions, sigma**2 * np.eye(n), 0.4, level)
        np.testing.assert_allclose(radii, level_set_radius(level, sigma, 0.4, n), rtol=1e-8)


@pytest.mark.parametrize("n", [2, 3])
def test_compiled_monitor_probabilities_match_numpy(n):
    """The monitor's probabilities with full covariances: the compiled kernel (LAPACK eigh
    in numba) against the numpy reference (numpy eigh), at points near and far from the
    obstacles; agreement to 1e-12 (the contour integral is the same code on both paths, the
    eigenbases differ in the last bits). A broken Σ_j is named by its index on both paths."""
    from stt_drake.core.invariants import evaluate_invariants

    rng = np.random.default_rng(SEED + 60 + n)
    belief = field(rng, n, 9, covariance=True, ratio=100.0)
    for _ in range(5):
        center, output = rng.uniform(0.0, 4.0, (2, n))
        radius = rng.uniform(0.05, 0.5)
        with backend.pure_numpy(False):
            assert backend.compiled("anisotropic_invariants", n) is not None
            fast = evaluate_invariants(output, center, radius, belief, 0.05)
        with backend.pure_numpy():
            slow = evaluate_invariants(output, center, radius, belief, 0.05)
        for name in ("margins", "output_avoid_probability", "tube_avoid_probability"):
            np.testing.assert_allclose(
                getattr(fast, name), getattr(slow, name), rtol=1e-12, atol=1e-14
            )
    broken = belief.covariance.copy()
    broken[4] = -broken[4]  # negative definite
    for pure in (False, True):
        with backend.pure_numpy(pure), pytest.raises(
            ValueError, match=r"^obstacle 4: covariance must be positive definite"
        ):
            evaluate_invariants(output, center, 0.1, replace(belief, covariance=broken), 0.05)


@pytest.mark.parametrize("n", [2, 3])
def test_a_port_belief_with_covariances_runs_the_packed_kernel_alike(n):
    """A tube's belief straight from its port (some slots inactive, per-slot gains, 3D
    circulation axes) gives what the law gives on the active obstacles' arrays, spread over
    the slots, and unpacks nothing on the way."""
    rng = np.random.default_rng(SEED + n)
    count = 12
    belief = field(rng, n, count, covariance=True)
    active = np.ones(count, dtype=bool)
    active[[1, 4, 9]] = False
    vector = GaussianBelief(belief.mean, belief.covariance, active).to_vector()
    law = make_law(n, k2=np.linspace(0.2, 0.6, count), k3=np.linspace(0.0, 0.9, count))
    axes = None
    if n == 3:
        axes = rng.normal(size=(count, 3))
        axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    task = belief.task
    acting = 0
    for center in rng.uniform(0.0, 4.0, (6, n)):
        port = ObstacleBelief.from_port(vector, n, task, full_covariance=True)
        packed = law.evaluate(center, port, circulation=axes)
        assert "_obstacles" not in port.__dict__ and "slots" not in port.__dict__
        arrays = ObstacleBelief.from_port(vector, n, task, full_covariance=True).obstacles()
        per_slot_law = replace(law, k2=law.k2[active], k3=law.k3[active])
        direct = per_slot_law.evaluate(
            center, arrays, circulation=None if axes is None else axes[active]
        )
        # The same compiled driver on the same numbers: only the copies differ.
        np.testing.assert_allclose(packed.center_rate, direct.center_rate, rtol=1e-12, atol=1e-15)
        assert packed.radius == pytest.approx(direct.radius, rel=1e-12)
        for name, fill in (("avoid_probability", 1.0), ("quantile_distance", np.inf)):
            values = getattr(packed, name)
            np.testing.assert_allclose(values[active], getattr(direct, name), rtol=1e-12)
            assert np.all(values[~active] == fill)
        np.testing.assert_array_equal(packed.theta[~active], 0.0)
        acting += int(np.sum(direct.theta > 0.0))
    assert acting > 0  # the obstacles' share of ċ is exercised


@pytest.mark.parametrize("n", [2, 3])
def test_the_monitor_skips_only_hits_below_double_precision(n):
    """Beyond r_o + HIT_NEGLIGIBLE_SIGMAS·σ_max the compiled monitor reads q = 1 without
    integrating; the contour integral there gives 1 too (to 1e-15), and just inside that
    distance it still integrates (q < 1 where the hit is not negligible)."""
    from stt_drake.core.constants import HIT_NEGLIGIBLE_SIGMAS
    from stt_drake.core.invariants import evaluate_invariants

    rng = np.random.default_rng(SEED)
    covariance = random_covariance(rng, n, 20.0, 0.3)
    sigma_max = float(np.sqrt(np.linalg.eigvalsh(covariance)[-1]))
    direction = np.linalg.eigh(covariance)[1][:, -1]  # along the widest axis
    radius = 0.2
    for sigmas, negligible in ((HIT_NEGLIGIBLE_SIGMAS * 1.001, True), (5.0, False)):
        output = (radius + sigmas * sigma_max) * direction
        belief = ObstacleBelief(
            mean=np.zeros((1, n)), sigma=np.array([sigma_max]), radius=np.array([radius]),
            epsilon=np.array([0.9]), p_d=np.array([0.9999]), covariance=covariance[None],
        )
        far_center = np.full(n, 100.0)
        sample = evaluate_invariants(output, far_center, 0.1, belief, 0.05)
        exact = anisotropic.ball_probabilities(
            np.linalg.eigvalsh(covariance), np.linalg.eigh(covariance)[1].T @ output, radius
        )[1]
        q_output = sample.output_avoid_probability[0]
        if negligible:
            assert q_output == 1.0 and exact == pytest.approx(1.0, abs=1e-15)
        else:
            assert q_output < 1.0 and q_output == pytest.approx(exact, abs=1e-13)


@pytest.mark.parametrize("n", [2, 3])
def test_the_monitor_reads_covariances_from_its_port_alike(n):
    """The monitor's belief straight from its port (some slots inactive): the packed kernel
    gives the margins and per-slot probabilities of the active obstacles' arrays (the same
    contour integral on the same Σ_j; the output-to-centre distance may differ by one
    rounding), unpacks nothing, and a broken Σ_j is still named by its obstacle index."""
    from stt_drake.core.invariants import evaluate_tube_invariants

    rng = np.random.default_rng(SEED + 80 + n)
    count = 9
    belief = field(rng, n, count, covariance=True, ratio=50.0)
    active = np.ones(count, dtype=bool)
    active[[2, 5]] = False
    vector = GaussianBelief(belief.mean, belief.covariance, active).to_vector()
    for _ in range(6):
        output, center = rng.uniform(0.0, 4.0, (2, n))
        tube = np.append(center, rng.uniform(0.05, 0.5))
        port = ObstacleBelief.from_port(vector, n, belief.task, full_covariance=True)
        packed = evaluate_tube_invariants(output, tube, port, 0.05)
        assert "_obstacles" not in port.__dict__ and "slots" not in port.__dict__
        arrays = ObstacleBelief.from_port(vector, n, belief.task, full_covariance=True)
        direct = evaluate_tube_invariants(output, tube, arrays.obstacles(), 0.05)
        np.testing.assert_allclose(packed.margins, direct.margins, rtol=0, atol=1e-15)
        for name in ("output_avoid_probability", "tube_avoid_probability"):
            values = getattr(packed, name)
            np.testing.assert_array_equal(values[active], getattr(direct, name))
            assert np.all(values[~active] == 1.0)
    broken = belief.covariance.copy()
    broken[4] = -broken[4]  # slot 4 is active obstacle 3 (slot 2 is inactive)
    vector = GaussianBelief(belief.mean, broken, active).to_vector()
    port = ObstacleBelief.from_port(vector, n, belief.task, full_covariance=True)
    with pytest.raises(ValueError, match=r"^obstacle 3: covariance must be positive definite"):
        evaluate_tube_invariants(output, tube, port, 0.05)
