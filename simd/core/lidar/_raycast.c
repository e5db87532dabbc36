/*
 * simd._raycast: compiled lidar ray-casting kernel for simd.core.lidar.
 *
 * The contract, the data layout and the reasons for the algorithm are in the docstring of
 * simd/core/lidar/, whose numpy kernel (cast_numpy) is the reference.  This file computes the same
 * thing sensor by sensor, against the StaticScene's grid (the same CSR candidate lists) and a
 * uniform grid of robot outline groups built here on every call.
 *
 * Bitwise agreement with the numpy kernel.  Every number that a hit distance is made of is
 * computed with the same float64 formulas in the same order as in lidar.py (_segment_hits,
 * _circle_hits), from the same inputs: cos/sin of the beam-0 bearings and the beam direction
 * table come from numpy (its SIMD cos/sin need not equal libm's), circle distances from
 * hypot() as np.hypot, and outline loops are grouped, found closed and turned
 * counter-clockwise exactly as _DynGrid does (including numpy's pairwise summation order for
 * the loop area, whose sign decides the orientation).  Hence: compile without FMA contraction
 * (-ffp-contract=off) and without -ffast-math (the flags are in pyproject.toml).  Vector
 * instructions change nothing: IEEE division, square root and comparisons are exact per lane.
 *
 * What is not reproduced bit for bit is the choice of the beams to test: numpy takes segment
 * bearings in float32 with its SIMD atan2 and pads each arc by EPS_ANGLE.  Here bearings are
 * float64 (a polynomial atan2, |error| < 2e-10 rad), arcs are padded more (the caller passes
 * EPS_ANGLE_NATIVE), a robot outline may be tested on all the beams of its bounding circle,
 * and beams are tested in fixed-width chunks (up to CHUNK - 1 beams past a run).  So every
 * (primitive, beam) pair that the numpy kernel tests is tested here too, with the same result;
 * an extra pair can only hit in a degenerate case (with range_min ~0 a sensor within ~1e-4 m of
 * a segment or a circle boundary; a ray exactly through a segment end): see lidar.py.
 *
 * Static segment pieces farther than range_max (bounding-box distance, 1e-6 m slack) are skipped
 * before any bearing is computed: their hits would all be beyond range_max, except for rays
 * collinear with the piece to ~1e-9 rad, a case the contract leaves open.  Robot groups are
 * range-tested and back-face culled on a bound of numpy's radius (at most 1e-12 above it): a
 * group just out of range only adds misses, and back faces, then tested too, are never a first
 * crossing (but for a ray exactly through a vertex).
 *
 * Only the Python C API and the buffer protocol are used (no numpy headers).  All inputs are
 * checked for type (format code, item size), C-contiguity, shape and length; CSR lists are
 * checked as they are read.  The computation runs without the GIL.
 */

#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#if defined(__FAST_MATH__)
#error "simd/core/lidar/_raycast.c must not be compiled with -ffast-math (results must match the numpy kernel)"
#endif
#if defined(__clang__)
#pragma STDC FP_CONTRACT OFF
#endif

/* The per-sensor work is compiled for AVX-512, AVX2 and the baseline, picked at load time
 * (x86-64 with glibc's ifunc; elsewhere one baseline build). */
#if defined(__x86_64__) && defined(__GLIBC__) && defined(__has_attribute)
#if __has_attribute(target_clones)
#define KERNEL_CLONES __attribute__((target_clones("avx512f", "avx2", "default")))
#endif
#endif
#ifndef KERNEL_CLONES
#define KERNEL_CLONES
#endif
#if defined(__GNUC__) || defined(__clang__)
#define RESTRICT __restrict__
#else
#define RESTRICT
#endif
/* no loop-carried dependences: the scratch row never aliases the beam tables */
#if defined(__GNUC__) && !defined(__clang__)
#define IVDEP _Pragma("GCC ivdep")
#else
#define IVDEP
#endif
/* the per-sensor helpers are inlined into each clone, so that each is compiled for its ISA */
#if defined(__GNUC__) || defined(__clang__)
#define HOT static inline __attribute__((always_inline))
#else
#define HOT static inline
#endif

/* Beams are tested in chunks of this many consecutive beams (vectors, once compiled). */
#define CHUNK 8
/* A group whose circle covers at most this many beams is tested on all of them, segment by
 * segment (no per-segment bearings); wider ones (a sensor close by) use each segment's arc. */
#define GROUP_RUN_MAX 24
/* Groups whose bounding radius exceeds this (m) are not binned but tested by every sensor, so
 * that one huge outline does not widen every sensor's grid search. */
#define BIG_GROUP_RADIUS 1.0
/* Groups farther out than this (m) are not binned either (keeps the grid arithmetic finite). */
#define MAX_BIN_COORD 1e12
/* Largest range_max accepted (m): squares of the search reach stay far from overflow. */
#define MAX_RANGE 1e6
/* Smallest dynamic grid cell accepted (m): its inverse stays finite. */
#define MIN_DYN_CELL 1e-6
/* Extra reach (m) of the grid search, against rounding of the cell arithmetic. */
#define GRID_MARGIN 1e-3
/* Bounding-box slack (m) of the static range cull. */
#define STATIC_CULL_SLACK 1e-6
/* Longest group: group_max is checked against it. */
#define GROUP_MAX_LIMIT 128

/* ------------------------------------------------------------------------------------------ */
/* scalar helpers                                                                             */

/* Branch-free selects: the comparisons they replace are data-dependent coin flips, and a
 * mispredicted branch costs more than the arithmetic around it. */
static inline uint64_t
bits_of(double x)
{
    uint64_t u;
    memcpy(&u, &x, sizeof(u));
    return u;
}

static inline double
of_bits(uint64_t u)
{
    double x;
    memcpy(&x, &u, sizeof(x));
    return x;
}

/* all ones when c is true */
static inline uint64_t
mask_of(int c)
{
    return (uint64_t)0 - (uint64_t)(c != 0);
}

/* m ? a : b */
static inline double
select_d(uint64_t m, double a, double b)
{
    return of_bits((bits_of(a) & m) | (bits_of(b) & ~m));
}

static const uint64_t SIGN_BIT = (uint64_t)1 << 63;
static const double PI_ = 3.141592653589793;

/* atan(w)/w ~ P(w^2) on |w| <= tan(pi/8): least-squares fit, max |error| of w*P(w^2) 1.3e-10 */
static const double ATAN_P[6] = {
    0.9999999961630329, -0.33333269851884856, 0.1999698218192675,
    -0.14223614807993545, 0.10477412113591948, -0.058310389754757705,
};

/* atan2(y, x) in [-pi, pi] to within 2e-10 rad (0 for (0, 0)); NaN in, NaN out.  Only used to
 * choose beams, whose arcs are padded far more. */
HOT double
fast_atan2(double y, double x)
{
    double ax = fabs(x), ay = fabs(y);
    double hi = ax > ay ? ax : ay, lo = ax > ay ? ay : ax;
    /* octant angle atan(lo / hi) in [0, pi/4]; above tan(pi/8) as pi/4 + atan((lo-hi)/(lo+hi)) */
    uint64_t big = mask_of(lo > 0.41421356237309503 * hi);
    double num = select_d(big, lo - hi, lo), den = select_d(big, lo + hi, hi);
    double w, s, p, r;
    uint64_t m;
    den = select_d(mask_of(den == 0.0), 1.0, den);
    w = num / den;
    s = w * w;
    p = ATAN_P[5];
    p = p * s + ATAN_P[4];
    p = p * s + ATAN_P[3];
    p = p * s + ATAN_P[2];
    p = p * s + ATAN_P[1];
    p = p * s + ATAN_P[0];
    r = of_bits(big & bits_of(0.25 * PI_)) + w * p;
    m = mask_of(ay > ax); /* pi/2 - r */
    r = of_bits(m & bits_of(0.5 * PI_)) + of_bits(bits_of(r) ^ (m & SIGN_BIT));
    m = mask_of(x < 0.0); /* pi - r */
    r = of_bits(m & bits_of(PI_)) + of_bits(bits_of(r) ^ (m & SIGN_BIT));
    return of_bits(bits_of(r) | (bits_of(y) & SIGN_BIT));
}

/* ------------------------------------------------------------------------------------------ */
/* call context                                                                               */

typedef struct {
    /* static scene (StaticScene) */
    const double *pieces; /* (P, 4) */
    Py_ssize_t npieces;
    const double *circles; /* (C, 3) */
    Py_ssize_t ncircles;
    const int64_t *seg_bounds, *seg_items, *cir_bounds, *cir_items;
    Py_ssize_t nseg_items, ncir_items;
    double gx, gy, gcell;
    Py_ssize_t gnx, gny;
    /* sensors */
    const double *origins, *h0, *cos_h0, *sin_h0;
    const int64_t *owners;
    Py_ssize_t nsens;
    /* moving segments */
    const double *dseg;
    const int64_t *downer;
    Py_ssize_t ndseg;
    /* beams: directions of beams 0 .. n-1, padded by CHUNK (the overrun of chunks) */
    const double *tx, *ty;
    Py_ssize_t n;
    double inv, turn, inv_turn, eps; /* beam units: rad -> beam, one turn, pad */
    int full;                        /* the beams go round the whole circle */
    double rmin, rmax, rmin_cull, rmax_cull, seg_lo, seg_hi, static_cull;
    Py_ssize_t group_max;
    double group_max_radius, dyn_cell;
    /* nearest hit of the current sensor per beam, and CHUNK slots for the overrun of chunks */
    double *ext;
    double *out;       /* float64 output rows, or */
    float *out32;      /* float32 ones, rounded as numpy's astype(float32) */
    int bad_csr; /* set (without the GIL) when a CSR list is inconsistent */
} Ctx;

typedef struct {
    double ox, oy, ch, sh, shift;
    int64_t owner;
} Sensor;

/* A group: a run of consecutive moving segments of one owner (see _DynGrid).  Binning only needs
 * the centre and a bound on the radius; the exact radius and the loop test are worked out the
 * first time a sensor comes near (most groups are near no sensor of the batch). */
typedef struct {
    double cx, cy; /* bounding-box centre, exactly as _group_circles */
    double r;      /* exact radius (0.5 * hypot of the bbox diagonal) once known, else a bound */
    double w, h;   /* bbox size */
    Py_ssize_t start, count;
    int64_t owner;
    int known; /* r exact, closed and flip set */
    int closed, flip;
} Group;

typedef struct {
    Group *groups;      /* all groups */
    Py_ssize_t *order;  /* the binned ones, sorted by cell (row-major along x) */
    Py_ssize_t ngroups; /* binned */
    Py_ssize_t *big;    /* groups too wide or too far out to bin: every sensor tests them */
    Py_ssize_t nbig;
    Py_ssize_t *bounds; /* (nx * ny + 1) */
    double x0, y0, cell, inv, reach;
    Py_ssize_t nx, ny;
} DynIndex;

/* ------------------------------------------------------------------------------------------ */
/* beams                                                                                      */

/* Extended beam run [k0, k1] of the arc [start, end] (beam units from beam 0, start in
 * [0, turn]), as _Frames.runs in lidar.py; a circle covers each beam at most once.  Returns 0
 * when the run is empty (or NaN). */
HOT int
beam_run(const Ctx *c, double start, double end, int circle, Py_ssize_t *k0o, Py_ssize_t *k1o)
{
    double n = (double)c->n;
    double endp = end + c->eps;
    double k0 = ceil(start - c->eps);
    double last;
    if (c->full) {
        last = floor(endp >= c->turn ? endp - (c->turn - n) : endp);
    }
    else {
        if (k0 > n) {
            k0 = n;
        }
        if (endp >= c->turn) {
            last = floor(endp - c->turn) + n;
        }
        else {
            last = floor(endp);
            if (last > n - 1.0) {
                last = n - 1.0;
            }
        }
    }
    if (circle && last - k0 + 1.0 > n) {
        last = k0 + n - 1.0;
    }
    if (!(last >= k0)) {
        return 0;
    }
    if (k0 < 0.0) {
        k0 = 0.0;
    }
    if (last > 2.0 * n - 1.0) {
        last = 2.0 * n - 1.0;
    }
    if (!(last >= k0)) {
        return 0;
    }
    *k0o = (Py_ssize_t)k0;
    *k1o = (Py_ssize_t)last;
    return 1;
}

/* The beams j0 .. j1 (all < n) in whole chunks into the scratch row (whose CHUNK extra slots
 * take the overrun, discarded): exact hits of a segment given in the sensor frame by its start
 * (pax, pay), its direction (pex, pey) and c0 = cross(a, e); the float64 arithmetic of
 * _segment_hits in lidar.py, term for term. */
HOT void
segment_chunks(const Ctx *c, double pax, double pay, double pex, double pey, double c0, Py_ssize_t j0,
               Py_ssize_t j1)
{
    double rmin = c->rmin, rmax = c->rmax, seg_lo = c->seg_lo, seg_hi = c->seg_hi;
    const double *RESTRICT tx = c->tx + j0, *RESTRICT ty = c->ty + j0;
    double *RESTRICT ext = c->ext + j0;
    Py_ssize_t j, len = ((j1 - j0) / CHUNK + 1) * CHUNK;
    IVDEP
    for (j = 0; j < len; j++) {
        double dx = tx[j], dy = ty[j];
        double inv_den = 1.0 / (dx * pey - dy * pex);
        double t = c0 * inv_den;                     /* ray parameter: cross(a, e) / cross(d, e) */
        double sp = (pax * dy - pay * dx) * inv_den; /* segment parameter: cross(a, d) / cross(d, e) */
        int ok = (t >= rmin) & (t <= rmax) & (sp >= seg_lo) & (sp <= seg_hi);
        double v = ok ? t : INFINITY;
        ext[j] = v < ext[j] ? v : ext[j];
    }
}

/* the extended beams k0 .. k1 (< 2n): those past n are beams k - n, one turn on */
HOT void
segment_run(const Ctx *c, double pax, double pay, double pex, double pey, double c0, Py_ssize_t k0, Py_ssize_t k1)
{
    Py_ssize_t n = c->n;
    if (k0 < n) {
        segment_chunks(c, pax, pay, pex, pey, c0, k0, k1 < n ? k1 : n - 1);
    }
    if (k1 >= n) {
        segment_chunks(c, pax, pay, pex, pey, c0, (k0 > n ? k0 : n) - n, k1 - n);
    }
}

/* Exact hits of one segment on the extended beams k0 .. k1, endpoints a, b relative to the
 * sensor (world axes), turned into the sensor frame as in _segment_hits. */
HOT void
segment_beams(const Ctx *c, const Sensor *s, double ax, double ay, double bx, double by, Py_ssize_t k0,
              Py_ssize_t k1)
{
    double ex = bx - ax, ey = by - ay;
    segment_run(c, s->ch * ax + s->sh * ay, s->ch * ay - s->sh * ax, s->ch * ex + s->sh * ey,
                s->ch * ey - s->sh * ex, ax * ey - ay * ex, k0, k1);
}

/* Hits of one segment on the beams of its own arc; ua and ub are the world bearings (beam
 * units) of a and b.  The arc is the shorter one between them, as in _segment_hits. */
HOT void
segment(const Ctx *c, const Sensor *s, double ax, double ay, double bx, double by, double ua, double ub)
{
    double lo = ua < ub ? ua : ub, hi = ua < ub ? ub : ua;
    double span = hi - lo, start;
    Py_ssize_t k0, k1;
    if (span > 0.5 * c->turn) { /* the short way round crosses the -pi/pi cut */
        start = hi;
        span = c->turn - span;
    }
    else {
        start = lo;
    }
    start += s->shift;
    start -= c->turn * floor(start * c->inv_turn);
    if (beam_run(c, start, start + span, 0, &k0, &k1)) {
        segment_beams(c, s, ax, ay, bx, by, k0, k1);
    }
}

/* The beams j0 .. j1 (all < n), in whole chunks, of a circle centred at (pfx, pfy) in the sensor
 * frame, cc = |f|^2 - r^2: the nearer boundary crossing at or beyond range_min, as _circle_hits. */
HOT void
circle_chunks(const Ctx *c, double pfx, double pfy, double cc, Py_ssize_t j0, Py_ssize_t j1)
{
    double rmin = c->rmin, rmax = c->rmax;
    const double *RESTRICT tx = c->tx + j0, *RESTRICT ty = c->ty + j0;
    double *RESTRICT ext = c->ext + j0;
    Py_ssize_t j, len = ((j1 - j0) / CHUNK + 1) * CHUNK;
    IVDEP
    for (j = 0; j < len; j++) {
        double b = tx[j] * pfx + ty[j] * pfy;
        double disc = b * b - cc;
        double root = sqrt(disc > 0.0 ? disc : 0.0);
        double t = b - root >= rmin ? b - root : b + root;
        int ok = (disc >= 0.0) & (t >= rmin) & (t <= rmax);
        double v = ok ? t : INFINITY;
        ext[j] = v < ext[j] ? v : ext[j];
    }
}

/* Hits of one circle of radius r centred at (fx, fy) relative to the sensor, as _circle_hits:
 * cull, then the arc bearing -+ asin(r / dist) (padded; every beam from inside), then per beam
 * the nearer boundary crossing at or beyond range_min. */
HOT void
circle(const Ctx *c, const Sensor *s, double fx, double fy, double r)
{
    double dist = hypot(fx, fy), half, start, pfx, pfy, cc;
    Py_ssize_t k0, k1;
    if (!(fabs(dist - r) <= c->rmax_cull)) {
        return;
    }
    if (dist <= r) {
        half = 0.5 * c->turn;
    }
    else { /* bounded above by tan(asin(r / dist)), and by a quarter turn */
        half = r / sqrt((dist - r) * (dist + r)) * (c->inv * (1.0 + 1e-6));
        if (!(half <= 0.25 * c->turn)) {
            half = 0.25 * c->turn;
        }
    }
    start = fast_atan2(fy, fx) * c->inv + s->shift;
    start -= c->turn * floor(start * c->inv_turn);
    start -= half;
    if (start < 0.0) {
        start += c->turn;
    }
    if (!beam_run(c, start, start + 2.0 * half, 1, &k0, &k1)) {
        return;
    }
    pfx = s->ch * fx + s->sh * fy;
    pfy = s->ch * fy - s->sh * fx;
    cc = dist * dist - r * r;
    if (k0 < c->n) {
        circle_chunks(c, pfx, pfy, cc, k0, k1 < c->n ? k1 : c->n - 1);
    }
    if (k1 >= c->n) {
        circle_chunks(c, pfx, pfy, cc, (k0 > c->n ? k0 : c->n) - c->n, k1 - c->n);
    }
}

/* ------------------------------------------------------------------------------------------ */
/* moving segments: groups and their grid                                                     */

/* numpy's sum of a contiguous float64 run as np.add.reduceat computes it: the first element
 * plus the pairwise sum of the others (n <= GROUP_MAX_LIMIT here) */
HOT double
numpy_reduce_sum(const double *a, Py_ssize_t n)
{
    double res, r[8];
    const double *rest = a + 1;
    Py_ssize_t i, j, m = n - 1;
    if (n <= 0) {
        return 0.0;
    }
    if (m < 8) {
        res = 0.0;
        for (i = 0; i < m; i++) {
            res += rest[i];
        }
    }
    else {
        for (j = 0; j < 8; j++) {
            r[j] = rest[j];
        }
        for (i = 8; i < m - (m % 8); i += 8) {
            for (j = 0; j < 8; j++) {
                r[j] += rest[i + j];
            }
        }
        res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
        for (; i < m; i++) {
            res += rest[i];
        }
    }
    return a[0] + res;
}

/* Bounding box of segments start .. start+count-1 (centre as _group_circles) and an upper bound
 * on its half diagonal.  Min and max are exact, so their order does not matter (a NaN coordinate
 * may be skipped here, but then makes every test of its segment fail: it is never hit). */
HOT void
group_box(const double *seg, Py_ssize_t start, Py_ssize_t count, Group *g)
{
    double lo[4] = {INFINITY, INFINITY, INFINITY, INFINITY}, hi[4] = {-INFINITY, -INFINITY, -INFINITY, -INFINITY};
    double xlo, xhi, ylo, yhi;
    Py_ssize_t i;
    int l;
    for (i = start; i < start + count; i++) {
        const double *q = seg + 4 * i;
        for (l = 0; l < 4; l++) {
            lo[l] = q[l] < lo[l] ? q[l] : lo[l];
            hi[l] = q[l] > hi[l] ? q[l] : hi[l];
        }
    }
    xlo = lo[0] < lo[2] ? lo[0] : lo[2];
    ylo = lo[1] < lo[3] ? lo[1] : lo[3];
    xhi = hi[0] > hi[2] ? hi[0] : hi[2];
    yhi = hi[1] > hi[3] ? hi[1] : hi[3];
    g->cx = 0.5 * (xlo + xhi);
    g->cy = 0.5 * (ylo + yhi);
    g->w = xhi - xlo;
    g->h = yhi - ylo;
    /* 0.5 * (w + h) >= 0.5 * hypot(w, h); the exact value comes in group_finish */
    g->r = 0.5 * (g->w + g->h) * (1.0 + 1e-12);
    g->start = start;
    g->count = count;
    g->known = 0;
}

/* exact radius, as _group_circles */
HOT double
group_radius(const Group *g)
{
    return 0.5 * hypot(g->w, g->h);
}

/* radius > limit, exactly as numpy decides it, computing hypot only when the bounds are close */
HOT int
group_wider_than(const Group *g, double limit)
{
    double lo = 0.5 * (g->w > g->h ? g->w : g->h); /* <= 0.5 * hypot(w, h) */
    if (lo > limit) {
        return 1;
    }
    if (!(g->r > limit)) { /* the upper bound; NaN: not wide, as numpy */
        return 0;
    }
    return group_radius(g) > limit;
}

/* exact radius, closed-loop test and orientation of a group, as _orient_loops */
HOT void
group_finish(const double *seg, Group *g)
{
    Py_ssize_t i, s = g->start, m = g->count;
    double area[GROUP_MAX_LIMIT], total;
    g->known = 1;
    g->r = group_radius(g);
    g->closed = 0;
    g->flip = 0;
    if (m < 3) {
        return;
    }
    for (i = s; i < s + m; i++) {
        const double *q = seg + 4 * i, *nx = seg + 4 * (i + 1 < s + m ? i + 1 : s);
        if (!(q[2] == nx[0] && q[3] == nx[1])) {
            return;
        }
        area[i - s] = q[0] * q[3] - q[2] * q[1];
    }
    total = numpy_reduce_sum(area, m);
    if (total != 0.0) {
        g->closed = 1;
        g->flip = total < 0.0;
    }
}

/* groups with a non-finite box can never pass the range test: they are dropped */
HOT int
group_finite(const Group *g)
{
    return isfinite(g->cx) && isfinite(g->cy) && isfinite(g->r);
}

HOT int
group_binned(const Group *g)
{
    return group_finite(g) && g->r <= BIG_GROUP_RADIUS && fabs(g->cx) <= MAX_BIN_COORD &&
           fabs(g->cy) <= MAX_BIN_COORD;
}

static void
dyn_free(DynIndex *d)
{
    free(d->groups);
    free(d->order);
    free(d->big);
    free(d->bounds);
    memset(d, 0, sizeof(*d));
}

/* Group the moving segments as _DynGrid does and bin the groups on a uniform grid by centre.
 * Returns -1 when out of memory. */
KERNEL_CLONES static int
dyn_build(const Ctx *c, DynIndex *d)
{
    Py_ssize_t m = c->ndseg, ng = 0, i, j, nbin = 0, ncells, cap;
    Group *all, *g;
    double xmin = INFINITY, xmax = -INFINITY, ymin = INFINITY, ymax = -INFINITY, rmax_bin = 0.0;
    Py_ssize_t *cells = NULL;
    memset(d, 0, sizeof(*d));
    if (m == 0) {
        return 0;
    }
    all = d->groups = (Group *)malloc((size_t)m * sizeof(Group));
    if (all == NULL) {
        return -1;
    }
    /* runs of one owner, cut every group_max segments; a group wider than group_max_radius is
     * split into single segments */
    for (i = 0; i < m; i = j) {
        const int64_t own = c->downer[i];
        Py_ssize_t end = i + c->group_max < m ? i + c->group_max : m;
        j = i + 1;
        while (j < end && c->downer[j] == own) {
            j++;
        }
        g = &all[ng];
        group_box(c->dseg, i, j - i, g);
        if (group_wider_than(g, c->group_max_radius)) {
            Py_ssize_t k;
            for (k = i; k < j; k++) {
                group_box(c->dseg, k, 1, &all[ng]);
                all[ng++].owner = own;
            }
        }
        else {
            g->owner = own;
            ng++;
        }
    }
    for (i = 0; i < ng; i++) {
        g = &all[i];
        if (group_binned(g)) {
            nbin++;
            xmin = g->cx < xmin ? g->cx : xmin;
            xmax = g->cx > xmax ? g->cx : xmax;
            ymin = g->cy < ymin ? g->cy : ymin;
            ymax = g->cy > ymax ? g->cy : ymax;
            rmax_bin = g->r > rmax_bin ? g->r : rmax_bin;
        }
        else if (group_finite(g)) {
            d->nbig++;
        }
    }
    if (d->nbig) {
        d->big = (Py_ssize_t *)malloc((size_t)d->nbig * sizeof(Py_ssize_t));
        if (d->big == NULL) {
            goto fail;
        }
        for (i = 0, j = 0; i < ng; i++) {
            if (group_finite(&all[i]) && !group_binned(&all[i])) {
                d->big[j++] = i;
            }
        }
    }
    if (nbin == 0) {
        return 0;
    }
    /* cells of dyn_cell m, doubled while there are too many */
    cap = 16 * nbin;
    cap = cap < 4096 ? 4096 : (cap > (1 << 22) ? (1 << 22) : cap);
    d->cell = c->dyn_cell > 0.0 ? c->dyn_cell : 1.0;
    while (((xmax - xmin) / d->cell + 1.0) * ((ymax - ymin) / d->cell + 1.0) > (double)cap) {
        d->cell *= 2.0;
    }
    d->inv = 1.0 / d->cell;
    d->x0 = xmin;
    d->y0 = ymin;
    d->nx = (Py_ssize_t)((xmax - xmin) * d->inv) + 1;
    d->ny = (Py_ssize_t)((ymax - ymin) * d->inv) + 1;
    d->reach = c->rmax_cull + rmax_bin + GRID_MARGIN;
    ncells = d->nx * d->ny;
    d->bounds = (Py_ssize_t *)calloc((size_t)ncells + 1, sizeof(Py_ssize_t));
    cells = (Py_ssize_t *)malloc((size_t)ng * sizeof(Py_ssize_t));
    d->order = (Py_ssize_t *)malloc((size_t)nbin * sizeof(Py_ssize_t));
    if (d->bounds == NULL || cells == NULL || d->order == NULL) {
        goto fail;
    }
    /* counting sort by cell id */
    for (i = 0; i < ng; i++) {
        double fx, fy;
        Py_ssize_t ix, iy;
        g = &all[i];
        if (!group_binned(g)) {
            cells[i] = -1;
            continue;
        }
        fx = (g->cx - d->x0) * d->inv;
        fy = (g->cy - d->y0) * d->inv;
        ix = fx < 0.0 ? 0 : (fx >= (double)(d->nx - 1) ? d->nx - 1 : (Py_ssize_t)fx);
        iy = fy < 0.0 ? 0 : (fy >= (double)(d->ny - 1) ? d->ny - 1 : (Py_ssize_t)fy);
        cells[i] = iy * d->nx + ix;
        d->bounds[cells[i] + 1]++;
    }
    for (i = 0; i < ncells; i++) {
        d->bounds[i + 1] += d->bounds[i];
    }
    for (i = 0; i < ng; i++) {
        if (cells[i] >= 0) {
            /* bounds[cell] is the insertion cursor, shifted back below */
            d->order[d->bounds[cells[i]]++] = i;
        }
    }
    for (i = ncells; i > 0; i--) {
        d->bounds[i] = d->bounds[i - 1];
    }
    d->bounds[0] = 0;
    d->ngroups = nbin;
    free(cells);
    return 0;
fail:
    free(cells);
    dyn_free(d);
    return -1;
}

/* ------------------------------------------------------------------------------------------ */
/* one sensor                                                                                 */

/* The segments of one group, if it is in range and not the sensor's own robot, as
 * _DynGrid.pairs and _segment_hits. */
HOT void
cast_group(const Ctx *c, const Sensor *s, Group *g)
{
    /* per segment, relative to the sensor: endpoints a, b (world axes), then in the sensor frame
     * a, e = b - a and cross(a, e), as in _segment_hits */
    double ax[GROUP_MAX_LIMIT], ay[GROUP_MAX_LIMIT], bx[GROUP_MAX_LIMIT], by[GROUP_MAX_LIMIT];
    double pax[GROUP_MAX_LIMIT], pay[GROUP_MAX_LIMIT], pex[GROUP_MAX_LIMIT], pey[GROUP_MAX_LIMIT];
    double c0[GROUP_MAX_LIMIT];
    int keep[GROUP_MAX_LIMIT], front[GROUP_MAX_LIMIT], nfront = 0, cull, f;
    double dx, dy, d2, lim, near, ox = s->ox, oy = s->oy, ch = s->ch, sh = s->sh;
    double pa[2] = {NAN, NAN}, pb[2] = {NAN, NAN}, ua_prev = 0.0, ub_prev = 0.0;
    const double *q = c->dseg + 4 * g->start;
    Py_ssize_t i, m = g->count;
    if (g->owner == s->owner) {
        return;
    }
    dx = g->cx - ox;
    dy = g->cy - oy;
    d2 = dx * dx + dy * dy;
    if (!g->known) {
        /* the bound on r is >= r: out of range for it is out of range for r */
        lim = g->r + c->rmax_cull;
        if (!(d2 <= lim * lim)) {
            return;
        }
        group_finish(c->dseg, g);
    }
    lim = g->r + c->rmax_cull;
    if (!(d2 <= lim * lim)) {
        return;
    }
    /* closed clockwise loops are turned counter-clockwise; a ray that starts (at range_min)
     * outside a closed loop first crosses a front face, so back faces are dropped (branch-free:
     * front and back faces come in no predictable order) */
    if (g->flip) {
        for (i = 0; i < m; i++) {
            ax[i] = q[4 * i + 2] - ox;
            ay[i] = q[4 * i + 3] - oy;
            bx[i] = q[4 * i] - ox;
            by[i] = q[4 * i + 1] - oy;
        }
    }
    else {
        for (i = 0; i < m; i++) {
            ax[i] = q[4 * i] - ox;
            ay[i] = q[4 * i + 1] - oy;
            bx[i] = q[4 * i + 2] - ox;
            by[i] = q[4 * i + 3] - oy;
        }
    }
    near = g->r + c->rmin_cull;
    cull = g->closed && d2 > near * near;
    for (i = 0; i < m; i++) {
        keep[i] = (!cull) | (ax[i] * by[i] - ay[i] * bx[i] < 0.0);
    }
    for (i = 0; i < m; i++) {
        front[nfront] = (int)i;
        nfront += keep[i];
    }
    /* With the sensor outside the group's circle, the beams that the circle covers (padded; the
     * half angle bounded above by r / sqrt(d^2 - r^2) = tan(asin(r / d))) include those of each
     * segment's own arc: when they are few, test them all on every segment rather than work out
     * two bearings per segment. */
    if (d2 > g->r * g->r) {
        double half, mid, start;
        Py_ssize_t k0, k1;
        /* d^2 - r^2 loses relative accuracy only when r ~ d, where the half angle is far too
         * wide for this path anyway; 1e-6 covers the rest */
        half = g->r / sqrt(d2 - g->r * g->r) * (c->inv * (1.0 + 1e-6));
        if (!(half <= 0.25 * c->turn)) {
            half = 0.25 * c->turn;
        }
        mid = fast_atan2(dy, dx) * c->inv + s->shift;
        mid -= c->turn * floor(mid * c->inv_turn);
        start = mid - half;
        if (start < 0.0) {
            start += c->turn;
        }
        if (!beam_run(c, start, start + 2.0 * half, 1, &k0, &k1)) {
            return;
        }
        if (k1 - k0 < GROUP_RUN_MAX) {
            for (i = 0; i < m; i++) {
                double ex = bx[i] - ax[i], ey = by[i] - ay[i];
                pax[i] = ch * ax[i] + sh * ay[i];
                pay[i] = ch * ay[i] - sh * ax[i];
                pex[i] = ch * ex + sh * ey;
                pey[i] = ch * ey - sh * ex;
                c0[i] = ax[i] * ey - ay[i] * ex; /* rotation invariant */
            }
            for (f = 0; f < nfront; f++) {
                i = front[f];
                segment_run(c, pax[i], pay[i], pex[i], pey[i], c0[i], k0, k1);
            }
            return;
        }
    }
    for (f = 0; f < nfront; f++) {
        double x0, y0, x1, y1, ua, ub;
        i = front[f];
        x0 = ax[i];
        y0 = ay[i];
        x1 = bx[i];
        y1 = by[i];
        /* consecutive edges of an outline share a vertex: reuse its bearing */
        if (x0 == pb[0] && y0 == pb[1]) {
            ua = ub_prev;
        }
        else if (x0 == pa[0] && y0 == pa[1]) {
            ua = ua_prev;
        }
        else {
            ua = fast_atan2(y0, x0) * c->inv;
        }
        if (x1 == pa[0] && y1 == pa[1]) {
            ub = ua_prev;
        }
        else if (x1 == pb[0] && y1 == pb[1]) {
            ub = ub_prev;
        }
        else {
            ub = fast_atan2(y1, x1) * c->inv;
        }
        pa[0] = x0;
        pa[1] = y0;
        pb[0] = x1;
        pb[1] = y1;
        ua_prev = ua;
        ub_prev = ub;
        segment(c, s, x0, y0, x1, y1, ua, ub);
    }
}

/* a CSR run [lo, hi) of a cell, or 0 (and the error flag) if inconsistent */
HOT int
csr_run(Ctx *c, const int64_t *bounds, Py_ssize_t cell, Py_ssize_t nitems, Py_ssize_t *lo, Py_ssize_t *hi)
{
    int64_t b0 = bounds[cell], b1 = bounds[cell + 1];
    if (b0 < 0 || b1 < b0 || b1 > (int64_t)nitems) {
        c->bad_csr = 1;
        return 0;
    }
    *lo = (Py_ssize_t)b0;
    *hi = (Py_ssize_t)b1;
    return 1;
}

/* the static pieces and circles listed for the sensor's static grid cell */
HOT void
cast_static(Ctx *c, const Sensor *s)
{
    double fx = floor((s->ox - c->gx) / c->gcell), fy = floor((s->oy - c->gy) / c->gcell);
    double pbx = NAN, pby = NAN, ub_prev = 0.0;
    Py_ssize_t cell, k, lo, hi;
    if (!(fx >= 0.0 && fx < (double)c->gnx && fy >= 0.0 && fy < (double)c->gny)) {
        return;
    }
    cell = (Py_ssize_t)fx * c->gny + (Py_ssize_t)fy;
    if (csr_run(c, c->seg_bounds, cell, c->nseg_items, &lo, &hi)) {
        for (k = lo; k < hi; k++) {
            int64_t p = c->seg_items[k];
            const double *q;
            double ax, ay, bx, by, qx, qy, lim, ua, ub;
            if (p < 0 || p >= (int64_t)c->npieces) {
                c->bad_csr = 1;
                break;
            }
            q = c->pieces + 4 * p;
            ax = q[0] - s->ox;
            ay = q[1] - s->oy;
            bx = q[2] - s->ox;
            by = q[3] - s->oy;
            /* range cull on the bounding-box distance (slack for EPS_SEG and rounding) */
            qx = ax > 0.0 && bx > 0.0 ? (ax < bx ? ax : bx) : (ax < 0.0 && bx < 0.0 ? -(ax > bx ? ax : bx) : 0.0);
            qy = ay > 0.0 && by > 0.0 ? (ay < by ? ay : by) : (ay < 0.0 && by < 0.0 ? -(ay > by ? ay : by) : 0.0);
            lim = c->static_cull + 2e-9 * (fabs(bx - ax) + fabs(by - ay));
            if (qx * qx + qy * qy > lim * lim) {
                continue;
            }
            /* pieces of one wall and edges of one polygon follow each other: reuse a shared
             * vertex's bearing */
            ua = (q[0] == pbx && q[1] == pby) ? ub_prev : fast_atan2(ay, ax) * c->inv;
            ub = fast_atan2(by, bx) * c->inv;
            pbx = q[2];
            pby = q[3];
            ub_prev = ub;
            segment(c, s, ax, ay, bx, by, ua, ub);
        }
    }
    if (csr_run(c, c->cir_bounds, cell, c->ncir_items, &lo, &hi)) {
        for (k = lo; k < hi; k++) {
            int64_t p = c->cir_items[k];
            const double *q;
            if (p < 0 || p >= (int64_t)c->ncircles) {
                c->bad_csr = 1;
                break;
            }
            q = c->circles + 3 * p;
            circle(c, s, q[0] - s->ox, q[1] - s->oy, q[2]);
        }
    }
}

/* the groups of the moving-segment grid rows within reach, each row one run of cells */
HOT void
cast_dynamic(const Ctx *c, DynIndex *d, const Sensor *s)
{
    double reach = d->reach, r0, r1;
    Py_ssize_t k, row_i, row_lo, row_hi;
    for (k = 0; k < d->nbig; k++) {
        cast_group(c, s, &d->groups[d->big[k]]);
    }
    if (!(d->ngroups && isfinite(s->ox) && isfinite(s->oy))) {
        return;
    }
    r0 = floor((s->oy - reach - d->y0) * d->inv);
    r1 = floor((s->oy + reach - d->y0) * d->inv);
    if (!(r0 <= r1) || r1 < 0.0 || r0 > (double)(d->ny - 1)) { /* !(r0 <= r1): NaN never indexes */
        return;
    }
    row_lo = r0 < 0.0 ? 0 : (Py_ssize_t)r0;
    row_hi = r1 > (double)(d->ny - 1) ? d->ny - 1 : (Py_ssize_t)r1;
    for (row_i = row_lo; row_i <= row_hi; row_i++) {
        double ylo = d->y0 + (double)row_i * d->cell;
        double gap = ylo - s->oy, half, c0, c1;
        Py_ssize_t col_lo, col_hi, g, g1;
        if (s->oy - (ylo + d->cell) > gap) {
            gap = s->oy - (ylo + d->cell);
        }
        if (gap < 0.0) {
            gap = 0.0;
        }
        if (gap > reach) {
            continue;
        }
        half = sqrt(reach * reach - gap * gap);
        c0 = floor((s->ox - half - d->x0) * d->inv);
        c1 = floor((s->ox + half - d->x0) * d->inv);
        if (!(c0 <= c1) || c1 < 0.0 || c0 > (double)(d->nx - 1)) {
            continue;
        }
        col_lo = c0 < 0.0 ? 0 : (Py_ssize_t)c0;
        col_hi = c1 > (double)(d->nx - 1) ? d->nx - 1 : (Py_ssize_t)c1;
        g1 = d->bounds[row_i * d->nx + col_hi + 1];
        for (g = d->bounds[row_i * d->nx + col_lo]; g < g1; g++) {
            cast_group(c, s, &d->groups[d->order[g]]);
        }
    }
}

/* every beam of sensor i, into row i of out */
KERNEL_CLONES static void
cast_sensor(Ctx *c, DynIndex *d, Py_ssize_t i)
{
    double *ext = c->ext, h0u;
    Py_ssize_t j, n = c->n;
    Sensor s;
    for (j = 0; j < n + CHUNK; j++) {
        ext[j] = INFINITY;
    }
    s.ox = c->origins[2 * i];
    s.oy = c->origins[2 * i + 1];
    s.ch = c->cos_h0[i];
    s.sh = c->sin_h0[i];
    s.owner = c->owners[i];
    /* as _Frames: bearing b (rad) -> beam units from beam 0 is b * inv + shift, modulo a turn */
    h0u = c->h0[i] * c->inv;
    h0u -= c->turn * floor(h0u / c->turn);
    s.shift = c->turn - h0u;
    cast_static(c, &s);
    cast_dynamic(c, d, &s);
    if (c->out32 != NULL) {
        float *row32 = c->out32 + i * n;
        for (j = 0; j < n; j++) {
            row32[j] = (float)ext[j];
        }
    }
    else {
        memcpy(c->out + i * n, ext, (size_t)n * sizeof(double));
    }
}

/* ------------------------------------------------------------------------------------------ */
/* argument checking                                                                          */

enum { KIND_F64, KIND_I64, KIND_F64_F32 };

/* Get a C-contiguous buffer of float64 or int64 items.  width > 0: shape (rows, width) or
 * flat with a multiple of width items; width == 0: one-dimensional.  *rows gets the row count
 * (the item count when width == 0). */
static int
get_buffer(PyObject *obj, const char *name, int kind, Py_ssize_t width, int writable, Py_buffer *view,
           Py_ssize_t *rows)
{
    const char *fmt;
    Py_ssize_t items;
    int ok;
    if (!PyObject_CheckBuffer(obj)) {
        PyErr_Format(PyExc_TypeError, "%s: expected a buffer (a numpy array), got %.100s", name,
                     Py_TYPE(obj)->tp_name);
        return -1;
    }
    if (PyObject_GetBuffer(obj, view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0)) < 0) {
        if (PyErr_ExceptionMatches(PyExc_BufferError) || PyErr_ExceptionMatches(PyExc_ValueError)) {
            PyErr_Clear();
            PyErr_Format(PyExc_ValueError, "%s: need a C-contiguous%s buffer", name, writable ? ", writable" : "");
        }
        return -1;
    }
    fmt = view->format != NULL ? view->format : "B";
#if PY_LITTLE_ENDIAN
    if (fmt[0] == '@' || fmt[0] == '=' || fmt[0] == '<') {
        fmt++;
    }
#else
    if (fmt[0] == '@' || fmt[0] == '=' || fmt[0] == '>' || fmt[0] == '!') {
        fmt++;
    }
#endif
    if (kind == KIND_F64) {
        ok = view->itemsize == 8 && fmt[0] == 'd' && fmt[1] == '\0';
    }
    else if (kind == KIND_F64_F32) {
        ok = ((view->itemsize == 8 && fmt[0] == 'd') || (view->itemsize == 4 && fmt[0] == 'f')) && fmt[1] == '\0';
    }
    else {
        ok = view->itemsize == 8 && (fmt[0] == 'q' || fmt[0] == 'l') && fmt[1] == '\0';
    }
    if (!ok) {
        PyErr_Format(PyExc_TypeError, "%s: need %s items, got format '%s' of %zd bytes", name,
                     kind == KIND_F64 ? "float64" : (kind == KIND_I64 ? "int64" : "float64 or float32"),
                     view->format != NULL ? view->format : "B", view->itemsize);
        goto fail;
    }
    items = view->len / view->itemsize;
    if (width == 0) {
        if (view->ndim > 1) {
            PyErr_Format(PyExc_ValueError, "%s: need a one-dimensional buffer, got %d dimensions", name, view->ndim);
            goto fail;
        }
        *rows = items;
        return 0;
    }
    if (view->ndim > 2 || (view->ndim == 2 && view->shape[1] != width) || items % width != 0) {
        PyErr_Format(PyExc_ValueError, "%s: need shape (rows, %zd)", name, width);
        goto fail;
    }
    *rows = items / width;
    return 0;
fail:
    PyBuffer_Release(view);
    return -1;
}

static int
expect_rows(const char *name, Py_ssize_t got, Py_ssize_t want)
{
    if (got != want) {
        PyErr_Format(PyExc_ValueError, "%s: need %zd rows, got %zd", name, want, got);
        return -1;
    }
    return 0;
}

/* ------------------------------------------------------------------------------------------ */
/* module                                                                                     */

enum {
    B_PIECES,
    B_CIRCLES,
    B_SEG_BOUNDS,
    B_SEG_ITEMS,
    B_CIR_BOUNDS,
    B_CIR_ITEMS,
    B_ORIGINS,
    B_H0,
    B_COS,
    B_SIN,
    B_OWNERS,
    B_DSEG,
    B_DOWNER,
    B_TABLE,
    B_OUT,
    NBUF
};

PyDoc_STRVAR(cast_doc,
             "cast(pieces, circles, seg_bounds, seg_items, cir_bounds, cir_items, grid_x0, grid_y0, grid_cell,\n"
             "     grid_nx, grid_ny, origins, h0, cos_h0, sin_h0, owners, dyn_segments, dyn_owner, table,\n"
             "     samples, angle_increment, range_min, range_max, eps_angle, eps_seg, eps_cull, group_max,\n"
             "     group_max_radius, dyn_cell, out) -> None\n"
             "\n"
             "Cast every beam of every sensor into out, a C-contiguous (N, samples) float64 buffer, or\n"
             "float32 (rounded as numpy's astype), +inf where nothing is hit.  The other buffers are\n"
             "C-contiguous float64 (pieces (P, 4), circles (C, 3), origins (N, 2), h0 / cos_h0 / sin_h0 (N,)\n"
             "beam-0 bearings and their cos/sin, dyn_segments (M, 4), table (2, 2 * samples) beam\n"
             "directions) or int64 (the CSR bounds (grid_nx * grid_ny + 1,) and items, owners (N,),\n"
             "dyn_owner (M,)).  See simd/core/lidar/, whose StaticScene builds the static arrays and whose\n"
             "constants give the tolerances.  The GIL is released while casting.");

static PyObject *
raycast_cast(PyObject *Py_UNUSED(module), PyObject *args, PyObject *kwargs)
{
    static char *kwlist[] = {"pieces",      "circles",   "seg_bounds", "seg_items",       "cir_bounds",
                             "cir_items",   "grid_x0",   "grid_y0",    "grid_cell",       "grid_nx",
                             "grid_ny",     "origins",   "h0",         "cos_h0",          "sin_h0",
                             "owners",      "dyn_segments", "dyn_owner", "table",          "samples",
                             "angle_increment", "range_min", "range_max", "eps_angle",    "eps_seg",
                             "eps_cull",    "group_max", "group_max_radius", "dyn_cell",  "out",
                             NULL};
    PyObject *obj[NBUF];
    Py_buffer view[NBUF];
    int held[NBUF] = {0};
    Ctx c;
    DynIndex dyn;
    Py_ssize_t rows, nb, i, samples, gnx, gny, group_max;
    double gx, gy, gcell, angle_increment, range_min, range_max, eps_angle, eps_seg, eps_cull, gmr, dyn_cell;
    PyObject *result = NULL;
    double *work = NULL;
    int failed = 0;

    memset(&c, 0, sizeof(c));
    if (!PyArg_ParseTupleAndKeywords(
            args, kwargs, "OOOOOOdddnnOOOOOOOOnddddddnddO:cast", kwlist, &obj[B_PIECES], &obj[B_CIRCLES],
            &obj[B_SEG_BOUNDS], &obj[B_SEG_ITEMS], &obj[B_CIR_BOUNDS], &obj[B_CIR_ITEMS], &gx, &gy, &gcell, &gnx,
            &gny, &obj[B_ORIGINS], &obj[B_H0], &obj[B_COS], &obj[B_SIN], &obj[B_OWNERS], &obj[B_DSEG],
            &obj[B_DOWNER], &obj[B_TABLE], &samples, &angle_increment, &range_min, &range_max, &eps_angle,
            &eps_seg, &eps_cull, &group_max, &gmr, &dyn_cell, &obj[B_OUT])) {
        return NULL;
    }
    if (samples < 1 || samples > (1 << 24)) {
        PyErr_SetString(PyExc_ValueError, "samples must lie in [1, 2**24]");
        return NULL;
    }
    if (!(angle_increment > 0.0) || !isfinite(angle_increment) || !(eps_angle >= 0.0) || !isfinite(eps_angle)) {
        PyErr_SetString(PyExc_ValueError, "angle_increment must be finite and > 0, eps_angle finite and >= 0");
        return NULL;
    }
    if (group_max < 1 || group_max > GROUP_MAX_LIMIT) {
        PyErr_Format(PyExc_ValueError, "group_max must lie in [1, %d]", GROUP_MAX_LIMIT);
        return NULL;
    }
    if (gnx < 1 || gny < 1 || gnx > PY_SSIZE_T_MAX / gny - 1 || !(gcell > 0.0)) {
        PyErr_SetString(PyExc_ValueError, "grid_nx, grid_ny must be >= 1 and grid_cell > 0");
        return NULL;
    }
    /* Finite, ordered numbers only: a NaN or an infinity here would reach the float-to-index
     * conversions of the grids (undefined behaviour in C), and range_max is bounded so that
     * squares of the search reach stay finite. */
    if (!(range_min >= 0.0 && range_min < range_max && range_max <= MAX_RANGE) || !isfinite(gx) || !isfinite(gy)
        || !isfinite(gcell) || !(eps_seg >= 0.0 && isfinite(eps_seg)) || !(eps_cull >= 0.0 && isfinite(eps_cull))
        || !(gmr >= 0.0 && isfinite(gmr)) || !(dyn_cell >= MIN_DYN_CELL && isfinite(dyn_cell))) {
        PyErr_SetString(PyExc_ValueError,
                        "need 0 <= range_min < range_max <= 1e6, finite grid origin and cell, finite eps_seg, "
                        "eps_cull and group_max_radius >= 0, and dyn_cell >= 1e-6");
        return NULL;
    }

#define GET(idx, name, kind, width, writable)                                                         \
    do {                                                                                              \
        if (get_buffer(obj[idx], name, kind, width, writable, &view[idx], &rows) < 0) {               \
            goto done;                                                                                \
        }                                                                                             \
        held[idx] = 1;                                                                                \
    } while (0)

    GET(B_PIECES, "pieces", KIND_F64, 4, 0);
    c.pieces = (const double *)view[B_PIECES].buf;
    c.npieces = rows;
    GET(B_CIRCLES, "circles", KIND_F64, 3, 0);
    c.circles = (const double *)view[B_CIRCLES].buf;
    c.ncircles = rows;
    GET(B_SEG_BOUNDS, "seg_bounds", KIND_I64, 0, 0);
    if (expect_rows("seg_bounds", rows, gnx * gny + 1) < 0) {
        goto done;
    }
    c.seg_bounds = (const int64_t *)view[B_SEG_BOUNDS].buf;
    GET(B_SEG_ITEMS, "seg_items", KIND_I64, 0, 0);
    c.seg_items = (const int64_t *)view[B_SEG_ITEMS].buf;
    c.nseg_items = rows;
    GET(B_CIR_BOUNDS, "cir_bounds", KIND_I64, 0, 0);
    if (expect_rows("cir_bounds", rows, gnx * gny + 1) < 0) {
        goto done;
    }
    c.cir_bounds = (const int64_t *)view[B_CIR_BOUNDS].buf;
    GET(B_CIR_ITEMS, "cir_items", KIND_I64, 0, 0);
    c.cir_items = (const int64_t *)view[B_CIR_ITEMS].buf;
    c.ncir_items = rows;

    GET(B_ORIGINS, "origins", KIND_F64, 2, 0);
    c.origins = (const double *)view[B_ORIGINS].buf;
    c.nsens = rows;
    GET(B_H0, "h0", KIND_F64, 0, 0);
    if (expect_rows("h0", rows, c.nsens) < 0) {
        goto done;
    }
    c.h0 = (const double *)view[B_H0].buf;
    GET(B_COS, "cos_h0", KIND_F64, 0, 0);
    if (expect_rows("cos_h0", rows, c.nsens) < 0) {
        goto done;
    }
    c.cos_h0 = (const double *)view[B_COS].buf;
    GET(B_SIN, "sin_h0", KIND_F64, 0, 0);
    if (expect_rows("sin_h0", rows, c.nsens) < 0) {
        goto done;
    }
    c.sin_h0 = (const double *)view[B_SIN].buf;
    GET(B_OWNERS, "owners", KIND_I64, 0, 0);
    if (expect_rows("owners", rows, c.nsens) < 0) {
        goto done;
    }
    c.owners = (const int64_t *)view[B_OWNERS].buf;

    GET(B_DSEG, "dyn_segments", KIND_F64, 4, 0);
    c.dseg = (const double *)view[B_DSEG].buf;
    c.ndseg = rows;
    GET(B_DOWNER, "dyn_owner", KIND_I64, 0, 0);
    if (expect_rows("dyn_owner", rows, c.ndseg) < 0) {
        goto done;
    }
    c.downer = (const int64_t *)view[B_DOWNER].buf;

    GET(B_TABLE, "table", KIND_F64, 2 * samples, 0);
    if (expect_rows("table", rows, 2) < 0) {
        goto done;
    }

    GET(B_OUT, "out", KIND_F64_F32, samples, 1);
    if (expect_rows("out", rows, c.nsens) < 0) {
        goto done;
    }
    if (view[B_OUT].itemsize == 4) {
        c.out32 = (float *)view[B_OUT].buf;
    }
    else {
        c.out = (double *)view[B_OUT].buf;
    }
#undef GET

    c.gx = gx;
    c.gy = gy;
    c.gcell = gcell;
    c.gnx = gnx;
    c.gny = gny;
    c.n = samples;
    c.inv = 1.0 / angle_increment;
    c.turn = 2.0 * PI_ * c.inv;
    c.inv_turn = 1.0 / c.turn;
    c.eps = eps_angle * c.inv;
    c.full = c.turn < (double)samples;
    c.rmin = range_min;
    c.rmax = range_max;
    c.rmin_cull = range_min + eps_cull;
    c.rmax_cull = range_max + eps_cull;
    c.seg_lo = -eps_seg;
    c.seg_hi = 1.0 + eps_seg;
    c.static_cull = range_max + STATIC_CULL_SLACK;
    c.group_max = group_max;
    c.group_max_radius = gmr;
    c.dyn_cell = dyn_cell;

    nb = c.nsens;
    Py_BEGIN_ALLOW_THREADS;
    /* beam directions over the extended indices, padded for whole chunks; scratch row */
    work = (double *)malloc((size_t)(3 * (samples + CHUNK)) * sizeof(double));
    if (work == NULL || dyn_build(&c, &dyn) < 0) {
        failed = 1;
    }
    else {
        const double *table = (const double *)view[B_TABLE].buf;
        double *tx = work, *ty = work + (samples + CHUNK);
        for (i = 0; i < samples + CHUNK; i++) {
            tx[i] = table[i % samples];
            ty[i] = table[2 * samples + i % samples];
        }
        c.tx = tx;
        c.ty = ty;
        c.ext = work + 2 * (samples + CHUNK);
        for (i = 0; i < nb; i++) {
            cast_sensor(&c, &dyn, i);
        }
        dyn_free(&dyn);
    }
    free(work);
    Py_END_ALLOW_THREADS;
    if (failed) {
        PyErr_NoMemory();
        goto done;
    }
    if (c.bad_csr) {
        PyErr_SetString(PyExc_ValueError, "inconsistent static grid: CSR bounds or items out of range");
        goto done;
    }
    result = Py_None;
    Py_INCREF(result);
done:
    for (i = 0; i < NBUF; i++) {
        if (held[i]) {
            PyBuffer_Release(&view[i]);
        }
    }
    return result;
}

PyDoc_STRVAR(outline_segments_doc,
             "outline_segments(x, y, cos_yaw, sin_yaw, outline, corners, out) -> None\n"
             "\n"
             "Every robot's outline in the world frame, as segments: robot i at (x[i], y[i]) heading\n"
             "(cos_yaw[i], sin_yaw[i]) has the corners outline[i * corners + j] (robot frame, (N * corners, 2)\n"
             "float64), and out[i * corners + j] (float64, (N * corners, 4)) becomes the segment from its\n"
             "corner j to corner j + 1 (the last closes the loop), each point computed as numpy computes\n"
             "x + ox * c - oy * s and y + ox * s + oy * c (the twin in simd/core/lidar/__init__.py).\n"
             "The GIL is released while it runs.");

static PyObject *
raycast_outline_segments(PyObject *Py_UNUSED(module), PyObject *args)
{
    PyObject *obj[7];
    Py_buffer view[7];
    int held[7] = {0};
    static const char *names[7] = {"x", "y", "cos_yaw", "sin_yaw", "outline", "corners", "out"};
    static const Py_ssize_t widths[7] = {0, 0, 0, 0, 2, 0, 4};
    Py_ssize_t rows[7], corners, n, i, j;
    PyObject *result = NULL;

    if (!PyArg_ParseTuple(args, "OOOOOnO:outline_segments", &obj[0], &obj[1], &obj[2], &obj[3], &obj[4], &corners,
                          &obj[6])) {
        return NULL;
    }
    if (corners < 1) {
        PyErr_SetString(PyExc_ValueError, "corners must be >= 1");
        return NULL;
    }
    for (i = 0; i < 7; i++) {
        if (i == 5) {
            continue;
        }
        if (get_buffer(obj[i], names[i], KIND_F64, widths[i], i == 6, &view[i], &rows[i]) < 0) {
            goto done;
        }
        held[i] = 1;
    }
    n = rows[0];
    if (n > PY_SSIZE_T_MAX / 4 / corners) {
        PyErr_SetString(PyExc_ValueError, "too many robots or corners");
        goto done;
    }
    if (expect_rows("y", rows[1], n) < 0 || expect_rows("cos_yaw", rows[2], n) < 0
        || expect_rows("sin_yaw", rows[3], n) < 0 || expect_rows("outline", rows[4], n * corners) < 0
        || expect_rows("out", rows[6], n * corners) < 0) {
        goto done;
    }
    {
        const double *x = (const double *)view[0].buf, *y = (const double *)view[1].buf;
        const double *cs = (const double *)view[2].buf, *sn = (const double *)view[3].buf;
        const double *ol = (const double *)view[4].buf;
        double *out = (double *)view[6].buf;
        Py_BEGIN_ALLOW_THREADS
        for (i = 0; i < n; i++) {
            const double c = cs[i], s = sn[i];
            const double *o = ol + 2 * i * corners;
            double *seg = out + 4 * i * corners;
            for (j = 0; j < corners; j++) {
                /* the same operations, in the same order, as the numpy twin: no contraction */
                seg[4 * j] = x[i] + o[2 * j] * c - o[2 * j + 1] * s;
                seg[4 * j + 1] = y[i] + o[2 * j] * s + o[2 * j + 1] * c;
            }
            for (j = 0; j < corners; j++) {
                const Py_ssize_t k = (j + 1) % corners;
                seg[4 * j + 2] = seg[4 * k];
                seg[4 * j + 3] = seg[4 * k + 1];
            }
        }
        Py_END_ALLOW_THREADS
    }
    Py_INCREF(Py_None);
    result = Py_None;
done:
    for (i = 0; i < 7; i++) {
        if (held[i]) {
            PyBuffer_Release(&view[i]);
        }
    }
    return result;
}

static PyMethodDef raycast_methods[] = {
    {"cast", (PyCFunction)(void (*)(void))raycast_cast, METH_VARARGS | METH_KEYWORDS, cast_doc},
    {"outline_segments", raycast_outline_segments, METH_VARARGS, outline_segments_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef raycast_module = {
    PyModuleDef_HEAD_INIT,
    "simd.core.lidar._raycast",
    "Compiled lidar ray casting for simd.core.lidar (see simd/core/lidar/_raycast.c and simd/core/lidar/).",
    -1,
    raycast_methods,
    NULL,
    NULL,
    NULL,
    NULL,
};

PyMODINIT_FUNC
PyInit__raycast(void)
{
    return PyModule_Create(&raycast_module);
}
