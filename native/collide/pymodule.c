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

static const pyarg_spec CCD_CULL[] = {
    ARR("positions", PA_F64, 0, 2, 3, 0),
    ARR("quads", PA_I64, 0, 2, 4, 0),
    VAL("split", PA_INT),
    ARR("displacement", PA_F64, 0, 2, 3, 0),
    ARR("gap", PA_F64, 0, 1, 0, 0),
    ARR("slack", PA_F64, OUT, 1, 0, 0),
    VAL("update", PA_FLAG),
    ARR("out", PA_I64, OUT, 1, 0, 0),
    /* the blocks of tcc_ccd_cull_blocks: all four or none */
    ARR("block_ptr", PA_I64, OPT, 1, 0, 0),
    ARR("block_vptr", PA_I64, OPT, 1, 0, 0),
    ARR("block_vertices", PA_I64, OPT, 1, 0, 0),
    ARR("block_min", PA_F64, OUT | OPT, 1, 0, 0),
    ARR("block_debt", PA_F64, OUT | OPT, 1, 0, 0),
    /* with the blocks: a second motion from positions, culled after the first without update */
    ARR("predicted", PA_F64, OPT, 2, 3, 0),
    ARR("predicted_out", PA_I64, OUT | OPT, 1, 0, 0),
};
enum { CU_X, CU_Q, CU_SPLIT, CU_MOVE, CU_GAP, CU_SLACK, CU_UPD, CU_OUT, CU_BPTR, CU_BVPTR, CU_BV, CU_BMIN, CU_BDEBT,
       CU_PRED, CU_PRED_OUT, CU_N };

static PyObject *py_ccd_cull(PyObject *self, PyObject *args, PyObject *kw)
{
    PARSE("ccd_cull", CCD_CULL, CU_N);
    Py_ssize_t n = ROWS(CU_X), k = ROWS(CU_Q);
    CHECK_ROWS(CU_MOVE, n);
    CHECK_ROWS(CU_GAP, k);
    CHECK_ROWS(CU_SLACK, k);
    CHECK_ROWS(CU_OUT, k);
    int blocks = D(CU_BPTR) != NULL;
    if (blocks != (D(CU_BVPTR) != NULL) || blocks != (D(CU_BV) != NULL) || blocks != (D(CU_BMIN) != NULL) ||
        blocks != (D(CU_BDEBT) != NULL)) {
        PyErr_SetString(PyExc_ValueError, "ccd_cull: block_ptr, block_vptr, block_vertices, block_min and block_debt "
                                          "go together (all or none)");
        goto fail;
    }
    int pred = D(CU_PRED) != NULL;
    if (pred != (D(CU_PRED_OUT) != NULL) || (pred && !blocks)) {
        PyErr_SetString(PyExc_ValueError, "ccd_cull: predicted and predicted_out go together, and with the blocks");
        goto fail;
    }
    CHECK_ROWS(CU_PRED, n);
    CHECK_ROWS(CU_PRED_OUT, k);
    Py_ssize_t nb = 0;
    if (blocks) {
        nb = ROWS(CU_BPTR) - 1;
        if (nb < 0) {
            PyErr_SetString(PyExc_ValueError, "ccd_cull: block_ptr needs at least one entry (0)");
            goto fail;
        }
        CHECK_ROWS(CU_BVPTR, nb + 1);
        CHECK_ROWS(CU_BMIN, nb);
        CHECK_ROWS(CU_BDEBT, nb);
    }
    if (pyarg_no_overlap(&s)) goto fail;
    tcc_error err = {0};
    tcc_idx count = 0, count2 = 0;
    int rc;
    if (blocks)
        RUN(tcc_ccd_cull_blocks(D(CU_X), n, D(CU_Q), k, s.v[CU_SPLIT].i, D(CU_MOVE), D(CU_GAP), D(CU_SLACK),
                                s.v[CU_UPD].i, D(CU_BPTR), nb, D(CU_BVPTR), D(CU_BV), ROWS(CU_BV), D(CU_BMIN),
                                D(CU_BDEBT), D(CU_OUT), &count, D(CU_PRED), D(CU_PRED_OUT), &count2, &err));
    else
        RUN(tcc_ccd_cull(D(CU_X), n, D(CU_Q), k, s.v[CU_SPLIT].i, D(CU_MOVE), D(CU_GAP), D(CU_SLACK), s.v[CU_UPD].i,
                         D(CU_OUT), &count, &err));
    pyarg_release(&s);
    if (rc) return kernel_error(&err);
    if (pred) return Py_BuildValue("LL", (long long)count, (long long)count2);
    return PyLong_FromLongLong(count);
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
    KERNEL(ccd_cull,
           "ccd_cull(positions, quads, split, displacement, gap, slack, update, out) -> count: the pairs that may "
           "come within their gap over a motion of the given displacement per vertex (their indices into out), from a lower "
           "bound slack of distance - gap carried per pair (updated and recomputed at positions with update). "
           "block_ptr=None, block_vptr=None, block_vertices=None, block_min=None, block_debt=None: the same by "
           "blocks of pairs, a block whose vertices moved less relative to each other than its bound allows is "
           "skipped unread (ccd.c tcc_ccd_cull_blocks). predicted=None, predicted_out=None (with the blocks): a "
           "second motion culled after the first without update, in the same pass; the result is then the pair "
           "(count, predicted count)."),
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
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef moddef = {
    PyModuleDef_HEAD_INIT, "_collide",
    "Kernels of clustered ray-traced collision detection (numpy arrays in and out, by position or keyword; see "
    "collide.h).",
    -1, methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__collide(void) { return PyModule_Create(&moddef); }
