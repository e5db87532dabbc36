"""TurtleBot3 models with the numbers of the Gazebo (ROBOTIS humble) SDF.

The 2D footprint is the union of the chassis collision box and the two wheel cylinders
seen from above. The wheels sit 1-2.5 mm outside the chassis box in the SDF; here their
rectangles reach inward to overlap it, so that the footprint is one closed outline (the
gap is narrower than any lidar beam spacing at range and no obstacle fits in it). The lidar
sees this outline; physics collides with the same footprint as two boxes (``collision_boxes``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from protocol.control import ModelLimits
from protocol.frames import SCAN_OFFSET

Rect = tuple[float, float, float, float]  # x_min, x_max, y_min, y_max in base_footprint

#: Odometry covariance diagonals of gazebo_ros_diff_drive (x, y, z, roll, pitch, yaw).
ODOM_COVARIANCE_DIAGONAL = (1e-5, 1e-5, 1e12, 1e12, 1e12, 1e-3)


@dataclass(frozen=True)
class RobotModel:
    name: str
    chassis: Rect
    wheel_x: tuple[float, float]  # wheel rim extent along x (radius 0.033 about the axle)
    wheel_y: tuple[float, float]  # |y| extent of each wheel rectangle (inner, outer)
    wheel_separation: float  # diff-drive plugin value
    wheel_radius: float
    max_linear_velocity: float  # m/s, hardware spec and teleop clamp
    max_angular_velocity: float  # rad/s
    max_wheel_acceleration: float  # m/s^2 at the rim (gazebo_ros_diff_drive max_wheel_acceleration)
    mass: float  # total SDF mass, kg
    lidar_offset: tuple[float, float]  # base_scan in base_footprint (x, y)
    outline: npt.NDArray[np.float64] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        cx0, cx1, _, cy = self.chassis
        (wx0, wx1), (wyi, _) = self.wheel_x, self.wheel_y
        # what collision_boxes() relies on: the wheels overlap the chassis's sides
        assert cx0 <= wx0 < wx1 <= cx1 and wyi < cy, "wheels must overlap the chassis"
        object.__setattr__(self, "outline", _outline(self.chassis, self.wheel_x, self.wheel_y))

    def collision_boxes(self) -> list[Rect]:
        """The footprint as two convex boxes for the physics: the chassis, and one band from
        wheel to wheel across it. Their union is exactly chassis plus wheels (the band's middle
        lies inside the chassis), with one shape fewer than chassis and two wheels, and
        without the convex hull's fill behind the wheels (a hull met a round pillar beside a
        wheel 4 mm early on a burger, 12 mm on a waffle)."""
        (wx0, wx1), (_, wyo) = self.wheel_x, self.wheel_y
        return [self.chassis, (wx0, wx1, -wyo, wyo)]

    def limits(self) -> ModelLimits:
        return ModelLimits(
            max_linear_velocity=self.max_linear_velocity,
            max_angular_velocity=self.max_angular_velocity,
            wheel_separation=self.wheel_separation,
            wheel_radius=self.wheel_radius,
            max_wheel_acceleration=self.max_wheel_acceleration,
        )

    @property
    def radius(self) -> float:
        """Distance from the origin to the farthest outline vertex."""
        return float(np.max(np.hypot(self.outline[:, 0], self.outline[:, 1])))


def _outline(chassis: Rect, wheel_x: tuple[float, float], wheel_y: tuple[float, float]) -> npt.NDArray[np.float64]:
    """The 12-vertex counter-clockwise outline of chassis plus wheels."""
    cx0, cx1, cy0, cy1 = chassis
    wx0, wx1 = wheel_x
    wyo = wheel_y[1]
    assert cy0 == -cy1, "chassis must be symmetric about x"
    cy = cy1
    pts = [
        (cx1, -cy),
        (cx1, cy),
        (wx1, cy),
        (wx1, wyo),
        (wx0, wyo),
        (wx0, cy),
        (cx0, cy),
        (cx0, -cy),
        (wx0, -cy),
        (wx0, -wyo),
        (wx1, -wyo),
        (wx1, -cy),
    ]
    return np.asarray(pts, dtype=np.float64)


BURGER = RobotModel(
    name="burger",
    chassis=(-0.102, 0.038, -0.070, 0.070),
    wheel_x=(-0.033, 0.033),
    wheel_y=(0.060, 0.089),
    wheel_separation=0.160,
    wheel_radius=0.033,
    max_linear_velocity=0.22,
    max_angular_velocity=2.84,
    max_wheel_acceleration=1.0,
    mass=1.0017,
    lidar_offset=SCAN_OFFSET["burger"][:2],
)

WAFFLE = RobotModel(
    name="waffle",
    chassis=(-0.1965, 0.0685, -0.1325, 0.1325),
    wheel_x=(-0.033, 0.033),
    wheel_y=(0.125, 0.153),
    wheel_separation=0.287,
    wheel_radius=0.033,
    max_linear_velocity=0.26,
    max_angular_velocity=1.82,
    max_wheel_acceleration=1.0,
    mass=1.7239,
    lidar_offset=SCAN_OFFSET["waffle"][:2],
)

WAFFLE_PI = RobotModel(
    name="waffle_pi",
    chassis=WAFFLE.chassis,
    wheel_x=WAFFLE.wheel_x,
    wheel_y=WAFFLE.wheel_y,
    wheel_separation=WAFFLE.wheel_separation,
    wheel_radius=WAFFLE.wheel_radius,
    max_linear_velocity=WAFFLE.max_linear_velocity,
    max_angular_velocity=WAFFLE.max_angular_velocity,
    max_wheel_acceleration=1.0,
    mass=1.5809,
    lidar_offset=WAFFLE.lidar_offset,
)

MODELS: dict[str, RobotModel] = {m.name: m for m in (BURGER, WAFFLE, WAFFLE_PI)}
