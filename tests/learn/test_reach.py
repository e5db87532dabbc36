"""Starts and goals are drawn only where the robot can drive from the world's spawn."""

from __future__ import annotations

import collections

import numpy as np

from learn.navigate import NavigateEnv
from learn.reach import reachable
from simd.core.models import MODELS
from simd.core.worldfile import world_from_dict


def test_a_walled_off_room_is_not_reachable() -> None:
    world = world_from_dict(
        {
            "name": "two_rooms",
            "bounds": {"x_min": 0.0, "x_max": 6.0, "y_min": 0.0, "y_max": 3.0},
            "default_spawn": {"x": 1.0, "y": 1.5, "yaw": 0.0},
            "obstacles": [{"type": "box", "name": "wall", "x_min": 2.9, "x_max": 3.1, "y_min": 0.0, "y_max": 3.0}],
        }
    )
    region = reachable(world, 0.124)
    assert region.contains(1.0, 1.5) and region.contains(2.5, 2.5)
    assert not region.contains(4.5, 1.5) and not region.contains(3.0, 1.5)
    assert 6.0 < region.area < 9.0  # the left room (2.9 m x 3 m) less a robot radius all round
    opened = world_from_dict(  # a door in the wall joins the rooms
        {
            "name": "two_rooms_door",
            "bounds": {"x_min": 0.0, "x_max": 6.0, "y_min": 0.0, "y_max": 3.0},
            "default_spawn": {"x": 1.0, "y": 1.5, "yaw": 0.0},
            "obstacles": [
                {"type": "box", "name": "wall_s", "x_min": 2.9, "x_max": 3.1, "y_min": 0.0, "y_max": 1.2},
                {"type": "box", "name": "wall_n", "x_min": 2.9, "x_max": 3.1, "y_min": 1.8, "y_max": 3.0},
            ],
        }
    )
    assert reachable(opened, 0.124).contains(4.5, 1.5)
    assert not reachable(opened, 0.35).contains(4.5, 1.5)  # a robot wider than the door stays out


def test_navigate_draws_inside_turtlebot3_worlds_wall() -> None:
    """Checked against a flood fill of the simulator's own collision test from the spawn (0.1 m
    steps, no raster): every drawn start and goal is within a step of a pose it reached."""
    env = NavigateEnv(lidar_noise=False)
    model = MODELS["burger"]
    sx, sy, _ = env.places.geometry.default_spawn
    step = 0.1
    seen = {(0, 0)}
    todo = collections.deque([(0, 0)])
    while todo:
        i, j = todo.popleft()
        for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            cell = (i + di, j + dj)
            if cell not in seen and not env.places.touches(model, sx + cell[0] * step, sy + cell[1] * step, 0.0):
                seen.add(cell)
                todo.append(cell)
    assert 1200 < len(seen) < 3000  # the hexagon's floor, not the rectangle of the bounds (~6 000)
    outside = 0
    for seed in range(150):
        _, info = env.reset(seed=seed)
        for x, y in (info["pose"][:2], info["goal"]):
            near = (round((x - sx) / step), round((y - sy) / step))
            if not any((near[0] + a, near[1] + b) in seen for a in (-1, 0, 1) for b in (-1, 0, 1)):
                outside += 1
    assert outside == 0
    env.close()
    assert np.isfinite(info["distance"])
