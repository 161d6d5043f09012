"""`stt-drake compare`: STT, the CBF-QP and the potential field on one short scenario, end to
end, and its refusals of bad input."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from stt_drake.cli.main import main

#: The keys of every comparison.json row, written out here rather than imported
#: from the code under test.
ROW_KEYS = {
    "controller",
    "model_error",
    "success_rate",
    "worst_collision_frequency",
    "clopper_pearson_lower_99",
    "clopper_pearson_upper_99",
    "verdict",
    "runs_to_certify",
    "t_output_in_target_s",
    "path_length_m",
    "min_clearance_m",
    "step_us_median",
    "qp_infeasible_count",
    "collision_rate",
    "min_distance_m",
    "comfort_violation_s",
    "obstacle_collision_frequency",
}

#: A 2D omni robot among 2 moving obstacles, 6 s.
SHORT = """\
name: compare_short
start: [0.5, 0.5]
initial_set_radius: 0.3
target: [3.0, 3.0]
target_set_radius: 0.3
duration: 6.0
tube: {r_min: 0.21, r_max: 0.27, k1: 0.7, k2: 0.4, k3: 0.4, max_center_speed: 1.0}
controller: {kappa: [8.0]}
plant:
  disturbance_amplitude: [0.05, 0.05]
  disturbance_frequency_hz: 0.3
obstacles:
  - motion: !ConstantVelocity {start: [1.5, 1.9], velocity: [0.05, -0.05]}
    radius: 0.15
    sigma: 0.1
    epsilon: 0.8
    p_d: 0.9999
  - motion: !ConstantVelocity {start: [2.2, 1.5], velocity: [-0.05, 0.05]}
    radius: 0.15
    sigma: 0.05
    epsilon: 0.9
    p_d: 0.9999
"""


@pytest.fixture(scope="module")
def short_scenario(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("compare") / "short.yaml"
    path.write_text(SHORT)
    return path


@pytest.fixture(scope="module")
def compared(short_scenario):
    """The command run once, as a user runs it: (completed process, output folder)."""
    out = short_scenario.parent / "out"
    script = Path(sys.executable).with_name("stt-drake")  # the installed console script
    command = [str(script), "compare", str(short_scenario)]
    command += ["--controllers", "stt", "cbf", "apf", "--runs", "50", "--workers", "2"]
    command += ["--out", str(out)]
    environment = {**os.environ, "DRAKE_ALLOW_NETWORK": "meshcat:package_map"}
    done = subprocess.run(command, capture_output=True, text=True, env=environment, timeout=300)
    return done, out


@pytest.mark.slow
def test_compare_writes_one_row_per_controller(compared):
    done, out = compared
    assert done.returncode == 0, done.stderr
    document = json.loads((out / "comparison.json").read_text())
    rows = document["rows"]
    assert [row["controller"] for row in rows] == ["stt", "cbf", "apf"]
    for row in rows:
        assert set(row) == ROW_KEYS
        assert row["model_error"] is None
        assert row["success_rate"] in (0.0, 1.0)
        for key in (
            "worst_collision_frequency",
            "clopper_pearson_lower_99",
            "clopper_pearson_upper_99",
            "path_length_m",
            "min_clearance_m",
            "step_us_median",
        ):
            assert isinstance(row[key], float) and math.isfinite(row[key]), (row, key)
        assert (
            0.0
            <= row["clopper_pearson_lower_99"]
            <= row["worst_collision_frequency"]
            <= row["clopper_pearson_upper_99"]
            <= 1.0
        )
        assert row["step_us_median"] > 0.0 and row["path_length_m"] > 0.0
        assert row["verdict"] in ("certified", "inconclusive", "violated")
        needed = row["runs_to_certify"]
        assert needed is None or (row["verdict"] == "inconclusive" and needed > 50)
        t_in = row["t_output_in_target_s"]
        assert t_in is None or 0.0 <= t_in <= 6.0
        assert (t_in is not None) or row["success_rate"] == 0.0
    cbf = rows[1]
    assert type(cbf["qp_infeasible_count"]) is int and cbf["qp_infeasible_count"] >= 0
    assert rows[0]["qp_infeasible_count"] is None and rows[2]["qp_infeasible_count"] is None
    # Each controller's campaign is in its own folder; the table is printed and written.
    for controller in ("stt", "cbf", "apf"):
        campaign = json.loads((out / controller / "campaign.json").read_text())
        assert campaign["runs"] == 50
    table = (out / "comparison.md").read_text()
    assert table.startswith("# Controller comparison: compare_short\n")
    assert table.count("\n| ") == 4 and "| cbf |" in table  # the header and a row each
    assert "| stt |" in done.stdout
    assert "Polishing" not in done.stdout  # OSQP's C code prints nothing (polishing off)
    assert (out / "comparison.png").stat().st_size > 10_000


def test_a_bad_controller_is_refused_naming_the_option(short_scenario, tmp_path, capsys):
    out = tmp_path / "out"
    code = main(
        [
            "compare",
            str(short_scenario),
            "--controllers",
            "stt",
            "mpc",
            "--runs",
            "5",
            "--out",
            str(out),
        ]
    )
    error = capsys.readouterr().err
    assert code == 2
    assert "--controllers" in error and "'mpc'" in error and "Traceback" not in error
    assert not out.exists()


def test_the_arm_has_no_baseline(tmp_path, capsys):
    out = tmp_path / "out"
    code = main(
        [
            "compare",
            "franka_pick_place_case1",
            "--controllers",
            "stt",
            "cbf",
            "--runs",
            "5",
            "--out",
            str(out),
        ]
    )
    error = capsys.readouterr().err
    assert code == 2
    assert "--controllers" in error and "FrankaArm" in error and "Traceback" not in error
