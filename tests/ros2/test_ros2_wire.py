"""Golden tests of the ROS 2 adapter's wire: hashes, keys, tokens, attachments and CDR bytes,
each checked against an independent source (rosbags, rmw_zenoh's documented examples, the
stand-in's own key and token rules)."""

from __future__ import annotations

import math
import struct
from typing import Any

import numpy as np
import pytest
import zenoh.ext
from rosbags.typesys import Stores, get_typestore

from protocol.frames import Transform
from simd.adapters.ros2 import attachment, cdr, gazebo_services, graph, interfaces, tf_cdr
from simd.adapters.ros2.graph import Kind, Node, Qos, Topic
from simd.core.snapshot import TickSnapshot
from tests.ros2 import standin
from tests.ros2.conftest import DATA

MESSAGES = [
    "nav_msgs/msg/Odometry", "sensor_msgs/msg/LaserScan", "sensor_msgs/msg/Imu", "sensor_msgs/msg/JointState",
    "tf2_msgs/msg/TFMessage", "rosgraph_msgs/msg/Clock", "geometry_msgs/msg/Twist", "geometry_msgs/msg/TwistStamped",
    "nav_msgs/msg/OccupancyGrid", "geometry_msgs/msg/PoseWithCovarianceStamped",
]  # fmt: skip
#: published values (rmw_zenoh's design document; `ros2 topic info -v` outputs) and, for the
#: services, values computed by the reference's method and pinned here
PINNED = {
    "std_msgs/msg/String": "df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    "sensor_msgs/msg/LaserScan": "64c191398013af96509d518dac71d5164f9382553fce5c1f8cca5be7924bd828",
    "nav_msgs/msg/Odometry": "3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
    "tf2_msgs/msg/TFMessage": "e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
    "rosgraph_msgs/msg/Clock": "692f7a66e93a3c83e71765d033b60349ba68023a8c689a79e48078bcb5c58564",
    "geometry_msgs/msg/Twist": "9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a",
    "geometry_msgs/msg/TwistStamped": "5f0fcd4f81d5d06ad9b4c4c63e3ea51b82d6ae4d0558f1d475229b1121db6f64",
    "gazebo_msgs/srv/SpawnEntity": "a01b6c5a00d47ced8923b43e9e24764fcaa176d2eac6d88163cdb50a02f6cfb5",
    "gazebo_msgs/srv/DeleteEntity": "81b2eed68ee3a93de5a70a0915b57c51dbed9518da77ca5f0abc47222f1f44a2",
    # what rosidl ships in rcl_interfaces' share/rcl_interfaces/{msg,srv}/*.json (the PyPI wheel
    # ros-rcl-interfaces 2.3.0, Kilted): the parameter services, /rosout's and /parameter_events' types
    "rcl_interfaces/srv/DescribeParameters": "845b484d71eb0673dae682f2e3ba3c4851a65a3dcfb97bddd82c5b57e91e4cff",
    "rcl_interfaces/srv/GetParameterTypes": "da199c878688b3e530bdfe3ca8f74cb9fa0c303101e980a9e8f260e25e1c80ca",
    "rcl_interfaces/srv/GetParameters": "bf9803d5c74cf989a5de3e0c2e99444599a627c7ff75f97b8c05b01003675cbc",
    "rcl_interfaces/srv/ListParameters": "3e6062bfbb27bfb8730d4cef2558221f51a11646d78e7bb30a1e83afac3aad9d",
    "rcl_interfaces/srv/SetParameters": "56eed9a67e169f9cb6c1f987bc88f868c14a8fc9f743a263bc734c154015d7e0",
    "rcl_interfaces/srv/SetParametersAtomically": "0e192ef259c07fc3c07a13191d27002222e65e00ccec653ca05e856f79285fcd",
    "rcl_interfaces/msg/Log": "e28ce254ca8abc06abf92773b74602cdbf116ed34fbaf294fb9f81da9f318eac",
    "rcl_interfaces/msg/ParameterEvent": "043e627780fcad87a22d225bc2a037361dba713fca6a6b9f4b869a5aa0393204",
}
#: simulation_interfaces' changed services: 1.x (computed, docs' table) and 2.x (computed; the
#: wire audit's ends of the hashes of branch main)
SIMULATION_1 = {
    "SpawnEntity": "d4c086345d4194a5fc4c9ae45095736ca4062b5cdac4d06a42dec93d683e03cf",
    "SetEntityState": "ca210e7d2b66629ae133c8e1edf5246e618106d75c78ed0556c0e7a33c59ee5e",
    "GetSpawnables": "3bc0266bf8236058ff589c44512e013afe4f295427c39d44cff363d1c956bf36",
}
SIMULATION_2_ENDS = {"SpawnEntity": ("66860313", "a7"), "SetEntityState": ("fba636c9", "ac"),
                     "GetSpawnables": ("3e25fd82", "2a")}  # fmt: skip
JAZZY = get_typestore(Stores.ROS2_JAZZY)


# -- hashes, keys, tokens, attachments -----------------------------------------------------------


@pytest.mark.parametrize("typename", [*MESSAGES, "gazebo_msgs/srv/SpawnEntity", "gazebo_msgs/srv/DeleteEntity"])
def test_type_hashes_agree_with_the_stand_in(typename: str) -> None:
    assert interfaces.type_hash(typename, "jazzy") == standin.type_hash(typename)
    assert interfaces.type_hash(typename, "humble") == "TypeHashNotSupported"


@pytest.mark.parametrize("distro", ["jazzy", "kilted", "lyrical", "rolling"])
def test_each_distro_gets_its_simulation_interfaces_and_nav2(distro: str) -> None:
    """1.x up to Kilted, 2.x from Lyrical: the hashes of the three services that changed, and of
    every other served type, equal the stand-in's (its own IDL of that distro)."""
    two = distro in ("lyrical", "rolling")
    for srv, digest in SIMULATION_1.items():
        ours = interfaces.type_hash(f"simulation_interfaces/srv/{srv}", distro)
        if two:
            head, tail = SIMULATION_2_ENDS[srv]
            assert ours.startswith(f"RIHS01_{head}") and ours.endswith(tail), ours
        else:
            assert ours == f"RIHS01_{digest}"
    served = [*interfaces.SIMULATION_SERVICES, *interfaces.PARAMETER_SERVICES, "rcl_interfaces/msg/Log"]
    served += [f"{interfaces.NAVIGATE_TO_POSE}_{p}" for p in ("SendGoal", "GetResult", "FeedbackMessage")]
    for typename in served:
        assert interfaces.type_hash(typename, distro) == standin.type_hash(typename, distro), typename
    feedback = f"{interfaces.NAVIGATE_TO_POSE}_FeedbackMessage"
    assert (interfaces.type_hash(feedback, distro) == interfaces.type_hash(feedback, "jazzy")) is not two


@pytest.mark.parametrize(("typename", "digest"), PINNED.items())
def test_pinned_hashes(typename: str, digest: str) -> None:
    assert interfaces.rihs01(typename) == f"RIHS01_{digest}"


def test_the_design_documents_service_example_through_our_own_path() -> None:
    """AddTwoInts: catches rosbags' char client_gid in ServiceEventInfo, which breaks every service hash."""
    store = interfaces._hashing_store()
    store.register(
        interfaces.service_definitions(
            "example_interfaces/srv/AddTwoInts", "int64 a\nint64 b", "int64 sum", with_event=True
        )
    )
    assert interfaces.rihs01("example_interfaces/srv/AddTwoInts", store) == (
        "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a"
    )
    assert standin.type_hash("example_interfaces/srv/AddTwoInts") == interfaces.rihs01(
        "example_interfaces/srv/AddTwoInts", store
    )


def test_keys() -> None:
    assert Topic("/chatter", "std_msgs/msg/String", 0, "jazzy").key == (
        "0/chatter/std_msgs::msg::dds_::String_/RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
    )  # design.md's example
    for name, typename in [
        ("/tb3_0/scan", "sensor_msgs/msg/LaserScan"),
        ("/spawn_entity", "gazebo_msgs/srv/SpawnEntity"),
    ]:
        for distro in interfaces.DISTROS:
            assert Topic(name, typename, 3, distro).key == standin.key(3, name, typename, distro)
    assert Topic("/x", "gazebo_msgs/srv/SpawnEntity", 0, "humble").key == (
        "0/x/gazebo_msgs::srv::dds_::SpawnEntity_/TypeHashNotSupported"
    )


def test_tokens_parse_as_the_graph_cache_reads_them() -> None:
    node = Node(domain=5, zid="ab12", node_id=7, namespace="/tb3_0", name="turtlebot3_laserscan")
    n = standin.parse_token(node.token())
    assert (n.kind, n.node_fqn, n.zid, n.node_id, n.entity_id) == (
        "NN",
        "/tb3_0/turtlebot3_laserscan",
        "ab12",
        "7",
        "7",
    )
    assert node.token() == "@ros2_lv/5/ab12/7/7/NN/%/%tb3_0/turtlebot3_laserscan"
    topic = Topic("/tb3_0/scan", "sensor_msgs/msg/LaserScan", 5, "jazzy")
    e = standin.parse_token(node.entity_token(9, Kind.PUBLISHER, topic, graph.SCAN_QOS))
    assert (e.kind, e.topic, e.type, e.hash) == ("MP", "/tb3_0/scan", "sensor_msgs::msg::dds_::LaserScan_", topic.hash)
    assert standin.parse_qos(e.qos) == standin.QosProfile(reliability=1, durability=2, depth=5)
    root = Node(domain=0, zid="ab12", node_id=1, namespace="/", name="fleetsim")
    assert standin.parse_token(root.token()).namespace == "/"
    assert graph.ROSOUT_QOS.chunk() == ":1:,1000:,:10,0:,,"  # rcl's rosout: lifespan 10 s, 0 ns


#: rmw_zenoh's qos_to_keyexpr leaves out what equals its defaults (reliable, volatile, keep last,
#: depth 42, infinite durations): the chunks the audit of our wire expected (ros2-wire-audit M4)
QOS_CHUNKS = [
    (graph.ODOM_QOS, "::,1:,:,:,,"),  # reliable, volatile, keep last 1
    (graph.TF_STATIC_QOS, ":1:,1:,:,:,,"),  # transient local
    (graph.CLOCK_QOS, "2::,1:,:,:,,"),  # best effort
    (graph.SERVICE_QOS, "::,10:,:,:,,"),
    (Qos(depth=42), "::,:,:,:,,"),  # every field rmw_zenoh's default
    (Qos(depth=7, reliable=False, transient_local=True), "2:1:,7:,:,:,,"),
]


@pytest.mark.parametrize(("qos", "chunk"), QOS_CHUNKS)
def test_qos_chunks_are_written_as_rmw_zenoh_writes_them(qos: Qos, chunk: str) -> None:
    assert qos.chunk() == chunk
    profile = standin.parse_qos(chunk)
    assert (profile.reliability, profile.durability, profile.history, profile.depth) == (
        1 if qos.reliable else 2, 1 if qos.transient_local else 2, 1, qos.depth
    )  # fmt: skip
    assert profile.deadline == profile.lifespan == profile.lease == standin.INFINITE and profile.liveliness == 1


@pytest.mark.parametrize(
    ("short", "explicit"),
    [("::,1:,:,:,,", "1:2:1,1:,:,:,,"), (":1:,1:,:,:,,", "1:1:1,1:,:,:,,"), ("2::,1:,:,:,,", "2:2:1,1:,:,:,,"),
     ("::,:,:,:,,", "1:2:1,42:9223372036,854775807:9223372036,854775807:1,9223372036,854775807")],
)  # fmt: skip
def test_elided_and_explicit_qos_chunks_are_one_profile(short: str, explicit: str) -> None:
    """keyexpr_to_qos reads an empty field as the default: our older tokens meant what the new ones say."""
    assert standin.parse_qos(short) == standin.parse_qos(explicit)


@pytest.mark.parametrize("chunk", ["::,1:,:,:,", "::1:,:,:,,", "7::,1:,:,:,,", "::,-1:,:,:,,", "::,x:,:,:,,", ""])
def test_qos_chunks_rmw_zenoh_would_not_read_are_refused_by_the_stand_in(chunk: str) -> None:
    with pytest.raises(ValueError):
        standin.parse_qos(chunk)


def test_attachment_is_rmw_zenohs_33_bytes() -> None:
    gid = bytes(range(16))
    raw = attachment.encode(42, gid, stamp_ns=1_700_000_000_123)
    assert raw == zenoh.ext.z_serialize((zenoh.ext.Int64(42), zenoh.ext.Int64(1_700_000_000_123), gid)).to_bytes()
    assert attachment.decode(raw) == attachment.Attachment(42, 1_700_000_000_123, gid)
    with pytest.raises(ValueError):
        attachment.decode(raw[:-1])


def test_older_rmw_zenohs_attachment_is_read_and_echoed_in_its_format() -> None:
    """Jazzy 0.2.0-0.2.3 (attachment_helpers.cpp): each value after its name, zenoh-ext serialized."""
    gid = bytes(range(16, 32))
    values = ("sequence_number", zenoh.ext.Int64(7), "source_timestamp", zenoh.ext.Int64(1_700_000_000_000),
              "source_gid", gid)  # fmt: skip
    raw = zenoh.ext.z_serialize(values).to_bytes()
    att = attachment.decode(raw)
    assert att == attachment.Attachment(7, 1_700_000_000_000, gid, legacy=True)
    assert attachment.encode_legacy(7, gid, 1_700_000_000_000) == raw
    reply = attachment.echo(att)
    assert standin.read_legacy_attachment(reply) == (7, gid)  # what the older client's parser reads
    current = attachment.decode(attachment.echo(attachment.decode(attachment.encode(3, gid))))
    assert (current.sequence, current.gid, current.legacy) == (3, gid, False)
    for bad in (raw[:-1], raw.replace(b"source_gid", b"source_GID"), b"\x0fsequence_number" + bytes(61)):
        with pytest.raises(ValueError):
            attachment.decode(bad)


def test_the_legacy_notice_says_it_once_per_sender(caplog: pytest.LogCaptureFixture) -> None:
    notice = attachment.LegacyNotice()
    old_a, old_b = (attachment.Attachment(1, 0, bytes([i]) * 16, legacy=True) for i in (1, 2))
    with caplog.at_level("WARNING"):
        for att in (old_a, old_a, old_b, attachment.Attachment(1, 0, bytes(16)), old_a):
            notice.note(att, "/TB3_1/cmd_vel")
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 2 and notice.count == 4
    assert lines[0].startswith("/TB3_1/cmd_vel: an older rmw_zenoh")
    assert "jazzy >= 0.2.4, humble >= 0.1.2, kilted >= 0.6.0, rolling >= 0.6.0" in lines[0]


# -- CDR bytes --------------------------------------------------------------------------------


def _t(typename: str, /, **kw: Any) -> Any:
    return JAZZY.types[typename](**kw)


def _header(t: float, frame: str) -> object:
    sec, ns = cdr.stamp(t)
    return _t("std_msgs/msg/Header", stamp=_t("builtin_interfaces/msg/Time", sec=sec, nanosec=ns), frame_id=frame)


def _v3(x: float, y: float, z: float) -> object:
    return _t("geometry_msgs/msg/Vector3", x=float(x), y=float(y), z=float(z))


def _q(yaw: float) -> object:
    return _t("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))


def _ref(message: object, typename: str) -> bytes:
    return bytes(JAZZY.serialize_cdr(message, typename))


NAMES = ["tb3_0", "a", "robot_with_a_long_name_17", "ab"]  # strings of every length mod 4


def _snapshot(tick: int = 371) -> TickSnapshot:
    rng = np.random.default_rng(tick)
    n = len(NAMES)
    return TickSnapshot(
        tick=tick, time=tick / 30, namespaces=NAMES, x=rng.normal(size=n), y=rng.normal(size=n),
        yaw=rng.uniform(-3, 3, n), linear_x=rng.normal(size=n), linear_y=rng.normal(size=n) * 0.01,
        angular_z=rng.normal(size=n), scan_namespaces=[], scan_rows=np.zeros((0, 360), np.float32),
    )  # fmt: skip


@pytest.mark.parametrize("ticks_rows", [[(371, [3, 0, 2, 1])], [(5, [0, 1, 2, 3]), (6, [0, 1, 2, 3]), (7, [2, 0])]])
def test_odometry_bytes_equal_rosbags(ticks_rows: list[tuple[int, list[int]]]) -> None:
    """Laid out once and reused while the robots stay the same, laid out again when they change."""
    diag = (1e-5, 1e-5, 1e12, 1e12, 1e12, 1e-3)
    enc = cdr.OdometryCdr(diag)
    for tick, rows in ticks_rows:
        _check_odometry(enc, _snapshot(tick), rows, diag)


def _check_odometry(enc: cdr.OdometryCdr, snap: TickSnapshot, rows: list[int], diag: tuple[float, ...]) -> None:
    cov = np.diag(diag).ravel()
    out = enc.encode(snap, rows)
    for payload, i in zip(out, rows, strict=True):
        ns = NAMES[i]
        ref = _t(
            "nav_msgs/msg/Odometry",
            header=_header(snap.time, f"{ns}/odom"),
            child_frame_id=f"{ns}/base_footprint",
            pose=_t("geometry_msgs/msg/PoseWithCovariance", covariance=cov,
                    pose=_t("geometry_msgs/msg/Pose", position=_t("geometry_msgs/msg/Point", x=snap.x[i], y=snap.y[i],
                                                                   z=0.0), orientation=_q(snap.yaw[i]))),
            twist=_t("geometry_msgs/msg/TwistWithCovariance", covariance=cov,
                     twist=_t("geometry_msgs/msg/Twist", linear=_v3(snap.linear_x[i], snap.linear_y[i], 0),
                              angular=_v3(0, 0, snap.angular_z[i]))),
        )  # fmt: skip
        assert payload == _ref(ref, "nav_msgs/msg/Odometry")
        assert payload[:4] == b"\x00\x01\x00\x00"


def _odom_columns(snap: TickSnapshot, rows: list[int]) -> tf_cdr.PoseColumns:
    idx = np.asarray(rows)
    return snap.x[idx], snap.y[idx], snap.yaw[idx]


def _transform(t: float, parent: str, child: str, x: float, y: float, yaw: float) -> Any:
    return _t("geometry_msgs/msg/TransformStamped", header=_header(t, parent), child_frame_id=child,
              transform=_t("geometry_msgs/msg/Transform", translation=_v3(x, y, 0), rotation=_q(yaw)))  # fmt: skip


def test_tf_bytes_equal_rosbags() -> None:
    """The fleet's /tf: every robot's odom -> base_footprint, prefixed; laid out again when the robots change."""
    enc = tf_cdr.FleetTfCdr(lambda ns: [(f"{ns}/odom", f"{ns}/base_footprint")])
    for tick, rows in [(1, [2, 0, 3]), (2, [2, 0, 3]), (3, [0, 1, 2, 3]), (4, [1])]:
        snap = _snapshot(tick)
        names = tuple(NAMES[i] for i in rows)
        ref = [_transform(snap.time, f"{NAMES[i]}/odom", f"{NAMES[i]}/base_footprint", snap.x[i], snap.y[i],
                          snap.yaw[i]) for i in rows]  # fmt: skip
        ours = enc.encode(snap.time, names, [_odom_columns(snap, rows)])
        assert ours == _ref(_t("tf2_msgs/msg/TFMessage", transforms=ref), "tf2_msgs/msg/TFMessage")


def test_tf_with_map_to_odom_equals_rosbags() -> None:
    """With localization each robot has two transforms, map -> odom first (frames of every length mod 4)."""
    enc = tf_cdr.FleetTfCdr(lambda ns: [("map", f"{ns}/odom"), (f"{ns}/odom", f"{ns}/base_footprint")])
    snap = _snapshot(9)
    rows = [3, 1, 0, 2]
    names = tuple(NAMES[i] for i in rows)
    rng = np.random.default_rng(3)
    corr = (rng.normal(size=4), rng.normal(size=4), rng.uniform(-3, 3, 4))
    ref = []
    for k, i in enumerate(rows):
        ref.append(_transform(snap.time, "map", f"{NAMES[i]}/odom", corr[0][k], corr[1][k], corr[2][k]))
        ref.append(_transform(snap.time, f"{NAMES[i]}/odom", f"{NAMES[i]}/base_footprint", snap.x[i], snap.y[i],
                              snap.yaw[i]))  # fmt: skip
    ours = enc.encode(snap.time, names, [corr, _odom_columns(snap, rows)])
    assert ours == _ref(_t("tf2_msgs/msg/TFMessage", transforms=ref), "tf2_msgs/msg/TFMessage")


@pytest.mark.parametrize("frames", [[("odom", "base_footprint")], [("map", "odom"), ("odom", "base_footprint")],
                                    [("a", "bcdef")]])  # fmt: skip
def test_each_robots_own_tf_equals_rosbags(frames: list[tuple[str, str]]) -> None:
    """/<ns>/tf: one message per robot, unprefixed frames, laid out again when the count changes."""
    enc = tf_cdr.RobotTfCdr(frames)
    for tick, rows in [(1, [0, 1, 2, 3]), (2, [0, 1, 2, 3]), (3, [2])]:
        snap = _snapshot(tick)
        odom = _odom_columns(snap, rows)
        poses = [(odom[0] + k, odom[1] - k, odom[2] * (k + 1)) for k in range(len(frames))]
        out = enc.encode(snap.time, poses)
        assert len(out) == len(rows)
        for j, payload in enumerate(out):
            ref = [_transform(snap.time, parent, child, poses[k][0][j], poses[k][1][j], poses[k][2][j])
                   for k, (parent, child) in enumerate(frames)]  # fmt: skip
            assert payload == _ref(_t("tf2_msgs/msg/TFMessage", transforms=ref), "tf2_msgs/msg/TFMessage")
    assert enc.encode(1.0, [(np.zeros(0), np.zeros(0), np.zeros(0))] * len(frames)) == []


def test_map_to_odom_takes_the_odometry_onto_the_truth() -> None:
    rng = np.random.default_rng(5)
    odom = (rng.normal(size=50), rng.normal(size=50), rng.uniform(-3.1, 3.1, 50))
    truth = (rng.normal(size=50), rng.normal(size=50), rng.uniform(-3.1, 3.1, 50))
    mx, my, myaw = tf_cdr.map_to_odom(odom, truth)
    # map -> odom composed with odom -> base is the true pose
    c, s = np.cos(myaw), np.sin(myaw)
    np.testing.assert_allclose(mx + c * odom[0] - s * odom[1], truth[0], atol=1e-12)
    np.testing.assert_allclose(my + s * odom[0] + c * odom[1], truth[1], atol=1e-12)
    np.testing.assert_allclose(np.cos(myaw + odom[2]), np.cos(truth[2]), atol=1e-12)
    np.testing.assert_allclose(np.sin(myaw + odom[2]), np.sin(truth[2]), atol=1e-12)
    np.testing.assert_allclose(np.concatenate(tf_cdr.map_to_odom(odom, odom)), 0.0, atol=1e-12)


def test_unprefixed_frames_of_odometry_scan_and_imu() -> None:
    """Nav2's multi-robot layout: the robot's messages name its frames without the namespace."""
    snap = _snapshot(4)
    payload = cdr.OdometryCdr((1.0,) * 6, prefixed=False).encode(snap, [2])[0]
    o: Any = JAZZY.deserialize_cdr(payload, "nav_msgs/msg/Odometry")
    assert (o.header.frame_id, o.child_frame_id) == ("odom", "base_footprint")
    assert o.pose.pose.position.x == snap.x[2]
    scan = cdr.LaserScanCdr(0.0, 6.28, 6.28 / 359, 0.12, 3.5, 360, prefixed=False)
    s: Any = JAZZY.deserialize_cdr(scan.encode("a", 1.0, np.ones(360, np.float32)), "sensor_msgs/msg/LaserScan")
    assert s.header.frame_id == "base_scan"
    imu: Any = JAZZY.deserialize_cdr(cdr.ImuCdr(prefixed=False).encode("a", 1.0, 0.1, 0.2, 0.3, 0.4),
                                     "sensor_msgs/msg/Imu")  # fmt: skip
    assert imu.header.frame_id == "imu_link"


def test_static_tf_of_several_robots_equals_rosbags() -> None:
    per_robot: list[list[Transform]] = [
        [(f"{ns}/base_footprint", f"{ns}/base_link", (0.0, 0.0, 0.01), (0.0, 0.0, 0.0, 1.0)),
         (f"{ns}/base_link", f"{ns}/base_scan", (-0.032, 0.0, 0.172), (0.0, 0.0, 0.0, 1.0))]
        for ns in NAMES
    ]  # fmt: skip
    blobs = [tf_cdr.transform_elements((0, 0), tfs, first=i == 0) for i, tfs in enumerate(per_robot)]
    ours = tf_cdr.tf_message(sum(len(t) for t in per_robot), blobs)
    ref = [
        _t("geometry_msgs/msg/TransformStamped", header=_header(0.0, parent), child_frame_id=child,
           transform=_t("geometry_msgs/msg/Transform", translation=_v3(*xyz),
                        rotation=_t("geometry_msgs/msg/Quaternion", x=q[0], y=q[1], z=q[2], w=q[3])))
        for tfs in per_robot for parent, child, xyz, q in tfs
    ]  # fmt: skip
    assert ours == _ref(_t("tf2_msgs/msg/TFMessage", transforms=ref), "tf2_msgs/msg/TFMessage")


def test_scan_bytes_equal_rosbags() -> None:
    spec = (0.0, 6.28, 6.28 / 359, 0.12, 3.5, 360)
    enc = cdr.LaserScanCdr(*spec)
    ranges = np.random.default_rng(1).uniform(0.12, 3.5, 360).astype(np.float32)
    ranges[[0, 7]] = [np.inf, -np.inf]
    for ns in NAMES:
        ref = _t(
            "sensor_msgs/msg/LaserScan", header=_header(12.2, f"{ns}/base_scan"), angle_min=0.0, angle_max=6.28,
            angle_increment=6.28 / 359, time_increment=0.0, scan_time=0.0, range_min=0.12, range_max=3.5,
            ranges=ranges, intensities=np.zeros(360, np.float32),
        )  # fmt: skip
        assert enc.encode(ns, 12.2, ranges) == _ref(ref, "sensor_msgs/msg/LaserScan")
    with pytest.raises(ValueError):
        enc.encode("a", 0.0, ranges[:10])


def test_imu_joint_states_and_clock_bytes_equal_rosbags() -> None:
    for ns in NAMES:
        ref = _t(
            "sensor_msgs/msg/Imu", header=_header(3.1, f"{ns}/imu_link"), orientation=_q(0.7),
            orientation_covariance=np.zeros(9), angular_velocity=_v3(0, 0, 0.3),
            angular_velocity_covariance=np.diag([4e-8] * 3).ravel(), linear_acceleration=_v3(0.1, 0.2, cdr.GRAVITY),
            linear_acceleration_covariance=np.diag([2.89e-4] * 3).ravel(),
        )  # fmt: skip
        assert cdr.ImuCdr().encode(ns, 3.1, 0.7, 0.3, 0.1, 0.2) == _ref(ref, "sensor_msgs/msg/Imu")
    joints = _t(
        "sensor_msgs/msg/JointState", header=_header(3.1, ""), name=list(cdr.WHEEL_JOINTS),
        position=np.array([1.5, -2.0]), velocity=np.array([3.0, 4.0]), effort=np.zeros(0),
    )  # fmt: skip
    assert cdr.JointStateCdr().encode(3.1, (1.5, -2.0), (3.0, 4.0)) == _ref(joints, "sensor_msgs/msg/JointState")
    clock = _t("rosgraph_msgs/msg/Clock", clock=_t("builtin_interfaces/msg/Time", sec=3, nanosec=500_000_000))
    assert cdr.clock_cdr(3.5) == _ref(clock, "rosgraph_msgs/msg/Clock")


@pytest.mark.parametrize("little_endian", [True, False])
@pytest.mark.parametrize("frame", ["", "a", "base_link", "abcdefg"])
def test_command_decoders_read_what_rosbags_writes(little_endian: bool, frame: str) -> None:
    tw = _t("geometry_msgs/msg/Twist", linear=_v3(0.2, 0.0, 0.0), angular=_v3(0.0, 0.0, -0.5))
    raw = bytes(JAZZY.serialize_cdr(tw, "geometry_msgs/msg/Twist", little_endian=little_endian))
    assert cdr.decode_twist(raw) == (0.2, -0.5)
    stamped = _t("geometry_msgs/msg/TwistStamped", header=_header(1.0, frame), twist=tw)
    raw = bytes(JAZZY.serialize_cdr(stamped, "geometry_msgs/msg/TwistStamped", little_endian=little_endian))
    assert cdr.decode_twist_stamped(raw) == (0.2, -0.5)


@pytest.mark.parametrize(
    "payload",
    [b"", b"\x00\x01\x00\x00", b"\x07\x07\x00\x00" + bytes(48), b"\x00\x01\x00\x00" + bytes(20),
     b"\x00\x01\x00\x00" + struct.pack("<6d", math.nan, 0, 0, 0, 0, 0)],
)  # fmt: skip
def test_bad_twists_are_refused(payload: bytes) -> None:
    with pytest.raises(cdr.CdrError):
        cdr.decode_twist(payload)


def test_bad_twist_stamped_is_refused() -> None:
    for payload in [b"\x00\x01\x00\x00" + bytes(8) + struct.pack("<I", 1_000_000), b"\x00\x01\x00\x00" + bytes(12)]:
        with pytest.raises(cdr.CdrError):
            cdr.decode_twist_stamped(payload)


# -- the spawner's requests -------------------------------------------------------------------


@pytest.mark.parametrize(
    ("xml", "model"),
    [
        ((DATA / "turtlebot3_burger.sdf").read_text(), "burger"),
        ((DATA / "turtlebot3_waffle.urdf").read_text(), "waffle"),
        ("<sdf version='1.7'><model name='turtlebot3_waffle_pi'/></sdf>", "waffle_pi"),
        ("<robot name='turtlebot3_burger'/>", "burger"),
        ("<sdf version='1.7'><world name='w'><model name='waffle'/></world></sdf>", "waffle"),
    ],
)
def test_models_are_recognised_from_sdf_and_urdf(xml: str, model: str) -> None:
    assert gazebo_services.model_of(xml) == model


@pytest.mark.parametrize(
    ("xml", "start"),
    [
        ("<sdf><model", "Failed to parse XML string"),
        ("not xml at all", "Failed to parse XML string"),
        ("<sdf version='1.6'/>", "Failed to find a model or light on SDF"),
        ("<sdf version='1.6'><model name='turtlebot4'/></sdf>", "fleetsim simulates the TurtleBot3"),
        ("<robot name='pr2'/>", "fleetsim simulates the TurtleBot3"),
        ("<a>" + "x" * (gazebo_services.MAX_XML_BYTES + 1) + "</a>", "Failed to parse XML string: the xml is larger"),
    ],
)
def test_other_xml_is_refused_with_a_clear_message(xml: str, start: str) -> None:
    with pytest.raises(gazebo_services.Refused) as e:
        gazebo_services.model_of(xml)
    assert str(e.value).startswith(start)
    assert len(str(e.value)) < gazebo_services.QUOTE_CHARS + 300  # a huge xml is not echoed whole


@pytest.mark.parametrize("yaw", [0.0, 0.5, -1.2, 3.0, -3.0])
def test_yaw_from_quaternion(yaw: float) -> None:
    assert gazebo_services.yaw_of(0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)) == pytest.approx(yaw)
    assert gazebo_services.yaw_of(0.0, 0.0, 0.0, 0.0) == 0.0


def test_the_map_message_is_the_world_drawn_as_rosbags_reads_it() -> None:
    from simd.adapters.ros2.localization import occupancy_grid
    from simd.core.worldfile import load_world
    from simd.nav.costmap import Grid, occupied_cells

    world = load_world("turtlebot3_world")
    grid = Grid.covering(world)
    payload = occupancy_grid(interfaces.typestore("jazzy"), world, 12.5, grid)
    assert payload[:4] == b"\x00\x01\x00\x00"
    m: Any = JAZZY.deserialize_cdr(payload, "nav_msgs/msg/OccupancyGrid")
    assert (m.header.frame_id, m.header.stamp.sec, m.header.stamp.nanosec) == ("map", 12, 500_000_000)
    assert (m.info.width, m.info.height) == (grid.width, grid.height)
    assert m.info.resolution == pytest.approx(grid.resolution)
    assert (m.info.origin.position.x, m.info.origin.position.y, m.info.origin.orientation.w) == (-3.5, -3.6, 1.0)
    cells = np.asarray(m.data).reshape(grid.height, grid.width)
    np.testing.assert_array_equal(cells, np.where(occupied_cells(world, grid), 100, 0))


def test_the_cli_knows_the_distros_the_adapter_serves() -> None:
    from simd.cli import ROS_DISTROS

    assert ROS_DISTROS == interfaces.DISTROS
    assert set(interfaces.CMD_VEL_DEFAULT) == set(interfaces.SIMULATION_INTERFACES) == set(interfaces.DISTROS)
