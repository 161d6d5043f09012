"""`stt-drake campaign SCENARIO --runs N`: Monte Carlo verification of the probabilistic
guarantee (the campaigns themselves are :mod:`stt_drake.campaign`).

Exit codes: 0 the guarantee holds, 1 it does not or the campaign stopped (its message
ends with the exact command that resumes it), 2 bad input (found before any work).
"""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path

from stt_drake.campaign.backends import DASK_TIMEOUT_S
from stt_drake.campaign.executor import RUNS_FILE, run_campaign
from stt_drake.campaign.kinds import CROWD_KINDS, KINDS, SAMPLING_KINDS, sampling_only
from stt_drake.campaign.report import SUMMARY_FILE, report
from stt_drake.campaign.sampling import MOTIONS
from stt_drake.campaign.spec import (
    DEFAULT_MOTION,
    DEFAULT_TAU,
    MAX_RUNS,
    CampaignError,
    CampaignSpec,
    CampaignStoppedError,
)
from stt_drake.cli.main import (
    BadInputError,
    CommandError,
    announce_compilation,
    default_out_folder,
    flag_message,
    resolve_scenario,
)
from stt_drake.cli.progress import wants_progress
from stt_drake.core.crowd_metrics import DEFAULT_COMFORT_DISTANCE


def resume_command(
    spec: CampaignSpec, out_dir: Path, workers: int | None = None, scheduler: str | None = None
) -> str:
    """The shell command that resumes the campaign of `spec` in `out_dir` on the same
    `workers` or `scheduler` (defaults left out)."""
    words = ["stt-drake", "campaign", spec.scenario, "--runs", str(spec.runs)]
    words += ["--kind", spec.kind, "--seed", str(spec.seed)]
    if spec.motion != DEFAULT_MOTION:
        words += ["--true-obstacle-motion", spec.motion]
    if spec.tau != DEFAULT_TAU:
        words += ["--ou-tau", repr(spec.tau)]
    if not spec.guide:
        words += ["--no-guide"]
    if spec.comfort_distance != DEFAULT_COMFORT_DISTANCE:
        words += ["--comfort-distance", repr(spec.comfort_distance)]
    if workers is not None:
        words += ["--workers", str(workers)]
    if scheduler is not None:
        words += ["--scheduler", scheduler]
    return shlex.join([*words, "--out", str(out_dir), "--resume"])


def _motion(args: argparse.Namespace) -> tuple[str, float]:
    """The true-obstacle motion and OU time constant asked for, refused (naming the
    option) when given to a campaign they do not apply to."""
    given = {"motion": args.true_obstacle_motion, "tau": args.ou_tau}
    motion = args.true_obstacle_motion or DEFAULT_MOTION
    for parameter, value in given.items():
        if value is not None and args.kind not in SAMPLING_KINDS:
            why = flag_message(sampling_only(parameter, args.kind))
            raise BadInputError(f"stt-drake campaign: {why}")
    if args.ou_tau is not None and motion != "ou":
        why = flag_message(sampling_only("tau", args.kind, motion))
        raise BadInputError(f"stt-drake campaign: {why}")
    return motion, DEFAULT_TAU if args.ou_tau is None else args.ou_tau


def _campaign(args: argparse.Namespace) -> bool:
    motion, tau = _motion(args)
    comfort = args.comfort_distance
    if comfort is not None and args.kind not in CROWD_KINDS:
        raise BadInputError(
            f"stt-drake campaign: --comfort-distance: applies only to --kind "
            f"{' or '.join(CROWD_KINDS)} (the runs simulated against their true obstacles)"
        )
    args.scenario = resolve_scenario(args.scenario)  # a path, or a packaged scenario's name
    spec = CampaignSpec(
        scenario=str(args.scenario),
        kind=args.kind,
        runs=args.runs,
        seed=args.seed,
        motion=motion,
        tau=tau,
        guide=not args.no_guide,
        comfort_distance=DEFAULT_COMFORT_DISTANCE if comfort is None else comfort,
    )
    out_dir = args.out
    if out_dir is None:
        out_dir = default_out_folder(args.scenario) / f"campaign_{args.kind}"
    announce_compilation()
    try:
        outcome = run_campaign(
            spec,
            out_dir,
            workers=args.workers,
            scheduler=args.scheduler,
            resume=args.resume,
            chunk_size=args.chunk_size,
            progress=wants_progress(args.quiet),
            figures=not args.no_figures,
            dask_timeout=args.dask_timeout,
        )
    except CampaignError as error:
        raise BadInputError(f"stt-drake campaign: {flag_message(error)}") from error
    except (CampaignStoppedError, KeyboardInterrupt) as error:
        why = "interrupted" if isinstance(error, KeyboardInterrupt) else flag_message(error)
        message = f"stt-drake campaign: stopped: {why}"
        if (out_dir / RUNS_FILE).exists():
            command = resume_command(spec, out_dir, args.workers, args.scheduler)
            message += (
                f"\n  the finished runs are kept in {out_dir / RUNS_FILE}; resume with:"
                f"\n  {command}"
            )
            if args.scheduler is not None:
                message += "\n  (without --scheduler the remaining runs go to local processes)"
        raise CommandError(message) from None
    print(report(outcome.summary))
    print(f"  wrote {out_dir / SUMMARY_FILE}")
    return outcome.summary["holds"]


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Declare `stt-drake campaign`."""
    parser = commands.add_parser(
        "campaign",
        help="Monte Carlo verification of the probabilistic guarantee",
        description="Run N runs of one kind (--kind), write runs.jsonl, campaign.json and "
        "a figure, and print each verdict: certified, inconclusive (with about how many runs "
        "would certify) or violated.",
        epilog="Exit code 0: no obstacle's guarantee is violated (true-obstacles, end-to-end) / "
        "every draw held every guarantee (randomisation); 1 otherwise, or the campaign "
        "stopped (the message gives the command that resumes it); 2: bad input.",
    )
    parser.add_argument("scenario", help="scenario YAML, or a packaged scenario's name")
    parser.add_argument(
        "--runs", type=int, required=True, help=f"number of runs (at most {MAX_RUNS:,})"
    )
    parser.add_argument(
        "--kind",
        choices=KINDS,
        default="true-obstacles",
        help="true-obstacles (default): sample the true obstacle positions around the "
        "belief against one simulated closed loop (tests the probabilistic guarantee); "
        "randomisation: redraw the scenario's random_obstacles per run, simulate each and "
        "check every guarantee; end-to-end: simulate true obstacles, sensor, tracker and "
        "controller per run (needs a perception section) and count collisions with the true "
        "obstacles",
    )
    parser.add_argument("--seed", type=int, default=0, help="campaign seed (default 0)")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=None, help="local processes (default: cores)")
    where.add_argument("--scheduler", default=None, help="Dask scheduler, e.g. tcp://host:8786")
    parser.add_argument(
        "--dask-timeout",
        type=float,
        default=DASK_TIMEOUT_S,
        help="seconds to wait for the Dask scheduler, for a first worker, and at most without "
        f"any worker while runs are out (default {DASK_TIMEOUT_S:g})",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="output folder (default: results/<scenario name>/campaign_<kind>/)",
    )
    parser.add_argument("--resume", action="store_true", help="continue the campaign in --out")
    parser.add_argument(
        "--true-obstacle-motion",
        choices=MOTIONS,
        default=None,
        help="true-obstacles kind only: static (default): ξ drawn once per run; ou: "
        "Ornstein-Uhlenbeck ξ(t), same N(0, I) marginal",
    )
    parser.add_argument(
        "--ou-tau",
        type=float,
        default=None,
        help=f"with --true-obstacle-motion ou: OU time constant τ (s, default {DEFAULT_TAU:g})",
    )
    parser.add_argument("--chunk-size", type=int, default=None, help="runs per task")
    parser.add_argument(
        "--quiet",
        "--no-progress",
        dest="quiet",
        action="store_true",
        help="no progress bar (runs done, failures, runs/s, time left; it is shown on a "
        "terminal only)",
    )
    parser.add_argument("--no-figures", action="store_true", help="skip the PNG figure")
    parser.add_argument(
        "--no-guide",
        action="store_true",
        help="drop the scenario's guide section: the reactive tube on the same runs",
    )
    parser.add_argument(
        "--comfort-distance",
        type=float,
        default=None,
        help="randomisation / end-to-end: a run's comfort_violation_s counts the seconds its "
        "surface distance to a true obstacle is below this (m, default "
        f"{DEFAULT_COMFORT_DISTANCE:g}: about the edge of Hall's intimate space)",
    )
    parser.set_defaults(handler=_campaign)
