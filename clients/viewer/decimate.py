"""Which scans and trails a viewer frame carries, and how thinned: the frame's budget shared
among the robots in view, nearest the view's centre first; and how far a planned path is
thinned before it goes to pages. Pure functions of the robots' poses, the page's view and the
path (no state, no I/O), so each rule is tested on its own."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from fleetcommon.arrays import F32, F64

LIDAR_RANGE_MAX = 3.5
TRAIL_MAX_POINTS = 96
SCAN_POINT_BUDGET = 12_000  # beams per frame over all robots (before dropping non-finite)
MAX_BEAM_STEP = 12  # thinnest scan sent: every 12th beam (30 of 360)
TRAIL_POINT_BUDGET = 12_000
MIN_TRAIL_POINTS = 6
PATH_TOLERANCE_M = 0.02  # a planned path's points closer than this to the line kept are dropped
PATH_MAX_POINTS = 128
PATH_INPUT_MAX = 4096  # a longer path is evenly thinned to this many points before the rest


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


def thin_path(
    points: F64 | list[tuple[float, float]], tolerance: float = PATH_TOLERANCE_M, max_points: int = PATH_MAX_POINTS
) -> F64:
    """A planned path with the points a drawing does not need dropped: those within
    ``tolerance`` m of the line through the points kept (Ramer-Douglas-Peucker), then, if more
    than ``max_points`` are left, evenly thinned. Both ends are always kept; non-finite points
    are dropped first, and a path of more than PATH_INPUT_MAX points is evenly thinned to that
    first (a path is drawn, never trusted: this runs on a zenoh thread)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) > PATH_INPUT_MAX:  # bound the work on what the network sent
        pts = pts[np.linspace(0, len(pts) - 1, PATH_INPUT_MAX).round().astype(np.intp)]
    n = len(pts)
    if n <= 2:
        return pts
    keep = np.zeros(n, dtype=bool)
    keep[0] = keep[-1] = True
    spans = [(0, n - 1)]
    while spans:
        a, b = spans.pop()
        if b - a < 2:
            continue
        d = _distances_to_segment(pts[a + 1 : b], pts[a], pts[b])
        k = int(np.argmax(d))
        if d[k] > tolerance:
            m = a + 1 + k
            keep[m] = True
            spans += [(a, m), (m, b)]
    out = pts[keep]
    if len(out) > max_points:
        out = out[np.unique(np.linspace(0, len(out) - 1, max(2, max_points)).round().astype(np.intp))]
    return out


def _distances_to_segment(p: F64, a: F64, b: F64) -> F64:
    ab = b - a
    den = float(ab @ ab)
    t = np.zeros(len(p)) if den == 0.0 else np.clip((p - a) @ ab / den, 0.0, 1.0)
    d: F64 = np.hypot(*(p - a - t[:, None] * ab).T)
    return d
