/* solver.c - the linear solve of one implicit Euler sub-step: conjugate gradients on the constraint
 * manifold (the filtered PCG of Baraff & Witkin 1998), preconditioned with the inverse 3x3 diagonal
 * blocks (block Jacobi), warm-started, and solved for the velocity change rather than the velocity.
 *
 * The matrix is never formed beyond fem.c's diagonal and pair blocks: the solver only needs its
 * product (tc_matvec) and the constraint filter (constraints.c).
 */
#include "core.h"

#include <math.h>
#include <string.h>

/* The preconditioner: the inverse of each vertex's 3x3 diagonal block of A. */
void tc_precondition_build(tc_cloth *c)
{
    const double *D = tc_vec_ptr(&c->diag);
    double *P = tc_vec_ptr(&c->pinv);
    for (int32_t i = 0; i < c->nv; i++) {
        const double *a = D + 9 * i;
        double *o = P + 9 * i;
        double c00 = a[4] * a[8] - a[5] * a[7], c01 = a[5] * a[6] - a[3] * a[8], c02 = a[3] * a[7] - a[4] * a[6];
        double det = a[0] * c00 + a[1] * c01 + a[2] * c02;
        if (!(fabs(det) > TC_SINGULAR_DET)) {  /* cannot happen with positive masses; stay safe */
            memset(o, 0, 9 * sizeof(double));
            continue;
        }
        double id = 1.0 / det;
        o[0] = c00 * id; o[1] = (a[2] * a[7] - a[1] * a[8]) * id; o[2] = (a[1] * a[5] - a[2] * a[4]) * id;
        o[3] = c01 * id; o[4] = (a[0] * a[8] - a[2] * a[6]) * id; o[5] = (a[2] * a[3] - a[0] * a[5]) * id;
        o[6] = c02 * id; o[7] = (a[1] * a[6] - a[0] * a[7]) * id; o[8] = (a[0] * a[4] - a[1] * a[3]) * id;
    }
}

static void precondition(const tc_cloth *c, const double *r, double *z)
{
    const double *P = tc_vec_ptr(&c->pinv);
    for (int32_t i = 0; i < c->nv; i++) {
        const double *p = P + 9 * i, *x = r + 3 * i;
        double *o = z + 3 * i;
        o[0] = p[0] * x[0] + p[1] * x[1] + p[2] * x[2];
        o[1] = p[3] * x[0] + p[4] * x[1] + p[5] * x[2];
        o[2] = p[6] * x[0] + p[7] * x[1] + p[8] * x[2];
    }
}

static double dotn(const double *a, const double *b, size_t n)
{
    double s = 0.0;
    for (size_t i = 0; i < n; i++) s += a[i] * b[i];
    return s;
}

/* Solves A v = b on the constraint manifold {v_i = S_i v_i + fix_i}; v holds the warm start. */
TC_HOT static int pcg(tc_cloth *c, double *v, const double *b, const double *fix, double floor, double *residual)
{
    const size_t n3 = 3 * (size_t)c->nv;
    double *r = tc_vec_ptr(&c->sr), *z = tc_vec_ptr(&c->sz), *p = tc_vec_ptr(&c->sp), *q = tc_vec_ptr(&c->sq);
    tc_constraint_project(c, v, fix);  /* the warm start onto the constraint manifold */
    memcpy(q, b, n3 * sizeof(double));
    tc_constraint_filter(c, q);
    precondition(c, q, z);
    tc_constraint_filter(c, z);
    double bnorm = dotn(q, z, n3);
    if (bnorm < floor) bnorm = floor;
    tc_matvec(c, v, q);
    for (size_t k = 0; k < n3; k++) r[k] = b[k] - q[k];
    tc_constraint_filter(c, r);
    precondition(c, r, z);
    tc_constraint_filter(c, z);
    memcpy(p, z, n3 * sizeof(double));
    double rz = dotn(r, z, n3);
    const double tol2 = c->solver.cg_tolerance * c->solver.cg_tolerance;
    int it = 0;
    if (bnorm <= 0) bnorm = TC_TINY;
    while (it < c->solver.cg_max_iterations && rz > tol2 * bnorm) {
        tc_matvec(c, p, q);
        tc_constraint_filter(c, q);
        double pq = dotn(p, q, n3);
        if (!(pq > 0)) break;  /* A is SPD on the manifold; a non-positive curvature means round-off */
        double alpha = rz / pq;
        for (size_t k = 0; k < n3; k++) { v[k] += alpha * p[k]; r[k] -= alpha * q[k]; }
        precondition(c, r, z);
        tc_constraint_filter(c, z);
        double rz2 = dotn(r, z, n3);
        double beta = rz2 / rz;
        for (size_t k = 0; k < n3; k++) p[k] = z[k] + beta * p[k];
        rz = rz2;
        it++;
    }
    *residual = sqrt(rz / bnorm);
    return it;
}

/* Solves A v = b for the change du = v - v0 instead of v itself. The tolerance is then relative to
 * the forces (b - A v0) rather than to the momentum M v0 in b: a fast-moving cloth otherwise stops
 * iterating while its elastic response is still far off, and those errors pumped energy into
 * folded cloth until it blew up. v holds the warm start on entry (its change from v0 is reused). */
int tc_solve_dv(tc_cloth *c, double *v, const double *v0, const double *b, double *residual)
{
    const size_t n3 = 3 * (size_t)c->nv;
    double *rhs = tc_vec_ptr(&c->sb2), *fix = tc_vec_ptr(&c->sfix), *fixu = tc_vec_ptr(&c->sfix2);
    /* a cloth at rest has almost no net force: without a floor the relative tolerance would
       chase round-off (TC_CG_FLOOR) */
    double floor = 0.0;
    {
        const double *P = tc_vec_ptr(&c->pinv);
        for (int32_t i = 0; i < c->nv; i++) {
            const double *p = P + 9 * i, *x = b + 3 * i;
            floor += x[0] * (p[0] * x[0] + p[1] * x[1] + p[2] * x[2]) + x[1] * (p[3] * x[0] + p[4] * x[1] + p[5] * x[2]) +
                     x[2] * (p[6] * x[0] + p[7] * x[1] + p[8] * x[2]);
        }
        floor *= TC_CG_FLOOR;
    }
    tc_matvec(c, v0, rhs);
    for (size_t k = 0; k < n3; k++) { rhs[k] = b[k] - rhs[k]; v[k] -= v0[k]; }
    /* the constrained components of du: the prescribed velocity minus v0's part along them */
    memcpy(fixu, fix, n3 * sizeof(double));
    tc_constraint_offsets(c, v0, fixu);
    int it = pcg(c, v, rhs, fixu, floor, residual);
    for (size_t k = 0; k < n3; k++) v[k] += v0[k];
    return it;
}
