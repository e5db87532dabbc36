"""Nav2's multi-robot layout and localization for free, seen from a ROS tool (the stand-in).

``simd --ros-tf namespaced`` gives each robot a TF tree of its own on ``/<ns>/tf`` and
``/<ns>/tf_static`` with unprefixed frames, as nav2_bringup's multi-robot launches read it;
``simd --ros-localization`` adds ``map`` -> ``odom`` from the ground truth, ``/map`` drawn from
the world (transient local) and ``/<ns>/initialpose``. Lockstep daemons: nothing moves unless
the test steps it, and every wait is for a message or a state, never for a fixed time.

Nothing here imports the adapter: names, types and hashes are the stand-in's own.
"""

from __future__ import annotations

import math
import queue
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from clients import FleetClient, wait_until
from tests.ros2.conftest import RosDomain, pose
from tests.ros2.standin import StandIn, msg, wait_for

TF = "tf2_msgs/msg/TFMessage"
ODOM = "nav_msgs/msg/Odometry"
MAP = "nav_msgs/msg/OccupancyGrid"
INITIAL_POSE = "geometry_msgs/msg/PoseWithCovarianceStamped"
#: TB3_1 and TB3_2 of the four-robot launch; a free place a metre up the lane left of the pillars
START_1, START_2, FREE = (-2.0, -0.5), (0.5, -2.0), (-2.0, 0.5)


def step_until(c: FleetClient, q: queue.Queue[Any], predicate: Callable[[Any], bool] | None = None,
               timeout: float = 15.0) -> Any:  # fmt: skip
    """Step the lockstep daemon a few ticks at a time until ``q`` has an item that fits (a
    subscriber's first messages wait for the daemon to hear of it)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        c.step(3)
        try:
            return wait_for(q, predicate, timeout=0.3)
        except TimeoutError:
            continue
    raise TimeoutError("nothing arrived")


def transforms(message: Any) -> dict[tuple[str, str], tuple[float, float, float]]:
    """(parent, child) -> (x, y, yaw) of a TFMessage."""
    out = {}
    for t in message.transforms:
        q, p = t.transform.rotation, t.transform.translation
        out[(t.header.frame_id, t.child_frame_id)] = (p.x, p.y, 2 * math.atan2(q.z, q.w))
    return out


def compose(a: tuple[float, float, float], b: tuple[float, float, float]) -> tuple[float, float, float]:
    """Planar a ∘ b (b given in a's child frame)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], math.remainder(a[2] + b[2], 2 * math.pi)


def spawn_two(ros: RosDomain) -> FleetClient:
    c = ros.daemon.client()
    c.spawn("burger_1", *START_1, namespace="TB3_1")
    c.spawn("burger_2", *START_2, namespace="TB3_2")
    return c


def initial_pose(x: float, y: float, yaw: float, frame: str = "map") -> Any:
    header = msg("std_msgs/msg/Header", stamp=msg("builtin_interfaces/msg/Time", sec=0, nanosec=0), frame_id=frame)
    covariance = np.zeros(36)
    covariance[[0, 7, 35]] = [0.25, 0.25, 0.068]  # what RViz's "2D Pose Estimate" sends
    with_cov = msg("geometry_msgs/msg/PoseWithCovariance", pose=pose(x, y, yaw, z=0.0), covariance=covariance)
    return msg(INITIAL_POSE, header=header, pose=with_cov)


# -- --ros-tf namespaced ---------------------------------------------------------------------------


def test_namespaced_tf_a_tree_per_robot_with_unprefixed_frames(ros_factory: Callable[..., RosDomain]) -> None:
    ros = ros_factory("--lockstep", "--ros-tf", "namespaced")
    tool = ros.tool
    c = spawn_two(ros)
    g = tool.wait_graph(lambda g: {("/TB3_1/tf", "MP"), ("/TB3_2/tf_static", "MP")} <= {(e.topic, e.kind) for e in g})
    published = {e.topic for e in g if e.kind == "MP"}
    assert {"/TB3_1/tf", "/TB3_1/tf_static", "/TB3_2/tf", "/TB3_2/tf_static"} <= published
    assert not {"/tf", "/tf_static"} & published  # no fleet tree: unprefixed frames would collide in it
    tf1 = tool.subscribe("/TB3_1/tf", TF)
    odom1 = tool.subscribe("/TB3_1/odom", ODOM)
    scan1 = tool.subscribe("/TB3_1/scan", "sensor_msgs/msg/LaserScan")
    got = transforms(step_until(c, tf1)[0])
    assert set(got) == {("odom", "base_footprint")}  # TB3_1's alone
    assert got[("odom", "base_footprint")][:2] == pytest.approx(START_1)
    o = step_until(c, odom1)[0]
    assert (o.header.frame_id, o.child_frame_id) == ("odom", "base_footprint")
    assert step_until(c, scan1)[0].header.frame_id == "base_scan"
    late = StandIn(ros.router)  # joins after the static frames were sent, as a Nav2 node started later
    try:
        static: dict[tuple[str, str], Any] = {}
        q = late.subscribe_late("/TB3_2/tf_static", TF)
        deadline = time.monotonic() + 10
        while len(static) < 3 and time.monotonic() < deadline:
            static.update(transforms(wait_for(q)))
        assert set(static) == {("base_footprint", "base_link"), ("base_link", "base_scan"), ("base_link", "imu_link")}
        assert late.rejected == []
    finally:
        late.close()
    assert tool.rejected == []


def test_namespaced_tf_is_built_only_for_robots_somebody_reads(ros_factory: Callable[..., RosDomain]) -> None:
    """A subscriber of TB3_1's tree gets TB3_1's transforms; TB3_2's, unread, are never sent."""
    ros = ros_factory("--lockstep", "--ros-tf", "namespaced")
    c = spawn_two(ros)
    tf1 = ros.tool.subscribe("/TB3_1/tf", TF)
    step_until(c, tf1)
    tf2 = ros.tool.subscribe("/TB3_2/tf", TF)
    first = step_until(c, tf2)
    assert first[1] == 1  # the attachment's sequence: TB3_2's publisher sent nothing before it was read
    assert set(transforms(first[0])) == {("odom", "base_footprint")}


# -- --ros-localization ----------------------------------------------------------------------------


def test_map_is_the_world_drawn_and_reaches_a_late_subscriber(ros_factory: Callable[..., RosDomain]) -> None:
    ros = ros_factory("--lockstep", "--ros-localization")
    tool = ros.tool
    tool.wait_graph(lambda g: any(e.topic == "/map" and e.kind == "MP" for e in g))
    grid = wait_for(tool.subscribe_late("/map", MAP, depth=1), timeout=20.0)
    info = grid.info
    assert grid.header.frame_id == "map"
    assert info.resolution == pytest.approx(0.05)
    world = ros.daemon.client().world()
    b = world.bounds
    assert (info.origin.position.x, info.origin.position.y) == pytest.approx((b.x_min, b.y_min))
    assert info.width * info.resolution == pytest.approx(b.x_max - b.x_min, abs=0.05)
    assert info.height * info.resolution == pytest.approx(b.y_max - b.y_min, abs=0.05)
    cells = np.asarray(grid.data, dtype=np.int8).reshape(info.height, info.width)
    assert set(np.unique(cells).tolist()) == {0, 100}

    def at(x: float, y: float) -> int:
        return int(cells[int((y - b.y_min) / info.resolution), int((x - b.x_min) / info.resolution)])

    assert at(0.0, 0.0) == 100  # the centre pillar of turtlebot3_world
    assert at(*START_1) == 0 and at(*START_2) == 0 and at(*FREE) == 0
    assert at(-3.1, 0.0) == 100  # the hexagonal outer wall (a corner at x -2.93 inside, -3.30 outside)
    assert tool.rejected == []


def test_map_to_odom_from_the_ground_truth_in_the_fleet_tree(ros_factory: Callable[..., RosDomain]) -> None:
    """With drifting odometry, map -> odom -> base_footprint is still the true pose."""
    ros = ros_factory("--lockstep", "--ros-localization", "--odom-noise", "0.2")
    c = spawn_two(ros)
    c.step(60, cmd_vel={"TB3_1": (0.2, 0.8), "TB3_2": (0.15, -0.5)})  # a curve: the wheels slip
    c.step(30, cmd_vel={"TB3_1": (0.0, 0.0), "TB3_2": (0.0, 0.0)})  # to a stop: later ticks keep the poses
    tf = ros.tool.subscribe("/tf", TF)
    got = transforms(step_until(c, tf)[0])
    truth = {r.namespace: r.pose for r in c.robots()}  # the robots stand still now: the same tick's poses
    for ns in ("TB3_1", "TB3_2"):
        assert set(got) >= {("map", f"{ns}/odom"), (f"{ns}/odom", f"{ns}/base_footprint")}
        odom = got[(f"{ns}/odom", f"{ns}/base_footprint")]
        x, y, yaw = compose(got[("map", f"{ns}/odom")], odom)
        p = truth[ns]
        assert (x, y) == pytest.approx((p.x, p.y), abs=1e-6)
        assert math.remainder(yaw - p.yaw, 2 * math.pi) == pytest.approx(0.0, abs=1e-6)
        assert math.hypot(odom[0] - p.x, odom[1] - p.y) > 1e-4  # the odometry did drift
    assert ros.tool.rejected == []


def test_initialpose_places_the_robot(ros_factory: Callable[..., RosDomain]) -> None:
    """Nav2's layout with localization: RViz's "2D Pose Estimate" on /TB3_1/initialpose puts the
    robot there; a pose in a wall or in another frame moves nothing (in order: the last pose
    sent is the valid one, so once it is applied the others were refused)."""
    ros = ros_factory("--lockstep", "--ros-localization", "--ros-tf", "namespaced")
    tool = ros.tool
    c = spawn_two(ros)
    tool.wait_graph(lambda g: any(e.topic == "/TB3_1/initialpose" and e.kind == "MS" for e in g))
    put = tool.publisher("/TB3_1/initialpose", INITIAL_POSE, matched=10.0)
    put(initial_pose(*FREE, 1.2, frame="base_link"))
    put(initial_pose(0.0, 0.0, 0.0))  # the centre pillar
    put(initial_pose(*START_2, 0.0))  # on TB3_2
    put(initial_pose(*FREE, 1.2))

    def placed() -> bool:
        p = next(r.pose for r in c.robots() if r.namespace == "TB3_1")
        return math.hypot(p.x - FREE[0], p.y - FREE[1]) < 1e-9

    assert wait_until(placed, 10.0)
    robots = {r.namespace: r for r in c.robots()}
    assert robots["TB3_1"].pose.yaw == pytest.approx(1.2)
    assert robots["TB3_1"].linear_velocity == 0.0
    assert (robots["TB3_2"].pose.x, robots["TB3_2"].pose.y) == pytest.approx(START_2)  # not pushed
    log = ros.daemon.log()
    assert "'base_link' is not the world's" in log
    assert log.count("/TB3_1/initialpose refused") == 2  # the pillar and TB3_2
    tf1 = tool.subscribe("/TB3_1/tf", TF)
    got = transforms(step_until(c, tf1)[0])
    assert got[("map", "odom")] == pytest.approx((0.0, 0.0, 0.0))  # the odometry starts again where it was put
    assert got[("odom", "base_footprint")] == pytest.approx((*FREE, 1.2), abs=1e-9)
    assert tool.rejected == []


# -- fleet-ros nav2's files against what the daemon shows ------------------------------------------


@pytest.mark.parametrize("layout", ["namespaced", "global"])
def test_the_nav2_files_name_topics_and_frames_the_daemon_has(ros_factory: Callable[..., RosDomain],
                                                              layout: str) -> None:  # fmt: skip
    """Every topic the parameter files subscribe to is published with the type Nav2 reads, and
    every frame they name is in the robot's TF tree (the daemon's flags as the files ask)."""
    from clients.ros import nav2_files, nav2_params

    namespaced = layout == "namespaced"
    command = nav2_files.simd_command(namespaced).split()
    assert command[:2] == ["simd", "--ros2"]
    ros = ros_factory("--lockstep", *command[2:])
    tool = ros.tool
    c = spawn_two(ros)
    nodes = nav2_params.params(nav2_params.Robot("TB3_1", "burger"), "jazzy", namespaced)["TB3_1"]
    local = nodes["local_costmap"]["local_costmap"]["ros__parameters"]
    glob = nodes["global_costmap"]["global_costmap"]["ros__parameters"]
    wanted = {
        local["obstacle_layer"]["scan"]["topic"]: "sensor_msgs::msg::dds_::LaserScan_",
        nodes["bt_navigator"]["ros__parameters"]["odom_topic"]: "nav_msgs::msg::dds_::Odometry_",
        glob["static_layer"]["map_topic"]: "nav_msgs::msg::dds_::OccupancyGrid_",
    }

    def cmd_vel_types(g: list[Any]) -> set[str]:
        return {e.type for e in g if e.kind == "MS" and e.topic == "/TB3_1/cmd_vel"}

    # (the graph's tokens arrive in any order: wait for the subscription's too)
    g = tool.wait_graph(lambda g: set(wanted.items()) <= {(e.topic, e.type) for e in g if e.kind == "MP"}
                        and bool(cmd_vel_types(g)))  # fmt: skip
    assert set(wanted.items()) <= {(e.topic, e.type) for e in g if e.kind == "MP"}
    # the controller's cmd_vel, relative to its namespace, advertised as Jazzy's Nav2 sends it
    # (Twist: enable_stamped_cmd_vel is false there; both types drive)
    assert cmd_vel_types(g) == {"geometry_msgs::msg::dds_::Twist_"}
    tf_topic = "/TB3_1/tf" if namespaced else "/tf"
    tree = transforms(step_until(c, tool.subscribe(tf_topic, TF))[0])
    children = {child: parent for parent, child in tree}
    base, odom = local["robot_base_frame"], local["global_frame"]
    assert children[base] == odom and children[odom] == glob["global_frame"] == "map"
    assert tool.rejected == []
