/* rays.c - the rays of full detection, prepared for and taken back from Embree (embreex).
 *
 * Full detection casts, for a collider cluster b, the rays of every cloth cluster paired with b in
 * one Embree call into b's scene. The scene is kept in the pose it was built in (geometry.c's
 * rigid fit), so the rays are moved into that pose here, in float32 as Embree wants them. A ray
 * whose segment cannot reach b's box (the box is inflated by more than the scene's staleness
 * tolerance) is not cast at all: in a close pair most of a cluster's rays point away from, or stop
 * short of, the other cluster, and a slab test costs a few nanoseconds against a few hundred for
 * an Embree call per ray.
 *
 * embreex has no hit filter, so self-collision skips the vertex's own two-ring after the fact:
 * such a hit advances the ray just past it and the ray is cast again (tcc_accept_hits).
 */
#include "collide.h"
#include "vecmath.h"

#include <math.h>

int tcc_segment_box(const double o[3], const double d[3], double len, const double lo[3], const double hi[3])
{
    double inv[3], box[6];
    for (int a = 0; a < 3; a++) {
        inv[a] = fabs(d[a]) < 1e-300 ? INFINITY : 1.0 / d[a];
        box[a] = lo[a];
        box[3 + a] = hi[a];
    }
    return tcc_box_entry(o, inv, len, box) < INFINITY;
}

int tcc_pair_span(const tcc_ray_setup *s, tcc_idx p, tcc_idx a, tcc_idx b, tcc_idx *st, tcc_idx *en, tcc_error *err)
{
    if (a < 0 || a >= s->kc)
        return tcc_fail(err, TCC_ERR_INDEX, "pair %lld: cloth cluster %lld is not in [0, %lld)", (long long)p,
                        (long long)a, (long long)s->kc);
    if (b < 0 || b >= s->kb)
        return tcc_fail(err, TCC_ERR_INDEX, "pair %lld: collider cluster %lld is not in [0, %lld)", (long long)p,
                        (long long)b, (long long)s->kb);
    *st = s->ptr[a];
    *en = s->ptr[a + 1];
    if (*st < 0 || *en < *st || *en > s->norder)
        return tcc_fail(err, TCC_ERR_INDEX, "cloth cluster %lld spans [%lld, %lld), outside the %lld members",
                        (long long)a, (long long)*st, (long long)*en, (long long)s->norder);
    return TCC_OK;
}

int tcc_member_ray(const tcc_ray_setup *s, tcc_idx i, int slot, const double *lo, const double *hi, tcc_idx *v,
                   double ow[3], double dw[3], double *len, tcc_error *err)
{
    tcc_idx u = s->order[i];
    if (u < 0 || u >= s->n)
        return tcc_fail(err, TCC_ERR_INDEX, "order[%lld] = %lld is not a vertex index in [0, %lld)", (long long)i,
                        (long long)u, (long long)s->n);
    *v = u;
    if (!s->has_normal[u]) return 0;
    *len = (s->long_mask && s->long_mask[u] ? s->long_dist : s->short_dist) + s->backoff + s->tol;
    double sg = slot == 0 ? 1.0 : -1.0;
    const double *nv = s->normals + 3 * u, *xv = s->x + 3 * u;
    for (int c = 0; c < 3; c++) {
        dw[c] = nv[c] * sg;
        ow[c] = xv[c] - s->backoff * dw[c];
    }
    if (!(isfinite(ow[0]) && isfinite(ow[1]) && isfinite(ow[2]))) return 0;
    return tcc_segment_box(ow, dw, *len, lo, hi);
}

int tcc_prepare_rays(const tcc_ray_setup *s, const tcc_idx *pair_a, const tcc_idx *pair_b, tcc_idx np,
                     const tcc_idx *ub, const double *R, const double *centre, const double *ref_centre,
                     tcc_idx q, float *o, float *d, float *dist, tcc_idx *ray_v, tcc_idx *ray_slot, tcc_idx cap,
                     tcc_idx *seg, tcc_idx *count, tcc_error *err)
{
    tcc_idx m = 0, g = -1;
    for (tcc_idx p = 0; p < np; p++) {
        tcc_idx a = pair_a[p], b = pair_b[p], st, en;
        int rc = tcc_pair_span(s, p, a, b, &st, &en, err);
        if (rc) return rc;
        if (g < 0 || b != ub[g]) {
            /* next group: pairs are sorted by b and ub lists each b once, in that order */
            g++;
            if (g >= q || ub[g] != b)
                return tcc_fail(err, TCC_ERR_VALUE,
                                "pairs must be sorted by collider cluster, and clusters must list each of them once "
                                "in that order (pair %lld, cluster %lld)", (long long)p, (long long)b);
            seg[g] = m;
        }
        const double *Rg = R + 9 * b, *cg = centre + 3 * b, *rg = ref_centre + 3 * b;
        const double *lo = s->box_lo + 3 * b, *hi = s->box_hi + 3 * b;
        for (tcc_idx i = st; i < en; i++) {
            for (int slot = 0; slot < 2; slot++) {
                tcc_idx v;
                double ow[3], dw[3], len;
                int cast = tcc_member_ray(s, i, slot, lo, hi, &v, ow, dw, &len, err);
                if (cast < 0) return cast;
                if (!cast) continue;
                if (m < cap) {
                    /* world -> build frame: x0 = R^T (x - centre) + ref_centre */
                    double r[3] = {ow[0] - cg[0], ow[1] - cg[1], ow[2] - cg[2]};
                    for (int c = 0; c < 3; c++) {
                        o[3 * m + c] = (float)(r[0] * Rg[c] + r[1] * Rg[3 + c] + r[2] * Rg[6 + c] + rg[c]);
                        d[3 * m + c] = (float)(dw[0] * Rg[c] + dw[1] * Rg[3 + c] + dw[2] * Rg[6 + c]);
                    }
                    dist[m] = (float)len;
                    ray_v[m] = v;
                    ray_slot[m] = slot;
                }
                m++;
            }
        }
    }
    if (g + 1 != q)
        return tcc_fail(err, TCC_ERR_VALUE, "%lld clusters listed but the pairs name %lld", (long long)q,
                        (long long)(g + 1));
    seg[q] = m;
    *count = m;
    return TCC_OK;
}

int tcc_accept_hits(const tcc_idx *rays, const int32_t *prim, const float *tfar, tcc_idx r, const tcc_idx *scene_tris,
                    tcc_idx nscene, const tcc_idx *ray_v, tcc_idx nrays, const tcc_mesh *target, const tcc_ring *ring,
                    float *o, const float *d, float *dist, tcc_idx *hit_tri, tcc_idx *retry, tcc_idx *nretry,
                    tcc_error *err)
{
    tcc_idx k = 0;
    int filter = ring && ring->table;
    if (filter && !tfar) return tcc_fail(err, TCC_ERR_VALUE, "skipping excluded hits needs the hit distances (tfar)");
    for (tcc_idx i = 0; i < r; i++) {
        tcc_idx ray = rays[i];
        if (ray < 0 || ray >= nrays)
            return tcc_fail(err, TCC_ERR_INDEX, "ray index %lld is not in [0, %lld)", (long long)ray, (long long)nrays);
        int32_t p = prim[i];
        hit_tri[ray] = -1;
        if (p < 0) continue;
        if (p >= nscene)
            return tcc_fail(err, TCC_ERR_INDEX, "Embree returned primitive %d of a scene of %lld triangles", (int)p,
                            (long long)nscene);
        tcc_idx f = scene_tris[p];
        if (f < 0 || f >= target->nt)
            return tcc_fail(err, TCC_ERR_INDEX, "scene triangle %lld is not in [0, %lld)", (long long)f,
                            (long long)target->nt);
        if (filter) {
            tcc_idx v = ray_v[ray];
            if (v < 0 || v >= ring->rows)
                return tcc_fail(err, TCC_ERR_INDEX, "ray %lld: vertex %lld has no exclusion row (of %lld)",
                                (long long)ray, (long long)v, (long long)ring->rows);
            const tcc_idx *tv = target->tri + 3 * f, *row = ring->table + v * ring->width;
            int own = 0;
            for (tcc_idx w = 0; w < ring->width && !own; w++)
                own = row[w] >= 0 && (tv[0] == row[w] || tv[1] == row[w] || tv[2] == row[w]);
            if (own) {
                /* float32 scene: step past the excluded triangle by ~1 ulp at 1 m */
                double step = (double)tfar[i] + 1e-7;
                for (int c = 0; c < 3; c++) o[3 * ray + c] = (float)((double)o[3 * ray + c] + step * (double)d[3 * ray + c]);
                dist[ray] = (float)((double)dist[ray] - step);
                if (dist[ray] > 0 && retry) retry[k++] = ray;
                continue;
            }
        }
        hit_tri[ray] = f;
    }
    if (nretry) *nretry = k;
    return TCC_OK;
}
