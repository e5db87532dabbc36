"""What each robot's own lidar says about the way straight ahead: the room before it meets
something, whatever the map says (and behind, for a robot that drives with its back first:
the navigator asks with the frame turned half round).

The map knows walls and obstacles, the traffic knows the fleet's robots; the lidar is for
the rest (a box put down after the map was made, a robot of another daemon, a robot that
nobody placed in the traffic). Every due scan is read in the robot's frame, as the beams
leave the sensor: the hits inside a corridor as wide as the robot (plus a margin) in front of
it give the free distance ahead of its front edge. All the scans of a tick are worked out in
one pass.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from fleetcommon.arrays import F32, F64
from simd.core.lidar import LidarSpec

#: the corridor is this much wider than the robot on each side
SIDE_MARGIN_M = 0.03
#: hits further than this ahead do not limit anything (the robot stops within a few cm)
LOOK_AHEAD_M = 0.6


class LidarGuard:
    """Free distance ahead, from scans (beam angles of ``spec``)."""

    def __init__(self, spec: LidarSpec) -> None:
        angles = spec.angle_min + np.arange(spec.samples) * spec.angle_increment
        self.cos = np.cos(angles)[None, :]
        self.sin = np.sin(angles)[None, :]

    def points(self, ranges: F32, offset: F64) -> tuple[F64, F64]:
        """Each beam's end in its robot's frame (k, samples): x, y (far away where nothing
        was in range)."""
        r = np.asarray(ranges, dtype=np.float64)
        r = np.where(np.isfinite(r), r, 1e3)  # nothing in range: far beyond the corridor
        return offset[:, :1] + r * self.cos, offset[:, 1:2] + r * self.sin

    @staticmethod
    def room_ahead(
        px: F64, py: F64, half_width: F64, front: F64, ignore: npt.NDArray[np.bool_] | None = None
    ) -> tuple[F64, npt.NDArray[np.bool_]]:
        """For each scan row of beam ends (``points``): metres between the robot's front edge
        and the nearest hit in its corridor (``LOOK_AHEAD_M`` when there is none), and which
        beams hit there; hits where ``ignore`` is true do not count (what the map and the
        traffic already know)."""
        inside = (np.abs(py) <= (half_width + SIDE_MARGIN_M)[:, None]) & (px > front[:, None] - 0.02)
        inside &= px < front[:, None] + LOOK_AHEAD_M
        if ignore is not None:
            inside &= ~ignore
        ahead = np.where(inside, px - front[:, None], LOOK_AHEAD_M)
        room: F64 = np.minimum(ahead.min(axis=1), LOOK_AHEAD_M)
        return room, inside
