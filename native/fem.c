/* fem.c - co-rotational linear FEM on constant-strain triangles (plane stress) and the quadratic
 * bending energy: per-element rotation, stress and forces, assembly of the implicit Euler system
 * and its matrix-vector product, and the elastic and bending energies.
 *
 * Co-rotation: F = R S (polar decomposition of the 3x2 deformation gradient), strain
 * eps = sym(R^T F) - I, so rigid motions give exactly zero stress. The stiffness uses R frozen over
 * a step (the usual co-rotational linearisation): K_ab = R K0_ab R^T with
 * K0_ab = A h [mu ((g_a.g_b) I + g_b g_a^T) + lambda g_a g_b^T].
 */
#include "core.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static inline void lame(const tc_material *m, double *lambda, double *mu)
{
    /* plane-stress Lame constants */
    *lambda = m->young * m->poisson / (1.0 - m->poisson * m->poisson);
    *mu = m->young / (2.0 * (1.0 + m->poisson));
}

/* The general element (orthotropic or plastic, see ortho.c): the co-rotated strain eps (xx, yy,
 * xy tensor) of a triangle whose warp is (cs, sn) in its rest frame, less the plastic strain pl
 * (warp/weft axes; NULL: none), to the stress (xx, yy, xy) in the rest frame, through the warp/weft
 * axes. Returns the elastic energy density 0.5 sigma : eps_e (J/m^3). */
static inline double ortho_stress(const double Q[4], double cs, double sn, const double *pl, const double eps[3],
                                  double *sxx, double *syy, double *sxy)
{
    const double cc = cs * cs, ss = sn * sn, cn = cs * sn;
    double ew = cc * eps[0] + ss * eps[1] + 2.0 * cn * eps[2];
    double ef = ss * eps[0] + cc * eps[1] - 2.0 * cn * eps[2];
    double ewf = cn * (eps[1] - eps[0]) + (cc - ss) * eps[2];
    if (pl) { ew -= pl[0]; ef -= pl[1]; ewf -= pl[2]; }
    const double sw = Q[0] * ew + Q[2] * ef, sf = Q[2] * ew + Q[1] * ef, tau = 2.0 * Q[3] * ewf;
    *sxx = cc * sw + ss * sf - 2.0 * cn * tau;
    *syy = ss * sw + cc * sf + 2.0 * cn * tau;
    *sxy = cn * (sw - sf) + (cc - ss) * tau;
    return 0.5 * (sw * ew + sf * ef + 2.0 * tau * ewf);
}

/* The orthotropic moduli in the rest frame of a triangle whose warp is (cs, sn) there: the
 * transformed reduced stiffness (Jones 1999, eq. 2.85) on (eps_xx, eps_yy, gamma_xy), as
 * C11, C22, C12, C16, C26, C66. */
static inline void ortho_rest_moduli(const double Q[4], double cs, double sn, double C[6])
{
    const double c2 = cs * cs, s2 = sn * sn, c4 = c2 * c2, s4 = s2 * s2, cs2 = c2 * s2;
    const double a = Q[0] - Q[2] - 2.0 * Q[3], b = Q[2] - Q[1] + 2.0 * Q[3];
    C[0] = Q[0] * c4 + 2.0 * (Q[2] + 2.0 * Q[3]) * cs2 + Q[1] * s4;
    C[1] = Q[0] * s4 + 2.0 * (Q[2] + 2.0 * Q[3]) * cs2 + Q[1] * c4;
    C[2] = (Q[0] + Q[1] - 4.0 * Q[3]) * cs2 + Q[2] * (s4 + c4);
    C[3] = a * sn * c2 * cs + b * s2 * sn * cs;
    C[4] = a * s2 * sn * cs + b * sn * c2 * cs;
    C[5] = (Q[0] + Q[1] - 2.0 * Q[2] - 2.0 * Q[3]) * cs2 + Q[3] * (s4 + c4);
}

/* Rotation of one element from its deformation gradient columns F0, F1; returns the 2x2 strain. */
static void corotate(const double *F0, const double *F1, double *R, double eps[3])
{
    double a = dot3(F0, F0), b = dot3(F0, F1), d = dot3(F1, F1);
    double det = a * d - b * b;
    if (det > TC_COLLAPSE_DET * (a + d) * (a + d)) {
        double s = sqrt(det), t = sqrt(a + d + 2.0 * s);
        double S00 = (a + s) / t, S01 = b / t, S11 = (d + s) / t;
        double i00 = S11 / s, i01 = -S01 / s, i11 = S00 / s;  /* S^-1, det S = s */
        for (int k = 0; k < 3; k++) {
            R[k] = F0[k] * i00 + F1[k] * i01;
            R[3 + k] = F0[k] * i01 + F1[k] * i11;
        }
    } else {
        /* collapsed element: keep a frame by Gram-Schmidt on whatever direction survives */
        double n0 = sqrt(a);
        if (n0 > TC_TINY) for (int k = 0; k < 3; k++) R[k] = F0[k] / n0;
        double p = dot3(R + 3, R);
        double r1[3] = {R[3] - p * R[0], R[4] - p * R[1], R[5] - p * R[2]};
        double n1 = sqrt(dot3(r1, r1));
        if (n1 < TC_COLLAPSE_COLUMN) {  /* pick any unit vector orthogonal to R0 */
            double ax[3] = {fabs(R[0]) < TC_COLLAPSE_AXIS_LIMIT ? 1.0 : 0.0, fabs(R[0]) < TC_COLLAPSE_AXIS_LIMIT ? 0.0 : 1.0, 0.0};
            double q = dot3(ax, R);
            r1[0] = ax[0] - q * R[0]; r1[1] = ax[1] - q * R[1]; r1[2] = ax[2] - q * R[2];
            n1 = sqrt(dot3(r1, r1));
        }
        for (int k = 0; k < 3; k++) R[3 + k] = r1[k] / n1;
    }
    double m00 = dot3(R, F0), m01 = dot3(R, F1), m10 = dot3(R + 3, F0), m11 = dot3(R + 3, F1);
    eps[0] = m00 - 1.0;
    eps[1] = m11 - 1.0;
    eps[2] = 0.5 * (m01 + m10);
}

/* Rotations, stresses and elastic forces of every element at positions x. Returns the largest
 * principal stretch seen (for the explosion test), or NAN if any value is not finite. */
/* Both element loops are specialised by `general` (a constant at each call), so the isotropic one
 * compiles to what it was before the general element existed, to the last rounding. */
#if defined(__GNUC__) || defined(__clang__)
#define TC_INLINE static inline __attribute__((always_inline))
#else
#define TC_INLINE static inline
#endif

TC_INLINE double element_pass(tc_cloth *c, const double *x, const bool general)
{
    double worst2 = 0.0;
    double lambda, mu, Q[4];
    lame(&c->mat, &lambda, &mu);
    tc_ortho_moduli(&c->mat, Q);
    const bool plastic = c->mat.plastic;
    const double *AX = tc_vec_ptr(&c->taxis), *PL = tc_vec_ptr(&c->tplast);
    const double h = c->mat.thickness;
    const int32_t *T = tc_vec_ptr(&c->tri);
    const double *G = tc_vec_ptr(&c->grad), *A = tc_vec_ptr(&c->area);
    double *Rall = tc_vec_ptr(&c->rot), *sig = tc_vec_ptr(&c->sig), *S3 = tc_vec_ptr(&c->stress);
    double *pr = tc_vec_ptr(&c->principal), *pd = tc_vec_ptr(&c->pdir);
    double *f = tc_vec_ptr(&c->fel);
    double carried2 = 0.0;  /* the solver's scale of elastic forces (solver.c) */
    memset(f, 0, 3 * (size_t)c->nv * sizeof *f);
    for (int32_t t = 0; t < c->nt; t++) {
        const int32_t i0 = T[3 * t], i1 = T[3 * t + 1], i2 = T[3 * t + 2];
        const double *x0 = x + 3 * i0, *x1 = x + 3 * i1, *x2 = x + 3 * i2;
        const double *g = G + 4 * t;
        double e1[3], e2[3], F0[3], F1[3];
        sub3(x1, x0, e1); sub3(x2, x0, e2);
        for (int k = 0; k < 3; k++) {
            F0[k] = e1[k] * g[0] + e2[k] * g[2];
            F1[k] = e1[k] * g[1] + e2[k] * g[3];
        }
        double *R = Rall + 6 * t, eps[3];
        {
            /* largest eigenvalue of F^T F = squared principal stretch; NaN propagates through */
            double a = dot3(F0, F0), b = dot3(F0, F1), d = dot3(F1, F1);
            double s2 = 0.5 * (a + d) + sqrt(0.25 * (a - d) * (a - d) + b * b);
            if (!(s2 <= worst2)) worst2 = s2;  /* also takes NaN */
        }
        corotate(F0, F1, R, eps);
        double sxx, syy, sxy;
        if (!general) {
            double tr = eps[0] + eps[1];
            sxx = lambda * tr + 2.0 * mu * eps[0]; syy = lambda * tr + 2.0 * mu * eps[1]; sxy = 2.0 * mu * eps[2];
        } else {
            ortho_stress(Q, AX[2 * t], AX[2 * t + 1], plastic ? PL + 4 * (size_t)t : NULL, eps, &sxx, &syy, &sxy);
        }
        sig[3 * t] = sxx; sig[3 * t + 1] = syy; sig[3 * t + 2] = sxy;
        double P0[3], P1[3];
        for (int k = 0; k < 3; k++) {
            P0[k] = R[k] * sxx + R[3 + k] * sxy;
            P1[k] = R[k] * sxy + R[3 + k] * syy;
        }
        double w = A[t] * h;
        for (int k = 0; k < 3; k++) {
            double fa = -w * (P0[k] * g[0] + P1[k] * g[1]);
            double fb = -w * (P0[k] * g[2] + P1[k] * g[3]);
            f[3 * i1 + k] += fa;
            f[3 * i2 + k] += fb;
            f[3 * i0 + k] -= fa + fb;
            carried2 += fa * fa + fb * fb + (fa + fb) * (fa + fb);
        }
        double *S = S3 + 9 * t;
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++)
                S[3 * i + j] = R[i] * (sxx * R[j] + sxy * R[3 + j]) + R[3 + i] * (sxy * R[j] + syy * R[3 + j]);
        double mean = 0.5 * (sxx + syy), dd = 0.5 * (sxx - syy), rad = sqrt(dd * dd + sxy * sxy);
        pr[2 * t] = mean + rad; pr[2 * t + 1] = mean - rad;
        /* eigenvector of the largest eigenvalue without trigonometry: (l1 - syy, sxy) or
           (sxy, l1 - sxx), whichever is better conditioned */
        double l1 = mean + rad, ex = l1 - syy, ey = sxy, fx = sxy, fy = l1 - sxx;
        if (ex * ex + ey * ey < fx * fx + fy * fy) { ex = fx; ey = fy; }
        double el = sqrt(ex * ex + ey * ey);
        if (el > 0) { ex /= el; ey /= el; } else { ex = 1.0; ey = 0.0; }
        for (int k = 0; k < 3; k++) pd[3 * t + k] = R[k] * ex + R[3 + k] * ey;
    }
    c->carried2 = isfinite(carried2) ? carried2 : 0.0;
    return isfinite(worst2) ? sqrt(worst2) : NAN;
}

TC_HOT double tc_element_pass(tc_cloth *c, const double *x)
{
    return tc_material_general(&c->mat) ? element_pass(c, x, true) : element_pass(c, x, false);
}

TC_HOT void tc_bending_force(const tc_cloth *c, const double *x, double *f)
{
    const double k = c->mat.bending;
    if (k == 0.0) return;
    const double *vb = tc_vec_ptr(&c->vbend), *pb = tc_vec_ptr(&c->pbend);
    const int32_t *pi = tc_vec_ptr(&c->pi), *pj = tc_vec_ptr(&c->pj);
    for (int32_t v = 0; v < c->nv; v++) {
        double s = k * vb[v];
        f[3 * v] -= s * x[3 * v]; f[3 * v + 1] -= s * x[3 * v + 1]; f[3 * v + 2] -= s * x[3 * v + 2];
    }
    size_t np = c->pi.len;
    for (size_t p = 0; p < np; p++) {
        if (pi[p] < 0 || pb[p] == 0.0) continue;
        double s = k * pb[p];
        const double *xi = x + 3 * pi[p], *xj = x + 3 * pj[p];
        double *fi = f + 3 * pi[p], *fj = f + 3 * pj[p];
        fi[0] -= s * xj[0]; fi[1] -= s * xj[1]; fi[2] -= s * xj[2];
        fj[0] -= s * xi[0]; fj[1] -= s * xi[1]; fj[2] -= s * xi[2];
    }
}

/* System matrix A = (1 + dt alpha) M + (dt^2 + dt beta) (K + B), into the rows of core.h. */
TC_INLINE void assemble(tc_cloth *c, double dt, const bool general)
{
    double lambda, mu, Q[4];
    lame(&c->mat, &lambda, &mu);
    tc_ortho_moduli(&c->mat, Q);
    const double *AX = tc_vec_ptr(&c->taxis);
    const double h = c->mat.thickness, kb = c->mat.bending;
    const double ks = dt * dt + dt * c->mat.damping_stiffness, ms = 1.0 + dt * c->mat.damping_mass;
    c->mass_scale = ms;
    const double *m = tc_vec_ptr(&c->mass), *vb = tc_vec_ptr(&c->vbend), *pb = tc_vec_ptr(&c->pbend);
    double *D = tc_vec_ptr(&c->diag), *RB = tc_vec_ptr(&c->rblk), *FV = tc_vec_ptr(&c->fval);
    const int32_t *pi = tc_vec_ptr(&c->pi), *slot = tc_vec_ptr(&c->pslot);
    memset(D, 0, 12 * (size_t)c->nv * sizeof *D);
    memset(RB, 0, c->rblk.len * sizeof *RB);
    for (int32_t v = 0; v < c->nv; v++) {
        double *d = D + 12 * v, s = m[v] * ms + ks * kb * vb[v];
        d[0] = s; d[5] = s; d[10] = s;
    }
    size_t np = c->pi.len;
    for (size_t p = 0; p < np; p++) {
        if (pi[p] < 0) continue;
        const double s = ks * kb * pb[p];
        if (tc_pair_is_edge(c, p)) {
            double *a = RB + 9 * (size_t)slot[2 * p], *b = RB + 9 * (size_t)slot[2 * p + 1];
            a[0] = s; a[4] = s; a[8] = s;
            b[0] = s; b[4] = s; b[8] = s;
        } else {
            FV[slot[2 * p]] = s; FV[slot[2 * p + 1]] = s;
        }
    }
    const int32_t *T = tc_vec_ptr(&c->tri), *TP = tc_vec_ptr(&c->tpair);
    const double *G = tc_vec_ptr(&c->grad), *A = tc_vec_ptr(&c->area), *Rall = tc_vec_ptr(&c->rot);
    const double *S2 = tc_vec_ptr(&c->sig);
    for (int32_t t = 0; t < c->nt; t++) {
        const double *g = G + 4 * t, *R = Rall + 6 * t;
        const double gg[3][2] = {{-g[0] - g[2], -g[1] - g[3]}, {g[0], g[1]}, {g[2], g[3]}};
        const double w = ks * A[t] * h, wm = w * mu, wl = w * lambda;
        /* R K0_ab R^T = mu (g_a.g_b) P + mu r_b r_a^T + lambda r_a r_b^T with r_a = R g_a and
           P = R R^T (the projector on the element's plane): a third fewer flops than the product */
        double r[3][3], P[9];
        for (int a = 0; a < 3; a++)
            for (int k = 0; k < 3; k++) r[a][k] = R[k] * gg[a][0] + R[3 + k] * gg[a][1];
        /* Geometric (initial-stress) stiffness of the tensile part of the stress: k_ab = A h
           g_a^T sigma+ g_b, times I. The frozen-rotation linearisation has no term for how tension
           resists out-of-plane motion, so a stretched cloth moving sideways was integrated
           explicitly against its tension and blew up; keeping only sigma's positive part keeps
           the system positive definite (compression adds no stiffness: cloth buckles). */
        double sp00 = 0.0, sp01 = 0.0, sp11 = 0.0;
        {
            const double *sg = S2 + 3 * t;
            const double a = sg[0], d = sg[1], b = sg[2];
            const double m = 0.5 * (a + d), q = sqrt(0.25 * (a - d) * (a - d) + b * b);
            const double l1 = m + q, l2 = m - q;
            if (l2 >= 0.0) { sp00 = a; sp01 = b; sp11 = d; }
            else if (l1 > 0.0) {
                /* eigenvector of l1 */
                double ex = l1 - d, ey = b, fx = b, fy = l1 - a;
                if (ex * ex + ey * ey < fx * fx + fy * fy) { ex = fx; ey = fy; }
                const double el = sqrt(ex * ex + ey * ey);
                if (el > 0) { ex /= el; ey /= el; sp00 = l1 * ex * ex; sp01 = l1 * ex * ey; sp11 = l1 * ey * ey; }
            }
        }
        const double wg = ks * A[t] * h;
        for (int i = 0; i < 3; i++)
            for (int l = 0; l < 3; l++) P[3 * i + l] = R[i] * R[l] + R[3 + i] * R[3 + l];
        /* the general element: K0_ab = A h B_a^T C B_b with C the moduli in the rest frame on
           (eps_xx, eps_yy, gamma_xy) and B_b = [[g_b0, 0], [0, g_b1], [g_b1, g_b0]], then R K0 R^T
           (the plastic strain shifts the stress, not the stiffness) */
        double C[6] = {0};
        if (general) ortho_rest_moduli(Q, AX[2 * t], AX[2 * t + 1], C);
        for (int a = 0; a < 3; a++) {
            for (int b = a; b < 3; b++) {
                const double dab = gg[a][0] * gg[b][0] + gg[a][1] * gg[b][1];
                const double kg = wg * (gg[a][0] * (sp00 * gg[b][0] + sp01 * gg[b][1]) +
                                        gg[a][1] * (sp01 * gg[b][0] + sp11 * gg[b][1]));
                double B[9];
                if (!general) {
                    for (int i = 0; i < 3; i++)
                        for (int l = 0; l < 3; l++)
                            B[3 * i + l] = wm * (dab * P[3 * i + l] + r[b][i] * r[a][l]) + wl * r[a][i] * r[b][l];
                } else {
                    const double a0 = gg[a][0], a1 = gg[a][1], b0 = gg[b][0], b1 = gg[b][1];
                    /* C B_b, its two columns (xx, yy, xy rows) */
                    const double u0 = C[0] * b0 + C[3] * b1, u1 = C[2] * b0 + C[4] * b1, u2 = C[3] * b0 + C[5] * b1;
                    const double v0 = C[2] * b1 + C[3] * b0, v1 = C[1] * b1 + C[4] * b0, v2 = C[4] * b1 + C[5] * b0;
                    const double k00 = w * (a0 * u0 + a1 * u2), k01 = w * (a0 * v0 + a1 * v2);
                    const double k10 = w * (a1 * u1 + a0 * u2), k11 = w * (a1 * v1 + a0 * v2);
                    for (int i = 0; i < 3; i++) {
                        const double p0 = k00 * R[i] + k10 * R[3 + i], p1 = k01 * R[i] + k11 * R[3 + i];
                        for (int l = 0; l < 3; l++) B[3 * i + l] = p0 * R[l] + p1 * R[3 + l];
                    }
                }
                B[0] += kg; B[4] += kg; B[8] += kg;
                const int32_t va = T[3 * t + a];
                /* B is A_{va,vb}, row-major; a row slot holds its block column by column (core.h):
                   A_{va,vb} at [3k + r] = B[3r + k], A_{vb,va} = B^T at [3k + r] = B[3k + r]; the
                   diagonal block's columns are padded to 4 */
                if (a == b) {
                    double *d = D + 12 * va;  /* symmetric: either order */
                    for (int r = 0; r < 3; r++)
                        for (int k = 0; k < 3; k++) d[4 * k + r] += B[3 * r + k];
                } else {
                    const int32_t p = TP[3 * t + (3 - a - b)];
                    const int own = va == pi[p] ? 0 : 1;  /* which of the pair's slots is row va's */
                    double *sa = RB + 9 * (size_t)slot[2 * p + own], *sb = RB + 9 * (size_t)slot[2 * p + 1 - own];
                    for (int r = 0; r < 3; r++)
                        for (int k = 0; k < 3; k++) {
                            sa[3 * k + r] += B[3 * r + k];
                            sb[3 * k + r] += B[3 * k + r];
                        }
                }
            }
        }
    }
}

TC_HOT int tc_assemble(tc_cloth *c, double dt)
{
    if (tc_rows_update(c)) { tc_set_err(c, "out of memory building the rows of the system matrix"); return TC_ERR_NOMEM; }
    if (tc_material_general(&c->mat)) assemble(c, dt, true);
    else assemble(c, dt, false);
    return TC_OK;
}

/* ---------------- the matrix-vector product ----------------
 *
 * Row by row over the layout of core.h: no scatter, no branch between edges and flaps, one write
 * per row. Each row ends with p_i . y_i summed (the CG's curvature p.Ap, fused so p and y are not
 * read again). Kernels of the same arithmetic, picked at run time (one abi3 wheel runs on any
 * x86-64): AVX2 + FMA (a block column is one 4-lane load whose fourth lane, the next column's
 * first value, lands in a lane never stored: three FMAs per block, no padding), SSE2
 * (the x86-64 baseline: two lanes plus one), NEON on arm64 (fem_neon.c; compilers leave the
 * portable loop scalar there), and portable C everywhere. They differ only in rounding (FMA, the
 * order of the flap sums): tests/test_solver_simd.py holds them to 1e-12 relative. */

/* The arrays of the rows (core.h), fetched once per product for whichever kernel runs: matvec.h. */
#include "matvec.h"

static double matvec_scalar(const rows_view *m, const double *restrict p, double *restrict y)
{
    const double *restrict D = m->D, *restrict RB = m->RB, *restrict FV = m->FV;
    const int32_t *restrict rp = m->rp, *restrict rc = m->rc, *restrict fp = m->fp, *restrict fc = m->fc;
    double dot = 0.0;
    for (int32_t i = 0; i < m->nv; i++) {
        const double *d = D + 12 * (size_t)i, *x = p + 3 * (size_t)i;
        double y0 = d[0] * x[0] + d[4] * x[1] + d[8] * x[2];
        double y1 = d[1] * x[0] + d[5] * x[1] + d[9] * x[2];
        double y2 = d[2] * x[0] + d[6] * x[1] + d[10] * x[2];
        for (int32_t s = rp[i]; s < rp[i + 1]; s++) {
            const double *b = RB + 9 * (size_t)s, *xj = p + 3 * (size_t)rc[s];
            y0 += b[0] * xj[0] + b[3] * xj[1] + b[6] * xj[2];
            y1 += b[1] * xj[0] + b[4] * xj[1] + b[7] * xj[2];
            y2 += b[2] * xj[0] + b[5] * xj[1] + b[8] * xj[2];
        }
        for (int32_t s = fp[i]; s < fp[i + 1]; s++) {
            const double f = FV[s], *xj = p + 3 * (size_t)fc[s];
            y0 += f * xj[0]; y1 += f * xj[1]; y2 += f * xj[2];
        }
        double *o = y + 3 * (size_t)i;
        o[0] = y0; o[1] = y1; o[2] = y2;
        dot += x[0] * y0 + x[1] * y1 + x[2] * y2;
    }
    return dot;
}

#if defined(__x86_64__) || defined(_M_X64)
#define TC_X86_64 1
#include <immintrin.h>
#if defined(__GNUC__) || defined(__clang__)
#include <cpuid.h>
#endif

static double matvec_sse2(const rows_view *m, const double *restrict p, double *restrict y)
{
    const double *restrict D = m->D, *restrict RB = m->RB, *restrict FV = m->FV;
    const int32_t *restrict rp = m->rp, *restrict rc = m->rc, *restrict fp = m->fp, *restrict fc = m->fc;
    double dot = 0.0;
    for (int32_t i = 0; i < m->nv; i++) {
        const double *d = D + 12 * (size_t)i, *x = p + 3 * (size_t)i;
        __m128d x0 = _mm_set1_pd(x[0]), x1 = _mm_set1_pd(x[1]), x2 = _mm_set1_pd(x[2]);
        /* lo: rows 0 and 1; hi: row 2 and the zero pad */
        __m128d lo = _mm_add_pd(_mm_add_pd(_mm_mul_pd(_mm_loadu_pd(d), x0), _mm_mul_pd(_mm_loadu_pd(d + 4), x1)),
                                _mm_mul_pd(_mm_loadu_pd(d + 8), x2));
        __m128d hi = _mm_add_pd(_mm_add_pd(_mm_mul_pd(_mm_loadu_pd(d + 2), x0), _mm_mul_pd(_mm_loadu_pd(d + 6), x1)),
                                _mm_mul_pd(_mm_loadu_pd(d + 10), x2));
        for (int32_t s = rp[i]; s < rp[i + 1]; s++) {
            const double *b = RB + 9 * (size_t)s, *xj = p + 3 * (size_t)rc[s];
            __m128d a0 = _mm_set1_pd(xj[0]), a1 = _mm_set1_pd(xj[1]), a2 = _mm_set1_pd(xj[2]);
            lo = _mm_add_pd(lo, _mm_add_pd(_mm_add_pd(_mm_mul_pd(_mm_loadu_pd(b), a0), _mm_mul_pd(_mm_loadu_pd(b + 3), a1)),
                                           _mm_mul_pd(_mm_loadu_pd(b + 6), a2)));
            hi = _mm_add_pd(hi, _mm_add_pd(_mm_add_pd(_mm_mul_pd(_mm_load_sd(b + 2), a0), _mm_mul_pd(_mm_load_sd(b + 5), a1)),
                                           _mm_mul_pd(_mm_load_sd(b + 8), a2)));
        }
        for (int32_t s = fp[i]; s < fp[i + 1]; s++) {
            const double *xj = p + 3 * (size_t)fc[s];
            __m128d f = _mm_set1_pd(FV[s]);
            lo = _mm_add_pd(lo, _mm_mul_pd(f, _mm_loadu_pd(xj)));
            hi = _mm_add_pd(hi, _mm_mul_pd(f, _mm_load_sd(xj + 2)));  /* upper lane 0: no read past xj */
        }
        double *o = y + 3 * (size_t)i;
        _mm_storeu_pd(o, lo);
        _mm_store_sd(o + 2, hi);
        dot += x[0] * o[0] + x[1] * o[1] + x[2] * o[2];
    }
    return dot;
}

#if defined(__GNUC__) || defined(__clang__)
#define TC_TARGET_AVX2 __attribute__((target("avx2,fma")))
#else
#define TC_TARGET_AVX2 /* MSVC compiles AVX2 intrinsics without a flag */
#endif

/* The three components of vertex j as a 4-lane load; the last vertex's would read past the array,
 * so it alone is a masked load (a branch that is almost never taken: predicted). */
TC_TARGET_AVX2 static inline __m256d vertex_load(const double *p, int32_t j, int32_t last, __m256i m3)
{
    return j < last ? _mm256_loadu_pd(p + 3 * (size_t)j) : _mm256_maskload_pd(p + 3 * (size_t)j, m3);
}

/* The AVX2 product was bound by the latency of its FMA chains, not by the bytes it streams: with
 * two accumulators, the busier one chained ~15 dependent FMAs a row (the diagonal, half the edge
 * blocks' columns and every flap), ~60 cycles, about the 22 ns a row measured for the T-shirt
 * (37 us for 1,703 rows; its bytes need ~9 us from L2). So every block column of a pair of edge
 * blocks, and every flap of a group of three, feeds an accumulator of its own (six chains of
 * ~4-5 FMAs a row; measured 0.7x the time of the two-accumulator kernel), summed at the row's end,
 * and the curvature p.Ap is taken in vector lanes (no reload of the stored row). */
TC_TARGET_AVX2 static double matvec_avx2(const rows_view *m, const double *restrict p, double *restrict y)
{
    const double *restrict D = m->D, *restrict RB = m->RB, *restrict FV = m->FV;
    const int32_t *restrict rp = m->rp, *restrict rc = m->rc, *restrict fp = m->fp, *restrict fc = m->fc;
    const __m256i m3 = _mm256_set_epi64x(0, -1, -1, -1);  /* the three lanes of a vertex */
    __m256d dot0 = _mm256_setzero_pd(), dot1 = _mm256_setzero_pd();
    const __m256d keep = _mm256_castsi256_pd(m3);
    const int32_t last = m->nv - 1;
    int32_t s = rp[0], f = fp[0];
    for (int32_t i = 0; i < m->nv; i++) {
        const double *d = D + 12 * (size_t)i, *x = p + 3 * (size_t)i;
        const __m256d x0 = _mm256_broadcast_sd(x), x1 = _mm256_broadcast_sd(x + 1), x2 = _mm256_broadcast_sd(x + 2);
        __m256d a0 = _mm256_mul_pd(_mm256_loadu_pd(d), x0);
        __m256d a1 = _mm256_mul_pd(_mm256_loadu_pd(d + 4), x1);
        __m256d a2 = _mm256_mul_pd(_mm256_loadu_pd(d + 8), x2);
        __m256d a3 = _mm256_setzero_pd(), a4 = _mm256_setzero_pd(), a5 = _mm256_setzero_pd();
        const int32_t e = rp[i + 1];
        for (; s + 1 < e; s += 2) {
            const double *b = RB + 9 * (size_t)s, *xj = p + 3 * (size_t)rc[s], *xk = p + 3 * (size_t)rc[s + 1];
            a0 = _mm256_fmadd_pd(_mm256_loadu_pd(b), _mm256_broadcast_sd(xj), a0);
            a1 = _mm256_fmadd_pd(_mm256_loadu_pd(b + 3), _mm256_broadcast_sd(xj + 1), a1);
            a2 = _mm256_fmadd_pd(_mm256_loadu_pd(b + 6), _mm256_broadcast_sd(xj + 2), a2);
            a3 = _mm256_fmadd_pd(_mm256_loadu_pd(b + 9), _mm256_broadcast_sd(xk), a3);
            a4 = _mm256_fmadd_pd(_mm256_loadu_pd(b + 12), _mm256_broadcast_sd(xk + 1), a4);
            a5 = _mm256_fmadd_pd(_mm256_loadu_pd(b + 15), _mm256_broadcast_sd(xk + 2), a5);
        }
        if (s < e) {
            const double *b = RB + 9 * (size_t)s, *xj = p + 3 * (size_t)rc[s];
            a0 = _mm256_fmadd_pd(_mm256_loadu_pd(b), _mm256_broadcast_sd(xj), a0);
            a1 = _mm256_fmadd_pd(_mm256_loadu_pd(b + 3), _mm256_broadcast_sd(xj + 1), a1);
            a2 = _mm256_fmadd_pd(_mm256_loadu_pd(b + 6), _mm256_broadcast_sd(xj + 2), a2);
            s++;
        }
        const int32_t fe = fp[i + 1];
        for (; f + 2 < fe; f += 3) {
            a3 = _mm256_fmadd_pd(_mm256_broadcast_sd(FV + f), vertex_load(p, fc[f], last, m3), a3);
            a4 = _mm256_fmadd_pd(_mm256_broadcast_sd(FV + f + 1), vertex_load(p, fc[f + 1], last, m3), a4);
            a5 = _mm256_fmadd_pd(_mm256_broadcast_sd(FV + f + 2), vertex_load(p, fc[f + 2], last, m3), a5);
        }
        for (; f < fe; f++) a0 = _mm256_fmadd_pd(_mm256_broadcast_sd(FV + f), vertex_load(p, fc[f], last, m3), a0);
        /* lane 3 holds products of the next column's (or vertex's) first values: never stored, and
           cleared before the curvature's sum */
        const __m256d acc = _mm256_and_pd(
            _mm256_add_pd(_mm256_add_pd(_mm256_add_pd(a0, a1), _mm256_add_pd(a2, a3)), _mm256_add_pd(a4, a5)), keep);
        double *o = y + 3 * (size_t)i;
        _mm_storeu_pd(o, _mm256_castpd256_pd128(acc));
        _mm_store_sd(o + 2, _mm256_extractf128_pd(acc, 1));
        const __m256d xv = _mm256_blend_pd(_mm256_blend_pd(x0, x1, 0x2), x2, 0x4);  /* (x0, x1, x2, x0) */
        if (i & 1) dot1 = _mm256_fmadd_pd(acc, xv, dot1);
        else dot0 = _mm256_fmadd_pd(acc, xv, dot0);
    }
    const __m256d dv = _mm256_add_pd(dot0, dot1);
    const __m128d h = _mm_add_pd(_mm256_castpd256_pd128(dv), _mm256_extractf128_pd(dv, 1));
    return _mm_cvtsd_f64(_mm_add_sd(h, _mm_unpackhi_pd(h, h)));
}

/* CPUID and XGETBV read directly: __builtin_cpu_supports relies on the runtime filling a CPU
 * model at load time, which some targets (mingw through zig: Windows) never do, so there the AVX2
 * kernel would silently never run. */
static int cpu_has_avx2_fma(void)
{
#if defined(__GNUC__) || defined(__clang__)
    unsigned a, b, c, d;
    if (!__get_cpuid(1, &a, &b, &c, &d)) return 0;
    const unsigned fma = (c >> 12) & 1, osxsave = (c >> 27) & 1, avx = (c >> 28) & 1;
    if (!(fma && osxsave && avx)) return 0;
    unsigned lo, hi;
    __asm__ volatile("xgetbv" : "=a"(lo), "=d"(hi) : "c"(0));
    (void)hi;
    if ((lo & 6) != 6) return 0;  /* the OS saves the XMM and YMM state */
    if (__get_cpuid_max(0, 0) < 7) return 0;
    __cpuid_count(7, 0, a, b, c, d);
    return (b >> 5) & 1;
#elif defined(_MSC_VER)
    int r[4];
    __cpuid(r, 1);
    const int fma = (r[2] >> 12) & 1, osxsave = (r[2] >> 27) & 1, avx = (r[2] >> 28) & 1;
    if (!(fma && osxsave && avx) || (_xgetbv(0) & 6) != 6) return 0;  /* the OS saves the YMM state */
    __cpuidex(r, 7, 0);
    return (r[1] >> 5) & 1;
#else
    return 0;
#endif
}
#endif

/* The kernel in use, process-wide (a property of the CPU; tests switch it between steps). */
static int simd_active = -2;  /* not chosen yet */

static int simd_available(int level)
{
    if (level == TC_SIMD_SCALAR) return 1;
#ifdef TC_X86_64
    if (level == TC_SIMD_SSE2) return 1;
    if (level == TC_SIMD_AVX2) return cpu_has_avx2_fma();
#endif
#ifdef TC_HAVE_NEON
    if (level == TC_SIMD_NEON) return 1;
#endif
    return 0;
}

const char *tc_simd_name(int level)
{
    static const char *const names[] = {"scalar", "sse2", "avx2", "neon"};
    return level >= TC_SIMD_SCALAR && level <= TC_SIMD_LAST ? names[level] : "?";
}

int tc_simd_select(int level)
{
    if (level == TC_SIMD_AUTO) {
        level = simd_available(TC_SIMD_AVX2)   ? TC_SIMD_AVX2
                : simd_available(TC_SIMD_NEON) ? TC_SIMD_NEON
                : simd_available(TC_SIMD_SSE2) ? TC_SIMD_SSE2
                                               : TC_SIMD_SCALAR;
        const char *env = getenv("TEARCLOTH_SIMD");  /* a forced kernel, for tests and comparisons */
        if (env)
            for (int l = TC_SIMD_SCALAR; l <= TC_SIMD_LAST; l++)
                if (!strcmp(env, tc_simd_name(l)) && simd_available(l)) level = l;
    } else if (level < TC_SIMD_SCALAR || level > TC_SIMD_LAST || !simd_available(level)) {
        return -1;
    }
    simd_active = level;
    return level;
}

int tc_simd_level(void)
{
    if (simd_active < 0) tc_simd_select(TC_SIMD_AUTO);
    return simd_active;
}

int tc_cloth_product(tc_cloth *c, const double *p, int32_t n, double *y)
{
    if (n != c->nv) { tc_set_err(c, "product: %d vertices given for a cloth of %d", (int)n, (int)c->nv); return TC_ERR_INPUT; }
    if (!c->rows_built || c->rows_version != c->pair_version || c->rows_nv != c->nv) {
        tc_set_err(c, "product: no system matrix for the current mesh yet (step first)");
        return TC_ERR_INPUT;
    }
    for (size_t k = 0; k < 3 * (size_t)n; k++)
        if (!isfinite(p[k])) { tc_set_err(c, "product: component %zu of the vector is not finite (%g)", k, p[k]); return TC_ERR_INPUT; }
    tc_matvec(c, p, y);
    return TC_OK;
}

double tc_matvec(const tc_cloth *c, const double *restrict p, double *restrict y)
{
    const rows_view m = {tc_vec_ptr(&c->diag), tc_vec_ptr(&c->rblk), tc_vec_ptr(&c->fval), tc_vec_ptr(&c->rptr),
                         tc_vec_ptr(&c->rcol), tc_vec_ptr(&c->fptr), tc_vec_ptr(&c->fcol), c->nv};
#ifdef TC_X86_64
    switch (tc_simd_level()) {
    case TC_SIMD_AVX2: return matvec_avx2(&m, p, y);
    case TC_SIMD_SSE2: return matvec_sse2(&m, p, y);
    default: break;
    }
#endif
#ifdef TC_HAVE_NEON
    if (tc_simd_level() == TC_SIMD_NEON) return tc_matvec_neon(&m, p, y);
#endif
    return matvec_scalar(&m, p, y);
}

static double tc_elastic_energy(const tc_cloth *c, const double *x)
{
    double lambda, mu, Q[4];
    lame(&c->mat, &lambda, &mu);
    tc_ortho_moduli(&c->mat, Q);
    const bool general = tc_material_general(&c->mat);
    const double *AX = tc_vec_ptr(&c->taxis), *PL = tc_vec_ptr(&c->tplast);
    const int32_t *T = tc_vec_ptr(&c->tri);
    const double *G = tc_vec_ptr(&c->grad), *A = tc_vec_ptr(&c->area);
    double e = 0.0;
    for (int32_t t = 0; t < c->nt; t++) {
        const double *x0 = x + 3 * T[3 * t], *x1 = x + 3 * T[3 * t + 1], *x2 = x + 3 * T[3 * t + 2];
        const double *g = G + 4 * t;
        double e1[3], e2[3], F0[3], F1[3], R[6] = {1, 0, 0, 0, 1, 0}, eps[3];
        sub3(x1, x0, e1); sub3(x2, x0, e2);
        for (int k = 0; k < 3; k++) {
            F0[k] = e1[k] * g[0] + e2[k] * g[2];
            F1[k] = e1[k] * g[1] + e2[k] * g[3];
        }
        corotate(F0, F1, R, eps);
        if (general) {
            double sxx, syy, sxy;
            e += A[t] * c->mat.thickness *
                 ortho_stress(Q, AX[2 * t], AX[2 * t + 1], c->mat.plastic ? PL + 4 * (size_t)t : NULL, eps, &sxx, &syy, &sxy);
            continue;
        }
        double tr = eps[0] + eps[1];
        e += A[t] * c->mat.thickness *
             (mu * (eps[0] * eps[0] + eps[1] * eps[1] + 2.0 * eps[2] * eps[2]) + 0.5 * lambda * tr * tr);
    }
    return e;
}

static double tc_bending_energy(const tc_cloth *c, const double *x)
{
    const double *vb = tc_vec_ptr(&c->vbend), *pb = tc_vec_ptr(&c->pbend);
    const int32_t *pi = tc_vec_ptr(&c->pi), *pj = tc_vec_ptr(&c->pj);
    double e = 0.0;
    for (int32_t v = 0; v < c->nv; v++) e += 0.5 * vb[v] * dot3(x + 3 * v, x + 3 * v);
    size_t np = c->pi.len;
    for (size_t p = 0; p < np; p++)
        if (pi[p] >= 0) e += pb[p] * dot3(x + 3 * pi[p], x + 3 * pj[p]);
    return c->mat.bending * e;
}

tc_energy tc_cloth_energy(tc_cloth *c)
{
    tc_energy e = {0};
    const double *x = tc_vec_ptr(&c->x), *v = tc_vec_ptr(&c->v), *m = tc_vec_ptr(&c->mass);
    for (int32_t i = 0; i < c->nv; i++) {
        e.kinetic += 0.5 * m[i] * dot3(v + 3 * i, v + 3 * i);
        e.gravity -= m[i] * dot3(c->solver.gravity, x + 3 * i);
    }
    e.elastic = tc_elastic_energy(c, x);
    e.bending = tc_bending_energy(c, x);
    return e;
}
