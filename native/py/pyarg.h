/* pyarg.h - argument parsing shared by the two Python modules, tearcloth._native (native/pymodule.c)
 * and tearcloth._collide (native/collide/pymodule.c); compiled into both (setup.py).
 *
 * An argument is described by one row of a table (pyarg_spec): its name (the keyword, and the name
 * messages use), its type (an array dtype or a scalar), its shape, and whether it is an output
 * (must be writable) or optional (None allowed). pyarg_parse() reads a call's positional and
 * keyword arguments against the whole table, so a kernel with two dozen arrays is called by name
 * from Python, and the table is the documentation of its order. pyarg_buffer() checks one array
 * against one row (the _native module parses its few arguments with the CPython helpers).
 *
 * Arrays come in through the buffer protocol (numpy arrays, zero copy; no numpy C API). Wrong
 * types raise TypeError, wrong shapes the set's shape error (ValueError for the kernels,
 * InvalidInputError for the cloth). Messages with floating-point values are formatted by
 * pyarg_error() with the C library, since PyErr_Format has no %g (SystemError on Python 3.13).
 */
#ifndef TEARCLOTH_PYARG_H
#define TEARCLOTH_PYARG_H

#define PY_SSIZE_T_CLEAN
#include <Python.h>

/* element types of array arguments, then scalar types */
enum {
    PA_F64, PA_F32, PA_I64, PA_I32, PA_BOOL, PA_I8,  /* arrays */
    PA_DOUBLE,                                      /* a Python float (or int) -> double */
    PA_INT,                                         /* a Python int -> int */
    PA_SSIZE,                                       /* a Python int -> Py_ssize_t */
    PA_FLAG,                                        /* any object, by truth value -> int 0/1 */
};

enum {
    PA_OUT = 1,       /* an array the call writes: must be writable and overlap no other argument */
    PA_OPTIONAL = 2,  /* None allowed (an array then has a NULL data pointer and no rows) */
};

/* ndim >= 1: exactly ndim dimensions, dims[i] each (-1: any; the rows are usually -1 and checked
 * against other arguments with pyarg_rows).
 * ndim == 0: a flat table of rows: dims[0] = 0 for one dimension, dims[0] = k > 0 for rows of k
 * values (the trailing dimensions multiply to k, so (m, 3, 2) passes for k = 6). */
typedef struct pyarg_spec {
    const char *name;
    int type;
    unsigned flags;
    int ndim;
    Py_ssize_t dims[3];
} pyarg_spec;

typedef struct pyarg_value {
    Py_buffer view;
    int held;            /* view holds a buffer to release */
    Py_ssize_t rows;     /* arrays: first dimension (0 when absent) */
    double d;            /* PA_DOUBLE */
    int i;               /* PA_INT, PA_FLAG */
    Py_ssize_t n;        /* PA_SSIZE */
} pyarg_value;

#define PYARG_MAX 64

typedef struct pyarg_set {
    const pyarg_spec *spec;
    int n;
    PyObject *shape_error;  /* exception type of wrong shapes */
    pyarg_value v[PYARG_MAX];
} pyarg_set;

/* Parses args/kw of `fname` against the n rows of spec (positional in table order, or by keyword).
 * Every row without PA_OPTIONAL is required. On failure sets an exception, releases what it took
 * and returns -1. */
int pyarg_parse(pyarg_set *s, const char *fname, const pyarg_spec *spec, int n, PyObject *shape_error,
                PyObject *args, PyObject *kw);
void pyarg_release(pyarg_set *s);

/* Data pointer (NULL for an absent optional array) and rows of argument i. */
static inline void *pyarg_data(const pyarg_set *s, int i) { return s->v[i].held ? s->v[i].view.buf : NULL; }
static inline Py_ssize_t pyarg_nrows(const pyarg_set *s, int i) { return s->v[i].rows; }

/* Argument i must have `rows` rows (an absent optional one passes). */
int pyarg_rows(pyarg_set *s, int i, Py_ssize_t rows);
/* No output may share memory with any other argument: a kernel reads its inputs while writing. */
int pyarg_no_overlap(const pyarg_set *s);

/* One array against one row of a table (obj must not be None). */
int pyarg_buffer(PyObject *obj, const pyarg_spec *spec, PyObject *shape_error, pyarg_value *out);
void pyarg_value_release(pyarg_value *v);

/* Sets exception `type` with a message formatted by vsnprintf (so %g and %f work); returns NULL. */
PyObject *pyarg_error(PyObject *type, const char *fmt, ...);

#endif
