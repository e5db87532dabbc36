"""The cells a robot holds are those its circle overlaps: never one fewer (two robots' cells
must keep their bodies apart), and none the circle misses."""

from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from simd.core.worldfile import world_from_dict
from simd.nav.cells import CellGraph
from simd.nav.traffic import Traffic

WORLD = world_from_dict({"name": "open", "bounds": {"x_min": -2.0, "x_max": 2.0, "y_min": -2.0, "y_max": 2.0}})
TRAFFIC = Traffic(CellGraph(WORLD, 0.3667, align=True, one_way=False))


@settings(max_examples=300, deadline=None)
@given(
    x=st.floats(-1.5, 1.5),
    y=st.floats(-1.5, 1.5),
    r=st.floats(0.05, 0.35),
)
def test_the_cells_held_are_exactly_those_the_circle_overlaps(x: float, y: float, r: float) -> None:
    g = TRAFFIC.graph.grid
    held = set(TRAFFIC.box(x, y, r))
    # every point of the disc (sampled on rings) lies in a cell held
    for k in range(1, 9):
        rho = r * k / 8
        for j in range(64):
            a = 2 * math.pi * j / 64
            c = TRAFFIC.graph.index(x + rho * math.cos(a), y + rho * math.sin(a))
            assert c is None or c in held, (x, y, r, c)
    # and every cell held comes within r of the centre
    for c in held:
        row, col = divmod(c, g.width)
        cx0, cy0 = g.x0 + col * g.resolution, g.y0 + row * g.resolution
        dx = min(abs(x - cx0), abs(x - cx0 - g.resolution)) if not cx0 <= x <= cx0 + g.resolution else 0.0
        dy = min(abs(y - cy0), abs(y - cy0 - g.resolution)) if not cy0 <= y <= cy0 + g.resolution else 0.0
        assert math.hypot(dx, dy) <= r + 1e-9, (x, y, r, c)


def test_near_a_corner_the_circle_holds_three_cells_where_its_square_holds_four() -> None:
    g = TRAFFIC.graph.grid
    cx, cy = g.x0 + 5 * g.resolution, g.y0 + 5 * g.resolution  # a corner shared by four cells
    r = 0.12
    d = r * 0.85  # within r of both borders, not within r of the corner
    assert len(TRAFFIC.box(cx + d, cy + d, r)) == 3
    assert len(TRAFFIC.box(cx + 0.05, cy + 0.05, r)) == 4  # within r of the corner: all four
