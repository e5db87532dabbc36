"""2D ray casting for the TurtleBot3 LDS-01 lidar: a numpy kernel and its compiled twin.

Contract (Gazebo ``ray`` sensor semantics, before noise and masking, which the caller applies):

* A sensor at ``origin`` with yaw ``heading`` fires ``spec.samples`` rays at the angles
  ``heading + angle_min + k * angle_increment``; the last ray is at ``angle_max`` (6.28 for the
  LDS-01, 0.0032 rad short of a full turn: no beam looks into that gap).
* A ray starts at ``range_min`` from the origin.  The result is the distance from the origin to
  the first crossing of an obstacle *boundary* at a distance ``t`` with
  ``range_min <= t <= range_max``, or ``+inf`` when there is none.
* Consequently a ray that starts inside a circle or a closed polygon reports that shape's far
  side (its boundary), as in Gazebo, whose rays also start at ``range_min``; anything nearer
  than ``range_min`` is invisible.
* Obstacles are static segments (polygons given as their edges), static circles, and the robots'
  outline segments (``dyn_segments``), each tagged with its robot id; a sensor never sees the
  segments of its own robot.
* A ray exactly collinear with a segment does not hit that segment, and a ray that grazes a free
  segment end, a circle tangentially or a range limit to within rounding may go either way
  (measure-zero cases; a closed outline still stops a ray at its vertices, see EPS_SEG).

Two kernels.  ``cast`` runs the compiled kernel, simd/core/_raycast.c (module ``simd.core._raycast``, built
with the package where there is a C compiler), else the numpy kernel, ``cast_numpy``, which stays
the reference: tests/core/test_lidar_native.py checks that both return the same bits, and
tests/core/test_lidar.py checks both against an independent per-beam oracle.  ``KERNEL`` names the one
that ``cast`` uses ("native" or "numpy"; ``NATIVE_UNAVAILABLE`` says why not native).
``FLEETSIM_LIDAR=numpy`` forces numpy, ``=native`` fails at import if the module is missing, and
``auto`` (the default) takes what is there; when FLEETSIM_LIDAR is unset, the switch of all the
compiled fast paths, FLEETSIM_NATIVE, decides alike.

Why a compiled twin.  The numpy kernel below pays for ~200 numpy calls and a few MB of
temporaries per batch, whatever the batch: with 100 robots a batch of 100 sensors took ~2 ms
here (~6.5 ms measured inside the busy daemon, ~30% of its tick).  The C kernel does the same work
sensor by sensor, in registers and one row of scratch, with the GIL released.  Medians of
bench/lidar_bench.py (the two kernels interleaved call by call, on the 2-core development VM):

    world (bench/lidar_bench.py)    robots  sensors    numpy    native   speed-up
    arena (bench/arena.py grid)        100      100   2.05 ms  0.34 ms     6.0x
    arena                             1000      100   3.32 ms  0.56 ms     6.0x
    arena                             1000      167   5.19 ms  0.91 ms     5.8x
    random (60 m square)               100      100   2.05 ms  0.29 ms     7.1x
    random                            1000      100   4.44 ms  0.80 ms     5.6x
    random                            1000      167   5.87 ms  1.14 ms     5.0x

(the naive every-beam-x-every-primitive reference takes 45-350 ms for these, 150-330x the C
kernel); alone, without the numpy calls in between to evict its data, the C kernel runs ~30%
faster.  Its cost is spread over many small pieces (a few hundred cycles per robot in range:
finding the group, its beam run, ~6 front faces of 8-beam vector chunks, each a division per
beam), which is why it does not go much further single-threaded.

How the C kernel keeps the numpy kernel's results.  Every number that a hit distance is made of
is the same float64 expression of the same inputs, in the same order: cos/sin of the beam-0
bearings and the beam table come from numpy, outline groups, their closed-loop test and their
orientation are worked out as here, and the file is compiled with -ffp-contract=off (no FMA) and
without -ffast-math.  What differs is only which beams are *tested* for a primitive: the C kernel
takes bearings in float64 and pads arcs by EPS_ANGLE_NATIVE, tests a robot outline on all the
beams of its bounding circle when they are few, tests beams in chunks of 8, skips static pieces
beyond range_max, and culls back faces and groups on a radius bound 1e-12 above numpy's.  It
tests every (primitive, beam) pair that the numpy kernel tests, so the scans are bit for bit the
same (7 000 random scenes and specs: no beam differed; 10 000 more with sensors snapped onto the
geometry: only the cases below) except where an extra pair hits, which takes a degenerate case:
with range_min ~0, a sensor on (within ~1e-4 m of) a segment or a circle boundary, where every
ray meets it at t ~ 0 and the numpy kernel reports only the beams of the arc it picked; and a ray
exactly through a segment end (e.g. with a full 2*pi of beams the first and the last beam
coincide, and a segment that starts exactly on that ray is hit by both in C, by one in numpy).
Non-finite coordinates: the numpy kernel may raise, the C kernel reports misses.

Why the numpy kernel has this shape.  The target is ~167 sensors x 360 beams against ~12 000 moving
segments (1 000 robots x 12 edges) per 30 Hz tick on one core.  Testing every beam against every
primitive in range wastes almost all the work: a robot 2 m away covers ~5 of 360 beams, and one
of its edges 0 to 2.  So the work is done per (sensor, primitive) *pair*, only over the beams
that the primitive can hit:

1. Pairs.  Static geometry is indexed once on a uniform grid whose cells list every primitive
   that may come within ``range_max`` of a point of the cell: one lookup per sensor.  Moving
   segments are grouped per robot outline (consecutive segments with the same owner) and the
   groups' bounding circles binned every call (a radix sort of small cell ids); a sensor visits,
   row by row, the cells that its range disc covers, each (sensor, row) being one contiguous run
   of groups.  Groups out of range or of the sensor's own robot are dropped whole.
2. Back faces.  When a group is a closed loop and the ray starts outside it (the group is beyond
   ``range_min``), the first crossing into it is through an edge that faces the sensor, so the
   edges facing away (about half) are dropped before any angle is computed.
3. Beams.  A segment not through the origin subtends the shorter arc between its endpoints'
   bearings (computed in float32 with a safety pad, EPS_ANGLE: they only choose beams); a circle
   subtends ``bearing +- asin(r / d)`` (every beam when the origin is inside).  The arc is one
   contiguous run of *extended* beam indices ``0 .. 2*samples-1``, where ``samples + k`` is beam
   ``k`` reached after wrapping past 2*pi; beam indices are not simply modular because the last
   beam is at ``angle_max``, short of 2*pi.  ~40% of the remaining pairs cover no beam at all.
4. Entries.  Runs are flattened into (pair, beam) entries; each is an exact float64 ray/segment
   (ray/circle) intersection, in the sensor frame so that beam directions come from one table.
5. Reduction.  ``np.minimum.at`` on the flat (sensor, beam) key keeps the nearest hit.

At 1 000 robots a batch of 167 sensors has ~23k candidate pairs, ~12k after back-face culling,
~7k that cover beams and ~22k entries.  The cost is spread over some 200 numpy calls; data is
kept in contiguous rows (``np.take`` along an axis moves whole rows, measured much faster than
separate column gathers).  There is no Python loop over rays, primitives or sensors; numpy
releases the GIL during the array work.  See bench/lidar_bench.py.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Protocol
from typing import cast as _typed

import numpy as np
import numpy.typing as npt

from simd.core import native

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
B = npt.NDArray[np.bool_]
FA = npt.NDArray[np.floating]

TWO_PI = 2.0 * np.pi

# Padding (rad) added to both ends of a primitive's angular interval before it is turned into
# beam indices.  Segment bearings are computed in float32 (a pure speed choice): input rounding,
# atan2 and the shift into beam units add up to < 3e-6 rad, so 2e-5 rad is a safe margin, and
# only adds a beam to ~0.2% of the runs.  The exact float64 per-beam test decides hits.
EPS_ANGLE = 2e-5

# The native kernel takes bearings in float64 (error < 2e-10 rad) and pads by this much more, so
# that it tests every beam that the numpy kernel tests (whose float32 bearings err by < 3e-6 rad).
EPS_ANGLE_NATIVE = EPS_ANGLE + 1e-5

# Tolerance on the segment parameter s in [0, 1] of a ray/segment hit.  A ray through the shared
# vertex of two polygon edges must hit at least one of them despite rounding; 1e-9 of an edge
# length is far below any physical size.  It also rejects the hits on an edge's extension that
# the beam padding (EPS_ANGLE) lets through.
EPS_SEG = 1e-9

# Bounds of a LidarSpec, the same as the compiled kernel's: a range beyond MAX_RANGE (m) would
# let squared distances overflow, and more than MAX_SAMPLES beams is no lidar.
MAX_RANGE = 1e6
MAX_SAMPLES = 1 << 24

# Slack (m) on every range cull, so that rounding never drops a primitive at exactly range_max.
EPS_CULL = 1e-9

# Static grid cell size (m).  A sensor reads the candidate list of its own cell, which holds the
# primitives within range_max + half a cell diagonal of the cell centre: smaller cells give
# tighter lists but a bigger one-off index.
STATIC_CELL = 1.0

# Static segments are split into pieces no longer than this (m), so that a long wall only
# contributes the beams of the pieces that are within range_max of the sensor.
STATIC_PIECE = 1.0

# Upper bound on the number of static grid cells; the cell size doubles for huge worlds.
STATIC_MAX_CELLS = 1 << 22

# Moving segments are culled per group: a run of consecutive segments of one owner (a robot
# outline), at most GROUP_MAX long and at most GROUP_MAX_RADIUS (m) in bounding radius.
GROUP_MAX = 16
GROUP_MAX_RADIUS = 0.5

# Dynamic grid cell size (m): a sensor's candidate groups are those whose centre lies in the
# cells that its range disc (grown by the largest group radius) touches; smaller cells hug the
# disc more tightly but cost more runs.  bench/lidar_bench.py: 0.5 to 1 m equal, 0.25 m slower.
DYN_CELL = 1.0

# Upper bound on the number of dynamic grid cells (cell ids then fit uint16, which numpy sorts
# with a radix sort); the cell size doubles when the robots spread wider.
DYN_MAX_CELLS = 1 << 16

# Sensors handled per pass: bounds the temporaries of very large batches.  Smaller chunks were
# measured slower at 167 sensors: the fixed cost of ~200 numpy calls per pass dominates.
CHUNK_SENSORS = 512


# One call allocates a few MB of numpy temporaries.  With glibc's default malloc thresholds that
# memory goes back to the OS after every call and is page-faulted in again on the next (~1 500
# minor faults per 167-sensor batch, measured at ~40% of the call time).  Allocating and freeing
# one block of HEAP_WARMUP_BYTES once raises glibc's dynamic mmap/trim thresholds to that size,
# so the heap keeps the memory between calls.  Elsewhere it is just one short-lived allocation.
HEAP_WARMUP_BYTES = 16 << 20


def _warm_heap() -> None:
    np.empty(HEAP_WARMUP_BYTES, dtype=np.uint8)


_warm_heap()


@dataclass(frozen=True)
class LidarSpec:
    """Ray layout and range of a planar lidar (defaults: TurtleBot3 LDS-01 in Gazebo)."""

    samples: int = 360
    angle_min: float = 0.0
    angle_max: float = 6.28
    range_min: float = 0.12
    range_max: float = 3.5

    def __post_init__(self) -> None:
        if self.samples < 2:
            raise ValueError("samples must be >= 2")
        if not 0.0 < self.angle_max - self.angle_min <= TWO_PI:
            raise ValueError("angle_max - angle_min must lie in (0, 2*pi]")
        if not 0.0 <= self.range_min < self.range_max <= MAX_RANGE:
            raise ValueError(f"need 0 <= range_min < range_max <= {MAX_RANGE:g} m")
        if self.samples > MAX_SAMPLES:
            raise ValueError(f"samples must be at most {MAX_SAMPLES}")

    @property
    def angle_increment(self) -> float:
        return (self.angle_max - self.angle_min) / (self.samples - 1)

    def angles(self) -> F64:
        """Beam angles relative to the sensor heading, shape (samples,)."""
        k = np.arange(self.samples, dtype=np.float64)
        return self.angle_min + k * self.angle_increment


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
        self._native_args: _SceneArgs = (
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
            s, pos = _expand(sensors, first, bounds[cells + 1] - first)
            pairs += [s, items[pos]]
        return pairs[0], pairs[1], pairs[2], pairs[3]


def _csr(keys: I64, values: I64, nkeys: int) -> tuple[I64, I64]:
    """Group ``values`` by ``keys`` in [0, nkeys): run bounds (nkeys + 1,) and grouped values."""
    order = np.argsort(keys, kind="stable")
    bounds = np.zeros(nkeys + 1, dtype=np.int64)
    np.cumsum(np.bincount(keys, minlength=nkeys), out=bounds[1:])
    return bounds, values[order].astype(np.int64)


def _expand(owner: I64, first: I64, count: I64) -> tuple[I64, I64]:
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


class _DynGrid:
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
        s, g = _expand(sensor.astype(np.int64), first, last - first)
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
        s_full, i_full = _expand(s[full], self.start[g[full]], self.count[g[full]])
        s_part, i_part = _expand(s[part], self.start[g[part]], self.count[g[part]])
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


@functools.lru_cache(maxsize=8)
def _beam_table(spec: LidarSpec) -> F64:
    """Unit beam directions in the sensor frame over the extended range: rows dx, dy."""
    rel = np.tile(spec.angles() - spec.angle_min, 2)
    table = np.stack([np.cos(rel), np.sin(rel)])
    table.flags.writeable = False
    return table


class _Frames:
    """Per-call sensor quantities: beam-0 bearing shift (beam units), cos/sin of beam-0 bearing."""

    def __init__(self, spec: LidarSpec, headings: F64) -> None:
        n = spec.samples
        self.n = n
        self.inv = 1.0 / spec.angle_increment  # rad -> beam units
        self.turn = TWO_PI * self.inv  # one full turn in beam units (>= n - 1)
        self.eps = EPS_ANGLE * self.inv
        self.full = self.turn < n  # the beams go round the whole circle (LDS-01: 359.18 < 360)
        h0 = headings + spec.angle_min  # world bearing of beam 0
        h0u = h0 * self.inv
        h0u -= self.turn * np.floor(h0u / self.turn)  # [0, turn)
        # bearing b (rad) -> beam units from beam 0: b*inv + shift, taken modulo one turn
        self.shift = self.turn - h0u
        self.shift32 = self.shift.astype(np.float32)
        self.inv32 = np.float32(self.inv)
        self.turn32 = np.float32(self.turn)
        self.cos = np.cos(h0)
        self.sin = np.sin(h0)
        self.table = _beam_table(spec)

    def wrap(self, u: FA) -> FA:
        """Beam units modulo one turn, into [0, turn] (in place)."""
        u -= self.turn * np.floor(u * (1.0 / self.turn))
        return u

    def runs(self, start: FA, end: FA) -> tuple[FA, FA]:
        """Extended beam runs (first index, count; count <= 0: none) of arcs [start, end].

        ``start`` is in [0, turn] and ``end >= start``, both in beam units from beam 0.  Beam
        ``k`` sits at ``k`` and, after one turn, at ``turn + k`` = extended index ``n + k``.
        """
        n, turn = self.n, self.turn
        endp = end + self.eps
        k0 = np.ceil(start - self.eps)
        if self.full:
            # beams up to n-1 lie below one turn, the wrapped ones at turn + k
            last = np.floor(endp - (endp >= turn) * (turn - n))
        else:
            k0 = np.minimum(k0, float(n))
            # past one turn only the n beams again (a narrow field of view: turn >> n)
            wrapped = np.minimum(np.floor(endp - turn), n - 1.0) + n
            last = np.where(endp >= turn, wrapped, np.minimum(np.floor(endp), n - 1.0))
        return k0, last - k0 + 1.0


def _entries(k0: FA, count: I64) -> tuple[I64, I64]:
    """Flatten runs (all with count > 0) into entries: run index and extended beam index."""
    total = int(count.sum())
    start = np.cumsum(count) - count
    rep = np.repeat(np.arange(len(count), dtype=np.int64), count)
    k = np.arange(total, dtype=np.int64) + np.take(k0.astype(np.int64) - start, rep)
    return rep, k


def _segment_hits(fr: _Frames, spec: LidarSpec, sensor: I64, rel: F64, cull_from: int) -> tuple[I64, F64]:
    """Beam hits on segments; ``rel`` rows are the endpoints ``ax, ay, bx, by`` relative to each
    pair's sensor (world axes).  Pairs from ``cull_from`` on are edges of counter-clockwise
    closed loops that the ray enters from outside: their back faces (sensor on the left of the
    edge) are dropped, since a first crossing into a loop is always through a front face.

    Returns the flat output key (``sensor * samples + beam``) and the distance of every beam
    that hits its pair's segment within [range_min, range_max].
    """
    rel = np.ascontiguousarray(rel.T)  # rows ax, ay, bx, by: contiguous for the math below
    if cull_from < len(sensor):
        ax, ay, bx, by = rel[:, cull_from:]
        front = ax * by - ay * bx < 0.0  # cross(a, b) < 0: the sensor is right of a -> b
        keep = np.concatenate([np.arange(cull_from), cull_from + np.flatnonzero(front)])
        sensor = sensor[keep]
        rel = np.take(rel, keep, axis=1)
    # bearings of both endpoints at once, in float32 (only to choose beams: padded by EPS_ANGLE)
    rt = rel.astype(np.float32)
    u = np.arctan2(rt[1::2], rt[0::2])
    u *= fr.inv32  # world bearings in beam units, within +- half a turn
    # the shorter arc between them (a segment not through the origin spans < half a turn)
    lo = np.minimum(u[0], u[1])
    hi = np.maximum(u[0], u[1])
    span = hi - lo
    wraps = span > 0.5 * fr.turn32  # the short way round crosses the -pi/pi cut
    start = np.where(wraps, hi, lo)
    span = np.where(wraps, fr.turn32 - span, span)
    start += fr.shift32[sensor]  # relative to beam 0
    fr.wrap(start)
    k0, count = fr.runs(start, start + span)
    keep = np.flatnonzero(count > 0.0)

    # survivors: rotate into the sensor frame, pack rows ax, ay, ex, ey, cross(a, e), key base
    sp = sensor[keep]
    ax, ay, bx, by = np.take(rel, keep, axis=1)
    ch, sh = fr.cos[sp], fr.sin[sp]
    ex, ey = bx - ax, by - ay
    pk = np.empty((6, len(keep)))
    pk[0] = ch * ax + sh * ay
    pk[1] = ch * ay - sh * ax
    pk[2] = ch * ex + sh * ey
    pk[3] = ch * ey - sh * ex
    pk[4] = ax * ey - ay * ex  # rotation invariant
    pk[5] = sp * float(fr.n)

    # entries: one per (pair, beam), rows gathered contiguously
    rep, k = _entries(k0[keep], count[keep].astype(np.int64))
    eax, eay, eex, eey, ec0, ebase = np.take(pk, rep, axis=1)
    dx, dy = np.take(fr.table, k, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_den = 1.0 / (dx * eey - dy * eex)
        t = ec0 * inv_den  # ray parameter: cross(a, e) / cross(d, e)
        s = (eax * dy - eay * dx) * inv_den  # segment parameter: cross(a, d) / cross(d, e)
    hit = np.flatnonzero((t >= spec.range_min) & (t <= spec.range_max) & (s >= -EPS_SEG) & (s <= 1.0 + EPS_SEG))
    kh = k[hit]
    return np.take(ebase, hit).astype(np.int64) + kh - fr.n * (kh >= fr.n), t[hit]


def _circle_hits(fr: _Frames, spec: LidarSpec, sensor: I64, rel: F64, radius: F64) -> tuple[I64, F64]:
    """Beam hits on circles of ``radius`` centred at ``rel`` (relative to each pair's sensor).

    Boundary crossings are at t = b -+ sqrt(b^2 - (|f|^2 - r^2)) with b = d.f; the nearer one at
    or beyond range_min counts, so a ray that starts inside the circle reports its far side.
    """
    fx, fy = rel[:, 0], rel[:, 1]
    dist = np.hypot(fx, fy)
    keep = np.flatnonzero(np.abs(dist - radius) <= spec.range_max + EPS_CULL)
    sensor, fx, fy, radius, dist = sensor[keep], fx[keep], fy[keep], radius[keep], dist[keep]
    with np.errstate(divide="ignore", invalid="ignore"):
        half = np.where(dist <= radius, 0.5 * fr.turn, np.arcsin(np.minimum(radius / dist, 1.0)) * fr.inv)
    start = fr.wrap(np.arctan2(fy, fx) * fr.inv + fr.shift[sensor]) - half
    start += fr.turn * (start < 0.0)
    k0, count = fr.runs(start, start + 2.0 * half)
    count = np.minimum(count, float(fr.n))  # a full circle covers each beam once
    keep = np.flatnonzero(count > 0.0)

    sp = sensor[keep]
    ch, sh = fr.cos[sp], fr.sin[sp]
    fx, fy, dist, radius = fx[keep], fy[keep], dist[keep], radius[keep]
    pk = np.empty((4, len(keep)))
    pk[0] = ch * fx + sh * fy
    pk[1] = ch * fy - sh * fx
    pk[2] = dist * dist - radius * radius
    pk[3] = sp * float(fr.n)

    rep, k = _entries(k0[keep], count[keep].astype(np.int64))
    efx, efy, ecc, ebase = np.take(pk, rep, axis=1)
    dx, dy = np.take(fr.table, k, axis=1)
    b = dx * efx + dy * efy
    disc = b * b - ecc
    root = np.sqrt(np.maximum(disc, 0.0))
    t = np.where(b - root >= spec.range_min, b - root, b + root)
    hit = np.flatnonzero((disc >= 0.0) & (t >= spec.range_min) & (t <= spec.range_max))
    kh = k[hit]
    return np.take(ebase, hit).astype(np.int64) + kh - fr.n * (kh >= fr.n), t[hit]


def _cast_chunk(
    scene: StaticScene,
    spec: LidarSpec,
    fr: _Frames,
    origins: F64,
    owners: I64,
    grid: _DynGrid | None,
    lo: int,
    hi: int,
    out: F64,
) -> None:
    """Hits of sensors lo .. hi-1, min-reduced into ``out`` (flat, sensor * samples + beam)."""
    org = origins[lo:hi]
    s_st, i_st, s_ci, i_ci = scene.candidates(org)
    if len(s_ci):
        rel = np.take(scene.circles[:, :2], i_ci, axis=0) - np.take(org, s_ci, axis=0)
        np.minimum.at(out, *_circle_hits(fr, spec, s_ci + lo, rel, scene.circles[i_ci, 2]))
    # static pieces and other robots' edges together (fewer, larger numpy calls)
    rows = [np.take(scene.pieces, i_st, axis=0)]
    sensors = [s_st]
    cull_from = len(s_st)
    if grid is not None:
        s_full, i_full, s_part, i_part = grid.pairs(org, owners[lo:hi])
        rows += [np.take(grid.segments, i_full, axis=0), np.take(grid.segments, i_part, axis=0)]
        sensors += [s_full, s_part]
        cull_from += len(s_full)
    sensor = np.concatenate(sensors)
    if len(sensor) == 0:
        return
    rel = np.concatenate(rows)
    rel -= np.take(np.concatenate([org, org], axis=1), sensor, axis=0)  # relative to the sensor
    np.minimum.at(out, *_segment_hits(fr, spec, sensor + lo, rel, cull_from))


# The native kernel's arguments (simd/core/_raycast.c, cast): the static scene's index, the sensors
# and moving segments of the call, the spec and the tolerances, the output rows.
_SceneArgs = tuple[F64, F64, I64, I64, I64, I64, float, float, float, int, int]
_SpecArgs = tuple[F64, int, float, float, float, float, float, float, int, float, float]


class _NativeModule(Protocol):
    """The API of the compiled kernel, simd.core._raycast (simd/core/_raycast.c)."""

    def cast(
        self,
        pieces: F64,
        circles: F64,
        seg_bounds: I64,
        seg_items: I64,
        cir_bounds: I64,
        cir_items: I64,
        grid_x0: float,
        grid_y0: float,
        grid_cell: float,
        grid_nx: int,
        grid_ny: int,
        origins: F64,
        h0: F64,
        cos_h0: F64,
        sin_h0: F64,
        owners: I64,
        dyn_segments: F64,
        dyn_owner: I64,
        table: F64,
        samples: int,
        angle_increment: float,
        range_min: float,
        range_max: float,
        eps_angle: float,
        eps_seg: float,
        eps_cull: float,
        group_max: int,
        group_max_radius: float,
        dyn_cell: float,
        out: npt.NDArray[np.float64] | npt.NDArray[np.float32],
        /,
    ) -> None: ...


@functools.lru_cache(maxsize=8)
def _native_spec_args(spec: LidarSpec) -> _SpecArgs:
    return (
        _beam_table(spec),
        spec.samples,
        spec.angle_increment,
        spec.range_min,
        spec.range_max,
        EPS_ANGLE_NATIVE,
        EPS_SEG,
        EPS_CULL,
        GROUP_MAX,
        GROUP_MAX_RADIUS,
        DYN_CELL,
    )


def _load_native() -> tuple[_NativeModule | None, str | None]:
    """The compiled kernel, or None and the reason why it is not used (simd/core/native.py's switch,
    which FLEETSIM_LIDAR overrides for the lidar alone)."""
    module, why = native.load("raycast")
    return (_typed(_NativeModule, module), None) if module is not None else (None, why)


_NATIVE, NATIVE_UNAVAILABLE = _load_native()

#: The kernel that ``cast`` uses: "native" (simd.core._raycast) or "numpy" (``cast_numpy``).
#: ``NATIVE_UNAVAILABLE`` says why the native kernel is not used, when it is not.
KERNEL = "native" if _NATIVE is not None else "numpy"


def _inputs(
    scene: StaticScene,
    spec: LidarSpec,
    origins: np.ndarray,
    headings: np.ndarray,
    sensor_owner: np.ndarray,
    dyn_segments: np.ndarray,
    dyn_owner: np.ndarray,
) -> tuple[F64, F64, I64, F64, I64]:
    """Checked, contiguous float64 / int64 copies (or views) of ``cast``'s array arguments."""
    org = np.ascontiguousarray(origins, dtype=np.float64).reshape(-1, 2)
    hdg = np.ascontiguousarray(headings, dtype=np.float64).reshape(-1)
    sown = np.ascontiguousarray(sensor_owner, dtype=np.int64).reshape(-1)
    dseg = np.ascontiguousarray(dyn_segments, dtype=np.float64).reshape(-1, 4)
    down = np.ascontiguousarray(dyn_owner, dtype=np.int64).reshape(-1)
    if len(hdg) != len(org) or len(sown) != len(org) or len(down) != len(dseg):
        raise ValueError("origins/headings/sensor_owner and dyn_segments/dyn_owner lengths differ")
    if spec.range_max > scene.range_max + EPS_CULL:
        raise ValueError("spec.range_max exceeds the range the StaticScene was indexed for")
    return org, hdg, sown, dseg, down


def _cast64_numpy(scene: StaticScene, spec: LidarSpec, org: F64, hdg: F64, sown: I64, dseg: F64, down: I64) -> F64:
    """The numpy kernel on checked inputs: (N, samples) float64."""
    nsens, n = len(org), spec.samples
    out = np.full(nsens * n, np.inf)
    if nsens == 0:
        return out.reshape(0, n)
    fr = _Frames(spec, hdg)
    grid = _DynGrid(dseg, down, spec.range_min, spec.range_max) if len(dseg) else None
    # sensors in chunks (one chunk at fleet sizes of interest), to bound the temporaries
    for lo in range(0, nsens, CHUNK_SENSORS):
        hi = min(lo + CHUNK_SENSORS, nsens)
        _cast_chunk(scene, spec, fr, org, sown, grid, lo, hi, out)
    return out.reshape(nsens, n)


def _cast_native_into(
    scene: StaticScene,
    spec: LidarSpec,
    org: F64,
    hdg: F64,
    sown: I64,
    dseg: F64,
    down: I64,
    out: npt.NDArray[np.float64] | npt.NDArray[np.float32],
) -> None:
    """The compiled kernel on checked inputs, into out (N, samples), float64 or float32."""
    if _NATIVE is None:
        raise RuntimeError(f"the native lidar kernel is not available: {NATIVE_UNAVAILABLE}")
    if len(org) == 0:
        return
    h0 = hdg + spec.angle_min  # beam-0 bearings; cos/sin from numpy, exactly as _Frames
    _NATIVE.cast(*scene._native_args, org, h0, np.cos(h0), np.sin(h0), sown, dseg, down, *_native_spec_args(spec), out)


def _cast64_native(scene: StaticScene, spec: LidarSpec, org: F64, hdg: F64, sown: I64, dseg: F64, down: I64) -> F64:
    """The compiled kernel on checked inputs: (N, samples) float64."""
    out = np.empty((len(org), spec.samples))
    _cast_native_into(scene, spec, org, hdg, sown, dseg, down, out)
    return out


def _cast32_native(
    scene: StaticScene, spec: LidarSpec, org: F64, hdg: F64, sown: I64, dseg: F64, down: I64
) -> npt.NDArray[np.float32]:
    """The compiled kernel on checked inputs: (N, samples) float32 (rounded in C)."""
    out = np.empty((len(org), spec.samples), dtype=np.float32)
    _cast_native_into(scene, spec, org, hdg, sown, dseg, down, out)
    return out


def cast_numpy(
    scene: StaticScene,
    spec: LidarSpec,
    origins: np.ndarray,
    headings: np.ndarray,
    sensor_owner: np.ndarray,
    dyn_segments: np.ndarray,
    dyn_owner: np.ndarray,
) -> np.ndarray:
    """``cast`` with the numpy kernel (the reference), whatever ``KERNEL`` is."""
    args = _inputs(scene, spec, origins, headings, sensor_owner, dyn_segments, dyn_owner)
    return _cast64_numpy(scene, spec, *args).astype(np.float32)


def cast_native(
    scene: StaticScene,
    spec: LidarSpec,
    origins: np.ndarray,
    headings: np.ndarray,
    sensor_owner: np.ndarray,
    dyn_segments: np.ndarray,
    dyn_owner: np.ndarray,
) -> np.ndarray:
    """``cast`` with the compiled kernel; RuntimeError if it is not available (see KERNEL)."""
    args = _inputs(scene, spec, origins, headings, sensor_owner, dyn_segments, dyn_owner)
    return _cast32_native(scene, spec, *args)


def cast(
    scene: StaticScene,
    spec: LidarSpec,
    origins: np.ndarray,
    headings: np.ndarray,
    sensor_owner: np.ndarray,
    dyn_segments: np.ndarray,
    dyn_owner: np.ndarray,
) -> np.ndarray:
    """Cast every beam of every sensor; see the module docstring for the contract.

    origins (N, 2) sensor positions; headings (N,) sensor yaw; sensor_owner (N,) robot id of each
    sensor; dyn_segments (M, 4) robot outline edges ``x0, y0, x1, y1`` in the world frame;
    dyn_owner (M,) their robot ids.  Returns (N, samples) float32 distances, ``+inf`` where no
    boundary is crossed within [range_min, range_max].  Uses the kernel named by ``KERNEL``.
    """
    args = _inputs(scene, spec, origins, headings, sensor_owner, dyn_segments, dyn_owner)
    if _NATIVE is not None:
        return _cast32_native(scene, spec, *args)
    return _cast64_numpy(scene, spec, *args).astype(np.float32)
