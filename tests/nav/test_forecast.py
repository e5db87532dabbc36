"""The traffic's forecast on an open floor: a robot deciding its next cell counts on the
robots with older goals crossing its way a few seconds on, and on nobody else."""

from __future__ import annotations

import math

from protocol.control import SpawnRequest
from protocol.navigation import NavigateRequest
from simd.core.models import MODELS
from simd.core.sim import SimConfig, Simulation
from simd.core.worldfile import world_from_dict
from simd.nav.navigator import Navigator


def expected_times(crosser: str) -> list[float]:
    """``b`` drives east along y = 0; ``a`` (with ``crosser`` "older": a goal older than
    ``b``'s, "newer", or "none": no ``a``) drives north along x = 0 and would reach the
    crossing when ``b`` does. When ``b`` is expected at its goal through each of its next
    cells, best first."""
    world = world_from_dict({"name": "open", "bounds": {"x_min": -3, "x_max": 3, "y_min": -3, "y_max": 3}})
    sim = Simulation(world, SimConfig(seed=0))
    nav = Navigator(world, sim.config.lidar, sim.robots)
    burger = MODELS["burger"]
    sim.spawn(SpawnRequest(name="b", x=-1.1, y=0.0, yaw=0.0))
    if crosser != "none":
        sim.spawn(SpawnRequest(name="a", x=0.0, y=-1.1, yaw=math.pi / 2))
    a_goal = NavigateRequest(x=0.0, y=2.0, tolerance=0.1)
    if crosser == "older":
        nav.goal("a", burger, a_goal, 0.0)
    nav.goal("b", burger, NavigateRequest(x=2.0, y=0.0, tolerance=0.1), 0.01)
    if crosser == "newer":
        nav.goal("a", burger, a_goal, 0.02)
    for _ in range(6):
        nav.step(sim.robots, sim.tick, sim.time)
        nav.apply(sim.robots, sim.command_rows)
        nav.observe(sim.step())
    traffic = nav.floor.traffic
    assert traffic.forecasting  # (an open floor)
    b = traffic.movers[nav.robots["b"].slot]
    traffic.begin_round()
    traffic.forecast_round(sim.time)
    frontier = b.route[-1] if b.route else b.cell
    return [traffic._expected(b, n, frontier) for n, _ in traffic._moves_from(b, frontier)]


def test_an_older_goals_robot_crossing_the_way_is_waited_for_and_a_newer_ones_is_not() -> None:
    alone, older, newer = expected_times("none"), expected_times("older"), expected_times("newer")
    assert newer == alone  # a newer goal makes way (priorities), so it does not hold b up
    assert older[0] > alone[0] + 1.0  # straight on: it waits at the crossing while a goes by
    bound = (2.0 - -1.1) / MODELS["burger"].max_linear_velocity
    assert bound < alone[0] < bound + 1.0  # alone: about the straight line at top speed, from now
