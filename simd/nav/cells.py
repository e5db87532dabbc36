"""The floor as a graph of cells: where each model can stand, how it may move, how far
every cell is from a goal.

Fleet traffic works on cells one robot wide (simd/nav/traffic.py): a robot stands in one,
moves to a neighbour (eight of them; a diagonal step only past two free side cells, as a
robot does not cut a corner), and no cell has two robots. A cell is one robot wide when the
model's circle with its margins (:data:`MARGIN_M` beyond the circumscribed radius, plus
:data:`TRACKING_M` for how far it may stray from the line between two cell centres) fits in
it: 0.35 m for a burger. On a MovingAI map the cells are the map's own.

A model can stand in a cell when its circle (radius plus margin) is clear of every wall at
the cell's centre, and step between two neighbours when it is also clear halfway (a thin
wall on the border between two free cells blocks the step). Clearances come from the world's
exact geometry (costmap.clearance_field) sampled at every cell centre and every midpoint.

Each goal gets a distance field: the length of the shortest way from every cell to the goal
cell over the moves the model may make (Dijkstra). It is the robot's plan and more: when its
next cell on the best way is taken, it knows at once how good every other neighbour is,
which is what priority inheritance (traffic.py) needs.

``dijkstra`` runs the compiled twin, simd/nav/_cellpaths.c (label ``"cellpaths"`` in
simd/core/native.py), when it is built, else ``dijkstra_python`` here, which stays the
reference: both pop their queue in (distance, cell) order, try the moves in :data:`ALL_MOVES`
order (the eight, then for a (cells, 16) graph the knight's moves), replace a distance only by
a strictly smaller one (of two ways of equal length, the one found first stays), add the same
float64 steps (``size * sqrt(dr*dr + dc*dc)``, a correctly rounded square root in both) in the
same order and cast to float32 at the end, so their arrays are equal bit for bit (tested, and
both against a Bellman-Ford relaxation, over the eight moves and over all sixteen).

Speed (``python -m bench.cells_bench``: 134x123 cells of 0.35 m, as many as a 1 000-robot
warehouse has, 50 goals among the free cells; on the 2-core development VM (AMD EPYC), shared
with other work; medians, and the median of 5 runs): with 30 % of the cells blocked at random
(11 400 cells reached) a field over the eight moves takes 0.47 ms compiled and 11.6 ms in
Python (25x), over the sixteen that ``CellGraph.distances`` searches 0.72 ms and 17.1 ms (24x);
on the 1 000-robot warehouse map itself (worlds/warehouse.py, 65 % free) 0.35 ms and 10.8 ms
(31x) over the eight, 0.48 ms and 16.3 ms (34x) over the sixteen. At a goal per robot every
40 s, the sixteen-move fields take ~1-2 % of a core instead of ~40 %. The C search spends ~40 ns
a cell over the eight moves, ~65 ns over the sixteen (twice the moves to try, a third more
edges, a sixth more pushes), most of it in the queue: a 4-ary heap whose entries are one
128-bit integer each (the distance's bits above the cell), so that ordering two takes one
comparison, without branches on the many ties. (Runs on this VM vary by up to a third.)
"""

from __future__ import annotations

import heapq
import math
import operator
from dataclasses import dataclass, field
from typing import Protocol, cast

import numpy as np
import numpy.typing as npt

from fleetcommon.arrays import F32, F64, I64
from simd.core import native
from simd.core.models import RobotModel
from simd.core.worldfile import WorldGeometry
from simd.nav.costmap import Grid, clearance_field
from simd.nav.lanes import keep_right, reversed_moves

B = npt.NDArray[np.bool_]

#: room (m) kept between a robot's circumscribed circle and anything else
MARGIN_M = 0.02
#: how far (m) a robot may stray from the line between two cell centres
TRACKING_M = 0.03
#: the eight moves as (d_row, d_col), axis moves first
MOVES: tuple[tuple[int, int], ...] = ((0, 1), (1, 0), (0, -1), (-1, 0), (1, 1), (1, -1), (-1, -1), (-1, 1))
# the moves that leave a cell upwards (to a smaller row), downwards, to the left, to the right
_UP, _DOWN = [k for k, m in enumerate(MOVES) if m[0] < 0], [k for k, m in enumerate(MOVES) if m[0] > 0]
_LEFT, _RIGHT = [k for k, m in enumerate(MOVES) if m[1] < 0], [k for k, m in enumerate(MOVES) if m[1] > 0]


class _CompiledDistances(Protocol):
    """simd.nav._cellpaths (simd/nav/_cellpaths.c): the distances as float32 bytes."""

    def dijkstra(self, moves: npt.NDArray[np.bool_], width: int, goal: int, size: float, /) -> bytearray: ...


_module, NATIVE_UNAVAILABLE = native.load("cellpaths")
_native = cast("_CompiledDistances | None", _module)


def body_radius(model: RobotModel) -> float:
    """The radius of the circle a model holds cells with (circumscribed, plus margin)."""
    return model.radius + MARGIN_M


def cell_size_for(model: RobotModel) -> float:
    """The smallest cell one robot of ``model`` fits in, rounded up to the centimetre."""
    return math.ceil(200.0 * (body_radius(model) + TRACKING_M)) / 100.0


@dataclass
class CellGraph:
    """The cells over a world's bounds (side ``size``, origin at the bounds' lower-left
    corner, row 0 at the smallest y) and, per model, where it stands and how it moves."""

    world: WorldGeometry
    size: float
    align: bool = False
    #: one-way lanes in the corridors two cells wide (simd/nav/lanes.py): on grid maps
    one_way: bool = False
    grid: Grid = field(init=False)
    _half: F32 = field(init=False)  # clearance at every centre and midpoint (a grid of size/2)
    _standable: dict[str, B] = field(default_factory=dict, init=False)
    _moves: dict[str, npt.NDArray[np.bool_]] = field(default_factory=dict, init=False)
    _inside: npt.NDArray[np.bool_] | None = field(default=None, init=False)

    #: with ``align``, origins tried per axis (the one that lets most cell centres be stood on is taken)
    SHIFTS = 7

    def __post_init__(self) -> None:
        self.grid = Grid.covering(self.world, self.size)
        if self.align:
            self.grid = self._aligned()
        self._half = clearance_field(self.world, _half_grid(self.grid), max(self.size, 1.0))

    def _aligned(self) -> Grid:
        """The cells laid so that the most of the floor around the world's default spawn is
        connected (an open world's pillars and walls do not follow its bounds' corner: a grid
        shifted by part of a cell often lets far more cell centres be stood on, and a passage
        one robot wide be passed). A grid map's cells are its own, never shifted."""
        x_min, x_max, y_min, y_max = self.world.bounds
        size = self.size
        # laid for the largest model the cells are for (a waffle's floor is not a burger's)
        need = max((body_radius(m) for m in _models() if cell_size_for(m) <= size + 1e-9), default=0.0)
        need = need or min(body_radius(m) for m in _models())
        spawn = self.world.default_spawn
        best, best_score = self.grid, (-1, -1)
        for sx in range(self.SHIFTS):
            for sy in range(self.SHIFTS):
                x0 = x_min - sx * size / self.SHIFTS
                y0 = y_min - sy * size / self.SHIFTS
                grid = Grid(x0, y0, size, max(1, math.ceil((x_max - x0) / size - 1e-9)),
                            max(1, math.ceil((y_max - y0) / size - 1e-9)))  # fmt: skip
                stand, across, up = _axis_steps(self.world, grid, need)
                score = (_component(stand, across, up, grid.cell(spawn[0], spawn[1])), int(stand.sum()))
                if score > best_score:
                    best, best_score = grid, score
        return best

    @property
    def width(self) -> int:
        return self.grid.width

    @property
    def height(self) -> int:
        return self.grid.height

    @property
    def count(self) -> int:
        return self.grid.width * self.grid.height

    def index(self, x: float, y: float) -> int | None:
        cell = self.grid.cell(x, y)
        return None if cell is None else cell[0] * self.grid.width + cell[1]

    def centre(self, index: int) -> tuple[float, float]:
        row, col = divmod(index, self.grid.width)
        return self.grid.centre(row, col)

    def centres(self, indices: I64) -> F64:
        rows, cols = np.divmod(indices, self.grid.width)
        xy = np.empty((len(indices), 2))
        xy[:, 0] = self.grid.x0 + (cols + 0.5) * self.size
        xy[:, 1] = self.grid.y0 + (rows + 0.5) * self.size
        return xy

    def fits(self, model: RobotModel) -> bool:
        """Whether one robot of ``model`` fits in a cell."""
        return cell_size_for(model) <= self.size + 1e-9

    def standable(self, model: RobotModel) -> B:
        """Per cell (flat): whether the model can stand at its centre."""
        s = self._standable.get(model.name)
        if s is None:
            need = body_radius(model)
            s = (self._half[1::2, 1::2] >= need).ravel()
            s.setflags(write=False)
            self._standable[model.name] = s
        return s

    def moves(self, model: RobotModel) -> npt.NDArray[np.bool_]:
        """(cells, 8): whether the model may step from each cell by each of :data:`MOVES`."""
        m = self._moves.get(model.name)
        if m is None:
            m = self._allowed_moves(model)
            if self.one_way:
                m = keep_right(self.standable(model).reshape(self.height, self.width), m, MOVES)
            m.setflags(write=False)
            self._moves[model.name] = m
        return m

    def _allowed_moves(self, model: RobotModel) -> npt.NDArray[np.bool_]:
        h, w = self.height, self.width
        need = body_radius(model)
        stand = self.standable(model).reshape(h, w)
        padded = np.zeros((h + 2, w + 2), dtype=bool)
        padded[1:-1, 1:-1] = stand
        half = self._half
        out = np.zeros((h, w, len(MOVES)), dtype=bool)
        for k, (dr, dc) in enumerate(MOVES):
            target = padded[1 + dr : 1 + dr + h, 1 + dc : 1 + dc + w]
            ok = stand & target
            # the step's midpoint on the half grid: centre (2r+1, 2c+1) plus (dr, dc)
            mid = np.full((h, w), -1.0, dtype=np.float32)
            r0, c0 = 1 + dr, 1 + dc
            mid[:, :] = half[r0 : r0 + 2 * h : 2, c0 : c0 + 2 * w : 2]
            ok &= mid >= need
            if dr and dc:  # a diagonal passes both side cells: no corner cutting
                ok &= padded[1 + dr : 1 + dr + h, 1 : 1 + w] & padded[1 : 1 + h, 1 + dc : 1 + dc + w]
            out[:, :, k] = ok
        return out.reshape(h * w, len(MOVES))

    @property
    def inside(self) -> npt.NDArray[np.bool_]:
        """(cells, 8): whether each move stays on the grid (a way back onto the map's steps
        for a robot that stands off them)."""
        if self._inside is None:
            rows, cols = np.divmod(np.arange(self.count), self.width)
            self._inside = np.stack(
                [(rows + dr >= 0) & (rows + dr < self.height) & (cols + dc >= 0) & (cols + dc < self.width)
                 for dr, dc in MOVES], axis=1)  # fmt: skip
        return self._inside

    def sweep(self, index: int, k: int) -> tuple[int, ...]:
        """Every cell a robot covers stepping from cell ``index`` by move ``k``: the two cells,
        and the two side cells of a diagonal (it passes their corner)."""
        n = self.neighbour(index, k)
        dr, dc = MOVES[k]
        if dr and dc:
            w = self.grid.width
            return (index, n, index + dc, index + dr * w)
        return (index, n)

    def neighbour(self, index: int, k: int) -> int:
        """The cell one move ``k`` away (the caller knows it is on the grid)."""
        dr, dc = MOVES[k]
        return index + dr * self.grid.width + dc

    def distances(self, model: RobotModel, goal: int, blocked: I64 | None = None) -> F32:
        """Metres from every cell to ``goal`` (inf where there is no way), with the cells
        ``blocked`` (flat) treated as walls. Measured over the eight moves and the eight
        knight's moves (each allowed where both ways of making it from the eight are), so the
        field is within 3 % of straight-line distance in the open instead of 8 %: a robot that
        walks down it cell by cell takes a near-straight line, not an L."""
        moves = self.moves(model)
        if blocked is not None and len(blocked):
            moves = moves.copy()
            hit = set(blocked.tolist())
            w, h = self.width, self.height
            for b in hit:  # no step whose body passes over a blocked cell
                br, bc = divmod(b, w)
                for r in range(max(0, br - 2), min(h, br + 3)):
                    for c in range(max(0, bc - 2), min(w, bc + 3)):
                        src = r * w + c
                        for k in np.flatnonzero(moves[src]).tolist():
                            if not hit.isdisjoint(self.sweep(src, k)):
                                moves[src, k] = False
        if self.one_way:  # the distance *to* the goal: searched from it over the moves turned around
            moves = reversed_moves(moves, self.width, MOVES)
        return dijkstra(with_knights(moves, self.width), self.width, goal, self.size)


#: the knight's moves of the distance fields, each as its two ways through the eight:
#: (d_row, d_col), (first move, then move), (other first move, then move) as MOVES indices
KNIGHTS: tuple[tuple[tuple[int, int], tuple[int, int], tuple[int, int]], ...] = tuple(
    (
        (dr, dc),
        (MOVES.index(a), MOVES.index((dr - a[0], dc - a[1]))),
        (MOVES.index(b), MOVES.index((dr - b[0], dc - b[1]))),
    )
    for dr, dc, a, b in (
        (1, 2, (0, 1), (1, 1)),
        (2, 1, (1, 0), (1, 1)),
        (2, -1, (1, 0), (1, -1)),
        (1, -2, (0, -1), (1, -1)),
        (-1, -2, (0, -1), (-1, -1)),
        (-2, -1, (-1, 0), (-1, -1)),
        (-2, 1, (-1, 0), (-1, 1)),
        (-1, 2, (0, 1), (-1, 1)),
    )
)
ALL_MOVES: tuple[tuple[int, int], ...] = MOVES + tuple(k[0] for k in KNIGHTS)


def with_knights(moves: npt.NDArray[np.bool_], width: int) -> npt.NDArray[np.bool_]:
    """(cells, 16): the eight moves, then the knight's moves allowed where both of their ways
    through the eight are (so a knight's move never cuts a corner or jumps a wall)."""
    n = len(moves)
    out = np.zeros((n, len(ALL_MOVES)), dtype=bool)
    out[:, : len(MOVES)] = moves
    idx = np.arange(n)
    for j, (_, (a1, a2), (b1, b2)) in enumerate(KNIGHTS):
        ok = np.ones(n, dtype=bool)
        for first, then in ((a1, a2), (b1, b2)):
            dr, dc = MOVES[first]
            mid = idx + dr * width + dc
            inside = (mid >= 0) & (mid < n)
            step = np.zeros(n, dtype=bool)
            step[inside] = moves[inside, first] & moves[mid[inside], then]
            ok &= step
        out[:, len(MOVES) + j] = ok
    return out


def dijkstra(moves: npt.NDArray[np.bool_], width: int, goal: int, size: float) -> F32:
    """Distances to ``goal`` on the graph ``moves`` of a grid ``width`` wide: (cells, 8) over
    :data:`MOVES`, or (cells, 16) over :data:`ALL_MOVES` (the eight and the knight's moves, as
    :func:`with_knights` makes them), move (dr, dc) costing ``size * sqrt(dr*dr + dc*dc)``:
    float32, inf where there is no way, all inf when ``goal`` is not a cell. The moves must be
    symmetric (then distances *to* the goal are distances *from* it; not checked). ValueError
    when ``moves`` is not a C-contiguous (cells, 8) or (cells, 16) bool array, ``width`` (>= 1)
    does not divide its cells into rows, ``size`` is not finite and > 0, or a move leads off the
    grid. Runs the compiled twin when it is built (``moves`` read in place without the GIL: no
    other thread may write it meanwhile), else ``dijkstra_python``; both return the same array,
    bit for bit."""
    return (dijkstra_python if _native is None else dijkstra_native)(moves, width, goal, size)


def dijkstra_native(moves: npt.NDArray[np.bool_], width: int, goal: int, size: float) -> F32:
    """``dijkstra`` in the compiled twin (RuntimeError when it is not built)."""
    if _native is None:
        raise RuntimeError(f"the compiled distance field is not available: {NATIVE_UNAVAILABLE}")
    width, size = checked_graph(moves, width, size)
    goal = operator.index(goal)
    if not 0 <= goal < len(moves):  # also keeps a goal beyond a C integer off the compiled call
        return np.full(len(moves), np.inf, dtype=np.float32)
    # _cellpaths.c checks that no move leads off the grid itself (the border only), in check_on_grid's words
    return np.frombuffer(_native.dijkstra(moves, width, goal, size), dtype=np.float32)


def dijkstra_python(moves: npt.NDArray[np.bool_], width: int, goal: int, size: float) -> F32:
    """``dijkstra`` in Python (heapq): the reference of the compiled twin."""
    width, size = checked_graph(moves, width, size)
    check_on_grid(moves, width)
    goal = operator.index(goal)
    n = len(moves)
    dist = np.full(n, np.inf, dtype=np.float64)
    if not 0 <= goal < n:
        return dist.astype(np.float32)
    dist[goal] = 0.0
    kinds = moves.shape[1]
    offsets = [dr * width + dc for dr, dc in ALL_MOVES[:kinds]]
    steps = [size * math.sqrt(dr * dr + dc * dc) for dr, dc in ALL_MOVES[:kinds]]
    heap = [(0.0, goal)]
    allowed = moves.tolist()
    while heap:
        d, c = heapq.heappop(heap)
        if d > dist[c]:
            continue
        row = allowed[c]
        for k in range(kinds):
            if row[k]:
                nb = c + offsets[k]
                nd = d + steps[k]
                if nd < dist[nb]:
                    dist[nb] = nd
                    heapq.heappush(heap, (nd, nb))
    return dist.astype(np.float32)


def checked_graph(moves: npt.NDArray[np.bool_], width: int, size: float) -> tuple[int, float]:
    """``width`` as an int and ``size`` as a float, or ValueError saying what is wrong with the
    graph (all but moves leading off the grid: :func:`check_on_grid`)."""
    kinds = (len(MOVES), len(ALL_MOVES))
    if not isinstance(moves, np.ndarray) or moves.dtype != np.bool_ or moves.ndim != 2 or moves.shape[1] not in kinds:
        what = f"{moves.shape} {moves.dtype} array" if isinstance(moves, np.ndarray) else type(moves).__name__
        raise ValueError(f"moves must be a (cells, 8) or (cells, 16) bool array, not {what}")
    if not moves.flags.c_contiguous:
        raise ValueError("moves must be C-contiguous")
    width = operator.index(width)
    if width < 1 or len(moves) % width:
        raise ValueError(f"width {width} does not divide the {len(moves)} cells into rows")
    size = float(size)  # a numpy float32 would make the steps float32
    if not (math.isfinite(size) and size > 0.0):
        raise ValueError(f"size must be finite and > 0, not {size!r}")
    return width, size


def check_on_grid(moves: npt.NDArray[np.bool_], width: int) -> None:
    """ValueError naming the first (cell, move) that leads off the grid ``width`` wide, as
    _cellpaths.c words it, if any: the searches trust the moves and do no bounds checks. Only
    border cells can, so this reads O(rows + width) of ``moves``."""
    kinds = moves.shape[1]
    grid = moves.reshape(-1, width, kinds)
    rows = len(grid)
    if kinds == len(MOVES) and (
        not rows
        or not (
            grid[0][:, _UP].any()
            or grid[-1][:, _DOWN].any()
            or grid[:, 0][:, _LEFT].any()
            or grid[:, -1][:, _RIGHT].any()
        )
    ):
        return
    edge = 1 if kinds == len(MOVES) else 2  # knight's moves reach two cells
    sides = [c for c in range(width) if c < edge or c >= width - edge]  # all of them when width <= 2 * edge
    for r in range(rows):
        cols = range(width) if (r < edge or r >= rows - edge) else sides
        for c in cols:
            for k, (dr, dc) in enumerate(ALL_MOVES[:kinds]):
                if grid[r, c, k] and not (0 <= r + dr < rows and 0 <= c + dc < width):
                    raise ValueError(f"moves[{r * width + c}, {k}] steps off the grid ({width} cells wide)")


def _half_grid(grid: Grid) -> Grid:
    """The grid of every cell centre and every midpoint between two neighbours' centres."""
    s = grid.resolution
    return Grid(grid.x0 - s / 4, grid.y0 - s / 4, s / 2, 2 * grid.width + 1, 2 * grid.height + 1)


def _axis_steps(world: WorldGeometry, grid: Grid, need: float) -> tuple[B, B, B]:
    """Where a circle of radius ``need`` stands (per cell), and may step right and up
    (per cell: to the neighbour at col + 1 / row + 1), as (h, w) arrays."""
    half = clearance_field(world, _half_grid(grid), need + 0.01)
    h, w = grid.height, grid.width
    stand = half[1::2, 1::2] >= need
    across = np.zeros((h, w), dtype=bool)
    across[:, :-1] = stand[:, :-1] & stand[:, 1:] & (half[1::2, 2:-1:2] >= need)
    up = np.zeros((h, w), dtype=bool)
    up[:-1, :] = stand[:-1, :] & stand[1:, :] & (half[2:-1:2, 1::2] >= need)
    return stand, across, up


def _component(stand: B, across: B, up: B, start: tuple[int, int] | None) -> int:
    """How many cells the axis steps connect to ``start`` (0 when it cannot be stood on): the
    cells a distance field over those steps reaches. A flood fill in Python took ~0.2 s a
    grid on the 287 x 287 cells of the empty world, ~10 s for the 49 grids tried there before
    its first goal; the field is a few ms."""
    if start is None or not stand[start]:
        return 0
    h, w = stand.shape
    moves = np.zeros((h, w, len(MOVES)), dtype=bool)  # MOVES: right, up a row, left, down a row, ...
    moves[:, :, 0] = across
    moves[:, :, 1] = up
    moves[:, 1:, 2] = across[:, :-1]
    moves[1:, :, 3] = up[:-1, :]
    reached = np.isfinite(dijkstra(moves.reshape(h * w, len(MOVES)), w, start[0] * w + start[1], 1.0))
    return int(reached.sum())


def _models() -> list[RobotModel]:
    from simd.core.models import MODELS

    return list(MODELS.values())
