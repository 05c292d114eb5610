/* mesh.c - validation and topology of a cloth's mesh: vertex and triangle storage, the pair
 * table (mesh edges and bending flaps, with a hash for lookup), triangle adjacency, rest-shape
 * elements, lumped masses and bending stencils.
 *
 * Everything that tearing changes is updated locally here (acquire/release a pair, add/remove a
 * stencil, recompute one triangle's rest element), so a cut costs a few microseconds whatever the
 * mesh size.
 */
#include "core.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ---------------- pair hash ---------------- */

static inline size_t hslot(int32_t a, int32_t b, size_t cap)
{
    uint64_t h = (uint64_t)(uint32_t)a * 0x9E3779B97F4A7C15ull ^ (uint64_t)(uint32_t)b * 0xC2B2AE3D27D4EB4Full;
    return (size_t)(h ^ (h >> 29)) & (cap - 1);
}

#define HEMPTY (-1)
#define HTOMB (-2)

/* A slot holds only the pair id (or HEMPTY / HTOMB): its key is that pair's ends, pi and pj, so
 * keys kept beside the ids would be a copy (8 of the 12 bytes a slot took, 8 MB of a
 * 100K-triangle cloth whose hash sits at a quarter load). A probe reads pi/pj of the candidate. */
static inline bool hslot_is(const tc_cloth *c, int32_t v, int32_t a, int32_t b)
{
    return v >= 0 && ((const int32_t *)tc_vec_ptr(&c->pi))[v] == a && ((const int32_t *)tc_vec_ptr(&c->pj))[v] == b;
}

static int hash_rehash(tc_cloth *c, size_t ncap)
{
    int32_t *vv = malloc(ncap * sizeof *vv);
    if (!vv) return TC_ERR_NOMEM;
    const int32_t *pi = tc_vec_ptr(&c->pi), *pj = tc_vec_ptr(&c->pj);
    for (size_t s = 0; s < ncap; s++) vv[s] = HEMPTY;
    for (size_t s = 0; s < c->hcap; s++) {
        const int32_t p = c->hvals[s];
        if (p < 0) continue;
        size_t t = hslot(pi[p], pj[p], ncap);
        while (vv[t] != HEMPTY) t = (t + 1) & (ncap - 1);
        vv[t] = p;
    }
    free(c->hvals);
    c->hvals = vv; c->hcap = ncap; c->htomb = 0;
    return TC_OK;
}

/* The hash serves lookups: the mesh build, tears (tc_tear_step when a tip runs or a tear starts,
 * tc_cloth_scripted_tear) and the removal of the pieces they free; no step of a cloth that does not
 * tear reads it. So a new cloth drops it after its build (a 100K-triangle cloth's 2^19 slots: 21
 * bytes per triangle, 2 % of its memory target) and makes it again from the pairs when a tear
 * first needs it (tc_pair_hash_ensure); a snapshot carries it (made for the blob where dropped), and
 * a cloth read from one keeps it as read, so that its own snapshot is the blob it came from. Where it is absent a release leaves it
 * absent (it is made from the pairs as they are then) and a lookup scans the pairs (a caller that
 * did not ensure it: correct, slow). */
int tc_pair_hash_ensure(tc_cloth *c)
{
    if (c->hvals) return TC_OK;
    const int32_t *pi = tc_vec_ptr(&c->pi);
    size_t live = 0, cap = TC_HASH_INITIAL;
    for (size_t p = 0; p < c->pi.len; p++) live += pi[p] >= 0;
    while ((live + 1) * 4 > cap * 3) cap *= 2;  /* under acquire's three-quarter load, one more fits */
    c->hvals = malloc(cap * sizeof(int32_t));
    if (!c->hvals) return TC_ERR_NOMEM;
    c->hcap = cap;
    tc_pair_hash_rebuild(c);
    return TC_OK;
}

void tc_pair_hash_drop(tc_cloth *c)
{
    free(c->hvals);
    c->hvals = NULL;
    c->hcap = c->hcount = c->htomb = 0;
}

int32_t tc_pair_find(const tc_cloth *c, int32_t a, int32_t b)
{
    if (a > b) { int32_t t = a; a = b; b = t; }
    if (!c->hvals) {
        const int32_t *pi = tc_vec_ptr(&c->pi), *pj = tc_vec_ptr(&c->pj);
        for (size_t p = 0; p < c->pi.len; p++)
            if (pi[p] == a && pj[p] == b) return (int32_t)p;
        return -1;
    }
    size_t s = hslot(a, b, c->hcap);
    for (;;) {
        int32_t v = c->hvals[s];
        if (v == HEMPTY) return -1;
        if (hslot_is(c, v, a, b)) return v;
        s = (s + 1) & (c->hcap - 1);
    }
}

int32_t tc_pair_acquire(tc_cloth *c, int32_t a, int32_t b)
{
    if (tc_pair_hash_ensure(c)) return -1;
    int32_t p = tc_pair_find(c, a, b);
    c->pair_version++;  /* a new pair, or a triangle's edge where a flap was: the rows change */
    if (p >= 0) { ((int32_t *)tc_vec_ptr(&c->puse))[p]++; return p; }
    if (a > b) { int32_t t = a; a = b; b = t; }
    /* at three-quarter load (live keys and tombstones) rebuild: twice as large when the live keys
       alone fill half of it, else the same size (that only sweeps the tombstones away). The load
       then stays in (3/8, 3/4]: linear probing at 0.6 reads ~1.7 slots per hit and ~3.6 per miss,
       and the pairs are looked up at the build and by tears, not in a step; the earlier half-load
       rule kept a 100K-triangle cloth's 300K pairs in 2^20 slots (4 MB, 42 B per triangle) where
       2^19 hold them (21 B) */
    if ((c->hcount + c->htomb + 1) * 4 > c->hcap * 3) {
        if (hash_rehash(c, c->hcount * 2 + TC_HASH_INITIAL > c->hcap ? c->hcap * 2 : c->hcap)) return -1;
    }
    if (c->pfree.len) {
        p = ((int32_t *)tc_vec_ptr(&c->pfree))[--c->pfree.len];
    } else {
        p = (int32_t)c->pi.len;
        size_t n = c->pi.len + 1;
        if (tc_vec_resize(&c->pi, n) || tc_vec_resize(&c->pj, n) || tc_vec_resize(&c->puse, n) ||
            tc_vec_resize(&c->ptris, 2 * n) || tc_vec_resize(&c->pstencil, n) || tc_vec_resize(&c->pbend, n))
            return -1;
    }
    ((int32_t *)tc_vec_ptr(&c->pi))[p] = a;
    ((int32_t *)tc_vec_ptr(&c->pj))[p] = b;
    ((int32_t *)tc_vec_ptr(&c->puse))[p] = 1;
    ((int32_t *)tc_vec_ptr(&c->ptris))[2 * p] = -1;
    ((int32_t *)tc_vec_ptr(&c->ptris))[2 * p + 1] = -1;
    ((int32_t *)tc_vec_ptr(&c->pstencil))[p] = -1;
    ((double *)tc_vec_ptr(&c->pbend))[p] = 0.0;
    size_t s = hslot(a, b, c->hcap);
    while (c->hvals[s] >= 0) s = (s + 1) & (c->hcap - 1);
    if (c->hvals[s] == HTOMB) c->htomb--;
    c->hvals[s] = p;
    c->hcount++;
    return p;
}

void tc_pair_release(tc_cloth *c, int32_t p)
{
    int32_t *use = tc_vec_ptr(&c->puse);
    c->pair_version++;  /* an edge may become a flap, or the pair go */
    if (--use[p] > 0) return;
    int32_t *pi = tc_vec_ptr(&c->pi), *pj = tc_vec_ptr(&c->pj);
    if (c->hvals) {
        size_t s = hslot(pi[p], pj[p], c->hcap);
        while (c->hvals[s] != p) s = (s + 1) & (c->hcap - 1);
        c->hvals[s] = HTOMB; c->hcount--; c->htomb++;
    }
    pi[p] = -1; pj[p] = -1;
    ((double *)tc_vec_ptr(&c->pbend))[p] = 0.0;
    if (tc_vec_resize(&c->pfree, c->pfree.len + 1) == TC_OK)
        ((int32_t *)tc_vec_ptr(&c->pfree))[c->pfree.len - 1] = p;
}

/* The hash from the pairs' current ends (fragment.c renumbers vertices): same capacity, no more
 * keys than before, so it cannot fail. */
void tc_pair_hash_rebuild(tc_cloth *c)
{
    if (!c->hvals) return;  /* made from the pairs when next needed */
    const int32_t *pi = tc_vec_ptr(&c->pi), *pj = tc_vec_ptr(&c->pj);
    for (size_t s = 0; s < c->hcap; s++) c->hvals[s] = HEMPTY;
    c->hcount = 0; c->htomb = 0;
    for (size_t p = 0; p < c->pi.len; p++) {
        if (pi[p] < 0) continue;
        size_t s = hslot(pi[p], pj[p], c->hcap);
        while (c->hvals[s] != HEMPTY) s = (s + 1) & (c->hcap - 1);
        c->hvals[s] = (int32_t)p;
        c->hcount++;
    }
}

/* ---------------- storage ---------------- */

int tc_reserve_vertices(tc_cloth *c, int32_t n)
{
    size_t N = (size_t)n;
    /* sb, x0 and fel stay empty (step.c, fem.c) */
    tc_vec *v3[] = {&c->x, &c->v, &c->rest, &c->force, &c->sr, &c->sz, &c->sp, &c->sq,
                    &c->sfix, &c->sb2, &c->sdv, &c->v0, &c->vkinetic};
    for (size_t i = 0; i < sizeof v3 / sizeof *v3; i++)
        if (tc_vec_resize(v3[i], 3 * N)) return TC_ERR_NOMEM;
    if (c->vgoal.len && (tc_vec_resize(&c->vgoal, 3 * N) || tc_vec_resize(&c->vgoal0, 3 * N)))  /* once made */
        return TC_ERR_NOMEM;
    if (c->vpink.len && tc_vec_resize(&c->vpink, N)) return TC_ERR_NOMEM;
    if (tc_vec_resize(&c->diag, 12 * N) || tc_vec_resize(&c->pinv, 9 * N) ||
        tc_vec_resize(&c->snorm, 9 * N) || tc_vec_resize(&c->scount, N) ||
        tc_vec_resize(&c->vsa, N) || tc_vec_resize(&c->vcstate, N))
        return TC_ERR_NOMEM;
    size_t old = c->mass.len;
    if (tc_vec_resize(&c->mass, N) || tc_vec_resize(&c->vbend, N) || tc_vec_resize(&c->strength, N) ||
        tc_vec_resize(&c->vtri, N) || tc_vec_resize(&c->vflag, N) || tc_vec_resize(&c->vhandle, N) ||
        tc_vec_resize(&c->vpin, N) || tc_vec_resize(&c->groups, N * (size_t)(c->ng ? c->ng : 1)))
        return TC_ERR_NOMEM;
    for (size_t i = old; i < N; i++) {
        ((double *)tc_vec_ptr(&c->strength))[i] = 1.0;
        ((int32_t *)tc_vec_ptr(&c->vhandle))[i] = -1;
        ((int32_t *)tc_vec_ptr(&c->vtri))[i] = -1;
    }
    return TC_OK;
}

int tc_reserve_triangles(tc_cloth *c, int32_t m)
{
    size_t M = (size_t)m;
    if (tc_vec_resize(&c->tri, 3 * M) || tc_vec_resize(&c->tpair, 3 * M) ||
        tc_vec_resize(&c->grad, 4 * M) || tc_vec_resize(&c->area, M) || tc_vec_resize(&c->rot, 6 * M) ||
        tc_vec_resize(&c->sig, 3 * M) || tc_vec_resize(&c->uv, 6 * M))
        return TC_ERR_NOMEM;
    /* the grain angles and the axes only where stored (ortho.c's head) */
    const size_t old = c->tgrain.len;
    if ((old && tc_vec_resize(&c->tgrain, M)) ||
        (tc_axes_stored(c) && (tc_vec_resize(&c->twarp, 3 * M) || tc_vec_resize(&c->taxis, 2 * M))) ||
        tc_vec_resize(&c->tplast, 4 * M))
        return TC_ERR_NOMEM;
    /* a new triangle has no grain angle of its own until told (the remesh copies its parent's) */
    if (old)
        for (size_t t = old; t < M; t++) ((double *)tc_vec_ptr(&c->tgrain))[t] = NAN;
    return TC_OK;
}

int32_t tc_tri_local(const tc_cloth *c, int32_t t, int32_t v)
{
    const int32_t *T = (const int32_t *)tc_vec_ptr(&c->tri) + 3 * (size_t)t;
    return T[0] == v ? 0 : T[1] == v ? 1 : T[2] == v ? 2 : -1;
}

/* ---------------- the matrix by rows ---------------- */

/* The row pattern (core.h) from the pairs: a counting sort of both ends of every pair, O(pairs),
 * done lazily before an assembly when a tear changed any pair (tens of microseconds for a T-shirt,
 * against a milliseconds-long step); within a row, the slots of lower-numbered neighbours (the
 * Gauss-Seidel sweeps' order) first, then the others, each part in pair order, so the product is
 * deterministic. */
int tc_rows_update(tc_cloth *c)
{
    if (c->rows_built && c->rows_version == c->pair_version && c->rows_nv == c->nv) return TC_OK;
    const size_t nv = (size_t)c->nv, np = c->pi.len;
    if (tc_vec_resize(&c->rptr, nv + 1) || tc_vec_resize(&c->fptr, nv + 1) || tc_vec_resize(&c->pslot, 2 * np))
        return TC_ERR_NOMEM;
    int32_t *rp = tc_vec_ptr(&c->rptr), *fp = tc_vec_ptr(&c->fptr), *slot = tc_vec_ptr(&c->pslot);
    const int32_t *pi = tc_vec_ptr(&c->pi), *pj = tc_vec_ptr(&c->pj);
    memset(rp, 0, (nv + 1) * sizeof *rp);
    memset(fp, 0, (nv + 1) * sizeof *fp);
    for (size_t p = 0; p < np; p++) {
        if (pi[p] < 0) continue;
        int32_t *cnt = tc_pair_is_edge(c, p) ? rp : fp;
        cnt[pi[p] + 1]++; cnt[pj[p] + 1]++;
    }
    for (size_t i = 0; i < nv; i++) { rp[i + 1] += rp[i]; fp[i + 1] += fp[i]; }
    const size_t ne = (size_t)rp[nv], nf = (size_t)fp[nv];
    if (tc_vec_resize(&c->rcol, ne) || tc_vec_resize(&c->rblk, 9 * ne + TC_ROW_SLACK) || tc_vec_resize(&c->fcol, nf) ||
        tc_vec_resize(&c->fval, nf))
        return TC_ERR_NOMEM;
    int32_t *rcol = tc_vec_ptr(&c->rcol), *fcol = tc_vec_ptr(&c->fcol);
    /* fill: the running end of each row, then shift back. Two passes: first each pair's slot in the
       row of its higher-numbered end (there the other end is a lower neighbour), then its slot in
       the other row, so every row holds its lower slots first and the sweeps (solver.c) read either
       half as one range of the rows themselves; the product reads a row whole, in any order. */
    for (int pass = 0; pass < 2; pass++) {
        for (size_t p = 0; p < np; p++) {
            if (pi[p] < 0) { slot[2 * p] = slot[2 * p + 1] = -1; continue; }
            const int32_t i = pi[p], j = pj[p];
            /* end 0 (row i) or 1 (row j) whose slot goes in this pass */
            const int e = (j < i) == (pass == 0) ? 0 : 1;
            const int32_t row = e ? j : i, col = e ? i : j;
            if (tc_pair_is_edge(c, p)) { slot[2 * p + e] = rp[row]; rcol[rp[row]++] = col; }
            else { slot[2 * p + e] = fp[row]; fcol[fp[row]++] = col; }
        }
    }
    for (size_t i = nv; i > 0; i--) { rp[i] = rp[i - 1]; fp[i] = fp[i - 1]; }
    rp[0] = 0; fp[0] = 0;
    c->stats.matrix_bytes = (int64_t)(ne * (9 * sizeof(double) + sizeof(int32_t)) + nf * (sizeof(double) + sizeof(int32_t)) +
                                      nv * (12 * sizeof(double) + 2 * sizeof(int32_t)));
    c->rows_built = true;
    c->rows_version = c->pair_version;
    c->rows_nv = c->nv;
    return TC_OK;
}

bool tc_rows_sweep_ordered(const tc_cloth *c)
{
    if (!c->rows_built) return true;
    const int32_t nv = c->rows_nv;
    const int32_t *rp = tc_vec_ptr(&c->rptr), *rc = tc_vec_ptr(&c->rcol), *fp = tc_vec_ptr(&c->fptr), *fc = tc_vec_ptr(&c->fcol);
    for (int32_t i = 0; i < nv; i++) {
        if (tc_row_upper_start(rc, rp[i], rp[i + 1], i) < 0 || tc_row_upper_start(fc, fp[i], fp[i + 1], i) < 0)
            return false;
    }
    return true;
}

/* Rest element of triangle t: shape gradients in the triangle's own rest frame and its area. */
int tc_tri_rest(tc_cloth *c, int32_t t, char *msg, size_t msz)
{
    const int32_t *T = (const int32_t *)tc_vec_ptr(&c->tri) + 3 * (size_t)t;
    const double *X = tc_vec_ptr(&c->rest);
    const double *a = X + 3 * (size_t)T[0], *b = X + 3 * (size_t)T[1], *d = X + 3 * (size_t)T[2];
    double e1[3], e2[3], n[3];
    sub3(b, a, e1); sub3(d, a, e2); cross3(e1, e2, n);
    double l1 = sqrt(dot3(e1, e1)), l2 = sqrt(dot3(e2, e2)), nn = sqrt(dot3(n, n));
    double area = 0.5 * nn;
    double lmax = l1 > l2 ? l1 : l2;
    double e3[3]; sub3(d, b, e3);
    double l3 = sqrt(dot3(e3, e3));
    if (l3 > lmax) lmax = l3;
    /* relative test (TC_SLIVER_AREA): a sliver cannot be inverted reliably in double precision */
    if (!(area > TC_SLIVER_AREA * lmax * lmax) || !isfinite(area)) {
        if (msg) tc_culprit(t, T[0]), tc_culprit(-1, T[1]), tc_culprit(-1, T[2]);
        if (msg) snprintf(msg, msz, "triangle %d (vertices %d, %d, %d) is degenerate: rest area %.3g m^2", (int)t,
                          (int)T[0], (int)T[1], (int)T[2], area);
        return TC_ERR_INPUT;
    }
    /* 2-D rest frame: t1 along e1, t2 = n x t1 */
    double t1[3] = {e1[0] / l1, e1[1] / l1, e1[2] / l1};
    double nu[3] = {n[0] / nn, n[1] / nn, n[2] / nn};
    double t2[3]; cross3(nu, t1, t2);
    double D00 = l1, D01 = dot3(e2, t1), D10 = 0.0, D11 = dot3(e2, t2);
    double det = D00 * D11 - D01 * D10;
    /* Dm^-1; rows are the gradients of the shape functions of vertices 1 and 2 */
    double *g = (double *)tc_vec_ptr(&c->grad) + 4 * (size_t)t;
    g[0] = D11 / det;  g[1] = -D01 / det;   /* g1 */
    g[2] = -D10 / det; g[3] = D00 / det;    /* g2 */
    ((double *)tc_vec_ptr(&c->area))[t] = area;
    /* rotation starts as the rest frame so a cloth created in place has no spurious stress */
    double *R = (double *)tc_vec_ptr(&c->rot) + 6 * (size_t)t;
    R[0] = t1[0]; R[1] = t1[1]; R[2] = t1[2]; R[3] = t2[0]; R[4] = t2[1]; R[5] = t2[2];
    tc_axes_set(c, t, false);  /* the warp in this (possibly new) rest frame */
    return TC_OK;
}

void tc_masses_update(tc_cloth *c)
{
    double *m = tc_vec_ptr(&c->mass);
    const int32_t *T = tc_vec_ptr(&c->tri);
    const double *A = tc_vec_ptr(&c->area);
    memset(m, 0, (size_t)c->nv * sizeof *m);
    double k = c->mat.density * c->mat.thickness / 3.0;
    for (int32_t t = 0; t < c->nt; t++) {
        double w = k * A[t];
        m[T[3 * t]] += w; m[T[3 * t + 1]] += w; m[T[3 * t + 2]] += w;
    }
}

/* ---------------- bending stencils ---------------- */

static double cotan(const double *p, const double *a, const double *b)
{
    double u[3], v[3], w[3];
    sub3(a, p, u); sub3(b, p, v); cross3(u, v, w);
    double s = sqrt(dot3(w, w));
    return s > 0 ? dot3(u, v) / s : 0.0;
}

static void stencil_apply(tc_cloth *c, const tc_stencil *s, double sign)
{
    double *vb = tc_vec_ptr(&c->vbend), *pb = tc_vec_ptr(&c->pbend);
    for (int a = 0; a < 4; a++) {
        vb[s->v[a]] += sign * s->coef * s->q[a] * s->q[a];
        for (int b = a + 1; b < 4; b++) {
            int32_t p = tc_pair_find(c, s->v[a], s->v[b]);
            if (p >= 0) pb[p] += sign * s->coef * s->q[a] * s->q[b];
        }
    }
}

/* Quadratic bending (Bergou et al. 2006): for the edge v0-v1 between triangles (v0,v1,v2) and
 * (v1,v0,v3), K = cotangent weights, energy = k/2 * 1/(A0+A1) |sum K_i x_i|^2, which vanishes for
 * any flat configuration of the four vertices; its Hessian is constant, so it costs nothing to
 * re-assemble. Bergou et al. weight by 3/(A0+A1); we use 1/(A0+A1) so that k is the plate's
 * bending stiffness D: a sheet rolled into a cylinder of radius r then stores D/2 A / r^2 (checked
 * in tests/test_fem.py: within 2 % on a regular mesh, ~15 % on a strongly jittered one).
 *
 * A stencil is not stored: it lives in vbend and pbend (stencil_apply), and pstencil marks the
 * edges that have one. Its removal makes it again from the edge's two triangles, which are those
 * it was made from: every change to a triangle (its corners, its rest shape, its place in ptris)
 * happens between stencils_off and stencils_on of its edges (remesh.c) or removes it with them
 * (fragment.c), and rest positions and areas change nowhere else; the same doubles through the same
 * operations give the same bits, so what the removal subtracts is what the addition added. (Stored,
 * the stencils were 64 bytes per interior edge: 96 bytes per triangle.) 0: the edge has none. */
static int stencil_make(const tc_cloth *c, int32_t ep, tc_stencil *s)
{
    const int32_t *pt = (const int32_t *)tc_vec_ptr(&c->ptris) + 2 * (size_t)ep;
    if (pt[0] < 0 || pt[1] < 0) return 0;
    int32_t v0 = ((int32_t *)tc_vec_ptr(&c->pi))[ep], v1 = ((int32_t *)tc_vec_ptr(&c->pj))[ep];
    const int32_t *T0 = (const int32_t *)tc_vec_ptr(&c->tri) + 3 * (size_t)pt[0];
    const int32_t *T1 = (const int32_t *)tc_vec_ptr(&c->tri) + 3 * (size_t)pt[1];
    int32_t v2 = -1, v3 = -1;
    for (int k = 0; k < 3; k++) {
        if (T0[k] != v0 && T0[k] != v1) v2 = T0[k];
        if (T1[k] != v0 && T1[k] != v1) v3 = T1[k];
    }
    if (v2 < 0 || v3 < 0 || v2 == v3) return 0;
    const double *X = tc_vec_ptr(&c->rest);
    const double *x0 = X + 3 * (size_t)v0, *x1 = X + 3 * (size_t)v1, *x2 = X + 3 * (size_t)v2, *x3 = X + 3 * (size_t)v3;
    double c0A = cotan(x0, x1, x2), c1A = cotan(x1, x0, x2);
    double c0B = cotan(x0, x1, x3), c1B = cotan(x1, x0, x3);
    const double *A = tc_vec_ptr(&c->area);
    *s = (tc_stencil){.v = {v0, v1, v2, v3},
                      .q = {c1A + c1B, c0A + c0B, -c0A - c1A, -c0B - c1B},
                      .coef = 1.0 / (A[pt[0]] + A[pt[1]]),
                      .pair = ep};
    return 1;
}

int tc_stencil_add(tc_cloth *c, int32_t ep)
{
    if (((const int32_t *)tc_vec_ptr(&c->pstencil))[ep] >= 0) return TC_OK;
    tc_stencil s;
    if (!stencil_make(c, ep, &s)) return TC_OK;
    if (tc_pair_acquire(c, s.v[2], s.v[3]) < 0) return TC_ERR_NOMEM;  /* the flap pair */
    ((int32_t *)tc_vec_ptr(&c->pstencil))[ep] = 0;
    stencil_apply(c, &s, 1.0);
    return TC_OK;
}

void tc_stencil_remove(tc_cloth *c, int32_t ep)
{
    int32_t *pst = tc_vec_ptr(&c->pstencil);
    if (pst[ep] < 0) return;
    pst[ep] = -1;
    tc_stencil s;
    if (!stencil_make(c, ep, &s)) return;  /* only a corrupted snapshot marks such an edge */
    stencil_apply(c, &s, -1.0);
    int32_t fp = tc_pair_find(c, s.v[2], s.v[3]);
    if (fp >= 0) tc_pair_release(c, fp);
}

/* ---------------- build from arrays ---------------- */

int tc_mesh_build(tc_cloth *c, char *msg, size_t msz)
{
    const int32_t *T = tc_vec_ptr(&c->tri);
    int32_t *tpair = tc_vec_ptr(&c->tpair), *vtri = tc_vec_ptr(&c->vtri);
    for (int32_t t = 0; t < c->nt; t++) {
        for (int k = 0; k < 3; k++) {
            int32_t a = T[3 * t + (k + 1) % 3], b = T[3 * t + (k + 2) % 3];
            int32_t p = tc_pair_acquire(c, a, b);
            if (p < 0) { snprintf(msg, msz, "out of memory building edges"); return TC_ERR_NOMEM; }
            int32_t *pt = (int32_t *)tc_vec_ptr(&c->ptris) + 2 * (size_t)p;
            if (pt[0] < 0) pt[0] = t;
            else if (pt[1] < 0) pt[1] = t;
            else {
                tc_culprit(pt[0], a); tc_culprit(pt[1], b); tc_culprit(t, -1);
                snprintf(msg, msz, "non-manifold edge (%d, %d): used by triangles %d, %d and %d", (int)a, (int)b,
                         (int)pt[0], (int)pt[1], (int)t);
                return TC_ERR_INPUT;
            }
            tpair[3 * t + k] = p;
        }
        for (int k = 0; k < 3; k++) vtri[T[3 * t + k]] = t;
    }
    const int32_t *ptris = tc_vec_ptr(&c->ptris);
    for (int32_t t = 0; t < c->nt; t++) {
        for (int k = 0; k < 3; k++) {
            int32_t p = tpair[3 * t + k];
            int32_t o = ptris[2 * p] == t ? ptris[2 * p + 1] : ptris[2 * p];
            if (o >= 0) {
                /* consistent winding: the shared edge runs a->b here and b->a in the neighbour */
                int32_t a = T[3 * t + (k + 1) % 3], b = T[3 * t + (k + 2) % 3];
                int32_t la = tc_tri_local(c, o, a);
                if (T[3 * o + (la + 1) % 3] == b) {
                    tc_culprit(t, a); tc_culprit(o, b);
                    snprintf(msg, msz, "inconsistent winding: triangles %d and %d traverse edge (%d, %d) in the same direction",
                             (int)t, (int)o, (int)a, (int)b);
                    return TC_ERR_INPUT;
                }
            }
        }
    }
    /* every vertex used, and its triangles form one fan (else tearing could not walk around it) */
    int32_t *count = calloc((size_t)c->nv, sizeof *count);
    if (!count) { snprintf(msg, msz, "out of memory"); return TC_ERR_NOMEM; }
    for (int32_t t = 0; t < c->nt; t++)
        for (int k = 0; k < 3; k++) count[T[3 * t + k]]++;
    int rc = TC_OK;
    for (int32_t v = 0; v < c->nv && rc == TC_OK; v++) {
        if (count[v] == 0) {
            snprintf(msg, msz, "vertex %d is not used by any triangle (remove loose vertices)", (int)v);
            tc_culprit(-1, v);
            rc = TC_ERR_INPUT;
            break;
        }
        /* walk the fan one way until a boundary or back at the start, then the other way */
        int32_t start = vtri[v], n = 1, t = start;
        bool closed = false;
        for (;;) {
            int32_t nb = tc_nbr(c, t, (tc_tri_local(c, t, v) + 2) % 3);
            if (nb < 0) break;
            if (nb == start) { closed = true; break; }
            t = nb;
            if (++n > count[v]) break;
        }
        for (t = start; !closed;) {
            int32_t nb = tc_nbr(c, t, (tc_tri_local(c, t, v) + 1) % 3);
            if (nb < 0 || nb == start) break;
            t = nb;
            if (++n > count[v]) break;
        }
        if (n != count[v]) {
            snprintf(msg, msz, "non-manifold vertex %d: its %d triangles form more than one fan", (int)v, (int)count[v]);
            tc_culprit(-1, v);
            rc = TC_ERR_INPUT;
        }
    }
    free(count);
    if (rc) return rc;
    size_t np = c->pi.len;
    for (size_t p = 0; p < np; p++)
        if (tc_stencil_add(c, (int32_t)p)) { snprintf(msg, msz, "out of memory"); return TC_ERR_NOMEM; }
    return TC_OK;
}
