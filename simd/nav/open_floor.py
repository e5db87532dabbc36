"""Navigation in an open world (a world file, a map_server map): smooth paths, exclusive
claims along them, and robots of lower priority making way.

Each goal is planned on the world's costmap (A*, simd/nav/grid_search.py, then pulled straight
where the cells allow: an any-angle path, as Nav2's smoother gives), so a robot alone takes
about the shortest way. The fleet shares the floor through claims (simd/nav/claims.py): a robot
drives only as far as the cells its body will sweep are its own.

When a robot cannot go on because another holds its way:

* the other moves on: it waits (a queue);
* the other is younger (its goal is more recent), stands still and navigates: the other makes
  way, to the nearest place off the older robot's next metres (its *corridor*) that it can
  reach through free cells, and waits there until the older one has passed (priorities as in
  PIBT: the oldest goal always gets on, so a meeting in a passage one robot wide resolves);
* the other cannot make way (no such place within reach), or does not navigate (no goal, or
  somebody else drives it): after a while the waiting robot plans around it, if that is not
  much longer; failing that, an older robot that has waited long makes way itself.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from simd.core.models import RobotModel
from simd.core.worldfile import WorldGeometry
from simd.nav import grid_search, line_of_sight
from simd.nav.claims import FREE, ClaimGrid, Holder
from simd.nav.costmap import Costmap
from simd.nav.follow import PathBank

if TYPE_CHECKING:
    from simd.nav.navigator import NavRobot

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
B = npt.NDArray[np.bool_]

#: room (m) kept around each robot's circumscribed circle in the claims
MARGIN_M = 0.02
#: claims reach this far (m) ahead of the robot
CLAIM_AHEAD_M = 0.25
#: a robot making way keeps clear of this much (m) of the other's way ahead
CORRIDOR_M = 2.0
#: and looks for a place to do so this far (m) around it
REFUGE_REACH_M = 4.0
#: waiting this long (s) for a robot that does not make way, a robot plans around it
DETOUR_S = 3.0
#: a detour may be at most this much longer than the way it replaces (times, plus metres)
DETOUR_FACTOR, DETOUR_EXTRA_M = 1.5, 3.0
#: an older robot that has waited this long for one that cannot move makes way itself
GIVE_WAY_S = 6.0
#: having made way, a robot waits at most this long before it sets off again
YIELD_S = 8.0
#: obstacles a robot planned around are kept on its map this long (s)
ROBOT_MARK_S = 8.0


@dataclass(eq=False)
class Wayfarer:
    """One robot on an open floor."""

    holder: Holder
    path: F64 | None = None
    seg: int = 0
    progress: float = 0.0
    room: float = 0.0
    waited_since: float | None = None
    detour_at: float = -math.inf
    refuge: tuple[float, float] | None = None
    yield_to: int = FREE
    yield_until: float = 0.0
    around: F64 | None = None  # robots' cells it plans around for now (world points)
    around_until: float = 0.0


class OpenFloor:
    """An open world's costmap, claims, and the robots on them."""

    def __init__(self, world: WorldGeometry, costmap: Costmap) -> None:
        self.world = world
        self.costmap = costmap
        self.grid = ClaimGrid(world.bounds)
        self.robots: dict[int, Wayfarer] = {}
        self._by_slot: dict[int, NavRobot] = {}
        self._standable: dict[str, B] = {}

    def describe(self) -> str:
        g = self.costmap.grid
        return f"costmap {g.width} x {g.height} cells of {g.resolution:g} m, claims on {self.grid.cell:g} m cells"

    def refuses(self, model: RobotModel) -> str | None:
        return None

    def add(self, robot: NavRobot) -> None:
        self.robots[robot.slot] = Wayfarer(Holder(robot.slot, robot.model.radius + MARGIN_M))
        self._by_slot[robot.slot] = robot

    def remove(self, robot: NavRobot) -> None:
        w = self.robots.pop(robot.slot, None)
        self._by_slot.pop(robot.slot, None)
        if w is not None:
            self.grid.release(w.holder)

    def stand(self, robot: NavRobot, x: float, y: float) -> None:
        self.grid.stand(self.robots[robot.slot].holder, x, y)

    # -- planning --------------------------------------------------------------------------------

    def plan(self, robot: NavRobot, here: tuple[float, float], blocked: F64 | None) -> F64 | None:
        """A path from ``here`` to the robot's goal (or to the place it makes way to) around
        the map's walls, the ``blocked`` points its lidar met and the robots it plans around."""
        w = self.robots[robot.slot]
        goal = robot.goal
        assert goal is not None
        around = w.around if w.around is not None and w.around_until > robot.now else None
        target, tolerance = (w.refuge, 0.05) if w.refuge is not None else ((goal.x, goal.y), goal.tolerance)
        path = self._path(robot.model, here, target, tolerance, blocked, around, w.holder.radius)
        if path is None:
            return None
        self._follow(w, path)
        return path

    def _path(
        self,
        model: RobotModel,
        start: tuple[float, float],
        goal: tuple[float, float],
        tolerance: float,
        seen: F64 | None,
        robots: F64 | None = None,
        radius: float = 0.0,
    ) -> F64 | None:
        """A smoothed path on the costmap, around the points ``seen`` (its lidar's) and the claim
        cells (centres) ``robots`` that other robots hold (its square must not reach them)."""
        cm = self.costmap
        cost = cm.costs(model)
        blocked = []
        if seen is not None and len(seen):
            blocked.append(_disc_cells(cm, seen, model.radius + MARGIN_M))
        if robots is not None and len(robots):
            blocked.append(_square_cells(cm, robots, radius + self.grid.cell / 2))
        if blocked:
            cost = cost.copy()
            cost.reshape(-1)[np.concatenate(blocked)] = np.inf
        a = _near_free(cm, cost, start, 0.5)
        b = _near_free(cm, cost, goal, max(tolerance, cm.grid.resolution))
        if a is None or b is None:
            return None
        cells = grid_search.plan(cost, a, b, diagonal=True)
        if cells is None:
            return None
        if len(cells) > 2:
            cells = line_of_sight.smooth(np.isfinite(cost), cells)
        points = cm.grid.centres(cells)
        points[0] = start
        if cm.grid.cell(*goal) == (int(cells[-1, 0]), int(cells[-1, 1])):
            points[-1] = goal
        return _distinct(points)

    def _follow(self, w: Wayfarer, path: F64) -> None:
        w.path, w.seg, w.progress, w.room = path, 0, 0.0, 0.0
        self.grid.follow(w.holder, self.grid.path_claims(path, w.holder.radius))

    def stop(self, robot: NavRobot) -> None:
        w = self.robots.get(robot.slot)
        if w is None:
            return
        w.path, w.refuge, w.yield_to, w.waited_since = None, None, FREE, None
        self.grid.follow(w.holder, None)

    # -- deciding --------------------------------------------------------------------------------

    def decide(self, driven: list[NavRobot], now: float) -> None:
        moving = [r for r in driven if self.robots[r.slot].path is not None]
        if not moving:
            return
        ways = [self.robots[r.slot] for r in moving]
        bank = PathBank.of([w.path for w in ways if w.path is not None])
        x = np.array([r.xy[0] if r.xy else 0.0 for r in moving])
        y = np.array([r.xy[1] if r.xy else 0.0 for r in moving])
        seg, progress = bank.project(x, y, np.array([w.seg for w in ways], dtype=np.int64))
        length = bank.length()
        for k, w in enumerate(ways):
            w.seg, w.progress = int(seg[k]), float(progress[k])
        # claims in order: those making way first (they untie a knot), then the oldest goals
        order = sorted(range(len(moving)), key=lambda k: (ways[k].refuge is None, moving[k].started, moving[k].slot))
        for k in order:
            w = ways[k]
            frontier = self.grid.advance(w.holder, w.progress, CLAIM_AHEAD_M)
            w.room = max(0.0, min(frontier, float(length[k])) - w.progress)
        for k in order:
            self._sort_out(moving[k], ways[k], now)

    def _sort_out(self, robot: NavRobot, w: Wayfarer, now: float) -> None:
        """A robot held up by another: wait, have it make way, plan around it, or make way."""
        if w.refuge is not None:
            self._yield_done(robot, w, now)
            return
        other_slot = w.holder.blocked_by
        if other_slot == FREE or w.room > 0.02:
            w.waited_since = None
            return
        w.waited_since = w.waited_since if w.waited_since is not None else now
        waited = now - w.waited_since
        other = self._by_slot.get(other_slot)
        ow = self.robots.get(other_slot)
        if other is not None and ow is not None and other.active and other.planned and not other.overridden:
            if ow.refuge is None and ow.room <= 0.02 and (other.started, other.slot) > (robot.started, robot.slot):
                if self._make_way(other, ow, robot, w, now):
                    return
            if ow.refuge is not None or ow.room > 0.02:
                return  # it is on its way (or making way): wait
        if waited >= DETOUR_S and now - w.detour_at >= DETOUR_S:
            w.detour_at = now
            if self._detour(robot, w, other_slot, now):
                return
        if waited >= GIVE_WAY_S and other is not None and ow is not None and other.active:
            self._make_way(robot, w, other, ow, now)

    def _make_way(self, robot: NavRobot, w: Wayfarer, for_robot: NavRobot, fw: Wayfarer, now: float) -> bool:
        """``robot`` goes to the nearest place off ``for_robot``'s corridor, if it can reach one."""
        avoid = self.grid.corridor(fw.holder, fw.progress, CORRIDOR_M)
        here = robot.xy
        if here is None:
            return False
        spot = self._refuge(robot, w, here, avoid)
        if spot is None:
            return False
        path_cells, target = spot
        if not self.grid.clear_start(w.holder, self.grid.path_claims(path_cells, w.holder.radius), 0.15):
            return False  # it could not set off that way (too close to another robot)
        self.grid.retract(w.holder, w.progress)
        w.refuge, w.yield_to, w.yield_until = target, for_robot.slot, now + YIELD_S
        w.waited_since = None
        self._follow(w, path_cells)
        robot.recoveries += 1
        robot.making_way = True
        return True

    def _refuge(
        self, robot: NavRobot, w: Wayfarer, here: tuple[float, float], avoid: I64
    ) -> tuple[F64, tuple[float, float]] | None:
        """The nearest cell (by steps through cells nobody else holds) where the robot's body
        touches none of ``avoid``, and the straightened way there."""
        g = self.grid
        start = g.index(*here)
        if start is None:
            return None
        banned = np.zeros(g.width * g.height, dtype=bool)
        banned[avoid] = True
        passable = self.standable(robot.model) & self._clear_of_others(robot.slot, w.holder.radius)
        passable[start] = True
        parent = {start: start}
        queue = deque([start])
        steps = int(REFUGE_REACH_M / g.cell)
        found = None
        while queue and found is None:
            c = queue.popleft()
            r, q = divmod(c, g.width)
            if abs(r - start // g.width) > steps or abs(q - start % g.width) > steps:
                continue
            for rr, qq in ((r + 1, q), (r - 1, q), (r, q + 1), (r, q - 1)):
                if 0 <= rr < g.height and 0 <= qq < g.width:
                    n = rr * g.width + qq
                    if n in parent or not passable[n]:
                        continue
                    parent[n] = c
                    cx, cy = g.centre(n)
                    if not any(banned[k] for k in g.box(cx, cy, w.holder.radius)):
                        found = n
                        break
                    queue.append(n)
        if found is None:
            return None
        chain = [found]
        while chain[-1] != start:
            chain.append(parent[chain[-1]])
        chain.reverse()
        cells = np.array([divmod(c, g.width) for c in chain], dtype=np.int32)
        if len(cells) > 2:
            cells = line_of_sight.smooth(passable.reshape(g.height, g.width), cells)
        pts = np.array([g.centre(int(r) * g.width + int(q)) for r, q in cells])
        pts[0] = here
        target = g.centre(found)
        return _distinct(pts), target

    def _clear_of_others(self, slot: int, radius: float) -> B:
        """Per cell: whether a robot's square of half-side ``radius`` about the cell's centre
        touches no cell another robot holds (summed over a window of the grid)."""
        g = self.grid
        others = ((g.owner != FREE) & (g.owner != slot)).reshape(g.height, g.width).astype(np.int32)
        k = max(1, math.ceil(radius / g.cell - 0.5))
        padded = np.pad(others, k)
        integral = np.pad(padded.cumsum(0).cumsum(1), ((1, 0), (1, 0)))
        n = 2 * k + 1
        window = integral[n:, n:] - integral[:-n, n:] - integral[n:, :-n] + integral[:-n, :-n]
        clear: B = (window == 0).ravel()
        return clear

    def standable(self, model: RobotModel) -> B:
        """Per claim cell: whether the model can stand at its centre (by the costmap)."""
        s = self._standable.get(model.name)
        if s is None:
            g, cm = self.grid, self.costmap
            idx = np.arange(g.width * g.height)
            xs = g.x0 + (idx % g.width + 0.5) * g.cell
            ys = g.y0 + (idx // g.width + 0.5) * g.cell
            cg = cm.grid
            cols = np.clip(np.floor((xs - cg.x0) / cg.resolution).astype(np.int64), 0, cg.width - 1)
            rows = np.clip(np.floor((ys - cg.y0) / cg.resolution).astype(np.int64), 0, cg.height - 1)
            s = np.isfinite(cm.costs(model)[rows, cols])
            self._standable[model.name] = s
        return s

    def _detour(self, robot: NavRobot, w: Wayfarer, other_slot: int, now: float) -> bool:
        """Plan around the robot in the way (its cells, for a while); take the new path if it is
        not much longer than what is left of the old one."""
        goal = robot.goal
        here = robot.xy
        if goal is None or here is None or w.path is None:
            return False
        ow = self.robots.get(other_slot)
        if ow is None:
            return False
        cells = np.fromiter(ow.holder.held, dtype=np.int64, count=len(ow.holder.held))
        if len(cells) == 0:
            return False
        around = np.array([self.grid.centre(int(c)) for c in cells])
        path = self._path(robot.model, here, (goal.x, goal.y), goal.tolerance, robot.blocked, around, w.holder.radius)
        if path is None:
            return False
        left = max(0.0, _length(w.path) - w.progress)
        if _length(path) > DETOUR_FACTOR * left + DETOUR_EXTRA_M:
            return False
        w.around, w.around_until = around, now + ROBOT_MARK_S
        w.waited_since = None
        self._follow(w, path)
        robot.recoveries += 1
        robot.replanned = True
        return True

    def _yield_done(self, robot: NavRobot, w: Wayfarer, now: float) -> None:
        """A robot making way: once there, it waits until the other has gone by (or long
        enough), then plans again for its own goal."""
        assert w.refuge is not None
        here = robot.xy
        there = here is not None and math.hypot(w.refuge[0] - here[0], w.refuge[1] - here[1]) <= 0.08
        other = self.robots.get(w.yield_to)
        gone = other is None or other.path is None or other.holder.blocked_by != robot.slot
        stuck = not there and w.room <= 0.02 and w.holder.blocked_by != FREE
        if there and not gone and other is not None and now >= w.yield_until - YIELD_S + 1.0:
            # still in its way (it took another way since): make way again, from here
            for_robot = self._by_slot.get(w.yield_to)
            if for_robot is not None and self._make_way(robot, w, for_robot, other, now):
                return
        if (there and gone and now >= w.yield_until - YIELD_S + 1.0) or now >= w.yield_until or stuck:
            w.refuge, w.yield_to = None, FREE
            robot.making_way = False
            robot.planned = False  # the navigator plans its goal again

    # -- driving ---------------------------------------------------------------------------------

    def way(self, robot: NavRobot, x: float, y: float) -> list[tuple[float, float]]:
        """Where the robot may drive now: along its path from where it is, as far as its claims."""
        w = self.robots[robot.slot]
        if w.path is None:
            return [(x, y), (x, y)]
        path = w.path
        cum = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(path, axis=0).T))))
        end = w.progress + w.room
        j0, j1 = int(np.searchsorted(cum, w.progress, side="right")), int(np.searchsorted(cum, end, side="right"))
        pts = [(x, y)]
        pts += [(float(p[0]), float(p[1])) for p in path[j0:j1]]
        if end < cum[-1] - 1e-9:
            pts.append((float(np.interp(end, cum, path[:, 0])), float(np.interp(end, cum, path[:, 1]))))
        else:
            pts.append((float(path[-1, 0]), float(path[-1, 1])))
        return pts

    def waiting_for(self, robot: NavRobot) -> int:
        w = self.robots[robot.slot]
        return w.holder.blocked_by if w.room <= 0.02 else FREE

    def yielding(self, robot: NavRobot) -> bool:
        return self.robots[robot.slot].refuge is not None

    def intrudes(self, robot: NavRobot, x: float, y: float) -> bool:
        h = self.robots[robot.slot].holder
        cells = [c for c in self.grid.box(x, y, h.radius) if c not in h.box]
        owners = self.grid.owner[cells] if cells else np.zeros(0, np.int64)
        return bool(np.any((owners != FREE) & (owners != h.slot)))

    def owner_at(self, wx: F64, wy: F64) -> I64:
        g = self.grid
        col = np.floor((wx - g.x0) / g.cell).astype(np.int64)
        row = np.floor((wy - g.y0) / g.cell).astype(np.int64)
        on = (col >= 0) & (col < g.width) & (row >= 0) & (row < g.height)
        out = np.full(wx.shape, FREE, dtype=np.int64)
        out[on] = g.owner[row[on] * g.width + col[on]]
        return out

    def left(self, robot: NavRobot, x: float, y: float) -> float:
        w = self.robots[robot.slot]
        if w.path is None or w.refuge is not None:
            return 0.0 if robot.goal is None else math.hypot(robot.goal.x - x, robot.goal.y - y)
        return max(0.0, _length(w.path) - w.progress)


def _length(path: F64) -> float:
    return float(np.hypot(*np.diff(path, axis=0).T).sum()) if len(path) > 1 else 0.0


def _distinct(points: F64) -> F64:
    keep = np.ones(len(points), dtype=bool)
    keep[1:] = np.hypot(*np.diff(points, axis=0).T) > 1e-9
    kept = points[keep]
    return np.vstack([kept, kept]) if len(kept) == 1 else kept


def _near_free(cm: Costmap, cost: F32, xy: tuple[float, float], within: float) -> tuple[int, int] | None:
    """The costmap cell of ``xy`` if the model fits there, else the nearest one within ``within`` m."""
    g = cm.grid
    cell = g.cell(*xy)
    if cell is not None and math.isfinite(float(cost[cell])):
        return cell
    k = max(1, math.ceil(within / g.resolution))
    col = math.floor((xy[0] - g.x0) / g.resolution)
    row = math.floor((xy[1] - g.y0) / g.resolution)
    r0, r1, c0, c1 = max(0, row - k), min(g.height, row + k + 1), max(0, col - k), min(g.width, col + k + 1)
    if r0 >= r1 or c0 >= c1:
        return None
    rr, cc = np.nonzero(np.isfinite(cost[r0:r1, c0:c1]))
    if rr.size == 0:
        return None
    d2 = (g.x0 + (cc + c0 + 0.5) * g.resolution - xy[0]) ** 2 + (g.y0 + (rr + r0 + 0.5) * g.resolution - xy[1]) ** 2
    i = int(np.argmin(d2))
    if d2[i] > within * within:
        return None
    return int(rr[i] + r0), int(cc[i] + c0)


def _square_cells(cm: Costmap, centres: F64, half: float) -> I64:
    """The costmap cells (flat) whose centres lie within ``half`` of any of ``centres`` along
    both axes (where a robot's square would reach a square another robot holds)."""
    g = cm.grid
    k = math.ceil(half / g.resolution) + 1
    offs = np.arange(-k, k + 1)
    dr, dc = np.meshgrid(offs, offs, indexing="ij")
    cols = np.floor((centres[:, 0] - g.x0) / g.resolution).astype(np.int64)
    rows = np.floor((centres[:, 1] - g.y0) / g.resolution).astype(np.int64)
    rr = rows[:, None] + dr.ravel()[None, :]
    cc = cols[:, None] + dc.ravel()[None, :]
    cx = g.x0 + (cc + 0.5) * g.resolution
    cy = g.y0 + (rr + 0.5) * g.resolution
    near = (np.abs(cx - centres[:, 0:1]) < half) & (np.abs(cy - centres[:, 1:2]) < half)
    ok = near & (rr >= 0) & (rr < g.height) & (cc >= 0) & (cc < g.width)
    flat: I64 = np.unique(rr[ok] * g.width + cc[ok])
    return flat


def _disc_cells(cm: Costmap, points: F64, radius: float) -> I64:
    """The costmap cells (flat) whose centres lie within ``radius`` of any of ``points``."""
    g = cm.grid
    k = math.ceil(radius / g.resolution)
    offs = np.arange(-k, k + 1)
    dr, dc = np.meshgrid(offs, offs, indexing="ij")
    cols = np.floor((points[:, 0] - g.x0) / g.resolution).astype(np.int64)
    rows = np.floor((points[:, 1] - g.y0) / g.resolution).astype(np.int64)
    rr = rows[:, None] + dr.ravel()[None, :]
    cc = cols[:, None] + dc.ravel()[None, :]
    cx = g.x0 + (cc + 0.5) * g.resolution
    cy = g.y0 + (rr + 0.5) * g.resolution
    near = (cx - points[:, 0:1]) ** 2 + (cy - points[:, 1:2]) ** 2 <= radius * radius
    ok = near & (rr >= 0) & (rr < g.height) & (cc >= 0) & (cc < g.width)
    flat: I64 = np.unique(rr[ok] * g.width + cc[ok])
    return flat
