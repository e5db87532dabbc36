/*
 * simd.wire._listpack: the robot list's MessagePack bytes in one call that never lets go of the GIL.
 *
 * simd/wire/list_codec.py lays the fleet's records end to end once and, for every list, copies
 * them into the reply and writes each robot's pose and twist into its record.  Its numpy path
 * does that in about ten array operations, and numpy releases the GIL in each one over a few
 * hundred items.  The list is answered on a zenoh query thread while the simulation and the
 * outbox threads want the GIL too: every release cost the query thread a wait for the GIL back,
 * and the list of 20 000 robots (~4 ms alone) took 35-60 ms under load.  Here the copy and the
 * writes are one C pass (~3 ms for 16 MB, mostly the copy) done with the GIL held.  The numpy
 * path stays as the reference: tests check both give the same bytes.
 *
 * pick(prefix, buffer, starts, lengths, marks, rows, x, y, yaw, linear, angular) -> bytearray
 *   prefix   bytes: what comes before the records (the list's head and its array header)
 *   buffer   uint8 buffer: every record's bytes, end to end
 *   starts   int64 (n,): where record i starts in ``buffer``
 *   lengths  int64 (n,): how long record i is
 *   marks    int64 (n, 5): where in record i its five float64 numbers start (past the 0xcb byte)
 *   rows     None for every record in order, or int64 (m,): the records to copy, in that order
 *            (None joins the records in index order: for a layout laid end to end from 0, which
 *            is what list_codec makes, that is the buffer itself, as the numpy path copies it)
 *   x .. angular  float64 (n,): the numbers, written big-endian (MessagePack float 64)
 * Every index is checked before anything is written; the result is a new bytearray.
 */

#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <stdint.h>
#include <string.h>

#include "_buffers.h"

#define FIELDS 5

static PyObject *pick(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *prefix, *objs[10];
    if (!PyArg_ParseTuple(args, "O!OOOOOOOOOO:pick", &PyBytes_Type, &prefix, &objs[0], &objs[1], &objs[2],
                          &objs[3], &objs[4], &objs[5], &objs[6], &objs[7], &objs[8], &objs[9])) {
        return NULL;
    }
    /* buffer, starts, lengths, marks, rows, then the five columns */
    Py_buffer views[10];
    int held[10] = {0};
    PyObject *out = NULL;
    const char *names[10] = {"buffer", "starts", "lengths", "marks", "rows", "x", "y", "yaw", "linear", "angular"};
    if (get_buffer(objs[0], &views[0], names[0], "B", 1, -1) < 0) {
        goto done;
    }
    held[0] = 1;
    if (get_buffer(objs[1], &views[1], names[1], "q", 8, -1) < 0) {
        goto done;
    }
    held[1] = 1;
    Py_ssize_t n = views[1].len / 8;
    if (get_buffer(objs[2], &views[2], names[2], "q", 8, n) < 0) {
        goto done;
    }
    held[2] = 1;
    if (get_buffer(objs[3], &views[3], names[3], "q", 8, FIELDS * n) < 0) {
        goto done;
    }
    held[3] = 1;
    int all = objs[4] == Py_None;
    if (!all) {
        if (get_buffer(objs[4], &views[4], names[4], "q", 8, -1) < 0) {
            goto done;
        }
        held[4] = 1;
    }
    for (int k = 0; k < FIELDS; k++) {
        if (get_buffer(objs[5 + k], &views[5 + k], names[5 + k], "d", 8, n) < 0) {
            goto done;
        }
        held[5 + k] = 1;
    }
    const unsigned char *src = (const unsigned char *)views[0].buf;
    const int64_t *starts = (const int64_t *)views[1].buf;
    const int64_t *lengths = (const int64_t *)views[2].buf;
    const int64_t *marks = (const int64_t *)views[3].buf;
    const int64_t *rows = all ? NULL : (const int64_t *)views[4].buf;
    Py_ssize_t m = all ? n : views[4].len / 8;
    const double *col[FIELDS];
    for (int k = 0; k < FIELDS; k++) {
        col[k] = (const double *)views[5 + k].buf;
    }

    /* every row, its record and its numbers inside the buffer, before anything is written */
    Py_ssize_t total = PyBytes_GET_SIZE(prefix);
    for (Py_ssize_t j = 0; j < m; j++) {
        int64_t r = all ? (int64_t)j : rows[j];
        if (r < 0 || r >= (int64_t)n) {
            PyErr_Format(PyExc_ValueError, "rows outside the %zd records: %lld", n, (long long)r);
            goto done;
        }
        int64_t a = starts[r], len = lengths[r];
        if (a < 0 || len < 0 || len > (int64_t)views[0].len - a) {
            PyErr_Format(PyExc_ValueError, "record %lld is outside the buffer", (long long)r);
            goto done;
        }
        for (int k = 0; k < FIELDS; k++) {
            int64_t o = marks[FIELDS * r + k];
            if (o < 0 || o > len - 8) {
                PyErr_Format(PyExc_ValueError, "number %d of record %lld is outside the record", k, (long long)r);
                goto done;
            }
        }
        if (len > PY_SSIZE_T_MAX - total) {
            PyErr_SetString(PyExc_OverflowError, "the list is too long");
            goto done;
        }
        total += (Py_ssize_t)len;
    }

    out = PyByteArray_FromStringAndSize(NULL, total);
    if (out == NULL) {
        goto done;
    }
    char *dst = PyByteArray_AS_STRING(out);
    memcpy(dst, PyBytes_AS_STRING(prefix), (size_t)PyBytes_GET_SIZE(prefix));
    dst += PyBytes_GET_SIZE(prefix);
    if (all && n > 0) { /* records in order: one copy, then the numbers written in */
        int64_t first = starts[0];
        int64_t span = total - PyBytes_GET_SIZE(prefix);
        int contiguous = 1;
        for (Py_ssize_t i = 1; i < n && contiguous; i++) {
            contiguous = starts[i] == starts[i - 1] + lengths[i - 1];
        }
        if (contiguous) {
            memcpy(dst, src + first, (size_t)span);
            for (Py_ssize_t i = 0; i < n; i++) {
                char *rec = dst + (starts[i] - first);
                for (int k = 0; k < FIELDS; k++) {
                    uint64_t be = to_big_endian(col[k][i]);
                    memcpy(rec + marks[FIELDS * i + k], &be, sizeof be);
                }
            }
            goto done;
        }
    }
    for (Py_ssize_t j = 0; j < m; j++) {
        int64_t r = all ? (int64_t)j : rows[j];
        int64_t len = lengths[r];
        memcpy(dst, src + starts[r], (size_t)len);
        for (int k = 0; k < FIELDS; k++) {
            uint64_t be = to_big_endian(col[k][r]);
            memcpy(dst + marks[FIELDS * r + k], &be, sizeof be);
        }
        dst += len;
    }

done:
    for (int i = 0; i < 10; i++) {
        if (held[i]) {
            PyBuffer_Release(&views[i]);
        }
    }
    return out;
}

static PyMethodDef methods[] = {
    {"pick", pick, METH_VARARGS,
     "pick(prefix, buffer, starts, lengths, marks, rows, x, y, yaw, linear, angular) -> bytearray: "
     "records copied after the prefix with their five numbers written in."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "simd.wire._listpack", "The robot list's records copied and patched in one pass.", -1,
    methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__listpack(void) { return PyModule_Create(&module); }
