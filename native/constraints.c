/* constraints.c - what holds the cloth: pins (zero velocity), handles (vertex sets moved rigidly to
 * an affine target: the grasped part of the cloth) and contacts (a vertex on a surface), and how
 * they enter the step: as velocity filters (Baraff & Witkin 1998).
 *
 * Each sub-step gives every vertex a kind (vflag: free, pinned, handle, contact) and a prescribed
 * velocity (sfix). Pins and handles fix all three components; a contact fixes the velocity along
 * its normal to the touched surface's (inelastic), and a vertex touching several things keeps an
 * orthonormal basis of their normals (snorm, scount). The solver then works on the manifold
 * {v_i = S_i v_i + z_i}: tc_constraint_filter applies S, tc_constraint_project puts a vector on
 * the manifold. After the solve, contacts whose reaction pulls (adhesion) are released, friction
 * caps the tangential velocity change at mu times the normal impulse, and the bounded extra
 * normal speed used to recover a penetration is taken back out of the velocity (no bounce).
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

int tc_cloth_pin(tc_cloth *c, const int32_t *idx, int32_t k, int pinned)
{
    if (check_indices(c, idx, k)) return TC_ERR_INPUT;
    int8_t *p = tc_vec_ptr(&c->vpin);
    for (int32_t i = 0; i < k; i++) p[idx[i]] = pinned ? 1 : 0;
    return TC_OK;
}

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

/* Per vertex, an orthonormal basis of its active contact normals with the normal velocity each
 * one prescribes (inelastic: the touched surface's). A vertex may touch several things at once -
 * a body and another layer of cloth over it - and must respect all of them: keeping only the
 * deepest let the layers push each other through the body in turn, which pumped energy. Normals
 * that add no new direction (a vertex squeezed between two layers) share the prescribed speed. */
void tc_contact_basis(tc_cloth *c, double dt)
{
    int8_t *fl = tc_vec_ptr(&c->vflag), *cnt = tc_vec_ptr(&c->scount);
    double *fix = tc_vec_ptr(&c->sfix), *N = tc_vec_ptr(&c->snorm);
    const int32_t nc = (int32_t)c->cvert.len;
    const int32_t *cv = tc_vec_ptr(&c->cvert);
    const double *cn = tc_vec_ptr(&c->cnormal), *cvel = tc_vec_ptr(&c->cvel);
    const int8_t *act = tc_vec_ptr(&c->cactive);
    for (int32_t k = 0; k < nc; k++) {
        int32_t i = cv[k];
        if (fl[i] != VC_FREE) continue;  /* pins and handles keep their prescribed velocity */
        cnt[i] = 0;
        fix[3 * i] = fix[3 * i + 1] = fix[3 * i + 2] = 0.0;
    }
    for (int32_t k = 0; k < nc; k++) {
        if (!act[k]) continue;
        int32_t i = cv[k];
        if (fl[i] != VC_FREE && fl[i] != VC_CONTACT) continue;
        fl[i] = VC_CONTACT;
        const double *n = cn + 3 * k;
        /* the touched surface's normal speed, plus a bounded share of the depth per step: the
           penetration is recovered through the solve, so the membrane around the vertex follows
           consistently (moving only the vertex's position stretched its stiff neighbourhood and
           flung it at metres per second) */
        double push = c->solver.contact_correction * ((const double *)tc_vec_ptr(&c->cdepth))[k] / dt;
        if (push > c->solver.contact_max_push) push = c->solver.contact_max_push;
        double z = dot3(cvel + 3 * k, n) + push;
        double u[3] = {n[0], n[1], n[2]};
        int best = -1;
        double bestd = 0.0;
        for (int j = 0; j < cnt[i]; j++) {
            const double *e = N + 9 * i + 3 * j;
            double d = dot3(n, e);
            u[0] -= d * e[0]; u[1] -= d * e[1]; u[2] -= d * e[2];
            if (fabs(d) > fabs(bestd)) { bestd = d; best = j; }
        }
        double lu = sqrt(dot3(u, u));
        if (lu > TC_CONTACT_NEW_DIRECTION && cnt[i] < 3) {
            double e[3] = {u[0] / lu, u[1] / lu, u[2] / lu};
            double zf = z - dot3(fix + 3 * i, n);  /* what the earlier components leave to do */
            double ze = zf / lu;
            memcpy(N + 9 * i + 3 * cnt[i], e, sizeof e);
            cnt[i]++;
            for (int q = 0; q < 3; q++) fix[3 * i + q] += ze * e[q];
        } else if (best >= 0) {
            const double *e = N + 9 * i + 3 * best;
            double cur = dot3(fix + 3 * i, e), want = z / bestd;
            double delta = TC_CONTACT_SHARE * (want - cur);
            for (int q = 0; q < 3; q++) fix[3 * i + q] += delta * e[q];
        }
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
    tc_contact_basis(c, dt);
    for (int32_t i = 0; i < n; i++)
        if (pin[i]) { fl[i] = VC_PINNED; fix[3 * i] = fix[3 * i + 1] = fix[3 * i + 2] = 0.0; }
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

/* Marks inactive the contacts whose reaction (J - b along the normal, J = A v) pulls the cloth
 * onto the surface; returns how many. */
int tc_contacts_release(tc_cloth *c, const double *J, const double *b)
{
    const int32_t nc = (int32_t)c->cvert.len;
    const int32_t *cv = tc_vec_ptr(&c->cvert);
    const double *cn = tc_vec_ptr(&c->cnormal);
    int8_t *fl = tc_vec_ptr(&c->vflag), *act = tc_vec_ptr(&c->cactive);
    int released = 0;
    for (int32_t k = 0; k < nc; k++) {
        int32_t i = cv[k];
        if (fl[i] != VC_CONTACT) continue;
        double jn = 0.0;
        for (int q = 0; q < 3; q++) jn += (J[3 * i + q] - b[3 * i + q]) * cn[3 * k + q];
        if (jn < 0.0) { act[k] = 0; released++; }
    }
    if (released)  /* every contact vertex is free again until tc_contact_basis rebuilds the basis */
        for (int32_t k = 0; k < nc; k++) if (fl[cv[k]] == VC_CONTACT) fl[cv[k]] = VC_FREE;
    return released;
}

/* Coulomb friction on the active contacts: the tangential velocity relative to the surface loses
 * at most mu times the normal impulse (per unit mass). Returns the number of active contacts. */
int32_t tc_contacts_friction(tc_cloth *c, double *v, const double *J, const double *b)
{
    const int32_t nc = (int32_t)c->cvert.len;
    const int32_t *cv = tc_vec_ptr(&c->cvert);
    const double *cn = tc_vec_ptr(&c->cnormal), *cvel = tc_vec_ptr(&c->cvel), *cf = tc_vec_ptr(&c->cfric);
    const double *m = tc_vec_ptr(&c->mass);
    const int8_t *fl = tc_vec_ptr(&c->vflag), *act = tc_vec_ptr(&c->cactive);
    int32_t active = 0;
    for (int32_t k = 0; k < nc; k++) {
        int32_t i = cv[k];
        if (fl[i] != VC_CONTACT || !act[k]) continue;
        active++;
        if (cf[k] <= 0.0) continue;
        double *vi = v + 3 * i;
        const double *nn = cn + 3 * k, *vs = cvel + 3 * k;
        double jn = 0.0;
        for (int q = 0; q < 3; q++) jn += (J[3 * i + q] - b[3 * i + q]) * nn[q];
        if (!(jn > 0.0)) continue;  /* no push, no friction (and a negative cap would accelerate) */
        double rel[3] = {vi[0] - vs[0], vi[1] - vs[1], vi[2] - vs[2]};
        double rn = dot3(rel, nn);
        double vt[3] = {rel[0] - rn * nn[0], rel[1] - rn * nn[1], rel[2] - rn * nn[2]};
        double lt = sqrt(dot3(vt, vt));
        double cap = cf[k] * jn / m[i];  /* Coulomb: tangential impulse <= mu * normal impulse */
        double s = lt > cap ? cap / lt : 1.0;
        for (int q = 0; q < 3; q++) vi[q] -= s * vt[q];
    }
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
        double push = c->solver.contact_correction * cd[k] / dt;
        if (push > c->solver.contact_max_push) push = c->solver.contact_max_push;
        const double *nn = cn + 3 * k;
        double vn = dot3(v + 3 * i, nn) - dot3(cvel + 3 * k, nn);  /* relative normal speed */
        double take = vn < push ? (vn > 0 ? vn : 0.0) : push;
        for (int q = 0; q < 3; q++) v[3 * i + q] -= take * nn[q];
    }
}
