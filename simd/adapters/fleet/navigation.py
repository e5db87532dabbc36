"""Navigation over the fleet protocol: each robot's goal keys in, what the navigator says out.

In: ``P/<ns>/navigate`` (a goal), ``P/<ns>/navigate/cancel`` and ``P/<ns>/navigate/state``,
declared once as wildcard queryables; the robot is the key's ``<ns>`` chunk. The goal and
the cancel act only on a query for one concrete key (a wildcard get never sends a robot
anywhere), and the state answers one robot per query (a wildcard gets no reply: ``P/navigation``
carries every navigating robot's state, and ``P/*/plan`` answers wildcards).

Out, on the fleet adapter's thread: a goal's result on ``P/<ns>/navigate/result`` (always:
once per goal), each path on ``P/<ns>/plan`` (always: a path is planned a few times per
goal; its latest is also a get away), feedback on ``P/<ns>/navigate/feedback`` at 5 Hz and
the fleet's summary on ``P/navigation`` at 2 Hz, both only while somebody subscribes.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

import msgspec
import zenoh

from protocol.codec import decode, encode
from protocol.errors import FleetError
from protocol.keys import Keys
from protocol.navigation import (
    CancelRequest,
    NavigateRequest,
    NavigationRequest,
    NavigationStateRequest,
)
from simd.adapters.fleet.requests import Pending, reply_format
from simd.adapters.zenoh_entities import Interest, undeclare_all
from simd.nav.report import NavEvents

log = logging.getLogger(__name__)

MSGPACK = "application/msgpack"


class NavigationKeys:
    """The navigation queryables and publishers of one daemon."""

    def __init__(
        self,
        session: zenoh.Session,
        keys: Keys,
        submit: Callable[[NavigationRequest, Pending], None],
    ) -> None:
        self.session = session
        self.keys = keys
        self._submit = submit
        self._lock = threading.Lock()
        self._plans: dict[str, bytes] = {}  # the latest path of each robot, as put
        self.fleet_pub = session.declare_publisher(keys.fleet_navigation, encoding=MSGPACK)
        self._feedback_probe = session.declare_publisher(keys.navigate_feedback("*"))
        self.fleet_wanted = Interest(self.fleet_pub)
        self.feedback_wanted = Interest(self._feedback_probe)
        self.interests = (self.fleet_wanted, self.feedback_wanted)  # asked again before a step
        self._entities: list[Any] = [
            *self.interests,
            session.declare_queryable(keys.navigate("*"), self._route(NavigateRequest, ())),
            session.declare_queryable(keys.navigate_cancel("*"), self._route(CancelRequest, ("cancel",))),
            session.declare_queryable(keys.navigate_state("*"), self._answer_state),
            session.declare_queryable(keys.plan("*"), self._answer_plan),
            self.fleet_pub,
            self._feedback_probe,
        ]

    # -- in (zenoh's threads) -------------------------------------------------------------------

    def _route(self, kind: type[Any], tail: tuple[str, ...]) -> Callable[[zenoh.Query], None]:
        def on_query(query: zenoh.Query) -> None:
            key = str(query.key_expr)
            robot = self.keys.robot_of(key, "navigate", *tail)
            if robot is None:  # a wildcard: somebody looking, not sending a robot anywhere
                query.drop()
                return
            payload = query.payload.to_bytes() if query.payload is not None else b""
            pending = Pending(query, key, reply_format(query, payload))
            try:
                request = decode(payload, kind)
            except FleetError as e:
                pending.error(e)
                return
            self._submit(msgspec.structs.replace(request, robot=robot), pending)

        return on_query

    def _answer_state(self, query: zenoh.Query) -> None:
        key = str(query.key_expr)
        robot = self.keys.robot_of(key, "navigate", "state")
        if robot is None:  # a wildcard: each robot's state is asked for by its own key
            query.drop()
            return
        payload = query.payload.to_bytes() if query.payload is not None else b""
        self._submit(NavigationStateRequest(robot=robot), Pending(query, key, reply_format(query, payload)))

    def _answer_plan(self, query: zenoh.Query) -> None:
        try:
            with self._lock:
                plans = dict(self._plans)
            for robot, payload in plans.items():
                key = self.keys.plan(robot)
                if zenoh.KeyExpr(key).intersects(query.key_expr):
                    query.reply(key, payload, encoding=MSGPACK)
        finally:
            query.drop()

    # -- out (the fleet adapter's thread) --------------------------------------------------------

    def publish(self, events: NavEvents) -> None:
        put = self.session.put
        for path in events.plans:
            payload = encode(path)
            with self._lock:
                if path.points:
                    self._plans[path.robot] = payload
                else:
                    self._plans.pop(path.robot, None)
            put(self.keys.plan(path.robot), payload, encoding=MSGPACK)
        for result in events.results:
            put(self.keys.navigate_result(result.robot), encode(result), encoding=MSGPACK)
        if events.feedback and self.feedback_wanted:
            for fb in events.feedback:
                put(self.keys.navigate_feedback(fb.robot), encode(fb), encoding=MSGPACK)
        if events.fleet is not None and self.fleet_wanted:
            self.fleet_pub.put(encode(events.fleet))

    def forget(self, robot: str) -> None:
        with self._lock:
            self._plans.pop(robot, None)

    def close(self) -> None:
        undeclare_all(self._entities)
