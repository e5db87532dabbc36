"""The other daemons' robots of a shared fleet, for this daemon's physics and lidar.

The engine asks for them before each tick and the core places them as kinematic bodies and
lidar outlines: a robot sees and bumps into a robot on another daemon. Two clocks, two ways:

- **Real time.** Each ``--join`` daemon follows the fleet odometry topic ``P/odometry`` (every
  daemon publishes its own robots' there while somebody listens) and keeps the latest pose of
  every robot that is not its own and still alive (its ``P/<ns>/alive`` token, through
  :class:`Members`). The robots' models come from the daemons' ``P/robots`` answers, asked
  once a second on a thread of the feed's own (never on zenoh's callback threads). A ghost
  stands where its daemon last published it: a tick or two old.
- **Stepped** (lockstep, or paused and stepped: ``sim/step`` reaches every daemon). Before each
  tick a daemon puts its robots (true poses and models) on ``P/daemons/<id>/tick`` and waits
  until every other live daemon has put the same tick, then places theirs. Every daemon thus
  steps tick t against the others' poses at t - 1 whatever the timing, and a stepped fleet is
  deterministic across daemons. A daemon that does not step along (it refused the step, or it
  runs in real time) is waited for ``WAIT_S`` once, then not until it puts a tick again; one
  that dies leaves the fleet (its token) and is not waited for.
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import msgspec
import numpy as np
import zenoh

from protocol.codec import decode
from protocol.control import DaemonTick, RobotList
from protocol.errors import FleetError
from protocol.keys import Keys
from protocol.messages import FleetOdometry
from simd.adapters.fleet.presence import Members
from simd.engine.ports import OwnRobots

log = logging.getLogger(__name__)

#: how often the models of robots first seen are asked for (s)
MODELS_EVERY_S = 1.0
#: how long a stepping daemon waits for another's tick before it goes on without (s)
WAIT_S = 1.0
#: ticks of each daemon kept, for a daemon that runs a little ahead
TICKS_KEPT = 64

Ghosts = dict[str, tuple[str, float, float, float]]


class GhostFeed:
    """The fleet's robots on other daemons; see the module docstring."""

    def __init__(self, session: zenoh.Session, keys: Keys, members: Members, own: Callable[[], set[str]]) -> None:
        self._session, self._keys, self._members, self._own = session, keys, members, own
        self._id = members.daemon_id
        self._lock = threading.Lock()
        self._poses: dict[str, tuple[float, float, float]] = {}
        self._models: dict[str, str] = {}
        self._changed = False
        self._seen_version = -1
        self._decoder = msgspec.msgpack.Decoder(FleetOdometry)
        # stepped: what each other daemon put, by tick, and those that did not step along
        self._arrived = threading.Condition(self._lock)
        self._ticks: dict[str, collections.OrderedDict[int, DaemonTick]] = {}
        self._stalled: set[str] = set()
        self._tick_decoder = msgspec.msgpack.Decoder(DaemonTick)
        self._tick_pub: Any = session.declare_publisher(keys.daemon_tick(self._id))
        self._subs: list[Any] = [
            session.declare_subscriber(keys.fleet_odom, self._on_odometry),
            session.declare_subscriber(keys.daemon_tick("*"), self._on_tick),
        ]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._ask_models, name="ghost-models", daemon=True)
        self._thread.start()

    # -- real time ------------------------------------------------------------------------------

    def _on_odometry(self, sample: zenoh.Sample) -> None:
        try:
            msg = self._decoder.decode(sample.payload.to_bytes())
        except msgspec.DecodeError:
            return
        own = self._own()
        rows = zip(msg.namespaces, msg.array("x").tolist(), msg.array("y").tolist(), msg.array("yaw").tolist(),
                   strict=True)  # fmt: skip
        with self._lock:
            for ns, x, y, yaw in rows:
                if ns not in own:
                    self._poses[ns] = (x, y, yaw)
                    self._changed = True

    def _ask_models(self) -> None:
        while not self._stop.wait(MODELS_EVERY_S):
            with self._lock:
                unknown = [ns for ns in self._poses if ns not in self._models]
            if not unknown:
                continue
            try:
                replies = self._session.get(f"{self._keys.robots}?format=msgpack", timeout=2.0,
                                            target=zenoh.QueryTarget.ALL,
                                            consolidation=zenoh.ConsolidationMode.NONE)  # fmt: skip
                found = {}
                for reply in replies:
                    if reply.ok is not None:
                        for r in decode(reply.ok.payload.to_bytes(), RobotList).robots:
                            found[r.namespace] = r.model
            except (FleetError, zenoh.ZError):
                continue
            with self._lock:
                self._models.update(found)
                self._changed = True

    def _latest(self) -> Ghosts | None:
        with self._lock:
            if not self._changed and self._members.version == self._seen_version:
                return None  # no pose, model, arrival or departure since the last tick
            self._changed = False
            self._seen_version = self._members.version
            for ns in [ns for ns in self._poses if not self._members.alive(ns)]:
                del self._poses[ns]  # it left the fleet (deleted, or its daemon died)
            return {ns: (self._models[ns], *pose) for ns, pose in self._poses.items() if ns in self._models}

    # -- stepped --------------------------------------------------------------------------------

    def _on_tick(self, sample: zenoh.Sample) -> None:
        try:
            msg = self._tick_decoder.decode(sample.payload.to_bytes())
        except msgspec.DecodeError:
            return
        if (
            msg.daemon == self._id
            or len(msg.poses) != 24 * len(msg.namespaces)
            or len(msg.models) != len(msg.namespaces)
        ):
            return
        with self._arrived:
            kept = self._ticks.setdefault(msg.daemon, collections.OrderedDict())
            if kept and msg.tick <= next(reversed(kept)):
                kept.clear()  # its clock went back: it was reset, the ticks kept are of the old run
            kept[msg.tick] = msg
            while len(kept) > TICKS_KEPT:
                kept.popitem(last=False)
            self._stalled.discard(msg.daemon)
            self._arrived.notify_all()

    def _stepped(self, mine: OwnRobots) -> Ghosts:
        """Put this daemon's robots for ``mine.tick`` and return the others' of the same tick."""
        poses = np.stack([mine.x, mine.y, mine.yaw], axis=1).astype("<f8")
        self._tick_pub.put(msgspec.msgpack.encode(DaemonTick(
            daemon=self._id, tick=mine.tick, namespaces=mine.namespaces, models=mine.models, poses=poses.tobytes(),
        )))  # fmt: skip
        tick, deadline = mine.tick, time.monotonic() + WAIT_S
        with self._arrived:
            while True:
                others = [d for d in self._members.daemons() if d != self._id]
                waiting = [d for d in others if d not in self._stalled and not self._has(d, tick)]
                left = deadline - time.monotonic()
                if not waiting or left <= 0:
                    break
                self._arrived.wait(min(left, 0.05))  # short: a daemon that dies leaves ``others``
            for d in waiting:
                self._stalled.add(d)
                log.warning(
                    "daemon %r did not step tick %d with this one within %.1f s; going on without it until it "
                    "steps again (reset the fleet to step every daemon together)", d, tick, WAIT_S,
                )  # fmt: skip
            ghosts: Ghosts = {}
            for d in sorted(others):  # one order on every daemon: bodies are added in it
                msg = self._at(d, tick)
                if msg is None:
                    continue
                rows = np.frombuffer(msg.poses, dtype="<f8").reshape(-1, 3).tolist()
                for ns, model, (x, y, yaw) in zip(msg.namespaces, msg.models, rows, strict=True):
                    ghosts[ns] = (model, x, y, yaw)
            self._changed = True  # back in real time, the next take gives the topic's poses again
            return ghosts

    def _has(self, daemon: str, tick: int) -> bool:
        """Whether ``daemon``'s tick ``tick`` is here, or it is already past it (then its nearest is used)."""
        kept = self._ticks.get(daemon)
        return kept is not None and (tick in kept or next(reversed(kept)) > tick)

    def _at(self, daemon: str, tick: int) -> DaemonTick | None:
        """``daemon``'s robots at ``tick``, or at the nearest tick it put (a daemon out of step)."""
        kept = self._ticks.get(daemon)
        if not kept:
            return None
        if tick in kept:
            return kept[tick]
        return min(kept.values(), key=lambda m: (abs(m.tick - tick), m.tick))

    # -- both -----------------------------------------------------------------------------------

    def forget(self) -> None:
        """This daemon was reset, and with it the fleet: the ticks kept are of the old run."""
        with self._arrived:
            self._ticks.clear()

    def take(self, stepping: OwnRobots | None) -> Ghosts | None:
        """The ghosts now (namespace -> (model, x, y, yaw)), or None if nothing changed."""
        return self._latest() if stepping is None else self._stepped(stepping)

    def close(self) -> None:
        self._stop.set()
        for s in self._subs:
            s.undeclare()
        self._tick_pub.undeclare()
        self._thread.join(timeout=3.0)
