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
import itertools
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from fleetcommon.arrays import I64
from simd.core.robots import RobotTable
from simd.core.snapshot import TickSnapshot
from simd.engine.ports import ObservedArrays


class LatestScans:
    """Each robot's newest scan, as (snapshot, row in its scans), kept tick by tick.

    Snapshots are indexed by namespace only when somebody asks (``get``, ``forget``, or a
    fill after the robot table changed): a packed step reads its scans through the window of
    the last ``scan_every`` snapshots and never needs the index, and filling it costs a dict
    write per scan (~0.2 ms a step of a thousand robots). Snapshots waiting for the index are
    kept while they may hold a robot's newest scan: every robot scans once every ``scan_every``
    ticks, so one more than that many suffice (a robot deleted meanwhile was ``forget``-ed,
    which indexes everything first).
    """

    def __init__(self, scan_every: int) -> None:
        self._scan_every = scan_every
        self._by_namespace: dict[str, tuple[TickSnapshot, int]] = {}
        #: the newest snapshots: the last ``scan_every`` are the window, all may wait for the index
        self._recent: collections.deque[TickSnapshot] = collections.deque(maxlen=scan_every + 1)
        self._unindexed = 0  # how many of the newest in _recent the index has not seen

    def record(self, snap: TickSnapshot) -> None:
        self._recent.append(snap)
        self._unindexed = min(self._unindexed + 1, len(self._recent))

    def _index(self) -> None:
        by_namespace = self._by_namespace
        recent = self._recent
        for snap in itertools.islice(recent, len(recent) - self._unindexed, None):
            for i, ns in enumerate(snap.scan_namespaces):
                by_namespace[ns] = (snap, i)
        self._unindexed = 0

    def get(self, namespace: str) -> tuple[TickSnapshot, int] | None:
        self._index()
        return self._by_namespace.get(namespace)

    def forget(self, namespace: str) -> None:
        self._index()
        self._by_namespace.pop(namespace, None)

    def clear(self) -> None:
        self._by_namespace.clear()
        self._recent.clear()
        self._unindexed = 0

    def _window(self, table: RobotTable) -> Sequence[TickSnapshot] | None:
        """The last ``scan_every`` snapshots, if they hold every robot's newest scan: the
        table's rows did not change over them (same generation, same epoch)."""
        recent = self._recent
        if len(recent) < self._scan_every:
            return None
        window = list(itertools.islice(recent, len(recent) - self._scan_every, None))
        epoch, generation = window[-1].epoch, table.generation
        for s in window:  # (a loop: a generator costs more than these few snapshots)
            if s.generation != generation or s.epoch != epoch:
                return None
        return window

    def fill(
        self, table: RobotTable, rows: I64, samples: int, everyone: bool = False
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float32]]:
        """The newest scan of the robot in table row ``rows[k]`` as ``ranges[k]``, its sim
        time as ``scan_time[k]``; NaN rows for robots that have not scanned yet.
        ``everyone``: ``rows`` is every row of the table, in order (k is the row)."""
        window = self._window(table)
        if window is not None and everyone:
            for snap in window:  # every robot scanned at once (few robots, one lidar batch a
                if len(snap.scan_index) == len(rows):  # period): that tick's rows are all of
                    scan_time = np.empty(len(rows))  # the table, in order
                    scan_time.fill(snap.time)
                    return scan_time, snap.scans
        if window is not None:
            # every robot scanned once in the window: each row is written below, unless a
            # robot is named twice (then the general way below)
            scan_time = np.empty(len(rows))
            ranges = np.empty((len(rows), samples), dtype=np.float32)
            if not everyone:
                at = np.full(len(table), -1, dtype=np.int64)  # table row -> k
                at[rows] = np.arange(len(rows))
            written = 0
            for snap in window:
                if not len(snap.scan_index):
                    continue
                if everyone:
                    ranges[snap.scan_index] = snap.scans
                    scan_time[snap.scan_index] = snap.time
                    written += len(snap.scan_index)
                    continue
                ks = at[snap.scan_index]
                taken = ks >= 0
                if taken.all():
                    ranges[ks] = snap.scans
                else:
                    ks = ks[taken]
                    ranges[ks] = snap.scans[taken]
                scan_time[ks] = snap.time
                written += len(ks)
            if written == len(rows):
                return scan_time, ranges
        # the table changed lately: robot by robot, grouped by the snapshot that holds the scan
        scan_time = np.full(len(rows), np.nan)
        ranges = np.full((len(rows), samples), np.nan, dtype=np.float32)
        self._index()
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
        return scan_time, ranges


def observe_packed(
    table: RobotTable, last: TickSnapshot | None, scans: LatestScans, names: list[str], rows: I64, samples: int
) -> ObservedArrays:
    """The odometry and newest scans of the robots in table ``rows`` (named ``names``), as
    arrays: what their topics carried (or would have, in a step that publishes nothing)."""
    if last is not None and last.generation == table.generation:  # rows unchanged since the last tick
        columns = (last.x, last.y, last.yaw, last.linear_x, last.linear_y, last.angular_z)
    else:  # a spawn or delete since (a cancelled step): the table's own columns
        columns = (table.odom_x, table.odom_y, table.odom_yaw, table.vx, table.vy, table.wz)
    n = len(table)
    # (one row of a one-row table is all of it: no comparison, which costs more than the rest)
    everyone = len(rows) == n and (n == 1 or bool(np.array_equal(rows, np.arange(n))))
    # the columns joined in one call, (n, 6) seen through a transpose: fewer numpy calls than
    # stacking them, which a step of one robot notices (the same values; one row is already
    # in its order)
    if n == 1 and everyone:
        odom = np.array([[c.item() for c in columns]])
    else:
        table_odom = np.concatenate(columns).reshape(6, n).T
        odom = np.ascontiguousarray(table_odom if everyone else table_odom[rows])
    scan_time, ranges = scans.fill(table, rows, samples, everyone)
    return ObservedArrays(names, odom, scan_time, ranges)
