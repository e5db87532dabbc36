/*
 * simd._scannoise: the lidar sensor model of simd/core/sensor_model.py (its numpy reference), compiled.
 *
 * Why: the numpy version masks the raw ranges, draws one float32 standard normal per beam that
 * hit something (numpy's Generator.standard_normal, ~19 ns a value here), scales, adds and
 * clamps, with a temporary for every step: ~0.6 ms a tick for 100 scans of 360 beams.  This
 * module does the same work in one pass over the beams (four at a time with SSE2), with its own
 * generator and normal sampler: ~0.08 ms for the same batch (~7x, quiet machine).
 *
 * apply(raw, out, range_min, range_max, stddev, seed) -> None
 *   raw        C-contiguous float32 buffer, any shape, read as n items in row-major order
 *   out        writable C-contiguous float32 buffer of n items; may be raw itself (in place), and
 *              any other overlap with raw is handled as if raw had been copied first
 *   range_min, range_max, stddev
 *              Python floats, rounded to float32 as np.float32(x) does; NaN ranges, range_min >
 *              range_max, and a NaN, infinite or negative stddev (or one that overflows float32)
 *              raise ValueError
 *   seed       int in [0, 2**64); anything else raises TypeError or OverflowError
 * For every item, as Gazebo's RaySensor: a raw range that is not < range_max (>= range_max, or
 * NaN) becomes +inf.  Every other item (a "hit") gets, when stddev != 0, noise added in float32,
 * v + float32(z) * float32(stddev) with z ~ N(0, 1), and is then clamped to [range_min, range_max]
 * (NaN propagates, as in np.clip).  With stddev == 0 hits are copied unchanged and NOT clamped,
 * exactly the numpy reference with noise off.
 *
 * The noise stream is a pure function of the seed and of the order of the hits: the k-th hit in
 * row-major order always gets the k-th normal of the stream.  The same seed and raw give the same
 * bytes.  The stream is not numpy's (nothing here reproduces numpy's generator).  The
 * output does not depend on the shape of raw, on SSE2 being used, or on out being raw.
 *
 * Everything below is our own implementation, written for this project from the published
 * algorithms:
 *   - xoshiro256++ (Blackman and Vigna, 2018) as the uniform generator, its 256-bit state seeded
 *     from the 64-bit seed with splitmix64, as its authors recommend;
 *   - the ziggurat method of Marsaglia and Tsang ("The Ziggurat Method for Generating Random
 *     Variables", J. Stat. Software 5(8), 2000) for the standard normal, with 256 layers, the
 *     arithmetic in double, Marsaglia's exact sampler for the tail beyond the last layer, and
 *     two candidates per 64-bit output (23 bits of magnitude each, as many as float32 keeps; see
 *     "Sampling" below).  The layer table is computed once when the module is imported
 *     (bisection on the base-layer edge r so that the 256 equal-area layers close exactly at the
 *     top of the density), not copied from anywhere.  Each normal is rounded to float32.
 *
 * No fast-math: the masks rely on NaN comparing false, the clamps on NaN propagating, and the
 * noise on float32 rounding of each operation (the source refuses -ffast-math).  The product
 * and the sum are rounded separately: plain x86-64 has no FMA; a build with -mfma (or for another
 * architecture) should add -ffp-contract=off, or the scalar and SSE2 loops may differ.  The GIL is
 * released around the loop; the module has no mutable global state after import.
 */

#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <math.h>
#include <stdint.h>
#include <string.h>

#if defined(__FAST_MATH__)
#error "simd/core/_scannoise.c must not be compiled with -ffast-math"
#endif

/* The noisy pass does four items at a time with SSE2 (every x86-64 has it); elsewhere, or with
 * -DSCANNOISE_NO_SIMD (to check that both give the same bytes), only the scalar loop. */
#if defined(__SSE2__) && !defined(SCANNOISE_NO_SIMD)
#define SCANNOISE_SSE2 1
#include <emmintrin.h>
#else
#define SCANNOISE_SSE2 0
#endif

/* ---------------------------------------------------------------- uniform generator */

typedef struct {
    uint64_t s[4];
} Rng;

static inline uint64_t rotl64(uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }

/* splitmix64: the state's four words are four consecutive outputs.  Its output function is a
 * bijection of the counter, so at most one of them can be zero and the state is never all zero. */
static void rng_seed(Rng *r, uint64_t seed) {
    uint64_t x = seed;
    for (int k = 0; k < 4; k++) {
        x += UINT64_C(0x9e3779b97f4a7c15);
        uint64_t z = x;
        z = (z ^ (z >> 30)) * UINT64_C(0xbf58476d1ce4e5b9);
        z = (z ^ (z >> 27)) * UINT64_C(0x94d049bb133111eb);
        r->s[k] = z ^ (z >> 31);
    }
}

/* xoshiro256++ */
static inline uint64_t rng_next(Rng *r) {
    uint64_t *s = r->s;
    uint64_t out = rotl64(s[0] + s[3], 23) + s[0];
    uint64_t t = s[1] << 17;
    s[2] ^= s[0];
    s[3] ^= s[1];
    s[1] ^= s[2];
    s[0] ^= s[3];
    s[2] ^= t;
    s[3] = rotl64(s[3], 45);
    return out;
}

#define TWO_M53 (1.0 / 9007199254740992.0) /* 2**-53 */

/* uniform on [0, 1) and on (0, 1], 53 bits */
static inline double uniform_co(Rng *r) { return (double)(rng_next(r) >> 11) * TWO_M53; }
static inline double uniform_oc(Rng *r) { return (double)((rng_next(r) >> 11) + 1) * TWO_M53; }

/* ---------------------------------------------------------------- ziggurat tables */

/*
 * The ziggurat covers the half-normal density, unnormalised, f(x) = exp(-x*x/2) on x >= 0, with
 * N layers of equal area v.  Edges x[1] = r > x[2] > ... > x[N-1] > x[N] = 0 satisfy
 * x[i] * (f(x[i+1]) - f(x[i])) = v: layer i (1 <= i < N) is the box [0, x[i]] x [f(x[i]), f(x[i+1])].
 * Layer 0 is the box [0, r] x [0, f(r)] plus the tail x > r, of total area
 * v = r f(r) + integral_r^inf f; it is sampled as a box of width x[0] = v / f(r), whose part
 * beyond r stands for the tail.
 *
 * Sampling: a 32-bit word gives the layer i (its low 8 bits) and a signed uniform u in [-1, 1)
 * (its other 24 bits read as a two's-complement fraction: a sign and 23 bits of magnitude, as
 * many as float32 keeps); x = u * x[i].  If |x| < x[i+1] the point is under the curve whatever
 * its height: accept (98.5% of candidates).  Otherwise, in layer 0 draw |x| from the tail; in
 * another layer draw the height y uniform in [f(x[i]), f(x[i+1])] (53 bits) and accept x if
 * y < f(x) (the wedge), else start over with a new candidate, from then on from 64-bit draws
 * (52 bits of magnitude).  (u = -1 exactly has |x| = x[i]: always a wedge or tail case; u = 0 is
 * counted once where a separate sign bit would count it twice: biases of 2**-24 of one layer's
 * mass, far below anything the float32 output or a test could see.)
 */

#define ZIG_LAYERS 256

static double zig_x[ZIG_LAYERS + 1]; /* layer edges, x[0] = v / f(r), x[1] = r, x[N] = 0 */
static double zig_xin[ZIG_LAYERS];   /* x[i+1]: layer i's box that is wholly under the curve */
static double zig_f[ZIG_LAYERS + 1]; /* f at the edges, f[0] = f(r), f[N] = 1 */
static double zig_w32[ZIG_LAYERS];   /* x[i] * 2**-31 and x[i] * 2**-63: a masked word as a signed */
static double zig_w64[ZIG_LAYERS];   /* integer times these is u * x[i] (see zig_candidate*) */
static double zig_r;

/* integral_r^inf exp(-x*x/2) dx */
static double upper_tail_area(double r) { return sqrt(M_PI / 2.0) * erfc(r / M_SQRT2); }

/* Build the layers for base edge r into x and f.  Returns how far the top layer misses the top
 * of the density: > 0 if the layers reach f = 1 too early (r too small, v too big), < 0 if the
 * last layer stops short of it (r too large). */
static double zig_try(double r, double *x, double *f) {
    double fr = exp(-0.5 * r * r);
    double v = r * fr + upper_tail_area(r);
    x[0] = v / fr;
    f[0] = fr;
    x[1] = r;
    f[1] = fr;
    for (int i = 1; i < ZIG_LAYERS - 1; i++) {
        double y = f[i] + v / x[i];
        if (y >= 1.0) {
            return 1.0 + (double)(ZIG_LAYERS - 1 - i); /* overshoot, more the earlier it happens */
        }
        x[i + 1] = sqrt(-2.0 * log(y));
        f[i + 1] = y;
    }
    return f[ZIG_LAYERS - 1] + v / x[ZIG_LAYERS - 1] - 1.0;
}

static int zig_build(void) {
    double lo = 2.0, hi = 6.0; /* the residual is > 0 at lo and < 0 at hi for 256 layers */
    if (!(zig_try(lo, zig_x, zig_f) > 0.0) || !(zig_try(hi, zig_x, zig_f) < 0.0)) {
        return -1;
    }
    for (int it = 0; it < 200; it++) {
        double mid = 0.5 * (lo + hi);
        if (mid <= lo || mid >= hi) {
            break;
        }
        if (zig_try(mid, zig_x, zig_f) > 0.0) {
            lo = mid;
        }
        else {
            hi = mid;
        }
    }
    /* hi: the last layer (width x[N-1], up to f = 1) is at most a rounding error too big.  The
     * result agrees with Marsaglia and Tsang's r = 3.6541528853610088 to ~1e-15. */
    double miss = zig_try(hi, zig_x, zig_f);
    if (!(fabs(miss) < 1e-9)) {
        return -1;
    }
    zig_r = hi;
    zig_x[ZIG_LAYERS] = 0.0;
    zig_f[ZIG_LAYERS] = 1.0;
    for (int i = 0; i < ZIG_LAYERS; i++) {
        zig_xin[i] = zig_x[i + 1];
        zig_w32[i] = ldexp(zig_x[i], -31);
        zig_w64[i] = ldexp(zig_x[i], -63);
    }
    return 0;
}

/* ---------------------------------------------------------------- the normal sampler */

/* A candidate u * x[i] from a word whose low 8 bits chose layer i: its other bits, read as a
 * two's-complement fraction, are u in [-1, 1).  Both conversions are exact (the masked integer
 * has at most 24, resp. 53, significant bits; GCC and Clang convert to signed types modulo). */
static inline double zig_candidate32(uint32_t w, unsigned i) {
    return (double)(int32_t)(w & ~UINT32_C(0xff)) * zig_w32[i];
}
static inline double zig_candidate64(uint64_t b, unsigned i) {
    return (double)(int64_t)(b & ~UINT64_C(0x7ff)) * zig_w64[i];
}

/* Marsaglia (1964): a normal deviate beyond r, exactly */
static double zig_tail(Rng *rng) {
    for (;;) {
        double a = -log(uniform_oc(rng)) / zig_r;
        double e = -log(uniform_oc(rng));
        if (e + e >= a * a) {
            return zig_r + a;
        }
    }
}

/* The rare cases (~1% of candidates): x from layer i fell outside the layer's safe box.  Finish
 * that candidate (tail or wedge), and on rejection start over with fresh 64-bit candidates. */
#if defined(__GNUC__)
__attribute__((noinline))
#endif
static double zig_slow(Rng *rng, unsigned i, double x) {
    for (;;) {
        if (i == 0) {
            double t = zig_tail(rng);
            return x < 0.0 ? -t : t;
        }
        double y = zig_f[i] + uniform_co(rng) * (zig_f[i + 1] - zig_f[i]);
        if (y < exp(-0.5 * x * x)) {
            return x;
        }
        uint64_t b = rng_next(rng);
        i = (unsigned)(b & (ZIG_LAYERS - 1));
        x = zig_candidate64(b, i);
        if (fabs(x) < zig_xin[i]) {
            return x;
        }
    }
}

/* One standard normal from the 32-bit word w (the fast path, inlined), rounded to float32. */
static inline float zig_normal32(Rng *rng, uint32_t w) {
    unsigned i = w & (ZIG_LAYERS - 1);
    double x = zig_candidate32(w, i);
    if (fabs(x) >= zig_xin[i]) {
        Rng tmp = *rng; /* the slow path gets a copy's address, so rng itself can live in registers */
        x = zig_slow(&tmp, i, x);
        *rng = tmp;
    }
    return (float)x;
}

/*
 * The noise stream: blocks of ZBLOCK normals, each block generated from the state the previous
 * one left, two candidates per 64-bit output (its low word, then its high word; the slow path
 * draws outputs of its own in between).  The k-th normal of the stream depends only on the seed
 * and k, however many normals the caller takes at a time.
 */
#define ZBLOCK 256 /* even */

static void zig_block(Rng *state, float *z) {
    Rng rng = *state;
    for (int j = 0; j < ZBLOCK; j += 2) {
        uint64_t b = rng_next(&rng);
        z[j] = zig_normal32(&rng, (uint32_t)b);
        z[j + 1] = zig_normal32(&rng, (uint32_t)(b >> 32));
    }
    *state = rng;
}

/* ---------------------------------------------------------------- the sensor model */

#define CHUNK ZBLOCK

#if SCANNOISE_SSE2
/* for a 4-bit hit mask: how many of the lanes before lane l hit (l = 0..3), and how many hit */
#define LANE_HITS(b)                                                                             \
    {0, (b) & 1, ((b) & 1) + (((b) >> 1) & 1), ((b) & 1) + (((b) >> 1) & 1) + (((b) >> 2) & 1),  \
     ((b) & 1) + (((b) >> 1) & 1) + (((b) >> 2) & 1) + (((b) >> 3) & 1)}
static const unsigned char lane_hits[16][5] = {
    LANE_HITS(0),  LANE_HITS(1),  LANE_HITS(2),  LANE_HITS(3),  LANE_HITS(4),  LANE_HITS(5),
    LANE_HITS(6),  LANE_HITS(7),  LANE_HITS(8),  LANE_HITS(9),  LANE_HITS(10), LANE_HITS(11),
    LANE_HITS(12), LANE_HITS(13), LANE_HITS(14), LANE_HITS(15),
};
#endif

/* cond ? a : b in integer masks: a plain ?: on floats becomes a branch, mispredicted whenever
 * hits and misses alternate irregularly */
static inline float select_f32(int cond, float a, float b) {
    uint32_t ua, ub, mask = (uint32_t)0 - (uint32_t)(cond != 0);
    memcpy(&ua, &a, sizeof ua);
    memcpy(&ub, &b, sizeof ub);
    uint32_t u = (ua & mask) | (ub & ~mask);
    float r;
    memcpy(&r, &u, sizeof r);
    return r;
}

/* src and dst are the same array or disjoint.  Per chunk of CHUNK items: make sure enough normals
 * are ready, then one branch-free pass (the hit/miss pattern can be irregular) in which hit j of
 * the chunk takes the j-th ready normal.  Each item is read before it is written, so in place
 * works.  Normals are made ahead CHUNK at a time, except for the last chunk, whose hits are
 * counted so that no more than needed are made (a short scan costs only its hits). */
static void sensor_model(const float *src, float *dst, Py_ssize_t n, float rmin, float rmax, float sd, int noise,
                         uint64_t seed) {
    if (!noise) {
        Py_ssize_t k = 0;
#if SCANNOISE_SSE2
        const __m128 vmax = _mm_set1_ps(rmax), vinf = _mm_set1_ps(INFINITY);
        for (; k + 4 <= n; k += 4) {
            __m128 v = _mm_loadu_ps(src + k);
            __m128 hit = _mm_cmplt_ps(v, vmax);
            _mm_storeu_ps(dst + k, _mm_or_ps(_mm_and_ps(hit, v), _mm_andnot_ps(hit, vinf)));
        }
#endif
        for (; k < n; k++) {
            float v = src[k];
            dst[k] = v < rmax ? v : INFINITY; /* NaN compares false */
        }
        return;
    }
    Rng rng;
    rng_seed(&rng, seed);
    /* ready normals are z[pos, end); 2 blocks hold anything left plus a new block, and one more
     * slot is read (never used) when the last item of a chunk with no hit left is examined */
    float z[2 * ZBLOCK + 1];
    memset(z, 0, sizeof z);
    int pos = 0, end = 0;
    for (Py_ssize_t base = 0; base < n; base += CHUNK) {
        int len = n - base < CHUNK ? (int)(n - base) : CHUNK;
        const float *s = src + base;
        float *d = dst + base;
        int need = len;
        if (base + len == n) {
            need = 0;
            for (int k = 0; k < len; k++) {
                need += (s[k] < rmax);
            }
        }
        if (end - pos < need) {
            memmove(z, z + pos, (size_t)(end - pos) * sizeof(float));
            end -= pos;
            pos = 0;
            while (end < need) { /* at most once: need <= ZBLOCK */
                zig_block(&rng, z + end);
                end += ZBLOCK;
            }
        }
        const float *zp = z + pos;
        int j = 0, k = 0;
#if SCANNOISE_SSE2
        /* four items at a time, the same float32 operations as the loop below, lane by lane */
        const __m128 vmin = _mm_set1_ps(rmin), vmax = _mm_set1_ps(rmax), vsd = _mm_set1_ps(sd);
        const __m128 vinf = _mm_set1_ps(INFINITY);
        for (; k + 4 <= len; k += 4) {
            __m128 v = _mm_loadu_ps(s + k);
            __m128 hit = _mm_cmplt_ps(v, vmax); /* NaN compares false */
            const unsigned char *o = lane_hits[_mm_movemask_ps(hit)];
            /* hit lanes take the next normals in order; a miss lane reads one it does not use */
            __m128 zl = _mm_setr_ps(zp[j + o[0]], zp[j + o[1]], zp[j + o[2]], zp[j + o[3]]);
            __m128 t = _mm_add_ps(v, _mm_mul_ps(zl, vsd));
            t = _mm_max_ps(vmin, t); /* maxps(a, b) is a > b ? a : b: t < rmin ? rmin : t */
            t = _mm_min_ps(vmax, t); /* and t > rmax ? rmax : t; NaN stays NaN */
            _mm_storeu_ps(d + k, _mm_or_ps(_mm_and_ps(hit, t), _mm_andnot_ps(hit, vinf)));
            j += o[4];
        }
#endif
        for (; k < len; k++) {
            float v = s[k];
            float t = v + zp[j] * sd; /* float32 product and sum: noise *= stddev; vals += noise */
            t = t < rmin ? rmin : t;  /* np.clip: NaN stays NaN */
            t = t > rmax ? rmax : t;
            int hit = v < rmax; /* NaN compares false */
            d[k] = select_f32(hit, t, INFINITY);
            j += hit;
        }
        pos += j;
    }
}

/* ---------------------------------------------------------------- argument checks */

/* Borrow a C-contiguous float32 buffer.  TypeError for a non-buffer or another item type,
 * ValueError (with the exporter's reason) for a non-contiguous or read-only one. */
static int borrow_f32(PyObject *obj, Py_buffer *view, const char *name, int writable) {
    if (!PyObject_CheckBuffer(obj)) {
        PyErr_Format(PyExc_TypeError, "%s must be a float32 buffer (a numpy array), got %.100s", name,
                     Py_TYPE(obj)->tp_name);
        return -1;
    }
    if (PyObject_GetBuffer(obj, view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0)) < 0) {
        /* the exporter's exception (numpy: "ndarray is not C-contiguous", "... read-only") */
#if PY_VERSION_HEX >= 0x030C0000
        PyObject *why = PyErr_GetRaisedException();
#else
        PyObject *type, *why, *tb;
        PyErr_Fetch(&type, &why, &tb);
        PyErr_NormalizeException(&type, &why, &tb);
        Py_XDECREF(type);
        Py_XDECREF(tb);
#endif
        PyErr_Format(PyExc_ValueError, "%s must be a C-contiguous%s float32 buffer (%S)", name,
                     writable ? ", writable" : "", why ? why : Py_None);
        Py_XDECREF(why);
        return -1;
    }
    const char *f = view->format ? view->format : "B";
#if PY_LITTLE_ENDIAN
    const char *g = (*f == '<' || *f == '=' || *f == '@') ? f + 1 : f;
#else
    const char *g = (*f == '>' || *f == '!' || *f == '=' || *f == '@') ? f + 1 : f;
#endif
    if (view->itemsize != 4 || strcmp(g, "f") != 0) {
        PyErr_Format(PyExc_TypeError, "%s must hold float32 items, got format '%s' of %zd bytes", name, f,
                     view->itemsize);
        PyBuffer_Release(view);
        return -1;
    }
    return 0;
}

/* float(obj) for a real number (float, int, numpy scalar); TypeError naming the argument otherwise */
static int get_real(PyObject *obj, const char *name, double *out) {
    *out = PyFloat_AsDouble(obj);
    if (*out == -1.0 && PyErr_Occurred()) {
        if (PyErr_ExceptionMatches(PyExc_TypeError)) {
            PyErr_Clear();
            PyErr_Format(PyExc_TypeError, "%s must be a real number, got %.100s", name, Py_TYPE(obj)->tp_name);
        }
        return -1; /* OverflowError for an int too big for a double stays */
    }
    return 0;
}

static PyObject *apply(PyObject *self, PyObject *args, PyObject *kwargs) {
    (void)self;
    static char *kwlist[] = {"raw", "out", "range_min", "range_max", "stddev", "seed", NULL};
    PyObject *raw_obj, *out_obj, *rmin_obj, *rmax_obj, *sd_obj, *seed_obj;
    double range_min, range_max, stddev;
    if (!PyArg_ParseTupleAndKeywords(args, kwargs, "OOOOOO:apply", kwlist, &raw_obj, &out_obj, &rmin_obj, &rmax_obj,
                                     &sd_obj, &seed_obj)) {
        return NULL;
    }
    if (get_real(rmin_obj, "range_min", &range_min) < 0 || get_real(rmax_obj, "range_max", &range_max) < 0 ||
        get_real(sd_obj, "stddev", &stddev) < 0) {
        return NULL;
    }
    if (isnan(range_min) || isnan(range_max)) {
        PyErr_SetString(PyExc_ValueError, "range_min and range_max must not be NaN");
        return NULL;
    }
    if (range_min > range_max) {
        PyErr_SetString(PyExc_ValueError, "range_min must not exceed range_max");
        return NULL;
    }
    /* np.float32(x): round to nearest; beyond float32's range this gives +-inf (IEEE 754) */
    float rmin = (float)range_min, rmax = (float)range_max, sd = (float)stddev;
    if (!isfinite(stddev) || stddev < 0.0 || !isfinite(sd)) {
        PyErr_SetString(PyExc_ValueError, "stddev must be a finite float >= 0 (and fit in float32)");
        return NULL;
    }
    PyObject *seed_int = PyNumber_Index(seed_obj);
    if (seed_int == NULL) {
        if (PyErr_ExceptionMatches(PyExc_TypeError)) {
            PyErr_Clear();
            PyErr_Format(PyExc_TypeError, "seed must be an int, got %.100s", Py_TYPE(seed_obj)->tp_name);
        }
        return NULL;
    }
    unsigned long long seed = PyLong_AsUnsignedLongLong(seed_int);
    Py_DECREF(seed_int);
    if (seed == (unsigned long long)-1 && PyErr_Occurred()) {
        if (PyErr_ExceptionMatches(PyExc_OverflowError)) {
            PyErr_Clear();
            PyErr_SetString(PyExc_OverflowError, "seed must be an int in [0, 2**64)");
        }
        return NULL;
    }

    Py_buffer raw, out;
    if (borrow_f32(raw_obj, &raw, "raw", 0) < 0) {
        return NULL;
    }
    if (borrow_f32(out_obj, &out, "out", 1) < 0) {
        PyBuffer_Release(&raw);
        return NULL;
    }
    Py_ssize_t n = raw.len / 4;
    if (out.len != raw.len) {
        PyErr_Format(PyExc_ValueError, "out holds %zd items, raw %zd: they must match", out.len / 4, n);
        PyBuffer_Release(&out);
        PyBuffer_Release(&raw);
        return NULL;
    }
    const float *src = (const float *)raw.buf;
    float *dst = (float *)out.buf;
    int noise = stddev != 0.0;
    Py_BEGIN_ALLOW_THREADS;
    if (n > 0 && (const char *)src != (const char *)dst) {
        uintptr_t a = (uintptr_t)src, b = (uintptr_t)dst, bytes = (uintptr_t)raw.len;
        if (a < b + bytes && b < a + bytes) {
            /* partial overlap: copy first, then work in place (numpy copies raw first too) */
            memmove(dst, src, (size_t)bytes);
            src = dst;
        }
    }
    sensor_model(src, dst, n, rmin, rmax, sd, noise, (uint64_t)seed);
    Py_END_ALLOW_THREADS;
    PyBuffer_Release(&out);
    PyBuffer_Release(&raw);
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"apply", (PyCFunction)(void (*)(void))apply, METH_VARARGS | METH_KEYWORDS,
     "apply($module, /, raw, out, range_min, range_max, stddev, seed)\n--\n\n"
     "The lidar sensor model: ranges not < range_max become +inf; the others get float32 Gaussian\n"
     "noise of the given stddev (seeded, in row-major hit order) and are clamped to\n"
     "[range_min, range_max]; stddev == 0 copies them unchanged.  out may be raw."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "simd.core._scannoise", "Lidar masking and Gaussian noise, compiled (see simd/core/_scannoise.c).",
    -1, methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__scannoise(void) {
    if (zig_build() < 0) {
        PyErr_SetString(PyExc_ImportError, "simd._scannoise: could not build the ziggurat tables");
        return NULL;
    }
    PyObject *m = PyModule_Create(&module);
    if (m == NULL) {
        return NULL;
    }
    /* for the tests: normals beyond ZIGGURAT_R come from the tail sampler */
    PyObject *r = PyFloat_FromDouble(zig_r);
    int rc = r == NULL ? -1 : PyModule_AddObjectRef(m, "ZIGGURAT_R", r);
    Py_XDECREF(r);
    if (rc < 0 || PyModule_AddIntConstant(m, "ZIGGURAT_LAYERS", ZIG_LAYERS) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
