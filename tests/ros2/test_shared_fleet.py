"""A fleet shared by several daemons on ROS 2 (simd/adapters/ros2/shared_fleet.py), on zenoh
sessions in this process around a router on loopback: which daemon speaks for the fleet, and
how the daemons' replies to a service's request make one answer."""

from __future__ import annotations

import json
import queue
from collections.abc import Callable, Iterator
from typing import Any

import pytest
import zenoh

from clients import wait_until
from protocol.codec import encode
from protocol.control import (
    Clock,
    ClockRequest,
    DeleteRequest,
    ListRequest,
    PauseRequest,
    Pose2D,
    ResumeRequest,
    RobotList,
    RobotRecord,
    SpawnRequest,
    StepReply,
    StepRequest,
)
from protocol.errors import ErrorCode, FleetError
from protocol.keys import Keys
from protocol.messages import Time
from simd.adapters.ros2.session import ros_config
from simd.adapters.ros2.shared_fleet import FleetRequests, Speaker

KEYS = Keys("shared")


@pytest.fixture
def sessions(router: str) -> Iterator[Callable[[], zenoh.Session]]:
    """Sessions joined to the router as a daemon's ROS session joins rmw_zenohd; all closed after."""
    opened: list[zenoh.Session] = []

    def open_one() -> zenoh.Session:
        s = zenoh.open(ros_config(router))
        opened.append(s)
        return s

    yield open_one
    for s in opened:
        s.close()


class Told:
    """Counts a Speaker's ``changed`` calls."""

    def __init__(self) -> None:
        self.count = 0

    def __call__(self) -> None:
        self.count += 1


def test_the_daemon_serving_longest_speaks_and_the_next_takes_over(sessions: Callable[[], zenoh.Session]) -> None:
    told = {d: Told() for d in "abcz"}
    speakers: list[Speaker] = []

    def speaker(daemon_id: str, since: int, domain: int = 0, session: zenoh.Session | None = None) -> Speaker:
        s = Speaker(session or sessions(), KEYS, daemon_id, domain, "jazzy", told[daemon_id], since, settle_s=0.2)
        speakers.append(s)
        return s

    try:
        b_session = sessions()
        b = speaker("b", 100, session=b_session)
        assert b.speaker() is None  # listening for the others first: it says nothing yet
        assert wait_until(lambda: b.speaks(), 5.0) and told["b"].count == 1
        a = speaker("a", 200)  # a smaller id, but later: it does not take over
        c = speaker("c", 100)  # as long as b: the smaller id speaks
        z = speaker("z", 300, domain=1)  # another ROS domain has a voice of its own
        assert wait_until(lambda: a.speaker() is not None and c.speaker() is not None, 5.0)
        assert wait_until(lambda: (a.speaker(), c.speaker(), b.speaker()) == ("b", "b", "b"), 5.0)
        assert wait_until(lambda: z.speaks(), 5.0)
        assert told["b"].count == 1  # nobody who joined changed b's mind
        b_session.close()  # b's process ends: its token goes, c (since 100) takes over
        assert wait_until(lambda: c.speaks() and a.speaker() == "c", 10.0)
        assert told["c"].count >= 2 and told["a"].count >= 2  # settled, then b left
        assert z.speaks()
    finally:
        for s in speakers:
            s.close()


def _daemon(session: zenoh.Session, answers: dict[str, Callable[[zenoh.Query], None]]) -> list[Any]:
    """A stand-in daemon: on each key, a queryable that answers as given."""

    def on(answer: Callable[[zenoh.Query], None]) -> Callable[[zenoh.Query], None]:
        def handler(query: zenoh.Query) -> None:
            try:
                answer(query)
            finally:
                query.drop()

        return handler

    return [session.declare_queryable(key, on(answer)) for key, answer in answers.items()]


def _ok(message: object) -> Callable[[zenoh.Query], None]:
    return lambda q: q.reply(q.key_expr, encode(message))


def _refuse(code: ErrorCode, message: str = "no") -> Callable[[zenoh.Query], None]:
    return lambda q: q.reply_err(encode(FleetError(code, message).to_reply()))


def _skip(q: zenoh.Query) -> None:
    pass  # another daemon's business: no reply


def _record(name: str, daemon: str) -> RobotRecord:
    return RobotRecord(name=name, namespace=name, model="burger", pose=Pose2D(x=1.0, y=2.0, yaw=0.5), daemon=daemon)


def _clock(tick: int, **more: Any) -> dict[str, Any]:
    fields = dict(clock=Time.from_seconds(tick / 30), tick=tick, dt=1 / 30, paused=True, lockstep=True,
                  real_time_factor=0.0, target_real_time_factor=1.0, robots=1)  # fmt: skip
    return {**fields, **more}


def test_the_daemons_replies_make_one_answer(router: str) -> None:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([router]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    d1, d2, asker = (zenoh.open(conf) for _ in range(3))
    entities = _daemon(d1, {
        KEYS.spawn: _skip,  # not placed here
        KEYS.delete: _refuse(ErrorCode.NOT_FOUND),  # the name's daemon: the robot is not here
        KEYS.robots: _ok(RobotList(stamp=Time.from_seconds(1.0), robots=[_record("r2", "d1")])),
        KEYS.step: _ok(StepReply(**_clock(35), ticks_run=5)),
        KEYS.pause: _refuse(ErrorCode.NOT_ALLOWED, "d1 will not"),
    }) + _daemon(d2, {
        KEYS.spawn: _ok(_record("r1", "d2")),
        KEYS.delete: _ok(_record("r1", "d2")),
        KEYS.robots: _ok(RobotList(stamp=Time.from_seconds(1.0), robots=[_record("r1", "d2")])),
        KEYS.step: _ok(StepReply(**_clock(33), ticks_run=3, cancelled=True)),
        KEYS.pause: _refuse(ErrorCode.NOT_ALLOWED, "d2 will not"),
        KEYS.clock: _ok(Clock(**_clock(33))),
    })  # fmt: skip
    fleet = FleetRequests(asker, KEYS, 1 / 30)
    answers: queue.Queue[Any] = queue.Queue()

    def ask(request: Any) -> Any:
        fleet.ask(request, answers.put)
        answer = answers.get(timeout=15.0)
        assert answers.empty()  # one answer, however many daemons replied
        return answer

    try:

        def listers() -> int:
            every = zenoh.QueryTarget.ALL
            return len(list(asker.get(KEYS.robots, target=every, consolidation=zenoh.ConsolidationMode.NONE)))

        assert wait_until(lambda: listers() == 2, 10.0)  # both daemons are there
        spawned = ask(SpawnRequest(name="r1"))  # only the daemon it is placed on replies
        assert isinstance(spawned, RobotRecord)  # the services encode from the protocol's records
        assert (spawned.name, spawned.model, spawned.pose.x, spawned.pose.yaw) == ("r1", "burger", 1.0, 0.5)
        assert ask(DeleteRequest(name="r1")).name == "r1"  # the robot's daemon wins over not_found
        listed = ask(ListRequest())
        assert isinstance(listed, RobotList) and [r.name for r in listed.robots] == ["r1", "r2"]
        stepped = ask(StepRequest(ticks=5))
        assert isinstance(stepped, StepReply) and (stepped.ticks_run, stepped.cancelled) == (3, True)
        assert ask(ClockRequest()).tick == 33
        refused = ask(PauseRequest())
        assert isinstance(refused, FleetError) and refused.code == ErrorCode.NOT_ALLOWED
        nobody = ask(ResumeRequest())  # no daemon serves it
        assert isinstance(nobody, FleetError) and nobody.code == ErrorCode.UNAVAILABLE
    finally:
        for e in entities:
            e.undeclare()
        for s in (d1, d2, asker):
            s.close()
