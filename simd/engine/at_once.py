"""The control plane answered on the asking thread: what needs nothing of the simulation
thread is answered from what that thread last made known, so looking never waits behind a
tick however long ticks take (issue 33: a daemon that never goes deaf).

:class:`AnsweredAtOnce` is a part of :class:`~simd.engine.engine.Engine`, kept apart because it
is the one part other threads call: the clock, the robot list's status, the world, a spawn
refused at the robot limit, and, while the simulation runs, a pause, the resume that follows
a pause not yet served, and the spawns and deletes whose answer is certain
(simd/engine/promises.py). Those are queued for the simulation thread as usual, with nothing
asked before them still waiting but other answers given at once, and answered now: the loop
serves every queued request before it starts a tick, so each takes effect before the next
tick, in the order asked. After a pause the loop starts no tick until it has served it, so
the reply names the last tick there will be. The lock ``_gate`` makes what these replies say,
the requests still queued and the ticks the loop starts agree.
"""

from __future__ import annotations

import dataclasses
import math
import queue
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from protocol.control import (
    Clock,
    ClockRequest,
    DeleteRequest,
    PauseRequest,
    Request,
    ResumeRequest,
    SpawnRequest,
    WorldRequest,
)
from protocol.errors import ErrorCode, FleetError
from simd.core.sim import Simulation
from simd.core.snapshot import RobotState
from simd.engine.capacity import limit_refusal
from simd.engine.ports import Adapter, GhostSource, PlaceRequest, Reply, Result
from simd.engine.promises import Promises
from simd.engine.status import Roster, Status

if TYPE_CHECKING:
    from protocol.navigation import NavigationRequest


@dataclass
class Call:
    """A request waiting in the simulation thread's inbox, and how to answer it. ``waits``:
    its asker waits for the simulation thread's answer (it was not answered at once)."""

    request: Request | NavigationRequest | PlaceRequest
    reply: Reply
    waits: bool = False


def ignore(result: Result | FleetError) -> None:
    """The reply of a pause or resume already answered."""


def promised(result: Result | FleetError) -> None:
    """The reply of a spawn or delete already answered (simd/engine/promises.py)."""


class AnsweredAtOnce:
    """The requests any thread may answer (a part of ``Engine``; the module docstring)."""

    # the engine's, which these methods read
    sim: Simulation
    adapters: list[Adapter]
    _inbox: queue.Queue[Call | str | None]
    _wall: Callable[[], float]
    ghost_source: GhostSource | None

    def _status(self, measured_cost: bool = True) -> Status:
        raise NotImplementedError

    def _init_at_once(self) -> None:
        self._gate = threading.Lock()
        self._control: list[bool] = []  # pauses (True) and resumes answered at once, not yet served
        self._promises = Promises(self.sim)  # spawns and deletes answered at once, not yet made
        self._waiting = 0  # requests queued whose askers wait for the simulation thread
        self._ticking = False  # a tick has started and its status is not known yet
        self._known = self._status()

    def _queue(self, call: Call) -> None:
        """Queue a request for the simulation thread (raises queue.Full)."""
        with self._gate:
            self._inbox.put_nowait(call)
            if call.waits:
                self._waiting += 1

    def answer_at_once(self, request: Request | NavigationRequest | PlaceRequest) -> Result | FleetError | None:
        """The answer to a request that need not wait for the simulation thread, on the caller's
        thread, or None (then :meth:`submit` it): the clock and the robot list from what the
        simulation thread last made known (simd/engine/status.py), the world, the refusal of a
        spawn while the robot limit is reached, and, while running, a pause, the resume of a
        pause not yet served, and a spawn or delete whose answer is certain; those with an
        effect are queued here all the same, in the order answered (the module docstring). So
        looking, and changing the fleet, never wait behind a tick, however long ticks take. Any
        thread may call it."""
        if isinstance(request, (ClockRequest, PauseRequest, ResumeRequest)):
            return self._clock_at_once(request)
        if isinstance(request, WorldRequest):
            return self.sim.world
        if isinstance(request, (SpawnRequest, DeleteRequest)):
            return self._change_at_once(request)
        return None

    def known(self) -> Status:
        """What the simulation thread last made known (any thread)."""
        return self._known

    def roster_now(self) -> Roster:
        """The robots as the simulation thread last made them known, with the spawns and
        deletes already answered (any thread)."""
        with self._gate:
            status = self._known
            return self._promises.roster(status.roster) if self._promises else status.roster

    def _may_promise(self, status: Status) -> bool:
        """Whether an answer given now is the one the simulation thread will give: it runs
        (so no step is under way; a pause or resume answered at once changes no robot),
        nothing asked before is still waiting for it but answers already given, and no other
        daemon's robots share the floor (their ghosts come with the ticks)."""
        return not (status.paused or status.lockstep or self._waiting or self.ghost_source)

    def _change_at_once(self, request: SpawnRequest | DeleteRequest) -> RobotState | FleetError | None:
        """A spawn refused at the robot limit, or a spawn or delete whose answer is certain
        (simd/engine/promises.py), answered on the caller's thread; None: the simulation
        thread answers it."""
        with self._gate:
            status = self._known
            if isinstance(request, SpawnRequest):
                try:
                    self.sim.check_spawn_fields(request)  # a bad field is refused first, as the simulation thread would
                except FleetError as e:
                    return e
                if self._promises.count(status.robots) >= status.max_robots:
                    return limit_refusal(status.max_robots, status.capacity_robots)
            if not self._may_promise(status):
                return None
            if isinstance(request, SpawnRequest):
                state = self._promises.spawn(request, status.roster)
            else:
                state = self._promises.delete(request, status.roster)
            if state is None:
                return None
            try:
                self._inbox.put_nowait(Call(request, promised))
            except queue.Full:
                self._promises.pending.pop()
                return FleetError(ErrorCode.BUSY, "the daemon is busy: too many pending requests; retry")
            return state

    def deleted_at(self) -> tuple[int, int]:
        """The (epoch, tick) a delete answered now leaves at: the last tick there is before it
        is made (the one being computed, if any). Ticks up to it leave the robot out."""
        with self._gate:
            status = self._known
            return status.epoch, status.tick + (1 if self._ticking else 0)

    def _clock_at_once(self, request: ClockRequest | PauseRequest | ResumeRequest) -> Clock | FleetError | None:
        """The clock, a pause of a running simulation, or the resume of a pause not yet served,
        answered on the caller's thread.

        A pause is queued for the simulation thread as usual (in its order among the other
        requests; it does the pausing: steps cancelled, the clock topic told), but answered now:
        from here on the loop starts no tick until it has served it, so the reply names the last
        tick there will be (the one being computed, if any) and says paused, and so does every
        clock asked meanwhile. A resume asked before that pause is served is answered now too:
        the simulation thread serves the two in order before any tick, and the clock it answers
        runs again from the pause's last tick at the target factor (the resume's own, measured
        from its first tick). Paused already, the simulation thread answers either as before."""
        with self._gate:
            status = self._known
            if isinstance(request, (PauseRequest, ResumeRequest)):
                pause = isinstance(request, PauseRequest)
                if status.paused or status.lockstep:
                    return None
                if not pause and (self._waiting or not (self._control and self._control[-1])):
                    return None  # running, no pause asked: the simulation thread says nothing changed
                try:
                    self._inbox.put_nowait(Call(request, ignore))
                except queue.Full:
                    return FleetError(ErrorCode.BUSY, "the daemon is busy: too many pending requests; retry")
                self._control.append(pause)
            if self._promises:
                status = dataclasses.replace(status, robots=self._promises.count(status.robots))
            if self._control and not status.paused:
                last = status.tick + (1 if self._ticking else 0)
                if self._control[-1]:
                    status = dataclasses.replace(status, paused=True, tick=last, time=last * status.dt,
                                                 real_time_factor=0.0, falling_behind=False)  # fmt: skip
                else:  # running again from the pause's last tick; nothing slipped yet
                    status = dataclasses.replace(status, tick=last, time=last * status.dt,
                                                 real_time_factor=status.target_rtf, falling_behind=False,
                                                 slipped_s=0.0, next_deadline=math.inf)  # fmt: skip
        return status.clock(self._wall(), self._dropped())

    def _dropped(self) -> int:
        return sum(a.dropped_commands() for a in self.adapters)

    def _make_known(self, served: Call | None = None) -> None:
        """Publish the engine's status for other threads (none without adapters: a local fleet),
        at once with the end of a tick being computed and with the request just ``served``
        leaving the queue (a pause, resume, spawn or delete answered at once: now made)."""
        status = self._status() if self.adapters else self._known
        with self._gate:
            self._known = status
            self._ticking = False
            if served is not None:
                if served.waits:
                    self._waiting -= 1
                elif served.reply is ignore and self._control:
                    self._control.pop(0)
                elif served.reply is promised:
                    self._promises.made()

    def _start_tick(self) -> bool:
        """Whether the loop may start a tick now (no pause asked, nothing queued): then it is
        being computed."""
        with self._gate:  # a request queued before this is served first (a promise: before the tick)
            self._ticking = not self._control and self._inbox.empty()
            return self._ticking
