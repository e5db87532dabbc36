"""Odometry for the whole fleet in one vectorised pass.

An ``Odometry`` message is ~1.1 kB of MessagePack of which only seven float64 numbers and
the stamp change from tick to tick: the frame names and the two 36-entry covariances are the
same forever. Building and encoding a struct per robot per tick costs ~11 us; here each robot
gets a byte template once (encoded by msgspec, so the bytes are exactly what msgspec would
produce), and each tick writes the new numbers into all templates with one numpy scatter.
msgspec always encodes a float as MessagePack float64 (0xcb + 8 big-endian bytes), so the
numbers sit at fixed offsets; the stamp's integers vary in size, so the stamp is encoded once
per tick and spliced between the two halves of each template.

The per-robot copies are done by the compiled ``simd.wire._odompack`` when it is built (one pass,
~0.2 us a robot instead of ~2 us); the numpy scatter below is the reference it is tested
against, and the fallback.
"""

from __future__ import annotations

from collections.abc import Sequence

import msgspec
import numpy as np
import numpy.typing as npt

from fleetcommon.arrays import F64
from protocol.messages import Time
from simd.core import carry
from simd.core import native as _fast
from simd.wire.convert import odometry

_native, _why = _fast.load("odompack")  # None without a C compiler: the numpy path does the same


#: Distinct values that cannot occur in real data, one per patched field, in this order:
#: position.x, position.y, orientation.z, orientation.w, twist.linear.x, linear.y, angular.z
_SENTINELS = tuple(-1.2345678912345e-301 * (k + 1) for k in range(7))
_ZERO_STAMP = msgspec.msgpack.encode(Time())
_encoder = msgspec.msgpack.Encoder()


class _Template:
    __slots__ = ("head", "offsets", "tail")

    def __init__(self, ns: str) -> None:
        x, y, qz, qw, vx, vy, wz = _SENTINELS
        msg = odometry(ns, Time(), x, y, 0.0, vx, vy, wz)
        msg.pose.pose.orientation.z = qz
        msg.pose.pose.orientation.w = qw
        raw = _encoder.encode(msg)
        cut = raw.index(_ZERO_STAMP)
        self.head = raw[:cut]
        self.tail = raw[cut + len(_ZERO_STAMP) :]
        offsets = []
        for s in _SENTINELS:
            marker = b"\xcb" + np.array([s], dtype=">f8").tobytes()
            i = self.tail.index(marker)
            assert self.tail.count(marker) == 1
            offsets.append(i + 1)
        self.offsets = np.asarray(offsets, dtype=np.int64)


class OdometryEncoder:
    """Encodes one tick of odometry for every robot; templates are kept per namespace.

    The robots' tails lie in one buffer that outlives fleet changes: a spawned robot's tail is
    written after the others, a deleted one's is left where it was, and each robot's row says
    where its own is (``bounds``, ``offsets``). After a spawn or a delete the rows are carried
    over from the last layout by the namespaces' identities (simd/core/carry.py), in numpy
    (only the heads are listed again in Python), instead of a pass over the fleet that laid
    out and copied its ~20 MB of tails (at 20 000 robots
    that was ~9 % of the daemon's Python time under ``bench.overload``, which spawns and
    deletes a robot a round). The tails are copied into a new buffer only when its room runs
    out or when less than half of it is tails still in use (``carry.copy_needed``, as the robot
    list's records).
    """

    def __init__(self, native: bool | None = None) -> None:
        """``native``: use the compiled packer (default: when it is built)."""
        if native and _native is None:
            raise RuntimeError(f"the compiled odometry packer is not available: {_why}")
        self.native = _native is not None if native is None else native
        self._templates: dict[str, _Template] = {}
        # the layout, held: the identities of its namespaces stay theirs while it is
        self._layout: list[str] = []
        self._ids = np.zeros(0, dtype=np.uint64)
        self._heads: list[bytes] = []
        self._buffer = np.zeros(0, dtype=np.uint8)
        self._used = 0  # bytes of the buffer written; the rest is room for new tails
        self._bounds = np.zeros((0, 2), dtype=np.int64)  # each row's tail in the buffer
        self._offsets = np.zeros((0, 7), dtype=np.int64)  # where each row's seven numbers start

    def forget(self, ns: str) -> None:
        self._templates.pop(ns, None)

    def _template(self, ns: str) -> _Template:
        t = self._templates.get(ns)
        if t is None:
            t = self._templates[ns] = _Template(ns)
        return t

    def _relayout(self, namespaces: list[str]) -> None:
        """Rows for ``namespaces``: the last layout's carried over, new tails written after."""
        ids = carry.identities(namespaces)
        source = carry.positions(self._ids, ids)
        found = source >= 0
        n = len(namespaces)
        bounds = np.zeros((n, 2), dtype=np.int64)
        offsets = np.zeros((n, 7), dtype=np.int64)
        bounds[found] = self._bounds[source[found]]
        offsets[found] = self._offsets[source[found]]
        old_heads = self._heads
        heads = [old_heads[k] if k >= 0 else b"" for k in source.tolist()]
        fresh = [(k, self._template(namespaces[k])) for k in np.flatnonzero(~found).tolist()]
        need = sum(len(t.tail) for _, t in fresh)
        kept = int((bounds[found, 1] - bounds[found, 0]).sum())
        buffer, used = self._buffer, self._used
        if carry.copy_needed(used, need, len(buffer), kept):
            buffer = _compact(buffer, bounds, offsets, found, kept + need)
            used = kept
        for k, t in fresh:
            size = len(t.tail)
            buffer[used : used + size] = np.frombuffer(t.tail, dtype=np.uint8)
            bounds[k] = (used, used + size)
            offsets[k] = used + t.offsets
            heads[k] = t.head
            used += size
        self._layout, self._ids, self._heads = list(namespaces), ids, heads
        self._buffer, self._used, self._bounds, self._offsets = buffer, used, bounds, offsets

    def encode(
        self,
        namespaces: list[str],
        time: float,
        x: F64,
        y: F64,
        yaw: F64,
        vx: F64,
        vy: F64,
        wz: F64,
        *,
        rows: Sequence[int] | None = None,
    ) -> list[bytes]:
        """MessagePack ``Odometry`` per robot, byte-identical to encoding the struct; with
        ``rows``, only those robots' (rows of ``namespaces`` and of the columns), in that order:
        the others' would not be sent."""
        if namespaces != self._layout:
            self._relayout(namespaces)
        values = np.ascontiguousarray(
            np.stack([x, y, np.sin(yaw * 0.5), np.cos(yaw * 0.5), vx, vy, wz], axis=1), dtype=np.float64
        ).reshape(-1, 7)
        heads, bounds, offsets = self._heads, self._bounds, self._offsets
        if rows is not None:
            pick = np.asarray(rows, dtype=np.int64)
            heads = [heads[i] for i in rows]
            bounds, offsets, values = bounds[pick], offsets[pick], values[pick]
        if not heads:
            return []
        stamp = _encoder.encode(Time.from_seconds(time))
        if self.native:
            assert _native is not None
            packed: list[bytes] = _native.pack(heads, stamp, self._buffer, bounds, offsets, values)
            return packed
        # the reference: every number scattered into the buffer, then each robot's bytes sliced
        index = offsets[:, :, None] + np.arange(8, dtype=np.int64)[None, None, :]
        self._buffer[index] = values.astype(">f8").view(np.uint8).reshape(len(heads), 7, 8)
        buf = self._buffer.tobytes()
        return [h + stamp + buf[a:b] for h, (a, b) in zip(heads, bounds.tolist(), strict=True)]


def _compact(
    buffer: npt.NDArray[np.uint8], bounds: npt.NDArray[np.int64], offsets: npt.NDArray[np.int64],
    found: npt.NDArray[np.bool_], need: int,
) -> npt.NDArray[np.uint8]:  # fmt: skip
    """A new buffer with the ``found`` rows' tails in row order at its start and room after them
    (``carry.room_for`` of ``need`` bytes); those rows' ``bounds`` and ``offsets`` are moved with
    them, in place."""
    rows = np.flatnonzero(found)
    starts, ends = bounds[rows, 0], bounds[rows, 1]
    sizes = ends - starts
    new_starts = np.zeros(len(rows), dtype=np.int64)
    np.cumsum(sizes[:-1], out=new_starts[1:])
    total = int(sizes.sum())
    out = np.empty(carry.room_for(need), dtype=np.uint8)
    # every kept byte's place in the old buffer, row after row, in one gather
    out[:total] = buffer[np.repeat(starts - new_starts, sizes) + np.arange(total, dtype=np.int64)]
    shift = new_starts - starts
    bounds[rows] += shift[:, None]
    offsets[rows] += shift[:, None]
    return out
