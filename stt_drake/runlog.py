"""The run log: one schema for what a run records, written once and read everywhere.

A :class:`RunLog` is a read-only mapping of names to numpy arrays — exactly the members of
``log.npz`` — with the decoded views every reader needs (the obstacle beliefs unpacked per
sample and obstacle, the task, the diagnostics) as attributes. It is made from a
simulation's loggers (:meth:`RunLog.from_loggers`), from a ``log.npz``
(:meth:`RunLog.load`) or from any mapping with the same keys (:meth:`RunLog.of`: a dict,
``np.load("log.npz")``, a synthetic log in a test), and written with :meth:`RunLog.save`.

Layout (T samples, m obstacles, n = dimension; "samples first": row k is time ``t[k]``):

========================== =============================================================
key                        contents
========================== =============================================================
name                       str (a 0-d array in an npz)
t                          (T,) seconds
output                     (T, n) robot output y
center, radius             (T, n) tube centre c and (T,) tube radius r
belief                     (T, m·(n+n²+1)) slot-major records [mean (n), covariance (n²),
                           active] (:mod:`stt_drake.core.belief`'s port layout, one row a
                           sample)
obstacle_radius, epsilon,  (m,) the task numbers r_o_j, ε_j, p_d_j of each slot
p_d
full_covariance            0-d bool: the tube and monitor used each Σ_j exactly (else
                           σ_j² = λ_max(Σ_j)); optional, False when absent
avoid_probability          (T, m) q_j(c) = P(‖c − O_j‖ ≥ r_o_j + r_min)
quantile_distance, theta   (T, m) d̂_j and θ_j of the tube law (the tube's diagnostics)
recovery                   (T, m) 1 while the tube recovers from obstacle j, else 0
control                    (T, n) the controller's command u
margins                    (T, 5) in ``stt_drake.core.invariants.INVARIANT_NAMES`` order
output_avoid_probability   (T, m) P(‖y − O_j‖ ≥ r_o_j)
tube_avoid_probability     (T, m) P(‖c − O_j‖ ≥ r_o_j + r)
dimension                  n (0-d)
start, initial_set_radius  (n,) and 0-d: the initial set S = B(start, ·)
target, target_set_radius  (n,) and 0-d: the (final) target set T = B(η, R_T)
r_min, r_max               0-d tube radius bounds (r_max optional for a reader)
mean_speed_bound,          (m,) sup ‖μ̇_j‖ and sup |σ̇_j| of the belief's motion model
sigma_rate_bound           (m/s, steps excluded)
========================== =============================================================

A plant may log more signals, samples first (the UAV's ``wind``; the arm's
``joint_state``, ``requested_torque``, ``applied_torque``, ``funnel_errors``,
``joint_velocity_reference``, ``external_force``; a task sequence's ``task_target``, the
target active at each sample; a guide's ``guide_target``, its η(t)) and constants (the
arm's ``position_lower``, ``position_upper``, ``velocity_limit``, ``effort_limit``); they
are members like any other.

The run's other files are strict JSON (:func:`strict_json`, :func:`write_json`: no
``NaN``/``Infinity``; a non-finite value is ``null`` and named in ``"non_finite"``), in a
folder checked before any work (:func:`unwritable_reason`).

Pure numpy: no Drake is imported (the loggers are read through their methods).
"""

from __future__ import annotations

import json
import tempfile
from collections.abc import Iterator, Mapping, Sequence
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from stt_drake.core.belief import (
    GaussianBelief,
    ObstacleBelief,
    ObstacleTask,
    largest_sigma,
    obstacle_rate_bounds,
    record_size,
)

if TYPE_CHECKING:
    from stt_drake.config import Scenario


class _Log(Protocol):  # pydrake.systems.primitives.VectorLog
    def num_samples(self) -> int: ...
    def data(self) -> np.ndarray: ...
    def sample_times(self) -> np.ndarray: ...


class LogSink(Protocol):
    """What :meth:`RunLog.from_loggers` reads: a ``VectorLogSink`` or a
    :class:`~stt_drake.assembly.loggers.LoggedSignal` (its log in a context)."""

    def FindLog(self, context: Any) -> _Log: ...  # noqa: N802 - Drake's name


class RunLog(Mapping[str, np.ndarray]):
    """A run log (the ``log.npz`` members, see the module docstring) and its decoded views.

    Read-only: the views are decoded once, on first use, from the stored arrays (they are
    views of them where a reshape allows, so they must not be written to).
    """

    def __init__(self, arrays: Mapping[str, Any]) -> None:
        """Hold `arrays` (each made a numpy array, in the given order: the npz order)."""
        self._arrays = {name: np.asarray(arrays[name]) for name in arrays}

    # ------------------------------------------------------------------ making and saving

    @classmethod
    def of(cls, log: Mapping[str, Any]) -> RunLog:
        """`log` as a RunLog: itself if it is one, else its members read once (an npz
        re-reads a member from its zip on every access)."""
        return log if isinstance(log, RunLog) else cls(log)

    @classmethod
    def from_loggers(
        cls,
        loggers: Mapping[str, LogSink],
        root_context: Any,
        scenario: Scenario,
        extra_logs: Sequence[str] = (),
        constants: Mapping[str, Any] | None = None,
    ) -> RunLog:
        """Read every logger of a simulated scenario into the run log.

        Args:
            loggers: the diagram's logger per logged signal (a ``LoggedSignal``, or any
                ``VectorLogSink``): ``output``,
                ``tube`` ([c, r]), ``belief``, ``diagnostics`` ([q, d̂, θ] per obstacle),
                ``recovery``, ``control``, ``margins``, ``output_avoid_probability``,
                ``tube_avoid_probability`` and the names in `extra_logs`.
            root_context: the simulator's (root) context the logs live in.
            scenario: the simulated scenario (name, task, tube bounds, obstacle models).
            extra_logs: plant-specific signals, logged as they are.
            constants: plant-specific constants added to the log.

        A run that an exception stopped during a publish has loggers one sample apart:
        every signal is cut to the samples all loggers have.
        """
        logs = {name: sink.FindLog(root_context) for name, sink in loggers.items()}
        samples = min(log.num_samples() for log in logs.values())
        data = {name: log.data()[:, :samples].T for name, log in logs.items()}
        mean_speed_bound, sigma_rate_bound = obstacle_rate_bounds(scenario.obstacles)
        task = ObstacleTask.of(scenario.obstacles)
        n, m = scenario.dimension, len(scenario.obstacles)
        tube = data["tube"]
        diagnostics = data["diagnostics"].reshape(samples, 3, m)
        arrays = {
            "name": np.array(scenario.name),
            "t": logs["tube"].sample_times()[:samples].copy(),
            "output": data["output"].copy(),
            "center": tube[:, :n].copy(),
            "radius": tube[:, n].copy(),
            "belief": data["belief"].copy(),
            "avoid_probability": diagnostics[:, 0, :].copy(),
            "quantile_distance": diagnostics[:, 1, :].copy(),
            "theta": diagnostics[:, 2, :].copy(),
            "recovery": data["recovery"].copy(),
            "control": data["control"].copy(),
            "margins": data["margins"].copy(),
            "output_avoid_probability": data["output_avoid_probability"].copy(),
            "tube_avoid_probability": data["tube_avoid_probability"].copy(),
            "dimension": np.array(n),
            "start": np.asarray(scenario.start, dtype=float),
            "initial_set_radius": np.array(scenario.initial_set_radius),
            "target": np.asarray(scenario.target, dtype=float),
            "target_set_radius": np.array(scenario.target_set_radius),
            "r_min": np.array(scenario.tube.r_min),
            "r_max": np.array(scenario.tube.r_max),
            "mean_speed_bound": mean_speed_bound,
            "sigma_rate_bound": sigma_rate_bound,
            "obstacle_radius": task.radius,
            "epsilon": task.epsilon,
            "p_d": task.p_d,
        }
        for name in extra_logs:
            arrays[name] = data[name].copy()
        arrays.update({name: np.asarray(value) for name, value in (constants or {}).items()})
        return cls(arrays)

    def save(self, path: str | Path) -> Path:
        """Write every member to `path` as a compressed ``.npz`` (``log.npz``)."""
        np.savez_compressed(path, **self._arrays)
        return Path(path)

    @classmethod
    def load(cls, path: str | Path) -> RunLog:
        """Read a run log written by :meth:`save`."""
        with np.load(path) as data:
            return cls({name: data[name] for name in data.files})

    # ------------------------------------------------------------------ the mapping

    def __getitem__(self, name: str) -> np.ndarray:
        return self._arrays[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._arrays)

    def __len__(self) -> int:
        return len(self._arrays)

    def __repr__(self) -> str:
        return f"RunLog({self.name!r}, {self.samples} samples, keys {list(self._arrays)})"

    def rows(self, name: str, width: int | None = None) -> np.ndarray:
        """Member `name` as float rows, one per sample: (T, width) (None: as logged); how a
        plant-specific signal is read (``log.rows("requested_torque")``)."""
        values = np.asarray(self[name], dtype=float)
        if width is None:
            width = values.shape[-1] if values.ndim > 1 else values.size // max(self.samples, 1)
        return values.reshape(self.samples, width)

    def _scalar(self, name: str) -> float:
        return float(np.asarray(self[name]))

    # ------------------------------------------------------------------ time and task

    @property
    def name(self) -> str:
        """The scenario name ("" when the log has none)."""
        return str(np.asarray(self["name"]).item()) if "name" in self else ""

    @cached_property
    def dimension(self) -> int:
        """n, the dimension of the output space."""
        return int(np.asarray(self["dimension"]))

    @cached_property
    def t(self) -> np.ndarray:
        """(T,) sample times, s."""
        return np.asarray(self["t"], dtype=float)

    @property
    def samples(self) -> int:
        """T, the number of logged samples."""
        return self.t.shape[0]

    @cached_property
    def start(self) -> np.ndarray:
        """(n,) centre of the initial set."""
        return np.asarray(self["start"], dtype=float).reshape(self.dimension)

    @property
    def initial_set_radius(self) -> float:
        """Radius of the initial set, m."""
        return self._scalar("initial_set_radius")

    @cached_property
    def target(self) -> np.ndarray:
        """(n,) η, the (final) target."""
        return np.asarray(self["target"], dtype=float).reshape(self.dimension)

    @property
    def target_set_radius(self) -> float:
        """R_T, m."""
        return self._scalar("target_set_radius")

    @cached_property
    def active_target(self) -> np.ndarray:
        """(T, n) the target active at each sample: a task sequence's logged
        ``task_target``, else :attr:`target` at every sample."""
        if "task_target" in self:
            return self.rows("task_target")
        return np.broadcast_to(self.target, (self.samples, self.dimension))

    @cached_property
    def attraction_point(self) -> np.ndarray:
        """(T, n) η(t), the point the tube centre is attracted to at each sample: a guide's
        logged ``guide_target``, else :attr:`active_target`."""
        if "guide_target" in self:
            return self.rows("guide_target", self.dimension)
        return self.active_target

    @property
    def r_min(self) -> float:
        """The tube's minimum radius r_min, m."""
        return self._scalar("r_min")

    @property
    def r_max(self) -> float | None:
        """The tube's maximum radius r_max, m (None when the log has none)."""
        return self._scalar("r_max") if "r_max" in self else None

    # ------------------------------------------------------------------ robot and tube

    @cached_property
    def output(self) -> np.ndarray:
        """(T, n) robot output y."""
        return self.rows("output", self.dimension)

    @cached_property
    def center(self) -> np.ndarray:
        """(T, n) tube centre c."""
        return self.rows("center", self.dimension)

    @cached_property
    def radius(self) -> np.ndarray:
        """(T,) tube radius r (the obstacles' radii are :attr:`obstacle_radius`)."""
        return np.asarray(self["radius"], dtype=float).reshape(self.samples)

    @property
    def control(self) -> np.ndarray | None:
        """(T, n) the command u (None when the log has none)."""
        return self.rows("control") if "control" in self else None

    # ------------------------------------------------------------------ obstacle beliefs

    @cached_property
    def _belief(self) -> GaussianBelief:
        """Every logged slot record, (T·m) slots in sample-major order."""
        rows = self.rows("belief")
        record = record_size(self.dimension)
        if rows.shape[1] % record:
            raise ValueError(
                f"belief rows of length {rows.shape[1]} are not a whole number of "
                f"{record}-long slot records [mean, covariance, active] for dimension "
                f"{self.dimension}"
            )
        return GaussianBelief.from_vector(rows.ravel(), self.dimension)

    @cached_property
    def count(self) -> int:
        """m, the number of obstacle slots."""
        return self.rows("belief").shape[1] // record_size(self.dimension)

    def _per_obstacle(self, values: np.ndarray) -> np.ndarray:
        return values.reshape(self.samples, self.count, *values.shape[1:])

    def _per_sample(self, name: str) -> np.ndarray:
        """(T, m) view of the task constant `name` ((m,)), repeated for every sample."""
        values = np.asarray(self[name], dtype=float)
        return np.broadcast_to(values, (self.samples, values.shape[0]))

    @cached_property
    def mean(self) -> np.ndarray:
        """(T, m, n) belief means μ_j."""
        return self._per_obstacle(self._belief.mean)

    @cached_property
    def belief_covariance(self) -> np.ndarray:
        """(T, m, n, n) belief covariances Σ_j (m²), whatever law the tube used."""
        return self._per_obstacle(self._belief.covariance)

    @cached_property
    def active(self) -> np.ndarray:
        """(T, m) bool: slot j held a track at sample k."""
        return self._per_obstacle(self._belief.active)

    @cached_property
    def shown_mean(self) -> np.ndarray:
        """(T, m, n) :attr:`mean` with NaN where the slot held no track (for drawing)."""
        return np.where(self.active[..., None], self.mean, np.nan)

    @cached_property
    def shown_sigma(self) -> np.ndarray:
        """(T, m) :attr:`sigma` with NaN where the slot held no track (for drawing)."""
        return np.where(self.active, self.sigma, np.nan)

    @cached_property
    def sigma(self) -> np.ndarray:
        """(T, m) σ_j = √λ_max(Σ_j), the belief's largest standard deviation (m)."""
        return largest_sigma(self.belief_covariance)

    @cached_property
    def full_covariance(self) -> bool:
        """Whether the tube and monitor used each Σ_j exactly."""
        return bool(self["full_covariance"]) if "full_covariance" in self else False

    @cached_property
    def obstacle_radius(self) -> np.ndarray:
        """(T, m) obstacle radii r_o_j."""
        return self._per_sample("obstacle_radius")

    @cached_property
    def mean_clearance(self) -> np.ndarray:
        """(T, m) ‖y − μ_j‖ − r_o_j (m): the output's distance to the surface of obstacle j
        at its mean (negative inside it); NaN where slot j held no track."""
        distance = np.linalg.norm(self.output[:, None, :] - self.mean, axis=2)
        return np.where(self.active, distance - self.obstacle_radius, np.nan)

    @cached_property
    def epsilon(self) -> np.ndarray:
        """(T, m) required avoidance probabilities ε_j."""
        return self._per_sample("epsilon")

    @cached_property
    def p_d(self) -> np.ndarray:
        """(T, m) separation levels p_d_j of Assumption 3."""
        return self._per_sample("p_d")

    @cached_property
    def covariance(self) -> np.ndarray | None:
        """(T, m, n, n) full covariances Σ_j (m²) of a run whose tube used them, else None."""
        return self.belief_covariance if self.full_covariance else None

    @cached_property
    def task(self) -> ObstacleTask:
        """r_o, ε, p_d of every slot."""
        return ObstacleTask(
            np.asarray(self["obstacle_radius"], dtype=float),
            np.asarray(self["epsilon"], dtype=float),
            np.asarray(self["p_d"], dtype=float),
        )

    def belief_at(self, index: int) -> ObstacleBelief:
        """The belief of the slots active at sample `index`, as the tube law read it
        (:meth:`ObstacleBelief.of`); all m slots in a run without a tracker."""
        gaussian = GaussianBelief(
            self.mean[index], self.belief_covariance[index], self.active[index]
        )
        return ObstacleBelief.of(gaussian, self.task, self.full_covariance)

    @cached_property
    def mean_speed_bound(self) -> np.ndarray:
        """(m,) sup ‖μ̇_j‖, m/s (steps excluded)."""
        return np.asarray(self["mean_speed_bound"], dtype=float)

    @cached_property
    def sigma_rate_bound(self) -> np.ndarray:
        """(m,) sup |σ̇_j|, m/s (steps excluded)."""
        return np.asarray(self["sigma_rate_bound"], dtype=float)

    # ------------------------------------------------------------------ diagnostics

    @cached_property
    def avoid_probability(self) -> np.ndarray:
        """(T, m) the tube's q_j(c) (buffered radius r_o_j + r_min)."""
        return self.rows("avoid_probability", self.count)

    @cached_property
    def quantile_distance(self) -> np.ndarray:
        """(T, m) the tube law's d̂_j."""
        return self.rows("quantile_distance", self.count)

    @cached_property
    def theta(self) -> np.ndarray:
        """(T, m) the tube law's θ_j."""
        return self.rows("theta", self.count)

    @cached_property
    def recovery(self) -> np.ndarray:
        """(T, m) bool: the tube recovers from obstacle j (logged flag = 1)."""
        return self.rows("recovery", self.count) == 1.0

    @cached_property
    def margins(self) -> np.ndarray:
        """(T, 5) every guarantee's margin (``INVARIANT_NAMES`` order)."""
        return self.rows("margins")

    @cached_property
    def output_avoid_probability(self) -> np.ndarray:
        """(T, m) P(‖y − O_j‖ ≥ r_o_j)."""
        return self.rows("output_avoid_probability", self.count)

    @cached_property
    def tube_avoid_probability(self) -> np.ndarray:
        """(T, m) P(‖c − O_j‖ ≥ r_o_j + r)."""
        return self.rows("tube_avoid_probability", self.count)


# ---------------------------------------------------------------------- the other files

#: The key that lists a JSON document's non-finite values (see :func:`strict_json`).
NON_FINITE_KEY = "non_finite"


def _pointer_part(key: object) -> str:
    return str(key).replace("~", "~0").replace("/", "~1")


def _finite_copy(value: Any, pointer: str, found: dict[str, str]) -> Any:
    """`value` with numpy scalars and arrays as Python values and every non-finite float
    replaced by None (its JSON pointer and ``repr`` recorded in `found`)."""
    if isinstance(value, Mapping):
        return {
            str(key): _finite_copy(item, f"{pointer}/{_pointer_part(key)}", found)
            for key, item in value.items()
        }
    if isinstance(value, list | tuple | np.ndarray):
        items = value.tolist() if isinstance(value, np.ndarray) else value
        return [_finite_copy(item, f"{pointer}/{k}", found) for k, item in enumerate(items)]
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        number = float(value)
        if not np.isfinite(number):
            found[pointer] = repr(number)  # "inf", "-inf" or "nan"
            return None
        return number
    return value


def strict_json(document: Mapping[str, Any], indent: int | None = None) -> str:
    """`document` as strict JSON (RFC 8259: no ``NaN``/``Infinity`` tokens), one line
    unless `indent` is given; every JSON file the package writes goes through here.

    A non-finite number is written as ``null`` and named, with its value, in the
    document's top-level ``"non_finite"`` object: JSON pointer (RFC 6901) → ``"inf"``,
    ``"-inf"`` or ``"nan"``, e.g. ``{"/invariants/output_in_tube/worst_margin": "inf"}``
    (the key is present only when there is one). :func:`restore_non_finite` undoes it.
    """
    found: dict[str, str] = {}
    clean = _finite_copy(document, "", found)
    if found:
        clean[NON_FINITE_KEY] = {**clean.get(NON_FINITE_KEY, {}), **found}
    return json.dumps(clean, indent=indent, allow_nan=False)


def write_json(path: str | Path, document: Mapping[str, Any]) -> Path:
    """Write `document` to `path` as indented strict JSON (:func:`strict_json`)."""
    path = Path(path)
    path.write_text(strict_json(document, indent=2) + "\n")
    return path


def restore_non_finite(document: dict[str, Any]) -> dict[str, Any]:
    """Undo :func:`strict_json`'s replacements in a parsed document, in place: each value
    named in ``"non_finite"`` gets its float back and the key is removed. Returns it."""
    named = document.pop(NON_FINITE_KEY, None)
    if not isinstance(named, dict):
        return document
    for pointer, text in named.items():
        parts = [p.replace("~1", "/").replace("~0", "~") for p in str(pointer).split("/")[1:]]
        parent: Any = document
        for part in parts[:-1]:
            parent = parent[int(part)] if isinstance(parent, list) else parent[part]
        last = parts[-1]
        if isinstance(parent, list):
            parent[int(last)] = float(text)
        else:
            parent[last] = float(text)
    return document


def unwritable_reason(folder: str | Path) -> str | None:
    """Why files cannot be written into `folder` (created if missing), or None if they can.

    Writes nothing: the nearest existing ancestor must be a folder in which an unnamed
    temporary file can be made (``O_TMPFILE``, gone when closed), so permissions,
    read-only file systems and a file in the way are all found before any work is done.
    """
    folder = Path(folder)
    existing = folder
    try:
        while not existing.exists() and existing.parent != existing:
            existing = existing.parent
    except (OSError, ValueError) as error:  # cannot even be looked at (EACCES, a NUL byte)
        return f"cannot be reached: {getattr(error, 'strerror', None) or error}"
    if not existing.is_dir():
        where = "" if existing == folder else f" ({existing} is in the way)"
        return f"is not a folder{where}"
    try:
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as error:
        where = "" if existing == folder else f" (in {existing})"
        return f"cannot be written{where}: {error.strerror or error}"
    return None
