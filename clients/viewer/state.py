"""The fleet as the viewer keeps it, and the frames it sends to pages.

Zenoh callbacks (a thread per subscriber) only write into :class:`FleetState` under its
lock: a pose, a reference to the newest scan, a trail point. Everything costly happens when a
frame is built, for the robots that frame needs: scans are turned into world-frame points at
the beam density the frame can afford, trails are thinned, and a scan is transformed with the
odometry pose of its own stamp (cached once that pose has arrived).

A frame is one binary websocket message (little-endian)::

    u32      header length H (a multiple of 4)
    H bytes  JSON header, space-padded: seq, meta, t, n, scans, scan_points, trails,
             trail_points, beam_step, stats, and ``clock`` when the daemon's clock changed
             since the page's last frame (:meth:`FleetState.clock_update`)
    f32[5n]  x, y, yaw, v, w of every robot in the order of the current meta (v, w are NaN
             until its first odometry; x, y, yaw are then its spawn pose)
    u32[s]   robot index of each scan      u32[s]  its point count
    f32[2S]  scan points, world frame (x0, y0, x1, y1, ...)
    u32[t]   robot index of each trail     u32[t]  its point count
    f32[2T]  trail points, oldest first (a drawing continues the line to the robot's pose)

The robots' static description (namespace, name, model, footprint, colour) travels in a
JSON ``meta`` message, sent before the first frame that needs a new version of it; their goals,
navigation states and planned paths in JSON ``nav`` messages of what changed
(:mod:`clients.viewer.navigation`), sent before the frame when something did.
"""

from __future__ import annotations

import logging
import math
import re
import threading
import time
from dataclasses import dataclass

import msgspec
import numpy as np

from clients.naming import natural_key
from clients.viewer.decimate import (
    View,
    pick_scans,
    pick_trails,
    thin_path,
)
from clients.viewer.navigation import GoalView, NavBoard, NavCursor
from clients.viewer.robot import TRAIL_MIN_STEP, TRAIL_SECONDS, KeptScan, RobotState
from fleetcommon.arrays import F32
from protocol.control import Clock, RobotRecord, WorldInfo
from protocol.messages import FleetOdometry, FleetScans, LaserScan, Odometry
from protocol.navigation import FleetNavigation, NavigationPath, NavigationResult

log = logging.getLogger(__name__)


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
    """World, robots, poses, scans, trails and navigation; written by zenoh threads, read by
    frames."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.world: WorldInfo | None = None
        self.world_version = 0  # bumped when a restarted daemon serves another world
        self.world_wanted = threading.Event()  # a daemon came: ask for the world again
        self._robots: dict[str, RobotState] = {}
        self.nav = NavBoard()  # under self._lock, for present robots only
        self._order: list[RobotState] = []  # robots with a record, natural order of name
        self._version = 0
        self._meta_json = b""
        self._scan_seq = 0
        self.records_wanted = threading.Event()
        self.odom_count = 0
        self.scan_count = 0
        self.sim_time = 0.0
        self._clock: dict[str, float | bool] | None = None  # the page's view of the daemon's clock
        self._clock_version = 0

    def set_world(self, world: WorldInfo) -> None:
        """The daemon's world; pages are sent it again when it changed (a daemon restarted with
        another ``--world``)."""
        if world != self.world:
            self.world = world
            self.world_version += 1

    # -- written from zenoh callback threads ----------------------------------------------

    def on_daemon(self, daemon_id: str, alive: bool) -> None:
        """A daemon came (or came back): its world may not be the one shown."""
        if alive:
            self.world_wanted.set()
            self.records_wanted.set()  # wakes the feed's thread

    def on_presence(self, ns: str, alive: bool) -> None:
        with self._lock:
            if alive:
                if ns not in self._robots:
                    self._robots[ns] = RobotState(ns)
                    self.records_wanted.set()
            elif self._robots.pop(ns, None) is not None:
                self.nav.forget(ns)
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
        r.scan = KeptScan(self._scan_seq, t, ranges, angle_min, inc, range_min, range_max)

    # -- navigation: goals, states and paths (clients/viewer/navigation.py) ------------------

    def on_navigation(self, msg: FleetNavigation) -> None:
        """The fleet's navigation summary (``P/navigation``)."""
        now = time.monotonic()
        with self._lock:
            for entry in msg.robots:
                if entry.robot in self._robots:
                    self.nav.summary_row(entry.robot, entry, now)

    def on_plan(self, path: NavigationPath) -> None:
        """A robot's path (``P/<ns>/plan``), thinned before the lock is taken."""
        thinned = thin_path(path.points)
        with self._lock:
            if path.robot in self._robots:
                self.nav.plan(path.robot, path, thinned)

    def on_nav_result(self, result: NavigationResult) -> None:
        """A goal ended (``P/<ns>/navigate/result``)."""
        now = time.monotonic()
        with self._lock:
            if result.robot in self._robots:
                self.nav.result(result.robot, result, now)

    def apply_plans(self, plans: dict[str, NavigationPath]) -> None:
        """The current paths, as a get returned them (a viewer opened mid-goal)."""
        thinned = {ns: (p, thin_path(p.points)) for ns, p in plans.items() if p.robot == ns}
        with self._lock:
            self.nav.initial_plans({ns: v for ns, v in thinned.items() if ns in self._robots})

    def goals_under_way(self) -> dict[str, GoalView]:
        """Each present robot's goal under way, with its path (NavBoard.under_way)."""
        with self._lock:
            return self.nav.under_way()

    def has_goal(self, namespaces: set[str]) -> bool:
        """True when every robot in ``namespaces`` has its goal's row (from ``P/navigation``)
        and a path."""
        with self._lock:
            return all(ns in self.nav.goals and ns in self.nav.paths for ns in namespaces)

    def nav_updates(self, cursor: NavCursor) -> bytes | None:
        """The ``nav`` message a page with ``cursor`` needs, or None (see NavBoard.updates)."""
        with self._lock:
            self.nav.prune(time.monotonic())
            return self.nav.updates(cursor)

    # -- the daemon's clock (its real-time factor), asked for about once a second ------------

    def set_clock(self, clock: Clock | None) -> None:
        """The daemon's latest clock, or None when it did not answer: what the page's status
        line shows of it (achieved and target real-time factor, falling behind, paused)."""
        shown: dict[str, float | bool] | None = None
        if clock is not None:
            shown = {
                "rtf": round(clock.real_time_factor, 3),
                "target": clock.target_real_time_factor,
                "behind_s": round(clock.behind_s, 1),
                "falling_behind": clock.falling_behind,
                "paused": clock.paused,
                "lockstep": clock.lockstep,
            }
        with self._lock:
            if shown != self._clock:
                self._clock = shown
                self._clock_version += 1

    def clock_update(self, known: int) -> tuple[int, dict[str, float | bool] | None] | None:
        """The clock's version and what to show of it (None: unknown), or None when a page
        that has version ``known`` has it already."""
        with self._lock:
            if known == self._clock_version:
                return None
            return self._clock_version, self._clock

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
        self,
        view: View,
        seq: int = 0,
        known_meta: int = -1,
        extra: dict[str, float] | None = None,
        fields: dict[str, object] | None = None,
    ) -> tuple[int, bytes | None, bytes, FrameStats]:
        """Build one frame for ``view`` (``fields``: more fields of its header).

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
            scans: list[int] = []
            step = 1
            if view.scans:
                has_scan = np.fromiter((r.scan is not None for r in order), bool, len(order))
                selected = next((i for i, r in enumerate(order) if r.namespace == view.selected and has_scan[i]), None)
                beams = next((len(r.scan.ranges) for r in order if r.scan is not None), 360)
                scans, step = pick_scans(has_scan, selected, beams, poses, view)
            scan_arrays = [order[i].scan_points(1 if order[i].namespace == view.selected else step) for i in scans]
            trails, per_trail = pick_trails(poses, view) if view.trails else ([], 0)
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
            **(fields or {}),
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
