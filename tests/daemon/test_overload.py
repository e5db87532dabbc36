"""A real simd keeping time: a resume is not a burst, a daemon asked for more than the machine
can do says so (once, in its log; in every clock reply; in ``fleet clock``), and a spawn
beyond ``--max-robots`` is refused with the capacity it measured. The assertions are one-sided
bounds that hold whatever the machine's speed, or conditions waited for, never timings."""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Callable

import pytest

from clients import wait_until
from protocol import FleetError
from protocol.control import SpawnRequest
from tests.conftest import ROOT, Daemon

DT = 1 / 30


def _grid(n: int) -> list[SpawnRequest]:
    return [SpawnRequest(name=f"r{i}", x=float(i % 10) - 4.5, y=float(i // 10) - 4.5) for i in range(n)]


def test_after_a_resume_the_sim_clock_never_leads_the_wall_clock(daemon_factory: Callable[..., Daemon]) -> None:
    d = daemon_factory("--world", "empty", "--no-noise")
    c = d.client()
    c.spawn_many(_grid(20))
    for _ in range(3):
        c.pause()
        for _ in range(10):  # requests while paused (the loop used to keep a stale deadline through them)
            c.clock()
        c.step(3)
        sent = time.monotonic()  # before the daemon resumed: its wall clock can only be behind this
        resumed = c.resume()
        assert resumed.real_time_factor <= 1.0
        start = resumed.clock.to_seconds()
        while True:
            clock = c.clock()
            wall = time.monotonic() - sent
            ran = clock.clock.to_seconds() - start
            assert ran <= wall + DT + 1e-6, (ran, wall)  # at most one tick ahead, ever
            assert clock.real_time_factor <= 1.05, clock  # measured from the resume: no burst in it
            if clock.tick >= resumed.tick + 30:
                break
    assert "falling behind" not in d.log()


def test_a_daemon_asked_for_more_than_it_can_do_says_so_once(daemon_factory: Callable[..., Daemon]) -> None:
    # no machine ticks 50 robots at 30 kHz; paused until they are there, so the warning is theirs
    d = daemon_factory("--world", "empty", "--no-noise", "--rtf", "1000", "--paused")
    c = d.client()
    c.spawn_many(_grid(50))
    c.resume()
    assert wait_until(lambda: c.clock().falling_behind, 30.0), c.clock()
    clock = c.clock()
    assert clock.real_time_factor < 0.9 * 1000 and clock.behind_s > 0.0
    assert clock.tick_s > 0.0 and clock.capacity_robots > 0
    warned = [line for line in d.log().splitlines() if "falling behind" in line]
    assert len(warned) == 1 and "WARNING" in warned[0] and "50 robots" in warned[0], warned
    tick = clock.tick
    assert wait_until(lambda: c.clock().tick > tick + 300, 30.0)  # it runs on, slower, and says nothing more
    later = c.clock()
    assert later.falling_behind and later.behind_s > clock.behind_s
    assert [line for line in d.log().splitlines() if "falling behind" in line] == warned
    shown = subprocess.run(
        [sys.executable, "-m", "clients.fleet.cli", "clock", "-e", d.endpoint],
        cwd=ROOT, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert shown.returncode == 0 and "falling behind (" in shown.stdout, shown
    assert "robots like these keep real time here" in shown.stdout
    paused = c.pause()
    assert not paused.falling_behind and paused.behind_s == 0.0
    assert wait_until(lambda: "no longer falling behind: paused" in d.log(), 5.0), d.log()


def test_a_spawn_beyond_the_robot_limit_says_what_this_machine_can_keep(daemon_factory: Callable[..., Daemon]) -> None:
    d = daemon_factory("--world", "empty", "--no-noise", "--max-robots", "5")
    c = d.client()
    c.spawn_many(_grid(5))
    assert wait_until(lambda: c.clock().capacity_robots > 0, 15.0)  # a few ticks measured
    with pytest.raises(FleetError, match=r"robot limit \(5\) is reached; this machine keeps about \d+ robots") as e:
        c.spawn("one_more", 4.0, 4.0)
    assert e.value.code.value == "robot_limit"
