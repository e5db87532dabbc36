"""The viewer's frame budget (clients/viewer/decimate.py), rule by rule: which scans and
trails a frame carries and how thinned. Pure functions of poses and a view."""

from __future__ import annotations

import math

import numpy as np
import pytest

from clients.viewer.decimate import (
    MAX_BEAM_STEP,
    MIN_TRAIL_POINTS,
    SCAN_POINT_BUDGET,
    TRAIL_MAX_POINTS,
    TRAIL_POINT_BUDGET,
    View,
    by_distance_to_centre,
    in_view,
    pick_scans,
    pick_trails,
)


def poses(*xy: tuple[float, float]) -> np.ndarray:
    p = np.zeros((len(xy), 5), np.float32)
    p[:, :2] = xy
    return p


@pytest.mark.parametrize(
    ("view", "margin", "inside"),
    [
        (View(), 0.0, [True, True, True]),  # no view reported yet: everything
        (View(-1, -1, 1, 1), 0.0, [True, False, False]),
        (View(-1, -1, 1, 1), 3.5, [True, True, False]),  # grown by the lidar's range
        (View(4, 4, 6, 6), 0.0, [False, False, False]),
    ],
)
def test_in_view(view: View, margin: float, inside: list[bool]) -> None:
    assert in_view(poses((0, 0), (3, 0), (20, 20)), view, margin).tolist() == inside


def test_nearest_to_the_view_centre_first() -> None:
    p = poses((5, 5), (0, 0), (1, 1), (9, 9))
    assert by_distance_to_centre(np.arange(4), p, View(-2, -2, 2, 2)) == [1, 2, 0, 3]
    assert by_distance_to_centre(np.arange(4), p, View()) == [0, 1, 2, 3]  # no view: as listed


@pytest.mark.parametrize(
    ("robots", "step", "kept"),
    [
        (1, 1, 1),
        (SCAN_POINT_BUDGET // 360, 1, SCAN_POINT_BUDGET // 360),  # all at full density
        (SCAN_POINT_BUDGET // 360 + 1, 2, SCAN_POINT_BUDGET // 360 + 1),  # every second beam
        (1000, MAX_BEAM_STEP, SCAN_POINT_BUDGET // 30),  # thinnest, then the nearest kept
    ],
)
def test_scans_share_the_beam_budget(robots: int, step: int, kept: int) -> None:
    p = poses(*[(0.01 * i, 0.0) for i in range(robots)])
    picked, got_step = pick_scans(np.ones(robots, bool), None, 360, p, View())
    assert (got_step, len(picked)) == (step, kept)
    assert len(picked) * math.ceil(360 / got_step) <= SCAN_POINT_BUDGET


def test_the_selected_robots_scan_comes_first_and_robots_without_a_scan_never() -> None:
    p = poses((0, 0), (50, 50), (1, 1))
    has = np.array([True, True, False])
    picked, _ = pick_scans(has, 1, 360, p, View(-2, -2, 2, 2))  # selected though far out of view
    assert picked == [1, 0]
    assert pick_scans(np.zeros(3, bool), None, 360, p, View()) == ([], 1)


MANY = TRAIL_POINT_BUDGET // TRAIL_MAX_POINTS + 1


@pytest.mark.parametrize(
    ("robots", "per"),
    [
        (1, TRAIL_MAX_POINTS),
        (MANY, TRAIL_POINT_BUDGET // MANY),  # one robot too many for full trails: each thinned
        (10_000, MIN_TRAIL_POINTS),
    ],
)
def test_trails_share_the_point_budget(robots: int, per: int) -> None:
    picked, got = pick_trails(poses(*[(0.001 * i, 0.0) for i in range(robots)]), View())
    assert got == per and len(picked) * got <= TRAIL_POINT_BUDGET
    assert len(picked) == min(robots, TRAIL_POINT_BUDGET // per)


def test_no_trail_out_of_view() -> None:
    assert pick_trails(poses((10, 10)), View(-1, -1, 1, 1)) == ([], 0)
