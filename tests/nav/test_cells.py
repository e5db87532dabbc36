"""simd/nav/cells.py's distance fields: the compiled Dijkstra (_cellpaths.c) returns the
Python reference's float32 array bit for bit, both agree with a Bellman-Ford relaxation
written out here, and the table cases and input checks."""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from simd.core import native
from simd.core.models import BURGER
from simd.core.worldfile import load_world
from simd.nav import cells
from simd.nav.cells import CellGraph, cell_size_for, dijkstra, dijkstra_native, dijkstra_python

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
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


def bellman_ford(moves: Moves, width: int, goal: int, size: float) -> F64:
    """The distances to ``goal`` by relaxing every move of every cell at once until nothing
    changes: d(c) = min over the moves k allowed from c of |k| * size + d(c + k)."""
    n = len(moves)
    if not 0 <= goal < n:
        return np.full(n, np.inf)
    rows = n // width
    dist = np.full((rows + 2, width + 2), np.inf)  # a border no move reaches
    dist[1 + goal // width, 1 + goal % width] = 0.0
    allowed = moves.reshape(rows, width, 8)
    while True:
        inner = dist[1:-1, 1:-1]
        best = inner.copy()
        for k, (dr, dc) in enumerate(MOVES):
            there = dist[1 + dr : 1 + dr + rows, 1 + dc : 1 + dc + width]
            best = np.minimum(best, np.where(allowed[:, :, k], there + math.hypot(dr, dc) * size, np.inf))
        if np.array_equal(best, inner):
            return best.ravel()
        dist[1:-1, 1:-1] = best


@dataclass(frozen=True)
class Graph:
    """A move graph and a search on it."""

    moves: Moves
    width: int
    goal: int
    size: float


@st.composite
def graphs(draw: st.DrawFn, max_side: int = 60) -> Graph:
    """Free cells drawn at random (numpy from a drawn seed), a share of the midpoints walls,
    a cell size, and a goal: mostly a free cell, sometimes a blocked one or no cell at all."""
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
    return Graph(moves_from(free, walls), cols, goal, size)


def same_as_oracle(found: F32, oracle: F64) -> None:
    assert found.dtype == np.float32
    np.testing.assert_array_equal(np.isinf(found), np.isinf(oracle))
    finite = np.isfinite(oracle)
    np.testing.assert_allclose(found[finite], oracle[finite], rtol=1e-6, atol=0.0)


# --- the two twins, and the oracle ----------------------------------------------------------------


@settings(max_examples=60, derandomize=True, deadline=None)
@given(graph=graphs())
def test_the_generated_moves_are_symmetric(graph: Graph) -> None:
    rows = len(graph.moves) // graph.width
    grid = graph.moves.reshape(rows, graph.width, 8)
    for k, (dr, dc) in enumerate(MOVES):
        back = MOVES.index((-dr, -dc))
        for r, c in np.argwhere(grid[:, :, k]).tolist():
            assert grid[r + dr, c + dc, back]


@needs_cellpaths
@settings(max_examples=300, derandomize=True, deadline=None)
@given(graph=graphs())
def test_compiled_and_python_return_the_same_array(graph: Graph) -> None:
    fast = dijkstra_native(graph.moves, graph.width, graph.goal, graph.size)
    ref = dijkstra_python(graph.moves, graph.width, graph.goal, graph.size)
    assert fast.dtype == ref.dtype == np.float32 and fast.shape == ref.shape == (len(graph.moves),)
    assert np.array_equal(fast, ref)  # inf where inf, every other value to the bit
    assert fast.tobytes() == ref.tobytes()


@pytest.mark.parametrize("search", SEARCHES)
@settings(max_examples=80, derandomize=True, deadline=None)
@given(graph=graphs())
def test_distances_are_those_of_bellman_ford(search: Search, graph: Graph) -> None:
    found = search(graph.moves, graph.width, graph.goal, graph.size)
    same_as_oracle(found, bellman_ford(graph.moves, graph.width, graph.goal, graph.size))


@needs_cellpaths
def test_compiled_and_python_agree_on_warehouse_sized_grids() -> None:
    """134 x 123 cells (a 1 000-robot warehouse), 30 % blocked and a few thin walls."""
    rng = np.random.default_rng(3)
    rows, cols = 123, 134
    for size in (0.35, 0.5, 1.0 / 3.0):
        free = rng.random((rows, cols)) >= 0.3
        walls = rng.random((2 * rows + 1, 2 * cols + 1)) < 0.03
        moves = moves_from(free, walls)
        for goal in rng.choice(np.flatnonzero(free), 4, replace=False).tolist():
            fast = dijkstra_native(moves, cols, goal, size)
            assert np.array_equal(fast, dijkstra_python(moves, cols, goal, size))
            assert np.isfinite(fast).sum() > rows * cols // 2  # most of the floor is reached
    same_as_oracle(fast, bellman_ford(moves, cols, goal, size))


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
    return [
        (good.astype(np.uint8), 3, 1.0, "(cells, 8) bool array, not (6, 8) uint8 array"),
        (good[:, :7], 3, 1.0, "(cells, 8) bool array, not (6, 7) bool array"),
        (good.ravel(), 3, 1.0, "(cells, 8) bool array, not (48,) bool array"),
        (good.tolist(), 3, 1.0, "(cells, 8) bool array, not list"),
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
    with pytest.raises(ValueError, match="bool buffer"):
        compiled.dijkstra(good[:, :4].copy(), 4, 0, 1.0)
    with pytest.raises(ValueError, match="C-contiguous"):
        compiled.dijkstra(np.asfortranarray(good), 4, 0, 1.0)
    with pytest.raises(ValueError, match="width 5 does not divide"):
        compiled.dijkstra(good, 5, 0, 1.0)
    with pytest.raises(ValueError, match="size must be finite"):
        compiled.dijkstra(good, 4, 0, -0.0)
    assert np.isposinf(np.frombuffer(compiled.dijkstra(good, 4, 12, 1.0), dtype=np.float32)).all()


@needs_cellpaths
def test_both_name_the_same_move_off_the_grid() -> None:
    rng = np.random.default_rng(8)
    for _ in range(40):
        rows, cols = (int(v) for v in rng.integers(1, 6, 2))
        moves = moves_from(rng.random((rows, cols)) >= 0.2)
        moves |= rng.random(moves.shape) < 0.1  # some of them off the grid, most likely
        messages = []
        for search in (dijkstra_python, dijkstra_native):
            try:
                search(moves, cols, 0, 1.0)
                messages.append("")
            except ValueError as exc:
                messages.append(str(exc))
        assert messages[0] == messages[1]


# --- the public name, the registry, the caller ----------------------------------------------------


def test_dijkstra_takes_the_compiled_twin_when_built(monkeypatch: pytest.MonkeyPatch) -> None:
    moves = moves_from(np.random.default_rng(2).random((20, 30)) >= 0.3)
    ref = dijkstra_python(moves, 30, 45, 0.35)
    assert np.array_equal(dijkstra(moves, 30, 45, 0.35), ref)
    monkeypatch.setattr(cells, "_native", None)
    with pytest.raises(RuntimeError, match="compiled distance field is not available"):
        dijkstra_native(moves, 30, 45, 0.35)
    assert np.array_equal(dijkstra(moves, 30, 45, 0.35), ref)


def test_the_distance_field_is_a_registered_kernel() -> None:
    kernel = native.KERNELS["cellpaths"]
    assert kernel.module == "simd.nav._cellpaths" and kernel.source == "simd/nav/_cellpaths.c"


def test_cell_graph_distances_treat_blocked_cells_as_walls() -> None:
    graph = CellGraph(load_world("turtlebot3_world"), cell_size_for(BURGER))
    moves = graph.moves(BURGER)
    standable = np.flatnonzero(graph.standable(BURGER))
    goal = int(standable[len(standable) // 2])
    free = graph.distances(BURGER, goal)
    assert np.array_equal(free, dijkstra_python(moves, graph.width, goal, graph.size))
    reached = np.flatnonzero(np.isfinite(free) & (free > 0))
    blocked = reached[:: max(1, len(reached) // 5)]
    walled = graph.distances(BURGER, goal, blocked)
    assert np.isposinf(walled[blocked]).all()
    assert (walled[np.isfinite(walled)] >= free[np.isfinite(walled)]).all()  # walls only lengthen ways
    kept = moves.reshape(graph.height, graph.width, 8).copy()
    grid_free = np.ones(graph.count, dtype=bool)
    grid_free[blocked] = False
    for k, (dr, dc) in enumerate(MOVES):  # no move out of a blocked cell, nor into one
        shifted = np.zeros((graph.height + 2, graph.width + 2), dtype=bool)
        shifted[1:-1, 1:-1] = grid_free.reshape(graph.height, graph.width)
        into = shifted[1 + dr : 1 + dr + graph.height, 1 + dc : 1 + dc + graph.width]
        kept[:, :, k] &= grid_free.reshape(graph.height, graph.width) & into
    same_as_oracle(walled, bellman_ford(kept.reshape(-1, 8), graph.width, goal, graph.size))
