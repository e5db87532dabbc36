"""A TurtleBot3's fixed frames: what robot_state_publisher sends on ``/tf_static`` from the URDF.

Frames carry the robot's namespace (``TB3_1/base_link``), as the TurtleBot3 multi-robot launch
names them with ``frame_prefix``, so one tree holds the whole fleet. Nav2's multi-robot bringup
instead gives each robot a tree of its own (``/TB3_1/tf``) whose frames carry no prefix
(``base_link``): ``prefixed=False`` names them that way. The daemon's ROS 2 adapter publishes
these, and ``fleet-record`` writes them into bags made from the fleet protocol.
"""

from __future__ import annotations

Vector = tuple[float, float, float]
Quaternion = tuple[float, float, float, float]
Transform = tuple[str, str, Vector, Quaternion]  # parent, child, translation, rotation

IDENTITY: Quaternion = (0.0, 0.0, 0.0, 1.0)
#: base_footprint -> base_link, every model
BASE_LINK_Z = 0.010
#: base_link -> base_scan and base_link -> imu_link (turtlebot3_description's URDFs)
SCAN_OFFSET: dict[str, Vector] = {
    "burger": (-0.032, 0.0, 0.172),
    "waffle": (-0.064, 0.0, 0.122),
    "waffle_pi": (-0.064, 0.0, 0.122),
}
IMU_OFFSET: dict[str, Vector] = {
    "burger": (-0.032, 0.0, 0.068),
    "waffle": (0.0, 0.0, 0.068),
    "waffle_pi": (0.0, 0.0, 0.068),
}


def frame_id(namespace: str, name: str, prefixed: bool = True) -> str:
    """A robot's frame: ``TB3_1/odom`` in the fleet's one tree, ``odom`` in a tree of its own."""
    return f"{namespace}/{name}" if prefixed else name


def static_transforms(
    namespace: str, model: str, world_frame: str | None = None, *, prefixed: bool = True
) -> list[Transform]:
    """base_footprint -> base_link -> base_scan and imu_link; with ``world_frame``, also
    ``world_frame`` -> odom (the odometry is ground truth, so the two coincide)."""

    def f(name: str) -> str:
        return frame_id(namespace, name, prefixed)

    world: list[Transform] = [(world_frame, f("odom"), (0.0, 0.0, 0.0), IDENTITY)] if world_frame else []
    return [
        *world,
        (f("base_footprint"), f("base_link"), (0.0, 0.0, BASE_LINK_Z), IDENTITY),
        (f("base_link"), f("base_scan"), SCAN_OFFSET[model], IDENTITY),
        (f("base_link"), f("imu_link"), IMU_OFFSET[model], IDENTITY),
    ]
