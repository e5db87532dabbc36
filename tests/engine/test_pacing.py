"""Keeping time, on injected wall clocks: the tick grid after a resume, a loop that cannot keep
up (even ticks, the lag counted, no burst), the warning's hysteresis, and the tick cost and
capacity the engine reports. Nothing here waits on the wall clock."""

from __future__ import annotations

import itertools
import logging
import math

import pytest

from protocol import control
from protocol.errors import ErrorCode, FleetError
from simd.core.sim import SimConfig, Simulation
from simd.core.snapshot import TickSnapshot
from simd.core.worldfile import load_world
from simd.engine import Engine
from simd.engine.capacity import TickCost
from simd.engine.pacing import LagWatch, Pacer, RtfMeter
from tests.engine.test_engine import FakeWall, Recorder

DT = 1 / 30


def _loop(pacer: Pacer, start: float, until: float, cost: float, stalls: dict[int, float] | None = None,
          late: dict[int, float] | None = None) -> list[float]:  # fmt: skip
    """The engine's loop on a simulated wall clock: it sleeps until a tick is due (waking
    ``late[k]`` late), the tick takes ``cost`` (plus ``stalls[k]``). The wall time each tick
    ended at, in order."""
    stalls, late = stalls or {}, late or {}
    now, ends = start, list[float]()
    pacer.start(now)
    while now < until:
        k = len(ends)
        now = max(now, pacer.next + late.get(k, 0.0)) + cost + stalls.get(k, 0.0)
        pacer.ticked(now)
        ends.append(now)
    return ends


@pytest.mark.parametrize("rtf", [1.0, 4.0, 0.5])
def test_after_a_resume_the_sim_clock_never_leads_the_wall_clock(rtf: float) -> None:
    pacer = Pacer(DT, rtf)
    resumed = 1000.0  # long after the last tick: the pause owes no ticks
    ends = _loop(pacer, resumed, resumed + 2.0, cost=0.0002)
    for k, end in enumerate(ends, 1):
        assert k * DT <= (end - resumed) * rtf + 1e-9, k  # the k-th tick ran after its deadline
    assert ends[0] >= resumed + DT / rtf  # the first tick is a period after the resume, not at once
    assert pacer.behind_s(ends[-1]) == 0.0


def test_a_loop_that_cannot_keep_up_runs_evenly_and_counts_its_lag() -> None:
    pacer = Pacer(DT, 1.0)
    cost = 1.5 * DT  # every tick takes half again the time real time allows
    ends = _loop(pacer, 0.0, 10.0, cost)
    gaps = [b - a for a, b in itertools.pairwise(ends)]
    assert min(gaps) == pytest.approx(cost) and max(gaps) == pytest.approx(cost)  # no burst, no freeze
    achieved = len(ends) * DT / ends[-1]
    assert achieved == pytest.approx(1 / 1.5, rel=0.01)
    # what it lost: the wall time run minus the sim time made, within a tick or two
    assert pacer.behind_s(ends[-1]) == pytest.approx(ends[-1] - len(ends) * DT, abs=2 * cost)


def test_a_stall_costs_its_time_and_is_followed_by_at_most_one_tick_at_once() -> None:
    pacer = Pacer(DT, 1.0)
    ends = _loop(pacer, 0.0, 3.0, cost=0.001, stalls={30: 10 * DT})
    gaps = [b - a for a, b in itertools.pairwise(ends)]
    quick = [i for i, g in enumerate(gaps) if g < DT * 0.9]
    assert quick == [30]  # the tick after the stall runs at once; then the grid again
    assert pacer.behind_s(ends[-1]) == pytest.approx(10 * DT, abs=DT)  # the stall is not caught up


def test_a_short_stall_is_caught_up_and_the_grid_does_not_drift() -> None:
    """A garbage collection or a heavy tick costs a few periods now and then: a machine that
    keeps real time on average must hold it, so up to CATCH_UP_TICKS late is made up."""
    pacer = Pacer(DT, 1.0)
    ends = _loop(pacer, 0.0, 3.0, cost=0.001, stalls={30: 3 * DT})
    gaps = [b - a for a, b in itertools.pairwise(ends)]
    quick = [i for i, g in enumerate(gaps) if g < DT * 0.9]
    assert quick == [30, 31, 32]  # three ticks at once, then the grid again
    assert pacer.behind_s(ends[-1]) == 0.0
    assert ends[-1] == pytest.approx(len(ends) * DT + 0.001, abs=1e-9)


def test_waking_late_by_less_than_a_tick_is_caught_up() -> None:
    pacer = Pacer(DT, 1.0)
    ends = _loop(pacer, 0.0, 2.0, cost=0.001, late={k: 0.6 * DT for k in range(0, 60, 7)})
    assert pacer.behind_s(ends[-1]) == 0.0
    assert ends[-1] == pytest.approx(len(ends) * DT + 0.001, abs=1e-9)  # the grid did not drift


def test_unpaced_is_never_behind() -> None:
    pacer = Pacer(DT, 0.0)
    pacer.start(5.0)
    assert pacer.due(5.0) and pacer.wait(5.0) == 0.0
    pacer.ticked(6.0)
    assert pacer.behind_s(100.0) == 0.0


def _warnings(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == "simd.engine.pacing"]


def test_falling_behind_is_said_once_and_recovering_once(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger="simd.engine.pacing")
    watch = LagWatch()
    watch.judge(0.0, 0.2, 0.5, 1.0)  # under a second measured: not judged yet
    assert not watch.behind and not _warnings(caplog)
    for t in range(1, 20):  # a long overload, wobbling
        watch.judge(float(t), 0.5 + 0.05 * (t % 3), 2.0, 1.0, lambda: "; 900 robots")
    assert watch.behind
    assert _warnings(caplog) == ["falling behind: running at 0.55x of the target 1x; 900 robots"]
    watch.judge(20.0, 0.95, 2.0, 1.0)  # better, but within the hysteresis band: still behind
    assert watch.behind and len(_warnings(caplog)) == 1
    watch.judge(21.0, 0.99, 2.0, 1.0)
    assert not watch.behind
    assert _warnings(caplog)[1:] == ["caught up: running at 0.99x of the target 1x again"]
    # it falls behind again soon after: counted, not said, until a minute has passed
    watch.judge(30.0, 0.5, 2.0, 1.0)
    watch.judge(31.0, 1.0, 2.0, 1.0)
    assert len(_warnings(caplog)) == 2
    watch.judge(90.0, 0.5, 2.0, 1.0)
    assert _warnings(caplog)[2:] == ["falling behind: running at 0.50x of the target 1x (1 more episodes since the "
                                     "last warning)"]  # fmt: skip
    watch.stopped("paused")
    assert not watch.behind and _warnings(caplog)[3:] == ["no longer falling behind: paused"]


def test_the_tick_cost_gives_the_robots_that_fit_in_real_time() -> None:
    cost = TickCost()
    assert cost.capacity(DT) == 0  # nothing measured
    for _ in range(50):
        cost.record(0, 0.001)  # the loop alone: 1 ms
    for _ in range(50):
        cost.record(100, 0.011)  # 100 robots: 0.1 ms each (no smaller fleet measured: net of the empty tick)
    assert cost.mean_s == pytest.approx(0.011)
    assert cost.capacity(DT) == int((DT - 0.001) / 0.0001)


def test_the_first_robots_fixed_costs_are_not_counted_as_every_robots() -> None:
    """Having robots at all costs a tick more than each robot does (its messages are put, the
    navigator runs): 10 ms here, and 0.5 ms per robot. A few robots give no estimate; two
    counts give the slope, and the capacity of a machine that keeps 44 such robots."""
    cost = TickCost()
    for _ in range(50):
        cost.record(0, 0.001)
    for n in (1, 4, 10, 19):
        for _ in range(20):
            cost.record(n, 0.011 + 0.0005 * n)
        assert cost.capacity(DT) == 0, n  # too few to tell: (tick - empty) / robots said 10 at 4 robots
    for _ in range(20):
        cost.record(40, 0.011 + 0.0005 * 40)
    assert cost.capacity(DT) == math.floor((DT - 0.011) / 0.0005) == 44
    for _ in range(20):  # the fleet shrinks to 30: the slope from the largest count at most half of it
        cost.record(30, 0.011 + 0.0005 * 30)
    assert cost.capacity(DT) == 44


def test_the_clock_a_spawn_that_crosses_it_and_a_refused_spawn_say_the_capacity(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.WARNING, logger="simd.engine.engine")
    wall = FakeWall()
    sim = Simulation(load_world("empty"), SimConfig(noise=False, max_robots=45))
    e = Engine(sim, lockstep=True, clock=wall, cpu_clock=wall)
    r = Recorder()

    def costs(snapshot: TickSnapshot) -> None:  # each tick takes (fake) time: 11 ms with robots, 0.5 ms each
        wall.now += 0.001 if not snapshot.namespaces else 0.011 + 0.0005 * len(snapshot.namespaces)

    r.on_tick = costs  # type: ignore[method-assign]
    e.attach(r)

    def spawn(k: int) -> object:
        name = f"r{k}"
        e.submit(control.SpawnRequest(name=name, x=float(k % 10) * 2 - 9, y=float(k // 10) * 2 - 9), r.reply(name))
        e.serve_pending()
        return dict(r.log)[name]

    def run(ticks: int) -> None:
        for _ in range(ticks):
            e.tick()

    run(20)
    for k in range(20):
        spawn(k)
        run(1 if k not in (9, 19) else 20)  # 10 and 20 robots measured
    clock = e.clock()
    assert clock.tick_s == pytest.approx(0.021) and clock.capacity_robots == 44
    assert not caplog.records
    for k in range(20, 45):  # the 45th crosses it: said at once
        spawn(k)
    assert [m.getMessage() for m in caplog.records] == [
        "45 robots: more than the about 44 like these this machine keeps in real time (measured); expect the "
        "simulation to fall behind"
    ]
    run(20)
    refused = spawn(45)
    assert isinstance(refused, FleetError) and refused.code is ErrorCode.ROBOT_LIMIT
    assert str(refused) == (
        "robot_limit: the daemon's robot limit (45) is reached; this machine keeps about 44 robots like these in "
        "real time (measured)"
    )
    assert clock.behind_s == 0.0 and not clock.falling_behind  # lockstep is never behind
    stepped = e.clock(measured_cost=False)  # as a step's reply has it: nothing measured in it
    assert (stepped.tick_s, stepped.capacity_robots) == (0.0, 0)


def test_the_factor_is_measured_over_seconds_however_fast_the_ticks_come() -> None:
    meter = RtfMeter()
    meter.restart(0.0, 0.0)
    for k in range(1, 100_001):  # 10 kHz ticks for 10 s, at 300x
        meter.record(k * 1e-4, k * DT)
    assert 2.0 <= meter.span() < 2.1 and len(meter.window) < 600
    assert meter.measure() == pytest.approx(DT / 1e-4)
