"""``/<ns>/cmd_vel`` from ROS: Twist (teleop_twist_keyboard, Humble's teleop) and TwistStamped
(Jazzy's TurtleBot3 teleop, ``stamped:=true``, Nav2 from Kilted on), for every robot through one
subscriber.

A ROS publisher puts on ``<domain>/<ns>/cmd_vel/<dds type>/<hash>``; the wildcard
``<domain>/*/cmd_vel/*/*`` takes both types and both kinds of hash chunk (a hash, Humble's
constant), and the type chunk picks the decoder. So a command of either type drives, whichever
type the robot's subscription advertises (one, the distro's default or ``--ros-cmd-vel``'s, so
that tools which infer the topic's type find one: robot_ports.py): data reaches a subscriber by
its key alone, the graph's tokens only tell tools what is there. A command from an older
rmw_zenoh (its attachment in the old format, attachment.py) drives the robot too, and the log
says once that its sender cannot read the daemon's topics.

Commands go to the engine like the fleet protocol's, with the same limits and watchdog.
Anything else (another type, bad CDR, a velocity that is not finite, a robot that does not
exist) is counted and logged once per kind: the world never changes for it.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

import zenoh

from simd.adapters.ros2.cdr import CdrError, decode_twist, decode_twist_stamped
from simd.adapters.ros2.interfaces import HUMBLE_HASH, dds_type_name, rihs01
from simd.adapters.ros2.robot_ports import CMD_VEL_TYPES, Participant

log = logging.getLogger(__name__)

#: The largest cmd_vel payload looked at (a TwistStamped with a long frame id is ~100 bytes).
MAX_CMD_BYTES = 4096


class RosCommandIntake:
    """The newest (linear x, angular z) per namespace, taken by the engine every tick."""

    def __init__(self, p: Participant, known: Callable[[str], bool]) -> None:
        self._known = known
        self._legacy = p.legacy
        decoders = (decode_twist, decode_twist_stamped)
        self._decoders: dict[tuple[str, str], Callable[[bytes], tuple[float, float]]] = {}
        for typename, decoder in zip(CMD_VEL_TYPES, decoders, strict=True):
            for h in (rihs01(typename), HUMBLE_HASH):
                self._decoders[(dds_type_name(typename), h)] = decoder
        self._lock = threading.Lock()
        self._latest: dict[str, tuple[float, float]] = {}
        self.dropped = 0
        self._reported: set[str] = set()
        self._sub = p.session.declare_subscriber(f"{p.domain}/*/cmd_vel/*/*", self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        chunks = str(sample.key_expr).split("/")
        namespace, type_chunk, hash_chunk = chunks[1], chunks[3], chunks[4]
        decoder = self._decoders.get((type_chunk, hash_chunk))
        if decoder is None:
            return self._drop("type", f"cmd_vel of type {type_chunk} / {hash_chunk} ignored (Twist or TwistStamped)")
        self._legacy.check(sample.attachment, f"/{namespace}/cmd_vel")
        payload = sample.payload.to_bytes()
        if len(payload) > MAX_CMD_BYTES:
            return self._drop("size", f"cmd_vel of {len(payload)} bytes ignored")
        try:
            command = decoder(payload)
        except CdrError as e:
            return self._drop("cdr", f"cmd_vel for {namespace!r} ignored: {e}")
        if not self._known(namespace):
            return self._drop("robot", f"cmd_vel for {namespace!r} ignored: no such robot")
        with self._lock:
            self._latest[namespace] = command

    def _drop(self, kind: str, message: str) -> None:
        with self._lock:
            self.dropped += 1
            first = kind not in self._reported
            self._reported.add(kind)
        if first:
            log.warning("%s (further ones of this kind are only counted)", message)

    def take(self) -> dict[str, tuple[float, float]]:
        with self._lock:
            latest, self._latest = self._latest, {}
        return latest

    def close(self) -> None:
        try:
            self._sub.undeclare()
        except zenoh.ZError:
            pass
