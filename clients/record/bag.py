"""A rosbag2 bag (MCAP storage) written through rosbags, for ``fleet-record``.

rosbags writes what ``ros2 bag info``, ``ros2 bag play`` and Foxglove read: a bag directory
with ``metadata.yaml`` and one ``.mcap`` file (profile ``ros2``, one ``ros2msg`` schema per
type, ``cdr`` channels with their offered QoS, a summary with statistics). ``/tf_static`` is
offered transient local, so ``ros2 bag play`` latches it for late subscribers as
robot_state_publisher does.
"""

from __future__ import annotations

import collections
from pathlib import Path
from typing import Any

from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

_ZERO = QosTime(sec=0, nsec=0)


def qos(depth: int, *, transient_local: bool = False) -> Qos:
    return Qos(
        history=QosHistory.KEEP_LAST, depth=depth, reliability=QosReliability.RELIABLE,
        durability=QosDurability.TRANSIENT_LOCAL if transient_local else QosDurability.VOLATILE,
        deadline=_ZERO, lifespan=_ZERO, liveliness=QosLiveliness.AUTOMATIC, liveliness_lease_duration=_ZERO,
        avoid_ros_namespace_conventions=False,
    )  # fmt: skip


class BagExists(FileExistsError):
    """The output path is taken: a recording never overwrites anything."""


class BagWriter:
    """Messages in, a bag out; counts what it wrote per topic."""

    def __init__(self, path: Path) -> None:
        if path.exists():
            raise BagExists(f"{path} already exists: choose another -o (nothing was written)")
        self.path = path
        self.types = get_typestore(Stores.ROS2_JAZZY)
        self._writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
        self._writer.open()
        self._connections: dict[str, Any] = {}
        self.counts: collections.Counter[str] = collections.Counter()
        self.first_ns: int | None = None
        self.last_ns: int | None = None

    def make(self, typename: str, **fields: Any) -> Any:
        return self.types.types[typename](**fields)

    def write(self, topic: str, typename: str, stamp_ns: int, message: Any, *, latched: bool = False) -> None:
        """Serialize ``message`` (a rosbags message of ``typename``) into ``topic`` at ``stamp_ns``."""
        self.write_cdr(topic, typename, stamp_ns, bytes(self.types.serialize_cdr(message, typename)), latched=latched)

    def write_cdr(self, topic: str, typename: str, stamp_ns: int, data: bytes, *, latched: bool = False) -> None:
        """Write a message already in CDR (as it came over rmw_zenoh)."""
        conn = self._connections.get(topic)
        if conn is None:
            profile = qos(1 if latched else 10, transient_local=latched)
            conn = self._connections[topic] = self._writer.add_connection(
                topic, typename, typestore=self.types, offered_qos_profiles=[profile]
            )
        self._writer.write(conn, stamp_ns, data)
        self.counts[topic] += 1
        self.first_ns = stamp_ns if self.first_ns is None else min(self.first_ns, stamp_ns)
        self.last_ns = stamp_ns if self.last_ns is None else max(self.last_ns, stamp_ns)

    def close(self) -> None:
        self._writer.close()

    def size_bytes(self) -> int:
        return sum(f.stat().st_size for f in self.path.iterdir() if f.is_file())
