"""A daemon frozen with SIGSTOP for 5 s and continued (a debugger, a swapped-out VM, a host
that stalls): it answers again, keeps its robots, its clock does not burst to catch up the
5 s (the pacing grid slips: simd/engine/pacing.py) but says it lost them, it says it fell
behind and then caught up, and a client that saw it go quiet goes on by itself."""

from __future__ import annotations

import signal
import threading
import time
from collections.abc import Callable

import pytest

from clients import wait_until
from protocol import FleetError
from protocol.control import Clock
from tests.conftest import Daemon

STOPPED_S = 5.0


@pytest.mark.slow  # a 5 s stop is a wall-clock promise
def test_a_daemon_stopped_for_5_s_answers_again_without_a_burst(daemon_factory: Callable[..., Daemon]) -> None:
    d = daemon_factory("--world", "empty", "--no-noise")
    c = d.client(timeout=1.0)
    names = [f"tb3_{i}" for i in range(3)]
    for i, n in enumerate(names):
        c.spawn(n, float(i), 0.0)
    odom: list[float] = []  # arrival times of the robots' odometry, as a subscriber sees it
    lock = threading.Lock()

    def on_odom(ns: str, msg: object) -> None:
        with lock:
            odom.append(time.monotonic())

    c.on_odom("*", on_odom)
    assert wait_until(lambda: len(odom) > 30, 10.0)
    # running in real time, not in a falling-behind episode (a loaded machine's slow spell
    # would otherwise have said its warning already)
    assert wait_until(lambda: (k := c.clock()).real_time_factor > 0.9 and not k.falling_behind, 30.0)

    logged = len(d.log())  # what it says from here on
    before: Clock = c.clock()
    t_before = time.monotonic()
    d.proc.send_signal(signal.SIGSTOP)
    try:
        t_stopped = time.monotonic()
        with pytest.raises(FleetError):
            c.clock()  # frozen: no answer (the client times out, as it must)
        time.sleep(max(0.0, STOPPED_S - (time.monotonic() - t_stopped)))
    finally:
        d.proc.send_signal(signal.SIGCONT)
    t_cont = time.monotonic()

    # it answers again, with its robots, through the same client
    after: Clock | None = None
    deadline = t_cont + 15.0
    while after is None:
        try:
            after = c.clock()
        except FleetError:
            assert time.monotonic() < deadline, d.log()
    t_after = time.monotonic()
    # it says it fell behind (from the first tick after the stop: this answer may have come first)
    assert after.falling_behind or wait_until(lambda: c.clock().falling_behind, 1.0), c.clock()
    assert sorted(r.name for r in c.robots()) == names
    assert d.alive()

    # no burst: the 5 s frozen are lost to the sim clock, not run back to back afterwards. The
    # daemon ran for at most the wall time outside the stop, plus the few ticks of lateness the
    # grid catches up (CATCH_UP_TICKS) and the tick that was due: well under the stop's length.
    sim_advance = (after.tick - before.tick) * after.dt
    ran_for = (t_after - t_before) - STOPPED_S
    assert sim_advance <= ran_for + 7 * after.dt, (sim_advance, ran_for)
    assert after.behind_s >= STOPPED_S - 0.5, after  # and it says what it lost
    # the factor it reports over the stall is low, never a burst (it was 140 once after a pause)
    replies = [after, *(c.clock() for _ in range(5))]
    assert all(r.real_time_factor <= 1.2 for r in replies), [r.real_time_factor for r in replies]

    # the subscriber receives again, at the usual rate, without reconnecting anything
    with lock:
        seen = len(odom)
    assert wait_until(lambda: len(odom) > seen + 30, 10.0)
    # it fell behind (one warning) and caught up (one line), and is back in real time
    assert wait_until(lambda: c.clock().real_time_factor > 0.9, 20.0), c.clock()
    assert wait_until(lambda: "caught up" in d.log()[logged:], 30.0), d.log()
    warned = d.log()[logged:].count("falling behind: running at")
    assert warned == 1 or (warned == 0 and before.falling_behind), d.log()  # once (an episode begun just
    # before the stop was told then)
    c.spawn("tb3_late", 5.0, 0.0)  # and it takes requests as before
    assert len(c.robots()) == 4
