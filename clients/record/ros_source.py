"""Recording ROS 2 topics straight off rmw_zenoh's wire, as ``ros2 bag record`` would, without ROS.

The graph is read from liveliness tokens (``@ros2_lv/<domain>/...``): every publisher token
names its topic, its DDS type and its type hash, which together are the key its samples are
put on. The recorder subscribes on exactly those keys (``/tf_static`` with history, so the
fixed frames already sent are recorded too) and keeps the CDR payloads as they came, so the
bag holds the same bytes a ROS subscriber received. A robot spawned while recording is picked
up when its tokens appear.
"""

from __future__ import annotations

import json
import struct
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import zenoh
import zenoh.ext

#: what fleet-record can take from ROS, by the topic's last name (per robot) or whole name
ROBOT_TOPICS = ("odom", "scan", "imu", "joint_states")
FLEET_TOPICS = ("tf", "tf_static", "clock")
#: the transform topics, recorded both as the fleet's (``/tf``) and as each robot's own
#: (``/<ns>/tf``, what ``simd --ros-tf namespaced`` publishes: Nav2's multi-robot layout)
TF_TOPICS = ("tf", "tf_static")

#: topic, ROS type, sim-time stamp (ns), CDR payload, latched
Sink = Callable[[str, str, int, bytes, bool], None]


@dataclass(frozen=True)
class Publication:
    topic: str  # /TB3_1/odom
    typename: str  # nav_msgs/msg/Odometry
    key: str  # the data key its samples are put on


def parse_publisher_token(token: str) -> Publication | None:
    """A publisher's token (``MP``) as what to subscribe to; None for anything else."""
    parts = token.split("/")
    if len(parts) < 13 or parts[0] != "@ros2_lv" or parts[5] != "MP":
        return None
    domain, topic, dds, hash_ = parts[1], parts[9].replace("%", "/"), parts[10], parts[11]
    pkg, _, rest = dds.partition("::")
    kind, _, rest = rest.partition("::dds_::")
    if not (pkg and kind and rest.endswith("_")):
        return None
    typename = f"{pkg}/{kind}/{rest[:-1]}"
    return Publication(topic, typename, f"{domain}/{topic.strip('/')}/{dds}/{hash_}")


def stamp_of(typename: str, data: bytes) -> int | None:
    """The sim-time stamp (ns) in a message's first header (or Clock's time); None if it has none."""
    offset = {"tf2_msgs/msg/TFMessage": 8}.get(typename, 4)  # a TFMessage's first transform follows its count
    if len(data) < offset + 8 or data[1] != 1:  # little-endian CDR only (what rmw_zenoh on x86 and ARM sends)
        return None
    if typename == "tf2_msgs/msg/TFMessage" and struct.unpack_from("<I", data, 4)[0] == 0:
        return None
    sec, nsec = struct.unpack_from("<iI", data, offset)
    return int(sec) * 1_000_000_000 + int(nsec)


class RosSource:
    """Subscribes to the wanted publications of one domain and hands each sample to ``sink``."""

    def __init__(self, session: zenoh.Session, domain: int, wanted: Callable[[str], bool], sink: Sink) -> None:
        self._session = session
        self._domain = domain
        self._wanted = wanted
        self._sink = sink
        self._lock = threading.Lock()
        self._keys: set[str] = set()
        self._entities: list[Any] = []
        self.latest_stamp = 0
        self._tokens = session.liveliness().declare_subscriber(f"@ros2_lv/{domain}/**", self._on_token, history=True)

    def _on_token(self, sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.PUT:
            return
        pub = parse_publisher_token(str(sample.key_expr))
        if pub is None or not self._wanted(pub.topic):
            return
        with self._lock:
            if pub.key in self._keys:
                return
            self._keys.add(pub.key)
        latched = pub.topic.rsplit("/", 1)[-1] == "tf_static"

        def on_sample(s: zenoh.Sample) -> None:
            data = s.payload.to_bytes()
            stamp = stamp_of(pub.typename, data)
            if stamp is None or (latched and stamp == 0):
                stamp = self.latest_stamp  # the fixed frames (stamped zero) go in at the current time
            else:
                self.latest_stamp = max(self.latest_stamp, stamp)
            self._sink(pub.topic, pub.typename, stamp, data, latched)

        entity: Any
        if latched:  # as a transient-local subscription: what the publishers' caches hold, then live
            entity = zenoh.ext.declare_advanced_subscriber(
                self._session,
                pub.key,
                on_sample,
                history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1),
            )
        else:
            entity = self._session.declare_subscriber(pub.key, on_sample)
        with self._lock:
            self._entities.append(entity)

    def close(self) -> None:
        with self._lock:
            entities, self._entities = [self._tokens, *self._entities], []
        for e in entities:
            try:
                e.undeclare()
            except zenoh.ZError:
                pass


def ros_session(router: str, timeout: float) -> zenoh.Session:
    """A peer on the ROS domain's router, as rmw_zenoh's processes are; raises zenoh.ZError
    when the router does not answer within ``timeout`` seconds."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", json.dumps([router]))
    conf.insert_json5("connect/timeout_ms", str(int(timeout * 1000)))
    conf.insert_json5("connect/exit_on_failure", "true")
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf)


def topic_filter(topics: set[str], robots: set[str] | None) -> Callable[[str], bool]:
    """Which ROS topic names to record: ``/<ns>/<t>`` for the robot topics asked (of the
    robots asked), ``/tf``, ``/tf_static``, ``/clock`` when asked, and ``/<ns>/tf`` and
    ``/<ns>/tf_static`` (of the robots asked) with ``tf`` and ``tf_static``."""

    def wanted(topic: str) -> bool:
        parts = topic.strip("/").split("/")
        if len(parts) == 1:
            return parts[0] in topics and parts[0] in FLEET_TOPICS
        if len(parts) == 2:
            ns, name = parts
            per_robot = name in ROBOT_TOPICS or name in TF_TOPICS
            return name in topics and per_robot and (robots is None or ns in robots)
        return False

    return wanted
