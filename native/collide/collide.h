/* collide.h - the kernels of clustered, ray-traced collision detection (tearcloth._collide).
 *
 * The Python package `tearcloth.collision` owns the state and the order of a step (clusters,
 * measures, Embree scenes, tracks); these kernels own every loop over vertices, rays, triangles or
 * cluster pairs in that step, so that a step costs a few dozen calls whatever the mesh size.
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

typedef int64_t tcc_idx;

enum { TCC_OK = 0, TCC_ERR_INDEX = -1, TCC_ERR_VALUE = -2, TCC_ERR_NOMEM = -3 };

typedef struct {
    int code;
    char what[200];
} tcc_error;

/* Records the first error only: later failures keep the message of the first cause. */
int tcc_fail(tcc_error *err, int code, const char *fmt, ...);

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

/* The pairs (quad[q]: 4 vertex ids, the first `split` one element) that may come within gap[q]
 * over a motion of displacement disp (n, 3) (m) per vertex: out[0..*nout) their indices; slack (k) in/out, a
 * lower bound of distance - gap (start at -inf: exact on first use), carried on and recomputed
 * exactly at x for the pairs handed out when update is set (see ccd.c). */
int tcc_ccd_cull(const double *x, tcc_idx n, const tcc_idx *quad, tcc_idx k, int split, const double *disp,
                 const double *gap, double *slack, int update, tcc_idx *out, tcc_idx *nout, tcc_error *err);

/* tcc_ccd_cull by blocks of pairs (pair ranges block_ptr (nb + 1), each with the vertices
 * block_vertices[block_vptr[b] .. block_vptr[b + 1]) that its pairs' corners are among): a block
 * whose bound block_min (nb, in/out; -inf: unknown) minus its uncharged motion block_debt (nb,
 * in/out; start at 0) and this step's relative motion of its vertices stays positive is skipped
 * without reading its pairs (see ccd.c). Like tcc_ccd_cull, it hands out every pair that can come within its gap. disp2 (n, 3) or
 * NULL: a second motion culled after the first without update, into out2 (k) and *nout2. */
int tcc_ccd_cull_blocks(const double *x, tcc_idx n, const tcc_idx *quad, tcc_idx k, int split, const double *disp,
                        const double *gap, double *slack, int update, const tcc_idx *block_ptr, tcc_idx nb,
                        const tcc_idx *block_vptr, const tcc_idx *block_vertices, tcc_idx nbv, double *block_min,
                        double *block_debt, tcc_idx *out, tcc_idx *nout, const double *disp2, tcc_idx *out2,
                        tcc_idx *nout2, tcc_error *err);

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
