"""The path follower's control law on single robots (pure functions of arrays: no simulation)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simd.core.models import MODELS
from simd.nav.follow import BACK_WITHIN_M, Limits, pursue

BURGER = MODELS["burger"]
LIMITS = Limits(np.array([BURGER.max_linear_velocity]), np.array([BURGER.max_angular_velocity]))


def command(
    bearing_deg: float, dist: float, room: float, yaw: float = 0.3, back: float = BACK_WITHIN_M
) -> tuple[float, float]:
    """The command of a burger at the origin, heading ``yaw``, for an aim ``dist`` away at
    ``bearing_deg`` off its heading (on an open floor, unless ``back`` is 0: in lanes)."""
    a = yaw + math.radians(bearing_deg)
    one = np.array([0.0])
    v, w = pursue(one, one, np.array([yaw]), np.array([dist * math.cos(a)]), np.array([dist * math.sin(a)]),
                  np.array([room]), LIMITS, back)  # fmt: skip
    return float(v[0]), float(w[0])


def test_ahead_it_drives_within_its_limits() -> None:
    v, w = command(0.0, 0.2, 1.0)
    assert v == pytest.approx(BURGER.max_linear_velocity) and w == pytest.approx(0.0, abs=1e-9)
    v, w = command(20.0, 0.2, 1.0)
    assert 0 < v <= BURGER.max_linear_velocity and 0 < w <= BURGER.max_angular_velocity


@pytest.mark.parametrize("bearing", [180.0, 150.0, -150.0, 100.0])
def test_an_aim_centimetres_behind_is_backed_into_not_turned_round_for(bearing: float) -> None:
    v, w = command(bearing, 0.05, 0.05)
    assert v < 0.0, "backs up"
    back = math.remainder(math.radians(bearing) - math.pi, 2 * math.pi)  # the aim off the robot's back
    assert w == pytest.approx(0.0, abs=1e-9) if back == 0 else math.copysign(1.0, w) == math.copysign(1.0, back)
    assert abs(w) <= BURGER.max_angular_velocity


def test_an_aim_further_behind_is_turned_to_on_the_spot() -> None:
    v, w = command(150.0, BACK_WITHIN_M + 0.1, 1.0)
    assert v == 0.0 and w > 0.5  # it turns left, towards it, before it drives


def test_in_lanes_robots_turn_rather_than_back_up() -> None:
    v, w = command(150.0, 0.05, 0.05, back=0.0)
    assert v == 0.0 and w > 0.5


def test_no_room_no_motion_but_it_faces_the_aim() -> None:
    assert command(0.0, 0.05, 0.0) == (0.0, 0.0)
    v, w = command(90.0, 0.3, 0.0)
    assert v == 0.0 and w > 0.0
    v, w = command(170.0, 0.05, 0.0)  # behind, but nowhere to go: it does not back up either
    assert v == 0.0
