"""How robots follow each other through the cells (simd/nav/traffic.py, floor.py): every step's
cells are the robot's own or promised to it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from protocol.control import SpawnRequest
from protocol.navigation import NavigateRequest
from simd.core.models import MODELS
from simd.core.sim import SimConfig, Simulation
from simd.core.worldfile import load_world
from simd.nav.navigator import Navigator


def _crowd(seed: int) -> tuple[Simulation, Navigator, list[str], np.random.Generator]:
    """Ten burgers in turtlebot3_world placed and sent as bench.nav_crowd does for ``seed``."""
    from bench.nav_crowd import MIN_APART_M, goal_points

    world = load_world("turtlebot3_world")
    sim = Simulation(world, SimConfig(seed=0))
    nav = Navigator(world, sim.config.lidar, sim.robots)
    points = goal_points(nav, world, MODELS["burger"])
    rng = np.random.default_rng(seed)
    names: list[str] = []
    while len(names) < 10:
        x, y = points[rng.integers(len(points))]
        if names and np.hypot(sim.robots.x - x, sim.robots.y - y).min() < MIN_APART_M:
            continue
        names.append(f"r{len(names)}")
        sim.spawn(SpawnRequest(name=names[-1], x=float(x), y=float(y), yaw=float(rng.uniform(-math.pi, math.pi))))
    return sim, nav, names, rng


@pytest.mark.parametrize("seed", [3, 31])  # (each once had a step's cell neither its own nor promised to it)
def test_every_cell_a_step_needs_is_the_robots_or_promised_to_it(seed: int) -> None:
    """Checked at every control step of a crowd's first 40 s: a cell no longer promised to a
    robot that still needs it (a pushed robot's diagonal over its pusher's cells took the
    promise, or a route cut short dropped one its kept step shared) stays out of its reach for
    ever, and everybody behind it waits: a jam that ends only when the goals fail."""
    from bench.nav_crowd import goal_points

    sim, nav, names, rng = _crowd(seed)
    points = goal_points(nav, sim.world, MODELS["burger"])

    def send(name: str) -> None:
        row = sim.robots.row_of(name)
        hx, hy = float(sim.robots.x[row]), float(sim.robots.y[row])
        while True:
            x, y = points[rng.integers(len(points))]
            if math.hypot(x - hx, y - hy) > 1.0:
                nav.goal(name, MODELS["burger"], NavigateRequest(x=float(x), y=float(y), tolerance=0.1), sim.time)
                return

    for name in names:
        send(name)
    traffic = nav.floor.traffic
    checked = 0
    for _ in range(int(40 / sim.config.dt)):
        nav.step(sim.robots, sim.tick, sim.time)
        nav.apply(sim.robots, sim.command_rows)
        nav.observe(sim.step())
        for r in nav.take_events().results:
            send(r.robot)
        if sim.tick % nav.config.control_every == 1:
            for m in traffic.movers.values():
                for k, cells in enumerate(m.needs):
                    for c in cells:
                        assert m.slot in (traffic.owner[c], traffic.pending[c]), (sim.time, m.slot, k, c)
                        checked += 1
    assert checked > 1000  # the crowd did take steps
