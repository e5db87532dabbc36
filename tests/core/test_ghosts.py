"""Robots simulated elsewhere (another daemon of a shared fleet) are seen by this world's lidar
and block its robots, but are not its robots."""

from __future__ import annotations

import numpy as np

from protocol.control import SpawnRequest
from simd.core.sim import SimConfig, Simulation
from simd.core.worldfile import load_world


def _front(sim: Simulation) -> float:
    """Range straight ahead in the robot's next scan."""
    for _ in range(sim.config.scan_every):
        snap = sim.step()
        if snap.scan_namespaces:
            return float(snap.scans[0][0])
    raise AssertionError("no scan in a lidar period")


def test_a_ghost_is_seen_felt_and_left_out_of_the_fleet() -> None:
    sim = Simulation(load_world("empty"), SimConfig(noise=False, lidar_thread=False, cmd_timeout=0))
    sim.spawn(SpawnRequest(name="a", x=0.0, y=0.0, yaw=0.0))
    assert np.isposinf(_front(sim))  # nothing ahead on the empty floor
    sim.set_ghosts({"g": ("burger", 1.0, 0.0, 0.0)})
    ahead = _front(sim)
    assert 0.85 < ahead < 1.05  # the ghost's rear, about a metre ahead of the lidar
    assert [s.name for s in sim.states()] == ["a"] and len(sim) == 1
    sim.command(sim.find("a"), 0.22, 0.0)  # type: ignore[arg-type]
    for _ in range(300):  # 10 s at full speed would carry it 2.2 m: the ghost stops it
        sim.step()
    x = sim.state(sim.find("a")).x  # type: ignore[arg-type]
    assert 0.6 < x < 0.9  # stopped nose to tail
    sim.set_ghosts({"g": ("burger", 1.0, 2.0, 0.0)})  # it moved away (on its own daemon)
    assert np.isposinf(_front(sim))
    sim.set_ghosts({})
    assert sim.ghosts == {}
    sim.set_ghosts({"h": ("no_such_model", 1.0, 0.0, 0.0), "k": ("burger", float("nan"), 0.0, 0.0)})
    assert sim.ghosts == {}  # left out, not a crash
    sim.close()
