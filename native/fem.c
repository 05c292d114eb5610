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

/* x86-64: the AVX2 kernels below (the assembly's scatter, the product), picked at run time */
#if defined(__x86_64__) || defined(_M_X64)
#define TC_X86_64 1
#include <immintrin.h>
#if defined(__GNUC__) || defined(__clang__)
#include <cpuid.h>
#define TC_TARGET_AVX2 __attribute__((target("avx2,fma")))
#else
#define TC_TARGET_AVX2 /* MSVC compiles AVX2 intrinsics without a flag */
#endif
#endif

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

TC_INLINE double element_pass_reference(tc_cloth *c, const double *x, const bool general)
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
    double *Rall = tc_vec_ptr(&c->rot), *sig = tc_vec_ptr(&c->sig);
    double *f = tc_vec_ptr(&c->force);  /* the elastic part; tc_total_force adds the rest */
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
            if (!(s2 <= worst2) && worst2 == worst2) worst2 = s2;  /* takes NaN, and keeps it: a later finite triangle must not hide an overflowed one */
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
        /* the world stress, the principal stresses and direction are not stored: R and sigma give
           them (tc_world_stress, tc_principal, tc_principal_dir), for tearing and the arrays' readers */
    }
    c->carried2 = isfinite(carried2) ? carried2 : 0.0;
    return isfinite(worst2) ? sqrt(worst2) : NAN;
}

/* The elastic force of one triangle linearized about its state at x0 turned into the frame R (the
 * rest of the step's linearization: the stress stays sigma0, the stiffness R K0 R^T plus the
 * geometric part of sigma0's tensile part sp), evaluated at x0:
 *   g(R) = -w R sigma(sym(R^T F0) - I) g_a + w (R S0 - F0) sp g_a
 * (the first term is the frozen-rotation force about R at x0, exact for the material part, which
 * is linear in x once R is fixed; the second, the geometric stiffness times x_e - x0, where x_e is
 * x0 turned into R: its deformation gradient R S0). g(R0) is the element pass's force at x0. The
 * two columns of the 3x2 matrix M with f_a = -w M g_a (a = 1, 2; f_0 = -f_1 - f_2) into m. */
TC_INLINE void turned_force(const double R[6], const double F0[3], const double F1[3], const double S0[3],
                            const double sp[3], const double Q[4], double lambda, double mu, bool general,
                            double cs, double sn, const double *pl, double m[6])
{
    const double m00 = dot3(R, F0), m01 = dot3(R, F1), m10 = dot3(R + 3, F0), m11 = dot3(R + 3, F1);
    const double eps[3] = {m00 - 1.0, m11 - 1.0, 0.5 * (m01 + m10)};
    double sxx, syy, sxy;
    if (!general) {
        const double tr = eps[0] + eps[1];
        sxx = lambda * tr + 2.0 * mu * eps[0]; syy = lambda * tr + 2.0 * mu * eps[1]; sxy = 2.0 * mu * eps[2];
    } else {
        ortho_stress(Q, cs, sn, pl, eps, &sxx, &syy, &sxy);
    }
    for (int k = 0; k < 3; k++) {
        /* (R S0 - F0) sp, by columns */
        const double e0 = R[k] * S0[0] + R[3 + k] * S0[1] - F0[k], e1 = R[k] * S0[1] + R[3 + k] * S0[2] - F1[k];
        m[k] = R[k] * sxx + R[3 + k] * sxy - (e0 * sp[0] + e1 * sp[1]);
        m[3 + k] = R[k] * sxy + R[3 + k] * syy - (e0 * sp[1] + e1 * sp[2]);
    }
}

/* The tensile part of the stress s (xx, yy, xy) into sp (xx, xy, yy): what the geometric
 * stiffness takes (assemble_reference says why; the batches compute the same in lanes) */
static void tensile_part(const double *s, double sp[3])
{
    const double a = s[0], d = s[1], b = s[2];
    const double m = 0.5 * (a + d), q = sqrt(0.25 * (a - d) * (a - d) + b * b);
    const double l1 = m + q, l2 = m - q;
    sp[0] = sp[1] = sp[2] = 0.0;
    if (l2 >= 0.0) { sp[0] = a; sp[1] = b; sp[2] = d; }
    else if (l1 > 0.0) {
        /* eigenvector of l1 */
        double ex = l1 - d, ey = b, fx = b, fy = l1 - a;
        if (ex * ex + ey * ey < fx * fx + fy * fy) { ex = fx; ey = fy; }
        const double el = sqrt(ex * ex + ey * ey);
        if (el > 0) { ex /= el; ey /= el; sp[0] = l1 * ex * ex; sp[1] = l1 * ex * ey; sp[2] = l1 * ey * ey; }
    }
}

/* What tc_turn_pass would find, estimated from the velocity gradients alone (step.c skips the
 * pass, ~140 ns a triangle, where this says it could not pass the bar): a triangle whose vertices'
 * motion over the sub-step has gradient L = dt grad v reads a strain of at most about |L|^2 / 2
 * through its frozen frame (a turn by theta: 1 - cos theta ~ theta^2 / 2 of the plane's stretch),
 * a stress of E_eff times that, and its compression turns by about |L| with it (the tensile part
 * is in the tangent, the compressed not). Each triangle's force change bounded by w |g| times
 * those; squared and summed, times TC_TURN_VALENCE for the triangles that share a vertex. */
double tc_turn_estimate(const tc_cloth *c, const double *v, double dt)
{
    double lambda, mu, Q[4];
    lame(&c->mat, &lambda, &mu);
    tc_ortho_moduli(&c->mat, Q);
    const double stiff = tc_material_general(&c->mat) ? fmax(Q[0], Q[1]) + fabs(Q[2]) : lambda + 2.0 * mu;
    const double h = c->mat.thickness;
    const int32_t *T = tc_vec_ptr(&c->tri);
    const double *G = tc_vec_ptr(&c->grad), *A = tc_vec_ptr(&c->area), *sig = tc_vec_ptr(&c->sig);
    double sum = 0.0;
    for (int32_t t = 0; t < c->nt; t++) {
        const int32_t i0 = T[3 * t], i1 = T[3 * t + 1], i2 = T[3 * t + 2];
        const double *g = G + 4 * t, *sg = sig + 3 * t;
        double l2 = 0.0;
        for (int k = 0; k < 3; k++) {
            const double d1 = v[3 * i1 + k] - v[3 * i0 + k], d2 = v[3 * i2 + k] - v[3 * i0 + k];
            const double a = d1 * g[0] + d2 * g[2], b = d1 * g[1] + d2 * g[3];
            l2 += a * a + b * b;
        }
        l2 *= dt * dt;
        const double m = 0.5 * (sg[0] + sg[1]), q = sqrt(0.25 * (sg[0] - sg[1]) * (sg[0] - sg[1]) + sg[2] * sg[2]);
        const double compressed = fmax(0.0, q - m);  /* minus the smaller principal stress, when negative */
        const double g2 = g[0] * g[0] + g[1] * g[1] + g[2] * g[2] + g[3] * g[3] +
                          (g[0] + g[2]) * (g[0] + g[2]) + (g[1] + g[3]) * (g[1] + g[3]);
        const double e = A[t] * h * (0.5 * stiff * l2 + compressed * sqrt(l2));
        sum += e * e * g2;
    }
    return TC_TURN_VALENCE * sum;
}

/* Newton on the rotations (step.c): each triangle's frame turned from the one the system was
 * linearized about (rot) to the polar rotation of its deformation gradient at x + dt v, and the
 * change g(R_new) - g(R_old) of its linearized force at x (turned_force) summed into dg. The
 * stress (sig) stays x's: only the frame turns. Triangles left in their frame: collapsed at either
 * end (no rotation to follow), or turning by more than 60 degrees in one sub-step (TC_TURN_MAX_COS) (a frame
 * that far off is no better a point to linearize about than the one it had); returns their count. */
int32_t tc_turn_pass(tc_cloth *c, const double *x, const double *v, double dt, double *dg)
{
    double lambda, mu, Q[4];
    lame(&c->mat, &lambda, &mu);
    tc_ortho_moduli(&c->mat, Q);
    const bool general = tc_material_general(&c->mat), plastic = c->mat.plastic;
    const double *AX = tc_vec_ptr(&c->taxis), *PL = tc_vec_ptr(&c->tplast);
    const double h = c->mat.thickness;
    const int32_t *T = tc_vec_ptr(&c->tri);
    const double *G = tc_vec_ptr(&c->grad), *A = tc_vec_ptr(&c->area), *sig = tc_vec_ptr(&c->sig);
    double *Rall = tc_vec_ptr(&c->rot);
    int32_t kept = 0;
    memset(dg, 0, 3 * (size_t)c->nv * sizeof *dg);
    for (int32_t t = 0; t < c->nt; t++) {
        const int32_t i0 = T[3 * t], i1 = T[3 * t + 1], i2 = T[3 * t + 2];
        const double *g = G + 4 * t;
        double F0[3], F1[3], P0[3], P1[3];
        for (int k = 0; k < 3; k++) {
            const double e1 = x[3 * i1 + k] - x[3 * i0 + k], e2 = x[3 * i2 + k] - x[3 * i0 + k];
            const double d1 = dt * (v[3 * i1 + k] - v[3 * i0 + k]), d2 = dt * (v[3 * i2 + k] - v[3 * i0 + k]);
            F0[k] = e1 * g[0] + e2 * g[2];
            F1[k] = e1 * g[1] + e2 * g[3];
            P0[k] = F0[k] + d1 * g[0] + d2 * g[2];
            P1[k] = F1[k] + d1 * g[1] + d2 * g[3];
        }
        /* S0 = (F0^T F0)^(1/2), as corotate's */
        const double a = dot3(F0, F0), b = dot3(F0, F1), d = dot3(F1, F1), det = a * d - b * b;
        const double a1 = dot3(P0, P0), b1 = dot3(P0, P1), d1 = dot3(P1, P1);
        if (!(det > TC_COLLAPSE_DET * (a + d) * (a + d)) || !(a1 * d1 - b1 * b1 > TC_COLLAPSE_DET * (a1 + d1) * (a1 + d1))) {
            kept++;  /* collapsed at either end: its frame is not a rotation to follow */
            continue;
        }
        const double sd = sqrt(det), st = sqrt(a + d + 2.0 * sd);
        const double S0[3] = {(a + sd) / st, b / st, (d + sd) / st};
        double *R = Rall + 6 * t, Rn[6], en[3], sp[3], m0[6], m1[6];
        corotate(P0, P1, Rn, en);
        {
            /* cos of the turn: the trace of R_new R^T on the plane, plus the normals' dot */
            double n0[3], n1[3];
            cross3(R, R + 3, n0);
            cross3(Rn, Rn + 3, n1);
            const double cos_turn = 0.5 * (dot3(Rn, R) + dot3(Rn + 3, R + 3) + dot3(n0, n1) - 1.0);
            if (!(cos_turn >= TC_TURN_MAX_COS)) { kept++; continue; }
        }
        tensile_part(sig + 3 * t, sp);
        const double cs = general ? AX[2 * t] : 1.0, sn = general ? AX[2 * t + 1] : 0.0;
        const double *pl = plastic ? PL + 4 * (size_t)t : NULL;
        turned_force(R, F0, F1, S0, sp, Q, lambda, mu, general, cs, sn, pl, m0);
        turned_force(Rn, F0, F1, S0, sp, Q, lambda, mu, general, cs, sn, pl, m1);
        const double w = A[t] * h;
        for (int k = 0; k < 3; k++) {
            const double q0 = m1[k] - m0[k], q1 = m1[3 + k] - m0[3 + k];
            const double fa = -w * (q0 * g[0] + q1 * g[1]), fb = -w * (q0 * g[2] + q1 * g[3]);
            dg[3 * i1 + k] += fa; dg[3 * i2 + k] += fb; dg[3 * i0 + k] -= fa + fb;
        }
        memcpy(R, Rn, sizeof Rn);
    }
    return kept;
}

TC_HOT __attribute__((noinline)) void tc_tri_world_stress(const tc_cloth *c, size_t t, double S[9])
{
    tc_world_stress((const double *)tc_vec_ptr(&c->rot) + 6 * t, (const double *)tc_vec_ptr(&c->sig) + 3 * t, S);
}

TC_HOT __attribute__((noinline)) void tc_tri_principal(const tc_cloth *c, size_t t, double p[2])
{
    tc_principal((const double *)tc_vec_ptr(&c->sig) + 3 * t, p);
}

TC_HOT __attribute__((noinline)) void tc_tri_principal_dir(const tc_cloth *c, size_t t, double d[3])
{
    tc_principal_dir((const double *)tc_vec_ptr(&c->rot) + 6 * t, (const double *)tc_vec_ptr(&c->sig) + 3 * t, d);
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

/* The total force at positions x in `force`, which the element pass filled with the elastic part:
 * plus gravity and bending. (The elastic part had an array of its own, fel, read only here: 12
 * bytes per triangle. A pass that leaves the element state stale, as tearing's, calls this after
 * it so that `force` is never the elastic part alone when read.) */
void tc_total_force(tc_cloth *c, const double *x)
{
    double *f = tc_vec_ptr(&c->force);
    const double *m = tc_vec_ptr(&c->mass);
    const double *g = c->solver.gravity;
    for (int32_t i = 0; i < c->nv; i++)
        for (int k = 0; k < 3; k++) f[3 * i + k] = f[3 * i + k] + m[i] * g[k];
    tc_bending_force(c, x, f);
}

/* the small loops inside a lane loop unrolled before the vectoriser runs, which then sees one
   straight-line body per lane (it vectorises innermost loops only) */
#if defined(__GNUC__) && !defined(__clang__)
#define TC_UNROLL _Pragma("GCC unroll 16")
#elif defined(__clang__)
#define TC_UNROLL _Pragma("unroll")
#else
#define TC_UNROLL
#endif

/* The stiffness block A_{va,vb} (a <= b) of one triangle, row-major, times the sub-step's
 * (dt^2 + dt beta): w = that times A h, wm = w mu, wl = w lambda; r_a = R g_a, P = R R^T,
 * sp the tensile part of the stress, C the general element's moduli (see assemble_reference). */
TC_INLINE void element_block(const double gg[3][2], const double r[3][3], const double P[9], const double R[6],
                             const double C[6], double w, double wm, double wl, double sp00, double sp01, double sp11,
                             int a, int b, const bool general, double B[9])
{
    const double dab = gg[a][0] * gg[b][0] + gg[a][1] * gg[b][1];
    const double kg = w * (gg[a][0] * (sp00 * gg[b][0] + sp01 * gg[b][1]) + gg[a][1] * (sp01 * gg[b][0] + sp11 * gg[b][1]));
    if (!general) {
        TC_UNROLL
        for (int i = 0; i < 3; i++)
            TC_UNROLL
            for (int k = 0; k < 3; k++) B[3 * i + k] = wm * (dab * P[3 * i + k] + r[b][i] * r[a][k]) + wl * r[a][i] * r[b][k];
    } else {
        const double a0 = gg[a][0], a1 = gg[a][1], b0 = gg[b][0], b1 = gg[b][1];
        /* C B_b, its two columns (xx, yy, xy rows) */
        const double u0 = C[0] * b0 + C[3] * b1, u1 = C[2] * b0 + C[4] * b1, u2 = C[3] * b0 + C[5] * b1;
        const double v0 = C[2] * b1 + C[3] * b0, v1 = C[1] * b1 + C[4] * b0, v2 = C[4] * b1 + C[5] * b0;
        const double k00 = w * (a0 * u0 + a1 * u2), k01 = w * (a0 * v0 + a1 * v2);
        const double k10 = w * (a1 * u1 + a0 * u2), k11 = w * (a1 * v1 + a0 * v2);
        TC_UNROLL
        for (int i = 0; i < 3; i++) {
            const double p0 = k00 * R[i] + k10 * R[3 + i], p1 = k01 * R[i] + k11 * R[3 + i];
            TC_UNROLL
            for (int k = 0; k < 3; k++) B[3 * i + k] = p0 * R[k] + p1 * R[3 + k];
        }
    }
    B[0] += kg; B[4] += kg; B[8] += kg;
}

/* System matrix A = (1 + dt alpha) M + (dt^2 + dt beta) (K + B), into the rows of core.h. */
TC_INLINE void assemble_reference(tc_cloth *c, double dt, const bool general)
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
        double sp[3];
        tensile_part(S2 + 3 * t, sp);
        const double sp00 = sp[0], sp01 = sp[1], sp11 = sp[2];
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
                double B[9];
                element_block(gg, r, P, R, C, wg, wm, wl, sp00, sp01, sp11, a, b, general, B);
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

/* ---------------- the element pass and the assembly, by batches of triangles ----------------
 *
 * The loops above are the reference: one triangle at a time, each stiffness block found through
 * its pair (which slot of the two is row va's) and added into an rblk cleared first. The loops
 * below compute TC_LANES triangles at once, every quantity an array over the batch, so the
 * compiler keeps one vector register per quantity (4 doubles in the AVX2/FMA clone of TC_HOT, 2
 * in SSE2, NEON on arm64) with no branch inside (the collapsed elements, rare, are redone one by
 * one through corotate()); then the batch is written out triangle by triangle, in the reference's
 * order, into the slots of its pairs (batch_slots). The element
 * pass and the assembly share the batch: when both are due on the same positions (a sub-step
 * whose element state was stale) one pass over the triangles does both (tc_element_assemble).
 * They differ from the reference only in rounding (FMA; the corotation's S^-1 by one division; a
 * diagonal block as minus the sum of its row's edge blocks; the AVX2 scatter's order of the sums
 * into a diagonal block): tests/test_fem_batches.py and
 * native/tests/test_core.c hold them to 1e-12 relative. TEARCLOTH_FEM=reference selects the
 * reference loops (for comparisons; tc_fem_reference). */

int tc_fem_reference = -1;  /* -1: not read yet from TEARCLOTH_FEM */

static bool fem_reference(void)
{
    if (tc_fem_reference < 0) {
        const char *env = getenv("TEARCLOTH_FEM");
        tc_fem_reference = env && !strcmp(env, "reference");
    }
    return tc_fem_reference != 0;
}

enum { TC_LANES = 4, TSLOT = 9 };

/* triangle edge e joins local vertices EA[e] and EB[e]; its pair is tpair[3 - EA - EB] */
static const int EA[3] = {0, 0, 1}, EB[3] = {1, 2, 2};

/* The slots of a batch: for edge e of triangle t, ts[9 l + 3 e ..] (l = t - t0) = the offset in
 * rblk of A_{va,vb} in row va, that of A_{vb,va} in row vb, and 2 p + first (p the pair; first when
 * t is the lowest-numbered triangle on the edge: it stores the block where the others add, as the
 * reference's sum does after its clearing, so rblk is never cleared). Derived per batch from the
 * pair's slots (pslot) and triangles (ptris): a table of them per triangle, built once per row
 * pattern, was 36 bytes per triangle (and a byte per pair), a twentieth of the memory of a 100K-
 * triangle cloth, for 12 lookups a batch into arrays the pass walks in about the same order. */
TC_INLINE void batch_slots(const tc_cloth *c, int32_t t0, int nl, int32_t *restrict ts)
{
    const int32_t *T = tc_vec_ptr(&c->tri), *TP = tc_vec_ptr(&c->tpair), *pi = tc_vec_ptr(&c->pi);
    const int32_t *slot = tc_vec_ptr(&c->pslot), *PT = tc_vec_ptr(&c->ptris);
    for (int l = 0; l < nl; l++) {
        const int32_t t = t0 + l;
        TC_UNROLL
        for (int e = 0; e < 3; e++) {
            const int32_t p = TP[3 * (size_t)t + (3 - EA[e] - EB[e])];
            const int own = T[3 * (size_t)t + EA[e]] == pi[p] ? 0 : 1;  /* which of the pair's slots is row va's */
            const int32_t a = PT[2 * (size_t)p], b = PT[2 * (size_t)p + 1];  /* t is one of them */
            int32_t *o = ts + TSLOT * l + 3 * e;
            o[0] = 9 * slot[2 * (size_t)p + own];
            o[1] = 9 * slot[2 * (size_t)p + 1 - own];
            o[2] = 2 * p + ((a < 0 || a >= t) && (b < 0 || b >= t));
        }
    }
}

/* What the stiffness of a batch reads, for TC_LANES consecutive triangles as stored (rotation R
 * 3x2 by columns, local stress, shape gradients, rest area, warp axis); the last, partial batch
 * points into a padded copy. */
typedef struct fem_batch {
    const double *R, *sig, *g, *A, *ax;
} fem_batch;

typedef struct fem_tail {
    double R[6 * TC_LANES], sig[3 * TC_LANES], g[4 * TC_LANES], A[TC_LANES], ax[2 * TC_LANES];
} fem_tail;

/* batch of triangles t0 .. t0 + nl - 1; lanes past nl repeat the first (computed, never written) */
static fem_batch batch_at(const tc_cloth *c, int32_t t0, int nl, bool general, fem_tail *tail)
{
    const double *R = tc_vec_ptr(&c->rot), *S = tc_vec_ptr(&c->sig), *G = tc_vec_ptr(&c->grad);
    const double *A = tc_vec_ptr(&c->area), *AX = tc_vec_ptr(&c->taxis);
    const size_t t = (size_t)t0;
    if (nl == TC_LANES) return (fem_batch){R + 6 * t, S + 3 * t, G + 4 * t, A + t, general ? AX + 2 * t : NULL};
    for (int l = 0; l < TC_LANES; l++) {
        const size_t u = t + (size_t)(l < nl ? l : 0);
        memcpy(tail->R + 6 * l, R + 6 * u, 6 * sizeof(double));
        memcpy(tail->sig + 3 * l, S + 3 * u, 3 * sizeof(double));
        memcpy(tail->g + 4 * l, G + 4 * u, 4 * sizeof(double));
        tail->A[l] = A[u];
        if (general) memcpy(tail->ax + 2 * l, AX + 2 * u, 2 * sizeof(double));
    }
    return (fem_batch){tail->R, tail->sig, tail->g, tail->A, general ? tail->ax : NULL};
}

typedef struct fem_params {
    double lambda, mu, Q[4], h, ks, ms, kb;
} fem_params;

static void fem_params_get(const tc_cloth *c, double dt, fem_params *p)
{
    lame(&c->mat, &p->lambda, &p->mu);
    tc_ortho_moduli(&c->mat, p->Q);
    p->h = c->mat.thickness;
    p->kb = c->mat.bending;
    p->ks = dt * dt + dt * c->mat.damping_stiffness;
    p->ms = 1.0 + dt * c->mat.damping_mass;
}

/* The six blocks A_{va,vb} (a <= b, in the order (0,0) (0,1) (0,2) (1,1) (1,2) (2,2)) of each lane,
 * row-major: the reference's B, same formulas for the edge blocks (see assemble_reference for the
 * why of each term), the diagonal ones from them (below). */
TC_INLINE void stiffness_lanes(const fem_batch *in, const fem_params *pp, double B[6][9][TC_LANES], const bool general)
{
    const double lambda = pp->lambda, mu = pp->mu, ks = pp->ks, h = pp->h;
    /* by lane first (the compiler vectorises loops over lanes, not strided reads of the batch) */
    double Rl[6][TC_LANES], Sl[3][TC_LANES], Gl[4][TC_LANES], Al[TC_LANES], Xl[2][TC_LANES];
    for (int l = 0; l < TC_LANES; l++) {
        TC_UNROLL
        for (int k = 0; k < 6; k++) Rl[k][l] = in->R[6 * l + k];
        TC_UNROLL
        for (int k = 0; k < 3; k++) Sl[k][l] = in->sig[3 * l + k];
        TC_UNROLL
        for (int k = 0; k < 4; k++) Gl[k][l] = in->g[4 * l + k];
        Al[l] = in->A[l];
        if (general) { Xl[0][l] = in->ax[2 * l]; Xl[1][l] = in->ax[2 * l + 1]; }
    }
    for (int l = 0; l < TC_LANES; l++) {
        double R[6];
        TC_UNROLL
        for (int k = 0; k < 6; k++) R[k] = Rl[k][l];
        const double g0 = Gl[0][l], g1 = Gl[1][l], g2 = Gl[2][l], g3 = Gl[3][l];
        const double gg[3][2] = {{-g0 - g2, -g1 - g3}, {g0, g1}, {g2, g3}};
        const double w = ks * Al[l] * h, wm = w * mu, wl = w * lambda;
        double r[3][3], P[9];
        TC_UNROLL
        for (int a = 0; a < 3; a++)
            TC_UNROLL
            for (int k = 0; k < 3; k++) r[a][k] = R[k] * gg[a][0] + R[3 + k] * gg[a][1];
        TC_UNROLL
        for (int i = 0; i < 3; i++)
            TC_UNROLL
            for (int k = 0; k < 3; k++) P[3 * i + k] = R[i] * R[k] + R[3 + i] * R[3 + k];
        /* the tensile part of the stress, branch-free (the reference's cases as selects) */
        const double sa = Sl[0][l], sd = Sl[1][l], sb = Sl[2][l];
        const double m = 0.5 * (sa + sd), q = sqrt(0.25 * (sa - sd) * (sa - sd) + sb * sb);
        const double l1 = m + q, l2 = m - q;
        double ex = l1 - sd, ey = sb;
        const double fx = sb, fy = l1 - sa;
        const bool other = ex * ex + ey * ey < fx * fx + fy * fy;
        ex = other ? fx : ex; ey = other ? fy : ey;
        const double el = sqrt(ex * ex + ey * ey), eld = el > 0 ? el : 1.0;
        ex = ex / eld; ey = ey / eld;
        const bool all = l2 >= 0.0, part = !all && l1 > 0.0 && el > 0;
        /* every value computed, then selected: a conditional flop would keep the compiler from
           vectorising (it may not assume floating-point operations never trap) */
        const double q00 = l1 * ex * ex, q01 = l1 * ex * ey, q11 = l1 * ey * ey;
        const double sp00 = all ? sa : part ? q00 : 0.0;
        const double sp01 = all ? sb : part ? q01 : 0.0;
        const double sp11 = all ? sd : part ? q11 : 0.0;
        double C[6] = {0};
        if (general) ortho_rest_moduli(pp->Q, Xl[0][l], Xl[1][l], C);
        /* the edge blocks (0,1) (0,2) (1,2); the diagonal ones follow below */
        static const int ea[3] = {0, 0, 1}, eb[3] = {1, 2, 2}, ee[3] = {1, 2, 4};
        TC_UNROLL
        for (int q = 0; q < 3; q++) {
            double Bl[9];
            element_block(gg, r, P, R, C, w, wm, wl, sp00, sp01, sp11, ea[q], eb[q], general, Bl);
            TC_UNROLL
            for (int k = 0; k < 9; k++) B[ee[q]][k][l] = Bl[k];
        }
    }
    /* A block row of an element's stiffness sums to zero (sum_b g_b = 0: every term of
       element_block is linear in g_b, the general element's B_b too), so a diagonal block is minus
       the others of its row (A_ba = A_ab^T): A_00 = -(A_01 + A_02), A_11 = -(A_01^T + A_12),
       A_22 = -(A_02^T + A_12^T). 27 additions for element_block's 27 entries of ~5 operations. */
    TC_UNROLL
    for (int i = 0; i < 3; i++)
        TC_UNROLL
        for (int k = 0; k < 3; k++)
            for (int l = 0; l < TC_LANES; l++) {
                B[0][3 * i + k][l] = -(B[1][3 * i + k][l] + B[2][3 * i + k][l]);
                B[3][3 * i + k][l] = -(B[1][3 * k + i][l] + B[4][3 * i + k][l]);
                B[5][3 * i + k][l] = -(B[2][3 * k + i][l] + B[4][3 * k + i][l]);
            }
}

/* Lane l's blocks into the rows: diagonal blocks added (columns padded to 4), edge blocks stored
 * by the edge's first triangle with the pair's bending part, added by the other (core.h's slot
 * layout: A_{va,vb} at [3k + r] = B[3r + k] in row va, its transpose in row vb). */
TC_INLINE void scatter_lane(double *restrict D, double *restrict RB, const int32_t *tri, const int32_t *ts,
                            const double *pb, double kbend, const double B[6][9][TC_LANES], int l)
{
    static const int diag_e[3] = {0, 3, 5}, edge_e[3] = {1, 2, 4};  /* (a,a); (0,1) (0,2) (1,2) */
    TC_UNROLL
    for (int a = 0; a < 3; a++) {
        double *d = D + 12 * (size_t)tri[a];
        const int e = diag_e[a];
        TC_UNROLL
        for (int r = 0; r < 3; r++)
            TC_UNROLL
            for (int k = 0; k < 3; k++) d[4 * k + r] += B[e][3 * r + k][l];
    }
    TC_UNROLL
    for (int q = 0; q < 3; q++) {
        const int32_t *s = ts + 3 * q;
        double *sa = RB + s[0], *sb = RB + s[1];
        const int e = edge_e[q];
        if (s[2] & 1) {
            const double bend = kbend * pb[s[2] >> 1];
            TC_UNROLL
            for (int r = 0; r < 3; r++)
                TC_UNROLL
                for (int k = 0; k < 3; k++) {
                    const double dg = r == k ? bend : 0.0;
                    sa[3 * k + r] = dg + B[e][3 * r + k][l];
                    sb[3 * k + r] = dg + B[e][3 * k + r][l];
                }
        } else {
            TC_UNROLL
            for (int r = 0; r < 3; r++)
                TC_UNROLL
                for (int k = 0; k < 3; k++) {
                    sa[3 * k + r] += B[e][3 * r + k][l];
                    sb[3 * k + r] += B[e][3 * k + r][l];
                }
        }
    }
}

#ifdef TC_X86_64
/* o[l] = (r0[l], r1[l], r2[l], r3[l]): four lanes of four quantities into four per-lane vectors */
TC_TARGET_AVX2 static inline void transpose4(__m256d r0, __m256d r1, __m256d r2, __m256d r3, double *o0, double *o1,
                                             double *o2, double *o3)
{
    const __m256d t0 = _mm256_unpacklo_pd(r0, r1), t1 = _mm256_unpackhi_pd(r0, r1);
    const __m256d t2 = _mm256_unpacklo_pd(r2, r3), t3 = _mm256_unpackhi_pd(r2, r3);
    _mm256_storeu_pd(o0, _mm256_permute2f128_pd(t0, t2, 0x20));
    _mm256_storeu_pd(o1, _mm256_permute2f128_pd(t1, t3, 0x20));
    _mm256_storeu_pd(o2, _mm256_permute2f128_pd(t0, t2, 0x31));
    _mm256_storeu_pd(o3, _mm256_permute2f128_pd(t1, t3, 0x31));
}

/* scatter_lane for every lane of a batch, four doubles at a time: the scalar scatter's 81
 * read-modify-writes a triangle, many on a diagonal block the triangle before had just written (a
 * chain through store-to-load forwarding), were ~40 % of the fused element pass and assembly. The
 * batch's blocks are turned from lanes (B[e][k][lane]) into each triangle's slot order by 4x4
 * transposes: a diagonal block's three padded columns, added at once for the four lanes (straight
 * from the registers: the sums into a vertex's diagonal block may come in another order than the
 * scalar scatter's, a rounding difference); an edge block as its row va slot (column by column)
 * and its row vb slot (row by row), 8 + 8 doubles and the shared last value, written lane by lane
 * in the scalar order (an edge's first triangle stores, the other adds: a triangle of the same
 * batch may share the edge). */
TC_TARGET_AVX2 static void scatter_batch_avx2(double *restrict D, double *restrict RB, const int32_t *tri,
                                              const int32_t *ts, const double *pb, double kbend,
                                              const double B[6][9][TC_LANES], int nl)
{
    static const int diag_e[3] = {0, 3, 5}, edge_e[3] = {1, 2, 4};  /* (a,a); (0,1) (0,2) (1,2) */
    enum { PER_LANE = 3 * 16 };
    _Alignas(32) double o[TC_LANES][PER_LANE];
    const __m256d zero = _mm256_setzero_pd();
#define TC_B(e, k) _mm256_loadu_pd(B[e][k])
    for (int q = 0; q < 3; q++) {
        const int e = edge_e[q], at = 16 * q;
        /* row va's slot holds B column by column: B0 B3 B6 B1 | B4 B7 B2 B5 | B8 */
        transpose4(TC_B(e, 0), TC_B(e, 3), TC_B(e, 6), TC_B(e, 1), o[0] + at, o[1] + at, o[2] + at, o[3] + at);
        transpose4(TC_B(e, 4), TC_B(e, 7), TC_B(e, 2), TC_B(e, 5), o[0] + at + 4, o[1] + at + 4, o[2] + at + 4,
                   o[3] + at + 4);
        /* row vb's slot holds B^T column by column, i.e. B row by row: B0 .. B3 | B4 .. B7 | B8 */
        transpose4(TC_B(e, 0), TC_B(e, 1), TC_B(e, 2), TC_B(e, 3), o[0] + at + 8, o[1] + at + 8, o[2] + at + 8,
                   o[3] + at + 8);
        transpose4(TC_B(e, 4), TC_B(e, 5), TC_B(e, 6), TC_B(e, 7), o[0] + at + 12, o[1] + at + 12, o[2] + at + 12,
                   o[3] + at + 12);
    }
    for (int a = 0; a < 3; a++) {
        const int e = diag_e[a];
        double *d[TC_LANES];
        for (int l = 0; l < TC_LANES; l++) d[l] = D + 12 * (size_t)tri[3 * (l < nl ? l : 0) + a];
        for (int k = 0; k < 3; k++) {  /* column k, padded: (B[k], B[3 + k], B[6 + k], 0) */
            const __m256d r0 = TC_B(e, k), r1 = TC_B(e, 3 + k), r2 = TC_B(e, 6 + k);
            const __m256d t0 = _mm256_unpacklo_pd(r0, r1), t1 = _mm256_unpackhi_pd(r0, r1);
            const __m256d t2 = _mm256_unpacklo_pd(r2, zero), t3 = _mm256_unpackhi_pd(r2, zero);
            const __m256d col[TC_LANES] = {_mm256_permute2f128_pd(t0, t2, 0x20), _mm256_permute2f128_pd(t1, t3, 0x20),
                                           _mm256_permute2f128_pd(t0, t2, 0x31), _mm256_permute2f128_pd(t1, t3, 0x31)};
            for (int l = 0; l < nl; l++)
                _mm256_storeu_pd(d[l] + 4 * k, _mm256_add_pd(_mm256_loadu_pd(d[l] + 4 * k), col[l]));
        }
    }
#undef TC_B
    for (int l = 0; l < nl; l++) {
        const double *ol = o[l];
        for (int q = 0; q < 3; q++) {
            const int32_t *s = ts + TSLOT * l + 3 * q;
            double *sa = RB + s[0], *sb = RB + s[1];
            const double *oq = ol + 16 * q, b8 = B[edge_e[q]][8][l];
            const __m256d a0 = _mm256_load_pd(oq), a1 = _mm256_load_pd(oq + 4);
            const __m256d b0 = _mm256_load_pd(oq + 8), b1 = _mm256_load_pd(oq + 12);
            if (s[2] & 1) {
                /* the edge's first triangle stores, with the pair's bending part on the diagonal
                   (flat 0, 4, 8 of a 3x3 block either way) */
                const double bend = kbend * pb[s[2] >> 1];
                const __m256d dg = _mm256_set_pd(0.0, 0.0, 0.0, bend);
                _mm256_storeu_pd(sa, _mm256_add_pd(dg, a0));
                _mm256_storeu_pd(sa + 4, _mm256_add_pd(dg, a1));
                sa[8] = bend + b8;
                _mm256_storeu_pd(sb, _mm256_add_pd(dg, b0));
                _mm256_storeu_pd(sb + 4, _mm256_add_pd(dg, b1));
                sb[8] = bend + b8;
            } else {
                _mm256_storeu_pd(sa, _mm256_add_pd(_mm256_loadu_pd(sa), a0));
                _mm256_storeu_pd(sa + 4, _mm256_add_pd(_mm256_loadu_pd(sa + 4), a1));
                sa[8] += b8;
                _mm256_storeu_pd(sb, _mm256_add_pd(_mm256_loadu_pd(sb), b0));
                _mm256_storeu_pd(sb + 4, _mm256_add_pd(_mm256_loadu_pd(sb + 4), b1));
                sb[8] += b8;
            }
        }
    }
}
#endif

/* Before the triangles: diagonal blocks cleared to mass and bending, flaps set to their bending
 * part. (An edge pair is one a triangle uses (ptris), and that triangle writes its blocks.) */
static void assemble_begin(tc_cloth *c, const fem_params *pp)
{
    const double ks = pp->ks, kb = pp->kb, ms = pp->ms;
    c->mass_scale = ms;
    const double *m = tc_vec_ptr(&c->mass), *vb = tc_vec_ptr(&c->vbend), *pb = tc_vec_ptr(&c->pbend);
    double *D = tc_vec_ptr(&c->diag), *FV = tc_vec_ptr(&c->fval);
    const int32_t *pi = tc_vec_ptr(&c->pi), *slot = tc_vec_ptr(&c->pslot);
    memset(D, 0, 12 * (size_t)c->nv * sizeof *D);
    for (int32_t v = 0; v < c->nv; v++) {
        double *d = D + 12 * v, s = m[v] * ms + ks * kb * vb[v];
        d[0] = s; d[5] = s; d[10] = s;
    }
    const size_t np = c->pi.len;
    for (size_t p = 0; p < np; p++) {
        if (pi[p] < 0 || tc_pair_is_edge(c, p)) continue;
        const double s = ks * kb * pb[p];
        FV[slot[2 * p]] = s; FV[slot[2 * p + 1]] = s;
    }
}

/* The stiffness of triangles t0 .. t0 + nl - 1 (from their stored R and sigma) into the rows. */
TC_INLINE void assemble_batch(tc_cloth *c, const fem_params *pp, int32_t t0, int nl, const bool general)
{
    fem_tail tail;
    const fem_batch in = batch_at(c, t0, nl, general, &tail);
    _Alignas(32) double B[6][9][TC_LANES];
    stiffness_lanes(&in, pp, B, general);
    const double kbend = pp->ks * pp->kb, *pb = tc_vec_ptr(&c->pbend);
    const int32_t *T = tc_vec_ptr(&c->tri);
    double *D = tc_vec_ptr(&c->diag), *RB = tc_vec_ptr(&c->rblk);
    int32_t ts[TSLOT * TC_LANES];
    batch_slots(c, t0, nl, ts);
#ifdef TC_X86_64
    if (tc_simd_level() == TC_SIMD_AVX2) {
        scatter_batch_avx2(D, RB, T + 3 * (size_t)t0, ts, pb, kbend, B, nl);
        return;
    }
#endif
    for (int l = 0; l < nl; l++) scatter_lane(D, RB, T + 3 * (size_t)(t0 + l), ts + TSLOT * l, pb, kbend, B, l);
}

/* The element pass by batches (see element_pass_reference for the physics), and with `fuse` the
 * assembly of the system matrix for a sub-step of length dt from the same batch. */
TC_INLINE double element_pass_lanes(tc_cloth *c, const double *x, const bool general, const bool fuse, double dt)
{
    fem_params pp;
    fem_params_get(c, dt, &pp);
    const double lambda = pp.lambda, mu = pp.mu, h = pp.h;
    const bool plastic = general && c->mat.plastic;
    const double *AX = tc_vec_ptr(&c->taxis), *PL = tc_vec_ptr(&c->tplast);
    const int32_t *T = tc_vec_ptr(&c->tri);
    const double *G = tc_vec_ptr(&c->grad), *A = tc_vec_ptr(&c->area);
    double *Rall = tc_vec_ptr(&c->rot), *sig = tc_vec_ptr(&c->sig);
    double *f = tc_vec_ptr(&c->force);  /* the elastic part; tc_total_force adds the rest */
    double worst2 = 0.0, carried2 = 0.0;
    memset(f, 0, 3 * (size_t)c->nv * sizeof *f);
    if (fuse) assemble_begin(c, &pp);
    const int32_t nt = c->nt;
    for (int32_t t0 = 0; t0 < nt; t0 += TC_LANES) {
        const int nl = nt - t0 < TC_LANES ? nt - t0 : TC_LANES;
        /* lanes past the last triangle repeat the batch's first: computed, never written */
        struct { double R[6][TC_LANES], sig[3][TC_LANES], g[4][TC_LANES], A[TC_LANES], ax[2][TC_LANES]; } in;
        double F[6][TC_LANES], pl[3][TC_LANES];
        for (int l = 0; l < TC_LANES; l++) {
            const int32_t t = t0 + (l < nl ? l : 0);
            const double *x0 = x + 3 * (size_t)T[3 * t], *x1 = x + 3 * (size_t)T[3 * t + 1], *x2 = x + 3 * (size_t)T[3 * t + 2];
            const double *g = G + 4 * (size_t)t;
            TC_UNROLL
            for (int k = 0; k < 4; k++) in.g[k][l] = g[k];
            TC_UNROLL
            for (int k = 0; k < 3; k++) {
                const double e1 = x1[k] - x0[k], e2 = x2[k] - x0[k];
                F[k][l] = e1 * g[0] + e2 * g[2];
                F[3 + k][l] = e1 * g[1] + e2 * g[3];
            }
            in.A[l] = A[t];
            if (general) { in.ax[0][l] = AX[2 * t]; in.ax[1][l] = AX[2 * t + 1]; }
            TC_UNROLL
            for (int k = 0; k < 3; k++) pl[k][l] = plastic ? PL[4 * (size_t)t + k] : 0.0;
        }
        /* co-rotation of the regular elements (corotate()'s first branch) */
        double s2[TC_LANES], eps[3][TC_LANES];
        double collapsed[TC_LANES];  /* 1 or 0: a double, as the lanes' other values (a bool would keep the loop scalar) */
        for (int l = 0; l < TC_LANES; l++) {
            const double F0[3] = {F[0][l], F[1][l], F[2][l]}, F1[3] = {F[3][l], F[4][l], F[5][l]};
            const double a = dot3(F0, F0), b = dot3(F0, F1), d = dot3(F1, F1);
            s2[l] = 0.5 * (a + d) + sqrt(0.25 * (a - d) * (a - d) + b * b);
            const double det = a * d - b * b;
            const bool regular = det > TC_COLLAPSE_DET * (a + d) * (a + d);
            collapsed[l] = regular ? 0.0 : 1.0;
            const double s = sqrt(regular ? det : 1.0), t = sqrt(a + d + 2.0 * s);
            /* S^-1 = [[d + s, -b], [-b, a + s]] / (s t) (S = [[a + s, b], [b, d + s]] / t, det S = s):
               one division for corotate()'s six (a vector division is ~8 cycles a lane group) */
            const double k = 1.0 / (s * t);
            const double i00 = (d + s) * k, i01 = -b * k, i11 = (a + s) * k;
            double R[6];
            TC_UNROLL
            for (int k = 0; k < 3; k++) {
                R[k] = F0[k] * i00 + F1[k] * i01;
                R[3 + k] = F0[k] * i01 + F1[k] * i11;
            }
            TC_UNROLL
            for (int k = 0; k < 6; k++) in.R[k][l] = R[k];
            eps[0][l] = dot3(R, F0) - 1.0;
            eps[1][l] = dot3(R + 3, F1) - 1.0;
            eps[2][l] = 0.5 * (dot3(R, F1) + dot3(R + 3, F0));
        }
        /* collapsed ones (rare) one by one, from their last rotation as the reference does */
        for (int l = 0; l < nl; l++) {
            if (collapsed[l] == 0.0) continue;
            const double F0[3] = {F[0][l], F[1][l], F[2][l]}, F1[3] = {F[3][l], F[4][l], F[5][l]};
            double R[6], e3[3];
            memcpy(R, Rall + 6 * (size_t)(t0 + l), sizeof R);
            corotate(F0, F1, R, e3);
            TC_UNROLL
            for (int k = 0; k < 6; k++) in.R[k][l] = R[k];
            TC_UNROLL
            for (int k = 0; k < 3; k++) eps[k][l] = e3[k];
        }
        /* stress and forces (the world stress, the principal stresses and direction: from R and
           sigma where read, tc_world_stress / tc_principal / tc_principal_dir) */
        double fab[6][TC_LANES];
        for (int l = 0; l < TC_LANES; l++) {
            double sxx, syy, sxy;
            const double e0 = eps[0][l], e1 = eps[1][l], e2 = eps[2][l];
            if (!general) {
                const double tr = e0 + e1;
                sxx = lambda * tr + 2.0 * mu * e0; syy = lambda * tr + 2.0 * mu * e1; sxy = 2.0 * mu * e2;
            } else {
                const double ee[3] = {e0, e1, e2}, pp3[3] = {pl[0][l], pl[1][l], pl[2][l]};
                ortho_stress(pp.Q, in.ax[0][l], in.ax[1][l], pp3, ee, &sxx, &syy, &sxy);
            }
            in.sig[0][l] = sxx; in.sig[1][l] = syy; in.sig[2][l] = sxy;
            double R[6];
            TC_UNROLL
            for (int k = 0; k < 6; k++) R[k] = in.R[k][l];
            const double g0 = in.g[0][l], g1 = in.g[1][l], g2 = in.g[2][l], g3 = in.g[3][l];
            const double w = in.A[l] * h;
            TC_UNROLL
            for (int k = 0; k < 3; k++) {
                const double P0 = R[k] * sxx + R[3 + k] * sxy, P1 = R[k] * sxy + R[3 + k] * syy;
                fab[k][l] = -w * (P0 * g0 + P1 * g1);
                fab[3 + k][l] = -w * (P0 * g2 + P1 * g3);
            }
        }
        /* out, triangle by triangle in order (the force sums as the reference's) */
        for (int l = 0; l < nl; l++) {
            const size_t t = (size_t)(t0 + l);
            if (!(s2[l] <= worst2) && worst2 == worst2) worst2 = s2[l];  /* takes NaN and keeps it (as above) */
            TC_UNROLL
            for (int k = 0; k < 6; k++) Rall[6 * t + k] = in.R[k][l];
            TC_UNROLL
            for (int k = 0; k < 3; k++) sig[3 * t + k] = in.sig[k][l];
            const int32_t i0 = T[3 * t], i1 = T[3 * t + 1], i2 = T[3 * t + 2];
            TC_UNROLL
            for (int k = 0; k < 3; k++) {
                const double fa = fab[k][l], fb = fab[3 + k][l];
                f[3 * i1 + k] += fa;
                f[3 * i2 + k] += fb;
                f[3 * i0 + k] -= fa + fb;
                carried2 += fa * fa + fb * fb + (fa + fb) * (fa + fb);
            }
        }
        if (fuse) assemble_batch(c, &pp, t0, nl, general);  /* from the R and sigma just stored (in cache) */
    }
    c->carried2 = isfinite(carried2) ? carried2 : 0.0;
    return isfinite(worst2) ? sqrt(worst2) : NAN;
}

/* The assembly alone by batches, from the rotations and stresses of the last element pass. */
TC_INLINE void assemble_lanes(tc_cloth *c, double dt, const bool general)
{
    fem_params pp;
    fem_params_get(c, dt, &pp);
    assemble_begin(c, &pp);
    for (int32_t t0 = 0; t0 < c->nt; t0 += TC_LANES)
        assemble_batch(c, &pp, t0, c->nt - t0 < TC_LANES ? c->nt - t0 : TC_LANES, general);
}

TC_HOT double tc_element_pass(tc_cloth *c, const double *x)
{
    const bool general = tc_material_general(&c->mat);
    if (fem_reference()) return general ? element_pass_reference(c, x, true) : element_pass_reference(c, x, false);
    return general ? element_pass_lanes(c, x, true, false, 0.0) : element_pass_lanes(c, x, false, false, 0.0);
}

static int rows_ready(tc_cloth *c)
{
    if (tc_rows_update(c)) {
        tc_set_err(c, "out of memory building the rows of the system matrix");
        return TC_ERR_NOMEM;
    }
    return TC_OK;
}

TC_HOT int tc_assemble(tc_cloth *c, double dt)
{
    if (rows_ready(c)) return TC_ERR_NOMEM;
    const bool general = tc_material_general(&c->mat);
    if (fem_reference()) {
        if (general) assemble_reference(c, dt, true);
        else assemble_reference(c, dt, false);
    } else if (general) {
        assemble_lanes(c, dt, true);
    } else {
        assemble_lanes(c, dt, false);
    }
    return TC_OK;
}

TC_HOT int tc_element_assemble(tc_cloth *c, const double *x, double dt, double *worst)
{
    if (rows_ready(c)) return TC_ERR_NOMEM;
    const bool general = tc_material_general(&c->mat);
    if (fem_reference()) {
        *worst = tc_element_pass(c, x);
        return tc_assemble(c, dt);
    }
    *worst = general ? element_pass_lanes(c, x, true, true, dt) : element_pass_lanes(c, x, false, true, dt);
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

#ifdef TC_X86_64

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

/* Doubles of the block stream the AVX2 product prefetches ahead of the pair it reads (~7 blocks:
 * 64 and 128 measured alike, 32 gained nothing). */
#define TC_PREFETCH_AHEAD 64

/* The three components of vertex j as a 4-lane load; the last vertex's would read past the array,
 * so it alone is a masked load (a branch that is almost never taken: predicted). */
TC_TARGET_AVX2 static inline __m256d vertex_load(const double *p, int32_t j, int32_t last, __m256i m3)
{
    return j < last ? _mm256_loadu_pd(p + 3 * (size_t)j) : _mm256_maskload_pd(p + 3 * (size_t)j, m3);
}

/* The AVX2 product. Every block column of a pair of edge blocks, and every flap of a pair, feeds an
 * accumulator of its own (six chains of ~3 FMAs a row: with two accumulators the busier one
 * chained ~15 dependent FMAs a row, ~60 cycles, and bound the kernel), summed at the row's end,
 * and the curvature p.Ap is taken in vector lanes (no reload of the stored row). What bounds it
 * now is the issue of its instructions (~6 per block column and flap: the broadcast of the x
 * component, the FMA with the block's column, the index and its address) and, on a core whose
 * sibling thread is busy, the L2 it then shares: so the row's blocks and flaps are walked by
 * pointer (the index-based loop kept spilling its bounds), and the block stream is prefetched
 * TC_PREFETCH_AHEAD doubles ahead (measured 0.88x the time of the kernel before, T-shirt, quiet
 * core; equal when the sibling thread evicts the matrix from L2 and the product streams from L3). */
TC_TARGET_AVX2 static double matvec_avx2(const rows_view *m, const double *restrict p, double *restrict y)
{
    const double *restrict D = m->D;
    const int32_t *restrict rp = m->rp, *restrict fp = m->fp;
    const __m256i m3 = _mm256_set_epi64x(0, -1, -1, -1);  /* the three lanes of a vertex */
    __m256d dot0 = _mm256_setzero_pd(), dot1 = _mm256_setzero_pd();
    const __m256d keep = _mm256_castsi256_pd(m3);
    const int32_t nv = m->nv, last = nv - 1;
    const double *restrict b = m->RB + 9 * (size_t)rp[0], *restrict fv = m->FV + fp[0];
    const int32_t *restrict c = m->rc + rp[0], *restrict fc = m->fc + fp[0];
    for (int32_t i = 0; i < nv; i++) {
        const double *d = D + 12 * (size_t)i, *x = p + 3 * (size_t)i;
        const __m256d x0 = _mm256_broadcast_sd(x), x1 = _mm256_broadcast_sd(x + 1), x2 = _mm256_broadcast_sd(x + 2);
        __m256d a0 = _mm256_mul_pd(_mm256_loadu_pd(d), x0);
        __m256d a1 = _mm256_mul_pd(_mm256_loadu_pd(d + 4), x1);
        __m256d a2 = _mm256_mul_pd(_mm256_loadu_pd(d + 8), x2);
        __m256d a3 = _mm256_setzero_pd(), a4 = _mm256_setzero_pd(), a5 = _mm256_setzero_pd();
        const int32_t *ce = m->rc + rp[i + 1];
        for (; c + 1 < ce; c += 2, b += 18) {
            const double *xj = p + 3 * (size_t)c[0], *xk = p + 3 * (size_t)c[1];
            /* two blocks are 2.25 cache lines: two prefetches keep up */
            _mm_prefetch((const char *)(b + TC_PREFETCH_AHEAD), _MM_HINT_T0);
            _mm_prefetch((const char *)(b + TC_PREFETCH_AHEAD + 8), _MM_HINT_T0);
            a0 = _mm256_fmadd_pd(_mm256_loadu_pd(b), _mm256_broadcast_sd(xj), a0);
            a1 = _mm256_fmadd_pd(_mm256_loadu_pd(b + 3), _mm256_broadcast_sd(xj + 1), a1);
            a2 = _mm256_fmadd_pd(_mm256_loadu_pd(b + 6), _mm256_broadcast_sd(xj + 2), a2);
            a3 = _mm256_fmadd_pd(_mm256_loadu_pd(b + 9), _mm256_broadcast_sd(xk), a3);
            a4 = _mm256_fmadd_pd(_mm256_loadu_pd(b + 12), _mm256_broadcast_sd(xk + 1), a4);
            a5 = _mm256_fmadd_pd(_mm256_loadu_pd(b + 15), _mm256_broadcast_sd(xk + 2), a5);
        }
        if (c < ce) {
            const double *xj = p + 3 * (size_t)c[0];
            a0 = _mm256_fmadd_pd(_mm256_loadu_pd(b), _mm256_broadcast_sd(xj), a0);
            a1 = _mm256_fmadd_pd(_mm256_loadu_pd(b + 3), _mm256_broadcast_sd(xj + 1), a1);
            a2 = _mm256_fmadd_pd(_mm256_loadu_pd(b + 6), _mm256_broadcast_sd(xj + 2), a2);
            c++;
            b += 9;
        }
        const int32_t *fe = m->fc + fp[i + 1];
        for (; fc + 1 < fe; fc += 2, fv += 2) {
            a3 = _mm256_fmadd_pd(_mm256_broadcast_sd(fv), vertex_load(p, fc[0], last, m3), a3);
            a4 = _mm256_fmadd_pd(_mm256_broadcast_sd(fv + 1), vertex_load(p, fc[1], last, m3), a4);
        }
        if (fc < fe) {
            a5 = _mm256_fmadd_pd(_mm256_broadcast_sd(fv), vertex_load(p, fc[0], last, m3), a5);
            fc++;
            fv++;
        }
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
    /* finite: an exponent field not all ones, i.e. adding 1 to it does not carry into bit 63. Tested
       on the bits with no exit or comparison inside, the loop vectorises even with SSE2 (the
       isfinite() loop with an early exit cost ~10 % of a T-shirt's product); the culprit is looked
       for only when there is one */
    uint64_t carry = 0;
    for (size_t k = 0; k < 3 * (size_t)n; k++) {
        uint64_t u;
        memcpy(&u, p + k, sizeof u);
        carry |= (u & 0x7ff0000000000000u) + 0x0010000000000000u;
    }
    for (size_t k = 0; (carry >> 63) && k < 3 * (size_t)n; k++)
        if (!isfinite(p[k])) { tc_set_err(c, "product: component %zu of the vector is not finite (%g)", k, p[k]); return TC_ERR_INPUT; }
    tc_matvec(c, p, y);
    return TC_OK;
}

/* y -= A q for a q that is zero but at a few vertices (a solve's prescribed velocities: pins,
 * handles, contacts). Column j of A is row j transposed (A_kj = A_jk^T: the assembly writes both
 * slots of a pair from the same values; a flap is a multiple of I), so each vertex with q_j != 0
 * subtracts its diagonal block's A_jj q_j from y_j and A_jk^T q_j from each neighbour y_k: work in
 * proportion to those vertices' rows, not the whole product (one of the three products a solve
 * did besides its iterations). The sums come in another order than the full product's. */
TC_HOT void tc_matvec_sub_sparse(const tc_cloth *c, const double *restrict q, double *restrict y)
{
    const double *D = tc_vec_ptr(&c->diag), *RB = tc_vec_ptr(&c->rblk), *FV = tc_vec_ptr(&c->fval);
    const int32_t *rp = tc_vec_ptr(&c->rptr), *rc = tc_vec_ptr(&c->rcol), *fp = tc_vec_ptr(&c->fptr), *fc = tc_vec_ptr(&c->fcol);
    for (int32_t j = 0; j < c->nv; j++) {
        const double *qj = q + 3 * (size_t)j;
        if (qj[0] == 0.0 && qj[1] == 0.0 && qj[2] == 0.0) continue;
        const double *d = D + 12 * (size_t)j;  /* columns padded to 4 */
        double *yj = y + 3 * (size_t)j;
        for (int r = 0; r < 3; r++) yj[r] -= d[r] * qj[0] + d[4 + r] * qj[1] + d[8 + r] * qj[2];
        for (int32_t s = rp[j]; s < rp[j + 1]; s++) {
            const double *b = RB + 9 * (size_t)s;  /* A_jk column by column: A_kj's rows */
            double *yk = y + 3 * (size_t)rc[s];
            for (int r = 0; r < 3; r++) yk[r] -= b[3 * r] * qj[0] + b[3 * r + 1] * qj[1] + b[3 * r + 2] * qj[2];
        }
        for (int32_t s = fp[j]; s < fp[j + 1]; s++) {
            const double f = FV[s];
            double *yk = y + 3 * (size_t)fc[s];
            for (int r = 0; r < 3; r++) yk[r] -= f * qj[r];
        }
    }
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
    if (c->vpink.len) {  /* towards the goals the last step reached (vgoal) */
        const double *ks = tc_vec_ptr(&c->vpink), *g = tc_vec_ptr(&c->vgoal);
        const int8_t *pin = tc_vec_ptr(&c->vpin);
        for (int32_t i = 0; i < c->nv; i++)
            if (ks[i] > 0 && !pin[i]) {
                const double d[3] = {x[3 * i] - g[3 * i], x[3 * i + 1] - g[3 * i + 1], x[3 * i + 2] - g[3 * i + 2]};
                e.pins += 0.5 * ks[i] * dot3(d, d);
            }
    }
    return e;
}
