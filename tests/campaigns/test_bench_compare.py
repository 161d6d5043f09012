"""`make bench-compare`'s verdict (benchmarks/compare_with_main.py): a row is named when its
minimum and its median both grow by more than 10 %, and only rows timed in both runs are
compared."""

from __future__ import annotations

from benchmarks.compare_with_main import THRESHOLD, regressions


def test_rows_more_than_ten_percent_slower_are_named_and_only_those():
    assert THRESHOLD == 0.10
    reference = {
        "fast": (1.0, 1.1),
        "same": (2.0, 2.2),
        "edge": (1.0, 1.0),
        "slower": (3.0, 3.3),
        "gone": (1.0, 1.0),
    }
    working = {
        "fast": (0.5, 0.6),
        "same": (2.0, 2.2),
        "edge": (1.0999, 1.0999),
        "slower": (3.31, 3.64),
        "new": (9.0, 9.0),
    }
    assert regressions(reference, working) == ["slower"]


def test_noise_in_one_statistic_alone_is_not_a_regression():
    reference = {"lucky_minimum": (0.27, 0.385), "busy_median": (14.0, 14.0)}
    working = {"lucky_minimum": (0.377, 0.386), "busy_median": (14.2, 16.2)}
    assert regressions(reference, working) == []


def test_no_common_row_is_no_regression():
    assert regressions({"a": (1.0, 1.0)}, {"b": (100.0, 100.0)}) == []


def test_each_run_times_the_tree_it_is_asked_to(tmp_path):
    """The reference run imports the exported tree, not the working tree it was started
    from (the comparison once timed the working tree twice): a tree whose stt_drake is a
    stub that cannot be imported fails its run, and a run asked to time a tree it does not
    import stops with exit code 2."""
    import os
    import subprocess
    import sys

    from benchmarks.compare_with_main import ROOT, TREE_VARIABLE, _timed_rows

    stub = tmp_path / "stub"
    (stub / "stt_drake").mkdir(parents=True)
    (stub / "stt_drake" / "__init__.py").write_text("raise ImportError('the stub tree')\n")
    (stub / "benchmarks").mkdir()
    for name in ("__init__.py", "conftest.py"):
        (stub / "benchmarks" / name).write_text((ROOT / "benchmarks" / name).read_text())
    assert _timed_rows(tmp_path / "out.json", stub) is None  # it imported the stub: failed

    env = {**os.environ, TREE_VARIABLE: str(stub)}
    env.pop("PYTHONPATH", None)
    checked = subprocess.run(
        [sys.executable, "-m", "pytest", str(ROOT / "benchmarks"), "--collect-only", "-q",
         "-p", "no:cacheprovider", "-p", "no:xdist"],
        cwd=ROOT, env=env, capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert checked.returncode == 2
    assert f"asked to time {stub}" in checked.stdout + checked.stderr


def test_row_files_that_do_not_import_on_the_reference_are_found(tmp_path):
    """A new row on a new helper: its file does not import on an older reference, so the
    comparison leaves it out of that run (and says so) instead of failing the whole run."""
    from benchmarks.compare_with_main import unimportable

    tree = tmp_path / "older"
    (tree / "stt_drake").mkdir(parents=True)
    (tree / "stt_drake" / "__init__.py").write_text("HELPER = 1\n")
    rows = tree / "benchmarks"
    rows.mkdir()
    (rows / "__init__.py").write_text("")
    (rows / "test_old_row.py").write_text("from stt_drake import HELPER\n")
    (rows / "test_new_row.py").write_text("from stt_drake import NEW_HELPER\n")
    assert unimportable(tree) == [rows / "test_new_row.py"]
