"""rmw_zenoh's naming: data keys, liveliness tokens (the ROS graph), their QoS chunk and GIDs.

From rmw_zenoh's design document ("Topic and Service name mapping", "Graph Cache",
"Publishers"): a topic ``/tb3_0/scan`` of ``sensor_msgs/msg/LaserScan`` in domain 0 is the key
``0/tb3_0/scan/sensor_msgs::msg::dds_::LaserScan_/<hash>``; a participant announces itself,
its nodes and their publishers, subscriptions and services with liveliness tokens under
``@ros2_lv/<domain>/<zid>/...``, where names have every ``/`` replaced by ``%``. ROS tools
subscribe on exact keys and read the graph from the tokens only: without a token a topic is
invisible to ``ros2 topic list`` and a service never "available" to a waiting client.

An entity's GID is derived from its token as rmw_zenoh derives it, so that the GID a sample's
attachment (attachment.py) carries is the one ``ros2 topic info -v`` shows for its publisher.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import xxhash

from simd.adapters.ros2.interfaces import Distro, dds_type_name, type_hash

ADMIN_SPACE = "@ros2_lv"
#: rmw_zenoh's default depth (``src/detail/qos.cpp``): a token leaves out a depth equal to it
DEFAULT_DEPTH = 42


class Kind(Enum):
    """Entity kinds of a liveliness token."""

    NODE = "NN"
    PUBLISHER = "MP"
    SUBSCRIPTION = "MS"
    SERVICE = "SS"
    CLIENT = "SC"


@dataclass(frozen=True)
class Qos:
    """The QoS an entity advertises: keep-last history of ``depth``, reliable or best effort,
    volatile or transient local; deadline, lifespan and liveliness lease infinite, liveliness
    automatic (what rclcpp's profiles resolve to)."""

    depth: int = 10
    reliable: bool = True
    transient_local: bool = False
    #: how long a sample stays valid, in whole seconds (None: for ever, rmw's default)
    lifespan_s: int | None = None

    def chunk(self) -> str:
        """The token's QoS chunk, ``<rel>:<dur>:<hist>,<depth>:<deadline s>,<ns>:<lifespan s>,<ns>:
        <liveliness>,<lease s>,<ns>``, as rmw_zenoh's ``qos_to_keyexpr`` writes it: a field equal
        to rmw_zenoh's default (reliable, volatile, keep last, depth 42, infinite durations,
        automatic liveliness) is left empty; otherwise the rmw enum's number (reliability 2 best
        effort, durability 1 transient local). ``keyexpr_to_qos`` reads an empty field as the
        default, so both spellings mean the same profile, but this one is the one ROS tools
        see from rmw_zenoh's own processes. A finite lifespan is whole seconds and 0 ns (the
        infinite default's nanoseconds are not 0, so they are written)."""
        rel = "" if self.reliable else "2"
        dur = "1" if self.transient_local else ""
        depth = "" if self.depth == DEFAULT_DEPTH else str(self.depth)
        lifespan = "," if self.lifespan_s is None else f"{self.lifespan_s},0"
        return f"{rel}:{dur}:,{depth}:,:{lifespan}:,,"


#: QoS as the Gazebo TurtleBot3 and tf2 advertise them
ODOM_QOS = Qos(depth=1)
SCAN_QOS = Qos(depth=5)
IMU_QOS = Qos(depth=5)
JOINT_STATES_QOS = Qos(depth=1000)
CMD_VEL_QOS = Qos(depth=1)
TF_QOS = Qos(depth=100)
TF_STATIC_QOS = Qos(depth=1, transient_local=True)
CLOCK_QOS = Qos(depth=1, reliable=False)
SERVICE_QOS = Qos(depth=10)
#: what rcl gives every node: its parameter services and /parameter_events (rmw's parameters
#: profiles, depth 1000), /rosout (transient local, depth 1000, samples valid for 10 s)
PARAMETERS_QOS = Qos(depth=1000)
PARAMETER_EVENTS_QOS = Qos(depth=1000)
ROSOUT_QOS = Qos(depth=1000, transient_local=True, lifespan_s=10)


def mangle(name: str) -> str:
    """A ROS name in a token chunk: every ``/`` becomes ``%``; empty becomes ``%``."""
    return name.replace("/", "%") or "%"


@dataclass(frozen=True)
class Topic:
    """A topic or service with its type, as keys and tokens name it in one domain."""

    name: str  # fully qualified: /tb3_0/scan
    typename: str  # sensor_msgs/msg/LaserScan
    domain: int
    distro: Distro

    @property
    def hash(self) -> str:
        return type_hash(self.typename, self.distro)

    @property
    def dds_type(self) -> str:
        return dds_type_name(self.typename)

    @property
    def key(self) -> str:
        return f"{self.domain}/{self.name.strip('/')}/{self.dds_type}/{self.hash}"


@dataclass(frozen=True)
class Node:
    """A ROS node of this participant: ``namespace`` '/' or '/tb3_0', ``name`` 'turtlebot3_diff_drive'."""

    domain: int
    zid: str
    node_id: int
    namespace: str
    name: str
    enclave: str = ""

    def _prefix(self, entity_id: int, kind: Kind) -> str:
        ns = "" if self.namespace == "/" else self.namespace
        return "/".join(
            (
                ADMIN_SPACE,
                str(self.domain),
                self.zid,
                str(self.node_id),
                str(entity_id),
                kind.value,
                mangle(self.enclave),
                mangle(ns),
                mangle(self.name),
            )
        )

    @property
    def fqn(self) -> str:
        """The node's fully qualified name: ``/fleetsim``, ``/tb3_0/turtlebot3``."""
        return f"{self.namespace.rstrip('/')}/{self.name}"

    def token(self) -> str:
        return self._prefix(self.node_id, Kind.NODE)

    def entity_token(self, entity_id: int, kind: Kind, topic: Topic, qos: Qos) -> str:
        return "/".join((self._prefix(entity_id, kind), mangle(topic.name), topic.dds_type, topic.hash, qos.chunk()))


def gid(token: str) -> bytes:
    """The entity's 16-byte GID as rmw_zenoh makes it (``Entity::Entity`` in
    ``src/detail/liveliness_utils.cpp``): XXH3-128 (seed 0) of the token's text, the low 64-bit
    half then the high one, each little-endian, i.e. the 128-bit value little-endian. (xxhash's
    ``digest()`` is the canonical big-endian form, the reverse of these bytes.)"""
    return xxhash.xxh3_128_intdigest(token.encode()).to_bytes(16, "little")
