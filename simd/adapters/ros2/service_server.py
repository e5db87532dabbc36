"""ROS 2 services on rmw_zenoh's wire: a queryable per service, CDR in and out, attachments echoed.

A ROS client ``get``s the service's key with the request's CDR and an attachment (its sequence
number and GID); the server replies on the same key with the response's CDR and an attachment
carrying the same sequence number and GID, by which rclcpp matches the answer to the call, in
the format the request came in (attachment.py: an older rmw_zenoh's client is answered in
its own). rclcpp never hands an error reply to the caller, so every refusal is an ordinary
response (``success = false``, or a ``Result`` code, and a message). An ``SS`` liveliness token
makes the service exist for ``ros2 service list`` and for a client's ``wait_for_service``.

Like the fleet protocol's actions, a service acts only on its exact key: a wildcard ``get``
(somebody looking around) gets no answer and changes nothing.

What a service does lives in its handler (gazebo_services.py, simulation_services.py): it gets
a :class:`Call` with the decoded request, asks the simulation through it, and answers once. The
simulation is this daemon's engine, or, in a fleet shared by several daemons, the whole fleet
through its protocol (shared_fleet.py).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import zenoh
from rosbags.interfaces import Nodetype
from rosbags.typesys.store import Typestore

from protocol.control import Request
from simd.adapters.ros2 import attachment, graph
from simd.adapters.ros2.attachment import Attachment, LegacyNotice
from simd.adapters.ros2.interfaces import typestore
from simd.adapters.ros2.robot_ports import Participant
from simd.adapters.ros2.shared_fleet import Answer, Ask
from simd.adapters.zenoh_entities import undeclare_all
from simd.engine.outbox import Outbox

log = logging.getLogger(__name__)

#: The largest request payload decoded (the xml of a SpawnEntity is the big one).
MAX_REQUEST_BYTES = (1 << 20) + 4096  # a SpawnEntity's xml may have 1 MiB (gazebo_services.MAX_XML_BYTES)


class Call:
    """One service call on its way: the request, the simulation to ask, the one answer to give."""

    def __init__(self, name: str, request: Any, response_type: str, store: Typestore,
                 send: Callable[[bytes], None], outbox: Outbox, ask: Ask | None = None) -> None:  # fmt: skip
        self.name = name
        self.request = request
        self._response_type = response_type
        self._store = store
        self._ask = ask
        self._send = send
        self._outbox = outbox
        self._answered = False

    def make(self, typename: str, **fields: Any) -> Any:
        """A message of ``typename`` (for the nested parts of a response); fields not given are zero."""
        return zero_message(self._store, typename, fields)

    def fields(self, typename: str) -> list[str]:
        """The field names of ``typename`` as this call's distro defines it."""
        return [name for name, _ in self._store.fielddefs[typename][1]]

    @property
    def response_fields(self) -> list[str]:
        return self.fields(self._response_type)

    def respond(self, **fields: Any) -> None:
        """Answer with a response of these fields, the others zero (any thread; sent from the
        adapter's thread). Only the first answer counts."""
        payload = self._payload(fields)
        if payload is not None:
            self._outbox.put(lambda: self._send(payload))

    def respond_here(self, **fields: Any) -> None:
        """Answer as :meth:`respond` does, but on this thread: for work that already runs on the
        adapter's thread, which must never wait for room in its own queue."""
        payload = self._payload(fields)
        if payload is not None:
            self._send(payload)

    def _payload(self, fields: dict[str, Any]) -> bytes | None:
        if self._answered:
            return None
        self._answered = True
        response = zero_message(self._store, self._response_type, fields)
        return bytes(self._store.serialize_cdr(response, self._response_type))

    def ask(self, request: Request, then: Answer) -> None:
        """Ask the simulation; ``then`` gets its result or error (busy included), once."""
        if self._ask is None:
            raise RuntimeError(f"{self.name} was given nothing to ask")
        self._ask(request, then)


Handler = Callable[[Call], None]

_NUMPY_TYPES = {
    "bool": np.bool_, "byte": np.uint8, "char": np.uint8, "int8": np.int8, "uint8": np.uint8,
    "int16": np.int16, "uint16": np.uint16, "int32": np.int32, "uint32": np.uint32,
    "int64": np.int64, "uint64": np.uint64, "float32": np.float32, "float64": np.float64,
}  # fmt: skip


def zero_message(store: Typestore, typename: str, given: dict[str, Any] | None = None) -> Any:
    """A message of ``typename`` with ``given`` fields and every other one zero, empty or false
    (rosbags' message classes have no defaults)."""
    given = given or {}
    fields = {name: given[name] if name in given else _zero(store, node, desc)
              for name, (node, desc) in store.fielddefs[typename][1]}  # fmt: skip
    return store.types[typename](**fields)


def _zero(store: Typestore, node: Nodetype, desc: Any) -> Any:
    if node == Nodetype.BASE:
        kind = desc[0]
        return "" if kind == "string" else False if kind == "bool" else 0.0 if kind.startswith("float") else 0
    if node == Nodetype.NAME:
        return zero_message(store, desc)
    (inner, inner_desc), length = desc
    primitive = inner == Nodetype.BASE and inner_desc[0] != "string"
    if node == Nodetype.ARRAY:
        if primitive:
            return np.zeros(length, dtype=_NUMPY_TYPES[inner_desc[0]])
        return [_zero(store, inner, inner_desc) for _ in range(length)]
    return np.zeros(0, dtype=_NUMPY_TYPES[inner_desc[0]]) if primitive else []


@dataclass(frozen=True)
class Service:
    name: str  # /spawn_entity
    typename: str  # gazebo_msgs/srv/SpawnEntity
    handler: Handler
    #: the response to a request that cannot be decoded, given the message
    malformed: Callable[[Call, str], None]


class ServiceServer:
    """Serves services by asking the simulation (``ask``); replies leave through the outbox."""

    def __init__(self, p: Participant, node: graph.Node, ask: Ask, outbox: Outbox,
                 services: list[Service]) -> None:  # fmt: skip
        self.ask = ask
        self.outbox = outbox
        self._store = typestore(p.distro)
        self._legacy = p.legacy
        self._entities: list[Any] = []
        self.malformed = 0
        for service in services:
            topic = p.topic(service.name, service.typename)
            token = node.entity_token(p.next_id(), graph.Kind.SERVICE, topic, graph.SERVICE_QOS)
            handler = self._on_query(service, topic.key, graph.gid(token))
            self._entities.append(p.session.declare_queryable(topic.key, handler, complete=True))
            self._entities.append(p.session.liveliness().declare_token(token))

    def _on_query(self, service: Service, key: str, server_gid: bytes) -> Callable[[zenoh.Query], None]:
        request_type = f"{service.typename}_Request"
        response_type = f"{service.typename}_Response"
        store = self._store

        def on_query(query: zenoh.Query) -> None:
            if str(query.key_expr) != key:
                query.drop()  # a wildcard: somebody looking, not calling
                return
            send = reply_sender(query, key, server_gid, self._legacy, service.name)
            call = Call(service.name, None, response_type, store, send, self.outbox, self.ask)
            wrong = read_request(call, query, store, request_type)
            if wrong is not None:
                self._malformed(service, call, wrong)
                return
            try:
                service.handler(call)
            except Exception:  # our bug: the caller still gets an answer, the daemon goes on
                log.exception("%s failed", service.name)
                service.malformed(call, "internal error in fleetsim (see the daemon's log)")

        return on_query

    def _malformed(self, service: Service, call: Call, message: str) -> None:
        self.malformed += 1
        log.info("%s refused: %s", service.name, message)
        service.malformed(call, message)

    def close(self) -> None:
        undeclare_all(self._entities)


def read_request(call: Call, query: zenoh.Query, store: Typestore, request_type: str) -> str | None:
    """Decode the query's CDR payload into ``call.request``; or why not, in one line (too
    large, or bytes that are not a ``request_type``), and ``call.request`` stays None."""
    payload = query.payload.to_bytes() if query.payload is not None else b""
    if len(payload) > MAX_REQUEST_BYTES:
        return f"request of {len(payload)} bytes is larger than {MAX_REQUEST_BYTES}"
    try:
        call.request = store.deserialize_cdr(payload, request_type)
    except Exception as e:  # rosbags raises several kinds for bytes that are not the type
        return f"malformed {request_type}: {type(e).__name__}: {e}"
    return None


def reply_sender(query: zenoh.Query, key: str, server_gid: bytes, legacy: LegacyNotice,
                 name: str) -> Callable[[bytes], None]:  # fmt: skip
    """The one reply to a query, on ``key``, with the attachment rclcpp matches it by: the
    request's sequence number and the client's GID, in the request's format (a caller without
    an attachment, zenoh's CLI say, is answered all the same). An older rmw_zenoh's request is
    told to ``legacy`` (``name`` says what it called)."""
    try:
        caller = _caller(query.attachment)
    except ValueError:
        caller = Attachment(0, 0, server_gid)
    legacy.note(caller, name)

    def send(payload: bytes) -> None:
        try:
            query.reply(key, payload, attachment=attachment.echo(caller))
        finally:
            query.drop()

    return send


def _caller(raw: zenoh.ZBytes | None) -> Attachment:
    if raw is None:
        raise ValueError("no attachment")
    return attachment.decode(raw.to_bytes())
