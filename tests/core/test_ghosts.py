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
    """A fleet's thousands of ghosts change pose every tick: as columns, and only those near
    this world's robots are bodies in its physics; a near one is driven to its new pose each
    tick (a robot in the way is pushed, as on the ghost's own daemon), and only a jump is a
    teleport. The lidar sees them all."""
    from simd.core.ghosts import GhostColumns

    sim = Simulation(load_world("empty"), SimConfig(noise=False, lidar_thread=False, cmd_timeout=0))
    sim.spawn(SpawnRequest(name="a", x=0.0, y=0.0, yaw=0.0))
    names = ["g0", "g1", *(f"far{i}" for i in range(300))]
    far = np.arange(300, dtype=np.float64)

    def ghosts(x0: float) -> GhostColumns:
        xs = np.concatenate([[x0, 3.0], -3.0 + (far % 20) * 0.3])
        ys = np.concatenate([[0.0, 0.0], 1.0 + (far // 20) * 0.3])
        return GhostColumns(names, ["burger"] * len(names), xs, ys, np.zeros(len(names)))

    sim.set_ghosts(ghosts(1.5))
    sim.step()
    assert sim._ghosts.bodies == 0 and len(sim.ghosts) == len(names)  # nobody near a yet: no bodies
    assert 1.35 < _front(sim) < 1.5  # but the lidar sees g0 straight ahead
    x0, body = 1.5, None
    for _ in range(340):  # g0 comes at 0.15 m/s (5 mm a tick) and drives 0.2 m into a
        x0 -= 0.005
        sim.set_ghosts(ghosts(x0))
        sim.step()
        g0 = sim.physics._ghosts.get("g0")
        if g0 is not None:
            body = body or g0
            assert g0 is body  # once near, the same body all along
            assert abs(g0.position.x - x0) < 1e-9 and abs(g0.position.y) < 1e-9  # where its daemon put it
    assert body is not None and sim._ghosts.bodies == 1  # g0 alone is near a
    a = sim.state(sim.find("a"))  # type: ignore[arg-type]
    assert a.x < -0.05  # pushed back by the ghost that ran into it
    sim.set_ghosts(ghosts(-3.0))  # a jump (its daemon reset it): put there, nobody swept away
    before = a.x
    sim.step()
    assert abs(sim.state(sim.find("a")).x - before) < 0.01  # type: ignore[arg-type]
    assert "g0" not in sim.physics._ghosts  # and no longer near a: not a body
    sim.close()
