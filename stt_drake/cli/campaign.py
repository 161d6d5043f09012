"""`stt-drake campaign SCENARIO --runs N`: Monte Carlo verification of the probabilistic
guarantee (the campaigns themselves are :mod:`stt_drake.campaign`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from stt_drake.campaign.executor import RUNS_FILE, run_campaign
from stt_drake.campaign.report import SUMMARY_FILE, report
from stt_drake.campaign.sampling import MOTIONS
from stt_drake.campaign.spec import KINDS, CampaignError, CampaignSpec
from stt_drake.cli.main import BadInputError, CommandError


def _campaign(args: argparse.Namespace) -> bool:
    spec = CampaignSpec(
        scenario=str(args.scenario),
        kind=args.kind,
        runs=args.runs,
        seed=args.seed,
        motion=args.true_obstacle_motion,
        tau=args.ou_tau,
    )
    out_dir = args.out
    if out_dir is None:
        out_dir = Path("results") / Path(args.scenario).stem / f"campaign_{args.kind}"
    try:
        outcome = run_campaign(
            spec,
            out_dir,
            workers=args.workers,
            scheduler=args.scheduler,
            resume=args.resume,
            chunk_size=args.chunk_size,
            progress=not args.no_progress,
            figures=not args.no_figures,
        )
    except CampaignError as error:
        raise BadInputError(f"stt-drake campaign: {error}") from error
    except KeyboardInterrupt:
        raise CommandError(
            f"stt-drake campaign: interrupted; finished runs are in {out_dir / RUNS_FILE}, "
            "continue with --resume"
        ) from None
    print(report(outcome.summary))
    print(f"  wrote {out_dir / SUMMARY_FILE}")
    return outcome.summary["holds"]


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Declare `stt-drake campaign`."""
    parser = commands.add_parser(
        "campaign",
        help="Monte Carlo verification of the probabilistic guarantee",
        description="Exit code 0: no obstacle's guarantee is violated (true-obstacle) / every "
        "draw held every guarantee (randomisation); 1 otherwise; 2: bad input.",
    )
    parser.add_argument("scenario", type=Path, help="scenario YAML")
    parser.add_argument("--runs", type=int, required=True, help="number of runs")
    parser.add_argument(
        "--kind",
        choices=KINDS,
        default="true-obstacles",
        help="true-obstacles: sample true obstacle positions against one simulated closed "
        "loop; randomisation: redraw random_obstacles per run and simulate each",
    )
    parser.add_argument("--seed", type=int, default=0, help="campaign seed (default 0)")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=None, help="local processes (default: cores)")
    where.add_argument("--scheduler", default=None, help="Dask scheduler, e.g. tcp://host:8786")
    parser.add_argument("--out", type=Path, default=None, help="output folder")
    parser.add_argument("--resume", action="store_true", help="continue the campaign in --out")
    parser.add_argument(
        "--true-obstacle-motion",
        choices=MOTIONS,
        default="static",
        help="static: ξ drawn once per run; ou: Ornstein-Uhlenbeck ξ(t), same N(0, I) marginal",
    )
    parser.add_argument("--ou-tau", type=float, default=2.0, help="OU time constant τ (s)")
    parser.add_argument("--chunk-size", type=int, default=None, help="runs per task")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--no-figures", action="store_true", help="skip the PNG figure")
    parser.set_defaults(handler=_campaign)
