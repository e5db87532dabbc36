"""The simulation core without any network: determinism, collisions, sensors, reset."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest
from shapely.geometry import Point as SPoint
from shapely.geometry import Polygon

from protocol import ErrorCode, FleetError, SpawnRequest
from simd.core.models import BURGER
from simd.core.sim import SimConfig, Simulation
from simd.core.worldfile import load_world, world_from_dict

MULTI = [(-2.0, -0.5), (0.5, -2.0), (2.0, 0.5), (-0.5, 2.0)]


def fleet(seed: int = 7, noise: bool = True, lidar_thread: bool = True) -> Simulation:
    sim = Simulation(load_world("turtlebot3_world"), SimConfig(seed=seed, noise=noise, lidar_thread=lidar_thread))
    for i, (x, y) in enumerate(MULTI, 1):
        sim.spawn(SpawnRequest(name=f"burger_{i}", namespace=f"TB3_{i}", x=x, y=y))
    return sim


def rollout(sim: Simulation, ticks: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    poses, scans = [], []
    for k in range(ticks):
        v = 0.15 + 0.05 * math.sin(k / 10)
        cmds = {f"TB3_{i}": (v, 0.8 * math.cos(k / 7 + i)) for i in range(1, 5)}
        sim.command_many(cmds)
        out = sim.step()
        poses.append(np.stack([out.x, out.y, out.yaw, out.linear_x, out.angular_z]))
        scans.append(out.scans.copy())
    return poses, scans


def test_same_seed_same_commands_identical_odometry_and_scans() -> None:
    p1, s1 = rollout(fleet(seed=3), 150)
    p2, s2 = rollout(fleet(seed=3), 150)
    assert all(np.array_equal(a, b) for a, b in zip(p1, p2, strict=True))
    assert all(np.array_equal(a, b) for a, b in zip(s1, s2, strict=True))
    assert sum(len(s) for s in s1) == 150 * 4 // 6  # every robot scans at 5 Hz
    _, s3 = rollout(fleet(seed=4), 150)
    assert not all(np.array_equal(a, b) for a, b in zip(s1, s3, strict=True))


def test_the_lidar_thread_gives_the_scans_of_the_simulation_thread_bit_for_bit() -> None:
    """Scans read only at the end, so that the lidar's jobs queue up behind the ticks, and a
    reset with jobs still queued (they draw from the noise generator it replaces)."""

    def run(lidar_thread: bool) -> list[np.ndarray]:
        sim = fleet(seed=5, lidar_thread=lidar_thread)
        snaps = []
        for k in range(90):
            sim.command_many({f"TB3_{i}": (0.2, 0.5 * math.sin(k / 9 + i)) for i in range(1, 5)})
            snaps.append(sim.step())
            if k == 44:
                sim.reset()
        sim.close()
        return [np.concatenate([s.x, s.y, s.yaw, s.scans.reshape(-1)]) for s in snaps]

    threaded, inline = run(True), run(False)
    assert all(np.array_equal(a, b) for a, b in zip(threaded, inline, strict=True))
    assert sum(a.size for a in threaded) > 90 * 12 + 4 * 360  # scans were taken


@pytest.mark.parametrize("robots", [40, 5])
def test_scans_wanted_at_once_are_the_lidar_threads_bit_for_bit(robots: int) -> None:
    """A step's last tick casts its scans on the simulation's thread (its reply waits for
    them); with the lidar's earlier jobs still queued (scans read only at the end), the noise
    must still be drawn in tick order."""

    def run(wanted_every: int) -> list[np.ndarray]:
        sim = Simulation(load_world("empty"), SimConfig(seed=9, lidar_thread=wanted_every > 0))
        for i in range(robots):  # a grid 1.5 m apart: each sees the others
            sim.spawn(SpawnRequest(name=f"r{i}", x=1.5 * (i % 8), y=1.5 * (i // 8), yaw=0.3 * i))
        snaps = []
        for k in range(40):
            sim.command_many({f"r{i}": (0.2, 0.5 * math.sin(k / 9 + i)) for i in range(robots)})
            snaps.append(sim.step(scans_wanted=wanted_every > 0 and k % wanted_every == 0))
            if k == 25:
                sim.reset()
        sim.close()
        return [np.concatenate([s.x, s.yaw, s.scans.reshape(-1)]) for s in snaps]

    inline = run(0)
    for every in (1, 5):
        assert all(np.array_equal(a, b) for a, b in zip(run(every), inline, strict=True))
    assert sum(a.size for a in inline) > 40 * 2 * robots + robots * 360  # scans were taken


def test_reset_replays_the_same_run() -> None:
    sim = fleet(seed=11)
    p1, s1 = rollout(sim, 60)
    sim.reset()
    assert sim.tick == 0
    assert [s.x for s in sim.states()] == [x for x, _ in MULTI]
    p2, s2 = rollout(sim, 60)
    assert all(np.array_equal(a, b) for a, b in zip(p1, p2, strict=True))
    assert all(np.array_equal(a, b) for a, b in zip(s1, s2, strict=True))


def test_robot_never_passes_through_a_wall() -> None:
    world = world_from_dict(
        {
            "name": "wall",
            "bounds": {"x_min": -5, "x_max": 5, "y_min": -5, "y_max": 5},
            "obstacles": [{"type": "box", "x_min": 1.0, "x_max": 1.02, "y_min": -2, "y_max": 2}],
        }
    )
    sim = Simulation(world, SimConfig(noise=False, cmd_timeout=0))
    r = sim.spawn(SpawnRequest(name="r", model="waffle"))
    sim.command(r, 10.0, 0.0)
    for _ in range(30 * 30):  # 30 s pushing into a 2 cm wall
        sim.step()
    s = sim.state(r)
    front = s.x + r.model.chassis[1]
    assert front <= 1.0 + 0.003  # contact depth stays within a few millimetres
    assert s.linear_velocity == pytest.approx(0.0, abs=0.02)


def test_robots_collide_instead_of_overlapping() -> None:
    sim = Simulation(load_world("empty"), SimConfig(noise=False, cmd_timeout=0))
    a = sim.spawn(SpawnRequest(name="a", x=0.0, y=0.0))
    b = sim.spawn(SpawnRequest(name="b", x=1.0, y=0.0, yaw=math.pi))
    sim.command(a, 0.22, 0.0)
    sim.command(b, 0.22, 0.0)
    for _ in range(30 * 8):
        sim.step()

    def poly(st: object) -> Polygon:
        x, y, yaw = st.x, st.y, st.yaw  # type: ignore[attr-defined]
        c, s = math.cos(yaw), math.sin(yaw)
        return Polygon([(x + px * c - py * s, y + px * s + py * c) for px, py in BURGER.outline])

    pa, pb = poly(sim.state(a)), poly(sim.state(b))
    # touching: each robot pushing at full speed sinks ~2 mm at most (as into a wall), so the
    # combined depth across the 0.14 m chassis faces stays within 4 mm
    assert pa.intersection(pb).area / 0.14 < 0.004


def test_scans_see_other_robots_not_themselves() -> None:
    sim = Simulation(load_world("empty"), SimConfig(noise=False))
    sim.spawn(SpawnRequest(name="a", x=0.0, y=0.0))
    sim.spawn(SpawnRequest(name="b", x=1.0, y=0.0))
    scans: dict[str, np.ndarray] = {}
    for _ in range(6):
        out = sim.step()
        scans.update(zip(out.scan_namespaces, out.scans, strict=True))
    a, b = scans["a"], scans["b"]
    # a's lidar is at x=-0.032; b's rear (chassis x_min -0.102) is at 0.898 -> 0.930 ahead
    assert a[0] == pytest.approx(1.0 - 0.102 + 0.032, abs=1e-6)
    assert np.isinf(a[180])  # nothing behind: its own body is invisible
    # b looks at a from behind its own back: beam 180 (pi) hits a's front at x=0.038
    assert b[180] == pytest.approx((1.0 - 0.032) - 0.038, abs=2e-3)
    assert np.isinf(b[0])


def test_sensor_model_noise_and_range_semantics() -> None:
    sim = Simulation(load_world("turtlebot3_world"), SimConfig(seed=1, noise=True))
    sim.spawn(SpawnRequest(name="a", x=-2.0, y=-0.5))
    clean = Simulation(load_world("turtlebot3_world"), SimConfig(seed=1, noise=False))
    clean.spawn(SpawnRequest(name="a", x=-2.0, y=-0.5))
    noisy = quiet = None
    for _ in range(6):
        o1, o2 = sim.step(), clean.step()
        if o1.scan_namespaces:
            noisy, quiet = o1.scans[0], o2.scans[0]
    assert noisy is not None and quiet is not None
    finite = np.isfinite(quiet)
    assert finite.sum() > 100
    assert np.array_equal(np.isinf(noisy), np.isinf(quiet))  # +inf only where nothing is in range
    err = noisy[finite] - quiet[finite]
    assert 0.006 < float(np.std(err)) < 0.014
    assert noisy[finite].min() >= 0.12 and noisy[finite].max() <= 3.5


def test_spawn_rules_leave_the_world_untouched() -> None:
    sim = fleet()
    before = [(s.name, s.x, s.y) for s in sim.states()]
    bad = [
        (SpawnRequest(name="burger_1", x=0.5, y=0.5), ErrorCode.ALREADY_EXISTS),
        (SpawnRequest(name="new", namespace="TB3_2", x=0.5, y=0.5), ErrorCode.ALREADY_EXISTS),
        (SpawnRequest(name="new", x=0.0, y=0.0), ErrorCode.COLLISION),  # the centre pillar
        (SpawnRequest(name="new", x=-2.05, y=-0.45), ErrorCode.COLLISION),  # on burger_1
        (SpawnRequest(name="new", x=2.9, y=0.0), ErrorCode.COLLISION),  # in the outer wall
        (SpawnRequest(name="new", x=50.0, y=0.0), ErrorCode.OUT_OF_BOUNDS),
        (SpawnRequest(name="new", x=1e300, y=0.0), ErrorCode.OUT_OF_BOUNDS),
        (SpawnRequest(name="new", yaw=math.inf), ErrorCode.NON_FINITE),
        (SpawnRequest(name="new", model="tank"), ErrorCode.UNKNOWN_MODEL),
        (SpawnRequest(name="world"), ErrorCode.RESERVED_NAME),
        (SpawnRequest(name="a/b"), ErrorCode.INVALID_NAME),
    ]
    for req, code in bad:
        with pytest.raises(FleetError) as e:
            sim.spawn(req)
        assert e.value.code is code, (req, e.value)
    assert [(s.name, s.x, s.y) for s in sim.states()] == before
    assert len(sim.physics.space.bodies) == 4


def test_robot_limit_and_delete() -> None:
    sim = Simulation(load_world("empty"), SimConfig(max_robots=2))
    sim.spawn(SpawnRequest(name="a", x=0.0))
    sim.spawn(SpawnRequest(name="b", x=1.0))
    with pytest.raises(FleetError) as e:
        sim.spawn(SpawnRequest(name="c", x=2.0))
    assert e.value.code is ErrorCode.ROBOT_LIMIT
    assert sim.delete("a").name == "a"
    with pytest.raises(FleetError) as e:
        sim.delete("a")
    assert e.value.code is ErrorCode.NOT_FOUND
    sim.spawn(SpawnRequest(name="c", x=0.0))
    assert sorted(s.name for s in sim.states()) == ["b", "c"]
    for _ in range(10):
        out = sim.step()
    assert out.namespaces == ["b", "c"]


def test_spawned_pose_is_free_of_obstacles_per_shapely() -> None:
    world = load_world("turtlebot3_world")
    obstacles = [Polygon(p) for p in world.polygons] + [SPoint(c[0], c[1]).buffer(c[2]) for c in world.circles]
    sim = fleet()
    for st in sim.states():
        c, s = math.cos(st.yaw), math.sin(st.yaw)
        fp = Polygon([(st.x + px * c - py * s, st.y + px * s + py * c) for px, py in BURGER.outline])
        assert not any(fp.intersects(o) for o in obstacles)


def _rss_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


@pytest.mark.skipif(not Path("/proc/self/statm").exists(), reason="needs Linux /proc")
def test_physics_does_not_leak_memory_per_tick() -> None:
    """pymunk.batch.Buffer() is never freed, nor the arrays pymunk fills in it: a daemon must
    not make one per tick (at 1 000 robots in real time that was ~4 GB an hour)."""
    sim = Simulation(load_world("empty"), SimConfig(noise=False))
    sim.spawn(SpawnRequest(name="r", x=0.0, y=0.0))
    physics = sim.physics
    rids = sim.robots.rid
    zero = np.zeros(1)
    for _ in range(2000):  # warm up allocator pools
        physics.step(rids, zero, zero, zero, 1 / 30)
        physics.poses(rids)
    before = _rss_bytes()
    ticks = 60_000
    for _ in range(ticks):
        physics.step(rids, zero, zero, zero, 1 / 30)
        physics.poses(rids)
    grown = _rss_bytes() - before
    # one Buffer per call would leak ~21 MB here (one robot; ~39 kB a call at 1 000)
    assert grown < 3_000_000, f"RSS grew by {grown / 1e6:.1f} MB over {ticks} ticks"


def test_poses_and_commands_follow_the_right_robots_after_a_delete() -> None:
    """pymunk reorders its bodies when one is removed; rows must still match robots."""
    sim = Simulation(load_world("empty"), SimConfig(noise=False, cmd_timeout=0))
    spots = [(-1.5, -1.5), (-1.5, 1.5), (1.5, -1.5), (1.5, 1.5), (0.0, 0.0)]
    robots = [sim.spawn(SpawnRequest(name=f"r{i}", x=x, y=y)) for i, (x, y) in enumerate(spots)]
    sim.step()
    assert sim.physics._in_order  # the fast path while nothing was deleted
    sim.delete("r1")
    sim.command(robots[3], 0.2, 0.0)
    for _ in range(30):
        sim.step()
    assert not sim.physics._in_order  # ... and the general one after the delete
    for i in (0, 2, 4):
        s = sim.state(robots[i])
        assert (s.x, s.y) == pytest.approx(spots[i], abs=1e-9)
    moved = sim.state(robots[3])
    assert moved.x > spots[3][0] + 0.1 and moved.y == pytest.approx(spots[3][1], abs=1e-6)


@pytest.mark.parametrize("model", ["burger", "waffle", "waffle_pi"])
def test_collision_boxes_cover_exactly_the_footprint(model: str) -> None:
    """Physics collides with two boxes; together they must be the outline the lidar sees."""
    from shapely.ops import unary_union

    from simd.core.models import MODELS

    m = MODELS[model]
    boxes = [Polygon([(x0, y0), (x1, y0), (x1, y1), (x0, y1)]) for x0, x1, y0, y1 in m.collision_boxes()]
    union = unary_union(boxes)
    outline = Polygon(m.outline)
    assert union.symmetric_difference(outline).area < 1e-12
    assert outline.area > 0.01


def test_deleting_many_robots_at_once_and_its_bad_requests() -> None:
    sim = Simulation(load_world("empty"))
    for k in range(5):
        sim.spawn(SpawnRequest(name=f"r{k}", x=float(k) - 2.0))
    for keys, code in ((["r1", "nobody"], ErrorCode.NOT_FOUND), (["r1", "r1"], ErrorCode.INVALID_VALUE)):
        with pytest.raises(FleetError) as e:
            sim.delete_many(keys)
        assert e.value.code is code
        assert len(sim.states()) == 5  # nothing removed
    last = sim.delete_many(["r3", "r0"])
    assert [s.name for s in last] == ["r3", "r0"] and last[0].x == pytest.approx(1.0)
    assert [s.name for s in sim.states()] == ["r1", "r2", "r4"]
    sim.spawn(SpawnRequest(name="r0", x=-2.0))  # its place is free again, in the physics too
    for _ in range(7):
        out = sim.step()
    assert out.namespaces == ["r1", "r2", "r4", "r0"] and len(out.scan_index) <= 4
