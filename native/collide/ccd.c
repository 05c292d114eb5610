/* ccd.c - continuous (swept) vertex-triangle tests for cloth self-collision, and the state of a
 * vertex-triangle pair at one configuration.
 *
 * Why swept tests beside the rays: the rays of a full detection reach the track range along the
 * vertex normal, and the cloth's own two-ring is never hit (narrow.ring_table). So a layer moving
 * more than the track range in one step, or a crease that folds a vertex onto a triangle of its
 * own two-ring, passes through unseen. Here every point moves linearly over the interval and the
 * earliest time the vertex comes within `gap` of the triangle is found exactly: the vertex is
 * coplanar with the moving triangle at the roots of a cubic (Provot 1997; Bridson et al. 2002),
 * and the distance is checked at those roots and at the interval's ends.
 */
#include "collide.h"

#include <math.h>

static inline void sub3(const double *a, const double *b, double *o) { o[0] = a[0] - b[0]; o[1] = a[1] - b[1]; o[2] = a[2] - b[2]; }
static inline double dot3(const double *a, const double *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
static inline void cross3(const double *a, const double *b, double *o)
{
    o[0] = a[1] * b[2] - a[2] * b[1];
    o[1] = a[2] * b[0] - a[0] * b[2];
    o[2] = a[0] * b[1] - a[1] * b[0];
}

/* Closest point of triangle abc to p (Ericson, Real-Time Collision Detection 5.1.5): its
 * barycentrics w and the squared distance. */
static double closest_on_triangle(const double *p, const double *a, const double *b, const double *c, double w[3])
{
    double ab[3], ac[3], ap[3], bp[3], cp[3];
    sub3(b, a, ab); sub3(c, a, ac); sub3(p, a, ap);
    double d1 = dot3(ab, ap), d2 = dot3(ac, ap);
    if (d1 <= 0 && d2 <= 0) { w[0] = 1; w[1] = w[2] = 0; goto done; }
    sub3(p, b, bp);
    double d3 = dot3(ab, bp), d4 = dot3(ac, bp);
    if (d3 >= 0 && d4 <= d3) { w[1] = 1; w[0] = w[2] = 0; goto done; }
    double vc = d1 * d4 - d3 * d2;
    if (vc <= 0 && d1 >= 0 && d3 <= 0) {
        double t = d1 / (d1 - d3);
        w[0] = 1 - t; w[1] = t; w[2] = 0;
        goto done;
    }
    sub3(p, c, cp);
    double d5 = dot3(ab, cp), d6 = dot3(ac, cp);
    if (d6 >= 0 && d5 <= d6) { w[2] = 1; w[0] = w[1] = 0; goto done; }
    double vb = d5 * d2 - d1 * d6;
    if (vb <= 0 && d2 >= 0 && d6 <= 0) {
        double t = d2 / (d2 - d6);
        w[0] = 1 - t; w[2] = t; w[1] = 0;
        goto done;
    }
    double va = d3 * d6 - d5 * d4;
    if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
        double t = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        w[1] = 1 - t; w[2] = t; w[0] = 0;
        goto done;
    }
    {
        double den = va + vb + vc;
        if (!(fabs(den) > 0)) { w[0] = 1; w[1] = w[2] = 0; goto done; }  /* degenerate: a corner */
        double v = vb / den, u = vc / den;
        w[0] = 1 - v - u; w[1] = v; w[2] = u;
    }
done:;
    double q[3];
    for (int i = 0; i < 3; i++) q[i] = w[0] * a[i] + w[1] * b[i] + w[2] * c[i] - p[i];
    return dot3(q, q);
}

static int pair_points(const double *x, tcc_idx n, const tcc_idx *tri, tcc_idx nt, tcc_idx v, tcc_idx t, tcc_idx k,
                       const double *P[4], tcc_error *err)
{
    if (v < 0 || v >= n) return tcc_fail(err, TCC_ERR_INDEX, "pair %lld: vertex %lld is not in [0, %lld)", (long long)k, (long long)v, (long long)n);
    if (t < 0 || t >= nt) return tcc_fail(err, TCC_ERR_INDEX, "pair %lld: triangle %lld is not in [0, %lld)", (long long)k, (long long)t, (long long)nt);
    P[0] = x + 3 * v;
    for (int c = 0; c < 3; c++) {
        tcc_idx q = tri[3 * t + c];
        if (q < 0 || q >= n) return tcc_fail(err, TCC_ERR_INDEX, "triangle %lld: corner %lld is not in [0, %lld)", (long long)t, (long long)q, (long long)n);
        if (q == v) return tcc_fail(err, TCC_ERR_VALUE, "pair %lld: vertex %lld is a corner of triangle %lld", (long long)k, (long long)v, (long long)t);
        P[c + 1] = x + 3 * q;
    }
    return 0;
}

/* points at time s of the linear motion p0 + s (p1 - p0) */
static void at(const double *const A[4], const double *const B[4], double s, double o[4][3])
{
    for (int j = 0; j < 4; j++)
        for (int i = 0; i < 3; i++) o[j][i] = A[j][i] + s * (B[j][i] - A[j][i]);
}

static double dist2_at(const double *const A[4], const double *const B[4], double s, double w[3])
{
    double o[4][3];
    at(A, B, s, o);
    return closest_on_triangle(o[0], o[1], o[2], o[3], w);
}

static double cubic(const double c[4], double s) { return ((c[3] * s + c[2]) * s + c[1]) * s + c[0]; }

/* The triple product (r0 + s dr) . ((u0 + s du) x (v0 + s dv)) as a cubic c0 + c1 s + c2 s^2 +
 * c3 s^3, and u0 x v0 (its scale at s = 0). */
static void triple_cubic(const double r0[3], const double dr[3], const double u0[3], const double du[3],
                         const double v0[3], const double dv[3], double c[4], double A[3])
{
    double B1[3], B2[3], B[3], C[3];
    cross3(u0, v0, A);
    cross3(u0, dv, B1); cross3(du, v0, B2);
    for (int i = 0; i < 3; i++) B[i] = B1[i] + B2[i];
    cross3(du, dv, C);
    c[0] = dot3(r0, A);
    c[1] = dot3(r0, B) + dot3(dr, A);
    c[2] = dot3(r0, C) + dot3(dr, B);
    c[3] = dot3(dr, C);
}

/* Candidate times in increasing order where a cubic c0 + c1 s + c2 s^2 + c3 s^3 may vanish on
 * [0, 1]: 0, its extrema inside (a touch without a sign change), a root (bisection, 2^-40 of the
 * interval) in each monotone piece with a sign change, and 1. Returns their count (<= 7). */
static int cubic_candidates(const double c[4], double cand[8])
{
    int nc = 0;
    cand[nc++] = 0.0;
    double split[4] = {0.0, 0.0, 0.0, 1.0};
    int ns = 1;
    double qa = 3 * c[3], qb = 2 * c[2], qc = c[1];
    double r[2];
    int nr = 0;
    if (fabs(qa) > 0) {
        double disc = qb * qb - 4 * qa * qc;
        if (disc >= 0) {
            double sq = sqrt(disc);
            double t1 = (-qb - sq) / (2 * qa), t2 = (-qb + sq) / (2 * qa);
            r[nr++] = t1 < t2 ? t1 : t2;
            r[nr++] = t1 < t2 ? t2 : t1;
        }
    } else if (fabs(qb) > 0) {
        r[nr++] = -qc / qb;
    }
    for (int i = 0; i < nr; i++)
        if (r[i] > 0 && r[i] < 1 && r[i] > split[ns - 1]) split[ns++] = r[i];
    split[ns++] = 1.0;
    for (int i = 0; i + 1 < ns; i++) {
        double lo = split[i], hi = split[i + 1];
        double flo = cubic(c, lo), fhi = cubic(c, hi);
        if (i > 0) cand[nc++] = lo;
        if (flo == 0.0 || (flo < 0) != (fhi < 0)) {
            for (int it = 0; it < 40; it++) {
                double mid = 0.5 * (lo + hi), fm = cubic(c, mid);
                if ((fm < 0) == (flo < 0) && fm != 0.0) { lo = mid; flo = fm; } else hi = mid;
            }
            cand[nc++] = hi;
        }
    }
    cand[nc++] = 1.0;
    return nc;
}

/* True when the boxes swept by points 0..split-1 and split..3 over the interval, each grown by
 * gap, are apart: the pair cannot meet. Why: the candidate lists hold every neighbour pair the
 * rays skip (tens of thousands on a small sheet), almost all of them far apart against their
 * motion; this reject is a few compares where the exact distance test costs a square root and
 * the closest-point search. */
static int swept_boxes_apart(const double *const A[4], const double *const B[4], int split, double gap)
{
    for (int i = 0; i < 3; i++) {
        double lo0 = INFINITY, hi0 = -INFINITY, lo1 = INFINITY, hi1 = -INFINITY;
        for (int j = 0; j < 4; j++) {
            double a = A[j][i], b = B[j][i], lo = a < b ? a : b, hi = a < b ? b : a;
            if (j < split) { if (lo < lo0) lo0 = lo; if (hi > hi0) hi0 = hi; }
            else { if (lo < lo1) lo1 = lo; if (hi > hi1) hi1 = hi; }
        }
        if (lo0 > hi1 + gap || lo1 > hi0 + gap) return 1;
    }
    return 0;
}

int tcc_vt_sweep(const double *const A[4], const double *const B[4], double gap, double *toi, double w[3],
                 int8_t *side)
{
    *toi = INFINITY;
    *side = 0;
    w[0] = w[1] = w[2] = 0.0;
    if (swept_boxes_apart(A, B, 1, gap)) return 0;
    /* displacements, and the fastest the vertex can approach the triangle */
    double D[4][3], reach2 = 0.0;
    for (int j = 0; j < 4; j++) sub3(B[j], A[j], D[j]);
    for (int j = 1; j < 4; j++) {
        double r[3];
        sub3(D[0], D[j], r);
        double r2 = dot3(r, r);
        if (r2 > reach2) reach2 = r2;
    }
    double wq[3];
    double d0 = dist2_at(A, B, 0.0, wq);
    double lim = gap + sqrt(reach2);
    if (d0 > lim * lim) return 0;
    /* f(s) = (p - a) . ((b - a) x (c - a)) as a cubic in s */
    double d[3], e1[3], e2[3], dd[3], de1[3], de2[3];
    sub3(A[0], A[1], d); sub3(A[2], A[1], e1); sub3(A[3], A[1], e2);
    sub3(D[0], D[1], dd); sub3(D[2], D[1], de1); sub3(D[3], D[1], de2);
    double c[4], Ac[3];
    triple_cubic(d, dd, e1, de1, e2, de2, c, Ac);
    /* candidate times in increasing order: 0, the cubic's roots and extrema in (0, 1), 1 */
    double cand[8];
    int nc = cubic_candidates(c, cand);
    for (int i = 0; i < nc; i++) {
        double s = cand[i];
        if (i > 0 && s < cand[i - 1]) continue;
        double d2 = (i == 0) ? d0 : dist2_at(A, B, s, wq);
        /* at a root the vertex is on the plane to within the bisection's 2^-40 of the motion */
        double tol = i == 0 ? gap : gap + 1e-9 * sqrt(reach2);
        if (d2 > tol * tol) continue;
        *toi = s;
        w[0] = wq[0]; w[1] = wq[1]; w[2] = wq[2];
        /* the side it came from: the sign of f at the start, else (on the plane at the start)
           opposite to its motion across the plane */
        double f0 = c[0], scale = sqrt(dot3(Ac, Ac)) * (gap > 0 ? gap : 1.0) * 1e-9;
        if (fabs(f0) > scale) *side = f0 > 0 ? 1 : -1;
        else *side = c[1] > 0 ? -1 : 1;
        return 1;
    }
    return 0;
}

int tcc_ccd_vertex_triangle(const double *x0, const double *x1, tcc_idx n, const tcc_idx *tri, tcc_idx nt,
                            const tcc_idx *pv, const tcc_idx *pt, tcc_idx k, double gap_all, const double *pair_gap,
                            double *toi, double *w, int8_t *side, tcc_idx *nhit, tcc_error *err)
{
    tcc_idx hits = 0;
    for (tcc_idx q = 0; q < k; q++) {
        const double gap = (pair_gap && pair_gap[q] < gap_all) ? pair_gap[q] : gap_all;
        const double *A[4], *B[4];
        if (pair_points(x0, n, tri, nt, pv[q], pt[q], q, A, err) || pair_points(x1, n, tri, nt, pv[q], pt[q], q, B, err))
            return err->code;
        hits += tcc_vt_sweep(A, B, gap, toi + q, w + 3 * q, side + q);
    }
    *nhit = hits;
    return TCC_OK;
}

void tcc_vt_state(const double *const P[4], double *sd, double *dist, double w[3], double normal[3])
{
    double e1[3], e2[3], nn[3], r[3];
    sub3(P[2], P[1], e1); sub3(P[3], P[1], e2);
    cross3(e1, e2, nn);
    double l = sqrt(dot3(nn, nn));
    if (l > 0) for (int i = 0; i < 3; i++) nn[i] /= l;
    sub3(P[0], P[1], r);
    *sd = dot3(r, nn);
    *dist = sqrt(closest_on_triangle(P[0], P[1], P[2], P[3], w));
    for (int i = 0; i < 3; i++) normal[i] = nn[i];
}

int tcc_vertex_triangle_state(const double *x, tcc_idx n, const tcc_idx *tri, tcc_idx nt, const tcc_idx *pv,
                              const tcc_idx *pt, tcc_idx k, double *sd, double *dist, double *w, double *normal,
                              tcc_error *err)
{
    for (tcc_idx q = 0; q < k; q++) {
        const double *P[4];
        if (pair_points(x, n, tri, nt, pv[q], pt[q], q, P, err)) return err->code;
        tcc_vt_state(P, sd + q, dist + q, w + 3 * q, normal + 3 * q);
    }
    return TCC_OK;
}

/* Closest points of segments p1 q1 and p2 q2 (Ericson 5.1.9): parameters *s, *t in [0, 1] and
 * the squared distance. */
static double closest_segments(const double *p1, const double *q1, const double *p2, const double *q2, double *s,
                               double *t)
{
    double d1[3], d2[3], r[3];
    sub3(q1, p1, d1); sub3(q2, p2, d2); sub3(p1, p2, r);
    double a = dot3(d1, d1), e = dot3(d2, d2), f = dot3(d2, r);
    const double eps = 1e-30;
    if (a <= eps && e <= eps) { *s = *t = 0; }
    else if (a <= eps) { *s = 0; *t = f / e; *t = *t < 0 ? 0 : (*t > 1 ? 1 : *t); }
    else {
        double c = dot3(d1, r);
        if (e <= eps) { *t = 0; *s = -c / a; *s = *s < 0 ? 0 : (*s > 1 ? 1 : *s); }
        else {
            double b = dot3(d1, d2), den = a * e - b * b;
            *s = den > 0 ? (b * f - c * e) / den : 0.0;
            *s = *s < 0 ? 0 : (*s > 1 ? 1 : *s);
            *t = (b * *s + f) / e;
            if (*t < 0) { *t = 0; *s = -c / a; *s = *s < 0 ? 0 : (*s > 1 ? 1 : *s); }
            else if (*t > 1) { *t = 1; *s = (b - c) / a; *s = *s < 0 ? 0 : (*s > 1 ? 1 : *s); }
        }
    }
    double g[3];
    for (int i = 0; i < 3; i++) g[i] = p1[i] + *s * d1[i] - p2[i] - *t * d2[i];
    return dot3(g, g);
}

static int edge_points(const double *x, tcc_idx n, const tcc_idx *ea, const tcc_idx *eb, tcc_idx q, const double *P[4],
                       tcc_error *err)
{
    tcc_idx id[4] = {ea[2 * q], ea[2 * q + 1], eb[2 * q], eb[2 * q + 1]};
    for (int j = 0; j < 4; j++) {
        if (id[j] < 0 || id[j] >= n)
            return tcc_fail(err, TCC_ERR_INDEX, "edge pair %lld: vertex %lld is not in [0, %lld)", (long long)q, (long long)id[j], (long long)n);
        P[j] = x + 3 * id[j];
    }
    if (id[0] == id[2] || id[0] == id[3] || id[1] == id[2] || id[1] == id[3])
        return tcc_fail(err, TCC_ERR_VALUE, "edge pair %lld: the edges share a vertex", (long long)q);
    return 0;
}

int tcc_ee_sweep(const double *const A[4], const double *const B[4], double gap, double *toi, double st[2],
                 int8_t *side)
{
    *toi = INFINITY;
    *side = 0;
    st[0] = st[1] = 0.0;
    if (swept_boxes_apart(A, B, 2, gap)) return 0;
    double D[4][3], reach = 0.0;
    for (int j = 0; j < 4; j++) sub3(B[j], A[j], D[j]);
    for (int i = 0; i < 2; i++)
        for (int j = 2; j < 4; j++) {
            double r[3];
            sub3(D[i], D[j], r);
            double l = sqrt(dot3(r, r));
            if (l > reach) reach = l;
        }
    double ss, tt;
    double d0 = closest_segments(A[0], A[1], A[2], A[3], &ss, &tt);
    double lim = gap + reach;
    if (d0 > lim * lim) return 0;
    /* f(s) = (c - a) . ((b - a) x (d - c)): zero when the two lines are coplanar */
    double r0[3], u0[3], v0[3], dr[3], du[3], dv[3];
    sub3(A[2], A[0], r0); sub3(A[1], A[0], u0); sub3(A[3], A[2], v0);
    sub3(D[2], D[0], dr); sub3(D[1], D[0], du); sub3(D[3], D[2], dv);
    double c[4], Ac[3];
    triple_cubic(r0, dr, u0, du, v0, dv, c, Ac);
    double cand[8];
    int nc = cubic_candidates(c, cand);
    for (int i = 0; i < nc; i++) {
        double s = cand[i];
        if (i > 0 && s < cand[i - 1]) continue;
        double d2 = d0;
        if (i > 0) {
            double o[4][3];
            at(A, B, s, o);
            d2 = closest_segments(o[0], o[1], o[2], o[3], &ss, &tt);
        }
        double tol = i == 0 ? gap : gap + 1e-9 * reach;
        if (d2 > tol * tol) continue;
        *toi = s;
        st[0] = ss; st[1] = tt;
        double f0 = c[0], scale = sqrt(dot3(Ac, Ac)) * (gap > 0 ? gap : 1.0) * 1e-9;
        if (fabs(f0) > scale) *side = f0 > 0 ? -1 : 1;  /* +1: ab on the side n = u x v points to */
        else *side = c[1] > 0 ? 1 : -1;
        return 1;
    }
    return 0;
}

int tcc_ccd_edge_edge(const double *x0, const double *x1, tcc_idx n, const tcc_idx *ea, const tcc_idx *eb, tcc_idx k,
                      double gap_all, const double *pair_gap, double *toi, double *st, int8_t *side, tcc_idx *nhit,
                      tcc_error *err)
{
    tcc_idx hits = 0;
    for (tcc_idx q = 0; q < k; q++) {
        const double gap = (pair_gap && pair_gap[q] < gap_all) ? pair_gap[q] : gap_all;
        const double *A[4], *B[4];
        if (edge_points(x0, n, ea, eb, q, A, err) || edge_points(x1, n, ea, eb, q, B, err)) return err->code;
        hits += tcc_ee_sweep(A, B, gap, toi + q, st + 2 * q, side + q);
    }
    *nhit = hits;
    return TCC_OK;
}

void tcc_ee_state(const double *const P[4], double *sd, double *dist, double st[2], double normal[3])
{
    double s, t, u[3], v[3], nn[3], g[3];
    *dist = sqrt(closest_segments(P[0], P[1], P[2], P[3], &s, &t));
    st[0] = s; st[1] = t;
    sub3(P[1], P[0], u); sub3(P[3], P[2], v);
    cross3(u, v, nn);
    double l = sqrt(dot3(nn, nn));
    if (l > 0) for (int i = 0; i < 3; i++) nn[i] /= l;
    /* signed distance of edge ab's line from edge cd's along n (the lines' common normal) */
    sub3(P[0], P[2], g);
    *sd = dot3(g, nn);
    for (int i = 0; i < 3; i++) normal[i] = nn[i];
}

int tcc_edge_edge_state(const double *x, tcc_idx n, const tcc_idx *ea, const tcc_idx *eb, tcc_idx k, double *sd,
                        double *dist, double *st, double *normal, tcc_error *err)
{
    for (tcc_idx q = 0; q < k; q++) {
        const double *P[4];
        if (edge_points(x, n, ea, eb, q, P, err)) return err->code;
        tcc_ee_state(P, sd + q, dist + q, st + 2 * q, normal + 3 * q);
    }
    return TCC_OK;
}

double tcc_pair_distance2(const double *const P[4], int split)
{
    double w[3], s, t;
    return split == 1 ? closest_on_triangle(P[0], P[1], P[2], P[3], w) : closest_segments(P[0], P[1], P[2], P[3], &s, &t);
}
