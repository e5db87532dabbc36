"""The simulation core: robots, the fixed-step tick, sensors, spawn rules and reset.

Free of any transport. A single thread owns a :class:`Simulation` (and through it the
pymunk space). Per-robot state lives in the robot table (simd/core/robots.py), one row per
robot in spawn order, so that control, odometry and lidar are computed for the whole fleet
at once; each tick hands out a :class:`~simd.core.snapshot.TickSnapshot`.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Mapping
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from fleetcommon.arrays import F32, F64, I64
from protocol.control import MODELS as MODEL_NAMES
from protocol.control import SpawnRequest
from protocol.errors import ErrorCode, FleetError, not_found
from protocol.names import check_name
from simd.core import drive, sensor_model
from simd.core.ghosts import GhostColumns, Ghosts
from simd.core.lidar import LidarSpec, StaticScene, cast, outline_segments
from simd.core.models import MODELS, RobotModel
from simd.core.physics import Physics
from simd.core.robots import Robot, RobotTable
from simd.core.snapshot import RobotState, TickSnapshot
from simd.core.worldfile import WorldGeometry

#: Scans are batched: a scan phase takes up to this many robots before the next phase opens.
#: Few robots then scan in one lidar call per 5 Hz period (the kernel's per-call overhead
#: dominates small batches); many robots spread evenly over the six phases of a period.
SCAN_BATCH = 128
#: Motion closer than this to the commanded arc counts as unobstructed (m or rad).
_FREE_MOTION_TOLERANCE = 1e-7


@dataclass(frozen=True)
class SimConfig:
    dt: float = 1.0 / 30.0  # the diff-drive plugin's 30 Hz update; odometry every tick
    substeps: int = 2  # pymunk steps per tick: contact depth stays ~2 mm (see physics.py)
    seed: int = 0
    noise: bool = True
    noise_stddev: float = 0.01  # LDS-01 Gaussian noise of the Gazebo model
    cmd_timeout: float = 0.5  # s of sim time without cmd_vel before a robot stops; 0 = never
    max_robots: int = 5000
    scan_every: int = 6  # ticks between scans of one robot: 5 Hz at 30 Hz ticks
    lidar: LidarSpec = field(default_factory=LidarSpec)
    #: cast the scans on a thread of their own, beside the next tick's physics (both release
    #: the GIL): the same scans, bit for bit, since the lidar's jobs run in tick order
    lidar_thread: bool = True
    #: wheel slip: each wheel's travel in a tick is off by this fraction, times a standard normal
    #: draw (its own seeded generator), so the odometry a robot reports drifts from its true
    #: pose as a real robot's does; 0 = exact odometry (ground truth, as Gazebo's default)
    odom_noise: float = 0.0


def _slip_rng(seed: int) -> np.random.Generator:
    """The wheel-slip draws' own generator: the lidar noise's stream stays as it was."""
    return np.random.default_rng(np.random.SeedSequence([seed, 1]))


def wrap_angle(a: float) -> float:
    return math.atan2(math.sin(a), math.cos(a))


class Simulation:
    """The world and its robots, advanced one fixed tick at a time by the thread that owns it."""

    def __init__(self, world: WorldGeometry, config: SimConfig | None = None) -> None:
        self.world = world
        self.config = config or SimConfig()
        if self.config.seed < 0:
            raise ValueError("seed must be a non-negative integer")
        self.physics = Physics(world, self.config.substeps)
        self.scene = StaticScene(world.segments(), world.circles, self.config.lidar.range_max)
        self.tick = 0
        self.epoch = 0  # resets so far
        self._seed = self.config.seed
        self.rng = np.random.default_rng(np.random.SeedSequence(self._seed))
        self.slip_rng = _slip_rng(self._seed)
        self.robots = RobotTable()
        self._next_rid = 0
        self._phase_load = [0] * self.config.scan_every
        self._due_of: int | None = None  # the table generation _due_by_tick was worked out for
        self._due_by_tick: list[I64] = []
        self._lidar = ThreadPoolExecutor(1, "lidar") if self.config.lidar_thread else None
        self._last_scans: Future[F32] | None = None
        #: the scans of a tick on which no lidar fires (most ticks), handed out tick after tick
        self._no_scans = np.zeros((0, self.config.lidar.samples), dtype=np.float32)
        self._no_scans.flags.writeable = False
        #: robots simulated elsewhere (another daemon of a shared fleet), seen and felt here
        self._ghosts = Ghosts(self.physics, world.bounds)

    # -- queries ----------------------------------------------------------------------

    @property
    def time(self) -> float:
        return self.tick * self.config.dt

    def start_at(self, tick: int) -> None:
        """Start an empty world's clock at ``tick`` (a daemon joining a fleet takes its clock)."""
        if len(self.robots) or self.tick:
            raise ValueError("only an empty world that has not ticked can start at another tick")
        if tick < 0:
            raise ValueError("tick must be >= 0")
        self.tick = tick

    @property
    def seed(self) -> int:
        return self._seed

    def __len__(self) -> int:
        return len(self.robots)

    def find(self, key: str) -> Robot | None:
        """A robot by name or namespace."""
        return self.robots.find(key)

    def state(self, robot: Robot) -> RobotState:
        return self._state_at(robot, self.robots.row(robot))

    def _state_at(self, robot: Robot, i: int) -> RobotState:
        t = self.robots
        return RobotState(
            name=robot.name,
            namespace=robot.namespace,
            model=robot.model,
            x=float(t.x[i]),
            y=float(t.y[i]),
            yaw=float(t.yaw[i]),
            linear_velocity=float(t.vx[i]),
            angular_velocity=float(t.wz[i]),
            spawn_pose=robot.spawn_pose,
            lateral_velocity=float(t.vy[i]),
            odom=(float(t.odom_x[i]), float(t.odom_y[i]), float(t.odom_yaw[i])),
        )

    def states(self) -> list[RobotState]:
        return [self._state_at(r, i) for i, r in enumerate(self.robots.robots)]

    # -- spawn / delete -------------------------------------------------------------------

    def check_spawn_fields(self, req: SpawnRequest) -> tuple[str, str, RobotModel]:
        """The checks of a spawn request that need nothing of the world (names, model, finite
        pose), in the order :meth:`validate_spawn` makes them; any thread may call it."""
        name = check_name(req.name, "name")
        namespace = check_name(req.namespace if req.namespace else name, "namespace")
        model = MODELS.get(req.model)
        if model is None:
            close = difflib.get_close_matches(str(req.model), MODEL_NAMES, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise FleetError(
                ErrorCode.UNKNOWN_MODEL,
                f"unknown model {req.model!r}: choose one of {', '.join(MODEL_NAMES)}{hint}",
                "model",
            )
        for fname in ("x", "y", "yaw"):
            v = getattr(req, fname)
            if not math.isfinite(v):
                raise FleetError(ErrorCode.NON_FINITE, f"{fname} must be finite, got {v}", fname)
        return name, namespace, model

    def validate_spawn(
        self, req: SpawnRequest, robots_may_overlap: bool = False
    ) -> tuple[str, str, RobotModel, float, float, float]:
        """Check a spawn request against every rule; return the normalised fields. With
        ``robots_may_overlap`` a robot in the way does not count (see :meth:`spawn`)."""
        name, namespace, model = self.check_spawn_fields(req)
        if len(self.robots) >= self.config.max_robots:
            raise FleetError(
                ErrorCode.ROBOT_LIMIT,
                f"the daemon's robot limit ({self.config.max_robots}) is reached",
            )
        for key, fname in ((name, "name"), (namespace, "namespace")):
            other = self.robots.find(key)
            if other is not None:
                raise FleetError(
                    ErrorCode.ALREADY_EXISTS,
                    f"Entity [{key}] already exists (robot {other.name!r}, namespace {other.namespace!r})",
                    fname,
                )
        x, y, yaw = float(req.x), float(req.y), wrap_angle(float(req.yaw))
        self._check_place(model, x, y, yaw, robots=not robots_may_overlap)
        return name, namespace, model, x, y, yaw

    def outside(self, model: RobotModel, x: float, y: float, yaw: float) -> bool:
        """Whether the model's outline at this pose leaves the world's bounds (any thread)."""
        c, s = math.cos(yaw), math.sin(yaw)
        ox = x + model.outline[:, 0] * c - model.outline[:, 1] * s
        oy = y + model.outline[:, 0] * s + model.outline[:, 1] * c
        x0, x1, y0, y1 = self.world.bounds
        return bool(ox.min() < x0 or ox.max() > x1 or oy.min() < y0 or oy.max() > y1)

    def _check_place(
        self, model: RobotModel, x: float, y: float, yaw: float, ignore: int | None = None, robots: bool = True
    ) -> None:
        """Refuse a pose that puts the model outside the world or on a wall or another robot
        (robot ``ignore``, the one being moved, does not count; no robot without ``robots``)."""
        if self.outside(model, x, y, yaw):
            x0, x1, y0, y1 = self.world.bounds
            raise FleetError(
                ErrorCode.OUT_OF_BOUNDS,
                f"pose ({x:g}, {y:g}) puts the {model.name} outside the world "
                f"{self.world.name!r}: x in [{x0:g}, {x1:g}], y in [{y0:g}, {y1:g}]",
                "x",
            )
        hit = self.physics.blocker(model, x, y, yaw, ignore, robots)
        if hit is not None:
            if hit < 0:
                what = "a wall or obstacle"
            else:
                what = next((f"robot {r.name!r}" for r in self.robots.robots if r.rid == hit), "a robot")
            raise FleetError(
                ErrorCode.COLLISION,
                f"a {model.name} at ({x:g}, {y:g}, yaw {yaw:.3g}) would overlap {what}",
                "x",
            )

    def spawn(
        self,
        req: SpawnRequest,
        *,
        spawn_pose: tuple[float, float, float] | None = None,
        odom: tuple[float, float, float] | None = None,
        robots_may_overlap: bool = False,
    ) -> Robot:
        """Add a robot, or raise :class:`FleetError` leaving the world untouched. A robot
        brought back from a saved state keeps the ``spawn_pose`` a reset returns it to and the
        ``odom`` pose its odometry had reached; a new one starts with both at its pose.
        ``robots_may_overlap``: a spawn already promised (answered at once, with room to
        spare then) is made even if a robot pushed since has come too near; the physics
        parts them, as Gazebo's spawns into a robot do."""
        name, namespace, model, x, y, yaw = self.validate_spawn(req, robots_may_overlap)
        ox, oy, oyaw = odom if odom is not None else (x, y, yaw)
        open_phases = [p for p, load in enumerate(self._phase_load) if load < SCAN_BATCH]
        phase = open_phases[0] if open_phases else int(np.argmin(self._phase_load))
        self._phase_load[phase] += 1
        robot = Robot(self._next_rid, name, namespace, model, spawn_pose or (x, y, yaw), phase)
        self._next_rid += 1
        self.physics.add_robot(robot.rid, model, x, y, yaw)
        self.robots.append(
            robot,
            rid=robot.rid,
            last_cmd=self.tick,
            x=x,
            y=y,
            yaw=yaw,
            odom_x=ox,
            odom_y=oy,
            odom_yaw=oyaw,
            sep=model.wheel_separation,
            max_v=model.max_linear_velocity,
            max_w=model.max_angular_velocity,
            acc=model.max_wheel_acceleration,
            lidar_off=model.lidar_offset,
            outline=model.outline,
            phase=phase,
        )
        return robot

    def delete(self, key: str) -> RobotState:
        """Remove the robot with this name or namespace; return its last state."""
        return self.delete_many([key])[0]

    def delete_many(self, keys: list[str]) -> list[RobotState]:
        """Remove the robots with these names or namespaces at once (an environment clearing
        its fleet); their last states, in the order asked. Nothing is removed if one is
        missing or named twice."""
        robots = [self.robots.find(key) for key in keys]
        for key, robot in zip(keys, robots, strict=True):
            if robot is None:
                raise not_found(key)
        found = [r for r in robots if r is not None]
        if len({r.rid for r in found}) < len(found):
            raise FleetError(ErrorCode.INVALID_VALUE, "a robot is named twice", "name")
        last = [self.state(r) for r in found]
        for robot in found:
            self.physics.remove_robot(robot.rid)
            self._phase_load[robot.scan_phase] -= 1
        self.robots.remove_many(found)
        return last

    def place(self, key: str, x: float, y: float, yaw: float) -> RobotState:
        """Move a robot (name or namespace) to a pose at once, at rest, as ROS's ``initialpose``
        moves nav2_loopback_sim's robot; or raise :class:`FleetError` and move nothing. The
        rules are a spawn's (finite, inside the world, clear of walls and other robots), and
        its odometry starts again at the new pose, as a spawned robot's does."""
        robot = self.robots.find(key)
        if robot is None:
            raise not_found(key)
        for fname, v in (("x", x), ("y", y), ("yaw", yaw)):
            if not math.isfinite(v):
                raise FleetError(ErrorCode.NON_FINITE, f"{fname} must be finite, got {v}", fname)
        x, y, yaw = float(x), float(y), wrap_angle(float(yaw))
        self._check_place(robot.model, x, y, yaw, ignore=robot.rid)
        t = self.robots
        i = t.row(robot)
        self.physics.place(robot.rid, x, y, yaw)
        # new arrays, not writes into the old ones: a snapshot handed out may still hold them
        for name, value in (("x", x), ("y", y), ("yaw", yaw), ("vx", 0.0), ("vy", 0.0), ("wz", 0.0)):
            column = getattr(t, name).copy()
            column[i] = value
            setattr(t, name, column)
        odom = [a.copy() for a in (t.odom_x, t.odom_y, t.odom_yaw)]
        odom[0][i], odom[1][i], odom[2][i] = x, y, yaw
        t.odom_x, t.odom_y, t.odom_yaw = odom
        for a in (t.target_v, t.target_w, t.wheel_l, t.wheel_r):
            a[i] = 0.0
        return self._state_at(robot, i)

    # -- control ------------------------------------------------------------------------

    def command(self, robot: Robot, linear_x: float, angular_z: float) -> None:
        """Set a robot's velocity target (clamped later); refreshes its watchdog."""
        i = self.robots.row(robot)
        t = self.robots
        t.target_v[i] = linear_x
        t.target_w[i] = angular_z
        t.last_cmd[i] = self.tick

    def command_many(self, commands: Mapping[str, tuple[float, float]]) -> int:
        """Apply the latest command per namespace; returns how many matched a robot."""
        if not commands:
            return 0
        t = self.robots
        rows: list[int] = []
        vs: list[float] = []
        ws: list[float] = []
        for ns, (v, w) in commands.items():
            i = t.row_of(ns)
            if i is not None:
                rows.append(i)
                vs.append(v)
                ws.append(w)
        if rows:
            self.command_rows(np.asarray(rows), np.asarray(vs), np.asarray(ws))
        return len(rows)

    def command_rows(self, rows: I64 | slice, v: F64, w: F64) -> None:
        """Command the robots of table ``rows`` at once (rows from ``robots.row_of``, or a
        slice of them, valid while the table's ``generation`` is the same); refreshes their
        watchdogs."""
        t = self.robots
        t.target_v[rows] = v
        t.target_w[rows] = w
        t.last_cmd[rows] = self.tick

    def reset(self, seed: int | None = None) -> None:
        """Time to zero, robots to their spawn poses at rest, noise reseeded."""
        if seed is not None:
            if seed < 0:
                raise FleetError(ErrorCode.INVALID_VALUE, "seed must be >= 0", "seed")
            self._seed = seed
        self._finish_scans()  # the lidar draws noise from the generator about to be replaced
        self.rng = np.random.default_rng(np.random.SeedSequence(self._seed))
        self.slip_rng = _slip_rng(self._seed)
        self.tick = 0
        self.epoch += 1
        t = self.robots
        n = len(t)
        # new arrays, not writes into the old ones: a snapshot handed out may still hold them
        x, y, yaw = np.empty(n), np.empty(n), np.empty(n)
        for i, r in enumerate(t.robots):
            x[i], y[i], yaw[i] = r.spawn_pose
            self.physics.place(r.rid, *r.spawn_pose)
        t.x, t.y, t.yaw = x, y, yaw
        t.odom_x, t.odom_y, t.odom_yaw = x.copy(), y.copy(), yaw.copy()
        t.vx, t.vy, t.wz = np.zeros(n), np.zeros(n), np.zeros(n)
        for a in (t.target_v, t.target_w, t.wheel_l, t.wheel_r):
            a[:] = 0.0
        t.last_cmd[:] = 0

    # -- robots simulated elsewhere -------------------------------------------------------

    def set_ghosts(self, ghosts: Mapping[str, tuple[str, float, float, float]] | GhostColumns) -> None:
        """The robots of the other daemons of a shared fleet, at their latest known poses
        (namespace -> (model name, x, y, yaw), or as columns): kinematic bodies this world's
        robots bump into, outlines its lidar sees (simd/core/ghosts.py). Ghosts not named
        again leave; unknown models and poses that are not finite are left out."""
        self._ghosts.update(ghosts if isinstance(ghosts, GhostColumns) else GhostColumns.from_mapping(ghosts))

    @property
    def ghosts(self) -> dict[str, tuple[RobotModel, float, float, float]]:
        """The ghosts now: namespace -> (model, x, y, yaw)."""
        return self._ghosts.as_dict()

    def _with_ghosts(self) -> tuple[F64, F64, F64, I64, F64]:
        """The robots' columns the lidar sees: this world's robots, then the ghosts."""
        t = self.robots
        columns = self._ghosts.lidar_columns()
        if columns is None:
            return t.x, t.y, t.yaw, t.rid, t.outline
        gx, gy, gyaw, grid, gout = columns
        return (np.concatenate([t.x, gx]), np.concatenate([t.y, gy]), np.concatenate([t.yaw, gyaw]),
                np.concatenate([t.rid, grid]), np.concatenate([t.outline, gout]))  # fmt: skip

    # -- the tick -------------------------------------------------------------------------

    def step(self, scans_wanted: bool = False) -> TickSnapshot:
        """Advance one fixed tick; return odometry for all robots and the scans due.
        ``scans_wanted``: the caller reads this tick's scans at once (a step's last tick, whose
        reply carries them): they are cast on this thread, not handed to the lidar's and waited
        for (the same scans, bit for bit)."""
        cfg = self.config
        dt = cfg.dt
        t = self.robots
        v, w, dx, dy = drive.advance(self.tick, cfg.cmd_timeout, dt, t)
        self.physics.step(t.rid, dx / dt, dy / dt, w, dt, self._ghosts.velocities(dt, t.x, t.y))
        x, y, yaw = self.physics.poses(t.rid)
        old_x, old_y, old_yaw = t.x, t.y, t.yaw
        # reported twist: the wheels' when motion was free, the achieved motion otherwise
        t.vx, t.vy, t.wz, t.yaw = drive.report_twist(
            dt, _FREE_MOTION_TOLERANCE, t.x, t.y, t.yaw, x, y, yaw, v, w, dx, dy
        )
        t.x, t.y = x, y
        twist = (t.vx, t.vy, t.wz)  # what the odometry reports moving at
        if cfg.odom_noise > 0.0:
            twist = self._slip(old_x, old_y, old_yaw)
        else:  # exact odometry: the same arrays, no work
            t.odom_x, t.odom_y, t.odom_yaw = t.x, t.y, t.yaw
        self.tick += 1

        due = self._due_rows(t)[self.tick % cfg.scan_every]
        scans: F32 | Future[F32]
        if len(due) == 0:
            scans = self._no_scans
        elif self._lidar is None:
            scans = self._scan(due, *self._with_ghosts(), t.lidar_off)
        elif scans_wanted:  # waited for at once: no hand-over, no thread to wake (~5 % of a fleet
            # env's step at 1 000 robots); the lidar's earlier jobs first, which draw noise before
            self._finish_scans()
            scans = self._scan(due, *self._with_ghosts(), t.lidar_off)
        else:  # the columns are replaced, never written, from tick to tick: safe to read there
            scans = self._lidar.submit(self._scan, due, *self._with_ghosts(), t.lidar_off)
            self._last_scans = scans
        return TickSnapshot(
            tick=self.tick,
            time=self.time,
            namespaces=t.namespaces,
            x=t.odom_x,
            y=t.odom_y,
            yaw=t.odom_yaw,
            linear_x=twist[0],
            linear_y=twist[1],
            angular_z=twist[2],
            scan_namespaces=[t.namespaces[i] for i in due.tolist()],
            scan_rows=scans,
            epoch=self.epoch,
            scan_index=due,
            true_pose=(t.x, t.y, t.yaw) if cfg.odom_noise > 0.0 else None,
            generation=t.generation,
        )

    def _due_rows(self, t: RobotTable) -> list[I64]:
        """The table rows whose lidar fires on a tick, by the tick's place in the scan period
        (a robot scans when ``(tick - phase) % scan_every == 0``). Worked out again only when
        the table changes: rows and phases move only with a spawn or delete, which give the
        table a new generation."""
        if self._due_of != t.generation:
            k = self.config.scan_every
            period_tick = t.phase % k
            self._due_by_tick = [np.flatnonzero(period_tick == r) for r in range(k)]
            for rows in self._due_by_tick:  # handed out tick after tick (TickSnapshot.scan_index)
                rows.flags.writeable = False
            self._due_of = t.generation
        return self._due_by_tick

    def _slip(self, old_x: F64, old_y: F64, old_yaw: F64) -> tuple[F64, F64, F64]:
        """Odometry from the wheels' travel with slip: each wheel's share of the tick's true motion
        (forward along the old heading, and the turn) off by ``odom_noise`` times a normal draw;
        sideways motion (a robot pushed) is not seen by the wheels at all. Returns the twist the
        wheels measured (forward, sideways 0, turn rate), which the odometry reports with the
        pose, as a robot's encoders give both."""
        t = self.robots
        n = len(t)
        ds = (t.x - old_x) * np.cos(old_yaw) + (t.y - old_y) * np.sin(old_yaw)
        dth = np.arctan2(np.sin(t.yaw - old_yaw), np.cos(t.yaw - old_yaw))
        half = dth * t.sep / 2.0
        slip = 1.0 + self.config.odom_noise * self.slip_rng.standard_normal((2, n))
        left, right = (ds - half) * slip[0], (ds + half) * slip[1]
        ds_o, dth_o = (left + right) / 2.0, (right - left) / t.sep
        mid = t.odom_yaw + dth_o / 2.0
        t.odom_x = t.odom_x + ds_o * np.cos(mid)  # new arrays: a snapshot may still hold the old
        t.odom_y = t.odom_y + ds_o * np.sin(mid)
        t.odom_yaw = np.arctan2(np.sin(t.odom_yaw + dth_o), np.cos(t.odom_yaw + dth_o))
        dt = self.config.dt
        return ds_o / dt, np.zeros(n), dth_o / dt

    def _scan(self, rows: I64, x: F64, y: F64, yaw: F64, rid: I64, outline: F64, lidar_off: F64) -> F32:
        """The scans of the robots in ``rows``, against every robot's outline at (x, y, yaw)."""
        spec = self.config.lidar
        c, s = np.cos(yaw), np.sin(yaw)
        dyn_segments = outline_segments(x, y, c, s, outline)  # every robot's outline in the world frame
        dyn_owner = np.repeat(rid, outline.shape[1])
        off = lidar_off[rows]
        cr, sr = c[rows], s[rows]
        origins = np.stack(
            [
                x[rows] + off[:, 0] * cr - off[:, 1] * sr,
                y[rows] + off[:, 0] * sr + off[:, 1] * cr,
            ],
            axis=1,
        )
        raw = cast(self.scene, spec, origins, yaw[rows], rid[rows], dyn_segments, dyn_owner)
        return self._sensor_model(raw)

    def _finish_scans(self) -> None:
        """Wait for the lidar's queued scans (they draw from the noise generator)."""
        if self._last_scans is not None:
            self._last_scans.result()
            self._last_scans = None

    def close(self) -> None:
        """Finish the lidar's work and stop its thread (the simulation is not used after)."""
        self._finish_scans()
        if self._lidar is not None:
            self._lidar.shutdown(wait=True)

    def _sensor_model(self, raw: F32) -> F32:
        """Gazebo RaySensor masking and noise (simd/core/sensor_model.py)."""
        cfg = self.config
        return sensor_model.apply(raw, cfg.lidar, cfg.noise_stddev if cfg.noise else 0.0, self.rng)
