"""`stt-drake campaign`: Monte Carlo verification of the probabilistic guarantee.

Three kinds of campaign:

``true-obstacles``
    Sample the *true* obstacle centres from the belief, O_j(t) = μ_j(t) + σ_j(t)·ξ_j, and
    count actual collisions of the robot's output (‖y − O_j‖ < r_o_j) and of the tube
    (‖c − O_j‖ < r_o_j + r) per obstacle and time. ξ_j ~ N(0, I) is drawn once per run
    (``static``), or is an Ornstein-Uhlenbeck path with the same N(0, I) marginal (``ou``).
    The closed loop (y, c, r) depends only on the belief and the plant's (deterministic)
    disturbance, never on ξ, so it is **simulated once** and every run is a cheap,
    vectorised draw of ξ against the logged trajectory.
``randomisation``
    Each run loads the scenario with its own seed, which redraws the `random_obstacles`
    field (draws breaking the paper's assumptions are rejected by the loader and counted),
    simulates it and checks every guarantee. Failing draws are kept as scenario YAML.
``end-to-end``
    For a scenario with perception in the loop: each run draws the obstacles' process
    noise and the sensor's noise and dropouts from its seed, simulates truth, sensor,
    tracker, tube, controller and plant, and counts collisions with the TRUE obstacles and
    the belief's calibration (:mod:`~stt_drake.campaign.end_to_end`).

Runs go through a :class:`concurrent.futures.Executor`: a local process pool, or a Dask
``distributed`` client. Each finished run is appended to ``runs.jsonl``; ``--resume`` skips
the runs already there. Summaries are order-independent functions of the set of runs.

Run i uses the seed :func:`run_seed` (campaign seed, i); ``stt-drake run SCENARIO --seed S``
replays a randomisation run alone. The statistics are in :mod:`stt_drake.core.statistics`; the
command is :mod:`stt_drake.cli.campaign`.

Modules: :mod:`~stt_drake.campaign.kinds` (the kinds as objects: what a kind needs, one
file), :mod:`~stt_drake.campaign.spec` (:class:`CampaignSpec`, :class:`CampaignError`,
:class:`CampaignStoppedError`), :mod:`~stt_drake.campaign.sampling` (seeds, true-obstacle
draws, the closed loop they are drawn against), :mod:`~stt_drake.campaign.randomisation`
(a randomisation run), :mod:`~stt_drake.campaign.end_to_end` (an end-to-end run),
:mod:`~stt_drake.campaign.backends` (local pool / Dask, :func:`execute`),
:mod:`~stt_drake.campaign.folder` (the lock, ``campaign_spec.json``, reading
``runs.jsonl``), :mod:`~stt_drake.campaign.executor` (:func:`run_campaign`, resume),
:mod:`~stt_drake.campaign.summaries` (the per-kind summaries and printed lines),
:mod:`~stt_drake.campaign.report` (``campaign.json``, the figure, the printed report; the
package attribute ``report`` is the function :func:`report`, re-exported below); the
figures are :mod:`stt_drake.plotting.campaign`.
"""

from stt_drake.campaign.executor import CLOSED_LOOP_FILE, run_campaign
from stt_drake.campaign.folder import read_records
from stt_drake.campaign.report import report
from stt_drake.campaign.sampling import ClosedLoop, run_seed, sample_true_obstacles, sample_xi
from stt_drake.campaign.spec import CampaignError, CampaignSpec, CampaignStoppedError

__all__ = [
    "CLOSED_LOOP_FILE",
    "CampaignError",
    "CampaignSpec",
    "CampaignStoppedError",
    "ClosedLoop",
    "read_records",
    "report",
    "run_campaign",
    "run_seed",
    "sample_true_obstacles",
    "sample_xi",
]
