"""Which scans and trails a viewer frame carries, and how thinned: the frame's budget shared
among the robots in view, nearest the view's centre first. Pure functions of the robots'
poses and the page's view (no state, no I/O), so each rule is tested on its own."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

F32 = npt.NDArray[np.float32]

LIDAR_RANGE_MAX = 3.5
TRAIL_MAX_POINTS = 96
SCAN_POINT_BUDGET = 12_000  # beams per frame over all robots (before dropping non-finite)
MAX_BEAM_STEP = 12  # thinnest scan sent: every 12th beam (30 of 360)
TRAIL_POINT_BUDGET = 12_000
MIN_TRAIL_POINTS = 6


@dataclass(frozen=True)
class View:
    """What one page shows, as it last reported: the visible world rectangle and toggles."""

    x0: float = -math.inf
    y0: float = -math.inf
    x1: float = math.inf
    y1: float = math.inf
    scans: bool = True
    trails: bool = True
    selected: str | None = None


def in_view(poses: F32, view: View, margin: float) -> npt.NDArray[np.bool_]:
    x, y = poses[:, 0], poses[:, 1]
    ok: npt.NDArray[np.bool_] = (
        (x >= view.x0 - margin) & (x <= view.x1 + margin) & (y >= view.y0 - margin) & (y <= view.y1 + margin)
    )
    return ok


def by_distance_to_centre(idx: npt.NDArray[np.intp], poses: F32, view: View) -> list[int]:
    if not all(math.isfinite(v) for v in (view.x0, view.y0, view.x1, view.y1)):
        return [int(i) for i in idx]
    cx, cy = (view.x0 + view.x1) / 2, (view.y0 + view.y1) / 2
    d = np.hypot(poses[idx, 0] - cx, poses[idx, 1] - cy)
    return [int(i) for i in idx[np.argsort(d, kind="stable")]]


def pick_scans(
    has_scan: npt.NDArray[np.bool_], selected: int | None, beams: int, poses: F32, view: View
) -> tuple[list[int], int]:
    """Which robots' scans to send and at which beam step.

    Candidates are robots with a scan (``has_scan``) whose origin is within the view grown by
    the lidar range. The step is the smallest that fits all of them in SCAN_POINT_BUDGET beams
    of ``beams`` a scan, at most MAX_BEAM_STEP; past that, the robots nearest the view centre
    are kept. The ``selected`` robot's scan is always sent first.
    """
    idx = np.flatnonzero(has_scan & in_view(poses, view, LIDAR_RANGE_MAX))
    picked = by_distance_to_centre(idx, poses, view)
    if selected is not None:
        picked = [selected, *(i for i in picked if i != selected)]
    if not picked:
        return [], 1
    step = 1
    while step < MAX_BEAM_STEP and len(picked) * math.ceil(beams / step) > SCAN_POINT_BUDGET:
        step += 1
    keep = max(1, SCAN_POINT_BUDGET // math.ceil(beams / step))
    return picked[:keep], step


def pick_trails(poses: F32, view: View) -> tuple[list[int], int]:
    """Trails of the robots in view (grown by 1.5 m), each thinned so the frame holds at
    most TRAIL_POINT_BUDGET points; if even MIN_TRAIL_POINTS each is too many, the robots
    nearest the view centre keep theirs."""
    idx = np.flatnonzero(in_view(poses, view, 1.5))
    picked = by_distance_to_centre(idx, poses, view)
    if not picked:
        return [], 0
    per = max(MIN_TRAIL_POINTS, min(TRAIL_MAX_POINTS, TRAIL_POINT_BUDGET // len(picked)))
    return picked[: TRAIL_POINT_BUDGET // per], per
