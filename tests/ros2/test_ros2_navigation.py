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
from tests.ros2.conftest import RosDomain
from tests.ros2.standin import (
    ActionClient,
    StandIn,
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


def pose_stamped(x: float, y: float, yaw: float = 0.0, frame: str = "map") -> Any:
    header = msg("std_msgs/msg/Header", stamp=msg("builtin_interfaces/msg/Time", sec=0, nanosec=0), frame_id=frame)
    p = msg(
        "geometry_msgs/msg/Pose",
        position=msg("geometry_msgs/msg/Point", x=x, y=y, z=0.0),
        orientation=msg("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)),
    )
    return msg("geometry_msgs/msg/PoseStamped", header=header, pose=p)


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
