"""How the fleet's frames are laid out for ROS: one tree for the whole fleet, or one per robot.

Two conventions meet here (docs/ros2.md, "Nav2"):

- **global** (the default, as the TurtleBot3 multi-robot launch): every robot's transforms on
  ``/tf`` and ``/tf_static``, its frames prefixed by its namespace (``TB3_1/odom``,
  ``TB3_1/base_footprint``), so one RViz shows the whole fleet in one tree;
- **namespaced** (``simd --ros-tf namespaced``, nav2_bringup's multi-robot launches, which remap
  ``/tf`` to ``tf`` in every node): each robot's transforms on ``/<ns>/tf`` and
  ``/<ns>/tf_static``, its frames unprefixed (``odom``, ``base_footprint``, ``base_scan``), as a
  single robot's. The messages' frame ids (odometry, scan, IMU) follow.

With ``localization`` (``simd --ros-localization``) each tree also has ``map`` -> ``odom``, taken
from the ground truth: Nav2 then needs no AMCL and no SLAM, as with nav2_loopback_sim. The map
frame is the world's (``/map`` is drawn from it), shared by every robot of the global tree.
"""

from __future__ import annotations

from dataclasses import dataclass

from protocol import frames

#: the frame the ground truth's map is in (nav2's global_frame, AMCL's global_frame_id)
MAP_FRAME = "map"


@dataclass(frozen=True)
class TfLayout:
    namespaced: bool = False
    localization: bool = False
    #: a static frame every robot's odom hangs from (``--ros-world-frame``), or none
    world_frame: str | None = None

    def frame(self, namespace: str, name: str) -> str:
        """A robot's frame: ``TB3_1/odom`` in the fleet's tree, ``odom`` in its own."""
        return frames.frame_id(namespace, name, not self.namespaced)

    def tf_topic(self, namespace: str) -> str:
        return f"/{namespace}/tf" if self.namespaced else "/tf"

    def tf_static_topic(self, namespace: str) -> str:
        return f"/{namespace}/tf_static" if self.namespaced else "/tf_static"

    def dynamic(self, namespace: str) -> list[tuple[str, str]]:
        """The (parent, child) frames of the robot's transforms sent every tick, in this order."""
        odom = self.frame(namespace, "odom")
        base = (odom, self.frame(namespace, "base_footprint"))
        return [(MAP_FRAME, odom), base] if self.localization else [base]

    def static(self, namespace: str, model: str) -> list[frames.Transform]:
        """The robot's fixed frames, as robot_state_publisher sends them."""
        return frames.static_transforms(namespace, model, self.world_frame, prefixed=not self.namespaced)

    def pose_frame(self, namespace: str) -> str:
        """The frame the navigator's poses and paths of the robot are given in: a frame that
        coincides with the world (the map when the daemon localises)."""
        if self.localization:
            return MAP_FRAME
        return self.world_frame or self.frame(namespace, "odom")
