/* bvh.c - a bounding volume hierarchy per cluster of a collider (the cloth itself, each body),
 * refitted instead of rebuilt, and the traversals full detection needs.
 *
 * Why native trees: a cloth cluster deforms every step, so its Embree scene (the previous release's
 * narrow.ClusterScenes, reused only up to a rigid motion) was rebuilt in most steps of the artist's
 * bake - 12.5 of 18 clusters per sub-step, 5.3 ms of bookkeeping, per-triangle copies through Python
 * and Embree builds - and embreex can neither refit a scene nor filter hits, nor be called from C.
 * Here the tree of each cluster is built once per topology (median split, the topology does not
 * change between tears) and refitted bottom-up from the current positions when a step first needs
 * it: a refit is one pass over the cluster's ~300 triangles, and its boxes are exact, so there is
 * no staleness tolerance to add to the rays and no rigid frame to move them into. The bodies use
 * the same trees: a walking body's cluster deforms a little every step too, a refit costs what the
 * former rigid fit did, and with every collider in C a step's full detection is one call per
 * collider (detect.c) - the contacts are the same as with Embree's candidates refined, bit for bit.
 * The two-ring filter runs inside the traversal.
 *
 * Layout (arrays owned by the caller, narrow.ClusterBVH): cluster c's nodes are rows
 * node_ptr[c] .. node_ptr[c+1] of node (N, 2) and box (N, 6: lo xyz, hi xyz), its root first; an
 * inner node holds its two children (both after it, so a refit runs the rows backwards), a leaf
 * holds -1 - first and count: triangles prim[first .. first+count). Every index read from these
 * arrays is checked, so a corrupted tree gives TCC_ERR_INDEX, never an out-of-bounds read.
 *
 * A hit is the nearest triangle the ray o + t d meets for t in [0, tmax] (barycentrics within
 * -BVH_EPS, so a ray through a shared edge is not lost between the two triangles), skipping
 * triangles of the ray vertex's two-ring when a ring is given: what Embree followed by the
 * re-casts of tcc_accept_hits found, in double precision. A refit also copies each prim's corners
 * (corner, when kept): the traversals then read a leaf's triangles from one place.
 */
#include "collide.h"
#include "vecmath.h"

#include <math.h>
#include <stdlib.h>

#define BVH_LEAF 4      /* triangles per leaf at most */
#define BVH_STACK 64    /* a median split over 2^40 triangles is 41 deep */
#define BVH_EPS 1e-12   /* barycentric slack (relative to 1) */

/* ------------------------------------------------------------------ build */

typedef struct {
    tcc_idx *perm;       /* scene rows of the cluster being built, permuted */
    const double *cent;  /* (rows, 3) triangle centroids */
    tcc_idx *node;
    tcc_idx nnode;       /* nodes written so far (global) */
} builder;

/* Partial sort of perm[lo..hi) so that perm[mid] has the median centroid along axis (quickselect). */
static void select_median(tcc_idx *perm, const double *cent, int axis, tcc_idx lo, tcc_idx hi, tcc_idx mid)
{
    while (hi - lo > 1) {
        double pivot = cent[3 * perm[lo + (hi - lo) / 2] + axis];
        tcc_idx i = lo, j = hi - 1;
        while (i <= j) {
            while (cent[3 * perm[i] + axis] < pivot) i++;
            while (cent[3 * perm[j] + axis] > pivot) j--;
            if (i <= j) {
                tcc_idx t = perm[i];
                perm[i] = perm[j];
                perm[j] = t;
                i++;
                j--;
            }
        }
        if (mid <= j) hi = j + 1;
        else if (mid >= i) lo = i;
        else return;
    }
}

/* Node for perm[lo..hi) at row b->nnode, then its subtrees (preorder: children after parents). */
static void build_node(builder *b, tcc_idx lo, tcc_idx hi, int depth)
{
    tcc_idx me = b->nnode++;
    if (hi - lo <= BVH_LEAF || depth >= BVH_STACK - 2) {
        b->node[2 * me] = -1 - lo;
        b->node[2 * me + 1] = hi - lo;
        return;
    }
    double clo[3] = {INFINITY, INFINITY, INFINITY}, chi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (tcc_idx i = lo; i < hi; i++)
        for (int a = 0; a < 3; a++) {
            double c = b->cent[3 * b->perm[i] + a];
            if (c < clo[a]) clo[a] = c;
            if (c > chi[a]) chi[a] = c;
        }
    int axis = 0;
    for (int a = 1; a < 3; a++)
        if (chi[a] - clo[a] > chi[axis] - clo[axis]) axis = a;
    tcc_idx mid = lo + (hi - lo) / 2;
    select_median(b->perm, b->cent, axis, lo, hi, mid);
    b->node[2 * me] = b->nnode;
    build_node(b, lo, mid, depth + 1);
    b->node[2 * me + 1] = b->nnode;
    build_node(b, mid, hi, depth + 1);
}

/* Corners of triangle f, checked. */
static int corners(const tcc_mesh *m, tcc_idx f, const double *p[3], tcc_error *err)
{
    if (f < 0 || f >= m->nt)
        return tcc_fail(err, TCC_ERR_INDEX, "BVH triangle %lld is not in [0, %lld)", (long long)f, (long long)m->nt);
    const tcc_idx *tv = m->tri + 3 * f;
    for (int k = 0; k < 3; k++) {
        if (tv[k] < 0 || tv[k] >= m->nv)
            return tcc_fail(err, TCC_ERR_INDEX, "triangles[%lld, %d] = %lld is not a vertex index in [0, %lld)",
                            (long long)f, k, (long long)tv[k], (long long)m->nv);
        p[k] = m->x + 3 * tv[k];
    }
    return TCC_OK;
}

int tcc_bvh_build(const tcc_mesh *m, const tcc_idx *scene_ptr, const tcc_idx *scene_tri, tcc_idx nrows, tcc_idx k,
                  tcc_idx *node_ptr, tcc_idx *node, double *box, tcc_idx cap, tcc_idx *prim, tcc_idx *nnodes,
                  tcc_error *err)
{
    if (scene_ptr[0] != 0 || scene_ptr[k] != nrows)
        return tcc_fail(err, TCC_ERR_VALUE, "scene_ptr must run from 0 to the %lld scene rows", (long long)nrows);
    if (cap < 2 * nrows)
        return tcc_fail(err, TCC_ERR_VALUE, "the node arrays need 2 * %lld rows, have %lld", (long long)nrows,
                        (long long)cap);
    double *cent = malloc(sizeof(double) * 3 * (size_t)(nrows > 0 ? nrows : 1));
    tcc_idx *perm = malloc(sizeof(tcc_idx) * (size_t)(nrows > 0 ? nrows : 1));
    if (!cent || !perm) {
        free(cent);
        free(perm);
        return tcc_fail(err, TCC_ERR_NOMEM, "no memory for the BVH build of %lld triangles", (long long)nrows);
    }
    int rc = TCC_OK;
    for (tcc_idx r = 0; r < nrows && rc == TCC_OK; r++) {
        const double *p[3];
        rc = corners(m, scene_tri[r], p, err);
        if (rc) break;
        for (int a = 0; a < 3; a++) cent[3 * r + a] = (p[0][a] + p[1][a] + p[2][a]) / 3.0;
    }
    builder b = {perm, cent, node, 0};
    for (tcc_idx c = 0; c < k && rc == TCC_OK; c++) {
        tcc_idx s = scene_ptr[c], e = scene_ptr[c + 1];
        if (s < 0 || e < s || e > nrows) {
            rc = tcc_fail(err, TCC_ERR_INDEX, "scene_ptr: cluster %lld spans [%lld, %lld) of %lld rows", (long long)c,
                          (long long)s, (long long)e, (long long)nrows);
            break;
        }
        node_ptr[c] = b.nnode;
        if (e == s) continue;
        for (tcc_idx r = s; r < e; r++) perm[r] = r;
        build_node(&b, s, e, 0);
    }
    if (rc == TCC_OK) {
        node_ptr[k] = b.nnode;
        for (tcc_idx r = 0; r < nrows; r++) prim[r] = scene_tri[perm[r]];
        *nnodes = b.nnode;
        tcc_bvh t = {node_ptr, k, node, box, b.nnode, prim, nrows, NULL};
        for (tcc_idx c = 0; c < k && rc == TCC_OK; c++) rc = tcc_bvh_refit(m, &t, c, err);
    }
    free(cent);
    free(perm);
    return rc;
}

/* ------------------------------------------------------------------ refit */

/* Node rows [s, e) of cluster c, checked. */
static int cluster_nodes(const tcc_bvh *b, tcc_idx c, tcc_idx *s, tcc_idx *e, tcc_error *err)
{
    if (c < 0 || c >= b->k)
        return tcc_fail(err, TCC_ERR_INDEX, "cluster %lld is not in [0, %lld)", (long long)c, (long long)b->k);
    *s = b->node_ptr[c];
    *e = b->node_ptr[c + 1];
    if (*s < 0 || *e < *s || *e > b->nnodes)
        return tcc_fail(err, TCC_ERR_INDEX, "node_ptr: cluster %lld spans [%lld, %lld) of %lld nodes", (long long)c,
                        (long long)*s, (long long)*e, (long long)b->nnodes);
    return TCC_OK;
}

/* The children (inner) or triangle range (leaf) of node i of a cluster spanning [s, e), checked. */
static int node_links(const tcc_bvh *b, tcc_idx i, tcc_idx e, int *leaf, tcc_idx *x, tcc_idx *y, tcc_error *err)
{
    tcc_idx p = b->node[2 * i], q = b->node[2 * i + 1];
    *leaf = p < 0;
    if (p < 0) {
        tcc_idx first = -1 - p;
        if (q < 1 || first > b->nprim - q)
            return tcc_fail(err, TCC_ERR_INDEX, "BVH leaf %lld holds triangles [%lld, +%lld) of %lld", (long long)i,
                            (long long)first, (long long)q, (long long)b->nprim);
        *x = first;
        *y = first + q;
    } else {
        if (p <= i || p >= e || q <= i || q >= e)
            return tcc_fail(err, TCC_ERR_INDEX, "BVH node %lld: children %lld, %lld must lie in (%lld, %lld)",
                            (long long)i, (long long)p, (long long)q, (long long)i, (long long)e);
        *x = p;
        *y = q;
    }
    return TCC_OK;
}

/* fmin / fmax (a NaN operand yields the other), inline: libm's are calls */
static inline double min_num(double a, double b) { return (b < a || a != a) ? b : a; }
static inline double max_num(double a, double b) { return (b > a || a != a) ? b : a; }

int tcc_bvh_refit(const tcc_mesh *m, tcc_bvh *b, tcc_idx c, tcc_error *err)
{
    tcc_idx s, e;
    int rc = cluster_nodes(b, c, &s, &e, err);
    if (rc) return rc;
    for (tcc_idx i = e - 1; i >= s; i--) {
        int leaf;
        tcc_idx x, y;
        if ((rc = node_links(b, i, e, &leaf, &x, &y, err))) return rc;
        double *bx = b->box + 6 * i;
        if (leaf) {
            double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
            for (tcc_idx r = x; r < y; r++) {
                const double *p[3];
                if ((rc = corners(m, b->prim[r], p, err))) return rc;
                double *cr = b->corner ? b->corner + 9 * r : NULL;
                for (int k = 0; k < 3; k++)
                    for (int a = 0; a < 3; a++) {
                        double v = p[k][a];
                        if (v < lo[a]) lo[a] = v;
                        if (v > hi[a]) hi[a] = v;
                        if (cr) cr[3 * k + a] = v;
                    }
            }
            for (int a = 0; a < 3; a++) {
                bx[a] = lo[a];
                bx[3 + a] = hi[a];
            }
        } else {
            const double *l = b->box + 6 * x, *r = b->box + 6 * y;
            for (int a = 0; a < 3; a++) {
                bx[a] = min_num(l[a], r[a]);
                bx[3 + a] = max_num(l[3 + a], r[3 + a]);
            }
        }
    }
    return TCC_OK;
}

/* ------------------------------------------------------------------ query */

int tcc_bvh_first_hit(const tcc_mesh *m, const tcc_bvh *b, tcc_idx c, const double o[3], const double d[3],
                      double tmax, const tcc_ring *ring, tcc_idx v, tcc_hit *h, tcc_error *err)
{
    h->tri = -1;
    h->t = INFINITY;
    h->u = h->v = 0.0;
    h->flips = 0;
    tcc_idx s, e;
    int rc = cluster_nodes(b, c, &s, &e, err);
    if (rc || e == s) return rc;
    int filter = ring && ring->table;
    if (filter && (v < 0 || v >= ring->rows))
        return tcc_fail(err, TCC_ERR_INDEX, "ray vertex %lld has no exclusion row (of %lld)", (long long)v,
                        (long long)ring->rows);
    double inv[3];
    for (int a = 0; a < 3; a++) inv[a] = fabs(d[a]) < 1e-300 ? INFINITY : 1.0 / d[a];
    double best = tmax;
    tcc_idx stack[BVH_STACK];
    int top = 0;
    if (tcc_box_entry(o, inv, best, b->box + 6 * s) < INFINITY) stack[top++] = s;
    while (top > 0) {
        tcc_idx i = stack[--top];
        if (tcc_box_entry(o, inv, best, b->box + 6 * i) == INFINITY) continue; /* best shrank since the push */
        int leaf;
        tcc_idx x, y;
        if ((rc = node_links(b, i, e, &leaf, &x, &y, err))) return rc;
        if (leaf) {
            for (tcc_idx r = x; r < y; r++) {
                const double *p[3];
                tcc_idx f = b->prim[r];
                if ((rc = corners(m, f, p, err))) return rc;
                double t, u, w;
                if (!tcc_line_triangle(o, d, p[0], p[1], p[2], &t, &u, &w)) continue;
                if (!(t >= 0.0 && t <= best && u >= -BVH_EPS && w >= -BVH_EPS && u + w <= 1.0 + BVH_EPS)) continue;
                if (t == best && h->tri >= 0) continue; /* a tie keeps the first found */
                const tcc_idx *tv = m->tri + 3 * f;
                /* the ray's own vertex first: every ray passes through its ~6 incident triangles */
                if (filter && (tv[0] == v || tv[1] == v || tv[2] == v || tcc_ring_excludes(ring, v, tv))) continue;
                best = t;
                h->tri = f;
                h->t = t;
                h->u = u;
                h->v = w;
            }
            continue;
        }
        double tx = tcc_box_entry(o, inv, best, b->box + 6 * x), ty = tcc_box_entry(o, inv, best, b->box + 6 * y);
        if (top + 2 > BVH_STACK)
            return tcc_fail(err, TCC_ERR_VALUE, "BVH of cluster %lld is deeper than %d levels", (long long)c,
                            BVH_STACK);
        /* the nearer child is popped first */
        if (tx <= ty) {
            if (ty < INFINITY) stack[top++] = y;
            if (tx < INFINITY) stack[top++] = x;
        } else {
            if (tx < INFINITY) stack[top++] = x;
            if (ty < INFINITY) stack[top++] = y;
        }
    }
    return TCC_OK;
}

int tcc_bvh_cast(const tcc_mesh *m, const tcc_bvh *b, const tcc_idx *cluster, const double *o, const double *d,
                 const double *tmax, const tcc_idx *ray_v, tcc_idx r, const tcc_ring *ring, tcc_hits out,
                 tcc_error *err)
{
    for (tcc_idx i = 0; i < r; i++) {
        tcc_hit h;
        int rc = tcc_bvh_first_hit(m, b, cluster[i], o + 3 * i, d + 3 * i, tmax[i], ring, ray_v ? ray_v[i] : -1, &h,
                                   err);
        if (rc) return rc;
        out.tri[i] = h.tri;
        out.t[i] = h.t;
        out.u[i] = h.u;
        out.v[i] = h.v;
        out.flips[i] = 0;
    }
    return TCC_OK;
}

/* ------------------------------------------------------------------ a step's self-collision rays */

int tcc_self_cast(const tcc_ray_setup *s, const tcc_mesh *target, tcc_bvh *b, tcc_idx *refit_step, tcc_idx step,
                  const tcc_ring *ring, const tcc_idx *pair_a, const tcc_idx *pair_b, tcc_idx np, tcc_idx *ray_v,
                  tcc_idx *ray_slot, tcc_idx *hit_tri, tcc_idx cap, tcc_idx *nhits, tcc_idx *nrays, tcc_error *err)
{
    tcc_idx hits = 0, rays = 0;
    if (s->kb != b->k)
        return tcc_fail(err, TCC_ERR_VALUE, "%lld collider boxes for a BVH of %lld clusters", (long long)s->kb,
                        (long long)b->k);
    for (tcc_idx p = 0; p < np; p++) {
        tcc_idx a = pair_a[p], c = pair_b[p], st, en;
        int rc = tcc_pair_span(s, p, a, c, &st, &en, err);
        if (rc) return rc;
        const double *lo = s->box_lo + 3 * c, *hi = s->box_hi + 3 * c;
        int fitted = 0;
        for (tcc_idx i = st; i < en; i++) {
            for (int slot = 0; slot < 2; slot++) {
                tcc_idx v;
                double ow[3], dw[3], len;
                int cast = tcc_member_ray(s, i, slot, lo, hi, &v, ow, dw, &len, err);
                if (cast < 0) return cast;
                if (!cast) continue;
                if (!fitted && refit_step[c] != step) {
                    /* the first ray into cluster c this step refits its tree from the current positions */
                    if ((rc = tcc_bvh_refit(target, b, c, err))) return rc;
                    refit_step[c] = step;
                }
                fitted = 1;
                rays++;
                tcc_hit h;
                if ((rc = tcc_bvh_first_hit(target, b, c, ow, dw, len, ring, v, &h, err))) return rc;
                if (h.tri < 0) continue;
                if (hits < cap) {
                    ray_v[hits] = v;
                    ray_slot[hits] = slot;
                    hit_tri[hits] = h.tri;
                }
                hits++;
            }
        }
    }
    *nhits = hits;
    *nrays = rays;
    return TCC_OK;
}

/* ------------------------------------------------------------------ both rays of a vertex at once
 *
 * Full detection casts from each cloth vertex along +n and -n: one line, two windows. One traversal
 * serves both (the nodes near the vertex, where most of a short ray's work is, are visited once
 * instead of twice), reading each prim's corners from the copy the refit made (no index lookups).
 * A node is entered when the line's span in its box meets what is still open of the two windows:
 * (best of slot 1, best of slot 0); the child nearer to the vertex first. */

int tcc_bvh_check(const tcc_mesh *m, tcc_bvh *b, tcc_idx c, tcc_error *err)
{
    tcc_idx s, e;
    int rc = cluster_nodes(b, c, &s, &e, err);
    if (rc) return rc;
    for (tcc_idx i = s; i < e; i++) {
        int leaf;
        tcc_idx x, y;
        if ((rc = node_links(b, i, e, &leaf, &x, &y, err))) return rc;
        if (!leaf) continue;
        for (tcc_idx r = x; r < y; r++) {
            const double *p[3];
            if ((rc = corners(m, b->prim[r], p, err))) return rc;
        }
    }
    return TCC_OK;
}

/* A line prepared for many box tests: per axis the bound it meets first (by the sign of d), and
 * the axes along which it does not move (tested by containment). */
typedef struct {
    double o[3], inv[3];
    int near[3], far[3], flat;
} prepared_line;

static inline void prepare_line(const double o[3], const double d[3], prepared_line *L)
{
    L->flat = 0;
    for (int a = 0; a < 3; a++) {
        L->o[a] = o[a];
        if (fabs(d[a]) < 1e-300) {
            L->inv[a] = INFINITY;
            L->flat |= 1 << a;
            L->near[a] = a;
            L->far[a] = 3 + a;
            continue;
        }
        L->inv[a] = 1.0 / d[a];
        L->near[a] = d[a] > 0 ? a : 3 + a;
        L->far[a] = d[a] > 0 ? 3 + a : a;
    }
}

/* tcc_line_box for a prepared line: the same span (the same expressions), fewer branches. */
static inline int prepared_box(const prepared_line *L, double lo, double hi, const double *bx, double *t0, double *t1)
{
    if (L->flat) {
        for (int a = 0; a < 3; a++)
            if ((L->flat >> a & 1) && !(L->o[a] >= bx[a] && L->o[a] <= bx[3 + a])) return 0;
    }
    for (int a = 0; a < 3; a++) {
        if (L->flat >> a & 1) continue;
        double ta = (bx[L->near[a]] - L->o[a]) * L->inv[a], tb = (bx[L->far[a]] - L->o[a]) * L->inv[a];
        if (ta > lo) lo = ta;
        if (tb < hi) hi = tb;
    }
    if (!(lo <= hi)) return 0;
    *t0 = lo;
    *t1 = hi;
    return 1;
}

/* distance from s = 0 to the span [t0, t1] */
static inline double span_gap(double t0, double t1) { return t0 > 0 ? t0 : (t1 < 0 ? -t1 : 0.0); }

void tcc_bvh_line(const tcc_mesh *m, const tcc_bvh *b, tcc_idx c, const double x[3], const double d[3], int active,
                  double backoff, double *s0, double *s1, const tcc_ring *ring, tcc_idx v, tcc_idx tri[2])
{
    tcc_idx s = b->node_ptr[c], e = b->node_ptr[c + 1];
    if (e == s || !(active & 3)) return;
    int filter = ring && ring->table;
    prepared_line L;
    prepare_line(x, d, &L);
    double b0 = *s0, b1 = *s1; /* the open windows: slot 0 [-backoff, b0], slot 1 [b1, backoff] */
#define LO ((active & 2) ? b1 : -backoff)
#define HI ((active & 1) ? b0 : backoff)
    /* the stack holds each node with its line span, so a pop re-checks it against the windows as they
     * are now with two compares */
    struct span_node {
        tcc_idx i;
        double t0, t1;
    } stack[BVH_STACK];
    int top = 0;
    double t0, t1;
    if (prepared_box(&L, LO, HI, b->box + 6 * s, &t0, &t1)) stack[top++] = (struct span_node){s, t0, t1};
    while (top > 0) {
        top--;
        tcc_idx i = stack[top].i;
        if (stack[top].t0 > HI || stack[top].t1 < LO) continue; /* the windows shrank since the push */
        tcc_idx p = b->node[2 * i], q = b->node[2 * i + 1];
        if (p < 0) {
            for (tcc_idx r = -1 - p; r < -1 - p + q; r++) {
                tcc_idx f = b->prim[r];
                const tcc_idx *tv = m->tri + 3 * f;
                /* the ray's own two-ring first: every ray passes through its ~6 incident triangles, and
                 * the leaves it visits hold mostly its neighbours' */
                if (filter && (tv[0] == v || tv[1] == v || tv[2] == v || tcc_ring_excludes(ring, v, tv))) continue;
                const double *P = b->corner + 9 * r;
                double t, u, w;
                if (!tcc_line_triangle_inline(x, d, P, P + 3, P + 6, &t, &u, &w)) continue;
                if (!(u >= -BVH_EPS && w >= -BVH_EPS && u + w <= 1.0 + BVH_EPS)) continue;
                /* a tie keeps the first found */
                int c0 = (active & 1) && t >= -backoff && (t < b0 || (t == b0 && tri[0] < 0));
                int c1 = (active & 2) && t <= backoff && (t > b1 || (t == b1 && tri[1] < 0));
                if (!c0 && !c1) continue;
                if (c0) {
                    b0 = t;
                    tri[0] = f;
                }
                if (c1) {
                    b1 = t;
                    tri[1] = f;
                }
            }
            continue;
        }
        double pa = 0, pb = 0, qa = 0, qb = 0;
        int hp = prepared_box(&L, LO, HI, b->box + 6 * p, &pa, &pb);
        int hq = prepared_box(&L, LO, HI, b->box + 6 * q, &qa, &qb);
        if (top + 2 > BVH_STACK) break; /* deeper than any built tree: a corrupt one, searched no further */
        /* the nearer child (to the vertex) is popped first */
        if (hp && hq && span_gap(pa, pb) > span_gap(qa, qb)) {
            stack[top++] = (struct span_node){p, pa, pb};
            stack[top++] = (struct span_node){q, qa, qb};
        } else {
            if (hq) stack[top++] = (struct span_node){q, qa, qb};
            if (hp) stack[top++] = (struct span_node){p, pa, pb};
        }
    }
#undef LO
#undef HI
    *s0 = b0;
    *s1 = b1;
}

/* Whether the line x + s d meets a triangle of cluster c's tree other than skip for s in [lo, hi)
 * (barycentrics exactly within the triangle): the inside confirmation's test (contacts.c
 * tcc_confirm_inside's arithmetic, the same corners), answered from the tree. */
int tcc_bvh_blocked(const tcc_bvh *b, tcc_idx c, const double x[3], const double d[3], double lo, double hi,
                    tcc_idx skip)
{
    tcc_idx s = b->node_ptr[c], e = b->node_ptr[c + 1];
    if (e == s || !(lo <= hi)) return 0;
    prepared_line L;
    prepare_line(x, d, &L);
    tcc_idx stack[BVH_STACK];
    int top = 0;
    double t0, t1;
    if (prepared_box(&L, lo, hi, b->box + 6 * s, &t0, &t1)) stack[top++] = s;
    while (top > 0) {
        tcc_idx i = stack[--top];
        tcc_idx p = b->node[2 * i], q = b->node[2 * i + 1];
        if (p < 0) {
            for (tcc_idx r = -1 - p; r < -1 - p + q; r++) {
                if (b->prim[r] == skip) continue;
                const double *P = b->corner + 9 * r;
                double t, u, w;
                if (!tcc_line_triangle_inline(x, d, P, P + 3, P + 6, &t, &u, &w)) continue;
                if (u >= 0 && w >= 0 && u + w <= 1 && t >= lo && t < hi) return 1;
            }
            continue;
        }
        if (top + 2 > BVH_STACK) break; /* deeper than any built tree: a corrupt one */
        if (prepared_box(&L, lo, hi, b->box + 6 * p, &t0, &t1)) stack[top++] = p;
        if (prepared_box(&L, lo, hi, b->box + 6 * q, &t0, &t1)) stack[top++] = q;
    }
    return 0;
}
