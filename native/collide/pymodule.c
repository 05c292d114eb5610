/* pymodule.c - the Python face of the collision kernels, `tearcloth._collide`.
 *
 * CPython limited API 3.11 (abi3), like `tearcloth._native`: one build serves every Blender from
 * 4.2 on. Arrays come in through the buffer protocol (numpy arrays, zero copy) and results go into
 * arrays the caller allocated, so this module never depends on numpy's C API. Every argument is
 * checked here before a kernel runs - dtype, number of dimensions, shape against the other
 * arguments, C-contiguity, writability of outputs, and that no output overlaps another argument -
 * and the kernels check every index they read (collide.h). Wrong types raise TypeError, wrong
 * shapes or values ValueError, out-of-range indices IndexError. The GIL is released while a kernel
 * runs.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include "collide.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ---------------------------------------------------------------- arguments */

enum { F64, F32, I64, I32, BOOL, I8 };
static const char *KIND_NAME[] = {"float64", "float32", "int64", "int32", "bool", "int8"};

typedef struct {
    Py_buffer v;
    int held, out;
    const char *name;
} Buf;

#define MAXBUF 48
typedef struct {
    Buf b[MAXBUF];
    int n;
} Ctx;

static void ctx_release(Ctx *c)
{
    for (int i = 0; i < c->n; i++)
        if (c->b[i].held) {
            PyBuffer_Release(&c->b[i].v);
            c->b[i].held = 0;
        }
    c->n = 0;
}

static int format_ok(const char *f, int kind, Py_ssize_t itemsize)
{
    if (!f) f = "B";
    if (*f == '<' || *f == '=' || *f == '@' || *f == '|') f++;
    if (f[0] == 0 || f[1] != 0) return 0;
    char ch = f[0];
    switch (kind) {
    case F64: return ch == 'd' && itemsize == 8;
    case F32: return ch == 'f' && itemsize == 4;
    case I64: return (ch == 'q' || ch == 'l' || ch == 'n') && itemsize == 8;
    case I32: return (ch == 'i' || ch == 'l') && itemsize == 4;
    case BOOL: return (ch == '?' || ch == 'B') && itemsize == 1;
    case I8: return ch == 'b' && itemsize == 1;
    }
    return 0;
}

static void shape_text(char *s, size_t size, int ndim, const Py_ssize_t *d)
{
    size_t k = (size_t)snprintf(s, size, "(");
    for (int i = 0; i < ndim && k < size; i++)
        k += (size_t)snprintf(s + k, size - k, i + 1 < ndim ? "%zd, " : (ndim == 1 ? "%zd," : "%zd"), d[i]);
    if (k < size) snprintf(s + k, size - k, ")");
}

/* An array argument: dtype `kind`, `ndim` dimensions, each of the given size (-1: any).
 * out: must be writable. Returns NULL with an exception set on failure. */
static Buf *arg(Ctx *c, PyObject *o, const char *name, int kind, int out, int ndim, Py_ssize_t d0, Py_ssize_t d1,
                Py_ssize_t d2)
{
    if (c->n >= MAXBUF) {
        PyErr_SetString(PyExc_RuntimeError, "too many array arguments");
        return NULL;
    }
    Buf *b = &c->b[c->n];
    memset(b, 0, sizeof *b);
    b->name = name;
    b->out = out;
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (out ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(o, &b->v, flags) < 0) {
        PyObject *t, *v, *tb;
        PyErr_Fetch(&t, &v, &tb);
        PyErr_Format(PyExc_TypeError, "%s must be a C-contiguous%s %s numpy array (%S)", name, out ? ", writable" : "",
                     KIND_NAME[kind], v ? v : Py_None);
        Py_XDECREF(t);
        Py_XDECREF(v);
        Py_XDECREF(tb);
        return NULL;
    }
    b->held = 1;
    c->n++;
    if (!format_ok(b->v.format, kind, b->v.itemsize)) {
        PyErr_Format(PyExc_TypeError, "%s must have dtype %s (got buffer format '%s', item size %zd)", name,
                     KIND_NAME[kind], b->v.format ? b->v.format : "B", b->v.itemsize);
        return NULL;
    }
    Py_ssize_t want[3] = {d0, d1, d2};
    int bad = b->v.ndim != ndim || !b->v.shape;
    for (int i = 0; !bad && i < ndim; i++) bad = want[i] >= 0 && b->v.shape[i] != want[i];
    if (bad) {
        char got[96], exp[96] = "(";
        if (b->v.shape)
            shape_text(got, sizeof got, b->v.ndim, b->v.shape);
        else
            snprintf(got, sizeof got, "no shape");
        size_t k = 1;
        for (int i = 0; i < ndim && k < sizeof exp; i++) {
            const char *sep = i + 1 < ndim ? ", " : (ndim == 1 ? "," : "");
            k += want[i] >= 0 ? (size_t)snprintf(exp + k, sizeof exp - k, "%zd%s", want[i], sep)
                              : (size_t)snprintf(exp + k, sizeof exp - k, "any%s", sep);
        }
        if (k < sizeof exp) snprintf(exp + k, sizeof exp - k, ")");
        PyErr_Format(PyExc_ValueError, "%s must have shape %s, got %s", name, exp, got);
        return NULL;
    }
    return b;
}

/* Optional array: None gives an empty Buf whose data pointer is NULL. */
static Buf *opt(Ctx *c, PyObject *o, const char *name, int kind, int out, int ndim, Py_ssize_t d0, Py_ssize_t d1,
                Py_ssize_t d2)
{
    if (o != Py_None) return arg(c, o, name, kind, out, ndim, d0, d1, d2);
    if (c->n >= MAXBUF) {
        PyErr_SetString(PyExc_RuntimeError, "too many array arguments");
        return NULL;
    }
    Buf *b = &c->b[c->n++];
    memset(b, 0, sizeof *b);
    b->name = name;
    return b;
}

#define DATA(b) ((b)->v.buf)
#define ROWS(b) ((b)->v.shape[0])

/* No output may share memory with any other argument: a kernel reads its inputs while writing. */
static int no_overlap(Ctx *c)
{
    for (int i = 0; i < c->n; i++) {
        Buf *a = &c->b[i];
        if (!a->held || !a->out || a->v.len == 0) continue;
        const char *a0 = a->v.buf, *a1 = a0 + a->v.len;
        for (int j = 0; j < c->n; j++) {
            Buf *b = &c->b[j];
            if (j == i || !b->held || b->v.len == 0) continue;
            const char *b0 = b->v.buf, *b1 = b0 + b->v.len;
            if (a0 < b1 && b0 < a1) {
                PyErr_Format(PyExc_ValueError, "output %s shares memory with %s: pass separate arrays", a->name, b->name);
                return -1;
            }
        }
    }
    return 0;
}

static PyObject *kernel_error(const tcc_error *e)
{
    if (e->code == TCC_ERR_NOMEM) return PyErr_NoMemory();
    PyErr_SetString(e->code == TCC_ERR_INDEX ? PyExc_IndexError : PyExc_ValueError, e->what);
    return NULL;
}

static int finite_param(double x, const char *name, int positive)
{
    if (!isfinite(x) || (positive && x < 0)) {
        char msg[160];
        snprintf(msg, sizeof msg, "%s must be a finite%s number, got %g", name, positive ? " non-negative" : "", x);
        PyErr_SetString(PyExc_ValueError, msg);
        return -1;
    }
    return 0;
}

#define TRY(x)                                                                                                        \
    if (!(x)) goto fail
#define RUN(call)                                                                                                     \
    do {                                                                                                              \
        Py_BEGIN_ALLOW_THREADS rc = (call);                                                                           \
        Py_END_ALLOW_THREADS                                                                                          \
    } while (0)

/* A mesh from (vertices (nv,3) f64, triangles (nt,3) i64, adjacency (nt,3) i64 | None, flip (nt,3) bool | None). */
static int mesh_args(Ctx *c, tcc_mesh *m, PyObject *x, PyObject *tri, PyObject *adj, PyObject *flip)
{
    Buf *bx = arg(c, x, "target vertices", F64, 0, 2, -1, 3, 0);
    if (!bx) return -1;
    Buf *bt = arg(c, tri, "target triangles", I64, 0, 2, -1, 3, 0);
    if (!bt) return -1;
    Py_ssize_t nt = ROWS(bt);
    Buf *ba = opt(c, adj, "adjacency", I64, 0, 2, nt, 3, 0);
    if (!ba) return -1;
    Buf *bf = opt(c, flip, "flip", BOOL, 0, 2, nt, 3, 0);
    if (!bf) return -1;
    m->x = DATA(bx);
    m->nv = ROWS(bx);
    m->tri = DATA(bt);
    m->nt = nt;
    m->adj = DATA(ba);
    m->flip = DATA(bf);
    return 0;
}

static int ring_arg(Ctx *c, tcc_ring *r, PyObject *o)
{
    Buf *b = opt(c, o, "ring", I64, 0, 2, -1, -1, 0);
    if (!b) return -1;
    r->table = DATA(b);
    r->rows = b->held ? ROWS(b) : 0;
    r->width = b->held ? b->v.shape[1] : 0;
    return 0;
}

/* ---------------------------------------------------------------- functions */

static PyObject *py_vertex_normals(PyObject *self, PyObject *args)
{
    PyObject *a[4];
    if (!PyArg_ParseTuple(args, "OOOO:vertex_normals", &a[0], &a[1], &a[2], &a[3])) return NULL;
    Ctx c = {.n = 0};
    Buf *x, *t, *out, *has;
    TRY(x = arg(&c, a[0], "positions", F64, 0, 2, -1, 3, 0));
    Py_ssize_t n = ROWS(x);
    TRY(t = arg(&c, a[1], "triangles", I64, 0, 2, -1, 3, 0));
    TRY(out = arg(&c, a[2], "normals", F64, 1, 2, n, 3, 0));
    TRY(has = arg(&c, a[3], "has_normal", BOOL, 1, 1, n, 0, 0));
    if (no_overlap(&c)) goto fail;
    tcc_mesh m = {DATA(x), n, DATA(t), ROWS(t), NULL, NULL};
    tcc_error err = {0};
    int rc;
    RUN(tcc_vertex_normals(&m, DATA(out), DATA(has), &err));
    ctx_release(&c);
    if (rc) return kernel_error(&err);
    Py_RETURN_NONE;
fail:
    ctx_release(&c);
    return NULL;
}

static PyObject *py_cluster_normals(PyObject *self, PyObject *args)
{
    PyObject *a[10];
    a[9] = Py_None;
    if (!PyArg_ParseTuple(args, "OOOOOOOOO|O:cluster_normals", &a[0], &a[1], &a[2], &a[3], &a[4], &a[5], &a[6], &a[7],
                          &a[8], &a[9]))
        return NULL;
    Ctx c = {.n = 0};
    Buf *x, *t, *vp, *vt, *order, *ptr, *cl, *out, *has, *done;
    TRY(x = arg(&c, a[0], "positions", F64, 0, 2, -1, 3, 0));
    Py_ssize_t n = ROWS(x);
    TRY(t = arg(&c, a[1], "triangles", I64, 0, 2, -1, 3, 0));
    TRY(vp = arg(&c, a[2], "vt_ptr", I64, 0, 1, n + 1, 0, 0));
    TRY(vt = arg(&c, a[3], "vt_tri", I64, 0, 1, -1, 0, 0));
    TRY(order = arg(&c, a[4], "order", I64, 0, 1, -1, 0, 0));
    TRY(ptr = arg(&c, a[5], "ptr", I64, 0, 1, -1, 0, 0));
    if (ROWS(ptr) < 1) {
        PyErr_SetString(PyExc_ValueError, "ptr must hold the k + 1 cluster bounds (at least one entry)");
        goto fail;
    }
    TRY(cl = arg(&c, a[6], "clusters", I64, 0, 1, -1, 0, 0));
    TRY(out = arg(&c, a[7], "normals", F64, 1, 2, n, 3, 0));
    TRY(has = arg(&c, a[8], "has_normal", BOOL, 1, 1, n, 0, 0));
    TRY(done = opt(&c, a[9], "done", BOOL, 1, 1, ROWS(ptr) - 1, 0, 0));
    if (no_overlap(&c)) goto fail;
    tcc_mesh m = {DATA(x), n, DATA(t), ROWS(t), NULL, NULL};
    tcc_error err = {0};
    int rc;
    RUN(tcc_cluster_normals(&m, DATA(vp), DATA(vt), ROWS(vt), DATA(order), ROWS(order), DATA(ptr), ROWS(ptr) - 1,
                            DATA(cl), ROWS(cl), DATA(out), DATA(has), DATA(done), &err));
    ctx_release(&c);
    if (rc) return kernel_error(&err);
    Py_RETURN_NONE;
fail:
    ctx_release(&c);
    return NULL;
}

static PyObject *py_cluster_motion(PyObject *self, PyObject *args)
{
    PyObject *a[6];
    if (!PyArg_ParseTuple(args, "OOOOOO:cluster_motion", &a[0], &a[1], &a[2], &a[3], &a[4], &a[5])) return NULL;
    Ctx c = {.n = 0};
    Buf *x, *p, *order, *ptr, *avg, *dev;
    TRY(x = arg(&c, a[0], "positions", F64, 0, 2, -1, 3, 0));
    Py_ssize_t n = ROWS(x);
    TRY(p = arg(&c, a[1], "previous", F64, 0, 2, n, 3, 0));
    TRY(order = arg(&c, a[2], "order", I64, 0, 1, -1, 0, 0));
    TRY(ptr = arg(&c, a[3], "ptr", I64, 0, 1, -1, 0, 0));
    Py_ssize_t k = ROWS(ptr) - 1;
    if (k < 0) {
        PyErr_SetString(PyExc_ValueError, "ptr must hold the k + 1 cluster bounds (at least one entry)");
        goto fail;
    }
    TRY(avg = arg(&c, a[4], "avg", F64, 1, 2, k, 3, 0));
    TRY(dev = arg(&c, a[5], "dev", F64, 1, 1, k, 0, 0));
    if (no_overlap(&c)) goto fail;
    tcc_error err = {0};
    int rc;
    RUN(tcc_cluster_motion(DATA(x), DATA(p), n, DATA(order), ROWS(order), DATA(ptr), k, DATA(avg), DATA(dev), &err));
    ctx_release(&c);
    if (rc) return kernel_error(&err);
    Py_RETURN_NONE;
fail:
    ctx_release(&c);
    return NULL;
}

static PyObject *py_cluster_boxes(PyObject *self, PyObject *args)
{
    PyObject *a[6];
    double inflate;
    if (!PyArg_ParseTuple(args, "OOOdOO:cluster_boxes", &a[0], &a[1], &a[2], &inflate, &a[4], &a[5])) return NULL;
    if (finite_param(inflate, "inflate", 0)) return NULL;
    Ctx c = {.n = 0};
    Buf *x, *index, *ptr, *lo, *hi;
    TRY(x = arg(&c, a[0], "positions", F64, 0, 2, -1, 3, 0));
    TRY(index = arg(&c, a[1], "index", I64, 0, 1, -1, 0, 0));
    TRY(ptr = arg(&c, a[2], "ptr", I64, 0, 1, -1, 0, 0));
    Py_ssize_t k = ROWS(ptr) - 1;
    if (k < 0) {
        PyErr_SetString(PyExc_ValueError, "ptr must hold the k + 1 box bounds (at least one entry)");
        goto fail;
    }
    TRY(lo = arg(&c, a[4], "lo", F64, 1, 2, k, 3, 0));
    TRY(hi = arg(&c, a[5], "hi", F64, 1, 2, k, 3, 0));
    if (no_overlap(&c)) goto fail;
    tcc_error err = {0};
    int rc;
    RUN(tcc_cluster_boxes(DATA(x), ROWS(x), DATA(index), ROWS(index), DATA(ptr), k, inflate, DATA(lo), DATA(hi), &err));
    ctx_release(&c);
    if (rc) return kernel_error(&err);
    Py_RETURN_NONE;
fail:
    ctx_release(&c);
    return NULL;
}

static PyObject *py_box_pairs(PyObject *self, PyObject *args)
{
    PyObject *a[7];
    int self_pairs;
    if (!PyArg_ParseTuple(args, "OOOOpOO:box_pairs", &a[0], &a[1], &a[2], &a[3], &self_pairs, &a[5], &a[6]))
        return NULL;
    Ctx c = {.n = 0};
    Buf *la, *ha, *lb, *hb, *oi, *oj;
    TRY(la = arg(&c, a[0], "lo_a", F64, 0, 2, -1, 3, 0));
    TRY(ha = arg(&c, a[1], "hi_a", F64, 0, 2, ROWS(la), 3, 0));
    TRY(lb = arg(&c, a[2], "lo_b", F64, 0, 2, -1, 3, 0));
    TRY(hb = arg(&c, a[3], "hi_b", F64, 0, 2, ROWS(lb), 3, 0));
    if (self_pairs && ROWS(la) != ROWS(lb)) {
        PyErr_SetString(PyExc_ValueError, "self pairs need the same boxes on both sides");
        goto fail;
    }
    TRY(oi = arg(&c, a[5], "i", I64, 1, 1, -1, 0, 0));
    TRY(oj = arg(&c, a[6], "j", I64, 1, 1, ROWS(oi), 0, 0));
    if (no_overlap(&c)) goto fail;
    tcc_idx count = 0;
    Py_BEGIN_ALLOW_THREADS tcc_box_pairs(DATA(la), DATA(ha), ROWS(la), DATA(lb), DATA(hb), ROWS(lb), self_pairs,
                                         DATA(oi), DATA(oj), ROWS(oi), &count);
    Py_END_ALLOW_THREADS ctx_release(&c);
    return PyLong_FromLongLong(count);
fail:
    ctx_release(&c);
    return NULL;
}

static PyObject *py_relative_measure(PyObject *self, PyObject *args)
{
    PyObject *a[16];
    double threshold, lookahead = 0.0;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOdOOOOO|d:relative_measure", &a[0], &a[1], &a[2], &a[3], &a[4], &a[5],
                          &a[6], &a[7], &a[8], &a[9], &threshold, &a[11], &a[12], &a[13], &a[14], &a[15], &lookahead))
        return NULL;
    if (isnan(threshold) || !isfinite(lookahead) || lookahead < 0) {
        PyErr_SetString(PyExc_ValueError, "threshold must be a number and lookahead a finite number of steps >= 0");
        return NULL;
    }
    Ctx c = {.n = 0};
    Buf *ok, *oa, *od, *pi, *pj, *aa, *da, *ab, *db, *force, *keys, *ra, *rd, *amp, *full;
    TRY(ok = arg(&c, a[0], "old_keys", I64, 0, 1, -1, 0, 0));
    Py_ssize_t nold = ROWS(ok);
    TRY(oa = arg(&c, a[1], "old_avg", F64, 0, 2, nold, 3, 0));
    TRY(od = arg(&c, a[2], "old_dev", F64, 0, 1, nold, 0, 0));
    TRY(pi = arg(&c, a[3], "i", I64, 0, 1, -1, 0, 0));
    Py_ssize_t np_ = ROWS(pi);
    TRY(pj = arg(&c, a[4], "j", I64, 0, 1, np_, 0, 0));
    TRY(aa = arg(&c, a[5], "avg_a", F64, 0, 2, -1, 3, 0));
    TRY(da = arg(&c, a[6], "dev_a", F64, 0, 1, ROWS(aa), 0, 0));
    TRY(ab = arg(&c, a[7], "avg_b", F64, 0, 2, -1, 3, 0));
    TRY(db = arg(&c, a[8], "dev_b", F64, 0, 1, ROWS(ab), 0, 0));
    TRY(force = opt(&c, a[9], "force", BOOL, 0, 1, np_, 0, 0));
    TRY(keys = arg(&c, a[11], "keys", I64, 1, 1, np_, 0, 0));
    TRY(ra = arg(&c, a[12], "rel_avg", F64, 1, 2, np_, 3, 0));
    TRY(rd = arg(&c, a[13], "rel_dev", F64, 1, 1, np_, 0, 0));
    TRY(amp = arg(&c, a[14], "amplitude", F64, 1, 1, np_, 0, 0));
    TRY(full = arg(&c, a[15], "full", BOOL, 1, 1, np_, 0, 0));
    if (no_overlap(&c)) goto fail;
    tcc_error err = {0};
    tcc_idx nfull = 0;
    int rc;
    RUN(tcc_relative_measure(DATA(ok), DATA(oa), DATA(od), nold, DATA(pi), DATA(pj), np_, DATA(aa), DATA(da), ROWS(aa),
                             DATA(ab), DATA(db), ROWS(ab), DATA(force), threshold, lookahead, DATA(keys), DATA(ra), DATA(rd),
                             DATA(amp), DATA(full), &nfull, &err));
    ctx_release(&c);
    if (rc) return kernel_error(&err);
    return PyLong_FromLongLong(nfull);
fail:
    ctx_release(&c);
    return NULL;
}

static PyObject *py_rigid_fit(PyObject *self, PyObject *args)
{
    PyObject *a[8];
    Py_ssize_t row;
    if (!PyArg_ParseTuple(args, "OOOOOOOn:rigid_fit", &a[0], &a[1], &a[2], &a[3], &a[4], &a[5], &a[6], &row))
        return NULL;
    Ctx c = {.n = 0};
    Buf *x, *t, *ref, *tris, *R, *cen, *rc_;
    TRY(x = arg(&c, a[0], "positions", F64, 0, 2, -1, 3, 0));
    TRY(t = arg(&c, a[1], "triangles", I64, 0, 2, -1, 3, 0));
    TRY(tris = arg(&c, a[3], "scene_triangles", I64, 0, 1, -1, 0, 0));
    TRY(ref = arg(&c, a[2], "ref_corners", F64, 0, 3, ROWS(tris), 3, 3));
    TRY(R = arg(&c, a[4], "R", F64, 1, 3, -1, 3, 3));
    Py_ssize_t k = ROWS(R);
    TRY(cen = arg(&c, a[5], "centre", F64, 1, 2, k, 3, 0));
    TRY(rc_ = arg(&c, a[6], "ref_centre", F64, 1, 2, k, 3, 0));
    if (row < 0 || row >= k) {
        PyErr_Format(PyExc_IndexError, "row %zd is not in [0, %zd)", row, k);
        goto fail;
    }
    if (no_overlap(&c)) goto fail;
    tcc_mesh m = {DATA(x), ROWS(x), DATA(t), ROWS(t), NULL, NULL};
    tcc_error err = {0};
    double resid2 = 0.0;
    int rc;
    RUN(tcc_rigid_fit(&m, DATA(ref), DATA(tris), ROWS(tris), (double *)DATA(R) + 9 * row,
                      (double *)DATA(cen) + 3 * row, (double *)DATA(rc_) + 3 * row, &resid2, &err));
    ctx_release(&c);
    if (rc) return kernel_error(&err);
    return PyFloat_FromDouble(resid2);
fail:
    ctx_release(&c);
    return NULL;
}

static PyObject *py_rigid_fit_many(PyObject *self, PyObject *args)
{
    PyObject *a[10];
    if (!PyArg_ParseTuple(args, "OOOOOOOOOO:rigid_fit_many", &a[0], &a[1], &a[2], &a[3], &a[4], &a[5], &a[6], &a[7],
                          &a[8], &a[9]))
        return NULL;
    Ctx c = {.n = 0};
    Buf *x, *t, *ptr, *tris, *ref, *cl, *R, *cen, *rcen, *res;
    TRY(x = arg(&c, a[0], "positions", F64, 0, 2, -1, 3, 0));
    TRY(t = arg(&c, a[1], "triangles", I64, 0, 2, -1, 3, 0));
    TRY(ptr = arg(&c, a[2], "scene_ptr", I64, 0, 1, -1, 0, 0));
    Py_ssize_t k = ROWS(ptr) - 1;
    if (k < 0) {
        PyErr_SetString(PyExc_ValueError, "scene_ptr must hold the k + 1 scene bounds (at least one entry)");
        goto fail;
    }
    TRY(tris = arg(&c, a[3], "scene_triangles", I64, 0, 1, -1, 0, 0));
    TRY(ref = arg(&c, a[4], "ref_corners", F64, 0, 3, ROWS(tris), 3, 3));
    TRY(cl = arg(&c, a[5], "clusters", I64, 0, 1, -1, 0, 0));
    Py_ssize_t q = ROWS(cl);
    TRY(R = arg(&c, a[6], "R", F64, 1, 3, k, 3, 3));
    TRY(cen = arg(&c, a[7], "centre", F64, 1, 2, k, 3, 0));
    TRY(rcen = arg(&c, a[8], "ref_centre", F64, 1, 2, k, 3, 0));
    TRY(res = arg(&c, a[9], "resid2", F64, 1, 1, q, 0, 0));
    if (no_overlap(&c)) goto fail;
    tcc_mesh m = {DATA(x), ROWS(x), DATA(t), ROWS(t), NULL, NULL};
    tcc_error err = {0};
    int rc = TCC_OK;
    const tcc_idx *pp = DATA(ptr), *cc = DATA(cl), *tt = DATA(tris);
    const double *rf = DATA(ref);
    double *Rp = DATA(R), *cp = DATA(cen), *rp = DATA(rcen), *out = DATA(res);
    Py_ssize_t nsc = ROWS(tris);
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t g = 0; g < q && rc == TCC_OK; g++) {
        tcc_idx b = cc[g];
        if (b < 0 || b >= k) {
            rc = tcc_fail(&err, TCC_ERR_INDEX, "cluster %lld is not in [0, %lld)", (long long)b, (long long)k);
            break;
        }
        tcc_idx s0 = pp[b], s1 = pp[b + 1];
        if (s0 < 0 || s1 < s0 || s1 > nsc) {
            rc = tcc_fail(&err, TCC_ERR_INDEX, "scene %lld spans [%lld, %lld), outside the %lld listed", (long long)b,
                          (long long)s0, (long long)s1, (long long)nsc);
            break;
        }
        rc = tcc_rigid_fit(&m, rf + 9 * s0, tt + s0, s1 - s0, Rp + 9 * b, cp + 3 * b, rp + 3 * b, out + g, &err);
    }
    Py_END_ALLOW_THREADS
    ctx_release(&c);
    if (rc) return kernel_error(&err);
    Py_RETURN_NONE;
fail:
    ctx_release(&c);
    return NULL;
}

static PyObject *py_walk(PyObject *self, PyObject *args)
{
    PyObject *a[16];
    int max_steps;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOiOOOOO:walk", &a[0], &a[1], &a[2], &a[3], &a[4], &a[5], &a[6], &a[7], &a[8],
                          &a[9], &max_steps, &a[11], &a[12], &a[13], &a[14], &a[15]))
        return NULL;
    if (max_steps < 0 || max_steps > 1000) {
        PyErr_Format(PyExc_ValueError, "max_steps must be in [0, 1000], got %d", max_steps);
        return NULL;
    }
    Ctx c = {.n = 0};
    Buf *x, *nrm, *rv, *rs, *st, *ot, *otp, *ou, *ov, *of;
    tcc_mesh m;
    tcc_ring ring;
    TRY(x = arg(&c, a[0], "positions", F64, 0, 2, -1, 3, 0));
    Py_ssize_t n = ROWS(x);
    TRY(nrm = arg(&c, a[1], "normals", F64, 0, 2, n, 3, 0));
    TRY(rv = arg(&c, a[2], "ray_vertex", I64, 0, 1, -1, 0, 0));
    Py_ssize_t k = ROWS(rv);
    TRY(rs = arg(&c, a[3], "ray_slot", I64, 0, 1, k, 0, 0));
    TRY(st = arg(&c, a[4], "start", I64, 0, 1, k, 0, 0));
    if (mesh_args(&c, &m, a[5], a[6], a[7], a[8])) goto fail;
    if (ring_arg(&c, &ring, a[9])) goto fail;
    TRY(ot = arg(&c, a[11], "tri", I64, 1, 1, k, 0, 0));
    TRY(otp = arg(&c, a[12], "t", F64, 1, 1, k, 0, 0));
    TRY(ou = arg(&c, a[13], "u", F64, 1, 1, k, 0, 0));
    TRY(ov = arg(&c, a[14], "v", F64, 1, 1, k, 0, 0));
    TRY(of = arg(&c, a[15], "flips", BOOL, 1, 1, k, 0, 0));
    if (no_overlap(&c)) goto fail;
    tcc_hits out = {DATA(ot), DATA(otp), DATA(ou), DATA(ov), DATA(of)};
    tcc_error err = {0};
    int rc;
    RUN(tcc_walk(DATA(x), DATA(nrm), n, DATA(rv), DATA(rs), DATA(st), k, &m, &ring, max_steps, out, &err));
    ctx_release(&c);
    if (rc) return kernel_error(&err);
    Py_RETURN_NONE;
fail:
    ctx_release(&c);
    return NULL;
}

static PyObject *py_prepare_rays(PyObject *self, PyObject *args)
{
    PyObject *a[24];
    double sd, ld, backoff, tol;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOOOOOddddOOOOOO:prepare_rays", &a[0], &a[1], &a[2], &a[3], &a[4], &a[5],
                          &a[6], &a[7], &a[8], &a[9], &a[10], &a[11], &a[12], &a[13], &sd, &ld, &backoff, &tol, &a[18],
                          &a[19], &a[20], &a[21], &a[22], &a[23]))
        return NULL;
    if (finite_param(sd, "short_dist", 1) || finite_param(ld, "long_dist", 1) || finite_param(backoff, "backoff", 1) ||
        finite_param(tol, "tolerance", 1))
        return NULL;
    Ctx c = {.n = 0};
    Buf *x, *nrm, *has, *lm, *order, *ptr, *blo, *bhi, *pa, *pb, *ub, *R, *cen, *rcen, *o, *d, *dist, *rv, *rs, *seg;
    TRY(x = arg(&c, a[0], "positions", F64, 0, 2, -1, 3, 0));
    Py_ssize_t n = ROWS(x);
    TRY(nrm = arg(&c, a[1], "normals", F64, 0, 2, n, 3, 0));
    TRY(has = arg(&c, a[2], "has_normal", BOOL, 0, 1, n, 0, 0));
    TRY(lm = opt(&c, a[3], "long_mask", BOOL, 0, 1, n, 0, 0));
    TRY(order = arg(&c, a[4], "order", I64, 0, 1, -1, 0, 0));
    TRY(ptr = arg(&c, a[5], "ptr", I64, 0, 1, -1, 0, 0));
    if (ROWS(ptr) < 1) {
        PyErr_SetString(PyExc_ValueError, "ptr must hold the k + 1 cluster bounds (at least one entry)");
        goto fail;
    }
    TRY(blo = arg(&c, a[6], "box_lo", F64, 0, 2, -1, 3, 0));
    Py_ssize_t kb = ROWS(blo);
    TRY(bhi = arg(&c, a[7], "box_hi", F64, 0, 2, kb, 3, 0));
    TRY(pa = arg(&c, a[8], "pair_a", I64, 0, 1, -1, 0, 0));
    TRY(pb = arg(&c, a[9], "pair_b", I64, 0, 1, ROWS(pa), 0, 0));
    TRY(ub = arg(&c, a[10], "clusters", I64, 0, 1, -1, 0, 0));
    Py_ssize_t q = ROWS(ub);
    TRY(R = arg(&c, a[11], "R", F64, 0, 3, kb, 3, 3));
    TRY(cen = arg(&c, a[12], "centre", F64, 0, 2, kb, 3, 0));
    TRY(rcen = arg(&c, a[13], "ref_centre", F64, 0, 2, kb, 3, 0));
    TRY(o = arg(&c, a[18], "origins", F32, 1, 2, -1, 3, 0));
    Py_ssize_t cap = ROWS(o);
    TRY(d = arg(&c, a[19], "directions", F32, 1, 2, cap, 3, 0));
    TRY(dist = arg(&c, a[20], "dists", F32, 1, 1, cap, 0, 0));
    TRY(rv = arg(&c, a[21], "ray_vertex", I64, 1, 1, cap, 0, 0));
    TRY(rs = arg(&c, a[22], "ray_slot", I64, 1, 1, cap, 0, 0));
    TRY(seg = arg(&c, a[23], "segments", I64, 1, 1, q + 1, 0, 0));
    if (no_overlap(&c)) goto fail;
    tcc_ray_setup s = {DATA(x), DATA(nrm), DATA(has), DATA(lm), n, DATA(order), DATA(ptr), ROWS(order), ROWS(ptr) - 1,
                       DATA(blo), DATA(bhi), kb, sd, ld, backoff, tol};
    tcc_error err = {0};
    tcc_idx count = 0;
    int rc;
    RUN(tcc_prepare_rays(&s, DATA(pa), DATA(pb), ROWS(pa), DATA(ub), DATA(R), DATA(cen), DATA(rcen), q, DATA(o), DATA(d),
                         DATA(dist), DATA(rv), DATA(rs), cap, DATA(seg), &count, &err));
    ctx_release(&c);
    if (rc) return kernel_error(&err);
    return PyLong_FromLongLong(count);
fail:
    ctx_release(&c);
    return NULL;
}

static PyObject *py_accept_hits(PyObject *self, PyObject *args)
{
    PyObject *a[12];
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOOO:accept_hits", &a[0], &a[1], &a[2], &a[3], &a[4], &a[5], &a[6], &a[7],
                          &a[8], &a[9], &a[10], &a[11]))
        return NULL;
    Ctx c = {.n = 0};
    Buf *rays, *prim, *tfar, *stris, *rv, *tt, *o, *d, *dist, *hit, *retry;
    tcc_ring ring;
    TRY(rays = arg(&c, a[0], "rays", I64, 0, 1, -1, 0, 0));
    Py_ssize_t r = ROWS(rays);
    TRY(prim = arg(&c, a[1], "prim", I32, 0, 1, r, 0, 0));
    TRY(tfar = opt(&c, a[2], "tfar", F32, 0, 1, r, 0, 0));
    TRY(stris = arg(&c, a[3], "scene_triangles", I64, 0, 1, -1, 0, 0));
    TRY(rv = arg(&c, a[4], "ray_vertex", I64, 0, 1, -1, 0, 0));
    Py_ssize_t nr = ROWS(rv);
    TRY(tt = arg(&c, a[5], "target triangles", I64, 0, 2, -1, 3, 0));
    if (ring_arg(&c, &ring, a[6])) goto fail;
    TRY(o = arg(&c, a[7], "origins", F32, 1, 2, nr, 3, 0));
    TRY(d = arg(&c, a[8], "directions", F32, 0, 2, nr, 3, 0));
    TRY(dist = arg(&c, a[9], "dists", F32, 1, 1, nr, 0, 0));
    TRY(hit = arg(&c, a[10], "hit_triangle", I64, 1, 1, nr, 0, 0));
    TRY(retry = arg(&c, a[11], "retry", I64, 1, 1, -1, 0, 0));
    if (ring.table && ROWS(retry) < r) {
        PyErr_Format(PyExc_ValueError, "retry must have room for the %zd rays (has %zd)", r, ROWS(retry));
        goto fail;
    }
    if (no_overlap(&c)) goto fail;
    tcc_mesh m = {NULL, 0, DATA(tt), ROWS(tt), NULL, NULL};
    tcc_error err = {0};
    tcc_idx nretry = 0;
    int rc;
    RUN(tcc_accept_hits(DATA(rays), DATA(prim), DATA(tfar), r, DATA(stris), ROWS(stris), DATA(rv), nr, &m, &ring,
                        DATA(o), DATA(d), DATA(dist), DATA(hit), DATA(retry), &nretry, &err));
    ctx_release(&c);
    if (rc) return kernel_error(&err);
    return PyLong_FromLongLong(nretry);
fail:
    ctx_release(&c);
    return NULL;
}

static PyObject *py_refine(PyObject *self, PyObject *args)
{
    PyObject *a[22];
    int kind;
    double track_range;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOidOOOOOOOOO:refine", &a[0], &a[1], &a[2], &a[3], &a[4], &a[5], &a[6], &a[7],
                          &a[8], &a[9], &kind, &track_range, &a[12], &a[13], &a[14], &a[15], &a[16], &a[17], &a[18],
                          &a[19], &a[20]))
        return NULL;
    if (kind < TCC_VOLUME || kind > TCC_SELF) {
        PyErr_Format(PyExc_ValueError, "kind must be 0 (volume), 1 (surface) or 2 (self), got %d", kind);
        return NULL;
    }
    if (finite_param(track_range, "track_range", 1)) return NULL;
    Ctx c = {.n = 0};
    Buf *x, *nrm, *rv, *rs, *hit, *ip, *ov, *os, *ot, *otp, *ou, *ovv, *of, *st;
    tcc_mesh m;
    tcc_ring ring;
    TRY(x = arg(&c, a[0], "positions", F64, 0, 2, -1, 3, 0));
    Py_ssize_t n = ROWS(x);
    TRY(nrm = arg(&c, a[1], "normals", F64, 0, 2, n, 3, 0));
    TRY(rv = arg(&c, a[2], "ray_vertex", I64, 0, 1, -1, 0, 0));
    Py_ssize_t r = ROWS(rv);
    TRY(rs = arg(&c, a[3], "ray_slot", I64, 0, 1, r, 0, 0));
    TRY(hit = arg(&c, a[4], "hit_triangle", I64, 0, 1, r, 0, 0));
    if (mesh_args(&c, &m, a[5], a[6], a[7], a[8])) goto fail;
    if (ring_arg(&c, &ring, a[9])) goto fail;
    TRY(ip = opt(&c, a[12], "inside_prev", BOOL, 0, 1, n, 0, 0));
    TRY(ov = arg(&c, a[13], "out_vertex", I64, 1, 1, r, 0, 0));
    TRY(os = arg(&c, a[14], "out_slot", I64, 1, 1, r, 0, 0));
    TRY(ot = arg(&c, a[15], "out_tri", I64, 1, 1, r, 0, 0));
    TRY(otp = arg(&c, a[16], "out_t", F64, 1, 1, r, 0, 0));
    TRY(ou = arg(&c, a[17], "out_u", F64, 1, 1, r, 0, 0));
    TRY(ovv = arg(&c, a[18], "out_v", F64, 1, 1, r, 0, 0));
    TRY(of = arg(&c, a[19], "out_flips", BOOL, 1, 1, r, 0, 0));
    TRY(st = arg(&c, a[20], "status", BOOL, 1, 1, r, 0, 0));
    if (!m.adj || !m.flip) {
        PyErr_SetString(PyExc_ValueError, "refine walks: adjacency and flip are required");
        goto fail;
    }
    if (no_overlap(&c)) goto fail;
    tcc_hits out = {DATA(ot), DATA(otp), DATA(ou), DATA(ovv), DATA(of)};
    tcc_error err = {0};
    tcc_idx count = 0;
    int rc;
    RUN(tcc_refine(DATA(x), DATA(nrm), n, DATA(rv), DATA(rs), DATA(hit), r, &m, &ring, kind, track_range, DATA(ip),
                   DATA(ov), DATA(os), out, DATA(st), &count, &err));
    ctx_release(&c);
    if (rc) return kernel_error(&err);
    return PyLong_FromLongLong(count);
fail:
    ctx_release(&c);
    return NULL;
}

static PyObject *py_drop_dominated(PyObject *self, PyObject *args)
{
    PyObject *a[7];
    if (!PyArg_ParseTuple(args, "OOOOOOO:drop_dominated", &a[0], &a[1], &a[2], &a[3], &a[4], &a[5], &a[6])) return NULL;
    Ctx c = {.n = 0};
    Buf *v, *s, *t, *st, *tk, *wt, *wtp;
    TRY(v = arg(&c, a[0], "vertex", I64, 0, 1, -1, 0, 0));
    Py_ssize_t k = ROWS(v);
    TRY(s = arg(&c, a[1], "slot", I64, 0, 1, k, 0, 0));
    TRY(t = arg(&c, a[2], "t", F64, 0, 1, k, 0, 0));
    TRY(st = arg(&c, a[3], "status", BOOL, 1, 1, k, 0, 0));
    TRY(tk = arg(&c, a[4], "track_key", I64, 0, 1, -1, 0, 0));
    TRY(wt = arg(&c, a[5], "walked_tri", I64, 0, 1, ROWS(tk), 0, 0));
    TRY(wtp = arg(&c, a[6], "walked_t", F64, 0, 1, ROWS(tk), 0, 0));
    if (no_overlap(&c)) goto fail;
    tcc_error err = {0};
    tcc_idx left = 0;
    int rc;
    RUN(tcc_drop_dominated(DATA(v), DATA(s), DATA(t), DATA(st), k, DATA(tk), ROWS(tk), DATA(wt), DATA(wtp), &left,
                           &err));
    ctx_release(&c);
    if (rc) return kernel_error(&err);
    return PyLong_FromLongLong(left);
fail:
    ctx_release(&c);
    return NULL;
}

static PyObject *py_confirm_inside(PyObject *self, PyObject *args)
{
    PyObject *a[13];
    double backoff, eps;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOddO:confirm_inside", &a[0], &a[1], &a[2], &a[3], &a[4], &a[5], &a[6], &a[7],
                          &a[8], &a[9], &backoff, &eps, &a[12]))
        return NULL;
    if (finite_param(backoff, "backoff", 1) || finite_param(eps, "eps", 1)) return NULL;
    Ctx c = {.n = 0};
    Buf *order, *ptr, *lo, *hi, *o, *d, *te, *et, *ok;
    tcc_mesh m;
    if (mesh_args(&c, &m, a[0], a[1], Py_None, Py_None)) goto fail;
    TRY(order = arg(&c, a[2], "tri_order", I64, 0, 1, -1, 0, 0));
    TRY(ptr = arg(&c, a[3], "tri_ptr", I64, 0, 1, -1, 0, 0));
    Py_ssize_t k = ROWS(ptr) - 1;
    if (k < 0) {
        PyErr_SetString(PyExc_ValueError, "tri_ptr must hold the k + 1 cluster bounds (at least one entry)");
        goto fail;
    }
    TRY(lo = arg(&c, a[4], "lo", F64, 0, 2, k, 3, 0));
    TRY(hi = arg(&c, a[5], "hi", F64, 0, 2, k, 3, 0));
    TRY(o = arg(&c, a[6], "origins", F64, 0, 2, -1, 3, 0));
    Py_ssize_t r = ROWS(o);
    TRY(d = arg(&c, a[7], "directions", F64, 0, 2, r, 3, 0));
    TRY(te = arg(&c, a[8], "t_exit", F64, 0, 1, r, 0, 0));
    TRY(et = arg(&c, a[9], "exit_tri", I64, 0, 1, r, 0, 0));
    TRY(ok = arg(&c, a[12], "ok", BOOL, 1, 1, r, 0, 0));
    if (no_overlap(&c)) goto fail;
    tcc_error err = {0};
    int rc;
    RUN(tcc_confirm_inside(&m, DATA(order), ROWS(order), DATA(ptr), k, DATA(lo), DATA(hi), DATA(o), DATA(d), DATA(te),
                           DATA(et), r, backoff, eps, DATA(ok), &err));
    ctx_release(&c);
    if (rc) return kernel_error(&err);
    Py_RETURN_NONE;
fail:
    ctx_release(&c);
    return NULL;
}

static PyObject *py_merge_classify(PyObject *self, PyObject *args, PyObject *kw)
{
    static char *kwl[] = {"positions", "normals", "previous", "velocity", "target_vertices", "target_triangles",
                          "target_previous", "target_velocity", "kind", "first", "thickness", "track_range",
                          "track_key", "track_tri", "track_side", "walked_tri", "walked_t", "walked_u", "walked_v",
                          "walked_flips", "found_vertex", "found_slot", "found_tri", "found_t", "found_u", "found_v",
                          "found_flips", "found_status", "out_key", "out_tri", "out_side", "out_inside",
                          "contact_vertex", "depth", "normal", "contact_velocity", NULL};
    PyObject *a[36];
    int kind, first;
    double th, tr;
    if (!PyArg_ParseTupleAndKeywords(args, kw, "OOOOOOOOipddOOOOOOOOOOOOOOOOOOOOOOOO:merge_classify", kwl, &a[0], &a[1],
                                     &a[2], &a[3], &a[4], &a[5], &a[6], &a[7], &kind, &first, &th, &tr, &a[12], &a[13],
                                     &a[14], &a[15], &a[16], &a[17], &a[18], &a[19], &a[20], &a[21], &a[22], &a[23],
                                     &a[24], &a[25], &a[26], &a[27], &a[28], &a[29], &a[30], &a[31], &a[32], &a[33],
                                     &a[34], &a[35]))
        return NULL;
    if (kind < TCC_VOLUME || kind > TCC_SELF) {
        PyErr_Format(PyExc_ValueError, "kind must be 0 (volume), 1 (surface) or 2 (self), got %d", kind);
        return NULL;
    }
    if (finite_param(th, "thickness", 1) || finite_param(tr, "track_range", 1)) return NULL;
    Ctx c = {.n = 0};
    Buf *x, *nrm, *xp, *vel, *tx, *tt, *tp, *tv, *tk, *ttri, *tside;
    Buf *wt, *wtp, *wu, *wvv, *wf, *fv, *fs, *ft, *ftp, *fu, *fvv, *ff, *fst;
    Buf *okey, *otri, *oside, *oin, *cv, *dep, *onrm, *ovel;
    TRY(x = arg(&c, a[0], "positions", F64, 0, 2, -1, 3, 0));
    Py_ssize_t n = ROWS(x);
    TRY(nrm = arg(&c, a[1], "normals", F64, 0, 2, n, 3, 0));
    TRY(xp = arg(&c, a[2], "previous", F64, 0, 2, n, 3, 0));
    TRY(vel = opt(&c, a[3], "velocity", F64, 0, 2, n, 3, 0));
    TRY(tx = arg(&c, a[4], "target_vertices", F64, 0, 2, -1, 3, 0));
    Py_ssize_t nv = ROWS(tx);
    TRY(tt = arg(&c, a[5], "target_triangles", I64, 0, 2, -1, 3, 0));
    TRY(tp = arg(&c, a[6], "target_previous", F64, 0, 2, nv, 3, 0));
    TRY(tv = opt(&c, a[7], "target_velocity", F64, 0, 2, nv, 3, 0));
    TRY(tk = arg(&c, a[12], "track_key", I64, 0, 1, -1, 0, 0));
    Py_ssize_t kt = ROWS(tk);
    TRY(ttri = arg(&c, a[13], "track_tri", I64, 0, 1, kt, 0, 0));
    TRY(tside = arg(&c, a[14], "track_side", I8, 0, 1, kt, 0, 0));
    TRY(wt = arg(&c, a[15], "walked_tri", I64, 0, 1, kt, 0, 0));
    TRY(wtp = arg(&c, a[16], "walked_t", F64, 0, 1, kt, 0, 0));
    TRY(wu = arg(&c, a[17], "walked_u", F64, 0, 1, kt, 0, 0));
    TRY(wvv = arg(&c, a[18], "walked_v", F64, 0, 1, kt, 0, 0));
    TRY(wf = arg(&c, a[19], "walked_flips", BOOL, 0, 1, kt, 0, 0));
    TRY(fv = arg(&c, a[20], "found_vertex", I64, 0, 1, -1, 0, 0));
    Py_ssize_t kf = ROWS(fv);
    TRY(fs = arg(&c, a[21], "found_slot", I64, 0, 1, kf, 0, 0));
    TRY(ft = arg(&c, a[22], "found_tri", I64, 0, 1, kf, 0, 0));
    TRY(ftp = arg(&c, a[23], "found_t", F64, 0, 1, kf, 0, 0));
    TRY(fu = arg(&c, a[24], "found_u", F64, 0, 1, kf, 0, 0));
    TRY(fvv = arg(&c, a[25], "found_v", F64, 0, 1, kf, 0, 0));
    TRY(ff = arg(&c, a[26], "found_flips", BOOL, 0, 1, kf, 0, 0));
    TRY(fst = opt(&c, a[27], "found_status", BOOL, 0, 1, kf, 0, 0));
    TRY(okey = arg(&c, a[28], "out_key", I64, 1, 1, -1, 0, 0));
    Py_ssize_t cap = ROWS(okey);
    if (cap < kt + kf) {
        PyErr_Format(PyExc_ValueError, "the outputs need room for %zd entries (tracks + new hits), out_key has %zd",
                     kt + kf, cap);
        goto fail;
    }
    TRY(otri = arg(&c, a[29], "out_tri", I64, 1, 1, cap, 0, 0));
    TRY(oside = arg(&c, a[30], "out_side", I8, 1, 1, cap, 0, 0));
    TRY(oin = arg(&c, a[31], "out_inside", I64, 1, 1, cap, 0, 0));
    TRY(cv = arg(&c, a[32], "contact_vertex", I64, 1, 1, cap, 0, 0));
    TRY(dep = arg(&c, a[33], "depth", F64, 1, 1, cap, 0, 0));
    TRY(onrm = arg(&c, a[34], "normal", F64, 1, 2, cap, 3, 0));
    TRY(ovel = arg(&c, a[35], "contact_velocity", F64, 1, 2, cap, 3, 0));
    if (no_overlap(&c)) goto fail;
    tcc_mesh m = {DATA(tx), nv, DATA(tt), ROWS(tt), NULL, NULL};
    tcc_merge_in in = {
        .x = DATA(x), .normals = DATA(nrm), .x_prev = DATA(xp), .velocity = DATA(vel), .n = n, .target = &m,
        .target_prev = DATA(tp), .target_velocity = DATA(tv), .kind = kind, .first = first, .thickness = th,
        .track_range = tr, .track_key = DATA(tk), .track_tri = DATA(ttri), .track_side = DATA(tside), .kt = kt,
        .walked = {DATA(wt), DATA(wtp), DATA(wu), DATA(wvv), DATA(wf)},
        .f_v = DATA(fv), .f_slot = DATA(fs), .f_hit = {DATA(ft), DATA(ftp), DATA(fu), DATA(fvv), DATA(ff)},
        .f_status = DATA(fst), .kf = kf,
    };
    tcc_merge_out out = {.track_key = DATA(okey), .track_tri = DATA(otri), .track_side = DATA(oside),
                         .inside = DATA(oin), .contact_v = DATA(cv), .depth = DATA(dep), .normal = DATA(onrm),
                         .velocity = DATA(ovel)};
    tcc_error err = {0};
    int rc;
    RUN(tcc_merge_classify(&in, &out, &err));
    ctx_release(&c);
    if (rc) return kernel_error(&err);
    return Py_BuildValue("(LLL)", (long long)out.ntracks, (long long)out.ninside, (long long)out.ncontacts);
fail:
    ctx_release(&c);
    return NULL;
}

static PyObject *py_assemble(PyObject *self, PyObject *args)
{
    PyObject *a[17];
    Py_ssize_t n;
    if (!PyArg_ParseTuple(args, "OOOOOOnOOOOOOOOOO:assemble", &a[0], &a[1], &a[2], &a[3], &a[4], &a[5], &n, &a[7],
                          &a[8], &a[9], &a[10], &a[11], &a[12], &a[13], &a[14], &a[15], &a[16]))
        return NULL;
    if (n < 0 || n > 0x7fffffff) {
        PyErr_Format(PyExc_ValueError, "n must be a vertex count in [0, 2^31), got %zd", n);
        return NULL;
    }
    Ctx c = {.n = 0};
    Buf *seg, *v, *dep, *nrm, *vel, *fr, *dv, *dn, *dd, *dvel, *dfr, *av, *an, *ad, *avel, *afr;
    TRY(seg = arg(&c, a[0], "segments", I64, 0, 1, -1, 0, 0));
    Py_ssize_t cc = ROWS(seg) - 1;
    if (cc < 0) {
        PyErr_SetString(PyExc_ValueError, "segments must hold the c + 1 bounds (at least one entry)");
        goto fail;
    }
    TRY(v = arg(&c, a[1], "vertex", I64, 0, 1, -1, 0, 0));
    Py_ssize_t k = ROWS(v);
    TRY(dep = arg(&c, a[2], "depth", F64, 0, 1, k, 0, 0));
    TRY(nrm = arg(&c, a[3], "normal", F64, 0, 2, k, 3, 0));
    TRY(vel = arg(&c, a[4], "velocity", F64, 0, 2, k, 3, 0));
    TRY(fr = arg(&c, a[5], "friction", F64, 0, 1, cc, 0, 0));
    const tcc_idx *sp = DATA(seg);
    if (sp[cc] != k) {
        PyErr_Format(PyExc_ValueError, "segments must end at the %zd contacts, ends at %lld", k, (long long)sp[cc]);
        goto fail;
    }
    TRY(dv = arg(&c, a[7], "deep_vertex", I32, 1, 1, k, 0, 0));
    TRY(dn = arg(&c, a[8], "deep_normal", F64, 1, 2, k, 3, 0));
    TRY(dd = arg(&c, a[9], "deep_depth", F64, 1, 1, k, 0, 0));
    TRY(dvel = arg(&c, a[10], "deep_velocity", F64, 1, 2, k, 3, 0));
    TRY(dfr = arg(&c, a[11], "deep_friction", F64, 1, 1, k, 0, 0));
    TRY(av = arg(&c, a[12], "all_vertex", I32, 1, 1, k, 0, 0));
    TRY(an = arg(&c, a[13], "all_normal", F64, 1, 2, k, 3, 0));
    TRY(ad = arg(&c, a[14], "all_depth", F64, 1, 1, k, 0, 0));
    TRY(avel = arg(&c, a[15], "all_velocity", F64, 1, 2, k, 3, 0));
    TRY(afr = arg(&c, a[16], "all_friction", F64, 1, 1, k, 0, 0));
    if (no_overlap(&c)) goto fail;
    tcc_idx kd = 0, ka = 0;
    tcc_error err = {0};
    int rc;
    RUN(tcc_assemble(DATA(seg), cc, DATA(v), DATA(dep), DATA(nrm), DATA(vel), DATA(fr), n, DATA(dv), DATA(dn),
                     DATA(dd), DATA(dvel), DATA(dfr), &kd, DATA(av), DATA(an), DATA(ad), DATA(avel), DATA(afr), &ka,
                     &err));
    ctx_release(&c);
    if (rc) return kernel_error(&err);
    return Py_BuildValue("(LL)", (long long)kd, (long long)ka);
fail:
    ctx_release(&c);
    return NULL;
}

static PyMethodDef methods[] = {
    {"vertex_normals", py_vertex_normals, METH_VARARGS,
     "vertex_normals(positions, triangles, normals_out, has_normal_out): area-weighted unit vertex normals."},
    {"cluster_normals", py_cluster_normals, METH_VARARGS,
     "cluster_normals(positions, triangles, vt_ptr, vt_tri, order, ptr, clusters, normals_out, has_normal_out, "
     "done=None): vertex normals of the listed clusters' vertices only (skipping and marking done clusters)."},
    {"cluster_motion", py_cluster_motion, METH_VARARGS,
     "cluster_motion(positions, previous, order, ptr, avg_out, dev_out): mean and deviation of the displacement."},
    {"cluster_boxes", py_cluster_boxes, METH_VARARGS,
     "cluster_boxes(positions, index, ptr, inflate, lo_out, hi_out): inflated AABB per cluster."},
    {"box_pairs", py_box_pairs, METH_VARARGS,
     "box_pairs(lo_a, hi_a, lo_b, hi_b, self_pairs, i_out, j_out) -> count (> len(i_out): call again, larger)."},
    {"relative_measure", py_relative_measure, METH_VARARGS,
     "relative_measure(old_keys, old_avg, old_dev, i, j, avg_a, dev_a, avg_b, dev_b, force, threshold, keys_out, "
     "rel_avg_out, rel_dev_out, amplitude_out, full_out, lookahead=0) -> number of full pairs."},
    {"rigid_fit", py_rigid_fit, METH_VARARGS,
     "rigid_fit(positions, triangles, ref_corners, scene_triangles, R, centre, ref_centre, row) -> max residual^2."},
    {"rigid_fit_many", py_rigid_fit_many, METH_VARARGS,
     "rigid_fit_many(positions, triangles, scene_ptr, scene_triangles, ref_corners, clusters, R, centre, ref_centre, "
     "resid2_out): the rigid fit of each listed cluster's scene (rows R[c] ...), its max residual^2."},
    {"walk", py_walk, METH_VARARGS,
     "walk(positions, normals, ray_vertex, ray_slot, start, target_vertices, target_triangles, adjacency, flip, "
     "ring, max_steps, tri_out, t_out, u_out, v_out, flips_out)."},
    {"prepare_rays", py_prepare_rays, METH_VARARGS,
     "prepare_rays(positions, normals, has_normal, long_mask, order, ptr, box_lo, box_hi, pair_a, pair_b, clusters, "
     "R, centre, ref_centre, short_dist, long_dist, backoff, tolerance, origins_out, directions_out, dists_out, "
     "ray_vertex_out, ray_slot_out, segments_out) -> ray count (> capacity: call again, larger)."},
    {"accept_hits", py_accept_hits, METH_VARARGS,
     "accept_hits(rays, prim, tfar, scene_triangles, ray_vertex, target_triangles, ring, origins, directions, "
     "dists, hit_triangle_out, retry_out) -> number of rays to cast again."},
    {"refine", py_refine, METH_VARARGS,
     "refine(positions, normals, ray_vertex, ray_slot, hit_triangle, target_vertices, target_triangles, adjacency, "
     "flip, ring, kind, track_range, inside_prev, vertex_out, slot_out, tri_out, t_out, u_out, v_out, flips_out, "
     "status_out) -> count."},
    {"drop_dominated", py_drop_dominated, METH_VARARGS,
     "drop_dominated(vertex, slot, t, status, track_key, walked_tri, walked_t) -> far back-face hits left: those "
     "a nearer hit of the same ray beats get status 0."},
    {"confirm_inside", py_confirm_inside, METH_VARARGS,
     "confirm_inside(target_vertices, target_triangles, tri_order, tri_ptr, lo, hi, origins, directions, t_exit, "
     "exit_tri, backoff, eps, ok_out): ok where no other triangle is hit before the exit."},
    {"merge_classify", (PyCFunction)(void (*)(void))py_merge_classify, METH_VARARGS | METH_KEYWORDS,
     "merge_classify(**arrays) -> (tracks, inside, contacts): the new tracks, the vertices inside and the "
     "deepest contact per vertex of one collider."},
    {"assemble", py_assemble, METH_VARARGS,
     "assemble(segments, vertex, depth, normal, velocity, friction, n, deep outputs x5, all outputs x5) -> "
     "(deep count, all count)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef moddef = {
    PyModuleDef_HEAD_INIT, "_collide",
    "Kernels of clustered ray-traced collision detection (numpy arrays in and out; see collide.h).", -1, methods,
    NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__collide(void) { return PyModule_Create(&moddef); }
