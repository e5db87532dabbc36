"""The simulation core: robots, the fixed-step tick, sensors, spawn rules and reset.

Free of any transport. A single thread owns a :class:`Simulation` (and through it the
pymunk space). Per-robot state lives in numpy arrays, one row per robot in spawn order,
so that control, odometry and lidar are computed for the whole fleet at once.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from protocol.control import MODELS as MODEL_NAMES
from protocol.control import SpawnRequest
from protocol.errors import ErrorCode, FleetError
from protocol.names import check_name
from simd.core import drive, sensor_model
from simd.core.lidar import LidarSpec, StaticScene, cast
from simd.core.models import MODELS, RobotModel
from simd.core.physics import Physics
from simd.core.worldfile import WorldGeometry

F64 = npt.NDArray[np.float64]
F32 = npt.NDArray[np.float32]
I64 = npt.NDArray[np.int64]

#: Odometry covariance diagonals of gazebo_ros_diff_drive (x, y, z, roll, pitch, yaw).
ODOM_COVARIANCE_DIAGONAL = (1e-5, 1e-5, 1e12, 1e12, 1e12, 1e-3)
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


@dataclass
class Robot:
    rid: int
    name: str
    namespace: str
    model: RobotModel
    spawn_pose: tuple[float, float, float]
    scan_phase: int


@dataclass(frozen=True)
class RobotState:
    """A robot as reported by list/spawn/delete."""

    name: str
    namespace: str
    model: RobotModel
    x: float
    y: float
    yaw: float
    linear_velocity: float
    angular_velocity: float
    spawn_pose: tuple[float, float, float]


@dataclass(frozen=True)
class TickOutput:
    """What one tick measured: odometry of every robot, scans of those due."""

    tick: int
    time: float
    namespaces: list[str]
    x: F64
    y: F64
    yaw: F64
    linear_x: F64  # body frame
    linear_y: F64
    angular_z: F64
    scan_namespaces: list[str]
    scans: F32  # (k, samples)


def wrap_angle(a: float) -> float:
    return math.atan2(math.sin(a), math.cos(a))


class Simulation:
    def __init__(self, world: WorldGeometry, config: SimConfig | None = None) -> None:
        self.world = world
        self.config = config or SimConfig()
        if self.config.seed < 0:
            raise ValueError("seed must be a non-negative integer")
        self.physics = Physics(world, self.config.substeps)
        self.scene = StaticScene(world.segments(), world.circles, self.config.lidar.range_max)
        self.tick = 0
        self._seed = self.config.seed
        self.rng = np.random.default_rng(np.random.SeedSequence(self._seed))
        self._robots: list[Robot] = []
        # every tick hands out this list: replaced (never changed in place) on spawn and delete
        self._namespaces: list[str] = []
        self._by_key: dict[str, Robot] = {}  # names and namespaces share one key space
        self._row_of: dict[str, int] = {}  # namespace -> row in the state arrays
        self._next_rid = 0
        self._phase_load = [0] * self.config.scan_every
        n = 0
        self._rid: I64 = np.zeros(n, dtype=np.int64)
        self._target_v: F64 = np.zeros(n)
        self._target_w: F64 = np.zeros(n)
        self._wheel_l: F64 = np.zeros(n)
        self._wheel_r: F64 = np.zeros(n)
        self._last_cmd: I64 = np.zeros(n, dtype=np.int64)
        self._x: F64 = np.zeros(n)
        self._y: F64 = np.zeros(n)
        self._yaw: F64 = np.zeros(n)
        self._vx: F64 = np.zeros(n)
        self._vy: F64 = np.zeros(n)
        self._wz: F64 = np.zeros(n)
        self._sep: F64 = np.zeros(n)
        self._max_v: F64 = np.zeros(n)
        self._max_w: F64 = np.zeros(n)
        self._acc: F64 = np.zeros(n)
        self._lidar_off: F64 = np.zeros((n, 2))
        self._outline: F64 = np.zeros((n, 12, 2))
        self._phase: I64 = np.zeros(n, dtype=np.int64)

    # -- queries ----------------------------------------------------------------------

    @property
    def time(self) -> float:
        return self.tick * self.config.dt

    @property
    def seed(self) -> int:
        return self._seed

    def __len__(self) -> int:
        return len(self._robots)

    def find(self, key: str) -> Robot | None:
        """A robot by name or namespace."""
        return self._by_key.get(key)

    def _row(self, robot: Robot) -> int:
        return self._row_of[robot.namespace]

    def state(self, robot: Robot) -> RobotState:
        i = self._row(robot)
        return self._state_at(robot, i)

    def _state_at(self, robot: Robot, i: int) -> RobotState:
        return RobotState(
            name=robot.name,
            namespace=robot.namespace,
            model=robot.model,
            x=float(self._x[i]),
            y=float(self._y[i]),
            yaw=float(self._yaw[i]),
            linear_velocity=float(self._vx[i]),
            angular_velocity=float(self._wz[i]),
            spawn_pose=robot.spawn_pose,
        )

    def states(self) -> list[RobotState]:
        return [self._state_at(r, i) for i, r in enumerate(self._robots)]

    # -- spawn / delete -------------------------------------------------------------------

    def validate_spawn(self, req: SpawnRequest) -> tuple[str, str, RobotModel, float, float, float]:
        """Check a spawn request against every rule; return the normalised fields."""
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
        if len(self._robots) >= self.config.max_robots:
            raise FleetError(
                ErrorCode.ROBOT_LIMIT,
                f"the daemon's robot limit ({self.config.max_robots}) is reached",
            )
        for key, fname in ((name, "name"), (namespace, "namespace")):
            other = self._by_key.get(key)
            if other is not None:
                raise FleetError(
                    ErrorCode.ALREADY_EXISTS,
                    f"Entity [{key}] already exists (robot {other.name!r}, namespace {other.namespace!r})",
                    fname,
                )
        x, y, yaw = float(req.x), float(req.y), wrap_angle(float(req.yaw))
        c, s = math.cos(yaw), math.sin(yaw)
        ox = x + model.outline[:, 0] * c - model.outline[:, 1] * s
        oy = y + model.outline[:, 0] * s + model.outline[:, 1] * c
        x0, x1, y0, y1 = self.world.bounds
        if ox.min() < x0 or ox.max() > x1 or oy.min() < y0 or oy.max() > y1:
            raise FleetError(
                ErrorCode.OUT_OF_BOUNDS,
                f"pose ({x:g}, {y:g}) puts the {model.name} outside the world "
                f"{self.world.name!r}: x in [{x0:g}, {x1:g}], y in [{y0:g}, {y1:g}]",
                "x",
            )
        hit = self.physics.blocker(model, x, y, yaw)
        if hit is not None:
            if hit < 0:
                what = "a wall or obstacle"
            else:
                what = next((f"robot {r.name!r}" for r in self._robots if r.rid == hit), "a robot")
            raise FleetError(
                ErrorCode.COLLISION,
                f"a {model.name} at ({x:g}, {y:g}, yaw {yaw:.3g}) would overlap {what}",
                "x",
            )
        return name, namespace, model, x, y, yaw

    def spawn(self, req: SpawnRequest) -> Robot:
        """Add a robot, or raise :class:`FleetError` leaving the world untouched."""
        name, namespace, model, x, y, yaw = self.validate_spawn(req)
        open_phases = [p for p, load in enumerate(self._phase_load) if load < SCAN_BATCH]
        phase = open_phases[0] if open_phases else int(np.argmin(self._phase_load))
        self._phase_load[phase] += 1
        robot = Robot(self._next_rid, name, namespace, model, (x, y, yaw), phase)
        self._next_rid += 1
        self.physics.add_robot(robot.rid, model, x, y, yaw)
        self._row_of[namespace] = len(self._robots)
        self._robots.append(robot)
        self._namespaces = [*self._namespaces, namespace]
        self._by_key[name] = robot
        self._by_key[namespace] = robot

        def app(a: npt.NDArray[np.generic], v: object) -> npt.NDArray[np.generic]:
            return np.concatenate([a, np.asarray([v], dtype=a.dtype)])

        self._rid = app(self._rid, robot.rid)  # type: ignore[assignment]
        for attr in ("_target_v", "_target_w", "_wheel_l", "_wheel_r", "_vx", "_vy", "_wz"):
            setattr(self, attr, app(getattr(self, attr), 0.0))
        self._last_cmd = app(self._last_cmd, self.tick)  # type: ignore[assignment]
        self._x = app(self._x, x)  # type: ignore[assignment]
        self._y = app(self._y, y)  # type: ignore[assignment]
        self._yaw = app(self._yaw, yaw)  # type: ignore[assignment]
        self._sep = app(self._sep, model.wheel_separation)  # type: ignore[assignment]
        self._max_v = app(self._max_v, model.max_linear_velocity)  # type: ignore[assignment]
        self._max_w = app(self._max_w, model.max_angular_velocity)  # type: ignore[assignment]
        self._acc = app(self._acc, model.max_wheel_acceleration)  # type: ignore[assignment]
        self._phase = app(self._phase, phase)  # type: ignore[assignment]
        self._lidar_off = np.vstack([self._lidar_off, np.asarray([model.lidar_offset])])
        self._outline = np.concatenate([self._outline, model.outline[None]], axis=0)
        return robot

    def delete(self, key: str) -> RobotState:
        """Remove the robot with this name or namespace; return its last state."""
        robot = self._by_key.get(key)
        if robot is None:
            raise FleetError(ErrorCode.NOT_FOUND, f"Entity [{key}] does not exist", "name")
        i = self._row(robot)
        last = self._state_at(robot, i)
        self.physics.remove_robot(robot.rid)
        del self._robots[i]
        self._namespaces = [r.namespace for r in self._robots]
        self._row_of = {r.namespace: k for k, r in enumerate(self._robots)}
        del self._by_key[robot.name]
        self._by_key.pop(robot.namespace, None)
        self._phase_load[robot.scan_phase] -= 1
        for attr in (
            "_rid", "_target_v", "_target_w", "_wheel_l", "_wheel_r", "_last_cmd", "_x", "_y",
            "_yaw", "_vx", "_vy", "_wz", "_sep", "_max_v", "_max_w", "_acc", "_phase",
            "_lidar_off", "_outline",
        ):  # fmt: skip
            setattr(self, attr, np.delete(getattr(self, attr), i, axis=0))
        return last

    # -- control ------------------------------------------------------------------------

    def command(self, robot: Robot, linear_x: float, angular_z: float) -> None:
        """Set a robot's velocity target (clamped later); refreshes its watchdog."""
        i = self._row(robot)
        self._target_v[i] = linear_x
        self._target_w[i] = angular_z
        self._last_cmd[i] = self.tick

    def command_many(self, commands: dict[str, tuple[float, float]]) -> int:
        """Apply the latest command per namespace; returns how many matched a robot."""
        if not commands:
            return 0
        row_of = self._row_of
        rows: list[int] = []
        vs: list[float] = []
        ws: list[float] = []
        for ns, (v, w) in commands.items():
            i = row_of.get(ns)
            if i is not None:
                rows.append(i)
                vs.append(v)
                ws.append(w)
        if rows:
            idx = np.asarray(rows)
            self._target_v[idx] = vs
            self._target_w[idx] = ws
            self._last_cmd[idx] = self.tick
        return len(rows)

    def reset(self, seed: int | None = None) -> None:
        """Time to zero, robots to their spawn poses at rest, noise reseeded."""
        if seed is not None:
            if seed < 0:
                raise FleetError(ErrorCode.INVALID_VALUE, "seed must be >= 0", "seed")
            self._seed = seed
        self.rng = np.random.default_rng(np.random.SeedSequence(self._seed))
        self.tick = 0
        for i, r in enumerate(self._robots):
            x, y, yaw = r.spawn_pose
            self.physics.place(r.rid, x, y, yaw)
            self._x[i], self._y[i], self._yaw[i] = x, y, yaw
        for a in (self._target_v, self._target_w, self._wheel_l, self._wheel_r,
                  self._vx, self._vy, self._wz):  # fmt: skip
            a[:] = 0.0
        self._last_cmd[:] = 0

    # -- the tick -------------------------------------------------------------------------

    def step(self) -> TickOutput:
        """Advance one fixed tick; return odometry for all robots and the scans due."""
        cfg = self.config
        dt = cfg.dt
        v, w, dx, dy = drive.advance(
            self.tick, cfg.cmd_timeout, dt, self._last_cmd, self._target_v, self._target_w, self._max_v,
            self._max_w, self._sep, self._acc, self._wheel_l, self._wheel_r, self._yaw,
        )  # fmt: skip
        self.physics.step(self._rid, dx / dt, dy / dt, w, dt)
        x, y, yaw = self.physics.poses(self._rid)
        # reported twist: the wheels' when motion was free, the achieved motion otherwise
        self._vx, self._vy, self._wz, self._yaw = drive.report_twist(
            dt, _FREE_MOTION_TOLERANCE, self._x, self._y, self._yaw, x, y, yaw, v, w, dx, dy
        )
        self._x, self._y = x, y
        self.tick += 1

        due = np.flatnonzero((self.tick - self._phase) % cfg.scan_every == 0)
        scans = self._scan(due)
        return TickOutput(
            tick=self.tick,
            time=self.time,
            namespaces=self._namespaces,
            x=self._x,
            y=self._y,
            yaw=self._yaw,
            linear_x=self._vx,
            linear_y=self._vy,
            angular_z=self._wz,
            scan_namespaces=[self._namespaces[i] for i in due.tolist()],
            scans=scans,
        )

    def _scan(self, rows: I64) -> F32:
        spec = self.config.lidar
        if len(rows) == 0:
            return np.zeros((0, spec.samples), dtype=np.float32)
        c, s = np.cos(self._yaw), np.sin(self._yaw)
        # every robot's outline in the world frame, as segments
        ox = self._outline[:, :, 0]
        oy = self._outline[:, :, 1]
        wx = self._x[:, None] + ox * c[:, None] - oy * s[:, None]
        wy = self._y[:, None] + ox * s[:, None] + oy * c[:, None]
        seg = np.stack([wx, wy, np.roll(wx, -1, axis=1), np.roll(wy, -1, axis=1)], axis=2)
        dyn_segments = seg.reshape(-1, 4)
        dyn_owner = np.repeat(self._rid, self._outline.shape[1])
        off = self._lidar_off[rows]
        cr, sr = c[rows], s[rows]
        origins = np.stack(
            [
                self._x[rows] + off[:, 0] * cr - off[:, 1] * sr,
                self._y[rows] + off[:, 0] * sr + off[:, 1] * cr,
            ],
            axis=1,
        )
        raw = cast(self.scene, spec, origins, self._yaw[rows], self._rid[rows], dyn_segments, dyn_owner)
        return self._sensor_model(raw)

    def _sensor_model(self, raw: F32) -> F32:
        """Gazebo RaySensor masking and noise (simd/core/sensor_model.py)."""
        cfg = self.config
        return sensor_model.apply(raw, cfg.lidar, cfg.noise_stddev if cfg.noise else 0.0, self.rng)
