"""Localization for free (``simd --ros-localization``): what AMCL and map_server give Nav2, from
the ground truth, as nav2_loopback_sim gives it.

- ``/map`` (nav_msgs/msg/OccupancyGrid, transient local, depth 1, as map_server's): the world's
  walls and obstacles drawn on a grid (simd/nav/costmap.py's clearances: a cell is occupied when
  the geometry comes within half a cell of its centre), 5 cm a cell (coarser for huge worlds),
  in frame ``map``, the world's; drawn once, when the adapter starts, on a thread of its own;
- ``/<ns>/initialpose`` (geometry_msgs/msg/PoseWithCovarianceStamped, RViz's "2D Pose
  Estimate"): the robot is put at that pose at once, at rest (the engine's
  :class:`~simd.engine.ports.PlaceRequest`: the rules of a spawn, its odometry starting there
  again, a goal it was on cancelled). nav2_loopback_sim moves its robot the same way; with
  AMCL the pose would only be a guess, here it is where the robot is;
- ``map`` -> ``odom`` in every robot's tree (tf_topics.py).

One wildcard subscriber (``<domain>/*/initialpose/<type>/*``) takes every robot's initial
poses, so a spawn declares only the robot's token (robot_ports.py). A pose in a frame that is
not the world's, for a robot this daemon does not simulate, or that the world refuses (a wall,
another robot) moves nothing and is logged: a topic has nobody to answer.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from functools import partial
from typing import Any

import numpy as np
import zenoh

from protocol.errors import FleetError
from protocol.messages import Time
from simd.adapters.ros2.gazebo_services import yaw_of
from simd.adapters.ros2.graph import Node, Qos
from simd.adapters.ros2.interfaces import HUMBLE_HASH, dds_type_name, rihs01, typestore
from simd.adapters.ros2.nav_messages import FrameRefused, world_frames
from simd.adapters.ros2.robot_ports import INITIAL_POSE_TYPE, LatchedPublisher, Participant
from simd.adapters.ros2.service_server import MAX_REQUEST_BYTES
from simd.adapters.ros2.tf_layout import MAP_FRAME
from simd.adapters.zenoh_entities import undeclare_all
from simd.core.worldfile import WorldGeometry
from simd.engine.outbox import Outbox
from simd.engine.ports import PlaceRequest, Reply, Result
from simd.nav.costmap import Grid, occupied_cells

log = logging.getLogger(__name__)

MAP_TYPE = "nav_msgs/msg/OccupancyGrid"
#: map_server's publisher: reliable, transient local, depth 1
MAP_QOS = Qos(depth=1, transient_local=True)

Submit = Callable[[PlaceRequest, Reply], None]


def occupancy_grid(store: Any, world: WorldGeometry, t: float, grid: Grid | None = None) -> bytes:
    """The CDR of the world's nav_msgs/msg/OccupancyGrid at sim time ``t``: 100 occupied, 0 free."""
    grid = grid or Grid.covering(world)
    cells = np.where(occupied_cells(world, grid), 100, 0).astype(np.int8)
    T = store.types
    stamp = Time.from_seconds(t)
    time = T["builtin_interfaces/msg/Time"](sec=stamp.sec, nanosec=stamp.nanosec)
    origin = T["geometry_msgs/msg/Pose"](
        position=T["geometry_msgs/msg/Point"](x=grid.x0, y=grid.y0, z=0.0),
        orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
    )
    info = T["nav_msgs/msg/MapMetaData"](
        map_load_time=time, resolution=grid.resolution, width=grid.width, height=grid.height, origin=origin
    )
    message = T[MAP_TYPE](header=T["std_msgs/msg/Header"](stamp=time, frame_id=MAP_FRAME), info=info,
                          data=np.ascontiguousarray(cells.ravel()))  # fmt: skip
    return bytes(store.serialize_cdr(message, MAP_TYPE))


class RosLocalization:
    """``/map`` and every robot's ``/<ns>/initialpose`` (the module docstring)."""

    def __init__(self, p: Participant, node: Node, world: WorldGeometry, submit: Submit, outbox: Outbox,
                 known: Callable[[str], bool], world_frame: str | None, now: Callable[[], float]) -> None:  # fmt: skip
        self.p = p
        self._submit = submit
        self._outbox = outbox
        self._known = known
        self._world_frame = world_frame
        self.store = typestore(p.distro)
        self.malformed = 0  # initial poses that could not be decoded (counted, logged)
        self._tokens: list[Any] = []
        self.map_pub = LatchedPublisher(p, node, p.topic("/map", MAP_TYPE), MAP_QOS, self._tokens, lazy=True)
        self._hashes = {rihs01(INITIAL_POSE_TYPE), HUMBLE_HASH}
        key = f"{p.domain}/*/initialpose/{dds_type_name(INITIAL_POSE_TYPE)}/*"
        self._sub = p.session.declare_subscriber(key, self._on_initial_pose)
        # a large world takes a while to draw: on a thread of its own, sent in the adapter's order
        threading.Thread(target=self._draw_map, args=(world, now), name="ros2-map", daemon=True).start()

    def _draw_map(self, world: WorldGeometry, now: Callable[[], float]) -> None:
        grid = Grid.covering(world)
        payload = occupancy_grid(self.store, world, now(), grid)
        log.info("/map: %s drawn as %dx%d cells of %g m", world.name, grid.width, grid.height, grid.resolution)
        self._outbox.put(partial(self.map_pub.put, payload))

    # -- initial poses in (zenoh's threads) ---------------------------------------------------------

    def _on_initial_pose(self, sample: zenoh.Sample) -> None:
        chunks = str(sample.key_expr).split("/")
        namespace = chunks[1]
        if len(chunks) != 5 or chunks[4] not in self._hashes or not self._known(namespace):
            return  # another daemon's robot, or another distro's
        payload = sample.payload.to_bytes()
        try:
            if len(payload) > MAX_REQUEST_BYTES:
                raise ValueError(f"{len(payload)} bytes")
            message = self.store.deserialize_cdr(payload, INITIAL_POSE_TYPE)
            request = place_request(message, namespace, world_frames(namespace, self._world_frame))
        except FrameRefused as e:
            log.info("/%s/initialpose ignored: %s", namespace, e)
            return
        except Exception as e:  # rosbags raises several kinds for bytes that are not the type
            self.malformed += 1
            log.info("/%s/initialpose ignored: malformed PoseWithCovarianceStamped: %s", namespace, e)
            return
        try:
            self._submit(request, partial(self._placed, namespace))
        except FleetError as e:  # busy
            log.info("/%s/initialpose ignored: %s", namespace, e.message)

    def _placed(self, namespace: str, result: Result | FleetError) -> None:
        if isinstance(result, FleetError):
            log.info("/%s/initialpose refused: %s", namespace, result.message)

    def close(self) -> None:
        """No more initial poses; /map and its token go."""
        try:
            self._sub.undeclare()
        except zenoh.ZError:
            pass
        self.map_pub.undeclare()
        undeclare_all(self._tokens)


def place_request(message: Any, namespace: str, frames: frozenset[str]) -> PlaceRequest:
    """A PoseWithCovarianceStamped as the engine's request to put robot ``namespace`` there, or
    :class:`FrameRefused` for a frame that is not the world's (the covariance is ignored: the
    pose is where the robot will be, not a guess)."""
    frame = str(message.header.frame_id)
    if frame.lstrip("/") not in frames:
        allowed = ", ".join(repr(f) for f in sorted(frames))
        raise FrameRefused(f"frame {frame!r} is not the world's (fleetsim does no tf transforms): one of {allowed}")
    pose = message.pose.pose
    q = pose.orientation
    yaw = yaw_of(float(q.x), float(q.y), float(q.z), float(q.w))  # the engine refuses what is not finite
    return PlaceRequest(robot=namespace, x=float(pose.position.x), y=float(pose.position.y), yaw=yaw)
