"""Stall detection: is the tube centre still getting closer to its attraction point?

Eq. (4) of the paper drives the centre c(t) toward an attraction point η(t) (the scenario's
target; a task sequence's active target; a guide's moving point). Around obstacles the law
has equilibria and limit cycles: the centre sits still or oscillates in a pocket forever,
every guarantee holds and the run simply never reaches the target. This module names that.

The rule (one definition, used online by a system and offline on a log). The detector keeps
`best`, the distance ‖c − η‖ at the last *progress event* (the reference the centre must
beat), and `anchor`, η at that event. A progress event happens at a sample when

* ‖c − η‖ ≤ `arrived` (the caller's target set radius: being there is not a stall), or
* ‖η − anchor‖ > `progress` (the attraction point moved on, e.g. a guide advanced it), or
* ‖c − η‖ < best − `progress` (the centre got `progress` metres closer);

then `best` and `anchor` take the current values. The centre is *stalled* at t when
t − (time of the last progress event) ≥ `stall_time`. A stall episode starts at that last
progress event and ends at the next one, or at the end of the run. The first sample (and a
:meth:`StallDetector.reset`) counts as a progress event.

Pure numpy, no Drake.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

#: Slack on t − t_event ≥ stall_time (s): logged times are sums of float periods.
TIME_TOLERANCE = 1e-9

#: Why a progress event happened (index = the code kept in the state vector).
EVENTS = ("start", "progress", "attraction point moved", "arrived")
_START, _PROGRESS, _MOVED, _ARRIVED = range(len(EVENTS))
#: The state vector's scalars before the anchor: [seen, t_event, best, stalled, event].
_SCALARS = 5


@dataclass(frozen=True)
class StallRule:
    """A stall: no progress of `progress` metres toward η for `stall_time` seconds."""

    stall_time: float  # s
    progress: float  # m

    def __post_init__(self) -> None:
        if not (np.isfinite(self.stall_time) and self.stall_time > 0.0):
            raise ValueError(f"stall_time must be finite and > 0 (got {self.stall_time})")
        if not (np.isfinite(self.progress) and self.progress >= 0.0):
            raise ValueError(f"progress must be finite and ≥ 0 (got {self.progress})")


#: The rule of a run without a guide: 10 s without getting 0.1 m closer to η. 0.1 m is the
#: r_min of the omni cases (a creep or an oscillation smaller than the tube's minimum
#: radius is no headway). 10 s is about twice the longest detour of the packaged scenarios
#: (diagrams/, measured with this rule): 5.06 s in omni_authors_field_50hz (t = 29.4 to
#: 34.4 s, the tube waiting 9 m from η for obstacles that oscillate at 0.01 to 0.05 Hz),
#: then 2.3 s (omni_cluttered_50) and ≤ 2 s in every other; 5 s flagged that wait.
DEFAULT_STALL_RULE = StallRule(stall_time=10.0, progress=0.1)


class StallDetector:
    """The rule of the module docstring, fed one sample at a time."""

    def __init__(self, rule: StallRule, arrived: float) -> None:
        """`arrived`: the distance ‖c − η‖ at or below which the centre is at η (m)."""
        self.rule, self.arrived = rule, float(arrived)
        self._seen, self._stalled = False, False
        self._t_event, self._best, self._event = 0.0, np.inf, _START
        self._anchor: np.ndarray | None = None

    # ------------------------------------------------------------------ state

    @property
    def stalled(self) -> bool:
        """Whether the centre is stalled now (since the last detection, until progress)."""
        return self._stalled

    @property
    def since(self) -> float:
        """Time of the last progress event (s): the start of a current stall."""
        return self._t_event

    @property
    def last_event(self) -> str:
        """Why the last progress event happened (one of :data:`EVENTS`)."""
        return EVENTS[self._event]

    def reset(self, t: float, center: np.ndarray, attraction: np.ndarray) -> None:
        """Start over at `t` (a progress event): e.g. a caller that replanned."""
        self._event_at(t, center, attraction, _START)

    def _event_at(self, t: float, center: np.ndarray, attraction: np.ndarray, code: int) -> None:
        attraction = np.array(attraction, dtype=float)  # a copy: the anchor
        self._seen, self._stalled, self._t_event, self._event = True, False, float(t), code
        self._best = float(np.linalg.norm(np.asarray(center, dtype=float) - attraction))
        self._anchor = attraction

    def update(self, t: float, center: np.ndarray, attraction: np.ndarray) -> bool:
        """Fold in the sample at `t`; True exactly when a new stall is detected at it
        (t − last progress event first reaches `stall_time`)."""
        center, attraction = np.asarray(center, float), np.asarray(attraction, float)
        distance = float(np.linalg.norm(center - attraction))
        progress, code = self.rule.progress, None
        if not self._seen:
            code = _START
        elif distance <= self.arrived:
            code = _ARRIVED
        elif float(np.linalg.norm(attraction - self._anchor)) > progress:
            code = _MOVED
        elif distance < self._best - progress:
            code = _PROGRESS
        if code is not None:
            self._event_at(t, center, attraction, code)
            return False
        if not self._stalled and t - self._t_event >= self.rule.stall_time - TIME_TOLERANCE:
            self._stalled = True
            return True
        return False

    # ------------------------------------------------------------------ as a vector

    @staticmethod
    def vector_size(n: int) -> int:
        """Length of :meth:`as_vector` in dimension n."""
        return _SCALARS + n

    def as_vector(self, n: int | None = None) -> np.ndarray:
        """The whole state as floats: [seen, t_event, best, stalled, event code, anchor (n)].
        `n` is needed only before the first sample (the anchor is then zeros)."""
        anchor = self._anchor
        if anchor is None:
            if n is None:
                raise ValueError("as_vector: give n for a detector that has seen no sample")
            anchor = np.zeros(n)
        best = self._best if np.isfinite(self._best) else 0.0
        head = [float(self._seen), self._t_event, best, float(self._stalled), float(self._event)]
        return np.concatenate([head, anchor])

    @classmethod
    def from_vector(cls, vector: np.ndarray, rule: StallRule, arrived: float) -> StallDetector:
        """A detector in the state :meth:`as_vector` gave (rule and `arrived` are not state)."""
        vector = np.asarray(vector, dtype=float)
        detector = cls(rule, arrived)
        if vector[0] != 0.0:
            detector._seen = True
            detector._t_event = float(vector[1])
            detector._best = float(vector[2])
            detector._stalled = bool(vector[3])
            detector._event = int(vector[4])
            detector._anchor = vector[_SCALARS:].copy()
        return detector


def find_stalls(
    t: np.ndarray,
    center: np.ndarray,
    attraction: np.ndarray,
    rule: StallRule,
    arrived: float,
) -> list[dict[str, Any]]:
    """Every stall episode of a logged run (the rule of the module docstring).

    Args:
        t: (T,) sample times; center: (T, n) tube centres c; attraction: (T, n) η per
            sample; rule: the stall rule; arrived: the target set radius (m).

    Returns:
        One record per episode, in time order: `start_s` (the last progress event before
        it), `end_s` (the progress event that ended it; None if it lasts to the end),
        `detected_s`, `position` (c at detection, a list), `distance_m` (‖c − η‖ at
        detection) and `ended` ("progress", "attraction point moved", "arrived" or
        "end of run").
    """
    t = np.asarray(t, dtype=float)
    center = np.asarray(center, dtype=float)
    attraction = np.asarray(attraction, dtype=float)
    detector = StallDetector(rule, arrived)
    episodes: list[dict[str, Any]] = []
    for k in range(t.shape[0]):
        was_stalled = detector.stalled
        if detector.update(float(t[k]), center[k], attraction[k]):
            episodes.append(
                {
                    "start_s": detector.since,
                    "end_s": None,
                    "detected_s": float(t[k]),
                    "position": center[k].tolist(),
                    "distance_m": float(np.linalg.norm(center[k] - attraction[k])),
                    "ended": "end of run",
                }
            )
        elif was_stalled and not detector.stalled:
            episodes[-1]["end_s"] = float(t[k])
            episodes[-1]["ended"] = detector.last_event
    return episodes
