"""How robots follow each other through the cells (simd/nav/traffic.py, floor.py): every step's
cells are the robot's own or promised to it, and a follower drives up to its cell's border
while the robot ahead leaves the next cell, without taking that cell early."""

from __future__ import annotations

import math

import numpy as np
import pytest

from protocol.control import SpawnRequest
from protocol.navigation import NavigateRequest
from simd.core.models import MODELS
from simd.core.sim import SimConfig, Simulation
from simd.core.worldfile import load_world, world_from_dict
from simd.nav.navigator import Navigator
from simd.nav.traffic import FREE


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


def test_a_follower_drives_to_its_cells_border_while_the_leader_leaves_the_next() -> None:
    """``b`` comes up behind ``a``, which first turns a quarter round on the spot (a robot whose
    way starts behind it would drive off backwards at once); the cell ahead of ``b``
    is promised to it and becomes its own only once ``a``'s body has left it whole. Meanwhile
    ``b`` drives on to the border of its own cell (it used to stand at the centre), its centre
    stays in its own cell, and the two bodies keep apart."""
    world = world_from_dict({"name": "open", "bounds": {"x_min": -3.0, "x_max": 3.0, "y_min": -3.0, "y_max": 3.0}})
    sim = Simulation(world, SimConfig(seed=0))
    nav = Navigator(world, sim.config.lidar, sim.robots, None)
    sim.spawn(SpawnRequest(name="a", x=0.0, y=0.0, yaw=math.pi / 2))
    sim.spawn(SpawnRequest(name="b", x=-0.7, y=0.0, yaw=0.0))
    model = MODELS["burger"]
    nav.goal("a", model, NavigateRequest(x=2.5, y=0.0, tolerance=0.1), 0.0)
    nav.goal("b", model, NavigateRequest(x=2.0, y=0.0, tolerance=0.1), 0.01)
    traffic = nav.floor.traffic
    g = nav.floor.graph
    b = traffic.movers[nav.robots["b"].slot]
    crept = []  # b's lead over its cell's centre while a cell of its next step was still a's
    closest = math.inf
    for _ in range(int(20 / sim.config.dt)):
        nav.step(sim.robots, sim.tick, sim.time)
        nav.apply(sim.robots, sim.command_rows)
        nav.observe(sim.step())
        nav.take_events()
        xa, xb = float(sim.robots.x[0]), float(sim.robots.x[1])
        closest = min(closest, xa - xb)
        if b.route and b.cell != FREE and any(traffic.owner[c] not in (b.slot, FREE) for c in b.needs[0]):
            assert g.index(xb, float(sim.robots.y[1])) == b.cell  # its centre stays in its cell
            crept.append(xb - g.centre(b.cell)[0])
    assert crept, "b never followed a into a cell: the scene does not test what it says"
    assert max(crept) > 0.08  # near the border (0.175 m from the centre), not at the centre
    assert closest > 2 * model.radius + 0.02  # the bodies never touched
