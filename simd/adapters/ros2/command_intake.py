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

Commands go to the engine like the fleet protocol's, with the same limits and watchdog, and come
in the same way (simd/adapters/fleet/commands.py): samples wait in a zenoh ring channel that the
simulation thread drains once a tick, and are decoded there, at the edge. No Python callback
wakes up per command to fight the simulation for the GIL, and a flood only overwrites the oldest
samples. Anything else (another type, bad CDR, a velocity that is not finite, a robot that does
not exist) is counted and logged once per kind: the world never changes for it.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import zenoh

from simd.adapters.ros2.cdr import CdrError, decode_twist, decode_twist_stamped
from simd.adapters.ros2.interfaces import HUMBLE_HASH, dds_type_name, rihs01
from simd.adapters.ros2.robot_ports import CMD_VEL_TYPES, Participant
from simd.adapters.zenoh_entities import undeclare_all

log = logging.getLogger(__name__)

#: The largest cmd_vel payload looked at (a TwistStamped with a long frame id is ~100 bytes).
MAX_CMD_BYTES = 4096
#: cmd_vel samples buffered between two drains (a 30 Hz tick); beyond it the oldest go.
CMD_VEL_RING = 65536


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
        self.dropped = 0
        self._reported: set[str] = set()
        self._sub = p.session.declare_subscriber(f"{p.domain}/*/cmd_vel/*/*", zenoh.handlers.RingChannel(CMD_VEL_RING))

    def _command(self, sample: zenoh.Sample) -> tuple[str, tuple[float, float]] | None:
        """The namespace and command of a sample; None (counted) for anything else."""
        chunks = str(sample.key_expr).split("/")
        namespace, type_chunk, hash_chunk = chunks[1], chunks[3], chunks[4]
        decoder = self._decoders.get((type_chunk, hash_chunk))
        if decoder is None:
            self._drop("type", f"cmd_vel of type {type_chunk} / {hash_chunk} ignored (Twist or TwistStamped)")
            return None
        self._legacy.check(sample.attachment, f"/{namespace}/cmd_vel")
        payload = sample.payload.to_bytes()
        if len(payload) > MAX_CMD_BYTES:
            self._drop("size", f"cmd_vel of {len(payload)} bytes ignored")
            return None
        try:
            command = decoder(payload)
        except CdrError as e:
            self._drop("cdr", f"cmd_vel for {namespace!r} ignored: {e}")
            return None
        except Exception as e:  # whatever hostile bytes provoke, they never stop the tick
            self._drop("cdr", f"cmd_vel for {namespace!r} ignored: {type(e).__name__}: {e}")
            return None
        if not self._known(namespace):
            self._drop("robot", f"cmd_vel for {namespace!r} ignored: no such robot")
            return None
        return namespace, command

    def _drop(self, kind: str, message: str) -> None:
        self.dropped += 1
        if kind not in self._reported:
            self._reported.add(kind)
            log.warning("%s (further ones of this kind are only counted)", message)

    def take(self) -> dict[str, tuple[float, float]]:
        """The newest command per namespace since the last call (simulation thread)."""
        latest: dict[str, tuple[float, float]] = {}
        sub = self._sub
        while (sample := sub.try_recv()) is not None:
            taken = self._command(sample)
            if taken is not None:
                latest[taken[0]] = taken[1]
        return latest

    def close(self) -> None:
        undeclare_all([self._sub])
