"""The template odometry encoder must produce exactly what msgspec produces."""

from __future__ import annotations

import msgspec
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

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


def _reference(names: list[str], t: float, cols: list[np.ndarray]) -> list[bytes]:
    return [
        msgspec.msgpack.encode(odometry(ns, Time.from_seconds(t), *(float(c[i]) for c in cols)))
        for i, ns in enumerate(names)
    ]


#: One change of the fleet: ("spawn", k) appends k new robots, ("delete", i) takes out the robot
#: at i (modulo the fleet), ("again", i) gives the robot at i a namespace string that is equal
#: but another object (as a fleet restored from a file has), ("back", k) spawns a deleted name.
CHANGES = st.lists(
    st.tuples(st.sampled_from(["spawn", "delete", "again", "back"]), st.integers(0, 40)), min_size=1, max_size=30
)


@pytest.mark.parametrize("native", PATHS)
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(changes=CHANGES, subset=st.integers(0, 2**16))
def test_a_layout_carried_through_fleet_changes_encodes_what_msgspec_does(
    native: bool, changes: list[tuple[str, int]], subset: int
) -> None:
    enc = OdometryEncoder(native)
    rng = np.random.default_rng(subset)
    names = [f"r{i}" for i in range(3)]
    gone: list[str] = []
    made = 3
    for step, (kind, k) in enumerate(changes):
        if kind == "spawn":
            names = [*names, *(f"r{made + j}" for j in range(k % 5 + 1))]
            made += k % 5 + 1
        elif kind == "delete" and names:
            gone.append(names[k % len(names)])
            names = [n for j, n in enumerate(names) if j != k % len(names)]
        elif kind == "again" and names:
            names = list(names)
            names[k % len(names)] = "".join(list(names[k % len(names)]))  # equal, another object
        elif kind == "back" and gone:
            names = [*names, gone.pop(k % len(gone))]
        cols = [rng.normal(scale=4, size=len(names)) for _ in range(6)]
        t = 0.5 + step / 30
        want = _reference(names, t, cols)
        assert enc.encode(names, t, *cols) == want
        rows = [j for j in range(len(names)) if (subset >> (j % 16)) & 1][::-1]  # any rows, any order
        assert enc.encode(names, t, *cols, rows=rows) == [want[j] for j in rows]


@pytest.mark.parametrize("native", PATHS)
def test_tails_stay_in_one_buffer_until_its_room_runs_out_or_most_of_it_is_robots_gone(native: bool) -> None:
    enc = OdometryEncoder(native)
    z = np.zeros(4000)
    names = [f"robot_{i}" for i in range(1000)]
    enc.encode(names, 1.0, *[z[:1000]] * 6)
    buffer = enc._buffer
    room = len(buffer) - enc._used
    assert room >= len(buffer) // 5  # a quarter of what it holds, to spare
    enc.encode(names[:500] + names[501:], 1.1, *[z[:999]] * 6)  # a delete copies nothing
    assert enc._buffer is buffer
    grown = names + [f"new_{i}" for i in range(10)]
    enc.encode(grown, 1.2, *[z[: len(grown)]] * 6)  # a spawn writes after the others
    assert enc._buffer is buffer
    tail = int(enc._bounds[0, 1] - enc._bounds[0, 0])
    more = grown + [f"more_{i}" for i in range(room // tail + 1)]  # more than the room
    out = enc.encode(more, 1.3, *[z[: len(more)]] * 6)
    assert enc._buffer is not buffer
    assert out == _reference(more, 1.3, [z[: len(more)]] * 6)
    buffer = enc._buffer
    few = more[::3]  # two thirds gone: the rest is copied out, and the buffer shrinks
    cols = [np.arange(len(few), dtype=float) + c for c in range(6)]
    assert enc.encode(few, 1.4, *cols) == _reference(few, 1.4, cols)
    assert enc._buffer is not buffer and len(enc._buffer) < len(buffer)
