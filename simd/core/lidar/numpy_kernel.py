"""The numpy kernel: the reference the compiled kernel is tested against, and its fallback.

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

import numpy as np
import numpy.typing as npt

from fleetcommon.arrays import F64, I64
from simd.core.lidar.dyngrid import DynGrid
from simd.core.lidar.scene import StaticScene
from simd.core.lidar.spec import CHUNK_SENSORS, EPS_ANGLE, EPS_CULL, EPS_SEG, TWO_PI, LidarSpec, beam_table

B = npt.NDArray[np.bool_]
FA = npt.NDArray[np.floating]


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
        self.table = beam_table(spec)

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
    grid: DynGrid | None,
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


def cast64(scene: StaticScene, spec: LidarSpec, org: F64, hdg: F64, sown: I64, dseg: F64, down: I64) -> F64:
    """The numpy kernel on checked inputs: (N, samples) float64."""
    nsens, n = len(org), spec.samples
    out = np.full(nsens * n, np.inf)
    if nsens == 0:
        return out.reshape(0, n)
    fr = _Frames(spec, hdg)
    grid = DynGrid(dseg, down, spec.range_min, spec.range_max) if len(dseg) else None
    # sensors in chunks (one chunk at fleet sizes of interest), to bound the temporaries
    for lo in range(0, nsens, CHUNK_SENSORS):
        hi = min(lo + CHUNK_SENSORS, nsens)
        _cast_chunk(scene, spec, fr, org, sown, grid, lo, hi, out)
    return out.reshape(nsens, n)
