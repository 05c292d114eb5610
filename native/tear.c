/* tear.c - stress-driven tearing with a snapping remesh (Le Gouis et al. 2017, section V).
 *
 * Where: per vertex, the area-weighted average of its triangles' stress tensors, projected on the
 * vertex tangent plane; its largest eigenvalue against tear_stress * strength(v). Until a tear
 * runs, every vertex is examined each step (the highest over the threshold starts the tear); while
 * tears run, only their tips are, plus one slice of 1/scan_period of the other vertices per step,
 * so a second tear elsewhere still starts within scan_period steps at a flat, small cost.
 *
 * Which way: orthogonal to the principal direction, in the tangent plane at the tip. The segment
 * goes from the tip through the triangle whose corner holds that direction to the opposite edge;
 * it snaps to an end vertex of that edge when the path passes within snap_tolerance * (edge length)
 * of it (or when a split would make a triangle with an angle below min_angle_deg), otherwise the
 * edge is split where the path meets it.
 * So each cut adds at most one vertex and two triangles, and the path follows the stress instead
 * of the mesh edges.
 *
 * Separation: the cut edges stop connecting their two triangles; every vertex whose triangles then
 * form more than one fan is duplicated, one copy per fan. A tear from an interior vertex cuts two
 * segments (both ways) before separating, since one slit with two interior ends has no indexed-mesh
 * representation. A tip whose target lies on a boundary (the rim, or another tear) ends there.
 *
 * What a vertex carries comes along: rest position, velocity, groups, tear strength, pin and handle
 * membership (split vertices interpolate and join a handle only when both parents belong to it);
 * per-corner UVs are interpolated for split triangles and kept for duplicated vertices (a UV seam).
 * Masses are lumped from rest areas, which splits preserve exactly, so total mass is conserved.
 */
#include "core.h"

#include <math.h>
#include <string.h>


/* ---------------- fans ---------------- */

static bool in_set(const int32_t *set, int n, int32_t p)
{
    for (int i = 0; i < n; i++)
        if (set[i] == p) return true;
    return false;
}

/* Triangles around u reachable from `start` without crossing a boundary or a pair in `cut`.
 * Returns the count, or -1 if the fan exceeds cap. *closed tells whether the fan wraps around. */
static int fan_walk(const tc_cloth *c, int32_t u, int32_t start, const int32_t *cut, int ncut, int32_t *out, int cap,
                    bool *closed)
{
    const int32_t *TP = tc_vec_ptr(&c->tpair);
    int n = 0;
    out[n++] = start;
    *closed = false;
    int32_t t = start;
    for (;;) {
        int k = (tc_tri_local(c, t, u) + 2) % 3;
        if (in_set(cut, ncut, TP[3 * t + k])) break;
        int32_t nb = tc_nbr(c, t, k);
        if (nb < 0) break;
        if (nb == start) { *closed = true; return n; }
        if (n >= cap) return -1;
        out[n++] = t = nb;
    }
    t = start;
    for (;;) {
        int k = (tc_tri_local(c, t, u) + 1) % 3;
        if (in_set(cut, ncut, TP[3 * t + k])) break;
        int32_t nb = tc_nbr(c, t, k);
        if (nb < 0 || nb == start) break;
        if (n >= cap) return -1;
        out[n++] = t = nb;
    }
    return n;
}

static bool is_boundary_vertex(const tc_cloth *c, int32_t u)
{
    int32_t fan[TC_FAN_MAX];
    bool closed;
    int n = fan_walk(c, u, ((int32_t *)tc_vec_ptr(&c->vtri))[u], NULL, 0, fan, TC_FAN_MAX, &closed);
    return n < 0 || !closed;
}

/* ---------------- stress at vertices ---------------- */

static void tangent_basis(const double *n, double *t1, double *t2)
{
    double a[3] = {fabs(n[0]) < TC_TANGENT_AXIS_LIMIT ? 1.0 : 0.0, fabs(n[0]) < TC_TANGENT_AXIS_LIMIT ? 0.0 : 1.0, 0.0};
    cross3(n, a, t1);
    double l = sqrt(dot3(t1, t1));
    t1[0] /= l; t1[1] /= l; t1[2] /= l;
    cross3(n, t1, t2);
}

/* Largest eigenvalue and its direction of the 3x3 stress S restricted to the plane normal to n. */
static double principal_in_plane(const double *S, const double *n, double *dir)
{
    double t1[3], t2[3];
    tangent_basis(n, t1, t2);
    double St1[3], St2[3];
    for (int i = 0; i < 3; i++) {
        St1[i] = S[3 * i] * t1[0] + S[3 * i + 1] * t1[1] + S[3 * i + 2] * t1[2];
        St2[i] = S[3 * i] * t2[0] + S[3 * i + 1] * t2[1] + S[3 * i + 2] * t2[2];
    }
    double a = dot3(t1, St1), b = 0.5 * (dot3(t1, St2) + dot3(t2, St1)), d = dot3(t2, St2);
    double mean = 0.5 * (a + d), h = 0.5 * (a - d), r = sqrt(h * h + b * b);
    double th = 0.5 * atan2(2.0 * b, a - d), ct = cos(th), st = sin(th);
    for (int k = 0; k < 3; k++) dir[k] = t1[k] * ct + t2[k] * st;
    return mean + r;
}

static void tri_normal(const tc_cloth *c, int32_t t, double *n)
{
    const int32_t *T = (const int32_t *)tc_vec_ptr(&c->tri) + 3 * (size_t)t;
    const double *x = tc_vec_ptr(&c->x);
    double e1[3], e2[3];
    sub3(x + 3 * T[1], x + 3 * T[0], e1);
    sub3(x + 3 * T[2], x + 3 * T[0], e2);
    cross3(e1, e2, n);
}

/* Stress of one vertex by walking its fan (used for tips and scan slices). */
static double vertex_stress(tc_cloth *c, int32_t v, double *dir, double *normal)
{
    int32_t fan[TC_FAN_MAX];
    bool closed;
    int nf = fan_walk(c, v, ((int32_t *)tc_vec_ptr(&c->vtri))[v], NULL, 0, fan, TC_FAN_MAX, &closed);
    if (nf <= 0) return 0.0;
    const double *S3 = tc_vec_ptr(&c->stress), *A = tc_vec_ptr(&c->area);
    double S[9] = {0}, n[3] = {0}, wsum = 0.0;
    for (int i = 0; i < nf; i++) {
        int32_t t = fan[i];
        double w = A[t], tn[3];
        for (int q = 0; q < 9; q++) S[q] += w * S3[9 * t + q];
        tri_normal(c, t, tn);
        n[0] += tn[0]; n[1] += tn[1]; n[2] += tn[2];
        wsum += w;
    }
    double ln = sqrt(dot3(n, n));
    if (!(ln > 0) || !(wsum > 0)) return 0.0;
    for (int q = 0; q < 3; q++) n[q] /= ln;
    for (int q = 0; q < 9; q++) S[q] /= wsum;
    if (normal) memcpy(normal, n, sizeof n);
    return principal_in_plane(S, n, dir);
}

int tc_cloth_vertex_stress(tc_cloth *c, int32_t v, double *value, double direction[3])
{
    if (v < 0 || v >= c->nv) { tc_set_err(c, "vertex %d is outside [0, %d)", (int)v, (int)c->nv); return TC_ERR_INPUT; }
    if (c->dirty) { tc_element_pass(c, tc_vec_ptr(&c->x)); }
    *value = vertex_stress(c, v, direction, NULL);
    return TC_OK;
}

/* ---------------- local remeshing primitives ---------------- */

static void tri_unlink(tc_cloth *c, int32_t t)
{
    for (int k = 0; k < 3; k++) {
        int32_t p = ((int32_t *)tc_vec_ptr(&c->tpair))[3 * t + k];
        int32_t *pt = (int32_t *)tc_vec_ptr(&c->ptris) + 2 * (size_t)p;
        if (pt[0] == t) { pt[0] = pt[1]; pt[1] = -1; }
        else if (pt[1] == t) pt[1] = -1;
        tc_pair_release(c, p);
    }
}

static int tri_link(tc_cloth *c, int32_t t)
{
    for (int k = 0; k < 3; k++) {
        const int32_t *T = (const int32_t *)tc_vec_ptr(&c->tri) + 3 * (size_t)t;
        int32_t p = tc_pair_acquire(c, T[(k + 1) % 3], T[(k + 2) % 3]);
        if (p < 0) return TC_ERR_NOMEM;
        int32_t *pt = (int32_t *)tc_vec_ptr(&c->ptris) + 2 * (size_t)p;
        if (pt[0] < 0) pt[0] = t;
        else if (pt[1] < 0) pt[1] = t;
        else { tc_set_err(c, "internal: edge (%d, %d) would get a third triangle", (int)T[(k + 1) % 3], (int)T[(k + 2) % 3]); return TC_ERR_INPUT; }
        ((int32_t *)tc_vec_ptr(&c->tpair))[3 * t + k] = p;
    }
    int32_t *vt = tc_vec_ptr(&c->vtri);
    const int32_t *T = (const int32_t *)tc_vec_ptr(&c->tri) + 3 * (size_t)t;
    for (int k = 0; k < 3; k++) vt[T[k]] = t;
    return TC_OK;
}

static void stencils_off(tc_cloth *c, const int32_t *tris, int n)
{
    for (int i = 0; i < n; i++)
        for (int k = 0; k < 3; k++) tc_stencil_remove(c, ((int32_t *)tc_vec_ptr(&c->tpair))[3 * tris[i] + k]);
}

static int stencils_on(tc_cloth *c, const int32_t *tris, int n)
{
    for (int i = 0; i < n; i++)
        for (int k = 0; k < 3; k++)
            if (tc_stencil_add(c, ((int32_t *)tc_vec_ptr(&c->tpair))[3 * tris[i] + k])) return TC_ERR_NOMEM;
    return TC_OK;
}

/* New vertex = (1 - s) a + s b (b < 0: a copy of a). */
static int32_t new_vertex(tc_cloth *c, int32_t a, int32_t b, double s)
{
    int32_t v = c->nv;
    if (tc_reserve_vertices(c, v + 1)) return -1;
    c->nv = v + 1;
    double wa = b < 0 ? 1.0 : 1.0 - s, wb = b < 0 ? 0.0 : s;
    int32_t bb = b < 0 ? a : b;
    tc_vec *lerp3[] = {&c->x, &c->v, &c->rest, &c->x0, &c->v0, &c->sdv};
    for (int i = 0; i < 6; i++) {
        double *p = tc_vec_ptr(lerp3[i]);
        for (int k = 0; k < 3; k++) p[3 * v + k] = wa * p[3 * a + k] + wb * p[3 * bb + k];
    }
    double *g = tc_vec_ptr(&c->groups);
    for (int k = 0; k < c->ng; k++) g[(size_t)v * c->ng + k] = wa * g[(size_t)a * c->ng + k] + wb * g[(size_t)bb * c->ng + k];
    double *st = tc_vec_ptr(&c->strength);
    st[v] = wa * st[a] + wb * st[bb];
    int8_t *pin = tc_vec_ptr(&c->vpin);
    pin[v] = (int8_t)(pin[a] && pin[bb]);
    int32_t *vh = tc_vec_ptr(&c->vhandle);
    vh[v] = -1;
    if (vh[a] >= 0 && vh[a] == vh[bb]) {
        /* grasp position interpolated from the parents' grasp positions */
        tc_handle *H = &c->handles[vh[a]];
        double ga[3] = {0}, gb[3] = {0};
        for (int32_t i = 0; i < H->count; i++) {
            if (H->verts[i] == a) memcpy(ga, H->grasp + 3 * i, sizeof ga);
            if (H->verts[i] == bb) memcpy(gb, H->grasp + 3 * i, sizeof gb);
        }
        double gp[3] = {wa * ga[0] + wb * gb[0], wa * ga[1] + wb * gb[1], wa * ga[2] + wb * gb[2]};
        if (tc_handle_add_member(c, vh[a], v, gp)) return -1;
    }
    if (tc_event_new_vertex(c, v, a, b, wa)) return -1;
    return v;
}

/* Would splitting edge (a, b) at s leave every new triangle's angles above the minimum? */
static bool split_ok(tc_cloth *c, int32_t a, int32_t b, double s)
{
    int32_t e = tc_pair_find(c, a, b);
    const int32_t *pt = (const int32_t *)tc_vec_ptr(&c->ptris) + 2 * (size_t)e;
    const double *X = tc_vec_ptr(&c->rest);
    double minang = c->tear.min_angle_deg * TC_PI / 180.0;
    /* a temporary rest point for the angle test */
    double P[3];
    for (int k = 0; k < 3; k++) P[k] = (1 - s) * X[3 * a + k] + s * X[3 * b + k];
    for (int side = 0; side < 2; side++) {
        int32_t t = pt[side];
        if (t < 0) continue;
        const int32_t *T = (const int32_t *)tc_vec_ptr(&c->tri) + 3 * (size_t)t;
        int32_t o = T[0] != a && T[0] != b ? T[0] : T[1] != a && T[1] != b ? T[1] : T[2];
        const double *O = X + 3 * o;
        const double *ends[2] = {X + 3 * a, X + 3 * b};
        for (int j = 0; j < 2; j++) {
            const double *q[3] = {O, ends[j], P};
            for (int i = 0; i < 3; i++) {
                double u[3], w[3], cr[3];
                sub3(q[(i + 1) % 3], q[i], u); sub3(q[(i + 2) % 3], q[i], w); cross3(u, w, cr);
                if (atan2(sqrt(dot3(cr, cr)), dot3(u, w)) < minang) return false;
            }
        }
    }
    return true;
}

/* Splits edge (a, b) at parameter s from a; returns the new vertex or -1. */
static int32_t split_edge(tc_cloth *c, int32_t a, int32_t b, double s)
{
    int32_t e = tc_pair_find(c, a, b);
    if (e < 0) return -1;
    int32_t side[2] = {((int32_t *)tc_vec_ptr(&c->ptris))[2 * e], ((int32_t *)tc_vec_ptr(&c->ptris))[2 * e + 1]};
    int32_t olds[2];
    int nold = 0;
    for (int i = 0; i < 2; i++) if (side[i] >= 0) olds[nold++] = side[i];
    /* stencils of every edge of the triangles that change: their opposite vertices change */
    stencils_off(c, olds, nold);
    int32_t p = new_vertex(c, a, b, s);
    if (p < 0) return -1;
    int32_t touched[4];
    int nt = 0;
    for (int i = 0; i < nold; i++) {
        int32_t t = olds[i];
        tri_unlink(c, t);
        int32_t *T = (int32_t *)tc_vec_ptr(&c->tri) + 3 * (size_t)t;
        int k;  /* local index of the vertex opposite edge (a, b) */
        for (k = 0; k < 3; k++) if (T[k] != a && T[k] != b) break;
        int32_t o = T[k], e0 = T[(k + 1) % 3], e1 = T[(k + 2) % 3];
        double s0 = e0 == a ? s : 1.0 - s;  /* parameter of p from e0 */
        double *UV = (double *)tc_vec_ptr(&c->uv) + 6 * (size_t)t;
        double uo[2] = {UV[2 * k], UV[2 * k + 1]};
        double u0[2] = {UV[2 * ((k + 1) % 3)], UV[2 * ((k + 1) % 3) + 1]};
        double u1[2] = {UV[2 * ((k + 2) % 3)], UV[2 * ((k + 2) % 3) + 1]};
        double up[2] = {(1 - s0) * u0[0] + s0 * u1[0], (1 - s0) * u0[1] + s0 * u1[1]};
        /* t becomes (o, e0, p); a new triangle (o, p, e1) */
        int32_t t2 = c->nt;
        if (tc_reserve_triangles(c, t2 + 1)) return -1;
        c->nt = t2 + 1;
        T = (int32_t *)tc_vec_ptr(&c->tri) + 3 * (size_t)t;
        UV = (double *)tc_vec_ptr(&c->uv) + 6 * (size_t)t;
        T[0] = o; T[1] = e0; T[2] = p;
        UV[0] = uo[0]; UV[1] = uo[1]; UV[2] = u0[0]; UV[3] = u0[1]; UV[4] = up[0]; UV[5] = up[1];
        int32_t *T2 = (int32_t *)tc_vec_ptr(&c->tri) + 3 * (size_t)t2;
        double *UV2 = (double *)tc_vec_ptr(&c->uv) + 6 * (size_t)t2;
        T2[0] = o; T2[1] = p; T2[2] = e1;
        UV2[0] = uo[0]; UV2[1] = uo[1]; UV2[2] = up[0]; UV2[3] = up[1]; UV2[4] = u1[0]; UV2[5] = u1[1];
        /* the new element inherits the rotation so the first force evaluation starts from it */
        double *R = tc_vec_ptr(&c->rot);
        memcpy(R + 6 * (size_t)t2, R + 6 * (size_t)t, 6 * sizeof(double));
        char msg[8];
        if (tc_tri_rest(c, t, msg, sizeof msg) || tc_tri_rest(c, t2, msg, sizeof msg)) {
            tc_set_err(c, "internal: a split produced a degenerate triangle");
            return -1;
        }
        if (tc_event_changed_triangle(c, t) || tc_event_new_triangle(c, t2)) return -1;
        touched[nt++] = t;
        touched[nt++] = t2;
    }
    for (int i = 0; i < nt; i++)
        if (tri_link(c, touched[i])) return -1;
    if (stencils_on(c, touched, nt)) return -1;
    return p;
}

/* Picks the segment from tip v along dir: the triangle whose corner at v holds dir, the point where
 * the segment meets the opposite edge, then snap or split. Returns the far vertex (or -1) and the
 * pair to cut in *pair. `avoid` lists pairs already in the cut so the path never folds back. */
static int32_t prepare_segment(tc_cloth *c, int32_t v, const double *dir, const int32_t *avoid, int navoid, int32_t *pair)
{
    int32_t fan[TC_FAN_MAX];
    bool closed;
    int nf = fan_walk(c, v, ((int32_t *)tc_vec_ptr(&c->vtri))[v], NULL, 0, fan, TC_FAN_MAX, &closed);
    if (nf <= 0) return -1;
    const double *x = tc_vec_ptr(&c->x);
    int32_t best_t = -1;
    double best_score = -1e300, best_s = 0.0;
    int32_t best_a = -1, best_b = -1;
    for (int i = 0; i < nf; i++) {
        int32_t t = fan[i];
        const int32_t *T = (const int32_t *)tc_vec_ptr(&c->tri) + 3 * (size_t)t;
        int l = tc_tri_local(c, t, v);
        int32_t a = T[(l + 1) % 3], b = T[(l + 2) % 3];
        double ea[3], eb[3], n[3];
        sub3(x + 3 * a, x + 3 * v, ea);
        sub3(x + 3 * b, x + 3 * v, eb);
        cross3(ea, eb, n);
        double ln = sqrt(dot3(n, n));
        if (!(ln > 0)) continue;
        for (int k = 0; k < 3; k++) n[k] /= ln;
        double d[3];  /* dir projected on this triangle's plane */
        double dn = dot3(dir, n);
        for (int k = 0; k < 3; k++) d[k] = dir[k] - dn * n[k];
        double la = sqrt(dot3(ea, ea)), lb = sqrt(dot3(eb, eb)), ld = sqrt(dot3(d, d));
        if (!(ld > 0)) continue;
        double ca[3], cb[3];
        cross3(ea, d, ca); cross3(d, eb, cb);
        double sa = dot3(ca, n) / (la * ld), sb = dot3(cb, n) / (lb * ld);
        /* inside the corner when both are >= 0; the best fit maximises the smaller one */
        double score = sa < sb ? sa : sb;
        if (dot3(d, ea) < 0 && dot3(d, eb) < 0) score -= TC_CORNER_BACKWARDS_PENALTY;  /* pointing backwards */
        if (score > best_score) {
            double eab[3] = {eb[0] - ea[0], eb[1] - ea[1], eb[2] - ea[2]}, cab[3];
            cross3(eab, d, cab);
            double den = dot3(cab, n);
            double s = fabs(den) > TC_TINY ? -dot3(ca, n) / den : TC_PARALLEL_SPLIT;
            if (s < 0) s = 0;
            if (s > 1) s = 1;
            best_score = score; best_t = t; best_s = s; best_a = a; best_b = b;
        }
    }
    if (best_t < 0 || best_score < TC_CORNER_MIN_SCORE) return -1;
    /* Snap when the path passes within snap_tolerance * |ab| of a or b (distance measured across the
       path, as WWD14's snapping does): the cut then follows an existing edge, adding nothing. */
    double tol = c->mat.snap_tolerance;
    double ab[3], dl = sqrt(dot3(dir, dir));
    sub3(x + 3 * best_b, x + 3 * best_a, ab);
    double lab = sqrt(dot3(ab, ab)), dperp[2];
    int32_t ends[2] = {best_a, best_b};
    for (int i = 0; i < 2; i++) {
        double e[3], cr[3];
        sub3(x + 3 * ends[i], x + 3 * v, e);
        cross3(e, dir, cr);
        dperp[i] = sqrt(dot3(cr, cr)) / dl;
    }
    int32_t cand[2];
    if (dperp[0] <= dperp[1]) { cand[0] = best_a; cand[1] = best_b; }
    else { cand[0] = best_b; cand[1] = best_a; }
    double dmin = dperp[0] < dperp[1] ? dperp[0] : dperp[1];
    if (dmin >= tol * lab && split_ok(c, best_a, best_b, best_s)) {
        /* a split edge on the boundary is fine: the tear then ends on the rim at the new vertex */
        int32_t w = split_edge(c, best_a, best_b, best_s);
        if (w < 0) return -1;
        *pair = tc_pair_find(c, v, w);
        return w;
    }
    for (int i = 0; i < 2; i++) {
        int32_t p = tc_pair_find(c, v, cand[i]);
        if (p < 0 || in_set(avoid, navoid, p)) continue;
        const int32_t *pt = (const int32_t *)tc_vec_ptr(&c->ptris) + 2 * (size_t)p;
        if (pt[0] < 0 || pt[1] < 0) continue;  /* already a boundary: nothing to cut */
        /* the farther end only when it is not much off the path (within 45 degrees) */
        if (i == 1) {
            double e[3];
            sub3(x + 3 * cand[i], x + 3 * v, e);
            if (dot3(e, dir) <= TC_FAR_END_COS * sqrt(dot3(e, e)) * dl) continue;
        }
        *pair = p;
        return cand[i];
    }
    return -1;
}

/* Separates the mesh along the pairs in `cut`: every listed vertex whose triangles fall into more
 * than one fan gets a copy per extra fan. Returns TC_OK; *dup_mask bit i set when verts[i] split. */
static int separate(tc_cloth *c, const int32_t *cut, int ncut, const int32_t *verts, int nverts, unsigned *dup_mask)
{
    /* every vertex's whole fan is listed before anything changes: once one endpoint is duplicated,
       the cut edge is a real boundary and a walk could no longer reach the far side */
    int32_t all[4][TC_FAN_MAX], fan[TC_FAN_MAX], affected[4 * TC_FAN_MAX] = {0};
    int nall[4], naff = 0;
    bool closed;
    *dup_mask = 0;
    if (nverts > 4) return TC_ERR_INPUT;
    for (int i = 0; i < nverts; i++) {
        nall[i] = fan_walk(c, verts[i], ((int32_t *)tc_vec_ptr(&c->vtri))[verts[i]], NULL, 0, all[i], TC_FAN_MAX, &closed);
        if (nall[i] <= 0) return TC_ERR_INPUT;
        for (int j = 0; j < nall[i]; j++)
            if (!in_set(affected, naff, all[i][j])) affected[naff++] = all[i][j];
    }
    stencils_off(c, affected, naff);
    for (int i = 0; i < nverts; i++) {
        int32_t u = verts[i];
        int n = nall[i];
        bool assigned[TC_FAN_MAX] = {false};
        int nf = fan_walk(c, u, all[i][0], cut, ncut, fan, TC_FAN_MAX, &closed);
        if (nf <= 0) return TC_ERR_INPUT;
        for (int j = 0; j < n; j++) assigned[j] = in_set(fan, nf, all[i][j]);
        for (int j = 0; j < n; j++) {
            if (assigned[j]) continue;
            int m = fan_walk(c, u, all[i][j], cut, ncut, fan, TC_FAN_MAX, &closed);
            if (m <= 0) return TC_ERR_INPUT;
            int32_t u2 = new_vertex(c, u, -1, 0.0);
            if (u2 < 0) return TC_ERR_NOMEM;
            *dup_mask |= 1u << i;
            for (int q = 0; q < m; q++) {
                int32_t t = fan[q];
                for (int r = 0; r < n; r++) if (all[i][r] == t) assigned[r] = true;
                tri_unlink(c, t);
                int32_t *T = (int32_t *)tc_vec_ptr(&c->tri) + 3 * (size_t)t;
                for (int k = 0; k < 3; k++) if (T[k] == u) T[k] = u2;
                if (tri_link(c, t) || tc_event_changed_triangle(c, t)) return TC_ERR_NOMEM;
            }
        }
        /* u keeps the first fan; vtri must point into it */
        ((int32_t *)tc_vec_ptr(&c->vtri))[u] = all[i][0];
    }
    if (stencils_on(c, affected, naff)) return TC_ERR_NOMEM;
    tc_masses_update(c);
    c->dirty = true;
    return TC_OK;
}

/* ---------------- tears ---------------- */

static int tip_add(tc_cloth *c, int32_t v, const double *dir)
{
    if (tc_vec_push_i32(&c->tips, v)) return TC_ERR_NOMEM;
    if (tc_vec_resize(&c->tipdir, 3 * c->tips.len)) return TC_ERR_NOMEM;
    memcpy((double *)tc_vec_ptr(&c->tipdir) + 3 * (c->tips.len - 1), dir, 3 * sizeof(double));
    return TC_OK;
}

static void tip_remove(tc_cloth *c, size_t i)
{
    int32_t *tp = tc_vec_ptr(&c->tips);
    double *td = tc_vec_ptr(&c->tipdir);
    size_t last = c->tips.len - 1;
    tp[i] = tp[last];
    memcpy(td + 3 * i, td + 3 * last, 3 * sizeof(double));
    c->tips.len--;
    c->tipdir.len = 3 * c->tips.len;
}

static void unit_dir(const tc_cloth *c, int32_t a, int32_t b, double *d)
{
    const double *x = tc_vec_ptr(&c->x);
    sub3(x + 3 * b, x + 3 * a, d);
    double l = sqrt(dot3(d, d));
    if (l > 0) { d[0] /= l; d[1] /= l; d[2] /= l; }
}

/* Cuts one segment from an existing tip; updates or ends the tip. Returns 1 if a cut was made. */
static int advance_tip(tc_cloth *c, size_t ti, const double *dir)
{
    int32_t v = ((int32_t *)tc_vec_ptr(&c->tips))[ti];
    int32_t pair = -1;
    int32_t w = prepare_segment(c, v, dir, NULL, 0, &pair);
    if (w < 0 || pair < 0) { tip_remove(c, ti); return 0; }
    bool w_boundary = is_boundary_vertex(c, w);
    int32_t verts[2] = {v, w};
    unsigned dup;
    if (separate(c, &pair, 1, verts, 2, &dup)) { tip_remove(c, ti); return 0; }
    c->stats.cuts++;
    double d[3];
    unit_dir(c, v, w, d);
    if (w_boundary || (dup & 2u)) tip_remove(c, ti);
    else {
        ((int32_t *)tc_vec_ptr(&c->tips))[ti] = w;
        memcpy((double *)tc_vec_ptr(&c->tipdir) + 3 * ti, d, sizeof d);
    }
    return 1;
}

/* Starts a tear at v along +-dir (both ways from an interior vertex, inward from a boundary one). */
static int start_tear(tc_cloth *c, int32_t v, const double *dir, bool one_way)
{
    double back[3] = {-dir[0], -dir[1], -dir[2]};
    if (is_boundary_vertex(c, v)) {
        int32_t pair = -1, w = prepare_segment(c, v, dir, NULL, 0, &pair);
        const double *used = dir;
        if ((w < 0 || pair < 0) && !one_way) { w = prepare_segment(c, v, back, NULL, 0, &pair); used = back; }
        if (w < 0 || pair < 0) return 0;
        bool wb = is_boundary_vertex(c, w);
        int32_t verts[2] = {v, w};
        unsigned dup;
        if (separate(c, &pair, 1, verts, 2, &dup)) return 0;
        c->stats.cuts++;
        c->stats.tears_started++;
        double d[3];
        unit_dir(c, v, w, d);
        (void)used;
        if (!wb && !(dup & 2u)) return tip_add(c, w, d) ? -1 : 1;
        return 1;
    }
    int32_t p1 = -1, p2 = -1;
    int32_t w1 = prepare_segment(c, v, dir, NULL, 0, &p1);
    if (w1 < 0 || p1 < 0) return 0;
    int32_t w2;
    const int32_t *from2 = &v;
    double d1[3];
    unit_dir(c, v, w1, d1);
    if (one_way) {  /* scripted: continue forward from w1 so the slit has two edges */
        w2 = prepare_segment(c, w1, d1, &p1, 1, &p2);
        from2 = &w1;
    } else {
        w2 = prepare_segment(c, v, back, &p1, 1, &p2);
    }
    if (w2 < 0 || p2 < 0 || p2 == p1) return 0;
    bool b1 = is_boundary_vertex(c, w1), b2 = is_boundary_vertex(c, w2);
    int32_t cut[2] = {p1, p2};
    int32_t verts[3] = {v, w1, w2};
    unsigned dup;
    if (separate(c, cut, 2, verts, 3, &dup)) return 0;
    c->stats.cuts += 2;
    c->stats.tears_started++;
    double d2[3];
    unit_dir(c, *from2, w2, d2);
    if (!one_way && !b1 && !(dup & 2u)) if (tip_add(c, w1, d1)) return -1;
    if (!b2 && !(dup & 4u)) if (tip_add(c, w2, d2)) return -1;
    return 1;
}

static double ratio_of(const tc_cloth *c, int32_t v, double sigma)
{
    return sigma / (c->mat.tear_stress * ((const double *)tc_vec_ptr(&c->strength))[v]);
}

/* Grasped and pinned vertices never start a tear: their stress is the clamp's, not the cloth's. */
static bool held(const tc_cloth *c, int32_t v)
{
    return ((const int8_t *)tc_vec_ptr(&c->vpin))[v] || ((const int32_t *)tc_vec_ptr(&c->vhandle))[v] >= 0;
}

typedef struct { double ratio; int32_t v; double dir[3]; } candidate;

static void cand_push(candidate *cs, int *n, double r, int32_t v, const double *dir)
{
    int i = *n < TC_TEAR_CANDIDATES ? (*n)++ : TC_TEAR_CANDIDATES - 1;
    if (i == TC_TEAR_CANDIDATES - 1 && *n == TC_TEAR_CANDIDATES && cs[i].ratio >= r && cs[i].v >= 0) return;
    cs[i].ratio = r; cs[i].v = v; memcpy(cs[i].dir, dir, sizeof cs[i].dir);
    for (; i > 0 && cs[i].ratio > cs[i - 1].ratio; i--) { candidate t = cs[i]; cs[i] = cs[i - 1]; cs[i - 1] = t; }
}

/* Full scan: per-vertex stress accumulated over triangles in one pass; the few highest vertices over
 * their threshold, best first. */
static int scan_all(tc_cloth *c, candidate *cs)
{
    double *S = tc_vec_ptr(&c->vs9), *N = tc_vec_ptr(&c->vsn), *W = tc_vec_ptr(&c->vsa);
    memset(S, 0, 9 * (size_t)c->nv * sizeof(double));
    memset(N, 0, 3 * (size_t)c->nv * sizeof(double));
    memset(W, 0, (size_t)c->nv * sizeof(double));
    const int32_t *T = tc_vec_ptr(&c->tri);
    const double *S3 = tc_vec_ptr(&c->stress), *A = tc_vec_ptr(&c->area);
    for (int32_t t = 0; t < c->nt; t++) {
        double tn[3];
        tri_normal(c, t, tn);
        const double w = A[t], *st = S3 + 9 * t;
        for (int k = 0; k < 3; k++) {
            int32_t v = T[3 * t + k];
            double *s = S + 9 * v;
            for (int q = 0; q < 9; q++) s[q] += w * st[q];
            N[3 * v] += tn[0]; N[3 * v + 1] += tn[1]; N[3 * v + 2] += tn[2];
            W[v] += w;
        }
    }
    int n = 0;
    const double *strength = tc_vec_ptr(&c->strength);
    const double thr = c->mat.tear_stress;
    for (int32_t v = 0; v < c->nv; v++) {
        if (!(W[v] > 0) || held(c, v)) continue;
        const double *s = S + 9 * v;
        double floor_r = n == TC_TEAR_CANDIDATES ? cs[TC_TEAR_CANDIDATES - 1].ratio : 1.0;
        /* cheap bound first: no eigenvalue of a projection exceeds the Frobenius norm */
        double fro = 0, lim = thr * strength[v] * floor_r * W[v];
        for (int q = 0; q < 9; q++) fro += s[q] * s[q];
        if (fro <= lim * lim) continue;
        double nn[3] = {N[3 * v], N[3 * v + 1], N[3 * v + 2]}, ln = sqrt(dot3(nn, nn));
        if (!(ln > 0)) continue;
        nn[0] /= ln; nn[1] /= ln; nn[2] /= ln;
        double Sv[9], pd[3], td[3];
        for (int q = 0; q < 9; q++) Sv[q] = s[q] / W[v];
        double r = principal_in_plane(Sv, nn, pd) / (thr * strength[v]);
        if (r > floor_r) {
            cross3(nn, pd, td);  /* the tear runs orthogonal to the principal direction */
            cand_push(cs, &n, r, v, td);
        }
    }
    return n;
}

static bool is_tip(const tc_cloth *c, int32_t v)
{
    const int32_t *tp = tc_vec_ptr(&c->tips);
    for (size_t i = 0; i < c->tips.len; i++)
        if (tp[i] == v) return true;
    return false;
}

/* Around a running tip the stress is concentrated by the tip itself; a second tear there would only
 * branch the first one, so the slice scan leaves a disc of a few local edge lengths alone. */
static bool near_tip(const tc_cloth *c, int32_t v)
{
    const int32_t *tp = tc_vec_ptr(&c->tips);
    const double *x = tc_vec_ptr(&c->x);
    int32_t t = ((const int32_t *)tc_vec_ptr(&c->vtri))[v];
    const int32_t *T = (const int32_t *)tc_vec_ptr(&c->tri) + 3 * (size_t)t;
    double e[3], len = 0.0;
    for (int k = 0; k < 3; k++) {
        sub3(x + 3 * T[(k + 1) % 3], x + 3 * T[k], e);
        len += sqrt(dot3(e, e)) / 3.0;
    }
    double r2 = TC_NEAR_TIP_RADIUS2 * len * len;
    for (size_t i = 0; i < c->tips.len; i++) {
        sub3(x + 3 * tp[i], x + 3 * v, e);
        if (dot3(e, e) < r2) return true;
    }
    return false;
}

int tc_tear_step(tc_cloth *c)
{
    if (c->dirty) { tc_element_pass(c, tc_vec_ptr(&c->x)); }
    double dir[3];
    if (c->tips.len == 0) {
        candidate cs[TC_TEAR_CANDIDATES];
        int n = scan_all(c, cs);
        /* several vertices may pass in one step: the highest starts the tear; the next ones are
           tried only if no segment can be cut from it (e.g. its direction runs along the rim) */
        for (int i = 0; i < n; i++) {
            int rc = start_tear(c, cs[i].v, cs[i].dir, false);
            if (rc < 0) return TC_ERR_NOMEM;
            if (rc > 0) break;
        }
        return TC_OK;
    }
    /* tips first: each examines its own stress only */
    for (size_t i = 0; i < c->tips.len;) {
        int32_t v = ((int32_t *)tc_vec_ptr(&c->tips))[i];
        double n[3], pd[3];
        double sig = vertex_stress(c, v, pd, n);
        if (ratio_of(c, v, sig) > 1.0) {
            cross3(n, pd, dir);
            const double *prev = (const double *)tc_vec_ptr(&c->tipdir) + 3 * i;
            if (dot3(dir, prev) < 0) { dir[0] = -dir[0]; dir[1] = -dir[1]; dir[2] = -dir[2]; }
            size_t before = c->tips.len;
            advance_tip(c, i, dir);
            if (c->tips.len < before) continue;  /* tip ended; slot i now holds another tip */
        }
        i++;
    }
    /* one slice of the rest of the mesh, so a second tear can start elsewhere */
    int32_t slice = (c->nv + c->tear.scan_period - 1) / c->tear.scan_period;
    int32_t best = -1;
    double best_r = 1.0, best_d[3] = {0};
    for (int32_t k = 0; k < slice; k++) {
        int32_t v = (c->scan_cursor + k) % c->nv;
        if (is_tip(c, v) || held(c, v) || near_tip(c, v)) continue;
        double n[3], pd[3];
        double sig = vertex_stress(c, v, pd, n);
        double r = ratio_of(c, v, sig);
        if (r > best_r) { best_r = r; best = v; cross3(n, pd, best_d); }
    }
    c->scan_cursor = (c->scan_cursor + slice) % (c->nv ? c->nv : 1);
    if (best >= 0 && start_tear(c, best, best_d, false) < 0) return TC_ERR_NOMEM;
    return TC_OK;
}

int tc_cloth_scripted_tear(tc_cloth *c, int32_t start, const double direction[3], double length, int32_t *cuts)
{
    *cuts = 0;
    if (start < 0 || start >= c->nv) { tc_set_err(c, "scripted tear starts at vertex %d, outside [0, %d)", (int)start, (int)c->nv); return TC_ERR_INPUT; }
    double l = sqrt(dot3(direction, direction));
    if (!(l > 0) || !isfinite(l)) { tc_set_err(c, "scripted tear direction must be a non-zero finite vector"); return TC_ERR_INPUT; }
    if (!(length > 0) || !isfinite(length)) { tc_set_err(c, "scripted tear length must be > 0 m (got %g)", length); return TC_ERR_INPUT; }
    if (c->dirty) tc_element_pass(c, tc_vec_ptr(&c->x));
    double d[3] = {direction[0] / l, direction[1] / l, direction[2] / l};
    const double *x = tc_vec_ptr(&c->x);
    double origin[3] = {x[3 * start], x[3 * start + 1], x[3 * start + 2]};
    int32_t before = c->stats.cuts;
    size_t ntips = c->tips.len;
    int rc = start_tear(c, start, d, true);
    if (rc < 0) return TC_ERR_NOMEM;
    if (rc == 0) { tc_set_err(c, "cannot tear from vertex %d along (%g, %g, %g): no triangle there to cut", (int)start, d[0], d[1], d[2]); return TC_ERR_INPUT; }
    /* follow the tip this tear created until the length is covered */
    for (int guard = 0; guard < TC_SCRIPTED_MAX_CUTS && c->tips.len > ntips; guard++) {
        size_t ti = c->tips.len - 1;
        int32_t v = ((int32_t *)tc_vec_ptr(&c->tips))[ti];
        x = tc_vec_ptr(&c->x);
        double off[3];
        sub3(x + 3 * v, origin, off);
        if (dot3(off, d) >= length) break;
        /* steer back toward the scripted line so snapping errors do not accumulate */
        double along = dot3(off, d), lat[3];
        for (int k = 0; k < 3; k++) lat[k] = off[k] - along * d[k];
        double step_dir[3];
        for (int k = 0; k < 3; k++) step_dir[k] = d[k] - TC_STEER_GAIN * lat[k] / (fabs(along) + TC_STEER_SOFTENING);
        if (!advance_tip(c, ti, step_dir)) break;
    }
    /* a scripted tear leaves its end as a running tip only if tearing is enabled */
    if (!c->tear.enabled)
        while (c->tips.len > ntips) tip_remove(c, c->tips.len - 1);
    *cuts = c->stats.cuts - before;
    return TC_OK;
}
