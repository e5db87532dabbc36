"""How good a map is, against the world's true geometry (the map benchmark and the tests).

- **precision**: the share of a map's occupied cells within one cell (1.5 cells between centre
  and surface) of a true wall, pillar or block;
- **recall**: the share of true wall cells (cells a true obstacle covers, next to free space
  reachable from the robots' spawn poses) with an occupied cell of the map within one cell;
- **coverage**: the share of that reachable free space the map holds as free.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from clients.mapping.explore import wavefront
from fleetcommon.arrays import F64
from fleetcommon.mapfile import OccupancyMap
from protocol.control import WorldInfo


def distance_to_world(points: F64, world: WorldInfo) -> F64:
    """Each point's distance to the nearest obstacle surface (polygon edge or circle)."""
    best = np.full(len(points), np.inf)
    for poly in world.polygons:
        p = np.asarray(poly, dtype=np.float64)
        a, b = p, np.roll(p, -1, axis=0)
        ab = b - a
        t = ((points[:, None, :] - a[None]) * ab[None]).sum(-1) / (ab * ab).sum(-1)[None]
        closest = a[None] + np.clip(t, 0, 1)[..., None] * ab[None]
        best = np.minimum(best, np.linalg.norm(points[:, None, :] - closest, axis=-1).min(axis=1))
    for c in world.circles:
        best = np.minimum(best, np.abs(np.hypot(points[:, 0] - c.x, points[:, 1] - c.y) - c.radius))
    return best


def _raster(world: WorldInfo, origin: tuple[float, float], shape: tuple[int, int], res: float) -> npt.NDArray[np.bool_]:
    """Cells whose centre lies inside a true obstacle."""
    rows, cols = np.indices(shape)
    px = origin[0] + (cols + 0.5) * res
    py = origin[1] + (rows + 0.5) * res
    solid = np.zeros(shape, dtype=bool)
    for poly in world.polygons:
        p = np.asarray(poly, dtype=np.float64)
        inside = np.ones(shape, dtype=bool)
        for (x0, y0), (x1, y1) in zip(p, np.roll(p, -1, axis=0), strict=True):  # convex, counter-clockwise
            inside &= (x1 - x0) * (py - y0) - (y1 - y0) * (px - x0) >= 0
        solid |= inside
    for c in world.circles:
        solid |= np.hypot(px - c.x, py - c.y) <= c.radius
    return solid


def _flood(open_: npt.NDArray[np.bool_], starts: list[tuple[int, int]]) -> npt.NDArray[np.bool_]:
    reach = np.zeros(open_.shape, dtype=bool)
    for s in starts:
        reach |= wavefront(open_, s) >= 0
    return reach


def score(m: OccupancyMap, world: WorldInfo, poses: list[tuple[float, float]]) -> dict[str, float]:
    """Precision, recall and free-space coverage of a map (see the module docstring)."""
    res, origin = m.resolution, (m.origin[0], m.origin[1])
    solid = _raster(world, origin, m.cells.shape, res)
    starts = [(int((y - origin[1]) // res), int((x - origin[0]) // res)) for x, y in poses]
    reachable = _flood(~solid, starts)
    near_reachable = np.zeros_like(reachable)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            near_reachable |= np.roll(np.roll(reachable, dr, 0), dc, 1)
    true_wall = solid & near_reachable
    occupied = m.cells == 100
    occ_idx = np.argwhere(occupied)
    centres = np.column_stack([origin[0] + (occ_idx[:, 1] + 0.5) * res, origin[1] + (occ_idx[:, 0] + 0.5) * res])
    precision = float((distance_to_world(centres, world) <= 1.5 * res).mean()) if len(centres) else 0.0
    grown = occupied.copy()
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            grown |= np.roll(np.roll(occupied, dr, 0), dc, 1)
    recall = float((grown & true_wall).sum() / max(1, true_wall.sum()))
    coverage = float(((m.cells == 0) & reachable).sum() / max(1, reachable.sum()))
    return {"precision": precision, "recall": recall, "coverage": coverage}
