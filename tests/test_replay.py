"""The Meshcat replay (stt_drake.replay) and `stt-drake run --meshcat` on the UAV scenario.

The replay's animation is read back from the HTML itself (the base64 msgpack command
Meshcat embeds) and compared with the log it was written from.
"""

from __future__ import annotations

import base64
import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import msgpack
import numpy as np
import pytest
from conftest import INVARIANT_KEYS
from test_plotting import make_log

from stt_drake.core.belief import ObstacleBelief
from stt_drake.replay import write_meshcat_replay

ROOT = Path(__file__).resolve().parent.parent
#: The metrics.json contract (README), the same for every case study.
METRICS_KEYS = {
    "scenario",
    "reached",
    "t_reach",
    "holds",
    "sim_time_s",
    "wall_time_s",
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
    "step_rate",
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


def animation(html: str) -> tuple[float, dict[str, dict[str, np.ndarray]]]:
    """The replay's animation: (frames per second, {path: {track: (frames, k) values}})."""
    for blob in re.findall(r"base64,([A-Za-z0-9+/=]+)", html):
        raw = base64.b64decode(blob)
        if b"set_animation" not in raw:
            continue
        command = msgpack.unpackb(raw, raw=False, strict_map_key=False)
        tracks, rates = {}, set()
        for item in command["animations"]:
            rates.add(item["clip"]["fps"])
            tracks[item["path"]] = {
                track["name"]: np.array([key["value"] for key in track["keys"]], dtype=float)
                for track in item["clip"]["tracks"]
            }
            for track in item["clip"]["tracks"]:
                assert [key["time"] for key in track["keys"]] == list(range(len(track["keys"])))
        assert len(rates) == 1
        return rates.pop(), tracks
    raise AssertionError("no set_animation command in the HTML")


def shown_samples(positions: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Index of the logged sample each animation frame shows (exact row match)."""
    indices = []
    for position in positions:
        (match,) = np.flatnonzero(np.all(reference == position, axis=1))[:1]
        indices.append(int(match))
    return np.array(indices)


def lift(points: np.ndarray) -> np.ndarray:
    return np.concatenate([points, np.zeros((*points.shape[:-1], 3 - points.shape[-1]))], -1)


def rotate(quaternion_xyzw: np.ndarray, vector: np.ndarray) -> np.ndarray:
    """Rotate `vector` by a unit quaternion [x, y, z, w] (three.js order)."""
    u, w = quaternion_xyzw[:3], quaternion_xyzw[3]
    return vector + 2.0 * np.cross(u, np.cross(u, vector) + w * vector)


@pytest.mark.parametrize("dimension", [2, 3])
def test_replay_animates_the_logged_run(tmp_path, dimension):
    """Every frame shows one logged sample: the tube at c with scale r, each obstacle at its
    mean, the robot at y (2D runs in the plane z = 0); frames run from the first to the last
    sample, at most max_frames + 1 of them, played back on the logged time scale."""
    log = make_log(dimension)
    max_frames = 20
    path = write_meshcat_replay(log, tmp_path / "out" / "replay.html", max_frames=max_frames)
    assert path == tmp_path / "out" / "replay.html"
    html = path.read_text()
    check_self_contained(html)
    fps, tracks = animation(html)

    # y circles c, so the robot position identifies the sample (c rests at the end).
    samples = shown_samples(tracks["/stt/robot"][".position"], lift(log["output"]))
    tube = tracks["/stt/tube"]
    np.testing.assert_array_equal(tube[".position"], lift(log["center"])[samples])
    t = log["t"]
    assert samples[0] == 0 and samples[-1] == t.size - 1
    assert np.all(np.diff(samples) > 0)
    assert samples.size <= max_frames + 1
    assert np.max(np.diff(samples)) <= math.ceil(t.size / max_frames)
    assert (samples.size - 1) / fps == pytest.approx(t[-1] - t[0])
    np.testing.assert_allclose(tube[".scale"], np.repeat(log["radius"][samples, None], 3, 1))
    means = np.array([ObstacleBelief.from_vector(row, dimension).mean for row in log["belief"]])
    for j in range(means.shape[1]):
        np.testing.assert_array_equal(
            tracks[f"/stt/obstacles/{j}"][".position"], lift(means[samples, j])
        )


def test_replay_tilts_the_uav_along_the_commanded_force(tmp_path):
    """In 3D the body's z axis follows the commanded force u (the thrust direction)."""
    log = make_log(3)
    html = write_meshcat_replay(log, tmp_path / "replay.html", body_radius=0.3).read_text()
    _, tracks = animation(html)
    robot = tracks["/stt/robot"]
    samples = shown_samples(robot[".position"], log["output"])
    for quaternion, k in zip(robot[".quaternion"], samples, strict=True):
        direction = log["control"][k] / np.linalg.norm(log["control"][k])
        np.testing.assert_allclose(
            rotate(quaternion, np.array([0.0, 0.0, 1.0])), direction, atol=1e-9
        )


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
        env={**os.environ, "MPLBACKEND": "Agg", "DRAKE_ALLOW_NETWORK": "meshcat"},
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
    assert metrics["scenario"] == "uav_paper" and metrics["reached"] is True
    assert 0 < metrics["t_reach"] < metrics["sim_time_s"] == pytest.approx(40.0)
    assert set(metrics["invariants"]) == INVARIANT_KEYS
    assert all(record["holds"] for record in metrics["invariants"].values())
    assert len(metrics["obstacles"]) == 4
    assert all(set(o) == OBSTACLE_KEYS for o in metrics["obstacles"])

    log = np.load(out / "log.npz")
    assert log["output"].shape == (len(log["t"]), 3)
    check_self_contained((out / "replay.html").read_text())


def test_the_replay_meshcat_listens_on_the_loopback_only():
    """pydrake's own default host is every interface ("*"); the replay's server is bound
    to 127.0.0.1 unless another host is asked for."""
    import psutil

    from stt_drake.replay import start_meshcat

    meshcat = start_meshcat()
    try:
        assert meshcat.web_url() == f"http://127.0.0.1:{meshcat.port()}"
        listening = [
            c.laddr
            for c in psutil.Process().net_connections(kind="tcp")
            if c.status == psutil.CONN_LISTEN and c.laddr.port == meshcat.port()
        ]
        assert listening and all(address.ip == "127.0.0.1" for address in listening)
    finally:
        del meshcat
