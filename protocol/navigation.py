"""Navigation on the wire: send a robot to a goal, follow it, cancel it (docs/protocol.md).

Each robot has its own keys (``P/<ns>/navigate`` and below), as it has its own ``cmd_vel``, so
access control can give a driver one robot's goals and nothing else. What they carry mirrors
Nav2's ``navigate_to_pose`` action (goal, feedback, result) so that the ROS 2 action and the
fleet protocol tell the same story: a goal is accepted or refused at once (a goal in a wall or
off the map is refused, and nothing moves), then it is planned and driven, and ends once with
a :class:`NavigationResult`.
"""

from __future__ import annotations

from typing import Literal

import msgspec

from protocol.control import Pose2D
from protocol.messages import Time

#: Nav2's goal checker defaults (nav2_params.yaml: xy_goal_tolerance, yaw_goal_tolerance).
DEFAULT_TOLERANCE_M = 0.25
DEFAULT_YAW_TOLERANCE_RAD = 0.25
#: the longest goal id a client may choose (a ROS goal's UUID is 32 hex digits)
MAX_GOAL_ID_LENGTH = 64

#: What a robot with a goal is doing. ``planning``: its path is being found; ``driving``: it
#: follows it; ``waiting``: another robot holds the way ahead (fleet traffic); ``yielding``: it
#: makes way for another robot (a meeting in a passage one robot wide); ``blocked``: its lidar
#: sees something the map lacks on its path (it stops, then plans around it); ``overridden``:
#: somebody else's cmd_vel drives it for now (it goes on when they stop); ``reached`` and
#: ``failed`` end the goal.
State = Literal["planning", "driving", "waiting", "yielding", "blocked", "overridden", "reached", "failed"]
ACTIVE_STATES: frozenset[str] = frozenset({"planning", "driving", "waiting", "yielding", "blocked", "overridden"})

#: Why a goal failed. ``no_path``: nothing connects the robot to the goal; ``blocked``: the way
#: stayed blocked for the goal's patience; ``timeout``: the goal's time ran out; ``cancelled``:
#: somebody cancelled it; ``preempted``: a newer goal for the same robot replaced it;
#: ``robot_gone``: the robot was deleted (or its daemon restarted without ``--state``).
Reason = Literal["no_path", "blocked", "timeout", "cancelled", "preempted", "robot_gone"]
REASONS: tuple[str, ...] = ("no_path", "blocked", "timeout", "cancelled", "preempted", "robot_gone")


class NavigateRequest(msgspec.Struct, kw_only=True):
    """``P/<ns>/navigate``: drive robot ``<ns>`` to (``x``, ``y``) in the world frame.

    ``yaw`` (rad) is the heading to arrive with, or None for any. The goal is reached once the
    robot is within ``tolerance`` m of it (and ``yaw_tolerance`` rad of ``yaw``, if given).
    ``timeout`` (s of sim time, 0 = none) fails the goal with ``timeout`` when it runs out.
    ``goal_id`` names the goal (the daemon makes one up when it is empty; the ROS adapter passes
    the action's UUID). A new goal for a robot that has one preempts the old one."""

    x: float
    y: float
    yaw: float | None = None
    tolerance: float = DEFAULT_TOLERANCE_M
    yaw_tolerance: float = DEFAULT_YAW_TOLERANCE_RAD
    timeout: float = 0.0
    goal_id: str = ""
    #: the robot, taken from the key by the daemon (a value in the body is ignored)
    robot: str = ""


class CancelRequest(msgspec.Struct, kw_only=True):
    """``P/<ns>/navigate/cancel``: end the robot's goal (``goal_id`` empty: whichever it has)."""

    goal_id: str = ""
    robot: str = ""  # from the key, as in NavigateRequest


class NavigationStateRequest(msgspec.Struct, kw_only=True):
    """``P/<ns>/navigate/state``: the robot's current goal, or its last one."""

    robot: str = ""  # from the key


#: The navigation requests (one key each, per robot: ``robot`` comes from the key).
NavigationRequest = NavigateRequest | CancelRequest | NavigationStateRequest


class NavigateReply(msgspec.Struct, kw_only=True):
    """A goal was accepted: it is the robot's goal now (planning starts at the next tick)."""

    goal_id: str
    robot: str  # the namespace
    goal: Pose2D
    #: the goal that this one preempted, if the robot had one
    preempted: str = ""
    stamp: Time = msgspec.field(default_factory=Time)


class NavigationFeedback(msgspec.Struct, kw_only=True):
    """``P/<ns>/navigate/feedback``, at 5 Hz of sim time while a goal is active (as Nav2's
    NavigateToPose feedback: current pose, distance and time left, time so far, recoveries)."""

    goal_id: str
    robot: str
    stamp: Time
    state: str
    pose: Pose2D
    #: metres along the planned path (0 before the first plan)
    distance_remaining: float
    #: seconds, at the model's top speed plus the time already spent waiting (an estimate)
    estimated_time_remaining: float
    #: seconds of sim time since the goal was accepted
    navigation_time: float
    #: times it had to plan again (blocked, a detour, making way for another robot)
    recoveries: int = 0
    #: the robot it waits for or makes way for (``waiting``, ``yielding``), else empty
    other: str = ""


class NavigationResult(msgspec.Struct, kw_only=True):
    """``P/<ns>/navigate/result``: how a goal ended, once. ``status`` is ``reached`` or
    ``failed``; a failure has a ``reason`` (see :data:`REASONS`) and a sentence in ``message``."""

    goal_id: str
    robot: str
    stamp: Time
    status: Literal["reached", "failed"]
    reason: str = ""
    message: str = ""
    goal: Pose2D = msgspec.field(default_factory=Pose2D)
    pose: Pose2D = msgspec.field(default_factory=Pose2D)
    navigation_time: float = 0.0
    #: metres driven (the odometry's path length) while the goal was active
    distance_travelled: float = 0.0
    recoveries: int = 0


class NavigationState(msgspec.Struct, kw_only=True):
    """``P/<ns>/navigate/state``: the goal (None if the robot never had one), its latest
    feedback while active, and its result once it ended."""

    robot: str
    goal_id: str = ""
    goal: NavigateRequest | None = None
    active: bool = False
    feedback: NavigationFeedback | None = None
    result: NavigationResult | None = None


class NavigationPath(msgspec.Struct, kw_only=True):
    """``P/<ns>/plan``: the path the robot follows, put each time it is planned (and empty
    when a goal ends). Points in the world frame, start (the robot) first, goal last; what RViz
    shows as ``/<ns>/plan``."""

    goal_id: str
    robot: str
    stamp: Time
    points: list[tuple[float, float]]


class RobotNavigation(msgspec.Struct, kw_only=True):
    """One robot's row of :class:`FleetNavigation`."""

    robot: str
    goal_id: str
    state: str
    goal: Pose2D
    distance_remaining: float
    other: str = ""
    reason: str = ""  # of a goal that ended since the last message
    #: the goal's ``tolerance`` (m) and whether it asks for a heading (``goal.yaw`` is 0 when
    #: it does not): what a viewer needs to draw the goal without asking each robot's state
    tolerance: float = DEFAULT_TOLERANCE_M
    has_yaw: bool = False


class FleetNavigation(msgspec.Struct, kw_only=True):
    """``P/navigation``, at 2 Hz of sim time while somebody subscribes: every robot with an
    active goal, and those whose goal ended since the last message (what a viewer or a fleet
    dashboard draws)."""

    stamp: Time
    robots: list[RobotNavigation]
    #: wall seconds the navigator has worked on the daemon's simulation thread since it started
    #: (what navigating costs the simulation; a benchmark reads it)
    work_seconds: float = 0.0
