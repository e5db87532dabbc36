"""Loop closure search: where a keyframe's scan was taken, seen from an older part of the map.

The front end (match.py) matches each scan against the whole map near where odometry says the
robot is, within centimetres. After a long drift that is not enough: back at a place it mapped
a minute ago, the robot's estimate is decimetres and degrees off, and the old walls are out of
the refinement's reach. The back end therefore searches for each new keyframe, as
Cartographer's constraint builder and slam_toolbox's loop closure do:

- **A submap of old keyframes.** The caller gathers the scan points of a run of older
  keyframes that saw the same walls, in the frame of one of them (the anchor), with where each
  point was seen from; only the keyframes' relative poses matter, and those the front end got
  right.
- **First, where the graph says.** A point-to-line refinement (match.py's) from the current
  estimate: when the graph is already right, this pairs most of the scan at once.
- **Else a wide correlative search.** ±1 m and ±0.25 rad around the estimate, first on cells
  twice the map's (every pose a coarse cell and a coarse-cell-at-the-range's-end of angle
  apart), then on the map's cells around the best: the score of a pose is the mean, over the
  scan's points, of the submap's evidence (1 on a point's cell, falling off over a cell or
  two). Translations are whole cells, so a rotation's scores are one gather. The best pose is
  refined by point-to-line ICP.
- **Only confident matches.** A false closure bends a good map out of shape, a missed one
  costs nothing but time, so a match is refused unless most of the scan lies on the submap's
  walls (support, score), unless the walls hold the position in every direction (a single
  wall or a corridor lets the scan slide along it: the spread of the pairs' normals), unless
  the scan sees its walls from the side the submap saw them (a robot outside the house sees
  the outer faces of the walls another mapped from inside, a wall's thickness away: laid on
  the inner faces they fit well, and wrongly), and, from the wide search, unless the best
  pose beats every pose more than a few cells away clearly (no second place almost as good: a
  repeated structure).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from clients.mapping.grid import LogOddsGrid
from clients.mapping.match import Obstacles, refine
from clients.mapping.posegraph import Pose, information
from fleetcommon.arrays import F64

#: the wide search's reach around the estimate (metres, radians)
WIDE_M = 1.0
WIDE_RAD = 0.25
#: a scan and a submap need this many points to be matched at all
MIN_POINTS = 60
#: at most this many of the scan's points in the coarse stage of the wide search (evenly picked)
COARSE_POINTS = 120
#: the refinement's pull toward where it starts: loose (the data decides), but it keeps a
#: direction the walls do not hold from wandering off
PRIOR = information(0.2, 0.1)
#: accepting: the share of the scan's points paired with the submap's walls within 3 cm after
#: the refinement, and the walls' spread (see match.Fit.spread)
MIN_SUPPORT = 0.5
MIN_SPREAD = 0.08
#: at most this share of the pairs may be seen from opposite sides (the two faces of a wall),
#: a pair being points this close
MAX_BACKSIDE = 0.1
PAIR_M = 0.05
#: the wide search's best mean evidence, and how close the best pose more than AMBIGUOUS_CELLS
#: coarse cells or AMBIGUOUS_RAD away may come to it
MIN_SCORE = 0.45
MAX_SECOND = 0.95
AMBIGUOUS_CELLS = 2
AMBIGUOUS_RAD = 0.06
#: the refinement from the estimate is taken when it moves at most this far (metres, radians)
DIRECT_M = 0.1
DIRECT_RAD = 0.05
#: the refinement of the wide search's best may move this far from it (a basin, not a jump)
REFINED_M = 0.1
REFINED_RAD = 0.05


@dataclass(frozen=True)
class Closure:
    """What a search found: the scan's pose in the submap's frame and how much to believe it."""

    pose: Pose
    support: float
    spread: float
    #: the wide search's best mean evidence and the best elsewhere (0 when it did not run)
    score: float = 0.0
    second: float = 0.0
    #: why it is refused ("" when accepted)
    refused: str = ""
    #: the share of its pairs seen from the other side of their walls
    backside: float = 0.0

    @property
    def accepted(self) -> bool:
        return not self.refused


class _Submap:
    """The submap's points as remembered obstacle points of a small grid (for point-to-line ICP),
    and for each cell the side its points were seen from (the sum of unit vectors from each
    point toward the sensor that saw it)."""

    def __init__(self, points: F64, sensors: F64, guess: Pose, resolution: float) -> None:
        reach = WIDE_M + 4.0  # the scan's range and the wide search's around the estimate
        x0 = min(float(points[:, 0].min()), guess[0] - reach) - 0.2
        x1 = max(float(points[:, 0].max()), guess[0] + reach) + 0.2
        y0 = min(float(points[:, 1].min()), guess[1] - reach) - 0.2
        y1 = max(float(points[:, 1].max()), guess[1] + reach) + 0.2
        self.grid = grid = LogOddsGrid((x0, x1, y0, y1), resolution)
        grid.add_points(points[:, 0].copy(), points[:, 1].copy())
        self.obstacles = Obstacles(grid)
        view = sensors - points
        view /= np.maximum(np.hypot(view[:, 0], view[:, 1]), 1e-9)[:, None]
        row, col = self._cells(points[:, 0], points[:, 1])
        self.view = np.zeros((grid.height, grid.width, 2))
        np.add.at(self.view, (row, col), view)

    def _cells(self, x: F64, y: F64) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
        g = self.grid
        col = np.clip(np.floor((x - g.origin[0]) / g.resolution).astype(np.intp), 0, g.width - 1)
        row = np.clip(np.floor((y - g.origin[1]) / g.resolution).astype(np.intp), 0, g.height - 1)
        return row, col

    def backside(self, px: F64, py: F64, pose: Pose) -> float:
        """The share of the scan's points at ``pose`` that pair with a wall the submap saw from its
        other side (the scan on one side of the wall's line, the submap's sensors on the other):
        a scan of a wall's outer face laid on its inner face."""
        c, s = math.cos(pose[2]), math.sin(pose[2])
        wx, wy = pose[0] + c * px - s * py, pose[1] + s * px + c * py
        mx, my, nx, ny, found = self.obstacles.pairs(wx, wy, 1)
        close = found & (np.hypot(np.where(found, mx - wx, 0.0), np.where(found, my - wy, 0.0)) < PAIR_M)
        if not close.any():
            return 0.0
        row, col = self._cells(mx[close], my[close])
        seen = self.view[row, col]
        nx, ny = nx[close], ny[close]
        theirs = nx * seen[:, 0] + ny * seen[:, 1]
        mine = nx * (pose[0] - wx[close]) + ny * (pose[1] - wy[close])
        return float((theirs * mine < 0.0).mean())


def _evidence(points: F64, guess: Pose, res: float) -> tuple[F64, float, float]:
    """The submap's evidence on cells of ``res`` around ``guess``: 1 on a cell holding a point,
    exp(-d²/2) a distance of d cells from one (d ≤ 2), 0 elsewhere; and the window's corner."""
    reach = WIDE_M + 4.0  # the scan's range and the search's reach around the estimate
    x0, y0 = guess[0] - reach, guess[1] - reach
    n = math.ceil(2 * reach / res)
    col = np.floor((points[:, 0] - x0) / res).astype(np.intp)
    row = np.floor((points[:, 1] - y0) / res).astype(np.intp)
    inside = (col >= 0) & (col < n) & (row >= 0) & (row < n)
    occupied = np.zeros((n + 4, n + 4))
    occupied[row[inside] + 2, col[inside] + 2] = 1.0
    out = occupied[2:-2, 2:-2].copy()
    for dr in range(-2, 3):
        for dc in range(-2, 3):
            d2 = dr * dr + dc * dc
            if 0 < d2 <= 4:
                np.maximum(out, math.exp(-d2 / 2.0) * occupied[2 + dr : 2 + dr + n, 2 + dc : 2 + dc + n], out=out)
    return out, x0, y0


def _scores(evidence: tuple[F64, float, float], res: float, px: F64, py: F64, centre: Pose, angles: F64,
            reach: int) -> F64:  # fmt: skip
    """Mean evidence under the scan's points at ``centre`` turned by each of ``angles`` and
    shifted by -reach..reach cells each way: scores[angle, row shift, column shift]."""
    grid, x0, y0 = evidence
    n = grid.shape[0]
    padded = np.pad(grid, reach + 1)  # a zero border: points off the window count nothing
    shifts = np.arange(-reach, reach + 1)
    scores = np.zeros((len(angles), len(shifts), len(shifts)))
    for k, da in enumerate(angles):
        c, s = math.cos(centre[2] + da), math.sin(centre[2] + da)
        col = np.floor((centre[0] + c * px - s * py - x0) / res).astype(np.intp)
        row = np.floor((centre[1] + s * px + c * py - y0) / res).astype(np.intp)
        col = np.clip(col, -reach - 1, n + reach) + reach + 1
        row = np.clip(row, -reach - 1, n + reach) + reach + 1
        rows = np.clip(row[None, :] + shifts[:, None], 0, n + 2 * reach + 1)
        cols = np.clip(col[None, :] + shifts[:, None], 0, n + 2 * reach + 1)
        scores[k] = padded[rows[:, None, :], cols[None, :, :]].sum(axis=2) / len(px)
    return scores


def _wide(submap: F64, px: F64, py: F64, guess: Pose, res: float) -> tuple[Pose, float, float]:
    """The correlative search, coarse to fine: every pose within WIDE_M and WIDE_RAD of ``guess``
    on cells twice as large (the evidence blurred as much), then around the best on the map's
    cells. Returns the best pose, its coarse score and the best coarse score elsewhere (more
    than AMBIGUOUS_CELLS coarse cells or AMBIGUOUS_RAD away)."""
    far = max(float(np.hypot(px, py).max()), res)
    coarse = 2.0 * res
    step = coarse / far  # the farthest point moves a coarse cell a step
    count = math.ceil(WIDE_RAD / step)
    angles = np.arange(-count, count + 1, dtype=np.float64) * step
    reach = round(WIDE_M / coarse)
    few = np.linspace(0, len(px) - 1, min(len(px), COARSE_POINTS)).round().astype(np.intp)
    scores = _scores(_evidence(submap, guess, coarse), coarse, px[few], py[few], guess, angles, reach)
    k, i, j = (int(v) for v in np.unravel_index(int(np.argmax(scores)), scores.shape))
    best = float(scores[k, i, j])
    a = AMBIGUOUS_CELLS
    others = scores.copy()
    others[np.abs(angles - angles[k]) <= AMBIGUOUS_RAD, max(0, i - a) : i + a + 1, max(0, j - a) : j + a + 1] = 0.0
    second = float(others.max())
    centre = (guess[0] + (j - reach) * coarse, guess[1] + (i - reach) * coarse, guess[2] + float(angles[k]))
    fine_step = res / far
    fine_angles = np.arange(-2, 3, dtype=np.float64) * fine_step
    fine = _scores(_evidence(submap, centre, res), res, px, py, centre, fine_angles, 2)
    k, i, j = (int(v) for v in np.unravel_index(int(np.argmax(fine)), fine.shape))
    return (centre[0] + (j - 2) * res, centre[1] + (i - 2) * res, centre[2] + float(fine_angles[k])), best, second


def _fit(obstacles: Obstacles, px: F64, py: F64, start: Pose) -> tuple[Pose, float, float, F64]:
    fit = refine(obstacles, px, py, start, np.zeros(3), PRIOR)
    p = fit.offset
    th = start[2] + float(p[2])
    pose = (start[0] + float(p[0]), start[1] + float(p[1]), math.atan2(math.sin(th), math.cos(th)))
    return pose, fit.support, fit.spread(), p


def search(scan: F64, submap: F64, sensors: F64, guess: Pose, resolution: float = 0.05) -> Closure:
    """Where the scan with end points ``scan`` (n x 2, in its robot's frame) was taken, in the
    frame of the ``submap``'s points (m x 2; ``sensors``, m x 2, where each was seen from), near
    ``guess`` (the graph's estimate, in that frame)."""
    if len(scan) < MIN_POINTS or len(submap) < MIN_POINTS:
        return Closure(guess, 0.0, 0.0, refused="too few points")
    px, py = scan[:, 0].copy(), scan[:, 1].copy()
    sub = _Submap(submap, sensors, guess, resolution)
    pose, support, spread, p = _fit(sub.obstacles, px, py, guess)
    close = math.hypot(p[0], p[1]) <= DIRECT_M and abs(p[2]) <= DIRECT_RAD
    back = sub.backside(px, py, pose)
    if support >= MIN_SUPPORT and spread >= MIN_SPREAD and close and back <= MAX_BACKSIDE:
        return Closure(pose, support, spread, backside=back)
    start, best, second = _wide(submap, px, py, guess, resolution)
    pose, support, spread, p = _fit(sub.obstacles, px, py, start)
    back = sub.backside(px, py, pose)
    refused = ""
    if best < MIN_SCORE:
        refused = f"score {best:.2f} < {MIN_SCORE}"
    elif second > MAX_SECOND * best:
        refused = f"ambiguous: {second:.2f} elsewhere against {best:.2f}"
    elif support < MIN_SUPPORT:
        refused = f"support {support:.2f} < {MIN_SUPPORT}"
    elif spread < MIN_SPREAD:
        refused = f"the walls hold one direction only (spread {spread:.2f})"
    elif math.hypot(p[0], p[1]) > REFINED_M or abs(p[2]) > REFINED_RAD:
        refused = "the refinement left the search's best"
    elif back > MAX_BACKSIDE:
        refused = f"{back:.0%} of the pairs are on the far side of their walls"
    return Closure(pose, support, spread, best, second, refused, back)
