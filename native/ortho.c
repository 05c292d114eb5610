/* ortho.c - the woven sheet: material axes per triangle (warp and weft), the orthotropic
 * plane-stress moduli, and plasticity (yield, hardening, the plastic rest metric). fem.c's element
 * pass and assembly read the moduli and the axes, tear.c the axes and the strengths, step.c
 * commits the plastic strain after every kept sub-step.
 *
 * AXES. Each triangle keeps its warp as a unit vector in the rest space (twarp), so a triangle the
 * remesh splits hands it on unchanged (the halves lie in the parent's plane), and as (cos, sin) in
 * its own 2-D rest frame (taxis, what the element loop reads), derived again whenever the rest
 * frame is (tc_tri_rest). Only a sheet whose material reads them stores them (orthotropic or
 * plastic: tc_material_general, from the first time its material is, then for good): an isotropic
 * one reads neither, and they were 40 bytes per triangle, 4 % of the memory target of a
 * 100K-triangle cloth. When a material first needs them they are made from the UVs and grain
 * angles (tc_axes_store), as a new cloth makes them; a reader of the warp of a sheet that stores
 * none gets them made so (tc_tri_warp). Likewise the triangles' own grain angles (tgrain) are
 * stored from the first tc_cloth_set_grain_angles on; none stored reads as NaN everywhere. The warp is the direction of increasing u with v constant, dX/du, as a
 * thread of a pattern piece laid on the UV map runs (garment patterns carry a grain line: it
 * follows the piece wherever it lies on the body); the weft is the in-plane perpendicular (a
 * sheared UV map is taken as orthogonal threads). Rotated by the grain angle about the rest normal
 * (counter-clockwise seen from the side the normal points to): the triangle's own angle
 * (tc_cloth_set_grain_angles) or, where that is NaN, the material's grain_angle. A triangle whose
 * UVs are degenerate (no UV map: all zero) takes the rest X axis projected into its plane (the
 * rest Y axis if its plane is perpendicular to X), then the same rotation.
 *
 * ELASTICITY. Plane-stress orthotropic (Jones, Mechanics of Composite Materials, 2nd ed. 1999,
 * eq. 2.61): Q11 = E1 / (1 - nu12 nu21), Q22 = E2 / (1 - nu12 nu21), Q12 = nu12 E2 / (1 - nu12 nu21),
 * Q66 = G12, with nu21 = nu12 E2 / E1 (the reciprocity of the compliance). Isotropy is E1 = E2 = E,
 * G = E / 2(1 + nu): then Q11 = lambda + 2 mu, Q12 = lambda, Q66 = mu (fem.c's Lame constants).
 *
 * PLASTICITY. Small-strain, additive in the co-rotated frame: eps = eps_e + eps_p, with eps the
 * co-rotational strain sym(R^T F) - I of fem.c. Why additive and not F = Fe Fp: the co-rotational
 * CST is a linear (small strain) model in its rotated frame, where strains add exactly, and the
 * plastic strain then changes only the rest metric the stress is measured from (the rest metric
 * is (I + eps_p)^2 to first order); the rest gradients and areas stay untouched, so the lumped
 * masses (density h area / 3) are exactly conserved and nothing the remesh or the tearing reads
 * about the rest shape moves. eps_p lives in the warp/weft axes (tplast), so a split hands it on
 * (and a change of grain angle turns the set with the threads). Turning plasticity off ignores the
 * set (the original rest shape returns); turning it on again restores it.
 * Yield: Hill's 1948 quadratic criterion in plane stress (R. Hill, Proc. R. Soc. A 193, 281, 1948)
 * with warp and weft yield stresses X, Y and the warp-equivalent stress
 *     sbar^2 = X^2 (s_w^2 / X^2 - s_w s_f / (X Y) + s_f^2 / Y^2 + 3 t^2 / (X Y)),
 * von Mises when X = Y (the through-thickness yield stress of Hill's form is then X, the shear
 * yield X / sqrt 3; for X != Y both are the geometric-mean choices that keep the form convex).
 * Linear proportional hardening: sbar <= X + H kappa, H = hardening * E1, kappa the
 * work-conjugate equivalent plastic strain (sbar dkappa = sigma : deps_p); along the warp a
 * uniaxial stress past yield keeps eps_p = (E eps - X) / (E + H). Associated flow, closest-point
 * return (Simo & Hughes, Computational Inelasticity, 1998, ch. 3): sigma = (I + g X^2 C P)^-1
 * sigma_trial, g >= 0 from a scalar equation solved by safeguarded secant steps. The commit is
 * explicit in time (the solve of a sub-step uses the plastic strain of the sub-step before and
 * the elastic stiffness, which keeps the system positive definite); the stress after a commit is
 * the returned one (the element state is marked stale).
 */
#include "core.h"

#include <math.h>
#include <string.h>

bool tc_material_general(const tc_material *m) { return m->orthotropic || m->plastic; }

void tc_ortho_moduli(const tc_material *m, double Q[4])
{
    const double E1 = m->young, E2 = m->orthotropic ? m->young_weft : m->young;
    const double G = m->orthotropic ? m->shear_modulus : m->young / (2.0 * (1.0 + m->poisson));
    const double nu12 = m->poisson, nu21 = nu12 * E2 / E1, d = 1.0 - nu12 * nu21;
    Q[0] = E1 / d; Q[1] = E2 / d; Q[2] = nu12 * E2 / d; Q[3] = G;
}

/* ---------------- axes ---------------- */

/* The rest frame of tc_tri_rest: t1 along the first edge, t2 = n x t1; n the unit normal. */
static void rest_frame(const tc_cloth *c, int32_t t, double *t1, double *t2, double *n)
{
    const int32_t *T = (const int32_t *)tc_vec_ptr(&c->tri) + 3 * (size_t)t;
    const double *X = tc_vec_ptr(&c->rest);
    double e1[3], e2[3];
    sub3(X + 3 * T[1], X + 3 * T[0], e1); sub3(X + 3 * T[2], X + 3 * T[0], e2);
    cross3(e1, e2, n);
    double l1 = sqrt(dot3(e1, e1)), ln = sqrt(dot3(n, n));
    for (int k = 0; k < 3; k++) { t1[k] = e1[k] / l1; n[k] /= ln; }
    cross3(n, t1, t2);
}

/* The warp's direction (a, b) in triangle t's 2-D rest frame from its UVs, the direction of
 * increasing u with v constant (not normalised); false when the UVs carry no direction: no UV map
 * (all zero), the triangle collapsed in UV space, or values so large that their gradients overflow.
 * Such a triangle's warp is the rest X axis (warp_from_uv), which tc_cloth_warp_fallbacks names. */
static bool uv_warp(const tc_cloth *c, int32_t t, double *a, double *b)
{
    const double *uv = (const double *)tc_vec_ptr(&c->uv) + 6 * (size_t)t, *g = (const double *)tc_vec_ptr(&c->grad) + 4 * (size_t)t;
    /* gradients of u and v in the rest frame; the thread v = const runs along perp(grad v) */
    const double du1 = uv[2] - uv[0], du2 = uv[4] - uv[0], dv1 = uv[3] - uv[1], dv2 = uv[5] - uv[1];
    const double gu[2] = {du1 * g[0] + du2 * g[2], du1 * g[1] + du2 * g[3]};
    const double gv[2] = {dv1 * g[0] + dv2 * g[2], dv1 * g[1] + dv2 * g[3]};
    const double det = gu[0] * gv[1] - gu[1] * gv[0];
    if (!(fabs(det) > TC_UV_DEGENERATE * (gu[0] * gu[0] + gu[1] * gu[1] + gv[0] * gv[0] + gv[1] * gv[1])) || !isfinite(det))
        return false;
    *a = gv[1]; *b = -gv[0];  /* perp(grad v), oriented so that u increases along it */
    if (*a * gu[0] + *b * gu[1] < 0) { *a = -*a; *b = -*b; }
    return true;
}

/* The warp of triangle t from its UVs and grain angle, into w (see the head). */
static void warp_from_uv(const tc_cloth *c, int32_t t, const double *t1, const double *t2, const double *n, double *w)
{
    double a, b;
    if (!uv_warp(c, t, &a, &b)) {
        /* no usable UVs: the rest X axis in the triangle's plane (Y if the plane is normal to X) */
        double ax[3] = {1.0, 0.0, 0.0};
        if (fabs(n[0]) > TC_AXIS_FALLBACK_NX) { ax[0] = 0.0; ax[1] = 1.0; }
        a = dot3(ax, t1); b = dot3(ax, t2);
    }
    const double l = sqrt(a * a + b * b);
    a /= l; b /= l;
    const double own = c->tgrain.len ? ((const double *)tc_vec_ptr(&c->tgrain))[t] : NAN;
    const double phi = isfinite(own) ? own : c->mat.grain_angle, cp = cos(phi), sp = sin(phi);
    const double ra = a * cp - b * sp, rb = a * sp + b * cp;
    for (int k = 0; k < 3; k++) w[k] = ra * t1[k] + rb * t2[k];
}

int32_t tc_cloth_warp_fallbacks(const tc_cloth *c, uint8_t *out)
{
    int32_t count = 0;
    for (int32_t t = 0; t < c->nt; t++) {
        double a, b;
        out[t] = !uv_warp(c, t, &a, &b);
        count += out[t];
    }
    return count;
}

void tc_axes_set(tc_cloth *c, int32_t t, bool from_uv)
{
    if (!tc_axes_stored(c)) return;
    double t1[3], t2[3], n[3];
    rest_frame(c, t, t1, t2, n);
    double *w = (double *)tc_vec_ptr(&c->twarp) + 3 * (size_t)t;
    if (from_uv || !(dot3(w, w) > 0)) warp_from_uv(c, t, t1, t2, n, w);
    double a = dot3(w, t1), b = dot3(w, t2), l = sqrt(a * a + b * b);
    double *ax = (double *)tc_vec_ptr(&c->taxis) + 2 * (size_t)t;
    if (l > 0 && isfinite(l)) { ax[0] = a / l; ax[1] = b / l; }
    else { ax[0] = 1.0; ax[1] = 0.0; }
}

void tc_axes_refresh(tc_cloth *c)
{
    if (!tc_axes_stored(c)) return;
    for (int32_t t = 0; t < c->nt; t++) tc_axes_set(c, t, true);
}

int tc_axes_store(tc_cloth *c)
{
    if (tc_axes_stored(c)) return TC_OK;
    const size_t m = (size_t)c->nt;
    /* fresh blocks: zero, so every warp is unset and made from the UVs, as for a new cloth */
    if (tc_vec_resize(&c->twarp, 3 * m) || tc_vec_resize(&c->taxis, 2 * m)) {
        c->twarp.len = c->taxis.len = 0;
        return TC_ERR_NOMEM;
    }
    for (int32_t t = 0; t < c->nt; t++) tc_axes_set(c, t, false);
    return TC_OK;
}

void tc_tri_warp(const tc_cloth *c, int32_t t, double w[3])
{
    if (tc_axes_stored(c)) {
        memcpy(w, (const double *)tc_vec_ptr(&c->twarp) + 3 * (size_t)t, 3 * sizeof(double));
        return;
    }
    double t1[3], t2[3], n[3];
    rest_frame(c, t, t1, t2, n);
    warp_from_uv(c, t, t1, t2, n, w);
}

int tc_cloth_set_grain_angles(tc_cloth *c, const double *angles, int32_t m)
{
    if (m != c->nt) { tc_set_err(c, "expected %d grain angles (one per triangle), got %d", (int)c->nt, (int)m); return TC_ERR_INPUT; }
    for (int32_t t = 0; t < m; t++)
        if (isinf(angles[t]) || fabs(angles[t]) > TC_GRAIN_ANGLE_MAX) {
            tc_set_err(c, "grain angle of triangle %d must be finite radians within +-%g, or NaN for the material's (got %g)",
                       (int)t, TC_GRAIN_ANGLE_MAX, angles[t]);
            return TC_ERR_INPUT;
        }
    if (!c->tgrain.len && tc_vec_resize(&c->tgrain, (size_t)m)) { tc_set_err(c, "out of memory"); return TC_ERR_NOMEM; }
    memcpy(tc_vec_ptr(&c->tgrain), angles, (size_t)m * sizeof(double));
    tc_axes_refresh(c);
    c->dirty = true;
    return TC_OK;
}

/* ---------------- plasticity ---------------- */

/* Warp-equivalent Hill stress of (s_w, s_f, t) with yield stresses X, Y. */
static double hill(double sw, double sf, double tau, double X, double Y)
{
    const double q = sw * sw / (X * X) - sw * sf / (X * Y) + sf * sf / (Y * Y) + 3.0 * tau * tau / (X * Y);
    return X * sqrt(q > 0 ? q : 0.0);
}

/* sigma(g) = (I + g X^2 C P)^-1 sigma_trial, blockwise: (w, f) 2x2 and the shear alone. */
static void returned(const double Q[4], double X, double Y, double g, const double *tr, double *s)
{
    const double P00 = 1.0 / (X * X), P01 = -0.5 / (X * Y), P11 = 1.0 / (Y * Y), P22 = 3.0 / (X * Y);
    const double k = g * X * X;
    /* M = I + k C P with C = [[Q11, Q12], [Q12, Q22]] on (w, f), Q66 on the engineering shear */
    const double m00 = 1.0 + k * (Q[0] * P00 + Q[2] * P01), m01 = k * (Q[0] * P01 + Q[2] * P11);
    const double m10 = k * (Q[2] * P00 + Q[1] * P01), m11 = 1.0 + k * (Q[2] * P01 + Q[1] * P11);
    const double det = m00 * m11 - m01 * m10;
    s[0] = (m11 * tr[0] - m01 * tr[1]) / det;
    s[1] = (-m10 * tr[0] + m00 * tr[1]) / det;
    s[2] = tr[2] / (1.0 + k * Q[3] * P22);
}

/* Commits the plastic strain of every triangle from the stresses of the last element pass (at the
 * positions of the sub-step just kept). Returns the number of triangles that yielded. */
int32_t tc_plastic_commit(tc_cloth *c)
{
    if (!c->mat.plastic) return 0;
    double Q[4];
    tc_ortho_moduli(&c->mat, Q);
    const double X = c->mat.yield_stress, Y = c->mat.orthotropic ? c->mat.yield_stress_weft : X;
    const double H = c->mat.hardening * c->mat.young;
    const double *sig = tc_vec_ptr(&c->sig), *ax = tc_vec_ptr(&c->taxis);
    double *pl = tc_vec_ptr(&c->tplast);
    int32_t yielded = 0;
    for (int32_t t = 0; t < c->nt; t++) {
        const double *s = sig + 3 * (size_t)t, cs = ax[2 * t], sn = ax[2 * t + 1];
        const double cc = cs * cs, ss = sn * sn, cn = cs * sn;
        const double tr[3] = {cc * s[0] + ss * s[1] + 2.0 * cn * s[2], ss * s[0] + cc * s[1] - 2.0 * cn * s[2],
                              cn * (s[1] - s[0]) + (cc - ss) * s[2]};
        double *p = pl + 4 * (size_t)t;
        const double k0 = p[3];
        double f0 = hill(tr[0], tr[1], tr[2], X, Y) - (X + H * k0);
        if (!(f0 > TC_YIELD_TOLERANCE * X)) continue;
        /* f(g) = sbar(sigma(g)) - (X + H (k0 + g sbar(sigma(g)))), f(0) > 0, f < 0 for large g */
        double sg[3], ga = 0.0, fa = f0, gb = 1.0 / (Q[0] > Q[1] ? Q[0] : Q[1]), fb;
        int it = 0;
        for (;; it++) {
            returned(Q, X, Y, gb, tr, sg);
            double sb = hill(sg[0], sg[1], sg[2], X, Y);
            fb = sb - (X + H * (k0 + gb * sb));
            if (fb < 0 || it > TC_RETURN_MAX_ITERATIONS) break;
            ga = gb; fa = fb; gb *= 4.0;
        }
        /* Illinois false position on [ga, gb]: f(ga) > 0 > f(gb) */
        double g = gb;
        int side = 0;
        for (it = 0; it < TC_RETURN_MAX_ITERATIONS; it++) {
            g = (ga * fb - gb * fa) / (fb - fa);
            returned(Q, X, Y, g, tr, sg);
            double sb = hill(sg[0], sg[1], sg[2], X, Y);
            double fg = sb - (X + H * (k0 + g * sb));
            if (fabs(fg) <= TC_RETURN_TOLERANCE * X) break;
            if (fg > 0) { ga = g; fa = fg; if (side == 1) fb *= 0.5; side = 1; }
            else { gb = g; fb = fg; if (side == -1) fa *= 0.5; side = -1; }
        }
        if (it == TC_RETURN_MAX_ITERATIONS) c->stats.plastic_unconverged++;
        returned(Q, X, Y, g, tr, sg);
        const double sb = hill(sg[0], sg[1], sg[2], X, Y);
        /* deps_p = g X^2 P sigma on (w, f, engineering shear); kappa += g sbar */
        const double dw = g * X * X * (sg[0] / (X * X) - 0.5 * sg[1] / (X * Y));
        const double df = g * X * X * (-0.5 * sg[0] / (X * Y) + sg[1] / (Y * Y));
        const double dgam = g * X * X * 3.0 * sg[2] / (X * Y);
        if (!(isfinite(dw) && isfinite(df) && isfinite(dgam))) continue;  /* never NaN into the state */
        p[0] += dw; p[1] += df; p[2] += 0.5 * dgam; p[3] = k0 + g * sb;
        yielded++;
    }
    if (yielded) c->dirty = true;
    return yielded;
}
