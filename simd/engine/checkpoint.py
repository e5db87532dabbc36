"""``simd --state FILE``: the fleet written to a file as it runs, and brought back on start.

A daemon that restarts (a crash, ``kill -9``, an upgrade, a container that is replaced) would
otherwise come back empty, and every client would find its robot gone. The state file holds
what makes the fleet: the world's name, the sim time, and every robot's name, namespace, model,
true pose, odometry pose, spawn pose and last commanded velocity, and the goals the robots are
on (``fleet goto``: a restarted daemon drives them on to where they were sent; the goal's
time and timeout count again from the restart). It is written every
``SAVE_EVERY_S`` seconds of wall time, soon after every spawn, delete or reset, and on
shutdown, always whole: JSON to a temporary file in the same directory, flushed to disk, then
renamed over the old one, so a kill at any moment leaves either the previous state or the new
one, never half of either.

On start, a file that is missing is a first run (it will be created); a file that is not a
fleetsim state, is damaged, or was saved with another world is refused with one line saying
so, and left as it is: the daemon does not start rather than overwrite a fleet it cannot read.

Not kept: the lidar and slip noise streams (they restart from ``--seed``), the wheels' current
speed (a robot accelerates again to its last command, which the watchdog stops after
``--cmd-timeout`` unless a client keeps sending), pause/lockstep (the flags decide).
"""

from __future__ import annotations

import logging
import math
import os
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

import msgspec

from protocol.control import SpawnRequest
from protocol.errors import FleetError
from protocol.navigation import NavigateRequest
from simd.core.sim import Simulation

log = logging.getLogger(__name__)

FORMAT = "fleetsim-state"
VERSION = 1
#: wall seconds between saves while the daemon runs
SAVE_EVERY_S = 2.0
#: a spawn, delete or reset is saved within this many wall seconds
SAVE_CHANGE_S = 0.2
#: a state file larger than this is not read (a fleet of 5 000 robots is about 2 MB)
MAX_BYTES = 64 * 1024 * 1024


class StateFileError(Exception):
    """A state file that cannot be used; the message says which and why, in one line."""


class SavedRobot(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    name: str
    namespace: str
    model: str
    pose: tuple[float, float, float]
    odom: tuple[float, float, float]
    spawn_pose: tuple[float, float, float]
    linear_velocity: float = 0.0
    angular_velocity: float = 0.0


class SavedFleet(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    format: str
    version: int
    world: str
    tick: int
    dt: float
    robots: list[SavedRobot]
    saved_at: float = 0.0  # wall clock (Unix time), for people reading the file
    goals: list[NavigateRequest] = []  # the active goals, each with its robot and goal_id


def capture(sim: Simulation, goals: list[NavigateRequest] | None = None) -> SavedFleet:
    """The fleet as it is now, with the navigator's active ``goals`` (call from the thread
    that owns the simulation)."""
    robots = [
        SavedRobot(
            name=s.name,
            namespace=s.namespace,
            model=s.model.name,
            pose=(s.x, s.y, s.yaw),
            odom=s.odom_pose,
            spawn_pose=s.spawn_pose,
            linear_velocity=s.linear_velocity,
            angular_velocity=s.angular_velocity,
        )
        for s in sim.states()
    ]
    return SavedFleet(format=FORMAT, version=VERSION, world=sim.world.name, tick=sim.tick, dt=sim.config.dt,
                      robots=robots, saved_at=time.time(), goals=goals or [])  # fmt: skip


def write(path: Path, fleet: SavedFleet) -> None:
    """Write ``fleet`` to ``path`` whole or not at all (temporary file, fsync, rename)."""
    data = msgspec.json.format(msgspec.json.encode(fleet), indent=1)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, 0o644)  # as an ordinary file (mkstemp makes it private)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def read(path: Path) -> SavedFleet | None:
    """The fleet saved in ``path``; None when there is no such file (a first run)."""
    try:
        size = path.stat().st_size
        if size > MAX_BYTES:
            raise StateFileError(f"state file {path} is {size} bytes, more than a fleetsim state can be")
        data = path.read_bytes()
    except FileNotFoundError:
        return None
    except IsADirectoryError:
        raise StateFileError(f"state file {path} is a directory: give a file name") from None
    except OSError as e:
        raise StateFileError(f"cannot read state file {path}: {e.strerror or e}") from None
    try:
        head = msgspec.json.decode(data, type=dict[str, object])
    except (msgspec.DecodeError, RecursionError):
        raise StateFileError(f"{path} is not a fleetsim state file (not JSON); move it away or choose "
                             "another --state") from None  # fmt: skip
    if head.get("format") != FORMAT:
        raise StateFileError(f"{path} is not a fleetsim state file (no \"format\": \"{FORMAT}\"); move it away "
                             "or choose another --state")  # fmt: skip
    if head.get("version") != VERSION:
        raise StateFileError(f"{path} is a version {head.get('version')!r} fleetsim state; this simd reads "
                             f"version {VERSION}")  # fmt: skip
    try:
        return msgspec.json.decode(data, type=SavedFleet)
    except msgspec.ValidationError as e:
        raise StateFileError(f"{path} is a damaged fleetsim state: {e}") from None


def restore(sim: Simulation, fleet: SavedFleet, path: Path) -> int:
    """Put the saved robots into ``sim`` (empty, just made); the number restored. Raises
    StateFileError, with ``sim`` left empty, when the file does not fit this daemon."""
    if fleet.world != sim.world.name:
        raise StateFileError(f"{path} was saved with world {fleet.world!r}, this daemon runs {sim.world.name!r}: "
                             f"start with --world {fleet.world} or choose another --state")  # fmt: skip
    if abs(fleet.dt - sim.config.dt) > 1e-12:
        raise StateFileError(f"{path} was saved with a tick of {fleet.dt} s, this daemon ticks {sim.config.dt} s")
    if fleet.tick < 0:
        raise StateFileError(f"{path} is a damaged fleetsim state: tick {fleet.tick} < 0")
    sim.tick = fleet.tick
    try:
        for r in fleet.robots:
            x, y, yaw = r.pose
            robot = sim.spawn(
                SpawnRequest(name=r.name, namespace=r.namespace, model=r.model, x=x, y=y, yaw=yaw),
                spawn_pose=r.spawn_pose,
                odom=r.odom,
            )
            sim.command(robot, r.linear_velocity, r.angular_velocity)
    except FleetError as e:
        for s in sim.states():
            sim.delete(s.name)
        sim.tick = 0
        raise StateFileError(f"{path}: robot {r.name!r} cannot be restored: {e.message}") from None
    return len(fleet.robots)


#: while saves keep failing (a full disk), at most one line about it this often
FAILURE_LOG_EVERY_S = 60.0


class Saver:
    """Writes the newest captured fleet on a thread of its own, so that a slow disk never
    holds up a tick; ``save_now`` writes on the calling thread (at shutdown).

    A save that fails (a full disk, a read-only remount, a quota) leaves the previous file as
    it was (``write`` replaces it only once the new one is whole on disk); the daemon runs
    on, says so in one line, and the next save (within ``SAVE_EVERY_S``) tries again. While
    the saves go on failing it says so at most once every ``FAILURE_LOG_EVERY_S``, with the
    count, and once more when a save succeeds again, so that an operator sees both the
    trouble and its end and the log does not fill (a full disk is often the log's disk too).
    """

    def __init__(
        self,
        path: Path,
        *,
        writer: Callable[[Path, SavedFleet], None] = write,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.path = path
        self._writer = writer
        self._clock = clock
        self._pending: SavedFleet | None = None
        self._cond = threading.Condition()
        self._closed = False
        self.failures = 0  # in a row, since the last save that succeeded
        self.saves = 0
        self.attempts = 0  # saves tried, whatever came of them
        self._failing_since = 0.0
        self._saved_time = 0.0  # the sim time of the last fleet saved
        self._logged_at = -math.inf
        self._thread = threading.Thread(target=self._run, name="state-saver", daemon=True)
        self._thread.start()

    def offer(self, fleet: SavedFleet) -> None:
        with self._cond:
            self._pending = fleet
            self._cond.notify()

    def _run(self) -> None:
        while True:
            with self._cond:
                while self._pending is None and not self._closed:
                    self._cond.wait()
                if self._pending is None:
                    return
                fleet, self._pending = self._pending, None
            self._write(fleet)

    def _write(self, fleet: SavedFleet) -> None:
        try:
            self._save(fleet)
        finally:
            self.attempts += 1  # last: whoever waits for an attempt finds it logged

    def _save(self, fleet: SavedFleet) -> None:
        now = self._clock()
        try:
            self._writer(self.path, fleet)
        except OSError as e:
            if self.failures == 0:
                self._failing_since = now
            self.failures += 1
            if now - self._logged_at >= FAILURE_LOG_EVERY_S:
                self._logged_at = now
                kept = f"sim time {self._saved_time:.3f} s" if self.saves else "as it was"
                log.error("cannot write the state file %s: %s; the file keeps the fleet of before (%s); simd "
                          "runs on and tries again every %g s (failed saves so far: %d)", self.path,
                          e.strerror or e, kept, SAVE_EVERY_S, self.failures)  # fmt: skip
            return
        if self.failures:
            log.warning("the state file %s is written again (after %d failed saves over %.0f s)", self.path,
                        self.failures, now - self._failing_since)  # fmt: skip
            self.failures = 0
            self._logged_at = -math.inf  # the next trouble is told at once
        self.saves += 1
        self._saved_time = fleet.tick * fleet.dt

    def save_now(self, fleet: SavedFleet) -> None:
        """Stop the thread and write ``fleet`` last."""
        with self._cond:
            self._closed = True
            self._pending = None
            self._cond.notify()
        self._thread.join()
        self._write(fleet)
