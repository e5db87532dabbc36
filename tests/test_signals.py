"""fleetcommon.signals.SignalEvent: set from a signal handler that interrupted the main thread
while it held the event's own lock (where ``Event.set()`` in the handler waits for ever)."""

from __future__ import annotations

import os
import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Any

from clients import wait_until
from fleetcommon.signals import SignalEvent


@contextmanager
def handled(signum: int, handler: Callable[[int, FrameType | None], Any]) -> Iterator[None]:
    before = signal.signal(signum, handler)
    try:
        yield
    finally:
        signal.signal(signum, before)


def test_a_handler_sets_the_event_while_the_interrupted_thread_holds_its_lock() -> None:
    event = SignalEvent()
    woken = threading.Event()

    def wait() -> None:
        if event.wait(10.0):
            woken.set()

    waiter = threading.Thread(target=wait, daemon=True)
    waiter.start()
    cond: Any = event._cond  # type: ignore[attr-defined]  # (threading.Event's, private)
    assert wait_until(lambda: bool(cond._waiters), 5.0)  # the waiter is inside wait()
    with handled(signal.SIGUSR1, lambda signum, frame: event.set_from_signal()):
        with cond:  # as inside Event.wait on the main thread, when the signal lands
            os.kill(os.getpid(), signal.SIGUSR1)
            assert wait_until(lambda: event._signalled, 5.0)  # the handler ran, and returned
            assert event.is_set() and event.wait(0.0)  # seen at once, the lock still held here
            assert not woken.is_set()  # the waiters are woken once the lock is free
        assert woken.wait(5.0)
    waiter.join(5.0)
    assert event.is_set()
    event.clear()
    assert not event.is_set() and not event.wait(0.0)


def test_it_is_an_event_otherwise() -> None:
    event = SignalEvent()
    assert not event.is_set() and not event.wait(0.01)
    event.set()
    assert event.is_set() and event.wait()
    event.clear()
    assert not event.is_set()


def test_cleared_before_its_waiters_are_woken_it_stays_clear() -> None:
    first, second = SignalEvent(), SignalEvent()
    first.set_from_signal()
    first.clear()
    second.set_from_signal()
    assert wait_until(lambda: threading.Event.is_set(second), 5.0)  # the waker got to it: first is done
    assert not first.is_set() and not first.wait(0.0)
