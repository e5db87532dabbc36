"""MovingAI grid maps: the strict reader, the map as a world, and how simd finds and sizes one.

Geometry is checked with shapely as an independent oracle: the boxes' union against the
union of the blocked cells' squares, drawn here from the text by the documented formula.
"""

from __future__ import annotations

import math
import subprocess
from pathlib import Path

import numpy as np
import pytest
from shapely.geometry import Point, Polygon, box
from shapely.ops import unary_union

from simd import container_entry
from simd.cli import build_parser
from simd.core import mapworld
from simd.core.mapworld import CLOSING_WALL_M, load_world_or_map, world_from_movingai
from simd.core.movingai import (
    DEFAULT_CELL_SIZE_M,
    MAX_SIDE,
    MovingAIMap,
    is_movingai,
    load_movingai,
    parse_movingai,
    read_movingai,
)
from simd.core.worldfile import WorldFileError
from tests.conftest import ROOT, free_port, simd_command

TINY = """type octile
height 4
width 6
map
@.....
.@@@@.
..T.W.
G.S..O
"""
TINY_PASSABLE = [
    [0, 1, 1, 1, 1, 1],
    [1, 0, 0, 0, 0, 1],
    [1, 1, 0, 1, 0, 1],
    [1, 1, 1, 1, 1, 0],
]


def header(height: int = 2, width: int = 3) -> str:
    return f"type octile\nheight {height}\nwidth {width}\nmap\n"


def cell_square(grid: MovingAIMap, row: int, col: int, c: float) -> Polygon:
    """Cell (row, col) as the format's documentation places it: row 0 on top."""
    return box(col * c, (grid.height - 1 - row) * c, (col + 1) * c, (grid.height - row) * c)


# --- reading --------------------------------------------------------------------------------


def test_a_tiny_map_reads_row_by_row_top_first() -> None:
    grid = parse_movingai(TINY, "tiny.map")
    assert (grid.width, grid.height) == (6, 4)
    assert grid.passable.dtype == np.bool_ and not grid.passable.flags.writeable
    assert grid.passable.astype(int).tolist() == TINY_PASSABLE  # . G S open; @ O T W blocked


def test_crlf_trailing_space_blank_tail_and_byte_order_mark_read_the_same() -> None:
    messy = "\ufeff" + "".join(line + " \t\r\n" for line in TINY.splitlines()) + "\r\n\r\n"
    grid = read_movingai(messy.encode("utf-8"), "messy.map")
    assert np.array_equal(grid.passable, parse_movingai(TINY, "tiny.map").passable)


def test_the_header_lines_come_in_any_order() -> None:
    text = "width 3\ntype octile\nheight 2\nmap\n...\n.@.\n"
    assert parse_movingai(text, "m.map").passable.astype(int).tolist() == [[1, 1, 1], [1, 0, 1]]


BAD_HEADERS = [
    ("", "line 1", "an empty file, not a MovingAI map (one begins 'type octile')"),
    ("height 2\nwidth 3\nmap\n...\n...\n", "line 3", "the header has no 'type' line before 'map'"),
    ("type octile\nwidth 3\nmap\n...\n...\n", "line 3", "the header has no 'height' line before 'map'"),
    (
        "type octile\nheight 2\nheight 2\nwidth 3\nmap\n...\n...\n",
        "line 3",
        "a second 'height' line (the first is line 2)",
    ),
    (
        "type octile\nheight 2\nwidth 3\n...\n...\n",
        "line 4",
        "expected a header line 'type octile', 'height H', 'width W' or 'map', got '...'",
    ),
    (
        "type octile\n\nheight 2\nwidth 3\nmap\n...\n...\n",
        "line 2",
        "expected a header line 'type octile', 'height H', 'width W' or 'map', got an empty line",
    ),
    ("type octile\nheight 2\nwidth 3\n", "line 4", "the file ends before the header's 'map' line"),
    ("type octile\nheight 2\nwidth 3", "line 4", "the file ends before the header's 'map' line"),
    ("type hex\nheight 2\nwidth 3\nmap\n", "line 1", "unknown map type 'hex' (MovingAI maps are 'type octile')"),
    ("type octile\nheight 2 3\nwidth 3\nmap\n", "line 2", "expected 'height VALUE', got 'height 2 3'"),
    ("type octile\nheight two\nwidth 3\nmap\n", "line 2", "height must be a whole number > 0, got 'two'"),
    ("type octile\nheight 2\nwidth 0\nmap\n", "line 3", "width must be a whole number > 0, got '0'"),
    ("type octile\nheight 2\nwidth -3\nmap\n", "line 3", "width must be a whole number > 0, got '-3'"),
    ("type octile\nheight 2.5\nwidth 3\nmap\n", "line 2", "height must be a whole number > 0, got '2.5'"),
    (f"type octile\nheight {MAX_SIDE + 1}\nwidth 3\nmap\n", "line 2", "height 4001 is more than 4000 cells"),
    ("type octile\nheight 2\nwidth 40000\nmap\n", "line 3", "width 40000 is more than 4000 cells"),
]

BAD_GRIDS = [
    (header() + "...\n..\n", "line 6", "a grid line of 2 characters, the map's width is 3"),
    (header() + "....\n...\n", "line 5", "a grid line of 4 characters, the map's width is 3"),
    (header() + "...\n\n...\n", "line 6", "a grid line of 0 characters, the map's width is 3"),
    (header() + "...\n", "line 6", "the map ends after 1 of its 2 grid lines (height 2)"),
    (header(), "line 5", "the map ends after 0 of its 2 grid lines (height 2)"),
    (header() + "...\n...\n...\n", "line 7", "a grid line beyond the map's height 2"),
    (
        header() + "...\n.x.\n",
        "line 6, column 2",
        "unknown character 'x' (passable: . G S; blocked: @ O T W)",
    ),
    (
        header() + "..é\n...\n",
        "line 5, column 3",
        "unknown character 'é' (passable: . G S; blocked: @ O T W)",
    ),
    (
        header() + "...\n.\t.\n",
        "line 6, column 2",
        "unknown character '\\t' (passable: . G S; blocked: @ O T W)",
    ),
]


@pytest.mark.parametrize(("text", "location", "reason"), BAD_HEADERS + BAD_GRIDS)
def test_a_malformed_map_is_one_located_line(text: str, location: str, reason: str) -> None:
    with pytest.raises(WorldFileError) as info:
        parse_movingai(text, "bad.map")
    assert (info.value.source, info.value.location, info.value.reason) == ("bad.map", location, reason)
    assert str(info.value) == f"bad.map: {location}: {reason}"


def test_bytes_that_are_not_utf8_are_located() -> None:
    with pytest.raises(WorldFileError, match=r"^bad\.map: line 6: not a text file \(byte 0xff is not UTF-8\)$"):
        read_movingai((header() + "...\n.\xff.\n").encode("latin-1"), "bad.map")


def test_is_movingai_by_name_or_first_line() -> None:
    assert is_movingai(b"", "w.map")
    assert is_movingai(b"type octile\n", "w.txt")
    assert is_movingai(b"\xef\xbb\xbftype octile\r\n", "w")
    assert not is_movingai(b"type: box\n", "w.yaml")
    assert not is_movingai(b"name: w\n", "w.yaml")


# --- as a world -----------------------------------------------------------------------------


def test_a_tiny_map_becomes_boxes_that_cover_its_blocked_cells_exactly() -> None:
    grid = parse_movingai(TINY, "tiny.map")
    c = 0.5
    world = world_from_movingai(grid, "some/where/tiny.map", c)
    assert world.name == "tiny" and world.source == "some/where/tiny.map"
    assert world.bounds == (0.0, 6 * c, 0.0, 4 * c)
    assert world.circles.shape == (0, 3)
    inside = box(0.0, 0.0, 6 * c, 4 * c)
    polygons = [Polygon(p) for p in world.polygons]
    cells = [polygon for polygon in polygons if polygon.intersection(inside).area > 0]
    walls = [polygon for polygon in polygons if polygon.intersection(inside).area == 0]
    blocked = [(r, k) for r in range(4) for k in range(6) if not TINY_PASSABLE[r][k]]
    expected = unary_union([cell_square(grid, r, k, c) for r, k in blocked])
    got = unary_union(cells)
    assert got.symmetric_difference(expected).area < 1e-12
    assert sum(p.area for p in cells) == pytest.approx(len(blocked) * c * c)  # no overlaps
    assert len(cells) < len(blocked)  # merged: the row of four is one box
    for r in range(4):
        for k in range(6):
            if TINY_PASSABLE[r][k]:
                centre = Point(*grid.cell_centre(r, k, c))
                assert not any(p.intersects(centre) for p in polygons), (r, k)
    # the four closing walls: just outside the bounds, sealing every side and corner
    assert len(walls) == 4
    t = CLOSING_WALL_M
    outside = [(-t / 2, 1.0), (6 * c + t / 2, 1.0), (1.0, -t / 2), (1.0, 4 * c + t / 2), (-t / 2, -t / 2)]
    outside += [(6 * c + t / 2, 4 * c + t / 2)]
    for x, y in outside:
        assert any(w.contains(Point(x, y)) for w in walls), (x, y)
    assert unary_union(walls).bounds == pytest.approx((-t, -t, 6 * c + t, 4 * c + t))
    for polygon in world.polygons:  # counter-clockwise and read-only, as the simulator wants
        assert Polygon(polygon).exterior.is_ccw and not polygon.flags.writeable


def test_the_top_line_is_the_top_of_the_world() -> None:
    grid = parse_movingai(header(3, 4) + "@...\n....\n....\n", "corner.map")
    world = world_from_movingai(grid, "corner.map", 2.0)
    corner = [p for p in world.polygons if Polygon(p).intersection(box(0, 0, 8, 6)).area > 0]
    assert len(corner) == 1 and Polygon(corner[0]).bounds == (0.0, 4.0, 2.0, 6.0)  # x 0..2, y 4..6


def test_the_default_spawn_is_the_open_cell_nearest_the_middle() -> None:
    grid = parse_movingai(header(3, 3) + "...\n.@.\n...\n", "ring.map")
    world = world_from_movingai(grid, "ring.map", 1.0)
    assert world.default_spawn == (1.5, 2.5, 0.0)  # the middle is blocked: the first of its 4 neighbours
    grid = parse_movingai(header(3, 3) + "...\n...\n...\n", "open.map")
    assert world_from_movingai(grid, "open.map", 0.6).default_spawn == pytest.approx((0.9, 0.9, 0.0))


def test_cells_and_points() -> None:
    grid = parse_movingai(TINY, "tiny.map")
    for r in range(grid.height):
        for k in range(grid.width):
            assert grid.cell_at(*grid.cell_centre(r, k, 0.6), 0.6) == (r, k)
    assert grid.cell_at(0.0, 0.0, 0.5) == (3, 0)
    assert grid.cell_at(2.99, 1.99, 0.5) == (0, 5)
    for x, y in ((-0.01, 1.0), (3.0, 1.0), (1.0, 2.0), (1.0, -1e-9)):
        assert grid.cell_at(x, y, 0.5) is None


def test_maps_that_cannot_be_worlds(monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(WorldFileError, match=r"^solid\.map: no passable cell to spawn a robot in$"):
        world_from_movingai(parse_movingai(header() + "@@@\nTTW\n", "solid.map"), "solid.map", 0.5)
    monkeypatch.setattr(mapworld, "MAX_BOXES", 2)
    grid = parse_movingai(header(3, 3) + "@.@\n...\n@..\n", "many.map")
    with pytest.raises(WorldFileError, match=r"^many\.map: the map's blocked cells make 3 boxes, more than 2$"):
        world_from_movingai(grid, "many.map", 0.5)
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="cell size must be a finite number of metres > 0"):
            world_from_movingai(parse_movingai(TINY, "tiny.map"), "tiny.map", bad)


# --- finding and sizing one -----------------------------------------------------------------


def test_load_world_or_map_knows_a_map_by_its_name_or_its_first_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "tiny.map").write_text(TINY)
    (tmp_path / "tiny.txt").write_text(TINY)
    monkeypatch.chdir(tmp_path)
    world = load_world_or_map("tiny.map")  # no '/': a path all the same, not a shipped name
    assert world.name == "tiny" and world.bounds == (0.0, 6 * DEFAULT_CELL_SIZE_M, 0.0, 4 * DEFAULT_CELL_SIZE_M)
    world = load_world_or_map(str(tmp_path / "tiny.txt"), cell_size=0.6)
    assert world.name == "tiny.txt" and world.bounds == pytest.approx((0.0, 3.6, 0.0, 2.4))
    assert load_movingai(tmp_path / "tiny.map").passable.astype(int).tolist() == TINY_PASSABLE
    assert load_world_or_map("empty", cell_size=123.0).name == "empty"  # other worlds ignore it
    (tmp_path / "broken.map").write_text("name: broken\n")  # a .map is read as one, strictly
    with pytest.raises(WorldFileError, match=r"^broken\.map: line 1: expected a header line"):
        load_world_or_map("broken.map")
    with pytest.raises(WorldFileError, match=r"^gone\.map: file not found$"):
        load_world_or_map("gone.map")
    with pytest.raises(WorldFileError, match=r"A file path must contain '/' or end in \.yaml, \.yml or \.map$"):
        load_world_or_map("warehouse")


def test_cell_size_flag_and_its_variable() -> None:
    parser = build_parser()
    assert parser.get_default("cell_size") == DEFAULT_CELL_SIZE_M
    assert parser.parse_args(["--world", "w.map", "--cell-size", "0.6"]).cell_size == 0.6
    args = parser.parse_args(container_entry.build_argv([], {"SIMD_CELL_SIZE": "0.6", "SIMD_WORLD": "w.map"}))
    assert (args.cell_size, args.world) == (0.6, "w.map")


@pytest.mark.parametrize("value", ["0", "-0.5", "nan", "inf"])
def test_a_bad_cell_size_is_one_line_and_exit_2(value: str) -> None:
    p = subprocess.run(
        simd_command("--world", "empty", f"--cell-size={value}", "-l", f"tcp/127.0.0.1:{free_port()}"),
        capture_output=True, text=True, cwd=ROOT, timeout=30,
    )  # fmt: skip
    assert p.returncode == 2
    assert p.stderr.strip() == f"simd: error: --cell-size must be a finite number of metres > 0, got {float(value):g}"
