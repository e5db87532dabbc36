"""The engine: one thread owns the simulation, paces it, and serves typed requests.

It wakes for whichever comes first, the next tick's deadline or a request, so requests are
answered within milliseconds while ticks stay on a fixed sim-time grid. Each tick's snapshot
goes to every adapter (simd/engine/ports.py), which is all they see of the core. In lockstep
(or while paused) time advances only through steps (simd/engine/stepping.py), run in slices of
about ``SLICE_SECONDS`` with the other requests served between them; a pause, resume or reset
cancels what is left. Pacing and load: simd/engine/pacing.py and capacity.py. After every tick and
request the loop publishes its status (simd/engine/status.py), from which the clock and the robots
are answered on other threads; it never blocks in an adapter without room: it serves requests."""

from __future__ import annotations

import collections
import dataclasses
import logging
import math
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from protocol.control import (
    Clock,
    ClockRequest,
    DeleteRequest,
    ListRequest,
    PauseRequest,
    Request,
    ResetRequest,
    ResumeRequest,
    SpawnRequest,
    StepRequest,
    WorldRequest,
)
from protocol.errors import ErrorCode, FleetError
from protocol.navigation import CancelRequest, NavigateRequest, NavigationRequest, NavigationStateRequest
from simd.core.sim import Simulation
from simd.core.snapshot import TickSnapshot
from simd.engine.capacity import limit_refusal
from simd.engine.checkpoint import SAVE_CHANGE_S, SAVE_EVERY_S, Saver, capture
from simd.engine.heap import HeapKeeper
from simd.engine.here import ServedHere
from simd.engine.navigation_requests import NavigationRequests
from simd.engine.observe import LatestScans
from simd.engine.pacing import Timekeeper
from simd.engine.ports import (
    Adapter,
    Deleted,
    Event,
    GhostSource,
    Navigation,
    PlaceRequest,
    Reply,
    Result,
    RobotList,
    SimulationSetup,
    Spawned,
    StepResult,
    WorldReset,
)
from simd.engine.status import Status, StatusBoard
from simd.engine.stepping import StepJob, StepPlanner, step_result
from simd.nav.navigator import Navigator

log = logging.getLogger(__name__)

#: Requests waiting for the simulation thread beyond this are refused as busy.
MAX_PENDING_REQUESTS = 4096
#: Ticks between clock messages: 10 Hz, as gazebo_ros publishes /clock.
CLOCK_EVERY = 3
#: Wall time a step runs before the requests that arrived meanwhile are served.
SLICE_SECONDS = 0.02
#: The longest wait for an adapter's room (it says it has room through :meth:`Engine.wake`).
ROOM_POLL_S = 0.05
#: cmd_vel samples an adapter decodes at a time before the requests that came meanwhile are
#: served (8 000 robots driven at 10 Hz send 80 000 a second: ~2 us each, more under load).
DRAIN_CHUNK = 1000
#: Chunks decoded before a tick at most (the tick takes the rest): commands arriving as fast as
#: they are decoded never hold a tick back (the fleet adapter's ring holds 65 536).
DRAIN_CHUNKS = 64
_WAKE = "wake"  # what Engine.wake puts in the inbox


@dataclass
class _Call:
    request: Request | NavigationRequest | PlaceRequest
    reply: Reply


class Engine(ServedHere):
    """Runs a :class:`Simulation` for its adapters; see the module docstring."""

    def __init__(
        self,
        sim: Simulation,
        *,
        rtf: float = 1.0,
        lockstep: bool = False,
        paused: bool = False,
        clock: Callable[[], float] = time.monotonic,
        cpu_clock: Callable[[], float] | None = time.process_time,
        saver: Saver | None = None,
        navigator: Navigator | None = None,
        heap: HeapKeeper | None = None,
    ) -> None:
        """``heap``: keeps the garbage collector off the long-lived objects (the daemon's, which
        owns its process: simd/engine/heap.py)."""
        self.sim = sim
        #: drives the robots that have a goal (simd/nav); None: no navigation (``--no-nav``)
        self.navigator = navigator
        self.setup = SimulationSetup(sim.config.dt, sim.config.lidar, sim.world, navigator is not None)  # for adapters
        self.rtf = rtf
        self.lockstep = lockstep
        self.paused = paused or lockstep
        self.adapters: list[Adapter] = []
        self.stop_event = threading.Event()
        self._wall = clock
        self._inbox: queue.Queue[_Call | str | None] = queue.Queue(MAX_PENDING_REQUESTS)
        self._waiting_for_room = False
        self._steps: collections.deque[StepJob] = collections.deque()
        self._planner = StepPlanner()
        self._pending_commands: dict[str, tuple[float, float]] = {}
        self._drain_at = -math.inf  # paused: when the adapters' commands are next drained (wall)
        self._scans = LatestScans(sim.config.scan_every)  # each robot's newest scan
        self._last_snap: TickSnapshot | None = None
        self._time = Timekeeper(sim.config.dt, rtf, cpu_clock)  # cpu_clock: the process's, publishing included
        self._pacer = self._time.pacer
        self._board = StatusBoard()
        self._heap = heap
        # A pause is answered at once, on the query's thread (answer_at_once): what it says and
        # the ticks the loop still starts agree through this lock. The loop starts no tick while
        # a pause is asked and not yet served; ``_ticking``: a tick has started and its status is
        # not known yet (the pause's reply names that tick as the last).
        self._gate = threading.Lock()
        self._pauses_asked = 0
        self._ticking = False
        #: robots simulated elsewhere (other daemons of a shared fleet), asked before each tick
        self.ghost_source: GhostSource | None = None
        self._saver = saver  # --state: the fleet written as it runs
        self._next_save = math.inf
        self._navigation = NavigationRequests(sim, navigator, self._event, self._changed)
        self._handlers: dict[type[Any], Callable[[Any, Reply], Result | None]] = {
            SpawnRequest: self._spawn,
            DeleteRequest: self._delete,
            ListRequest: lambda req, reply: RobotList(self.sim.time, self.sim.states()),
            WorldRequest: lambda req, reply: self.sim.world,
            ClockRequest: lambda req, reply: self.clock(),
            PauseRequest: self._pause,
            ResumeRequest: self._resume,
            ResetRequest: self._reset,
            StepRequest: self._step,
            NavigateRequest: self._navigation.navigate,
            CancelRequest: self._navigation.cancel,
            NavigationStateRequest: self._navigation.state,
            PlaceRequest: self._place,
        }
        self._known = self._status()

    def attach(self, adapter: Adapter) -> None:
        """Add an adapter; it hears of every robot already in the world (restored from a
        state file, or attached late) as if each had just been spawned."""
        self.adapters.append(adapter)
        self._known = self._status()
        for state in self.sim.states():
            adapter.on_event(Spawned(state, self.sim.time))

    # -- from any thread --------------------------------------------------------------------

    def submit(self, request: Request | NavigationRequest | PlaceRequest, reply: Reply) -> None:
        """Queue a request for the simulation thread, which calls ``reply`` once. Raises
        FleetError (busy) at once when the queue is full, so a flood never grows without
        bound and ``reply`` is never called for it."""
        try:
            self._inbox.put_nowait(_Call(request, reply))
        except queue.Full:
            raise FleetError(ErrorCode.BUSY, "the daemon is busy: too many pending requests; retry") from None

    def wake(self) -> None:
        """An adapter has room for a tick again (any thread): the loop goes on if it waits."""
        if self._waiting_for_room:
            self._waiting_for_room = False
            try:
                self._inbox.put_nowait(_WAKE)
            except queue.Full:  # then it wakes for a request anyway
                pass

    def stop(self) -> None:
        self.stop_event.set()
        try:
            self._inbox.put_nowait(None)  # wake the loop
        except queue.Full:
            pass

    # -- status -----------------------------------------------------------------------------

    def clock(self, measured_cost: bool = True) -> Clock:
        """The clock now; with ``measured_cost`` False without the tick cost and capacity (a
        step's reply: the same seed and commands give the same bytes)."""
        return self._status(measured_cost).clock(self._wall(), self._dropped())

    def capacity(self) -> int:
        """About how many robots like these this machine keeps in real time (0: not known yet).
        Real time, whatever the target: the number a user sizes a fleet by."""
        return self._time.capacity()

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
                    self._inbox.put_nowait(_Call(request, _ignore))
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

    def _status(self, measured_cost: bool = True) -> Status:
        """The engine now, as other threads may see it (the simulation thread)."""
        return self._board.status(self.sim, self._time, self.paused, self.lockstep, measured_cost)

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

    # -- the loop ---------------------------------------------------------------------------

    def run(self) -> None:
        """Serve and tick until :meth:`stop`; then cancel what is left and close the adapters."""
        start = self._wall()
        self._time.start(start, self.sim.time)
        self._make_known()
        if self._saver is not None:
            self._next_save = start  # at once: a restored or new fleet is on disk from the start
        try:
            while not self.stop_event.is_set():
                if self._heap is not None:
                    self._heap.keep(len(self.sim), self.sim.robots.generation)
                if self._saver is not None and self._wall() >= self._next_save:
                    self._save()
                due = bool(self._steps) or (not self.paused and self._pacer.due(self._wall()))
                if due and not self._adapters_ready():
                    self._serve_while_waiting()  # an adapter is still sending: requests meanwhile
                    continue
                if self._steps:
                    self._run_slice()
                    self.serve_pending()
                    continue
                timeout = self._drain_while_paused() if self.paused else self._pacer.wait(self._wall())
                call = self._next_call(timeout)
                if call is not None:
                    self._serve(call)
                    continue
                if self.paused:  # (its commands drained above)
                    continue
                if self._pacer.due(self._wall()) and self._adapters_ready():  # else: served above, until ready
                    if not self._drain_commands() or not self._start_tick():
                        continue  # requests came meanwhile (a pause is served before any tick)
                    self.tick()
                    now = self._wall()
                    self._time.ticked(now, lambda: self._time.load(len(self.sim)))
                    self._make_known()
        finally:
            self._cancel_steps()
            self.serve_pending()
            if self._heap is not None:
                self._heap.close()
            if self._saver is not None:
                self._saver.save_now(capture(self.sim, self._goals()))

    def _drain_while_paused(self) -> float:
        """Keep the adapters' command buffers drained while time stands still, once a tick
        period of wall time as when running, however many requests keep the loop busy; the
        wait until the next drain. (Drained only when no request came for 0.25 s, a paused
        daemon under a soak's steady requests let 5 s of 1 000 robots' cmd_vel pile up in the
        ring, ~50 000 samples: the allocator kept the 8 MB they took, docs/robustness.md.)"""
        now = self._wall()
        if now >= self._drain_at:
            self._gather_commands()
            self._drain_at = now + self.sim.config.dt
        return max(0.0, self._drain_at - now)

    def _adapters_ready(self) -> bool:
        """Whether every adapter takes a tick at once (one that may make the loop wait says so
        with a ``ready()`` method: simd/adapters/fleet/adapter.py)."""
        return all(getattr(a, "ready", _always)() for a in self.adapters)

    def _serve_while_waiting(self) -> None:
        """Serve what comes until an adapter has room (it wakes the loop) instead of blocking in
        it; decode the commands waiting meanwhile, so the next tick has few left to decode."""
        self._waiting_for_room = True
        if self._adapters_ready():  # room came meanwhile: on
            call = None
        elif self._drain_chunk():
            call = self._next_call(0.0)
        else:
            call = self._next_call(ROOM_POLL_S)
        self._waiting_for_room = False
        if call is not None:
            self._serve(call)
            self.serve_pending()

    def _save(self) -> None:
        assert self._saver is not None
        self._saver.offer(capture(self.sim, self._goals()))
        self._next_save = self._wall() + SAVE_EVERY_S

    def _goals(self) -> list[NavigateRequest]:
        return [] if self.navigator is None else self.navigator.goals()

    def _changed(self) -> None:
        """The fleet changed (spawn, delete, reset): save it soon."""
        if self._saver is not None:
            self._next_save = min(self._next_save, self._wall() + SAVE_CHANGE_S)

    def _next_call(self, timeout: float) -> _Call | None:
        try:
            call = self._inbox.get(timeout=timeout) if timeout > 0 else self._inbox.get_nowait()
        except queue.Empty:
            return None
        if call is None:  # stop() woke us
            self.stop_event.set()
        return call if isinstance(call, _Call) else None  # (None too for a wake-up)

    def _drain_chunk(self) -> bool:
        """Let each adapter decode up to DRAIN_CHUNK of its waiting commands (those with a
        ``drain_commands`` method: simd/adapters/fleet/adapter.py); whether any had more waiting."""
        more = False
        for a in self.adapters:
            drain = getattr(a, "drain_commands", None)
            if drain is not None and drain(DRAIN_CHUNK):
                more = True
        return more

    def _drain_commands(self) -> bool:
        """Before a tick: decode the waiting commands a chunk at a time with the requests that
        come meanwhile served in between, so that none waits for all of them (the tick takes
        what is left). False if a request was served: the loop looks again before ticking."""
        served = False
        for _ in range(DRAIN_CHUNKS):
            if not self._drain_chunk() or self.stop_event.is_set():
                break
            while (call := self._next_call(0.0)) is not None:
                self._serve(call)
                served = True
        return not served

    def serve_pending(self) -> None:
        """Serve every request waiting now (the loop does this between ticks and slices)."""
        while (call := self._next_call(0.0)) is not None:
            self._serve(call)

    def _gather_commands(self) -> dict[str, tuple[float, float]]:
        cmds = self._pending_commands
        for a in self.adapters:
            cmds.update(a.take_commands())
        return cmds

    def tick(self, publish: bool = True, *, held: bool = False, last: bool = False) -> TickSnapshot:
        """Apply the newest commands, advance one tick, hand the snapshot to every adapter
        (unless a step asked for no publishing: then no adapter hears of the tick). ``held``:
        the running step's commands were written at the tick before this one and nothing was
        served since (the ticks of one slice after its first). ``last``: a step's last tick,
        whose scans its reply carries at once."""
        sim = self.sim
        nav = self.navigator
        commands = self._gather_commands() if self.adapters else self._pending_commands
        if commands:  # (none without adapters: a local fleet's every tick)
            if nav is not None:  # an idle teleop's zeros never stop a robot on its way
                commands = nav.filter_commands(commands, sim.time)
            sim.command_many(commands)
            self._pending_commands = {}
        if self.ghost_source is not None:
            ghosts = self.ghost_source.take(self._board.own_robots(self.sim), stepping=bool(self._steps))
            if ghosts is not None:
                sim.set_ghosts(ghosts)
        # a step's own commands hold for all of its ticks: written again unless they are still
        # there (nothing commanded since, no watchdog counting the ticks since: a local
        # fleet's every tick but a slice's first)
        if self._steps and (not held or commands or nav is not None or sim.config.cmd_timeout > 0):
            self._steps[0].apply(sim, nav)
        if nav is not None:
            nav.step(sim.robots, sim.tick, sim.time)
            nav.apply(sim.robots, sim.command_rows)
        snap = sim.step(scans_wanted=last)
        self._scans.record(snap)
        self._last_snap = snap
        if not self.paused:  # stepped time has no factor; a resume measures it anew
            self._time.meter.record(self._wall(), snap.time)
        if nav is not None:
            nav.observe(snap)
            said = nav.take_events()
            if said:
                self._event(Navigation(said))
                if said.results:
                    self._changed()  # a goal ended: no longer one to resume after a restart
        self._make_known()  # before anyone hears of the tick: a reader of it finds the clock there
        if publish:
            for a in self.adapters:
                a.on_tick(snap)
            if snap.tick % CLOCK_EVERY == 0:
                self._announce_clock()
        self._time.tick_cost(len(snap.namespaces))
        return snap

    def _announce_clock(self) -> None:
        clock = self.clock()
        for a in self.adapters:
            a.on_clock(clock)

    # -- requests ---------------------------------------------------------------------------

    def _serve_call(self, request: Request | NavigationRequest | PlaceRequest, reply: Reply) -> None:
        self._serve(_Call(request, reply))

    def _serve(self, call: _Call) -> None:
        if isinstance(call.request, ClockRequest):  # drained first: the dropped count is current
            self._gather_commands()  # (not before every request: 80 000 commands a second take a while)
        handler = self._handlers.get(type(call.request))
        result: Result | FleetError | None
        try:
            if handler is None:
                raise TypeError(f"no handler for {type(call.request).__name__}")
            result = handler(call.request, call.reply)
        except FleetError as e:
            log.info("%s refused: %s", type(call.request).__name__, e)
            result = e
        except Exception as e:  # our bug: the daemon goes on, the client is told
            log.exception("%s failed", type(call.request).__name__)
            result = FleetError(ErrorCode.INTERNAL, f"internal error: {type(e).__name__}: {e}")
        self._make_known()  # before the reply: whoever has it and asks the clock sees its effect
        if result is not None:  # None: the handler replies later (a step)
            _send(call.reply, result)

    def _spawn(self, req: SpawnRequest, reply: Reply) -> Result:
        try:
            robot = self.sim.spawn(req)
        except FleetError as e:
            if e.code is not ErrorCode.ROBOT_LIMIT:
                raise
            raise limit_refusal(self.sim.config.max_robots, self.capacity()) from None
        state = self.sim.state(robot)
        self._event(Spawned(state, self.sim.time))
        self._changed()
        log.info("spawned %s (%s) at (%.3f, %.3f, %.3f) ns=%s", robot.name, robot.model.name,
                 state.x, state.y, state.yaw, robot.namespace)  # fmt: skip
        cap = self.capacity()
        if cap and len(self.sim) == cap + 1:  # this spawn crossed it: said before it bites
            log.warning("%d robots: more than the about %d like these this machine keeps in real time (measured); "
                        "expect the simulation to fall behind", len(self.sim), cap)  # fmt: skip
        return state

    def _delete(self, req: DeleteRequest, reply: Reply) -> Result:
        last = self.sim.delete(req.name)
        if self.navigator is not None:
            self.navigator.deleted(last.namespace, self.sim.time)
            self._navigation.tell()
        self._scans.forget(last.namespace)
        self._pending_commands.pop(last.namespace, None)
        self._event(Deleted(last, (self.sim.epoch, self.sim.tick)))
        self._changed()
        log.info("deleted %s", last.name)
        return last

    def _place(self, req: PlaceRequest, reply: Reply) -> Result:
        state = self.sim.place(req.robot, req.x, req.y, req.yaw)
        self._pending_commands.pop(state.namespace, None)  # a command sent before the move does not outlive it
        if self.navigator is not None:
            self.navigator.placed(state.namespace, self.sim.time)
            self._navigation.tell()
        self._changed()
        log.info("placed %s at (%.3f, %.3f, %.3f)", state.name, state.x, state.y, state.yaw)
        return state

    def _pause(self, req: PauseRequest, reply: Reply) -> Result:
        self._cancel_steps()
        self.paused = True
        self._time.idle()
        self._time.lag.stopped("paused")
        if reply is _ignore:  # answered at once (answer_at_once): the pause asked is served
            self._make_known(pause_served=True)
        self._announce_clock()
        return self.clock()

    def _resume(self, req: ResumeRequest, reply: Reply) -> Result:
        if self.lockstep:
            raise FleetError(ErrorCode.NOT_ALLOWED, "the daemon runs in lockstep: time advances only through sim/step")
        self._cancel_steps()
        if self.paused:  # a resume while running changes nothing (no new grid, no burst)
            self.paused = False
            self._time.start(self._wall(), self.sim.time)
        self._announce_clock()
        return self.clock()

    def _reset(self, req: ResetRequest, reply: Reply) -> Result:
        self._cancel_steps()
        self.sim.reset(req.seed)
        if self.ghost_source is not None:
            self.ghost_source.forget()
        self._gather_commands()  # commands sent before the reset do not outlive it
        self._pending_commands = {}
        self._scans.clear()
        if self.navigator is not None:
            self.navigator.reset(self.sim.time)
            self._navigation.tell()
        self._event(WorldReset(self.sim.epoch))
        self._changed()
        self._time.lag.stopped("the simulation was reset")
        self._time.start(self._wall(), self.sim.time)
        self._announce_clock()
        return self.clock()

    def _step(self, req: StepRequest, reply: Reply) -> Result | None:
        self._steps.append(self._step_job(req, reply))
        return None

    def _run_slice(self) -> None:
        """Run the current step for about SLICE_SECONDS (at least one tick)."""
        job = self._steps[0]
        wall, stopped = self._wall, self.stop_event.is_set
        end = wall() + SLICE_SECONDS
        publish, ticks, observed = job.request.publish, job.request.ticks, bool(job.request.observe)
        held = False  # the first tick of a slice writes the step's commands (requests came between)
        while job.ran < ticks and not stopped():
            self.tick(publish, held=held, last=observed and job.ran == ticks - 1)
            held = True
            job.ran += 1
            if wall() >= end:
                break
        if job.done:
            self._steps.popleft()
            self._time.idle()  # between steps the daemon waits for the next
            _send(job.reply, self._step_result(job, cancelled=False))

    def _cancel_steps(self) -> None:
        while self._steps:
            job = self._steps.popleft()
            _send(job.reply, self._step_result(job, cancelled=True))

    def _step_result(self, job: StepJob, cancelled: bool) -> StepResult:
        return step_result(self.sim, job, self._step_clock(), cancelled, self._last_snap, self._scans)

    def _step_clock(self) -> Clock:
        """The clock of a step's reply (:meth:`clock` without the measured cost)."""
        if self.paused:  # every step's, whose reply comes before time may run again
            return self._board.stood_still_clock(self.sim, self._time, self.lockstep, self._dropped())
        return self.clock(measured_cost=False)

    def _event(self, event: Event) -> None:
        for a in self.adapters:
            a.on_event(event)


def _always() -> bool:
    return True


def _ignore(result: Result | FleetError) -> None:
    """The reply of a request already answered (a pause answered at once)."""


def _send(reply: Reply, result: Result | FleetError) -> None:
    """Reply, and never let an adapter's failure to reply stop the simulation thread."""
    try:
        reply(result)
    except Exception:
        log.exception("a reply failed")
