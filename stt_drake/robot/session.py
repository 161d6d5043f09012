"""Running the halves: both in one process (:func:`simulate_split`), the controller
(:func:`run_controller`) and the station (:func:`run_station`) as processes of their own,
and :func:`merge_logs`, which joins the station's log into the controller's RunLog."""

from __future__ import annotations

import copy
import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydrake.lcm import DrakeLcm, DrakeLcmParams
from pydrake.systems.framework import DiagramBuilder

from stt_drake.assembly.diagram import add_loggers
from stt_drake.config import Scenario
from stt_drake.config.lcm import LcmConfig
from stt_drake.config.validate_lcm import validate_lcm
from stt_drake.robot.halves import (
    STARTUP_TIMEOUT,
    Link,
    add_bus,
    add_station,
    channels,
    link_clock,
)
from stt_drake.robot.remote import remote_scenario
from stt_drake.robot.transport import FilteredSubscriber, StaleLinkError
from stt_drake.run import RunResult, scenario_simulator, simulate
from stt_drake.runlog import RunLog, write_json

#: How long past its duration the station keeps serving a controller that lags behind
#: real time (s, simulated): it ends when the commands stop, at most this much later.
END_GRACE = 5.0

def simulate_split(scenario: Scenario, strict: bool | None = None) -> RunResult:
    """Both halves in one Simulator over an in-process ``memq://`` bus: the station's
    status and the controller's command cross the link every control period (with
    perception, the station's detections every sensor period), and the controller's run
    is checked and reported as ``stt-drake run``'s (its metrics gain the link's `lcm`
    record; the truth, in the same diagram, is logged as in process)."""
    return simulate(remote_scenario(scenario, in_process=True), strict)


def wait_for_station(scenario: Scenario, timeout: float = STARTUP_TIMEOUT) -> None:
    """Return once the station's status is on the scenario's bus (it announces its initial
    status until the first command); StaleLinkError after `timeout` wall-clock seconds.
    Waiting here, before the controller's Simulator exists, keeps the wait out of its
    real-time pacing (a Simulator paced from its Initialize would otherwise run the
    waited seconds at full speed to catch up)."""
    config = scenario.lcm or LcmConfig()
    lcm = DrakeLcm(DrakeLcmParams(lcm_url=config.lcm_url, channel_suffix=config.channel_suffix))
    inbox: list[bytes] = []
    status, _ = channels(scenario)
    lcm.Subscribe(status, inbox.append)
    deadline = time.monotonic() + timeout
    while not inbox and time.monotonic() < deadline:
        lcm.HandleSubscriptions(100)
    if not inbox:
        raise StaleLinkError(
            f"no {status} message within {timeout:g} s: is `stt-drake station` running on "
            f"this bus ({config.lcm_url or 'the default URL'})?"
        )


def run_controller(scenario: Scenario, strict: bool | None = None) -> RunResult:
    """The controller as a process of its own: the scenario's loop on the station's
    status, paced at real time (``set_target_realtime_rate(1)``, through the scenario's
    SimulatorConfig). It waits up to :data:`STARTUP_TIMEOUT` s for the station
    (:func:`wait_for_station`); a stale status sends the safe command and ends the run
    with that `stop_reason`."""
    remote = remote_scenario(scenario)
    wait_for_station(remote)
    config = copy.copy(remote.simulator)
    config.target_realtime_rate = 1.0
    return simulate(dataclasses.replace(remote, simulator=config), strict)


@dataclass
class StationResult:
    """A finished station run: its log (t and the logged signals) and its record."""

    log: dict[str, np.ndarray]
    record: dict[str, Any]

    def write(self, out_dir: Path) -> list[Path]:
        """station_log.npz and station.json into `out_dir`."""
        out_dir.mkdir(parents=True, exist_ok=True)
        log_path = out_dir / "station_log.npz"
        np.savez_compressed(log_path, **self.log)
        return [log_path, write_json(out_dir / "station.json", self.record)]


def run_station(scenario: Scenario, duration: float | None = None) -> StationResult:
    """The station as a process of its own, paced at real time: it announces its initial
    status until the controller's first command arrives (up to :data:`STARTUP_TIMEOUT` s),
    then runs for `duration` (default the scenario's) and on, up to :data:`END_GRACE` s
    more, until the commands go stale: a controller paced slightly behind real time (a busy
    machine, a 1 kHz arm) still gets its status to its own end. Stale commands before
    `duration` (the controller died) are the record's `stop_reason`; after it, the
    controller's normal end. Returns its log and record."""
    config = scenario.lcm or LcmConfig()
    validate_lcm(config)
    builder = DiagramBuilder()
    lcm = add_bus(builder, config)
    link = Link(lcm, config, link_clock(scenario, two_processes=True), STARTUP_TIMEOUT)
    plant = add_station(builder, scenario, link)
    loggers = add_loggers(
        builder, {"plant_state": plant.plant_state, **plant.logged}, scenario.log_period
    )
    diagram = builder.Build()
    subscriber: FilteredSubscriber = diagram.GetSubsystemByName("command_subscriber")
    simulator = scenario_simulator(diagram, scenario)
    simulator.set_target_realtime_rate(1.0)
    stop_reason = None
    end = scenario.duration if duration is None else duration
    start = time.perf_counter()
    try:
        simulator.Initialize()  # waits for the controller's first command
        simulator.ResetStatistics()  # real-time pacing from now on, not from the wait
        simulator.AdvanceTo(end + END_GRACE)
    except StaleLinkError as error:
        if simulator.get_context().get_time() < end:
            stop_reason = str(error)
    wall = time.perf_counter() - start
    context = simulator.get_context()
    log = {"t": loggers["plant_state"].FindLog(context).sample_times().copy()}
    for name, logger in loggers.items():
        log[name] = logger.FindLog(context).data().T.copy()
    link = subscriber.GetOutputPort("link")
    record = {
        "scenario": scenario.name,
        "stop_reason": stop_reason,
        "sim_time_s": context.get_time(),
        "wall_time_s": wall,
        "clock_epoch_s": subscriber.clock.epoch,
        "commands": subscriber.statistics.summary(
            link.Eval(subscriber.GetMyContextFromRoot(context))
        ),
    }
    return StationResult(log, record)


def merge_logs(controller_dir: Path, station_dir: Path) -> Path:
    """Join a station's log (station_log.npz, station.json) into the controller's run log
    (log.npz, metrics.json) in `controller_dir`, as merged_log.npz: every station signal
    as ``station_<name>`` with its times ``station_t`` on the controller's clock (shifted
    by the two processes' clock epochs, so the plots can draw the station's truth beside
    what the controller received)."""
    import json

    metrics = json.loads((controller_dir / "metrics.json").read_text())
    record = json.loads((station_dir / "station.json").read_text())
    station = np.load(station_dir / "station_log.npz")
    shift = 0.0
    epochs = (record.get("clock_epoch_s"), metrics.get("lcm", {}).get("clock_epoch_s"))
    if None not in epochs:
        shift = epochs[0] - epochs[1]
    merged = dict(RunLog.load(controller_dir / "log.npz"))
    merged["station_t"] = station["t"] + shift
    for name in station.files:
        if name != "t":
            merged[f"station_{name}"] = station[name]
    return RunLog.of(merged).save(controller_dir / "merged_log.npz")
