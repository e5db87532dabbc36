"""Diff-drive control, vectorised over every robot.

It reproduces gazebo_ros_diff_drive at its 30 Hz update rate: each update moves each
wheel's rim speed toward its target by at most ``max_wheel_acceleration * dt`` and snaps
to the target once both wheels are within 0.01 m/s. Commands are first clamped to the
model's limits (the TurtleBot3 firmware does this; the Gazebo plugin does not).

``advance`` and ``report_twist`` are what the simulation calls once per tick; they run in the
compiled ``simd.core._drive`` when it is built (one loop instead of ~60 small numpy operations,
~0.25 ms a tick at 100 robots) and otherwise in the numpy functions here, which are the
reference the compiled loop is tested against (simd/core/native.py).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from fleetcommon.arrays import F64, I64
from simd.core import native

_native, _why = native.load("drive")
_F8, _I8 = np.dtype(np.float64), np.dtype(np.int64)

#: The plugin snaps to the target when both wheels are this close (m/s).
SNAP_TOLERANCE = 0.01


def wheel_targets(v: F64, w: F64, max_v: F64, max_w: F64, separation: F64) -> tuple[F64, F64]:
    """Clamp (v, w) to the limits and turn them into left/right rim speeds."""
    v = np.clip(v, -max_v, max_v)
    w = np.clip(w, -max_w, max_w)
    half = w * separation * 0.5
    return v - half, v + half


def ramp_wheels(
    left: F64, right: F64, left_target: F64, right_target: F64, max_accel: F64, dt: float
) -> tuple[F64, F64]:
    """One plugin update: rim speeds after ``dt`` under the wheel acceleration limit."""
    step = max_accel * dt
    dl = left_target - left
    dr = right_target - right
    snap = (np.abs(dl) < SNAP_TOLERANCE) & (np.abs(dr) < SNAP_TOLERANCE)
    new_left = np.where(snap, left_target, left + np.clip(dl, -step, step))
    new_right = np.where(snap, right_target, right + np.clip(dr, -step, step))
    return new_left, new_right


def body_twist(left: F64, right: F64, separation: F64) -> tuple[F64, F64]:
    """Linear and angular velocity of the base from the rim speeds."""
    return (left + right) * 0.5, (right - left) / separation


def arc_displacement(v: F64, w: F64, yaw: F64, dt: float) -> tuple[F64, F64]:
    """World-frame displacement over ``dt`` along the exact arc of constant (v, w).

    Setting the body's velocity to this chord divided by ``dt`` makes the fixed-step
    integrator land exactly on the closed-form arc when nothing is in the way.
    """
    th = w * dt
    small = np.abs(th) < 1e-9
    safe = np.where(small, 1.0, th)
    # forward and leftward travel in the start-of-step body frame
    fwd = np.where(small, v * dt, v * dt * np.sin(safe) / safe)
    left = np.where(small, v * dt * th * 0.5, v * dt * (1.0 - np.cos(safe)) / safe)
    c, s = np.cos(yaw), np.sin(yaw)
    return fwd * c - left * s, fwd * s + left * c


class DriveColumns(Protocol):
    """The per-robot columns the controller reads and updates (the robot table has them)."""

    last_cmd: I64  # tick of each robot's last command (the watchdog's clock)
    target_v: F64  # commanded twist, zeroed in place by the watchdog
    target_w: F64
    max_v: F64  # the model's limits
    max_w: F64
    sep: F64  # wheel separation
    acc: F64  # wheel acceleration limit at the rim
    wheel_l: F64  # rim speeds, ramped in place
    wheel_r: F64
    yaw: F64  # heading at the start of the tick


def advance(
    tick: int, cmd_timeout: float, dt: float, robots: DriveColumns, *, use_native: bool | None = None
) -> tuple[F64, F64, F64, F64]:
    """One controller update for every robot: returns (v, w, dx, dy), the body twist and the
    world-frame displacement over ``dt``.

    In place: targets older than ``cmd_timeout`` (when > 0) are zeroed (the plugin's
    watchdog), and the wheel speeds ramp. ``use_native`` picks the path (default: compiled
    when built).
    """
    r = robots
    n = len(r.yaw)
    if (_native is not None) if use_native is None else use_native:
        if _native is None:
            raise RuntimeError(f"the compiled drive is not available: {_why}")
        v, w, dx, dy = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
        # read-only inputs are converted as numpy would take them; the targets and wheels are
        # updated in place, so those must already be contiguous float64 (TypeError otherwise)
        asc = np.ascontiguousarray  # (the dtype by position: a call a tick of each costs less)
        _native.advance(
            tick, cmd_timeout, dt, asc(r.last_cmd, _I8), r.target_v, r.target_w, asc(r.max_v, _F8),
            asc(r.max_w, _F8), asc(r.sep, _F8), asc(r.acc, _F8), r.wheel_l, r.wheel_r, asc(r.yaw, _F8), v, w, dx, dy,
        )  # fmt: skip
        return v, w, dx, dy
    if cmd_timeout > 0 and n:
        stale = (tick - r.last_cmd) * dt > cmd_timeout + 1e-9
        r.target_v[stale] = 0.0
        r.target_w[stale] = 0.0
    lt, rt = wheel_targets(r.target_v, r.target_w, r.max_v, r.max_w, r.sep)
    r.wheel_l[:], r.wheel_r[:] = ramp_wheels(r.wheel_l, r.wheel_r, lt, rt, r.acc, dt)
    v, w = body_twist(r.wheel_l, r.wheel_r, r.sep)
    dx, dy = arc_displacement(v, w, r.yaw, dt)
    return v, w, dx, dy


def report_twist(
    dt: float,
    tolerance: float,
    x0: F64,
    y0: F64,
    yaw0: F64,
    x: F64,
    y: F64,
    yaw: F64,
    v: F64,
    w: F64,
    dx: F64,
    dy: F64,
    *,
    use_native: bool | None = None,
) -> tuple[F64, F64, F64, F64]:
    """The twist odometry reports after the physics moved the robots from (x0, y0, yaw0) to
    (x, y, yaw): the wheels' (v, 0, w) when the motion was the free one (within
    ``tolerance`` of (dx, dy, w * dt)), the achieved motion otherwise (pushed, blocked).
    Returns (vx, vy, wz, yaw wrapped to [-pi, pi])."""
    if (_native is not None) if use_native is None else use_native:
        if _native is None:
            raise RuntimeError(f"the compiled drive is not available: {_why}")
        n = len(x)
        vx, vy, wz, out_yaw = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
        asc = np.ascontiguousarray  # (the dtype by position: a call a tick of each costs less)
        _native.report(
            dt, tolerance, asc(x0, _F8), asc(y0, _F8), asc(yaw0, _F8), asc(x, _F8), asc(y, _F8), asc(yaw, _F8),
            asc(v, _F8), asc(w, _F8), asc(dx, _F8), asc(dy, _F8), vx, vy, wz, out_yaw,
        )  # fmt: skip
        return vx, vy, wz, out_yaw
    ax, ay = x - x0, y - y0
    dyaw = np.arctan2(np.sin(yaw - yaw0), np.cos(yaw - yaw0))
    free = (np.abs(ax - dx) < tolerance) & (np.abs(ay - dy) < tolerance) & (np.abs(dyaw - w * dt) < tolerance)
    mid = yaw0 + 0.5 * dyaw
    c, s = np.cos(mid), np.sin(mid)
    vx = np.where(free, v, (ax * c + ay * s) / dt)
    vy = np.where(free, 0.0, (-ax * s + ay * c) / dt)
    wz = np.where(free, w, dyaw / dt)
    return vx, vy, wz, np.arctan2(np.sin(yaw), np.cos(yaw))
