"""A ROS 2 action server as rcl_action keeps one: its goals, their status, results and cancels.

ROS 2 has no actions at the rmw level (rmw_zenoh's design document, "Actions"): rcl_action
builds one from three services and two topics under ``<action>/_action/``, and rmw_zenoh
carries those as any other service or topic (keys, ``SS``/``MP`` tokens, attachments):

=====================  ========================================  ======================
name                   type                                      rmw_zenoh entity
=====================  ========================================  ======================
``send_goal``          ``<A>_SendGoal`` (goal_id, goal)          service (SS)
``get_result``         ``<A>_GetResult`` (goal_id)               service (SS)
``cancel_goal``        ``action_msgs/srv/CancelGoal``            service (SS)
``feedback``           ``<A>_FeedbackMessage`` (goal_id, ...)    publisher (MP)
``status``             ``action_msgs/msg/GoalStatusArray``       publisher (MP), transient local, depth 1
=====================  ========================================  ======================

``ros2 action list`` finds an action by its ``/_action/feedback`` publisher (rcl_action's
graph.c); an action client's ``wait_for_action_server`` waits for the three services and both
publishers. This module holds what does not depend on the action's meaning: the names, the QoS
rcl_action gives each entity, and a :class:`GoalBook`, the goals of one server with rclcpp's
rules for them:

- a goal is known by its 16-byte UUID (chosen by the client; a UUID already known is refused)
  and stamped when accepted; it runs, then ends once, SUCCEEDED, CANCELED or ABORTED;
- ``get_result`` of a goal that runs waits until it ends; of an unknown goal it answers at once
  with status UNKNOWN (rclcpp_action's server does both);
- ``cancel_goal`` selects goals as ``rcl_action_process_cancel_request`` does (a UUID and no
  stamp: that goal, ERROR_UNKNOWN_GOAL_ID or ERROR_GOAL_TERMINATED if it cannot be; otherwise
  every running goal accepted at or before the stamp, or all of them for a zero stamp, plus
  the one named);
- ended goals stay listed (in the status array, for ``get_result``) until newer ones push them
  out: rcl_action forgets them after a result timeout (15 minutes), this book keeps the last
  :data:`ENDED_KEPT` instead, which needs no clock.

The book is plain data, used on the adapter's thread only.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

import numpy as np
from rosbags.typesys.store import Typestore

from simd.adapters.ros2.graph import Kind, Qos
from simd.adapters.ros2.service_server import zero_message

#: ended goals a server keeps for get_result and its status array
ENDED_KEPT = 16

UUID_BYTES = 16


class GoalStatus(IntEnum):
    """action_msgs/msg/GoalStatus."""

    UNKNOWN = 0
    ACCEPTED = 1
    EXECUTING = 2
    CANCELING = 3
    SUCCEEDED = 4
    CANCELED = 5
    ABORTED = 6


TERMINAL = frozenset({GoalStatus.SUCCEEDED, GoalStatus.CANCELED, GoalStatus.ABORTED})


class CancelCode(IntEnum):
    """action_msgs/srv/CancelGoal's return codes."""

    ERROR_NONE = 0
    ERROR_REJECTED = 1
    ERROR_UNKNOWN_GOAL_ID = 2
    ERROR_GOAL_TERMINATED = 3


#: QoS of rcl_action's entities: the services and the feedback as rmw's defaults (reliable,
#: volatile, depth 10), the status transient local with depth 1
#: (``rcl_action_qos_profile_status_default``), so a late client learns where goals stand
SERVICE_QOS = Qos(depth=10)
FEEDBACK_QOS = Qos(depth=10)
STATUS_QOS = Qos(depth=1, transient_local=True)

CANCEL_GOAL = "action_msgs/srv/CancelGoal"
STATUS_ARRAY = "action_msgs/msg/GoalStatusArray"


@dataclass(frozen=True)
class ActionPart:
    """One of the five entities of an action: its name under the action, type, kind and QoS."""

    suffix: str  # send_goal
    typename: str
    kind: Kind
    qos: Qos

    def name(self, action: str) -> str:
        """The entity's fully qualified name: ``/tb3_0/navigate_to_pose/_action/send_goal``."""
        return f"{action}/_action/{self.suffix}"


def action_parts(action_type: str) -> dict[str, ActionPart]:
    """The five entities of an action of ``action_type`` (``pkg/action/A``), by suffix."""
    parts = [
        ActionPart("send_goal", f"{action_type}_SendGoal", Kind.SERVICE, SERVICE_QOS),
        ActionPart("get_result", f"{action_type}_GetResult", Kind.SERVICE, SERVICE_QOS),
        ActionPart("cancel_goal", CANCEL_GOAL, Kind.SERVICE, SERVICE_QOS),
        ActionPart("feedback", f"{action_type}_FeedbackMessage", Kind.PUBLISHER, FEEDBACK_QOS),
        ActionPart("status", STATUS_ARRAY, Kind.PUBLISHER, STATUS_QOS),
    ]
    return {p.suffix: p for p in parts}


Stamp = tuple[int, int]  # (sec, nanosec)


@dataclass
class ServerGoal:
    """One goal of a server: accepted at ``stamp``, with its status and, once ended, its result
    (the ``<A>_Result`` fields); ``waiting`` are the answers owed to get_result calls."""

    uuid: bytes
    stamp: Stamp
    status: GoalStatus = GoalStatus.EXECUTING
    result: dict[str, Any] = field(default_factory=dict)
    waiting: list[Callable[[GoalStatus, dict[str, Any]], None]] = field(default_factory=list)

    @property
    def active(self) -> bool:
        return self.status not in TERMINAL


class GoalBook:
    """The goals of one action server, oldest first (see the module docstring)."""

    def __init__(self, kept: int = ENDED_KEPT) -> None:
        self._goals: dict[bytes, ServerGoal] = {}
        self._kept = kept

    def __contains__(self, uuid: bytes) -> bool:
        return uuid in self._goals

    def get(self, uuid: bytes) -> ServerGoal | None:
        return self._goals.get(uuid)

    def goals(self) -> list[ServerGoal]:
        return list(self._goals.values())

    def active(self) -> list[ServerGoal]:
        return [g for g in self._goals.values() if g.active]

    def accept(self, uuid: bytes, stamp: Stamp) -> ServerGoal:
        """A goal that runs from now (the caller checked that its UUID is new)."""
        goal = ServerGoal(uuid, stamp)
        self._goals[uuid] = goal
        return goal

    def end(self, uuid: bytes, status: GoalStatus, result: dict[str, Any]) -> bool:
        """The goal ended (once: a goal that already ended keeps its end); every get_result
        that waited for it is answered. Whether anything changed."""
        goal = self._goals.get(uuid)
        if goal is None or not goal.active:
            return False
        goal.status, goal.result = status, result
        waiting, goal.waiting = goal.waiting, []
        for answer in waiting:
            answer(status, result)
        self._forget_old()
        return True

    def result_of(self, uuid: bytes, answer: Callable[[GoalStatus, dict[str, Any]], None]) -> None:
        """get_result: ``answer`` now for a goal that ended or is unknown (UNKNOWN, no result),
        when it ends for one that runs."""
        goal = self._goals.get(uuid)
        if goal is None:
            answer(GoalStatus.UNKNOWN, {})
        elif goal.active:
            goal.waiting.append(answer)
        else:
            answer(goal.status, goal.result)

    def to_cancel(self, uuid: bytes, stamp: Stamp) -> tuple[CancelCode, list[ServerGoal]]:
        """The goals a CancelGoal request selects, and its return code, as rcl_action decides."""
        named = any(uuid)
        if named and stamp == (0, 0):
            goal = self._goals.get(uuid)
            if goal is None:
                return CancelCode.ERROR_UNKNOWN_GOAL_ID, []
            if not goal.active:
                return CancelCode.ERROR_GOAL_TERMINATED, []
            return CancelCode.ERROR_NONE, [goal]
        limit = stamp if stamp != (0, 0) else (2**63, 0)
        chosen = [g for g in self._goals.values() if g.active and (g.stamp <= limit or (named and g.uuid == uuid))]
        return CancelCode.ERROR_NONE, chosen

    def _forget_old(self) -> None:
        ended = [u for u, g in self._goals.items() if not g.active]
        for uuid in ended[: max(0, len(ended) - self._kept)]:
            del self._goals[uuid]

    def clear(self) -> list[ServerGoal]:
        """Forget every goal (the server goes away); the goals that still ran are returned."""
        running = self.active()
        self._goals.clear()
        return running


# -- messages ------------------------------------------------------------------------------------


def goal_info(store: Typestore, uuid: bytes, stamp: Stamp) -> Any:
    """action_msgs/msg/GoalInfo."""
    return store.types["action_msgs/msg/GoalInfo"](
        goal_id=store.types["unique_identifier_msgs/msg/UUID"](uuid=np.frombuffer(uuid, dtype=np.uint8).copy()),
        stamp=store.types["builtin_interfaces/msg/Time"](sec=stamp[0], nanosec=stamp[1]),
    )


def status_array(store: Typestore, goals: list[ServerGoal]) -> bytes:
    """The CDR of action_msgs/msg/GoalStatusArray listing ``goals``."""
    status_type = store.types["action_msgs/msg/GoalStatus"]
    rows = [status_type(goal_info=goal_info(store, g.uuid, g.stamp), status=int(g.status)) for g in goals]
    message = store.types[STATUS_ARRAY](status_list=rows)
    return bytes(store.serialize_cdr(message, STATUS_ARRAY))


def uuid_of(message: Any) -> bytes:
    """The 16 bytes of a unique_identifier_msgs/msg/UUID."""
    raw = bytes(bytearray(message.uuid))
    if len(raw) != UUID_BYTES:
        raise ValueError(f"a UUID has {UUID_BYTES} bytes, got {len(raw)}")
    return raw


def stamp_of(message: Any) -> Stamp:
    """(sec, nanosec) of a builtin_interfaces/msg/Time."""
    return int(message.sec), int(message.nanosec)


def result_message(store: Typestore, result_type: str, fields: dict[str, Any]) -> Any:
    """An ``<A>_Result`` of the fields its type has (Humble's NavigateToPose result has none of
    Jazzy's), the others zero."""
    known = {name for name, _ in store.fielddefs[result_type][1]}
    return zero_message(store, result_type, {k: v for k, v in fields.items() if k in known})
