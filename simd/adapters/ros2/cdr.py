"""CDR for the messages sent every tick, built from the snapshot's columns without message objects.

rosbags serializes one message object at a time (tens of microseconds each); a fleet of a
thousand robots sends odometry thirty times a second, so the hot messages are laid out here
once per robot (header, frame names, padding, constant covariances) and each tick only packs
the numbers. The layout follows CDR as Fast-CDR writes it for rmw_zenoh: a 4-byte
little-endian encapsulation header, then every primitive aligned to its size counted from the
end of that header, strings as a uint32 length (NUL included) and the bytes. The tests check
every encoder byte for byte against ``rosbags.serialize_cdr``, and the two decoders (the
commands coming in) against ``rosbags.deserialize_cdr``. The TF messages are in tf_cdr.py.

A robot's frames carry its namespace (``TB3_1/odom``, the fleet's one tree) unless an encoder is
made with ``prefixed=False`` (``odom``: each robot's tree of its own, Nav2's multi-robot layout).
"""

from __future__ import annotations

import math
import struct

import numpy as np
import numpy.typing as npt

from fleetcommon.arrays import F32
from protocol.frames import frame_id as robot_frame
from protocol.messages import Time
from simd.core.snapshot import TickSnapshot

ENCAPSULATION = b"\x00\x01\x00\x00"  # CDR, little endian
_STAMP = struct.Struct("<iI")
_U32 = struct.Struct("<I")


def _pad(pos: int, size: int) -> int:
    return -pos % size


def cdr_string(text: str, pos: int) -> bytes:
    """A string at payload offset ``pos``: padding to 4, uint32 length with the NUL, bytes, NUL."""
    raw = text.encode() + b"\x00"
    return b"\x00" * _pad(pos, 4) + _U32.pack(len(raw)) + raw


def frames_blob(frame_id: str, child: str | None, pos: int, align_after: int) -> bytes:
    """The strings of a header (and a child frame) from ``pos`` up to the next field aligned
    to ``align_after``."""
    blob = cdr_string(frame_id, pos)
    if child is not None:
        blob += cdr_string(child, pos + len(blob))
    return blob + b"\x00" * _pad(pos + len(blob), align_after)


def stamp(t: float) -> tuple[int, int]:
    """builtin_interfaces/Time of sim time ``t``: whole seconds and nanoseconds (as the fleet
    protocol's stamps)."""
    time = Time.from_seconds(t)
    return time.sec, time.nanosec


def covariance(diagonal: tuple[float, ...]) -> bytes:
    c = np.zeros((6, 6))
    np.fill_diagonal(c, diagonal)
    return c.tobytes()


def write_stamps(buf: npt.NDArray[np.uint8], stamp_at: npt.NDArray[np.intp], t: float) -> None:
    """Write sim time ``t`` as builtin_interfaces/Time at int32 indices ``stamp_at`` of a laid-out buffer."""
    i32 = buf.view(np.int32)
    sec, nsec = stamp(t)
    i32[stamp_at] = sec
    i32[stamp_at + 1] = nsec


def write_poses(
    f64: npt.NDArray[np.float64], pose_at: npt.NDArray[np.intp],
    x: npt.NDArray[np.float64], y: npt.NDArray[np.float64], yaw: npt.NDArray[np.float64],
) -> None:  # fmt: skip
    """Write planar poses at float64 indices ``pose_at`` of a laid-out buffer: x y (z stays 0),
    then the yaw's quaternion (qx qy stay 0, qz qw)."""
    half = yaw / 2.0
    f64[pose_at] = x
    f64[pose_at + 1] = y
    f64[pose_at + 5] = np.sin(half)
    f64[pose_at + 6] = np.cos(half)


def _write_stamps_and_poses(
    buf: npt.NDArray[np.uint8], stamp_at: npt.NDArray[np.intp], pose_at: npt.NDArray[np.intp],
    snap: TickSnapshot, rows: npt.NDArray[np.intp],
) -> npt.NDArray[np.float64]:  # fmt: skip
    """Write the tick's stamp (int32 indices ``stamp_at``) and each robot's position and yaw
    quaternion (float64 indices ``pose_at``: x y z, then qx qy qz qw) into a laid-out buffer;
    returns its float64 view for the rest."""
    write_stamps(buf, stamp_at, snap.time)
    f64 = buf.view(np.float64)
    write_poses(f64, pose_at, snap.x[rows], snap.y[rows], snap.yaw[rows])
    return f64


class OdometryCdr:
    """nav_msgs/msg/Odometry of every robot in a tick: frames ``<ns>/odom`` -> ``<ns>/base_footprint``.

    The messages of a tick are laid out in one buffer, once for a set of robots: each message
    starts 4 bytes before an 8-aligned offset, so that its payload and the doubles in it are
    8-aligned in the buffer, and a tick writes the stamps and the numbers of all of them with a
    few numpy assignments. Each robot's message is then one slice of the buffer's bytes.
    """

    def __init__(self, covariance_diagonal: tuple[float, ...], prefixed: bool = True) -> None:
        self._cov = covariance(covariance_diagonal)
        self._prefixed = prefixed
        self._key: tuple[str, ...] = ()
        self._buf = np.zeros(0, np.uint8)
        self._spans: list[tuple[int, int]] = []
        self._stamp_at = np.zeros(0, np.intp)  # int32 index of each message's stamp
        self._pose_at = np.zeros(0, np.intp)  # float64 index of each message's pose

    def forget(self, ns: str) -> None:
        self._key = ()

    def _lay_out(self, names: tuple[str, ...]) -> None:
        parts: list[bytes] = []
        spans, stamps, poses = [], [], []
        pos = 0
        for ns in names:
            pad = (4 - pos) % 8  # the payload (after the 4-byte header) starts 8-aligned
            parts.append(bytes(pad))
            pos += pad
            odom, base = robot_frame(ns, "odom", self._prefixed), robot_frame(ns, "base_footprint", self._prefixed)
            frames = frames_blob(odom, base, 8, 8)
            message = b"".join((ENCAPSULATION, bytes(8), frames, bytes(56), self._cov, bytes(48), self._cov))
            spans.append((pos, pos + len(message)))
            stamps.append((pos + 4) // 4)
            poses.append((pos + 4 + 8 + len(frames)) // 8)
            parts.append(message)
            pos += len(message)
        self._buf = np.frombuffer(b"".join(parts) + bytes(8), dtype=np.uint8).copy()
        self._spans = spans
        self._stamp_at = np.asarray(stamps, dtype=np.intp)
        self._pose_at = np.asarray(poses, dtype=np.intp)
        self._key = names

    def encode(self, snap: TickSnapshot, rows: list[int]) -> list[bytes]:
        """The messages of robots ``rows`` (indices into the snapshot's columns)."""
        if not rows:
            return []
        names = tuple(snap.namespaces[r] for r in rows)
        if names != self._key:
            self._lay_out(names)
        idx = np.asarray(rows, dtype=np.intp)
        f64 = _write_stamps_and_poses(self._buf[: len(self._buf) // 8 * 8], self._stamp_at, self._pose_at, snap, idx)
        twist = self._pose_at + 7 + 36  # after the pose and its covariance
        f64[twist] = snap.linear_x[idx]
        f64[twist + 1] = snap.linear_y[idx]
        f64[twist + 5] = snap.angular_z[idx]
        data = self._buf.tobytes()
        return [data[a:b] for a, b in self._spans]


class LaserScanCdr:
    """sensor_msgs/msg/LaserScan as the Gazebo LDS-01 plugin fills it (frame ``<ns>/base_scan``;
    time_increment and scan_time 0; intensities all 0, one per range)."""

    def __init__(self, angle_min: float, angle_max: float, angle_increment: float,
                 range_min: float, range_max: float, samples: int, prefixed: bool = True) -> None:  # fmt: skip
        self._prefixed = prefixed
        self._params = struct.pack("<7f", angle_min, angle_max, angle_increment, 0.0, 0.0, range_min, range_max)
        self._count = _U32.pack(samples)
        self._intensities = self._count + bytes(4 * samples)
        self._samples = samples
        self._frames: dict[str, bytes] = {}

    def _frames_of(self, ns: str) -> bytes:
        blob = self._frames.get(ns)
        if blob is None:
            frame = robot_frame(ns, "base_scan", self._prefixed)
            blob = self._frames[ns] = frames_blob(frame, None, 8, 4) + self._params + self._count
        return blob

    def forget(self, ns: str) -> None:
        self._frames.pop(ns, None)

    def encode(self, ns: str, t: float, ranges: F32) -> bytes:
        if len(ranges) != self._samples:
            raise ValueError(f"scan of {len(ranges)} ranges, expected {self._samples}")
        return b"".join(
            (ENCAPSULATION, _STAMP.pack(*stamp(t)), self._frames_of(ns),
             np.ascontiguousarray(ranges, dtype="<f4").tobytes(), self._intensities)
        )  # fmt: skip


def clock_cdr(t: float) -> bytes:
    """rosgraph_msgs/msg/Clock."""
    return ENCAPSULATION + _STAMP.pack(*stamp(t))


class CdrError(ValueError):
    """A payload that is not the CDR of the expected message."""


def _check_header(data: bytes) -> str:
    if len(data) < 4 or data[0] != 0 or data[1] not in (0, 1):
        raise CdrError("no CDR encapsulation header")
    return "<" if data[1] == 1 else ">"


def decode_twist(data: bytes) -> tuple[float, float]:
    """(linear.x, angular.z) of a geometry_msgs/msg/Twist."""
    end = _check_header(data)
    if len(data) < 4 + 48:
        raise CdrError(f"Twist needs 52 bytes, got {len(data)}")
    lx, _, _, _, _, az = struct.unpack_from(end + "6d", data, 4)
    return _finite(lx, az)


def decode_twist_stamped(data: bytes) -> tuple[float, float]:
    """(linear.x, angular.z) of a geometry_msgs/msg/TwistStamped (the header is skipped)."""
    end = _check_header(data)
    if len(data) < 4 + 12:
        raise CdrError("TwistStamped too short")
    (length,) = struct.unpack_from(end + "I", data, 4 + 8)
    pos = 12 + length  # payload offset after the frame id
    pos += _pad(pos, 8)
    if length == 0 or len(data) < 4 + pos + 48:
        raise CdrError("TwistStamped too short for its frame id")
    lx, _, _, _, _, az = struct.unpack_from(end + "6d", data, 4 + pos)
    return _finite(lx, az)


def _finite(v: float, w: float) -> tuple[float, float]:
    if not (math.isfinite(v) and math.isfinite(w)):
        raise CdrError("velocity is not finite")
    return v, w


class ImuCdr:
    """sensor_msgs/msg/Imu in frame ``<ns>/imu_link``, covariances as the Gazebo TurtleBot3 IMU
    (orientation's not filled, angular velocity 4e-8, linear acceleration 2.89e-4 on the diagonal)."""

    def __init__(self, prefixed: bool = True) -> None:
        self._prefixed = prefixed
        zero9 = bytes(72)
        self._angular_cov = np.diag([4e-8] * 3).tobytes()
        self._linear_cov = np.diag([2.89e-4] * 3).tobytes()
        self._orientation_cov = zero9
        self._frames: dict[str, bytes] = {}

    def forget(self, ns: str) -> None:
        self._frames.pop(ns, None)

    def encode(self, ns: str, t: float, yaw: float, angular_z: float, accel_x: float, accel_y: float) -> bytes:
        blob = self._frames.get(ns)
        if blob is None:
            blob = self._frames[ns] = frames_blob(robot_frame(ns, "imu_link", self._prefixed), None, 8, 8)
        half = yaw / 2.0
        return b"".join(
            (
                ENCAPSULATION,
                _STAMP.pack(*stamp(t)),
                blob,
                struct.pack("<4d", 0.0, 0.0, math.sin(half), math.cos(half)),
                self._orientation_cov,
                struct.pack("<3d", 0.0, 0.0, angular_z),
                self._angular_cov,
                struct.pack("<3d", accel_x, accel_y, GRAVITY),
                self._linear_cov,
            )
        )


#: What an IMU at rest on level ground reads on z (it measures the reaction to gravity)
GRAVITY = 9.80665

WHEEL_JOINTS = ("wheel_left_joint", "wheel_right_joint")


class JointStateCdr:
    """sensor_msgs/msg/JointState of the two wheel joints: position and velocity, no effort."""

    def __init__(self) -> None:
        pos = 8 + len(frames_blob("", None, 8, 4))  # the header's frame id is empty, as Gazebo's
        names = _U32.pack(len(WHEEL_JOINTS))
        pos += 4
        for joint in WHEEL_JOINTS:
            s = cdr_string(joint, pos)
            names += s
            pos += len(s)
        count = b"\x00" * _pad(pos, 4) + _U32.pack(2)
        pos += len(count)
        self._middle = frames_blob("", None, 8, 4) + names + count + b"\x00" * _pad(pos, 8)
        # after the two positions the offset is 8-aligned: velocity's count, 4 bytes of padding
        self._velocity = struct.Struct("<I4x2d")
        self._effort = _U32.pack(0)

    def encode(self, t: float, positions: tuple[float, float], velocities: tuple[float, float]) -> bytes:
        return b"".join(
            (
                ENCAPSULATION,
                _STAMP.pack(*stamp(t)),
                self._middle,
                struct.pack("<2d", *positions),
                self._velocity.pack(2, *velocities),
                self._effort,
            )
        )
