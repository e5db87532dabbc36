"""ROS 2 services on rmw_zenoh's wire: a queryable per service, CDR in and out, attachments echoed.

A ROS client ``get``s the service's key with the request's CDR and a 33-byte attachment
(its sequence number and GID); the server replies on the same key with the response's CDR and
an attachment carrying the same sequence number and GID, by which rclcpp matches the answer
to the call. rclcpp never hands an error reply to the caller, so every refusal is an ordinary
response (``success = false`` and a message). An ``SS`` liveliness token makes the service
exist for ``ros2 service list`` and for a client's ``wait_for_service``.

Like the fleet protocol's actions, a service acts only on its exact key: a wildcard ``get``
(somebody looking around) gets no answer and changes nothing.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import zenoh

from protocol.control import Request
from protocol.errors import FleetError
from simd.adapters.ros2 import gazebo_services as gz
from simd.adapters.ros2 import graph
from simd.adapters.ros2.interfaces import typestore
from simd.adapters.ros2.robot_ports import Participant
from simd.adapters.zenoh_entities import undeclare_all
from simd.engine import Engine
from simd.engine.outbox import Outbox
from simd.engine.ports import Result

log = logging.getLogger(__name__)

#: The largest request payload decoded (the xml of a SpawnEntity is the big one).
MAX_REQUEST_BYTES = gz.MAX_XML_BYTES + 4096


@dataclass(frozen=True)
class Service:
    """One service: how a decoded request becomes the engine's, and the answers' words."""

    name: str  # /spawn_entity
    typename: str  # gazebo_msgs/srv/SpawnEntity
    to_request: Callable[[Any], Request]
    ok: Callable[[str], str]
    failed: Callable[[str, FleetError], str]


GAZEBO_SERVICES = (
    Service("/spawn_entity", "gazebo_msgs/srv/SpawnEntity", gz.spawn_request, gz.spawn_success, gz.spawn_failure),
    Service("/delete_entity", "gazebo_msgs/srv/DeleteEntity", gz.delete_request, gz.delete_success,
            gz.delete_failure),
)  # fmt: skip


class ServiceServer:
    """Serves :data:`GAZEBO_SERVICES` through the engine; replies leave through the outbox."""

    def __init__(self, p: Participant, node: graph.Node, engine: Engine, outbox: Outbox) -> None:
        self.engine = engine
        self.outbox = outbox
        self._store = typestore(p.distro)
        self._entities: list[Any] = []
        self.refused = 0
        for service in GAZEBO_SERVICES:
            topic = p.topic(service.name, service.typename)
            token = node.entity_token(p.next_id(), graph.Kind.SERVICE, topic, graph.SERVICE_QOS)
            gid = graph.gid(token)
            handler = self._handler(service, topic.key, gid)
            self._entities.append(p.session.declare_queryable(topic.key, handler, complete=True))
            self._entities.append(p.session.liveliness().declare_token(token))

    def _handler(self, service: Service, key: str, server_gid: bytes) -> Callable[[zenoh.Query], None]:
        request_type = f"{service.typename}_Request"
        response_type = f"{service.typename}_Response"
        store = self._store

        def on_query(query: zenoh.Query) -> None:
            if str(query.key_expr) != key:
                query.drop()  # a wildcard: somebody looking, not calling
                return
            try:
                sequence, client_gid = _caller(query.attachment)
            except ValueError:
                sequence, client_gid = 0, server_gid  # not rclcpp (zenoh's CLI?): answer all the same

            def respond(success: bool, message: str) -> None:
                response = store.types[response_type](success=success, status_message=message)
                payload = bytes(store.serialize_cdr(response, response_type))
                try:
                    query.reply(key, payload, attachment=graph.attachment(sequence, client_gid))
                finally:
                    query.drop()

            payload = query.payload.to_bytes() if query.payload is not None else b""
            try:
                if len(payload) > MAX_REQUEST_BYTES:
                    raise gz.Refused(f"request of {len(payload)} bytes is larger than {MAX_REQUEST_BYTES}")
                try:
                    msg: Any = store.deserialize_cdr(payload, request_type)
                except Exception as e:  # rosbags raises several kinds for bytes that are not the type
                    raise gz.Refused(f"malformed {request_type}: {type(e).__name__}: {e}") from None
                name = str(msg.name)
                request = service.to_request(msg)
            except gz.Refused as e:
                self.refused += 1
                log.info("%s refused: %s", service.name, e)
                respond(False, str(e))
                return

            def on_result(result: Result | FleetError) -> None:
                if isinstance(result, FleetError):
                    self.outbox.put(lambda: respond(False, service.failed(name, result)))
                else:
                    self.outbox.put(lambda: respond(True, service.ok(name)))

            try:
                self.engine.submit(request, on_result)
            except FleetError as e:  # busy
                respond(False, service.failed(name, e))

        return on_query

    def close(self) -> None:
        undeclare_all(self._entities)


def _caller(attachment: zenoh.ZBytes | None) -> tuple[int, bytes]:
    if attachment is None:
        raise ValueError("no attachment")
    sequence, _, gid = graph.parse_attachment(attachment.to_bytes())
    return sequence, gid
