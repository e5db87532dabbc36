"""The other daemons' robots of a shared fleet, for this daemon's physics and lidar.

Each ``--join`` daemon follows the fleet odometry topic ``P/odometry`` (every daemon publishes
its own robots' there while somebody listens) and keeps the latest pose of every robot that is
not its own and still alive (its ``P/<ns>/alive`` token, through :class:`Members`). The robots'
models come from the daemons' ``P/robots`` answers, asked once a second on a thread of the
feed's own (never on zenoh's callback threads). The engine takes the poses at each tick and the
core places them as kinematic bodies and lidar outlines: a robot sees and bumps into a robot on
another daemon, at the pose that daemon last published (a tick or two old: docs/scale-out.md).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import msgspec
import zenoh

from protocol.codec import decode
from protocol.control import RobotList
from protocol.errors import FleetError
from protocol.keys import Keys
from protocol.messages import FleetOdometry
from simd.adapters.fleet.presence import Members

#: how often the models of robots first seen are asked for (s)
MODELS_EVERY_S = 1.0

Ghosts = dict[str, tuple[str, float, float, float]]


class GhostFeed:
    """Latest poses of the fleet's robots on other daemons; see the module docstring."""

    def __init__(self, session: zenoh.Session, keys: Keys, members: Members, own: Callable[[], set[str]]) -> None:
        self._session, self._keys, self._members, self._own = session, keys, members, own
        self._lock = threading.Lock()
        self._poses: dict[str, tuple[float, float, float]] = {}
        self._models: dict[str, str] = {}
        self._changed = False
        self._seen_version = -1
        self._decoder = msgspec.msgpack.Decoder(FleetOdometry)
        self._sub: Any = session.declare_subscriber(keys.fleet_odom, self._on_odometry)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._ask_models, name="ghost-models", daemon=True)
        self._thread.start()

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

    def take(self) -> Ghosts | None:
        """The ghosts now (namespace -> (model, x, y, yaw)), or None if nothing changed."""
        with self._lock:
            if not self._changed and self._members.version == self._seen_version:
                return None  # no pose, model, arrival or departure since the last tick
            self._changed = False
            self._seen_version = self._members.version
            for ns in [ns for ns in self._poses if not self._members.alive(ns)]:
                del self._poses[ns]  # it left the fleet (deleted, or its daemon died)
            return {ns: (self._models[ns], *pose) for ns, pose in self._poses.items() if ns in self._models}

    def close(self) -> None:
        self._stop.set()
        self._sub.undeclare()
        self._thread.join(timeout=3.0)
