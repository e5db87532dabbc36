"""The engine: one thread owns the simulation, paces it, and serves typed requests.

It wakes for whichever comes first, the next tick's deadline or a request, so requests are
answered within milliseconds while ticks stay on a fixed sim-time grid. Each tick's snapshot
goes to every adapter (simd/engine/ports.py), which is all they see of the core. In lockstep
(or while paused) time advances only through steps (simd/engine/stepping.py), run in slices of
about ``SLICE_SECONDS`` with the other requests served between them; a pause, resume or reset
cancels what is left. Pacing and load: simd/engine/pacing.py and capacity.py. After every tick and
request the loop publishes its status (simd/engine/status.py), from which the clock, the robots
and a pause are answered on other threads (simd/engine/at_once.py); the adapters' commands are
drained in chunks between requests (simd/engine/intake.py); it never blocks in an adapter without
room: it serves requests."""

from __future__ import annotations

import collections
import logging
import math
import queue
import threading
import time
from collections.abc import Callable
from typing import Any

from protocol import listing
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
from simd.core.snapshot import RobotState, TickSnapshot
from simd.engine.at_once import AnsweredAtOnce, Call, promised
from simd.engine.capacity import limit_refusal
from simd.engine.checkpoint import SAVE_CHANGE_S, SAVE_EVERY_S, Saver, capture
from simd.engine.heap import HeapKeeper
from simd.engine.here import ServedHere
from simd.engine.intake import CommandIntake
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
_WAKE = "wake"  # what Engine.wake puts in the inbox


class Engine(CommandIntake, AnsweredAtOnce, ServedHere):
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
        self._inbox: queue.Queue[Call | str | None] = queue.Queue(MAX_PENDING_REQUESTS)
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
        #: robots simulated elsewhere (other daemons of a shared fleet), asked before each tick
        self.ghost_source: GhostSource | None = None
        self._saver = saver  # --state: the fleet written as it runs
        self._next_save = math.inf
        self._navigation = NavigationRequests(sim, navigator, self._event, self._changed)
        self._handlers: dict[type[Any], Callable[[Any, Reply], Result | None]] = {
            SpawnRequest: self._spawn,
            DeleteRequest: self._delete,
            ListRequest: lambda req, reply: RobotList(self.sim.time, _listed(self.sim.states(), req)),
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
        self._init_at_once()  # a pause answered at once: simd/engine/at_once.py

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
            self._queue(Call(request, reply, waits=True))
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

    def _status(self, measured_cost: bool = True) -> Status:
        """The engine now, as other threads may see it (the simulation thread)."""
        return self._board.status(self.sim, self._time, self.paused, self.lockstep, measured_cost)

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

    def _next_call(self, timeout: float) -> Call | None:
        try:
            call = self._inbox.get(timeout=timeout) if timeout > 0 else self._inbox.get_nowait()
        except queue.Empty:
            return None
        if call is None:  # stop() woke us
            self.stop_event.set()
        return call if isinstance(call, Call) else None  # (None too for a wake-up)

    def serve_pending(self) -> None:
        """Serve every request waiting now (the loop does this between ticks and slices)."""
        while (call := self._next_call(0.0)) is not None:
            self._serve(call)

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
        self._serve(Call(request, reply))

    def _serve(self, call: Call) -> None:
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
        self._make_known(call)  # before the reply: whoever has it and asks the clock sees its effect
        if result is not None:  # None: the handler replies later (a step)
            _send(call.reply, result)

    def _spawn(self, req: SpawnRequest, reply: Reply) -> Result:
        try:
            robot = self.sim.spawn(req, robots_may_overlap=reply is promised)
        except FleetError as e:
            if reply is promised:  # a bug: its answer was given (simd/engine/promises.py)
                log.error("a spawn answered at once could not be made: %s", e)
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
        self._deleted([last])
        return last

    def _deleted(self, gone: list[RobotState]) -> None:
        """What the engine and its adapters keep of robots just deleted goes with them."""
        if self.navigator is not None:
            for last in gone:
                self.navigator.deleted(last.namespace, self.sim.time)
            self._navigation.tell()
        for last in gone:
            self._scans.forget(last.namespace)
            self._pending_commands.pop(last.namespace, None)
            self._event(Deleted(last, (self.sim.epoch, self.sim.tick)))
            log.info("deleted %s", last.name)
        self._changed()

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


def _send(reply: Reply, result: Result | FleetError) -> None:
    """Reply, and never let an adapter's failure to reply stop the simulation thread."""
    try:
        reply(result)
    except Exception:
        log.exception("a reply failed")


def _listed(states: list[RobotState], request: ListRequest) -> list[RobotState]:
    """The robots a list request asks for (protocol/listing.py): all, the named, or a page."""
    listing.check(request)
    return listing.select(states, request)
