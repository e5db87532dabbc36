"""A robot's path: from where it stands to its goal, on its model's costmap and around what
it has learnt since (obstacles its lidar met, robots it plans around).

The search runs on the costmap's cells (simd/nav/grid_search.py, A* with a compiled twin);
the path then starts at the robot itself and ends at the goal point. In an open world it is
pulled straight wherever the cells allow (any-angle, as Nav2's smoother does), so a robot
drives diagonally instead of along the grid's staircase; on a MovingAI map (``lanes``) it
keeps to the centres of the map's cells, so robots passing in a two-cell corridor keep to
their lanes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from simd.core.models import RobotModel
from simd.nav import grid_search, line_of_sight
from simd.nav.costmap import Costmap

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

#: a robot that stands where its circle does not fit (spawned against a wall, pushed) plans
#: from the nearest cell where it does, within this distance
START_SEARCH_M = 0.5


@dataclass(frozen=True)
class Marks:
    """Cells of the costmap a robot treats as blocked for now (flat indices), each group
    until a sim time."""

    cells: I64
    until: float


def disc_cells(costmap: Costmap, points: F64, radius: float) -> I64:
    """The costmap cells (flat) whose centres lie within ``radius`` of any of ``points``."""
    g = costmap.grid
    if len(points) == 0:
        return np.zeros(0, dtype=np.int64)
    k = math.ceil(radius / g.resolution)
    offs = np.arange(-k, k + 1)
    dr, dc = np.meshgrid(offs, offs, indexing="ij")
    cols = np.floor((points[:, 0] - g.x0) / g.resolution).astype(np.int64)
    rows = np.floor((points[:, 1] - g.y0) / g.resolution).astype(np.int64)
    rr = rows[:, None] + dr.ravel()[None, :]
    cc = cols[:, None] + dc.ravel()[None, :]
    cx = g.x0 + (cc + 0.5) * g.resolution
    cy = g.y0 + (rr + 0.5) * g.resolution
    near = (cx - points[:, 0:1]) ** 2 + (cy - points[:, 1:2]) ** 2 <= radius * radius
    ok = near & (rr >= 0) & (rr < g.height) & (cc >= 0) & (cc < g.width)
    flat: I64 = np.unique(rr[ok] * g.width + cc[ok])
    return flat


def square_cells(costmap: Costmap, centres: F64, half: float, grow: float) -> I64:
    """The costmap cells (flat) within ``grow`` of squares of half-side ``half`` about
    ``centres``: traffic cells another robot holds, as obstacles for one robot's plan."""
    g = costmap.grid
    out = []
    for cx, cy in centres:
        c0 = max(0, math.floor((cx - half - grow - g.x0) / g.resolution))
        c1 = min(g.width, math.ceil((cx + half + grow - g.x0) / g.resolution))
        r0 = max(0, math.floor((cy - half - grow - g.y0) / g.resolution))
        r1 = min(g.height, math.ceil((cy + half + grow - g.y0) / g.resolution))
        if c0 < c1 and r0 < r1:
            rr, cc = np.meshgrid(np.arange(r0, r1), np.arange(c0, c1), indexing="ij")
            out.append((rr * g.width + cc).ravel())
    if not out:
        return np.zeros(0, dtype=np.int64)
    return np.unique(np.concatenate(out)).astype(np.int64)


class Planner:
    """Paths on one costmap, for any model."""

    def __init__(self, costmap: Costmap, lanes: bool) -> None:
        self.costmap = costmap
        self.lanes = lanes

    def cost_with(self, model: RobotModel, marks: list[Marks]) -> F32:
        base = self.costmap.costs(model)
        if not marks:
            return base
        cost = base.copy()
        flat = cost.reshape(-1)
        for m in marks:
            flat[m.cells] = np.inf
        return cost

    def start_cell(self, model: RobotModel, cost: F32, x: float, y: float) -> tuple[int, int] | None:
        cell = self.costmap.grid.cell(x, y)
        if cell is not None and math.isfinite(float(cost[cell])):
            return cell
        g = self.costmap.grid
        k = max(1, math.ceil(START_SEARCH_M / g.resolution))
        col = math.floor((x - g.x0) / g.resolution)
        row = math.floor((y - g.y0) / g.resolution)
        r0, r1, c0, c1 = max(0, row - k), min(g.height, row + k + 1), max(0, col - k), min(g.width, col + k + 1)
        if r0 >= r1 or c0 >= c1:
            return None
        rr, cc = np.nonzero(np.isfinite(cost[r0:r1, c0:c1]))
        if rr.size == 0:
            return None
        d2 = (g.x0 + (cc + c0 + 0.5) * g.resolution - x) ** 2 + (g.y0 + (rr + r0 + 0.5) * g.resolution - y) ** 2
        i = int(np.argmin(d2))
        return int(rr[i] + r0), int(cc[i] + c0)

    def goal_cell(self, model: RobotModel, cost: F32, x: float, y: float, tolerance: float) -> tuple[int, int] | None:
        """The goal's cell, or the nearest standable cell within ``tolerance`` of the goal."""
        cell = self.costmap.grid.cell(x, y)
        if cell is not None and math.isfinite(float(cost[cell])):
            return cell
        g = self.costmap.grid
        k = max(1, math.ceil(tolerance / g.resolution))
        col = math.floor((x - g.x0) / g.resolution)
        row = math.floor((y - g.y0) / g.resolution)
        r0, r1, c0, c1 = max(0, row - k), min(g.height, row + k + 1), max(0, col - k), min(g.width, col + k + 1)
        if r0 >= r1 or c0 >= c1:
            return None
        rr, cc = np.nonzero(np.isfinite(cost[r0:r1, c0:c1]))
        if rr.size == 0:
            return None
        d2 = (g.x0 + (cc + c0 + 0.5) * g.resolution - x) ** 2 + (g.y0 + (rr + r0 + 0.5) * g.resolution - y) ** 2
        i = int(np.argmin(d2))
        if d2[i] > tolerance * tolerance:
            return None
        return int(rr[i] + r0), int(cc[i] + c0)

    def path(
        self,
        model: RobotModel,
        start: tuple[float, float],
        goal: tuple[float, float],
        tolerance: float,
        marks: list[Marks] | None = None,
    ) -> F64 | None:
        """Waypoints (n, 2) from ``start`` to ``goal``, or None when nothing connects them."""
        cost = self.cost_with(model, marks or [])
        a = self.start_cell(model, cost, *start)
        b = self.goal_cell(model, cost, goal[0], goal[1], tolerance)
        if a is None or b is None:
            return None
        cells = grid_search.plan(cost, a, b, diagonal=True)
        if cells is None:
            return None
        if not self.lanes and len(cells) > 2:
            cells = line_of_sight.smooth(np.isfinite(cost), cells)
        points = self.costmap.grid.centres(cells)
        points[0] = start
        # end at the goal itself when it is in the last cell; else at that cell's centre,
        # the nearest place within the goal's tolerance where the robot fits
        if self.costmap.grid.cell(*goal) == (int(cells[-1, 0]), int(cells[-1, 1])):
            points[-1] = goal
        if len(points) == 1:
            points = np.vstack([points, points])
        return _drop_repeats(points)


def _drop_repeats(points: F64) -> F64:
    keep = np.ones(len(points), dtype=bool)
    keep[1:] = np.hypot(np.diff(points[:, 0]), np.diff(points[:, 1])) > 1e-9
    kept = points[keep]
    if len(kept) == 1:
        kept = np.vstack([kept, kept])
    return kept
