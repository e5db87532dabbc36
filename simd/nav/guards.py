"""The last guards under the floor's rules, on every command the navigator gives.

The traffic (simd/nav/traffic.py) lets a robot drive only into cells it holds, but a robot
tracks its way with some error, cuts corners, and may be pushed or driven by teleop: before a
command goes out, each robot's body is walked along the way it would go before it could stop
again, and the command is refused (speed 0) if that body would reach into a cell another robot
holds, or bring two robots' circles closer than their margins on the true poses.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from fleetcommon.arrays import F64, I64
from simd.core.robots import RobotTable
from simd.nav.floor import Floor
from simd.nav.robot import NavRobot

#: how far ahead (s, at the commanded speed) a command is checked
GUARD_S = 0.1
#: the deceleration the guard counts on (the wheels manage 1 m/s^2) and its sampling step (m)
GUARD_DECEL, GUARD_STEP_M = 0.8, 0.02
#: no command brings two robots' circumscribed circles closer than this (m) to each other
GUARD_MARGIN_M = 0.02


def would_crowd(
    floor: Floor, driven: list[NavRobot], x: F64, y: F64, yaw: F64, v: F64, v_now: F64
) -> npt.NDArray[np.bool_]:
    """Whether each robot's body, somewhere along the way it goes before it could stop
    again (one control period at the new speed, plus braking from the speed it has now),
    would reach into cells another robot holds: a last guard under the floor's rules."""
    horizon = np.abs(v) * GUARD_S + v_now * GUARD_S + v_now * v_now / (2.0 * GUARD_DECEL)
    out = np.zeros(len(driven), dtype=bool)
    for k in np.flatnonzero(v != 0).tolist():
        ahead = 1.0 if v[k] > 0 else -1.0  # a robot backing up is walked backwards
        c, s = ahead * math.cos(yaw[k]), ahead * math.sin(yaw[k])
        for d in np.arange(GUARD_STEP_M, float(horizon[k]) + GUARD_STEP_M, GUARD_STEP_M).tolist():
            if floor.intrudes(driven[k], float(x[k] + d * c), float(y[k] + d * s)):
                out[k] = True
                break
    return out


def too_close(
    driven: list[NavRobot], rows: I64, table: RobotTable, x: F64, y: F64, yaw: F64, v: F64
) -> npt.NDArray[np.bool_]:
    """Whether each robot, GUARD_S on at its speed (forwards or backwards), would come closer to another robot
    than their two circles with margins allow: the last guard, on the true poses, whatever
    the floor's cells say (a robot that strayed, one pushed, one driven by teleop)."""
    out = np.zeros(len(driven), dtype=bool)
    moving = np.flatnonzero(v != 0)
    if len(moving) == 0 or len(table.x) < 2:
        return out
    ax, ay = table.x, table.y
    reach = 2 * (float(np.max(table.outline[:, :, 0] ** 2 + table.outline[:, :, 1] ** 2)) ** 0.5) + 2 * GUARD_MARGIN_M
    keys = np.floor(ax / reach).astype(np.int64) * 1_000_003 + np.floor(ay / reach).astype(np.int64)
    buckets: dict[int, list[int]] = {}
    for i, key in enumerate(keys.tolist()):
        buckets.setdefault(key, []).append(i)
    step = v * GUARD_S
    for k in moving.tolist():
        i = int(rows[k])
        nx, ny = x[k] + step[k] * math.cos(yaw[k]), y[k] + step[k] * math.sin(yaw[k])
        bx, by = math.floor(x[k] / reach), math.floor(y[k] / reach)
        r_me = driven[k].model.radius + GUARD_MARGIN_M
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                for j in buckets.get((bx + dx) * 1_000_003 + (by + dy), ()):
                    if j == i:
                        continue
                    need = r_me + float(np.hypot(*table.outline[j].T).max()) + GUARD_MARGIN_M
                    now_d = math.hypot(ax[j] - x[k], ay[j] - y[k])
                    next_d = math.hypot(ax[j] - nx, ay[j] - ny)
                    if next_d < need and next_d < now_d:
                        out[k] = True
    return out
