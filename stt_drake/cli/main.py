"""The `stt-drake` command.

Each subcommand is a module with ``add_parser(commands)`` that declares its arguments and
sets ``handler`` (a function of the parsed arguments returning the exit code); `run` lives
here. Exit codes are shared: 0 success, 1 a guarantee failed, the goal was missed or the run
stopped early (its metrics say why), 2 bad input.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence
from pathlib import Path

#: The scenario `stt-drake run` uses when none is given.
DEFAULT_SCENARIO = Path("diagrams/omni_hardware_case1.yaml")

EXIT_SUCCESS, EXIT_FAILURE, EXIT_BAD_INPUT = 0, 1, 2

#: Modules that add a subcommand (each defines ``add_parser(commands)``).
SUBCOMMAND_MODULES: tuple[str, ...] = (
    "stt_drake.campaign",
    "stt_drake.cli.diagram",
    "stt_drake.bench",
)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="stt-drake",
        description="Spatiotemporal Tube control among uncertain moving obstacles (Drake).",
    )
    commands = parser.add_subparsers(dest="command", required=True)
    run = commands.add_parser(
        "run",
        help="simulate one scenario and check every guarantee",
        description="Exit code 0: every guarantee held and the target was reached; "
        "1: a guarantee failed, the target was not reached or the run stopped early "
        "(integrator failure, step-rate watchdog, --strict); 2: bad input.",
    )
    run.add_argument(
        "scenario",
        nargs="?",
        type=Path,
        default=DEFAULT_SCENARIO,
        help=f"scenario YAML (default: {DEFAULT_SCENARIO})",
    )
    run.add_argument(
        "--out", type=Path, default=None, help="output folder (default: results/<scenario name>/)"
    )
    run.add_argument(
        "--seed",
        type=int,
        default=None,
        help="override the scenario's seed (also redraws random_obstacles)",
    )
    run.add_argument("--strict", action="store_true", help="stop at the first violated guarantee")
    run.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    run.add_argument(
        "--meshcat",
        action="store_true",
        help="also write replay.html, a self-contained Meshcat replay of the run",
    )
    run.set_defaults(handler=_run)
    for module in SUBCOMMAND_MODULES:
        importlib.import_module(module).add_parser(commands)
    return parser


def _run(args: argparse.Namespace) -> int:
    from stt_drake.config import ScenarioError, load_scenario
    from stt_drake.run import simulate, summary, write_outputs

    try:
        scenario = load_scenario(args.scenario, seed=args.seed)
    except ScenarioError as error:
        print(f"stt-drake: bad scenario {args.scenario}: {error}", file=sys.stderr)
        return EXIT_BAD_INPUT
    result = simulate(scenario, strict=True if args.strict else None)
    out_dir = args.out if args.out is not None else Path("results") / scenario.name
    written = write_outputs(result, out_dir, figures=not args.no_figures)
    if args.meshcat and len(result.log["t"]) == 0:
        print(
            "stt-drake: no replay: the run stopped before its first logged sample", file=sys.stderr
        )
    elif args.meshcat:
        from stt_drake.replay import body_radius, write_meshcat_replay

        written.append(
            write_meshcat_replay(
                result.log, out_dir / "replay.html", body_radius=body_radius(scenario.plant)
            )
        )
    print(summary(result))
    print(f"  wrote {', '.join(str(p) for p in written)}")
    return EXIT_SUCCESS if result.success else EXIT_FAILURE


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `stt-drake` console script."""
    args = _parser().parse_args(argv)
    return args.handler(args)


if __name__ == "__main__":
    sys.exit(main())
