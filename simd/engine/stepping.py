"""Steps: the requests that advance a paused or lockstep simulation by a number of ticks.

A step is checked when it comes (its commands, the robots it observes) and queued as a
:class:`StepJob`; the engine then runs it slice by slice (simd/engine/engine.py), serving the
other requests in between, and answers with a :class:`~simd.engine.ports.StepResult` when its
ticks have run or it was cancelled. This module holds what a step is and how its commands and
observations map to the robot table's rows; when it runs is the engine's business.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from fleetcommon.arrays import F64, I64
from protocol.control import MAX_STEP_TICKS, Clock, StepRequest, check_finite_commands
from protocol.errors import ErrorCode, FleetError
from simd.core.robots import RobotTable
from simd.core.sim import Simulation
from simd.core.snapshot import TickSnapshot
from simd.engine.observe import LatestScans, observe_packed
from simd.engine.ports import ObservedArrays, Reply, ScanRow, StepResult
from simd.nav.navigator import Navigator


@dataclass
class StepJob:
    """A step request being run, slice by slice. Its commands (``names[k]`` at ``v[k]``,
    ``w[k]``) are applied at every tick, as table rows while the table's rows stay put (a
    spawn or delete between two slices makes the engine look the namespaces up again)."""

    request: StepRequest
    reply: Reply
    names: list[str]
    v: F64
    w: F64
    ran: int = 0
    rows_of: int | None = None  # the table generation ``rows`` belong to
    rows: I64 = field(default_factory=lambda: np.zeros(0, np.int64))
    here: npt.NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, bool))  # names still in the world
    #: the table rows of ``request.observe``, found when the request came (valid while the
    #: table's generation is ``watched_of``)
    watched: I64 = field(default_factory=lambda: np.zeros(0, np.int64))
    watched_of: int | None = None
    #: ``rows`` as a slice when they are consecutive (most steps: a slice writes the three
    #: command columns several times faster than an index array, at every tick); None: not found yet
    span: slice | I64 | None = None

    @property
    def done(self) -> bool:
        return self.ran >= self.request.ticks

    def apply(self, sim: Simulation, nav: Navigator | None = None) -> None:
        """Command this step's robots for the coming tick (those of them that navigate: only
        with commands other than zero, which override the navigator as cmd_vel does)."""
        t = sim.robots
        if self.rows_of != t.generation:
            found = [t.row_of(ns) for ns in self.names]
            self.here = np.array([i is not None for i in found], dtype=bool)
            self.rows = np.array([i for i in found if i is not None], dtype=np.int64)
            self.rows_of = t.generation
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


def _span(rows: I64) -> slice | I64:
    """The same rows as a slice, if they are consecutive and ascending; else as they are."""
    n = len(rows)
    if n and (n == 1 or (rows[-1] - rows[0] == n - 1 and bool((np.diff(rows) == 1).all()))):
        first = int(rows[0])
        return slice(first, first + n)
    return rows


class RowsMemo:
    """The table rows of the name list a learner sends step after step: a thousand names
    looked up again cost ~0.1 ms a step, comparing the list with the last one ~0.01 ms. Valid
    while the table's generation is the one the rows were found in (a spawn or delete
    changes it). The rows found are kept as an array too, and as a slice where they are
    consecutive: a step of one robot notices each numpy call it makes (both read only, so the
    jobs of many steps may hold them)."""

    def __init__(self, lookup: Callable[[RobotTable, list[str]], list[int | None]]) -> None:
        self._lookup = lookup
        self._of: int | None = None
        self._names: list[str] = []
        self._rows: list[int | None] = []
        self._array: I64 = np.zeros(0, np.int64)
        self._span: slice | I64 = self._array

    def rows(self, table: RobotTable, names: list[str]) -> list[int | None]:
        """The row of each name (None where no robot has it), as ``lookup`` finds them."""
        if self._of != table.generation or names != self._names:
            self._rows, self._names, self._of = self._lookup(table, names), list(names), table.generation
            self._array = np.array([r for r in self._rows if r is not None], dtype=np.int64)
            self._array.flags.writeable = False
            self._span = _span(self._array)
        return self._rows

    def found(self) -> tuple[I64, slice | I64]:
        """The rows of the names :meth:`rows` was last asked (those found), as an array and as
        :func:`_span` gives them."""
        return self._array, self._span


def command_rows(table: RobotTable, names: list[str]) -> list[int | None]:
    """The rows of a step's commanded namespaces; a namespace given twice is refused."""
    if len(set(names)) != len(names):
        twice = next(n for n in names if names.count(n) > 1)
        raise FleetError(ErrorCode.INVALID_VALUE, f"commands name {twice!r} more than once", "commands")
    return [table.row_of(ns) for ns in names]


class StepPlanner:
    """Turns step requests into jobs (refusing bad ones) and jobs into their results. The
    name lists a learner repeats step after step are looked up once (:class:`RowsMemo`)."""

    def __init__(self) -> None:
        self._observed_rows = RowsMemo(RobotTable.rows_of)  # by name or namespace, as observe names them
        self._commanded_rows = RowsMemo(command_rows)

    def job(
        self, sim: Simulation, req: StepRequest, reply: Reply, given: tuple[list[str], F64] | None = None
    ) -> StepJob:
        """The job of a step request, or the FleetError that refuses it; its commands are
        ``given`` (names, an (n, 2) array of (v, w)) instead of the request's when given (a
        local fleet's step, simd/engine/local.py: no bytes of packed commands)."""
        if not 1 <= req.ticks <= MAX_STEP_TICKS:
            raise FleetError(ErrorCode.INVALID_VALUE, f"ticks must be in 1..{MAX_STEP_TICKS}, got {req.ticks}", "ticks")
        t = sim.robots
        names, v, w = self._commands(t, req, given)
        watched = self._observed_rows.rows(t, req.observe)
        if None in watched:
            ns = req.observe[watched.index(None)]
            raise FleetError(ErrorCode.NOT_FOUND, f"no robot called {ns!r} to observe", "observe")
        rows, span = self._commanded_rows.found()
        return StepJob(
            req, reply, names, v, w, rows_of=t.generation, rows=rows, here=_all_here(len(rows)),
            watched=self._observed_rows.found()[0], watched_of=t.generation, span=span,
        )  # fmt: skip

    def _commands(
        self, table: RobotTable, req: StepRequest, given: tuple[list[str], F64] | None
    ) -> tuple[list[str], F64, F64]:
        """A step's commands (``given``, else the request's), checked, as namespaces and (v,
        w) columns; their table rows are the commanded memo's (``found()``)."""
        if req.commands is not None and given is None:
            if req.cmd_vel:
                raise FleetError(ErrorCode.INVALID_VALUE, "give cmd_vel or commands, not both", "commands")
            names, values, field = req.commands.names, req.commands.rows(), "commands"  # checked there
        else:
            if given is not None:
                (names, values), field = given, "commands"
            else:
                names = list(req.cmd_vel)
                values = np.array([(tw.linear.x, tw.angular.z) for tw in req.cmd_vel.values()], dtype=np.float64)
                field = "cmd_vel"
            values = values.reshape(len(names), 2)
            check_finite_commands(names, values, field)
        rows = self._commanded_rows.rows(table, names)
        if None in rows:
            ns = names[rows.index(None)]
            raise FleetError(ErrorCode.NOT_FOUND, f"no robot with namespace {ns!r}", field)
        v, w = values.T.copy()  # (one copy: two contiguous rows)
        return names, v, w


@functools.lru_cache(maxsize=8)
def _all_here(n: int) -> npt.NDArray[np.bool_]:
    """``StepJob.here`` of a job whose robots are all in the world (read only, shared)."""
    here = np.ones(n, dtype=bool)
    here.flags.writeable = False
    return here


def step_result(
    sim: Simulation, job: StepJob, clock: Clock, cancelled: bool, last: TickSnapshot | None, scans: LatestScans
) -> StepResult:
    """What a step answers: the clock after it, the ticks that ran, the observations asked for
    (as records, or packed as arrays)."""
    if job.request.packed:
        return StepResult(clock, job.ran, cancelled, packed=_observe_packed(sim, job, last, scans))
    states = {}
    found = {}
    for key in job.request.observe:
        robot = sim.find(key)
        if robot is None:  # deleted during the step
            continue
        states[key] = sim.state(robot)
        scan = scans.get(robot.namespace)
        if scan is not None:
            found[key] = ScanRow(*scan)
    return StepResult(clock, job.ran, cancelled, states, found)


def _observe_packed(sim: Simulation, job: StepJob, last: TickSnapshot | None, scans: LatestScans) -> ObservedArrays:
    """The odometry and latest scans of the robots the step observes, as arrays (robots
    deleted during the step left out)."""
    t, keys = sim.robots, job.request.observe
    if job.watched_of == t.generation:  # no spawn or delete since the request came
        names, rows = keys, job.watched
    else:
        found = t.rows_of(keys)
        names = [key for key, row in zip(keys, found, strict=True) if row is not None]
        rows = np.array([row for row in found if row is not None], dtype=np.int64)
    return observe_packed(t, last, scans, names, rows, sim.config.lidar.samples)
