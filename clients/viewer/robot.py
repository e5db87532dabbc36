"""One robot as the viewer keeps it: its pose and the recent ones (to place a scan at the pose
of its own stamp), its newest scan, and its trail; turned into world-frame points only when a
frame asks for them."""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from clients.viewer.decimate import TRAIL_MAX_POINTS
from fleetcommon.arrays import F32, F64
from protocol.frames import SCAN_OFFSET

#: ``base_scan`` in ``base_footprint`` (x, y) per model (protocol/frames.py, from the URDFs).
LIDAR_OFFSET: dict[str, tuple[float, float]] = {model: (x, y) for model, (x, y, _) in SCAN_OFFSET.items()}

TRAIL_SECONDS = 5.0  # sim seconds of trail kept per robot
TRAIL_MIN_STEP = 0.03  # m between stored trail points
POSE_HISTORY = 12  # odometry poses kept to match scan stamps (0.4 s at 30 Hz)


@dataclass
class KeptScan:
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
    scan: KeptScan | None = None
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
