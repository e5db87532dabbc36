"""The fleet topics ``P/odometry`` and ``P/scans``: one message a tick for the whole fleet.

They must say exactly what the per-robot topics say for the same tick, follow the fleet as
robots come and go, and cost nothing while nobody listens.
"""

from __future__ import annotations

import json
import math
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import msgspec
import numpy as np
import pytest
import zenoh

from clients import wait_until
from protocol import FleetOdometry, FleetScans, Keys, LaserScan, Odometry, SpawnRequest
from simd.adapters.fleet.adapter import FleetAdapter
from simd.adapters.fleet.publisher import Publisher
from simd.core.lidar import LidarSpec
from simd.core.sim import Simulation
from simd.core.worldfile import load_world
from simd.engine import Engine
from simd.wire.fleet_codec import encode_fleet_odometry, encode_fleet_scans
from tests.conftest import Daemon, free_port
from tests.zraw import client_config, get, matching

# -- the messages ---------------------------------------------------------------------------


def test_fleet_odometry_round_trip_and_named_fields() -> None:
    rng = np.random.default_rng(3)
    cols = [rng.normal(size=4) for _ in range(6)]
    data = encode_fleet_odometry(["a", "b", "c", "d"], 12.5, *cols)
    msg = msgspec.msgpack.decode(data, type=FleetOdometry)
    assert msg.namespaces == ["a", "b", "c", "d"]
    assert msg.stamp.sec == 12 and msg.stamp.nanosec == 500_000_000
    for name, col in zip(("x", "y", "yaw", "linear_x", "linear_y", "angular_z"), cols, strict=True):
        assert msg.array(name).tolist() == col.tolist()  # to the bit
    # a map with named fields, readable without our structs (any language)
    raw = msgspec.msgpack.decode(data)
    assert set(raw) >= {"stamp", "namespaces", "x", "y", "yaw", "linear_x", "linear_y", "angular_z"}
    with pytest.raises(ValueError, match="no column 'z'"):
        msg.array("z")


def test_fleet_odometry_refuses_columns_of_another_length() -> None:
    a = np.zeros(3)
    with pytest.raises(ValueError, match="2 namespaces"):
        encode_fleet_odometry(["a", "b"], 0.0, a, a, a, a, a, a)


def test_fleet_scans_round_trip_and_shape_checks() -> None:
    spec = LidarSpec()
    rows = np.random.default_rng(1).uniform(0.12, 3.5, size=(3, spec.samples)).astype(np.float32)
    rows[1, 7] = np.inf
    msg = msgspec.msgpack.decode(encode_fleet_scans(spec, ["a", "b", "c"], 0.2, rows), type=FleetScans)
    assert msg.namespaces == ["a", "b", "c"] and msg.beams == spec.samples
    assert (msg.angle_min, msg.angle_max, msg.range_min, msg.range_max) == (
        spec.angle_min, spec.angle_max, spec.range_min, spec.range_max,
    )  # fmt: skip
    got = msg.ranges_array()
    assert got.shape == (3, spec.samples) and got.tobytes() == rows.tobytes()
    with pytest.raises(ValueError, match="2 namespaces"):
        encode_fleet_scans(spec, ["a", "b"], 0.2, rows)
    broken = msgspec.structs.replace(msg, beams=100)
    with pytest.raises(ValueError, match="rows of 100 beams"):
        broken.ranges_array()


# -- the daemon -----------------------------------------------------------------------------


def _collect(session: zenoh.Session, key: str, out: list[bytes], lock: threading.Lock) -> zenoh.Subscriber[None]:
    def on(sample: zenoh.Sample) -> None:
        with lock:
            out.append(sample.payload.to_bytes())

    return session.declare_subscriber(key, on)


def test_each_tick_of_the_fleet_topics_equals_the_robots_own_messages(
    daemon_factory: Callable[..., Daemon],
) -> None:
    d = daemon_factory("--lockstep", "--seed", "2")
    c = d.client()
    names = ["r0", "r1", "r2"]
    for i, n in enumerate(names):
        c.spawn(n, x=-2.0 + 1.2 * i, y=-0.5, model=("burger", "waffle", "waffle_pi")[i])
    lock = threading.Lock()
    fleet_odom: list[bytes] = []
    fleet_scan: list[bytes] = []
    odom: list[tuple[str, Odometry]] = []
    scans: list[tuple[str, LaserScan]] = []
    with zenoh.open(client_config(d.endpoint)) as s:
        _collect(s, "fleet/odometry", fleet_odom, lock)
        _collect(s, "fleet/scans", fleet_scan, lock)
        c.on_odom("*", lambda ns, m: odom.append((ns, m)))
        c.on_scan("*", lambda ns, m: scans.append((ns, m)))
        # a subscription reaches the daemon some milliseconds after it is declared: warm up
        assert wait_until(lambda: bool(c.step(6)) and bool(fleet_odom and fleet_scan and odom and scans), 5.0)
        start = c.clock().clock.to_seconds()
        for k in range(12):
            c.step(1, cmd_vel={n: (0.2, 0.8 * math.sin(k + i)) for i, n in enumerate(names)})

        def since_start() -> None:
            """Keep only what the 12 steps published (a warm-up message may still arrive)."""

            def stamp(data: bytes, type_: type[FleetOdometry] | type[FleetScans]) -> float:
                return msgspec.msgpack.decode(data, type=type_).stamp.to_seconds()

            with lock:
                fleet_odom[:] = [d for d in fleet_odom if stamp(d, FleetOdometry) > start]
                fleet_scan[:] = [d for d in fleet_scan if stamp(d, FleetScans) > start]
            odom[:] = [(ns, m) for ns, m in odom if m.header.stamp.to_seconds() > start]
            scans[:] = [(ns, m) for ns, m in scans if m.header.stamp.to_seconds() > start]

        def complete() -> bool:
            since_start()
            return len(fleet_odom) == 12 and len(odom) == 36 and len(scans) == 6 and len(fleet_scan) >= 2

        assert wait_until(complete, 5.0)

        by_stamp: dict[tuple[int, int, str], Odometry] = {
            (m.header.stamp.sec, m.header.stamp.nanosec, ns): m for ns, m in odom
        }
        moved = 0
        for data in fleet_odom:
            f = msgspec.msgpack.decode(data, type=FleetOdometry)
            assert sorted(f.namespaces) == names
            for i, ns in enumerate(f.namespaces):
                m = by_stamp[(f.stamp.sec, f.stamp.nanosec, ns)]
                p, tw = m.pose.pose, m.twist.twist
                assert f.array("x")[i] == p.position.x and f.array("y")[i] == p.position.y
                assert f.array("yaw")[i] == pytest.approx(p.orientation.yaw(), abs=1e-12)
                assert f.array("linear_x")[i] == tw.linear.x and f.array("linear_y")[i] == tw.linear.y
                assert f.array("angular_z")[i] == tw.angular.z
                moved += abs(tw.linear.x) > 0
        assert moved > 0  # the comparison saw robots in motion, not only zeros

        scan_by_stamp = {(m.header.stamp.sec, m.header.stamp.nanosec, ns): m for ns, m in scans}
        seen = 0
        for data in fleet_scan:
            fs = msgspec.msgpack.decode(data, type=FleetScans)
            rows = fs.ranges_array()
            for i, ns in enumerate(fs.namespaces):
                ms = scan_by_stamp[(fs.stamp.sec, fs.stamp.nanosec, ns)]
                assert rows[i].tobytes() == ms.ranges
                assert (fs.angle_increment, fs.range_max) == (ms.angle_increment, ms.range_max)
                seen += 1
        assert seen == 6  # every robot's scan of the 12 ticks (5 Hz of a 30 Hz tick: once each in 6)

        # a deleted robot leaves the next tick's message; a new one joins it
        c.delete("r1")
        c.spawn("late", x=-0.5, y=2.0)
        c.step(1)
        assert wait_until(lambda: len(fleet_odom) == 13, 2.0)
        last = msgspec.msgpack.decode(fleet_odom[-1], type=FleetOdometry)
        assert sorted(last.namespaces) == ["late", "r0", "r2"]
        assert last.array("x")[last.namespaces.index("late")] == -0.5


def test_client_api_follows_the_fleet(daemon: Daemon) -> None:
    c = daemon.client()
    c.spawn("tb3_0", -2.0, -0.5)
    c.spawn("tb3_1", 0.5, -2.0)
    f = c.wait_fleet_odom()
    assert sorted(f.namespaces) == ["tb3_0", "tb3_1"]
    i = f.namespaces.index("tb3_1")
    assert (f.array("x")[i], f.array("y")[i]) == pytest.approx((0.5, -2.0), abs=1e-3)
    got: list[FleetScans] = []
    with c.on_fleet_scans(got.append):
        assert wait_until(lambda: {ns for m in got for ns in m.namespaces} == {"tb3_0", "tb3_1"}, 2.0)
    rows = got[0].ranges_array()
    assert rows.shape == (len(got[0].namespaces), 360)
    assert np.all(np.isinf(rows) | ((rows >= 0.12) & (rows <= 3.5)))


def test_fleet_topics_are_built_only_while_somebody_subscribes() -> None:
    """The daemon asks zenoh whether anyone matches before encoding a fleet message."""
    port = free_port()
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", f'["tcp/127.0.0.1:{port}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    with zenoh.open(conf) as daemon_side:
        publisher = Publisher(daemon_side, Keys(), LidarSpec())
        try:
            assert not publisher.wants_fleet_odom() and not publisher.wants_fleet_scan()
            with zenoh.open(client_config(f"tcp/127.0.0.1:{port}")) as user:
                sub = user.declare_subscriber("fleet/odometry", lambda s: None)
                assert wait_until(publisher.wants_fleet_odom, 3.0)
                assert not publisher.wants_fleet_scan()  # only what is asked for
                per_robot = user.declare_subscriber("fleet/*/odom", lambda s: None)
                sub.undeclare()
                assert wait_until(lambda: not publisher.wants_fleet_odom(), 3.0)  # P/*/odom is not P/odom
                per_robot.undeclare()
        finally:
            publisher.close()


# -- the engine and the fleet adapter in-process, on a real zenoh session ----------------------


@contextmanager
def in_process_daemon(names: list[str], **engine_args: Any) -> Iterator[tuple[Engine, FleetAdapter, str]]:
    """The daemon's engine and adapter on a real zenoh session; the test ticks it itself, or
    runs its loop in a thread."""
    port = free_port()
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    sim = Simulation(load_world("empty"))
    with zenoh.open(conf) as session:
        engine = Engine(sim, **({"rtf": 0.0} | engine_args))
        adapter = FleetAdapter(session, Keys(), engine)
        for i, n in enumerate(names):
            engine.submit(SpawnRequest(name=n, x=-3.0 + i, y=0.0), lambda r: None)
        engine.serve_pending()
        try:
            yield engine, adapter, f"tcp/127.0.0.1:{port}"
        finally:
            adapter.close()


@contextmanager
def running(engine: Engine) -> Iterator[None]:
    """The engine's own loop in a thread, as in simd."""
    t = threading.Thread(target=engine.run, daemon=True)
    t.start()
    try:
        yield
    finally:
        engine.stop()
        t.join(5.0)


def _warm_up(engine: Engine, *received: list[Any]) -> int:
    """Tick until every subscriber has received something (a subscription reaches the daemon
    some milliseconds after it is declared); returns the last warm-up tick: what the test
    counts comes after it."""
    for _ in range(250):
        if all(received):
            break
        engine.tick()
        wait_until(lambda: all(received), 0.02)
    assert all(received), "the subscribers received nothing"
    return engine.sim.tick


def _ticks(fleet: list[bytes]) -> list[int]:
    return [round(msgspec.msgpack.decode(d, type=FleetOdometry).stamp.to_seconds() * 30) for d in fleet]


def test_a_robot_deleted_between_two_ticks_is_in_neither_view_of_the_second() -> None:
    with (
        in_process_daemon(["a", "b", "c"], lockstep=True) as (engine, _, endpoint),
        zenoh.open(client_config(endpoint)) as user,
    ):
        fleet: list[bytes] = []
        robots: list[tuple[str, int]] = []
        dec = msgspec.msgpack.Decoder(Odometry)
        _collect(user, "fleet/odometry", fleet, threading.Lock())

        def on_odom(s: zenoh.Sample) -> None:
            robots.append((str(s.key_expr), round(dec.decode(s.payload.to_bytes()).header.stamp.to_seconds() * 30)))

        user.declare_subscriber("fleet/*/odom", on_odom)
        warm = _warm_up(engine, fleet, robots)
        with running(engine):
            get(user, "fleet/delete", json.dumps({"name": "b"}).encode(), 5.0)
            get(user, "fleet/sim/step", b'{"ticks": 1}', 5.0)
            tick = warm + 1

            def of_the_tick() -> tuple[list[bytes], list[str]]:
                return [d for d, t in zip(fleet, _ticks(fleet), strict=True) if t == tick], sorted(
                    k for k, t in robots if t == tick
                )

            assert wait_until(lambda: len(of_the_tick()[0]) == 1 and len(of_the_tick()[1]) == 2, 2.0)
        fleet_msgs, robot_keys = of_the_tick()
        last = msgspec.msgpack.decode(fleet_msgs[0], type=FleetOdometry)
        assert last.namespaces == ["a", "c"] and last.array("x").tolist() == [-3.0, -1.0]
        assert robot_keys == ["fleet/a/odom", "fleet/c/odom"]


def test_after_a_reset_both_views_start_again_from_the_first_tick() -> None:
    """A running fleet paused, reset and stepped: no tick of before the reset is published
    after it, and both views count the new run's ticks from one."""
    with (
        in_process_daemon(["a"]) as (engine, _, endpoint),
        zenoh.open(client_config(endpoint)) as user,
    ):
        fleet: list[bytes] = []
        _collect(user, "fleet/odometry", fleet, threading.Lock())
        stamps: list[float] = []
        dec = msgspec.msgpack.Decoder(Odometry)
        user.declare_subscriber(
            "fleet/a/odom", lambda s: stamps.append(dec.decode(s.payload.to_bytes()).header.stamp.to_seconds())
        )
        engine.sim.command_many({"a": (0.2, 0.0)})
        _warm_up(engine, fleet, stamps)
        with running(engine):
            assert wait_until(lambda: len(fleet) > 20, 5.0)
            get(user, "fleet/sim/pause", None, 5.0)
            get(user, "fleet/sim/reset", None, 5.0)
            reply, err = get(user, "fleet/sim/step", b'{"ticks": 7}', 5.0)
        assert reply is not None and json.loads(reply)["ticks_run"] == 7, err
        # the reply came after the step's messages were put: wait for them to arrive
        assert wait_until(lambda: _ticks(fleet)[-7:] == list(range(1, 8)), 5.0), _ticks(fleet)[-7:]
        assert wait_until(lambda: [round(t * 30) for t in stamps][-7:] == list(range(1, 8)), 5.0)
        fleet_ticks = _ticks(fleet)
        robot_ticks = [round(t * 30) for t in stamps]
        for ticks in (fleet_ticks, robot_ticks):
            cut = len(ticks) - 7
            assert ticks[cut:] == list(range(1, 8)), ticks
            assert ticks[:cut] == list(range(ticks[0], ticks[0] + cut)), ticks  # before: no gap, no repeat


def test_the_daemon_builds_fleet_messages_only_while_somebody_subscribes() -> None:
    with in_process_daemon(["a", "b"]) as (engine, adapter, endpoint):
        for _ in range(12):
            engine.tick()
        assert adapter.outbox.flush()
        assert adapter.publisher.fleet_messages == 0
        with zenoh.open(client_config(endpoint)) as user:
            got: list[bytes] = []
            _collect(user, "fleet/scans", got, threading.Lock())
            assert wait_until(adapter.publisher.wants_fleet_scan, 3.0)
            for _ in range(12):  # two 5 Hz periods: both robots scan twice
                engine.tick()
            assert adapter.outbox.flush()
            assert adapter.publisher.fleet_messages == 2  # scans only: nobody asked for P/odometry
            assert wait_until(lambda: len(got) >= 1, 2.0)  # (the first may race the subscription)
        assert wait_until(lambda: not adapter.publisher.wants_fleet_scan(), 3.0)
        for _ in range(12):
            engine.tick()
        assert adapter.outbox.flush()
        assert adapter.publisher.fleet_messages == 2


def test_robots_own_messages_are_encoded_only_while_somebody_subscribes_and_gets_still_answer() -> None:
    with in_process_daemon(["a", "b"]) as (engine, adapter, endpoint), zenoh.open(client_config(endpoint)) as user:
        pub = adapter.publisher
        spawned = pub.odom_puts  # each robot's first odometry goes out at its spawn
        for _ in range(13):
            engine.tick()
        assert adapter.outbox.flush()
        assert pub.odom_puts == spawned  # nobody listens: nothing encoded, nothing put
        ok, _ = get(user, "fleet/a/odom")  # yet the latest is there, at the latest tick
        assert ok is not None and round(msgspec.msgpack.decode(ok, type=Odometry).header.stamp.to_seconds() * 30) == 13
        ok, _ = get(user, "fleet/b/scan")
        assert ok is not None and len(msgspec.msgpack.decode(ok, type=LaserScan).ranges_array()) == 360
        got: list[bytes] = []
        _collect(user, "fleet/a/odom", got, threading.Lock())
        assert wait_until(lambda: matching(pub._odom_probe), 3.0)
        _warm_up(engine, got)
        engine.tick()
        tick = engine.sim.tick

        def latest_tick() -> int:
            return round(msgspec.msgpack.decode(got[-1], type=Odometry).header.stamp.to_seconds() * 30)

        assert adapter.outbox.flush() and wait_until(lambda: latest_tick() == tick, 2.0)  # this tick's message too
        assert pub.odom_puts > spawned
        ok, _ = get(user, "fleet/a/odom")
        assert ok == got[-1]  # a get answers the bytes the topic carried
