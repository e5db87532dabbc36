"""The loop of a client that follows the fleet until told to stop (fleet-record, fleet-map).

Messages arrive on zenoh's threads into a queue; this loop hands them, in order, to one handler
on the main thread, shows a progress line (rewritten every second on a terminal, a new line
every five seconds otherwise, e.g. in a log), and ends at Ctrl-C, SIGTERM or a wall-clock
duration.
"""

from __future__ import annotations

import queue
import signal
import sys
import threading
import time
from collections.abc import Callable
from types import FrameType
from typing import TypeVar

T = TypeVar("T")


def stop_on_signals() -> threading.Event:
    """An event that SIGINT and SIGTERM set (the loop ends cleanly, and the output is written)."""
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

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
) -> float:
    """Handle messages until ``stop`` or ``duration`` wall seconds (0: no limit); returns the time
    taken. ``every_loop`` runs at least ten times a second (a controller's hook)."""
    t0 = time.monotonic()
    tty = sys.stderr.isatty()
    every = 1.0 if tty else 5.0
    next_report = t0 + every
    while not stop.is_set():
        now = time.monotonic()
        if duration and now - t0 >= duration:
            break
        try:
            handle(inbox.get(timeout=0.1))
        except queue.Empty:
            pass
        if every_loop is not None:
            every_loop()
        if now >= next_report:
            line = progress(now - t0)
            print(("\r" + line) if tty else line, end="" if tty else "\n", file=sys.stderr, flush=True)
            next_report = now + every
    if tty:
        print(file=sys.stderr)
    return time.monotonic() - t0


def drain(inbox: queue.Queue[T], handle: Callable[[T], None]) -> None:
    """Handle what arrived before the input was closed."""
    while True:
        try:
            handle(inbox.get_nowait())
        except queue.Empty:
            return
