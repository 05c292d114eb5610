/* bvh.c - one bounding volume hierarchy per collider cluster, refitted instead of rebuilt, and the
 * first-hit ray query the full detection runs through it.
 *
 * Why not Embree here: embreex exposes no refit, so a cluster that deformed needed a new scene,
 * copied through Python at ~1.4 us per triangle plus the build (0.3-0.8 ms for a 200-triangle
 * cluster); the cloth deforms every step and the skinned body does too. A cluster's tree here is
 * built once per topology (median split on triangle centroids, leaves of up to BVH_LEAF
 * triangles) and only its boxes are recomputed from the current corners before a query (a few
 * microseconds per cluster). The clusters are geodesic k-means patches of ~100 vertices: compact
 * pieces of surface whose triangles keep their neighbours under cloth-like deformation, so refitted
 * boxes stay tight enough. Rays are a few thousand per step, where Embree's SIMD traversal does not
 * pay; the query skips a self-collision ray's own two-ring inside the traversal (embreex has no hit
 * filter: it needed up to eight re-casts from Python).
 *
 * Layout (arrays the caller owns): cluster c's scene triangles are tris[ptr[c]:ptr[c+1]] (global
 * triangle ids, n_c of them); its nodes are node rows [2 ptr[c], 2 ptr[c] + 2 n_c - 1) in pre-order
 * (a node's left child follows it; its right child's local index is in `first`); a leaf has
 * count > 0 and covers perm[ptr[c] + first .. + count), perm being the cluster's triangles
 * reordered by the build; rows no node uses have count -1. Boxes lo/hi are (rows, 3) doubles.
 */
#include "collide.h"

#include <math.h>
#include <stdlib.h>

#define BVH_LEAF 4
#define BVH_EDGE 1e-9 /* barycentric slack: a ray through a shared edge hits one of its two triangles */

typedef struct {
    double key;
    tcc_idx tri;
} centroid;

static void select_nth(centroid *a, tcc_idx n, tcc_idx k)
{
    /* quickselect: a[k] ends where it would be in sorted order, smaller keys before it */
    tcc_idx lo = 0, hi = n - 1;
    while (lo < hi) {
        double pivot = a[(lo + hi) / 2].key;
        tcc_idx i = lo, j = hi;
        while (i <= j) {
            while (a[i].key < pivot) i++;
            while (a[j].key > pivot) j--;
            if (i <= j) {
                centroid t = a[i];
                a[i] = a[j];
                a[j] = t;
                i++;
                j--;
            }
        }
        if (k <= j) hi = j;
        else if (k >= i) lo = i;
        else return;
    }
}

typedef struct {
    const tcc_mesh *m;
    centroid *c;
    double *cent; /* (n, 3) centroids of the cluster's triangles, by position in c's input */
    tcc_idx *first, *count;
    tcc_idx nodes;
} builder;

static void tri_box(const tcc_mesh *m, tcc_idx f, double lo[3], double hi[3])
{
    const tcc_idx *t = m->tri + 3 * f;
    for (int a = 0; a < 3; a++) {
        double x0 = m->x[3 * t[0] + a], x1 = m->x[3 * t[1] + a], x2 = m->x[3 * t[2] + a];
        double l = x0 < x1 ? x0 : x1, h = x0 > x1 ? x0 : x1;
        lo[a] = l < x2 ? l : x2;
        hi[a] = h > x2 ? h : x2;
    }
}

/* builds the subtree over b->c[s, e) at local node b->nodes; returns its local index */
static tcc_idx build(builder *b, tcc_idx s, tcc_idx e, int depth)
{
    tcc_idx me = b->nodes++;
    tcc_idx n = e - s;
    if (n <= BVH_LEAF || depth > 60) {
        b->first[me] = s;
        b->count[me] = n;
        return me;
    }
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (tcc_idx i = s; i < e; i++)
        for (int a = 0; a < 3; a++) {
            double v = b->cent[3 * b->c[i].tri + a];
            lo[a] = v < lo[a] ? v : lo[a];
            hi[a] = v > hi[a] ? v : hi[a];
        }
    int axis = 0;
    for (int a = 1; a < 3; a++)
        if (hi[a] - lo[a] > hi[axis] - lo[axis]) axis = a;
    for (tcc_idx i = s; i < e; i++) b->c[i].key = b->cent[3 * b->c[i].tri + axis];
    tcc_idx mid = s + n / 2;
    select_nth(b->c + s, n, mid - s);
    b->count[me] = 0;
    build(b, s, mid, depth + 1);
    b->first[me] = build(b, mid, e, depth + 1);
    return me;
}

int tcc_bvh_build(const tcc_mesh *m, const tcc_idx *ptr, tcc_idx k, const tcc_idx *tris, tcc_idx ntris,
                  tcc_idx *perm, tcc_idx *first, tcc_idx *count, tcc_error *err)
{
    tcc_idx most = 0;
    for (tcc_idx c = 0; c < k; c++) {
        if (ptr[c] < 0 || ptr[c + 1] < ptr[c] || ptr[c + 1] > ntris)
            return tcc_fail(err, TCC_ERR_INDEX, "cluster %lld spans [%lld, %lld), outside the %lld scene triangles",
                            (long long)c, (long long)ptr[c], (long long)ptr[c + 1], (long long)ntris);
        if (ptr[c + 1] - ptr[c] > most) most = ptr[c + 1] - ptr[c];
    }
    for (tcc_idx i = 0; i < ntris; i++) {
        tcc_idx f = tris[i];
        if (f < 0 || f >= m->nt)
            return tcc_fail(err, TCC_ERR_INDEX, "scene triangle %lld = %lld is not in [0, %lld)", (long long)i,
                            (long long)f, (long long)m->nt);
        for (int q = 0; q < 3; q++)
            if (m->tri[3 * f + q] < 0 || m->tri[3 * f + q] >= m->nv)
                return tcc_fail(err, TCC_ERR_INDEX, "triangle %lld names vertex %lld, not in [0, %lld)", (long long)f,
                                (long long)m->tri[3 * f + q], (long long)m->nv);
    }
    for (tcc_idx r = 0; r < 2 * ntris; r++) {
        first[r] = 0;
        count[r] = -1; /* a row no node uses (leaves of several triangles leave rows over) */
    }
    centroid *cbuf = malloc(sizeof *cbuf * (size_t)(most > 0 ? most : 1));
    double *cent = malloc(sizeof *cent * 3 * (size_t)(most > 0 ? most : 1));
    if (!cbuf || !cent) {
        free(cbuf);
        free(cent);
        return tcc_fail(err, TCC_ERR_NOMEM, "out of memory building the trees of %lld clusters", (long long)k);
    }
    for (tcc_idx c = 0; c < k; c++) {
        tcc_idx s = ptr[c], n = ptr[c + 1] - ptr[c];
        if (n == 0) continue;
        for (tcc_idx i = 0; i < n; i++) {
            const tcc_idx *t = m->tri + 3 * tris[s + i];
            for (int a = 0; a < 3; a++)
                cent[3 * i + a] = (m->x[3 * t[0] + a] + m->x[3 * t[1] + a] + m->x[3 * t[2] + a]) / 3.0;
            cbuf[i].tri = i;
            cbuf[i].key = 0.0;
        }
        builder b = {m, cbuf, cent, first + 2 * s, count + 2 * s, 0};
        build(&b, 0, n, 0);
        for (tcc_idx i = 0; i < n; i++) perm[s + i] = tris[s + cbuf[i].tri];
    }
    free(cbuf);
    free(cent);
    return TCC_OK;
}

int tcc_bvh_refit(const tcc_mesh *m, const tcc_idx *ptr, tcc_idx k, const tcc_idx *perm, tcc_idx ntris,
                  const tcc_idx *first, const tcc_idx *count, const tcc_idx *clusters, tcc_idx q, double *lo,
                  double *hi, tcc_error *err)
{
    for (tcc_idx g = 0; g < q; g++) {
        tcc_idx c = clusters[g];
        if (c < 0 || c >= k)
            return tcc_fail(err, TCC_ERR_INDEX, "cluster %lld is not in [0, %lld)", (long long)c, (long long)k);
        tcc_idx s = ptr[c], n = ptr[c + 1] - ptr[c];
        if (s < 0 || n < 0 || s + n > ntris)
            return tcc_fail(err, TCC_ERR_INDEX, "cluster %lld spans [%lld, %lld), outside the %lld scene triangles",
                            (long long)c, (long long)s, (long long)(s + n), (long long)ntris);
        if (n == 0) continue;
        const tcc_idx *fi = first + 2 * s, *ct = count + 2 * s;
        double *L = lo + 6 * s, *H = hi + 6 * s;
        /* pre-order: every child comes after its parent, so one backward pass refits bottom-up */
        for (tcc_idx node = 2 * n - 2; node >= 0; node--) {
            double *l = L + 3 * node, *h = H + 3 * node;
            if (ct[node] < 0) continue;
            if (ct[node] > 0) {
                if (fi[node] < 0 || fi[node] + ct[node] > n)
                    return tcc_fail(err, TCC_ERR_INDEX, "cluster %lld: leaf %lld covers [%lld, %lld) of %lld triangles",
                                    (long long)c, (long long)node, (long long)fi[node],
                                    (long long)(fi[node] + ct[node]), (long long)n);
                l[0] = l[1] = l[2] = INFINITY;
                h[0] = h[1] = h[2] = -INFINITY;
                for (tcc_idx i = fi[node]; i < fi[node] + ct[node]; i++) {
                    double tl[3], th[3];
                    tri_box(m, perm[s + i], tl, th);
                    for (int a = 0; a < 3; a++) {
                        l[a] = tl[a] < l[a] ? tl[a] : l[a];
                        h[a] = th[a] > h[a] ? th[a] : h[a];
                    }
                }
            } else {
                tcc_idx left = node + 1, right = fi[node];
                if (right <= node + 1 || right > 2 * n - 2 || ct[right] < 0 || ct[left] < 0)
                    return tcc_fail(err, TCC_ERR_INDEX, "cluster %lld: node %lld has right child %lld", (long long)c,
                                    (long long)node, (long long)right);
                for (int a = 0; a < 3; a++) {
                    double la = L[3 * left + a], lb = L[3 * right + a], ha = H[3 * left + a], hb = H[3 * right + a];
                    l[a] = la < lb ? la : lb;
                    h[a] = ha > hb ? ha : hb;
                }
            }
        }
    }
    return TCC_OK;
}

/* entry distance of the ray into the box, or INFINITY when it misses within [0, tmax] */
static double ray_box(const double o[3], const double inv[3], double tmax, const double *l, const double *h)
{
    double t0 = 0.0, t1 = tmax;
    for (int a = 0; a < 3; a++) {
        double ta = (l[a] - o[a]) * inv[a], tb = (h[a] - o[a]) * inv[a];
        if (ta > tb) {
            double t = ta;
            ta = tb;
            tb = t;
        }
        if (ta != ta) ta = -INFINITY; /* 0 * inf: the ray lies in the slab's plane */
        if (tb != tb) tb = INFINITY;
        t0 = ta > t0 ? ta : t0;
        t1 = tb < t1 ? tb : t1;
        if (t0 > t1) return INFINITY;
    }
    return t0;
}

static int excluded(const tcc_ring *ring, tcc_idx v, const tcc_idx *tv)
{
    const tcc_idx *row = ring->table + v * ring->width;
    for (tcc_idx w = 0; w < ring->width; w++)
        if (row[w] >= 0 && (tv[0] == row[w] || tv[1] == row[w] || tv[2] == row[w])) return 1;
    return 0;
}

int tcc_bvh_cast(const tcc_mesh *m, const tcc_idx *ptr, tcc_idx k, const tcc_idx *perm, tcc_idx ntris,
                 const tcc_idx *first, const tcc_idx *count, const double *lo, const double *hi, const tcc_idx *ub,
                 tcc_idx q, const tcc_idx *seg, const float *o, const float *d, const float *dist,
                 const tcc_idx *ray_v, tcc_idx nrays, const tcc_ring *ring, tcc_idx *hit_tri, double *hit_t,
                 tcc_error *err)
{
    int filter = ring && ring->table;
    tcc_idx stack[128];
    double entry[128];
    for (tcc_idx g = 0; g < q; g++) {
        tcc_idx c = ub[g];
        if (c < 0 || c >= k)
            return tcc_fail(err, TCC_ERR_INDEX, "cluster %lld is not in [0, %lld)", (long long)c, (long long)k);
        if (seg[g] < 0 || seg[g + 1] < seg[g] || seg[g + 1] > nrays)
            return tcc_fail(err, TCC_ERR_INDEX, "cluster %lld's rays [%lld, %lld) are not within the %lld rays",
                            (long long)c, (long long)seg[g], (long long)seg[g + 1], (long long)nrays);
        tcc_idx s = ptr[c], n = ptr[c + 1] - ptr[c];
        if (s < 0 || n < 0 || s + n > ntris)
            return tcc_fail(err, TCC_ERR_INDEX, "cluster %lld spans [%lld, %lld), outside the %lld scene triangles",
                            (long long)c, (long long)s, (long long)(s + n), (long long)ntris);
        const tcc_idx *fi = first + 2 * s, *ct = count + 2 * s;
        const double *L = lo + 6 * s, *H = hi + 6 * s;
        for (tcc_idx r = seg[g]; r < seg[g + 1]; r++) {
            hit_tri[r] = -1;
            hit_t[r] = INFINITY;
            if (n == 0) continue;
            double oo[3] = {o[3 * r], o[3 * r + 1], o[3 * r + 2]}, dd[3] = {d[3 * r], d[3 * r + 1], d[3 * r + 2]};
            double inv[3] = {1.0 / dd[0], 1.0 / dd[1], 1.0 / dd[2]};
            double best = (double)dist[r];
            if (!(best >= 0.0)) continue; /* NaN or negative length: no ray */
            tcc_idx v = ray_v[r];
            if (filter && (v < 0 || v >= ring->rows))
                return tcc_fail(err, TCC_ERR_INDEX, "ray %lld: vertex %lld has no exclusion row (of %lld)",
                                (long long)r, (long long)v, (long long)ring->rows);
            /* nearer child first, each with its entry distance: a subtree that starts beyond the
             * nearest hit so far is skipped when it comes off the stack */
            int top = 0;
            double t_root = ray_box(oo, inv, best, L, H);
            if (ct[0] < 0)
                return tcc_fail(err, TCC_ERR_INDEX, "cluster %lld: its tree has no root", (long long)c);
            if (t_root != INFINITY) {
                stack[top] = 0;
                entry[top++] = t_root;
            }
            while (top > 0) {
                top--;
                tcc_idx node = stack[top];
                if (entry[top] > best) continue;
                if ((ct[node] == 0 && (fi[node] <= node + 1 || fi[node] > 2 * n - 2)) ||
                    (ct[node] > 0 && (fi[node] < 0 || fi[node] + ct[node] > n)))
                    return tcc_fail(err, TCC_ERR_INDEX, "cluster %lld: node %lld is not a node of its tree",
                                    (long long)c, (long long)node);
                if (ct[node] == 0) {
                    if (top + 2 > 128) return tcc_fail(err, TCC_ERR_VALUE, "cluster %lld: tree deeper than 128", (long long)c);
                    tcc_idx a = node + 1, b = fi[node];
                    if (ct[a] < 0 || ct[b] < 0)
                        return tcc_fail(err, TCC_ERR_INDEX, "cluster %lld: node %lld is not a node of its tree",
                                        (long long)c, (long long)node);
                    double ta = ray_box(oo, inv, best, L + 3 * a, H + 3 * a);
                    double tb = ray_box(oo, inv, best, L + 3 * b, H + 3 * b);
                    if (ta > tb) {
                        double t = ta;
                        ta = tb;
                        tb = t;
                        tcc_idx x = a;
                        a = b;
                        b = x;
                    }
                    if (tb != INFINITY) {
                        stack[top] = b;
                        entry[top++] = tb;
                    }
                    if (ta != INFINITY) {
                        stack[top] = a;
                        entry[top++] = ta;
                    }
                    continue;
                }
                for (tcc_idx i = fi[node]; i < fi[node] + ct[node]; i++) {
                    tcc_idx f = perm[s + i];
                    const tcc_idx *tv = m->tri + 3 * f;
                    double t, u, w;
                    if (!tcc_line_triangle(oo, dd, m->x + 3 * tv[0], m->x + 3 * tv[1], m->x + 3 * tv[2], &t, &u, &w))
                        continue;
                    if (!(t >= 0.0 && t <= best && u >= -BVH_EDGE && w >= -BVH_EDGE && u + w <= 1.0 + BVH_EDGE)) continue;
                    if (filter && excluded(ring, v, tv)) continue;
                    best = t;
                    hit_tri[r] = f;
                    hit_t[r] = t;
                }
            }
        }
    }
    return TCC_OK;
}
