"""The floor as the fleet shares it: cells one robot wide, each robot's way down its goal's
distance field, and who steps where next (simd/nav/traffic.py).

Each goal's plan is a distance field over the cells (simd/nav/cells.py); a robot commits to
the neighbour nearest its goal whenever it nears the last cell it holds, pushing robots of
lower priority out of its way (priority inheritance), and drives through the cells it holds.

On a grid map (a MovingAI warehouse) the cells are the map's own, and robots keep to the cell
centres: lanes, as warehouse robots drive. In an open world (a world file, a map_server map)
the cells are laid over it as well as they fit (simd/nav/cells.py aligns them), and a robot
cuts straight across the cells it holds wherever that line is clear of walls and of cells
other robots hold, so that it drives nearly straight lines rather than the grid's staircase.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import numpy.typing as npt

from fleetcommon.arrays import F64, I64
from fleetcommon.polyline import nearest_on
from simd.core.models import RobotModel
from simd.core.worldfile import WorldGeometry
from simd.nav.cells import CellGraph, body_radius, cell_size_for
from simd.nav.costmap import Costmap
from simd.nav.follow import ROTATE_ABOVE_RAD
from simd.nav.robot import NavRobot
from simd.nav.traffic import FREE, Mover, Traffic

#: commit to the next cell when this close (in cells) to the centre of the last one held
DECIDE_WITHIN_CELLS = 0.6
#: a goal reached short of its point (others hold cells the robot needs there) is reached
#: this much (m) inside its tolerance: what the controller may fall short of a point by
NEAR_GOAL_SPARE_M = 0.015
#: a robot waiting this long (s) for one that does not navigate plans around it ...
DETOUR_S = 3.0
#: ... and keeps it on its map this long (s)
AROUND_S = 20.0
#: in the open, a robot that waited this long (s) for another plans around it too
JAM_S = 5.0
#: a robot following another into a cell stops this far (m) short of leaving its own cell ...
EDGE_SPARE_M = 0.03
#: ... and keeps this much (m) between its body's circle and the leader's
FOLLOW_GAP_M = 0.03
#: cells a robot commits to ahead of the one it stands in (in the open: further, so that it
#: can cut straight across them)
AHEAD = 2
OPEN_AHEAD = 3
#: in the open, a robot aims at the farthest of this many cells of its way (past those it
#: holds) that it sees in a straight line, and drives that line as far as its cells allow ...
AIM_CELLS = 3
#: ... with its body this much (m) off others' cells
AIM_SPARE_M = 0.05


class Floor:
    """A world's cells, the robots on them, and the way each may drive."""

    def __init__(self, world: WorldGeometry, cell: float, costmap: Costmap | None = None) -> None:
        """On a grid map (no ``costmap``) robots keep to the cell centres; given the ``costmap``
        of an open world, they cut straight across the cells they hold where that is clear."""
        self.costmap = costmap
        self.graph = CellGraph(world, cell, align=costmap is not None, one_way=costmap is None)
        self.traffic = Traffic(self.graph, ahead=AHEAD if costmap is None else OPEN_AHEAD, forecast=costmap is not None)

    def describe(self) -> str:
        how = "in lanes" if self.costmap is None else "driven straight across"
        return f"{self.graph.width} x {self.graph.height} cells of {self.graph.size:g} m, {how}"

    def refuses(self, model: RobotModel) -> str | None:
        if self.graph.fits(model):
            return None
        return (
            f"a {model.name} needs cells of at least {cell_size_for(model):g} m and this world's are "
            f"{self.graph.size:g} m " + ("(simd --cell-size)" if self.costmap is None else "(simd --nav-cell)")
        )

    def add(self, robot: NavRobot) -> None:
        self.traffic.add(robot.slot, robot.model)

    def remove(self, robot: NavRobot) -> None:
        m = self.traffic.movers.get(robot.slot)
        if m is not None:
            self.traffic.remove(m)

    def _m(self, robot: NavRobot) -> Mover:
        return self.traffic.movers[robot.slot]

    def stand(self, robot: NavRobot, x: float, y: float) -> None:
        self.traffic.stand(self._m(robot), x, y)

    # -- planning --------------------------------------------------------------------------------

    def plan(self, robot: NavRobot, here: tuple[float, float], blocked: F64 | None) -> F64 | None:
        """The goal's distance field (with the cells holding ``blocked`` points treated as
        walls): the way the robot means to take, from where it stands, or None."""
        goal = robot.goal
        assert goal is not None
        g = self.graph
        m = self._m(robot)
        goal_cell = self._goal_cell(robot.model, goal.x, goal.y, goal.tolerance)
        if goal_cell is None:
            return None
        cells = None
        if blocked is not None and len(blocked):
            cells = np.unique(np.array([c for x, y in blocked if (c := g.index(float(x), float(y))) is not None]))
        dist = g.distances(robot.model, goal_cell, cells)
        start = m.cell if m.cell != FREE else g.index(*here)
        if start is None or not math.isfinite(self._reach(robot.model, dist, start)):
            return None
        self.traffic.set_goal(m, dist, goal_cell, (goal.x, goal.y), robot.started)
        return self._descent(robot, here)

    def _reach(self, model: RobotModel, dist: npt.NDArray[np.float32], start: int) -> float:
        """Metres from ``start`` to the goal (from a neighbour when the robot stands where its
        circle does not fit, e.g. spawned against a wall; from a cell it fits in, only along
        the steps: the corner between two walls is no way out)."""
        d = float(dist[start])
        g = self.graph
        if math.isfinite(d) or g.standable(model)[start]:
            return d
        inside = g.inside[start]
        near = [g.neighbour(start, k) for k in range(8) if inside[k]]  # not off one edge onto the other
        return min((float(dist[n]) for n in near), default=math.inf)

    def _goal_cell(self, model: RobotModel, x: float, y: float, tolerance: float) -> int | None:
        """The goal's cell, or the nearest cell the model stands in within the goal's tolerance
        plus a cell (the robot drives on to the goal point from there)."""
        g = self.graph
        stand = g.standable(model)
        c = g.index(x, y)
        if c is not None and stand[c]:
            return c
        k = max(1, math.ceil((tolerance + g.size) / g.size))
        at = g.grid.cell(x, y)
        if at is None:
            return None
        best, best_d = None, math.inf
        for dr in range(-k, k + 1):
            for dc in range(-k, k + 1):
                r, q = at[0] + dr, at[1] + dc
                if 0 <= r < g.height and 0 <= q < g.width and stand[r * g.width + q]:
                    cx, cy = g.grid.centre(r, q)
                    d = math.hypot(cx - x, cy - y)
                    if d < best_d:
                        best, best_d = r * g.width + q, d
        return best

    def path(self, robot: NavRobot, here: tuple[float, float]) -> F64:
        """The way it means to take from ``here`` on, by its current plan (what /plan shows)."""
        return self._descent(robot, here)

    def _descent(self, robot: NavRobot, here: tuple[float, float]) -> F64:
        """The way down the distance field from the robot's cell (what /plan shows)."""
        m = self._m(robot)
        g = self.graph
        dist = m.dist
        assert dist is not None and robot.goal is not None
        moves = g.moves(robot.model)
        c = m.cell if m.cell != FREE else g.index(*here)
        cells = []
        for _ in range(g.count):
            if c is None or c == FREE or c == m.goal_cell:
                break
            nxt = min((g.neighbour(c, k) for k in range(8) if moves[c, k]), key=lambda n: float(dist[n]), default=FREE)
            if nxt == FREE or float(dist[nxt]) >= float(dist[c]):
                break
            cells.append(nxt)
            c = nxt
        points = [here, *(g.centre(k) for k in cells), (robot.goal.x, robot.goal.y)]
        return _straightened(np.array(points))

    def stop(self, robot: NavRobot) -> None:
        """No goal to drive to (it ended, or a new plan is coming): it stands where it is headed."""
        m = self._m(robot)
        self.traffic.set_goal(m, None, FREE, m.goal_xy, math.inf)

    # -- deciding and driving --------------------------------------------------------------------

    def decide(self, driven: list[NavRobot], now: float) -> None:
        """Robots that near the last cell they hold commit to the next one, the oldest goal
        first; a robot that stands in its goal's cell but cannot reach the goal point for the
        robots around it goes last (as PIBT resets an agent's priority at its goal)."""
        traffic = self.traffic
        traffic.begin_round()
        size = self.graph.size
        deciding = []
        for robot in driven:
            m = self._m(robot)
            m.priority = (math.inf if robot.held_up_at_goal else robot.started, m.slot)
            near = False
            if m.route and robot.xy is not None:
                cx, cy = self.graph.centre(m.route[-1])
                near = math.hypot(cx - robot.xy[0], cy - robot.xy[1]) <= DECIDE_WITHIN_CELLS * size
            if traffic.wants_decision(m, near):
                deciding.append(m)
        if deciding and traffic.forecasting:  # (after the broken promises and the priorities of now)
            traffic.forecast_round(now)
        for m in sorted(deciding, key=lambda m: m.priority):
            if m.slot not in traffic.decided:  # pushed already this round
                traffic.decide(m, now)
        for robot in driven:
            self._around_still(robot, now)

    def _around_still(self, robot: NavRobot, now: float) -> None:
        """A robot that has waited DETOUR_S for one that does not navigate (no goal, or its
        goal ended there) plans around it, for a while: the cells it holds go on its map."""
        m = self._m(robot)
        other = self.traffic.movers.get(m.waiting_for) if not m.route else None
        if other is None:
            m.still_since = None
            return
        m.still_since = m.still_since if m.still_since is not None else now
        # one that does not navigate: after DETOUR_S; one that does but stays in the way
        # (a jam in the open, where cells are reserved but nobody moves): after JAM_S
        patience = DETOUR_S if other.dist is None else JAM_S if self.costmap is not None else math.inf
        if now - m.still_since < patience:
            return
        m.still_since = None
        cells = np.array(sorted(other.held), dtype=np.int64)
        robot.marks.append((self.graph.centres(cells), now + AROUND_S))
        robot.recoveries += 1
        robot.planned = False  # the navigator plans again, around it

    def way(self, robot: NavRobot, x: float, y: float, yaw: float | None = None) -> list[tuple[float, float]]:
        """Where the robot may drive now: along the points of the cells it holds ahead, from
        the point of that line nearest it, and in its goal's cell on to the goal point itself
        (when the cells its body needs there are free); in the open, cut straight where clear.
        A robot with nowhere to go settles into its cell's centre (see ``_settles``)."""
        traffic = self.traffic
        g = self.graph
        m = self._m(robot)
        model = robot.model
        way = traffic.way(m)
        pts = [(x, y)]
        edge = self._edge(m, way) if self.costmap is not None else None
        # (in the open, from the cell its first step starts from: one whose centre slipped back
        # over the border behind it drives on along its step, not across to the step's end)
        start = m.needs[0][0] if m.needs and self.costmap is not None else m.cell
        if way and m.cell != FREE:
            pts += _onto([g.centre(start)] + [g.centre(c) for c in way], x, y)
        elif edge is not None:
            pts += _onto([g.centre(start), edge], x, y)
        else:
            pts += [g.centre(c) for c in way]
        if edge is not None and way:
            pts.append(edge)
        last = way[-1] if way else m.cell
        robot.held_up_at_goal = False
        goal = robot.goal
        if last == m.goal_cell and goal is not None and len(way) == len(m.route):
            gx, gy = goal.x, goal.y
            if traffic.hold_free(m, traffic.box(gx, gy, m.radius)):
                pts.append((gx, gy))
            elif self.costmap is not None and (near := self._near_goal(m, g.centre(last), (gx, gy), goal.tolerance)):
                pts.append(near)  # in the open, as near the goal as the others leave room for
            elif not way:
                if self._settles(m):
                    pts.append(g.centre(last))
                robot.held_up_at_goal = True
        elif not way and edge is None and m.cell != FREE and self._settles(m):
            pts.append(g.centre(m.cell))
        aim = self.costmap is not None and way and edge is None and pts[-1] == g.centre(way[-1])
        if self.costmap is not None and len(pts) > 2:
            pts = self._pulled(m, model, pts)
        if aim:
            aimed = self._aimed(m, model, (x, y), way)
            if aimed is not None:
                # no longer than the way through the centres (it stops where it did), and never
                # a line that turns it on the spot where that way would not (measured: in a
                # crowd, the line's aim swings as others take cells, and robots turned more)
                room = sum(math.hypot(b[0] - a[0], b[1] - a[1]) for a, b in itertools.pairwise(pts))
                (ax, ay), d = aimed, math.hypot(aimed[0] - x, aimed[1] - y)
                if d > room > 0.0:
                    ax, ay = x + (ax - x) * room / d, y + (ay - y) * room / d
                if yaw is None or _off(yaw, (x, y), (ax, ay)) <= ROTATE_ABOVE_RAD \
                        or _off(yaw, (x, y), pts[1]) > ROTATE_ABOVE_RAD:  # fmt: skip
                    return [(x, y), (ax, ay)]
        return pts

    def _aimed(
        self, m: Mover, model: RobotModel, here: tuple[float, float], way: list[int]
    ) -> tuple[float, float] | None:
        """Where a robot driving a straight line towards the farthest point of its way (down
        its distance field, AIM_CELLS past the cells it holds) that it sees clear of walls may
        stop: the farthest point of that line in the last cell it holds, reached with its body
        (and AIM_SPARE_M) over its own or free cells only. Where others' cells cut the line to
        a point, the line to a nearer one; None if none reaches that cell so. Alone, a robot
        then drives nearly straight lines rather than through cell centres (a lone burger in
        turtlebot3_world: 1.196 -> 1.140 of the straight-line bound, bench.nav_crowd; ten: 1.364 -> 1.353)."""
        assert self.costmap is not None and m.dist is not None
        g = self.graph
        need = body_radius(model)
        cells = self.traffic.descent(m, way[-1], AIM_CELLS)
        ahead = [g.centre(c) for c in [way[-1], *cells]]
        if (cells[-1] if cells else way[-1]) == m.goal_cell and len(cells) < AIM_CELLS:
            ahead.append(m.goal_xy)
        x, y = here
        for tx, ty in reversed(ahead):
            if math.hypot(tx - x, ty - y) < 1e-6:
                return None
            line = self._clear_line(here, (tx, ty), need, 0.02)
            if line is None:
                continue
            best = None
            for a, b in zip(*line, strict=True):
                if not self._crossable(m, self.traffic.box(a, b, m.radius + AIM_SPARE_M)):
                    break
                if g.index(a, b) == way[-1]:
                    best = (a, b)
                elif best is not None:
                    break
            if best is not None:
                return best
        return None

    def _crossable(self, m: Mover, cells: tuple[int, ...]) -> bool:
        """Whether every one of ``cells`` is the robot's or free (and promised to nobody else)."""
        traffic = self.traffic
        return all(int(traffic.owner[c]) in (FREE, m.slot) and int(traffic.pending[c]) in (FREE, m.slot) for c in cells)

    def _edge(self, m: Mover, way: list[int]) -> tuple[float, float] | None:
        """Where a robot following others out of the cells of its next step may drive before
        those cells are its own: on towards them, up to where its centre would leave the last
        cell it holds, and no nearer the leaders than their two circles and FOLLOW_GAP_M. Its
        claim is unchanged (the cells become its own as the leaders' bodies leave them whole);
        only it stands at the border, at speed, instead of at its own cell's centre. None when
        the next step's cells are not all its own or promised to it by robots on their way
        out."""
        k = len(way)
        if k >= len(m.route):
            return None
        frm = m.needs[k][0]  # the cell the step starts from
        leavers = self.traffic.next_leavers(m, k)
        if not leavers:
            return None
        g = self.graph
        (ax, ay), (bx, by) = g.centre(frm), g.centre(m.route[k])
        step = math.hypot(bx - ax, by - ay)
        t = 0.5 - EDGE_SPARE_M / step  # (the segment between two neighbours' centres leaves the first halfway)
        while t > 0.0:
            px, py = ax + t * (bx - ax), ay + t * (by - ay)
            if all(o.xy is None or math.hypot(o.xy[0] - px, o.xy[1] - py) >= m.radius + o.radius + FOLLOW_GAP_M
                   for o in leavers):  # fmt: skip
                return (px, py)
            t -= 0.02 / step
        return None

    def _near_goal(
        self, m: Mover, start: tuple[float, float], goal: tuple[float, float], tolerance: float
    ) -> tuple[float, float] | None:
        """When others hold cells the robot's body needs at the goal point: the point nearest
        the goal, on the line to it from ``start``, within the goal's tolerance (NEAR_GOAL_SPARE_M
        to spare for tracking), whose
        cells it can take (it takes them), or None. A goal within reach is reached, rather than
        waited for until the others leave (measured: a fifth more goals reached per hour by
        ten burgers in turtlebot3_world, and a shorter tail)."""
        traffic = self.traffic
        (sx, sy), (gx, gy) = start, goal
        d = math.hypot(gx - sx, gy - sy)
        for back in np.arange(0.02, tolerance - NEAR_GOAL_SPARE_M, 0.01).tolist():
            if back >= d:
                break
            t = 1.0 - back / d
            x, y = sx + t * (gx - sx), sy + t * (gy - sy)
            if traffic.hold_free(m, traffic.box(x, y, m.radius)):
                return (x, y)
        return None

    def _settles(self, m: Mover) -> bool:
        """Whether a robot with nowhere to go drives to its cell's centre. In lanes, always:
        robots keep to the centres there (more goals ended ``blocked`` in the 100-robot
        warehouse when they did not). In the open only while its body reaches into a
        neighbouring cell: a few centimetres are not worth turning round for, and back."""
        return self.costmap is None or len(m.box) > 1

    def _pulled(self, m: Mover, model: RobotModel, pts: list[tuple[float, float]]) -> list[tuple[float, float]]:
        """The way cut straight to the farthest of its points that the robot reaches on a
        straight line clear of walls and of cells other robots hold (it holds them as it goes)."""
        traffic = self.traffic
        need = body_radius(model)
        for j in range(len(pts) - 1, 1, -1):
            line = self._clear_line(pts[0], pts[j], need, 0.05)
            if line is None:
                continue
            if not any(self._others(m, traffic.box(a, b, m.radius)) for a, b in zip(*line, strict=True)):
                return [pts[0], *pts[j:]]
        return pts

    def _clear_line(
        self, start: tuple[float, float], end: tuple[float, float], need: float, step: float
    ) -> tuple[list[float], list[float]] | None:
        """The points every ``step`` (m) of the straight line from ``start`` to ``end``, if it
        stays on the map with ``need`` (m) of clearance from walls past its start; else None."""
        assert self.costmap is not None
        grid, clearance = self.costmap.grid, self.costmap.clearance
        (x, y), (tx, ty) = start, end
        ts = np.linspace(0.0, 1.0, max(2, math.ceil(math.hypot(tx - x, ty - y) / step) + 1))
        xs, ys = x + ts * (tx - x), y + ts * (ty - y)
        col = np.floor((xs - grid.x0) / grid.resolution).astype(np.int64)[1:]
        row = np.floor((ys - grid.y0) / grid.resolution).astype(np.int64)[1:]
        on = (col >= 0) & (col < grid.width) & (row >= 0) & (row < grid.height)
        if not on.all() or (clearance[row, col] < need).any():
            return None
        return xs.tolist(), ys.tolist()

    def _others(self, m: Mover, cells: tuple[int, ...]) -> bool:
        owner = self.traffic.owner
        return any(int(owner[c]) not in (FREE, m.slot) for c in cells)

    def waiting_for(self, robot: NavRobot) -> int:
        """The robot it waits for: the one holding the cell it would take next; once it has
        taken its next step, the one still leaving a cell of that step (it follows it out:
        until then it stands); in its goal's cell, one holding the goal point's. FREE if none."""
        m = self._m(robot)
        owner = self.traffic.owner
        if robot.held_up_at_goal and robot.goal is not None:  # in its goal's cell, the goal point's taken
            return next((o for c in self.traffic.box(robot.goal.x, robot.goal.y, m.radius)
                         if (o := int(owner[c])) not in (FREE, m.slot)), m.waiting_for)  # fmt: skip
        if not m.route:
            return m.waiting_for
        for c in m.needs[0]:
            o = int(owner[c])
            if o not in (FREE, m.slot):
                return o
        return FREE

    def yielding(self, robot: NavRobot) -> int:
        """The robot it moves aside for (pushed out of its way), else FREE."""
        m = self._m(robot)
        return m.yielding_to if m.route else FREE

    def intrudes(self, robot: NavRobot, x: float, y: float) -> bool:
        """Whether the robot's body at (x, y) would reach into a cell another robot holds that
        it does not reach into already (but for a cell promised to it that its holder is
        leaving: ``_edge``; the guard on the two bodies, guards.too_close, stays)."""
        m = self._m(robot)
        traffic = self.traffic
        for c in traffic.box(x, y, m.radius):
            if c in m.box:
                continue
            o = int(traffic.owner[c])
            if o not in (FREE, m.slot) and (self.costmap is None or traffic.leaving(m, c) is None):
                return True
        return False

    def owner_at(self, wx: F64, wy: F64) -> I64:
        """The holder of each world point's cell (FREE off the floor)."""
        g = self.graph.grid
        col = np.floor((wx - g.x0) / g.resolution).astype(np.int64)
        row = np.floor((wy - g.y0) / g.resolution).astype(np.int64)
        on = (col >= 0) & (col < g.width) & (row >= 0) & (row < g.height)
        out = np.full(wx.shape, FREE, dtype=np.int64)
        out[on] = self.traffic.owner[row[on] * g.width + col[on]]
        return out

    def left(self, robot: NavRobot, x: float, y: float) -> float:
        """Metres left to the goal (down its distance field)."""
        m = self._m(robot)
        if m.dist is None or robot.goal is None:
            return 0.0
        g = self.graph
        c = g.index(x, y)
        if c is None or not math.isfinite(float(m.dist[c])):
            return math.hypot(robot.goal.x - x, robot.goal.y - y)
        gx, gy = g.centre(m.goal_cell)
        return float(m.dist[c]) + math.hypot(robot.goal.x - gx, robot.goal.y - gy)


def _off(yaw: float, here: tuple[float, float], to: tuple[float, float]) -> float:
    """How far (rad) the direction from ``here`` to ``to`` is off heading ``yaw``."""
    if math.hypot(to[0] - here[0], to[1] - here[1]) < 1e-6:
        return 0.0
    return abs(math.remainder(math.atan2(to[1] - here[1], to[0] - here[0]) - yaw, 2 * math.pi))


def _onto(line: list[tuple[float, float]], x: float, y: float) -> list[tuple[float, float]]:
    """The rest of polyline ``line`` from the point on it nearest (x, y): where a robot that
    strayed or cut a corner joins its way again (the later of two equally near segments)."""
    best, at, k_best = nearest_on(line, x, y)
    rest = line[k_best + 1 :]
    return ([at] if best > 0.01 or not rest else []) + rest


def _straightened(points: F64) -> F64:
    """A polyline with its collinear middle points left out (a cell path's straight runs)."""
    if len(points) < 3:
        return points
    d = np.diff(points, axis=0)
    cross = d[:-1, 0] * d[1:, 1] - d[:-1, 1] * d[1:, 0]
    keep = np.concatenate(([True], np.abs(cross) > 1e-9, [True]))
    kept: F64 = points[keep]
    return kept
