"""CDR for the messages sent every tick, built from the snapshot's columns without message objects.

rosbags serializes one message object at a time (tens of microseconds each); a fleet of a
thousand robots sends odometry thirty times a second, so the hot messages are laid out here
once per robot (header, frame names, padding, constant covariances) and each tick only packs
the numbers. The layout follows CDR as Fast-CDR writes it for rmw_zenoh: a 4-byte
little-endian encapsulation header, then every primitive aligned to its size counted from the
end of that header, strings as a uint32 length (NUL included) and the bytes. The tests check
every encoder byte for byte against ``rosbags.serialize_cdr``, and the two decoders (the
commands coming in) against ``rosbags.deserialize_cdr``.
"""

from __future__ import annotations

import math
import struct

import numpy as np
import numpy.typing as npt

from protocol.frames import Transform
from protocol.messages import Time
from simd.core.snapshot import TickSnapshot

F32 = npt.NDArray[np.float32]

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


def _write_stamps_and_poses(
    buf: npt.NDArray[np.uint8], stamp_at: npt.NDArray[np.intp], pose_at: npt.NDArray[np.intp],
    snap: TickSnapshot, rows: npt.NDArray[np.intp],
) -> npt.NDArray[np.float64]:  # fmt: skip
    """Write the tick's stamp (int32 indices ``stamp_at``) and each robot's position and yaw
    quaternion (float64 indices ``pose_at``: x y z, then qx qy qz qw) into a laid-out buffer;
    returns its float64 view for the rest."""
    i32 = buf.view(np.int32)
    f64 = buf.view(np.float64)
    sec, nsec = stamp(snap.time)
    i32[stamp_at] = sec
    i32[stamp_at + 1] = nsec
    half = snap.yaw[rows] / 2.0
    f64[pose_at] = snap.x[rows]
    f64[pose_at + 1] = snap.y[rows]
    f64[pose_at + 5] = np.sin(half)
    f64[pose_at + 6] = np.cos(half)
    return f64


class OdometryCdr:
    """nav_msgs/msg/Odometry of every robot in a tick: frames ``<ns>/odom`` -> ``<ns>/base_footprint``.

    The messages of a tick are laid out in one buffer, once for a set of robots: each message
    starts 4 bytes before an 8-aligned offset, so that its payload and the doubles in it are
    8-aligned in the buffer, and a tick writes the stamps and the numbers of all of them with a
    few numpy assignments. Each robot's message is then one slice of the buffer's bytes.
    """

    def __init__(self, covariance_diagonal: tuple[float, ...]) -> None:
        self._cov = covariance(covariance_diagonal)
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
            frames = frames_blob(f"{ns}/odom", f"{ns}/base_footprint", 8, 8)
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
                 range_min: float, range_max: float, samples: int) -> None:  # fmt: skip
        self._params = struct.pack("<7f", angle_min, angle_max, angle_increment, 0.0, 0.0, range_min, range_max)
        self._count = _U32.pack(samples)
        self._intensities = self._count + bytes(4 * samples)
        self._samples = samples
        self._frames: dict[str, bytes] = {}

    def _frames_of(self, ns: str) -> bytes:
        blob = self._frames.get(ns)
        if blob is None:
            blob = self._frames[ns] = frames_blob(f"{ns}/base_scan", None, 8, 4) + self._params + self._count
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


class TfCdr:
    """tf2_msgs/msg/TFMessage with one odom -> base_footprint transform per robot.

    Laid out once for a set of robots, like :class:`OdometryCdr`: the first transform starts 4
    bytes into the payload (after the count), every later one 8-aligned (each ends with
    doubles), and a tick writes the stamps and numbers with numpy.
    """

    def __init__(self) -> None:
        self._key: tuple[str, ...] = ()
        self._buf = np.zeros(0, np.uint8)
        self._stamp_at = np.zeros(0, np.intp)
        self._xyz_at = np.zeros(0, np.intp)
        self._end = 0

    def forget(self, ns: str) -> None:
        self._key = ()

    def _lay_out(self, names: tuple[str, ...]) -> None:
        # 4 bytes of padding, the header, then the payload 8-aligned in the buffer
        parts = [bytes(4), ENCAPSULATION, _U32.pack(len(names))]
        stamps, xyz = [], []
        pos = 4  # payload offset
        for ns in names:
            frames = frames_blob(f"{ns}/odom", f"{ns}/base_footprint", pos + 8, 8)
            stamps.append((pos + 8) // 4)
            xyz.append((pos + 8 + 8 + len(frames)) // 8)
            parts += (bytes(8), frames, bytes(56))
            pos += 8 + len(frames) + 56
        raw = b"".join(parts)
        self._end = len(raw)
        self._buf = np.frombuffer(raw + bytes(-len(raw) % 8), dtype=np.uint8).copy()
        self._stamp_at = np.asarray(stamps, dtype=np.intp)
        self._xyz_at = np.asarray(xyz, dtype=np.intp)
        self._key = names

    def encode(self, snap: TickSnapshot, rows: list[int]) -> bytes:
        names = tuple(snap.namespaces[r] for r in rows)
        if names != self._key:
            self._lay_out(names)
        _write_stamps_and_poses(self._buf, self._stamp_at, self._xyz_at, snap, np.asarray(rows, dtype=np.intp))
        return self._buf[4 : self._end].tobytes()


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


def transform_elements(stamp_: tuple[int, int], transforms: list[Transform], first: bool) -> bytes:
    """geometry_msgs/msg/TransformStamped elements of a TFMessage, laid out as the first ones of
    the message (the first starting 4 bytes in) or as later ones (8-aligned)."""
    parts = []
    pos = 4 if first else 0
    for parent, child, xyz, quat in transforms:
        blob = _STAMP.pack(*stamp_) + frames_blob(parent, child, pos + 8, 8)
        parts.append(blob + struct.pack("<7d", *xyz, *quat))
        pos = 0  # every element ends with doubles: the next one starts 8-aligned
    return b"".join(parts)


def tf_message(count: int, elements: list[bytes]) -> bytes:
    """A TFMessage of ``count`` transforms from :func:`transform_elements` blobs (the first laid
    out as first)."""
    return b"".join((ENCAPSULATION, _U32.pack(count), *elements))


class ImuCdr:
    """sensor_msgs/msg/Imu in frame ``<ns>/imu_link``, covariances as the Gazebo TurtleBot3 IMU
    (orientation's not filled, angular velocity 4e-8, linear acceleration 2.89e-4 on the diagonal)."""

    def __init__(self) -> None:
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
            blob = self._frames[ns] = frames_blob(f"{ns}/imu_link", None, 8, 8)
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
