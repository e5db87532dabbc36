/*
 * simd.nav._astar: the A* of simd/nav/grid_search.py (``plan_python``), compiled.
 *
 * The Python search is the reference: tests compare the two paths array for array, not just
 * their costs.  For that, this file repeats its choices exactly:
 *   - the neighbours in the same order (MOVES below: up, down, left, right, then the diagonals
 *     up-left, up-right, down-left, down-right), a diagonal only when both orthogonal cells it
 *     passes are traversable;
 *   - the same float64 arithmetic in the same order: a step costs length * (c[a] + c[b]) / 2.0,
 *     g[b] = g[a] + step, h = (hi - lo) + SQRT2 * lo (octile) or dr + dc (Manhattan), f = g + h;
 *     the file is compiled without FMA contraction or fast-math (pyproject.toml) so that each
 *     operation rounds as Python's does;
 *   - the same open list order, (f, h, push counter), the counter counting every push; a
 *     node popped a second time is skipped, a closed node is never relaxed, a neighbour is
 *     updated only when its new g is strictly smaller, and the search stops when the goal is
 *     popped.
 * The keys are unique (the counter), so any heap pops them in the same sequence as heapq.
 *
 * plan(cost, start_row, start_col, goal_row, goal_col, diagonal) -> bytearray | None
 *     cost: a C-contiguous 2-D float32 buffer, +inf where blocked (the caller has checked that
 *     every other value is finite and >= 1).  Returns the path as int32 (row, col) pairs, start
 *     first, or None when the goal cannot be reached (or start or goal is blocked).  The GIL
 *     is released during the search; the caller must not write the grid meanwhile.
 */

#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#if defined(__FAST_MATH__)
#error "simd/nav/_astar.c must not be compiled with -ffast-math"
#endif

#define SQRT2 1.4142135623730951 /* the double nearest sqrt(2), as Python's math.sqrt(2.0) */
/* nodes are int32 indices and the push counter a uint32 (at most 8 pushes a cell): a bound far
 * above any costmap (16 384 x 16 384) */
#define MAX_CELLS (1 << 28)

/* a cell's state in the search: not reached yet, reached (g and parent set), expanded, or blocked */
enum { NEW, OPEN, CLOSED, BLOCKED };

/* An open-list entry: 16 bytes, so that four children share a cache line.  h is not stored: it
 * is a function of the node, worked out again on the rare ties in f. */
typedef struct {
    double f;
    uint32_t order; /* the push counter: the last tie-breaker, so keys never tie */
    int32_t node;   /* index in the padded grid */
} Entry;

/* A 4-ary min-heap ordered by (f, h, order), and what it needs to find h. */
typedef struct {
    Entry *items;
    size_t len, cap;
    int32_t width, goal_row, goal_col; /* of the padded grid */
    int diagonal;
} Heap;

/* h of the cell at (r, c) of the padded grid */
static inline double heuristic_at(const Heap *q, int32_t r, int32_t c) {
    int32_t dr = r > q->goal_row ? r - q->goal_row : q->goal_row - r;
    int32_t dc = c > q->goal_col ? c - q->goal_col : q->goal_col - c;
    if (!q->diagonal) return (double)(dr + dc);
    int32_t lo = dr < dc ? dr : dc, hi = dr < dc ? dc : dr;
    return (double)(hi - lo) + SQRT2 * (double)lo;
}

static inline double heuristic(const Heap *q, int32_t node) { return heuristic_at(q, node / q->width, node % q->width); }

static inline int before(const Heap *q, const Entry *a, const Entry *b) {
    if (a->f != b->f) return a->f < b->f;
    double ha = heuristic(q, a->node), hb = heuristic(q, b->node);
    if (ha != hb) return ha < hb;
    return a->order < b->order;
}

static int heap_push(Heap *q, Entry e) {
    if (q->len == q->cap) {
        size_t cap = q->cap ? 2 * q->cap : 4096;
        Entry *grown = realloc(q->items, cap * sizeof(Entry));
        if (grown == NULL) return -1;
        q->items = grown;
        q->cap = cap;
    }
    size_t i = q->len++;
    while (i > 0) {
        size_t up = (i - 1) / 4;
        if (!before(q, &e, &q->items[up])) break;
        q->items[i] = q->items[up];
        i = up;
    }
    q->items[i] = e;
    return 0;
}

/* The least of the children items[first:end]: by f alone, without branches the CPU would
 * mispredict half the time, unless the least f occurs twice (then by the full order). */
static inline size_t min_child(const Heap *q, size_t first, size_t end) {
    size_t best = first;
    double least = q->items[first].f;
    int tie = 0;
    for (size_t k = first + 1; k < end; k++) {
        double f = q->items[k].f;
        tie |= f == least; /* whatever ties the final least meets it here, before or after it came */
        int less = f < least;
        best = less ? k : best;
        least = less ? f : least;
    }
    if (tie) {
        best = first;
        for (size_t k = first + 1; k < end; k++) {
            if (before(q, &q->items[k], &q->items[best])) best = k;
        }
    }
    return best;
}

static Entry heap_pop(Heap *q) {
    Entry top = q->items[0];
    Entry last = q->items[--q->len];
    size_t i = 0, n = q->len;
    for (;;) {
        size_t first = 4 * i + 1;
        if (first >= n) break;
        size_t best = min_child(q, first, first + 4 < n ? first + 4 : n);
        if (!before(q, &q->items[best], &last)) break;
        q->items[i] = q->items[best];
        i = best;
    }
    if (n > 0) q->items[i] = last;
    return top;
}

/* (row step, col step, length) in the reference's order; the first four are the orthogonal ones */
static const struct {
    int dr, dc;
    double length;
} MOVES[8] = {
    {-1, 0, 1.0}, {1, 0, 1.0}, {0, -1, 1.0}, {0, 1, 1.0},
    {-1, -1, SQRT2}, {-1, 1, SQRT2}, {1, -1, SQRT2}, {1, 1, SQRT2},
};

typedef struct {
    /* inputs */
    const float *cost;
    Py_ssize_t rows, cols;
    Py_ssize_t start_row, start_col, goal_row, goal_col;
    int diagonal;
    /* outputs: status 1 found (path/path_len set, path malloc'd), 0 no path, -1 out of memory */
    int status;
    int32_t *path;
    Py_ssize_t path_len;
} Search;

/* The search.  Nodes are indices in the grid padded with one blocked cell all round, which only
 * ``state`` covers (no bounds checks); costs are read from the caller's grid.  g and parent are
 * left unset until a cell is first reached (state NEW -> OPEN), so that a short search touches
 * little memory.  Runs without the GIL: touches no Python object. */
static void search(Search *s) {
    Py_ssize_t width = s->cols + 2, cells = (s->rows + 2) * width;
    double *g = malloc((size_t)cells * sizeof(double));
    int32_t *parent = malloc((size_t)cells * sizeof(int32_t));
    unsigned char *state = malloc((size_t)cells);
    int32_t width32 = (int32_t)width, cols32 = (int32_t)s->cols;
    Heap open = {NULL, 0, 0, width32, (int32_t)s->goal_row + 1, (int32_t)s->goal_col + 1, s->diagonal};
    s->status = -1;
    s->path = NULL;
    if (g == NULL || parent == NULL || state == NULL) goto done;
    memset(state, BLOCKED, (size_t)cells);
    for (Py_ssize_t r = 0; r < s->rows; r++) {
        const float *src = s->cost + r * s->cols;
        unsigned char *mark = state + (r + 1) * width + 1;
        for (Py_ssize_t c = 0; c < s->cols; c++) mark[c] = isinf(src[c]) ? BLOCKED : NEW;
    }
    int32_t step[8], cost_step[8]; /* a move in the padded grid, and in the caller's */
    for (int k = 0; k < 8; k++) {
        step[k] = MOVES[k].dr * width32 + MOVES[k].dc;
        cost_step[k] = MOVES[k].dr * cols32 + MOVES[k].dc;
    }
    int moves = s->diagonal ? 8 : 4;
    int32_t start = (int32_t)((s->start_row + 1) * width + s->start_col + 1);
    int32_t goal = (int32_t)((s->goal_row + 1) * width + s->goal_col + 1);
    s->status = 0;
    if (state[start] == BLOCKED || state[goal] == BLOCKED) goto done;
    uint32_t pushes = 0; /* at most 8 a cell plus one: below 2**32 (plan() caps the cells) */
    double h0 = heuristic(&open, start);
    g[start] = 0.0;
    parent[start] = -1;
    state[start] = OPEN;
    if (heap_push(&open, (Entry){0.0 + h0, pushes++, start}) < 0) goto oom;
    int found = 0;
    while (open.len > 0) {
        int32_t a = heap_pop(&open).node;
        if (state[a] == CLOSED) continue; /* a stale entry: reached cheaper since */
        if (a == goal) {
            found = 1;
            break;
        }
        state[a] = CLOSED;
        int32_t r = a / width32, c = a % width32, at = (r - 1) * cols32 + (c - 1);
        double ga = g[a], ca = (double)s->cost[at];
        for (int k = 0; k < moves; k++) {
            int32_t b = a + step[k];
            unsigned char seen = state[b];
            if (seen == BLOCKED || seen == CLOSED) continue;
            if (k >= 4 && (state[a + MOVES[k].dr * width32] == BLOCKED || state[a + MOVES[k].dc] == BLOCKED)) continue;
            double gb = ga + MOVES[k].length * (ca + (double)s->cost[at + cost_step[k]]) / 2.0;
            if (seen == NEW || gb < g[b]) { /* NEW: g is +inf in the reference */
                g[b] = gb;
                parent[b] = a;
                state[b] = OPEN;
                double f = gb + heuristic_at(&open, r + MOVES[k].dr, c + MOVES[k].dc);
                if (heap_push(&open, (Entry){f, pushes++, b}) < 0) goto oom;
            }
        }
    }
    if (found) {
        Py_ssize_t len = 1;
        for (int32_t v = goal; v != start; v = parent[v]) len++;
        s->path = malloc((size_t)len * 2 * sizeof(int32_t));
        if (s->path == NULL) goto oom;
        Py_ssize_t i = len;
        for (int32_t v = goal;; v = parent[v]) {
            i--;
            s->path[2 * i] = v / width32 - 1;
            s->path[2 * i + 1] = v % width32 - 1;
            if (v == start) break;
        }
        s->path_len = len;
        s->status = 1;
    }
    goto done;
oom:
    s->status = -1;
done:
    free(open.items);
    free(state);
    free(parent);
    free(g);
}

static PyObject *plan(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *grid;
    Search s = {0};
    if (!PyArg_ParseTuple(args, "Onnnnp:plan", &grid, &s.start_row, &s.start_col, &s.goal_row, &s.goal_col,
                          &s.diagonal)) {
        return NULL;
    }
    Py_buffer view;
    if (PyObject_GetBuffer(grid, &view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0) {
        PyErr_SetString(PyExc_TypeError, "cost must be a C-contiguous buffer");
        return NULL;
    }
    const char *f = view.format ? view.format : "B";
    if (*f == '<' || *f == '=' || *f == '@') f++;
    if (view.ndim != 2 || view.itemsize != 4 || f[0] != 'f' || f[1] != '\0') {
        PyBuffer_Release(&view);
        PyErr_SetString(PyExc_TypeError, "cost must be a 2-D float32 buffer");
        return NULL;
    }
    s.cost = view.buf;
    s.rows = view.shape[0];
    s.cols = view.shape[1];
    if (s.start_row < 0 || s.start_row >= s.rows || s.start_col < 0 || s.start_col >= s.cols || s.goal_row < 0 ||
        s.goal_row >= s.rows || s.goal_col < 0 || s.goal_col >= s.cols) {
        PyBuffer_Release(&view);
        PyErr_SetString(PyExc_ValueError, "start and goal must lie inside the grid");
        return NULL;
    }
    if ((s.rows + 2) > MAX_CELLS / (s.cols + 2)) {
        PyBuffer_Release(&view);
        PyErr_SetString(PyExc_ValueError, "the grid has too many cells (at most 2**28 with its border)");
        return NULL;
    }
    Py_BEGIN_ALLOW_THREADS;
    search(&s);
    Py_END_ALLOW_THREADS;
    PyBuffer_Release(&view);
    if (s.status < 0) return PyErr_NoMemory();
    if (s.status == 0) Py_RETURN_NONE;
    PyObject *out = PyByteArray_FromStringAndSize((const char *)s.path, s.path_len * 2 * (Py_ssize_t)sizeof(int32_t));
    free(s.path);
    return out;
}

static PyMethodDef methods[] = {
    {"plan", plan, METH_VARARGS,
     "plan(cost, start_row, start_col, goal_row, goal_col, diagonal) -> bytearray | None\n--\n\n"
     "The cheapest path as int32 (row, col) pairs, or None (see the module comment).  "
     "The GIL is released while it searches."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "simd.nav._astar", "A* on a grid costmap, compiled (twin of simd/nav/grid_search.py).",
    -1, methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__astar(void) { return PyModule_Create(&module); }
