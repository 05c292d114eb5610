/* walk.c - incremental ray detection: follow a ray's hit from one step to the next over the
 * triangle adjacency (Lehericey et al. 2013), the exact arithmetic of incremental.walk.
 *
 * Each ray re-tests the triangle it hit last and steps across the edge opposite the corner with
 * the most negative barycentric coordinate, a handful of steps at most while the pair moves less
 * than the displacement threshold. Rays are lines: t may be negative, so a vertex that crossed
 * the surface still finds the same triangle behind it (inversion handling and the inside test
 * need exactly that). Self-collision never accepts a triangle of the vertex's two-ring; the walk
 * is lost there instead.
 */
#include "collide.h"
#include "vecmath.h"

#include <math.h>

#define BARY_EPS 1e-9 /* a hit on a shared edge is not bounced back and forth */

static const int EDGE_OPPOSITE[3] = {1, 2, 0}; /* corner k -> edge opposite it */

int tcc_walk_one(const tcc_mesh *m, const double o[3], const double d[3], tcc_idx v, tcc_idx start,
                 const tcc_ring *ring, int max_steps, tcc_hit *h, tcc_error *err)
{
    h->tri = -1;
    h->t = INFINITY;
    h->u = h->v = 0.0;
    h->flips = 0;
    tcc_idx cur = start;
    int flips = 0;
    for (int step = 0; cur >= 0; step++) {
        if (cur >= m->nt)
            return tcc_fail(err, TCC_ERR_INDEX, "triangle %lld is not in [0, %lld)", (long long)cur, (long long)m->nt);
        const tcc_idx *tv = m->tri + 3 * cur;
        for (int k = 0; k < 3; k++)
            if (tv[k] < 0 || tv[k] >= m->nv)
                return tcc_fail(err, TCC_ERR_INDEX, "triangles[%lld, %d] = %lld is not a vertex index in [0, %lld)",
                                (long long)cur, k, (long long)tv[k], (long long)m->nv);
        double t, u, w1;
        int ok = tcc_line_triangle(o, d, m->x + 3 * tv[0], m->x + 3 * tv[1], m->x + 3 * tv[2], &t, &u, &w1);
        double b[3] = {1.0 - u - w1, u, w1};
        int kmin = 0;
        if (b[1] < b[kmin]) kmin = 1;
        if (b[2] < b[kmin]) kmin = 2;
        int inside = ok && b[kmin] >= -BARY_EPS;
        if (ring && ring->table && tcc_ring_excludes(ring, v, tv)) ok = inside = 0;
        if (inside) {
            h->tri = cur;
            h->t = t;
            h->u = u;
            h->v = w1;
            h->flips = flips;
            return TCC_OK;
        }
        if (!ok || step == max_steps) return TCC_OK;
        int e = EDGE_OPPOSITE[kmin];
        if (!m->adj || !m->flip)
            return tcc_fail(err, TCC_ERR_VALUE, "a walk needs the triangle adjacency");
        tcc_idx nxt = m->adj[3 * cur + e];
        if (nxt < -1 || nxt >= m->nt)
            return tcc_fail(err, TCC_ERR_INDEX, "adjacency[%lld, %d] = %lld is not a triangle index (or -1)",
                            (long long)cur, e, (long long)nxt);
        flips ^= m->flip[3 * cur + e] != 0;
        cur = nxt;
    }
    return TCC_OK;
}

int tcc_walk(const double *cloth_x, const double *normals, tcc_idx n, const tcc_idx *ray_v,
             const tcc_idx *ray_slot, const tcc_idx *start, tcc_idx k, const tcc_mesh *target,
             const tcc_ring *ring, int max_steps, tcc_hits out, tcc_error *err)
{
    for (tcc_idx i = 0; i < k; i++) {
        tcc_idx v = ray_v[i], s = ray_slot[i];
        if (v < 0 || v >= n || (ring && ring->table && v >= ring->rows))
            return tcc_fail(err, TCC_ERR_INDEX, "ray %lld: vertex %lld is not in [0, %lld)", (long long)i,
                            (long long)v, (long long)n);
        if (s != 0 && s != 1)
            return tcc_fail(err, TCC_ERR_VALUE, "ray %lld: slot must be 0 (+n) or 1 (-n), got %lld", (long long)i,
                            (long long)s);
        if (start[i] < -1)
            return tcc_fail(err, TCC_ERR_INDEX, "ray %lld: start triangle %lld is not a triangle index (or -1)",
                            (long long)i, (long long)start[i]);
        double sg = s == 0 ? 1.0 : -1.0;
        const double *nv = normals + 3 * v;
        double d[3] = {nv[0] * sg, nv[1] * sg, nv[2] * sg};
        tcc_hit h;
        int rc = tcc_walk_one(target, cloth_x + 3 * v, d, v, start[i], ring, max_steps, &h, err);
        if (rc) return rc;
        out.tri[i] = h.tri;
        out.t[i] = h.t;
        out.u[i] = h.u;
        out.v[i] = h.v;
        out.flips[i] = (uint8_t)h.flips;
    }
    return TCC_OK;
}
