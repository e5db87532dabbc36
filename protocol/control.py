"""Requests and replies of the daemon's control keys (spawn, delete, list, world, clock, sim)."""

from __future__ import annotations

import math

import msgspec
import numpy as np
import numpy.typing as npt

from protocol.errors import ErrorCode, FleetError
from protocol.messages import LaserScan, Odometry, Time, Twist

MODELS = ("burger", "waffle", "waffle_pi")


class Pose2D(msgspec.Struct, kw_only=True):
    """A planar pose in the world frame (metres, radians)."""

    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0


class SpawnRequest(msgspec.Struct, kw_only=True):
    """``P/spawn``. ``namespace`` defaults to ``name``; ``model`` to ``burger``."""

    name: str
    namespace: str | None = None
    model: str = "burger"
    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0


class DeleteRequest(msgspec.Struct, kw_only=True):
    """``P/delete``: a robot's name or its namespace."""

    name: str


#: Most ticks one step request may ask for (about 9 hours of sim time). A long step runs in
#: slices with other requests served between them, and ``P/sim/pause`` cancels what is left.
MAX_STEP_TICKS = 1_000_000


class PackedCommands(msgspec.Struct, kw_only=True):
    """Commands for many robots at once (``StepRequest.commands``, ``P/commands``): ``names``
    are namespaces, ``twist`` float64 little-endian, a row of (linear.x, angular.z) for each,
    in order."""

    names: list[str]
    twist: bytes

    def rows(self, field: str = "commands") -> npt.NDArray[np.float64]:
        """The (n, 2) rows, checked as a daemon takes them: ``twist`` holds 16 bytes a name
        (else ``invalid_value``) and every number is finite (else ``non_finite``, naming the
        robot). A name given twice is the caller's to refuse (a step finds it with the rows)."""
        n, got = len(self.names), len(self.twist)
        if got != 16 * n:
            why = f"{field}.twist must hold 2 float64 for each of the {n} names, got {got} bytes"
            raise FleetError(ErrorCode.INVALID_VALUE, why, field)
        values = np.frombuffer(self.twist, dtype="<f8").astype(np.float64).reshape(n, 2)
        check_finite_commands(self.names, values, field)
        return values


#: up to this many values are checked in Python: fewer than numpy's two calls cost
FEW_VALUES = 32


def check_finite_commands(names: list[str], values: npt.NDArray[np.float64], field: str) -> None:
    """Refuse (``non_finite``, naming the first robot) commands ``values`` (a row per name) that
    hold a number that is not finite."""
    few = values.size <= FEW_VALUES
    if not (all(map(math.isfinite, values.flat)) if few else bool(np.isfinite(values).all())):
        ns = names[int(np.argmin(np.isfinite(values).all(axis=1)))]
        raise FleetError(ErrorCode.NON_FINITE, f"{field} for {ns!r} is not finite", field)


class StepRequest(msgspec.Struct, kw_only=True):
    """``P/sim/step``: advance ``ticks`` fixed steps (1/30 s each) while paused or in lockstep.

    ``cmd_vel`` maps namespaces to commands that hold for every tick of the step (the 0.5 s
    watchdog never cuts them short), so a lockstep client's command and step cannot race
    each other on different zenoh threads. ``observe`` names robots whose odometry and latest
    scan come back in the reply, saving a round trip per robot.

    Learning loops step many robots and read them all, and nothing else: ``publish=False``
    runs the step's ticks without encoding or publishing any topic (odometry, scans, /tf,
    clock), and ``packed=True`` returns the observations as a few arrays
    (:class:`PackedObservations`) instead of one message per robot. The world advances the
    same either way. ``commands`` gives the step's commands as arrays instead of ``cmd_vel``.
    """

    ticks: int = 1
    cmd_vel: dict[str, Twist] = msgspec.field(default_factory=dict)
    commands: PackedCommands | None = None
    observe: list[str] = msgspec.field(default_factory=list)
    publish: bool = True
    packed: bool = False


class ResetRequest(msgspec.Struct, kw_only=True):
    """``P/sim/reset``: time to zero, robots back to their spawn poses, noise reseeded.

    ``seed`` replaces the daemon's seed when given.
    """

    seed: int | None = None


class EmptyRequest(msgspec.Struct, kw_only=True):
    """Requests that carry nothing (world, clock, pause, resume)."""


class ListRequest(msgspec.Struct, kw_only=True):
    """``P/robots``: every robot in spawn order (no field given), only the robots named in
    ``names`` (by name or namespace; spawn order), or a page: at most ``limit`` robots in name
    order, those whose name sorts after ``after`` (protocol/listing.py)."""

    names: list[str] = msgspec.field(default_factory=list)
    after: str = ""
    limit: int = 0


class WorldRequest(EmptyRequest, kw_only=True):
    """``P/world``."""


class ClockRequest(EmptyRequest, kw_only=True):
    """``P/clock``."""


class PauseRequest(EmptyRequest, kw_only=True):
    """``P/sim/pause``: time stands still; a running step stops where it is."""


class ResumeRequest(EmptyRequest, kw_only=True):
    """``P/sim/resume``."""


#: Every request the daemon serves.
Request = (
    SpawnRequest
    | DeleteRequest
    | ListRequest
    | WorldRequest
    | ClockRequest
    | PauseRequest
    | ResumeRequest
    | ResetRequest
    | StepRequest
)

#: The request each control key takes, by the key's name in :class:`protocol.keys.Keys`.
REQUESTS: dict[str, type[Request]] = {
    "spawn": SpawnRequest,
    "delete": DeleteRequest,
    "robots": ListRequest,
    "world": WorldRequest,
    "clock": ClockRequest,
    "pause": PauseRequest,
    "resume": ResumeRequest,
    "reset": ResetRequest,
    "step": StepRequest,
}
#: The keys that change the world: they act only on a query for exactly their key.
ACTIONS = frozenset({"spawn", "delete", "pause", "resume", "reset", "step"})


class Topics(msgspec.Struct, kw_only=True):
    """The concrete keys of one robot."""

    cmd_vel: str
    odom: str
    scan: str
    alive: str


class Frames(msgspec.Struct, kw_only=True):
    """TF frame names, namespaced as the TurtleBot3 multi-robot launch does (no leading slash)."""

    odom: str
    base_footprint: str
    base_scan: str


class ModelLimits(msgspec.Struct, kw_only=True):
    max_linear_velocity: float
    max_angular_velocity: float
    wheel_separation: float
    wheel_radius: float
    max_wheel_acceleration: float


class RobotRecord(msgspec.Struct, kw_only=True):
    """One live robot, as spawn, delete and list report it."""

    name: str
    namespace: str
    model: str
    pose: Pose2D
    linear_velocity: float = 0.0
    angular_velocity: float = 0.0
    spawn_pose: Pose2D = msgspec.field(default_factory=Pose2D)
    limits: ModelLimits | None = None
    #: The outline of the robot in its body frame (``base_footprint``), counter-clockwise.
    footprint: list[tuple[float, float]] = msgspec.field(default_factory=list)
    topics: Topics | None = None
    frames: Frames | None = None
    #: the id of the daemon that simulates it (``simd --id``)
    daemon: str = ""
    #: body-frame sideways velocity (m/s): nonzero only while something pushes it sideways
    lateral_velocity: float = 0.0


#: The id of a daemon started without ``--id``.
DEFAULT_DAEMON_ID = "simd"


class RobotList(msgspec.Struct, kw_only=True):
    stamp: Time
    robots: list[RobotRecord]


class DaemonInfo(msgspec.Struct, kw_only=True):
    """``P/daemons``: who a daemon is (each daemon of the fleet answers with its own)."""

    id: str
    world: str
    host: str
    pid: int
    zid: str
    #: wall-clock time it started (Unix seconds)
    started: float
    #: it shares the fleet with other daemons (``simd --join``)
    shared: bool = False


class DaemonTick(msgspec.Struct, kw_only=True):
    """``P/daemons/<id>/tick``: a daemon of a shared fleet, about to step its tick ``tick``,
    says where its robots are (the true poses, not the odometry's): ``namespaces`` and their
    ``models``, and ``poses`` as little-endian float64 rows x, y, yaw. The other daemons wait
    for it and place those robots as ghosts before they step the same tick, so that a stepped
    fleet is deterministic across daemons (docs/scale-out.md)."""

    daemon: str
    tick: int
    namespaces: list[str]
    models: list[str]
    poses: bytes


class Bounds(msgspec.Struct, kw_only=True):
    x_min: float
    x_max: float
    y_min: float
    y_max: float


class Circle(msgspec.Struct, kw_only=True):
    x: float
    y: float
    radius: float


class WorldInfo(msgspec.Struct, kw_only=True):
    """``P/world``: the loaded world's static geometry, for viewers and mappers."""

    name: str
    bounds: Bounds
    default_spawn: Pose2D
    #: Convex polygons, each a list of (x, y) vertices, counter-clockwise.
    polygons: list[list[tuple[float, float]]]
    circles: list[Circle]


class Clock(msgspec.Struct, kw_only=True):
    """``P/clock`` (published at 10 Hz sim time, and the reply of every ``P/sim/*`` request)."""

    clock: Time
    tick: int
    dt: float
    paused: bool
    lockstep: bool
    #: Measured sim seconds per wall second over the last second (0 while paused).
    real_time_factor: float
    #: Requested real-time factor; 0 means as fast as possible.
    target_real_time_factor: float
    robots: int
    #: cmd_vel messages dropped because they did not decode or were not finite.
    dropped_commands: int = 0
    #: Sim seconds the clock is behind where the target factor would have it since time last
    #: started running (the start, a resume, a reset): it grows while the daemon cannot keep
    #: up. 0 while paused, in lockstep and when unpaced (target 0).
    behind_s: float = 0.0
    #: Whether the daemon is falling behind its target now: set when the measured factor drops
    #: below 0.9 of the target, cleared when it is back above 0.97 of it (or time stops).
    falling_behind: bool = False
    #: CPU seconds the daemon spends on a tick of the robots there now, all its threads
    #: (simulation, publishing, zenoh; moving average; 0: not measured yet, and always 0 in a
    #: step's reply, which stays deterministic).
    tick_s: float = 0.0
    #: About how many robots like these the daemon can keep in real time on this machine now,
    #: from its measured tick cost (0: not known yet; 0 in a step's reply too).
    capacity_robots: int = 0


class Observation(msgspec.Struct, kw_only=True):
    """One robot after a step: its odometry, and its latest scan (None before the first)."""

    odom: Odometry
    scan: LaserScan | None = None


class PackedObservations(msgspec.Struct, kw_only=True):
    """The observed robots of a ``packed`` step, row by row in the order asked for, as
    little-endian arrays (raw bytes in msgpack, base64 in JSON). ``odom``: float64 (n, 6), each
    row x, y, yaw, linear.x, linear.y, angular.z of the robot's odometry after the step (what
    its odom topic says for that tick); ``scan_time``: float64 (n,), the sim time of each
    robot's latest scan, NaN before its first; ``ranges``: float32 (n, samples), those scans
    (a ``LaserScan.ranges`` each; NaN rows before the first). A robot deleted during the step
    is left out of ``names`` and of every array.

    The arrays are read-only memoryviews of bytes: decoded from msgpack they are views on the
    reply's bytes, not copies (a thousand robots' scans are 1.4 MB a step, and a learner reads
    them every step); ``bytes(view)`` is a copy (to pickle, or to keep one field without the
    whole reply). Any contiguous buffer (bytes, a numpy array) may be given when encoding."""

    names: list[str]
    samples: int
    odom: memoryview
    scan_time: memoryview
    ranges: memoryview


class StepReply(Clock, kw_only=True):
    """The reply of ``P/sim/step``: the clock after the step, how many ticks ran (fewer than
    asked when a pause cancelled the rest), and the observations asked for. A client that
    decodes it as a :class:`Clock` reads the clock."""

    ticks_run: int = 0
    cancelled: bool = False
    observations: dict[str, Observation] = msgspec.field(default_factory=dict)
    #: the observations of a ``packed`` step (``observations`` is empty then)
    packed: PackedObservations | None = None
