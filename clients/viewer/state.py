"""The fleet as the viewer keeps it, and the frames it sends to pages.

Zenoh callbacks (a thread per subscriber) only write into :class:`FleetState` under its
lock: a pose, a reference to the newest scan, a trail point. Everything costly happens when a
frame is built, for the robots that frame needs: scans are turned into world-frame points at
the beam density the frame can afford, trails are thinned, and a scan is transformed with the
odometry pose of its own stamp (cached once that pose has arrived).

A frame is one binary websocket message (little-endian)::

    u32      header length H (a multiple of 4)
    H bytes  JSON header, space-padded: seq, meta, t, n, scans, scan_points, trails,
             trail_points, beam_step, stats
    f32[5n]  x, y, yaw, v, w of every robot in the order of the current meta (v, w are NaN
             until its first odometry; x, y, yaw are then its spawn pose)
    u32[s]   robot index of each scan      u32[s]  its point count
    f32[2S]  scan points, world frame (x0, y0, x1, y1, ...)
    u32[t]   robot index of each trail     u32[t]  its point count
    f32[2T]  trail points, oldest first (a drawing continues the line to the robot's pose)

The robots' static description (namespace, name, model, footprint, colour) travels in a
JSON ``meta`` message, sent before the first frame that needs a new version of it.
"""

from __future__ import annotations

import logging
import math
import re
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import msgspec
import numpy as np
import numpy.typing as npt

from protocol.control import RobotRecord, WorldInfo
from protocol.errors import FleetError
from protocol.messages import FleetOdometry, FleetScans, LaserScan, Odometry

if TYPE_CHECKING:
    from clients.api import FleetClient, Subscription

log = logging.getLogger(__name__)

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]

#: Robot colours (fill of the footprint; scans and trails use the same hue).
PALETTE: tuple[str, ...] = (
    "#4cc9f0",  # sky
    "#f72585",  # pink
    "#ffd166",  # yellow
    "#06d6a0",  # green
    "#fb8500",  # orange
    "#a08cff",  # violet
    "#c5e35a",  # lime
    "#ff595e",  # red
)
#: ``base_scan`` in ``base_footprint`` (x, y) per model, from the TurtleBot3 URDFs.
LIDAR_OFFSET: dict[str, tuple[float, float]] = {
    "burger": (-0.032, 0.0),
    "waffle": (-0.064, 0.0),
    "waffle_pi": (-0.064, 0.0),
}
LIDAR_RANGE_MAX = 3.5

TRAIL_SECONDS = 5.0  # sim seconds of trail kept per robot
TRAIL_MIN_STEP = 0.03  # m between stored trail points
TRAIL_MAX_POINTS = 96
POSE_HISTORY = 12  # odometry poses kept to match scan stamps (0.4 s at 30 Hz)

SCAN_POINT_BUDGET = 12_000  # beams per frame over all robots (before dropping non-finite)
MAX_BEAM_STEP = 12  # thinnest scan sent: every 12th beam (30 of 360)
TRAIL_POINT_BUDGET = 12_000
MIN_TRAIL_POINTS = 6


def color_index(namespace: str) -> int:
    """Palette index of a robot: its trailing number if it has one (tb3_0, tb3_1 ... get
    distinct colours), else a stable hash of the name."""
    m = re.search(r"(\d+)$", namespace)
    if m:
        return int(m.group(1)[-6:]) % len(PALETTE)
    h = 2166136261
    for b in namespace.encode():
        h = ((h ^ b) * 16777619) & 0xFFFFFFFF
    return h % len(PALETTE)


def color_rgb(index: int) -> tuple[int, int, int]:
    c = PALETTE[index % len(PALETTE)]
    return int(c[1:3], 16), int(c[3:5], 16), int(c[5:7], 16)


def natural_key(name: str) -> tuple[str | int, ...]:
    """Sort key that puts r2 before r10."""
    return tuple(int(p) if p.isdigit() else p for p in re.split(r"(\d+)", name))


@dataclass(frozen=True)
class View:
    """What one page shows, as it last reported: the visible world rectangle and toggles."""

    x0: float = -math.inf
    y0: float = -math.inf
    x1: float = math.inf
    y1: float = math.inf
    scans: bool = True
    trails: bool = True
    selected: str | None = None


@dataclass
class _Scan:
    seq: int
    stamp: float
    ranges: F32
    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float


@dataclass
class RobotState:
    """One live robot. ``record`` is False until its name, model and footprint are known."""

    namespace: str
    name: str = ""
    model: str = ""
    footprint: tuple[float, ...] = ()  # flat x0, y0, x1, y1, ... in base_footprint
    color: int = 0
    record: bool = False
    has_odom: bool = False
    stamp: float = 0.0
    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0
    v: float = 0.0
    w: float = 0.0
    poses: deque[tuple[float, float, float, float]] = field(default_factory=lambda: deque(maxlen=POSE_HISTORY))
    trail: deque[tuple[float, float, float]] = field(default_factory=lambda: deque(maxlen=TRAIL_MAX_POINTS))
    scan: _Scan | None = None
    trail_version: int = 0  # bumped whenever the trail changes
    _cache_key: tuple[int, int] = (-1, 0)
    _cache: F32 | None = None
    _trail_key: tuple[int, int] = (-1, 0)
    _trail_cache: F32 | None = None

    @property
    def lidar_offset(self) -> tuple[float, float]:
        return LIDAR_OFFSET.get(self.model, (0.0, 0.0))

    def trail_array(self, max_points: int = TRAIL_MAX_POINTS) -> F32:
        """Trail points of the last TRAIL_SECONDS, oldest first, thinned evenly to at most
        ``max_points`` (keeping both ends). The current pose is not included: a drawing
        ends the line at the robot."""
        key = (self.trail_version, max_points)
        if self._trail_cache is not None and self._trail_key == key:
            return self._trail_cache
        arr = np.asarray([(x, y) for _, x, y in self.trail], dtype=np.float32).reshape(-1, 2)
        if len(arr) > max_points:
            n = max(2, max_points)
            arr = arr[np.unique(np.linspace(0, len(arr) - 1, n).round().astype(np.intp))]
        self._trail_key, self._trail_cache = key, arr
        return arr

    def scan_points(self, step: int = 1) -> F32:
        """The latest scan as world-frame points (every ``step``-th beam, finite ranges only),
        using the odometry pose with the scan's stamp."""
        scan = self.scan
        if scan is None:
            return np.empty((0, 2), np.float32)
        if self._cache is not None and self._cache_key == (scan.seq, step):
            return self._cache
        exact, (px, py, pyaw) = self._pose_at(scan.stamp)
        ranges = scan.ranges[::step]
        cos_b, sin_b = _beam_dirs(scan.angle_min, scan.angle_increment, len(scan.ranges), step)
        ok = np.isfinite(ranges) & (ranges >= scan.range_min) & (ranges <= scan.range_max)
        r = ranges[ok].astype(np.float64)
        ox, oy = self.lidar_offset
        bx = ox + r * cos_b[ok]  # body frame
        by = oy + r * sin_b[ok]
        c, s = math.cos(pyaw), math.sin(pyaw)
        out = np.empty((len(r), 2), np.float32)
        out[:, 0] = px + c * bx - s * by
        out[:, 1] = py + s * bx + c * by
        if exact:
            self._cache, self._cache_key = out, (scan.seq, step)
        return out

    def _pose_at(self, stamp: float) -> tuple[bool, tuple[float, float, float]]:
        best: tuple[float, float, float, float] | None = None
        for p in self.poses:
            if best is None or abs(p[0] - stamp) < abs(best[0] - stamp):
                best = p
        if best is None:
            return False, (self.x, self.y, self.yaw)
        return abs(best[0] - stamp) < 1e-6, best[1:]


_beam_cache: dict[tuple[float, float, int, int], tuple[F64, F64]] = {}


def _beam_dirs(angle_min: float, inc: float, n: int, step: int) -> tuple[F64, F64]:
    key = (angle_min, inc, n, step)
    dirs = _beam_cache.get(key)
    if dirs is None:
        a = angle_min + inc * np.arange(0, n, step, dtype=np.float64)
        dirs = _beam_cache[key] = (np.cos(a), np.sin(a))
    return dirs


@dataclass
class FrameStats:
    """What went into one frame (also sent in its header)."""

    robots: int = 0
    scans: int = 0
    scan_points: int = 0
    trails: int = 0
    trail_points: int = 0
    beam_step: int = 1
    build_ms: float = 0.0
    nbytes: int = 0


class FleetState:
    """World, robots, poses, scans and trails; written by zenoh threads, read by frames."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.world: WorldInfo | None = None
        self._robots: dict[str, RobotState] = {}
        self._order: list[RobotState] = []  # robots with a record, natural order of name
        self._version = 0
        self._meta_json = b""
        self._scan_seq = 0
        self.records_wanted = threading.Event()
        self.odom_count = 0
        self.scan_count = 0
        self.sim_time = 0.0

    # -- written from zenoh callback threads ----------------------------------------------

    def on_presence(self, ns: str, alive: bool) -> None:
        with self._lock:
            if alive:
                if ns not in self._robots:
                    self._robots[ns] = RobotState(ns)
                    self.records_wanted.set()
            elif self._robots.pop(ns, None) is not None:
                self._reorder()

    def on_odom(self, ns: str, msg: Odometry) -> None:
        """One robot's odometry (``P/<ns>/odom``)."""
        p = msg.pose.pose
        tw = msg.twist.twist
        with self._lock:
            self.odom_count += 1
            self._pose(ns, msg.header.stamp.to_seconds(), p.position.x, p.position.y, p.orientation.yaw(),
                       tw.linear.x, tw.angular.z)  # fmt: skip

    def on_fleet_odom(self, msg: FleetOdometry) -> None:
        """Every robot's odometry of one tick (``P/odometry``): one message and one lock a tick
        however many robots there are."""
        t = msg.stamp.to_seconds()
        cols = zip(
            msg.namespaces,
            msg.array("x").tolist(),
            msg.array("y").tolist(),
            msg.array("yaw").tolist(),
            msg.array("linear_x").tolist(),
            msg.array("angular_z").tolist(),
            strict=True,
        )
        with self._lock:
            self.odom_count += len(msg.namespaces)
            for ns, x, y, yaw, v, w in cols:
                self._pose(ns, t, x, y, yaw, v, w)

    def _pose(self, ns: str, t: float, x: float, y: float, yaw: float, v: float, w: float) -> None:
        """Record a robot's pose (lock held)."""
        self.sim_time = max(self.sim_time, t)
        r = self._robots.get(ns)
        if r is None:
            return  # not (or no longer) present
        trail = r.trail
        if r.has_odom and t < r.stamp - 1e-9:  # the simulation was reset
            trail.clear()
            r.poses.clear()
            self.sim_time = t
        r.has_odom, r.stamp, r.x, r.y, r.yaw = True, t, x, y, yaw
        r.v, r.w = v, w
        r.poses.append((t, x, y, yaw))
        changed = False
        while trail and trail[0][0] < t - TRAIL_SECONDS:
            trail.popleft()
            changed = True
        if not trail or math.hypot(x - trail[-1][1], y - trail[-1][2]) >= TRAIL_MIN_STEP:
            trail.append((t, x, y))
            changed = True
        if changed:
            r.trail_version += 1

    def on_scan(self, ns: str, msg: LaserScan) -> None:
        """One robot's scan (``P/<ns>/scan``)."""
        ranges = msg.ranges_array()
        with self._lock:
            self.scan_count += 1
            self._scan(ns, msg.header.stamp.to_seconds(), ranges, msg.angle_min, msg.angle_increment,
                       msg.range_min, msg.range_max)  # fmt: skip

    def on_fleet_scans(self, msg: FleetScans) -> None:
        """The scans of one tick (``P/scans``), a row per robot."""
        rows = msg.ranges_array()
        t = msg.stamp.to_seconds()
        with self._lock:
            self.scan_count += len(msg.namespaces)
            for ns, ranges in zip(msg.namespaces, rows, strict=True):
                self._scan(ns, t, ranges, msg.angle_min, msg.angle_increment, msg.range_min, msg.range_max)

    def _scan(
        self, ns: str, t: float, ranges: F32, angle_min: float, inc: float, range_min: float, range_max: float
    ) -> None:
        """Record a robot's scan (lock held)."""
        r = self._robots.get(ns)
        if r is None:
            return
        self._scan_seq += 1
        r.scan = _Scan(self._scan_seq, t, ranges, angle_min, inc, range_min, range_max)

    # -- records (name, model, footprint), fetched off the zenoh threads --------------------

    def missing_records(self) -> int:
        with self._lock:
            return sum(1 for r in self._robots.values() if not r.record)

    def apply_records(self, records: list[RobotRecord]) -> None:
        """Fill in the robots that are present and lack their record. A record of a robot
        that is not (or no longer) present is ignored: presence is the truth."""
        with self._lock:
            changed = False
            for rec in records:
                r = self._robots.get(rec.namespace)
                if r is None or r.record:
                    continue
                r.name, r.model, r.record = rec.name, rec.model, True
                r.footprint = tuple(v for xy in rec.footprint for v in xy)
                r.color = color_index(rec.namespace)
                if not r.has_odom:
                    r.x, r.y, r.yaw = rec.pose.x, rec.pose.y, rec.pose.yaw
                changed = True
            if changed:
                self._reorder()

    def _reorder(self) -> None:
        self._order = sorted(
            (r for r in self._robots.values() if r.record),
            key=lambda r: (natural_key(r.name), natural_key(r.namespace)),
        )
        self._version += 1
        self._meta_json = b""

    # -- read by the server and the snapshot ------------------------------------------------

    @property
    def version(self) -> int:
        return self._version

    def counts(self) -> dict[str, int]:
        with self._lock:
            return {
                "present": len(self._robots),
                "robots": len(self._order),
                "with_odom": sum(1 for r in self._order if r.has_odom),
                "with_scan": sum(1 for r in self._order if r.scan is not None),
            }

    def ready(self, namespaces: set[str]) -> bool:
        """True when every robot in ``namespaces`` has its record, an odometry and a scan."""
        with self._lock:
            for ns in namespaces:
                r = self._robots.get(ns)
                if r is None or not r.record or not r.has_odom or r.scan is None:
                    return False
            return True

    def robots(self) -> list[RobotState]:
        """A copy of every robot with a record (trails and scans shared, read-only)."""
        with self._lock:
            out = []
            for r in self._order:
                c = RobotState(
                    r.namespace, r.name, r.model, r.footprint, r.color, r.record, r.has_odom,
                    r.stamp, r.x, r.y, r.yaw, r.v, r.w,
                )  # fmt: skip
                c.poses.extend(r.poses)
                c.trail.extend(r.trail)
                c.scan = r.scan
                out.append(c)
            return out

    def world_json(self) -> bytes:
        w = self.world
        if w is None:
            return msgspec.json.encode({"type": "world", "name": "", "bounds": None, "polygons": [], "circles": []})
        b = w.bounds
        return msgspec.json.encode(
            {
                "type": "world",
                "name": w.name,
                "bounds": [b.x_min, b.y_min, b.x_max, b.y_max],
                "polygons": [[v for xy in poly for v in xy] for poly in w.polygons],
                "circles": [[c.x, c.y, c.radius] for c in w.circles],
            }
        )

    def meta_json(self) -> tuple[int, bytes]:
        """The current version and its meta message (robots in frame order)."""
        with self._lock:
            return self._version, self._meta_locked()

    def _meta_locked(self) -> bytes:
        if not self._meta_json:
            footprints: dict[tuple[float, ...], int] = {}
            rows = []
            for r in self._order:
                fp = footprints.setdefault(r.footprint, len(footprints))
                rows.append([r.namespace, r.name, r.model, fp, r.color])
            self._meta_json = msgspec.json.encode(
                {
                    "type": "meta",
                    "version": self._version,
                    "palette": PALETTE,
                    "footprints": [[round(v, 4) for v in fp] for fp in footprints],
                    "robots": rows,
                }
            )
        return self._meta_json

    def frame(
        self, view: View, seq: int = 0, known_meta: int = -1, extra: dict[str, float] | None = None
    ) -> tuple[int, bytes | None, bytes, FrameStats]:
        """Build one frame for ``view``.

        Returns the meta version the frame refers to, the meta message if that is not
        ``known_meta`` (send it first), the frame bytes and what went into it.
        """
        t0 = time.perf_counter()
        with self._lock:
            order = self._order
            version = self._version
            meta = None if known_meta == version else self._meta_locked()
            n = len(order)
            poses = np.full((n, 5), np.nan, np.float32)
            for i, r in enumerate(order):
                if r.has_odom:
                    poses[i] = (r.x, r.y, r.yaw, r.v, r.w)
                else:
                    poses[i, :3] = (r.x, r.y, r.yaw)
            sim_time = self.sim_time
            scans, step = _pick_scans(order, poses, view) if view.scans else ([], 1)
            scan_arrays = [order[i].scan_points(1 if order[i].namespace == view.selected else step) for i in scans]
            trails, per_trail = _pick_trails(order, poses, view) if view.trails else ([], 0)
            trail_arrays = [order[i].trail_array(per_trail) for i in trails]
        stats = FrameStats(
            robots=n,
            scans=len(scans),
            scan_points=sum(len(a) for a in scan_arrays),
            trails=len(trails),
            trail_points=sum(len(a) for a in trail_arrays),
            beam_step=step,
        )
        header = {
            "seq": seq,
            "meta": version,
            "t": round(sim_time, 3),
            "n": n,
            "scans": stats.scans,
            "scan_points": stats.scan_points,
            "trails": stats.trails,
            "trail_points": stats.trail_points,
            "beam_step": step,
            "stats": {"odom": self.odom_count, "scan": self.scan_count, **(extra or {})},
        }
        parts = [
            poses.tobytes(),
            np.asarray(scans, np.uint32).tobytes(),
            np.asarray([len(a) for a in scan_arrays], np.uint32).tobytes(),
            *(a.tobytes() for a in scan_arrays),
            np.asarray(trails, np.uint32).tobytes(),
            np.asarray([len(a) for a in trail_arrays], np.uint32).tobytes(),
            *(a.tobytes() for a in trail_arrays),
        ]
        head = msgspec.json.encode(header)
        head += b" " * (-len(head) % 4)
        data = b"".join([len(head).to_bytes(4, "little"), head, *parts])
        stats.nbytes = len(data)
        stats.build_ms = (time.perf_counter() - t0) * 1e3
        return version, meta, data, stats


def _in_view(poses: F32, view: View, margin: float) -> npt.NDArray[np.bool_]:
    x, y = poses[:, 0], poses[:, 1]
    ok: npt.NDArray[np.bool_] = (
        (x >= view.x0 - margin) & (x <= view.x1 + margin) & (y >= view.y0 - margin) & (y <= view.y1 + margin)
    )
    return ok


def _by_distance_to_centre(idx: npt.NDArray[np.intp], poses: F32, view: View) -> list[int]:
    if not all(math.isfinite(v) for v in (view.x0, view.y0, view.x1, view.y1)):
        return [int(i) for i in idx]
    cx, cy = (view.x0 + view.x1) / 2, (view.y0 + view.y1) / 2
    d = np.hypot(poses[idx, 0] - cx, poses[idx, 1] - cy)
    return [int(i) for i in idx[np.argsort(d, kind="stable")]]


def _pick_scans(order: list[RobotState], poses: F32, view: View) -> tuple[list[int], int]:
    """Which robots' scans to send and at which beam step.

    Candidates are robots with a scan whose origin is within the view grown by the lidar
    range. The step is the smallest that fits all of them in SCAN_POINT_BUDGET beams, at most
    MAX_BEAM_STEP; past that, the robots nearest the view centre are kept. The selected
    robot's scan is always sent, at full density.
    """
    has_scan = np.fromiter((r.scan is not None for r in order), bool, len(order))
    idx = np.flatnonzero(has_scan & _in_view(poses, view, LIDAR_RANGE_MAX))
    picked = _by_distance_to_centre(idx, poses, view)
    sel = next(
        (i for i, r in enumerate(order) if r.namespace == view.selected and r.scan is not None),
        None,
    )
    if sel is not None:
        picked = [sel, *(i for i in picked if i != sel)]
    if not picked:
        return [], 1
    beams = len(order[picked[0]].scan.ranges) if order[picked[0]].scan else 360  # type: ignore[union-attr]
    step = 1
    while step < MAX_BEAM_STEP and len(picked) * math.ceil(beams / step) > SCAN_POINT_BUDGET:
        step += 1
    keep = max(1, SCAN_POINT_BUDGET // math.ceil(beams / step))
    return picked[:keep], step


def _pick_trails(order: list[RobotState], poses: F32, view: View) -> tuple[list[int], int]:
    """Trails of the robots in view (grown by 1.5 m), each thinned so the frame holds at
    most TRAIL_POINT_BUDGET points; if even MIN_TRAIL_POINTS each is too many, the robots
    nearest the view centre keep theirs."""
    idx = np.flatnonzero(_in_view(poses, view, 1.5))
    picked = _by_distance_to_centre(idx, poses, view)
    if not picked:
        return [], 0
    per = max(MIN_TRAIL_POINTS, min(TRAIL_MAX_POINTS, TRAIL_POINT_BUDGET // len(picked)))
    return picked[: TRAIL_POINT_BUDGET // per], per


class Feed:
    """Connects a :class:`FleetState` to a :class:`FleetClient`: the world, presence, odom and
    scan callbacks, and a thread that fetches the records of robots that appeared (a query,
    so never from a zenoh callback)."""

    def __init__(self, client: FleetClient, state: FleetState) -> None:
        self.client = client
        self.state = state
        self._stop = threading.Event()
        self._subs: list[Subscription] = []
        self._thread = threading.Thread(target=self._records_loop, name="fleet-view-records", daemon=True)

    def start(self) -> None:
        self.state.world = self.client.world()
        self._subs.append(self.client.on_presence(self.state.on_presence))
        # the fleet topics: one message a tick for all robots, where the per-robot topics would
        # be 35 000 messages a second at 1 000 robots (each ~10 us of this process's CPU)
        self._subs.append(self.client.on_fleet_odom(self.state.on_fleet_odom))
        self._subs.append(self.client.on_fleet_scans(self.state.on_fleet_scans))
        self._thread.start()

    def _records_loop(self) -> None:
        wanted = self.state.records_wanted
        while not self._stop.is_set():
            if not wanted.wait(0.25):
                continue
            wanted.clear()
            self._stop.wait(0.05)  # let a burst of spawns arrive, then ask once
            try:
                self.state.apply_records(self.client.robots())
            except FleetError as e:
                log.warning("could not list robots: %s", e)
                self._stop.wait(0.5)
            if self.state.missing_records():
                self._stop.wait(0.2)
                wanted.set()

    def close(self) -> None:
        self._stop.set()
        for s in self._subs:
            s.close()
        self._subs.clear()
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)
