"""The network layer: maps the core to the wire protocol over one zenoh session.

Zenoh callbacks never touch the simulation. cmd_vel samples wait in a zenoh ring channel
that the simulation thread drains between ticks, keeping the newest command per namespace:
no Python callback thread wakes up per command (at 1 000 robots driven at 10 Hz that thread
fought the simulation for the GIL 10 000 times a second), and a flood only overwrites the
oldest samples, never blocking zenoh. Control queries are put on a bounded queue that the
simulation thread drains; it replies from there. A flood beyond the queue's bound is
answered ``busy`` from the callback without reaching the simulation.
"""

from __future__ import annotations

import logging
import math
import queue
from dataclasses import dataclass
from typing import Any

import msgspec
import zenoh

from protocol.codec import Format, decode, encode, media_type, sniff_format
from protocol.errors import ErrorCode, FleetError
from protocol.keys import Keys
from protocol.messages import Twist

log = logging.getLogger(__name__)

#: Control requests waiting for the simulation thread beyond this are refused as busy.
MAX_PENDING_REQUESTS = 4096
#: cmd_vel samples buffered between two drains (a 30 Hz tick); beyond it the oldest go.
CMD_VEL_RING = 65536

CONTROL_KINDS = ("spawn", "delete", "robots", "world", "clock", "pause", "resume", "reset", "step")


@dataclass
class Request:
    kind: str
    query: zenoh.Query
    payload: bytes
    fmt: Format


def reply_format(query: zenoh.Query, payload: bytes) -> Format:
    """JSON or MessagePack for the reply: ``?format=`` wins, then the request's own
    encoding; an empty request gets JSON, which zenoh's CLI prints as it is."""
    wanted = query.parameters.get("format")
    if wanted in ("json", "msgpack"):
        return wanted  # type: ignore[return-value]
    enc = str(query.encoding) if query.encoding is not None else ""
    if enc.startswith("application/msgpack"):
        return "msgpack"
    if not payload:
        return "json"
    return sniff_format(payload)


def reply_ok(req: Request, key: str, obj: Any) -> None:
    req.query.reply(key, encode(obj, req.fmt), encoding=media_type(req.fmt))


def reply_error(req: Request, err: FleetError) -> None:
    req.query.reply_err(encode(err.to_reply(), req.fmt), encoding=media_type(req.fmt))


def to_json(topic: str, msgpack_payload: bytes) -> bytes:
    """A published message as JSON for people; a scan's ranges become a list (null = inf)."""
    from protocol.messages import LaserScan, Odometry

    if topic == "scan":
        scan = msgspec.msgpack.decode(msgpack_payload, type=LaserScan)
        d = msgspec.structs.asdict(scan)
        d["ranges"] = [None if not math.isfinite(r) else round(r, 4) for r in scan.ranges_array().tolist()]
        d["intensities"] = scan.intensities_array().tolist()
        return msgspec.json.encode(d)
    return msgspec.json.encode(msgspec.msgpack.decode(msgpack_payload, type=Odometry))


class Bridge:
    """Declares the daemon's zenoh entities and moves data across the thread boundary."""

    def __init__(self, session: zenoh.Session, keys: Keys) -> None:
        self.session = session
        self.keys = keys
        self.requests: queue.Queue[Request | None] = queue.Queue(MAX_PENDING_REQUESTS)
        self._commands: dict[str, tuple[float, float]] = {}
        self.dropped_commands = 0
        self._twist = msgspec.msgpack.Decoder(Twist)
        self._odom_pub: dict[str, zenoh.Publisher] = {}
        # the put methods of the odometry publishers in the order of the last tick's namespaces:
        # looked up once per fleet change instead of once per robot per tick
        self._odom_puts: tuple[list[str], list[Any]] = ([], [])
        self._scan_pub: dict[str, zenoh.Publisher] = {}
        self._tokens: dict[str, zenoh.LivelinessToken] = {}
        self.latest_odom: dict[str, bytes] = {}
        self.latest_scan: dict[str, bytes] = {}
        self._entities: list[Any] = []
        k = keys
        control_keys = {
            "spawn": k.spawn, "delete": k.delete, "robots": k.robots, "world": k.world,
            "clock": k.clock, "pause": k.pause, "resume": k.resume, "reset": k.reset,
            "step": k.step,
        }  # fmt: skip
        self.control_keys = control_keys
        for kind, key in control_keys.items():
            self._entities.append(session.declare_queryable(key, self._make_enqueue(kind)))
        self._cmd_vel = session.declare_subscriber(f"{k.prefix}/*/cmd_vel", zenoh.handlers.RingChannel(CMD_VEL_RING))
        self._entities.append(self._cmd_vel)
        self._entities.append(
            session.declare_queryable(f"{k.prefix}/*/odom", self._latest_answerer(self.latest_odom, "odom"))
        )
        self._entities.append(
            session.declare_queryable(f"{k.prefix}/*/scan", self._latest_answerer(self.latest_scan, "scan"))
        )
        self.clock_pub = session.declare_publisher(k.clock, encoding="application/msgpack")
        # The fleet topics (one message a tick for the whole fleet) are built only while their
        # publisher has a match, like the JSON mirrors below; scans at the scans' priority.
        self.fleet_odom_pub = session.declare_publisher(k.fleet_odom, encoding="application/msgpack")
        self.fleet_scan_pub = session.declare_publisher(
            k.fleet_scan, encoding="application/msgpack", priority=zenoh.Priority.DATA_LOW
        )
        # JSON mirrors for people with zenoh's CLI (whose subscriber cannot read MessagePack).
        # These wildcard publishers only probe for subscribers: the mirrors cost nothing
        # until somebody subscribes to a P/<ns>/odom/json or P/<ns>/scan/json key.
        self._odom_json_probe = session.declare_publisher(f"{k.prefix}/*/odom/json")
        self._scan_json_probe = session.declare_publisher(f"{k.prefix}/*/scan/json")

    # -- inputs (zenoh threads) -------------------------------------------------------------

    def _make_enqueue(self, kind: str) -> Any:
        def enqueue(query: zenoh.Query) -> None:
            payload = query.payload.to_bytes() if query.payload is not None else b""
            req = Request(kind, query, payload, reply_format(query, payload))
            try:
                self.requests.put_nowait(req)
            except queue.Full:
                reply_error(
                    req,
                    FleetError(ErrorCode.BUSY, "the daemon is busy: too many pending requests; retry"),
                )
                query.drop()

        return enqueue

    def poll_commands(self) -> None:
        """Move waiting cmd_vel samples into the newest-per-namespace table (simulation thread)."""
        sub = self._cmd_vel
        commands = self._commands
        decoder = self._twist
        while (sample := sub.try_recv()) is not None:
            ns = self.keys.namespace_of(str(sample.key_expr))
            if ns is None or "*" in ns or "$" in ns:
                self.dropped_commands += 1
                continue
            payload = sample.payload.to_bytes()
            try:
                # JSON from people and their tools; MessagePack (the fast path) from programs
                json_like = payload[:1] and payload[0] in b" \t\r\n{"
                twist = decode(payload, Twist) if json_like else decoder.decode(payload)
                v, w = float(twist.linear.x), float(twist.angular.z)
            except (FleetError, msgspec.DecodeError, TypeError, ValueError):
                self.dropped_commands += 1
                continue
            if not (math.isfinite(v) and math.isfinite(w)):
                self.dropped_commands += 1
                continue
            commands[ns] = (v, w)

    def take_commands(self) -> dict[str, tuple[float, float]]:
        """The newest command per namespace since the last call (simulation thread)."""
        self.poll_commands()
        cmds, self._commands = self._commands, {}
        return cmds

    def _latest_answerer(self, cache: dict[str, bytes], topic: str) -> Any:
        def answer(query: zenoh.Query) -> None:
            with query:
                fmt: Format = "json" if query.parameters.get("format") == "json" else "msgpack"
                for ns, data in list(cache.items()):
                    key = f"{self.keys.prefix}/{ns}/{topic}"
                    if query.key_expr.intersects(zenoh.KeyExpr(key)):
                        body = data if fmt == "msgpack" else to_json(topic, data)
                        query.reply(key, body, encoding=media_type(fmt))

        return answer

    # -- outputs (simulation thread) --------------------------------------------------------

    def add_robot(self, ns: str) -> None:
        k = self.keys
        self._odom_pub[ns] = self.session.declare_publisher(k.odom(ns), encoding="application/msgpack")
        # Scans travel at DATA_LOW: zenoh gives each priority its own transmit queue, so a tick's
        # scans and its odometry each get a full queue, and odometry goes first when a link is
        # congested (it is what closes a control loop).
        self._scan_pub[ns] = self.session.declare_publisher(
            k.scan(ns), encoding="application/msgpack", priority=zenoh.Priority.DATA_LOW
        )
        self._tokens[ns] = self.session.liveliness().declare_token(k.alive(ns))
        self._odom_puts = ([], [])

    def remove_robot(self, ns: str) -> None:
        for table in (self._odom_pub, self._scan_pub):
            pub = table.pop(ns, None)
            if pub is not None:
                pub.undeclare()
        tok = self._tokens.pop(ns, None)
        if tok is not None:
            tok.undeclare()
        self.latest_odom.pop(ns, None)
        self.latest_scan.pop(ns, None)
        self._odom_puts = ([], [])

    def wants_fleet_odom(self) -> bool:
        """True while somebody subscribes to ``P/odometry``."""
        return bool(self.fleet_odom_pub.matching_status.matching)  # type: ignore[attr-defined]  # stub says bool

    def wants_fleet_scan(self) -> bool:
        """True while somebody subscribes to ``P/scans``."""
        return bool(self.fleet_scan_pub.matching_status.matching)  # type: ignore[attr-defined]

    def publish(
        self,
        namespaces: list[str],
        odom: list[bytes],
        scan_namespaces: list[str],
        scans: list[bytes],
    ) -> None:
        """Put one tick's messages back to back (bursts amortise zenoh's wake-ups)."""
        layout, puts = self._odom_puts
        if namespaces != layout:  # cheap when equal: the simulation hands out the same list
            puts = [self._odom_pub[ns].put for ns in namespaces]
            self._odom_puts = (list(namespaces), puts)
        for put, data in zip(puts, odom, strict=True):
            put(data)
        spubs = self._scan_pub
        for ns, data in zip(scan_namespaces, scans, strict=True):
            spubs[ns].put(data)
        self.latest_odom.update(zip(namespaces, odom, strict=True))
        self.latest_scan.update(zip(scan_namespaces, scans, strict=True))
        if self._odom_json_probe.matching_status.matching:  # type: ignore[attr-defined]  # stub says bool
            self._mirror("odom", namespaces, odom)
        if scans and self._scan_json_probe.matching_status.matching:  # type: ignore[attr-defined]
            self._mirror("scan", scan_namespaces, scans)

    def _mirror(self, topic: str, namespaces: list[str], payloads: list[bytes]) -> None:
        for ns, data in zip(namespaces, payloads, strict=True):
            self.session.put(
                f"{self.keys.prefix}/{ns}/{topic}/json",
                to_json(topic, data),
                encoding="application/json",
            )

    def close(self) -> None:
        for ent in self._entities:
            try:
                ent.undeclare()
            except zenoh.ZError:
                pass
        self._entities.clear()
