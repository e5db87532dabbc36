"""Who serves the fleet: each daemon's liveliness token ``P/daemons/<id>`` and its answer on
``P/daemons``.

A daemon announces itself so that clients, routers and other daemons can see which daemons
serve a key space, and for how long (the token goes when the daemon does, however it dies).
Until daemons can share one fleet (issue "scale-out": spawns placed on one daemon, one list,
robots that see each other across daemons), two daemons on one key space would both answer
every spawn and each list only their own robots; a daemon therefore refuses to start where
another already serves its prefix, and says how to run beside it. In a shared fleet two
daemons with one ``--id`` would answer as one, so a joining daemon with an id taken is refused.

Who is there is asked, not listened for: a liveliness query (the tokens the network knows) and
a query on ``P/daemons`` that every daemon answers, each ending as soon as every answer is in
(zenoh's final reply), which on one network is milliseconds and does not depend on how busy
the fleet is. The bound ``ASK_S`` only stops a wait for a fleet that cannot answer at all, and
a daemon that meets it does not start (:class:`Unanswered`): never a guess from silence. Two
daemons started with one id at the same moment both pass that look; each then looks again
with its own answer declared, and the later of the two leaves (:func:`twin`).
"""

from __future__ import annotations

import os
import socket
import threading
import time
from typing import Any, TypeVar

import zenoh

from protocol import placement
from protocol.codec import decode
from protocol.control import Clock, DaemonInfo
from protocol.errors import FleetError
from protocol.keys import Keys
from simd.adapters.fleet.requests import Pending, reply_format

T = TypeVar("T")

#: the most a starting daemon waits for the fleet's answers (they end in milliseconds: see the
#: module docstring); a fleet that has not answered by then keeps the daemon from starting
ASK_S = 30.0


class Unanswered(Exception):
    """The fleet did not finish answering within the bound: who serves the prefix is unknown."""

    def __init__(self, what: str, timeout: float) -> None:
        super().__init__(f"no complete answer on {what} within {timeout:g} s: cannot tell which daemons serve it")


def serving(session: zenoh.Session, keys: Keys, timeout: float = ASK_S) -> list[str]:
    """The ids of the daemons that serve ``keys``' prefix on this network now (their tokens)."""
    found = []
    head = keys.daemon("")
    began = time.monotonic()
    for reply in session.liveliness().get(keys.daemon("*"), timeout=timeout):
        if reply.ok is not None:
            found.append(str(reply.ok.key_expr)[len(head) :])
    if time.monotonic() - began >= timeout:
        raise Unanswered(keys.daemon("*"), timeout)
    return sorted(found)


def _answers(session: zenoh.Session, key: str, reply_type: type[T], timeout: float, complete: bool = False) -> list[T]:
    """Every daemon's answer on ``key`` (target all, no consolidation); others' replies left
    out. ``complete``: raise :class:`Unanswered` if the bound ended the query."""
    found = []
    began = time.monotonic()
    for reply in session.get(
        f"{key}?format=msgpack",
        timeout=timeout,
        target=zenoh.QueryTarget.ALL,
        consolidation=zenoh.ConsolidationMode.NONE,
    ):
        if reply.ok is not None:
            try:
                found.append(decode(reply.ok.payload.to_bytes(), reply_type))
            except FleetError:
                continue  # not a daemon of ours
    if complete and time.monotonic() - began >= timeout:
        raise Unanswered(key, timeout)
    return found


def infos(session: zenoh.Session, keys: Keys, timeout: float = ASK_S) -> list[DaemonInfo]:
    """What every daemon serving ``keys``' prefix says of itself (``P/daemons``), all of them
    (raises :class:`Unanswered` if they did not all answer within ``timeout``)."""
    return _answers(session, keys.daemons, DaemonInfo, timeout, complete=True)


def twin(session: zenoh.Session, keys: Keys, me: DaemonInfo, timeout: float = ASK_S) -> DaemonInfo | None:
    """Another daemon with this one's id that started first (by its start time, then its zenoh
    id), asked once this one's own answer is declared: of two started at once, the later
    leaves."""
    rank = (me.started, me.zid)
    same = [i for i in infos(session, keys, timeout) if i.id == me.id and i.zid != me.zid and (i.started, i.zid) < rank]
    return min(same, key=lambda i: (i.started, i.zid)) if same else None


def fleet_tick(session: zenoh.Session, keys: Keys, timeout: float = ASK_S) -> int | None:
    """The tick the fleet's daemons are at (the latest of their clocks), None if none answers:
    a daemon that joins starts its clock there, so that the fleet steps its ticks together."""
    ticks = [c.tick for c in _answers(session, keys.clock, Clock, timeout)]
    return max(ticks) if ticks else None


def refusal(
    others: list[str], infos_there: list[DaemonInfo], daemon_id: str, world: str, join: bool, prefix: str
) -> str | None:
    """Why this daemon may not serve ``prefix`` beside the daemons ``others`` (None: it may)."""
    if not others:
        return None
    if not join:
        return (
            f"daemon {others[0]!r} already serves prefix {prefix!r} on this network (fleet daemons lists it): "
            "run this one with another --prefix, or start every daemon of one fleet with --join"
        )
    if daemon_id in others:
        return f"a daemon with --id {daemon_id!r} already serves prefix {prefix!r}: give this one another --id"
    for info in sorted(infos_there, key=lambda i: i.id):
        if not info.shared:
            return (
                f"daemon {info.id!r} serves prefix {prefix!r} without --join: a fleet is shared only when "
                "every daemon of it is started with --join"
            )
        if info.world != world:
            return f"the fleet at prefix {prefix!r} runs world {info.world!r} (daemon {info.id!r}), this one {world!r}"
    return None


class Presence:
    """The daemon's token and its answer on ``P/daemons``, for as long as it runs."""

    def __init__(self, session: zenoh.Session, keys: Keys, daemon_id: str, world: str, shared: bool = False) -> None:
        self.info = DaemonInfo(
            id=daemon_id,
            world=world,
            shared=shared,
            host=socket.gethostname(),
            pid=os.getpid(),
            zid=str(session.zid()),
            started=time.time(),
        )
        self._token = session.liveliness().declare_token(keys.daemon(daemon_id))
        self._queryable: Any = session.declare_queryable(keys.daemons, self._on_query)
        self._key = keys.daemons

    def _on_query(self, query: zenoh.Query) -> None:
        payload = query.payload.to_bytes() if query.payload is not None else b""
        fmt = reply_format(query, payload)
        Pending(query, self._key, fmt).ok(self.info)

    def close(self) -> None:
        self._queryable.undeclare()
        self._token.undeclare()


class Members:
    """The live daemons of a shared fleet and the robots alive anywhere in it, from liveliness
    (``P/daemons/*`` and ``P/*/alive``, with history so that those already there count): what
    a daemon needs to place spawns and keep names unique across daemons."""

    def __init__(self, session: zenoh.Session, keys: Keys, daemon_id: str) -> None:
        self.daemon_id = daemon_id
        self._lock = threading.Lock()
        self._daemons: set[str] = {daemon_id}
        self._alive: set[str] = set()
        self.version = 0  # counts the robots' arrivals and departures
        self._head_daemon, self._keys = keys.daemon(""), keys
        self._subs: list[Any] = [
            session.liveliness().declare_subscriber(keys.daemon("*"), self._on_daemon, history=True),
            session.liveliness().declare_subscriber(keys.alive("*"), self._on_robot, history=True),
        ]

    def _on_daemon(self, sample: zenoh.Sample) -> None:
        daemon_id = str(sample.key_expr)[len(self._head_daemon) :]
        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self._daemons.add(daemon_id)
            elif daemon_id != self.daemon_id:
                self._daemons.discard(daemon_id)

    def _on_robot(self, sample: zenoh.Sample) -> None:
        ns = self._keys.namespace_of(str(sample.key_expr))
        if ns is None:
            return
        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self._alive.add(ns)
            else:
                self._alive.discard(ns)
            self.version += 1  # readers that cache what is alive look again

    def left(self, namespace: str) -> None:
        """This daemon deleted its robot ``namespace``: the name is free at once, not only when
        the undeclared token's removal has come back round through the router (a spawn of the
        same name right after the delete was refused as existing elsewhere)."""
        with self._lock:
            if namespace in self._alive:
                self._alive.discard(namespace)
                self.version += 1

    def daemons(self) -> list[str]:
        with self._lock:
            return sorted(self._daemons)

    def owner(self, name: str) -> str:
        """The daemon that places ``name`` among the live ones (protocol/placement.py)."""
        return placement.owner(name, self.daemons())

    def alive(self, namespace: str) -> bool:
        """Whether a robot with this namespace lives anywhere in the fleet."""
        with self._lock:
            return namespace in self._alive

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()
