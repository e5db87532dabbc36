"""A map_server map (``map.yaml`` + its image) as a world: ``simd --world map.yaml``.

So that a map made by ``fleet-map``, by Cartographer or slam_toolbox, or taken from any ROS
repository becomes a world to drive in. Occupied cells become solid boxes, merged into as few
as the grid allows (runs of a row, then equal runs of consecutive rows), so physics and the
lidar see the walls the map shows, to within a cell: a wall's surface passes somewhere through
the cells that saw it, and the box's face is the cell's edge, so ranges come out up to a cell
short (turtlebot3_world mapped at 5 cm and loaded back: median 3.5 cm, 90 % within 6.6 cm).
Free **and unknown** cells are open space (a SLAM map's unknown outside is beyond its walls
anyway); the map's extent is the world's bounds. The default spawn is the free spot nearest the
map's centre with room for a waffle around it. Maps with a rotated origin are refused.

A MovingAI grid map (``simd --world warehouse.map --cell-size 0.5``, :mod:`simd.core.movingai`)
becomes a world the same way, its blocked cells the boxes, with cells of the size asked for
(the format has none). Its outside is impassable, so four thin walls close it.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from fleetcommon.mapfile import FREE, MapFileError, OccupancyMap, read_map
from simd.core.movingai import DEFAULT_CELL_SIZE_M, MovingAIMap, is_movingai, read_movingai
from simd.core.worldfile import SHIPPED_WORLDS, FloatArray, WorldFileError, WorldGeometry, load_world

#: cells at least this likely to be occupied are walls (the map saver's occupied threshold)
OCCUPIED_FROM = 65
#: free room a default spawn needs around it (a waffle's reach is 0.22 m)
SPAWN_CLEARANCE_M = 0.25
#: the most boxes a map may become (each is a physics shape and four lidar segments)
MAX_BOXES = 200_000
#: the thickness of the walls that close a MovingAI map, just outside its bounds
CLOSING_WALL_M = 0.1


def load_world_or_map(name_or_path: str, cell_size: float = DEFAULT_CELL_SIZE_M) -> WorldGeometry:
    """A shipped world by name, a world file, a map_server map by its YAML's path, or a MovingAI
    map (``*.map``, or a file that begins ``type ...``) with cells of ``cell_size`` metres (which
    other worlds ignore)."""
    data, source = SHIPPED_WORLDS.read(name_or_path)
    if is_movingai(data, source):
        return world_from_movingai(read_movingai(data, source), source, cell_size)
    if is_map_file(data.decode("utf-8", errors="replace")):
        return load_map_world(source)
    return load_world(name_or_path)


def is_map_file(text: str) -> bool:
    """Whether a world YAML is a map_server map (it names an image) rather than a world file."""
    import yaml

    try:
        data = yaml.safe_load(text)
    except (yaml.YAMLError, RecursionError):  # (nested too deep: the world loader says so)
        return False
    return isinstance(data, dict) and "image" in data and "obstacles" not in data


def load_map_world(path: str) -> WorldGeometry:
    try:
        grid = read_map(path)
    except MapFileError as e:
        raise WorldFileError(e.source, e.reason, e.location) from None
    return world_from_map(grid, path)


def occupied_boxes(solid: npt.NDArray[np.bool_]) -> list[tuple[int, int, int, int]]:
    """Rectangles (row0, row1, col0, col1), end-exclusive, that cover ``solid`` exactly: each row's
    runs, grown downwards while the next row has the very same run."""
    boxes: list[tuple[int, int, int, int]] = []
    open_runs: dict[tuple[int, int], int] = {}  # (col0, col1) -> first row
    height = solid.shape[0]
    for r in range(height + 1):
        runs: set[tuple[int, int]] = set()
        if r < height:
            row = np.concatenate(([False], solid[r], [False])).astype(np.int8)
            edges = np.flatnonzero(np.diff(row))
            runs = {(int(a), int(b)) for a, b in zip(edges[0::2], edges[1::2], strict=True)}
        for run in [k for k in open_runs if k not in runs]:
            boxes.append((open_runs.pop(run), r, run[0], run[1]))
        for run in runs:
            open_runs.setdefault(run, r)
    return boxes


def default_spawn(grid: OccupancyMap) -> tuple[float, float, float] | None:
    """The centre of the free cell nearest the map's centre whose surroundings are all free."""
    free = grid.cells == FREE
    k = max(1, math.ceil(SPAWN_CLEARANCE_M / grid.resolution))
    blocked = np.pad((~free).astype(np.int32), k, constant_values=1)
    integral = np.pad(blocked.cumsum(0).cumsum(1), ((1, 0), (1, 0)))
    size = 2 * k + 1
    window = integral[size:, size:] - integral[:-size, size:] - integral[size:, :-size] + integral[:-size, :-size]
    rows, cols = np.nonzero((window == 0) & free)
    if rows.size == 0:
        return None
    centre_r, centre_c = (grid.height - 1) / 2, (grid.width - 1) / 2
    i = int(np.argmin((rows - centre_r) ** 2 + (cols - centre_c) ** 2))
    x0, y0, _ = grid.origin
    return float(x0 + (cols[i] + 0.5) * grid.resolution), float(y0 + (rows[i] + 0.5) * grid.resolution), 0.0


def world_from_map(grid: OccupancyMap, source: str) -> WorldGeometry:
    x0, y0, yaw = grid.origin
    if abs(yaw) > 1e-9:
        raise WorldFileError(source, f"a rotated map (origin yaw {yaw}) cannot be a world; rotate the image instead")
    boxes = occupied_boxes(grid.cells >= OCCUPIED_FROM)
    if len(boxes) > MAX_BOXES:
        raise WorldFileError(source, f"the map's walls make {len(boxes)} boxes, more than {MAX_BOXES}")
    spawn = default_spawn(grid)
    if spawn is None:
        raise WorldFileError(source, f"no free spot with {SPAWN_CLEARANCE_M} m of room around it to spawn a robot")
    res = grid.resolution
    # flush with the cells: neighbouring boxes seal a diagonal wall
    polygons = [_box(x0 + c0 * res, x0 + c1 * res, y0 + r0 * res, y0 + r1 * res) for r0, r1, c0, c1 in boxes]
    name = source.rsplit("/", 1)[-1].removesuffix(".yaml").removesuffix(".yml")
    return WorldGeometry(
        name=name,
        source=source,
        bounds=grid.bounds(),
        default_spawn=spawn,
        polygons=tuple(polygons),
        circles=_no_circles(),
    )


def world_from_movingai(grid: MovingAIMap, source: str, cell_size: float) -> WorldGeometry:
    """The map as a world with cells of ``cell_size`` metres, placed as
    :class:`~simd.core.movingai.MovingAIMap` says (the lower-left corner at the origin, the first
    text line on top): blocked cells as boxes, four walls of :data:`CLOSING_WALL_M` just outside
    the bounds, and the default spawn at the centre of the passable cell nearest the middle."""
    if not (math.isfinite(cell_size) and cell_size > 0):
        raise ValueError(f"a cell size must be a finite number of metres > 0, got {cell_size}")
    boxes = occupied_boxes(~grid.passable)
    if len(boxes) > MAX_BOXES:
        raise WorldFileError(source, f"the map's blocked cells make {len(boxes)} boxes, more than {MAX_BOXES}")
    rows, cols = np.nonzero(grid.passable)
    if rows.size == 0:
        raise WorldFileError(source, "no passable cell to spawn a robot in")
    i = int(np.argmin((rows - (grid.height - 1) / 2) ** 2 + (cols - (grid.width - 1) / 2) ** 2))
    x, y = grid.cell_centre(int(rows[i]), int(cols[i]), cell_size)
    c, h, t = cell_size, grid.height, CLOSING_WALL_M
    top, right = h * c, grid.width * c
    polygons = [_box(c0 * c, c1 * c, (h - r1) * c, (h - r0) * c) for r0, r1, c0, c1 in boxes]
    polygons += [
        _box(-t, right + t, -t, 0.0),  # below, with the corners
        _box(-t, right + t, top, top + t),  # above, with the corners
        _box(-t, 0.0, 0.0, top),  # left
        _box(right, right + t, 0.0, top),  # right
    ]
    return WorldGeometry(
        name=source.rsplit("/", 1)[-1].removesuffix(".map"),
        source=source,
        bounds=(0.0, right, 0.0, top),
        default_spawn=(x, y, 0.0),
        polygons=tuple(polygons),
        circles=_no_circles(),
    )


def _box(x_min: float, x_max: float, y_min: float, y_max: float) -> FloatArray:
    polygon = np.array([[x_min, y_min], [x_max, y_min], [x_max, y_max], [x_min, y_max]], dtype=np.float64)
    polygon.setflags(write=False)
    return polygon


def _no_circles() -> FloatArray:
    circles = np.zeros((0, 3), dtype=np.float64)
    circles.setflags(write=False)
    return circles
