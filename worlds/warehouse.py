"""A warehouse as a MovingAI grid map, for ``simd --world warehouse.map --cell-size 0.5``.

    python -m worlds.warehouse -o warehouse.map [--blocks-x 4] [--blocks-y 3] [--shelf-length 10]
                                                [--rows-per-block 5] [--seed N] [--force]

Our own layout, in the spirit of the League of Robot Runners' warehouse maps: a grid of shelf
blocks. A block is ``rows_per_block`` shelves, each one cell thick and ``shelf_length`` cells
long, stacked with a one-cell aisle between consecutive shelves; every aisle runs the block's
whole length and opens at both ends onto a two-cell main corridor. Main corridors run between
the blocks and all around the edge. With a seed, about half of the shelves get a one-cell gap at
a place drawn from it (a crossing between two aisles); without one every shelf is whole. So there
is no dead end, and every open cell reaches every other (checked by a flood fill before the map
is returned). The same arguments give the same text.

Here is ``warehouse_text(2, 1, 6, 3)``: 18 x 9 cells, 126 open, 4 aisles::

    ..................
    ..................
    ..@@@@@@..@@@@@@..
    ..................
    ..@@@@@@..@@@@@@..
    ..................
    ..@@@@@@..@@@@@@..
    ..................
    ..................
"""

from __future__ import annotations

import argparse
import math
import os
import random
import sys
import tempfile
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import NoReturn

CORRIDOR = 2  # cells: the main corridors between blocks and around the edge
AISLE = 1  # cells: between two shelves of a block
#: the largest side simd reads (simd.core.movingai.MAX_SIDE; this package does not import simd)
MAX_SIDE = 4_000
#: the share of open cells that robots may take in :func:`warehouse_for_robots`
ROBOT_SHARE = 0.10
OPEN, SHELF = ".", "@"


@dataclass(frozen=True)
class Layout:
    """The sizes of a warehouse, and where its shelves are."""

    blocks_x: int
    blocks_y: int
    shelf_length: int
    rows_per_block: int

    def __post_init__(self) -> None:
        for name in ("blocks_x", "blocks_y", "shelf_length", "rows_per_block"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"{name} must be a whole number >= 1, got {value!r}")
        if max(self.width, self.height) > MAX_SIDE:
            raise ValueError(
                f"a warehouse of {self.width} x {self.height} cells is larger than simd reads "
                f"({MAX_SIDE} x {MAX_SIDE}): use fewer or smaller blocks"
            )

    @property
    def block_height(self) -> int:
        return self.rows_per_block + (self.rows_per_block - 1) * AISLE

    @property
    def width(self) -> int:
        return CORRIDOR + self.blocks_x * (self.shelf_length + CORRIDOR)

    @property
    def height(self) -> int:
        return CORRIDOR + self.blocks_y * (self.block_height + CORRIDOR)

    @property
    def aisles(self) -> int:
        return self.blocks_x * self.blocks_y * (self.rows_per_block - 1)

    @property
    def shelves(self) -> int:
        return self.blocks_x * self.blocks_y * self.rows_per_block

    def open_cells(self) -> int:
        """The open cells with every shelf whole (a seed's gaps add one each)."""
        return self.width * self.height - self.shelves * self.shelf_length

    def shelf_rows(self) -> list[tuple[int, int]]:
        """(row, first column) of every shelf, top to bottom, left to right."""
        return [
            (
                CORRIDOR + by * (self.block_height + CORRIDOR) + k * (1 + AISLE),
                CORRIDOR + bx * (self.shelf_length + CORRIDOR),
            )
            for by in range(self.blocks_y)
            for k in range(self.rows_per_block)
            for bx in range(self.blocks_x)
        ]


def warehouse_rows(layout: Layout, seed: int | None = None) -> list[str]:
    """The map's lines, top first, checked to be one connected open space."""
    grid = [[OPEN] * layout.width for _ in range(layout.height)]
    rng = random.Random(seed) if seed is not None else None
    for row, col in layout.shelf_rows():
        grid[row][col : col + layout.shelf_length] = [SHELF] * layout.shelf_length
        if rng is not None and layout.shelf_length >= 3 and rng.random() < 0.5:
            grid[row][col + rng.randrange(1, layout.shelf_length - 1)] = OPEN  # never at an end
    rows = ["".join(line) for line in grid]
    regions = open_regions(rows)
    if regions != 1:  # the layout's promise; a failure here is a bug in this module
        raise RuntimeError(f"the warehouse's open space falls into {regions} parts")
    return rows


def warehouse_text(
    blocks_x: int = 4,
    blocks_y: int = 3,
    shelf_length: int = 10,
    rows_per_block: int = 5,
    seed: int | None = None,
) -> str:
    """The warehouse as the text of a MovingAI ``.map`` file (ValueError on bad sizes)."""
    layout = Layout(blocks_x, blocks_y, shelf_length, rows_per_block)
    return map_text(warehouse_rows(layout, seed))


def warehouse_for_robots(n: int, seed: int | None = None) -> str:
    """The smallest warehouse of default blocks (growing one block at a time, wider first) in
    which ``n`` robots, one a cell, take at most :data:`ROBOT_SHARE` of the open cells."""
    layout = layout_for_robots(n)
    return map_text(warehouse_rows(layout, seed))


def layout_for_robots(n: int) -> Layout:
    if not isinstance(n, int) or isinstance(n, bool) or n < 0:
        raise ValueError(f"the number of robots must be a whole number >= 0, got {n!r}")
    need = math.ceil(n / ROBOT_SHARE)
    blocks_x = blocks_y = 1
    while True:
        layout = Layout(blocks_x, blocks_y, 10, 5)  # ValueError once it outgrows MAX_SIDE
        if layout.open_cells() >= need:
            return layout
        if blocks_x > blocks_y:
            blocks_y += 1
        else:
            blocks_x += 1


def map_text(rows: Sequence[str]) -> str:
    return f"type octile\nheight {len(rows)}\nwidth {len(rows[0])}\nmap\n" + "".join(f"{row}\n" for row in rows)


def open_regions(rows: Sequence[str]) -> int:
    """How many separate pieces the open cells make, neighbours being the four sides."""
    height, width = len(rows), len(rows[0]) if rows else 0
    seen = [[False] * width for _ in range(height)]
    regions = 0
    for r0 in range(height):
        for c0 in range(width):
            if rows[r0][c0] != OPEN or seen[r0][c0]:
                continue
            regions += 1
            seen[r0][c0] = True
            todo = deque([(r0, c0)])
            while todo:
                r, c = todo.popleft()
                for rr, cc in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)):
                    if 0 <= rr < height and 0 <= cc < width and rows[rr][cc] == OPEN and not seen[rr][cc]:
                        seen[rr][cc] = True
                        todo.append((rr, cc))
    return regions


# --- the command ------------------------------------------------------------------------------


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:  # one line, as simd's own refusals
        self.exit(2, f"{self.prog}: error: {message}\n")


def _whole(least: int) -> Callable[[str], int]:
    """An argparse type: a whole number at least ``least``, else one line saying so."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = least - 1
        if value < least:
            raise argparse.ArgumentTypeError(f"must be a whole number >= {least}, got {text!r}")
        return value

    return parse


_at_least_one, _seed = _whole(1), _whole(0)


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog="python -m worlds.warehouse",
        description="Write a warehouse as a MovingAI grid map: blocks of shelves with one-cell aisles between "
        "them, two-cell corridors between the blocks and around the edge (simd --world FILE.map --cell-size 0.5).",
    )
    p.add_argument("-o", "--output", required=True, metavar="FILE.map", help="where to write the map")
    p.add_argument(
        "--blocks-x", type=_at_least_one, default=4, metavar="N", help="blocks across (default: %(default)s)"
    )
    p.add_argument("--blocks-y", type=_at_least_one, default=3, metavar="N", help="blocks down (default: %(default)s)")
    p.add_argument(
        "--shelf-length", type=_at_least_one, default=10, metavar="N", help="cells per shelf (default: %(default)s)"
    )
    p.add_argument(
        "--rows-per-block",
        type=_at_least_one,
        default=5,
        metavar="N",
        help="shelves per block, with an aisle between each two (default: %(default)s)",
    )
    p.add_argument(
        "--seed",
        type=_seed,
        default=None,
        metavar="N",
        help="cut a one-cell gap into about half of the shelves, at places drawn from N (default: every shelf whole)",
    )
    p.add_argument("--force", action="store_true", help="replace FILE.map if it exists")
    return p


def write_new(path: Path, text: str, force: bool) -> None:
    """Write ``text`` to ``path`` whole or not at all; without ``force`` an existing file stays
    (FileExistsError), even one that appears while this writes."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="ascii", newline="\n") as f:
            f.write(text)
        os.chmod(tmp, 0o644)  # as any file the user writes (mkstemp makes it private)
        if not force:
            try:
                os.link(tmp, path)  # fails if the name is taken, unlike a rename
                return
            except FileExistsError:
                raise
            except OSError:  # a file system without hard links: look, then rename
                if path.exists():
                    raise FileExistsError(path) from None
        os.replace(tmp, path)
    finally:
        Path(tmp).unlink(missing_ok=True)


def main(argv: list[str] | None = None) -> int:
    p = build_parser()
    args = p.parse_args(argv)
    path = Path(args.output)
    try:
        layout = Layout(args.blocks_x, args.blocks_y, args.shelf_length, args.rows_per_block)
    except ValueError as e:
        p.error(str(e))
    if not path.parent.is_dir():
        p.error(f"{path.parent}: no such directory")
    if path.exists() and not args.force:
        p.error(f"{path} already exists: choose another -o, or --force to replace it")
    rows = warehouse_rows(layout, args.seed)
    try:
        write_new(path, map_text(rows), args.force)
    except FileExistsError:
        p.error(f"{path} already exists: choose another -o, or --force to replace it")
    except OSError as e:
        p.error(f"cannot write {path}: {e.strerror or e}")
    print(f"warehouse: wrote {path}: {summary(layout, rows)}")
    return 0


def summary(layout: Layout, rows: Sequence[str]) -> str:
    """``50 x 35 cells, 1150 passable, 48 aisles (4 x 3 blocks of 5 shelves of 10 cells)``"""
    passable = sum(row.count(OPEN) for row in rows)
    blocks = f"{layout.blocks_x} x {layout.blocks_y} blocks of {layout.rows_per_block} shelves of {layout.shelf_length}"
    return f"{layout.width} x {layout.height} cells, {passable} passable, {layout.aisles} aisles ({blocks} cells)"


if __name__ == "__main__":
    sys.exit(main())
