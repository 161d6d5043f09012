"""Receiving over LCM with fault handling: :class:`FilteredSubscriber`.

Drake's ``LcmSubscriberSystem`` keeps the newest message it received. A robot link needs
more: every message is checked against the newest one accepted (by its `utime`, the first
field of every message here and of Drake's ``lcmt_panda_*``), a duplicate (same utime) or
an out-of-order message (older utime) is dropped and counted, and a link that delivers
nothing new for `stale_timeout` seconds is *stale*: the subscriber calls its `on_stale`
action (the controller's safe command) and raises :class:`StaleLinkError`, which ends the
run with that reason. How old the newest status is at each tick (its *age*) is measured on
a :class:`LinkClock` both ends share.
"""

from __future__ import annotations

import math
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.lcm import DrakeLcmInterface
from pydrake.systems.framework import BasicVector, Context, LeafSystem, State
from pydrake.systems.lcm import SerializerInterface

#: The `link` output of a :class:`FilteredSubscriber`, in order: the silences longer than
#: the stale timeout (a link that stops at the first: 1.0 once stale), the newest accepted
#: message's age (s), the messages accepted, the duplicates and the out-of-order messages
#: dropped, and the newest accepted utime (µs; −1 before any).
LINK_FIELDS = ("stale", "age_s", "accepted", "duplicates", "out_of_order", "newest_utime")

#: Bytes of an LCM message before its first field (the type's fingerprint).
_FINGERPRINT_BYTES = 8


def message_utime(raw: bytes) -> int:
    """The utime of an encoded LCM message whose first field is ``int64_t utime``."""
    return struct.unpack_from(">q", raw, _FINGERPRINT_BYTES)[0]


def cpp_serializer(lcm_type: type) -> SerializerInterface:
    """Drake's C++ serializer of a Drake message type (what ``LcmSubscriberSystem.Make(...,
    use_cpp_serializer=True)`` uses), for systems such as the Panda senders and receivers
    whose ports hold the C++ message."""
    from pydrake.systems import lcm as systems_lcm

    return systems_lcm._Serializer_[lcm_type]()


class StaleLinkError(RuntimeError):
    """A link delivered no new message for its stale timeout."""


@dataclass
class LinkClock:
    """The clock a link's utime is read on. In one Simulator both ends share its time
    (`wall` False). Between processes both stamp and read the wall clock (`wall` True:
    ``time.time()``), so on one host (or hosts with synchronised clocks) the receiver's
    age of a message is its true age, transport and pacing included; `epoch`, the wall
    time of this end's t = 0 (time.time() − t at the first reading), aligns the two
    processes' logs (:func:`stt_drake.robot.session.merge_logs`)."""

    wall: bool = False
    epoch: float | None = None

    def now(self, t: float) -> float:
        """The link time (s) at this end's Simulator time `t`."""
        if not self.wall:
            return t
        now = time.time()
        if self.epoch is None:
            self.epoch = now - t
        return now

    def idle(self) -> float:
        """The link time before this end's Simulator starts (its announcements): the wall
        clock, or 0."""
        return time.time() if self.wall else 0.0

    def to_link(self, times: np.ndarray, t: float) -> np.ndarray:
        """This end's times (s; e.g. a sensor's stamps) on the link clock, read at this
        end's time `t` (identity in one Simulator)."""
        if not self.wall:
            return times
        self.now(t)
        return times + self.epoch

    def from_link(self, times: np.ndarray, t: float) -> np.ndarray:
        """Link-clock times as this end's times, read at this end's time `t`, none later
        than `t` (the two processes' clocks are aligned only within the start-up
        handshake; identity in one Simulator)."""
        if not self.wall:
            return times
        self.now(t)
        return np.minimum(times - self.epoch, t)


@dataclass
class LinkStatistics:
    """What a :class:`FilteredSubscriber` saw: the newest status's age at every tick (s)
    and the counters."""

    ages: list[float] = field(default_factory=list)

    def summary(self, link: np.ndarray) -> dict[str, Any]:
        """p50/p99/max of the ages and the counters of a final `link` vector."""
        values = dict(zip(LINK_FIELDS, np.asarray(link, dtype=float), strict=True))
        return {
            "age_s": percentiles(self.ages),
            "accepted": int(values["accepted"]),
            "duplicates_dropped": int(values["duplicates"]),
            "out_of_order_dropped": int(values["out_of_order"]),
            "silences": int(values["stale"]),
        }


def percentiles(values: list[float]) -> dict[str, float | None]:
    """p50, p99 and max of `values` (None for none)."""
    if not values:
        return {"p50": None, "p99": None, "max": None}
    array = np.asarray(values, dtype=float)
    p50, p99 = np.percentile(array, [50.0, 99.0])
    return {"p50": float(p50), "p99": float(p99), "max": float(array.max())}


class TickTimer(LeafSystem):
    """A pass-through of a vector `u` (input `u`, output `y`) that times, in wall-clock
    seconds, each evaluation of its input: put after the controller, it measures one
    controller tick (the tube's output, the control law) each time the command is
    published."""

    def __init__(self, size: int) -> None:
        super().__init__()
        self.ticks: list[float] = []
        self._input = self.DeclareVectorInputPort("u", size)
        self.DeclareVectorOutputPort("y", size, self._calc)

    def _calc(self, context: Context, output: BasicVector) -> None:
        start = time.perf_counter()
        value = self._input.Eval(context)
        self.ticks.append(time.perf_counter() - start)
        output.SetFromVector(value)


class FilteredSubscriber(LeafSystem):
    """Subscribes to `channel` on `lcm` and, every `period` seconds (the tick, from `offset`),
    pumps the bus and drains what arrived: a message with a utime above the newest
    accepted one is accepted (the newest of them is kept), any other is dropped and
    counted as a duplicate (same utime) or out of order (older).

    Outputs `message`, the newest accepted message decoded by `serializer` (the encoded
    `default` before any: the value the other end starts from), and `link` (:data:`LINK_FIELDS`).
    Without a new message for more than `stale_timeout` seconds (counted from t = 0
    before the first) the tick calls `on_stale` (with the time) and raises :class:`StaleLinkError`;
    with `stop_when_stale` False it only counts the silence (a link whose silence is
    handled downstream, e.g. detections, whose tracker loses its tracks).
    With `startup_timeout` > 0 the initialization waits up to that many wall-clock
    seconds for a first message (the other process may start later), calling `announce`
    (e.g. publishing this end's initial status) every 0.1 s meanwhile, and raises
    :class:`StaleLinkError` if none came.
    """

    def __init__(
        self,
        channel: str,
        serializer: SerializerInterface,
        lcm: DrakeLcmInterface,
        period: float,
        stale_timeout: float,
        *,
        clock: LinkClock,
        default: bytes = b"",
        startup_timeout: float = 0.0,
        offset: float = 0.0,
        stop_when_stale: bool = True,
        on_stale: Callable[[float], None] | None = None,
        announce: Callable[[], None] | None = None,
    ) -> None:
        super().__init__()
        self._channel, self._lcm, self._serializer = channel, lcm, serializer
        self._timeout, self._clock, self._on_stale = stale_timeout, clock, on_stale
        self._startup_timeout, self._announce = startup_timeout, announce
        self._stop_when_stale = stop_when_stale
        self._inbox: list[bytes] = []
        self.statistics = LinkStatistics()
        lcm.Subscribe(channel, self._inbox.append)
        self._model = serializer.CreateDefaultValue()
        if default:
            serializer.Deserialize(default, self._model)
        self._raw = self.DeclareAbstractState(AbstractValue.Make(b""))
        # [newest utime (µs), tick of its acceptance (s), accepted, duplicates, out of order,
        #  age (s), silences, 1.0 while silent past the timeout]
        self._counts = self.DeclareDiscreteState(np.array([-1.0, 0.0, 0, 0, 0, 0.0, 0.0, 0.0]))
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, offset, self._drain)
        if startup_timeout > 0.0:
            self.DeclareInitializationUnrestrictedUpdateEvent(self._wait_for_first)
        self.DeclareAbstractOutputPort("message", self._model.Clone, self._calc_message)
        self.DeclareVectorOutputPort("link", len(LINK_FIELDS), self._calc_link)

    @property
    def channel(self) -> str:
        return self._channel

    @property
    def clock(self) -> LinkClock:
        return self._clock

    def _wait_for_first(self, context: Context, state: State) -> None:
        deadline = time.monotonic() + self._startup_timeout
        while not self._inbox and time.monotonic() < deadline:
            if self._announce is not None:
                self._announce()
            self._lcm.HandleSubscriptions(100)
        if not self._inbox:
            raise StaleLinkError(
                f"no {self._channel} message within the startup timeout of "
                f"{self._startup_timeout:g} s (is the other process running on this bus?)"
            )
        self._drain(context, state)

    def _drain(self, context: Context, state: State) -> None:
        self._lcm.HandleSubscriptions(0)
        t = context.get_time()
        counts = np.array(context.get_discrete_state(self._counts).get_value())
        newest, raw = counts[0], None
        for message in self._inbox:
            utime = message_utime(message)
            if utime > newest:
                newest, raw = utime, message
                counts[2] += 1
            else:
                counts[3 if utime == newest else 4] += 1
        self._inbox.clear()
        if raw is not None:
            counts[0], counts[1] = newest, t
            state.get_mutable_abstract_state(self._raw).set_value(raw)
        if counts[0] >= 0.0:
            counts[5] = self._clock.now(t) - counts[0] * 1e-6
            self.statistics.ages.append(float(counts[5]))
        silent = t - counts[1]
        if silent <= self._timeout:
            counts[7] = 0.0
        elif not self._stop_when_stale:
            counts[6] += 1.0 - counts[7]  # one count per silence
            counts[7] = 1.0
        else:
            if self._on_stale is not None:
                self._on_stale(t)
            raise StaleLinkError(
                f"stale link: no new {self._channel} message for {silent:.3f} s "
                f"(stale_timeout {self._timeout:g} s); the safe command was sent"
            )
        state.get_mutable_discrete_state(self._counts).set_value(counts)

    def _calc_message(self, context: Context, value: AbstractValue) -> None:
        raw = context.get_abstract_state(self._raw).get_value()
        if raw:
            self._serializer.Deserialize(raw, value)
        else:
            value.SetFrom(self._model)

    def _calc_link(self, context: Context, output: BasicVector) -> None:
        counts = context.get_discrete_state(self._counts).get_value()
        age = counts[5] if counts[0] >= 0.0 else math.nan
        output.SetFromVector([counts[6], age, counts[2], counts[3], counts[4], counts[0]])
