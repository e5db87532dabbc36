"""What fleet-teleop knows and shows, without any I/O: keys, targets and ramps, the nearest
obstacle of a scan, and the text of its screen.

Same keys and numbers as ``turtlebot3_teleop``: ``w``/``x`` change the linear target by
±0.01 m/s, ``a``/``d`` the angular target by +0.1/−0.1 rad/s, ``s`` or space stop at once
(target and output to zero, no ramp); the arrow keys do the same as w/x/a/d. The output ramps
toward the target by at most 0.005 m/s and 0.05 rad/s per loop iteration. The terminal, the
zenoh session and the 10 Hz loop are in clients/teleop/cli.py.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from protocol.control import RobotRecord
from protocol.messages import LaserScan, Odometry

#: turtlebot3_teleop's steps and smoothing (half a step per loop iteration).
LIN_VEL_STEP = 0.01
ANG_VEL_STEP = 0.1
LIN_RAMP = LIN_VEL_STEP / 2
ANG_RAMP = ANG_VEL_STEP / 2
RATE_HZ = 10.0

#: Odometry older than this is shown as stale (the daemon publishes at 30 Hz while running).
ODOM_STALE_S = 1.0

#: (style class, text) pieces of the screen, as prompt_toolkit's formatted text takes them.
Screen = list[tuple[str, str]]


def _clamp(value: float, limit: float) -> float:
    return max(-limit, min(limit, value))


def _toward(output: float, target: float, slop: float) -> float:
    """turtlebot3_teleop's ``make_simple_profile``: move by at most ``slop``."""
    if target > output:
        return min(target, output + slop)
    if target < output:
        return max(target, output - slop)
    return target


class TeleopState:
    """Targets, ramped output and clamps; one :meth:`tick` per loop iteration.

    Values are rounded to 1e-9 after each change, so 22 presses of ``w`` are exactly 0.22
    rather than 0.22000000000000006.
    """

    def __init__(self, max_linear: float, max_angular: float) -> None:
        self.max_linear = max_linear
        self.max_angular = max_angular
        self.target_linear = 0.0
        self.target_angular = 0.0
        self.linear = 0.0
        self.angular = 0.0

    def set_limits(self, max_linear: float, max_angular: float) -> None:
        self.max_linear, self.max_angular = max_linear, max_angular
        self.target_linear = _clamp(self.target_linear, max_linear)
        self.target_angular = _clamp(self.target_angular, max_angular)
        self.linear = _clamp(self.linear, max_linear)
        self.angular = _clamp(self.angular, max_angular)

    def change_linear(self, delta: float) -> None:
        self.target_linear = round(_clamp(self.target_linear + delta, self.max_linear), 9)

    def change_angular(self, delta: float) -> None:
        self.target_angular = round(_clamp(self.target_angular + delta, self.max_angular), 9)

    def stop(self) -> None:
        """Force stop: target and output to zero at once, no ramp."""
        self.target_linear = self.target_angular = 0.0
        self.linear = self.angular = 0.0

    def press(self, key: str) -> bool:
        """Apply a key (``w x a d s`` or space, or ``up down left right``); False if ignored."""
        match key:
            case "w" | "up":
                self.change_linear(+LIN_VEL_STEP)
            case "x" | "down":
                self.change_linear(-LIN_VEL_STEP)
            case "a" | "left":
                self.change_angular(+ANG_VEL_STEP)
            case "d" | "right":
                self.change_angular(-ANG_VEL_STEP)
            case "s" | " " | "space":
                self.stop()
            case _:
                return False
        return True

    def tick(self) -> tuple[float, float]:
        """Ramp the output one step toward the target; returns the command to publish."""
        self.linear = round(_toward(self.linear, self.target_linear, LIN_RAMP), 9)
        self.angular = round(_toward(self.angular, self.target_angular, ANG_RAMP), 9)
        return self.linear, self.angular


def nearest_obstacle(scan: LaserScan) -> tuple[float, float] | None:
    """(distance m, bearing rad) of the closest return, bearing 0 ahead and positive left.

    The distance is measured from the lidar (``base_scan``), as the scan is. None when
    nothing is within range.
    """
    ranges = scan.ranges_array()
    valid = np.isfinite(ranges) & (ranges >= scan.range_min)
    if not valid.any():
        return None
    i = int(np.argmin(np.where(valid, ranges, np.inf)))
    bearing = scan.angle_min + i * scan.angle_increment
    bearing = (bearing + math.pi) % (2 * math.pi) - math.pi
    return float(ranges[i]), bearing


#: The eight sectors of a bearing, 45° each, centred on ahead, the sides and behind.
_SECTORS = ("ahead", "ahead-left", "left", "behind-left", "behind", "behind-right", "right", "ahead-right")


def describe_bearing(bearing: float) -> str:
    """``-157°`` → ``"-157° (behind-right)"``: the bearing in degrees (positive to the left,
    REP-103) and which of eight 45° sectors it falls in (ahead is -22.5°..+22.5°)."""
    deg = math.degrees(math.atan2(math.sin(bearing), math.cos(bearing)))  # (-180, 180]
    shown = round(deg)
    if shown == -180:
        shown = 180
    k = math.ceil((abs(deg) - 22.5) / 45.0) if abs(deg) > 22.5 else 0  # 0 ahead .. 4 behind
    side = _SECTORS[k] if deg >= 0 or k in (0, 4) else _SECTORS[8 - k]
    return f"{shown:+d}° ({side})"


@dataclass
class Seen:
    """What the zenoh callbacks and the monitor last saw (written by them, read by the UI)."""

    odom: Odometry | None = None
    odom_at: float = 0.0
    nearest: tuple[float, float] | None = None
    scan_at: float = 0.0
    robot_alive: bool = True
    daemon_up: bool = True
    paused: bool = False
    #: A fresh record after the robot came back (new limits); the loop applies it.
    new_record: RobotRecord | None = None


def status(seen: Seen, endpoints: str, namespace: str) -> tuple[str, str]:
    """(style class, text) of the connection line."""
    if not seen.daemon_up:
        return "bad", f"no daemon at {endpoints} - waiting for it"
    if not seen.robot_alive:
        return "warn", f"robot gone - waiting for {namespace} to be spawned again"
    if seen.paused:
        return "warn", "robot alive, simulation paused"
    return "good", "robot alive"


def screen(record: RobotRecord, state: TeleopState, seen: Seen, topic: str, endpoints: str, now: float) -> Screen:
    """The whole screen: connection, target and output, the odometry (stale after
    ``ODOM_STALE_S`` of ``now``), the nearest obstacle, the keys and the limits."""
    style, text = status(seen, endpoints, record.namespace)
    st = state

    def vel(v: float, w: float) -> str:
        return f"{v:+.3f} m/s   {w:+.3f} rad/s"

    out: Screen = [
        ("class:title", f"fleet-teleop {record.name} ({record.model}) -> {topic}  "),
        (f"class:{style}", f"[{text}]\n"),
        ("class:dim", "          linear       angular\n"),
        ("", f"target    {vel(st.target_linear, st.target_angular)}\n"),
        ("", f"output    {vel(st.linear, st.angular)}   cmd_vel at {RATE_HZ:g} Hz\n"),
    ]
    odom = seen.odom
    if odom is None:
        out.append(("class:dim", "actual    (no odometry yet)\npose      (no odometry yet)\n"))
    else:
        tw, p = odom.twist.twist, odom.pose.pose
        yaw = p.orientation.yaw()
        stale = "   (stale)" if now - seen.odom_at > ODOM_STALE_S else ""
        out.append(("", f"actual    {vel(tw.linear.x, tw.angular.z)}   odom{stale}\n"))
        out.append(
            ("", f"pose      x {p.position.x:+.3f} m   y {p.position.y:+.3f} m   "
                 f"yaw {yaw:+.3f} rad ({math.degrees(yaw):+.1f}°)\n")
        )  # fmt: skip
    if seen.scan_at == 0.0:
        out.append(("class:dim", "nearest   (no scan yet)\n"))
    elif seen.nearest is None:
        out.append(("", "nearest   nothing within range\n"))
    else:
        dist, bearing = seen.nearest
        out.append(("", f"nearest   {dist:.2f} m at {describe_bearing(bearing)}\n"))
    out.append(
        ("class:dim", f"w/x ±{LIN_VEL_STEP:g} m/s  a/d ±{ANG_VEL_STEP:g} rad/s  (or arrows)  "
                      "s/space stop  q/Esc/Ctrl-C quit\n"
                      f"limits ±{st.max_linear:g} m/s  ±{st.max_angular:g} rad/s")
    )  # fmt: skip
    return out
