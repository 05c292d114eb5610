/* pymodule.c - the Python face of the collision kernels, `tearcloth._collide`.
 *
 * CPython limited API 3.11 (abi3), like `tearcloth._native`: one build serves every Blender from
 * 4.2 on. Arrays come in through the buffer protocol (numpy arrays, zero copy) and results go into
 * arrays the caller allocated, so this module never depends on numpy's C API.
 *
 * Each kernel's arguments are one table (pyarg_spec, native/py/pyarg.h) in the order of its
 * docstring: name, dtype, shape, output or optional. A kernel takes them by position in that order
 * or by keyword (addon/collision/kernels.py calls them by name). Every argument is checked before a
 * kernel runs - dtype, number of dimensions, shape against the other arguments, C-contiguity,
 * writability of outputs, and that no output overlaps another argument - and the kernels check
 * every index they read (collide.h). Wrong types raise TypeError, wrong shapes or values
 * ValueError, out-of-range indices IndexError. The GIL is released while a kernel runs.
 */
#include "pyarg.h"

#include "collide.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>
#ifdef _WIN32
#define WIN32_LEAN_AND_MEAN
#include <windows.h>  /* QueryPerformanceCounter: the swept job's own time */
#else
#include <time.h>     /* clock_gettime */
#include <unistd.h>   /* getpid: a swept worker's thread is not in a forked child */
#endif

/* table rows: an array (rows checked against other arguments after parsing), a scalar */
#define ARR(name, type, flags, ndim, d1, d2) {name, type, flags, ndim, {-1, d1, d2}}
#define VAL(name, type) {name, type, 0, 0, {0, 0, 0}}
#define OUT PA_OUT
#define OPT PA_OPTIONAL

#define D(i) pyarg_data(&s, i)
#define ROWS(i) pyarg_nrows(&s, i)
#define CHECK_ROWS(i, r) \
    if (pyarg_rows(&s, i, r)) goto fail
#define PARSE(name, table, count)                                                                                     \
    pyarg_set s;                                                                                                      \
    if (pyarg_parse(&s, name, table, count, PyExc_ValueError, args, kw)) return NULL
#define RUN(call)                                                                                                     \
    do {                                                                                                              \
        Py_BEGIN_ALLOW_THREADS rc = (call);                                                                           \
        Py_END_ALLOW_THREADS                                                                                          \
    } while (0)

static PyObject *kernel_error(const tcc_error *e)
{
    if (e->code == TCC_ERR_NOMEM) return PyErr_NoMemory();
    PyErr_SetString(e->code == TCC_ERR_INDEX ? PyExc_IndexError : PyExc_ValueError, e->what);
    return NULL;
}

static int finite_param(double x, const char *name, int positive)
{
    if (!isfinite(x) || (positive && x < 0)) {
        pyarg_error(PyExc_ValueError, "%s must be a finite%s number, got %g", name, positive ? " non-negative" : "", x);
        return -1;
    }
    return 0;
}

static int kind_ok(int kind)
{
    if (kind >= TCC_VOLUME && kind <= TCC_SELF) return 1;
    PyErr_Format(PyExc_ValueError, "kind must be 0 (volume), 1 (surface) or 2 (self), got %d", kind);
    return 0;
}

static int bounds_ok(Py_ssize_t rows, const char *name, const char *what)
{
    if (rows >= 1) return 1;
    PyErr_Format(PyExc_ValueError, "%s must hold the k + 1 %s bounds (at least one entry)", name, what);
    return 0;
}

/* A target mesh from four consecutive rows: vertices (nv, 3), triangles (nt, 3), adjacency and
 * flip (nt, 3) or absent. */
static int mesh_from(pyarg_set *p, int first, tcc_mesh *m)
{
    Py_ssize_t nt = pyarg_nrows(p, first + 1);
    if (pyarg_rows(p, first + 2, nt) || pyarg_rows(p, first + 3, nt)) return -1;
    m->x = pyarg_data(p, first);
    m->nv = pyarg_nrows(p, first);
    m->tri = pyarg_data(p, first + 1);
    m->nt = nt;
    m->adj = pyarg_data(p, first + 2);
    m->flip = pyarg_data(p, first + 3);
    return 0;
}

static tcc_ring ring_from(const pyarg_set *p, int i)
{
    const pyarg_value *v = &p->v[i];
    tcc_ring r = {pyarg_data(p, i), v->held ? v->rows : 0, v->held ? v->view.shape[1] : 0};
    return r;
}

/* rays of cloth vertices: positions (n, 3), normals (n, 3), ray_vertex (r,), ray_slot (r,) */
#define RAY_ROWS                                                                                                      \
    ARR("positions", PA_F64, 0, 2, 3, 0), ARR("normals", PA_F64, 0, 2, 3, 0), ARR("ray_vertex", PA_I64, 0, 1, 0, 0), \
        ARR("ray_slot", PA_I64, 0, 1, 0, 0)
#define RING_ROW ARR("ring", PA_I64, OPT, 2, -1, 0)
/* a tcc_hits output: triangle, t, u, v, flips (r,) each */
#define HITS_ROWS(tri, t, u, v, flips)                                                                                \
    ARR(tri, PA_I64, OUT, 1, 0, 0), ARR(t, PA_F64, OUT, 1, 0, 0), ARR(u, PA_F64, OUT, 1, 0, 0),                       \
        ARR(v, PA_F64, OUT, 1, 0, 0), ARR(flips, PA_BOOL, OUT, 1, 0, 0)
#define MESH_ROWS(prefix)                                                                                             \
    ARR(prefix "vertices", PA_F64, 0, 2, 3, 0), ARR(prefix "triangles", PA_I64, 0, 2, 3, 0),                          \
        ARR("adjacency", PA_I64, OPT, 2, 3, 0), ARR("flip", PA_BOOL, OPT, 2, 3, 0)

/* ---------------------------------------------------------------- functions */

static const pyarg_spec VERTEX_NORMALS[] = {
    ARR("positions", PA_F64, 0, 2, 3, 0),
    ARR("triangles", PA_I64, 0, 2, 3, 0),
    ARR("normals", PA_F64, OUT, 2, 3, 0),
    ARR("has_normal", PA_BOOL, OUT, 1, 0, 0),
};
enum { VN_X, VN_T, VN_NORMALS, VN_HAS, VN_N };

static PyObject *py_vertex_normals(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("vertex_normals", VERTEX_NORMALS, VN_N);
    Py_ssize_t n = ROWS(VN_X);
    CHECK_ROWS(VN_NORMALS, n);
    CHECK_ROWS(VN_HAS, n);
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_mesh m = {D(VN_X), n, D(VN_T), ROWS(VN_T), NULL, NULL};
    tcc_error err = {0};
    int rc;
    RUN(tcc_vertex_normals(&m, D(VN_NORMALS), D(VN_HAS), &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    Py_RETURN_NONE;
fail:
    pyarg_release(&s);
    return NULL;
}

static const pyarg_spec CLUSTER_NORMALS[] = {
    ARR("positions", PA_F64, 0, 2, 3, 0),
    ARR("triangles", PA_I64, 0, 2, 3, 0),
    ARR("vt_ptr", PA_I64, 0, 1, 0, 0),
    ARR("vt_tri", PA_I64, 0, 1, 0, 0),
    ARR("order", PA_I64, 0, 1, 0, 0),
    ARR("ptr", PA_I64, 0, 1, 0, 0),
    ARR("clusters", PA_I64, 0, 1, 0, 0),
    ARR("normals", PA_F64, OUT, 2, 3, 0),
    ARR("has_normal", PA_BOOL, OUT, 1, 0, 0),
    ARR("done", PA_BOOL, OUT | OPT, 1, 0, 0),
};
enum { CN_X, CN_T, CN_VP, CN_VT, CN_ORDER, CN_PTR, CN_CL, CN_NORMALS, CN_HAS, CN_DONE, CN_N };

static PyObject *py_cluster_normals(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("cluster_normals", CLUSTER_NORMALS, CN_N);
    Py_ssize_t n = ROWS(CN_X);
    CHECK_ROWS(CN_VP, n + 1);
    if (!bounds_ok(ROWS(CN_PTR), "ptr", "cluster")) goto fail;
    CHECK_ROWS(CN_NORMALS, n);
    CHECK_ROWS(CN_HAS, n);
    CHECK_ROWS(CN_DONE, ROWS(CN_PTR) - 1);
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_mesh m = {D(CN_X), n, D(CN_T), ROWS(CN_T), NULL, NULL};
    tcc_error err = {0};
    int rc;
    RUN(tcc_cluster_normals(&m, D(CN_VP), D(CN_VT), ROWS(CN_VT), D(CN_ORDER), ROWS(CN_ORDER), D(CN_PTR),
                            ROWS(CN_PTR) - 1, D(CN_CL), ROWS(CN_CL), D(CN_NORMALS), D(CN_HAS), D(CN_DONE), &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    Py_RETURN_NONE;
fail:
    pyarg_release(&s);
    return NULL;
}

static const pyarg_spec CLUSTER_MOTION[] = {
    ARR("positions", PA_F64, 0, 2, 3, 0),
    ARR("previous", PA_F64, 0, 2, 3, 0),
    ARR("order", PA_I64, 0, 1, 0, 0),
    ARR("ptr", PA_I64, 0, 1, 0, 0),
    ARR("avg", PA_F64, OUT, 2, 3, 0),
    ARR("dev", PA_F64, OUT, 1, 0, 0),
};
enum { CM_X, CM_PREV, CM_ORDER, CM_PTR, CM_AVG, CM_DEV, CM_N };

static PyObject *py_cluster_motion(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("cluster_motion", CLUSTER_MOTION, CM_N);
    Py_ssize_t n = ROWS(CM_X);
    CHECK_ROWS(CM_PREV, n);
    if (!bounds_ok(ROWS(CM_PTR), "ptr", "cluster")) goto fail;
    Py_ssize_t k = ROWS(CM_PTR) - 1;
    CHECK_ROWS(CM_AVG, k);
    CHECK_ROWS(CM_DEV, k);
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_error err = {0};
    int rc;
    RUN(tcc_cluster_motion(D(CM_X), D(CM_PREV), n, D(CM_ORDER), ROWS(CM_ORDER), D(CM_PTR), k, D(CM_AVG), D(CM_DEV),
                           &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    Py_RETURN_NONE;
fail:
    pyarg_release(&s);
    return NULL;
}

static const pyarg_spec CLUSTER_BOXES[] = {
    ARR("positions", PA_F64, 0, 2, 3, 0),
    ARR("index", PA_I64, 0, 1, 0, 0),
    ARR("ptr", PA_I64, 0, 1, 0, 0),
    VAL("inflate", PA_DOUBLE),
    ARR("lo", PA_F64, OUT, 2, 3, 0),
    ARR("hi", PA_F64, OUT, 2, 3, 0),
};
enum { CB_X, CB_INDEX, CB_PTR, CB_INFLATE, CB_LO, CB_HI, CB_N };

static PyObject *py_cluster_boxes(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("cluster_boxes", CLUSTER_BOXES, CB_N);
    double inflate = s.v[CB_INFLATE].d;
    if (finite_param(inflate, "inflate", 0)) goto fail;
    if (!bounds_ok(ROWS(CB_PTR), "ptr", "box")) goto fail;
    Py_ssize_t k = ROWS(CB_PTR) - 1;
    CHECK_ROWS(CB_LO, k);
    CHECK_ROWS(CB_HI, k);
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_error err = {0};
    int rc;
    RUN(tcc_cluster_boxes(D(CB_X), ROWS(CB_X), D(CB_INDEX), ROWS(CB_INDEX), D(CB_PTR), k, inflate, D(CB_LO), D(CB_HI),
                          &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    Py_RETURN_NONE;
fail:
    pyarg_release(&s);
    return NULL;
}

static const pyarg_spec BOX_PAIRS[] = {
    ARR("lo_a", PA_F64, 0, 2, 3, 0),
    ARR("hi_a", PA_F64, 0, 2, 3, 0),
    ARR("lo_b", PA_F64, 0, 2, 3, 0),
    ARR("hi_b", PA_F64, 0, 2, 3, 0),
    VAL("self_pairs", PA_FLAG),
    ARR("i", PA_I64, OUT, 1, 0, 0),
    ARR("j", PA_I64, OUT, 1, 0, 0),
};
enum { BP_LOA, BP_HIA, BP_LOB, BP_HIB, BP_SELF, BP_I, BP_J, BP_N };

static PyObject *py_box_pairs(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("box_pairs", BOX_PAIRS, BP_N);
    int self_pairs = s.v[BP_SELF].i;
    CHECK_ROWS(BP_HIA, ROWS(BP_LOA));
    CHECK_ROWS(BP_HIB, ROWS(BP_LOB));
    if (self_pairs && ROWS(BP_LOA) != ROWS(BP_LOB)) {
        PyErr_SetString(PyExc_ValueError, "self pairs need the same boxes on both sides");
        goto fail;
    }
    CHECK_ROWS(BP_J, ROWS(BP_I));
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_idx count = 0;
    Py_BEGIN_ALLOW_THREADS tcc_box_pairs(D(BP_LOA), D(BP_HIA), ROWS(BP_LOA), D(BP_LOB), D(BP_HIB), ROWS(BP_LOB),
                                         self_pairs, D(BP_I), D(BP_J), ROWS(BP_I), &count);
    Py_END_ALLOW_THREADS pyarg_release(&s);
    return PyLong_FromLongLong(count);
fail:
    pyarg_release(&s);
    return NULL;
}

static const pyarg_spec RELATIVE_MEASURE[] = {
    ARR("old_keys", PA_I64, 0, 1, 0, 0),
    ARR("old_avg", PA_F64, 0, 2, 3, 0),
    ARR("old_dev", PA_F64, 0, 1, 0, 0),
    ARR("i", PA_I64, 0, 1, 0, 0),
    ARR("j", PA_I64, 0, 1, 0, 0),
    ARR("avg_a", PA_F64, 0, 2, 3, 0),
    ARR("dev_a", PA_F64, 0, 1, 0, 0),
    ARR("avg_b", PA_F64, 0, 2, 3, 0),
    ARR("dev_b", PA_F64, 0, 1, 0, 0),
    ARR("force", PA_BOOL, OPT, 1, 0, 0),
    VAL("threshold", PA_DOUBLE),
    ARR("keys", PA_I64, OUT, 1, 0, 0),
    ARR("rel_avg", PA_F64, OUT, 2, 3, 0),
    ARR("rel_dev", PA_F64, OUT, 1, 0, 0),
    ARR("amplitude", PA_F64, OUT, 1, 0, 0),
    ARR("full", PA_BOOL, OUT, 1, 0, 0),
    {"lookahead", PA_DOUBLE, OPT, 0, {0, 0, 0}},  /* steps; absent: 0 */
};
enum { RM_OK, RM_OA, RM_OD, RM_I, RM_J, RM_AA, RM_DA, RM_AB, RM_DB, RM_FORCE, RM_THRESHOLD, RM_KEYS, RM_RA, RM_RD,
       RM_AMP, RM_FULL, RM_LOOKAHEAD, RM_N };

static PyObject *py_relative_measure(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("relative_measure", RELATIVE_MEASURE, RM_N);
    double threshold = s.v[RM_THRESHOLD].d, lookahead = s.v[RM_LOOKAHEAD].d;
    if (isnan(threshold) || !isfinite(lookahead) || lookahead < 0) {
        PyErr_SetString(PyExc_ValueError, "threshold must be a number and lookahead a finite number of steps >= 0");
        goto fail;
    }
    Py_ssize_t nold = ROWS(RM_OK), np_ = ROWS(RM_I);
    CHECK_ROWS(RM_OA, nold);
    CHECK_ROWS(RM_OD, nold);
    CHECK_ROWS(RM_J, np_);
    CHECK_ROWS(RM_DA, ROWS(RM_AA));
    CHECK_ROWS(RM_DB, ROWS(RM_AB));
    CHECK_ROWS(RM_FORCE, np_);
    CHECK_ROWS(RM_KEYS, np_);
    CHECK_ROWS(RM_RA, np_);
    CHECK_ROWS(RM_RD, np_);
    CHECK_ROWS(RM_AMP, np_);
    CHECK_ROWS(RM_FULL, np_);
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_error err = {0};
    tcc_idx nfull = 0;
    int rc;
    RUN(tcc_relative_measure(D(RM_OK), D(RM_OA), D(RM_OD), nold, D(RM_I), D(RM_J), np_, D(RM_AA), D(RM_DA), ROWS(RM_AA),
                             D(RM_AB), D(RM_DB), ROWS(RM_AB), D(RM_FORCE), threshold, lookahead, D(RM_KEYS), D(RM_RA),
                             D(RM_RD), D(RM_AMP), D(RM_FULL), &nfull, &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    return PyLong_FromLongLong(nfull);
fail:
    pyarg_release(&s);
    return NULL;
}

static const pyarg_spec CLUSTER_STATE[] = {
    ARR("positions", PA_F64, 0, 2, 3, 0),
    ARR("previous", PA_F64, 0, 2, 3, 0),
    ARR("order", PA_I64, 0, 1, 0, 0),
    ARR("ptr", PA_I64, 0, 1, 0, 0),
    ARR("box_index", PA_I64, 0, 1, 0, 0),
    ARR("box_ptr", PA_I64, 0, 1, 0, 0),
    VAL("inflate", PA_DOUBLE),
    ARR("avg", PA_F64, OUT, 2, 3, 0),
    ARR("dev", PA_F64, OUT, 1, 0, 0),
    ARR("lo", PA_F64, OUT, 2, 3, 0),
    ARR("hi", PA_F64, OUT, 2, 3, 0),
};
enum { CS_X, CS_PREV, CS_ORDER, CS_PTR, CS_BI, CS_BPTR, CS_INFL, CS_AVG, CS_DEV, CS_LO, CS_HI, CS_N };

static PyObject *py_cluster_state(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("cluster_state", CLUSTER_STATE, CS_N);
    Py_ssize_t n = ROWS(CS_X), k = ROWS(CS_PTR) - 1;
    if (!bounds_ok(ROWS(CS_PTR), "ptr", "cluster")) goto fail;
    CHECK_ROWS(CS_PREV, n);
    CHECK_ROWS(CS_BPTR, k + 1);
    CHECK_ROWS(CS_AVG, k);
    CHECK_ROWS(CS_DEV, k);
    CHECK_ROWS(CS_LO, k);
    CHECK_ROWS(CS_HI, k);
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_error err = {0};
    int rc;
    RUN(tcc_cluster_state(D(CS_X), D(CS_PREV), n, D(CS_ORDER), ROWS(CS_ORDER), D(CS_PTR), k, D(CS_BI), ROWS(CS_BI),
                          D(CS_BPTR), s.v[CS_INFL].d, D(CS_AVG), D(CS_DEV), D(CS_LO), D(CS_HI), &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    Py_RETURN_NONE;
fail:
    pyarg_release(&s);
    return NULL;
}

static const pyarg_spec PAIR_STEP[] = {
    ARR("lo_a", PA_F64, 0, 2, 3, 0),
    ARR("hi_a", PA_F64, 0, 2, 3, 0),
    ARR("lo_b", PA_F64, 0, 2, 3, 0),
    ARR("hi_b", PA_F64, 0, 2, 3, 0),
    VAL("self_pairs", PA_FLAG),
    VAL("first", PA_FLAG),
    ARR("forced", PA_I64, OPT, 1, 0, 0),
    ARR("avg_a", PA_F64, OPT, 2, 3, 0),
    ARR("dev_a", PA_F64, OPT, 1, 0, 0),
    ARR("avg_b", PA_F64, OPT, 2, 3, 0),
    ARR("dev_b", PA_F64, OPT, 1, 0, 0),
    ARR("old_keys", PA_I64, 0, 1, 0, 0),
    ARR("old_avg", PA_F64, 0, 2, 3, 0),
    ARR("old_dev", PA_F64, 0, 1, 0, 0),
    VAL("threshold", PA_DOUBLE),
    VAL("lookahead", PA_DOUBLE),
    ARR("i", PA_I64, OUT, 1, 0, 0),
    ARR("j", PA_I64, OUT, 1, 0, 0),
    ARR("full", PA_BOOL, OUT, 1, 0, 0),
    ARR("keys", PA_I64, OUT, 1, 0, 0),
    ARR("rel_avg", PA_F64, OUT, 2, 3, 0),
    ARR("rel_dev", PA_F64, OUT, 1, 0, 0),
    ARR("amplitude", PA_F64, OUT, 1, 0, 0),
};
enum { PS_LOA, PS_HIA, PS_LOB, PS_HIB, PS_SELF, PS_FIRST, PS_FORCED, PS_AA, PS_DA, PS_AB, PS_DB, PS_OK, PS_OA, PS_OD,
       PS_TH, PS_LA, PS_I, PS_J, PS_FULL, PS_KEYS, PS_RA, PS_RD, PS_AMP, PS_N };

static PyObject *py_pair_step(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("pair_step", PAIR_STEP, PS_N);
    Py_ssize_t ka = ROWS(PS_LOA), kb = ROWS(PS_LOB), cap = ROWS(PS_I), nold = ROWS(PS_OK);
    CHECK_ROWS(PS_HIA, ka);
    CHECK_ROWS(PS_HIB, kb);
    int relative = D(PS_AA) != NULL;
    if (relative != (D(PS_DA) != NULL) || relative != (D(PS_AB) != NULL) || relative != (D(PS_DB) != NULL)) {
        PyErr_SetString(PyExc_ValueError, "pair_step: avg_a, dev_a, avg_b and dev_b go together (all or none)");
        goto fail;
    }
    CHECK_ROWS(PS_AA, ka);
    CHECK_ROWS(PS_DA, ka);
    CHECK_ROWS(PS_AB, kb);
    CHECK_ROWS(PS_DB, kb);
    CHECK_ROWS(PS_OA, nold);
    CHECK_ROWS(PS_OD, nold);
    CHECK_ROWS(PS_J, cap);
    CHECK_ROWS(PS_FULL, cap);
    CHECK_ROWS(PS_KEYS, cap);
    CHECK_ROWS(PS_RA, cap);
    CHECK_ROWS(PS_RD, cap);
    CHECK_ROWS(PS_AMP, cap);
    double threshold = s.v[PS_TH].d, lookahead = s.v[PS_LA].d;
    if (isnan(threshold) || !isfinite(lookahead) || lookahead < 0) {
        PyErr_SetString(PyExc_ValueError, "threshold must be a number and lookahead a finite number of steps >= 0");
        goto fail;
    }
    if (s.v[PS_SELF].i && ka != kb) {
        PyErr_SetString(PyExc_ValueError, "pair_step: self pairs need the same boxes on both sides");
        goto fail;
    }
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_pair_step_in in = {D(PS_LOA), D(PS_HIA), D(PS_LOB), D(PS_HIB), ka, kb, s.v[PS_SELF].i, s.v[PS_FIRST].i,
                           D(PS_FORCED), ROWS(PS_FORCED), D(PS_AA), D(PS_DA), D(PS_AB), D(PS_DB), D(PS_OK), D(PS_OA),
                           D(PS_OD), nold, threshold, lookahead};
    tcc_error err = {0};
    tcc_idx np_ = 0, nfull = 0;
    int rc;
    RUN(tcc_pair_step(&in, cap, D(PS_I), D(PS_J), D(PS_FULL), D(PS_KEYS), D(PS_RA), D(PS_RD), D(PS_AMP), &np_, &nfull,
                      &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    return Py_BuildValue("LL", (long long)np_, (long long)nfull);
fail:
    pyarg_release(&s);
    return NULL;
}

/* the trip rule (measure.c): cluster fits, pair bounds, the spent clearance */
static const pyarg_spec CLUSTER_FIT[] = {
    ARR("positions", PA_F64, 0, 2, 3, 0),
    ARR("previous", PA_F64, 0, 2, 3, 0),
    ARR("order", PA_I64, 0, 1, 0, 0),
    ARR("ptr", PA_I64, 0, 1, 0, 0),
    VAL("reach", PA_DOUBLE),
    ARR("fit", PA_F64, OUT, 2, TCC_FIT_LEN, 0),
};
enum { CF_X, CF_PREV, CF_ORDER, CF_PTR, CF_REACH, CF_FIT, CF_N };

static PyObject *py_cluster_fit(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("cluster_fit", CLUSTER_FIT, CF_N);
    double reach = s.v[CF_REACH].d;
    if (finite_param(reach, "reach", 1)) goto fail;
    Py_ssize_t n = ROWS(CF_X);
    CHECK_ROWS(CF_PREV, n);
    if (!bounds_ok(ROWS(CF_PTR), "ptr", "cluster")) goto fail;
    Py_ssize_t k = ROWS(CF_PTR) - 1;
    CHECK_ROWS(CF_FIT, k);
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_error err = {0};
    int rc;
    RUN(tcc_cluster_fit(D(CF_X), D(CF_PREV), n, D(CF_ORDER), ROWS(CF_ORDER), D(CF_PTR), k, reach, D(CF_FIT), &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    Py_RETURN_NONE;
fail:
    pyarg_release(&s);
    return NULL;
}

static const pyarg_spec PAIR_MOTION[] = {
    ARR("i", PA_I64, 0, 1, 0, 0),
    ARR("j", PA_I64, 0, 1, 0, 0),
    ARR("positions_a", PA_F64, 0, 2, 3, 0),
    ARR("previous_a", PA_F64, 0, 2, 3, 0),
    ARR("order_a", PA_I64, 0, 1, 0, 0),
    ARR("ptr_a", PA_I64, 0, 1, 0, 0),
    ARR("fit_a", PA_F64, 0, 2, TCC_FIT_LEN, 0),
    ARR("positions_b", PA_F64, 0, 2, 3, 0),
    ARR("previous_b", PA_F64, 0, 2, 3, 0),
    ARR("order_b", PA_I64, 0, 1, 0, 0),
    ARR("ptr_b", PA_I64, 0, 1, 0, 0),
    ARR("fit_b", PA_F64, 0, 2, TCC_FIT_LEN, 0),
    VAL("reach", PA_DOUBLE),
    ARR("bound", PA_F64, OUT, 1, 0, 0),
};
enum { PM_I, PM_J, PM_XA, PM_PA, PM_OA, PM_PTA, PM_FA, PM_XB, PM_PB, PM_OB, PM_PTB, PM_FB, PM_REACH, PM_M, PM_N };

/* members of one side: every order entry a vertex, ptr non-decreasing within order (so the kernel,
 * which trusts them, reads nothing out of bounds) */
static int members_ok(pyarg_set *p, int x, int order, int ptr, int fit, const char *side)
{
    Py_ssize_t n = pyarg_nrows(p, x), no = pyarg_nrows(p, order), np1 = pyarg_nrows(p, ptr);
    if (np1 < 1 || pyarg_nrows(p, fit) != np1 - 1) {
        PyErr_Format(PyExc_ValueError, "side %s: ptr must hold k + 1 bounds for the k fitted clusters", side);
        return 0;
    }
    const tcc_idx *o = pyarg_data(p, order), *q = pyarg_data(p, ptr);
    for (Py_ssize_t i = 0; i < no; i++)
        if (o[i] < 0 || o[i] >= n) {
            PyErr_Format(PyExc_IndexError, "side %s: order[%zd] = %lld is not a vertex index", side, i, (long long)o[i]);
            return 0;
        }
    for (Py_ssize_t c = 0; c + 1 < np1; c++)
        if (q[c] < 0 || q[c + 1] < q[c] || q[c + 1] > no) {
            PyErr_Format(PyExc_IndexError, "side %s: cluster %zd spans [%lld, %lld), outside the %zd members", side, c,
                         (long long)q[c], (long long)q[c + 1], no);
            return 0;
        }
    return 1;
}

static PyObject *py_pair_motion(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("pair_motion", PAIR_MOTION, PM_N);
    double reach = s.v[PM_REACH].d;
    if (finite_param(reach, "reach", 1)) goto fail;
    Py_ssize_t np_ = ROWS(PM_I);
    CHECK_ROWS(PM_J, np_);
    CHECK_ROWS(PM_M, np_);
    CHECK_ROWS(PM_PA, ROWS(PM_XA));
    CHECK_ROWS(PM_PB, ROWS(PM_XB));
    if (!members_ok(&s, PM_XA, PM_OA, PM_PTA, PM_FA, "a") || !members_ok(&s, PM_XB, PM_OB, PM_PTB, PM_FB, "b")) goto fail;
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_error err = {0};
    int rc;
    RUN(tcc_pair_motion(D(PM_I), D(PM_J), np_, D(PM_XA), D(PM_PA), D(PM_OA), D(PM_PTA), D(PM_FA), ROWS(PM_FA), D(PM_XB),
                        D(PM_PB), D(PM_OB), D(PM_PTB), D(PM_FB), ROWS(PM_FB), reach, D(PM_M), &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    Py_RETURN_NONE;
fail:
    pyarg_release(&s);
    return NULL;
}

static const pyarg_spec TRIP_MEASURE[] = {
    ARR("old_keys", PA_I64, 0, 1, 0, 0),
    ARR("old_used", PA_F64, 0, 1, 0, 0),
    ARR("i", PA_I64, 0, 1, 0, 0),
    ARR("j", PA_I64, 0, 1, 0, 0),
    ARR("bound", PA_F64, 0, 1, 0, 0),
    ARR("lo_a", PA_F64, 0, 2, 3, 0),
    ARR("hi_a", PA_F64, 0, 2, 3, 0),
    ARR("lo_b", PA_F64, 0, 2, 3, 0),
    ARR("hi_b", PA_F64, 0, 2, 3, 0),
    VAL("inflate", PA_DOUBLE),
    VAL("budget", PA_DOUBLE),
    VAL("thickness", PA_DOUBLE),
    ARR("force", PA_BOOL, OPT, 1, 0, 0),
    VAL("lookahead", PA_DOUBLE),
    ARR("keys", PA_I64, OUT, 1, 0, 0),
    ARR("used", PA_F64, OUT, 1, 0, 0),
    ARR("amplitude", PA_F64, OUT, 1, 0, 0),
    ARR("full", PA_BOOL, OUT, 1, 0, 0),
};
enum { TM_OK, TM_OU, TM_I, TM_J, TM_M, TM_LOA, TM_HIA, TM_LOB, TM_HIB, TM_INFLATE, TM_BUDGET, TM_TH, TM_FORCE,
       TM_LOOKAHEAD, TM_KEYS, TM_USED, TM_AMP, TM_FULL, TM_N };

static PyObject *py_trip_measure(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("trip_measure", TRIP_MEASURE, TM_N);
    double inflate = s.v[TM_INFLATE].d, budget = s.v[TM_BUDGET].d, th = s.v[TM_TH].d, la = s.v[TM_LOOKAHEAD].d;
    if (finite_param(inflate, "inflate", 1) || finite_param(budget, "budget", 1) || finite_param(th, "thickness", 1) ||
        finite_param(la, "lookahead", 1))
        goto fail;
    Py_ssize_t nold = ROWS(TM_OK), np_ = ROWS(TM_I);
    CHECK_ROWS(TM_OU, nold);
    CHECK_ROWS(TM_J, np_);
    CHECK_ROWS(TM_M, np_);
    CHECK_ROWS(TM_HIA, ROWS(TM_LOA));
    CHECK_ROWS(TM_HIB, ROWS(TM_LOB));
    CHECK_ROWS(TM_FORCE, np_);
    CHECK_ROWS(TM_KEYS, np_);
    CHECK_ROWS(TM_USED, np_);
    CHECK_ROWS(TM_AMP, np_);
    CHECK_ROWS(TM_FULL, np_);
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_error err = {0};
    tcc_idx nfull = 0;
    int rc;
    RUN(tcc_trip_measure(D(TM_OK), D(TM_OU), nold, D(TM_I), D(TM_J), np_, D(TM_M), D(TM_LOA), D(TM_HIA), ROWS(TM_LOA),
                         D(TM_LOB), D(TM_HIB), ROWS(TM_LOB), inflate, budget, th, D(TM_FORCE), la, D(TM_KEYS),
                         D(TM_USED), D(TM_AMP), D(TM_FULL), &nfull, &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    return PyLong_FromLongLong(nfull);
fail:
    pyarg_release(&s);
    return NULL;
}

static const pyarg_spec RIGID_FIT[] = {
    ARR("positions", PA_F64, 0, 2, 3, 0),
    ARR("triangles", PA_I64, 0, 2, 3, 0),
    ARR("ref_corners", PA_F64, 0, 3, 3, 3),
    ARR("scene_triangles", PA_I64, 0, 1, 0, 0),
    ARR("R", PA_F64, OUT, 3, 3, 3),
    ARR("centre", PA_F64, OUT, 2, 3, 0),
    ARR("ref_centre", PA_F64, OUT, 2, 3, 0),
    VAL("row", PA_SSIZE),
};
enum { RF_X, RF_T, RF_REF, RF_TRIS, RF_R, RF_CEN, RF_RCEN, RF_ROW, RF_N };

static PyObject *py_rigid_fit(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("rigid_fit", RIGID_FIT, RF_N);
    Py_ssize_t row = s.v[RF_ROW].n, k = ROWS(RF_R);
    CHECK_ROWS(RF_REF, ROWS(RF_TRIS));
    CHECK_ROWS(RF_CEN, k);
    CHECK_ROWS(RF_RCEN, k);
    if (row < 0 || row >= k) {
        PyErr_Format(PyExc_IndexError, "row %zd is not in [0, %zd)", row, k);
        goto fail;
    }
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_mesh m = {D(RF_X), ROWS(RF_X), D(RF_T), ROWS(RF_T), NULL, NULL};
    tcc_error err = {0};
    double resid2 = 0.0;
    int rc;
    RUN(tcc_rigid_fit(&m, D(RF_REF), D(RF_TRIS), ROWS(RF_TRIS), (double *)D(RF_R) + 9 * row,
                      (double *)D(RF_CEN) + 3 * row, (double *)D(RF_RCEN) + 3 * row, &resid2, &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    return PyFloat_FromDouble(resid2);
fail:
    pyarg_release(&s);
    return NULL;
}

static const pyarg_spec RIGID_FIT_MANY[] = {
    ARR("positions", PA_F64, 0, 2, 3, 0),
    ARR("triangles", PA_I64, 0, 2, 3, 0),
    ARR("scene_ptr", PA_I64, 0, 1, 0, 0),
    ARR("scene_triangles", PA_I64, 0, 1, 0, 0),
    ARR("ref_corners", PA_F64, 0, 3, 3, 3),
    ARR("clusters", PA_I64, 0, 1, 0, 0),
    ARR("R", PA_F64, OUT, 3, 3, 3),
    ARR("centre", PA_F64, OUT, 2, 3, 0),
    ARR("ref_centre", PA_F64, OUT, 2, 3, 0),
    ARR("resid2", PA_F64, OUT, 1, 0, 0),
};
enum { RM2_X, RM2_T, RM2_PTR, RM2_TRIS, RM2_REF, RM2_CL, RM2_R, RM2_CEN, RM2_RCEN, RM2_RES, RM2_N };

static PyObject *py_rigid_fit_many(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("rigid_fit_many", RIGID_FIT_MANY, RM2_N);
    if (!bounds_ok(ROWS(RM2_PTR), "scene_ptr", "scene")) goto fail;
    Py_ssize_t k = ROWS(RM2_PTR) - 1, q = ROWS(RM2_CL), nsc = ROWS(RM2_TRIS);
    CHECK_ROWS(RM2_REF, nsc);
    CHECK_ROWS(RM2_R, k);
    CHECK_ROWS(RM2_CEN, k);
    CHECK_ROWS(RM2_RCEN, k);
    CHECK_ROWS(RM2_RES, q);
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_mesh m = {D(RM2_X), ROWS(RM2_X), D(RM2_T), ROWS(RM2_T), NULL, NULL};
    tcc_error err = {0};
    int rc = TCC_OK;
    const tcc_idx *pp = D(RM2_PTR), *cc = D(RM2_CL), *tt = D(RM2_TRIS);
    const double *rf = D(RM2_REF);
    double *Rp = D(RM2_R), *cp = D(RM2_CEN), *rp = D(RM2_RCEN), *out = D(RM2_RES);
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
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    Py_RETURN_NONE;
fail:
    pyarg_release(&s);
    return NULL;
}

static const pyarg_spec WALK[] = {
    RAY_ROWS,
    ARR("start", PA_I64, 0, 1, 0, 0),
    MESH_ROWS("target_"),
    RING_ROW,
    VAL("max_steps", PA_INT),
    HITS_ROWS("tri_out", "t_out", "u_out", "v_out", "flips_out"),
};
enum { WK_X, WK_NRM, WK_RV, WK_RS, WK_START, WK_MESH, WK_RING = WK_MESH + 4, WK_MAX, WK_TRI, WK_T, WK_U, WK_V,
       WK_FLIPS, WK_N };

static PyObject *py_walk(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("walk", WALK, WK_N);
    int max_steps = s.v[WK_MAX].i;
    if (max_steps < 0 || max_steps > 1000) {
        PyErr_Format(PyExc_ValueError, "max_steps must be in [0, 1000], got %d", max_steps);
        goto fail;
    }
    Py_ssize_t n = ROWS(WK_X), k = ROWS(WK_RV);
    CHECK_ROWS(WK_NRM, n);
    CHECK_ROWS(WK_RS, k);
    CHECK_ROWS(WK_START, k);
    tcc_mesh m;
    if (mesh_from(&s, WK_MESH, &m)) goto fail;
    tcc_ring ring = ring_from(&s, WK_RING);
    for (int i = WK_TRI; i <= WK_FLIPS; i++) CHECK_ROWS(i, k);
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_hits out = {D(WK_TRI), D(WK_T), D(WK_U), D(WK_V), D(WK_FLIPS)};
    tcc_error err = {0};
    int rc;
    RUN(tcc_walk(D(WK_X), D(WK_NRM), n, D(WK_RV), D(WK_RS), D(WK_START), k, &m, &ring, max_steps, out, &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    Py_RETURN_NONE;
fail:
    pyarg_release(&s);
    return NULL;
}

static const pyarg_spec PREPARE_RAYS[] = {
    ARR("positions", PA_F64, 0, 2, 3, 0),
    ARR("normals", PA_F64, 0, 2, 3, 0),
    ARR("has_normal", PA_BOOL, 0, 1, 0, 0),
    ARR("long_mask", PA_BOOL, OPT, 1, 0, 0),
    ARR("order", PA_I64, 0, 1, 0, 0),
    ARR("ptr", PA_I64, 0, 1, 0, 0),
    ARR("box_lo", PA_F64, 0, 2, 3, 0),
    ARR("box_hi", PA_F64, 0, 2, 3, 0),
    ARR("pair_a", PA_I64, 0, 1, 0, 0),
    ARR("pair_b", PA_I64, 0, 1, 0, 0),
    ARR("clusters", PA_I64, 0, 1, 0, 0),
    ARR("R", PA_F64, 0, 3, 3, 3),
    ARR("centre", PA_F64, 0, 2, 3, 0),
    ARR("ref_centre", PA_F64, 0, 2, 3, 0),
    VAL("short_dist", PA_DOUBLE),
    VAL("long_dist", PA_DOUBLE),
    VAL("backoff", PA_DOUBLE),
    VAL("tolerance", PA_DOUBLE),
    ARR("origins", PA_F32, OUT, 2, 3, 0),
    ARR("directions", PA_F32, OUT, 2, 3, 0),
    ARR("dists", PA_F32, OUT, 1, 0, 0),
    ARR("ray_vertex", PA_I64, OUT, 1, 0, 0),
    ARR("ray_slot", PA_I64, OUT, 1, 0, 0),
    ARR("segments", PA_I64, OUT, 1, 0, 0),
};
enum { PR_X, PR_NRM, PR_HAS, PR_LONG, PR_ORDER, PR_PTR, PR_BLO, PR_BHI, PR_PA, PR_PB, PR_CL, PR_R, PR_CEN, PR_RCEN,
       PR_SD, PR_LD, PR_BACKOFF, PR_TOL, PR_O, PR_D, PR_DIST, PR_RV, PR_RS, PR_SEG, PR_N };

static PyObject *py_prepare_rays(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("prepare_rays", PREPARE_RAYS, PR_N);
    double sd = s.v[PR_SD].d, ld = s.v[PR_LD].d, backoff = s.v[PR_BACKOFF].d, tol = s.v[PR_TOL].d;
    if (finite_param(sd, "short_dist", 1) || finite_param(ld, "long_dist", 1) || finite_param(backoff, "backoff", 1) ||
        finite_param(tol, "tolerance", 1))
        goto fail;
    Py_ssize_t n = ROWS(PR_X);
    CHECK_ROWS(PR_NRM, n);
    CHECK_ROWS(PR_HAS, n);
    CHECK_ROWS(PR_LONG, n);
    if (!bounds_ok(ROWS(PR_PTR), "ptr", "cluster")) goto fail;
    Py_ssize_t kb = ROWS(PR_BLO), q = ROWS(PR_CL), cap = ROWS(PR_O);
    CHECK_ROWS(PR_BHI, kb);
    CHECK_ROWS(PR_PB, ROWS(PR_PA));
    CHECK_ROWS(PR_R, kb);
    CHECK_ROWS(PR_CEN, kb);
    CHECK_ROWS(PR_RCEN, kb);
    for (int i = PR_D; i <= PR_RS; i++) CHECK_ROWS(i, cap);
    CHECK_ROWS(PR_SEG, q + 1);
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_ray_setup setup = {D(PR_X), D(PR_NRM), D(PR_HAS), D(PR_LONG), n, D(PR_ORDER), D(PR_PTR), ROWS(PR_ORDER),
                           ROWS(PR_PTR) - 1, D(PR_BLO), D(PR_BHI), kb, sd, ld, backoff, tol};
    tcc_error err = {0};
    tcc_idx count = 0;
    int rc;
    RUN(tcc_prepare_rays(&setup, D(PR_PA), D(PR_PB), ROWS(PR_PA), D(PR_CL), D(PR_R), D(PR_CEN), D(PR_RCEN), q, D(PR_O),
                         D(PR_D), D(PR_DIST), D(PR_RV), D(PR_RS), cap, D(PR_SEG), &count, &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    return PyLong_FromLongLong(count);
fail:
    pyarg_release(&s);
    return NULL;
}

static const pyarg_spec ACCEPT_HITS[] = {
    ARR("rays", PA_I64, 0, 1, 0, 0),
    ARR("prim", PA_I32, 0, 1, 0, 0),
    ARR("tfar", PA_F32, OPT, 1, 0, 0),
    ARR("scene_triangles", PA_I64, 0, 1, 0, 0),
    ARR("ray_vertex", PA_I64, 0, 1, 0, 0),
    ARR("target_triangles", PA_I64, 0, 2, 3, 0),
    RING_ROW,
    ARR("origins", PA_F32, OUT, 2, 3, 0),
    ARR("directions", PA_F32, 0, 2, 3, 0),
    ARR("dists", PA_F32, OUT, 1, 0, 0),
    ARR("hit_triangle", PA_I64, OUT, 1, 0, 0),
    ARR("retry", PA_I64, OUT, 1, 0, 0),
};
enum { AH_RAYS, AH_PRIM, AH_TFAR, AH_STRIS, AH_RV, AH_TT, AH_RING, AH_O, AH_D, AH_DIST, AH_HIT, AH_RETRY, AH_N };

static PyObject *py_accept_hits(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("accept_hits", ACCEPT_HITS, AH_N);
    Py_ssize_t r = ROWS(AH_RAYS), nr = ROWS(AH_RV);
    CHECK_ROWS(AH_PRIM, r);
    CHECK_ROWS(AH_TFAR, r);
    tcc_ring ring = ring_from(&s, AH_RING);
    for (int i = AH_O; i <= AH_HIT; i++) CHECK_ROWS(i, nr);
    if (ring.table && ROWS(AH_RETRY) < r) {
        PyErr_Format(PyExc_ValueError, "retry must have room for the %zd rays (has %zd)", r, ROWS(AH_RETRY));
        goto fail;
    }
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_mesh m = {NULL, 0, D(AH_TT), ROWS(AH_TT), NULL, NULL};
    tcc_error err = {0};
    tcc_idx nretry = 0;
    int rc;
    RUN(tcc_accept_hits(D(AH_RAYS), D(AH_PRIM), D(AH_TFAR), r, D(AH_STRIS), ROWS(AH_STRIS), D(AH_RV), nr, &m, &ring,
                        D(AH_O), D(AH_D), D(AH_DIST), D(AH_HIT), D(AH_RETRY), &nretry, &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    return PyLong_FromLongLong(nretry);
fail:
    pyarg_release(&s);
    return NULL;
}

static const pyarg_spec REFINE[] = {
    RAY_ROWS,
    ARR("hit_triangle", PA_I64, 0, 1, 0, 0),
    MESH_ROWS("target_"),
    RING_ROW,
    VAL("kind", PA_INT),
    VAL("track_range", PA_DOUBLE),
    ARR("inside_prev", PA_BOOL, OPT, 1, 0, 0),
    ARR("out_vertex", PA_I64, OUT, 1, 0, 0),
    ARR("out_slot", PA_I64, OUT, 1, 0, 0),
    HITS_ROWS("out_tri", "out_t", "out_u", "out_v", "out_flips"),
    ARR("status", PA_BOOL, OUT, 1, 0, 0),
};
enum { RE_X, RE_NRM, RE_RV, RE_RS, RE_HIT, RE_MESH, RE_RING = RE_MESH + 4, RE_KIND, RE_RANGE, RE_INSIDE, RE_OV,
       RE_OS, RE_OT, RE_OTP, RE_OU, RE_OVV, RE_OF, RE_STATUS, RE_N };

static PyObject *py_refine(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("refine", REFINE, RE_N);
    int kind = s.v[RE_KIND].i;
    double track_range = s.v[RE_RANGE].d;
    if (!kind_ok(kind) || finite_param(track_range, "track_range", 1)) goto fail;
    Py_ssize_t n = ROWS(RE_X), r = ROWS(RE_RV);
    CHECK_ROWS(RE_NRM, n);
    CHECK_ROWS(RE_RS, r);
    CHECK_ROWS(RE_HIT, r);
    tcc_mesh m;
    if (mesh_from(&s, RE_MESH, &m)) goto fail;
    tcc_ring ring = ring_from(&s, RE_RING);
    CHECK_ROWS(RE_INSIDE, n);
    for (int i = RE_OV; i <= RE_STATUS; i++) CHECK_ROWS(i, r);
    if (!m.adj || !m.flip) {
        PyErr_SetString(PyExc_ValueError, "refine walks: adjacency and flip are required");
        goto fail;
    }
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_hits out = {D(RE_OT), D(RE_OTP), D(RE_OU), D(RE_OVV), D(RE_OF)};
    tcc_error err = {0};
    tcc_idx count = 0;
    int rc;
    RUN(tcc_refine(D(RE_X), D(RE_NRM), n, D(RE_RV), D(RE_RS), D(RE_HIT), r, &m, &ring, kind, track_range, D(RE_INSIDE),
                   D(RE_OV), D(RE_OS), out, D(RE_STATUS), &count, &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    return PyLong_FromLongLong(count);
fail:
    pyarg_release(&s);
    return NULL;
}

static const pyarg_spec DROP_DOMINATED[] = {
    ARR("vertex", PA_I64, 0, 1, 0, 0),
    ARR("slot", PA_I64, 0, 1, 0, 0),
    ARR("t", PA_F64, 0, 1, 0, 0),
    ARR("status", PA_BOOL, OUT, 1, 0, 0),
    ARR("track_key", PA_I64, 0, 1, 0, 0),
    ARR("walked_tri", PA_I64, 0, 1, 0, 0),
    ARR("walked_t", PA_F64, 0, 1, 0, 0),
};
enum { DD_V, DD_S, DD_T, DD_ST, DD_TK, DD_WT, DD_WTP, DD_N };

static PyObject *py_drop_dominated(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("drop_dominated", DROP_DOMINATED, DD_N);
    Py_ssize_t k = ROWS(DD_V);
    CHECK_ROWS(DD_S, k);
    CHECK_ROWS(DD_T, k);
    CHECK_ROWS(DD_ST, k);
    CHECK_ROWS(DD_WT, ROWS(DD_TK));
    CHECK_ROWS(DD_WTP, ROWS(DD_TK));
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_error err = {0};
    tcc_idx left = 0;
    int rc;
    RUN(tcc_drop_dominated(D(DD_V), D(DD_S), D(DD_T), D(DD_ST), k, D(DD_TK), ROWS(DD_TK), D(DD_WT), D(DD_WTP), &left,
                           &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    return PyLong_FromLongLong(left);
fail:
    pyarg_release(&s);
    return NULL;
}

static const pyarg_spec CONFIRM_INSIDE[] = {
    ARR("target_vertices", PA_F64, 0, 2, 3, 0),
    ARR("target_triangles", PA_I64, 0, 2, 3, 0),
    ARR("tri_order", PA_I64, 0, 1, 0, 0),
    ARR("tri_ptr", PA_I64, 0, 1, 0, 0),
    ARR("lo", PA_F64, 0, 2, 3, 0),
    ARR("hi", PA_F64, 0, 2, 3, 0),
    ARR("origins", PA_F64, 0, 2, 3, 0),
    ARR("directions", PA_F64, 0, 2, 3, 0),
    ARR("t_exit", PA_F64, 0, 1, 0, 0),
    ARR("exit_tri", PA_I64, 0, 1, 0, 0),
    VAL("backoff", PA_DOUBLE),
    VAL("eps", PA_DOUBLE),
    ARR("ok", PA_BOOL, OUT, 1, 0, 0),
};
enum { CI_TX, CI_TT, CI_ORDER, CI_PTR, CI_LO, CI_HI, CI_O, CI_D, CI_TE, CI_ET, CI_BACKOFF, CI_EPS, CI_OK, CI_N };

static PyObject *py_confirm_inside(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("confirm_inside", CONFIRM_INSIDE, CI_N);
    double backoff = s.v[CI_BACKOFF].d, eps = s.v[CI_EPS].d;
    if (finite_param(backoff, "backoff", 1) || finite_param(eps, "eps", 1)) goto fail;
    if (!bounds_ok(ROWS(CI_PTR), "tri_ptr", "cluster")) goto fail;
    Py_ssize_t k = ROWS(CI_PTR) - 1, r = ROWS(CI_O);
    CHECK_ROWS(CI_LO, k);
    CHECK_ROWS(CI_HI, k);
    CHECK_ROWS(CI_D, r);
    CHECK_ROWS(CI_TE, r);
    CHECK_ROWS(CI_ET, r);
    CHECK_ROWS(CI_OK, r);
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_mesh m = {D(CI_TX), ROWS(CI_TX), D(CI_TT), ROWS(CI_TT), NULL, NULL};
    tcc_error err = {0};
    int rc;
    RUN(tcc_confirm_inside(&m, D(CI_ORDER), ROWS(CI_ORDER), D(CI_PTR), k, D(CI_LO), D(CI_HI), D(CI_O), D(CI_D),
                           D(CI_TE), D(CI_ET), r, backoff, eps, D(CI_OK), &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    Py_RETURN_NONE;
fail:
    pyarg_release(&s);
    return NULL;
}

static const pyarg_spec MERGE_CLASSIFY[] = {
    ARR("positions", PA_F64, 0, 2, 3, 0),
    ARR("normals", PA_F64, 0, 2, 3, 0),
    ARR("previous", PA_F64, 0, 2, 3, 0),
    ARR("velocity", PA_F64, OPT, 2, 3, 0),
    ARR("target_vertices", PA_F64, 0, 2, 3, 0),
    ARR("target_triangles", PA_I64, 0, 2, 3, 0),
    ARR("target_previous", PA_F64, 0, 2, 3, 0),
    ARR("target_velocity", PA_F64, OPT, 2, 3, 0),
    VAL("kind", PA_INT),
    VAL("first", PA_FLAG),
    VAL("thickness", PA_DOUBLE),
    VAL("track_range", PA_DOUBLE),
    ARR("track_key", PA_I64, 0, 1, 0, 0),
    ARR("track_tri", PA_I64, 0, 1, 0, 0),
    ARR("track_side", PA_I8, 0, 1, 0, 0),
    ARR("walked_tri", PA_I64, 0, 1, 0, 0),
    ARR("walked_t", PA_F64, 0, 1, 0, 0),
    ARR("walked_u", PA_F64, 0, 1, 0, 0),
    ARR("walked_v", PA_F64, 0, 1, 0, 0),
    ARR("walked_flips", PA_BOOL, 0, 1, 0, 0),
    ARR("found_vertex", PA_I64, 0, 1, 0, 0),
    ARR("found_slot", PA_I64, 0, 1, 0, 0),
    ARR("found_tri", PA_I64, 0, 1, 0, 0),
    ARR("found_t", PA_F64, 0, 1, 0, 0),
    ARR("found_u", PA_F64, 0, 1, 0, 0),
    ARR("found_v", PA_F64, 0, 1, 0, 0),
    ARR("found_flips", PA_BOOL, 0, 1, 0, 0),
    ARR("found_status", PA_BOOL, OPT, 1, 0, 0),
    ARR("out_key", PA_I64, OUT, 1, 0, 0),
    ARR("out_tri", PA_I64, OUT, 1, 0, 0),
    ARR("out_side", PA_I8, OUT, 1, 0, 0),
    ARR("out_inside", PA_I64, OUT, 1, 0, 0),
    ARR("contact_vertex", PA_I64, OUT, 1, 0, 0),
    ARR("depth", PA_F64, OUT, 1, 0, 0),
    ARR("normal", PA_F64, OUT, 2, 3, 0),
    ARR("contact_velocity", PA_F64, OUT, 2, 3, 0),
};
enum { MC_X, MC_NRM, MC_XP, MC_VEL, MC_TX, MC_TT, MC_TP, MC_TV, MC_KIND, MC_FIRST, MC_TH, MC_TR, MC_TK, MC_TTRI,
       MC_TSIDE, MC_WT, MC_WTP, MC_WU, MC_WV, MC_WF, MC_FV, MC_FS, MC_FT, MC_FTP, MC_FU, MC_FVV, MC_FF, MC_FST,
       MC_OKEY, MC_OTRI, MC_OSIDE, MC_OIN, MC_CV, MC_DEP, MC_ONRM, MC_OVEL, MC_N };

static PyObject *py_merge_classify(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("merge_classify", MERGE_CLASSIFY, MC_N);
    int kind = s.v[MC_KIND].i;
    double th = s.v[MC_TH].d, tr = s.v[MC_TR].d;
    if (!kind_ok(kind) || finite_param(th, "thickness", 1) || finite_param(tr, "track_range", 1)) goto fail;
    Py_ssize_t n = ROWS(MC_X), nv = ROWS(MC_TX), kt = ROWS(MC_TK), kf = ROWS(MC_FV), cap = ROWS(MC_OKEY);
    CHECK_ROWS(MC_NRM, n);
    CHECK_ROWS(MC_XP, n);
    CHECK_ROWS(MC_VEL, n);
    CHECK_ROWS(MC_TP, nv);
    CHECK_ROWS(MC_TV, nv);
    for (int i = MC_TTRI; i <= MC_WF; i++) CHECK_ROWS(i, kt);
    for (int i = MC_FS; i <= MC_FST; i++) CHECK_ROWS(i, kf);
    if (cap < kt + kf) {
        PyErr_Format(PyExc_ValueError, "the outputs need room for %zd entries (tracks + new hits), out_key has %zd",
                     kt + kf, cap);
        goto fail;
    }
    for (int i = MC_OTRI; i <= MC_OVEL; i++) CHECK_ROWS(i, cap);
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_mesh m = {D(MC_TX), nv, D(MC_TT), ROWS(MC_TT), NULL, NULL};
    tcc_merge_in in = {
        .x = D(MC_X), .normals = D(MC_NRM), .x_prev = D(MC_XP), .velocity = D(MC_VEL), .n = n, .target = &m,
        .target_prev = D(MC_TP), .target_velocity = D(MC_TV), .kind = kind, .first = s.v[MC_FIRST].i,
        .thickness = th, .track_range = tr, .track_key = D(MC_TK), .track_tri = D(MC_TTRI),
        .track_side = D(MC_TSIDE), .kt = kt, .walked = {D(MC_WT), D(MC_WTP), D(MC_WU), D(MC_WV), D(MC_WF)},
        .f_v = D(MC_FV), .f_slot = D(MC_FS), .f_hit = {D(MC_FT), D(MC_FTP), D(MC_FU), D(MC_FVV), D(MC_FF)},
        .f_status = D(MC_FST), .kf = kf,
    };
    tcc_merge_out out = {.track_key = D(MC_OKEY), .track_tri = D(MC_OTRI), .track_side = D(MC_OSIDE),
                         .inside = D(MC_OIN), .contact_v = D(MC_CV), .depth = D(MC_DEP), .normal = D(MC_ONRM),
                         .velocity = D(MC_OVEL)};
    tcc_error err = {0};
    int rc;
    RUN(tcc_merge_classify(&in, &out, &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    return Py_BuildValue("(LLL)", (long long)out.ntracks, (long long)out.ninside, (long long)out.ncontacts);
fail:
    pyarg_release(&s);
    return NULL;
}

static const pyarg_spec ASSEMBLE[] = {
    ARR("segments", PA_I64, 0, 1, 0, 0),
    ARR("vertex", PA_I64, 0, 1, 0, 0),
    ARR("depth", PA_F64, 0, 1, 0, 0),
    ARR("normal", PA_F64, 0, 2, 3, 0),
    ARR("velocity", PA_F64, 0, 2, 3, 0),
    ARR("friction", PA_F64, 0, 1, 0, 0),
    VAL("n", PA_SSIZE),
    ARR("deep_vertex", PA_I32, OUT, 1, 0, 0),
    ARR("deep_normal", PA_F64, OUT, 2, 3, 0),
    ARR("deep_depth", PA_F64, OUT, 1, 0, 0),
    ARR("deep_velocity", PA_F64, OUT, 2, 3, 0),
    ARR("deep_friction", PA_F64, OUT, 1, 0, 0),
    ARR("all_vertex", PA_I32, OUT, 1, 0, 0),
    ARR("all_normal", PA_F64, OUT, 2, 3, 0),
    ARR("all_depth", PA_F64, OUT, 1, 0, 0),
    ARR("all_velocity", PA_F64, OUT, 2, 3, 0),
    ARR("all_friction", PA_F64, OUT, 1, 0, 0),
};
enum { AS_SEG, AS_V, AS_DEP, AS_NRM, AS_VEL, AS_FR, AS_NV, AS_DV, AS_DN, AS_DD, AS_DVEL, AS_DFR, AS_AV, AS_AN,
       AS_AD, AS_AVEL, AS_AFR, AS_N };

static PyObject *py_assemble(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("assemble", ASSEMBLE, AS_N);
    Py_ssize_t n = s.v[AS_NV].n;
    if (n < 0 || n > 0x7fffffff) {
        PyErr_Format(PyExc_ValueError, "n must be a vertex count in [0, 2^31), got %zd", n);
        goto fail;
    }
    if (ROWS(AS_SEG) < 1) {
        PyErr_SetString(PyExc_ValueError, "segments must hold the c + 1 bounds (at least one entry)");
        goto fail;
    }
    Py_ssize_t cc = ROWS(AS_SEG) - 1, k = ROWS(AS_V);
    CHECK_ROWS(AS_DEP, k);
    CHECK_ROWS(AS_NRM, k);
    CHECK_ROWS(AS_VEL, k);
    CHECK_ROWS(AS_FR, cc);
    const tcc_idx *sp = D(AS_SEG);
    if (sp[cc] != k) {
        PyErr_Format(PyExc_ValueError, "segments must end at the %zd contacts, ends at %lld", k, (long long)sp[cc]);
        goto fail;
    }
    for (int i = AS_DV; i <= AS_AFR; i++) CHECK_ROWS(i, k);
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_idx kd = 0, ka = 0;
    tcc_error err = {0};
    int rc;
    RUN(tcc_assemble(D(AS_SEG), cc, D(AS_V), D(AS_DEP), D(AS_NRM), D(AS_VEL), D(AS_FR), n, D(AS_DV), D(AS_DN),
                     D(AS_DD), D(AS_DVEL), D(AS_DFR), &kd, D(AS_AV), D(AS_AN), D(AS_AD), D(AS_AVEL), D(AS_AFR), &ka,
                     &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    return Py_BuildValue("(LL)", (long long)kd, (long long)ka);
fail:
    pyarg_release(&s);
    return NULL;
}

static const pyarg_spec CCD_VERTEX_TRIANGLE[] = {
    ARR("start", PA_F64, 0, 2, 3, 0),
    ARR("end", PA_F64, 0, 2, 3, 0),
    ARR("triangles", PA_I64, 0, 2, 3, 0),
    ARR("vertex", PA_I64, 0, 1, 0, 0),
    ARR("triangle", PA_I64, 0, 1, 0, 0),
    VAL("gap", PA_DOUBLE),
    ARR("toi", PA_F64, OUT, 1, 0, 0),
    ARR("weights", PA_F64, OUT, 2, 3, 0),
    ARR("side", PA_I8, OUT, 1, 0, 0),
    ARR("pair_gap", PA_F64, OPT, 1, 0, 0),
};
enum { CC_X0, CC_X1, CC_T, CC_V, CC_TRI, CC_GAP, CC_TOI, CC_W, CC_SIDE, CC_PG, CC_N };

static PyObject *py_ccd_vertex_triangle(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("ccd_vertex_triangle", CCD_VERTEX_TRIANGLE, CC_N);
    double gap = s.v[CC_GAP].d;
    if (finite_param(gap, "gap", 1)) goto fail;
    Py_ssize_t n = ROWS(CC_X0), k = ROWS(CC_V);
    CHECK_ROWS(CC_X1, n);
    CHECK_ROWS(CC_TRI, k);
    CHECK_ROWS(CC_TOI, k);
    CHECK_ROWS(CC_W, k);
    CHECK_ROWS(CC_SIDE, k);
    CHECK_ROWS(CC_PG, k);
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_error err = {0};
    tcc_idx hits = 0;
    int rc;
    RUN(tcc_ccd_vertex_triangle(D(CC_X0), D(CC_X1), n, D(CC_T), ROWS(CC_T), D(CC_V), D(CC_TRI), k, gap, D(CC_PG), D(CC_TOI),
                                D(CC_W), D(CC_SIDE), &hits, &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    return PyLong_FromLongLong(hits);
fail:
    pyarg_release(&s);
    return NULL;
}

static const pyarg_spec VERTEX_TRIANGLE_STATE[] = {
    ARR("positions", PA_F64, 0, 2, 3, 0),
    ARR("triangles", PA_I64, 0, 2, 3, 0),
    ARR("vertex", PA_I64, 0, 1, 0, 0),
    ARR("triangle", PA_I64, 0, 1, 0, 0),
    ARR("sd", PA_F64, OUT, 1, 0, 0),
    ARR("dist", PA_F64, OUT, 1, 0, 0),
    ARR("weights", PA_F64, OUT, 2, 3, 0),
    ARR("normal", PA_F64, OUT, 2, 3, 0),
};
enum { VS_X, VS_T, VS_V, VS_TRI, VS_SD, VS_DIST, VS_W, VS_NRM, VS_N };

static PyObject *py_vertex_triangle_state(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("vertex_triangle_state", VERTEX_TRIANGLE_STATE, VS_N);
    Py_ssize_t k = ROWS(VS_V);
    CHECK_ROWS(VS_TRI, k);
    CHECK_ROWS(VS_SD, k);
    CHECK_ROWS(VS_DIST, k);
    CHECK_ROWS(VS_W, k);
    CHECK_ROWS(VS_NRM, k);
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_error err = {0};
    int rc;
    RUN(tcc_vertex_triangle_state(D(VS_X), ROWS(VS_X), D(VS_T), ROWS(VS_T), D(VS_V), D(VS_TRI), k, D(VS_SD),
                                  D(VS_DIST), D(VS_W), D(VS_NRM), &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    Py_RETURN_NONE;
fail:
    pyarg_release(&s);
    return NULL;
}

static const pyarg_spec CCD_EDGE_EDGE[] = {
    ARR("start", PA_F64, 0, 2, 3, 0),
    ARR("end", PA_F64, 0, 2, 3, 0),
    ARR("edge_a", PA_I64, 0, 2, 2, 0),
    ARR("edge_b", PA_I64, 0, 2, 2, 0),
    VAL("gap", PA_DOUBLE),
    ARR("toi", PA_F64, OUT, 1, 0, 0),
    ARR("params", PA_F64, OUT, 2, 2, 0),
    ARR("side", PA_I8, OUT, 1, 0, 0),
    ARR("pair_gap", PA_F64, OPT, 1, 0, 0),
};
enum { CE_X0, CE_X1, CE_EA, CE_EB, CE_GAP, CE_TOI, CE_ST, CE_SIDE, CE_PG, CE_N };

static PyObject *py_ccd_edge_edge(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("ccd_edge_edge", CCD_EDGE_EDGE, CE_N);
    double gap = s.v[CE_GAP].d;
    if (finite_param(gap, "gap", 1)) goto fail;
    Py_ssize_t n = ROWS(CE_X0), k = ROWS(CE_EA);
    CHECK_ROWS(CE_X1, n);
    CHECK_ROWS(CE_EB, k);
    CHECK_ROWS(CE_TOI, k);
    CHECK_ROWS(CE_ST, k);
    CHECK_ROWS(CE_SIDE, k);
    CHECK_ROWS(CE_PG, k);
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_error err = {0};
    tcc_idx hits = 0;
    int rc;
    RUN(tcc_ccd_edge_edge(D(CE_X0), D(CE_X1), n, D(CE_EA), D(CE_EB), k, gap, D(CE_PG), D(CE_TOI), D(CE_ST), D(CE_SIDE), &hits,
                          &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    return PyLong_FromLongLong(hits);
fail:
    pyarg_release(&s);
    return NULL;
}

static const pyarg_spec EDGE_EDGE_STATE[] = {
    ARR("positions", PA_F64, 0, 2, 3, 0),
    ARR("edge_a", PA_I64, 0, 2, 2, 0),
    ARR("edge_b", PA_I64, 0, 2, 2, 0),
    ARR("sd", PA_F64, OUT, 1, 0, 0),
    ARR("dist", PA_F64, OUT, 1, 0, 0),
    ARR("params", PA_F64, OUT, 2, 2, 0),
    ARR("normal", PA_F64, OUT, 2, 3, 0),
};
enum { ES_X, ES_EA, ES_EB, ES_SD, ES_DIST, ES_ST, ES_NRM, ES_N };

static PyObject *py_edge_edge_state(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("edge_edge_state", EDGE_EDGE_STATE, ES_N);
    Py_ssize_t k = ROWS(ES_EA);
    CHECK_ROWS(ES_EB, k);
    CHECK_ROWS(ES_SD, k);
    CHECK_ROWS(ES_DIST, k);
    CHECK_ROWS(ES_ST, k);
    CHECK_ROWS(ES_NRM, k);
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_error err = {0};
    int rc;
    RUN(tcc_edge_edge_state(D(ES_X), ROWS(ES_X), D(ES_EA), D(ES_EB), k, D(ES_SD), D(ES_DIST), D(ES_ST), D(ES_NRM),
                            &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    Py_RETURN_NONE;
fail:
    pyarg_release(&s);
    return NULL;
}

/* ---------------------------------------------------------------- bvh.c */

/* a cluster BVH forest from five consecutive rows: node_ptr (k+1), node (N, 2), box (N, 6), prim */
#define BVH_ROWS(box_flags)                                                                                           \
    ARR("node_ptr", PA_I64, 0, 1, 0, 0), ARR("node", PA_I64, 0, 2, 2, 0), ARR("box", PA_F64, box_flags, 2, 6, 0),     \
        ARR("prim", PA_I64, 0, 1, 0, 0)

static int bvh_from(pyarg_set *p, int first, tcc_bvh *b)
{
    if (!bounds_ok(pyarg_nrows(p, first), "node_ptr", "cluster")) return -1;
    if (pyarg_rows(p, first + 2, pyarg_nrows(p, first + 1))) return -1;
    b->node_ptr = pyarg_data(p, first);
    b->k = pyarg_nrows(p, first) - 1;
    b->node = pyarg_data(p, first + 1);
    b->box = pyarg_data(p, first + 2);
    b->nnodes = pyarg_nrows(p, first + 1);
    b->prim = pyarg_data(p, first + 3);
    b->nprim = pyarg_nrows(p, first + 3);
    b->corner = NULL;
    return 0;
}

static const pyarg_spec BVH_BUILD[] = {
    ARR("positions", PA_F64, 0, 2, 3, 0),
    ARR("triangles", PA_I64, 0, 2, 3, 0),
    ARR("scene_ptr", PA_I64, 0, 1, 0, 0),
    ARR("scene_triangles", PA_I64, 0, 1, 0, 0),
    ARR("node_ptr", PA_I64, OUT, 1, 0, 0),
    ARR("node", PA_I64, OUT, 2, 2, 0),
    ARR("box", PA_F64, OUT, 2, 6, 0),
    ARR("prim", PA_I64, OUT, 1, 0, 0),
};
enum { BB_X, BB_T, BB_SP, BB_ST, BB_NP, BB_NODE, BB_BOX, BB_PRIM, BB_N };

static PyObject *py_bvh_build(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("bvh_build", BVH_BUILD, BB_N);
    if (!bounds_ok(ROWS(BB_SP), "scene_ptr", "cluster")) goto fail;
    Py_ssize_t k = ROWS(BB_SP) - 1, nrows = ROWS(BB_ST);
    CHECK_ROWS(BB_NP, k + 1);
    CHECK_ROWS(BB_BOX, ROWS(BB_NODE));
    CHECK_ROWS(BB_PRIM, nrows);
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_mesh m = {D(BB_X), ROWS(BB_X), D(BB_T), ROWS(BB_T), NULL, NULL};
    tcc_error err = {0};
    tcc_idx nnodes = 0;
    int rc;
    RUN(tcc_bvh_build(&m, D(BB_SP), D(BB_ST), nrows, k, D(BB_NP), D(BB_NODE), D(BB_BOX), ROWS(BB_NODE), D(BB_PRIM),
                      &nnodes, &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    return PyLong_FromLongLong(nnodes);
fail:
    pyarg_release(&s);
    return NULL;
}

static const pyarg_spec BVH_REFIT[] = {
    ARR("positions", PA_F64, 0, 2, 3, 0),
    ARR("triangles", PA_I64, 0, 2, 3, 0),
    BVH_ROWS(OUT),
    ARR("clusters", PA_I64, 0, 1, 0, 0),
};
enum { BR_X, BR_T, BR_BVH, BR_CL = BR_BVH + 4, BR_N };

static PyObject *py_bvh_refit(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("bvh_refit", BVH_REFIT, BR_N);
    tcc_bvh b;
    if (bvh_from(&s, BR_BVH, &b)) goto fail;
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_mesh m = {D(BR_X), ROWS(BR_X), D(BR_T), ROWS(BR_T), NULL, NULL};
    tcc_error err = {0};
    const tcc_idx *cl = D(BR_CL);
    Py_ssize_t q = ROWS(BR_CL);
    int rc = TCC_OK;
    Py_BEGIN_ALLOW_THREADS for (Py_ssize_t i = 0; i < q && rc == TCC_OK; i++) rc = tcc_bvh_refit(&m, &b, cl[i], &err);
    Py_END_ALLOW_THREADS pyarg_release(&s);
    if (rc) return kernel_error(&err);
    Py_RETURN_NONE;
fail:
    pyarg_release(&s);
    return NULL;
}

static const pyarg_spec BVH_CAST[] = {
    ARR("positions", PA_F64, 0, 2, 3, 0),
    ARR("triangles", PA_I64, 0, 2, 3, 0),
    BVH_ROWS(0),
    ARR("cluster", PA_I64, 0, 1, 0, 0),
    ARR("origins", PA_F64, 0, 2, 3, 0),
    ARR("directions", PA_F64, 0, 2, 3, 0),
    ARR("tmax", PA_F64, 0, 1, 0, 0),
    ARR("ray_vertex", PA_I64, OPT, 1, 0, 0),
    RING_ROW,
    ARR("tri_out", PA_I64, OUT, 1, 0, 0),
    ARR("t_out", PA_F64, OUT, 1, 0, 0),
    ARR("u_out", PA_F64, OUT, 1, 0, 0),
    ARR("v_out", PA_F64, OUT, 1, 0, 0),
};
enum { BC_X, BC_T, BC_BVH, BC_CL = BC_BVH + 4, BC_O, BC_D, BC_TMAX, BC_RV, BC_RING, BC_TRI, BC_TT, BC_U, BC_V, BC_N };

static PyObject *py_bvh_cast(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("bvh_cast", BVH_CAST, BC_N);
    tcc_bvh b;
    if (bvh_from(&s, BC_BVH, &b)) goto fail;
    Py_ssize_t r = ROWS(BC_CL);
    for (int i = BC_O; i <= BC_RV; i++) CHECK_ROWS(i, r);
    for (int i = BC_TRI; i <= BC_V; i++) CHECK_ROWS(i, r);
    tcc_ring ring = ring_from(&s, BC_RING);
    if (ring.table && !D(BC_RV)) {
        PyErr_SetString(PyExc_ValueError, "skipping the two-ring needs ray_vertex");
        goto fail;
    }
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_mesh m = {D(BC_X), ROWS(BC_X), D(BC_T), ROWS(BC_T), NULL, NULL};
    uint8_t *flips = PyMem_Malloc(r > 0 ? (size_t)r : 1);
    if (!flips) {
        PyErr_NoMemory();
        goto fail;
    }
    tcc_hits out = {D(BC_TRI), D(BC_TT), D(BC_U), D(BC_V), flips};
    tcc_error err = {0};
    int rc;
    RUN(tcc_bvh_cast(&m, &b, D(BC_CL), D(BC_O), D(BC_D), D(BC_TMAX), D(BC_RV), r, &ring, out, &err));
    PyMem_Free(flips);
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    Py_RETURN_NONE;
fail:
    pyarg_release(&s);
    return NULL;
}

static const pyarg_spec SELF_CAST[] = {
    ARR("positions", PA_F64, 0, 2, 3, 0),
    ARR("normals", PA_F64, 0, 2, 3, 0),
    ARR("has_normal", PA_BOOL, 0, 1, 0, 0),
    ARR("order", PA_I64, 0, 1, 0, 0),
    ARR("ptr", PA_I64, 0, 1, 0, 0),
    ARR("box_lo", PA_F64, 0, 2, 3, 0),
    ARR("box_hi", PA_F64, 0, 2, 3, 0),
    ARR("triangles", PA_I64, 0, 2, 3, 0),
    BVH_ROWS(OUT),
    ARR("refit_step", PA_I64, OUT, 1, 0, 0),
    VAL("step", PA_SSIZE),
    RING_ROW,
    ARR("pair_a", PA_I64, 0, 1, 0, 0),
    ARR("pair_b", PA_I64, 0, 1, 0, 0),
    VAL("dist", PA_DOUBLE),
    VAL("backoff", PA_DOUBLE),
    ARR("ray_vertex", PA_I64, OUT, 1, 0, 0),
    ARR("ray_slot", PA_I64, OUT, 1, 0, 0),
    ARR("hit_triangle", PA_I64, OUT, 1, 0, 0),
};
enum { SC_X, SC_NRM, SC_HAS, SC_ORDER, SC_PTR, SC_BLO, SC_BHI, SC_T, SC_BVH, SC_STAMP = SC_BVH + 4, SC_STEP, SC_RING,
       SC_PA, SC_PB, SC_DIST, SC_BACKOFF, SC_RV, SC_RS, SC_HIT, SC_N };

static PyObject *py_self_cast(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("self_cast", SELF_CAST, SC_N);
    double dist = s.v[SC_DIST].d, backoff = s.v[SC_BACKOFF].d;
    if (finite_param(dist, "dist", 1) || finite_param(backoff, "backoff", 1)) goto fail;
    Py_ssize_t n = ROWS(SC_X), cap = ROWS(SC_RV);
    CHECK_ROWS(SC_NRM, n);
    CHECK_ROWS(SC_HAS, n);
    if (!bounds_ok(ROWS(SC_PTR), "ptr", "cluster")) goto fail;
    tcc_bvh b;
    if (bvh_from(&s, SC_BVH, &b)) goto fail;
    CHECK_ROWS(SC_BLO, b.k);
    CHECK_ROWS(SC_BHI, b.k);
    CHECK_ROWS(SC_STAMP, b.k);
    CHECK_ROWS(SC_PB, ROWS(SC_PA));
    CHECK_ROWS(SC_RS, cap);
    CHECK_ROWS(SC_HIT, cap);
    tcc_ring ring = ring_from(&s, SC_RING);
    if (!ring.table || ring.rows != n) {
        PyErr_Format(PyExc_ValueError, "self_cast needs the ring table of the %zd cloth vertices (has %lld rows)", n,
                     (long long)ring.rows);
        goto fail;
    }
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_ray_setup setup = {D(SC_X), D(SC_NRM), D(SC_HAS), NULL, n, D(SC_ORDER), D(SC_PTR), ROWS(SC_ORDER),
                           ROWS(SC_PTR) - 1, D(SC_BLO), D(SC_BHI), b.k, dist, dist, backoff, 0.0};
    tcc_mesh m = {D(SC_X), n, D(SC_T), ROWS(SC_T), NULL, NULL};
    tcc_error err = {0};
    tcc_idx nhits = 0, nrays = 0;
    int rc;
    RUN(tcc_self_cast(&setup, &m, &b, D(SC_STAMP), (tcc_idx)s.v[SC_STEP].n, &ring, D(SC_PA), D(SC_PB), ROWS(SC_PA),
                      D(SC_RV), D(SC_RS), D(SC_HIT), cap, &nhits, &nrays, &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    return Py_BuildValue("(LL)", (long long)nhits, (long long)nrays);
fail:
    pyarg_release(&s);
    return NULL;
}

/* ---------------------------------------------------------------- a collider's step (detect.c) */

static const pyarg_spec DETECT[] = {
    ARR("positions", PA_F64, 0, 2, 3, 0),
    ARR("previous", PA_F64, 0, 2, 3, 0),
    ARR("velocity", PA_F64, OPT, 2, 3, 0),
    ARR("triangles", PA_I64, 0, 2, 3, 0),
    ARR("vt_ptr", PA_I64, 0, 1, 0, 0),
    ARR("vt_tri", PA_I64, 0, 1, 0, 0),
    ARR("order", PA_I64, 0, 1, 0, 0),
    ARR("ptr", PA_I64, 0, 1, 0, 0),
    ARR("labels", PA_I64, 0, 1, 0, 0),
    ARR("normals", PA_F64, OUT, 2, 3, 0),
    ARR("has_normal", PA_BOOL, OUT, 1, 0, 0),
    ARR("done", PA_BOOL, OUT, 1, 0, 0),
    VAL("kind", PA_INT),
    ARR("target_vertices", PA_F64, 0, 2, 3, 0),
    ARR("target_triangles", PA_I64, 0, 2, 3, 0),
    ARR("adjacency", PA_I64, 0, 2, 3, 0),
    ARR("flip", PA_BOOL, 0, 2, 3, 0),
    ARR("target_previous", PA_F64, 0, 2, 3, 0),
    ARR("target_velocity", PA_F64, OPT, 2, 3, 0),
    ARR("tri_labels", PA_I64, 0, 1, 0, 0),
    ARR("box_lo", PA_F64, 0, 2, 3, 0),
    ARR("box_hi", PA_F64, 0, 2, 3, 0),
    RING_ROW,
    ARR("node_ptr", PA_I64, 0, 1, 0, 0),
    ARR("node", PA_I64, 0, 2, 2, 0),
    ARR("box", PA_F64, OUT, 2, 6, 0),
    ARR("prim", PA_I64, 0, 1, 0, 0),
    ARR("corner", PA_F64, OUT, 2, 9, 0),
    ARR("refit_step", PA_I64, OUT, 1, 0, 0),
    VAL("step", PA_SSIZE),
    ARR("pair_i", PA_I64, 0, 1, 0, 0),
    ARR("pair_j", PA_I64, 0, 1, 0, 0),
    ARR("full", PA_BOOL, OUT, 1, 0, 0),
    ARR("track_key", PA_I64, 0, 1, 0, 0),
    ARR("track_tri", PA_I64, 0, 1, 0, 0),
    ARR("track_side", PA_I8, 0, 1, 0, 0),
    ARR("inside", PA_I64, 0, 1, 0, 0),
    VAL("thickness", PA_DOUBLE),
    VAL("track_range", PA_DOUBLE),
    VAL("ray_length", PA_DOUBLE),
    VAL("inflate", PA_DOUBLE),
    VAL("backoff", PA_DOUBLE),
    VAL("first", PA_FLAG),
    ARR("out_key", PA_I64, OUT, 1, 0, 0),
    ARR("out_tri", PA_I64, OUT, 1, 0, 0),
    ARR("out_side", PA_I8, OUT, 1, 0, 0),
    ARR("out_inside", PA_I64, OUT, 1, 0, 0),
    ARR("contact_vertex", PA_I64, OUT, 1, 0, 0),
    ARR("depth", PA_F64, OUT, 1, 0, 0),
    ARR("normal", PA_F64, OUT, 2, 3, 0),
    ARR("contact_velocity", PA_F64, OUT, 2, 3, 0),
    ARR("stats", PA_I64, OUT, 1, 0, 0),
    ARR("times", PA_F64, OUT | OPT, 1, 0, 0),
    ARR("clearance", PA_F64, OUT | OPT, 1, 0, 0),
    {"probe_length", PA_DOUBLE, OPT, 0, {0, 0, 0}},
    ARR("rel_avg", PA_F64, OUT | OPT, 2, 3, 0),
    ARR("rel_dev", PA_F64, OUT | OPT, 1, 0, 0),
    {"credit_unit", PA_DOUBLE, OPT, 0, {0, 0, 0}},
    {"clearance_cap", PA_DOUBLE, OPT, 0, {0, 0, 0}},
};
enum { DT_X, DT_PREV, DT_VEL, DT_TRI, DT_VTP, DT_VTT, DT_ORDER, DT_PTR, DT_LABELS, DT_NRM, DT_HAS, DT_DONE, DT_KIND,
       DT_TX, DT_TT, DT_ADJ, DT_FLIP, DT_TPREV, DT_TVEL, DT_TLAB, DT_LO, DT_HI, DT_RING, DT_NPTR,
       DT_NODE, DT_BOX, DT_PRIM, DT_CORNER, DT_REFIT, DT_STEP, DT_PI, DT_PJ, DT_FULL, DT_KEY, DT_KTRI, DT_KSIDE, DT_INSIDE, DT_TH,
       DT_TR, DT_LEN, DT_INFL, DT_BACK, DT_FIRST, DT_OKEY, DT_OTRI, DT_OSIDE, DT_OIN, DT_CV, DT_DEPTH, DT_CN, DT_CVEL,
       DT_STATS, DT_TIMES, DT_CLEAR, DT_PROBE, DT_RAVG, DT_RDEV, DT_CUNIT, DT_CCAP, DT_N };

static PyObject *py_detect(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("detect", DETECT, DT_N);
    Py_ssize_t n = ROWS(DT_X), nt = ROWS(DT_TRI), nv = ROWS(DT_TX), ntt = ROWS(DT_TT), kc = ROWS(DT_PTR) - 1;
    Py_ssize_t kb = ROWS(DT_NPTR) - 1, np = ROWS(DT_PI), kt = ROWS(DT_KEY);
    if (!bounds_ok(ROWS(DT_PTR), "ptr", "cluster") || !bounds_ok(ROWS(DT_NPTR), "node_ptr", "cluster") ||
        !bounds_ok(ROWS(DT_VTP), "vt_ptr", "vertex"))
        goto fail;
    CHECK_ROWS(DT_PREV, n);
    CHECK_ROWS(DT_VEL, n);
    CHECK_ROWS(DT_VTP, n + 1);
    CHECK_ROWS(DT_ORDER, n);
    CHECK_ROWS(DT_LABELS, n);
    CHECK_ROWS(DT_NRM, n);
    CHECK_ROWS(DT_HAS, n);
    CHECK_ROWS(DT_DONE, n);
    CHECK_ROWS(DT_ADJ, ntt);
    CHECK_ROWS(DT_FLIP, ntt);
    CHECK_ROWS(DT_TPREV, nv);
    CHECK_ROWS(DT_TVEL, nv);
    CHECK_ROWS(DT_TLAB, ntt);
    CHECK_ROWS(DT_LO, kb);
    CHECK_ROWS(DT_HI, kb);
    CHECK_ROWS(DT_BOX, ROWS(DT_NODE));
    CHECK_ROWS(DT_REFIT, kb);
    CHECK_ROWS(DT_CORNER, ROWS(DT_PRIM));
    CHECK_ROWS(DT_PJ, np);
    CHECK_ROWS(DT_FULL, np);
    CHECK_ROWS(DT_KTRI, kt);
    CHECK_ROWS(DT_KSIDE, kt);
    CHECK_ROWS(DT_OKEY, 2 * n);
    CHECK_ROWS(DT_OTRI, 2 * n);
    CHECK_ROWS(DT_OSIDE, 2 * n);
    CHECK_ROWS(DT_OIN, n);
    CHECK_ROWS(DT_CV, n);
    CHECK_ROWS(DT_DEPTH, n);
    CHECK_ROWS(DT_CN, n);
    CHECK_ROWS(DT_CVEL, n);
    CHECK_ROWS(DT_STATS, 8);
    CHECK_ROWS(DT_TIMES, 4);
    CHECK_ROWS(DT_CLEAR, np);
    CHECK_ROWS(DT_RAVG, np);
    CHECK_ROWS(DT_RDEV, np);
    if (!D(DT_RAVG) != !D(DT_RDEV) || (D(DT_RDEV) && !D(DT_CLEAR))) {
        PyErr_SetString(PyExc_ValueError, "detect: rel_avg and rel_dev go together, with clearance");
        goto fail;
    }
    if (D(DT_RDEV) && (finite_param(s.v[DT_CUNIT].d, "credit_unit", 1) || finite_param(s.v[DT_CCAP].d, "clearance_cap", 1)))
        goto fail;
    if (D(DT_RDEV) && s.v[DT_CCAP].d < 1.0) {
        PyErr_SetString(PyExc_ValueError, "detect: clearance_cap must be a factor >= 1");
        goto fail;
    }
    int kind = s.v[DT_KIND].i;
    if (!kind_ok(kind)) goto fail;
    if (finite_param(s.v[DT_TH].d, "thickness", 1) || finite_param(s.v[DT_TR].d, "track_range", 1) ||
        finite_param(s.v[DT_LEN].d, "ray_length", 1) || finite_param(s.v[DT_INFL].d, "inflate", 1) ||
        finite_param(s.v[DT_BACK].d, "backoff", 1))
        goto fail;
    /* absent (0): the rays' own length */
    double probe = s.v[DT_PROBE].d == 0.0 ? s.v[DT_LEN].d : s.v[DT_PROBE].d;
    if (finite_param(probe, "probe_length", 1)) goto fail;
    if (probe < s.v[DT_LEN].d) {
        PyErr_SetString(PyExc_ValueError, "detect: probe_length must be at least ray_length");
        goto fail;
    }
    if (kind == TCC_SELF && nv != n) {
        PyErr_SetString(PyExc_ValueError, "detect: self-collision's target is the cloth (the same vertices)");
        goto fail;
    }
    if (pyarg_no_overlap(&s)) goto fail;
    const tcc_idx *lab = D(DT_LABELS), *tlab = D(DT_TLAB), *ord = D(DT_ORDER), *ptr = D(DT_PTR);
    tcc_detect_in in;
    memset(&in, 0, sizeof in);
    in.x = D(DT_X); in.x_prev = D(DT_PREV); in.velocity = D(DT_VEL); in.n = n;
    in.tri = D(DT_TRI); in.nt = nt; in.vt_ptr = D(DT_VTP); in.vt_tri = D(DT_VTT); in.nvt = ROWS(DT_VTT);
    in.order = ord; in.ptr = ptr; in.labels = lab; in.norder = ROWS(DT_ORDER); in.kc = kc;
    in.normals = D(DT_NRM); in.has_normal = D(DT_HAS); in.done = D(DT_DONE);
    in.kind = kind;
    in.target = (tcc_mesh){D(DT_TX), nv, D(DT_TT), ntt, D(DT_ADJ), D(DT_FLIP)};
    in.target_prev = D(DT_TPREV); in.target_velocity = D(DT_TVEL);
    in.tri_labels = tlab; in.kb = kb;
    in.box_lo = D(DT_LO); in.box_hi = D(DT_HI);
    in.ring = ring_from(&s, DT_RING);
    if (in.ring.table && in.ring.rows < n) {
        PyErr_Format(PyExc_ValueError, "detect: the ring table needs a row per cloth vertex (%zd)", n);
        goto fail;
    }
    in.bvh = (tcc_bvh){D(DT_NPTR), kb, D(DT_NODE), D(DT_BOX), ROWS(DT_NODE), D(DT_PRIM), ROWS(DT_PRIM), D(DT_CORNER)};
    in.refit_step = D(DT_REFIT); in.step = s.v[DT_STEP].n;
    in.pi = D(DT_PI); in.pj = D(DT_PJ); in.full = D(DT_FULL); in.np = np;
    in.track_key = D(DT_KEY); in.track_tri = D(DT_KTRI); in.track_side = D(DT_KSIDE); in.kt = kt;
    in.inside = D(DT_INSIDE); in.ninside = ROWS(DT_INSIDE);
    in.thickness = s.v[DT_TH].d; in.track_range = s.v[DT_TR].d; in.ray_length = s.v[DT_LEN].d;
    in.inflate = s.v[DT_INFL].d; in.backoff = s.v[DT_BACK].d; in.first = s.v[DT_FIRST].i;
    in.clearance = D(DT_CLEAR); in.probe_length = probe;
    in.rel_avg = D(DT_RAVG); in.rel_dev = D(DT_RDEV); in.credit_unit = s.v[DT_CUNIT].d; in.clearance_cap = s.v[DT_CCAP].d;
    tcc_merge_out out = {D(DT_OKEY), D(DT_OTRI), D(DT_OSIDE), 0, D(DT_OIN), 0, D(DT_CV), D(DT_DEPTH), D(DT_CN),
                         D(DT_CVEL), 0};
    tcc_detect_stats st;
    tcc_error err = {0};
    int rc;
    RUN(tcc_detect(&in, &out, &st, &err));
    if (rc == TCC_OK) {
        tcc_idx vals[8] = {out.ntracks, out.ninside, out.ncontacts, st.tracked, st.lost, st.full_pairs, st.rays,
                           st.hits};
        memcpy(D(DT_STATS), vals, sizeof vals);
        if (D(DT_TIMES)) memcpy(D(DT_TIMES), st.seconds, sizeof st.seconds);
    }
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    Py_RETURN_NONE;
fail:
    pyarg_release(&s);
    return NULL;
}

/* ---------------------------------------------------------------- the swept stage (swept.c) */

/* the rows of one kind of pairs in SWEPT_STEP: its pairs, blocks, memory and outputs */
#define SWEPT_KIND_ROWS(p)                                                                                            \
    ARR(p "quads", PA_I64, 0, 2, 4, 0), ARR(p "gap", PA_F64, 0, 1, 0, 0), ARR(p "slack", PA_F64, OUT, 1, 0, 0),        \
        ARR(p "block_ptr", PA_I64, 0, 1, 0, 0), ARR(p "block_vptr", PA_I64, 0, 1, 0, 0),                             \
        ARR(p "block_vertices", PA_I64, 0, 1, 0, 0), ARR(p "block_state", PA_F64, OUT, 2, 2, 0),                      \
        ARR(p "block_reference", PA_F64, OUT, 2, 3, 0), ARR(p "block_gptr", PA_I64, 0, 1, 0, 0),                      \
        ARR(p "block_groups", PA_I64, 0, 1, 0, 0),                                                                    \
        ARR(p "memory", PA_I64, 0, 1, 0, 0), ARR(p "memory_normal", PA_F64, 0, 2, 3, 0),                              \
        ARR(p "memory_out", PA_I64, OUT, 1, 0, 0), ARR(p "memory_normal_out", PA_F64, OUT, 2, 3, 0),                   \
        ARR(p "pairs_out", PA_I64, OUT, 1, 0, 0), ARR(p "normal_out", PA_F64, OUT, 2, 3, 0),                          \
        ARR(p "depth_out", PA_F64, OUT, 1, 0, 0), ARR(p "weights_out", PA_F64, OUT, 2, 3, 0)
enum { SK_Q, SK_GAP, SK_SLACK, SK_BPTR, SK_BVPTR, SK_BV, SK_BSTATE, SK_BREF, SK_BGPTR, SK_BG, SK_MEM, SK_MEMN, SK_MEMO, SK_MEMNO,
       SK_PAIRS, SK_NORMAL, SK_DEPTH, SK_W, SK_N };

static const pyarg_spec SWEPT_STEP[] = {
    ARR("positions", PA_F64, 0, 2, 3, 0),
    ARR("previous", PA_F64, OPT, 2, 3, 0),
    ARR("velocity", PA_F64, OPT, 2, 3, 0),
    VAL("dt", PA_DOUBLE),
    VAL("thickness", PA_DOUBLE),
    ARR("group_ptr", PA_I64, 0, 1, 0, 0),
    ARR("group_vertices", PA_I64, 0, 1, 0, 0),
    ARR("has_reference", PA_BOOL, OUT, 1, 0, 0),
    SWEPT_KIND_ROWS("vt_"),
    SWEPT_KIND_ROWS("ee_"),
    ARR("counts", PA_I64, OUT, 1, 0, 0),
    ARR("vt_handed_out", PA_I64, OUT | OPT, 1, 0, 0),
    ARR("vt_predicted_out", PA_I64, OUT | OPT, 1, 0, 0),
    ARR("ee_handed_out", PA_I64, OUT | OPT, 1, 0, 0),
    ARR("ee_predicted_out", PA_I64, OUT | OPT, 1, 0, 0),
};
enum { SS_X, SS_PREV, SS_V, SS_DT, SS_TH, SS_GPTR, SS_GV, SS_HAS, SS_VT, SS_EE = SS_VT + SK_N,
       SS_COUNTS = SS_EE + SK_N, SS_CAND, SS_N = SS_CAND + 4 };
enum { SWEPT_COUNTS = 12 }; /* per kind: memory, live, predicted, tested, crossed, remembered, handed out (both
                               windows), blocks settled by the bounds 1, 2, 3, blocks read */

/* A kind's rows of the table from argument `first` into K, shapes checked (n vertices). */
static int swept_kind_from(pyarg_set *p, int first, int split, tcc_swept_kind *K)
{
    Py_ssize_t k = pyarg_nrows(p, first + SK_Q), nb = pyarg_nrows(p, first + SK_BPTR) - 1;
    if (nb < 0) {
        PyErr_Format(PyExc_ValueError, "%s needs at least one entry (0)", p->spec[first + SK_BPTR].name);
        return -1;
    }
    if (pyarg_rows(p, first + SK_GAP, k) || pyarg_rows(p, first + SK_SLACK, k) || pyarg_rows(p, first + SK_BVPTR, nb + 1) ||
        pyarg_rows(p, first + SK_BSTATE, nb) || pyarg_rows(p, first + SK_BGPTR, nb + 1) ||
        pyarg_rows(p, first + SK_BREF, pyarg_nrows(p, first + SK_BV)) ||
        pyarg_rows(p, first + SK_MEMN, pyarg_nrows(p, first + SK_MEM)) || pyarg_rows(p, first + SK_MEMO, k) ||
        pyarg_rows(p, first + SK_MEMNO, k) || pyarg_rows(p, first + SK_PAIRS, k) || pyarg_rows(p, first + SK_NORMAL, k) ||
        pyarg_rows(p, first + SK_DEPTH, k) || pyarg_rows(p, first + SK_W, k))
        return -1;
    memset(K, 0, sizeof *K);
    K->split = split;
    K->quad = pyarg_data(p, first + SK_Q);
    K->k = k;
    K->gap = pyarg_data(p, first + SK_GAP);
    K->slack = pyarg_data(p, first + SK_SLACK);
    K->bptr = pyarg_data(p, first + SK_BPTR);
    K->bvptr = pyarg_data(p, first + SK_BVPTR);
    K->bverts = pyarg_data(p, first + SK_BV);
    K->bgptr = pyarg_data(p, first + SK_BGPTR);
    K->bgroups = pyarg_data(p, first + SK_BG);
    K->nb = nb;
    K->nbv = pyarg_nrows(p, first + SK_BV);
    K->nbg = pyarg_nrows(p, first + SK_BG);
    K->bstate = pyarg_data(p, first + SK_BSTATE);
    K->bref = pyarg_data(p, first + SK_BREF);
    K->mem = pyarg_data(p, first + SK_MEM);
    K->mem_n = pyarg_data(p, first + SK_MEMN);
    K->nmem = pyarg_nrows(p, first + SK_MEM);
    K->mem_out = pyarg_data(p, first + SK_MEMO);
    K->mem_n_out = pyarg_data(p, first + SK_MEMNO);
    K->out_q = pyarg_data(p, first + SK_PAIRS);
    K->out_normal = pyarg_data(p, first + SK_NORMAL);
    K->out_depth = pyarg_data(p, first + SK_DEPTH);
    K->out_w = pyarg_data(p, first + SK_W);
    return 0;
}

/* The swept step's arguments into sw (pointers into the buffers p holds); -1 with an exception set
 * (and p released) on bad input */
static int swept_parse(pyarg_set *p, tcc_swept *sw, const char *fname, PyObject *args, PyObject *kw)
{
    if (pyarg_parse(p, fname, SWEPT_STEP, SS_N, PyExc_ValueError, args, kw)) return -1;
    Py_ssize_t n = pyarg_nrows(p, SS_X);
    if (pyarg_rows(p, SS_PREV, n) || pyarg_rows(p, SS_V, n) || pyarg_rows(p, SS_HAS, 1) ||
        pyarg_rows(p, SS_COUNTS, 2 * SWEPT_COUNTS))
        goto fail;
    if (pyarg_nrows(p, SS_GPTR) < 1) {
        PyErr_SetString(PyExc_ValueError, "group_ptr needs at least one entry (0)");
        goto fail;
    }
    if (finite_param(p->v[SS_DT].d, "dt", 1) || finite_param(p->v[SS_TH].d, "thickness", 1)) goto fail;
    memset(sw, 0, sizeof *sw);
    if (swept_kind_from(p, SS_VT, 1, &sw->kind[0]) || swept_kind_from(p, SS_EE, 2, &sw->kind[1])) goto fail;
    for (int k = 0; k < 2; k++) {
        int a = SS_CAND + 2 * k;
        if ((pyarg_data(p, a) != NULL) != (pyarg_data(p, a + 1) != NULL)) {
            PyErr_Format(PyExc_ValueError, "%s: a kind's handed_out and predicted_out go together", fname);
            goto fail;
        }
        if (pyarg_rows(p, a, sw->kind[k].k) || pyarg_rows(p, a + 1, sw->kind[k].k)) goto fail;
        sw->cand_out[k] = pyarg_data(p, a);
        sw->pcand_out[k] = pyarg_data(p, a + 1);
    }
    if (pyarg_no_overlap(p)) goto fail;
    sw->x = pyarg_data(p, SS_X);
    sw->x_prev = pyarg_data(p, SS_PREV);
    sw->v = pyarg_data(p, SS_V);
    sw->n = n;
    sw->dt = p->v[SS_DT].d;
    sw->thickness = p->v[SS_TH].d;
    sw->group_ptr = pyarg_data(p, SS_GPTR);
    sw->ngroups = pyarg_nrows(p, SS_GPTR) - 1;
    sw->group_vertices = pyarg_data(p, SS_GV);
    sw->ngv = pyarg_nrows(p, SS_GV);
    sw->has_ref = pyarg_data(p, SS_HAS);
    return 0;
fail:
    pyarg_release(p);
    return -1;
}

/* The counts (24,) of a step that ran */
static void swept_counts(pyarg_set *p, const tcc_swept *sw)
{
    tcc_idx *c = pyarg_data(p, SS_COUNTS);
    for (int k = 0; k < 2; k++, c += SWEPT_COUNTS) {
        const tcc_swept_kind *K = &sw->kind[k];
        tcc_idx v[SWEPT_COUNTS] = {K->nmem_out, K->nlive, K->npred, K->tested, K->crossed, K->remembered,
                                   sw->ncand[k], sw->npcand[k], K->settled[0], K->settled[1],
                                   K->settled[2], K->settled[3]};
        memcpy(c, v, sizeof v);
    }
}

static PyObject *py_swept_step(PyObject *self, PyObject *args, PyObject *kw)
{
    pyarg_set s;
    tcc_swept sw;
    if (swept_parse(&s, &sw, "swept_step", args, kw)) return NULL;
    tcc_error err = {0};
    int rc;
    RUN(tcc_swept_step(&sw, &err));
    if (rc == TCC_OK) swept_counts(&s, &sw);
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    Py_RETURN_NONE;
}

/* ---- the swept step on a thread of its own (swept_worker, swept_start, swept_join) ----
 * The detector runs the swept stage beside its colliders. On a Python worker thread that stage
 * first had to get the GIL, which the main thread holds through the colliders' Python between its
 * C calls: on the collision bench's replay (dt = 1 ms, the body walking, the machine loaded) the
 * step began a median 0.37 ms (mean 1.1, at most 6.1 ms) after it was handed over, for ~0.3 ms of
 * work. Here it runs on an OS thread that never touches the interpreter, one per detector, started
 * once by CPython's own thread API (in the stable ABI: a direct pthread_create would bind glibc
 * 2.34's symbol version, and Blender runs on older systems) and kept: a thread started per step
 * was slower still on a loaded machine (the scheduler starts a new thread late; it wakes a
 * sleeping one at once). A step is handed over and waited for through two locks (go, done),
 * waited for without the GIL. A job (a capsule) holds its argument buffers, so the arrays live
 * while it runs, and its worker; a job dropped unjoined is waited for before they are let go. */
typedef struct swept_job swept_job;

typedef struct swept_worker {
    PyThread_type_lock go, done;  /* go: released to hand a job over; done: released by the thread */
    swept_job *job;               /* the job handed over (NULL: idle) */
    int quit;
    int alive;                    /* the thread runs (0: none could be started; jobs run in swept_start) */
    long pid;                     /* the process whose thread it is: a fork's child has none */
} swept_worker;

struct swept_job {
    pyarg_set s;
    tcc_swept sw;
    tcc_error err;
    int rc;
    PyObject *worker;  /* the worker's capsule (a reference), NULL once waited for */
    int on_thread;     /* 0: the worker had no thread, the step ran in swept_start */
    int joined;        /* swept_join took its results (and released the buffers) */
    double seconds;    /* the step's own time */
};

#define SWEPT_JOB "tearcloth._collide.swept_job"
#define SWEPT_WORKER "tearcloth._collide.swept_worker"

static long process_id(void)
{
#ifdef _WIN32
    return (long)GetCurrentProcessId();
#else
    return (long)getpid();
#endif
}

/* the worker's thread runs in this process (not in the parent of a fork's child) */
static int swept_worker_here(const swept_worker *w) { return w->alive && w->pid == process_id(); }

static double seconds_now(void)
{
#ifdef _WIN32
    LARGE_INTEGER t, f;
    QueryPerformanceCounter(&t);
    QueryPerformanceFrequency(&f);
    return (double)t.QuadPart / (double)f.QuadPart;
#else
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
#endif
}

/* the step itself, without the GIL */
static void swept_job_run(swept_job *j)
{
    const double t0 = seconds_now();
    j->rc = tcc_swept_step(&j->sw, &j->err);
    j->seconds = seconds_now() - t0;
}

/* The worker's thread: a job per release of go, done released after each (PyThread locks are not
 * owned: any thread may release one another acquired), and once more when it quits. */
static void swept_worker_main(void *arg)
{
    swept_worker *w = arg;
    for (;;) {
        PyThread_acquire_lock(w->go, WAIT_LOCK);
        if (w->quit) break;
        swept_job_run(w->job);
        PyThread_release_lock(w->done);
    }
    PyThread_release_lock(w->done);
}

/* until the job's step has finished on its worker (called with the GIL; waits without it) */
static void swept_job_wait(swept_job *j)
{
    if (!j->worker) return;
    swept_worker *w = PyCapsule_GetPointer(j->worker, SWEPT_WORKER);
    if (w && w->job == j) {
        if (swept_worker_here(w)) {
            Py_BEGIN_ALLOW_THREADS
            PyThread_acquire_lock(w->done, WAIT_LOCK);
            Py_END_ALLOW_THREADS
        } else {  /* handed over before a fork, joined in the child: its thread is the parent's */
            j->rc = tcc_fail(&j->err, TCC_ERR_VALUE, "swept_join: this step was handed to a thread of process %ld, "
                                                      "not of this one (a fork's child)", w->pid);
        }
        w->job = NULL;
    }
    Py_CLEAR(j->worker);
}

static void swept_job_free(PyObject *capsule)
{
    swept_job *j = PyCapsule_GetPointer(capsule, SWEPT_JOB);
    if (!j) {
        PyErr_Clear();
        return;
    }
    swept_job_wait(j);  /* never free what the worker still reads and writes */
    if (!j->joined) pyarg_release(&j->s);
    free(j);
}

static void swept_worker_free(PyObject *capsule)
{
    swept_worker *w = PyCapsule_GetPointer(capsule, SWEPT_WORKER);
    if (!w) {
        PyErr_Clear();
        return;
    }
    if (swept_worker_here(w)) {  /* (no job runs: each holds a reference to this capsule until waited for) */
        w->quit = 1;
        PyThread_release_lock(w->go);
        Py_BEGIN_ALLOW_THREADS
        PyThread_acquire_lock(w->done, WAIT_LOCK);
        Py_END_ALLOW_THREADS
    }
    if (w->go) PyThread_free_lock(w->go);
    if (w->done) PyThread_free_lock(w->done);
    free(w);
}

static PyObject *py_swept_worker(PyObject *self, PyObject *noargs)
{
    swept_worker *w = calloc(1, sizeof *w);
    if (!w) return PyErr_NoMemory();
    PyObject *cap = PyCapsule_New(w, SWEPT_WORKER, swept_worker_free);
    if (!cap) {
        free(w);
        return NULL;
    }
    w->pid = process_id();
    w->go = PyThread_allocate_lock();
    w->done = PyThread_allocate_lock();
    /* both held here: the thread waits on go, a join on done */
    if (w->go && w->done && PyThread_acquire_lock(w->go, NOWAIT_LOCK)) {
        if (PyThread_acquire_lock(w->done, NOWAIT_LOCK)) {
            w->alive = PyThread_start_new_thread(swept_worker_main, w) != (unsigned long)-1;
            if (!w->alive) PyThread_release_lock(w->done);
        }
        if (!w->alive) PyThread_release_lock(w->go);
    }
    return cap;  /* without a thread (the system's limit) jobs run in swept_start, and swept_join says so */
}

static PyObject *py_swept_start(PyObject *self, PyObject *args, PyObject *kw)
{
    if (PyTuple_Size(args) < 1) {
        PyErr_SetString(PyExc_TypeError, "swept_start(worker, ...): the first argument is a swept_worker()");
        return NULL;
    }
    PyObject *wcap = PyTuple_GetItem(args, 0);
    swept_worker *w = PyCapsule_GetPointer(wcap, SWEPT_WORKER);
    if (!w) return NULL;
    if (w->job) {
        PyErr_SetString(PyExc_ValueError, "swept_start: this worker's last step was not joined yet");
        return NULL;
    }
    PyObject *rest = PyTuple_GetSlice(args, 1, PyTuple_Size(args));
    if (!rest) return NULL;
    swept_job *j = calloc(1, sizeof *j);
    if (!j) {
        Py_DECREF(rest);
        return PyErr_NoMemory();
    }
    const int bad = swept_parse(&j->s, &j->sw, "swept_start", rest, kw);
    Py_DECREF(rest);
    if (bad) {
        free(j);
        return NULL;
    }
    PyObject *job = PyCapsule_New(j, SWEPT_JOB, swept_job_free);
    if (!job) {
        pyarg_release(&j->s);
        free(j);
        return NULL;
    }
    if (swept_worker_here(w)) {
        Py_INCREF(wcap);
        j->worker = wcap;
        j->on_thread = 1;
        w->job = j;
        PyThread_release_lock(w->go);
    } else {
        Py_BEGIN_ALLOW_THREADS swept_job_run(j);
        Py_END_ALLOW_THREADS
    }
    return job;
}

static PyObject *py_swept_join(PyObject *self, PyObject *arg)
{
    swept_job *j = PyCapsule_GetPointer(arg, SWEPT_JOB);
    if (!j) return NULL;
    if (j->joined) {
        PyErr_SetString(PyExc_ValueError, "swept_join: this swept step was joined already");
        return NULL;
    }
    swept_job_wait(j);
    j->joined = 1;
    if (j->rc == TCC_OK) swept_counts(&j->s, &j->sw);
    pyarg_release(&j->s);
    if (j->rc) return kernel_error(&j->err);
    return Py_BuildValue("(dO)", j->seconds, j->on_thread ? Py_True : Py_False);
}

#define SWEPT_LIST_ROWS(p)                                                                                            \
    ARR(p "quads", PA_I64, 0, 2, 4, 0), ARR(p "pairs", PA_I64, 0, 1, 0, 0), ARR(p "normal", PA_F64, 0, 2, 3, 0),       \
        ARR(p "depth", PA_F64, 0, 1, 0, 0), ARR(p "weights", PA_F64, 0, 2, 3, 0), VAL(p "live", PA_SSIZE)
enum { SL_Q, SL_PAIRS, SL_NORMAL, SL_DEPTH, SL_W, SL_LIVE, SL_N };

static const pyarg_spec SWEPT_ROWS[] = {
    SWEPT_LIST_ROWS("vt_"),
    SWEPT_LIST_ROWS("ee_"),
    ARR("velocity", PA_F64, OPT, 2, 3, 0),
    VAL("n", PA_SSIZE),
    ARR("vertex", PA_I32, 0, 1, 0, 0),
    ARR("normal", PA_F64, 0, 2, 3, 0),
    ARR("depth", PA_F64, 0, 1, 0, 0),
    ARR("contact_velocity", PA_F64, 0, 2, 3, 0),
    ARR("friction", PA_F64, 0, 1, 0, 0),
    VAL("cloth_friction", PA_DOUBLE),
    ARR("out_vertex", PA_I32, OUT, 1, 0, 0),
    ARR("out_normal", PA_F64, OUT, 2, 3, 0),
    ARR("out_depth", PA_F64, OUT, 1, 0, 0),
    ARR("out_velocity", PA_F64, OUT, 2, 3, 0),
    ARR("out_friction", PA_F64, OUT, 1, 0, 0),
};
enum { SR_VT, SR_EE = SR_VT + SL_N, SR_V = SR_EE + SL_N, SR_NV, SR_EV, SR_EN, SR_ED, SR_EVEL, SR_EF, SR_FRIC, SR_OV, SR_ON,
       SR_OD, SR_OVEL, SR_OF, SR_N };

static PyObject *py_swept_rows(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("swept_rows", SWEPT_ROWS, SR_N);
    Py_ssize_t n = s.v[SR_NV].n, ne = ROWS(SR_EV), cap = ROWS(SR_OV);
    CHECK_ROWS(SR_V, n);
    CHECK_ROWS(SR_EN, ne);
    CHECK_ROWS(SR_ED, ne);
    CHECK_ROWS(SR_EVEL, ne);
    CHECK_ROWS(SR_EF, ne);
    CHECK_ROWS(SR_ON, cap);
    CHECK_ROWS(SR_OD, cap);
    CHECK_ROWS(SR_OVEL, cap);
    CHECK_ROWS(SR_OF, cap);
    if (n < 0) {
        PyErr_SetString(PyExc_ValueError, "n must be a vertex count >= 0");
        goto fail;
    }
    tcc_swept_kind kinds[2];
    for (int k = 0; k < 2; k++) {
        int a = k ? SR_EE : SR_VT;
        Py_ssize_t m = ROWS(a + SL_PAIRS), live = s.v[a + SL_LIVE].n;
        CHECK_ROWS(a + SL_NORMAL, m);
        CHECK_ROWS(a + SL_DEPTH, m);
        CHECK_ROWS(a + SL_W, m);
        if (live < 0 || live > m) {
            PyErr_Format(PyExc_ValueError, "%s must lie in [0, %zd]", s.spec[a + SL_LIVE].name, m);
            goto fail;
        }
        memset(&kinds[k], 0, sizeof kinds[k]);
        kinds[k].split = k ? 2 : 1;
        kinds[k].quad = D(a + SL_Q);
        kinds[k].k = ROWS(a + SL_Q);
        kinds[k].out_q = D(a + SL_PAIRS);
        kinds[k].out_normal = D(a + SL_NORMAL);
        kinds[k].out_depth = D(a + SL_DEPTH);
        kinds[k].out_w = D(a + SL_W);
        kinds[k].nlive = live;
        kinds[k].npred = m - live;
    }
    if (finite_param(s.v[SR_FRIC].d, "cloth_friction", 1)) goto fail;
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_error err = {0};
    tcc_idx count = 0, bad = 0;
    int rc;
    RUN(tcc_swept_rows(kinds, D(SR_V), n, D(SR_EV), D(SR_EN), D(SR_ED), D(SR_EVEL), D(SR_EF), ne, s.v[SR_FRIC].d,
                       D(SR_OV), D(SR_ON), D(SR_OD), D(SR_OVEL), D(SR_OF), cap, &count, &bad, &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    return Py_BuildValue("LL", (long long)count, (long long)bad);
fail:
    pyarg_release(&s);
    return NULL;
}

static const pyarg_spec SWEPT_PAIRS[] = {
    ARR("triangles", PA_I64, 0, 2, 3, 0),
    RING_ROW,
    VAL("n", PA_SSIZE),
    ARR("edges", PA_I64, OUT, 2, 2, 0),
    ARR("vt", PA_I64, OUT, 2, 2, 0),
    ARR("ee", PA_I64, OUT, 2, 2, 0),
};
enum { SP_T, SP_RING, SP_NV, SP_E, SP_VT, SP_EE, SP_N };

static PyObject *py_swept_pairs(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("swept_pairs", SWEPT_PAIRS, SP_N);
    Py_ssize_t n = s.v[SP_NV].n;
    tcc_ring ring = ring_from(&s, SP_RING);
    if (n < 0 || !ring.table) {
        PyErr_SetString(PyExc_ValueError, "swept_pairs: n must be >= 0 and the ring table given");
        goto fail;
    }
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_error err = {0};
    tcc_idx ne = 0, nvt = 0, nee = 0;
    int rc;
    RUN(tcc_swept_pairs(D(SP_T), ROWS(SP_T), n, &ring, D(SP_E), ROWS(SP_E), D(SP_VT), ROWS(SP_VT), D(SP_EE), ROWS(SP_EE),
                        &ne, &nvt, &nee, &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    return Py_BuildValue("LLL", (long long)ne, (long long)nvt, (long long)nee);
fail:
    pyarg_release(&s);
    return NULL;
}

static const pyarg_spec SWEPT_BLOCKS[] = {
    ARR("quads", PA_I64, 0, 2, 4, 0),
    VAL("size", PA_SSIZE),
    ARR("group", PA_I64, 0, 1, 0, 0),
    ARR("block_ptr", PA_I64, OUT, 1, 0, 0),
    ARR("block_vptr", PA_I64, OUT, 1, 0, 0),
    ARR("block_vertices", PA_I64, OUT, 1, 0, 0),
    ARR("block_gptr", PA_I64, OUT, 1, 0, 0),
    ARR("block_groups", PA_I64, OUT, 1, 0, 0),
};
enum { SB_Q, SB_SIZE, SB_G, SB_PTR, SB_VPTR, SB_V, SB_GPTR, SB_GR, SB_N };

static PyObject *py_swept_blocks(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("swept_blocks", SWEPT_BLOCKS, SB_N);
    Py_ssize_t k = ROWS(SB_Q), size = s.v[SB_SIZE].n;
    if (size < 1) {
        PyErr_SetString(PyExc_ValueError, "swept_blocks: size must be >= 1");
        goto fail;
    }
    Py_ssize_t nb = (k + size - 1) / size;
    CHECK_ROWS(SB_PTR, nb + 1);
    CHECK_ROWS(SB_VPTR, nb + 1);
    CHECK_ROWS(SB_GPTR, nb + 1);
    CHECK_ROWS(SB_V, 4 * k);
    CHECK_ROWS(SB_GR, 4 * k);
    const tcc_idx *g = D(SB_G);
    Py_ssize_t n = ROWS(SB_G);
    for (Py_ssize_t v = 0; v < n; v++)
        if (g[v] < 0) {
            PyErr_Format(PyExc_ValueError, "swept_blocks: group[%zd] is negative", v);
            goto fail;
        }
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_error err = {0};
    int rc;
    RUN(tcc_swept_blocks(D(SB_Q), k, size, g, n, D(SB_PTR), D(SB_VPTR), D(SB_V), D(SB_GPTR), D(SB_GR), &err));
    tcc_idx nv = 0, ng = 0;
    if (rc == TCC_OK) {
        nv = ((tcc_idx *)D(SB_VPTR))[nb];
        ng = ((tcc_idx *)D(SB_GPTR))[nb];
    }
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    return Py_BuildValue("LL", (long long)nv, (long long)ng);
fail:
    pyarg_release(&s);
    return NULL;
}

/* ---------------------------------------------------------------- impact.c (the impact guard) */

static const pyarg_spec IMPACT_RESOLVE[] = {
    ARR("start", PA_F64, 0, 2, 3, 0),
    ARR("end", PA_F64, OUT, 2, 3, 0),
    ARR("velocity", PA_F64, OUT, 2, 3, 0),
    ARR("mass", PA_F64, 0, 1, 0, 0),
    ARR("rest", PA_F64, 0, 2, 3, 0),
    ARR("triangles", PA_I64, 0, 2, 3, 0),
    ARR("vertex_owner", PA_I64, 0, 1, 0, 0),
    ARR("edge_owner", PA_BOOL, 0, 2, 3, 0),
    ARR("node", PA_I64, 0, 2, 2, 0),
    ARR("prim", PA_I64, 0, 1, 0, 0),
    ARR("adjacency", PA_I64, 0, 2, 3, 0),
    ARR("flip", PA_BOOL, 0, 2, 3, 0),
    ARR("interior", PA_BOOL, 0, 1, 0, 0),
    ARR("vt_ptr", PA_I64, 0, 1, 0, 0),
    ARR("vt_tri", PA_I64, 0, 1, 0, 0),
    ARR("patch", PA_I64, OUT, 1, 0, 0),
    ARR("loop", PA_I64, OUT, 1, 0, 0),
    ARR("loop_off", PA_I64, 0, 1, 0, 0),
    VAL("dt", PA_DOUBLE),
    VAL("gap", PA_DOUBLE),
    VAL("rest_fraction", PA_DOUBLE),
    VAL("min_rest", PA_DOUBLE),
    VAL("impulse_passes", PA_INT),
    VAL("zone_passes", PA_INT),
};
enum { IR_X0, IR_X1, IR_V, IR_M, IR_REST, IR_T, IR_VOWN, IR_EOWN, IR_NODE, IR_PRIM, IR_ADJ, IR_FLIP, IR_INT, IR_VTP,
       IR_VTT, IR_PATCH, IR_LOOP, IR_LOFF, IR_DT, IR_GAP, IR_RF, IR_MR, IR_IP, IR_ZP, IR_N };

static PyObject *py_impact_resolve(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("impact_resolve", IMPACT_RESOLVE, IR_N);
    Py_ssize_t n = ROWS(IR_X0), nt = ROWS(IR_T);
    CHECK_ROWS(IR_X1, n);
    CHECK_ROWS(IR_V, n);
    CHECK_ROWS(IR_M, n);
    CHECK_ROWS(IR_REST, n);
    CHECK_ROWS(IR_VOWN, n);
    CHECK_ROWS(IR_EOWN, nt);
    CHECK_ROWS(IR_PRIM, nt);
    CHECK_ROWS(IR_ADJ, nt);
    CHECK_ROWS(IR_FLIP, nt);
    CHECK_ROWS(IR_INT, n);
    CHECK_ROWS(IR_VTP, n + 1);
    CHECK_ROWS(IR_PATCH, ROWS(IR_NODE));
    CHECK_ROWS(IR_LOFF, ROWS(IR_NODE) + 1);
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_impact_in in = {D(IR_X0), D(IR_X1), D(IR_V), D(IR_M), D(IR_REST), n, D(IR_T), nt, D(IR_VOWN), D(IR_EOWN),
                        D(IR_NODE), ROWS(IR_NODE), D(IR_PRIM), D(IR_ADJ), D(IR_FLIP), D(IR_INT), D(IR_VTP),
                        D(IR_VTT), ROWS(IR_VTT), D(IR_PATCH), D(IR_LOOP),
                        D(IR_LOFF), ROWS(IR_LOOP), s.v[IR_DT].d, s.v[IR_GAP].d, s.v[IR_RF].d, s.v[IR_MR].d,
                        s.v[IR_IP].i, s.v[IR_ZP].i};
    tcc_impact_counts c;
    tcc_error err = {0};
    int rc;
    RUN(tcc_impact_resolve(&in, &c, &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    return Py_BuildValue("{sLsLsLsLsLsLsLsLsLsLsLsLsLsL}", "patches_free", (long long)c.patches_free, "candidates", (long long)c.candidates, "collisions",
                         (long long)c.collisions, "excluded", (long long)c.excluded, "crossing_only",
                         (long long)c.crossing_only, "impulses", (long long)c.impulses, "impulse_passes",
                         (long long)c.impulse_passes, "zone_passes", (long long)c.zone_passes, "zones",
                         (long long)c.zones, "zone_vertices", (long long)c.zone_vertices, "unresolved",
                         (long long)c.unresolved, "rigid_cloth", (long long)c.rigid_cloth, "moved",
                         (long long)c.moved, "immovable", (long long)c.immovable);
fail:
    pyarg_release(&s);
    return NULL;
}

#define KERNEL(name, doc) {#name, (PyCFunction)(void (*)(void))py_##name, METH_VARARGS | METH_KEYWORDS, doc}

static PyMethodDef methods[] = {
    KERNEL(vertex_normals,
           "vertex_normals(positions, triangles, normals, has_normal): area-weighted unit vertex normals into the "
           "outputs normals and has_normal."),
    KERNEL(cluster_normals,
           "cluster_normals(positions, triangles, vt_ptr, vt_tri, order, ptr, clusters, normals, has_normal, "
           "done=None): vertex normals of the listed clusters' vertices only (skipping and marking done clusters)."),
    KERNEL(cluster_motion,
           "cluster_motion(positions, previous, order, ptr, avg, dev): mean and deviation of the displacement."),
    KERNEL(cluster_boxes, "cluster_boxes(positions, index, ptr, inflate, lo, hi): inflated AABB per cluster."),
    KERNEL(box_pairs,
           "box_pairs(lo_a, hi_a, lo_b, hi_b, self_pairs, i, j) -> count (> len(i): call again, larger)."),
    KERNEL(relative_measure,
           "relative_measure(old_keys, old_avg, old_dev, i, j, avg_a, dev_a, avg_b, dev_b, force, threshold, keys, "
           "rel_avg, rel_dev, amplitude, full, lookahead=0) -> number of full pairs."),
    KERNEL(cluster_state,
           "cluster_state(positions, previous, order, ptr, box_index, box_ptr, inflate, avg, dev, lo, hi): "
           "cluster_motion and cluster_boxes in one call."),
    KERNEL(pair_step,
           "pair_step(lo_a, hi_a, lo_b, hi_b, self_pairs, first, forced, avg_a, dev_a, avg_b, dev_b, old_keys, "
           "old_avg, old_dev, threshold, lookahead, i, j, full, keys, rel_avg, rel_dev, amplitude) -> (pairs, full "
           "pairs): a collider's close pairs, those forced to full detection, and with avg_a the relative measure's "
           "update (measure.c tcc_pair_step); pairs > len(i): nothing else written, call again with more room."),
    KERNEL(cluster_fit,
           "cluster_fit(positions, previous, order, ptr, reach, fit): affine fit of each cluster's displacement, "
           "its largest residual and |L| (the trip rule, measure.c)."),
    KERNEL(pair_motion,
           "pair_motion(i, j, positions_a, previous_a, order_a, ptr_a, fit_a, positions_b, previous_b, order_b, "
           "ptr_b, fit_b, reach, bound): per pair, the step's bound on a vertex's motion towards the other cluster."),
    KERNEL(trip_measure,
           "trip_measure(old_keys, old_used, i, j, bound, lo_a, hi_a, lo_b, hi_b, inflate, budget, thickness, force, "
           "lookahead, keys, used, amplitude, full) -> number of full pairs (the clearance each pair spent)."),
    KERNEL(rigid_fit,
           "rigid_fit(positions, triangles, ref_corners, scene_triangles, R, centre, ref_centre, row) -> max "
           "residual^2."),
    KERNEL(rigid_fit_many,
           "rigid_fit_many(positions, triangles, scene_ptr, scene_triangles, ref_corners, clusters, R, centre, "
           "ref_centre, resid2): the rigid fit of each listed cluster's scene (rows R[c] ...), its max residual^2."),
    KERNEL(walk,
           "walk(positions, normals, ray_vertex, ray_slot, start, target_vertices, target_triangles, adjacency, flip, "
           "ring, max_steps, tri_out, t_out, u_out, v_out, flips_out)."),
    KERNEL(prepare_rays,
           "prepare_rays(positions, normals, has_normal, long_mask, order, ptr, box_lo, box_hi, pair_a, pair_b, "
           "clusters, R, centre, ref_centre, short_dist, long_dist, backoff, tolerance, origins, directions, dists, "
           "ray_vertex, ray_slot, segments) -> ray count (> capacity: call again, larger)."),
    KERNEL(accept_hits,
           "accept_hits(rays, prim, tfar, scene_triangles, ray_vertex, target_triangles, ring, origins, directions, "
           "dists, hit_triangle, retry) -> number of rays to cast again."),
    KERNEL(refine,
           "refine(positions, normals, ray_vertex, ray_slot, hit_triangle, target_vertices, target_triangles, "
           "adjacency, flip, ring, kind, track_range, inside_prev, out_vertex, out_slot, out_tri, out_t, out_u, "
           "out_v, out_flips, status) -> count."),
    KERNEL(drop_dominated,
           "drop_dominated(vertex, slot, t, status, track_key, walked_tri, walked_t) -> far back-face hits left: "
           "those a nearer hit of the same ray beats get status 0."),
    KERNEL(confirm_inside,
           "confirm_inside(target_vertices, target_triangles, tri_order, tri_ptr, lo, hi, origins, directions, "
           "t_exit, exit_tri, backoff, eps, ok): ok where no other triangle is hit before the exit."),
    KERNEL(merge_classify,
           "merge_classify(positions, normals, previous, velocity, target_vertices, target_triangles, "
           "target_previous, target_velocity, kind, first, thickness, track_range, track_key, track_tri, track_side, "
           "walked_tri, walked_t, walked_u, walked_v, walked_flips, found_vertex, found_slot, found_tri, found_t, "
           "found_u, found_v, found_flips, found_status, out_key, out_tri, out_side, out_inside, contact_vertex, "
           "depth, normal, contact_velocity) -> (tracks, inside, contacts): the new tracks, the vertices inside and "
           "the deepest contact per vertex of one collider."),
    KERNEL(assemble,
           "assemble(segments, vertex, depth, normal, velocity, friction, n, deep_vertex, deep_normal, deep_depth, "
           "deep_velocity, deep_friction, all_vertex, all_normal, all_depth, all_velocity, all_friction) -> "
           "(deep count, all count)."),
    KERNEL(ccd_vertex_triangle,
           "ccd_vertex_triangle(start, end, triangles, vertex, triangle, gap, toi, weights, side, pair_gap=None) -> "
           "hits: the "
           "earliest time in [0, 1] of linear motion start -> end at which each vertex comes within gap of its "
           "triangle (inf if never), the closest point's barycentrics and the side the vertex came from."),
    KERNEL(vertex_triangle_state,
           "vertex_triangle_state(positions, triangles, vertex, triangle, sd, dist, weights, normal): signed plane "
           "distance, distance, closest-point barycentrics and unit normal of each vertex-triangle pair."),
    KERNEL(ccd_edge_edge,
           "ccd_edge_edge(start, end, edge_a, edge_b, gap, toi, params, side, pair_gap=None) -> hits: the earliest time in [0, 1] "
           "at which each pair of moving edges comes within gap, the closest points' parameters and the side of "
           "edge a from edge b before."),
    KERNEL(edge_edge_state,
           "edge_edge_state(positions, edge_a, edge_b, sd, dist, params, normal): signed distance along the unit "
           "common normal, distance and closest-point parameters of each edge pair."),
    KERNEL(bvh_build,
           "bvh_build(positions, triangles, scene_ptr, scene_triangles, node_ptr, node, box, prim) -> node count: "
           "a BVH per cluster over its scene triangles (node and box need 2 * len(scene_triangles) rows)."),
    KERNEL(bvh_refit, "bvh_refit(positions, triangles, node_ptr, node, box, prim, clusters): refit the listed "
                      "clusters' boxes bottom-up from the positions."),
    KERNEL(bvh_cast,
           "bvh_cast(positions, triangles, node_ptr, node, box, prim, cluster, origins, directions, tmax, "
           "ray_vertex=None, ring=None, tri_out, t_out, u_out, v_out): the nearest hit (t in [0, tmax]) of each ray "
           "in its cluster's tree, skipping the ray vertex's two-ring when a ring is given; tri -1 when none."),
    KERNEL(self_cast,
           "self_cast(positions, normals, has_normal, order, ptr, box_lo, box_hi, triangles, node_ptr, node, box, "
           "prim, refit_step, step, ring, pair_a, pair_b, dist, backoff, ray_vertex, ray_slot, hit_triangle) -> "
           "(hits, rays): every close pair's rays cast into the target cluster's tree (refitted once per step), the "
           "two-ring skipped; the rays that hit (more than len(ray_vertex): call again, larger)."),
    KERNEL(impact_resolve,
           "impact_resolve(start, end, velocity, mass, rest, triangles, vertex_owner, edge_owner, node, prim, adjacency, "
           "flip, interior, vt_ptr, vt_tri, patch, loop, loop_off, dt, gap, rest_fraction, min_rest, impulse_passes, zone_passes) -> counts: the step's motion start -> end made free "
           "of self-crossings (impulses, rigid impact zones; impact.c), end and velocity corrected in place."),
    KERNEL(detect,
           "detect(positions, previous, velocity, triangles, vt_ptr, vt_tri, order, ptr, labels, normals, has_normal, "
           "done, kind, target_vertices, target_triangles, adjacency, flip, target_previous, target_velocity, "
           "tri_labels, box_lo, box_hi, ring, node_ptr, node, box, prim, corner, refit_step, step, "
           "pair_i, "
           "pair_j, full, track_key, track_tri, track_side, inside, thickness, track_range, ray_length, inflate, "
           "backoff, first, out_key, out_tri, out_side, out_inside, contact_vertex, depth, normal, contact_velocity, "
           "stats, times=None, clearance=None, probe_length=0, rel_avg=None, rel_dev=None, credit_unit=0, "
           "clearance_cap=0): one collider's step (detect.c): walks, full "
           "detection of the marked pairs in the collider's trees, refinement, merge; stats (8,): tracks, inside, "
           "contacts, tracked, lost, full pairs, rays, hits; times (4,): seconds of the walks, casts, refinement, "
           "merge; clearance (pairs,): per pair fully detected the distance along its vertices' lines to the "
           "nearest untracked hit (at most probe_length, >= ray_length; 0: ray_length), NaN for the others; "
           "rel_avg (pairs, 3) and rel_dev (pairs,) with clearance: the relative measure of the pairs fully detected "
           "restarted with their clearance credit (credit_unit, clearance_cap; collide.h tcc_detect_in)."),
    KERNEL(swept_pairs,
           "swept_pairs(triangles, ring, n, edges, vt, ee) -> (edges, vt pairs, ee pairs): the swept stage's pairs of a "
           "topology (swept.c tcc_swept_pairs), each list ascending; a list is written only when it fits: call again "
           "with room for the counts."),
    KERNEL(swept_blocks,
           "swept_blocks(quads, size, group, block_ptr, block_vptr, block_vertices, block_gptr, block_groups) -> "
           "(vertices, groups): the cull's blocks of `size` consecutive pairs, their vertices and groups ascending."),
    KERNEL(swept_step,
           "swept_step(positions, previous, velocity, dt, thickness, group_ptr, group_vertices, has_reference, "
           "vt_* and ee_* (quads, gap, slack, block_ptr, block_vptr, block_vertices, block_state, block_reference, "
           "block_gptr, block_groups, memory, memory_normal, memory_out, memory_normal_out, pairs_out, normal_out, "
           "depth_out, weights_out), counts, vt_handed_out=None, vt_predicted_out=None, ee_handed_out=None, "
           "ee_predicted_out=None): one step of the swept stage (swept.c): the cull, the swept tests, the "
           "remembered crossings, and per kind the pairs that give contacts; counts (24,) per kind: memory, live, "
           "predicted, tested, crossed, remembered, handed out (real, predicted), blocks settled by the bounds 1, 2, 3, "
           "blocks read."),
    {"swept_worker", (PyCFunction)py_swept_worker, METH_NOARGS,
     "swept_worker() -> worker: an OS thread for swept_start's steps, which never takes the GIL; it ends when "
     "the worker is let go."},
    KERNEL(swept_start,
           "swept_start(worker, the arguments of swept_step) -> job: the same step, handed to the worker's thread "
           "before the call returns; the arrays must stay as they are until swept_join(job)."),
    {"swept_join", (PyCFunction)py_swept_join, METH_O,
     "swept_join(job) -> (seconds, on_thread): waits for a swept_start step without the GIL, writes its counts, "
     "raises its error; seconds is the step's own time, on_thread False when no thread could be started and the "
     "step ran inside swept_start."},
    KERNEL(swept_rows,
           "swept_rows(vt_* and ee_* (quads, pairs, normal, depth, weights, live), velocity, n, vertex, normal, "
           "depth, contact_velocity, friction, cloth_friction, out_vertex, out_normal, out_depth, out_velocity, "
           "out_friction) -> (count, rows without a normal): the swept pairs' contact rows merged by vertex after "
           "the colliders' contacts (written only when count fits the outputs)."),
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef moddef = {
    PyModuleDef_HEAD_INIT, "_collide",
    "Kernels of clustered ray-traced collision detection (numpy arrays in and out, by position or keyword; see "
    "collide.h).",
    -1, methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__collide(void) { return PyModule_Create(&moddef); }
