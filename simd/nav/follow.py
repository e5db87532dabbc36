"""Path following for every navigating robot at once: where each stands on its path, and the
command that takes it on.

The control law is a regulated pure pursuit, as Nav2's default controller for diff-drive
robots: steer for a point ``LOOKAHEAD_M`` further along the path; turn in place first when
that point is more than ``ROTATE_ABOVE_RAD`` off the heading (a TurtleBot3 turns on the spot,
and a path through a one-cell aisle has right angles), or back up to it when it is a few
centimetres behind; slow down in tight curves and so as to
stop, at the wheels' acceleration, before the end of what the robot may drive (the goal, the
cells its traffic claims reach, or the nearest obstacle its lidar sees). Commands stay within
the model's limits; the simulation's diff-drive then ramps the wheels at their acceleration.

Each robot follows a short polyline: from where it stands through the centres of the cells
it holds ahead (simd/nav/traffic.py), so every robot's pursuit point is found for the whole
fleet at once with a few numpy operations.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fleetcommon.arrays import F64

LOOKAHEAD_M = 0.2
#: turn in place when the pursuit point is further off the heading than this
ROTATE_ABOVE_RAD = 0.6
#: the deceleration commands plan with (the wheels manage 1 m/s^2; commands change at 10 Hz)
PLAN_DECEL = 0.5
#: the angular deceleration turns plan with (rad/s^2)
PLAN_ANGULAR_DECEL = 4.0
#: pure pursuit's regulation: below this turning radius the speed is scaled down
REGULATE_RADIUS_M = 0.25
#: on an open floor, an aim behind the robot and nearer than this is backed into, not turned round for
BACK_WITHIN_M = 0.1


def along(px: F64, py: F64, lookahead: float) -> tuple[F64, F64, F64]:
    """For short polylines, one per row of ``px``/``py`` (n, k; the robot's position first,
    rows padded by repeating their last point): the point ``lookahead`` along each (or its
    end), and each one's length (the room to drive)."""
    dx, dy = np.diff(px, axis=1), np.diff(py, axis=1)
    seg = np.hypot(dx, dy)
    cum = np.concatenate([np.zeros((len(px), 1)), np.cumsum(seg, axis=1)], axis=1)
    room = cum[:, -1]
    s = np.minimum(lookahead, room)
    # the segment holding distance s of each row
    j = np.clip((cum[:, 1:] < s[:, None]).sum(axis=1), 0, seg.shape[1] - 1) if seg.shape[1] else np.zeros(len(px), int)
    rows = np.arange(len(px))
    if seg.shape[1] == 0:
        return px[:, 0], py[:, 0], room
    length = seg[rows, j]
    t = np.where(length > 0, (s - cum[rows, j]) / np.where(length > 0, length, 1.0), 0.0)
    ax = px[rows, j] + t * dx[rows, j]
    ay = py[rows, j] + t * dy[rows, j]
    return ax, ay, room


def wrap(a: F64) -> F64:
    wrapped: F64 = (a + np.pi) % (2 * np.pi) - np.pi
    return wrapped


@dataclass(frozen=True)
class Limits:
    """Each robot's model limits, as columns."""

    max_v: F64
    max_w: F64


def _arc(alpha: F64, dist: F64, room: F64, limits: Limits) -> tuple[F64, F64]:
    """Speed and turn rate along pure pursuit's arc to a point ``dist`` away and ``alpha`` off
    the direction of travel: the top speed, regulated in tight curves, and so as to stop within
    the room; slower still where the wheels could not turn that curve at speed."""
    curvature = 2.0 * np.sin(alpha) / np.maximum(dist, 1e-6)
    radius = 1.0 / np.maximum(np.abs(curvature), 1e-9)
    v = limits.max_v * np.minimum(1.0, radius / REGULATE_RADIUS_M)
    v = np.minimum(v, np.sqrt(2.0 * PLAN_DECEL * np.maximum(room, 0.0)))
    w = v * curvature
    over = np.abs(w) > limits.max_w
    scale = np.where(over, limits.max_w / np.maximum(np.abs(w), 1e-9), 1.0)
    return v * scale, w * scale


def pursue(
    x: F64,
    y: F64,
    yaw: F64,
    aim_x: F64,
    aim_y: F64,
    room: F64,
    limits: Limits,
    back_within: float = 0.0,
) -> tuple[F64, F64]:
    """The (linear, angular) command of each robot steering for (aim_x, aim_y) with ``room``
    metres it may still drive along its path (0: stop, it may still turn to face the aim).
    An aim behind the robot and nearer than ``back_within`` is backed into: on an open floor
    (``BACK_WITHIN_M``), where turning round for a few centimetres and back again cost a
    TurtleBot3 two seconds each time. In lanes it turns (measured: more goals ended
    ``blocked`` in the 100-robot warehouse when robots backed up there)."""
    dx, dy = aim_x - x, aim_y - y
    dist = np.hypot(dx, dy)
    alpha = wrap(np.arctan2(dy, dx) - yaw)
    alpha = np.where(dist > 1e-6, alpha, 0.0)
    backing = (dist < back_within) & (np.abs(alpha) > np.pi / 2) & (room > 1e-3)
    turn_in_place = (np.abs(alpha) > ROTATE_ABOVE_RAD) & ~backing
    v, w = _arc(np.where(backing, wrap(alpha + np.pi), alpha), dist, room, limits)
    v = np.where(backing, -v, v)
    still = turn_in_place | (room <= 1e-3)
    v, w = np.where(still, 0.0, v), np.where(still, 0.0, w)
    spin = np.sign(alpha) * np.minimum(limits.max_w, np.sqrt(2.0 * PLAN_ANGULAR_DECEL * np.abs(alpha)))
    w = np.where(turn_in_place, spin, w)
    # standing still (no room) but not yet facing the aim: face it, to be ready
    w = np.where((room <= 1e-3) & ~turn_in_place, np.where(np.abs(alpha) > 0.05, spin, 0.0), w)
    return v, w


def turn_to(yaw: F64, target: F64, limits: Limits) -> F64:
    """The angular command that turns each robot in place to ``target``."""
    err = wrap(target - yaw)
    w: F64 = np.sign(err) * np.minimum(limits.max_w, np.sqrt(2.0 * PLAN_ANGULAR_DECEL * np.abs(err)))
    return w
