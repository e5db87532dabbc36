"""Lockstep a script can lean on: a step's commands hold for the whole step, a step returns
the observations it is asked for, waits after a step do not hang, and the clock's real-time
factor is right after a resume. All in sim time: nothing here races the wall clock."""

from __future__ import annotations

import queue
from collections.abc import Callable

import msgspec
import numpy as np
import pytest

from clients import FleetClient, wait_until
from protocol import FleetError
from protocol.messages import FleetOdometry
from tests.conftest import Daemon

DT = 1.0 / 30.0


def ramped_distance(speed: float, ticks: int, accel: float = 1.0) -> float:
    """Distance a robot covers from rest in ``ticks`` ticks under the diff-drive plugin's
    wheel ramp (``accel`` m/s² at the rim, snapping to the target within 0.01 m/s)."""
    v, d = 0.0, 0.0
    for _ in range(ticks):
        v = speed if abs(speed - v) < 0.01 else v + min(accel * DT, speed - v)
        d += v * DT
    return d


def test_a_steps_commands_hold_for_the_whole_step(daemon_factory: Callable[..., Daemon]) -> None:
    """30 ticks is 1 s, twice the 0.5 s watchdog: the robot must drive all of it."""
    d = daemon_factory("--lockstep", "--world", "empty", "--no-noise")
    c = d.client()
    c.spawn("a", 0.0, 0.0)
    reply = c.step(30, cmd_vel={"a": (0.2, 0.0)}, observe=["a"])
    x = reply.observations["a"].odom.pose.pose.position.x
    assert x == pytest.approx(ramped_distance(0.2, 30), abs=1e-9)  # 0.183 m (the watchdog cut it to 0.107)
    # the next step without commands: the watchdog counts from the step's last tick
    more = c.step(30, observe=["a"]).observations["a"].odom
    assert more.twist.twist.linear.x == 0.0
    assert more.pose.pose.position.x == pytest.approx(x + 0.2 * 15 * DT, abs=0.02)


def test_a_step_returns_odometry_and_the_latest_scan_of_the_robots_it_names(
    daemon_factory: Callable[..., Daemon],
) -> None:
    d = daemon_factory("--lockstep")
    c = d.client()
    c.spawn("tb3_0", -2.0, -0.5)
    c.spawn("tb3_1", 0.5, -2.0, namespace="second")
    first = c.step(1, observe=["tb3_0", "tb3_1"])
    assert first.ticks_run == 1 and not first.cancelled and first.tick == 1
    assert set(first.observations) == {"tb3_0", "tb3_1"}
    assert first.observations["tb3_0"].scan is None or first.observations["tb3_0"].scan.header.stamp.sec == 0
    reply = c.step(12, cmd_vel={"tb3_0": (0.1, 0.3)}, observe=["tb3_0", "tb3_1"])
    obs = reply.observations["tb3_0"]
    assert obs.odom.header.stamp == reply.clock and obs.odom.header.frame_id == "tb3_0/odom"
    # the odometry of the step's last tick, to the bit, as the robot's own topic carried it
    latest = c.latest_odom("tb3_0")
    assert latest is not None and msgspec.msgpack.encode(latest) == msgspec.msgpack.encode(obs.odom)
    assert obs.scan is not None and obs.scan.header.frame_id == "tb3_0/base_scan"
    scan = c.latest_scan("tb3_0")
    assert scan is not None and scan.header.stamp == obs.scan.header.stamp
    assert np.array_equal(scan.ranges_array(), obs.scan.ranges_array(), equal_nan=True)
    assert reply.observations["tb3_1"].odom.header.frame_id == "second/odom"  # named by name, framed by namespace


def test_observing_a_robot_that_does_not_exist_is_refused_before_any_tick(
    daemon_factory: Callable[..., Daemon],
) -> None:
    d = daemon_factory("--lockstep", "--world", "empty")
    c = d.client()
    c.spawn("a", 0.0, 0.0)
    with pytest.raises(FleetError, match="ghost") as e:
        c.step(5, observe=["a", "ghost"])
    assert e.value.code.value == "not_found" and e.value.field == "observe"
    assert c.clock().tick == 0


def test_waiting_for_odometry_or_a_scan_after_a_step_does_not_hang(daemon_factory: Callable[..., Daemon]) -> None:
    d = daemon_factory("--lockstep")
    c = d.client()
    c.spawn("tb3_0", -2.0, -0.5)
    c.step(7)
    odom = c.wait_odom("tb3_0", timeout=2.0)
    assert round(odom.header.stamp.to_seconds() / DT) == 7
    scan = c.wait_scan("tb3_0", timeout=2.0)
    assert scan.header.stamp.to_seconds() <= 7 * DT and scan.ranges_array().shape == (360,)


def test_the_real_time_factor_is_measured_right_after_a_resume(daemon_factory: Callable[..., Daemon]) -> None:
    d = daemon_factory("--world", "empty")
    c = d.client()
    paused = c.pause()
    assert paused.paused and paused.real_time_factor == 0.0
    resumed = c.resume()
    assert not resumed.paused and resumed.real_time_factor == 1.0  # the target until a tick has run
    tick = resumed.tick
    assert wait_until(lambda: c.clock().tick >= tick + 3, 5.0)
    assert c.clock().real_time_factor > 0.3  # measured over the ticks since the resume, not 0.00


def test_a_packed_step_returns_what_the_messages_say(daemon_factory: Callable[..., Daemon]) -> None:
    """The arrays of a packed step hold, row for row, the odometry and scans the per-robot
    observations carry; a quiet step moves the world as a publishing one does."""
    from clients.api import observed_arrays

    d = daemon_factory("--lockstep")
    c = d.client()
    c.spawn("tb3_0", -2.0, -0.5)
    c.spawn("tb3_1", 0.5, -2.0, namespace="second")
    c.spawn("tb3_2", 0.5, 0.5)
    names = ["tb3_1", "tb3_0", "tb3_2"]
    first = observed_arrays(c.step(1, observe=names, packed=True).packed)  # type: ignore[arg-type]
    assert first.names == names and np.isnan(first.ranges).all() and np.isnan(first.scan_time).all()
    cmds = {"tb3_0": (0.1, 0.3), "second": (0.2, -0.5)}
    c.step(11, cmd_vel=cmds, publish=False)
    reply = c.step(12, cmd_vel=cmds, observe=names, packed=True)
    assert reply.observations == {} and reply.packed is not None
    packed = observed_arrays(reply.packed)
    c.reset()
    c.step(1)  # the same run again, publishing, one message per robot
    c.step(11, cmd_vel=cmds)
    again = c.step(12, cmd_vel=cmds, observe=names).observations
    for k, name in enumerate(names):
        odom, scan = again[name].odom, again[name].scan
        assert scan is not None
        p, t = odom.pose.pose, odom.twist.twist
        assert packed.odom[k, :2].tolist() == [p.position.x, p.position.y]
        assert packed.odom[k, 3:].tolist() == [t.linear.x, t.linear.y, t.angular.z]
        assert packed.odom[k, 2] == pytest.approx(2 * np.arctan2(p.orientation.z, p.orientation.w), abs=1e-12)
        assert packed.scan_time[k] == scan.header.stamp.sec + scan.header.stamp.nanosec * 1e-9
        assert np.array_equal(packed.ranges[k], scan.ranges_array(), equal_nan=True)


def test_a_quiet_step_publishes_nothing(daemon_factory: Callable[..., Daemon]) -> None:
    """Messages of one session arrive in order: if the quiet step had published, its odometry
    would come before the next step's."""
    d = daemon_factory("--lockstep", "--world", "empty")
    c = d.client()
    c.spawn("a", 0.0, 0.0)
    seen: list[int] = []
    with c.on_odom("a", lambda ns, m: seen.append(m.header.stamp.nanosec + m.header.stamp.sec * 10**9)):
        c.step(6, cmd_vel={"a": (0.2, 0.0)}, publish=False)
        last = c.step(1)
        stamp = last.clock.sec * 10**9 + last.clock.nanosec
        assert wait_until(lambda: stamp in seen, 5.0)
    assert seen == [stamp]


def test_a_follower_that_subscribes_and_then_steps_gets_that_step(daemon_factory: Callable[..., Daemon]) -> None:
    """zenoh tells the daemon that somebody subscribed through a listener, a moment after it
    knows: under load the step that followed a subscription could run before that news, and
    its tick went unsent (5 times in 200 with six busy processes beside; fleet-map --explore
    then drew another map). A step asks zenoh again first."""
    d = daemon_factory("--lockstep", "--world", "empty")
    d.client().spawn("a", 0.0, 0.0)
    missed = []
    for _ in range(40):  # each a fresh follower: its subscription, then at once its step
        with FleetClient(d.endpoint, prefix=d.prefix, timeout=3.0) as follower:
            got: queue.Queue[FleetOdometry] = queue.Queue()
            follower.on_fleet_odom(got.put)
            stepped = follower.step(1)
            try:
                odom = got.get(timeout=5.0)
            except queue.Empty:
                missed.append(stepped.tick)
                continue
            assert odom.stamp == stepped.clock
    assert missed == []


def test_commands_as_arrays_drive_as_cmd_vel_does_and_bad_ones_are_refused(
    daemon_factory: Callable[..., Daemon],
) -> None:
    d = daemon_factory("--lockstep", "--world", "empty")
    c = d.client()
    c.spawn("a", 0.0, 0.0)
    c.spawn("b", 1.0, 1.0)
    by_dict = c.step(20, cmd_vel={"a": (0.2, 0.4), "b": (-0.1, 1.0)}, observe=["a", "b"], packed=True)
    c.reset()
    values = np.array([[-0.1, 1.0], [0.2, 0.4]])
    by_arrays = c.step(20, commands=(["b", "a"], values), observe=["a", "b"], packed=True)
    assert by_dict.packed is not None and by_arrays.packed is not None
    assert by_arrays.packed.odom == by_dict.packed.odom  # the same bytes
    assert c.clock().tick == 20
    bad = [
        ((["a"], np.array([[np.nan, 0.0]])), "non_finite", "'a' is not finite"),
        ((["ghost"], np.array([[0.1, 0.0]])), "not_found", "'ghost'"),
    ]
    for commands, code, words in bad:
        with pytest.raises(FleetError, match=words) as e:
            c.step(5, commands=commands)
        assert e.value.code.value == code and e.value.field == "commands"
    with pytest.raises(FleetError, match="'a' more than once") as twice:
        c.step(5, commands=(["a", "a"], np.zeros((2, 2))))
    assert twice.value.code.value == "invalid_value"
    with pytest.raises(ValueError, match=r"shape \(2, 2\)"):
        c.step(5, commands=(["a", "b"], np.zeros(3)))
    assert c.clock().tick == 20  # nothing stepped
