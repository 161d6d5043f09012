"""Packaging: the wheel ships the scenarios and the arm model, the CLI finds them by name from
any folder, dependencies are ranges with exact versions in requirements.lock, and Dask is
needed only for ``--scheduler``."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest
from packaging.requirements import Requirement

from stt_drake.cli.main import main, packaged_scenarios, resolve_scenario

ROOT = Path(__file__).resolve().parents[2]
SCENARIOS = sorted(path.name for path in (ROOT / "diagrams").glob("*.yaml"))
#: The fastest packaged scenario that reaches its target (25 s simulated, ~1-2 s of wall).
FAST = "omni_hardware_case1"


def _console_script() -> str:
    script = Path(sys.executable).parent / "stt-drake"
    assert script.exists(), "the stt-drake console script is not installed next to python"
    return str(script)


def _pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """A wheel built offline from a copy of the sources (the build writes build/ and
    *.egg-info next to them, not into the checkout)."""
    work = tmp_path_factory.mktemp("wheel")
    src = work / "src"
    src.mkdir()
    shutil.copy(ROOT / "pyproject.toml", src)
    shutil.copy(ROOT / "README.md", src)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    for folder in ("stt_drake", "diagrams", "models"):
        shutil.copytree(ROOT / folder, src / folder, ignore=ignore)
    build = ["wheel", "--no-deps", "--no-build-isolation", "--no-index", "-w", str(work / "dist")]
    completed = subprocess.run(
        [sys.executable, "-m", "pip", *build, str(src)],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert completed.returncode == 0, completed.stdout + completed.stderr
    (built,) = (work / "dist").glob("stt_drake-*.whl")
    return built


@pytest.mark.slow
def test_the_wheel_ships_the_scenarios_the_arm_model_and_every_module(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    assert SCENARIOS, "no scenario in diagrams/"
    missing = [name for name in SCENARIOS if f"stt_drake/diagrams/{name}" not in names]
    assert not missing, f"scenarios missing from {wheel.name}: {missing}"
    assert "stt_drake/models/franka_fr3.urdf" in names
    # Every module of the source tree (a package not listed in pyproject.toml would be lost).
    modules = {
        path.relative_to(ROOT).as_posix()
        for path in (ROOT / "stt_drake").rglob("*.py")
        if "__pycache__" not in path.parts
    }
    assert not modules - names, f"modules missing from the wheel: {sorted(modules - names)}"


@pytest.mark.slow
def test_the_unpacked_wheel_finds_its_data_with_importlib_resources(wheel, tmp_path):
    """The wheel's own files (not the checkout's) on sys.path first: the scenarios, the URDF
    and `stt-drake list` resolve inside it, from an unrelated folder."""
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    code = (
        "import stt_drake, sys\n"
        "from stt_drake.cli.main import main, packaged_scenarios\n"
        "from stt_drake.systems.plants.franka import FR3_MODEL\n"
        "from stt_drake.bench import DIAGRAMS\n"
        "print(stt_drake.__file__)\n"
        "print(FR3_MODEL, FR3_MODEL.is_file())\n"
        "print(DIAGRAMS)\n"
        "print(sorted(p.name for p in packaged_scenarios().values()))\n"
        "sys.exit(main(['list']))\n"
    )
    unrelated = tmp_path / "elsewhere"
    unrelated.mkdir()
    completed = subprocess.run(
        [sys.executable, "-c", code],
        cwd=unrelated,
        env={**os.environ, "PYTHONPATH": str(site)},
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert completed.returncode == 0, completed.stdout + completed.stderr
    package, model, diagrams, scenarios, *listing = completed.stdout.splitlines()
    assert Path(package).is_relative_to(site)
    assert model == f"{site / 'stt_drake' / 'models' / 'franka_fr3.urdf'} True"
    assert diagrams == str(site / "stt_drake" / "diagrams")
    assert scenarios == str(SCENARIOS)
    assert any(line.startswith("franka_pick_place_case1 ") for line in listing)


@pytest.mark.slow
def test_list_and_run_by_name_from_an_unrelated_folder(tmp_path):
    unrelated = tmp_path / "elsewhere"
    unrelated.mkdir()
    env = {**os.environ, "MPLBACKEND": "Agg"}
    listing = subprocess.run(
        [_console_script(), "list"],
        cwd=unrelated,
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
        check=False,
    )
    assert listing.returncode == 0, listing.stderr
    lines = {line.split()[0]: line for line in listing.stdout.splitlines() if line.strip()}
    for name in (Path(scenario).stem for scenario in SCENARIOS):
        assert name in lines, f"{name} not listed"
    assert "indoor arena" in lines[FAST]  # the first comment line of the file

    out = tmp_path / "out"
    completed = subprocess.run(
        [_console_script(), "run", FAST, "--out", str(out), "--no-figures"],
        cwd=unrelated,
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
        check=False,
    )
    assert completed.returncode == 0, completed.stdout + completed.stderr
    assert (out / "metrics.json").stat().st_size > 0
    assert "reached the target set: yes" in completed.stdout
    assert not (unrelated / "results").exists()


def test_an_existing_path_wins_over_a_packaged_name(tmp_path, monkeypatch):
    packaged = packaged_scenarios()
    assert resolve_scenario(FAST) == packaged[FAST]
    assert resolve_scenario(f"{FAST}.yaml") == packaged[FAST]
    monkeypatch.chdir(tmp_path)
    (tmp_path / FAST).write_text("# a local file of the same name\n")
    assert resolve_scenario(FAST) == Path(FAST)


def test_an_unknown_name_exits_2_with_close_names(capsys):
    assert main(["run", "omni_hardwre_case1"]) == 2
    err = capsys.readouterr().err
    assert "no such scenario file, and no packaged scenario of that name" in err
    assert "omni_hardware_case1" in err and "stt-drake list" in err


def test_dependencies_are_ranges_and_the_lock_pins_versions_inside_them():
    project = _pyproject()["project"]
    lock = {}
    for line in (ROOT / "requirements.lock").read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            requirement = Requirement(line)
            (spec,) = requirement.specifier
            assert spec.operator == "==", line
            lock[requirement.name.lower().replace("_", "-")] = spec.version
    requirements = [*project["dependencies"]]
    for extra in project["optional-dependencies"].values():
        requirements += [r for r in extra if not r.startswith("stt-drake")]
    for text in requirements:
        requirement = Requirement(text)
        assert all(spec.operator != "==" for spec in requirement.specifier), text
        name = requirement.name.lower().replace("_", "-")
        assert name in lock, f"{name} is not in requirements.lock"
        assert requirement.specifier.contains(lock[name]), f"{name}=={lock[name]} not in {text}"
    # Dask only in the cluster extra, which the test extra pulls in.
    names = {Requirement(r).name for r in project["dependencies"]}
    assert not names & {"dask", "distributed"}
    assert {Requirement(r).name for r in project["optional-dependencies"]["cluster"]} == {
        "dask",
        "distributed",
    }
    assert "stt-drake[cluster]" in project["optional-dependencies"]["test"]
    makefile = (ROOT / "Makefile").read_text()
    assert "pip install --quiet -c requirements.lock -e '.[test]'" in makefile


def test_scheduler_without_dask_exits_2_naming_the_extra(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "distributed", None)  # `import distributed` fails
    cluster = ["--scheduler", "tcp://127.0.0.1:8786", "--out", str(tmp_path / "c")]
    code = main(["campaign", FAST, "--runs", "2", *cluster, "--no-progress"])  # by name
    err = capsys.readouterr().err
    assert code == 2, err
    assert "pip install 'stt-drake[cluster]'" in err and "--scheduler" in err
