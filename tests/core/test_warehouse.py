"""The warehouse generator: its layout (aisles, corridors, no dead end, one open space), its
determinism and sizing, its command, and a generated warehouse served by a real simd."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from protocol import FleetError
from protocol.errors import ErrorCode
from simd.core import movingai
from simd.core.movingai import MovingAIMap, parse_movingai
from tests.conftest import ROOT, Daemon
from worlds import warehouse
from worlds.warehouse import Layout, layout_for_robots, main, open_regions, warehouse_for_robots, warehouse_text

Size = tuple[int, int, int, int]  # blocks_x, blocks_y, shelf_length, rows_per_block
SIZES: list[Size] = [(1, 1, 1, 1), (1, 1, 3, 2), (2, 1, 6, 3), (4, 3, 10, 5), (3, 5, 7, 4)]


def read(text: str) -> MovingAIMap:
    """Through simd's own reader: the generator writes what simd reads."""
    return parse_movingai(text, "warehouse.map")


def one_piece(passable: np.ndarray) -> bool:
    """Whether the open cells are one 4-connected piece: grow from one cell until nothing changes
    (a flood fill of its own, shared with nothing in the generator)."""
    reached = np.zeros_like(passable)
    reached[tuple(np.argwhere(passable)[0])] = True
    while True:
        grown = reached.copy()
        grown[1:] |= reached[:-1]
        grown[:-1] |= reached[1:]
        grown[:, 1:] |= reached[:, :-1]
        grown[:, :-1] |= reached[:, 1:]
        grown &= passable
        if np.array_equal(grown, reached):
            return bool(np.array_equal(reached, passable))
        reached = grown


def runs(line: np.ndarray) -> list[int]:
    """The lengths of the runs of True in a line of cells."""
    edges = np.flatnonzero(np.diff(np.concatenate(([0], line.astype(np.int8), [0]))))
    return [int(b - a) for a, b in zip(edges[0::2], edges[1::2], strict=True)]


def open_neighbours(passable: np.ndarray) -> np.ndarray:
    p = np.pad(passable, 1).astype(np.int8)
    return p[:-2, 1:-1] + p[2:, 1:-1] + p[1:-1, :-2] + p[1:-1, 2:]


# --- the layout -----------------------------------------------------------------------------


@pytest.mark.parametrize("size", SIZES)
@pytest.mark.parametrize("seed", [None, 0, 7])
def test_every_open_cell_reaches_every_other_and_none_is_a_dead_end(size: Size, seed: int | None) -> None:
    layout = Layout(*size)
    grid = read(warehouse_text(*size, seed=seed))
    assert (grid.width, grid.height) == (layout.width, layout.height)
    assert one_piece(grid.passable)
    assert (open_neighbours(grid.passable)[grid.passable] >= 2).all()  # no dead end anywhere


@pytest.mark.parametrize("size", SIZES)
def test_one_cell_aisles_between_shelves_and_two_cell_corridors_around_blocks(size: Size) -> None:
    blocks_x, blocks_y, shelf_length, rows_per_block = size
    layout = Layout(*size)
    passable = read(warehouse_text(*size)).passable
    shelf_rows = sorted({row for row, _ in layout.shelf_rows()})
    shelf_cols = sorted({col + k for _, col in layout.shelf_rows() for k in range(shelf_length)})
    assert len(shelf_rows) == blocks_y * rows_per_block and len(shelf_cols) == blocks_x * shelf_length
    # down a column through the shelves: corridors of 2 above, between and below the blocks,
    # and a one-cell aisle between each two shelves of a block
    column = [2]
    for _ in range(blocks_y):
        column += [1] * (rows_per_block - 1) + [2]
    assert runs(passable[:, shelf_cols[0]]) == column
    for col in shelf_cols:
        assert np.array_equal(passable[:, col], passable[:, shelf_cols[0]])
    # along a shelf's row: shelves of shelf_length between corridors of 2
    for row in shelf_rows:
        assert runs(passable[row]) == [2] * (blocks_x + 1)
        assert runs(~passable[row]) == [shelf_length] * blocks_x
    # every other row is open from end to end: corridors, and aisles open at both ends
    for row in set(range(layout.height)) - set(shelf_rows):
        assert passable[row].all()
    aisles = [r for r in range(layout.height) if r not in shelf_rows and r - 1 in shelf_rows and r + 1 in shelf_rows]
    assert len(aisles) == blocks_y * (rows_per_block - 1) and layout.aisles == blocks_x * len(aisles)


def test_the_documented_example() -> None:
    text = warehouse_text(2, 1, 6, 3)
    assert text.splitlines()[4:] == [
        "..................",
        "..................",
        "..@@@@@@..@@@@@@..",
        "..................",
        "..@@@@@@..@@@@@@..",
        "..................",
        "..@@@@@@..@@@@@@..",
        "..................",
        "..................",
    ]
    assert text.startswith("type octile\nheight 9\nwidth 18\nmap\n") and text.endswith("..\n")
    assert "18 x 9 cells, 126 open, 4 aisles" in (warehouse.__doc__ or "")
    assert (warehouse.__doc__ or "").count("..@@@@@@..@@@@@@..") == 3


def test_the_same_arguments_give_the_same_map() -> None:
    assert warehouse_text() == warehouse_text()
    assert warehouse_text(seed=3) == warehouse_text(seed=3)
    assert len({warehouse_text(seed=s) for s in range(5)} | {warehouse_text()}) == 6
    gaps = read(warehouse_text(seed=3)).passable.sum() - read(warehouse_text()).passable.sum()
    assert 0 < gaps < Layout(4, 3, 10, 5).shelves  # some shelves, not all, have a gap


def test_sized_for_a_number_of_robots() -> None:
    sizes = []
    for n in (0, 1, 13, 100, 250, 1000):
        grid = read(warehouse_for_robots(n))
        open_cells = int(grid.passable.sum())
        assert n <= 0.10 * open_cells
        if n >= 100:  # not much larger than needed either
            assert n > 0.05 * open_cells, (n, open_cells)
        sizes.append(open_cells)
    assert sizes == sorted(sizes)
    assert warehouse_for_robots(100, seed=1) == warehouse_for_robots(100, seed=1)
    layout = layout_for_robots(100)
    smaller = Layout(layout.blocks_x - 1, layout.blocks_y, 10, 5) if layout.blocks_x > layout.blocks_y else None
    smaller = smaller or Layout(layout.blocks_x, layout.blocks_y - 1, 10, 5)
    assert smaller.open_cells() < 10 * 100  # one block less would not do
    with pytest.raises(ValueError, match="the number of robots must be a whole number >= 0, got -1"):
        warehouse_for_robots(-1)
    with pytest.raises(ValueError, match="larger than simd reads"):
        warehouse_for_robots(10_000_000)


def test_bad_sizes_are_refused() -> None:
    with pytest.raises(ValueError, match=r"^blocks_x must be a whole number >= 1, got 0$"):
        warehouse_text(blocks_x=0)
    with pytest.raises(ValueError, match=r"^rows_per_block must be a whole number >= 1, got True$"):
        warehouse_text(rows_per_block=True)
    with pytest.raises(ValueError, match=r"^a warehouse of 4010 x 35 cells is larger than simd reads \(4000 x 4000\)"):
        warehouse_text(blocks_x=334)
    assert warehouse.MAX_SIDE == movingai.MAX_SIDE
    assert open_regions(["..@..", "..@.."]) == 2 and open_regions(["....."]) == 1


# --- the command ----------------------------------------------------------------------------


def test_the_command_writes_a_map_and_says_what_it_is(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "w.map"
    sizes = ["--blocks-x", "2", "--blocks-y", "1", "--shelf-length", "6", "--rows-per-block", "3"]
    assert main(["-o", str(out), *sizes]) == 0
    assert out.read_text() == warehouse_text(2, 1, 6, 3)
    assert capsys.readouterr().out == (
        f"warehouse: wrote {out}: 18 x 9 cells, 126 passable, 4 aisles (2 x 1 blocks of 3 shelves of 6 cells)\n"
    )
    assert out.stat().st_mode & 0o777 == 0o644
    assert main(["-o", str(out), "--seed", "5", "--force"]) == 0
    assert out.read_text() == warehouse_text(seed=5)
    assert [p.name for p in tmp_path.iterdir()] == ["w.map"]  # no temporary file left behind


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--blocks-x", "0"], "argument --blocks-x: must be a whole number >= 1, got '0'"),
        (["--blocks-y", "two"], "argument --blocks-y: must be a whole number >= 1, got 'two'"),
        (["--shelf-length", "-4"], "argument --shelf-length: must be a whole number >= 1, got '-4'"),
        (["--rows-per-block", "1.5"], "argument --rows-per-block: must be a whole number >= 1, got '1.5'"),
        (["--seed", "-1"], "argument --seed: must be a whole number >= 0, got '-1'"),
        (
            ["--blocks-x", "400"],
            "a warehouse of 4802 x 35 cells is larger than simd reads (4000 x 4000): use fewer or smaller blocks",
        ),
        (["-o", "/nonexistent-dir/w.map"], "/nonexistent-dir: no such directory"),
        (["-o", "TAKEN"], "TAKEN already exists: choose another -o, or --force to replace it"),
    ],
)
def test_the_command_refuses_bad_values_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    taken = tmp_path / "taken.map"
    taken.write_text("mine\n")
    argv = [str(taken) if a == "TAKEN" else a for a in args]
    if "-o" not in argv:
        argv = ["-o", str(tmp_path / "new.map"), *argv]
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err == f"python -m worlds.warehouse: error: {message.replace('TAKEN', str(taken))}\n"
    assert taken.read_text() == "mine\n" and sorted(p.name for p in tmp_path.iterdir()) == ["taken.map"]


def test_the_command_runs_as_a_module(tmp_path: Path) -> None:
    out = tmp_path / "w.map"
    p = subprocess.run([sys.executable, "-m", "worlds.warehouse", "-o", str(out)],
                       capture_output=True, text=True, cwd=ROOT, timeout=30)  # fmt: skip
    assert p.returncode == 0, p.stderr
    assert p.stdout.startswith(f"warehouse: wrote {out}: 50 x 35 cells, 1150 passable, 48 aisles")
    again = subprocess.run([sys.executable, "-m", "worlds.warehouse", "-o", str(out)],
                           capture_output=True, text=True, cwd=ROOT, timeout=30)  # fmt: skip
    assert again.returncode == 2 and len(again.stderr.splitlines()) == 1 and "already exists" in again.stderr


# --- served by simd -------------------------------------------------------------------------


def test_simd_serves_a_generated_warehouse(tmp_path: Path, daemon_factory: Callable[..., Daemon]) -> None:
    path = tmp_path / "warehouse.map"
    path.write_text(warehouse_text())
    grid = parse_movingai(path.read_text(), str(path))
    c = 0.5
    d = daemon_factory("--world", str(path), "--cell-size", str(c), "--lockstep", "--no-noise")
    client = d.client()
    world = client.world()
    b = world.bounds
    assert world.name == "warehouse" and (b.x_min, b.x_max, b.y_min, b.y_max) == (0.0, 25.0, 0.0, 17.5)
    (shelf_row, shelf_col), *_ = Layout(4, 3, 10, 5).shelf_rows()
    aisle = (shelf_row + 1, shelf_col + 4)
    assert grid.passable[aisle] and not grid.passable[shelf_row, shelf_col + 4]
    x, y = grid.cell_centre(*aisle, c)
    robot = client.spawn("tb3_0", x, y)
    assert (robot.pose.x, robot.pose.y) == (x, y)
    x, y = grid.cell_centre(shelf_row, shelf_col + 4, c)
    with pytest.raises(FleetError) as info:
        client.spawn("tb3_1", x, y)
    assert info.value.code == ErrorCode.COLLISION and "would overlap a wall or obstacle" in info.value.message
    assert [r.name for r in client.robots()] == ["tb3_0"]
