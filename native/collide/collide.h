/* collide.h - the kernels of clustered, ray-traced collision detection (tearcloth._collide).
 *
 * The Python package `tearcloth.collision` owns the state between steps (clusters, measures, trees,
 * tracks) and calls a step's stages; these kernels own every loop over vertices, rays, triangles or
 * cluster pairs, and the step's orchestration itself (measure.c's cluster_state and pair_step,
 * detect.c's per-collider step, swept.c's swept stage), so that a step costs a handful of calls
 * whatever the mesh size.
 *
 * Design rules (the same as the native FEM core):
 * - No state: every array is owned by the caller (numpy, through the buffer protocol) and every
 *   kernel is a pure function of its arguments, so the numpy reference of each kernel in the
 *   package is a complete specification that the tests compare against.
 * - No allocation per element: a kernel allocates at most one scratch block per call.
 * - Never read out of bounds: every index read from an array is checked against the length of the
 *   array it indexes before it is used; a bad index stops the kernel with TCC_ERR_INDEX and a
 *   message naming the array (the Python layer raises it as IndexError). The cost is a compare per
 *   read, which is noise next to the arithmetic.
 * - Units are SI (metres); a ray direction is a unit vertex normal times +1 (slot 0) or -1
 *   (slot 1); "lines" are rays extended both ways (t may be negative).
 *
 * Index type: int64 everywhere (numpy's default on every platform Blender ships for).
 */
#ifndef TCC_COLLIDE_H
#define TCC_COLLIDE_H

#include <stddef.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

typedef int64_t tcc_idx;

enum { TCC_OK = 0, TCC_ERR_INDEX = -1, TCC_ERR_VALUE = -2, TCC_ERR_NOMEM = -3 };

typedef struct {
    int code;
    char what[200];
} tcc_error;

/* Records the first error only: later failures keep the message of the first cause. */
int tcc_fail(tcc_error *err, int code, const char *fmt, ...);

/* The per-call checks of whole tables (cluster orders and labels, a collider's triangle labels, the
 * swept stage's groups, the positions' finiteness) as one branch-free pass each, which the compiler
 * vectorizes: with a branch per entry they were ~15 us of a quiet step (bench shirt, 1,700 vertices,
 * a 7,600-triangle body). A caller that sees a failure re-scans with its own loop for the first bad
 * entry and its message, so what is checked and what is said are unchanged. */

/* Whether every a[i], i < count, is in [0, bound). Why it holds: for 0 <= a < bound both a and
 * bound - 1 - a are in [0, bound) (sign bit clear); a negative a has the sign bit set, and for
 * a >= bound, bound - 1 - a is in [-2^63, 0) (two's complement of int64: sign bit set). */
static inline int tcc_all_in_range(const tcc_idx *a, tcc_idx count, tcc_idx bound)
{
    if (count <= 0) return 1;
    if (bound <= 0) return 0;
    uint64_t bad = 0, top = (uint64_t)(bound - 1);
    for (tcc_idx i = 0; i < count; i++) bad |= (uint64_t)a[i] | (top - (uint64_t)a[i]);
    return !(bad >> 63);
}

/* Whether every x[i], i < count, is finite: an exponent of all ones (inf, NaN) carries into the
 * sign bit when one is added to the exponent field. */
static inline int tcc_all_finite(const double *x, tcc_idx count)
{
    uint64_t bad = 0;
    for (tcc_idx i = 0; i < count; i++) {
        uint64_t b;
        memcpy(&b, x + i, sizeof b);
        bad |= (b & UINT64_C(0x7ff0000000000000)) + UINT64_C(0x0010000000000000);
    }
    return !(bad >> 63);
}

/* A triangle mesh as the kernels see it. adj/flip may be NULL where no walk is done. */
typedef struct {
    const double *x;     /* (nv, 3) vertex positions */
    tcc_idx nv;
    const tcc_idx *tri;  /* (nt, 3) vertex indices */
    tcc_idx nt;
    const tcc_idx *adj;  /* (nt, 3) neighbour across edge k = (tri[k], tri[k+1]) or -1 */
    const uint8_t *flip; /* (nt, 3) 1 when that neighbour has the opposite winding */
} tcc_mesh;

/* Self-collision exclusion: row v of `table` (width entries, -1 padded) lists vertex v and its
 * one-ring; a triangle touching any of them (the two-ring of v) is never a hit for v's rays.
 * table == NULL: nothing is excluded (a body). */
typedef struct {
    const tcc_idx *table;
    tcc_idx rows;
    tcc_idx width;
} tcc_ring;

/* Whether triangle tv touches the exclusion row of vertex v (v < rows, checked by the caller). */
static inline int tcc_ring_excludes(const tcc_ring *ring, tcc_idx v, const tcc_idx tv[3])
{
    const tcc_idx *row = ring->table + v * ring->width;
    for (tcc_idx w = 0; w < ring->width; w++) {
        tcc_idx e = row[w];
        if (e >= 0 && (tv[0] == e || tv[1] == e || tv[2] == e)) return 1;
    }
    return 0;
}

/* ---------------------------------------------------------------- geometry.c */

/* Area-weighted unit vertex normals; zero (and has_normal 0) for a vertex of no non-degenerate
 * triangle. has_normal may be NULL. */
int tcc_vertex_normals(const tcc_mesh *m, double *normals, uint8_t *has_normal, tcc_error *err);

/* The normal of vertex v alone, summed from its incident triangles vt_tri[vt_ptr[v] .. vt_ptr[v+1]]
 * in that order (zero, has_normal 0, for a vertex without area): the one sum both the cluster pass
 * below and the detector's per-vertex need use, so their normals agree bit for bit. */
int tcc_vertex_normal(const tcc_mesh *m, const tcc_idx *vt_ptr, const tcc_idx *vt_tri, tcc_idx nvt, tcc_idx v,
                      double *normals, uint8_t *has_normal, tcc_error *err);

/* The same normals for the vertices of the listed clusters only (members order[ptr[c]..ptr[c+1]]
 * of each c in clusters[0..q)), each summed from its incident triangles vt_tri[vt_ptr[v] ..
 * vt_ptr[v+1]] in ascending order: bit for bit what tcc_vertex_normals gives. Other rows are not
 * touched. done (k,) may be NULL; else clusters marked there are skipped, and those done are marked. A step needs the normals of the vertices it casts or walks rays from, which in a quiet
 * step is few clusters or none. */
int tcc_cluster_normals(const tcc_mesh *m, const tcc_idx *vt_ptr, const tcc_idx *vt_tri, tcc_idx nvt,
                        const tcc_idx *order, tcc_idx norder, const tcc_idx *ptr, tcc_idx k, const tcc_idx *clusters,
                        tcc_idx q, double *normals, uint8_t *has_normal, uint8_t *done, tcc_error *err);

/* Rigid fit (Horn's quaternion method) of the corners of triangles tris[0..k) now (m->x) to the
 * same corners at build time (ref (k, 3, 3), row i for tris[i]): x_now ~ R (x_ref - ref_centre)
 * + centre. Returns the largest squared residual in *resid2. */
int tcc_rigid_fit(const tcc_mesh *m, const double *ref, const tcc_idx *tris, tcc_idx k, double R[9],
                  double centre[3], double ref_centre[3], double *resid2, tcc_error *err);

/* ---------------------------------------------------------------- measure.c */

/* Per cluster c (members order[ptr[c]..ptr[c+1])): mean displacement x - prev (avg, (k,3)) and
 * its standard deviation (dev, (k,)): sqrt(mean |d|^2 - |avg|^2). */
int tcc_cluster_motion(const double *x, const double *prev, tcc_idx n, const tcc_idx *order, tcc_idx norder,
                       const tcc_idx *ptr, tcc_idx k, double *avg, double *dev, tcc_error *err);

/* Per cluster: AABB of the positions index[ptr[c]..ptr[c+1]) grown by inflate (empty: lo = +inf,
 * hi = -inf, which overlaps nothing). */
int tcc_cluster_boxes(const double *x, tcc_idx n, const tcc_idx *index, tcc_idx nindex, const tcc_idx *ptr,
                      tcc_idx k, double inflate, double *lo, double *hi, tcc_error *err);

/* Overlapping box pairs (i, j) in row-major order (i ascending, then j); self_pairs: j >= i only.
 * Writes at most cap pairs and returns the total count in *count (call again with a larger cap
 * when *count > cap). */
void tcc_box_pairs(const double *lo_a, const double *hi_a, tcc_idx ka, const double *lo_b, const double *hi_b,
                   tcc_idx kb, int self_pairs, tcc_idx *out_i, tcc_idx *out_j, tcc_idx cap, tcc_idx *count);

/* The paper's relative measure (eqs. 1-4) over the close pairs of one object pair. old_keys
 * (sorted, i << 32 | j) with their accumulated rel_avg / rel_dev; this step's pairs (i, j), each
 * once, in any order (tcc_box_pairs' order costs no sort). Writes the new keys / accumulators in
 * key order (reset where full), and in the pairs' order the amplitude before the reset and
 * full = amplitude > threshold or force; *nfull counts the full pairs. When any pair is full and
 * lookahead > 0, every pair that at this step's rate (|avg_a - avg_b| + dev_a + dev_b) would pass
 * the threshold within lookahead steps is made full too (batching, measure.py). */
int tcc_relative_measure(const tcc_idx *old_keys, const double *old_avg, const double *old_dev, tcc_idx nold,
                         const tcc_idx *pi, const tcc_idx *pj, tcc_idx np, const double *avg_a,
                         const double *dev_a, tcc_idx ka, const double *avg_b, const double *dev_b, tcc_idx kb,
                         const uint8_t *force, double threshold, double lookahead, tcc_idx *keys, double *rel_avg,
                         double *rel_dev, double *amplitude, uint8_t *full, tcc_idx *nfull, tcc_error *err);

/* tcc_cluster_motion and tcc_cluster_boxes of one object in one call. */
int tcc_cluster_state(const double *x, const double *prev, tcc_idx n, const tcc_idx *order, tcc_idx norder,
                      const tcc_idx *ptr, tcc_idx k, const tcc_idx *box_index, tcc_idx nindex, const tcc_idx *box_ptr,
                      double inflate, double *avg, double *dev, double *lo, double *hi, tcc_error *err);

/* A collider's close pairs of a step and the measure's verdict (one call): the overlapping boxes of
 * a (the cloth's clusters) and b (tcc_box_pairs, row-major; self_pairs: j >= i), the pairs forced to
 * full detection (first: all; else those with a cluster listed in forced, on a's side or, for self
 * pairs, either side), and with avg_a set the relative measure's update (tcc_relative_measure, its
 * state old_* -> keys, rel_avg, rel_dev); without it full = forced. *np > cap: nothing but the count
 * was written, call again with room for *np. */
typedef struct {
    const double *lo_a, *hi_a, *lo_b, *hi_b;
    tcc_idx ka, kb;
    int self_pairs, first;
    const tcc_idx *forced;
    tcc_idx nforced;
    const double *avg_a, *dev_a, *avg_b, *dev_b; /* NULL: pairs and forced only */
    const tcc_idx *old_keys;
    const double *old_avg, *old_dev;
    tcc_idx nold;
    double threshold, lookahead;
} tcc_pair_step_in;

int tcc_pair_step(const tcc_pair_step_in *in, tcc_idx cap, tcc_idx *pi, tcc_idx *pj, uint8_t *full, tcc_idx *keys,
                  double *rel_avg, double *rel_dev, double *amplitude, tcc_idx *np, tcc_idx *nfull, tcc_error *err);

/* The trip rule (measure.c, issue 15). Per cluster, the affine fit of the step's displacement
 * x - prev over the previous positions, TCC_FIT_LEN doubles per cluster: centre c[3], mean
 * displacement t[3], L[9] (row-major), e = the largest residual over the members, |L|_F (L = 0
 * when a pure translation bounds tighter at this reach). */
#define TCC_FIT_LEN 17
int tcc_cluster_fit(const double *x, const double *prev, tcc_idx n, const tcc_idx *order, tcc_idx norder,
                    const tcc_idx *ptr, tcc_idx k, double reach, double *fit, tcc_error *err);

/* Per pair (i of object a, j of object b): a bound m of how much the step changed the distance
 * between any vertex of one cluster and the other cluster's surface (within reach): the smaller of
 * max_{x in i} |d_x - A_j(x)| + e_j + |L_j| reach and the same from j's vertices. The clusters'
 * members are order / ptr as given to tcc_cluster_fit (indices checked there). Non-finite -> inf. */
int tcc_pair_motion(const tcc_idx *pi, const tcc_idx *pj, tcc_idx np, const double *xa, const double *pa,
                    const tcc_idx *oa, const tcc_idx *pta, const double *fa, tcc_idx ka, const double *xb,
                    const double *pb, const tcc_idx *ob, const tcc_idx *ptb, const double *fb, tcc_idx kb,
                    double reach, double *m, tcc_error *err);

/* Per close pair, the clearance spent since it was last known (used, m): a known pair adds this
 * step's bound m; every pair is capped by what its boxes (inflated by `inflate`) prove now,
 * budget - (gap - thickness), which is also where a new pair starts. full = used > budget or force
 * (then used resets to 0: a full detection tracks every hit within thickness + budget); batching as
 * in tcc_relative_measure with used + lookahead * m. Pairs in row-major order, each once; keys /
 * used / amplitude (the spent clearance before a reset) / full in that order. */
int tcc_trip_measure(const tcc_idx *old_keys, const double *old_used, tcc_idx nold, const tcc_idx *pi,
                     const tcc_idx *pj, tcc_idx np, const double *m, const double *lo_a, const double *hi_a,
                     tcc_idx ka, const double *lo_b, const double *hi_b, tcc_idx kb, double inflate, double budget,
                     double thickness, const uint8_t *force, double lookahead, tcc_idx *keys, double *used,
                     double *amplitude, uint8_t *full, tcc_idx *nfull, tcc_error *err);

/* ---------------------------------------------------------------- walk.c */

typedef struct {
    tcc_idx tri; /* hit triangle or -1 (lost) */
    double t, u, v; /* signed distance along the direction, barycentrics of corners 1 and 2 */
    int flips;   /* parity of orientation flips crossed */
} tcc_hit;

/* Hits as parallel arrays (k entries each), the layout numpy hands over. */
typedef struct {
    tcc_idx *tri;
    double *t, *u, *v;
    uint8_t *flips;
} tcc_hits;

/* Line o + t d against triangle (a, b, c) (Moller-Trumbore for lines). Returns 0 when parallel. */
int tcc_line_triangle(const double o[3], const double d[3], const double a[3], const double b[3],
                      const double c[3], double *t, double *u, double *v);

/* tcc_line_triangle's arithmetic, inline for the trees' inner loops (incremental.line_triangle,
 * expression for expression). */
static inline int tcc_line_triangle_inline(const double o[3], const double d[3], const double a[3], const double b[3],
                                           const double c[3], double *t, double *u, double *v)
{
    double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    double p[3] = {d[1] * e2[2] - d[2] * e2[1], d[2] * e2[0] - d[0] * e2[2], d[0] * e2[1] - d[1] * e2[0]};
    double det = e1[0] * p[0] + e1[1] * p[1] + e1[2] * p[2];
    double e11 = e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2];
    int ok = fabs(det) > 1e-14 * (e11 > 1e-30 ? e11 : 1e-30);
    double inv = ok ? 1.0 / det : 0.0;
    double s[3] = {o[0] - a[0], o[1] - a[1], o[2] - a[2]};
    *u = (s[0] * p[0] + s[1] * p[1] + s[2] * p[2]) * inv;
    double q[3] = {s[1] * e1[2] - s[2] * e1[1], s[2] * e1[0] - s[0] * e1[2], s[0] * e1[1] - s[1] * e1[0]};
    *v = (d[0] * q[0] + d[1] * q[1] + d[2] * q[2]) * inv;
    *t = (e2[0] * q[0] + e2[1] * q[1] + e2[2] * q[2]) * inv;
    return ok;
}

/* One line o + t d walked from triangle start (-1: lost at once) for cloth vertex v (its ring row
 * is the exclusion). Returns TCC_OK with *h filled (h->tri = -1: lost) or an error code. */
int tcc_walk_one(const tcc_mesh *m, const double o[3], const double d[3], tcc_idx v, tcc_idx start,
                 const tcc_ring *ring, int max_steps, tcc_hit *h, tcc_error *err);

/* Rays of cloth vertices (origin x[v], direction +-n[v] by slot) walked over the target's triangle
 * adjacency from start[i] until the line passes through the triangle (found) or the walk leaves
 * the mesh, meets an excluded triangle, a parallel triangle or the step budget (lost). */
int tcc_walk(const double *cloth_x, const double *normals, tcc_idx n, const tcc_idx *ray_v,
             const tcc_idx *ray_slot, const tcc_idx *start, tcc_idx k, const tcc_mesh *target,
             const tcc_ring *ring, int max_steps, tcc_hits out, tcc_error *err);

/* ---------------------------------------------------------------- rays.c */

/* Rays for Embree, one segment per collider cluster. Close pairs (pair_a cloth cluster, pair_b
 * collider cluster) sorted by pair_b; ub[q] the distinct pair_b values in order. Collider cluster
 * b's world -> build frame transform is R[b] (kb,3,3), centre[b], ref_centre[b]. Every vertex v of a cluster
 * pair_a with has_normal casts two rays (slot 0: +n, slot 1: -n) from x - backoff d, of length
 * dist = (long_mask[v] ? long_dist : short_dist) + backoff + tol; a ray whose segment misses
 * the world box (lo, hi) of its collider cluster is culled. Written rays are float32 in the build
 * frame. seg (q+1) delimits each cluster's rays. Returns the needed count in *count (> cap:
 * nothing beyond cap was written; call again with a larger cap). */
typedef struct {
    const double *x, *normals;
    const uint8_t *has_normal;
    const uint8_t *long_mask; /* may be NULL */
    tcc_idx n;
    const tcc_idx *order, *ptr; /* cloth clustering */
    tcc_idx norder, kc;
    const double *box_lo, *box_hi; /* collider cluster boxes (kb, 3) */
    tcc_idx kb;
    double short_dist, long_dist, backoff, tol;
} tcc_ray_setup;

int tcc_prepare_rays(const tcc_ray_setup *s, const tcc_idx *pair_a, const tcc_idx *pair_b, tcc_idx np,
                     const tcc_idx *ub, const double *R, const double *centre, const double *ref_centre,
                     tcc_idx q, float *o, float *d, float *dist, tcc_idx *ray_v, tcc_idx *ray_slot, tcc_idx cap,
                     tcc_idx *seg, tcc_idx *count, tcc_error *err);

/* Embree's answer for rays[0..r) of one cluster scene: prim (scene-local triangle or -1) and,
 * for self-collision, tfar. Maps prim to the global triangle through scene_tris and writes
 * hit_tri[ray]. With a ring, a hit on an excluded triangle is skipped: the ray (o, d, dist,
 * float32, build frame) is advanced just past it and listed in retry (returned in *nretry) for
 * another cast, its hit_tri left at -1. */
int tcc_accept_hits(const tcc_idx *rays, const int32_t *prim, const float *tfar, tcc_idx r, const tcc_idx *scene_tris,
                    tcc_idx nscene, const tcc_idx *ray_v, tcc_idx nrays, const tcc_mesh *target, const tcc_ring *ring,
                    float *o, const float *d, float *dist, tcc_idx *hit_tri, tcc_idx *retry, tcc_idx *nretry,
                    tcc_error *err);

/* Entry distance of the ray (o, 1/d) into box over [0, tmax], or INFINITY when it misses. NaN
 * boxes (a NaN position) are missed. */
static inline double tcc_box_entry(const double o[3], const double inv[3], double tmax, const double *bx)
{
    double t0 = 0.0, t1 = tmax;
    for (int a = 0; a < 3; a++) {
        double lo = bx[a], hi = bx[3 + a];
        if (!(lo <= hi)) return INFINITY;
        if (isinf(inv[a])) {
            if (o[a] < lo || o[a] > hi) return INFINITY;
            continue;
        }
        double ta = (lo - o[a]) * inv[a], tb = (hi - o[a]) * inv[a];
        if (ta > tb) {
            double t = ta;
            ta = tb;
            tb = t;
        }
        if (ta > t0) t0 = ta;
        if (tb < t1) t1 = tb;
        if (t0 > t1) return INFINITY;
    }
    return t0;
}

/* The span [*t0, *t1] of the line o + s d (inv = 1 / d) inside box bx (lo xyz, hi xyz), clipped to
 * [lo, hi]; 0 when empty (NaN boxes are missed). */
static inline int tcc_line_box(const double o[3], const double inv[3], double lo, double hi, const double *bx,
                               double *t0, double *t1)
{
    for (int a = 0; a < 3; a++) {
        double l = bx[a], h = bx[3 + a];
        if (!(l <= h)) return 0;
        if (isinf(inv[a])) {
            if (o[a] < l || o[a] > h) return 0;
            continue;
        }
        double ta = (l - o[a]) * inv[a], tb = (h - o[a]) * inv[a];
        if (ta > tb) {
            double t = ta;
            ta = tb;
            tb = t;
        }
        if (ta > lo) lo = ta;
        if (tb < hi) hi = tb;
        if (lo > hi) return 0;
    }
    *t0 = lo;
    *t1 = hi;
    return 1;
}

/* Pair p (a cloth cluster, b collider cluster) checked; [*st, *en) the members of a in s->order. */
int tcc_pair_span(const tcc_ray_setup *s, tcc_idx p, tcc_idx a, tcc_idx b, tcc_idx *st, tcc_idx *en, tcc_error *err);

/* The world ray of member i of the cloth clustering (vertex *v = order[i], checked) along slot:
 * from x - backoff d, length *len; 1 when it is cast, 0 when not (no normal, not finite, or its
 * segment misses the box [lo, hi]), an error code (< 0) for a bad index. */
int tcc_member_ray(const tcc_ray_setup *s, tcc_idx i, int slot, const double *lo, const double *hi, tcc_idx *v,
                   double ow[3], double dw[3], double *len, tcc_error *err);

/* Whether the segment o + s d, s in [0, len], meets the box [lo, hi] (an empty or NaN box: no). */
int tcc_segment_box(const double o[3], const double d[3], double len, const double lo[3], const double hi[3]);

/* ---------------------------------------------------------------- bvh.c */

/* Per-cluster BVHs of the cloth (bvh.c's module docs): cluster c's nodes node_ptr[c] ..
 * node_ptr[c+1] of node (nnodes, 2) and box (nnodes, 6); leaves index prim (nprim). */
typedef struct {
    const tcc_idx *node_ptr; /* (k + 1) */
    tcc_idx k;
    const tcc_idx *node;     /* inner: two children; leaf: -1 - first, count */
    double *box;             /* lo xyz, hi xyz */
    tcc_idx nnodes;
    const tcc_idx *prim;     /* triangle ids */
    tcc_idx nprim;
    double *corner;          /* (nprim, 9) or NULL: each prim's corners as of its last refit (the refit writes them) */
} tcc_bvh;

/* Builds every cluster's tree over its scene triangles scene_tri[scene_ptr[c] .. scene_ptr[c+1]]
 * (median splits at the current positions, then a refit): node_ptr (k+1), node and box with room
 * for cap >= 2 * nrows rows, prim (nrows). *nnodes = rows used. */
int tcc_bvh_build(const tcc_mesh *m, const tcc_idx *scene_ptr, const tcc_idx *scene_tri, tcc_idx nrows, tcc_idx k,
                  tcc_idx *node_ptr, tcc_idx *node, double *box, tcc_idx cap, tcc_idx *prim, tcc_idx *nnodes,
                  tcc_error *err);

/* Cluster c's boxes, bottom-up from the current positions m->x. */
int tcc_bvh_refit(const tcc_mesh *m, tcc_bvh *b, tcc_idx c, tcc_error *err);

/* Nearest triangle of cluster c's tree hit by o + t d, t in [0, tmax], skipping the two-ring of
 * vertex v when ring->table is set: h->tri (-1 if none), t, u, v. */
int tcc_bvh_first_hit(const tcc_mesh *m, const tcc_bvh *b, tcc_idx c, const double o[3], const double d[3],
                      double tmax, const tcc_ring *ring, tcc_idx v, tcc_hit *h, tcc_error *err);

/* Both rays of a cloth vertex in one traversal of cluster c's tree: the line x + s d, slot 0 (+d) the
 * nearest hit with s in [-backoff, *s0] (out: the hit's s), slot 1 (-d) the nearest with s in [*s1,
 * backoff]; active (bit 0, bit 1) the slots asked for. tri[k] in/out: a hit found, or -1 (a hit at
 * exactly the window's end replaces only a -1: the first found wins a tie). The tree must have
 * been refitted with corners, or checked, in this call (tcc_bvh_refit / tcc_bvh_check): its nodes and
 * prims are read without checks. The two-ring of v is skipped when ring is set. */
void tcc_bvh_line(const tcc_mesh *m, const tcc_bvh *b, tcc_idx c, const double x[3], const double d[3], int active,
                  double backoff, double *s0, double *s1, const tcc_ring *ring, tcc_idx v, tcc_idx tri[2]);

/* Whether the line x + s d meets a triangle of cluster c's tree other than skip for s in [lo, hi), its
 * barycentrics exactly within [0, 1] (tcc_confirm_inside's test). The tree as for tcc_bvh_line. */
int tcc_bvh_blocked(const tcc_bvh *b, tcc_idx c, const double x[3], const double d[3], double lo, double hi,
                    tcc_idx skip);

/* Cluster c's nodes and prims checked (the reads tcc_bvh_line skips), corners written when kept. */
int tcc_bvh_check(const tcc_mesh *m, tcc_bvh *b, tcc_idx c, tcc_error *err);

/* tcc_bvh_first_hit for r rays (o, d (r, 3), tmax, cluster, ray_v (may be NULL without a ring)). */
int tcc_bvh_cast(const tcc_mesh *m, const tcc_bvh *b, const tcc_idx *cluster, const double *o, const double *d,
                 const double *tmax, const tcc_idx *ray_v, tcc_idx r, const tcc_ring *ring, tcc_hits out,
                 tcc_error *err);

/* Full self-collision detection of a step in one call: for every close pair (pair_a cloth cluster,
 * pair_b cloth cluster as the target, any order) the rays of pair_a's vertices (as
 * tcc_prepare_rays: from x - backoff d, length dist + backoff + tol, culled against pair_b's box),
 * each cast into pair_b's tree, refitted first when refit_step[pair_b] != step (then set to step).
 * Rays that hit are written (ray_v, ray_slot, hit_tri, at most cap); *nhits = how many hit (> cap:
 * call again with more room), *nrays = rays cast. */
int tcc_self_cast(const tcc_ray_setup *s, const tcc_mesh *target, tcc_bvh *b, tcc_idx *refit_step, tcc_idx step,
                  const tcc_ring *ring, const tcc_idx *pair_a, const tcc_idx *pair_b, tcc_idx np, tcc_idx *ray_v,
                  tcc_idx *ray_slot, tcc_idx *hit_tri, tcc_idx cap, tcc_idx *nhits, tcc_idx *nrays, tcc_error *err);

/* ---------------------------------------------------------------- contacts.c */

enum { TCC_VOLUME = 0, TCC_SURFACE = 1, TCC_SELF = 2 };

/* Candidates from Embree refined on the current geometry: each ray with hit_tri >= 0 is walked
 * (4 steps at most) from it; a found hit with t >= -2e-6 is written (compacted) to out with status
 * 1 = keep, 2 = needs the inside confirmation (a volume: a back face beyond track_range for a
 * vertex that was not inside), 0 = out of range (kept in the list: a nearer hit of the same ray,
 * whatever its range, proves a far back face is not the exit). Returns the count in *count. */
int tcc_refine(const double *cloth_x, const double *normals, tcc_idx n, const tcc_idx *ray_v, const tcc_idx *ray_slot,
               const tcc_idx *hit_tri, tcc_idx r, const tcc_mesh *target, const tcc_ring *ring, int kind,
               double track_range, const uint8_t *inside_prev, tcc_idx *out_v, tcc_idx *out_slot, tcc_hits out,
               uint8_t *status, tcc_idx *count, tcc_error *err);

/* Tracks are sparse: a list sorted by key = 2 * vertex + slot (most vertices track nothing). */
/* A far back-face hit (status 2) is not the exit if another hit of the same ray (vertex, slot)
 * is nearer: a candidate among these k (any status) or the ray's walked track (track_key sorted,
 * walked_tri / walked_t parallel to it). Such hits get status 0; *left counts the status 2 left. */
int tcc_drop_dominated(const tcc_idx *v, const tcc_idx *slot, const double *t, uint8_t *status, tcc_idx k,
                       const tcc_idx *track_key, tcc_idx kt, const tcc_idx *walked_tri, const double *walked_t,
                       tcc_idx *left, tcc_error *err);

/* The inside confirmation of a far exit (tcc_refine's status 2): for each ray o + s d (world),
 * whether no triangle other than exit_tri[i] is hit for s in [-backoff, t_exit[i] - eps], over
 * the triangles of every cluster whose box (lo, hi) the segment crosses (tri_order[tri_ptr[c] ..
 * tri_ptr[c+1]] are cluster c's triangles). Exact, on the current geometry. */
int tcc_confirm_inside(const tcc_mesh *m, const tcc_idx *tri_order, tcc_idx ntri_order, const tcc_idx *tri_ptr,
                       tcc_idx k, const double *lo, const double *hi, const double *o, const double *d,
                       const double *t_exit, const tcc_idx *exit_tri, tcc_idx r, double backoff, double eps,
                       uint8_t *ok, tcc_error *err);

typedef struct {
    /* cloth */
    const double *x, *normals, *x_prev, *velocity; /* (n,3); velocity may be NULL (zero) */
    tcc_idx n;
    /* collider */
    const tcc_mesh *target;
    const double *target_prev, *target_velocity; /* (nv,3); target_velocity may be NULL (zero) */
    int kind, first;
    double thickness, track_range;
    /* tracks of the previous step (kt, sorted by key) and where their walk ended this step */
    const tcc_idx *track_key, *track_tri;
    const int8_t *track_side;
    tcc_idx kt;
    tcc_hits walked; /* kt entries, parallel to the tracks */
    /* new hits of full detection (kf rays); status 1 = keep, anything else is ignored */
    const tcc_idx *f_v, *f_slot;
    tcc_hits f_hit;
    const uint8_t *f_status;
    tcc_idx kf;
} tcc_merge_in;

/* Every output list has room for kt + kf entries. */
typedef struct {
    tcc_idx *track_key, *track_tri; /* the new tracks, sorted by key */
    int8_t *track_side;
    tcc_idx ntracks;
    tcc_idx *inside; /* vertices inside a closed body, ascending */
    tcc_idx ninside;
    tcc_idx *contact_v; /* this collider's deepest contact per vertex, ascending vertex */
    double *depth, *normal, *velocity;
    tcc_idx ncontacts;
} tcc_merge_out;

/* Nearest hit per vertex and ray slot, classified into contacts (narrow.py module docs), the new
 * tracks, and per vertex the deepest contact of this collider. */
int tcc_merge_classify(const tcc_merge_in *in, tcc_merge_out *out, tcc_error *err);

/* Contacts of c colliders, each list sorted by vertex (seg (c+1) delimits them in v, depth,
 * normal, velocity): per vertex the deepest one (deep_*, first collider on ties) and every one
 * (all_*, by vertex then collider); friction (c,) per collider. Outputs have room for seg[c]. */
int tcc_assemble(const tcc_idx *seg, tcc_idx c, const tcc_idx *v, const double *depth, const double *normal,
                 const double *velocity, const double *friction, tcc_idx n, int32_t *deep_v, double *deep_normal,
                 double *deep_depth, double *deep_velocity, double *deep_friction, tcc_idx *ndeep, int32_t *all_v,
                 double *all_normal, double *all_depth, double *all_velocity, double *all_friction, tcc_idx *nall,
                 tcc_error *err);

/* ---------------------------------------------------------------- ccd.c */

/* Swept vertex-triangle test: every point moves linearly from x0 to x1 ((n, 3) each) over s in
 * [0, 1]. For each pair (pv[q], pt[q]) (the vertex must not be a corner of the triangle): toi[q]
 * the earliest s at which the vertex is within gap of the triangle (+inf if never), w[q] the
 * barycentrics of its closest point then, side[q] the side it came from (+1: the side the face
 * normal (b - a) x (c - a) points to; its side at s = 0, or, on the plane at s = 0, the side it
 * moves away from; 0 without a hit). A pair farther apart at s = 0 than gap plus the vertex's
 * largest motion relative to a corner is rejected before any root search. *nhit = hits. The gap of
 * pair q is the smaller of gap_all and pair_gap[q] (pair_gap may be NULL). */
int tcc_ccd_vertex_triangle(const double *x0, const double *x1, tcc_idx n, const tcc_idx *tri, tcc_idx nt,
                            const tcc_idx *pv, const tcc_idx *pt, tcc_idx k, double gap_all, const double *pair_gap,
                            double *toi, double *w, int8_t *side, tcc_idx *nhit, tcc_error *err);

/* Vertex-triangle pairs at positions x: sd[q] the signed distance of the vertex to the triangle's
 * plane along its unit normal normal[q], dist[q] the distance to the triangle, w[q] the
 * barycentrics of the closest point. */
int tcc_vertex_triangle_state(const double *x, tcc_idx n, const tcc_idx *tri, tcc_idx nt, const tcc_idx *pv,
                              const tcc_idx *pt, tcc_idx k, double *sd, double *dist, double *w, double *normal,
                              tcc_error *err);

/* Swept edge-edge test, the dual of the vertex-triangle one: edges ea[q] = (a, b) and eb[q] =
 * (c, d) (no shared vertex) moving linearly from x0 to x1. toi[q] the earliest s in [0, 1] at which
 * the segments come within gap (+inf if never), st[q] the closest points' parameters along ab and
 * cd then, side[q] the side of ab from cd along n = (b - a) x (d - c) before (+1 or -1, 0 without a
 * hit); the same rejection before any root search. */
int tcc_ccd_edge_edge(const double *x0, const double *x1, tcc_idx n, const tcc_idx *ea, const tcc_idx *eb, tcc_idx k,
                      double gap_all, const double *pair_gap, double *toi, double *st, int8_t *side, tcc_idx *nhit,
                      tcc_error *err);

/* Edge pairs at positions x: sd[q] = (a - c) . n with n[q] the unit (b - a) x (d - c), dist[q] the
 * segments' distance, st[q] their closest points' parameters. */
int tcc_edge_edge_state(const double *x, tcc_idx n, const tcc_idx *ea, const tcc_idx *eb, tcc_idx k, double *sd,
                        double *dist, double *st, double *normal, tcc_error *err);

/* One pair, its four points given (vertex, triangle corners / edge ends): the swept tests over
 * A -> B (1 = hit, *toi, the closest point's barycentrics w or edge parameters st, *side), the
 * state at P (as the array kernels above) and the squared distance of the two elements (split 1:
 * vertex-triangle, 2: edge-edge). The array kernels above are these over lists of pairs. */
int tcc_vt_sweep(const double *const A[4], const double *const B[4], double gap, double *toi, double w[3],
                 int8_t *side);
int tcc_ee_sweep(const double *const A[4], const double *const B[4], double gap, double *toi, double st[2],
                 int8_t *side);
void tcc_vt_state(const double *const P[4], double *sd, double *dist, double w[3], double normal[3]);
void tcc_ee_state(const double *const P[4], double *sd, double *dist, double st[2], double normal[3]);
double tcc_pair_distance2(const double *const P[4], int split);

/* ---------------------------------------------------------------- swept.c */

/* One kind of swept pairs of the two-ring (vertex-triangle or edge-edge) and the state the swept
 * stage carries for it between steps (swept.c's module docs). */
typedef struct {
    int split;              /* 1: vertex-triangle, quad = (vertex, corners); 2: edge-edge, quad = (a, b, c, d) */
    const tcc_idx *quad;    /* (k, 4) */
    tcc_idx k;
    const double *gap;      /* (k) */
    double *slack;          /* (k) in/out: a lower bound of distance - gap when the pair was last read */
    const tcc_idx *bptr, *bvptr, *bverts, *bgptr, *bgroups; /* blocks: pairs, vertices (ascending), groups */
    tcc_idx nb, nbv, nbg;
    double *bstate;         /* (nb, 2) in/out: min, and a bound of the spread since the reference pose */
    double *bref;           /* (nbv, 3) in/out: each block's vertices at its reference pose */
    const tcc_idx *mem;     /* remembered crossings (nmem) and the side each is pushed to (nmem, 3) */
    const double *mem_n;
    tcc_idx nmem;
    tcc_idx *mem_out;       /* (k) the memory after this step, mem_n_out (k, 3) */
    double *mem_n_out;
    tcc_idx nmem_out;
    /* the pairs that give contacts this step (k at most): the nlive remembered ones still on the
     * wrong side or close, then the npred predicted ones; normal (k, 3), depth (k), w (k, 3): the
     * closest point's barycentrics (vertex-triangle) or edge parameters and 0 (edge-edge) */
    tcc_idx *out_q;
    double *out_normal, *out_depth, *out_w;
    tcc_idx nlive, npred;
    tcc_idx tested, crossed, remembered; /* counts of this step */
    tcc_idx settled[4];     /* blocks settled by the cull's bounds 1, 2, 3 (swept.c), and blocks read */
} tcc_swept_kind;

typedef struct {
    const double *x, *x_prev, *v; /* (n, 3); x_prev NULL: no previous step; v NULL: no prediction */
    tcc_idx n;
    double dt, thickness;
    const tcc_idx *group_ptr, *group_vertices; /* small groups of nearby vertices, for the blocks' bounds */
    tcc_idx ngroups, ngv;
    uint8_t *has_ref;       /* in/out: the blocks' reference poses are set (else: set from x_prev, or x) */
    tcc_swept_kind kind[2]; /* vertex-triangle, edge-edge */
    tcc_idx *cand_out[2], *pcand_out[2]; /* optional (k each): the pairs the cull handed out, both windows */
    tcc_idx ncand[2], npcand[2];
} tcc_swept;

/* One step of the swept stage: cull, swept tests, memory, and the pairs that give contacts. x_prev
 * must be the x of the previous call (the blocks' running bounds grow by the motion between the two). */
int tcc_swept_step(tcc_swept *s, tcc_error *err);

/* Contact rows of the pairs tcc_swept_step listed (4 per pair: both elements' vertices pushed apart
 * along the pair's normal, at the pair's mean velocity v (may be NULL: zero)), those without a normal
 * dropped (*no_normal rows), merged stably by vertex after the colliders' contacts (ev ascending):
 * *count rows; written only when they fit in cap. */
int tcc_swept_rows(const tcc_swept_kind kind[2], const double *v, tcc_idx n, const int32_t *ev, const double *enormal,
                   const double *edepth, const double *evel, const double *efric, tcc_idx ne, double friction,
                   int32_t *ov, double *onormal, double *odepth, double *ovel, double *ofric, tcc_idx cap,
                   tcc_idx *count, tcc_idx *no_normal, tcc_error *err);

/* The swept stage's pairs of a topology (swept.c): the edges (min, max) ascending (*ne), the
 * vertex-triangle pairs (u, t) with u in the ring of a corner of t and not a corner (*nvt), and the
 * edge-edge pairs (a, b) of edge ids, a < b, no shared vertex, an end of b in the ring of an end of
 * a (*nee), each list ascending and once per pair (np.unique's order). A list is written only when
 * it fits its capacity (edges ecap, vt vcap, ee ecap2; ee needs the edges): call again with room. */
int tcc_swept_pairs(const tcc_idx *tri, tcc_idx nt, tcc_idx n, const tcc_ring *ring, tcc_idx *edges, tcc_idx ecap,
                    tcc_idx *vt, tcc_idx vcap, tcc_idx *ee, tcc_idx ecap2, tcc_idx *ne, tcc_idx *nvt, tcc_idx *nee,
                    tcc_error *err);

/* The cull's blocks: runs of `size` consecutive pairs of quad (k, 4), each with its vertices
 * ascending (bverts, room for 4k) and their groups ascending (bgroups, room for 4k); bptr, bvptr,
 * bgptr have nb + 1 = ceil(k / size) + 1 entries. */
int tcc_swept_blocks(const tcc_idx *quad, tcc_idx k, tcc_idx size, const tcc_idx *group, tcc_idx n, tcc_idx *bptr,
                     tcc_idx *bvptr, tcc_idx *bverts, tcc_idx *bgptr, tcc_idx *bgroups, tcc_error *err);

/* ---------------------------------------------------------------- detect.c */

/* One collider's step (detect.c): the cloth, the collider, its close pairs and tracks. */
typedef struct {
    /* the cloth: positions, positions at the previous step, velocities (may be NULL) */
    const double *x, *x_prev, *velocity;
    tcc_idx n;
    const tcc_idx *tri;                     /* (nt, 3) */
    tcc_idx nt;
    const tcc_idx *vt_ptr, *vt_tri;         /* vertex -> incident triangles (CSR, ascending), for normals */
    tcc_idx nvt;
    const tcc_idx *order, *ptr, *labels;    /* the cloth's clusters: members, bounds (kc + 1), label per vertex */
    tcc_idx norder, kc;
    double *normals;                        /* (n, 3) in/out: the step's normals, per vertex as needed */
    uint8_t *has_normal, *done;             /* (n) each, in/out: done marks the normals computed this step */
    /* the collider (the cloth itself for self-collision: kind TCC_SELF) */
    int kind;
    tcc_mesh target;                        /* with adjacency: the walks */
    const double *target_prev, *target_velocity; /* its positions at the previous step; velocities or NULL */
    const tcc_idx *tri_labels;              /* (nt) cluster of each triangle */
    tcc_idx kb;                             /* collider clusters */
    const double *box_lo, *box_hi;          /* (kb, 3) the collider clusters' inflated boxes */
    tcc_ring ring;                          /* self-collision: the two-ring exclusion (table NULL: none) */
    tcc_bvh bvh;                            /* the collider clusters' trees */
    tcc_idx *refit_step;                    /* (kb) in/out: the step each tree was refitted at */
    tcc_idx step;
    /* close pairs (cloth cluster, collider cluster) in row-major order, and which get full detection
     * (in/out: a lost walk marks its pair) */
    const tcc_idx *pi, *pj;
    uint8_t *full;
    tcc_idx np;
    /* tracks (ascending key 2 * vertex + slot, triangle, remembered side), vertices inside (ascending) */
    const tcc_idx *track_key, *track_tri;
    const int8_t *track_side;
    tcc_idx kt;
    const tcc_idx *inside;
    tcc_idx ninside;
    double thickness, track_range;
    double ray_length;  /* full detection's rays (m; a closed body's: track_range + 2 inflate + its extent) */
    double inflate, backoff;
    int first;          /* the first detection of this collider: new hits take their current side */
    /* the pairs' clearance (optional, NULL: not measured): for each pair fully detected, the shortest
     * distance along its cloth vertices' lines (+n and -n) to the nearest hit NOT within track_range
     * (untracked), at most probe_length; track_range for a ray hit within it (it is tracked, the walk
     * covers it) and for a vertex that was inside a closed body; NaN for the pairs not fully detected.
     * probe_length >= ray_length: how far the lines of a cloth or thin surface are searched for it
     * (only hits within ray_length become tracks, so the contacts do not depend on it). */
    double *clearance;
    double probe_length;
    /* the clearance credit of the paper's rule (optional: rel_dev NULL, or clearance NULL: none;
     * collision/detector.py's module docs, "Clearance"): each pair fully detected (lost walks
     * included) restarts its relative measure - rel_avg (np, 3) set to 0 - with the credit as a
     * negative start of its deviation: rel_dev = -credit_unit * clamp((clearance - thickness) /
     * (track_range - thickness) - 1, 0, clearance_cap - 1) (0 when that is not finite). Here rather
     * than in numpy after the call: the step's per-pair work stays in this one call. */
    double *rel_avg, *rel_dev;
    double credit_unit, clearance_cap;
} tcc_detect_in;

typedef struct {
    tcc_idx tracked, lost, full_pairs, rays, hits;
    double seconds[4]; /* wall time of the walks, the casts, the refinement, the merge */
} tcc_detect_stats;

/* The step of one collider: walks (lost walks mark their pairs full), full detection of the marked
 * pairs, refinement, the merge (tcc_merge_classify: out's lists have room for 2n tracks, n inside,
 * n contacts). */
int tcc_detect(tcc_detect_in *in, tcc_merge_out *out, tcc_detect_stats *stats, tcc_error *err);

/* ---------------------------------------------------------------- impact.c */

/* The impact guard (impact.c's module docs): the step's motion x0 -> x1 of the cloth made free of
 * self-crossings by inelastic impulses, then rigid impact zones, then (the cap hit) one rigid
 * cloth. x1 and v are corrected in place for the vertices whose motion changed. The tree is
 * tcc_bvh_build's with one cluster (rows node (nnodes, 2), prim (nt): a node's triangles are a
 * contiguous run of prim rows);
 * vertex_owner[v] is the one triangle that tests v against others (-1: v is in none), edge_owner
 * (nt, 3) is 1 where the triangle tests its edge k = (tri[k], tri[k+1 mod 3]) (one triangle per
 * edge). */
typedef struct {
    const double *x0;      /* (n, 3) m: positions at the step's start */
    double *x1;            /* (n, 3) m: at its end, in/out */
    double *v;             /* (n, 3) m/s: velocities at its end, in/out */
    const double *mass;    /* (n,) kg, > 0 */
    const double *rest;    /* (n, 3) m: rest positions (twins of a cut share theirs) */
    tcc_idx n;
    const tcc_idx *tri;    /* (nt, 3) */
    tcc_idx nt;
    const tcc_idx *vowner; /* (n,) */
    const uint8_t *eowner; /* (nt, 3) */
    const tcc_idx *node;   /* (nnodes, 2) */
    tcc_idx nnodes;
    const tcc_idx *prim;   /* (nt,) */
    const tcc_idx *adj;    /* (nt, 3) the triangle across edge k, -1 none, -2 an edge of more than two */
    const uint8_t *flip;   /* (nt, 3) 1 when that neighbour's winding is opposite */
    const uint8_t *interior; /* (n,) 1: every edge at the vertex has two consistently wound triangles */
    const tcc_idx *vt_ptr; /* (n + 1) the vertex's triangles vt_tri[vt_ptr[v] .. vt_ptr[v+1]) */
    const tcc_idx *vt_tri;
    tcc_idx nvt;
    tcc_idx *patch;        /* (nnodes,) in/out cache of the topology: -1 unknown, -2 not a disk, else the
                              length of the node's boundary loop (start at -1 after a topology change) */
    tcc_idx *loop;         /* (nloop,) in/out: node i's loop at loop_off[i] (room for its triangles + 2) */
    const tcc_idx *loop_off; /* (nnodes + 1) */
    tcc_idx nloop;
    double dt;             /* s, > 0 */
    double gap;            /* m, > 0: a pair this close during the step and approaching collides */
    double rest_fraction;  /* a pair's gap is at most this share of its rest distance */
    double min_rest;       /* m: pairs closer than this at rest are one piece (never collide) */
    int impulse_passes, zone_passes; /* caps */
} tcc_impact_in;

typedef struct {
    tcc_idx candidates;     /* element pairs given to the swept tests, over every detection */
    tcc_idx collisions;     /* collisions of the step as the solve left it (the first detection) */
    tcc_idx excluded;       /* pairs within the gap that coincide at rest (twins): never collisions */
    tcc_idx crossing_only;  /* collisions of pairs that parted within their gap but crossed later */
    tcc_idx impulses;       /* impulses applied */
    tcc_idx impulse_passes; /* detections followed by impulses */
    tcc_idx zone_passes;    /* detections followed by zone merges */
    tcc_idx zones;          /* impact zones at the end */
    tcc_idx zone_vertices;  /* vertices in them */
    tcc_idx unresolved;     /* collisions left at the zone pass cap (then the cloth moved as one zone) */
    tcc_idx rigid_cloth;    /* 1 when the cap was hit and the whole cloth moved rigidly */
    tcc_idx moved;          /* vertices whose motion changed */
    tcc_idx immovable;      /* vertices the step left exactly in place (infinite mass here) */
    tcc_idx patches_free;   /* tree nodes not tested against themselves (normal cone and star contour) */
} tcc_impact_counts;

int tcc_impact_resolve(const tcc_impact_in *in, tcc_impact_counts *out, tcc_error *err);


#endif
