"""A robot as the navigator knows it: its goal, its state, what it has seen and done.

Every robot of the world has one (navigating or not: the others need to know where it stands).
The floor (simd/nav/floor.py) keeps its own record of the robot in the traffic, by ``slot``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from fleetcommon.arrays import F64
from protocol.navigation import ACTIVE_STATES, NavigateRequest, NavigationFeedback, NavigationResult
from simd.core.models import RobotModel
from simd.nav.lidar_guard import LOOK_AHEAD_M


@dataclass(eq=False)
class NavRobot:
    """One robot as the navigator knows it (every robot of the world has one)."""

    namespace: str
    model: RobotModel
    slot: int  # its place in the floor (never reused)
    goal: NavigateRequest | None = None
    goal_id: str = ""
    state: str = ""  # "" before its first goal; else an ACTIVE state, "reached" or "failed"
    started: float = 0.0
    planned: bool = False  # its floor has a plan for its goal
    xy: tuple[float, float] | None = None  # where it is, as of the last control step
    now: float = 0.0
    #: the free room its lidar saw ahead of its front and of its back (lidar_guard), its
    #: heading then, and the returns in either corridor (world frame): the room on the end
    #: it drives with counts (``reversed``), and its returns are what it marks when blocked
    lidar_rooms: tuple[float, float] = (LOOK_AHEAD_M, LOOK_AHEAD_M)
    lidar_yaw: float = 0.0
    lidar_hits: tuple[F64, F64] = field(default_factory=lambda: (np.zeros((0, 2)), np.zeros((0, 2))))
    blocked_since: float | None = None
    stuck_since: float | None = None
    marks: list[tuple[F64, float]] = field(default_factory=list)  # points it saw blocked, until
    recoveries: int = 0
    travelled: float = 0.0
    command: tuple[float, float] = (0.0, 0.0)
    overridden_until: float = -math.inf
    result: NavigationResult | None = None
    feedback: NavigationFeedback | None = None
    ended: str = ""  # how its goal ended, for the next fleet summary
    held_up_at_goal: bool = False  # (lanes) in its goal's cell, the goal point's cells held by others
    #: the path last put on P/<ns>/plan, and when (a robot that leaves it gets a new one told)
    told_path: F64 = field(default_factory=lambda: np.zeros((0, 2)))
    told_at: float = -math.inf
    #: the least distance left it has had, and when it last got this much nearer (PROGRESS_M)
    best_left: float = math.inf
    progress_at: float = 0.0
    #: when it last got that much nearer, whatever it did meanwhile (waited, made way, planned)
    nearer_at: float = 0.0
    #: the corner of its way it goes to first (cutting it would reach into another's cells)
    corner: tuple[float, float] | None = None
    #: it drives with its back first (its way started behind it: navigator.SWITCH_ENDS_ABOVE_RAD)
    reversed: bool = False

    @property
    def active(self) -> bool:
        return self.state in ACTIVE_STATES

    @property
    def overridden(self) -> bool:
        return self.overridden_until >= self.now

    @property
    def blocked(self) -> F64 | None:
        """The points its lidar saw in its way that it still plans around."""
        live = [pts for pts, until in self.marks if until > self.now]
        return np.concatenate(live) if live else None
