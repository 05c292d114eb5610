/* vecmath.h - the one set of 3-vector helpers of the native code, used by the core (native/) and
 * by the collision kernels (native/collide/). Header-only: every helper is a static inline so
 * hot loops keep it inlined.
 *
 * Argument order: inputs first, the result last (sub3(a, b, out) is out = a - b), like the math
 * it writes out. The expression order of each helper is fixed on purpose: the collision kernels'
 * numpy references (collision/incremental.py: cross, dot) evaluate the same products in the same
 * order, and the build has no -ffast-math (and -std=c17 keeps floating-point contraction off), so C
 * and numpy agree to the last bit. Do not "simplify" these expressions.
 */
#ifndef TEARCLOTH_VECMATH_H
#define TEARCLOTH_VECMATH_H

static inline double dot3(const double *a, const double *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

static inline void sub3(const double *a, const double *b, double *out)
{
    out[0] = a[0] - b[0];
    out[1] = a[1] - b[1];
    out[2] = a[2] - b[2];
}

/* out = a x b; out must not alias a or b. */
static inline void cross3(const double *a, const double *b, double *out)
{
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

#endif
