"""An event that a signal handler may set.

A Python signal handler runs on the main thread between two bytecodes, wherever that thread
is, possibly inside ``threading.Event.wait`` holding the event's own lock (a ``Lock``, not
re-entrant). An ``Event.set()`` in the handler then waits for that lock, which the interrupted
frame holds and can never release: the program hangs and ignores every later signal. simd
stopped that way once in the suite (simd/cli.py stops its engine from a thread since).

:class:`SignalEvent` is an ``Event`` whose :meth:`set_from_signal` takes no lock: it writes a
plain attribute (seen at once by :meth:`is_set` and :meth:`wait`, on any thread) and leaves
the locked ``set()``, which wakes the waiters, to a short-lived thread of its own.
"""

from __future__ import annotations

import threading


class SignalEvent(threading.Event):
    """A ``threading.Event`` that a signal handler sets with :meth:`set_from_signal`."""

    def __init__(self) -> None:
        super().__init__()
        self._signalled = False  # written by the handler, without a lock

    def set_from_signal(self) -> None:
        """Set the event from a signal handler: at once for whoever asks, and waiters woken
        from another thread (never the interrupted one, which may hold the lock)."""
        self._signalled = True
        threading.Thread(target=self.set, name="signalled", daemon=True).start()

    def is_set(self) -> bool:
        return self._signalled or super().is_set()

    def wait(self, timeout: float | None = None) -> bool:
        return self._signalled or super().wait(timeout)

    def clear(self) -> None:
        self._signalled = False
        super().clear()
