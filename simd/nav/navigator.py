"""The navigator: every robot's goal, driven tick by tick on the simulation's own thread.

Why inside the daemon, on the simulation thread (docs/navigation.md has the measurements):
the navigator reads the true poses and the scans where they are made and writes commands into
the robot table, with no message in between (a thousand robots' commands would otherwise be
ten thousand zenoh messages a second each way), and it runs in tick order, so a stepped
(lockstep) run navigates the same way every time for a seed.

Every tick it re-applies each navigating robot's command (an idle teleop's zeros never stop a
robot on its way); every ``control_every`` ticks (10 Hz) it does the work:

1. every robot holds the floor under it (floor.py: a grid map's own cells, or cells laid
   over an open world), goal or not;
2. the scans since the last step give each robot's room ahead (lidar_guard.py): the first
   thing the map and the fleet do not explain stops it, and if that lasts, it marks what it
   sees and plans again;
3. robots with a new goal are planned, a few per step;
4. the floor decides who goes where next (priorities: the oldest goal first);
5. each robot drives the way its floor gives it (follow.py); goals that are reached, timed
   out or stuck end.
"""

from __future__ import annotations

import logging
import math
import re
import time
from collections.abc import Callable
from dataclasses import dataclass

import msgspec
import numpy as np
import numpy.typing as npt

from fleetcommon.arrays import F64, I64
from protocol.errors import ErrorCode, FleetError
from protocol.messages import Time
from protocol.navigation import (
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
from simd.nav.cells import cell_size_for
from simd.nav.costmap import Costmap, Grid
from simd.nav.floor import Floor
from simd.nav.follow import BACK_WITHIN_M, LOOKAHEAD_M, Limits, along, pursue, turn_to, wrap
from simd.nav.guards import too_close, would_crowd
from simd.nav.lidar_guard import LOOK_AHEAD_M, LidarGuard
from simd.nav.report import NavEvents, goal_pose, path_message, pose, summary_row
from simd.nav.robot import NavRobot
from simd.nav.traffic import FREE

log = logging.getLogger(__name__)


__all__ = ["NavConfig", "NavEvents", "NavRobot", "Navigator"]

_BURGER = MODELS["burger"]

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
#: a goal driven (not waiting, not making way) for its patience without getting this much (m)
#: nearer fails (``blocked``): a robot that keeps trying and getting nowhere says so
PROGRESS_M = 0.1
#: a goal no nearer for this many patiences, in any state, fails (``blocked``): robots that
#: take turns waiting for each other, each drive short of a way round, never stall for a whole
#: patience in one state, and would cycle for ever
STALL_PATIENCES = 2.0
#: a robot the guard stops turns on the spot until it faces its way's first point within this
#: (rad), then drives to that point (the corner it would have cut) until this near (m)
FACING_RAD, CORNER_REACHED_M = 0.05, 0.03
#: on an open floor a robot drives its way backwards when the way starts further than this
#: (rad) off the end it drives with, and the other end is nearer: turning round costs a
#: burger about a second; a TurtleBot3's drive and 360-degree lidar work both ways (the
#: margin over a right angle keeps it from switching ends on a way that starts square to it)
SWITCH_ENDS_ABOVE_RAD = math.pi / 2 + 0.3
#: a robot whose way runs this far (m) from the path it told has it told again, at most this often (s)
OFF_PATH_M, RETELL_S = 0.3, 1.0


@dataclass(frozen=True)
class NavConfig:
    """How the navigator works. ``lanes``: the world is a grid map (MovingAI) of cells
    ``cell`` m wide, and robots drive from cell centre to cell centre (else: smooth paths on
    the world's costmap)."""

    lanes: bool = False
    cell: float | None = None
    control_every: int = 3
    plans_per_step: int = 8
    feedback_every: int = 6
    fleet_every: int = 15
    patience: float = PATIENCE_S


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
        self._floor: Floor | None = None
        self.robots: dict[str, NavRobot] = {}
        self._next_slot = 0
        self._goal_counter = 0
        self._rows_of: int | None = None
        self._row: dict[str, int] = {}
        self._snaps: list[TickSnapshot] = []
        self._events = NavEvents()
        self._drive_of: int | None = None
        self._drive: tuple[I64, F64, F64] = (np.zeros(0, np.int64), np.zeros(0), np.zeros(0))
        self._stopping: list[str] = []
        self._now = 0.0
        #: wall seconds of work on the simulation thread (reported; never decides anything)
        self.work_seconds = 0.0

    # -- the world as navigation sees it (built when the first goal comes) -----------------------

    @property
    def costmap(self) -> Costmap:
        """The world's clearances at 5 cm (or coarser for huge worlds)."""
        if self._costmap is None:
            self._costmap = Costmap(self.world, Grid.covering(self.world))
        return self._costmap

    @property
    def floor(self) -> Floor:
        if self._floor is None:
            # cells one robot wide: of the map's size on a grid map, else for the largest
            # model in the world (a fleet of burgers gets smaller cells than one with waffles),
            # or the size the world file asks for if that is larger (cells that fit its layout)
            size = self.config.cell or max(
                self.world.nav_cell or 0.0,
                *(cell_size_for(m) for m in [_BURGER, *(r.model for r in self.robots.values())]),
            )
            self._floor = Floor(self.world, size, None if self.config.lanes else self.costmap)
            log.info("navigation: %s", self._floor.describe())
            for robot in self.robots.values():
                self._floor.add(robot)
        return self._floor

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
        if self.floor.refuses(model) and not (self.config.lanes or self.config.cell or self.busy):
            self._floor = None  # laid out for smaller robots before this one came: again, for all
        why = self.floor.refuses(model)
        if why is not None:
            raise FleetError(ErrorCode.INVALID_VALUE, why, "robot")
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
        robot.command, robot.overridden_until = (0.0, 0.0), -math.inf
        robot.held_up_at_goal = False
        robot.best_left, robot.progress_at, robot.nearer_at, robot.corner = math.inf, now, now, None
        self.floor.stop(robot)
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
        if self._floor is not None:
            self._floor.remove(robot)
        self._rows_of = self._drive_of = None

    def reset(self, now: float) -> None:
        """The world was reset (robots back at their spawn poses): goals end, the floor is free."""
        for robot in self.robots.values():
            if robot.active:
                self._end(robot, "failed", "cancelled", "the simulation was reset", now)
            if self._floor is not None:
                self._floor.remove(robot)
                self._floor.add(robot)
            robot.reversed = False  # (back at its spawn pose: a reset run drives as a fresh one)
        self._snaps.clear()
        self._rows_of = self._drive_of = None

    def placed(self, namespace: str, now: float) -> None:
        """The robot was put somewhere else (ROS's ``initialpose``): its goal is cancelled, as
        the way it was taking starts where it no longer is, and the cells it held are free."""
        robot = self.robots.get(namespace)
        if robot is None:
            return
        if robot.active:
            self._end(robot, "failed", "cancelled", f"robot {namespace!r} was placed elsewhere", now)
        if self._floor is not None:
            self._floor.remove(robot)
            self._floor.add(robot)
        robot.xy = None
        robot.reversed = False
        self._drive_of = None

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
        if self._drive_of != table.generation:
            driven = [r for r in self.robots.values() if r.active and r.overridden_until < self._now]
            found = [table.row_of(r.namespace) for r in driven]
            keep = [k for k, row in enumerate(found) if row is not None]
            self._drive = (
                np.array([found[k] for k in keep], dtype=np.int64),
                np.array([driven[k].command[0] for k in keep]),
                np.array([driven[k].command[1] for k in keep]),
            )
            self._drive_of = table.generation
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
        started = time.perf_counter()
        busy = self.busy
        if busy and tick % cfg.control_every == 0:
            self._control(table, now)
            self._drive_of = None
        if busy and tick % cfg.feedback_every == 0:
            self._feedback(table, now)
        if tick % cfg.fleet_every == 0:
            self._fleet_summary(now)
        self.work_seconds += time.perf_counter() - started

    def _sync(self, table: RobotTable) -> None:
        """Know every robot of the table, and the row of each (the table changed)."""
        if self._rows_of == table.generation:
            return
        present = set(table.namespaces)
        for ns in [ns for ns in self.robots if ns not in present]:
            self.deleted(ns, self._now)
        for info in table.robots:
            self._robot(info.namespace, info.model)
        self._row = {ns: i for i, ns in enumerate(table.namespaces)}
        self._rows_of = table.generation

    def _robot(self, namespace: str, model: RobotModel) -> NavRobot:
        robot = self.robots.get(namespace)
        if robot is None:
            robot = NavRobot(namespace, model, self._next_slot)
            self._next_slot += 1
            self.robots[namespace] = robot
            if self._floor is not None:
                self._floor.add(robot)
        return robot

    def _control(self, table: RobotTable, now: float) -> None:
        self._sync(table)
        floor = self.floor
        xs, ys = table.x, table.y
        row = self._row
        for robot in self.robots.values():
            i = row[robot.namespace]
            x, y = float(xs[i]), float(ys[i])
            floor.stand(robot, x, y)
            if robot.active and robot.xy is not None:
                robot.travelled += math.hypot(x - robot.xy[0], y - robot.xy[1])
            robot.xy, robot.now = (x, y), now
        self._read_scans()
        self._plan_some(now)
        driven = [r for r in self.robots.values() if r.active and r.planned and not r.overridden]
        floor.decide(driven, now)
        self._plan_some(now)  # those the floor sent back to plan (around a robot that stays)
        driven = [r for r in driven if r.planned]
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
        """Its floor's plan for its goal (around what its lidar saw); or the goal ends."""
        goal = robot.goal
        assert goal is not None
        here = robot.xy or (goal.x, goal.y)
        robot.marks = [(pts, until) for pts, until in robot.marks if until > now]
        path = self.floor.plan(robot, here, robot.blocked)
        if path is None:
            if robot.marks:  # what it saw may be in the way for good, or may go: wait and see
                robot.state, robot.planned = "blocked", False
                robot.stuck_since = robot.stuck_since if robot.stuck_since is not None else now
                return
            where = f"from ({here[0]:.2f}, {here[1]:.2f}) to ({goal.x:g}, {goal.y:g})"
            self._end(robot, "failed", "no_path", f"no path for a {robot.model.name} {where}", now)
            return
        robot.planned, robot.state = True, "driving"
        self._tell_path(robot, path, now)

    def _tell_path(self, robot: NavRobot, path: F64 | None, now: float) -> None:
        if path is not None:
            robot.told_path, robot.told_at = np.asarray(path, dtype=np.float64).reshape(-1, 2), now
            self._events.plans.append(path_message(robot.goal_id, robot.namespace, now, path))

    def _retell_if_off(self, robot: NavRobot, way: list[tuple[float, float]], now: float) -> None:
        """A robot whose way (the cells it holds and heads for) left the path it last told (it
        made way for another, the traffic sent it round) has its path told again, from where
        it is, at most every RETELL_S: what P/<ns>/plan shows is where it goes."""
        if now - robot.told_at < RETELL_S or len(way) < 2 or len(robot.told_path) < 2:
            return
        if _off_path(robot.told_path, way[-1]) > OFF_PATH_M:
            self._tell_path(robot, self.floor.path(robot, way[0]), now)

    # -- driving ---------------------------------------------------------------------------------

    def _drive_robots(self, driven: list[NavRobot], table: RobotTable, now: float) -> None:
        floor = self.floor
        rows = np.array([self._row[r.namespace] for r in driven], dtype=np.int64)
        x, y, real_yaw = table.x[rows], table.y[rows], table.yaw[rows]
        back_of = np.array([r.reversed for r in driven])
        yaw = wrap(real_yaw + np.pi * back_of)
        ways = [floor.way(r, float(x[k]), float(y[k]), float(yaw[k])) for k, r in enumerate(driven)]
        width = max(len(w) for w in ways)
        px = np.array([[p[0] for p in w] + [w[-1][0]] * (width - len(w)) for w in ways])
        py = np.array([[p[1] for p in w] + [w[-1][1]] * (width - len(w)) for w in ways])
        aim_x, aim_y, room = along(px, py, LOOKAHEAD_M)
        for k, robot in enumerate(driven):  # one the guard sent to its way's corner goes there first
            corner = robot.corner
            if corner is None:
                continue
            left = math.hypot(corner[0] - x[k], corner[1] - y[k])
            on_way = any(math.hypot(corner[0] - p[0], corner[1] - p[1]) < 0.02 for p in ways[k][1:])
            if left <= CORNER_REACHED_M or not on_way:
                robot.corner = None
            else:
                aim_x[k], aim_y[k], room[k] = corner[0], corner[1], min(float(room[k]), left)
        if floor.costmap is not None:
            self._choose_ends(driven, x, y, yaw, aim_x, aim_y)
            back_of = np.array([r.reversed for r in driven])
        lidar = np.array([  # the room on the end it drives with, if it still heads as it did then
            LOOK_AHEAD_M if abs(math.remainder(float(real_yaw[k]) - r.lidar_yaw, 2 * math.pi)) > 0.3
            else r.lidar_rooms[r.reversed]
            for k, r in enumerate(driven)
        ])  # fmt: skip
        lidar_room = np.maximum(lidar - LIDAR_STOP_M, 0.0)
        limits = Limits(np.array([r.model.max_linear_velocity for r in driven]),
                        np.array([r.model.max_angular_velocity for r in driven]))  # fmt: skip
        room = np.minimum(room, lidar_room)
        back = BACK_WITHIN_M if floor.costmap is not None else 0.0  # (in lanes robots turn)
        v, w = pursue(x, y, yaw, aim_x, aim_y, room, limits, back)
        v = np.where(back_of, -v, v)
        v_now = np.abs(table.vx[rows])
        crowd = would_crowd(self.floor, driven, x, y, real_yaw, v, v_now)
        if crowd.any():  # cutting across would touch another's cells: by the way's first point
            ks = np.flatnonzero(crowd)
            first = np.array([_first_step(ways[j]) for j in ks.tolist()])
            sub = Limits(limits.max_v[ks], limits.max_w[ks])
            dist = np.minimum(room[ks], np.hypot(first[:, 0] - x[ks], first[:, 1] - y[ks]))
            v[ks], w[ks] = pursue(x[ks], y[ks], yaw[ks], first[:, 0], first[:, 1], dist, sub, back)
            v[ks] = np.where(back_of[ks], -v[ks], v[ks])
            still = would_crowd(self.floor, driven, x, y, real_yaw, v, v_now)
            if still.any():  # even that arc would: stop, and turn on the spot to face the first point
                js = np.flatnonzero(still)
                pts = np.array([_first_step(ways[j]) for j in js.tolist()])
                heading = np.arctan2(pts[:, 1] - y[js], pts[:, 0] - x[js])
                facing = np.abs(wrap(heading - yaw[js])) <= FACING_RAD
                w[js] = np.where(facing, 0.0, turn_to(yaw[js], heading, Limits(limits.max_v[js], limits.max_w[js])))
                v[js] = 0.0
                for j, (cx, cy) in zip(js.tolist(), pts.tolist(), strict=True):
                    driven[j].corner = (cx, cy)  # and aims there, not round it, until it is there
        v = np.where(too_close(driven, rows, table, x, y, real_yaw, v), 0.0, v)
        for k, robot in enumerate(driven):
            robot.command = (float(v[k]), float(w[k]))
            self._retell_if_off(robot, ways[k], now)
            lidar_stops = lidar_room[k] <= 0.01 and room[k] < 0.02 and lidar[k] < LOOK_AHEAD_M
            if lidar_stops and floor.yielding(robot) == FREE:
                robot.state = "blocked"
                robot.blocked_since = robot.blocked_since if robot.blocked_since is not None else now
                if now - robot.blocked_since >= BLOCKED_REPLAN_S:
                    self._mark_seen(robot, now)
                continue
            robot.blocked_since = None
            if floor.yielding(robot) != FREE:
                robot.state = "yielding"
            elif floor.waiting_for(robot) != FREE:
                robot.state = "waiting"
            else:
                robot.state = "driving"

    @staticmethod
    def _choose_ends(driven: list[NavRobot], x: F64, y: F64, yaw: F64, aim_x: F64, aim_y: F64) -> None:
        """Each robot whose aim lies more than SWITCH_ENDS_ABOVE_RAD off the end it drives
        with drives with the other end from now on (``yaw``: the heading of the end each
        drives with, turned round for those that switch). Not while it heads for a corner
        the guard sent it to."""
        dx, dy = aim_x - x, aim_y - y
        off = np.abs(wrap(np.arctan2(dy, dx) - yaw))
        switch = (off > SWITCH_ENDS_ABOVE_RAD) & (np.hypot(dx, dy) > 0.05)
        for k in np.flatnonzero(switch).tolist():
            if driven[k].corner is None:
                driven[k].reversed = not driven[k].reversed
                yaw[k] = math.remainder(float(yaw[k]) + math.pi, 2 * math.pi)

    def _mark_seen(self, robot: NavRobot, now: float) -> None:
        """What the lidar keeps seeing in the way goes on this robot's map; then a new plan."""
        hits = robot.lidar_hits[robot.reversed]
        if len(hits):
            robot.marks.append((hits, now + MARK_S))
        robot.recoveries += 1
        robot.blocked_since = None
        robot.planned = False
        self.floor.stop(robot)
        robot.state = "planning"

    def _read_scans(self) -> None:
        """The room ahead of each navigating robot, from the scans of the ticks since the last
        control step (not the newest tick's: its lidar may still be casting; it waits for the
        next step)."""
        if len(self._snaps) <= 1:
            return
        ready, self._snaps = self._snaps[:-1], self._snaps[-1:]
        floor = self.floor
        for snap in ready:
            wanted = [k for k, ns in enumerate(snap.scan_namespaces) if self._navigating(ns)]
            if not wanted:
                continue
            robots = [self.robots[snap.scan_namespaces[k]] for k in wanted]
            scans = snap.scans[wanted]
            idx = snap.scan_index[wanted]
            offsets = np.array([r.model.lidar_offset for r in robots], dtype=np.float64)
            half = np.array([float(np.max(np.abs(r.model.outline[:, 1]))) for r in robots])
            front = np.array([float(np.max(r.model.outline[:, 0])) for r in robots])
            rear = -np.array([float(np.min(r.model.outline[:, 0])) for r in robots])
            sx, sy, syaw = snap.x[idx], snap.y[idx], snap.yaw[idx]
            px, py = self._guard.points(scans, offsets)
            c, s = np.cos(syaw)[:, None], np.sin(syaw)[:, None]
            wx, wy = sx[:, None] + px * c - py * s, sy[:, None] + px * s + py * c
            mine = np.array([r.slot for r in robots], dtype=np.int64)[:, None]
            owner = floor.owner_at(wx, wy)
            # what the map or the fleet explains is not the lidar's business
            known = ((owner != FREE) & (owner != mine)) | self._on_map(wx, wy)
            ahead, seen_ahead = self._guard.room_ahead(px, py, half, front, known)
            if floor.costmap is not None:  # and behind (the frame turned half round), for when it
                behind, seen_behind = self._guard.room_ahead(-px, -py, half, rear, known)  # drives back first
            else:  # (in lanes robots always drive forwards)
                behind, seen_behind = np.full(len(robots), LOOK_AHEAD_M), np.zeros_like(seen_ahead)
            for k, robot in enumerate(robots):
                robot.lidar_rooms = (float(ahead[k]), float(behind[k]))
                robot.lidar_yaw = float(syaw[k])
                robot.lidar_hits = (
                    np.stack([wx[k][seen_ahead[k]], wy[k][seen_ahead[k]]], axis=1),
                    np.stack([wx[k][seen_behind[k]], wy[k][seen_behind[k]]], axis=1),
                )

    def _navigating(self, namespace: str) -> bool:
        robot = self.robots.get(namespace)
        return robot is not None and robot.active

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
            if robot.state != "driving":  # waiting or making way: the traffic's business, not a stall
                robot.progress_at = now
            if now - robot.progress_at >= self.config.patience:  # driving, maybe, but getting nowhere
                self._end(robot, "failed", "blocked", f"no nearer the goal for {self.config.patience:g} s", now)
                continue
            if robot.overridden:
                robot.nearer_at = now  # somebody else drives it: no stall of the navigator's
            stall = STALL_PATIENCES * self.config.patience
            if now - robot.nearer_at >= stall:  # by turns waiting, making way, driving: getting nowhere
                self._end(robot, "failed", "blocked", f"no nearer the goal for {stall:g} s, waiting included", now)
                continue
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
        if self._floor is not None:
            self._floor.stop(robot)
        self._events.results.append(result)
        self._events.plans.append(path_message(robot.goal_id, robot.namespace, now, []))
        self._drive_of = None
        self._stopping.append(robot.namespace)
        return result

    # -- reporting -------------------------------------------------------------------------------

    def _feedback(self, table: RobotTable, now: float) -> None:
        self._sync(table)
        stamp = Time.from_seconds(now)
        floor = self._floor
        slots = {r.slot: r.namespace for r in self.robots.values()}
        for robot in self.robots.values():
            if not robot.active:
                continue
            i = self._row[robot.namespace]
            x, y = float(table.x[i]), float(table.y[i])
            left = floor.left(robot, x, y) if floor is not None and robot.planned else 0.0
            if robot.planned and left < robot.best_left - PROGRESS_M:
                robot.best_left, robot.progress_at, robot.nearer_at = left, now, now
            other = ""
            if robot.state == "waiting" and floor is not None:
                other = slots.get(floor.waiting_for(robot), "")
            elif robot.state == "yielding" and floor is not None:
                other = slots.get(floor.yielding(robot), "")
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

    def _fleet_summary(self, now: float) -> None:
        rows = []
        floor = self._floor
        for robot in self.robots.values():
            if (not robot.active and not robot.ended) or robot.goal is None:
                continue
            left = 0.0
            if robot.active and robot.planned and floor is not None and robot.xy is not None:
                left = floor.left(robot, *robot.xy)
            rows.append(summary_row(robot.namespace, robot.goal_id, robot.state, robot.goal, left,
                                    "" if robot.active else robot.ended))  # fmt: skip
            robot.ended = ""
        if rows:
            self._events.fleet = FleetNavigation(
                stamp=Time.from_seconds(now), robots=rows, work_seconds=round(self.work_seconds, 4)
            )


def _off_path(path: F64, point: tuple[float, float]) -> float:
    """How far ``point`` is from the polyline ``path`` (m)."""
    a, b = path[:-1], path[1:]
    ab = b - a
    p = np.asarray(point, dtype=np.float64)
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-12), 0.0, 1.0)
    nearest = a + t[:, None] * ab
    return float(np.min(np.hypot(nearest[:, 0] - p[0], nearest[:, 1] - p[1])))


def _first_step(way: list[tuple[float, float]]) -> tuple[float, float]:
    """The first point of a way more than 2 cm from the robot."""
    x, y = way[0]
    return next((p for p in way[1:] if math.hypot(p[0] - x, p[1] - y) > 0.02), way[-1])


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
