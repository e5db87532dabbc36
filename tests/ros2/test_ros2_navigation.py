"""Nav2's interface to simd's navigator, seen from a ROS tool: the stand-in (standin.py) as an
rclcpp action client of ``/<ns>/navigate_to_pose``, a publisher of ``/<ns>/goal_pose`` (RViz's
"2D Goal Pose") and a subscriber of ``/<ns>/plan``, on a lockstep daemon: the simulation moves
only when the test steps it, so a goal takes the same ticks on any machine.

Nothing here imports the adapter: names, types and hashes are the stand-in's own.
"""

from __future__ import annotations

import math
import queue
from collections.abc import Callable
from typing import Any

import pytest

from clients import FleetClient, wait_until
from tests.ros2.conftest import RosDomain, pose_stamped
from tests.ros2.standin import (
    ActionClient,
    action_server_available,
    actions,
    dds_name,
    msg,
    type_hash,
    wait_for,
)

NAV = "nav2_msgs/action/NavigateToPose"
#: GoalStatus and CancelGoal's return codes (action_msgs)
SUCCEEDED, CANCELED, ABORTED, UNKNOWN = 4, 5, 6, 0
ERROR_NONE, ERROR_UNKNOWN_GOAL_ID, ERROR_GOAL_TERMINATED = 0, 2, 3
#: TB3_1 of the four-robot launch, and a goal a metre up the free lane left of the pillars
START = (-2.0, -0.5)
GOAL = (-2.0, 0.5)
#: ticks of 1/30 s per step: a control period of the navigator is 3
STEP = 15


def goal(x: float, y: float, yaw: float = 0.0, frame: str = "map", behavior_tree: str = "") -> Any:
    return msg(f"{NAV}_Goal", pose=pose_stamped(x, y, yaw, frame), behavior_tree=behavior_tree)


def robot_ready(ros: RosDomain, ns: str = "TB3_1", at: tuple[float, float] = START) -> tuple[FleetClient, ActionClient]:
    """A lockstep daemon's robot, its action server seen in the graph."""
    c = ros.daemon.client()
    c.spawn(f"burger_{ns[-1]}", *at, namespace=ns)
    action = f"/{ns}/navigate_to_pose"
    assert wait_until(lambda: action_server_available(ros.tool.graph(), action, NAV), 10.0)
    return c, ActionClient(ros.tool, action, NAV)


def step_until(c: FleetClient, done: Callable[[], bool], ticks: int = 1800) -> int:
    """Step the simulation STEP ticks at a time until ``done`` (at most ``ticks``); the ticks run."""
    ran = 0
    while not done():
        assert ran < ticks, f"not done after {ran} ticks"
        c.step(STEP)
        ran += STEP
    return ran


def result_of(q: queue.Queue[Any]) -> Callable[[], bool]:
    return lambda: not q.empty()


@pytest.fixture
def ros(ros_factory: Callable[..., RosDomain]) -> RosDomain:
    return ros_factory("--lockstep")


def test_goal_reached_end_to_end_with_feedback_status_and_plan(ros: RosDomain) -> None:
    c, nav = robot_ready(ros)
    feedback, status = nav.feedback(), nav.status()
    plan = ros.tool.subscribe("/TB3_1/plan", "nav_msgs/msg/Path")
    goal_id, accepted = nav.send_goal(goal(*GOAL, yaw=math.pi / 2))
    assert accepted.accepted
    result = nav.get_result(goal_id)
    ran = step_until(c, result_of(result))
    answer = result.get_nowait()
    assert answer.status == SUCCEEDED, answer
    assert (answer.result.error_code, answer.result.error_msg) == (0, "")
    (robot,) = c.robots()
    assert math.hypot(robot.pose.x - GOAL[0], robot.pose.y - GOAL[1]) <= 0.25
    assert abs(math.remainder(robot.pose.yaw - math.pi / 2, 2 * math.pi)) <= 0.25
    assert 4.0 < ran / 30 < 20.0  # a metre at the burger's 0.22 m/s, a quarter turn
    fb = wait_for(feedback)[0]
    assert bytes(fb.goal_id.uuid) == goal_id
    f = fb.feedback
    assert f.current_pose.header.frame_id == "TB3_1/odom"
    assert f.distance_remaining > 0 and f.navigation_time.sec + f.navigation_time.nanosec * 1e-9 >= 0
    path = wait_for(plan, lambda m: len(m[0].poses) > 0)[0]
    assert path.header.frame_id == "TB3_1/odom"
    first, last = path.poses[0].pose.position, path.poses[-1].pose.position
    assert math.hypot(first.x - START[0], first.y - START[1]) < 0.3
    assert math.hypot(last.x - GOAL[0], last.y - GOAL[1]) < 0.3
    final = wait_for(status, lambda m: any(s.status == SUCCEEDED for s in m.status_list))
    (row,) = final.status_list
    assert bytes(row.goal_info.goal_id.uuid) == goal_id
    assert ros.tool.rejected == []
    assert "Traceback" not in ros.daemon.log()


def test_cancel_by_id_then_the_codes_of_cancels_that_find_nothing(ros: RosDomain) -> None:
    c, nav = robot_ready(ros)
    goal_id, accepted = nav.send_goal(goal(*GOAL))
    assert accepted.accepted
    result = nav.get_result(goal_id)
    c.step(2 * STEP)
    answer = nav.cancel_goal(goal_id)
    assert answer.return_code == ERROR_NONE
    (info,) = answer.goals_canceling
    assert bytes(info.goal_id.uuid) == goal_id
    assert (info.stamp.sec, info.stamp.nanosec) == (accepted.stamp.sec, accepted.stamp.nanosec)
    done = wait_for(result)
    assert done.status == CANCELED
    c.step(STEP)
    (robot,) = c.robots()
    assert robot.linear_velocity == pytest.approx(0.0, abs=1e-3)  # it stopped
    assert nav.cancel_goal(goal_id).return_code == ERROR_GOAL_TERMINATED
    assert nav.cancel_goal(bytes(range(16))).return_code == ERROR_UNKNOWN_GOAL_ID
    everything = nav.cancel_goal()  # zero id, zero stamp: every goal, and none runs
    assert (everything.return_code, list(everything.goals_canceling)) == (ERROR_NONE, [])
    again = nav.get_result(goal_id)  # an ended goal's result stays to be asked for
    assert wait_for(again).status == CANCELED
    unknown = nav.get_result(bytes(range(16)))
    assert wait_for(unknown).status == UNKNOWN


def test_cancel_all_by_stamp(ros: RosDomain) -> None:
    c, nav = robot_ready(ros)
    c.step(STEP)
    goal_id, accepted = nav.send_goal(goal(*GOAL))
    assert (accepted.stamp.sec, accepted.stamp.nanosec) == (0, 500_000_000)  # sim time: 15 ticks of 1/30 s
    c.step(STEP)
    before = nav.cancel_goal(sec=0, nanosec=499_999_999)  # goals accepted before: none
    assert (before.return_code, list(before.goals_canceling)) == (ERROR_NONE, [])
    answer = nav.cancel_goal(sec=0, nanosec=500_000_000)  # at or before: this one
    assert answer.return_code == ERROR_NONE
    assert [bytes(i.goal_id.uuid) for i in answer.goals_canceling] == [goal_id]
    assert wait_for(nav.get_result(goal_id)).status == CANCELED


def test_a_new_goal_preempts_the_running_one_which_ends_aborted(ros: RosDomain) -> None:
    c, nav = robot_ready(ros)
    status = nav.status()
    first, ok = nav.send_goal(goal(*GOAL))
    assert ok.accepted
    first_result = nav.get_result(first)
    c.step(STEP)
    second, ok = nav.send_goal(goal(-2.0, -0.2))
    assert ok.accepted
    old = wait_for(first_result)
    assert old.status == ABORTED  # as Nav2's SimpleActionServer aborts the goal it preempts
    assert old.result.error_code == 0 and "replaced by a newer goal" in old.result.error_msg
    rows = wait_for(status, lambda m: len(m.status_list) == 2).status_list
    assert {bytes(r.goal_info.goal_id.uuid): r.status for r in rows} == {first: ABORTED, second: 2}  # EXECUTING
    # a goal from the fleet protocol replaces a ROS goal as well
    second_result = nav.get_result(second)
    fleet_goal = c.navigate("TB3_1", -2.0, 0.0)
    replaced = wait_for(second_result)
    assert replaced.status == ABORTED and "replaced" in replaced.result.error_msg
    fleet_goal.close()


def test_goals_in_a_wall_off_the_map_or_in_another_frame(ros: RosDomain) -> None:
    c, nav = robot_ready(ros)
    running, ok = nav.send_goal(goal(*GOAL))
    assert ok.accepted
    wall_id, ok = nav.send_goal(goal(0.0, 0.0))  # the centre pillar of turtlebot3_world
    assert ok.accepted  # as Nav2 accepts it and its planner fails it: the reason reaches the client
    wall = wait_for(nav.get_result(wall_id))
    assert wall.status == ABORTED
    assert wall.result.error_code == 206  # ComputePathToPose's GOAL_OCCUPIED
    assert "would overlap a wall or obstacle" in wall.result.error_msg
    off_id, ok = nav.send_goal(goal(40.0, 0.0))
    off = wait_for(nav.get_result(off_id))
    assert (off.status, off.result.error_code) == (ABORTED, 204)  # GOAL_OUTSIDE_MAP
    assert "off the map" in off.result.error_msg
    # a frame fleetsim cannot transform from, a UUID in use: refused outright
    assert not nav.send_goal(goal(*GOAL, frame="TB3_1/base_link"))[1].accepted
    assert not nav.send_goal(goal(*GOAL, frame="TB3_2/odom"))[1].accepted
    assert not nav.send_goal(goal(*GOAL), goal_id=running)[1].accepted
    for frame in ("", "/map", "odom", "world", "TB3_1/map", "TB3_1/odom"):  # the world, by any of its names
        g, ok = nav.send_goal(goal(*GOAL, frame=frame))
        assert ok.accepted, frame
        running = g
    # the refused goals left the running one alone: it goes on
    status = wait_for(nav.status(), lambda m: any(bytes(r.goal_info.goal_id.uuid) == running for r in m.status_list))
    rows = {bytes(r.goal_info.goal_id.uuid): r.status for r in status.status_list}
    assert rows[running] == 2  # EXECUTING
    c.step(STEP)
    (robot,) = c.robots()
    assert robot.linear_velocity > 0 or abs(robot.angular_velocity) > 0
    assert ros.daemon.alive()
    assert "Traceback" not in ros.daemon.log()


def test_goal_pose_drives_the_robot_as_rvizs_2d_goal_pose(ros: RosDomain) -> None:
    c, nav = robot_ready(ros)
    status = nav.status()
    plan = ros.tool.subscribe("/TB3_1/plan", "nav_msgs/msg/Path")
    publish = ros.tool.publisher("/TB3_1/goal_pose", "geometry_msgs/msg/PoseStamped")
    publish(pose_stamped(*GOAL, frame="TB3_1/base_link"))  # not the world's frame: ignored
    publish(pose_stamped(*GOAL, frame="map"))
    # as bt_navigator: the pose becomes a goal of the robot's own action, listed with its status
    running = wait_for(status, lambda m: len(m.status_list) == 1).status_list[0]
    assert running.status == 2  # EXECUTING
    goal_id = bytes(running.goal_info.goal_id.uuid)
    result = nav.get_result(goal_id)
    step_until(c, result_of(result))
    assert result.get_nowait().status == SUCCEEDED
    (robot,) = c.robots()
    assert math.hypot(robot.pose.x - GOAL[0], robot.pose.y - GOAL[1]) <= 0.25
    assert len(wait_for(plan)[0].poses) > 1
    wait_for(plan, lambda m: len(m[0].poses) == 0)  # the goal ended: RViz stops drawing its path
    assert ros.tool.rejected == []


def test_action_list_and_the_entities_hashes_and_qos(ros: RosDomain) -> None:
    robot_ready(ros)
    expected = {
        ("SS", "/TB3_1/navigate_to_pose/_action/send_goal"): f"{NAV}_SendGoal",
        ("SS", "/TB3_1/navigate_to_pose/_action/get_result"): f"{NAV}_GetResult",
        ("SS", "/TB3_1/navigate_to_pose/_action/cancel_goal"): "action_msgs/srv/CancelGoal",
        ("MP", "/TB3_1/navigate_to_pose/_action/feedback"): f"{NAV}_FeedbackMessage",
        ("MP", "/TB3_1/navigate_to_pose/_action/status"): "action_msgs/msg/GoalStatusArray",
        ("MP", "/TB3_1/plan"): "nav_msgs/msg/Path",
        ("MS", "/TB3_1/goal_pose"): "geometry_msgs/msg/PoseStamped",
    }
    # a graph query may miss a token a moment after another showed it: ask until all are there
    g = ros.tool.wait_graph(lambda g: set(expected) <= {(e.kind, e.topic) for e in g})
    assert actions(g) == {"/TB3_1/navigate_to_pose": {NAV}}  # what `ros2 action list -t` shows
    mine = {(e.kind, e.topic): e for e in g if e.namespace == "/TB3_1"}
    for (kind, topic), typename in expected.items():
        e = mine[(kind, topic)]
        assert (e.type, e.hash, e.node_fqn) == (dds_name(typename), type_hash(typename), "/TB3_1/turtlebot3")
    from tests.ros2.standin import parse_qos

    status_qos = parse_qos(mine[("MP", "/TB3_1/navigate_to_pose/_action/status")].qos)
    assert (status_qos.reliability, status_qos.durability, status_qos.depth) == (1, 1, 1)  # rcl_action's status QoS
    # a wildcard call is somebody looking: no answer, no goal
    key = f"0/*/navigate_to_pose/_action/send_goal/{dds_name(NAV + '_SendGoal')}/{type_hash(NAV + '_SendGoal')}"
    assert [r for r in ros.tool.session.get(key, timeout=1.0) if r.ok is not None] == []


def test_a_deleted_robots_action_vanishes_and_its_waiting_result_is_answered(ros: RosDomain) -> None:
    c, nav = robot_ready(ros)
    goal_id, ok = nav.send_goal(goal(*GOAL))
    assert ok.accepted
    result = nav.get_result(goal_id)
    # a second call on the same service, answered at once, follows the first: the first waits now
    assert wait_for(nav.get_result(bytes(16))).status == UNKNOWN
    c.delete("burger_1")
    gone = wait_for(result)
    assert gone.status == ABORTED and "deleted" in gone.result.error_msg
    g = ros.tool.wait_graph(lambda g: not actions(g))
    assert actions(g) == {}


def test_no_nav_no_action(ros_factory: Callable[..., RosDomain]) -> None:
    ros = ros_factory("--lockstep", "--no-nav")
    ros.daemon.client().spawn("burger_1", *START, namespace="TB3_1")
    g = ros.tool.wait_graph(lambda g: any(e.topic == "/TB3_1/odom" for e in g))
    assert actions(g) == {} and not any(e.topic in ("/TB3_1/plan", "/TB3_1/goal_pose") for e in g)


def test_humble_keys(ros_factory: Callable[..., RosDomain]) -> None:
    ros = ros_factory("--lockstep", distro="humble")
    ros.daemon.client().spawn("burger_1", *START, namespace="TB3_1")
    g = ros.tool.wait_graph(lambda g: bool(actions(g)))
    assert actions(g) == {"/TB3_1/navigate_to_pose": {NAV}}
    assert all(e.hash == "TypeHashNotSupported" for e in g if "navigate_to_pose" in e.topic)
    nav = ActionClient(ros.tool, "/TB3_1/navigate_to_pose", NAV)  # the goal's fields are Humble's too
    goal_id, ok = nav.send_goal(goal(*GOAL))
    assert ok.accepted
    assert nav.cancel_goal(goal_id).return_code == ERROR_NONE


def test_two_robots_two_actions(ros: RosDomain) -> None:
    c, first = robot_ready(ros, "TB3_1", START)
    _, second = robot_ready(ros, "TB3_2", (0.5, -2.0))
    a, ok_a = first.send_goal(goal(*GOAL))
    b, ok_b = second.send_goal(goal(1.0, -2.0))
    assert ok_a.accepted and ok_b.accepted
    assert second.cancel_goal(a).return_code == ERROR_UNKNOWN_GOAL_ID  # each robot's goals are its own
    assert first.cancel_goal(a).return_code == ERROR_NONE
    done_b = second.get_result(b)
    step_until(c, result_of(done_b))
    assert done_b.get_nowait().status == SUCCEEDED


def test_rolling_feedback_carries_the_tracking_errors(ros_factory: Callable[..., RosDomain]) -> None:
    """Lyrical's and Rolling's NavigateToPose feedback has two more fields (nav2_msgs, branches
    lyrical and main): a Rolling client decodes it, the goal and result as on Jazzy."""
    ros = ros_factory("--lockstep", distro="rolling")
    c, nav = robot_ready(ros)
    feedback = nav.feedback()
    goal_id, accepted = nav.send_goal(goal(*GOAL))
    assert accepted.accepted
    result = nav.get_result(goal_id)
    step_until(c, result_of(result))
    assert result.get_nowait().status == SUCCEEDED
    fb = wait_for(feedback)[0]
    assert bytes(fb.goal_id.uuid) == goal_id
    assert (fb.feedback.position_tracking_error, fb.feedback.heading_tracking_error) == (0.0, 0.0)
    assert fb.feedback.current_pose.header.frame_id == "TB3_1/odom"
    assert ros.tool.rejected == []
