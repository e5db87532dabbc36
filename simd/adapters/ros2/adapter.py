"""The ROS 2 adapter: the fleet on rmw_zenoh's wire, for unmodified ROS 2 tools (docs/ros2.md).

It joins a ROS domain as one more zenoh participant (its own session, beside the fleet
protocol's) and shows every robot the way the Gazebo TurtleBot3 does: ``/<ns>/odom``,
``/<ns>/scan``, ``/<ns>/imu``, ``/<ns>/joint_states`` and ``/<ns>/cmd_vel`` (Twist or
TwistStamped as the distro's tools send it, both taken), the whole fleet on ``/tf`` and each
robot's fixed frames on ``/tf_static`` (namespaced frames, so one tree holds every robot; or
Nav2's multi-robot layout, a tree per robot on ``/<ns>/tf``: tf_layout.py), sim time on
``/clock``, and gazebo_ros' ``/spawn_entity`` and ``/delete_entity``; with the navigator on,
each robot also has Nav2's ``navigate_to_pose`` action, ``goal_pose`` and ``plan``
(navigation.py); with localization, ``/map``, ``map`` -> ``odom`` and ``/<ns>/initialpose``
(localization.py). Every node also has what rclcpp gives a node: parameter services (``ros2
param``), ``/rosout`` and ``/parameter_events`` (node_entities.py); the daemon's node logs each
robot spawned and deleted on ``/rosout``. Liveliness tokens make all of it visible to ``ros2
node|topic|service|action|param list`` and RViz.

In a fleet shared by several daemons (``simd --join``) each daemon shows its own robots, under a
node of its own (``/fleetsim_<id>``), and one of them speaks for the fleet: it alone publishes
``/clock`` and serves the services, which ask the whole fleet (shared_fleet.py).

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

from protocol.control import DEFAULT_DAEMON_ID, Clock
from protocol.keys import DEFAULT_PREFIX, Keys
from protocol.messages import Time
from simd.adapters.ros2 import cdr, gazebo_services, graph, node_entities, simulation_services
from simd.adapters.ros2.command_intake import RosCommandIntake
from simd.adapters.ros2.interfaces import CMD_VEL_DEFAULT, CmdVel, Distro
from simd.adapters.ros2.localization import RosLocalization
from simd.adapters.ros2.navigation import RosNavigation
from simd.adapters.ros2.node_entities import ParameterServer, RobotNodes, Rosout
from simd.adapters.ros2.robot_ports import Participant, RobotPorts, RosPublisher
from simd.adapters.ros2.service_server import ServiceServer
from simd.adapters.ros2.shared_fleet import FleetRequests, SharedFleet, Speaker, engine_ask
from simd.adapters.ros2.tf_layout import TfLayout
from simd.adapters.ros2.tf_topics import TfTopics
from simd.adapters.zenoh_entities import undeclare_all
from simd.core.models import ODOM_COVARIANCE_DIAGONAL
from simd.core.snapshot import RobotState, TickSnapshot
from simd.engine import Engine
from simd.engine.outbox import Outbox
from simd.engine.ports import Deleted, Event, Navigation, Spawned, WorldReset

log = logging.getLogger(__name__)

#: the participant's own node, which holds the fleet-wide topics and the services
NODE_NAME = "fleetsim"


def node_name(daemon_id: str | None = None) -> str:
    """The daemon's own node: ``fleetsim``, or ``fleetsim_<id>`` for each daemon of a shared fleet."""
    return f"{NODE_NAME}_{daemon_id}" if daemon_id else NODE_NAME


@dataclass(frozen=True)
class RosOptions:
    domain_id: int = 0
    distro: Distro = "jazzy"
    #: a frame every robot's odom hangs from (a fixed frame for RViz), or none
    world_frame: str | None = None
    #: the type(s) each robot's cmd_vel subscription advertises (both are taken): None, the distro's
    cmd_vel: CmdVel | None = None
    #: each robot's transforms on /<ns>/tf with unprefixed frames (Nav2's multi-robot layout)
    #: instead of the fleet's /tf with prefixed ones
    namespaced_tf: bool = False
    #: /map, map -> odom from the ground truth and /<ns>/initialpose (no AMCL or SLAM needed)
    localization: bool = False

    @property
    def layout(self) -> TfLayout:
        return TfLayout(self.namespaced_tf, self.localization, self.world_frame)

    @property
    def advertised_cmd_vel(self) -> CmdVel:
        return self.cmd_vel or CMD_VEL_DEFAULT[self.distro]


class Ros2Adapter:
    """Serves one engine to one ROS domain on one zenoh session (and, with ``shared``, speaks
    for the fleet when its turn comes)."""

    def __init__(
        self, session: zenoh.Session, engine: Engine, options: RosOptions, shared: SharedFleet | None = None
    ) -> None:
        self.engine = engine
        self.options = options
        p = self.participant = Participant(session, options.domain_id, options.distro)
        self.layout = layout = options.layout
        prefixed = not layout.namespaced
        spec = engine.setup.lidar
        self._odom = cdr.OdometryCdr(ODOM_COVARIANCE_DIAGONAL, prefixed)
        self._scan = cdr.LaserScanCdr(
            spec.angle_min, spec.angle_max, spec.angle_increment, spec.range_min, spec.range_max, spec.samples,
            prefixed,
        )  # fmt: skip
        self._imu = cdr.ImuCdr(prefixed)
        self._joints = cdr.JointStateCdr()
        self._dt = engine.setup.dt
        self._tokens: list[Any] = []
        node = self.node = p.node("/", node_name(shared.daemon_id if shared is not None else None))
        self._tokens.append(session.liveliness().declare_token(node.token()))
        self.tf = TfTopics(p, node, layout, self._tokens)
        self._time: float | None = None  # the latest sim time heard of
        self.robots: dict[str, RobotPorts] = {}
        self.outbox = Outbox("ros2-out")
        self.commands = RosCommandIntake(p, self._known)
        # what rclcpp gives every node: the daemon's own (its parameters, its /rosout), every robot's
        node_entities.declare_tokens(p, node, self._tokens, rosout=False)
        self.rosout = Rosout(p, node, self._tokens)
        self.own_parameters = ParameterServer(p, self.outbox, node.fqn, lambda path: True)
        self.robot_nodes = RobotNodes(p, self.outbox, self._known)
        #: Nav2's navigate_to_pose, goal_pose and plan of each robot (not with --no-nav); a robot's
        #: goals go to this daemon's own engine, which navigates it, shared fleet or not
        self.navigation = RosNavigation(p, engine.submit, self.outbox, layout) if engine.setup.navigation else None
        #: /map and /<ns>/initialpose (--ros-localization); each daemon of a shared fleet draws the
        #: same world and places its own robots
        self.localization = (
            RosLocalization(p, node, engine.setup.world, engine.submit, self.outbox, self._known, options.world_frame,
                            lambda: self._time or 0.0)
            if layout.localization
            else None
        )  # fmt: skip
        # the fleet's voice (/clock and the services): declared while this daemon speaks for the
        # fleet, which a lone daemon always does; touched on the outbox thread only
        self.clock_pub: RosPublisher | None = None
        self.services: ServiceServer | None = None
        self._voice_tokens: list[Any] = []
        self._sent_stamp: tuple[int, int] | None = None  # the (sec, nanosec) last put on /clock
        self.speaker: Speaker | None = None
        self._heard_speaker: str | None = None  # the speaker last logged
        self._closing = False
        if shared is None:
            # the records are only read by the services (never sent): the default key space will do
            self._ask = engine_ask(engine.submit, Keys(DEFAULT_PREFIX), DEFAULT_DAEMON_ID)
            self._follow_speaker()
        else:
            self._ask = FleetRequests(shared.session, shared.keys, self._dt).ask
            # it says when it has settled, and whenever the speaker changes
            self.speaker = Speaker(
                session, shared.keys, shared.daemon_id, options.domain_id, options.distro, self._speaker_changed
            )
        engine.attach(self)

    def _known(self, namespace: str) -> bool:
        return namespace in self.robots

    # -- the engine's side (simulation thread) ----------------------------------------------------

    def on_tick(self, snapshot: TickSnapshot) -> None:
        self.outbox.put(partial(self._publish_tick, snapshot))

    def on_event(self, event: Event) -> None:
        if isinstance(event, Spawned):
            self.outbox.put(partial(self._add_robot, event.robot))
        elif isinstance(event, Deleted):
            self.outbox.put(partial(self._remove_robot, event.robot))
        elif isinstance(event, WorldReset):
            self.outbox.put(self._reset)
        elif isinstance(event, Navigation) and self.navigation is not None:
            self.outbox.put(partial(self.navigation.publish, event.events))

    def on_clock(self, clock: Clock) -> None:
        if clock.paused:  # while running, every tick sends the clock (see _publish_tick)
            self.outbox.put(partial(self._publish_clock, clock.clock.to_seconds()))

    def take_commands(self) -> Mapping[str, tuple[float, float]]:
        return self.commands.take()

    def dropped_commands(self) -> int:
        return self.commands.dropped

    def close(self) -> None:
        self._closing = True  # a change of speaker heard from now on declares nothing
        if self.speaker is not None:
            self.speaker.close()
        self.outbox.put(self._fall_silent)  # no service call taken once the outbox has stopped
        self.commands.close()
        self.own_parameters.close()
        self.robot_nodes.close_inputs()
        if self.navigation is not None:
            self.navigation.close_inputs()
        self.outbox.close()
        if self.localization is not None:
            self.localization.close()
        if self.navigation is not None:
            self.navigation.close()
        self.robot_nodes.close()
        for ports in self.robots.values():
            ports.close()
        self.robots.clear()
        if self.tf.fleet_pub is not None:
            self.tf.fleet_pub.undeclare()
        self.rosout.undeclare()
        undeclare_all(self._tokens)

    # -- the fleet's voice --------------------------------------------------------------------------

    def _speaker_changed(self) -> None:
        self.outbox.put(self._follow_speaker)

    def _follow_speaker(self) -> None:
        """Declare /clock and the services when this daemon speaks for the fleet, undeclare
        them when it no longer does (another daemon took over)."""
        if self._closing:
            return
        speaks = True
        if self.speaker is not None:
            who = self.speaker.speaker()
            if who is None:
                return  # still listening for the daemons already there
            speaks = who == self.speaker.daemon_id
            if who != self._heard_speaker:
                self._heard_speaker = who
                if speaks:
                    log.info("this daemon speaks for the fleet on ROS 2: /clock and the services")
                else:
                    log.info("daemon %r speaks for the fleet on ROS 2: /clock and the services", who)
        if speaks and self.clock_pub is None:
            self._speak()
        elif not speaks and self.clock_pub is not None:
            self._fall_silent()

    def _speak(self) -> None:
        p, node = self.participant, self.node
        clock = p.topic("/clock", "rosgraph_msgs/msg/Clock")
        self.clock_pub = RosPublisher(p, node, clock, graph.CLOCK_QOS, self._voice_tokens)
        services = [*gazebo_services.SERVICES, *simulation_services.services()]
        self.services = ServiceServer(p, node, self._ask, self.outbox, services)
        if self.speaker is not None and self._time is not None:  # taking over: the time now
            self._publish_clock(self._time)

    def _fall_silent(self) -> None:
        if self.services is not None:
            self.services.close()
            self.services = None
        if self.clock_pub is not None:
            self.clock_pub.undeclare()
            self.clock_pub = None
        undeclare_all(self._voice_tokens)
        self._sent_stamp = None

    # -- the outbox thread ------------------------------------------------------------------------

    def _add_robot(self, robot: RobotState) -> None:
        namespace = robot.namespace
        if namespace in self.robots:
            return
        ports = RobotPorts(self.participant, namespace, robot.model, self.layout, self.options.advertised_cmd_vel)
        self.robots[namespace] = ports
        self.robot_nodes.add_robot(namespace, ports.node)
        if self.navigation is not None:
            self.navigation.add_robot(namespace, ports.node)
        self.rosout.log(
            f"spawned {robot.name} ({robot.model.name}) as {ports.node.fqn} at "
            f"x {robot.x:.3f} y {robot.y:.3f} yaw {robot.yaw:.3f}"
        )

    def _remove_robot(self, robot: RobotState) -> None:
        namespace = robot.namespace
        ports = self.robots.pop(namespace, None)
        if ports is not None:
            ports.close()
            self.rosout.log(f"deleted {robot.name} ({ports.node.fqn})")
        self.robot_nodes.remove_robot(namespace)
        if self.navigation is not None:
            self.navigation.remove_robot(namespace)
        for enc in (self._odom, self._scan, self.tf, self._imu):
            enc.forget(namespace)

    def _reset(self) -> None:
        for ports in self.robots.values():
            ports.wheel_angles = (0.0, 0.0)
            ports.last_linear = None

    def _publish_clock(self, t: float) -> None:
        """Each sim time once on /clock (a step's last tick is also the clock of the pause after it)."""
        self._time = t
        if self.navigation is not None:
            self.navigation.now = Time.from_seconds(t)
        pub = self.clock_pub
        stamp = cdr.stamp(t)  # the tick's time and the clock's (rounded to ns) are one stamp
        if pub is not None and pub.wanted and stamp != self._sent_stamp:
            pub.put(cdr.clock_cdr(t))
            self._sent_stamp = stamp

    def _publish_tick(self, snap: TickSnapshot) -> None:
        self._publish_clock(snap.time)
        p = self.participant
        if not (self.tf.wanted or p.robot_interest):
            return  # nobody reads any robot's topic: nothing per robot is built
        robots = self.robots
        ports = [robots.get(ns) for ns in snap.namespaces]
        now = time.time_ns()  # the attachments' source timestamp, once a tick
        self.tf.publish(snap, ports, now)
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
