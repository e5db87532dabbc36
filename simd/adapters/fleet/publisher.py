"""Messages out: every robot's odometry and scans, the fleet topics, the clock, JSON mirrors.

One tick's messages are encoded from the snapshot's columns in one pass (simd/wire) and put
back to back, which amortises zenoh's wake-ups. Each robot has declared publishers (a
declared key is routed once, a key string at every put) and a liveliness token.

Nothing is encoded for nobody: a wildcard publisher on ``P/*/odom`` (and one on ``P/*/scan``)
learns from zenoh (a matching listener, see :class:`Interest`) whether anyone subscribes to any
robot's odometry (scans); when nobody does, the per-robot messages are neither encoded nor put,
which is most of a tick's sending work when clients follow the fleet topics instead.
``get P/<ns>/odom`` and ``get P/<ns>/scan`` are answered from the latest snapshot, encoded on
request: the same bytes the topic carries. A get on a robot's exact key is also what a client
starting to follow that robot sends (FleetClient.on_odom, fleet-teleop): its publisher is then
declared by the next tick, ahead of the others (see ``Publisher._robot_puts``).
Everything but those answers runs on one thread at a time (the adapter's), in the engine's order.
"""

from __future__ import annotations

import collections
import logging
import math
import threading
import time
from collections.abc import Callable, Iterable
from typing import Any

import msgspec
import numpy as np
import zenoh

from protocol.codec import encode, media_type
from protocol.keys import Keys
from protocol.messages import LaserScan, Odometry, Time
from simd.adapters.zenoh_entities import Interest, undeclare_all
from simd.core.lidar import LidarSpec
from simd.core.snapshot import RobotState, TickSnapshot
from simd.wire import convert
from simd.wire.fleet_codec import encode_fleet_odometry, encode_fleet_scans
from simd.wire.odom_codec import OdometryEncoder
from simd.wire.scan_codec import ScanEncoder

log = logging.getLogger(__name__)

#: Wall time a tick may spend declaring per-robot publishers (see ``Publisher._robot_puts``).
DECLARE_BUDGET_S = 0.02
#: Publishers of followed robots (asked for by their exact key) a tick declares before the others,
#: whatever the budget: a handful of followers are served at once, thousands of asks cannot stall
#: a tick (~15 ms each among 20 000 robots' publishers); the rest wait for the next ticks.
FOLLOWED_PER_TICK = 16


def to_json(topic: str, msgpack_payload: bytes) -> bytes:
    """A published message as JSON for people; a scan's ranges become a list (null = inf)."""
    if topic == "scan":
        scan = msgspec.msgpack.decode(msgpack_payload, type=LaserScan)
        d = msgspec.structs.asdict(scan)
        d["ranges"] = [None if not math.isfinite(r) else round(r, 4) for r in scan.ranges_array().tolist()]
        d["intensities"] = scan.intensities_array().tolist()
        return msgspec.json.encode(d)
    return msgspec.json.encode(msgspec.msgpack.decode(msgpack_payload, type=Odometry))


class Publisher:
    """The daemon's outgoing zenoh entities and the latest message of every robot."""

    def __init__(self, session: zenoh.Session, keys: Keys, spec: LidarSpec) -> None:
        self.session = session
        self.keys = keys
        self.spec = spec
        self.fleet_messages = 0  # P/odometry and P/scans messages sent (built only when wanted)
        self._fleet_failed = False
        self._odom = OdometryEncoder()
        self._scans = ScanEncoder(spec)
        self._odom_pub: dict[str, zenoh.Publisher] = {}
        self._scan_pub: dict[str, zenoh.Publisher] = {}
        self._tokens: dict[str, zenoh.LivelinessToken] = {}
        # each topic's put of every robot of the last tick's roster, looked up once per fleet
        # change instead of once per robot per tick, and the robots still without a publisher
        self._puts = {"odom": RobotPuts(), "scan": RobotPuts()}
        self.odom_puts = 0  # per-robot odometry messages put (none while nobody subscribes)
        self.scan_puts = 0  # per-robot scans put, likewise
        self._declared = 0  # publishers declared this tick
        self._declare_from = 0.0  # when this tick's first declaration started
        # what get P/<ns>/odom and P/<ns>/scan answer from, read on zenoh's threads
        self._latest_lock = threading.Lock()
        self._latest_tick: TickSnapshot | None = None
        self._first_odom: dict[str, bytes] = {}  # spawned since the latest tick
        #: deleted robots, at (epoch, tick) of their delete, until a later tick is sent
        self._removed: dict[str, tuple[int, int]] = {}
        self._gone: frozenset[str] = frozenset()  # those of them the tick being sent still names
        self._latest_scan: dict[str, tuple[TickSnapshot, int]] = {}
        # robots somebody asked for by their exact key (a client starting to follow one), in the
        # order asked, whose publisher is not declared yet: added on zenoh's threads, taken by ticks
        self._followed: dict[str, dict[str, None]] = {"odom": {}, "scan": {}}
        k = keys
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
        # the same for the robots' own topics (a subscriber of P/tb3_0/odom or P/** matches too)
        self._odom_probe = session.declare_publisher(k.odom("*"))
        self._scan_probe = session.declare_publisher(k.scan("*"))
        self.odom_wanted = Interest(self._odom_probe)
        self.scan_wanted = Interest(self._scan_probe)
        self.odom_json_wanted = Interest(self._odom_json_probe)
        self.scan_json_wanted = Interest(self._scan_json_probe)
        self.fleet_odom_wanted = Interest(self.fleet_odom_pub)
        self.fleet_scan_wanted = Interest(self.fleet_scan_pub)
        self.interests = (  # asked again before a step (Interest.refresh)
            self.odom_wanted,
            self.scan_wanted,
            self.odom_json_wanted,
            self.scan_json_wanted,
            self.fleet_odom_wanted,
            self.fleet_scan_wanted,
        )
        self._entities: list[Any] = [
            *self.interests,
            session.declare_queryable(k.odom("*"), self._answer_odom),
            session.declare_queryable(k.scan("*"), self._answer_scan),
            self.clock_pub,
            self.fleet_odom_pub,
            self.fleet_scan_pub,
            self._odom_json_probe,
            self._scan_json_probe,
            self._odom_probe,
            self._scan_probe,
        ]

    # -- robots -------------------------------------------------------------------------------

    def add_robot(self, state: RobotState, time: float, put: bool = True) -> None:
        """Declare the robot's token and put its first odometry (to whoever subscribes), so a
        robot is never silent, even while paused. Without ``put`` (a spawn answered at once
        while running: simd/engine/promises.py) the first odometry is only kept for whoever
        asks for it; the tick that follows declares the robot's publisher within its budget and
        puts it (declaring one costs ~15 ms among 20 000 robots' publishers)."""
        ns = state.namespace
        self._tokens[ns] = self.session.liveliness().declare_token(self.keys.alive(ns))
        first = encode(convert.odometry(ns, Time.from_seconds(time), *state.odom_pose, 0.0, 0.0, 0.0))
        with self._latest_lock:
            self._first_odom[ns] = first
        if put and (self.odom_wanted or self.odom_json_wanted):
            # declared now, whatever the tick's budget: the spawn's reply follows this
            pub = self._odom_pub.get(ns) or self._declare("odom", ns)
            if pub is not None:
                pub.put(first)
                self.odom_puts += 1
            if self.odom_json_wanted:
                self._mirror("odom", [ns], [first])

    def _may_declare(self) -> bool:
        """Whether another per-robot publisher may be declared in this tick's budget."""
        if self._declared >= 1 and time.perf_counter() - self._declare_from > DECLARE_BUDGET_S:
            return False
        if self._declared == 0:
            self._declare_from = time.perf_counter()
        self._declared += 1
        return True

    def _robot_puts(self, topic: str, namespaces: list[str]) -> RobotPuts:
        """How this tick's messages of ``topic`` are put: through each robot's publisher,
        declared the first time somebody subscribes to some robot's topics (thousands of
        publishers declared up front made a daemon behind a router answer ever later,
        docs/scale-out.md, and nobody may ever subscribe to them). Declaring 8 000 at once held
        the daemon for seconds, so each tick declares them for at most ``DECLARE_BUDGET_S``, in
        roster order; the robots still without one are neither encoded nor put until then
        (their latest message is still answered on request), and a tick looks only at the next
        of them, not at every robot (at 20 000 robots the publishers take hours to declare, and
        a pass over the fleet every tick was a tenth of the daemon's Python time). The spawn
        order alone made a follower of the 20 000th robot wait minutes: robots asked for by
        their exact key are declared first (:meth:`_declare_followed`). Never put on a key
        string instead: zenoh matches such a key against every resource it knows at every put,
        and with 8 000 robots' tokens and a driver's 8 000 publishers that made a tick take
        seconds (bench.overload)."""
        table = self._puts[topic]
        declared = self._odom_pub if topic == "odom" else self._scan_pub
        if table.stale or namespaces != table.layout:  # cheap when equal: the simulation hands out the same list
            table.lay_out(namespaces, declared, self._gone)
        while table.waiting:
            ns = table.layout[table.waiting[0]]
            if ns in self._gone:  # deleted after this tick was made: no publisher
                table.waiting.popleft()
                continue
            if not self._may_declare():
                break
            pub = declared.get(ns) or self._declare(topic, ns)
            if pub is None:  # deleted while it was being declared
                table.waiting.popleft()
                continue
            table.declared(pub)
        return table

    def remove_robot(self, ns: str, at: tuple[int, int], publishers: bool = True) -> None:
        """Undeclare a deleted robot's token and publishers now (any thread: its delete is
        answered at once), deleted at (epoch, tick) ``at``: ticks up to then, still queued for
        sending, leave it out. :meth:`forget` follows them, in the tick order. Without
        ``publishers`` those are left for :meth:`drop_publishers`."""
        with self._latest_lock:
            self._removed[ns] = at
            self._first_odom.pop(ns, None)
            self._latest_scan.pop(ns, None)
            for asked in self._followed.values():
                asked.pop(ns, None)
        tok = self._tokens.pop(ns, None)
        if tok is not None:
            tok.undeclare()
        if publishers:
            self.drop_publishers(ns)

    def drop_publishers(self, ns: str) -> None:
        """Undeclare a deleted robot's publishers (:meth:`remove_robot` does; a delete answered
        at once does after its answer: the ticks leave the robot out from then on anyway)."""
        for declared in (self._odom_pub, self._scan_pub):
            pub = declared.pop(ns, None)
            if pub is not None:
                pub.undeclare()
        self._stale(ns)

    def _stale(self, ns: str) -> None:
        """The robot's publishers changed outside the tick's tables: those that have it look
        them up again (a table has to be laid out again only for a robot it has)."""
        for table in self._puts.values():
            if ns in table.row_of:
                table.stale = True

    def forget(self, ns: str) -> None:
        """A deleted robot's encoder caches, after the ticks queued before its delete."""
        self._odom.forget(ns)
        self._scans.forget(ns)

    # -- ticks ----------------------------------------------------------------------------------

    def publish_tick(self, snap: TickSnapshot) -> None:
        """Every robot's odometry, the scans due, then the fleet topics, of one tick."""
        self._declared = 0
        with self._latest_lock:
            self._latest_tick = snap
            if self._first_odom:  # a robot spawned after this tick ran (its odometry went ahead) keeps its first
                named = set(snap.namespaces)
                self._first_odom = {ns: b for ns, b in self._first_odom.items() if ns not in named}
            if self._removed:  # deleted robots this tick (queued before the delete) still names
                at = (snap.epoch, snap.tick)
                self._removed = {ns: when for ns, when in self._removed.items() if at <= when}
            gone = frozenset(self._removed)
            for ns in gone ^ self._gone:  # a robot deleted (or no longer named): looked up again
                self._stale(ns)
            self._gone = gone
            latest_scan = self._latest_scan
            for i, ns in enumerate(snap.scan_namespaces):
                if ns not in gone:  # a deleted robot's scan, kept, would keep the whole snapshot for ever
                    latest_scan[ns] = (snap, i)
        if self._followed["odom"] or self._followed["scan"]:
            self._declare_followed()
        if self.odom_wanted or self.odom_json_wanted:
            puts = self._robot_puts("odom", snap.namespaces)
            mirrored = bool(self.odom_json_wanted)  # (the JSON mirror has every robot's)
            if puts.ready or mirrored:
                rows = None if mirrored or len(puts.ready) == len(puts.layout) else puts.ready
                cols = (snap.x, snap.y, snap.yaw, snap.linear_x, snap.linear_y, snap.angular_z)
                odom = self._odom.encode(snap.namespaces, snap.time, *cols, rows=rows)
                _send(puts, range(len(odom)) if rows is None else rows, odom)
                self.odom_puts += len(puts.ready)
                if mirrored:
                    self._mirror("odom", snap.namespaces, odom)
        if snap.scan_namespaces and (self.scan_wanted or self.scan_json_wanted):
            # the table is the whole roster's, as odometry's (the robots scanning change from
            # tick to tick: a table of theirs would be laid out again at every tick)
            puts = self._robot_puts("scan", snap.namespaces)
            due = snap.scan_index
            mirrored = bool(self.scan_json_wanted)
            ready = puts.ready_mask[due]
            if mirrored or ready.all():
                scans = self._scans.encode(snap.scan_namespaces, snap.time, snap.scans)
                _send(puts, due.tolist(), scans)
                self.scan_puts += int(ready.sum())
                if mirrored:
                    self._mirror("scan", snap.scan_namespaces, scans)
            elif ready.any():  # only the robots with a publisher: a scan is ~1.5 kB to encode
                picked = np.flatnonzero(ready)
                names = [snap.scan_namespaces[k] for k in picked.tolist()]
                _send(puts, due[picked].tolist(), self._scans.encode(names, snap.time, snap.scans[picked]))
                self.scan_puts += len(names)
        self._publish_fleet_topics(snap)

    def _declare_followed(self, most: int = FOLLOWED_PER_TICK) -> None:
        """Declare the publishers of the robots somebody asked for by their exact key (in the
        order asked, ``most`` of them), before this tick's round robin and outside its budget,
        while somebody subscribes to that topic; the others stay asked for the next ticks."""
        wanted = {
            "odom": bool(self.odom_wanted or self.odom_json_wanted),
            "scan": bool(self.scan_wanted or self.scan_json_wanted),
        }
        taken: list[tuple[str, str]] = []
        with self._latest_lock:
            for topic, asked in self._followed.items():
                while wanted[topic] and asked and len(taken) < most:
                    ns = next(iter(asked))
                    del asked[ns]
                    taken.append((topic, ns))
        for topic, ns in taken:
            table = self._odom_pub if topic == "odom" else self._scan_pub
            if ns not in table and ns in self._tokens and ns not in self._gone:  # (else declared meanwhile, or deleted)
                self._declare(topic, ns)
                self._stale(ns)

    def _declare(self, topic: str, ns: str) -> zenoh.Publisher | None:
        """Declare the robot's publisher of ``topic`` (``odom`` or ``scan``) and keep it; None
        when the robot was deleted meanwhile (a delete answered at once, on a query's thread,
        drops its publishers: one kept after that would never be undeclared). Scans
        travel at DATA_LOW: zenoh gives each priority its own transmit queue, so a tick's scans
        and its odometry each get a full queue, and odometry goes first when a link is
        congested (it is what closes a control loop)."""
        if topic == "odom":
            table = self._odom_pub
            pub = self.session.declare_publisher(self.keys.odom(ns), encoding="application/msgpack")
        else:
            table = self._scan_pub
            pub = self.session.declare_publisher(
                self.keys.scan(ns), encoding="application/msgpack", priority=zenoh.Priority.DATA_LOW
            )
        table[ns] = pub
        # kept first, then checked: a delete that pops the token after this finds it and drops it
        if ns not in self._tokens and table.pop(ns, None) is pub:
            pub.undeclare()
            return None
        return pub

    def _publish_fleet_topics(self, snap: TickSnapshot) -> None:
        """The tick as one message per topic, for whoever follows the whole fleet (if anyone).

        After the per-robot topics, and never fatal: these are a convenience on top of the
        contract, so a failure here is logged (once) and the simulation goes on.
        """
        try:
            if snap.namespaces and self.fleet_odom_wanted:
                s = snap
                cols = (s.x, s.y, s.yaw, s.linear_x, s.linear_y, s.angular_z)
                self.fleet_odom_pub.put(encode_fleet_odometry(s.namespaces, s.time, *cols))
                self.fleet_messages += 1
            if snap.scan_namespaces and self.fleet_scan_wanted:
                self.fleet_scan_pub.put(encode_fleet_scans(self.spec, snap.scan_namespaces, snap.time, snap.scans))
                self.fleet_messages += 1
        except Exception:
            if not self._fleet_failed:
                log.exception("the fleet topics failed (logged once; the robots' own topics go on)")
            self._fleet_failed = True

    def _mirror(self, topic: str, namespaces: list[str], payloads: list[bytes]) -> None:
        for ns, data in zip(namespaces, payloads, strict=True):
            self.session.put(f"{self.keys.prefix}/{ns}/{topic}/json", to_json(topic, data), encoding="application/json")

    def wants_fleet_odom(self) -> bool:
        """True while somebody subscribes to ``P/odometry``."""
        return bool(self.fleet_odom_wanted)

    def wants_fleet_scan(self) -> bool:
        """True while somebody subscribes to ``P/scans``."""
        return bool(self.fleet_scan_wanted)

    def publish_clock(self, payload: bytes) -> None:
        self.clock_pub.put(payload)

    # -- the latest message, on request (zenoh threads) -------------------------------------------

    def latest_odom(self, ns: str) -> bytes | None:
        """The robot's latest odometry, encoded as its topic carried (or would carry) it."""
        with self._latest_lock:
            first = self._first_odom.get(ns)
            snap = None if ns in self._removed else self._latest_tick
        if first is not None:
            return first
        if snap is None or ns not in snap.namespaces:
            return None
        return encode(convert.odometry_row(snap, snap.namespaces.index(ns)))

    def latest_scan(self, ns: str) -> bytes | None:
        with self._latest_lock:
            found = self._latest_scan.get(ns)
        if found is None:
            return None
        snap, i = found
        return encode(convert.laser_scan(ns, Time.from_seconds(snap.time), self.spec, snap.scans[i]))

    def _robots_now(self) -> list[str]:
        with self._latest_lock:
            snap = self._latest_tick
            now = set(self._first_odom) | ({*snap.namespaces} - set(self._removed) if snap is not None else set())
        return sorted(now)

    def _answer(self, query: zenoh.Query, topic: str) -> None:
        with query:
            json_wanted = query.parameters.get("format") == "json"
            lookup = self.latest_odom if topic == "odom" else self.latest_scan
            asked = str(query.key_expr)
            ns = self.keys.namespace_of(asked)
            if ns is not None and "*" not in ns and "$" not in ns:  # one robot's exact key: a follower
                if ns in self._tokens:  # one of this daemon's robots
                    self._follow(topic, ns)
                data = lookup(ns)
                if data is not None:
                    body = to_json(topic, data) if json_wanted else data
                    query.reply(asked, body, encoding=media_type("json" if json_wanted else "msgpack"))
                return
            for ns in self._robots_now():
                key = f"{self.keys.prefix}/{ns}/{topic}"
                if not query.key_expr.intersects(zenoh.KeyExpr(key)):
                    continue
                data = lookup(ns)
                if data is not None:
                    body = to_json(topic, data) if json_wanted else data
                    query.reply(key, body, encoding=media_type("json" if json_wanted else "msgpack"))

    def _follow(self, topic: str, ns: str) -> None:
        """Remember that somebody asked for the robot's latest message by its exact key, as a
        client does when it starts following that robot: the next tick declares its publisher
        first (:meth:`_declare_followed`). On zenoh's threads."""
        table = self._odom_pub if topic == "odom" else self._scan_pub
        if ns in table:  # declared already (the usual case): nothing to do
            return
        with self._latest_lock:
            if ns not in self._removed:
                self._followed[topic][ns] = None

    def _answer_odom(self, query: zenoh.Query) -> None:
        self._answer(query, "odom")

    def _answer_scan(self, query: zenoh.Query) -> None:
        self._answer(query, "scan")

    def close(self) -> None:
        """Undeclare the fixed entities; the robots' go with the session."""
        undeclare_all(self._entities)


def _skip(data: bytes) -> None:
    """The put of a robot without a publisher (deleted after the tick being sent, or waiting for
    its publisher): nothing."""


class RobotPuts:
    """One topic's put for every robot of a roster (its namespaces, in order): the rows whose
    publisher is declared (``ready``, and as a mask) and those still waiting for one
    (``waiting``, in roster order). A robot deleted after the tick being sent is in neither."""

    def __init__(self) -> None:
        self.layout: list[str] = []
        self.puts: list[Callable[[bytes], object]] = []
        self.ready: list[int] = []
        self.ready_mask = np.zeros(0, dtype=bool)
        self.waiting: collections.deque[int] = collections.deque()
        self.row_of: dict[str, int] = {}  # (read on other threads: replaced, never changed)
        #: a publisher was declared or undeclared outside this table: look them up again
        self.stale = False

    def lay_out(self, namespaces: list[str], declared: dict[str, zenoh.Publisher], gone: frozenset[str]) -> None:
        self.stale = False  # (first: another thread may make it stale again meanwhile)
        puts: list[Callable[[bytes], object]] = [_skip] * len(namespaces)
        ready, waiting = [], []
        for i, ns in enumerate(namespaces):
            if ns in gone:
                continue
            pub = declared.get(ns)
            if pub is None:
                waiting.append(i)
            else:
                puts[i] = pub.put
                ready.append(i)
        mask = np.zeros(len(namespaces), dtype=bool)
        mask[ready] = True
        self.layout, self.puts, self.ready, self.ready_mask = list(namespaces), puts, ready, mask
        self.waiting = collections.deque(waiting)
        self.row_of = dict(zip(namespaces, range(len(namespaces)), strict=True))

    def declared(self, pub: zenoh.Publisher) -> None:
        """The first waiting robot's publisher is declared: its messages are put from now on."""
        i = self.waiting.popleft()
        self.puts[i] = pub.put
        self.ready.append(i)
        self.ready_mask[i] = True


def _send(table: RobotPuts, rows: Iterable[int], payloads: list[bytes]) -> None:
    """Put each payload through the publisher of its row (a waiting robot's put: nothing)."""
    puts = table.puts
    for i, data in zip(rows, payloads, strict=True):
        try:
            puts[i](data)
        except zenoh.ZError:  # a robot deleted meanwhile: its publisher is gone
            pass
