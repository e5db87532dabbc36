"""Pure conversions from core objects to protocol messages (no zenoh here)."""

from __future__ import annotations

import math

import msgspec
import numpy as np
import numpy.typing as npt

from protocol.control import (
    Bounds,
    Circle,
    Frames,
    Pose2D,
    RobotRecord,
    Topics,
    WorldInfo,
)
from protocol.keys import Keys
from protocol.messages import (
    Header,
    LaserScan,
    Odometry,
    Point,
    Pose,
    PoseWithCovariance,
    Quaternion,
    Time,
    Twist,
    TwistWithCovariance,
    Vector3,
)
from simd.core.lidar import LidarSpec
from simd.core.models import ODOM_COVARIANCE_DIAGONAL
from simd.core.snapshot import RobotState, TickSnapshot
from simd.core.worldfile import WorldGeometry


def _covariance() -> list[float]:
    c = [0.0] * 36
    for i, d in enumerate(ODOM_COVARIANCE_DIAGONAL):
        c[i * 7] = d
    return c


_COVARIANCE = _covariance()
_encoder = msgspec.msgpack.Encoder()


def frames(ns: str) -> Frames:
    return Frames(odom=f"{ns}/odom", base_footprint=f"{ns}/base_footprint", base_scan=f"{ns}/base_scan")


def robot_record(state: RobotState, keys: Keys, daemon: str = "") -> RobotRecord:
    ns = state.namespace
    sx, sy, syaw = state.spawn_pose
    return RobotRecord(
        name=state.name,
        namespace=ns,
        model=state.model.name,
        pose=Pose2D(x=state.x, y=state.y, yaw=state.yaw),
        linear_velocity=state.linear_velocity,
        angular_velocity=state.angular_velocity,
        spawn_pose=Pose2D(x=sx, y=sy, yaw=syaw),
        limits=state.model.limits(),
        footprint=[(float(px), float(py)) for px, py in state.model.outline],
        topics=Topics(cmd_vel=keys.cmd_vel(ns), odom=keys.odom(ns), scan=keys.scan(ns), alive=keys.alive(ns)),
        frames=frames(ns),
        daemon=daemon,
        lateral_velocity=state.lateral_velocity,
    )


def world_info(world: WorldGeometry) -> WorldInfo:
    x0, x1, y0, y1 = world.bounds
    sx, sy, syaw = world.default_spawn
    return WorldInfo(
        name=world.name,
        bounds=Bounds(x_min=x0, x_max=x1, y_min=y0, y_max=y1),
        default_spawn=Pose2D(x=sx, y=sy, yaw=syaw),
        polygons=[[(float(px), float(py)) for px, py in poly] for poly in world.polygons],
        circles=[Circle(x=float(c[0]), y=float(c[1]), radius=float(c[2])) for c in world.circles],
    )


def odometry(ns: str, stamp: Time, x: float, y: float, yaw: float, vx: float, vy: float, wz: float) -> Odometry:
    return Odometry(
        header=Header(stamp=stamp, frame_id=f"{ns}/odom"),
        child_frame_id=f"{ns}/base_footprint",
        pose=PoseWithCovariance(
            pose=Pose(
                position=Point(x=x, y=y),
                orientation=Quaternion(z=math.sin(yaw * 0.5), w=math.cos(yaw * 0.5)),
            ),
            covariance=_COVARIANCE,
        ),
        twist=TwistWithCovariance(
            twist=Twist(linear=Vector3(x=vx, y=vy), angular=Vector3(z=wz)),
            covariance=_COVARIANCE,
        ),
    )


def laser_scan(ns: str, stamp: Time, spec: LidarSpec, ranges: npt.NDArray[np.float32]) -> LaserScan:
    """One robot's scan as the protocol's ``LaserScan`` (ranges little-endian float32)."""
    return LaserScan(
        header=Header(stamp=stamp, frame_id=f"{ns}/base_scan"),
        angle_min=spec.angle_min,
        angle_max=spec.angle_max,
        angle_increment=spec.angle_increment,
        range_min=spec.range_min,
        range_max=spec.range_max,
        ranges=ranges.astype("<f4", copy=False).tobytes(),
    )


def odometry_row(snap: TickSnapshot, i: int) -> Odometry:
    """Row ``i`` of a tick as the protocol's ``Odometry``."""
    return odometry(
        snap.namespaces[i], Time.from_seconds(snap.time), float(snap.x[i]), float(snap.y[i]), float(snap.yaw[i]),
        float(snap.linear_x[i]), float(snap.linear_y[i]), float(snap.angular_z[i]),
    )  # fmt: skip


def encode_scans(out: TickSnapshot, spec: LidarSpec) -> list[bytes]:
    """One MessagePack LaserScan per scan in ``out.scan_namespaces`` order, struct by struct:
    the reference that the daemon's byte templates (simd/wire/scan_codec.py) are tested against."""
    stamp = Time.from_seconds(out.time)
    return [_encoder.encode(laser_scan(ns, stamp, spec, out.scans[i])) for i, ns in enumerate(out.scan_namespaces)]
