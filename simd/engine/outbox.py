"""A thread of an adapter's own, so that encoding and sending overlap the next tick.

The engine calls adapters on the simulation thread, which must go on at once; an adapter
hands its work to an :class:`Outbox` instead. Work keeps the engine's order (a spawn's reply
after the robot's first message, a step's after its last tick), and the queue of tick data is
short, so an adapter that falls behind slows the simulation down instead of piling up ticks.

Ticks cost the most to send: a tick of 8 000 robots whose topics somebody follows takes the
outbox a few hundred ms, longer than a user waits for an answer. So the data lane is bounded
in time as well as in items (``has_room`` says no once the queued ticks would take the outbox
more than ``QUEUED_S``: then the simulation runs at the outbox's pace, one tick ahead), and what
needs no tick data before it does not queue at all.

``put`` is the data lane: ticks, and what must follow them (a reset's reply must not be followed
by the old world's ticks). ``put_urgent`` runs the work at once on the
caller's thread: replies and messages that depend on no tick data (a refusal, the clock, a
pause's answer, a deleted robot's undeclaring, which the ticks queued before it then leave out).
``put_ordered`` is for what must stay behind an earlier data-lane item of the same key but not
behind ticks (a spawned robot's first odometry, then the spawn's reply): at once, unless such an
item still waits in the data lane; then behind it.
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from collections.abc import Callable

log = logging.getLogger(__name__)

#: Ticks (and the work queued with them) waiting for the outbox thread before the simulation
#: waits: two scan periods, so that the simulation runs on while the outbox waits for a batch of
#: scans (100 robots at --rtf 0, fleet topics: RTF 155-162 with 3, 168-190 with 12, no better with 30).
OUTBOX_DEPTH = 12
#: What the queued ticks may take the outbox to send (from what the last ones took) before the
#: simulation waits: a delete's reply waits behind about this much.
QUEUED_S = 0.05
#: Weight of the newest item in the moving average of what a data item takes to send.
ALPHA = 0.2

Work = Callable[[], object]


class Outbox:
    """One thread that runs the data lane in order (``put`` blocks while it is full); urgent
    and ordered work runs at once where nothing it depends on waits (the module docstring)."""

    def __init__(self, name: str, depth: int = OUTBOX_DEPTH, on_room: Callable[[], None] | None = None) -> None:
        """``on_room``: called (on this outbox's thread) whenever an item has run and there is room."""
        self._depth = depth
        self._on_room = on_room
        self._cond = threading.Condition()
        self._data: collections.deque[tuple[Work | None, str | None]] = collections.deque()  # (work, key)
        self._unfinished = 0
        self._waiting_keys: collections.Counter[str] = collections.Counter()  # keyed items not yet run
        self._item_s = 0.0  # what a data item takes to send (moving average)
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def put(self, work: Work, key: str | None = None, wait: bool = True) -> None:
        """Queue ``work`` in the data lane; ``key``: later ordered work of that key waits for it.
        Blocks while the lane is full, unless not ``wait`` (an event between ticks: the engine
        asks ``has_room`` before each tick, and must not stop in the middle of a request)."""
        with self._cond:
            while wait and len(self._data) >= self._depth:
                self._cond.wait()
            self._data.append((work, key))
            self._unfinished += 1
            if key is not None:
                self._waiting_keys[key] += 1
            self._cond.notify_all()

    def put_urgent(self, work: Work) -> None:
        """Run ``work`` now, on this thread (it depends on nothing queued)."""
        _run_one(work)

    def put_ordered(self, work: Work, key: str) -> None:
        """Run ``work`` now, unless an item of ``key`` waits in the data lane: then behind it."""
        with self._cond:
            behind = self._waiting_keys[key] > 0
        if behind:
            self.put(work, key, wait=False)
        else:
            _run_one(work)

    def has_room(self) -> bool:
        """Whether a tick put now would not make the queue longer than it should be (in items,
        and in the time the queued items would take to send)."""
        n = len(self._data)
        return n == 0 or (n < self._depth and n * self._item_s < QUEUED_S)

    def idle(self) -> bool:
        """Whether everything put so far has run: then work done on the caller's thread
        instead keeps the order (a lockstep reply need not wait for this thread to wake)."""
        return self._unfinished == 0

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._data:
                    self._cond.wait()
                work, key = self._data.popleft()
                self._cond.notify_all()  # room in the data lane
            if work is None:
                return
            t0 = time.perf_counter()
            _run_one(work)
            took = time.perf_counter() - t0
            with self._cond:
                self._item_s += ALPHA * (took - self._item_s)
                self._unfinished -= 1
                if key is not None:
                    self._waiting_keys[key] -= 1
                    if not self._waiting_keys[key]:
                        del self._waiting_keys[key]
            if self._on_room is not None and self.has_room():
                self._on_room()

    def flush(self, timeout: float = 5.0) -> bool:
        """Wait until everything put so far has run (tests, and a clean shutdown)."""
        done = threading.Event()
        self.put(done.set)
        return done.wait(timeout)

    def close(self, timeout: float = 5.0) -> None:
        """Run what is queued, then stop."""
        with self._cond:
            self._data.append((None, None))
            self._cond.notify_all()
        self._thread.join(timeout)


def _run_one(work: Work) -> None:
    try:
        work()
    except Exception:  # a failed put or reply must not stop the ones after it
        log.exception("sending failed")
