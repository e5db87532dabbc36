"""The robot list as MessagePack, from byte templates: the list of 8 000 robots in a few ms.

A ``RobotRecord`` is ~750 bytes of MessagePack of which five numbers change from one list to the
next (the pose and the twist); the name, the model's limits and footprint, the topics and the
frames are the robot's for life. Building 8 000 records and encoding them took ~60 ms with the
GIL held, on the thread that answers queries, and made 16 000 objects for the garbage collector
each time. Here each robot's record is encoded once (by msgspec, with markers in those five
places, as simd/wire/odom_codec.py does for odometry), the records of the fleet are laid end to
end once per fleet change, and each list copies that buffer and writes the five float64 numbers
of every robot into it with one numpy scatter per field. msgspec encodes a float as a
MessagePack float64 (0xcb and 8 big-endian bytes), so the bytes are exactly what encoding the
``RobotList`` struct gives (tested).
"""

from __future__ import annotations

import threading

import msgspec
import numpy as np
import numpy.typing as npt

from fleetcommon.arrays import F64
from protocol.control import Pose2D, RobotList, RobotRecord
from protocol.messages import Time

_encoder = msgspec.msgpack.Encoder()
#: Values that cannot occur in real data, one per patched field: pose x, y, yaw, linear, angular.
_MARKERS = tuple(-1.2345678912345e-301 * (k + 1) for k in range(5))


def _template(record: RobotRecord) -> tuple[bytes, npt.NDArray[np.int64]]:
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
    return raw, np.asarray(offsets, dtype=np.int64)


def _array_header(n: int) -> bytes:
    """A MessagePack array header of ``n`` items, as msgspec writes it (the shortest form)."""
    if n < 16:
        return bytes([0x90 | n])
    if n < 1 << 16:
        return b"\xdc" + n.to_bytes(2, "big")
    return b"\xdd" + n.to_bytes(4, "big")


class RobotListEncoder:
    """Encodes ``RobotList`` messages of the fleet's records with the pose and twist of now
    (any thread: one list is built at a time)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._templates: dict[str, tuple[RobotRecord, bytes, npt.NDArray[np.int64]]] = {}
        self._layout: list[RobotRecord] | None = None  # the list of records laid out in the buffer
        self._buffer = np.zeros(0, dtype=np.uint8)
        self._index = np.zeros((5, 0), dtype=np.int64)  # per field: where each record's number starts

    def encode(self, time: float, records: list[RobotRecord], x: F64, y: F64, yaw: F64, linear: F64,
               angular: F64) -> bytes:  # fmt: skip
        """The MessagePack of ``RobotList(stamp=time, robots=records)`` with row ``k``'s pose
        and twist put into ``records[k]``. ``records`` is laid out again whenever it is another
        list than the last one: the caller makes a new list when the fleet changes."""
        n = len(records)
        columns = (x, y, yaw, linear, angular)
        if any(len(c) != n for c in columns):
            raise ValueError(f"{n} records for columns of {[len(c) for c in columns]} values")
        head = _encoder.encode(RobotList(stamp=Time.from_seconds(time), robots=[]))
        if not head.endswith(b"\x90"):  # robots, the last field, is empty: a fixarray of 0
            raise ValueError("a RobotList does not end with its robots")
        with self._lock:
            if records is not self._layout:
                self._lay_out(records)
            out = self._buffer.copy()
            index = self._index
        for k, column in enumerate(columns):
            numbers = np.ascontiguousarray(column, dtype=">f8").view(np.uint8).reshape(n, 8)
            out[index[k][:, None] + np.arange(8)] = numbers
        return head[:-1] + _array_header(n) + out.tobytes()

    def _lay_out(self, records: list[RobotRecord]) -> None:
        parts, starts, offsets = [], [], []
        pos = 0
        kept: dict[str, tuple[RobotRecord, bytes, npt.NDArray[np.int64]]] = {}
        for record in records:
            known = self._templates.get(record.namespace)
            if known is None or known[0] is not record:
                raw, offs = _template(record)
                known = (record, raw, offs)
            kept[record.namespace] = known
            parts.append(known[1])
            offsets.append(known[2])
            starts.append(pos)
            pos += len(known[1])
        self._templates = kept  # robots gone are forgotten with the layout that had them
        self._buffer = np.frombuffer(b"".join(parts), dtype=np.uint8).copy()
        where = np.asarray(starts, dtype=np.int64)[:, None] + np.asarray(offsets, dtype=np.int64).reshape(-1, 5)
        self._index = np.ascontiguousarray(where.T)
        self._layout = records
