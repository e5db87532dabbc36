"""Putting a robot somewhere else at once (ROS's initialpose): the core's rules, the engine's
request, and what the navigator does with a robot that was moved."""

from __future__ import annotations

import math

import numpy as np
import pytest

from protocol.control import SpawnRequest
from protocol.errors import ErrorCode, FleetError
from protocol.navigation import NavigateRequest
from simd.core.sim import SimConfig, Simulation
from simd.core.snapshot import RobotState
from simd.core.worldfile import load_world
from simd.engine import Engine
from simd.engine.ports import PlaceRequest, Result
from simd.nav.navigator import Navigator


def sim(odom_noise: float = 0.0) -> Simulation:
    s = Simulation(load_world("turtlebot3_world"), SimConfig(noise=False, odom_noise=odom_noise))
    s.spawn(SpawnRequest(name="a", x=-2.0, y=-0.5))
    s.spawn(SpawnRequest(name="b", x=0.5, y=-2.0))
    return s


def test_place_moves_the_robot_at_rest_and_its_odometry_starts_there() -> None:
    s = sim(odom_noise=0.2)
    s.command(s.find("a"), 0.2, 0.5)  # type: ignore[arg-type]
    for _ in range(30):
        s.step()
    old_columns = (s.robots.x, s.robots.odom_x)
    state = s.place("a", -2.0, 0.5, 4.0)
    assert (state.x, state.y) == (-2.0, 0.5)
    assert state.yaw == pytest.approx(4.0 - 2 * math.pi)  # wrapped
    assert state.odom_pose == (state.x, state.y, state.yaw)
    assert (state.linear_velocity, state.angular_velocity) == (0.0, 0.0)
    assert old_columns[0][0] != -2.0 and old_columns[1] is not s.robots.odom_x  # a snapshot's columns stay
    snap = s.step()
    assert snap.x[0] == pytest.approx(-2.0) and snap.y[0] == pytest.approx(0.5)  # the command was dropped
    b = s.state(s.find("b"))  # type: ignore[arg-type]
    assert (b.x, b.y) == pytest.approx((0.5, -2.0))


def test_place_a_little_off_where_it_stands_overlaps_only_itself() -> None:
    s = sim()
    assert s.place("a", -1.95, -0.5, 0.1).x == -1.95


@pytest.mark.parametrize(
    ("pose", "code"),
    [
        ((0.0, 0.0, 0.0), ErrorCode.COLLISION),  # the centre pillar
        ((0.5, -2.0, 0.0), ErrorCode.COLLISION),  # robot b
        ((40.0, 0.0, 0.0), ErrorCode.OUT_OF_BOUNDS),
        ((math.nan, 0.0, 0.0), ErrorCode.NON_FINITE),
    ],
)
def test_place_refuses_as_a_spawn_would_and_moves_nothing(pose: tuple[float, float, float], code: ErrorCode) -> None:
    s = sim()
    before = s.states()
    with pytest.raises(FleetError) as e:
        s.place("a", *pose)
    assert e.value.code is code
    assert s.states() == before
    with pytest.raises(FleetError) as missing:
        s.place("nobody", -2.0, 0.5, 0.0)
    assert missing.value.code is ErrorCode.NOT_FOUND


def test_snapshots_carry_the_true_pose_only_when_the_odometry_drifts() -> None:
    assert sim().step().true_pose is None
    s = sim(odom_noise=0.2)
    s.command(s.find("a"), 0.2, 0.5)  # type: ignore[arg-type]
    for _ in range(20):
        snap = s.step()
    assert snap.true_pose is not None
    tx, ty, _ = snap.truth
    assert tx[0] == s.robots.x[0] and ty[0] == s.robots.y[0]
    assert not np.allclose((snap.x[0], snap.y[0]), (tx[0], ty[0]), atol=1e-6)


def test_the_engine_places_and_the_navigator_cancels_the_goal_it_was_on() -> None:
    s = sim()
    nav = Navigator(s.world, s.config.lidar, s.robots)
    e = Engine(s, lockstep=True, navigator=nav)
    replies: list[Result | FleetError] = []
    nav.goal("a", s.find("a").model, NavigateRequest(x=-2.0, y=1.0), s.time)  # type: ignore[union-attr]
    nav.take_events()
    for _ in range(6):
        e.tick()
    e.submit(PlaceRequest("a", -2.0, 0.5, 0.0), replies.append)
    e.submit(PlaceRequest("a", 0.0, 0.0, 0.0), replies.append)  # the pillar: refused, nothing changes
    e.serve_pending()
    placed, refused = replies
    assert isinstance(placed, RobotState) and (placed.x, placed.y) == (-2.0, 0.5)
    assert isinstance(refused, FleetError) and refused.code is ErrorCode.COLLISION
    state = nav.state("a")
    assert not state.active and state.result is not None
    assert (state.result.status, state.result.reason) == ("failed", "cancelled")
    for _ in range(30):
        e.tick()
    a = s.state(s.find("a"))  # type: ignore[arg-type]
    assert math.hypot(a.x + 2.0, a.y - 0.5) < 0.02  # it stays where it was put
