"""The robot list as MessagePack, from byte templates: the list of 20 000 robots in a few ms.

A ``RobotRecord`` is ~750 bytes of MessagePack of which five numbers change from one list to the
next (the pose and the twist); the name, the model's limits and footprint, the topics and the
frames are the robot's for life. Building 8 000 records and encoding them took ~60 ms with the
GIL held, on the thread that answers queries, and made 16 000 objects for the garbage collector
each time. Here each robot's record is encoded once (by msgspec, with markers in those five
places, as simd/wire/odom_codec.py does for odometry), the records of the fleet are laid end to
end in one buffer, and each list copies that buffer once, into the reply, and writes the five
float64 numbers of every robot into it with one numpy scatter per field. msgspec encodes a float
as a MessagePack float64 (0xcb and 8 big-endian bytes), so the bytes are exactly what encoding
the ``RobotList`` struct gives (tested).

The copy and the writes are done by the compiled ``simd.wire._listpack`` when it is built (one
pass with the GIL held; the numpy path below is the reference it is tested against, and the
fallback). The list is answered on a zenoh query thread while the simulation and the outbox
threads want the GIL too, and numpy lets go of it in every operation over a few hundred items:
each time the query thread waited to get it back. A standalone probe (a 16 MB reply with one
other thread busy in Python, 1 ms switch interval): 12.5 ms the numpy way, 4.9 for bytes made
beforehand. In the daemon at 20 000 robots under ``python -m bench.overload`` the whole list
while running went from 68 and 55 ms (p50) to 47 and 40 in alternating runs.

A fleet change (a spawn appends a record, a delete takes one out) makes a new layout from the
last one: the records both lists have are found by identity with numpy, and only the records
new to it are encoded. The numpy path copies the kept records into a new buffer in runs, slice
by slice (a change of a few robots in 20 000: ~2 ms, where laying every record out again in a
Python loop took ~40). The compiled packer's layouts share one buffer instead: the kept records
stay where they are, a new one is written after the last, and only when the buffer's room
(``carry.SPARE``) is used up are the records copied into a new one. A list right after a change at
20 000 robots then takes 3.8-4.0 ms of CPU instead of 4.6-4.8, and the worst of 20 such lists
5-10 ms instead of 7-38 (a fresh 16 MB buffer is faulted in page by page): ``python -m
bench.fleet_change --robots 20000 --rounds 20``, three alternating pairs.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import msgspec
import numpy as np
import numpy.typing as npt

from fleetcommon.arrays import F64
from protocol.control import Pose2D, RobotList, RobotRecord
from protocol.messages import Time
from simd.core import carry
from simd.core import native as _fast

_native, _why = _fast.load("listpack")  # None without a C compiler: the numpy path does the same
_encoder = msgspec.msgpack.Encoder()
#: Values that cannot occur in real data, one per patched field: pose x, y, yaw, linear, angular.
_MARKERS = tuple(-1.2345678912345e-301 * (k + 1) for k in range(5))
_BYTE = np.arange(8, dtype=np.int64)


#: A record's bytes with markers where its pose and twist go, and where each marker starts.
_Template = tuple[bytes, list[int]]


def _template(record: RobotRecord) -> _Template:
    """The record's bytes with the five markers in, and where each marker's 8 bytes start."""
    x, y, yaw, v, w = _MARKERS
    raw = _encoder.encode(
        msgspec.structs.replace(record, pose=Pose2D(x=x, y=y, yaw=yaw), linear_velocity=v, angular_velocity=w)
    )
    offsets = []
    for m in _MARKERS:
        marker = b"\xcb" + np.array([m], dtype=">f8").tobytes()
        if raw.count(marker) != 1:
            raise ValueError(f"the record of {record.namespace} holds the marker {m!r} other than once")
        offsets.append(raw.index(marker) + 1)
    return raw, offsets


def _array_header(n: int) -> bytes:
    """A MessagePack array header of ``n`` items, as msgspec writes it (the shortest form)."""
    if n < 16:
        return bytes([0x90 | n])
    if n < 1 << 16:
        return b"\xdc" + n.to_bytes(2, "big")
    return b"\xdd" + n.to_bytes(4, "big")


@dataclass(eq=False)
class _Carried:
    """What a new list of records keeps of a layout's: each record's length and marks, those
    found by identity (``source``: their rows in the layout, -1 for the others) and the bytes
    of the others."""

    identities: npt.NDArray[np.uint64]
    source: npt.NDArray[np.int64]
    lengths: npt.NDArray[np.int64]
    marks: npt.NDArray[np.int64]
    fresh: dict[int, bytes]  # row -> its record's template


@dataclass(eq=False)
class _Layout:
    """Records in a buffer: their bytes, where each starts, how long each is and where its
    five numbers are (relative to its start). Its arrays never change once made, nor do the
    bytes of its records (the numpy path's positions are computed from them on first use; the
    compiled packer's next layout may write new records into the buffer past ``used``): a list
    reads it without the lock.

    The numpy path's layouts lay the records end to end from 0 and nothing else (``successor``);
    the compiled packer's share one buffer from one change to the next, the records of robots
    deleted since left where they were until the buffer is full (``shared_successor``)."""

    records: list[RobotRecord]  # held: the identities stay theirs while this layout lives
    identities: npt.NDArray[np.uint64]  # id() of each record
    buffer: npt.NDArray[np.uint8]
    starts: npt.NDArray[np.int64]
    lengths: npt.NDArray[np.int64]
    marks: npt.NDArray[np.int64]  # (n, 5)
    used: int  # the bytes of the buffer in use, by this layout's records or earlier ones'

    @functools.cached_property
    def scatter(self) -> npt.NDArray[np.int64]:
        """Per field, the 8 bytes of every record's number: (5, n, 8) positions in the buffer.
        Made on the numpy path's first list of this layout only: at 20 000 robots it is 6 MB
        and ~1 ms after every fleet change, which the compiled packer does not need."""
        return np.ascontiguousarray((self.starts[:, None] + self.marks).T)[:, :, None] + _BYTE

    @classmethod
    def empty(cls) -> _Layout:
        none = np.zeros(0, dtype=np.int64)
        return cls(
            [], carry.identities([]), np.zeros(0, dtype=np.uint8), none, none, np.zeros((0, 5), dtype=np.int64), 0
        )

    def _carry(self, records: list[RobotRecord], template: Callable[[RobotRecord], _Template]) -> _Carried:
        """The records this layout has (found by identity: both lists are alive, so an equal
        ``id`` is the same object), and the others' bytes from ``template``."""
        n = len(records)
        ids = carry.identities(records)
        source = carry.positions(self.identities, ids)
        found = source >= 0
        lengths = np.zeros(n, dtype=np.int64)
        marks = np.zeros((n, 5), dtype=np.int64)
        lengths[found] = self.lengths[source[found]]
        marks[found] = self.marks[source[found]]
        fresh: dict[int, bytes] = {}
        made: dict[int, tuple[bytes, list[int]]] = {}  # (a record listed twice is encoded once)
        for k in np.flatnonzero(~found).tolist():
            record = records[k]
            encoded = made.get(id(record))
            if encoded is None:
                encoded = made[id(record)] = template(record)
            fresh[k] = encoded[0]
            lengths[k] = len(encoded[0])
            marks[k] = encoded[1]
        return _Carried(ids, source, lengths, marks, fresh)

    def successor(self, records: list[RobotRecord], template: Callable[[RobotRecord], _Template] = _template
                  ) -> _Layout:  # fmt: skip
        """The layout of ``records`` end to end in a new buffer: the records this one has
        copied from it in runs, the others' bytes from ``template``."""
        c = self._carry(records, template)
        n, lengths = len(records), c.lengths
        starts = np.zeros(n, dtype=np.int64)
        np.cumsum(lengths[:-1], out=starts[1:])
        buffer = np.empty(int(starts[-1] + lengths[-1]) if n else 0, dtype=np.uint8)
        for first, count, before in carry.runs(c.source):  # each run: one slice of the old buffer
            dst, src = int(starts[first]), int(self.starts[before])
            size = int(starts[first + count - 1] + lengths[first + count - 1]) - dst
            buffer[dst : dst + size] = self.buffer[src : src + size]
        for k, raw in c.fresh.items():
            buffer[starts[k] : starts[k] + lengths[k]] = np.frombuffer(raw, dtype=np.uint8)
        return _Layout(records, c.identities, buffer, starts, lengths, c.marks, len(buffer))

    def shared_successor(self, records: list[RobotRecord], template: Callable[[RobotRecord], _Template] = _template
                         ) -> _Layout:  # fmt: skip
        """The layout of ``records`` for the compiled packer: the records this one has stay
        where they are in its buffer, the others are written into it past ``used``; only when
        they do not fit, or the records kept are less than half of what the buffer holds, are
        the records copied into a new buffer (in order, with room after them: ``carry.room_for``). A spawn
        or a delete among 20 000 robots then copies no 16 MB."""
        assert _native is not None
        c = self._carry(records, template)
        found = c.source >= 0
        starts = np.zeros(len(records), dtype=np.int64)
        starts[found] = self.starts[c.source[found]]
        need = sum(len(raw) for raw in c.fresh.values())
        buffer, used = self.buffer, self.used
        kept_bytes = int(c.lengths[found].sum())
        if carry.copy_needed(used, need, len(buffer), kept_bytes):  # copied, in order, into a new buffer
            kept = c.source[found]
            zeros = np.zeros(len(self.starts))  # (the numbers are written by every list anyway)
            packed = _native.pick(b"", self.buffer, self.starts, self.lengths, self.marks, kept, *[zeros] * 5)
            live = len(packed) + need
            buffer = np.empty(carry.room_for(live), dtype=np.uint8)
            buffer[: len(packed)] = np.frombuffer(packed, dtype=np.uint8)
            kept_starts = np.zeros(len(kept), dtype=np.int64)
            np.cumsum(c.lengths[found][:-1], out=kept_starts[1:])
            starts[found] = kept_starts
            used = len(packed)
        for k, raw in c.fresh.items():
            buffer[used : used + len(raw)] = np.frombuffer(raw, dtype=np.uint8)
            starts[k] = used
            used += len(raw)
        return _Layout(records, c.identities, buffer, starts, c.lengths, c.marks, used)


class RobotListEncoder:
    """Encodes ``RobotList`` messages of the fleet's records with the pose and twist of now
    (any thread: one layout is made at a time)."""

    def __init__(self, native: bool | None = None) -> None:
        """``native``: write lists with the compiled ``simd.wire._listpack`` (default: when it is
        built). It does what the numpy path does in one pass that keeps the GIL: the numpy path
        lets go of it in each of its ~10 array operations, and the query thread answering a list
        waits to get it back each time behind the simulation and the outbox threads."""
        if native and _native is None:
            raise RuntimeError(f"the compiled list packer is not available: {_why}")
        self.native = _native is not None if native is None else native
        self._lock = threading.Lock()
        #: the layouts of the recent lists of records (the latest made first: the next is made
        #: from it, past every byte the others use of a buffer they share)
        self._layouts: carry.Recent[_Layout] = carry.Recent()
        #: new robots' templates made ahead of the next list, by namespace (with the record)
        self._ready: dict[str, tuple[RobotRecord, _Template]] = {}

    def prepare(self, record: RobotRecord) -> None:
        """Encode a new robot's record now (any thread but a query's: the spawn's), so that the
        next list lays it out without encoding it. Encoding 20 000 records at once took the
        first list after a big spawn ~0.5 s, on the thread answering it."""
        self._ready[record.namespace] = (record, _template(record))

    def forget(self, namespace: str) -> None:
        """A robot is gone before a list laid it out: its template is not needed."""
        self._ready.pop(namespace, None)

    def _drop_laid_out(self, layout: _Layout) -> None:
        """Forget the templates of records the layout has already (a list laid one out before
        its spawn's ``prepare`` ran, or with another record while the spawn was promised):
        they would never be used, and waited for the robot's delete."""
        entries = list(self._ready.items())  # (prepare may add one meanwhile: it stays)
        laid = carry.positions(layout.identities, carry.identities([entry[0] for _, entry in entries])) >= 0
        for (ns, entry), done in zip(entries, laid.tolist(), strict=True):
            if done and self._ready.get(ns) is entry:
                del self._ready[ns]

    def _template(self, record: RobotRecord) -> _Template:
        ready = self._ready.pop(record.namespace, None)
        if ready is not None and ready[0] is record:
            return ready[1]
        return _template(record)

    def latest_layout(self) -> _Layout:
        """The layout made last (an empty one before the first list)."""
        latest = self._layouts.latest()
        return latest[1] if latest is not None else _Layout.empty()

    def lay_out(self, records: list[RobotRecord]) -> None:
        """Make the layout of ``records`` now (any thread), so that a list of them only copies
        their bytes and writes their numbers."""
        with self._lock:
            self._layout_of(records)

    def _layout_of(self, records: list[RobotRecord]) -> _Layout:
        """The layout of ``records``: a recent one, or one made from the latest (the caller
        holds the lock)."""
        layout = self._layouts.get(records)
        if layout is None:
            last = self.latest_layout()
            made = last.shared_successor if self.native else last.successor
            layout = made(records, self._template)
            self._layouts.put(records, layout)
            if self._ready:
                self._drop_laid_out(layout)
        return layout

    def encode(self, time: float, records: list[RobotRecord], x: F64, y: F64, yaw: F64, linear: F64,
               angular: F64, *, rows: Sequence[int] | None = None) -> bytearray:  # fmt: skip
        """The MessagePack of ``RobotList(stamp=time, robots=records)`` with row ``k``'s pose
        and twist put into ``records[k]`` (a bytearray: the reply's only copy of the buffer).
        ``records`` is laid out again whenever it is another list than the last one: the caller
        makes a new list when the fleet changes, and keeps the records of the robots that stay.
        With ``rows``, the list holds those rows only, in that order (a page of a big fleet:
        its records' bytes picked from the fleet's layout, ~1 ms for 1 000 of 20 000
        robots, where building and encoding their structs took ~5)."""
        n = len(records)
        columns = (x, y, yaw, linear, angular)
        if any(len(c) != n for c in columns):
            raise ValueError(f"{n} records for columns of {[len(c) for c in columns]} values")
        head = _encoder.encode(RobotList(stamp=Time.from_seconds(time), robots=[]))
        if not head.endswith(b"\x90"):  # robots, the last field, is empty: a fixarray of 0
            raise ValueError("a RobotList does not end with its robots")
        with self._lock:
            layout = self._layout_of(records)
        picked = None if rows is None else np.asarray(rows, dtype=np.int64).reshape(-1)
        if self.native:
            assert _native is not None
            prefix = head[:-1] + _array_header(n if picked is None else len(picked))
            contiguous = [np.ascontiguousarray(c, dtype=np.float64) for c in columns]
            out: bytearray = _native.pick(
                prefix, layout.buffer, layout.starts, layout.lengths, layout.marks, picked, *contiguous
            )
            return out
        if picked is not None:
            return _picked(head[:-1], layout, picked, columns)
        prefix = head[:-1] + _array_header(n)
        out = bytearray(prefix) + layout.buffer.data
        body = np.frombuffer(out, dtype=np.uint8, offset=len(prefix))
        for k, column in enumerate(columns):
            numbers = np.ascontiguousarray(column, dtype=">f8").view(np.uint8).reshape(n, 8)
            body[layout.scatter[k]] = numbers
        return out


def _picked(head: bytes, layout: _Layout, rows: npt.NDArray[np.int64], columns: tuple[F64, ...]) -> bytearray:
    """The list of the layout's ``rows`` (in that order) after ``head``: each row's bytes
    gathered from the layout's buffer, and its five numbers written into them."""
    if len(rows) and (rows.min() < 0 or rows.max() >= len(layout.starts)):
        raise ValueError(f"rows outside the {len(layout.starts)} records")
    lengths = layout.lengths[rows]
    starts = np.zeros(len(rows), dtype=np.int64)
    np.cumsum(lengths[:-1], out=starts[1:])
    # every byte of the picked records: for each, its place in the layout's buffer
    total = int(lengths.sum())
    source = np.repeat(layout.starts[rows] - starts, lengths) + np.arange(total, dtype=np.int64)
    prefix = head + _array_header(len(rows))
    out = bytearray(prefix) + layout.buffer[source].data
    body = np.frombuffer(out, dtype=np.uint8, offset=len(prefix))
    places = (starts[:, None] + layout.marks[rows]).T  # (5, rows): where each number starts
    for k, column in enumerate(columns):
        numbers = np.ascontiguousarray(np.asarray(column)[rows], dtype=">f8").view(np.uint8).reshape(len(rows), 8)
        body[places[k][:, None] + _BYTE] = numbers
    return out
