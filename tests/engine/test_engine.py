"""The engine through its seam, in-process: a recording adapter sees every tick, event and
reply in the engine's order. Time is the engine's injected clock or lockstep ticks; nothing
here waits on the wall clock."""

from __future__ import annotations

import math
import signal
import threading
from collections.abc import Mapping

import numpy as np
import pytest

from protocol import control
from protocol.errors import ErrorCode, FleetError
from protocol.messages import Twist, Vector3
from simd.core.sim import SimConfig, Simulation
from simd.core.snapshot import TickSnapshot
from simd.core.worldfile import load_world
from simd.engine import Engine
from simd.engine.pacing import RtfMeter
from simd.engine.ports import (
    Deleted,
    Event,
    PlaceRequest,
    Reply,
    Result,
    RobotList,
    Spawned,
    StepResult,
    WorldReset,
)


class Recorder:
    """An adapter that keeps everything the engine tells it, in order."""

    def __init__(self) -> None:
        self.log: list[tuple[str, object]] = []
        self.commands: dict[str, tuple[float, float]] = {}

    def on_tick(self, snapshot: TickSnapshot) -> None:
        self.log.append(("tick", snapshot))

    def on_event(self, event: Event) -> None:
        self.log.append(("event", event))

    def on_clock(self, clock: object) -> None:
        self.log.append(("clock", clock))

    def take_commands(self) -> Mapping[str, tuple[float, float]]:
        cmds, self.commands = self.commands, {}
        return cmds

    def dropped_commands(self) -> int:
        return 7

    def close(self) -> None:
        pass

    def reply(self, name: str) -> Reply:
        def reply(result: Result | FleetError) -> None:
            self.log.append((name, result))

        return reply

    def kinds(self) -> list[str]:
        return [k for k, _ in self.log if k != "clock"]


class FakeWall:
    """The engine's wall clock, advanced by the test."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def engine(lockstep: bool = True, clock: FakeWall | None = None) -> tuple[Engine, Recorder]:
    sim = Simulation(load_world("empty"), SimConfig(noise=False))
    e = Engine(sim, lockstep=lockstep) if clock is None else Engine(sim, lockstep=lockstep, clock=clock)
    r = Recorder()
    e.attach(r)
    return e, r


def test_a_spawn_is_announced_before_its_reply_and_ticks_carry_it_after() -> None:
    e, r = engine(lockstep=True)
    e.submit(control.SpawnRequest(name="a", x=1.0), r.reply("spawned"))
    e.serve_pending()
    assert r.kinds() == ["event", "spawned"]
    event, reply = r.log[0][1], r.log[-1][1]
    assert isinstance(event, Spawned) and event.robot.name == "a" and event.time == 0.0
    assert reply == event.robot  # the reply is the core's value; the adapter makes its message
    e.tick()
    snap = r.log[-1][1]
    assert isinstance(snap, TickSnapshot) and snap.namespaces == ["a"] and snap.tick == 1


def test_requests_are_dispatched_by_type_and_errors_reach_the_reply() -> None:
    e, r = engine(lockstep=True)
    requests: list[tuple[str, control.Request]] = [
        ("list", control.ListRequest()),
        ("clock", control.ClockRequest()),
        ("delete", control.DeleteRequest(name="nobody")),
        ("resume", control.ResumeRequest()),
    ]
    for name, req in requests:
        e.submit(req, r.reply(name))
    e.serve_pending()
    got = dict(r.log)
    assert isinstance(got["list"], RobotList) and got["list"].robots == []
    assert got["clock"].lockstep and got["clock"].dropped_commands == 7  # type: ignore[attr-defined]
    assert isinstance(got["delete"], FleetError) and got["delete"].code is ErrorCode.NOT_FOUND
    assert isinstance(got["resume"], FleetError) and got["resume"].code is ErrorCode.NOT_ALLOWED


def test_the_in_process_list_gives_the_named_robots_and_pages_and_refuses_bad_ones() -> None:
    e, r = engine(lockstep=True)
    for k, name in enumerate(["c", "a", "b"]):
        e.submit(control.SpawnRequest(name=name, x=float(k)), r.reply("spawned"))
    asks = {
        "named": control.ListRequest(names=["b", "c", "nobody"]),
        "page": control.ListRequest(after="a", limit=1),
        "bad": control.ListRequest(limit=-1),
    }
    for what, request in asks.items():
        e.submit(request, r.reply(what))
    e.serve_pending()
    got = dict(r.log)
    assert [s.name for s in got["named"].robots] == ["c", "b"]  # type: ignore[attr-defined]  # spawn order
    assert [s.name for s in got["page"].robots] == ["b"]  # type: ignore[attr-defined]  # name order, after "a"
    assert isinstance(got["bad"], FleetError) and got["bad"].code is ErrorCode.INVALID_VALUE


def test_a_full_inbox_refuses_at_once_and_never_replies_later() -> None:
    e, r = engine(lockstep=True)
    sent = 0
    with pytest.raises(FleetError) as busy:
        while True:
            e.submit(control.ClockRequest(), r.reply("clock"))
            sent += 1
    assert busy.value.code is ErrorCode.BUSY and sent > 0
    assert r.log == []  # the refusal was the exception, not a reply
    e.serve_pending()
    replies = [v for k, v in r.log if k == "clock"]
    assert len(replies) == sent and not any(isinstance(v, FleetError) for v in replies)


def test_a_step_runs_in_slices_and_serves_requests_between_them() -> None:
    wall = FakeWall()
    e, r = engine(lockstep=True, clock=wall)
    e.submit(control.SpawnRequest(name="a"), r.reply("spawned"))
    e.serve_pending()
    ticks_before_list: list[int] = []

    def advance_wall(snapshot: TickSnapshot) -> None:  # every tick takes 5 ms of (fake) wall time
        wall.now += 0.005
        if snapshot.tick == 10:  # a request arrives during the step
            e.submit(control.ListRequest(), lambda res: ticks_before_list.append(e.sim.tick))

    r.on_tick = advance_wall  # type: ignore[method-assign]
    e.submit(control.StepRequest(ticks=40), r.reply("step"))
    thread = threading.Thread(target=e.run)
    thread.start()
    try:
        for _ in range(500):
            if any(k == "step" for k, _ in r.log):
                break
            threading.Event().wait(0.01)
    finally:
        e.stop()
        thread.join(5)
    result = dict(r.log)["step"]
    assert isinstance(result, StepResult) and result.ticks_run == 40 and not result.cancelled
    # slices of ~20 ms of 5 ms ticks: the list was served at the end of the slice that held
    # tick 10, while the step still had ticks to run
    assert len(ticks_before_list) == 1 and 10 <= ticks_before_list[0] < 16


def test_pause_and_reset_cancel_a_step_and_say_how_far_it_got() -> None:
    e, r = engine(lockstep=True)
    e.submit(control.SpawnRequest(name="a"), r.reply("spawned"))
    e.serve_pending()
    e.submit(control.StepRequest(ticks=1000), r.reply("step"))
    e.serve_pending()  # queued: nothing ran yet
    e.tick()
    e.tick()
    e.submit(control.ResetRequest(), r.reply("reset"))
    e.serve_pending()
    step = dict(r.log)["step"]
    assert isinstance(step, StepResult) and step.cancelled and step.ticks_run == 0  # ticks outside the job
    reset_at = [k for k, _ in r.log].index("event", 2)
    assert isinstance(r.log[reset_at][1], WorldReset)
    assert [k for k, _ in r.log].index("step") < reset_at  # the step's reply before the reset's event
    assert e.sim.tick == 0


def test_a_steps_commands_hold_and_observations_come_back() -> None:
    e, r = engine(lockstep=True)
    e.submit(control.SpawnRequest(name="a"), r.reply("spawned"))
    e.serve_pending()
    go = {"a": Twist(linear=Vector3(x=0.2))}
    e.submit(control.StepRequest(ticks=30, cmd_vel=go, observe=["a"]), r.reply("step"))
    e.serve_pending()
    while not any(k == "step" for k, _ in r.log):
        e._run_slice()
    step = dict(r.log)["step"]
    assert isinstance(step, StepResult) and step.ticks_run == 30
    assert step.states["a"].linear_velocity == pytest.approx(0.2)  # 1 s: the 0.5 s watchdog did not stop it
    assert step.scans["a"].ranges.shape == (360,) and step.scans["a"].time <= 1.0


@pytest.mark.parametrize("lockstep", [True, False], ids=["lockstep", "paused"])
def test_a_steps_reply_carries_the_clock_the_engine_says_after_it(lockstep: bool) -> None:
    """A step's clock is made without the engine's status (a learner's step of one robot
    notices the status): it must be the status's clock without the measured cost, the
    adapters' dropped commands counted."""
    wall = FakeWall()
    e, r = engine(lockstep=lockstep, clock=wall)
    if not lockstep:
        e.submit(control.ResumeRequest(), r.reply("resumed"))
        e.serve_pending()
        for _ in range(4):  # time runs for a while: a measured factor, a cost
            wall.now += 1 / 30
            e.tick()
        e.submit(control.PauseRequest(), r.reply("paused"))
    e.submit(control.SpawnRequest(name="a"), r.reply("spawned"))
    e.serve_pending()
    step = _packed_step(e, r, 7, ["a"])
    wall.now += 5.0
    assert step.clock == e._status(measured_cost=False).clock(wall.now, 7)
    assert step.clock.tick == e.sim.tick and step.clock.robots == 1 and step.clock.dropped_commands == 7
    assert step.clock.paused and step.clock.lockstep == lockstep


def test_a_steps_commands_are_written_again_after_a_request_between_its_slices() -> None:
    """Without a watchdog the commands a step wrote at a tick are still there at the next one
    of the same slice, and are not written again; a request served between two slices may
    change them (a placed robot stands still), so each slice writes them at its first tick."""
    wall = FakeWall()
    sim = Simulation(load_world("empty"), SimConfig(noise=False, cmd_timeout=0))
    e = Engine(sim, lockstep=True, clock=wall)
    r = Recorder()
    e.attach(r)
    e.submit(control.SpawnRequest(name="a"), r.reply("spawned"))
    e.serve_pending()

    def tick_takes_5_ms(snapshot: TickSnapshot) -> None:
        wall.now += 0.005
        if snapshot.tick == 10:  # served after the slice that holds tick 10: the robot stops
            e.submit(PlaceRequest("a", 1.0, 0.0, 0.0), r.reply("placed"))

    r.on_tick = tick_takes_5_ms  # type: ignore[method-assign]
    go = {"a": Twist(linear=Vector3(x=0.2))}
    e.submit(control.StepRequest(ticks=30, cmd_vel=go, observe=["a"]), r.reply("step"))
    e.serve_pending()
    placed_at = None
    while e._steps:
        e._run_slice()
        e.serve_pending()
        if placed_at is None and any(k == "placed" for k, _ in r.log):
            placed_at = e.sim.tick
    step = dict(r.log)["step"]
    assert placed_at is not None and 10 <= placed_at < 20
    assert isinstance(step, StepResult) and step.ticks_run == 30
    assert e.sim.robots.target_v[0] == 0.2 and step.states["a"].linear_velocity == pytest.approx(0.2)
    assert step.states["a"].x > 1.0  # it drove on from where it was placed


def _packed_step(e: Engine, r: Recorder, ticks: int, observe: list[str]) -> StepResult:
    e.submit(control.StepRequest(ticks=ticks, observe=observe, packed=True), r.reply("step"))
    e.serve_pending()
    while not any(k == "step" for k, _ in r.log):
        e._run_slice()
    step = r.log.pop(next(i for i, (k, _) in enumerate(r.log) if k == "step"))[1]
    assert isinstance(step, StepResult) and step.packed is not None
    return step


def _newest_scans(
    r: Recorder, names: list[str], born: dict[str, int] | None = None
) -> tuple[list[float], list[object]]:
    """Each robot's newest scan in the ticks the recorder saw since the last reset (the
    reference); ``born``: robots spawned again, with the log's length when they were."""
    times: list[float] = []
    scans: list[object] = []
    for ns in names:
        log = r.log[(born or {}).get(ns, 0) :]
        ticks = [s for k, s in log if k == "tick" and isinstance(s, TickSnapshot)]
        found = next(
            ((s.time, s.scans[s.scan_namespaces.index(ns)]) for s in reversed(ticks) if ns in s.scan_namespaces), None
        )
        times.append(found[0] if found else math.nan)
        scans.append(found[1] if found else None)
    return times, scans


@pytest.mark.parametrize(
    "asked",
    [["r5", "r0", "r3", "r6", "r1"], [f"r{i}" for i in range(7)], ["r5", "r0", "r3", "r5", "r1"]],
    ids=["some robots", "every robot in table order", "a robot named twice"],
)
def test_a_packed_step_returns_each_robots_newest_scan_whatever_changed_meanwhile(asked: list[str]) -> None:
    """The newest scans are read from the last few ticks' snapshots while the table stays put
    and looked up robot by robot after a spawn or delete: both must give what the ticks said
    (a robot deleted and spawned again under its name has no scan until it scans)."""
    e, r = engine(lockstep=True)
    for i in range(7):
        e.submit(control.SpawnRequest(name=f"r{i}", x=float(i) - 3.0), r.reply("spawned"))
    e.serve_pending()
    changes = [(13, None), (4, None), (2, "delete r3"), (1, None), (9, "spawn r9"), (3, None), (6, None)]
    changes += [(40, None), (1, "respawn r1"), (2, None), (7, None)]
    born: dict[str, int] = {}
    for ticks, change in changes:
        if change == "delete r3":
            e.submit(control.DeleteRequest(name="r3"), r.reply("deleted"))
            asked = [a for a in asked if a != "r3"]
        elif change == "spawn r9":
            e.submit(control.SpawnRequest(name="r9", x=3.5), r.reply("spawned"))
            asked = [*asked, "r9"]
        elif change == "respawn r1":
            e.submit(control.DeleteRequest(name="r1"), r.reply("deleted"))
            e.submit(control.SpawnRequest(name="r1", x=4.5), r.reply("spawned"))
            born["r1"] = len(r.log)  # the old r1's scans are not the new one's
        e.serve_pending()
        step = _packed_step(e, r, ticks, asked)
        p = step.packed
        assert p is not None and p.names == asked
        times, scans = _newest_scans(r, asked, born)
        np.testing.assert_array_equal(p.scan_time, times)
        for k, want in enumerate(scans):
            if want is None:
                assert np.isnan(p.ranges[k]).all()
            else:
                np.testing.assert_array_equal(p.ranges[k], want)
        last = [s for k, s in r.log if k == "tick"][-1]
        assert isinstance(last, TickSnapshot)
        rows = [last.namespaces.index(e.sim.find(a).namespace) for a in asked]  # type: ignore[union-attr]
        np.testing.assert_array_equal(p.odom[:, 0], last.x[rows])
        np.testing.assert_array_equal(p.odom[:, 5], last.angular_z[rows])


def _commanded_step(e: Engine, r: Recorder, names: list[str], values: list[tuple[float, float]]) -> object:
    """One tick with ``commands`` (the same list object each time, as a learner sends it)."""
    twist = np.array(values, dtype="<f8").tobytes()
    req = control.StepRequest(ticks=1, commands=control.PackedCommands(names=names, twist=twist), observe=names)
    e.submit(req, r.reply("step"))
    e.serve_pending()
    while e._steps:
        e._run_slice()
    return r.log.pop(next(i for i, (k, _) in enumerate(r.log) if k == "step"))[1]


def test_a_learners_repeated_name_list_reaches_the_right_robots_after_the_table_changes() -> None:
    """The rows of a name list sent step after step are looked up once while the table stays
    put: a delete (rows shift) or a spawn must be seen, and a bad list refused every time."""
    e, r = engine(lockstep=True)
    for i in range(3):
        e.submit(control.SpawnRequest(name=f"r{i}", x=2.0 * i), r.reply("spawned"))
    e.serve_pending()
    t = e.sim.robots

    def targets(name: str) -> tuple[float, float]:
        row = t.row_of(name)
        assert row is not None
        return float(t.target_v[row]), float(t.target_w[row])

    names = ["r2", "r1"]
    for _ in range(2):  # the second time from the memo
        result = _commanded_step(e, r, names, [(0.2, 0.0), (0.0, 1.0)])
        assert isinstance(result, StepResult) and list(result.states) == ["r2", "r1"]
        assert targets("r2") == (0.2, 0.0) and targets("r1") == (0.0, 1.0) and targets("r0") == (0.0, 0.0)
    e.submit(control.DeleteRequest(name="r0"), r.reply("deleted"))  # r1 and r2 move up a row
    e.serve_pending()
    result = _commanded_step(e, r, names, [(0.0, -1.0), (0.1, 0.0)])
    assert isinstance(result, StepResult) and list(result.states) == ["r2", "r1"]
    assert targets("r2") == (0.0, -1.0) and targets("r1") == (0.1, 0.0)
    e.submit(control.DeleteRequest(name="r1"), r.reply("deleted"))
    e.serve_pending()
    for _ in range(2):
        refused = _commanded_step(e, r, names, [(0.0, 0.0), (0.0, 0.0)])
        assert isinstance(refused, FleetError) and refused.code is ErrorCode.NOT_FOUND
    twice = ["r2", "r2"]
    for _ in range(2):
        refused = _commanded_step(e, r, twice, [(0.0, 0.0), (0.0, 0.0)])
        assert isinstance(refused, FleetError) and "more than once" in str(refused)


def test_the_rtf_meter_measures_from_a_resume_on_an_injected_clock() -> None:
    m = RtfMeter()
    assert m.measure() is None
    m.restart(10.0, 5.0)
    assert m.measure() is None  # one point: nothing to measure yet
    m.record(10.5, 5.25)
    assert m.measure() == pytest.approx(0.5)
    m.restart(20.0, 5.25)  # a pause and a resume in between must not count
    m.record(21.0, 7.25)
    assert m.measure() == pytest.approx(2.0)


def test_a_delete_is_announced_and_the_robot_leaves_the_next_tick() -> None:
    e, r = engine(lockstep=True)
    for n in ("a", "b"):
        e.submit(control.SpawnRequest(name=n, x=0.0 if n == "a" else 2.0), r.reply("spawned"))
    e.serve_pending()
    e.tick()
    e.submit(control.DeleteRequest(name="a"), r.reply("deleted"))
    e.submit(control.PauseRequest(), r.reply("paused"))
    e.serve_pending()
    kinds = r.kinds()
    assert kinds[-3:] == ["event", "deleted", "paused"]
    assert isinstance(r.log[[k for k, _ in r.log].index("deleted") - 1][1], Deleted)
    e.tick()
    last = r.log[-1][1]
    assert isinstance(last, TickSnapshot) and last.namespaces == ["b"]


class Buffering(Recorder):
    """An adapter whose commands arrive on the engine's (fake) wall clock, ``rate`` a second,
    and wait in its buffer until the engine takes them, as the fleet adapter's cmd_vel ring
    does; it counts the most the buffer ever held."""

    def __init__(self, wall: FakeWall, rate: float) -> None:
        super().__init__()
        self.wall, self.rate = wall, rate
        self.taken_at = wall.now
        self.most_held = 0

    def held(self) -> int:
        return round((self.wall.now - self.taken_at) * self.rate)

    def take_commands(self) -> Mapping[str, tuple[float, float]]:
        self.most_held = max(self.most_held, self.held())
        self.taken_at = self.wall.now
        return super().take_commands()


def test_a_paused_engine_keeps_draining_commands_while_requests_keep_coming() -> None:
    """Paused, with a request every 50 ms (the soak's churn, lists and hostile queries), the
    engine drained the adapters' commands only after 0.25 s without any request: never, so
    5 s of 1 000 robots' cmd_vel waited in the ring, ~50 000 samples whose memory the daemon
    kept (docs/robustness.md). It drains them once a tick period, as when running."""
    wall = FakeWall()
    sim = Simulation(load_world("empty"), SimConfig(noise=False))
    e = Engine(sim, paused=True, clock=wall)
    rate = 10_000.0  # 1 000 robots at 10 Hz
    r = Buffering(wall, rate)
    e.attach(r)
    requests, done = 40, threading.Event()
    answered: list[Result | FleetError] = []

    def next_request(result: Result | FleetError) -> None:  # on the simulation thread
        answered.append(result)
        wall.now += 0.05
        if len(answered) < requests:
            e.submit(control.ListRequest(), next_request)
        else:
            done.set()

    e.submit(control.ListRequest(), next_request)
    thread = threading.Thread(target=e.run)
    thread.start()
    try:
        assert done.wait(30)
    finally:
        e.stop()
        thread.join(5)
    assert not thread.is_alive() and all(isinstance(a, RobotList) for a in answered)
    assert e.sim.tick == 0  # paused: no tick took the commands
    most = max(r.most_held, r.held())  # (what still waits counts too)
    assert most <= rate * (sim.config.dt + 0.05), most  # a tick period and a request's worth, not 2 s


def test_a_stop_signal_that_lands_inside_the_request_queue_still_stops_the_loop() -> None:
    """SIGTERM's handler runs on the simulation thread between two bytecodes, maybe while the
    loop holds its request queue's lock: stopping there must not take that lock on the spot
    (a daemon once waited for itself forever and ignored SIGTERM)."""
    from simd.cli import stopping_handler

    e, _ = engine(lockstep=True)
    handler = stopping_handler(e)
    thread = threading.Thread(target=e.run)
    thread.start()
    with e._inbox.mutex:  # as if the signal came while the loop was inside the queue's get
        handler(signal.SIGTERM, None)  # returns at once: the stop waits for the lock elsewhere
    thread.join(10.0)
    assert not thread.is_alive() and e.stop_event.is_set()
