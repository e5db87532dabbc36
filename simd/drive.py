"""Diff-drive control, vectorised over every robot.

It reproduces gazebo_ros_diff_drive at its 30 Hz update rate: each update moves each
wheel's rim speed toward its target by at most ``max_wheel_acceleration * dt`` and snaps
to the target once both wheels are within 0.01 m/s. Commands are first clamped to the
model's limits (the TurtleBot3 firmware does this; the Gazebo plugin does not).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]

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
