"""Campaign statistics against scipy's exact binomial interval and closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import binom, binomtest

from stt_drake.core.statistics import (
    CERTIFIED,
    INCONCLUSIVE,
    VIOLATED,
    clopper_pearson,
    family_confidence,
    runs_to_certify,
    simultaneous_verdict,
)


@pytest.mark.parametrize("trials", [1, 7, 60, 1000])
@pytest.mark.parametrize("confidence", [0.9, 0.99, 0.9999])
def test_clopper_pearson_matches_scipy_exact_interval(trials, confidence):
    successes = np.unique(np.linspace(0, trials, 9).round().astype(int))
    lower, upper = clopper_pearson(successes, trials, confidence)
    for k, low, high in zip(successes, lower, upper, strict=True):
        reference = binomtest(int(k), trials).proportion_ci(
            confidence_level=confidence, method="exact"
        )
        assert low == pytest.approx(reference.low, rel=1e-7, abs=1e-15)  # binomtest root-finds
        assert high == pytest.approx(reference.high, rel=1e-7, abs=1e-15)  # binomtest root-finds


@pytest.mark.parametrize("trials", [1, 10, 528, 5000])
def test_clopper_pearson_closed_forms_at_the_ends(trials):
    """Two-sided convention: k = 0 → upper 1 − (α/2)^{1/n}; k = n → lower (α/2)^{1/n}."""
    alpha = 0.01
    lower, upper = clopper_pearson(np.array([0, trials]), trials, 1 - alpha)
    assert lower[0] == 0.0 and upper[1] == 1.0
    assert upper[0] == pytest.approx(1 - (alpha / 2) ** (1 / trials), rel=1e-12)
    assert lower[1] == pytest.approx((alpha / 2) ** (1 / trials), rel=1e-12)


@pytest.mark.parametrize("p", [0.003, 0.05, 0.31, 0.9])
def test_clopper_pearson_covers_with_at_least_the_confidence(p):
    """Exact coverage Σ_k Binom(k; n, p)·[p ∈ CI(k)] is ≥ the nominal level."""
    trials, confidence = 80, 0.95
    k = np.arange(trials + 1)
    lower, upper = clopper_pearson(k, trials, confidence)
    covered = (lower <= p) & (p <= upper)
    assert binom.pmf(k, trials, p)[covered].sum() >= confidence


def test_family_confidence_is_bonferroni():
    assert family_confidence(0.99, 1) == pytest.approx(0.99)
    assert family_confidence(0.99, 10_000) == pytest.approx(1 - 1e-6)
    with pytest.raises(ValueError):
        family_confidence(0.99, 0)


@pytest.mark.parametrize("threshold", [0.01, 0.05, 0.3])
def test_runs_to_certify_with_no_collision_is_the_closed_form(threshold):
    confidence = 0.999
    expected = math.ceil(math.log((1 - confidence) / 2) / math.log(1 - threshold))
    assert runs_to_certify(0.0, threshold, confidence) == expected


@pytest.mark.parametrize(("frequency", "threshold"), [(0.007, 0.01), (0.06, 0.1), (0.2, 0.3)])
def test_runs_to_certify_is_the_smallest_certifying_count(frequency, threshold):
    """At k = f·n the exact upper bound (scipy) is ≤ threshold at n and > threshold at n − 1."""
    confidence = 0.99
    n = runs_to_certify(frequency, threshold, confidence)
    assert n is not None

    def upper(trials: int) -> float:
        from scipy.stats import beta

        return beta.ppf(1 - (1 - confidence) / 2, frequency * trials + 1, trials * (1 - frequency))

    assert upper(n) <= threshold < upper(n - 1)


def test_runs_to_certify_is_none_when_the_frequency_reaches_the_threshold():
    assert runs_to_certify(0.1, 0.1, 0.99) is None
    assert runs_to_certify(0.2, 0.1, 0.99) is None
    # 3/300 against 1 − 0.99 = 0.010000000000000009: below only by rounding
    assert runs_to_certify(3 / 300, 1 - 0.99, 0.99) is None


def test_simultaneous_verdict_certifies_violates_or_asks_for_more_runs():
    confidence = family_confidence(0.99, 3)
    trials = 2000
    quiet = np.array([0, 3, 1])
    certified = simultaneous_verdict(quiet, trials, 0.01, confidence)
    assert certified.verdict == CERTIFIED and certified.index == 1
    reference = binomtest(3, trials).proportion_ci(confidence_level=confidence, method="exact")
    assert certified.upper == pytest.approx(reference.high, rel=1e-9)
    assert certified.lower == pytest.approx(reference.low, rel=1e-9)
    assert certified.frequency == 3 / trials and certified.runs_to_certify is None

    violated = simultaneous_verdict(np.array([10, 80, 5]), trials, 0.01, confidence)
    assert violated.verdict == VIOLATED and violated.index == 1
    assert violated.lower > 0.01

    unsure = simultaneous_verdict(np.array([0, 14, 2]), trials, 0.01, confidence)
    assert unsure.verdict == INCONCLUSIVE
    assert unsure.lower <= 0.01 < unsure.upper
    assert unsure.runs_to_certify == runs_to_certify(14 / trials, 0.01, confidence)
    assert unsure.runs_to_certify > trials

    hopeless = simultaneous_verdict(np.array([0, 22, 2]), trials, 0.01, confidence)
    assert hopeless.verdict == INCONCLUSIVE and hopeless.runs_to_certify is None


def test_simultaneous_verdict_breaks_ties_by_the_given_key():
    counts = np.zeros(5, dtype=int)
    assert simultaneous_verdict(counts, 100, 0.1, 0.99).index == 0
    predicted = np.array([0.0, 0.02, 0.07, 0.01, 0.0])
    assert simultaneous_verdict(counts, 100, 0.1, 0.99, predicted).index == 2
    counts[4] = 1
    assert simultaneous_verdict(counts, 100, 0.1, 0.99, predicted).index == 4


def test_worst_of_many_times_bias_needs_the_simultaneous_level():
    """p(t) = 1 − ε exactly at 2000 independent times: a pointwise 99 % test of the worst
    time calls the correct tube violated; the Bonferroni-simultaneous test does not."""
    rng = np.random.default_rng(7)
    times, trials, threshold = 2000, 3000, 0.05
    counts = rng.binomial(trials, threshold, size=times)
    pointwise = simultaneous_verdict(counts, trials, threshold, 0.99)
    simultaneous = simultaneous_verdict(counts, trials, threshold, family_confidence(0.99, times))
    assert pointwise.verdict == VIOLATED
    assert simultaneous.verdict != VIOLATED


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: clopper_pearson(1, 0, 0.99), "trials"),
        (lambda: clopper_pearson(5, 4, 0.99), "successes"),
        (lambda: clopper_pearson(1, 4, 1.0), "confidence"),
        (lambda: runs_to_certify(1.5, 0.1, 0.99), "frequency"),
        (lambda: simultaneous_verdict(np.array([]), 10, 0.1, 0.99), "counts"),
    ],
)
def test_bad_arguments_raise(call, message):
    with pytest.raises(ValueError, match=message):
        call()
