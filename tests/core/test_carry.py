"""The lookups that carry a list over to the next one (simd/core/carry.py) agree with a dict
and a Python loop: each item's place in the last list, and the runs that rebuild the new one."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from simd.core import carry

_IDS = st.integers(0, 2**63 - 1)
_EDITS = st.lists(st.tuples(st.sampled_from(("new", "drop", "move")), st.integers(0, 99)))


@given(table=st.lists(_IDS, unique=True, max_size=60), queries=st.lists(_IDS, max_size=60))
def test_positions_are_what_a_dict_of_the_table_says(table: list[int], queries: list[int]) -> None:
    mixed = queries + table[::2]  # some found, some not
    place = {v: k for k, v in enumerate(table)}
    got = carry.positions(np.array(table, dtype=np.uint64), np.array(mixed, dtype=np.uint64))
    assert got.tolist() == [place.get(q, -1) for q in mixed]


@given(before=st.integers(0, 50), edits=_EDITS)
def test_the_runs_and_the_new_items_rebuild_the_new_list(before: int, edits: list[tuple[str, int]]) -> None:
    old = [object() for _ in range(before)]
    new = list(old)
    for what, at in edits:
        if what == "new" or not new:
            new.insert(at % (len(new) + 1), object())
        elif what == "drop":
            del new[at % len(new)]
        else:
            new.insert(at % len(new), new.pop(at % len(new)))
    source = carry.positions(carry.identities(old), carry.identities(new))
    rebuilt: list[object | None] = [None] * len(new)
    for first, count, at in carry.runs(source):
        assert all(source[first + i] == at + i for i in range(count))
        rebuilt[first : first + count] = old[at : at + count]
    for k in np.flatnonzero(source < 0).tolist():
        assert new[k] not in old
        rebuilt[k] = new[k]
    assert all(a is b for a, b in zip(rebuilt, new, strict=True))


def test_recent_lists_are_found_again_by_the_identity_of_their_items() -> None:
    """The same list, or another of the same objects in the same order, finds its value; equal
    objects that are not the same do not; the oldest of more than ``size`` is forgotten."""
    a, b, c = [object() for _ in range(3)]
    recent: carry.Recent[str] = carry.Recent(size=2)
    assert recent.get([a]) is None and recent.latest() is None
    first, second = [a, b], [a, b, c]
    recent.put(first, "first")
    recent.put(second, "second")
    assert recent.get(first) == "first" and recent.get([b, a]) is None
    again = [a, b]
    assert recent.get(again) == "first"
    assert recent.latest() == (second, "second") and recent._entries[1][0] is again  # kept for it from now on
    assert recent.get(first) == "first"  # the same items all the same
    assert recent.get(list(second)) == "second" and recent.latest() == (second, "second")
    assert recent.get([[1], [2]]) is None  # a list of equal items is not the same list
    same = [[1], [2]]
    recent.put(same, "lists")
    assert recent.get(same) == "lists" and recent.get([[1], [2]]) is None
    assert recent.get(first) is None and recent.get(second) == "second"  # two kept: the oldest went
