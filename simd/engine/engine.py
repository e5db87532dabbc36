"""The engine: one thread owns the simulation, paces it, and serves typed requests.

It wakes for whichever comes first, the next tick's deadline or a request, so spawns are
answered within milliseconds while ticks stay on a fixed sim-time grid. Each tick's snapshot
goes to every adapter (simd/engine/ports.py), which is all they see of the core. In lockstep
(or while paused) time advances only through step requests; a long step runs in slices of
about ``SLICE_SECONDS`` with the other requests served between them, so no request freezes
the daemon, and a pause, resume or reset cancels what is left of it. When ticks are due is
simd/engine/pacing.py's to say (and whether the loop keeps up); what they cost,
simd/engine/capacity.py's.
"""

from __future__ import annotations

import collections
import logging
import math
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from protocol.control import (
    MAX_STEP_TICKS,
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
from protocol.messages import Time
from protocol.navigation import CancelRequest, NavigateRequest, NavigationRequest, NavigationStateRequest
from simd.core.robots import RobotTable
from simd.core.sim import Simulation
from simd.core.snapshot import TickSnapshot
from simd.engine.capacity import TickCost
from simd.engine.checkpoint import SAVE_CHANGE_S, SAVE_EVERY_S, Saver, capture
from simd.engine.observe import LatestScans, observe_packed
from simd.engine.pacing import LagWatch, Pacer, RtfMeter
from simd.engine.ports import (
    Adapter,
    Deleted,
    GhostSource,
    Navigation,
    ObservedArrays,
    OwnRobots,
    PlaceRequest,
    Reply,
    Result,
    RobotList,
    ScanRow,
    Spawned,
    StepResult,
    WorldReset,
)
from simd.nav.navigator import Navigator

log = logging.getLogger(__name__)

#: Requests waiting for the simulation thread beyond this are refused as busy.
MAX_PENDING_REQUESTS = 4096
#: Ticks between clock messages: 10 Hz, as gazebo_ros publishes /clock.
CLOCK_EVERY = 3
#: Wall time a step runs before the requests that arrived meanwhile are served.
SLICE_SECONDS = 0.02


@dataclass
class _Call:
    request: Request | NavigationRequest | PlaceRequest
    reply: Reply


@dataclass
class _StepJob:
    """A step request being run, slice by slice. Its commands (``names[k]`` at ``v[k]``,
    ``w[k]``) are applied at every tick, as table rows while the table's rows stay put (a
    spawn or delete between two slices makes the engine look the namespaces up again)."""

    request: StepRequest
    reply: Reply
    names: list[str]
    v: npt.NDArray[np.float64]
    w: npt.NDArray[np.float64]
    ran: int = 0
    rows_of: list[str] | None = None  # the table's namespaces list that ``rows`` belong to
    rows: npt.NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    here: npt.NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, bool))  # names still in the world
    #: the table rows of ``request.observe``, found when the request came (valid while the
    #: table's namespaces list is ``watched_of``)
    watched: npt.NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    watched_of: list[str] | None = None
    #: ``rows`` as a slice when they are consecutive (most steps: a slice writes the three
    #: command columns several times faster than an index array, at every tick); None: not found yet
    span: slice | npt.NDArray[np.int64] | None = None

    def apply(self, sim: Simulation, nav: Navigator | None = None) -> None:
        """Command this step's robots for the coming tick (those of them that navigate: only
        with commands other than zero, which override the navigator as cmd_vel does)."""
        t = sim.robots
        if self.rows_of is not t.namespaces:
            found = [t.row_of(ns) for ns in self.names]
            self.here = np.array([i is not None for i in found], dtype=bool)
            self.rows = np.array([i for i in found if i is not None], dtype=np.int64)
            self.rows_of = t.namespaces
            self.span = None
        if self.span is None:
            self.span = _span(self.rows)
        if len(self.rows):
            all_here = len(self.rows) == len(self.names)
            v, w = (self.v, self.w) if all_here else (self.v[self.here], self.w[self.here])
            sim.command_rows(self.span, v, w)
            if nav is not None and nav.busy:
                names = self.names if all_here else [n for n, h in zip(self.names, self.here, strict=True) if h]
                nav.overridden_by_step(names, v, w, sim.time)


def _span(rows: npt.NDArray[np.int64]) -> slice | npt.NDArray[np.int64]:
    """The same rows as a slice, if they are consecutive and ascending; else as they are."""
    n = len(rows)
    if n and (n == 1 or (rows[-1] - rows[0] == n - 1 and bool((np.diff(rows) == 1).all()))):
        first = int(rows[0])
        return slice(first, first + n)
    return rows


class RowsMemo:
    """The table rows of the name list a learner sends step after step: a thousand names
    looked up again cost ~0.1 ms a step, comparing the list with the last one ~0.01 ms. Valid
    while the table's namespaces list is the one the rows were found in (a spawn, delete or
    reset replaces it)."""

    def __init__(self, lookup: Callable[[RobotTable, list[str]], list[int | None]]) -> None:
        self._lookup = lookup
        self._of: list[str] | None = None
        self._names: list[str] = []
        self._rows: list[int | None] = []

    def rows(self, table: RobotTable, names: list[str]) -> list[int | None]:
        """The row of each name (None where no robot has it), as ``lookup`` finds them."""
        if self._of is not table.namespaces or names != self._names:
            self._rows, self._names, self._of = self._lookup(table, names), list(names), table.namespaces
        return self._rows


def _command_rows(table: RobotTable, names: list[str]) -> list[int | None]:
    """The rows of a step's commanded namespaces; a namespace given twice is refused."""
    if len(set(names)) != len(names):
        twice = next(n for n in names if names.count(n) > 1)
        raise FleetError(ErrorCode.INVALID_VALUE, f"commands name {twice!r} more than once", "commands")
    return [table.row_of(ns) for ns in names]


class Engine:
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
    ) -> None:
        self.sim = sim
        #: drives the robots that have a goal (simd/nav); None: no navigation (``--no-nav``)
        self.navigator = navigator
        self.rtf = rtf
        self.lockstep = lockstep
        self.paused = paused or lockstep
        self.adapters: list[Adapter] = []
        self.stop_event = threading.Event()
        self._wall = clock
        self._inbox: queue.Queue[_Call | None] = queue.Queue(MAX_PENDING_REQUESTS)
        self._steps: collections.deque[_StepJob] = collections.deque()
        self._pending_commands: dict[str, tuple[float, float]] = {}
        self._scans = LatestScans(sim.config.scan_every)  # each robot's newest scan
        self._last_snap: TickSnapshot | None = None
        self._rtf = RtfMeter()
        self._pacer = Pacer(sim.config.dt, rtf)
        self._lag = LagWatch()
        self._cost = TickCost()
        #: the whole process's CPU time: the cost of a tick, publishing included (None: no tick
        #: costs measured, for an engine in a learner's process that nobody asks its capacity)
        self._cpu = cpu_clock
        self._cpu_mark: float | None = None  # at the end of the last tick while time runs on
        #: robots simulated elsewhere (other daemons of a shared fleet), asked before each tick
        self.ghost_source: GhostSource | None = None
        self._models: tuple[list[str] | None, list[str]] = (None, [])  # (namespaces, their models)
        self._observed_rows = RowsMemo(RobotTable.rows_of)  # by name or namespace, as observe names them
        self._commanded_rows = RowsMemo(_command_rows)
        self._saver = saver  # --state: the fleet written as it runs
        self._next_save = math.inf
        self._handlers: dict[type[Any], Callable[[Any, Reply], Result | None]] = {
            SpawnRequest: self._spawn,
            DeleteRequest: self._delete,
            ListRequest: self._list,
            WorldRequest: self._world,
            ClockRequest: self._clock,
            PauseRequest: self._pause,
            ResumeRequest: self._resume,
            ResetRequest: self._reset,
            StepRequest: self._step,
            NavigateRequest: self._navigate,
            CancelRequest: self._cancel_goal,
            NavigationStateRequest: self._navigation_state,
            PlaceRequest: self._place,
        }

    def attach(self, adapter: Adapter) -> None:
        """Add an adapter; it hears of every robot already in the world (restored from a
        state file, or attached late) as if each had just been spawned."""
        self.adapters.append(adapter)
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

    def serve_here(self, request: Request | NavigationRequest | PlaceRequest) -> Result | FleetError:
        """Serve one request on the calling thread, a step to its last tick, and return its
        answer: for an engine no thread runs (a local fleet, simd/engine/local.py)."""
        answers: list[Result | FleetError] = []
        self._serve(_Call(request, answers.append))
        while self._steps:
            self._run_slice()
        return answers[0]

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
        sim = self.sim
        running = not self.paused
        measured = self._rtf.measure() if running else None
        return Clock(
            clock=Time.from_seconds(sim.time),
            tick=sim.tick,
            dt=sim.config.dt,
            paused=self.paused,
            lockstep=self.lockstep,
            # until the first tick after a resume there is nothing to measure: the target
            real_time_factor=0.0 if self.paused else (self.rtf if measured is None else measured),
            target_real_time_factor=self.rtf,
            robots=len(sim),
            dropped_commands=sum(a.dropped_commands() for a in self.adapters),
            behind_s=self._pacer.behind_s(self._wall()) if running else 0.0,
            falling_behind=running and self._lag.behind,
            tick_s=self._cost.mean_s if measured_cost else 0.0,
            capacity_robots=self.capacity() if measured_cost else 0,
        )

    def capacity(self) -> int:
        """About how many robots like these this machine keeps in real time (0: not known yet).
        Real time, whatever the target: the number a user sizes a fleet by."""
        return self._cost.capacity(self.sim.config.dt)

    # -- the loop ---------------------------------------------------------------------------

    def run(self) -> None:
        """Serve and tick until :meth:`stop`; then cancel what is left and close the adapters."""
        start = self._wall()
        self._start_time(start)
        if self._saver is not None:
            self._next_save = start  # at once: a restored or new fleet is on disk from the start
        try:
            while not self.stop_event.is_set():
                if self._saver is not None and self._wall() >= self._next_save:
                    self._save()
                if self._steps:
                    self._run_slice()
                    self.serve_pending()
                    continue
                timeout = 0.25 if self.paused else self._pacer.wait(self._wall())
                call = self._next_call(timeout)
                if call is not None:
                    self._serve(call)
                    continue
                if self.paused:
                    self._gather_commands()  # keep the adapters' buffers drained while time stands still
                    continue
                if self._pacer.due(self._wall()):
                    self.tick()
                    now = self._wall()
                    self._pacer.ticked(now)
                    self._lag.judge(now, self._rtf.measure(), self._rtf.span(), self.rtf, self._load)
        finally:
            self._cancel_steps()
            self.serve_pending()
            if self._saver is not None:
                self._saver.save_now(capture(self.sim, self._goals()))

    def _tick_cost(self, robots: int) -> None:
        """What the daemon spent since the last tick, all its threads (the outbox encoding and
        zenoh sending this tick's messages take more than the physics): the tick's cost, while
        time runs on (the first tick after time stood still would count the idle wait)."""
        assert self._cpu is not None
        now = self._cpu()
        if self._cpu_mark is not None:
            self._cost.record(robots, now - self._cpu_mark)
        self._cpu_mark = now

    def _start_time(self, now: float) -> None:
        """Time starts running now (the start, a resume, a reset): the first tick is due a
        period from now, and the factor is measured from here."""
        self._pacer.start(now)
        self._rtf.restart(now, self.sim.time)
        self._cpu_mark = None

    def _load(self) -> str:
        """What the warning of a loop falling behind says of its load."""
        n, cost = len(self.sim), self._cost.mean_s
        if not n or not cost:
            return ""
        said = f"; {n} robots, a tick takes {cost * 1e3:.1f} ms of the {self._pacer.period * 1e3:.1f} ms it may"
        cap = self.capacity()
        return said + (f" (about {cap} robots like these keep real time here)" if cap else "")

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
        return call

    def serve_pending(self) -> None:
        """Serve every request waiting now (the loop does this between ticks and slices)."""
        while (call := self._next_call(0.0)) is not None:
            self._serve(call)

    def _gather_commands(self) -> dict[str, tuple[float, float]]:
        cmds = self._pending_commands
        for a in self.adapters:
            cmds.update(a.take_commands())
        return cmds

    def tick(self, publish: bool = True) -> TickSnapshot:
        """Apply the newest commands, advance one tick, hand the snapshot to every adapter
        (unless a step asked for no publishing: then no adapter hears of the tick)."""
        sim = self.sim
        nav = self.navigator
        commands = self._gather_commands() if self.adapters else self._pending_commands
        if commands:  # (none without adapters: a local fleet's every tick)
            if nav is not None:  # an idle teleop's zeros never stop a robot on its way
                commands = nav.filter_commands(commands, sim.time)
            sim.command_many(commands)
            self._pending_commands = {}
        if self.ghost_source is not None:
            ghosts = self.ghost_source.take(self._own_robots(), stepping=bool(self._steps))
            if ghosts is not None:
                sim.set_ghosts(ghosts)
        if self._steps:  # a step's own commands hold for all of its ticks
            self._steps[0].apply(sim, nav)
        if nav is not None:
            nav.step(sim.robots, sim.tick, sim.time)
            nav.apply(sim.robots, sim.command_rows)
        snap = sim.step()
        self._scans.record(snap)
        self._last_snap = snap
        if not self.paused:  # stepped time has no factor; a resume measures it anew
            self._rtf.record(self._wall(), snap.time)
        if nav is not None:
            nav.observe(snap)
            said = nav.take_events()
            if said:
                self._event(Navigation(said))
                if said.results:
                    self._changed()  # a goal ended: no longer one to resume after a restart
        if publish:
            for a in self.adapters:
                a.on_tick(snap)
            if snap.tick % CLOCK_EVERY == 0:
                self._announce_clock()
        if self._cpu is not None:
            self._tick_cost(len(snap.namespaces))
        return snap

    def _own_robots(self) -> OwnRobots:
        t = self.sim.robots
        if self._models[0] is not t.namespaces:
            self._models = (t.namespaces, [r.model.name for r in t.robots])
        return OwnRobots(self.sim.tick, t.namespaces, self._models[1], t.x, t.y, t.yaw)

    def _announce_clock(self) -> None:
        clock = self.clock()
        for a in self.adapters:
            a.on_clock(clock)

    # -- requests ---------------------------------------------------------------------------

    def _serve(self, call: _Call) -> None:
        self._gather_commands()  # drained before each request: the clock's dropped count is current
        handler = self._handlers.get(type(call.request))
        try:
            if handler is None:
                raise TypeError(f"no handler for {type(call.request).__name__}")
            result = handler(call.request, call.reply)
        except FleetError as e:
            log.info("%s refused: %s", type(call.request).__name__, e)
            _send(call.reply, e)
            return
        except Exception as e:  # our bug: the daemon goes on, the client is told
            log.exception("%s failed", type(call.request).__name__)
            _send(call.reply, FleetError(ErrorCode.INTERNAL, f"internal error: {type(e).__name__}: {e}"))
            return
        if result is not None:  # None: the handler replies later (a step)
            _send(call.reply, result)

    def _spawn(self, req: SpawnRequest, reply: Reply) -> Result:
        try:
            robot = self.sim.spawn(req)
        except FleetError as e:
            cap = self.capacity()
            if e.code is not ErrorCode.ROBOT_LIMIT or not cap:
                raise
            said = f"{e.message}; this machine keeps about {cap} robots like these in real time (measured)"
            raise FleetError(e.code, said, e.field) from None
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
            self._tell_navigation()
        self._scans.forget(last.namespace)
        self._pending_commands.pop(last.namespace, None)
        self._event(Deleted(last))
        self._changed()
        log.info("deleted %s", last.name)
        return last

    def _place(self, req: PlaceRequest, reply: Reply) -> Result:
        state = self.sim.place(req.robot, req.x, req.y, req.yaw)
        self._pending_commands.pop(state.namespace, None)  # a command sent before the move does not outlive it
        if self.navigator is not None:
            self.navigator.placed(state.namespace, self.sim.time)
            self._tell_navigation()
        self._changed()
        log.info("placed %s at (%.3f, %.3f, %.3f)", state.name, state.x, state.y, state.yaw)
        return state

    def _list(self, req: ListRequest, reply: Reply) -> Result:
        return RobotList(self.sim.time, self.sim.states())

    def _world(self, req: WorldRequest, reply: Reply) -> Result:
        return self.sim.world

    def _clock(self, req: ClockRequest, reply: Reply) -> Result:
        return self.clock()

    def _pause(self, req: PauseRequest, reply: Reply) -> Result:
        self._cancel_steps()
        self.paused = True
        self._cpu_mark = None
        self._lag.stopped("paused")
        self._announce_clock()
        return self.clock()

    def _resume(self, req: ResumeRequest, reply: Reply) -> Result:
        if self.lockstep:
            raise FleetError(
                ErrorCode.NOT_ALLOWED,
                "the daemon runs in lockstep: time advances only through sim/step",
            )
        self._cancel_steps()
        if self.paused:  # a resume while running changes nothing (no new grid, no burst)
            self.paused = False
            self._start_time(self._wall())
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
            self._tell_navigation()
        self._event(WorldReset(self.sim.epoch))
        self._changed()
        self._lag.stopped("the simulation was reset")
        self._start_time(self._wall())
        self._announce_clock()
        return self.clock()

    def _step(self, req: StepRequest, reply: Reply) -> Result | None:
        self._steps.append(self._step_job(req, reply))
        return None

    def step_here(self, req: StepRequest, names: list[str], values: npt.NDArray[np.float64]) -> StepResult:
        """Run a step on the calling thread to its last tick and return its answer, its
        commands (``names`` at the (v, w) rows of ``values``, an (n, 2) array) given apart
        from ``req``, whose own are not read: a local fleet's step (simd/engine/local.py),
        without the bytes of packed commands, the queue and the reply. The checks, ticks and
        answer are those of ``req`` with these commands; a refusal raises FleetError."""
        answers: list[Result | FleetError] = []
        self._gather_commands()
        self._steps.append(self._step_job(req, answers.append, (names, values)))
        while self._steps:
            self._run_slice()
        answer = answers[0]
        assert isinstance(answer, StepResult)
        return answer

    def _step_job(
        self, req: StepRequest, reply: Reply, given: tuple[list[str], npt.NDArray[np.float64]] | None = None
    ) -> _StepJob:
        """A step request checked (FleetError if refused) and ready to run."""
        if not self.paused:
            raise FleetError(
                ErrorCode.NOT_ALLOWED,
                "step needs a paused simulation or --lockstep (pause it first with sim/pause)",
            )
        if not 1 <= req.ticks <= MAX_STEP_TICKS:
            raise FleetError(ErrorCode.INVALID_VALUE, f"ticks must be in 1..{MAX_STEP_TICKS}, got {req.ticks}", "ticks")
        t = self.sim.robots
        names, rows, v, w = self._step_commands(req, given)
        watched = self._observed_rows.rows(t, req.observe)
        if None in watched:
            ns = req.observe[watched.index(None)]
            raise FleetError(ErrorCode.NOT_FOUND, f"no robot called {ns!r} to observe", "observe")
        here = np.ones(len(rows), dtype=bool)
        watched_rows = np.array(watched, dtype=np.int64)
        return _StepJob(req, reply, names, v, w, 0, t.namespaces, rows, here, watched_rows, t.namespaces)

    def _step_commands(
        self, req: StepRequest, given: tuple[list[str], npt.NDArray[np.float64]] | None = None
    ) -> tuple[list[str], npt.NDArray[np.int64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """A step's commands (``given``, else the request's), checked, as namespaces, their
        table rows and (v, w) columns."""
        if given is not None:
            (names, values), field = given, "commands"
        elif req.commands is None:
            names = list(req.cmd_vel)
            values = np.array([(tw.linear.x, tw.angular.z) for tw in req.cmd_vel.values()], dtype=np.float64)
            field = "cmd_vel"
        else:
            if req.cmd_vel:
                raise FleetError(ErrorCode.INVALID_VALUE, "give cmd_vel or commands, not both", "commands")
            names, raw = req.commands.names, req.commands.twist
            if len(raw) != 16 * len(names):
                raise FleetError(
                    ErrorCode.INVALID_VALUE,
                    f"commands.twist must hold 2 float64 for each of the {len(names)} names, got {len(raw)} bytes",
                    "commands",
                )
            values = np.frombuffer(raw, dtype="<f8").astype(np.float64)
            field = "commands"
        values = values.reshape(len(names), 2)
        if not np.isfinite(values).all():
            finite = np.isfinite(values).all(axis=1)
            ns = names[int(np.argmin(finite))]
            raise FleetError(ErrorCode.NON_FINITE, f"{field} for {ns!r} is not finite", field)
        rows = self._commanded_rows.rows(self.sim.robots, names)
        if None in rows:
            ns = names[rows.index(None)]
            raise FleetError(ErrorCode.NOT_FOUND, f"no robot with namespace {ns!r}", field)
        return names, np.array(rows, dtype=np.int64), values[:, 0].copy(), values[:, 1].copy()

    def _run_slice(self) -> None:
        """Run the current step for about SLICE_SECONDS (at least one tick)."""
        job = self._steps[0]
        end = self._wall() + SLICE_SECONDS
        publish = job.request.publish
        while job.ran < job.request.ticks and not self.stop_event.is_set():
            self.tick(publish)
            job.ran += 1
            if self._wall() >= end:
                break
        if job.ran >= job.request.ticks:
            self._steps.popleft()
            self._cpu_mark = None  # between steps the daemon waits for the next
            _send(job.reply, self._step_result(job, cancelled=False))

    def _cancel_steps(self) -> None:
        while self._steps:
            job = self._steps.popleft()
            _send(job.reply, self._step_result(job, cancelled=True))

    def _step_result(self, job: _StepJob, cancelled: bool) -> StepResult:
        if job.request.packed:
            return StepResult(self.clock(measured_cost=False), job.ran, cancelled, packed=self._observe_packed(job))
        states = {}
        scans = {}
        for key in job.request.observe:
            robot = self.sim.find(key)
            if robot is None:  # deleted during the step
                continue
            states[key] = self.sim.state(robot)
            scan = self._scans.get(robot.namespace)
            if scan is not None:
                scans[key] = ScanRow(*scan)
        return StepResult(self.clock(measured_cost=False), job.ran, cancelled, states, scans)

    def _observe_packed(self, job: _StepJob) -> ObservedArrays:
        """The odometry and latest scans of the robots the step observes, as arrays (robots
        deleted during the step left out)."""
        t, keys = self.sim.robots, job.request.observe
        if job.watched_of is t.namespaces:  # no spawn or delete since the request came
            names, rows = keys, job.watched
        else:
            found = t.rows_of(keys)
            names = [key for key, row in zip(keys, found, strict=True) if row is not None]
            rows = np.array([row for row in found if row is not None], dtype=np.int64)
        return observe_packed(t, self._last_snap, self._scans, names, rows, self.sim.config.lidar.samples)

    # -- navigation -------------------------------------------------------------------------

    def _nav(self, robot: str) -> tuple[Navigator, str]:
        """The navigator and the robot's namespace, or the error that refuses the request."""
        if self.navigator is None:
            raise FleetError(ErrorCode.NOT_ALLOWED, "navigation is off on this daemon (it was started with --no-nav)")
        found = self.sim.find(robot)
        if found is None:
            raise FleetError(ErrorCode.NOT_FOUND, f"no robot called {robot!r}", "robot")
        return self.navigator, found.namespace

    def _navigate(self, req: NavigateRequest, reply: Reply) -> Result:
        nav, ns = self._nav(req.robot)
        robot = self.sim.find(ns)
        assert robot is not None
        accepted = nav.goal(ns, robot.model, req, self.sim.time)
        self._tell_navigation()  # the preempted goal's result goes before this reply
        self._changed()
        return accepted

    def _cancel_goal(self, req: CancelRequest, reply: Reply) -> Result:
        nav, ns = self._nav(req.robot)
        result = nav.cancel(ns, req.goal_id, self.sim.time)
        self._tell_navigation()
        self._changed()
        return result

    def _navigation_state(self, req: NavigationStateRequest, reply: Reply) -> Result:
        nav, ns = self._nav(req.robot)
        return nav.state(ns)

    def _tell_navigation(self) -> None:
        assert self.navigator is not None
        said = self.navigator.take_events()
        if said:
            self._event(Navigation(said))

    def _event(self, event: Spawned | Deleted | WorldReset | Navigation) -> None:
        for a in self.adapters:
            a.on_event(event)


def _send(reply: Reply, result: Result | FleetError) -> None:
    """Reply, and never let an adapter's failure to reply stop the simulation thread."""
    try:
        reply(result)
    except Exception:
        log.exception("a reply failed")
