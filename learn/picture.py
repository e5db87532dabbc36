"""A top-down picture of an environment's world, in the viewer's colours: walls and obstacles,
every robot's footprint, the agents' goals and their latest scans."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

import numpy as np
import numpy.typing as npt

from simd.core.models import RobotModel
from simd.core.worldfile import WorldGeometry

SIZE = 480  # pixels on the world's longer side
BACKGROUND = (246, 246, 242)
WALL = (70, 70, 78)
ROBOT = (52, 101, 164)
GOAL = (78, 154, 6)
SCAN = (204, 0, 0)


def top_down(
    world: WorldGeometry, robots: Iterable[tuple[str, RobotModel, tuple[float, float, float]]],
    goal: tuple[float, float] | Mapping[str, tuple[float, float]], agent: str | None = None,
    scan: npt.NDArray[np.float32] | None = None,
) -> npt.NDArray[np.uint8]:  # fmt: skip
    """An (H, W, 3) uint8 image of ``world`` with ``robots`` (name, model, pose) on it, and the
    scan of ``agent``. ``goal`` is one point, or a point per agent. The poses are the caller's
    (the env's latest), so that a remote episode draws as an in-process one."""
    from PIL import Image, ImageDraw

    x0, x1, y0, y1 = world.bounds
    scale = SIZE / max(x1 - x0, y1 - y0)
    w, h = max(1, round((x1 - x0) * scale)), max(1, round((y1 - y0) * scale))

    def px(x: float, y: float) -> tuple[float, float]:
        return (x - x0) * scale, (y1 - y) * scale

    image = Image.new("RGB", (w, h), BACKGROUND)
    draw = ImageDraw.Draw(image)
    for poly in world.polygons:
        draw.polygon([px(float(x), float(y)) for x, y in poly], fill=WALL)
    for cx, cy, r in np.asarray(world.circles).reshape(-1, 3):
        (ax, ay), (bx, by) = px(cx - r, cy + r), px(cx + r, cy - r)
        draw.ellipse([ax, ay, bx, by], fill=WALL)
    goals = goal if isinstance(goal, Mapping) else {agent or "": goal}
    for gx, gy in goals.values():
        (ax, ay), (bx, by) = px(gx - 0.1, gy + 0.1), px(gx + 0.1, gy - 0.1)
        draw.ellipse([ax, ay, bx, by], outline=GOAL, width=3)
    for name, model, (x, y, yaw) in robots:
        c, sn = math.cos(yaw), math.sin(yaw)
        outline = [px(x + ox * c - oy * sn, y + ox * sn + oy * c) for ox, oy in model.outline]
        draw.polygon(outline, fill=ROBOT)
        if name == agent and scan is not None:
            lx, ly = model.lidar_offset
            sx, sy = x + lx * c - ly * sn, y + lx * sn + ly * c
            angles = yaw + np.arange(len(scan)) * (2 * math.pi / len(scan))
            ok = np.isfinite(scan)
            for a, r in zip(angles[ok], scan[ok], strict=True):
                qx, qy = px(sx + r * math.cos(a), sy + r * math.sin(a))
                draw.rectangle([qx - 1, qy - 1, qx + 1, qy + 1], fill=SCAN)
    return np.asarray(image, dtype=np.uint8)
