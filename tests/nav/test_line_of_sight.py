"""simd/nav/line_of_sight.py: the supercover cells against exact geometry, and smoothed paths
that only ever join points in sight of each other."""

from __future__ import annotations

import itertools
from fractions import Fraction

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from simd.nav.grid_search import plan_python, smooth
from simd.nav.line_of_sight import FAR, segment_cells, visible
from tests.nav.grids import Case, cases

Cell = tuple[int, int]
Mask = npt.NDArray[np.bool_]
HALF = Fraction(1, 2)


def touches(a: Cell, b: Cell, cell: Cell) -> bool:
    """Whether the segment between the centres of a and b meets the closed square of ``cell``:
    the parameters t in [0, 1] inside the cell's row band and its column band, in fractions."""
    lo, hi = Fraction(0), Fraction(1)
    for p0, p1, k in ((a[0], b[0], cell[0]), (a[1], b[1], cell[1])):
        if p0 == p1:
            if abs(p0 - k) > HALF:
                return False
            continue
        t1, t2 = (k - HALF - p0) / Fraction(p1 - p0), (k + HALF - p0) / Fraction(p1 - p0)
        lo, hi = max(lo, min(t1, t2)), min(hi, max(t1, t2))
    return lo <= hi


def touched(a: Cell, b: Cell) -> set[Cell]:
    """Every cell the segment touches: the cells near its line (a loose float filter) checked
    exactly."""
    (r0, c0), (r1, c1) = a, b
    rows, cols = np.mgrid[min(r0, r1) - 1 : max(r0, r1) + 2, min(c0, c1) - 1 : max(c0, c1) + 2]
    length = max(np.hypot(r1 - r0, c1 - c0), 1e-9)
    near = np.abs((rows - r0) * (c1 - c0) - (cols - c0) * (r1 - r0)) / length <= 0.75  # sqrt(2)/2 and a margin
    return {(int(r), int(c)) for r, c in zip(rows[near], cols[near], strict=True) if touches(a, b, (int(r), int(c)))}


def in_sight(free: Mask, a: Cell, b: Cell) -> bool:
    return all(free[cell] for cell in touched(a, b))


offset = st.integers(-15, 15)


@settings(max_examples=200, derandomize=True, deadline=None)
@given(origin=st.tuples(st.integers(-5, 5), st.integers(-5, 5)), moves=st.lists(st.tuples(offset, offset), max_size=6))
def test_segment_cells_are_the_supercover(origin: Cell, moves: list[Cell]) -> None:
    targets = np.array([(origin[0] + dr, origin[1] + dc) for dr, dc in moves], dtype=np.int64).reshape(-1, 2)
    seg, rows, cols = segment_cells(origin, targets)
    for k, (r, c) in enumerate(targets.tolist()):
        mine = list(zip(rows[seg == k].tolist(), cols[seg == k].tolist(), strict=True))
        assert len(mine) == len(set(mine))  # each cell once
        assert set(mine) == touched(origin, (r, c))


@pytest.mark.parametrize(
    ("target", "expected"),
    [
        ((0, 0), {(0, 0)}),
        ((0, 3), {(0, 0), (0, 1), (0, 2), (0, 3)}),
        ((2, 2), {(0, 0), (0, 1), (1, 0), (1, 1), (1, 2), (2, 1), (2, 2)}),  # both cells at each corner
        ((1, 2), {(0, 0), (0, 1), (1, 1), (1, 2)}),  # through the middle of a cell border
        ((-1, 3), {(0, 0), (0, 1), (0, 2), (-1, 1), (-1, 2), (-1, 3)}),  # a corner halfway: all four cells
    ],
)
def test_segment_cells_table(target: Cell, expected: set[Cell]) -> None:
    _, rows, cols = segment_cells((0, 0), np.array([target], dtype=np.int64))
    assert set(zip(rows.tolist(), cols.tolist(), strict=True)) == expected


@settings(max_examples=100, derandomize=True, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), blocked=st.sampled_from([0.05, 0.2, 0.4]))
def test_visible_matches_exact_geometry(seed: int, blocked: float) -> None:
    rng = np.random.default_rng(seed)
    free = rng.random((20, 20)) >= blocked
    origin = (int(rng.integers(20)), int(rng.integers(20)))
    targets = rng.integers(0, 20, (12, 2))
    got = visible(free, origin, targets)
    assert got.tolist() == [in_sight(free, origin, (int(r), int(c))) for r, c in targets]


def check_smoothed(free: Mask, path: npt.NDArray[np.int32], kept: npt.NDArray[np.int32]) -> None:
    """Start and goal kept, kept points in path order, each in sight of the one before, and
    the path point after each kept one (but the last) hidden from the one kept before it."""
    assert kept.dtype == np.int32 and kept.shape[1] == 2
    np.testing.assert_array_equal(kept[0], path[0])
    np.testing.assert_array_equal(kept[-1], path[-1])
    index = {tuple(p): i for i, p in enumerate(path.tolist())}  # plan never visits a cell twice
    at = [index[tuple(p)] for p in kept.tolist()]
    assert at == sorted(set(at))
    cells = [(int(r), int(c)) for r, c in path.tolist()]
    for a, b in itertools.pairwise(at):
        assert in_sight(free, cells[a], cells[b])  # never through a blocked cell
        if b < len(cells) - 1:
            assert not in_sight(free, cells[a], cells[b + 1])  # as far as it goes


@settings(max_examples=120, derandomize=True, deadline=None)
@given(case=cases())
def test_smoothed_paths_stay_in_sight(case: Case) -> None:
    path = plan_python(case.cost, case.start, case.goal, diagonal=case.diagonal)
    if path is None:
        return
    free = np.isfinite(case.cost)
    check_smoothed(free, path, smooth(free, path))


@pytest.mark.parametrize("layout", ["serpentine", "boxes"])
def test_long_runs_gallop_and_still_stay_in_sight(layout: str) -> None:
    """Runs much longer than FAR points, where the kept point is found by galloping."""
    n = 120
    cost = np.ones((n, n), dtype=np.float32)
    rng = np.random.default_rng(3)
    if layout == "serpentine":
        for k, r in enumerate(range(5, n - 5, 10)):  # walls with a gap at alternate ends
            cost[r, 4:] = np.inf
            cost[r, : n - 4] = np.inf
            cost[r, :4] = 1.0 if k % 2 else np.inf
            cost[r, n - 4 :] = np.inf if k % 2 else 1.0
    else:
        for _ in range(40):
            r, c = rng.integers(2, n - 20, 2)
            cost[r : r + rng.integers(3, 18), c : c + rng.integers(3, 18)] = np.inf
    cost[0, 0] = cost[-1, -1] = 1.0
    path = plan_python(cost, (0, 0), (n - 1, n - 1))
    assert path is not None
    free = np.isfinite(cost)
    kept = smooth(free, path)
    assert len(path) > 4 * FAR and len(kept) < len(path) // 10
    check_smoothed(free, path, kept)


@pytest.mark.parametrize("goal", [(0, 49), (49, 0), (49, 49), (30, 49), (49, 17)])
def test_an_open_line_becomes_two_points(goal: Cell) -> None:
    free = np.ones((50, 50), dtype=bool)
    path = plan_python(np.ones((50, 50), dtype=np.float32), (0, 0), goal)
    assert path is not None
    np.testing.assert_array_equal(smooth(free, path), [(0, 0), goal])


def test_short_paths_are_kept_whole() -> None:
    free = np.ones((3, 3), dtype=bool)
    one = np.array([[1, 1]], dtype=np.int32)
    np.testing.assert_array_equal(smooth(free, one), one)
    two = np.array([[1, 1], [2, 2]], dtype=np.int32)
    np.testing.assert_array_equal(smooth(free, two), two)


def test_a_step_out_of_sight_is_kept() -> None:
    """A path that cuts a blocked corner is not made worse: its points stay."""
    free = np.array([[1, 0], [1, 1]], dtype=bool)
    path = np.array([[0, 0], [1, 1]], dtype=np.int32)
    np.testing.assert_array_equal(smooth(free, path), path)


@pytest.mark.parametrize(
    ("free", "path", "message"),
    [
        (np.ones((3, 3), dtype=np.uint8), [[0, 0]], "bool"),
        (np.ones(9, dtype=bool), [[0, 0]], "2-D"),
        (np.ones((3, 3), dtype=bool), np.zeros((0, 2), dtype=np.int32), "k >= 1"),
        (np.ones((3, 3), dtype=bool), [[0.0, 0.0]], "integer"),
        (np.ones((3, 3), dtype=bool), [[0, 0, 0]], r"\(k, 2\)"),
        (np.ones((3, 3), dtype=bool), [[0, 0], [0, 3]], "leaves the 3x3 grid"),
        (np.ones((3, 3), dtype=bool), [[0, 0], [-1, 0]], "leaves"),
        (np.ones((3, 3), dtype=bool), [[0, 0], [2, 2]], "neighbours"),
    ],
)
def test_bad_input_is_refused(free: Mask, path: object, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        smooth(free, np.asarray(path))
