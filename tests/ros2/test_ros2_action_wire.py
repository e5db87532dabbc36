"""Golden tests of the ROS 2 action pieces: type hashes against independent sources, the goal
book's rules against rcl_action's, and the navigation messages against the stand-in's rosbags.

Hash sources: rosidl's own ``share/<pkg>/<kind>/<Type>.json`` files as the PyPI wheels
ros-action-msgs 2.3.0, ros-nav-msgs 5.5.1 and ros-test-msgs 2.3.0 ship them (action_msgs and
nav_msgs are the same on Jazzy); test_msgs' Fibonacci is the one action whose rosidl hashes are
published, so it checks how both the adapter and the stand-in expand an action. No published
hash of nav2_msgs' NavigateToPose was found: its values are computed (by the adapter from .msg
text, by the stand-in from IDL, which must agree) and pinned.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from protocol.control import Pose2D
from protocol.errors import ErrorCode, FleetError
from protocol.messages import Time
from protocol.navigation import NavigationFeedback, NavigationPath, NavigationResult
from simd.adapters.ros2 import interfaces, nav_messages
from simd.adapters.ros2.action_server import CancelCode, GoalBook, GoalStatus, status_array
from tests.ros2 import standin
from tests.ros2.conftest import pose_stamped

NAV = "nav2_msgs/action/NavigateToPose"
#: rosidl's values (the wheels' JSON files, see the module docstring)
OFFICIAL = {
    "action_msgs/srv/CancelGoal": "573d8b0a534451d7bc2ac8c5ffde8ac14b8593b7001175d0cd6516dcbeb8689a",
    "action_msgs/msg/GoalStatusArray": "6c1684b00f177d37438febe6e709fc4e2b0d4248dca4854946f9ed8b30cda83e",
    "nav_msgs/msg/Path": "1957a5bb3cee5da65c4e52e52b65a93df227efce4c20f8458b36e73066ca334b",
    "geometry_msgs/msg/PoseStamped": "10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8",
}
FIBONACCI = {
    "test_msgs/action/Fibonacci": "be9273e3557225044b4a040811112491f7079326e3a573f83258b0b4c30bd069",
    "test_msgs/action/Fibonacci_SendGoal": "d807633803e38e164276573cd97e9fbd71e109c290bbf4cc312a0a1c9da7bbd9",
    "test_msgs/action/Fibonacci_GetResult": "5d30fdeb21d20e117aa5f36c7b4f0b6874f1a8cf7a9c038d58f1156c5737b209",
    "test_msgs/action/Fibonacci_FeedbackMessage": "37487bae8cea358366b97003c1ef1ca7ce7c08df36f9e8cca496624226aee64e",
    "test_msgs/action/Fibonacci_Goal": "e58ef5a8f4f039ab522a740823547c460b1d5aed8031c8b7825d33d345d90df8",
}
#: computed for Jazzy (and Kilted: the same fields) and pinned
NAVIGATE_TO_POSE = {
    NAV: "a56dba8a3234a1215e610180dc703ae25bbf406dded8b54887891c9732857eab",
    f"{NAV}_SendGoal": "a4fcb3bee1bf32e21a0e541a943b221aa0826996e2c98f079b47022b256f48b5",
    f"{NAV}_GetResult": "c407920357d566771e8882b4ef4d1f1a84ee922d609920ccd57faa6d6e391dc5",
    f"{NAV}_FeedbackMessage": "9d1f6fa2eb975ce733b419ac2e97b134d8ff92b6478b6559feed9a50bdfd82b3",
}


# -- hashes ------------------------------------------------------------------------------------


@pytest.mark.parametrize(("typename", "digest"), {**OFFICIAL, **NAVIGATE_TO_POSE}.items())
def test_action_hashes_pinned_and_equal_to_the_stand_ins(typename: str, digest: str) -> None:
    assert interfaces.rihs01(typename) == f"RIHS01_{digest}"
    assert standin.type_hash(typename) == f"RIHS01_{digest}"
    assert interfaces.type_hash(typename, "humble") == "TypeHashNotSupported"


def test_fibonacci_through_both_expansions_equals_rosidls() -> None:
    """The adapter's and the stand-in's way of expanding an action, against rosidl's hashes."""
    store = interfaces._hashing_store()
    name = "test_msgs/action/Fibonacci"
    store.register(
        interfaces.action_definitions(name, "int32 order", "int32[] sequence", "int32[] sequence", with_event=True)
    )
    for typename, digest in FIBONACCI.items():
        assert interfaces.rihs01(typename, store) == f"RIHS01_{digest}", typename
        assert standin.type_hash(typename) == f"RIHS01_{digest}", typename


def test_dds_names_of_an_actions_parts() -> None:
    """rmw_zenoh names a service by its response type less ``Response_``, in the action's namespace."""
    assert interfaces.dds_type_name(f"{NAV}_SendGoal") == "nav2_msgs::action::dds_::NavigateToPose_SendGoal_"
    assert interfaces.dds_type_name(f"{NAV}_FeedbackMessage") == (
        "nav2_msgs::action::dds_::NavigateToPose_FeedbackMessage_"
    )


def test_humble_result_is_empty_and_its_cdr_is_rosbags() -> None:
    """Humble's NavigateToPose result is std_msgs/Empty (one uint8 in CDR)."""
    store = interfaces.typestore("humble")
    response_type = f"{NAV}_GetResult_Response"
    empty = store.types["std_msgs/msg/Empty"](structure_needs_at_least_one_member=0)
    message = store.types[response_type](status=4, result=store.types[f"{NAV}_Result"](result=empty))
    assert bytes(store.serialize_cdr(message, response_type)) == b"\x00\x01\x00\x00\x04\x00"
    jazzy = interfaces.typestore("jazzy").fielddefs[f"{NAV}_Result"][1]
    assert [name for name, _ in jazzy] == ["error_code", "error_msg"]


# -- the goal book: rcl_action_process_cancel_request and rclcpp's get_result ------------------


def _book(*goals: tuple[int, tuple[int, int]]) -> GoalBook:
    book = GoalBook(kept=2)
    for n, stamp in goals:
        book.accept(bytes([n]) * 16, stamp)
    return book


def test_cancel_one_goal_by_id() -> None:
    book = _book((1, (5, 0)))
    code, goals = book.to_cancel(bytes([1]) * 16, (0, 0))
    assert (code, [g.uuid for g in goals]) == (CancelCode.ERROR_NONE, [bytes([1]) * 16])
    assert book.to_cancel(bytes([9]) * 16, (0, 0)) == (CancelCode.ERROR_UNKNOWN_GOAL_ID, [])
    book.end(bytes([1]) * 16, GoalStatus.SUCCEEDED, {})
    assert book.to_cancel(bytes([1]) * 16, (0, 0)) == (CancelCode.ERROR_GOAL_TERMINATED, [])


def test_cancel_by_stamp_all_and_id_plus_stamp() -> None:
    book = _book((1, (5, 0)), (2, (7, 0)), (3, (9, 0)))
    assert [g.uuid[0] for g in book.to_cancel(bytes(16), (0, 0))[1]] == [1, 2, 3]  # all
    assert [g.uuid[0] for g in book.to_cancel(bytes(16), (7, 0))[1]] == [1, 2]  # at or before
    assert [g.uuid[0] for g in book.to_cancel(bytes([3]) * 16, (5, 0))[1]] == [1, 3]  # both rules
    book.end(bytes([1]) * 16, GoalStatus.ABORTED, {})
    assert [g.uuid[0] for g in book.to_cancel(bytes(16), (0, 0))[1]] == [2, 3]  # ended goals stay ended
    assert book.to_cancel(bytes([9]) * 16, (1, 0)) == (CancelCode.ERROR_NONE, [])  # a stamp: no unknown-id code


def test_get_result_waits_for_the_end_and_ended_goals_are_kept_up_to_a_count() -> None:
    book = _book((1, (1, 0)), (2, (2, 0)), (3, (3, 0)))
    answers: list[tuple[GoalStatus, dict[str, Any]]] = []
    book.result_of(bytes([1]) * 16, lambda s, r: answers.append((s, r)))
    assert answers == []  # it runs: the answer waits
    book.result_of(bytes([7]) * 16, lambda s, r: answers.append((s, r)))
    assert answers == [(GoalStatus.UNKNOWN, {})]
    assert book.end(bytes([1]) * 16, GoalStatus.SUCCEEDED, {"error_code": 0})
    assert answers[-1] == (GoalStatus.SUCCEEDED, {"error_code": 0})
    assert not book.end(bytes([1]) * 16, GoalStatus.ABORTED, {})  # a goal ends once
    book.end(bytes([2]) * 16, GoalStatus.ABORTED, {})
    book.end(bytes([3]) * 16, GoalStatus.CANCELED, {})
    assert [g.uuid[0] for g in book.goals()] == [2, 3]  # kept=2: the oldest ended goal went


def test_status_array_bytes_equal_rosbags() -> None:
    book = _book((1, (5, 7)), (2, (6, 0)))
    book.end(bytes([1]) * 16, GoalStatus.SUCCEEDED, {})
    payload = status_array(interfaces.typestore("jazzy"), book.goals())
    m = standin.deserialize(payload, "action_msgs/msg/GoalStatusArray")
    rows = [(bytes(r.goal_info.goal_id.uuid), r.goal_info.stamp.sec, r.goal_info.stamp.nanosec, r.status)
            for r in m.status_list]  # fmt: skip
    assert rows == [(bytes([1]) * 16, 5, 7, 4), (bytes([2]) * 16, 6, 0, 2)]
    assert standin.serialize(m, "action_msgs/msg/GoalStatusArray") == payload


# -- navigation messages ------------------------------------------------------------------------


def _pose(frame: str, x: float = 1.0, y: float = 2.0, yaw: float = 0.5) -> Any:
    return pose_stamped(x, y, yaw, frame)


@pytest.mark.parametrize("frame", ["", "map", "/map", "odom", "world", "TB3_1/map", "TB3_1/odom", "/TB3_1/odom", "w"])
def test_goals_in_the_worlds_frames(frame: str) -> None:
    frames = nav_messages.world_frames("TB3_1", "w")
    req = nav_messages.navigate_request(_pose(frame), "TB3_1", frames, "ab" * 16)
    assert (req.x, req.y, req.goal_id, req.robot) == (1.0, 2.0, "ab" * 16, "TB3_1")
    assert req.yaw == pytest.approx(0.5)
    assert (req.tolerance, req.yaw_tolerance) == (0.25, 0.25)  # Nav2's goal checker


@pytest.mark.parametrize("frame", ["base_link", "TB3_1/base_footprint", "TB3_2/odom", "w"])
def test_goals_in_other_frames_are_refused(frame: str) -> None:
    with pytest.raises(nav_messages.FrameRefused, match="is not the world's"):
        nav_messages.navigate_request(_pose(frame), "TB3_1", nav_messages.world_frames("TB3_1", None), "x")


def _result(status: str, reason: str = "", message: str = "") -> NavigationResult:
    return NavigationResult(goal_id="g", robot="r", stamp=Time(), status=status, reason=reason,  # type: ignore[arg-type]
                            message=message)  # fmt: skip


@pytest.mark.parametrize(
    ("status", "reason", "expected"),
    [
        ("reached", "", (GoalStatus.SUCCEEDED, 0)),
        ("failed", "cancelled", (GoalStatus.CANCELED, 0)),
        ("failed", "preempted", (GoalStatus.ABORTED, 0)),
        ("failed", "no_path", (GoalStatus.ABORTED, 208)),
        ("failed", "blocked", (GoalStatus.ABORTED, 105)),
        ("failed", "timeout", (GoalStatus.ABORTED, 9003)),
        ("failed", "robot_gone", (GoalStatus.ABORTED, 9000)),
    ],
)
def test_how_goals_end_in_nav2s_terms(status: str, reason: str, expected: tuple[GoalStatus, int]) -> None:
    got, fields = nav_messages.outcome(_result(status, reason, "why"))
    assert (got, fields["error_code"]) == expected
    assert fields["error_msg"] == ("" if status == "reached" else "why")


def test_refusal_codes() -> None:
    assert nav_messages.refusal_code(FleetError(ErrorCode.COLLISION, "x")) == 206
    assert nav_messages.refusal_code(FleetError(ErrorCode.OUT_OF_BOUNDS, "x")) == 204
    assert nav_messages.refusal_code(FleetError(ErrorCode.INVALID_VALUE, "x")) == 200


def test_feedback_and_path_decode_as_the_stand_in_reads_them() -> None:
    msgs = nav_messages.Messages(interfaces.typestore("jazzy"))
    fb = NavigationFeedback(goal_id="g", robot="TB3_1", stamp=Time(sec=3, nanosec=5), state="driving",
                            pose=Pose2D(x=1.0, y=-2.0, yaw=0.3), distance_remaining=1.25,
                            estimated_time_remaining=5.5, navigation_time=2.25, recoveries=2)  # fmt: skip
    uuid = bytes(range(16))
    m = standin.deserialize(msgs.feedback(NAV, uuid, fb, "TB3_1/odom"), f"{NAV}_FeedbackMessage")
    assert bytes(m.goal_id.uuid) == uuid
    f = m.feedback
    assert f.current_pose.header.frame_id == "TB3_1/odom"
    assert (f.current_pose.header.stamp.sec, f.current_pose.header.stamp.nanosec) == (3, 5)
    assert (f.current_pose.pose.position.x, f.current_pose.pose.position.y) == (1.0, -2.0)
    q = f.current_pose.pose.orientation
    assert 2 * math.atan2(q.z, q.w) == pytest.approx(0.3)
    assert (f.navigation_time.sec, f.navigation_time.nanosec) == (2, 250_000_000)
    assert (f.estimated_time_remaining.sec, f.estimated_time_remaining.nanosec) == (5, 500_000_000)
    assert (f.number_of_recoveries, f.distance_remaining) == (2, np.float32(1.25))
    path = NavigationPath(goal_id="g", robot="TB3_1", stamp=Time(sec=1), points=[(0.0, 0.0), (1.0, 0.0), (1.0, 1.0)])
    p = standin.deserialize(msgs.path(path, "world"), "nav_msgs/msg/Path")
    assert p.header.frame_id == "world" and len(p.poses) == 3
    yaws = [2 * math.atan2(s.pose.orientation.z, s.pose.orientation.w) for s in p.poses]
    assert yaws == pytest.approx([0.0, math.pi / 2, math.pi / 2])  # each headed for the next
    empty = standin.deserialize(msgs.path(NavigationPath(goal_id="g", robot="r", stamp=Time(), points=[]), "w"),
                                "nav_msgs/msg/Path")  # fmt: skip
    assert len(empty.poses) == 0
