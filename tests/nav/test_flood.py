"""simd/nav/flood.py: the flood fill against a plain Dijkstra, and table cases."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings

from simd.nav.flood import reachable
from tests.nav.grids import Case, cases, dijkstra


@settings(max_examples=100, derandomize=True, deadline=None)
@given(case=cases(max_side=25))
def test_reachable_is_where_dijkstra_gets(case: Case) -> None:
    mask = reachable(np.isfinite(case.cost), case.start, diagonal=case.diagonal)
    expected = np.zeros(case.cost.shape, dtype=bool)
    for cell in dijkstra(case.cost, case.start, case.diagonal):
        expected[cell] = True
    np.testing.assert_array_equal(mask, expected)


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
