"""The moving segments (robot outlines) of one call, grouped and binned for culling."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from fleetcommon.arrays import F64, I64
from simd.core.lidar.scene import expand
from simd.core.lidar.spec import DYN_CELL, DYN_MAX_CELLS, EPS_CULL, GROUP_MAX, GROUP_MAX_RADIUS

B = npt.NDArray[np.bool_]


class DynGrid:
    """Per-call index of the moving segments, queried for candidate (sensor, segment) pairs.

    Segments are grouped into runs of consecutive segments with the same owner (a robot's
    outline), at most ``GROUP_MAX`` long; a group wider than ``GROUP_MAX_RADIUS`` is split into
    single segments, so that any input order stays correct and only the culling gets coarser.
    Group bounding circles are binned by centre into square cells of ``DYN_CELL`` m (doubled if
    there would be too many) and sorted by cell id, row-major along x (a radix sort of uint16
    ids).  For each grid row within reach of a sensor, the cells that the disc of radius
    ``range_max + largest group radius`` touches in that row are consecutive in the sort, so each
    (sensor, row) is one run of groups.  Groups out of range or of the sensor's own robot are
    dropped before they are expanded into their segments.
    """

    def __init__(self, segments: F64, owner: I64, range_min: float, range_max: float) -> None:
        m = len(segments)
        new = np.empty(m, dtype=np.bool_)
        new[0] = True
        np.not_equal(owner[1:], owner[:-1], out=new[1:])
        start = np.flatnonzero(new)
        if np.max(np.diff(start, append=m)) > GROUP_MAX:
            run = np.cumsum(new) - 1
            new |= (np.arange(m) - start[run]) % GROUP_MAX == 0
            start = np.flatnonzero(new)
        cx, cy, radius = _group_circles(segments, start)
        wide = radius > GROUP_MAX_RADIUS
        if wide.any():
            count = np.diff(start, append=m)
            new[np.repeat(wide, count)] = True
            start = np.flatnonzero(new)
            cx, cy, radius = _group_circles(segments, start)
        count = np.diff(start, append=m)
        segments, closed = _orient_loops(segments, new, start, count)
        self.range_min, self.range_max = range_min, range_max
        self.reach = range_max + float(radius.max())

        cell = DYN_CELL
        x0, y0 = float(cx.min()), float(cy.min())
        span_x, span_y = float(cx.max()) - x0, float(cy.max()) - y0
        while (span_x / cell + 1.0) * (span_y / cell + 1.0) > DYN_MAX_CELLS:
            cell *= 2.0
        inv = 1.0 / cell
        nx, ny = int(span_x * inv) + 1, int(span_y * inv) + 1
        key = ((cy - y0) * inv).astype(np.int64) * nx + ((cx - x0) * inv).astype(np.int64)
        # stable argsort of uint16 keys is a radix sort, O(G)
        order = np.argsort(key.astype(np.uint16), kind="stable")
        self.bounds = np.zeros(nx * ny + 1, dtype=np.int64)
        np.cumsum(np.bincount(key, minlength=nx * ny), out=self.bounds[1:])
        # sorted groups: circle rows (cx, cy, r) and their segment runs and owners
        self.circle: F64 = np.stack([cx[order], cy[order], radius[order]], axis=1)
        self.start: I64 = start[order]
        self.count: I64 = count[order]
        self.owner: I64 = owner[self.start]
        self.closed: B = closed[order]
        self.segments = segments
        self.cell, self.inv, self.x0, self.y0, self.nx, self.ny = cell, inv, x0, y0, nx, ny

    def pairs(self, origins: F64, owners: I64) -> tuple[I64, I64, I64, I64]:
        """Candidate pairs (sensor index, segment index): those to test in full, then those of
        closed counter-clockwise loops that lie beyond range_min, whose back faces can be culled.
        """
        cell, inv, x0, y0, nx, ny, reach = (self.cell, self.inv, self.x0, self.y0, self.nx, self.ny, self.reach)
        r = int(np.ceil(reach * inv))
        ox, oy = origins[:, 0:1], origins[:, 1:2]
        row = np.floor((oy - y0) * inv).astype(np.int64) + np.arange(-r, r + 1)  # (N, 2r+1)
        row_lo = y0 + row * cell
        gap = np.maximum(np.maximum(row_lo - oy, oy - (row_lo + cell)), 0.0)
        half = np.sqrt(np.maximum((reach + EPS_CULL) ** 2 - gap * gap, 0.0))
        c_lo = np.floor((ox - half - x0) * inv).astype(np.int64)
        c_hi = np.floor((ox + half - x0) * inv).astype(np.int64)
        ok = (row >= 0) & (row < ny) & (gap <= reach + EPS_CULL) & (c_hi >= 0) & (c_lo < nx)
        sensor, slot = np.nonzero(ok)
        base = row[sensor, slot] * nx
        first = self.bounds[base + np.maximum(c_lo[sensor, slot], 0)]
        last = self.bounds[base + np.minimum(c_hi[sensor, slot], nx - 1) + 1]
        s, g = expand(sensor.astype(np.int64), first, last - first)
        # exact cull on the group circle, and never the sensor's own robot
        c = np.take(self.circle, g, axis=0)
        o = np.take(origins, s, axis=0)
        dx, dy = c[:, 0] - o[:, 0], c[:, 1] - o[:, 1]
        d2 = dx * dx + dy * dy
        lim = c[:, 2] + (self.range_max + EPS_CULL)
        keep = (d2 <= lim * lim) & (self.owner[g] != owners[s])
        # a ray that starts (at range_min) outside a closed loop first crosses a front face
        near = c[:, 2] + (self.range_min + EPS_CULL)
        cull = self.closed[g] & (d2 > near * near)
        full = np.flatnonzero(keep & ~cull)
        part = np.flatnonzero(keep & cull)
        s_full, i_full = expand(s[full], self.start[g[full]], self.count[g[full]])
        s_part, i_part = expand(s[part], self.start[g[part]], self.count[g[part]])
        return s_full, i_full, s_part, i_part


def _orient_loops(segments: F64, new: B, start: I64, count: I64) -> tuple[F64, B]:
    """Find the groups whose segments form one closed loop (each segment ends exactly where the
    next begins, the last where the first begins) and turn those loops counter-clockwise by
    reversing the segments of clockwise ones.  Returns the segments and a per-group flag.
    """
    m = len(segments)
    x0, y0, x1, y1 = segments[:, 0], segments[:, 1], segments[:, 2], segments[:, 3]
    linked = np.empty(m, dtype=np.bool_)
    np.logical_and(x1[:-1] == x0[1:], y1[:-1] == y0[1:], out=linked[:-1])
    last = np.append(start[1:], m) - 1
    linked[last] = (x1[last] == x0[start]) & (y1[last] == y0[start])
    closed = np.logical_and.reduceat(linked, start) & (count >= 3)
    # twice the signed area of each loop (shoelace)
    area = np.add.reduceat(x0 * y1 - x1 * y0, start)
    closed &= area != 0.0
    flip = closed & (area < 0.0)
    if flip.any():
        rows = np.repeat(flip, count)
        segments = segments.copy()
        segments[rows] = segments[rows][:, [2, 3, 0, 1]]
    return segments, closed


def _group_circles(segments: F64, start: I64) -> tuple[F64, F64, F64]:
    """Bounding circles (centre of the bounding box, half its diagonal) of segment groups."""
    x0, y0, x1, y1 = segments[:, 0], segments[:, 1], segments[:, 2], segments[:, 3]
    xlo = np.minimum.reduceat(np.minimum(x0, x1), start)
    xhi = np.maximum.reduceat(np.maximum(x0, x1), start)
    ylo = np.minimum.reduceat(np.minimum(y0, y1), start)
    yhi = np.maximum.reduceat(np.maximum(y0, y1), start)
    return 0.5 * (xlo + xhi), 0.5 * (ylo + yhi), 0.5 * np.hypot(xhi - xlo, yhi - ylo)
