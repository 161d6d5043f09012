"""The live Meshcat view (stt_drake.systems.visualizer, stt_drake.replay) and `stt-drake run
--meshcat` on the UAV scenario.

The recording is read back from the saved HTML itself (the base64 msgpack commands Meshcat
embeds) and compared with the run's log.
"""

from __future__ import annotations

import base64
import dataclasses
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import msgpack
import numpy as np
import pytest

from stt_drake.assembly import load_scenario
from stt_drake.plotting import level_set_radius
from stt_drake.replay import LOCALHOST, simulate_live, start_meshcat
from stt_drake.runlog import RunLog
from stt_drake.systems.visualizer import PUBLISH_PERIOD
from tests.conftest import INVARIANT_KEYS

ROOT = Path(__file__).resolve().parents[2]
#: The metrics.json contract (docs/guide/outputs.md), the same for every case study.
METRICS_KEYS = {
    "scenario",
    "reached",
    "t_tube_in_target",
    "t_output_in_target",
    "holds",
    "sim_time_s",
    "wall_time_s",
    "compile_time_s",
    "realtime_factor",
    "steps",
    "holds_tolerance",
    "strict_stop",
    "first_violation",
    "invariants",
    "obstacles",
    "stop_reason",
    "reach",
    "warnings",
    "assumptions",
    "belief_discontinuities",
    "recovery",
    "stalls",
    "step_rate",
    "tracks",
}
OBSTACLE_KEYS = {
    "index",
    "min_distance_to_mean",
    "t_min_distance",
    "sigma",
    "radius",
    "epsilon",
    "min_output_avoid_probability",
}


def check_self_contained(html: str) -> None:
    assert len(html.encode()) > 100_000
    assert "meshcat" in html.lower()
    assert not re.search(r"<script[^>]*\bsrc\s*=\s*[\"']?https?:", html, re.IGNORECASE)
    assert not re.search(r"<link[^>]*\bhref\s*=\s*[\"']?https?:", html, re.IGNORECASE)


def commands(html: str) -> list[dict]:
    """Every Meshcat command the HTML embeds (base64 msgpack)."""
    found = []
    for blob in re.findall(r"base64,([A-Za-z0-9+/=]+)", html):
        try:
            command = msgpack.unpackb(base64.b64decode(blob), raw=False, strict_map_key=False)
        except (ValueError, msgpack.exceptions.ExtraData):
            continue
        if isinstance(command, dict) and "type" in command:
            found.append(command)
    return found


def animation(html: str) -> tuple[float, dict[str, dict[str, np.ndarray]]]:
    """The replay's animation: (frames per second, {path: {track: (keys, k) values}}), and
    each track's key frame numbers under {path: {track + "@frames": (keys,)}}."""
    for command in commands(html):
        if command["type"] != "set_animation":
            continue
        tracks, rates = {}, set()
        for item in command["animations"]:
            rates.add(item["clip"]["fps"])
            tracks[item["path"]] = {}
            for track in item["clip"]["tracks"]:
                keys = track["keys"]
                tracks[item["path"]][track["name"]] = np.array(
                    [key["value"] for key in keys], dtype=float
                )
                frames = np.array([key["time"] for key in keys], dtype=float)
                assert np.all(np.diff(frames) > 0)
                tracks[item["path"]][track["name"] + "@frames"] = frames
        assert len(rates) == 1
        return rates.pop(), tracks
    raise AssertionError("no set_animation command in the HTML")


def lift(points: np.ndarray) -> np.ndarray:
    return np.concatenate([points, np.zeros((*points.shape[:-1], 3 - points.shape[-1]))], -1)


def rotate(quaternion_xyzw: np.ndarray, vector: np.ndarray) -> np.ndarray:
    """Rotate `vector` by a unit quaternion [x, y, z, w] (three.js order)."""
    u, w = quaternion_xyzw[:3], quaternion_xyzw[3]
    return vector + 2.0 * np.cross(u, np.cross(u, vector) + w * vector)


def listening_addresses(port: int) -> list:
    import psutil

    return [
        c.laddr
        for c in psutil.Process().net_connections(kind="tcp")
        if c.status == psutil.CONN_LISTEN and c.laddr.port == port
    ]


def short_scenario(name: str, duration: float):
    return dataclasses.replace(load_scenario(ROOT / "diagrams" / f"{name}.yaml"), duration=duration)


@pytest.mark.parametrize(("name", "dimension"), [("omni_hardware_case1", 2), ("uav_paper", 3)])
def test_live_view_records_the_tube_and_the_belief_on_the_loopback(tmp_path, name, dimension):
    """A short run drawn live into a Meshcat on 127.0.0.1: the saved replay.html holds the
    geometry set once (tube, each obstacle's r_o ball and its ε / p_d level sets, the robot,
    the task sets) and the recorded animation, at the publish rate, of the tube at c with
    scale r and each obstacle at its mean with its level-set radii — equal to the log at
    the instants both sampled."""
    meshcat = start_meshcat()
    assert meshcat.web_url() == f"http://{LOCALHOST}:{meshcat.port()}"
    listening = listening_addresses(meshcat.port())
    assert listening and all(address.ip == LOCALHOST for address in listening)
    try:
        result, path = simulate_live(
            short_scenario(name, 2.0), tmp_path / "out" / "replay.html", meshcat=meshcat
        )
    finally:
        del meshcat
    assert path == tmp_path / "out" / "replay.html"
    html = path.read_text()
    check_self_contained(html)
    log = result.log
    count = len(log["epsilon"])
    set_objects = {c["path"] for c in commands(html) if c["type"] == "set_object"}
    expected = {"/stt/tube/ball/shape", "/stt/robot/body/shape", "/stt/start", "/stt/target/0"}
    for j in range(count):
        for part in ("body", "epsilon_set", "p_d_set"):
            expected.add(f"/stt/obstacles/{j}/{part}/shape")
    assert expected <= set_objects

    fps, tracks = animation(html)
    assert fps == pytest.approx(1.0 / PUBLISH_PERIOD)
    tube = tracks["/stt/tube"]
    frames = tube[".position@frames"]
    assert frames[0] == 0 and frames[-1] == pytest.approx(2.0 * fps)
    assert frames.size >= 2.0 * fps  # one key per publish
    t = np.asarray(log["t"])
    # Frames that fall on a logged sample show that sample — up to the rounding of the
    # publish time k/30 (0.99999… s may precede a discrete update at 1 s): then they show
    # the state just before it, within one sample's motion.
    common = [
        (i, int(k)) for i, f in enumerate(frames) for k in np.flatnonzero(np.isclose(t, f / fps))
    ]
    assert len(common) >= 5
    rows, samples = np.array(common).T

    def matches(shown: np.ndarray, logged: np.ndarray) -> None:
        exact = np.all(np.isclose(shown, logged, rtol=0, atol=1e-9), axis=1)
        assert exact.mean() >= 0.8
        step = np.linalg.norm(np.diff(logged, axis=0), axis=1).max(initial=0.0)
        assert np.all(np.linalg.norm(shown - logged, axis=1) <= step + 1e-9)

    matches(tube[".position"][rows], lift(log["center"][samples]))
    matches(tracks["/stt/robot"][".position"][rows], lift(log["output"][samples]))
    # The tube's scale is recorded whenever r changes; the key at or before a frame holds.
    ball = tracks["/stt/tube/ball"]
    held = np.searchsorted(ball[".scale@frames"], frames[rows], side="right") - 1
    exact = np.isclose(ball[".scale"][held][:, 0], log["radius"][samples], rtol=1e-12)
    assert exact.mean() >= 0.8
    beliefs = [RunLog.of(log).belief_at(k) for k in range(len(log["t"]))]
    for j in range(count):
        matches(
            tracks[f"/stt/obstacles/{j}"][".position"][rows],
            lift(np.array([beliefs[k].mean[j] for k in samples])),
        )
        belief = beliefs[0]
        r_o = belief.radius[j]
        for part, level in (("epsilon_set", belief.epsilon[j]), ("p_d_set", belief.p_d[j])):
            radius = level_set_radius(level, belief.sigma[j], r_o, dimension)
            radius = max(radius, r_o) if np.isfinite(radius) else r_o
            scale = tracks[f"/stt/obstacles/{j}/{part}"][".scale"][0]
            assert scale[0] == pytest.approx(radius, rel=1e-8)
            assert scale[2] == pytest.approx(radius if dimension == 3 else 1.0, rel=1e-8)
        assert tracks[f"/stt/obstacles/{j}/body"][".scale"][0][0] == pytest.approx(r_o)


@pytest.mark.slow
def test_cli_runs_the_uav_scenario_with_the_2d_contract_and_a_replay(tmp_path):
    """`stt-drake run diagrams/uav_paper.yaml --out DIR --meshcat`: exit 0, the summary, the
    metrics.json contract of the 2D case, the 3D figures and a self-contained replay."""
    script = Path(sys.executable).parent / "stt-drake"
    out = tmp_path / "uav"
    completed = subprocess.run(
        [str(script), "run", "diagrams/uav_paper.yaml", "--out", str(out), "--meshcat"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env={**os.environ, "MPLBACKEND": "Agg", "DRAKE_ALLOW_NETWORK": "meshcat:package_map"},
        timeout=900,
        check=False,
    )
    assert completed.returncode == 0, completed.stdout + completed.stderr
    assert "reached the target set: yes" in completed.stdout
    assert "real-time factor" in completed.stdout and "SUCCESS" in completed.stdout
    for key in INVARIANT_KEYS:
        assert key in completed.stdout
    for name in ("metrics.json", "log.npz", "snapshots.png", "margins.png"):
        assert (out / name).stat().st_size > 10_000 or name == "metrics.json", name
    for name in ("snapshots.png", "margins.png"):
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    metrics = json.loads((out / "metrics.json").read_text())
    assert set(metrics) == METRICS_KEYS
    assert metrics["tracks"] == []  # no tracker: no track records
    assert metrics["scenario"] == "uav_paper" and metrics["reached"] is True
    assert 0 < metrics["t_tube_in_target"] < metrics["sim_time_s"] == pytest.approx(40.0)
    assert 0 < metrics["t_output_in_target"] <= metrics["t_tube_in_target"]
    assert set(metrics["invariants"]) == INVARIANT_KEYS
    assert all(record["holds"] for record in metrics["invariants"].values())
    assert len(metrics["obstacles"]) == 4
    assert all(set(o) == OBSTACLE_KEYS for o in metrics["obstacles"])

    log = np.load(out / "log.npz")
    assert log["output"].shape == (len(log["t"]), 3)
    html = (out / "replay.html").read_text()
    check_self_contained(html)
    _, tracks = animation(html)
    assert {"/stt/tube", "/stt/robot", "/stt/obstacles/0"} <= set(tracks)
    assert "live view: http://127.0.0.1:" in completed.stdout


def test_the_live_view_meshcat_listens_on_the_loopback_only():
    """pydrake's own default host is every interface ("*"); the live view's server is bound
    to 127.0.0.1 unless another host is asked for."""
    meshcat = start_meshcat()
    try:
        assert meshcat.web_url() == f"http://127.0.0.1:{meshcat.port()}"
        listening = listening_addresses(meshcat.port())
        assert listening and all(address.ip == "127.0.0.1" for address in listening)
    finally:
        del meshcat
