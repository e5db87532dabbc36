"""fleet-teleop's pure model (clients/teleop/model.py), table by table: keys, clamps, ramps,
the nearest obstacle and its bearing, and the text of the screen (with an injected clock)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from clients.teleop.model import (
    ANG_RAMP,
    LIN_RAMP,
    Seen,
    TeleopState,
    describe_bearing,
    nearest_obstacle,
    screen,
    status,
)
from protocol import LaserScan
from protocol.control import ModelLimits, Pose2D, RobotRecord
from protocol.messages import Odometry, Point, Pose, PoseWithCovariance, Quaternion, Twist, TwistWithCovariance, Vector3

BURGER = (0.22, 2.84)
WAFFLE = (0.26, 1.82)


def press(state: TeleopState, keys: str | list[str]) -> None:
    for k in keys:
        state.press(k)


def test_keys_change_targets_by_teleop_keyboard_steps() -> None:
    s = TeleopState(*BURGER)
    press(s, "www")
    assert (s.target_linear, s.target_angular) == (0.03, 0.0)
    press(s, "x")
    assert s.target_linear == 0.02
    press(s, "aa")
    assert s.target_angular == 0.2  # a turns left (counter-clockwise): positive
    press(s, "ddd")
    assert s.target_angular == -0.1
    press(s, ["up", "up", "left", "down", "right", "right"])
    assert (s.target_linear, s.target_angular) == (0.03, -0.2)
    assert not s.press("k") and not s.press("q")  # ignored, nothing changes
    assert (s.target_linear, s.target_angular) == (0.03, -0.2)
    assert (s.linear, s.angular) == (0.0, 0.0)  # keys move targets only; the loop ramps


@pytest.mark.parametrize(("limits", "w_presses", "a_presses"), [(BURGER, 22, 29), (WAFFLE, 26, 19)])
def test_targets_clamp_to_the_models_limits(limits: tuple[float, float], w_presses: int, a_presses: int) -> None:
    max_v, max_w = limits
    s = TeleopState(max_v, max_w)
    press(s, "w" * (w_presses - 1))
    assert s.target_linear < max_v
    press(s, "w")
    assert s.target_linear == max_v  # exactly, no 0.22000000000000006
    press(s, "w" * 10)
    assert s.target_linear == max_v
    press(s, "x" * 100)
    assert s.target_linear == -max_v
    press(s, "a" * (a_presses - 1))
    assert s.target_angular < max_w
    press(s, "a" * 30)
    assert s.target_angular == max_w
    press(s, "d" * 100)
    assert s.target_angular == -max_w
    s.set_limits(0.1, 1.0)  # a robot that came back as another model
    assert (s.target_linear, s.target_angular) == (-0.1, -1.0)


def test_output_ramps_by_half_a_step_per_loop() -> None:
    s = TeleopState(*BURGER)
    press(s, "wwwww" + "aaa")  # targets 0.05 m/s, 0.3 rad/s
    outputs = [s.tick() for _ in range(12)]
    assert outputs[0] == (LIN_RAMP, ANG_RAMP) == (0.005, 0.05)
    assert outputs[1] == (0.01, 0.1)
    assert outputs[5] == (0.03, 0.3)  # angular reached its target after 6 loops
    assert outputs[9] == outputs[11] == (0.05, 0.3)  # linear after 10, then holds
    press(s, "x" * 10)  # target -0.05: back down through zero, 0.005 per loop
    downs = [s.tick()[0] for _ in range(20)]
    assert downs[0] == 0.045 and downs[9] == 0.0 and downs[19] == -0.05
    assert all(abs(b - a) <= LIN_RAMP + 1e-12 for a, b in zip([0.05, *downs], downs, strict=False))


@pytest.mark.parametrize("key", ["s", " ", "space"])
def test_stop_zeroes_target_and_output_at_once(key: str) -> None:
    s = TeleopState(*BURGER)
    press(s, "w" * 20 + "a" * 10)
    for _ in range(30):
        s.tick()
    assert s.linear > 0.1 and s.angular > 0.9
    assert s.press(key)
    assert (s.target_linear, s.target_angular, s.linear, s.angular) == (0, 0, 0, 0)
    assert s.tick() == (0.0, 0.0)


def scan_with(hits: dict[int, float], range_min: float = 0.12) -> LaserScan:
    ranges = np.full(360, np.inf, dtype="<f4")
    for i, r in hits.items():
        ranges[i] = r
    return LaserScan(
        angle_min=0.0,
        angle_max=6.28,
        angle_increment=6.28 / 359,
        range_min=range_min,
        range_max=3.5,
        ranges=ranges.tobytes(),
    )


def test_nearest_obstacle_bearing_is_relative_to_the_robot() -> None:
    assert nearest_obstacle(scan_with({})) is None
    d, b = nearest_obstacle(scan_with({0: 1.0, 90: 0.5, 200: 2.0})) or (0, 0)
    assert d == 0.5 and math.isclose(b, 90 * 6.28 / 359)  # left
    d, b = nearest_obstacle(scan_with({270: 0.4, 10: 0.9})) or (0, 0)
    assert d == pytest.approx(0.4) and b == pytest.approx(270 * 6.28 / 359 - 2 * math.pi)  # right
    assert nearest_obstacle(scan_with({5: 0.05}, range_min=0.12)) is None  # below range_min
    assert describe_bearing(0.05) == "+3° (ahead)"


@pytest.mark.parametrize(
    ("degrees", "label"),
    [
        (0, "+0° (ahead)"),
        (14, "+14° (ahead)"),
        (-14, "-14° (ahead)"),
        (22.4, "+22° (ahead)"),
        (23, "+23° (ahead-left)"),
        (-45, "-45° (ahead-right)"),
        (67.4, "+67° (ahead-left)"),
        (68, "+68° (left)"),
        (90, "+90° (left)"),
        (-90, "-90° (right)"),
        (-112.4, "-112° (right)"),
        (113, "+113° (behind-left)"),
        (135, "+135° (behind-left)"),
        (-157, "-157° (behind-right)"),  # was "(right)": the example
        (157.4, "+157° (behind-left)"),
        (158, "+158° (behind)"),
        (-170, "-170° (behind)"),
        (180, "+180° (behind)"),
        (-180, "+180° (behind)"),
        (270, "-90° (right)"),  # wrapped into (-180, 180]
        (-300, "+60° (ahead-left)"),
    ],
)
def test_every_bearing_has_the_right_side(degrees: float, label: str) -> None:
    assert describe_bearing(math.radians(degrees)) == label


def test_sides_are_mirror_images() -> None:
    for d in np.arange(-179.5, 180.0, 0.5):
        left = describe_bearing(math.radians(abs(d))).split("(")[1]
        right = describe_bearing(math.radians(-abs(d))).split("(")[1]
        assert left.replace("left", "right") == right, d


def record() -> RobotRecord:
    return RobotRecord(
        name="burger_1", namespace="TB3_1", model="burger", pose=Pose2D(),
        limits=ModelLimits(max_linear_velocity=0.22, max_angular_velocity=2.84, wheel_separation=0.16,
                           wheel_radius=0.033, max_wheel_acceleration=1.0),
    )  # fmt: skip


def odometry(x: float, y: float, yaw: float, v: float, w: float) -> Odometry:
    q = Quaternion.from_yaw(yaw)
    return Odometry(
        pose=PoseWithCovariance(pose=Pose(position=Point(x=x, y=y), orientation=q)),
        twist=TwistWithCovariance(twist=Twist(linear=Vector3(x=v), angular=Vector3(z=w))),
    )


@pytest.mark.parametrize(
    ("seen", "style", "text"),
    [
        (Seen(), "good", "robot alive"),
        (Seen(paused=True), "warn", "robot alive, simulation paused"),
        (Seen(robot_alive=False), "warn", "robot gone - waiting for TB3_1 to be spawned again"),
        (Seen(daemon_up=False, robot_alive=False), "bad", "no daemon at tcp/127.0.0.1:7447 - waiting for it"),
    ],
)
def test_the_connection_line(seen: Seen, style: str, text: str) -> None:
    assert status(seen, "tcp/127.0.0.1:7447", "TB3_1") == (style, text)


def test_the_screen_as_the_readme_shows_it() -> None:
    state = TeleopState(*BURGER)
    for k in "w" * 15 + "aaa":
        state.press(k)
    for _ in range(40):
        state.tick()
    seen = Seen(odom=odometry(-1.8, -0.393, 0.795, 0.15, 0.3), odom_at=10.0, nearest=(0.69, math.radians(-14)),
                scan_at=10.0)  # fmt: skip
    text = "".join(t for _, t in screen(record(), state, seen, "fleet/TB3_1/cmd_vel", "tcp/127.0.0.1:7447", 10.5))
    assert text.splitlines() == [
        "fleet-teleop burger_1 (burger) -> fleet/TB3_1/cmd_vel  [robot alive]",
        "          linear       angular",
        "target    +0.150 m/s   +0.300 rad/s",
        "output    +0.150 m/s   +0.300 rad/s   cmd_vel at 10 Hz",
        "actual    +0.150 m/s   +0.300 rad/s   odom",
        "pose      x -1.800 m   y -0.393 m   yaw +0.795 rad (+45.6°)",
        "nearest   0.69 m at -14° (ahead)",
        "w/x ±0.01 m/s  a/d ±0.1 rad/s  (or arrows)  s/space stop  q/Esc/Ctrl-C quit",
        "limits ±0.22 m/s  ±2.84 rad/s",
    ]


@pytest.mark.parametrize(
    ("seen", "now", "line"),
    [
        (Seen(), 0.0, "actual    (no odometry yet)"),
        (Seen(odom=odometry(0, 0, 0, 0, 0), odom_at=1.0), 1.9, "actual    +0.000 m/s   +0.000 rad/s   odom"),
        (Seen(odom=odometry(0, 0, 0, 0, 0), odom_at=1.0), 2.1, "actual    +0.000 m/s   +0.000 rad/s   odom   (stale)"),
        (Seen(scan_at=0.0), 0.0, "nearest   (no scan yet)"),
        (Seen(scan_at=1.0, nearest=None), 1.0, "nearest   nothing within range"),
    ],
)
def test_screen_lines_for_what_was_seen(seen: Seen, now: float, line: str) -> None:
    text = "".join(t for _, t in screen(record(), TeleopState(*BURGER), seen, "k", "e", now))
    assert line in text.splitlines()
