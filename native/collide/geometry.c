/* geometry.c - error reporting, vertex normals, line/triangle test and the rigid fit of a cluster.
 *
 * The rigid fit is what lets an Embree scene of a cluster outlive the cluster's motion: the scene
 * stays in the pose it was built in, and each query moves the rays into that pose instead of
 * moving the triangles (embreex cannot update vertices). Horn's closed form (the rotation is the
 * eigenvector of the largest eigenvalue of a symmetric 4x4 matrix, found by Jacobi sweeps) is
 * exact, always proper (det +1, no reflection fix-up as with an SVD) and a few hundred flops.
 */
#include "collide.h"
#include "vecmath.h"

#include <math.h>

#include <stdarg.h>
#include <stdio.h>
#include <string.h>

int tcc_fail(tcc_error *err, int code, const char *fmt, ...)
{
    if (err && err->code == TCC_OK) {
        err->code = code;
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(err->what, sizeof err->what, fmt, ap);
        va_end(ap);
    }
    return code;
}

int tcc_vertex_normals(const tcc_mesh *m, double *normals, uint8_t *has_normal, tcc_error *err)
{
    memset(normals, 0, sizeof(double) * 3 * (size_t)m->nv);
    for (tcc_idx f = 0; f < m->nt; f++) {
        const tcc_idx *t = m->tri + 3 * f;
        for (int k = 0; k < 3; k++)
            if (t[k] < 0 || t[k] >= m->nv)
                return tcc_fail(err, TCC_ERR_INDEX, "triangles[%lld, %d] = %lld is not a vertex index in [0, %lld)",
                                (long long)f, k, (long long)t[k], (long long)m->nv);
        const double *a = m->x + 3 * t[0], *b = m->x + 3 * t[1], *c = m->x + 3 * t[2];
        double e1[3], e2[3], cr[3];
        sub3(b, a, e1);
        sub3(c, a, e2);
        cross3(e1, e2, cr); /* |cr| = twice the area: the area weighting */
        for (int k = 0; k < 3; k++) {
            double *acc = normals + 3 * t[k];
            acc[0] += cr[0];
            acc[1] += cr[1];
            acc[2] += cr[2];
        }
    }
    for (tcc_idx v = 0; v < m->nv; v++) {
        double *nv = normals + 3 * v;
        double len = sqrt(dot3(nv, nv));
        double s = len > 0 ? len : 1.0;
        nv[0] /= s;
        nv[1] /= s;
        nv[2] /= s;
        if (has_normal) has_normal[v] = dot3(nv, nv) > 0.5;
    }
    return TCC_OK;
}

int tcc_vertex_normal(const tcc_mesh *m, const tcc_idx *vt_ptr, const tcc_idx *vt_tri, tcc_idx nvt, tcc_idx v,
                      double *normals, uint8_t *has_normal, tcc_error *err)
{
    tcc_idx a0 = vt_ptr[v], a1 = vt_ptr[v + 1];
    if (a0 < 0 || a1 < a0 || a1 > nvt)
        return tcc_fail(err, TCC_ERR_INDEX, "vertex %lld's triangles span [%lld, %lld), outside the %lld listed",
                        (long long)v, (long long)a0, (long long)a1, (long long)nvt);
    double acc[3] = {0.0, 0.0, 0.0};
    for (tcc_idx j = a0; j < a1; j++) {
        tcc_idx f = vt_tri[j];
        if (f < 0 || f >= m->nt)
            return tcc_fail(err, TCC_ERR_INDEX, "triangle %lld is not in [0, %lld)", (long long)f, (long long)m->nt);
        const tcc_idx *t = m->tri + 3 * f;
        for (int a = 0; a < 3; a++)
            if (t[a] < 0 || t[a] >= m->nv)
                return tcc_fail(err, TCC_ERR_INDEX, "triangles[%lld, %d] = %lld is not a vertex index in [0, %lld)",
                                (long long)f, a, (long long)t[a], (long long)m->nv);
        double e1[3], e2[3], cr[3];
        sub3(m->x + 3 * t[1], m->x + 3 * t[0], e1);
        sub3(m->x + 3 * t[2], m->x + 3 * t[0], e2);
        cross3(e1, e2, cr);
        acc[0] += cr[0];
        acc[1] += cr[1];
        acc[2] += cr[2];
    }
    double len = sqrt(dot3(acc, acc));
    double sc = len > 0 ? len : 1.0;
    double *nv = normals + 3 * v;
    nv[0] = acc[0] / sc;
    nv[1] = acc[1] / sc;
    nv[2] = acc[2] / sc;
    has_normal[v] = dot3(nv, nv) > 0.5;
    return TCC_OK;
}

int tcc_cluster_normals(const tcc_mesh *m, const tcc_idx *vt_ptr, const tcc_idx *vt_tri, tcc_idx nvt,
                        const tcc_idx *order, tcc_idx norder, const tcc_idx *ptr, tcc_idx k, const tcc_idx *clusters,
                        tcc_idx q, double *normals, uint8_t *has_normal, uint8_t *done, tcc_error *err)
{
    for (tcc_idx g = 0; g < q; g++) {
        tcc_idx c = clusters[g];
        if (c < 0 || c >= k)
            return tcc_fail(err, TCC_ERR_INDEX, "cluster %lld is not in [0, %lld)", (long long)c, (long long)k);
        if (done) {
            if (done[c]) continue;
            done[c] = 1;
        }
        tcc_idx s = ptr[c], e = ptr[c + 1];
        if (s < 0 || e < s || e > norder)
            return tcc_fail(err, TCC_ERR_INDEX, "cluster %lld spans [%lld, %lld), outside the %lld members",
                            (long long)c, (long long)s, (long long)e, (long long)norder);
        for (tcc_idx i = s; i < e; i++) {
            tcc_idx v = order[i];
            if (v < 0 || v >= m->nv)
                return tcc_fail(err, TCC_ERR_INDEX, "order[%lld] = %lld is not a vertex index in [0, %lld)",
                                (long long)i, (long long)v, (long long)m->nv);
            int rc = tcc_vertex_normal(m, vt_ptr, vt_tri, nvt, v, normals, has_normal, err);
            if (rc) return rc;
        }
    }
    return TCC_OK;
}

int tcc_line_triangle(const double o[3], const double d[3], const double a[3], const double b[3],
                      const double c[3], double *t, double *u, double *v)
{
    return tcc_line_triangle_inline(o, d, a, b, c, t, u, v);
}

/* Eigen decomposition of a symmetric 4x4 matrix (cyclic Jacobi); columns of V are eigenvectors. */
static void jacobi4(double A[4][4], double V[4][4])
{
    for (int i = 0; i < 4; i++)
        for (int j = 0; j < 4; j++) V[i][j] = i == j;
    for (int sweep = 0; sweep < 64; sweep++) {
        double off = 0.0, diag = 0.0;
        for (int p = 0; p < 4; p++) {
            diag += A[p][p] * A[p][p];
            for (int q = p + 1; q < 4; q++) off += A[p][q] * A[p][q];
        }
        if (off <= 1e-30 * diag || off == 0.0) break;
        for (int p = 0; p < 3; p++)
            for (int q = p + 1; q < 4; q++) {
                if (A[p][q] == 0.0) continue;
                double theta = (A[q][q] - A[p][p]) / (2.0 * A[p][q]);
                double t = (theta >= 0 ? 1.0 : -1.0) / (fabs(theta) + sqrt(theta * theta + 1.0));
                double c = 1.0 / sqrt(t * t + 1.0), s = t * c;
                for (int k = 0; k < 4; k++) { /* A P */
                    double akp = A[k][p], akq = A[k][q];
                    A[k][p] = c * akp - s * akq;
                    A[k][q] = s * akp + c * akq;
                }
                for (int k = 0; k < 4; k++) { /* P^T (A P) */
                    double apk = A[p][k], aqk = A[q][k];
                    A[p][k] = c * apk - s * aqk;
                    A[q][k] = s * apk + c * aqk;
                }
                for (int k = 0; k < 4; k++) {
                    double vkp = V[k][p], vkq = V[k][q];
                    V[k][p] = c * vkp - s * vkq;
                    V[k][q] = s * vkp + c * vkq;
                }
            }
    }
}

int tcc_rigid_fit(const tcc_mesh *m, const double *ref, const tcc_idx *tris, tcc_idx k, double R[9],
                  double centre[3], double ref_centre[3], double *resid2, tcc_error *err)
{
    double c0[3] = {0, 0, 0}, c1[3] = {0, 0, 0};
    for (tcc_idx i = 0; i < k; i++) {
        tcc_idx f = tris[i];
        if (f < 0 || f >= m->nt)
            return tcc_fail(err, TCC_ERR_INDEX, "scene triangle %lld is not in [0, %lld)", (long long)f, (long long)m->nt);
        for (int j = 0; j < 3; j++) {
            tcc_idx v = m->tri[3 * f + j];
            if (v < 0 || v >= m->nv)
                return tcc_fail(err, TCC_ERR_INDEX, "triangles[%lld, %d] = %lld is not a vertex index in [0, %lld)",
                                (long long)f, j, (long long)v, (long long)m->nv);
            for (int a = 0; a < 3; a++) {
                c0[a] += ref[9 * i + 3 * j + a];
                c1[a] += m->x[3 * v + a];
            }
        }
    }
    double w = k > 0 ? 1.0 / (3.0 * (double)k) : 0.0;
    for (int a = 0; a < 3; a++) {
        c0[a] *= w;
        c1[a] *= w;
    }
    double S[3][3] = {{0}};
    for (tcc_idx i = 0; i < k; i++) {
        tcc_idx f = tris[i];
        for (int j = 0; j < 3; j++) {
            const double *r = ref + 9 * i + 3 * j, *x = m->x + 3 * m->tri[3 * f + j];
            double p[3] = {r[0] - c0[0], r[1] - c0[1], r[2] - c0[2]};
            double q[3] = {x[0] - c1[0], x[1] - c1[1], x[2] - c1[2]};
            for (int a = 0; a < 3; a++)
                for (int b = 0; b < 3; b++) S[a][b] += p[a] * q[b];
        }
    }
    /* Horn (1987): the unit quaternion of the rotation ref -> now maximises q^T N q. */
    double N[4][4] = {
        {S[0][0] + S[1][1] + S[2][2], S[1][2] - S[2][1], S[2][0] - S[0][2], S[0][1] - S[1][0]},
        {S[1][2] - S[2][1], S[0][0] - S[1][1] - S[2][2], S[0][1] + S[1][0], S[2][0] + S[0][2]},
        {S[2][0] - S[0][2], S[0][1] + S[1][0], -S[0][0] + S[1][1] - S[2][2], S[1][2] + S[2][1]},
        {S[0][1] - S[1][0], S[2][0] + S[0][2], S[1][2] + S[2][1], -S[0][0] - S[1][1] + S[2][2]},
    };
    double V[4][4];
    jacobi4(N, V);
    int best = 0;
    for (int i = 1; i < 4; i++)
        if (N[i][i] > N[best][best]) best = i;
    double qw = V[0][best], qx = V[1][best], qy = V[2][best], qz = V[3][best];
    double qn = sqrt(qw * qw + qx * qx + qy * qy + qz * qz);
    if (!(qn > 0)) {
        qw = 1;
        qx = qy = qz = 0;
        qn = 1;
    }
    qw /= qn;
    qx /= qn;
    qy /= qn;
    qz /= qn;
    R[0] = 1 - 2 * (qy * qy + qz * qz);
    R[1] = 2 * (qx * qy - qw * qz);
    R[2] = 2 * (qx * qz + qw * qy);
    R[3] = 2 * (qx * qy + qw * qz);
    R[4] = 1 - 2 * (qx * qx + qz * qz);
    R[5] = 2 * (qy * qz - qw * qx);
    R[6] = 2 * (qx * qz - qw * qy);
    R[7] = 2 * (qy * qz + qw * qx);
    R[8] = 1 - 2 * (qx * qx + qy * qy);
    double worst = 0.0;
    for (tcc_idx i = 0; i < k; i++) {
        tcc_idx f = tris[i];
        for (int j = 0; j < 3; j++) {
            const double *r = ref + 9 * i + 3 * j, *x = m->x + 3 * m->tri[3 * f + j];
            double p[3] = {r[0] - c0[0], r[1] - c0[1], r[2] - c0[2]};
            double e2 = 0.0;
            for (int a = 0; a < 3; a++) {
                double e = R[3 * a] * p[0] + R[3 * a + 1] * p[1] + R[3 * a + 2] * p[2] - (x[a] - c1[a]);
                e2 += e * e;
            }
            if (!(e2 <= worst)) worst = isnan(e2) ? INFINITY : e2; /* a NaN cluster never fits */
        }
    }
    for (int a = 0; a < 3; a++) {
        centre[a] = c1[a];
        ref_centre[a] = c0[a];
    }
    *resid2 = worst;
    return TCC_OK;
}
