/* tear.c - stress-driven tearing (Le Gouis et al. 2017, section V): where a tear starts, which way
 * it runs, how fast, and its tips; the remesh each cut makes is remesh.c's.
 *
 * Where: the stress of a vertex is the mean stress tensor over its material disc (the triangles
 * within tear_radius of it, connected through uncut edges), its largest in-plane eigenvalue held
 * against tear_stress * strength(v). Every vertex can start a tear, grasped and pinned ones too (a
 * held vertex splits into two held copies), so no configuration is untearable. Each step every
 * triangle's sigma_1 bounds the discs that hold it (while tips run: a slice of 1/scan_period of
 * them, so any region starts within scan_period steps), and each region over threshold that holds
 * no running tip starts a tear at its highest vertex (scan()); a held vertex over threshold with
 * a single triangle left slips out of its grip instead (let_go()).
 *
 * Which way: the direction rule of rank_directions(): stress across the cut over strength ahead,
 * among the orthogonal-to-principal direction and the edges at the tip (woven sheets: also the
 * warp and weft, with the strength of each thread family; see "woven sheets" below). A tear from an interior
 * vertex cuts two segments (both ways) before separating; a tip whose target lies on a boundary
 * (the rim, or another tear) ends there.
 *
 * How fast: advance_tips(), a crack speed from the driving stress (Freund), capped at a fraction of
 * the Rayleigh wave speed, integrated in time; tips whose stress fell to the threshold retire.
 */
#include "core.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>


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

/* ---------------- the material disc ---------------- */

/* Visit marks and the walk's queue, sized to the current mesh (tearing grows it). */
static int marks_ready(tc_cloth *c)
{
    size_t nt = (size_t)c->nt, nv = (size_t)c->nv;
    if ((c->tstamp.len < nt && tc_vec_resize(&c->tstamp, nt)) || (c->tqueue.len < nt && tc_vec_resize(&c->tqueue, nt)) ||
        (c->vstamp.len < 3 * nv && tc_vec_resize(&c->vstamp, 3 * nv)) || (c->vqueue.len < nv && tc_vec_resize(&c->vqueue, nv))) {
        tc_set_err(c, "out of memory for the tearing walk (%d triangles)", (int)c->nt);
        return TC_ERR_NOMEM;
    }
    return TC_OK;
}

static int32_t new_mark(tc_cloth *c)
{
    if (c->stamp == INT32_MAX) {  /* after 2^31 walks: forget every old mark */
        memset(tc_vec_ptr(&c->tstamp), 0, c->tstamp.len * sizeof(int32_t));
        memset(tc_vec_ptr(&c->vstamp), 0, c->vstamp.len * sizeof(int32_t));
        c->stamp = 0;
    }
    return ++c->stamp;
}

static double dist2(const double *a, const double *b)
{
    double e[3];
    sub3(a, b, e);
    return dot3(e, e);
}

/* Does triangle t belong to the disc of radius r around the rest point P? BY_CENTROID: its rest
 * centroid lies inside (the stress average of a vertex); otherwise any of its corners does (the
 * search for vertices whose disc may hold a given triangle). */
enum { BY_CENTROID = 0, BY_CORNER = 1 };
static bool in_disc(const tc_cloth *c, int32_t t, const double *P, double r2, int rule)
{
    const int32_t *T = (const int32_t *)tc_vec_ptr(&c->tri) + 3 * (size_t)t;
    const double *X = tc_vec_ptr(&c->rest);
    if (rule == BY_CORNER) {
        for (int k = 0; k < 3; k++)
            if (dist2(X + 3 * T[k], P) <= r2) return true;
        return false;
    }
    double g[3];
    for (int q = 0; q < 3; q++) g[q] = (X[3 * T[0] + q] + X[3 * T[1] + q] + X[3 * T[2] + q]) / 3.0;
    return dist2(g, P) <= r2;
}

/* Walks the disc: from the seeds (always inside) through uncut edges to every triangle in_disc.
 * Leaves the triangles in the queue; returns their count. A cut is a boundary, so the disc of a
 * vertex beside a tear never reaches across it: the stress of the other flank is not its own. */
static int32_t disc_walk(tc_cloth *c, const double *P, double r, const int32_t *seeds, int nseeds, int rule)
{
    int32_t mark = new_mark(c), *ts = tc_vec_ptr(&c->tstamp), *q = tc_vec_ptr(&c->tqueue);
    int32_t n = 0;
    for (int i = 0; i < nseeds; i++)
        if (ts[seeds[i]] != mark) { ts[seeds[i]] = mark; q[n++] = seeds[i]; }
    const double r2 = r * r;
    for (int32_t head = 0; head < n; head++) {
        int32_t t = q[head];
        for (int k = 0; k < 3; k++) {
            int32_t nb = tc_nbr(c, t, k);
            if (nb < 0 || ts[nb] == mark) continue;
            ts[nb] = mark;
            if (in_disc(c, nb, P, r2, rule)) q[n++] = nb;
        }
    }
    return n;
}

/* The discs kept (c->discs). A vertex's disc - its fan, then the triangles disc_walk adds, in the
 * walk's order - depends on the topology, the rest positions and the radius only, so it is kept
 * from one step to the next until one of them changes (a cut, a snapshot restored, a new
 * tear_radius): the disc stress then sums a list instead of walking. Why: with a tip running
 * through a sheet stressed near its threshold everywhere (a banknote pulled apart: Table I's
 * "after" column), each step evaluates the disc stress of every vertex of the tip's region, and
 * the walks took ~1 ms a step there. The result is the walk's, bit for bit (same triangles, same
 * order). Lists are made only for vertices whose stress is asked for, into one pool of at most
 * TC_DISC_POOL_PER_TRIANGLE ints a triangle; past that, the walk is used uncached. */
struct tc_discs {
    int32_t *off;        /* (nv) start of a vertex's list in pool, -1: none yet */
    int32_t *pool;       /* per list: nf, m, the fan's nf triangles, the disc's m (the fan's again first) */
    size_t used, cap, nv_cap;
    uint64_t pair_version;  /* the key the lists hold for */
    int32_t nv, nt;
    double radius;
};

void tc_discs_free(tc_discs *d)
{
    if (!d) return;
    free(d->off);
    free(d->pool);
    free(d);
}

size_t tc_discs_bytes(const tc_discs *d)
{
    return d ? sizeof *d + d->nv_cap * sizeof(int32_t) + d->cap * sizeof(int32_t) : 0;
}

/* The cache, emptied when its key no longer holds; NULL when it cannot be had (no memory: the
 * walks then run uncached, as before) */
static tc_discs *discs_ready(tc_cloth *c)
{
    tc_discs *d = c->discs;
    if (!d && !(d = c->discs = calloc(1, sizeof *d))) return NULL;
    if (d->off && d->pair_version == c->pair_version && d->nv == c->nv && d->nt == c->nt &&
        d->radius == c->mat.tear_radius)
        return d;
    if (d->nv_cap < (size_t)c->nv) {
        int32_t *o = realloc(d->off, (size_t)c->nv * sizeof *o);
        if (!o) return NULL;
        d->off = o;
        d->nv_cap = (size_t)c->nv;
    }
    for (int32_t v = 0; v < c->nv; v++) d->off[v] = -1;
    d->used = 0;
    d->pair_version = c->pair_version;
    d->nv = c->nv;
    d->nt = c->nt;
    d->radius = c->mat.tear_radius;
    return d;
}

/* Vertex v's fan (*nf triangles, <= 0: none, nothing returned; into fan) and disc (*m triangles,
 * *disc), from the cache or walked (then *disc is tqueue's, valid until the next walk). The fan is
 * kept apart from the disc's first triangles: on a corrupted mesh it may name one twice, which the
 * walk does not. */
static const int32_t *disc_of(tc_cloth *c, int32_t v, int32_t fan[TC_FAN_MAX], int *nf, int32_t *m, const int32_t **disc)
{
    tc_discs *d = discs_ready(c);
    if (d && d->off[v] >= 0) {
        const int32_t *l = d->pool + d->off[v];
        *nf = l[0];
        *m = l[1];
        *disc = l + 2 + l[0];
        return l + 2;
    }
    bool closed;
    *nf = tc_fan_walk(c, v, ((int32_t *)tc_vec_ptr(&c->vtri))[v], NULL, 0, fan, TC_FAN_MAX, &closed);
    *m = 0;
    if (*nf <= 0) return NULL;
    *m = disc_walk(c, (const double *)tc_vec_ptr(&c->rest) + 3 * (size_t)v, c->mat.tear_radius, fan, *nf, BY_CENTROID);
    const int32_t *Q = tc_vec_ptr(&c->tqueue);
    *disc = Q;
    const size_t need = d ? d->used + 2 + (size_t)*nf + (size_t)*m : 0,
                 limit = (size_t)TC_DISC_POOL_PER_TRIANGLE * (size_t)c->nt;
    if (!d || need > limit) return fan;
    if (need > d->cap) {
        size_t cap = d->cap ? 2 * d->cap : 4096;
        while (cap < need) cap *= 2;
        if (cap > limit) cap = limit;
        int32_t *p = realloc(d->pool, cap * sizeof *p);
        if (!p) return fan;
        d->pool = p;
        d->cap = cap;
    }
    int32_t *l = d->pool + d->used;
    l[0] = *nf;
    l[1] = *m;
    memcpy(l + 2, fan, (size_t)*nf * sizeof *fan);
    memcpy(l + 2 + *nf, Q, (size_t)*m * sizeof *Q);
    d->off[v] = (int32_t)d->used;
    d->used = need;
    *disc = l + 2 + *nf;
    return l + 2;
}

/* Vertex v's fan into buf: copied from the cache when its disc was asked for already (a copy: the
 * callers ask for discs while they read it, which may move the pool), else walked */
static const int32_t *fan_of(tc_cloth *c, int32_t v, int32_t buf[TC_FAN_MAX], int *nf)
{
    tc_discs *d = discs_ready(c);
    if (d && d->off[v] >= 0) {
        const int32_t *l = d->pool + d->off[v];
        *nf = l[0];
        memcpy(buf, l + 2, (size_t)l[0] * sizeof *buf);
        return buf;
    }
    bool closed;
    *nf = tc_fan_walk(c, v, ((int32_t *)tc_vec_ptr(&c->vtri))[v], NULL, 0, buf, TC_FAN_MAX, &closed);
    return buf;
}

/* The stress of vertex v over its material disc: area-weighted mean tensor S (9), the vertex
 * normal n (from its own fan, the local tangent plane), and the largest in-plane principal value
 * and direction. Why an average over a material radius rather than one vertex ring: a ring's
 * average depends on the mesh (the ring shrinks as the mesh is refined, and the stress at a notch
 * grows without bound), the disc's does not once the mesh resolves it, so tears start and arrest
 * at the same load and place on any mesh; with a radius below the ring it is the ring. */
static double disc_stress(tc_cloth *c, int32_t v, double *dir, double *normal, double *Sout)
{
    int nf;
    int32_t m, fan_walked[TC_FAN_MAX];
    const int32_t *Q;
    const int32_t *fan = disc_of(c, v, fan_walked, &nf, &m, &Q);
    if (nf <= 0) return 0.0;
    double n[3] = {0};
    for (int i = 0; i < nf; i++) {
        double tn[3];
        tri_normal(c, fan[i], tn);
        n[0] += tn[0]; n[1] += tn[1]; n[2] += tn[2];
    }
    double ln = sqrt(dot3(n, n));
    if (!(ln > 0)) return 0.0;
    for (int q = 0; q < 3; q++) n[q] /= ln;
    const double *A = tc_vec_ptr(&c->area);
    double S[9] = {0}, wsum = 0.0;
    for (int32_t i = 0; i < m; i++) {
        double st[9];
        tc_tri_world_stress(c, (size_t)Q[i], st);
        const double w = A[Q[i]];
        for (int q = 0; q < 9; q++) S[q] += w * st[q];
        wsum += w;
    }
    if (!(wsum > 0)) return 0.0;
    for (int q = 0; q < 9; q++) S[q] /= wsum;
    if (normal) memcpy(normal, n, sizeof n);
    if (Sout) memcpy(Sout, S, sizeof S);
    return principal_in_plane(S, n, dir);
}

int tc_cloth_vertex_stress(tc_cloth *c, int32_t v, double *value, double direction[3])
{
    if (v < 0 || v >= c->nv) { tc_set_err(c, "vertex %d is outside [0, %d)", (int)v, (int)c->nv); return TC_ERR_INPUT; }
    if (c->dirty) { tc_element_pass(c, tc_vec_ptr(&c->x)); tc_total_force(c, tc_vec_ptr(&c->x)); }
    if (marks_ready(c)) return TC_ERR_NOMEM;
    *value = disc_stress(c, v, direction, NULL, NULL);
    return TC_OK;
}

static double threshold(const tc_cloth *c, int32_t v)
{
    return c->mat.tear_stress * ((const double *)tc_vec_ptr(&c->strength))[v];
}

/* ---------------- woven sheets: strength by direction ----------------
 *
 * A woven sheet (material orthotropic) fails by its threads: the warp threads break when the
 * stress along the warp, s_ww = w^T S w, reaches tear_stress, the weft threads when s_ff reaches
 * tear_stress_weft (the maximum-stress criterion of fibre composites, R. M. Jones, Mechanics of
 * Composite Materials, 2nd ed. 1999, sec. 2.9.1; the shear alone breaks no thread: cloth on the
 * bias shears). The failure index of a vertex is therefore
 *     r = max(s_ww / tear_stress, s_ff / tear_stress_weft) / strength(v),
 * (the isotropic r is sigma_1 / tear_stress / strength(v)). The interpolation for a cut at any
 * angle is netting analysis (the sheet as two families of threads that carry only their own axial
 * stress; D. Hull, T. W. Clyne, An Introduction to Composite Materials, 2nd ed. 1996, sec. 4.1):
 * of the normal traction across a cut whose normal m makes angle theta with the warp, the warp
 * threads carry s_ww cos^2 theta and the weft threads s_ff sin^2 theta, each against its own
 * strength, so the cut's index is
 *     r(m) = s_ww cos^2 theta / tear_stress + s_ff sin^2 theta / tear_stress_weft,
 * a convex combination of the two thread indices: it is largest across one of the thread
 * families (theta = 0 or 90 degrees), never in between, so a woven sheet tears along its threads
 * (across the family that fails) whatever the angle of the pull, as denim does; a weak line (a
 * seam) still steers it through the strength ahead. Paper's machine direction is the warp of a
 * sheet whose fibres are mostly aligned with it. */

/* The warp w and weft f at vertex v, unit, in the plane normal to n: the threads are material
 * lines, so each fan triangle carries its rest axes forward by its deformation gradient F (not by
 * its rotation R: a sheared sheet turns its threads apart, and a cut that follows a thread in the
 * current shape must follow it in the rest shape too); area-weighted means over v's fan,
 * sign-aligned to the first. w and f are not orthogonal in a sheared sheet. False when they
 * cancel out (the isotropic rule is then used at v). */
static bool vertex_axes(tc_cloth *c, int32_t v, const double *n, double *w, double *f)
{
    int32_t buf[TC_FAN_MAX];
    int nf;
    const int32_t *fan = fan_of(c, v, buf, &nf);
    const double *x = tc_vec_ptr(&c->x), *G = tc_vec_ptr(&c->grad), *AX = tc_vec_ptr(&c->taxis), *A = tc_vec_ptr(&c->area);
    const int32_t *T = tc_vec_ptr(&c->tri);
    double aw[3] = {0}, af[3] = {0};
    for (int i = 0; i < nf; i++) {
        const int32_t t = fan[i], *tt = T + 3 * (size_t)t;
        const double *g = G + 4 * (size_t)t, *ax = AX + 2 * (size_t)t;
        double e1[3], e2[3], dw[3], df[3];
        sub3(x + 3 * tt[1], x + 3 * tt[0], e1);
        sub3(x + 3 * tt[2], x + 3 * tt[0], e2);
        for (int k = 0; k < 3; k++) {
            const double F0 = e1[k] * g[0] + e2[k] * g[2], F1 = e1[k] * g[1] + e2[k] * g[3];
            dw[k] = F0 * ax[0] + F1 * ax[1];
            df[k] = -F0 * ax[1] + F1 * ax[0];
        }
        const double sw = (i && dot3(dw, aw) < 0) ? -A[t] : A[t], sf = (i && dot3(df, af) < 0) ? -A[t] : A[t];
        for (int k = 0; k < 3; k++) { aw[k] += sw * dw[k]; af[k] += sf * df[k]; }
    }
    const double pw = dot3(aw, n), pf = dot3(af, n);
    for (int k = 0; k < 3; k++) { aw[k] -= pw * n[k]; af[k] -= pf * n[k]; }
    const double lw = sqrt(dot3(aw, aw)), lf = sqrt(dot3(af, af));
    if (!(lw > 0 && lf > 0)) return false;
    for (int k = 0; k < 3; k++) { w[k] = aw[k] / lw; f[k] = af[k] / lf; }
    return true;
}

static double quad(const double *S, const double *a)
{
    double Sa[3];
    for (int r = 0; r < 3; r++) Sa[r] = S[3 * r] * a[0] + S[3 * r + 1] * a[1] + S[3 * r + 2] * a[2];
    return dot3(a, Sa);
}

/* Failure index at v over its disc (see above; 0 where v has no stress), with the disc's S, n and
 * principal direction pd out; w, f: the thread axes at v when woven (else untouched). */
static double vertex_ratio(tc_cloth *c, int32_t v, double *pd, double *n, double *S, double *w, double *f, bool *woven)
{
    double Sl[9] = {0}, nl[3] = {0, 0, 1}, wl[3], fl[3];
    double s1 = disc_stress(c, v, pd, nl, Sl);
    bool wv = false;
    double r = s1 / threshold(c, v);
    if (c->mat.orthotropic && s1 != 0.0 && vertex_axes(c, v, nl, wl, fl)) {
        const double st = ((const double *)tc_vec_ptr(&c->strength))[v];
        double rw = quad(Sl, wl) / c->mat.tear_stress, rf = quad(Sl, fl) / c->mat.tear_stress_weft;
        r = (rw > rf ? rw : rf) / st;
        wv = true;
    }
    if (n) memcpy(n, nl, sizeof nl);
    if (S) memcpy(S, Sl, sizeof Sl);
    if (w && wv) { memcpy(w, wl, sizeof wl); memcpy(f, fl, sizeof fl); }
    if (woven) *woven = wv;
    return r;
}

/* ---------------- which way ---------------- */

/* Strength where direction d (tangent, unit) leads from v: interpolated along the opposite edge of
 * the corner of v's fan that holds d, where d meets it. False when no corner holds d (it points
 * out of the cloth). */
static bool strength_ahead(const tc_cloth *c, int32_t v, const double *d, const int32_t *fan, int nf, double *out,
                           double *rest_at)
{
    const double *x = tc_vec_ptr(&c->x), *st = tc_vec_ptr(&c->strength);
    for (int i = 0; i < nf; i++) {
        const int32_t *T = (const int32_t *)tc_vec_ptr(&c->tri) + 3 * (size_t)fan[i];
        int l = tc_tri_local(c, fan[i], v);
        int32_t a = T[(l + 1) % 3], b = T[(l + 2) % 3];
        double ea[3], eb[3], n[3], ca[3], cb[3];
        sub3(x + 3 * a, x + 3 * v, ea);
        sub3(x + 3 * b, x + 3 * v, eb);
        cross3(ea, eb, n);
        cross3(ea, d, ca);
        cross3(d, eb, cb);
        double sa = dot3(ca, n), sb = dot3(cb, n);
        /* strictly inside: a direction along a boundary edge (the rim) cuts nothing */
        double ln = sqrt(dot3(n, n)), la = TC_CORNER_INSIDE * ln * sqrt(dot3(ea, ea)), lb = TC_CORNER_INSIDE * ln * sqrt(dot3(eb, eb));
        if (!(sa > la && sb > lb)) {
            int32_t pa = tc_pair_find(c, v, a), pb = tc_pair_find(c, v, b);
            const int32_t *PT = tc_vec_ptr(&c->ptris);
            bool rim_a = PT[2 * pa] < 0 || PT[2 * pa + 1] < 0, rim_b = PT[2 * pb] < 0 || PT[2 * pb + 1] < 0;
            /* on an inner edge of the fan the direction still lies inside the cloth */
            if (sa < -la || sb < -lb || (sa <= la && rim_a) || (sb <= lb && rim_b)) continue;
        }
        /* d = alpha ea + beta eb in the corner; it meets ab at s = beta / (alpha + beta) */
        double s = sa / (sa + sb + TC_TINY);
        *out = (1.0 - s) * st[a] + s * st[b];
        if (rest_at) {  /* where d meets ab, in the rest space */
            const double *X = tc_vec_ptr(&c->rest);
            for (int k = 0; k < 3; k++) rest_at[k] = (1.0 - s) * X[3 * a + k] + s * X[3 * b + k];
        }
        return true;
    }
    return false;
}

/* Mean stress (world 3x3) over the disc of radius tear_radius around the rest point half the
 * tear radius from v towards `lead` (at lead if that is nearer), through uncut edges from v's fan.
 * False when the disc holds no area. */
static bool stress_ahead(tc_cloth *c, int32_t v, const double *lead, const int32_t *fan, int nf, double *S)
{
    const double *X = (const double *)tc_vec_ptr(&c->rest) + 3 * (size_t)v;
    double e[3], P[3];
    sub3(lead, X, e);
    double l = sqrt(dot3(e, e)), r = 0.5 * c->mat.tear_radius, t = l > r ? r / l : 1.0;
    for (int k = 0; k < 3; k++) P[k] = X[k] + t * e[k];
    int32_t m = disc_walk(c, P, c->mat.tear_radius, fan, nf, BY_CENTROID);
    const int32_t *Q = tc_vec_ptr(&c->tqueue);
    const double *A = tc_vec_ptr(&c->area);
    double wsum = 0.0;
    memset(S, 0, 9 * sizeof(double));
    for (int32_t i = 0; i < m; i++) {
        double st[9];
        tc_tri_world_stress(c, (size_t)Q[i], st);
        const double wt = A[Q[i]];
        for (int q = 0; q < 9; q++) S[q] += wt * st[q];
        wsum += wt;
    }
    if (!(wsum > 0)) return false;
    for (int q = 0; q < 9; q++) S[q] /= wsum;
    return true;
}

/* THE DIRECTION RULE. Among the directions available at v - the one orthogonal to the principal
 * stress (either sense) and every uncut edge from v - a tear takes the one that maximises
 *     (m^T S m) / strength ahead,
 * the stress that would open the cut (m: the in-plane normal of the direction) over the strength
 * where the direction leads (the far end of the edge, or along the opposite edge where the
 * orthogonal direction meets it). With uniform strength that is the orthogonal direction (m^T S m
 * is largest there: sigma_1); a weak line (a seam) wins when its strength falls more than the
 * stress across it does, e.g. a seam of factor 0.5 at 40 degrees to the orthogonal direction
 * (cos^2 40 = 0.59 > 0.5). Only directions whose cosine with `fwd` exceeds TC_TIP_FORWARD_COS
 * count (fwd NULL: all), and only those the stress can open (opening stress above tear_stress
 * times the segment's strength, the mean of its ends'): a cut that would not open, such as one
 * along the pull from the face of a crack, is no way forward. Fills `out` (3 per direction) with the best TC_TEAR_DIRECTIONS, best
 * first, so a caller whose best direction cannot be cut (the remesh refuses it) takes the next;
 * returns their count. */
static int rank_directions(tc_cloth *c, int32_t v, const double *S, const double *n, const double *pd,
                           const double *fwd, const double *w, const double *f, double *out)
{
    /* woven (w, f given): the thread directions are candidates too, and a cut's opening measure is
       the netting index of the head of this file's strength section instead of m^T S m / tear_stress */
    const double sww = w ? quad(S, w) / c->mat.tear_stress : 0.0, sff = w ? quad(S, f) / c->mat.tear_stress_weft : 0.0;
    int32_t fan[TC_FAN_MAX];
    bool closed;
    int nf = tc_fan_walk(c, v, ((int32_t *)tc_vec_ptr(&c->vtri))[v], NULL, 0, fan, TC_FAN_MAX, &closed);
    if (nf <= 0) return 0;
    const double *x = tc_vec_ptr(&c->x), *st = tc_vec_ptr(&c->strength);
    double scores[TC_TEAR_DIRECTIONS];
    int count = 0;
    double orth[3];
    cross3(n, pd, orth);
    for (int i = w ? -6 : -2; i < 2 * nf; i++) {
        double d[3], s_ahead, lead[3];  /* lead: a rest point the direction leads through */
        if (i < -2) {  /* woven: along the weft or the warp, both senses */
            const double *axis = i < -4 ? f : w, sg = (i & 1) ? -1.0 : 1.0;
            for (int k = 0; k < 3; k++) d[k] = sg * axis[k];
            if (!strength_ahead(c, v, d, fan, nf, &s_ahead, lead)) continue;
        } else if (i < 0) {  /* the orthogonal direction, both senses */
            double sg = i == -2 ? 1.0 : -1.0;
            for (int k = 0; k < 3; k++) d[k] = sg * orth[k];
            if (!strength_ahead(c, v, d, fan, nf, &s_ahead, lead)) continue;
        } else {  /* the two edges of each fan triangle at v (closed fans list each edge twice) */
            const int32_t *T = (const int32_t *)tc_vec_ptr(&c->tri) + 3 * (size_t)fan[i / 2];
            int32_t w = T[(tc_tri_local(c, fan[i / 2], v) + 1 + i % 2) % 3];
            int32_t p = tc_pair_find(c, v, w);
            const int32_t *pt = (const int32_t *)tc_vec_ptr(&c->ptris) + 2 * (size_t)p;
            if (pt[0] < 0 || pt[1] < 0) continue;  /* a boundary: nothing left to cut */
            sub3(x + 3 * w, x + 3 * v, d);
            double dn = dot3(d, n);
            for (int k = 0; k < 3; k++) d[k] -= dn * n[k];
            double l = sqrt(dot3(d, d));
            if (!(l > 0)) continue;
            for (int k = 0; k < 3; k++) d[k] /= l;
            s_ahead = st[w];
            memcpy(lead, (const double *)tc_vec_ptr(&c->rest) + 3 * (size_t)w, sizeof lead);
        }
        if (fwd && dot3(d, fwd) <= TC_TIP_FORWARD_COS * sqrt(dot3(fwd, fwd))) continue;
        double m[3];
        cross3(d, n, m);
        double open;  /* the cut's opening index (1 at tear_stress with strength 1) */
        if (w) {
            /* the thread stresses ahead, at half the critical distance along the direction (the
               point method of the theory of critical distances, Taylor 2007): the crossing threads
               a cut must break are those ahead of the tip, and the tip's own disc mixes in the
               stress of the threads parallel to the crack beside it, which a net does not feel */
            double Sa[9], cw = dot3(m, w), cf = dot3(m, f), aw = sww, af = sff;
            if (stress_ahead(c, v, lead, fan, nf, Sa)) { aw = quad(Sa, w) / c->mat.tear_stress; af = quad(Sa, f) / c->mat.tear_stress_weft; }
            /* normalised: w and f need not be orthogonal in a sheared sheet, and a cut along a
               thread (m normal to it) must weigh only the other family */
            const double q = cw * cw + cf * cf;
            open = q > 0 ? (aw * cw * cw + af * cf * cf) / q : 0.0;
        }
        else open = quad(S, m) / c->mat.tear_stress;
        double score = open / s_ahead;
        /* available only if the stress opens it: the opening index over the segment's strength
           (the mean of its two ends') passes 1 */
        if (!(open > 0.5 * (st[v] + s_ahead))) continue;
        if (count == TC_TEAR_DIRECTIONS && !(score > scores[count - 1])) continue;
        int j = count < TC_TEAR_DIRECTIONS ? count++ : count - 1;  /* insertion, best first */
        for (; j > 0 && scores[j - 1] < score; j--) { scores[j] = scores[j - 1]; memcpy(out + 3 * j, out + 3 * (j - 1), 3 * sizeof(double)); }
        scores[j] = score;
        memcpy(out + 3 * j, d, 3 * sizeof(double));
    }
    return count;
}

/* ---------------- tips ---------------- */

/* A new tip at v; advance: what it has earned already (negative: the length its start cut, which it
 * pays back before cutting more, so a start or a restart never lets a tear run faster). */
static int tip_add(tc_cloth *c, int32_t v, const double *dir, double advance)
{
    if (tc_vec_push_i32(&c->tips, v) || tc_vec_push_f64(&c->tipadv, advance)) return TC_ERR_NOMEM;
    if (tc_vec_resize(&c->tipdir, 3 * c->tips.len)) return TC_ERR_NOMEM;
    memcpy((double *)tc_vec_ptr(&c->tipdir) + 3 * (c->tips.len - 1), dir, 3 * sizeof(double));
    return TC_OK;
}

static void tip_remove(tc_cloth *c, size_t i)
{
    int32_t *tp = tc_vec_ptr(&c->tips);
    double *td = tc_vec_ptr(&c->tipdir), *ta = tc_vec_ptr(&c->tipadv);
    size_t last = c->tips.len - 1;
    tp[i] = tp[last];
    ta[i] = ta[last];
    memcpy(td + 3 * i, td + 3 * last, 3 * sizeof(double));
    c->tips.len--;
    c->tipadv.len = c->tips.len;
    c->tipdir.len = 3 * c->tips.len;
}

static void unit_dir(const tc_cloth *c, int32_t a, int32_t b, double *d)
{
    const double *x = tc_vec_ptr(&c->x);
    sub3(x + 3 * b, x + 3 * a, d);
    double l = sqrt(dot3(d, d));
    if (l > 0) { d[0] /= l; d[1] /= l; d[2] /= l; }
}

static double rest_length(const tc_cloth *c, int32_t a, int32_t b)
{
    const double *X = tc_vec_ptr(&c->rest);
    return sqrt(dist2(X + 3 * a, X + 3 * b));
}

/* Cuts one segment from tip ti; updates or ends the tip. Returns the segment's rest length, 0 when
 * nothing could be cut along dir (the tip is then unchanged). */
static double advance_tip(tc_cloth *c, size_t ti, const double *dir)
{
    int32_t v = ((int32_t *)tc_vec_ptr(&c->tips))[ti];
    int32_t pair = -1;
    int32_t w = tc_prepare_segment(c, v, dir, NULL, 0, &pair);
    if (w < 0 || pair < 0) return 0.0;
    bool w_boundary = tc_is_boundary_vertex(c, w);
    double len = rest_length(c, v, w);
    int32_t verts[2] = {v, w};
    unsigned dup;
    if (tc_separate(c, &pair, 1, verts, 2, &dup)) return 0.0;
    c->stats.cuts++;
    double d[3];
    unit_dir(c, v, w, d);
    if (w_boundary || (dup & 2u)) tip_remove(c, ti);
    else {
        ((int32_t *)tc_vec_ptr(&c->tips))[ti] = w;
        memcpy((double *)tc_vec_ptr(&c->tipdir) + 3 * ti, d, sizeof d);
    }
    return len > 0 ? len : TC_TINY;
}

/* Starts a tear at v: inward along dir from a boundary vertex (back: the sense tried when dir
 * leads nowhere, or NULL), or from an interior vertex along dir and back (two segments, since one
 * slit with two interior ends has no indexed-mesh representation). one_way: scripted, the second
 * segment continues forward from the first. Returns 1 when it cut, 0 when it could not, -1 on
 * allocation failure. */
static int start_tear(tc_cloth *c, int32_t v, const double *dir, const double *back, bool one_way)
{
    if (tc_is_boundary_vertex(c, v)) {
        int32_t pair = -1, w = tc_prepare_segment(c, v, dir, NULL, 0, &pair);
        if ((w < 0 || pair < 0) && back && !one_way) w = tc_prepare_segment(c, v, back, NULL, 0, &pair);
        if (w < 0 || pair < 0) return 0;
        bool wb = tc_is_boundary_vertex(c, w);
        int32_t verts[2] = {v, w};
        unsigned dup;
        if (tc_separate(c, &pair, 1, verts, 2, &dup)) return 0;
        c->stats.cuts++;
        c->stats.tears_started++;
        double d[3];
        unit_dir(c, v, w, d);
        if (!wb && !(dup & 2u)) return tip_add(c, w, d, one_way ? 0.0 : -rest_length(c, v, w)) ? -1 : 1;
        return 1;
    }
    int32_t p1 = -1, p2 = -1;
    int32_t w1 = tc_prepare_segment(c, v, dir, NULL, 0, &p1);
    if (w1 < 0 || p1 < 0) return 0;
    int32_t w2;
    const int32_t *from2 = &v;
    double d1[3];
    unit_dir(c, v, w1, d1);
    if (one_way) {  /* scripted: continue forward from w1 so the slit has two edges */
        w2 = tc_prepare_segment(c, w1, d1, &p1, 1, &p2);
        from2 = &w1;
    } else {
        double opp[3] = {-dir[0], -dir[1], -dir[2]};
        w2 = tc_prepare_segment(c, v, back ? back : opp, &p1, 1, &p2);
    }
    if (w2 < 0 || p2 < 0 || p2 == p1) return 0;
    bool b1 = tc_is_boundary_vertex(c, w1), b2 = tc_is_boundary_vertex(c, w2);
    int32_t cut[2] = {p1, p2};
    int32_t verts[3] = {v, w1, w2};
    unsigned dup;
    if (tc_separate(c, cut, 2, verts, 3, &dup)) return 0;
    c->stats.cuts += 2;
    c->stats.tears_started++;
    double d2[3];
    unit_dir(c, *from2, w2, d2);
    if (!one_way && !b1 && !(dup & 2u)) if (tip_add(c, w1, d1, -rest_length(c, v, w1))) return -1;
    if (!b2 && !(dup & 4u)) if (tip_add(c, w2, d2, one_way ? 0.0 : -rest_length(c, *from2, w2))) return -1;
    return 1;
}

/* ---------------- where: the scan for new tears ---------------- */

/* A vertex that may start a tear; region: which region over threshold it belongs to. */
typedef struct { double ratio; int32_t v, region; } candidate;
enum { TC_CANDIDATES_KEPT = TC_TEAR_CANDIDATES * TC_REGION_TRIES };

static void cand_push(candidate *cs, int *n, double r, int32_t v, int32_t region)
{
    if (*n == TC_CANDIDATES_KEPT && cs[TC_CANDIDATES_KEPT - 1].ratio >= r) return;
    int i = *n < TC_CANDIDATES_KEPT ? (*n)++ : TC_CANDIDATES_KEPT - 1;
    cs[i].ratio = r; cs[i].v = v; cs[i].region = region;
    for (; i > 0 && cs[i].ratio > cs[i - 1].ratio; i--) { candidate t = cs[i]; cs[i] = cs[i - 1]; cs[i - 1] = t; }
}

/* Per-vertex marks of one scan (vstamp holds three per vertex) and the ratio memo (vsa). */
enum { MARK_NEAR_HOT = 0, MARK_EVALUATED = 1, MARK_FLOODED = 2 };

static double ratio_memo(tc_cloth *c, int32_t v, int32_t emark)
{
    int32_t *vs = tc_vec_ptr(&c->vstamp);
    double *R = tc_vec_ptr(&c->vsa);
    if (vs[3 * (size_t)v + MARK_EVALUATED] != emark) {
        double pd[3];
        R[v] = vertex_ratio(c, v, pd, NULL, NULL, NULL, NULL, NULL);
        vs[3 * (size_t)v + MARK_EVALUATED] = emark;
    }
    return R[v];
}

/* The region over threshold around v: every vertex connected to v through vertices whose ratio is
 * above 1 (v itself whatever its ratio). Marks it and leaves it in vqueue; returns its size. */
static int32_t flood(tc_cloth *c, int32_t v, int32_t emark, int32_t fmark)
{
    int32_t *vs = tc_vec_ptr(&c->vstamp), *q = tc_vec_ptr(&c->vqueue);
    int32_t n = 0;
    ratio_memo(c, v, emark);
    vs[3 * (size_t)v + MARK_FLOODED] = fmark;
    q[n++] = v;
    for (int32_t head = 0; head < n; head++) {
        int32_t u = q[head], buf[TC_FAN_MAX];
        int nf;
        const int32_t *fan = fan_of(c, u, buf, &nf);
        for (int i = 0; i < nf; i++)
            for (int k = 0; k < 3; k++) {
                int32_t w = ((const int32_t *)tc_vec_ptr(&c->tri))[3 * (size_t)fan[i] + k];
                if (vs[3 * (size_t)w + MARK_FLOODED] == fmark) continue;
                double r = ratio_memo(c, w, emark);
                if (!(r > 1.0)) continue;
                vs[3 * (size_t)w + MARK_FLOODED] = fmark;
                q[n++] = w;
            }
    }
    return n;
}

/* WHERE. A vertex's disc stress is a mean of its disc's triangle stresses, and no in-plane
 * eigenvalue of a mean exceeds the largest of the triangles' own: a vertex can pass its threshold
 * only if a triangle of its disc has sigma_1 above tear_stress times the smallest strength of the
 * cloth. So the scan reads one number per triangle (triangles t0 .. t0 + count - 1, mod nt), and
 * evaluates disc stresses only around those "hot" triangles (every vertex within the radius of a
 * corner of one): exact, and cheap while nothing is near tearing. The vertices over threshold form
 * regions (connected through vertices over threshold); a region holding a running tip is being
 * torn by it (this is the exclusion near a tip: the tip's own stress concentration, however far it
 * reaches, never starts a branch). Every other region starts one tear, at its highest vertex: the
 * best TC_TEAR_CANDIDATES regions per step, returned best first. */
static int scan(tc_cloth *c, int32_t t0, int32_t count, candidate *cs)
{
    const double *st = tc_vec_ptr(&c->strength);
    double smin = INFINITY;
    for (int32_t v = 0; v < c->nv; v++) smin = st[v] < smin ? st[v] : smin;
    /* woven: no thread index exceeds sigma_1 over the weaker thread's strength */
    const double weakest = c->mat.orthotropic && c->mat.tear_stress_weft < c->mat.tear_stress ? c->mat.tear_stress_weft
                                                                                             : c->mat.tear_stress;
    const double hot = weakest * smin;
    int32_t vmark = 0, *vs = tc_vec_ptr(&c->vstamp);
    const int32_t *T = tc_vec_ptr(&c->tri);
    const double *X = tc_vec_ptr(&c->rest), *sig = tc_vec_ptr(&c->sig);
    for (int32_t k = 0; k < count; k++) {
        int32_t t = (t0 + k) % c->nt;
        /* sigma_1 = mean + sqrt(dd^2 + sxy^2) <= mean + |dd| + |sxy|: a triangle that bound (with
           room for the rounding of either side) leaves below the threshold is not hot, without the
           square root; the others are judged on sigma_1 itself, derived from sigma as the PRINCIPAL
           array is (core.h) */
        const double *sg = sig + 3 * (size_t)t;
        const double mean = 0.5 * (sg[0] + sg[1]), bound = fabs(0.5 * (sg[0] - sg[1])) + fabs(sg[2]);
        if (mean + bound + 1e-12 * (fabs(mean) + bound) < hot) continue;
        double pr[2];
        tc_tri_principal(c, (size_t)t, pr);
        if (!(pr[0] > hot)) continue;
        if (!vmark) vmark = new_mark(c);
        double P[3];
        for (int q = 0; q < 3; q++) P[q] = (X[3 * T[3 * t] + q] + X[3 * T[3 * t + 1] + q] + X[3 * T[3 * t + 2] + q]) / 3.0;
        /* the corners of t are in their own discs (their fans); any other vertex whose rest
           position is within the radius of t's centroid may hold t in its disc */
        int32_t m = disc_walk(c, P, c->mat.tear_radius, &t, 1, BY_CORNER);
        const int32_t *Q = tc_vec_ptr(&c->tqueue);
        double r2 = c->mat.tear_radius * c->mat.tear_radius;
        for (int32_t i = 0; i < m; i++)
            for (int j = 0; j < 3; j++) {
                int32_t u = T[3 * Q[i] + j];
                if (Q[i] == t || dist2(X + 3 * u, P) <= r2) vs[3 * (size_t)u + MARK_NEAR_HOT] = vmark;
            }
    }
    if (!vmark) return 0;
    int32_t emark = new_mark(c), fmark = new_mark(c);
    bool tips_flooded = false;
    int n = 0;
    for (int32_t v = 0; v < c->nv; v++) {
        if (vs[3 * (size_t)v + MARK_NEAR_HOT] != vmark || vs[3 * (size_t)v + MARK_FLOODED] == fmark) continue;
        if (!(ratio_memo(c, v, emark) > 1.0)) continue;
        if (!tips_flooded) {  /* the regions of the running tips first: they start nothing */
            for (size_t i = 0; i < c->tips.len; i++) {
                int32_t tp = ((const int32_t *)tc_vec_ptr(&c->tips))[i];
                if (vs[3 * (size_t)tp + MARK_FLOODED] != fmark) flood(c, tp, emark, fmark);
            }
            tips_flooded = true;
            if (vs[3 * (size_t)v + MARK_FLOODED] == fmark) continue;
        }
        /* the region's best few vertices: when the remesh refuses every direction at the best
           one (a held corner, a crack face), the next one starts the region's tear */
        int32_t m = flood(c, v, emark, fmark), best[TC_REGION_TRIES];
        const int32_t *q = tc_vec_ptr(&c->vqueue);
        const double *R = tc_vec_ptr(&c->vsa);
        int nb = 0;
        for (int32_t i = 0; i < m; i++) {
            int32_t u = q[i];
            if (!(R[u] > 1.0)) continue;
            if (nb == TC_REGION_TRIES && !(R[u] > R[best[nb - 1]])) continue;
            int j = nb < TC_REGION_TRIES ? nb++ : nb - 1;
            for (; j > 0 && R[best[j - 1]] < R[u]; j--) best[j] = best[j - 1];
            best[j] = u;
        }
        for (int j = 0; j < nb; j++) cand_push(cs, &n, R[best[j]], best[j], v);
    }
    return n;
}

/* ---------------- how fast: the tips ---------------- */

/* Rayleigh wave speed of the sheet, c_R = c_s (0.862 + 1.14 nu) / (1 + nu) (Viktorov's fit), with
 * the shear wave speed c_s = sqrt(mu / rho) of a membrane: about 0.93 c_s at nu = 0.3. */
static double rayleigh_speed(const tc_material *m)
{
    double mu = m->young / (2.0 * (1.0 + m->poisson));
    return sqrt(mu / m->density) * (0.862 + 1.14 * m->poisson) / (1.0 + m->poisson);
}

/* PROPAGATION. Stress-based, over the material disc: a tip advances while the disc stress at the
 * tip exceeds its threshold (ratio r > 1) and retires when it falls to it. Why stress and not an
 * energy release rate G against G_c: the same measure then starts, drives and arrests a tear (a
 * tear can start where there is no crack, and G is not defined there), and it costs one disc
 * average per tip instead of a J-integral contour on the deformed mesh; averaging the stress over
 * a critical distance is the theory of critical distances (Taylor, 2007), which is equivalent to
 * G = G_c for a sharp crack when the radius is ~ E G_c / (pi sigma_E^2) (see materials.py).
 * Speed: Freund's equation of motion of a crack, v = c_R (1 - G_c / G), with G / G_c = r^2 (G grows
 * as the square of the stress) and c_R capped to the material's fastest crack speed (brittle cracks
 * branch before reaching c_R): v = crack_speed_ratio c_R (1 - 1 / r^2). The advance v dt is earned
 * every step and spent in whole segments (their rest length), the rest carried over, so the tear
 * after a given time is the same at any time step. Segments after the first in one step use this
 * step's stresses, which do not yet feel the cut: a tip stops early (keeping what it earned) where
 * they fall below the threshold, and only a fresh stress (the next step's) retires it. */
static double crack_speed(const tc_cloth *c, double r)
{
    return c->mat.crack_speed_ratio * rayleigh_speed(&c->mat) * (1.0 - 1.0 / (r * r));
}

/* Tip i earns `earned` metres and cuts while what it has earned is positive and its disc stress is
 * over the threshold (checked: already known for this step's stress). S, n, pd: the disc stress at
 * the tip. Returns 1 if slot i still holds this tip afterwards, 0 if the tip ended (slot i
 * then holds another one), -1 on allocation failure. */
static int run_tip(tc_cloth *c, size_t i, double earned, bool checked, double *S, double *n, double *pd)
{
    double *adv = (double *)tc_vec_ptr(&c->tipadv) + i;
    *adv += earned;
    for (int first = 1; *adv > 0; first = 0) {
        int32_t v = ((int32_t *)tc_vec_ptr(&c->tips))[i];
        double w[3], f[3];
        bool woven = false;
        if (!first || !checked) {
            if (!(vertex_ratio(c, v, pd, n, S, w, f, &woven) > 1.0)) {
                if (*adv > earned) *adv = earned;
                break;
            }
        } else if (c->mat.orthotropic) {
            woven = vertex_axes(c, v, n, w, f);  /* S, n, pd: the caller's, of this step */
        }
        double dirs[3 * TC_TEAR_DIRECTIONS];
        const double *prev = (const double *)tc_vec_ptr(&c->tipdir) + 3 * i;
        int nd = rank_directions(c, v, S, n, pd, prev, woven ? w : NULL, f, dirs);
        size_t before = c->tips.len;
        double len = 0.0;
        for (int k = 0; k < nd && len == 0.0; k++) {
            len = advance_tip(c, i, dirs + 3 * k);
            if (marks_ready(c)) return -1;  /* a refused segment may still have split an edge */
        }
        if (len == 0.0) { tip_remove(c, i); return 0; }  /* no way forward: the tip ends */
        if (c->tips.len < before) return 0;
        adv = (double *)tc_vec_ptr(&c->tipadv) + i;
        *adv -= len;
    }
    return 1;
}

/* The tips that ran before this step: retire those whose (fresh) disc stress fell to the
 * threshold, advance the others. */
static int advance_tips(tc_cloth *c, double dt)
{
    for (size_t i = 0; i < c->tips.len;) {
        int32_t v = ((int32_t *)tc_vec_ptr(&c->tips))[i];
        double pd[3], n[3], S[9];
        double r = vertex_ratio(c, v, pd, n, S, NULL, NULL, NULL);
        if (!(r > 1.0)) { tip_remove(c, i); c->stats.tips_retired++; continue; }
        int rc = run_tip(c, i, crack_speed(c, r) * dt, true, S, n, pd);
        if (rc < 0) return TC_ERR_NOMEM;
        if (rc > 0) i++;
    }
    return TC_OK;
}

/* A held vertex over its threshold whose fan is a single triangle has nothing left to separate (a
 * clamp's corner, the last element joining two hands): the cloth slips out of the grip there, as a
 * thread pulls out of fingers, so no held configuration stays overstressed. Counted in
 * tc_stats.grips_released. */
static void let_go(tc_cloth *c, int32_t v)
{
    int8_t *pin = tc_vec_ptr(&c->vpin);
    int32_t *vh = tc_vec_ptr(&c->vhandle);
    if (!pin[v] && vh[v] < 0) return;
    int32_t fan[TC_FAN_MAX];
    bool closed;
    if (tc_fan_walk(c, v, ((int32_t *)tc_vec_ptr(&c->vtri))[v], NULL, 0, fan, TC_FAN_MAX, &closed) != 1) return;
    if (vh[v] >= 0) {
        tc_handle *H = &c->handles[vh[v]];
        for (int32_t i = 0; i < H->count; i++)
            if (H->verts[i] == v) {
                H->count--;
                H->verts[i] = H->verts[H->count];
                memcpy(H->grasp + 3 * i, H->grasp + 3 * H->count, 3 * sizeof(double));
                break;
            }
        vh[v] = -1;
    }
    pin[v] = 0;
    c->stats.grips_released++;
}

/* Starts a tear at each candidate (the best vertex of a region over threshold). The new tips started during this step: they earn
 * its advance at the speed of the stress that started them (so the tear after a given time does
 * not depend on the step), spent with this step's stresses. */
static int start_tears(tc_cloth *c, const candidate *cs, int n, double dt)
{
    int32_t done[TC_CANDIDATES_KEPT];
    int ndone = 0;
    for (int i = 0; i < n; i++) {
        int32_t v = cs[i].v;
        bool region_done = false;
        for (int k = 0; k < ndone; k++) region_done |= done[k] == cs[i].region;
        if (region_done || ndone == TC_TEAR_CANDIDATES) continue;
        double pd[3], nrm[3], S[9], dirs[3 * TC_TEAR_DIRECTIONS], w[3], f[3];
        bool woven = false;
        if (!(vertex_ratio(c, v, pd, nrm, S, w, f, &woven) > 0)) continue;
        int nd = rank_directions(c, v, S, nrm, pd, NULL, woven ? w : NULL, f, dirs);
        size_t before = c->tips.len;
        int rc = 0;
        for (int k = 0; k < nd && rc == 0; k++) {
            /* the other way: the best direction pointing away from this one */
            const double *d1 = dirs + 3 * k;
            double back[3] = {-d1[0], -d1[1], -d1[2]};
            for (int j = 0; j < nd; j++)
                if (dot3(dirs + 3 * j, d1) < 0) { memcpy(back, dirs + 3 * j, sizeof back); break; }
            rc = start_tear(c, v, d1, back, false);
            /* even a start that gave up may have split an edge: the marks follow the mesh */
            if (rc >= 0 && marks_ready(c)) return TC_ERR_NOMEM;
        }
        if (rc < 0) return TC_ERR_NOMEM;
        if (rc == 0) {
            let_go(c, v);
            continue;
        }
        done[ndone++] = cs[i].region;
        /* at most two new tips, appended; running one may move the other into its slot */
        int32_t fresh[2];
        int nfresh = 0;
        for (size_t k = before; k < c->tips.len; k++) fresh[nfresh++] = ((int32_t *)tc_vec_ptr(&c->tips))[k];
        for (int k = 0; k < nfresh; k++) {
            size_t ti = before;
            while (ti < c->tips.len && ((int32_t *)tc_vec_ptr(&c->tips))[ti] != fresh[k]) ti++;
            if (ti == c->tips.len) continue;
            if (!(disc_stress(c, fresh[k], pd, nrm, S) > 0)) continue;
            if (run_tip(c, ti, crack_speed(c, cs[i].ratio) * dt, false, S, nrm, pd) < 0) return TC_ERR_NOMEM;
        }
    }
    return TC_OK;
}

int tc_tear_step(tc_cloth *c, double dt)
{
    if (c->dirty) { tc_element_pass(c, tc_vec_ptr(&c->x)); tc_total_force(c, tc_vec_ptr(&c->x)); }
    if (c->nt == 0) return TC_OK;
    if (marks_ready(c)) return TC_ERR_NOMEM;
    /* how far: the tips that ran before this step (they look pairs up: mesh.c's hash) */
    if (c->tips.len && tc_pair_hash_ensure(c)) return TC_ERR_NOMEM;
    if (advance_tips(c, dt)) return TC_ERR_NOMEM;
    /* where: every triangle while no tear runs; with tips, one slice of 1/scan_period per step, so
       a region elsewhere starts its own tear within scan_period steps at a flat cost */
    int32_t count = c->nt;
    if (c->tips.len) count = (c->nt + c->tear.scan_period - 1) / c->tear.scan_period;
    int32_t t0 = c->scan_cursor % c->nt;
    c->scan_cursor = (int32_t)((t0 + (int64_t)count) % c->nt);
    candidate cs[TC_CANDIDATES_KEPT];
    if (marks_ready(c)) return TC_ERR_NOMEM;
    int n = scan(c, t0, count, cs);
    int rc = n ? (tc_pair_hash_ensure(c) ? TC_ERR_NOMEM : start_tears(c, cs, n, dt)) : TC_OK;
    return rc ? rc : tc_fragments_remove(c);  /* pieces the cuts set free, if tiny */
}

int tc_cloth_scripted_tear(tc_cloth *c, int32_t start, const double direction[3], double length, int32_t *cuts)
{
    *cuts = 0;
    if (start < 0 || start >= c->nv) { tc_set_err(c, "scripted tear starts at vertex %d, outside [0, %d)", (int)start, (int)c->nv); return TC_ERR_INPUT; }
    double l = sqrt(dot3(direction, direction));
    if (!(l > 0) || !isfinite(l)) { tc_set_err(c, "scripted tear direction must be a non-zero finite vector"); return TC_ERR_INPUT; }
    if (!(length > 0) || !isfinite(length)) { tc_set_err(c, "scripted tear length must be > 0 m (got %g)", length); return TC_ERR_INPUT; }
    if (tc_pair_hash_ensure(c)) { tc_set_err(c, "out of memory"); return TC_ERR_NOMEM; }  /* the cuts look pairs up */
    if (c->dirty) { tc_element_pass(c, tc_vec_ptr(&c->x)); tc_total_force(c, tc_vec_ptr(&c->x)); }
    double d[3] = {direction[0] / l, direction[1] / l, direction[2] / l};
    const double *x = tc_vec_ptr(&c->x);
    double origin[3] = {x[3 * start], x[3 * start + 1], x[3 * start + 2]};
    int32_t before = c->stats.cuts;
    size_t ntips = c->tips.len;
    int rc = start_tear(c, start, d, NULL, true);
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
    return tc_fragments_remove(c);
}
