"""ROS 2 output of a fleet that several daemons share (``simd --join --ros2``): one voice.

Every daemon shows its own robots to ROS (their nodes, topics, ``/tf`` and ``/tf_static``), but
a ROS user must see one simulator: one ``/clock``, one ``/spawn_entity`` that answers once. So
of the daemons that serve one ROS domain for one fleet, exactly one *speaks for the fleet*: it
publishes ``/clock`` and declares the services, and the services ask the fleet through its own
protocol (``P/spawn``, ``P/delete``, ``P/robots``, ``P/clock``, ``P/sim/*``). A ROS spawn is
then placed by name as ``fleet spawn`` places it, a name stays unique across the daemons, a
delete reaches the robot's daemon, a step or a pause reaches every daemon, and the ROS caller
gets one reply, the fleet's.

Who speaks (:class:`Speaker`): every such daemon declares the liveliness token
``P/daemons/<id>/ros2/<domain>/<distro>/<since>`` on its ROS session and follows the others'
(with history); the one that has served longest (the smallest ``since``, then the smallest
id) speaks. Every daemon computes the same from the same tokens. A daemon that joins never
takes over, so there is no moment with two speakers; when the speaker leaves, its tokens go
with its session and the next in line starts at once. Only daemons that serve ROS take part
(a ``--join`` daemon without ``--ros2`` never wins and leaves the fleet mute), and only those
on one domain and distro (the keys of ``/clock`` differ between them).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import zenoh

from protocol.codec import MAX_REPLY_BYTES, MSGPACK, decode, encode, reply_error
from protocol.control import (
    REQUESTS,
    Clock,
    ClockRequest,
    DeleteRequest,
    ListRequest,
    PauseRequest,
    Request,
    ResumeRequest,
    RobotList,
    RobotRecord,
    SpawnRequest,
    StepReply,
    StepRequest,
)
from protocol.errors import ErrorCode, FleetError
from protocol.gather import GATHER, Gathering, merge
from protocol.keys import Keys
from protocol.messages import Time
from simd.core.snapshot import RobotState
from simd.engine.ports import Reply, Result, StepResult
from simd.engine.ports import RobotList as EngineRobotList
from simd.wire import convert

log = logging.getLogger(__name__)

#: What the services are answered with: the fleet protocol's messages, whoever answers (this
#: daemon's engine, or the fleet through its protocol), so that they encode from one kind of
#: record
Message = RobotRecord | RobotList | StepReply | Clock
Answer = Callable[[Message | FleetError], None]
#: Ask the simulation something: the answer comes once, on any thread.
Ask = Callable[[Request, Answer], None]

#: How long a service waits for the fleet's answer (rmw_zenoh's client gives up after 10 s too).
FORWARD_TIMEOUT_S = 10.0
#: How long a daemon that has just joined listens for the others before it may speak.
SETTLE_S = 1.0


@dataclass(frozen=True)
class SharedFleet:
    """What the ROS adapter of a ``--join`` daemon needs of the fleet: its session (the fleet
    protocol's, not the ROS one), its keys and this daemon's id."""

    session: zenoh.Session
    keys: Keys
    daemon_id: str


class Speaker:
    """Whether this daemon speaks for the fleet in its ROS domain; ``changed`` is called (on a
    thread of zenoh's) whenever that may have changed: read :meth:`speaks` then.

    A daemon that has just joined says nothing for ``settle_s``: the other daemons' tokens reach
    a new session over some milliseconds (a liveliness query right after the session opened
    came back empty now and then), and a newcomer that spoke before hearing of them would speak
    beside the daemon that already does."""

    def __init__(self, ros_session: zenoh.Session, keys: Keys, daemon_id: str, domain: int, distro: str,
                 changed: Callable[[], None], since_ns: int | None = None,
                 settle_s: float = SETTLE_S) -> None:  # fmt: skip
        self.daemon_id = daemon_id
        self._changed = changed
        self._head = keys.daemon("")
        self._lock = threading.Lock()
        since = time.time_ns() if since_ns is None else since_ns
        self._own = keys.daemon_ros2(daemon_id, domain, distro, since)
        self._serving: dict[str, tuple[int, str]] = {self._own: (since, daemon_id)}  # token -> (since, id)
        self._settled = False
        liveliness = ros_session.liveliness()
        self._token = liveliness.declare_token(self._own)
        pattern = keys.daemon_ros2("*", domain, distro, "*")
        self._sub = liveliness.declare_subscriber(pattern, self._on_token, history=True)
        self._timer = threading.Timer(settle_s, self._settle)
        self._timer.daemon = True
        self._timer.start()

    def _settle(self) -> None:
        with self._lock:
            self._settled = True
        self._changed()

    def _on_token(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        parts = key[len(self._head) :].split("/") if key.startswith(self._head) else []
        try:
            entry = (int(parts[-1]), parts[0])
        except (IndexError, ValueError):
            return  # not one of ours
        with self._lock:
            before = self._first()
            if sample.kind == zenoh.SampleKind.PUT:
                self._serving[key] = entry
            elif key != self._own:
                self._serving.pop(key, None)
            moved = self._settled and self._first() != before
        if moved:
            self._changed()

    def _first(self) -> str:
        return min(self._serving.values())[1]

    def speaker(self) -> str | None:
        """The id of the daemon that speaks for the fleet, as far as this one knows (None while
        this one settles)."""
        with self._lock:
            return self._first() if self._settled else None

    def speaks(self) -> bool:
        return self.speaker() == self.daemon_id

    def close(self) -> None:
        self._timer.cancel()
        for entity in (self._sub, self._token):
            try:
                entity.undeclare()
            except zenoh.ZError:
                pass


# -- asking the fleet -----------------------------------------------------------------------------

#: the message each request is answered with (the others: the clock)
_REPLY: dict[type[Any], type[Any]] = {
    SpawnRequest: RobotRecord,
    DeleteRequest: RobotRecord,
    ListRequest: RobotList,
    StepRequest: StepReply,
}
_KIND = {request: kind for kind, request in REQUESTS.items()}


class FleetRequests:
    """Requests asked of the whole fleet through its protocol, as ``fleet`` asks them (zenoh
    target *all*, no consolidation), the daemons' replies made one answer as every client
    makes it (protocol/gather.py). Nothing blocks: the replies come on zenoh's threads and the
    answer with the last one (or the first, when that one is the answer)."""

    def __init__(self, session: zenoh.Session, keys: Keys, tick_s: float) -> None:
        self.session = session
        self.keys = keys
        self.tick_s = tick_s

    def ask(self, request: Request, then: Answer) -> None:
        kind = _KIND[type(request)]
        key = getattr(self.keys, kind)
        reply_type = _REPLY.get(type(request), Clock)
        timeout = FORWARD_TIMEOUT_S
        if isinstance(request, StepRequest):
            timeout += request.ticks * self.tick_s  # a long step answers when it is done
        observe = request.observe if isinstance(request, StepRequest) else []
        gathering: Gathering[Message] = Gathering(GATHER.get(type(request), "any"))
        lock = threading.Lock()
        answered = [False]

        def answer() -> None:
            with lock:
                if answered[0]:
                    return
                answered[0] = True
                try:
                    result: Message | FleetError = merge(gathering.answer(nobody), observe)
                except FleetError as e:
                    result = e
            try:
                then(result)
            except Exception:  # the handler's bug: logged, the fleet goes on
                log.exception("answering %s failed", kind)

        nobody = FleetError(ErrorCode.UNAVAILABLE, f"no daemon of the fleet answered {key}")

        def on_reply(reply: zenoh.Reply) -> None:
            message: Message | FleetError
            if reply.ok is not None:
                try:
                    message = decode(reply.ok.payload.to_bytes(), reply_type, MAX_REPLY_BYTES)
                except FleetError as e:
                    message = e
            else:
                assert reply.err is not None
                message = reply_error(
                    reply.err.payload.to_bytes(), f"the fleet did not answer {key} within {timeout:g} s"
                )
            with lock:
                known = not answered[0] and gathering.add(message)
            if known:
                answer()

        def on_done() -> None:
            answer()

        bare = isinstance(request, (ListRequest, ClockRequest, PauseRequest, ResumeRequest))
        try:
            self.session.get(
                f"{key}?format=msgpack",
                zenoh.handlers.Callback(on_reply, on_done),
                payload=None if bare else encode(request),
                encoding=MSGPACK,
                target=zenoh.QueryTarget.ALL,
                consolidation=zenoh.ConsolidationMode.NONE,
                timeout=timeout,
            )
        except zenoh.ZError as e:
            nobody = FleetError(ErrorCode.UNAVAILABLE, f"cannot ask the fleet on {key}: {e}")
            answer()


def protocol_message(result: Result, keys: Keys, daemon_id: str) -> Message:
    """The fleet protocol's message for this daemon's engine's answer, as its fleet adapter
    sends it (a step's observations left out: the services ask for none)."""
    if isinstance(result, RobotState):
        return convert.robot_record(result, keys, daemon_id)
    if isinstance(result, EngineRobotList):
        robots = [convert.robot_record(s, keys, daemon_id) for s in result.robots]
        return RobotList(stamp=Time.from_seconds(result.time), robots=robots)
    if isinstance(result, StepResult):
        fields = {f: getattr(result.clock, f) for f in result.clock.__struct_fields__}
        return StepReply(**fields, ticks_run=result.ticks_run, cancelled=result.cancelled)
    if isinstance(result, Clock):
        return result
    raise TypeError(f"the services ask nothing answered with {type(result).__name__}")


def engine_ask(submit: Callable[[Request, Reply], None], keys: Keys, daemon_id: str) -> Ask:
    """Ask one daemon's own engine (``Engine.submit``; busy comes back as the answer), its
    answers turned into the protocol's messages."""

    def ask(request: Request, then: Answer) -> None:
        def reply(result: Result | FleetError) -> None:
            then(result if isinstance(result, FleetError) else protocol_message(result, keys, daemon_id))

        try:
            submit(request, reply)
        except FleetError as e:
            then(e)

    return ask
