/* test_collide.c - native tests of the collision kernels (native/collide/, no Python), built with
 * AddressSanitizer and UndefinedBehaviorSanitizer by native/tests/run_sanitizers.sh. A cloth grid
 * deforms step by step over a closed box body that moves; every step runs the per-step kernels a
 * detection runs (normals, cluster motion, boxes, pairs, the relative measure, rays,
 * refinement of candidate hits, walks, the swept stage), the grid is then "torn" (a row of vertices duplicated,
 * triangles re-indexed) and run again, and bad indices must come back as errors. Each check prints and counts; the exit code is the number of
 * failures. */
#include "collide.h"

#include <float.h>
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

/* The swept stage's step (swept.c) on the grid's pairs near each other (vertex-triangle: a vertex and
 * a triangle two rows over; edge-edge: parallel edges a row apart), in blocks of 8 pairs: over steps
 * that turn the grid, jitter it, shift it and now and then throw one vertex through a triangle, every
 * pair the exact swept test hits over the real motion (gap 0 and its gap) and over the prediction is
 * among those the cull handed out; a vertex driven through a triangle is remembered and gives four
 * contact rows, merged by vertex; quiet steps settle most blocks without reading them; bad input is
 * an error. */
typedef struct {
    tcc_idx *quad, k, nb, nbv, nbg, *bptr, *bvptr, *bv, *bgptr, *bg, *mem, *memo, *outq, *cand, *pcand;
    double *gap, *slack, *bstate, *bref, *memn, *memno, *outn, *outd, *outw;
} swept_kind_arrays;

static int cmp_idx(const void *a, const void *b)
{
    tcc_idx x = *(const tcc_idx *)a, y = *(const tcc_idx *)b;
    return x < y ? -1 : x > y;
}

/* pairs of kind split over the grid m, blocks of 8, groups of 16 vertex ids */
static void swept_arrays(const mesh *m, int split, swept_kind_arrays *A)
{
    tcc_idx cap = 2 * m->nt + 2 * m->nv;
    A->quad = malloc(sizeof(tcc_idx) * 4 * cap);
    A->k = 0;
    if (split == 1) {
        for (tcc_idx f = 0; f < m->nt; f++) {
            const tcc_idx *t = m->tri + 3 * f;
            tcc_idx v = t[0] + 2 < m->nv ? t[0] + 2 : t[0] - 2; /* two rows over in the column */
            if (v == t[0] || v == t[1] || v == t[2]) continue;
            tcc_idx *q = A->quad + 4 * A->k++;
            q[0] = v; q[1] = t[0]; q[2] = t[1]; q[3] = t[2];
        }
    } else {
        for (tcc_idx f = 0; f < m->nt; f++) {
            const tcc_idx *t = m->tri + 3 * f;
            tcc_idx a = t[0], b = t[1], c = t[1] + 1 < m->nv ? t[1] + 1 : t[1], d = t[2] + 1 < m->nv ? t[2] + 1 : t[2];
            if (a == c || a == d || b == c || b == d || c == d) continue;
            tcc_idx *q = A->quad + 4 * A->k++;
            q[0] = a; q[1] = b; q[2] = c; q[3] = d;
        }
    }
    A->nb = (A->k + 7) / 8;
    A->bptr = malloc(sizeof(tcc_idx) * (A->nb + 1));
    A->bvptr = malloc(sizeof(tcc_idx) * (A->nb + 1));
    A->bgptr = malloc(sizeof(tcc_idx) * (A->nb + 1));
    A->bv = malloc(sizeof(tcc_idx) * 32 * A->nb);
    A->bg = malloc(sizeof(tcc_idx) * 32 * A->nb);
    A->nbv = A->nbg = 0;
    for (tcc_idx b = 0; b < A->nb; b++) {
        A->bptr[b] = 8 * b;
        A->bvptr[b] = A->nbv;
        A->bgptr[b] = A->nbg;
        tcc_idx e = 8 * b + 8 < A->k ? 8 * b + 8 : A->k, start = A->nbv;
        for (tcc_idx q = 8 * b; q < e; q++)
            for (int j = 0; j < 4; j++) A->bv[A->nbv++] = A->quad[4 * q + j];
        qsort(A->bv + start, (size_t)(A->nbv - start), sizeof(tcc_idx), cmp_idx);
        tcc_idx u = start;
        for (tcc_idx i = start; i < A->nbv; i++)
            if (i == start || A->bv[i] != A->bv[u - 1]) A->bv[u++] = A->bv[i];
        A->nbv = u;
        for (tcc_idx i = start; i < u; i++) {
            tcc_idx g = A->bv[i] / 16;
            if (A->nbg == A->bgptr[b] || A->bg[A->nbg - 1] != g) A->bg[A->nbg++] = g;
        }
    }
    A->bptr[A->nb] = A->k;
    A->bvptr[A->nb] = A->nbv;
    A->bgptr[A->nb] = A->nbg;
    A->gap = malloc(sizeof(double) * A->k);
    A->slack = malloc(sizeof(double) * A->k);
    for (tcc_idx q = 0; q < A->k; q++) {
        A->gap[q] = 0.001;
        A->slack[q] = -INFINITY;
    }
    A->bstate = malloc(sizeof(double) * 2 * A->nb);
    for (tcc_idx b = 0; b < A->nb; b++) {
        A->bstate[2 * b] = -INFINITY;
        A->bstate[2 * b + 1] = 0.0;
    }
    A->bref = malloc(sizeof(double) * 3 * A->nbv);
    A->mem = malloc(sizeof(tcc_idx) * A->k);
    A->memo = malloc(sizeof(tcc_idx) * A->k);
    A->outq = malloc(sizeof(tcc_idx) * A->k);
    A->cand = malloc(sizeof(tcc_idx) * A->k);
    A->pcand = malloc(sizeof(tcc_idx) * A->k);
    A->memn = malloc(sizeof(double) * 3 * A->k);
    A->memno = malloc(sizeof(double) * 3 * A->k);
    A->outn = malloc(sizeof(double) * 3 * A->k);
    A->outd = malloc(sizeof(double) * A->k);
    A->outw = malloc(sizeof(double) * 3 * A->k);
}

static void swept_free(swept_kind_arrays *A)
{
    free(A->quad); free(A->bptr); free(A->bvptr); free(A->bgptr); free(A->bv); free(A->bg); free(A->gap);
    free(A->slack); free(A->bstate); free(A->bref); free(A->mem); free(A->memo); free(A->outq); free(A->cand);
    free(A->pcand); free(A->memn); free(A->memno); free(A->outn); free(A->outd); free(A->outw);
}

static void swept_bind(swept_kind_arrays *A, int split, tcc_idx nmem, tcc_swept_kind *K)
{
    memset(K, 0, sizeof *K);
    K->split = split;
    K->quad = A->quad; K->k = A->k; K->gap = A->gap; K->slack = A->slack;
    K->bptr = A->bptr; K->bvptr = A->bvptr; K->bverts = A->bv; K->bgptr = A->bgptr; K->bgroups = A->bg;
    K->nb = A->nb; K->nbv = A->nbv; K->nbg = A->nbg; K->bstate = A->bstate; K->bref = A->bref;
    K->mem = A->mem; K->mem_n = A->memn; K->nmem = nmem; K->mem_out = A->memo; K->mem_n_out = A->memno;
    K->out_q = A->outq; K->out_normal = A->outn; K->out_depth = A->outd; K->out_w = A->outw;
}

static int handed(const tcc_idx *l, tcc_idx n, tcc_idx q)
{
    for (tcc_idx i = 0; i < n; i++)
        if (l[i] == q) return 1;
    return 0;
}

static void test_swept_step(const mesh *m)
{
    tcc_idx n = m->nv, ng = (n + 15) / 16;
    double *x0 = malloc(sizeof(double) * 3 * n), *xp = malloc(sizeof(double) * 3 * n);
    double *x = malloc(sizeof(double) * 3 * n), *v = malloc(sizeof(double) * 3 * n), *x1 = malloc(sizeof(double) * 3 * n);
    memcpy(x0, m->x, sizeof(double) * 3 * n);
    memcpy(xp, m->x, sizeof(double) * 3 * n);
    tcc_idx *gptr = malloc(sizeof(tcc_idx) * (ng + 1)), *gv = malloc(sizeof(tcc_idx) * n);
    for (tcc_idx g = 0; g <= ng; g++) gptr[g] = 16 * g < n ? 16 * g : n;
    for (tcc_idx i = 0; i < n; i++) gv[i] = i;
    swept_kind_arrays A[2];
    swept_arrays(m, 1, &A[0]);
    swept_arrays(m, 2, &A[1]);
    CHECK(A[0].k > 100 && A[1].k > 100, "swept pairs: %lld vertex-triangle, %lld edge-edge", (long long)A[0].k,
          (long long)A[1].k);
    tcc_idx nmem[2] = {0, 0}, missed = 0, hits = 0, quiet_blocks = 0, quiet_settled = 0, remembered_rows = 0;
    uint8_t has_ref = 0;
    double dt = 1e-3, ang = 0.0;
    unsigned seed = 12345;
    tcc_error err = {0};
    for (int step = 0; step < 60; step++) {
        int violent = step >= 20 && step < 35;
        ang += 0.002;
        double c = cos(ang), sn = sin(ang);
        for (tcc_idx i = 0; i < n; i++) {
            const double *p = x0 + 3 * i;
            double j[3];
            for (int a = 0; a < 3; a++) {
                seed = seed * 1103515245u + 12345u;
                j[a] = ((double)(seed >> 8) / 16777216.0 - 0.5) * (violent ? 4e-3 : 2e-5);
            }
            x[3 * i] = c * p[0] - sn * p[1] + 0.001 * step + j[0];
            x[3 * i + 1] = sn * p[0] + c * p[1] + j[1];
            x[3 * i + 2] = p[2] + j[2];
            for (int a = 0; a < 3; a++) v[3 * i + a] = (x[3 * i + a] - xp[3 * i + a]) / dt;
        }
        if (step == 39 || step == 40) { /* one vertex thrown through its pair's triangle (3 mm each side) */
            const tcc_idx *q = A[0].quad + 4 * (A[0].k / 2);
            double cen[3] = {0, 0, 0};
            for (int j = 1; j < 4; j++)
                for (int a = 0; a < 3; a++) cen[a] += x[3 * q[j] + a] / 3.0;
            for (int a = 0; a < 3; a++) x[3 * q[0] + a] = cen[a] + (a == 2 ? (step == 39 ? 0.003 : -0.003) : 0.0);
        }
        tcc_swept s;
        memset(&s, 0, sizeof s);
        s.x = x; s.x_prev = step ? xp : NULL; s.v = v; s.n = n; s.dt = dt; s.thickness = 0.004;
        s.group_ptr = gptr; s.group_vertices = gv; s.ngroups = ng; s.ngv = n; s.has_ref = &has_ref;
        for (int k = 0; k < 2; k++) {
            swept_bind(&A[k], k + 1, nmem[k], &s.kind[k]);
            s.cand_out[k] = A[k].cand;
            s.pcand_out[k] = A[k].pcand;
        }
        int rc = tcc_swept_step(&s, &err);
        CHECK(rc == TCC_OK, "swept step %d: %s", step, err.what);
        if (rc) break;
        for (tcc_idx i = 0; i < 3 * n; i++) x1[i] = x[i] + dt * v[i];
        /* every pair the exact tests hit was handed out */
        for (int k = 0; k < 2; k++) {
            for (tcc_idx q = 0; q < A[k].k; q++) {
                const tcc_idx *id = A[k].quad + 4 * q;
                const double *P0[4], *P1[4], *P2[4];
                for (int j = 0; j < 4; j++) {
                    P0[j] = xp + 3 * id[j];
                    P1[j] = x + 3 * id[j];
                    P2[j] = x1 + 3 * id[j];
                }
                double toi, w[3];
                int8_t side;
                int real = step > 0 && (k ? tcc_ee_sweep(P0, P1, A[k].gap[q], &toi, w, &side)
                                          : tcc_vt_sweep(P0, P1, A[k].gap[q], &toi, w, &side));
                int pred = k ? tcc_ee_sweep(P1, P2, A[k].gap[q], &toi, w, &side)
                             : tcc_vt_sweep(P1, P2, A[k].gap[q], &toi, w, &side);
                hits += real + pred;
                missed += (real && !handed(A[k].cand, s.ncand[k], q)) || (pred && !handed(A[k].pcand, s.npcand[k], q));
            }
            if (step >= 5 && step < 20) {
                quiet_blocks += A[k].nb;
                quiet_settled += s.kind[k].settled[0] + s.kind[k].settled[1];
            }
            /* the memory carries to the next step */
            nmem[k] = s.kind[k].nmem_out;
            memcpy(A[k].mem, A[k].memo, sizeof(tcc_idx) * (size_t)nmem[k]);
            memcpy(A[k].memn, A[k].memno, sizeof(double) * 3 * (size_t)nmem[k]);
        }
        if (step == 40) {
            CHECK(s.kind[0].crossed >= 1 && s.kind[0].nlive >= 1, "the thrown vertex is remembered: %lld crossed, %lld live",
                  (long long)s.kind[0].crossed, (long long)s.kind[0].nlive);
            /* its rows, merged after one collider contact of vertex 0 */
            tcc_idx rows = 4 * (s.kind[0].nlive + s.kind[0].npred + s.kind[1].nlive + s.kind[1].npred), count = 0, bad = 0;
            int32_t ev = 0, *ov = malloc(sizeof(int32_t) * (rows + 1));
            double en[3] = {0, 0, 1}, ed = 0.001, evel[3] = {0, 0, 0}, ef = 0.3;
            double *on = malloc(sizeof(double) * 3 * (rows + 1)), *od = malloc(sizeof(double) * (rows + 1));
            double *ovel = malloc(sizeof(double) * 3 * (rows + 1)), *of = malloc(sizeof(double) * (rows + 1));
            rc = tcc_swept_rows(s.kind, v, n, &ev, en, &ed, evel, &ef, 1, 0.5, ov, on, od, ovel, of, rows + 1, &count,
                                &bad, &err);
            int sorted = 1;
            for (tcc_idx i = 1; i < count; i++) sorted &= ov[i] >= ov[i - 1];
            CHECK(rc == TCC_OK && count == 1 + rows - bad && sorted && ov[0] == 0 && od[0] == 0.001,
                  "swept rows: rc %d, %lld of %lld rows, sorted %d", rc, (long long)count, (long long)rows, sorted);
            remembered_rows = rows;
            tcc_idx small = 0;
            CHECK(tcc_swept_rows(s.kind, v, n, &ev, en, &ed, evel, &ef, 1, 0.5, ov, on, od, ovel, of, 0, &small, &bad,
                                 &err) == TCC_OK && small == count, "rows without room: only counted");
            free(ov); free(on); free(od); free(ovel); free(of);
        }
        memcpy(xp, x, sizeof(double) * 3 * n);
    }
    CHECK(missed == 0 && hits > 0, "swept cull: %lld pairs hit but not handed out (of %lld hits)", (long long)missed,
          (long long)hits);
    CHECK(remembered_rows >= 4, "the remembered pair gives rows");
    CHECK(quiet_settled > quiet_blocks / 2, "quiet steps: %lld of %lld blocks settled unread", (long long)quiet_settled,
          (long long)quiet_blocks);
    /* bad input: errors, never reads out of bounds */
    {
        tcc_swept s;
        memset(&s, 0, sizeof s);
        s.x = x; s.x_prev = xp; s.v = v; s.n = n; s.dt = dt; s.thickness = 0.004;
        s.group_ptr = gptr; s.group_vertices = gv; s.ngroups = ng; s.ngv = n; s.has_ref = &has_ref;
        for (int k = 0; k < 2; k++) swept_bind(&A[k], k + 1, 0, &s.kind[k]);
        tcc_error e1 = {0}, e2 = {0}, e3 = {0}, e4 = {0}, e5 = {0};
        gv[3] = n;
        CHECK(tcc_swept_step(&s, &e1) == TCC_ERR_INDEX, "a group vertex out of range is an index error");
        gv[3] = 3;
        A[0].mem[0] = A[0].k;
        s.kind[0].nmem = 1;
        CHECK(tcc_swept_step(&s, &e2) == TCC_ERR_INDEX, "a remembered pair out of range is an index error");
        s.kind[0].nmem = 0;
        x[5] = NAN;
        CHECK(tcc_swept_step(&s, &e3) == TCC_ERR_VALUE, "a NaN position is a value error");
        x[5] = 0.0;
        tcc_idx keep = A[1].bptr[A[1].nb];
        A[1].bptr[A[1].nb] = keep - 1;
        CHECK(tcc_swept_step(&s, &e4) == TCC_ERR_VALUE, "blocks not covering the pairs are a value error");
        A[1].bptr[A[1].nb] = keep;
        /* a pair whose corner is not among its block's vertices, read (every bound unknown) */
        for (tcc_idx b = 0; b < A[0].nb; b++) A[0].bstate[2 * b] = -INFINITY;
        tcc_idx saved = A[0].quad[1];
        A[0].quad[1] = A[0].quad[4 * (A[0].k - 1) + 1] == saved ? A[0].quad[4 * (A[0].k - 1) + 2] : A[0].quad[4 * (A[0].k - 1) + 1];
        int rc5 = tcc_swept_step(&s, &e5);
        CHECK(rc5 == TCC_ERR_VALUE || rc5 == TCC_ERR_INDEX, "a pair outside its block's vertices is an error (rc %d)", rc5);
        A[0].quad[1] = saved;
    }
    swept_free(&A[0]);
    swept_free(&A[1]);
    free(x0); free(xp); free(x); free(v); free(x1); free(gptr); free(gv);
}

/* The swept stage's pairs and blocks of a topology (swept.c tcc_swept_pairs, tcc_swept_blocks) on the
 * grid, before and after the tear: every list ascending and once per pair, each vertex-triangle
 * pair's vertex in the ring of a corner and not a corner, edge pairs sharing no vertex, every block
 * holding its pairs' corners (ascending) and their groups; too little room only counts; bad indices
 * are errors. */
static void test_swept_build(const mesh *m)
{
    enum { W = 16 };
    tcc_idx n = m->nv, nt = m->nt;
    tcc_idx *table = malloc(sizeof(tcc_idx) * W * n);
    for (tcc_idx i = 0; i < W * n; i++) table[i] = -1;
    for (tcc_idx v = 0; v < n; v++) table[W * v] = v;
    for (tcc_idx f = 0; f < nt; f++)
        for (int a = 0; a < 3; a++)
            for (int b = 0; b < 3; b++) {
                tcc_idx *row = table + W * m->tri[3 * f + a], vb = m->tri[3 * f + b];
                for (int w = 0; w < W; w++) {
                    if (row[w] == vb) break;
                    if (row[w] < 0) { row[w] = vb; break; }
                }
            }
    tcc_ring ring = {table, n, W};
    tcc_idx ne = 0, nvt = 0, nee = 0;
    tcc_error err = {0};
    int rc = tcc_swept_pairs(m->tri, nt, n, &ring, NULL, 0, NULL, 0, NULL, 0, &ne, &nvt, &nee, &err);
    CHECK(rc == TCC_OK && ne > 0 && nvt == 0 && nee == 0, "no room: the edges counted (%lld), nothing else", (long long)ne);
    tcc_idx *edges = malloc(sizeof(tcc_idx) * 2 * ne);
    rc = tcc_swept_pairs(m->tri, nt, n, &ring, edges, ne, NULL, 0, NULL, 0, &ne, &nvt, &nee, &err);
    CHECK(rc == TCC_OK && nvt > 0 && nee > 0, "counts: %lld vt, %lld ee", (long long)nvt, (long long)nee);
    tcc_idx *vt = malloc(sizeof(tcc_idx) * 2 * nvt), *ee = malloc(sizeof(tcc_idx) * 2 * nee);
    rc = tcc_swept_pairs(m->tri, nt, n, &ring, edges, ne, vt, nvt, ee, nee, &ne, &nvt, &nee, &err);
    CHECK(rc == TCC_OK, "swept pairs: %s", err.what);
    int bad = 0;
    for (tcc_idx i = 0; i < ne; i++)
        bad += !(edges[2 * i] < edges[2 * i + 1] &&
                 (i == 0 || edges[2 * i] > edges[2 * i - 2] || (edges[2 * i] == edges[2 * i - 2] && edges[2 * i + 1] > edges[2 * i - 1])));
    CHECK(bad == 0, "edges ascending, once each: %d bad", bad);
    bad = 0;
    for (tcc_idx i = 0; i < nvt; i++) {
        tcc_idx u = vt[2 * i], t = vt[2 * i + 1];
        const tcc_idx *c = m->tri + 3 * t;
        int in_ring = 0;
        for (int k = 0; k < 3; k++)
            for (int w = 0; w < W; w++) in_ring |= table[W * c[k] + w] == u;
        bad += !(in_ring && u != c[0] && u != c[1] && u != c[2] &&
                 (i == 0 || u > vt[2 * i - 2] || (u == vt[2 * i - 2] && t > vt[2 * i - 1])));
    }
    CHECK(bad == 0, "vertex-triangle pairs: %d bad of %lld", bad, (long long)nvt);
    bad = 0;
    for (tcc_idx i = 0; i < nee; i++) {
        tcc_idx a = ee[2 * i], b = ee[2 * i + 1];
        const tcc_idx *ea = edges + 2 * a, *eb = edges + 2 * b;
        bad += !(a < b && ea[0] != eb[0] && ea[0] != eb[1] && ea[1] != eb[0] && ea[1] != eb[1] &&
                 (i == 0 || a > ee[2 * i - 2] || (a == ee[2 * i - 2] && b > ee[2 * i - 1])));
    }
    CHECK(bad == 0, "edge-edge pairs: %d bad of %lld", bad, (long long)nee);
    /* blocks of 7 edge pairs over groups of 10 vertex ids */
    tcc_idx k = nee, *quad = malloc(sizeof(tcc_idx) * 4 * k), *group = malloc(sizeof(tcc_idx) * n);
    for (tcc_idx i = 0; i < k; i++) {
        quad[4 * i] = edges[2 * ee[2 * i]];
        quad[4 * i + 1] = edges[2 * ee[2 * i] + 1];
        quad[4 * i + 2] = edges[2 * ee[2 * i + 1]];
        quad[4 * i + 3] = edges[2 * ee[2 * i + 1] + 1];
    }
    for (tcc_idx v = 0; v < n; v++) group[v] = v / 10;
    tcc_idx nb = (k + 6) / 7, *bptr = malloc(sizeof(tcc_idx) * (nb + 1)), *bvptr = malloc(sizeof(tcc_idx) * (nb + 1));
    tcc_idx *bgptr = malloc(sizeof(tcc_idx) * (nb + 1)), *bv = malloc(sizeof(tcc_idx) * 4 * k), *bg = malloc(sizeof(tcc_idx) * 4 * k);
    rc = tcc_swept_blocks(quad, k, 7, group, n, bptr, bvptr, bv, bgptr, bg, &err);
    CHECK(rc == TCC_OK && bptr[nb] == k, "swept blocks: %s", err.what);
    bad = 0;
    for (tcc_idx b = 0; b < nb && rc == TCC_OK; b++) {
        for (tcc_idx i = bvptr[b] + 1; i < bvptr[b + 1]; i++) bad += bv[i] <= bv[i - 1];
        for (tcc_idx i = bgptr[b] + 1; i < bgptr[b + 1]; i++) bad += bg[i] <= bg[i - 1];
        for (tcc_idx q = bptr[b]; q < bptr[b + 1]; q++)
            for (int j = 0; j < 4; j++) {
                int found = 0, gfound = 0;
                for (tcc_idx i = bvptr[b]; i < bvptr[b + 1]; i++) found |= bv[i] == quad[4 * q + j];
                for (tcc_idx i = bgptr[b]; i < bgptr[b + 1]; i++) gfound |= bg[i] == group[quad[4 * q + j]];
                bad += !found || !gfound;
            }
    }
    CHECK(bad == 0, "blocks hold their pairs' corners and groups, ascending: %d bad", bad);
    tcc_error e1 = {0}, e2 = {0};
    quad[5] = n;
    CHECK(tcc_swept_blocks(quad, k, 7, group, n, bptr, bvptr, bv, bgptr, bg, &e1) == TCC_ERR_INDEX,
          "a pair's vertex out of range is an index error");
    table[3] = n;
    CHECK(tcc_swept_pairs(m->tri, nt, n, &ring, edges, ne, vt, nvt, ee, nee, &ne, &nvt, &nee, &e2) == TCC_ERR_INDEX,
          "a ring entry out of range is an index error");
    free(table); free(edges); free(vt); free(ee); free(quad); free(group); free(bptr); free(bvptr); free(bgptr);
    free(bv); free(bg);
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
    double *corner = malloc(sizeof(double) * 9 * nt);
    tcc_bvh b = {node_ptr, K, node, box, nnodes, prim, nt, corner};
    tcc_idx stamp[K];
    for (int c = 0; c < K; c++) stamp[c] = -1;
    tcc_idx *rv = malloc(sizeof(tcc_idx) * 2 * nv * K), *rs = malloc(sizeof(tcc_idx) * 2 * nv * K);
    tcc_idx *ht = malloc(sizeof(tcc_idx) * 2 * nv * K);
    int compared = 0, found = 0, mismatched = 0, line_compared = 0, line_mismatched = 0, blocked_mismatched = 0,
        blocked_any = 0;
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
                    /* both rays in one traversal (tcc_bvh_line): slot `slot` of the line along +n */
                    double n0[3] = {nrm[3 * v], nrm[3 * v + 1], nrm[3 * v + 2]}, w0 = 0.5, w1 = -0.5;
                    tcc_idx lt[2] = {-1, -1};
                    tcc_bvh_line(&tm, &b, c, m->x + 3 * v, n0, 1 << slot, 0.0, &w0, &w1, &ring, v, lt);
                    double lref = slot ? -w1 : w0;
                    line_compared++;
                    if ((lt[slot] >= 0) != isfinite(ref) || (lt[slot] >= 0 && fabs(lref - ref) > 1e-12)) line_mismatched++;
                    /* blocked: whether another triangle is hit within 0.5 m (its ring not skipped) */
                    double stop = 0.5; /* anything hit, other than the first hit, within 0.5 m */
                    int blk = tcc_bvh_blocked(&b, c, m->x + 3 * v, d, -1e-9, stop, lt[slot]);
                    int want = 0;
                    for (tcc_idx f = tptr[c]; f < tptr[c + 1] && !want; f++) {
                        if (stri[f] == lt[slot]) continue;
                        const tcc_idx *tv = m->tri + 3 * stri[f];
                        double tt, uu, ww;
                        if (!tcc_line_triangle(m->x + 3 * v, d, m->x + 3 * tv[0], m->x + 3 * tv[1], m->x + 3 * tv[2], &tt, &uu, &ww))
                            continue;
                        want = uu >= 0 && ww >= 0 && uu + ww <= 1 && tt >= -1e-9 && tt < stop;
                    }
                    blocked_mismatched += blk != want;
                    blocked_any += want;
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
    CHECK(line_mismatched == 0 && line_compared == compared, "bvh line hits vs brute force: %d of %d differ",
          line_mismatched, line_compared);
    CHECK(blocked_mismatched == 0 && blocked_any > 0, "bvh blocked vs brute force: %d differ (%d blocked)",
          blocked_mismatched, blocked_any);
    /* a checked tree reads no index out of range; a corrupt one is an error */
    tcc_error e6 = {0};
    CHECK(tcc_bvh_check(&tm, &b, 0, &e6) == TCC_OK, "a built tree checks: %s", e6.what);
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
    tcc_error e7 = {0};
    CHECK(tcc_bvh_check(&tm, &b, 0, &e7) == TCC_ERR_INDEX, "a checked leaf triangle out of range is an index error");
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
    free(rv); free(rs); free(ht); free(corner);
}

/* A collider's step in one call (detect.c, with measure.c's cluster_state and pair_step): the grid
 * deforming over a closed box that rises through it, and against itself; tracks and measures carried
 * from step to step as the Python detector carries them. Every contact is a vertex with a normal,
 * tracks stay sorted, a vertex the box swallowed is inside with a contact deeper than the thickness,
 * and every full-detection hit is the nearest of the line among the tripped clusters' triangles
 * (brute force); bad input is an error. */
static void build_scene_tree(const tcc_mesh *tm, tcc_idx k, const tcc_idx *tptr, const tcc_idx *tord, tcc_idx **node_ptr,
                             tcc_idx **node, double **box, tcc_idx **prim, double **corner, tcc_idx *nnodes)
{
    tcc_idx rows = tptr[k];
    *node_ptr = malloc(sizeof(tcc_idx) * (k + 1));
    *node = malloc(sizeof(tcc_idx) * 4 * (rows + 1));
    *box = malloc(sizeof(double) * 12 * (rows + 1));
    *prim = malloc(sizeof(tcc_idx) * (rows + 1));
    *corner = malloc(sizeof(double) * 9 * (rows + 1));
    tcc_error err = {0};
    int rc = tcc_bvh_build(tm, tptr, tord, rows, k, *node_ptr, *node, *box, 2 * rows, *prim, nnodes, &err);
    CHECK(rc == TCC_OK, "scene tree: %s", err.what);
}

static void test_detect_pipeline(mesh *m)
{
    enum { K = 6, KB = 2, W = 16 };
    const double th = 0.004, tr = th + 1.5 * 0.003, inflate = 0.5 * (0.003 + th), bo = 1e-6;
    tcc_idx n = m->nv, nt = m->nt;
    /* the cloth: strips of rows, vertex -> triangles, labels, its trees over its own triangles */
    tcc_idx *order = malloc(sizeof(tcc_idx) * n), ptr[K + 1], tptr[K + 1], *labels = malloc(sizeof(tcc_idx) * n);
    strips(n, nt, K, order, ptr, tptr);
    for (int c = 0; c < K; c++)
        for (tcc_idx i = ptr[c]; i < ptr[c + 1]; i++) labels[order[i]] = c;
    tcc_idx *tlab = malloc(sizeof(tcc_idx) * nt), *tord = malloc(sizeof(tcc_idx) * nt), tp2[K + 1] = {0};
    for (tcc_idx f = 0; f < nt; f++) tlab[f] = labels[m->tri[3 * f]];
    for (tcc_idx f = 0; f < nt; f++) tp2[tlab[f] + 1]++;
    for (int c = 0; c < K; c++) tp2[c + 1] += tp2[c];
    {
        tcc_idx fill[K];
        for (int c = 0; c < K; c++) fill[c] = tp2[c];
        for (tcc_idx f = 0; f < nt; f++) tord[fill[tlab[f]]++] = f;
    }
    tcc_idx *vt_ptr = calloc(n + 1, sizeof(tcc_idx)), *vt_tri = malloc(sizeof(tcc_idx) * 3 * nt);
    for (tcc_idx i = 0; i < 3 * nt; i++) vt_ptr[m->tri[i] + 1]++;
    for (tcc_idx v = 0; v < n; v++) vt_ptr[v + 1] += vt_ptr[v];
    {
        tcc_idx *fill = malloc(sizeof(tcc_idx) * n);
        memcpy(fill, vt_ptr, sizeof(tcc_idx) * n);
        for (tcc_idx i = 0; i < 3 * nt; i++) vt_tri[fill[m->tri[i]]++] = i / 3;
        free(fill);
    }
    tcc_idx *bindex = malloc(sizeof(tcc_idx) * (n + 3 * nt)), bptr_c[K + 1]; /* box members: own vertices, triangles' */
    {
        tcc_idx q = 0;
        for (int c = 0; c < K; c++) {
            bptr_c[c] = q;
            for (tcc_idx i = ptr[c]; i < ptr[c + 1]; i++) bindex[q++] = order[i];
            for (tcc_idx f = tp2[c]; f < tp2[c + 1]; f++)
                for (int k = 0; k < 3; k++) bindex[q++] = m->tri[3 * tord[f] + k];
        }
        bptr_c[K] = q;
    }
    tcc_idx *adj = malloc(sizeof(tcc_idx) * 3 * nt);
    uint8_t *flip = calloc(3 * nt, 1);
    for (tcc_idx f = 0; f < nt; f++)
        for (int e = 0; e < 3; e++) {
            tcc_idx a = m->tri[3 * f + e], b = m->tri[3 * f + (e + 1) % 3];
            adj[3 * f + e] = -1;
            for (tcc_idx g = 0; g < nt && adj[3 * f + e] < 0; g++) {
                if (g == f) continue;
                for (int h = 0; h < 3; h++) {
                    tcc_idx c = m->tri[3 * g + h], d = m->tri[3 * g + (h + 1) % 3];
                    if ((c == a && d == b) || (c == b && d == a)) {
                        adj[3 * f + e] = g;
                        flip[3 * f + e] = c == a;
                    }
                }
            }
        }
    tcc_idx *table = malloc(sizeof(tcc_idx) * W * n);
    for (tcc_idx i = 0; i < W * n; i++) table[i] = -1;
    for (tcc_idx v = 0; v < n; v++) table[W * v] = v;
    for (tcc_idx f = 0; f < nt; f++)
        for (int a = 0; a < 3; a++)
            for (int b = 0; b < 3; b++) {
                tcc_idx *row = table + W * m->tri[3 * f + a], vb = m->tri[3 * f + b];
                for (int w = 0; w < W; w++) {
                    if (row[w] == vb) break;
                    if (row[w] < 0) { row[w] = vb; break; }
                }
            }
    tcc_mesh cm = {m->x, n, m->tri, nt, adj, flip};
    tcc_idx *cnp, *cnode, *cprim, cnn = 0;
    double *cbox, *ccorner;
    build_scene_tree(&cm, K, tp2, tord, &cnp, &cnode, &cbox, &cprim, &ccorner, &cnn);
    /* the body: a closed box, its 12 triangles in 2 clusters */
    double bx[24], bprev[24], bvel[24] = {0};
    box_at(bx, 0.0, 0.0, -0.2);
    memcpy(bprev, bx, sizeof bx);
    tcc_idx btlab[12], btord[12], btp[KB + 1] = {0, 6, 12}, border[8] = {0, 1, 2, 3, 4, 5, 6, 7}, bvp[KB + 1] = {0, 4, 8};
    for (int f = 0; f < 12; f++) { btlab[f] = f / 6; btord[f] = f; }
    tcc_idx bbi[8 + 36], bbp[KB + 1];
    {
        tcc_idx q = 0;
        for (int c = 0; c < KB; c++) {
            bbp[c] = q;
            for (int v = 4 * c; v < 4 * c + 4; v++) bbi[q++] = v;
            for (int f = 6 * c; f < 6 * c + 6; f++)
                for (int k = 0; k < 3; k++) bbi[q++] = BOX_T[3 * f + k];
        }
        bbp[KB] = q;
    }
    tcc_idx badj[36];
    uint8_t bflip[36] = {0};
    for (int f = 0; f < 12; f++)
        for (int e = 0; e < 3; e++) {
            tcc_idx a = BOX_T[3 * f + e], b = BOX_T[3 * f + (e + 1) % 3];
            badj[3 * f + e] = -1;
            for (int g = 0; g < 12; g++)
                for (int h = 0; h < 3; h++)
                    if (g != f && BOX_T[3 * g + h] == b && BOX_T[3 * g + (h + 1) % 3] == a) badj[3 * f + e] = g;
        }
    tcc_mesh bm = {bx, 8, BOX_T, 12, badj, bflip};
    tcc_idx *bnp, *bnode, *bprim, bnn = 0;
    double *bbox, *bcorner;
    build_scene_tree(&bm, KB, btp, btord, &bnp, &bnode, &bbox, &bprim, &bcorner, &bnn);
    /* state carried from step to step */
    double *prev = malloc(sizeof(double) * 3 * n), *normals = malloc(sizeof(double) * 3 * n);
    uint8_t *has = calloc(n, 1), *done = calloc(n, 1);
    memcpy(prev, m->x, sizeof(double) * 3 * n);
    tcc_idx crefit[K], brefit[KB];
    for (int c = 0; c < K; c++) crefit[c] = -1;
    for (int c = 0; c < KB; c++) brefit[c] = -1;
    struct target_state {
        tcc_idx *key, *tri, *inside, kt, ni, *okey, *otri, *oin;
        int8_t *side, *oside;
        tcc_idx *keys;
        double *ravg, *rdev;
        tcc_idx nold;
    } st[2];
    for (int k = 0; k < 2; k++) {
        st[k].key = malloc(sizeof(tcc_idx) * 2 * n); st[k].tri = malloc(sizeof(tcc_idx) * 2 * n);
        st[k].side = malloc(2 * n); st[k].inside = malloc(sizeof(tcc_idx) * n);
        st[k].okey = malloc(sizeof(tcc_idx) * 2 * n); st[k].otri = malloc(sizeof(tcc_idx) * 2 * n);
        st[k].oside = malloc(2 * n); st[k].oin = malloc(sizeof(tcc_idx) * n);
        st[k].keys = malloc(sizeof(tcc_idx) * K * K); st[k].ravg = malloc(sizeof(double) * 3 * K * K);
        st[k].rdev = malloc(sizeof(double) * K * K);
        st[k].kt = st[k].ni = st[k].nold = 0;
    }
    tcc_idx *cv = malloc(sizeof(tcc_idx) * n);
    double *depth = malloc(sizeof(double) * n), *cn = malloc(sizeof(double) * 3 * n), *cvel = malloc(sizeof(double) * 3 * n);
    int inside_seen = 0, contacts_seen = 0, bad_contacts = 0, unsorted = 0, full_seen = 0, nearest_bad = 0, hits_seen = 0;
    int clear_bad = 0, clear_credit = 0, credit_bad = 0, credited = 0;
    tcc_error err = {0};
    for (int step = 0; step < 30; step++) {
        box_at(bx, 0.0, 0.0, -0.2 + 0.008 * step); /* rises through the cloth at 8 mm per step */
        for (int i = 0; i < 24; i++) bvel[i] = (bx[i] - bprev[i]) / 1e-3;
        for (tcc_idx v = 0; v < n; v++) m->x[3 * v + 2] = 0.003 * sin(8.0 * m->x[3 * v] + 0.5 * step);
        double cavg[3 * K], cdev[K], clo[3 * K], chi[3 * K], bavg[3 * KB], bdev[KB], blo[3 * KB], bhi[3 * KB];
        CHECK(tcc_cluster_state(m->x, prev, n, order, n, ptr, K, bindex, bptr_c[K], bptr_c, inflate, cavg, cdev, clo, chi,
                                &err) == TCC_OK, "cloth state: %s", err.what);
        CHECK(tcc_cluster_state(bx, bprev, 8, border, 8, bvp, KB, bbi, bbp[KB], bbp, inflate, bavg, bdev, blo, bhi, &err) ==
                  TCC_OK, "body state: %s", err.what);
        memset(done, 0, (size_t)n);
        for (int k = 0; k < 2; k++) {
            int self = k == 1;
            tcc_idx pi[K * K], pj[K * K], np_ = 0, nfull = 0, keys[K * K];
            double ravg[3 * K * K], rdev[K * K], amp[K * K];
            uint8_t full[K * K];
            tcc_pair_step_in ps = {clo, chi, self ? clo : blo, self ? chi : bhi, K, self ? K : KB, self, step == 0,
                                   NULL, 0, cavg, cdev, self ? cavg : bavg, self ? cdev : bdev, st[k].keys, st[k].ravg,
                                   st[k].rdev, st[k].nold, 0.0015, 3.0};
            CHECK(tcc_pair_step(&ps, K * K, pi, pj, full, keys, ravg, rdev, amp, &np_, &nfull, &err) == TCC_OK,
                  "pair step: %s", err.what);
            memcpy(st[k].keys, keys, sizeof(tcc_idx) * np_);
            memcpy(st[k].ravg, ravg, sizeof(double) * 3 * np_);
            memcpy(st[k].rdev, rdev, sizeof(double) * np_);
            st[k].nold = np_;
            tcc_detect_in in;
            memset(&in, 0, sizeof in);
            in.x = m->x; in.x_prev = prev; in.velocity = NULL; in.n = n; in.tri = m->tri; in.nt = nt;
            in.vt_ptr = vt_ptr; in.vt_tri = vt_tri; in.nvt = 3 * nt; in.order = order; in.ptr = ptr; in.labels = labels;
            in.norder = n; in.kc = K; in.normals = normals; in.has_normal = has; in.done = done;
            in.kind = self ? TCC_SELF : TCC_VOLUME;
            if (self) {
                in.target = cm; in.target_prev = prev; in.tri_labels = tlab; in.kb = K; in.box_lo = clo;
                in.box_hi = chi;
                in.ring = (tcc_ring){table, n, W};
                in.bvh = (tcc_bvh){cnp, K, cnode, cbox, cnn, cprim, nt, ccorner};
                in.refit_step = crefit;
            } else {
                in.target = bm; in.target_prev = bprev; in.target_velocity = bvel; in.tri_labels = btlab;
                in.kb = KB; in.box_lo = blo; in.box_hi = bhi;
                in.bvh = (tcc_bvh){bnp, KB, bnode, bbox, bnn, bprim, 12, bcorner};
                in.refit_step = brefit;
            }
            in.step = step; in.pi = pi; in.pj = pj; in.full = full; in.np = np_;
            in.track_key = st[k].key; in.track_tri = st[k].tri; in.track_side = st[k].side; in.kt = st[k].kt;
            in.inside = st[k].inside; in.ninside = self ? 0 : st[k].ni;
            in.thickness = th; in.track_range = tr; in.ray_length = tr; in.inflate = inflate; in.backoff = bo;
            in.first = step == 0;
            /* the pairs' clearance, on odd steps (even ones run without it, as a detector with no credit) */
            double clr[K * K], avg0[3 * K * K], dev0[K * K];
            if (step & 1) {
                in.clearance = clr;
                in.probe_length = 4.0 * tr;
                /* the clearance credit restarts the pairs fully detected in the measure carried to the
                 * next step (detector.py's paper rule, clearance_cap 3) */
                in.rel_avg = st[k].ravg;
                in.rel_dev = st[k].rdev;
                in.credit_unit = 0.0015;
                in.clearance_cap = 3.0;
                memcpy(avg0, st[k].ravg, sizeof(double) * 3 * np_);
                memcpy(dev0, st[k].rdev, sizeof(double) * np_);
            }
            tcc_merge_out out = {st[k].okey, st[k].otri, st[k].oside, 0, st[k].oin, 0, cv, depth, cn, cvel, 0};
            tcc_detect_stats ds;
            int rc = tcc_detect(&in, &out, &ds, &err);
            CHECK(rc == TCC_OK, "step %d %s: %s", step, self ? "self" : "body", err.what);
            if (rc) continue;
            /* NaN for pairs not fully detected; else at least the track range, at most the lines'
             * length; and no triangle of the pair's collider cluster lies on a line of its cloth
             * cluster's vertices nearer than the clearance, beyond the track range (brute force over
             * the box; the cloth's own lines skip their two-ring, not checked here) */
            for (tcc_idx p = 0; p < np_ && (step & 1); p++) {
                if (!full[p]) {
                    clear_bad += !isnan(clr[p]);
                    /* untouched measure */
                    credit_bad += memcmp(avg0 + 3 * p, st[k].ravg + 3 * p, 3 * sizeof(double)) != 0 ||
                                  memcmp(dev0 + p, st[k].rdev + p, sizeof(double)) != 0;
                    continue;
                }
                {
                    /* restarted: no mean motion, the deviation starts at minus the credit, the clearance
                     * beyond the track range in units of its margin, at most 2 (cap 3) thresholds */
                    double r = (clr[p] - th) / (tr - th) - 1.0, want = -0.0015 * (r < 0 ? 0 : (r > 2.0 ? 2.0 : r));
                    credit_bad += !(st[k].ravg[3 * p] == 0.0 && st[k].ravg[3 * p + 1] == 0.0 &&
                                    st[k].ravg[3 * p + 2] == 0.0 && fabs(st[k].rdev[p] - want) <= 1e-15 &&
                                    st[k].rdev[p] <= 0.0 && st[k].rdev[p] >= -2.0 * 0.0015);
                    credited += st[k].rdev[p] < 0.0;
                }
                clear_bad += !(clr[p] >= tr && (self ? clr[p] <= 4.0 * tr : isfinite(clr[p])));
                clear_credit += clr[p] > tr;
                if (self || !(clr[p] > tr)) continue;
                for (tcc_idx i = ptr[pi[p]]; i < ptr[pi[p] + 1]; i++) {
                    tcc_idx v = order[i];
                    for (int slot = 0; slot < 2 && has[v]; slot++) {
                        double sg = slot ? -1.0 : 1.0, d[3] = {normals[3 * v] * sg, normals[3 * v + 1] * sg,
                                                               normals[3 * v + 2] * sg};
                        for (int f = 6 * (int)pj[p]; f < 6 * (int)pj[p] + 6; f++) {
                            const tcc_idx *tv = BOX_T + 3 * f;
                            double t, u, w;
                            if (!tcc_line_triangle(m->x + 3 * v, d, bx + 3 * tv[0], bx + 3 * tv[1], bx + 3 * tv[2], &t,
                                                   &u, &w))
                                continue;
                            if (u >= 0 && w >= 0 && u + w <= 1 && t >= -bo && t > tr && t < clr[p] - 1e-12) clear_bad++;
                        }
                    }
                }
            }
            full_seen += ds.full_pairs > 0;
            hits_seen += (int)ds.hits;
            for (tcc_idx i = 0; i < out.ncontacts; i++) {
                double l = sqrt(cn[3 * i] * cn[3 * i] + cn[3 * i + 1] * cn[3 * i + 1] + cn[3 * i + 2] * cn[3 * i + 2]);
                bad_contacts += !(depth[i] > 0 && isfinite(depth[i]) && fabs(l - 1.0) < 1e-9 && cv[i] >= 0 && cv[i] < n &&
                                  (i == 0 || cv[i] > cv[i - 1]));
            }
            for (tcc_idx i = 1; i < out.ntracks; i++) unsorted += st[k].okey[i] <= st[k].okey[i - 1];
            contacts_seen += (int)out.ncontacts;
            if (!self) {
                inside_seen += (int)out.ninside;
                /* a vertex inside the box has a contact deeper than the thickness */
                for (tcc_idx i = 0; i < out.ninside; i++) {
                    tcc_idx v = st[k].oin[i], j = 0;
                    while (j < out.ncontacts && cv[j] != v) j++;
                    bad_contacts += !(j < out.ncontacts && depth[j] > th);
                }
            }
            /* every tracked hit of a full pair's vertex is no farther than the nearest triangle of the
             * collider along its line (brute force over all of the collider's triangles, within the
             * track range: the track can only be nearer, or an untripped cluster's) */
            for (tcc_idx i = 0; i < out.ntracks && !self; i++) {
                tcc_idx v = st[k].okey[i] >> 1, slot = st[k].okey[i] & 1, f = st[k].otri[i];
                double sg = slot ? -1.0 : 1.0, d[3] = {normals[3 * v] * sg, normals[3 * v + 1] * sg, normals[3 * v + 2] * sg};
                double t, u, w;
                const tcc_idx *tv = BOX_T + 3 * f;
                nearest_bad += !(f >= 0 && f < 12 &&
                                 tcc_line_triangle(m->x + 3 * v, d, bx + 3 * tv[0], bx + 3 * tv[1], bx + 3 * tv[2], &t, &u, &w));
            }
            st[k].kt = out.ntracks;
            memcpy(st[k].key, st[k].okey, sizeof(tcc_idx) * out.ntracks);
            memcpy(st[k].tri, st[k].otri, sizeof(tcc_idx) * out.ntracks);
            memcpy(st[k].side, st[k].oside, (size_t)out.ntracks);
            if (!self) {
                st[k].ni = out.ninside;
                memcpy(st[k].inside, st[k].oin, sizeof(tcc_idx) * out.ninside);
            }
        }
        memcpy(prev, m->x, sizeof(double) * 3 * n);
        memcpy(bprev, bx, sizeof bx);
    }
    CHECK(full_seen > 0 && hits_seen > 0 && contacts_seen > 0, "full detection ran and found contacts (%d, %d, %d)",
          full_seen, hits_seen, contacts_seen);
    CHECK(inside_seen > 0, "the rising box swallowed cloth vertices");
    CHECK(clear_bad == 0 && clear_credit > 0, "pair clearances: %d wrong, %d beyond the track range", clear_bad,
          clear_credit);
    CHECK(credit_bad == 0 && credited > 0, "clearance credits: %d wrong, %d pairs credited", credit_bad, credited);
    CHECK(bad_contacts == 0 && unsorted == 0 && nearest_bad == 0, "contacts %d bad, tracks %d unsorted, %d tracks off their triangles",
          bad_contacts, unsorted, nearest_bad);
    /* bad input: errors, never reads out of bounds */
    {
        tcc_idx pi[1] = {K / 2}, pj[1] = {KB}, key[2] = {4, 2}, tri[2] = {0, 0};
        double blo2[3 * KB], bhi2[3 * KB], bavg2[3 * KB], bdev2[KB];
        box_at(bx, 0.0, 0.0, 0.0); /* around the cloth's middle: its rays reach the box */
        tcc_cluster_state(bx, bprev, 8, border, 8, bvp, KB, bbi, bbp[KB], bbp, inflate, bavg2, bdev2, blo2, bhi2, &err);
        int8_t side[2] = {1, 1};
        uint8_t full[1] = {1};
        tcc_detect_in in;
        memset(&in, 0, sizeof in);
        in.x = m->x; in.x_prev = prev; in.n = n; in.tri = m->tri; in.nt = nt; in.vt_ptr = vt_ptr; in.vt_tri = vt_tri;
        in.nvt = 3 * nt; in.order = order; in.ptr = ptr; in.labels = labels; in.norder = n; in.kc = K;
        in.normals = normals; in.has_normal = has; in.done = done; in.kind = TCC_VOLUME; in.target = bm;
        in.target_prev = bprev; in.tri_labels = btlab; in.kb = KB; in.box_lo = blo2; in.box_hi = bhi2; in.bvh = (tcc_bvh){bnp, KB, bnode, bbox, bnn, bprim, 12, bcorner};
        in.refit_step = brefit; in.step = 99; in.pi = pi; in.pj = pj; in.full = full; in.np = 1;
        in.thickness = th; in.track_range = tr; in.ray_length = tr; in.inflate = inflate; in.backoff = bo;
        tcc_merge_out out = {st[0].okey, st[0].otri, st[0].oside, 0, st[0].oin, 0, cv, depth, cn, cvel, 0};
        tcc_detect_stats ds;
        tcc_error e1 = {0}, e2 = {0}, e3 = {0}, e4 = {0};
        CHECK(tcc_detect(&in, &out, &ds, &e1) == TCC_ERR_VALUE, "a pair's collider cluster out of range is an error");
        pj[0] = 0;
        in.track_key = key; in.track_tri = tri; in.track_side = side; in.kt = 2;
        CHECK(tcc_detect(&in, &out, &ds, &e2) == TCC_ERR_VALUE, "unsorted track keys are an error");
        in.kt = 0;
        in.kind = 7;
        CHECK(tcc_detect(&in, &out, &ds, &e3) == TCC_ERR_VALUE, "an unknown kind is an error");
        in.kind = TCC_VOLUME;
        tcc_error e5 = {0}, e6 = {0};
        labels[0] = K;
        CHECK(tcc_detect(&in, &out, &ds, &e5) == TCC_ERR_INDEX, "a cloth label out of range is an index error");
        labels[0] = 0;
        btlab[3] = KB;
        CHECK(tcc_detect(&in, &out, &ds, &e6) == TCC_ERR_INDEX, "a collider triangle's cluster out of range is an index error");
        btlab[3] = 0;
        tcc_idx keepn = bnode[2 * bnp[0]];
        bnode[2 * bnp[0]] = bnp[0]; /* the root its own child */
        brefit[0] = brefit[1] = -1;
        memset(done, 0, (size_t)n);
        int rc4 = tcc_detect(&in, &out, &ds, &e4);
        CHECK(rc4 == TCC_ERR_INDEX, "a corrupt tree is an index error (rc %d: %s)", rc4, e4.what);
        bnode[2 * bnp[0]] = keepn;
    }
    for (tcc_idx v = 0; v < n; v++) m->x[3 * v + 2] = 0.0;
    for (int k = 0; k < 2; k++) {
        free(st[k].key); free(st[k].tri); free(st[k].side); free(st[k].inside); free(st[k].okey); free(st[k].otri);
        free(st[k].oside); free(st[k].oin); free(st[k].keys); free(st[k].ravg); free(st[k].rdev);
    }
    free(order); free(labels); free(tlab); free(tord); free(vt_ptr); free(vt_tri); free(bindex); free(adj); free(flip);
    free(table); free(cnp); free(cnode); free(cbox); free(cprim); free(ccorner); free(bnp); free(bnode); free(bbox);
    free(bprim); free(bcorner); free(prev); free(normals); free(has); free(done); free(cv); free(depth); free(cn); free(cvel);
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

/* collide.h's branch-free table checks against the branchy ones they stand for (every per-call check
 * of a whole table goes through them): edge values of the int64 range and of the doubles. */
static void test_table_checks(void)
{
    const tcc_idx vals[] = {0, 1, 2, 5, 6, 7, -1, -2, INT64_MIN, INT64_MIN + 1, INT64_MAX, INT64_MAX - 1,
                            (tcc_idx)1 << 62, -((tcc_idx)1 << 62)};
    const tcc_idx bounds[] = {-3, 0, 1, 2, 6, 7, INT64_MAX};
    const int nv = (int)(sizeof vals / sizeof vals[0]);
    for (int b = 0; b < (int)(sizeof bounds / sizeof bounds[0]); b++)
        for (int i = 0; i < nv; i++)
            for (int j = 0; j < nv; j++) {
                tcc_idx a[5] = {0, vals[i], 0, vals[j], 0}; /* a bad entry among good ones (bound > 0) */
                int want = 1;
                for (int k = 0; k < 5; k++) want &= a[k] >= 0 && a[k] < bounds[b];
                CHECK(tcc_all_in_range(a, 5, bounds[b]) == want, "in range: %lld, %lld in [0, %lld)", (long long)vals[i],
                      (long long)vals[j], (long long)bounds[b]);
                CHECK(tcc_all_in_range(a + 1, 1, bounds[b]) == (vals[i] >= 0 && vals[i] < bounds[b]),
                      "in range: %lld alone in [0, %lld)", (long long)vals[i], (long long)bounds[b]);
            }
    CHECK(tcc_all_in_range(vals, 0, -1) == 1, "an empty table is in any range");
    const double xs[] = {0.0, -0.0, 1.0, -1.5, DBL_MAX, -DBL_MAX, DBL_MIN, 4.9e-324, -4.9e-324, INFINITY, -INFINITY,
                         NAN, -NAN, 1e308, 3.0e-300};
    const int nx = (int)(sizeof xs / sizeof xs[0]);
    for (int i = 0; i < nx; i++)
        for (int j = 0; j < nx; j++) {
            double x[7] = {1.0, 2.0, xs[i], 3.0, xs[j], 4.0, 5.0};
            CHECK(tcc_all_finite(x, 7) == (isfinite(xs[i]) && isfinite(xs[j])), "finite: %g, %g", xs[i], xs[j]);
        }
    CHECK(tcc_all_finite(xs, 0) == 1, "an empty table is finite");
}

int main(void)
{
    test_table_checks();
    mesh m = grid();
    test_measure_and_detection_steps(&m);
    test_ccd(&m);
    test_swept_step(&m);
    test_swept_build(&m);
    test_bvh(&m);
    test_impact(&m, 0);
    test_detect_pipeline(&m);
    tear(&m);
    test_measure_and_detection_steps(&m);
    test_swept_step(&m);
    test_swept_build(&m);
    test_bvh(&m);
    test_impact(&m, 1);
    test_detect_pipeline(&m);
    free(m.x);
    free(m.tri);
    printf("collide: %d checks, %d failures\n", checks, failures);
    return failures;
}
