"""`stt-drake bench`, the whole measurement: :func:`run_benchmark` (every row, the
machine, the scaling figure) and the issue's targets with the values measured."""

from __future__ import annotations

import os
import platform
from pathlib import Path
from typing import Any

import numpy as np

from stt_drake.bench.campaigns import bench_campaigns
from stt_drake.bench.floor import bench_drake_floor
from stt_drake.bench.guide import bench_guide_plans, bench_guided_loop
from stt_drake.bench.kernels import (
    COUNTS,
    bench_anisotropic_tube_steps,
    bench_controller,
    bench_tracker_update,
    bench_tube_steps,
)
from stt_drake.bench.loops import SCENARIOS, bench_fixed_rate_against_continuous, fixed_rate_name
from stt_drake.core import backend

#: The issue's targets on a 2-core machine (reported, not enforced).
TARGETS = {
    "tube_step_50_us": 30.0,
    "anisotropic_tube_step_50_us": 50.0,
    "tracker_update_us": 20.0,
    "speedup_50": 100.0,
    "controller_us": 10.0,
    "omni_cluttered_50_realtime_factor": 20.0,
    "guide_plan_ms_median": 5.0,
    "guide_plan_ms_p99": 20.0,
    "guided_over_unguided": 0.8,
}


def run_benchmark(
    repeats: int = 7,
    loop_repeats: int = 3,
    loop_duration: float | None = None,
    counts: tuple[int, ...] = COUNTS,
    out_dir: Path = Path("results/bench"),
    campaign_scale: float | None = 1.0,
) -> dict[str, Any]:
    """Every measurement of the module docstring, as one JSON-ready dict.

    Keys: ``tube_step_us`` / ``baseline_tube_step_us`` / ``speedup_vs_baseline`` (typical
    field, by "2d"/"3d" and count), ``worst_case_tube_step_us`` and
    ``worst_case_speedup_vs_baseline`` (no pruning possible), ``controller_us`` ("stage1",
    "stage2"), ``realtime_factor`` (by scenario; "not available" if its file is missing),
    ``derivative_evaluations_per_s``, ``campaign_runs_per_core_second`` (by campaign kind,
    :func:`stt_drake.bench.campaigns.bench_campaigns` with `campaign_scale` times its runs;
    None: not measured), ``over_drake_floor`` (each loop's wall µs per
    derivative evaluation over :func:`stt_drake.bench.floor.bench_drake_floor`'s, measured
    in the same run), ``targets`` (each with its value and whether it is
    met), ``details`` (spreads and everything else), ``machine``, ``plot``.
    """
    load_before = os.getloadavg()
    tube = bench_tube_steps(counts, repeats)
    anisotropic = bench_anisotropic_tube_steps(repeats)
    tracking = bench_tracker_update(repeats)
    controller = bench_controller(repeats)
    plans, guided = bench_guide_plans(), bench_guided_loop(duration=loop_duration)
    loops, ratios = {}, {}
    for name in SCENARIOS:  # the continuous and the fixed-rate loop, in interleaved pairs
        loops[name], loops[fixed_rate_name(name)], ratios[name] = (
            bench_fixed_rate_against_continuous(name, loop_repeats, loop_duration)
        )
    floor = bench_drake_floor(loop_repeats)
    campaigns = {} if campaign_scale is None else bench_campaigns(campaign_scale)
    plot = save_scaling_figure(tube, counts, out_dir / "tube_step_scaling.png")

    def table(field: str, key: str) -> dict[str, dict[str, float]]:
        return {
            f"{n}d": {
                str(c): (
                    tube[f"{field}/{n}d/{c}"][key]["median"]
                    if key != "speedup"
                    else tube[f"{field}/{n}d/{c}"]["speedup"]
                )
                for c in counts
            }
            for n in (2, 3)
        }

    controller_us = {name: entry["compiled_us"]["median"] for name, entry in controller.items()}
    realtime = {
        name: (loop["realtime_factor"] if loop["available"] else "not available")
        for name, loop in loops.items()
    }
    fixed_over_continuous = {name: ratio["median"] for name, ratio in ratios.items() if ratio}
    tube_step_us: dict[str, Any] = table("typical", "kernel_us")
    tube_step_us["anisotropic"] = {
        f"{n}d": {"50": anisotropic[f"{n}d/50"]["kernel_us"]["median"]} for n in (2, 3)
    }
    result: dict[str, Any] = {
        "tube_step_us": tube_step_us,
        "tracker_update_us": {
            f"{n}d": {"50": tracking[f"{n}d/50"]["update_us"]["median"]} for n in (2, 3)
        },
        "guide_plan_ms": {key: {"50": row["median"]} for key, row in plans.items()},
        "guided_over_unguided": guided["ratio"],
        "baseline_tube_step_us": table("typical", "baseline_us"),
        "speedup_vs_baseline": table("typical", "speedup"),
        "worst_case_tube_step_us": table("worst", "kernel_us"),
        "worst_case_speedup_vs_baseline": table("worst", "speedup"),
        "controller_us": controller_us,
        "realtime_factor": realtime,
        "fixed_rate_over_continuous": fixed_over_continuous,
        "derivative_evaluations_per_s": {
            name: loop.get("derivative_evaluations_per_s", "not available")
            for name, loop in loops.items()
        },
        "campaign_runs_per_core_second": {
            kind: row["runs_per_core_second"] for kind, row in campaigns.items()
        },
        "over_drake_floor": {
            name: 1e6 / loop["derivative_evaluations_per_s"] / floor["us_per_derivative_evaluation"]
            for name, loop in loops.items()
            if loop["available"]
        },
        "details": {
            "drake_floor": floor,
            "campaigns": campaigns,
            "tube_step": tube,
            "anisotropic_tube_step": anisotropic,
            "tracker_update": tracking,
            "guide_plan": plans,
            "guided_loop": guided,
            "controller": controller,
            "closed_loop": loops,
            "fixed_rate_over_continuous": ratios,
        },
        "machine": {
            "cpus": os.cpu_count(),
            "load_average_before": load_before,
            "load_average_after": os.getloadavg(),
            "python": platform.python_version(),
            "platform": platform.platform(),
            "numpy": np.__version__,
            "numba": _version("numba"),
            "drake": _version("drake"),
            "compiled_kernels": backend.using_compiled(),
        },
        "plot": str(plot),
    }
    result["targets"] = _targets(result, counts)
    return result


def _version(package: str) -> str | None:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(package)
    except PackageNotFoundError:  # pragma: no cover
        return None


def _targets(result: dict[str, Any], counts: tuple[int, ...]) -> dict[str, Any]:
    """The issue's targets with the measured values (informational)."""
    targets: dict[str, Any] = {}
    if 50 in counts:
        for n in ("2d", "3d"):
            value = result["tube_step_us"][n]["50"]
            targets[f"tube_step_50_{n}_us"] = {
                "value": value,
                "target": f"<= {TARGETS['tube_step_50_us']}",
                "met": value <= TARGETS["tube_step_50_us"],
            }
            speedup = result["speedup_vs_baseline"][n]["50"]
            targets[f"speedup_50_{n}"] = {
                "value": speedup,
                "target": f">= {TARGETS['speedup_50']}",
                "met": speedup >= TARGETS["speedup_50"],
            }
    for n, row in result["tube_step_us"]["anisotropic"].items():
        targets[f"anisotropic_tube_step_50_{n}_us"] = {
            "value": row["50"],
            "target": f"<= {TARGETS['anisotropic_tube_step_50_us']}",
            "met": row["50"] <= TARGETS["anisotropic_tube_step_50_us"],
        }
    for n, row in result["tracker_update_us"].items():
        targets[f"tracker_update_50_{n}_us"] = {
            "value": row["50"],
            "target": f"<= {TARGETS['tracker_update_us']}",
            "met": row["50"] <= TARGETS["tracker_update_us"],
        }
    for n, row in result["details"]["guide_plan"].items():
        for statistic in ("median", "p99"):
            limit = TARGETS[f"guide_plan_ms_{statistic}"]
            targets[f"guide_plan_ms_{statistic}_{n}"] = {
                "value": row[statistic],
                "target": f"<= {limit}",
                "met": row[statistic] <= limit,
            }
    targets["guided_over_unguided"] = {
        "value": result["guided_over_unguided"],
        "target": f">= {TARGETS['guided_over_unguided']} (median over draws, interleaved pairs)",
        "met": result["guided_over_unguided"] >= TARGETS["guided_over_unguided"],
    }
    for name, value in result["controller_us"].items():
        targets[f"controller_{name}_us"] = {
            "value": value,
            "target": f"<= {TARGETS['controller_us']}",
            "met": value <= TARGETS["controller_us"],
        }
    for name, ratio in result["fixed_rate_over_continuous"].items():
        targets[f"{name}_fixed_rate_over_continuous"] = {
            "value": ratio,
            "target": ">= 1 (median of interleaved pairs)",
            "met": ratio >= 1.0,
        }
    factor = result["realtime_factor"].get("omni_cluttered_50")
    if isinstance(factor, float):
        targets["omni_cluttered_50_realtime_factor"] = {
            "value": factor,
            "target": f">= {TARGETS['omni_cluttered_50_realtime_factor']}",
            "met": factor >= TARGETS["omni_cluttered_50_realtime_factor"],
        }
    return targets


def save_scaling_figure(tube: dict[str, Any], counts: tuple[int, ...], path: Path) -> Path:
    """Write :func:`stt_drake.plotting.bench.plot_tube_step_scaling` as a PNG at `path`
    (its folder created); return `path`."""
    from stt_drake.plotting.bench import plot_tube_step_scaling

    path.parent.mkdir(parents=True, exist_ok=True)
    plot_tube_step_scaling(tube, counts).savefig(path, dpi=120)
    return path
