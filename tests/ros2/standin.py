"""A stand-in for a ROS 2 tool on rmw_zenoh, for tests on a machine without ROS.

Written from rmw_zenoh's design document (docs/design.md: "Topic and Service name mapping",
"Graph Cache", "Publishers", "Service Clients/Servers") and zenoh-ext's advanced pub/sub, and
deliberately **not** from the daemon's adapter: it imports nothing of ``simd``. Keys and tokens
are built here by their own rules; types, CDR and hashes come from rosbags, with the service
types written in IDL (the adapter parses .srv text), so a mistake in one is not copied into
the other. It behaves as a ROS process does:

- a peer session that connects to the router, multicast scouting off;
- subscribers on the exact key a ROS subscriber declares (a wrong type name or hash delivers
  nothing), which reject samples without the 33-byte attachment;
- publishers and service clients that send the attachment, and a client that matches the
  reply by its sequence number;
- a late ``/tf_static`` subscriber that asks the publishers' caches for history, as a
  transient-local ROS subscription does;
- the graph read from liveliness tokens, parsed as rmw_zenoh's GraphCache parses them, with
  each entity's GID computed from its token as rmw_zenoh computes it (xxh3.py, checked against
  xxHash's published vectors) and its QoS chunk read as ``keyexpr_to_qos`` reads it, and what
  ``ros2 node info``, ``ros2 topic list -t`` and ``ros2 param`` make of the graph;
- with ``legacy=True``, an older rmw_zenoh (jazzy 0.2.0-0.2.3, humble 0.1.0-0.1.1, rolling
  0.3-0.5), whose attachments name each value (``attachment_helpers.cpp`` of jazzy 0.2.3).

Types are per distro where the distros differ: simulation_interfaces is 1.x on Humble, Jazzy
and Kilted and 2.x (branch main, 2.1.0) on Lyrical and Rolling, and Nav2's NavigateToPose
feedback has two more fields on Lyrical and Rolling.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import queue
import struct
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import zenoh
import zenoh.ext
from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from tests.ros2 import xxh3

# -- types and hashes ---------------------------------------------------------------------------

_IDL = """
module gazebo_msgs { module srv {
  struct SpawnEntity_Request { string name; string xml; string robot_namespace;
                               geometry_msgs::msg::Pose initial_pose; string reference_frame; };
  struct SpawnEntity_Response { boolean success; string status_message; };
  struct DeleteEntity_Request { string name; };
  struct DeleteEntity_Response { boolean success; string status_message; };
  struct SpawnEntity_Event { service_msgs::msg::ServiceEventInfo info;
    sequence<gazebo_msgs::srv::SpawnEntity_Request, 1> request;
    sequence<gazebo_msgs::srv::SpawnEntity_Response, 1> response; };
  struct SpawnEntity { gazebo_msgs::srv::SpawnEntity_Request request_message;
    gazebo_msgs::srv::SpawnEntity_Response response_message; gazebo_msgs::srv::SpawnEntity_Event event_message; };
  struct DeleteEntity_Event { service_msgs::msg::ServiceEventInfo info;
    sequence<gazebo_msgs::srv::DeleteEntity_Request, 1> request;
    sequence<gazebo_msgs::srv::DeleteEntity_Response, 1> response; };
  struct DeleteEntity { gazebo_msgs::srv::DeleteEntity_Request request_message;
    gazebo_msgs::srv::DeleteEntity_Response response_message; gazebo_msgs::srv::DeleteEntity_Event event_message; };
}; };
module example_interfaces { module srv {
  struct AddTwoInts_Request { int64 a; int64 b; };
  struct AddTwoInts_Response { int64 sum; };
  struct AddTwoInts_Event { service_msgs::msg::ServiceEventInfo info;
    sequence<example_interfaces::srv::AddTwoInts_Request, 1> request;
    sequence<example_interfaces::srv::AddTwoInts_Response, 1> response; };
  struct AddTwoInts { example_interfaces::srv::AddTwoInts_Request request_message;
    example_interfaces::srv::AddTwoInts_Response response_message;
    example_interfaces::srv::AddTwoInts_Event event_message; };
}; };
"""


#: simulation_interfaces 1.5 (branch jazzy) in IDL: messages, then services (request; response)
_SI_MSGS = {
    "Result": "uint8 result; string error_message;",
    "EntityCategory": "uint8 category;",
    "TagsFilter": "sequence<string> tags; uint8 filter_mode;",
    "Bounds": "uint8 type; sequence<geometry_msgs::msg::Vector3> points;",
    "EntityFilters": "string filter; sequence<simulation_interfaces::msg::EntityCategory> categories; "
    "simulation_interfaces::msg::TagsFilter tags; simulation_interfaces::msg::Bounds bounds;",
    "EntityState": "std_msgs::msg::Header header; geometry_msgs::msg::Pose pose; geometry_msgs::msg::Twist twist; "
    "geometry_msgs::msg::Accel acceleration;",
    "SimulationState": "uint8 state;",
    "SimulatorFeatures": "sequence<uint16> features; sequence<string> spawn_formats; string custom_info;",
    "Spawnable": "string uri; string description; simulation_interfaces::msg::Bounds spawn_bounds;",
}
_R = "simulation_interfaces::msg::Result result;"
#: ... and 2.x (branch main, 2.1.0): what it changed
_SI2_MSGS = {
    **_SI_MSGS,
    "Resource": "string uri; string resource_string;",
    "Spawnable": "simulation_interfaces::msg::Resource entity_resource; string description; "
    "simulation_interfaces::msg::Bounds spawn_bounds;",
}
_SI_SRVS = {
    "SpawnEntity": ("string name; boolean allow_renaming; string uri; string resource_string; "
                    "string entity_namespace; geometry_msgs::msg::PoseStamped initial_pose;",
                    f"{_R} string entity_name;"),
    "DeleteEntity": ("string entity;", _R),
    "GetEntities": ("simulation_interfaces::msg::EntityFilters filters;", f"{_R} sequence<string> entities;"),
    "GetEntityState": ("string entity;", f"{_R} simulation_interfaces::msg::EntityState state;"),
    "SetEntityState": ("string entity; simulation_interfaces::msg::EntityState state;", _R),
    "GetSimulationState": ("uint8 structure_needs_at_least_one_member;",
                           f"simulation_interfaces::msg::SimulationState state; {_R}"),
    "SetSimulationState": ("simulation_interfaces::msg::SimulationState state;", _R),
    "StepSimulation": ("uint64 steps;", _R),
    "ResetSimulation": ("uint8 scope;", _R),
    "GetSimulatorFeatures": ("uint8 structure_needs_at_least_one_member;",
                             "simulation_interfaces::msg::SimulatorFeatures features;"),
    "GetSpawnables": ("sequence<string> sources;", f"{_R} sequence<simulation_interfaces::msg::Spawnable> spawnables;"),
}  # fmt: skip
_SI2_SRVS = {
    **_SI_SRVS,
    "SpawnEntity": ("string name; boolean allow_renaming; simulation_interfaces::msg::Resource entity_resource; "
                    "string entity_namespace; geometry_msgs::msg::PoseStamped initial_pose;",
                    f"{_R} string entity_name;"),
    "SetEntityState": ("string entity; simulation_interfaces::msg::EntityState state; boolean set_pose; "
                       "boolean set_twist; boolean set_acceleration;", _R),
}  # fmt: skip


def _services_idl(pkg: str, services: dict[str, tuple[str, str]]) -> str:
    """Services as rosidl expands them: request, response, the event and the service type."""
    out = []
    for name, (req, resp) in services.items():
        q = f"{pkg}::srv::{name}"
        out.append(
            f"struct {name}_Request {{ {req} }}; struct {name}_Response {{ {resp} }};\n"
            f"struct {name}_Event {{ service_msgs::msg::ServiceEventInfo info; sequence<{q}_Request, 1> request; "
            f"sequence<{q}_Response, 1> response; }};\n"
            f"struct {name} {{ {q}_Request request_message; {q}_Response response_message; "
            f"{q}_Event event_message; }};\n"
        )
    return f"module {pkg} {{ module srv {{\n{''.join(out)}}}; }};\n"


def _simulation_idl(version: int) -> str:
    messages, services = (_SI_MSGS, _SI_SRVS) if version == 1 else (_SI2_MSGS, _SI2_SRVS)
    msgs = "".join(f"struct {name} {{ {body} }};\n" for name, body in messages.items())
    return f"module simulation_interfaces {{ module msg {{\n{msgs}}}; }};\n" + _services_idl(
        "simulation_interfaces", services
    )


#: rcl_interfaces' parameter services (ros2/rcl_interfaces srv/*.srv); their messages are in rosbags' stores
_RCL = "rcl_interfaces::msg::"
_PARAMETER_IDL = _services_idl("rcl_interfaces", {
    "DescribeParameters": ("sequence<string> names;", f"sequence<{_RCL}ParameterDescriptor> descriptors;"),
    "GetParameterTypes": ("sequence<string> names;", "sequence<uint8> types;"),
    "GetParameters": ("sequence<string> names;", f"sequence<{_RCL}ParameterValue> values;"),
    "ListParameters": ("sequence<string> prefixes; uint64 depth;", f"{_RCL}ListParametersResult result;"),
    "SetParameters": (f"sequence<{_RCL}Parameter> parameters;", f"sequence<{_RCL}SetParametersResult> results;"),
    "SetParametersAtomically": (f"sequence<{_RCL}Parameter> parameters;", f"{_RCL}SetParametersResult result;"),
})  # fmt: skip


def _action_idl(pkg: str, name: str, goal: str, result: str, feedback: str) -> str:
    """An action as rosidl expands it (rosidl_parser's Action; REP-2011 hashes the whole of it):
    Goal, Result, Feedback, the SendGoal and GetResult services with their events, the feedback
    message, and the action type that holds the six."""
    q = f"{pkg}::action::{name}"
    uuid = "unique_identifier_msgs::msg::UUID goal_id;"
    services = {
        "SendGoal": (f"{uuid} {q}_Goal goal;", "boolean accepted; builtin_interfaces::msg::Time stamp;"),
        "GetResult": (uuid, f"int8 status; {q}_Result result;"),
    }
    out = [f"struct {name}_Goal {{ {goal} }};", f"struct {name}_Result {{ {result} }};",
           f"struct {name}_Feedback {{ {feedback} }};"]  # fmt: skip
    for srv, (req, resp) in services.items():
        out.append(
            f"struct {name}_{srv}_Request {{ {req} }}; struct {name}_{srv}_Response {{ {resp} }};\n"
            f"struct {name}_{srv}_Event {{ service_msgs::msg::ServiceEventInfo info; "
            f"sequence<{q}_{srv}_Request, 1> request; sequence<{q}_{srv}_Response, 1> response; }};\n"
            f"struct {name}_{srv} {{ {q}_{srv}_Request request_message; {q}_{srv}_Response response_message; "
            f"{q}_{srv}_Event event_message; }};"
        )
    out.append(f"struct {name}_FeedbackMessage {{ {uuid} {q}_Feedback feedback; }};")
    out.append(
        f"struct {name} {{ {q}_Goal goal; {q}_Result result; {q}_Feedback feedback; "
        f"{q}_SendGoal send_goal_service; {q}_GetResult get_result_service; "
        f"{q}_FeedbackMessage feedback_message; }};"
    )
    body = "\n".join(out)
    return f"module {pkg} {{ module action {{\n{body}\n}}; }};\n"


#: action_msgs/srv/CancelGoal (ros2/rcl_interfaces); its GoalInfo is in rosbags' stores
_CANCEL_IDL = """
module action_msgs { module srv {
  struct CancelGoal_Request { action_msgs::msg::GoalInfo goal_info; };
  struct CancelGoal_Response { int8 return_code; sequence<action_msgs::msg::GoalInfo> goals_canceling; };
  struct CancelGoal_Event { service_msgs::msg::ServiceEventInfo info;
    sequence<action_msgs::srv::CancelGoal_Request, 1> request;
    sequence<action_msgs::srv::CancelGoal_Response, 1> response; };
  struct CancelGoal { action_msgs::srv::CancelGoal_Request request_message;
    action_msgs::srv::CancelGoal_Response response_message; action_msgs::srv::CancelGoal_Event event_message; };
}; };
"""

#: nav2_msgs/action/NavigateToPose, Jazzy (ros-navigation/navigation2, branch jazzy; its feedback
#: gained the two tracking errors on branches lyrical and main), and test_msgs/action/Fibonacci,
#: whose hashes rosidl publishes (to check the expansion itself)
_NAV_FEEDBACK = (
    "geometry_msgs::msg::PoseStamped current_pose; builtin_interfaces::msg::Duration navigation_time; "
    "builtin_interfaces::msg::Duration estimated_time_remaining; int16 number_of_recoveries; "
    "float distance_remaining;"
)
_FIBONACCI_IDL = _action_idl("test_msgs", "Fibonacci", "int32 order;", "sequence<int32> sequence;",
                             "sequence<int32> sequence;")  # fmt: skip


def _navigate_idl(feedback: str) -> str:
    return _action_idl("nav2_msgs", "NavigateToPose", "geometry_msgs::msg::PoseStamped pose; string behavior_tree;",
                       "uint16 error_code; string error_msg;", feedback)  # fmt: skip


#: which simulation_interfaces (and Nav2 feedback) each distro's tools were built with
INTERFACES_VERSION = {"humble": 1, "jazzy": 1, "kilted": 1, "lyrical": 2, "rolling": 2}


def types(distro: str = "jazzy") -> Typestore:
    """The types a ROS tool of ``distro`` knows (Humble's keys carry no hash, and its other
    differences are no concern of these tests: it uses the 1.x store)."""
    return _types(INTERFACES_VERSION[distro])


@functools.lru_cache(maxsize=2)
def _types(version: int) -> Typestore:
    """Jazzy's messages, rosidl's ServiceEventInfo (uint8 client_gid) and the services in IDL."""
    jazzy = get_typestore(Stores.ROS2_JAZZY)
    store = get_typestore(Stores.EMPTY)
    store.register({k: v for k, v in jazzy.fielddefs.items() if k != "service_msgs/msg/ServiceEventInfo"})
    store.register(
        get_types_from_msg(
            "uint8 event_type\nbuiltin_interfaces/Time stamp\nuint8[16] client_gid\nint64 sequence_number",
            "service_msgs/msg/ServiceEventInfo",
        )
    )
    store.register(get_types_from_idl(_IDL))
    store.register(get_types_from_idl(_CANCEL_IDL))
    tracking = " float position_tracking_error; float heading_tracking_error;" if version == 2 else ""
    store.register(get_types_from_idl(_navigate_idl(_NAV_FEEDBACK + tracking) + _FIBONACCI_IDL))
    store.register(get_types_from_idl(_simulation_idl(version)))
    store.register(get_types_from_idl(_PARAMETER_IDL))
    return store


def type_hash(typename: str, distro: str = "jazzy") -> str:
    return "TypeHashNotSupported" if distro == "humble" else types(distro).hash_rihs01(typename)


def dds_name(typename: str) -> str:
    pkg, kind, name = typename.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def key(domain: int, name: str, typename: str, distro: str = "jazzy") -> str:
    return f"{domain}/{name.strip('/')}/{dds_name(typename)}/{type_hash(typename, distro)}"


def msg(typename: str, distro: str = "jazzy", **fields: Any) -> Any:
    return types(distro).types[typename](**fields)


def serialize(message: Any, typename: str, distro: str = "jazzy") -> bytes:
    return bytes(types(distro).serialize_cdr(message, typename))


def deserialize(payload: bytes, typename: str, distro: str = "jazzy") -> Any:
    return types(distro).deserialize_cdr(payload, typename)


def attachment(seq: int, gid: bytes) -> bytes:
    """rmw_zenoh's attachment: int64 sequence, int64 source timestamp (ns), 16, the GID."""
    return struct.pack("<qqB", seq, time.time_ns(), 16) + gid


#: the older attachment's values, as zenoh-ext deserializes them (a tuple type is a value here)
_LEGACY_TYPES: Any = tuple[str, zenoh.ext.Int64, str, zenoh.ext.Int64, str, bytes]


def legacy_attachment(seq: int, gid: bytes) -> bytes:
    """An older rmw_zenoh's attachment: zenoh-ext's serializer with each value's name before it."""
    values = ("sequence_number", zenoh.ext.Int64(seq), "source_timestamp", zenoh.ext.Int64(time.time_ns()),
              "source_gid", gid)  # fmt: skip
    return bytes(zenoh.ext.z_serialize(values).to_bytes())


def read_legacy_attachment(raw: bytes) -> tuple[int, bytes]:
    """(sequence, GID) of an older rmw_zenoh's attachment; ValueError for anything else (its
    parser throws)."""
    try:
        names_values: tuple[str, int, str, int, str, bytes] = zenoh.ext.z_deserialize(_LEGACY_TYPES, zenoh.ZBytes(raw))
    except zenoh.ext.ZDeserializeError as e:
        raise ValueError(f"not a string-keyed attachment ({len(raw)} bytes)") from e
    seq_name, seq, ts_name, _, gid_name, gid = names_values
    if (seq_name, ts_name, gid_name) != ("sequence_number", "source_timestamp", "source_gid"):
        raise ValueError(f"unexpected names {seq_name!r}, {ts_name!r}, {gid_name!r}")
    return int(seq), bytes(gid)


# -- the graph --------------------------------------------------------------------------------


@dataclass(frozen=True)
class Entity:
    """A parsed liveliness token."""

    zid: str
    node_id: str
    entity_id: str
    kind: str  # NN MP MS SS SC
    namespace: str  # '/' or '/tb3_0'
    node: str
    topic: str = ""  # '/tb3_0/scan'
    type: str = ""  # 'sensor_msgs::msg::dds_::LaserScan_'
    hash: str = ""
    qos: str = ""
    token: str = ""  # the whole token

    @property
    def node_fqn(self) -> str:
        return f"{self.namespace.rstrip('/')}/{self.node}"

    @property
    def gid(self) -> bytes:
        """As rmw_zenoh's graph cache derives it from the token (what ``ros2 topic info -v`` shows)."""
        return xxh3.gid(self.token)


def _unmangle(chunk: str) -> str:
    return "/" if chunk == "%" else chunk.replace("%", "/")


def parse_token(token: str) -> Entity:
    """As rmw_zenoh's Entity parser: rejects foreign admin spaces, unknown kinds, short tokens."""
    parts = token.split("/")
    if parts[0] != "@ros2_lv":
        raise ValueError(f"not a ROS token: {token}")
    if any(p == "" for p in parts):
        raise ValueError(f"empty chunk in {token}")
    kind = parts[5]
    if kind not in ("NN", "MP", "MS", "SS", "SC"):
        raise ValueError(f"unknown entity kind {kind}")
    if kind == "NN":
        if len(parts) != 9:
            raise ValueError(f"a node token has 9 chunks: {token}")
        return Entity(parts[2], parts[3], parts[4], kind, _unmangle(parts[7]), parts[8], token=token)
    if len(parts) != 13:
        raise ValueError(f"an entity token has 13 chunks: {token}")
    parse_qos(parts[12])  # the graph cache drops an entity whose QoS does not parse
    return Entity(
        parts[2], parts[3], parts[4], kind, _unmangle(parts[7]), parts[8],
        _unmangle(parts[9]), parts[10], parts[11], parts[12], token,
    )  # fmt: skip


#: RMW_DURATION_INFINITE as (seconds, nanoseconds)
INFINITE = (9223372036, 854775807)


@dataclass(frozen=True)
class QosProfile:
    """An entity's QoS with rmw's enum numbers; the defaults are rmw_zenoh's (``src/detail/qos.cpp``):
    reliable, volatile, keep last 42, infinite durations, automatic liveliness."""

    reliability: int = 1  # 1 reliable, 2 best effort
    durability: int = 2  # 1 transient local, 2 volatile
    history: int = 1  # 1 keep last, 2 keep all
    depth: int = 42
    deadline: tuple[int, int] = INFINITE
    lifespan: tuple[int, int] = INFINITE
    liveliness: int = 1  # 1 automatic, 3 manual by topic
    lease: tuple[int, int] = INFINITE


#: the enum numbers each field takes (rmw/types.h), as ``std::to_string`` writes them
_ENUMS = {
    "reliability": ("0", "1", "2", "3", "4"),
    "durability": ("0", "1", "2", "3", "4"),
    "history": ("0", "1", "2", "3"),
    "liveliness": ("0", "1", "3", "4", "5"),
}


def parse_qos(chunk: str) -> QosProfile:
    """A token's QoS chunk as rmw_zenoh's ``keyexpr_to_qos`` reads it (``src/detail/liveliness_utils.cpp``,
    jazzy 0.2.10): ``<rel>:<dur>:<hist>,<depth>:<deadline s>,<ns>:<lifespan s>,<ns>:<liveliness>,<lease s>,<ns>``,
    an empty field meaning rmw_zenoh's default, so that ``::,1:,:,:,,`` and ``1:2:1,1:,:,:,,`` are one
    profile. ValueError where rmw_zenoh gives up (too few parts, an unknown enum, a number that is not one)."""
    parts = chunk.split(":")
    if len(parts) < 6:
        raise ValueError(f"QoS {chunk!r}: fewer than 6 parts")
    history, deadline, lifespan, liveliness = (parts[i].split(",") for i in (2, 3, 4, 5))
    if min(len(history), len(deadline), len(lifespan)) < 2 or len(liveliness) < 3:
        raise ValueError(f"QoS {chunk!r}: a part has too few fields")
    d = QosProfile()

    def enum(field: str, text: str, default: int) -> int:
        if text == "":
            return default
        if text not in _ENUMS[field]:
            raise ValueError(f"QoS {chunk!r}: {field} {text!r}")
        return int(text)

    def number(text: str, default: int) -> int:
        if text == "":
            return default
        if not (text.isascii() and text.isdigit()):
            raise ValueError(f"QoS {chunk!r}: {text!r} is not a number")
        return int(text)

    return QosProfile(
        reliability=enum("reliability", parts[0], d.reliability),
        durability=enum("durability", parts[1], d.durability),
        history=enum("history", history[0], d.history),
        depth=number(history[1], d.depth),
        deadline=(number(deadline[0], d.deadline[0]), number(deadline[1], d.deadline[1])),
        lifespan=(number(lifespan[0], d.lifespan[0]), number(lifespan[1], d.lifespan[1])),
        liveliness=enum("liveliness", liveliness[0], d.liveliness),
        lease=(number(liveliness[1], d.lease[0]), number(liveliness[2], d.lease[1])),
    )


def _raw(zbytes: zenoh.ZBytes | None) -> bytes:
    return zbytes.to_bytes() if zbytes is not None else b""


def ros_type(dds_type: str) -> str:
    """``pkg::msg::dds_::Name_`` -> ``pkg/msg/Name``."""
    pkg, kind, _, name = dds_type.split("::")
    return f"{pkg}/{kind}/{name[:-1]}"


def topic_types(graph: list[Entity]) -> dict[str, set[str]]:
    """What ``ros2 topic list -t`` shows: every topic with the types its publishers and
    subscriptions advertise (a tool that infers a topic's type needs exactly one)."""
    out: dict[str, set[str]] = {}
    for e in graph:
        if e.kind in ("MP", "MS"):
            out.setdefault(e.topic, set()).add(ros_type(e.type))
    return out


def node_info(graph: list[Entity], node: str) -> dict[str, dict[str, set[str]]]:
    """What ``ros2 node info <node>`` lists, by kind: names with their types."""
    kinds = {"MP": "publishers", "MS": "subscribers", "SS": "services", "SC": "clients"}
    out: dict[str, dict[str, set[str]]] = {k: {} for k in kinds.values()}
    for e in graph:
        if e.kind in kinds and e.node_fqn == node:
            out[kinds[e.kind]].setdefault(e.topic, set()).add(ros_type(e.type))
    return out


# -- the tool ---------------------------------------------------------------------------------


class StandIn:
    """One ROS process: a peer session joined to the router at ``router``."""

    def __init__(self, router: str, domain: int = 0, distro: str = "jazzy", *, legacy: bool = False) -> None:
        """``legacy``: an rmw_zenoh of before the attachment's change (jazzy 0.2.0-0.2.3)."""
        conf = zenoh.Config()
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("connect/endpoints", json.dumps([router]))
        conf.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
        conf.insert_json5("scouting/multicast/enabled", "false")
        self.session = zenoh.open(conf)
        self.domain = domain
        self.distro = distro
        self.legacy = legacy
        self.gid = hashlib.md5(str(self.session.zid()).encode()).digest()
        self._seq = 0
        self._entities: list[Any] = []
        self._seen_services: set[str] = set()  # services a call found in the graph once
        self.rejected: list[str] = []  # samples a ROS subscription would have dropped

    def close(self) -> None:
        for e in self._entities:
            try:
                e.undeclare()
            except zenoh.ZError:
                pass
        self.session.close()

    def key(self, name: str, typename: str) -> str:
        return key(self.domain, name, typename, self.distro)

    def msg(self, typename: str, **fields: Any) -> Any:
        """A message of ``typename`` as this tool's distro defines it."""
        return msg(typename, self.distro, **fields)

    def _attachment(self, seq: int, gid: bytes) -> bytes:
        return legacy_attachment(seq, gid) if self.legacy else attachment(seq, gid)

    def _read_attachment(self, raw: bytes) -> tuple[int, bytes]:
        """(sequence, GID) as this tool's rmw_zenoh reads an attachment; ValueError where it throws."""
        if self.legacy:
            return read_legacy_attachment(raw)
        if len(raw) != 33 or raw[16] != 16:
            raise ValueError(f"attachment of {len(raw)} bytes")
        return struct.unpack_from("<q", raw)[0], bytes(raw[17:])

    # graph
    def graph(self) -> list[Entity]:
        out = []
        for reply in self.session.liveliness().get(f"@ros2_lv/{self.domain}/**", timeout=3.0):
            if reply.ok is not None:
                out.append(parse_token(str(reply.ok.key_expr)))
        return out

    def wait_graph(self, predicate: Any, timeout: float = 10.0) -> list[Entity]:
        """Poll the graph until ``predicate(entities)`` holds (a peer's tokens take a moment)."""
        deadline = time.monotonic() + timeout
        while True:
            g = self.graph()
            if predicate(g) or time.monotonic() > deadline:
                return g
            time.sleep(0.1)

    # topics
    def subscribe(self, name: str, typename: str) -> queue.Queue[tuple[Any, int, bytes, bytes]]:
        """Decoded messages of the topic, with their sequence numbers, raw payloads and the
        GIDs of the publishers that sent them."""
        out: queue.Queue[tuple[Any, int, bytes, bytes]] = queue.Queue()

        def on_sample(sample: zenoh.Sample) -> None:
            try:
                seq, gid = self._read_attachment(_raw(sample.attachment))
            except ValueError as e:
                self.rejected.append(f"{sample.key_expr}: {e}")
                return
            payload = sample.payload.to_bytes()
            out.put((deserialize(payload, typename, self.distro), seq, payload, gid))

        self._entities.append(self.session.declare_subscriber(self.key(name, typename), on_sample))
        return out

    def timestamps(self, name: str, typename: str) -> list[Any]:
        """The zenoh timestamps of the topic's samples as they arrive (None: a sample without one)."""
        out: list[Any] = []
        sub = self.session.declare_subscriber(self.key(name, typename), lambda sample: out.append(sample.timestamp))
        self._entities.append(sub)
        return out

    def subscribe_late(self, name: str, typename: str, depth: int = 100) -> queue.Queue[Any]:
        """A transient-local subscription: history from the publishers' caches, then live."""
        out: queue.Queue[Any] = queue.Queue()

        def on_sample(sample: zenoh.Sample) -> None:
            try:
                self._read_attachment(_raw(sample.attachment))
            except ValueError as e:
                self.rejected.append(f"{sample.key_expr}: {e}")
                return
            out.put(deserialize(sample.payload.to_bytes(), typename, self.distro))

        sub = zenoh.ext.declare_advanced_subscriber(
            self.session,
            self.key(name, typename),
            on_sample,
            history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=depth),
            subscriber_detection=True,
        )
        self._entities.append(sub)
        return out

    def publisher(self, name: str, typename: str, matched: float = 0.0) -> Callable[..., None]:
        """A publisher's put; with ``matched``, first wait up to that many seconds until a
        subscriber matches (what rclcpp's ``wait_for_matched``-style helpers do), so that the
        first message is not sent into the void."""
        pub = self.session.declare_publisher(self.key(name, typename))
        self._entities.append(pub)
        deadline = time.monotonic() + matched
        status = pub.matching_status
        while not status.matching and time.monotonic() < deadline:  # type: ignore[attr-defined]  # stub: bool
            time.sleep(0.02)
            status = pub.matching_status
        gid = hashlib.md5(f"{name}{typename}".encode()).digest()
        seq = [0]

        def put(message: Any, with_attachment: bool = True) -> None:
            seq[0] += 1
            payload = serialize(message, typename, self.distro)
            if with_attachment:
                pub.put(payload, attachment=self._attachment(seq[0], gid))
            else:
                pub.put(payload)

        return put

    # services
    def call(self, name: str, srv_type: str, request: Any, timeout: float = 10.0) -> Any:
        """As an rclcpp client: get with the attachment, take the reply whose sequence matches
        (rclcpp drops any later reply of the same sequence: the call is no longer pending).
        The first call of a service waits for it to show in the graph (at most ``timeout``), as
        ``ros2 service call`` waits for the service: a daemon declares its services one by one."""
        if name not in self._seen_services:
            kind = dds_name(srv_type)

            def served(g: list[Entity]) -> bool:
                return any(e.kind == "SS" and e.topic == name and e.type == kind for e in g)

            if served(self.wait_graph(served, timeout)):
                self._seen_services.add(name)
        for response in self._call(name, srv_type, request, timeout):
            return response
        raise TimeoutError(f"no reply from {name}")

    def call_all(self, name: str, srv_type: str, request: Any, timeout: float = 10.0) -> list[Any]:
        """Every reply the call gets that rclcpp would take (its sequence and GID), until the
        query ends: what the servers of a service answered, all of them."""
        return list(self._call(name, srv_type, request, timeout))

    def call_later(self, name: str, srv_type: str, request: Any, timeout: float = 10.0) -> Callable[[], Any]:
        """Send the call now; the function returned waits for its reply (as :meth:`call`)."""
        replies = self._call(name, srv_type, request, timeout)

        def wait() -> Any:
            for response in replies:
                return response
            raise TimeoutError(f"no reply from {name}")

        return wait

    def _call(self, name: str, srv_type: str, request: Any, timeout: float) -> Iterator[Any]:
        """As rmw_zenoh's client: target all complete queryables, no consolidation. The query
        leaves at once; the replies are read as the iterator is."""
        self._seq += 1
        seq = self._seq
        payload = serialize(request, f"{srv_type}_Request", self.distro)
        replies = self.session.get(
            self.key(name, srv_type),
            payload=payload,
            attachment=self._attachment(seq, self.gid),
            target=zenoh.QueryTarget.ALL_COMPLETE,
            consolidation=zenoh.ConsolidationMode.NONE,
            timeout=timeout,
        )
        return self._replies(name, srv_type, seq, replies)

    def _replies(self, name: str, srv_type: str, seq: int, replies: Any) -> Iterator[Any]:
        for reply in replies:
            if reply.ok is None:
                continue  # rclcpp logs error replies and keeps waiting
            try:
                rseq, gid = self._read_attachment(_raw(reply.ok.attachment))
            except ValueError as e:
                self.rejected.append(f"reply on {name}: {e}")
                continue
            if rseq != seq or gid != self.gid:
                self.rejected.append(f"reply for sequence {rseq}, not {seq}")
                continue
            yield deserialize(reply.ok.payload.to_bytes(), f"{srv_type}_Response", self.distro)

    def service_available(self, name: str, srv_type: str) -> bool:
        """As GraphCache::service_server_is_available: an SS token of that name and type."""
        return any(e.kind == "SS" and e.topic == name and e.type == dds_name(srv_type) for e in self.graph())

    # parameters, as ros2param's api calls them
    def list_parameters(self, node: str, prefixes: tuple[str, ...] = (), depth: int = 0) -> Any:
        """``ros2 param list <node>``'s call (depth 0: DEPTH_RECURSIVE). ros2 param lists only
        nodes whose ``list_parameters`` is in the graph: wait for it first (``service_available``;
        one graph query may miss a token another one showed)."""
        service = (f"{node}/list_parameters", "rcl_interfaces/srv/ListParameters")
        request = self.msg("rcl_interfaces/srv/ListParameters_Request", prefixes=list(prefixes), depth=depth)
        return self.call(*service, request).result

    def parameter_call(self, node: str, service: str, **fields: Any) -> Any:
        """One of a node's parameter services (``get_parameters``, ``describe_parameters``, ...)."""
        typename = "rcl_interfaces/srv/" + "".join(w.capitalize() for w in service.split("_"))
        return self.call(f"{node}/{service}", typename, self.msg(f"{typename}_Request", **fields))

    def set_parameter(self, node: str, name: str, value: Any, atomically: bool = False) -> Any:
        """``ros2 param set``: the value's ParameterValue as ros2param builds it from Python."""
        kind, field = {bool: (1, "bool_value"), int: (2, "integer_value"), float: (3, "double_value"),
                       str: (4, "string_value")}[type(value)]  # fmt: skip
        v = _parameter_value(self, kind, field, value)
        parameter = self.msg("rcl_interfaces/msg/Parameter", name=name, value=v)
        service = "set_parameters_atomically" if atomically else "set_parameters"
        return self.parameter_call(node, service, parameters=[parameter])


def _parameter_value(tool: StandIn, kind: int, field: str, value: Any) -> Any:
    import numpy as np

    fields: dict[str, Any] = {
        "type": kind, "bool_value": False, "integer_value": 0, "double_value": 0.0, "string_value": "",
        "byte_array_value": np.zeros(0, np.uint8), "bool_array_value": np.zeros(0, np.bool_),
        "integer_array_value": np.zeros(0, np.int64), "double_array_value": np.zeros(0, np.float64),
        "string_array_value": [],
    }  # fmt: skip
    fields[field] = value
    return tool.msg("rcl_interfaces/msg/ParameterValue", **fields)


# -- actions (rcl_action over rmw_zenoh: three services and two topics under <action>/_action/) --------


def actions(graph: list[Entity]) -> dict[str, set[str]]:
    """What ``ros2 action list -t`` shows: rcl_action's graph.c takes every topic whose name
    contains ``/_action/feedback`` as an action (the name before it) of the feedback's type less
    its ``_FeedbackMessage``."""
    out: dict[str, set[str]] = {}
    for e in graph:
        if e.kind == "MP" and "/_action/feedback" in e.topic:
            pkg, kind, _, name = e.type.split("::")
            out.setdefault(e.topic.split("/_action/feedback")[0], set()).add(
                f"{pkg}/{kind}/{name[:-1].removesuffix('_FeedbackMessage')}"
            )
    return out


def action_server_available(graph: list[Entity], action: str, action_type: str) -> bool:
    """As rcl_action_server_is_available: the three services and both publishers exist."""
    services = {(e.topic, e.type) for e in graph if e.kind == "SS"}
    publishers = {(e.topic, e.type) for e in graph if e.kind == "MP"}
    return all(
        (f"{action}/_action/{suffix}", dds_name(t)) in services
        for suffix, t in (("send_goal", f"{action_type}_SendGoal"), ("get_result", f"{action_type}_GetResult"),
                          ("cancel_goal", "action_msgs/srv/CancelGoal"))
    ) and all(
        (f"{action}/_action/{suffix}", dds_name(t)) in publishers
        for suffix, t in (("feedback", f"{action_type}_FeedbackMessage"), ("status", "action_msgs/msg/GoalStatusArray"))
    )  # fmt: skip


def uuid_msg(raw: bytes) -> Any:
    import numpy as np

    return msg("unique_identifier_msgs/msg/UUID", uuid=np.frombuffer(raw, dtype=np.uint8).copy())


class ActionClient:
    """An rclcpp action client of one action: goals by send_goal, results by get_result (asked at
    once, answered when the goal ends), cancels by cancel_goal, all as service calls."""

    def __init__(self, tool: StandIn, action: str, action_type: str) -> None:
        self.tool = tool
        self.action = action
        self.type = action_type

    def send_goal(self, goal: Any, goal_id: bytes | None = None, timeout: float = 10.0) -> tuple[bytes, Any]:
        goal_id = goal_id or os.urandom(16)
        request = msg(f"{self.type}_SendGoal_Request", goal_id=uuid_msg(goal_id), goal=goal)
        return goal_id, self.tool.call(f"{self.action}/_action/send_goal", f"{self.type}_SendGoal", request, timeout)

    def get_result(self, goal_id: bytes, timeout: float = 60.0) -> queue.Queue[Any]:
        """The call leaves now; its reply (it comes when the goal ends) is waited for on a thread
        of its own and arrives in the queue, or the exception that waiting raised."""
        out: queue.Queue[Any] = queue.Queue()
        request = msg(f"{self.type}_GetResult_Request", goal_id=uuid_msg(goal_id))
        wait = self.tool.call_later(f"{self.action}/_action/get_result", f"{self.type}_GetResult", request, timeout)

        def run() -> None:
            try:
                out.put(wait())
            except Exception as e:
                out.put(e)

        threading.Thread(target=run, daemon=True).start()
        return out

    def cancel_goal(self, goal_id: bytes = bytes(16), sec: int = 0, nanosec: int = 0) -> Any:
        info = msg("action_msgs/msg/GoalInfo", goal_id=uuid_msg(goal_id),
                   stamp=msg("builtin_interfaces/msg/Time", sec=sec, nanosec=nanosec))  # fmt: skip
        request = msg("action_msgs/srv/CancelGoal_Request", goal_info=info)
        return self.tool.call(f"{self.action}/_action/cancel_goal", "action_msgs/srv/CancelGoal", request)

    def feedback(self) -> queue.Queue[tuple[Any, int, bytes, bytes]]:
        return self.tool.subscribe(f"{self.action}/_action/feedback", f"{self.type}_FeedbackMessage")

    def status(self) -> queue.Queue[Any]:
        """As rcl_action's status subscription: transient local, depth 1."""
        return self.tool.subscribe_late(f"{self.action}/_action/status", "action_msgs/msg/GoalStatusArray", depth=1)


def wait_for(q: queue.Queue[Any], predicate: Any = None, timeout: float = 10.0) -> Any:
    """The first item of ``q`` for which ``predicate`` holds."""
    deadline = time.monotonic() + timeout
    while True:
        left = deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError("nothing arrived")
        try:
            item = q.get(timeout=left)
        except queue.Empty:
            raise TimeoutError("nothing arrived") from None
        if predicate is None or predicate(item):
            return item
