"""The seam between the engine and its adapters: what crosses it, in both directions.

The engine owns the simulation on one thread. An adapter maps it to one outside world (the
fleet protocol over zenoh today; ROS 2, a recorder or other daemons next) and needs only
this module: it receives every tick's :class:`~simd.core.snapshot.TickSnapshot`, the events
between ticks and the clock, and gives back commands (newest per namespace) and requests
(typed, decoded at its edge) with a function to reply through. Nothing here knows a
transport or a wire format, so adding an adapter touches no core or engine file.

Threads: ``on_*`` and ``take_commands`` are called on the simulation thread and must return
quickly (hand work to a thread of the adapter's own); ``Engine.submit`` may be called from
any thread, and either raises at once (busy) or calls the :data:`Reply` exactly once, on the
simulation thread, after every ``on_*`` call that the request caused. ``Engine.answer_at_once``
answers on the caller's thread what needs no simulation thread (the clock, the world, a spawn
refused at the robot limit). An adapter whose ``on_tick`` may block (a full queue) may have a
``ready()`` method: the engine asks it before each tick and serves requests while it says no.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Protocol

from fleetcommon.arrays import F32, F64
from protocol.control import Clock
from protocol.errors import FleetError
from protocol.navigation import NavigateReply, NavigationResult, NavigationState
from simd.core.ghosts import GhostColumns
from simd.core.lidar import LidarSpec
from simd.core.snapshot import RobotState, TickSnapshot
from simd.core.worldfile import WorldGeometry
from simd.nav.navigator import NavEvents


@dataclass(frozen=True)
class SimulationSetup:
    """What does not change while the engine runs, for an adapter to build its encoders and
    maps from (``Engine.setup``): an adapter sees this, never the simulation itself."""

    dt: float  # one tick, in sim seconds
    lidar: LidarSpec
    world: WorldGeometry
    navigation: bool  # the engine navigates robots to goals (not with ``--no-nav``)


@dataclass(frozen=True)
class Spawned:
    """A robot joined at sim ``time``; it stands at its spawn pose, at rest."""

    robot: RobotState
    time: float


@dataclass(frozen=True)
class Deleted:
    """A robot left; ``robot`` is its last state, ``at`` the (epoch, tick) it left at."""

    robot: RobotState
    at: tuple[int, int] = (0, 0)


@dataclass(frozen=True)
class WorldReset:
    """Time went back to zero and every robot to its spawn pose (``epoch`` counts resets)."""

    epoch: int


@dataclass(frozen=True)
class Navigation:
    """What the navigator said during a tick (results, paths, feedback, the fleet's summary:
    protocol/navigation.py's messages). Handed on even by steps that do not publish: a goal's
    result must reach the client that waits for it."""

    events: NavEvents


Event = Spawned | Deleted | WorldReset | Navigation


@dataclass(frozen=True)
class PlaceRequest:
    """Put a robot (name or namespace) at a pose at once, at rest: ROS's ``initialpose``
    (simd/adapters/ros2/localization.py). An engine request that no fleet protocol key carries;
    answered with the robot's :class:`~simd.core.snapshot.RobotState` there."""

    robot: str
    x: float
    y: float
    yaw: float


@dataclass(frozen=True)
class ScanRow:
    """A robot's latest scan: row ``row`` of a tick's scans (read when asked for: the lidar
    may still be casting it)."""

    snapshot: TickSnapshot
    row: int

    @property
    def time(self) -> float:
        return self.snapshot.time

    @property
    def ranges(self) -> F32:
        row: F32 = self.snapshot.scans[self.row]
        return row


@dataclass(frozen=True)
class RobotList:
    """The answer to a list request: every robot, in spawn order, at sim ``time``."""

    time: float
    robots: list[RobotState]


@dataclass(frozen=True)
class ObservedArrays:
    """The observations of a packed step, row by row in ``names`` order: ``odom`` (n, 6) is
    each robot's odometry (x, y, yaw, linear x, linear y, angular z) after the step's last
    tick, ``scan_time`` (n,) and ``ranges`` (n, samples) its latest scan (NaN before the first)."""

    names: list[str]
    odom: F64
    scan_time: F64
    ranges: F32


@dataclass(frozen=True)
class StepResult:
    """The answer to a step: the clock after it, the ticks that ran, and observations."""

    clock: Clock
    ticks_run: int
    cancelled: bool
    states: dict[str, RobotState] = field(default_factory=dict)
    scans: dict[str, ScanRow] = field(default_factory=dict)
    packed: ObservedArrays | None = None  # instead of states and scans, when the step asked


#: What a request is answered with: a core or engine value, or the error that refused it.
Result = (
    RobotState | RobotList | WorldGeometry | Clock | StepResult | NavigateReply | NavigationResult | NavigationState
)
Reply = Callable[[Result | FleetError], None]


class Adapter(Protocol):
    """One outside world, as the engine sees it."""

    def on_tick(self, snapshot: TickSnapshot) -> None:
        """A tick ran; ``snapshot`` is immutable and may be kept."""

    def on_event(self, event: Event) -> None:
        """Something changed between ticks (called before the reply to the request that did it)."""

    def on_clock(self, clock: Clock) -> None:
        """The clock, at 10 Hz of sim time and whenever pause, resume or reset change it."""

    def take_commands(self) -> Mapping[str, tuple[float, float]]:
        """The newest (linear x, angular z) per namespace since the last call."""
        ...

    def dropped_commands(self) -> int:
        """Commands this adapter refused (undecodable, not finite) so far, for the clock."""
        ...

    def close(self) -> None:
        """Stop: undeclare, join threads. Called once, on the thread that ran the engine."""


@dataclass(frozen=True)
class OwnRobots:
    """This daemon's robots as a step is about to run tick ``tick + 1``: true poses, rows of
    ``namespaces``. What the other daemons of a shared fleet place as ghosts for that tick."""

    tick: int
    namespaces: list[str]
    models: list[str]
    x: F64
    y: F64
    yaw: F64


class GhostSource(Protocol):
    """The robots simulated elsewhere (the other daemons of a shared fleet), asked before each tick."""

    def take(self, own: OwnRobots, stepping: bool) -> GhostColumns | None:
        """Hear of this daemon's robots; return the others' when they changed, else None:
        while a step runs (``stepping``) those of the same tick (one clock), otherwise the
        latest (real time)."""
        ...

    def forget(self) -> None:
        """This world was reset (every daemon of a fleet is, before the next step): what the
        others put before is of the old run."""
        ...
