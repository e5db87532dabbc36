"""Diff-drive kinematics against closed form: clamps, the acceleration ramp, arcs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from protocol import SpawnRequest
from simd.core import drive
from simd.core.models import BURGER, WAFFLE
from simd.core.sim import SimConfig, Simulation
from simd.core.worldfile import load_world

DT = 1.0 / 30.0


def a(*v: float) -> np.ndarray:
    return np.asarray(v, dtype=np.float64)


def test_commands_are_clamped_to_model_limits() -> None:
    lt, rt = drive.wheel_targets(a(1.0, -1.0), a(10.0, -10.0), a(0.22, 0.26), a(2.84, 1.82), a(0.16, 0.287))
    v, w = drive.body_twist(lt, rt, a(0.16, 0.287))
    assert v.tolist() == pytest.approx([0.22, -0.26])
    assert w.tolist() == pytest.approx([2.84, -1.82])


def test_wheel_ramp_is_one_metre_per_second_squared_then_snaps() -> None:
    left = right = a(0.0)
    target = a(0.22)
    speeds = []
    for _ in range(10):
        left, right = drive.ramp_wheels(left, right, target, target, a(1.0), DT)
        speeds.append(float(left[0]))
    # +1/30 m/s per update: 0.0333, 0.0667, ..., until within 0.01 of the target, then snap
    assert speeds[0] == pytest.approx(1.0 / 30.0)
    assert speeds[5] == pytest.approx(0.2)
    assert speeds[6] == pytest.approx(0.22)
    assert speeds[-1] == pytest.approx(0.22)


def test_arc_displacement_matches_closed_form() -> None:
    v, w, yaw = 0.2, 1.5, 0.3
    dx, dy = drive.arc_displacement(a(v), a(w), a(yaw), DT)
    r = v / w
    ex = r * (math.sin(yaw + w * DT) - math.sin(yaw))
    ey = -r * (math.cos(yaw + w * DT) - math.cos(yaw))
    assert float(dx[0]) == pytest.approx(ex, abs=1e-15)
    assert float(dy[0]) == pytest.approx(ey, abs=1e-15)
    sx, sy = drive.arc_displacement(a(0.2), a(0.0), a(0.0), DT)
    assert (float(sx[0]), float(sy[0])) == pytest.approx((0.2 * DT, 0.0))


def _sim(cmd_timeout: float = 0.0) -> Simulation:
    return Simulation(load_world("empty"), SimConfig(noise=False, cmd_timeout=cmd_timeout))


def test_robot_follows_the_closed_form_arc_once_at_speed() -> None:
    sim = _sim()
    r = sim.spawn(SpawnRequest(name="r", x=1.0, y=2.0, yaw=0.5))
    v, w = 0.2, 1.0
    sim.command(r, v, w)
    # wheel targets: v -/+ w*sep/2 = 0.12 / 0.28 m/s, reached after ceil(0.28*30)=9 updates
    for _ in range(9):
        sim.step()
    s0 = sim.state(r)
    assert (s0.linear_velocity, s0.angular_velocity) == pytest.approx((v, w))
    n = 60
    for _ in range(n):
        sim.step()
    s1 = sim.state(r)
    t = n * DT
    rad = v / w
    ex = s0.x + rad * (math.sin(s0.yaw + w * t) - math.sin(s0.yaw))
    ey = s0.y - rad * (math.cos(s0.yaw + w * t) - math.cos(s0.yaw))
    assert (s1.x, s1.y) == pytest.approx((ex, ey), abs=1e-9)
    assert s1.yaw == pytest.approx(math.atan2(math.sin(s0.yaw + w * t), math.cos(s0.yaw + w * t)), abs=1e-9)


def test_straight_line_distance_with_ramp() -> None:
    sim = _sim()
    r = sim.spawn(SpawnRequest(name="r", model="waffle"))
    sim.command(r, 5.0, 0.0)  # clamped to 0.26
    xs = []
    for _ in range(60):
        sim.step()
        xs.append(sim.state(r).x)
    # ramp: speeds k/30 for k=1..7 (0.2333), snap to 0.26 at update 8, then constant
    speeds = [min(k / 30.0, 0.26) if k < 8 else 0.26 for k in range(1, 61)]
    assert xs[-1] == pytest.approx(sum(speeds) * DT, abs=1e-9)
    assert sim.state(r).linear_velocity == pytest.approx(WAFFLE.max_linear_velocity)


def test_watchdog_stops_a_robot_half_a_second_after_its_last_command() -> None:
    sim = _sim(cmd_timeout=0.5)
    r = sim.spawn(SpawnRequest(name="r"))
    sim.command(r, 0.2, 0.0)
    speeds = []
    for _ in range(40):
        sim.step()
        speeds.append(sim.state(r).linear_velocity)
    # driven for 0.5 s (15 ticks), then the target drops to 0 and the wheels ramp down
    assert speeds[14] == pytest.approx(0.2)
    assert speeds[15] == pytest.approx(0.2)  # tick 16 sees (16-0)*dt > 0.5
    assert speeds[16] < 0.2
    assert speeds[-1] == 0.0


def test_watchdog_off_keeps_the_last_command() -> None:
    sim = _sim(cmd_timeout=0.0)
    r = sim.spawn(SpawnRequest(name="r"))
    sim.command(r, 0.1, 0.0)
    for _ in range(120):
        sim.step()
    assert sim.state(r).linear_velocity == pytest.approx(0.1)


def test_burger_angular_limit() -> None:
    sim = _sim()
    r = sim.spawn(SpawnRequest(name="r"))
    sim.command(r, 0.0, 100.0)
    for _ in range(30):
        sim.step()
    assert sim.state(r).angular_velocity == pytest.approx(BURGER.max_angular_velocity)
