"""Which items of a new list were in the last one, by identity, with numpy instead of a Python
loop: what lets a list of 20 000 records (or robots) made again after a spawn or a delete be
built from runs of the last one plus the few new items (simd/wire/list_codec.py,
simd/adapters/fleet/adapter.py).

An item is known by ``id()``: equal ids are the same object only while both are alive, so the
caller holds the last list as long as it holds its identities.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt


def identities(items: Sequence[object]) -> npt.NDArray[np.uint64]:
    """The ``id()`` of each item (read from the list: the items themselves are not touched)."""
    return np.fromiter(map(id, items), dtype=np.uint64, count=len(items))


def sources(before: npt.NDArray[np.uint64], after: npt.NDArray[np.uint64]) -> npt.NDArray[np.int64]:
    """For each identity of ``after``, its index in ``before``; -1 where it is new. An item
    listed twice in ``before`` is found at one of its places."""
    if not len(before):
        return np.full(len(after), -1, dtype=np.int64)
    order = np.argsort(before, kind="stable")
    known = before[order]
    at = np.minimum(np.searchsorted(known, after), len(known) - 1)
    return np.where(known[at] == after, order[at], -1).astype(np.int64, copy=False)


def runs(source: npt.NDArray[np.int64]) -> list[tuple[int, int, int]]:
    """The runs of items carried over in the same order: ``(first, count, first_before)`` for
    ``after[first : first + count]``, which is ``before[first_before : first_before + count]``.
    A spawn (one item appended) or a delete (one taken out) leaves one or two runs."""
    found = source >= 0
    follows = np.zeros(len(source), dtype=bool)
    follows[1:] = found[1:] & found[:-1] & (source[1:] == source[:-1] + 1)
    last = found.copy()
    last[:-1] &= ~follows[1:]
    firsts, lasts = np.flatnonzero(found & ~follows), np.flatnonzero(last)
    return list(zip(firsts.tolist(), (lasts - firsts + 1).tolist(), source[firsts].tolist(), strict=True))
