"""A campaign's folder: its lock, ``campaign_spec.json`` (resume only by the same spec)
and ``runs.jsonl`` (one run record a line, read back whatever state a kill or a bad disk
left it in).

* **Lock**: :func:`folder_lock` holds an exclusive ``flock`` on ``DIR/.lock`` while a
  campaign runs there, so a second campaign on the same folder stops at once instead of
  redoing the same runs. The kernel drops the lock when the holder exits, however it
  exits (also SIGKILL); the file stays, holding the last holder's pid and command.
* **Records**: every line is written by :func:`record_line`, with a ``"sha256"`` checksum
  of the record's canonical JSON (:func:`record_checksum`). :func:`scan_runs` keeps the
  valid lines of ``runs.jsonl`` and counts the rest (not JSON, not an object, a run index
  or seed that is not a non-negative integer, a checksum that is missing or wrong — an
  edited line, or one written before records had checksums — a record the campaign's own
  check refuses: missing keys, wrong types, another seed); a torn last line (no newline:
  a kill mid-write) is cut off and not counted. The runs of the skipped lines are simply
  not done yet, so a resume redoes them.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import shlex
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from stt_drake.campaign.spec import CampaignError, CampaignSpec
from stt_drake.core.crowd_metrics import DEFAULT_COMFORT_DISTANCE
from stt_drake.runlog import restore_non_finite, strict_json, write_json

RUNS_FILE, SPEC_FILE, LOCK_FILE = "runs.jsonl", "campaign_spec.json", ".lock"
#: The key of a run record's checksum in runs.jsonl (:func:`record_checksum`).
CHECKSUM_KEY = "sha256"
#: Why a line that is a run record was not taken: no checksum, or a wrong one.
NO_CHECKSUM, BAD_CHECKSUM = "no checksum", "checksum mismatch"
#: Spec fields added after the first campaigns, with the value older specs meant.
SPEC_DEFAULTS = {"guide": True, "comfort_distance": DEFAULT_COMFORT_DISTANCE}

Record = dict[str, Any]


@contextlib.contextmanager
def folder_lock(out_dir: Path, what: str = "campaign") -> Iterator[None]:
    """Hold the lock of `out_dir` (which must exist) for the ``with`` block; `what` (a
    campaign, a comparison) names the work in the refusal.

    Raises:
        CampaignError: another process holds it (the message names the folder and the
            holder: pid, start time, command).
    """
    path = out_dir / LOCK_FILE
    descriptor = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)  # not inherited by children
    try:
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = path.read_text(errors="replace").strip() or "a process that is starting"
            raise CampaignError(
                f"`out_dir`: {out_dir} is in use by another {what} ({holder}); wait for it "
                "to end or choose another `out_dir`"
            ) from None
        command = shlex.join([Path(sys.argv[0]).name, *sys.argv[1:]])
        started = time.strftime("%Y-%m-%d %H:%M:%S")
        os.ftruncate(descriptor, 0)
        os.write(descriptor, f"pid {os.getpid()} since {started}: {command}\n".encode())
        yield
    finally:
        os.close(descriptor)  # releases the lock


def check_resumable(out_dir: Path, spec: CampaignSpec, text_hash: str, resume: bool) -> None:
    """Refuse to overwrite a campaign without `resume`, or to resume another spec (up to
    `runs`); then write ``campaign_spec.json``."""
    spec_path = out_dir / SPEC_FILE
    wanted = {**asdict(spec), "scenario_sha256": text_hash}
    if spec_path.exists() and (out_dir / RUNS_FILE).exists():
        if not resume:
            raise CampaignError(
                f"`out_dir`: {out_dir} already holds a campaign; pass `resume` to continue it "
                "or choose another `out_dir`"
            )
        check_same_spec(spec_path, wanted, "campaign", ("runs", "scenario"), SPEC_DEFAULTS)
    write_json(spec_path, wanted)


def check_same_spec(
    path: Path,
    wanted: dict[str, Any],
    what: str,
    free: tuple[str, ...] = (),
    defaults: dict[str, Any] | None = None,
) -> None:
    """Refuse to resume unless the spec stored at `path` equals `wanted` (CampaignError
    naming the first key that differs), except the `free` keys (the run count may grow,
    the path may be written differently); a key a spec written before it existed lacks
    reads as its value in `defaults`. `what` names the thing resumed in the messages."""
    try:
        stored = json.loads(path.read_text())
    except (ValueError, OSError) as error:
        raise CampaignError(
            f"`resume`: {path} is unreadable ({error}), so this cannot be checked "
            f"to be the same {what}; choose another `out_dir`"
        ) from None
    if not isinstance(stored, dict):
        stored = {}
    defaults = defaults or {}
    for key, value in wanted.items():
        if key not in free and stored.get(key, defaults.get(key)) != value:
            raise CampaignError(
                f"`resume`: {key} differs from the {what} in {path.parent} "
                f"({stored.get(key)!r} there, {value!r} now)"
            )


def is_number(value: Any) -> bool:
    """Whether a value read back from a record is a JSON number (an int or a float, not a
    bool, which Python counts as an int)."""
    return isinstance(value, int | float) and not isinstance(value, bool)


def _is_index(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def _canonical(document: Any) -> bytes:
    """The canonical JSON of a parsed strict-JSON document: sorted keys, no spaces."""
    return json.dumps(document, sort_keys=True, separators=(",", ":"), allow_nan=False).encode()


def record_checksum(document: dict[str, Any]) -> str:
    """The sha256 (hex) of a record as written: `document` is the parsed strict JSON of
    the record (``"non_finite"`` included), without its checksum key."""
    return hashlib.sha256(_canonical(document)).hexdigest()


def record_line(record: Record) -> str:
    """`record` as one line of runs.jsonl (no newline): strict JSON with its checksum
    (:data:`CHECKSUM_KEY`, the last key)."""
    text = strict_json({k: v for k, v in record.items() if k != CHECKSUM_KEY})
    checksum = record_checksum(json.loads(text))  # of what a reader will parse
    return f'{text[:-1]}, "{CHECKSUM_KEY}": "{checksum}"}}'  # text is a JSON object


def _parse(line: bytes, checksums: bool = True) -> tuple[Record | None, str | None]:
    """(a line's run record, why its checksum failed): the record with its checksum checked
    (with `checksums`) and removed, its non-finite values restored, and None; for a run
    record whose checksum is missing or wrong, the record as read and :data:`NO_CHECKSUM`
    or :data:`BAD_CHECKSUM`; (None, None) when the line is not a run record at all."""
    try:
        record = json.loads(line)
    except (ValueError, RecursionError):  # not JSON, not UTF-8, absurdly nested
        return None, None
    if not (isinstance(record, dict) and _is_index(record.get("run"))):
        return None, None
    if not _is_index(record.get("seed")):
        return None, None
    checksum = record.pop(CHECKSUM_KEY, None)
    try:
        if checksums and checksum is None:
            return record, NO_CHECKSUM
        if checksums and checksum != record_checksum(record):
            return record, BAD_CHECKSUM
        return restore_non_finite(record), None
    except (LookupError, TypeError, ValueError, RecursionError):  # e.g. a "non_finite"
        return None, None  # entry that names nothing


@dataclass
class RunsFile:
    """What :func:`scan_runs` read: the valid runs by index, the number of lines skipped
    (`malformed`, checksum failures included) and, by run index, why a line that is a run
    record failed its checksum (:data:`NO_CHECKSUM` or :data:`BAD_CHECKSUM`)."""

    records: dict[int, Record] = field(default_factory=dict)
    malformed: int = 0
    tampered: dict[int, str] = field(default_factory=dict)


def scan_runs(
    path: Path, valid: Callable[[Record], bool] | None = None, checksums: bool = True
) -> RunsFile:
    """The runs in `path` (:class:`RunsFile`).

    A line is skipped (counted in `malformed`) when it is not a JSON object with
    non-negative integer ``run`` and ``seed``, when its checksum is missing or wrong (with
    `checksums`; the run is also named in `tampered`), or when `valid` refuses it; the
    first valid line of a run index wins. A torn last line (no newline) is cut off the file
    and not counted. Without `checksums` the checksum is removed unchecked.
    """
    found = RunsFile()
    if not path.exists():
        return found
    data = path.read_bytes()
    keep = data.rfind(b"\n") + 1
    if keep < len(data):
        with path.open("r+b") as stream:
            stream.truncate(keep)
    for line in data[:keep].split(b"\n"):
        if not line.strip():
            continue
        record, failure = _parse(line, checksums)
        if record is not None and failure is not None:
            found.tampered.setdefault(record["run"], failure)
        if record is None or failure is not None or (valid is not None and not valid(record)):
            found.malformed += 1
            continue
        found.records.setdefault(record["run"], record)
    return found


def load_runs(
    path: Path, valid: Callable[[Record], bool] | None = None
) -> tuple[dict[int, Record], int]:
    """(the runs in `path` by index, the number of lines skipped): :func:`scan_runs`,
    checksums checked."""
    found = scan_runs(path, valid)
    return found.records, found.malformed


def read_records(path: Path) -> dict[int, Record]:
    """The runs in `runs.jsonl` by index, for reading results: :func:`scan_runs` without a
    record check and without checking checksums (they are removed)."""
    return scan_runs(path, checksums=False).records


def tampered_lines(tampered: dict[int, str], records: dict[int, Record], limit: int = 10) -> str:
    """The lines to say on stderr about runs whose checksum failed: ``run N: checksum
    mismatch, redone`` (or ``no checksum``; ``..., skipped`` when a later line of the run
    is valid), the first `limit` by name and then how many more."""
    lines = []
    for run in sorted(tampered)[:limit]:
        done = "skipped (a valid record of the run is kept)" if run in records else "redone"
        lines.append(f"run {run}: {tampered[run]}, {done}")
    if len(tampered) > limit:
        redone = sum(run not in records for run in tampered)
        lines.append(
            f"... and {len(tampered) - limit} more run(s) whose checksum is missing or wrong "
            f"({redone} of all {len(tampered)} redone)"
        )
    return "\n".join(lines)
