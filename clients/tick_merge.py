"""One tick of the fleet's odometry as one message, however many daemons share the fleet.

A daemon puts one ``P/odometry`` message a tick with the rows of its own robots. Alone, that
is the whole fleet; in a fleet shared by several daemons (``simd --join``) each puts its part
with the same stamp, a few milliseconds apart. A follower of the whole fleet wants what one
daemon gives: one message a tick with every robot. :class:`TickMerge` gathers the parts of a
stamp and hands them on as one message once every live daemon's part is in. A part may never
come (a daemon with no robots puts none; a daemon that just died): a tick still waiting once
``hold`` later ticks have begun and it has waited ``hold_s`` of wall time, or when a later tick
is whole, is handed on with the parts it has, so nothing waits long and no row is dropped (with
``flush_after``, a timer hands on what waited ``hold_s`` when no more parts come). Both
conditions, because a stepped fleet runs ticks far faster than real time: three ticks were a
fraction of a millisecond there, less than one daemon's part may lag another's through a
router, and a tick then came out in two messages. A part that comes after its tick went is
handed on alone; a stamp far older than the last one handed on is a reset, and starts over.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from protocol.messages import FLEET_ODOM_COLUMNS, FleetOdometry, Time

#: later ticks begun before a tick still missing a part is handed on without it
HOLD_TICKS = 3
#: ... and the wall time it has waited (three ticks in real time)
HOLD_S = 0.1
#: a part this much older than the newest tick handed on is a new run (a reset), not a late part
RESET_SECONDS = 1.0


def stamp_ns(stamp: Time) -> int:
    """A stamp as one integer of nanoseconds (keys and differences without rounding)."""
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def is_reset(newest_ns: int, stamp_ns: int) -> bool:
    """Whether a stamp this far behind the newest one starts a new run (the daemon was reset)
    rather than being a late part of the ones already seen."""
    return newest_ns - stamp_ns >= RESET_SECONDS * 1e9


def merge(parts: list[FleetOdometry]) -> FleetOdometry:
    """The parts of one tick as one message, rows in the order the parts came."""
    if len(parts) == 1:
        return parts[0]
    columns = {c: b"".join(getattr(p, c) for p in parts) for c in FLEET_ODOM_COLUMNS}
    return FleetOdometry(stamp=parts[0].stamp, namespaces=[ns for p in parts for ns in p.namespaces], **columns)


class TickMerge:
    """Gathers the daemons' parts of each tick; ``emit`` gets one message a tick, in stamp order.

    ``expected()`` says how many daemons serve the fleet now (their liveliness tokens); until
    the first is known, one part makes a tick.
    """

    def __init__(
        self,
        expected: Callable[[], int],
        emit: Callable[[FleetOdometry], None],
        hold: int = HOLD_TICKS,
        hold_s: float = HOLD_S,
        clock: Callable[[], float] = time.monotonic,
        flush_after: bool = False,
    ) -> None:
        self._expected = expected
        self._emit = emit
        self._hold = hold
        self._hold_s = hold_s
        self._clock = clock
        self._flush_after = flush_after
        # reentrant: a callback may end its subscription (undeclare) while it is handed a tick
        self._lock = threading.RLock()
        self._closed = False
        self._pending: dict[int, list[FleetOdometry]] = {}
        self._since: dict[int, float] = {}  # when each pending tick's first part came
        self._last: int | None = None  # the newest tick handed on
        self._timer: threading.Timer | None = None

    def add(self, part: FleetOdometry) -> None:
        key = stamp_ns(part.stamp)
        with self._lock:  # held while handing on: the timer's thread hands on too, in order
            self._hand_on([] if self._closed else self._take(key, part))

    def flush(self) -> None:
        """Hand on the ticks that have waited ``hold_s`` with the parts they have (oldest first;
        the timer of ``flush_after`` calls this)."""
        with self._lock:
            self._timer = None
            self._hand_on([] if self._closed else self._overdue(0))

    def _hand_on(self, out: list[FleetOdometry]) -> None:
        """Emit, then time the oldest tick still waiting (under the lock)."""
        for msg in out:
            self._emit(msg)
        self._arm()

    def undeclare(self) -> None:
        """Stop: nothing more is handed on (a subscription that ends ends its merge too)."""
        with self._lock:
            self._closed = True
            if self._timer is not None:
                self._timer.cancel()
                self._timer = None

    def _arm(self) -> None:
        """With ``flush_after``: a timer for the oldest tick still waiting (under the lock)."""
        if not self._flush_after or self._closed or self._timer is not None or not self._pending:
            return
        wait = self._since[min(self._pending)] + self._hold_s - self._clock()
        self._timer = threading.Timer(max(wait, 0.0) + 0.001, self.flush)
        self._timer.daemon = True
        self._timer.start()

    def _overdue(self, keep: int) -> list[FleetOdometry]:
        """The oldest pending ticks, while more than ``keep`` wait and the oldest has waited
        ``hold_s`` (under the lock)."""
        out: list[FleetOdometry] = []
        now = self._clock()
        while len(self._pending) > keep:
            oldest = min(self._pending)
            if now - self._since[oldest] < self._hold_s:
                break
            out.append(merge(self._pending.pop(oldest)))
            del self._since[oldest]
            self._last = oldest
        return out

    def _take(self, key: int, part: FleetOdometry) -> list[FleetOdometry]:
        """What is ready to hand on once ``part`` is in (called under the lock)."""
        if self._last is not None and key <= self._last:
            if not is_reset(self._last, key):
                return [part]  # a late part of a tick already handed on: alone, not lost
            self._pending.clear()  # the clock went back: a reset
            self._since.clear()
            self._last = None
        if key not in self._pending:
            self._since[key] = self._clock()
        parts = self._pending.setdefault(key, [])
        parts.append(part)
        out: list[FleetOdometry] = []
        if len(parts) >= max(1, self._expected()):  # whole: it and every older tick go
            for k in sorted(k for k in self._pending if k <= key):
                out.append(merge(self._pending.pop(k)))
                del self._since[k]
            self._last = key
        out += self._overdue(self._hold)  # a part that is not coming: the oldest go as they are
        return out
