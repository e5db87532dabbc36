"""The fleet protocol's messages as ROS 2 messages (rosbags' classes), for bags made without ROS.

What the daemon's ROS 2 adapter would have sent for the same tick: ``nav_msgs/Odometry`` with
frames ``<ns>/odom`` -> ``<ns>/base_footprint``, ``sensor_msgs/LaserScan`` in ``<ns>/base_scan``,
one ``tf2_msgs/TFMessage`` a tick for ``/tf``, each robot's fixed frames for ``/tf_static``
(protocol/frames.py) and ``rosgraph_msgs/Clock``. Pure functions of their inputs: the recorder
does the I/O.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from protocol.frames import Transform
from protocol.messages import FleetOdometry, FleetScans, Time

Make = Callable[..., Any]  # BagWriter.make: (typename, **fields) -> message


def stamp_ns(t: Time) -> int:
    return t.sec * 1_000_000_000 + t.nanosec


def _time(make: Make, t: Time) -> Any:
    return make("builtin_interfaces/msg/Time", sec=t.sec, nanosec=t.nanosec)


def _header(make: Make, t: Time, frame: str) -> Any:
    return make("std_msgs/msg/Header", stamp=_time(make, t), frame_id=frame)


def _v3(make: Make, x: float, y: float, z: float) -> Any:
    return make("geometry_msgs/msg/Vector3", x=float(x), y=float(y), z=float(z))


def _yaw(make: Make, yaw: float) -> Any:
    return make("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))


def odometry(make: Make, msg: FleetOdometry, rows: Sequence[int], covariance: npt.NDArray[np.float64]) -> list[Any]:
    """nav_msgs/msg/Odometry of rows ``rows`` of a fleet odometry message."""
    cols = {c: msg.array(c) for c in ("x", "y", "yaw", "linear_x", "linear_y", "angular_z")}
    out = []
    for i in rows:
        ns = msg.namespaces[i]
        pose = make("geometry_msgs/msg/Pose", position=make("geometry_msgs/msg/Point", x=float(cols["x"][i]),
                    y=float(cols["y"][i]), z=0.0), orientation=_yaw(make, float(cols["yaw"][i])))  # fmt: skip
        twist = make("geometry_msgs/msg/Twist", linear=_v3(make, cols["linear_x"][i], cols["linear_y"][i], 0.0),
                     angular=_v3(make, 0.0, 0.0, cols["angular_z"][i]))  # fmt: skip
        out.append(
            make(
                "nav_msgs/msg/Odometry",
                header=_header(make, msg.stamp, f"{ns}/odom"),
                child_frame_id=f"{ns}/base_footprint",
                pose=make("geometry_msgs/msg/PoseWithCovariance", pose=pose, covariance=covariance),
                twist=make("geometry_msgs/msg/TwistWithCovariance", twist=twist, covariance=covariance),
            )
        )
    return out


def tf(make: Make, msg: FleetOdometry, rows: Sequence[int]) -> Any:
    """/tf of one tick: odom -> base_footprint of rows ``rows``."""
    x, y, yaw = msg.array("x"), msg.array("y"), msg.array("yaw")
    transforms = [
        make("geometry_msgs/msg/TransformStamped", header=_header(make, msg.stamp, f"{msg.namespaces[i]}/odom"),
             child_frame_id=f"{msg.namespaces[i]}/base_footprint",
             transform=make("geometry_msgs/msg/Transform", translation=_v3(make, x[i], y[i], 0.0),
                            rotation=_yaw(make, float(yaw[i]))))
        for i in rows
    ]  # fmt: skip
    return make("tf2_msgs/msg/TFMessage", transforms=transforms)


def scans(make: Make, msg: FleetScans, rows: Sequence[int]) -> list[Any]:
    """sensor_msgs/msg/LaserScan of rows ``rows`` of a fleet scans message (intensities 0, as Gazebo)."""
    ranges = msg.ranges_array()
    zeros = np.zeros(msg.beams, dtype=np.float32)
    out = []
    for i in rows:
        header = _header(make, msg.stamp, f"{msg.namespaces[i]}/base_scan")
        out.append(
            make(
                "sensor_msgs/msg/LaserScan",
                header=header,
                angle_min=msg.angle_min,
                angle_max=msg.angle_max,
                angle_increment=msg.angle_increment,
                time_increment=msg.time_increment,
                scan_time=msg.scan_time,
                range_min=msg.range_min,
                range_max=msg.range_max,
                ranges=np.array(ranges[i], dtype=np.float32),
                intensities=zeros,
            )
        )
    return out


def static_tf(make: Make, transforms: Sequence[Transform]) -> Any:
    """/tf_static: fixed frames, stamped zero (they hold at every time)."""
    zero = make("builtin_interfaces/msg/Time", sec=0, nanosec=0)
    return make(
        "tf2_msgs/msg/TFMessage",
        transforms=[
            make("geometry_msgs/msg/TransformStamped",
                 header=make("std_msgs/msg/Header", stamp=zero, frame_id=parent), child_frame_id=child,
                 transform=make("geometry_msgs/msg/Transform", translation=_v3(make, *xyz),
                                rotation=make("geometry_msgs/msg/Quaternion", x=q[0], y=q[1], z=q[2], w=q[3])))
            for parent, child, xyz, q in transforms
        ],
    )  # fmt: skip


def clock(make: Make, t: Time) -> Any:
    return make("rosgraph_msgs/msg/Clock", clock=_time(make, t))
