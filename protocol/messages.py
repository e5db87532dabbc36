"""Sensor and motion messages, mirroring the ROS 2 messages they stand for.

Field names follow ``geometry_msgs/Twist``, ``nav_msgs/Odometry`` and
``sensor_msgs/LaserScan`` so that a ROS user reads them without a table. Units are SI,
angles in radians, axes REP-103. Structs encode as MessagePack *maps* (named fields), so
any language can read them, and decoders ignore fields they do not know.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import msgspec

if TYPE_CHECKING:  # numpy is imported on use: CLI tools start 0.4 s faster without it
    import numpy as np
    import numpy.typing as npt


class Time(msgspec.Struct, kw_only=True):
    """``builtin_interfaces/Time``: sim time split into whole seconds and nanoseconds."""

    sec: int = 0
    nanosec: int = 0

    @classmethod
    def from_seconds(cls, t: float) -> Time:
        ns = round(t * 1e9)
        return cls(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)

    def to_seconds(self) -> float:
        return self.sec + self.nanosec * 1e-9


class Header(msgspec.Struct, kw_only=True):
    stamp: Time = msgspec.field(default_factory=Time)
    frame_id: str = ""


class Vector3(msgspec.Struct, kw_only=True):
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0


class Point(msgspec.Struct, kw_only=True):
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0


class Quaternion(msgspec.Struct, kw_only=True):
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    w: float = 1.0

    @classmethod
    def from_yaw(cls, yaw: float) -> Quaternion:
        return cls(z=math.sin(yaw / 2.0), w=math.cos(yaw / 2.0))

    def yaw(self) -> float:
        """Heading about +z (the only rotation a planar robot has)."""
        return math.atan2(2.0 * (self.w * self.z + self.x * self.y), 1.0 - 2.0 * (self.y**2 + self.z**2))


class Pose(msgspec.Struct, kw_only=True):
    position: Point = msgspec.field(default_factory=Point)
    orientation: Quaternion = msgspec.field(default_factory=Quaternion)


class PoseWithCovariance(msgspec.Struct, kw_only=True):
    pose: Pose = msgspec.field(default_factory=Pose)
    covariance: list[float] = msgspec.field(default_factory=lambda: [0.0] * 36)


class Twist(msgspec.Struct, kw_only=True):
    """``geometry_msgs/Twist``. The daemon uses ``linear.x`` and ``angular.z`` only."""

    linear: Vector3 = msgspec.field(default_factory=Vector3)
    angular: Vector3 = msgspec.field(default_factory=Vector3)


class TwistWithCovariance(msgspec.Struct, kw_only=True):
    twist: Twist = msgspec.field(default_factory=Twist)
    covariance: list[float] = msgspec.field(default_factory=lambda: [0.0] * 36)


class Odometry(msgspec.Struct, kw_only=True):
    """``nav_msgs/Odometry``: pose in the world (``<ns>/odom``) frame, twist in the body frame."""

    header: Header = msgspec.field(default_factory=Header)
    child_frame_id: str = ""
    pose: PoseWithCovariance = msgspec.field(default_factory=PoseWithCovariance)
    twist: TwistWithCovariance = msgspec.field(default_factory=TwistWithCovariance)


class LaserScan(msgspec.Struct, kw_only=True):
    """``sensor_msgs/LaserScan`` with ``ranges`` and ``intensities`` as packed float32.

    ``ranges`` holds little-endian float32 values (``numpy.frombuffer(ranges, '<f4')``);
    packing instead of a list makes encoding 16x and decoding 17x cheaper. In JSON the
    bytes appear base64-encoded. ``+inf`` means nothing within ``range_max``.
    """

    header: Header = msgspec.field(default_factory=Header)
    angle_min: float = 0.0
    angle_max: float = 0.0
    angle_increment: float = 0.0
    time_increment: float = 0.0
    scan_time: float = 0.0
    range_min: float = 0.0
    range_max: float = 0.0
    ranges: bytes = b""
    intensities: bytes = b""

    def ranges_array(self) -> npt.NDArray[np.float32]:
        """The ranges as a read-only float32 array (no copy)."""
        import numpy as np

        return np.frombuffer(self.ranges, dtype="<f4")

    def intensities_array(self) -> npt.NDArray[np.float32]:
        import numpy as np

        return np.frombuffer(self.intensities, dtype="<f4")


class FleetOdometry(msgspec.Struct, kw_only=True):
    """Every robot's odometry of one tick in one message, column by column (``P/odometry``).

    For programs that follow the whole fleet: at 100 robots and 20x real time the per-robot
    topics are 60 000 messages a second, which a Python subscriber cannot take (zenoh-python
    costs ~10 us of CPU per message on a 2-core machine); this is 600. Row ``i`` of every
    column belongs to ``namespaces[i]``. The values are those of that robot's
    ``P/<ns>/odom`` message with the same stamp, with the heading as ``yaw`` (radians) instead of
    a quaternion. Each column is little-endian float64 (``numpy.frombuffer(x, '<f8')``, or
    :meth:`array`). Frames and covariances are those of the per-robot messages.
    """

    stamp: Time = msgspec.field(default_factory=Time)
    namespaces: list[str] = msgspec.field(default_factory=list)
    x: bytes = b""
    y: bytes = b""
    yaw: bytes = b""
    linear_x: bytes = b""  # body frame, as twist.twist.linear.x
    linear_y: bytes = b""
    angular_z: bytes = b""

    def array(self, column: str) -> npt.NDArray[np.float64]:
        """One column (``x``, ``y``, ``yaw``, ``linear_x``, ``linear_y``, ``angular_z``) as a
        read-only float64 array, one value per namespace (no copy)."""
        import numpy as np

        if column not in FLEET_ODOM_COLUMNS:
            raise ValueError(f"no column {column!r}; the columns are {', '.join(FLEET_ODOM_COLUMNS)}")
        return np.frombuffer(getattr(self, column), dtype="<f8")


#: The float64 columns of a FleetOdometry, in wire order.
FLEET_ODOM_COLUMNS = ("x", "y", "yaw", "linear_x", "linear_y", "angular_z")


class FleetScans(msgspec.Struct, kw_only=True):
    """The scans taken in one tick, by every robot that scanned in it, in one message (``P/scans``).

    Robots scan at 5 Hz in groups spread over the ticks of a period (up to 128 robots a tick
    until the fleet fills all six), so each message holds the group due in its tick.
    Every robot carries the same LDS-01, so the angles and limits are given once. ``ranges``
    holds one row of ``beams`` little-endian float32 values per namespace, the ranges of that
    robot's ``P/<ns>/scan`` message with the same stamp (:meth:`ranges_array` gives the rows).
    """

    stamp: Time = msgspec.field(default_factory=Time)
    namespaces: list[str] = msgspec.field(default_factory=list)
    beams: int = 0
    angle_min: float = 0.0
    angle_max: float = 0.0
    angle_increment: float = 0.0
    time_increment: float = 0.0
    scan_time: float = 0.0
    range_min: float = 0.0
    range_max: float = 0.0
    ranges: bytes = b""

    def ranges_array(self) -> npt.NDArray[np.float32]:
        """The ranges as a read-only (len(namespaces), beams) float32 array (no copy)."""
        import numpy as np

        flat = np.frombuffer(self.ranges, dtype="<f4")
        if self.beams < 0 or flat.size != self.beams * len(self.namespaces):
            raise ValueError(f"{flat.size} ranges do not make {len(self.namespaces)} rows of {self.beams} beams")
        return flat.reshape(len(self.namespaces), self.beams)
