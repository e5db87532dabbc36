"""The typed Python client of a fleetsim daemon.

One zenoh session per client; every call is a query with a deadline, so nothing waits
forever, and a missing daemon is reported at once with the endpoint that was tried::

    from clients import FleetClient

    with FleetClient() as fleet:                      # tcp/127.0.0.1:7447, prefix "fleet"
        robot = fleet.spawn("tb3_0", x=-2.0, y=-0.5)
        fleet.drive("tb3_0", 0.1, 0.0)
        odom = fleet.wait_odom("tb3_0")
        print(odom.pose.pose.position)

One module over the usual size on purpose: it is one class, the client's whole surface
(queries, driving, subscriptions, the fleet topics), and reads best in one place.
"""

from __future__ import annotations

import collections
import queue
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import msgspec
import numpy as np
import numpy.typing as npt
import zenoh

from clients.navigation import Goal
from clients.tick_merge import TickMerge
from fleetcommon.zenoh_config import DEFAULT_ENDPOINT, ZenohOptions, zenoh_error_text
from protocol.codec import MAX_REPLY_BYTES, decode, encode, reply_error
from protocol.control import (
    Clock,
    DaemonInfo,
    DeleteRequest,
    ListRequest,
    PackedCommands,
    PackedObservations,
    ResetRequest,
    RobotList,
    RobotRecord,
    SpawnRequest,
    StepReply,
    StepRequest,
    WorldInfo,
)
from protocol.errors import ErrorCode, FleetError
from protocol.gather import GATHER, Gather, Gathering, merge_lists, merge_steps
from protocol.keys import DEFAULT_PREFIX, Keys
from protocol.listing import select
from protocol.messages import FleetOdometry, FleetScans, LaserScan, Odometry, Twist, Vector3
from protocol.names import check_name
from protocol.navigation import (
    DEFAULT_TOLERANCE_M,
    DEFAULT_YAW_TOLERANCE_RAD,
    CancelRequest,
    FleetNavigation,
    NavigateReply,
    NavigateRequest,
    NavigationPath,
    NavigationResult,
    NavigationState,
)

T = TypeVar("T")

DEFAULT_TIMEOUT = 3.0
#: Requests in flight in ``spawn_many`` / ``delete_many``: enough to hide the round trip,
#: few enough that the daemon's request queue keeps room for everybody else's.
PIPELINE_WINDOW = 64


class Subscription:
    """A live subscription; ``close()`` (or leaving a ``with`` block) ends it."""

    def __init__(self, *entities: Any) -> None:
        self._entities = list(entities)

    def close(self) -> None:
        for entity in self._entities:
            try:
                entity.undeclare()
            except zenoh.ZError:
                pass
        self._entities.clear()

    def __enter__(self) -> Subscription:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    undeclare = close  # a subscription can hold another (it ends with it)


class FleetClient:
    """Connects to a daemon (or a zenoh router in front of it) and speaks its protocol."""

    def __init__(
        self,
        connect: str | list[str] | None = None,
        *,
        prefix: str = DEFAULT_PREFIX,
        timeout: float = DEFAULT_TIMEOUT,
        options: ZenohOptions | None = None,
    ) -> None:
        if options is None:
            endpoints = [connect] if isinstance(connect, str) else list(connect or [DEFAULT_ENDPOINT])
            options = ZenohOptions(mode="client", connect=endpoints)
        self.options = options
        self.keys = Keys(prefix)
        self.timeout = timeout
        try:
            conf = options.build()
        except ValueError as e:  # a bad endpoint, config file or --cfg: the user's to fix
            raise FleetError(ErrorCode.INVALID_VALUE, f"bad zenoh configuration: {e}", "connect") from None
        if options.mode == "client":
            # fail within the timeout instead of hanging when nothing listens there
            conf.insert_json5("connect/timeout_ms", str(int(timeout * 1000)))
        try:
            self.session = zenoh.open(conf)
        except zenoh.ZError as e:
            raise FleetError(
                ErrorCode.UNAVAILABLE,
                f"cannot reach a fleetsim daemon at {options.endpoints()}: {zenoh_error_text(e)} "
                "(is simd running? start it with: simd)",
            ) from None
        self._subs: list[Subscription] = []
        self._cmd_pubs: dict[str, zenoh.Publisher] = {}
        self._batch_pub: zenoh.Publisher | None = None
        self._cmd_lock = threading.Lock()

    # -- lifecycle ------------------------------------------------------------------------

    def close(self) -> None:
        for s in self._subs:
            s.close()
        self._subs.clear()
        self._cmd_pubs.clear()  # the session's close undeclares them
        self._batch_pub = None
        self.session.close()

    def __enter__(self) -> FleetClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- queries --------------------------------------------------------------------------

    def _ask(self, key: str, request: object | None, deadline: float) -> Any:
        """Send a query every daemon that declares ``key`` hears (in a shared fleet the one
        that owns the answer replies; zenoh's default target would pick one of them), keeping
        each one's reply (they share the key, which zenoh's default consolidation would merge)."""
        return self.session.get(
            f"{key}?format=msgpack",
            payload=encode(request) if request is not None else None,
            encoding="application/msgpack",
            timeout=deadline,
            target=zenoh.QueryTarget.ALL,
            consolidation=zenoh.ConsolidationMode.NONE,
        )

    def _query_all(
        self, key: str, request: object | None, reply_type: type[T], timeout: float | None = None, how: Gather = "any"
    ) -> list[T]:
        """The daemons' good replies (a fleet shared by several daemons: docs/scale-out.md),
        gathered ``how`` protocol/gather.py says; or the refusal that is the answer."""
        deadline = self.timeout if timeout is None else timeout
        return self._answers(key, self._ask(key, request, deadline), reply_type, deadline, how)

    def _answers(self, key: str, replies: Any, reply_type: type[T], deadline: float, how: Gather = "any") -> list[T]:
        """The good replies among a query's ``replies``, as :meth:`_query_all` gives them."""
        gathering: Gathering[T] = Gathering(how)
        for reply in replies:
            if reply.ok is not None:
                answer: T | FleetError = decode(reply.ok.payload.to_bytes(), reply_type, MAX_REPLY_BYTES)
            else:
                answer = self._error(key, reply, deadline)
            if gathering.add(answer):
                break
        return gathering.answer(self._unavailable(key))

    def _query(self, key: str, request: object | None, reply_type: type[T], timeout: float | None = None) -> T:
        """The first reply (one daemon, or the one that owns the answer in a shared fleet)."""
        return self._query_all(key, request, reply_type, timeout, "first")[0]

    def _error(self, key: str, reply: zenoh.Reply, deadline: float) -> FleetError:
        """The error an error reply carries (a timeout, a structured refusal, or garbage)."""
        err = reply.err
        assert err is not None
        return reply_error(err.payload.to_bytes(), f"the daemon did not answer {key} within {deadline:g} s")

    def _unavailable(self, key: str) -> FleetError:
        return FleetError(
            ErrorCode.UNAVAILABLE,
            f"no fleetsim daemon answered on {key} via {self.options.endpoints()} "
            + (
                "(is simd running with the same --prefix?)"
                if self.options.user() is None
                else f"({self.options.no_answer_hint()})"
            ),
        )

    def spawn(
        self,
        name: str,
        x: float = 0.0,
        y: float = 0.0,
        yaw: float = 0.0,
        *,
        model: str = "burger",
        namespace: str | None = None,
    ) -> RobotRecord:
        """Spawn a robot; returns its record once it is live. Raises FleetError if refused.
        The pose may be any real numbers (numpy's too)."""
        req = SpawnRequest(name=name, namespace=namespace, model=model, x=float(x), y=float(y), yaw=float(yaw))
        return self._query(self.keys.spawn, req, RobotRecord)

    def spawn_many(self, robots: Iterable[SpawnRequest], window: int = PIPELINE_WINDOW) -> list[RobotRecord]:
        """Spawn these robots in this order, without waiting for each reply before sending the
        next (up to ``window`` requests in flight): a thousand spawns take a few round trips'
        time instead of a thousand. The daemon serves them in the order sent (one link carries
        them in order, and zenoh runs a queryable's callback on one thread, first in first
        out), so the fleet's rows (and with them each robot's scan phase) are those of
        spawning one by one (tests/daemon/test_daemon.py checks it with 300 in flight). Every
        request is answered before anything is raised: a refused one raises the first refusal,
        naming the robot, with the others spawned."""
        requests = list(robots)
        for r in requests:
            if not isinstance(r, SpawnRequest):
                raise TypeError(f"spawn_many takes SpawnRequest(name=..., x=..., y=...) items, got {r!r}")
        return self._pipelined([(self.keys.spawn, r.name, r) for r in requests], RobotRecord, window)

    def delete_many(self, names: Iterable[str], window: int = PIPELINE_WINDOW) -> list[RobotRecord]:
        """Delete these robots in this order, pipelined as :meth:`spawn_many`; their last
        records. A refused one (not found) raises the first refusal once all were answered."""
        requests = []
        for n in names:
            if not isinstance(n, str):
                raise TypeError(f"delete_many takes robot names, got {n!r}")
            requests.append(DeleteRequest(name=n))
        return self._pipelined([(self.keys.delete, r.name, r) for r in requests], RobotRecord, window)

    def _pipelined(self, sends: Sequence[tuple[str, str, object]], reply_type: type[T], window: int) -> list[T]:
        """Send each (key, whom, request) in order, at most ``window`` unanswered at a time;
        the replies in order, each one answered as :meth:`delete` takes its answer (in a shared
        fleet the robot's daemon answers, others may say not found). A refusal is raised once
        all were answered (the first one, naming ``whom``); the others stand."""
        if window < 1:
            raise ValueError(f"window must be at least 1, got {window}")
        in_flight: collections.deque[tuple[str, str, Any]] = collections.deque()
        out: list[T] = []
        refusal: FleetError | None = None

        def answer() -> None:
            nonlocal refusal
            key, whom, replies = in_flight.popleft()
            try:
                out.append(self._answers(key, replies, reply_type, self.timeout)[0])
            except FleetError as e:
                if refusal is None:
                    refusal = FleetError(e.code, f"{whom}: {e.message}", e.field)

        for key, whom, request in sends:
            in_flight.append((key, whom, self._ask(key, request, self.timeout)))
            if len(in_flight) >= window:
                answer()
        while in_flight:
            answer()
        if refusal is not None:
            raise refusal
        return out

    def delete(self, name: str) -> RobotRecord:
        """Delete a robot by name or namespace; returns its last record. (In a shared fleet
        the robot's daemon answers, and so may the daemon its name is placed on, with
        not found: the robot's answer wins.)"""
        return self._query_all(self.keys.delete, DeleteRequest(name=name), RobotRecord)[0]

    # -- navigation (docs/navigation.md) -----------------------------------------------------

    def navigate(
        self,
        robot: str,
        x: float,
        y: float,
        yaw: float | None = None,
        *,
        tolerance: float = DEFAULT_TOLERANCE_M,
        yaw_tolerance: float = DEFAULT_YAW_TOLERANCE_RAD,
        timeout: float = 0.0,
        goal_id: str = "",
    ) -> Goal:
        """Send ``robot`` (its namespace) to (x, y), arriving with heading ``yaw`` if given.
        Returns a :class:`~clients.navigation.Goal` once the daemon accepted it: ``wait()``,
        ``feedback``, ``cancel()``, ``result``. Raises FleetError if refused (a goal in a wall
        or off the map, an unknown robot, a bad number): then nothing moves. ``timeout`` (s of
        sim time, 0 = none) fails the goal with ``timeout`` when it runs out."""
        req = NavigateRequest(
            x=float(x),
            y=float(y),
            yaw=None if yaw is None else float(yaw),
            tolerance=float(tolerance),
            yaw_tolerance=float(yaw_tolerance),
            timeout=float(timeout),
            goal_id=goal_id,
        )
        goal = Goal(self, robot)  # listening before the goal goes out: its result cannot slip by
        try:
            reply = self._query_all(self.keys.navigate(robot), req, NavigateReply)[0]
        except BaseException:
            goal.close()
            raise
        goal._accepted(reply)
        return goal

    def send_goals(
        self, robot_goals: Iterable[tuple[str, NavigateRequest]], window: int = PIPELINE_WINDOW
    ) -> list[NavigateReply]:
        """Send many robots their goals without waiting for each reply (as :meth:`spawn_many`);
        the replies in order. A refused goal raises the first refusal, naming the robot, once
        all were answered (the others stand)."""
        return self._pipelined([(self.keys.navigate(robot), robot, req) for robot, req in robot_goals],
                               NavigateReply, window)  # fmt: skip

    def cancel_goal(self, robot: str, goal_id: str = "") -> NavigationResult:
        """End the robot's goal (``goal_id`` empty: whichever it has); the goal's result."""
        return self._query_all(self.keys.navigate_cancel(robot), CancelRequest(goal_id=goal_id), NavigationResult)[0]

    def navigation_state(self, robot: str) -> NavigationState:
        """The robot's current (or last) goal, its latest feedback and its result."""
        return self._query_all(self.keys.navigate_state(robot), None, NavigationState)[0]

    def plans(self, robot: str = "*") -> dict[str, NavigationPath]:
        """The path each robot follows now (``robot`` a namespace or ``*``)."""
        found = {}
        for reply in self._ask(self.keys.plan(robot), None, self.timeout):
            if reply.ok is not None:
                path = decode(reply.ok.payload.to_bytes(), NavigationPath, MAX_REPLY_BYTES)
                found[path.robot] = path
        return found

    def _on_decoded(self, key: str, type_: type[T], callback: Callable[[T], None]) -> Subscription:
        """``callback`` with each sample on ``key`` that decodes as ``type_`` (others are dropped,
        whatever their bytes: protocol.codec.decode)."""

        def on_sample(sample: zenoh.Sample) -> None:
            try:
                msg = decode(sample.payload.to_bytes(), type_, MAX_REPLY_BYTES)
            except FleetError:
                return
            callback(msg)

        sub = Subscription(self.session.declare_subscriber(key, on_sample))
        self._subs.append(sub)
        return sub

    def on_navigation(self, callback: Callable[[FleetNavigation], None]) -> Subscription:
        """Call ``callback`` with the fleet's navigation summary (2 Hz of sim time: every
        robot with a goal, its state and goal, and goals that ended since)."""
        return self._on_decoded(self.keys.fleet_navigation, FleetNavigation, callback)

    def on_plans(self, callback: Callable[[NavigationPath], None], robot: str = "*") -> Subscription:
        """Call ``callback`` with each path a robot plans (``robot`` a namespace or ``*``);
        an empty path when its goal ended. :meth:`plans` asks for the current ones."""
        return self._on_decoded(self.keys.plan(robot), NavigationPath, callback)

    def on_navigation_results(self, callback: Callable[[NavigationResult], None], robot: str = "*") -> Subscription:
        """Call ``callback`` with the result of each goal that ends (``robot`` a namespace or
        ``*``): put always, once per goal, where ``P/navigation`` is put only while listened to."""
        return self._on_decoded(self.keys.navigate_result(robot), NavigationResult, callback)

    def robots(self, names: Sequence[str] | None = None) -> list[RobotRecord]:
        """Every robot of the fleet, whichever daemon runs it (each daemon lists its own); with
        ``names``, only the robots of those names or namespaces (those that exist)."""
        if names is None:
            return merge_lists(self._query_all(self.keys.robots, None, RobotList)).robots
        if not names:
            return []
        return self._listed(ListRequest(names=list(names)))

    def robots_page(self, after: str = "", limit: int = 1000) -> list[RobotRecord]:
        """At most ``limit`` robots in name order (plain string order: ``burger_10`` before
        ``burger_2``), those whose name sorts after ``after``: read a big fleet a page at a
        time (the next page is after the last name of this one; a page shorter than ``limit``
        is the last), or let :meth:`iter_robots` do it. Protocol/listing.py says why."""
        return self._listed(ListRequest(after=after, limit=limit))

    def iter_robots(self, page: int = 1000) -> Iterator[RobotRecord]:
        """Every robot of the fleet, in name order, asked for ``page`` at a time: a fleet of
        tens of thousands read without one reply of tens of MB."""
        after = ""
        while True:
            got = self.robots_page(after, page)
            yield from got
            if len(got) < page:
                return
            after = got[-1].name

    def _listed(self, request: ListRequest) -> list[RobotRecord]:
        """A named list or a page, picked again here from what the daemons answered: each
        daemon gives its own, and a daemon older than these fields gives every robot."""
        return select(merge_lists(self._query_all(self.keys.robots, request, RobotList)).robots, request)

    def robot(self, key: str) -> RobotRecord | None:
        """The record of a robot by name or namespace, or None (asked for alone: a daemon
        older than the ``names`` filter lists every robot, and the one is picked out here)."""
        try:
            check_name(key)
        except FleetError:
            return None
        return next((r for r in self.robots([key]) if key in (r.name, r.namespace)), None)

    def daemons(self) -> list[DaemonInfo]:
        """Every daemon serving this prefix, by id (each answers ``P/daemons`` for itself)."""
        found = []
        for reply in self._ask(self.keys.daemons, None, self.timeout):
            if reply.ok is not None:
                found.append(decode(reply.ok.payload.to_bytes(), DaemonInfo))
        return sorted(found, key=lambda d: d.id)

    def world(self) -> WorldInfo:
        return self._query(self.keys.world, None, WorldInfo)

    def clock(self) -> Clock:
        return self._query(self.keys.clock, None, Clock)

    # Pause, resume, reset and step reach every daemon of a shared fleet, and return once all
    # of them have acted (the reply is the first daemon's clock): one clock for the fleet.

    def pause(self) -> Clock:
        return self._query_all(self.keys.pause, None, Clock)[0]

    def resume(self) -> Clock:
        return self._query_all(self.keys.resume, None, Clock)[0]

    def reset(self, seed: int | None = None) -> Clock:
        return self._query_all(self.keys.reset, ResetRequest(seed=seed), Clock)[0]

    def step(
        self,
        ticks: int = 1,
        cmd_vel: dict[str, tuple[float, float]] | None = None,
        timeout: float | None = None,
        *,
        observe: Iterable[str] = (),
        publish: bool = True,
        packed: bool = False,
        commands: tuple[list[str], npt.ArrayLike] | None = None,
    ) -> StepReply:
        """Advance ``ticks`` ticks of a paused or lockstep daemon and return once they ran.

        ``cmd_vel`` ({namespace: (linear, angular)}) holds for every tick of the step.
        ``observe`` names robots whose odometry and latest scan come back in the reply
        (``reply.observations[name].odom`` / ``.scan``), with no further round trip. The reply
        is the clock after the step, with ``ticks_run`` (fewer than asked, and ``cancelled``,
        when somebody paused, resumed or reset the daemon meanwhile).

        For many robots (a learning loop): ``publish=False`` steps without publishing any
        topic, and ``packed=True`` returns the observations as arrays in ``reply.packed``
        (read them with :func:`observed_arrays`); ``commands=(namespaces, values)`` with
        ``values`` of shape (n, 2) (linear, angular) replaces ``cmd_vel`` by arrays."""
        cmds = {ns: Twist(linear=Vector3(x=v), angular=Vector3(z=w)) for ns, (v, w) in (cmd_vel or {}).items()}
        arrays = None
        if commands is not None:
            arrays = _packed(*commands, "commands")
        req = StepRequest(
            ticks=ticks, cmd_vel=cmds, commands=arrays, observe=list(observe), publish=publish, packed=packed
        )
        # a daemon that refused did not step: the fleet is not where the caller thinks
        return merge_steps(self._query_all(self.keys.step, req, StepReply, timeout, GATHER[StepRequest]), req.observe)

    # -- motion ---------------------------------------------------------------------------

    def drive(self, namespace: str, linear: float, angular: float) -> None:
        """Put one cmd_vel. The daemon stops a robot 0.5 s after its last command.

        Each namespace gets a publisher, declared on first use and kept. With plain puts on
        key strings instead, 1 000 robots driven at 5 Hz from one client backed up that
        client's link at the daemon: its own queries waited 1.6–3.7 s (median) behind its
        commands, against 7.6 ms with publishers (a declared key is routed once; a key string,
        it seems, at every put). For thousands of robots :meth:`drive_many` is cheaper (one
        message a cycle). Keep this client a zenoh client (the default): from a zenoh *peer*,
        8 000 robots' commands at 10 Hz mostly never arrived (docs/robustness.md).
        """
        msg = Twist(linear=Vector3(x=linear), angular=Vector3(z=angular))
        pub = self._cmd_pubs.get(namespace)
        if pub is None:
            with self._cmd_lock:  # one publisher per namespace, whichever thread drives it first
                pub = self._cmd_pubs.get(namespace)
                if pub is None:
                    key = self.keys.cmd_vel(namespace)
                    pub = self._cmd_pubs[namespace] = self.session.declare_publisher(
                        key, encoding="application/msgpack"
                    )
        pub.put(encode(msg))

    def drive_many(self, namespaces: Sequence[str], values: npt.ArrayLike) -> None:
        """Put one command to each of many robots in one message, on ``P/commands``: ``values``
        of shape (n, 2), (linear, angular) for each namespace, as :meth:`step`'s ``commands``.
        The same as a :meth:`drive` for each robot (the watchdog, the limits), for the price of
        one put: a program driving thousands of robots at 10 Hz otherwise spends a core putting
        tens of thousands of messages a second, and the daemon one decoding them (docs/clients.md).
        Names no daemon has are ignored, as commands for unknown robots are; a daemon drops a
        batch it cannot take whole (logged, and counted in the clock's ``dropped_commands``),
        so what is wrong with it is refused here first."""
        batch = _packed(namespaces, values, "values")
        try:
            batch.rows()
        except FleetError as e:
            raise ValueError(e.message) from None
        if len(set(batch.names)) != len(batch.names):
            raise ValueError("a namespace is given more than once")
        if self._batch_pub is None:
            with self._cmd_lock:
                if self._batch_pub is None:
                    self._batch_pub = self.session.declare_publisher(
                        self.keys.commands(), encoding="application/msgpack"
                    )
        self._batch_pub.put(encode(batch))

    def stop(self, namespace: str) -> None:
        self.drive(namespace, 0.0, 0.0)

    # -- presence -------------------------------------------------------------------------

    def alive(self) -> list[str]:
        """Namespaces of the live robots, from their liveliness tokens."""
        out = []
        for r in self.session.liveliness().get(f"{self.keys.prefix}/*/alive", timeout=self.timeout):
            if r.ok is not None:
                ns = self.keys.namespace_of(str(r.ok.key_expr))
                if ns:
                    out.append(ns)
        return sorted(out)

    def on_presence(self, callback: Callable[[str, bool], None]) -> Subscription:
        """Call ``callback(namespace, alive)`` for robots present now and as they come and go."""

        def handler(sample: zenoh.Sample) -> None:
            ns = self.keys.namespace_of(str(sample.key_expr))
            if ns:
                callback(ns, sample.kind == zenoh.SampleKind.PUT)

        sub = Subscription(
            self.session.liveliness().declare_subscriber(f"{self.keys.prefix}/*/alive", handler, history=True)
        )
        self._subs.append(sub)
        return sub

    def on_daemons(self, callback: Callable[[str, bool], None]) -> Subscription:
        """Call ``callback(daemon_id, alive)`` for the daemons serving the fleet now and as
        they come and go (their ``P/daemons/<id>`` tokens): a daemon that dies, however, is
        told within its zenoh lease (at once when its process ends)."""
        head = self.keys.daemon("")

        def handler(sample: zenoh.Sample) -> None:
            callback(str(sample.key_expr)[len(head) :], sample.kind == zenoh.SampleKind.PUT)

        sub = Subscription(self.session.liveliness().declare_subscriber(self.keys.daemon("*"), handler, history=True))
        self._subs.append(sub)
        return sub

    def wait_for_robot(self, namespace: str, timeout: float = 10.0) -> bool:
        """Block until the robot's liveliness token exists; False on timeout."""
        seen = threading.Event()

        def cb(ns: str, up: bool) -> None:
            if ns == namespace and up:
                seen.set()

        with self.on_presence(cb):
            return seen.wait(timeout)

    # -- sensors --------------------------------------------------------------------------

    def _subscribe(
        self, topic: str, namespace: str, type_: type[T], callback: Callable[[str, T], None]
    ) -> Subscription:
        dec = msgspec.msgpack.Decoder(type_)

        def handler(sample: zenoh.Sample) -> None:
            ns = self.keys.namespace_of(str(sample.key_expr))
            if ns is None:
                return
            try:
                msg = dec.decode(sample.payload.to_bytes())
            except msgspec.DecodeError:
                return
            callback(ns, msg)

        key = f"{self.keys.prefix}/{namespace}/{topic}"
        sub = Subscription(self.session.declare_subscriber(key, handler))
        self._subs.append(sub)
        if "*" not in namespace and "$" not in namespace:
            self._announce_follower(key)
        return sub

    def _announce_follower(self, key: str) -> None:
        """Ask for one robot's latest message by its exact key, as following it starts, and wait
        for the answer (its content is not used). The get tells the daemon that somebody follows
        this robot: in a large fleet it declares the robot's publisher by its next tick instead
        of in its turn in spawn order (at 20 000 robots, minutes later; docs/protocol.md). Sent
        after the subscriber on the same session, so once answered the daemon knows both."""
        for _ in self.session.get(key, timeout=self.timeout):
            pass

    def on_odom(self, namespace: str, callback: Callable[[str, Odometry], None]) -> Subscription:
        """``callback(namespace, odom)`` for every odometry message; ``namespace`` may be ``*``.
        One robot's namespace is announced to the daemon (one round trip, see
        :meth:`_announce_follower`): its messages come from the next tick on."""
        return self._subscribe("odom", namespace, Odometry, callback)

    def on_scan(self, namespace: str, callback: Callable[[str, LaserScan], None]) -> Subscription:
        """``callback(namespace, scan)`` per scan; ``scan.ranges_array()`` is a numpy view."""
        return self._subscribe("scan", namespace, LaserScan, callback)

    def _iterate(self, topic: str, namespace: str, type_: type[T], timeout: float | None) -> Iterator[tuple[str, T]]:
        q: queue.Queue[tuple[str, T]] = queue.Queue(maxsize=1024)

        def put(ns: str, msg: T) -> None:
            try:
                q.put_nowait((ns, msg))
            except queue.Full:  # a slow consumer loses the oldest-newest, never blocks zenoh
                pass

        with self._subscribe(topic, namespace, type_, put):
            while True:
                try:
                    yield q.get(timeout=timeout)
                except queue.Empty:
                    return

    def odom_stream(self, namespace: str, timeout: float | None = 5.0) -> Iterator[tuple[str, Odometry]]:
        """Iterate (namespace, Odometry); ends when nothing arrives for ``timeout`` s."""
        return self._iterate("odom", namespace, Odometry, timeout)

    def scan_stream(self, namespace: str, timeout: float | None = 5.0) -> Iterator[tuple[str, LaserScan]]:
        return self._iterate("scan", namespace, LaserScan, timeout)

    def _wait(self, topic: str, namespace: str, type_: type[T], timeout: float) -> T:
        """The next message on a robot's topic; on a paused or lockstep daemon, where nothing
        new comes until somebody steps it, the latest one."""
        q: queue.Queue[T] = queue.Queue(maxsize=1)

        def put(ns: str, msg: T) -> None:
            try:
                q.put_nowait(msg)
            except queue.Full:
                pass

        with self._subscribe(topic, namespace, type_, put):
            if self.clock().paused:
                latest = self._latest(topic, namespace, type_)
                if latest is not None:
                    return latest
            try:
                return q.get(timeout=timeout)
            except queue.Empty:
                raise FleetError(ErrorCode.TIMEOUT, f"no {topic} from {namespace!r} within {timeout:g} s") from None

    def wait_odom(self, namespace: str, timeout: float = 5.0) -> Odometry:
        """The next odometry message of a robot (its latest while the daemon is paused)."""
        return self._wait("odom", namespace, Odometry, timeout)

    def wait_scan(self, namespace: str, timeout: float = 5.0) -> LaserScan:
        """The next scan of a robot (its latest while the daemon is paused)."""
        return self._wait("scan", namespace, LaserScan, timeout)

    # -- the whole fleet, one message a tick --------------------------------------------------

    def _subscribe_fleet(self, key: str, type_: type[T], callback: Callable[[T], None], *more: Any) -> Subscription:
        """A subscriber of one fleet topic, decoded (``more``: entities that end with it)."""
        dec = msgspec.msgpack.Decoder(type_)

        def handler(sample: zenoh.Sample) -> None:
            try:
                msg = dec.decode(sample.payload.to_bytes())
            except msgspec.DecodeError:
                return
            callback(msg)

        sub = Subscription(self.session.declare_subscriber(key, handler), *more)
        self._subs.append(sub)
        return sub

    def on_fleet_odom(self, callback: Callable[[FleetOdometry], None]) -> Subscription:
        """``callback(fleet_odom)`` once a tick with every robot's odometry (``P/odometry``).

        One message a tick instead of one per robot: the way to follow a whole fleet, and the
        only one that keeps up with a hundred robots at 20x real time in Python.
        ``fleet_odom.array("x")`` is a numpy view, row ``i`` being ``fleet_odom.namespaces[i]``.
        In a fleet shared by several daemons each puts its own robots' rows: their parts of a
        tick are merged into one message (clients/tick_merge.py), so the callback sees what one
        daemon would give.
        """
        live: set[str] = set()
        daemons = self.on_daemons(lambda daemon_id, alive: (live.add if alive else live.discard)(daemon_id))
        head = self.keys.daemon("")
        for reply in self.session.liveliness().get(self.keys.daemon("*"), timeout=self.timeout):  # known at once
            if reply.ok is not None:
                live.add(str(reply.ok.key_expr)[len(head) :])
        merger = TickMerge(lambda: len(live), callback, flush_after=True)
        return self._subscribe_fleet(self.keys.fleet_odom, FleetOdometry, merger.add, daemons, merger)

    def on_fleet_scans(self, callback: Callable[[FleetScans], None]) -> Subscription:
        """``callback(fleet_scans)`` once a tick with the scans taken in it (``P/scans``);
        ``fleet_scans.ranges_array()`` has one row per namespace."""
        return self._subscribe_fleet(self.keys.fleet_scan, FleetScans, callback)

    def wait_fleet_odom(self, timeout: float = 5.0) -> FleetOdometry:
        """The next tick's odometry of the whole fleet (a paused daemon has none until it is
        stepped or resumed)."""
        q: queue.Queue[FleetOdometry] = queue.Queue(maxsize=1)

        def put(msg: FleetOdometry) -> None:
            try:
                q.put_nowait(msg)
            except queue.Full:
                pass

        with self.on_fleet_odom(put):
            try:
                return q.get(timeout=timeout)
            except queue.Empty:
                raise FleetError(ErrorCode.TIMEOUT, f"no fleet odometry within {timeout:g} s") from None

    def _latest(self, topic: str, namespace: str, type_: type[T]) -> T | None:
        for r in self.session.get(f"{self.keys.prefix}/{namespace}/{topic}", timeout=self.timeout):
            if r.ok is not None:
                return decode(r.ok.payload.to_bytes(), type_)
        return None

    def latest_odom(self, namespace: str) -> Odometry | None:
        """The daemon's most recent odometry of a robot (a query, no subscription)."""
        return self._latest("odom", namespace, Odometry)

    def latest_scan(self, namespace: str) -> LaserScan | None:
        """The daemon's most recent scan of a robot (None before its first scan)."""
        return self._latest("scan", namespace, LaserScan)


@dataclass(frozen=True)
class ObservedFleet:
    """A packed step's observations as numpy arrays, row k for ``names[k]``: ``odom`` (n, 6)
    x, y, yaw, linear x, linear y, angular z; ``scan_time`` (n,) and ``ranges`` (n, samples)
    the latest scans, NaN before a robot's first."""

    names: list[str]
    odom: npt.NDArray[np.float64]
    scan_time: npt.NDArray[np.float64]
    ranges: npt.NDArray[np.float32]


def observed_arrays(packed: PackedObservations) -> ObservedFleet:
    """Read ``StepReply.packed`` (views on the reply's bytes: no copy, read-only)."""
    n = len(packed.names)
    return ObservedFleet(  # (the dtypes as objects, given by position: a third of the cost)
        names=packed.names,
        odom=np.frombuffer(packed.odom, _F8).reshape(n, 6),
        scan_time=np.frombuffer(packed.scan_time, _F8),
        ranges=np.frombuffer(packed.ranges, _F4).reshape(n, packed.samples),
    )


_F8, _F4 = np.dtype("<f8"), np.dtype("<f4")


def wait_until(predicate: Callable[[], bool], timeout: float, interval: float = 0.02) -> bool:
    """Poll ``predicate`` until true or ``timeout`` s pass (for scripts and tests)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(interval)
    return predicate()


def _packed(names: Iterable[str], values: npt.ArrayLike, what: str) -> PackedCommands:
    """Commands as arrays (a row of (linear, angular) per name) packed as the wire has them."""
    names = list(names)
    twist = np.ascontiguousarray(values, dtype="<f8")
    if twist.shape != (len(names), 2):
        raise ValueError(f"{what}: values must have shape ({len(names)}, 2), got {twist.shape}")
    return PackedCommands(names=names, twist=twist.tobytes())
