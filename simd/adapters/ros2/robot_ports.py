"""One robot as ROS 2 sees it: a node in its namespace with the topics of the Gazebo TurtleBot3.

Gazebo loads each robot's plugins as nodes of their own (``turtlebot3_diff_drive``,
``turtlebot3_laserscan``, ``turtlebot3_imu``, ``turtlebot3_joint_state``, and the launch file's
``robot_state_publisher``); here one node, ``/<ns>/turtlebot3``, holds all of their topics.
The topics are what tools use; the node names only show in ``ros2 node list``. One node keeps
the graph small: zenoh's key tree grows a branch per node, and with five nodes a robot the
thousandth spawn declared its tokens ten times slower than the first (5.3 against 0.9 ms a
robot with one). A robot's publishers and tokens are declared when it spawns and undeclared
when it is deleted.

Each publisher knows (from zenoh's matching listener) whether anybody subscribes: messages
are built only for topics somebody reads.

Where the robot's transforms go and what its frames are called is the :class:`TfLayout`'s
(tf_layout.py): ``/tf_static`` with prefixed frames by default, ``/<ns>/tf_static`` and a
``/<ns>/tf`` of the robot's own with unprefixed frames in Nav2's multi-robot layout.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Any

import zenoh
import zenoh.ext

from protocol import frames
from simd.adapters.ros2 import attachment, graph, tf_cdr
from simd.adapters.ros2.attachment import LegacyNotice
from simd.adapters.ros2.graph import Kind, Node, Qos, Topic
from simd.adapters.ros2.interfaces import CmdVel, Distro
from simd.adapters.ros2.tf_layout import TfLayout
from simd.adapters.zenoh_entities import Interest, Tally, undeclare_all
from simd.core.models import RobotModel

#: the node that holds each robot's topics, in the robot's namespace
NODE_NAME = "turtlebot3"

TWIST, TWIST_STAMPED = "geometry_msgs/msg/Twist", "geometry_msgs/msg/TwistStamped"
#: what ``/<ns>/cmd_vel`` takes on the wire: both, whichever one it advertises
CMD_VEL_TYPES = (TWIST, TWIST_STAMPED)
#: the types its subscription advertises, by ``--ros-cmd-vel``: one, so that a tool that infers a
#: topic's type from the graph (``ros2 topic echo`` and ``pub`` without a type, rosbag2) finds one
ADVERTISED_CMD_VEL: dict[CmdVel, tuple[str, ...]] = {
    "twist": (TWIST,),
    "stamped": (TWIST_STAMPED,),
    "both": CMD_VEL_TYPES,
}
TF_TYPE = "tf2_msgs/msg/TFMessage"
#: what RViz's "2D Pose Estimate" sends (AMCL's and nav2_loopback_sim's initialpose)
INITIAL_POSE_TYPE = "geometry_msgs/msg/PoseWithCovarianceStamped"
#: advertised reliable and volatile, as RViz publishes it (rmw_zenoh has no incompatible QoS pairs)
INITIAL_POSE_QOS = Qos(depth=1)


@dataclass
class Participant:
    """This daemon in one ROS domain: the session, its id and the counter of entity ids."""

    session: zenoh.Session
    domain: int
    distro: Distro
    zid: str = ""
    #: how many robots' odom, scan, imu, joint_states and own tf have a subscriber (all zero: a
    #: tick builds nothing per robot)
    odom_interest: Tally = field(default_factory=Tally)
    scan_interest: Tally = field(default_factory=Tally)
    imu_interest: Tally = field(default_factory=Tally)
    joints_interest: Tally = field(default_factory=Tally)
    tf_interest: Tally = field(default_factory=Tally)
    #: says once per sender that an older rmw_zenoh reached the daemon (attachment.py)
    legacy: LegacyNotice = field(default_factory=LegacyNotice)
    _ids: itertools.count[int] = field(default_factory=lambda: itertools.count(1))

    def __post_init__(self) -> None:
        self.zid = str(self.session.zid())

    @property
    def robot_interest(self) -> bool:
        return bool(
            self.odom_interest or self.scan_interest or self.imu_interest or self.joints_interest or self.tf_interest
        )

    def next_id(self) -> int:
        return next(self._ids)

    def topic(self, name: str, typename: str) -> Topic:
        return Topic(name, typename, self.domain, self.distro)

    def node(self, namespace: str, name: str) -> Node:
        return Node(self.domain, self.zid, self.next_id(), namespace, name)


class _Attached:
    """Puts whose every sample carries rmw_zenoh's attachment: a count from 1, and the GID."""

    pub: Any
    gid: bytes
    sequence: int

    def put(self, payload: bytes, stamp_ns: int | None = None) -> None:
        """Send with the attachment; ``stamp_ns`` (wall clock) saves reading the clock per message."""
        self.sequence += 1
        self.pub.put(payload, attachment=attachment.encode(self.sequence, self.gid, stamp_ns))


class RosPublisher(_Attached):
    """A declared publisher whose every sample carries rmw_zenoh's attachment, with its token."""

    def __init__(self, p: Participant, node: Node, topic: Topic, qos: Qos, tokens: list[Any],
                 tally: Tally | None = None) -> None:  # fmt: skip
        token = node.entity_token(p.next_id(), Kind.PUBLISHER, topic, qos)
        self.topic = topic
        self.gid = graph.gid(token)
        self.sequence = 0
        self.pub = p.session.declare_publisher(topic.key, reliability=_reliability(qos))
        self.wanted = Interest(self.pub, tally)
        tokens.append(p.session.liveliness().declare_token(token))

    def undeclare(self) -> None:
        self.wanted.undeclare()
        self.pub.undeclare()


class LatchedPublisher(_Attached):
    """A transient-local publisher (``/tf_static``): late subscribers get its last message.

    rmw_zenoh declares a transient-local publisher as a zenoh-ext advanced publisher with a
    cache of ``depth`` samples, publisher detection and a 500 ms sporadic heartbeat; a late
    ROS subscriber queries that cache. tf2's static broadcaster keeps one message, and tf2
    merges the static messages of all publishers, so each robot has one of these, as each
    Gazebo robot has its robot_state_publisher.
    """

    def __init__(self, p: Participant, node: Node, topic: Topic, qos: Qos, tokens: list[Any],
                 *, lazy: bool = False) -> None:  # fmt: skip
        """``lazy``: the token now, the cache with the first message (a publisher that may never
        send, an action's status, costs a spawn only its token; nobody can miss what was
        never sent, and a late subscriber finds the cache when it appears)."""
        token = node.entity_token(p.next_id(), Kind.PUBLISHER, topic, qos)
        self.gid = graph.gid(token)
        self.sequence = 0
        self._session, self._key, self._depth = p.session, topic.key, qos.depth
        self.pub = None if lazy else self._declare()
        tokens.append(p.session.liveliness().declare_token(token))

    def _declare(self) -> Any:
        return zenoh.ext.declare_advanced_publisher(
            self._session,
            self._key,
            cache=zenoh.ext.CacheConfig(max_samples=self._depth),
            publisher_detection=True,
            sample_miss_detection=zenoh.ext.MissDetectionConfig(heartbeat=None, sporadic_heartbeat=0.5),
        )

    def put(self, payload: bytes, stamp_ns: int | None = None) -> None:
        if self.pub is None:
            self.pub = self._declare()
        super().put(payload, stamp_ns)

    def undeclare(self) -> None:
        try:
            if self.pub is not None:
                self.pub.undeclare()
        except zenoh.ZError:
            pass


class KeyPublisher(_Attached):
    """A ROS publisher that is only its token: each message is a ``session.put`` on the key.
    For topics that carry a few messages while something happens (a goal's feedback, its
    plans): a declared zenoh publisher per robot would cost every spawn more than they do."""

    def __init__(self, p: Participant, node: Node, topic: Topic, qos: Qos, tokens: list[Any]) -> None:
        token = node.entity_token(p.next_id(), Kind.PUBLISHER, topic, qos)
        self.topic = topic
        self.gid = graph.gid(token)
        self.sequence = 0
        self.pub = _KeyPut(p.session, topic.key)
        tokens.append(p.session.liveliness().declare_token(token))


@dataclass(frozen=True)
class _KeyPut:
    session: zenoh.Session
    key: str

    def put(self, payload: bytes, attachment: bytes) -> None:
        self.session.put(self.key, payload, attachment=attachment)


def _reliability(qos: Qos) -> zenoh.Reliability:
    return zenoh.Reliability.RELIABLE if qos.reliable else zenoh.Reliability.BEST_EFFORT


def declare_node(p: Participant, node: Node, tokens: list[Any]) -> Node:
    tokens.append(p.session.liveliness().declare_token(node.token()))
    return node


class RobotPorts:
    """A robot's ROS entities; also the wheel angles its joint_states report."""

    def __init__(self, p: Participant, namespace: str, model: RobotModel, layout: TfLayout | None = None,
                 cmd_vel: CmdVel = "both") -> None:  # fmt: skip
        self.namespace = namespace
        self.model = model
        self.layout = layout = layout or TfLayout()
        self._tokens: list[Any] = []
        ns = f"/{namespace}"
        t = self._tokens
        node = self.node = declare_node(p, p.node(ns, NODE_NAME), t)
        odom = p.topic(f"{ns}/odom", "nav_msgs/msg/Odometry")
        scan = p.topic(f"{ns}/scan", "sensor_msgs/msg/LaserScan")
        imu_topic = p.topic(f"{ns}/imu", "sensor_msgs/msg/Imu")
        joint_topic = p.topic(f"{ns}/joint_states", "sensor_msgs/msg/JointState")
        self.odom = RosPublisher(p, node, odom, graph.ODOM_QOS, t, p.odom_interest)
        self.scan = RosPublisher(p, node, scan, graph.SCAN_QOS, t, p.scan_interest)
        self.imu = RosPublisher(p, node, imu_topic, graph.IMU_QOS, t, p.imu_interest)
        self.joint_states = RosPublisher(p, node, joint_topic, graph.JOINT_STATES_QOS, t, p.joints_interest)
        for typename in ADVERTISED_CMD_VEL[cmd_vel]:  # the intake subscribes to every robot's cmd_vel at once
            topic = p.topic(f"{ns}/cmd_vel", typename)
            token = node.entity_token(p.next_id(), Kind.SUBSCRIPTION, topic, graph.CMD_VEL_QOS)
            t.append(p.session.liveliness().declare_token(token))
        #: the robot's own /<ns>/tf (Nav2's multi-robot layout), else None: it is on the fleet's /tf
        self.tf: RosPublisher | None = None
        if layout.namespaced:
            self.tf = RosPublisher(p, node, p.topic(layout.tf_topic(namespace), TF_TYPE), graph.TF_QOS, t,
                                   p.tf_interest)  # fmt: skip
        if layout.localization:  # one subscriber takes every robot's (localization.py)
            topic = p.topic(f"{ns}/initialpose", INITIAL_POSE_TYPE)
            t.append(p.session.liveliness().declare_token(
                node.entity_token(p.next_id(), Kind.SUBSCRIPTION, topic, INITIAL_POSE_QOS)))  # fmt: skip
        self.tf_static = LatchedPublisher(
            p, node, p.topic(layout.tf_static_topic(namespace), TF_TYPE), graph.TF_STATIC_QOS, t
        )
        self.tf_static.put(tf_cdr.static_message(self.static_transforms()))
        self.wheel_angles = (0.0, 0.0)
        self.last_linear: float | None = None  # the IMU's speed a tick ago

    def static_transforms(self) -> list[frames.Transform]:
        """The robot's fixed frames (protocol/frames.py), as robot_state_publisher sends them."""
        return self.layout.static(self.namespace, self.model.name)

    def close(self) -> None:
        for pub in (self.odom, self.scan, self.imu, self.joint_states, self.tf, self.tf_static):
            if pub is not None:
                pub.undeclare()
        undeclare_all(self._tokens)
