"""The template odometry encoder must produce exactly what msgspec produces."""

from __future__ import annotations

import msgspec
import numpy as np
import pytest

from protocol import Odometry, Time
from simd.wire import odom_codec
from simd.wire.convert import odometry
from simd.wire.odom_codec import OdometryEncoder

PATHS = [
    pytest.param(False, id="numpy"),
    pytest.param(
        True, id="native", marks=pytest.mark.skipif(odom_codec._native is None, reason="_odompack is not built")
    ),
]


@pytest.mark.parametrize("native", PATHS)
def test_template_encoding_is_byte_identical_to_msgspec(native: bool) -> None:
    enc = OdometryEncoder(native)
    rng = np.random.default_rng(1)
    names = ["a", "TB3_1", "robot_with_a_much_longer_namespace_than_usual"]
    for t in (0.0, 1 / 30, 12.345, 86400.5):
        cols = [rng.normal(scale=5, size=len(names)) for _ in range(6)]
        cols[2] = rng.uniform(-np.pi, np.pi, size=len(names))
        out = enc.encode(names, t, *cols)
        for i, ns in enumerate(names):
            ref = msgspec.msgpack.encode(odometry(ns, Time.from_seconds(t), *(float(c[i]) for c in cols)))
            assert out[i] == ref
            msg = msgspec.msgpack.decode(out[i], type=Odometry)
            assert msg.header.frame_id == f"{ns}/odom"
            assert (
                msg.pose.pose.orientation.yaw() == np.float64(cols[2][i]).item()
                or abs(msg.pose.pose.orientation.yaw() - cols[2][i]) < 1e-12
            )


@pytest.mark.parametrize("native", PATHS)
def test_layout_follows_spawns_and_deletes(native: bool) -> None:
    enc = OdometryEncoder(native)
    z = np.zeros(2)
    enc.encode(["a", "b"], 1.0, z, z, z, z, z, z)
    enc.forget("a")
    out = enc.encode(["b", "c"], 2.0, np.array([1.0, 2.0]), z, z, z, z, z)
    decoded = [msgspec.msgpack.decode(o, type=Odometry) for o in out]
    assert [d.header.frame_id for d in decoded] == ["b/odom", "c/odom"]
    assert [d.pose.pose.position.x for d in decoded] == [1.0, 2.0]
    assert enc.encode([], 3.0, *(np.zeros(0) for _ in range(6))) == []


@pytest.mark.parametrize("native", PATHS)
def test_appending_robots_matches_a_full_layout(native: bool) -> None:
    grown, fresh = OdometryEncoder(native), OdometryEncoder(native)
    names = [f"r{i}" for i in range(5)]
    z = np.zeros(5)
    grown.encode(names[:2], 0.5, z[:2], z[:2], z[:2], z[:2], z[:2], z[:2])
    grown.encode(names[:3], 0.6, z[:3], z[:3], z[:3], z[:3], z[:3], z[:3])
    vals = [np.arange(5.0) + k for k in range(6)]
    assert grown.encode(names, 0.7, *vals) == fresh.encode(names, 0.7, *vals)
