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
#include <string.h>

static inline void lame(const tc_material *m, double *lambda, double *mu)
{
    /* plane-stress Lame constants */
    *lambda = m->young * m->poisson / (1.0 - m->poisson * m->poisson);
    *mu = m->young / (2.0 * (1.0 + m->poisson));
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
TC_HOT double tc_element_pass(tc_cloth *c, const double *x)
{
    double worst2 = 0.0;
    double lambda, mu;
    lame(&c->mat, &lambda, &mu);
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
        double tr = eps[0] + eps[1];
        double sxx = lambda * tr + 2.0 * mu * eps[0], syy = lambda * tr + 2.0 * mu * eps[1], sxy = 2.0 * mu * eps[2];
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

/* System matrix A = (1 + dt alpha) M + (dt^2 + dt beta) (K + B). */
TC_HOT void tc_assemble(tc_cloth *c, double dt)
{
    double lambda, mu;
    lame(&c->mat, &lambda, &mu);
    const double h = c->mat.thickness, kb = c->mat.bending;
    const double ks = dt * dt + dt * c->mat.damping_stiffness, ms = 1.0 + dt * c->mat.damping_mass;
    c->mass_scale = ms;
    const double *m = tc_vec_ptr(&c->mass), *vb = tc_vec_ptr(&c->vbend), *pb = tc_vec_ptr(&c->pbend);
    double *D = tc_vec_ptr(&c->diag), *PB = tc_vec_ptr(&c->pblock);
    const int32_t *pi = tc_vec_ptr(&c->pi);
    for (int32_t v = 0; v < c->nv; v++) {
        double *d = D + 9 * v, s = m[v] * ms + ks * kb * vb[v];
        d[0] = s; d[1] = 0; d[2] = 0; d[3] = 0; d[4] = s; d[5] = 0; d[6] = 0; d[7] = 0; d[8] = s;
    }
    size_t np = c->pi.len;
    for (size_t p = 0; p < np; p++) {
        double *b = PB + 9 * p, s = pi[p] >= 0 ? ks * kb * pb[p] : 0.0;
        b[0] = s; b[1] = 0; b[2] = 0; b[3] = 0; b[4] = s; b[5] = 0; b[6] = 0; b[7] = 0; b[8] = s;
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
        for (int a = 0; a < 3; a++) {
            for (int b = a; b < 3; b++) {
                const double dab = gg[a][0] * gg[b][0] + gg[a][1] * gg[b][1];
                const double kg = wg * (gg[a][0] * (sp00 * gg[b][0] + sp01 * gg[b][1]) +
                                        gg[a][1] * (sp01 * gg[b][0] + sp11 * gg[b][1]));
                double B[9];
                for (int i = 0; i < 3; i++)
                    for (int l = 0; l < 3; l++)
                        B[3 * i + l] = wm * (dab * P[3 * i + l] + r[b][i] * r[a][l]) + wl * r[a][i] * r[b][l];
                B[0] += kg; B[4] += kg; B[8] += kg;
                const int32_t va = T[3 * t + a];
                if (a == b) {
                    double *d = D + 9 * va;
                    for (int q = 0; q < 9; q++) d[q] += B[q];
                } else {
                    const int32_t p = TP[3 * t + (3 - a - b)];
                    double *blk = PB + 9 * (size_t)p;
                    if (va == pi[p]) {
                        for (int q = 0; q < 9; q++) blk[q] += B[q];
                    } else {
                        for (int i = 0; i < 3; i++)
                            for (int l = 0; l < 3; l++) blk[3 * i + l] += B[3 * l + i];
                    }
                }
            }
        }
    }
}

TC_HOT void tc_matvec(const tc_cloth *c, const double *restrict p, double *restrict y)
{
    const double *restrict D = tc_vec_ptr(&c->diag), *restrict PB = tc_vec_ptr(&c->pblock);
    const int32_t *restrict pi = tc_vec_ptr(&c->pi), *restrict pj = tc_vec_ptr(&c->pj);
    const int32_t nv = c->nv;
    for (int32_t v = 0; v < nv; v++) {
        const double *d = D + 9 * v, *x = p + 3 * v;
        double x0 = x[0], x1 = x[1], x2 = x[2];
        y[3 * v] = d[0] * x0 + d[1] * x1 + d[2] * x2;
        y[3 * v + 1] = d[3] * x0 + d[4] * x1 + d[5] * x2;
        y[3 * v + 2] = d[6] * x0 + d[7] * x1 + d[8] * x2;
    }
    const int32_t *restrict pt = tc_vec_ptr(&c->ptris);
    const size_t np = c->pi.len;
    for (size_t q = 0; q < np; q++) {
        const int32_t i = pi[q], j = pj[q];
        if (i < 0) continue;
        const double *B = PB + 9 * q;
        if (pt[2 * q] < 0) {
            /* a bending flap (no triangle edge): its block is a multiple of I - a third of the
               flops, and half the pairs of a mesh are flaps */
            const double s = B[0];
            y[3 * i] += s * p[3 * j]; y[3 * i + 1] += s * p[3 * j + 1]; y[3 * i + 2] += s * p[3 * j + 2];
            y[3 * j] += s * p[3 * i]; y[3 * j + 1] += s * p[3 * i + 1]; y[3 * j + 2] += s * p[3 * i + 2];
            continue;
        }
        const double a0 = p[3 * i], a1 = p[3 * i + 1], a2 = p[3 * i + 2];
        const double b0 = p[3 * j], b1 = p[3 * j + 1], b2 = p[3 * j + 2];
        const double B0 = B[0], B1 = B[1], B2 = B[2], B3 = B[3], B4 = B[4], B5 = B[5], B6 = B[6], B7 = B[7], B8 = B[8];
        y[3 * i] += B0 * b0 + B1 * b1 + B2 * b2;
        y[3 * i + 1] += B3 * b0 + B4 * b1 + B5 * b2;
        y[3 * i + 2] += B6 * b0 + B7 * b1 + B8 * b2;
        y[3 * j] += B0 * a0 + B3 * a1 + B6 * a2;
        y[3 * j + 1] += B1 * a0 + B4 * a1 + B7 * a2;
        y[3 * j + 2] += B2 * a0 + B5 * a1 + B8 * a2;
    }
}

static double tc_elastic_energy(const tc_cloth *c, const double *x)
{
    double lambda, mu;
    lame(&c->mat, &lambda, &mu);
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
