"""A thread of an adapter's own, so that encoding and sending overlap the next tick.

The engine calls adapters on the simulation thread, which must go on at once; an adapter
hands its work to an :class:`Outbox` instead. One queue keeps everything in the engine's
order (a spawn's reply after the robot's first message, a delete's after its last), and the
queue is short, so an adapter that falls behind slows the simulation down instead of
piling up ticks.
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable

log = logging.getLogger(__name__)

#: Ticks (and events, replies) waiting for the outbox thread before the simulation waits: two
#: scan periods, so that the simulation runs on while the outbox waits for a batch of scans
#: (100 robots at --rtf 0, fleet topics: RTF 155-162 with 3, 168-190 with 12, no better with 30).
OUTBOX_DEPTH = 12


class Outbox:
    """One thread that runs what it is given, in order; ``put`` blocks while it is full."""

    def __init__(self, name: str, depth: int = OUTBOX_DEPTH) -> None:
        self._queue: queue.Queue[Callable[[], object] | None] = queue.Queue(depth)
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def put(self, work: Callable[[], object]) -> None:
        self._queue.put(work)

    def idle(self) -> bool:
        """Whether everything put so far has run: then work done on the caller's thread
        instead keeps the order (a lockstep reply need not wait for this thread to wake)."""
        return self._queue.unfinished_tasks == 0

    def _run(self) -> None:
        while (work := self._queue.get()) is not None:
            try:
                work()
            except Exception:  # a failed put or reply must not stop the ones after it
                log.exception("sending failed")
            finally:
                self._queue.task_done()

    def flush(self, timeout: float = 5.0) -> bool:
        """Wait until everything put so far has run (tests, and a clean shutdown)."""
        done = threading.Event()
        self.put(done.set)
        return done.wait(timeout)

    def close(self, timeout: float = 5.0) -> None:
        """Run what is queued, then stop."""
        self._queue.put(None)
        self._thread.join(timeout)
