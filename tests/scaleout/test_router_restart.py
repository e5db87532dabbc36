"""The router under a shared fleet restarts (killed, a crash or an upgrade, and started again on
its port): the daemons and the clients reconnect by themselves, the fleet reforms (both
daemons, every robot, spawns placed by name as before, the robots on one daemon seen by the
other's lidar), and no robot is lost. All real processes on loopback."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest

from clients import FleetClient, wait_until
from protocol import FleetError
from protocol.placement import owner
from tests.conftest import free_port, simd_command
from tests.scaleout.test_router import _start, _stop, _wait_for


def _router(endpoint: str, log: Path) -> subprocess.Popen[str]:
    proc = _start([sys.executable, "-m", "simd.router", "-l", endpoint], log)
    _wait_for(log, "fleet-router: routing on", proc)
    return proc


def _names(c: FleetClient) -> list[str] | None:
    try:
        return [r.name for r in c.robots()]
    except FleetError:
        return None


def _daemon_ids(c: FleetClient) -> list[str] | None:
    try:
        return [d.id for d in c.daemons()]
    except FleetError:
        return None


@pytest.mark.slow  # a router's death is told within the zenoh lease; reconnecting takes about a second
def test_a_restarted_router_reforms_the_fleet_with_every_robot(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = _router(endpoint, tmp_path / "router-1.log")
    logs = {d: tmp_path / f"simd-{d}.log" for d in ("a", "b")}
    args = ("-m", "client", "-e", endpoint, "--world", "empty", "--no-noise", "--join")
    daemons = {d: _start(simd_command(*args, "--id", d), logs[d]) for d in ("a", "b")}
    try:
        with FleetClient(endpoint, timeout=3.0) as c:
            assert wait_until(lambda: _daemon_ids(c) == ["a", "b"], 20.0), [p.read_text() for p in logs.values()]
            names = [f"tb3_{i}" for i in range(8)]
            placed = {n: owner(n, ["a", "b"]) for n in names}
            assert set(placed.values()) == {"a", "b"}
            told: list[tuple[str, bool]] = []
            c.on_daemons(lambda d, alive: told.append((d, alive)))
            assert wait_until(lambda: sorted(told) == [("a", True), ("b", True)], 5.0), told
            for i, n in enumerate(names):
                assert c.spawn(n, 2.0 * i, 0.0).daemon == placed[n]

            router.send_signal(signal.SIGKILL)  # the router dies: every link through it is cut at once
            router.wait()
            assert wait_until(lambda: _names(c) is None, 10.0)  # the client finds nobody
            assert all(p.poll() is None for p in daemons.values()), "a daemon died with the router"
            router = _router(endpoint, tmp_path / "router-2.log")  # the same port, a new router

            # daemons and client reconnect by themselves; the fleet reforms with every robot
            assert wait_until(lambda: _daemon_ids(c) == ["a", "b"], 20.0), [p.read_text() for p in logs.values()]
            assert wait_until(lambda: _names(c) == names, 20.0), _names(c)
            assert {r.name: r.daemon for r in c.robots()} == placed
            assert wait_until(lambda: told[-2:] in ([("a", True), ("b", True)], [("b", True), ("a", True)]), 10.0), told
            # the fleet works as before: placement by name over both daemons, one list, deletes
            more = [f"late_{i}" for i in range(6)]
            for i, n in enumerate(more):
                assert c.spawn(n, 2.0 * i, 4.0).daemon == owner(n, ["a", "b"])
            assert c.delete("tb3_0").daemon == placed["tb3_0"]
            assert _names(c) == sorted(names[1:] + more)
            # the robots of one daemon are in the other's lidar again (the ghosts' exchange is back)
            # (new names: a name deleted and spawned again at once can race its own liveliness
            # token, which the daemon hears back through the router a moment later)
            fresh = [f"see_{i}" for i in range(20)]
            on_a = next(n for n in fresh if owner(n, ["a", "b"]) == "a")
            on_b = next(n for n in fresh if owner(n, ["a", "b"]) == "b")
            assert c.spawn(on_a, 10.0, 10.0, 0.0).daemon == "a"
            assert c.spawn(on_b, 11.0, 10.0, 3.14159).daemon == "b"

            def ahead(ns: str) -> float:
                scan = c.latest_scan(ns)
                return float(scan.ranges_array()[0]) if scan is not None else float("inf")

            assert wait_until(lambda: 0.85 < ahead(on_a) < 1.05, 10.0), ahead(on_a)
            assert wait_until(lambda: 0.85 < ahead(on_b) < 1.05, 10.0), ahead(on_b)
            # and commands reach a robot through the new router (a client daemon takes cmd_vel
            # on a session of its own: it reconnected too)
            driven = next(n for n in names[1:] if placed[n] == "b")
            start = c.wait_odom(driven).pose.pose.position.x

            def moved() -> bool:
                c.drive(driven, 0.2, 0.0)
                return c.wait_odom(driven).pose.pose.position.x > start + 0.05

            assert wait_until(moved, 10.0, interval=0.1)
        for d, p in daemons.items():
            assert p.poll() is None, logs[d].read_text()
            assert "Traceback" not in logs[d].read_text(), logs[d].read_text()
    finally:
        for p in daemons.values():
            _stop(p)
        _stop(router)
