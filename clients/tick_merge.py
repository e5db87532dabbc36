"""One tick of the fleet's odometry as one message, however many daemons share the fleet.

A daemon puts one ``P/odometry`` message a tick with the rows of its own robots. Alone, that
is the whole fleet; in a fleet shared by several daemons (``simd --join``) each puts its part
with the same stamp, a few milliseconds apart. A follower of the whole fleet wants what one
daemon gives: one message a tick with every robot. :class:`TickMerge` gathers the parts of a
stamp and hands them on as one message once every live daemon's part is in. A part may never
come (a daemon with no robots puts none; a daemon that just died): a tick still waiting when
``hold`` later ticks have begun, or when a later tick is whole, is handed on with the parts it
has, so nothing waits long and no row is dropped. A part that comes after its tick went is
handed on alone; a stamp far older than the last one handed on is a reset, and starts over.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from protocol.messages import FLEET_ODOM_COLUMNS, FleetOdometry, Time

#: later ticks begun before a tick still missing a part is handed on without it
HOLD_TICKS = 3
#: a part this much older than the newest tick handed on is a new run (a reset), not a late part
RESET_SECONDS = 1.0


def _key(stamp: Time) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


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
        self, expected: Callable[[], int], emit: Callable[[FleetOdometry], None], hold: int = HOLD_TICKS
    ) -> None:
        self._expected = expected
        self._emit = emit
        self._hold = hold
        self._lock = threading.Lock()
        self._pending: dict[int, list[FleetOdometry]] = {}
        self._last: int | None = None  # the newest tick handed on

    def add(self, part: FleetOdometry) -> None:
        key = _key(part.stamp)
        with self._lock:
            out = self._take(key, part)
        for msg in out:
            self._emit(msg)

    def _take(self, key: int, part: FleetOdometry) -> list[FleetOdometry]:
        """What is ready to hand on once ``part`` is in (called under the lock)."""
        if self._last is not None and key <= self._last:
            if self._last - key < RESET_SECONDS * 1e9:
                return [part]  # a late part of a tick already handed on: alone, not lost
            self._pending.clear()  # the clock went back: a reset
            self._last = None
        parts = self._pending.setdefault(key, [])
        parts.append(part)
        out: list[FleetOdometry] = []
        if len(parts) >= max(1, self._expected()):  # whole: it and every older tick go
            for k in sorted(k for k in self._pending if k <= key):
                out.append(merge(self._pending.pop(k)))
            self._last = key
        while len(self._pending) > self._hold:  # a part that is not coming: the oldest goes as it is
            oldest = min(self._pending)
            out.append(merge(self._pending.pop(oldest)))
            self._last = oldest
        return out
