"""Map worlds: a map_server map's walls as boxes, and the round trip world -> map -> world."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from clients.mapping.grid import Beams, LogOddsGrid
from fleetcommon.mapfile import OccupancyMap, write_map
from protocol.control import SpawnRequest
from simd.core.mapworld import load_world_or_map, occupied_boxes, world_from_map
from simd.core.sim import SimConfig, Simulation
from simd.core.worldfile import WorldFileError, load_world


@settings(max_examples=60, deadline=None)
@given(arrays(np.bool_, st.tuples(st.integers(1, 12), st.integers(1, 12))))
def test_boxes_cover_the_occupied_cells_exactly_once(solid: np.ndarray) -> None:
    cover = np.zeros(solid.shape, dtype=np.int32)
    for r0, r1, c0, c1 in occupied_boxes(solid):
        assert r0 < r1 and c0 < c1
        cover[r0:r1, c0:c1] += 1
    assert np.array_equal(cover, solid.astype(np.int32))


def test_runs_of_equal_rows_merge() -> None:
    solid = np.zeros((5, 6), dtype=bool)
    solid[1:4, 2:5] = True  # one block
    solid[0, :] = True  # a wall along the bottom
    assert sorted(occupied_boxes(solid)) == [(0, 1, 0, 6), (1, 4, 2, 5)]


# poses that between them see every wall of turtlebot3_world
POSES = [(-2.0, -0.5), (0.5, -2.0), (2.0, 0.5), (-0.5, 2.0), (-0.55, 0.55), (0.55, -0.55), (0.55, 0.55), (-0.55, -0.55)]


def _scans(world: object) -> list[np.ndarray]:
    """A burger's scan at each pose, alone in the world (robots seen in a map would become walls)."""
    out = []
    for x, y in POSES:
        sim = Simulation(world, SimConfig(noise=False, lidar_thread=False))  # type: ignore[arg-type]
        sim.spawn(SpawnRequest(name="r", x=x, y=y))
        while not (snap := sim.step()).scan_namespaces:
            pass
        out.append(np.array(snap.scans[0]))
        sim.close()
    return out


def test_a_mapped_world_gives_the_same_ranges(tmp_path: Path) -> None:
    """Map turtlebot3_world from its own scans, load the map as a world: at the same poses the
    lidar sees the same walls, to within a cell."""
    world = load_world("turtlebot3_world")
    spec = SimConfig().lidar
    beams = Beams(spec.angle_min, spec.angle_increment, spec.samples, spec.range_min, spec.range_max)
    grid = LogOddsGrid(world.bounds, 0.05)
    first = _scans(world)
    for _ in range(3):  # three looks: free space is sure
        for (x, y), ranges in zip(POSES, first, strict=True):
            grid.integrate(x - 0.032, y, 0.0, ranges, beams)  # the burger's lidar sits 3.2 cm back
    write_map(tmp_path / "tb3", grid.occupancy())
    again = _scans(load_world_or_map(str(tmp_path / "tb3.yaml")))
    diffs = []
    for ranges, mapped in zip(first, again, strict=True):
        both = np.isfinite(ranges) & np.isfinite(mapped)
        assert both.sum() > 0.9 * np.isfinite(ranges).sum()  # the same beams hit something
        diffs.append(np.abs(ranges[both] - mapped[both]))
    d = np.concatenate(diffs)
    # within a cell (0.05 m): the boxes' faces are the edges of the cells the walls pass through
    assert np.median(d) < 0.04 and np.percentile(d, 90) < 0.075, (np.median(d), np.percentile(d, 90))


def test_maps_that_cannot_be_worlds(tmp_path: Path) -> None:
    cells = np.zeros((40, 40), dtype=np.int8)
    with pytest.raises(WorldFileError, match="rotated map"):
        world_from_map(OccupancyMap(cells, 0.05, (0.0, 0.0, 0.5)), "m.yaml")
    with pytest.raises(WorldFileError, match="no free spot"):
        world_from_map(OccupancyMap(np.full((40, 40), 100, dtype=np.int8), 0.05), "m.yaml")
    world = world_from_map(OccupancyMap(cells, 0.05, (-1.0, -1.0, 0.0)), "m.yaml")
    assert world.bounds == (-1.0, 1.0, -1.0, 1.0) and world.polygons == ()
    x, y, _ = world.default_spawn
    assert math.hypot(x, y) < 0.05  # the middle of an empty map
    (tmp_path / "bad.yaml").write_text("image: nowhere.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n")
    with pytest.raises(WorldFileError, match="cannot read the map image"):
        load_world_or_map(str(tmp_path / "bad.yaml"))


def _nested(depth: int) -> str:
    return "[" * depth + "]" * depth


def test_yaml_nested_past_what_python_parses_is_a_file_error(tmp_path: Path) -> None:
    """PyYAML's pure-Python loader recurses once a level: a file nested some hundreds deep
    raised RecursionError, a traceback out of simd (libyaml, which msgspec uses, stops at
    1 000 levels with a syntax error of its own)."""
    depth = 500  # (CPython's default recursion limit: enough; deeper only takes longer)
    from clients.fleetfile import FleetFileError, load_fleet
    from fleetcommon.mapfile import MapFileError, read_map

    world = tmp_path / "world.yaml"
    world.write_text(f"name: deep\nbounds: {_nested(depth)}\n")
    with pytest.raises(WorldFileError):
        load_world_or_map(str(world))
    a_map = tmp_path / "map.yaml"
    a_map.write_text(f"image: map.pgm\nresolution: 0.05\norigin: {_nested(depth)}\n")
    with pytest.raises((MapFileError, WorldFileError)):
        load_world_or_map(str(a_map))
    with pytest.raises(MapFileError, match="nested too deep"):
        read_map(a_map)
    fleet = tmp_path / "fleet.yaml"
    fleet.write_text(f"- {{name: a, x: {_nested(depth)}}}\n")
    with pytest.raises(FleetFileError):
        load_fleet(str(fleet))
