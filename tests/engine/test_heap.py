"""The daemon's heap keeper on an injected clock: what lived through a freeze is out of the
collector's sight, and a full collection comes back when the fleet has changed enough or
enough time has passed. The collector is process-wide: every test gives it back whole."""

from __future__ import annotations

import gc
import weakref
from collections.abc import Iterator

import pytest

from simd.engine.heap import YOUNG_PER_ROBOT, HeapKeeper


class Node:
    """Half of a reference cycle: garbage only a full collection finds."""

    other: Node | None = None


@pytest.fixture
def keeper() -> Iterator[tuple[HeapKeeper, list[float]]]:
    now = [0.0]
    k = HeapKeeper(every_s=1.0, growth=0.25, collect_every_s=600.0, clock=lambda: now[0])
    try:
        yield k, now
    finally:
        k.close()
        gc.collect()


def _cycle() -> weakref.ref[Node]:
    a, b = Node(), Node()
    a.other, b.other = b, a
    return weakref.ref(a)


def test_a_cycle_frozen_alive_waits_for_the_full_collection_due_after_enough_changes(
    keeper: tuple[HeapKeeper, list[float]],
) -> None:
    k, now = keeper
    k.keep(robots=400, changes=0)  # the first time: a full collection
    assert k.full_collections == 1
    a, b = Node(), Node()
    a.other, b.other = b, a
    probe = weakref.ref(a)
    now[0] += 1.0
    k.keep(robots=400, changes=100)  # a quarter of the fleet, not more: frozen
    assert k.full_collections == 1 and gc.get_freeze_count() > 0
    del a, b
    gc.collect()
    assert probe() is not None  # out of the collector's sight
    now[0] += 0.5
    k.keep(robots=400, changes=101)  # more than a quarter, but not due yet
    assert k.full_collections == 1 and probe() is not None
    now[0] += 0.5
    k.keep(robots=400, changes=101)
    assert k.full_collections == 2 and probe() is None


def test_young_garbage_is_collected_as_ever_and_time_alone_brings_a_full_collection(
    keeper: tuple[HeapKeeper, list[float]],
) -> None:
    k, now = keeper
    k.keep(robots=0, changes=0)
    young = _cycle()  # never lived through a freeze
    gc.collect()
    assert young() is None
    for _ in range(5):
        now[0] += 1.0
        k.keep(robots=0, changes=0)
    assert k.full_collections == 1
    now[0] += 600.0
    k.keep(robots=0, changes=0)
    assert k.full_collections == 2


def test_closing_gives_the_frozen_objects_back(keeper: tuple[HeapKeeper, list[float]]) -> None:
    k, _ = keeper
    k.keep(robots=0, changes=0)
    assert gc.get_freeze_count() > 0
    k.close()
    assert gc.get_freeze_count() == 0


def test_the_youngest_generation_grows_with_the_fleet_and_is_given_back(
    keeper: tuple[HeapKeeper, list[float]],
) -> None:
    k, now = keeper
    before = gc.get_threshold()
    k.keep(robots=10, changes=0)  # a small fleet: CPython's own
    assert gc.get_threshold() == before
    now[0] += 1.0
    k.keep(robots=20_000, changes=0)
    assert gc.get_threshold() == (YOUNG_PER_ROBOT * 20_000, *before[1:])
    young = _cycle()  # young cyclic garbage is still found by a collection
    gc.collect(0)
    assert young() is None
    now[0] += 1.0
    k.keep(robots=5_000, changes=20_000)  # the fleet shrank
    assert gc.get_threshold()[0] == YOUNG_PER_ROBOT * 5_000
    k.close()
    assert gc.get_threshold() == before
