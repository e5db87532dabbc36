"""The static scene: walls and obstacles, indexed once on a uniform grid when the world loads."""

from __future__ import annotations

import numpy as np

from fleetcommon.arrays import F64, I64
from simd.core.lidar.spec import EPS_CULL, STATIC_CELL, STATIC_MAX_CELLS, STATIC_PIECE

#: The static scene's index as the compiled kernel's first arguments (simd/core/lidar/_raycast.c).
SceneArgs = tuple[F64, F64, I64, I64, I64, I64, float, float, float, int, int]


class StaticScene:
    """Static geometry, indexed once (uniform grid) when the world loads.

    ``segments`` is (S, 4) ``x0, y0, x1, y1`` (polygons are given as their edges) and ``circles``
    is (C, 3) ``x, y, r``; either may be empty.  Segments are split into pieces of at most
    ``STATIC_PIECE`` m.  Every grid cell lists the primitives whose boundary may come within
    ``range_max`` of a point of the cell, so a sensor finds its static candidates with one lookup.
    ``cast`` accepts a spec whose ``range_max`` is at most the one given here.
    """

    def __init__(self, segments: np.ndarray, circles: np.ndarray, range_max: float = 3.5) -> None:
        seg = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
        cir = np.ascontiguousarray(np.asarray(circles, dtype=np.float64).reshape(-1, 3))
        self.range_max = float(range_max)
        self.segments = seg
        self.circles = cir

        # split long segments into pieces (repeat each segment by its piece count)
        length = np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1])
        npieces = np.maximum(np.ceil(length / STATIC_PIECE), 1).astype(np.int64)
        sid = np.repeat(np.arange(len(seg)), npieces)
        first = np.cumsum(npieces) - npieces
        j = (np.arange(len(sid)) - first[sid]).astype(np.float64)
        u0 = (j / npieces[sid])[:, None]
        u1 = ((j + 1.0) / npieces[sid])[:, None]
        a, b = seg[sid, :2], seg[sid, 2:]
        p0 = a + u0 * (b - a)
        p1 = np.where(u1 >= 1.0, b, a + u1 * (b - a))
        # pieces as packed rows x0, y0, x1, y1
        self.pieces: F64 = np.ascontiguousarray(np.concatenate([p0, p1], axis=1))

        nseg = len(self.pieces)
        lo = np.concatenate([np.minimum(p0, p1), cir[:, :2] - cir[:, 2:3]], axis=0)
        hi = np.concatenate([np.maximum(p0, p1), cir[:, :2] + cir[:, 2:3]], axis=0)
        reach = self.range_max
        cell = STATIC_CELL
        gmin = lo.min(axis=0) - reach if len(lo) else np.zeros(2)
        gmax = hi.max(axis=0) + reach if len(lo) else np.zeros(2)
        while np.prod(np.floor((gmax - gmin) / cell) + 1) > STATIC_MAX_CELLS:
            cell *= 2.0
        nx, ny = (int(v) for v in np.floor((gmax - gmin) / cell) + 1)
        self.cell = float(cell)
        self.origin: F64 = gmin
        self.shape = (nx, ny)
        lim = reach + cell * np.sqrt(0.5) + EPS_CULL  # range + half a cell diagonal

        # each primitive's candidate cells: its bbox grown by `lim`, then an exact test of the
        # distance from the cell centre to the primitive's boundary
        ilo = np.clip(np.floor((lo - lim - gmin) / cell), 0, [nx - 1, ny - 1]).astype(np.int64)
        ihi = np.clip(np.floor((hi + lim - gmin) / cell), 0, [nx - 1, ny - 1]).astype(np.int64)
        cx = ihi[:, 0] - ilo[:, 0] + 1
        cy = ihi[:, 1] - ilo[:, 1] + 1
        prim = np.repeat(np.arange(len(lo)), cx * cy)
        first = np.cumsum(cx * cy) - cx * cy
        j2 = np.arange(len(prim)) - first[prim]
        ix = ilo[prim, 0] + j2 // cy[prim]
        iy = ilo[prim, 1] + j2 % cy[prim]
        px = gmin[0] + (ix + 0.5) * cell
        py = gmin[1] + (iy + 0.5) * cell
        is_seg = prim < nseg
        dist = np.full(len(prim), np.inf)
        ps = prim[is_seg]
        dist[is_seg] = _point_segment_distance(
            px[is_seg] - self.pieces[ps, 0],
            py[is_seg] - self.pieces[ps, 1],
            self.pieces[ps, 2] - self.pieces[ps, 0],
            self.pieces[ps, 3] - self.pieces[ps, 1],
        )
        pc = prim[~is_seg] - nseg
        dist[~is_seg] = np.abs(np.hypot(px[~is_seg] - cir[pc, 0], py[~is_seg] - cir[pc, 1]) - cir[pc, 2])
        keep = dist <= lim
        cell_id = ix * ny + iy
        self._seg_csr = _csr(cell_id[keep & is_seg], prim[keep & is_seg], nx * ny)
        self._cir_csr = _csr(cell_id[keep & ~is_seg], prim[keep & ~is_seg] - nseg, nx * ny)
        # the same index as the native kernel's first arguments
        self._native_args: SceneArgs = (
            self.pieces,
            self.circles,
            *self._seg_csr,
            *self._cir_csr,
            float(gmin[0]),
            float(gmin[1]),
            self.cell,
            nx,
            ny,
        )

    def candidates(self, origins: F64) -> tuple[I64, I64, I64, I64]:
        """(sensor, piece) and (sensor, circle) candidate pairs of the given sensor origins."""
        nx, ny = self.shape
        ij = np.floor((origins - self.origin) / self.cell)
        inside = (ij[:, 0] >= 0) & (ij[:, 0] < nx) & (ij[:, 1] >= 0) & (ij[:, 1] < ny)
        sensors = np.flatnonzero(inside)
        cells = (ij[sensors, 0] * ny + ij[sensors, 1]).astype(np.int64)
        pairs: list[I64] = []
        for bounds, items in (self._seg_csr, self._cir_csr):
            first = bounds[cells]
            s, pos = expand(sensors, first, bounds[cells + 1] - first)
            pairs += [s, items[pos]]
        return pairs[0], pairs[1], pairs[2], pairs[3]


def _csr(keys: I64, values: I64, nkeys: int) -> tuple[I64, I64]:
    """Group ``values`` by ``keys`` in [0, nkeys): run bounds (nkeys + 1,) and grouped values."""
    order = np.argsort(keys, kind="stable")
    bounds = np.zeros(nkeys + 1, dtype=np.int64)
    np.cumsum(np.bincount(keys, minlength=nkeys), out=bounds[1:])
    return bounds, values[order].astype(np.int64)


def expand(owner: I64, first: I64, count: I64) -> tuple[I64, I64]:
    """Flatten the index runs ``first[i] .. first[i]+count[i]-1`` into (owner, index) pairs."""
    total = int(count.sum())
    rep_owner = np.repeat(owner, count)
    index = np.arange(total, dtype=np.int64) + np.repeat(first - (np.cumsum(count) - count), count)
    return rep_owner, index


def _point_segment_distance(wx: F64, wy: F64, ex: F64, ey: F64) -> F64:
    """Distance from points at offset (wx, wy) from segment starts to the segments (ex, ey)."""
    ee = ex * ex + ey * ey
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.clip((wx * ex + wy * ey) / ee, 0.0, 1.0)
    s = np.where(ee > 0.0, s, 0.0)
    return np.hypot(wx - s * ex, wy - s * ey)
