"""`stt-drake run [SCENARIO]`: simulate one scenario and check every guarantee.

Writes metrics.json, log.npz and the figures into the out folder and prints the run's
summary; with --meshcat the run is drawn live in Meshcat and its recording saved as
replay.html.
"""

from __future__ import annotations

import argparse

from stt_drake.cli.main import (
    DEFAULT_SCENARIO,
    BadInputError,
    add_scenario_arguments,
    announce_compilation,
    load_scenario_arguments,
)
from stt_drake.cli.progress import RunProgress, wants_progress


def check_seed_argument(seed: int | None, option: str = "--seed") -> None:
    """Raise BadInputError unless `seed` is None or a seed the scenario's `seed` field
    could hold (in [0, :data:`stt_drake.config.limits.MAX_SEED`])."""
    from stt_drake.config.limits import MAX_SEED

    if seed is not None and not 0 <= seed <= MAX_SEED:
        raise BadInputError(
            f"stt-drake: {option}: must be an integer in [0, 2^63 − 1] (a seed) (got {seed})"
        )


def parse_times(text: str, duration: float, option: str = "--snapshots") -> list[float]:
    """The comma-separated times (s) of `text`, each in [0, `duration`]; BadInputError
    otherwise."""
    try:
        times = [float(part) for part in text.split(",")]
    except ValueError:
        times = []
    if not times or not all(0.0 <= time <= duration for time in times):
        raise BadInputError(
            f"stt-drake: {option}: give comma-separated times in seconds within the run, "
            f"0 to {duration:g} (e.g. 1.5,3.0) (got {text!r})"
        )
    return times


def _run(args: argparse.Namespace) -> bool:
    from stt_drake.run import simulate, summary, write_outputs

    check_seed_argument(args.seed)
    if args.meshcat_host is not None and not args.meshcat:
        raise BadInputError(
            "stt-drake: --meshcat-host: applies only with --meshcat (the live view's server)"
        )
    scenario, out_dir = load_scenario_arguments(args, seed=args.seed, strict=args.strict)
    if args.no_guide:
        scenario.guide = None
    snapshots = None if args.snapshots is None else parse_times(args.snapshots, scenario.duration)
    strict = True if args.strict else None
    announce_compilation()
    if args.meshcat:  # drawn live in Meshcat while it runs; the recording is replay.html
        from stt_drake.replay import LOCALHOST, MeshcatHostError, simulate_live, start_meshcat

        host = LOCALHOST if args.meshcat_host is None else args.meshcat_host
        try:  # before anything is simulated: an address that cannot be bound is bad input
            meshcat = start_meshcat(host)
        except MeshcatHostError as error:
            raise BadInputError(f"stt-drake: --meshcat-host: {error}") from None
        result, replay = simulate_live(
            scenario, out_dir / "replay.html", strict, meshcat=meshcat, announce=True
        )
    else:
        progress = RunProgress(scenario.duration) if wants_progress(args.quiet) else None
        result, replay = simulate(scenario, strict=strict, progress=progress), None
    written = write_outputs(result, out_dir, figures=not args.no_figures, snapshot_times=snapshots)
    if replay is not None:
        written.append(replay)
    print(summary(result))
    print(f"  wrote {', '.join(str(p) for p in written)}")
    return result.success


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Declare `stt-drake run`."""
    parser = commands.add_parser(
        "run",
        help="simulate one scenario and check every guarantee",
        description="Exit code 0: every guarantee held and the target was reached; "
        "1: a guarantee failed, the target was not reached or the run stopped early "
        "(integrator failure, step-rate watchdog, --strict); 2: bad input.",
    )
    add_scenario_arguments(parser, scenario_help=f"scenario YAML (default: {DEFAULT_SCENARIO})")
    parser.add_argument(
        "--seed",
        type=int,
        default=None,
        help="override the scenario's seed (also redraws random_obstacles)",
    )
    parser.add_argument(
        "--strict", action="store_true", help="stop at the first violated guarantee"
    )
    parser.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    parser.add_argument(
        "--snapshots",
        default=None,
        metavar="TIMES",
        help="times in seconds for snapshots.png, comma-separated (e.g. 1.5,3.0); default: "
        "the start, the time of each guarantee's worst margin and the end",
    )
    parser.add_argument(
        "--quiet",
        action="store_true",
        help="no progress lines while simulating (they are printed on a terminal only)",
    )
    parser.add_argument(
        "--no-guide",
        action="store_true",
        help="drop the scenario's guide section: the paper's reactive tube",
    )
    parser.add_argument(
        "--meshcat",
        action="store_true",
        help="draw the run live in Meshcat (its URL is printed) and save the recording as "
        "replay.html, a self-contained Meshcat replay",
    )
    parser.add_argument(
        "--meshcat-host",
        default=None,
        help="with --meshcat: interface the live view's Meshcat server listens on (default "
        "127.0.0.1, the loopback only; '*' for every interface); one this machine cannot "
        "listen on is refused (exit 2) before the run",
    )
    parser.set_defaults(handler=_run)
