"""The daemons' parts of a tick's fleet odometry become one message (clients/tick_merge.py)."""

from __future__ import annotations

import numpy as np
import pytest

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


def run(daemons: int, parts: list[FleetOdometry]) -> list[tuple[int, list[str]]]:
    """(tick, namespaces) of each message handed on."""
    out: list[FleetOdometry] = []
    m = TickMerge(lambda: daemons, out.append)
    for p in parts:
        m.add(p)
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
