/*
 * simd._drive: the per-tick diff-drive arithmetic of simd/core/drive.py in one pass over the robots.
 *
 * drive.py's numpy functions are the reference (tests compare the two).  With 100 robots numpy
 * spends ~0.25 ms a tick on some 60 small-array operations that each allocate and loop once;
 * the loop below does the same arithmetic in a few microseconds.  Every formula is written in
 * the numpy code's order and the file is compiled without FMA contraction (see pyproject.toml),
 * so that the only differences come from sin, cos and atan2 (libm here, numpy's own there),
 * which may differ in the last bit.
 *
 * advance(tick, cmd_timeout, dt, last_cmd, target_v, target_w, max_v, max_w, separation,
 *         max_accel, wheel_l, wheel_r, yaw, out_v, out_w, out_dx, out_dy)
 *     Stale commands (older than cmd_timeout, when > 0) are zeroed in target_v/target_w, the
 *     wheels ramp toward the clamped targets (updated in place), and out_* get the body twist
 *     and the world-frame displacement along the arc over dt.
 * report(dt, tolerance, x0, y0, yaw0, x, y, yaw, v, w, dx, dy, out_vx, out_vy, out_wz, out_yaw)
 *     The twist to report after the physics moved the robots from (x0, y0, yaw0) to (x, y, yaw):
 *     the wheels' when the motion was the free one, the achieved one otherwise; out_yaw gets yaw
 *     wrapped to [-pi, pi].
 * All arrays are C-contiguous, n long, float64 (int64 for last_cmd); out_* are written.
 */

#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <math.h>
#include <stdint.h>
#include <string.h>

#if defined(__FAST_MATH__)
#error "simd/core/_drive.c must not be compiled with -ffast-math"
#endif

#define SNAP_TOLERANCE 0.01
#define SMALL_TURN 1e-9
#define MAX_ARRAYS 16

typedef struct {
    Py_buffer views[MAX_ARRAYS];
    int count;
} Buffers;

static void release_all(Buffers *b) {
    for (int i = 0; i < b->count; i++) {
        PyBuffer_Release(&b->views[i]);
    }
    b->count = 0;
}

/* Borrow a C-contiguous buffer of n items of the given format ('d' float64, 'q' int64);
 * n < 0 accepts any length (the first array sets it for the others). */
static void *borrow(Buffers *b, PyObject *obj, const char *name, char fmt, Py_ssize_t n, int writable) {
    Py_buffer *view = &b->views[b->count];
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, view, flags) < 0) {
        PyErr_Format(PyExc_TypeError, "%s must be a C-contiguous%s buffer", name, writable ? " writable" : "");
        return NULL;
    }
    b->count++;
    const char *f = view->format ? view->format : "B";
    if (*f == '<' || *f == '=' || *f == '@') {
        f++;
    }
    int ok = view->itemsize == 8 && f[0] != '\0' && f[1] == '\0' && (f[0] == fmt || (fmt == 'q' && f[0] == 'l'));
    if (!ok) {
        PyErr_Format(PyExc_TypeError, "%s must hold %s", name, fmt == 'd' ? "float64" : "int64");
        return NULL;
    }
    if (n >= 0 && view->len != n * 8) {
        PyErr_Format(PyExc_ValueError, "%s holds %zd items, expected %zd", name, view->len / 8, n);
        return NULL;
    }
    return view->buf;
}

/* np.maximum / np.minimum: a NaN in either operand is the result */
static inline double np_maximum(double a, double b) { return (a != a) ? a : (b != b) ? b : (a >= b ? a : b); }
static inline double np_minimum(double a, double b) { return (a != a) ? a : (b != b) ? b : (a <= b ? a : b); }

/* np.clip(a, lo, hi) == np.minimum(np.maximum(a, lo), hi) */
static inline double clip(double a, double lo, double hi) { return np_minimum(np_maximum(a, lo), hi); }

static PyObject *advance(PyObject *self, PyObject *args) {
    (void)self;
    long long tick;
    double cmd_timeout, dt;
    PyObject *o[14];
    if (!PyArg_ParseTuple(args, "LddOOOOOOOOOOOOOO:advance", &tick, &cmd_timeout, &dt, &o[0], &o[1], &o[2],
                          &o[3], &o[4], &o[5], &o[6], &o[7], &o[8], &o[9], &o[10], &o[11], &o[12], &o[13])) {
        return NULL;
    }
    Buffers b = {.count = 0};
    const int64_t *last_cmd = borrow(&b, o[0], "last_cmd", 'q', -1, 0);
    Py_ssize_t n = last_cmd ? b.views[0].len / 8 : 0;
    double *tv = last_cmd ? borrow(&b, o[1], "target_v", 'd', n, 1) : NULL;
    double *tw = tv ? borrow(&b, o[2], "target_w", 'd', n, 1) : NULL;
    const double *max_v = tw ? borrow(&b, o[3], "max_v", 'd', n, 0) : NULL;
    const double *max_w = max_v ? borrow(&b, o[4], "max_w", 'd', n, 0) : NULL;
    const double *sep = max_w ? borrow(&b, o[5], "separation", 'd', n, 0) : NULL;
    const double *acc = sep ? borrow(&b, o[6], "max_accel", 'd', n, 0) : NULL;
    double *wl = acc ? borrow(&b, o[7], "wheel_l", 'd', n, 1) : NULL;
    double *wr = wl ? borrow(&b, o[8], "wheel_r", 'd', n, 1) : NULL;
    const double *yaw = wr ? borrow(&b, o[9], "yaw", 'd', n, 0) : NULL;
    double *out_v = yaw ? borrow(&b, o[10], "out_v", 'd', n, 1) : NULL;
    double *out_w = out_v ? borrow(&b, o[11], "out_w", 'd', n, 1) : NULL;
    double *out_dx = out_w ? borrow(&b, o[12], "out_dx", 'd', n, 1) : NULL;
    double *out_dy = out_dx ? borrow(&b, o[13], "out_dy", 'd', n, 1) : NULL;
    if (out_dy == NULL) {
        release_all(&b);
        return NULL;
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        if (cmd_timeout > 0 && (double)(tick - last_cmd[i]) * dt > cmd_timeout + 1e-9) {
            tv[i] = 0.0;
            tw[i] = 0.0;
        }
        /* wheel_targets */
        double v = clip(tv[i], -max_v[i], max_v[i]);
        double w = clip(tw[i], -max_w[i], max_w[i]);
        double half = w * sep[i] * 0.5;
        double lt = v - half, rt = v + half;
        /* ramp_wheels */
        double step = acc[i] * dt;
        double dl = lt - wl[i], dr = rt - wr[i];
        int snap = fabs(dl) < SNAP_TOLERANCE && fabs(dr) < SNAP_TOLERANCE;
        double l = snap ? lt : wl[i] + clip(dl, -step, step);
        double r = snap ? rt : wr[i] + clip(dr, -step, step);
        wl[i] = l;
        wr[i] = r;
        /* body_twist */
        double bv = (l + r) * 0.5;
        double bw = (r - l) / sep[i];
        /* arc_displacement */
        double th = bw * dt;
        double fwd, left;
        if (fabs(th) < SMALL_TURN) {
            fwd = bv * dt;
            left = bv * dt * th * 0.5;
        } else {
            fwd = bv * dt * sin(th) / th;
            left = bv * dt * (1.0 - cos(th)) / th;
        }
        double c = cos(yaw[i]), s = sin(yaw[i]);
        out_v[i] = bv;
        out_w[i] = bw;
        out_dx[i] = fwd * c - left * s;
        out_dy[i] = fwd * s + left * c;
    }
    release_all(&b);
    Py_RETURN_NONE;
}

static PyObject *report(PyObject *self, PyObject *args) {
    (void)self;
    double dt, tol;
    PyObject *o[14];
    if (!PyArg_ParseTuple(args, "ddOOOOOOOOOOOOOO:report", &dt, &tol, &o[0], &o[1], &o[2], &o[3], &o[4], &o[5],
                          &o[6], &o[7], &o[8], &o[9], &o[10], &o[11], &o[12], &o[13])) {
        return NULL;
    }
    Buffers b = {.count = 0};
    Py_ssize_t n = -1;
    static const char *names[14] = {"x0", "y0", "yaw0", "x", "y", "yaw", "v", "w", "dx", "dy",
                                    "out_vx", "out_vy", "out_wz", "out_yaw"};
    double *p[14];
    for (int k = 0; k < 14; k++) {
        p[k] = borrow(&b, o[k], names[k], 'd', n, k >= 10);
        if (p[k] == NULL) {
            release_all(&b);
            return NULL;
        }
        n = b.views[0].len / 8;
    }
    const double *x0 = p[0], *y0 = p[1], *yaw0 = p[2], *x = p[3], *y = p[4], *yaw = p[5];
    const double *v = p[6], *w = p[7], *dx = p[8], *dy = p[9];
    double *vx = p[10], *vy = p[11], *wz = p[12], *out_yaw = p[13];
    for (Py_ssize_t i = 0; i < n; i++) {
        double ax = x[i] - x0[i], ay = y[i] - y0[i];
        double d = yaw[i] - yaw0[i];
        double dyaw = atan2(sin(d), cos(d));
        int free_motion = fabs(ax - dx[i]) < tol && fabs(ay - dy[i]) < tol && fabs(dyaw - w[i] * dt) < tol;
        if (free_motion) {
            vx[i] = v[i];
            vy[i] = 0.0;
            wz[i] = w[i];
        } else { /* the mid-tick heading only for the achieved motion: most robots move freely */
            double mid = yaw0[i] + 0.5 * dyaw;
            double c = cos(mid), s = sin(mid);
            vx[i] = (ax * c + ay * s) / dt;
            vy[i] = (-ax * s + ay * c) / dt;
            wz[i] = dyaw / dt;
        }
        out_yaw[i] = atan2(sin(yaw[i]), cos(yaw[i]));
    }
    release_all(&b);
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"advance", advance, METH_VARARGS, "One drive-controller update for every robot (see the module comment)."},
    {"report", report, METH_VARARGS, "The twist to report after the physics step (see the module comment)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "simd.core._drive", "Per-tick diff-drive arithmetic, compiled.", -1, methods,
    NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__drive(void) { return PyModule_Create(&module); }
