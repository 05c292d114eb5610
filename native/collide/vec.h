/* vec.h - small 3-vector helpers shared by the collide kernels (private, header-only). */
#ifndef TCC_VEC_H
#define TCC_VEC_H

#include <math.h>

static inline void v_sub(double r[3], const double a[3], const double b[3])
{
    r[0] = a[0] - b[0];
    r[1] = a[1] - b[1];
    r[2] = a[2] - b[2];
}

/* The same expression order as incremental.cross, so C and numpy agree to the last bit. */
static inline void v_cross(double r[3], const double a[3], const double b[3])
{
    r[0] = a[1] * b[2] - a[2] * b[1];
    r[1] = a[2] * b[0] - a[0] * b[2];
    r[2] = a[0] * b[1] - a[1] * b[0];
}

static inline double v_dot(const double a[3], const double b[3]) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

#endif
