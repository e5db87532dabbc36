"""CDR of tf2_msgs/msg/TFMessage: the fleet's ``/tf`` each tick, each robot's ``/<ns>/tf``, static frames.

The dynamic transforms go out every tick, for a thousand robots, so they are laid out as the
other hot messages are (cdr.py): once for a set of robots, a tick writing only the stamps and
the numbers with numpy. Two layouts:

- :class:`FleetTfCdr`: one message with every robot's transforms (``/tf``, frames prefixed by
  the namespace: the fleet's one tree);
- :class:`RobotTfCdr`: one message per robot (``/<ns>/tf``, Nav2's multi-robot layout). Its
  frames carry no prefix, so every robot's message has the same layout: one template, repeated.

Which transforms a robot has (``odom`` -> ``base_footprint``, and ``map`` -> ``odom`` when the
daemon localises) is the caller's; each comes with a column of planar poses per tick.
:func:`map_to_odom` gives the one that takes a drifting odometry onto the true pose.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence

import numpy as np
import numpy.typing as npt

from fleetcommon.arrays import F64
from protocol.frames import Transform
from simd.adapters.ros2.cdr import ENCAPSULATION, frames_blob, stamp, write_poses, write_stamps

#: (parent, child) of a transform
Frames = tuple[str, str]
#: the x, y and yaw columns of one transform of every robot of a tick
PoseColumns = tuple[F64, F64, F64]

_STAMP = struct.Struct("<iI")
_U32 = struct.Struct("<I")
#: the bytes of a transform after its frames: translation and rotation, seven doubles
_NUMBERS = 56


def map_to_odom(odom: PoseColumns, truth: PoseColumns) -> PoseColumns:
    """``map`` -> ``odom`` such that ``map`` -> ``odom`` -> ``base_footprint`` is the true pose:
    truth ∘ odom⁻¹ in the plane (identity while the odometry is exact), as a perfect AMCL's."""
    ox, oy, oyaw = odom
    tx, ty, tyaw = truth
    yaw = np.arctan2(np.sin(tyaw - oyaw), np.cos(tyaw - oyaw))
    c, s = np.cos(yaw), np.sin(yaw)
    return tx - (c * ox - s * oy), ty - (s * ox + c * oy), yaw


def _elements(frames: Sequence[Frames], pos: int) -> tuple[bytes, list[int], list[int]]:
    """Zeroed TransformStamped elements from payload offset ``pos`` (4 for the first of a
    message, after its count): their bytes, and each one's payload offset of its stamp and of
    its numbers (8-aligned)."""
    parts: list[bytes] = []
    stamps, numbers = [], []
    for parent, child in frames:
        blob = frames_blob(parent, child, pos + 8, 8)
        stamps.append(pos)
        numbers.append(pos + 8 + len(blob))
        parts += (bytes(8), blob, bytes(_NUMBERS))
        pos += 8 + len(blob) + _NUMBERS
    return b"".join(parts), stamps, numbers


class FleetTfCdr:
    """One TFMessage with the transforms ``frames(ns)`` of every robot, robot after robot.

    Laid out once for a set of robots: the first transform starts 4 bytes into the payload
    (after the count), every later one 8-aligned (each ends with doubles); a tick writes the
    stamps and numbers with numpy.
    """

    def __init__(self, frames: Callable[[str], list[Frames]]) -> None:
        self._frames = frames
        self._key: tuple[str, ...] = ()
        self._buf = np.zeros(0, np.uint8)
        self._stamp_at = np.zeros(0, np.intp)
        self._pose_at: list[npt.NDArray[np.intp]] = []  # per kind of transform, one index per robot
        self._end = 0

    def forget(self, ns: str) -> None:
        self._key = ()

    def _lay_out(self, names: tuple[str, ...]) -> None:
        kinds = len(self._frames(names[0])) if names else 0
        parts = [bytes(4), ENCAPSULATION, _U32.pack(len(names) * kinds)]  # 4 bytes: the payload 8-aligned
        stamps: list[int] = []
        poses: list[list[int]] = [[] for _ in range(kinds)]
        pos = 4  # payload offset
        for ns in names:
            blob, at, numbers = _elements(self._frames(ns), pos)
            stamps += at
            for k, n in enumerate(numbers):
                poses[k].append(n)
            parts.append(blob)
            pos += len(blob)
        raw = b"".join(parts)
        self._end = len(raw)
        self._buf = np.frombuffer(raw + bytes(-len(raw) % 8), dtype=np.uint8).copy()
        self._stamp_at = (np.asarray(stamps, dtype=np.intp) + 8) // 4  # buffer offset: 4 + the header
        self._pose_at = [(np.asarray(p, dtype=np.intp) + 8) // 8 for p in poses]
        self._key = names

    def encode(self, t: float, names: tuple[str, ...], poses: Sequence[PoseColumns]) -> bytes:
        """The message at sim time ``t`` for robots ``names``; ``poses[k]`` holds the k-th
        transform of each (columns in ``names`` order)."""
        if names != self._key:
            self._lay_out(names)
        write_stamps(self._buf, self._stamp_at, t)
        f64 = self._buf.view(np.float64)
        for at, (x, y, yaw) in zip(self._pose_at, poses, strict=True):
            write_poses(f64, at, x, y, yaw)
        return self._buf[4 : self._end].tobytes()


class RobotTfCdr:
    """One TFMessage per robot, all with the same ``frames`` (unprefixed): one template laid out
    again and again in one buffer, each copy's payload 8-aligned, a tick writing every copy's
    stamps and numbers at once."""

    def __init__(self, frames: list[Frames]) -> None:
        blob, stamps, numbers = _elements(frames, 4)
        message = ENCAPSULATION + _U32.pack(len(frames)) + blob
        self._length = len(message)
        self._stride = 4 + self._length + (-(4 + self._length) % 8)  # 4 bytes before each: payloads 8-aligned
        self._row = bytes(4) + message + bytes(self._stride - 4 - self._length)
        self._stamps = np.asarray(stamps, dtype=np.intp)  # payload offsets within one message
        self._numbers = [int(n) for n in numbers]
        self._count = -1
        self._buf = np.zeros(0, np.uint8)
        self._stamp_at = np.zeros(0, np.intp)
        self._pose_at: list[npt.NDArray[np.intp]] = []

    def _lay_out(self, count: int) -> None:
        self._buf = np.frombuffer(self._row * count, dtype=np.uint8).copy()
        starts = np.arange(count, dtype=np.intp) * self._stride + 8  # each copy's payload in the buffer
        self._stamp_at = ((starts[:, None] + self._stamps[None, :]) // 4).ravel()
        self._pose_at = [(starts + n) // 8 for n in self._numbers]
        self._count = count

    def encode(self, t: float, poses: Sequence[PoseColumns]) -> list[bytes]:
        """One message per robot at sim time ``t``; ``poses[k]`` holds the k-th transform of
        each robot (all columns of one length)."""
        count = len(poses[0][0]) if poses else 0
        if count == 0:
            return []
        if count != self._count:
            self._lay_out(count)
        write_stamps(self._buf, self._stamp_at, t)
        f64 = self._buf.view(np.float64)
        for at, (x, y, yaw) in zip(self._pose_at, poses, strict=True):
            write_poses(f64, at, x, y, yaw)
        data = self._buf.tobytes()
        stride, length = self._stride, self._length
        return [data[i * stride + 4 : i * stride + 4 + length] for i in range(count)]


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


def static_message(transforms: list[Transform], t: float = 0.0) -> bytes:
    """A TFMessage of fixed transforms stamped at sim time ``t``."""
    return tf_message(len(transforms), [transform_elements(stamp(t), transforms, first=True)])
