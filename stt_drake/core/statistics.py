"""Exact binomial statistics for verification campaigns (pure numpy/scipy, no Drake).

A campaign observes, at each logged time t, how many of n independent runs collided with
obstacle j: k_j(t) ~ Binomial(n, p_j(t)). The guarantee to check is p_j(t) ≤ 1 − ε_j at
*every* t. Taking the worst of thousands of times and testing it with the same samples at a
per-time 99 % level is biased (with ~10⁴ correlated times one of them exceeds its pointwise
bound by chance even for a correct tube), so the bounds here are **simultaneous**:

* each (check, obstacle, time) is one member of a family of size F fixed before sampling;
* every member gets the two-sided Clopper-Pearson interval at level 1 − α/F (Bonferroni),
  so with probability ≥ 1 − α *all* F intervals cover their p at once;
* the bounds are monotone in k for a fixed n, so "the upper bound at every time" is the
  upper bound at the time of the largest count, and likewise for the lower bound.

Conventions: :func:`clopper_pearson` is the *two-sided* exact interval at ``confidence``
(each tail (1 − confidence)/2); for k = 0 its upper end is 1 − (α/2)^{1/n}.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import beta

#: Largest run count :func:`runs_to_certify` reports (counts stay exact in a float).
_LARGEST_COUNT = 2**53

#: The verdicts of one (check, obstacle): see :func:`simultaneous_verdict`.
CERTIFIED, VIOLATED, INCONCLUSIVE = "certified", "violated", "inconclusive"


def clopper_pearson(
    successes: np.ndarray | float, trials: int, confidence: float
) -> tuple[np.ndarray, np.ndarray]:
    """Two-sided exact (Clopper-Pearson) interval for a binomial proportion.

    Args:
        successes: k (array or scalar); real values are accepted (the Beta quantiles are
            continuous in k), which :func:`runs_to_certify` uses.
        trials: n ≥ 1.
        confidence: 1 − α; each tail gets α/2.

    Returns:
        (lower, upper) arrays shaped like `successes`, with lower = 0 at k = 0 and
        upper = 1 at k = n.
    """
    if trials < 1:
        raise ValueError(f"trials must be ≥ 1 (got {trials})")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must lie in (0, 1) (got {confidence})")
    k = np.asarray(successes, dtype=float)
    if np.any((k < 0) | (k > trials)):
        raise ValueError(f"successes must lie in [0, {trials}]")
    tail = (1.0 - confidence) / 2.0
    with np.errstate(invalid="ignore", divide="ignore"):
        lower = np.where(k > 0, beta.ppf(tail, np.maximum(k, 1e-300), trials - k + 1), 0.0)
        upper = np.where(
            k < trials, beta.ppf(1.0 - tail, k + 1, np.maximum(trials - k, 1e-300)), 1.0
        )
    return lower, upper


def family_confidence(confidence: float, family_size: int) -> float:
    """Per-member confidence 1 − α/F that makes F intervals hold jointly at 1 − α."""
    if family_size < 1:
        raise ValueError(f"family_size must be ≥ 1 (got {family_size})")
    return 1.0 - (1.0 - confidence) / family_size


def runs_to_certify(frequency: float, threshold: float, confidence: float) -> int | None:
    """Smallest n whose Clopper-Pearson upper bound at the observed `frequency` is ≤ threshold.

    The count is taken as k = frequency·n (continuous), i.e. "if further runs kept the
    frequency seen so far". None when frequency ≥ threshold (no finite n certifies it) or
    when n would exceed 2⁵³ (frequency only a rounding error below threshold).
    For frequency 0 this is ⌈ln(α/2)/ln(1 − threshold)⌉.
    """
    if not 0.0 <= frequency <= 1.0:
        raise ValueError(f"frequency must lie in [0, 1] (got {frequency})")
    if frequency >= threshold or threshold <= 0.0:
        return None
    if threshold >= 1.0:
        return 1

    def certifies(n: int) -> bool:
        return bool(clopper_pearson(frequency * n, n, confidence)[1] <= threshold)

    high = 1
    while not certifies(high):
        high *= 2
        if high > _LARGEST_COUNT:  # frequency a rounding error below threshold
            return None
    low = high // 2  # certifies(low) is False (or low = 0)
    while high - low > 1:
        middle = (low + high) // 2
        if certifies(middle):
            high = middle
        else:
            low = middle
    return high


@dataclass(frozen=True)
class Verdict:
    """The outcome of testing p(t) ≤ threshold at every time from counts k(t) of n runs.

    `frequency` and `index` are the worst time's k/n and its position; `lower`/`upper` are
    its simultaneous Clopper-Pearson bounds (the extreme bounds over all times).
    """

    frequency: float
    index: int
    lower: float
    upper: float
    verdict: str
    runs_to_certify: int | None


def verdict_words(verdict: str, runs_to_certify: int | None) -> str:
    """A verdict as the reports, tables and figures print it: ``certified``,
    ``violated``, ``inconclusive``, or ``inconclusive (needs ≈1,444 runs)`` when the
    inconclusive verdict's data says how many runs would certify it
    (:attr:`Verdict.runs_to_certify`)."""
    if verdict == INCONCLUSIVE and runs_to_certify is not None:
        return f"{verdict} (needs ≈{runs_to_certify:,} runs)"
    return verdict


def simultaneous_verdict(
    counts: np.ndarray,
    trials: int,
    threshold: float,
    member_confidence: float,
    tie_break: np.ndarray | None = None,
) -> Verdict:
    """Test H: p(t) ≤ threshold for all t, from collision counts k(t) of `trials` runs.

    Every time gets the two-sided Clopper-Pearson interval at `member_confidence` (use
    :func:`family_confidence` to make a whole family simultaneous). Verdict:

    * ``certified`` — the upper bound at every time is ≤ threshold;
    * ``violated`` — the lower bound at some time exceeds threshold;
    * ``inconclusive`` — neither; `runs_to_certify` says how many runs would certify at the
      worst observed frequency (None if that frequency is already ≥ threshold).

    The worst time is the one with the largest count; among ties (e.g. no collision at
    all), the one with the largest `tie_break` (e.g. the predicted probability), else the
    first.
    """
    counts = np.asarray(counts)
    if counts.ndim != 1 or counts.size == 0:
        raise ValueError("counts must be a non-empty 1-D array (one count per time)")
    worst = np.flatnonzero(counts == counts.max())  # bounds are monotone in k: it rules both
    index = int(worst[0] if tie_break is None else worst[np.argmax(np.asarray(tie_break)[worst])])
    lower, upper = clopper_pearson(counts[index], trials, member_confidence)
    frequency = float(counts[index]) / trials
    needed = None
    if upper <= threshold:
        verdict = CERTIFIED
    elif lower > threshold:
        verdict = VIOLATED
    else:
        verdict = INCONCLUSIVE
        needed = runs_to_certify(frequency, threshold, member_confidence)
    return Verdict(frequency, index, float(lower), float(upper), verdict, needed)
