"""The world as a planner sees it: a grid of clearances, and each model's costs on it.

Every cell keeps the distance from its centre to the nearest wall or obstacle (its
*clearance*), computed once from the world's exact geometry. A robot model can stand in a
cell when its circumscribed circle fits there with a margin (``clearance >= radius + margin``):
a diff-drive robot turns in place, so a path planned for its circle is safe at any heading.
Within ``INFLATION_M`` of that limit a cell costs more (as Nav2's inflation layer makes
robots keep off walls when there is room); the rest costs 1 per metre.

The grid covers the world's bounds. Its cells are ``resolution`` wide, 5 cm unless the world
is so large that that would pass ``MAX_CELLS`` (the empty world's 100 x 100 m is planned at
10 cm). A MovingAI world is planned on its own cells (``resolution`` = its cell size, the
grid aligned to the map), so robots keep to the lanes the map draws.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from fleetcommon.arrays import F32, F64
from simd.core.models import RobotModel
from simd.core.worldfile import WorldGeometry

DEFAULT_RESOLUTION_M = 0.05
MAX_CELLS = 1_000_000
#: room kept between a robot's circumscribed circle and a wall on every planned path
MARGIN_M = 0.03
#: cells closer than this beyond the margin cost more (the robot keeps off walls if it can)
INFLATION_M = 0.25
#: the extra cost per metre at the margin itself, falling linearly to 0 at INFLATION_M
INFLATION_COST = 2.0


@dataclass(frozen=True)
class Grid:
    """Cell (row, col) covers x in [x0 + col*res, x0 + (col+1)*res), y likewise with row:
    row 0 is the smallest y, as in nav_msgs/OccupancyGrid."""

    x0: float
    y0: float
    resolution: float
    width: int
    height: int

    @classmethod
    def covering(cls, world: WorldGeometry, resolution: float | None = None) -> Grid:
        """The grid over ``world``'s bounds: ``resolution`` if given, else 5 cm or coarser."""
        x_min, x_max, y_min, y_max = world.bounds
        area = (x_max - x_min) * (y_max - y_min)
        res = resolution or max(DEFAULT_RESOLUTION_M, math.sqrt(area / MAX_CELLS))
        width = max(1, math.ceil((x_max - x_min) / res - 1e-9))
        height = max(1, math.ceil((y_max - y_min) / res - 1e-9))
        return cls(x_min, y_min, res, width, height)

    @property
    def shape(self) -> tuple[int, int]:
        return self.height, self.width

    def cell(self, x: float, y: float) -> tuple[int, int] | None:
        """The (row, col) holding the point, or None off the grid (or not finite)."""
        if not (math.isfinite(x) and math.isfinite(y)):
            return None
        col = math.floor((x - self.x0) / self.resolution)
        row = math.floor((y - self.y0) / self.resolution)
        if 0 <= row < self.height and 0 <= col < self.width:
            return row, col
        return None

    def centre(self, row: int, col: int) -> tuple[float, float]:
        return self.x0 + (col + 0.5) * self.resolution, self.y0 + (row + 0.5) * self.resolution

    def centres(self, cells: npt.NDArray[np.int32]) -> F64:
        """(k, 2) (row, col) cells as (k, 2) world points."""
        xy = np.empty(cells.shape, dtype=np.float64)
        xy[:, 0] = self.x0 + (cells[:, 1] + 0.5) * self.resolution
        xy[:, 1] = self.y0 + (cells[:, 0] + 0.5) * self.resolution
        return xy


def _segment_distances(px: F64, py: F64, edges: F64) -> F64:
    """Distance of each point to the nearest of ``edges`` (m, 4): rows x0, y0, x1, y1."""
    ax, ay, bx, by = (edges[:, k][None, :] for k in range(4))
    dx, dy = bx - ax, by - ay
    length2 = np.maximum(dx * dx + dy * dy, 1e-18)
    t = np.clip(((px[:, None] - ax) * dx + (py[:, None] - ay) * dy) / length2, 0.0, 1.0)
    ex = px[:, None] - (ax + t * dx)
    ey = py[:, None] - (ay + t * dy)
    d: F64 = np.sqrt(ex * ex + ey * ey).min(axis=1)
    return d


def _convex_distance(px: F64, py: F64, polygon: F64) -> F64:
    """Distance of each point to a convex counter-clockwise polygon (0 inside)."""
    ends = np.roll(polygon, -1, axis=0)
    edges = np.hstack([polygon, ends])
    d = _segment_distances(px, py, edges)
    ex, ey = ends[:, 0] - polygon[:, 0], ends[:, 1] - polygon[:, 1]
    cross = ex[None, :] * (py[:, None] - polygon[None, :, 1]) - ey[None, :] * (px[:, None] - polygon[None, :, 0])
    inside = (cross >= 0.0).all(axis=1)
    d[inside] = 0.0
    return d


def clearance_field(world: WorldGeometry, grid: Grid, reach: float) -> F32:
    """Each cell centre's distance to the nearest wall or obstacle, capped at ``reach`` (0
    inside one). Exact for the world's geometry; each obstacle touches only the cells within
    ``reach`` of its bounding box."""
    out = np.full(grid.shape, reach, dtype=np.float64)
    res = grid.resolution

    def window(x_lo: float, x_hi: float, y_lo: float, y_hi: float) -> tuple[slice, slice, F64, F64] | None:
        c0 = max(0, math.floor((x_lo - reach - grid.x0) / res))
        c1 = min(grid.width, math.ceil((x_hi + reach - grid.x0) / res))
        r0 = max(0, math.floor((y_lo - reach - grid.y0) / res))
        r1 = min(grid.height, math.ceil((y_hi + reach - grid.y0) / res))
        if c0 >= c1 or r0 >= r1:
            return None
        xs = grid.x0 + (np.arange(c0, c1) + 0.5) * res
        ys = grid.y0 + (np.arange(r0, r1) + 0.5) * res
        px, py = np.meshgrid(xs, ys)
        return slice(r0, r1), slice(c0, c1), px.ravel(), py.ravel()

    for polygon in world.polygons:
        w = window(polygon[:, 0].min(), polygon[:, 0].max(), polygon[:, 1].min(), polygon[:, 1].max())
        if w is None:
            continue
        rows, cols, px, py = w
        block = out[rows, cols]
        np.minimum(block, _convex_distance(px, py, polygon).reshape(block.shape), out=block)
    for cx, cy, radius in world.circles:
        w = window(cx - radius, cx + radius, cy - radius, cy + radius)
        if w is None:
            continue
        rows, cols, px, py = w
        block = out[rows, cols]
        d = np.maximum(np.hypot(px - cx, py - cy) - radius, 0.0)
        np.minimum(block, d.reshape(block.shape), out=block)
    return out.astype(np.float32)


def occupied_cells(world: WorldGeometry, grid: Grid) -> npt.NDArray[np.bool_]:
    """The cells a wall or obstacle reaches into, as a map_server map marks them: a cell whose
    centre lies within half a cell of the geometry (a wall thinner than a cell still leaves a
    closed line of cells). Rows from the smallest y, as nav_msgs/OccupancyGrid's."""
    half = grid.resolution / 2.0
    occupied: npt.NDArray[np.bool_] = clearance_field(world, grid, grid.resolution) < half
    return occupied


@dataclass
class Costmap:
    """The world's clearances on a grid, and the cost of every cell for each model (made when
    a model first navigates: a thousand burgers share one)."""

    world: WorldGeometry
    grid: Grid
    margin: float = MARGIN_M
    clearance: F32 = field(init=False)
    _costs: dict[str, F32] = field(default_factory=dict, init=False)

    def __post_init__(self) -> None:
        from simd.core.models import MODELS

        widest = max(m.radius for m in MODELS.values())
        self.clearance = clearance_field(
            self.world, self.grid, widest + self.margin + INFLATION_M + self.grid.resolution
        )

    def radius(self, model: RobotModel) -> float:
        """The clearance a cell needs for ``model`` to stand in it."""
        return model.radius + self.margin

    def costs(self, model: RobotModel) -> F32:
        """Per-cell cost for ``model``: inf where it cannot stand, 1 in the open, up to
        1 + INFLATION_COST close to walls. Read-only; shared."""
        cost = self._costs.get(model.name)
        if cost is None:
            need = self.radius(model)
            c = self.clearance
            near = np.clip(1.0 - (c - need) / INFLATION_M, 0.0, 1.0)
            cost = (1.0 + INFLATION_COST * near).astype(np.float32)
            cost[c < need] = np.inf
            cost.setflags(write=False)
            self._costs[model.name] = cost
        return cost

    def clearance_at(self, x: float, y: float) -> float | None:
        """The clearance of the cell holding (x, y), or None off the grid."""
        cell = self.grid.cell(x, y)
        return None if cell is None else float(self.clearance[cell])
