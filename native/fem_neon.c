/* The solver's matrix-vector product on arm64 (NEON, part of every arm64 CPU): the same rows and the
 * same fused p.Ap as fem.c's kernels, rows 0 and 1 of a vertex in one two-lane register and row 2 in
 * scalar fused multiply-adds. A portable C loop is not vectorised by clang or GCC here (the gather
 * through rc/fc defeats them: 0 vector FMAs in the build), so the lanes are written out. Blocks go
 * two at a time into two accumulators, which halves the chain of dependent FMAs per row (as the
 * AVX2 kernel does). It differs from the scalar kernel only in rounding (FMA, the order of sums);
 * tests/test_solver_simd.py and native/tests/test_core.c hold it to 1e-12 relative. */
#include "matvec.h"

#ifdef TC_HAVE_NEON
#include <arm_neon.h>

double tc_matvec_neon(const rows_view *m, const double *restrict p, double *restrict y)
{
    const double *restrict D = m->D, *restrict RB = m->RB, *restrict FV = m->FV;
    const int32_t *restrict rp = m->rp, *restrict rc = m->rc, *restrict fp = m->fp, *restrict fc = m->fc;
    double dot = 0.0;
    for (int32_t i = 0; i < m->nv; i++) {
        /* the diagonal block: three columns of four (row 3 is padding) */
        const double *d = D + 12 * (size_t)i, *x = p + 3 * (size_t)i;
        float64x2_t lo = vmulq_n_f64(vld1q_f64(d), x[0]);
        lo = vfmaq_n_f64(lo, vld1q_f64(d + 4), x[1]);
        lo = vfmaq_n_f64(lo, vld1q_f64(d + 8), x[2]);
        double hi = d[2] * x[0] + d[6] * x[1] + d[10] * x[2];
        float64x2_t lo2 = vdupq_n_f64(0.0);
        double hi2 = 0.0;
        /* the edge blocks: three columns of three */
        int32_t s = rp[i];
        const int32_t e = rp[i + 1];
        for (; s + 1 < e; s += 2) {
            const double *b = RB + 9 * (size_t)s, *xj = p + 3 * (size_t)rc[s], *xk = p + 3 * (size_t)rc[s + 1];
            const float64x2_t aj = vld1q_f64(xj), ak = vld1q_f64(xk);
            lo = vfmaq_laneq_f64(lo, vld1q_f64(b), aj, 0);
            lo2 = vfmaq_laneq_f64(lo2, vld1q_f64(b + 9), ak, 0);
            lo = vfmaq_laneq_f64(lo, vld1q_f64(b + 3), aj, 1);
            lo2 = vfmaq_laneq_f64(lo2, vld1q_f64(b + 12), ak, 1);
            lo = vfmaq_n_f64(lo, vld1q_f64(b + 6), xj[2]);
            lo2 = vfmaq_n_f64(lo2, vld1q_f64(b + 15), xk[2]);
            hi += b[2] * xj[0] + b[5] * xj[1] + b[8] * xj[2];
            hi2 += b[11] * xk[0] + b[14] * xk[1] + b[17] * xk[2];
        }
        if (s < e) {
            const double *b = RB + 9 * (size_t)s, *xj = p + 3 * (size_t)rc[s];
            const float64x2_t aj = vld1q_f64(xj);
            lo = vfmaq_laneq_f64(lo, vld1q_f64(b), aj, 0);
            lo = vfmaq_laneq_f64(lo, vld1q_f64(b + 3), aj, 1);
            lo = vfmaq_n_f64(lo, vld1q_f64(b + 6), xj[2]);
            hi += b[2] * xj[0] + b[5] * xj[1] + b[8] * xj[2];
        }
        /* the flaps (bending couplings): a scalar times the identity */
        for (s = fp[i]; s < fp[i + 1]; s++) {
            const double f = FV[s], *xj = p + 3 * (size_t)fc[s];
            lo2 = vfmaq_n_f64(lo2, vld1q_f64(xj), f);
            hi2 += f * xj[2];
        }
        lo = vaddq_f64(lo, lo2);
        hi += hi2;
        double *o = y + 3 * (size_t)i;
        vst1q_f64(o, lo);
        o[2] = hi;
        dot += x[0] * o[0] + x[1] * o[1] + x[2] * hi;
    }
    return dot;
}
#else
/* other CPUs: nothing here (ISO C wants a declaration in every file) */
typedef int tc_no_neon;
#endif
