"""The local fleet (simd/engine/local.py): the engine's requests on the caller's thread, answered
as a lockstep simd answers them, refused as it refuses them."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from clients.api import observed_arrays
from protocol.control import SpawnRequest
from protocol.errors import ErrorCode, FleetError
from simd.core.models import MODELS
from simd.engine.local import LocalFleet

ROBOTS = [SpawnRequest(name="a", x=-2.0, y=-0.5), SpawnRequest(name="b", namespace="bee", x=0.5, y=-2.0, yaw=1.0),
          SpawnRequest(name="c", x=0.5, y=0.5, yaw=-2.0)]  # fmt: skip


def _drive(fleet: Any, steps: int) -> list[tuple[bytes, bytes, bytes, int]]:
    """Step the three robots with seeded commands; each step's packed observation, as bytes."""
    rng = np.random.default_rng(4)
    names = ["a", "bee", "c"]
    out = []
    for _ in range(steps):
        cmd = np.stack([rng.uniform(-0.2, 0.22, 3), rng.uniform(-2.0, 2.0, 3)], axis=1)
        reply = fleet.step(6, commands=(names, cmd), observe=["c", "a", "bee"], packed=True, publish=False)
        p = reply.packed
        out.append((bytes(p.odom), bytes(p.scan_time), bytes(p.ranges), reply.tick))
    return out


def test_a_local_fleet_steps_as_a_lockstep_daemon_does(daemon_factory: Any) -> None:
    d = daemon_factory("--lockstep", "--cmd-timeout", "0")
    remote = d.client()
    local = LocalFleet("turtlebot3_world")
    for fleet in (remote, local):
        fleet.reset(7)
        fleet.spawn_many(ROBOTS)
    here, there = _drive(local, 12), _drive(remote, 12)
    assert here == there  # the same engine: the same bytes, tick for tick
    assert [r.name for r in local.robots()] == [r.name for r in remote.robots()] == ["a", "b", "c"]
    seen = observed_arrays(local.step(1, observe=["a"], packed=True).packed)  # type: ignore[arg-type]
    assert not seen.ranges.flags.writeable and seen.names == ["a"]  # read-only views, as a decoded reply's
    local.close()


def test_a_local_fleet_refuses_as_the_daemon_does() -> None:
    with LocalFleet("turtlebot3_world", lidar_thread=False) as fleet:
        fleet.spawn("a", -2.0, -0.5)
        refused = r": b: a burger .* would overlap robot 'a'"  # naming the robot refused
        with pytest.raises(FleetError, match=refused) as e:
            fleet.spawn_many([SpawnRequest(name="b", x=-2.0, y=-0.5), SpawnRequest(name="c", x=0.5, y=0.5)])
        assert e.value.code is ErrorCode.COLLISION
        assert [r.name for r in fleet.robots()] == ["a", "c"]  # the others were spawned
        with pytest.raises(FleetError, match="no robot with namespace 'nobody'"):
            fleet.step(1, cmd_vel={"nobody": (0.1, 0.0)})
        with pytest.raises(ValueError, match="packed=True"):
            fleet.step(1, observe=["a"])
        with pytest.raises(FleetError, match=r": zz: Entity \[zz\] does not exist"):
            fleet.delete_many(["c", "zz"])
        assert len(fleet) == 1 and fleet.clock().paused and fleet.clock().lockstep


def test_deleting_many_at_once_is_deleting_them_one_by_one() -> None:
    """``delete_many`` deletes in one go (the table re-indexed once): the same robots gone, the
    same refusal, and the ticks after it the same bytes as deletes served one at a time."""
    spots = [
        (-0.55, 1.6),
        (0.55, 1.6),
        (-1.6, 0.55),
        (1.6, 0.55),
        (-0.55, -1.6),
        (1.6, -0.55),
        (-0.55, 0.55),
        (0.55, -0.55),
    ]
    more = [SpawnRequest(name=f"r{i}", x=x, y=y) for i, (x, y) in enumerate(spots)]
    fleets = [LocalFleet("turtlebot3_world", lidar_thread=False) for _ in range(2)]
    try:
        for fleet in fleets:
            fleet.reset(3)
            fleet.spawn_many([*ROBOTS, *more])
        names = ["r5", "bee", "r1", "b", "r6", "nobody"]  # "b" is "bee" again: refused, as "nobody"
        at_once, one_by_one = fleets
        with pytest.raises(FleetError, match=r"^not_found: b: Entity \[b\] does not exist$") as e:
            at_once.delete_many(names)
        assert e.value.code is ErrorCode.NOT_FOUND
        for name in names:
            try:
                one_by_one.delete(name)
            except FleetError:
                pass
        assert [r.name for r in at_once.robots()] == [r.name for r in one_by_one.robots()]
        assert len(at_once) == 3 + 8 - 4
        left = [r.namespace for r in at_once.robots()]
        rng = np.random.default_rng(5)
        for _ in range(5):  # the ticks after: the same bytes
            cmd = np.stack([rng.uniform(-0.2, 0.22, len(left)), rng.uniform(-2.0, 2.0, len(left))], axis=1)
            mine, theirs = (f.step(6, commands=(left, cmd), observe=left, packed=True).packed for f in fleets)
            assert mine is not None and theirs is not None
            assert (bytes(mine.odom), bytes(mine.ranges)) == (bytes(theirs.odom), bytes(theirs.ranges))
    finally:
        for fleet in fleets:
            fleet.close()


def test_a_local_fleets_step_with_command_arrays_is_checked_as_a_request_is() -> None:
    """The envs' every step (commands as arrays, served without the request's bytes) refuses
    what a step request is refused for, with the same codes, and runs nothing then."""
    with LocalFleet("turtlebot3_world", lidar_thread=False) as fleet:
        fleet.spawn("a", -2.0, -0.5)
        go = (["a"], [(0.1, 0.0)])
        refused = [
            ((["a"], [(np.nan, 0.0)]), ["a"], 1, ErrorCode.NON_FINITE, "commands for 'a' is not finite"),
            ((["zz"], [(0.1, 0.0)]), ["a"], 1, ErrorCode.NOT_FOUND, "no robot with namespace 'zz'"),
            ((["a", "a"], [(0.1, 0.0), (0.1, 0.0)]), ["a"], 1, ErrorCode.INVALID_VALUE, "'a' more than once"),
            (go, ["a"], 0, ErrorCode.INVALID_VALUE, "ticks must be in 1.."),
            (go, ["zz"], 1, ErrorCode.NOT_FOUND, "no robot called 'zz' to observe"),
        ]
        for commands, observe, ticks, code, said in refused:
            with pytest.raises(FleetError, match=said) as e:
                fleet.step(ticks, commands=commands, observe=observe, packed=True)
            assert e.value.code is code
        with pytest.raises(ValueError, match=r"shape \(1, 2\)"):
            fleet.step(1, commands=(["a"], [(0.1, 0.0, 0.0)]), observe=["a"], packed=True)
        with pytest.raises(FleetError, match="not both"):
            fleet.step(1, cmd_vel={"a": (0.1, 0.0)}, commands=go)
        assert fleet.clock().tick == 0  # nothing ran
        reply = fleet.step(2, commands=go, observe=["a"], packed=True)
        assert reply.ticks_run == 2 and reply.tick == 2
        assert observed_arrays(reply.packed).odom[0, 3] > 0.0  # type: ignore[arg-type]  # it drives


def test_a_local_fleet_says_where_a_robot_fits() -> None:
    with LocalFleet("turtlebot3_world", lidar_thread=False) as fleet:
        burger = MODELS["burger"]
        assert fleet.fits("burger", -2.0, -0.5, 0.0) and not fleet.touches(burger, -2.0, -0.5, 0.0)
        assert not fleet.fits("burger", 0.0, 0.0, 0.0)  # the middle pillar
        assert fleet.touches(burger, 0.0, 0.0, 0.0, static_only=True)
        assert not fleet.fits("burger", 100.0, 0.0, 0.0) and not fleet.fits("tank", -2.0, -0.5, 0.0)
        fleet.spawn("a", -2.0, -0.5)
        assert not fleet.fits("burger", -2.0, -0.5, 0.0) and fleet.touches(burger, -2.0, -0.5, 0.0)
        assert not fleet.touches(burger, -2.0, -0.5, 0.0, static_only=True)  # a robot, not a wall
