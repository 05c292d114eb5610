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

/* Every pair a cluster pair of [0, ka) x [0, kb) that fits a key, and the stored keys ascending.
 * Returns TCC_OK and *sorted = whether the pairs come in ascending key order. */
static int check_pairs(const tcc_idx *pi, const tcc_idx *pj, tcc_idx np, tcc_idx ka, tcc_idx kb,
                       const tcc_idx *old_keys, tcc_idx nold, int *sorted, tcc_error *err)
{
    *sorted = 1;
    for (tcc_idx p = 0; p < np; p++) {
        tcc_idx i = pi[p], j = pj[p];
        if (i < 0 || i >= ka || j < 0 || j >= kb || i > 0x7fffffff || j > 0x7fffffff)
            return tcc_fail(err, TCC_ERR_INDEX, "pair %lld = (%lld, %lld) is not a cluster pair of [0, %lld) x [0, %lld)",
                            (long long)p, (long long)i, (long long)j, (long long)ka, (long long)kb);
        if (p > 0 && ((i << 32) | j) <= ((pi[p - 1] << 32) | pj[p - 1])) *sorted = 0;
    }
    for (tcc_idx o = 1; o < nold; o++)
        if (old_keys[o] <= old_keys[o - 1])
            return tcc_fail(err, TCC_ERR_VALUE, "the stored pair keys are not sorted (entry %lld)", (long long)o);
    return TCC_OK;
}

int tcc_relative_measure(const tcc_idx *old_keys, const double *old_avg, const double *old_dev, tcc_idx nold,
                         const tcc_idx *pi, const tcc_idx *pj, tcc_idx np, const double *avg_a,
                         const double *dev_a, tcc_idx ka, const double *avg_b, const double *dev_b, tcc_idx kb,
                         const uint8_t *force, double threshold, double lookahead, tcc_idx *keys, double *rel_avg,
                         double *rel_dev, double *amplitude, uint8_t *full, tcc_idx *nfull, tcc_error *err)
{
    int sorted, rc = check_pairs(pi, pj, np, ka, kb, old_keys, nold, &sorted, err);
    if (rc != TCC_OK) return rc;
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

int tcc_cluster_state(const double *x, const double *prev, tcc_idx n, const tcc_idx *order, tcc_idx norder,
                      const tcc_idx *ptr, tcc_idx k, const tcc_idx *box_index, tcc_idx nindex, const tcc_idx *box_ptr,
                      double inflate, double *avg, double *dev, double *lo, double *hi, tcc_error *err)
{
    int rc = tcc_cluster_motion(x, prev, n, order, norder, ptr, k, avg, dev, err);
    return rc ? rc : tcc_cluster_boxes(x, n, box_index, nindex, box_ptr, k, inflate, lo, hi, err);
}

int tcc_pair_step(const tcc_pair_step_in *in, tcc_idx cap, tcc_idx *pi, tcc_idx *pj, uint8_t *full, tcc_idx *keys,
                  double *rel_avg, double *rel_dev, double *amplitude, tcc_idx *np, tcc_idx *nfull, tcc_error *err)
{
    tcc_box_pairs(in->lo_a, in->hi_a, in->ka, in->lo_b, in->hi_b, in->kb, in->self_pairs, pi, pj, cap, np);
    *nfull = 0;
    if (*np > cap) return TCC_OK; /* the caller calls again with room for *np */
    tcc_idx m = *np;
    /* forced: every pair of a new collider, or each pair with a cluster a tear changed */
    uint8_t *mask = NULL;
    if (!in->first && in->nforced > 0) {
        tcc_idx km = in->ka > in->kb ? in->ka : in->kb;
        mask = calloc((size_t)(km > 0 ? km : 1), 1);
        if (!mask) return tcc_fail(err, TCC_ERR_NOMEM, "no memory for %lld clusters", (long long)km);
        for (tcc_idx i = 0; i < in->nforced; i++)
            if (in->forced[i] >= 0 && in->forced[i] < km) mask[in->forced[i]] = 1;
    }
    for (tcc_idx p = 0; p < m; p++) {
        int f = in->first;
        if (mask) f = (pi[p] < in->ka && mask[pi[p]]) || (in->self_pairs && pj[p] < in->kb && mask[pj[p]]);
        full[p] = (uint8_t)f;
    }
    free(mask);
    if (!in->avg_a) {
        for (tcc_idx p = 0; p < m; p++) *nfull += full[p];
        return TCC_OK;
    }
    /* full is read as the force and written as the verdict: tcc_relative_measure reads a pair's force
     * before it writes that pair's verdict, once per pair */
    return tcc_relative_measure(in->old_keys, in->old_avg, in->old_dev, in->nold, pi, pj, m, in->avg_a, in->dev_a,
                                in->ka, in->avg_b, in->dev_b, in->kb, (in->first || in->nforced > 0) ? full : NULL,
                                in->threshold, in->lookahead, keys, rel_avg, rel_dev, amplitude, full, nfull, err);
}

/* ------------------------------------------------------------------ the trip rule (issue 15)
 *
 * A bound, not a threshold per step: per close pair (a, b), how far any vertex of a can have moved
 * towards b since b's surface near it was last known, against the clearance that knowledge left.
 *
 * Each cluster's displacement over the step is fitted by an affine field A(x) = t + L (x - c) over
 * its previous positions (c their mean, t the mean displacement, L least squares, regularised:
 * any L gives a valid bound below, the fit only makes it tight). e = the largest residual
 * |d_v - A(x_v)| over the cluster's vertices. A point y of b's surface is a convex combination of
 * b's vertices, so its displacement is A_b(y) + (a residual of length <= e_b). For a vertex x of a
 * and the point y of b nearest to it, |x - y| <= reach while it matters, so the step changes their
 * distance by at most
 *     |d_x - d_y| <= |d_x - A_b(x)| + |L_b| |x - y| + e_b <= max_x |d_x - A_b(x)| + |L_b|_F reach + e_b,
 * and the same with the roles of a and b swapped; the smaller of the two is the pair's bound m.
 * Rigid co-motion (a sleeve on a swinging arm, neighbouring cloth clusters translating and turning
 * together) then costs only its residual, where the paper's ||avg_a - avg_b|| + dev_a + dev_b
 * counts both clusters' rotation spread again at every step. */

#define TCC_FIT TCC_FIT_LEN

static int inv3_sym(const double a[9], double out[9])
{
    double c00 = a[4] * a[8] - a[5] * a[7], c01 = a[5] * a[6] - a[3] * a[8], c02 = a[3] * a[7] - a[4] * a[6];
    double det = a[0] * c00 + a[1] * c01 + a[2] * c02;
    if (!(fabs(det) > 0.0) || !isfinite(det)) return 0;
    double id = 1.0 / det;
    out[0] = c00 * id;
    out[1] = (a[2] * a[7] - a[1] * a[8]) * id;
    out[2] = (a[1] * a[5] - a[2] * a[4]) * id;
    out[3] = c01 * id;
    out[4] = (a[0] * a[8] - a[2] * a[6]) * id;
    out[5] = (a[2] * a[3] - a[0] * a[5]) * id;
    out[6] = c02 * id;
    out[7] = (a[1] * a[6] - a[0] * a[7]) * id;
    out[8] = (a[0] * a[4] - a[1] * a[3]) * id;
    return 1;
}

/* |d_v - t - L (p_v - c)| for vertex v */
static double fit_residual(const double *x, const double *prev, tcc_idx v, const double *f)
{
    const double *p = prev + 3 * v;
    double q0 = p[0] - f[0], q1 = p[1] - f[1], q2 = p[2] - f[2];
    const double *L = f + 6;
    double r0 = x[3 * v] - p[0] - f[3] - (L[0] * q0 + L[1] * q1 + L[2] * q2);
    double r1 = x[3 * v + 1] - p[1] - f[4] - (L[3] * q0 + L[4] * q1 + L[5] * q2);
    double r2 = x[3 * v + 2] - p[2] - f[5] - (L[6] * q0 + L[7] * q1 + L[8] * q2);
    return sqrt(r0 * r0 + r1 * r1 + r2 * r2);
}

int tcc_cluster_fit(const double *x, const double *prev, tcc_idx n, const tcc_idx *order, tcc_idx norder,
                    const tcc_idx *ptr, tcc_idx k, double reach, double *fit, tcc_error *err)
{
    for (tcc_idx c = 0; c < k; c++) {
        tcc_idx s = ptr[c], e = ptr[c + 1];
        if (s < 0 || e < s || e > norder)
            return tcc_fail(err, TCC_ERR_INDEX, "cluster %lld spans [%lld, %lld), outside the %lld members",
                            (long long)c, (long long)s, (long long)e, (long long)norder);
        double *f = fit + TCC_FIT * c;
        double cen[3] = {0, 0, 0}, t[3] = {0, 0, 0};
        for (tcc_idx q = s; q < e; q++) {
            tcc_idx v = order[q];
            if (v < 0 || v >= n)
                return tcc_fail(err, TCC_ERR_INDEX, "order[%lld] = %lld is not a vertex index in [0, %lld)",
                                (long long)q, (long long)v, (long long)n);
            for (int a = 0; a < 3; a++) {
                cen[a] += prev[3 * v + a];
                t[a] += x[3 * v + a] - prev[3 * v + a];
            }
        }
        double cnt = e > s ? (double)(e - s) : 1.0;
        double C[9] = {0}, S[9] = {0};
        for (int a = 0; a < 3; a++) {
            cen[a] /= cnt;
            t[a] /= cnt;
        }
        for (tcc_idx q = s; q < e; q++) {
            tcc_idx v = order[q];
            double p[3], d[3];
            for (int a = 0; a < 3; a++) {
                p[a] = prev[3 * v + a] - cen[a];
                d[a] = x[3 * v + a] - prev[3 * v + a] - t[a];
            }
            for (int a = 0; a < 3; a++)
                for (int b = 0; b < 3; b++) {
                    C[3 * a + b] += p[a] * p[b];
                    S[3 * a + b] += d[a] * p[b];
                }
        }
        /* A flat cluster's covariance is singular along its normal: regularise by a thousandth of its
         * mean spread so L stays bounded there (the residual e measures whatever this costs). */
        double reg = 1e-3 * (C[0] + C[4] + C[8]) / 3.0 + 1e-300;
        C[0] += reg;
        C[4] += reg;
        C[8] += reg;
        double Ci[9], L[9] = {0};
        if (inv3_sym(C, Ci))
            for (int a = 0; a < 3; a++)
                for (int b = 0; b < 3; b++) L[3 * a + b] = S[3 * a] * Ci[b] + S[3 * a + 1] * Ci[3 + b] + S[3 * a + 2] * Ci[6 + b];
        double ln = 0.0;
        for (int a = 0; a < 9; a++) ln += L[a] * L[a];
        ln = sqrt(ln);
        if (!isfinite(ln)) { /* NaN / inf motion: the field is unusable, the residual below says so */
            for (int a = 0; a < 9; a++) L[a] = 0.0;
            ln = 0.0;
        }
        for (int a = 0; a < 3; a++) {
            f[a] = cen[a];
            f[3 + a] = t[a];
        }
        for (int a = 0; a < 9; a++) f[6 + a] = L[a];
        double emax = 0.0;
        for (tcc_idx q = s; q < e; q++) {
            double r = fit_residual(x, prev, order[q], f);
            emax = r > emax || r != r ? r : emax;
        }
        /* pure translation (L = 0) when that bounds tighter: a fit that only follows noise */
        double emax0 = 0.0;
        for (int a = 0; a < 9; a++) f[6 + a] = 0.0;
        for (tcc_idx q = s; q < e; q++) {
            double r = fit_residual(x, prev, order[q], f);
            emax0 = r > emax0 || r != r ? r : emax0;
        }
        if (emax + ln * reach < emax0) {
            for (int a = 0; a < 9; a++) f[6 + a] = L[a];
        } else {
            emax = emax0;
            ln = 0.0;
        }
        f[15] = emax;
        f[16] = ln;
    }
    return TCC_OK;
}

/* max over the members of cluster `ca` (of the object x_a / prev_a) of |d_x - A_b(x)|, + e_b + |L_b| reach */
static double one_way(const double *xa, const double *pa, const tcc_idx *oa, const tcc_idx *pta, tcc_idx ca,
                      const double *fb, double reach)
{
    double m = 0.0;
    for (tcc_idx q = pta[ca]; q < pta[ca + 1]; q++) {
        double r = fit_residual(xa, pa, oa[q], fb);
        m = r > m || r != r ? r : m;
    }
    return m + fb[15] + fb[16] * reach;
}

int tcc_pair_motion(const tcc_idx *pi, const tcc_idx *pj, tcc_idx np, const double *xa, const double *pa,
                    const tcc_idx *oa, const tcc_idx *pta, const double *fa, tcc_idx ka, const double *xb,
                    const double *pb, const tcc_idx *ob, const tcc_idx *ptb, const double *fb, tcc_idx kb,
                    double reach, double *m, tcc_error *err)
{
    /* members were checked by tcc_cluster_fit against the same order / ptr arrays */
    for (tcc_idx p = 0; p < np; p++) {
        tcc_idx i = pi[p], j = pj[p];
        if (i < 0 || i >= ka || j < 0 || j >= kb)
            return tcc_fail(err, TCC_ERR_INDEX, "pair %lld = (%lld, %lld) is not a cluster pair of [0, %lld) x [0, %lld)",
                            (long long)p, (long long)i, (long long)j, (long long)ka, (long long)kb);
        double ab = one_way(xa, pa, oa, pta, i, fb + TCC_FIT * j, reach);
        double ba = one_way(xb, pb, ob, ptb, j, fa + TCC_FIT * i, reach);
        double v = ab < ba ? ab : ba;
        m[p] = v == v ? v : INFINITY; /* NaN motion: unbounded, full detection */
    }
    return TCC_OK;
}

/* Euclidean distance between two boxes given inflated by `inflate` (0 when they overlap; NaN
 * boxes give 0, the conservative answer) */
static double box_gap(const double *la, const double *ha, const double *lb, const double *hb, double inflate)
{
    double g2 = 0.0;
    for (int a = 0; a < 3; a++) {
        double g1 = lb[a] - ha[a] + 2.0 * inflate, g2a = la[a] - hb[a] + 2.0 * inflate;
        double g = g1 > g2a ? g1 : g2a;
        if (g > 0.0) g2 += g * g;
    }
    return sqrt(g2);
}

int tcc_trip_measure(const tcc_idx *old_keys, const double *old_used, tcc_idx nold, const tcc_idx *pi,
                     const tcc_idx *pj, tcc_idx np, const double *m, const double *lo_a, const double *hi_a,
                     tcc_idx ka, const double *lo_b, const double *hi_b, tcc_idx kb, double inflate, double budget,
                     double thickness, const uint8_t *force, double lookahead, tcc_idx *keys, double *used,
                     double *amplitude, uint8_t *full, tcc_idx *nfull, tcc_error *err)
{
    int sorted, rc = check_pairs(pi, pj, np, ka, kb, old_keys, nold, &sorted, err);
    if (rc != TCC_OK) return rc;
    if (!sorted)
        return tcc_fail(err, TCC_ERR_VALUE, "the pairs must come in row-major order, each once (tcc_box_pairs' order)");
    tcc_idx o = 0, nf = 0;
    for (tcc_idx p = 0; p < np; p++) {
        tcc_idx i = pi[p], j = pj[p], key = (i << 32) | j;
        keys[p] = key;
        while (o < nold && old_keys[o] < key) o++;
        /* the clearance the boxes prove now: no vertex of a is nearer than the gap to b */
        double fresh = budget - (box_gap(lo_a + 3 * i, hi_a + 3 * i, lo_b + 3 * j, hi_b + 3 * j, inflate) - thickness);
        fresh = fresh > 0.0 ? fresh : 0.0;
        /* a known pair spends this step's bound; a new one starts from what its boxes prove */
        double u = (o < nold && old_keys[o] == key) ? old_used[o] + m[p] : fresh;
        if (fresh < u) u = fresh;
        if (u != u) u = INFINITY;
        int f = u > budget || (force && force[p]);
        amplitude[p] = u;
        if (f) nf++;
        full[p] = (uint8_t)f;
        used[p] = f ? 0.0 : u;
    }
    /* batching (measure.py): a step that runs full detection anyway takes the pairs that at this
     * step's bound would spend their clearance within `lookahead` steps */
    if (nf > 0 && lookahead > 0.0)
        for (tcc_idx p = 0; p < np; p++)
            if (!full[p] && amplitude[p] + lookahead * m[p] > budget) {
                full[p] = 1;
                used[p] = 0.0;
                nf++;
            }
    *nfull = nf;
    return TCC_OK;
}
