"""The navigator: every robot's goal, driven tick by tick on the simulation's own thread.

Why inside the daemon, on the simulation thread (docs/navigation.md has the measurements):
the navigator reads the true poses and the scans where they are made and writes commands into
the robot table, with no message in between (a thousand robots' commands would otherwise be
ten thousand zenoh messages a second each way), and it runs in tick order, so a stepped
(lockstep) run navigates the same way every time for a seed.

Every tick it re-applies each navigating robot's command (an idle teleop's zeros never stop a
robot on its way); every ``control_every`` ticks (10 Hz) it does the work:

1. every robot holds the cells under it (simd/nav/traffic.py), goal or not;
2. the scans since the last step give each robot's room ahead (lidar_guard.py): the first
   thing the map and the traffic do not explain stops it, and if that lasts, it marks what it
   sees as blocked and plans again;
3. robots with a new goal get its distance field (cells.py), a few per step;
4. robots that reached a cell commit to the next, in order of priority, pushing robots of
   lower priority out of their way (traffic.py);
5. each drives along the cells it holds (follow.py), and goals that are reached, timed out or
   stuck end.
"""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Callable
from dataclasses import dataclass, field

import msgspec
import numpy as np
import numpy.typing as npt

from protocol.errors import ErrorCode, FleetError
from protocol.messages import Time
from protocol.navigation import (
    ACTIVE_STATES,
    MAX_GOAL_ID_LENGTH,
    FleetNavigation,
    NavigateReply,
    NavigateRequest,
    NavigationFeedback,
    NavigationResult,
    NavigationState,
)
from simd.core.lidar import LidarSpec
from simd.core.models import MODELS, RobotModel
from simd.core.robots import RobotTable
from simd.core.snapshot import TickSnapshot
from simd.core.worldfile import WorldGeometry
from simd.nav.cells import CellGraph, cell_size_for
from simd.nav.costmap import Costmap, Grid
from simd.nav.follow import LOOKAHEAD_M, Limits, along, pursue, turn_to
from simd.nav.lidar_guard import LOOK_AHEAD_M, LidarGuard
from simd.nav.report import NavEvents, goal_pose, path_message, pose, summary_row
from simd.nav.traffic import FREE, Mover, Traffic

log = logging.getLogger(__name__)

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

__all__ = ["NavConfig", "NavEvents", "Navigator"]

GOAL_ID = re.compile(r"[A-Za-z0-9_.:-]+")
#: the largest goal tolerance accepted (m)
MAX_TOLERANCE_M = 100.0
#: an outside cmd_vel other than zero drives a navigating robot for this long (s of sim time)
OVERRIDE_S = 0.5
#: stop this far (m) before something the lidar sees that the map and the traffic do not explain
LIDAR_STOP_M = 0.06
#: a lidar hit this close (m) to a wall or obstacle of the map is that wall
MAP_HIT_M = 0.05
#: a robot its lidar holds up this long marks what it sees as blocked and plans around it
BLOCKED_REPLAN_S = 2.0
#: ... and forgets those marks after this long (the box may have gone)
MARK_S = 30.0
#: a robot that has had no way forward this long fails with ``blocked`` (s of sim time)
PATIENCE_S = 120.0
#: commit to the next cell when this close (in cells) to the centre of the last one held
DECIDE_WITHIN_CELLS = 0.6
#: a step in which the robot's body would enter a cell another robot holds is not taken
GUARD_S = 0.1
import os
OPEN_AHEAD = int(os.environ.get("NAV_AHEAD", "3"))


@dataclass(frozen=True)
class NavConfig:
    """How the navigator works. ``cell``: the side of the traffic's cells (None: the smallest
    a burger fits in, or the largest model navigating); ``lanes``: the world is a grid map
    (MovingAI) whose cells are ``cell`` and drive from cell centre to cell centre."""

    cell: float | None = None
    lanes: bool = False
    control_every: int = 3
    plans_per_step: int = 8
    feedback_every: int = 6
    fleet_every: int = 15
    patience: float = PATIENCE_S


@dataclass(eq=False)
class NavRobot:
    """One robot as the navigator knows it (every robot of the world has one)."""

    namespace: str
    model: RobotModel
    mover: Mover
    goal: NavigateRequest | None = None
    goal_id: str = ""
    state: str = ""  # "" before its first goal; else an ACTIVE state, "reached" or "failed"
    started: float = 0.0
    planned: bool = False  # its goal's distance field is made
    lidar_room: float = LOOK_AHEAD_M
    lidar_yaw: float = 0.0  # heading when that room was measured
    lidar_hits: F64 = field(default_factory=lambda: np.zeros((0, 2)))  # what it saw ahead (world frame)
    blocked_since: float | None = None
    stuck_since: float | None = None
    marks: list[tuple[I64, float]] = field(default_factory=list)  # cells blocked for it, until
    recoveries: int = 0
    travelled: float = 0.0
    last_xy: tuple[float, float] | None = None
    command: tuple[float, float] = (0.0, 0.0)
    overridden_until: float = -math.inf
    result: NavigationResult | None = None
    feedback: NavigationFeedback | None = None
    ended: str = ""  # how its goal ended, for the next fleet summary
    held_up_at_goal: bool = False  # in its goal's cell, the goal point's cells held by others

    @property
    def active(self) -> bool:
        return self.state in ACTIVE_STATES


class Navigator:
    """Goals for the robots of one simulation (see the module docstring)."""

    def __init__(
        self, world: WorldGeometry, lidar: LidarSpec, table: RobotTable, config: NavConfig | None = None
    ) -> None:
        self.world = world
        self.table = table  # the simulation's robot table, read on its thread only
        self.config = config or NavConfig()
        self._guard = LidarGuard(lidar)
        self._costmap: Costmap | None = None
        self._traffic: Traffic | None = None
        self.robots: dict[str, NavRobot] = {}
        self._next_slot = 0
        self._goal_counter = 0
        self._rows_of: list[str] | None = None
        self._row: dict[str, int] = {}
        self._snaps: list[TickSnapshot] = []
        self._events = NavEvents()
        self._drive_of: list[str] | None = None
        self._drive: tuple[I64, F64, F64] = (np.zeros(0, np.int64), np.zeros(0), np.zeros(0))
        self._stopping: list[str] = []
        self._now = 0.0

    # -- the world as navigation sees it (built when the first goal comes) -----------------------

    @property
    def costmap(self) -> Costmap:
        """The world's clearances at 5 cm: where a goal may be."""
        if self._costmap is None:
            self._costmap = Costmap(self.world, Grid.covering(self.world))
        return self._costmap

    @property
    def traffic(self) -> Traffic:
        if self._traffic is None:
            widest = [cell_size_for(MODELS["burger"])] + [cell_size_for(r.model) for r in self.robots.values()]
            size = self.config.cell or max(widest)
            graph = CellGraph(self.world, size)
            log.info("navigation: %d x %d cells of %.3g m", graph.width, graph.height, size)
            # in the open, robots commit further ahead: their ways are cut straight across cells
            self._traffic = Traffic(graph, ahead=2 if self.config.lanes else OPEN_AHEAD)
            for robot in self.robots.values():
                robot.mover = self._traffic.add(robot.mover.slot, robot.model)
        return self._traffic

    @property
    def busy(self) -> bool:
        """Whether some robot has an active goal (else a tick costs the navigator nothing)."""
        return any(r.active for r in self.robots.values())

    # -- requests (simulation thread) ------------------------------------------------------------

    def goal(self, namespace: str, model: RobotModel, req: NavigateRequest, now: float) -> NavigateReply:
        """Accept a goal for the robot, or raise FleetError and change nothing."""
        self._now = now
        _check_goal(req)
        x_min, x_max, y_min, y_max = self.world.bounds
        if not (x_min <= req.x <= x_max and y_min <= req.y <= y_max):
            raise FleetError(
                ErrorCode.OUT_OF_BOUNDS,
                f"goal ({req.x:g}, {req.y:g}) is off the map of {self.world.name!r}: "
                f"x in [{x_min:g}, {x_max:g}], y in [{y_min:g}, {y_max:g}]",
                "x",
            )
        clearance = self.costmap.clearance_at(req.x, req.y)
        if clearance is not None and clearance < model.radius:
            raise FleetError(
                ErrorCode.COLLISION,
                f"a {model.name} at the goal ({req.x:g}, {req.y:g}) would overlap a wall or obstacle",
                "x",
            )
        self._sync(self.table)
        if not self.traffic.graph.fits(model) and not self.config.cell and not self.busy:
            self._traffic = None  # laid out for smaller robots: again, for this one too
            for r in self.robots.values():
                r.mover = Mover(r.mover.slot, r.model, 0.0)
        graph = self.traffic.graph
        if not graph.fits(model):
            raise FleetError(
                ErrorCode.INVALID_VALUE,
                f"a {model.name} needs navigation cells of at least {cell_size_for(model):g} m and this daemon's are "
                f"{graph.size:g} m"
                + (
                    " (simd --cell-size)"
                    if self.config.lanes
                    else ": send it when the others are done, or start simd with --nav-cell"
                ),
                "robot",
            )
        robot = self._robot(namespace, model)
        preempted = ""
        if robot.active:
            preempted = robot.goal_id
            self._end(robot, "failed", "preempted", f"goal {robot.goal_id} was replaced by a newer goal", now)
        if req.goal_id:
            goal_id = req.goal_id
        else:
            self._goal_counter += 1
            goal_id = f"{namespace}-{self._goal_counter}"
        robot.goal, robot.goal_id, robot.state, robot.started = req, goal_id, "planning", now
        robot.planned, robot.marks, robot.recoveries, robot.travelled = False, [], 0, 0.0
        robot.blocked_since = robot.stuck_since = None
        robot.result = robot.feedback = None
        robot.command, robot.overridden_until, robot.last_xy = (0.0, 0.0), -math.inf, None
        self.traffic.set_goal(robot.mover, None, FREE, (req.x, req.y), now)
        self._drive_of = None
        return NavigateReply(goal_id=goal_id, robot=namespace, goal=goal_pose(req), preempted=preempted,
                             stamp=Time.from_seconds(now))  # fmt: skip

    def cancel(self, namespace: str, goal_id: str, now: float) -> NavigationResult:
        robot = self.robots.get(namespace)
        if robot is None or not robot.active:
            raise FleetError(ErrorCode.NOT_FOUND, f"robot {namespace!r} has no goal to cancel", "goal_id")
        if goal_id and goal_id != robot.goal_id:
            raise FleetError(
                ErrorCode.NOT_FOUND, f"robot {namespace!r} is on goal {robot.goal_id!r}, not {goal_id!r}", "goal_id"
            )
        return self._end(robot, "failed", "cancelled", "cancelled on request", now)

    def state(self, namespace: str) -> NavigationState:
        robot = self.robots.get(namespace)
        if robot is None or robot.goal is None:
            return NavigationState(robot=namespace)
        return NavigationState(robot=namespace, goal_id=robot.goal_id, goal=robot.goal, active=robot.active,
                               feedback=robot.feedback if robot.active else None, result=robot.result)  # fmt: skip

    def deleted(self, namespace: str, now: float) -> None:
        """The robot left the world: its goal fails (``robot_gone``), its cells are free."""
        robot = self.robots.pop(namespace, None)
        if robot is None:
            return
        if robot.active:
            self._end(robot, "failed", "robot_gone", f"robot {namespace!r} was deleted", now)
        if self._traffic is not None:
            self._traffic.remove(robot.mover)
        self._rows_of = self._drive_of = None

    def reset(self, now: float) -> None:
        """The world was reset (robots back at their spawn poses): goals end, cells are free."""
        for robot in self.robots.values():
            if robot.active:
                self._end(robot, "failed", "cancelled", "the simulation was reset", now)
            if self._traffic is not None:
                self._traffic.remove(robot.mover)
                robot.mover = self._traffic.add(robot.mover.slot, robot.model)
        self._snaps.clear()
        self._rows_of = self._drive_of = None

    def goals(self) -> list[NavigateRequest]:
        """The active goals, each with its robot and id (what a state file keeps)."""
        return [
            msgspec.structs.replace(r.goal, robot=r.namespace, goal_id=r.goal_id)
            for r in self.robots.values()
            if r.active and r.goal is not None
        ]

    # -- commands (simulation thread, every tick) -------------------------------------------------

    def filter_commands(self, commands: dict[str, tuple[float, float]], now: float) -> dict[str, tuple[float, float]]:
        """Outside commands for navigating robots: a zero one is dropped (an idle teleop never
        stops a robot on its way), any other drives the robot for OVERRIDE_S instead of the
        navigator (as twist_mux gives a joystick priority over Nav2)."""
        if not commands or not self.robots:
            return commands
        out = commands
        for ns, (v, w) in commands.items():
            robot = self.robots.get(ns)
            if robot is None or not robot.active:
                continue
            if v == 0.0 and w == 0.0:
                if out is commands:
                    out = dict(commands)
                del out[ns]
            else:
                self._override(robot, now)
        return out

    def overridden_by_step(self, namespaces: list[str], v: F64, w: F64, now: float) -> None:
        """A lockstep step's commands: those other than zero override as cmd_vel does."""
        for k in np.flatnonzero((v != 0.0) | (w != 0.0)).tolist():
            robot = self.robots.get(namespaces[k])
            if robot is not None and robot.active:
                self._override(robot, now)

    def _override(self, robot: NavRobot, now: float) -> None:
        if robot.overridden_until < now:
            self._drive_of = None
        robot.overridden_until = now + OVERRIDE_S

    def apply(self, table: RobotTable, command_rows: Callable[[I64, F64, F64], None]) -> None:
        """Every tick: each navigating robot's latest command unless somebody overrides it; a
        robot whose goal just ended is told to stop, once."""
        if self._stopping:
            stop = [r for ns in self._stopping if (r := table.row_of(ns)) is not None]
            self._stopping = []
            if stop:
                zero = np.zeros(len(stop))
                command_rows(np.array(stop, dtype=np.int64), zero, zero)
        if self._drive_of is not table.namespaces:
            driven = [r for r in self.robots.values() if r.active and r.overridden_until < self._now]
            found = [table.row_of(r.namespace) for r in driven]
            keep = [k for k, row in enumerate(found) if row is not None]
            self._drive = (
                np.array([found[k] for k in keep], dtype=np.int64),
                np.array([driven[k].command[0] for k in keep]),
                np.array([driven[k].command[1] for k in keep]),
            )
            self._drive_of = table.namespaces
        if len(self._drive[0]):
            command_rows(*self._drive)

    def observe(self, snapshot: TickSnapshot) -> None:
        """A tick ran: its scans are read at the next control step (the lidar may still cast them)."""
        if self.busy:
            self._snaps.append(snapshot)

    def take_events(self) -> NavEvents:
        ev, self._events = self._events, NavEvents()
        return ev

    # -- the control step -------------------------------------------------------------------------

    def step(self, table: RobotTable, tick: int, now: float) -> None:
        """Before the tick ``tick`` runs: the work every ``control_every`` ticks, feedback and
        the fleet's summary on their own schedules."""
        self._now = now
        cfg = self.config
        if not self.robots:
            return
        busy = self.busy
        if busy and tick % cfg.control_every == 0:
            self._control(table, now)
            self._drive_of = None
        if busy and tick % cfg.feedback_every == 0:
            self._feedback(table, now)
        if tick % cfg.fleet_every == 0:
            self._fleet_summary(now)

    def _sync(self, table: RobotTable) -> None:
        """Know every robot of the table, and the row of each (the table changed)."""
        if self._rows_of is table.namespaces:
            return
        present = set(table.namespaces)
        for ns in [ns for ns in self.robots if ns not in present]:
            self.deleted(ns, self._now)
        for info in table.robots:
            self._robot(info.namespace, info.model)
        self._row = {ns: i for i, ns in enumerate(table.namespaces)}
        self._rows_of = table.namespaces

    def _robot(self, namespace: str, model: RobotModel) -> NavRobot:
        robot = self.robots.get(namespace)
        if robot is None:
            slot = self._next_slot
            self._next_slot += 1
            mover = self.traffic.add(slot, model) if self._traffic is not None else Mover(slot, model, 0.0)
            robot = NavRobot(namespace, model, mover)
            self.robots[namespace] = robot
        return robot

    def _control(self, table: RobotTable, now: float) -> None:
        self._sync(table)
        traffic = self.traffic
        xs, ys = table.x, table.y
        row = self._row
        for robot in self.robots.values():
            i = row[robot.namespace]
            x, y = float(xs[i]), float(ys[i])
            traffic.stand(robot.mover, x, y)
            if robot.active:
                if robot.last_xy is not None:
                    robot.travelled += math.hypot(x - robot.last_xy[0], y - robot.last_xy[1])
                robot.last_xy = (x, y)
        self._read_scans()
        self._plan_some(now)
        self._decide(table)
        driven = [r for r in self.robots.values() if r.active and r.planned]
        if driven:
            self._drive_robots(driven, table, now)
        self._check_goals(table, now)

    # -- planning --------------------------------------------------------------------------------

    def _plan_some(self, now: float) -> None:
        budget = self.config.plans_per_step
        for robot in self.robots.values():
            if budget <= 0:
                break
            if robot.goal is None or not robot.active or robot.planned:
                continue
            budget -= 1
            self._plan(robot, now)

    def _plan(self, robot: NavRobot, now: float) -> None:
        """Its goal's distance field, with what it marked as blocked; or the goal ends."""
        goal = robot.goal
        assert goal is not None
        traffic = self.traffic
        graph = traffic.graph
        robot.marks = [(cells, until) for cells, until in robot.marks if until > now]
        blocked = np.unique(np.concatenate([c for c, _ in robot.marks])) if robot.marks else None
        goal_cell = self._goal_cell(robot.model, goal)
        m = robot.mover
        dist = None if goal_cell is None else graph.distances(robot.model, goal_cell, blocked)
        start = m.cell if m.cell != FREE else graph.index(*self._xy(robot))
        reach = math.inf if dist is None or start is None else self._reach(dist, robot.model, start)
        if not math.isfinite(reach):
            if robot.marks:  # what it saw may be in the way for good, or may go: wait and see
                robot.state, robot.planned = "blocked", False
                robot.stuck_since = robot.stuck_since if robot.stuck_since is not None else now
                return
            here = self._xy(robot)
            why = f"no {robot.model.name} fits at the goal" if goal_cell is None else "nothing connects them"
            where = f"from ({here[0]:.2f}, {here[1]:.2f}) to ({goal.x:g}, {goal.y:g})"
            self._end(robot, "failed", "no_path", f"no path for a {robot.model.name} {where}: {why}", now)
            return
        assert dist is not None and goal_cell is not None
        traffic.set_goal(m, dist, goal_cell, (goal.x, goal.y), robot.started)
        robot.planned, robot.state = True, "driving"
        self._tell_path(robot, now)

    def _reach(self, dist: F32, model: RobotModel, start: int) -> float:
        """Metres from ``start`` to the goal (from a standable neighbour when the robot stands
        where its circle does not fit, e.g. spawned against a wall)."""
        d = float(dist[start])
        if math.isfinite(d):
            return d
        g = self.traffic.graph
        near = [g.neighbour(start, k) for k in range(8)]
        return min((float(dist[n]) for n in near if 0 <= n < g.count), default=math.inf)

    def _goal_cell(self, model: RobotModel, goal: NavigateRequest) -> int | None:
        """The goal's cell, or the nearest cell the model stands in within the goal's
        tolerance plus a cell (the robot then drives to the goal point from there)."""
        g = self.traffic.graph
        stand = g.standable(model)
        c = g.index(goal.x, goal.y)
        if c is not None and stand[c]:
            return c
        k = max(1, math.ceil((goal.tolerance + g.size) / g.size))
        gc = g.grid.cell(goal.x, goal.y)
        if gc is None:
            return None
        best, best_d = None, math.inf
        for dr in range(-k, k + 1):
            for dc in range(-k, k + 1):
                r, q = gc[0] + dr, gc[1] + dc
                if 0 <= r < g.height and 0 <= q < g.width and stand[r * g.width + q]:
                    cx, cy = g.grid.centre(r, q)
                    d = math.hypot(cx - goal.x, cy - goal.y)
                    if d < best_d:
                        best, best_d = r * g.width + q, d
        return best

    def _tell_path(self, robot: NavRobot, now: float) -> None:
        """The way the robot means to take, from where it is: down its distance field."""
        m = robot.mover
        graph = self.traffic.graph
        if m.dist is None:
            return
        cells = [m.cell] if m.cell != FREE else []
        c = m.cell
        dist = m.dist
        moves = graph.moves(robot.model)
        for _ in range(graph.count):
            if c == FREE or c == m.goal_cell:
                break
            best = min(
                (graph.neighbour(c, k) for k in range(8) if moves[c, k]),
                key=lambda n: float(dist[n]),
                default=FREE,
            )
            if best == FREE or float(dist[best]) >= float(dist[c]):
                break
            cells.append(best)
            c = best
        points = [self._xy(robot)] + [graph.centre(k) for k in cells[1:]]
        goal = robot.goal
        assert goal is not None
        points.append((goal.x, goal.y))
        pts = _straightened(np.array(points))
        self._events.plans.append(path_message(robot.goal_id, robot.namespace, now, pts))

    # -- traffic ---------------------------------------------------------------------------------

    def _decide(self, table: RobotTable) -> None:
        traffic = self.traffic
        traffic.begin_round()
        size = traffic.graph.size
        deciding = []
        for robot in self.robots.values():
            if not (robot.active and robot.planned) or robot.overridden_until >= self._now:
                continue
            m = robot.mover
            # the oldest goal goes first; a robot that stands in its goal's cell but cannot
            # reach the goal point for the robots around it goes last (as PIBT resets an
            # agent's priority at its goal): it may be pushed out, and comes back
            m.priority = (math.inf if robot.held_up_at_goal else robot.started, m.slot)
            near = False
            if m.route:
                cx, cy = traffic.graph.centre(m.route[-1])
                x, y = self._xy(robot)
                near = math.hypot(cx - x, cy - y) <= DECIDE_WITHIN_CELLS * size
            if traffic.wants_decision(m, near):
                deciding.append(robot)
        for robot in sorted(deciding, key=lambda r: r.mover.priority):
            if robot.mover.slot in traffic._round:
                continue  # pushed already this round
            traffic.decide(robot.mover, self._now)

    # -- driving ---------------------------------------------------------------------------------

    def _xy(self, robot: NavRobot) -> tuple[float, float]:
        i = self.table.row_of(robot.namespace)
        assert i is not None
        return float(self.table.x[i]), float(self.table.y[i])

    def _way_points(self, robot: NavRobot, x: float, y: float) -> list[tuple[float, float]]:
        """Where the robot may drive: through the centres of the cells it holds ahead, or at
        its goal's cell, to the goal point itself (when the cells its body needs there are free)."""
        traffic = self.traffic
        graph = traffic.graph
        m = robot.mover
        way = traffic.way(m)
        pts = [(x, y)]
        if way and m.cell != FREE:  # along the line of its steps, from the middle of its cell
            pts += _onto([graph.centre(m.cell)] + [graph.centre(c) for c in way], x, y)
        else:
            pts += [graph.centre(c) for c in way]
        last = way[-1] if way else m.cell
        robot.held_up_at_goal = False
        if last == m.goal_cell and robot.goal is not None and len(way) == len(m.route):
            gx, gy = robot.goal.x, robot.goal.y
            if traffic.hold_free(m, traffic.box(gx, gy, m.radius)):
                pts.append((gx, gy))
            elif not way:
                pts.append(graph.centre(last))
                robot.held_up_at_goal = True
        elif not way and m.cell != FREE:
            pts.append(graph.centre(m.cell))  # settle at the centre of its cell
        if not self.config.lanes and len(pts) > 2:
            pts = self._pulled(m, pts)
        return pts

    def _pulled(self, m: Mover, pts: list[tuple[float, float]]) -> list[tuple[float, float]]:
        """In the open: the way cut straight to the farthest of its points that the robot's
        body reaches on a straight line through cells nobody else holds (it holds them as it
        goes), so that a way of cell centres is driven as a straight line where it can be."""
        traffic = self.traffic
        x, y = pts[0]
        for j in range(len(pts) - 1, 1, -1):
            tx, ty = pts[j]
            n = max(2, math.ceil(math.hypot(tx - x, ty - y) / 0.05) + 1)
            clear = True
            for t in np.linspace(0.0, 1.0, n).tolist():
                for c in traffic.box(x + t * (tx - x), y + t * (ty - y), m.radius):
                    o = int(traffic.owner[c])
                    if o != FREE and o != m.slot:
                        clear = False
                        break
                if not clear:
                    break
            if clear:
                return [pts[0], *pts[j:]]
        return pts[:2]  # nothing straight is clear: to the centre of its own cell first

    def _drive_robots(self, driven: list[NavRobot], table: RobotTable, now: float) -> None:
        rows = np.array([self._row[r.namespace] for r in driven], dtype=np.int64)
        x, y, yaw = table.x[rows], table.y[rows], table.yaw[rows]
        ways = [self._way_points(r, float(x[k]), float(y[k])) for k, r in enumerate(driven)]
        width = max(len(w) for w in ways)
        px = np.array([[p[0] for p in w] + [w[-1][0]] * (width - len(w)) for w in ways])
        py = np.array([[p[1] for p in w] + [w[-1][1]] * (width - len(w)) for w in ways])
        aim_x, aim_y, room = along(px, py, LOOKAHEAD_M)
        lidar = np.array([
            LOOK_AHEAD_M if abs(math.remainder(float(yaw[k]) - r.lidar_yaw, 2 * math.pi)) > 0.3 else r.lidar_room
            for k, r in enumerate(driven)
        ])  # fmt: skip
        lidar_room = np.maximum(lidar - LIDAR_STOP_M, 0.0)
        limits = Limits(np.array([r.model.max_linear_velocity for r in driven]),
                        np.array([r.model.max_angular_velocity for r in driven]))  # fmt: skip
        room = np.minimum(room, lidar_room)
        v, w = pursue(x, y, yaw, aim_x, aim_y, room, limits)
        crowd = self._would_crowd(driven, x, y, yaw, v)
        if crowd.any():  # cutting across would touch another's cell: by the centres instead
            k = np.flatnonzero(crowd)
            first = np.array([_first_step(ways[j]) for j in k.tolist()])
            sub = Limits(limits.max_v[k], limits.max_w[k])
            dist = np.hypot(first[:, 0] - x[k], first[:, 1] - y[k])
            v[k], w[k] = pursue(x[k], y[k], yaw[k], first[:, 0], first[:, 1], np.minimum(room[k], dist), sub)
            v = np.where(self._would_crowd(driven, x, y, yaw, v), 0.0, v)
        for k, robot in enumerate(driven):
            robot.command = (float(v[k]), float(w[k]))
            m = robot.mover
            lidar_stops = lidar_room[k] <= 0.01 and room[k] > lidar_room[k] + 0.01
            if robot.overridden_until >= now:
                robot.state = "overridden"
            elif lidar_stops:
                robot.state = "blocked"
                robot.blocked_since = robot.blocked_since if robot.blocked_since is not None else now
                if now - robot.blocked_since >= BLOCKED_REPLAN_S:
                    self._mark_seen(robot, now)
            else:
                robot.blocked_since = None
                robot.state = "waiting" if (m.waiting_for != FREE and not m.route) else "driving"

    def _would_crowd(self, driven: list[NavRobot], x: F64, y: F64, yaw: F64, v: F64) -> npt.NDArray[np.bool_]:
        """Whether each robot's body, GUARD_S ahead at its speed, would reach into a cell
        another robot holds (a last guard under the traffic's rules: it then only turns)."""
        traffic = self.traffic
        out = np.zeros(len(driven), dtype=bool)
        ahead = v * GUARD_S
        nx, ny = x + ahead * np.cos(yaw), y + ahead * np.sin(yaw)
        for k in np.flatnonzero(ahead > 0).tolist():
            m = driven[k].mover
            cells = [c for c in traffic.box(float(nx[k]), float(ny[k]), m.radius) if c not in m.box]
            if cells:
                owners = traffic.owner[cells]
                out[k] = bool(np.any((owners != FREE) & (owners != m.slot)))
        return out

    def _mark_seen(self, robot: NavRobot, now: float) -> None:
        """What the lidar keeps seeing in the way goes on this robot's map; then a new plan."""
        graph = self.traffic.graph
        hits = robot.lidar_hits
        if len(hits):
            cells = {c for hx, hy in hits if (c := graph.index(float(hx), float(hy))) is not None}
            robot.marks.append((np.array(sorted(cells), dtype=np.int64), now + MARK_S))
        robot.recoveries += 1
        robot.blocked_since = None
        robot.planned = False
        self.traffic.set_goal(robot.mover, None, FREE, robot.mover.goal_xy, robot.started)
        robot.state = "planning"

    def _read_scans(self) -> None:
        """The room ahead of each navigating robot, from the scans of the ticks since the last
        control step (not the newest tick's: its lidar may still be casting; it waits for the
        next step)."""
        if len(self._snaps) <= 1:
            return
        ready, self._snaps = self._snaps[:-1], self._snaps[-1:]
        for snap in ready:
            wanted = [
                k for k, ns in enumerate(snap.scan_namespaces) if (r := self.robots.get(ns)) is not None and r.active
            ]
            if not wanted:
                continue
            robots = [self.robots[snap.scan_namespaces[k]] for k in wanted]
            scans = snap.scans[wanted]
            idx = snap.scan_index[wanted]
            offsets = np.array([r.model.lidar_offset for r in robots], dtype=np.float64)
            half = np.array([float(np.max(np.abs(r.model.outline[:, 1]))) for r in robots])
            front = np.array([float(np.max(r.model.outline[:, 0])) for r in robots])
            sx, sy, syaw = snap.x[idx], snap.y[idx], snap.yaw[idx]
            px, py = self._guard.points(scans, offsets)
            c, s = np.cos(syaw)[:, None], np.sin(syaw)[:, None]
            wx, wy = sx[:, None] + px * c - py * s, sy[:, None] + px * s + py * c
            mine = np.array([r.mover.slot for r in robots], dtype=np.int64)[:, None]
            owner = self._owner_at(wx, wy)
            # what the map or the traffic explains is not the lidar's business
            known = ((owner != FREE) & (owner != mine)) | self._on_map(wx, wy)
            rooms, seen = self._guard.room_ahead(px, py, half, front, known)
            for k, robot in enumerate(robots):
                robot.lidar_room = float(rooms[k])
                robot.lidar_yaw = float(syaw[k])
                robot.lidar_hits = np.stack([wx[k][seen[k]], wy[k][seen[k]]], axis=1)

    def _owner_at(self, wx: F64, wy: F64) -> I64:
        """The traffic's holder of each world point's cell (FREE off the floor)."""
        g = self.traffic.graph.grid
        col = np.floor((wx - g.x0) / g.resolution).astype(np.int64)
        row = np.floor((wy - g.y0) / g.resolution).astype(np.int64)
        on = (col >= 0) & (col < g.width) & (row >= 0) & (row < g.height)
        out = np.full(wx.shape, FREE, dtype=np.int64)
        out[on] = self.traffic.owner[row[on] * g.width + col[on]]
        return out

    def _on_map(self, wx: F64, wy: F64) -> npt.NDArray[np.bool_]:
        """Whether each world point lies on (or within MAP_HIT_M of) a wall of the map."""
        cm = self.costmap
        g = cm.grid
        col = np.floor((wx - g.x0) / g.resolution).astype(np.int64)
        row = np.floor((wy - g.y0) / g.resolution).astype(np.int64)
        on = (col >= 0) & (col < g.width) & (row >= 0) & (row < g.height)
        out = np.zeros(wx.shape, dtype=bool)
        out[on] = cm.clearance[row[on], col[on]] <= MAP_HIT_M + g.resolution
        return out

    # -- goals ending ----------------------------------------------------------------------------

    def _check_goals(self, table: RobotTable, now: float) -> None:
        for robot in self.robots.values():
            if not robot.active or robot.goal is None:
                continue
            goal = robot.goal
            i = self._row[robot.namespace]
            x, y, yaw = float(table.x[i]), float(table.y[i]), float(table.yaw[i])
            if goal.timeout > 0 and now - robot.started >= goal.timeout:
                self._end(robot, "failed", "timeout", f"not reached within {goal.timeout:g} s", now)
                continue
            if robot.state in ("blocked", "waiting"):
                robot.stuck_since = robot.stuck_since if robot.stuck_since is not None else now
                if now - robot.stuck_since >= self.config.patience:
                    self._end(robot, "failed", "blocked", f"no way forward for {self.config.patience:g} s", now)
                    continue
                if robot.state == "blocked" and not robot.planned and now - robot.stuck_since >= BLOCKED_REPLAN_S:
                    robot.state = "planning"  # look again: the way may have cleared
                    continue
            else:
                robot.stuck_since = None
            if math.hypot(goal.x - x, goal.y - y) <= goal.tolerance:
                if goal.yaw is None or abs(math.remainder(goal.yaw - yaw, 2 * math.pi)) <= goal.yaw_tolerance:
                    self._end(robot, "reached", "", "goal reached", now)
                else:
                    one = Limits(
                        np.array([robot.model.max_linear_velocity]), np.array([robot.model.max_angular_velocity])
                    )
                    robot.command = (0.0, float(turn_to(np.array([yaw]), np.array([goal.yaw]), one)[0]))

    def _end(self, robot: NavRobot, status: str, reason: str, message: str, now: float) -> NavigationResult:
        goal = robot.goal or NavigateRequest(x=0.0, y=0.0)
        i = self.table.row_of(robot.namespace)
        t = self.table
        at = pose(t.x[i], t.y[i], t.yaw[i]) if i is not None else pose(0.0, 0.0)
        result = NavigationResult(
            goal_id=robot.goal_id,
            robot=robot.namespace,
            stamp=Time.from_seconds(now),
            status=status,  # type: ignore[arg-type]
            reason=reason,
            message=message,
            goal=goal_pose(goal),
            pose=at,
            navigation_time=now - robot.started,
            distance_travelled=robot.travelled,
            recoveries=robot.recoveries,
        )
        robot.state, robot.result, robot.ended = status, result, reason or status
        robot.command, robot.planned = (0.0, 0.0), False
        if self._traffic is not None:
            self._traffic.set_goal(robot.mover, None, FREE, (goal.x, goal.y), math.inf)
        self._events.results.append(result)
        self._events.plans.append(path_message(robot.goal_id, robot.namespace, now, []))
        self._drive_of = None
        self._stopping.append(robot.namespace)
        return result

    # -- reporting -------------------------------------------------------------------------------

    def _feedback(self, table: RobotTable, now: float) -> None:
        self._sync(table)
        stamp = Time.from_seconds(now)
        traffic = self._traffic
        for robot in self.robots.values():
            if not robot.active:
                continue
            i = self._row[robot.namespace]
            x, y = float(table.x[i]), float(table.y[i])
            left = self._left(robot, x, y)
            other = ""
            if robot.state == "waiting" and traffic is not None:
                o = robot.mover.waiting_for
                other = next((r.namespace for r in self.robots.values() if r.mover.slot == o), "")
            robot.feedback = NavigationFeedback(
                goal_id=robot.goal_id,
                robot=robot.namespace,
                stamp=stamp,
                state=robot.state,
                pose=pose(x, y, table.yaw[i]),
                distance_remaining=left,
                estimated_time_remaining=left / robot.model.max_linear_velocity,
                navigation_time=now - robot.started,
                recoveries=robot.recoveries,
                other=other,
            )
            self._events.feedback.append(robot.feedback)

    def _left(self, robot: NavRobot, x: float, y: float) -> float:
        """Metres left along the robot's way (its distance field from where it is)."""
        m = robot.mover
        if m.dist is None or robot.goal is None:
            return 0.0
        g = self.traffic.graph
        c = g.index(x, y)
        if c is None or not math.isfinite(float(m.dist[c])):
            return math.hypot(robot.goal.x - x, robot.goal.y - y)
        gx, gy = g.centre(m.goal_cell)
        return float(m.dist[c]) + math.hypot(robot.goal.x - gx, robot.goal.y - gy)

    def _fleet_summary(self, now: float) -> None:
        rows = []
        for robot in self.robots.values():
            if (not robot.active and not robot.ended) or robot.goal is None:
                continue
            x, y = self._xy(robot) if robot.namespace in self._row else (robot.goal.x, robot.goal.y)
            left = self._left(robot, x, y) if robot.active else 0.0
            rows.append(summary_row(robot.namespace, robot.goal_id, robot.state, robot.goal, left,
                                    "" if robot.active else robot.ended))  # fmt: skip
            robot.ended = ""
        if rows:
            self._events.fleet = FleetNavigation(stamp=Time.from_seconds(now), robots=rows)


def _onto(line: list[tuple[float, float]], x: float, y: float) -> list[tuple[float, float]]:
    """The rest of polyline ``line`` from the point on it nearest (x, y): where a robot that
    strayed or cut a corner joins its way again (the later of two equally near segments)."""
    best, at, k_best = math.inf, line[0], 0
    for k in range(len(line) - 1):
        (ax, ay), (bx, by) = line[k], line[k + 1]
        dx, dy = bx - ax, by - ay
        length2 = dx * dx + dy * dy
        t = 0.0 if length2 == 0 else min(1.0, max(0.0, ((x - ax) * dx + (y - ay) * dy) / length2))
        px, py = ax + t * dx, ay + t * dy
        d = math.hypot(px - x, py - y)
        if d <= best + 1e-9:
            best, at, k_best = d, (px, py), k
    rest = line[k_best + 1 :]
    return ([at] if best > 0.01 or not rest else []) + rest


def _first_step(way: list[tuple[float, float]]) -> tuple[float, float]:
    """The first point of a way more than 2 cm from the robot (the centre of its own cell,
    unless it stands there already)."""
    x, y = way[0]
    return next((p for p in way[1:] if math.hypot(p[0] - x, p[1] - y) > 0.02), way[-1])


def _straightened(points: F64) -> F64:
    """A polyline with its collinear middle points left out (a cell path's straight runs)."""
    if len(points) < 3:
        return points
    d = np.diff(points, axis=0)
    cross = d[:-1, 0] * d[1:, 1] - d[:-1, 1] * d[1:, 0]
    keep = np.concatenate(([True], np.abs(cross) > 1e-9, [True]))
    return points[keep]


def _check_goal(req: NavigateRequest) -> None:
    for name in ("x", "y", "tolerance", "yaw_tolerance", "timeout"):
        value = getattr(req, name)
        if not math.isfinite(value):
            raise FleetError(ErrorCode.NON_FINITE, f"{name} must be finite, got {value}", name)
    if req.yaw is not None and not math.isfinite(req.yaw):
        raise FleetError(ErrorCode.NON_FINITE, f"yaw must be finite, got {req.yaw}", "yaw")
    if not 0.0 < req.tolerance <= MAX_TOLERANCE_M:
        raise FleetError(
            ErrorCode.INVALID_VALUE,
            f"tolerance must be in (0, {MAX_TOLERANCE_M:g}] m, got {req.tolerance:g}",
            "tolerance",
        )
    if not 0.0 < req.yaw_tolerance <= math.pi:
        raise FleetError(
            ErrorCode.INVALID_VALUE, f"yaw_tolerance must be in (0, pi] rad, got {req.yaw_tolerance:g}", "yaw_tolerance"
        )
    if req.timeout < 0:
        raise FleetError(ErrorCode.INVALID_VALUE, f"timeout must be >= 0 s (0: none), got {req.timeout:g}", "timeout")
    if req.goal_id and (len(req.goal_id) > MAX_GOAL_ID_LENGTH or GOAL_ID.fullmatch(req.goal_id) is None):
        raise FleetError(
            ErrorCode.INVALID_VALUE,
            f"goal_id must be 1..{MAX_GOAL_ID_LENGTH} of letters, digits, '_', '.', ':', '-'",
            "goal_id",
        )
