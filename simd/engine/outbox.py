"""A thread of an adapter's own, so that encoding and sending overlap the next tick.

The engine calls adapters on the simulation thread, which must go on at once; an adapter
hands its work to an :class:`Outbox` instead. Work keeps the engine's order (a spawn's reply
after the robot's first message, a delete's after its last), and the queue of tick data is
short, so an adapter that falls behind slows the simulation down instead of piling up ticks.

Ticks cost the most to send: a tick of 20 000 robots whose topics somebody follows takes the
outbox longer than a user waits for an answer, and a dozen of them wait in the queue when the
simulation outruns it. So there are two lanes. ``put`` is the data lane: ticks, and whatever
must not pass them (a deleted robot's undeclaring: a tick queued before it still names the
robot). ``put_urgent`` is served first: replies and messages that depend on no tick data (a
refusal, the clock, a pause's answer). ``put_ordered`` is for what must keep its order with the
other events and replies but not with ticks (a spawned robot's first odometry, then the spawn's
reply): it goes urgent unless an ordered item is still waiting in the data lane, then it waits
behind that one.
"""

from __future__ import annotations

import collections
import logging
import threading
from collections.abc import Callable

log = logging.getLogger(__name__)

#: Ticks (and the work queued with them) waiting for the outbox thread before the simulation
#: waits: two scan periods, so that the simulation runs on while the outbox waits for a batch of
#: scans (100 robots at --rtf 0, fleet topics: RTF 155-162 with 3, 168-190 with 12, no better with 30).
OUTBOX_DEPTH = 12

Work = Callable[[], object]


class Outbox:
    """One thread that runs what it is given, urgent work first, each lane in order; ``put``
    blocks while the data lane is full (see the module docstring)."""

    def __init__(self, name: str, depth: int = OUTBOX_DEPTH) -> None:
        self._depth = depth
        self._cond = threading.Condition()
        self._data: collections.deque[tuple[Work | None, bool]] = collections.deque()  # (work, ordered)
        self._urgent: collections.deque[Work] = collections.deque()
        self._unfinished = 0
        self._ordered_waiting = 0  # ordered items put in the data lane that have not run yet
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def put(self, work: Work, ordered: bool = False) -> None:
        """Queue ``work`` in the data lane (``ordered``: later ordered work waits for it)."""
        self._put_data(work, ordered)

    def put_urgent(self, work: Work) -> None:
        """Queue ``work`` ahead of the data lane (it never blocks)."""
        with self._cond:
            self._urgent.append(work)
            self._unfinished += 1
            self._cond.notify_all()

    def put_ordered(self, work: Work) -> None:
        """Queue ``work`` after every ordered item before it, but ahead of tick data when it can."""
        with self._cond:
            if self._ordered_waiting == 0:
                self._urgent.append(work)
                self._unfinished += 1
                self._cond.notify_all()
                return
        self._put_data(work, True)

    def _put_data(self, work: Work | None, ordered: bool) -> None:
        with self._cond:
            while len(self._data) >= self._depth:
                self._cond.wait()
            self._data.append((work, ordered))
            self._unfinished += 1
            self._ordered_waiting += ordered
            self._cond.notify_all()

    def has_room(self) -> bool:
        """Whether ``put`` would queue at once instead of waiting."""
        return len(self._data) < self._depth

    def idle(self) -> bool:
        """Whether everything put so far has run: then work done on the caller's thread
        instead keeps the order (a lockstep reply need not wait for this thread to wake)."""
        return self._unfinished == 0

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._urgent and not self._data:
                    self._cond.wait()
                ordered = False
                if self._urgent:
                    work: Work | None = self._urgent.popleft()
                else:
                    work, ordered = self._data.popleft()
                self._cond.notify_all()  # room in the data lane
            if work is None:
                return
            try:
                work()
            except Exception:  # a failed put or reply must not stop the ones after it
                log.exception("sending failed")
            finally:
                with self._cond:
                    self._unfinished -= 1
                    self._ordered_waiting -= ordered

    def flush(self, timeout: float = 5.0) -> bool:
        """Wait until everything put so far has run (tests, and a clean shutdown)."""
        done = threading.Event()
        self.put(done.set)
        return done.wait(timeout)

    def close(self, timeout: float = 5.0) -> None:
        """Run what is queued, then stop."""
        self._put_data(None, False)
        self._thread.join(timeout)
