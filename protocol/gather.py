"""How several daemons' replies to one request make one answer (a shared fleet, docs/scale-out.md).

A client of a fleet asks every daemon at once (zenoh target *all*, no consolidation) and gets
a reply from each daemon that answers the key: the one daemon that owns the answer (a spawn
placed on it, the clock), or every daemon (a list, a delete, pause, resume, reset, a step).
The rules that make one answer of them are part of the shared fleet's contract, and two
programs apply them: the Python client (clients/api.py) and the ROS adapter's services, which
ask the fleet as any client does (simd/adapters/ros2/shared_fleet.py). They live here, in the
protocol, because it is the one package both may import (clients never import ``simd``; the
protocol imports neither), and because a client in another language must apply the same.

Pure: protocol messages and :class:`~protocol.errors.FleetError` in, one answer out; nothing
waits and nothing knows zenoh. :class:`Gathering` takes the replies as they arrive and says
when the answer is known; :func:`merge` makes one message of the good replies.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Generic, Literal, TypeVar, cast

import msgspec
import numpy as np
import numpy.typing as npt

from protocol.control import (
    ClockRequest,
    DeleteRequest,
    ListRequest,
    PackedObservations,
    PauseRequest,
    ResetRequest,
    ResumeRequest,
    RobotList,
    SpawnRequest,
    StepReply,
    StepRequest,
    WorldRequest,
)
from protocol.errors import FleetError

T = TypeVar("T")

#: How the replies make one answer:
#:
#: - ``first``: the first reply is the answer, good or a refusal (one daemon owns it: a spawn is
#:   answered by the daemon its name is placed on, the clock and the world by any one daemon);
#: - ``any``: one good reply is enough, a refusal is the answer only when no daemon replied well
#:   (a delete: the robot's daemon answers, the one its name is placed on may say not found;
#:   a list; pause, resume, reset);
#: - ``all``: every daemon must have acted, any refusal is the answer (a step: a daemon that
#:   refused did not step, and the fleet is not where the caller thinks).
Gather = Literal["first", "any", "all"]

#: How each request of the fleet protocol is gathered (others: ``any``).
GATHER: dict[type[Any], Gather] = {
    SpawnRequest: "first",
    ClockRequest: "first",
    WorldRequest: "first",
    DeleteRequest: "any",
    ListRequest: "any",
    PauseRequest: "any",
    ResumeRequest: "any",
    ResetRequest: "any",
    StepRequest: "all",
}


class Gathering(Generic[T]):
    """The replies to one request as they arrive: :meth:`add` each daemon's message or
    refusal (it says when the answer is known before the others reply), :meth:`answer` once
    they are all in (or the first one, for ``first``)."""

    def __init__(self, how: Gather) -> None:
        self.how = how
        self.replies: list[T | FleetError] = []  # in the order they came

    def add(self, reply: T | FleetError) -> bool:
        """Take one daemon's reply; True when the answer is known already (``first``)."""
        self.replies.append(reply)
        return self.how == "first"

    def answer(self, nobody: FleetError) -> list[T]:
        """The good replies that make the answer, in the order they came; or raise the refusal
        that is the answer (the first one), or ``nobody`` when no daemon replied."""
        replies = self.replies[:1] if self.how == "first" else self.replies
        good = [r for r in replies if not isinstance(r, FleetError)]
        refused = next((r for r in replies if isinstance(r, FleetError)), None)
        if good and (refused is None or self.how == "any"):
            return good
        raise refused if refused is not None else nobody


def merge(replies: Sequence[T], observe: Sequence[str] = ()) -> T:
    """One message of the daemons' good replies to one request: lists and steps merged
    (:func:`merge_lists`, :func:`merge_steps`, ``observe`` the step's), anything else the
    first daemon's (a robot's record, a clock: the daemons of a fleet share one)."""
    first = replies[0]
    if len(replies) == 1:
        return first
    every: list[Any] = list(replies)  # all of one request's type
    if isinstance(first, RobotList):
        return cast(T, merge_lists(every))
    if isinstance(first, StepReply):
        return cast(T, merge_steps(every, list(observe)))
    return first


def merge_lists(lists: list[RobotList]) -> RobotList:
    """Every daemon's robots as one list: one daemon's in its order (spawn order), several
    daemons' by name; stamped with the latest of their stamps. (A page or a named list is
    then picked from it: protocol/listing.py.)"""
    if len(lists) == 1:
        return lists[0]
    robots = sorted((r for rl in lists for r in rl.robots), key=lambda r: r.name)
    stamp = max((rl.stamp for rl in lists), key=lambda t: (t.sec, t.nanosec))
    return RobotList(stamp=stamp, robots=robots)


def merge_steps(replies: list[StepReply], observe: list[str]) -> StepReply:
    """One step reply from every daemon's: the observations of all (packed rows in the order
    asked in ``observe``), the fewest ticks run, cancelled if any daemon's was; the first
    daemon's clock."""
    if len(replies) == 1:
        return replies[0]
    observations = {k: v for r in replies for k, v in r.observations.items()}
    parts = [r.packed for r in replies if r.packed is not None]
    packed = None
    if parts:
        names = [n for p in parts for n in p.names]
        samples = parts[0].samples
        odom = np.concatenate([np.frombuffer(p.odom, "<f8").reshape(-1, 6) for p in parts])
        scan_time = np.concatenate([np.frombuffer(p.scan_time, "<f8") for p in parts])
        ranges = np.concatenate([np.frombuffer(p.ranges, "<f4").reshape(-1, samples) for p in parts])
        where = {n: k for k, n in enumerate(names)}
        order = [where[n] for n in observe if n in where]
        packed = PackedObservations(
            names=[names[k] for k in order],
            samples=samples,
            odom=byte_view(odom[order]),
            scan_time=byte_view(scan_time[order]),
            ranges=byte_view(ranges[order]),
        )
    return msgspec.structs.replace(
        replies[0],
        ticks_run=min(r.ticks_run for r in replies),
        cancelled=any(r.cancelled for r in replies),
        observations=observations,
        packed=packed,
    )


def byte_view(array: npt.NDArray[Any]) -> memoryview:
    """A read-only, flat byte view of a fresh array: what a decoded reply's fields are."""
    array.flags.writeable = False
    return array.data.cast("B")
