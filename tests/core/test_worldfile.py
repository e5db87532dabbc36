"""World files: the shipped geometry matches the reference, and every bad input is located.

Geometry checks use shapely as an independent oracle, so they do not share code (or bugs)
with the loader's own polygon handling.
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path

import numpy as np
import pytest
from shapely.geometry import Point, Polygon
from shapely.ops import unary_union

import worlds
from simd.core.worldfile import WorldFileError, WorldGeometry, load_world, world_from_dict

FOOTPRINT_RADIUS_M = 0.16  # a little more than the burger's circumscribed radius
MULTI_ROBOT_POSES = [(-2.0, -0.5), (0.5, -2.0), (2.0, 0.5), (-0.5, 2.0)]


def shoelace(points: np.ndarray) -> float:
    x, y = points[:, 0], points[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def clearance(world: WorldGeometry, x: float, y: float) -> float:
    """Distance from (x, y) to the nearest obstacle; 0 inside one."""
    here = Point(x, y)
    distances = [float(Polygon(p).distance(here)) for p in world.polygons]
    distances += [max(0.0, math.hypot(cx - x, cy - y) - r) for cx, cy, r in world.circles]
    return min(distances, default=math.inf)


# --- shipped worlds -------------------------------------------------------------------------


def test_list_worlds() -> None:
    assert worlds.list_worlds() == ["empty", "turtlebot3_house", "turtlebot3_world"]
    assert worlds.world_path("empty") == worlds.WORLDS_DIR / "empty.yaml"


@pytest.mark.parametrize("name", ["empty", "turtlebot3_house", "turtlebot3_world"])
def test_shipped_world_loads_as_ccw_readonly_geometry(name: str) -> None:
    world = load_world(name)
    assert world.name == name
    assert world.source.endswith(f"{name}.yaml")
    for polygon in world.polygons:
        assert polygon.dtype == np.float64
        assert polygon.ndim == 2 and polygon.shape[1] == 2 and polygon.shape[0] >= 3
        assert shoelace(polygon) > 0
        assert Polygon(polygon).is_valid
        assert not polygon.flags.writeable
    assert world.circles.dtype == np.float64 and world.circles.shape[1] == 3
    assert not world.circles.flags.writeable


def test_load_by_path_matches_load_by_name() -> None:
    by_name = load_world("turtlebot3_world")
    by_path = load_world(worlds.world_path("turtlebot3_world"))
    assert by_path.source == by_name.source
    assert len(by_path.polygons) == len(by_name.polygons)
    np.testing.assert_array_equal(by_path.segments(), by_name.segments())


def test_turtlebot3_world_counts_and_pillars() -> None:
    world = load_world("turtlebot3_world")
    assert world.default_spawn == (-2.0, -0.5, 0.0)
    assert [len(p) for p in world.polygons] == [4] * 6 + [6] * 5
    grid = sorted((x, y) for x in (-1.1, 0.0, 1.1) for y in (-1.1, 0.0, 1.1))
    assert sorted((float(x), float(y)) for x, y, _ in world.circles) == grid
    np.testing.assert_array_equal(world.circles[:, 2], 0.15)


def test_turtlebot3_world_outer_wall_is_a_hexagonal_ring() -> None:
    world = load_world("turtlebot3_world")
    ring = unary_union([Polygon(p) for p in world.polygons[:6]])
    assert ring.geom_type == "Polygon" and len(ring.interiors) == 1
    inner_r, outer_r = 2.9329, 3.2996
    hexagon_area = 1.5 * math.sqrt(3.0)  # times circumradius squared
    assert ring.area == pytest.approx(hexagon_area * (outer_r**2 - inner_r**2), rel=1e-3)
    assert Polygon(ring.interiors[0]).area == pytest.approx(hexagon_area * inner_r**2, rel=1e-3)
    # Flat sides face +-y and +-30 deg (apothem 2.54 inside, 2.8575 outside); corners on +-x.
    for angle_deg in (90.0, -90.0, 30.0, 150.0, -150.0):
        ux, uy = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
        for distance, inside_wall in ((2.5, False), (2.6, True), (2.8, True), (2.9, False)):
            assert ring.contains(Point(distance * ux, distance * uy)) is inside_wall
    for x, inside_wall in ((2.9, False), (3.0, True), (3.25, True), (3.35, False)):
        assert ring.contains(Point(x, 0.0)) is inside_wall
        assert ring.contains(Point(-x, 0.0)) is inside_wall


def test_turtlebot3_world_blocks() -> None:
    world = load_world("turtlebot3_world")
    head, *limbs = (Polygon(p) for p in world.polygons[6:])
    assert head.bounds == pytest.approx((2.3268, -1.016, 4.6732, 1.016))
    for limb, (cx, cy) in zip(
        limbs, [(1.8, 2.7), (1.8, -2.7), (-1.8, 2.7), (-1.8, -2.7)], strict=True
    ):
        assert limb.centroid.x == pytest.approx(cx) and limb.centroid.y == pytest.approx(cy)
        assert limb.bounds == pytest.approx((cx - 0.8066, cy - 0.6985, cx + 0.8066, cy + 0.6985))
    # Everything fits in the declared bounds.
    x_min, x_max, y_min, y_max = world.bounds
    every = unary_union([Polygon(p) for p in world.polygons])
    bx0, by0, bx1, by1 = every.bounds
    assert x_min < bx0 and bx1 < x_max and y_min < by0 and by1 < y_max


def test_turtlebot3_house_counts_and_extent() -> None:
    world = load_world("turtlebot3_house")
    assert world.default_spawn == (-2.0, -0.5, 0.0)
    walls, furniture = world.polygons[:32], world.polygons[32:]
    assert len(walls) == 32
    assert len(furniture) == 3 * 3 + 3 * 3 + 2  # bookshelf panels, cabinet plates, cafe columns
    assert len(world.circles) == 4  # table legs
    np.testing.assert_array_equal(world.circles[:, 2], 0.02)
    house = unary_union([Polygon(p) for p in walls]).bounds
    assert house == pytest.approx((-7.575, -5.35, 7.578, 5.35))
    x_min, x_max, y_min, y_max = world.bounds
    everything = unary_union([Polygon(p) for p in world.polygons]).bounds
    assert x_min < everything[0] and everything[2] < x_max
    assert y_min < everything[1] and everything[3] < y_max


def test_turtlebot3_house_bookshelves_stand_against_the_north_wall() -> None:
    world = load_world("turtlebot3_house")
    walls = unary_union([Polygon(p) for p in world.polygons[:32]])
    shelves = [Polygon(p) for p in world.polygons[32:41]]
    for back, left, right in zip(shelves[0::3], shelves[1::3], shelves[2::3], strict=True):
        assert back.distance(walls) < 0.02
        for side in (left, right):
            assert side.bounds[3] <= back.bounds[3] + 1e-9  # sides reach into the room (south)
            assert side.bounds[1] == pytest.approx(back.bounds[1] - 0.395, abs=1e-3)


def test_empty_world() -> None:
    world = load_world("empty")
    assert world.bounds == (-50.0, 50.0, -50.0, 50.0)
    assert world.default_spawn == (0.0, 0.0, 0.0)
    assert world.polygons == ()
    assert world.circles.shape == (0, 3)
    assert world.segments().shape == (0, 4)


@pytest.mark.parametrize(
    ("name", "x", "y"),
    [("turtlebot3_world", x, y) for x, y in MULTI_ROBOT_POSES]
    + [("turtlebot3_house", -2.0, -0.5), ("empty", 0.0, 0.0)],
)
def test_spawn_poses_are_clear(name: str, x: float, y: float) -> None:
    world = load_world(name)
    assert clearance(world, x, y) >= FOOTPRINT_RADIUS_M


def test_default_spawn_is_clear_in_every_shipped_world() -> None:
    for name in worlds.list_worlds():
        world = load_world(name)
        x, y, _ = world.default_spawn
        assert clearance(world, x, y) >= FOOTPRINT_RADIUS_M, name


def test_segments_are_polygon_edges() -> None:
    world = load_world("turtlebot3_world")
    segments = world.segments()
    assert segments.shape == (sum(len(p) for p in world.polygons), 4)
    assert segments.dtype == np.float64
    first = world.polygons[0]
    np.testing.assert_array_equal(segments[: len(first), :2], first)
    np.testing.assert_array_equal(segments[: len(first), 2:], np.roll(first, -1, axis=0))


# --- world_from_dict ------------------------------------------------------------------------


def base_world(**extra: object) -> dict[str, object]:
    return {"name": "t", "bounds": {"x_min": -5, "x_max": 5, "y_min": -5, "y_max": 5}, **extra}


def test_world_from_dict_converts_every_obstacle_kind() -> None:
    world = world_from_dict(
        base_world(
            default_spawn={"x": -4, "y": -4, "yaw": 1.0},
            obstacles=[
                {"type": "box", "x_min": 0, "x_max": 2, "y_min": 0, "y_max": 1, "name": "b"},
                {"type": "rect", "x": 1, "y": 1, "size_x": 2, "size_y": 1, "yaw": math.pi / 2},
                {"type": "polygon", "points": [[0, 0], [0, 1], [1, 0]]},  # clockwise
                {"type": "circle", "x": 3, "y": 3, "radius": 0.5},
            ],
        ),
        source="generated",
    )
    assert world.source == "generated"
    assert world.default_spawn == (-4.0, -4.0, 1.0)
    box, rect, triangle = world.polygons
    np.testing.assert_array_equal(box, [[0, 0], [2, 0], [2, 1], [0, 1]])
    assert Polygon(rect).bounds == pytest.approx((0.5, 0.0, 1.5, 2.0))
    assert shoelace(rect) == pytest.approx(2.0)
    assert shoelace(triangle) == pytest.approx(0.5)  # normalised to counter-clockwise
    np.testing.assert_array_equal(world.circles, [[3.0, 3.0, 0.5]])


def test_world_from_dict_reports_the_given_source() -> None:
    bad = base_world(obstacles=[{"type": "circle", "x": 0, "y": 0, "radius": -1}])
    with pytest.raises(WorldFileError) as info:
        world_from_dict(bad, source="bench:seed=3")
    assert str(info.value).startswith("bench:seed=3: $.obstacles[0].radius: Expected `float` > 0")
    assert info.value.source == "bench:seed=3"
    assert info.value.location == "$.obstacles[0].radius"


def test_nav_cell_is_the_world_files_or_none() -> None:
    """A world may name the size of navigation's cells (turtlebot3_world: three between two
    pillars); without it, none (navigation sizes them for the robots)."""
    assert load_world("turtlebot3_world").nav_cell == pytest.approx(1.1 / 3, abs=1e-4)
    assert load_world("empty").nav_cell is None
    bounds = {"x_min": -1, "x_max": 1, "y_min": -1, "y_max": 1}
    assert world_from_dict({"name": "w", "bounds": bounds, "nav_cell": 0.4}).nav_cell == 0.4


def test_geometry_is_read_only() -> None:
    world = load_world("turtlebot3_world")
    with pytest.raises(ValueError):
        world.polygons[0][0, 0] = 0.0


# --- bad world files ------------------------------------------------------------------------

HEADER = "name: bad\nbounds: {x_min: -5, x_max: 5, y_min: -5, y_max: 5}\n"
CIRCLE = "  - {type: circle, x: 1, y: 1, radius: 0.5}\n"


def with_obstacle(line: str) -> str:
    return HEADER + "obstacles:\n" + CIRCLE + f"  - {line}\n"


BAD_FILES = [
    ("unknown top-level field", HEADER + "gravity: 9.81\n", "$", "unknown field `gravity`"),
    (
        "unknown obstacle field",
        with_obstacle("{type: circle, x: 0, y: 0, radius: 1, colour: red}"),
        "$.obstacles[1]",
        "unknown field `colour`",
    ),
    ("unknown obstacle type", with_obstacle("{type: blob, x: 0}"), "$.obstacles[1].type", "'blob'"),
    (
        "missing obstacle type",
        with_obstacle("{x: 0, y: 0, radius: 1}"),
        "$.obstacles[1]",
        "missing required field `type`",
    ),
    (
        "negative radius",
        with_obstacle("{type: circle, x: 0, y: 0, radius: -0.5}"),
        "$.obstacles[1].radius",
        "Expected `float` > 0.0",
    ),
    (
        "zero rect size",
        with_obstacle("{type: rect, x: 0, y: 0, size_x: 0, size_y: 1}"),
        "$.obstacles[1].size_x",
        "Expected `float` > 0.0",
    ),
    (
        "string for a number",
        with_obstacle("{type: circle, x: zero, y: 0, radius: 1}"),
        "$.obstacles[1].x",
        "Expected `float`, got `str`",
    ),
    (
        "nan coordinate",
        with_obstacle("{type: box, x_min: .nan, x_max: 1, y_min: 0, y_max: 1}"),
        "$.obstacles[1].x_min",
        "must be a finite number, got nan",
    ),
    (
        "nan polygon point",
        with_obstacle("{type: polygon, points: [[0, 0], [1, .nan], [0, 1]]}"),
        "$.obstacles[1].points[1][1]",
        "must be a finite number, got nan",
    ),
    (
        "infinite bound",
        "name: bad\nbounds: {x_min: -5, x_max: 5, y_min: -5, y_max: .inf}\n",
        "$.bounds.y_max",
        "must be a finite number, got inf",
    ),
    (
        "non-convex polygon",
        with_obstacle("{type: polygon, points: [[0, 0], [2, 0], [2, 2], [1, 0.5], [0, 2]]}"),
        "$.obstacles[1].points",
        "not convex",
    ),
    (
        "self-crossing polygon",
        with_obstacle("{type: polygon, points: [[0, 0], [1, 1], [1, 0], [0, 1]]}"),
        "$.obstacles[1].points",
        "not convex",
    ),
    (
        "pentagram",
        with_obstacle(
            "{type: polygon, points: "
            + str(
                [
                    [round(math.cos(a), 4), round(math.sin(a), 4)]
                    for a in (4 * math.pi * k / 5 for k in range(5))
                ]
            )
            + "}"
        ),
        "$.obstacles[1].points",
        "crosses itself",
    ),
    (
        "two-point polygon",
        with_obstacle("{type: polygon, points: [[0, 0], [1, 1]]}"),
        "$.obstacles[1].points",
        "Expected `array` of length >= 3",
    ),
    (
        "collinear polygon",
        with_obstacle("{type: polygon, points: [[0, 0], [1, 1], [2, 2]]}"),
        "$.obstacles[1].points",
        "collinear",
    ),
    (
        "repeated polygon point",
        with_obstacle("{type: polygon, points: [[0, 0], [1, 0], [1, 1], [0, 0]]}"),
        "$.obstacles[1].points",
        "coincide",
    ),
    (
        "three-number point",
        with_obstacle("{type: polygon, points: [[0, 0, 0], [1, 0, 0], [1, 1, 0]]}"),
        "$.obstacles[1].points[0]",
        "length 2",
    ),
    (
        "empty box",
        with_obstacle("{type: box, x_min: 1, x_max: 1, y_min: 0, y_max: 1}"),
        "$.obstacles[1]",
        "x_min (1.0) must be less than x_max (1.0)",
    ),
    (
        "x_min >= x_max",
        "name: bad\nbounds: {x_min: 5, x_max: 1, y_min: -5, y_max: 5}\n",
        "$.bounds",
        "x_min (5.0) must be less than x_max (1.0)",
    ),
    (
        "spawn outside bounds",
        HEADER + "default_spawn: {x: 6, y: 0}\n",
        "$.default_spawn",
        "spawn point (6.0, 0.0) is outside the bounds",
    ),
    ("nav_cell too small", HEADER + "nav_cell: 0.1\n", "$.nav_cell", ">= 0.2"),
    ("nav_cell too large", HEADER + "nav_cell: 6\n", "$.nav_cell", "<= 5.0"),
    ("nav_cell not a number", HEADER + "nav_cell: wide\n", "$.nav_cell", "Expected `float | null`"),
    ("missing name", "bounds: {x_min: 0, x_max: 1, y_min: 0, y_max: 1}\n", "$", "`name`"),
    ("empty name", HEADER.replace("name: bad", "name: ''"), "$.name", "length >= 1"),
    ("empty file", "", "$", "Expected `object`, got `null`"),
    ("top level is a list", "- 1\n- 2\n", "$", "Expected `object`, got `array`"),
    (
        "yaml syntax error",
        HEADER + "obstacles:\n  - {type: circle, x: 0\n",
        "line 5, column 1",
        "YAML syntax error",
    ),
]


@pytest.mark.parametrize(
    ("text", "location", "reason"),
    [pytest.param(text, loc, reason, id=case) for case, text, loc, reason in BAD_FILES],
)
def test_bad_world_file_is_located(tmp_path: Path, text: str, location: str, reason: str) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(WorldFileError) as info:
        load_world(str(path))
    message = str(info.value)
    assert message.startswith(f"{path}: {location}: "), message
    assert reason in message, message
    assert info.value.source == str(path)
    assert info.value.location == location


def test_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "nowhere.yaml"
    with pytest.raises(WorldFileError, match=re.escape(f"{path}: file not found")):
        load_world(str(path))


def test_missing_file_named_like_a_shipped_world_hints_at_the_bare_name(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    with pytest.raises(WorldFileError, match="pass the bare name 'turtlebot3_world'"):
        load_world("turtlebot3_world.yaml")


def test_directory_is_not_a_world_file(tmp_path: Path) -> None:
    with pytest.raises(WorldFileError, match=re.escape(f"{tmp_path}/: is a directory")):
        load_world(f"{tmp_path}/")


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0, reason="root reads any file")
def test_unreadable_file(tmp_path: Path) -> None:
    path = tmp_path / "secret.yaml"
    path.write_text(HEADER)
    path.chmod(0)
    try:
        with pytest.raises(WorldFileError, match=re.escape(f"{path}: cannot read file")):
            load_world(str(path))
    finally:
        path.chmod(0o600)


def test_unknown_world_name_suggests_the_closest() -> None:
    with pytest.raises(WorldFileError) as info:
        load_world("turtlebot3_wrld")
    message = str(info.value)
    assert message.startswith("turtlebot3_wrld: unknown world; did you mean 'turtlebot3_world'?")
    assert "Available worlds: empty, turtlebot3_house, turtlebot3_world" in message


def test_unknown_world_name_without_a_close_match_lists_the_worlds() -> None:
    with pytest.raises(WorldFileError) as info:
        load_world("warehouse")
    assert "did you mean" not in str(info.value)
    assert "Available worlds: empty, turtlebot3_house, turtlebot3_world" in str(info.value)
