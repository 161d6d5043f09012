"""The link's fault handling: duplicates and out-of-order messages dropped and counted, a
stale link calls its safe action and raises StaleLinkError."""

from __future__ import annotations

import numpy as np
import pytest
from pydrake.lcm import DrakeLcm
from pydrake.systems.analysis import Simulator
from pydrake.systems.lcm import PySerializer

from stt_drake.robot.messages import state_message
from stt_drake.robot.stt_lcm import robot_state
from stt_drake.robot.transport import (
    LINK_FIELDS,
    FilteredSubscriber,
    LinkClock,
    StaleLinkError,
    percentiles,
)


def _subscriber(lcm, on_stale=None, stop_when_stale=True):
    return FilteredSubscriber(
        "STATUS",
        PySerializer(robot_state),
        lcm,
        0.01,
        0.05,
        clock=LinkClock(),
        default=state_message(0.0, np.zeros(2), np.zeros(2)).encode(),
        on_stale=on_stale,
        stop_when_stale=stop_when_stale,
    )


def _publish(lcm, t, value):
    lcm.Publish("STATUS", state_message(t, np.full(2, value), np.zeros(2)).encode(), None)


def test_duplicated_and_reordered_messages_are_dropped_and_counted():
    lcm = DrakeLcm("memq://")
    subscriber = _subscriber(lcm)
    simulator = Simulator(subscriber)
    context = simulator.get_mutable_context()
    simulator.Initialize()
    np.testing.assert_array_equal(subscriber.GetOutputPort("message").Eval(context).output, [0, 0])
    for t, value in ((0.004, 1.0), (0.004, 9.0), (0.002, 9.0), (0.008, 2.0)):  # dup, old
        _publish(lcm, t, value)
    simulator.AdvanceTo(0.005)  # the tick at 0 drained nothing; the next is at 0.01
    _publish(lcm, 0.006, 9.0)  # older than the newest accepted: out of order
    _publish(lcm, 0.009, 3.0)
    simulator.AdvanceTo(0.015)
    link = dict(zip(LINK_FIELDS, subscriber.GetOutputPort("link").Eval(context), strict=True))
    assert (link["accepted"], link["duplicates"], link["out_of_order"]) == (3, 1, 2)
    assert link["newest_utime"] == 9_000 and link["stale"] == 0.0
    assert link["age_s"] == pytest.approx(0.01 - 0.009)
    np.testing.assert_array_equal(subscriber.GetOutputPort("message").Eval(context).output, [3, 3])


def test_a_stale_link_sends_the_safe_command_and_stops():
    """No new message for longer than the stale timeout (a repeated one does not count):
    the safe action runs once with the time and the run ends with StaleLinkError."""
    lcm = DrakeLcm("memq://")
    calls = []
    subscriber = _subscriber(lcm, calls.append)
    simulator = Simulator(subscriber)
    simulator.Initialize()
    _publish(lcm, 0.0, 1.0)
    simulator.AdvanceTo(0.03)
    for _ in range(3):
        _publish(lcm, 0.0, 1.0)
    with pytest.raises(StaleLinkError, match=r"no new STATUS message for 0\.060 s"):
        simulator.AdvanceTo(1.0)
    assert calls == [pytest.approx(0.06)]
    assert subscriber.statistics.summary(np.array([1, 0, 1, 3, 0, 0]))["duplicates_dropped"] == 3


def test_percentiles():
    assert percentiles([]) == {"p50": None, "p99": None, "max": None}
    summary = percentiles(list(range(101)))
    assert (summary["p50"], summary["p99"], summary["max"]) == (50.0, 99.0, 100.0)


def test_a_link_that_does_not_stop_counts_each_silence_once():
    """stop_when_stale False (the detections): a silence longer than the timeout is
    counted once however long it lasts, and the run goes on."""
    lcm = DrakeLcm("memq://")
    subscriber = _subscriber(lcm, stop_when_stale=False)
    simulator = Simulator(subscriber)
    simulator.Initialize()
    for t in (0.0, 0.2, 0.25):  # silent 0–0.2 s (one silence), then in time
        simulator.AdvanceTo(t)
        _publish(lcm, t, 1.0)
    simulator.AdvanceTo(0.6)  # silent again from 0.26 s
    link = dict(
        zip(
            LINK_FIELDS, subscriber.GetOutputPort("link").Eval(simulator.get_context()), strict=True
        )
    )
    assert (link["stale"], link["accepted"]) == (2.0, 3.0)


def test_a_wall_clock_link_carries_stamps_on_the_link_clock():
    """Between processes, stamps go out on the link (wall) clock and come back on the
    receiver's, none later than its time; in one Simulator both are the identity."""
    stamps = np.array([0.5, -np.inf])
    assert LinkClock().to_link(stamps, 1.0) is stamps
    sender, receiver = LinkClock(wall=True), LinkClock(wall=True)
    sent = sender.to_link(stamps, 1.0)
    assert sent[0] == pytest.approx(sender.epoch + 0.5) and sent[1] == -np.inf
    back = receiver.from_link(sent, 2.0)
    assert back[0] == pytest.approx(0.5 + sender.epoch - receiver.epoch) and back[0] <= 2.0
    assert receiver.from_link(np.array([sender.epoch + 50.0]), 2.0)[0] == 2.0
