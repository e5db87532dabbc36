"""What a step hands back about the robots it names: their odometry and newest scans.

A learner steps a thousand robots and reads all of them back after every step, so this is on
the lockstep's critical path (the simulation thread waits for the learner's next request
meanwhile). Every robot scans once every ``scan_every`` ticks, so the newest scans of all
robots are in the last ``scan_every`` snapshots: while the robot table has not changed over
those ticks (no spawn, delete or reset), the scans are copied snapshot by snapshot with array
indexing. Otherwise each robot's newest scan is looked up by namespace, as the message path
does. Both give the same arrays.
"""

from __future__ import annotations

import collections
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from simd.core.robots import RobotTable
from simd.core.snapshot import TickSnapshot
from simd.engine.ports import ObservedArrays

I64 = npt.NDArray[np.int64]


class LatestScans:
    """Each robot's newest scan, as (snapshot, row in its scans), kept tick by tick."""

    def __init__(self, scan_every: int) -> None:
        self._by_namespace: dict[str, tuple[TickSnapshot, int]] = {}
        self._recent: collections.deque[TickSnapshot] = collections.deque(maxlen=scan_every)

    def record(self, snap: TickSnapshot) -> None:
        by_namespace = self._by_namespace
        for i, ns in enumerate(snap.scan_namespaces):
            by_namespace[ns] = (snap, i)
        self._recent.append(snap)

    def get(self, namespace: str) -> tuple[TickSnapshot, int] | None:
        return self._by_namespace.get(namespace)

    def forget(self, namespace: str) -> None:
        self._by_namespace.pop(namespace, None)

    def clear(self) -> None:
        self._by_namespace.clear()
        self._recent.clear()

    def _window(self, table: RobotTable) -> Sequence[TickSnapshot] | None:
        """The last ``scan_every`` snapshots, if they hold every robot's newest scan: the
        table's rows did not change over them (same namespaces list, same epoch)."""
        recent = self._recent
        if len(recent) < (recent.maxlen or 0):
            return None
        epoch = recent[-1].epoch
        if any(s.namespaces is not table.namespaces or s.epoch != epoch for s in recent):
            return None
        return recent

    def fill(
        self, table: RobotTable, rows: I64, scan_time: npt.NDArray[np.float64], ranges: npt.NDArray[np.float32]
    ) -> None:
        """Write the newest scan of the robot in table row ``rows[k]`` into ``ranges[k]`` and
        its sim time into ``scan_time[k]`` (rows without a scan are left as they are)."""
        window = self._window(table)
        if window is not None:
            at = np.full(len(table), -1, dtype=np.int64)  # table row -> k
            at[rows] = np.arange(len(rows))
            for snap in window:
                if not len(snap.scan_index):
                    continue
                ks = at[snap.scan_index]
                taken = ks >= 0
                if taken.all():
                    ranges[ks] = snap.scans
                else:
                    ks = ks[taken]
                    ranges[ks] = snap.scans[taken]
                scan_time[ks] = snap.time
            return
        # the table changed lately: robot by robot, grouped by the snapshot that holds the scan
        groups: dict[int, tuple[TickSnapshot, list[int], list[int]]] = {}
        namespaces = table.namespaces
        for k, row in enumerate(rows.tolist()):
            latest = self._by_namespace.get(namespaces[row])
            if latest is not None:
                snap, i = latest
                group = groups.get(id(snap))
                if group is None:
                    group = groups[id(snap)] = (snap, [], [])
                group[1].append(k)
                group[2].append(i)
        for snap, ks_list, scan_rows in groups.values():
            ranges[ks_list] = snap.scans[scan_rows]
            scan_time[ks_list] = snap.time


def observe_packed(
    table: RobotTable, last: TickSnapshot | None, scans: LatestScans, names: list[str], rows: I64, samples: int
) -> ObservedArrays:
    """The odometry and newest scans of the robots in table ``rows`` (named ``names``), as
    arrays: what their topics carried (or would have, in a step that publishes nothing)."""
    if last is not None and last.namespaces is table.namespaces:  # rows unchanged since the last tick
        columns = (last.x, last.y, last.yaw, last.linear_x, last.linear_y, last.angular_z)
    else:  # a spawn or delete since (a cancelled step): the table's own columns
        columns = (table.odom_x, table.odom_y, table.odom_yaw, table.vx, table.vy, table.wz)
    everyone = len(rows) == len(table) and bool(np.array_equal(rows, np.arange(len(table))))
    odom = np.stack(columns if everyone else [c[rows] for c in columns], axis=1)
    scan_time = np.full(len(rows), np.nan)
    ranges = np.full((len(rows), samples), np.nan, dtype=np.float32)
    scans.fill(table, rows, scan_time, ranges)
    return ObservedArrays(names, odom, scan_time, ranges)
