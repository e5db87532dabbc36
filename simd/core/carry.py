"""Which items of a new list were in the last one, with numpy instead of a Python loop over the
fleet: what lets a list of 20 000 records (or robots) made again after a spawn or a delete be
built from runs of the last one plus the few new items (simd/wire/list_codec.py,
simd/adapters/fleet/adapter.py), and the physics find each body's row (simd/core/physics.py).

An item of a list is known by ``id()``: equal ids are the same object only while both are alive,
so the caller holds the last list as long as it holds its identities.
"""

from __future__ import annotations

import operator
import threading
from collections.abc import Sequence
from typing import Generic, TypeVar

import numpy as np
import numpy.typing as npt

T = TypeVar("T")


def identities(items: Sequence[object]) -> npt.NDArray[np.uint64]:
    """The ``id()`` of each item (read from the list: the items themselves are not touched)."""
    return np.fromiter(map(id, items), dtype=np.uint64, count=len(items))


def positions(table: npt.NDArray[np.generic], queries: npt.NDArray[np.generic]) -> npt.NDArray[np.int64]:
    """For each of ``queries``, its index in ``table``; -1 where it is not there. A value found
    twice in ``table`` is found at one of its places."""
    if not len(table):
        return np.full(len(queries), -1, dtype=np.int64)
    order = np.argsort(table, kind="stable")
    known = table[order]
    at = np.minimum(np.searchsorted(known, queries), len(known) - 1)
    return np.where(known[at] == queries, order[at], -1).astype(np.int64, copy=False)


def runs(source: npt.NDArray[np.int64]) -> list[tuple[int, int, int]]:
    """The runs of items carried over in the same order, ``source`` being :func:`positions` of
    the new list's identities in the last one's: ``(first, count, first_before)`` for
    ``after[first : first + count]``, which is ``before[first_before : first_before + count]``.
    A spawn (one item appended) or a delete (one taken out) leaves one or two runs."""
    found = source >= 0
    follows = np.zeros(len(source), dtype=bool)
    follows[1:] = found[1:] & found[:-1] & (source[1:] == source[:-1] + 1)
    last = found.copy()
    last[:-1] &= ~follows[1:]
    firsts, lasts = np.flatnonzero(found & ~follows), np.flatnonzero(last)
    return list(zip(firsts.tolist(), (lasts - firsts + 1).tolist(), source[firsts].tolist(), strict=True))


#: Room kept after the records of a buffer that layouts carried over fleet changes share, as a
#: share of the records' bytes (and at least ``MIN_SPARE`` bytes): a spawned robot's record is
#: written there instead of into a new copy of the whole fleet's bytes (simd/wire/list_codec.py,
#: simd/wire/odom_codec.py).
SPARE = 0.25
MIN_SPARE = 64 * 1024


def room_for(live: int) -> int:
    """The size of a new shared buffer for ``live`` bytes of records: them and the room after."""
    return live + max(int(live * SPARE), MIN_SPARE)


def copy_needed(used: int, need: int, size: int, kept: int) -> bool:
    """Whether a shared buffer of ``size`` bytes, ``used`` of them written, must be copied into a
    new one for a layout that keeps ``kept`` bytes of its records and adds ``need``: when the new
    ones do not fit, or when most of what it holds is the records of robots gone (a fleet that
    shrank would otherwise keep the bytes of its biggest size)."""
    return used + need > size or 2 * kept < used


#: Lists remembered by :class:`Recent`.
RECENT = 2


class Recent(Generic[T]):
    """What was made for each of the last few lists (of robots, of records), found again for a
    list of the same items, by identity: the list itself, or another holding the same objects
    in the same order (the simulation makes a new list of its robots whenever the fleet
    changes; a spawn and a delete of the same robot make one equal to the one before).

    More than one, because the fleet a list shows can go back and forth: a spawn answered at
    once adds a robot to the list until the simulation makes it, a delete of it answered at once
    takes it out again, and a client spawning, deleting and listing in turn at 20 000 robots
    made every list's records and byte layout anew (~13 ms of CPU each, simd/wire/list_codec.py).
    Any thread: the entries are replaced whole under a lock; the lists are held, so the
    identities of their items stay theirs."""

    def __init__(self, size: int = RECENT) -> None:
        self.size = size
        self._lock = threading.Lock()
        self._entries: list[tuple[Sequence[object], T]] = []  # the latest first

    def get(self, items: Sequence[object]) -> T | None:
        """What was made for a list of the same items, or None. Found in another list of the
        same items, it is kept for ``items`` from then on: the next ask of this list is one
        comparison instead of one per item (~1 ms at 20 000 robots, and the lists of a fleet
        are asked for many times a tick)."""
        with self._lock:
            entries = self._entries
        for known, value in entries:
            if known is items:
                return value
        for known, value in entries:
            if len(known) == len(items) and all(map(operator.is_, known, items)):
                with self._lock:
                    self._entries = [(items, v) if k is known else (k, v) for k, v in self._entries]
                return value
        return None

    def put(self, items: Sequence[object], value: T) -> None:
        """Remember ``value`` for ``items``, as the latest (the oldest beyond ``size`` goes)."""
        with self._lock:
            self._entries = [(items, value), *(e for e in self._entries if e[0] is not items)][: self.size]

    def latest(self) -> tuple[Sequence[object], T] | None:
        """The list remembered last, and its value."""
        with self._lock:
            return self._entries[0] if self._entries else None
