"""Random costmaps for the navigation tests, and the plainest Dijkstra to check plans against.

A grid is drawn as its size, how much of it is blocked, what kind of costs it has and a seed
(numpy builds the cells from the seed: hypothesis shrinks the size and the fraction, and a
failing example stays reproducible from what it prints). Costs come in three kinds: uniform
floats in [1, 5], small integers (ties between paths of equal cost are common) and all ones
(ties everywhere), so that the tie-breaking of the two planners is exercised.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from hypothesis import strategies as st

from fleetcommon.arrays import F32

Cell = tuple[int, int]


@dataclass(frozen=True)
class Case:
    """A costmap and the two ends of a plan on it."""

    cost: F32
    start: Cell
    goal: Cell
    diagonal: bool


def make_grid(rows: int, cols: int, blocked: float, kind: str, seed: int) -> F32:
    rng = np.random.default_rng(seed)
    if kind == "uniform":
        cost = rng.uniform(1.0, 5.0, (rows, cols)).astype(np.float32)
    elif kind == "integer":
        cost = rng.integers(1, 4, (rows, cols)).astype(np.float32)
    else:
        cost = np.ones((rows, cols), dtype=np.float32)
    cost[rng.random((rows, cols)) < blocked] = np.inf
    return cost


@st.composite
def cases(draw: st.DrawFn, max_side: int = 40) -> Case:
    side = st.integers(1, 6) | st.integers(max_side // 2, max_side)  # the edge cases, and room for long paths
    rows, cols = draw(side), draw(side)
    blocked = draw(st.sampled_from([0.0, 0.1, 0.2, 0.3, 0.45]))
    kind = draw(st.sampled_from(["uniform", "integer", "ones"]))
    cost = make_grid(rows, cols, blocked, kind, draw(st.integers(0, 2**32 - 1)))
    near, far = (0.25, 0.75) if draw(st.booleans()) else (1.0, 0.0)  # half the time corner to corner
    start = (draw(st.integers(0, int((rows - 1) * near))), draw(st.integers(0, int((cols - 1) * near))))
    goal = (draw(st.integers(int((rows - 1) * far), rows - 1)), draw(st.integers(int((cols - 1) * far), cols - 1)))
    if draw(st.integers(0, 9)):  # mostly both ends free: blocked ends are a table test of their own
        for r, c in (start, goal):
            cost[r, c] = 1.0 if kind == "ones" else 2.0
    return Case(cost, start, goal, draw(st.booleans()))


def neighbour_steps(cost: F32, cell: Cell, diagonal: bool) -> list[tuple[Cell, float]]:
    """The moves out of ``cell`` with their costs, written out from the rules, not from the
    planner's tables: 4 orthogonal ones, and diagonals past two free cells only."""
    rows, cols = cost.shape
    r, c = cell

    def free(rr: int, cc: int) -> bool:
        return 0 <= rr < rows and 0 <= cc < cols and math.isfinite(float(cost[rr, cc]))

    out = []
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if (dr, dc) == (0, 0) or not free(r + dr, c + dc):
                continue
            if dr and dc and not (diagonal and free(r + dr, c) and free(r, c + dc)):
                continue
            length = math.sqrt(2.0) if dr and dc else 1.0
            out.append(((r + dr, c + dc), length * (float(cost[r, c]) + float(cost[r + dr, c + dc])) / 2.0))
    return out


def dijkstra(cost: F32, start: Cell, diagonal: bool) -> dict[Cell, float]:
    """The cost of the cheapest path from ``start`` to every cell it reaches (nothing when
    ``start`` is blocked)."""
    if not math.isfinite(float(cost[start])):
        return {}
    best = {start: 0.0}
    queue = [(0.0, start)]
    done: set[Cell] = set()
    while queue:
        d, cell = heapq.heappop(queue)
        if cell in done:
            continue
        done.add(cell)
        for nxt, step in neighbour_steps(cost, cell, diagonal):
            if d + step < best.get(nxt, math.inf):
                best[nxt] = d + step
                heapq.heappush(queue, (d + step, nxt))
    return best


def path_cost(cost: F32, path: npt.NDArray[np.int32]) -> float:
    """What a path costs under the planner's rule, summed in the order it is driven."""
    total = 0.0
    for (r0, c0), (r1, c1) in zip(path[:-1].tolist(), path[1:].tolist(), strict=True):
        length = math.sqrt(2.0) if r0 != r1 and c0 != c1 else 1.0
        total += length * (float(cost[r0, c0]) + float(cost[r1, c1])) / 2.0
    return total
