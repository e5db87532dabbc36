"""Scans and odometry of the fleet topics into a grid: each scan at its robot's pose of the same tick.

The fleet topics carry a tick's odometry and its scans as two messages, which may arrive in
either order: a scan waits for its tick's odometry, and the odometry of the last ``ODOM_KEPT_S``
of simulated time is kept for scans that come after it (zenoh sends scans at a lower priority
than odometry, so under load they trail it by a second or more). A scan whose odometry never
comes (lost on the way, or older than what is kept) is counted in ``unpaired``. The scan
is placed at the robot's pose plus the lidar's mounting offset of its model
(protocol/frames.py). With ``matching``, each scan's pose is first corrected against the map
(match.py) and, with ``loops`` (the default), handed to the back end (backend.py), which keeps
the keyframes and the pose graph, draws the scan, and tells which robots' corrections to move
when the graph bends. Used by fleet-map and by the viewer's live map layer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from clients.mapping.backend import Backend
from clients.mapping.grid import Beams, LogOddsGrid
from clients.mapping.match import locate
from clients.mapping.posegraph import compose
from clients.tick_merge import is_reset, stamp_ns
from protocol.frames import SCAN_OFFSET
from protocol.messages import FleetOdometry, FleetScans

#: simulated seconds of odometry kept to pair with scans that come after it
ODOM_KEPT_S = 10.0
#: scans kept waiting for their tick's odometry
WAITING_KEPT = 64


class TickPoses:
    """One tick's odometry as it came (columns, not a tuple per robot: a viewer's mapper keeps
    ten seconds of a thousand robots); a row index is shared by the ticks of one roster. In a
    fleet shared by several daemons a daemon's part may come after the rest of its tick
    (clients/tick_merge.py): it is added as a part of its own."""

    __slots__ = ("parts",)

    def __init__(self, rows: dict[str, int], msg: FleetOdometry) -> None:
        self.parts = [(rows, msg.array("x"), msg.array("y"), msg.array("yaw"))]

    def add(self, rows: dict[str, int], msg: FleetOdometry) -> None:
        self.parts.append((rows, msg.array("x"), msg.array("y"), msg.array("yaw")))

    def get(self, ns: str) -> tuple[float, float, float] | None:
        for rows, x, y, yaw in self.parts:
            i = rows.get(ns)
            if i is not None:
                return float(x[i]), float(y[i]), float(yaw[i])
        return None


@dataclass
class Mapper:
    """Pairs each scan with its robot's pose of the same tick and fuses it into the grid."""

    grid: LogOddsGrid
    robots: set[str] | None
    models: dict[str, str]
    #: each kept tick's odometry by stamp (nanoseconds), oldest first
    poses: dict[int, TickPoses] = field(default_factory=dict)
    waiting: list[FleetScans] = field(default_factory=list)
    #: scans (one a robot) left out because their tick's odometry did not come (or came too long before them)
    unpaired: int = 0
    _roster: tuple[list[str], dict[str, int]] = field(default_factory=lambda: ([], {}))
    paths: dict[str, list[tuple[float, float]]] = field(default_factory=dict)
    beams: Beams | None = None
    latest: dict[str, tuple[float, float, float]] = field(default_factory=dict)  # each robot's newest pose
    latest_stamp: int = -1  # the newest odometry's stamp, nanoseconds
    #: match each scan against the map before fusing it (scan matching corrects drifting odometry)
    matching: bool = False
    #: per robot, the map frame's pose of its odometry frame (x, y, yaw): what scan matching learned
    corrections: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    #: with matching, close loops too: keyframes, a pose graph, the grid redrawn when it bends (backend.py)
    loops: bool = True
    backend: Backend | None = None

    def __post_init__(self) -> None:
        if self.matching:
            self.grid.keep_points()

    def corrected(self, ns: str, pose: tuple[float, float, float]) -> tuple[float, float, float]:
        """An odometry pose in the map's frame."""
        cx, cy, cth = self.corrections.get(ns, (0.0, 0.0, 0.0))
        x, y, yaw = pose
        c, s = math.cos(cth), math.sin(cth)
        return cx + c * x - s * y, cy + s * x + c * y, math.atan2(math.sin(yaw + cth), math.cos(yaw + cth))

    def _learn(self, ns: str, odom: tuple[float, float, float], true_in_map: tuple[float, float, float]) -> None:
        """The correction that takes ``odom`` to ``true_in_map``."""
        x, y, yaw = true_in_map
        cth = yaw - odom[2]
        c, s = math.cos(cth), math.sin(cth)
        self.corrections[ns] = (x - (c * odom[0] - s * odom[1]), y - (s * odom[0] + c * odom[1]), cth)

    def take(self, msg: FleetOdometry | FleetScans) -> None:
        if isinstance(msg, FleetOdometry):
            self.on_odometry(msg)
        else:
            self.on_scans(msg)

    def on_odometry(self, msg: FleetOdometry) -> None:
        x, y, yaw = msg.array("x"), msg.array("y"), msg.array("yaw")
        for i, ns in enumerate(msg.namespaces):
            if self.follows(ns):
                here = self.corrected(ns, (float(x[i]), float(y[i]), float(yaw[i])))
                self.latest[ns] = here
                path = self.paths.setdefault(ns, [])
                if not path or abs(path[-1][0] - here[0]) + abs(path[-1][1] - here[1]) > 0.02:
                    path.append((here[0], here[1]))
        if msg.namespaces != self._roster[0]:
            self._roster = (msg.namespaces, {ns: i for i, ns in enumerate(msg.namespaces)})
        stamp = stamp_ns(msg.stamp)
        if stamp <= self.latest_stamp:
            if not is_reset(self.latest_stamp, stamp):
                # a daemon's part of a tick that went on without it (a shared fleet)
                if (kept := self.poses.get(stamp)) is not None:
                    kept.add(self._roster[1], msg)
                return
            self.poses.clear()  # the clock went back: the daemon was reset
            self.waiting.clear()
        self.poses[stamp] = TickPoses(self._roster[1], msg)
        self.latest_stamp = stamp
        oldest = stamp - ODOM_KEPT_S * 1e9
        while next(iter(self.poses)) < oldest:
            self.poses.pop(next(iter(self.poses)))
        waiting, self.waiting = self.waiting, []
        for scans in waiting:
            self.on_scans(scans)

    def follows(self, ns: str) -> bool:
        return self.robots is None or ns in self.robots

    def give_up_waiting(self) -> None:
        """The input ended: the scans still waiting for their odometry are counted as unpaired."""
        for msg in self.waiting:
            self.unpaired += sum(map(self.follows, msg.namespaces))
        self.waiting.clear()

    def on_scans(self, msg: FleetScans) -> None:
        stamp = stamp_ns(msg.stamp)
        poses = self.poses.get(stamp)
        if poses is None:
            # odometry comes in stamp order: once a later tick's has come, this one's never will
            if stamp > self.latest_stamp and len(self.waiting) < WAITING_KEPT:
                self.waiting.append(msg)  # its tick's odometry is still on its way
            else:
                self.unpaired += sum(map(self.follows, msg.namespaces))
            return
        if self.beams is None:
            self.beams = Beams(msg.angle_min, msg.angle_increment, msg.beams, msg.range_min, msg.range_max)
        rows = msg.ranges_array()
        for i, ns in enumerate(msg.namespaces):
            pose = poses.get(ns) if self.follows(ns) else None
            if pose is None:
                continue
            ox, oy, _ = SCAN_OFFSET.get(self.models.get(ns, "burger"), SCAN_OFFSET["burger"])
            x, y, yaw = self.corrected(ns, pose)
            if self.matching:
                (x, y, yaw), support = locate(self.grid, (x, y, yaw), (ox, oy), rows[i], self.beams)
                self._learn(ns, pose, (x, y, yaw))
                if self.loops:
                    if self.backend is None:
                        self.backend = Backend(self.grid, self.beams)
                    self._moved(self.backend.add(ns, (x, y, yaw), (ox, oy), rows[i], support))
                    continue
            sx, sy = x + ox * np.cos(yaw) - oy * np.sin(yaw), y + ox * np.sin(yaw) + oy * np.cos(yaw)
            self.grid.integrate(sx, sy, yaw, rows[i], self.beams)

    def _moved(self, moved: dict[str, tuple[float, float, float]]) -> None:
        """The pose graph moved these robots (by a rigid motion of the map frame each): their
        corrections, newest poses and drawn paths follow."""
        if not moved or self.backend is None:
            return
        for ns, motion in moved.items():
            if ns in self.corrections:
                self.corrections[ns] = compose(motion, self.corrections[ns])
            if ns in self.latest:
                self.latest[ns] = compose(motion, self.latest[ns])
            self.paths[ns] = [*self.backend.path(ns), self.latest.get(ns, (0.0, 0.0, 0.0))[:2]]
