"""`make test`'s set-up of the Debian packages (the Makefile's `system-packages` recipe),
run with PATH limited to a folder of stand-ins: `id` says who the user is, `sudo` and `env`
record their arguments instead of running anything, and `dot`/`chromium` are there or not.
Nothing is installed."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
MAKE = shutil.which("make")
COMMAND = "sudo apt-get install -y graphviz chromium"


def _shims(folder: Path, uid: int, tools: tuple[str, ...]) -> Path:
    """A folder of stand-ins: `id -u` prints `uid`; each of `tools` records its arguments
    in calls.txt (one line per call) and succeeds."""
    folder.mkdir()
    (folder / "id").write_text(f"#!/bin/sh\necho {uid}\n")
    for tool in tools:
        (folder / tool).write_text(f'#!/bin/sh\necho "{tool} $*" >> "{folder}/calls.txt"\n')
    for path in folder.iterdir():
        path.chmod(0o755)
    return folder


def _system_packages(folder: Path) -> subprocess.CompletedProcess[str]:
    assert MAKE is not None
    return subprocess.run(
        [MAKE, "-s", "-C", str(ROOT), "system-packages"],
        env={"PATH": str(folder)},
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )


def _calls(folder: Path) -> list[str]:
    calls = folder / "calls.txt"
    return calls.read_text().splitlines() if calls.exists() else []


def test_without_root_or_sudo_it_stops_with_the_command_to_run(tmp_path):
    shims = _shims(tmp_path / "bin", uid=1000, tools=())
    done = _system_packages(shims)
    assert done.returncode != 0
    assert "needs root or sudo" in done.stderr
    assert f"\n  {COMMAND}\n" in done.stderr


def test_without_root_it_asks_through_sudo(tmp_path):
    shims = _shims(tmp_path / "bin", uid=1000, tools=("sudo",))
    done = _system_packages(shims)
    assert done.returncode == 0, done.stderr
    assert "(through sudo)" in done.stdout
    assert _calls(shims) == [
        "sudo env DEBIAN_FRONTEND=noninteractive apt-get update -qq",
        "sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y graphviz chromium -qq",
    ]


def test_as_root_it_installs_directly(tmp_path):
    shims = _shims(tmp_path / "bin", uid=0, tools=("env",))
    done = _system_packages(shims)
    assert done.returncode == 0, done.stderr
    assert "sudo" not in done.stdout
    assert [call.split()[2] for call in _calls(shims)] == ["apt-get"] * 2


def test_a_failed_install_stops_with_the_command_to_run(tmp_path):
    shims = _shims(tmp_path / "bin", uid=1000, tools=())
    (shims / "sudo").write_text("#!/bin/sh\nexit 1\n")  # e.g. not in the sudoers file
    (shims / "sudo").chmod(0o755)
    done = _system_packages(shims)
    assert done.returncode != 0
    assert "installing graphviz and chromium failed" in done.stderr
    assert f"\n  {COMMAND}\n" in done.stderr


@pytest.mark.parametrize("uid", [0, 1000])
def test_nothing_is_installed_when_both_programs_are_there(tmp_path, uid):
    shims = _shims(tmp_path / "bin", uid=uid, tools=("dot", "chromium", "sudo", "env"))
    done = _system_packages(shims)
    assert done.returncode == 0 and done.stdout == "" and done.stderr == ""
    assert _calls(shims) == []
