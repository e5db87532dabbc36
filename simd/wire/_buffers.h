/*
 * simd/wire/_buffers.h: what the wire's compiled packers (_odompack.c, _listpack.c) share: a
 * buffer argument checked for its item format, size and count, and a float64 in big-endian
 * byte order (MessagePack's float 64).  Included by each packer; every function is static.
 */

#ifndef SIMD_WIRE_BUFFERS_H
#define SIMD_WIRE_BUFFERS_H

#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <stdint.h>
#include <string.h>

static int get_buffer(PyObject *obj, Py_buffer *view, const char *name, const char *fmt, Py_ssize_t itemsize,
                      Py_ssize_t count) {
    if (PyObject_GetBuffer(obj, view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0) {
        PyErr_Format(PyExc_TypeError, "%s must be a C-contiguous buffer", name);
        return -1;
    }
    const char *f = view->format ? view->format : "B";
    if (*f == '<' || *f == '=' || *f == '@') {
        f++;
    }
    int fmt_ok = strcmp(f, fmt) == 0 || (itemsize == 8 && fmt[0] == 'q' && strcmp(f, "l") == 0);
    if (!fmt_ok || view->itemsize != itemsize) {
        PyErr_Format(PyExc_TypeError, "%s has item format '%s' (size %zd), expected '%s' (size %zd)", name,
                     view->format ? view->format : "B", view->itemsize, fmt, itemsize);
        PyBuffer_Release(view);
        return -1;
    }
    if (count >= 0 && view->len != count * itemsize) {
        PyErr_Format(PyExc_ValueError, "%s holds %zd items, expected %zd", name, view->len / itemsize, count);
        PyBuffer_Release(view);
        return -1;
    }
    return 0;
}

static inline uint64_t to_big_endian(double v) {
    uint64_t u;
    memcpy(&u, &v, sizeof u);
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
    u = __builtin_bswap64(u);
#endif
    return u;
}

#endif
