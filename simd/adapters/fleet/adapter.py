"""The fleet protocol adapter: the engine as the key space of docs/protocol.md, over zenoh.

It is the only place where the daemon touches zenoh objects. Requests are decoded at the
edge (requests.py) and submitted to the engine with a reply that maps the engine's answer
(a core value) to the protocol's message; commands come from the cmd_vel intake
(commands.py); ticks, events and the clock go out through the publisher (publisher.py).
Output and replies leave in the engine's order, so a spawn's reply always follows the
robot's first odometry and a delete's reply its last.

The encoding and the puts run on the adapter's own thread (:class:`Outbox`), so that the
simulation thread goes on with the next tick meanwhile: the daemon then uses both cores.
Everything the adapter sends goes through that one queue, in order; the queue is short, so a
publisher that falls behind slows the simulation down instead of piling up ticks.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping
from functools import partial
from typing import Any, cast

import msgspec
import numpy as np
import numpy.typing as npt
import zenoh

from protocol import listing
from protocol.codec import encode
from protocol.control import (
    Clock,
    ClockRequest,
    DeleteRequest,
    ListRequest,
    Observation,
    PackedCommands,
    PackedObservations,
    PauseRequest,
    Pose2D,
    Request,
    ResumeRequest,
    RobotList,
    RobotRecord,
    SpawnRequest,
    StepReply,
    StepRequest,
    WorldRequest,
)
from protocol.errors import ErrorCode, FleetError
from protocol.keys import Keys
from protocol.messages import Time
from protocol.navigation import NavigationRequest
from simd.adapters.fleet import requests
from simd.adapters.fleet.commands import CommandIntake
from simd.adapters.fleet.navigation import NavigationKeys
from simd.adapters.fleet.presence import Members
from simd.adapters.fleet.publisher import Publisher
from simd.adapters.zenoh_entities import undeclare_all
from simd.core import carry
from simd.core.snapshot import RobotState, TickSnapshot
from simd.core.worldfile import WorldGeometry
from simd.engine import Engine
from simd.engine.outbox import Outbox
from simd.engine.ports import Deleted, Event, Navigation, Result, Spawned, StepResult
from simd.engine.ports import RobotList as EngineRobotList
from simd.engine.status import Roster
from simd.wire import convert
from simd.wire.list_codec import RobotListEncoder

log = logging.getLogger(__name__)

#: a MessagePack list of more robots than this is written from the fleet's byte templates (a
#: page); of fewer, from their records (one robot by name: no layout of the fleet needed)
FEW_ROWS = 64
#: For how long after a list was asked the fleet's list is laid out again whenever the fleet
#: changes, before anybody asks (seconds).
LISTS_WARM_S = 30.0


class FleetAdapter:
    """Serves one engine on one zenoh session under one key prefix."""

    def __init__(
        self,
        session: zenoh.Session,
        keys: Keys,
        engine: Engine,
        daemon_id: str = "",
        members: Members | None = None,
        command_session: zenoh.Session | None = None,
    ) -> None:
        """``command_session``: where cmd_vel comes in, when not ``session`` (see
        :func:`simd.adapters.fleet.commands.command_session_needed`)."""
        self.keys = keys
        self.engine = engine
        self.daemon_id = daemon_id
        #: a fleet shared with other daemons (simd --join): spawns placed by name, deletes
        #: answered by the robot's daemon (docs/scale-out.md)
        self.members = members
        self._own: set[str] = set()  # names and namespaces of this daemon's robots (sim thread writes)
        #: each robot's record as its spawn made it (sim thread writes; lists read it)
        self._records: dict[str, RobotRecord] = {}
        #: the recent rosters' robots, and their index by name: see _name_index
        self._names_cache: carry.Recent[listing.NameIndex] = carry.Recent()
        #: the recent rosters' robots, and (their identities, their records in order): see _list_records
        self._list_cache: carry.Recent[tuple[npt.NDArray[np.uint64], list[RobotRecord]]] = carry.Recent()
        self._list_encoder = RobotListEncoder()
        #: when a list was last asked (monotonic s; 0: never): ticks lay out the next one while
        #: lists are being asked (see _warm_list)
        self._list_wanted = 0.0
        #: spawns answered at once whose robots the publisher announced then, by namespace: their
        #: Spawned events (and a Deleted event of that name before them) leave the publisher be
        self._announced: dict[str, int] = {}
        self._at_once = threading.Lock()  # spawns and deletes answered at once: answered and announced in order
        spec = engine.setup.lidar
        self.spec = spec
        self._world_info = convert.world_info(engine.setup.world)
        self.publisher = Publisher(session, keys, spec)
        self.commands = CommandIntake(command_session or session, keys)
        self.outbox = Outbox("fleet-out", on_room=engine.wake)  # the engine waits for room, never in a put
        # this daemon's clock alone, under its id: what its healthcheck asks in a shared fleet
        mine = [requests.Route(keys.daemon_clock(daemon_id), ClockRequest, acts=False)] if daemon_id else []
        self._queryables: list[Any] = requests.declare(session, keys, self._submit, mine)
        # declared with navigation off too: a goal is then refused saying why (--no-nav)
        self.navigation = NavigationKeys(session, keys, self._submit)
        engine.attach(self)

    # -- requests (zenoh threads) ---------------------------------------------------------------

    def _submit(self, request: Request | NavigationRequest, pending: requests.Pending) -> None:
        if self.members is not None:
            if not self._ours(request, pending):
                return
            if isinstance(request, StepRequest):
                request = self._for_here(request)
        if isinstance(request, (StepRequest, ResumeRequest)):
            for wanted in (*self.publisher.interests, *self.navigation.interests):
                wanted.refresh()  # who subscribed just before the step gets its ticks
        if isinstance(request, ListRequest):  # looking, or a refusal: answered here, never behind a tick
            try:
                listing.check(request)
            except FleetError as e:
                pending.error(e)
                return
            self._list_wanted = time.monotonic()  # ticks lay out the next list meanwhile
            if pending.fmt == "msgpack":
                pending.ok_encoded(self.msgpack_list(request))
            else:
                _answer(pending, self._robot_list(request))
            return
        if isinstance(request, (SpawnRequest, DeleteRequest)):
            with self._at_once:
                at_once = self.engine.answer_at_once(request)
                if isinstance(at_once, RobotState):
                    self._announce_at_once(request, at_once)
        else:
            at_once = self.engine.answer_at_once(request)
        if at_once is not None:
            _answer(pending, at_once if isinstance(at_once, FleetError) else self._message(at_once))
            if isinstance(request, DeleteRequest) and isinstance(at_once, RobotState):
                self.outbox.put_urgent(partial(self.publisher.drop_publishers, at_once.namespace))
            return
        lane = _lane(request)

        def send(result: Result | FleetError) -> None:
            _answer(pending, result if isinstance(result, FleetError) else self._message(result))

        def deliver(result: Result | FleetError) -> None:
            # a step's reply is what a lockstep client waits for, and nothing it needs can be
            # queued behind an idle outbox: sent at once, it saves a thread switch a step
            if (isinstance(result, StepResult) and self.outbox.idle()) or isinstance(result, FleetError):
                send(result)
            else:
                lane(self.outbox, result, partial(send, result))

        try:
            self.engine.submit(request, deliver)
        except FleetError as e:  # busy: refused on the spot, never queued behind the flood
            pending.error(e)

    def _announce_at_once(self, request: SpawnRequest | DeleteRequest, state: RobotState) -> None:
        """A spawn or delete answered at once (simd/engine/promises.py) is true for subscribers
        from its answer on, as one served between ticks: a spawned robot's token is declared
        (its first odometry comes with the next tick, which declares its publisher); a deleted
        one's token is gone and the tick being computed leaves it out (its publishers are
        undeclared after the answer). Declaring among 20 000 robots' costs ~10-15 ms each."""
        ns = state.namespace
        if isinstance(request, SpawnRequest):
            self._announced[ns] = self._announced.get(ns, 0) + 1
            work = partial(self.publisher.add_robot, state, self.engine.known().time, put=False)
            self.outbox.put_ordered(work, ns)
        else:
            self.outbox.put_urgent(partial(self.publisher.remove_robot, ns, self.engine.deleted_at(), publishers=False))

    def msgpack_list(self, request: ListRequest) -> bytes | bytearray:
        """The MessagePack answer to a list request (checked: listing.check) on the query's
        thread. The whole list and a page are written from byte templates of the robots'
        records (simd/wire/list_codec.py: 8 000 robots in a few ms instead of ~60; a page of
        1 000 among 20 000 just after a change in ~2.5 ms of CPU instead of ~8, most of it now
        ordering the names), a few robots from their records."""
        r = self.engine.roster_now()
        rows = None if listing.whole(request) else self._name_index(r).rows(request)
        if rows is None or len(rows) > FEW_ROWS:
            records = self._list_records(r)
            return self._list_encoder.encode(r.time, records, r.x, r.y, r.yaw, r.linear, r.angular, rows=rows)
        return encode(self._robot_list(request, r, rows))

    def _robot_list(self, request: ListRequest, roster: Roster | None = None, rows: list[int] | None = None
                    ) -> RobotList:  # fmt: skip
        """The robots a list request asks for (protocol/listing.py) from the engine's latest
        status (simd/engine/status.py), on the query's thread: each robot's record is kept from
        its spawn, with the pose and twist of now put in: a JSON list, and a few robots in
        MessagePack (:meth:`msgpack_list`). ``rows``: the request's rows of ``roster``, when the
        caller has them."""
        roster = roster if roster is not None else self.engine.roster_now()
        if listing.whole(request):
            records = self._list_records(roster)
            columns = (roster.x, roster.y, roster.yaw, roster.linear, roster.angular)
        else:  # some robots: their records looked up, not the fleet's laid out
            rows = rows if rows is not None else self._name_index(roster).rows(request)
            records = [self._record_of(roster, k) for k in rows]
            columns = (roster.x[rows], roster.y[rows], roster.yaw[rows], roster.linear[rows], roster.angular[rows])
        replace = msgspec.structs.replace
        robots = [replace(record, pose=Pose2D(x=x, y=y, yaw=yaw), linear_velocity=v, angular_velocity=w)
                  for record, x, y, yaw, v, w in zip(records, *(c.tolist() for c in columns), strict=True)]  # fmt: skip
        return RobotList(stamp=Time.from_seconds(roster.time), robots=robots)

    def _warm_list(self) -> None:
        """Lay out the list of the fleet as it is now, on the outbox thread, when the fleet has
        changed since the last list (the module docstring of simd/wire/list_codec.py): the next
        list asked only writes the pose and twist of now into bytes made beforehand. Making the
        records and their layout anew after a spawn or a delete took ~13 ms of CPU at 20 000
        robots on the query's thread, in a dozen numpy operations that each let go of the GIL
        and waited to get it back behind the simulation and the outbox threads: ~35 ms of a
        list's latency while the fleet ran (bench.overload)."""
        roster = self.engine.roster_now()
        if self._list_cache.get(roster.robots) is not None:
            return
        self._list_encoder.lay_out(self._list_records(roster))
        self._name_index(roster)

    def _name_index(self, roster: Roster) -> listing.NameIndex:
        """The roster's robots by name (made once per fleet: a roster's robots list is
        replaced when the fleet changes, kept otherwise)."""
        index = self._names_cache.get(roster.robots)
        if index is None:
            index = listing.NameIndex(roster.names, roster.namespaces)
            self._names_cache.put(roster.robots, index)
        return index

    def _list_records(self, roster: Roster) -> list[RobotRecord]:
        """Each robot's record as its spawn made it, in the roster's order (a robot deleted a
        moment ago: as it was). A new list only when the roster changes, made from the last
        one: the robots both rosters have keep their records, copied over in runs (found by
        identity, simd/core/carry.py), and only the others are looked up, where looking up
        20 000 robots took ~5 ms. A robot's record does not change while it lives."""
        cached = self._list_cache.get(roster.robots)
        if cached is not None:
            return cached[1]
        robots = roster.robots
        ids = carry.identities(robots)
        latest = self._list_cache.latest()
        before_ids, before = latest[1] if latest is not None else (carry.identities([]), [])
        source = carry.positions(before_ids, ids)
        listed: list[RobotRecord | None] = [None] * len(robots)
        for first, count, at in carry.runs(source):
            listed[first : first + count] = before[at : at + count]
        for k in np.flatnonzero(source < 0).tolist():
            listed[k] = self._record_of(roster, k)
        made = cast("list[RobotRecord]", listed)
        self._list_cache.put(robots, (ids, made))  # the robots held: their identities stay theirs
        return made

    def _record_of(self, roster: Roster, row: int) -> RobotRecord:
        """A robot's record as its spawn made it (one just deleted, or answered at once and not
        yet made: from what the roster says of it)."""
        robot = roster.robots[row]
        record = self._records.get(robot.namespace)
        if record is None or record.name != robot.name:
            state = RobotState(robot.name, robot.namespace, robot.model, 0.0, 0.0, 0.0, 0.0, 0.0, robot.spawn_pose)
            record = convert.robot_record(state, self.keys, self.daemon_id)
        return record

    def own_namespaces(self) -> set[str]:
        """The names and namespaces of this daemon's robots (a copy, for other threads)."""
        return set(self._own)

    def _ours(self, request: Request | NavigationRequest, pending: requests.Pending) -> bool:
        """In a shared fleet, whether this daemon answers: a spawn if the name is placed here
        (and is nobody's elsewhere), a delete if the robot is here or, when it is nowhere, if
        its name would be placed here (that one daemon says not found). Others let it pass."""
        assert self.members is not None
        if isinstance(request, SpawnRequest):
            if self.members.owner(request.name) != self.daemon_id:
                pending.skip()
                return False
            for key in {request.name, request.namespace or request.name}:
                if key not in self._own and self.members.alive(key):
                    field = "name" if key == request.name else "namespace"
                    message = f"Entity [{key}] already exists (on another daemon)"
                    pending.error(FleetError(ErrorCode.ALREADY_EXISTS, message, field))
                    return False
        elif isinstance(request, DeleteRequest) and not self._answers_delete(request.name):
            pending.skip()
            return False
        elif isinstance(request, NavigationRequest) and not self._answers_delete(request.robot):
            pending.skip()  # the robot's own daemon navigates it
            return False
        return True

    def _for_here(self, request: StepRequest) -> StepRequest:
        """A shared fleet's step as this daemon runs it: every daemon steps (the client waits
        for all of them), each commanding and observing its own robots; names alive on another
        daemon are left to it; a name alive nowhere (yet: a robot spawned a moment ago on another
        daemon may not have reached this one's membership) is left to the daemon it is placed
        on, which runs it or refuses it as unknown."""
        assert self.members is not None
        members, own = self.members, self._own

        def here(ns: str) -> bool:
            return ns in own or (not members.alive(ns) and members.owner(ns) == self.daemon_id)

        commands = request.commands
        if commands is not None and not all(here(n) for n in commands.names):
            keep = [k for k, n in enumerate(commands.names) if here(n)]
            twist = b"".join(commands.twist[16 * k : 16 * k + 16] for k in keep)
            commands = PackedCommands(names=[commands.names[k] for k in keep], twist=twist)
        return msgspec.structs.replace(
            request,
            cmd_vel={ns: tw for ns, tw in request.cmd_vel.items() if here(ns)},
            commands=commands,
            observe=[ns for ns in request.observe if here(ns)],
        )

    def _answers_delete(self, key: str) -> bool:
        assert self.members is not None
        if key in self._own:
            return True
        return not self.members.alive(key) and self.members.owner(key) == self.daemon_id

    def _message(self, result: Result) -> object:
        """The protocol's message for an engine answer."""
        if isinstance(result, RobotState):
            return convert.robot_record(result, self.keys, self.daemon_id)
        if isinstance(result, EngineRobotList):
            return RobotList(
                stamp=Time.from_seconds(result.time),
                robots=[convert.robot_record(s, self.keys, self.daemon_id) for s in result.robots],
            )
        if isinstance(result, WorldGeometry):
            return self._world_info
        if isinstance(result, StepResult):
            return self._step_reply(result)
        return result  # a Clock already is the message

    def _step_reply(self, result: StepResult) -> StepReply:
        fields = {f: getattr(result.clock, f) for f in result.clock.__struct_fields__}
        if result.packed is not None:
            p = result.packed
            packed = PackedObservations(
                names=p.names,
                samples=p.ranges.shape[1],
                # views on the arrays: the encoder copies them once, into the reply
                odom=np.ascontiguousarray(p.odom, dtype="<f8").data,
                scan_time=np.ascontiguousarray(p.scan_time, dtype="<f8").data,
                ranges=np.ascontiguousarray(p.ranges, dtype="<f4").data,
            )
            return StepReply(**fields, ticks_run=result.ticks_run, cancelled=result.cancelled, packed=packed)
        spec = self.spec
        stamp = result.clock.clock
        observations: dict[str, Observation] = {}
        for key, s in result.states.items():
            x, y, yaw = s.odom_pose  # what its odometry topic says (drifting with --odom-noise)
            odom = convert.odometry(
                s.namespace, stamp, x, y, yaw, s.linear_velocity, s.lateral_velocity, s.angular_velocity
            )
            row = result.scans.get(key)
            scan = None
            if row is not None:
                scan = convert.laser_scan(s.namespace, Time.from_seconds(row.time), spec, row.ranges)
            observations[key] = Observation(odom=odom, scan=scan)
        return StepReply(**fields, ticks_run=result.ticks_run, cancelled=result.cancelled, observations=observations)

    # -- the engine's side (simulation thread) ----------------------------------------------------

    def on_tick(self, snapshot: TickSnapshot) -> None:
        if self._list_wanted and self._list_wanted + LISTS_WARM_S > time.monotonic():
            # first: publishing a tick of 20 000 robots takes the outbox thread ~0.3 s, and a
            # list asked meanwhile would make the layout itself
            self.outbox.put(self._warm_list, wait=False)
        self.outbox.put(partial(self.publisher.publish_tick, snapshot))

    def on_event(self, event: Event) -> None:
        # _own and _records are changed in place, by this thread only: other threads test
        # membership, get one record or copy the set whole (each one C call under the GIL, never
        # half a change). Copying them at every change took ~2 ms of a spawn at 20 000 robots.
        if isinstance(event, Spawned):
            self._own.update((event.robot.name, event.robot.namespace))
        elif isinstance(event, Deleted):
            self._own.difference_update((event.robot.name, event.robot.namespace))
            if self.members is not None:
                self.members.left(event.robot.namespace)
        if isinstance(event, Spawned):
            robot = event.robot
            record = self._records[robot.namespace] = convert.robot_record(robot, self.keys, self.daemon_id)
            self.outbox.put(partial(self._list_encoder.prepare, record), wait=False)
            with self._at_once:
                announced = self._announced.pop(robot.namespace, 0)
                if announced > 1:
                    self._announced[robot.namespace] = announced - 1
            if not announced:  # (else declared with its answer)
                # a new robot's first odometry need not wait for ticks that do not name it
                self.outbox.put_ordered(partial(self.publisher.add_robot, robot, event.time), robot.namespace)
        elif isinstance(event, Deleted):
            self._records.pop(event.robot.namespace, None)
            self.outbox.put(partial(self._list_encoder.forget, event.robot.namespace), wait=False)
            # behind the ticks queued before it: they still name the robot
            # at once, so that the delete is answered at once; the ticks queued before it leave
            # the robot out, and its encoders are forgotten after them
            ns = event.robot.namespace
            with self._at_once:
                renewed = ns in self._announced  # a robot of that name answered at once since: its own now
            if not renewed:
                self.outbox.put_urgent(partial(self.publisher.remove_robot, ns, event.at))
            self.outbox.put(partial(self.publisher.forget, ns), wait=False)
            self.navigation.forget(event.robot.namespace)
        elif isinstance(event, Navigation):
            self.outbox.put(partial(self.navigation.publish, event.events), wait=False)

    def on_clock(self, clock: Clock) -> None:
        # at once, ahead of tick data: the clock topic is what tells a user the daemon lives (and
        # it keeps its own order, every clock sent from the simulation thread)
        self.outbox.put_urgent(partial(self.publisher.publish_clock, encode(clock)))

    def ready(self) -> bool:
        """Whether a tick handed over now is queued at once (the engine serves requests meanwhile)."""
        return self.outbox.has_room()

    def take_commands(self) -> Mapping[str, tuple[float, float]]:
        return self.commands.take()

    def drain_commands(self, most: int) -> bool:
        """Decode up to ``most`` waiting cmd_vel samples into the table :meth:`take_commands`
        hands out (the engine does this in chunks, serving requests between them); whether more
        may wait."""
        return self.commands.poll(most)

    def dropped_commands(self) -> int:
        return self.commands.dropped

    def close(self) -> None:
        if self.members is not None:
            self.members.close()
        undeclare_all(self._queryables)
        self.navigation.close()
        self.commands.close()
        self.outbox.close()
        self.publisher.close()


def _answer(pending: requests.Pending, message: object) -> None:
    if isinstance(message, FleetError):
        pending.error(message)
    else:
        pending.ok(message)


def _lane(request: object) -> Callable[[Outbox, Result, Callable[[], object]], None]:
    """Where a request's reply waits in the outbox: it follows what the request caused. A
    spawn's follows the robot's first odometry (behind nothing else); a delete's the robot's
    undeclaring, a pause's or resume's their clock (all sent at once); a reset's, a step's and
    navigation's follow the ticks and events queued before (the data lane: a client that reset
    must not hear of the old world after)."""
    if isinstance(request, SpawnRequest):
        return lambda outbox, result, work: outbox.put_ordered(work, getattr(result, "namespace", ""))
    if isinstance(request, (DeleteRequest, PauseRequest, ResumeRequest, ClockRequest, WorldRequest, ListRequest)):
        return lambda outbox, result, work: outbox.put_urgent(work)
    return lambda outbox, result, work: outbox.put(work, wait=False)
