"""What rclcpp gives every node, on the daemon's nodes: parameter services, /rosout, /parameter_events.

An rclcpp node serves six services on its parameters (``<node>/list_parameters``,
``get_parameters``, ``describe_parameters``, ``get_parameter_types``, ``set_parameters``,
``set_parameters_atomically``, rcl_interfaces' types) and publishes on ``/rosout`` and
``/parameter_events``. ``ros2 param`` finds a node's parameters through those services (it looks
for the node's ``list_parameters`` in the graph, then calls it), and ``ros2 node info`` lists them:
a node without them looks broken, and ``ros2 param list`` on it times out. The daemon's nodes
(``/<ns>/turtlebot3`` per robot, ``/fleetsim`` or ``/fleetsim_<id>`` for the daemon) have them
all, with one parameter, ``use_sim_time``, true (parameters.py says how they answer).

Cost per spawn: a robot's node adds eight tokens (six ``SS``, two ``MP``) and nothing else. One
wildcard queryable per service (``<domain>/*/turtlebot3/<service>/...``) answers every robot's
node, as navigation.py's action server does, and only for this daemon's own robots (in a shared
fleet, another daemon's robot is that daemon's to answer). A robot node's ``/rosout`` and
``/parameter_events`` are tokens only: nothing ever changes its parameters, and what the daemon
has to say (a robot spawned or deleted) goes out on its own node's ``/rosout``, one transient-local
publisher as rcl declares it (depth 1000), so ``ros2 topic echo /rosout`` and rqt_console show it.

Requests are decoded on zenoh's threads and answered through the adapter's outbox, as every
other service's are.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from enum import IntEnum
from typing import Any

import numpy as np
import zenoh

from simd.adapters.ros2 import graph
from simd.adapters.ros2.graph import Kind, Node
from simd.adapters.ros2.interfaces import typestore
from simd.adapters.ros2.parameters import VALUE_FIELDS, Declared, NodeParameters, SetResult, value_of
from simd.adapters.ros2.robot_ports import NODE_NAME, LatchedPublisher, Participant
from simd.adapters.ros2.service_server import Call, read_request, reply_sender
from simd.adapters.zenoh_entities import undeclare_all
from simd.engine.outbox import Outbox

log = logging.getLogger(__name__)

RCL = "rcl_interfaces"
#: the parameter services of a node, by the suffix of their names (``<node>/<suffix>``)
PARAMETER_SERVICES: dict[str, str] = {
    "describe_parameters": f"{RCL}/srv/DescribeParameters",
    "get_parameter_types": f"{RCL}/srv/GetParameterTypes",
    "get_parameters": f"{RCL}/srv/GetParameters",
    "list_parameters": f"{RCL}/srv/ListParameters",
    "set_parameters": f"{RCL}/srv/SetParameters",
    "set_parameters_atomically": f"{RCL}/srv/SetParametersAtomically",
}
ROSOUT, LOG = "/rosout", f"{RCL}/msg/Log"
PARAMETER_EVENTS, PARAMETER_EVENT = "/parameter_events", f"{RCL}/msg/ParameterEvent"


class LogLevel(IntEnum):
    """rcl_interfaces/msg/Log's levels."""

    DEBUG = 10
    INFO = 20
    WARN = 30
    ERROR = 40
    FATAL = 50


def declare_tokens(p: Participant, node: Node, tokens: list[Any], *, rosout: bool = True) -> None:
    """The tokens of a node's parameter services and ``/parameter_events`` publisher, and of its
    ``/rosout`` publisher unless the caller declares that publisher itself (:class:`Rosout`)."""
    liveliness = p.session.liveliness()
    for suffix, typename in PARAMETER_SERVICES.items():
        topic = p.topic(f"{node.fqn}/{suffix}", typename)
        tokens.append(
            liveliness.declare_token(node.entity_token(p.next_id(), Kind.SERVICE, topic, graph.PARAMETERS_QOS))
        )
    events = p.topic(PARAMETER_EVENTS, PARAMETER_EVENT)
    tokens.append(
        liveliness.declare_token(node.entity_token(p.next_id(), Kind.PUBLISHER, events, graph.PARAMETER_EVENTS_QOS))
    )
    if rosout:
        topic = p.topic(ROSOUT, LOG)
        tokens.append(liveliness.declare_token(node.entity_token(p.next_id(), Kind.PUBLISHER, topic, graph.ROSOUT_QOS)))


def logger_name(node: Node) -> str:
    """The name rclcpp logs a node's lines under: ``TB3_1.turtlebot3``, ``fleetsim``."""
    return node.fqn.strip("/").replace("/", ".")


class Rosout:
    """A node's ``/rosout``: lines as rcl's rosout handler sends them (the wall clock's stamp,
    the node's logger name, no source location). Used on the adapter's thread only."""

    def __init__(self, p: Participant, node: Node, tokens: list[Any]) -> None:
        self._store = typestore(p.distro)
        self._name = logger_name(node)
        self._pub = LatchedPublisher(p, node, p.topic(ROSOUT, LOG), graph.ROSOUT_QOS, tokens, lazy=True)

    def log(self, text: str, level: LogLevel = LogLevel.INFO) -> None:
        sec, nanosec = divmod(time.time_ns(), 1_000_000_000)
        t = self._store.types
        message = t[LOG](
            stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec),
            level=int(level), name=self._name, msg=text, file="", function="", line=0,
        )  # fmt: skip
        self._pub.put(bytes(self._store.serialize_cdr(message, LOG)))

    def undeclare(self) -> None:
        self._pub.undeclare()


class ParameterServer:
    """The parameter services of the nodes at ``node_path`` (``/fleetsim``, or ``/*/turtlebot3``
    for every robot's), one queryable each; ``answers`` says, from the node path's chunks of a
    request's key, whether the node is this daemon's to answer for."""

    def __init__(self, p: Participant, outbox: Outbox, node_path: str, answers: Callable[[list[str]], bool],
                 parameters: NodeParameters | None = None) -> None:  # fmt: skip
        self._store = typestore(p.distro)
        self._outbox = outbox
        self._answers = answers
        self._legacy = p.legacy
        self.parameters = parameters or NodeParameters()
        self.malformed = 0
        handlers: dict[str, Callable[[Call], None]] = {
            "describe_parameters": self._describe,
            "get_parameter_types": self._types,
            "get_parameters": self._get,
            "list_parameters": self._list,
            "set_parameters": self._set,
            "set_parameters_atomically": self._set_atomically,
        }
        self._queryables: list[Any] = []
        for suffix, typename in PARAMETER_SERVICES.items():
            key = p.topic(f"{node_path}/{suffix}", typename).key
            handler = self._on_query(suffix, typename, handlers[suffix])
            self._queryables.append(p.session.declare_queryable(key, handler, complete=True))

    def _on_query(self, suffix: str, typename: str, handle: Callable[[Call], None]) -> Callable[[zenoh.Query], None]:
        request_type, response_type = f"{typename}_Request", f"{typename}_Response"

        def on_query(query: zenoh.Query) -> None:
            key = str(query.key_expr)
            path = key.split("/")[1:-3]
            if "*" in key or "$" in key or not self._answers(path):
                query.drop()  # somebody looking around, or another daemon's robot
                return
            name = f"/{'/'.join(path)}/{suffix}"
            send = reply_sender(query, key, graph.gid(key), self._legacy, name)
            call = Call(name, None, response_type, self._store, send, self._outbox)
            wrong = read_request(call, query, self._store, request_type)
            if wrong is not None:
                self.malformed += 1
                log.info("%s refused: %s", call.name, wrong)
                call.respond()  # empty lists, an unsuccessful result: as rclcpp answers a bad name
                return
            handle(call)

        return on_query

    # -- the six services (rclcpp's answers: parameters.py) -----------------------------------------

    def _value(self, call: Call, p: Declared) -> Any:
        return call.make(f"{RCL}/msg/ParameterValue", type=int(p.type), **{VALUE_FIELDS[p.type]: p.value})

    def _get(self, call: Call) -> None:
        found = self.parameters.get([str(n) for n in call.request.names])
        call.respond(values=[self._value(call, p) for p in found])

    def _describe(self, call: Call) -> None:
        found = self.parameters.describe([str(n) for n in call.request.names])
        call.respond(descriptors=[
            call.make(f"{RCL}/msg/ParameterDescriptor", name=p.name, type=int(p.type), description=p.description,
                      additional_constraints=p.additional_constraints, read_only=p.read_only)
            for p in found
        ])  # fmt: skip

    def _types(self, call: Call) -> None:
        found = self.parameters.types([str(n) for n in call.request.names])
        call.respond(types=np.array([int(t) for t in found], dtype=np.uint8))

    def _list(self, call: Call) -> None:
        names, prefixes = self.parameters.list_names([str(n) for n in call.request.prefixes], int(call.request.depth))
        call.respond(result=call.make(f"{RCL}/msg/ListParametersResult", names=names, prefixes=prefixes))

    def _result(self, call: Call, result: SetResult) -> Any:
        return call.make(f"{RCL}/msg/SetParametersResult", successful=result.successful, reason=result.reason)

    def _set(self, call: Call) -> None:
        results = [self.parameters.set_one(str(p.name), *value_of(p.value)) for p in call.request.parameters]
        call.respond(results=[self._result(call, r) for r in results])

    def _set_atomically(self, call: Call) -> None:
        result = self.parameters.set_atomically([(str(p.name), *value_of(p.value)) for p in call.request.parameters])
        call.respond(result=self._result(call, result))

    def close(self) -> None:
        undeclare_all(self._queryables)


class RobotNodes:
    """The rclcpp entities of every robot's node: its tokens, declared on spawn and undeclared on
    delete, and one :class:`ParameterServer` for all of them (the adapter's thread adds and removes
    robots; zenoh's threads only ask ``known``)."""

    def __init__(self, p: Participant, outbox: Outbox, known: Callable[[str], bool]) -> None:
        self._p = p
        self._tokens: dict[str, list[Any]] = {}
        self.server = ParameterServer(p, outbox, f"/*/{NODE_NAME}", lambda path: len(path) == 2 and known(path[0]))

    def add_robot(self, namespace: str, node: Node) -> None:
        tokens: list[Any] = []
        declare_tokens(self._p, node, tokens)
        self._tokens[namespace] = tokens

    def remove_robot(self, namespace: str) -> None:
        undeclare_all(self._tokens.pop(namespace, []))

    def close_inputs(self) -> None:
        """No more requests (before the adapter's thread stops)."""
        self.server.close()

    def close(self) -> None:
        for namespace in list(self._tokens):
            self.remove_robot(namespace)
