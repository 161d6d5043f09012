"""`stt-drake run [SCENARIO]`: simulate one scenario and check every guarantee.

Writes metrics.json, log.npz and the figures (optionally a Meshcat replay) into the out
folder and prints the run's summary.
"""

from __future__ import annotations

import argparse
import sys

from stt_drake.cli.main import (
    DEFAULT_SCENARIO,
    BadInputError,
    add_scenario_arguments,
    load_scenario_arguments,
)


def check_seed_argument(seed: int | None, option: str = "--seed") -> None:
    """Raise BadInputError unless `seed` is None or a seed the scenario's `seed` field
    could hold (in [0, :data:`stt_drake.config.limits.MAX_SEED`])."""
    from stt_drake.config.limits import MAX_SEED

    if seed is not None and not 0 <= seed <= MAX_SEED:
        raise BadInputError(
            f"stt-drake: {option}: must be an integer in [0, 2^63 − 1] (a seed) (got {seed})"
        )


def _run(args: argparse.Namespace) -> bool:
    from stt_drake.run import simulate, summary, write_outputs

    check_seed_argument(args.seed)
    scenario, out_dir = load_scenario_arguments(args, seed=args.seed)
    result = simulate(scenario, strict=True if args.strict else None)
    written = write_outputs(result, out_dir, figures=not args.no_figures)
    if args.meshcat and len(result.log["t"]) == 0:
        print(
            "stt-drake: no replay: the run stopped before its first logged sample", file=sys.stderr
        )
    elif args.meshcat:
        from stt_drake.replay import body_radius, write_meshcat_replay

        written.append(
            write_meshcat_replay(
                result.log,
                out_dir / "replay.html",
                body_radius=body_radius(scenario.plant),
                host=args.meshcat_host,
            )
        )
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
        "--meshcat",
        action="store_true",
        help="also write replay.html, a self-contained Meshcat replay of the run",
    )
    parser.add_argument(
        "--meshcat-host",
        default="127.0.0.1",
        help="interface the replay's Meshcat server listens on while it draws (default "
        "127.0.0.1, the loopback only; '*' for every interface)",
    )
    parser.set_defaults(handler=_run)
