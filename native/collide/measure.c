/* measure.c - paper section IV-B per step: cluster motion, cluster boxes, close pairs, the
 * relative displacement measure.
 *
 * Close pairs are found by testing every box against every box. At the paper's cluster counts
 * (30 to 1000 clusters of ~100 vertices) that is 1K to 500K box tests, 2 ns each, which a sweep
 * would not beat by enough to be worth its sort; and the row-major order it produces is the order
 * the relative measure's merge needs.
 */
#include "collide.h"

#include <math.h>
#include <stdlib.h>

int tcc_cluster_motion(const double *x, const double *prev, tcc_idx n, const tcc_idx *order, tcc_idx norder,
                       const tcc_idx *ptr, tcc_idx k, double *avg, double *dev, tcc_error *err)
{
    for (tcc_idx c = 0; c < k; c++) {
        tcc_idx s = ptr[c], e = ptr[c + 1];
        if (s < 0 || e < s || e > norder)
            return tcc_fail(err, TCC_ERR_INDEX, "cluster %lld spans [%lld, %lld), outside the %lld members",
                            (long long)c, (long long)s, (long long)e, (long long)norder);
        double sum[4] = {0, 0, 0, 0};
        for (tcc_idx i = s; i < e; i++) {
            tcc_idx v = order[i];
            if (v < 0 || v >= n)
                return tcc_fail(err, TCC_ERR_INDEX, "order[%lld] = %lld is not a vertex index in [0, %lld)",
                                (long long)i, (long long)v, (long long)n);
            double d0 = x[3 * v] - prev[3 * v], d1 = x[3 * v + 1] - prev[3 * v + 1], d2 = x[3 * v + 2] - prev[3 * v + 2];
            sum[0] += d0;
            sum[1] += d1;
            sum[2] += d2;
            sum[3] += d0 * d0 + d1 * d1 + d2 * d2;
        }
        double cnt = e - s > 0 ? (double)(e - s) : 1.0;
        double a0 = sum[0] / cnt, a1 = sum[1] / cnt, a2 = sum[2] / cnt;
        avg[3 * c] = a0;
        avg[3 * c + 1] = a1;
        avg[3 * c + 2] = a2;
        double var = sum[3] / cnt - (a0 * a0 + a1 * a1 + a2 * a2);
        dev[c] = sqrt(var > 0.0 ? var : 0.0);
    }
    return TCC_OK;
}

int tcc_cluster_boxes(const double *x, tcc_idx n, const tcc_idx *index, tcc_idx nindex, const tcc_idx *ptr,
                      tcc_idx k, double inflate, double *lo, double *hi, tcc_error *err)
{
    for (tcc_idx c = 0; c < k; c++) {
        tcc_idx s = ptr[c], e = ptr[c + 1];
        if (s < 0 || e < s || e > nindex)
            return tcc_fail(err, TCC_ERR_INDEX, "box %lld spans [%lld, %lld), outside the %lld members",
                            (long long)c, (long long)s, (long long)e, (long long)nindex);
        double l0 = INFINITY, l1 = INFINITY, l2 = INFINITY, h0 = -INFINITY, h1 = -INFINITY, h2 = -INFINITY;
        double nan = 0.0; /* x - x is NaN for NaN or inf; its sum marks a box that must overlap nothing */
        for (tcc_idx i = s; i < e; i++) {
            tcc_idx v = index[i];
            if (v < 0 || v >= n)
                return tcc_fail(err, TCC_ERR_INDEX, "box member %lld = %lld is not a vertex index in [0, %lld)",
                                (long long)i, (long long)v, (long long)n);
            const double *p = x + 3 * v;
            l0 = p[0] < l0 ? p[0] : l0;
            l1 = p[1] < l1 ? p[1] : l1;
            l2 = p[2] < l2 ? p[2] : l2;
            h0 = p[0] > h0 ? p[0] : h0;
            h1 = p[1] > h1 ? p[1] : h1;
            h2 = p[2] > h2 ? p[2] : h2;
            nan += (p[0] - p[0]) + (p[1] - p[1]) + (p[2] - p[2]);
        }
        double l[3] = {l0, l1, l2}, h[3] = {h0, h1, h2};
        if (nan != 0.0) /* NaN (numpy's minimum / maximum propagate it): overlaps nothing */
            l[0] = l[1] = l[2] = h[0] = h[1] = h[2] = NAN;
        for (int a = 0; a < 3; a++) {
            lo[3 * c + a] = l[a] - inflate;
            hi[3 * c + a] = h[a] + inflate;
        }
    }
    return TCC_OK;
}

void tcc_box_pairs(const double *lo_a, const double *hi_a, tcc_idx ka, const double *lo_b, const double *hi_b,
                   tcc_idx kb, int self_pairs, tcc_idx *out_i, tcc_idx *out_j, tcc_idx cap, tcc_idx *count)
{
    tcc_idx m = 0;
    for (tcc_idx i = 0; i < ka; i++) {
        const double *la = lo_a + 3 * i, *ha = hi_a + 3 * i;
        for (tcc_idx j = self_pairs ? i : 0; j < kb; j++) {
            const double *lb = lo_b + 3 * j, *hb = hi_b + 3 * j;
            if (la[0] <= hb[0] && lb[0] <= ha[0] && la[1] <= hb[1] && lb[1] <= ha[1] && la[2] <= hb[2] &&
                lb[2] <= ha[2]) {
                if (m < cap) {
                    out_i[m] = i;
                    out_j[m] = j;
                }
                m++;
            }
        }
    }
    *count = m;
}

typedef struct {
    tcc_idx key, p;
} keyed;

static int by_key(const void *pa, const void *pb)
{
    const keyed *a = pa, *b = pb;
    return a->key < b->key ? -1 : (a->key > b->key);
}

int tcc_relative_measure(const tcc_idx *old_keys, const double *old_avg, const double *old_dev, tcc_idx nold,
                         const tcc_idx *pi, const tcc_idx *pj, tcc_idx np, const double *avg_a,
                         const double *dev_a, tcc_idx ka, const double *avg_b, const double *dev_b, tcc_idx kb,
                         const uint8_t *force, double threshold, double lookahead, tcc_idx *keys, double *rel_avg,
                         double *rel_dev, double *amplitude, uint8_t *full, tcc_idx *nfull, tcc_error *err)
{
    int sorted = 1;
    for (tcc_idx p = 0; p < np; p++) {
        tcc_idx i = pi[p], j = pj[p];
        if (i < 0 || i >= ka || j < 0 || j >= kb || i > 0x7fffffff || j > 0x7fffffff)
            return tcc_fail(err, TCC_ERR_INDEX, "pair %lld = (%lld, %lld) is not a cluster pair of [0, %lld) x [0, %lld)",
                            (long long)p, (long long)i, (long long)j, (long long)ka, (long long)kb);
        if (p > 0 && ((i << 32) | j) <= ((pi[p - 1] << 32) | pj[p - 1])) sorted = 0;
    }
    for (tcc_idx o = 1; o < nold; o++)
        if (old_keys[o] <= old_keys[o - 1])
            return tcc_fail(err, TCC_ERR_VALUE, "the stored pair keys are not sorted (entry %lld)", (long long)o);
    /* pairs in any order: the stored keys come out sorted, full / amplitude in the caller's order */
    keyed *ord = NULL;
    if (!sorted) {
        ord = malloc(sizeof *ord * (size_t)np);
        if (!ord) return tcc_fail(err, TCC_ERR_NOMEM, "out of memory sorting %lld pairs", (long long)np);
        for (tcc_idx p = 0; p < np; p++) {
            ord[p].key = (pi[p] << 32) | pj[p];
            ord[p].p = p;
        }
        qsort(ord, (size_t)np, sizeof *ord, by_key);
        for (tcc_idx q = 1; q < np; q++)
            if (ord[q].key == ord[q - 1].key) {
                tcc_idx key = ord[q].key;
                free(ord);
                return tcc_fail(err, TCC_ERR_VALUE, "pair (%lld, %lld) is listed twice", (long long)(key >> 32),
                                (long long)(key & 0xffffffff));
            }
    }
    tcc_idx o = 0, nf = 0;
    for (tcc_idx q = 0; q < np; q++) {
        tcc_idx p = ord ? ord[q].p : q;
        tcc_idx i = pi[p], j = pj[p];
        tcc_idx key = (i << 32) | j;
        keys[q] = key;
        /* old_keys is sorted too: one forward merge */
        while (o < nold && old_keys[o] < key) o++;
        double ra0 = 0, ra1 = 0, ra2 = 0, rd = 0;
        if (o < nold && old_keys[o] == key) {
            ra0 = old_avg[3 * o];
            ra1 = old_avg[3 * o + 1];
            ra2 = old_avg[3 * o + 2];
            rd = old_dev[o];
        }
        ra0 += avg_a[3 * i] - avg_b[3 * j];
        ra1 += avg_a[3 * i + 1] - avg_b[3 * j + 1];
        ra2 += avg_a[3 * i + 2] - avg_b[3 * j + 2];
        rd += dev_a[i] + dev_b[j];
        double amp = sqrt(ra0 * ra0 + ra1 * ra1 + ra2 * ra2) + rd;
        int f = amp > threshold || (force && force[p]);
        if (f) {
            ra0 = ra1 = ra2 = rd = 0.0;
            nf++;
        }
        rel_avg[3 * q] = ra0;
        rel_avg[3 * q + 1] = ra1;
        rel_avg[3 * q + 2] = ra2;
        rel_dev[q] = rd;
        amplitude[p] = amp;
        full[p] = (uint8_t)f;
    }
    /* batching: a step that runs full detection anyway also takes the pairs that, at this step's
     * rate, would pass the threshold within `lookahead` steps: together the fixed costs are paid once */
    if (nf > 0 && lookahead > 0.0) {
        for (tcc_idx q = 0; q < np; q++) {
            tcc_idx p = ord ? ord[q].p : q;
            if (full[p]) continue;
            tcc_idx i = pi[p], j = pj[p];
            double d0 = avg_a[3 * i] - avg_b[3 * j], d1 = avg_a[3 * i + 1] - avg_b[3 * j + 1],
                   d2 = avg_a[3 * i + 2] - avg_b[3 * j + 2];
            double rate = sqrt(d0 * d0 + d1 * d1 + d2 * d2) + dev_a[i] + dev_b[j];
            if (!(amplitude[p] + lookahead * rate > threshold)) continue;
            full[p] = 1;
            rel_avg[3 * q] = rel_avg[3 * q + 1] = rel_avg[3 * q + 2] = 0.0;
            rel_dev[q] = 0.0;
            nf++;
        }
    }
    free(ord);
    *nfull = nf;
    return TCC_OK;
}
