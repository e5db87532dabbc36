"""The real daemon process over real zenoh sessions: every key of the protocol."""

from __future__ import annotations

import itertools
import math
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import msgspec
import numpy as np
import pytest

from clients import FleetClient, wait_until
from protocol import ErrorCode, FleetError, LaserScan, Odometry
from protocol.control import RobotRecord, SpawnRequest
from tests.conftest import ROOT, Daemon, free_port, simd_command
from tests.zraw import Collector, get_json, matching, raw_session

MULTI = [(-2.0, -0.5), (0.5, -2.0), (2.0, 0.5), (-0.5, 2.0)]


def warm_up(c: FleetClient, *collectors: Collector) -> None:
    """Step until every collector has received something (a subscription reaches the daemon a
    few milliseconds after it is declared), then forget it: counts start from here."""
    for _ in range(300):
        if all(len(col) for col in collectors):
            break
        c.step(1)
    for col in collectors:
        col.clear()


def test_spawn_then_odom_every_tick_and_a_scan_every_sixth(daemon_factory: Callable[..., Daemon]) -> None:
    d = daemon_factory("--lockstep")
    c = d.client()
    with raw_session(d.endpoint) as s:
        odom = Collector(s, "fleet/tb3_0/odom")
        scan = Collector(s, "fleet/tb3_0/scan")
        rec = c.spawn("tb3_0", -2.0, -0.5)
        assert rec.topics is not None and rec.topics.odom == "fleet/tb3_0/odom"
        assert rec.frames is not None and rec.frames.base_scan == "tb3_0/base_scan"
        assert rec.limits is not None and rec.limits.max_linear_velocity == 0.22
        warm_up(c, odom, scan)
        start = c.clock().tick
        c.step(60)  # 2 s of sim time

        def ticks(col: Collector, type_: type[Odometry] | type[LaserScan]) -> list[int]:
            """The ticks of the messages received from this step on (a straggler of the
            warm-up carries an earlier stamp)."""
            with col.lock:
                raw = [p for _, p in col.samples]
            stamps = [round(msgspec.msgpack.decode(p, type=type_).header.stamp.to_seconds() * 30) for p in raw]
            return [t for t in stamps if t > start]

        # exactly 30 odometry and 5 scans per sim second, whatever the wall clock did
        assert wait_until(lambda: len(ticks(odom, Odometry)) == 60 and len(ticks(scan, LaserScan)) == 10, 5.0)
        assert ticks(odom, Odometry) == list(range(start + 1, start + 61))
        assert all(b - a == 6 for a, b in itertools.pairwise(ticks(scan, LaserScan)))
    o = msgspec.msgpack.decode(odom.samples[-1][1], type=Odometry)
    assert o.header.frame_id == "tb3_0/odom" and o.child_frame_id == "tb3_0/base_footprint"
    assert (o.pose.pose.position.x, o.pose.pose.position.y) == pytest.approx((-2.0, -0.5), abs=1e-6)
    assert o.pose.covariance[0] == 1e-5 and o.pose.covariance[35] == 1e-3 and o.pose.covariance[14] == 1e12
    sc = msgspec.msgpack.decode(scan.samples[-1][1], type=LaserScan)
    r = sc.ranges_array()
    assert r.shape == (360,) and r.dtype == np.float32
    assert sc.angle_max == 6.28 and sc.angle_increment == pytest.approx(6.28 / 359)
    assert sc.range_min == 0.12 and sc.range_max == 3.5
    assert sc.header.frame_id == "tb3_0/base_scan"
    finite = r[np.isfinite(r)]
    assert len(finite) > 50 and finite.min() >= 0.12 and finite.max() <= 3.5


def test_the_first_odometry_needs_no_tick(daemon_factory: Callable[..., Daemon]) -> None:
    """A spawn reply means the robot has published: even a daemon that never ticks (lockstep)
    has put its first odometry by then."""
    d = daemon_factory("--lockstep")
    c = d.client()
    got: list[Odometry] = []
    c.on_odom("tb3_0", lambda ns, m: got.append(m))
    c.spawn("tb3_0", -2.0, -0.5)
    assert wait_until(lambda: len(got) == 1, 5.0)
    assert got[0].header.stamp.to_seconds() == 0.0 and c.clock().tick == 0
    assert got[0].pose.pose.position.x == pytest.approx(-2.0)


def step_until(c: FleetClient, done: Callable[[], bool], most: int = 30) -> int:
    """Step one tick at a time until ``done`` (a command put on a topic and a step query may
    reach the daemon in either order); returns the ticks stepped."""
    for k in range(most):
        if done():
            return k
        c.step(1)
    raise AssertionError(f"not done after {most} ticks")


def test_json_cmd_vel_drives_and_the_watchdog_stops(daemon_factory: Callable[..., Daemon]) -> None:
    d = daemon_factory("--lockstep")
    c = d.client()
    c.spawn("tb3_0", -2.0, -0.5)
    with raw_session(d.endpoint) as s:
        pub = s.declare_publisher("fleet/tb3_0/cmd_vel")
        assert wait_until(lambda: matching(pub), 5.0)
        pub.put(b'{"linear": {"x": 0.2}, "angular": {"z": 0.0}}\n')  # as zenoh-cli put sends it
        step_until(c, lambda: (r := c.robot("tb3_0")) is not None and r.linear_velocity > 0)
    # 0.5 s of sim time after the command the watchdog zeroes the target; the wheels ramp down
    c.step(15 + 8)  # 15 ticks to the watchdog, 7 to ramp the wheels down and snap to 0
    stopped = c.robot("tb3_0")
    assert stopped is not None and stopped.linear_velocity == 0.0 and stopped.pose.x > -1.95
    c.step(30)
    assert c.robot("tb3_0") == stopped  # stays put


def test_the_client_drives_each_robot_through_one_publisher(daemon_factory: Callable[..., Daemon]) -> None:
    """FleetClient.drive declares a publisher per namespace on first use and keeps it: with
    plain puts on key strings, 1 000 robots driven from one client held that client's queries
    for seconds (docs/clients.md)."""
    d = daemon_factory("--lockstep")
    c = d.client()
    c.spawn("tb3_0", -2.0, -0.5)
    c.spawn("tb3_1", 0.5, -2.0)
    threads = [threading.Thread(target=c.drive, args=(ns, 0.2, 0.0)) for ns in ("tb3_0", "tb3_1") * 4]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(c._cmd_pubs) == ["tb3_0", "tb3_1"]  # one each, though eight threads raced
    pubs = dict(c._cmd_pubs)

    def both_moving() -> bool:
        for ns in ("tb3_0", "tb3_1"):
            c.drive(ns, 0.2, 0.0)
        return all(r.linear_velocity > 0 for r in c.robots())

    step_until(c, both_moving)
    assert c._cmd_pubs == pubs


def test_four_robots_spawned_at_once_each_on_its_own_namespace(daemon_factory: Callable[..., Daemon]) -> None:
    daemon = daemon_factory("--lockstep")
    clients = [daemon.client() for _ in MULTI]
    results: dict[int, object] = {}

    def spawn(i: int) -> None:
        x, y = MULTI[i]
        try:
            results[i] = clients[i].spawn(f"burger_{i + 1}", x, y, namespace=f"TB3_{i + 1}")
        except FleetError as e:
            results[i] = e

    threads = [threading.Thread(target=spawn, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert all(not isinstance(r, FleetError) for r in results.values()), results
    c = clients[0]
    assert c.alive() == ["TB3_1", "TB3_2", "TB3_3", "TB3_4"]
    for i, (x, y) in enumerate(MULTI, 1):
        o = c.wait_odom(f"TB3_{i}")
        assert o.header.frame_id == f"TB3_{i}/odom"
        assert (o.pose.pose.position.x, o.pose.pose.position.y) == pytest.approx((x, y), abs=1e-6)
    c.step(12, cmd_vel={"TB3_3": (0.0, 1.0)})  # only TB3_3 turns
    yaws = {r.namespace: r.pose.yaw for r in c.robots()}
    assert yaws["TB3_3"] > 0.05
    assert yaws["TB3_1"] == yaws["TB3_2"] == yaws["TB3_4"] == 0.0


def test_many_spawns_and_deletes_in_flight_are_served_in_the_order_sent(
    daemon_factory: Callable[..., Daemon],
) -> None:
    """A learner's env spawns its fleet with many requests in flight; the daemon's rows (and
    scan phases) must be those of spawning one by one, or the episode differs from the
    in-process one. A refusal among them names its robot, once all were answered."""
    from protocol.control import SpawnRequest

    daemon = daemon_factory("--lockstep", "--world", "empty", "--max-robots", "400")
    c = daemon.client()
    names = [f"r{(k * 37) % 300:03d}" for k in range(300)]  # not in name order
    wanted = [SpawnRequest(name=n, x=-9.0 + (k % 30) * 0.6, y=-9.0 + (k // 30) * 0.6) for k, n in enumerate(names)]
    records = c.spawn_many(wanted, window=32)
    assert [r.name for r in records] == names
    assert [r.name for r in c.robots()] == names  # the table, in the order sent
    gone = names[::3]
    assert [r.name for r in c.delete_many(gone)] == gone
    assert [r.name for r in c.robots()] == [n for n in names if n not in set(gone)]
    bad = [SpawnRequest(name="fresh_a", x=9.0, y=9.0), SpawnRequest(name=names[1], x=9.0, y=8.0),
           SpawnRequest(name="fresh_b", x=9.0, y=7.0)]  # fmt: skip
    with pytest.raises(FleetError) as e:
        c.spawn_many(bad)
    assert e.value.code is ErrorCode.ALREADY_EXISTS and e.value.message.startswith(f"{names[1]}: ")
    assert {"fresh_a", "fresh_b"} <= {r.name for r in c.robots()}  # the others were spawned
    with pytest.raises(FleetError) as e:
        c.delete_many(["fresh_a", "nobody", "fresh_b"])
    assert e.value.code is ErrorCode.NOT_FOUND and e.value.message.startswith("nobody: ")
    assert not {"fresh_a", "fresh_b"} & {r.name for r in c.robots()}
    with pytest.raises(ValueError, match="window"):
        c.spawn_many(bad, window=0)
    with pytest.raises(TypeError, match="SpawnRequest"):
        c.spawn_many([("r1", 0.0, 0.0)])  # type: ignore[list-item]
    with pytest.raises(TypeError, match="names"):
        c.delete_many([names[1], 7])  # type: ignore[list-item]
    assert names[1] in {r.name for r in c.robots()}  # nothing sent


def test_delete_list_and_liveliness(daemon: Daemon) -> None:
    c = daemon.client()
    events: list[tuple[str, bool]] = []
    c.on_presence(lambda ns, up: events.append((ns, up)))
    c.spawn("a", -2.0, -0.5)
    c.spawn("b", 0.5, -2.0, model="waffle_pi")
    assert [(r.name, r.model) for r in c.robots()] == [("a", "burger"), ("b", "waffle_pi")]
    assert c.delete("a").name == "a"
    assert [r.name for r in c.robots()] == ["b"]
    assert wait_until(lambda: ("a", False) in events, 2.0)
    assert ("a", True) in events and ("b", True) in events
    with pytest.raises(FleetError) as e:
        c.delete("a")
    assert e.value.code is ErrorCode.NOT_FOUND
    assert "does not exist" in e.value.message
    # a deleted robot's name is free again, and it lives again
    c.spawn("a", -2.0, -0.5)
    assert c.wait_odom("a").pose.pose.position.x == pytest.approx(-2.0)


def test_a_list_of_named_robots_and_a_fleet_read_page_by_page(daemon: Daemon) -> None:
    c = daemon.client()
    c.pause()  # the poses stand still: the lists compare whole
    spawned = {"r_c": (-2.0, -0.5), "r_a": (0.5, -2.0), "r_e": (2.0, 0.5), "r_b": (-0.5, 2.0), "r_d": (1.5, -1.0)}
    for name, (x, y) in spawned.items():
        c.spawn(name, x, y, namespace=f"ns_{name}" if name == "r_e" else "")
    everyone = c.robots()
    assert [r.name for r in everyone] == list(spawned)  # spawn order
    # named (by name or namespace; spawn order), the absent left out
    assert [r.name for r in c.robots(["r_d", "ns_r_e", "nobody", "r_c"])] == ["r_c", "r_e", "r_d"]
    assert c.robot("ns_r_e") == everyone[2] and c.robot("nobody") is None and c.robot("not a name") is None
    # pages in name order, each after the last name of the one before; the same records
    pages = [c.robots_page(limit=2), c.robots_page("r_b", 2), c.robots_page("r_d", 2)]
    assert [[r.name for r in p] for p in pages] == [["r_a", "r_b"], ["r_c", "r_d"], ["r_e"]]
    assert sorted((r for p in pages for r in p), key=lambda r: r.name) == sorted(everyone, key=lambda r: r.name)
    with raw_session(daemon.endpoint) as s:  # JSON, as a person asks with zenoh-cli
        ok, err = get_json(s, "fleet/robots", {"after": "r_a", "limit": 1})
        assert err is None and [r["name"] for r in ok["robots"]] == ["r_b"]
        refused = [
            ({"limit": -1}, "invalid_value", "limit"),
            ({"names": ["a b"]}, "invalid_name", "names"),
            ({"after": "*"}, "invalid_name", "after"),
            ({"limit": "x"}, "malformed", "limit"),
        ]
        for body, code, field in refused:
            ok, err = get_json(s, "fleet/robots", body)
            assert ok is None and err["code"] == code and err.get("field") == field, (body, err)
    assert c.robots() == everyone  # refused, and nothing changed


def test_a_page_of_many_robots_is_the_same_records_as_json_gives(daemon_factory: Callable[..., Daemon]) -> None:
    """A page of more than a few robots is written from the fleet's byte templates
    (simd/wire/list_codec.py); JSON and a few robots by name come from their records: the
    same robots either way, before and after the fleet changes."""
    d = daemon_factory("--world", "empty", "--paused")
    c = d.client()
    names = [f"p{k:03d}" for k in range(150)]
    c.spawn_many(SpawnRequest(name=n, x=-4.0 + 0.6 * (k % 14), y=-4.0 + 0.6 * (k // 14)) for k, n in enumerate(names))
    for change in (None, "p010", "p075"):
        if change is not None:
            c.delete(change)
            names.remove(change)
        everyone = {r.name: r for r in c.robots()}
        page = c.robots_page("p004", 100)
        assert [r.name for r in page] == sorted(names)[5:105]
        assert page == [everyone[r.name] for r in page]
        with raw_session(d.endpoint) as s:
            ok, err = get_json(s, "fleet/robots", {"after": "p004", "limit": 100})
        assert err is None and msgspec.convert(ok["robots"], list[RobotRecord]) == page
        assert c.robots([r.name for r in page[:3]]) == page[:3]  # a few, from their records


def test_world_and_clock(daemon: Daemon) -> None:
    c = daemon.client()
    w = c.world()
    assert w.name == "turtlebot3_world"
    assert len(w.circles) == 9 and len(w.polygons) == 11
    assert (w.default_spawn.x, w.default_spawn.y) == (-2.0, -0.5)
    k0 = c.clock()
    assert wait_until(lambda: c.clock().tick > k0.tick, 5.0)  # it runs by itself
    k1 = c.clock()
    assert not k1.paused
    assert k1.dt == pytest.approx(1 / 30)
    with raw_session(daemon.endpoint) as s:
        clock = Collector(s, "fleet/clock")
        assert wait_until(lambda: len(clock) >= 3, 2.0)  # 10 Hz


def test_pause_step_resume_reset(daemon: Daemon) -> None:
    c = daemon.client()
    c.spawn("r", -2.0, -0.5)
    assert wait_until(lambda: c.clock().tick > 3, 5.0)
    p = c.pause()
    assert p.paused
    s = c.step(30, cmd_vel={"r": (0.2, 0.0)})
    assert s.tick == p.tick + 30  # nothing ticked between the pause and the step
    moved = c.robot("r")
    assert moved is not None and moved.pose.x > -2.0
    assert not c.resume().paused
    r = c.reset()
    assert r.tick == 0 or r.tick < 3
    back = c.robot("r")
    assert back is not None and (back.pose.x, back.pose.y) == pytest.approx((-2.0, -0.5), abs=2e-3)


def test_step_refused_while_running(daemon: Daemon) -> None:
    c = daemon.client()
    with pytest.raises(FleetError) as e:
        c.step(1)
    assert e.value.code is ErrorCode.NOT_ALLOWED


def test_lockstep_runs_only_on_request_and_is_deterministic(
    daemon_factory: Callable[..., Daemon],
) -> None:
    runs = []
    for _ in range(2):
        d = daemon_factory("--lockstep", "--seed", "5")
        c = d.client()
        c.spawn("r", -2.0, -0.5)
        c.spawn("q", 0.5, -2.0)
        assert c.clock().tick == 0
        with pytest.raises(FleetError) as e:
            c.resume()
        assert e.value.code is ErrorCode.NOT_ALLOWED
        assert c.step(1).tick == 1  # nothing moved on its own meanwhile
        scans: list[bytes] = []
        c.on_scan("r", lambda ns, m, out=scans: out.append(m.ranges))  # type: ignore[misc]
        for k in range(10):
            c.step(6 if k else 5, cmd_vel={"r": (0.2, 0.5 * math.sin(k)), "q": (0.1, -0.3)})
        assert c.clock().tick == 60
        assert wait_until(lambda out=scans: len(out) == 10, 2.0)  # type: ignore[misc]
        runs.append(([(r.pose.x, r.pose.y, r.pose.yaw) for r in c.robots()], list(scans)))
        d.stop()
    assert runs[0] == runs[1]


def test_latest_odom_query_in_json(daemon: Daemon) -> None:
    c = daemon.client()
    c.spawn("tb3_0", -2.0, -0.5)
    c.wait_odom("tb3_0")
    with raw_session(daemon.endpoint) as s:
        ok, err = get_json(s, "fleet/tb3_0/odom?format=json")
    assert err is None
    assert ok["header"]["frame_id"] == "tb3_0/odom"
    assert ok["pose"]["pose"]["position"]["x"] == pytest.approx(-2.0)


def test_prefix_separates_two_simulations(daemon_factory: Callable[..., Daemon]) -> None:
    d = daemon_factory(prefix="sim_b")
    c = d.client()
    rec = c.spawn("tb3_0", -2.0, -0.5)
    assert rec.topics is not None and rec.topics.odom == "sim_b/tb3_0/odom"
    with (
        FleetClient(d.endpoint, prefix="fleet", timeout=1.0) as other,
        pytest.raises(FleetError) as e,
    ):
        other.robots()
    assert e.value.code is ErrorCode.UNAVAILABLE


@pytest.mark.slow  # the promise is in wall time: no stale daemon to kill
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_signal_stops_within_one_second_with_exit_0(daemon: Daemon, sig: int) -> None:
    c = daemon.client()
    c.spawn("tb3_0", -2.0, -0.5)
    c.close()
    daemon.clients.clear()
    t0 = time.monotonic()
    daemon.proc.send_signal(sig)
    code = daemon.proc.wait(5)
    elapsed = time.monotonic() - t0
    assert code == 0, daemon.log()
    assert elapsed < 1.0, f"took {elapsed:.2f} s"


def test_port_in_use_is_one_line_and_exit_2(daemon: Daemon) -> None:
    p = subprocess.run(simd_command("-l", daemon.endpoint), capture_output=True, text=True, timeout=20, cwd=ROOT)
    assert p.returncode == 2
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1, p.stderr
    assert str(daemon.port) in lines[0] and "in use" in lines[0]


def test_bad_world_file_is_one_line_and_exit_2(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        "name: bad\nbounds: {x_min: 0, x_max: 1, y_min: 0, y_max: 1}\n"
        "obstacles:\n  - {type: circle, x: 0, y: 0, radius: -1}\n"
    )
    for world, fragment in ((str(bad), "radius"), ("turtlebot3_wrld", "turtlebot3_world")):
        p = subprocess.run(
            simd_command("--world", world, "-l", f"tcp/127.0.0.1:{free_port()}"),
            capture_output=True, text=True, timeout=20, cwd=ROOT,
        )  # fmt: skip
        assert p.returncode == 2
        lines = p.stderr.strip().splitlines()
        assert len(lines) == 1 and fragment in lines[0], p.stderr


@pytest.mark.parametrize("variable", ["FLEETSIM_NATIVE", "FLEETSIM_LIDAR"])
def test_bad_fast_path_switch_is_one_line_and_exit_2(variable: str) -> None:
    env = {k: v for k, v in os.environ.items() if k not in ("FLEETSIM_NATIVE", "FLEETSIM_LIDAR")}
    p = subprocess.run(
        simd_command("-l", f"tcp/127.0.0.1:{free_port()}"),
        capture_output=True, text=True, timeout=20, cwd=ROOT, env={**env, variable: "fastest"},
    )  # fmt: skip
    assert p.returncode == 2
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and variable in lines[0] and "'numpy'" in lines[0], p.stderr


def test_help_lists_the_flags() -> None:
    p = subprocess.run(
        [sys.executable, "-m", "simd.cli", "--help"],
        capture_output=True,
        text=True,
        timeout=20,
        cwd=ROOT,
    )
    for flag in ("--world", "--cell-size", "--prefix", "--seed", "--rtf", "--no-noise", "--cmd-timeout", "--max-robots",
                 "--lockstep", "--listen", "--connect", "--mode", "--config", "--cfg"):  # fmt: skip
        assert flag in p.stdout


def test_json_mirrors_flow_only_while_subscribed(daemon: Daemon) -> None:
    import json

    c = daemon.client()
    c.spawn("tb3_0", -2.0, -0.5)
    with raw_session(daemon.endpoint) as s:
        odom = Collector(s, "fleet/tb3_0/odom/json")
        scan = Collector(s, "fleet/tb3_0/scan/json")
        assert wait_until(lambda: len(odom) >= 5 and len(scan) >= 1, 3.0)
        o = json.loads(odom.samples[-1][1])
        assert o["header"]["frame_id"] == "tb3_0/odom"
        sc = json.loads(scan.samples[-1][1])
        assert len(sc["ranges"]) == 360
        assert all(r is None or 0.12 <= r <= 3.5 for r in sc["ranges"])


def test_spawn_and_delete_churn_between_ticks(daemon_factory: Callable[..., Daemon]) -> None:
    d = daemon_factory("--lockstep", "--world", "empty")
    c = d.client()
    for i in range(40):
        c.spawn(f"r{i}", x=(i % 8) * 1.0 - 4, y=(i // 8) * 1.0 - 4)
    dec = msgspec.msgpack.Decoder(Odometry)

    def published_at(odom: Collector, tick: int) -> set[str]:
        """The robots whose odometry of ``tick`` arrived (a spawn's first odometry carries the
        stamp of the tick before, and may still be on its way)."""
        with odom.lock:
            samples = list(odom.samples)
        return {k.split("/")[1] for k, p in samples if round(dec.decode(p).header.stamp.to_seconds() * 30) == tick}

    with raw_session(d.endpoint) as s:
        odom = Collector(s, "fleet/*/odom")
        warm_up(c, odom)
        for k in range(60):
            c.spawn("churn", x=5.0, y=5.0)
            c.delete("churn")
            if k % 10 == 0:
                c.delete(f"r{k // 10}")
        tick = c.step(1).tick
        live = {f"r{i}" for i in range(6, 40)}
        # one tick: exactly the live robots (wait for all of them, then compare)
        assert wait_until(lambda: published_at(odom, tick) >= live, 5.0)
        assert published_at(odom, tick) == live
        # the same name deleted and spawned again between two ticks (so the fleet's namespace
        # list is the same before and after): its odometry flows on its new publisher, not on
        # the one undeclared with the first
        c.spawn("churn", x=5.0, y=5.0)
        c.step(1)
        c.delete("churn")
        c.spawn("churn", x=5.0, y=5.0)
        tick = c.step(1).tick
        assert wait_until(lambda: published_at(odom, tick) >= live | {"churn"}, 5.0)
        assert published_at(odom, tick) == live | {"churn"}
    assert d.alive()
    assert "failed" not in d.log() and "Traceback" not in d.log()
