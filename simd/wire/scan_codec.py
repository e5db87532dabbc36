"""LaserScan messages for a batch of scans, from byte templates.

A scan is ~1.5 kB of MessagePack of which only the stamp and the 1 440 bytes of ranges change:
the frame name, the angles and the limits are the same forever. Building a ``LaserScan``
struct per scan and encoding it costs ~3 us; here each robot gets its bytes around the stamp
and the ranges once (encoded by msgspec, so the result is exactly what msgspec would produce),
and each scan is one join of five pieces. ``convert.encode_scans`` is the reference the tests
compare with.
"""

from __future__ import annotations

import msgspec
import numpy as np

from fleetcommon.arrays import F32
from protocol.messages import Header, LaserScan, Time
from simd.core.lidar import LidarSpec

_ZERO_STAMP = msgspec.msgpack.encode(Time())
_encoder = msgspec.msgpack.Encoder()


class ScanEncoder:
    """Encodes the scans of one tick; templates are kept per namespace, for one lidar spec."""

    def __init__(self, spec: LidarSpec) -> None:
        self._spec = spec
        self._width = 4 * spec.samples  # bytes of ranges per scan
        self._parts: dict[str, tuple[bytes, bytes, bytes]] = {}  # ns -> before stamp, stamp..ranges, after

    def forget(self, ns: str) -> None:
        self._parts.pop(ns, None)

    def _template(self, ns: str) -> tuple[bytes, bytes, bytes]:
        s = self._spec

        def encoded(fill: int) -> bytes:
            return _encoder.encode(
                LaserScan(
                    header=Header(stamp=Time(), frame_id=f"{ns}/base_scan"),
                    angle_min=s.angle_min,
                    angle_max=s.angle_max,
                    angle_increment=s.angle_increment,
                    range_min=s.range_min,
                    range_max=s.range_max,
                    ranges=bytes([fill]) * self._width,
                )
            )

        low, high = encoded(0x00), encoded(0xFF)
        # the ranges are where the two encodings differ; the stamp is the header's first field
        start = next(i for i, (a, b) in enumerate(zip(low, high, strict=True)) if a != b)
        end = start + self._width
        cut = low.index(_ZERO_STAMP)
        assert cut < start and low[end:] == high[end:]
        parts = (low[:cut], low[cut + len(_ZERO_STAMP) : start], low[end:])
        self._parts[ns] = parts
        return parts

    def encode(self, namespaces: list[str], time: float, scans: F32) -> list[bytes]:
        """One MessagePack LaserScan per row of ``scans``, in ``namespaces`` order."""
        if not namespaces:
            return []
        stamp = _encoder.encode(Time.from_seconds(time))
        data = np.ascontiguousarray(scans, dtype="<f4").reshape(-1).data.cast("B")
        w = self._width
        if len(data) != w * len(namespaces):
            raise ValueError(f"{len(namespaces)} namespaces for {len(data) // 4} ranges of {w // 4} samples")
        parts = self._parts
        out = []
        for i, ns in enumerate(namespaces):
            head, mid, tail = parts.get(ns) or self._template(ns)
            out.append(b"".join((head, stamp, mid, data[i * w : (i + 1) * w], tail)))
        return out
