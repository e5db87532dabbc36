"""What the engine makes known to other threads, so that looking never waits for a tick.

A daemon that cannot keep its fleet in real time runs ticks back to back, each one longer
than a user waits for an answer. The clock, the robot list and the refusal of a spawn beyond
the robot limit need nothing of the simulation but what the simulation thread last made known,
so the engine publishes that as an immutable :class:`Status` after every tick and every request
it serves, and the adapters answer those requests on their own threads from it
(:meth:`simd.engine.Engine.answer_at_once`). A status is one reference, replaced whole: a
reader sees one consistent moment, never half of a spawn.
"""

from __future__ import annotations

from dataclasses import dataclass

from fleetcommon.arrays import F64
from protocol.control import Clock
from protocol.listing import find_row
from protocol.messages import Time
from simd.core.robots import Robot, RobotTable
from simd.core.sim import Simulation
from simd.engine.pacing import Timekeeper
from simd.engine.ports import OwnRobots


@dataclass(frozen=True)
class Roster:
    """Every robot at sim ``time``, in spawn order: ``robots[k]`` is row ``k`` of the columns
    (true pose and body-frame twist, ``lateral`` its sideways part). The columns are the
    table's own arrays, which the step replaces rather than writes into, so they stay as they
    were."""

    time: float
    robots: list[Robot]
    x: F64
    y: F64
    yaw: F64
    linear: F64
    angular: F64
    lateral: F64
    #: each robot's name and namespace, row by row (the table's lists, replaced when rows change
    #: and never changed in place: searched in C by whoever looks a robot up, never rebuilt)
    names: list[str]
    namespaces: list[str]

    @classmethod
    def of(cls, table: RobotTable, time: float, robots: list[Robot]) -> Roster:
        return cls(time, robots, table.x, table.y, table.yaw, table.vx, table.wz, table.vy, table.names,
                   table.namespaces)  # fmt: skip

    def row(self, key: str) -> int | None:
        """The row of the robot with this name or namespace (protocol/listing.py)."""
        return find_row(self.names, self.namespaces, key)


@dataclass(frozen=True)
class Status:
    """The engine as the simulation thread last saw it (see the module docstring). The clock
    is kept as its parts: what grows with the wall clock (``behind_s`` while running) is worked
    out when asked."""

    time: float
    tick: int
    dt: float
    paused: bool
    lockstep: bool
    target_rtf: float
    real_time_factor: float
    robots: int
    falling_behind: bool
    tick_s: float
    capacity_robots: int
    #: the pacer's grid: the wall seconds it slipped, the next deadline and the period
    slipped_s: float
    next_deadline: float
    period: float
    max_robots: int
    roster: Roster
    epoch: int = 0  # resets so far

    def behind_s(self, now: float) -> float:
        """As :meth:`simd.engine.pacing.Pacer.behind_s`, at ``now``."""
        if self.paused or self.period <= 0:
            return 0.0
        return (self.slipped_s + max(0.0, now - self.next_deadline - self.period)) * self.target_rtf

    def clock(self, now: float, dropped_commands: int) -> Clock:
        return Clock(
            clock=Time.from_seconds(self.time),
            tick=self.tick,
            dt=self.dt,
            paused=self.paused,
            lockstep=self.lockstep,
            real_time_factor=self.real_time_factor,
            target_real_time_factor=self.target_rtf,
            robots=self.robots,
            dropped_commands=dropped_commands,
            behind_s=self.behind_s(now),
            falling_behind=self.falling_behind,
            tick_s=self.tick_s,
            capacity_robots=self.capacity_robots,
        )


class StatusBoard:
    """Builds the engine's :class:`Status` (on the simulation thread). The robot table's list of
    robots grows in place, so the roster keeps a copy, made again only when the rows change."""

    def __init__(self) -> None:
        self._of: int | None = None  # the table generation the copy was made at
        self._robots: list[Robot] = []
        self._models: tuple[int | None, list[str]] = (None, [])  # (table generation, its models)

    def own_robots(self, sim: Simulation) -> OwnRobots:
        """This daemon's robots as the next tick is about to run: what the other daemons of a
        shared fleet place as ghosts (simd/engine/ports.py)."""
        t = sim.robots
        if self._models[0] != t.generation:
            self._models = (t.generation, [r.model.name for r in t.robots])
        return OwnRobots(sim.tick, t.namespaces, self._models[1], t.x, t.y, t.yaw)

    def stood_still_clock(self, sim: Simulation, keeper: Timekeeper, lockstep: bool, dropped_commands: int) -> Clock:
        """The clock of a step's reply while time stands still between steps (paused, in
        lockstep) and nothing measured is in it: what ``status(sim, keeper, True, lockstep,
        False).clock(now, dropped_commands)`` gives at any ``now``, without the status, which a
        learner's step of one robot would notice (~3 µs of ~200)."""
        return Clock(
            clock=Time.from_seconds(sim.time),
            tick=sim.tick,
            dt=sim.config.dt,
            paused=True,
            lockstep=lockstep,
            real_time_factor=0.0,
            target_real_time_factor=keeper.rtf,
            robots=len(sim),
            dropped_commands=dropped_commands,
            behind_s=0.0,
            falling_behind=False,
            tick_s=0.0,
            capacity_robots=0,
        )

    def status(self, sim: Simulation, keeper: Timekeeper, paused: bool, lockstep: bool, measured_cost: bool) -> Status:
        t = sim.robots
        if self._of != t.generation:
            self._robots, self._of = list(t.robots), t.generation
        running = not paused
        measured = keeper.meter.measure() if running else None
        rtf, pacer = keeper.rtf, keeper.pacer
        return Status(
            time=sim.time,
            tick=sim.tick,
            dt=sim.config.dt,
            paused=paused,
            lockstep=lockstep,
            target_rtf=rtf,
            # until the first tick after a resume there is nothing to measure: the target
            real_time_factor=0.0 if paused else (rtf if measured is None else measured),
            robots=len(sim),
            falling_behind=running and keeper.lag.behind,
            tick_s=keeper.cost.mean_s if measured_cost else 0.0,
            capacity_robots=keeper.capacity() if measured_cost else 0,
            slipped_s=pacer.slipped_s,
            next_deadline=pacer.next,
            period=pacer.period,
            max_robots=sim.config.max_robots,
            roster=Roster.of(t, sim.time, self._robots),
            epoch=sim.epoch,
        )
