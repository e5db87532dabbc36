"""Requests in: the control queryables, decoded at the edge into the engine's typed requests.

Everything a query carries is hostile until decoded: the body is decoded here, on zenoh's
thread, into the request type of its key (bounded in size, every failure a structured
``malformed`` / ``too_large`` reply), so only well-formed requests reach the simulation
thread. Keys that change the world (spawn, delete, pause, resume, reset, step) act only on a
query for exactly their key: ``get P/**`` or ``get P/sim/*`` is somebody looking, and gets
the read-only answers (robots, world, clock, the latest odometry and scans), never an action.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import zenoh

from protocol.codec import Format, decode, encode, media_type, sniff_format
from protocol.control import ACTIONS, REQUESTS, Request
from protocol.errors import ErrorCode, FleetError
from protocol.keys import Keys

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Route:
    """One control key: the request type its body decodes to, and whether it acts."""

    key: str
    request: type[Any]
    acts: bool


def routes(keys: Keys) -> list[Route]:
    return [Route(getattr(keys, kind), request, kind in ACTIONS) for kind, request in REQUESTS.items()]


def reply_format(query: zenoh.Query, payload: bytes) -> Format:
    """JSON or MessagePack for the reply: ``?format=`` wins, then the request's own
    encoding; an empty request gets JSON, which zenoh's CLI prints as it is."""
    wanted = query.parameters.get("format")
    if wanted == "json":
        return "json"
    if wanted == "msgpack":
        return "msgpack"
    enc = str(query.encoding) if query.encoding is not None else ""
    if enc.startswith("application/msgpack"):
        return "msgpack"
    if not payload:
        return "json"
    return sniff_format(payload)


@dataclass
class Pending:
    """A query on its way through the engine: answered once, then dropped."""

    query: zenoh.Query
    key: str
    fmt: Format

    def ok(self, message: object) -> None:
        try:
            try:
                payload = encode(message, self.fmt)
            except Exception as e:  # our bug: the client hears of it instead of waiting in vain
                log.exception("cannot encode the reply on %s", self.key)
                err = FleetError(ErrorCode.INTERNAL, f"internal error: cannot encode the reply: {e}")
                self.query.reply_err(encode(err.to_reply(), self.fmt), encoding=media_type(self.fmt))
                return
            self.query.reply(self.key, payload, encoding=media_type(self.fmt))
        finally:
            self.query.drop()

    def ok_encoded(self, payload: bytes | bytearray) -> None:
        """Reply with a message already encoded in this query's format."""
        try:
            self.query.reply(self.key, payload, encoding=media_type(self.fmt))
        finally:
            self.query.drop()

    def skip(self) -> None:
        """Leave the query to another daemon: no reply from this one."""
        self.query.drop()

    def error(self, err: FleetError) -> None:
        try:
            self.query.reply_err(encode(err.to_reply(), self.fmt), encoding=media_type(self.fmt))
        finally:
            self.query.drop()


def declare(
    session: zenoh.Session, keys: Keys, submit: Callable[[Request, Pending], None], extra: list[Route] | None = None
) -> list[zenoh.Queryable[Any]]:
    """Declare every control queryable (and the ``extra`` routes); well-formed requests go to ``submit``."""

    def handler(route: Route) -> Callable[[zenoh.Query], None]:
        def on_query(query: zenoh.Query) -> None:
            if route.acts and str(query.key_expr) != route.key:
                query.drop()  # a wildcard: somebody looking, not asking for this action
                return
            payload = query.payload.to_bytes() if query.payload is not None else b""
            pending = Pending(query, route.key, reply_format(query, payload))
            try:
                request = decode(payload, route.request)
            except FleetError as e:
                pending.error(e)
                return
            submit(request, pending)

        return on_query

    return [session.declare_queryable(r.key, handler(r)) for r in [*routes(keys), *(extra or [])]]
