"""An event that a signal handler may set.

A Python signal handler runs on the main thread between two bytecodes, wherever that thread
is, possibly inside ``threading.Event.wait`` holding the event's own lock (a ``Lock``, not
re-entrant). An ``Event.set()`` in the handler then waits for that lock, which the interrupted
frame holds and can never release: the program hangs and ignores every later signal. simd
stopped that way once in the suite (simd/cli.py stops its engine from a thread since).

:class:`SignalEvent` is an ``Event`` whose :meth:`set_from_signal` takes no lock: it writes a
plain attribute (seen at once by :meth:`is_set` and :meth:`wait`, on any thread) and hands the
locked ``set()``, which wakes the waiters, to a thread started beforehand, through a
``queue.SimpleQueue``, whose ``put`` is documented as safe to call re-entrantly (from a signal
handler): the handler takes no lock the interrupted frame could hold.
"""

from __future__ import annotations

import queue
import threading

_to_wake: queue.SimpleQueue[SignalEvent] = queue.SimpleQueue()
_waker_started = threading.Lock()
_waker: threading.Thread | None = None


def _wake_forever() -> None:
    while True:
        _to_wake.get()._wake()


def _start_waker() -> None:
    """The thread that sets the events signalled (one per process, started outside handlers)."""
    global _waker
    with _waker_started:
        if _waker is None or not _waker.is_alive():
            _waker = threading.Thread(target=_wake_forever, name="signal-waker", daemon=True)
            _waker.start()


class SignalEvent(threading.Event):
    """A ``threading.Event`` that a signal handler sets with :meth:`set_from_signal`."""

    def __init__(self) -> None:
        super().__init__()
        self._signalled = False  # written by the handler, without a lock
        _start_waker()

    def set_from_signal(self) -> None:
        """Set the event from a signal handler: at once for whoever asks, and waiters woken
        from another thread (never the interrupted one, which may hold the lock)."""
        self._signalled = True
        _to_wake.put(self)

    def _wake(self) -> None:
        if self._signalled:  # (not when cleared meanwhile)
            super().set()

    def is_set(self) -> bool:
        return self._signalled or super().is_set()

    def wait(self, timeout: float | None = None) -> bool:
        return self._signalled or super().wait(timeout)

    def clear(self) -> None:
        self._signalled = False
        super().clear()
