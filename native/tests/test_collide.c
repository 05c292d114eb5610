/* test_collide.c - native tests of the collision kernels (native/collide/, no Python), built with
 * AddressSanitizer and UndefinedBehaviorSanitizer by native/tests/run_sanitizers.sh. A cloth grid
 * deforms step by step over a closed box body that moves; every step runs the per-step kernels a
 * detection runs (normals, cluster motion, boxes, pairs, the relative measure, rays,
 * refinement of candidate hits, walks), the grid is then "torn" (a row of vertices duplicated,
 * triangles re-indexed) and run again, and bad indices must come back as errors. Each check prints and counts; the exit code is the number of
 * failures. */
#include "collide.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static int failures, checks;
#define CHECK(cond, ...) do { checks++; if (!(cond)) { failures++; printf("FAIL %s:%d: ", __FILE__, __LINE__); printf(__VA_ARGS__); printf("\n"); } } while (0)

enum { NX = 24, NY = 24 };

typedef struct {
    double *x;
    tcc_idx *tri;
    tcc_idx nv, nt;
} mesh;

static mesh grid(void)
{
    mesh m = {malloc(sizeof(double) * 3 * (NX * NY + NY)), malloc(sizeof(tcc_idx) * 6 * (NX - 1) * (NY - 1)), NX * NY,
              2 * (NX - 1) * (NY - 1)};
    for (int i = 0; i < NX; i++)
        for (int j = 0; j < NY; j++) {
            double *p = m.x + 3 * (i * NY + j);
            p[0] = -0.3 + 0.6 * i / (NX - 1);
            p[1] = -0.3 + 0.6 * j / (NY - 1);
            p[2] = 0.0;
        }
    tcc_idx k = 0;
    for (int i = 0; i < NX - 1; i++)
        for (int j = 0; j < NY - 1; j++) {
            tcc_idx a = i * NY + j, b = (i + 1) * NY + j, c = (i + 1) * NY + j + 1, d = i * NY + j + 1;
            tcc_idx *t = m.tri + 3 * k;
            t[0] = a; t[1] = b; t[2] = c; t[3] = a; t[4] = c; t[5] = d;
            k += 2;
        }
    return m;
}

/* closed box, outward winding: 8 corners, 12 triangles */
static const tcc_idx BOX_T[36] = {0, 2, 1, 0, 3, 2, 4, 5, 6, 4, 6, 7, 0, 1, 5, 0, 5, 4,
                                  1, 2, 6, 1, 6, 5, 2, 3, 7, 2, 7, 6, 3, 0, 4, 3, 4, 7};

static void box_at(double *x, double cx, double cy, double cz)
{
    static const double s[8][3] = {{-1, -1, -1}, {1, -1, -1}, {1, 1, -1}, {-1, 1, -1},
                                   {-1, -1, 1},  {1, -1, 1},  {1, 1, 1},  {-1, 1, 1}};
    for (int v = 0; v < 8; v++) {
        x[3 * v] = cx + 0.1 * s[v][0];
        x[3 * v + 1] = cy + 0.1 * s[v][1];
        x[3 * v + 2] = cz + 0.05 * s[v][2];
    }
}

/* clusters of the grid: k strips of rows (order = identity, ptr by rows), triangles by the same */
static void strips(tcc_idx nv, tcc_idx nt, tcc_idx k, tcc_idx *order, tcc_idx *ptr, tcc_idx *tptr)
{
    for (tcc_idx v = 0; v < nv; v++) order[v] = v;
    for (tcc_idx c = 0; c <= k; c++) {
        ptr[c] = nv * c / k;
        tptr[c] = nt * c / k;
    }
}

static void test_measure_and_detection_steps(mesh *m)
{
    enum { K = 6, KB = 2 };
    tcc_idx order[NX * NY + NY], ptr[K + 1], tptr[K + 1];
    strips(m->nv, m->nt, K, order, ptr, tptr);
    double *prev = malloc(sizeof(double) * 3 * m->nv), *normals = malloc(sizeof(double) * 3 * m->nv);
    uint8_t *has = malloc(m->nv);
    double avg[3 * K], dev[K], lo[3 * K], hi[3 * K];
    double bx[24], bprev[24], bavg[3 * KB], bdev[KB], blo[3 * KB], bhi[3 * KB];
    tcc_idx border[8] = {0, 1, 2, 3, 4, 5, 6, 7}, bptr[KB + 1] = {0, 4, 8};
    tcc_idx old_keys[K * KB], keys[K * KB], pi[K * KB], pj[K * KB], np_ = 0, nold = 0, nfull;
    double old_avg[3 * K * KB], old_dev[K * KB], rel_avg[3 * K * KB], rel_dev[K * KB], amp[K * KB];
    uint8_t full[K * KB];
    /* the trip rule's state beside the paper's (measure.c) */
    double fit_c[TCC_FIT_LEN * K], fit_b[TCC_FIT_LEN * KB], bound[K * KB], t_used_old[K * KB], t_used[K * KB];
    tcc_idx t_keys_old[K * KB], t_keys[K * KB], t_nold = 0, t_nfull = 0;
    int t_tripped = 0;
    tcc_error err = {0};
    memcpy(prev, m->x, sizeof(double) * 3 * m->nv);
    box_at(bx, 0.0, 0.0, -0.2);
    memcpy(bprev, bx, sizeof bx);
    tcc_mesh cloth = {m->x, m->nv, m->tri, m->nt, NULL, NULL};
    int tripped = 0, refined = 0;
    for (int step = 0; step < 30; step++) {
        box_at(bx, 0.0, 0.0, -0.2 + 0.01 * step); /* rises through the cloth */
        for (tcc_idx v = 0; v < m->nv; v++) m->x[3 * v + 2] = 0.003 * sin(8.0 * m->x[3 * v] + 0.5 * step);
        CHECK(tcc_vertex_normals(&cloth, normals, has, &err) == TCC_OK, "normals: %s", err.what);
        CHECK(tcc_cluster_motion(m->x, prev, m->nv, order, m->nv, ptr, K, avg, dev, &err) == TCC_OK,
              "motion: %s", err.what);
        for (int c = 0; c < K; c++) CHECK(dev[c] >= 0 && isfinite(dev[c]), "a deviation is a finite distance");
        CHECK(tcc_cluster_motion(bx, bprev, 8, border, 8, bptr, KB, bavg, bdev, &err) == TCC_OK, "body");
        CHECK(tcc_cluster_boxes(m->x, m->nv, order, m->nv, ptr, K, 0.002, lo, hi, &err) == TCC_OK, "boxes");
        CHECK(tcc_cluster_boxes(bx, 8, border, 8, bptr, KB, 0.002, blo, bhi, &err) == TCC_OK, "body boxes");
        tcc_box_pairs(lo, hi, K, blo, bhi, KB, 0, pi, pj, K * KB, &np_);
        CHECK(np_ <= K * KB, "pairs fit");
        CHECK(tcc_relative_measure(old_keys, old_avg, old_dev, nold, pi, pj, np_, avg, dev, K, bavg, bdev, KB,
                                   NULL, 0.01, 3.0, keys, rel_avg, rel_dev, amp, full, &nfull, &err) == TCC_OK,
              "measure: %s", err.what);
        tripped += nfull > 0;
        CHECK(tcc_cluster_fit(m->x, prev, m->nv, order, m->nv, ptr, K, 0.01, fit_c, &err) == TCC_OK, "fit: %s",
              err.what);
        CHECK(tcc_cluster_fit(bx, bprev, 8, border, 8, bptr, KB, 0.01, fit_b, &err) == TCC_OK, "body fit");
        CHECK(tcc_pair_motion(pi, pj, np_, m->x, prev, order, ptr, fit_c, K, bx, bprev, border, bptr, fit_b, KB, 0.01,
                              bound, &err) == TCC_OK, "pair motion: %s", err.what);
        /* the box rises 10 mm per step, the cloth's wave moves it by at most 1.5 mm: every pair's bound
         * covers the 8.5 mm left of relative motion */
        for (tcc_idx p = 0; p < np_; p++) CHECK(bound[p] >= 0.0 && (step == 0 || bound[p] >= 0.0085), "bound %g", bound[p]);
        CHECK(tcc_trip_measure(t_keys_old, t_used_old, t_nold, pi, pj, np_, bound, lo, hi, K, blo, bhi, KB, 0.002,
                               0.0015, 0.002, NULL, 1.0, t_keys, t_used, amp, full, &t_nfull, &err) == TCC_OK,
              "trip measure: %s", err.what);
        for (tcc_idx p = 0; p < np_; p++) CHECK(t_used[p] >= 0.0 && t_used[p] <= 0.0015, "spent clearance in range");
        t_tripped += t_nfull > 0;
        memcpy(t_keys_old, t_keys, sizeof(tcc_idx) * np_);
        memcpy(t_used_old, t_used, sizeof(double) * np_);
        t_nold = np_;
        memcpy(old_keys, keys, sizeof(tcc_idx) * np_);
        memcpy(old_avg, rel_avg, sizeof(double) * 3 * np_);
        memcpy(old_dev, rel_dev, sizeof(double) * np_);
        nold = np_;
        /* rays of every pair into the body (world frame: identity transforms) */
        if (np_ > 0) {
            double R[9 * KB], cen[3 * KB] = {0}, ref[3 * KB] = {0};
            for (int b = 0; b < KB; b++)
                for (int q = 0; q < 9; q++) R[9 * b + q] = q % 4 == 0;
            tcc_idx ub[KB], q = 0, sa[K * KB], sb[K * KB], ns = 0;
            for (int b = 0; b < KB; b++) {
                int any = 0;
                for (tcc_idx p = 0; p < np_; p++)
                    if (pj[p] == b) {
                        sa[ns] = pi[p];
                        sb[ns++] = b;
                        any = 1;
                    }
                if (any) ub[q++] = b;
            }
            tcc_ray_setup rs = {m->x, normals, has, NULL, m->nv, order, ptr, m->nv, K, blo, bhi, KB, 0.5, 0.5, 1e-6, 0.0};
            tcc_idx cap = 2 * m->nv, count = 0, seg[KB + 1];
            float *o = malloc(sizeof(float) * 3 * cap), *d = malloc(sizeof(float) * 3 * cap), *dist = malloc(sizeof(float) * cap);
            tcc_idx *rv = malloc(sizeof(tcc_idx) * cap), *rslot = malloc(sizeof(tcc_idx) * cap), *hit = malloc(sizeof(tcc_idx) * cap);
            double *ht = malloc(sizeof(double) * cap);
            CHECK(tcc_prepare_rays(&rs, sa, sb, ns, ub, R, cen, ref, q, o, d, dist, rv, rslot, cap, seg, &count, &err) ==
                      TCC_OK, "rays: %s", err.what);
            CHECK(count <= cap, "rays fit");
            /* the candidate hits: each ray's first hit among the body's 12 triangles, exhaustively
             * (what a scene query returns), so refine and walk run on real candidates */
            for (tcc_idx r = 0; r < count; r++) {
                double oo[3] = {o[3 * r], o[3 * r + 1], o[3 * r + 2]}, dd[3] = {d[3 * r], d[3 * r + 1], d[3 * r + 2]};
                hit[r] = -1;
                ht[r] = INFINITY;
                for (tcc_idx f = 0; f < 12; f++) {
                    const tcc_idx *tv = BOX_T + 3 * f;
                    double t, u, w;
                    if (!tcc_line_triangle(oo, dd, bx + 3 * tv[0], bx + 3 * tv[1], bx + 3 * tv[2], &t, &u, &w)) continue;
                    if (t >= 0 && t <= dist[r] && u >= 0 && w >= 0 && u + w <= 1 && t < ht[r]) {
                        ht[r] = t;
                        hit[r] = f;
                    }
                }
            }
            tcc_idx *ov = malloc(sizeof(tcc_idx) * (count + 1)), *os = malloc(sizeof(tcc_idx) * (count + 1));
            tcc_idx *otri = malloc(sizeof(tcc_idx) * (count + 1));
            double *ot = malloc(sizeof(double) * (count + 1)), *ou = malloc(sizeof(double) * (count + 1)),
                   *ovv = malloc(sizeof(double) * (count + 1));
            uint8_t *of = malloc(count + 1), *st = malloc(count + 1);
            tcc_hits out = {otri, ot, ou, ovv, of};
            tcc_idx kept = 0;
            tcc_idx adj[36];
            uint8_t flip[36] = {0};
            for (int i = 0; i < 36; i++) adj[i] = -1;
            tcc_mesh bodyw = {bx, 8, BOX_T, 12, adj, flip};
            CHECK(tcc_refine(m->x, normals, m->nv, rv, rslot, hit, count, &bodyw, NULL, TCC_VOLUME, 0.01, NULL, ov, os, out,
                             st, &kept, &err) == TCC_OK, "refine: %s", err.what);
            CHECK(kept <= count, "refined hits fit");
            refined += kept > 0;
            /* walks of the kept hits from their own triangles stay on them */
            if (kept > 0) {
                tcc_hits wout = {otri, ot, ou, ovv, of};
                tcc_idx *start = malloc(sizeof(tcc_idx) * kept);
                memcpy(start, otri, sizeof(tcc_idx) * kept);
                CHECK(tcc_walk(m->x, normals, m->nv, ov, os, start, kept, &bodyw, NULL, 4, wout, &err) == TCC_OK,
                      "walk: %s", err.what);
                free(start);
            }
            free(o); free(d); free(dist); free(rv); free(rslot); free(hit); free(ht);
            free(ov); free(os); free(otri); free(ot); free(ou); free(ovv); free(of); free(st);
        }
        memcpy(prev, m->x, sizeof(double) * 3 * m->nv);
        memcpy(bprev, bx, sizeof bx);
    }
    CHECK(tripped > 0, "the rising body trips full detection");
    CHECK(t_tripped > 0, "the rising body trips the trip rule too");
    CHECK(refined > 0, "rays found the body and were refined on it");
    /* bad indices are errors */
    order[0] = m->nv + 5;
    CHECK(tcc_cluster_motion(m->x, prev, m->nv, order, m->nv, ptr, K, avg, dev, &err) == TCC_ERR_INDEX,
          "bad member");
    order[0] = 0;
    free(prev);
    free(normals);
    free(has);
}

/* a tear: the middle row of vertices is duplicated and the triangles on one side use the copies */
static void tear(mesh *m)
{
    tcc_idx mid = NX / 2;
    for (int j = 0; j < NY; j++) {
        tcc_idx src = mid * NY + j, dst = m->nv + j;
        memcpy(m->x + 3 * dst, m->x + 3 * src, sizeof(double) * 3);
    }
    for (tcc_idx f = 0; f < m->nt; f++) {
        tcc_idx *t = m->tri + 3 * f;
        int right = 0;
        for (int q = 0; q < 3; q++) right |= t[q] / NY > mid;
        if (!right) continue;
        for (int q = 0; q < 3; q++)
            if (t[q] / NY == mid) t[q] = m->nv + t[q] % NY;
    }
    m->nv += NY;
}

/* The swept kernels (ccd.c) on the grid: vertex 0 is driven through the middle of a far triangle,
 * every other point at rest; among all its pairs exactly that triangle is hit, half way, from
 * above; one edge is driven through another; bad pairs are errors, not reads out of bounds. */
static void test_ccd(const mesh *m)
{
    size_t nx = 3 * (size_t)m->nv;
    double *x0 = malloc(sizeof(double) * nx), *x1 = malloc(sizeof(double) * nx);
    memcpy(x0, m->x, sizeof(double) * nx);
    memcpy(x1, m->x, sizeof(double) * nx);
    tcc_idx far = m->nt / 2;
    double c[3] = {0, 0, 0};
    for (int k = 0; k < 3; k++)
        for (int i = 0; i < 3; i++) c[i] += m->x[3 * m->tri[3 * far + k] + i] / 3.0;
    /* the far triangle's unit normal (the grid was deformed by the detection steps) */
    const double *ta = m->x + 3 * m->tri[3 * far], *tb = m->x + 3 * m->tri[3 * far + 1], *tc = m->x + 3 * m->tri[3 * far + 2];
    double e1[3], e2[3], nh[3];
    for (int i = 0; i < 3; i++) { e1[i] = tb[i] - ta[i]; e2[i] = tc[i] - ta[i]; }
    nh[0] = e1[1] * e2[2] - e1[2] * e2[1];
    nh[1] = e1[2] * e2[0] - e1[0] * e2[2];
    nh[2] = e1[0] * e2[1] - e1[1] * e2[0];
    double ln = sqrt(nh[0] * nh[0] + nh[1] * nh[1] + nh[2] * nh[2]);
    for (int i = 0; i < 3; i++) nh[i] /= ln;
    for (int i = 0; i < 3; i++) { x0[i] = c[i] + 0.01 * nh[i]; x1[i] = c[i] - 0.01 * nh[i]; }
    tcc_idx *pv = malloc(sizeof(tcc_idx) * (size_t)m->nt), *pt = malloc(sizeof(tcc_idx) * (size_t)m->nt);
    tcc_idx k = 0;
    for (tcc_idx t = 0; t < m->nt; t++) {
        const tcc_idx *q = m->tri + 3 * t;
        if (q[0] == 0 || q[1] == 0 || q[2] == 0) continue;
        pv[k] = 0; pt[k] = t; k++;
    }
    double *toi = malloc(sizeof(double) * (size_t)k), *w = malloc(sizeof(double) * 3 * (size_t)k);
    int8_t *side = malloc((size_t)k);
    tcc_idx hits = -1;
    tcc_error err = {0};
    int rc = tcc_ccd_vertex_triangle(x0, x1, m->nv, m->tri, m->nt, pv, pt, k, 0.0, NULL, toi, w, side, &hits, &err);
    CHECK(rc == TCC_OK && hits == 1, "vertex through a triangle: rc %d, %lld hits", rc, (long long)hits);
    for (tcc_idx q = 0; q < k; q++)
        if (pt[q] == far) {
            CHECK(fabs(toi[q] - 0.5) < 1e-9, "time of impact %g, not 0.5", toi[q]);
            CHECK(side[q] == 1, "side %d of a vertex coming from the normal's side", side[q]);
            CHECK(fabs(w[3 * q] - 1.0 / 3) < 1e-9 && fabs(w[3 * q + 1] - 1.0 / 3) < 1e-9, "weights %g %g", w[3 * q], w[3 * q + 1]);
        }
    /* the carried distance bound (tcc_ccd_cull): unknown bounds hand every pair out and are made
       exact at x1; then with no motion only the pairs within their gap come out again (the driven
       vertex sits at the far triangle's centre - 1 cm below it); bad input is an error */
    {
        tcc_idx *quad = malloc(sizeof(tcc_idx) * 4 * (size_t)k), *out = malloc(sizeof(tcc_idx) * (size_t)k);
        double *gapq = malloc(sizeof(double) * (size_t)k), *slack = malloc(sizeof(double) * (size_t)k);
        double *disp = calloc(nx, sizeof(double));
        for (tcc_idx q = 0; q < k; q++) {
            quad[4 * q] = pv[q];
            for (int j = 0; j < 3; j++) quad[4 * q + 1 + j] = m->tri[3 * pt[q] + j];
            gapq[q] = 0.002;
            slack[q] = -INFINITY;
        }
        for (int i = 0; i < 3; i++) disp[i] = x1[i] - x0[i];
        tcc_idx nout = -1;
        rc = tcc_ccd_cull(x1, m->nv, quad, k, 1, disp, gapq, slack, 1, out, &nout, &err);
        CHECK(rc == TCC_OK && nout == k, "unknown bounds: rc %d, %lld of %lld handed out", rc, (long long)nout, (long long)k);
        int finite = 1;
        for (tcc_idx q = 0; q < k; q++) finite &= isfinite(slack[q]);
        CHECK(finite, "every bound made exact");
        memset(disp, 0, sizeof(double) * nx);
        rc = tcc_ccd_cull(x1, m->nv, quad, k, 1, disp, gapq, slack, 1, out, &nout, &err);
        tcc_idx close = 0;
        for (tcc_idx q = 0; q < k; q++) close += slack[q] <= 0;
        CHECK(rc == TCC_OK && nout == close && nout < k, "still: rc %d, %lld handed out, %lld within their gap of %lld",
              rc, (long long)nout, (long long)close, (long long)k);
        tcc_error c1 = {0}, c2 = {0}, c3 = {0};
        CHECK(tcc_ccd_cull(x1, m->nv, quad, k, 3, disp, gapq, slack, 0, out, &nout, &c1) == TCC_ERR_VALUE, "split 3 is a value error");
        disp[4] = NAN;
        CHECK(tcc_ccd_cull(x1, m->nv, quad, k, 1, disp, gapq, slack, 0, out, &nout, &c2) == TCC_ERR_VALUE, "a NaN displacement is a value error");
        disp[4] = 0.0;
        quad[4 * (k - 1) + 2] = m->nv;
        CHECK(tcc_ccd_cull(x1, m->nv, quad, k, 2, disp, gapq, slack, 0, out, &nout, &c3) == TCC_ERR_INDEX, "a vertex out of range is an index error");
        quad[4 * (k - 1) + 2] = m->tri[3 * pt[k - 1] + 1];
        /* by blocks (tcc_ccd_cull_blocks) of 3 pairs, each with its pairs' corners: unknown bounds hand
           every pair out; still, the same pairs as pairwise; a block moved rigidly is skipped unread
           (its debt grows by 0, a corrupt quad in it goes unnoticed) while a block whose vertices move
           apart is read; bad blocks are errors */
        tcc_idx nb = (k + 2) / 3, *bptr = malloc(sizeof(tcc_idx) * (size_t)(nb + 1));
        tcc_idx *bvptr = malloc(sizeof(tcc_idx) * (size_t)(nb + 1)), *bv = malloc(sizeof(tcc_idx) * 4 * (size_t)k);
        double *bmin = malloc(sizeof(double) * (size_t)nb), *bdebt = calloc((size_t)nb, sizeof(double));
        tcc_idx nbv = 0;
        for (tcc_idx b = 0; b < nb; b++) {
            bptr[b] = 3 * b;
            bvptr[b] = nbv;
            for (tcc_idx q = 3 * b; q < 3 * b + 3 && q < k; q++)
                for (int j = 0; j < 4; j++) bv[nbv++] = quad[4 * q + j];  /* repeats are allowed */
            bmin[b] = -INFINITY;
        }
        bptr[nb] = k;
        bvptr[nb] = nbv;
        for (tcc_idx q = 0; q < k; q++) slack[q] = -INFINITY;
        rc = tcc_ccd_cull_blocks(x1, m->nv, quad, k, 1, disp, gapq, slack, 1, bptr, nb, bvptr, bv, nbv, bmin, bdebt, out,
                                 &nout, NULL, NULL, NULL, &err);
        CHECK(rc == TCC_OK && nout == k, "blocks, unknown bounds: rc %d, %lld of %lld handed out", rc, (long long)nout, (long long)k);
        rc = tcc_ccd_cull_blocks(x1, m->nv, quad, k, 1, disp, gapq, slack, 1, bptr, nb, bvptr, bv, nbv, bmin, bdebt, out,
                                 &nout, NULL, NULL, NULL, &err);
        CHECK(rc == TCC_OK && nout == close, "blocks, still: rc %d, %lld handed out, %lld within their gap", rc,
              (long long)nout, (long long)close);
        tcc_idx open_blocks = 0;
        for (tcc_idx b = 0; b < nb; b++) open_blocks += !(bmin[b] > 0);
        CHECK(open_blocks < nb, "%lld of %lld blocks hold a pair within its gap: nothing to skip", (long long)open_blocks, (long long)nb);
        for (tcc_idx v = 0; v < m->nv; v++) disp[3 * v] = 1e-3;  /* a rigid shift: no relative motion */
        tcc_idx far_b = 0;
        while (far_b < nb - 1 && !(bmin[far_b] > 1e-3)) far_b++;
        CHECK(bmin[far_b] > 1e-3, "no block 1 mm clear of its gaps");
        tcc_idx saved = quad[4 * bptr[far_b]];
        quad[4 * bptr[far_b]] = m->nv;  /* read, this would be an index error */
        rc = tcc_ccd_cull_blocks(x1, m->nv, quad, k, 1, disp, gapq, slack, 1, bptr, nb, bvptr, bv, nbv, bmin, bdebt, out,
                                 &nout, NULL, NULL, NULL, &err);
        CHECK(rc == TCC_OK && nout == close && bdebt[far_b] == 0.0, "blocks, rigid shift: rc %d, %lld handed out, debt %g",
              rc, (long long)nout, bdebt[far_b]);
        quad[4 * bptr[far_b]] = saved;
        double before = bmin[far_b];
        for (tcc_idx v = 0; v < m->nv; v++) disp[3 * v] = 1e-4 * (double)(v % 2);  /* neighbours 0.1 mm apart */
        rc = tcc_ccd_cull_blocks(x1, m->nv, quad, k, 1, disp, gapq, slack, 0, bptr, nb, bvptr, bv, nbv, bmin, bdebt, out,
                                 &nout, NULL, NULL, NULL, &err);
        CHECK(rc == TCC_OK && nout >= close && bmin[far_b] == before && bdebt[far_b] == 0.0,
              "blocks, predicted (nothing carried): rc %d, %lld handed out", rc, (long long)nout);
        rc = tcc_ccd_cull_blocks(x1, m->nv, quad, k, 1, disp, gapq, slack, 1, bptr, nb, bvptr, bv, nbv, bmin, bdebt, out,
                                 &nout, NULL, NULL, NULL, &err);
        int parity[2] = {0, 0};
        for (tcc_idx i = bvptr[far_b]; i < bvptr[far_b + 1]; i++) parity[bv[i] % 2] = 1;
        double want = (parity[0] && parity[1]) ? 1e-4 : 0.0;
        CHECK(rc == TCC_OK && nout >= close && fabs(bdebt[far_b] - want) < 1e-12,
              "blocks, relative motion charged as debt: rc %d, debt %g, want %g", rc, bdebt[far_b], want);
        /* a second (predicted) motion in the same pass: the same as a second call without update */
        {
            double *slack2 = malloc(sizeof(double) * (size_t)k), *bmin2 = malloc(sizeof(double) * (size_t)nb);
            double *bdebt2 = malloc(sizeof(double) * (size_t)nb), *pred = malloc(sizeof(double) * nx);
            tcc_idx *outa = malloc(sizeof(tcc_idx) * (size_t)k), *outb = malloc(sizeof(tcc_idx) * (size_t)k);
            tcc_idx *outc = malloc(sizeof(tcc_idx) * (size_t)k), na = 0, nb2 = 0, nc = 0;
            memcpy(slack2, slack, sizeof(double) * (size_t)k);
            memcpy(bmin2, bmin, sizeof(double) * (size_t)nb);
            memcpy(bdebt2, bdebt, sizeof(double) * (size_t)nb);
            for (size_t i = 0; i < nx; i++) pred[i] = 2e-2 * sin(0.7 * (double)i);  /* 2 cm: some blocks open */
            rc = tcc_ccd_cull_blocks(x1, m->nv, quad, k, 1, disp, gapq, slack, 1, bptr, nb, bvptr, bv, nbv, bmin, bdebt,
                                     out, &nout, pred, outa, &na, &err);
            int rc2 = tcc_ccd_cull_blocks(x1, m->nv, quad, k, 1, disp, gapq, slack2, 1, bptr, nb, bvptr, bv, nbv, bmin2,
                                          bdebt2, outb, &nb2, NULL, NULL, NULL, &err);
            rc2 |= tcc_ccd_cull_blocks(x1, m->nv, quad, k, 1, pred, gapq, slack2, 0, bptr, nb, bvptr, bv, nbv, bmin2,
                                       bdebt2, outc, &nc, NULL, NULL, NULL, &err);
            int same = rc == TCC_OK && rc2 == TCC_OK && nout == nb2 && na == nc && na > 0;
            for (tcc_idx i = 0; same && i < nout; i++) same = out[i] == outb[i];
            for (tcc_idx i = 0; same && i < na; i++) same = outa[i] == outc[i];
            for (tcc_idx q = 0; same && q < k; q++) same = slack[q] == slack2[q];
            CHECK(same, "blocks, predicted in the same pass: %lld / %lld and %lld / %lld handed out", (long long)nout,
                  (long long)nb2, (long long)na, (long long)nc);
            free(slack2); free(bmin2); free(bdebt2); free(pred); free(outa); free(outb); free(outc);
        }
        tcc_error c4 = {0}, c5 = {0};
        bptr[nb] = k - 1;
        CHECK(tcc_ccd_cull_blocks(x1, m->nv, quad, k, 1, disp, gapq, slack, 0, bptr, nb, bvptr, bv, nbv, bmin, bdebt, out,
                                  &nout, NULL, NULL, NULL, &c4) == TCC_ERR_VALUE, "blocks not covering the pairs are a value error");
        bptr[nb] = k;
        bv[nbv - 1] = -1;
        CHECK(tcc_ccd_cull_blocks(x1, m->nv, quad, k, 1, disp, gapq, slack, 0, bptr, nb, bvptr, bv, nbv, bmin, bdebt, out,
                                  &nout, NULL, NULL, NULL, &c5) == TCC_ERR_INDEX, "a block vertex out of range is an index error");
        free(bptr); free(bvptr); free(bv); free(bmin); free(bdebt);
        free(quad); free(out); free(gapq); free(slack); free(disp);
    }
    /* edge (0, 1), across an edge of the far triangle, driven along the normal through it */
    tcc_idx ea[2] = {0, 1}, eb[2] = {m->tri[3 * far], m->tri[3 * far + 2]};
    const double *pa = m->x + 3 * eb[0], *pb = m->x + 3 * eb[1];
    double mid[3], d[3];
    for (int i = 0; i < 3; i++) mid[i] = 0.5 * (pa[i] + pb[i]);
    d[0] = nh[1] * e2[2] - nh[2] * e2[1];
    d[1] = nh[2] * e2[0] - nh[0] * e2[2];
    d[2] = nh[0] * e2[1] - nh[1] * e2[0];
    double ld = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    for (int i = 0; i < 3; i++) {
        d[i] *= 0.01 / ld;
        x0[i] = mid[i] - d[i] + 0.01 * nh[i]; x0[3 + i] = mid[i] + d[i] + 0.01 * nh[i];
        x1[i] = mid[i] - d[i] - 0.03 * nh[i]; x1[3 + i] = mid[i] + d[i] - 0.03 * nh[i];
    }
    double st[2];
    int8_t es;
    double et;
    rc = tcc_ccd_edge_edge(x0, x1, m->nv, ea, eb, 1, 0.0, NULL, &et, st, &es, &hits, &err);
    CHECK(rc == TCC_OK && hits == 1 && fabs(et - 0.25) < 1e-9 && fabs(st[0] - 0.5) < 1e-9 && fabs(st[1] - 0.5) < 1e-9,
          "edge through an edge: rc %d, %lld hits, toi %g, params %g %g", rc, (long long)hits, et, st[0], st[1]);
    double sd, dist, nrm[3];
    rc = tcc_edge_edge_state(x1, m->nv, ea, eb, 1, &sd, &dist, st, nrm, &err);
    CHECK(rc == TCC_OK && (sd > 0 ? 1 : -1) == -es && fabs(dist - 0.03) < 1e-9, "edge state: sd %g (side %d), dist %g", sd, es, dist);
    /* the swept-box reject (ccd.c swept_boxes_apart): the same edge held still 3 mm below the other
       is found at once with a 4 mm gap (boxes grown by the gap overlap), and not with a 2 mm gap;
       carried 1 m sideways over the interval it meets nothing */
    for (int i = 0; i < 3; i++) {
        x0[i] = x1[i] = mid[i] - d[i] - 0.003 * nh[i];
        x0[3 + i] = x1[3 + i] = mid[i] + d[i] - 0.003 * nh[i];
    }
    rc = tcc_ccd_edge_edge(x0, x1, m->nv, ea, eb, 1, 0.004, NULL, &et, st, &es, &hits, &err);
    CHECK(rc == TCC_OK && hits == 1 && et == 0.0, "still edge within the gap: rc %d, %lld hits, toi %g", rc, (long long)hits, et);
    rc = tcc_ccd_edge_edge(x0, x1, m->nv, ea, eb, 1, 0.002, NULL, &et, st, &es, &hits, &err);
    CHECK(rc == TCC_OK && hits == 0 && isinf(et), "still edge beyond the gap: rc %d, %lld hits", rc, (long long)hits);
    for (int i = 0; i < 3; i++) { x0[i] += 1.0; x0[3 + i] += 1.0; x1[i] += 1.0 + 1e-3; x1[3 + i] += 1.0 + 1e-3; }
    rc = tcc_ccd_edge_edge(x0, x1, m->nv, ea, eb, 1, 0.004, NULL, &et, st, &es, &hits, &err);
    CHECK(rc == TCC_OK && hits == 0, "far edge: rc %d, %lld hits", rc, (long long)hits);
    /* bad pairs */
    tcc_idx badt = m->nt, badv = m->nv;
    tcc_error ex = {0};
    CHECK(tcc_ccd_vertex_triangle(x0, x1, m->nv, m->tri, m->nt, pv, &badt, 1, 0.0, NULL, toi, w, side, &hits, &ex) == TCC_ERR_INDEX,
          "a triangle out of range is an index error");
    tcc_error e3 = {0};
    CHECK(tcc_ccd_vertex_triangle(x0, x1, m->nv, m->tri, m->nt, &badv, pt, 1, 0.0, NULL, toi, w, side, &hits, &e3) == TCC_ERR_INDEX,
          "a vertex out of range is an index error");
    tcc_idx own = m->tri[0];
    tcc_idx t0 = 0;
    tcc_error e4 = {0};
    CHECK(tcc_ccd_vertex_triangle(x0, x1, m->nv, m->tri, m->nt, &own, &t0, 1, 0.0, NULL, toi, w, side, &hits, &e4) == TCC_ERR_VALUE,
          "a vertex of its own triangle is a value error");
    tcc_idx shared[2] = {1, 2};
    tcc_error e5 = {0};
    CHECK(tcc_ccd_edge_edge(x0, x1, m->nv, ea, shared, 1, 0.0, NULL, &et, st, &es, &hits, &e5) == TCC_ERR_VALUE,
          "edges sharing a vertex are a value error");
    free(x0); free(x1); free(pv); free(pt); free(toi); free(w); free(side);
}

/* The cloth's BVHs (bvh.c): the grid wrapped around a cylinder that breathes and wobbles, so its
 * vertices' inward rays cross to the far side; every step the trees are refitted (never rebuilt)
 * and each ray's first hit in every cluster must equal a brute-force test of the cluster's
 * triangles with the same two-ring exclusion; the step's self_cast must find the same hits; bad
 * trees and indices are errors. */
static double brute_first_hit(const mesh *m, const tcc_idx *tris, tcc_idx nt, const double o[3], const double d[3],
                              double tmax, const tcc_ring *ring, tcc_idx v)
{
    double best = INFINITY;
    for (tcc_idx i = 0; i < nt; i++) {
        const tcc_idx *tv = m->tri + 3 * tris[i];
        double t, u, w;
        if (!tcc_line_triangle(o, d, m->x + 3 * tv[0], m->x + 3 * tv[1], m->x + 3 * tv[2], &t, &u, &w)) continue;
        if (t < 0 || t > tmax || u < -1e-12 || w < -1e-12 || u + w > 1 + 1e-12) continue;
        if (ring && tcc_ring_excludes(ring, v, tv)) continue;
        if (t < best) best = t;
    }
    return best;
}

static void test_bvh(mesh *m)
{
    enum { K = 6, W = 16 };
    tcc_idx nv = m->nv, nt = m->nt;
    double *x0 = malloc(sizeof(double) * 3 * nv), *nrm = malloc(sizeof(double) * 3 * nv);
    uint8_t *has = malloc(nv);
    memcpy(x0, m->x, sizeof(double) * 3 * nv);
    tcc_idx *order = malloc(sizeof(tcc_idx) * nv), ptr[K + 1], tptr[K + 1];
    tcc_idx *stri = malloc(sizeof(tcc_idx) * nt), *prim = malloc(sizeof(tcc_idx) * nt);
    tcc_idx *node = malloc(sizeof(tcc_idx) * 4 * nt), node_ptr[K + 1], nnodes = 0;
    double *box = malloc(sizeof(double) * 12 * nt);
    strips(nv, nt, K, order, ptr, tptr);
    for (tcc_idx f = 0; f < nt; f++) stri[f] = f;
    /* ring table: each vertex and its edge neighbours */
    tcc_idx *table = malloc(sizeof(tcc_idx) * W * nv);
    for (tcc_idx i = 0; i < W * nv; i++) table[i] = -1;
    for (tcc_idx v = 0; v < nv; v++) table[W * v] = v;
    for (tcc_idx f = 0; f < nt; f++)
        for (int a = 0; a < 3; a++)
            for (int b = 0; b < 3; b++) {
                tcc_idx va = m->tri[3 * f + a], vb = m->tri[3 * f + b];
                tcc_idx *row = table + W * va;
                for (int w = 0; w < W; w++) {
                    if (row[w] == vb) break;
                    if (row[w] < 0) { row[w] = vb; break; }
                }
            }
    tcc_ring ring = {table, nv, W};
    tcc_mesh tm = {m->x, nv, m->tri, nt, NULL, NULL};
    tcc_error err = {0};
    int rc = tcc_bvh_build(&tm, tptr, stri, nt, K, node_ptr, node, box, 2 * nt, prim, &nnodes, &err);
    CHECK(rc == TCC_OK && nnodes > K && nnodes <= 2 * nt, "bvh build: rc %d (%s), %lld nodes", rc, err.what,
          (long long)nnodes);
    tcc_bvh b = {node_ptr, K, node, box, nnodes, prim, nt};
    tcc_idx stamp[K];
    for (int c = 0; c < K; c++) stamp[c] = -1;
    tcc_idx *rv = malloc(sizeof(tcc_idx) * 2 * nv * K), *rs = malloc(sizeof(tcc_idx) * 2 * nv * K);
    tcc_idx *ht = malloc(sizeof(tcc_idx) * 2 * nv * K);
    int compared = 0, found = 0, mismatched = 0;
    for (int step = 0; step < 4; step++) {
        /* wrap x onto 1.7 pi of a cylinder of radius 0.1 + 0.01 step, wobbling in y */
        double R = 0.1 + 0.01 * step;
        for (tcc_idx v = 0; v < nv; v++) {
            double th = 1.7 * 3.141592653589793 * (x0[3 * v] + 0.3) / 0.6;
            m->x[3 * v] = R * cos(th);
            m->x[3 * v + 1] = x0[3 * v + 1] + 0.01 * sin(3 * th + step);
            m->x[3 * v + 2] = R * sin(th);
        }
        tcc_vertex_normals(&tm, nrm, has, &err);
        for (int c = 0; c < K; c++) {
            rc = tcc_bvh_refit(&tm, &b, c, &err);
            CHECK(rc == TCC_OK, "refit of cluster %d: %s", c, err.what);
        }
        /* boxes of the refitted roots hold their triangles' corners */
        for (int c = 0; c < K; c++) {
            const double *rb = box + 6 * node_ptr[c];
            int ok = 1;
            for (tcc_idx f = tptr[c]; f < tptr[c + 1]; f++)
                for (int k = 0; k < 3; k++)
                    for (int a = 0; a < 3; a++) {
                        double xv = m->x[3 * m->tri[3 * f + k] + a];
                        ok &= xv >= rb[a] && xv <= rb[3 + a];
                    }
            CHECK(ok, "step %d: cluster %d's root box holds its triangles", step, c);
        }
        for (tcc_idx v = 0; v < nv; v += 3)
            for (int slot = 0; slot < 2; slot++)
                for (int c = 0; c < K; c++) {
                    double sg = slot ? -1.0 : 1.0, d[3] = {nrm[3 * v] * sg, nrm[3 * v + 1] * sg, nrm[3 * v + 2] * sg};
                    tcc_hit h;
                    rc = tcc_bvh_first_hit(&tm, &b, c, m->x + 3 * v, d, 0.5, &ring, v, &h, &err);
                    double ref = brute_first_hit(m, stri + tptr[c], tptr[c + 1] - tptr[c], m->x + 3 * v, d, 0.5,
                                                 &ring, v);
                    compared++;
                    found += h.tri >= 0;
                    if (rc != TCC_OK || (h.tri >= 0) != isfinite(ref) || (h.tri >= 0 && fabs(h.t - ref) > 1e-12))
                        mismatched++;
                }
        /* the step's self detection: every cluster pair, one call */
        tcc_idx pa[K * K], pb[K * K], np = 0;
        double lo[3 * K], hi[3 * K];
        for (int c = 0; c < K; c++)
            for (int a = 0; a < 3; a++) {
                lo[3 * c + a] = box[6 * node_ptr[c] + a] - 0.01;
                hi[3 * c + a] = box[6 * node_ptr[c] + 3 + a] + 0.01;
            }
        for (int a = 0; a < K; a++)
            for (int c = 0; c < K; c++) {
                pa[np] = a;
                pb[np++] = c;
            }
        tcc_ray_setup setup = {m->x, nrm, has, NULL, nv, order, ptr, nv, K, lo, hi, K, 0.5, 0.5, 0.0, 0.0};
        tcc_idx nh = 0, nr = 0;
        rc = tcc_self_cast(&setup, &tm, &b, stamp, step, &ring, pa, pb, np, rv, rs, ht, 2 * nv * K, &nh, &nr, &err);
        int all_stamped = 1;
        for (int c = 0; c < K; c++) all_stamped &= stamp[c] == step;
        CHECK(rc == TCC_OK && nh > 0 && nh <= nr && all_stamped, "self_cast: rc %d (%s), %lld hits of %lld rays",
              rc, err.what, (long long)nh, (long long)nr);
        int bad_hits = 0;
        for (tcc_idx i = 0; i < nh; i++) {
            const tcc_idx *tv = m->tri + 3 * ht[i];
            bad_hits += tcc_ring_excludes(&ring, rv[i], tv);
        }
        CHECK(bad_hits == 0, "self_cast: %d hits on the ray vertex's own two-ring", bad_hits);
    }
    CHECK(mismatched == 0 && found > compared / 20, "bvh first hits vs brute force: %d of %d differ (%d hits)",
          mismatched, compared, found);
    /* bad trees and indices are errors, never reads out of bounds */
    tcc_hit h;
    tcc_error e1 = {0}, e2 = {0}, e3 = {0}, e4 = {0}, e5 = {0};
    double o[3] = {0, 0, 0}, d[3] = {0, 0, 1};
    CHECK(tcc_bvh_first_hit(&tm, &b, K, o, d, 1.0, NULL, 0, &h, &e1) == TCC_ERR_INDEX, "a cluster out of range");
    tcc_idx keep = node[2 * node_ptr[0] + 1];
    node[2 * node_ptr[0] + 1] = node_ptr[0]; /* the root its own child */
    CHECK(tcc_bvh_refit(&tm, &b, 0, &e2) == TCC_ERR_INDEX, "a child before its parent is an index error: %s", e2.what);
    node[2 * node_ptr[0] + 1] = keep;
    keep = prim[0];
    prim[0] = nt;
    CHECK(tcc_bvh_refit(&tm, &b, 0, &e3) == TCC_ERR_INDEX, "a leaf triangle out of range is an index error");
    prim[0] = keep;
    tcc_idx bad_pair = K, zero_pair = 0;
    tcc_ray_setup setup = {m->x, nrm, has, NULL, nv, order, ptr, nv, K, box, box, K, 0.5, 0.5, 0.0, 0.0};
    tcc_idx nh, nr;
    CHECK(tcc_self_cast(&setup, &tm, &b, stamp, 9, &ring, &zero_pair, &bad_pair, 1, rv, rs, ht, 1, &nh, &nr, &e4) ==
              TCC_ERR_INDEX, "a pair's target cluster out of range is an index error");
    CHECK(tcc_bvh_build(&tm, tptr, stri, nt, K, node_ptr, node, box, nt, prim, &nnodes, &e5) == TCC_ERR_VALUE,
          "a node array without room for 2 rows per triangle is a value error");
    memcpy(m->x, x0, sizeof(double) * 3 * nv);
    free(x0); free(nrm); free(has); free(order); free(stri); free(prim); free(node); free(box); free(table);
    free(rv); free(rs); free(ht);
}

/* ------------------------------------------------------------------ the impact guard (impact.c) */

typedef struct {
    tcc_idx *vown, *adj, *node, *prim, *patch, *loop, *loop_off, *vt_ptr, *vt_tri;
    uint8_t *eown, *flip, *interior;
    tcc_idx nnodes, nloop;
} impact_tables;

/* The topology's tables by brute force (impact.py's numpy is the other implementation) and the
 * cloth's tree over the rest positions x. */
static impact_tables impact_setup(const mesh *m, const double *x)
{
    tcc_idx nv = m->nv, nt = m->nt;
    impact_tables q = {0};
    q.vown = malloc(sizeof(tcc_idx) * nv);
    q.adj = malloc(sizeof(tcc_idx) * 3 * nt);
    q.eown = malloc(3 * nt);
    q.flip = malloc(3 * nt);
    q.interior = malloc(nv);
    q.vt_ptr = calloc(nv + 1, sizeof(tcc_idx));
    q.vt_tri = malloc(sizeof(tcc_idx) * 3 * nt);
    for (tcc_idx v = 0; v < nv; v++) q.vown[v] = -1;
    for (tcc_idx f = nt - 1; f >= 0; f--)
        for (int k = 0; k < 3; k++) q.vown[m->tri[3 * f + k]] = f;
    for (tcc_idx f = 0; f < nt; f++)
        for (int k = 0; k < 3; k++) {
            tcc_idx a = m->tri[3 * f + k], b = m->tri[3 * f + (k + 1) % 3], found = -1, count = 0;
            int same = 0, first = 1;
            for (tcc_idx u = 0; u < nt; u++) {
                if (u == f) continue;
                for (int l = 0; l < 3; l++) {
                    tcc_idx c = m->tri[3 * u + l], d = m->tri[3 * u + (l + 1) % 3];
                    if ((c == a && d == b) || (c == b && d == a)) {
                        count++;
                        found = u;
                        same = c == a;
                        if (u < f) first = 0;
                    }
                }
            }
            q.adj[3 * f + k] = count > 1 ? -2 : found;
            q.flip[3 * f + k] = (uint8_t)same;
            q.eown[3 * f + k] = (uint8_t)first;
        }
    for (tcc_idx v = 0; v < nv; v++) q.interior[v] = 0;
    for (tcc_idx f = 0; f < nt; f++)
        for (int k = 0; k < 3; k++) {
            q.interior[m->tri[3 * f + k]] = 1;
            q.vt_ptr[m->tri[3 * f + k] + 1]++;
        }
    for (tcc_idx f = 0; f < nt; f++)
        for (int k = 0; k < 3; k++)
            if (q.adj[3 * f + k] < 0 || q.flip[3 * f + k])
                q.interior[m->tri[3 * f + k]] = q.interior[m->tri[3 * f + (k + 1) % 3]] = 0;
    for (tcc_idx v = 0; v < nv; v++) q.vt_ptr[v + 1] += q.vt_ptr[v];
    tcc_idx *fill = calloc(nv, sizeof(tcc_idx));
    for (tcc_idx f = 0; f < nt; f++)
        for (int k = 0; k < 3; k++) {
            tcc_idx v = m->tri[3 * f + k];
            q.vt_tri[q.vt_ptr[v] + fill[v]++] = f;
        }
    free(fill);
    q.node = malloc(sizeof(tcc_idx) * 4 * nt);
    q.prim = malloc(sizeof(tcc_idx) * nt);
    double *box = malloc(sizeof(double) * 12 * nt);
    tcc_idx *stri = malloc(sizeof(tcc_idx) * nt), sptr[2] = {0, nt}, nptr[2];
    for (tcc_idx f = 0; f < nt; f++) stri[f] = f;
    tcc_mesh tm = {x, nv, m->tri, nt, NULL, NULL};
    tcc_error err = {0};
    int rc = tcc_bvh_build(&tm, sptr, stri, nt, 1, nptr, q.node, box, 2 * nt, q.prim, &q.nnodes, &err);
    CHECK(rc == TCC_OK, "impact tree: %s", err.what);
    free(box);
    free(stri);
    /* room for each node's loop: its triangles + 2 */
    tcc_idx *size = calloc(q.nnodes, sizeof(tcc_idx));
    for (tcc_idx i = q.nnodes - 1; i >= 0; i--)
        size[i] = q.node[2 * i] < 0 ? q.node[2 * i + 1] : size[q.node[2 * i]] + size[q.node[2 * i + 1]];
    q.loop_off = malloc(sizeof(tcc_idx) * (q.nnodes + 1));
    q.loop_off[0] = 0;
    for (tcc_idx i = 0; i < q.nnodes; i++) q.loop_off[i + 1] = q.loop_off[i] + size[i] + 2;
    free(size);
    q.nloop = q.loop_off[q.nnodes];
    q.loop = calloc(q.nloop, sizeof(tcc_idx));
    q.patch = malloc(sizeof(tcc_idx) * q.nnodes);
    for (tcc_idx i = 0; i < q.nnodes; i++) q.patch[i] = -1;
    return q;
}

static void impact_free(impact_tables *q)
{
    free(q->vown); free(q->adj); free(q->eown); free(q->flip); free(q->interior); free(q->vt_ptr); free(q->vt_tri);
    free(q->node); free(q->prim); free(q->patch); free(q->loop); free(q->loop_off);
}

static tcc_impact_in impact_in(const mesh *m, const impact_tables *q, const double *x0, double *x1, double *v,
                               const double *mass, const double *rest, int ip, int zp)
{
    tcc_impact_in in = {x0, x1, v, mass, rest, m->nv, m->tri, m->nt, q->vown, q->eown, q->node, q->nnodes, q->prim,
                        q->adj, q->flip, q->interior, q->vt_ptr, q->vt_tri, 3 * m->nt, q->patch, q->loop, q->loop_off,
                        q->nloop, 1e-3, 4e-4, 0.25, 1e-6, ip, zp};
    return in;
}

/* Brute force over every vertex-triangle and edge-edge pair (no shared vertex, apart at rest): how
 * many meet (gap 0, ccd.c) over the motion x0 -> x1. */
static tcc_idx crossings(const mesh *m, const double *x0, const double *x1, const double *rest)
{
    tcc_idx nv = m->nv, nt = m->nt, hits = 0, nh;
    tcc_error err = {0};
    for (tcc_idx v = 0; v < nv; v++)
        for (tcc_idx f = 0; f < nt; f++) {
            const tcc_idx *t = m->tri + 3 * f;
            if (t[0] == v || t[1] == v || t[2] == v) continue;
            double toi, w[3], sd, dist, nrm[3];
            int8_t side;
            tcc_vertex_triangle_state(rest, nv, m->tri, nt, &v, &f, 1, &sd, &dist, w, nrm, &err);
            if (dist < 1e-6) continue;
            tcc_ccd_vertex_triangle(x0, x1, nv, m->tri, nt, &v, &f, 1, 0.0, NULL, &toi, w, &side, &nh, &err);
            hits += nh;
        }
    for (tcc_idx f = 0; f < nt; f++)
        for (int k = 0; k < 3; k++)
            for (tcc_idx g = f; g < nt; g++)
                for (int l = 0; l < 3; l++) {
                    tcc_idx ea[2] = {m->tri[3 * f + k], m->tri[3 * f + (k + 1) % 3]};
                    tcc_idx eb[2] = {m->tri[3 * g + l], m->tri[3 * g + (l + 1) % 3]};
                    if (ea[0] > ea[1] || eb[0] > eb[1]) continue; /* each edge once, as (low, high) */
                    if (g == f && l <= k) continue;
                    if (ea[0] == eb[0] || ea[0] == eb[1] || ea[1] == eb[0] || ea[1] == eb[1]) continue;
                    double toi, st[2], sd, dist, nrm[3];
                    int8_t side;
                    tcc_edge_edge_state(rest, nv, ea, eb, 1, &sd, &dist, st, nrm, &err);
                    if (dist < 1e-6) continue;
                    tcc_ccd_edge_edge(x0, x1, nv, ea, eb, 1, 0.0, NULL, &toi, st, &side, &nh, &err);
                    hits += nh;
                }
    return hits;
}

static void momentum(const double *x0, const double *x1, const double *mass, tcc_idx n, double dt, double p[3], double L[3])
{
    p[0] = p[1] = p[2] = L[0] = L[1] = L[2] = 0.0;
    for (tcc_idx v = 0; v < n; v++) {
        double u[3];
        for (int a = 0; a < 3; a++) {
            u[a] = (x1[3 * v + a] - x0[3 * v + a]) / dt;
            p[a] += mass[v] * u[a];
        }
        const double *r = x0 + 3 * v;
        L[0] += mass[v] * (r[1] * u[2] - r[2] * u[1]);
        L[1] += mass[v] * (r[2] * u[0] - r[0] * u[2]);
        L[2] += mass[v] * (r[0] * u[1] - r[1] * u[0]);
    }
}

/* The grid folded over its middle row as a crease whose two sides are then driven through each
 * other, and a corner vertex thrown through a far triangle: the guard must leave no pair of the
 * grid meeting over the corrected motion (brute force over all pairs), with impulses and zones,
 * with zones only (which keep linear and angular momentum), and with the pass cap hit (the whole
 * cloth rigid); a still vertex never moves; after the tear the twins of the cut are excluded;
 * bad input is an error. */
static void test_impact(const mesh *m, int torn)
{
    tcc_idx nv = m->nv;
    size_t nx = 3 * (size_t)nv;
    double *rest = malloc(sizeof(double) * nx), *x0 = malloc(sizeof(double) * nx), *x1 = malloc(sizeof(double) * nx);
    double *xa = malloc(sizeof(double) * nx), *v = malloc(sizeof(double) * nx), *va = malloc(sizeof(double) * nx);
    double *mass = malloc(sizeof(double) * nv);
    memcpy(rest, m->x, sizeof(double) * nx);
    impact_tables q = impact_setup(m, rest);
    /* start: the grid's left half (x < 0) folded about x = 0 over the right half, 20 degrees above
       it; end: swung on to 10 degrees below it (through it), the right half risen by 2 mm, and the
       corner vertex 0 thrown sideways through the grid */
    for (tcc_idx i = 0; i < nv; i++) {
        const double *r = rest + 3 * i;
        double d = -r[0], a0 = 0.349, a1 = -0.175;
        if (d > 0) {
            x0[3 * i] = d * cos(a0); x0[3 * i + 1] = r[1]; x0[3 * i + 2] = r[2] + d * sin(a0);
            x1[3 * i] = d * cos(a1); x1[3 * i + 1] = r[1]; x1[3 * i + 2] = r[2] + d * sin(a1);
        } else {
            memcpy(x0 + 3 * i, r, sizeof(double) * 3);
            memcpy(x1 + 3 * i, r, sizeof(double) * 3);
            x1[3 * i + 2] += 0.002;
        }
        mass[i] = 1e-4 * (1.0 + 0.5 * sin(0.7 * (double)i));
    }
    x1[0] = x0[0] + 0.35; x1[1] = x0[1] + 0.3; x1[2] = x0[2] - 0.05;
    tcc_idx before = crossings(m, x0, x1, rest);
    CHECK(before > 0, "torn %d: the driven motion crosses (%lld pairs meet)", torn, (long long)before);
    double p0[3], L0[3], p1[3], L1[3];
    momentum(x0, x1, mass, nv, 1e-3, p0, L0);
    for (int mode = 0; mode < 3; mode++) {
        int ip = mode == 0 ? 4 : 0, zp = mode == 2 ? 0 : 64;
        memcpy(xa, x1, sizeof(double) * nx);
        for (size_t k = 0; k < nx; k++) va[k] = 0.5;
        tcc_impact_in in = impact_in(m, &q, x0, xa, va, mass, rest, ip, zp);
        tcc_impact_counts c;
        tcc_error err = {0};
        int rc = tcc_impact_resolve(&in, &c, &err);
        CHECK(rc == TCC_OK, "torn %d mode %d: rc %d (%s)", torn, mode, rc, err.what);
        tcc_idx after = crossings(m, x0, xa, rest);
        CHECK(after == 0, "torn %d mode %d: %lld pairs still meet (collisions %lld, impulses %lld, zones %lld, rigid %lld)",
              torn, mode, (long long)after, (long long)c.collisions, (long long)c.impulses, (long long)c.zones,
              (long long)c.rigid_cloth);
        CHECK(c.collisions > 0 && c.moved > 0, "torn %d mode %d: %lld collisions, %lld moved", torn, mode,
              (long long)c.collisions, (long long)c.moved);
        CHECK(mode != 2 || c.rigid_cloth == 1, "torn %d: the pass cap of 0 moves the whole cloth rigidly", torn);
        /* the end velocity changed by what the mean one did */
        int vok = 1;
        for (size_t k = 0; k < nx; k++) vok &= fabs((va[k] - 0.5) - ((xa[k] - x0[k]) - (x1[k] - x0[k])) / 1e-3) < 1e-6;
        CHECK(vok, "torn %d mode %d: velocities corrected by the change of the mean velocity", torn, mode);
        if (mode >= 1) { /* zones only (and the whole cloth): momentum kept */
            momentum(x0, xa, mass, nv, 1e-3, p1, L1);
            double pe = 0, le = 0, ps = 0, ls = 0;
            for (int a = 0; a < 3; a++) {
                pe = fmax(pe, fabs(p1[a] - p0[a]));
                le = fmax(le, fabs(L1[a] - L0[a]));
                ps = fmax(ps, fabs(p0[a]));
                ls = fmax(ls, fabs(L0[a]));
            }
            CHECK(pe <= 1e-12 * ps && le <= 1e-12 * ls, "torn %d mode %d: momentum changed by %g (of %g), angular %g (of %g)",
                  torn, mode, pe, ps, le, ls);
        }
        if (mode == 0 && torn) CHECK(c.excluded > 0, "the twins of the cut are excluded (%lld)", (long long)c.excluded);
    }
    /* a still vertex (pinned) is never moved: the corner's triangle left in place */
    memcpy(xa, x1, sizeof(double) * nx);
    for (int k = 0; k < 3; k++) {
        tcc_idx c0 = m->tri[3 * (m->nt / 2) + k];
        memcpy(xa + 3 * c0, x0 + 3 * c0, sizeof(double) * 3);
    }
    {
        tcc_impact_in in = impact_in(m, &q, x0, xa, va, mass, rest, 4, 64);
        tcc_impact_counts c;
        tcc_error err = {0};
        int rc = tcc_impact_resolve(&in, &c, &err);
        int still = 1;
        for (int k = 0; k < 3; k++) {
            tcc_idx c0 = m->tri[3 * (m->nt / 2) + k];
            for (int a = 0; a < 3; a++) still &= xa[3 * c0 + a] == x0[3 * c0 + a];
        }
        CHECK(rc == TCC_OK && still && c.immovable >= 3, "torn %d: still vertices stay (rc %d, %lld immovable)", torn, rc,
              (long long)c.immovable);
        CHECK(crossings(m, x0, xa, rest) == 0, "torn %d: no pair meets with still vertices", torn);
    }
    /* bad input: an error, nothing read out of bounds */
    {
        tcc_error err = {0};
        tcc_impact_counts c;
        memcpy(xa, x1, sizeof(double) * nx);
        tcc_impact_in in = impact_in(m, &q, x0, xa, va, mass, rest, 4, 64);
        in.gap = -1.0;
        CHECK(tcc_impact_resolve(&in, &c, &err) == TCC_ERR_VALUE, "a negative gap is a value error");
        in = impact_in(m, &q, x0, xa, va, mass, rest, 4, 64);
        double keep = xa[5];
        xa[5] = NAN;
        CHECK(tcc_impact_resolve(&in, &c, &err) == TCC_ERR_VALUE, "a NaN end position is a value error");
        xa[5] = keep;
        tcc_idx k0 = q.node[0];
        q.node[0] = q.nnodes + 5;
        in = impact_in(m, &q, x0, xa, va, mass, rest, 4, 64);
        CHECK(tcc_impact_resolve(&in, &c, &err) == TCC_ERR_INDEX, "a child outside the tree is an index error");
        q.node[0] = k0;
        tcc_idx p0 = q.prim[0];
        q.prim[0] = q.prim[1];
        in = impact_in(m, &q, x0, xa, va, mass, rest, 4, 64);
        CHECK(tcc_impact_resolve(&in, &c, &err) == TCC_ERR_INDEX, "a tree missing a triangle is an error");
        q.prim[0] = p0;
        tcc_idx vt0 = q.vt_tri[0];
        q.vt_tri[0] = m->nt;
        in = impact_in(m, &q, x0, xa, va, mass, rest, 4, 64);
        CHECK(tcc_impact_resolve(&in, &c, &err) == TCC_ERR_INDEX, "a fan naming no triangle is an index error");
        q.vt_tri[0] = vt0;
        q.patch[0] = q.loop_off[1] + 1;
        in = impact_in(m, &q, x0, xa, va, mass, rest, 4, 64);
        CHECK(tcc_impact_resolve(&in, &c, &err) == TCC_ERR_VALUE, "a loop longer than its room is a value error");
        q.patch[0] = -1;
    }
    impact_free(&q);
    free(rest); free(x0); free(x1); free(xa); free(v); free(va); free(mass);
}

int main(void)
{
    mesh m = grid();
    test_measure_and_detection_steps(&m);
    test_ccd(&m);
    test_bvh(&m);
    test_impact(&m, 0);
    tear(&m);
    test_measure_and_detection_steps(&m);
    test_bvh(&m);
    test_impact(&m, 1);
    free(m.x);
    free(m.tri);
    printf("collide: %d checks, %d failures\n", checks, failures);
    return failures;
}
