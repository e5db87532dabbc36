"""PNG snapshots of the fleet, drawn with Pillow in the page's style.

:func:`fit` gives the world-to-pixel mapping a snapshot uses (tests use it to find robots in
the image); :func:`render` draws; :func:`take_snapshot` connects, waits for every robot's
odometry and one scan of each (bounded by a timeout), asks for the goals under way and their
paths, and writes the file. As on the page, a robot with a goal shows its path, the goal (the
tolerance circle, a cross, an arrow if a heading is asked for) and, when it is not simply
driving, a ring in its navigation state's colour; its label names the state.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from PIL import Image, ImageDraw, ImageFont

from clients.viewer.feed import Feed
from clients.viewer.navigation import GoalView
from clients.viewer.robot import RobotState
from clients.viewer.state import FleetState, color_rgb
from fleetcommon.polyline import nearest_on
from protocol.errors import FleetError

if TYPE_CHECKING:
    from clients.api import FleetClient
    from protocol.control import WorldInfo

log = logging.getLogger(__name__)

RGB = tuple[int, int, int]

BACKGROUND: RGB = (11, 16, 22)
FLOOR: RGB = (18, 27, 36)
GRID: RGB = (30, 42, 54)
BOUNDS: RGB = (52, 70, 88)
OBSTACLE: RGB = (58, 74, 94)
OBSTACLE_EDGE: RGB = (120, 142, 168)
ROBOT_EDGE: RGB = (8, 10, 14)
HEADING: RGB = (250, 250, 250)
TEXT: RGB = (226, 232, 240)
MUTED: RGB = (140, 154, 170)

#: navigation states, coloured as on the page (clients/viewer/static/viewer.js NAV_COLORS)
NAV_COLORS: dict[str, RGB] = {
    "planning": (159, 179, 200), "driving": (6, 214, 160), "waiting": (255, 209, 102),
    "yielding": (251, 133, 0), "blocked": (255, 89, 94), "overridden": (247, 37, 133),
}  # fmt: skip
#: the states that get a ring round the robot (navigating, but not simply driving)
NAV_RING = frozenset({"planning", "waiting", "yielding", "blocked", "overridden"})

#: a robot farther than this (m) from its path is not joined to it (the page's PATH_OFF_M)
PATH_OFF_M = 0.3

SUPERSAMPLE = 2
MARGIN = 0.04  # of the image side, around the content
ROBOTS_PAD = 1.5  # m around the robots when a world has no geometry to frame


@dataclass(frozen=True)
class Transform:
    """World metres to image pixels (x right, y down); ``scale`` is pixels per metre."""

    cx: float
    cy: float
    scale: float
    width: int
    height: int

    def to_pixel(self, x: float, y: float) -> tuple[float, float]:
        return (
            self.width / 2 + (x - self.cx) * self.scale,
            self.height / 2 - (y - self.cy) * self.scale,
        )

    def scaled(self, k: int) -> Transform:
        return Transform(self.cx, self.cy, self.scale * k, self.width * k, self.height * k)


def content_rect(world: WorldInfo | None, poses: Sequence[tuple[float, float]]) -> tuple[float, float, float, float]:
    """What a view should frame: the world's bounds if it has geometry, else the robots
    (grown by ROBOTS_PAD), else a 10 m square around the origin. Same rule as the page."""
    if world is not None and (world.polygons or world.circles):
        b = world.bounds
        return b.x_min, b.y_min, b.x_max, b.y_max
    if poses:
        xs = [p[0] for p in poses]
        ys = [p[1] for p in poses]
        return (
            min(xs) - ROBOTS_PAD,
            min(ys) - ROBOTS_PAD,
            max(xs) + ROBOTS_PAD,
            max(ys) + ROBOTS_PAD,
        )
    return -5.0, -5.0, 5.0, 5.0


def fit(world: WorldInfo | None, poses: Sequence[tuple[float, float]], size: int) -> Transform:
    """The transform of a ``size`` x ``size`` snapshot of this world with robots at ``poses``."""
    x0, y0, x1, y1 = content_rect(world, poses)
    usable = size * (1 - 2 * MARGIN)
    scale = usable / max(x1 - x0, y1 - y0, 1e-3)
    return Transform((x0 + x1) / 2, (y0 + y1) / 2, scale, size, size)


def outer_edges(
    polygons: Sequence[Sequence[tuple[float, float]]],
) -> list[tuple[tuple[float, float], tuple[float, float]]]:
    """The polygons' edges minus those two polygons share (a wall split into convex pieces
    is outlined as one shape)."""

    def key(a: tuple[float, float]) -> tuple[float, float]:
        return round(a[0], 4), round(a[1], 4)

    edges = [(a, poly[(i + 1) % len(poly)]) for poly in polygons for i, a in enumerate(poly)]
    count: dict[frozenset[tuple[float, float]], int] = {}
    for a, b in edges:
        k = frozenset((key(a), key(b)))
        count[k] = count.get(k, 0) + 1
    return [(a, b) for a, b in edges if count[frozenset((key(a), key(b)))] == 1]


def _mix(c: RGB, bg: RGB, a: float) -> RGB:
    return (
        round(c[0] * a + bg[0] * (1 - a)),
        round(c[1] * a + bg[1] * (1 - a)),
        round(c[2] * a + bg[2] * (1 - a)),
    )


def _font(px: int) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    return ImageFont.load_default(size=px)


def _grid_step(scale: float) -> float:
    for step in (0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0):
        if step * scale >= 40 * SUPERSAMPLE:
            return step
    return 100.0


def render(
    world: WorldInfo | None,
    robots: Sequence[RobotState],
    size: int = 1024,
    sim_time: float | None = None,
    goals: dict[str, GoalView] | None = None,
) -> tuple[Image.Image, Transform]:
    """Draw the world, robots (footprint, heading, label), scans and trails, and the
    ``goals`` under way (paths, goal marks, state rings)."""
    tf = fit(world, [(r.x, r.y) for r in robots], size)
    k = SUPERSAMPLE
    big = tf.scaled(k)
    img = Image.new("RGB", (big.width, big.height), BACKGROUND)
    d = ImageDraw.Draw(img)
    px = big.to_pixel

    if world is not None:
        b = world.bounds
        (ax, ay), (bx, by) = px(b.x_min, b.y_max), px(b.x_max, b.y_min)
        d.rectangle((ax, ay, bx, by), fill=FLOOR)
        step = _grid_step(big.scale)
        gx = math.ceil(b.x_min / step) * step
        while gx <= b.x_max:
            d.line((px(gx, b.y_min), px(gx, b.y_max)), fill=GRID, width=k)
            gx += step
        gy = math.ceil(b.y_min / step) * step
        while gy <= b.y_max:
            d.line((px(b.x_min, gy), px(b.x_max, gy)), fill=GRID, width=k)
            gy += step
        d.rectangle((ax, ay, bx, by), outline=BOUNDS, width=k)
        for poly in world.polygons:
            d.polygon([px(x, y) for x, y in poly], fill=OBSTACLE)
        for e0, e1 in outer_edges(world.polygons):
            d.line((px(*e0), px(*e1)), fill=OBSTACLE_EDGE, width=k)
        for circ in world.circles:
            cx, cy = px(circ.x, circ.y)
            rr = circ.radius * big.scale
            d.ellipse((cx - rr, cy - rr, cx + rr, cy + rr), fill=OBSTACLE, outline=OBSTACLE_EDGE, width=k)

    now = sim_time if sim_time is not None else max((r.stamp for r in robots), default=0.0)
    for r in robots:  # trails under everything robot-related
        pts = [px(float(x), float(y)) for x, y in r.trail_array()] + [px(r.x, r.y)]
        if len(pts) >= 2:
            d.line(
                pts,
                fill=_mix(color_rgb(r.color), FLOOR, 0.45),
                width=2 * k,
            )
    dot = max(1.0, 1.1 * k)
    for r in robots:
        col = _mix(color_rgb(r.color), FLOOR, 0.85)
        for x, y in r.scan_points(1):
            sx, sy = px(float(x), float(y))
            d.rectangle((sx - dot, sy - dot, sx + dot, sy + dot), fill=col)
    goals = goals or {}
    _draw_goals(d, px, big.scale, robots, goals)
    for r in robots:
        c, s = math.cos(r.yaw), math.sin(r.yaw)
        fp = r.footprint
        outline = [px(r.x + c * fp[i] - s * fp[i + 1], r.y + s * fp[i] + c * fp[i + 1]) for i in range(0, len(fp), 2)]
        if len(outline) >= 3:
            d.polygon(outline, fill=color_rgb(r.color), outline=ROBOT_EDGE, width=k)
        reach = _reach(r)
        d.line(
            (px(r.x, r.y), px(r.x + c * reach * 1.45, r.y + s * reach * 1.45)),
            fill=HEADING,
            width=2 * k,
        )

    label_font = _font(13 * k)
    for r in robots:
        reach = _reach(r)
        lx, ly = px(r.x, r.y)
        text = r.name if r.name == r.namespace else f"{r.name} ({r.namespace})"
        goal = goals.get(r.namespace)
        if goal is not None:
            text += f" · {goal.state}"
        pos = (lx + reach * big.scale + 4 * k, ly - reach * big.scale - 14 * k)
        d.text((pos[0] + k, pos[1] + k), text, fill=BACKGROUND, font=label_font)
        d.text(pos, text, fill=TEXT, font=label_font)

    plural = "s" if len(robots) != 1 else ""
    title = f"{world.name if world else 'fleet'} · {len(robots)} robot{plural} · t = {now:.1f} s"
    d.text((14 * k, 10 * k), title, fill=TEXT, font=_font(16 * k))
    bar = _grid_step(big.scale)
    y = big.height - 16 * k
    d.line((16 * k, y, 16 * k + bar * big.scale, y), fill=TEXT, width=2 * k)
    d.text((20 * k + bar * big.scale, y - 9 * k), f"{bar:g} m", fill=MUTED, font=_font(12 * k))
    return img.resize((tf.width, tf.height), Image.Resampling.LANCZOS), tf


def goal_rgb(color: int) -> RGB:
    """The colour of a robot's path and goal mark: its own, a little faded into the floor."""
    return _mix(color_rgb(color), FLOOR, 0.7)


def path_ahead(path: list[tuple[float, float]], x: float, y: float) -> list[tuple[float, float]]:
    """What is left of ``path`` for a robot at (x, y): from the robot when it is within
    PATH_OFF_M of the path, else from the path's point nearest to it (no line through a wall to
    get there), as the page draws it. The path was planned from where the robot stood then."""
    if len(path) < 2:
        return []
    off, at, k = nearest_on(path, x, y)
    return [(x, y) if off <= PATH_OFF_M else at, *path[k + 1 :]]


def _reach(r: RobotState) -> float:
    fp = r.footprint
    return max((math.hypot(fp[i], fp[i + 1]) for i in range(0, len(fp), 2)), default=0.1)


def _draw_goals(
    d: ImageDraw.ImageDraw,
    px: Callable[[float, float], tuple[float, float]],
    scale: float,
    robots: Sequence[RobotState],
    goals: dict[str, GoalView],
) -> None:
    """Each goal's path from the robot on and its mark, in the robot's colour; a ring in the
    state's colour round each robot that navigates but is not simply driving."""
    k = SUPERSAMPLE
    for r in robots:
        goal = goals.get(r.namespace)
        if goal is None:
            continue
        col = goal_rgb(r.color)
        ahead = path_ahead(goal.path, r.x, r.y)
        if len(ahead) >= 2:
            d.line([px(x, y) for x, y in ahead], fill=col, width=2 * k, joint="curve")
        cx, cy = px(goal.x, goal.y)
        rr = max(goal.tolerance * scale, 3 * k)
        d.ellipse((cx - rr, cy - rr, cx + rr, cy + rr), outline=col, width=2 * k)
        c = max(3 * k, min(7 * k, rr * 0.5))
        d.line((cx - c, cy, cx + c, cy), fill=col, width=2 * k)
        d.line((cx, cy - c, cx, cy + c), fill=col, width=2 * k)
        if goal.yaw is not None:
            length, a = max(rr + 8 * k, 16 * k), -goal.yaw  # image y points down
            ex, ey = cx + math.cos(a) * length, cy + math.sin(a) * length
            d.line((cx, cy, ex, ey), fill=col, width=2 * k)
            for side in (-0.45, 0.45):
                tip = (ex - 7 * k * math.cos(a + side), ey - 7 * k * math.sin(a + side))
                d.line((ex, ey, *tip), fill=col, width=2 * k)
        if goal.state in NAV_RING:
            x, y = px(r.x, r.y)
            ring = _reach(r) * scale + 4 * k
            d.ellipse((x - ring, y - ring, x + ring, y + ring), outline=NAV_COLORS[goal.state], width=2 * k)


def take_snapshot(client: FleetClient, path: Path, size: int = 1024, timeout: float = 5.0) -> int:
    """Connect, wait for every robot's odometry and one scan and for the goals under way (at
    most ``timeout`` s in all), write the PNG. Returns the number of robots drawn."""
    state = FleetState()
    feed = Feed(client, state)
    try:
        feed.start()
        expected = {r.namespace for r in client.robots()}
        deadline = time.monotonic() + timeout
        while not state.ready(expected) and time.monotonic() < deadline:
            time.sleep(0.02)
        if not state.ready(expected):
            log.warning(
                "not every robot reported odometry and a scan within %g s; drawing what arrived",
                timeout,
            )
        # the robots with a path have a goal under way: wait for its row (P/navigation, 2 Hz)
        try:
            planned = set(client.plans()) & expected
        except FleetError as e:  # a daemon too busy to say: no goals drawn
            log.warning("could not ask for the robots' paths: %s", e)
            planned = set()
        while not state.has_goal(planned) and time.monotonic() < deadline:
            time.sleep(0.02)
        robots = state.robots()
        img, _ = render(state.world, robots, size, state.sim_time, state.goals_under_way())
    finally:
        feed.close()
    path.parent.mkdir(parents=True, exist_ok=True)
    img.save(path, optimize=True)
    return len(robots)
