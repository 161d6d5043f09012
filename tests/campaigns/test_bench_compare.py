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
