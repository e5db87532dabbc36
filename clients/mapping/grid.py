"""A log-odds occupancy grid that scans are fused into, and its map_server form.

Each scan updates the cells its beams cross: the cell a beam ends in is evidence of an obstacle
(log-odds + ``HIT``), the cells before it of free space (``MISS``), each cell at most once per
scan (a cell many beams cross would otherwise count many times for one look). A beam with
nothing in range (``+inf``, the LDS-01's "no return") clears the cells along its whole range, as
Cartographer's ``missing_data_ray_length`` does; a beam below the minimum range (``-inf``) says
nothing. Values are clamped so that the map can change its mind when a robot moves. The numbers
are the usual ones of probabilistic mapping (p(hit) 0.7, p(miss) 0.4, as in Cartographer's
TurtleBot3 setup within rounding).

A cell is occupied when its probability passes 0.65 and free below 0.25, the map saver's
thresholds, so the saved map reads back to the same grid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from protocol.mapfile import FREE, OCCUPIED, UNKNOWN, OccupancyMap

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]

HIT = math.log(0.7 / 0.3)
MISS = math.log(0.4 / 0.6)
CLAMP = (-2.0, 3.5)
OCCUPIED_LOGODDS = math.log(0.65 / 0.35)
FREE_LOGODDS = math.log(0.25 / 0.75)


@dataclass
class Beams:
    """A lidar's ray layout: angles in the sensor frame and the range limits."""

    angle_min: float
    angle_increment: float
    count: int
    range_min: float
    range_max: float
    angles: F64 = field(init=False)

    def __post_init__(self) -> None:
        self.angles = (self.angle_min + np.arange(self.count) * self.angle_increment).astype(np.float64)


class LogOddsGrid:
    """Cells of ``resolution`` metres over ``bounds`` (x_min, x_max, y_min, y_max)."""

    def __init__(self, bounds: tuple[float, float, float, float], resolution: float = 0.05) -> None:
        if not resolution > 0:
            raise ValueError(f"resolution must be > 0, got {resolution}")
        x0, x1, y0, y1 = bounds
        self.resolution = resolution
        self.origin = (x0, y0)
        self.width = max(1, math.ceil((x1 - x0) / resolution))
        self.height = max(1, math.ceil((y1 - y0) / resolution))
        self.logodds = np.zeros((self.height, self.width), dtype=np.float32)
        self.seen = np.zeros((self.height, self.width), dtype=bool)
        self.scans = 0

    def integrate(self, x: float, y: float, yaw: float, ranges: F32, beams: Beams) -> None:
        """One scan taken by a sensor at (x, y) looking along ``yaw`` (world frame)."""
        r = np.asarray(ranges, dtype=np.float64)
        no_return = np.isposinf(r)
        valid = np.isfinite(r) & (r >= beams.range_min) & (r <= beams.range_max)
        reach = np.where(no_return, beams.range_max, np.where(valid, r, 0.0))
        use = valid | no_return
        if not use.any():
            return
        theta = yaw + beams.angles[use]
        reach = reach[use]
        dx, dy = np.cos(theta), np.sin(theta)
        res = self.resolution
        # points every half cell along each beam, up to (not into) its end
        steps = np.arange(0.0, beams.range_max, res / 2.0)
        along = steps[None, :] < reach[:, None] - res / 2.0
        px = x + dx[:, None] * steps[None, :]
        py = y + dy[:, None] * steps[None, :]
        free = self._cells(px[along], py[along])
        hit_beams = valid[use]
        hits = self._cells(x + dx[hit_beams] * reach[hit_beams], y + dy[hit_beams] * reach[hit_beams])
        free = np.setdiff1d(free, hits, assume_unique=False)
        flat = self.logodds.reshape(-1)
        seen = self.seen.reshape(-1)
        flat[free] += MISS
        flat[hits] += HIT
        np.clip(flat, *CLAMP, out=flat)
        seen[free] = True
        seen[hits] = True
        self.scans += 1

    def _cells(self, px: F64, py: F64) -> npt.NDArray[np.int64]:
        """Unique flat indices of the cells holding the points (points off the grid dropped)."""
        col = np.floor((px - self.origin[0]) / self.resolution).astype(np.int64)
        row = np.floor((py - self.origin[1]) / self.resolution).astype(np.int64)
        inside = (col >= 0) & (col < self.width) & (row >= 0) & (row < self.height)
        return np.unique(row[inside] * self.width + col[inside])

    def occupancy(self) -> OccupancyMap:
        """The grid as map_server sees it: 100 occupied, 0 free, -1 unknown."""
        cells = np.full(self.logodds.shape, UNKNOWN, dtype=np.int8)
        cells[self.seen & (self.logodds < FREE_LOGODDS)] = FREE
        cells[self.seen & (self.logodds > OCCUPIED_LOGODDS)] = OCCUPIED
        return OccupancyMap(cells, self.resolution, (self.origin[0], self.origin[1], 0.0))

    def explored_m2(self) -> float:
        """Area known to be free or occupied."""
        occ = self.occupancy().cells
        return float(np.count_nonzero(occ != UNKNOWN)) * self.resolution**2

    def to_world(self, row: int, col: int) -> tuple[float, float]:
        """The centre of a cell."""
        return self.origin[0] + (col + 0.5) * self.resolution, self.origin[1] + (row + 0.5) * self.resolution
