"""simd/nav/cells.py's distance fields: the compiled Dijkstra (_cellpaths.c) returns the
Python reference's float32 array bit for bit, over the eight moves and over the sixteen with
the knight's moves (``with_knights``), both agree with a Bellman-Ford relaxation written out
here, and the table cases, the knight's moves allowed, the steps' costs and input checks."""

from __future__ import annotations

import ctypes
import ctypes.util
import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from fractions import Fraction

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fleetcommon.arrays import F32, F64
from simd.core import native
from simd.core.models import BURGER
from simd.core.worldfile import load_world
from simd.nav import cells
from simd.nav.cells import CellGraph, cell_size_for, dijkstra, dijkstra_native, dijkstra_python, with_knights

Moves = npt.NDArray[np.bool_]
Search = Callable[[Moves, int, int, float], F32]

needs_cellpaths = pytest.mark.skipif(
    cells._native is None, reason=f"simd.nav._cellpaths is not built: {cells.NATIVE_UNAVAILABLE}"
)
SEARCHES = [
    pytest.param(dijkstra_python, id="python"),
    pytest.param(dijkstra_native, id="native", marks=needs_cellpaths),
]
#: the moves as (d_row, d_col), written out again: the contract, not a copy of the table
MOVES = ((0, 1), (1, 0), (0, -1), (-1, 0), (1, 1), (1, -1), (-1, -1), (-1, 1))
#: the sixteen of a (cells, 16) graph: the eight, then the knight's moves
ALL_MOVES = (*MOVES, (1, 2), (2, 1), (2, -1), (1, -2), (-1, -2), (-2, -1), (-2, 1), (-1, 2))


def moves_from(free: Moves, walls: Moves | None = None) -> Moves:
    """The (cells, 8) moves on a grid of ``free`` cells, as CellGraph._allowed_moves makes
    them: both ends free, the midpoint between them not a wall (``walls`` is the half grid,
    (2 rows + 1, 2 cols + 1), cell (r, c) at (2r + 1, 2c + 1)), a diagonal only past two free
    side cells. Symmetric by construction: both directions share the midpoint."""
    rows, cols = free.shape
    if walls is None:
        walls = np.zeros((2 * rows + 1, 2 * cols + 1), dtype=bool)
    padded = np.zeros((rows + 2, cols + 2), dtype=bool)
    padded[1:-1, 1:-1] = free
    out = np.zeros((rows, cols, 8), dtype=bool)
    for k, (dr, dc) in enumerate(MOVES):
        ok = free & padded[1 + dr : 1 + dr + rows, 1 + dc : 1 + dc + cols]
        ok &= ~walls[1 + dr : 1 + dr + 2 * rows : 2, 1 + dc : 1 + dc + 2 * cols : 2]
        if dr and dc:
            ok &= padded[1 + dr : 1 + dr + rows, 1 : 1 + cols] & padded[1 : 1 + rows, 1 + dc : 1 + dc + cols]
        out[:, :, k] = ok
    return out.reshape(rows * cols, 8)


def knights_from(moves: Moves, width: int) -> Moves:
    """(cells, 16): ``moves`` (cells, 8), then each knight's move where every way of making it
    as two of the eight is allowed (a loop over cells, written out again: the contract of
    ``with_knights``). Each knight's move is two of the eight in two orders: an axis move and a
    diagonal, and the diagonal first."""
    n = len(moves)
    out = np.zeros((n, 16), dtype=bool)
    out[:, :8] = moves
    for j, (dr, dc) in enumerate(ALL_MOVES[8:]):
        ways = [(a, b) for a in range(8) for b in range(8) if np.add(MOVES[a], MOVES[b]).tolist() == [dr, dc]]
        assert len(ways) == 2
        for c in range(n):
            out[c, 8 + j] = all(moves[c, a] and moves[c + MOVES[a][0] * width + MOVES[a][1], b] for a, b in ways)
    return out


def bellman_ford(moves: Moves, width: int, goal: int, size: float) -> F64:
    """The distances to ``goal`` by relaxing every move of every cell at once until nothing
    changes: d(c) = min over the moves k allowed from c of |k| * size + d(c + k), over the
    eight moves or (16 columns) the sixteen."""
    n, kinds = moves.shape
    if not 0 <= goal < n:
        return np.full(n, np.inf)
    rows = n // width
    dist = np.full((rows + 4, width + 4), np.inf)  # a border two cells deep that no move reaches
    dist[2 + goal // width, 2 + goal % width] = 0.0
    allowed = moves.reshape(rows, width, kinds)
    while True:
        inner = dist[2:-2, 2:-2]
        best = inner.copy()
        for k, (dr, dc) in enumerate(ALL_MOVES[:kinds]):
            there = dist[2 + dr : 2 + dr + rows, 2 + dc : 2 + dc + width]
            best = np.minimum(best, np.where(allowed[:, :, k], there + math.hypot(dr, dc) * size, np.inf))
        if np.array_equal(best, inner):
            return best.ravel()
        dist[2:-2, 2:-2] = best


@dataclass(frozen=True)
class Graph:
    """A move graph and a search on it."""

    moves: Moves
    width: int
    goal: int
    size: float


@st.composite
def graphs(draw: st.DrawFn, max_side: int = 60, knights: bool = False) -> Graph:
    """Free cells drawn at random (numpy from a drawn seed), a share of the midpoints walls,
    a cell size, and a goal: mostly a free cell, sometimes a blocked one or no cell at all.
    The eight moves, or with ``knights`` the sixteen (``with_knights`` of the eight)."""
    side = st.integers(1, 5) | st.integers(max_side // 3, max_side)
    rows, cols = draw(side), draw(side)
    blocked = draw(st.sampled_from([0.0, 0.1, 0.3, 0.45]))
    walled = draw(st.sampled_from([0.0, 0.0, 0.05, 0.2]))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    free = rng.random((rows, cols)) >= blocked
    walls = rng.random((2 * rows + 1, 2 * cols + 1)) < walled
    size = draw(st.sampled_from([1.0, 0.35, 0.5, 0.1]) | st.floats(1e-3, 100.0))
    n = rows * cols
    open_cells = np.flatnonzero(free).tolist()
    kind = draw(st.integers(0, 9))
    if kind >= 2 and open_cells:
        goal = open_cells[draw(st.integers(0, len(open_cells) - 1))]
    elif kind == 1:
        goal = draw(st.integers(-3, -1) | st.integers(n, n + 3))
    else:
        goal = draw(st.integers(0, n - 1))  # blocked or free
    moves = moves_from(free, walls)
    return Graph(with_knights(moves, cols) if knights else moves, cols, goal, size)


@st.composite
def any_graphs(draw: st.DrawFn) -> Graph:
    """Any (cells, 8) or (cells, 16) moves that stay on the grid, symmetric or not, dense or
    sparse: the twins must agree on every graph they accept, not only on CellGraph's. (Not
    for the Bellman-Ford oracle: on moves that are not symmetric the search's distances are
    those *from* the goal, the oracle's those *to* it.)"""
    rows, cols = draw(st.integers(1, 25)), draw(st.integers(1, 25))
    kinds = draw(st.sampled_from([8, 16]))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    moves = rng.random((rows, cols, kinds)) < draw(st.sampled_from([0.1, 0.3, 0.6, 0.9]))
    r, c = np.indices((rows, cols))
    for k, (dr, dc) in enumerate(ALL_MOVES[:kinds]):
        moves[:, :, k] &= (r + dr >= 0) & (r + dr < rows) & (c + dc >= 0) & (c + dc < cols)
    size = draw(st.sampled_from([1.0, 0.35]) | st.floats(1e-3, 100.0))
    return Graph(moves.reshape(rows * cols, kinds), cols, draw(st.integers(-1, rows * cols)), size)


def same_as_oracle(found: F32, oracle: F64) -> None:
    assert found.dtype == np.float32
    np.testing.assert_array_equal(np.isinf(found), np.isinf(oracle))
    finite = np.isfinite(oracle)
    np.testing.assert_allclose(found[finite], oracle[finite], rtol=1e-6, atol=0.0)


# --- the two twins, and the oracle ----------------------------------------------------------------


def test_the_move_tables_are_the_contract() -> None:
    assert cells.MOVES == MOVES and cells.ALL_MOVES == ALL_MOVES
    for knight, (a1, a2), (b1, b2) in cells.KNIGHTS:  # two ways through the eight, in both orders
        assert np.add(MOVES[a1], MOVES[a2]).tolist() == np.add(MOVES[b1], MOVES[b2]).tolist() == list(knight)
        assert (a1, a2) == (b2, b1)


@pytest.mark.parametrize("knights", [False, True], ids=["8", "16"])
@settings(max_examples=60, derandomize=True, deadline=None)
@given(data=st.data())
def test_the_generated_moves_are_symmetric(knights: bool, data: st.DataObject) -> None:
    graph = data.draw(graphs(knights=knights))
    kinds = graph.moves.shape[1]
    assert kinds == (16 if knights else 8)
    rows = len(graph.moves) // graph.width
    grid = graph.moves.reshape(rows, graph.width, kinds)
    for k, (dr, dc) in enumerate(ALL_MOVES[:kinds]):
        back = ALL_MOVES.index((-dr, -dc))
        for r, c in np.argwhere(grid[:, :, k]).tolist():
            assert grid[r + dr, c + dc, back]


@settings(max_examples=60, derandomize=True, deadline=None)
@given(graph=graphs(max_side=25))
def test_with_knights_is_both_ways_through_the_eight(graph: Graph) -> None:
    got = with_knights(graph.moves, graph.width)
    assert got.dtype == np.bool_ and got.shape == (len(graph.moves), 16) and got.flags.c_contiguous
    np.testing.assert_array_equal(got, knights_from(graph.moves, graph.width))


def same_twins(graph: Graph) -> None:
    fast = dijkstra_native(graph.moves, graph.width, graph.goal, graph.size)
    ref = dijkstra_python(graph.moves, graph.width, graph.goal, graph.size)
    assert fast.dtype == ref.dtype == np.float32 and fast.shape == ref.shape == (len(graph.moves),)
    assert np.array_equal(fast, ref)  # inf where inf, every other value to the bit
    assert fast.tobytes() == ref.tobytes()


@needs_cellpaths
@pytest.mark.parametrize("knights", [False, True], ids=["8", "16"])
@settings(max_examples=300, derandomize=True, deadline=None)
@given(data=st.data())
def test_compiled_and_python_return_the_same_array(knights: bool, data: st.DataObject) -> None:
    same_twins(data.draw(graphs(knights=knights)))


@needs_cellpaths
@settings(max_examples=150, derandomize=True, deadline=None)
@given(graph=any_graphs())
def test_compiled_and_python_agree_on_any_graph_on_the_grid(graph: Graph) -> None:
    same_twins(graph)


@pytest.mark.parametrize("search", SEARCHES)
@pytest.mark.parametrize("knights", [False, True], ids=["8", "16"])
@settings(max_examples=80, derandomize=True, deadline=None)
@given(data=st.data())
def test_distances_are_those_of_bellman_ford(search: Search, knights: bool, data: st.DataObject) -> None:
    graph = data.draw(graphs(knights=knights))
    found = search(graph.moves, graph.width, graph.goal, graph.size)
    same_as_oracle(found, bellman_ford(graph.moves, graph.width, graph.goal, graph.size))


@needs_cellpaths
def test_compiled_and_python_agree_on_warehouse_sized_grids() -> None:
    """134 x 123 cells (a 1 000-robot warehouse), 30 % blocked and a few thin walls; over the
    eight moves and over the sixteen."""
    rng = np.random.default_rng(3)
    rows, cols = 123, 134
    for size in (0.35, 0.5, 1.0 / 3.0):
        free = rng.random((rows, cols)) >= 0.3
        walls = rng.random((2 * rows + 1, 2 * cols + 1)) < 0.03
        eight = moves_from(free, walls)
        sixteen = with_knights(eight, cols)
        reached = []
        for goal in rng.choice(np.flatnonzero(free), 3, replace=False).tolist():
            fields = []
            for moves in (eight, sixteen):
                fields.append(dijkstra_native(moves, cols, goal, size))
                assert np.array_equal(fields[-1], dijkstra_python(moves, cols, goal, size))
            # the knight's moves shorten ways but reach no other cell (each is two of the eight)
            np.testing.assert_array_equal(np.isfinite(fields[0]), np.isfinite(fields[1]))
            assert (fields[1] <= fields[0]).all()
            reached.append(int(np.isfinite(fields[1]).sum()))
        assert max(reached) > rows * cols // 2  # most of the floor is reached
        same_as_oracle(fields[1], bellman_ford(sixteen, cols, goal, size))


# --- table cases ----------------------------------------------------------------------------------


def floor(rows: list[str]) -> tuple[Moves, int]:
    """A grid drawn as text ('#' blocked) as its moves and width."""
    free = np.array([[ch != "#" for ch in row] for row in rows])
    return moves_from(free), free.shape[1]


@pytest.mark.parametrize("search", SEARCHES)
def test_a_corridor_and_an_open_square(search: Search) -> None:
    moves, width = floor(["....."])
    np.testing.assert_array_equal(search(moves, width, 4, 0.5), np.array([2.0, 1.5, 1.0, 0.5, 0.0], dtype=np.float32))
    moves, width = floor(["...", "...", "..."])
    d = np.float32(0.35 * math.sqrt(2.0))
    expected = np.array([d, 0.35, d, 0.35, 0.0, 0.35, d, 0.35, d], dtype=np.float32)
    np.testing.assert_array_equal(search(moves, width, 4, 0.35), expected)


@pytest.mark.parametrize("search", SEARCHES)
def test_no_corner_cutting_and_thin_walls(search: Search) -> None:
    moves, width = floor([".#", ".."])  # (0, 0) to (1, 1) past the blocked (0, 1): two axis steps
    np.testing.assert_array_equal(search(moves, width, 0, 1.0), np.array([0.0, np.inf, 1.0, 2.0], dtype=np.float32))
    free = np.ones((2, 3), dtype=bool)
    walls = np.zeros((5, 7), dtype=bool)
    walls[1, 2] = True  # the midpoint between (0, 0) and (0, 1)
    got = search(moves_from(free, walls), 3, 0, 1.0)
    assert got[1] == np.float32(1.0 + math.sqrt(2.0))  # round the wall: an axis step and a diagonal


Walls = tuple[tuple[int, int], ...]


def drawn(rows: list[str], walls: Walls = ()) -> tuple[Moves, Moves]:
    """A grid drawn as text ('#' blocked) and thin walls at the given half-grid points (cell
    (r, c) at (2r + 1, 2c + 1)), as free cells and the half grid of walls."""
    free = np.array([[ch != "#" for ch in row] for row in rows])
    half = np.zeros((2 * free.shape[0] + 1, 2 * free.shape[1] + 1), dtype=bool)
    for point in walls:
        half[point] = True
    return free, half


def knight_floor(rows: list[str], walls: Walls = ()) -> tuple[Moves, int]:
    """A grid drawn as text, with thin walls, as its (cells, 16) moves and width."""
    free, half = drawn(rows, walls)
    width = free.shape[1]
    return with_knights(moves_from(free, half), width), width


KNIGHT_12 = ALL_MOVES.index((1, 2))  # from (0, 0) to (1, 2) on a 2 x 3 floor: cell 0 to cell 5
KNIGHT_BACK = ALL_MOVES.index((-1, -2))


@pytest.mark.parametrize(
    ("rows", "walls", "allowed"),
    [
        (["...", "..."], (), True),  # both ways: right then down-right, down-right then right
        (["..#", "..."], (), False),  # the first way cuts the corner of (0, 2)
        (["...", "#.."], (), False),  # the second way cuts the corner of (1, 0)
        (["...", "..."], ((1, 2),), False),  # a thin wall between (0, 0) and (0, 1): the first way
        (["...", "..."], ((3, 4),), False),  # between (1, 1) and (1, 2): the second way
        (["...", "..."], ((2, 2),), False),  # on the corner between (0, 0) and (1, 1): the second way
        (["...", "..."], ((2, 4),), False),  # on the corner between (0, 1) and (1, 2): the first way
        (["...", "..."], ((3, 2),), True),  # between (1, 0) and (1, 1): on neither way
        (["...", "..."], ((1, 4),), True),  # between (0, 1) and (0, 2): on neither way
    ],
)
def test_a_knights_move_needs_both_its_ways_through_the_eight(rows: list[str], walls: Walls, allowed: bool) -> None:
    moves, _ = knight_floor(rows, walls)
    assert moves[0, KNIGHT_12] == moves[5, KNIGHT_BACK] == allowed  # either way round
    np.testing.assert_array_equal(moves[:, :8], moves_from(*drawn(rows, walls)))  # the eight as they were


@pytest.mark.parametrize("knight", range(8, 16))
def test_a_knights_move_needs_every_other_cell_of_its_box(knight: int) -> None:
    """On an open 5 x 5 floor every knight's move from the centre is allowed; blocking any of
    the four other cells of the 2 x 3 box it crosses refuses it (a corner of one of its two
    ways), and blocking a cell outside the box does not."""
    dr, dc = ALL_MOVES[knight]
    centre = (2, 2)
    moves, _ = knight_floor(["....."] * 5)
    assert moves[12, 8:].all()
    box = {(2 + r, 2 + c) for r in range(min(0, dr), max(0, dr) + 1) for c in range(min(0, dc), max(0, dc) + 1)}
    assert len(box) == 6
    for cell in [(r, c) for r in range(5) for c in range(5) if (r, c) not in (centre, (2 + dr, 2 + dc))]:
        rows = ["".join("#" if (r, c) == cell else "." for c in range(5)) for r in range(5)]
        moves, _ = knight_floor(rows)
        assert moves[12, knight] == (cell not in box), cell


@pytest.mark.parametrize("search", SEARCHES)
def test_knights_moves_in_the_search(search: Search) -> None:
    moves, width = knight_floor(["...", "..."])
    got = search(moves, width, 5, 1.0)
    assert got[0] == np.float32(math.sqrt(5.0))  # one knight's move, not 1 + sqrt(2)
    moves, width = knight_floor(["..#", "..."])
    assert search(moves, width, 5, 1.0)[0] == np.float32(1.0 + math.sqrt(2.0))  # round the corner
    moves, width = knight_floor(["...", "..."], ((2, 2),))
    assert search(moves, width, 5, 1.0)[0] == np.float32(1.0 + math.sqrt(2.0))  # by the first way
    moves, width = knight_floor(["....", "....", "....", "...."])
    got = search(moves, width, 0, 0.5)
    assert got[2 * width + 3] == pytest.approx(0.5 * (math.sqrt(5.0) + math.sqrt(2.0)), rel=1e-6)  # knight, diagonal
    assert got[3 * width + 3] == pytest.approx(0.5 * 3.0 * math.sqrt(2.0), rel=1e-6)  # three diagonals
    assert got[3 * width + 1] == pytest.approx(0.5 * (math.sqrt(5.0) + 1.0), rel=1e-6)  # knight, a step down


@pytest.mark.parametrize("search", SEARCHES)
@settings(max_examples=40, derandomize=True, deadline=None)
@given(rows=st.integers(1, 45), cols=st.integers(1, 45), at=st.floats(0.0, 1.0), size=st.floats(0.01, 10.0))
def test_on_an_open_floor_the_field_is_near_the_straight_line(
    search: Search, rows: int, cols: int, at: float, size: float
) -> None:
    """Over the sixteen moves the field is within 3 % of the straight-line distance (at most
    1 / cos(atan(1/2) / 2) - 1 = 2.75 %, between an axis and a knight's move), over the eight
    within 8.3 % (at most sqrt(4 - 2 sqrt(2)) - 1 = 8.24 %); and never below it."""
    goal = min(int(at * rows * cols), rows * cols - 1)
    r, c = np.divmod(np.arange(rows * cols), cols)
    line = size * np.hypot(r - goal // cols, c - goal % cols)
    eight = moves_from(np.ones((rows, cols), dtype=bool))
    for moves, bound in ((eight, 1.083), (with_knights(eight, cols), 1.03)):
        got = search(moves, cols, goal, size).astype(np.float64)
        assert np.isfinite(got).all()
        assert (got >= line * (1.0 - 1e-6)).all()
        assert (got <= line * bound * (1.0 + 1e-6)).all()


def test_the_bounds_on_an_open_floor_are_tight() -> None:
    n = 60
    eight = moves_from(np.ones((n, n), dtype=bool))
    r, c = np.divmod(np.arange(1, n * n), n)
    line = np.hypot(r, c)
    ratio8 = dijkstra(eight, n, 0, 1.0)[1:] / line
    ratio16 = dijkstra(with_knights(eight, n), n, 0, 1.0)[1:] / line
    assert 1.08 < ratio8.max() <= 1.083 and 1.027 < ratio16.max() <= 1.03


def a_size_that_tells(root: float, other: float) -> float:
    """A cell size whose product with ``root`` rounds (float64, then float32) to another float32
    than its product with ``other``: a step computed with ``other`` would show in the field."""
    for m in range(1, 100):
        size = (1.0 + (2 * m + 1) * 2.0**-24) / root  # near a float32 midpoint
        for _ in range(8):
            if np.float32(size * root) != np.float32(size * other):
                return size
            size = math.nextafter(size, math.inf)
    raise AssertionError(f"no size tells {root!r} from {other!r}")


@pytest.mark.parametrize("n", [1, 2, 5])
def test_python_and_c_square_roots_are_the_same_correctly_rounded_doubles(n: int) -> None:
    root = math.sqrt(n)
    below, above = math.nextafter(root, 0.0), math.nextafter(root, math.inf)
    # correctly rounded: n lies between the squares of the midpoints to its neighbours, exactly
    lo, hi = (Fraction(below) + Fraction(root)) / 2, (Fraction(root) + Fraction(above)) / 2
    assert lo * lo < n < hi * hi
    assert root == math.sqrt(float(n)) == float(n) ** 0.5
    libm = ctypes.util.find_library("m")
    if libm is not None:  # C's sqrt itself (the compiled twin may inline the instruction: below)
        c_sqrt = ctypes.CDLL(libm).sqrt
        c_sqrt.restype, c_sqrt.argtypes = ctypes.c_double, [ctypes.c_double]
        assert c_sqrt(float(n)) == root


@pytest.mark.parametrize("search", SEARCHES)
@pytest.mark.parametrize(("n", "to"), [(1, 1), (2, 4), (5, 5)])  # (0, 0) to (0, 1), (1, 1), (1, 2)
def test_a_step_costs_size_times_the_square_root_exactly(search: Search, n: int, to: int) -> None:
    """A step's float64 cost is size * math.sqrt(dr^2 + dc^2) to the bit: for sizes where a
    square root one double off either way would give another float32."""
    moves, width = knight_floor(["...", "..."])
    root = math.sqrt(n)
    for other in (math.nextafter(root, 0.0), math.nextafter(root, math.inf)):
        size = a_size_that_tells(root, other)
        got = search(moves, width, 0, size)[to]
        assert got == np.float32(size * root) != np.float32(size * other)


@pytest.mark.parametrize("search", SEARCHES)
def test_a_blocked_goal_is_reached_from_nowhere(search: Search) -> None:
    moves, width = floor(["...", ".#.", "..."])
    got = search(moves, width, 4, 1.0)
    expected = np.full(9, np.inf, dtype=np.float32)
    expected[4] = 0.0
    np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("search", SEARCHES)
@pytest.mark.parametrize("goal", [-1, 9, 10**30, -(10**30)])
def test_a_goal_that_is_no_cell_gives_all_inf(search: Search, goal: int) -> None:
    moves, width = floor(["...", "...", "..."])
    got = search(moves, width, goal, 1.0)
    assert got.dtype == np.float32 and got.shape == (9,) and np.isposinf(got).all()


@pytest.mark.parametrize("search", SEARCHES)
def test_empty_grid_numpy_goal_and_a_writable_result(search: Search) -> None:
    assert search(np.zeros((0, 8), dtype=bool), 3, 0, 1.0).shape == (0,)
    assert search(np.zeros((0, 16), dtype=bool), 3, 0, 1.0).shape == (0,)
    moves, width = floor(["....", "...."])
    got = search(moves, width, np.int64(7), np.float32(0.25))  # type: ignore[arg-type]  # numpy scalars on purpose
    assert np.array_equal(got, dijkstra_python(moves, width, 7, 0.25))  # the steps in float64 all the same
    got[0] = 1.0  # the caller's to keep and change


def bad_moves() -> list[tuple[object, int, float, str]]:
    good = moves_from(np.ones((2, 3), dtype=bool))
    up = good.copy()
    up[1, 3] = True  # from row 0 upwards
    wrap = good.copy()
    wrap[2, 0] = True  # from the last column to the right: the next row's first cell, were it allowed
    left = good.copy()
    left[3, 6] = left[3, 2] = True  # from (1, 0): leftwards, and up-left
    # knight's moves on 4 rows of 5: from the second row and the second column too
    good16 = with_knights(moves_from(np.ones((4, 5), dtype=bool)), 5)
    knights = []
    for cell, knight in ((7, (-2, 1)), (13, (1, 2)), (11, (1, -2)), (17, (2, 1)), (1, (-1, -2)), (18, (-1, 2))):
        bad = good16.copy()
        bad[cell, ALL_MOVES.index(knight)] = True
        knights.append((bad, 5, 1.0, f"moves[{cell}, {ALL_MOVES.index(knight)}] steps off the grid (5 cells wide)"))
    two = good16.copy()
    two[11, 11] = two[11, 3] = True  # from (2, 1): a knight's move left and up-left (later), and up (first)
    return [
        (good.astype(np.uint8), 3, 1.0, "(cells, 8) or (cells, 16) bool array, not (6, 8) uint8 array"),
        (good[:, :7], 3, 1.0, "(cells, 8) or (cells, 16) bool array, not (6, 7) bool array"),
        (good.ravel(), 3, 1.0, "(cells, 8) or (cells, 16) bool array, not (48,) bool array"),
        (good.tolist(), 3, 1.0, "(cells, 8) or (cells, 16) bool array, not list"),
        (good16.astype(np.uint8), 5, 1.0, "(cells, 8) or (cells, 16) bool array, not (20, 16) uint8 array"),
        (np.zeros((6, 12), dtype=bool), 3, 1.0, "(cells, 8) or (cells, 16) bool array, not (6, 12) bool array"),
        (np.zeros((6, 16, 1), dtype=bool), 3, 1.0, "(cells, 8) or (cells, 16) bool array, not (6, 16, 1) bool"),
        (good16[:, ::-1], 5, 1.0, "moves must be C-contiguous"),
        (good16, 3, 1.0, "width 3 does not divide the 20 cells"),
        (np.asfortranarray(good), 3, 1.0, "moves must be C-contiguous"),
        (np.repeat(good, 2, axis=0)[::2], 3, 1.0, "moves must be C-contiguous"),
        (good, 0, 1.0, "width 0 does not divide the 6 cells into rows"),
        (good, -3, 1.0, "width -3 does not divide"),
        (good, 4, 1.0, "width 4 does not divide the 6 cells"),
        (good, 3, 0.0, "size must be finite and > 0, not 0.0"),
        (good, 3, -1.0, "size must be finite and > 0, not -1.0"),
        (good, 3, math.nan, "size must be finite and > 0, not nan"),
        (good, 3, math.inf, "size must be finite and > 0, not inf"),
        (up, 3, 1.0, "moves[1, 3] steps off the grid (3 cells wide)"),
        (wrap, 3, 1.0, "moves[2, 0] steps off the grid (3 cells wide)"),
        (left, 3, 1.0, "moves[3, 2] steps off the grid"),
        *knights,
        (two, 5, 1.0, "moves[11, 11] steps off the grid (5 cells wide)"),
    ]


@pytest.mark.parametrize("search", SEARCHES)
@pytest.mark.parametrize(("moves", "width", "size", "message"), bad_moves())
def test_bad_input_is_refused(search: Search, moves: Moves, width: int, size: float, message: str) -> None:
    with pytest.raises(ValueError, match=re.escape(message)):
        search(moves, width, 0, size)


@needs_cellpaths
def test_compiled_search_checks_its_buffer_itself() -> None:
    compiled = cells._native
    assert compiled is not None
    good = moves_from(np.ones((3, 4), dtype=bool))
    with pytest.raises(ValueError, match="bool buffer"):
        compiled.dijkstra(good.astype(np.uint8), 4, 0, 1.0)
    with pytest.raises(ValueError, match=re.escape("moves must be a (cells, 8) or (cells, 16) bool buffer")):
        compiled.dijkstra(good[:, :4].copy(), 4, 0, 1.0)
    with pytest.raises(ValueError, match="bool buffer"):
        compiled.dijkstra(np.zeros((12, 12), dtype=bool), 4, 0, 1.0)
    knights = with_knights(good, 4)
    with pytest.raises(ValueError, match="bool buffer"):
        compiled.dijkstra(knights.astype(np.uint8), 4, 0, 1.0)
    with pytest.raises(ValueError, match="C-contiguous"):
        compiled.dijkstra(np.asfortranarray(knights), 4, 0, 1.0)
    reached = np.frombuffer(compiled.dijkstra(knights, 4, 0, 1.0), dtype=np.float32)
    assert reached[6] == np.float32(math.sqrt(5.0))  # (1, 2): one knight's move
    off = knights.copy()
    off[5, ALL_MOVES.index((-2, 1))] = True  # from (1, 1), the second row: two rows up
    with pytest.raises(ValueError, match=re.escape("moves[5, 14] steps off the grid (4 cells wide)")):
        compiled.dijkstra(off, 4, 0, 1.0)
    with pytest.raises(ValueError, match="C-contiguous"):
        compiled.dijkstra(np.asfortranarray(good), 4, 0, 1.0)
    with pytest.raises(ValueError, match="width 5 does not divide"):
        compiled.dijkstra(good, 5, 0, 1.0)
    with pytest.raises(ValueError, match="size must be finite"):
        compiled.dijkstra(good, 4, 0, -0.0)
    assert np.isposinf(np.frombuffer(compiled.dijkstra(good, 4, 12, 1.0), dtype=np.float32)).all()


@needs_cellpaths
@pytest.mark.parametrize("knights", [False, True], ids=["8", "16"])
def test_both_name_the_same_move_off_the_grid(knights: bool) -> None:
    rng = np.random.default_rng(8)
    for _ in range(200):
        rows, cols = (int(v) for v in rng.integers(1, 8, 2))
        moves = moves_from(rng.random((rows, cols)) >= 0.2)
        if knights:
            moves = with_knights(moves, cols)
        moves |= rng.random(moves.shape) < rng.choice([0.002, 0.02, 0.1])  # some off the grid, or none
        messages = []
        for search in (dijkstra_python, dijkstra_native):
            try:
                search(moves, cols, 0, 1.0)
                messages.append("")
            except ValueError as exc:
                messages.append(str(exc))
        assert messages[0] == messages[1]


# --- the public name, the registry, the caller ----------------------------------------------------


@pytest.mark.parametrize("knights", [False, True], ids=["8", "16"])
def test_dijkstra_takes_the_compiled_twin_when_built(monkeypatch: pytest.MonkeyPatch, knights: bool) -> None:
    moves = moves_from(np.random.default_rng(2).random((20, 30)) >= 0.3)
    if knights:
        moves = with_knights(moves, 30)
    ref = dijkstra_python(moves, 30, 45, 0.35)
    calls: list[int] = []

    def counted(moves: Moves, width: int, goal: int, size: float) -> F32:
        calls.append(moves.shape[1])
        return dijkstra_native(moves, width, goal, size)

    monkeypatch.setattr(cells, "dijkstra_native", counted)
    assert np.array_equal(dijkstra(moves, 30, 45, 0.35), ref)
    assert calls == ([] if cells._native is None else [moves.shape[1]])  # compiled for 8 and 16 moves
    monkeypatch.setattr(cells, "_native", None)
    with pytest.raises(RuntimeError, match="compiled distance field is not available"):
        dijkstra_native(moves, 30, 45, 0.35)
    assert np.array_equal(dijkstra(moves, 30, 45, 0.35), ref)
    assert len(calls) <= 1


def test_the_distance_field_is_a_registered_kernel() -> None:
    kernel = native.KERNELS["cellpaths"]
    assert kernel.module == "simd.nav._cellpaths" and kernel.source == "simd/nav/_cellpaths.c"


def test_cell_graph_distances_treat_blocked_cells_as_walls() -> None:
    graph = CellGraph(load_world("turtlebot3_world"), cell_size_for(BURGER))
    moves = graph.moves(BURGER)
    standable = np.flatnonzero(graph.standable(BURGER))
    goal = int(standable[len(standable) // 2])
    free = graph.distances(BURGER, goal)
    assert np.array_equal(free, dijkstra_python(with_knights(moves, graph.width), graph.width, goal, graph.size))
    reached = np.flatnonzero(np.isfinite(free) & (free > 0))
    blocked = reached[:: max(1, len(reached) // 5)]
    walled = graph.distances(BURGER, goal, blocked)
    assert np.isposinf(walled[blocked]).all()
    assert (walled[np.isfinite(walled)] >= free[np.isfinite(walled)]).all()  # walls only lengthen ways
    kept = moves.copy()
    wall = set(blocked.tolist())
    for c in range(graph.count):  # no step out of a blocked cell, into one, nor past one's corner
        for k, (dr, dc) in enumerate(MOVES):
            if not kept[c, k]:
                continue
            touched = {c, c + dr * graph.width + dc}
            if dr and dc:
                touched |= {c + dc, c + dr * graph.width}
            if touched & wall:
                kept[c, k] = False
    kept16 = knights_from(kept, graph.width)  # and the knight's moves through what is left
    same_as_oracle(walled, bellman_ford(kept16, graph.width, goal, graph.size))


def flood_fill(stand: npt.NDArray[np.bool_], across: npt.NDArray[np.bool_], up: npt.NDArray[np.bool_],
               start: tuple[int, int]) -> int:  # fmt: skip
    """The cells connected to ``start`` by the axis steps, counted one by one (the reference)."""
    if not stand[start]:
        return 0
    h, w = stand.shape
    seen, todo = {start}, [start]
    while todo:
        r, c = todo.pop()
        for rr, cc, ok in ((r, c + 1, c + 1 < w and across[r, c]), (r, c - 1, c > 0 and across[r, c - 1]),
                           (r + 1, c, r + 1 < h and up[r, c]), (r - 1, c, r > 0 and up[r - 1, c])):  # fmt: skip
            if ok and (rr, cc) not in seen:
                seen.add((rr, cc))
                todo.append((rr, cc))
    return len(seen)


@settings(max_examples=200, derandomize=True, deadline=None)
@given(data=st.data())
def test_the_floor_connected_to_the_spawn_is_counted_as_a_flood_fill_counts_it(data: st.DataObject) -> None:
    """How an open world's cells are laid (``CellGraph(align=True)``) is chosen by the floor
    connected to its spawn, counted through a distance field: the same count as a flood fill."""
    h, w = data.draw(st.integers(1, 12)), data.draw(st.integers(1, 12))
    stand = np.array(data.draw(st.lists(st.booleans(), min_size=h * w, max_size=h * w)), dtype=bool).reshape(h, w)
    steps = [np.array(data.draw(st.lists(st.booleans(), min_size=h * w, max_size=h * w)), dtype=bool).reshape(h, w)
             for _ in range(2)]  # fmt: skip
    across, up = steps
    across[:, :-1] &= stand[:, :-1] & stand[:, 1:]  # a step joins two cells stood on, as _axis_steps makes them
    across[:, -1] = False
    up[:-1, :] &= stand[:-1, :] & stand[1:, :]
    up[-1, :] = False
    start = (data.draw(st.integers(0, h - 1)), data.draw(st.integers(0, w - 1)))
    assert cells._component(stand, across, up, start) == flood_fill(stand, across, up, start)
    assert cells._component(stand, across, up, None) == 0


@pytest.mark.parametrize("world", ["turtlebot3_world", "turtlebot3_house", "empty"])
def test_an_open_worlds_cells_are_laid_where_the_most_floor_joins_the_spawn(world: str) -> None:
    graph = CellGraph(load_world(world), 0.35, align=True)
    stand, across, up = cells._axis_steps(graph.world, graph.grid, cells.body_radius(BURGER))
    spawn = graph.grid.cell(*graph.world.default_spawn[:2])
    assert spawn is not None and cells._component(stand, across, up, spawn) == flood_fill(stand, across, up, spawn)
