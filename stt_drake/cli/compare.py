"""`stt-drake compare SCENARIO --runs N`: STT against the CBF-QP and potential-field
baselines on one scenario (:mod:`stt_drake.compare`), or every controller on K randomised
draws (``--draws K``, :mod:`stt_drake.compare_draws`). Controllers default to
:data:`DEFAULT_CONTROLLERS`, the folder to ``results/<scenario name>_compare``.

Exit codes: 0 the comparison finished (comparison.json, .md and .png written; the table is
printed), 1 a campaign stopped, 2 bad input (found before any simulation).
"""

from __future__ import annotations

import argparse
import contextlib
from collections.abc import Iterator
from pathlib import Path

from stt_drake.cli.main import (
    BadInputError,
    CommandError,
    announce_compilation,
    check_out_folder,
    default_out_folder,
    flag_message,
    resolve_scenario,
)
from stt_drake.cli.progress import CountProgress, wants_progress

#: The controllers compared without ``--controllers``: the paper's reactive tube and both
#: baselines (``stt-guided``, the tube under the guide, on request).
DEFAULT_CONTROLLERS = ("stt", "cbf", "apf")


@contextlib.contextmanager
def _exit_codes(args: argparse.Namespace) -> Iterator[None]:
    """Bad input (CompareError) becomes exit 2; a stopped campaign or an interrupt exit 1,
    with how to continue."""
    from stt_drake.campaign import CampaignStoppedError
    from stt_drake.compare import CompareError

    try:
        yield
    except CompareError as error:
        raise BadInputError(f"stt-drake compare: {flag_message(error)}") from None
    except (CampaignStoppedError, KeyboardInterrupt) as error:
        why = "interrupted" if isinstance(error, KeyboardInterrupt) else flag_message(error)
        raise CommandError(f"stt-drake compare: stopped: {why}{_resume_hint(args)}") from None


def _compare(args: argparse.Namespace) -> bool:
    # Imported here: the comparison loads Drake, which other subcommands' start-up avoids.
    from stt_drake.compare import TABLE_FILE, compare, comparison_table

    scenario = resolve_scenario(args.scenario)  # a path, or a packaged scenario's name
    if args.out is None:
        args.out = default_out_folder(scenario, "_compare")
        check_out_folder(args.out, "the output folder")
    if args.draws is not None:
        return _compare_draws(args, scenario)
    if args.runs is None:
        raise BadInputError("stt-drake compare: --runs: required (or --draws K)")
    if args.seed is not None:
        raise BadInputError(
            "stt-drake compare: --seed: applies only with --draws (the seed of the draws; "
            "the campaigns of a comparison over --runs use seed 0)"
        )
    with _exit_codes(args):
        announce_compilation()
        progress = None
        if wants_progress(args.quiet):  # a line per closed loop, then its campaign's bar
            progress = CountProgress("compare", "closed loops", period=0.0)
        document = compare(
            scenario,
            args.controllers,
            args.runs,
            args.out,
            workers=args.workers,
            scheduler=args.scheduler,
            model_error=args.model_error,
            solver=args.solver,
            progress=progress,
            resume=args.resume,
            comfort_distance=args.comfort_distance,
        )
    print(comparison_table(document["rows"]))
    print(f"  wrote {args.out / TABLE_FILE} and comparison.json, comparison.png there")
    return True


def _resume_hint(args: argparse.Namespace) -> str:
    """How to continue a comparison that stopped."""
    if args.resume:
        return "; run the same command again to continue"
    return "; the finished runs are kept: run the same command with --resume to continue"


def _compare_draws(args: argparse.Namespace, scenario: Path) -> bool:
    from stt_drake.compare_draws import compare_draws, draws_table

    if args.scheduler is not None or args.model_error:
        raise BadInputError(
            "stt-drake compare: --draws runs on local processes without model error "
            "(drop --scheduler and --model-error)"
        )
    if args.runs is not None:
        raise BadInputError(
            "stt-drake compare: --runs: not with --draws (--runs: one scenario and a campaign "
            "per controller; --draws: K randomised draws per controller)"
        )
    with _exit_codes(args):
        announce_compilation()
        progress = CountProgress("compare", "draw runs") if wants_progress(args.quiet) else None
        document = compare_draws(
            scenario,
            args.controllers,
            args.draws,
            args.out,
            seed=0 if args.seed is None else args.seed,
            workers=args.workers,
            solver=args.solver,
            resume=args.resume,
            comfort_distance=args.comfort_distance,
            progress=progress,
        )
    print(draws_table(document["rows"]))
    print(f"  wrote {args.out / 'comparison.md'} and comparison.json, draws.jsonl there")
    return True


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Declare `stt-drake compare`."""
    parser = commands.add_parser(
        "compare",
        help="compare STT with the CBF-QP and potential-field baselines",
        description="Simulate each controller once on the scenario, run a true-obstacle "
        "campaign against each closed loop, and write comparison.json/.md/.png (with --draws: "
        "every controller on K randomised draws, comparison.json/.md and draws.jsonl).",
        epilog="Exit code 0: done; 1: a campaign stopped; 2: bad input.",
    )
    parser.add_argument("scenario", help="scenario YAML, or a packaged scenario's name")
    parser.add_argument(
        "--controllers",
        nargs="+",
        default=list(DEFAULT_CONTROLLERS),
        help="controllers to compare: stt (the reactive tube), stt-guided (the tube under the "
        "guide), cbf (chance-constrained CBF-QP), apf (potential field); default: "
        + " ".join(DEFAULT_CONTROLLERS),
    )
    parser.add_argument(
        "--runs", type=int, default=None, help="campaign runs per controller (one scenario)"
    )
    parser.add_argument(
        "--draws",
        type=int,
        default=None,
        help="instead: every controller on K randomised draws of the scenario's random_obstacles "
        "(success, stall, timeout and unsafe rates)",
    )
    parser.add_argument(
        "--seed", type=int, default=None, help="with --draws: seed of the draws (default 0)"
    )
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=None, help="local processes (default: cores)")
    where.add_argument("--scheduler", default=None, help="Dask scheduler, e.g. tcp://host:8786")
    parser.add_argument(
        "--model-error",
        action="store_true",
        help="also compare with the plant's true parameters perturbed (omni: wheel radius x0.9; "
        "quadrotor: mass x0.5, mass x2, drag x2)",
    )
    parser.add_argument(
        "--solver", default="osqp", help="the CBF's QP solver: osqp (default) or clarabel"
    )
    parser.add_argument(
        "--comfort-distance",
        type=float,
        default=0.5,
        help="comfort_violation_s counts the seconds the output's surface distance to a true "
        "obstacle, ‖y − O_j‖ − r_o_j, is below this (m, default 0.5: about the edge of Hall's "
        "intimate space)",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="output folder (default: results/<scenario name>_compare/)",
    )
    parser.add_argument(
        "--quiet",
        action="store_true",
        help="no progress lines (they are printed on a terminal only)",
    )
    parser.add_argument(
        "--resume",
        action="store_true",
        help="continue the comparison in --out: each controller's campaign (or the draws) "
        "continues; with --runs the closed loops are simulated again",
    )
    parser.set_defaults(handler=_compare)
