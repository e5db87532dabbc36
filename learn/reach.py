"""Where a robot can drive: the free space connected to the world's default spawn.

A world's bounds hold more than its arena: turtlebot3_world's rectangle has free floor outside
the hexagonal wall, and over half of the start/goal pairs drawn uniformly over the bounds were
outside it or on opposite sides of the wall: episodes nobody can finish, which teach a policy
nothing. The environments therefore draw starts and goals only where the robot can get from the
default spawn (the place a user spawns a robot without saying where).

The obstacles are rasterised on a grid (5 cm cells, coarser in very large worlds so that the
grid stays near a million cells), grown by the robot's radius (the farthest point of its
footprint from the point it turns about), and the free cells connected to the spawn's cell are
found by sweeping along rows and columns of free cells until nothing new is reached.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from simd.core.worldfile import WorldGeometry

CELL_M = 0.05
MAX_CELLS = 1_000_000


@dataclass(frozen=True)
class Reachable:
    """Free cells a robot can reach from the spawn; ``mask[row, col]`` for y, x."""

    x0: float
    y0: float
    cell: float
    mask: npt.NDArray[np.bool_]

    def contains(self, x: float, y: float) -> bool:
        col, row = int((x - self.x0) / self.cell), int((y - self.y0) / self.cell)
        h, w = self.mask.shape
        return 0 <= row < h and 0 <= col < w and bool(self.mask[row, col])

    @property
    def area(self) -> float:
        """Square metres reached."""
        return float(self.mask.sum()) * self.cell * self.cell


def reachable(world: WorldGeometry, radius: float) -> Reachable:
    """The cells from which a robot of ``radius`` can drive to the world's default spawn. When
    the spawn itself is blocked (a world whose default spawn is in a wall), the largest
    connected free region stands in for it."""
    from PIL import Image, ImageDraw

    x0, x1, y0, y1 = world.bounds
    cell = max(CELL_M, math.sqrt((x1 - x0) * (y1 - y0) / MAX_CELLS))
    w, h = max(1, math.ceil((x1 - x0) / cell)), max(1, math.ceil((y1 - y0) / cell))

    def px(x: float, y: float) -> tuple[float, float]:
        return (x - x0) / cell, (y - y0) / cell

    image = Image.new("1", (w, h), 0)
    draw = ImageDraw.Draw(image)
    for poly in world.polygons:
        draw.polygon([px(float(x), float(y)) for x, y in poly], fill=1)
    for cx, cy, r in np.asarray(world.circles).reshape(-1, 3):
        (ax, ay), (bx, by) = px(cx - r, cy - r), px(cx + r, cy + r)
        draw.ellipse([ax, ay, bx, by], fill=1)
    occupied = np.array(image, dtype=bool)
    free = ~_grow(occupied, radius / cell)
    k = math.ceil(radius / cell)  # the bounds keep the robot in, as a wall would
    free[:k, :] = free[-k:, :] = False
    free[:, :k] = free[:, -k:] = False
    sx, sy, _ = world.default_spawn
    col, row = int((sx - x0) / cell), int((sy - y0) / cell)
    if 0 <= row < h and 0 <= col < w and free[row, col]:
        seed = np.zeros_like(free)
        seed[row, col] = True
        mask = _flood(free, seed)
    else:
        mask = _largest_region(free)
    return Reachable(x0, y0, cell, mask)


def _grow(occupied: npt.NDArray[np.bool_], r: float) -> npt.NDArray[np.bool_]:
    """Occupied cells grown by a disc of ``r`` cells."""
    k = math.ceil(r)
    h, w = occupied.shape
    padded = np.pad(occupied, k)
    grown = np.zeros_like(occupied)
    for dy in range(-k, k + 1):
        for dx in range(-k, k + 1):
            if dx * dx + dy * dy <= r * r:
                grown |= padded[k + dy : k + dy + h, k + dx : k + dx + w]
    return grown


def _runs(free: npt.NDArray[np.bool_]) -> npt.NDArray[np.int64]:
    """A label for each run of free cells along the rows (0 for blocked cells)."""
    starts = free & ~np.pad(free, ((0, 0), (1, 0)))[:, :-1]
    labels = np.cumsum(starts.ravel()).reshape(free.shape)
    return np.where(free, labels, 0)


def _flood(free: npt.NDArray[np.bool_], seed: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
    """The free cells connected (4-neighbours) to ``seed``: whole runs along rows, then along
    columns, until a sweep reaches nothing new."""
    rows, cols = _runs(free), _runs(free.T.copy()).T
    reach = seed & free
    while True:
        before = int(reach.sum())
        for labels in (rows, cols):
            hit = np.zeros(int(labels.max()) + 1, dtype=bool)
            hit[labels[reach]] = True
            hit[0] = False
            reach = hit[labels]
        if int(reach.sum()) == before:
            return reach


def _largest_region(free: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
    left = free.copy()
    best = np.zeros_like(free)
    while left.sum() > best.sum():  # a region left could still be the largest
        seed = np.zeros_like(free)
        seed.flat[int(np.argmax(left))] = True
        region = _flood(free, seed)
        if region.sum() > best.sum():
            best = region
        left &= ~region
    return best
