"""`stt-drake station SCENARIO` and `stt-drake controller SCENARIO`: the scenario split
at the robot's interface into two processes that talk over LCM (the scenario's `lcm:`
section: bus URL, channels, rate, stale timeout), and `stt-drake merge-logs`, which joins
the station's log into the controller's run log.

Start either first: each waits for the other. The controller writes metrics.json (with
the link's `lcm` timing record) and log.npz, as `stt-drake run`; the station writes
station.json and station_log.npz.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from stt_drake.cli.main import BadInputError, add_scenario_arguments, load_scenario_arguments

if TYPE_CHECKING:
    from stt_drake.config import Scenario


def _scenario(args: argparse.Namespace) -> tuple[Scenario, Path]:
    """The scenario and out folder, with ``--lcm-url`` in its `lcm:` section, which must
    be valid (a bad value is bad input, exit 2)."""
    from stt_drake.config import ScenarioError
    from stt_drake.config.lcm import LcmConfig
    from stt_drake.config.validate_lcm import validate_lcm

    scenario, out_dir = load_scenario_arguments(args)
    config = scenario.lcm or LcmConfig()
    if args.lcm_url is not None:
        config.lcm_url = args.lcm_url
    try:
        validate_lcm(config)
    except ScenarioError as error:
        raise BadInputError(f"stt-drake: {error}") from None
    scenario.lcm = config
    return scenario, out_dir


def _controller(args: argparse.Namespace) -> bool:
    from stt_drake.robot.session import run_controller
    from stt_drake.run import summary, write_outputs

    scenario, out_dir = _scenario(args)
    result = run_controller(scenario)
    written = write_outputs(result, out_dir, figures=not args.no_figures)
    print(summary(result))
    print(f"  wrote {', '.join(str(p) for p in written)}")
    return result.success


def _station(args: argparse.Namespace) -> bool:
    from stt_drake.robot.session import run_station

    scenario, out_dir = _scenario(args)
    result = run_station(scenario)
    written = result.write(out_dir)
    record = result.record
    print(f"station {record['scenario']}: simulated {record['sim_time_s']:.2f} s")
    if record["stop_reason"]:
        print(f"  stopped: {record['stop_reason']}")
    print(f"  wrote {', '.join(str(p) for p in written)}")
    return True


def _merge(args: argparse.Namespace) -> bool:
    from stt_drake.robot.session import merge_logs

    for folder, name in ((args.controller_dir, "metrics.json"), (args.station_dir, "station.json")):
        if not (folder / name).is_file():
            raise BadInputError(f"stt-drake: merge-logs: no {name} in {folder}")
    print(f"wrote {merge_logs(args.controller_dir, args.station_dir)}")
    return True


def _add_common(parser: argparse.ArgumentParser) -> None:
    add_scenario_arguments(parser, scenario_help="scenario YAML (its lcm: section sets the bus)")
    parser.add_argument(
        "--lcm-url",
        default=None,
        help="bus URL replacing the scenario's lcm.lcm_url (e.g. udpm://239.255.76.67:7667?ttl=0)",
    )


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Declare `stt-drake station`, `stt-drake controller` and `stt-drake merge-logs`."""
    station = commands.add_parser(
        "station",
        help="run a scenario's robot (plant, drive interface; with perception the "
        "obstacles and the sensor) on its own, over LCM",
        description="Publishes the robot's status and applies the controller's commands "
        "at the scenario's lcm.control_rate_hz (with perception, publishes the sensor's "
        "detections at its rate), paced at real time; ends at the scenario's duration or "
        "when the commands go stale.",
        epilog="Exit code 0: the station ran to its end (a stop is said in its output and "
        "station.json); 2: bad input.",
    )
    _add_common(station)
    station.set_defaults(handler=_station)
    controller = commands.add_parser(
        "controller",
        help="run a scenario's STT controller (tracker, tube, controller) and monitor on "
        "its own, over LCM",
        description="Exit code 0: every guarantee held and the target was reached; 1: a "
        "guarantee failed, the target was not reached or the run stopped (a stale status: "
        "the safe command was sent); 2: bad input.",
    )
    _add_common(controller)
    controller.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    controller.set_defaults(handler=_controller)
    merge = commands.add_parser(
        "merge-logs",
        help="join a station's log into the controller's run log",
        epilog="Exit code 0: merged; 2: bad input (a folder without its metrics.json or "
        "station.json).",
    )
    merge.add_argument("controller_dir", type=Path, help="the controller's output folder")
    merge.add_argument("station_dir", type=Path, help="the station's output folder")
    merge.set_defaults(handler=_merge)
