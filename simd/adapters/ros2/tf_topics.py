"""The transforms sent every tick: on the fleet's ``/tf``, or on each robot's ``/<ns>/tf``.

Which of the two, and with which frames, is the :class:`TfLayout`'s (tf_layout.py). Per robot
and tick: ``odom`` -> ``base_footprint`` (the odometry), and with localization ``map`` ->
``odom`` from the ground truth first (:func:`tf_cdr.map_to_odom`; the identity while the
odometry is exact). Each is stamped with the tick's sim time, the odometry's and the scan's, so
a tf2 lookup at a scan's stamp always finds them.

Nothing is built while nobody subscribes: the fleet's ``/tf`` by its publisher's matching
status, the robots' own by theirs (a tally of how many have a subscriber, so a tick with none
costs nothing per robot).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from fleetcommon.arrays import I64
from simd.adapters.ros2 import graph
from simd.adapters.ros2.graph import Node
from simd.adapters.ros2.robot_ports import TF_TYPE, Participant, RobotPorts, RosPublisher
from simd.adapters.ros2.tf_cdr import FleetTfCdr, PoseColumns, RobotTfCdr, map_to_odom
from simd.adapters.ros2.tf_layout import TfLayout
from simd.core.snapshot import TickSnapshot


class TfTopics:
    """The dynamic transforms of one daemon's robots (the adapter's thread only)."""

    def __init__(self, p: Participant, node: Node, layout: TfLayout, tokens: list[Any]) -> None:
        self.p = p
        self.layout = layout
        #: the fleet's /tf (the global layout), else None: each robot has its own (RobotPorts.tf)
        self.fleet_pub: RosPublisher | None = None
        self._fleet = FleetTfCdr(layout.dynamic)
        # unprefixed frames are the same for every robot: one template for all
        self._robot = RobotTfCdr(layout.dynamic("_"))
        if not layout.namespaced:
            self.fleet_pub = RosPublisher(p, node, p.topic("/tf", TF_TYPE), graph.TF_QOS, tokens)

    @property
    def wanted(self) -> bool:
        """Whether anybody reads any of these transforms."""
        if self.fleet_pub is not None:
            return self.fleet_pub.wanted.matching
        return bool(self.p.tf_interest)

    def forget(self, namespace: str) -> None:
        self._fleet.forget(namespace)

    def publish(self, snap: TickSnapshot, ports: Sequence[RobotPorts | None], now: int) -> None:
        """The tick's transforms of the robots with ports (rows of ``snap``), to whoever reads them."""
        if self.fleet_pub is not None:
            if self.fleet_pub.wanted.matching:
                rows = [i for i, q in enumerate(ports) if q is not None]
                if rows:
                    names = tuple(snap.namespaces[i] for i in rows)
                    payload = self._fleet.encode(snap.time, names, self._poses(snap, np.asarray(rows)))
                    self.fleet_pub.put(payload, now)
            return
        interest = self.p.tf_interest
        if not interest:
            return
        robots = sum(q is not None for q in ports)
        if interest.count >= robots:  # every robot's tf is read: no need to ask each
            rows = [i for i, q in enumerate(ports) if q is not None]
        else:
            rows = [i for i, q in enumerate(ports) if q is not None and q.tf is not None and q.tf.wanted.matching]
        if not rows:
            return
        for i, payload in zip(rows, self._robot.encode(snap.time, self._poses(snap, np.asarray(rows))), strict=True):
            pub = ports[i].tf  # type: ignore[union-attr]  # rows hold only robots with ports
            if pub is not None:
                pub.put(payload, now)

    def _poses(self, snap: TickSnapshot, rows: I64) -> list[PoseColumns]:
        """The columns of each transform ``layout.dynamic`` names, for table ``rows``."""
        odom = (snap.x[rows], snap.y[rows], snap.yaw[rows])
        if not self.layout.localization:
            return [odom]
        if snap.true_pose is None:  # exact odometry: map and odom coincide
            zero = np.zeros(len(rows))
            return [(zero, zero, zero), odom]
        tx, ty, tyaw = snap.true_pose
        return [map_to_odom(odom, (tx[rows], ty[rows], tyaw[rows])), odom]
