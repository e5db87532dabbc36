"""The robot list from byte templates is the MessagePack of the same ``RobotList``, to the byte,
whatever the fleet's size, names, models and numbers, and however it changes between lists: on
the numpy path and on the compiled one (simd/wire/_listpack.c) alike."""

from __future__ import annotations

import math

import msgspec
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.control import Pose2D, RobotList, RobotRecord
from protocol.keys import Keys
from protocol.messages import Time
from simd.core import carry
from simd.core.models import MODELS
from simd.core.snapshot import RobotState
from simd.wire import list_codec
from simd.wire.convert import robot_record
from simd.wire.list_codec import RobotListEncoder

KEYS = Keys("fleet")
needs_listpack = pytest.mark.skipif(list_codec._native is None, reason="simd.wire._listpack is not built")
PATHS = [pytest.param(False, id="numpy"), pytest.param(True, id="native", marks=needs_listpack)]


def _records(n: int, start: int = 0) -> list[RobotRecord]:
    models = list(MODELS.values())
    out = []
    for i in range(start, start + n):
        name = f"r{i}" + "x" * (i % 7)  # names of every length: records of different sizes
        state = RobotState(name, f"ns/{name}", models[i % len(models)], 0.0, 0.0, 0.0, 0.0, 0.0, (i, -i, 0.5))
        out.append(robot_record(state, KEYS, "simd-a"))
    return out


def _expected(time: float, records: list[RobotRecord], columns: list[np.ndarray]) -> bytes:
    robots = [
        msgspec.structs.replace(r, pose=Pose2D(x=x, y=y, yaw=yaw), linear_velocity=v, angular_velocity=w)
        for r, x, y, yaw, v, w in zip(records, *(c.tolist() for c in columns), strict=True)
    ]
    return msgspec.msgpack.encode(RobotList(stamp=Time.from_seconds(time), robots=robots))


@pytest.mark.parametrize("native", PATHS)
@pytest.mark.parametrize("n", [0, 1, 15, 16, 300, 70_000])
def test_the_list_is_byte_identical_to_encoding_the_struct(n: int, native: bool) -> None:
    rng = np.random.default_rng(n)
    records = _records(min(n, 300))
    records = [records[i % len(records)] for i in range(n)] if records else []  # (70 000: records repeat)
    columns = [rng.normal(0, 50, n) for _ in range(5)]
    columns[0][:1] = [0.0] if n else []  # zeros, negatives, large and small numbers alike
    special = [-0.0, math.inf, -math.inf, math.nan, 5e-324, 1.7976931348623157e308]
    columns[1][: len(special)] = special[:n]  # and what a float64 can hold at its edges
    enc = RobotListEncoder(native)
    got = enc.encode(12.345, records, *columns)
    assert got == _expected(12.345, records, columns)
    assert (
        msgspec.msgpack.decode(got, type=RobotList).robots[:3]
        == msgspec.msgpack.decode(_expected(12.345, records, columns), type=RobotList).robots[:3]
    )


@pytest.mark.parametrize("native", PATHS)
def test_a_fleet_that_changes_between_lists_is_laid_out_again(native: bool) -> None:
    enc = RobotListEncoder(native)
    first = _records(40)
    rng = np.random.default_rng(1)
    for records in (first, first[5:], [*first[5:], *_records(3, start=100)], first[5:]):
        columns = [rng.normal(0, 5, len(records)) for _ in range(5)]
        for t in (1.0, 2.0):  # the same layout twice: the second list reuses it
            assert enc.encode(t, records, *columns) == _expected(t, records, columns)


#: what happens to the fleet between two lists: a spawn appends a record, a delete takes the one
#: at a place out, a replaced record is another object (a robot of the same name spawned again,
#: longer or shorter), a move takes one record elsewhere; a copy is the same records, a new list
_CHANGES = st.one_of(
    st.tuples(st.just("spawn"), st.integers(0, 10**6)),
    st.tuples(st.just("delete"), st.integers(0, 10**6)),
    st.tuples(st.just("replace"), st.integers(0, 10**6)),
    st.tuples(st.just("move"), st.integers(0, 10**6)),
    st.tuples(st.just("copy"), st.just(0)),
)


#: the compiled packer's shared buffer: with its usual room, and with none (every spawn then
#: copies the records into a new buffer; the numpy path has no room either way)
ROOM = [pytest.param((carry.SPARE, carry.MIN_SPARE), id="room"), pytest.param((0.0, 0), id="no-room")]


@pytest.mark.parametrize("room", ROOM)
@pytest.mark.parametrize("native", PATHS)
@settings(max_examples=60, deadline=None)
@given(start=st.integers(0, 40), changes=st.lists(st.lists(_CHANGES, max_size=4), max_size=10), seed=st.integers(0, 99))
def test_every_list_after_spawns_deletes_and_replaced_records_is_the_structs_encoding(
    start: int, changes: list[list[tuple[str, int]]], seed: int, native: bool, room: tuple[float, int]
) -> None:
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(carry, "SPARE", room[0])
        mp.setattr(carry, "MIN_SPARE", room[1])
        _lists_after_changes(start, changes, seed, native)


def _lists_after_changes(start: int, changes: list[list[tuple[str, int]]], seed: int, native: bool) -> None:
    enc = RobotListEncoder(native)
    rng = np.random.default_rng(seed)
    pool = iter(_records(400, start=1000))
    records = _records(start)
    for t, batch in enumerate([[], *changes]):
        records = list(records)  # the caller's new list, as the adapter makes one per change
        for what, at in batch:
            if what == "spawn":
                records.append(next(pool))
                if at % 2:  # encoded ahead, as the adapter does at a spawn
                    enc.prepare(records[-1])
            elif records and what == "delete":
                del records[at % len(records)]
            elif records and what == "replace":
                old = records[at % len(records)]
                records[at % len(records)] = msgspec.structs.replace(old, name=old.name + "y" * (at % 3), daemon="b")
                if at % 3 == 1:  # a template of the namespace's record before: never used for the new one
                    enc.prepare(old)
                elif at % 3 == 2:
                    enc.prepare(records[at % len(records)])
            elif records and what == "move":
                records.insert(at % (len(records) + 1), records.pop(at % len(records)))
        columns = [rng.normal(0, 50, len(records)) for _ in range(5)]
        assert enc.encode(float(t), records, *columns) == _expected(float(t), records, columns)


@pytest.mark.parametrize("native", PATHS)
def test_columns_of_another_length_are_refused(native: bool) -> None:
    with pytest.raises(ValueError, match="2 records"):
        RobotListEncoder(native).encode(0.0, _records(2), *([np.zeros(3)] * 5))


@pytest.mark.parametrize("native", PATHS)
def test_a_template_prepared_at_a_spawn_is_what_the_next_list_lays_out_and_none_is_kept(native: bool) -> None:
    enc = RobotListEncoder(native)
    records = _records(3)
    enc.encode(1.0, records, *[np.zeros(3) for _ in range(5)])
    new, other = _records(2, start=50)
    enc.prepare(new)
    assert new.namespace in enc._ready
    # the prepared bytes are laid out as they are, not encoded again: made another record's here,
    # the list says the other record (what it would never do if it encoded the new one itself)
    enc._ready[new.namespace] = (new, _template_of(other))
    columns = [np.ones(4) for _ in range(5)]
    assert enc.encode(2.0, [*records, new], *columns) == _expected(2.0, [*records, other], columns)
    assert enc._ready == {}  # used once
    # a template prepared after a list laid its robot out is forgotten by the next new layout
    late = _records(1, start=60)[0]
    enc.encode(3.0, [*records, late], *[np.ones(4) for _ in range(5)])
    enc.prepare(late)
    enc.encode(4.0, [*records[1:], late], *[np.ones(3) for _ in range(5)])
    assert enc._ready == {}


def _template_of(record: RobotRecord) -> tuple[bytes, list[int]]:
    from simd.wire.list_codec import _template

    return _template(record)


@pytest.mark.parametrize("native", PATHS)
@settings(max_examples=40, deadline=None)
@given(n=st.integers(0, 60), picks=st.lists(st.integers(0, 10**6), max_size=80), seed=st.integers(0, 99))
def test_a_list_of_some_rows_is_the_structs_encoding_of_those_records(
    n: int, picks: list[int], seed: int, native: bool
) -> None:
    rng = np.random.default_rng(seed)
    records = _records(n)
    rows = [p % n for p in picks] if n else []  # any order, a row twice too
    columns = [rng.normal(0, 50, n) for _ in range(5)]
    enc = RobotListEncoder(native)
    got = enc.encode(3.5, records, *columns, rows=rows)
    assert got == _expected(3.5, [records[k] for k in rows], [c[rows] for c in columns])
    # and the layout it made serves the whole list, byte for byte, as before
    assert enc.encode(3.5, records, *columns) == _expected(3.5, records, columns)


@pytest.mark.parametrize("native", PATHS)
@pytest.mark.parametrize("row", [2, -1])
def test_rows_outside_the_records_are_refused(native: bool, row: int) -> None:
    with pytest.raises(ValueError, match="rows outside"):
        RobotListEncoder(native).encode(0.0, _records(2), *([np.zeros(2)] * 5), rows=[row])


@needs_listpack
def test_the_compiled_packer_checks_every_index_before_it_writes() -> None:
    """A record or a number outside the buffer, or arrays of the wrong kind, are refused with a
    clear error: never a write outside the list (the numpy path would raise an IndexError)."""
    pick = list_codec._native.pick  # type: ignore[union-attr]
    buffer = np.arange(40, dtype=np.uint8)  # every byte tells where it came from
    starts, lengths = np.array([0, 20], dtype=np.int64), np.array([20, 20], dtype=np.int64)
    marks = np.array([[0, 8, 12, 4, 12], [12, 4, 0, 8, 12]], dtype=np.int64)  # each record its own order
    cols = [np.array([10.0 * k + 1, 10.0 * k + 2]) for k in range(5)]  # column k, record i: 10k + i + 1

    def expected(order: list[int]) -> bytes:
        out = b"h"
        for i in order:
            record = bytearray(buffer[starts[i] : starts[i] + lengths[i]].tobytes())
            for k in range(5):  # in field order: a later field written over an earlier one wins
                record[marks[i, k] : marks[i, k] + 8] = np.array([cols[k][i]], dtype=">f8").tobytes()
            out += bytes(record)
        return out

    assert pick(b"h", buffer, starts, lengths, marks, None, *cols) == expected([0, 1])
    assert pick(b"h", buffer, starts, lengths, marks, np.array([1, 1, 0], dtype=np.int64), *cols) == expected([1, 1, 0])
    assert pick(b"h", buffer, starts, lengths, marks, np.zeros(0, dtype=np.int64), *cols) == b"h"
    # records out of order: copied from where each starts, in index order
    swapped = pick(
        b"h", buffer, starts[::-1].copy(), lengths, marks[::-1].copy(), None, *[c[::-1].copy() for c in cols]
    )
    assert swapped == expected([1, 0])
    with pytest.raises(ValueError, match="outside the buffer"):
        pick(b"", buffer, starts, np.array([20, 21], dtype=np.int64), marks, None, *cols)
    with pytest.raises(ValueError, match="outside the buffer"):
        pick(b"", buffer, np.array([0, 2**62], dtype=np.int64), lengths, marks, None, *cols)
    with pytest.raises(ValueError, match="outside the record"):
        pick(b"", buffer, starts, lengths, marks + 9, None, *cols)
    with pytest.raises(ValueError, match="rows outside"):
        pick(b"", buffer, starts, lengths, marks, np.array([0, -(2**63)], dtype=np.int64), *cols)
    with pytest.raises(ValueError, match="expected 10"):
        pick(b"", buffer, starts, lengths, marks[:1], None, *cols)
    with pytest.raises(TypeError, match="item format"):
        pick(b"", buffer, starts, lengths, marks, None, *([np.ones(2, dtype=np.float32)] * 5))
    with pytest.raises(TypeError, match="C-contiguous"):
        pick(b"", buffer, starts, lengths, marks, None, np.ones(4)[::2], *cols[1:])


@needs_listpack
def test_the_compiled_packers_layouts_share_a_buffer_until_it_is_full() -> None:
    """A spawn writes the new record after the others in the same buffer, a delete copies
    nothing, and only a spawn that does not fit copies the records into a new buffer; every
    list of every layout stays the structs' encoding, the older layouts' too."""
    enc = RobotListEncoder(native=True)
    records = _records(30)
    columns = [np.arange(30.0) + k for k in range(5)]
    assert enc.encode(1.0, records, *columns) == _expected(1.0, records, columns)
    first = enc.latest_layout()
    first_bytes = first.buffer[: first.used].tobytes()
    room = len(first.buffer) - first.used
    assert room >= carry.MIN_SPARE
    spawned = [*records, *_records(1, start=500)]
    cols = [np.arange(31.0) * 2 for _ in range(5)]
    assert enc.encode(2.0, spawned, *cols) == _expected(2.0, spawned, cols)
    second = enc.latest_layout()
    assert second.buffer is first.buffer and second.used > first.used
    deleted = spawned[3:]
    cols = [np.arange(28.0) * 3 for _ in range(5)]
    assert enc.encode(3.0, deleted, *cols) == _expected(3.0, deleted, cols)
    assert enc.latest_layout().buffer is first.buffer and enc.latest_layout().used == second.used
    # what the first layout's lists read is unchanged by what the later ones wrote
    assert first.buffer[: first.used].tobytes() == first_bytes
    # spawns until the room is gone: then one new buffer, the records in order, room after them
    pool = iter(_records(2000, start=1000))
    grown = list(records)
    while enc.latest_layout().buffer is first.buffer:
        grown = [*grown, next(pool)]
        cols = [np.ones(len(grown)) * k for k in range(5)]
        assert enc.encode(4.0, grown, *cols) == _expected(4.0, grown, cols)
    fresh = enc.latest_layout()
    assert fresh.starts[0] == 0 and np.all(fresh.starts[1:] == np.cumsum(fresh.lengths)[:-1])
    assert len(fresh.buffer) - fresh.used >= carry.MIN_SPARE


@needs_listpack
def test_a_fleet_that_shrank_to_less_than_half_is_copied_into_a_smaller_buffer() -> None:
    enc = RobotListEncoder(native=True)
    records = _records(200)
    enc.encode(1.0, records, *[np.zeros(200) for _ in range(5)])
    big = enc.latest_layout()
    most = records[:120]  # more than half of the bytes stays: the buffer is kept
    enc.encode(2.0, most, *[np.ones(120) for _ in range(5)])
    assert enc.latest_layout().buffer is big.buffer
    few = records[:10]
    cols = [np.full(10, 3.0) for _ in range(5)]
    assert enc.encode(3.0, few, *cols) == _expected(3.0, few, cols)
    small = enc.latest_layout()
    assert small.buffer is not big.buffer and small.used == int(small.lengths.sum())
    assert len(small.buffer) < len(big.buffer) / 2


@pytest.mark.parametrize("native", PATHS)
def test_a_fleet_going_back_and_forth_finds_its_recent_layouts(native: bool) -> None:
    """A robot spawned and deleted again (a promise, then the simulation's own list of the same
    robots): the list of the robots before is laid out once, found again for an equal list,
    and still right after the layouts made since wrote to the buffer they share."""
    enc = RobotListEncoder(native)
    records = _records(40)
    extra = _records(2, start=900)
    cols = [np.arange(40.0) + k for k in range(5)]
    assert enc.encode(1.0, records, *cols) == _expected(1.0, records, cols)
    before = enc.latest_layout()
    grown = [*records, extra[0]]
    more = [np.arange(41.0) * 2 for _ in range(5)]
    assert enc.encode(2.0, grown, *more) == _expected(2.0, grown, more)
    again = list(records)  # the same robots in a new list
    assert enc.encode(3.0, again, *cols) == _expected(3.0, again, cols)
    assert enc.latest_layout() is not before and enc._layouts.get(again) is before  # found, not made
    other = [*records, extra[1]]  # made from the latest, past every byte the others use
    assert enc.encode(4.0, other, *more) == _expected(4.0, other, more)
    assert enc.encode(5.0, grown, *more) == _expected(5.0, grown, more)
