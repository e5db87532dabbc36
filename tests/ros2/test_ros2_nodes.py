"""The daemon's nodes as ROS tools that look at nodes see them: ``ros2 param``, ``ros2 node info``,
``/rosout``, and one type per ``cmd_vel`` for tools that infer a topic's type (``ros2 topic list
-t``, ``echo`` without a type, rosbag2). The stand-in (standin.py) on a loopback ROS domain;
nothing here imports the adapter."""

from __future__ import annotations

import time
from collections.abc import Callable
from functools import partial
from typing import Any

import pytest

from clients import wait_until
from tests.ros2.conftest import RosDomain, twist
from tests.ros2.standin import StandIn, msg, node_info, topic_types, type_hash, wait_for
from tests.ros2.test_ros2_daemon import drive_until

TWIST, STAMPED = "geometry_msgs/msg/Twist", "geometry_msgs/msg/TwistStamped"
LIST = "rcl_interfaces/srv/ListParameters"
PARAMETER_SERVICES = {
    "describe_parameters": "rcl_interfaces/srv/DescribeParameters",
    "get_parameter_types": "rcl_interfaces/srv/GetParameterTypes",
    "get_parameters": "rcl_interfaces/srv/GetParameters",
    "list_parameters": LIST,
    "set_parameters": "rcl_interfaces/srv/SetParameters",
    "set_parameters_atomically": "rcl_interfaces/srv/SetParametersAtomically",
}
ROBOT_NODE = "/TB3_1/turtlebot3"


def stamped(v: float, w: float) -> Any:
    header = msg("std_msgs/msg/Header", stamp=msg("builtin_interfaces/msg/Time", sec=0, nanosec=0), frame_id="")
    return msg(STAMPED, header=header, twist=twist(v, w))


def robot(ros: RosDomain, node: str = ROBOT_NODE) -> None:
    """burger_1 in TB3_1, its node's parameter services in the graph."""
    ros.daemon.client().spawn("burger_1", -2.0, -0.5, namespace="TB3_1")
    assert wait_until(lambda: ros.tool.service_available(f"{node}/list_parameters", LIST), 10.0)


# -- cmd_vel: one advertised type, both taken ------------------------------------------------------


@pytest.mark.parametrize(
    ("distro", "flag", "advertised", "other"),
    [
        ("jazzy", None, {TWIST}, STAMPED),  # Nav2's default up to Jazzy: Twist
        ("kilted", None, {STAMPED}, TWIST),  # and from Kilted on: TwistStamped
        ("jazzy", "stamped", {STAMPED}, TWIST),
        ("kilted", "both", {TWIST, STAMPED}, TWIST),
    ],
)
def test_cmd_vel_advertises_one_type_and_takes_both(
    ros_factory: Callable[..., RosDomain], distro: str, flag: str | None, advertised: set[str], other: str
) -> None:
    ros = ros_factory(*(["--ros-cmd-vel", flag] if flag else []), distro=distro)
    tool = ros.tool
    ros.daemon.client().spawn("burger_1", -2.0, -0.5, namespace="TB3_1")
    # every subscriber's token: each arrives on its own, in any order
    g = tool.wait_graph(lambda g: topic_types(g).get("/TB3_1/cmd_vel", set()) >= advertised)
    assert topic_types(g)["/TB3_1/cmd_vel"] == advertised  # what `ros2 topic list -t` shows
    subs = [e for e in g if e.kind == "MS" and e.topic == "/TB3_1/cmd_vel"]
    assert {e.hash for e in subs} == {type_hash(t, distro) for t in advertised}
    pub = tool.publisher("/TB3_1/cmd_vel", other)  # a tool of the other habit still drives
    message = twist(0.2, 0.0) if other == TWIST else stamped(0.2, 0.0)
    m = drive_until(tool, "TB3_1", lambda: pub(message), lambda m: m.pose.pose.position.x > -1.9)
    assert m.twist.twist.linear.x == pytest.approx(0.2, abs=0.02)


# -- parameters, node info, /rosout ---------------------------------------------------------------


def test_ros2_param_on_the_robots_and_the_daemons_node(ros: RosDomain) -> None:
    tool = ros.tool
    robot(ros)
    for node in (ROBOT_NODE, "/fleetsim"):
        assert wait_until(partial(tool.service_available, f"{node}/list_parameters", LIST), 10.0)
        listed = tool.list_parameters(node)  # ros2 param list
        assert (list(listed.names), list(listed.prefixes)) == (["use_sim_time"], [])
        (value,) = tool.parameter_call(node, "get_parameters", names=["use_sim_time"]).values  # ros2 param get
        assert (value.type, value.bool_value) == (1, True)
        (d,) = tool.parameter_call(node, "describe_parameters", names=["use_sim_time"]).descriptors
        assert (d.name, d.type, d.read_only, d.dynamic_typing) == ("use_sim_time", 1, False, False)
        assert list(tool.parameter_call(node, "get_parameter_types", names=["use_sim_time"]).types) == [1]
        # an undeclared name empties the answer, as rclcpp's services do
        assert list(tool.parameter_call(node, "get_parameters", names=["use_sim_time", "rate"]).values) == []
        assert list(tool.parameter_call(node, "get_parameter_types", names=["rate"]).types) == []
        # ros2 param set: true stays true, anything else is refused with the reason
        (ok,) = tool.set_parameter(node, "use_sim_time", True).results
        assert (ok.successful, ok.reason) == (True, "")
        (no,) = tool.set_parameter(node, "use_sim_time", False).results
        assert not no.successful and "sim time" in no.reason
        (undeclared,) = tool.set_parameter(node, "rate", 1.5).results
        assert (undeclared.successful, undeclared.reason) == (
            False, "parameter 'rate' cannot be set because it was not declared",
        )  # fmt: skip
        assert tool.set_parameter(node, "use_sim_time", True, atomically=True).result.successful
        wrong = tool.set_parameter(node, "use_sim_time", "yes", atomically=True).result
        assert not wrong.successful and wrong.reason.startswith("Wrong parameter type")
    assert tool.rejected == []


def test_node_info_lists_what_an_rclcpp_node_has(ros: RosDomain) -> None:
    robot(ros)
    want = {f"{ROBOT_NODE}/{s}" for s in PARAMETER_SERVICES} | {"/rosout", "/parameter_events"}
    g = ros.tool.wait_graph(lambda g: want <= {e.topic for e in g if e.node_fqn == ROBOT_NODE})
    info = node_info(g, ROBOT_NODE)  # ros2 node info /TB3_1/turtlebot3
    for suffix, typename in PARAMETER_SERVICES.items():
        assert info["services"][f"{ROBOT_NODE}/{suffix}"] == {typename}
    assert info["publishers"]["/rosout"] == {"rcl_interfaces/msg/Log"}
    assert info["publishers"]["/parameter_events"] == {"rcl_interfaces/msg/ParameterEvent"}
    assert info["subscribers"]["/TB3_1/cmd_vel"] == {TWIST}
    tokens = {(e.kind, e.topic): e for e in g if e.node_fqn == ROBOT_NODE}
    for suffix, typename in PARAMETER_SERVICES.items():
        assert tokens[("SS", f"{ROBOT_NODE}/{suffix}")].hash == type_hash(typename)
    assert tokens[("MP", "/rosout")].hash == type_hash("rcl_interfaces/msg/Log")

    def daemon_node_complete(g: list[Any]) -> bool:
        own = node_info(g, "/fleetsim")
        return {"/rosout", "/parameter_events", "/clock", "/tf"} <= set(own["publishers"]) and {
            "/fleetsim/list_parameters", "/spawn_entity",
        } <= set(own["services"])  # fmt: skip

    own = node_info(ros.tool.wait_graph(daemon_node_complete), "/fleetsim")  # ros2 node info /fleetsim
    assert own["services"]["/fleetsim/list_parameters"] == {LIST}
    assert own["publishers"]["/rosout"] == {"rcl_interfaces/msg/Log"}


def test_rosout_tells_spawns_and_deletes_and_a_deleted_robot_has_no_parameters(ros: RosDomain) -> None:
    tool = ros.tool
    robot(ros)
    late = StandIn(ros.router)  # joins after the spawn: /rosout is transient local, as rcl's
    try:
        log = late.subscribe_late("/rosout", "rcl_interfaces/msg/Log", depth=1000)
        line = wait_for(log, lambda m: "burger_1" in m.msg)
        assert (line.name, line.level) == ("fleetsim", 20)  # INFO, from the daemon's node
        assert (
            line.msg.startswith("spawned burger_1 (burger) as /TB3_1/turtlebot3")
            and abs(line.stamp.sec - time.time()) < 60
        )
        ros.daemon.client().delete("burger_1")
        assert wait_for(log, lambda m: m.msg.startswith("deleted burger_1")).name == "fleetsim"
        assert late.rejected == []
    finally:
        late.close()
    g = tool.wait_graph(lambda g: not any(e.node_fqn == ROBOT_NODE for e in g))
    assert not any(e.node_fqn == ROBOT_NODE for e in g)
    with pytest.raises(TimeoutError):  # its services went with it: nobody answers for it any more
        tool.call(f"{ROBOT_NODE}/list_parameters", LIST, tool.msg(f"{LIST}_Request", prefixes=[], depth=0), timeout=1.0)
    # a wildcard call is somebody looking around: no answer
    key = f"0/*/turtlebot3/list_parameters/rcl_interfaces::srv::dds_::ListParameters_/{type_hash(LIST)}"
    assert [r for r in tool.session.get(key, timeout=1.0) if r.ok is not None] == []


def test_humble_parameter_services_carry_no_hash(ros_factory: Callable[..., RosDomain]) -> None:
    ros = ros_factory(distro="humble")
    robot(ros)
    both = {f"{ROBOT_NODE}/list_parameters", "/fleetsim/list_parameters"}
    g = ros.tool.wait_graph(lambda g: both <= {e.topic for e in g})
    assert {e.hash for e in g if e.topic in both} == {"TypeHashNotSupported"}
    assert list(ros.tool.list_parameters(ROBOT_NODE).names) == ["use_sim_time"]
