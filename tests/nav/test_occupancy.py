"""The world drawn as a map_server map (simd/nav/costmap.py's occupied_cells), against the
exact geometry: every cell whose centre is inside an obstacle is occupied, every cell farther
than a cell's diagonal from all of them is free, and a wall thinner than a cell leaves no gap."""

from __future__ import annotations

import numpy as np
from shapely.geometry import Point, Polygon

from simd.core.worldfile import load_world, world_from_dict
from simd.nav.costmap import Grid, occupied_cells


def test_cells_inside_obstacles_are_occupied_and_cells_clear_of_them_free() -> None:
    world = load_world("turtlebot3_world")
    grid = Grid.covering(world)
    occupied = occupied_cells(world, grid)
    assert occupied.shape == (grid.height, grid.width)
    shapes = [Polygon(p) for p in world.polygons] + [Point(x, y).buffer(r) for x, y, r in world.circles]
    rng = np.random.default_rng(0)
    for row, col in zip(rng.integers(0, grid.height, 3000), rng.integers(0, grid.width, 3000), strict=True):
        centre = Point(*grid.centre(int(row), int(col)))
        distance = min(s.distance(centre) for s in shapes)
        if distance == 0.0:
            assert occupied[row, col], (row, col)
        elif distance > grid.resolution * 0.75:
            assert not occupied[row, col], (row, col)


def test_a_wall_thinner_than_a_cell_is_a_closed_line() -> None:
    world = world_from_dict({
        "name": "thin", "bounds": {"x_min": 0.0, "x_max": 2.0, "y_min": 0.0, "y_max": 2.0},
        "default_spawn": {"x": 0.5, "y": 0.5},
        "obstacles": [{"type": "box", "x_min": 1.008, "x_max": 1.018, "y_min": 0.2, "y_max": 1.8}],
    })  # fmt: skip
    grid = Grid.covering(world, 0.05)
    occupied = occupied_cells(world, grid)
    rows = [r for r in range(grid.height) if 0.25 < grid.centre(r, 0)[1] < 1.75]
    assert all(occupied[r].any() for r in rows)  # no row of the wall's length lets a ray through
    assert occupied.sum() <= 2 * 33  # and it is at most two cells wide
