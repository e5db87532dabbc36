"""Several daemons' replies make one answer (protocol/gather.py): the gathering rules, table by
table and against a model of them, and merged lists and steps that read as one daemon's."""

from __future__ import annotations

import itertools
from typing import Any

import msgspec
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from clients.api import observed_arrays
from protocol.codec import decode, encode
from protocol.control import (
    ClockRequest,
    DeleteRequest,
    ListRequest,
    PackedObservations,
    Pose2D,
    ResetRequest,
    RobotList,
    RobotRecord,
    SpawnRequest,
    StepReply,
    StepRequest,
)
from protocol.errors import ErrorCode, FleetError
from protocol.gather import GATHER, Gather, Gathering, merge, merge_lists, merge_steps
from protocol.messages import Time

NOBODY = FleetError(ErrorCode.UNAVAILABLE, "nobody answered")
NOT_FOUND = FleetError(ErrorCode.NOT_FOUND, "not here")
REFUSED = FleetError(ErrorCode.NOT_ALLOWED, "will not")


def _gather(how: Gather, replies: list[Any]) -> list[Any] | FleetError:
    """What a gathering of these replies, given as they come, answers (a caller stops adding
    once it says the answer is known)."""
    g: Gathering[Any] = Gathering(how)
    for r in replies:
        if g.add(r):
            break
    try:
        return g.answer(NOBODY)
    except FleetError as e:
        return e


@pytest.mark.parametrize(
    ("how", "replies", "answer"),
    [
        ("first", ["a", "b"], ["a"]),  # the owner's reply; nobody else's counts
        ("first", [REFUSED, "a"], REFUSED),  # the owner refused
        ("first", ["a", REFUSED], ["a"]),
        ("first", [], NOBODY),
        ("any", [NOT_FOUND, "a"], ["a"]),  # the robot's daemon wins over not found
        ("any", ["a", NOT_FOUND, "b"], ["a", "b"]),
        ("any", [NOT_FOUND, REFUSED], NOT_FOUND),  # none good: the first refusal
        ("any", [], NOBODY),
        ("all", ["a", "b"], ["a", "b"]),
        ("all", ["a", REFUSED, "b"], REFUSED),  # one did not act: the fleet did not
        ("all", [], NOBODY),
    ],
)
def test_the_gathering_rules(how: Gather, replies: list[Any], answer: list[Any] | FleetError) -> None:
    got = _gather(how, replies)
    if isinstance(answer, FleetError):
        assert got is answer
    else:
        assert got == answer


def test_each_request_is_gathered_as_the_shared_fleet_needs() -> None:
    assert GATHER[SpawnRequest] == GATHER[ClockRequest] == "first"  # one daemon owns the answer
    assert GATHER[DeleteRequest] == GATHER[ListRequest] == GATHER[ResetRequest] == "any"
    assert GATHER[StepRequest] == "all"


_replies = st.lists(st.one_of(st.integers(0, 9), st.sampled_from([NOT_FOUND, REFUSED])), max_size=6)


@given(how=st.sampled_from(["first", "any", "all"]), replies=_replies)
def test_the_gathering_matches_its_description(how: Gather, replies: list[Any]) -> None:
    got = _gather(how, replies)
    seen = replies[:1] if how == "first" else replies
    good = [r for r in seen if not isinstance(r, FleetError)]
    refusals = [r for r in seen if isinstance(r, FleetError)]
    if not seen:
        assert got is NOBODY
    elif good and (how == "any" or not refusals):
        assert got == good  # in the order they came
    else:
        assert got is refusals[0]


def _record(name: str) -> RobotRecord:
    return RobotRecord(name=name, namespace=name, model="burger", pose=Pose2D())


@given(
    names=st.lists(st.text("abcxyz", min_size=1, max_size=3), unique=True, max_size=8),
    cuts=st.lists(st.integers(0, 8), max_size=3),
    stamps=st.lists(st.integers(0, 10**9), min_size=4, max_size=4),
)
def test_merged_lists_hold_every_robot_once_by_name_with_the_latest_stamp(
    names: list[str], cuts: list[int], stamps: list[int]
) -> None:
    bounds = sorted({0, len(names), *(min(c, len(names)) for c in cuts)})
    parts = [names[a:b] for a, b in itertools.pairwise(bounds)] or [[]]
    lists = [
        RobotList(stamp=Time(sec=0, nanosec=stamps[k % 4]), robots=[_record(n) for n in part])
        for k, part in enumerate(parts)
    ]
    merged = merge_lists(lists)
    got = [r.name for r in merged.robots]
    if len(lists) == 1:
        assert merged is lists[0]  # one daemon: its own order (spawn order)
    else:
        assert got == sorted(names)
        assert merged.stamp.nanosec == max(rl.stamp.nanosec for rl in lists)
    assert merge(lists) == merged  # merge picks the list rule


def _reply(names: list[str], first: float, ticks_run: int = 6) -> StepReply:
    """One daemon's answer as the client decodes it off the wire."""
    n = len(names)
    odom = np.arange(n * 6, dtype="<f8").reshape(n, 6) + first
    scan_time = np.full(n, first)
    ranges = np.full((n, 4), first, dtype="<f4")
    ranges[0, 1] = np.nan  # a beam with no return, which must not make equal replies unequal
    packed = PackedObservations(names=names, samples=4, odom=odom.data, scan_time=scan_time.data, ranges=ranges.data)
    reply = StepReply(
        clock=Time(sec=0, nanosec=200_000_000), tick=6, dt=1 / 30, paused=True, lockstep=True, real_time_factor=0.0,
        target_real_time_factor=0.0, robots=n, ticks_run=ticks_run, packed=packed,
    )  # fmt: skip
    return decode(encode(reply), StepReply)


def test_a_step_merges_to_the_fewest_ticks_and_any_cancel_and_anything_else_is_the_first() -> None:
    a, b = _reply(["a1"], 1.0, ticks_run=6), _reply(["b1"], 2.0, ticks_run=4)
    b = decode(encode(msgspec.structs.replace(b, cancelled=True)), StepReply)
    merged = merge([a, b], ["a1", "b1"])
    assert (merged.ticks_run, merged.cancelled, merged.tick) == (4, True, a.tick)
    assert merge([a], ["a1"]) is a  # one daemon: its reply as it is
    records = [_record("r1"), _record("r2")]
    assert merge(records) is records[0]  # a robot's record: the daemon that has it


def test_a_merged_packed_reply_holds_read_only_bytes_in_the_order_asked() -> None:
    a, b = _reply(["a1", "a2"], 100.0), _reply(["b1"], 200.0, ticks_run=5)
    merged = merge_steps([a, b], ["b1", "a2", "a1"])
    p = merged.packed
    assert p is not None and p.names == ["b1", "a2", "a1"] and merged.ticks_run == 5
    for field in (p.odom, p.scan_time, p.ranges):  # as a decoded reply's: flat bytes, read-only
        assert field.format == "B" and field.ndim == 1 and field.readonly
    assert len(p.ranges) == 3 * 4 * 4
    seen = observed_arrays(p)
    assert seen.odom[:, 0].tolist() == [200.0, 106.0, 100.0]
    assert seen.scan_time.tolist() == [200.0, 100.0, 100.0]
    assert not seen.ranges.flags.writeable
    with pytest.raises(ValueError):
        seen.ranges[0, 0] = 1.0
    again = merge_steps([a, b], ["b1", "a2", "a1"])
    assert again == merged  # NaN beams compare as bytes
    assert bytes(merged.packed.ranges) == bytes(again.packed.ranges)  # type: ignore[union-attr]
