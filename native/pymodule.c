/* pymodule.c - the Python face of the native core, `tearcloth._native`.
 *
 * Built against the CPython limited API 3.11 so that one abi3 build serves every Blender from 4.2
 * (Python 3.11) to 5.x (Python 3.13). Arrays go out through the buffer protocol without copying:
 * an `Array` holds a reference to the core's block (tc_buf), so it stays valid even when tearing
 * grows the cloth (it then shows the state before the growth; fetch a new one).
 *
 * Everything from Python is validated here or in the core before use (arrays by the argument
 * helper shared with tearcloth._collide, native/py/pyarg.h); failures become InvalidInputError (a
 * ValueError) or SimulationError (a RuntimeError) naming the problem. The core formats its messages
 * with the C library, and so does pyarg_error() here: PyErr_Format has no %g. defaults() hands out
 * the core's default settings so that tests hold them against the Python presets. The GIL
 * is released during a step; a `busy` flag refuses concurrent use of one cloth from two threads.
 */
#include "pyarg.h"
#include "tearcloth.h"

#include <math.h>
#include <stdlib.h>  /* free() of the snapshot blob: the cross builds' Python.h does not bring it */
#include <string.h>

static PyObject *ClothError, *InvalidInputError, *SimulationError;

/* ---------------- Array ---------------- */

typedef struct {
    PyObject_HEAD
    tc_buf *buf;
    Py_ssize_t shape[3];
    Py_ssize_t strides[3];
    int ndim;
    Py_ssize_t itemsize;
    char format[2];
    int exports;
} ArrayObject;

static PyTypeObject *ArrayType;

static void Array_dealloc(PyObject *self)
{
    ArrayObject *a = (ArrayObject *)self;
    tc_buf_decref(a->buf);
    PyTypeObject *tp = Py_TYPE(self);
    freefunc f = (freefunc)PyType_GetSlot(tp, Py_tp_free);
    f(self);
    Py_DECREF(tp);
}

static int Array_getbuffer(PyObject *self, Py_buffer *view, int flags)
{
    ArrayObject *a = (ArrayObject *)self;
    if (flags & PyBUF_WRITABLE) {
        PyErr_SetString(PyExc_BufferError, "cloth arrays are read-only: use Cloth.set_positions() and friends to change them");
        view->obj = NULL;
        return -1;
    }
    Py_ssize_t len = a->itemsize;
    for (int i = 0; i < a->ndim; i++) len *= a->shape[i];
    view->buf = tc_buf_data(a->buf);
    view->obj = self;
    Py_INCREF(self);
    view->len = len;
    view->readonly = 1;
    view->itemsize = a->itemsize;
    view->format = (flags & PyBUF_FORMAT) ? a->format : NULL;
    view->ndim = a->ndim;
    view->shape = (flags & PyBUF_ND) ? a->shape : NULL;
    view->strides = (flags & PyBUF_STRIDES) == PyBUF_STRIDES ? a->strides : NULL;
    view->suboffsets = NULL;
    view->internal = NULL;
    a->exports++;
    return 0;
}

static void Array_releasebuffer(PyObject *self, Py_buffer *view) { ((ArrayObject *)self)->exports--; }

static PyType_Slot Array_slots[] = {
    {Py_tp_dealloc, Array_dealloc},
    {Py_bf_getbuffer, Array_getbuffer},
    {Py_bf_releasebuffer, Array_releasebuffer},
    {Py_tp_doc, "A read-only, zero-copy view of one of the cloth's arrays (buffer protocol)."},
    {0, 0},
};
static PyType_Spec Array_spec = {"tearcloth._native.Array", sizeof(ArrayObject), 0, Py_TPFLAGS_DEFAULT, Array_slots};

static PyObject *make_array(tc_buf *buf, size_t rows, size_t cols, size_t item, int ndim3, const char *fmt)
{
    ArrayObject *a = PyObject_New(ArrayObject, ArrayType);
    if (!a) { tc_buf_decref(buf); return NULL; }
    a->buf = buf;
    a->itemsize = (Py_ssize_t)item;
    a->format[0] = fmt[0]; a->format[1] = 0;
    a->exports = 0;
    if (ndim3) {
        a->ndim = 3;
        a->shape[0] = (Py_ssize_t)rows; a->shape[1] = 3; a->shape[2] = (Py_ssize_t)(cols / 3);
    } else if (cols == 1) {
        a->ndim = 1; a->shape[0] = (Py_ssize_t)rows;
    } else {
        a->ndim = 2; a->shape[0] = (Py_ssize_t)rows; a->shape[1] = (Py_ssize_t)cols;
    }
    Py_ssize_t s = a->itemsize;
    for (int i = a->ndim - 1; i >= 0; i--) { a->strides[i] = s; s *= a->shape[i]; }
    return (PyObject *)a;
}

/* ---------------- buffer arguments ---------------- */

/* Arrays come in as flat tables checked by the shared helper (native/py/pyarg.h): float64 or int32,
 * C-contiguous, one dimension (cols 0) or rows of cols values; wrong shapes raise
 * InvalidInputError. */
typedef pyarg_value Arg;

static void arg_release(Arg *a) { pyarg_value_release(a); }

static int arg_get(PyObject *obj, const char *name, char kind, Py_ssize_t cols, Arg *out, Py_ssize_t *rows)
{
    pyarg_spec spec = {name, kind == 'd' ? PA_F64 : PA_I32, 0, 0, {cols, 0, 0}};
    if (pyarg_buffer(obj, &spec, InvalidInputError, out)) return -1;
    *rows = out->rows;
    return 0;
}

/* ---------------- Cloth ---------------- */

typedef struct {
    PyObject_HEAD
    tc_cloth *c;
    int busy;
} ClothObject;

static PyObject *raise_core(ClothObject *self, int rc)
{
    const char *m = self->c ? tc_cloth_error(self->c) : "no cloth";
    if (rc == TC_ERR_NOMEM) return PyErr_NoMemory();
    PyErr_SetString(rc == TC_ERR_UNSTABLE ? SimulationError : InvalidInputError, m);
    return NULL;
}

static int ready(ClothObject *self)
{
    if (!self->c) { PyErr_SetString(ClothError, "the cloth was not initialised"); return 0; }
    if (self->busy) { PyErr_SetString(ClothError, "the cloth is in use in another thread (a step, or a restore or creation of its state)"); return 0; }
    return 1;
}

static void Cloth_dealloc(PyObject *o)
{
    ClothObject *self = (ClothObject *)o;
    tc_cloth_destroy(self->c);
    PyTypeObject *tp = Py_TYPE(o);
    freefunc f = (freefunc)PyType_GetSlot(tp, Py_tp_free);
    f(o);
    Py_DECREF(tp);
}

/* InvalidInputError for a mesh the core refused, with the elements it names as attributes
 * (.triangles, .vertices: tuples of 0-based indices as given), so callers need not read the text. */
static void raise_refused_mesh(const char *msg, tc_culprits k)
{
    PyObject *exc = PyObject_CallFunction(InvalidInputError, "s", msg);
    if (!exc) return;
    PyObject *t = PyTuple_New(k.n_triangles), *v = PyTuple_New(k.n_vertices);
    for (int32_t i = 0; t && i < k.n_triangles; i++) PyTuple_SetItem(t, i, PyLong_FromLong(k.triangles[i]));
    for (int32_t i = 0; v && i < k.n_vertices; i++) PyTuple_SetItem(v, i, PyLong_FromLong(k.vertices[i]));
    if (t && v && !PyObject_SetAttrString(exc, "triangles", t) && !PyObject_SetAttrString(exc, "vertices", v))
        PyErr_SetObject(InvalidInputError, exc);
    Py_XDECREF(t); Py_XDECREF(v); Py_DECREF(exc);
}

static int Cloth_init(PyObject *o, PyObject *args, PyObject *kw)
{
    ClothObject *self = (ClothObject *)o;
    static char *kwl[] = {"positions", "triangles", "rest", "corner_uv", "groups", NULL};
    PyObject *pos, *tri, *rest = Py_None, *uv = Py_None, *groups = Py_None;
    if (!PyArg_ParseTupleAndKeywords(args, kw, "OO|OOO", kwl, &pos, &tri, &rest, &uv, &groups)) return -1;
    if (self->c) { PyErr_SetString(ClothError, "Cloth.__init__ called twice"); return -1; }
    Arg P = {0}, T = {0}, R = {0}, U = {0}, G = {0};
    Py_ssize_t n, m, k;
    int rest_dim = 0, ng = 0, rc = -1;
    if (arg_get(pos, "positions", 'd', 3, &P, &n) || arg_get(tri, "triangles", 'i', 3, &T, &m)) goto done;
    if (rest != Py_None) {
        if (arg_get(rest, "rest", 'd', 0, &R, &k)) goto done;
        if (k == 2 * n) rest_dim = 2;
        else if (k == 3 * n) rest_dim = 3;
        else { PyErr_Format(InvalidInputError, "rest must have shape (%zd, 2) or (%zd, 3)", n, n); goto done; }
    }
    if (uv != Py_None) {
        if (arg_get(uv, "corner_uv", 'd', 6, &U, &k)) goto done;
        if (k != m) { PyErr_Format(InvalidInputError, "corner_uv must have shape (%zd, 3, 2) (got %zd rows)", m, k); goto done; }
    }
    if (groups != Py_None) {
        if (arg_get(groups, "groups", 'd', 0, &G, &k)) goto done;
        if (n == 0 || k % n) { PyErr_Format(InvalidInputError, "groups must have shape (%zd, G)", n); goto done; }
        ng = (int)(k / n);
    }
    char msg[512] = "";
    tc_cloth *c;
    if (self->busy) { PyErr_SetString(ClothError, "the cloth is in use in another thread (a step, or a restore or creation of its state)"); goto done; }
    self->busy = 1;  /* as in restore: nothing may start on the cloth replaced below meanwhile */
    Py_BEGIN_ALLOW_THREADS
    c = tc_cloth_create(P.view.buf, (int32_t)n, T.view.buf, (int32_t)m, R.held ? R.view.buf : NULL, rest_dim,
                        U.held ? U.view.buf : NULL, G.held ? G.view.buf : NULL, ng, NULL, msg, sizeof msg);
    Py_END_ALLOW_THREADS
    self->busy = 0;
    if (!c) { raise_refused_mesh(msg, tc_create_culprits()); goto done; }
    tc_cloth_destroy(self->c);  /* __init__ called again: the cloth it had (none the first time) */
    self->c = c;
    rc = 0;
done:
    arg_release(&P); arg_release(&T); arg_release(&R); arg_release(&U); arg_release(&G);
    return rc;
}

static PyObject *Cloth_set_material(PyObject *o, PyObject *args, PyObject *kw)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    tc_material m = tc_cloth_material(self->c);
    static char *kwl[] = {"young", "poisson", "thickness", "density", "bending", "damping_mass",
                          "damping_stiffness", "tear_stress", "snap_tolerance", "tear_radius", "crack_speed_ratio",
                          "orthotropic", "young_weft", "shear_modulus", "grain_angle", "tear_stress_weft", "plastic",
                          "yield_stress", "yield_stress_weft", "hardening", NULL};
    if (!PyArg_ParseTupleAndKeywords(args, kw, "|$dddddddddddpddddpddd", kwl, &m.young, &m.poisson, &m.thickness,
                                     &m.density, &m.bending, &m.damping_mass, &m.damping_stiffness, &m.tear_stress,
                                     &m.snap_tolerance, &m.tear_radius, &m.crack_speed_ratio, &m.orthotropic,
                                     &m.young_weft, &m.shear_modulus, &m.grain_angle, &m.tear_stress_weft, &m.plastic,
                                     &m.yield_stress, &m.yield_stress_weft, &m.hardening))
        return NULL;
    int rc = tc_cloth_set_material(self->c, &m);
    if (rc) return raise_core(self, rc);
    Py_RETURN_NONE;
}

static PyObject *material_dict(const tc_material *m);
static PyObject *solver_dict(const tc_solver_settings *s);
static PyObject *tearing_dict(const tc_tear_settings *s);

static PyObject *Cloth_material(PyObject *o, PyObject *unused)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    tc_material m = tc_cloth_material(self->c);
    return material_dict(&m);
}

static PyObject *Cloth_set_solver(PyObject *o, PyObject *args, PyObject *kw)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    tc_solver_settings s = tc_cloth_solver(self->c);
    static char *kwl[] = {"gravity", "cg_tolerance", "cg_max_iterations", "max_stretch", "contact_max_push",
                          "contact_correction", "preconditioner", NULL};
    PyObject *g = NULL;
    const char *pre = NULL;
    if (!PyArg_ParseTupleAndKeywords(args, kw, "|$Odiddds", kwl, &g, &s.cg_tolerance, &s.cg_max_iterations,
                                     &s.max_stretch, &s.contact_max_push, &s.contact_correction, &pre))
        return NULL;
    if (pre) {
        s.preconditioner = tc_precond_from_name(pre);
        if (s.preconditioner < 0) {
            PyErr_Format(PyExc_ValueError, "preconditioner must be 'auto', 'jacobi', 'amg' or 'sgs' (got '%s')", pre);
            return NULL;
        }
    }
    if (g && !PyArg_ParseTuple(g, "ddd", &s.gravity[0], &s.gravity[1], &s.gravity[2])) return NULL;
    int rc = tc_cloth_set_solver(self->c, &s);
    if (rc) return raise_core(self, rc);
    Py_RETURN_NONE;
}

static PyObject *Cloth_solver(PyObject *o, PyObject *unused)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    tc_solver_settings s = tc_cloth_solver(self->c);
    return solver_dict(&s);
}

static PyObject *Cloth_set_tearing(PyObject *o, PyObject *args, PyObject *kw)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    tc_tear_settings s = tc_cloth_tearing(self->c);
    static char *kwl[] = {"enabled", "scan_period", "min_angle_deg", "min_fragment_area", NULL};
    if (!PyArg_ParseTupleAndKeywords(args, kw, "|$pidd", kwl, &s.enabled, &s.scan_period, &s.min_angle_deg,
                                     &s.min_fragment_area))
        return NULL;
    int rc = tc_cloth_set_tearing(self->c, &s);
    if (rc) return raise_core(self, rc);
    Py_RETURN_NONE;
}

static PyObject *Cloth_tearing(PyObject *o, PyObject *unused)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    tc_tear_settings s = tc_cloth_tearing(self->c);
    return tearing_dict(&s);
}

static PyObject *vertex_array_call(ClothObject *self, PyObject *arr, int which)
{
    Arg A = {0};
    Py_ssize_t n;
    int rc;
    if (which == 2) {
        if (arg_get(arr, "tear strength", 'd', 0, &A, &n)) return NULL;
        for (Py_ssize_t i = 0; i < n; i++) {
            double f = ((double *)A.view.buf)[i];
            if (!(f > 0 && isfinite(f))) {
                arg_release(&A);
                return pyarg_error(InvalidInputError, "tear strength factor of vertex %zd must be > 0 and finite (got %g)", i, f);
            }
        }
        rc = tc_cloth_set_tear_strength(self->c, A.view.buf, (int32_t)n);
    } else {
        if (arg_get(arr, which ? "velocities" : "positions", 'd', 3, &A, &n)) return NULL;
        rc = which ? tc_cloth_set_velocities(self->c, A.view.buf, (int32_t)n)
                   : tc_cloth_set_positions(self->c, A.view.buf, (int32_t)n);
    }
    arg_release(&A);
    if (rc) return raise_core(self, rc);
    Py_RETURN_NONE;
}

/* set_grain_angles(angles): one float64 per triangle (rad), NaN for the material's grain_angle. */
static PyObject *Cloth_set_grain_angles(PyObject *o, PyObject *arr)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    Arg A = {0};
    Py_ssize_t n;
    if (arg_get(arr, "grain angles", 'd', 0, &A, &n)) return NULL;
    int rc = n > INT32_MAX ? TC_ERR_INPUT : tc_cloth_set_grain_angles(self->c, A.view.buf, (int32_t)n);
    arg_release(&A);
    if (rc) return n > INT32_MAX ? pyarg_error(InvalidInputError, "too many grain angles (%zd)", n) : raise_core(self, rc);
    Py_RETURN_NONE;
}

static PyObject *Cloth_set_positions(PyObject *o, PyObject *a) { return ready((ClothObject *)o) ? vertex_array_call((ClothObject *)o, a, 0) : NULL; }
static PyObject *Cloth_set_velocities(PyObject *o, PyObject *a) { return ready((ClothObject *)o) ? vertex_array_call((ClothObject *)o, a, 1) : NULL; }
static PyObject *Cloth_set_tear_strength(PyObject *o, PyObject *a) { return ready((ClothObject *)o) ? vertex_array_call((ClothObject *)o, a, 2) : NULL; }

static PyObject *Cloth_pin(PyObject *o, PyObject *args, PyObject *kw)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    static char *kwl[] = {"vertices", "pinned", NULL};
    PyObject *idx;
    int pinned = 1;
    if (!PyArg_ParseTupleAndKeywords(args, kw, "O|p", kwl, &idx, &pinned)) return NULL;
    Arg A = {0};
    Py_ssize_t k;
    if (arg_get(idx, "vertices", 'i', 0, &A, &k)) return NULL;
    int rc = tc_cloth_pin(self->c, A.view.buf, (int32_t)k, pinned);
    arg_release(&A);
    if (rc) return raise_core(self, rc);
    Py_RETURN_NONE;
}

static PyObject *Cloth_set_pin_goals(PyObject *o, PyObject *args)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    PyObject *idx, *pos;
    if (!PyArg_ParseTuple(args, "OO", &idx, &pos)) return NULL;
    Arg A = {0}, P = {0};
    Py_ssize_t k, kp;
    if (arg_get(idx, "vertices", 'i', 0, &A, &k)) return NULL;
    if (arg_get(pos, "goals", 'd', 3, &P, &kp)) { arg_release(&A); return NULL; }
    if (k != kp) {
        arg_release(&A); arg_release(&P);
        return PyErr_Format(InvalidInputError, "%zd pinned vertices but %zd goals", k, kp);
    }
    int rc = tc_cloth_set_pin_goals(self->c, A.view.buf, P.view.buf, (int32_t)k);
    arg_release(&A); arg_release(&P);
    if (rc) return raise_core(self, rc);
    Py_RETURN_NONE;
}

static PyObject *Cloth_set_pin_springs(PyObject *o, PyObject *args)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    PyObject *idx, *stiff;
    if (!PyArg_ParseTuple(args, "OO", &idx, &stiff)) return NULL;
    Arg A = {0}, K = {0};
    Py_ssize_t k, kk;
    if (arg_get(idx, "vertices", 'i', 0, &A, &k)) return NULL;
    if (arg_get(stiff, "stiffness", 'd', 0, &K, &kk)) { arg_release(&A); return NULL; }
    if (k != kk) {
        arg_release(&A); arg_release(&K);
        return PyErr_Format(InvalidInputError, "%zd vertices but %zd pin spring stiffnesses", k, kk);
    }
    int rc = tc_cloth_set_pin_springs(self->c, A.view.buf, K.view.buf, (int32_t)k);
    arg_release(&A); arg_release(&K);
    if (rc) return raise_core(self, rc);
    Py_RETURN_NONE;
}

static PyObject *Cloth_pin_springs(PyObject *o, PyObject *unused)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    const double *k = tc_cloth_pin_springs(self->c);
    return PyBytes_FromStringAndSize((const char *)k, k ? (Py_ssize_t)tc_cloth_num_vertices(self->c) * (Py_ssize_t)sizeof(double) : 0);
}

static PyObject *Cloth_pin_flags(PyObject *o, PyObject *unused)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    return PyBytes_FromStringAndSize((const char *)tc_cloth_pin_flags(self->c), (Py_ssize_t)tc_cloth_num_vertices(self->c));
}

static PyObject *Cloth_warp_fallbacks(PyObject *o, PyObject *unused)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    PyObject *out = PyBytes_FromStringAndSize(NULL, (Py_ssize_t)tc_cloth_num_triangles(self->c));
    char *at = out ? PyBytes_AsString(out) : NULL;  /* (the limited API has no PyBytes_AS_STRING) */
    if (!at) { Py_XDECREF(out); return NULL; }
    tc_cloth_warp_fallbacks(self->c, (uint8_t *)at);
    return out;
}

static PyObject *Cloth_add_handle(PyObject *o, PyObject *idx)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    Arg A = {0};
    Py_ssize_t k;
    if (arg_get(idx, "vertices", 'i', 0, &A, &k)) return NULL;
    int32_t h = -1;
    int rc = tc_cloth_add_handle(self->c, A.view.buf, (int32_t)k, &h);
    arg_release(&A);
    if (rc) return raise_core(self, rc);
    return PyLong_FromLong(h);
}

static PyObject *Cloth_set_handle_target(PyObject *o, PyObject *args)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    int h;
    PyObject *m;
    if (!PyArg_ParseTuple(args, "iO", &h, &m)) return NULL;
    Arg A = {0};
    Py_ssize_t k;
    if (arg_get(m, "affine", 'd', 0, &A, &k) && (PyErr_Clear(), arg_get(m, "affine", 'd', 4, &A, &k))) return NULL;
    if (A.view.len != 12 * 8) {
        arg_release(&A);
        return PyErr_Format(InvalidInputError, "handle target must be a 3x4 affine matrix (12 float64 values)");
    }
    int rc = tc_cloth_set_handle_target(self->c, h, A.view.buf);
    arg_release(&A);
    if (rc) return raise_core(self, rc);
    Py_RETURN_NONE;
}

static PyObject *Cloth_release_handle(PyObject *o, PyObject *arg)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    long h = PyLong_AsLong(arg);
    if (h == -1 && PyErr_Occurred()) return NULL;
    int rc = tc_cloth_release_handle(self->c, (int32_t)h);
    if (rc) return raise_core(self, rc);
    Py_RETURN_NONE;
}

static PyObject *Cloth_forget_contacts(PyObject *o, PyObject *unused)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    tc_cloth_forget_contacts(self->c);
    Py_RETURN_NONE;
}

static PyObject *Cloth_handle_force(PyObject *o, PyObject *arg)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    long h = PyLong_AsLong(arg);
    if (h == -1 && PyErr_Occurred()) return NULL;
    double f[3];
    if (tc_cloth_handle_force(self->c, (int32_t)h, f))
        return PyErr_Format(InvalidInputError, "no handle %ld (there are %d)", h, (int)tc_cloth_num_handles(self->c));
    return Py_BuildValue("(ddd)", f[0], f[1], f[2]);
}

static PyObject *Cloth_pin_force(PyObject *o, PyObject *unused)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    double f[3];
    tc_cloth_pin_force(self->c, f);
    return Py_BuildValue("(ddd)", f[0], f[1], f[2]);
}

static PyObject *Cloth_set_contacts(PyObject *o, PyObject *args, PyObject *kw)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    static char *kwl[] = {"vertex", "normal", "depth", "velocity", "friction", NULL};
    PyObject *vo, *no, *dob, *velo = Py_None, *fro = Py_None;
    if (!PyArg_ParseTupleAndKeywords(args, kw, "OOO|OO", kwl, &vo, &no, &dob, &velo, &fro)) return NULL;
    Arg V = {0}, N = {0}, D = {0}, W = {0}, F = {0};
    Py_ssize_t k, k2;
    PyObject *ret = NULL;
    if (arg_get(vo, "vertex", 'i', 0, &V, &k)) goto done;
    if (arg_get(no, "normal", 'd', 3, &N, &k2)) goto done;
    if (k2 != k) { PyErr_Format(InvalidInputError, "normal has %zd rows, vertex has %zd", k2, k); goto done; }
    if (arg_get(dob, "depth", 'd', 0, &D, &k2)) goto done;
    if (k2 != k) { PyErr_Format(InvalidInputError, "depth has %zd values, vertex has %zd", k2, k); goto done; }
    if (velo != Py_None) {
        if (arg_get(velo, "velocity", 'd', 3, &W, &k2)) goto done;
        if (k2 != k) { PyErr_Format(InvalidInputError, "velocity has %zd rows, vertex has %zd", k2, k); goto done; }
    }
    if (fro != Py_None) {
        if (arg_get(fro, "friction", 'd', 0, &F, &k2)) goto done;
        if (k2 != k) { PyErr_Format(InvalidInputError, "friction has %zd values, vertex has %zd", k2, k); goto done; }
    }
    int rc = tc_cloth_set_contacts(self->c, V.view.buf, N.view.buf, D.view.buf, W.held ? W.view.buf : NULL,
                                   F.held ? F.view.buf : NULL, (int32_t)k);
    if (rc) { raise_core(self, rc); goto done; }
    ret = Py_None;
    Py_INCREF(ret);
done:
    arg_release(&V); arg_release(&N); arg_release(&D); arg_release(&W); arg_release(&F);
    return ret;
}

static PyObject *Cloth_step(PyObject *o, PyObject *args, PyObject *kw)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    static char *kwl[] = {"dt", "substeps", NULL};
    double dt;
    int sub = 1;
    if (!PyArg_ParseTupleAndKeywords(args, kw, "d|i", kwl, &dt, &sub)) return NULL;
    int rc;
    self->busy = 1;
    Py_BEGIN_ALLOW_THREADS
    rc = tc_cloth_step(self->c, dt, sub);
    Py_END_ALLOW_THREADS
    self->busy = 0;
    if (rc) return raise_core(self, rc);
    Py_RETURN_NONE;
}

static PyObject *Cloth_stats(PyObject *o, PyObject *unused)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    tc_stats s = tc_cloth_stats(self->c);
    return Py_BuildValue("{s:i,s:d,s:d,s:d,s:L,s:i,s:i,s:i,s:i,s:i,s:d,s:d,s:i,s:i,s:L,s:L,s:i,s:i,s:i,s:i,s:i,s:d,s:L,s:L,s:i,s:i,s:i,s:i,s:L,s:L,s:L,s:L,s:L,s:L,s:L,s:L,s:L,s:i,s:i,s:i,s:L,s:L,s:L,s:L}", "cg_iterations",
                         s.cg_iterations, "cg_residual", s.cg_residual, "fem_seconds", s.fem_seconds, "tear_seconds",
                         s.tear_seconds, "steps", (long long)s.steps, "tears_started", (int)s.tears_started, "cuts",
                         (int)s.cuts, "contacts", (int)s.contacts, "vertices", (int)tc_cloth_num_vertices(self->c),
                         "triangles", (int)tc_cloth_num_triangles(self->c), "cg_residual_force", s.cg_residual_force,
                         "cg_force_scale", s.cg_force_scale, "substep_splits", (int)s.substep_splits,
                         "unconverged_substeps", (int)s.unconverged_substeps, "unconverged_steps",
                         (long long)s.unconverged_steps, "matrix_bytes", (long long)s.matrix_bytes, "tips_retired",
                         (int)s.tips_retired, "grips_released", (int)s.grips_released, "plastic_triangles",
                         (int)s.plastic_triangles, "plastic_unconverged", (int)s.plastic_unconverged, "amg_levels",
                         (int)s.amg_levels, "amg_setup_seconds", s.amg_setup_seconds, "amg_fallbacks",
                         (long long)s.amg_fallbacks, "sgs_fallbacks", (long long)s.sgs_fallbacks, "fragments_removed",
                         (int)s.fragments_removed, "fragment_triangles_removed", (int)s.fragment_triangles_removed,
                         "fragment_vertices_removed", (int)s.fragment_vertices_removed, "fragments_kept",
                         (int)s.fragments_kept, "amg_bytes", (long long)s.amg_bytes,
                         "contact_directions_merged", (long long)s.contact_directions_merged,
                         "contact_speed_clamps", (long long)s.contact_speed_clamps,
                         "friction_slips", (long long)s.friction_slips,
                         "friction_cone_exceeded", (long long)s.friction_cone_exceeded,
                         "friction_sticks", (long long)s.friction_sticks, "slides_carried", (long long)s.slides_carried,
                         "lifts_carried", (long long)s.lifts_carried, "contact_rounds_capped", (long long)s.contact_rounds_capped,
                         "solves", (int)s.solves, "sgs_solves", (int)s.sgs_solves, "stiff_groups", (int)s.stiff_groups,
                         "stiff_group_failures", (long long)s.stiff_group_failures,
                         "contact_pushes_capped", (long long)s.contact_pushes_capped, "rotation_solves", (long long)s.rotation_solves,
                         "rotations_capped", (long long)s.rotations_capped);
}

/* _product(p) -> bytes of A p (float64, N x 3) with the last sub-step's matrix: private, for the
 * tests of the product's kernels (tc_cloth_product). */
static PyObject *Cloth_product(PyObject *o, PyObject *a)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    Arg A = {0};
    Py_ssize_t n;
    if (arg_get(a, "p", 'd', 3, &A, &n)) return NULL;
    PyObject *out = PyBytes_FromStringAndSize(NULL, 3 * n * (Py_ssize_t)sizeof(double));
    if (!out) { arg_release(&A); return NULL; }
    int rc = tc_cloth_product(self->c, A.view.buf, (int32_t)n, (double *)PyBytes_AsString(out));
    arg_release(&A);
    if (rc) { Py_DECREF(out); return raise_core(self, rc); }
    return out;
}

static PyObject *Cloth_energy(PyObject *o, PyObject *unused)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    tc_energy e = tc_cloth_energy(self->c);
    return Py_BuildValue("{s:d,s:d,s:d,s:d,s:d}", "kinetic", e.kinetic, "elastic", e.elastic, "bending", e.bending,
                         "gravity", e.gravity, "pins", e.pins);
}

static PyObject *Cloth_array(PyObject *o, PyObject *arg)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    long id = PyLong_AsLong(arg);
    if (id == -1 && PyErr_Occurred()) return NULL;
    if (id < 0 || id >= TC_ARRAY_COUNT) return PyErr_Format(PyExc_ValueError, "unknown array id %ld", id);
    size_t rows, cols, item;
    tc_buf *b = tc_cloth_array(self->c, (tc_array_id)id, &rows, &cols, &item);
    if (!b) return PyErr_NoMemory();
    int three = id == TC_CORNER_UV || id == TC_STRESS;
    return make_array(b, rows, cols, item, three, id == TC_TRIANGLES ? "i" : "d");
}

static PyObject *Cloth_counts(PyObject *o, PyObject *unused)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    return Py_BuildValue("(iii)", (int)tc_cloth_num_vertices(self->c), (int)tc_cloth_num_triangles(self->c),
                         tc_cloth_num_groups(self->c));
}

static PyObject *Cloth_scripted_tear(PyObject *o, PyObject *args)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    int v;
    double d[3], len;
    if (!PyArg_ParseTuple(args, "i(ddd)d", &v, &d[0], &d[1], &d[2], &len)) return NULL;
    int32_t cuts = 0;
    int rc = tc_cloth_scripted_tear(self->c, v, d, len, &cuts);
    if (rc) return raise_core(self, rc);
    return PyLong_FromLong(cuts);
}

static PyObject *bytes_of(const void *p, size_t n) { return PyBytes_FromStringAndSize(n ? p : "", (Py_ssize_t)n); }

static PyObject *Cloth_events(PyObject *o, PyObject *unused)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    tc_events e = tc_cloth_events(self->c);
    return Py_BuildValue("{s:N,s:N,s:N,s:N,s:N,s:N,s:N,s:N}",
                         "new_vertices", bytes_of(e.new_vertices, 4 * (size_t)e.n_new_vertices),
                         "parents", bytes_of(e.parents, 8 * (size_t)e.n_new_vertices),
                         "weights", bytes_of(e.weights, 8 * (size_t)e.n_new_vertices),
                         "changed_triangles", bytes_of(e.changed_triangles, 4 * (size_t)e.n_changed_triangles),
                         "new_triangles", bytes_of(e.new_triangles, 4 * (size_t)e.n_new_triangles),
                         "tips", bytes_of(e.tips, 4 * (size_t)e.n_tips),
                         "removed_vertices", bytes_of(e.removed_vertices, 4 * (size_t)e.n_removed_vertices),
                         "removed_triangles", bytes_of(e.removed_triangles, 4 * (size_t)e.n_removed_triangles));
}

static PyObject *Cloth_vertex_stress(PyObject *o, PyObject *arg)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    long v = PyLong_AsLong(arg);
    if (v == -1 && PyErr_Occurred()) return NULL;
    double val, dir[3];
    int rc = tc_cloth_vertex_stress(self->c, (int32_t)v, &val, dir);
    if (rc) return raise_core(self, rc);
    return Py_BuildValue("(d(ddd))", val, dir[0], dir[1], dir[2]);
}

/* The whole simulation state as bytes (snapshot.c), and back: restore() replaces this cloth's state
 * with a blob's, or raises InvalidInputError (the cloth unchanged) for a blob of another version or
 * build, a truncated or a corrupted one. */
static PyObject *Cloth_snapshot(PyObject *o, PyObject *unused)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    void *blob = NULL;
    size_t size = 0;
    if (tc_cloth_snapshot(self->c, &blob, &size)) return PyErr_NoMemory();
    PyObject *out = PyBytes_FromStringAndSize(blob, (Py_ssize_t)size);
    free(blob);
    return out;
}

/* _memory() -> {name: (bytes used, bytes held)} of every array (tc_cloth_memory): private, for the
 * memory accounting of the scaling bench and its tests. */
static PyObject *Cloth_memory(PyObject *o, PyObject *unused)
{
    ClothObject *self = (ClothObject *)o;
    if (!ready(self)) return NULL;
    PyObject *d = PyDict_New();
    if (!d) return NULL;
    for (size_t k = 0; k < tc_cloth_memory_count(); k++) {
        size_t used, held;
        const char *name = tc_cloth_memory(self->c, k, &used, &held);
        PyObject *v = Py_BuildValue("(nn)", (Py_ssize_t)used, (Py_ssize_t)held);
        if (!v || PyDict_SetItemString(d, name, v)) { Py_XDECREF(v); Py_DECREF(d); return NULL; }
        Py_DECREF(v);
    }
    return d;
}

static PyObject *Cloth_restore(PyObject *o, PyObject *arg)
{
    ClothObject *self = (ClothObject *)o;
    if (self->busy) { PyErr_SetString(ClothError, "the cloth is in use in another thread (a step, or a restore or creation of its state)"); return NULL; }
    Py_buffer view;
    if (PyObject_GetBuffer(arg, &view, PyBUF_SIMPLE)) return NULL;
    char msg[512] = "";
    tc_cloth *c;
    /* busy while the GIL is released: a step (or another restore) started by another thread in the
       meantime would run on the cloth destroyed below */
    self->busy = 1;
    Py_BEGIN_ALLOW_THREADS
    c = tc_cloth_from_snapshot(view.buf, (size_t)view.len, msg, sizeof msg);
    Py_END_ALLOW_THREADS
    self->busy = 0;
    PyBuffer_Release(&view);
    if (!c) { PyErr_SetString(InvalidInputError, msg); return NULL; }
    tc_cloth_destroy(self->c);
    self->c = c;
    Py_RETURN_NONE;
}

static PyMethodDef Cloth_methods[] = {
    {"set_material", (PyCFunction)(void (*)(void))Cloth_set_material, METH_VARARGS | METH_KEYWORDS, "Set material values (SI units)."},
    {"material", Cloth_material, METH_NOARGS, "Material values as a dict."},
    {"set_solver", (PyCFunction)(void (*)(void))Cloth_set_solver, METH_VARARGS | METH_KEYWORDS, "Set solver settings."},
    {"solver", Cloth_solver, METH_NOARGS, "Solver settings as a dict."},
    {"set_tearing", (PyCFunction)(void (*)(void))Cloth_set_tearing, METH_VARARGS | METH_KEYWORDS, "Set tearing settings."},
    {"tearing", Cloth_tearing, METH_NOARGS, "Tearing settings as a dict."},
    {"set_positions", Cloth_set_positions, METH_O, "Replace positions (N, 3) float64."},
    {"set_velocities", Cloth_set_velocities, METH_O, "Replace velocities (N, 3) float64."},
    {"set_tear_strength", Cloth_set_tear_strength, METH_O, "Per-vertex factor on the tear stress (N,) float64."},
    {"set_grain_angles", Cloth_set_grain_angles, METH_O, "Per-triangle grain angle (M,) float64 in radians; NaN: the material's."},
    {"pin", (PyCFunction)(void (*)(void))Cloth_pin, METH_VARARGS | METH_KEYWORDS, "Pin (or unpin) vertices."},
    {"set_pin_goals", Cloth_set_pin_goals, METH_VARARGS,
     "Where pinned vertices (int32 indices) are to be at the end of the next step ((k, 3) float64 m)."},
    {"pin_flags", Cloth_pin_flags, METH_NOARGS, "One byte per vertex, 1 where pinned."},
    {"warp_fallbacks", Cloth_warp_fallbacks, METH_NOARGS,
     "One byte per triangle, 1 where its UVs carry no warp direction (the rest X axis is taken)."},
    {"set_pin_springs", Cloth_set_pin_springs, METH_VARARGS,
     "set_pin_springs(vertices, stiffness): soft pins, a spring (N/m, 0 removes it) towards each vertex's goal."},
    {"pin_springs", Cloth_pin_springs, METH_NOARGS, "float64 bytes, one per vertex (N/m), or empty while none is set."},
    {"add_handle", Cloth_add_handle, METH_O, "Create a handle from vertex indices; returns its id."},
    {"set_handle_target", Cloth_set_handle_target, METH_VARARGS, "Set a handle's 3x4 affine target."},
    {"release_handle", Cloth_release_handle, METH_O, "Let go of a handle."},
    {"forget_contacts", Cloth_forget_contacts, METH_NOARGS,
     "Drop the contact state carried from the last sub-step (who slid, with what friction; who lifted off)."},
    {"handle_force", Cloth_handle_force, METH_O, "Force of eq. (6) on a handle (N)."},
    {"pin_force", Cloth_pin_force, METH_NOARGS, "Sum of elastic + external forces on pinned vertices (N)."},
    {"set_contacts", (PyCFunction)(void (*)(void))Cloth_set_contacts, METH_VARARGS | METH_KEYWORDS, "Contacts for the next step."},
    {"step", (PyCFunction)(void (*)(void))Cloth_step, METH_VARARGS | METH_KEYWORDS, "Advance by dt seconds (GIL released)."},
    {"stats", Cloth_stats, METH_NOARGS, "Statistics of the last step."},
    {"energy", Cloth_energy, METH_NOARGS, "Kinetic, elastic, bending and gravity energies (J)."},
    {"_product", Cloth_product, METH_O, "Private: A p (bytes, float64 N x 3) with the last sub-step's system matrix."},
    {"array", Cloth_array, METH_O, "Zero-copy view of an array by id."},
    {"counts", Cloth_counts, METH_NOARGS, "(vertices, triangles, groups)."},
    {"scripted_tear", Cloth_scripted_tear, METH_VARARGS, "Tear from a vertex along a direction for a length (m)."},
    {"events", Cloth_events, METH_NOARGS, "Topology events of the last step, as raw bytes."},
    {"vertex_stress", Cloth_vertex_stress, METH_O, "Largest principal stress at a vertex and its direction."},
    {"snapshot", Cloth_snapshot, METH_NOARGS, "The whole simulation state as bytes (restore() takes it back)."},
    {"_memory", Cloth_memory, METH_NOARGS, "Private: {array: (bytes used, bytes held)} of the cloth (accounting)."},
    {"restore", Cloth_restore, METH_O, "Replace the whole simulation state by a snapshot() blob (validated)."},
    {NULL, NULL, 0, NULL},
};

static PyType_Slot Cloth_slots[] = {
    {Py_tp_dealloc, Cloth_dealloc},
    {Py_tp_init, Cloth_init},
    {Py_tp_new, PyType_GenericNew},
    {Py_tp_methods, Cloth_methods},
    {Py_tp_doc, "Native cloth: co-rotational FEM, implicit Euler, tearing. Use tearcloth.Cloth instead."},
    {0, 0},
};
static PyType_Spec Cloth_spec = {"tearcloth._native.Cloth", sizeof(ClothObject), 0,
                                 Py_TPFLAGS_DEFAULT | Py_TPFLAGS_BASETYPE, Cloth_slots};

/* The C defaults (settings.c) with the C struct field names, so a test can hold them against the
 * Python side's presets: {"material": {...}, "solver": {...}, "tearing": {...}}. */
static PyObject *material_dict(const tc_material *m)
{
    return Py_BuildValue("{s:d,s:d,s:d,s:d,s:d,s:d,s:d,s:d,s:d,s:d,s:d,s:N,s:d,s:d,s:d,s:d,s:N,s:d,s:d,s:d}", "young",
                         m->young, "poisson", m->poisson, "thickness", m->thickness, "density", m->density, "bending",
                         m->bending, "damping_mass", m->damping_mass, "damping_stiffness", m->damping_stiffness,
                         "tear_stress", m->tear_stress, "snap_tolerance", m->snap_tolerance, "tear_radius",
                         m->tear_radius, "crack_speed_ratio", m->crack_speed_ratio, "orthotropic",
                         PyBool_FromLong(m->orthotropic), "young_weft", m->young_weft, "shear_modulus", m->shear_modulus,
                         "grain_angle", m->grain_angle, "tear_stress_weft", m->tear_stress_weft, "plastic",
                         PyBool_FromLong(m->plastic), "yield_stress", m->yield_stress, "yield_stress_weft",
                         m->yield_stress_weft, "hardening", m->hardening);
}

static PyObject *solver_dict(const tc_solver_settings *s)
{
    return Py_BuildValue("{s:(ddd),s:d,s:i,s:d,s:d,s:d,s:s}", "gravity", s->gravity[0], s->gravity[1], s->gravity[2],
                         "cg_tolerance", s->cg_tolerance, "cg_max_iterations", s->cg_max_iterations, "max_stretch",
                         s->max_stretch, "contact_max_push", s->contact_max_push, "contact_correction",
                         s->contact_correction, "preconditioner", tc_precond_name(s->preconditioner));
}

static PyObject *tearing_dict(const tc_tear_settings *s)
{
    return Py_BuildValue("{s:O,s:i,s:d,s:d}", "enabled", s->enabled ? Py_True : Py_False, "scan_period", s->scan_period,
                         "min_angle_deg", s->min_angle_deg, "min_fragment_area", s->min_fragment_area);
}

static PyObject *native_defaults(PyObject *mod, PyObject *unused)
{
    tc_material m = tc_material_default();
    tc_solver_settings s = tc_solver_default();
    tc_tear_settings t = tc_tear_default();
    return Py_BuildValue("{s:N,s:N,s:N}", "material", material_dict(&m), "solver", solver_dict(&s), "tearing",
                         tearing_dict(&t));
}

/* The product's kernel (fem.c): simd() names the one in use, simd("scalar" | "sse2" | "avx2" | "neon")
 * switches to it (process-wide; for tests and comparisons) and ValueError if the CPU or the build
 * lacks it. */
static PyObject *native_simd(PyObject *mod, PyObject *args)
{
    const char *name = NULL;
    if (!PyArg_ParseTuple(args, "|z", &name)) return NULL;
    if (name) {
        int level = -1;
        for (int l = TC_SIMD_SCALAR; l <= TC_SIMD_LAST; l++)
            if (!strcmp(name, tc_simd_name(l))) level = l;
        if (level < 0 || tc_simd_select(level) < 0) {
            PyErr_Format(PyExc_ValueError, "SIMD kernel '%s' is not available here (scalar, sse2, avx2 or neon, as the CPU allows)",
                         name);
            return NULL;
        }
    }
    return PyUnicode_FromString(tc_simd_name(tc_simd_level()));
}

static PyMethodDef module_methods[] = {
    {"simd", native_simd, METH_VARARGS,
     "simd(name=None) -> str: the matrix-vector kernel in use; with a name ('scalar', 'sse2', 'avx2', 'neon') switches to it "
     "(private: for tests and benchmarks)."},
    {"defaults", native_defaults, METH_NOARGS,
     "defaults() -> {'material': {...}, 'solver': {...}, 'tearing': {...}}: the C core's default settings, by the "
     "C struct field names (gravity as a 3-tuple)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef moddef = {PyModuleDef_HEAD_INIT, "_native", "Tear Cloth native core.", -1, module_methods,
                                    NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__native(void)
{
    PyObject *m = PyModule_Create(&moddef);
    if (!m) return NULL;
    ArrayType = (PyTypeObject *)PyType_FromSpec(&Array_spec);
    PyObject *ct = PyType_FromSpec(&Cloth_spec);
    if (!ArrayType || !ct) return NULL;
    ClothError = PyErr_NewException("tearcloth._native.ClothError", NULL, NULL);
    PyObject *b1 = Py_BuildValue("(OO)", ClothError, PyExc_ValueError);
    PyObject *b2 = Py_BuildValue("(OO)", ClothError, PyExc_RuntimeError);
    InvalidInputError = PyErr_NewException("tearcloth._native.InvalidInputError", b1, NULL);
    SimulationError = PyErr_NewException("tearcloth._native.SimulationError", b2, NULL);
    Py_XDECREF(b1); Py_XDECREF(b2);
    if (!ClothError || !InvalidInputError || !SimulationError) return NULL;
    Py_INCREF((PyObject *)ArrayType);
    PyModule_AddObject(m, "Array", (PyObject *)ArrayType);
    PyModule_AddObject(m, "Cloth", ct);
    Py_INCREF(ClothError); PyModule_AddObject(m, "ClothError", ClothError);
    Py_INCREF(InvalidInputError); PyModule_AddObject(m, "InvalidInputError", InvalidInputError);
    Py_INCREF(SimulationError); PyModule_AddObject(m, "SimulationError", SimulationError);
    static const char *names[] = {"POSITIONS", "VELOCITIES", "REST", "MASSES", "FORCES", "GROUPS", "TRIANGLES",
                                  "CORNER_UV", "STRESS", "PRINCIPAL", "PRINCIPAL_DIR", "TEAR_STRENGTH", "GRAIN_ANGLES",
                                  "WARP", "PLASTIC_STRAIN"};
    for (int i = 0; i < TC_ARRAY_COUNT; i++) PyModule_AddIntConstant(m, names[i], i);
    return m;
}
