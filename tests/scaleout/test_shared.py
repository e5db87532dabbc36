"""Two daemons share one fleet through a router (simd --join): spawns placed by name on one of
them, one list, deletes answered by the robot's daemon, refusals, and a daemon's death. All
real processes on loopback."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from clients import FleetClient, wait_until
from clients.api import observed_arrays
from protocol import FleetError
from protocol.messages import FleetOdometry
from protocol.placement import owner
from tests.conftest import ROOT, simd_command
from tests.scaleout.test_router import _start, _stop, _wait_for, router  # noqa: F401  (the router fixture)

Router = tuple[str, subprocess.Popen[str], Path]


@pytest.fixture
def fleet(router: Router, tmp_path: Path) -> Iterator[tuple[str, dict[str, subprocess.Popen[str]]]]:  # noqa: F811
    endpoint = router[0]
    daemons = {
        d: _start(
            simd_command("-m", "client", "-e", endpoint, "--join", "--id", d, "--world", "empty", "--no-noise"),
            tmp_path / f"simd-{d}.log",
        )
        for d in ("a", "b")
    }
    try:
        with FleetClient(endpoint, timeout=3.0) as c:
            assert wait_until(lambda: [d.id for d in c.daemons()] == ["a", "b"], 20.0), [
                (tmp_path / f"simd-{d}.log").read_text() for d in daemons
            ]
        yield endpoint, daemons
    finally:
        for p in daemons.values():
            _stop(p)


def test_spawns_are_placed_by_name_and_the_fleet_is_one_list(
    fleet: tuple[str, dict[str, subprocess.Popen[str]]], tmp_path: Path
) -> None:
    endpoint, daemons = fleet
    names = [f"tb3_{i}" for i in range(8)]
    placed = {n: owner(n, ["a", "b"]) for n in names}
    assert set(placed.values()) == {"a", "b"}  # these eight land on both
    with FleetClient(endpoint, timeout=5.0) as c:
        for i, n in enumerate(names):
            record = c.spawn(n, float(i), 0.0)
            assert record.daemon == placed[n], n  # the reply says which daemon runs it
        listed = c.robots()
        assert [r.name for r in listed] == sorted(names)
        assert {r.name: r.daemon for r in listed} == placed
        with pytest.raises(FleetError, match="already exists") as e:
            c.spawn("tb3_3", 0.0, 5.0)
        assert e.value.code.value == "already_exists"
        on_b = next(n for n in names if placed[n] == "b")
        assert c.delete(on_b).daemon == "b"
        with pytest.raises(FleetError) as missing:
            c.delete("ghost")
        assert missing.value.code.value == "not_found"
        assert on_b not in [r.name for r in c.robots()]
        told: list[tuple[str, bool]] = []
        c.on_daemons(lambda d, alive: told.append((d, alive)))
        assert wait_until(lambda: sorted(told) == [("a", True), ("b", True)], 5.0), told  # those there now
        watch_log = tmp_path / "watch.log"
        watch = _start([sys.executable, "-m", "clients.fleet.cli", "daemons", "--watch", "-e", endpoint], watch_log)
        try:
            _wait_for(watch_log, "daemons: a, b; watching", watch)
            _stop(daemons["b"])  # a daemon dies: its robots leave the fleet, its names go to the survivor
            assert wait_until(lambda: ("b", False) in told, 15.0), told  # clients are told
            _wait_for(watch_log, "b left: its robots left the fleet with it", watch)
        finally:
            _stop(watch)
        survivors = sorted(n for n in names if placed[n] == "a")
        assert wait_until(lambda: [d.id for d in c.daemons()] == ["a"], 15.0)
        assert [r.name for r in c.robots()] == survivors
        assert c.spawn(on_b, 20.0, 0.0).daemon == "a"

    def health(daemon_id: str) -> tuple[int, str]:
        cmd = [sys.executable, "-m", "simd.healthcheck", "-e", endpoint, "--id", daemon_id, "--timeout", "2"]
        done = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=30)
        return done.returncode, done.stdout

    # each daemon's healthcheck asks its own clock: a's says healthy, b's (dead) does not,
    # although the fleet's clock is still answered (by a)
    code, said = health("a")
    assert code == 0 and "fleet/daemons/a/clock answered" in said, said
    code, said = health("b")
    assert code == 1 and "no answer on fleet/daemons/b/clock" in said, said


def test_a_daemon_that_cannot_join_is_refused(fleet: tuple[str, dict[str, subprocess.Popen[str]]]) -> None:
    endpoint, _ = fleet
    cases = [
        (["--join", "--id", "a", "--world", "empty"], "a daemon with --id 'a' already serves prefix 'fleet'"),
        (["--join", "--id", "c"], "runs world 'empty' (daemon 'a'), this one 'turtlebot3_world'"),
        (["--id", "c", "--world", "empty"], "start every daemon of one fleet with --join"),
    ]
    for args, words in cases:
        r = subprocess.run(
            simd_command("-m", "client", "-e", endpoint, *args), cwd=ROOT, capture_output=True, text=True, timeout=60
        )
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 2 and len(lines) == 1 and words in lines[0], r.stderr
    with FleetClient(endpoint, timeout=3.0) as c:
        assert [d.id for d in c.daemons()] == ["a", "b"]  # the fleet is as it was
        assert all(d.shared for d in c.daemons())


def test_robots_on_different_daemons_see_each_other(fleet: tuple[str, dict[str, subprocess.Popen[str]]]) -> None:
    endpoint, _ = fleet
    names = [f"r{i}" for i in range(20)]
    on_a = next(n for n in names if owner(n, ["a", "b"]) == "a")
    on_b = next(n for n in names if owner(n, ["a", "b"]) == "b")
    with FleetClient(endpoint, timeout=5.0) as c:
        assert c.spawn(on_a, 0.0, 0.0, 0.0).daemon == "a"
        assert c.spawn(on_b, 1.0, 0.0, 3.14159).daemon == "b"  # a metre ahead, facing it

        def ahead(ns: str) -> float:
            scan = c.latest_scan(ns)
            return float(scan.ranges_array()[0]) if scan is not None else float("inf")

        # each sees the other, simulated on the other daemon, about a metre ahead (the empty
        # floor has nothing else): from the pose that daemon last published
        assert wait_until(lambda: 0.85 < ahead(on_a) < 1.05, 10.0), ahead(on_a)
        assert wait_until(lambda: 0.85 < ahead(on_b) < 1.05, 10.0), ahead(on_b)
        c.delete(on_b)  # gone from the fleet: gone from a's scans
        assert wait_until(lambda: ahead(on_a) == float("inf"), 10.0), ahead(on_a)


def test_one_clock_steps_every_daemon_and_merges_what_they_observe(
    router: Router,  # noqa: F811
    tmp_path: Path,
) -> None:
    from protocol.control import Clock

    endpoint = router[0]
    daemons = [
        _start(
            simd_command("-m", "client", "-e", endpoint, "--join", "--id", d, "--world", "empty", "--lockstep"),
            tmp_path / f"simd-{d}.log",
        )
        for d in ("a", "b")
    ]
    try:
        with FleetClient(endpoint, timeout=5.0) as c:
            assert wait_until(lambda: [d.id for d in c.daemons()] == ["a", "b"], 20.0)
            names = [f"r{i}" for i in range(20)]
            on_a = next(n for n in names if owner(n, ["a", "b"]) == "a")
            on_b = next(n for n in names if owner(n, ["a", "b"]) == "b")
            c.spawn(on_a, 0.0, 0.0)
            c.spawn(on_b, 0.0, 3.0)
            ticks: list[FleetOdometry] = []
            with c.on_fleet_odom(ticks.append):  # each daemon puts its own rows: one message a tick
                reply = c.step(30, cmd_vel={on_a: (0.2, 0.0), on_b: (0.1, 0.0)}, observe=[on_b, on_a])
                assert wait_until(lambda: len(ticks) == 30, 5.0), [m.namespaces for m in ticks]
            assert all(sorted(m.namespaces) == sorted([on_a, on_b]) for m in ticks), [m.namespaces for m in ticks]
            assert [round(m.stamp.to_seconds() * 30) for m in ticks] == list(range(1, 31))
            assert reply.ticks_run == 30 and sorted(reply.observations) == sorted([on_a, on_b])
            x_a = reply.observations[on_a].odom.pose.pose.position.x
            x_b = reply.observations[on_b].odom.pose.pose.position.x
            assert 0.15 < x_a < 0.2 and 0.07 < x_b < 0.1  # each driven as asked, on its own daemon
            clocks = c._query_all(c.keys.clock, None, Clock)  # every daemon's own clock
            assert sorted(k.tick for k in clocks) == [30, 30]  # one step, both daemons
            packed = c.step(6, commands=([on_a, on_b], np.array([[0.2, 0.0], [0.1, 0.0]])), observe=[on_b, on_a],
                            packed=True, publish=False)  # fmt: skip
            assert packed.packed is not None and packed.packed.names == [on_b, on_a]  # rows in the order asked
            c.reset()
            assert sorted(k.tick for k in c._query_all(c.keys.clock, None, Clock)) == [0, 0]
    finally:
        for p in daemons:
            _stop(p)


def test_a_stepped_fleet_repeats_exactly_across_daemons(router: Router, tmp_path: Path) -> None:  # noqa: F811
    """Stepped, each daemon places the others' robots of the same tick before it steps it (one
    clock): robots on two daemons that see and push each other give the same run twice, bit
    for bit, and see each other from the first tick on. A daemon that does not step along (it
    runs in real time) delays a step once, never hangs it."""
    import time

    from protocol.control import Clock

    endpoint = router[0]

    def start(d: str, *more: str) -> subprocess.Popen[str]:
        cmd = simd_command("-m", "client", "-e", endpoint, "--join", "--id", d, "--world", "empty", *more)
        return _start(cmd, tmp_path / f"simd-{d}.log")

    daemons = [start(d, "--lockstep") for d in ("a", "b")]
    try:
        with FleetClient(endpoint, timeout=10.0) as c:
            assert wait_until(lambda: [d.id for d in c.daemons()] == ["a", "b"], 20.0)
            names = [f"r{i}" for i in range(40)]
            on_a = [n for n in names if owner(n, ["a", "b"]) == "a"][:3]
            on_b = [n for n in names if owner(n, ["a", "b"]) == "b"][:3]
            ring = [n for pair in zip(on_a, on_b, strict=True) for n in pair]  # a, b, a, b, ...
            for k, n in enumerate(ring):  # six robots on a 0.6 m circle, facing its centre
                angle = k * np.pi / 3
                c.spawn(n, 0.6 * np.cos(angle), 0.6 * np.sin(angle), angle + np.pi)
            first = c.step(6, observe=ring, packed=True, publish=False)
            assert first.packed is not None
            seen = observed_arrays(first.packed)
            # robot 0 (on a) looks across the centre at robot 3 (on b; the empty floor has nothing
            # else): its lidar 1.23 m from robot 3's centre, robot 3's front a little nearer
            assert 1.1 < float(seen.ranges[0, 0]) < 1.23, seen.ranges[0, 0]

            def run() -> tuple[bytes, bytes]:
                c.reset(seed=3)
                odom, scans = b"", b""
                go = np.tile([0.2, 0.3], (6, 1))  # into each other, turning
                for _ in range(8):
                    reply = c.step(6, commands=(ring, go), observe=ring, packed=True, publish=False)
                    assert reply.packed is not None and reply.packed.names == ring
                    odom += reply.packed.odom
                    scans += reply.packed.ranges
                return odom, scans

            once, again = run(), run()
            assert once == again
            rows = np.frombuffer(once[0], dtype="<f8").reshape(8, 6, 6)
            assert np.hypot(rows[-1, :, 0], rows[-1, :, 1]).min() > 0.1  # they pushed, nobody drove through
            late = start("c")  # joins in real time: it will not step along
            daemons.append(late)
            assert wait_until(lambda: [d.id for d in c.daemons()] == ["a", "b", "c"], 20.0)
            t0 = time.monotonic()
            ticks = [k.tick for k in c._query_all(c.keys.clock, None, Clock) if k.lockstep]
            with pytest.raises(FleetError, match="paused") as refused:  # c said so; a and b stepped
                c.step(6, observe=ring, packed=True, publish=False)
            assert refused.value.code.value == "not_allowed" and time.monotonic() - t0 < 8.0
            assert [k.tick for k in c._query_all(c.keys.clock, None, Clock) if k.lockstep] == [t + 6 for t in ticks]
    finally:
        for p in daemons:
            _stop(p)


def test_a_name_deleted_is_free_again_at_once(fleet: tuple[str, dict[str, subprocess.Popen[str]]]) -> None:
    """Delete a robot and spawn one of the same name straight away, on either daemon: the
    daemon that deleted it knows the name is free before its robot's liveliness token has
    gone round through the router (it used to refuse: "already exists (on another daemon)")."""
    endpoint, _ = fleet
    names = [f"again_{i}" for i in range(6)]
    assert {owner(n, ["a", "b"]) for n in names} == {"a", "b"}
    with FleetClient(endpoint, timeout=5.0) as c:
        for n in names:
            c.spawn(n, 0.0, float(names.index(n)))
        for round_ in range(3):
            for n in names:
                assert c.delete(n).name == n
                record = c.spawn(n, float(round_ + 1), float(names.index(n)))
                assert (record.name, record.daemon) == (n, owner(n, ["a", "b"]))
        assert sorted(r.name for r in c.robots()) == sorted(names)


def test_one_batch_of_commands_drives_robots_on_every_daemon(
    fleet: tuple[str, dict[str, subprocess.Popen[str]]],
) -> None:
    """P/commands reaches every daemon through the router; each takes its own robots' rows."""
    endpoint, _ = fleet
    names = [f"r{i}" for i in range(20)]
    on_a = next(n for n in names if owner(n, ["a", "b"]) == "a")
    on_b = next(n for n in names if owner(n, ["a", "b"]) == "b")
    with FleetClient(endpoint, timeout=5.0) as c:
        c.spawn(on_a, 0.0, 0.0)
        c.spawn(on_b, 0.0, 3.0)

        def both_driven() -> bool:
            c.drive_many([on_a, on_b, "ghost"], [(0.2, 0.0), (0.0, 1.0), (0.1, 0.0)])  # again: the watchdog
            robots = {r.name: r for r in c.robots()}
            return robots[on_a].linear_velocity > 0.1 and robots[on_b].angular_velocity > 0.5

        assert wait_until(both_driven, 10.0)
        robots = {r.name: r for r in c.robots()}
        assert robots[on_a].daemon == "a" and robots[on_b].daemon == "b"
        assert abs(robots[on_a].angular_velocity) < 1e-6 and abs(robots[on_b].linear_velocity) < 1e-6
        assert c.clock().dropped_commands == 0  # a row for a robot of the other daemon is no bad command
