"""Scans and odometry of the fleet topics into a grid: each scan at its robot's pose of the same tick.

The fleet topics carry a tick's odometry and its scans as two messages, which may arrive in
either order; a scan waits for its tick's odometry (a few ticks of odometry are kept). The scan
is placed at the robot's pose plus the lidar's mounting offset of its model
(protocol/frames.py). Used by fleet-map and by the viewer's live map layer.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from clients.mapping.grid import Beams, LogOddsGrid
from protocol.frames import SCAN_OFFSET
from protocol.messages import FleetOdometry, FleetScans

#: ticks of odometry kept to pair with scans that arrive first
ODOM_KEPT = 30


@dataclass
class Mapper:
    """Pairs each scan with its robot's pose of the same tick and fuses it into the grid."""

    grid: LogOddsGrid
    robots: set[str] | None
    models: dict[str, str]
    poses: dict[tuple[int, int], dict[str, tuple[float, float, float]]] = field(default_factory=dict)
    waiting: list[FleetScans] = field(default_factory=list)
    paths: dict[str, list[tuple[float, float]]] = field(default_factory=dict)
    beams: Beams | None = None
    latest: dict[str, tuple[float, float, float]] = field(default_factory=dict)  # each robot's newest pose
    latest_stamp: tuple[int, int] = (-1, 0)

    def take(self, msg: FleetOdometry | FleetScans) -> None:
        if isinstance(msg, FleetOdometry):
            self.on_odometry(msg)
        else:
            self.on_scans(msg)

    def on_odometry(self, msg: FleetOdometry) -> None:
        x, y, yaw = msg.array("x"), msg.array("y"), msg.array("yaw")
        tick = {}
        for i, ns in enumerate(msg.namespaces):
            if self.robots is None or ns in self.robots:
                tick[ns] = (float(x[i]), float(y[i]), float(yaw[i]))
                path = self.paths.setdefault(ns, [])
                if not path or abs(path[-1][0] - tick[ns][0]) + abs(path[-1][1] - tick[ns][1]) > 0.02:
                    path.append((tick[ns][0], tick[ns][1]))
        self.poses[(msg.stamp.sec, msg.stamp.nanosec)] = tick
        self.latest.update(tick)
        self.latest_stamp = max(self.latest_stamp, (msg.stamp.sec, msg.stamp.nanosec))
        while len(self.poses) > ODOM_KEPT:
            self.poses.pop(next(iter(self.poses)))
        waiting, self.waiting = self.waiting, []
        for scans in waiting:
            self.on_scans(scans)

    def on_scans(self, msg: FleetScans) -> None:
        poses = self.poses.get((msg.stamp.sec, msg.stamp.nanosec))
        if poses is None:
            if len(self.waiting) < ODOM_KEPT:
                self.waiting.append(msg)  # its tick's odometry is still on its way
            return
        if self.beams is None:
            self.beams = Beams(msg.angle_min, msg.angle_increment, msg.beams, msg.range_min, msg.range_max)
        rows = msg.ranges_array()
        for i, ns in enumerate(msg.namespaces):
            pose = poses.get(ns)
            if pose is None:
                continue
            x, y, yaw = pose
            ox, oy, _ = SCAN_OFFSET.get(self.models.get(ns, "burger"), SCAN_OFFSET["burger"])
            sx, sy = x + ox * np.cos(yaw) - oy * np.sin(yaw), y + ox * np.sin(yaw) + oy * np.cos(yaw)
            self.grid.integrate(sx, sy, yaw, rows[i], self.beams)
