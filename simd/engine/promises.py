"""Spawns and deletes answered before the simulation thread makes them (issue 33).

A daemon with more robots than it keeps in real time spends ~120 ms in one physics step at
20 000 robots, and a spawn or delete served between ticks waited for it. When the answer is
certain from what the simulation thread last made known (simd/engine/status.py), it is given
at once and the request is queued as usual: a *promise*, made by the simulation thread before
its next tick, in the order asked. It is certain when nothing queued ahead of it can change it
(only promises are waiting, the caller checks) and:

- a spawn's names are free (counting the promises ahead), it fits under the robot limit, its
  pose is inside the world and off every wall (:class:`~simd.core.physics.Walls`, the same
  shapes), and no robot stands within ``MARGIN_M`` of its footprint's circle (robots deleted
  by a promise ahead do not count; they are gone first). A robot moves ~1 cm a tick, so the
  place is still free when the spawn is made; should a pushed robot have come nearer anyway,
  the spawn is made regardless and the physics parts them;
- a delete names a robot that is there (or promised).

Anything else (a name taken, a pose near a wall or a robot, a robot not found) is left to the
simulation thread, which answers as before. A promise's answer is what the simulation thread
would answer: a spawn's robot at rest at its pose, a deleted robot's last known state.
Not thread-safe: :class:`~simd.engine.at_once.AnsweredAtOnce` calls it under its lock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from protocol.control import DeleteRequest, SpawnRequest
from simd.core.models import MODELS, RobotModel
from simd.core.physics import Walls
from simd.core.robots import Robot
from simd.core.sim import Simulation, wrap_angle
from simd.core.snapshot import RobotState
from simd.engine.status import Roster

#: Room kept round a promised spawn beyond the robots' circles (m): what a robot could move
#: between the status it was checked against and the spawn, many times over.
MARGIN_M = 0.1
_WIDEST = max(m.radius for m in MODELS.values())


@dataclass(frozen=True)
class Promise:
    """A spawn or delete answered at once and queued for the simulation thread."""

    request: SpawnRequest | DeleteRequest
    #: the answer: the spawned robot at its pose, or the deleted robot's last known state
    state: RobotState

    @property
    def spawn(self) -> bool:
        return isinstance(self.request, SpawnRequest)


class Promises:
    """The promises not yet made, in order, and whether a new one can be given (see the
    module docstring)."""

    def __init__(self, sim: Simulation) -> None:
        self._sim = sim  # for its any-thread checks only (fields, bounds)
        # made now, with the engine: for the benchmark's arena of 20 000 robots it takes ~125 ms,
        # which the first spawn answered at once used to spend before its answer (issue 33)
        self._walls = Walls(sim.world)
        self.pending: list[Promise] = []
        #: the last roster made, with what it was made from: asked again before anything
        #: changed, the same one (a list keyed by its robots' identity then needs no new layout)
        self._made: tuple[Roster, tuple[Promise, ...], Roster] | None = None

    def __bool__(self) -> bool:
        return bool(self.pending)

    # -- the fleet as the promises leave it ------------------------------------------------

    def net(self) -> tuple[dict[str, Promise], set[str]]:
        """The spawns promised and not deleted after (by namespace), and the namespaces of
        robots there now that a promise deletes."""
        added: dict[str, Promise] = {}
        removed: set[str] = set()
        for p in self.pending:
            ns = p.state.namespace
            if p.spawn:
                added[ns] = p
            elif added.pop(ns, None) is None:
                removed.add(ns)
        return added, removed

    def count(self, robots_now: int) -> int:
        """How many robots there are once the promises are made."""
        added, removed = self.net()
        return robots_now + len(added) - len(removed)

    def roster(self, roster: Roster) -> Roster:
        """``roster`` as it is once the promises are made: the robots a promise deletes left out,
        those it spawns added at the end, at rest at their poses (as the simulation thread
        appends them). The same roster, asked again of the same promises, is the same object:
        every list asked while a promise waited made its records and their byte layout anew
        (~13 ms of CPU a list at 20 000 robots, with the GIL held)."""
        made = self._made
        if made is not None and made[0] is roster and _same(made[1], self.pending):
            return made[2]
        result = self._roster(roster)
        self._made = (roster, tuple(self.pending), result)
        return result

    def _roster(self, roster: Roster) -> Roster:
        added, removed = self.net()
        if not added and not removed:
            return roster
        # the rows of the robots deleted, found in C (a pass of Python over 20 000 robots took
        # ~5 ms of every list asked while a promise waited: issue 33)
        rows = sorted(_rows_of(roster.namespaces, removed), reverse=True)
        robots, names, namespaces = list(roster.robots), list(roster.names), list(roster.namespaces)
        for row in rows:
            del robots[row], names[row], namespaces[row]
        new = [p.state for p in added.values()]
        robots += [Robot(-1, s.name, s.namespace, s.model, s.spawn_pose, -1) for s in new]
        zeros = np.zeros(len(new))

        def column(values: np.ndarray, of_new: list[float] | np.ndarray) -> np.ndarray:
            return np.concatenate([np.delete(values, rows), np.asarray(of_new, dtype=np.float64)])

        return Roster(
            roster.time,
            robots,
            column(roster.x, [s.x for s in new]),
            column(roster.y, [s.y for s in new]),
            column(roster.yaw, [s.yaw for s in new]),
            column(roster.linear, zeros),
            column(roster.angular, zeros),
            column(roster.lateral, zeros),
            names + [s.name for s in new],
            namespaces + [s.namespace for s in new],
        )

    # -- promising ---------------------------------------------------------------------------

    def spawn(self, req: SpawnRequest, roster: Roster) -> RobotState | None:
        """The spawned robot, promised; or None: the simulation thread decides. The caller has
        checked the fields and the robot limit."""
        name, namespace, model = self._sim.check_spawn_fields(req)
        added, removed = self.net()
        taken = {k for p in added.values() for k in (p.state.name, p.state.namespace)}
        for key in {name, namespace}:
            row = roster.row(key)
            if key in taken or (row is not None and roster.robots[row].namespace not in removed):
                return None
        x, y, yaw = float(req.x), float(req.y), wrap_angle(float(req.yaw))
        if not self._clear(model, x, y, yaw, roster, added, removed):
            return None
        state = RobotState(name, namespace, model, x, y, yaw, 0.0, 0.0, (x, y, yaw), odom=(x, y, yaw))
        self.pending.append(Promise(req, state))
        return state

    def delete(self, req: DeleteRequest, roster: Roster) -> RobotState | None:
        """The deleted robot's last known state, promised; or None (the simulation thread says
        it is not there)."""
        added, removed = self.net()
        key = req.name
        state = next((p.state for p in added.values() if key in (p.state.name, p.state.namespace)), None)
        if state is None:
            row = roster.row(key)
            if row is None or roster.robots[row].namespace in removed:
                return None
            r = roster.robots[row]
            state = RobotState(r.name, r.namespace, r.model, float(roster.x[row]), float(roster.y[row]),
                               float(roster.yaw[row]), float(roster.linear[row]), float(roster.angular[row]),
                               r.spawn_pose, float(roster.lateral[row]))  # fmt: skip
        self.pending.append(Promise(req, state))
        return state

    def made(self) -> None:
        """The simulation thread has made the oldest promise (they are made in order)."""
        self.pending.pop(0)

    def _clear(self, model: RobotModel, x: float, y: float, yaw: float, roster: Roster,
               added: dict[str, Promise], removed: set[str]) -> bool:  # fmt: skip
        """Whether the footprint at this pose is inside the world, off the walls, and a margin
        clear of every robot's circle that will still be there."""
        if self._sim.outside(model, x, y, yaw):
            return False
        if self._walls.blocked(model, x, y, yaw):
            return False
        reach = model.radius + _WIDEST + MARGIN_M
        near = np.flatnonzero((roster.x - x) ** 2 + (roster.y - y) ** 2 < reach * reach)
        if any(roster.robots[i].namespace not in removed for i in near.tolist()):
            return False
        return all(
            math.hypot(p.state.x - x, p.state.y - y) >= model.radius + p.state.model.radius + MARGIN_M
            for p in added.values()
        )


def _rows_of(namespaces: list[str], wanted: set[str]) -> list[int]:
    """The rows of these namespaces (each searched for in C; one not there has none). Many of
    them (a fleet being cleared) in one pass instead."""
    if len(wanted) > 16:
        return [row for row, ns in enumerate(namespaces) if ns in wanted]
    rows = []
    for ns in wanted:
        try:
            rows.append(namespaces.index(ns))
        except ValueError:
            pass
    return rows


def _same(made_from: tuple[Promise, ...], pending: list[Promise]) -> bool:
    """The promises a roster was made from are the pending ones (the same objects)."""
    return len(made_from) == len(pending) and all(a is b for a, b in zip(made_from, pending, strict=True))
