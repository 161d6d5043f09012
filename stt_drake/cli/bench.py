"""`stt-drake bench`: time the tube step, the controller and the closed loop.

The measurements are :mod:`stt_drake.bench`; this module declares the command, prints its
human-readable report (or, with ``--json``, one JSON object: keys as in
:func:`stt_drake.bench.run_benchmark`) and says whether every benchmarked closed loop kept
its guarantees (exit code 0, or 1 if one failed).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from stt_drake.bench import (
    CAMPAIGNS,
    COUNTS,
    FIXED_RATE_HZ,
    SCENARIOS,
    profile_closed_loop,
    run_benchmark,
)
from stt_drake.cli.main import BadInputError
from stt_drake.core import backend


def format_table(result: dict[str, Any]) -> str:
    """The human-readable report."""
    lines = []
    machine = result["machine"]
    lines.append(
        f"stt-drake bench — {machine['cpus']} CPUs, load average "
        f"{machine['load_average_before'][0]:.2f} → {machine['load_average_after'][0]:.2f}, "
        f"numba {machine['numba']}, compiled kernels: {machine['compiled_kernels']}"
    )
    if max(machine["load_average_before"][0], machine["load_average_after"][0]) > (
        machine["cpus"] or 1
    ):
        lines.append(
            "  note: the machine is busy (load above its CPU count): wall-clock figures are "
            "inflated; the CPU columns show this process's own time"
        )
    tube = result["details"]["tube_step"]
    lines.append("")
    lines.append("1. one tube step (q, θ, m, v, d̂, r, ċ for all obstacles), µs, median [IQR]")
    header = (
        f"  {'field':<8}{'n':>3}{'count':>7}{'compiled':>11}{'IQR':>7}{'CPU':>8}"
        f"{'per obst.':>10}{'scipy loop':>12}{'speedup':>9}{'pruned':>8}{'active':>7}"
    )
    lines.append(header)
    for key, entry in tube.items():
        field, n, count = key.split("/")
        kernel, baseline = entry["kernel_us"], entry["baseline_us"]
        lines.append(
            f"  {field:<8}{n:>3}{count:>7}{kernel['median']:>11.2f}{kernel['iqr']:>7.2f}"
            f"{kernel['cpu_median']:>8.2f}{kernel['median'] / int(count):>10.3f}"
            f"{baseline['median']:>12.0f}{entry['speedup']:>8.0f}×{entry['pruned']:>8}"
            f"{entry['active']:>7}"
        )
    for key, entry in result["details"]["anisotropic_tube_step"].items():
        n, count = key.split("/")
        kernel = entry["kernel_us"]
        lines.append(
            f"  {'Σ full':<8}{n:>3}{count:>7}{kernel['median']:>11.2f}{kernel['iqr']:>7.2f}"
            f"{kernel['cpu_median']:>8.2f}{kernel['median'] / int(count):>10.3f}"
            f"{'—':>12}{'—':>9}{int(count) - entry['quantiles_computed']:>8}"
            f"{entry['active']:>7}"
        )
    lines.append("")
    lines.append("2. one controller evaluation (FunnelController.evaluate), µs, median [IQR]")
    for name, entry in result["details"]["controller"].items():
        compiled, reference = entry["compiled_us"], entry["numpy_us"]
        lines.append(
            f"  {name}: compiled {compiled['median']:.2f} [IQR {compiled['iqr']:.2f}, CPU "
            f"{compiled['cpu_median']:.2f}], numpy reference {reference['median']:.1f} "
            f"({entry['speedup']:.0f}×)"
        )
    lines.append("")
    lines.append("3. closed loop in Drake's Simulator, invariant monitor at every step")
    for name, loop in result["details"]["closed_loop"].items():
        if not loop["available"]:
            lines.append(f"  {name}: not available ({loop['reason']})")
            continue
        lines.append(
            f"  {name}: {loop['sim_time_s']:.0f} s simulated in {loop['wall_s']:.2f} s wall: "
            f"real-time factor {loop['realtime_factor']:.1f}× "
            f"(min {loop['realtime_factor_min']:.1f}, max {loop['realtime_factor_max']:.1f}, "
            f"per CPU second "
            f"{loop['realtime_factor_cpu']:.1f}×), {loop['steps']} steps, "
            f"{loop['derivative_evaluations_per_s']:.0f} derivative evaluations/s, "
            f"guarantees {'hold' if loop['holds'] else 'VIOLATED'}"
        )
    floor = result["details"]["drake_floor"]["us_per_derivative_evaluation"]
    lines.append(
        f"  Drake floor (the omni loop's 5 systems in Python, doing no work): {floor:.1f} µs "
        "per derivative evaluation; each loop's wall time per evaluation over it: "
        + ", ".join(f"{name} {ratio:.1f}×" for name, ratio in result["over_drake_floor"].items())
    )
    for name, ratio in result["fixed_rate_over_continuous"].items():
        lines.append(
            f"  {name}: fixed-rate tube at {FIXED_RATE_HZ:g} Hz / continuous tube, real-time "
            f"factor ratio {ratio:.2f}"
        )
    for key, row in result["details"]["tracker_update"].items():
        lines.append(
            f"  tracker, {key} tracks: update {row['update_us']['median']:.1f} µs plain, "
            f"{row['monitored_update_us']['median']:.1f} µs monitored (NIS test, adaptive "
            f"noise); whole step {row['step_us']['median']:.1f} / "
            f"{row['monitored_step_us']['median']:.1f} µs"
        )
    lines.append("")
    lines.append("4. the guide: one replan (forecast, level sets, space-time A*), ms")
    for n, row in result["details"]["guide_plan"].items():
        lines.append(
            f"  {n}, {row['count']} obstacles: median {row['median']:.2f}, p99 {row['p99']:.2f} "
            f"over {row['plans']} plans ({row['expansions']:.0f} cells expanded, median)"
        )
    guided = result["details"]["guided_loop"]
    lines.append(
        f"  liveness_clutter_2d closed loops: guided {guided['guided_realtime_factor']:.1f}×, "
        f"unguided {guided['unguided_realtime_factor']:.1f}× real time, ratio "
        f"{guided['ratio']:.2f} (median over draws {', '.join(guided['ratios'])}; worst: "
        f"draw {guided['worst_seed']}, {guided['worst_ratio']:.2f})"
    )
    lines.append("")
    lines.append(f"5. scaling plot: {result['plot']}")
    campaigns = result["details"]["campaigns"]
    if campaigns:
        lines.append("")
        lines.append("6. one campaign of each kind on one worker process, runs per core-second")
        for kind, row in campaigns.items():
            lines.append(
                f"  {kind:<15} {row['scenario']:<22} {row['runs']:>5} runs in "
                f"{row['wall_s']:.2f} s: {row['runs_per_core_second']:.3g} runs per core-second"
            )
    profile = result.get("profile")
    if profile and profile["available"]:
        lines.append("")
        lines.append(
            f"profile: {profile['sim_time_s']:.0f} s of {profile['scenario']} under cProfile "
            f"({profile['total_s']:.2f} s), functions by own time"
        )
        for row in profile["top"]:
            lines.append(f"  {100 * row['own_share']:5.1f}%  {row['calls']:>8}  {row['function']}")
    lines.append("")
    lines.append("targets (this machine):")
    for name, target in result["targets"].items():
        lines.append(
            f"  {name:<36} {target['value']:>10.2f}  (target {target['target']}) "
            f"{'met' if target['met'] else 'MISSED'}"
        )
    return "\n".join(lines)


def _bench(args: argparse.Namespace) -> bool:
    if args.repeats < 1 or args.loop_repeats < 1 or min(args.counts) < 1:
        raise BadInputError("stt-drake bench: --repeats, --loop-repeats and --counts must be ≥ 1")
    if not args.campaign_scale > 0.0:
        raise BadInputError("stt-drake bench: --campaign-scale must be a number > 0")
    if not backend.using_compiled():
        print(
            "stt-drake bench: STT_DRAKE_PURE_NUMPY is set, timing the numpy path", file=sys.stderr
        )
    result = run_benchmark(
        repeats=args.repeats,
        loop_repeats=args.loop_repeats,
        loop_duration=args.loop_duration,
        counts=tuple(args.counts),
        out_dir=args.out,
        campaign_scale=None if args.no_campaigns else args.campaign_scale,
    )
    if args.profile:
        result["profile"] = profile_closed_loop(SCENARIOS[0])
    print(json.dumps(result, indent=2) if args.json else format_table(result))
    loops = result["details"]["closed_loop"].values()
    return all(loop["holds"] for loop in loops if loop["available"])


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Declare `stt-drake bench`."""
    parser = commands.add_parser(
        "bench",
        help="time the tube step, the controller and the closed loop",
        description="Exit code 0; 1 if a guarantee failed in a benchmarked closed loop.",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--repeats", type=int, default=7, help="repeats per timing (default 7)")
    parser.add_argument(
        "--loop-repeats", type=int, default=3, help="runs per closed loop (default 3)"
    )
    parser.add_argument(
        "--loop-duration",
        type=float,
        default=None,
        help="cap on the simulated seconds of each closed loop (default: the scenario's)",
    )
    parser.add_argument(
        "--counts",
        type=int,
        nargs="+",
        default=list(COUNTS),
        help=f"obstacle counts (default {' '.join(map(str, COUNTS))})",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=Path("results/bench"),
        help="folder of the PNG (default: results/bench/)",
    )
    parser.add_argument(
        "--campaign-scale",
        type=float,
        default=1.0,
        help="the campaign rows' runs times this (default 1: "
        + ", ".join(f"{runs} {kind}" for kind, _name, runs in CAMPAIGNS)
        + ")",
    )
    parser.add_argument("--no-campaigns", action="store_true", help="leave out the campaign rows")
    parser.add_argument(
        "--profile",
        action="store_true",
        help="also profile 10 s of omni_cluttered_50 (cProfile, functions by own time)",
    )
    parser.set_defaults(handler=_bench)
