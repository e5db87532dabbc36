"""The navigator: every robot's goal, driven tick by tick on the simulation's own thread.

Why inside the daemon, on the simulation thread (docs/navigation.md has the measurements):
the navigator reads the true poses and the scans where they are made and writes commands into
the robot table, with no message in between; a thousand robots' commands would otherwise be
ten thousand zenoh messages a second each way. And it runs in tick order, so a stepped
(lockstep) run navigates exactly the same way every time for a seed.

Per tick it only re-applies each navigating robot's command (so that a zero command from an
idle teleop never stops it); every ``control_every`` ticks (10 Hz) it does the work:

1. every robot holds the traffic cells under it (simd/nav/traffic.py);
2. the scans since the last control step give each robot's room ahead (lidar_guard.py);
3. robots with a new goal are planned, a few per step (planning.py);
4. each robot's place on its path, and the cells ahead it claims: it may drive to where its
   claims reach, and no further than its lidar allows;
5. robots that wait for each other in a circle are sorted out (meetings.py): the one of lower
   priority (the younger goal) plans around, or makes way;
6. the commands (follow.py), then goals reached, timed out or stuck.

What it tells the world it puts in :class:`NavEvents` (protocol/navigation.py's messages, which
are plain data): the engine hands them to the adapters after the tick.
"""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from protocol.control import Pose2D
from protocol.errors import ErrorCode, FleetError
from protocol.messages import Time
from protocol.navigation import (
    ACTIVE_STATES,
    MAX_GOAL_ID_LENGTH,
    FleetNavigation,
    NavigateReply,
    NavigateRequest,
    NavigationFeedback,
    NavigationPath,
    NavigationResult,
    NavigationState,
    RobotNavigation,
)
from simd.core.lidar import LidarSpec
from simd.core.models import RobotModel
from simd.core.robots import RobotTable
from simd.core.snapshot import TickSnapshot
from simd.core.worldfile import WorldGeometry
from simd.nav import meetings
from simd.nav.costmap import Costmap, Grid
from simd.nav.follow import LOOKAHEAD_M, Limits, PathBank, pursue, turn_to
from simd.nav.lidar_guard import LOOK_AHEAD_M, LidarGuard
from simd.nav.planning import Marks, Planner, disc_cells, square_cells
from simd.nav.traffic import FREE, Hold, Traffic

log = logging.getLogger(__name__)

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

GOAL_ID = re.compile(r"[A-Za-z0-9_.:-]+")
#: the largest goal tolerance accepted (m)
MAX_TOLERANCE_M = 100.0
#: an outside cmd_vel other than zero drives a navigating robot for this long (s of sim time)
OVERRIDE_S = 0.5
#: stop this far (m) before an obstacle the lidar sees
LIDAR_STOP_M = 0.06
#: a lidar hit this close (m) to a wall or obstacle of the map is that wall
MAP_HIT_M = 0.05
#: a robot that its lidar holds up this long marks what it sees on its map and plans around it
BLOCKED_REPLAN_S = 2.0
#: marks of things seen are kept this long (s), then forgotten (the box may have gone)
MARK_S = 30.0
#: robots that wait for each other in a circle this long are sorted out
DEADLOCK_S = 1.0
#: a robot waiting this long for a robot that does not move plans around it
DETOUR_S = 4.0
#: a detour may be at most this much longer than the way it leaves (times, plus metres)
DETOUR_FACTOR, DETOUR_EXTRA_M = 2.0, 6.0
#: a robot that made way does not make way again this soon (the others of its circle do)
MAKE_WAY_AGAIN_S = 3.0
#: a robot plans around the other robots within this distance (m) of it
NEAR_M = 2.0
#: ... and treats the cells they hold as blocked this long (s)
ROBOT_MARK_S = 10.0
#: having made way, a robot waits at most this long before it sets off again
YIELD_WAIT_S = 8.0
#: a robot that has had no way forward (no path, or waiting) this long fails with ``blocked``
PATIENCE_S = 120.0
#: the traffic claims this far (m) ahead of the robot's circle
CLAIM_AHEAD_M = 0.2
#: the margin (m) around each robot's circumscribed circle in the traffic
TRAFFIC_MARGIN_M = 0.04
#: the traffic's cells in an open world (a world file): fine, so that cells stand for the
#: robots' circles to within a few centimetres
OPEN_TRAFFIC_CELL_M = 0.1
#: how far (m) a robot may stray from its path: its claims are this much wider than its circle
TRACKING_M = 0.05


@dataclass(frozen=True)
class NavConfig:
    """How the navigator plans and drives. ``resolution`` of the costmap (None: 5 cm, coarser
    for huge worlds); ``lanes``: plan on the grid's cell centres (MovingAI worlds);
    ``traffic_cell``: the side of the traffic's cells (None: the costmap's cell with lanes,
    else 0.35 m, a burger's circle with margins)."""

    resolution: float | None = None
    lanes: bool = False
    traffic_cell: float | None = None
    control_every: int = 3
    plans_per_step: int = 6
    feedback_every: int = 6
    fleet_every: int = 15
    patience: float = PATIENCE_S


@dataclass
class NavEvents:
    """What the navigator says after a tick: results of goals that ended, paths planned,
    feedback (5 Hz of sim time) and the fleet's summary (2 Hz)."""

    results: list[NavigationResult] = field(default_factory=list)
    plans: list[NavigationPath] = field(default_factory=list)
    feedback: list[NavigationFeedback] = field(default_factory=list)
    fleet: FleetNavigation | None = None

    def __bool__(self) -> bool:
        return bool(self.results or self.plans or self.feedback or self.fleet)


@dataclass(eq=False)
class NavRobot:
    """One robot as the navigator knows it (every robot of the world has one)."""

    namespace: str
    model: RobotModel
    slot: int
    hold: Hold
    goal: NavigateRequest | None = None
    goal_id: str = ""
    state: str = ""  # "" when it has no active goal
    started: float = 0.0
    path: F64 | None = None
    seg: int = 0
    progress: float = 0.0
    room: float = 0.0  # metres it may drive along its path
    lidar_room: float = LOOK_AHEAD_M
    lidar_at: tuple[float, float] = (0.0, 0.0)  # (progress, yaw) when the scan was taken
    blocked_since: float | None = None
    waiting_since: float | None = None
    stuck_since: float | None = None
    detour_tried: float = -math.inf
    made_way: float = -math.inf
    marks: list[Marks] = field(default_factory=list)
    recoveries: int = 0
    travelled: float = 0.0
    last_xy: tuple[float, float] | None = None
    command: tuple[float, float] = (0.0, 0.0)
    overridden_until: float = -math.inf
    refuge: tuple[float, float] | None = None
    yield_to: frozenset[int] = frozenset()
    yield_until: float = 0.0
    goals: int = 0
    result: NavigationResult | None = None
    feedback: NavigationFeedback | None = None
    ended_unreported: str = ""  # a reason for the next fleet summary

    @property
    def active(self) -> bool:
        return self.state in ACTIVE_STATES

    def priority(self) -> tuple[float, int]:
        """Smaller comes first: the older goal, then the older robot."""
        return self.started, self.slot


class Navigator:
    """Goals for the robots of one simulation (see the module docstring)."""

    def __init__(self, world: WorldGeometry, lidar: LidarSpec, table: RobotTable, config: NavConfig | None = None) -> None:
        self.world = world
        self.table = table  # the simulation's robot table (read on its thread only)
        self.config = config or NavConfig()
        self._lidar = LidarGuard(lidar)
        self._costmap: Costmap | None = None
        self._planner: Planner | None = None
        self._traffic: Traffic | None = None
        self._standable: dict[str, npt.NDArray[np.bool_]] = {}
        self.robots: dict[str, NavRobot] = {}
        self._by_slot: dict[int, NavRobot] = {}
        self._next_slot = 0
        self._goal_counter = 0
        self._table_of: list[str] | None = None
        self._row: dict[str, int] = {}
        self._snaps: list[TickSnapshot] = []
        self._events = NavEvents()
        self._drive_rows = np.zeros(0, dtype=np.int64)
        self._drive_v = np.zeros(0)
        self._drive_w = np.zeros(0)
        self._drive_of: list[str] | None = None
        self._stopping: list[str] = []  # robots whose goal ended: commanded to stop once
        self._time = 0.0
        self._table_x = np.zeros(0)
        self._table_y = np.zeros(0)
        self._latest_scan: dict[str, tuple[npt.NDArray[np.float32], float, float, float]] = {}

    # -- lazily built world models ----------------------------------------------------------------

    @property
    def costmap(self) -> Costmap:
        if self._costmap is None:
            self._costmap = Costmap(self.world, Grid.covering(self.world, self.config.resolution))
            log.info(
                "navigation costmap: %d x %d cells of %.3g m",
                self._costmap.grid.width,
                self._costmap.grid.height,
                self._costmap.grid.resolution,
            )
        return self._costmap

    @property
    def planner(self) -> Planner:
        if self._planner is None:
            self._planner = Planner(self.costmap, self.config.lanes)
        return self._planner

    @property
    def traffic(self) -> Traffic:
        if self._traffic is None:
            cell = self.config.traffic_cell
            if cell is None:
                cell = self.costmap.grid.resolution if self.config.lanes else OPEN_TRAFFIC_CELL_M
            self._traffic = Traffic(self.world.bounds, cell)
        return self._traffic

    def standable(self, model: RobotModel) -> npt.NDArray[np.bool_]:
        """Per traffic cell: whether ``model`` can stand at its centre."""
        s = self._standable.get(model.name)
        if s is None:
            tr, cm = self.traffic, self.costmap
            idx = np.arange(tr.width * tr.height)
            xs = tr.x0 + (idx % tr.width + 0.5) * tr.cell
            ys = tr.y0 + (idx // tr.width + 0.5) * tr.cell
            g = cm.grid
            cols = np.clip(np.floor((xs - g.x0) / g.resolution).astype(np.int64), 0, g.width - 1)
            rows = np.clip(np.floor((ys - g.y0) / g.resolution).astype(np.int64), 0, g.height - 1)
            s = np.isfinite(cm.costs(model)[rows, cols])
            self._standable[model.name] = s
        return s

    @property
    def busy(self) -> bool:
        """Whether some robot has an active goal (else a tick costs the navigator nothing)."""
        return any(r.active for r in self.robots.values())

    # -- requests (simulation thread) -------------------------------------------------------------

    def goal(self, namespace: str, model: RobotModel, req: NavigateRequest, now: float) -> NavigateReply:
        """Accept a goal for the robot, or raise FleetError and change nothing."""
        self._time = now
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
        robot.command, robot.overridden_until = (0.0, 0.0), -math.inf
        robot.path, robot.marks, robot.recoveries, robot.travelled = None, [], 0, 0.0
        robot.blocked_since = robot.waiting_since = robot.stuck_since = None
        robot.refuge, robot.yield_to, robot.result, robot.feedback = None, frozenset(), None, None
        robot.detour_tried = -math.inf
        robot.goals += 1
        self._drive_of = None
        return NavigateReply(
            goal_id=goal_id,
            robot=namespace,
            goal=Pose2D(x=req.x, y=req.y, yaw=req.yaw or 0.0),
            preempted=preempted,
            stamp=Time.from_seconds(now),
        )

    def cancel(self, namespace: str, goal_id: str, now: float) -> NavigationResult:
        robot = self.robots.get(namespace)
        if robot is None or not robot.active:
            raise FleetError(ErrorCode.NOT_FOUND, f"robot {namespace!r} has no goal to cancel", "goal_id")
        if goal_id and goal_id != robot.goal_id:
            raise FleetError(
                ErrorCode.NOT_FOUND,
                f"robot {namespace!r} is on goal {robot.goal_id!r}, not {goal_id!r}",
                "goal_id",
            )
        return self._end(robot, "failed", "cancelled", "cancelled on request", now)

    def state(self, namespace: str) -> NavigationState:
        robot = self.robots.get(namespace)
        if robot is None or robot.goal is None:
            return NavigationState(robot=namespace)
        return NavigationState(
            robot=namespace,
            goal_id=robot.goal_id,
            goal=robot.goal,
            active=robot.active,
            feedback=robot.feedback if robot.active else None,
            result=robot.result,
        )

    def deleted(self, namespace: str, now: float) -> None:
        """The robot left the world: its goal fails (``robot_gone``), its cells are free."""
        robot = self.robots.pop(namespace, None)
        if robot is None:
            return
        if robot.active:
            self._end(robot, "failed", "robot_gone", f"robot {namespace!r} was deleted", now)
        self.traffic.release(robot.hold)
        del self._by_slot[robot.slot]
        self._table_of = None
        self._drive_of = None

    def reset(self, now: float) -> None:
        """The world was reset: robots are back at their spawn poses, so goals end."""
        for robot in self.robots.values():
            if robot.active:
                self._end(robot, "failed", "cancelled", "the simulation was reset", now)
            if self._traffic is not None:
                self._traffic.release(robot.hold)
        self._snaps.clear()
        self._latest_scan.clear()
        self._table_of = None

    def goals(self) -> list[NavigateRequest]:
        """The active goals (with their robots), for a state file."""
        out = []
        for robot in self.robots.values():
            if robot.active and robot.goal is not None:
                out.append(_with_id(robot.goal, robot.namespace, robot.goal_id))
        return out

    # -- commands (simulation thread) -------------------------------------------------------------

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
                robot.overridden_until = now + OVERRIDE_S
        return out

    def overridden_by_step(self, namespaces: list[str], v: F64, w: F64, now: float) -> None:
        """A lockstep step's commands: those other than zero override like cmd_vel does."""
        moving = (v != 0.0) | (w != 0.0)
        for k in np.flatnonzero(moving).tolist():
            robot = self.robots.get(namespaces[k])
            if robot is not None and robot.active:
                robot.overridden_until = now + OVERRIDE_S

    def apply(self, table: RobotTable, command_rows: Callable[[I64, F64, F64], None]) -> None:
        """Every tick: each navigating robot's latest command, unless somebody overrides it;
        a robot whose goal just ended is told to stop, once."""
        if self._stopping:
            rows = [r for ns in self._stopping if (r := table.row_of(ns)) is not None]
            self._stopping = []
            if rows:
                zero = np.zeros(len(rows))
                command_rows(np.array(rows, dtype=np.int64), zero, zero)
        if self._drive_of is not table.namespaces:
            rows, vs, ws = [], [], []
            for robot in self.robots.values():
                if robot.active and robot.overridden_until < self._time:
                    row = table.row_of(robot.namespace)
                    if row is not None:
                        rows.append(row)
                        vs.append(robot.command[0])
                        ws.append(robot.command[1])
            self._drive_rows = np.array(rows, dtype=np.int64)
            self._drive_v, self._drive_w = np.array(vs), np.array(ws)
            self._drive_of = table.namespaces
        if len(self._drive_rows):
            command_rows(self._drive_rows, self._drive_v, self._drive_w)

    def observe(self, snapshot: TickSnapshot) -> None:
        """A tick ran: its scans are read at the next control step (the lidar may still cast them)."""
        if self.busy:
            self._snaps.append(snapshot)

    def take_events(self) -> NavEvents:
        ev, self._events = self._events, NavEvents()
        return ev

    # -- the control step -------------------------------------------------------------------------

    def step(self, table: RobotTable, tick: int, now: float) -> None:
        """Called before each tick with the tick about to run; does the work every
        ``control_every`` ticks and the reporting on its own schedule."""
        self._time = now
        cfg = self.config
        if not self.robots and not table.namespaces:
            return
        busy = self.busy
        if busy and tick % cfg.control_every == 0:
            self._control(table, now)
            self._drive_of = None
        if tick % cfg.feedback_every == 0 and busy:
            self._feedback(table, now)
        if tick % cfg.fleet_every == 0:
            self._fleet_summary(now)

    def _sync(self, table: RobotTable) -> None:
        if self._table_of is table.namespaces:
            return
        present = set(table.namespaces)
        for ns in [ns for ns in self.robots if ns not in present]:
            self.deleted(ns, self._time)
        for robot_info in table.robots:
            self._robot(robot_info.namespace, robot_info.model)
        self._row = {ns: i for i, ns in enumerate(table.namespaces)}
        self._table_of = table.namespaces

    def _robot(self, namespace: str, model: RobotModel) -> NavRobot:
        robot = self.robots.get(namespace)
        if robot is None:
            slot = self._next_slot
            self._next_slot += 1
            hold = Hold(slot, model.radius + TRAFFIC_MARGIN_M)
            robot = NavRobot(namespace, model, slot, hold)
            self.robots[namespace] = robot
            self._by_slot[slot] = robot
        return robot

    def _control(self, table: RobotTable, now: float) -> None:
        self._sync(table)
        traffic = self.traffic
        xs, ys, yaws = table.x, table.y, table.yaw
        row = self._row
        for robot in self.robots.values():
            i = row[robot.namespace]
            traffic.stand(robot.hold, float(xs[i]), float(ys[i]))
            if robot.active:
                x, y = float(xs[i]), float(ys[i])
                if robot.last_xy is not None:
                    robot.travelled += math.hypot(x - robot.last_xy[0], y - robot.last_xy[1])
                robot.last_xy = (x, y)
        self._read_scans(table)
        self._plan_some(table, now)
        moving = [r for r in self.robots.values() if r.active and r.path is not None and r.state != "planning"]
        if moving:
            rows = np.array([row[r.namespace] for r in moving], dtype=np.int64)
            bank = PathBank.of([r.path for r in moving if r.path is not None])
            seg = np.array([r.seg for r in moving], dtype=np.int64)
            new_seg, progress = bank.project(xs[rows], ys[rows], seg)
            length = bank.length()
            for k, robot in enumerate(moving):
                robot.seg = int(new_seg[k])
                robot.progress = float(progress[k])
            # claims in order of priority: those making way first (they clear a knot), then
            # the oldest goals
            for k in sorted(range(len(moving)), key=lambda k: (moving[k].refuge is None, moving[k].priority())):
                robot = moving[k]
                frontier = traffic.advance(robot.hold, robot.progress, CLAIM_AHEAD_M)
                robot.room = max(0.0, min(frontier, float(length[k])) - robot.progress)
            self._sort_out_meetings(now)
            self._drive(moving, bank, rows, table, now)
        self._check_goals(table, now)

    # -- planning --------------------------------------------------------------------------------

    def _plan_some(self, table: RobotTable, now: float) -> None:
        budget = self.config.plans_per_step
        for robot in self.robots.values():
            if budget <= 0:
                break
            if robot.state != "planning" or robot.goal is None:
                continue
            budget -= 1
            i = self._row[robot.namespace]
            here = (float(table.x[i]), float(table.y[i]))
            self._expire_marks(robot, now)
            target = robot.refuge or (robot.goal.x, robot.goal.y)
            tolerance = 0.05 if robot.refuge else robot.goal.tolerance
            path = self.planner.path(robot.model, here, target, tolerance, robot.marks)
            if path is None and robot.marks and robot.refuge is None:
                path = self.planner.path(robot.model, here, target, tolerance)  # what it saw may have gone
                if path is not None:
                    robot.marks = []
            if path is None:
                if robot.refuge is not None:  # nowhere to make way to after all: wait where it is
                    robot.refuge = None
                    continue
                if not robot.marks and robot.recoveries == 0:
                    self._end(robot, "failed", "no_path", _no_path_message(robot, here), now)
                    continue
                robot.stuck_since = robot.stuck_since or now
                robot.state = "blocked"
                continue
            self._follow(robot, path, now)

    def _follow(self, robot: NavRobot, path: F64, now: float) -> None:
        robot.path, robot.seg, robot.progress = path, 0, 0.0
        robot.state = "yielding" if robot.refuge is not None else "driving"
        robot.blocked_since = robot.waiting_since = None
        self.traffic.follow(robot.hold, self.traffic.path_claims(path, robot.hold.radius, TRACKING_M if self.config.lanes else 0.0))
        self._events.plans.append(
            NavigationPath(
                goal_id=robot.goal_id,
                robot=robot.namespace,
                stamp=Time.from_seconds(now),
                points=[(float(px), float(py)) for px, py in path],
            )
        )

    def _replan(self, robot: NavRobot, now: float) -> None:
        robot.recoveries += 1
        robot.state = "planning"
        robot.path = None
        robot.command = (0.0, 0.0)
        self.traffic.follow(robot.hold, None)

    def _expire_marks(self, robot: NavRobot, now: float) -> None:
        if robot.marks:
            robot.marks = [m for m in robot.marks if m.until > now]

    # -- meetings --------------------------------------------------------------------------------

    def _sort_out_meetings(self, now: float) -> None:
        waits: dict[int, int] = {}
        for robot in self.robots.values():
            if not robot.active or robot.path is None:
                continue
            blocker = robot.hold.blocked_by
            if blocker == FREE or min(robot.room, robot.lidar_room - LIDAR_STOP_M) > 0.02:
                robot.waiting_since = None
                continue
            robot.waiting_since = robot.waiting_since if robot.waiting_since is not None else now
            if robot.state == "driving":
                robot.state = "waiting"
            if now - robot.waiting_since >= DEADLOCK_S:
                waits[robot.slot] = blocker
        if not waits:
            return
        in_cycle: set[int] = set()
        for cycle in meetings.wait_cycles(waits):
            in_cycle.update(cycle)
            members = sorted((self._by_slot[s] for s in cycle), key=NavRobot.priority, reverse=True)
            for robot in members:  # claims ahead that nobody can use stand in the way
                self.traffic.retract(robot.hold, robot.progress)
            for robot in members:  # the youngest goal first
                others = frozenset(s for s in cycle if s != robot.slot)
                if self._make_way(robot, others, now):
                    log.debug("cycle %s: %s makes way", cycle, robot.namespace)
                    break
            else:
                log.debug("cycle %s: nobody can make way", cycle)
        for slot, blocker in waits.items():
            if slot in in_cycle:
                continue
            robot = self._by_slot[slot]
            other = self._by_slot.get(blocker)
            still = other is None or not other.active or other.state in ("blocked", "waiting", "overridden")
            waited = now - (robot.waiting_since or now)
            if still and waited >= DETOUR_S and now - robot.detour_tried >= DETOUR_S:
                robot.detour_tried = now
                self._detour(robot, now)

    def _others_cells(self, others: frozenset[int]) -> I64:
        """The traffic cells the robots ``others`` hold, and those their paths still need."""
        cells = [self.traffic.held_by(set(others))]
        for s in others:
            other = self._by_slot.get(s)
            claims = other.hold.claims if other is not None else None
            if claims is not None:
                ahead = claims.until >= (other.progress if other is not None else 0.0)
                cells.append(claims.cells[ahead])
        return np.unique(np.concatenate(cells)).astype(np.int64)

    def _around(self, robot: NavRobot, here: tuple[float, float], now: float) -> Marks:
        """The cells every other robot near ``robot`` holds, as obstacles on its costmap
        for a while: what its own lidar would show it, as Nav2's obstacle layer does."""
        tr = self.traffic
        t = self.table
        near = np.flatnonzero(np.hypot(t.x - here[0], t.y - here[1]) <= NEAR_M)
        slots = {
            r.slot for i in near.tolist() if (r := self.robots.get(t.namespaces[i])) is not None and r is not robot
        }
        held = tr.held_by(slots)
        centres = np.array([tr.centre(int(c)) for c in held]) if len(held) else np.zeros((0, 2))
        cells = square_cells(self.costmap, centres, tr.cell / 2, robot.model.radius + self.costmap.margin)
        return Marks(cells, now + ROBOT_MARK_S)

    def _here(self, robot: NavRobot) -> tuple[float, float]:
        i = self.table.row_of(robot.namespace)
        assert i is not None
        return float(self.table.x[i]), float(self.table.y[i])

    def _detour(self, robot: NavRobot, now: float) -> bool:
        """Plan around the robots near it; take the new path if it is not much longer."""
        if robot.goal is None or robot.path is None or robot.refuge is not None:
            return False
        here = self._here(robot)
        marks = [*robot.marks, self._around(robot, here, now)]
        path = self.planner.path(robot.model, here, (robot.goal.x, robot.goal.y), robot.goal.tolerance, marks)
        if path is None:
            return False
        left = max(0.0, _length(robot.path) - robot.progress)
        if _length(path) > DETOUR_FACTOR * left + DETOUR_EXTRA_M:
            return False
        robot.recoveries += 1
        robot.marks = marks
        self._follow(robot, path, now)
        return True

    def _make_way(self, robot: NavRobot, others: frozenset[int], now: float) -> bool:
        """Let ``others`` pass: a detour if there is one, else a place off their way."""
        if now - robot.made_way < MAKE_WAY_AGAIN_S:
            return False
        if self._detour(robot, now):
            robot.made_way = now
            return True
        here = self._here(robot)
        spot = meetings.refuge(
            self.traffic, robot.slot, here, robot.hold.radius, self.standable(robot.model), self._others_cells(others)
        )
        if spot is None:
            return False
        path = self.planner.path(robot.model, here, spot, 0.05, [self._around(robot, here, now)])
        if path is None:
            return False
        robot.refuge, robot.yield_to = spot, others
        robot.yield_until = now + YIELD_WAIT_S
        robot.recoveries += 1
        robot.made_way = now
        self._follow(robot, path, now)
        return True

    # -- driving ---------------------------------------------------------------------------------

    def _drive(self, moving: list[NavRobot], bank: PathBank, rows: I64, table: RobotTable, now: float) -> None:
        n = len(moving)
        x, y, yaw = table.x[rows], table.y[rows], table.yaw[rows]
        progress = np.array([r.progress for r in moving])
        room = np.array([r.room for r in moving])
        lidar = np.empty(n)
        for k, r in enumerate(moving):
            p0, yaw0 = r.lidar_at
            stale = abs(math.remainder(float(yaw[k]) - yaw0, 2 * math.pi)) > 0.3
            lidar[k] = LOOK_AHEAD_M if stale else r.lidar_room - (r.progress - p0)
        lidar_room = np.maximum(lidar - LIDAR_STOP_M, 0.0)
        aim_x, aim_y = bank.at(progress + LOOKAHEAD_M)
        limits = Limits(
            np.array([r.model.max_linear_velocity for r in moving]),
            np.array([r.model.max_angular_velocity for r in moving]),
        )
        v, w = pursue(x, y, yaw, aim_x, aim_y, np.minimum(room, lidar_room), limits)
        for k, robot in enumerate(moving):
            robot.command = (float(v[k]), float(w[k]))
            blocked_by_lidar = lidar_room[k] <= 0.01 and room[k] > lidar_room[k]
            if robot.state in ("driving", "waiting", "blocked") and robot.refuge is None:
                if blocked_by_lidar:
                    robot.state = "blocked"
                    robot.blocked_since = robot.blocked_since if robot.blocked_since is not None else now
                    if now - robot.blocked_since >= BLOCKED_REPLAN_S:
                        self._mark_seen(robot, table, now)
                elif robot.hold.blocked_by != FREE and room[k] <= 0.02:
                    robot.state = "waiting"
                    robot.blocked_since = None
                else:
                    robot.state = "driving"
                    robot.blocked_since = None
            if robot.overridden_until >= now:
                robot.state = "overridden"
            elif robot.state == "overridden":
                robot.state = "driving"

    def _mark_seen(self, robot: NavRobot, table: RobotTable, now: float) -> None:
        """What the lidar keeps seeing in the way goes on this robot's map; then a new plan."""
        snap_scan = self._latest_scan.get(robot.namespace)
        if snap_scan is None:
            return
        ranges, px, py, pyaw = snap_scan
        off = robot.model.lidar_offset
        half = float(np.max(np.abs(robot.model.outline[:, 1])))
        front = float(np.max(robot.model.outline[:, 0]))
        hits = self._lidar.hits_ahead(ranges, (float(off[0]), float(off[1])), half, front)
        if len(hits):
            c, s = math.cos(pyaw), math.sin(pyaw)
            world = np.stack([px + hits[:, 0] * c - hits[:, 1] * s, py + hits[:, 0] * s + hits[:, 1] * c], axis=1)
            cells = disc_cells(self.costmap, world, robot.model.radius + self.costmap.margin)
            robot.marks.append(Marks(cells, now + MARK_S))
        robot.stuck_since = robot.stuck_since or now
        self._replan(robot, now)

    def _read_scans(self, table: RobotTable) -> None:
        """The room ahead of each navigating robot, from the scans of the ticks since the last
        control step (all but the newest tick's, whose lidar may still be casting: it is kept
        for the next step)."""
        self._table_x, self._table_y = table.x, table.y
        if len(self._snaps) <= 1:
            return
        ready, self._snaps = self._snaps[:-1], self._snaps[-1:]
        for snap in ready:
            wanted = [k for k, ns in enumerate(snap.scan_namespaces) if (r := self.robots.get(ns)) is not None and r.active]
            if not wanted:
                continue
            scans = snap.scans[wanted]
            robots = [self.robots[snap.scan_namespaces[k]] for k in wanted]
            idx = snap.scan_index[wanted]
            offsets = np.array([r.model.lidar_offset for r in robots], dtype=np.float64)
            half = np.array([float(np.max(np.abs(r.model.outline[:, 1]))) for r in robots])
            front = np.array([float(np.max(r.model.outline[:, 0])) for r in robots])
            sx, sy, syaw = snap.x[idx], snap.y[idx], snap.yaw[idx]
            px, py = self._lidar.points(scans, offsets)
            c, s = np.cos(syaw)[:, None], np.sin(syaw)[:, None]
            wx, wy = sx[:, None] + px * c - py * s, sy[:, None] + px * s + py * c
            owner = self._owner_at(wx, wy)
            mine = np.array([r.slot for r in robots], dtype=np.int64)[:, None]
            # what the map or the traffic explains is not the lidar's business: the plan keeps
            # off walls, the traffic keeps robots apart
            known = ((owner != FREE) & (owner != mine)) | self._on_map(wx, wy)
            rooms = self._lidar.room_ahead(px, py, half, front, known)
            for k, robot in enumerate(robots):
                robot.lidar_room = float(rooms[k])
                robot.lidar_at = (robot.progress, float(syaw[k]))
                self._latest_scan[robot.namespace] = (scans[k], float(sx[k]), float(sy[k]), float(syaw[k]))

    def _owner_at(self, wx: F64, wy: F64) -> I64:
        """The traffic's holder of each world point's cell (FREE off the floor)."""
        tr = self.traffic
        col = np.floor((wx - tr.x0) / tr.cell).astype(np.int64)
        row = np.floor((wy - tr.y0) / tr.cell).astype(np.int64)
        on = (col >= 0) & (col < tr.width) & (row >= 0) & (row < tr.height)
        out = np.full(wx.shape, FREE, dtype=np.int64)
        out[on] = tr.owner[row[on] * tr.width + col[on]]
        return out

    def _on_map(self, wx: F64, wy: F64) -> npt.NDArray[np.bool_]:
        """Whether each world point lies on (or within MAP_HIT_M of) a wall or obstacle of the map."""
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
            if robot.refuge is not None:
                self._yield_check(robot, x, y, now)
                continue
            if goal.timeout > 0 and now - robot.started >= goal.timeout:
                self._end(robot, "failed", "timeout", f"not reached within {goal.timeout:g} s", now)
                continue
            stuck = robot.stuck_since
            if robot.state in ("blocked", "waiting") and stuck is None:
                robot.stuck_since = now
            elif robot.state not in ("blocked", "waiting", "planning"):
                robot.stuck_since = None
            if robot.stuck_since is not None and now - robot.stuck_since >= self.config.patience:
                self._end(robot, "failed", "blocked", f"no way forward for {self.config.patience:g} s", now)
                continue
            if robot.state == "blocked" and robot.path is None and now - (robot.stuck_since or now) >= BLOCKED_REPLAN_S:
                robot.state = "planning"  # try again: the way may have cleared
                continue
            if math.hypot(goal.x - x, goal.y - y) <= goal.tolerance:
                if goal.yaw is None or abs(math.remainder(goal.yaw - yaw, 2 * math.pi)) <= goal.yaw_tolerance:
                    self._end(robot, "reached", "", "goal reached", now)
                else:
                    lim = Limits(np.array([robot.model.max_linear_velocity]), np.array([robot.model.max_angular_velocity]))
                    w = turn_to(np.array([yaw]), np.array([goal.yaw]), lim)
                    robot.command = (0.0, float(w[0]))

    def _yield_check(self, robot: NavRobot, x: float, y: float, now: float) -> None:
        assert robot.refuge is not None
        there = math.hypot(robot.refuge[0] - x, robot.refuge[1] - y) <= 0.08
        if there:
            robot.command = (0.0, 0.0)
        others_gone = all(
            (o := self._by_slot.get(s)) is None or not o.active or o.hold.blocked_by != robot.slot
            for s in robot.yield_to
        )
        if (there and others_gone and now >= robot.yield_until - YIELD_WAIT_S + 2.0) or now >= robot.yield_until:
            robot.refuge, robot.yield_to = None, frozenset()
            self._replan(robot, now)

    def _end(self, robot: NavRobot, status: str, reason: str, message: str, now: float) -> NavigationResult:
        goal = robot.goal or NavigateRequest(x=0.0, y=0.0)
        pose = Pose2D()
        i = self.table.row_of(robot.namespace)
        if i is not None:
            t = self.table
            pose = Pose2D(x=float(t.x[i]), y=float(t.y[i]), yaw=float(t.yaw[i]))
        result = NavigationResult(
            goal_id=robot.goal_id,
            robot=robot.namespace,
            stamp=Time.from_seconds(now),
            status=status,  # type: ignore[arg-type]
            reason=reason,
            message=message,
            goal=Pose2D(x=goal.x, y=goal.y, yaw=goal.yaw or 0.0),
            pose=pose,
            navigation_time=now - robot.started,
            distance_travelled=robot.travelled,
            recoveries=robot.recoveries,
        )
        robot.state = status
        robot.result = result
        robot.command = (0.0, 0.0)
        robot.path, robot.refuge, robot.yield_to = None, None, frozenset()
        robot.ended_unreported = reason or status
        if self._traffic is not None:
            self._traffic.follow(robot.hold, None)
        self._events.results.append(result)
        self._events.plans.append(NavigationPath(goal_id=robot.goal_id, robot=robot.namespace, stamp=result.stamp, points=[]))
        self._drive_of = None
        self._stopping.append(robot.namespace)
        return result

    # -- reporting -------------------------------------------------------------------------------

    def _feedback(self, table: RobotTable, now: float) -> None:
        self._sync(table)
        stamp = Time.from_seconds(now)
        for robot in self.robots.values():
            if not robot.active:
                continue
            i = self._row[robot.namespace]
            left = max(0.0, _length(robot.path) - robot.progress) if robot.path is not None else 0.0
            other = self._by_slot.get(robot.hold.blocked_by) if robot.state == "waiting" else None
            fb = NavigationFeedback(
                goal_id=robot.goal_id,
                robot=robot.namespace,
                stamp=stamp,
                state=robot.state,
                pose=Pose2D(x=float(table.x[i]), y=float(table.y[i]), yaw=float(table.yaw[i])),
                distance_remaining=left,
                estimated_time_remaining=left / robot.model.max_linear_velocity,
                navigation_time=now - robot.started,
                recoveries=robot.recoveries,
                other=other.namespace if other is not None else "",
            )
            robot.feedback = fb
            self._events.feedback.append(fb)

    def _fleet_summary(self, now: float) -> None:
        rows = []
        for robot in self.robots.values():
            if not robot.active and not robot.ended_unreported:
                continue
            goal = robot.goal or NavigateRequest(x=0.0, y=0.0)
            left = max(0.0, _length(robot.path) - robot.progress) if robot.path is not None else 0.0
            rows.append(
                RobotNavigation(
                    robot=robot.namespace,
                    goal_id=robot.goal_id,
                    state=robot.state,
                    goal=Pose2D(x=goal.x, y=goal.y, yaw=goal.yaw or 0.0),
                    distance_remaining=left,
                    reason="" if robot.active else robot.ended_unreported,
                )
            )
            robot.ended_unreported = ""
        if rows:
            self._events.fleet = FleetNavigation(stamp=Time.from_seconds(now), robots=rows)


def _length(path: F64 | None) -> float:
    if path is None or len(path) < 2:
        return 0.0
    return float(np.hypot(*np.diff(path, axis=0).T).sum())


def _no_path_message(robot: NavRobot, here: tuple[float, float]) -> str:
    goal = robot.goal
    assert goal is not None
    return f"no path for a {robot.model.name} from ({here[0]:.2f}, {here[1]:.2f}) to ({goal.x:g}, {goal.y:g})"


def _check_goal(req: NavigateRequest) -> None:
    for name in ("x", "y", "tolerance", "yaw_tolerance", "timeout"):
        value = getattr(req, name)
        if not math.isfinite(value):
            raise FleetError(ErrorCode.NON_FINITE, f"{name} must be finite, got {value}", name)
    if req.yaw is not None and not math.isfinite(req.yaw):
        raise FleetError(ErrorCode.NON_FINITE, f"yaw must be finite, got {req.yaw}", "yaw")
    if not 0.0 < req.tolerance <= MAX_TOLERANCE_M:
        raise FleetError(ErrorCode.INVALID_VALUE, f"tolerance must be in (0, {MAX_TOLERANCE_M:g}] m, got {req.tolerance:g}", "tolerance")
    if not 0.0 < req.yaw_tolerance <= math.pi:
        raise FleetError(ErrorCode.INVALID_VALUE, f"yaw_tolerance must be in (0, pi] rad, got {req.yaw_tolerance:g}", "yaw_tolerance")
    if req.timeout < 0:
        raise FleetError(ErrorCode.INVALID_VALUE, f"timeout must be >= 0 s (0: none), got {req.timeout:g}", "timeout")
    if req.goal_id and (len(req.goal_id) > MAX_GOAL_ID_LENGTH or GOAL_ID.fullmatch(req.goal_id) is None):
        raise FleetError(
            ErrorCode.INVALID_VALUE,
            f"goal_id must be 1..{MAX_GOAL_ID_LENGTH} of letters, digits, '_', '.', ':', '-'",
            "goal_id",
        )


def _with_id(goal: NavigateRequest, robot: str, goal_id: str) -> NavigateRequest:
    import msgspec

    return msgspec.structs.replace(goal, robot=robot, goal_id=goal_id)
