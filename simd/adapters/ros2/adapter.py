"""The ROS 2 adapter: the fleet on rmw_zenoh's wire, for unmodified ROS 2 tools (docs/ros2.md).

It joins a ROS domain as one more zenoh participant (its own session, beside the fleet
protocol's) and shows every robot the way the Gazebo TurtleBot3 does: ``/<ns>/odom``,
``/<ns>/scan``, ``/<ns>/imu``, ``/<ns>/joint_states`` and ``/<ns>/cmd_vel`` (Twist and
TwistStamped), the whole fleet on ``/tf`` and each robot's fixed frames on ``/tf_static``
(namespaced frames, so one tree holds every robot), sim time
on ``/clock``, and gazebo_ros' ``/spawn_entity`` and ``/delete_entity``. Liveliness tokens make
all of it visible to ``ros2 node|topic|service list`` and RViz.

Like the fleet adapter it encodes and sends on a thread of its own (an :class:`Outbox`), in the
engine's order, and builds a message only while somebody subscribes to its topic.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping
from dataclasses import dataclass
from functools import partial
from typing import Any

import zenoh

from protocol.control import Clock
from simd.adapters.ros2 import cdr, gazebo_services, graph, simulation_services
from simd.adapters.ros2.command_intake import RosCommandIntake
from simd.adapters.ros2.interfaces import Distro
from simd.adapters.ros2.robot_ports import Participant, RobotPorts, RosPublisher
from simd.adapters.ros2.service_server import ServiceServer
from simd.adapters.zenoh_entities import undeclare_all
from simd.core.sim import ODOM_COVARIANCE_DIAGONAL
from simd.core.snapshot import TickSnapshot
from simd.engine import Engine
from simd.engine.outbox import Outbox
from simd.engine.ports import Deleted, Event, Spawned, WorldReset

log = logging.getLogger(__name__)

#: the participant's own node, which holds the fleet-wide topics and the services
NODE_NAME = "fleetsim"


@dataclass(frozen=True)
class RosOptions:
    domain_id: int = 0
    distro: Distro = "jazzy"
    #: a frame every robot's odom hangs from (a fixed frame for RViz), or none
    world_frame: str | None = None


class Ros2Adapter:
    """Serves one engine to one ROS domain on one zenoh session."""

    def __init__(self, session: zenoh.Session, engine: Engine, options: RosOptions) -> None:
        self.engine = engine
        self.options = options
        p = self.participant = Participant(session, options.domain_id, options.distro)
        spec = engine.sim.config.lidar
        self._odom = cdr.OdometryCdr(ODOM_COVARIANCE_DIAGONAL)
        self._scan = cdr.LaserScanCdr(
            spec.angle_min, spec.angle_max, spec.angle_increment, spec.range_min, spec.range_max, spec.samples
        )
        self._tf = cdr.TfCdr()
        self._imu = cdr.ImuCdr()
        self._joints = cdr.JointStateCdr()
        self._dt = engine.sim.config.dt
        self._tokens: list[Any] = []
        node = self.node = p.node("/", NODE_NAME)
        self._tokens.append(session.liveliness().declare_token(node.token()))
        self.clock_pub = RosPublisher(
            p, node, p.topic("/clock", "rosgraph_msgs/msg/Clock"), graph.CLOCK_QOS, self._tokens
        )
        self.tf_pub = RosPublisher(p, node, p.topic("/tf", "tf2_msgs/msg/TFMessage"), graph.TF_QOS, self._tokens)
        self.robots: dict[str, RobotPorts] = {}
        self.outbox = Outbox("ros2-out")
        self.commands = RosCommandIntake(p, self._known)
        self.services = ServiceServer(
            p, node, engine, self.outbox, [*gazebo_services.SERVICES, *simulation_services.services()]
        )
        engine.attach(self)

    def _known(self, namespace: str) -> bool:
        return namespace in self.robots

    # -- the engine's side (simulation thread) ----------------------------------------------------

    def on_tick(self, snapshot: TickSnapshot) -> None:
        self.outbox.put(partial(self._publish_tick, snapshot))

    def on_event(self, event: Event) -> None:
        if isinstance(event, Spawned):
            self.outbox.put(partial(self._add_robot, event.robot.namespace, event.robot.model))
        elif isinstance(event, Deleted):
            self.outbox.put(partial(self._remove_robot, event.robot.namespace))
        elif isinstance(event, WorldReset):
            self.outbox.put(self._reset)

    def on_clock(self, clock: Clock) -> None:
        if clock.paused:  # while running, every tick sends the clock (see _publish_tick)
            self.outbox.put(partial(self._publish_clock, clock.clock.to_seconds()))

    def take_commands(self) -> Mapping[str, tuple[float, float]]:
        return self.commands.take()

    def dropped_commands(self) -> int:
        return self.commands.dropped

    def close(self) -> None:
        self.services.close()
        self.commands.close()
        self.outbox.close()
        for ports in self.robots.values():
            ports.close()
        self.robots.clear()
        for pub in (self.clock_pub, self.tf_pub):
            pub.undeclare()
        undeclare_all(self._tokens)

    # -- the outbox thread ------------------------------------------------------------------------

    def _add_robot(self, namespace: str, model: Any) -> None:
        if namespace in self.robots:
            return
        self.robots[namespace] = RobotPorts(self.participant, namespace, model, self.options.world_frame)

    def _remove_robot(self, namespace: str) -> None:
        ports = self.robots.pop(namespace, None)
        if ports is not None:
            ports.close()
        for enc in (self._odom, self._scan, self._tf, self._imu):
            enc.forget(namespace)

    def _reset(self) -> None:
        for ports in self.robots.values():
            ports.wheel_angles = (0.0, 0.0)
            ports.last_linear = None

    def _publish_clock(self, t: float) -> None:
        if self.clock_pub.wanted:
            self.clock_pub.put(cdr.clock_cdr(t))

    def _publish_tick(self, snap: TickSnapshot) -> None:
        self._publish_clock(snap.time)
        p = self.participant
        tf_wanted = self.tf_pub.wanted.matching
        if not (tf_wanted or p.robot_interest):
            return  # nobody reads any robot's topic: nothing per robot is built
        robots = self.robots
        ports = [robots.get(ns) for ns in snap.namespaces]
        now = time.time_ns()  # the attachments' source timestamp, once a tick
        if tf_wanted:
            rows = [i for i, q in enumerate(ports) if q is not None]
            if rows:
                self.tf_pub.put(self._tf.encode(snap, rows), now)
        if p.odom_interest:
            if p.odom_interest.count >= len(robots):  # everybody's odometry is read: no need to ask
                odom_rows = [i for i, q in enumerate(ports) if q is not None]
            else:
                odom_rows = [i for i, q in enumerate(ports) if q is not None and q.odom.wanted.matching]
            for i, payload in zip(odom_rows, self._odom.encode(snap, odom_rows), strict=True):
                ports[i].odom.put(payload, now)  # type: ignore[union-attr]  # odom_rows holds only robots with ports
        if p.imu_interest or p.joints_interest:
            self._publish_wheels_and_imu(snap, ports, now)
        if snap.scan_namespaces and p.scan_interest:
            due = [(i, robots.get(ns)) for i, ns in enumerate(snap.scan_namespaces)]
            wanted = [(i, q) for i, q in due if q is not None and q.scan.wanted.matching]
            if wanted:
                scans = snap.scans
                for i, q in wanted:
                    q.scan.put(self._scan.encode(q.namespace, snap.time, scans[i]), now)

    def _publish_wheels_and_imu(self, snap: TickSnapshot, ports: list[RobotPorts | None], now: int) -> None:
        """joint_states integrate the wheel angles from the wheel speeds while somebody reads
        them (the angles count from the first message a subscriber gets); the IMU's forward
        acceleration is the change of speed since the last tick."""
        dt = self._dt
        t = snap.time
        for i, p in enumerate(ports):
            if p is None:
                continue
            joints, imu = p.joint_states.wanted.matching, p.imu.wanted.matching
            if not (joints or imu):
                continue
            v, w = float(snap.linear_x[i]), float(snap.angular_z[i])
            if joints:
                half = w * p.model.wheel_separation / 2.0
                r = p.model.wheel_radius
                left, right = (v - half) / r, (v + half) / r
                a, b = p.wheel_angles
                p.wheel_angles = (a + left * dt, b + right * dt)
                p.joint_states.put(self._joints.encode(t, p.wheel_angles, (left, right)), now)
            if imu:
                last = p.last_linear if p.last_linear is not None else v
                p.imu.put(self._imu.encode(p.namespace, t, float(snap.yaw[i]), w, (v - last) / dt, v * w), now)
                p.last_linear = v
