"""The navigator's words in Nav2's messages, and Nav2's goals in the navigator's: pure conversions.

A goal comes as a ``geometry_msgs/PoseStamped`` (the action's goal, or RViz's "2D Goal Pose" on
``goal_pose``). fleetsim has one coordinate frame, the world, and every robot's odometry is its
ground truth in it (the ``<ns>/odom`` frames all coincide with the world), so a goal is taken as
it is when its frame names the world, and refused when it names anything else, which would need
a transform fleetsim does not have (a robot's ``base_link``, another robot's odom):

- ``""``, ``map``, ``odom``, ``world``, the daemon's ``--ros-world-frame``;
- ``<ns>/map`` and ``<ns>/odom`` of the robot the goal is for;
- each with or without a leading ``/``.

``map`` is the world as long as no SLAM or localisation node publishes a map of its own; a goal
in such a map's frame reaches the robot in world coordinates all the same.

What goes back is stamped in sim time (``/clock``) in the robot's world-aligned frame
(tf_layout.TfLayout.pose_frame): ``map`` when the daemon localises, else the
``--ros-world-frame`` if there is one, else ``<ns>/odom`` (``odom`` in Nav2's multi-robot layout).

How a goal ends, in Nav2's terms: reached is SUCCEEDED; cancelled (on request, or by a reset of
the world) is CANCELED; everything else is ABORTED, a goal replaced by a newer one included,
as Nav2's ``SimpleActionServer::accept_pending_goal`` aborts the goal it preempts. Jazzy's
result carries an ``error_code`` (Nav2's codes: Jazzy's bt_navigator reports the code of the
server that failed, ComputePathToPose 2xx or FollowPath 1xx, and Kilted's NavigateToPose
defines its own 9xxx) and the navigator's sentence in ``error_msg``; Humble's result is empty.
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np
from rosbags.typesys.store import Typestore

from protocol.errors import ErrorCode, FleetError
from protocol.messages import Time
from protocol.navigation import NavigateRequest, NavigationFeedback, NavigationPath, NavigationResult
from simd.adapters.ros2.action_server import GoalStatus
from simd.adapters.ros2.gazebo_services import yaw_of
from simd.adapters.ros2.service_server import zero_message

#: Nav2's error codes for the ways a goal fails
NONE = 0
UNKNOWN = 9000  # NavigateToPose (Kilted)
TIMEOUT = 9003  # NavigateToPose (Kilted)
PLANNER_UNKNOWN = 200  # ComputePathToPose
GOAL_OUTSIDE_MAP = 204
GOAL_OCCUPIED = 206
NO_VALID_PATH = 208
FAILED_TO_MAKE_PROGRESS = 105  # FollowPath
_FAILURE_CODES = {"no_path": NO_VALID_PATH, "blocked": FAILED_TO_MAKE_PROGRESS, "timeout": TIMEOUT,
                  "robot_gone": UNKNOWN, "preempted": NONE, "cancelled": NONE}  # fmt: skip
_REFUSAL_CODES = {ErrorCode.COLLISION: GOAL_OCCUPIED, ErrorCode.OUT_OF_BOUNDS: GOAL_OUTSIDE_MAP}
#: the navigator's refusals of a goal itself (where it is, its numbers): Nav2 accepts such a
#: goal and its planner fails it, so they end ABORTED; any other refusal (busy, no such
#: robot) refuses the goal
GOAL_REFUSALS = frozenset({ErrorCode.COLLISION, ErrorCode.OUT_OF_BOUNDS, ErrorCode.INVALID_VALUE, ErrorCode.NON_FINITE})

WORLD_FRAMES = ("", "map", "odom", "world")


class FrameRefused(ValueError):
    """A goal in a frame that is not the world's."""


def world_frames(namespace: str, world_frame: str | None) -> frozenset[str]:
    """The frame ids a goal for robot ``namespace`` may name (see the module docstring)."""
    frames = {*WORLD_FRAMES, f"{namespace}/map", f"{namespace}/odom"}
    if world_frame:
        frames.add(world_frame)
    return frozenset(frames)


def navigate_request(pose: Any, namespace: str, frames: frozenset[str], goal_id: str) -> NavigateRequest:
    """A PoseStamped as the navigator's goal for robot ``namespace`` (Nav2's default goal
    tolerances: 0.25 m, 0.25 rad), or :class:`FrameRefused`."""
    frame = str(pose.header.frame_id)
    if frame.lstrip("/") not in frames:
        allowed = ", ".join(repr(f) for f in sorted(frames))
        raise FrameRefused(
            f"goal frame {frame!r} is not the world's: fleetsim takes goals in {allowed} (it has no transforms)"
        )
    p, q = pose.pose.position, pose.pose.orientation
    return NavigateRequest(x=float(p.x), y=float(p.y), yaw=yaw_of(q.x, q.y, q.z, q.w), goal_id=goal_id,
                           robot=namespace)  # fmt: skip


def refusal_code(error: FleetError) -> int:
    """Nav2's planner code for a goal the navigator refused."""
    return _REFUSAL_CODES.get(error.code, PLANNER_UNKNOWN)


def outcome(result: NavigationResult) -> tuple[GoalStatus, dict[str, Any]]:
    """How a goal ended, as the action's status and ``<A>_Result`` fields."""
    if result.status == "reached":
        return GoalStatus.SUCCEEDED, {"error_code": NONE, "error_msg": ""}
    status = GoalStatus.CANCELED if result.reason == "cancelled" else GoalStatus.ABORTED
    return status, {"error_code": _FAILURE_CODES.get(result.reason, UNKNOWN), "error_msg": result.message}


class Messages:
    """Builds the ROS messages of one distro's store."""

    def __init__(self, store: Typestore) -> None:
        self.store = store
        self._t = store.types

    def time(self, stamp: Time) -> Any:
        return self._t["builtin_interfaces/msg/Time"](sec=stamp.sec, nanosec=stamp.nanosec)

    def duration(self, seconds: float) -> Any:
        ns = max(0, round(seconds * 1e9))
        return self._t["builtin_interfaces/msg/Duration"](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)

    def pose_stamped(self, stamp: Time, frame: str, x: float, y: float, yaw: float) -> Any:
        t = self._t
        header = t["std_msgs/msg/Header"](stamp=self.time(stamp), frame_id=frame)
        position = t["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=0.0)
        orientation = t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))
        return t["geometry_msgs/msg/PoseStamped"](
            header=header, pose=t["geometry_msgs/msg/Pose"](position=position, orientation=orientation)
        )

    def path(self, path: NavigationPath, frame: str) -> bytes:
        """nav_msgs/msg/Path: each point headed for the next (the last as the one before it)."""
        pts = path.points
        yaws = [math.atan2(b[1] - a[1], b[0] - a[0]) for a, b in itertools.pairwise(pts)]
        if pts:
            yaws.append(yaws[-1] if yaws else 0.0)
        poses = [self.pose_stamped(path.stamp, frame, x, y, yaw) for (x, y), yaw in zip(pts, yaws, strict=True)]
        header = self._t["std_msgs/msg/Header"](stamp=self.time(path.stamp), frame_id=frame)
        message = self._t["nav_msgs/msg/Path"](header=header, poses=poses)
        return bytes(self.store.serialize_cdr(message, "nav_msgs/msg/Path"))

    def feedback(self, action_type: str, uuid: bytes, fb: NavigationFeedback, frame: str) -> bytes:
        """``<A>_FeedbackMessage`` of NavigateToPose: where the robot is, time spent and left,
        recoveries, metres left along its path (Lyrical's and Rolling's tracking errors, how far
        the robot is off its path, stay zero: the navigator does not measure them)."""
        t = self._t
        inner = zero_message(self.store, f"{action_type}_Feedback", {
            "current_pose": self.pose_stamped(fb.stamp, frame, fb.pose.x, fb.pose.y, fb.pose.yaw),
            "navigation_time": self.duration(fb.navigation_time),
            "estimated_time_remaining": self.duration(fb.estimated_time_remaining),
            "number_of_recoveries": min(fb.recoveries, 32767),
            "distance_remaining": float(np.float32(fb.distance_remaining)),
        })  # fmt: skip
        goal_id = t["unique_identifier_msgs/msg/UUID"](uuid=np.frombuffer(uuid, dtype=np.uint8).copy())
        message = t[f"{action_type}_FeedbackMessage"](goal_id=goal_id, feedback=inner)
        return bytes(self.store.serialize_cdr(message, f"{action_type}_FeedbackMessage"))
