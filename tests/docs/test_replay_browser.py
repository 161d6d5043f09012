"""The recorded Meshcat replay (replay.html) loads in headless Chromium and draws the scene
(not a blank page)."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread

from stt_drake.replay import simulate_live
from tests.outputs.test_replay import short_scenario

CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    # WebGL without a GPU: Chromium's software rasteriser.
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--window-size=900,700",
    "--virtual-time-budget=8000",
]


def _screenshot(page: Path, tmp_path: Path, attempts: int = 3) -> np.ndarray:
    """Chromium's screenshot of `page`.

    Headless Chromium now and then hangs without exiting (seen once in CI: 180 s with no
    screenshot, on a page that renders in ~5 s here). Each attempt runs in its own process
    group with a 60 s limit; a hung attempt is killed with all its children and retried."""
    chromium = shutil.which("chromium")
    assert chromium, "chromium is not installed (.ci/run installs the Debian package)"
    shot = tmp_path / f"{page.stem}.png"
    failures = []
    for attempt in range(attempts):
        shot.unlink(missing_ok=True)
        command = [
            chromium,
            *CHROMIUM_FLAGS,
            f"--user-data-dir={tmp_path / f'profile-{page.stem}-{attempt}'}",
            f"--screenshot={shot}",
            page.as_uri(),
        ]
        process = subprocess.Popen(
            command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True
        )
        try:
            _, stderr = process.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            _, stderr = process.communicate()
            failures.append(f"attempt {attempt + 1}: no exit within 60 s")
            continue
        if process.returncode == 0 and shot.exists():
            return imread(shot)[:, :, :3]
        failures.append(
            f"attempt {attempt + 1}: exit {process.returncode}, "
            f"stderr tail: {stderr.decode(errors='replace')[-400:]}"
        )
    pytest.fail("chromium took no screenshot:\n" + "\n".join(failures))


def _obstacle_red_pixels(image: np.ndarray) -> int:
    red, green, blue = image[:, :, 0], image[:, :, 1], image[:, :, 2]
    return int(np.count_nonzero((red > 0.55) & (red - green > 0.25) & (red - blue > 0.25)))


@pytest.mark.browser
def test_replay_renders_the_scene_in_headless_chromium(tmp_path):
    replay = tmp_path / "replay.html"
    simulate_live(short_scenario("omni_hardware_case1", 3.0), replay)
    blank = tmp_path / "blank.html"
    blank.write_text("<html><body style='background:#ddd'></body></html>")

    scene = _screenshot(replay, tmp_path)
    empty = _screenshot(blank, tmp_path)

    colours = np.unique((scene * 255).astype(np.uint8).reshape(-1, 3), axis=0)
    assert len(colours) > 200, "the replay page looks blank"
    assert _obstacle_red_pixels(scene) > 100, "no obstacle (red) drawn"
    assert _obstacle_red_pixels(empty) == 0  # the detector does not fire on a plain page
