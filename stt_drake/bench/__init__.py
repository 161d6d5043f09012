"""`stt-drake bench`: how fast the tube, the controller and the closed loop are.

Measured in one run, each as the median and spread over repeats (wall clock,
``time.perf_counter``; every timed call is warmed up first, which also loads or compiles
the numba kernels):

1. one tube step — q_j, θ_j, m_j, v_j, d̂_j, r and ċ for all obstacles
   (:meth:`stt_drake.core.tube.TubeLaw.evaluate`) — for 10, 50, 200 and 1000 obstacles in 2D and
   3D, against the *baseline*: a per-obstacle Python loop over ``scipy.stats.ncx2.cdf`` /
   ``.ppf`` (a direct port of the authors' MATLAB loop), measured in the same run; the
   ratio is the speedup. Two obstacle fields: ``typical`` (the density, σ and ε of the
   shipped cluttered scenarios, around a valid tube centre) and ``worst`` (every obstacle
   inside its avoidance layer, so no quantile can be pruned);
2. one controller evaluation, :meth:`stt_drake.core.control.FunnelController.evaluate`, for one
   stage (omni robot, n = 2) and two stages (UAV, n = 3), and the numpy reference path;
3. the closed loops of ``omni_cluttered_50`` and ``uav_cluttered`` in Drake's Simulator with
   the invariant monitor on (every guarantee checked at every step): simulated time / wall
   time (real-time factor), the same per CPU second, and derivative evaluations per second,
   each with the continuous tube and the fixed-rate one (FIXED_RATE_HZ), run in interleaved
   pairs, and the median ratio fixed-rate / continuous over the pairs;
4. the guide's replan time and its cost to a closed loop (:mod:`stt_drake.bench.guide`);
5. a PNG of tube-step cost against obstacle count;
6. runs per core-second of one campaign of each kind on one worker
   (:mod:`stt_drake.bench.campaigns`).

:func:`run_benchmark` returns them as one JSON-ready dict; the command's options, its text
report and its exit code are in :mod:`stt_drake.cli.bench`. Speed targets are reported,
never enforced.

Modules, one per job: :mod:`~stt_drake.bench.workloads` (the obstacle fields and the
scipy baseline), :mod:`~stt_drake.bench.timing` (:func:`time_call`),
:mod:`~stt_drake.bench.kernels` (rows 1-2 and the tracker), :mod:`~stt_drake.bench.loops`
(row 3 and the profile), :mod:`~stt_drake.bench.guide` (row 4),
:mod:`~stt_drake.bench.campaigns` (row 6) and
:mod:`~stt_drake.bench.results` (:func:`run_benchmark`, the targets); the figure (row 5)
is :func:`stt_drake.plotting.bench.plot_tube_step_scaling`.
"""

from stt_drake.bench.campaigns import CAMPAIGNS, bench_campaigns
from stt_drake.bench.guide import bench_guide_plans, bench_guided_loop
from stt_drake.bench.kernels import (
    COUNTS,
    bench_anisotropic_tube_steps,
    bench_controller,
    bench_tracker_update,
    bench_tube_steps,
)
from stt_drake.bench.loops import (
    DIAGRAMS,
    FIXED_RATE_HZ,
    SCENARIOS,
    bench_closed_loop,
    bench_fixed_rate_against_continuous,
    fixed_rate_name,
    profile_closed_loop,
)
from stt_drake.bench.results import TARGETS, run_benchmark, save_scaling_figure
from stt_drake.bench.timing import time_call
from stt_drake.bench.workloads import (
    FIELDS,
    OBSTACLE_RADIUS,
    P_D,
    anisotropic_field,
    baseline_tube_step,
    obstacle_field,
)

__all__ = [
    "CAMPAIGNS",
    "COUNTS",
    "DIAGRAMS",
    "FIELDS",
    "FIXED_RATE_HZ",
    "OBSTACLE_RADIUS",
    "P_D",
    "SCENARIOS",
    "TARGETS",
    "anisotropic_field",
    "baseline_tube_step",
    "bench_anisotropic_tube_steps",
    "bench_campaigns",
    "bench_closed_loop",
    "bench_controller",
    "bench_fixed_rate_against_continuous",
    "bench_guide_plans",
    "bench_guided_loop",
    "bench_tracker_update",
    "bench_tube_steps",
    "fixed_rate_name",
    "obstacle_field",
    "profile_closed_loop",
    "run_benchmark",
    "save_scaling_figure",
    "time_call",
]
