/*
 * simd.nav._cellpaths: the Dijkstra of simd/nav/cells.py (``dijkstra_python``), compiled.
 *
 * The Python search is the reference: tests compare the two distance arrays bit for bit
 * (np.array_equal, inf included).  For that, this file repeats its choices exactly:
 *   - the moves in the same order (MOVES below, as cells.ALL_MOVES: the four axis moves, the
 *     four diagonals, then the eight knight's moves), move (dr, dc) costing
 *     ``size * sqrt(dr*dr + dc*dc)`` worked out once in float64 before the search as the
 *     reference works it out (math.sqrt and C's sqrt are both correctly rounded, IEEE 754, so
 *     sqrt(1), sqrt(2) and sqrt(5) are the same doubles in both: tested);
 *   - the same float64 arithmetic: a neighbour's new distance is d + step, where d is the
 *     distance the cell was popped with; it replaces the old one only when strictly smaller
 *     (of two ways of equal length, the one found first stays); the file is compiled without
 *     FMA contraction or fast-math (pyproject.toml) so that each addition rounds as Python's;
 *   - the same queue order, (distance, cell), as heapq orders the reference's (d, c) tuples;
 *     an entry whose distance is above the cell's current one is stale and skipped.  A cell is
 *     pushed again only with a strictly smaller distance, so the keys never tie and any heap
 *     pops them in the same sequence as heapq;
 *   - the float64 distances cast to float32 at the end (round to nearest, as numpy's astype).
 * (Dijkstra's final distances hardly depend on the order anyway: each is the least of
 * d(neighbour) + step over its neighbours, and rounding is monotonic; but the same order makes
 * the two searches the same step for step, which leaves nothing to argue about.)
 *
 * dijkstra(moves, width, goal, size) -> bytearray
 *     moves: a C-contiguous (cells, 8) or (cells, 16) bool buffer, moves[c, k] whether a robot
 *     may step from cell c (flat, row * width + col) by move k of MOVES; the number of columns
 *     picks the move set (the first 8 moves, or all 16); width >= 1 divides cells; size finite
 *     > 0.  No move may lead off the grid (ValueError naming the first that does, in cell
 *     order then move order: the search trusts the moves and does no bounds checks; a knight's
 *     move reaches two cells, so for 16 columns the check looks two cells deep).  Returns the
 *     distances to ``goal`` as float32 (native byte order), inf where there is no way, all inf
 *     when ``goal`` is not a cell.
 *     The GIL is released during the search; the caller must not write ``moves`` meanwhile.
 *     The moves are meant to be symmetric (then the distances to the goal are those from it);
 *     that is not checked.
 */

#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#if defined(__FAST_MATH__)
#error "simd/nav/_cellpaths.c must not be compiled with -ffast-math"
#endif

#if defined(__GNUC__) || defined(__clang__)
#define ALWAYS_INLINE inline __attribute__((always_inline))
#else
#define ALWAYS_INLINE inline
#endif

/* (d_row, d_col) in cells.ALL_MOVES's order: the axis moves, the diagonals (cells.MOVES: a
 * (cells, 8) graph uses these), then the knight's moves (cells.KNIGHTS: a (cells, 16) graph) */
#define KINDS_8 8
#define KINDS_16 16
static const int MOVES[KINDS_16][2] = {
    {0, 1}, {1, 0},  {0, -1},  {-1, 0},  {1, 1},   {1, -1},  {-1, -1}, {-1, 1},
    {1, 2}, {2, 1},  {2, -1},  {1, -2},  {-1, -2}, {-2, -1}, {-2, 1},  {-1, 2},
};

/* A queue entry: a distance and a cell, ordered by (distance, cell) as the reference's tuples.
 * Distances are >= +0.0 and never NaN, and such doubles order as their bits do as unsigned
 * integers; so where the compiler has 128-bit integers an entry is the distance's bits above
 * the cell, and one comparison without branches orders two of them (twice as fast as comparing
 * the distances, then on the many ties the cells). */
#if defined(__SIZEOF_INT128__)
typedef unsigned __int128 Entry;

static inline Entry entry(double d, Py_ssize_t cell) {
    uint64_t bits;
    memcpy(&bits, &d, sizeof bits);
    return ((Entry)bits << 64) | (Entry)(uint64_t)cell;
}

static inline double entry_d(Entry e) {
    uint64_t bits = (uint64_t)(e >> 64);
    double d;
    memcpy(&d, &bits, sizeof d);
    return d;
}

static inline Py_ssize_t entry_cell(Entry e) { return (Py_ssize_t)(uint64_t)e; }

static inline int before(const Entry *a, const Entry *b) { return *a < *b; }
#else
typedef struct {
    double d;
    Py_ssize_t cell;
} Entry;

static inline Entry entry(double d, Py_ssize_t cell) { return (Entry){d, cell}; }

static inline double entry_d(Entry e) { return e.d; }

static inline Py_ssize_t entry_cell(Entry e) { return e.cell; }

static inline int before(const Entry *a, const Entry *b) {
    return a->d < b->d || (a->d == b->d && a->cell < b->cell);
}
#endif

/* A 4-ary min-heap of entries (four children share a cache line or two). */
typedef struct {
    Entry *items;
    size_t len, cap;
} Heap;

static int heap_push(Heap *q, Entry e) {
    if (q->len == q->cap) {
        size_t cap = q->cap ? 2 * q->cap : 1024;
        Entry *grown = realloc(q->items, cap * sizeof(Entry));
        if (grown == NULL) return -1;
        q->items = grown;
        q->cap = cap;
    }
    size_t i = q->len++;
    while (i > 0) {
        size_t up = (i - 1) / 4;
        if (!before(&e, &q->items[up])) break;
        q->items[i] = q->items[up];
        i = up;
    }
    q->items[i] = e;
    return 0;
}

static Entry heap_pop(Heap *q) {
    Entry top = q->items[0];
    Entry last = q->items[--q->len];
    size_t i = 0, n = q->len;
    for (;;) {
        size_t first = 4 * i + 1;
        if (first >= n) break;
        size_t end = first + 4 < n ? first + 4 : n, best = first;
        for (size_t k = first + 1; k < end; k++) {
            if (before(&q->items[k], &q->items[best])) best = k;
        }
        if (!before(&q->items[best], &last)) break;
        q->items[i] = q->items[best];
        i = best;
    }
    if (n > 0) q->items[i] = last;
    return top;
}

typedef struct {
    /* inputs */
    const unsigned char *moves; /* cells x kinds, 0 or 1 */
    Py_ssize_t cells, width, goal;
    int kinds; /* KINDS_8 or KINDS_16 */
    double size;
    /* output: cells float32, filled; status 0 done, -1 out of memory */
    float *out;
    int status;
} Search;

/* The search over the first ``kinds`` moves.  Runs without the GIL: touches no Python object
 * (``out`` is a new bytearray's buffer that nobody else holds yet).  Inlined into search() once
 * per move set, so that each copy's loop over the moves has a constant count. */
static ALWAYS_INLINE void search_kinds(Search *s, const int kinds) {
    Py_ssize_t n = s->cells;
    s->status = 0;
    if (s->goal < 0 || s->goal >= n) {
        for (Py_ssize_t i = 0; i < n; i++) s->out[i] = INFINITY;
        return;
    }
    double *dist = malloc((size_t)n * sizeof(double));
    Heap open = {NULL, 0, 0};
    if (dist == NULL) goto oom;
    for (Py_ssize_t i = 0; i < n; i++) dist[i] = INFINITY;
    Py_ssize_t offset[KINDS_16];
    double step[KINDS_16];
    for (int k = 0; k < kinds; k++) {
        int dr = MOVES[k][0], dc = MOVES[k][1];
        offset[k] = dr * s->width + dc;
        step[k] = s->size * sqrt((double)(dr * dr + dc * dc)); /* as cells.dijkstra_python */
    }
    dist[s->goal] = 0.0;
    if (heap_push(&open, entry(0.0, s->goal)) < 0) goto oom;
    while (open.len > 0) {
        Entry e = heap_pop(&open);
        double d = entry_d(e);
        Py_ssize_t c = entry_cell(e);
        if (d > dist[c]) continue; /* stale: reached by a shorter way since */
        const unsigned char *allowed = s->moves + (Py_ssize_t)kinds * c;
        for (int k = 0; k < kinds; k++) {
            if (!allowed[k]) continue;
            Py_ssize_t nb = c + offset[k];
            double nd = d + step[k];
            if (nd < dist[nb]) {
                dist[nb] = nd;
                if (heap_push(&open, entry(nd, nb)) < 0) goto oom;
            }
        }
    }
    for (Py_ssize_t i = 0; i < n; i++) s->out[i] = (float)dist[i];
    free(open.items);
    free(dist);
    return;
oom:
    s->status = -1;
    free(open.items);
    free(dist);
}

static void search(Search *s) {
    if (s->kinds == KINDS_16) {
        search_kinds(s, KINDS_16);
    } else {
        search_kinds(s, KINDS_8);
    }
}

/* The first (cell, move) in cell order, then move order, that leads off a grid ``width`` wide,
 * as *cell and *move; 0 when there is none.  Only the cells within ``edge`` of the border can
 * (the longest of the first ``kinds`` moves: 1 for 8, 2 for 16, a knight's move reaching two
 * rows or two columns away), so those are the cells read, as cells.check_on_grid reads them. */
static int first_off_grid(const unsigned char *moves, Py_ssize_t cells, Py_ssize_t width, int kinds,
                          Py_ssize_t *cell, int *move) {
    Py_ssize_t rows = cells / width;
    Py_ssize_t edge = kinds == KINDS_16 ? 2 : 1;
    for (Py_ssize_t r = 0; r < rows; r++) {
        /* every column of the ``edge`` first and last rows, the ``edge`` first and last of the others */
        int inner_row = r >= edge && r < rows - edge;
        for (Py_ssize_t col = 0; col < width; col++) {
            if (inner_row && col >= edge && col < width - edge) col = width - edge;
            const unsigned char *allowed = moves + (Py_ssize_t)kinds * (r * width + col);
            for (int k = 0; k < kinds; k++) {
                Py_ssize_t to_r = r + MOVES[k][0], to_c = col + MOVES[k][1];
                if (allowed[k] && (to_r < 0 || to_r >= rows || to_c < 0 || to_c >= width)) {
                    *cell = r * width + col;
                    *move = k;
                    return 1;
                }
            }
        }
    }
    return 0;
}

static PyObject *dijkstra(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *graph;
    Search s = {0};
    if (!PyArg_ParseTuple(args, "Onnd:dijkstra", &graph, &s.width, &s.goal, &s.size)) return NULL;
    Py_buffer view;
    if (PyObject_GetBuffer(graph, &view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0) {
        PyErr_SetString(PyExc_ValueError, "moves must be a C-contiguous buffer");
        return NULL;
    }
    const char *f = view.format ? view.format : "B";
    if (*f == '<' || *f == '>' || *f == '=' || *f == '@' || *f == '!') f++;
    if (view.ndim != 2 || view.itemsize != 1 || f[0] != '?' || f[1] != '\0' ||
        (view.shape[1] != KINDS_8 && view.shape[1] != KINDS_16)) {
        PyBuffer_Release(&view);
        PyErr_SetString(PyExc_ValueError, "moves must be a (cells, 8) or (cells, 16) bool buffer");
        return NULL;
    }
    s.moves = view.buf;
    s.kinds = (int)view.shape[1];
    s.cells = view.shape[0];
    if (s.width < 1 || s.cells % s.width != 0) {
        PyBuffer_Release(&view);
        PyErr_Format(PyExc_ValueError, "width %zd does not divide the %zd cells into rows", s.width, s.cells);
        return NULL;
    }
    if (!isfinite(s.size) || !(s.size > 0.0)) {
        PyBuffer_Release(&view);
        PyErr_Format(PyExc_ValueError, "size must be finite and > 0, not %R", PyTuple_GET_ITEM(args, 3));
        return NULL;
    }
    Py_ssize_t bad_cell;
    int bad_move;
    if (first_off_grid(s.moves, s.cells, s.width, s.kinds, &bad_cell, &bad_move)) {
        PyBuffer_Release(&view);
        PyErr_Format(PyExc_ValueError, "moves[%zd, %d] steps off the grid (%zd cells wide)", bad_cell, bad_move,
                     s.width);
        return NULL;
    }
    PyObject *out = PyByteArray_FromStringAndSize(NULL, s.cells * (Py_ssize_t)sizeof(float));
    if (out == NULL) {
        PyBuffer_Release(&view);
        return NULL;
    }
    s.out = (float *)PyByteArray_AS_STRING(out);
    Py_BEGIN_ALLOW_THREADS;
    search(&s);
    Py_END_ALLOW_THREADS;
    PyBuffer_Release(&view);
    if (s.status < 0) {
        Py_DECREF(out);
        return PyErr_NoMemory();
    }
    return out;
}

static PyMethodDef methods[] = {
    {"dijkstra", dijkstra, METH_VARARGS,
     "dijkstra(moves, width, goal, size) -> bytearray\n--\n\n"
     "The distances to goal over the moves as float32, inf where there is no way (see the module "
     "comment).  The GIL is released while it searches."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "simd.nav._cellpaths",
    "Distance fields on the cell graph (Dijkstra), compiled (twin of simd/nav/cells.py).",
    -1, methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__cellpaths(void) { return PyModule_Create(&module); }
