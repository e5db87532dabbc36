"""The control plane answered on the asking thread: what needs nothing of the simulation
thread is answered from what that thread last made known, so looking never waits behind a
tick however long ticks take (issue 33: a daemon that never goes deaf).

:class:`AnsweredAtOnce` is a part of :class:`~simd.engine.engine.Engine`, kept apart because it
is the one part other threads call: the clock, the robot list's status, the world, a spawn
refused at the robot limit, and a pause of a running simulation. A pause is queued for the
simulation thread as usual but answered at once; from then on the loop starts no tick until it
has served it, so the reply names the last tick there will be. The lock ``_gate`` makes what a
pause's reply says and the ticks the loop still starts agree.
"""

from __future__ import annotations

import dataclasses
import queue
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from protocol.control import Clock, ClockRequest, PauseRequest, Request, SpawnRequest, WorldRequest
from protocol.errors import ErrorCode, FleetError
from simd.core.sim import Simulation
from simd.engine.capacity import limit_refusal
from simd.engine.ports import Adapter, PlaceRequest, Reply, Result
from simd.engine.status import Status

if TYPE_CHECKING:
    from protocol.navigation import NavigationRequest


@dataclass
class Call:
    """A request waiting in the simulation thread's inbox, and how to answer it."""

    request: Request | NavigationRequest | PlaceRequest
    reply: Reply


def ignore(result: Result | FleetError) -> None:
    """The reply of a request already answered (a pause answered at once)."""


class AnsweredAtOnce:
    """The requests any thread may answer (a part of ``Engine``; the module docstring)."""

    # the engine's, which these methods read
    sim: Simulation
    adapters: list[Adapter]
    _inbox: queue.Queue[Call | str | None]
    _wall: Callable[[], float]

    def _status(self, measured_cost: bool = True) -> Status:
        raise NotImplementedError

    def _init_at_once(self) -> None:
        self._gate = threading.Lock()
        self._pauses_asked = 0  # pauses answered at once and not yet served
        self._ticking = False  # a tick has started and its status is not known yet
        self._known = self._status()

    def answer_at_once(self, request: Request | NavigationRequest | PlaceRequest) -> Result | FleetError | None:
        """The answer to a request that needs nothing of the simulation thread, on the caller's
        thread, or None (then :meth:`submit` it): the clock and the robot list from what the
        simulation thread last made known (simd/engine/status.py), the world, and the refusal
        of a spawn while the robot limit is reached. So looking never waits behind a tick, however
        long ticks take. Every request answered here has no effect to be ordered after; any
        thread may call it."""
        if isinstance(request, (ClockRequest, PauseRequest)):
            return self._clock_at_once(request)
        status = self._known
        if isinstance(request, WorldRequest):
            return self.sim.world
        if isinstance(request, SpawnRequest) and status.robots >= status.max_robots:
            try:
                self.sim.check_spawn_fields(request)  # a bad field is refused first, as the simulation thread would
            except FleetError as e:
                return e
            return limit_refusal(status.max_robots, status.capacity_robots)
        return None

    def known(self) -> Status:
        """What the simulation thread last made known (any thread)."""
        return self._known

    def _clock_at_once(self, request: ClockRequest | PauseRequest) -> Clock | FleetError | None:
        """The clock, or a pause of a running simulation, answered on the caller's thread.

        A pause is queued for the simulation thread as usual (in its order among the other
        requests; it does the pausing: steps cancelled, the clock topic told), but answered now:
        from here on the loop starts no tick until it has served it, so the reply names the last
        tick there will be (the one being computed, if any) and says paused, and so does every
        clock asked meanwhile. Paused already, the simulation thread answers it as before."""
        with self._gate:
            status = self._known
            if isinstance(request, PauseRequest):
                if status.paused or status.lockstep:
                    return None
                try:
                    self._inbox.put_nowait(Call(request, ignore))
                except queue.Full:
                    return FleetError(ErrorCode.BUSY, "the daemon is busy: too many pending requests; retry")
                self._pauses_asked += 1
            if self._pauses_asked and not status.paused:
                last = status.tick + (1 if self._ticking else 0)
                status = dataclasses.replace(status, paused=True, tick=last, time=last * status.dt,
                                             real_time_factor=0.0, falling_behind=False)  # fmt: skip
        return status.clock(self._wall(), self._dropped())

    def _dropped(self) -> int:
        return sum(a.dropped_commands() for a in self.adapters)

    def _make_known(self, pause_served: bool = False) -> None:
        """Publish the engine's status for other threads (none without adapters: a local fleet),
        at once with the end of a tick being computed and of a pause asked (``pause_served``)."""
        status = self._status() if self.adapters else self._known
        with self._gate:
            self._known = status
            self._ticking = False
            if pause_served:
                self._pauses_asked = max(0, self._pauses_asked - 1)

    def _start_tick(self) -> bool:
        """Whether the loop may start a tick now (no pause asked): then it is being computed."""
        with self._gate:
            self._ticking = not self._pauses_asked
            return self._ticking
