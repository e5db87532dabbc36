"""Global SLAM: keyframes, loop closures, the pose graph, and the grid redrawn when it bends.

The front end (match.py) corrects each scan against the map near the odometry's guess; what
it cannot correct (a heading error picked up while the lidar saw nothing) stays in the map,
turned. This back end keeps what is needed to bend the map back afterwards, as
Cartographer's global SLAM and slam_toolbox do:

- **Keyframes.** Whenever a robot has moved KEYFRAME_M or turned KEYFRAME_RAD since its last
  keyframe, its current scan becomes one: a node of the pose graph (posegraph.py), with the
  scan's end points in the robot's frame, tied to the robot's previous keyframe by the relative
  pose the front end measured. That edge is tight where the scans in between were matched and
  loose in proportion to the distance and turn driven blind (unmatched scans).
- **Every scan, kept.** Each scan is stored with its keyframe and its pose relative to it, so
  that when the keyframes move the grid can be redrawn with every scan where its keyframe now
  is (the scans between two keyframes are rigidly attached to the earlier one).
- **Closures.** Each new keyframe is looked for (loops.py) in submaps of older keyframes that
  saw the same walls, found through a coarse index of the cells each keyframe's scan ended in
  (two keyframes metres apart may see the same wall; two close ones may not): the same
  robot's from more than RECENT_M of driving ago, any other robot's (that is how the robots'
  maps are joined). A closure that agrees with the graph is added at once, and its robot looks
  again only after another LOCKED_M of driving; one that would move the robot needs a second,
  consistent one from one of its next keyframes, since a false closure does more harm than a
  missed one.
- **Optimising.** When a closure moves a robot, or after OPTIMISE_EVERY that did not, the graph
  is optimised; every robot's map ← odom correction then follows its latest keyframe, and the
  grid is redrawn from the stored scans when a keyframe moved by more than a fraction of a cell
  (REDRAW_M).

Everything is a function of the scans and odometry in the order they came: lockstep runs repeat
to the byte.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from clients.mapping.grid import Beams, LogOddsGrid
from clients.mapping.loops import MIN_POINTS, search
from clients.mapping.match import end_points
from clients.mapping.posegraph import Pose, PoseGraph, between, compose, information, inverse
from fleetcommon.arrays import F32, F64

#: a new keyframe after this much motion since the last (slam_toolbox's defaults are 0.5 m and
#: 0.5 rad; closer keyframes bend a map more smoothly and find closures sooner; a 360° lidar
#: turning on the spot sees nothing new, so turning alone makes few)
KEYFRAME_M = 0.25
KEYFRAME_RAD = 0.8
#: a trajectory edge's noise: where the front end matched its scans, and what drives blind adds
#: (the heading's random walk of 5 % wheel slip: ~0.04 rad over a metre, ~0.01 over a radian)
MATCHED_M = 0.01
MATCHED_RAD = 0.003
BLIND_M_PER_M = 0.05
BLIND_RAD_PER_SQRT_M = 0.05
BLIND_RAD_PER_SQRT_RAD = 0.015
#: a scan whose match paired less than this share of its points counts as blind
BLIND_SUPPORT = 0.2
#: a loop edge's noise (metres, radians)
LOOP_M = 0.02
LOOP_RAD = 0.01
#: each robot's first keyframe is held where its odometry started
ROOT = information(1e-3, 1e-3)
#: where closures are looked for: older keyframes that saw the same walls, found by an index of
#: the OVERLAP_M cells their scans ended in; a keyframe that shares MIN_SHARED of the cells the
#: new one's scan ended in (grown by a cell, the wide search's reach) is a candidate. The same
#: robot's only from RECENT_M of driving ago (the front end keeps the recent ones in line)
OVERLAP_M = 0.5
MIN_SHARED = 4
RECENT_M = 5.0
#: submaps tried per keyframe (those sharing the most first): a robot's candidates in a row (gaps
#: up to SUBMAP_GAP keyframes), at most SUBMAP_SPAN keyframes either side of the one sharing most
TRIES = 2
SUBMAP_GAP = 3
SUBMAP_SPAN = 12
#: a closure that moves its keyframe less than this agrees with the graph; a larger one waits
#: for another within CONFIRM_KEYFRAMES keyframes of the same robot that moves it the same way
AGREE_M = 0.05
AGREE_RAD = 0.02
CONFIRM_KEYFRAMES = 3
CONFIRM_M = 0.1
CONFIRM_RAD = 0.03
#: optimise after this many closures that agreed with the graph (one that moves a robot is
#: optimised at once)
OPTIMISE_EVERY = 50
#: a robot whose keyframe was found where the graph has it searches again after this much driving
LOCKED_M = 1.0
#: redraw the grid when a keyframe moved this much since it was drawn (metres; a turn counts
#: as the motion it gives a point LEVER_M away)
REDRAW_M = 0.02
LEVER_M = 2.0


@dataclass
class Keyframe:
    ns: str
    points: F64  # the scan's end points in the robot's frame (n x 2)
    travelled: float  # its robot's driving up to it (metres)
    seq: int  # its place among its robot's keyframes


@dataclass
class _Scan:
    node: int
    sensor: Pose  # the lidar's pose in its keyframe's frame
    ranges: F32


@dataclass
class _Candidate:
    node: int
    anchor: int
    z: Pose
    move: Pose  # where it would put its keyframe, as a rigid motion of the map frame


@dataclass
class Backend:
    """Keyframes, closures and the pose graph of a fleet's mapping run; draws into ``grid``."""

    grid: LogOddsGrid
    beams: Beams
    graph: PoseGraph = field(default_factory=PoseGraph)
    keyframes: list[Keyframe] = field(default_factory=list)
    scans: list[_Scan] = field(default_factory=list)
    last: dict[str, int] = field(default_factory=dict)  # each robot's newest keyframe
    closures: int = 0  # accepted so far
    optimisations: int = 0
    redraws: int = 0
    _blind: dict[str, tuple[int, int]] = field(default_factory=dict)  # scans since the last keyframe, blind ones
    _travelled: dict[str, float] = field(default_factory=dict)
    _count: dict[str, int] = field(default_factory=dict)  # keyframes of each robot
    _next_search: dict[str, float] = field(default_factory=dict)  # driving at which a robot searches again
    _pending: dict[str, list[_Candidate]] = field(default_factory=dict)
    _unoptimised: int = 0
    _drawn: list[Pose] = field(default_factory=list)  # each keyframe's pose the grid was drawn with
    _cells: list[npt.NDArray[np.intp]] = field(default_factory=list)  # each keyframe's overlap cells

    @property
    def _overlap_shape(self) -> tuple[int, int]:
        """Columns and rows of the overlap index over the grid's extent."""
        g = self.grid
        return math.ceil(g.width * g.resolution / OVERLAP_M), math.ceil(g.height * g.resolution / OVERLAP_M)

    def add(self, ns: str, pose: Pose, offset: tuple[float, float], ranges: F32, support: float) -> dict[str, Pose]:
        """A scan the front end placed at ``pose`` (map frame) with ``support``: stored, made a
        keyframe if the robot moved enough, closures looked for, the graph optimised if they
        call for it, and the scan drawn into the grid (with every other, if the graph bent).
        Returns, for each robot the graph moved, the rigid motion of the map frame that takes
        its old estimate to the new one (to apply to its map ← odom correction)."""
        seen, blind = self._blind.get(ns, (0, 0))
        self._blind[ns] = (seen + 1, blind + (support < BLIND_SUPPORT))
        node = self.last.get(ns)
        new = node is None
        if node is None:
            node = self._keyframe(ns, pose, ranges, offset, None)
        else:
            d = between(self.graph.poses[node], pose)
            if math.hypot(d[0], d[1]) >= KEYFRAME_M or abs(d[2]) >= KEYFRAME_RAD:
                node = self._keyframe(ns, pose, ranges, offset, node)
                new = True
        sensor = between(self.graph.poses[node], compose(pose, (offset[0], offset[1], 0.0)))
        self.scans.append(_Scan(node, sensor, np.array(ranges, dtype=np.float32)))
        moved = self._close(node) if new else {}
        if moved and self._needs_redraw():
            self.redraw()
        else:
            self._draw(self.scans[-1])
        return moved

    def path(self, ns: str) -> list[tuple[float, float]]:
        """A robot's keyframe positions, oldest first."""
        return [(p[0], p[1]) for p, k in zip(self.graph.poses, self.keyframes, strict=True) if k.ns == ns]

    # -- keyframes and closures ----------------------------------------------------------------

    def _keyframe(self, ns: str, pose: Pose, ranges: F32, offset: tuple[float, float], previous: int | None) -> int:
        px, py = end_points(ranges, self.beams, offset)
        travelled = self._travelled.get(ns, 0.0)
        if previous is None:
            node = self.graph.add_root(pose, ROOT)
        else:
            z = between(self.graph.poses[previous], pose)
            d, turn = math.hypot(z[0], z[1]), abs(z[2])
            seen, blind = self._blind.get(ns, (1, 0))
            share = blind / max(1, seen)
            sigma_m = MATCHED_M + share * BLIND_M_PER_M * d
            blind_rad2 = BLIND_RAD_PER_SQRT_M**2 * d + BLIND_RAD_PER_SQRT_RAD**2 * turn
            sigma_rad = math.sqrt(MATCHED_RAD**2 + share * blind_rad2)
            node = self.graph.add_node(previous, z, information(sigma_m, sigma_rad), pose)
            travelled += d
        self._travelled[ns] = travelled
        self._blind[ns] = (0, 0)
        self.keyframes.append(Keyframe(ns, np.column_stack([px, py]), travelled, self._count.get(ns, 0)))
        self._count[ns] = self._count.get(ns, 0) + 1
        self.last[ns] = node
        self._drawn.append(pose)
        self._cells.append(self._index(node))
        return node

    def _index(self, node: int) -> npt.NDArray[np.intp]:
        """The overlap index's cells where ``node``'s scan ended, at its current estimate."""
        pts = _moved(self.keyframes[node].points, self.graph.poses[node])
        col = np.floor((pts[:, 0] - self.grid.origin[0]) / OVERLAP_M).astype(np.intp)
        row = np.floor((pts[:, 1] - self.grid.origin[1]) / OVERLAP_M).astype(np.intp)
        w, h = self._overlap_shape
        inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
        return np.unique(row[inside] * w + col[inside])

    def _submaps(self, node: int) -> list[list[int]]:
        """Runs of older keyframes that saw what ``node`` sees (by the overlap index, the cells
        grown by the wide search's reach), the runs that share the most first."""
        if node == 0:
            return []
        me = self.keyframes[node]
        w, h = self._overlap_shape
        mine = np.zeros((h + 2, w + 2), dtype=bool)  # a margin of one cell all round
        rows, cols = np.divmod(self._cells[node], w)
        for dr in (0, 1, 2):
            for dc in (0, 1, 2):
                mine[rows + dr, cols + dc] = True
        seen = mine[1:-1, 1:-1].ravel()
        owner = np.concatenate([np.full(len(c), k, dtype=np.intp) for k, c in enumerate(self._cells[:node])])
        cells = np.concatenate(self._cells[:node])
        votes = np.bincount(owner[seen[cells]], minlength=node)
        runs: dict[str, list[list[int]]] = {}
        for k in np.flatnonzero(votes >= MIN_SHARED).tolist():
            kf = self.keyframes[k]
            if kf.ns == me.ns and me.travelled - kf.travelled < RECENT_M:
                continue
            robot = runs.setdefault(kf.ns, [])
            if robot and kf.seq - self.keyframes[robot[-1][-1]].seq <= SUBMAP_GAP:
                robot[-1].append(k)
            else:
                robot.append([k])
        found = [run for ns in sorted(runs) for run in runs[ns]]
        found.sort(key=lambda run: -max(int(votes[k]) for k in run))  # stable: ties keep their order
        submaps = []
        for run in found[:TRIES]:
            anchor = max(run, key=lambda k: int(votes[k]))
            seq = self.keyframes[anchor].seq
            submaps.append(
                [anchor, *(k for k in run if k != anchor and abs(self.keyframes[k].seq - seq) <= SUBMAP_SPAN)]
            )
        return submaps

    def _close(self, node: int) -> dict[str, Pose]:
        """Look for ``node`` in older submaps; add the closures found; optimise if they call for it."""
        me = self.keyframes[node]
        here = self.graph.poses[node]
        urgent = False
        if len(me.points) < MIN_POINTS or me.travelled < self._next_search.get(me.ns, 0.0):
            return {}
        for run in self._submaps(node):
            anchor = run[0]
            frame = self.graph.poses[anchor]
            seen_from = [between(frame, self.graph.poses[k]) for k in run]
            points = np.concatenate(
                [_moved(self.keyframes[k].points, rel) for k, rel in zip(run, seen_from, strict=True)]
            )
            sensors = np.concatenate([np.tile(rel[:2], (len(self.keyframes[k].points), 1))
                                      for k, rel in zip(run, seen_from, strict=True)])  # fmt: skip
            closure = search(me.points, points, sensors, between(frame, here), self.grid.resolution)
            if not closure.accepted:
                continue
            found = compose(frame, closure.pose)
            move = compose(found, inverse(here))
            step = between(here, found)
            candidate = _Candidate(node, anchor, closure.pose, move)
            if math.hypot(step[0], step[1]) <= AGREE_M and abs(step[2]) <= AGREE_RAD:
                self._accept(candidate)
                self._next_search[me.ns] = me.travelled + LOCKED_M
                continue
            recent = self._pending.get(me.ns, [])
            pending = [p for p in recent if me.seq - self.keyframes[p.node].seq <= CONFIRM_KEYFRAMES]
            agreeing = [p for p in pending if _agree(p.move, move, here)]
            if agreeing:
                for p in [*agreeing, candidate]:
                    self._accept(p)
                pending = [p for p in pending if p not in agreeing]
                urgent = True
            else:
                pending.append(candidate)
            self._pending[me.ns] = pending
        if urgent or self._unoptimised >= OPTIMISE_EVERY:
            return self._optimise()
        return {}

    def _accept(self, c: _Candidate) -> None:
        self.graph.add_loop(c.anchor, c.node, c.z, information(LOOP_M, LOOP_RAD))
        self.closures += 1
        self._unoptimised += 1

    def _optimise(self) -> dict[str, Pose]:
        before = list(self.graph.poses)
        self.graph.optimise()
        self.optimisations += 1
        self._unoptimised = 0
        self._pending.clear()  # their motions were measured in the frame the graph just left
        return {ns: compose(self.graph.poses[k], inverse(before[k])) for ns, k in self.last.items()}

    # -- the grid -----------------------------------------------------------------------------

    def _needs_redraw(self) -> bool:
        now = np.array(self.graph.poses, dtype=np.float64)
        drawn = np.array(self._drawn, dtype=np.float64)
        turn = np.abs(np.arctan2(np.sin(now[:, 2] - drawn[:, 2]), np.cos(now[:, 2] - drawn[:, 2])))
        return bool((np.hypot(*(now[:, :2] - drawn[:, :2]).T) + LEVER_M * turn).max() > REDRAW_M)

    def _draw(self, scan: _Scan) -> None:
        x, y, yaw = compose(self.graph.poses[scan.node], scan.sensor)
        self.grid.integrate(x, y, yaw, scan.ranges, self.beams)

    def redraw(self) -> None:
        """The grid again from every stored scan, each where its keyframe now is."""
        self.grid.clear()
        for scan in self.scans:
            self._draw(scan)
        self._drawn = list(self.graph.poses)
        self._cells = [self._index(k) for k in range(len(self.keyframes))]
        self.redraws += 1


def _moved(points: F64, pose: Pose) -> F64:
    """Points given in ``pose``'s frame, in the frame ``pose`` is given in."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    x, y = points[:, 0], points[:, 1]
    return np.column_stack([pose[0] + c * x - s * y, pose[1] + s * x + c * y])


def _agree(a: Pose, b: Pose, at: Pose) -> bool:
    """Whether two motions of the map frame put a pose ``at`` in about the same place."""
    d = between(compose(a, at), compose(b, at))
    return math.hypot(d[0], d[1]) <= CONFIRM_M and abs(d[2]) <= CONFIRM_RAD
