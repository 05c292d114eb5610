/* contacts.c - from hits to contacts: refining Embree's candidates, merging them with the walked
 * tracks, classifying (inside a closed body / near or through a thin surface), and assembling the
 * contacts over all colliders. The rules are those of narrow.py's module docs; the numpy
 * reference is tests/collision_reference.py, which the tests compare this file against.
 *
 * Per vertex there are two ray slots (+n, -n). Of the hits of a slot the nearest along the line
 * wins; on a tie the walked track wins over a new hit, because it carries the side memory.
 */
#include "collide.h"
#include "vecmath.h"

#include <math.h>
#include <stdlib.h>

/* Unit normal of triangle f (zero if degenerate) and the signed distance of p to its plane. */
static double plane_distance(const tcc_mesh *m, tcc_idx f, const double p[3], double nrm[3])
{
    const tcc_idx *t = m->tri + 3 * f;
    const double *a = m->x + 3 * t[0];
    double e1[3], e2[3], r[3];
    sub3(m->x + 3 * t[1], a, e1);
    sub3(m->x + 3 * t[2], a, e2);
    cross3(e1, e2, nrm);
    double len = sqrt(dot3(nrm, nrm));
    double s = len > 0 ? len : 1.0;
    nrm[0] /= s;
    nrm[1] /= s;
    nrm[2] /= s;
    sub3(p, a, r);
    return dot3(r, nrm);
}

static int check_triangle(const tcc_mesh *m, tcc_idx f, tcc_error *err)
{
    if (f < 0 || f >= m->nt)
        return tcc_fail(err, TCC_ERR_INDEX, "triangle %lld is not in [0, %lld)", (long long)f, (long long)m->nt);
    for (int k = 0; k < 3; k++) {
        tcc_idx v = m->tri[3 * f + k];
        if (v < 0 || v >= m->nv)
            return tcc_fail(err, TCC_ERR_INDEX, "triangles[%lld, %d] = %lld is not a vertex index in [0, %lld)",
                            (long long)f, k, (long long)v, (long long)m->nv);
    }
    return TCC_OK;
}

int tcc_refine(const double *cloth_x, const double *normals, tcc_idx n, const tcc_idx *ray_v, const tcc_idx *ray_slot,
               const tcc_idx *hit_tri, tcc_idx r, const tcc_mesh *target, const tcc_ring *ring, int kind,
               double track_range, const uint8_t *inside_prev, tcc_idx *out_v, tcc_idx *out_slot, tcc_hits out,
               uint8_t *status, tcc_idx *count, tcc_error *err)
{
    tcc_idx m = 0;
    for (tcc_idx i = 0; i < r; i++) {
        if (hit_tri[i] < 0) continue;
        tcc_idx v = ray_v[i], slot = ray_slot[i];
        if (v < 0 || v >= n || (ring && ring->table && v >= ring->rows))
            return tcc_fail(err, TCC_ERR_INDEX, "ray %lld: vertex %lld is not in [0, %lld)", (long long)i,
                            (long long)v, (long long)n);
        if (slot != 0 && slot != 1)
            return tcc_fail(err, TCC_ERR_VALUE, "ray %lld: slot must be 0 (+n) or 1 (-n), got %lld", (long long)i,
                            (long long)slot);
        double sg = slot == 0 ? 1.0 : -1.0;
        const double *nv = normals + 3 * v;
        double d[3] = {nv[0] * sg, nv[1] * sg, nv[2] * sg};
        tcc_hit h;
        int rc = tcc_walk_one(target, cloth_x + 3 * v, d, v, hit_tri[i], ring, 4, &h, err);
        if (rc) return rc;
        /* only hits ahead of the ray count for a new hit (the scene was cast forward) */
        if (h.tri < 0 || !(h.t >= -2e-6)) continue;
        uint8_t st;
        int near = fabs(h.t) <= track_range;
        if (kind == TCC_VOLUME) {
            double nrm[3];
            double sd = plane_distance(target, h.tri, cloth_x + 3 * v, nrm);
            /* A back face beyond track_range proves "inside" only if nothing in front of it was
             * missed: trusted for a vertex inside at the previous step, else confirmed by the caller. */
            st = near ? 1 : (sd < 0 ? (inside_prev && inside_prev[v] ? 1 : 2) : 0);
        } else {
            st = near ? 1 : 0;
        }
        out_v[m] = v;
        out_slot[m] = slot;
        out.tri[m] = h.tri;
        out.t[m] = h.t;
        out.u[m] = h.u;
        out.v[m] = h.v;
        out.flips[m] = (uint8_t)h.flips;
        status[m] = st;
        m++;
    }
    *count = m;
    return TCC_OK;
}

typedef struct {
    tcc_idx key;
    double at;
    tcc_idx i;
} ranked;

static int by_key_then_at(const void *pa, const void *pb)
{
    const ranked *a = pa, *b = pb;
    if (a->key != b->key) return a->key < b->key ? -1 : 1;
    if (a->at != b->at) return a->at < b->at ? -1 : 1;
    return a->i < b->i ? -1 : (a->i > b->i);
}

static tcc_idx find_sorted(const tcc_idx *keys, tcc_idx k, tcc_idx key);

int tcc_drop_dominated(const tcc_idx *v, const tcc_idx *slot, const double *t, uint8_t *status, tcc_idx k,
                       const tcc_idx *track_key, tcc_idx kt, const tcc_idx *walked_tri, const double *walked_t,
                       tcc_idx *left, tcc_error *err)
{
    *left = 0;
    int any = 0;
    for (tcc_idx i = 0; i < k && !any; i++) any = status[i] == 2;
    if (!any) return TCC_OK;
    for (tcc_idx j = 1; j < kt; j++)
        if (track_key[j] <= track_key[j - 1])
            return tcc_fail(err, TCC_ERR_VALUE, "track keys must ascend (entry %lld)", (long long)j);
    ranked *rk = malloc(sizeof *rk * (size_t)k);
    if (!rk) return tcc_fail(err, TCC_ERR_NOMEM, "out of memory ranking %lld hits", (long long)k);
    for (tcc_idx i = 0; i < k; i++) {
        if (v[i] < 0 || (slot[i] != 0 && slot[i] != 1)) {
            free(rk);
            return tcc_fail(err, TCC_ERR_INDEX, "hit %lld: (vertex %lld, slot %lld) is not a ray", (long long)i,
                            (long long)v[i], (long long)slot[i]);
        }
        rk[i] = (ranked){2 * v[i] + slot[i], fabs(t[i]), i};
    }
    qsort(rk, (size_t)k, sizeof *rk, by_key_then_at);
    tcc_idx n2 = 0;
    for (tcc_idx a = 0; a < k;) {
        tcc_idx b = a;
        while (b < k && rk[b].key == rk[a].key) b++;
        double best = rk[a].at; /* the group's nearest */
        tcc_idx w = find_sorted(track_key, kt, rk[a].key);
        double walked = w >= 0 && walked_tri[w] >= 0 ? fabs(walked_t[w]) : INFINITY;
        for (tcc_idx q = a; q < b; q++) {
            tcc_idx i = rk[q].i;
            if (status[i] != 2) continue;
            if (best < rk[q].at || walked < rk[q].at)
                status[i] = 0;
            else
                n2++;
        }
        a = b;
    }
    free(rk);
    *left = n2;
    return TCC_OK;
}

/* Where the segment o + s d, s in [s0, s1], enters the box [l, h]; -1 if it misses. */
static int segment_enters(const double o[3], const double d[3], double s0, double s1, const double l[3],
                          const double h[3], double *enter)
{
    for (int a = 0; a < 3; a++) {
        if (!(l[a] <= h[a])) return 0; /* empty or NaN box */
        if (fabs(d[a]) < 1e-300) {
            if (o[a] < l[a] || o[a] > h[a]) return 0;
            continue;
        }
        double inv = 1.0 / d[a], ta = (l[a] - o[a]) * inv, tb = (h[a] - o[a]) * inv;
        if (ta > tb) {
            double sw = ta;
            ta = tb;
            tb = sw;
        }
        s0 = ta > s0 ? ta : s0;
        s1 = tb < s1 ? tb : s1;
        if (s0 > s1) return 0;
    }
    *enter = s0;
    return 1;
}

typedef struct {
    double enter;
    tcc_idx c;
} crossing;

int tcc_confirm_inside(const tcc_mesh *m, const tcc_idx *tri_order, tcc_idx ntri_order, const tcc_idx *tri_ptr,
                       tcc_idx k, const double *lo, const double *hi, const double *o, const double *d,
                       const double *t_exit, const tcc_idx *exit_tri, tcc_idx r, double backoff, double eps,
                       uint8_t *ok, tcc_error *err)
{
    for (tcc_idx c = 0; c < k; c++)
        if (tri_ptr[c] < 0 || tri_ptr[c + 1] < tri_ptr[c] || tri_ptr[c + 1] > ntri_order)
            return tcc_fail(err, TCC_ERR_INDEX, "cluster %lld's triangles span [%lld, %lld), outside the %lld listed",
                            (long long)c, (long long)tri_ptr[c], (long long)tri_ptr[c + 1], (long long)ntri_order);
    crossing *cr = malloc(sizeof *cr * (size_t)(k > 0 ? k : 1));
    if (!cr) return tcc_fail(err, TCC_ERR_NOMEM, "out of memory for %lld clusters", (long long)k);
    int rc = TCC_OK;
    for (tcc_idx i = 0; i < r; i++) {
        const double *oi = o + 3 * i, *di = d + 3 * i;
        double smax = t_exit[i] - eps;
        int blocked = 0;
        /* the clusters the segment crosses, nearest first: a blocking front face is usually in the
         * first one, so an outside vertex is settled after one cluster's triangles */
        tcc_idx nc = 0;
        for (tcc_idx c = 0; c < k && -backoff <= smax; c++) {
            double enter;
            if (!segment_enters(oi, di, -backoff, smax, lo + 3 * c, hi + 3 * c, &enter)) continue;
            tcc_idx q = nc++;
            while (q > 0 && cr[q - 1].enter > enter) {
                cr[q] = cr[q - 1];
                q--;
            }
            cr[q] = (crossing){enter, c};
        }
        for (tcc_idx j = 0; j < nc && !blocked; j++) {
            tcc_idx c = cr[j].c;
            for (tcc_idx q = tri_ptr[c]; q < tri_ptr[c + 1] && !blocked; q++) {
                tcc_idx f = tri_order[q];
                if (f == exit_tri[i]) continue;
                if ((rc = check_triangle(m, f, err))) goto done;
                const tcc_idx *tv = m->tri + 3 * f;
                double t, u, v;
                if (!tcc_line_triangle(oi, di, m->x + 3 * tv[0], m->x + 3 * tv[1], m->x + 3 * tv[2], &t, &u, &v))
                    continue;
                blocked = u >= 0 && v >= 0 && u + v <= 1 && t >= -backoff && t < smax;
            }
        }
        ok[i] = (uint8_t)!blocked;
    }
done:
    free(cr);
    return rc;
}

/* Side (+1 / -1 along the triangle normal) a vertex comes from, for a new track (narrow.initial_side):
 * the side before the crossing if the vertex went through the triangle during the last step
 * (relative motion, linear in time), else the current side. */
static double corner_plane(const double x[3], const double t[3][3])
{
    double e1[3], e2[3], nrm[3], r[3];
    sub3(t[1], t[0], e1);
    sub3(t[2], t[0], e2);
    cross3(e1, e2, nrm);
    double len = sqrt(dot3(nrm, nrm));
    double s = len > 1e-30 ? len : 1e-30;
    nrm[0] /= s;
    nrm[1] /= s;
    nrm[2] /= s;
    sub3(x, t[0], r);
    return dot3(r, nrm);
}

static double sgn(double x) { return x > 0 ? 1.0 : (x < 0 ? -1.0 : 0.0); }

static int8_t initial_side(const double xp[3], const double xn[3], const double tp[3][3], const double tn[3][3])
{
    double s_now = corner_plane(xn, tn), s_prev = corner_plane(xp, tp);
    int8_t side = s_now >= 0 ? 1 : -1;
    if (sgn(s_prev) * sgn(s_now) < 0) {
        double alpha = s_prev / (s_prev - s_now);
        double x[3], t[3][3];
        for (int a = 0; a < 3; a++) {
            x[a] = (1 - alpha) * xp[a] + alpha * xn[a];
            for (int k = 0; k < 3; k++) t[k][a] = (1 - alpha) * tp[k][a] + alpha * tn[k][a];
        }
        double e1[3], e2[3], ex[3];
        sub3(t[1], t[0], e1);
        sub3(t[2], t[0], e2);
        sub3(x, t[0], ex);
        double d11 = dot3(e1, e1), d12 = dot3(e1, e2), d22 = dot3(e2, e2), d1x = dot3(e1, ex), d2x = dot3(e2, ex);
        double den = d11 * d22 - d12 * d12;
        if (den < 1e-30) den = 1e-30; /* np.maximum(den, 1e-30); NaN stays NaN */
        double v = (d22 * d1x - d12 * d2x) / den, w = (d11 * d2x - d12 * d1x) / den;
        if (v >= -1e-6 && w >= -1e-6 && v + w <= 1 + 1e-6) side = s_prev >= 0 ? 1 : -1;
    }
    return side;
}

/* One merged hit of a (vertex, slot). */
typedef struct {
    tcc_idx key, tri;
    double t, u, v;
    int8_t side;
} entry;

/* Found hits in (key, |t|, arrival) order: the first of each key is its nearest (stable on ties). */
typedef struct {
    tcc_idx key;
    double at;
    tcc_idx i;
} order_item;

static int by_key_then_distance(const void *pa, const void *pb)
{
    const order_item *a = pa, *b = pb;
    if (a->key != b->key) return a->key < b->key ? -1 : 1;
    if (a->at != b->at) return a->at < b->at ? -1 : 1;
    return a->i < b->i ? -1 : (a->i > b->i);
}

/* Index of key in the sorted keys[0..k), or -1. */
static tcc_idx find_sorted(const tcc_idx *keys, tcc_idx k, tcc_idx key)
{
    tcc_idx lo = 0, hi = k;
    while (lo < hi) {
        tcc_idx mid = lo + (hi - lo) / 2;
        if (keys[mid] < key)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo < k && keys[lo] == key ? lo : -1;
}

int tcc_merge_classify(const tcc_merge_in *in, tcc_merge_out *out, tcc_error *err)
{
    const tcc_mesh *tg = in->target;
    tcc_idx n = in->n, kt = in->kt, kf = in->kf;
    out->ntracks = out->ninside = out->ncontacts = 0;
    for (tcc_idx i = 0; i < kt; i++) {
        tcc_idx key = in->track_key[i];
        if (key < 0 || key >= 2 * n || (i > 0 && key <= in->track_key[i - 1]))
            return tcc_fail(err, TCC_ERR_VALUE, "track keys must be ascending keys 2 * vertex + slot in [0, %lld) (entry %lld)",
                            (long long)(2 * n), (long long)i);
    }
    size_t need = (size_t)(kt + kf) * sizeof(entry) + (size_t)kf * sizeof(order_item) + 16;
    char *block = malloc(need);
    if (!block) return tcc_fail(err, TCC_ERR_NOMEM, "out of memory merging %lld hits", (long long)(kt + kf));
    entry *m = (entry *)block;
    order_item *ord = (order_item *)(m + kt + kf);
    int rc = TCC_OK;
    /* 1. new hits, nearest first per (vertex, slot) */
    tcc_idx no = 0;
    for (tcc_idx i = 0; i < kf; i++) {
        if (in->f_status && in->f_status[i] != 1) continue;
        tcc_idx v = in->f_v[i], s = in->f_slot[i];
        if (v < 0 || v >= n || (s != 0 && s != 1)) {
            rc = tcc_fail(err, TCC_ERR_INDEX, "new hit %lld: (vertex %lld, slot %lld) is not in [0, %lld) x {0, 1}",
                          (long long)i, (long long)v, (long long)s, (long long)n);
            goto done;
        }
        if ((rc = check_triangle(tg, in->f_hit.tri[i], err))) goto done;
        ord[no].key = 2 * v + s;
        ord[no].at = fabs(in->f_hit.t[i]);
        ord[no].i = i;
        no++;
    }
    if (no > 1) qsort(ord, (size_t)no, sizeof *ord, by_key_then_distance);
    /* 2. merge with the walked tracks (both in key order); a new hit replaces a walked one only
     * if strictly nearer: on a tie the walked track wins, it carries the side memory */
    tcc_idx nm = 0, a = 0, b = 0;
    while (a < kt || b < no) {
        /* next walked track that still hits */
        while (a < kt && in->walked.tri[a] < 0) a++;
        tcc_idx ka = a < kt ? in->track_key[a] : INT64_MAX;
        tcc_idx kb = b < no ? ord[b].key : INT64_MAX;
        if (ka == INT64_MAX && kb == INT64_MAX) break;
        entry e;
        int from_found = 0;
        if (ka <= kb) {
            tcc_idx f = in->walked.tri[a];
            if ((rc = check_triangle(tg, f, err))) goto done;
            int8_t mem = in->track_side[a];
            e = (entry){ka, f, in->walked.t[a], in->walked.u[a], in->walked.v[a],
                        in->walked.flips[a] ? (int8_t)-mem : mem};
            if (ka == kb && fabs(in->f_hit.t[ord[b].i]) < fabs(e.t)) from_found = 1;
            a++;
        } else {
            from_found = 1;
        }
        if (from_found) {
            tcc_idx i = ord[b].i, key = ord[b].key, v = key / 2;
            tcc_idx f = in->f_hit.tri[i];
            /* a new hit on a triangle this vertex already tracked (either slot) keeps its memory */
            int8_t mem = 0;
            for (int k = 0; k < 2; k++) {
                tcc_idx j = find_sorted(in->track_key, kt, 2 * v + k);
                if (j >= 0 && in->track_tri[j] == f) mem = in->track_side[j];
            }
            e = (entry){key, f, in->f_hit.t[i], in->f_hit.u[i], in->f_hit.v[i], mem};
        }
        if (kb <= ka) {
            /* skip every other new hit of this key */
            tcc_idx key = kb;
            while (b < no && ord[b].key == key) b++;
        }
        m[nm++] = e;
    }
    /* 3. classify per vertex (slots 0 and 1 are adjacent in key order); write tracks, contacts */
    double th = in->thickness, tr = in->track_range;
    int volume = in->kind == TCC_VOLUME;
    for (tcc_idx i = 0; i < nm;) {
        tcc_idx v = m[i].key / 2;
        entry *es[2] = {NULL, NULL};
        while (i < nm && m[i].key / 2 == v) {
            es[m[i].key % 2] = &m[i];
            i++;
        }
        double t0 = es[0] ? es[0]->t : INFINITY, t1 = es[1] ? es[1]->t : INFINITY;
        int near_slot = fabs(t1) < fabs(t0) ? 1 : 0;
        double dep[2] = {-INFINITY, -INFINITY}, nrms[2][3];
        int inside = 0;
        for (int s = 0; s < 2; s++) {
            entry *e = es[s];
            if (!e) continue;
            double nrm[3];
            double sd = plane_distance(tg, e->tri, in->x + 3 * v, nrm);
            double depth, sign = 1.0;
            int contact, keep;
            int8_t aside;
            if (volume) {
                /* only the nearest hit along the normal line decides inside / outside */
                int nearest = s == near_slot;
                if (nearest && sd < 0) inside = 1;
                depth = th - sd; /* inside: |sd| + thickness; outside: thickness - distance */
                contact = nearest && depth > 0;
                keep = fabs(e->t) <= tr || sd < 0;
                aside = 1;
            } else {
                aside = e->side;
                if (aside == 0) {
                    if (in->first) {
                        aside = sd >= 0 ? 1 : -1;
                    } else {
                        const tcc_idx *tv = tg->tri + 3 * e->tri;
                        double tp[3][3], tn[3][3];
                        for (int c = 0; c < 3; c++)
                            for (int q = 0; q < 3; q++) {
                                tp[c][q] = in->target_prev[3 * tv[c] + q];
                                tn[c][q] = tg->x[3 * tv[c] + q];
                            }
                        aside = initial_side(in->x_prev + 3 * v, in->x + 3 * v, tp, tn);
                    }
                }
                int inverted = (sd >= 0 ? 1 : -1) != aside;
                double dist = fabs(sd);
                depth = inverted ? th + dist : th - dist;
                contact = depth > 0;
                sign = (double)aside;
                if (in->kind == TCC_SELF) {
                    /* layer over layer only: a triangle standing edge-on to this vertex's surface (a
                     * fold, a torn rim) would pin the membrane in-plane (narrow.py, detector.py) */
                    contact = contact && fabs(dot3(nrm, in->normals + 3 * v)) >= 0.5;
                }
                keep = fabs(e->t) <= tr || (inverted && dist <= tr + th);
                /* both slots on one triangle would double the memory: keep slot 0 only */
                if (s == 1 && es[0] && es[0]->tri == e->tri && fabs(t0) <= tr) keep = 0;
            }
            if (keep) {
                tcc_idx j = out->ntracks++;
                out->track_key[j] = e->key;
                out->track_tri[j] = e->tri;
                out->track_side[j] = aside;
            }
            if (contact) {
                dep[s] = depth;
                for (int q = 0; q < 3; q++) nrms[s][q] = nrm[q] * sign;
            }
        }
        if (inside) out->inside[out->ninside++] = v;
        int bs = dep[1] > dep[0] ? 1 : 0;
        if (!isfinite(dep[bs])) continue;
        entry *e = es[bs];
        tcc_idx j = out->ncontacts++;
        out->contact_v[j] = v;
        out->depth[j] = dep[bs];
        double *on = out->normal + 3 * j, *ov = out->velocity + 3 * j;
        on[0] = nrms[bs][0];
        on[1] = nrms[bs][1];
        on[2] = nrms[bs][2];
        /* hits are found on lines, so (u, v) can fall outside the triangle: the surface velocity
         * is an interpolation, never an extrapolation */
        double ur = e->u, vr = e->v;
        ur = ur < 0 ? 0 : (ur > 1 ? 1 : ur);
        vr = vr < 0 ? 0 : (vr > 1 ? 1 : vr);
        if (ur + vr > 1.0) {
            double sc = 1.0 / (ur + vr > 1e-300 ? ur + vr : 1e-300);
            ur *= sc;
            vr *= sc;
        }
        const tcc_idx *tv = tg->tri + 3 * e->tri;
        const double *V = in->target_velocity;
        for (int q = 0; q < 3; q++) {
            double vel = V ? (1.0 - ur - vr) * V[3 * tv[0] + q] + ur * V[3 * tv[1] + q] + vr * V[3 * tv[2] + q] : 0.0;
            if (in->kind == TCC_SELF) {
                /* two layers meeting: an inelastic collision of similar masses ends at their mean velocity */
                vel = 0.5 * (vel + (in->velocity ? in->velocity[3 * v + q] : 0.0));
            }
            ov[q] = vel;
        }
    }
done:
    free(block);
    return rc;
}

int tcc_assemble(const tcc_idx *seg, tcc_idx c, const tcc_idx *v, const double *depth, const double *normal,
                 const double *velocity, const double *friction, tcc_idx n, int32_t *deep_v, double *deep_normal,
                 double *deep_depth, double *deep_velocity, double *deep_friction, tcc_idx *ndeep, int32_t *all_v,
                 double *all_normal, double *all_depth, double *all_velocity, double *all_friction, tcc_idx *nall,
                 tcc_error *err)
{
    enum { MAXC = 64 };
    if (c > MAXC) return tcc_fail(err, TCC_ERR_VALUE, "at most %d colliders, got %lld", MAXC, (long long)c);
    tcc_idx head[MAXC];
    for (tcc_idx j = 0; j < c; j++) {
        if (seg[j] < 0 || seg[j + 1] < seg[j] || seg[j + 1] > seg[c])
            return tcc_fail(err, TCC_ERR_VALUE, "collider %lld's contacts span [%lld, %lld): not within [0, %lld)",
                            (long long)j, (long long)seg[j], (long long)seg[j + 1], (long long)seg[c]);
        head[j] = seg[j];
        for (tcc_idx i = seg[j]; i < seg[j + 1]; i++)
            if (v[i] < 0 || v[i] >= n || (i > seg[j] && v[i] <= v[i - 1]))
                return tcc_fail(err, TCC_ERR_VALUE, "collider %lld's contact vertices must ascend within [0, %lld) (entry %lld)",
                                (long long)j, (long long)n, (long long)i);
    }
    tcc_idx kd = 0, ka = 0;
    for (;;) {
        tcc_idx vmin = INT64_MAX;
        for (tcc_idx j = 0; j < c; j++)
            if (head[j] < seg[j + 1] && v[head[j]] < vmin) vmin = v[head[j]];
        if (vmin == INT64_MAX) break;
        tcc_idx best = -1;
        for (tcc_idx j = 0; j < c; j++) {
            if (head[j] >= seg[j + 1] || v[head[j]] != vmin) continue;
            tcc_idx i = head[j]++;
            if (!(depth[i] > 0)) continue;
            if (best < 0 || depth[i] > depth[best]) best = i;
            all_v[ka] = (int32_t)vmin;
            all_depth[ka] = depth[i];
            all_friction[ka] = friction[j];
            for (int q = 0; q < 3; q++) {
                all_normal[3 * ka + q] = normal[3 * i + q];
                all_velocity[3 * ka + q] = velocity[3 * i + q];
            }
            ka++;
            if (best == i) deep_friction[kd] = friction[j];
        }
        if (best < 0) continue;
        deep_v[kd] = (int32_t)vmin;
        deep_depth[kd] = depth[best];
        for (int q = 0; q < 3; q++) {
            deep_normal[3 * kd + q] = normal[3 * best + q];
            deep_velocity[3 * kd + q] = velocity[3 * best + q];
        }
        kd++;
    }
    *ndeep = kd;
    *nall = ka;
    return TCC_OK;
}
