"""`stt-drake diagram`: the Drake Diagram as Graphviz DOT, SVG and PNG."""

from __future__ import annotations

from pathlib import Path

import pytest

from stt_drake.cli.diagram import write_diagram_pictures
from stt_drake.cli.main import main

ROOT = Path(__file__).resolve().parents[2]
CASE1 = ROOT / "diagrams" / "omni_hardware_case1.yaml"
SYSTEMS = ("obstacle_belief_source", "spatiotemporal_tube", "stt_controller", "invariant_monitor")


def test_diagram_command_draws_every_system_and_port(tmp_path, capsys):
    assert main(["diagram", str(CASE1), "--out", str(tmp_path)]) == 0
    dot = (tmp_path / "diagram.dot").read_text()
    svg = (tmp_path / "diagram.svg").read_text()
    for name in (*SYSTEMS, "omni_robot", "omni_drive_interface"):
        assert name in dot and name in svg, name
    for port in ("obstacle_belief", "tube", "plant_state", "control", "margins"):
        assert port in svg, port
    assert (tmp_path / "diagram.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "diagram.svg" in capsys.readouterr().out


def test_without_graphviz_only_the_dot_file_is_written(tmp_path, monkeypatch):
    monkeypatch.setattr("shutil.which", lambda name: None)
    with pytest.raises(FileNotFoundError, match="graphviz"):
        write_diagram_pictures("digraph { a -> b }", tmp_path, ("svg",))
    assert (tmp_path / "diagram.dot").read_text() == "digraph { a -> b }"
    assert not (tmp_path / "diagram.svg").exists()


def test_bad_scenario_exits_2(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text(CASE1.read_text().replace("r_min: 0.21", "r_min: -1"))
    assert main(["diagram", str(bad), "--out", str(tmp_path / "out")]) == 2
    assert "scenario.tube.r_min" in capsys.readouterr().err
