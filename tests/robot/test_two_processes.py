"""`stt-drake station` and `stt-drake controller` as two processes over UDP multicast:
a short closed loop at real time, its logs merged, and the station killed mid-run."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pydrake.lcm import DrakeLcm

ROOT = Path(__file__).resolve().parents[2]
#: A port of our own, so a concurrent test run on the default bus is not disturbed.
URL = f"udpm://239.255.76.67:{7700 + os.getpid() % 200}?ttl=0"


def multicast_unavailable(url: str) -> str | None:
    """Why two processes cannot talk over `url` here (None: they can): Drake's network
    policy (``DRAKE_ALLOW_NETWORK`` without ``lcm`` turns every udpm:// bus off), or a
    message published on `url` that does not come back to a subscriber within 2 s."""
    policy = os.environ.get("DRAKE_ALLOW_NETWORK")
    if policy is not None and "lcm" not in policy.split(":"):
        return f"DRAKE_ALLOW_NETWORK={policy!r} does not allow lcm (UDP multicast is off)"
    try:
        lcm = DrakeLcm(url)
    except RuntimeError as error:
        return f"cannot open {url}: {error}"
    received: list[bytes] = []
    lcm.Subscribe("STT_PROBE", received.append)
    deadline = time.monotonic() + 2.0
    while not received and time.monotonic() < deadline:
        lcm.Publish("STT_PROBE", b"\0" * 16, None)
        lcm.HandleSubscriptions(50)
    return None if received else f"UDP multicast ({url}) does not loop back here"


UNAVAILABLE = multicast_unavailable(URL)
pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(UNAVAILABLE is not None, reason=str(UNAVAILABLE)),
]


def _scenario(tmp_path: Path, duration: float) -> Path:
    text = (ROOT / "diagrams" / "omni_hardware_case1.yaml").read_text()
    path = tmp_path / "short.yaml"
    path.write_text(
        text.replace("duration: 25.0", f"duration: {duration}") + f"lcm: {{lcm_url: '{URL}'}}\n"
    )
    return path


def _start(command: str, scenario: Path, out: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "stt_drake.cli.main", command, str(scenario), "--out", str(out)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


def test_two_processes_close_the_loop_and_a_killed_station_stops_the_controller(tmp_path):
    scenario = _scenario(tmp_path, 8.0)  # t_c = 7.2 s: reached, exit code 0
    station = _start("station", scenario, tmp_path / "station")
    controller = _start("controller", scenario, tmp_path / "controller")
    assert controller.wait(timeout=120) == 0, controller.stdout.read()
    assert station.wait(timeout=30) == 0, station.stdout.read()
    metrics = json.loads((tmp_path / "controller" / "metrics.json").read_text())
    assert metrics["holds"] and metrics["stop_reason"] is None
    assert 0.9 < metrics["realtime_factor"] < 1.1
    link = metrics["lcm"]
    assert link["accepted"] >= 700 and link["out_of_order_dropped"] == 0
    merged = subprocess.run(
        [
            sys.executable,
            "-m",
            "stt_drake.cli.main",
            "merge-logs",
            str(tmp_path / "controller"),
            str(tmp_path / "station"),
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert merged.returncode == 0, merged.stderr
    from stt_drake.runlog import RunLog

    log = RunLog.load(tmp_path / "controller" / "merged_log.npz")
    assert "station_plant_state" in log and "station_t" in log

    long = _scenario(tmp_path, 30.0)
    station = _start("station", long, tmp_path / "station_killed")
    controller = _start("controller", long, tmp_path / "controller_killed")
    time.sleep(8.0)
    station.kill()
    station.wait(timeout=10)
    killed_at = time.monotonic()
    assert controller.wait(timeout=60) == 1
    assert time.monotonic() - killed_at < 30.0  # writing figures included; nothing hangs
    metrics = json.loads((tmp_path / "controller_killed" / "metrics.json").read_text())
    assert "StaleLinkError" in metrics["stop_reason"] and "STT_STATUS" in metrics["stop_reason"]
    assert metrics["sim_time_s"] < 30.0
