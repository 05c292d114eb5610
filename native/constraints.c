/* constraints.c - what holds the cloth: pins (zero velocity), handles (vertex sets moved rigidly to
 * an affine target: the grasped part of the cloth) and contacts (a vertex on a surface), and how
 * they enter the step: as velocity filters (Baraff & Witkin 1998).
 *
 * Each sub-step gives every vertex a kind (vflag: free, pinned, handle, contact) and a prescribed
 * velocity (sfix). Pins and handles fix all three components; a contact fixes the velocity along
 * its normal to the touched surface's (inelastic), and a vertex touching several things keeps an
 * orthonormal basis of their normals (snorm, scount). The solver then works on the manifold
 * {v_i = S_i v_i + z_i}: tc_constraint_filter applies S, tc_constraint_project puts a vector on
 * the manifold. After each solve of a sub-step, held contact vertices whose reaction leaves the
 * Coulomb cone slide (kinetic friction joins the right-hand side), contacts whose reaction pulls
 * (adhesion) are released, and the step is solved again (step.c's rounds). Every vertex carries
 * how its contacts ended a sub-step into the next (vcstate, vkinetic): one that slid starts
 * sliding, with the kinetic friction of its last normal reaction; one that touches down after a
 * free sub-step starts sliding too (its friction follows, one sub-step late, as every sliding
 * vertex's does); one that lifted off starts released; a held one, or one whose slip stopped,
 * starts held. So the first solve is already right for most contacts and the rounds fix what
 * changed. The bounded extra normal speed used to recover a penetration is taken back out of the
 * velocity (no bounce).
 */
#include "core.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static int check_indices(tc_cloth *c, const int32_t *idx, int32_t k)
{
    if (k < 0) { tc_set_err(c, "negative count"); return TC_ERR_INPUT; }
    for (int32_t i = 0; i < k; i++)
        if (idx[i] < 0 || idx[i] >= c->nv) {
            tc_set_err(c, "vertex index %d (item %d) is outside [0, %d)", (int)idx[i], (int)i, (int)c->nv);
            return TC_ERR_INPUT;
        }
    return TC_OK;
}

/* The goals, made on first use: every vertex's where it is */
static int goals_made(tc_cloth *c)
{
    if (c->vgoal.len) return TC_OK;
    const size_t n3 = 3 * (size_t)c->nv;
    if (tc_vec_resize(&c->vgoal, n3) || tc_vec_resize(&c->vgoal0, n3)) {
        tc_vec_resize(&c->vgoal, 0); tc_vec_resize(&c->vgoal0, 0);
        tc_set_err(c, "out of memory"); return TC_ERR_NOMEM;
    }
    memcpy(tc_vec_ptr(&c->vgoal), tc_vec_ptr(&c->x), n3 * sizeof(double));
    memcpy(tc_vec_ptr(&c->vgoal0), tc_vec_ptr(&c->x), n3 * sizeof(double));
    return TC_OK;
}

int tc_cloth_pin(tc_cloth *c, const int32_t *idx, int32_t k, int pinned)
{
    if (check_indices(c, idx, k)) return TC_ERR_INPUT;
    int8_t *p = tc_vec_ptr(&c->vpin);
    const double *x = tc_vec_ptr(&c->x);
    double *g = tc_vec_ptr(&c->vgoal), *g0 = tc_vec_ptr(&c->vgoal0);
    for (int32_t i = 0; i < k; i++) {
        int32_t v = idx[i];
        /* held where it is (a vertex that already follows a goal, pinned or soft, keeps it) */
        if (pinned && !tc_follows_goal(c, v) && c->vgoal.len)
            for (int q = 0; q < 3; q++) g[3 * v + q] = g0[3 * v + q] = x[3 * v + q];
        p[v] = pinned ? 1 : 0;
    }
    return TC_OK;
}

int tc_cloth_set_pin_goals(tc_cloth *c, const int32_t *idx, const double *pos, int32_t k)
{
    if (check_indices(c, idx, k)) return TC_ERR_INPUT;
    for (int32_t i = 0; i < k; i++) {
        if (!tc_follows_goal(c, idx[i])) {
            tc_set_err(c, "vertex %d (item %d) is not pinned and has no pin spring", (int)idx[i], (int)i);
            return TC_ERR_INPUT;
        }
        for (int q = 0; q < 3; q++)
            if (!isfinite(pos[3 * i + q])) { tc_set_err(c, "pin goal %d (vertex %d) is not finite", (int)i, (int)idx[i]); return TC_ERR_INPUT; }
    }
    if (goals_made(c)) return TC_ERR_NOMEM;  /* the first goals: every pin's where it is, then these */
    double *g = tc_vec_ptr(&c->vgoal);
    for (int32_t i = 0; i < k; i++) memcpy(g + 3 * (size_t)idx[i], pos + 3 * (size_t)i, 3 * sizeof(double));
    return TC_OK;
}

int tc_cloth_set_pin_springs(tc_cloth *c, const int32_t *idx, const double *k, int32_t n)
{
    if (check_indices(c, idx, n)) return TC_ERR_INPUT;
    for (int32_t i = 0; i < n; i++)
        if (!(k[i] >= 0 && k[i] <= TC_PIN_SPRING_MAX)) {
            tc_set_err(c, "pin spring stiffness %g N/m (vertex %d) is not in [0, %g]", k[i], (int)idx[i], TC_PIN_SPRING_MAX);
            return TC_ERR_INPUT;
        }
    if (goals_made(c)) return TC_ERR_NOMEM;
    if (!c->vpink.len) {
        if (tc_vec_resize(&c->vpink, (size_t)c->nv)) { tc_set_err(c, "out of memory"); return TC_ERR_NOMEM; }
        memset(tc_vec_ptr(&c->vpink), 0, (size_t)c->nv * sizeof(double));
    }
    double *ks = tc_vec_ptr(&c->vpink), *g = tc_vec_ptr(&c->vgoal), *g0 = tc_vec_ptr(&c->vgoal0);
    const double *x = tc_vec_ptr(&c->x);
    for (int32_t i = 0; i < n; i++) {
        const int32_t v = idx[i];
        if (!tc_follows_goal(c, v))  /* a new soft pin's goal is where it is; one that has a goal keeps it */
            for (int q = 0; q < 3; q++) g[3 * v + q] = g0[3 * v + q] = x[3 * v + q];
        ks[v] = k[i];
    }
    return TC_OK;
}

const double *tc_cloth_pin_springs(const tc_cloth *c) { return c->vpink.len ? tc_vec_ptr((tc_vec *)&c->vpink) : NULL; }

void tc_pin_springs_add(tc_cloth *c, double dt, double alpha, double *b)
{
    if (!c->vpink.len) return;
    const double *ks = tc_vec_ptr(&c->vpink), *x = tc_vec_ptr(&c->x);
    const double *g = tc_vec_ptr(&c->vgoal), *g0 = tc_vec_ptr(&c->vgoal0);
    const int8_t *fl = tc_vec_ptr(&c->vflag);
    double *D = tc_vec_ptr(&c->diag);
    for (int32_t i = 0; i < c->nv; i++) {
        if (!(ks[i] > 0) || fl[i] == VC_PINNED || fl[i] == VC_HANDLE) continue;  /* held: its row is filtered out */
        double *d = D + 12 * (size_t)i;
        const double a = dt * dt * ks[i];
        d[0] += a; d[5] += a; d[10] += a;
        if (!b) continue;  /* the matrix's part alone (a matrix assembled again: step.c) */
        for (int q = 0; q < 3; q++) {
            const size_t o = 3 * (size_t)i + (size_t)q;
            b[o] += dt * ks[i] * (g0[o] + alpha * (g[o] - g0[o]) - x[o]);
        }
    }
}

const int8_t *tc_cloth_pin_flags(const tc_cloth *c) { return tc_vec_ptr((tc_vec *)&c->vpin); }

static const double IDENTITY[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};

int tc_cloth_add_handle(tc_cloth *c, const int32_t *idx, int32_t k, int32_t *out)
{
    if (k < 1) { tc_set_err(c, "a handle needs at least one vertex"); return TC_ERR_INPUT; }
    if (check_indices(c, idx, k)) return TC_ERR_INPUT;
    int32_t *vh = tc_vec_ptr(&c->vhandle);
    for (int32_t i = 0; i < k; i++)
        if (vh[idx[i]] >= 0) {
            tc_set_err(c, "vertex %d already belongs to handle %d", (int)idx[i], (int)vh[idx[i]]);
            return TC_ERR_INPUT;
        }
    if (c->nh == c->hcap_handles) {
        int32_t ncap = c->hcap_handles ? 2 * c->hcap_handles : 4;
        tc_handle *nh = realloc(c->handles, (size_t)ncap * sizeof *nh);
        if (!nh) { tc_set_err(c, "out of memory"); return TC_ERR_NOMEM; }
        c->handles = nh; c->hcap_handles = ncap;
    }
    tc_handle *h = &c->handles[c->nh];
    memset(h, 0, sizeof *h);
    h->verts = malloc((size_t)k * sizeof(int32_t));
    h->grasp = malloc(3 * (size_t)k * sizeof(double));
    if (!h->verts || !h->grasp) { free(h->verts); free(h->grasp); tc_set_err(c, "out of memory"); return TC_ERR_NOMEM; }
    const double *x = tc_vec_ptr(&c->x);
    int32_t cnt = 0;
    for (int32_t i = 0; i < k; i++) {
        if (vh[idx[i]] == c->nh) continue;  /* listed twice */
        vh[idx[i]] = c->nh;
        h->verts[cnt] = idx[i];
        memcpy(h->grasp + 3 * cnt, x + 3 * idx[i], 3 * sizeof(double));
        cnt++;
    }
    h->count = cnt;
    h->active = true;
    memcpy(h->prev, IDENTITY, sizeof IDENTITY);
    memcpy(h->target, IDENTITY, sizeof IDENTITY);
    *out = c->nh++;
    return TC_OK;
}

int tc_handle_add_member(tc_cloth *c, int32_t hid, int32_t v, const double grasp[3])
{
    tc_handle *h = &c->handles[hid];
    int32_t *nv = realloc(h->verts, (size_t)(h->count + 1) * sizeof(int32_t));
    if (!nv) return TC_ERR_NOMEM;
    h->verts = nv;
    double *ng = realloc(h->grasp, 3 * (size_t)(h->count + 1) * sizeof(double));
    if (!ng) return TC_ERR_NOMEM;
    h->grasp = ng;
    h->verts[h->count] = v;
    memcpy(h->grasp + 3 * h->count, grasp, 3 * sizeof(double));
    h->count++;
    ((int32_t *)tc_vec_ptr(&c->vhandle))[v] = hid;
    return TC_OK;
}

static int check_handle(tc_cloth *c, int32_t h)
{
    if (h < 0 || h >= c->nh || !c->handles[h].active) {
        tc_set_err(c, "no active handle %d (there are %d)", (int)h, (int)c->nh);
        return TC_ERR_INPUT;
    }
    return TC_OK;
}

int tc_cloth_set_handle_target(tc_cloth *c, int32_t h, const double affine[12])
{
    if (check_handle(c, h)) return TC_ERR_INPUT;
    for (int k = 0; k < 12; k++)
        if (!isfinite(affine[k])) { tc_set_err(c, "handle %d target has a non-finite entry", (int)h); return TC_ERR_INPUT; }
    memcpy(c->handles[h].target, affine, 12 * sizeof(double));
    return TC_OK;
}

int tc_cloth_release_handle(tc_cloth *c, int32_t h)
{
    if (check_handle(c, h)) return TC_ERR_INPUT;
    tc_handle *H = &c->handles[h];
    int32_t *vh = tc_vec_ptr(&c->vhandle);
    for (int32_t i = 0; i < H->count; i++) vh[H->verts[i]] = -1;
    H->active = false; H->count = 0;
    memset(H->force, 0, sizeof H->force);
    return TC_OK;
}

int32_t tc_cloth_num_handles(const tc_cloth *c) { return c->nh; }

int tc_cloth_handle_force(const tc_cloth *c, int32_t h, double out[3])
{
    if (h < 0 || h >= c->nh) return TC_ERR_INPUT;
    memcpy(out, c->handles[h].force, 3 * sizeof(double));
    return TC_OK;
}

int tc_cloth_pin_force(const tc_cloth *c, double out[3])
{
    const int8_t *p = tc_vec_ptr(&c->vpin);
    const double *f = tc_vec_ptr(&c->force);
    out[0] = out[1] = out[2] = 0.0;
    for (int32_t i = 0; i < c->nv; i++)
        if (p[i]) { out[0] += f[3 * i]; out[1] += f[3 * i + 1]; out[2] += f[3 * i + 2]; }
    return TC_OK;
}

int tc_cloth_set_contacts(tc_cloth *c, const int32_t *vertex, const double *normal, const double *depth,
                          const double *velocity, const double *friction, int32_t k)
{
    if (check_indices(c, vertex, k)) return TC_ERR_INPUT;
    for (int32_t i = 0; i < k; i++) {
        const double *n = normal + 3 * i;
        double l = sqrt(dot3(n, n));
        if (!isfinite(l) || fabs(l - 1.0) > TC_UNIT_NORMAL_TOLERANCE) { tc_set_err(c, "contact %d: normal is not a unit vector (length %g)", (int)i, l); return TC_ERR_INPUT; }
        if (!(depth[i] >= 0 && isfinite(depth[i]))) { tc_set_err(c, "contact %d: depth must be >= 0 and finite (got %g)", (int)i, depth[i]); return TC_ERR_INPUT; }
        if (velocity) for (int q = 0; q < 3; q++)
            if (!isfinite(velocity[3 * i + q])) { tc_set_err(c, "contact %d: surface velocity is not finite", (int)i); return TC_ERR_INPUT; }
        if (friction && !(friction[i] >= 0 && friction[i] < 100)) { tc_set_err(c, "contact %d: friction must lie in [0, 100) (got %g)", (int)i, friction[i]); return TC_ERR_INPUT; }
    }
    if (tc_vec_resize(&c->cvert, (size_t)k) || tc_vec_resize(&c->cactive, (size_t)k) ||
        tc_vec_resize(&c->cnormal, 3 * (size_t)k) || tc_vec_resize(&c->cdepth, (size_t)k) ||
        tc_vec_resize(&c->cvel, 3 * (size_t)k) || tc_vec_resize(&c->cfric, (size_t)k)) {
        tc_set_err(c, "out of memory"); return TC_ERR_NOMEM;
    }
    memcpy(tc_vec_ptr(&c->cvert), vertex, (size_t)k * sizeof(int32_t));
    double *nn = tc_vec_ptr(&c->cnormal);
    for (int32_t i = 0; i < k; i++) {
        const double *n = normal + 3 * i; double l = sqrt(dot3(n, n));
        nn[3 * i] = n[0] / l; nn[3 * i + 1] = n[1] / l; nn[3 * i + 2] = n[2] / l;
    }
    memcpy(tc_vec_ptr(&c->cdepth), depth, (size_t)k * sizeof(double));
    if (velocity) memcpy(tc_vec_ptr(&c->cvel), velocity, 3 * (size_t)k * sizeof(double));
    else memset(tc_vec_ptr(&c->cvel), 0, 3 * (size_t)k * sizeof(double));
    double *fr = tc_vec_ptr(&c->cfric);
    for (int32_t i = 0; i < k; i++) fr[i] = friction ? friction[i] : 0.0;
    return TC_OK;
}

static void apply_affine(const double *M, const double *p, double *o)
{
    for (int r = 0; r < 3; r++) o[r] = M[4 * r] * p[0] + M[4 * r + 1] * p[1] + M[4 * r + 2] * p[2] + M[4 * r + 3];
}

/* Force of eq. (6) on each handle: the sum of the forces on its vertices (the cloth's pull on the hand). */
void tc_handle_forces(tc_cloth *c)
{
    const double *f = tc_vec_ptr(&c->force);
    for (int32_t h = 0; h < c->nh; h++) {
        tc_handle *H = &c->handles[h];
        H->force[0] = H->force[1] = H->force[2] = 0.0;
        for (int32_t i = 0; i < H->count; i++)
            for (int k = 0; k < 3; k++) H->force[k] += f[3 * H->verts[i] + k];
    }
}

/* The filter S_i of vertex i as a matrix (row-major): 0 at a pin or handle, I minus the outer
 * products of its contact normals at a contact, I when free. */
void tc_constraint_matrix(const tc_cloth *c, int32_t i, double S[9])
{
    const int8_t f = ((const int8_t *)tc_vec_ptr(&c->vflag))[i];
    memset(S, 0, 9 * sizeof(double));
    if (f == VC_PINNED || f == VC_HANDLE) return;
    S[0] = S[4] = S[8] = 1.0;
    if (f != VC_CONTACT) return;
    const int8_t cnt = ((const int8_t *)tc_vec_ptr(&c->scount))[i];
    const double *N = (const double *)tc_vec_ptr(&c->snorm) + 9 * (size_t)i;
    for (int k = 0; k < cnt; k++)
        for (int a = 0; a < 3; a++)
            for (int b = 0; b < 3; b++) S[3 * a + b] -= N[3 * k + a] * N[3 * k + b];
}

/* F = S A S + w (I - S) for a vertex's diagonal block A and filter S (row-major): the diagonal block
 * of the filtered matrix the sweeps' contact rows and the stiff groups invert. Any w > 0 gives the
 * same filtered solve (the two ranges are decoupled); w = tr(A) / 3 keeps the block's own scale,
 * where w = 1 (kg) beside masses of micrograms and a sliver's stiffness lost the inverse's
 * accuracy. */
void tc_filtered_diagonal(const double S[9], const double A[9], double F[9])
{
    const double w = (A[0] + A[4] + A[8]) / 3.0;
    double AS[9];
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++) AS[3 * a + b] = A[3 * a] * S[b] + A[3 * a + 1] * S[3 + b] + A[3 * a + 2] * S[6 + b];
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++)
            F[3 * a + b] = S[3 * a] * AS[b] + S[3 * a + 1] * AS[3 + b] + S[3 * a + 2] * AS[6 + b] + w * ((a == b) - S[3 * a + b]);
}

/* Removes the constrained components: all three for pins and handles, the span of the vertex's
 * contact normals (an orthonormal basis of up to three directions) for contacts. */
void tc_constraint_filter(const tc_cloth *c, double *r)
{
    const int8_t *fl = tc_vec_ptr(&c->vflag), *cnt = tc_vec_ptr(&c->scount);
    const double *N = tc_vec_ptr(&c->snorm);
    for (int32_t i = 0; i < c->nv; i++) {
        int8_t f = fl[i];
        if (f == VC_FREE) continue;
        double *ri = r + 3 * i;
        if (f == VC_CONTACT) {
            for (int k = 0; k < cnt[i]; k++) {
                const double *e = N + 9 * i + 3 * k;
                double d = dot3(ri, e);
                ri[0] -= d * e[0]; ri[1] -= d * e[1]; ri[2] -= d * e[2];
            }
        } else {
            ri[0] = ri[1] = ri[2] = 0.0;
        }
    }
}

/* Eigen-decomposition of the symmetric 3x3 A (cyclic Jacobi): A = E diag(l) E^T, the columns of E
 * (E[3 * row + col]) orthonormal. A holds sums of unit normals' outer products (entries <= the
 * number of contacts), so a fixed sweep count reaches double precision. */
static void sym3_eigen(double A[9], double l[3], double E[9])
{
    static const double I3[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    memcpy(E, I3, sizeof I3);
    for (int sweep = 0; sweep < 16; sweep++) {
        double off = A[1] * A[1] + A[2] * A[2] + A[5] * A[5];
        double tr = A[0] * A[0] + A[4] * A[4] + A[8] * A[8];
        if (!(off > 1e-30 * tr)) break;
        for (int p = 0; p < 2; p++)
            for (int q = p + 1; q < 3; q++) {
                double apq = A[3 * p + q];
                if (apq == 0.0) continue;
                double th = (A[3 * q + q] - A[3 * p + p]) / (2.0 * apq);
                double t = (th >= 0 ? 1.0 : -1.0) / (fabs(th) + sqrt(th * th + 1.0));
                double cs = 1.0 / sqrt(t * t + 1.0), sn = t * cs;
                for (int k = 0; k < 3; k++) {  /* A <- A G (columns p, q) */
                    double akp = A[3 * k + p], akq = A[3 * k + q];
                    A[3 * k + p] = cs * akp - sn * akq; A[3 * k + q] = sn * akp + cs * akq;
                }
                for (int k = 0; k < 3; k++) {  /* A <- G^T A (rows p, q) */
                    double apk = A[3 * p + k], aqk = A[3 * q + k];
                    A[3 * p + k] = cs * apk - sn * aqk; A[3 * q + k] = sn * apk + cs * aqk;
                }
                for (int k = 0; k < 3; k++) {
                    double ekp = E[3 * k + p], ekq = E[3 * k + q];
                    E[3 * k + p] = cs * ekp - sn * ekq; E[3 * k + q] = sn * ekp + cs * ekq;
                }
            }
    }
    l[0] = A[0]; l[1] = A[4]; l[2] = A[8];
}

/* One vertex's contacts, summed as M = sum n_k n_k^T, r = sum z_k n_k and zz = sum z_k^2, become
 * its basis (cnt orthonormal directions in N) and prescribed velocity fix: the least-squares
 * velocity min sum (n_k . f - z_k)^2 over the directions M resolves, no faster than |z| = sqrt(zz).
 * Contacts are inequalities v . n_k >= z_k that the release step turns into an active set; two of
 * them with near-opposite normals (a vertex squeezed between two layers, or a layer and the body)
 * or near-parallel ones leave M an eigenvalue near 0 along their bisector (opposite) or their
 * difference (parallel). Prescribing that direction too (as Gram-Schmidt did) satisfied both
 * equalities with a sideways speed of up to |z| / sqrt(lambda): metres per second that flung torn
 * slivers and pumped energy into the walking shirt until it blew up. Such a direction is left free
 * instead (the vertex slides between the layers, as squeezed cloth does), and the resolved ones
 * take the compromise of what the contacts ask (their mean when they disagree). stick (non-NULL:
 * the surface velocity of a vertex held by static friction) fixes the remaining, tangential
 * directions to its components; they follow the normal ones in N. Returns 1 when the speed bound
 * was applied; *merged gets the directions left free. */
static int contact_solve(const double *acc, double zz, const double *stick, double *N, double *fix, int8_t *cnt,
                         int *merged)
{
    double A[9] = {acc[0], acc[1], acc[2], acc[1], acc[3], acc[4], acc[2], acc[4], acc[5]};
    const double *r = acc + 6;
    double l[3], E[9], g[3], lam[3], dir[3][3];
    sym3_eigen(A, l, E);
    int m = 0;
    *merged = 0;
    for (int j = 0; j < 3; j++) {
        if (!(l[j] >= TC_CONTACT_MIN_EIGEN)) {
            if (l[j] > TC_CONTACT_SAME_DIRECTION) (*merged)++;  /* not a duplicate normal: counted */
            continue;
        }
        for (int q = 0; q < 3; q++) dir[m][q] = E[3 * q + j];
        g[m] = dot3(r, dir[m]);
        lam[m] = l[j];
        m++;
    }
    /* the least-squares speeds g / lambda, or if they exceed the bound the trust-region solution
       g / (lambda + mu) with |f(mu)| = bound (|f| falls monotonically in mu; bisection on a
       bracket [0, |g| / bound] where |f| <= |g| / mu <= bound) */
    double bound = sqrt(zz), f2 = 0.0, gg = 0.0, mu = 0.0;
    for (int j = 0; j < m; j++) { f2 += g[j] * g[j] / (lam[j] * lam[j]); gg += g[j] * g[j]; }
    int clamped = 0;
    if (f2 > bound * bound * (1.0 + 1e-12)) {
        clamped = 1;
        double lo = 0.0, hi = sqrt(gg) / (bound > 0 ? bound : TC_TINY);
        for (int it = 0; it < 60; it++) {
            mu = 0.5 * (lo + hi);
            double s = 0.0;
            for (int j = 0; j < m; j++) s += g[j] * g[j] / ((lam[j] + mu) * (lam[j] + mu));
            if (s > bound * bound) lo = mu; else hi = mu;
        }
        mu = hi;  /* the side of the bracket within the bound */
    }
    fix[0] = fix[1] = fix[2] = 0.0;
    for (int j = 0; j < m; j++) {
        double s = g[j] / (lam[j] + mu);
        memcpy(N + 3 * j, dir[j], 3 * sizeof(double));
        for (int q = 0; q < 3; q++) fix[q] += s * dir[j][q];
    }
    /* static friction: the tangential directions too, at the touched surface's velocity; the
       reaction that holding takes is checked against the Coulomb cone after the solve */
    if (stick) {
        for (int j = 0; j < 3; j++) {
            if (l[j] >= TC_CONTACT_MIN_EIGEN) continue;
            double *e = N + 3 * m;
            for (int q = 0; q < 3; q++) e[q] = E[3 * q + j];
            double s = dot3(stick, e);
            for (int q = 0; q < 3; q++) fix[q] += s * e[q];
            m++;
        }
    }
    *cnt = (int8_t)m;
    return clamped;
}

/* The bounded extra normal speed that recovers a contact's penetration depth within the solve
 * (contact_correction of it per step, at most contact_max_push). */
static double recovery_push(const tc_cloth *c, double depth, double dt)
{
    double push = c->solver.contact_correction * depth / dt;
    return push > c->solver.contact_max_push ? c->solver.contact_max_push : push;
}

/* The normal speed contact k asks of its vertex: the touched surface's, plus the recovery push. */
static double contact_speed(const tc_cloth *c, int32_t k, double dt)
{
    const double *cn = tc_vec_ptr(&c->cnormal), *cvel = tc_vec_ptr(&c->cvel), *cd = tc_vec_ptr(&c->cdepth);
    return dot3(cvel + 3 * (size_t)k, cn + 3 * (size_t)k) + recovery_push(c, cd[k], dt);
}

/* Per vertex, an orthonormal basis of its active contact normals with the normal velocity they
 * prescribe (inelastic: the touched surface's). A vertex may touch several things at once - a body
 * and another layer of cloth over it - and must respect all of them: keeping only the deepest let
 * the layers push each other through the body in turn, which pumped energy. contact_solve turns
 * each vertex's contacts into its basis and speed, whatever their order. */
void tc_contact_basis(tc_cloth *c, double dt)
{
    int8_t *fl = tc_vec_ptr(&c->vflag), *cnt = tc_vec_ptr(&c->scount);
    double *fix = tc_vec_ptr(&c->sfix), *N = tc_vec_ptr(&c->snorm);
    const int32_t nc = (int32_t)c->cvert.len;
    const int32_t *cv = tc_vec_ptr(&c->cvert);
    const double *cn = tc_vec_ptr(&c->cnormal), *cvel = tc_vec_ptr(&c->cvel);
    const int8_t *act = tc_vec_ptr(&c->cactive);
    const double *cf = tc_vec_ptr(&c->cfric);
    double *sv = tc_vec_ptr(&c->sp);  /* solver scratch, free between solves: summed surface velocity */
    /* 1: the touched vertices start free, with their sums zero until pass 3 replaces them by the
       basis: snorm holds M's six entries and r, sfix zz, the largest friction coefficient (-1: a
       contact slides) and the number of contacts, sp their summed surface velocity */
    for (int32_t k = 0; k < nc; k++) {
        int32_t i = cv[k];
        if (fl[i] != VC_FREE && fl[i] != VC_CONTACT) continue;  /* pins and handles keep their prescribed velocity */
        fl[i] = VC_FREE;  /* a rebuild after a release or a slip: free unless a contact stays active */
        cnt[i] = 0;
        fix[3 * i] = fix[3 * i + 1] = fix[3 * i + 2] = 0.0;
        sv[3 * i] = sv[3 * i + 1] = sv[3 * i + 2] = 0.0;
        memset(N + 9 * i, 0, 9 * sizeof(double));
    }
    /* 2: sums of the active contacts; cnt = -1 marks a vertex whose basis is still to be solved */
    for (int32_t k = 0; k < nc; k++) {
        if (!act[k]) continue;
        int32_t i = cv[k];
        if (fl[i] != VC_FREE && fl[i] != VC_CONTACT) continue;
        fl[i] = VC_CONTACT;
        cnt[i] = -1;
        const double *n = cn + 3 * k;
        /* the touched surface's normal speed, plus a bounded share of the depth per step: the
           penetration is recovered through the solve, so the membrane around the vertex follows
           consistently (moving only the vertex's position stretched its stiff neighbourhood and
           flung it at metres per second) */
        double z = contact_speed(c, k, dt);
        double *a = N + 9 * i;
        a[0] += n[0] * n[0]; a[1] += n[0] * n[1]; a[2] += n[0] * n[2];
        a[3] += n[1] * n[1]; a[4] += n[1] * n[2]; a[5] += n[2] * n[2];
        a[6] += z * n[0]; a[7] += z * n[1]; a[8] += z * n[2];
        fix[3 * i] += z * z;
        if (fix[3 * i + 1] >= 0.0) fix[3 * i + 1] = act[k] == TC_CONTACT_SLIDING ? -1.0 : fmax(fix[3 * i + 1], cf[k]);
        fix[3 * i + 2] += 1.0;
        for (int q = 0; q < 3; q++) sv[3 * i + q] += cvel[3 * k + q];
    }
    /* 3: each pending vertex's basis and speed */
    for (int32_t k = 0; k < nc; k++) {
        int32_t i = cv[k];
        if (fl[i] != VC_CONTACT || cnt[i] != -1) continue;
        double acc[9], stick[3];
        memcpy(acc, N + 9 * i, sizeof acc);
        for (int q = 0; q < 3; q++) stick[q] = sv[3 * i + q] / fix[3 * i + 2];  /* the mean surface velocity */
        int merged;
        c->stats.contact_speed_clamps += contact_solve(acc, fix[3 * i], fix[3 * i + 1] > 0.0 ? stick : NULL,
                                                       N + 9 * i, fix + 3 * i, cnt + i, &merged);
        c->stats.contact_directions_merged += merged;
    }
}

/* The state each contact starts the sub-step in, from how its vertex ended the last one (vcstate):
 * a vertex that slid starts sliding (tc_contacts_kinetic_start gives it its kinetic friction), and
 * so does one that touches down after a sub-step free (its friction follows from the next sub-step,
 * once its normal reaction is known); one that lifted off starts released (tc_contacts_touch
 * makes a contact active again if the solve drives the vertex into the surface). Held, or not
 * known (NONE): held, judged on its reaction after the solve. This is the guess the rounds after
 * the solve correct: starting every contact held cost the walking shirt, whose ~80 contacts all
 * slide, a re-solve turning them to sliding every sub-step (issue 15). */
static void carry_in(tc_cloth *c)
{
    const int32_t nc = (int32_t)c->cvert.len;
    const int32_t *cv = tc_vec_ptr(&c->cvert);
    const int8_t *cs = tc_vec_ptr(&c->vcstate);
    int8_t *act = tc_vec_ptr(&c->cactive);
    for (int32_t k = 0; k < nc; k++) {
        const int8_t s = cs[cv[k]];
        if (s == TC_CARRY_SLIDING || s == TC_CARRY_FREE) act[k] = TC_CONTACT_SLIDING;
        else if (s == TC_CARRY_LIFTED) { act[k] = 0; c->stats.lifts_carried++; }
    }
}

/* The constraints of one sub-step of length dt that ends at fraction alpha of the handles' motion
 * from their previous to their target map. */
void tc_constraints_begin(tc_cloth *c, double dt, double alpha)
{
    const int32_t n = c->nv;
    const double *x = tc_vec_ptr(&c->x);
    int8_t *fl = tc_vec_ptr(&c->vflag);
    const int8_t *pin = tc_vec_ptr(&c->vpin);
    double *fix = tc_vec_ptr(&c->sfix);
    memset(fl, VC_FREE, (size_t)n);
    memset(tc_vec_ptr(&c->cactive), 1, c->cvert.len);
    carry_in(c);
    tc_contact_basis(c, dt);
    {
        const double *cd = tc_vec_ptr(&c->cdepth);
        for (size_t k = 0; k < c->cvert.len; k++)
            c->stats.contact_pushes_capped += c->solver.contact_correction * cd[k] / dt > c->solver.contact_max_push;
    }
    const double *g = c->vgoal.len ? tc_vec_ptr(&c->vgoal) : NULL, *g0 = tc_vec_ptr(&c->vgoal0);
    for (int32_t i = 0; i < n; i++)
        if (pin[i]) {
            /* at the goal on the line from vgoal0 to vgoal at this sub-step's end (a pin that
               holds still: g0 = g = x, exactly zero), or still while no pin has a goal */
            fl[i] = VC_PINNED;
            for (int q = 0; q < 3; q++) {
                const size_t o = 3 * (size_t)i + (size_t)q;
                fix[o] = g ? (g0[o] + alpha * (g[o] - g0[o]) - x[o]) / dt : 0.0;
            }
        }
    for (int32_t h = 0; h < c->nh; h++) {
        tc_handle *H = &c->handles[h];
        if (!H->active) continue;
        double M[12];
        for (int q = 0; q < 12; q++) M[q] = H->prev[q] + alpha * (H->target[q] - H->prev[q]);
        for (int32_t k = 0; k < H->count; k++) {
            int32_t i = H->verts[k];
            double goal[3];
            apply_affine(M, H->grasp + 3 * k, goal);
            fl[i] = VC_HANDLE;
            for (int q = 0; q < 3; q++) fix[3 * i + q] = (goal[q] - x[3 * i + q]) / dt;
        }
    }
}

/* Puts v on the constraint manifold: the constrained components of v become those of fix. */
void tc_constraint_project(const tc_cloth *c, double *v, const double *fix)
{
    const int8_t *fl = tc_vec_ptr(&c->vflag);
    const double *N = tc_vec_ptr(&c->snorm);
    const int8_t *cnt = tc_vec_ptr(&c->scount);
    for (int32_t i = 0; i < c->nv; i++) {
        double *vi = v + 3 * i;
        const double *zi = fix + 3 * i;
        if (fl[i] == VC_CONTACT) {
            for (int k = 0; k < cnt[i]; k++) {  /* fix lies in the span of the basis */
                const double *e = N + 9 * i + 3 * k;
                double d = dot3(vi, e) - dot3(zi, e);
                vi[0] -= d * e[0]; vi[1] -= d * e[1]; vi[2] -= d * e[2];
            }
        } else if (fl[i] != VC_FREE) {
            vi[0] = zi[0]; vi[1] = zi[1]; vi[2] = zi[2];
        }
    }
}

/* Prescribed values of a change du = v - v0: fix minus v0's constrained components. */
void tc_constraint_offsets(const tc_cloth *c, const double *v0, double *fix)
{
    const int8_t *fl = tc_vec_ptr(&c->vflag), *cnt = tc_vec_ptr(&c->scount);
    const double *N = tc_vec_ptr(&c->snorm);
    for (int32_t i = 0; i < c->nv; i++) {
        if (fl[i] == VC_FREE) continue;
        double *z = fix + 3 * i;
        const double *w = v0 + 3 * i;
        if (fl[i] == VC_CONTACT) {
            for (int k = 0; k < cnt[i]; k++) {
                const double *e = N + 9 * i + 3 * k;
                double d = dot3(w, e);
                z[0] -= d * e[0]; z[1] -= d * e[1]; z[2] -= d * e[2];
            }
        } else {
            z[0] -= w[0]; z[1] -= w[1]; z[2] -= w[2];
        }
    }
}

/* The largest friction coefficient of each vertex's active contacts, in mu (scratch, per vertex;
 * only the entries of contact vertices are written). */
static void vertex_friction(const tc_cloth *c, double *mu)
{
    const int32_t nc = (int32_t)c->cvert.len;
    const int32_t *cv = tc_vec_ptr(&c->cvert);
    const int8_t *fl = tc_vec_ptr(&c->vflag), *act = tc_vec_ptr(&c->cactive);
    const double *cf = tc_vec_ptr(&c->cfric);
    for (int32_t k = 0; k < nc; k++) mu[cv[k]] = 0.0;
    for (int32_t k = 0; k < nc; k++)
        if (act[k] && fl[cv[k]] == VC_CONTACT) mu[cv[k]] = fmax(mu[cv[k]], cf[k]);
}

/* The kinetic friction of the vertices that start the sub-step sliding as they slid in the last
 * one, into the right-hand side b: that sub-step's force (vkinetic: mu times its normal reaction
 * then, against its slip then) turned into this sub-step's tangent plane, its size kept, times
 * dt. Kinetic friction is thus explicit in the normal reaction (lagged one sub-step, as the
 * element rotations are taken at the sub-step's start), which spares the re-solve a reaction
 * measured after the solve would need; whether the vertex sticks or slides stays implicit (held
 * vertices are judged after each solve, a slip that reverses holds it from the next sub-step).
 * vkinetic then holds the force b carries, zero at every other vertex. */
/* f := 0 (a vertex's carried kinetic force), written only where it is not zero already (its bits:
 * -0.0 too, so the result is the same +0.0): the pages of vkinetic a sheet that never slides never
 * writes stay untouched and not resident (12 bytes per triangle of a 100K-triangle cloth) */
static inline void kinetic_clear(double *f)
{
    static const double zero[3] = {0.0, 0.0, 0.0};
    if (memcmp(f, zero, sizeof zero)) f[0] = f[1] = f[2] = 0.0;
}

void tc_contacts_kinetic_start(tc_cloth *c, double *b, double dt)
{
    const int8_t *cs = tc_vec_ptr(&c->vcstate), *fl = tc_vec_ptr(&c->vflag), *cnt = tc_vec_ptr(&c->scount);
    const double *N = tc_vec_ptr(&c->snorm);
    double *F = tc_vec_ptr(&c->vkinetic), *mu = tc_vec_ptr(&c->sr);  /* sr: solver scratch, free here */
    vertex_friction(c, mu);
    for (int32_t i = 0; i < c->nv; i++) {
        double *f = F + 3 * (size_t)i;
        if (cs[i] != TC_CARRY_SLIDING || fl[i] != VC_CONTACT) { kinetic_clear(f); continue; }
        const double l0 = sqrt(dot3(f, f));
        for (int j = 0; j < cnt[i]; j++) {  /* a sliding vertex's basis is its normals */
            const double *e = N + 9 * (size_t)i + 3 * j;
            const double d = dot3(f, e);
            f[0] -= d * e[0]; f[1] -= d * e[1]; f[2] -= d * e[2];
        }
        const double l = sqrt(dot3(f, f));
        const double s = mu[i] > 0.0 && l > 0.0 ? l0 / l : 0.0;
        for (int q = 0; q < 3; q++) { f[q] *= s; b[3 * (size_t)i + q] += dt * f[q]; }
        c->stats.slides_carried++;
    }
}

/* Contacts whose reaction (J - b along the normal, J = A v) pulls the cloth onto the surface are
 * released; returns how many (apply = 0: only counts them). A release is final for the sub-step.
 * The released contact's vertex is marked free until tc_contact_basis rebuilds its basis, so the
 * friction of this round leaves it to the next (its reaction changes with the release). */
int tc_contacts_release(tc_cloth *c, const double *J, const double *b, int apply)
{
    const int32_t nc = (int32_t)c->cvert.len;
    const int32_t *cv = tc_vec_ptr(&c->cvert);
    const double *cn = tc_vec_ptr(&c->cnormal), *cvel = tc_vec_ptr(&c->cvel), *m = tc_vec_ptr(&c->mass);
    int8_t *fl = tc_vec_ptr(&c->vflag), *act = tc_vec_ptr(&c->cactive), *cs = tc_vec_ptr(&c->vcstate);
    int released = 0;
    for (int32_t k = 0; k < nc; k++) {
        int32_t i = cv[k];
        if (fl[i] != VC_CONTACT || !act[k]) continue;
        double jn = 0.0;
        for (int q = 0; q < 3; q++) jn += (J[3 * i + q] - b[3 * i + q]) * cn[3 * k + q];
        /* pulling means more than rounding: a vertex squeezed to rest between two contacts that
           ask the same (contact_solve's compromise) has a zero reaction, and releasing one on its
           rounding noise let the other push it through */
        double scale = sqrt(dot3(J + 3 * i, J + 3 * i)) + sqrt(dot3(b + 3 * i, b + 3 * i)) +
                       m[i] * (sqrt(dot3(cvel + 3 * k, cvel + 3 * k)) + c->solver.contact_max_push);
        if (jn < -TC_RELEASE_ROUNDING * scale) {
            released++;
            if (apply) act[k] = -1;  /* released now: its vertex is marked below */
        }
    }
    if (released && apply)
        for (int32_t k = 0; k < nc; k++)
            if (act[k] < 0) {
                act[k] = 0;
                fl[cv[k]] = VC_FREE;
                /* final: not one that tc_contacts_touch may make active again */
                if (cs[cv[k]] == TC_CARRY_LIFTED) cs[cv[k]] = TC_CARRY_FREE;
            }
    return released;
}

/* A contact that began the sub-step released because its vertex lifted off in the last one
 * (carry_in) was guessed wrong when the solve drives the vertex into the surface (slower along the
 * normal than the contact asks, by more than rounding): it is made active again, sliding (it
 * touches down: its friction follows from the next sub-step), and from then on is an ordinary
 * contact (a release of it is final). Returns how many (apply = 0: only counts them). */
int tc_contacts_touch(tc_cloth *c, const double *v, double dt, int apply)
{
    const int32_t nc = (int32_t)c->cvert.len;
    const int32_t *cv = tc_vec_ptr(&c->cvert);
    const double *cn = tc_vec_ptr(&c->cnormal), *cvel = tc_vec_ptr(&c->cvel);
    int8_t *fl = tc_vec_ptr(&c->vflag), *act = tc_vec_ptr(&c->cactive), *cs = tc_vec_ptr(&c->vcstate);
    int touched = 0;
    for (int32_t k = 0; k < nc; k++) {
        const int32_t i = cv[k];
        if (act[k] || cs[i] != TC_CARRY_LIFTED || (fl[i] != VC_FREE && fl[i] != VC_CONTACT)) continue;
        const double *vi = v + 3 * (size_t)i;
        const double scale = sqrt(dot3(vi, vi)) + sqrt(dot3(cvel + 3 * k, cvel + 3 * k)) + c->solver.contact_max_push;
        if (dot3(vi, cn + 3 * k) >= contact_speed(c, k, dt) - TC_RELEASE_ROUNDING * scale) continue;
        touched++;
        if (apply) { act[k] = TC_CONTACT_SLIDING; fl[i] = VC_FREE; }
    }
    if (touched && apply)
        for (int32_t k = 0; k < nc; k++)
            if (act[k] && cs[cv[k]] == TC_CARRY_LIFTED) cs[cv[k]] = TC_CARRY_FREE;
    return touched;
}

/* Coulomb friction, judged after each solve. A held vertex (all three directions fixed,
 * tangentially at the touched surface's velocity) took the reaction R = J - b, stiffness and
 * neighbours included; where its tangential part exceeds mu times its normal part, static friction
 * cannot hold it and it slides, with the kinetic impulse R_t scaled onto the cone joining b (the
 * re-solve follows). Judging by the velocity a solve leaves instead (its tangential part lost at
 * most mu jn / m) let friction hold any load: an implicit step leaves a stiff, light vertex little
 * velocity to remove whatever pulls on it, so the shirt stuck to the walking body and was dragged
 * until it tore (112 N of tangential pull against 9.5 N of normal reaction on one shoulder vertex).
 *
 * A sliding vertex keeps the kinetic impulse b carries for this sub-step (tc_contacts_kinetic_start).
 * Its slip u relative to the touched surface gives the next sub-step's: mu times this solve's
 * normal reaction, against u; a slip the kinetic friction reversed (u . F > 0) or stopped (u = 0)
 * means static friction takes over, and the vertex starts the next sub-step held. Both are left in
 * solver scratch (sb2: force, sr: state) for tc_contacts_carry, which step.c calls right after the
 * last round, before any solve.
 *
 * apply = 0 only counts. Returns the held vertices outside their cone (that slide now, if apply).
 * A vertex left with no active contact (all released this round) gives its kinetic friction back. */
int tc_contacts_friction(tc_cloth *c, const double *J, const double *v, double *b, double dt, int apply)
{
    const int32_t nc = (int32_t)c->cvert.len;
    const int32_t *cv = tc_vec_ptr(&c->cvert);
    const double *cn = tc_vec_ptr(&c->cnormal), *cf = tc_vec_ptr(&c->cfric), *cvel = tc_vec_ptr(&c->cvel);
    const double *N = tc_vec_ptr(&c->snorm);
    const int8_t *fl = tc_vec_ptr(&c->vflag), *cnt = tc_vec_ptr(&c->scount);
    int8_t *act = tc_vec_ptr(&c->cactive);
    double *F = tc_vec_ptr(&c->vkinetic);
    /* solver scratch, free between solves, per vertex: w the weight of its basis directions on its
       contact normals (M's eigenvalues: normal or tangential); st its largest friction coefficient,
       its state (-1 not judged, 0 held and 2 sliding to judge, 1 judged, 4 to slide now, 5 stopped:
       held from the next sub-step) and its active contacts; vs their summed surface velocity; next
       the kinetic friction force it carries into the next sub-step */
    double *w = tc_vec_ptr(&c->sp), *st = tc_vec_ptr(&c->sr), *vs = tc_vec_ptr(&c->sz), *next = tc_vec_ptr(&c->sb2);
    for (int32_t k = 0; k < nc; k++) {
        const size_t i = (size_t)cv[k];
        if (fl[i] != VC_CONTACT && fl[i] != VC_FREE) continue;
        for (int q = 0; q < 3; q++) { w[3 * i + q] = 0.0; vs[3 * i + q] = 0.0; next[3 * i + q] = 0.0; }
        st[3 * i] = 0.0; st[3 * i + 1] = -1.0; st[3 * i + 2] = 0.0;
    }
    for (int32_t k = 0; k < nc; k++) {
        const size_t i = (size_t)cv[k];
        if ((fl[i] != VC_CONTACT && fl[i] != VC_FREE) || !act[k]) continue;
        st[3 * i + 2] += 1.0;
        for (int q = 0; q < 3; q++) vs[3 * i + q] += cvel[3 * k + q];
        if (fl[i] != VC_CONTACT) continue;  /* its basis is rebuilt before the next solve: judged after it */
        st[3 * i] = fmax(st[3 * i], cf[k]);
        if (act[k] == TC_CONTACT_SLIDING) st[3 * i + 1] = 2.0;
        else if (st[3 * i + 1] == -1.0 && cnt[i] == 3) st[3 * i + 1] = 0.0;
        for (int j = 0; j < cnt[i]; j++) {
            double d = dot3(cn + 3 * k, N + 9 * i + 3 * j);
            w[3 * i + j] += d * d;
        }
    }
    int slips = 0;
    for (int32_t k = 0; k < nc; k++) {
        const size_t i = (size_t)cv[k];
        if (fl[i] != VC_CONTACT || (st[3 * i + 1] != 0.0 && st[3 * i + 1] != 2.0)) continue;
        const int sliding = st[3 * i + 1] == 2.0;
        st[3 * i + 1] = 1.0;  /* judged once, whatever order its contacts come in */
        const double mu = st[3 * i];
        if (!(mu > 0.0)) continue;  /* frictionless: nothing held, no kinetic impulse */
        const double *e = N + 9 * i;
        double R[3], Rn[3] = {0, 0, 0};
        for (int q = 0; q < 3; q++) R[q] = J[3 * i + q] - b[3 * i + q];
        for (int j = 0; j < cnt[i]; j++) {
            if (w[3 * i + j] < TC_CONTACT_MIN_EIGEN) continue;  /* a tangential direction */
            const double d = dot3(R, e + 3 * j);
            for (int q = 0; q < 3; q++) Rn[q] += d * e[3 * j + q];
        }
        const double ln = sqrt(dot3(Rn, Rn));
        if (sliding) {
            /* its slip, tangential (the basis of a sliding vertex is its normals) */
            double u[3];
            for (int q = 0; q < 3; q++) u[q] = v[3 * i + q] - vs[3 * i + q] / st[3 * i + 2];
            for (int j = 0; j < cnt[i]; j++) {
                const double p = dot3(u, e + 3 * j);
                for (int q = 0; q < 3; q++) u[q] -= p * e[3 * j + q];
            }
            const double lu = sqrt(dot3(u, u));
            /* kinetic friction cannot push a vertex along its slip: one that turned more than a
               right angle from it, or stopped, was caught by static friction on the way */
            if (dot3(u, F + 3 * i) > 0.0 || !(lu > 0.0)) { st[3 * i + 1] = 5.0; continue; }
            const double lf = sqrt(dot3(F + 3 * i, F + 3 * i));
            for (int q = 0; q < 3; q++)
                next[3 * i + q] = lf > 0.0 ? mu * ln * F[3 * i + q] / (lf * dt) : -mu * ln * u[q] / (lu * dt);
            continue;
        }
        double Rt[3] = {R[0] - Rn[0], R[1] - Rn[1], R[2] - Rn[2]};
        const double lt = sqrt(dot3(Rt, Rt));
        if (lt <= mu * ln) continue;  /* static friction holds it */
        slips++;
        const double s = mu * ln / lt;  /* kinetic friction: the part of the holding impulse the cone allows */
        for (int q = 0; q < 3; q++) next[3 * i + q] = s * Rt[q] / dt;
        if (!apply) continue;
        for (int q = 0; q < 3; q++) { b[3 * i + q] += s * Rt[q]; F[3 * i + q] = s * Rt[q] / dt; }
        st[3 * i + 1] = 4.0;
    }
    if (apply)
        for (int32_t k = 0; k < nc; k++) {
            const size_t i = (size_t)cv[k];
            if (fl[i] != VC_CONTACT && fl[i] != VC_FREE) continue;
            if (st[3 * i + 2] == 0.0 && (F[3 * i] != 0.0 || F[3 * i + 1] != 0.0 || F[3 * i + 2] != 0.0))
                for (int q = 0; q < 3; q++) { b[3 * i + q] -= dt * F[3 * i + q]; F[3 * i + q] = 0.0; }
            if (act[k] && fl[i] == VC_CONTACT && st[3 * i + 1] == 4.0) act[k] = TC_CONTACT_SLIDING;
        }
    return slips;
}

/* After the last round of a sub-step: the state each vertex's contacts ended in, for the next one
 * to start from (carry_in), and the kinetic friction force a sliding one carries (from the round's
 * last tc_contacts_friction). Pins and handles: not known. */
void tc_contacts_carry(tc_cloth *c)
{
    const int32_t nc = (int32_t)c->cvert.len;
    const int32_t *cv = tc_vec_ptr(&c->cvert);
    const int8_t *fl = tc_vec_ptr(&c->vflag), *act = tc_vec_ptr(&c->cactive);
    int8_t *cs = tc_vec_ptr(&c->vcstate);
    double *F = tc_vec_ptr(&c->vkinetic);
    const double *next = tc_vec_ptr(&c->sb2), *st = tc_vec_ptr(&c->sr);
    for (int32_t i = 0; i < c->nv; i++) cs[i] = fl[i] == VC_FREE ? TC_CARRY_FREE : TC_CARRY_NONE;
    for (int32_t k = 0; k < nc; k++) {
        const size_t i = (size_t)cv[k];
        if (fl[i] == VC_FREE) cs[i] = TC_CARRY_LIFTED;  /* contacts, none active: all released */
        else if (fl[i] == VC_CONTACT && cs[i] != TC_CARRY_SLIDING)
            cs[i] = act[k] == TC_CONTACT_SLIDING ? TC_CARRY_SLIDING : TC_CARRY_HELD;
    }
    for (int32_t i = 0; i < c->nv; i++) {
        if (cs[i] == TC_CARRY_SLIDING && st[3 * (size_t)i + 1] == 5.0) {  /* its slip stopped */
            cs[i] = TC_CARRY_HELD;
            c->stats.friction_sticks++;
        }
        if (cs[i] == TC_CARRY_SLIDING) for (int q = 0; q < 3; q++) F[3 * (size_t)i + q] = next[3 * (size_t)i + q];
        else kinetic_clear(F + 3 * (size_t)i);
    }
}

void tc_cloth_forget_contacts(tc_cloth *c)
{
    memset(tc_vec_ptr(&c->vcstate), TC_CARRY_NONE, c->vcstate.len);
    memset(tc_vec_ptr(&c->vkinetic), 0, c->vkinetic.len * sizeof(double));
}

/* Active contacts (held or sliding) of vertices still in contact. */
int32_t tc_contacts_active(const tc_cloth *c)
{
    const int32_t nc = (int32_t)c->cvert.len;
    const int32_t *cv = tc_vec_ptr(&c->cvert);
    const int8_t *fl = tc_vec_ptr(&c->vflag), *act = tc_vec_ptr(&c->cactive);
    int32_t active = 0;
    for (int32_t k = 0; k < nc; k++) active += fl[cv[k]] == VC_CONTACT && act[k];
    return active;
}

/* The recovery speed was for this step's position only: take it back out of the velocity, so a
 * vertex pushed out of a body does not keep flying away (no bounce). */
void tc_contacts_take_back_push(const tc_cloth *c, double *v, double dt)
{
    const int32_t nc = (int32_t)c->cvert.len;
    const int32_t *cv = tc_vec_ptr(&c->cvert);
    const double *cn = tc_vec_ptr(&c->cnormal), *cd = tc_vec_ptr(&c->cdepth), *cvel = tc_vec_ptr(&c->cvel);
    const int8_t *fl = tc_vec_ptr(&c->vflag), *act = tc_vec_ptr(&c->cactive);
    for (int32_t k = 0; k < nc; k++) {
        int32_t i = cv[k];
        if (fl[i] != VC_CONTACT || !act[k]) continue;  /* released: it is leaving by itself */
        double push = recovery_push(c, cd[k], dt);
        const double *nn = cn + 3 * k;
        double vn = dot3(v + 3 * i, nn) - dot3(cvel + 3 * k, nn);  /* relative normal speed */
        double take = vn < push ? (vn > 0 ? vn : 0.0) : push;
        for (int q = 0; q < 3; q++) v[3 * i + q] -= take * nn[q];
    }
}
