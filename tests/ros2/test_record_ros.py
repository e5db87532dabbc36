"""fleet-record --source ros: the ROS topics of simd --ros2, recorded off the wire and read back."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import zenoh
from rosbags.highlevel import AnyReader

from tests.conftest import ROOT
from tests.ros2.conftest import RosDomain
from tests.ros2.standin import key, wait_for


def wait_subscribed(router: str, keys: list[str], proc: subprocess.Popen[str]) -> None:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", json.dumps([router]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    with zenoh.open(conf) as s:
        probes = [s.declare_publisher(k) for k in keys]
        deadline = time.monotonic() + 20
        while not all(p.matching_status.matching for p in probes):  # type: ignore[attr-defined]  # stub: bool
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "the recorder never subscribed"
            time.sleep(0.05)
        for p in probes:
            p.undeclare()


def start_recorder(ros: RosDomain, bag: Path, *args: str) -> subprocess.Popen[str]:
    """``fleet-record --source ros`` on the domain's router, writing ``bag`` (SIGINT stops it)."""
    return subprocess.Popen(
        [sys.executable, "-m", "clients.record.cli", "--source", "ros", "--ros-router", ros.router, "-o", str(bag),
         *args],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # fmt: skip


def test_ros_topics_recorded_as_they_came(ros_factory: Callable[..., RosDomain], tmp_path: Path) -> None:
    ros = ros_factory("--lockstep")
    c = ros.daemon.client()
    c.spawn("burger_1", -2.0, -0.5, namespace="TB3_1")
    c.spawn("waffle_2", 0.5, -2.0, model="waffle", namespace="TB3_2")
    bag = tmp_path / "ros_run"
    proc = start_recorder(ros, bag, "--robots", "TB3_1", "--topics", "odom,scan,imu,tf,tf_static,clock")
    keys = [
        key(0, "/TB3_1/odom", "nav_msgs/msg/Odometry"),
        key(0, "/TB3_1/scan", "sensor_msgs/msg/LaserScan"),
        key(0, "/TB3_1/imu", "sensor_msgs/msg/Imu"),
        key(0, "/tf", "tf2_msgs/msg/TFMessage"),
        key(0, "/clock", "rosgraph_msgs/msg/Clock"),
    ]
    wait_subscribed(ros.router, keys, proc)
    fence = ros.tool.subscribe("/TB3_1/odom", "nav_msgs/msg/Odometry")  # another peer of the router
    reply = c.step(60, observe=["TB3_1"])
    end = reply.clock
    wait_for(fence, lambda m: (m[0].header.stamp.sec, m[0].header.stamp.nanosec) == (end.sec, end.nanosec))
    time.sleep(0.2)  # the recorder is a peer of the same router: the last tick reached it too by now
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    assert "Traceback" not in err and "fleet-record: wrote" in out
    counts: Counter[str] = Counter()
    msgs: dict[str, list[Any]] = {}
    with AnyReader([bag]) as r:
        for conn, _, raw in r.messages():
            counts[conn.topic] += 1
            msgs.setdefault(conn.topic, []).append(r.deserialize(raw, conn.msgtype))
    assert counts["/TB3_1/odom"] == 60 and counts["/TB3_1/imu"] == 60 and counts["/tf"] == 60
    assert counts["/TB3_1/scan"] == 10
    assert counts["/clock"] >= 60
    assert "/TB3_2/odom" not in counts  # --robots TB3_1
    last = msgs["/TB3_1/odom"][-1]
    assert last.pose.pose.position.x == reply.observations["TB3_1"].odom.pose.pose.position.x
    static = {(t.header.frame_id, t.child_frame_id) for m in msgs["/tf_static"] for t in m.transforms}
    assert ("TB3_1/base_link", "TB3_1/base_scan") in static  # sent before the recorder started
    assert {t.child_frame_id for t in msgs["/tf"][0].transforms} == {"TB3_1/base_footprint", "TB3_2/base_footprint"}


def test_each_robots_own_transforms_recorded_in_nav2s_layout(
    ros_factory: Callable[..., RosDomain], tmp_path: Path
) -> None:
    """With ``--ros-tf namespaced`` the transforms are each robot's (``/<ns>/tf``): recorded for
    the robots asked, the fixed frames sent before the recorder started too."""
    ros = ros_factory("--lockstep", "--ros-tf", "namespaced")
    c = ros.daemon.client()
    c.spawn("burger_1", -2.0, -0.5, namespace="TB3_1")
    c.spawn("waffle_2", 0.5, -2.0, model="waffle", namespace="TB3_2")
    ros.tool.wait_graph(lambda g: ("/TB3_1/tf_static", "MP") in {(e.topic, e.kind) for e in g})
    bag = tmp_path / "ros_tf"
    proc = start_recorder(ros, bag, "--robots", "TB3_1", "--topics", "odom,tf,tf_static")
    wait_subscribed(ros.router, [key(0, "/TB3_1/odom", "nav_msgs/msg/Odometry")], proc)
    tf1 = ros.tool.subscribe("/TB3_1/tf", "tf2_msgs/msg/TFMessage")  # another peer of the router, as a fence
    reply = c.step(30, observe=["TB3_1"])
    end = reply.clock
    wait_for(tf1, lambda m: (m[0].transforms[0].header.stamp.sec, m[0].transforms[0].header.stamp.nanosec)
             == (end.sec, end.nanosec))  # fmt: skip
    time.sleep(0.2)  # the recorder is a peer of the same router: the last tick reached it too by now
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0 and "fleet-record: wrote" in out, err
    msgs: dict[str, list[Any]] = {}
    with AnyReader([bag]) as r:
        for conn, _, raw in r.messages():
            msgs.setdefault(conn.topic, []).append(r.deserialize(raw, conn.msgtype))
    assert set(msgs) == {"/TB3_1/odom", "/TB3_1/tf", "/TB3_1/tf_static"}  # TB3_2's are not asked for
    assert len(msgs["/TB3_1/tf"]) == 30
    assert {(t.header.frame_id, t.child_frame_id) for t in msgs["/TB3_1/tf"][-1].transforms} == {
        ("odom", "base_footprint")
    }
    static = {(t.header.frame_id, t.child_frame_id) for m in msgs["/TB3_1/tf_static"] for t in m.transforms}
    assert ("base_link", "base_scan") in static  # sent before the recorder started


@pytest.mark.parametrize(
    ("args", "code", "text"),
    [(["--topics", "imu"], 2, "need --source ros"), (["--source", "ros", "--ros-domain-id", "999"], 2, "0..232")],
)
def test_ros_source_flags(args: list[str], code: int, text: str, tmp_path: Path) -> None:
    p = subprocess.run([sys.executable, "-m", "clients.record.cli", "-o", str(tmp_path / "x"), *args],
                       capture_output=True, text=True, cwd=ROOT, timeout=30)  # fmt: skip
    assert p.returncode == code and text in p.stderr and not (tmp_path / "x").exists()


def test_no_router_is_one_line(tmp_path: Path) -> None:
    from tests.conftest import free_port

    p = subprocess.run(
        [sys.executable, "-m", "clients.record.cli", "--source", "ros", "--ros-router", f"tcp/127.0.0.1:{free_port()}",
         "-o", str(tmp_path / "x"), "--timeout", "1"],
        capture_output=True, text=True, cwd=ROOT, timeout=30,
    )  # fmt: skip
    assert p.returncode == 3 and "cannot reach the ROS router" in p.stderr and "Traceback" not in p.stderr
    assert not (tmp_path / "x").exists()
