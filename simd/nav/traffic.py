"""Fleet traffic: robots on a graph of cells one robot wide, and who moves where next.

Why cells and priorities, rather than reciprocal avoidance: a warehouse's aisles are one robot
wide, and velocity obstacles (ORCA and kin) neither promise that two robots never touch nor get
them past each other there. Here a cell has one holder at most. A robot holds the cells under
its circle and the one or two cells it has committed to next, and it drives only into cells
it holds, so no two robots' circles ever overlap.

Who goes where next is decided cell by cell, with priority inheritance (PIBT, Okumura et al.,
AIJ 2022, the core of the League of Robot Runners' winning planners), run asynchronously as
robots reach their cells: a robot takes the free neighbour nearest its goal (by its goal's
distance field, simd/nav/cells.py); when a robot of lower priority stands in that cell, it is
*pushed*: it must move away first (it decides at once, with the pusher's priority, and may
push others), and the pusher follows it in. The robot whose goal is oldest always gets on, so
two robots that meet head on in a corridor one robot wide both arrive: the younger backs out
until it can step aside. A robot that stands still with no goal (or is driven by somebody
else's cmd_vel) is never pushed: it is an obstacle the others go around.

A cell being left by one robot may be promised to the next (``pending``), so a queue of
robots moves up without gaps; the promised robot takes the cell when the other's circle has
left it.

On an open floor a robot also looks a few seconds ahead (``forecast``): every robot with a
goal is forecast down its way at top speed, and a robot deciding its next cell takes another
than its way's best when the older goals' robots expected across the best one would hold it
up longer (prioritized planning in space and time, as in cooperative A*, but over a few cells
and re-decided every step, so a late robot only costs time, never safety: the cells still
decide who drives where).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from fleetcommon.arrays import F32
from simd.core.models import RobotModel
from simd.nav.cells import MOVES, CellGraph, body_radius

#: each move's length in cells
STEP = tuple(math.hypot(dr, dc) for dr, dc in MOVES)


FREE = -1
#: a robot commits to at most this many cells ahead of the one it stands in
AHEAD = 2
#: pushes chain at most this deep (each push is one robot made to move)
MAX_PUSH_DEPTH = 8
#: a robot that stepped aside keeps out of the cell it left this long (s of sim time)
GIVE_WAY_S = 5.0
#: the forecast (open floors): each robot's next cells this far along its way
FORECAST_CELLS = 6
#: a robot takes another next cell than its way's best only when the forecast expects it
#: there this much sooner (s): smaller margins swap choices on noise and jam more
FORECAST_MARGIN_S = 0.5


@dataclass(eq=False)
class Mover:
    """One robot in the traffic."""

    slot: int
    model: RobotModel
    radius: float
    cell: int = FREE  # the cell its centre is in (or last reached)
    route: list[int] = field(default_factory=list)  # cells committed to, next first
    #: for each route cell, every cell the step into it needs (its footprint, the side cells
    #: of a diagonal): all must be the robot's before it drives there
    needs: list[tuple[int, ...]] = field(default_factory=list)
    held: set[int] = field(default_factory=set)
    box: tuple[int, ...] = ()
    #: the goal's distance field (None: no goal, the robot is an obstacle, never pushed)
    dist: F32 | None = None
    goal_cell: int = FREE
    goal_xy: tuple[float, float] = (0.0, 0.0)
    priority: tuple[float, int] = (math.inf, 0)  # smaller goes first
    #: the robot holding the cell it would take next (it waits for it), else FREE
    waiting_for: int = FREE
    #: a robot the traffic stepped into its way; FREE if none
    crowded_by: int = FREE
    #: a cell it stepped out of to let another robot through, and until when it keeps out
    gave_way: tuple[int, float] | None = None
    #: the robot it was pushed aside for (its route is not its own choice), else FREE
    yielding_to: int = FREE
    #: since when it waits for a robot that does not navigate (floor.py plans around it)
    still_since: float | None = None
    #: where its centre was when it last stood (``stand``)
    xy: tuple[float, float] | None = None

    @property
    def pushable(self) -> bool:
        return self.dist is not None and not self.route


class Traffic:
    """The cells of one world and the robots on them (see the module docstring)."""

    def __init__(self, graph: CellGraph, ahead: int = AHEAD, forecast: bool = False) -> None:
        self.graph = graph
        self.ahead = ahead  # cells a robot commits to ahead of its own
        self.forecasting = forecast
        #: cell -> (from, until, slot, priority): when each robot's body is expected over it
        #: (rebuilt by ``forecast_round`` in a control step where robots decide)
        self.forecast: dict[int, list[tuple[float, float, int, tuple[float, int]]]] = {}
        self.forecast_at = 0.0  # the sim time the forecast starts from
        self.owner = np.full(graph.count, FREE, dtype=np.int64)
        self.pending = np.full(graph.count, FREE, dtype=np.int64)
        self.movers: dict[int, Mover] = {}
        self.decided: set[int] = set()  # the robots that decided in this control step

    # -- robots arriving and leaving --------------------------------------------------------------

    def add(self, slot: int, model: RobotModel) -> Mover:
        m = Mover(slot, model, body_radius(model))
        self.movers[slot] = m
        return m

    def remove(self, m: Mover) -> None:
        for c in list(m.held):
            self._let_go(m, c)
        for c in np.flatnonzero(self.pending == m.slot).tolist():
            self.pending[c] = FREE
        m.route.clear()
        m.needs.clear()
        self.movers.pop(m.slot, None)

    def set_goal(
        self, m: Mover, dist: F32 | None, goal_cell: int, goal_xy: tuple[float, float], priority: float
    ) -> None:
        """A new goal (its distance field), or none: the robot stops where it is headed."""
        m.dist, m.goal_cell, m.goal_xy = dist, goal_cell, goal_xy
        m.priority = (priority, m.slot)
        self._drop_route(m)

    # -- where robots stand ---------------------------------------------------------------------

    def box(self, x: float, y: float, r: float) -> tuple[int, ...]:
        """The cells (flat) that the circle of radius ``r`` about (x, y) overlaps: its bounding
        square's cells less the corner cells it misses (a robot near a cell's corner, but not
        within ``r`` of it, holds three cells where its square would take four)."""
        g = self.graph.grid
        c0 = max(0, math.floor((x - r - g.x0) / g.resolution))
        c1 = min(g.width - 1, math.floor((x + r - g.x0) / g.resolution))
        r0 = max(0, math.floor((y - r - g.y0) / g.resolution))
        r1 = min(g.height - 1, math.floor((y + r - g.y0) / g.resolution))
        res, x0, y0 = g.resolution, g.x0, g.y0
        out = []
        for row in range(r0, r1 + 1):
            ylo = y0 + row * res
            dy = max(ylo - y, 0.0, y - ylo - res)
            for col in range(c0, c1 + 1):
                xlo = x0 + col * res
                dx = max(xlo - x, 0.0, x - xlo - res)
                if dx * dx + dy * dy <= r * r:
                    out.append(row * g.width + col)
        return tuple(out)

    def stand(self, m: Mover, x: float, y: float) -> None:
        """The robot is at (x, y): it holds the cells under it (those free), reaches the next
        cell of its route when it is in it, and lets go of what it no longer needs."""
        g = self.graph
        m.xy = (x, y)
        here = g.index(x, y)
        if here is not None:
            if here in m.route:  # reached the next cell of its route (or one further: cut across)
                k = m.route.index(here)
                if all(self.owner[c] == m.slot for cells in m.needs[: k + 1] for c in cells):
                    m.cell = here
                    del m.route[: k + 1]
                    del m.needs[: k + 1]
                # else its centre is over the border of a cell it follows another into, before
                # the other has left it whole (floor.py's ``_edge``): the step is still to come
            elif m.cell == FREE or here != m.cell:
                m.cell = here  # pushed off its cells, or placed: where it is now
        box = self.box(x, y, m.radius)
        owner = self.owner
        m.crowded_by = FREE
        for c in box:
            o = owner[c]
            if o == FREE and self.pending[c] in (FREE, m.slot):
                owner[c] = m.slot
                m.held.add(c)
                if self.pending[c] == m.slot:
                    self.pending[c] = FREE
            elif o != m.slot and o != FREE:
                m.crowded_by = int(o)
        m.box = box
        self._let_go_unneeded(m)

    def needed(self, m: Mover) -> set[int]:
        """Cells the robot needs now: under it, and those of the steps it committed to."""
        need = set(m.box)
        for cells in m.needs:
            need.update(cells)
        return need

    def _let_go_unneeded(self, m: Mover) -> None:
        need = self.needed(m)
        for c in [c for c in m.held if c not in need]:
            self._let_go(m, c)

    def _let_go(self, m: Mover, c: int) -> None:
        m.held.discard(c)
        if self.owner[c] != m.slot:
            return
        self.owner[c] = FREE
        heir = int(self.pending[c])
        if heir != FREE:  # promised to the robot following: it has it now
            self.pending[c] = FREE
            follower = self.movers.get(heir)
            if follower is not None and any(c in cells for cells in follower.needs):
                self.owner[c] = heir
                follower.held.add(c)

    def _drop_route(self, m: Mover) -> None:
        for c in np.flatnonzero(self.pending == m.slot).tolist():
            self.pending[c] = FREE
        m.route.clear()
        m.needs.clear()
        m.waiting_for = FREE
        self._let_go_unneeded(m)

    # -- deciding --------------------------------------------------------------------------------

    def begin_round(self) -> None:
        """A control step starts: promises that cannot be kept are dropped, so their robots
        decide again (the robot being followed out of a cell stopped in it instead)."""
        self.decided.clear()
        for m in self.movers.values():
            for k, cells in enumerate(m.needs):
                if self._promise_broken(m, cells):
                    self._cut_route(m, k)
                    break

    def _cut_route(self, m: Mover, k: int) -> None:
        """The robot's route from its ``k``-th step on is given up: promises and cells too."""
        kept = {c for cells in m.needs[:k] for c in cells}
        for later in m.needs[k:]:
            for c in later:
                if self.pending[c] == m.slot and c not in kept:  # (a step it keeps may need it too)
                    self.pending[c] = FREE
        del m.route[k:]
        del m.needs[k:]
        self._let_go_unneeded(m)

    def _promise_broken(self, m: Mover, cells: tuple[int, ...]) -> bool:
        """Whether a cell promised to ``m`` is held by a robot that no longer leaves it, or
        that (through others) waits for ``m`` itself."""
        for c in cells:
            if self.owner[c] == m.slot or self.pending[c] != m.slot:
                continue
            holder = self.movers.get(int(self.owner[c]))
            if holder is None:
                continue
            # it keeps the cell if it stands still on it, or it will need the cell on its way
            if holder.cell == c or any(c in n for n in holder.needs) or self._follows(holder, m.slot):
                return True
        return False

    def descent(self, m: Mover, c: int, cells: int) -> list[int]:
        """Up to ``cells`` cells on from ``c`` down the robot's distance field (steepest first),
        stopping at its goal's cell."""
        assert m.dist is not None
        g, dist = self.graph, m.dist
        moves = g.moves(m.model)
        out = []
        for _ in range(cells):
            if c == m.goal_cell:
                break
            steps = (g.neighbour(c, k) for k in range(len(MOVES)) if moves[c, k])
            nxt = min(steps, key=lambda n: float(dist[n]), default=FREE)
            if nxt == FREE or float(dist[nxt]) >= float(dist[c]):
                break
            out.append(nxt)
            c = nxt
        return out

    def _timed(self, m: Mover, cells: list[int], t: float) -> list[tuple[int, float]]:
        """When the robot's centre is expected at each of ``cells`` (from its position at
        ``t``), at top speed."""
        g = self.graph
        v = m.model.max_linear_velocity
        x, y = m.xy if m.xy is not None else g.centre(cells[0])
        out = []
        for c in cells:
            cx, cy = g.centre(c)
            t += math.hypot(cx - x, cy - y) / v
            out.append((c, t))
            x, y = cx, cy
        return out

    def forecast_round(self, now: float) -> None:
        """Where every robot with a goal is expected over the next cells of its way, and
        when: from where it stands, through the cells it committed to, then down its distance
        field, at top speed (a robot that waits is expected to go on at once: forecasting it
        to stay a while longer measured no better in bench.nav_crowd)."""
        self.forecast, self.forecast_at = {}, now
        for m in self.movers.values():
            if m.dist is None or m.cell == FREE:
                continue
            path = [m.cell, *m.route]
            path += self.descent(m, path[-1], FORECAST_CELLS)
            half = self._half_crossing(m)
            for c, t in self._timed(m, path, now):
                self.forecast.setdefault(c, []).append((t - half, t + half, m.slot, m.priority))

    def _expected(self, m: Mover, n: int, frontier: int) -> float:
        """When the robot stepping from ``frontier`` into ``n`` is expected at its goal: down
        its distance field from ``n`` for a few cells at top speed, waiting at each cell an
        older goal's robot is forecast over at the same time until it has passed, then the
        way left at top speed."""
        assert m.dist is not None
        path = [frontier, n, *self.descent(m, n, FORECAST_CELLS - 1)]
        half = self._half_crossing(m)
        delay, t_last = 0.0, self.forecast_at
        for c, t in self._timed(m, path, self.forecast_at):
            t += delay
            for t0, t1, slot, priority in self.forecast.get(c, ()):
                if slot != m.slot and priority < m.priority and t0 < t + half and t - half < t1:
                    delay += t1 - (t - half)
                    t = t1 + half
            t_last = t
        return t_last + float(m.dist[path[-1]]) / m.model.max_linear_velocity

    def _half_crossing(self, m: Mover) -> float:
        """How long the robot's body is over a cell before (and after) its centre is at the
        cell's centre, at top speed."""
        return (self.graph.size / 2 + m.radius) / m.model.max_linear_velocity

    def wants_decision(self, m: Mover, near_end: bool) -> bool:
        """Whether the robot should commit to a further cell now: it has a goal, it is not at
        its goal's cell with nothing left to do, and its route is empty or (``near_end``: it
        is close to the last cell) shorter than AHEAD."""
        if m.dist is None or m.slot in self.decided:
            return False
        frontier = m.route[-1] if m.route else m.cell
        if frontier == m.goal_cell:
            return False
        return not m.route or (len(m.route) < self.ahead and near_end)

    def decide(self, m: Mover, now: float = 0.0) -> bool:
        """Commit the robot to its next cell, pushing robots of lower priority out of the way
        if need be. False when it stays (then ``waiting_for`` says who is in its way)."""
        self.decided.add(m.slot)
        m.yielding_to = FREE
        if m.gave_way is not None and m.gave_way[1] <= now:
            m.gave_way = None
        moved = self._pibt(m, m.priority, frozenset(), 0)
        if not moved and m.waiting_for != FREE and not m.route:
            moved = self._give_way(m, now)
        return moved

    def _give_way(self, m: Mover, now: float) -> bool:
        """A swap in a dead end: the robot ``m`` waits for stands still in the only way out, and
        wants ``m``'s cell. Pushing cannot help (it has nowhere else to go), so ``m`` steps
        aside into any free neighbour, and leaves its cell to the other for a while."""
        other = self.movers.get(m.waiting_for)
        if other is None or other.dist is None or other.route or m.cell == FREE or other.cell == FREE:
            return False
        theirs = [n for n in self._candidates(other, other.cell) if n != other.cell]
        if theirs != [m.cell]:
            return False  # it could go elsewhere (pushing will see to it): no dead end to untangle
        blocked = frozenset({other.cell})
        for n, k in self._moves_from(m, m.cell):
            if n in blocked or n in m.route:
                continue
            need = self.graph.sweep(m.cell, k)
            if any(self._taken(c, m) for c in need):
                continue
            gave = m.cell
            self._commit(m, n, need)
            m.gave_way = (gave, now + GIVE_WAY_S)
            return True
        return False

    def _candidates(self, m: Mover, frontier: int) -> list[int]:
        return [n for n, _ in self._moves_from(m, frontier)]

    def _moves_from(self, m: Mover, frontier: int) -> list[tuple[int, int]]:
        """The neighbours of ``frontier`` the robot may step to, best first: nearest its goal
        by the distance field, then by straight line (so ways look straight in the open)."""
        dist = m.dist
        assert dist is not None
        g = self.graph
        allowed = g.moves(m.model)[frontier]
        if not math.isfinite(float(dist[frontier])) and not g.standable(m.model)[frontier]:
            # it stands where the map's steps do not go (spawned against a wall, or pushed
            # off the centres): back to any neighbour on the way, as the crow flies
            allowed = g.inside[frontier]
        gx, gy = m.goal_xy
        found = []
        for k in range(len(MOVES)):
            if allowed[k]:
                n = g.neighbour(frontier, k)
                d = float(dist[n])
                if math.isfinite(d):
                    cx, cy = g.centre(n)
                    # the step's own length counts: by distance left alone, diagonals always
                    # win and a way goes diagonal first, then straight (a dog-leg)
                    found.append((d + STEP[k] * g.size, math.hypot(cx - gx, cy - gy), k, n))
        found.sort()
        return [(n, k) for _, _, k, n in found]

    def _pibt(self, m: Mover, rank: tuple[float, int], forbid: frozenset[int], depth: int) -> bool:
        frontier = m.route[-1] if m.route else m.cell
        if frontier == FREE or m.dist is None:
            return False
        here = float(m.dist[frontier])
        m.waiting_for = FREE
        given = m.gave_way[0] if m.gave_way is not None else FREE
        leave = frozenset((frontier,))
        moves = self._moves_from(m, frontier)
        if depth == 0 and self.forecasting and len(moves) > 1:
            # a robot deciding for itself looks a few seconds ahead: the best next cell by
            # the way alone may be one that older goals' robots are about to cross
            expected = [self._expected(m, n, frontier) for n, _ in moves]
            best = min(range(len(moves)), key=expected.__getitem__)
            if expected[best] < expected[0] - FORECAST_MARGIN_S:
                moves.insert(0, moves.pop(best))
        for n, k in moves:
            if n == m.cell or n in m.route or n == given:
                continue  # (never back over its own route, nor into a cell it gave way from)
            if float(m.dist[n]) >= here and not (leave & forbid) and depth == 0:
                continue  # no nearer: staying is as good (and nobody needs its cells); a later one may be
            need = self.graph.sweep(frontier, k)
            if n in forbid or any(c in forbid for c in need[2:]):
                continue  # where a robot pushing it must go, or stands (the side cells of a diagonal too)
            promised = {int(self.pending[c]) for c in need} - {FREE, m.slot}
            if promised:  # promised to a robot following another out of it: wait behind them
                if m.waiting_for == FREE:
                    m.waiting_for = min(promised)
                continue
            owners = {int(self.owner[c]) for c in need} - {FREE, m.slot}
            if not owners:
                self._commit(m, n, need)
                return True
            others = [self.movers.get(o) for o in owners]
            if any(o is None for o in others):
                continue
            movers = [o for o in others if o is not None]
            leaving = len(movers) == 1 and movers[0].route and not any(c in movers[0].route for c in need)
            if leaving and not self._follows(movers[0], m.slot):
                self._commit(m, n, need)  # it is on its way out of there: follow it in
                return True
            pushable = all(o.pushable and o.slot not in self.decided and o.priority > rank for o in movers)
            if depth < MAX_PUSH_DEPTH and pushable:
                pushed = True
                for o in movers:
                    self.decided.add(o.slot)
                    moved = self._pibt(o, rank, forbid | leave | set(need), depth + 1)
                    if moved:
                        o.yielding_to = m.slot
                    pushed = moved and pushed
                if pushed:
                    self._commit(m, n, need)
                    return True
            if m.waiting_for == FREE:
                m.waiting_for = movers[0].slot
        return False

    def _ahead_of(self, m: Mover) -> set[int]:
        """The robots ``m`` follows: those holding cells promised to it."""
        out = set()
        for cells in m.needs:
            for c in cells:
                if self.pending[c] == m.slot and self.owner[c] not in (FREE, m.slot):
                    out.add(int(self.owner[c]))
        return out

    def _follows(self, m: Mover, slot: int, depth: int = 12) -> bool:
        """Whether ``m`` waits, through a chain of robots each following the next out of its
        cells, for robot ``slot`` (then ``slot`` following ``m`` would close a circle in which
        everybody waits for the one ahead to leave first)."""
        seen, frontier = {m.slot}, [m]
        for _ in range(depth):
            nxt = []
            for x in frontier:
                for o in self._ahead_of(x):
                    if o == slot:
                        return True
                    if o not in seen and (mo := self.movers.get(o)) is not None:
                        seen.add(o)
                        nxt.append(mo)
            if not nxt:
                return False
            frontier = nxt
        return True  # too long a chain to tell: do not add to it

    def _taken(self, c: int, m: Mover) -> bool:
        o, p = int(self.owner[c]), int(self.pending[c])
        return (o != FREE and o != m.slot) or (p != FREE and p != m.slot)

    def _commit(self, m: Mover, n: int, need: tuple[int, ...]) -> None:
        """The robot will step into ``n``: it holds the cells of ``need`` that are free, and
        the others (robots leaving them) are promised to it."""
        m.route.append(n)
        m.needs.append(need)
        m.waiting_for = FREE
        for c in need:
            if self.owner[c] in (FREE, m.slot):
                self.owner[c] = m.slot
                m.held.add(c)
            else:
                self.pending[c] = m.slot

    # -- driving ---------------------------------------------------------------------------------

    def way(self, m: Mover) -> list[int]:
        """The route cells whose steps the robot holds whole, in order: it may drive to the
        last one."""
        out = []
        for c, cells in zip(m.route, m.needs, strict=True):
            if any(self.owner[k] != m.slot for k in cells):
                break
            out.append(c)
        return out

    def leaving(self, m: Mover, c: int) -> Mover | None:
        """The robot holding cell ``c`` that is on its way out of it, when ``c`` is promised
        to ``m`` (``m`` follows it in): its centre is elsewhere, none of its steps needs ``c``,
        and it does not wait for ``m`` (it may stand meanwhile: it will not come back, as
        ``c`` is promised). Else None."""
        if self.pending[c] != m.slot:
            return None
        holder = self.movers.get(int(self.owner[c]))
        if holder is None or holder.cell == c or any(c in n for n in holder.needs):
            return None
        return None if self._follows(holder, m.slot) else holder

    def next_leavers(self, m: Mover, k: int) -> list[Mover] | None:
        """For the robot's ``k``-th step: the robots still in its cells that are leaving them
        (``leaving``), when every other cell of the step is the robot's own; else None."""
        out = []
        for c in m.needs[k]:
            if self.owner[c] == m.slot:
                continue
            holder = self.leaving(m, c)
            if holder is None:
                return None
            out.append(holder)
        return out

    def hold_free(self, m: Mover, cells: tuple[int, ...]) -> bool:
        """Take ``cells`` if every one is free or the robot's already (all or none)."""
        if any(self._taken(c, m) for c in cells):
            return False
        for c in cells:
            self.owner[c] = m.slot
            m.held.add(c)
        return True
