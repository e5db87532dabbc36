"""One robot as ROS 2 sees it: its nodes, topics and tokens, named as the Gazebo TurtleBot3 names them.

Gazebo loads each robot's plugins as nodes in the robot's namespace: ``turtlebot3_diff_drive``
(odom, cmd_vel), ``turtlebot3_laserscan`` (scan), ``turtlebot3_imu`` (imu) and
``turtlebot3_joint_state`` (joint_states), and the launch file adds a ``robot_state_publisher``
(the fixed frames on ``/tf_static``). The same nodes appear here, so ``ros2 node list``
and ``ros2 topic list`` look as they would with Gazebo. A robot's publishers are declared
when it spawns and undeclared when it is deleted, with their liveliness tokens.

Each publisher knows (from zenoh's matching listener) whether anybody subscribes: messages
are built only for topics somebody reads.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Any

import zenoh
import zenoh.ext

from simd.adapters.ros2 import cdr, graph
from simd.adapters.ros2.graph import Kind, Node, Qos, Topic
from simd.adapters.ros2.interfaces import Distro
from simd.adapters.zenoh_entities import Interest, undeclare_all
from simd.core.models import RobotModel

#: base_footprint -> base_link, and base_link -> base_scan / imu_link, per model (the URDF's offsets)
BASE_LINK_Z = 0.010
SCAN_OFFSET = {"burger": (-0.032, 0.0, 0.172), "waffle": (-0.064, 0.0, 0.122), "waffle_pi": (-0.064, 0.0, 0.122)}
IMU_OFFSET = {"burger": (-0.032, 0.0, 0.068), "waffle": (0.0, 0.0, 0.068), "waffle_pi": (0.0, 0.0, 0.068)}

CMD_VEL_TYPES = ("geometry_msgs/msg/Twist", "geometry_msgs/msg/TwistStamped")


@dataclass
class Participant:
    """This daemon in one ROS domain: the session, its id and the counter of entity ids."""

    session: zenoh.Session
    domain: int
    distro: Distro
    zid: str = ""
    _ids: itertools.count[int] = field(default_factory=lambda: itertools.count(1))

    def __post_init__(self) -> None:
        self.zid = str(self.session.zid())

    def next_id(self) -> int:
        return next(self._ids)

    def topic(self, name: str, typename: str) -> Topic:
        return Topic(name, typename, self.domain, self.distro)

    def node(self, namespace: str, name: str) -> Node:
        return Node(self.domain, self.zid, self.next_id(), namespace, name)


class RosPublisher:
    """A declared publisher whose every sample carries rmw_zenoh's attachment, with its token."""

    def __init__(self, p: Participant, node: Node, topic: Topic, qos: Qos, tokens: list[Any]) -> None:
        token = node.entity_token(p.next_id(), Kind.PUBLISHER, topic, qos)
        self.topic = topic
        self.gid = graph.gid(token)
        self.sequence = 0
        self.pub = p.session.declare_publisher(topic.key, reliability=_reliability(qos))
        self.wanted = Interest(self.pub)
        tokens.append(p.session.liveliness().declare_token(token))

    def put(self, payload: bytes) -> None:
        self.sequence += 1
        self.pub.put(payload, attachment=graph.attachment(self.sequence, self.gid))

    def undeclare(self) -> None:
        self.wanted.undeclare()
        self.pub.undeclare()


class LatchedPublisher:
    """A transient-local publisher (``/tf_static``): late subscribers get its last message.

    rmw_zenoh declares a transient-local publisher as a zenoh-ext advanced publisher with a
    cache of ``depth`` samples, publisher detection and a 500 ms sporadic heartbeat; a late
    ROS subscriber queries that cache. tf2's static broadcaster keeps one message, and tf2
    merges the static messages of all publishers, so each robot has one of these, as each
    Gazebo robot has its robot_state_publisher.
    """

    def __init__(self, p: Participant, node: Node, topic: Topic, qos: Qos, tokens: list[Any]) -> None:
        token = node.entity_token(p.next_id(), Kind.PUBLISHER, topic, qos)
        self.gid = graph.gid(token)
        self.sequence = 0
        self.pub = zenoh.ext.declare_advanced_publisher(
            p.session,
            topic.key,
            cache=zenoh.ext.CacheConfig(max_samples=qos.depth),
            publisher_detection=True,
            sample_miss_detection=zenoh.ext.MissDetectionConfig(heartbeat=None, sporadic_heartbeat=0.5),
        )
        tokens.append(p.session.liveliness().declare_token(token))

    def put(self, payload: bytes) -> None:
        self.sequence += 1
        self.pub.put(payload, attachment=graph.attachment(self.sequence, self.gid))

    def undeclare(self) -> None:
        try:
            self.pub.undeclare()
        except zenoh.ZError:
            pass


def _reliability(qos: Qos) -> zenoh.Reliability:
    return zenoh.Reliability.RELIABLE if qos.reliable else zenoh.Reliability.BEST_EFFORT


def declare_node(p: Participant, node: Node, tokens: list[Any]) -> Node:
    tokens.append(p.session.liveliness().declare_token(node.token()))
    return node


class RobotPorts:
    """A robot's ROS entities; also the wheel angles its joint_states report."""

    def __init__(self, p: Participant, namespace: str, model: RobotModel) -> None:
        self.namespace = namespace
        self.model = model
        self._tokens: list[Any] = []
        ns = f"/{namespace}"
        t = self._tokens
        drive = declare_node(p, p.node(ns, "turtlebot3_diff_drive"), t)
        laser = declare_node(p, p.node(ns, "turtlebot3_laserscan"), t)
        imu = declare_node(p, p.node(ns, "turtlebot3_imu"), t)
        joints = declare_node(p, p.node(ns, "turtlebot3_joint_state"), t)
        self.odom = RosPublisher(p, drive, p.topic(f"{ns}/odom", "nav_msgs/msg/Odometry"), graph.ODOM_QOS, t)
        self.scan = RosPublisher(p, laser, p.topic(f"{ns}/scan", "sensor_msgs/msg/LaserScan"), graph.SCAN_QOS, t)
        self.imu = RosPublisher(p, imu, p.topic(f"{ns}/imu", "sensor_msgs/msg/Imu"), graph.IMU_QOS, t)
        self.joint_states = RosPublisher(
            p, joints, p.topic(f"{ns}/joint_states", "sensor_msgs/msg/JointState"), graph.JOINT_STATES_QOS, t
        )
        for typename in CMD_VEL_TYPES:  # the intake subscribes to every robot's cmd_vel at once
            topic = p.topic(f"{ns}/cmd_vel", typename)
            token = drive.entity_token(p.next_id(), Kind.SUBSCRIPTION, topic, graph.CMD_VEL_QOS)
            t.append(p.session.liveliness().declare_token(token))
        state = declare_node(p, p.node(ns, "robot_state_publisher"), t)
        self.tf_static = LatchedPublisher(
            p, state, p.topic("/tf_static", "tf2_msgs/msg/TFMessage"), graph.TF_STATIC_QOS, t
        )
        transforms = self.static_transforms()
        self.tf_static.put(cdr.tf_message(len(transforms), [cdr.transform_elements((0, 0), transforms, first=True)]))
        self.wheel_angles = (0.0, 0.0)
        self.last_linear = 0.0

    def static_transforms(self) -> list[cdr.Transform]:
        """base_footprint -> base_link -> base_scan and imu_link, as robot_state_publisher sends them."""
        ns, m = self.namespace, self.model.name
        identity = (0.0, 0.0, 0.0, 1.0)
        return [
            (f"{ns}/base_footprint", f"{ns}/base_link", (0.0, 0.0, BASE_LINK_Z), identity),
            (f"{ns}/base_link", f"{ns}/base_scan", SCAN_OFFSET[m], identity),
            (f"{ns}/base_link", f"{ns}/imu_link", IMU_OFFSET[m], identity),
        ]

    def close(self) -> None:
        for pub in (self.odom, self.scan, self.imu, self.joint_states, self.tf_static):
            pub.undeclare()
        undeclare_all(self._tokens)
