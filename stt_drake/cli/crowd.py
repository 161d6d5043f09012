"""`stt-drake crowd`: simulate a JuPedSim crowd offline and write its tracks as CSV.

``stt-drake crowd --scene crossing --pedestrians 20 --seed 0 --duration 30 --rate 10 --out
tracks.csv`` writes ``t,id,x,y`` rows (s, m), grouped by pedestrian id with t increasing
(:mod:`stt_drake.crowd.tracks`), which a scenario reads back with ``!Recorded {file, id}``
obstacles. Bad input (pedestrians < 1, an unknown scene, rate ≤ 0, an output that cannot be
written, JuPedSim missing) exits 2 with one line, no traceback, nothing written.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import tempfile
from pathlib import Path

from stt_drake.cli.main import BadInputError

#: Most seconds of crowd one command simulates.
MAX_DURATION = 3600.0
#: Fastest sample rate (Hz).
MAX_RATE = 1000.0


def _check(args: argparse.Namespace) -> None:
    """The arguments' rules; BadInputError naming the option."""
    if args.pedestrians < 1:
        raise BadInputError(f"stt-drake crowd: --pedestrians must be ≥ 1 (got {args.pedestrians})")
    if not (math.isfinite(args.duration) and 0.0 <= args.duration <= MAX_DURATION):
        raise BadInputError(
            f"stt-drake crowd: --duration must lie in [0, {MAX_DURATION:g}] s (got {args.duration})"
        )
    if not (math.isfinite(args.rate) and 0.0 < args.rate <= MAX_RATE):
        raise BadInputError(
            f"stt-drake crowd: --rate must lie in (0, {MAX_RATE:g}] Hz (got {args.rate})"
        )
    if args.seed < 0:
        raise BadInputError(f"stt-drake crowd: --seed must be ≥ 0 (got {args.seed})")
    out: Path = args.out
    if out.is_dir():
        raise BadInputError(f"stt-drake crowd: --out: {out} is a folder, not a file")
    from stt_drake.runlog import unwritable_reason

    reason = unwritable_reason(out.parent if str(out.parent) else Path("."))
    if reason is not None:
        raise BadInputError(f"stt-drake crowd: --out: {out.parent} {reason}")


def _crowd(args: argparse.Namespace) -> bool:
    from stt_drake.core.rules import RuleError
    from stt_drake.crowd import CrowdUnavailableError, make_scene, run_tracks, write_tracks_csv

    _check(args)
    try:
        setup = make_scene(
            args.scene,
            args.pedestrians,
            args.seed,
            speed_range=args.speed_range,
            area=args.area,
            radius=args.radius,
        )
        tracks = run_tracks(setup, args.duration, args.rate)
    except RuleError as error:
        option = "--" + error.field.replace("_", "-")
        raise BadInputError(
            f"stt-drake crowd: {option} {error.rule} (got {error.value!r})"
        ) from None
    except CrowdUnavailableError as error:
        raise BadInputError(f"stt-drake crowd: {error}") from None
    except ValueError as error:
        raise BadInputError(f"stt-drake crowd: {error}") from None
    out: Path = args.out
    folder = out.parent if str(out.parent) else Path(".")
    folder.mkdir(parents=True, exist_ok=True)
    handle = tempfile.NamedTemporaryFile(  # noqa: SIM115 (renamed into place below)
        "w", dir=folder, prefix=f".{out.name}.", suffix=".tmp", delete=False, encoding="utf-8"
    )
    try:
        with handle:
            rows = write_tracks_csv(tracks, handle)
        os.replace(handle.name, out)
    except OSError as error:
        with contextlib.suppress(OSError):
            os.unlink(handle.name)
        raise BadInputError(f"stt-drake crowd: --out: {out}: {error.strerror or error}") from None
    left = int((~tracks.active[-1]).sum())
    print(
        f"wrote {out}: {rows} rows, {setup.count} pedestrians ({left} left the scene) over "
        f"{args.duration:g} s at {args.rate:g} Hz (scene {args.scene}, seed {args.seed})"
    )
    return True


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Declare `stt-drake crowd`."""
    from stt_drake.crowd.scenes import SCENE_NAMES

    parser = commands.add_parser(
        "crowd",
        help="simulate a JuPedSim crowd and write its tracks (t,id,x,y) as CSV",
        description="Simulate a crowd of pedestrians with JuPedSim (the crowd extra: pip "
        "install 'stt-drake[crowd]') and write its tracks as CSV: header t,id,x,y, SI "
        "units, rows grouped by id with t increasing; a pedestrian that reaches its exit "
        "is no longer written. Read them in a scenario with !Recorded {file, id}. Exit "
        "code 0, or 2 for bad input.",
    )
    parser.add_argument("--scene", choices=SCENE_NAMES, default="crossing")
    parser.add_argument("--pedestrians", type=int, default=20, help="N ≥ 1 (default 20)")
    parser.add_argument("--seed", type=int, default=0, help="the draw's seed (default 0)")
    parser.add_argument(
        "--duration", type=float, default=30.0, help="simulated seconds (default 30)"
    )
    parser.add_argument("--rate", type=float, default=10.0, help="samples per second (Hz)")
    parser.add_argument("--out", type=Path, required=True, help="the CSV file to write")
    parser.add_argument(
        "--area",
        type=float,
        nargs=4,
        metavar=("X_MIN", "Y_MIN", "X_MAX", "Y_MAX"),
        default=None,
        help="the walkable rectangle, m (default: the scene's)",
    )
    parser.add_argument(
        "--speed-range",
        type=float,
        nargs=2,
        metavar=("LOW", "HIGH"),
        default=None,
        help="desired walking speeds, m/s (default 1.0 1.4)",
    )
    parser.add_argument(
        "--radius", type=float, default=None, help="pedestrian radius, m (default 0.2)"
    )
    parser.set_defaults(handler=_crowd)
