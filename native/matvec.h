/* The solver's matrix-vector product as its kernels see it: the arrays of the rows (core.h's
 * layout, fetched once per product by fem.c's dispatch) and the kernels that live in files of
 * their own (one per instruction set whose intrinsics need their own header and target). */
#ifndef TC_MATVEC_H
#define TC_MATVEC_H

#include <stddef.h>
#include <stdint.h>

typedef struct rows_view {
    const double *D, *RB, *FV;
    const int32_t *rp, *rc, *fp, *fc;
    int32_t nv;
} rows_view;

#if defined(__aarch64__)
/* fem_neon.c: two-lane NEON fused multiply-adds (the arm64 baseline, so always available there). */
#define TC_HAVE_NEON 1
double tc_matvec_neon(const rows_view *m, const double *restrict p, double *restrict y);
#endif

#endif
