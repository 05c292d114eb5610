/* detect.c - a detector step of one collider in one call: the measure's close pairs, the walk of the
 * tracked rays, full detection of the pairs that need it, refinement, and the merge into tracks and
 * contacts (collision/detector.py's module docs give the method; the kernels it calls are the ones
 * the tests compare against their numpy specifications).
 *
 * Why one call: what was left of a step's cost after the kernels went native was orchestration -
 * numpy and Python per pair group, per plan, per stage (a full detection of every pair of the
 * shirt on the walking mannequin cost ~5.6 us per cloth vertex where a ray costs well under one).
 * Here a collider's step reads its arrays once and allocates a few scratch blocks.
 *
 * Full detection casts, for every close pair (a cloth cluster, b collider cluster) marked full, the
 * rays of a's vertices (+n and -n) that reach b's box into b's tree (bvh.c: the collider's clusters,
 * each over its own triangles and their edge neighbours, refitted the first time a step casts into
 * it). A cloth vertex usually meets several clusters b; all its hits go to the merge, which keeps
 * per ray the nearest, as tcc_merge_classify documents. Bodies use the same native trees as the
 * cloth (bvh.c's module docs say why).
 *
 * With a clearance array, full detection also measures per pair how far its cloth vertices' lines are
 * clear beyond the track range (the nearest untracked hit; the cloth's own and a thin surface's lines
 * searched to probe_length for it, their tracks still only within ray_length): the relative measure's
 * clearance credit (collision/detector.py's module docs, "Clearance").
 *
 * The cloth's normals are computed per vertex when the step first needs them (the vertices of
 * tracked rays and of the cast clusters): `done` marks those computed, shared by the step's calls.
 */
#include "collide.h"
#include "vecmath.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

/* Seconds on a wall clock, for the phases' times in the stats (C11). */
static double now_s(void)
{
    struct timespec ts;
    if (timespec_get(&ts, TIME_UTC) != TIME_UTC) return 0.0;
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* a growing list of (vertex, slot, triangle) */
typedef struct {
    tcc_idx *v, *slot, *tri, n, cap;
} hit_list;

static int hits_push(hit_list *l, tcc_idx v, tcc_idx slot, tcc_idx tri, tcc_error *err)
{
    if (l->n == l->cap) {
        tcc_idx cap = l->cap ? 2 * l->cap : 1024;
        tcc_idx *a = realloc(l->v, sizeof(tcc_idx) * (size_t)cap);
        if (!a) return tcc_fail(err, TCC_ERR_NOMEM, "no memory for %lld hits", (long long)cap);
        l->v = a;
        a = realloc(l->slot, sizeof(tcc_idx) * (size_t)cap);
        if (!a) return tcc_fail(err, TCC_ERR_NOMEM, "no memory for %lld hits", (long long)cap);
        l->slot = a;
        a = realloc(l->tri, sizeof(tcc_idx) * (size_t)cap);
        if (!a) return tcc_fail(err, TCC_ERR_NOMEM, "no memory for %lld hits", (long long)cap);
        l->tri = a;
        l->cap = cap;
    }
    l->v[l->n] = v;
    l->slot[l->n] = slot;
    l->tri[l->n] = tri;
    l->n++;
    return TCC_OK;
}

static void hits_free(hit_list *l)
{
    free(l->v);
    free(l->slot);
    free(l->tri);
}

/* The cloth's normal of vertex v, if this step has not computed it yet: summed from its incident
 * triangles in vt_tri's order by tcc_vertex_normal, as tcc_cluster_normals does. A step needs the
 * normals of the vertices it walks or casts rays from, often a few hundred of thousands. */
static int need_normal(const tcc_detect_in *in, tcc_idx v, tcc_error *err)
{
    if (in->done[v]) return TCC_OK;
    tcc_mesh m = {in->x, in->n, in->tri, in->nt, NULL, NULL};
    int rc = tcc_vertex_normal(&m, in->vt_ptr, in->vt_tri, in->nvt, v, in->normals, in->has_normal, err);
    if (rc) return rc;
    in->done[v] = 1;
    return TCC_OK;
}

/* Index of key in the ascending keys (i << 32 | j) of the close pairs, or -1. */
static tcc_idx pair_index(const tcc_detect_in *in, tcc_idx key)
{
    tcc_idx lo = 0, hi = in->np;
    while (lo < hi) {
        tcc_idx mid = lo + (hi - lo) / 2;
        tcc_idx k = (in->pi[mid] << 32) | in->pj[mid];
        if (k < key) lo = mid + 1;
        else hi = mid;
    }
    return lo < in->np && ((in->pi[lo] << 32) | in->pj[lo]) == key ? lo : -1;
}

typedef struct {
    tcc_idx b, p, a;
} pair_ref;

static int by_cloth_cluster(const void *x, const void *y)
{
    const pair_ref *u = x, *w = y;
    if (u->a != w->a) return u->a < w->a ? -1 : 1;
    return u->b < w->b ? -1 : (u->b > w->b);
}

/* Cluster c's tree ready for unchecked reads this call: refitted from the current positions the first
 * time this step (the refit checks its nodes), else checked. */
static int tree_ready(tcc_detect_in *in, tcc_idx c, uint8_t *ready, tcc_error *err)
{
    if (ready[c]) return TCC_OK;
    int rc;
    if (in->refit_step[c] != in->step) {
        if ((rc = tcc_bvh_refit(&in->target, &in->bvh, c, err))) return rc;
        in->refit_step[c] = in->step;
    } else if ((rc = tcc_bvh_check(&in->target, &in->bvh, c, err))) {
        return rc;
    }
    ready[c] = 1;
    return TCC_OK;
}

/* The full detection of cloth cluster a against collider clusters b[0..nb): per vertex both rays in one
 * traversal of each cluster's tree whose box they reach (bvh.c tcc_bvh_line). For all but a closed
 * body's vertices that were inside it, each ray keeps only its nearest hit over the clusters - the
 * merge keeps no other (a nearer hit of a ray beats it, and a far one beyond the track range is no
 * contact either), so each later cluster is searched only nearer than that. A vertex that was inside
 * keeps every cluster's hit: there a far back face counts without confirmation (tcc_refine), and a
 * nearer front face beyond the track range would not stand in for it. */
/* With in->clearance, each pair pairs[q] (of b[q]) takes the minimum over a's vertices of how far their
 * lines are clear (tcc_detect_in.clearance): the lines are searched to len, and a ray's nearest hit
 * counts only beyond track_range (within it the ray is tracked); keep reports which hits become
 * tracks' candidates: those within keep (a thin surface or the cloth: ray_length, whatever len). */
static int cast_cluster(tcc_detect_in *in, const tcc_ring *ring, tcc_idx a, const tcc_idx *b, const tcc_idx *pairs,
                        tcc_idx nb, double len, double keep, const uint8_t *trusted, uint8_t *ready, hit_list *hits,
                        tcc_idx *rays, tcc_error *err)
{
    int rc = TCC_OK;
    if (a < 0 || a >= in->kc)
        return tcc_fail(err, TCC_ERR_INDEX, "cloth cluster %lld is not in [0, %lld)", (long long)a, (long long)in->kc);
    for (tcc_idx q = 0; q < nb; q++)
        if (b[q] < 0 || b[q] >= in->kb)
            return tcc_fail(err, TCC_ERR_INDEX, "collider cluster %lld is not in [0, %lld)", (long long)b[q],
                            (long long)in->kb);
    const double bo = in->backoff;
    /* per vertex, the clusters its line meets, nearest first (a near hit then shortens the rest) */
    struct near_cluster {
        double gap;
        tcc_idx c;
    } *near = malloc(sizeof *near * (size_t)(nb > 0 ? nb : 1));
    if (!near) return tcc_fail(err, TCC_ERR_NOMEM, "no memory for %lld clusters", (long long)nb);
    for (tcc_idx i = in->ptr[a]; i < in->ptr[a + 1] && rc == TCC_OK; i++) {
        tcc_idx v = in->order[i];
        if ((rc = need_normal(in, v, err))) break;
        const double *x = in->x + 3 * v, *d = in->normals + 3 * v;
        if (!in->has_normal[v] || !(isfinite(x[0]) && isfinite(x[1]) && isfinite(x[2]))) {
            /* no line to search: this vertex is judged by the paper's margin alone */
            if (in->clearance)
                for (tcc_idx q = 0; q < nb; q++) in->clearance[pairs[q]] = fmin(in->clearance[pairs[q]], in->track_range);
            continue;
        }
        double inv[3];
        for (int c = 0; c < 3; c++) inv[c] = fabs(d[c]) < 1e-300 ? INFINITY : 1.0 / d[c];
        int keep_all = trusted && trusted[v];
        tcc_idx nn = 0;
        for (tcc_idx q = 0; q < nb; q++) {
            const double *lo = in->box_lo + 3 * b[q], *hi = in->box_hi + 3 * b[q];
            double bx[6] = {lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]}, t0, t1;
            if (!tcc_line_box(x, inv, -len, len, bx, &t0, &t1)) continue;
            double g = t0 > 0 ? t0 : (t1 < 0 ? -t1 : 0.0);
            tcc_idx k = nn++;
            while (k > 0 && near[k - 1].gap > g) {
                near[k] = near[k - 1];
                k--;
            }
            near[k] = (struct near_cluster){g, b[q]};
        }
        double s0 = len, s1 = -len; /* slot 0: s in [-bo, s0], slot 1: s in [s1, bo] (the nearest so far) */
        tcc_idx tri[2] = {-1, -1};
        for (tcc_idx q = 0; q < nn; q++) {
            tcc_idx c = near[q].c;
            const double *lo = in->box_lo + 3 * c, *hi = in->box_hi + 3 * c;
            double bx[6] = {lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]}, t0, t1;
            double w0 = keep_all ? len : s0, w1 = keep_all ? -len : s1;
            /* each ray against the cluster's box, as far as a nearer hit has not settled it */
            int active = (tcc_line_box(x, inv, -bo, w0, bx, &t0, &t1) ? 1 : 0) |
                         (tcc_line_box(x, inv, w1, bo, bx, &t0, &t1) ? 2 : 0);
            if (!active) continue;
            if ((rc = tree_ready(in, c, ready, err))) break;
            *rays += (active & 1) + (active >> 1);
            if (keep_all) {
                tcc_idx own[2] = {-1, -1};
                tcc_bvh_line(&in->target, &in->bvh, c, x, d, active, bo, &w0, &w1, ring, v, own);
                for (int k = 0; k < 2 && rc == TCC_OK; k++)
                    if (own[k] >= 0) rc = hits_push(hits, v, k, own[k], err);
                if (rc) break;
            } else {
                tcc_bvh_line(&in->target, &in->bvh, c, x, d, active, bo, &s0, &s1, ring, v, tri);
            }
        }
        double dist[2] = {s0, -s1}; /* each ray's nearest hit, or len */
        for (int k = 0; k < 2 && !keep_all && rc == TCC_OK; k++)
            if (tri[k] >= 0 && dist[k] <= keep) rc = hits_push(hits, v, k, tri[k], err);
        if (in->clearance && rc == TCC_OK) {
            /* a hit within track_range is tracked (the walks follow it); an inside vertex is trusted
             * to its tracks: both count as the paper's margin, no more */
            double c = keep_all ? in->track_range : len;
            for (int k = 0; k < 2 && !keep_all; k++)
                if (tri[k] >= 0) c = fmin(c, fmax(dist[k], in->track_range));
            for (tcc_idx q = 0; q < nb; q++) in->clearance[pairs[q]] = fmin(in->clearance[pairs[q]], c);
        }
    }
    free(near);
    return rc;
}

typedef struct {
    double enter;
    tcc_idx c;
} crossing;

/* The inside confirmation of the far back-face hits (status 2 -> 1 or 0): the segment from the
 * vertex (less the backoff) to 1e-6 short of the exit is tested against the triangles of every
 * collider cluster whose box it crosses, nearest first, until one blocks it - tcc_confirm_inside's
 * test, from the trees. */
static int confirm_inside(tcc_detect_in *in, const tcc_idx *hv, const tcc_idx *hs, const double *ht_t,
                          const tcc_idx *htri, uint8_t *status, tcc_idx nh, uint8_t *ready, tcc_error *err)
{
    crossing *cr = malloc(sizeof *cr * (size_t)(in->kb > 0 ? in->kb : 1));
    if (!cr) return tcc_fail(err, TCC_ERR_NOMEM, "no memory for %lld clusters", (long long)in->kb);
    int rc = TCC_OK;
    const double eps = 1e-6, bo = in->backoff;
    for (tcc_idx i = 0; i < nh && rc == TCC_OK; i++) {
        if (status[i] != 2) continue;
        tcc_idx v = hv[i];
        double sg = hs[i] == 0 ? 1.0 : -1.0, d[3], inv[3];
        const double *x = in->x + 3 * v;
        for (int c = 0; c < 3; c++) {
            d[c] = in->normals[3 * v + c] * sg;
            inv[c] = fabs(d[c]) < 1e-300 ? INFINITY : 1.0 / d[c];
        }
        double smax = ht_t[i] - eps;
        tcc_idx nc = 0;
        for (tcc_idx c = 0; c < in->kb && -bo <= smax; c++) {
            double bx[6], t0, t1;
            for (int a = 0; a < 3; a++) {
                bx[a] = in->box_lo[3 * c + a];
                bx[3 + a] = in->box_hi[3 * c + a];
            }
            if (!tcc_line_box(x, inv, -bo, smax, bx, &t0, &t1)) continue;
            tcc_idx q = nc++;
            while (q > 0 && cr[q - 1].enter > t0) {
                cr[q] = cr[q - 1];
                q--;
            }
            cr[q] = (crossing){t0, c};
        }
        int blocked = 0;
        for (tcc_idx j = 0; j < nc && !blocked; j++) {
            if ((rc = tree_ready(in, cr[j].c, ready, err))) break;
            blocked = tcc_bvh_blocked(&in->bvh, cr[j].c, x, d, -bo, smax, htri[i]);
        }
        status[i] = (uint8_t)!blocked;
    }
    free(cr);
    return rc;
}

/* The longest way a ray can travel inside the body: the diagonal of its clusters' boxes (NaN boxes:
 * of its vertices), numpy's max / min (NaN propagates). */
static double body_extent(const tcc_detect_in *in)
{
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    int nan = 0;
    for (tcc_idx c = 0; c < in->kb; c++)
        for (int a = 0; a < 3; a++) {
            double l = in->box_lo[3 * c + a], h = in->box_hi[3 * c + a];
            nan |= isnan(l) || isnan(h);
            if (l < lo[a]) lo[a] = l;
            if (h > hi[a]) hi[a] = h;
        }
    double e[3] = {hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]};
    double ext = sqrt(dot3(e, e));
    if (!nan && isfinite(ext)) return ext;
    for (int a = 0; a < 3; a++) {
        lo[a] = INFINITY;
        hi[a] = -INFINITY;
    }
    nan = 0;
    for (tcc_idx v = 0; v < in->target.nv; v++)
        for (int a = 0; a < 3; a++) {
            double x = in->target.x[3 * v + a];
            nan |= isnan(x);
            if (x < lo[a]) lo[a] = x;
            if (x > hi[a]) hi[a] = x;
        }
    for (int a = 0; a < 3; a++) e[a] = hi[a] - lo[a];
    return nan ? NAN : sqrt(dot3(e, e));
}

/* The clearance credit of the pairs fully detected this step (tcc_detect_in.rel_dev): the formula of
 * detector.py's former numpy step, term for term (a NaN clearance gives no credit, as numpy's clip
 * propagates it and the non-finite credit is dropped). */
static void credit_pairs(const tcc_detect_in *in)
{
    const double margin = in->track_range - in->thickness, top = in->clearance_cap - 1.0;
    for (tcc_idx p = 0; p < in->np; p++) {
        if (!in->full[p]) continue;
        double r = (in->clearance[p] - in->thickness) / margin - 1.0;
        double m = r > 0.0 ? r : 0.0; /* numpy's clip in its order (max, then min): -0.0 gives +0.0 */
        double credit = isnan(r) ? NAN : in->credit_unit * (m < top ? m : top);
        if (!isfinite(credit)) credit = 0.0;
        in->rel_avg[3 * p] = in->rel_avg[3 * p + 1] = in->rel_avg[3 * p + 2] = 0.0;
        in->rel_dev[p] = -credit;
    }
}

int tcc_detect(tcc_detect_in *in, tcc_merge_out *out, tcc_detect_stats *stats, tcc_error *err)
{
    const tcc_idx n = in->n;
    const int is_self = in->kind == TCC_SELF, volume = in->kind == TCC_VOLUME;
    memset(stats, 0, sizeof *stats);
    if (in->kind < TCC_VOLUME || in->kind > TCC_SELF)
        return tcc_fail(err, TCC_ERR_VALUE, "kind must be 0 (volume), 1 (surface) or 2 (self), got %d", in->kind);
    if (in->norder != n || in->ptr[0] != 0 || in->ptr[in->kc] != n)
        return tcc_fail(err, TCC_ERR_VALUE, "the cloth's clusters must hold its %lld vertices once", (long long)n);
    for (tcc_idx c = 0; c < in->kc; c++)
        if (in->ptr[c + 1] < in->ptr[c])
            return tcc_fail(err, TCC_ERR_VALUE, "the cloth's cluster bounds must not decrease (cluster %lld)", (long long)c);
    /* the branch-free passes (collide.h), then the first bad entry */
    if (!tcc_all_in_range(in->order, n, n) || !tcc_all_in_range(in->labels, n, in->kc))
        for (tcc_idx i = 0; i < n; i++)
            if (in->order[i] < 0 || in->order[i] >= n || in->labels[i] < 0 || in->labels[i] >= in->kc)
                return tcc_fail(err, TCC_ERR_INDEX, "order / labels entry %lld is out of range", (long long)i);
    if (!tcc_all_in_range(in->tri_labels, in->target.nt, in->kb))
        for (tcc_idx f = 0; f < in->target.nt; f++)
            if (in->tri_labels[f] < 0 || in->tri_labels[f] >= in->kb)
                return tcc_fail(err, TCC_ERR_INDEX, "tri_labels[%lld] = %lld is not a collider cluster", (long long)f,
                                (long long)in->tri_labels[f]);
    if (in->nvt != in->vt_ptr[n] || in->vt_ptr[0] != 0)
        return tcc_fail(err, TCC_ERR_VALUE, "vt_ptr must run from 0 to the %lld listed triangles", (long long)in->nvt);
    if (in->bvh.k != in->kb || in->bvh.node_ptr[0] < 0 || in->bvh.node_ptr[in->kb] > in->bvh.nnodes)
        return tcc_fail(err, TCC_ERR_VALUE, "the tree holds %lld clusters, the collider %lld", (long long)in->bvh.k,
                        (long long)in->kb);
    for (tcc_idx p = 0; p < in->np; p++)
        if (in->pi[p] < 0 || in->pi[p] >= in->kc || in->pj[p] < 0 || in->pj[p] >= in->kb ||
            (p > 0 && ((in->pi[p] << 32) | in->pj[p]) <= ((in->pi[p - 1] << 32) | in->pj[p - 1])))
            return tcc_fail(err, TCC_ERR_VALUE, "close pairs must be distinct cluster pairs in row-major order (pair %lld)",
                            (long long)p);
    for (tcc_idx i = 0; i < in->kt; i++) {
        tcc_idx key = in->track_key[i];
        if (key < 0 || key >= 2 * n || (i > 0 && key <= in->track_key[i - 1]))
            return tcc_fail(err, TCC_ERR_VALUE, "track keys must be ascending keys 2 * vertex + slot in [0, %lld) "
                            "(entry %lld)", (long long)(2 * n), (long long)i);
    }
    for (tcc_idx i = 0; i < in->ninside; i++)
        if (in->inside[i] < 0 || in->inside[i] >= n)
            return tcc_fail(err, TCC_ERR_INDEX, "inside vertex %lld is not in [0, %lld)", (long long)in->inside[i],
                            (long long)n);
    tcc_ring ring = in->ring;
    const tcc_ring *rp = is_self && ring.table ? &ring : NULL;
    int rc = TCC_OK;
    /* scratch: the walked hits (kt), per vertex the inside mask */
    size_t kt = (size_t)in->kt;
    char *block = malloc(kt * (sizeof(tcc_idx) + 3 * sizeof(double) + 1) + (size_t)n + 16);
    if (!block) return tcc_fail(err, TCC_ERR_NOMEM, "no memory for %lld tracks", (long long)in->kt);
    tcc_hits walked = {(tcc_idx *)block, (double *)(block + kt * sizeof(tcc_idx)), NULL, NULL, NULL};
    walked.u = walked.t + kt;
    walked.v = walked.u + kt;
    walked.flips = (uint8_t *)(walked.v + kt);
    uint8_t *inside_prev = walked.flips + kt;
    hit_list hits = {0};
    tcc_idx *rv_out = NULL, *rs_out = NULL, *ht = NULL;
    double *rt = NULL, *ru = NULL, *rw = NULL;
    uint8_t *rf = NULL, *status = NULL;
    pair_ref *order = NULL;
    /* the collider clusters whose trees this call refitted or checked (tcc_bvh_line reads them unchecked) */
    uint8_t *ready = calloc((size_t)(in->kb > 0 ? in->kb : 1), 1);
    if (!ready) {
        free(block);
        return tcc_fail(err, TCC_ERR_NOMEM, "no memory for %lld clusters", (long long)in->kb);
    }

    double t0 = now_s();
    /* 2. incremental: every tracked ray walked to its current hit */
    for (tcc_idx i = 0; i < in->kt; i++) {
        tcc_idx v = in->track_key[i] >> 1;
        if ((rc = need_normal(in, v, err))) goto done;
    }
    if (in->kt) {
        tcc_idx *tv = malloc(sizeof(tcc_idx) * 2 * kt);
        if (!tv) {
            rc = tcc_fail(err, TCC_ERR_NOMEM, "no memory for %lld tracks", (long long)in->kt);
            goto done;
        }
        for (tcc_idx i = 0; i < in->kt; i++) {
            tv[i] = in->track_key[i] >> 1;
            tv[kt + i] = in->track_key[i] & 1;
        }
        rc = tcc_walk(in->x, in->normals, n, tv, tv + kt, in->track_tri, in->kt, &in->target, rp, 8, walked, err);
        if (rc == TCC_OK)
            for (tcc_idx i = 0; i < in->kt; i++) {
                tcc_idx v = tv[i];
                if (!(walked.tri[i] < 0 && in->has_normal[v])) continue;
                stats->lost++;
                if (in->np == 0) continue;
                /* the pair (cloth cluster, collider cluster last hit) gets full detection now */
                tcc_idx start = in->track_tri[i];
                if (start < 0 || start >= in->target.nt) {
                    rc = tcc_fail(err, TCC_ERR_INDEX, "track triangle %lld is not in [0, %lld)", (long long)start,
                                  (long long)in->target.nt);
                    break;
                }
                tcc_idx la = in->labels[v], lb = in->tri_labels[start];
                if (is_self && lb < la) {
                    tcc_idx t = la;
                    la = lb;
                    lb = t;
                }
                tcc_idx p = pair_index(in, (la << 32) | lb);
                if (p >= 0) in->full[p] = 1;
            }
        free(tv);
        if (rc) goto done;
    }
    stats->tracked = in->kt;
    double t1 = now_s();
    stats->seconds[0] = t1 - t0;

    /* 3. full detection of the marked pairs */
    tcc_idx nfull = 0;
    for (tcc_idx p = 0; p < in->np; p++) nfull += in->full[p] != 0;
    stats->full_pairs = nfull;
    if (in->clearance)
        for (tcc_idx p = 0; p < in->np; p++) in->clearance[p] = in->full[p] ? INFINITY : NAN;
    if (nfull) {
        double len = in->ray_length, keep = in->ray_length;
        if (volume) len = keep = in->track_range + 2.0 * in->inflate + body_extent(in); /* a closed body's rays reach across it */
        else if (in->clearance && in->probe_length > len) len = in->probe_length;

        if (!in->bvh.corner) {
            rc = tcc_fail(err, TCC_ERR_VALUE, "full detection needs the trees' corner copies");
            goto done;
        }
        order = malloc(sizeof(pair_ref) * 2 * (size_t)nfull + 16);
        if (!order) {
            rc = tcc_fail(err, TCC_ERR_NOMEM, "no memory for %lld pairs", (long long)nfull);
            goto done;
        }
        /* self: a's rays into b's triangles and b's into a's (once for a == b); grouped by cloth cluster */
        tcc_idx m = 0;
        for (tcc_idx p = 0; p < in->np; p++)
            if (in->full[p]) order[m++] = (pair_ref){in->pj[p], p, in->pi[p]};
        if (is_self)
            for (tcc_idx p = 0; p < in->np; p++)
                if (in->full[p] && in->pi[p] != in->pj[p]) order[m++] = (pair_ref){in->pi[p], p, in->pj[p]};
        qsort(order, (size_t)m, sizeof *order, by_cloth_cluster);
        if (volume && in->ninside) { /* the vertices inside the body at the previous step */
            memset(inside_prev, 0, (size_t)n);
            for (tcc_idx i = 0; i < in->ninside; i++) inside_prev[in->inside[i]] = 1;
        }
        tcc_idx *targets = malloc(sizeof(tcc_idx) * 2 * (size_t)(m + 1));
        if (!targets) {
            rc = tcc_fail(err, TCC_ERR_NOMEM, "no memory for %lld pairs", (long long)m);
            goto done;
        }
        tcc_idx *pairs = targets + m + 1;
        for (tcc_idx q = 0; q < m && rc == TCC_OK;) {
            tcc_idx e = q, nb = 0;
            while (e < m && order[e].a == order[q].a) {
                pairs[nb] = order[e].p;
                targets[nb++] = order[e++].b;
            }
            rc = cast_cluster(in, rp, order[q].a, targets, pairs, nb, len, keep,
                              volume && in->ninside ? inside_prev : NULL, ready, &hits, &stats->rays, err);
            q = e;
        }
        free(targets);
        if (rc) goto done;
        /* a pair none of whose vertices had a line (an empty cluster), or lines of no finite length
         * (a body's extent from NaN positions): the paper's margin */
        if (in->clearance)
            for (tcc_idx p = 0; p < in->np; p++)
                if (in->full[p] && !(in->clearance[p] <= len)) in->clearance[p] = in->track_range;
    }
    stats->hits = hits.n;
    double t2 = now_s();
    stats->seconds[1] = t2 - t1;

    /* refine: the hits made exact on the current geometry, classified (status), and for a body the
     * far back faces confirmed */
    tcc_idx nf = 0;
    if (hits.n) {
        size_t r = (size_t)hits.n;
        rv_out = malloc(sizeof(tcc_idx) * r);
        rs_out = malloc(sizeof(tcc_idx) * r);
        ht = malloc(sizeof(tcc_idx) * r);
        rt = malloc(sizeof(double) * 3 * r);
        rf = malloc(r);
        status = malloc(r);
        if (!rv_out || !rs_out || !ht || !rt || !rf || !status) {
            rc = tcc_fail(err, TCC_ERR_NOMEM, "no memory for %lld hits", (long long)hits.n);
            goto done;
        }
        ru = rt + r;
        rw = ru + r;
        tcc_hits fh = {ht, rt, ru, rw, rf};
        if ((rc = tcc_refine(in->x, in->normals, n, hits.v, hits.slot, hits.tri, hits.n, &in->target, rp, in->kind,
                             in->track_range, volume && in->ninside ? inside_prev : NULL, rv_out, rs_out, fh, status,
                             &nf, err)))
            goto done;
        if (volume && nf) {
            tcc_idx left = 0;
            if ((rc = tcc_drop_dominated(rv_out, rs_out, rt, status, nf, in->track_key, in->kt, walked.tri, walked.t,
                                         &left, err)))
                goto done;
            if (left) {
                /* far back faces that no nearer hit disproves: inside only if nothing is in front of
                 * them, on the current geometry (the trees of every cluster the segment crosses) */
                if ((rc = confirm_inside(in, rv_out, rs_out, rt, ht, status, nf, ready, err))) goto done;
            }
        }
    }

    double t3 = now_s();
    stats->seconds[2] = t3 - t2;
    /* 4. merge with the walked tracks, classify, the new tracks and this collider's contacts */
    if (in->kt == 0 && nf == 0) {
        out->ntracks = out->ninside = out->ncontacts = 0;
    } else {
        tcc_hits fh = {ht, rt, ru, rw, rf};
        tcc_merge_in mi = {in->x, in->normals, in->x_prev, in->velocity, n, &in->target, in->target_prev,
                           in->target_velocity, in->kind, in->first, in->thickness, in->track_range, in->track_key,
                           in->track_tri, in->track_side, in->kt, walked, rv_out, rs_out, fh, status, nf};
        if ((rc = tcc_merge_classify(&mi, out, err))) goto done;
    }
    stats->seconds[3] = now_s() - t3;
    if (in->clearance && in->rel_dev) credit_pairs(in);
    rc = TCC_OK;
done:
    free(block);
    hits_free(&hits);
    free(rv_out);
    free(rs_out);
    free(ht);
    free(rt);
    free(rf);
    free(status);
    free(order);
    free(ready);
    return rc;
}
