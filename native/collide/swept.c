/* swept.c - the swept stage of a detector step in one call: which pairs of the cloth's two-ring can
 * meet (the cull), the swept tests of those, the remembered crossings, and the contact rows they
 * give (collision/swept.py's module docs say what each test means; ccd.c holds the tests).
 *
 * Why one call: the stage's work in a quiet step is a cull that hands out nothing, and the numpy
 * around it (displacements, set differences, concatenations, a dozen kernel calls) cost more than
 * the cull itself.
 *
 * The cull. Pairs come in blocks of consecutive pairs (bptr) with the vertices their corners use
 * (bverts, ascending). Each block keeps a reference pose - its vertices' positions when its pairs
 * were last read (bref) - and every pair q of it slack[q], a lower bound of its distance minus its
 * gap at that pose. Two points of the block's elements move apart, from the reference to any time,
 * by at most the spread (the diagonal of the box) of the block's displacements since the reference:
 * while bstate's min (the smallest slack) exceeds that spread, no pair of the block can come within
 * its gap. Over a window of linear motion (the real one from the previous step, or the predicted one
 * over dt with the velocities) the spread is at most the larger of its values at the window's ends
 * (the box of a convex combination).
 *
 * What a block costs per step is what decides the stage's cost: the two-ring of a 1,700-vertex
 * shirt has ~105,000 pairs in ~1,650 blocks of ~26 vertices, and reading every block's vertices
 * twice a step (the former cull) was ~0.3 ms. So bstate also holds acc, a bound of the spread since
 * the reference, grown each step by a bound of the step's own spread (triangle inequality) taken as
 * cheaply as will do:
 *   1. the largest spread of the step's motion over any group of vertices (groups: ~16 nearby
 *      vertices, group_ptr / group_vertices) - one addition per block;
 *   2. else the spread of the union of the boxes of the block's groups (bgroups) - a few boxes;
 *   3. else the block's own vertices against its reference pose: exact, and acc becomes it;
 *   4. else the block is read: each pair's bound is carried to this step (less the largest relative
 *      motion of its four corners since the reference), a pair that can come within its gap is
 *      handed out, tested exactly and its slack made exact, and the reference becomes this step's
 *      pose (acc 0).
 * A block with a wide margin is thus settled by one addition for many steps, and a margin used up
 * by loose bounds is restored by one exact read. Every bound is a lower bound of a pair's distance
 * minus its gap, so no pair that can come within its gap is kept back: the cull decides what is
 * read, never what is found.
 */
#include "collide.h"
#include "vecmath.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* A growing list of pair indices. */
typedef struct {
    tcc_idx *at, n, cap;
} pair_list;

static int list_push(pair_list *l, tcc_idx q, tcc_error *err)
{
    if (l->n == l->cap) {
        tcc_idx cap = l->cap ? 2 * l->cap : 1024;
        tcc_idx *at = realloc(l->at, sizeof(tcc_idx) * (size_t)cap);
        if (!at) return tcc_fail(err, TCC_ERR_NOMEM, "no memory for %lld swept pairs", (long long)cap);
        l->at = at;
        l->cap = cap;
    }
    l->at[l->n++] = q;
    return TCC_OK;
}

static int by_index(const void *a, const void *b)
{
    tcc_idx x = *(const tcc_idx *)a, y = *(const tcc_idx *)b;
    return x < y ? -1 : x > y;
}

/* Whether q is in the ascending list l[0..m). */
static int listed(const tcc_idx *l, tcc_idx m, tcc_idx q)
{
    tcc_idx lo = 0, hi = m;
    while (lo < hi) {
        tcc_idx mid = lo + (hi - lo) / 2;
        if (l[mid] < q) lo = mid + 1;
        else hi = mid;
    }
    return lo < m && l[lo] == q;
}

/* Diagonal of the box of x[vert[i]] - ref[i] over a block's vertices (checked against n); with x1,
 * also that of x1 (*s1); ref (count, 3) the block's reference pose. */
static int block_spread(const double *x, const double *x1, tcc_idx n, const tcc_idx *vert, const double *ref,
                        tcc_idx count, double *s0, double *s1, tcc_error *err)
{
    double lo[2][3] = {{INFINITY, INFINITY, INFINITY}, {INFINITY, INFINITY, INFINITY}};
    double hi[2][3] = {{-INFINITY, -INFINITY, -INFINITY}, {-INFINITY, -INFINITY, -INFINITY}};
    for (tcc_idx i = 0; i < count; i++) {
        tcc_idx v = vert[i];
        if (v < 0 || v >= n)
            return tcc_fail(err, TCC_ERR_INDEX, "block vertex %lld is not in [0, %lld)", (long long)v, (long long)n);
        for (int w = 0; w < (x1 ? 2 : 1); w++) {
            const double *p = (w ? x1 : x) + 3 * v, *r = ref + 3 * i;
            for (int c = 0; c < 3; c++) {
                double d = p[c] - r[c];
                if (d < lo[w][c]) lo[w][c] = d;
                if (d > hi[w][c]) hi[w][c] = d;
            }
        }
    }
    for (int w = 0; w < (x1 ? 2 : 1); w++) {
        double e[3] = {hi[w][0] - lo[w][0], hi[w][1] - lo[w][1], hi[w][2] - lo[w][2]};
        double l = count ? sqrt(dot3(e, e)) : 0.0;
        if (!isfinite(l) && count) l = INFINITY; /* a NaN position proves nothing */
        *(w ? s1 : s0) = l;
    }
    return TCC_OK;
}

/* Diagonal of the union of the group boxes gbox (ng, 6) of groups g[0..count). */
static double union_spread(const double *gbox, const tcc_idx *g, tcc_idx count)
{
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (tcc_idx i = 0; i < count; i++) {
        const double *b = gbox + 6 * g[i];
        for (int c = 0; c < 3; c++) {
            if (b[c] < lo[c]) lo[c] = b[c];
            if (b[3 + c] > hi[c]) hi[c] = b[3 + c];
        }
    }
    if (count == 0) return 0.0;
    double e[3] = {hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]};
    return sqrt(dot3(e, e));
}

/* Bound (squared) of how far apart two points of a pair's elements moved, from the displacements
 * d[j] of its four corners: 2 (ma^2 + mb^2), ma and mb the largest displacements of each element's
 * corners relative to corner 0 (ma + mb <= its root). */
static double pair_motion2(const double d[4][3], int split)
{
    double ma2 = 0.0, mb2 = 0.0;
    for (int j = 1; j < 4; j++) {
        double r[3];
        sub3(d[j], d[0], r);
        double l2 = dot3(r, r);
        if (j < split) {
            if (l2 > ma2) ma2 = l2;
        } else if (l2 > mb2)
            mb2 = l2;
    }
    return 2.0 * (ma2 + mb2);
}

static int pair_ids(const tcc_swept_kind *K, tcc_idx q, tcc_idx n, tcc_idx id[4], tcc_error *err)
{
    for (int j = 0; j < 4; j++) {
        id[j] = K->quad[4 * q + j];
        if (id[j] < 0 || id[j] >= n)
            return tcc_fail(err, TCC_ERR_INDEX, "pair %lld: vertex %lld is not in [0, %lld)", (long long)q,
                            (long long)id[j], (long long)n);
    }
    if (K->split == 1 ? (id[0] == id[1] || id[0] == id[2] || id[0] == id[3])
                      : (id[0] == id[2] || id[0] == id[3] || id[1] == id[2] || id[1] == id[3]))
        return tcc_fail(err, TCC_ERR_VALUE, "pair %lld: its elements share a vertex", (long long)q);
    return TCC_OK;
}

static void points(const double *x, const tcc_idx id[4], const double *P[4])
{
    for (int j = 0; j < 4; j++) P[j] = x + 3 * id[j];
}

/* Pair q's corners must be among its block's vertices, whose reference pose scatter_ref stamped
 * with the block's tag: a block built from other pairs would read other blocks' poses. */
static int in_block(const tcc_idx *stamp, tcc_idx tag, const tcc_idx id[4], tcc_idx q, tcc_error *err)
{
    for (int j = 0; j < 4; j++)
        if (stamp[id[j]] != tag)
            return tcc_fail(err, TCC_ERR_VALUE, "pair %lld: vertex %lld is not among its block's vertices", (long long)q,
                            (long long)id[j]);
    return TCC_OK;
}

/* The displacement of pair corners id from the reference pose (scattered per vertex into rs). */
static void corner_motion(const double *x, const tcc_idx id[4], const double *rs, double d[4][3])
{
    for (int j = 0; j < 4; j++)
        for (int c = 0; c < 3; c++) d[j][c] = x[3 * id[j] + c] - rs[3 * id[j] + c];
}

/* A block's reference pose scattered per vertex into rs (n, 3), its vertices stamped with tag: its
 * pairs' corners read it there. */
static void scatter_ref(const tcc_idx *vert, tcc_idx count, const double *ref, double *rs, tcc_idx *stamp, tcc_idx tag)
{
    for (tcc_idx i = 0; i < count; i++) {
        stamp[vert[i]] = tag;
        for (int c = 0; c < 3; c++) rs[3 * vert[i] + c] = ref[3 * i + c];
    }
}

static int check_kind(const tcc_swept_kind *K, tcc_idx n, tcc_idx ng, tcc_error *err)
{
    if (K->split != 1 && K->split != 2)
        return tcc_fail(err, TCC_ERR_VALUE, "split must be 1 (vertex-triangle) or 2 (edge-edge), got %d", K->split);
    if (K->bptr[0] != 0 || K->bptr[K->nb] != K->k || K->bvptr[0] != 0 || K->bvptr[K->nb] != K->nbv ||
        K->bgptr[0] != 0 || K->bgptr[K->nb] != K->nbg)
        return tcc_fail(err, TCC_ERR_VALUE, "block_ptr must run from 0 to the %lld pairs, block_vptr to the %lld block "
                        "vertices and block_gptr to the %lld block groups", (long long)K->k, (long long)K->nbv,
                        (long long)K->nbg);
    for (tcc_idx b = 0; b < K->nb; b++) {
        if (K->bptr[b + 1] < K->bptr[b] || K->bvptr[b + 1] < K->bvptr[b] || K->bgptr[b + 1] < K->bgptr[b])
            return tcc_fail(err, TCC_ERR_VALUE, "block %lld: block_ptr, block_vptr and block_gptr must not decrease",
                            (long long)b);
    }
    if (!tcc_all_in_range(K->bgroups, K->nbg, ng)) /* the branch-free pass, then the first bad one */
        for (tcc_idx i = 0; i < K->nbg; i++)
            if (K->bgroups[i] < 0 || K->bgroups[i] >= ng)
                return tcc_fail(err, TCC_ERR_INDEX, "block group %lld is not in [0, %lld)", (long long)K->bgroups[i],
                                (long long)ng);
    if (K->nmem > K->k)
        return tcc_fail(err, TCC_ERR_VALUE, "%lld remembered pairs of %lld", (long long)K->nmem, (long long)K->k);
    for (tcc_idx i = 0; i < K->nmem; i++)
        if (K->mem[i] < 0 || K->mem[i] >= K->k)
            return tcc_fail(err, TCC_ERR_INDEX, "remembered pair %lld is not in [0, %lld)", (long long)K->mem[i],
                            (long long)K->k);
    return TCC_OK;
}

/* The cull of one kind over both windows: cand (the real motion, with update) and pcand (the
 * predicted one). ustep / upred: the largest group spread of this step's motion and of the
 * prediction; gstep / gpred the group boxes of those motions. */
static int cull_kind(tcc_swept *s, tcc_swept_kind *K, const double *x1, const double *gstep, const double *gpred,
                     double ustep, double upred, double *rs, tcc_idx *stamp, tcc_idx *tag, pair_list *cand,
                     pair_list *pcand, tcc_error *err)
{
    const tcc_idx n = s->n;
    const double *xp = s->x_prev ? s->x_prev : s->x;
    cand->n = pcand->n = 0;
    K->settled[0] = K->settled[1] = K->settled[2] = K->settled[3] = 0;
    int rc;
    for (tcc_idx b = 0; b < K->nb; b++) {
        double *st = K->bstate + 2 * b; /* min, acc */
        const tcc_idx *vert = K->bverts + K->bvptr[b], *grp = K->bgroups + K->bgptr[b];
        double *ref = K->bref + 3 * K->bvptr[b];
        tcc_idx nv = K->bvptr[b + 1] - K->bvptr[b], ng = K->bgptr[b + 1] - K->bgptr[b];
        /* 1. the loosest bound: every group's motion as large as the largest */
        double acc = st[1] + ustep;
        if (st[0] - (x1 ? acc + upred : acc) > 0) {
            st[1] = acc;
            K->settled[0]++;
            continue;
        }
        /* 2. the block's groups */
        double us = union_spread(gstep, grp, ng), up = x1 ? union_spread(gpred, grp, ng) : 0.0;
        acc = st[1] + us;
        if (st[0] - (acc + up) > 0) {
            st[1] = acc;
            K->settled[1]++;
            continue;
        }
        /* 3. the block's own vertices against its reference pose: the window of the real motion
         * is bounded by the larger of its ends (the previous bound, and the exact one now) */
        double snow, spred = 0.0;
        if ((rc = block_spread(s->x, x1, n, vert, ref, nv, &snow, &spred, err))) return rc;
        int real_open = !(st[0] - fmax(st[1], snow) > 0);
        int pred_open = x1 && !(st[0] - fmax(snow, spred) > 0);
        st[1] = snow;
        K->settled[2 + real_open]++;
        if (real_open) {
            /* read the pairs: carry each bound to this step (less its own corners' motion since the
             * reference), hand out those that may meet; the reference becomes this step's pose.
             * The predicted window is judged in the same pass: from the new reference (this step's
             * pose) a pair's predicted motion is x1 - x at its corners, tested against its new
             * bound as the pass below would; its pairs are kept only if the block's own test
             * (its smallest bound against the spread of x1 - x) leaves the window open. The same
             * arithmetic as a second pass over the block (bit for bit), without reading it twice:
             * in the race's shirt at 10 sub-steps a frame a quarter of the blocks are read a step */
            double lo = INFINITY;
            int unknown = 0;
            const tcc_idx pfrom = pcand->n;
            scatter_ref(vert, nv, ref, rs, stamp, ++*tag); /* block_spread checked vert */
            for (tcc_idx q = K->bptr[b]; q < K->bptr[b + 1]; q++) {
                tcc_idx id[4];
                double dn[4][3], dp[4][3];
                if ((rc = pair_ids(K, q, n, id, err)) || (rc = in_block(stamp, *tag, id, q, err))) return rc;
                corner_motion(s->x, id, rs, dn);
                corner_motion(xp, id, rs, dp);
                double bn = pair_motion2(dn, K->split), bp = pair_motion2(dp, K->split);
                double sl = K->slack[q];
                if (sl > 0 && sl * sl > fmax(bn, bp)) {
                    K->slack[q] = sl - sqrt(bn);
                    if (K->slack[q] < lo) lo = K->slack[q]; /* sl > 0 and finite: never NaN */
                } else {
                    if ((rc = list_push(cand, q, err))) return rc;
                    const double *P[4];
                    points(s->x, id, P);
                    K->slack[q] = sqrt(tcc_pair_distance2(P, K->split)) - K->gap[q];
                    if (isnan(K->slack[q]))
                        unknown = 1;
                    else if (K->slack[q] < lo)
                        lo = K->slack[q];
                }
                if (x1) {
                    /* x - x at the corners (the new reference) is 0: the predicted motion alone */
                    double dx[4][3];
                    for (int j = 0; j < 4; j++)
                        for (int c = 0; c < 3; c++) dx[j][c] = x1[3 * id[j] + c] - s->x[3 * id[j] + c];
                    double ns = K->slack[q];
                    if (!(ns > 0 && ns * ns > fmax(0.0, pair_motion2(dx, K->split))) && (rc = list_push(pcand, q, err)))
                        return rc;
                }
            }
            st[0] = unknown ? NAN : lo;
            st[1] = 0.0;
            for (tcc_idx i = 0; i < nv; i++)
                for (int c = 0; c < 3; c++) ref[3 * i + c] = s->x[3 * vert[i] + c];
            if (x1) {
                double s0, s1;
                if ((rc = block_spread(s->x, x1, n, vert, ref, nv, &s0, &s1, err))) return rc;
                if (st[0] - s1 > 0) pcand->n = pfrom; /* the block's window is closed: none of them */
            }
            continue;
        }
        if (!pred_open) continue;
        scatter_ref(vert, nv, ref, rs, stamp, ++*tag);
        for (tcc_idx q = K->bptr[b]; q < K->bptr[b + 1]; q++) {
            tcc_idx id[4];
            double dn[4][3], dp[4][3];
            if ((rc = pair_ids(K, q, n, id, err)) || (rc = in_block(stamp, *tag, id, q, err))) return rc;
            corner_motion(s->x, id, rs, dn);
            corner_motion(x1, id, rs, dp);
            double sl = K->slack[q];
            if (sl > 0 && sl * sl > fmax(pair_motion2(dn, K->split), pair_motion2(dp, K->split))) continue;
            if ((rc = list_push(pcand, q, err))) return rc;
        }
    }
    return TCC_OK;
}

/* The tests of one kind after its cull: crossings over the real motion remembered, the remembered
 * ones kept while they are still on the wrong side or close, the predicted ones listed. */
static int test_kind(tcc_swept *s, tcc_swept_kind *K, const double *x1, const tcc_idx *cand, tcc_idx ncand,
                     const tcc_idx *pcand, tcc_idx npcand, tcc_error *err)
{
    const tcc_idx n = s->n;
    int rc, vt = K->split == 1;
    /* the memory in ascending order: what a crossing already in it, or a predicted pair, is checked against */
    tcc_idx *sorted = malloc(sizeof(tcc_idx) * (size_t)(K->nmem + ncand + 1));
    if (!sorted) return tcc_fail(err, TCC_ERR_NOMEM, "no memory for %lld remembered pairs", (long long)K->nmem);
    memcpy(sorted, K->mem, sizeof(tcc_idx) * (size_t)K->nmem);
    qsort(sorted, (size_t)K->nmem, sizeof(tcc_idx), by_index);
    for (tcc_idx i = 1; i < K->nmem; i++)
        if (sorted[i] == sorted[i - 1]) {
            rc = tcc_fail(err, TCC_ERR_VALUE, "pair %lld is remembered twice", (long long)sorted[i]);
            goto done;
        }
    /* 1. the remembered crossings, then this step's new ones (over the real motion, gap 0) */
    tcc_idx nm = K->nmem;
    memcpy(K->mem_out, K->mem, sizeof(tcc_idx) * (size_t)nm);
    memcpy(K->mem_n_out, K->mem_n, sizeof(double) * 3 * (size_t)nm);
    K->crossed = 0;
    if (s->x_prev) {
        for (tcc_idx i = 0; i < ncand; i++) {
            tcc_idx q = cand[i], id[4];
            if ((rc = pair_ids(K, q, n, id, err))) goto done;
            const double *A[4], *B[4];
            points(s->x_prev, id, A);
            points(s->x, id, B);
            double toi, w[3], sd, dist, nrm[3];
            int8_t side;
            int hit = vt ? tcc_vt_sweep(A, B, 0.0, &toi, w, &side) : tcc_ee_sweep(A, B, 0.0, &toi, w, &side);
            if (!hit) continue;
            K->crossed++;
            if (listed(sorted, K->nmem, q)) continue; /* cand ascends and is unique: only the old memory can hold q */
            if (vt)
                tcc_vt_state(A, &sd, &dist, w, nrm);
            else
                tcc_ee_state(A, &sd, &dist, w, nrm);
            K->mem_out[nm] = q;
            for (int c = 0; c < 3; c++) K->mem_n_out[3 * nm + c] = side * nrm[c];
            nm++;
        }
    }
    K->remembered = nm;
    /* 2. remembered pairs pushed back to their side until there again, or apart */
    tcc_idx live = 0, no = 0;
    for (tcc_idx i = 0; i < nm; i++) {
        tcc_idx q = K->mem_out[i], id[4];
        if ((rc = pair_ids(K, q, n, id, err))) goto done;
        const double *P[4];
        points(s->x, id, P);
        double sd, dist, w[3], nrm[3];
        if (vt)
            tcc_vt_state(P, &sd, &dist, w, nrm);
        else
            tcc_ee_state(P, &sd, &dist, w, nrm);
        double flip = dot3(nrm, K->mem_n_out + 3 * i) < 0 ? -1.0 : 1.0;
        for (int c = 0; c < 3; c++) nrm[c] = nrm[c] * flip;
        double h = sd * flip, g = K->gap[q]; /* the height over the other element, on the remembered side */
        if (!(h < g && dist < s->thickness)) continue;
        K->mem_out[live] = q;
        for (int c = 0; c < 3; c++) K->mem_n_out[3 * live + c] = nrm[c];
        live++;
        K->out_q[no] = q;
        for (int c = 0; c < 3; c++) {
            K->out_normal[3 * no + c] = nrm[c];
            K->out_w[3 * no + c] = vt || c < 2 ? w[c] : 0.0;
        }
        K->out_depth[no] = g - h;
        no++;
    }
    K->nmem_out = live;
    K->nlive = no;
    /* 3. predicted over this step: pairs that would come within their gap stop their approach */
    memcpy(sorted, K->mem_out, sizeof(tcc_idx) * (size_t)live);
    qsort(sorted, (size_t)live, sizeof(tcc_idx), by_index);
    K->npred = 0;
    if (x1) {
        for (tcc_idx i = 0; i < npcand; i++) {
            tcc_idx q = pcand[i], id[4];
            if (listed(sorted, live, q)) continue; /* remembered: pushed back above */
            if ((rc = pair_ids(K, q, n, id, err))) goto done;
            const double *A[4], *B[4];
            points(s->x, id, A);
            points(x1, id, B);
            double gap = K->gap[q] < s->thickness ? K->gap[q] : s->thickness;
            double toi, w[3], sd, dist, nrm[3], gv[3];
            int8_t side;
            int hit = vt ? tcc_vt_sweep(A, B, gap, &toi, w, &side) : tcc_ee_sweep(A, B, gap, &toi, w, &side);
            if (!hit) continue;
            if (vt) {
                tcc_vt_state(A, &sd, &dist, w, nrm);
                for (int c = 0; c < 3; c++)
                    gv[c] = A[0][c] - (w[0] * A[1][c] + w[1] * A[2][c] + w[2] * A[3][c]);
            } else {
                tcc_ee_state(A, &sd, &dist, w, nrm);
                double a = w[0], t = w[1];
                w[2] = 0.0;
                for (int c = 0; c < 3; c++)
                    gv[c] = (1 - a) * A[0][c] + a * A[1][c] - (1 - t) * A[2][c] - t * A[3][c];
            }
            /* the way the pair is apart: from the second element's closest point to the first's;
               where they nearly touch (closer than a tenth of the gap), the oriented normal. Why not
               the normal everywhere: for two nearly parallel edges (a crease's mirror diagonals) the
               cross product is ill-conditioned, and a contact along it pressed on the stiff membrane
               and blew the sheet up */
            double *on = K->out_normal + 3 * no;
            if (dist > 0.1 * K->gap[q])
                for (int c = 0; c < 3; c++) on[c] = gv[c] / dist;
            else
                for (int c = 0; c < 3; c++) on[c] = side * nrm[c];
            K->out_q[no] = q;
            for (int c = 0; c < 3; c++) K->out_w[3 * no + c] = w[c];
            K->out_depth[no] = 0.0;
            no++;
            K->npred++;
        }
    }
    K->tested = ncand + (x1 ? npcand : 0);
    rc = TCC_OK;
done:
    free(sorted);
    return rc;
}

/* The group boxes (ng, 6) of the displacement b - a over each group's vertices (box), with c (not
 * NULL) also those of c - b (cbox, the largest diagonal in *cmax); returns the largest diagonal of
 * box. One pass for both: the vertices are read once per step (a quiet step's cull is this pass). */
static double group_boxes(const tcc_swept *s, const double *a, const double *b, double *box, const double *c,
                          double *cbox, double *cmax)
{
    double umax = 0.0, vmax = 0.0;
    for (tcc_idx g = 0; g < s->ngroups; g++) {
        double *bx = box + 6 * g, *cx = c ? cbox + 6 * g : NULL;
        for (int k = 0; k < 3; k++) {
            bx[k] = INFINITY;
            bx[3 + k] = -INFINITY;
        }
        if (cx)
            for (int k = 0; k < 3; k++) {
                cx[k] = INFINITY;
                cx[3 + k] = -INFINITY;
            }
        for (tcc_idx i = s->group_ptr[g]; i < s->group_ptr[g + 1]; i++) {
            tcc_idx v = s->group_vertices[i];
            for (int k = 0; k < 3; k++) {
                double d = b[3 * v + k] - a[3 * v + k];
                if (d < bx[k]) bx[k] = d;
                if (d > bx[3 + k]) bx[3 + k] = d;
            }
            if (cx)
                for (int k = 0; k < 3; k++) {
                    double d = c[3 * v + k] - b[3 * v + k];
                    if (d < cx[k]) cx[k] = d;
                    if (d > cx[3 + k]) cx[3 + k] = d;
                }
        }
        if (s->group_ptr[g + 1] > s->group_ptr[g]) {
            double e[3] = {bx[3] - bx[0], bx[4] - bx[1], bx[5] - bx[2]};
            double l = sqrt(dot3(e, e));
            if (l > umax) umax = l;
            if (cx) {
                double f[3] = {cx[3] - cx[0], cx[4] - cx[1], cx[5] - cx[2]};
                l = sqrt(dot3(f, f));
                if (l > vmax) vmax = l;
            }
        }
    }
    if (cmax) *cmax = vmax;
    return umax;
}

int tcc_swept_step(tcc_swept *s, tcc_error *err)
{
    const tcc_idx n = s->n, ng = s->ngroups;
    int rc;
    if (s->group_ptr[0] != 0 || s->group_ptr[ng] != s->ngv)
        return tcc_fail(err, TCC_ERR_VALUE, "group_ptr must run from 0 to the %lld group vertices", (long long)s->ngv);
    for (tcc_idx g = 0; g < ng; g++)
        if (s->group_ptr[g + 1] < s->group_ptr[g])
            return tcc_fail(err, TCC_ERR_VALUE, "group %lld: group_ptr must not decrease", (long long)g);
    if (!tcc_all_in_range(s->group_vertices, s->ngv, n)) /* the branch-free pass, then the first bad one */
        for (tcc_idx i = 0; i < s->ngv; i++)
            if (s->group_vertices[i] < 0 || s->group_vertices[i] >= n)
                return tcc_fail(err, TCC_ERR_INDEX, "group vertex %lld is not in [0, %lld)",
                                (long long)s->group_vertices[i], (long long)n);
    for (int k = 0; k < 2; k++)
        if ((rc = check_kind(&s->kind[k], n, ng, err))) return rc;
    int predict = s->v && s->dt > 0;
    if (!tcc_all_finite(s->x, 3 * n) || (s->x_prev && !tcc_all_finite(s->x_prev, 3 * n)) ||
        (predict && !tcc_all_finite(s->v, 3 * n))) /* the branch-free passes, then the first bad vertex */
        for (tcc_idx i = 0; i < 3 * n; i++)
            if (!isfinite(s->x[i]) || (s->x_prev && !isfinite(s->x_prev[i])) || (predict && !isfinite(s->v[i])))
                return tcc_fail(err, TCC_ERR_VALUE, "the position%s of vertex %lld %s not finite",
                                predict ? ", previous position or velocity" : " or previous position",
                                (long long)(i / 3), predict ? "are" : "is");
    size_t bytes = (size_t)(6 * n + 12 * ng) * sizeof(double) + (size_t)(n + 1) * sizeof(tcc_idx);
    char *block = malloc(bytes);
    if (!block) return tcc_fail(err, TCC_ERR_NOMEM, "no memory for the swept stage of %lld vertices", (long long)n);
    double *x1 = (double *)block, *rs = x1 + 3 * n, *gstep = rs + 3 * n, *gpred = gstep + 6 * ng;
    tcc_idx *stamp = (tcc_idx *)(gpred + 6 * ng), tag = 0;
    pair_list cand = {0}, pcand = {0};
    memset(stamp, 0, sizeof(tcc_idx) * (size_t)n);
    if (!*s->has_ref) {
        /* every block's reference pose: the previous step's (its bounds hold there), or this one */
        const double *from = s->x_prev ? s->x_prev : s->x;
        for (int k = 0; k < 2; k++) {
            tcc_swept_kind *K = &s->kind[k];
            for (tcc_idx i = 0; i < K->nbv; i++) {
                tcc_idx v = K->bverts[i];
                if (v < 0 || v >= n) {
                    rc = tcc_fail(err, TCC_ERR_INDEX, "block vertex %lld is not in [0, %lld)", (long long)v, (long long)n);
                    goto done;
                }
                for (int c = 0; c < 3; c++) K->bref[3 * i + c] = from[3 * v + c];
            }
        }
        *s->has_ref = 1;
    }
    if (predict)
        for (tcc_idx i = 0; i < 3 * n; i++) x1[i] = s->x[i] + s->dt * s->v[i]; /* swept.py's x + dt v */
    /* the groups' boxes of this step's motion and of the prediction, and the largest of each */
    double upred = 0.0;
    double ustep = group_boxes(s, s->x_prev ? s->x_prev : s->x, s->x, gstep, predict ? x1 : NULL, gpred, &upred);
    for (int k = 0; k < 2; k++) {
        tcc_swept_kind *K = &s->kind[k];
        if ((rc = cull_kind(s, K, predict ? x1 : NULL, gstep, gpred, ustep, upred, rs, stamp, &tag, &cand, &pcand, err)))
            goto done;
        if (s->cand_out[k]) {
            if (cand.n) memcpy(s->cand_out[k], cand.at, sizeof(tcc_idx) * (size_t)cand.n);
            if (pcand.n) memcpy(s->pcand_out[k], pcand.at, sizeof(tcc_idx) * (size_t)pcand.n);
        }
        s->ncand[k] = cand.n;
        s->npcand[k] = pcand.n;
        if ((rc = test_kind(s, K, predict ? x1 : NULL, cand.at, cand.n, pcand.at, pcand.n, err))) goto done;
    }
    rc = TCC_OK;
done:
    free(cand.at);
    free(pcand.at);
    free(block);
    return rc;
}

/* Rows of one list of pairs (q, normal, depth, w) of one kind, in swept.py's order: the first
 * element's vertices, then the second's (vertex-triangle: p, then corners a, b, c; edge-edge: a, b,
 * then c, d), each block in list order. */
static tcc_idx kind_rows(const tcc_swept_kind *K, tcc_idx from, tcc_idx to, const double *v, tcc_idx *rv,
                         double *rdepth, double *rn, double *rvel)
{
    tcc_idx r = 0;
    for (int j = 0; j < 4; j++) {
        double sign = j < K->split ? 1.0 : -1.0;
        for (tcc_idx i = from; i < to; i++, r++) {
            tcc_idx q = K->out_q[i];
            const tcc_idx *id = K->quad + 4 * q;
            const double *w = K->out_w + 3 * i, *nn = K->out_normal + 3 * i;
            double dep = K->out_depth[i];
            rv[r] = id[j];
            rdepth[r] = dep < 0 ? 0.0 : dep; /* np.maximum(depth, 0): NaN stays NaN */
            for (int c = 0; c < 3; c++) {
                rn[3 * r + c] = sign * nn[c];
                double vel = 0.0;
                if (v) {
                    if (K->split == 1)
                        vel = 0.5 * (v[3 * id[0] + c] +
                                     (w[0] * v[3 * id[1] + c] + w[1] * v[3 * id[2] + c] + w[2] * v[3 * id[3] + c]));
                    else
                        vel = 0.5 * ((1 - w[0]) * v[3 * id[0] + c] + w[0] * v[3 * id[1] + c] +
                                     (1 - w[1]) * v[3 * id[2] + c] + w[1] * v[3 * id[3] + c]);
                }
                rvel[3 * r + c] = vel;
            }
        }
    }
    return r;
}

int tcc_swept_rows(const tcc_swept_kind kind[2], const double *v, tcc_idx n, const int32_t *ev, const double *enormal,
                   const double *edepth, const double *evel, const double *efric, tcc_idx ne, double friction,
                   int32_t *ov, double *onormal, double *odepth, double *ovel, double *ofric, tcc_idx cap,
                   tcc_idx *count, tcc_idx *no_normal, tcc_error *err)
{
    tcc_idx rows = 0;
    for (int k = 0; k < 2; k++) rows += 4 * (kind[k].nlive + kind[k].npred);
    for (tcc_idx i = 0; i < ne; i++)
        if (ev[i] < 0 || ev[i] >= n || (i > 0 && ev[i] < ev[i - 1]))
            return tcc_fail(err, TCC_ERR_VALUE, "contact vertices must ascend within [0, %lld) (entry %lld)",
                            (long long)n, (long long)i);
    for (int k = 0; k < 2; k++)
        for (tcc_idx i = 0; i < kind[k].nlive + kind[k].npred; i++) {
            tcc_idx q = kind[k].out_q[i];
            if (q < 0 || q >= kind[k].k)
                return tcc_fail(err, TCC_ERR_INDEX, "swept pair %lld is not in [0, %lld)", (long long)q,
                                (long long)kind[k].k);
            for (int j = 0; j < 4; j++)
                if (kind[k].quad[4 * q + j] < 0 || kind[k].quad[4 * q + j] >= n)
                    return tcc_fail(err, TCC_ERR_INDEX, "swept pair %lld: vertex %lld is not in [0, %lld)",
                                    (long long)q, (long long)kind[k].quad[4 * q + j], (long long)n);
        }
    size_t bytes = (size_t)rows * (sizeof(tcc_idx) + 7 * sizeof(double)) + (size_t)(n + 1) * sizeof(tcc_idx) + 16;
    char *block = malloc(bytes);
    if (!block) return tcc_fail(err, TCC_ERR_NOMEM, "no memory for %lld swept rows", (long long)rows);
    tcc_idx *rv = (tcc_idx *)block, *start = rv + rows;
    double *rdepth = (double *)(start + n + 1), *rn = rdepth + rows, *rvel = rn + 3 * rows;
    /* swept.py's order: live vertex-triangle, live edge-edge, predicted vertex-triangle, predicted edge-edge */
    tcc_idx r = 0;
    for (int part = 0; part < 2; part++)
        for (int k = 0; k < 2; k++) {
            const tcc_swept_kind *K = &kind[k];
            tcc_idx from = part ? K->nlive : 0, to = part ? K->nlive + K->npred : K->nlive;
            r += kind_rows(K, from, to, v, rv + r, rdepth + r, rn + 3 * r, rvel + 3 * r);
        }
    /* parallel edges or a collapsed triangle have no normal: no direction to hold them apart */
    tcc_idx kept = 0, bad = 0;
    for (tcc_idx i = 0; i < rows; i++) {
        if (!(dot3(rn + 3 * i, rn + 3 * i) > 0.25)) {
            bad++;
            rv[i] = -1;
            continue;
        }
        kept++;
    }
    *no_normal = bad;
    *count = ne + kept;
    if (ne + kept > cap) {
        free(block);
        return TCC_OK; /* the caller retries with room for *count */
    }
    /* stable merge by vertex: the colliders' contacts of a vertex first, then its swept rows in order */
    memset(start, 0, sizeof(tcc_idx) * (size_t)(n + 1));
    for (tcc_idx i = 0; i < ne; i++) start[ev[i] + 1]++;
    for (tcc_idx i = 0; i < rows; i++)
        if (rv[i] >= 0) start[rv[i] + 1]++;
    for (tcc_idx u = 0; u < n; u++) start[u + 1] += start[u];
    for (tcc_idx i = 0; i < ne; i++) {
        tcc_idx o = start[ev[i]]++;
        ov[o] = ev[i];
        odepth[o] = edepth[i];
        ofric[o] = efric[i];
        for (int c = 0; c < 3; c++) {
            onormal[3 * o + c] = enormal[3 * i + c];
            ovel[3 * o + c] = evel[3 * i + c];
        }
    }
    for (tcc_idx i = 0; i < rows; i++) {
        if (rv[i] < 0) continue;
        tcc_idx o = start[rv[i]]++;
        ov[o] = (int32_t)rv[i];
        odepth[o] = rdepth[i];
        ofric[o] = friction;
        for (int c = 0; c < 3; c++) {
            onormal[3 * o + c] = rn[3 * i + c];
            ovel[3 * o + c] = rvel[3 * i + c];
        }
    }
    free(block);
    return TCC_OK;
}

/* ------------------------------------------------------------------ the stage's pairs and blocks
 *
 * Built once per topology (after every tear): the two-ring pairs the rays skip and the cull's blocks.
 * Why in C: the former numpy built them with np.unique over ~0.7 million candidate rows, ~0.35 s per
 * tear on the shirt - in a tearing bake more than the rest of collision put together. Here every
 * list is built in the order np.unique gave (rows ascending), so the pairs, blocks and results are
 * the same. */


/* ascending, in place: the short lists of one edge or one block (tens of entries) */
static void sort_small(tcc_idx *a, tcc_idx n)
{
    for (tcc_idx i = 1; i < n; i++) {
        tcc_idx v = a[i], j = i;
        while (j > 0 && a[j - 1] > v) {
            a[j] = a[j - 1];
            j--;
        }
        a[j] = v;
    }
}

static int cmp_pair(const void *a, const void *b)
{
    const tcc_idx *x = a, *y = b;
    if (x[0] != y[0]) return x[0] < y[0] ? -1 : 1;
    return x[1] < y[1] ? -1 : x[1] > y[1];
}

int tcc_swept_pairs(const tcc_idx *tri, tcc_idx nt, tcc_idx n, const tcc_ring *ring, tcc_idx *edges, tcc_idx ecap,
                    tcc_idx *vt, tcc_idx vcap, tcc_idx *ee, tcc_idx ecap2, tcc_idx *ne, tcc_idx *nvt, tcc_idx *nee,
                    tcc_error *err)
{
    *ne = *nvt = *nee = 0;
    if (ring->rows < n) return tcc_fail(err, TCC_ERR_VALUE, "the ring table needs a row per vertex (%lld)", (long long)n);
    for (tcc_idx i = 0; i < 3 * nt; i++)
        if (tri[i] < 0 || tri[i] >= n)
            return tcc_fail(err, TCC_ERR_INDEX, "triangles[%lld, %lld] = %lld is not a vertex index in [0, %lld)",
                            (long long)(i / 3), (long long)(i % 3), (long long)tri[i], (long long)n);
    const tcc_idx W = ring->width;
    for (tcc_idx i = 0; i < n * W; i++)
        if (ring->table[i] < -1 || ring->table[i] >= n)
            return tcc_fail(err, TCC_ERR_INDEX, "ring entry %lld is not a vertex index (or -1)", (long long)ring->table[i]);
    int rc = TCC_OK;
    size_t cand = (size_t)nt * 3 * (size_t)(W > 0 ? W : 1);
    tcc_idx *e2 = malloc(sizeof(tcc_idx) * 6 * (size_t)(nt > 0 ? nt : 1));
    tcc_idx *stamp = malloc(sizeof(tcc_idx) * (size_t)(n > 0 ? n : 1));
    tcc_idx *list = malloc(sizeof(tcc_idx) * 2 * (cand > 0 ? cand : 1));
    tcc_idx *cnt = calloc((size_t)n + 1, sizeof(tcc_idx));
    tcc_idx *eptr = calloc((size_t)n + 1, sizeof(tcc_idx)), *einc = NULL, *small = NULL;
    if (!e2 || !stamp || !list || !cnt || !eptr) {
        rc = tcc_fail(err, TCC_ERR_NOMEM, "no memory for the two-ring pairs of %lld triangles", (long long)nt);
        goto done;
    }
    /* the edges (min, max), ascending and once each */
    for (tcc_idx t = 0; t < nt; t++)
        for (int k = 0; k < 3; k++) {
            tcc_idx a = tri[3 * t + k], b = tri[3 * t + (k + 1) % 3];
            e2[2 * (3 * t + k)] = a < b ? a : b;
            e2[2 * (3 * t + k) + 1] = a < b ? b : a;
        }
    qsort(e2, (size_t)(3 * nt), 2 * sizeof(tcc_idx), cmp_pair);
    tcc_idx m = 0;
    for (tcc_idx i = 0; i < 3 * nt; i++)
        if (i == 0 || e2[2 * i] != e2[2 * (i - 1)] || e2[2 * i + 1] != e2[2 * (i - 1) + 1]) {
            if (m < ecap) {
                edges[2 * m] = e2[2 * i];
                edges[2 * m + 1] = e2[2 * i + 1];
            }
            m++;
        }
    *ne = m;
    if (m > ecap) goto done; /* the caller calls again with room */
    /* vertex-triangle: (u, t) with u in the ring of a corner of t and not a corner; by u, then t */
    for (tcc_idx v = 0; v < n; v++) stamp[v] = -1;
    size_t nl = 0;
    for (tcc_idx t = 0; t < nt; t++) {
        const tcc_idx *c = tri + 3 * t;
        for (int k = 0; k < 3; k++)
            for (tcc_idx w = 0; w < W; w++) {
                tcc_idx u = ring->table[c[k] * W + w];
                if (u < 0 || u == c[0] || u == c[1] || u == c[2] || stamp[u] == t) continue;
                stamp[u] = t;
                list[2 * nl] = u;
                list[2 * nl + 1] = t;
                nl++;
                cnt[u + 1]++;
            }
    }
    *nvt = (tcc_idx)nl;
    if ((tcc_idx)nl <= vcap) {
        /* counting sort by u (t ascends within each u: the triangles were visited in order) */
        for (tcc_idx v = 0; v < n; v++) cnt[v + 1] += cnt[v];
        for (size_t i = 0; i < nl; i++) {
            tcc_idx o = cnt[list[2 * i]]++;
            vt[2 * o] = list[2 * i];
            vt[2 * o + 1] = list[2 * i + 1];
        }
    }
    /* edge-edge: (a, b), a < b, no shared vertex, an end of b in the ring of an end of a; ascending */
    for (tcc_idx i = 0; i < m; i++) {
        eptr[edges[2 * i] + 1]++;
        eptr[edges[2 * i + 1] + 1]++;
    }
    for (tcc_idx v = 0; v < n; v++) eptr[v + 1] += eptr[v];
    einc = malloc(sizeof(tcc_idx) * (size_t)(2 * m + 1));
    small = malloc(sizeof(tcc_idx) * (size_t)(2 * m + 1));
    if (!einc || !small) {
        rc = tcc_fail(err, TCC_ERR_NOMEM, "no memory for the edges of %lld triangles", (long long)nt);
        goto done;
    }
    {
        tcc_idx *fill = cnt; /* reused: n + 1 entries */
        memcpy(fill, eptr, sizeof(tcc_idx) * (size_t)(n + 1));
        for (tcc_idx i = 0; i < m; i++) { /* edges ascend: each vertex's list ascends too */
            einc[fill[edges[2 * i]]++] = i;
            einc[fill[edges[2 * i + 1]]++] = i;
        }
    }
    for (tcc_idx v = 0; v < n; v++) stamp[v] = -1;
    /* stamp now marks edges (m entries may exceed n): a second stamp array */
    tcc_idx *estamp = malloc(sizeof(tcc_idx) * (size_t)(m > 0 ? m : 1));
    if (!estamp) {
        rc = tcc_fail(err, TCC_ERR_NOMEM, "no memory for %lld edges", (long long)m);
        goto done;
    }
    for (tcc_idx i = 0; i < m; i++) estamp[i] = -1;
    tcc_idx q = 0;
    for (tcc_idx a = 0; a < m; a++) {
        tcc_idx a0 = edges[2 * a], a1 = edges[2 * a + 1], ns = 0;
        for (int end = 0; end < 2; end++) {
            tcc_idx x = end ? a1 : a0;
            for (tcc_idx w = 0; w < W; w++) {
                tcc_idx u = ring->table[x * W + w];
                if (u < 0) continue;
                for (tcc_idx j = eptr[u]; j < eptr[u + 1]; j++) {
                    tcc_idx b = einc[j];
                    if (b <= a || estamp[b] == a) continue;
                    estamp[b] = a;
                    tcc_idx b0 = edges[2 * b], b1 = edges[2 * b + 1];
                    if (a0 == b0 || a0 == b1 || a1 == b0 || a1 == b1) continue;
                    small[ns++] = b;
                }
            }
        }
        sort_small(small, ns);
        for (tcc_idx i = 0; i < ns; i++, q++)
            if (q < ecap2) {
                ee[2 * q] = a;
                ee[2 * q + 1] = small[i];
            }
    }
    *nee = q;
    free(estamp);
done:
    free(e2);
    free(stamp);
    free(list);
    free(cnt);
    free(eptr);
    free(einc);
    free(small);
    return rc;
}

int tcc_swept_blocks(const tcc_idx *quad, tcc_idx k, tcc_idx size, const tcc_idx *group, tcc_idx n, tcc_idx *bptr,
                     tcc_idx *bvptr, tcc_idx *bverts, tcc_idx *bgptr, tcc_idx *bgroups, tcc_error *err)
{
    if (size < 1) return tcc_fail(err, TCC_ERR_VALUE, "blocks need at least one pair, got %lld", (long long)size);
    tcc_idx nb = (k + size - 1) / size, nv = 0, ng = 0, ngr = 0;
    for (tcc_idx v = 0; v < n; v++)
        if (group[v] >= ngr) ngr = group[v] + 1;
    tcc_idx *vstamp = malloc(sizeof(tcc_idx) * (size_t)(n > 0 ? n : 1));
    tcc_idx *gstamp = malloc(sizeof(tcc_idx) * (size_t)(ngr > 0 ? ngr : 1));
    if (!vstamp || !gstamp) {
        free(vstamp);
        free(gstamp);
        return tcc_fail(err, TCC_ERR_NOMEM, "no memory for blocks over %lld vertices", (long long)n);
    }
    for (tcc_idx v = 0; v < n; v++) vstamp[v] = -1;
    for (tcc_idx g = 0; g < ngr; g++) gstamp[g] = -1;
    for (tcc_idx b = 0; b < nb; b++) {
        tcc_idx q0 = b * size, q1 = q0 + size < k ? q0 + size : k;
        bptr[b] = q0;
        bvptr[b] = nv;
        bgptr[b] = ng;
        /* the block's distinct vertices (stamped), then ascending; the same for their groups */
        for (tcc_idx q = q0; q < q1; q++)
            for (int j = 0; j < 4; j++) {
                tcc_idx v = quad[4 * q + j];
                if (v < 0 || v >= n) {
                    free(vstamp);
                    free(gstamp);
                    return tcc_fail(err, TCC_ERR_INDEX, "pair %lld: vertex %lld is not in [0, %lld)", (long long)q,
                                    (long long)v, (long long)n);
                }
                if (vstamp[v] == b) continue;
                vstamp[v] = b;
                bverts[nv++] = v;
                tcc_idx g = group[v];
                if (gstamp[g] == b) continue;
                gstamp[g] = b;
                bgroups[ng++] = g;
            }
        sort_small(bverts + bvptr[b], nv - bvptr[b]);
        sort_small(bgroups + bgptr[b], ng - bgptr[b]);
    }
    bptr[nb] = k;
    bvptr[nb] = nv;
    bgptr[nb] = ng;
    free(vstamp);
    free(gstamp);
    return TCC_OK;
}
