"""The fleet topics ``P/odometry`` and ``P/scans``: one message a tick for the whole fleet.

They must say exactly what the per-robot topics say for the same tick, follow the fleet as
robots come and go, and cost nothing while nobody listens.
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import msgspec
import numpy as np
import pytest
import zenoh

from clients import wait_until
from protocol import FleetOdometry, FleetScans, Keys, LaserScan, Odometry, SpawnRequest
from simd.adapters.fleet.bridge import Bridge
from simd.core.lidar import LidarSpec
from simd.core.sim import Simulation
from simd.core.worldfile import load_world
from simd.daemon import Daemon as SimDaemon
from simd.wire.fleet_codec import encode_fleet_odometry, encode_fleet_scans
from tests.conftest import Daemon, free_port
from tests.zraw import client_config, get

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
        time.sleep(0.1)
        for received in (fleet_odom, fleet_scan, odom, scans):
            received.clear()
        for k in range(12):
            c.step(1, cmd_vel={n: (0.2, 0.8 * math.sin(k + i)) for i, n in enumerate(names)})
        assert wait_until(lambda: len(fleet_odom) == 12 and len(odom) == 36 and len(scans) == 6, 3.0)
        assert wait_until(lambda: len(fleet_scan) >= 2, 1.0)

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
        bridge = Bridge(daemon_side, Keys())
        try:
            assert not bridge.wants_fleet_odom() and not bridge.wants_fleet_scan()
            with zenoh.open(client_config(f"tcp/127.0.0.1:{port}")) as user:
                sub = user.declare_subscriber("fleet/odometry", lambda s: None)
                assert wait_until(bridge.wants_fleet_odom, 3.0)
                assert not bridge.wants_fleet_scan()  # only what is asked for
                per_robot = user.declare_subscriber("fleet/*/odom", lambda s: None)
                sub.undeclare()
                assert wait_until(lambda: not bridge.wants_fleet_odom(), 3.0)  # P/*/odom is not P/odom
                per_robot.undeclare()
        finally:
            bridge.close()


# -- the daemon's own tick, in-process, with requests landing between its step and publishing --


@contextmanager
def in_process_daemon(names: list[str]) -> Iterator[tuple[SimDaemon, str]]:
    """The daemon's loop object on a real zenoh session, ticked by the test itself, so that a
    request can be made to land exactly between a tick's step and its publishing."""
    port = free_port()
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    sim = Simulation(load_world("empty"))
    with zenoh.open(conf) as session:
        keys = Keys()
        bridge = Bridge(session, keys)
        daemon = SimDaemon(sim, bridge, keys, rtf=0.0)
        for i, n in enumerate(names):
            sim.spawn(SpawnRequest(name=n, x=-3.0 + i, y=0.0))
            bridge.add_robot(n)
        try:
            yield daemon, f"tcp/127.0.0.1:{port}"
        finally:
            bridge.close()


def _queue(daemon: SimDaemon, user: zenoh.Session, selector: str, body: object | None = None) -> threading.Thread:
    """Send a request from a client session and wait until it sits in the daemon's queue
    (its reply comes when the daemon serves it)."""
    before = daemon.bridge.requests.qsize()
    payload = json.dumps(body).encode() if body is not None else None
    t = threading.Thread(target=get, args=(user, selector, payload, 5.0), daemon=True)
    t.start()
    assert wait_until(lambda: daemon.bridge.requests.qsize() == before + 1, 3.0)
    return t


def _warm_up(daemon: SimDaemon, *received: list[Any]) -> None:
    """Tick until every subscriber has received something (a subscription reaches the daemon
    some milliseconds after it is declared), then forget what they received."""
    deadline = time.monotonic() + 5.0
    while not all(received):
        assert time.monotonic() < deadline, "the subscribers received nothing"
        daemon.tick()
        time.sleep(0.02)
    time.sleep(0.1)
    for r in received:
        r.clear()


def test_a_robot_deleted_mid_tick_leaves_both_views_of_that_tick() -> None:
    with in_process_daemon(["a", "b", "c"]) as (daemon, endpoint), zenoh.open(client_config(endpoint)) as user:
        fleet: list[bytes] = []
        robots: list[str] = []
        _collect(user, "fleet/odometry", fleet, threading.Lock())
        user.declare_subscriber("fleet/*/odom", lambda s: robots.append(str(s.key_expr)))
        _warm_up(daemon, fleet, robots)
        t = _queue(daemon, user, "fleet/delete", {"name": "b"})
        daemon.tick(serve_between=True)  # steps a, b, c; serves the delete; publishes
        t.join(5.0)
        assert wait_until(lambda: len(fleet) == 1 and len(robots) == 2, 2.0)
        time.sleep(0.1)
        last = msgspec.msgpack.decode(fleet[-1], type=FleetOdometry)
        assert last.namespaces == ["a", "c"] and last.array("x").tolist() == [-3.0, -1.0]
        assert sorted(robots) == ["fleet/a/odom", "fleet/c/odom"] and len(fleet) == 1


def test_a_tick_made_stale_by_a_reset_and_steps_is_published_by_neither_view() -> None:
    """Pause, reset and step k served between a tick's step and its publishing, with k such
    that the tick count comes back to the stale tick's own: its measurements must not go out."""
    with in_process_daemon(["a"]) as (daemon, endpoint), zenoh.open(client_config(endpoint)) as user:
        fleet: list[bytes] = []
        _collect(user, "fleet/odometry", fleet, threading.Lock())
        stamps: list[float] = []
        dec = msgspec.msgpack.Decoder(Odometry)
        user.declare_subscriber(
            "fleet/a/odom", lambda s: stamps.append(dec.decode(s.payload.to_bytes()).header.stamp.to_seconds())
        )
        daemon.sim.command_many({"a": (0.2, 0.0)})
        _warm_up(daemon, fleet, stamps)
        k = daemon.sim.tick
        daemon.tick(serve_between=True)  # tick k + 1
        threads = [
            _queue(daemon, user, "fleet/sim/pause"),
            _queue(daemon, user, "fleet/sim/reset"),
            _queue(daemon, user, "fleet/sim/step", {"ticks": k + 2}),
        ]
        daemon.tick(serve_between=True)  # tick k + 2, then: pause, reset, ticks 1 .. k + 2 again
        for t in threads:
            t.join(5.0)
        assert daemon.sim.tick == k + 2
        time.sleep(0.3)
        expected = [k + 1, *range(1, k + 3)]
        fleet_ticks = [round(msgspec.msgpack.decode(d, type=FleetOdometry).stamp.to_seconds() * 30) for d in fleet]
        assert fleet_ticks == expected
        assert [round(t * 30) for t in stamps if t > 0] == expected  # (the reset re-publishes the spawn pose at 0)


def test_the_daemon_builds_fleet_messages_only_while_somebody_subscribes() -> None:
    with in_process_daemon(["a", "b"]) as (daemon, endpoint):
        for _ in range(12):
            daemon.tick()
        assert daemon.fleet_messages == 0
        with zenoh.open(client_config(endpoint)) as user:
            got: list[bytes] = []
            _collect(user, "fleet/scans", got, threading.Lock())
            assert wait_until(daemon.bridge.wants_fleet_scan, 3.0)
            for _ in range(12):  # two 5 Hz periods: both robots scan twice
                daemon.tick()
            assert daemon.fleet_messages == 2  # scans only: nobody asked for P/odometry
            assert wait_until(lambda: len(got) >= 1, 2.0)  # (the first may race the subscription)
        assert wait_until(lambda: not daemon.bridge.wants_fleet_scan(), 3.0)
        for _ in range(12):
            daemon.tick()
        assert daemon.fleet_messages == 2
