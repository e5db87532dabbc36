"""Spawns, deletes and a resume answered at once while the simulation runs (simd/engine/promises.py):
every such answer is the one the simulation thread gives when it serves the same requests one by
one, they take effect before the next tick in the order asked, and what cannot be certain is left
to the simulation thread. Lockstep engines and an injected wall clock; no test waits on time."""

from __future__ import annotations

import msgspec
import pytest
from hypothesis import event, given, settings
from hypothesis import strategies as st

from protocol import control
from protocol.control import Clock
from protocol.errors import ErrorCode, FleetError
from protocol.keys import Keys
from simd.core.sim import SimConfig, Simulation
from simd.core.snapshot import RobotState, TickSnapshot
from simd.core.worldfile import load_world
from simd.engine import Engine
from simd.engine.ports import Deleted, Spawned
from simd.engine.promises import MARGIN_M, _rows_of
from simd.engine.status import Roster
from simd.wire import convert
from tests.engine.test_at_once import Rushing, _run_until
from tests.engine.test_engine import Recorder


def _engine(world: str = "turtlebot3_world", *, running: bool = True, max_robots: int = 5) -> tuple[Engine, Recorder]:
    sim = Simulation(load_world(world), SimConfig(noise=False, max_robots=max_robots))
    e = Engine(sim, lockstep=not running, clock=Rushing())
    r = Recorder()
    e.attach(r)
    return e, r


def _served(e: Engine, request: control.Request) -> object:
    """What the simulation thread answers to ``request``, served now."""
    answers: list[object] = []
    e.submit(request, answers.append)
    e.serve_pending()
    return answers[0]


def _wire(answer: object) -> object:
    """What a client gets of an answer: the message's bytes, or the error's code and text."""
    if isinstance(answer, FleetError):
        return (answer.code, str(answer))
    assert isinstance(answer, RobotState), answer
    return msgspec.msgpack.encode(convert.robot_record(answer, Keys()))


def _listed(r: Roster) -> tuple[object, ...]:
    """What a robot list says of a roster (names, spawn records' parts, pose and twist columns)."""
    robots = [(robot.name, robot.namespace, robot.model.name, robot.spawn_pose) for robot in r.robots]
    columns = [c.tolist() for c in (r.x, r.y, r.yaw, r.linear, r.angular, r.lateral)]
    return r.names, r.namespaces, robots, columns


def _fleet(e: Engine) -> list[tuple[str, str, str, float, float, float]]:
    return [(s.name, s.namespace, s.model.name, s.x, s.y, s.yaw) for s in e.sim.states()]


# free places in turtlebot3_world (between the pillars and the walls), a pillar, and off the map
_PLACES = [(-2.0, -0.5), (-2.0, 0.5), (-1.7, -0.5), (0.5, 1.8), (0.5, -2.0), (2.2, 0.0), (-1.1, -1.1), (9.0, 0.0)]
_request = st.one_of(
    st.builds(
        lambda name, ns, place, yaw, model: control.SpawnRequest(
            name=name, namespace=ns, x=place[0], y=place[1], yaw=yaw, model=model
        ),
        st.sampled_from(["a", "b", "c", "d", "e", "f", ""]),
        st.sampled_from(["", "a", "g"]),
        st.sampled_from(_PLACES),
        st.sampled_from([0.0, 1.0, float("nan")]),
        st.sampled_from(["burger", "waffle", "waffle_pi", "tank"]),
    ),
    st.builds(lambda name: control.DeleteRequest(name=name), st.sampled_from(["a", "b", "c", "g", "zz"])),
    st.just("serve"),
)


@settings(max_examples=150, deadline=None)
@given(st.lists(_request, max_size=30))
def test_every_answer_given_at_once_is_the_simulation_threads(requests: list[object]) -> None:
    at_once, _ = _engine(running=True)
    serial, _ = _engine(running=False)
    for req in requests:
        if req == "serve":  # the simulation thread makes what was promised (between ticks)
            at_once.serve_pending()
            continue
        assert isinstance(req, (control.SpawnRequest, control.DeleteRequest))
        expected = _wire(_served(serial, req))
        answer: object = at_once.answer_at_once(req)
        event(f"{type(req).__name__} {'left to the simulation thread' if answer is None else 'at once'}")
        if answer is None:  # left to the simulation thread, after what was promised before it
            answer = _served(at_once, req)
        assert _wire(answer) == expected
        assert _listed(at_once.roster_now()) == _listed(serial.roster_now())  # the list counts promises
    at_once.serve_pending()
    assert _fleet(at_once) == _fleet(serial)
    assert not at_once._promises and at_once._waiting == 0


def test_a_spawn_asked_during_a_tick_is_answered_then_and_in_the_next_tick() -> None:
    e, r = _engine(running=True)
    e.submit(control.SpawnRequest(name="a", x=-2.0, y=-0.5), r.reply("spawned"))
    e.serve_pending()
    answers: list[object] = []
    take = r.take_commands

    def take_commands() -> dict[str, tuple[float, float]]:  # at the start of every tick
        if e.sim.tick == 4 and not answers:  # tick 5 is being computed
            answers.append(e.answer_at_once(control.SpawnRequest(name="b", x=0.5, y=1.8, yaw=1.0)))
            answers.append(e.answer_at_once(control.ClockRequest()))
            answers.append(e.roster_now())
        return dict(take())

    r.take_commands = take_commands  # type: ignore[method-assign]
    _run_until(e, lambda: e.sim.tick >= 7)
    spawned, clock, roster = answers
    assert isinstance(spawned, RobotState) and (spawned.name, spawned.x, spawned.y, spawned.yaw) == ("b", 0.5, 1.8, 1.0)
    assert isinstance(clock, Clock) and clock.robots == 2  # the clock counts it from the answer on
    assert isinstance(roster, Roster) and [robot.name for robot in roster.robots] == ["a", "b"]  # so does the list
    assert roster.x[1] == 0.5
    ticks = {s.tick: s.namespaces for k, s in r.log if k == "tick" and isinstance(s, TickSnapshot)}
    assert ticks[5] == ["a"] and ticks[6] == ["a", "b"]  # made before the next tick
    events = [v for k, v in r.log if k == "event"]
    assert isinstance(events[-1], Spawned) and events[-1].robot == spawned  # as the simulation thread tells it
    assert [k for k, _ in r.log].count("spawned") == 1  # b's answer was given once, at once


def test_a_delete_answered_at_once_is_gone_from_the_next_tick_and_frees_its_name_and_place() -> None:
    e, r = _engine(running=True)
    for name, x in (("a", -2.0), ("b", 2.2)):
        e.submit(control.SpawnRequest(name=name, x=x, y=0.0 if name == "b" else -0.5), r.reply("spawned"))
    e.serve_pending()
    e.tick()
    gone = e.answer_at_once(control.DeleteRequest(name="a"))
    assert isinstance(gone, RobotState) and gone.name == "a" and (gone.x, gone.y) == (-2.0, -0.5)
    assert [robot.name for robot in e.roster_now().robots] == ["b"]
    again = e.answer_at_once(control.SpawnRequest(name="a", x=-2.0, y=-0.5))  # where a stands until made
    assert isinstance(again, RobotState)
    assert e.answer_at_once(control.DeleteRequest(name="zz")) is None  # not there: the simulation thread says so
    e.serve_pending()
    assert [s.name for s in e.sim.states()] == ["b", "a"]
    kinds = [(type(v).__name__, v.robot.name) for k, v in r.log if k == "event" and isinstance(v, (Spawned, Deleted))]
    assert kinds[-2:] == [("Deleted", "a"), ("Spawned", "a")]


def test_the_roster_of_the_same_promises_is_made_once() -> None:
    """A list asked again while the same promises wait gets the same roster object (its records
    and their layout are then not made again), and a new promise makes a new one."""
    e, r = _engine(running=True)
    for name, x in (("a", -2.0), ("b", 2.2)):
        e.submit(control.SpawnRequest(name=name, x=x, y=0.0 if name == "b" else -0.5), r.reply("spawned"))
    e.serve_pending()
    e.tick()
    assert isinstance(e.answer_at_once(control.DeleteRequest(name="a")), RobotState)
    first = e.roster_now()
    assert e.roster_now() is first and [robot.name for robot in first.robots] == ["b"]
    assert isinstance(e.answer_at_once(control.SpawnRequest(name="c", x=-2.0, y=-0.5)), RobotState)
    second = e.roster_now()
    assert second is not first and [robot.name for robot in second.robots] == ["b", "c"]
    assert e.roster_now() is second
    e.serve_pending()
    e.tick()
    made = e.roster_now()  # no promise waits: the simulation thread's own
    assert made is e.known().roster and [robot.name for robot in made.robots] == ["b", "c"]


def test_what_is_not_certain_is_left_to_the_simulation_thread() -> None:
    e, r = _engine(running=True)
    e.submit(control.SpawnRequest(name="a", x=-2.0, y=-0.5), r.reply("spawned"))
    e.serve_pending()
    radius = e.sim.robots.robots[0].model.radius
    near = -2.0 + 2 * radius + MARGIN_M / 2  # clear of a's body, within the margin
    assert e.answer_at_once(control.SpawnRequest(name="b", x=near, y=-0.5)) is None
    assert e.answer_at_once(control.SpawnRequest(name="a", x=0.5, y=1.8)) is None  # name taken
    assert e.answer_at_once(control.SpawnRequest(name="b", x=-1.1, y=-1.1)) is None  # on a pillar
    e.submit(control.ListRequest(), r.reply("list"))  # a request waiting: nothing promised behind it
    assert e.answer_at_once(control.SpawnRequest(name="b", x=0.5, y=1.8)) is None
    assert e.answer_at_once(control.DeleteRequest(name="a")) is None
    e.serve_pending()
    assert isinstance(e.answer_at_once(control.SpawnRequest(name="b", x=0.5, y=1.8)), RobotState)
    e.serve_pending()
    assert isinstance(_served(e, control.SpawnRequest(name="c", x=near, y=-0.5)), RobotState)  # it fits


def test_bad_fields_and_the_robot_limit_are_refused_at_once_counting_promises() -> None:
    e, _ = _engine(running=True, max_robots=2)
    bad = e.answer_at_once(control.SpawnRequest(name="a", x=float("nan")))
    assert isinstance(bad, FleetError) and bad.code is ErrorCode.NON_FINITE
    assert isinstance(e.answer_at_once(control.SpawnRequest(name="a", x=-2.0, y=-0.5)), RobotState)
    assert isinstance(e.answer_at_once(control.SpawnRequest(name="b", x=0.5, y=1.8)), RobotState)
    over = e.answer_at_once(control.SpawnRequest(name="c", x=2.2, y=0.0))
    assert isinstance(over, FleetError) and over.code is ErrorCode.ROBOT_LIMIT
    assert isinstance(e.answer_at_once(control.DeleteRequest(name="a")), RobotState)
    assert isinstance(e.answer_at_once(control.SpawnRequest(name="c", x=2.2, y=0.0)), RobotState)
    e.serve_pending()
    assert [s.name for s in e.sim.states()] == ["b", "c"]


def test_paused_or_in_lockstep_nothing_is_promised() -> None:
    for running in (False, True):
        e, _ = _engine(running=running)
        if running:
            _served(e, control.PauseRequest())
        assert e.paused
        assert e.answer_at_once(control.SpawnRequest(name="a", x=-2.0, y=-0.5)) is None


def test_a_resume_after_a_pause_not_yet_served_is_answered_at_once() -> None:
    e, r = _engine(running=True)
    answers: list[object] = []

    def on_tick_(snapshot: TickSnapshot) -> None:
        if snapshot.tick == 3 and not answers:  # between ticks: tick 3 is the pause's last
            answers.append(e.answer_at_once(control.PauseRequest()))
            answers.append(e.answer_at_once(control.ResumeRequest()))
            answers.append(e.answer_at_once(control.ClockRequest()))

    r.on_tick = on_tick_  # type: ignore[method-assign]
    _run_until(e, lambda: e.sim.tick >= 6)
    paused, resumed, clock = answers
    assert isinstance(paused, Clock) and paused.paused and paused.tick == 3
    assert isinstance(resumed, Clock) and not resumed.paused and resumed.tick == 3
    assert resumed.real_time_factor == resumed.target_real_time_factor and resumed.behind_s == 0.0
    assert isinstance(clock, Clock) and not clock.paused
    assert not e.paused
    topics = [v.paused for k, v in r.log if k == "clock" and isinstance(v, Clock)]
    assert True in topics and topics[-1] is False  # the clock topic was told of both, in order


@pytest.mark.parametrize("lockstep", [True, False])
def test_a_resume_with_no_pause_asked_is_left_to_the_simulation_thread(lockstep: bool) -> None:
    e, _ = _engine(running=not lockstep)
    assert e.answer_at_once(control.ResumeRequest()) is None


def test_a_pause_and_resume_not_yet_served_do_not_hold_promises_back() -> None:
    e, r = _engine(running=True)
    answers: list[object] = []

    def on_tick_(snapshot: TickSnapshot) -> None:
        if snapshot.tick == 3 and not answers:
            answers.append(e.answer_at_once(control.PauseRequest()))
            answers.append(e.answer_at_once(control.SpawnRequest(name="a", x=-2.0, y=-0.5)))
            answers.append(e.answer_at_once(control.ResumeRequest()))
            answers.append(e.answer_at_once(control.DeleteRequest(name="a")))

    r.on_tick = on_tick_  # type: ignore[method-assign]
    _run_until(e, lambda: e.sim.tick >= 6)
    paused, spawned, resumed, deleted = answers
    assert isinstance(paused, Clock) and isinstance(resumed, Clock) and not resumed.paused
    assert isinstance(spawned, RobotState) and isinstance(deleted, RobotState) and deleted.name == "a"
    made = [(type(v).__name__, v.robot.name) for k, v in r.log if k == "event" and isinstance(v, (Spawned, Deleted))]
    assert made == [("Spawned", "a"), ("Deleted", "a")] and len(e.sim) == 0 and not e.paused


def test_the_rows_of_the_robots_a_promise_deletes_are_found_however_many() -> None:
    names = [f"r{i}" for i in range(100)]
    for wanted in ({"r3", "r99", "zz"}, {f"r{i}" for i in range(0, 100, 3)} | {"zz"}):  # a few; many (one pass)
        assert sorted(_rows_of(names, wanted)) == sorted(int(n[1:]) for n in wanted if n != "zz")
