/* remesh.c - the local remesh of a tear (Le Gouis et al. 2017, section V): fans around a vertex,
 * the segment a cut takes from a tip, edge splits, and the separation of the mesh along cut edges.
 *
 * Which way (tc_prepare_segment): the segment goes from the tip through the triangle whose corner
 * holds the wanted direction to the opposite edge; it snaps to an end vertex of that edge when the
 * path passes within snap_tolerance * (edge length) of it (or when a split would make a triangle
 * with an angle below min_angle_deg), otherwise the edge is split where the path meets it. So each
 * cut adds at most one vertex and two triangles, and the path follows the stress instead of the
 * mesh edges.
 *
 * Separation (tc_separate): the cut edges stop connecting their two triangles; every vertex whose
 * triangles then form more than one fan is duplicated, one copy per fan.
 *
 * What a vertex carries comes along: rest position, velocity, groups, tear strength, pin and handle
 * membership (split vertices interpolate and join a handle only when both parents belong to it);
 * per-corner UVs are interpolated for split triangles and kept for duplicated vertices (a UV seam).
 * Masses are lumped from rest areas, which splits preserve exactly, so total mass is conserved.
 * Every change is recorded as a topology event (events.c).
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
int tc_fan_walk(const tc_cloth *c, int32_t u, int32_t start, const int32_t *cut, int ncut, int32_t *out, int cap,
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

bool tc_is_boundary_vertex(const tc_cloth *c, int32_t u)
{
    int32_t fan[TC_FAN_MAX];
    bool closed;
    int n = tc_fan_walk(c, u, ((int32_t *)tc_vec_ptr(&c->vtri))[u], NULL, 0, fan, TC_FAN_MAX, &closed);
    return n < 0 || !closed;
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
    tc_vec *lerp3[] = {&c->x, &c->v, &c->rest, &c->v0, &c->sdv};
    for (int i = 0; i < 5; i++) {
        double *p = tc_vec_ptr(lerp3[i]);
        for (int k = 0; k < 3; k++) p[3 * v + k] = wa * p[3 * a + k] + wb * p[3 * bb + k];
    }
    if (c->vgoal.len) {
        /* the goals (once made): the new position plus the parents' offsets from their goals, a
           parent that follows none counting 0 (its goal is stale). Two parents that follow goals
           (a pinned split) put it on the line between theirs, as its position; a split between a
           soft pin and a free vertex keeps half the pull, towards where the soft pin's is. */
        const double *x = tc_vec_ptr(&c->x);
        const double fa = tc_follows_goal(c, a) ? wa : 0.0, fb = tc_follows_goal(c, bb) ? wb : 0.0;
        tc_vec *goals[] = {&c->vgoal, &c->vgoal0};
        for (int i = 0; i < 2; i++) {
            double *g = tc_vec_ptr(goals[i]);
            for (int k = 0; k < 3; k++)
                g[3 * v + k] = x[3 * v + k] + fa * (g[3 * a + k] - x[3 * a + k]) + fb * (g[3 * bb + k] - x[3 * bb + k]);
        }
    }
    double *g = tc_vec_ptr(&c->groups);
    for (int k = 0; k < c->ng; k++) g[(size_t)v * c->ng + k] = wa * g[(size_t)a * c->ng + k] + wb * g[(size_t)bb * c->ng + k];
    double *st = tc_vec_ptr(&c->strength);
    st[v] = wa * st[a] + wb * st[bb];
    if (c->vpink.len) {  /* a soft pin's spring, as its goals: between its parents' */
        double *kp = tc_vec_ptr(&c->vpink);
        kp[v] = wa * kp[a] + wb * kp[bb];
    }
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
        /* the new element inherits the rotation so the first force evaluation starts from it, and
           the stress (sigma, from which with R the world stress is derived: core.h) so tearing
           later in this step (before the next element pass) reads its parent's instead of zero */
        double *R = tc_vec_ptr(&c->rot), *SG = tc_vec_ptr(&c->sig);
        memcpy(R + 6 * (size_t)t2, R + 6 * (size_t)t, 6 * sizeof(double));
        memcpy(SG + 3 * (size_t)t2, SG + 3 * (size_t)t, 3 * sizeof(double));
        /* and the material: its warp (in the rest space, where both halves lie in the parent's
           plane), its own grain angle and its plastic strain (in the warp/weft axes), see ortho.c */
        double *TW = tc_vec_ptr(&c->twarp), *TG = tc_vec_ptr(&c->tgrain), *TL = tc_vec_ptr(&c->tplast);
        if (tc_axes_stored(c)) memcpy(TW + 3 * (size_t)t2, TW + 3 * (size_t)t, 3 * sizeof(double));
        if (c->tgrain.len) TG[t2] = TG[t];
        memcpy(TL + 4 * (size_t)t2, TL + 4 * (size_t)t, 4 * sizeof(double));
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
int32_t tc_prepare_segment(tc_cloth *c, int32_t v, const double *dir, const int32_t *avoid, int navoid, int32_t *pair)
{
    int32_t fan[TC_FAN_MAX];
    bool closed;
    int nf = tc_fan_walk(c, v, ((int32_t *)tc_vec_ptr(&c->vtri))[v], NULL, 0, fan, TC_FAN_MAX, &closed);
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
int tc_separate(tc_cloth *c, const int32_t *cut, int ncut, const int32_t *verts, int nverts, unsigned *dup_mask)
{
    /* every vertex's whole fan is listed before anything changes: once one endpoint is duplicated,
       the cut edge is a real boundary and a walk could no longer reach the far side */
    int32_t all[4][TC_FAN_MAX], fan[TC_FAN_MAX], affected[4 * TC_FAN_MAX] = {0};
    int nall[4], naff = 0;
    bool closed;
    *dup_mask = 0;
    if (nverts > 4) return TC_ERR_INPUT;
    for (int i = 0; i < nverts; i++) {
        nall[i] = tc_fan_walk(c, verts[i], ((int32_t *)tc_vec_ptr(&c->vtri))[verts[i]], NULL, 0, all[i], TC_FAN_MAX, &closed);
        if (nall[i] <= 0) return TC_ERR_INPUT;
        for (int j = 0; j < nall[i]; j++)
            if (!in_set(affected, naff, all[i][j])) affected[naff++] = all[i][j];
    }
    stencils_off(c, affected, naff);
    for (int i = 0; i < nverts; i++) {
        int32_t u = verts[i];
        int n = nall[i];
        bool assigned[TC_FAN_MAX] = {false};
        int nf = tc_fan_walk(c, u, all[i][0], cut, ncut, fan, TC_FAN_MAX, &closed);
        if (nf <= 0) return TC_ERR_INPUT;
        for (int j = 0; j < n; j++) assigned[j] = in_set(fan, nf, all[i][j]);
        for (int j = 0; j < n; j++) {
            if (assigned[j]) continue;
            int m = tc_fan_walk(c, u, all[i][j], cut, ncut, fan, TC_FAN_MAX, &closed);
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
