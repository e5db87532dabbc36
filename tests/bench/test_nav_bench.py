"""bench/nav_bench.py's own arithmetic: the contact check it counts, and the goals it draws."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.nav_bench import _boxes, close_pairs, touching_pairs, warehouse_goals
from worlds.warehouse import warehouse_for_robots


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 300), st.floats(0.05, 2.0), st.integers(0, 2**31 - 1))
def test_close_pairs_are_every_pair_within_reach(n: int, reach: float, seed: int) -> None:
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(-3, 7, n), rng.uniform(-2, 4, n)
    a, b = close_pairs(x, y, reach)
    d = np.hypot(x[:, None] - x[None, :], y[:, None] - y[None, :])
    i, j = np.nonzero(np.triu(d <= reach, 1))
    assert sorted(zip(a.tolist(), b.tolist(), strict=True)) == sorted(zip(i.tolist(), j.tolist(), strict=True))


def test_touching_is_the_footprints_not_the_centres() -> None:
    boxes = _boxes("burger")
    # side by side, wheel to wheel: the burger's wheel box is 0.178 m across its axle
    for gap, touching in ((0.17, True), (0.19, False)):
        x, y, yaw = np.array([0.0, 0.0]), np.array([0.0, gap]), np.zeros(2)
        assert bool(touching_pairs(x, y, yaw, boxes, 0.5)) is touching, gap
    # nose to nose the body is shorter than it is wide
    x, y, yaw = np.array([0.0, 0.25]), np.zeros(2), np.array([0.0, math.pi])
    assert not touching_pairs(x, y, yaw, boxes, 0.5)


def test_warehouse_goals_are_aisle_cells_beside_a_shelf() -> None:
    text = warehouse_for_robots(10)
    goals = warehouse_goals(text, 0.5)
    rows = text.splitlines()[4:]
    h = len(rows)
    for gx, gy in goals.points.tolist():
        r, c = h - 1 - math.floor(gy / 0.5), math.floor(gx / 0.5)
        assert rows[r][c] == "."
        around = [rows[rr][cc] for rr, cc in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1))
                  if 0 <= rr < h and 0 <= cc < len(rows[0])]  # fmt: skip
        assert "@" in around or len(around) < 4
