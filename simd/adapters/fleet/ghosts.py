"""The other daemons' robots of a shared fleet, for this daemon's physics and lidar.

Before each tick every ``--join`` daemon puts its robots (names, models, true poses) on
``P/daemons/<id>/tick`` (:class:`DaemonTick`) and takes the others' as ghosts, which the core
keeps as kinematic bodies and lidar outlines (simd/core/ghosts.py): a robot sees and bumps into
a robot on another daemon. Two clocks, two ways of taking them:

- **Real time**: the latest tick each other daemon put, a tick or two old (docs/scale-out.md).
- **Stepped** (lockstep, or paused and stepped: ``sim/step`` reaches every daemon): the
  daemon waits until every other live daemon has put the same tick, so every daemon steps tick
  t against the others' poses at t - 1 whatever the timing, and a stepped fleet is
  deterministic across daemons. A daemon that does not step along (it refused the step, or it
  runs in real time) is waited for ``WAIT_S`` once, then not until it puts a tick again; one
  that dies leaves the fleet (its token) and is not waited for.

The poses are the true ones (not the odometry's, which drifts with ``--odom-noise``), and the
models travel with them: a robot is a ghost from the first tick its daemon puts.
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from typing import Any

import msgspec
import numpy as np
import zenoh

from protocol.control import DaemonTick
from protocol.keys import Keys
from simd.adapters.fleet.presence import Members
from simd.core.ghosts import GhostColumns
from simd.engine.ports import OwnRobots

log = logging.getLogger(__name__)

#: how long a stepping daemon waits for another's tick before it goes on without (s)
WAIT_S = 1.0
#: ticks of each daemon kept, for a daemon that runs a little ahead
TICKS_KEPT = 64


class GhostFeed:
    """The fleet's robots on other daemons; see the module docstring."""

    def __init__(self, session: zenoh.Session, keys: Keys, members: Members) -> None:
        self._members = members
        self._id = members.daemon_id
        self._arrived = threading.Condition()
        self._ticks: dict[str, collections.OrderedDict[int, DaemonTick]] = {}
        self._stalled: set[str] = set()
        self._used: list[DaemonTick] | None = None  # what the last columns were made of
        self._decoder = msgspec.msgpack.Decoder(DaemonTick)
        self._encoder = msgspec.msgpack.Encoder()
        self._pub: Any = session.declare_publisher(keys.daemon_tick(self._id))
        self._sub: Any = session.declare_subscriber(keys.daemon_tick("*"), self._on_tick)

    def _on_tick(self, sample: zenoh.Sample) -> None:
        try:
            msg = self._decoder.decode(sample.payload.to_bytes())
        except msgspec.DecodeError:
            return
        n = len(msg.namespaces)
        if msg.daemon == self._id or len(msg.poses) != 24 * n or len(msg.models) != n:
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

    def take(self, own: OwnRobots, stepping: bool) -> GhostColumns | None:
        """Put this daemon's robots for ``own.tick``, and return the others' (the same tick
        when ``stepping``, else the latest), or None when they are what they were."""
        others = [d for d in self._members.daemons() if d != self._id]
        if others:
            poses = np.stack([own.x, own.y, own.yaw], axis=1).astype("<f8")
            self._pub.put(self._encoder.encode(DaemonTick(
                daemon=self._id, tick=own.tick, namespaces=own.namespaces, models=own.models, poses=poses.tobytes(),
            )))  # fmt: skip
        with self._arrived:
            if stepping:
                self._wait(others, own.tick)
            chosen = [(d, m) for d in sorted(others) if (m := self._pick(d, own.tick, stepping)) is not None]
            for gone in [d for d in self._ticks if d not in others]:
                del self._ticks[gone]  # it left the fleet: its robots with it
        used = [m for _, m in chosen]
        last = self._used
        if last is not None and len(used) == len(last) and all(a is b for a, b in zip(used, last, strict=True)):
            return None  # the same messages as last tick: nothing moved
        self._used = used
        names = [ns for _, m in chosen for ns in m.namespaces]
        models = [model for _, m in chosen for model in m.models]
        rows = np.concatenate([np.frombuffer(m.poses, dtype="<f8") for _, m in chosen]) if chosen else np.zeros(0)
        rows = rows.reshape(-1, 3)
        return GhostColumns(names, models, rows[:, 0].copy(), rows[:, 1].copy(), rows[:, 2].copy())

    def _wait(self, others: list[str], tick: int) -> None:
        """Until every other stepping daemon has put ``tick`` (the lock held, released while waiting)."""
        deadline = time.monotonic() + WAIT_S
        while True:
            waiting = [d for d in others if d not in self._stalled and not self._has(d, tick)]
            left = deadline - time.monotonic()
            if not waiting or left <= 0:
                break
            self._arrived.wait(min(left, 0.05))  # short: a daemon that dies leaves ``others``
            others = [d for d in self._members.daemons() if d != self._id]
        for d in waiting:
            self._stalled.add(d)
            log.warning(
                "daemon %r did not step tick %d with this one within %.1f s; going on without it until it "
                "steps again (reset the fleet to step every daemon together)", d, tick, WAIT_S,
            )  # fmt: skip

    def _has(self, daemon: str, tick: int) -> bool:
        """Whether ``daemon``'s tick ``tick`` is here, or it is already past it (then its nearest is used)."""
        kept = self._ticks.get(daemon)
        return kept is not None and (tick in kept or next(reversed(kept)) > tick)

    def _pick(self, daemon: str, tick: int, stepping: bool) -> DaemonTick | None:
        """``daemon``'s robots: its latest tick in real time; stepped, its tick ``tick``, or
        the nearest it put (a daemon out of step)."""
        kept = self._ticks.get(daemon)
        if not kept:
            return None
        if not stepping:
            return kept[next(reversed(kept))]
        if tick in kept:
            return kept[tick]
        return min(kept.values(), key=lambda m: (abs(m.tick - tick), m.tick))

    def forget(self) -> None:
        """This daemon was reset, and with it the fleet: the ticks kept are of the old run."""
        with self._arrived:
            self._ticks.clear()
            self._used = None

    def close(self) -> None:
        self._sub.undeclare()
        self._pub.undeclare()
