"""The template scan encoder must produce exactly what msgspec produces."""

from __future__ import annotations

import msgspec
import numpy as np
import pytest

from protocol.messages import LaserScan
from simd.core.lidar import LidarSpec
from simd.core.snapshot import TickSnapshot
from simd.wire import convert
from simd.wire.scan_codec import ScanEncoder


def reference(names: list[str], t: float, scans: np.ndarray, spec: LidarSpec) -> list[bytes]:
    z = np.zeros(0)
    out = TickSnapshot(
        tick=0, time=t, namespaces=[], x=z, y=z, yaw=z, linear_x=z, linear_y=z, angular_z=z,
        scan_namespaces=names, scan_rows=scans,
    )  # fmt: skip
    return convert.encode_scans(out, spec)


@pytest.mark.parametrize("spec", [LidarSpec(), LidarSpec(samples=7, range_max=12.0)], ids=["lds01", "custom"])
def test_template_encoding_is_byte_identical_to_msgspec(spec: LidarSpec) -> None:
    enc = ScanEncoder(spec)
    rng = np.random.default_rng(2)
    names = ["a", "TB3_1", "robot_with_a_much_longer_namespace_than_usual" * 3]
    for t in (0.0, 1 / 30, 12.345, 86400.5, 4e9):
        scans = rng.uniform(0.1, spec.range_max, (len(names), spec.samples)).astype(np.float32)
        scans[0, :3] = [np.inf, -np.inf, np.nan]
        out = enc.encode(names, t, scans)
        assert out == reference(names, t, scans, spec)
        msg = msgspec.msgpack.decode(out[1], type=LaserScan)
        assert msg.header.frame_id == "TB3_1/base_scan"
        assert np.array_equal(msg.ranges_array(), scans[1])


def test_subsets_forget_and_bad_shapes() -> None:
    spec = LidarSpec()
    enc = ScanEncoder(spec)
    scans = np.full((2, spec.samples), 1.5, dtype=np.float32)
    assert enc.encode([], 1.0, scans[:0]) == []
    assert enc.encode(["b", "a"], 2.0, scans) == reference(["b", "a"], 2.0, scans, spec)
    enc.forget("a")
    assert enc.encode(["a"], 3.0, scans[:1]) == reference(["a"], 3.0, scans[:1], spec)
    with pytest.raises(ValueError, match="namespaces"):
        enc.encode(["a", "b", "c"], 1.0, scans)
