"""The daemons' parts of a tick's fleet odometry become one message (clients/tick_merge.py)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from clients import wait_until
from clients.tick_merge import TickMerge, merge
from protocol.messages import FleetOdometry, Time

TICK_NS = 33_333_333


def part(tick: int, *namespaces: str) -> FleetOdometry:
    """A daemon's rows of a tick: x is the tick, y the row's index among all test robots."""
    n = len(namespaces)
    ys = [float(int(ns[1:])) for ns in namespaces]
    col = np.zeros(n).tobytes()
    return FleetOdometry(
        stamp=Time(sec=tick * TICK_NS // 10**9, nanosec=tick * TICK_NS % 10**9),
        namespaces=list(namespaces),
        x=np.full(n, float(tick)).tobytes(),
        y=np.array(ys).tobytes(),
        yaw=col,
        linear_x=col,
        linear_y=col,
        angular_z=col,
    )


class Clock:
    """Wall time for a merge, moved by the test."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def run(daemons: int, parts: list[FleetOdometry], apart_s: float = 0.04) -> list[tuple[int, list[str]]]:
    """(tick, namespaces) of each message handed on, the parts coming ``apart_s`` apart (about
    real time by default, clear of the hold's edge)."""
    out: list[FleetOdometry] = []
    clock = Clock()
    m = TickMerge(lambda: daemons, out.append, clock=clock)
    for p in parts:
        m.add(p)
        clock.now += apart_s
    return _ticks(out)


def _ticks(out: list[FleetOdometry]) -> list[tuple[int, list[str]]]:
    return [(int(msg.array("x")[0]), msg.namespaces) for msg in out]


@pytest.mark.parametrize(
    ("daemons", "parts", "want"),
    [
        pytest.param(1, [part(1, "a0"), part(2, "a0")], [(1, ["a0"]), (2, ["a0"])], id="one daemon: as they come"),
        pytest.param(
            2,
            [part(1, "a0", "a1"), part(1, "b2"), part(2, "b2"), part(2, "a0", "a1")],
            [(1, ["a0", "a1", "b2"]), (2, ["b2", "a0", "a1"])],
            id="two daemons: a tick once both parts are in",
        ),
        pytest.param(
            2,
            [part(1, "a0"), part(2, "a0"), part(1, "b1"), part(2, "b1")],
            [(1, ["a0", "b1"]), (2, ["a0", "b1"])],
            id="one daemon a tick ahead",
        ),
        pytest.param(
            2,
            [part(1, "a0"), part(2, "a0"), part(2, "b1")],
            [(1, ["a0"]), (2, ["a0", "b1"])],
            id="a later tick whole: the older goes with what it has",
        ),
        pytest.param(
            2,
            [part(t, "a0") for t in range(1, 6)],
            [(1, ["a0"]), (2, ["a0"])],
            id="a daemon with no robots puts nothing: held three ticks, never dropped",
        ),
        pytest.param(
            2,
            [part(1, "a0"), part(2, "a0"), part(2, "b1"), part(1, "b1")],
            [(1, ["a0"]), (2, ["a0", "b1"]), (1, ["b1"])],
            id="a part after its tick went: alone, not lost",
        ),
        pytest.param(
            2,
            [part(90, "a0"), part(90, "b1"), part(1, "a0"), part(1, "b1")],
            [(90, ["a0", "b1"]), (1, ["a0", "b1"])],
            id="the clock went back three seconds: a reset, merged again",
        ),
        pytest.param(0, [part(1, "a0")], [(1, ["a0"])], id="no daemon known yet: a part is a tick"),
    ],
)
def test_the_parts_of_a_tick_come_out_as_one_message(
    daemons: int, parts: list[FleetOdometry], want: list[tuple[int, list[str]]]
) -> None:
    assert run(daemons, parts) == want


def test_merged_columns_keep_each_row_with_its_namespace() -> None:
    msg = merge([part(4, "a0", "a3"), part(4, "b1"), part(4, "c2")])
    assert msg.namespaces == ["a0", "a3", "b1", "c2"]
    assert msg.array("y").tolist() == [0.0, 3.0, 1.0, 2.0]
    assert msg.array("x").tolist() == [4.0] * 4 and msg.stamp == part(4, "x0").stamp


def test_a_stepped_fleet_far_faster_than_real_time_keeps_its_ticks_whole() -> None:
    """Ticks a millisecond apart: one daemon's parts four ticks behind the other's (through a
    router) still join their ticks. Counted in ticks alone, the hold handed the first ticks on
    half, and their other halves after them (the flaky tests/scaleout/test_shared.py)."""
    a = [part(t, "a0") for t in range(1, 7)]
    b = [part(t, "b1") for t in range(1, 7)]
    parts = [a[0], a[1], a[2], a[3], a[4], b[0], a[5], b[1], b[2], b[3], b[4], b[5]]
    assert run(2, parts, apart_s=0.001) == [(t, ["a0", "b1"]) for t in range(1, 7)]


def test_ticks_missing_a_part_go_once_they_have_waited_when_no_more_parts_come() -> None:
    out: list[FleetOdometry] = []
    clock = Clock()
    m = TickMerge(lambda: 2, out.append, clock=clock)  # the other daemon has no robots: puts nothing
    for t in range(1, 6):  # a step of five ticks, a millisecond apart, then nothing
        m.add(part(t, "a0"))
        clock.now += 0.001
    assert out == []  # they have not waited yet
    clock.now += 0.05
    m.flush()
    assert out == []
    clock.now += 0.05
    m.flush()
    assert _ticks(out) == [(t, ["a0"]) for t in range(1, 6)]  # all, in order, none lost


def test_the_timer_hands_on_a_tick_whose_part_never_comes_and_stops_with_the_subscription() -> None:
    out: list[FleetOdometry] = []
    m = TickMerge(lambda: 2, out.append, hold_s=0.05, flush_after=True)
    m.add(part(1, "a0"))
    assert wait_until(lambda: len(out) == 1, 5.0)
    assert _ticks(out) == [(1, ["a0"])]
    m.add(part(2, "a0"))
    m.undeclare()  # before its hold is over: never handed on
    time.sleep(0.2)
    assert len(out) == 1


def test_a_callback_may_end_the_merge_it_is_handed_a_tick_by() -> None:
    out: list[FleetOdometry] = []

    def handed(msg: FleetOdometry) -> None:
        out.append(msg)
        m.undeclare()  # the subscription ends from its own callback

    m = TickMerge(lambda: 1, handed)
    m.add(part(1, "a0"))
    m.add(part(2, "a0"))  # ended: nothing more
    assert _ticks(out) == [(1, ["a0"])]
