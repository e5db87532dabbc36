"""The fleet topics' messages: one tick of the whole fleet in one message.

``P/odometry`` and ``P/scans`` carry what the per-robot topics carry, column by column, for a
client that follows every robot (a training loop, a fleet controller, a viewer of a thousand
robots). Their cost to a subscriber is per message, not per robot: one message a tick instead
of one per robot. Each is built only while somebody subscribes (simd/adapters/fleet/publisher.py), from the
same arrays the per-robot messages come from, so the two views of a tick agree to the bit.
"""

from __future__ import annotations

import msgspec
import numpy as np

from fleetcommon.arrays import F32, F64
from protocol.messages import FleetOdometry, FleetScans, Time
from simd.core.lidar import LidarSpec

_encoder = msgspec.msgpack.Encoder()


def _column(a: F64) -> bytes:
    return np.ascontiguousarray(a, dtype="<f8").tobytes()


def encode_fleet_odometry(
    namespaces: list[str], time: float, x: F64, y: F64, yaw: F64, linear_x: F64, linear_y: F64, angular_z: F64
) -> bytes:
    """One ``FleetOdometry`` of a tick, rows in ``namespaces`` order."""
    n = len(namespaces)
    cols = (x, y, yaw, linear_x, linear_y, angular_z)
    if any(len(c) != n for c in cols):
        raise ValueError(f"{n} namespaces for columns of {[len(c) for c in cols]} values")
    return _encoder.encode(
        FleetOdometry(
            stamp=Time.from_seconds(time),
            namespaces=namespaces,
            x=_column(x),
            y=_column(y),
            yaw=_column(yaw),
            linear_x=_column(linear_x),
            linear_y=_column(linear_y),
            angular_z=_column(angular_z),
        )
    )


def encode_fleet_scans(spec: LidarSpec, namespaces: list[str], time: float, scans: F32) -> bytes:
    """One ``FleetScans`` of a tick: row ``i`` of ``scans`` is ``namespaces[i]``'s scan."""
    rows = np.ascontiguousarray(scans, dtype="<f4")
    if rows.ndim != 2 or rows.shape != (len(namespaces), spec.samples):
        raise ValueError(f"{len(namespaces)} namespaces for scans of shape {rows.shape}")
    return _encoder.encode(
        FleetScans(
            stamp=Time.from_seconds(time),
            namespaces=namespaces,
            beams=spec.samples,
            angle_min=spec.angle_min,
            angle_max=spec.angle_max,
            angle_increment=spec.angle_increment,
            range_min=spec.range_min,
            range_max=spec.range_max,
            ranges=rows.tobytes(),
        )
    )
