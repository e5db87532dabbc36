"""cmd_vel in: the newest command per namespace, whatever arrives on ``P/*/cmd_vel`` or, many
robots' at once, on ``P/commands``.

Samples wait in a zenoh ring channel that the simulation thread drains between ticks: no
Python callback thread wakes up per command (at 1 000 robots driven at 10 Hz that thread
fought the simulation for the GIL 10 000 times a second), and a flood only overwrites the
oldest samples, never blocking zenoh. Every sample is hostile until decoded: a body that
does not decode as a Twist (too large, too deep, not UTF-8, wrong types), a non-finite
number or a key that is not ``P/<ns>/cmd_vel`` is dropped and counted, and logged at most
once per ``LOG_EVERY_SECONDS`` with the count, so a flood of garbage cannot flood the log.

Behind a router the commands come in on a zenoh session of their own
(:func:`command_session_needed`): a command reaches a router's client under its full key, and
the client's zenoh matches that key against every resource its session knows, once per
sample. The daemon's own session knows every robot's liveliness token (its own and, in a shared
fleet, everybody's): at 4 000 robots driven at 2 Hz that matching took a core, and the
daemon's answers queued behind the commands on the same link for seconds (its clock query
went unanswered). A session that holds only the cmd_vel subscriber matches against almost
nothing: the same load costs the daemon a few percent and its clock is answered in ms.

``P/commands`` carries many robots' commands in one message (``PackedCommands``: namespaces and
a float64 row of (linear.x, angular.z) each, as a step's ``commands``). A program driving
thousands of robots at 10 Hz otherwise declares a publisher per robot and puts tens of thousands
of samples a second: in Python that is a core of its own, the daemon decodes each sample, and
zenoh matches every publisher declared under ``P/`` against every robot's keys (10 000 of them
kept the daemon's receiving thread busy for ~30 s after such a driver started). A batch is
applied whole or not at all: one that does not decode, whose ``twist`` is not 16 bytes a name,
that names a robot twice or holds a number that is not finite is dropped and counted, like a
bad ``cmd_vel``; names of no robot here are ignored (another daemon of a shared fleet has them).
Within one drain the batches come after the single commands, so a robot commanded both ways in
one tick takes the batch's.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable

import msgspec
import zenoh

from protocol.codec import MAX_PAYLOAD_BYTES, decode
from protocol.control import PackedCommands
from protocol.errors import FleetError
from protocol.keys import Keys
from protocol.messages import Twist

log = logging.getLogger(__name__)

#: cmd_vel samples buffered between two drains (a 30 Hz tick); beyond it the oldest go.
CMD_VEL_RING = 65536
#: ``P/commands`` batches buffered between two drains; beyond it the oldest go. Many, so that a
#: driver that splits its fleet over several batches a tick loses none while ticks are slow.
COMMANDS_RING = 64
#: A Twist is ~100 bytes; anything much larger is not one.
MAX_TWIST_BYTES = 64 << 10
#: cmd_vel keys whose namespaces are kept (parsed once); beyond it the table starts again.
MAX_KEYS_KEPT = 1 << 17
#: Dropped commands are logged at most this often (with the count since the last line).
LOG_EVERY_SECONDS = 5.0


def command_session_needed(mode: str) -> bool:
    """Whether cmd_vel should come in on a session of its own: when the daemon is a router's
    client (a peer is reached directly by its clients, under keys it declared, and a second
    peer session would need a port of its own)."""
    return mode == "client"


class CommandIntake:
    """The cmd_vel and batch subscribers and the newest-command-per-namespace table."""

    def __init__(self, session: zenoh.Session, keys: Keys, clock: Callable[[], float] = time.monotonic) -> None:
        self.keys = keys
        self.dropped = 0
        self._commands: dict[str, tuple[float, float]] = {}
        self._msgpack = msgspec.msgpack.Decoder(Twist)
        self._clock = clock
        self._logged_at = -math.inf
        self._unlogged = 0
        self._last_reason = ""
        self._ns_of: dict[str, str | None] = {}  # cmd_vel key -> its namespace (None: not a robot's)
        self._packed = msgspec.msgpack.Decoder(PackedCommands)
        self._sub = session.declare_subscriber(keys.cmd_vel("*"), zenoh.handlers.RingChannel(CMD_VEL_RING))
        self._batches = session.declare_subscriber(keys.commands(), zenoh.handlers.RingChannel(COMMANDS_RING))

    def _twist(self, payload: bytes) -> tuple[float, float]:
        """(linear x, angular z) of a Twist body; raises on anything else."""
        if len(payload) > MAX_TWIST_BYTES:
            raise ValueError(f"{len(payload)} bytes is no Twist (limit {MAX_TWIST_BYTES})")
        if payload[:1] and payload[0] in b" \t\r\n{":  # JSON from people and their tools
            twist = decode(payload, Twist, max_bytes=MAX_TWIST_BYTES)
        else:  # MessagePack from programs: the fast path
            twist = self._msgpack.decode(payload)
        v, w = float(twist.linear.x), float(twist.angular.z)
        if not (math.isfinite(v) and math.isfinite(w)):
            raise ValueError("linear.x and angular.z must be finite")
        return v, w

    def _batch(self, payload: bytes) -> tuple[list[str], list[float], list[float]]:
        """(namespaces, linear x, angular z) of a ``P/commands`` body; raises on anything else."""
        if len(payload) > MAX_PAYLOAD_BYTES:
            raise ValueError(f"{len(payload)} bytes is more than a batch may hold ({MAX_PAYLOAD_BYTES})")
        if payload[:1] and payload[0] in b" \t\r\n{":
            batch = decode(payload, PackedCommands, max_bytes=MAX_PAYLOAD_BYTES)
        else:
            batch = self._packed.decode(payload)
        names, values = batch.names, batch.rows()  # 16 bytes a name, all finite: as a step takes them
        if len(set(names)) != len(names):
            seen: set[str] = set()
            twice = next(n for n in names if n in seen or seen.add(n))  # type: ignore[func-returns-value]
            raise ValueError(f"{twice!r} is named more than once")
        return names, values[:, 0].tolist(), values[:, 1].tolist()

    def poll(self, most: int | None = None) -> bool:
        """Move waiting samples into the table (simulation thread), at most ``most`` of them;
        whether that many were moved (more may wait)."""
        sub = self._sub
        commands = self._commands
        ns_of = self._ns_of
        left = -1 if most is None else most
        while left and (sample := sub.try_recv()) is not None:
            left -= 1
            key = str(sample.key_expr)
            if key in ns_of:  # parsed once per key: 8 000 robots at 10 Hz are 80 000 samples a second
                ns = ns_of[key]
            else:
                if len(ns_of) >= MAX_KEYS_KEPT:
                    ns_of.clear()
                ns = ns_of[key] = self.keys.namespace_of(key)
            try:
                if ns is None or "*" in ns or "$" in ns:
                    raise ValueError(f"{key!r} names no single robot")
                commands[ns] = self._twist(sample.payload.to_bytes())
            except (FleetError, ValueError, RecursionError, msgspec.MsgspecError) as e:
                self._drop(key, str(e))
            except Exception as e:  # whatever hostile bytes provoke, they never stop the tick
                self._drop(key, f"{type(e).__name__}: {e}")
        while left and (sample := self._batches.try_recv()) is not None:
            left -= 1
            try:
                names, v, w = self._batch(sample.payload.to_bytes())
                commands.update(zip(names, zip(v, w, strict=True), strict=True))
            except (FleetError, ValueError, RecursionError, msgspec.MsgspecError) as e:
                self._drop(str(sample.key_expr), str(e))
            except Exception as e:
                self._drop(str(sample.key_expr), f"{type(e).__name__}: {e}")
        return left == 0

    def _drop(self, key: str, reason: str) -> None:
        self.dropped += 1
        self._unlogged += 1
        self._last_reason = f"{key}: {reason}"[:300]
        now = self._clock()
        if now - self._logged_at >= LOG_EVERY_SECONDS:
            log.warning(
                "dropped %d cmd_vel message(s) that did not decode (%d in all); the last: %s",
                self._unlogged, self.dropped, self._last_reason,
            )  # fmt: skip
            self._logged_at = now
            self._unlogged = 0

    def take(self) -> dict[str, tuple[float, float]]:
        """The newest command per namespace since the last call (simulation thread)."""
        self.poll()
        cmds, self._commands = self._commands, {}
        return cmds

    def close(self) -> None:
        for sub in (self._sub, self._batches):
            try:
                sub.undeclare()
            except zenoh.ZError:
                pass
