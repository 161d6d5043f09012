"""What `stt-drake compare` refuses before any simulation, and its output folder.

Both comparisons (:mod:`stt_drake.compare`, one scenario and a campaign per controller;
:mod:`stt_drake.compare_draws`, every controller on K randomised draws) use:

* :class:`CompareError`, bad input (exit 2), the message naming the parameter or field;
* :func:`check_common`: ``controllers`` against a perception scenario (the baselines
  would read another belief than STT), ``workers``
  (:func:`~stt_drake.campaign.backends.check_workers`);
* :func:`comparison_folder`: the out folder locked for the whole comparison (the
  campaigns' lock, :func:`stt_drake.campaign.folder.folder_lock`, on ``DIR/.lock``), and a
  folder that already holds a comparison refused without ``resume``, at once;
* :func:`check_resumed_loop`: a resumed campaign must sample against the closed loop it
  started with (:func:`same_closed_loop`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from stt_drake.campaign import CLOSED_LOOP_FILE, CampaignError, ClosedLoop
from stt_drake.campaign.backends import check_workers
from stt_drake.campaign.folder import RUNS_FILE, SPEC_FILE, folder_lock
from stt_drake.config import draws_obstacles
from stt_drake.runlog import unwritable_reason

#: The controllers that are not STT (they read the obstacles' scripted belief).
BASELINE_CONTROLLERS = ("cbf", "apf")
COMPARISON_FILE, DRAWS_FILE = "comparison.json", "draws.jsonl"


class CompareError(ValueError):
    """Bad input to `compare`; the message names the parameter in backticks (the command
    line shows its flag, :func:`stt_drake.cli.main.flag_message`) or the scenario's field."""


def check_common(schema: Any, controllers: Sequence[str], workers: int | None) -> None:
    """Refuse what both comparisons refuse (:class:`CompareError`): a scenario without
    any obstacle (every row is a true-obstacle check), a baseline on a
    scenario with a ``perception`` section, and a bad ``workers``. `schema` is the
    parsed scenario (its ``perception`` field is read)."""
    baselines = [c for c in controllers if c in BASELINE_CONTROLLERS]
    if not schema.obstacles and not draws_obstacles(schema):
        raise CompareError(
            "scenario.obstacles: compare checks every controller against true obstacles; "
            "the scenario has none (nothing to compare on)"
        )
    if getattr(schema, "perception", None) is not None and baselines:
        raise CompareError(
            "scenario.perception: with perception in the loop STT reads the Kalman tracker's "
            f"belief while the baselines ({', '.join(baselines)}) read the obstacles' scripted "
            "prior, so they would not be compared on the same obstacle belief; compare a copy "
            "of the scenario without its perception section, or only stt / stt-guided"
        )
    try:
        check_workers(workers)
    except CampaignError as error:
        raise CompareError(str(error)) from None


def check_out(out_dir: Path) -> None:
    """Refuse an out folder that cannot be written (:class:`CompareError`, ``out_dir``)."""
    reason = unwritable_reason(out_dir)
    if reason is not None:
        raise CompareError(f"`out_dir`: {out_dir} {reason}")


def _holds_comparison(out_dir: Path, campaign_folders: Iterable[Path]) -> bool:
    if any((out_dir / name).exists() for name in (COMPARISON_FILE, DRAWS_FILE)):
        return True
    return any((f / SPEC_FILE).exists() or (f / RUNS_FILE).exists() for f in campaign_folders)


@contextlib.contextmanager
def comparison_folder(
    out_dir: Path, resume: bool, campaign_folders: Iterable[Path] = ()
) -> Iterator[None]:
    """Create and lock `out_dir` for the ``with`` block; without `resume`, refuse a folder
    that already holds a comparison (comparison.json, draws.jsonl, or a campaign in one of
    `campaign_folders`).

    Raises:
        CompareError: the folder is locked by another process (a comparison or a
            campaign), or holds a comparison and `resume` is False.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    try:
        with folder_lock(out_dir, "comparison"):
            if not resume and _holds_comparison(out_dir, campaign_folders):
                raise CompareError(
                    f"`out_dir`: {out_dir} already holds a comparison; pass `resume` to continue "
                    "it or choose another `out_dir`"
                )
            yield
    except CampaignError as error:
        raise CompareError(str(error)) from None


def same_closed_loop(first: ClosedLoop, second: ClosedLoop) -> bool:
    """Whether two closed loops hold the same arrays (a resumed campaign must sample
    against the trajectory it started with)."""
    arrays = [(getattr(first, k), getattr(second, k)) for k in first.__dataclass_fields__]
    return all(
        (a is None and b is None) or (a is not None and b is not None and np.array_equal(a, b))
        for a, b in arrays
    )


def check_resumed_loop(folder: Path, loop: ClosedLoop, controller: str) -> None:
    """Refuse to resume `controller`'s campaign in `folder` against a closed loop other
    than the one it sampled against (:class:`CompareError`, ``resume``)."""
    path = folder / CLOSED_LOOP_FILE
    if not path.exists():
        return
    try:
        same = same_closed_loop(ClosedLoop.load(path), loop)
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise CompareError(
            f"`resume`: {path} is unreadable ({error}), so {controller}'s campaign cannot be "
            "checked to sample the same closed loop; choose another `out_dir`"
        ) from None
    if not same:
        raise CompareError(
            f"`resume`: {controller}'s closed loop, simulated again, differs from the one its "
            f"campaign in {folder} sampled against (another scenario or code version); "
            "choose another `out_dir`"
        )
