"""Scan-to-map matching: where, near the odometry's guess, a scan fits the map best.

Odometry that drifts (a real robot's, or ``simd --odom-noise``) would smear a map built at the
odometry's poses. Before a scan goes into the grid, the robot's pose is corrected against the
map built so far by point-to-line ICP with a motion prior:

- **The map's obstacles, finer than its cells.** Each occupied cell remembers the mean of the
  scan end points that fell in it (grid.py), so a wall is known to a few millimetres although
  the cells are 5 cm; the local direction of the wall at a cell comes from its occupied
  neighbours' means (the smallest axis of their spread is the wall's normal).
- **Correspondences through the grid.** A scan point pairs with the nearest remembered point
  among the occupied cells around the cell it falls in; no search tree is needed, the grid is
  the index. Pairs farther apart than a few centimetres are dropped (new space, a robot that
  passed by).
- **Point-to-line least squares with a prior.** Each pair contributes its distance along the
  wall's normal; sliding along a wall costs nothing in that term, so along a long wall, in a
  corridor or on open floor the data cannot pull the pose in that direction, and the prior (a
  quadratic pull toward the odometry's guess, as wide as the odometry's error over one scan)
  holds it there. This is what keeps a scan from sliding where the map cannot tell: the same
  idea as the odometry term of Cartographer's Ceres scan matcher or slam_toolbox's penalties.

A scan with too few pairs is not matched at all: the odometry is the better guess there.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from clients.mapping.grid import OCCUPIED_LOGODDS, Beams, LogOddsGrid
from fleetcommon.arrays import F64

#: how far (cells) around a scan point's cell a correspondence is looked for, first and last
#: iteration: the first takes a few centimetres of drift, the last only what fits closely
SEARCH_CELLS = 1
PAIR_M = (0.05, 0.03)
ITERATIONS = 8
#: the scan's end points are this noisy along a wall's normal (metres): the data term's scale
POINT_SIGMA_M = 0.01
#: the odometry's error over one scan period (a fifth of a second): the prior's widths. 5 %
#: wheel slip gives a few millimetres and milliradians; the widths leave room for a jolt
PRIOR_M = 0.01
PRIOR_RAD = 0.02
#: a cell's neighbours form a wall when their spread across is under this share of their spread along
STRAIGHT = 0.1
#: a scan with fewer pairs than this, at the end, keeps the odometry's pose
MIN_PAIRS = 30
#: below this share of the scan's points paired, a wide search (± metres, ± radians, steps) looks
#: for a better basin, taken when it pairs at least RELOCK_GAIN more of the points
RELOCK_BELOW = 0.3
RELOCK_GAIN = 0.3
RELOCK_M = 0.15
RELOCK_STEP_M = 0.025
RELOCK_RAD = 0.08
RELOCK_STEP_RAD = 0.01
#: the map must hold at least this many scans before it is trusted as a reference
MIN_SCANS = 5


def _offsets(reach: int) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
    dr, dc = np.mgrid[-reach : reach + 1, -reach : reach + 1]
    return dr.ravel(), dc.ravel()


class Obstacles:
    """The map's remembered obstacle points and wall normals near a pose, for one scan's match."""

    def __init__(self, grid: LogOddsGrid) -> None:
        self.grid = grid

    def occupied(self, rows: npt.NDArray[np.intp], cols: npt.NDArray[np.intp]) -> npt.NDArray[np.bool_]:
        """Whether these cells hold an obstacle with remembered points (looked up, not the whole grid)."""
        return (self.grid.logodds[rows, cols] > OCCUPIED_LOGODDS) & (self.grid.hit_count[rows, cols] > 0)

    def pairs(self, wx: F64, wy: F64, reach: int) -> tuple[F64, F64, F64, F64, npt.NDArray[np.bool_]]:
        """For each point: the nearest obstacle point (mx, my) within ``reach`` cells, that
        wall's normal (nx, ny), and whether one was found."""
        g = self.grid
        res = g.resolution
        col = np.floor((wx - g.origin[0]) / res).astype(np.intp)
        row = np.floor((wy - g.origin[1]) / res).astype(np.intp)
        dr, dc = _offsets(reach)
        rows = np.clip(row[:, None] + dr[None, :], 0, g.height - 1)  # (points, candidates)
        cols = np.clip(col[:, None] + dc[None, :], 0, g.width - 1)
        occ = self.occupied(rows, cols)
        counts = np.maximum(g.hit_count[rows, cols], 1.0)
        mx = g.hit_x[rows, cols] / counts
        my = g.hit_y[rows, cols] / counts
        d2 = np.where(occ, (mx - wx[:, None]) ** 2 + (my - wy[:, None]) ** 2, np.inf)
        k = np.argmin(d2, axis=1)
        idx = np.arange(len(wx))
        found = np.isfinite(d2[idx, k])
        r, c = rows[idx, k], cols[idx, k]
        nx, ny, straight = self._normals(r, c)
        return mx[idx, k], my[idx, k], nx, ny, found & straight

    def _normals(self, r: npt.NDArray[np.intp], c: npt.NDArray[np.intp]) -> tuple[F64, F64, npt.NDArray[np.bool_]]:
        """The normal of the wall through each cell: the minor axis of its occupied 3x3 neighbours'
        means; and whether there is a wall there, i.e. at least three points in a line (a lone
        cell, a corner or a blob has no direction to slide along, nor one to be held by)."""
        g = self.grid
        dr, dc = _offsets(1)
        rows = np.clip(r[:, None] + dr[None, :], 0, g.height - 1)
        cols = np.clip(c[:, None] + dc[None, :], 0, g.width - 1)
        w = self.occupied(rows, cols).astype(np.float64)
        counts = np.maximum(g.hit_count[rows, cols], 1.0)
        px = g.hit_x[rows, cols] / counts
        py = g.hit_y[rows, cols] / counts
        n = np.maximum(w.sum(axis=1), 1.0)
        cx = (w * px).sum(axis=1) / n
        cy = (w * py).sum(axis=1) / n
        sxx = (w * (px - cx[:, None]) ** 2).sum(axis=1)
        syy = (w * (py - cy[:, None]) ** 2).sum(axis=1)
        sxy = (w * (px - cx[:, None]) * (py - cy[:, None])).sum(axis=1)
        # the major axis of a 2x2 covariance is at 0.5 atan2(2 sxy, sxx - syy); the normal is across it
        major = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
        half = (sxx + syy) / 2.0
        spread = np.sqrt(np.maximum(half * half - (sxx * syy - sxy * sxy), 0.0))
        straight = (w.sum(axis=1) >= 3) & (half - spread < STRAIGHT * (half + spread))
        return -np.sin(major), np.cos(major), straight


def _evidence(grid: LogOddsGrid, x: float, y: float, reach_m: float) -> tuple[F64, float, float]:
    """The map's evidence of obstacles around (x, y): 0 where free or unknown, rising to 1 with
    the log-odds, blurred by one [1/4, 1/2, 1/4] pass each way; and the window's corner (metres)."""
    res = grid.resolution
    span = math.ceil(reach_m / res) + 2
    cr, cc = int((y - grid.origin[1]) // res), int((x - grid.origin[0]) // res)
    r0, c0 = max(0, cr - span), max(0, cc - span)
    r1, c1 = min(grid.height, cr + span + 1), min(grid.width, cc + span + 1)
    e = np.maximum(0.0, 1.0 - 2.0 / (1.0 + np.exp(grid.logodds[r0:r1, c0:c1].astype(np.float64))))
    e[1:-1, :] = 0.25 * e[:-2, :] + 0.5 * e[1:-1, :] + 0.25 * e[2:, :]
    e[:, 1:-1] = 0.25 * e[:, :-2] + 0.5 * e[:, 1:-1] + 0.25 * e[:, 2:]
    return e, grid.origin[0] + c0 * res, grid.origin[1] + r0 * res


def _coarse(grid: LogOddsGrid, px: F64, py: F64, pose: tuple[float, float, float]) -> F64:
    """The offset (dx, dy, dyaw) on a lattice around ``pose`` where the scan's end points lie on
    the most evidence: a basin for the refinement to start from after a drift too large for it."""
    x0, y0, yaw0 = pose
    evidence, ox, oy = _evidence(grid, x0, y0, float(np.hypot(px, py).max()) + RELOCK_M)
    h, w = evidence.shape
    res = grid.resolution
    shifts = np.arange(-RELOCK_M, RELOCK_M + 1e-9, RELOCK_STEP_M)
    best = (-math.inf, 0.0, 0.0, 0.0)
    for dyaw in np.arange(-RELOCK_RAD, RELOCK_RAD + 1e-9, RELOCK_STEP_RAD):
        c, s = math.cos(yaw0 + dyaw), math.sin(yaw0 + dyaw)
        wx, wy = x0 + c * px - s * py, y0 + s * px + c * py
        col = np.clip(np.floor((wx[None, :] + shifts[:, None] - ox) / res).astype(np.intp), 0, w - 1)
        row = np.clip(np.floor((wy[None, :] + shifts[:, None] - oy) / res).astype(np.intp), 0, h - 1)
        scores = evidence[row[:, None, :], col[None, :, :]].sum(axis=2)  # [i, j]: shift i in y, j in x
        i, j = np.unravel_index(int(np.argmax(scores)), scores.shape)
        if scores[i, j] > best[0]:
            best = (float(scores[i, j]), float(shifts[j]), float(shifts[i]), float(dyaw))
    return np.array(best[1:])


#: the prior of scan-to-map matching, as an information matrix: the odometry's error over one scan
PRIOR = np.diag([1 / PRIOR_M**2, 1 / PRIOR_M**2, 1 / PRIOR_RAD**2])


class Fit:
    """Where a refinement ended: the offset from its guess, the share of the scan's points paired
    there (its support, 0 when too few pairs were found to trust), and the data's own
    information about the pose (Σ JᵀWJ of the last pairs, without the prior): a scan of one
    wall or of a corridor has next to none along it."""

    def __init__(self, offset: F64, support: float, information: F64) -> None:
        self.offset = offset
        self.support = support
        self.information = information

    def spread(self) -> float:
        """How well the pairs' walls hold the position in the direction they hold it least: the
        smaller eigenvalue of their normals' scatter over its trace (0 for parallel walls, 0.5
        for as much wall one way as across)."""
        t = self.information[:2, :2]
        trace = float(t[0, 0] + t[1, 1])
        if trace <= 0.0:
            return 0.0
        det = float(t[0, 0] * t[1, 1] - t[0, 1] * t[1, 0])
        smallest = trace / 2.0 - math.sqrt(max(trace * trace / 4.0 - det, 0.0))
        return smallest / trace


def refine(obstacles: Obstacles, px: F64, py: F64, pose: tuple[float, float, float], start: F64,
           prior: F64 = PRIOR) -> Fit:  # fmt: skip
    """Point-to-line ICP from the offset ``start``, with ``prior`` (an information matrix)
    pulling toward the guess ``pose``."""
    x0, y0, yaw0 = pose
    p = start.astype(np.float64).copy()
    pairs = 0
    data = np.zeros((3, 3))
    for it in range(ITERATIONS):
        c, s = math.cos(yaw0 + p[2]), math.sin(yaw0 + p[2])
        wx, wy = x0 + p[0] + c * px - s * py, y0 + p[1] + s * px + c * py
        mx, my, nx, ny, found = obstacles.pairs(wx, wy, SEARCH_CELLS)
        limit = PAIR_M[0] + (PAIR_M[1] - PAIR_M[0]) * it / max(1, ITERATIONS - 1)
        use = found & (np.hypot(np.where(found, mx - wx, 0), np.where(found, my - wy, 0)) < limit)
        pairs = int(use.sum())
        if pairs < MIN_PAIRS:
            return Fit(p, 0.0, np.zeros((3, 3)))
        nx, ny = nx[use], ny[use]
        residual = nx * (wx[use] - mx[use]) + ny * (wy[use] - my[use])
        # d(world point)/d(yaw) = (-s px - c py, c px - s py)
        dyaw = nx * (-s * px[use] - c * py[use]) + ny * (c * px[use] - s * py[use])
        jac = np.column_stack([nx, ny, dyaw])
        # Huber weights: a pair a few sigmas off (a corner, a robot) counts less
        scaled = np.abs(residual) / (2.0 * POINT_SIGMA_M)
        weight = np.where(scaled <= 1.0, 1.0, 1.0 / np.maximum(scaled, 1e-12)) / POINT_SIGMA_M**2
        data = (jac * weight[:, None]).T @ jac
        hessian = data + prior
        gradient = (jac * weight[:, None]).T @ residual + prior @ p
        step = np.linalg.solve(hessian, -gradient)
        p = p + step
        if abs(step[0]) + abs(step[1]) < 1e-4 and abs(step[2]) < 1e-4 and it >= ITERATIONS // 2:
            break
    return Fit(p, pairs / len(px), data)


def end_points(ranges: npt.ArrayLike, beams: Beams, offset: tuple[float, float]) -> tuple[F64, F64]:
    """A scan's end points in the robot's frame (valid returns only), for a lidar ``offset``
    ahead of the robot's origin."""
    r = np.asarray(ranges, dtype=np.float64)
    ok = np.isfinite(r) & (r >= beams.range_min) & (r < beams.range_max)
    a = beams.angles[ok]
    return offset[0] + r[ok] * np.cos(a), offset[1] + r[ok] * np.sin(a)


def locate(
    grid: LogOddsGrid, pose: tuple[float, float, float], offset: tuple[float, float], ranges: npt.ArrayLike,
    beams: Beams,
) -> tuple[tuple[float, float, float], float]:  # fmt: skip
    """The robot pose near ``pose`` (x, y, yaw of base_footprint) where the scan, taken by a lidar
    ``offset`` ahead of the robot's origin, fits ``grid`` best, and the share of the scan's
    points that support it; ``pose`` itself and 0 when the map cannot tell."""
    if not grid.hit_count.size:
        raise ValueError("scan matching needs a grid that keeps its points: call grid.keep_points() first")
    if grid.scans < MIN_SCANS:
        return pose, 0.0
    px, py = end_points(ranges, beams, offset)
    if len(px) < MIN_PAIRS:
        return pose, 0.0
    obstacles = Obstacles(grid)
    fit = refine(obstacles, px, py, pose, np.zeros(3))
    if fit.support < RELOCK_BELOW:
        # little of the scan fits where odometry says: after a long blind stretch the drift may
        # be beyond the refinement's reach; a wide search finds the basin, if there is one
        fit2 = refine(obstacles, px, py, pose, _coarse(grid, px, py, pose))
        if fit2.support >= max(RELOCK_BELOW, fit.support + RELOCK_GAIN):
            fit = fit2
    if fit.support == 0.0:
        return pose, 0.0
    x0, y0, yaw0 = pose
    p = fit.offset
    return (x0 + p[0], y0 + p[1], math.atan2(math.sin(yaw0 + p[2]), math.cos(yaw0 + p[2]))), fit.support


def match(
    grid: LogOddsGrid, pose: tuple[float, float, float], offset: tuple[float, float], ranges: npt.ArrayLike,
    beams: Beams,
) -> tuple[float, float, float]:  # fmt: skip
    """The robot pose near ``pose`` (x, y, yaw of base_footprint) where the scan, taken by a lidar
    ``offset`` ahead of the robot's origin, fits ``grid`` best; ``pose`` itself when the map
    cannot tell."""
    return locate(grid, pose, offset, ranges, beams)[0]
