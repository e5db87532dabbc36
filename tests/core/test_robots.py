"""The robot table: columns grow and shrink together, rows follow spawn order."""

from __future__ import annotations

import numpy as np
import pytest

from simd.core.models import BURGER, WAFFLE
from simd.core.robots import Robot, RobotTable


def robot(rid: int, name: str, namespace: str | None = None) -> Robot:
    return Robot(rid, name, namespace or name, BURGER if rid % 2 == 0 else WAFFLE, (float(rid), 0.0, 0.0), 0)


def test_rows_follow_spawn_order_and_every_column_keeps_the_length() -> None:
    t = RobotTable()
    for k in range(4):
        assert t.append(robot(k, f"r{k}"), rid=k, x=float(k), outline=robot(k, "x").model.outline) == k
    assert len(t) == 4 and t.namespaces == ["r0", "r1", "r2", "r3"]
    for name in RobotTable.columns():
        assert len(getattr(t, name)) == 4, name
    assert t.x.tolist() == [0.0, 1.0, 2.0, 3.0]
    assert t.outline.shape == (4, 12, 2) and np.array_equal(t.outline[1], WAFFLE.outline)
    assert t.y.tolist() == [0.0] * 4  # not given: zero


def test_remove_moves_later_rows_up_and_forgets_both_keys() -> None:
    t = RobotTable()
    robots = [robot(k, f"r{k}", f"ns{k}") for k in range(3)]
    for k, r in enumerate(robots):
        t.append(r, rid=k, x=float(k))
    before = t.namespaces
    assert t.remove(robots[1]) == 1
    assert t.namespaces == ["ns0", "ns2"] and before == ["ns0", "ns1", "ns2"]  # replaced, not changed
    assert t.x.tolist() == [0.0, 2.0] and t.rid.tolist() == [0, 2]
    assert t.find("r1") is None and t.find("ns1") is None
    assert t.find("r2") is robots[2] and t.find("ns2") is robots[2]
    assert t.row(robots[2]) == 1 and t.row_of("ns2") == 1 and t.row_of("ns1") is None
    for name in RobotTable.columns():
        assert len(getattr(t, name)) == 2, name


def test_an_unknown_column_is_refused_and_the_table_is_unchanged() -> None:
    t = RobotTable()
    with pytest.raises(TypeError, match="no such column: speed"):
        t.append(robot(0, "a"), speed=1.0)
    assert len(t) == 0 and t.find("a") is None and len(t.x) == 0
