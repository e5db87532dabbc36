"""The loop of a client that follows the fleet until told to stop (fleet-record, fleet-map).

Messages arrive on zenoh's threads into a queue; this loop hands them, in order, to one handler
on the main thread, shows a progress line (rewritten every second on a terminal, a new line
every five seconds otherwise, e.g. in a log), and ends at Ctrl-C, SIGTERM or a wall-clock
duration. With :class:`UpToStop`, what the fleet sent before that moment is still taken in.
"""

from __future__ import annotations

import queue
import signal
import sys
import threading
import time
from collections.abc import Callable
from types import FrameType
from typing import Any, TypeVar

from clients.tick_merge import is_reset, stamp_ns
from fleetcommon.signals import SignalEvent
from protocol import FleetError
from protocol.messages import FleetOdometry, FleetScans, Time

T = TypeVar("T")

#: after a stop, the longest a follower waits for messages that were sent before it (wall s,
#: the follower's own work on what comes not counted)
CATCH_UP_S = 5.0
#: once the stop's tick of odometry has come, this long without a message means nothing more is
#: on its way (a lockstep or paused daemon sends nothing after its last tick); also how long
#: messages are still taken after the first scan past the stop (the other daemons' scans of a
#: shared fleet, each daemon's in order of its own)
QUIET_S = 0.3
#: ... and this long before it has come (a fleet with no robot sends no odometry at all)
QUIET_NO_ODOMETRY_S = 1.0


class UpToStop:
    """Ctrl-C keeps what the fleet sent until that moment, however far behind the follower is.

    At the stop, the daemon's clock is the limit: messages stamped up to it that are still on
    their way are waited for, and later ones left out. Zenoh sends a tick's odometry before its
    scans, and the scans at a lower priority, so under load scans trail the odometry: two
    mappers stopped 0.2 s after a lockstep drive ended, on a loaded machine, drew different
    maps. The wait ends ``QUIET_S`` after the odometry of the limit's tick and a scan stamped
    after it have come (one daemon's scans come in order: none older is still on its way), when
    nothing has come for ``QUIET_S`` (``QUIET_NO_ODOMETRY_S`` before that tick's odometry), or
    after ``CATCH_UP_S``; ``ended`` says which.

    Seeing every message in order, it also counts the ticks whose odometry never came
    (``missed_ticks``, with the daemon's ``tick_s``): zenoh drops what a follower too slow for
    the fleet cannot take, and a map or a bag with holes should say so.
    """

    def __init__(
        self,
        clock: Callable[[], Time],
        odometry: bool = True,
        scans: bool = True,
        tick_s: float = 0.0,
        hurry: threading.Event | None = None,
    ) -> None:
        self._clock = clock
        self.hurry = hurry or threading.Event()  # set: stop taking anything more (a second Ctrl-C)
        self._odometry, self._scans = odometry, scans
        self._tick_s = tick_s
        self.missed_ticks = 0
        # stamps in nanoseconds (clients/tick_merge.py's stamp_ns)
        self.limit: int | None = None
        self.newest_odometry = -1
        self.newest_scans = -1
        self.left_out = 0  # messages stamped after the limit
        self.ended = ""  # "complete", "quiet", "cap", "no daemon" or "hurried", once caught up

    def keep(self, msg: Any) -> bool:
        """Notes ``msg``'s stamp; whether to take it (not when stamped after the limit)."""
        if isinstance(msg, FleetOdometry):
            stamp = stamp_ns(msg.stamp)
            if self._tick_s > 0 and stamp > self.newest_odometry >= 0:
                self.missed_ticks += max(0, round((stamp - self.newest_odometry) * 1e-9 / self._tick_s) - 1)
            self.newest_odometry = _newer(self.newest_odometry, stamp)
        elif isinstance(msg, FleetScans):
            stamp = stamp_ns(msg.stamp)
            self.newest_scans = _newer(self.newest_scans, stamp)
        else:
            return True
        if self.limit is not None and stamp > self.limit:
            self.left_out += 1
            return False
        return True

    def odometry_in(self) -> bool:
        assert self.limit is not None
        return not self._odometry or self.newest_odometry >= self.limit

    def complete(self) -> bool:
        return self.odometry_in() and (not self._scans or self.newest_scans > (self.limit or 0))

    def catch_up(self, inbox: queue.Queue[T], handle: Callable[[T], None]) -> None:
        """Take what comes up to the daemon's clock now (nothing more when no daemon answers)."""
        try:
            now = self._clock()
        except FleetError:
            self.ended = "no daemon"
            return
        self.limit = stamp_ns(now)
        start = last = time.monotonic()
        handling = 0.0  # the follower's own work does not count against the wait
        completed: float | None = None
        while True:
            if self.hurry.is_set():
                self.ended = "hurried"
                return
            t = time.monotonic()
            if completed is None and self.complete():
                completed = t
            if completed is not None and t - completed >= QUIET_S:
                self.ended = "complete"
                return
            if t - start - handling >= CATCH_UP_S:
                self.ended = "cap"
                return
            if t - last >= (QUIET_S if self.odometry_in() else QUIET_NO_ODOMETRY_S):
                self.ended = "quiet"
                return
            try:
                msg = inbox.get(timeout=0.05)
            except queue.Empty:
                continue
            got = time.monotonic()
            if self.keep(msg):
                handle(msg)
            last = time.monotonic()
            handling += last - got

    def report(self, tool: str, queued: int) -> list[str]:
        """The stderr lines a follower prints after its stop (``queued``: messages received and
        not handled): what a second stop left out, a wait that hit its cap, ticks that never came."""
        lines = []
        if self.hurry.is_set():
            lines.append(f"{tool}: a second stop: {queued} messages received were left out")
        if self.ended == "cap":
            lines.append(f"{tool}: stopped waiting for the messages sent before the stop after {CATCH_UP_S:g} s")
        if self.missed_ticks:
            lines.append(f"{tool}: {self.missed_ticks} ticks of the fleet's odometry did not come (lost on the way "
                         "to a follower too slow for the fleet, or stepped without publishing)")  # fmt: skip
        return lines


def _newer(newest: int, stamp: int) -> int:
    """The newest stamp of a stream, which starts again from a stamp a reset took back."""
    return stamp if stamp > newest or is_reset(newest, stamp) else newest


class Stop(SignalEvent):
    """Set at the first SIGINT or SIGTERM: the loop ends cleanly and the output is written.
    ``hurry`` is set at the second: what is still on its way or queued is not waited for (a
    follower far behind the fleet may have minutes of work queued). Both are set without a
    lock from the handler (fleetcommon/signals.py)."""

    def __init__(self) -> None:
        super().__init__()
        self.hurry = SignalEvent()


def stop_on_signals() -> Stop:
    """A :class:`Stop` that SIGINT and SIGTERM set."""
    stop = Stop()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        if stop.is_set():
            stop.hurry.set_from_signal()
        stop.set_from_signal()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    return stop


def follow(
    inbox: queue.Queue[T],
    handle: Callable[[T], None],
    stop: threading.Event,
    duration: float,
    progress: Callable[[float], str],
    every_loop: Callable[[], None] | None = None,
    up_to_stop: UpToStop | None = None,
    on_stop: Callable[[], None] | None = None,
) -> float:
    """Handle messages until ``stop`` or ``duration`` wall seconds (0: no limit); returns the time
    taken. ``every_loop`` runs at least ten times a second (a controller's hook), ``on_stop``
    once at the end (a controller stops its robots). With ``up_to_stop``, the messages the fleet
    sent before the end are then waited for and handled too."""
    keep = up_to_stop.keep if up_to_stop is not None else None
    t0 = time.monotonic()
    tty = sys.stderr.isatty()
    every = 1.0 if tty else 5.0
    next_report = t0 + every
    while not stop.is_set():
        now = time.monotonic()
        if duration and now - t0 >= duration:
            break
        try:
            msg = inbox.get(timeout=0.1)
        except queue.Empty:
            pass
        else:
            if keep is None or keep(msg):
                handle(msg)
        if every_loop is not None:
            every_loop()
        if now >= next_report:
            line = progress(now - t0)
            print(("\r" + line) if tty else line, end="" if tty else "\n", file=sys.stderr, flush=True)
            next_report = now + every
    if tty:
        print(file=sys.stderr)
    if on_stop is not None:
        on_stop()
    if up_to_stop is not None:
        up_to_stop.catch_up(inbox, handle)
    return time.monotonic() - t0


def drain(inbox: queue.Queue[T], handle: Callable[[T], None], up_to_stop: UpToStop | None = None) -> None:
    """Handle what arrived before the input was closed (up to the stop's limit, if any; nothing
    more once ``up_to_stop.hurry`` is set)."""
    while up_to_stop is None or not up_to_stop.hurry.is_set():
        try:
            msg = inbox.get_nowait()
        except queue.Empty:
            return
        if up_to_stop is None or up_to_stop.keep(msg):
            handle(msg)
