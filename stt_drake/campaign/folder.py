"""A campaign's folder: its lock, ``campaign_spec.json`` (resume only by the same spec)
and ``runs.jsonl`` (one run record a line, read back whatever state a kill or a bad disk
left it in).

* **Lock**: :func:`folder_lock` holds an exclusive ``flock`` on ``DIR/.lock`` while a
  campaign runs there, so a second campaign on the same folder stops at once instead of
  redoing the same runs. The kernel drops the lock when the holder exits, however it
  exits (also SIGKILL); the file stays, holding the last holder's pid and command.
* **Records**: :func:`load_runs` keeps the valid lines of ``runs.jsonl`` and counts the
  rest (not JSON, not an object, a run index or seed that is not a non-negative integer,
  a record the campaign's own check refuses: missing keys, wrong types, another seed);
  a torn last line (no newline: a kill mid-write) is cut off and not counted. The runs of
  the skipped lines are simply not done yet, so a resume redoes them.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import shlex
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict
from pathlib import Path
from typing import Any

from stt_drake.campaign.spec import CampaignError, CampaignSpec
from stt_drake.runlog import restore_non_finite, write_json

RUNS_FILE, SPEC_FILE, LOCK_FILE = "runs.jsonl", "campaign_spec.json", ".lock"
#: Spec fields added after the first campaigns, with the value older specs meant.
SPEC_DEFAULTS = {"guide": True}

Record = dict[str, Any]


@contextlib.contextmanager
def folder_lock(out_dir: Path) -> Iterator[None]:
    """Hold the campaign lock of `out_dir` (which must exist) for the ``with`` block.

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
                f"--out: {out_dir} is in use by another campaign ({holder}); wait for it "
                "to end or choose another --out"
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
                f"--out: {out_dir} already holds a campaign; pass --resume to continue it "
                "or choose another --out"
            )
        try:
            stored = json.loads(spec_path.read_text())
        except (ValueError, OSError) as error:
            raise CampaignError(
                f"--resume: {spec_path} is unreadable ({error}), so this cannot be checked "
                "to be the same campaign; choose another --out"
            ) from None
        if not isinstance(stored, dict):
            stored = {}
        for key, value in wanted.items():
            # a spec written before a field existed holds that field's default
            if key not in ("runs", "scenario") and stored.get(key, SPEC_DEFAULTS.get(key)) != value:
                raise CampaignError(
                    f"--resume: {key} differs from the campaign in {out_dir} "
                    f"({stored.get(key)!r} there, {value!r} now)"
                )
    write_json(spec_path, wanted)


def _is_index(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def _parse(line: bytes) -> Record | None:
    """A line's record, or None when it is not one (its non-finite values restored)."""
    try:
        record = json.loads(line)
    except (ValueError, RecursionError):  # not JSON, not UTF-8, absurdly nested
        return None
    if not (isinstance(record, dict) and _is_index(record.get("run"))):
        return None
    if not _is_index(record.get("seed")):
        return None
    try:
        return restore_non_finite(record)
    except (LookupError, TypeError, ValueError):  # a "non_finite" entry that names nothing
        return None


def load_runs(
    path: Path, valid: Callable[[Record], bool] | None = None
) -> tuple[dict[int, Record], int]:
    """(the runs in `path` by index, the number of malformed lines skipped).

    A line is malformed when it is not a JSON object with non-negative integer ``run`` and
    ``seed``, or `valid` refuses it; the first valid line of a run index wins. A torn last
    line (no newline) is cut off the file and not counted.
    """
    if not path.exists():
        return {}, 0
    data = path.read_bytes()
    keep = data.rfind(b"\n") + 1
    if keep < len(data):
        with path.open("r+b") as stream:
            stream.truncate(keep)
    records: dict[int, Record] = {}
    malformed = 0
    for line in data[:keep].split(b"\n"):
        if not line.strip():
            continue
        record = _parse(line)
        if record is None or (valid is not None and not valid(record)):
            malformed += 1
            continue
        records.setdefault(record["run"], record)
    return records, malformed


def read_records(path: Path) -> dict[int, Record]:
    """The runs in `runs.jsonl` by index (:func:`load_runs` without a record check)."""
    return load_runs(path)[0]
