"""Correlative scan matching: where, near a guess, a scan fits the map best.

Odometry that drifts (a real robot's, or ``simd --odom-noise``) would smear a map built at the
odometry's poses. Before a scan goes into the grid, the robot's pose is searched in a small
window around the guess: every candidate (a lattice of x, y and heading offsets) places the
scan's end points in the map, and scores the evidence of obstacles under them (positive
log-odds only); the best candidate wins if it beats the guess. This is the brute-force form of
Olson's correlative matching (and of what Cartographer's real-time correlative matcher does),
vectorised over the x-y lattice for each heading.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from clients.mapping.grid import Beams, LogOddsGrid

F32 = npt.NDArray[np.float32]

#: the search window (± metres, ± radians) and its steps
WINDOW_M = 0.12
STEP_M = 0.02
WINDOW_RAD = 0.08
STEP_RAD = 0.01
#: a scan with fewer end points than this is not matched (nothing to hold on to)
MIN_POINTS = 40
#: the map must hold at least this many scans before it is trusted as a reference
MIN_SCANS = 5
#: and explain the scan at the best fit: this share of its end points on obstacle evidence (a
#: scan of space the map has not seen yet would slide to wherever some wall is)
MIN_SUPPORT = 0.5
#: a correction is taken only when it fits this much better than the guess (a corridor or an
#: open floor fits almost equally well all along: there the odometry is the better guess)
MIN_GAIN = 1.05
#: and the guess must already be partly explained (this share of end points on evidence): a
#: scan that mostly sees new space has too little to hold on to
MIN_SUPPORT_AT_GUESS = 0.4


def match(
    grid: LogOddsGrid, pose: tuple[float, float, float], offset: tuple[float, float], ranges: F32, beams: Beams
) -> tuple[float, float, float]:
    """The robot pose near ``pose`` (x, y, yaw of base_footprint) where the scan, taken by a lidar
    ``offset`` ahead of the robot's origin, fits ``grid`` best; ``pose`` itself when nothing fits better."""
    if grid.scans < MIN_SCANS:
        return pose
    r = np.asarray(ranges, dtype=np.float64)
    ok = np.isfinite(r) & (r >= beams.range_min) & (r <= beams.range_max)
    if ok.sum() < MIN_POINTS:
        return pose
    a = beams.angles[ok]
    # end points in the robot's frame
    px = offset[0] + r[ok] * np.cos(a)
    py = offset[1] + r[ok] * np.sin(a)
    evidence = np.maximum(grid.logodds, 0.0)
    res = grid.resolution
    shifts = np.arange(-WINDOW_M, WINDOW_M + 1e-9, STEP_M)
    turns = np.arange(-WINDOW_RAD, WINDOW_RAD + 1e-9, STEP_RAD)
    x0, y0, yaw0 = pose
    best = (-math.inf, 0.0, 0.0, 0.0)
    prior = -math.inf
    for dth in turns:
        c, s = math.cos(yaw0 + dth), math.sin(yaw0 + dth)
        wx = x0 + c * px - s * py  # world end points for this heading, before the x-y shift
        wy = y0 + s * px + c * py
        col = np.floor((wx[None, :] + shifts[:, None] - grid.origin[0]) / res).astype(np.intp)  # (shifts, n)
        row = np.floor((wy[None, :] + shifts[:, None] - grid.origin[1]) / res).astype(np.intp)
        col = np.clip(col, 0, grid.width - 1)
        row = np.clip(row, 0, grid.height - 1)
        # scores[i, j]: shift i in y, shift j in x
        scores = evidence[row[:, None, :], col[None, :, :]].sum(axis=2)
        i, j = np.unravel_index(int(np.argmax(scores)), scores.shape)
        if scores[i, j] > best[0]:
            best = (float(scores[i, j]), float(shifts[j]), float(shifts[i]), float(dth))
        if abs(dth) < STEP_RAD / 2:
            k = len(shifts) // 2
            prior = float(scores[k, k])
    score, dx, dy, dth = best

    def support(x: float, y: float, yaw: float) -> float:
        c, s = math.cos(yaw), math.sin(yaw)
        col = np.clip(np.floor((x + c * px - s * py - grid.origin[0]) / res).astype(np.intp), 0, grid.width - 1)
        row = np.clip(np.floor((y + s * px + c * py - grid.origin[1]) / res).astype(np.intp), 0, grid.height - 1)
        return float((evidence[row, col] > 0).mean())

    if score <= prior * MIN_GAIN or support(x0 + dx, y0 + dy, yaw0 + dth) < MIN_SUPPORT:
        return pose
    if support(x0, y0, yaw0) < MIN_SUPPORT_AT_GUESS:
        return pose
    return x0 + dx, y0 + dy, math.atan2(math.sin(yaw0 + dth), math.cos(yaw0 + dth))
