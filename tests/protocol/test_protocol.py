"""The wire contract: names, keys, codec (MessagePack and JSON), errors."""

from __future__ import annotations

import math

import msgspec
import numpy as np
import pytest

from protocol import (
    ErrorCode,
    FleetError,
    Keys,
    LaserScan,
    Odometry,
    Quaternion,
    SpawnRequest,
    Time,
    Twist,
    check_name,
    decode,
    encode,
)


@pytest.mark.parametrize("name", ["tb3_0", "TB3_1", "a", "robot_with_64_chars_" + "x" * 44])
def test_valid_names(name: str) -> None:
    assert check_name(name) == name


@pytest.mark.parametrize(
    ("name", "code", "fragment"),
    [
        ("", ErrorCode.INVALID_NAME, "empty"),
        ("a/b", ErrorCode.INVALID_NAME, "'/'"),
        ("a*", ErrorCode.INVALID_NAME, "'*'"),
        ("a$", ErrorCode.INVALID_NAME, "'$'"),
        ("a?", ErrorCode.INVALID_NAME, "'?'"),
        ("a#", ErrorCode.INVALID_NAME, "'#'"),
        ("a b", ErrorCode.INVALID_NAME, "' '"),
        ("robé", ErrorCode.INVALID_NAME, "'é'"),
        ("机器人", ErrorCode.INVALID_NAME, "'机'"),
        ("0abc", ErrorCode.INVALID_NAME, "start with a letter"),
        ("_abc", ErrorCode.INVALID_NAME, "start with a letter"),
        ("x" * 65, ErrorCode.INVALID_NAME, "65 characters"),
        ("spawn", ErrorCode.RESERVED_NAME, "reserved"),
        ("sim", ErrorCode.RESERVED_NAME, "reserved"),
        ("cmd_vel", ErrorCode.RESERVED_NAME, "reserved"),
        ("scans", ErrorCode.RESERVED_NAME, "reserved"),
    ],
)
def test_invalid_names(name: str, code: ErrorCode, fragment: str) -> None:
    with pytest.raises(FleetError) as e:
        check_name(name)
    assert e.value.code is code
    assert fragment in e.value.message


def test_keys() -> None:
    k = Keys("fleet")
    assert k.spawn == "fleet/spawn"
    assert k.step == "fleet/sim/step"
    assert k.odom("tb3_0") == "fleet/tb3_0/odom"
    assert k.namespace_of("fleet/tb3_0/cmd_vel") == "tb3_0"
    assert k.namespace_of("fleet/a/b/cmd_vel") is None
    assert k.namespace_of("other/tb3_0/cmd_vel") is None
    assert Keys("sim_a/fleet").spawn == "sim_a/fleet/spawn"
    with pytest.raises(ValueError):
        Keys("bad prefix")
    with pytest.raises(ValueError):
        Keys("a//b")


def test_spawn_request_decodes_json_and_msgpack() -> None:
    js = b'{"name": "tb3_0", "x": -2, "y": -0.5}'
    req = decode(js, SpawnRequest)
    assert (req.name, req.x, req.y, req.yaw, req.model, req.namespace) == (
        "tb3_0",
        -2.0,
        -0.5,
        0.0,
        "burger",
        None,
    )
    assert decode(encode(req), SpawnRequest) == req
    # leading whitespace and a trailing newline (zenoh-cli keeps it) are fine
    assert decode(b"  \n" + js + b"\n", SpawnRequest) == req
    # unknown fields are ignored (forward compatibility)
    assert decode(b'{"name": "a", "z": 0.01, "future": [1]}', SpawnRequest).name == "a"


@pytest.mark.parametrize(
    ("payload", "field"),
    [
        (b"garbage", None),
        (b"{", None),
        (b"{}", "name"),
        (b'{"name": 5}', "name"),
        (b'{"name": "a", "x": "1"}', "x"),
        (b'{"name": "a", "x": null}', "x"),
        (b'{"name": "a", "model": 3}', "model"),
        (b"[1, 2, 3]", None),
        (b"\xc1\xff\x00", None),
        (msgspec.msgpack.encode([1, 2]), None),
        (msgspec.msgpack.encode({"name": ["x"]}), "name"),
    ],
)
def test_malformed_spawn_requests(payload: bytes, field: str | None) -> None:
    with pytest.raises(FleetError) as e:
        decode(payload, SpawnRequest)
    assert e.value.code is ErrorCode.MALFORMED
    if field:
        assert e.value.field == field


def test_twist_json_partial_fields() -> None:
    t = decode(b'{"linear": {"x": 0.1}, "angular": {"z": 0.5}}', Twist)
    assert (t.linear.x, t.linear.y, t.angular.z) == (0.1, 0.0, 0.5)
    assert decode(b"", Twist).linear.x == 0.0


def test_messages_are_maps_on_the_wire() -> None:
    odom = Odometry(child_frame_id="tb3_0/base_footprint")
    raw = msgspec.msgpack.decode(encode(odom))
    assert isinstance(raw, dict)
    assert raw["child_frame_id"] == "tb3_0/base_footprint"
    assert set(raw["pose"]) == {"pose", "covariance"}


def test_scan_ranges_roundtrip_float32() -> None:
    r = np.array([0.5, np.inf, 3.25], dtype="<f4")
    scan = decode(encode(LaserScan(ranges=r.tobytes())), LaserScan)
    assert np.array_equal(scan.ranges_array(), r)


def test_time_and_quaternion() -> None:
    t = Time.from_seconds(1.5)
    assert (t.sec, t.nanosec) == (1, 500_000_000)
    assert t.to_seconds() == 1.5
    for yaw in (-3.0, -1.0, 0.0, 0.7, 3.1):
        assert math.isclose(Quaternion.from_yaw(yaw).yaw(), yaw, abs_tol=1e-12)


def test_error_reply_roundtrip() -> None:
    err = FleetError(ErrorCode.COLLISION, "overlaps", "x")
    back = FleetError.from_reply(decode(encode(err.to_reply(), "json"), type(err.to_reply())))
    assert (back.code, back.message, back.field) == (ErrorCode.COLLISION, "overlaps", "x")
    assert str(back) == "collision: overlaps"


class _ClockBeforeOverload(msgspec.Struct, kw_only=True):
    """``Clock`` as a client built before the lag and capacity fields has it."""

    clock: Time
    tick: int
    dt: float
    paused: bool
    lockstep: bool
    real_time_factor: float
    target_real_time_factor: float
    robots: int
    dropped_commands: int = 0


@pytest.mark.parametrize("fmt", ["msgpack", "json"])
def test_the_clocks_lag_and_capacity_fields_keep_old_and_new_peers_reading_each_other(fmt: str) -> None:
    from protocol.control import Clock

    new = Clock(clock=Time(sec=2), tick=60, dt=1 / 30, paused=False, lockstep=False, real_time_factor=0.5,
                target_real_time_factor=1.0, robots=3, behind_s=1.5, falling_behind=True, tick_s=0.07,
                capacity_robots=40)  # fmt: skip
    old = _ClockBeforeOverload(**{f: getattr(new, f) for f in _ClockBeforeOverload.__struct_fields__})
    codec = (
        (msgspec.msgpack.encode, msgspec.msgpack.decode)
        if fmt == "msgpack"
        else (msgspec.json.encode, msgspec.json.decode)
    )
    assert codec[1](codec[0](new), type=_ClockBeforeOverload) == old  # an old client reads a new daemon
    from_old = codec[1](codec[0](old), type=Clock)  # a new client reads an old daemon: nothing said, nothing behind
    assert (from_old.behind_s, from_old.falling_behind, from_old.tick_s, from_old.capacity_robots) == (
        0.0,
        False,
        0.0,
        0,
    )
