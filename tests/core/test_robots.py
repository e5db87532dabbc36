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


def test_removing_many_at_once_leaves_what_removing_them_one_by_one_leaves() -> None:
    def table() -> tuple[RobotTable, list[Robot]]:
        t = RobotTable()
        robots = [robot(k, f"r{k}", f"ns{k}") for k in range(7)]
        for k, r in enumerate(robots):
            t.append(r, rid=k, x=float(k), outline=r.model.outline)
        return t, robots

    many, robots = table()
    many.remove_many([robots[5], robots[0], robots[3]])
    one, robots_one = table()
    for k in (5, 0, 3):
        one.remove(robots_one[k])
    assert many.namespaces == one.namespaces == ["ns1", "ns2", "ns4", "ns6"]
    for name in RobotTable.columns():
        np.testing.assert_array_equal(getattr(many, name), getattr(one, name), err_msg=name)
    assert [r.name for r in many.robots] == ["r1", "r2", "r4", "r6"]
    assert many.row_of("ns6") == 3 and many.find("r0") is None and many.find("ns3") is None
    many.remove_many([])
    assert len(many) == 4


def test_every_change_of_rows_and_only_that_gives_a_new_generation_never_seen_before() -> None:
    t, other = RobotTable(), RobotTable()
    seen = {t.generation, other.generation}
    assert len(seen) == 2  # two tables never share one
    robots = [robot(k, f"r{k}") for k in range(3)]
    for k, r in enumerate(robots):
        t.append(r, rid=k)
        assert t.generation not in seen
        seen.add(t.generation)
    before = t.generation
    t.x = t.x + 1.0  # a column replaced by the step: the same rows
    t.remove_many([])
    assert t.generation == before
    t.remove(robots[1])
    assert t.generation not in seen
    seen.add(t.generation)
    t.remove_many([robots[0], robots[2]])
    assert t.generation not in seen and len(t) == 0
