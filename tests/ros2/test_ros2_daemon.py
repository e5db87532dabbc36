"""simd --ros2 seen from a ROS tool: the stand-in (standin.py) on a loopback ROS domain.

Nothing here imports the adapter: keys, tokens, attachments and CDR are the stand-in's own,
from rmw_zenoh's design document and rosbags.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from clients import wait_until
from tests.ros2.conftest import DATA, RosDomain, spawn_request, twist
from tests.ros2.standin import StandIn, dds_name, msg, parse_qos, type_hash, wait_for

SPAWN = ("/spawn_entity", "gazebo_msgs/srv/SpawnEntity")
DELETE = ("/delete_entity", "gazebo_msgs/srv/DeleteEntity")
#: the Gazebo TurtleBot3 multi-robot launch: TB3_<n>, entity burger_<n>, these poses
MULTI = [("burger_1", "TB3_1", -2.0, -0.5), ("burger_2", "TB3_2", 0.5, -2.0),
         ("burger_3", "TB3_3", 2.0, 0.5), ("burger_4", "TB3_4", -0.5, 2.0)]  # fmt: skip


def spawn(tool: StandIn, name: str, ns: str, x: float, y: float, yaw: float = 0.0, **kw: Any) -> Any:
    return tool.call(*SPAWN, spawn_request(name, ns, x, y, yaw, **kw))


def latest(q: Any, timeout: float = 10.0) -> Any:
    """The newest message of a subscription (waiting for one if none is there yet)."""
    item = wait_for(q, timeout=timeout)
    while not q.empty():
        item = q.get_nowait()
    return item


def drive_until(tool: StandIn, ns: str, publish: Callable[[], None], moved: Callable[[Any], bool]) -> Any:
    """Publish commands (as teleop does, 10 a second) until the robot's odometry shows ``moved``."""
    odom = tool.subscribe(f"/{ns}/odom", "nav_msgs/msg/Odometry")
    deadline = time.monotonic() + 15.0
    while time.monotonic() < deadline:
        publish()
        time.sleep(0.1)
        m = latest(odom)[0]
        if moved(m):
            return m
    raise AssertionError(f"{ns} did not move")


def test_spawner_node_flow_four_namespaced_robots_then_drive_one(ros: RosDomain) -> None:
    """The multi-robot tutorial: wait for /spawn_entity, spawn TB3_1..4 with the SDF text, drive TB3_1."""
    tool = ros.tool
    # as the spawner node's wait_for_service: a graph query may miss a token a moment after it was seen
    assert wait_until(lambda: tool.service_available(*SPAWN), 10.0)
    for name, ns, x, y in MULTI:
        r = spawn(tool, name, ns, x, y)
        assert r.success, r.status_message
        assert r.status_message == f"SpawnEntity: Successfully spawned entity [{name}]"
    robots = {r.name: r for r in ros.daemon.client().robots()}
    assert sorted(robots) == [m[0] for m in MULTI]
    for name, ns, x, y in MULTI:
        assert robots[name].namespace == ns and robots[name].model == "burger"
        assert (robots[name].pose.x, robots[name].pose.y) == pytest.approx((x, y))

    pub = tool.publisher("/TB3_1/cmd_vel", "geometry_msgs/msg/Twist")
    m = drive_until(tool, "TB3_1", lambda: pub(twist(0.2, 0.0)), lambda m: m.pose.pose.position.x > -1.9)
    assert m.twist.twist.linear.x == pytest.approx(0.2, abs=0.02)
    others = {r.name: r for r in ros.daemon.client().robots()}
    for name, _, x, y in MULTI[1:]:  # only the commanded robot moved
        assert (others[name].pose.x, others[name].pose.y) == pytest.approx((x, y))


def test_spawn_refusals_use_gazebos_words_and_change_nothing(ros: RosDomain) -> None:
    tool = ros.tool
    assert spawn(tool, "burger_1", "TB3_1", -2.0, -0.5).success
    dup = spawn(tool, "burger_1", "TB3_9", 0.5, -2.0)
    assert (dup.success, dup.status_message) == (False, "Entity [burger_1] already exists.")
    nan = spawn(tool, "burger_2", "TB3_2", math.nan, 0.0)
    assert not nan.success and "not finite" in nan.status_message
    alien = spawn(tool, "x", "X", 0.5, -2.0, xml='<sdf version="1.6"><model name="pr2"/></sdf>')
    assert not alien.success and "[pr2]" in alien.status_message
    broken = spawn(tool, "y", "Y", 0.5, -2.0, xml="<sdf><model")
    assert not broken.success and broken.status_message.startswith("Failed to parse XML string")
    empty = spawn(tool, "z", "Z", 0.5, -2.0, xml="<sdf version='1.6'></sdf>")
    assert not empty.success and empty.status_message.startswith("Failed to find a model or light on SDF")
    frame = spawn(tool, "w", "W", 0.5, -2.0, reference_frame="burger_1::base_link")
    assert not frame.success and frame.status_message.startswith("Reference frame [burger_1::base_link] not found")
    wall = spawn(tool, "v", "V", 0.0, 0.0)  # the centre pillar of turtlebot3_world
    assert not wall.success
    assert [r.name for r in ros.daemon.client().robots()] == ["burger_1"]
    assert ros.daemon.alive()


def test_urdf_waffle_and_yaw_from_the_quaternion(ros: RosDomain) -> None:
    xml = (DATA / "turtlebot3_waffle.urdf").read_text()
    r = spawn(ros.tool, "waffle_1", "", 0.5, -2.0, yaw=1.2, xml=xml)
    assert r.success, r.status_message
    (robot,) = ros.daemon.client().robots()
    assert robot.model == "waffle" and robot.namespace == "waffle_1"  # no robot_namespace: the name
    assert robot.pose.yaw == pytest.approx(1.2)


def test_delete_entity(ros: RosDomain) -> None:
    tool = ros.tool
    assert spawn(tool, "burger_1", "TB3_1", -2.0, -0.5).success
    tool.wait_graph(lambda g: any(e.node_fqn == "/TB3_1/turtlebot3" for e in g))
    r = tool.call(*DELETE, msg("gazebo_msgs/srv/DeleteEntity_Request", name="burger_1"))
    assert (r.success, r.status_message) == (True, "Successfully deleted entity [burger_1]")
    again = tool.call(*DELETE, msg("gazebo_msgs/srv/DeleteEntity_Request", name="burger_1"))
    assert (again.success, again.status_message) == (False, "Entity [burger_1] does not exist")
    g = tool.wait_graph(lambda g: not any(e.namespace == "/TB3_1" for e in g))
    assert not any(e.namespace == "/TB3_1" for e in g)  # its nodes and topics vanished with it
    assert ros.daemon.client().robots() == []


def test_graph_names_nodes_topics_and_services_as_gazebo(ros: RosDomain) -> None:
    tool = ros.tool
    assert spawn(tool, "burger_1", "TB3_1", -2.0, -0.5).success
    # 6 of the Gazebo robot, 7 of Nav2's navigate_to_pose, goal_pose and plan (test_ros2_navigation.py),
    # and 8 of rclcpp's node (parameter services, /rosout, /parameter_events: test_parameters_and_rosout)
    g = tool.wait_graph(lambda g: sum(e.namespace == "/TB3_1" and e.kind != "NN" for e in g) == 21)
    nodes = {e.node_fqn for e in g if e.kind == "NN"}
    assert nodes == {"/fleetsim", "/TB3_1/turtlebot3"}
    assert {e.node_fqn for e in g if e.namespace == "/TB3_1"} == {"/TB3_1/turtlebot3"}
    pubs = {(e.topic, e.type): e for e in g if e.kind == "MP"}
    expected = {
        "/TB3_1/odom": "nav_msgs/msg/Odometry",
        "/TB3_1/scan": "sensor_msgs/msg/LaserScan",
        "/TB3_1/imu": "sensor_msgs/msg/Imu",
        "/TB3_1/joint_states": "sensor_msgs/msg/JointState",
        "/tf": "tf2_msgs/msg/TFMessage",
        "/tf_static": "tf2_msgs/msg/TFMessage",
        "/clock": "rosgraph_msgs/msg/Clock",
    }
    for topic, typename in expected.items():
        e = pubs[(topic, dds_name(typename))]
        assert e.hash == type_hash(typename)
    tf_static = parse_qos(pubs[("/tf_static", dds_name("tf2_msgs/msg/TFMessage"))].qos)
    assert (tf_static.reliability, tf_static.durability, tf_static.depth) == (1, 1, 1)
    subs = {e.type for e in g if e.kind == "MS" and e.topic == "/TB3_1/cmd_vel"}
    assert subs == {dds_name("geometry_msgs/msg/Twist")}  # Jazzy's tools' default: one type
    services = {(e.topic, e.type, e.hash) for e in g if e.kind == "SS"}
    for name, typename in (SPAWN, DELETE):
        assert (name, dds_name(typename), type_hash(typename)) in services


def test_odom_scan_tf_and_their_fields(ros: RosDomain) -> None:
    tool = ros.tool
    assert spawn(tool, "burger_1", "TB3_1", -2.0, -0.5, yaw=0.5).success
    assert spawn(tool, "burger_2", "TB3_2", 0.5, -2.0).success
    odom = tool.subscribe("/TB3_1/odom", "nav_msgs/msg/Odometry")
    scan = tool.subscribe("/TB3_1/scan", "sensor_msgs/msg/LaserScan")
    tf = tool.subscribe("/tf", "tf2_msgs/msg/TFMessage")
    first, second = wait_for(odom), wait_for(odom)
    assert second[1] == first[1] + 1  # the attachment counts the publisher's samples
    o = first[0]
    assert (o.header.frame_id, o.child_frame_id) == ("TB3_1/odom", "TB3_1/base_footprint")
    p = o.pose.pose
    assert (p.position.x, p.position.y) == pytest.approx((-2.0, -0.5))
    assert 2 * math.atan2(p.orientation.z, p.orientation.w) == pytest.approx(0.5)
    assert np.diag(o.pose.covariance.reshape(6, 6)).tolist() == [1e-5, 1e-5, 1e12, 1e12, 1e12, 1e-3]
    s = wait_for(scan)[0]
    assert s.header.frame_id == "TB3_1/base_scan"
    assert (s.angle_min, s.range_min, s.range_max) == pytest.approx((0.0, 0.12, 3.5))
    assert s.angle_max == pytest.approx(6.28)
    assert (s.angle_max - s.angle_min) / s.angle_increment + 1 == pytest.approx(360)  # what Karto checks
    assert (s.time_increment, s.scan_time) == (0.0, 0.0)
    assert len(s.ranges) == len(s.intensities) == 360
    finite = s.ranges[np.isfinite(s.ranges)]
    assert len(finite) > 0 and finite.min() >= 0.12 and finite.max() <= 3.5
    frames: set[str] = set()
    deadline = time.monotonic() + 10
    while frames != {"TB3_1/base_footprint", "TB3_2/base_footprint"} and time.monotonic() < deadline:
        t = wait_for(tf)[0]
        frames = {x.child_frame_id for x in t.transforms}
        assert all(x.header.frame_id == x.child_frame_id.replace("base_footprint", "odom") for x in t.transforms)
    assert frames == {"TB3_1/base_footprint", "TB3_2/base_footprint"}
    assert tool.rejected == []


def test_a_samples_gid_is_its_publishers_as_the_graph_shows_it(ros: RosDomain) -> None:
    """``ros2 topic info -v`` shows the GID rmw_zenoh derives from the publisher's token; a
    message's ``publisher_gid`` is its attachment's: the two agree. And the samples are
    timestamped, as rmw_zenoh's sessions timestamp theirs."""
    tool = ros.tool
    assert spawn(tool, "burger_1", "TB3_1", -2.0, -0.5).success
    stamps = tool.timestamps("/TB3_1/odom", "nav_msgs/msg/Odometry")
    for topic, typename in [("/TB3_1/odom", "nav_msgs/msg/Odometry"), ("/tf", "tf2_msgs/msg/TFMessage")]:
        _, _, _, gid = wait_for(tool.subscribe(topic, typename))
        g = tool.wait_graph(lambda g, topic=topic: any(e.kind == "MP" and e.topic == topic for e in g))
        assert [e.gid for e in g if e.kind == "MP" and e.topic == topic] == [gid]
    assert wait_until(lambda: len(stamps) > 0, 5.0)
    assert all(stamp is not None for stamp in stamps)
    assert tool.rejected == []


def test_an_older_rmw_zenoh_drives_and_calls_and_is_told_once(ros: RosDomain) -> None:
    """Jazzy 0.2.0-0.2.3 put its values after their names in every attachment. Its commands
    drive, its calls are answered in its own format, and the log says once per sender which
    releases can also read what the daemon publishes (this one cannot)."""
    old = StandIn(ros.router, legacy=True)
    try:
        assert wait_until(lambda: old.service_available(*SPAWN), 10.0)  # as the spawner node waits
        r = old.call(*SPAWN, spawn_request("burger_1", "TB3_1", -2.0, -0.5))
        assert r.success, r.status_message
        assert old.call(*SPAWN, spawn_request("burger_1", "TB3_1", -2.0, -0.5)).status_message.endswith("exists.")
        pub = old.publisher("/TB3_1/cmd_vel", "geometry_msgs/msg/Twist")
        drive_until(ros.tool, "TB3_1", lambda: pub(twist(0.2, 0.0)), lambda m: m.pose.pose.position.x > -1.9)
        odom = old.subscribe("/TB3_1/odom", "nav_msgs/msg/Odometry")
        assert wait_until(lambda: len(old.rejected) > 0, 5.0) and odom.empty()  # it cannot read today's format
    finally:
        old.close()
    log = ros.daemon.log()
    told = [line for line in log.splitlines() if "an older rmw_zenoh" in line]
    assert len(told) == 2, told  # its client, its publisher: once each
    assert any("/spawn_entity: an older rmw_zenoh" in line for line in told)
    assert any("/TB3_1/cmd_vel: an older rmw_zenoh" in line for line in told)
    assert "jazzy >= 0.2.4, humble >= 0.1.2, kilted >= 0.6.0, rolling >= 0.6.0" in told[0]
    assert "Traceback" not in log


def test_the_session_config_comes_from_the_environment_as_for_a_ros_process(
    router: str, daemon_factory: Callable[..., Any], tmp_path: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    """ZENOH_SESSION_CONFIG_URI replaces the session's config (this file does not timestamp, and
    connects nowhere useful); ZENOH_CONFIG_OVERRIDE then points it at the router."""
    path = tmp_path / "session.json5"
    path.write_text('{mode: "peer", connect: {endpoints: ["tcp/127.0.0.1:1"]}, '
                    'listen: {endpoints: ["tcp/127.0.0.1:0"]}, scouting: {multicast: {enabled: false}}}')  # fmt: skip
    overrides = f'connect/endpoints=["{router}"]'
    monkeypatch.setenv("ZENOH_SESSION_CONFIG_URI", str(path))
    monkeypatch.setenv("ZENOH_CONFIG_OVERRIDE", overrides)
    d = daemon_factory("--ros2")  # no --ros-router: the environment's
    tool = StandIn(router)
    try:
        assert wait_until(lambda: tool.service_available(*SPAWN), 10.0)
        assert spawn(tool, "burger_1", "TB3_1", -2.0, -0.5).success
        stamps = tool.timestamps("/TB3_1/odom", "nav_msgs/msg/Odometry")
        assert wait_until(lambda: len(stamps) > 2, 5.0)
        assert all(stamp is None for stamp in stamps)  # the file's config, not the built-in one
    finally:
        tool.close()
    line = next(x for x in d.log().splitlines() if x.startswith("simd: ROS 2"))
    assert f"joining the router at {router}; session config: ZENOH_SESSION_CONFIG_URI={path}" in line
    assert f"ZENOH_CONFIG_OVERRIDE={overrides}" in line


def test_tf_static_reaches_a_late_joiner(ros: RosDomain) -> None:
    tool = ros.tool
    assert spawn(tool, "burger_1", "TB3_1", -2.0, -0.5).success
    xml = (DATA / "turtlebot3_waffle.urdf").read_text()
    assert spawn(tool, "waffle_2", "TB3_2", 0.5, -2.0, xml=xml).success
    late = StandIn(ros.router)  # joins after both robots' static frames were sent
    try:
        q = late.subscribe_late("/tf_static", "tf2_msgs/msg/TFMessage")
        got: dict[tuple[str, str], Any] = {}
        deadline = time.monotonic() + 10
        while len(got) < 6 and time.monotonic() < deadline:
            for t in wait_for(q).transforms:
                got[(t.header.frame_id, t.child_frame_id)] = t.transform.translation
        assert set(got) == {
            ("TB3_1/base_footprint", "TB3_1/base_link"), ("TB3_1/base_link", "TB3_1/base_scan"),
            ("TB3_1/base_link", "TB3_1/imu_link"), ("TB3_2/base_footprint", "TB3_2/base_link"),
            ("TB3_2/base_link", "TB3_2/base_scan"), ("TB3_2/base_link", "TB3_2/imu_link"),
        }  # fmt: skip
        scan1, scan2 = got[("TB3_1/base_link", "TB3_1/base_scan")], got[("TB3_2/base_link", "TB3_2/base_scan")]
        assert (scan1.x, scan1.z) == pytest.approx((-0.032, 0.172))  # burger
        assert (scan2.x, scan2.z) == pytest.approx((-0.064, 0.122))  # waffle
        assert late.rejected == []
    finally:
        late.close()


def test_twist_stamped_drives_and_turns(ros: RosDomain) -> None:
    tool = ros.tool
    assert spawn(tool, "burger_1", "TB3_1", -2.0, -0.5).success
    pub = tool.publisher("/TB3_1/cmd_vel", "geometry_msgs/msg/TwistStamped")
    header = msg("std_msgs/msg/Header", stamp=msg("builtin_interfaces/msg/Time", sec=0, nanosec=0), frame_id="")
    stamped = msg("geometry_msgs/msg/TwistStamped", header=header, twist=twist(0.0, 1.0))
    # the wheels ramp up over three ticks (0.42, 0.83, 1.0 rad/s): wait past the ramp
    m = drive_until(tool, "TB3_1", lambda: pub(stamped), lambda m: abs(m.twist.twist.angular.z) > 0.9)
    assert m.twist.twist.angular.z == pytest.approx(1.0, abs=0.05)


def test_clock_follows_lockstep(ros_factory: Callable[..., RosDomain]) -> None:
    ros = ros_factory("--lockstep")
    clock = ros.tool.subscribe("/clock", "rosgraph_msgs/msg/Clock")
    c = ros.daemon.client()
    ticks = 0  # stepped a tick at a time until the daemon has heard the subscription and puts /clock
    deadline = time.monotonic() + 10
    while True:
        assert time.monotonic() < deadline, "/clock never came"
        ticks += c.step(1).ticks_run
        try:
            wait_for(clock, timeout=0.2)
            break
        except TimeoutError:
            continue
    c.step(45)
    want = (ticks + 45) / 30  # 45 more ticks of 1/30 s, on /clock for use_sim_time
    t = None
    while t != pytest.approx(want, abs=1e-9) and time.monotonic() < deadline:
        m = wait_for(clock)[0]
        t = m.clock.sec + m.clock.nanosec * 1e-9
    assert t == pytest.approx(want, abs=1e-9)


def test_bad_input_on_ros_keys_changes_nothing(ros: RosDomain) -> None:
    tool = ros.tool
    assert spawn(tool, "burger_1", "TB3_1", -2.0, -0.5).success
    s = tool.session
    domain_key = f"0/TB3_1/cmd_vel/{dds_name('geometry_msgs/msg/Twist')}/{type_hash('geometry_msgs/msg/Twist')}"
    s.put(domain_key, b"\x00\x01\x00\x00garbage")  # malformed CDR
    s.put(domain_key, b"")  # empty
    s.put(f"0/TB3_1/cmd_vel/{dds_name('std_msgs/msg/String')}/{type_hash('std_msgs/msg/String')}", b"x")
    pub = tool.publisher("/TB3_404/cmd_vel", "geometry_msgs/msg/Twist")
    pub(twist(0.2, 0.0))  # no such robot
    nan = tool.publisher("/TB3_1/cmd_vel", "geometry_msgs/msg/Twist")
    nan(twist(math.nan, 0.0))
    spawn_key = f"0/spawn_entity/{dds_name(SPAWN[1])}/{type_hash(SPAWN[1])}"
    replies = list(s.get(spawn_key, payload=b"\x00\x01\x00\x00\xff\xff\xff\x7f", timeout=5.0))
    decoded = [r.ok for r in replies if r.ok is not None]
    assert len(decoded) == 1  # a malformed request still gets an answer, success false
    from tests.ros2.standin import deserialize

    answer = deserialize(decoded[0].payload.to_bytes(), "gazebo_msgs/srv/SpawnEntity_Response")
    assert not answer.success and "malformed" in answer.status_message
    # a wildcard get is somebody looking: no answer, no robot
    looked = list(s.get("0/spawn_entity/**", payload=b"", timeout=2.0))
    assert [r for r in looked if r.ok is not None] == []
    c = ros.daemon.client()
    deadline = time.monotonic() + 5
    while c.clock().dropped_commands < 5 and time.monotonic() < deadline:
        time.sleep(0.05)
    assert c.clock().dropped_commands >= 5
    (robot,) = c.robots()
    assert (robot.pose.x, robot.pose.y) == pytest.approx((-2.0, -0.5))
    assert ros.daemon.alive()
    log = ros.daemon.log()
    assert "Traceback" not in log


def test_humble_keys_carry_no_hash(ros_factory: Callable[..., RosDomain]) -> None:
    ros = ros_factory(distro="humble", domain=7)
    tool = ros.tool  # a Humble tool in domain 7
    g = tool.graph()
    assert all(e.hash == "TypeHashNotSupported" for e in g if e.kind != "NN")
    assert spawn(tool, "burger_1", "TB3_1", -2.0, -0.5).success
    odom = tool.subscribe("/TB3_1/odom", "nav_msgs/msg/Odometry")
    assert wait_for(odom)[0].header.frame_id == "TB3_1/odom"
    jazzy = StandIn(ros.router, 7, "jazzy")  # a Jazzy tool's keys carry hashes: nothing answers them
    try:
        with pytest.raises(TimeoutError):
            jazzy.call(*SPAWN, spawn_request("burger_2", "TB3_2", 0.5, -2.0), timeout=1.0)
    finally:
        jazzy.close()


def test_the_shipped_rviz_config_resolves_against_the_four_robot_launch(ros_factory: Callable[..., RosDomain]) -> None:
    """Every display of docs/ros2/fleetsim.rviz gets messages, and every frame they name reaches
    the fixed frame through /tf and /tf_static, as RViz needs to draw them."""
    import yaml

    from tests.conftest import ROOT

    config = yaml.safe_load((ROOT / "docs/ros2/fleetsim.rviz").read_text())
    manager = config["Visualization Manager"]
    fixed = manager["Global Options"]["Fixed Frame"]
    ros = ros_factory("--ros-world-frame", fixed)
    c = ros.daemon.client()
    for name, ns, x, y in MULTI:
        c.spawn(name, x, y, namespace=ns)
    parents: dict[str, str] = {}
    static = ros.tool.subscribe_late("/tf_static", "tf2_msgs/msg/TFMessage")
    dynamic = ros.tool.subscribe("/tf", "tf2_msgs/msg/TFMessage")
    frames: set[str] = set()
    for display in manager["Displays"]:
        if "Topic" not in display:
            continue
        topic = display["Topic"]["Value"]
        typename = {"rviz_default_plugins/LaserScan": "sensor_msgs/msg/LaserScan",
                    "rviz_default_plugins/Odometry": "nav_msgs/msg/Odometry"}[display["Class"]]  # fmt: skip
        m = wait_for(ros.tool.subscribe(topic, typename))[0]
        frames.add(m.header.frame_id)
    assert len(frames) == 8  # four scans, four odometry frames
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and not all(_reaches(f, fixed, parents) for f in frames):
        for q in (static, dynamic):
            while not q.empty():
                item = q.get_nowait()
                message = item[0] if isinstance(item, tuple) else item
                for t in message.transforms:
                    parents[t.child_frame_id] = t.header.frame_id
        time.sleep(0.1)
    assert all(_reaches(f, fixed, parents) for f in frames), parents


def _reaches(frame: str, root: str, parents: dict[str, str]) -> bool:
    seen = set()
    while frame != root:
        if frame in seen or frame not in parents:
            return False
        seen.add(frame)
        frame = parents[frame]
    return True


@pytest.mark.parametrize(
    ("args", "env", "message"),
    [
        (["--ros-domain-id", "300"], {}, "domain id must be in 0..232"),
        ([], {"ROS_DOMAIN_ID": "abc"}, "ROS_DOMAIN_ID must be a whole number"),
        (["--ros-world-frame", "/world"], {}, "--ros-world-frame must be a tf frame name"),
        (["--ros-distro", "iron"], {}, "invalid choice"),
        (["--ros-cmd-vel", "twisted"], {}, "invalid choice"),
        (["--ros-serve-router", "--ros-mode", "client"], {}, "leave out --ros-mode client"),
        (["--ros-localization", "--ros-world-frame", "world"], {}, "a frame has one parent"),
        (["--ros-tf", "prefixed"], {}, "invalid choice"),
        ([], {"ZENOH_CONFIG_OVERRIDE": "transport/link/tx/lease"}, "'transport/link/tx/lease' is not KEY=VALUE"),
        ([], {"ZENOH_CONFIG_OVERRIDE": "transport/link/tx/lease=soon"}, "ZENOH_CONFIG_OVERRIDE: cannot set"),
        ([], {"ZENOH_SESSION_CONFIG_URI": "/no/such/ros.json5"}, "ZENOH_SESSION_CONFIG_URI=/no/such/ros.json5: not a"),
        (["--ros-serve-router"], {"ZENOH_ROUTER_CONFIG_URI": "/no/such/router.json5"}, "ZENOH_ROUTER_CONFIG_URI="),
    ],
)
def test_bad_ros_flags_are_one_clear_line(args: list[str], env: dict[str, str], message: str) -> None:
    import os
    import subprocess

    from tests.conftest import ROOT, free_port, simd_command

    p = subprocess.run(
        simd_command("--ros2", "-l", f"tcp/127.0.0.1:{free_port()}", *args),
        capture_output=True, text=True, timeout=30, cwd=ROOT, env={**os.environ, **env},
    )  # fmt: skip
    assert p.returncode == 2
    assert "Traceback" not in p.stderr
    last = p.stderr.strip().splitlines()[-1]  # argparse puts its usage before
    assert last.startswith("simd: error:") and message in last


def test_imu_and_joint_states_follow_the_wheels(ros: RosDomain) -> None:
    tool = ros.tool
    assert spawn(tool, "burger_1", "TB3_1", -2.0, -0.5).success
    imu = tool.subscribe("/TB3_1/imu", "sensor_msgs/msg/Imu")
    joints = tool.subscribe("/TB3_1/joint_states", "sensor_msgs/msg/JointState")
    pub = tool.publisher("/TB3_1/cmd_vel", "geometry_msgs/msg/Twist")
    drive_until(tool, "TB3_1", lambda: pub(twist(0.1, 0.5)), lambda m: abs(m.twist.twist.angular.z - 0.5) < 0.01)
    pub(twist(0.1, 0.5))
    j = latest(joints)[0]
    assert list(j.name) == ["wheel_left_joint", "wheel_right_joint"]
    left, right = j.velocity
    # v = r (left + right) / 2, w = r (right - left) / separation, for the burger
    assert 0.033 * (left + right) / 2 == pytest.approx(0.1, abs=0.01)
    assert 0.033 * (right - left) / 0.160 == pytest.approx(0.5, abs=0.05)
    later = latest(joints)[0]
    assert later.position[1] > j.position[1]  # the right wheel turns forward
    i = latest(imu)[0]
    assert i.header.frame_id == "TB3_1/imu_link"
    assert i.angular_velocity.z == pytest.approx(0.5, abs=0.05)
    assert i.linear_acceleration.y == pytest.approx(0.1 * 0.5, abs=0.01)  # centripetal
    assert i.linear_acceleration.z == pytest.approx(9.80665)


@pytest.mark.parametrize("serve", [True, False])
def test_without_listen_the_fleet_protocol_shares_the_routers_port(serve: bool, router: str, tmp_path: Any) -> None:
    """rmw_zenohd holds 7447, the port fleet clients know: simd --ros2 then serves the fleet
    protocol through the router (its own with --ros-serve-router) instead of failing on the port."""
    import subprocess

    from clients import FleetClient
    from protocol import FleetError
    from protocol.errors import ErrorCode
    from tests.conftest import ROOT, free_port, simd_command

    endpoint = f"tcp/127.0.0.1:{free_port()}" if serve else router
    args = ["--ros2", "--ros-router", endpoint] + (["--ros-serve-router"] if serve else [])
    log = tmp_path / "simd.log"
    with log.open("w") as out:
        proc = subprocess.Popen(simd_command(*args), stdout=out, stderr=subprocess.STDOUT, text=True, cwd=ROOT)
    tool = None
    try:
        deadline = time.monotonic() + 20
        while True:
            assert proc.poll() is None, log.read_text()
            try:
                with FleetClient(endpoint, timeout=1.0) as c:
                    c.spawn("tb3_0", -2.0, -0.5)
                    break
            except FleetError as e:
                if e.code == ErrorCode.ALREADY_EXISTS:
                    break  # an earlier try's spawn went through after its reply timed out
                assert time.monotonic() < deadline, log.read_text()
        tool = StandIn(endpoint)
        tool.wait_graph(lambda g: any(e.namespace == "/tb3_0" for e in g))
        # the graph's tokens arrive in any order: the service's may follow the node's
        assert wait_until(lambda: tool.service_available(*SPAWN), 10.0)
        assert wait_for(tool.subscribe("/tb3_0/odom", "nav_msgs/msg/Odometry"))[0].header.frame_id == "tb3_0/odom"
        assert "fleet protocol through the ROS router" in log.read_text()
    finally:
        if tool is not None:
            tool.close()
        proc.terminate()
        proc.wait(10)
