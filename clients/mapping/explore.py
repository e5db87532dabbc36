"""Frontier exploration: robots that map on their own, sharing the frontiers among them.

A frontier is a free cell next to unknown space. Each round, every robot is sent towards the
nearest frontier it can reach through free space that keeps clear of the walls (the occupied
cells grown by the robot's radius plus a margin) and of the other robots; frontiers near a goal
already given to another robot cost more, so four robots spread out instead of following each
other. Distances come from a wavefront over the grid (numpy, a row of cells at a time); the
robot heads for a point about half a metre along its path, slowing down to turn.
Exploration ends when no robot can reach a frontier any more: after several plans in a row that
found none, the robots turning on the spot meanwhile (free space needs a few looks to count as
free, so a robot that has just arrived first looks around).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from fleetcommon.mapfile import FREE, UNKNOWN

B = npt.NDArray[np.bool_]
I32 = npt.NDArray[np.int32]

#: room kept between a robot's centre and a wall, beyond its radius
MARGIN_M = 0.08
#: how far along its path a robot aims
LOOKAHEAD_M = 0.5
#: what sharing costs: a frontier this close to another robot's goal counts this much farther
SHARE_RADIUS_M = 1.0
SHARE_PENALTY_M = 3.0
#: plans in a row without a reachable frontier before exploration ends (each turns the robots a bit)
IDLE_ROUNDS = 8
#: frontier patches smaller than this many cells are noise (a gap between two scans' beams)
MIN_FRONTIER_CELLS = 3


def grow(mask: B, cells: int) -> B:
    """``mask`` dilated by a square of ``cells`` on each side (integral image)."""
    if cells <= 0:
        return mask.copy()
    k = 2 * cells + 1
    padded = np.pad(mask.astype(np.int32), cells)
    s = np.pad(padded.cumsum(0).cumsum(1), ((1, 0), (1, 0)))
    window = s[k:, k:] - s[:-k, k:] - s[k:, :-k] + s[:-k, :-k]
    return np.asarray(window > 0)


def wavefront(passable: B, start: tuple[int, int]) -> I32:
    """Steps (8-connected) from ``start`` to every cell reachable through ``passable``; -1 elsewhere."""
    dist = np.full(passable.shape, -1, dtype=np.int32)
    r, c = start
    if not (0 <= r < passable.shape[0] and 0 <= c < passable.shape[1]):
        return dist
    front = np.zeros(passable.shape, dtype=bool)
    front[r, c] = True
    dist[r, c] = 0
    step = 0
    while front.any():
        step += 1
        grown = front.copy()
        grown[1:, :] |= front[:-1, :]
        grown[:-1, :] |= front[1:, :]
        grown[:, 1:] |= grown[:, :-1].copy()
        grown[:, :-1] |= grown[:, 1:].copy()
        front = grown & passable & (dist < 0)
        dist[front] = step
    return dist


@dataclass
class Goal:
    cell: tuple[int, int]
    waypoint: tuple[float, float]


@dataclass
class Explorer:
    """Plans a goal per robot on the current map; ``command`` turns it into (v, w)."""

    resolution: float
    origin: tuple[float, float]
    radius_m: float = 0.12
    max_linear: float = 0.2
    max_angular: float = 1.5
    goals: dict[str, Goal] = field(default_factory=dict)
    #: consecutive plans that found no reachable frontier for anyone (while it grows, robots turn
    #: on the spot to look around: free space needs three looks before it is free)
    idle_rounds: int = 0

    def _cell(self, x: float, y: float) -> tuple[int, int]:
        return int((y - self.origin[1]) // self.resolution), int((x - self.origin[0]) // self.resolution)

    def _point(self, cell: tuple[int, int]) -> tuple[float, float]:
        r, c = cell
        return self.origin[0] + (c + 0.5) * self.resolution, self.origin[1] + (r + 0.5) * self.resolution

    def frontiers(self, cells: npt.NDArray[np.int8], clear: B) -> B:
        unknown = cells == UNKNOWN
        near_unknown = np.zeros_like(unknown)
        near_unknown[1:, :] |= unknown[:-1, :]
        near_unknown[:-1, :] |= unknown[1:, :]
        near_unknown[:, 1:] |= unknown[:, :-1]
        near_unknown[:, :-1] |= unknown[:, 1:]
        frontier = clear & near_unknown
        # drop specks: a frontier cell needs frontier cells around it
        counts = np.zeros(frontier.shape, dtype=np.int32)
        padded = np.pad(frontier.astype(np.int32), 1)
        for dr in (0, 1, 2):
            for dc in (0, 1, 2):
                counts += padded[dr : dr + frontier.shape[0], dc : dc + frontier.shape[1]]
        return np.asarray(frontier & (counts >= MIN_FRONTIER_CELLS))

    def plan(self, cells: npt.NDArray[np.int8], poses: dict[str, tuple[float, float, float]]) -> dict[str, Goal]:
        """A goal for every robot that can reach a frontier (none: it has nothing left to do)."""
        free = cells == FREE
        reach = math.ceil((self.radius_m + MARGIN_M) / self.resolution)
        clear = free & ~grow(cells == 100, reach)
        robot_cells = {ns: self._cell(x, y) for ns, (x, y, _) in poses.items()}
        frontier = self.frontiers(cells, clear)
        self.goals = {}
        taken: list[tuple[float, float]] = []
        for ns in sorted(poses):
            others = np.zeros_like(clear)
            for other, (r, c) in robot_cells.items():
                if other != ns and 0 <= r < clear.shape[0] and 0 <= c < clear.shape[1]:
                    others[r, c] = True
            passable = clear & ~grow(others, reach + 2)
            r, c = robot_cells[ns]
            start_area = grow(_one(clear.shape, r, c), reach)  # a robot near a wall may leave it
            passable |= start_area & free
            dist = wavefront(passable, (r, c))
            candidates = np.argwhere(frontier & (dist > 0))
            if candidates.size == 0:
                continue
            cost = dist[candidates[:, 0], candidates[:, 1]].astype(np.float64) * self.resolution
            for gx, gy in taken:
                px = self.origin[0] + (candidates[:, 1] + 0.5) * self.resolution
                py = self.origin[1] + (candidates[:, 0] + 0.5) * self.resolution
                cost += np.where(np.hypot(px - gx, py - gy) < SHARE_RADIUS_M, SHARE_PENALTY_M, 0.0)
            target = tuple(int(v) for v in candidates[int(np.argmin(cost))])
            path = _back(dist, (target[0], target[1]))
            ahead = max(1, round(LOOKAHEAD_M / self.resolution))
            waypoint = self._point(path[min(ahead, len(path) - 1)])
            self.goals[ns] = Goal((target[0], target[1]), waypoint)
            taken.append(self._point((target[0], target[1])))
        self.idle_rounds = 0 if self.goals else self.idle_rounds + 1
        return self.goals

    def finished(self) -> bool:
        """No robot has reached a frontier for IDLE_ROUNDS plans in a row, turning all the while."""
        return self.idle_rounds >= IDLE_ROUNDS

    def command(self, ns: str, pose: tuple[float, float, float]) -> tuple[float, float]:
        """(linear, angular) towards the robot's waypoint; stop without one."""
        goal = self.goals.get(ns)
        if goal is None:
            return (0.0, 0.0) if self.finished() else (0.0, self.max_angular * 0.5)  # look around
        x, y, yaw = pose
        wx, wy = goal.waypoint
        err = math.atan2(wy - y, wx - x) - yaw
        err = math.atan2(math.sin(err), math.cos(err))
        w = max(-self.max_angular, min(self.max_angular, 2.0 * err))
        v = self.max_linear * max(0.0, math.cos(err)) if abs(err) < 0.9 else 0.0
        return v, w


def _one(shape: tuple[int, ...], r: int, c: int) -> B:
    m = np.zeros(shape, dtype=bool)
    if 0 <= r < shape[0] and 0 <= c < shape[1]:
        m[r, c] = True
    return m


def _back(dist: I32, target: tuple[int, int]) -> list[tuple[int, int]]:
    """The path from the start (distance 0) to ``target``, walking down the wavefront."""
    path = [target]
    r, c = target
    while dist[r, c] > 0:
        d = dist[r, c]
        for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (-1, 1), (1, -1), (1, 1)):
            nr, nc = r + dr, c + dc
            if 0 <= nr < dist.shape[0] and 0 <= nc < dist.shape[1] and dist[nr, nc] == d - 1:
                r, c = nr, nc
                break
        else:
            break
        path.append((r, c))
    path.reverse()
    return path
