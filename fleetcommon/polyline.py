"""Where a point meets a polyline: what a navigating robot drives along (simd/nav/floor.py) and
what the viewer draws of a path from the robot on (clients/viewer/snapshot.py) both ask it."""

from __future__ import annotations

import math
from collections.abc import Sequence


def nearest_on(line: Sequence[tuple[float, float]], x: float, y: float) -> tuple[float, tuple[float, float], int]:
    """The point of polyline ``line`` (two points at least) nearest (x, y): its distance, the
    point, and the index of the segment it is on (the later of two equally near segments, so
    a robot at a corner is on its way on)."""
    best, at, k_best = math.inf, line[0], 0
    for k in range(len(line) - 1):
        (ax, ay), (bx, by) = line[k], line[k + 1]
        dx, dy = bx - ax, by - ay
        length2 = dx * dx + dy * dy
        t = 0.0 if length2 == 0 else min(1.0, max(0.0, ((x - ax) * dx + (y - ay) * dy) / length2))
        px, py = ax + t * dx, ay + t * dy
        d = math.hypot(px - x, py - y)
        if d <= best + 1e-9:
            best, at, k_best = d, (px, py), k
    return best, at, k_best
