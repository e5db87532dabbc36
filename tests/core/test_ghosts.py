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


def test_ghosts_as_columns_move_by_velocity_and_push_what_they_meet() -> None:
    """A fleet's thousands of ghosts change pose every tick: as columns, the same bodies are
    driven to their new poses (a robot in the way is pushed, as on the ghost's own daemon),
    and only a jump is a teleport."""
    from simd.core.ghosts import GhostColumns

    sim = Simulation(load_world("empty"), SimConfig(noise=False, lidar_thread=False, cmd_timeout=0))
    sim.spawn(SpawnRequest(name="a", x=0.0, y=0.0, yaw=0.0))
    names = ["g0", "g1", *(f"far{i}" for i in range(300))]
    far = np.arange(300, dtype=np.float64)

    def ghosts(x0: float) -> GhostColumns:
        xs = np.concatenate([[x0, 5.0], 20.0 + far % 20])
        ys = np.concatenate([[0.0, 5.0], 20.0 + far // 20])
        return GhostColumns(names, ["burger"] * len(names), xs, ys, np.zeros(len(names)))

    sim.set_ghosts(ghosts(0.6))
    sim.step()
    bodies = dict(sim.physics._ghosts)
    assert len(bodies) == len(names)
    x0 = 0.6
    for _ in range(140):  # g0 comes at 0.15 m/s (5 mm a tick) and drives 0.26 m into a
        x0 -= 0.005
        sim.set_ghosts(ghosts(x0))
        sim.step()
        g = sim.physics.ghost_poses()[0]
        assert abs(g[0] - x0) < 1e-9 and abs(g[1]) < 1e-9  # where its daemon put it, by moving there
    assert sim.physics._ghosts == bodies  # the same bodies all along: no ghost added or removed
    a = sim.state(sim.find("a"))  # type: ignore[arg-type]
    assert a.x < -0.05  # pushed back by the ghost that ran into it
    sim.set_ghosts(ghosts(-3.0))  # a jump (its daemon reset it): put there, nobody swept away
    before = sim.state(sim.find("a")).x  # type: ignore[arg-type]
    sim.step()
    assert abs(sim.physics.ghost_poses()[0][0] + 3.0) < 1e-9
    assert abs(sim.state(sim.find("a")).x - before) < 0.01  # type: ignore[arg-type]
    sim.close()
