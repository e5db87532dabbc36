"""Nav2's interface to the daemon's navigator, per robot: ``navigate_to_pose``, ``goal_pose``, ``plan``.

For every robot ``<ns>`` (with the navigator on, that is without ``simd --no-nav``):

- ``/<ns>/navigate_to_pose``, a nav2_msgs/action/NavigateToPose action server as rmw_zenoh carries
  one (action_server.py): a goal is a NavigateRequest whose ``goal_id`` is the goal's UUID in
  hex; its feedback is the navigator's (5 Hz of sim time) and it ends with the navigator's
  result (nav_messages.py says how each maps);
- ``/<ns>/goal_pose`` (geometry_msgs/msg/PoseStamped, what RViz's "2D Goal Pose" tool sends):
  a goal for the robot, sent to its own action as Nav2's bt_navigator does, so it shows in the
  status array and can be cancelled like any goal;
- ``/<ns>/plan`` (nav_msgs/msg/Path): each path the navigator plans, and an empty one when a
  goal ends (RViz then stops drawing the old one).

The robot's node (``/<ns>/turtlebot3``) holds these entities, as it holds the robot's topics.

One goal runs per robot, as in Nav2: a new goal (from ROS or from the fleet protocol) ends the
running one ABORTED. A goal the navigator refuses (in a wall, off the map) is accepted and
aborted at once with the navigator's sentence in ``error_msg``, as Nav2's planner would fail
it, and the running goal goes on. A goal in a frame that is not the world's, or under a UUID
already in use, is refused (``accepted`` false).

Wire and threads: three wildcard queryables (``<domain>/*/navigate_to_pose/_action/<service>/...``)
and one wildcard subscriber (``<domain>/*/goal_pose/...``) serve every robot of the daemon, so a
spawn declares only the robot's tokens; each answers only a call for one of this daemon's own
robots (in a shared fleet, another daemon's robot is that daemon's to answer). Requests are
decoded on zenoh's threads and handled on the adapter's thread (the :class:`Outbox`), which owns
every goal book, hears the navigator's events and replies: one thread, no lock, the engine's order.
"""

from __future__ import annotations

import logging
import uuid as uuidlib
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import zenoh

from protocol.errors import FleetError
from protocol.messages import Time
from protocol.navigation import CancelRequest, NavigateReply, NavigateRequest, NavigationRequest, NavigationResult
from simd.adapters.ros2 import graph
from simd.adapters.ros2.action_server import (
    CancelCode,
    GoalBook,
    GoalStatus,
    Stamp,
    action_parts,
    goal_info,
    result_message,
    stamp_of,
    status_array,
    uuid_of,
)
from simd.adapters.ros2.interfaces import HUMBLE_HASH, NAVIGATE_TO_POSE, dds_type_name, rihs01, typestore
from simd.adapters.ros2.nav_messages import (
    GOAL_REFUSALS,
    UNKNOWN,
    FrameRefused,
    Messages,
    navigate_request,
    outcome,
    refusal_code,
    world_frames,
)
from simd.adapters.ros2.robot_ports import KeyPublisher, LatchedPublisher, Participant
from simd.adapters.ros2.service_server import MAX_REQUEST_BYTES, Call, read_request, reply_sender
from simd.adapters.ros2.tf_layout import TfLayout
from simd.adapters.zenoh_entities import Interest, undeclare_all
from simd.engine.outbox import Outbox
from simd.engine.ports import Reply, Result
from simd.nav.report import NavEvents

log = logging.getLogger(__name__)

ACTION = "navigate_to_pose"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
PATH = "nav_msgs/msg/Path"
#: what RViz and bt_navigator use (rmw's defaults): reliable, volatile, depth 10; planner_server's
#: plan publisher has depth 1
GOAL_POSE_QOS = graph.Qos(depth=10)
PLAN_QOS = graph.Qos(depth=1)
SERVICES = ("send_goal", "get_result", "cancel_goal")

Submit = Callable[[NavigationRequest, Reply], None]
#: the answer to a request that cannot be decoded
_REFUSE: dict[str, dict[str, Any]] = {
    "send_goal": {"accepted": False},
    "get_result": {"status": int(GoalStatus.UNKNOWN)},
    "cancel_goal": {"return_code": int(CancelCode.ERROR_REJECTED)},
}


@dataclass
class RobotNav:
    """One robot's action server and topics (the adapter's thread only)."""

    namespace: str
    frames: frozenset[str]  # the frame ids its goals may name
    frame: str  # the frame its poses and paths are given in
    feedback: KeyPublisher
    status: LatchedPublisher
    plan: KeyPublisher
    tokens: list[Any]
    book: GoalBook = field(default_factory=GoalBook)
    pending: set[bytes] = field(default_factory=set)  # UUIDs sent to the engine, not answered yet

    @property
    def action(self) -> str:
        return f"/{self.namespace}/{ACTION}"


class RosNavigation:
    """navigate_to_pose, goal_pose and plan for every robot of one daemon (module docstring)."""

    def __init__(self, p: Participant, submit: Submit, outbox: Outbox, layout: TfLayout | None = None) -> None:
        self.p = p
        self._submit = submit
        self.outbox = outbox
        self.layout = layout or TfLayout()
        self.store = typestore(p.distro)
        self.messages = Messages(self.store)
        self.parts = action_parts(NAVIGATE_TO_POSE)
        self.robots: dict[str, RobotNav] = {}  # written on the adapter's thread; zenoh's only ask `in`
        self.now = Time()  # the latest sim time heard of (a goal refused at once is stamped with it)
        self.malformed = 0  # requests and goal poses that could not be decoded (counted, logged)
        s = p.session
        # whether anybody reads any robot's feedback or plan: one wildcard probe each
        feedback_probe = s.declare_publisher(self._part_key("feedback", "*"))
        plan_probe = s.declare_publisher(p.topic("/*/plan", PATH).key)
        self.feedback_wanted = Interest(feedback_probe)
        self.plan_wanted = Interest(plan_probe)
        self._inputs: list[Any] = [self.feedback_wanted, self.plan_wanted, feedback_probe, plan_probe]
        for suffix in SERVICES:
            self._inputs.append(s.declare_queryable(self._part_key(suffix, "*"), self._on_query(suffix), complete=True))
        goal_pose = f"{p.domain}/*/goal_pose/{dds_type_name(POSE_STAMPED)}/*"
        self._goal_pose_hashes = {rihs01(POSE_STAMPED), HUMBLE_HASH}
        self._inputs.append(s.declare_subscriber(goal_pose, self._on_goal_pose))

    def _part_key(self, suffix: str, namespace: str) -> str:
        """The key of one of a robot's action entities (``*``: every robot's)."""
        part = self.parts[suffix]
        return self.p.topic(part.name(f"/{namespace}/{ACTION}"), part.typename).key

    # -- robots (the adapter's thread) -------------------------------------------------------------

    def add_robot(self, namespace: str, node: graph.Node) -> None:
        """The robot's action server: its topics, then it is served, then its services' tokens
        (as rmw_zenoh declares a service's token after its queryable: a client that sees the
        server in the graph, as rclpy's ``wait_for_server`` does, gets an answer)."""
        p = self.p
        tokens: list[Any] = []
        action = f"/{namespace}/{ACTION}"
        fb, st = self.parts["feedback"], self.parts["status"]
        feedback = KeyPublisher(p, node, p.topic(fb.name(action), fb.typename), fb.qos, tokens)
        status = LatchedPublisher(p, node, p.topic(st.name(action), st.typename), st.qos, tokens, lazy=True)
        plan = KeyPublisher(p, node, p.topic(f"/{namespace}/plan", PATH), PLAN_QOS, tokens)
        goal_pose = p.topic(f"/{namespace}/goal_pose", POSE_STAMPED)
        tokens.append(p.session.liveliness().declare_token(
            node.entity_token(p.next_id(), graph.Kind.SUBSCRIPTION, goal_pose, GOAL_POSE_QOS)))  # fmt: skip
        frames = world_frames(namespace, self.layout.world_frame)
        self.robots[namespace] = RobotNav(namespace, frames, self.layout.pose_frame(namespace),
                                          feedback, status, plan, tokens)  # fmt: skip
        for suffix in SERVICES:
            part = self.parts[suffix]
            topic = p.topic(part.name(action), part.typename)
            token = node.entity_token(p.next_id(), part.kind, topic, part.qos)
            tokens.append(p.session.liveliness().declare_token(token))

    def remove_robot(self, namespace: str) -> None:
        robot = self.robots.pop(namespace, None)
        if robot is None:
            return
        for goal in robot.book.clear():  # the navigator already ended them (robot_gone): never left waiting
            for answer in goal.waiting:
                answer(GoalStatus.ABORTED, {"error_code": UNKNOWN, "error_msg": f"robot {namespace!r} was deleted"})
        robot.status.undeclare()
        undeclare_all(robot.tokens)

    # -- requests in (zenoh's threads) -------------------------------------------------------------

    def _on_query(self, suffix: str) -> Callable[[zenoh.Query], None]:
        part = self.parts[suffix]
        request_type, response_type = f"{part.typename}_Request", f"{part.typename}_Response"
        handle = {"send_goal": self._send_goal, "get_result": self._get_result, "cancel_goal": self._cancel}[suffix]
        refuse = _REFUSE[suffix]

        def on_query(query: zenoh.Query) -> None:
            key = str(query.key_expr)
            namespace = key.split("/")[1]
            if namespace not in self.robots or "*" in key or "$" in key:
                query.drop()  # somebody looking around, or another daemon's robot
                return
            name = part.name(f"/{namespace}/{ACTION}")
            send = reply_sender(query, key, graph.gid(key), self.p.legacy, name)
            call = Call(name, None, response_type, self.store, send, self.outbox)
            wrong = read_request(call, query, self.store, request_type)
            if wrong is not None:
                self.malformed += 1
                log.info("%s refused: %s", call.name, wrong)
                call.respond(**refuse)
                return
            self.outbox.put(partial(handle, namespace, call))

        return on_query

    def _on_goal_pose(self, sample: zenoh.Sample) -> None:
        chunks = str(sample.key_expr).split("/")
        namespace = chunks[1]
        if namespace not in self.robots or chunks[4] not in self._goal_pose_hashes:
            return
        self.p.legacy.check(sample.attachment, f"/{namespace}/goal_pose")
        payload = sample.payload.to_bytes()
        try:
            if len(payload) > MAX_REQUEST_BYTES:
                raise ValueError(f"{len(payload)} bytes")
            pose = self.store.deserialize_cdr(payload, POSE_STAMPED)
        except Exception as e:
            self.malformed += 1
            log.info("/%s/goal_pose ignored: malformed PoseStamped: %s", namespace, e)
            return
        self.outbox.put(partial(self._goal_pose, namespace, pose))

    # -- goals (the adapter's thread) --------------------------------------------------------------

    def _send_goal(self, namespace: str, call: Call) -> None:
        robot = self.robots.get(namespace)
        if robot is None:
            return call.respond_here(accepted=False)
        try:
            uuid = uuid_of(call.request.goal_id)
            if uuid in robot.book or uuid in robot.pending:
                raise ValueError(f"goal {uuid.hex()} is already known")
            request = navigate_request(call.request.goal.pose, namespace, robot.frames, uuid.hex())
        except (ValueError, FrameRefused) as e:
            log.info("%s refused a goal: %s", robot.action, e)
            return call.respond_here(accepted=False)
        self._start(robot, uuid, request, call)

    def _goal_pose(self, namespace: str, pose: Any) -> None:
        robot = self.robots.get(namespace)
        if robot is None:
            return
        uuid = uuidlib.uuid4().bytes
        try:
            request = navigate_request(pose, namespace, robot.frames, uuid.hex())
        except FrameRefused as e:
            log.info("/%s/goal_pose ignored: %s", namespace, e)
            return
        self._start(robot, uuid, request, None)

    def _start(self, robot: RobotNav, uuid: bytes, request: NavigateRequest, call: Call | None) -> None:
        namespace = robot.namespace
        try:
            self._submit(request, self._later(partial(self._started, namespace, uuid, call)))
        except FleetError as e:  # busy
            log.info("%s refused a goal: %s", robot.action, e.message)
            if call is not None:
                call.respond_here(accepted=False)
            return
        robot.pending.add(uuid)

    def _later(self, then: Callable[[Result | FleetError], None]) -> Reply:
        """The engine's reply (on the simulation thread) handed to ``then`` on the adapter's thread."""
        return lambda result: self.outbox.put(partial(then, result))

    def _started(self, namespace: str, uuid: bytes, call: Call | None, result: Result | FleetError) -> None:
        robot = self.robots.get(namespace)
        if robot is not None:
            robot.pending.discard(uuid)
        accepted = robot is not None and (
            isinstance(result, NavigateReply) or (isinstance(result, FleetError) and result.code in GOAL_REFUSALS)
        )
        if robot is None or not accepted or uuid in robot.book:
            why = result.message if isinstance(result, FleetError) else "the robot is gone"
            log.info("/%s/%s refused a goal: %s", namespace, ACTION, why)
            if call is not None:
                call.respond_here(accepted=False)
            return
        stamp = result.stamp if isinstance(result, NavigateReply) else self.now
        robot.book.accept(uuid, (stamp.sec, stamp.nanosec))
        if call is not None:
            call.respond_here(accepted=True, stamp=self.messages.time(stamp))
        if isinstance(result, FleetError):  # accepted, and failed as Nav2's planner would fail it
            log.info("%s aborted goal %s: %s", robot.action, uuid.hex(), result.message)
            robot.book.end(uuid, GoalStatus.ABORTED, {"error_code": refusal_code(result), "error_msg": result.message})
        self._publish_status(robot)

    def _get_result(self, namespace: str, call: Call) -> None:
        robot = self.robots.get(namespace)
        result_type = f"{NAVIGATE_TO_POSE}_Result"

        def answer(status: GoalStatus, fields: dict[str, Any]) -> None:
            call.respond_here(status=int(status), result=result_message(self.store, result_type, fields))

        try:
            uuid = uuid_of(call.request.goal_id)
        except ValueError:
            return answer(GoalStatus.UNKNOWN, {})
        if robot is None:
            return answer(GoalStatus.UNKNOWN, {})
        robot.book.result_of(uuid, answer)

    def _cancel(self, namespace: str, call: Call) -> None:
        robot = self.robots.get(namespace)
        info = call.request.goal_info
        try:
            uuid, stamp = uuid_of(info.goal_id), stamp_of(info.stamp)
        except ValueError:
            return call.respond_here(return_code=int(CancelCode.ERROR_REJECTED))
        if robot is None:
            return call.respond_here(return_code=int(CancelCode.ERROR_UNKNOWN_GOAL_ID))
        code, goals = robot.book.to_cancel(uuid, stamp)
        if not goals:
            return call.respond_here(return_code=int(code))
        cancelling: list[Any] = []
        left = [len(goals)]

        def cancelled(goal_uuid: bytes, goal_stamp: Stamp, result: Result | FleetError) -> None:
            if isinstance(result, NavigationResult):
                cancelling.append(goal_info(self.store, goal_uuid, goal_stamp))
            left[0] -= 1
            if left[0] == 0:  # rclcpp: a request whose every goal refused to cancel is refused
                rc = code if cancelling else CancelCode.ERROR_REJECTED
                call.respond_here(return_code=int(rc), goals_canceling=cancelling)

        for goal in goals:
            done = partial(cancelled, goal.uuid, goal.stamp)
            try:
                self._submit(CancelRequest(goal_id=goal.uuid.hex(), robot=namespace), self._later(done))
            except FleetError as e:  # busy
                done(e)

    # -- what the navigator says (the adapter's thread) -------------------------------------------

    def publish(self, events: NavEvents) -> None:
        ended: dict[str, RobotNav] = {}
        for result in events.results:
            robot = self.robots.get(result.robot)
            uuid = _uuid_from_hex(result.goal_id)
            if robot is not None and uuid is not None:
                status, fields = outcome(result)
                if robot.book.end(uuid, status, fields):
                    ended[robot.namespace] = robot
            self.now = result.stamp
        for robot in ended.values():
            self._publish_status(robot)
        if events.plans and self.plan_wanted:
            for path in events.plans:
                robot = self.robots.get(path.robot)
                if robot is not None:
                    robot.plan.put(self.messages.path(path, robot.frame))
        if events.feedback and self.feedback_wanted:
            for fb in events.feedback:
                robot = self.robots.get(fb.robot)
                uuid = _uuid_from_hex(fb.goal_id)
                goal = robot.book.get(uuid) if robot is not None and uuid is not None else None
                if robot is not None and uuid is not None and goal is not None and goal.active:
                    robot.feedback.put(self.messages.feedback(NAVIGATE_TO_POSE, uuid, fb, robot.frame))

    def _publish_status(self, robot: RobotNav) -> None:
        robot.status.put(status_array(self.store, robot.book.goals()))

    # -- closing -----------------------------------------------------------------------------------

    def close_inputs(self) -> None:
        """No more requests (before the adapter's thread stops)."""
        undeclare_all(self._inputs)

    def close(self) -> None:
        """Every robot's entities (after the adapter's thread stopped)."""
        for namespace in list(self.robots):
            self.remove_robot(namespace)


def _uuid_from_hex(goal_id: str) -> bytes | None:
    """A ROS goal's UUID from the navigator's goal id (None for goals that did not come from ROS)."""
    if len(goal_id) != 32:
        return None
    try:
        return bytes.fromhex(goal_id)
    except ValueError:
        return None
