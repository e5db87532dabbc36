"""simd/nav/grid_search.py: the A* (both twins) against a plain Dijkstra and the flood fill,
the very same path from the compiled and the Python search, and the table cases."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given, settings

from simd.core import native
from simd.nav import grid_search
from simd.nav.grid_search import plan, plan_native, plan_python, reachable
from tests.nav.grids import Case, cases, dijkstra, make_grid, neighbour_steps, path_cost

F32 = npt.NDArray[np.float32]
I32 = npt.NDArray[np.int32]
Planner = Callable[..., I32 | None]

needs_astar = pytest.mark.skipif(
    grid_search._native is None, reason=f"simd.nav._astar is not built: {grid_search.NATIVE_UNAVAILABLE}"
)
PLANNERS = [
    pytest.param(plan_python, id="python"),
    pytest.param(plan_native, id="native", marks=needs_astar),
]
INF = np.inf


def grid(rows: list[str]) -> F32:
    """A grid drawn as text: '#' blocked, a digit its cost, '.' cost 1."""
    table = {"#": INF, ".": 1.0}
    return np.array([[table.get(ch, float(ch) if ch.isdigit() else 0.0) for ch in row] for row in rows], np.float32)


def check_moves(case: Case, path: I32) -> None:
    """Start and goal right, every step a legal move between traversable cells."""
    assert path.dtype == np.int32 and path.ndim == 2 and path.shape[1] == 2
    assert tuple(path[0]) == case.start and tuple(path[-1]) == case.goal
    assert all(math.isfinite(float(case.cost[r, c])) for r, c in path.tolist())
    for a, b in zip(path[:-1].tolist(), path[1:].tolist(), strict=True):
        assert tuple(b) in [cell for cell, _ in neighbour_steps(case.cost, (a[0], a[1]), case.diagonal)]


@settings(max_examples=150, derandomize=True, deadline=None)
@given(case=cases())
def test_a_path_exactly_when_reachable_and_as_cheap_as_dijkstra(case: Case) -> None:
    path = plan_python(case.cost, case.start, case.goal, diagonal=case.diagonal)
    connected = bool(reachable(np.isfinite(case.cost), case.start, diagonal=case.diagonal)[case.goal])
    assert (path is not None) == connected
    best = dijkstra(case.cost, case.start, case.diagonal)
    assert (case.goal in best) == connected
    if path is not None:
        check_moves(case, path)
        assert path_cost(case.cost, path) == pytest.approx(best[case.goal], rel=1e-9, abs=0.0)


@needs_astar
@settings(max_examples=300, derandomize=True, deadline=None)
@given(case=cases())
def test_compiled_and_python_return_the_same_path(case: Case) -> None:
    fast = plan_native(case.cost, case.start, case.goal, diagonal=case.diagonal)
    ref = plan_python(case.cost, case.start, case.goal, diagonal=case.diagonal)
    assert (fast is None) == (ref is None)
    if fast is not None and ref is not None:
        assert fast.dtype == ref.dtype == np.int32
        np.testing.assert_array_equal(fast, ref)


@needs_astar
def test_compiled_and_python_agree_on_bigger_grids_full_of_ties() -> None:
    """All-ones and two-level grids of 120x150: many equal-cost paths, one answer."""
    rng = np.random.default_rng(11)
    for kind in ("ones", "integer", "uniform"):
        cost = make_grid(120, 150, 0.25, kind, int(rng.integers(2**32)))
        free = np.argwhere(np.isfinite(cost)).tolist()
        for _ in range(4):
            (sr, sc), (gr, gc) = free[rng.integers(len(free))], free[rng.integers(len(free))]
            for diagonal in (True, False):
                fast = plan_native(cost, (sr, sc), (gr, gc), diagonal=diagonal)
                ref = plan_python(cost, (sr, sc), (gr, gc), diagonal=diagonal)
                assert (fast is None) == (ref is None)
                if fast is not None and ref is not None:
                    np.testing.assert_array_equal(fast, ref)


@settings(max_examples=100, derandomize=True, deadline=None)
@given(case=cases(max_side=25))
def test_reachable_is_where_dijkstra_gets(case: Case) -> None:
    mask = reachable(np.isfinite(case.cost), case.start, diagonal=case.diagonal)
    expected = np.zeros(case.cost.shape, dtype=bool)
    for cell in dijkstra(case.cost, case.start, case.diagonal):
        expected[cell] = True
    np.testing.assert_array_equal(mask, expected)


# --- table cases --------------------------------------------------------------------------------


@pytest.mark.parametrize("planner", PLANNERS)
def test_start_is_goal(planner: Planner) -> None:
    path = planner(grid(["...", ".2.", "..."]), (1, 1), (1, 1))
    assert path is not None
    np.testing.assert_array_equal(path, [[1, 1]])
    assert path.dtype == np.int32


@pytest.mark.parametrize("planner", PLANNERS)
@pytest.mark.parametrize(("start", "goal"), [((0, 0), (2, 2)), ((2, 2), (0, 0)), ((0, 0), (0, 0))])
def test_blocked_start_or_goal(planner: Planner, start: tuple[int, int], goal: tuple[int, int]) -> None:
    assert planner(grid(["#..", "...", "..#"]), start, goal) is None


@pytest.mark.parametrize("planner", PLANNERS)
def test_a_corridor(planner: Planner) -> None:
    cost = grid(
        [
            "#######",
            "......#",
            "#####.#",
            "#.....#",
            "#.#####",
            "#......",
        ]
    )
    path = planner(cost, (1, 0), (5, 6))
    assert path is not None
    expected = [(1, c) for c in range(6)] + [(2, 5)] + [(3, c) for c in range(5, 0, -1)]
    expected += [(4, 1)] + [(5, c) for c in range(1, 7)]
    assert [tuple(p) for p in path.tolist()] == expected


@pytest.mark.parametrize("planner", PLANNERS)
def test_no_corner_cutting(planner: Planner) -> None:
    assert planner(grid([".#", "#."]), (0, 0), (1, 1)) is None  # two blocked cells meet at the corner
    one_side = planner(grid([".#", ".."]), (0, 0), (1, 1))  # one blocked cell beside the diagonal is enough
    assert one_side is not None and [tuple(p) for p in one_side.tolist()] == [(0, 0), (1, 0), (1, 1)]
    path = planner(grid([".#.", "..#", "..."]), (0, 0), (2, 2))  # the one diagonal with both sides free
    assert path is not None and [tuple(p) for p in path.tolist()] == [(0, 0), (1, 0), (2, 1), (2, 2)]


@pytest.mark.parametrize("planner", PLANNERS)
def test_diagonal_false_moves_orthogonally(planner: Planner) -> None:
    cost = np.ones((6, 9), dtype=np.float32)
    path = planner(cost, (0, 0), (5, 8), diagonal=False)
    assert path is not None and len(path) == 5 + 8 + 1
    assert (np.abs(np.diff(path, axis=0)).sum(axis=1) == 1).all()
    diagonal = planner(cost, (0, 0), (5, 8))
    assert diagonal is not None and len(diagonal) == 8 + 1  # 5 diagonal steps, 3 straight
    assert path_cost(cost, diagonal) == pytest.approx(3 + 5 * math.sqrt(2.0), rel=1e-12)


@pytest.mark.parametrize("planner", PLANNERS)
def test_costs_steer_the_path(planner: Planner) -> None:
    cost = grid(
        [
            ".....",
            ".999.",
            ".....",
        ]
    )
    path = planner(cost, (1, 0), (1, 4), diagonal=False)
    assert path is not None and path_cost(cost, path) == 6.0  # around the costly row (6), not through it (20)
    assert all(cost[r, c] == 1.0 for r, c in path.tolist())


@pytest.mark.parametrize("planner", PLANNERS)
def test_no_path(planner: Planner) -> None:
    assert planner(grid(["..#..", "..#..", "..#.."]), (0, 0), (2, 4)) is None


@pytest.mark.parametrize("planner", PLANNERS)
@pytest.mark.parametrize(
    ("cost", "start", "goal", "message"),
    [
        (np.ones((3, 3)), (0, 0), (1, 1), "2-D float32 array, not 2-D float64"),
        (np.ones((3, 3, 1), np.float32), (0, 0), (1, 1), "not 3-D float32"),
        ([[1.0, 1.0]], (0, 0), (0, 1), "not list"),
        (np.array([[1.0, np.nan]], np.float32), (0, 0), (0, 1), "NaN"),
        (np.array([[1.0, 0.5]], np.float32), (0, 0), (0, 1), "cost holds 0.5"),
        (np.array([[1.0, -np.inf]], np.float32), (0, 0), (0, 1), "cost holds -inf"),
        (np.ones((3, 4), np.float32), (3, 0), (1, 1), "start (3, 0) lies outside the 3x4 grid"),
        (np.ones((3, 4), np.float32), (-1, 0), (1, 1), "start (-1, 0) lies outside"),
        (np.ones((3, 4), np.float32), (0, 0), (0, 4), "goal (0, 4) lies outside"),
        (np.ones((0, 4), np.float32), (0, 0), (0, 0), "outside the 0x4 grid"),
    ],
)
def test_bad_input_is_refused(planner: Planner, cost: object, start: object, goal: object, message: str) -> None:
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        planner(cost, start, goal)


@pytest.mark.parametrize("planner", PLANNERS)
def test_a_strided_grid_is_taken_as_a_copy(planner: Planner) -> None:
    cost = np.ones((8, 8), dtype=np.float32)
    cost[2:, 2] = INF  # a wall with a gap in the first row
    view = cost[::2, :]
    path = planner(view, (3, 0), (3, 7))
    assert path is not None and path[:, 0].min() == 0  # through the gap
    np.testing.assert_array_equal(path, planner(np.ascontiguousarray(view), (3, 0), (3, 7)))


def test_plan_takes_the_compiled_twin_when_built(monkeypatch: pytest.MonkeyPatch) -> None:
    cost = make_grid(30, 30, 0.2, "integer", 5)
    cost[0, 0] = cost[29, 29] = 1.0
    monkeypatch.setattr(grid_search, "_native", None)
    with pytest.raises(RuntimeError, match="compiled planner is not available"):
        plan_native(cost, (0, 0), (29, 29))
    fallback = plan(cost, (0, 0), (29, 29))
    ref = plan_python(cost, (0, 0), (29, 29))
    assert (fallback is None and ref is None) or np.array_equal(fallback, ref)  # type: ignore[arg-type]


def test_the_planner_is_a_registered_kernel() -> None:
    kernel = native.KERNELS["astar"]
    assert kernel.module == "simd.nav._astar" and kernel.source == "simd/nav/_astar.c"


@needs_astar
def test_compiled_planner_checks_its_buffer() -> None:
    compiled = grid_search._native
    assert compiled is not None
    with pytest.raises(TypeError, match="float32"):
        compiled.plan(np.ones((3, 3)), 0, 0, 1, 1, True)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="C-contiguous"):
        compiled.plan(np.ones((4, 4), np.float32)[:, ::2], 0, 0, 1, 1, True)
    with pytest.raises(ValueError, match="inside the grid"):
        compiled.plan(np.ones((3, 3), np.float32), 0, 0, 3, 1, True)


@pytest.mark.parametrize("diagonal", [True, False])
def test_reachable_tables(diagonal: bool) -> None:
    free = np.array([[1, 0, 1], [0, 1, 0], [1, 0, 1]], dtype=bool)  # a checkerboard: corners only
    only = np.zeros_like(free)
    only[1, 1] = True
    np.testing.assert_array_equal(reachable(free, (1, 1), diagonal=diagonal), only)  # no corner cutting
    assert not reachable(free, (0, 1), diagonal=diagonal).any()  # a blocked start reaches nothing
    ring = np.ones((4, 4), dtype=bool)
    ring[1:3, 1:3] = False
    np.testing.assert_array_equal(reachable(ring, (0, 0), diagonal=diagonal), ring)
    with pytest.raises(ValueError, match="bool"):
        reachable(ring.astype(np.uint8), (0, 0))
    with pytest.raises(ValueError, match="outside"):
        reachable(ring, (4, 0))
