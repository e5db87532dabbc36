"""fleet-record against a real daemon in lockstep, its bag read back by independent readers (mcap, rosbags)."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader

from tests.conftest import ROOT, Daemon, free_port


def record(daemon: Daemon, out: Path, *args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "clients.record.cli", "-e", daemon.endpoint, "-o", str(out), *args],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # a background shell may ignore it
    )  # fmt: skip


def wait_subscribed(daemon: Daemon, key: str, proc: subprocess.Popen[str]) -> None:
    """Until the recorder's subscription reaches the daemon (no steps may be missed)."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", f'["{daemon.endpoint}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    with zenoh.open(conf) as s:
        probe = s.declare_publisher(key)
        deadline = time.monotonic() + 20
        while not probe.matching_status.matching:  # type: ignore[attr-defined]  # the stub says bool
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "the recorder never subscribed"
            time.sleep(0.05)
        probe.undeclare()


def stop(proc: subprocess.Popen[str]) -> tuple[int, str, str]:
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=30)
    return proc.returncode, out, err


def test_a_lockstep_run_recorded_and_read_back(daemon_factory: Callable[..., Daemon], tmp_path: Path) -> None:
    d = daemon_factory("--lockstep")
    c = d.client()
    c.spawn("burger_1", -2.0, -0.5, namespace="TB3_1")
    c.spawn("waffle_2", 0.5, -2.0, model="waffle", namespace="TB3_2")
    c.spawn("burger_3", 2.0, 0.5, namespace="TB3_3")
    bag = tmp_path / "run"
    proc = record(d, bag, "--robots", "TB3_1,TB3_2")
    wait_subscribed(d, "fleet/odometry", proc)
    wait_subscribed(d, "fleet/scans", proc)
    reply = c.step(90, cmd_vel={"TB3_1": (0.2, 0.5)}, observe=["TB3_1"])
    code, out, err = stop(proc)
    assert code == 0, err
    assert "Traceback" not in err and "fleet-record: wrote" in out

    # the MCAP file as any MCAP reader sees it
    (mcap_file,) = bag.glob("*.mcap")
    with mcap_file.open("rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
        assert {ch.message_encoding for ch in summary.channels.values()} == {"cdr"}
        counts = Counter(summary.channels[ch].topic for ch, n in summary.statistics.channel_message_counts.items()
                         for _ in range(n))  # fmt: skip
        assert "rosbag2" in [m.name for m in reader.iter_metadata()]
    # 90 ticks: odometry, /tf and /clock each tick, scans at 5 Hz, the fixed frames once per robot
    assert counts == {"/TB3_1/odom": 90, "/TB3_2/odom": 90, "/tf": 90, "/clock": 90,
                      "/TB3_1/scan": 15, "/TB3_2/scan": 15, "/tf_static": 2}  # fmt: skip
    assert (bag / "metadata.yaml").is_file()

    # and as a rosbag2 bag, decoded by rosbags
    with AnyReader([bag]) as r:
        msgs: dict[str, list[Any]] = {}
        times: dict[str, list[int]] = {}
        for conn, t, raw in r.messages():
            msgs.setdefault(conn.topic, []).append(r.deserialize(raw, conn.msgtype))
            times.setdefault(conn.topic, []).append(t)
    odom = msgs["/TB3_1/odom"]
    assert [o.header.stamp.sec * 10**9 + o.header.stamp.nanosec for o in odom] == times["/TB3_1/odom"]
    assert np.allclose(np.diff(times["/TB3_1/odom"]), 1e9 / 30, atol=1)  # one tick apart, sim time
    last = odom[-1]
    expected = reply.observations["TB3_1"].odom
    assert last.pose.pose.position.x == expected.pose.pose.position.x  # the very numbers the daemon had
    assert last.pose.pose.position.y == expected.pose.pose.position.y
    assert (last.header.frame_id, last.child_frame_id) == ("TB3_1/odom", "TB3_1/base_footprint")
    assert last.twist.twist.angular.z == pytest.approx(0.5, abs=0.01)
    assert np.diag(last.pose.covariance.reshape(6, 6)).tolist() == [1e-5, 1e-5, 1e12, 1e12, 1e12, 1e-3]
    scan = msgs["/TB3_2/scan"][-1]
    assert scan.header.frame_id == "TB3_2/base_scan" and len(scan.ranges) == 360
    assert (scan.angle_max - scan.angle_min) / scan.angle_increment + 1 == pytest.approx(360)
    assert {t.child_frame_id for t in msgs["/tf"][0].transforms} == {"TB3_1/base_footprint", "TB3_2/base_footprint"}
    static = {(t.header.frame_id, t.child_frame_id): t.transform.translation
              for m in msgs["/tf_static"] for t in m.transforms}  # fmt: skip
    assert static[("TB3_2/base_link", "TB3_2/base_scan")].x == pytest.approx(-0.064)  # the waffle's lidar
    assert static[("TB3_1/base_link", "TB3_1/base_scan")].x == pytest.approx(-0.032)
    assert math.isclose(
        msgs["/clock"][-1].clock.sec + msgs["/clock"][-1].clock.nanosec * 1e-9, reply.clock.to_seconds()
    )


def test_ticks_that_never_came_are_reported(daemon_factory: Callable[..., Daemon], tmp_path: Path) -> None:
    """Steps that do not publish leave a hole in the bag: fleet-record says how many ticks, as it
    would for ticks zenoh dropped on the way to a recorder too slow for the fleet."""
    d = daemon_factory("--lockstep")
    c = d.client()
    c.spawn("burger_1", -2.0, -0.5)
    bag = tmp_path / "holed"
    proc = record(d, bag, "--topics", "odom")
    wait_subscribed(d, "fleet/odometry", proc)
    c.step(30)
    c.step(12, publish=False)
    c.step(30)
    code, out, err = stop(proc)
    assert code == 0, err
    assert "/burger_1/odom" in out and " 60 messages" in out, out
    assert "fleet-record: 12 ticks of the fleet's odometry did not come" in err, err


def test_bad_requests_are_one_line_and_touch_nothing(daemon: Daemon, tmp_path: Path) -> None:
    taken = tmp_path / "taken"
    taken.mkdir()
    (taken / "mine.txt").write_text("keep me")

    def run(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "clients.record.cli", *args], capture_output=True, text=True,
                              cwd=ROOT, timeout=30)  # fmt: skip

    p = run("-e", daemon.endpoint, "-o", str(taken), "--duration", "1")
    assert p.returncode == 2 and "already exists" in p.stderr
    assert [f.name for f in taken.iterdir()] == ["mine.txt"] and (taken / "mine.txt").read_text() == "keep me"
    p = run("-e", daemon.endpoint, "-o", str(tmp_path / "a"), "--topics", "odom,lidar")
    assert p.returncode == 2 and "lidar" in p.stderr and not (tmp_path / "a").exists()
    p = run("-e", daemon.endpoint, "-o", str(tmp_path / "b"), "--duration", "-1")
    assert p.returncode == 2 and "--duration" in p.stderr
    p = run("-e", f"tcp/127.0.0.1:{free_port()}", "-o", str(tmp_path / "c"), "--timeout", "1")
    assert p.returncode == 3 and "cannot reach" in p.stderr and not (tmp_path / "c").exists()
    assert "Traceback" not in p.stderr
