/* pyarg.c - argument tables for the Python modules: positional/keyword matching, buffer checks
 * (contiguity, writability, dtype, shape), overlap of outputs, and messages formatted by the C
 * library. See pyarg.h for the table format. */
#include "pyarg.h"

#include <stdarg.h>
#include <stdlib.h>
#include <stdio.h>
#include <string.h>

static const char *TYPE_NAME[] = {"float64", "float32", "int64", "int32", "bool", "int8"};

PyObject *pyarg_error(PyObject *type, const char *fmt, ...)
{
    char msg[512];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    PyErr_SetString(type, msg);
    return NULL;
}

void pyarg_value_release(pyarg_value *v)
{
    if (v->held) {
        PyBuffer_Release(&v->view);
        v->held = 0;
    }
}

void pyarg_release(pyarg_set *s)
{
    for (int i = 0; i < s->n; i++) pyarg_value_release(&s->v[i]);
}

/* A buffer format (struct module syntax, one item) against an element type. */
static int format_ok(const char *f, int type, Py_ssize_t itemsize)
{
    if (!f) f = "B";
    if (*f == '<' || *f == '=' || *f == '@' || *f == '|') f++;
    if (f[0] == 0 || f[1] != 0) return 0;
    char ch = f[0];
    switch (type) {
    case PA_F64: return ch == 'd' && itemsize == 8;
    case PA_F32: return ch == 'f' && itemsize == 4;
    case PA_I64: return (ch == 'q' || ch == 'l' || ch == 'n') && itemsize == 8;
    case PA_I32: return (ch == 'i' || ch == 'l') && itemsize == 4;
    case PA_BOOL: return (ch == '?' || ch == 'B') && itemsize == 1;
    case PA_I8: return ch == 'b' && itemsize == 1;
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

/* "(3, any)" from wanted sizes, -1 printed as "any" */
static void want_text(char *s, size_t size, int ndim, const Py_ssize_t *want)
{
    size_t k = (size_t)snprintf(s, size, "(");
    for (int i = 0; i < ndim && k < size; i++) {
        const char *sep = i + 1 < ndim ? ", " : (ndim == 1 ? "," : "");
        k += want[i] >= 0 ? (size_t)snprintf(s + k, size - k, "%zd%s", want[i], sep)
                          : (size_t)snprintf(s + k, size - k, "any%s", sep);
    }
    if (k < size) snprintf(s + k, size - k, ")");
}

static int shape_error(const pyarg_spec *sp, PyObject *type, const Py_buffer *v, const Py_ssize_t *want)
{
    char got[96], exp[96];
    if (v->shape)
        shape_text(got, sizeof got, v->ndim, v->shape);
    else
        snprintf(got, sizeof got, "no shape");
    want_text(exp, sizeof exp, sp->ndim, want);
    pyarg_error(type, "%s must have shape %s, got %s", sp->name, exp, got);
    return -1;
}

/* A flat table (ndim == 0 rows): one dimension, or rows of dims[0] values. */
static int flat_rows(const pyarg_spec *sp, PyObject *type, pyarg_value *out)
{
    const Py_buffer *v = &out->view;
    Py_ssize_t n = v->len / v->itemsize, cols = sp->dims[0];
    if (cols > 0) {
        int nd = v->ndim;
        Py_ssize_t last = -1;
        if (nd >= 2 && v->shape) {
            last = 1;
            for (int i = 1; i < nd; i++) last *= v->shape[i];
        }
        if (last != cols || n % cols) {
            pyarg_error(type, "%s must have shape (N, %zd) (got %zd values in %d dimensions)", sp->name, cols, n, nd);
            return -1;
        }
        out->rows = n / cols;
    } else {
        if (v->ndim > 1) {
            pyarg_error(type, "%s must be one-dimensional (got %d dimensions)", sp->name, v->ndim);
            return -1;
        }
        out->rows = n;
    }
    /* the core counts vertices and triangles in int32, and multiplies rows by up to 9 values */
    if (out->rows > 0x7fffffff / 16) {
        pyarg_error(type, "%s is too large (%zd rows)", sp->name, out->rows);
        return -1;
    }
    return 0;
}

int pyarg_buffer(PyObject *obj, const pyarg_spec *sp, PyObject *shape_type, pyarg_value *out)
{
    int wr = (sp->flags & PA_OUT) != 0;
    memset(out, 0, sizeof *out);
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (wr ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, &out->view, flags) < 0) {
        PyObject *t, *v, *tb;
        PyErr_Fetch(&t, &v, &tb);
        PyErr_Format(PyExc_TypeError, "%s must be a C-contiguous%s %s numpy array (%S)", sp->name,
                     wr ? ", writable" : "", TYPE_NAME[sp->type], v ? v : Py_None);
        Py_XDECREF(t);
        Py_XDECREF(v);
        Py_XDECREF(tb);
        return -1;
    }
    out->held = 1;
    if (!format_ok(out->view.format, sp->type, out->view.itemsize)) {
        pyarg_error(PyExc_TypeError, "%s must have dtype %s (got buffer format '%s', item size %zd)", sp->name,
                    TYPE_NAME[sp->type], out->view.format ? out->view.format : "B", out->view.itemsize);
        pyarg_value_release(out);
        return -1;
    }
    if (sp->ndim == 0) {
        if (flat_rows(sp, shape_type, out)) {
            pyarg_value_release(out);
            return -1;
        }
        return 0;
    }
    int bad = out->view.ndim != sp->ndim || !out->view.shape;
    for (int i = 0; !bad && i < sp->ndim; i++) bad = sp->dims[i] >= 0 && out->view.shape[i] != sp->dims[i];
    if (bad) {
        shape_error(sp, shape_type, &out->view, sp->dims);
        pyarg_value_release(out);
        return -1;
    }
    out->rows = out->view.shape[0];
    return 0;
}

static int scalar(PyObject *obj, const pyarg_spec *sp, pyarg_value *out)
{
    if (sp->type == PA_FLAG) {
        int t = PyObject_IsTrue(obj);
        if (t < 0) return -1;
        out->i = t;
        return 0;
    }
    if (sp->type == PA_DOUBLE) {
        out->d = PyFloat_AsDouble(obj);
        return out->d == -1.0 && PyErr_Occurred() ? -1 : 0;
    }
    PyObject *ix = PyNumber_Index(obj);  /* ints and numpy integers; a float is a TypeError */
    if (!ix) return -1;
    if (sp->type == PA_SSIZE) {
        out->n = PyLong_AsSsize_t(ix);
        Py_DECREF(ix);
        return out->n == -1 && PyErr_Occurred() ? -1 : 0;
    }
    /* long long, not long: long is 32-bit on Windows, where the range check would vanish and
     * PyLong_AsLong's own message would name no argument */
    long long l = PyLong_AsLongLong(ix);
    Py_DECREF(ix);
    if (l == -1 && PyErr_Occurred()) return -1;
    if (l < -2147483647LL - 1 || l > 2147483647LL) {
        PyErr_Format(PyExc_OverflowError, "%s = %lld does not fit a C int", sp->name, l);
        return -1;
    }
    out->i = (int)l;
    return 0;
}

int pyarg_parse(pyarg_set *s, const char *fname, const pyarg_spec *spec, int n, PyObject *shape_type,
                PyObject *args, PyObject *kw)
{
    s->spec = spec;
    s->n = 0;
    s->shape_error = shape_type;
    if (n > PYARG_MAX) {
        PyErr_Format(PyExc_SystemError, "%s(): %d arguments, more than the %d a table may hold", fname, n, PYARG_MAX);
        return -1;
    }
    PyObject *obj[PYARG_MAX] = {0};
    Py_ssize_t npos = PyTuple_Size(args);
    if (npos < 0) return -1;
    if (npos > n) {
        PyErr_Format(PyExc_TypeError, "%s() takes at most %d arguments (%zd given)", fname, n, npos);
        return -1;
    }
    for (Py_ssize_t i = 0; i < npos; i++) obj[i] = PyTuple_GetItem(args, i);
    if (kw) {
        Py_ssize_t pos = 0;
        PyObject *key, *val;
        int hint = 0; /* keywords usually come in table order: the search starts after the last match */
        while (PyDict_Next(kw, &pos, &key, &val)) {
            const char *k = PyUnicode_AsUTF8AndSize(key, NULL);
            if (!k) return -1;
            int j = hint, tried = 0;
            while (tried < n && strcmp(spec[j].name, k) != 0) {
                j = j + 1 < n ? j + 1 : 0;
                tried++;
            }
            if (tried == n) j = n;
            else hint = j + 1 < n ? j + 1 : 0;
            if (j == n) {
                PyErr_Format(PyExc_TypeError, "%s() got an unexpected keyword argument '%s'", fname, k);
                return -1;
            }
            if (obj[j]) {
                PyErr_Format(PyExc_TypeError, "%s() got argument '%s' by position and by keyword", fname, k);
                return -1;
            }
            obj[j] = val;
        }
    }
    for (int i = 0; i < n; i++) {
        const pyarg_spec *sp = &spec[i];
        pyarg_value *v = &s->v[i];
        memset(v, 0, sizeof *v);
        s->n = i + 1;
        if (!obj[i] || (obj[i] == Py_None && (sp->flags & PA_OPTIONAL) && sp->type <= PA_I8)) {
            if (sp->flags & PA_OPTIONAL) continue;  /* absent: no data, no rows, a zero scalar */
            PyErr_Format(PyExc_TypeError, "%s() missing required argument '%s' (pos %d)", fname, sp->name, i + 1);
            goto fail;
        }
        if (sp->type <= PA_I8 ? pyarg_buffer(obj[i], sp, shape_type, v) : scalar(obj[i], sp, v)) goto fail;
    }
    return 0;
fail:
    pyarg_release(s);
    return -1;
}

int pyarg_rows(pyarg_set *s, int i, Py_ssize_t rows)
{
    const pyarg_value *v = &s->v[i];
    if (!v->held || v->rows == rows) return 0;
    const pyarg_spec *sp = &s->spec[i];
    Py_ssize_t want[3] = {rows, sp->dims[1], sp->dims[2]};
    return shape_error(sp, s->shape_error, &v->view, want);
}

typedef struct {
    const char *lo, *hi;
    int i;
} span;

static int by_start(const void *a, const void *b)
{
    const span *x = a, *y = b;
    return x->lo < y->lo ? -1 : x->lo > y->lo;
}

int pyarg_no_overlap(const pyarg_set *s)
{
    /* the arguments' memory spans in address order: an output overlapping another argument overlaps
     * one of the spans that start before it ends (tables of ~50 arrays: a sort, not all pairs) */
    span sp[PYARG_MAX];
    int m = 0;
    for (int i = 0; i < s->n; i++) {
        const pyarg_value *a = &s->v[i];
        if (!a->held || a->view.len == 0) continue;
        sp[m++] = (span){a->view.buf, (const char *)a->view.buf + a->view.len, i};
    }
    qsort(sp, (size_t)m, sizeof *sp, by_start);
    for (int j = 0; j < m; j++)
        for (int k = j + 1; k < m && sp[k].lo < sp[j].hi; k++) {
            int a = sp[j].i, b = sp[k].i;
            if (!(s->spec[a].flags & PA_OUT) && !(s->spec[b].flags & PA_OUT)) continue; /* inputs may share */
            int out = (s->spec[a].flags & PA_OUT) ? a : b, other = out == a ? b : a;
            pyarg_error(PyExc_ValueError, "output %s shares memory with %s: pass separate arrays", s->spec[out].name,
                        s->spec[other].name);
            return -1;
        }
    return 0;
}
