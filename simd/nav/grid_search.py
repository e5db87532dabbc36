"""Cheapest paths on a grid costmap (A*), and which cells a robot can reach at all.

The grid: ``cost[row, col]`` is float32, finite and >= 1 where a robot may be, ``np.inf``
where it may not. A robot moves to its 4 orthogonal neighbours and, with ``diagonal``, to
the 4 diagonal ones, but only when both orthogonal cells the diagonal passes are traversable
(no cutting a blocked corner). A step from a to b costs its length (1 or sqrt 2) times the
mean of the two cells' costs, so a path costs the same read in either direction and a cost of
1 everywhere gives geometric length.

``plan`` runs the compiled twin, simd/nav/_astar.c (label ``"astar"`` in
simd/core/native.py), when it is built, else ``plan_python`` here, which stays the reference:
both make the same float64 operations in the same order and order the open list by (f, h,
push counter), so they return the very same path, not just one of equal cost (tested).
The heuristic is the octile distance (Manhattan without diagonals) at a cost of 1 a cell: never
more than the true cost, since no cell costs less, so the path is optimal.

Speed (``python -m bench.plan_bench``: a 400x400 grid, 20 % of its cells blocked at random,
costs uniform in [1, 5], 50 random start/goal pairs joined by a path, median 203 cells long;
on the 2-core development VM (AMD EPYC), shared with other work): a plan takes 2.7 ms compiled
(median; 8.3 ms the longest) and 53 ms in Python (172 ms), 20x. The heuristic at cost 1 is weak
on costs that average 3, so a far goal has A* expand most of the grid: ~75 ns a cell in C, most
of it in the open list, which is a 4-ary heap of 16-byte entries picking the least child
without branches (h is worked out again only on ties in f). heapq, being C too, keeps the
Python search within 20x.

``reachable`` is a flood fill under the same move rules written apart from the search (a
breadth-first front in numpy), so that tests can use it as the oracle of whether a path exists,
and callers to draw goals a robot can reach. ``smooth`` (simd/nav/line_of_sight.py) shortens a
planned path to the points a robot must turn at.
"""

from __future__ import annotations

import heapq
import math
import operator
from typing import Protocol, cast

import numpy as np
import numpy.typing as npt

from simd.core import native
from simd.nav.line_of_sight import smooth

__all__ = ["plan", "plan_native", "plan_python", "reachable", "smooth"]

F32 = npt.NDArray[np.float32]
I32 = npt.NDArray[np.int32]
Mask = npt.NDArray[np.bool_]

#: the double nearest sqrt(2), spelled as _astar.c spells it
SQRT2 = 1.4142135623730951
# (row step, col step, length): the order neighbours are tried in, the same in _astar.c
MOVES = ((-1, 0, 1.0), (1, 0, 1.0), (0, -1, 1.0), (0, 1, 1.0))
DIAGONAL_MOVES = ((-1, -1, SQRT2), (-1, 1, SQRT2), (1, -1, SQRT2), (1, 1, SQRT2))


class _CompiledPlanner(Protocol):
    """simd.nav._astar (simd/nav/_astar.c): the path as int32 (row, col) pairs, or None."""

    def plan(
        self, cost: F32, start_row: int, start_col: int, goal_row: int, goal_col: int, diagonal: bool, /
    ) -> bytearray | None: ...


_module, NATIVE_UNAVAILABLE = native.load("astar")
_native = cast("_CompiledPlanner | None", _module)


def plan(cost: F32, start: tuple[int, int], goal: tuple[int, int], *, diagonal: bool = True) -> I32 | None:
    """The cheapest path from ``start`` to ``goal`` as (k, 2) int32 (row, col) rows, start first
    and goal last (one row when they are the same cell), or None when the goal cannot be
    reached or either end is blocked. ValueError for a grid that is not 2-D float32, holds NaN
    or values below 1, or an end outside it. The compiled search runs without the GIL, reading
    ``cost`` in place: no other thread may write it meanwhile."""
    return (plan_native if _native is not None else plan_python)(cost, start, goal, diagonal=diagonal)


def plan_native(cost: F32, start: tuple[int, int], goal: tuple[int, int], *, diagonal: bool = True) -> I32 | None:
    """``plan`` in the compiled twin (RuntimeError when it is not built)."""
    if _native is None:
        raise RuntimeError(f"the compiled planner is not available: {NATIVE_UNAVAILABLE}")
    grid = checked_costs(cost)
    (sr, sc), (gr, gc) = cell("start", start, grid.shape), cell("goal", goal, grid.shape)
    found = _native.plan(grid, sr, sc, gr, gc, diagonal)
    return None if found is None else np.frombuffer(found, dtype=np.int32).reshape(-1, 2)


def plan_python(cost: F32, start: tuple[int, int], goal: tuple[int, int], *, diagonal: bool = True) -> I32 | None:
    """``plan`` in Python: the reference of the compiled twin."""
    grid = checked_costs(cost)
    rows, cols = grid.shape
    (sr, sc), (gr, gc) = cell("start", start, grid.shape), cell("goal", goal, grid.shape)
    # a border of blocked cells all round: no bounds checks, and indices as in _astar.c
    width: int = cols + 2
    padded = np.full((rows + 2, width), np.inf)
    padded[1:-1, 1:-1] = grid
    costs: list[float] = padded.ravel().tolist()
    inf = math.inf
    moves = [(dr * width + dc, length, dr * width, dc) for dr, dc, length in MOVES + DIAGONAL_MOVES[: 4 * diagonal]]
    start_i, goal_i = (sr + 1) * width + sc + 1, (gr + 1) * width + gc + 1
    if costs[start_i] == inf or costs[goal_i] == inf:
        return None
    goal_r, goal_c = gr + 1, gc + 1

    def heuristic(node: int) -> float:
        r, c = divmod(node, width)
        dr, dc = abs(r - goal_r), abs(c - goal_c)
        if not diagonal:
            return float(dr + dc)
        lo, hi = min(dr, dc), max(dr, dc)
        return float(hi - lo) + SQRT2 * lo

    g = [inf] * len(costs)
    parent = [-1] * len(costs)
    closed = bytearray(len(costs))
    h0 = heuristic(start_i)
    g[start_i] = 0.0
    open_list: list[tuple[float, float, int, int]] = [(0.0 + h0, h0, 0, start_i)]
    pushes = 1
    while open_list:
        a = heapq.heappop(open_list)[3]
        if closed[a]:
            continue  # a stale entry: the node was reached cheaper since
        if a == goal_i:
            break
        closed[a] = 1
        ga, ca = g[a], costs[a]
        for offset, length, via_row, via_col in moves:
            b = a + offset
            cb = costs[b]
            if cb == inf or closed[b]:
                continue
            if via_col and via_row and (costs[a + via_row] == inf or costs[a + via_col] == inf):
                continue  # a diagonal past a blocked corner
            gb = ga + length * (ca + cb) / 2.0
            if gb < g[b]:
                g[b] = gb
                parent[b] = a
                hb = heuristic(b)
                heapq.heappush(open_list, (gb + hb, hb, pushes, b))
                pushes += 1
    else:
        return None
    path = [goal_i]
    while path[-1] != start_i:
        path.append(parent[path[-1]])
    flat = np.array(path[::-1], dtype=np.int64)
    return np.stack([flat // width - 1, flat % width - 1], axis=1).astype(np.int32)


def reachable(traversable: Mask, start: tuple[int, int], *, diagonal: bool = True) -> Mask:
    """The cells a robot at ``start`` can reach under ``plan``'s move rules (start included),
    as a mask of ``traversable``'s shape; all False when ``start`` itself is blocked."""
    grid = checked_mask(traversable)
    rows, cols = grid.shape
    r, c = cell("start", start, grid.shape)
    width: int = cols + 2
    padded = np.zeros((rows + 2, width), dtype=bool)
    padded[1:-1, 1:-1] = grid
    free = padded.ravel()
    seen = np.zeros_like(free)
    first = (r + 1) * width + c + 1
    front = np.array([first] if free[first] else [], dtype=np.intp)
    seen[front] = True
    while front.size:  # one breadth-first layer a turn
        found = [front + step for step in (-width, width, -1, 1)]
        if diagonal:
            for dr, dc, _ in DIAGONAL_MOVES:
                past_corner = front[free[front + dr * width] & free[front + dc]]
                found.append(past_corner + dr * width + dc)
        near = np.concatenate(found)
        near = np.unique(near[free[near] & ~seen[near]])
        seen[near] = True
        front = near
    reached: Mask = seen.reshape(rows + 2, width)[1:-1, 1:-1].copy()
    return reached


def checked_costs(cost: F32) -> F32:
    """``cost`` as a C-contiguous float32 grid (copied only when not contiguous), or
    ValueError saying what is wrong with it."""
    if not isinstance(cost, np.ndarray) or cost.dtype != np.float32 or cost.ndim != 2:
        what = f"{cost.ndim}-D {cost.dtype}" if isinstance(cost, np.ndarray) else type(cost).__name__
        raise ValueError(f"cost must be a 2-D float32 array, not {what}")
    if not (cost >= 1.0).all():  # NaN compares False too
        if np.isnan(cost).any():
            raise ValueError("cost holds NaN: a blocked cell is np.inf")
        raise ValueError(f"cost holds {cost.min()}: a traversable cell costs at least 1, a blocked one np.inf")
    return np.ascontiguousarray(cost)


def checked_mask(traversable: Mask) -> Mask:
    """``traversable`` if it is a 2-D bool array, else ValueError."""
    if not isinstance(traversable, np.ndarray) or traversable.dtype != np.bool_ or traversable.ndim != 2:
        raise ValueError("traversable must be a 2-D bool array")
    return traversable


def cell(name: str, where: tuple[int, int], shape: tuple[int, ...]) -> tuple[int, int]:
    """(row, col) of ``where`` as ints, or ValueError when it lies outside a grid of ``shape``."""
    r, c = (operator.index(v) for v in where)
    if not (0 <= r < shape[0] and 0 <= c < shape[1]):
        raise ValueError(f"{name} {(r, c)} lies outside the {shape[0]}x{shape[1]} grid")
    return r, c
