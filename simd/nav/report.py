"""What the navigator tells the world, as protocol/navigation.py's messages.

Built on the simulation thread from the navigator's own records (plain data, so the adapters
only encode them): a goal's result once, each robot's feedback at 5 Hz of sim time, the
fleet's summary at 2 Hz, and the path a robot means to take each time it changes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fleetcommon.arrays import F64
from protocol.control import Pose2D
from protocol.messages import Time
from protocol.navigation import (
    FleetNavigation,
    NavigateRequest,
    NavigationFeedback,
    NavigationPath,
    NavigationResult,
    RobotNavigation,
)


@dataclass
class NavEvents:
    """What the navigator says after a tick: results of goals that ended, paths planned,
    feedback (5 Hz of sim time) and the fleet's summary (2 Hz)."""

    results: list[NavigationResult] = field(default_factory=list)
    plans: list[NavigationPath] = field(default_factory=list)
    feedback: list[NavigationFeedback] = field(default_factory=list)
    fleet: FleetNavigation | None = None

    def __bool__(self) -> bool:
        return bool(self.results or self.plans or self.feedback or self.fleet)


def pose(x: float, y: float, yaw: float = 0.0) -> Pose2D:
    return Pose2D(x=float(x), y=float(y), yaw=float(yaw))


def goal_pose(goal: NavigateRequest) -> Pose2D:
    return Pose2D(x=goal.x, y=goal.y, yaw=goal.yaw or 0.0)


def path_message(goal_id: str, robot: str, now: float, points: F64 | list[tuple[float, float]]) -> NavigationPath:
    pts = [(float(x), float(y)) for x, y in points]
    return NavigationPath(goal_id=goal_id, robot=robot, stamp=Time.from_seconds(now), points=pts)


def path_length(points: F64) -> float:
    if len(points) < 2:
        return 0.0
    return float(np.hypot(*np.diff(points, axis=0).T).sum())


def summary_row(
    robot: str, goal_id: str, state: str, goal: NavigateRequest, left: float, reason: str
) -> RobotNavigation:
    return RobotNavigation(
        robot=robot,
        goal_id=goal_id,
        state=state,
        goal=goal_pose(goal),
        distance_remaining=left,
        reason=reason,
        tolerance=goal.tolerance,
        has_yaw=goal.yaw is not None,
    )
