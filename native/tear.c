/* tear.c - stress-driven tearing (Le Gouis et al. 2017, section V): where a tear starts, which way
 * it runs, and its tips; the remesh each cut makes is remesh.c's.
 *
 * Where: per vertex, the area-weighted average of its triangles' stress tensors, projected on the
 * vertex tangent plane; its largest eigenvalue against tear_stress * strength(v). Until a tear
 * runs, every vertex is examined each step (the highest over the threshold starts the tear); while
 * tears run, only their tips are, plus one slice of 1/scan_period of the other vertices per step,
 * so a second tear elsewhere still starts within scan_period steps at a flat, small cost.
 *
 * Which way: orthogonal to the principal direction, in the tangent plane at the tip. A tear from an
 * interior vertex cuts two segments (both ways) before separating, since one slit with two
 * interior ends has no indexed-mesh representation. A tip whose target lies on a boundary (the
 * rim, or another tear) ends there.
 */
#include "core.h"

#include <math.h>
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

/* Stress of one vertex by walking its fan (used for tips and scan slices). */
static double vertex_stress(tc_cloth *c, int32_t v, double *dir, double *normal)
{
    int32_t fan[TC_FAN_MAX];
    bool closed;
    int nf = tc_fan_walk(c, v, ((int32_t *)tc_vec_ptr(&c->vtri))[v], NULL, 0, fan, TC_FAN_MAX, &closed);
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
    int32_t w = tc_prepare_segment(c, v, dir, NULL, 0, &pair);
    if (w < 0 || pair < 0) { tip_remove(c, ti); return 0; }
    bool w_boundary = tc_is_boundary_vertex(c, w);
    int32_t verts[2] = {v, w};
    unsigned dup;
    if (tc_separate(c, &pair, 1, verts, 2, &dup)) { tip_remove(c, ti); return 0; }
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
    if (tc_is_boundary_vertex(c, v)) {
        int32_t pair = -1, w = tc_prepare_segment(c, v, dir, NULL, 0, &pair);
        const double *used = dir;
        if ((w < 0 || pair < 0) && !one_way) { w = tc_prepare_segment(c, v, back, NULL, 0, &pair); used = back; }
        if (w < 0 || pair < 0) return 0;
        bool wb = tc_is_boundary_vertex(c, w);
        int32_t verts[2] = {v, w};
        unsigned dup;
        if (tc_separate(c, &pair, 1, verts, 2, &dup)) return 0;
        c->stats.cuts++;
        c->stats.tears_started++;
        double d[3];
        unit_dir(c, v, w, d);
        (void)used;
        if (!wb && !(dup & 2u)) return tip_add(c, w, d) ? -1 : 1;
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
        w2 = tc_prepare_segment(c, v, back, &p1, 1, &p2);
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
