"""The recorded Meshcat replay (replay.html) loads in headless Chromium and draws the scene
(not a blank page)."""

from __future__ import annotations

import shutil
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


def _screenshot(page: Path, tmp_path: Path) -> np.ndarray:
    chromium = shutil.which("chromium")
    assert chromium, "chromium is not installed (.ci/run installs the Debian package)"
    shot = tmp_path / f"{page.stem}.png"
    subprocess.run(
        [
            chromium,
            *CHROMIUM_FLAGS,
            f"--user-data-dir={tmp_path / 'profile'}",
            f"--screenshot={shot}",
            page.as_uri(),
        ],
        check=True,
        capture_output=True,
        timeout=180,
    )
    return imread(shot)[:, :, :3]


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
