"""Recorded obstacle tracks from data files: ``motion: !Recorded {file: tracks.csv, id: 3}``
(:class:`stt_drake.core.motion.Recorded`), read and checked once per load.

Formats (SI units, one row per sample):

* CSV: a header ``t,id,x,y`` (2D) or ``t,id,x,y,z`` (3D), then one line of numbers per
  sample: time t (s), track id (an integer), position (m);
* NPZ (``numpy.savez``): arrays ``t`` (N,), ``id`` (N,) and ``position`` (N, n).

The rows of different ids may interleave; the rows of one id are its samples in time order.
`file` is relative to the scenario file's folder (a scenario read from text without a
path: the current folder); an absolute path is used as it is. Each file is read once per
load, however many obstacles name it (cached by its resolved path for that load).

The rules (every error names the field path and the rule, as the loader's do):

* the file exists, is a .csv or .npz of at most :data:`MAX_TRACK_FILE_BYTES`, with the
  header (CSV) or arrays (NPZ) above, every value finite and at most
  :data:`stt_drake.config.limits.MAX_MAGNITUDE` in magnitude, the ids integers
  (``...motion.file``);
* the position has the scenario's dimension n (``...motion.file``);
* the id is in the file (``...motion.id``) with at least 2 samples, times increasing
  strictly: a repeated time is refused — a recorded track has one position per time, a
  repeated stamp is a logging error, and a deliberate jump is written as a ``!Waypoints``
  step (``...motion.id``);
* no gap between consecutive samples longer than :data:`MAX_GAP_RATIO` times the track's
  median spacing (``...motion.id``): linear interpolation across such a gap would invent a
  straight walk the recording never saw (at 10 Hz a gap over 1 s: ten samples missing in
  a row), and the fixed-rate tube's speed bound (the largest segment speed) would be set
  by it. A track with a long gap is two tracks: give them two ids.

Outside its span [t_first, t_last] the obstacle does not exist (its belief slot is
inactive); :mod:`stt_drake.config.validate` checks the span against the run.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stt_drake.config.limits import MAX_MAGNITUDE
from stt_drake.config.schema import PLANT_DIMENSION, Scenario, ScenarioError
from stt_drake.core.motion import Recorded, Track

#: Largest track file read (bytes): 64 MiB, about 1.5 million 2D CSV rows.
MAX_TRACK_FILE_BYTES = 64 * 1024 * 1024

#: Largest gap between consecutive samples of a track, in multiples of its median spacing.
MAX_GAP_RATIO = 10.0

#: The CSV headers, by dimension.
CSV_HEADERS = {2: ("t", "id", "x", "y"), 3: ("t", "id", "x", "y", "z")}

#: The arrays of an NPZ track file.
NPZ_ARRAYS = ("t", "id", "position")


@dataclass(frozen=True)
class TrackFile:
    """One track file's samples grouped by id: rows ``start[i]:stop[i]`` of `times`,
    `positions` and `rows` (each sample's place in the file, for messages: the CSV data row
    counted from 1 after the header, the NPZ index) are the samples of ``ids[i]``, in file
    order."""

    path: Path
    ids: np.ndarray
    start: np.ndarray
    stop: np.ndarray
    times: np.ndarray
    positions: np.ndarray
    rows: np.ndarray
    row_name: str

    @property
    def dimension(self) -> int:
        return self.positions.shape[1]

    def samples(self, track_id: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """(times, positions, rows) of `track_id`, or None when the file has no such id."""
        i = int(np.searchsorted(self.ids, track_id))
        if i == self.ids.size or self.ids[i] != track_id:
            return None
        part = slice(int(self.start[i]), int(self.stop[i]))
        return self.times[part], self.positions[part], self.rows[part]


def attach_tracks(scenario: Scenario, base: Path | None = None) -> None:
    """Read the track of every ``!Recorded`` obstacle motion of `scenario` and attach it
    (:meth:`stt_drake.core.motion.Recorded.attach`), each file once; `base` is the folder a
    relative `file` is in (None: the current folder).

    Raises:
        ScenarioError: a rule of the module docstring is broken (the message names the
            field path, ``scenario.obstacles[j].motion.file`` or ``.id``, and the rule).
    """
    recorded = [
        (j, o.motion) for j, o in enumerate(scenario.obstacles) if isinstance(o.motion, Recorded)
    ]
    if not recorded:
        return
    folder = Path.cwd() if base is None else Path(base)
    dimension = PLANT_DIMENSION.get(type(scenario.plant), scenario.dimension)
    files: dict[Path, TrackFile] = {}
    for j, motion in recorded:
        where = f"scenario.obstacles[{j}].motion"
        if not motion.file:
            raise ScenarioError(f"{where}.file: must name a track file (.csv or .npz)")
        path = (folder / motion.file).resolve()
        if path not in files:
            files[path] = read_track_file(path, f"{where}.file")
        motion.attach(track_from_file(files[path], motion.id, dimension, where))


def read_track_file(path: Path, where: str) -> TrackFile:
    """The samples of a CSV or NPZ track file (module docstring), grouped by id; the file's
    own rules checked (`where` names the field in messages)."""
    suffix = path.suffix.lower()
    if suffix not in (".csv", ".npz"):
        raise ScenarioError(
            f"{where}: {path.name}: a track file must be a .csv (header t,id,x,y or "
            "t,id,x,y,z) or an .npz (arrays t, id, position)"
        )
    if not path.is_file():
        raise ScenarioError(
            f"{where}: no such track file {str(path)!r} (a relative name is relative to the "
            "scenario file's folder)"
        )
    size = path.stat().st_size
    if size > MAX_TRACK_FILE_BYTES:
        raise ScenarioError(
            f"{where}: {path.name} has {size} bytes; a track file may have at most "
            f"{MAX_TRACK_FILE_BYTES} (64 MiB)"
        )
    if suffix == ".csv":
        times, ids, positions = _read_csv(path, where)
        first_row, row_name = 1, "data row"  # counted after the header, from 1
    else:
        times, ids, positions = _read_npz(path, where)
        first_row, row_name = 0, "index"
    if times.size == 0:
        raise ScenarioError(f"{where}: {path.name} holds no samples")
    _check_values(times, ids, positions, path.name, where, first_row, row_name)
    order = np.argsort(ids, kind="stable")
    sorted_ids = ids[order].astype(np.int64)
    unique, start = np.unique(sorted_ids, return_index=True)
    stop = np.append(start[1:], sorted_ids.size)
    return TrackFile(
        path=path,
        ids=unique,
        start=start,
        stop=stop,
        times=times[order],
        positions=positions[order],
        rows=order + first_row,
        row_name=row_name,
    )


def _read_csv(path: Path, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    with path.open("r", encoding="utf-8", errors="replace", newline="") as stream:
        header = tuple(name.strip() for name in stream.readline().lstrip("\ufeff").split(","))
        if header not in CSV_HEADERS.values():
            written = ",".join(header)[:80]
            raise ScenarioError(
                f"{where}: {path.name}: the first line must be the header t,id,x,y (2D) or "
                f"t,id,x,y,z (3D) (got {written!r})"
            )
        try:
            data = np.loadtxt(stream, delimiter=",", dtype=float, ndmin=2)
        except ValueError as error:
            raise ScenarioError(
                f"{where}: {path.name}: every line after the header must hold {len(header)} "
                f"numbers separated by commas ({str(error)[:200]})"
            ) from None
    if data.size == 0:
        return np.empty(0), np.empty(0), np.empty((0, len(header) - 2))
    if data.shape[1] != len(header):
        raise ScenarioError(
            f"{where}: {path.name}: the lines hold {data.shape[1]} numbers; the header "
            f"{','.join(header)} names {len(header)}"
        )
    return data[:, 0], data[:, 1], data[:, 2:]


def _read_npz(path: Path, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    try:
        with np.load(path, allow_pickle=False) as archive:
            missing = [name for name in NPZ_ARRAYS if name not in archive.files]
            if missing:
                raise ScenarioError(
                    f"{where}: {path.name}: an NPZ track file needs the arrays t (N,), id (N,) "
                    f"and position (N, n); missing: {', '.join(missing)}"
                )
            arrays = [np.asarray(archive[name]) for name in NPZ_ARRAYS]
    except (OSError, ValueError, EOFError) as error:
        raise ScenarioError(
            f"{where}: {path.name}: not a readable NPZ file of numeric arrays ({str(error)[:200]})"
        ) from None
    times, ids, positions = arrays
    count = times.shape[0] if times.ndim == 1 else -1
    if (
        times.ndim != 1
        or ids.shape != (count,)
        or positions.ndim != 2
        or positions.shape[0] != count
    ):
        raise ScenarioError(
            f"{where}: {path.name}: the arrays must be t (N,), id (N,) and position (N, n) "
            f"(got shapes {times.shape}, {ids.shape}, {positions.shape})"
        )
    if not all(np.issubdtype(a.dtype, np.number) for a in arrays):
        raise ScenarioError(f"{where}: {path.name}: t, id and position must be numeric arrays")
    return times.astype(float), ids.astype(float), positions.astype(float)


def _check_values(
    times: np.ndarray,
    ids: np.ndarray,
    positions: np.ndarray,
    name: str,
    where: str,
    first_row: int,
    row_name: str,
) -> None:
    """Finite values of at most MAX_MAGNITUDE, integer ids: the first bad row named."""
    values = np.column_stack([times, ids, positions])
    bad = ~np.isfinite(values) | (np.abs(values) > MAX_MAGNITUDE)
    if bad.any():
        row = int(np.flatnonzero(bad.any(axis=1))[0])
        raise ScenarioError(
            f"{where}: {name}: {row_name} {row + first_row} holds {values[row].tolist()}: every "
            f"value must be finite and at most {MAX_MAGNITUDE:g} in magnitude"
        )
    fractional = ids != np.round(ids)
    if fractional.any():
        row = int(np.flatnonzero(fractional)[0])
        raise ScenarioError(
            f"{where}: {name}: {row_name} {row + first_row} has id {ids[row]!r}: a track id "
            "must be an integer"
        )


def track_from_file(file: TrackFile, track_id: int, dimension: int, where: str) -> Track:
    """The track of `track_id` in `file`, checked (module docstring); `where` is the
    motion's field path."""
    name = file.path.name
    if file.dimension != dimension:
        raise ScenarioError(
            f"{where}.file: {name} holds {file.dimension}D positions; this scenario is "
            f"{dimension}D (its plant works in {dimension} dimensions)"
        )
    found = file.samples(track_id)
    if found is None:
        shown = ", ".join(str(int(i)) for i in file.ids[:10])
        more = ", ..." if file.ids.size > 10 else ""
        raise ScenarioError(
            f"{where}.id: {track_id} is not a track id of {name} (its ids: {shown}{more})"
        )
    times, positions, rows = found
    if times.size < 2:
        raise ScenarioError(
            f"{where}.id: track {track_id} of {name} has {times.size} sample; a recorded track "
            "needs at least 2 (a fixed obstacle is a !ConstantVelocity with velocity 0)"
        )
    steps = np.diff(times)
    if not bool(np.all(steps > 0.0)):
        k = int(np.flatnonzero(steps <= 0.0)[0])
        raise ScenarioError(
            f"{where}.id: track {track_id} of {name}: time {times[k + 1]:g} s at "
            f"{file.row_name} {rows[k + 1]} does not follow {times[k]:g} s at "
            f"{file.row_name} {rows[k]}: a track's samples must increase strictly in time (a "
            "repeated time is refused; write a jump as a !Waypoints step)"
        )
    spacing = float(np.median(steps))
    gaps = steps > MAX_GAP_RATIO * spacing
    if gaps.any():
        k = int(np.flatnonzero(gaps)[0])
        raise ScenarioError(
            f"{where}.id: track {track_id} of {name} has a gap of {steps[k]:g} s from "
            f"{times[k]:g} s ({file.row_name} {rows[k]}): more than {MAX_GAP_RATIO:g} times "
            f"its median sample spacing {spacing:g} s; interpolating across it would invent "
            "motion: split the track into two ids"
        )
    return Track(times, positions)
