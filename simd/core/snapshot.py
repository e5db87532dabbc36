"""What the core hands out: one tick's measurements, and robots as list/spawn/delete see them.

A :class:`TickSnapshot` is the only thing that leaves the simulation thread each tick. Its
arrays are never written again once it is handed out (the step replaces whole columns rather
than writing into them), so an adapter may keep it and read it on another thread while the
next tick runs. Its scans may still be in the making when it is handed out (the lidar runs on
a thread of its own, beside the next tick's physics): reading ``scans`` waits for them.
"""

from __future__ import annotations

from concurrent.futures import Future
from dataclasses import dataclass, field

import numpy as np

from fleetcommon.arrays import F32, F64, I64
from simd.core.models import RobotModel


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
    lateral_velocity: float = 0.0  # body-frame y: nonzero only while pushed sideways
    #: the pose its odometry reports (x, y, yaw): the true pose above unless --odom-noise
    odom: tuple[float, float, float] | None = None

    @property
    def odom_pose(self) -> tuple[float, float, float]:
        return self.odom if self.odom is not None else (self.x, self.y, self.yaw)


@dataclass(slots=True, kw_only=True)
class TickSnapshot:
    """What one tick measured: odometry of every robot, scans of those due.

    ``x``, ``y`` and ``yaw`` are the odometry's pose: the true pose, unless the wheels slip
    (``SimConfig.odom_noise``); then ``true_pose`` holds the true one (None: the same). The
    scans are taken from the true pose.

    Rows of the odometry columns follow ``namespaces``; rows of ``scans`` follow
    ``scan_namespaces``. ``epoch`` counts resets: two snapshots with the same tick number
    but different epochs belong to different runs of the world. ``generation`` is the robot
    table's (:attr:`RobotTable.generation`) when the tick ran: snapshots with the same one
    have the same rows.

    Read only: handed to every adapter and kept for the step's observations, a snapshot is
    never written after the tick made it, nor are its arrays (the step replaces the table's
    columns). Not a frozen dataclass only because a frozen one costs ~1 µs more to make, at
    every tick (a learner's one-robot step is six ticks of ~15 µs).
    """

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
    scan_rows: F32 | Future[F32]  # (k, samples), or the lidar's promise of them
    epoch: int = 0
    #: the table rows of ``scan_namespaces`` (rows of this tick's ``namespaces``)
    scan_index: I64 = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    #: the true (x, y, yaw) columns when the odometry drifts from them, else None
    true_pose: tuple[F64, F64, F64] | None = None
    #: the robot table's generation: the same rows as the table while it has this one
    generation: int = 0

    @property
    def truth(self) -> tuple[F64, F64, F64]:
        """The true pose columns (the odometry's when it is exact)."""
        return self.true_pose if self.true_pose is not None else (self.x, self.y, self.yaw)

    @property
    def scans(self) -> F32:
        """The scans of ``scan_namespaces``, row by row (waits for the lidar if need be)."""
        rows = self.scan_rows
        return rows.result() if isinstance(rows, Future) else rows
