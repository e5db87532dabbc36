"""MovingAI grid maps (``.map``), the format of the MAPF benchmarks and the League of Robot Runners.

The format (https://movingai.com/benchmarks/formats.html)::

    type octile
    height 4
    width 6
    map
    ......
    .@@@@.
    ......
    @.....

``.`` and ``G`` are open ground, ``S`` (swamp) is passable too; ``@`` and ``O`` are out of
bounds, and trees (``T``) and water (``W``) are obstacles here as well, since a robot drives
through neither. The first grid line is the top of the map. The header's three keyed lines may
come in any order but each exactly once, and ``map`` ends them. Lines may end in spaces or CRLF.

A map file is untrusted input and is read strictly: every problem is one
:class:`~simd.core.worldfile.WorldFileError` naming the file and the line (and the column of a
bad character). :mod:`simd.core.mapworld` makes a world of it; the parsed grid stays available
(:func:`load_movingai`) for planners that work on cells.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from simd.core.worldfile import SHIPPED_WORLDS, WorldFileError

BoolArray = npt.NDArray[np.bool_]

#: the side of a cell in metres when nobody says otherwise: a burger turns in a one-cell aisle
DEFAULT_CELL_SIZE_M = 0.5
#: the largest height or width read (16 million cells, as many as the largest map_server image)
MAX_SIDE = 4_000
PASSABLE = ".GS"
BLOCKED = "@OTW"
_KINDS = f"passable: {' '.join(PASSABLE)}; blocked: {' '.join(BLOCKED)}"
_HEADER_KEYS = ("type", "height", "width")
#: the first line of a MovingAI map (after a byte-order mark, if any)
_FIRST_LINE = re.compile(rb"\A(?:\xef\xbb\xbf)?type[ \t]+\S")

# each byte of a grid: 1 passable, 0 blocked, 2 unknown
_LOOKUP = np.full(256, 2, dtype=np.int8)
_LOOKUP[[ord(ch) for ch in PASSABLE]] = 1
_LOOKUP[[ord(ch) for ch in BLOCKED]] = 0


@dataclass(frozen=True, eq=False)
class MovingAIMap:
    """A parsed map: ``passable[row, col]``, read-only, with row 0 the first grid line of the
    text (the top of the map, the largest y in a world).

    Placed in a world with cells of side ``cell_size``, cell (row, col) covers x in
    [col c, (col + 1) c] and y in [(height - 1 - row) c, (height - row) c]: the map reads
    as the text looks, and the world's origin is the map's lower-left corner.
    """

    passable: BoolArray

    @property
    def height(self) -> int:
        return int(self.passable.shape[0])

    @property
    def width(self) -> int:
        return int(self.passable.shape[1])

    def cell_centre(self, row: int, col: int, cell_size: float) -> tuple[float, float]:
        """The world point (x, y) at the centre of cell (row, col)."""
        return (col + 0.5) * cell_size, (self.height - row - 0.5) * cell_size

    def cell_at(self, x: float, y: float, cell_size: float) -> tuple[int, int] | None:
        """The cell (row, col) holding the world point (x, y), or None off the map; a point on
        the edge between two cells belongs to the one to its upper right."""
        col, up = math.floor(x / cell_size), math.floor(y / cell_size)
        if not (0 <= col < self.width and 0 <= up < self.height):
            return None
        return self.height - 1 - up, col


def is_movingai(data: bytes, source: str) -> bool:
    """Whether a world file is a MovingAI map: it is named ``*.map`` or begins ``type ...``."""
    return source.endswith(".map") or _FIRST_LINE.match(data) is not None


def load_movingai(path: str | os.PathLike[str]) -> MovingAIMap:
    """Read and check the map at ``path``; raises :class:`WorldFileError`."""
    data, source = SHIPPED_WORLDS.read(Path(path))  # a Path is always a path, never a shipped name
    return read_movingai(data, source)


def read_movingai(data: bytes, source: str) -> MovingAIMap:
    """Check and parse the bytes of a map file; ``source`` names it in errors."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        line = data.count(b"\n", 0, e.start) + 1
        raise WorldFileError(
            source, f"not a text file (byte 0x{data[e.start]:02x} is not UTF-8)", f"line {line}"
        ) from None
    return parse_movingai(text, source)


def parse_movingai(text: str, source: str) -> MovingAIMap:
    """Check and parse the text of a map; ``source`` names it in errors."""
    lines = text.removeprefix("\ufeff").split("\n")
    values, first_grid_line = _header(lines, source)
    height, width = values["height"], values["width"]
    rows = lines[first_grid_line:]
    while rows and not rows[-1].strip():  # blank lines at the end
        rows.pop()
    rows = [row.rstrip() for row in rows[: height + 1]]

    def where(k: int, col: int | None = None) -> str:  # the k-th grid line (from 0) in the file
        line = f"line {first_grid_line + k + 1}"
        return line if col is None else f"{line}, column {col + 1}"

    for k, row in enumerate(rows[:height]):
        if len(row) != width:
            raise WorldFileError(source, f"a grid line of {len(row)} characters, the map's width is {width}", where(k))
    if len(rows) < height:
        raise WorldFileError(
            source, f"the map ends after {len(rows)} of its {height} grid lines (height {height})", where(len(rows))
        )
    if len(rows) > height:
        raise WorldFileError(source, f"a grid line beyond the map's height {height}", where(height))
    grid = "".join(rows)
    if not grid.isascii():
        i = next(i for i, ch in enumerate(grid) if not ch.isascii())
        raise WorldFileError(source, f"unknown character {grid[i]!r} ({_KINDS})", where(*divmod(i, width)))
    kinds = _LOOKUP[np.frombuffer(grid.encode("ascii"), dtype=np.uint8)].reshape(height, width)
    unknown = np.flatnonzero(kinds == 2)
    if unknown.size:
        i = int(unknown[0])
        raise WorldFileError(source, f"unknown character {grid[i]!r} ({_KINDS})", where(*divmod(i, width)))
    passable = kinds == 1
    passable.setflags(write=False)
    return MovingAIMap(passable)


def _header(lines: list[str], source: str) -> tuple[dict[str, int], int]:
    """The header's height and width, and the index of the first grid line."""
    seen: dict[str, int] = {}  # key -> its line number
    values: dict[str, int] = {}
    end = len(lines) + 1  # where the file ends, or its blank tail begins
    for i, raw in enumerate(lines):
        number = i + 1
        line = raw.rstrip()
        words = line.split()
        if words == ["map"]:
            missing = [k for k in _HEADER_KEYS if k not in seen]
            if missing:
                raise WorldFileError(source, f"the header has no {missing[0]!r} line before 'map'", f"line {number}")
            return values, number
        if not words and not any(rest.strip() for rest in lines[i:]):
            end = number
            break
        key = words[0] if words else ""
        if key not in _HEADER_KEYS:
            expected = "'type octile', 'height H', 'width W' or 'map'"
            got = f"got {_excerpt(line)}" if line else "got an empty line"
            raise WorldFileError(source, f"expected a header line {expected}, {got}", f"line {number}")
        if key in seen:
            raise WorldFileError(source, f"a second {key!r} line (the first is line {seen[key]})", f"line {number}")
        seen[key] = number
        if len(words) != 2:
            raise WorldFileError(source, f"expected '{key} VALUE', got {_excerpt(line)}", f"line {number}")
        value = words[1]
        if key == "type":
            if value != "octile":
                raise WorldFileError(
                    source, f"unknown map type {value!r} (MovingAI maps are 'type octile')", f"line {number}"
                )
            continue
        if not re.fullmatch(r"[0-9]+", value) or int(value) == 0:
            raise WorldFileError(source, f"{key} must be a whole number > 0, got {_excerpt(value)}", f"line {number}")
        if int(value) > MAX_SIDE:
            raise WorldFileError(source, f"{key} {int(value)} is more than {MAX_SIDE} cells", f"line {number}")
        values[key] = int(value)
    if not seen:
        raise WorldFileError(source, "an empty file, not a MovingAI map (one begins 'type octile')", "line 1")
    raise WorldFileError(source, "the file ends before the header's 'map' line", f"line {end}")


def _excerpt(text: str, limit: int = 40) -> str:
    return repr(text if len(text) <= limit else text[: limit - 3] + "...")
