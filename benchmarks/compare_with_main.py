"""`make bench-compare`: the benchmark history's rows (this folder) timed on a reference
commit (default ``main``) and then on the working tree, on this machine; prints every row's
minimum and median on both and their ratios, names every row more than :data:`THRESHOLD`
slower on the working tree, and exits 1 if there is one (2 if a run could not be made). A
row file that does not import on the reference (a new row on a new helper) is left out of
the reference's run: its rows are timed on the working tree only, and the output says so.

The reference is exported with ``git archive`` into a temporary folder, the working tree's
benchmark files are copied into it, and its rows run from there: pytest puts the folder it
runs from first on ``sys.path``, so run from the working tree both runs would time the
working tree. Both runs time the working tree's benchmark files, so they measure the same
calls, and each checks that it imported the tree it was asked to time
(:data:`TREE_VARIABLE`, checked by ``benchmarks/conftest.py``). A row is slower when both
its minimum and its median over the rounds grew by more than the threshold: a real slowdown
moves both, while noise here moved one at a time (a closed loop's lucky round put its
minimum 30 % below its median; a busy moment moved a kernel's median by 16 % with its
minimum within 3 %). Run it on a quiet machine: other processes move closed loops by
10-25 % here.

Usage: ``python benchmarks/compare_with_main.py [REF]``.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: A row whose minimum and median both grow by more than this fraction is a regression.
THRESHOLD = 0.10
#: The environment variable naming the tree a run must time (benchmarks/conftest.py).
TREE_VARIABLE = "STT_DRAKE_BENCH_TREE"


Timing = tuple[float, float]  # (minimum, median) of a row's rounds, seconds


def _timed_rows(output: Path, tree: Path) -> dict[str, Timing] | None:
    """Run the rows of `tree`/benchmarks from `tree`, timing the stt_drake of `tree`; each
    row's (minimum, median) by name, None if it failed."""
    env = {key: value for key, value in os.environ.items() if key != "PYTHONPATH"}
    env |= {"PYTHONPATH": str(tree), TREE_VARIABLE: str(tree)}
    command = [
        sys.executable, "-m", "pytest", str(tree / "benchmarks"), "-q", "-p", "no:cacheprovider",
        "-p", "no:xdist", f"--benchmark-json={output}", "--benchmark-columns=min,median,rounds",
    ]  # fmt: skip
    if subprocess.run(command, cwd=tree, env=env, check=False).returncode != 0:
        return None
    rows = json.loads(output.read_text())["benchmarks"]
    return {row["fullname"]: (row["stats"]["min"], row["stats"]["median"]) for row in rows}


def unimportable(tree: Path) -> list[Path]:
    """The row files of `tree`/benchmarks that do not import against the stt_drake of
    `tree`: the working tree's files copied onto an older reference, whose new rows use
    helpers the reference does not have yet."""
    env = {key: value for key, value in os.environ.items() if key != "PYTHONPATH"}
    env["PYTHONPATH"] = str(tree)
    failing = []
    for path in sorted((tree / "benchmarks").glob("test_*.py")):
        command = [sys.executable, "-c", f"import benchmarks.{path.stem}"]
        if subprocess.run(command, cwd=tree, env=env, capture_output=True).returncode != 0:
            failing.append(path)
    return failing


def regressions(reference: dict[str, Timing], working: dict[str, Timing]) -> list[str]:
    """The rows of both runs whose minimum and median both grew by more than
    :data:`THRESHOLD`."""
    limit = 1.0 + THRESHOLD
    return [
        name
        for name in sorted(reference.keys() & working.keys())
        if all(now > limit * then for now, then in zip(working[name], reference[name], strict=True))
    ]


def main(argv: list[str]) -> int:
    reference_name = argv[0] if argv else "main"
    with tempfile.TemporaryDirectory() as folder:
        base = Path(folder) / "reference"
        base.mkdir()
        archive = subprocess.run(
            ["git", "archive", reference_name], cwd=ROOT, capture_output=True, check=False
        )
        if archive.returncode != 0:
            print(f"bench-compare: {reference_name}: {archive.stderr.decode().strip()}")
            return 2
        subprocess.run(["tar", "-x", "-C", str(base)], input=archive.stdout, check=True)
        shutil.copytree(ROOT / "benchmarks", base / "benchmarks", dirs_exist_ok=True)
        for path in unimportable(base):  # their rows are timed on the working tree only
            print(f"bench-compare: {path.name} does not import on {reference_name}: not compared")
            path.unlink()
        print(f"bench-compare: timing {reference_name}", flush=True)
        reference = _timed_rows(Path(folder) / "reference.json", base)
        print("bench-compare: timing the working tree", flush=True)
        working = _timed_rows(Path(folder) / "working.json", ROOT)
    if reference is None or working is None:
        print("bench-compare: a run of the rows failed (its output is above)")
        return 2
    print(f"\n{'row (µs: min / median)':<58} {reference_name:>21} {'working':>21}  ratios")
    for name in sorted(reference.keys() & working.keys()):
        (then_min, then_median), (now_min, now_median) = reference[name], working[name]
        print(
            f"{name.removeprefix('benchmarks/'):<58} "
            f"{1e6 * then_min:10.2f} {1e6 * then_median:10.2f} "
            f"{1e6 * now_min:10.2f} {1e6 * now_median:10.2f}  "
            f"{now_min / then_min:.3f} {now_median / then_median:.3f}"
        )
    slower = regressions(reference, working)
    for name in slower:
        print(f"bench-compare: SLOWER by more than {THRESHOLD:.0%}: {name}")
    if not slower:
        print(f"bench-compare: no row more than {THRESHOLD:.0%} slower than {reference_name}")
    return 1 if slower else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
