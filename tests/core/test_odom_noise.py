"""--odom-noise: odometry that drifts from the true pose as a slipping robot's does, and only then."""

from __future__ import annotations

import math
import subprocess

import numpy as np
import pytest

from protocol.control import SpawnRequest
from simd.core.sim import SimConfig, Simulation
from simd.core.worldfile import load_world
from tests.conftest import ROOT, free_port, simd_command


def _drive(noise: float, seed: int = 3, ticks: int = 300) -> tuple[Simulation, np.ndarray]:
    sim = Simulation(load_world("empty"), SimConfig(odom_noise=noise, seed=seed, lidar_thread=False, cmd_timeout=0))
    sim.spawn(SpawnRequest(name="r", x=0.0, y=0.0))
    sim.command_many({"r": (0.2, 0.4)})
    odom = []
    for _ in range(ticks):
        snap = sim.step()
        odom.append((snap.x[0], snap.y[0], snap.yaw[0]))
    return sim, np.array(odom)


def test_without_noise_odometry_is_the_true_pose() -> None:
    sim, odom = _drive(0.0)
    s = sim.state(sim.robots.robots[0])
    assert tuple(odom[-1]) == (s.x, s.y, s.yaw) and s.odom_pose == (s.x, s.y, s.yaw)


def test_with_noise_odometry_drifts_and_the_truth_stays_known() -> None:
    sim, odom = _drive(0.05)
    s = sim.state(sim.robots.robots[0])
    true_xy = np.array([s.x, s.y])
    drift = float(np.linalg.norm(odom[-1, :2] - true_xy))
    assert 0.005 < drift < 0.5  # 2 m of driving with 5 % wheel slip: centimetres to decimetres
    assert s.odom_pose == tuple(odom[-1])  # list and spawn report the truth, the odometry beside it
    _, again = _drive(0.05)
    assert np.array_equal(odom, again)  # seeded: the same run drifts the same way
    _, other = _drive(0.05, seed=4)
    assert not np.array_equal(odom, other)
    _, exact = _drive(0.0)
    assert math.dist(exact[-1, :2], true_xy) < 1e-12  # the slip does not change the true motion


def test_a_bad_odom_noise_is_one_line() -> None:
    p = subprocess.run(simd_command("--odom-noise", "-1", "-l", f"tcp/127.0.0.1:{free_port()}"),
                       capture_output=True, text=True, cwd=ROOT, timeout=30)  # fmt: skip
    assert (
        p.returncode == 2
        and p.stderr.strip() == "simd: error: --odom-noise must be in 0..0.5 (a fraction of each wheel's travel)"
    )


def test_the_odometry_twist_is_the_slipping_wheels_own() -> None:
    """Pose and twist come from the same wheel travel, as a robot's encoders give both: turning
    at the reported rate for a tick gives the next reported heading, not the true one."""
    sim = Simulation(load_world("empty"), SimConfig(odom_noise=0.05, seed=3, lidar_thread=False, cmd_timeout=0))
    sim.spawn(SpawnRequest(name="r", x=0.0, y=0.0))
    sim.command_many({"r": (0.2, 0.4)})
    for _ in range(30):  # past the wheels' ramp
        sim.step()
    before = sim.step()
    after = sim.step()
    true_w = sim.state(sim.robots.robots[0]).angular_velocity
    turned = math.remainder(float(after.yaw[0]) - float(before.yaw[0]), math.tau)
    assert turned == pytest.approx(float(after.angular_z[0]) * sim.config.dt, abs=1e-12)
    assert float(after.angular_z[0]) != pytest.approx(true_w, abs=1e-9)  # the slip shows in the twist too
    assert float(after.linear_y[0]) == 0.0  # wheels do not see sideways motion
