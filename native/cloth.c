/* cloth.c - life cycle of a cloth (create, validate, destroy), its settings, constraints
 * (pins, handles, contacts), the implicit Euler step with a filtered PCG solve, and the outputs
 * (arrays, handle forces of eq. (6), energies, statistics).
 *
 * One sub-step: with rotations R frozen at x0,
 *   ((1 + dt a) M + (dt^2 + dt b)(K + B)) v1 = M v0 + dt f(x0),  x1 = x0 + dt v1,
 * solved by conjugate gradients preconditioned with the inverse 3x3 diagonal blocks and warm-started
 * from the last velocity. Constraints enter as velocity filters (Baraff & Witkin 1998): pins and
 * handles fix all three components, a contact fixes the normal one to the touched surface's
 * (inelastic). A contact whose reaction would pull (adhesion) is released and the system solved
 * once more; friction then caps the tangential velocity change at mu times the normal impulse.
 * Penetration is recovered by a bounded extra normal speed inside the solve (contact_correction of
 * the depth per step, at most contact_max_push), taken back out of the velocity after the step, so
 * a vertex pushed out never keeps the speed to bounce away.
 */
#include "core.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

double tc_now(void)
{
    struct timespec ts;
    timespec_get(&ts, TIME_UTC);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

tc_solver_settings tc_solver_default(void)
{
    tc_solver_settings s = {.gravity = {0.0, 0.0, -9.81}, .cg_tolerance = 1e-3, .cg_max_iterations = 200,
                            .max_stretch = 20.0, .contact_max_push = 0.1,
                            .contact_correction = 0.2};
    return s;
}

tc_tear_settings tc_tear_default(void)
{
    tc_tear_settings s = {.enabled = 0, .scan_period = 16, .min_angle_deg = 10.0};
    return s;
}

#define FOR_EACH_VEC(c, X)                                                                           \
    X(x, double) X(v, double) X(rest, double) X(mass, double) X(force, double) X(groups, double)       \
    X(strength, double) X(vtri, int32_t) X(vflag, int8_t) X(vhandle, int32_t) X(vpin, int8_t)          \
    X(vbend, double) X(tri, int32_t) X(tpair, int32_t) X(grad, double) X(area, double) \
    X(rot, double) X(sig, double) X(stress, double) X(principal, double) X(pdir, double) X(uv, double)  \
    X(pi, int32_t) X(pj, int32_t) X(puse, int32_t) X(ptris, int32_t) X(pstencil, int32_t)              \
    X(pbend, double) X(pblock, double) X(pfree, int32_t) X(stencils, tc_stencil) X(sfree, int32_t)    \
    X(cvert, int32_t) X(cactive, int8_t) X(scount, int8_t) X(cnormal, double) X(cdepth, double) X(cvel, double) X(cfric, double)            \
    X(diag, double) X(pinv, double) X(sb, double) X(sr, double) X(sz, double) X(sp, double)            \
    X(sq, double) X(sdv, double) X(sb2, double) X(sfix2, double) X(sfix, double) X(snorm, double) X(x0, double) X(v0, double) X(fel, double)          \
    X(vs9, double) X(vsn, double) X(vsa, double) X(tips, int32_t) X(tipdir, double) X(ev_newv, int32_t) X(ev_par, int32_t) X(ev_w, double)          \
    X(ev_chg, int32_t) X(ev_newt, int32_t)

void tc_cloth_destroy(tc_cloth *c)
{
    if (!c) return;
#define FREE_VEC(name, type) tc_vec_free(&c->name);
    FOR_EACH_VEC(c, FREE_VEC)
#undef FREE_VEC
    free(c->hkeys_i); free(c->hkeys_j); free(c->hvals);
    for (int32_t h = 0; h < c->nh; h++) { free(c->handles[h].verts); free(c->handles[h].grasp); }
    free(c->handles);
    free(c);
}

tc_cloth *tc_cloth_create(const double *positions, int32_t n, const int32_t *triangles, int32_t m,
                          const double *rest, int rest_dim, const double *corner_uv,
                          const double *groups, int n_groups, const tc_material *material,
                          char *msg, size_t msz)
{
#define FAIL(...) do { snprintf(msg, msz, __VA_ARGS__); tc_cloth_destroy(c); return NULL; } while (0)
    tc_cloth *c = NULL;
    if (n < 3) { snprintf(msg, msz, "a cloth needs at least 3 vertices (got %d)", (int)n); return NULL; }
    if (m < 1) { snprintf(msg, msz, "a cloth needs at least 1 triangle (got %d)", (int)m); return NULL; }
    if (n_groups < 0 || n_groups > 4096) { snprintf(msg, msz, "bad number of vertex groups %d", n_groups); return NULL; }
    if (rest && rest_dim != 2 && rest_dim != 3) { snprintf(msg, msz, "rest coordinates must have 2 or 3 columns (got %d)", rest_dim); return NULL; }
    if (material && tc_material_check(material, msg, msz)) return NULL;
    for (int64_t i = 0; i < 3 * (int64_t)n; i++)
        if (!isfinite(positions[i])) {
            snprintf(msg, msz, "vertex %d has a non-finite coordinate (%g)", (int)(i / 3), positions[i]);
            return NULL;
        }
    if (rest)
        for (int64_t i = 0; i < rest_dim * (int64_t)n; i++)
            if (!isfinite(rest[i])) {
                snprintf(msg, msz, "rest coordinate of vertex %d is not finite (%g)", (int)(i / rest_dim), rest[i]);
                return NULL;
            }
    for (int32_t t = 0; t < m; t++) {
        const int32_t *T = triangles + 3 * (size_t)t;
        for (int k = 0; k < 3; k++)
            if (T[k] < 0 || T[k] >= n) {
                snprintf(msg, msz, "triangle %d refers to vertex %d, outside [0, %d)", (int)t, (int)T[k], (int)n);
                return NULL;
            }
        if (T[0] == T[1] || T[1] == T[2] || T[0] == T[2]) {
            snprintf(msg, msz, "triangle %d is degenerate: it repeats a vertex (%d, %d, %d)", (int)t, (int)T[0], (int)T[1], (int)T[2]);
            return NULL;
        }
    }
    c = calloc(1, sizeof *c);
    if (!c) { snprintf(msg, msz, "out of memory"); return NULL; }
    c->mat = material ? *material : tc_material_default();
    c->solver = tc_solver_default();
    c->tear = tc_tear_default();
    c->ng = n_groups;
    int bad = 0;
#define INIT_VEC(name, type) bad |= tc_vec_init(&c->name, sizeof(type), 16);
    FOR_EACH_VEC(c, INIT_VEC)
#undef INIT_VEC
    if (bad) FAIL("out of memory");
    c->hcap = 64;
    c->hkeys_i = malloc(c->hcap * sizeof(int32_t)); c->hkeys_j = malloc(c->hcap * sizeof(int32_t));
    c->hvals = malloc(c->hcap * sizeof(int32_t));
    if (!c->hkeys_i || !c->hkeys_j || !c->hvals) FAIL("out of memory");
    for (size_t s = 0; s < c->hcap; s++) c->hkeys_i[s] = -1;
    c->nv = n; c->nt = m;
    if (tc_reserve_vertices(c, n) || tc_reserve_triangles(c, m)) FAIL("out of memory");
    memcpy(tc_vec_ptr(&c->x), positions, 3 * (size_t)n * sizeof(double));
    double *X = tc_vec_ptr(&c->rest);
    if (!rest) memcpy(X, positions, 3 * (size_t)n * sizeof(double));
    else for (int32_t i = 0; i < n; i++) {
        X[3 * i] = rest[rest_dim * i]; X[3 * i + 1] = rest[rest_dim * i + 1];
        X[3 * i + 2] = rest_dim == 3 ? rest[3 * i + 2] : 0.0;
    }
    memcpy(tc_vec_ptr(&c->tri), triangles, 3 * (size_t)m * sizeof(int32_t));
    if (corner_uv) memcpy(tc_vec_ptr(&c->uv), corner_uv, 6 * (size_t)m * sizeof(double));
    if (groups && n_groups) memcpy(tc_vec_ptr(&c->groups), groups, (size_t)n * n_groups * sizeof(double));
    for (int32_t t = 0; t < m; t++)
        if (tc_tri_rest(c, t, msg, msz)) { tc_cloth_destroy(c); return NULL; }
    if (tc_mesh_build(c, msg, msz)) { tc_cloth_destroy(c); return NULL; }
    tc_masses_update(c);
    c->dirty = true;
    return c;
#undef FAIL
}

int tc_cloth_set_material(tc_cloth *c, const tc_material *m)
{
    if (tc_material_check(m, c->err, sizeof c->err)) return TC_ERR_INPUT;
    double rho_h = c->mat.density * c->mat.thickness;
    c->mat = *m;
    if (rho_h != m->density * m->thickness) tc_masses_update(c);
    c->dirty = true;
    return TC_OK;
}

tc_material tc_cloth_material(const tc_cloth *c) { return c->mat; }

int tc_cloth_set_solver(tc_cloth *c, const tc_solver_settings *s)
{
    for (int k = 0; k < 3; k++)
        if (!isfinite(s->gravity[k]) || fabs(s->gravity[k]) > 1e4) {
            tc_set_err(c, "gravity component %d is not a plausible acceleration (%g m/s^2)", k, s->gravity[k]);
            return TC_ERR_INPUT;
        }
    if (!(s->cg_tolerance > 0 && s->cg_tolerance < 1)) { tc_set_err(c, "cg_tolerance must lie in (0, 1) (got %g)", s->cg_tolerance); return TC_ERR_INPUT; }
    if (s->cg_max_iterations < 1 || s->cg_max_iterations > 100000) { tc_set_err(c, "cg_max_iterations must lie in [1, 100000] (got %d)", s->cg_max_iterations); return TC_ERR_INPUT; }
    if (!(s->max_stretch > 1.0)) { tc_set_err(c, "max_stretch must be > 1 (got %g)", s->max_stretch); return TC_ERR_INPUT; }
    if (!(s->contact_max_push > 0 && isfinite(s->contact_max_push))) { tc_set_err(c, "contact_max_push must be > 0 m/s (got %g)", s->contact_max_push); return TC_ERR_INPUT; }
    if (!(s->contact_correction >= 0 && s->contact_correction <= 1)) { tc_set_err(c, "contact_correction must lie in [0, 1] (got %g)", s->contact_correction); return TC_ERR_INPUT; }
    c->solver = *s;
    return TC_OK;
}

tc_solver_settings tc_cloth_solver(const tc_cloth *c) { return c->solver; }
int32_t tc_cloth_num_vertices(const tc_cloth *c) { return c->nv; }
int32_t tc_cloth_num_triangles(const tc_cloth *c) { return c->nt; }
int tc_cloth_num_groups(const tc_cloth *c) { return c->ng; }
tc_stats tc_cloth_stats(const tc_cloth *c) { return c->stats; }

static int check_finite(tc_cloth *c, const double *a, size_t k, const char *what)
{
    for (size_t i = 0; i < k; i++)
        if (!isfinite(a[i])) { tc_set_err(c, "%s of vertex %d is not finite (%g)", what, (int)(i / 3), a[i]); return TC_ERR_INPUT; }
    return TC_OK;
}

int tc_cloth_set_positions(tc_cloth *c, const double *x, int32_t n)
{
    if (n != c->nv) { tc_set_err(c, "expected %d positions, got %d", (int)c->nv, (int)n); return TC_ERR_INPUT; }
    if (check_finite(c, x, 3 * (size_t)n, "position")) return TC_ERR_INPUT;
    memcpy(tc_vec_ptr(&c->x), x, 3 * (size_t)n * sizeof(double));
    c->dirty = true;
    return TC_OK;
}

int tc_cloth_set_velocities(tc_cloth *c, const double *v, int32_t n)
{
    if (n != c->nv) { tc_set_err(c, "expected %d velocities, got %d", (int)c->nv, (int)n); return TC_ERR_INPUT; }
    if (check_finite(c, v, 3 * (size_t)n, "velocity")) return TC_ERR_INPUT;
    memcpy(tc_vec_ptr(&c->v), v, 3 * (size_t)n * sizeof(double));
    return TC_OK;
}

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
        if (!isfinite(l) || fabs(l - 1.0) > 1e-3) { tc_set_err(c, "contact %d: normal is not a unit vector (length %g)", (int)i, l); return TC_ERR_INPUT; }
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

/* ---------------- the step ---------------- */

/* Removes the constrained components: all three for pins and handles, the span of the vertex's
 * contact normals (an orthonormal basis of up to three directions) for contacts. */
static void filter(const tc_cloth *c, double *r)
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

static void invert_diag(tc_cloth *c)
{
    const double *D = tc_vec_ptr(&c->diag);
    double *P = tc_vec_ptr(&c->pinv);
    for (int32_t i = 0; i < c->nv; i++) {
        const double *a = D + 9 * i;
        double *o = P + 9 * i;
        double c00 = a[4] * a[8] - a[5] * a[7], c01 = a[5] * a[6] - a[3] * a[8], c02 = a[3] * a[7] - a[4] * a[6];
        double det = a[0] * c00 + a[1] * c01 + a[2] * c02;
        if (!(fabs(det) > 1e-300)) {  /* cannot happen with positive masses; stay safe */
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

/* Solves A v = b on the constraint manifold {v_i = S_i v_i + z_i}; v holds the warm start. */
TC_HOT static int pcg(tc_cloth *c, double *v, const double *b, double floor, double *residual)
{
    const size_t n3 = 3 * (size_t)c->nv;
    double *r = tc_vec_ptr(&c->sr), *z = tc_vec_ptr(&c->sz), *p = tc_vec_ptr(&c->sp), *q = tc_vec_ptr(&c->sq);
    const double *fix = tc_vec_ptr(&c->sfix);
    const int8_t *fl = tc_vec_ptr(&c->vflag);
    const double *N = tc_vec_ptr(&c->snorm);
    const int8_t *cnt = tc_vec_ptr(&c->scount);
    for (int32_t i = 0; i < c->nv; i++) {  /* put the warm start on the constraint manifold */
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
    memcpy(q, b, n3 * sizeof(double));
    filter(c, q);
    precondition(c, q, z);
    filter(c, z);
    double bnorm = dotn(q, z, n3);
    if (bnorm < floor) bnorm = floor;
    tc_matvec(c, v, q);
    for (size_t k = 0; k < n3; k++) r[k] = b[k] - q[k];
    filter(c, r);
    precondition(c, r, z);
    filter(c, z);
    memcpy(p, z, n3 * sizeof(double));
    double rz = dotn(r, z, n3);
    const double tol2 = c->solver.cg_tolerance * c->solver.cg_tolerance;
    int it = 0;
    if (bnorm <= 0) bnorm = 1e-300;
    while (it < c->solver.cg_max_iterations && rz > tol2 * bnorm) {
        tc_matvec(c, p, q);
        filter(c, q);
        double pq = dotn(p, q, n3);
        if (!(pq > 0)) break;  /* A is SPD on the manifold; a non-positive curvature means round-off */
        double alpha = rz / pq;
        for (size_t k = 0; k < n3; k++) { v[k] += alpha * p[k]; r[k] -= alpha * q[k]; }
        precondition(c, r, z);
        filter(c, z);
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
static int solve_dv(tc_cloth *c, double *v, const double *v0, const double *b, double *residual)
{
    const size_t n3 = 3 * (size_t)c->nv;
    double *rhs = tc_vec_ptr(&c->sb2), *fix = tc_vec_ptr(&c->sfix), *fixu = tc_vec_ptr(&c->sfix2);
    const int8_t *fl = tc_vec_ptr(&c->vflag), *cnt = tc_vec_ptr(&c->scount);
    const double *N = tc_vec_ptr(&c->snorm);
    /* a cloth at rest has almost no net force: without a floor the relative tolerance would
       chase round-off: the residual need not go below tolerance * 0.1 of the full right-hand side */
    double floor = 0.0;
    {
        const double *P = tc_vec_ptr(&c->pinv);
        for (int32_t i = 0; i < c->nv; i++) {
            const double *p = P + 9 * i, *x = b + 3 * i;
            floor += x[0] * (p[0] * x[0] + p[1] * x[1] + p[2] * x[2]) + x[1] * (p[3] * x[0] + p[4] * x[1] + p[5] * x[2]) +
                     x[2] * (p[6] * x[0] + p[7] * x[1] + p[8] * x[2]);
        }
        floor *= 1e-2;
    }
    tc_matvec(c, v0, rhs);
    for (size_t k = 0; k < n3; k++) { rhs[k] = b[k] - rhs[k]; v[k] -= v0[k]; }
    /* the constrained components of du: the prescribed velocity minus v0's part along them */
    memcpy(fixu, fix, n3 * sizeof(double));
    for (int32_t i = 0; i < c->nv; i++) {
        if (fl[i] == VC_FREE) continue;
        double *z = fixu + 3 * i;
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
    /* pcg reads the prescribed values from sfix: hand it du's for the solve */
    tc_vec keep = c->sfix;
    c->sfix = c->sfix2;
    int it = pcg(c, v, rhs, floor, residual);
    c->sfix2 = c->sfix;
    c->sfix = keep;
    for (size_t k = 0; k < n3; k++) v[k] += v0[k];
    return it;
}

static void apply_affine(const double *M, const double *p, double *o)
{
    for (int r = 0; r < 3; r++) o[r] = M[4 * r] * p[0] + M[4 * r + 1] * p[1] + M[4 * r + 2] * p[2] + M[4 * r + 3];
}

/* Per-vertex force at positions x: elastic (fel, already computed) + bending + gravity. */
static void total_force(tc_cloth *c, const double *x)
{
    double *f = tc_vec_ptr(&c->force);
    const double *fe = tc_vec_ptr(&c->fel), *m = tc_vec_ptr(&c->mass);
    const double *g = c->solver.gravity;
    for (int32_t i = 0; i < c->nv; i++)
        for (int k = 0; k < 3; k++) f[3 * i + k] = fe[3 * i + k] + m[i] * g[k];
    tc_bending_force(c, x, f);
}

static void handle_forces(tc_cloth *c)
{
    const double *f = tc_vec_ptr(&c->force);
    for (int32_t h = 0; h < c->nh; h++) {
        tc_handle *H = &c->handles[h];
        H->force[0] = H->force[1] = H->force[2] = 0.0;
        for (int32_t i = 0; i < H->count; i++)
            for (int k = 0; k < 3; k++) H->force[k] += f[3 * H->verts[i] + k];
    }
}

/* Per vertex, an orthonormal basis of its active contact normals with the normal velocity each
 * one prescribes (inelastic: the touched surface's). A vertex may touch several things at once -
 * a body and another layer of cloth over it - and must respect all of them: keeping only the
 * deepest let the layers push each other through the body in turn, which pumped energy. Normals
 * that add no new direction (a vertex squeezed between two layers) share the prescribed speed. */
static void build_contact_basis(tc_cloth *c, double dt)
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
        if (lu > 0.25 && cnt[i] < 3) {
            double e[3] = {u[0] / lu, u[1] / lu, u[2] / lu};
            double zf = z - dot3(fix + 3 * i, n);  /* what the earlier components leave to do */
            double ze = zf / lu;
            memcpy(N + 9 * i + 3 * cnt[i], e, sizeof e);
            cnt[i]++;
            for (int q = 0; q < 3; q++) fix[3 * i + q] += ze * e[q];
        } else if (best >= 0) {
            const double *e = N + 9 * i + 3 * best;
            double cur = dot3(fix + 3 * i, e), want = z / bestd;
            double delta = 0.5 * (want - cur);
            for (int q = 0; q < 3; q++) fix[3 * i + q] += delta * e[q];
        }
    }
}

static int substep(tc_cloth *c, double dt, double alpha_target)
{
    const int32_t n = c->nv;
    const size_t n3 = 3 * (size_t)n;
    double *x = tc_vec_ptr(&c->x), *v = tc_vec_ptr(&c->v);
    double *x0 = tc_vec_ptr(&c->x0), *v0 = tc_vec_ptr(&c->v0), *b = tc_vec_ptr(&c->sb);
    if (c->dirty) { tc_element_pass(c, x); total_force(c, x); c->dirty = false; }
    memcpy(x0, x, n3 * sizeof(double));
    memcpy(v0, v, n3 * sizeof(double));

    /* constraints of this sub-step */
    int8_t *fl = tc_vec_ptr(&c->vflag);
    const int8_t *pin = tc_vec_ptr(&c->vpin);
    double *fix = tc_vec_ptr(&c->sfix);
    memset(fl, VC_FREE, (size_t)n);
    const int32_t nc = (int32_t)c->cvert.len;
    const int32_t *cv = tc_vec_ptr(&c->cvert);
    const double *cn = tc_vec_ptr(&c->cnormal), *cd = tc_vec_ptr(&c->cdepth), *cvel = tc_vec_ptr(&c->cvel);
    int8_t *act = tc_vec_ptr(&c->cactive);
    memset(act, 1, (size_t)nc);
    build_contact_basis(c, dt);
    for (int32_t i = 0; i < n; i++)
        if (pin[i]) { fl[i] = VC_PINNED; fix[3 * i] = fix[3 * i + 1] = fix[3 * i + 2] = 0.0; }
    for (int32_t h = 0; h < c->nh; h++) {
        tc_handle *H = &c->handles[h];
        if (!H->active) continue;
        double M[12];
        for (int q = 0; q < 12; q++) M[q] = H->prev[q] + alpha_target * (H->target[q] - H->prev[q]);
        for (int32_t k = 0; k < H->count; k++) {
            int32_t i = H->verts[k];
            double goal[3];
            apply_affine(M, H->grasp + 3 * k, goal);
            fl[i] = VC_HANDLE;
            for (int q = 0; q < 3; q++) fix[3 * i + q] = (goal[q] - x[3 * i + q]) / dt;
        }
    }

    /* right-hand side M v0 + dt f(x0) */
    const double *m = tc_vec_ptr(&c->mass), *f = tc_vec_ptr(&c->force);
    for (int32_t i = 0; i < n; i++)
        for (int q = 0; q < 3; q++) b[3 * i + q] = m[i] * v0[3 * i + q] + dt * f[3 * i + q];

    tc_assemble(c, dt);
    invert_diag(c);
    double res = 0.0;
    /* warm start: the velocity change of the last step (constant acceleration), exact for a
       falling cloth and close for any smooth motion; pcg projects it onto this step's constraints */
    const double *dv_prev = tc_vec_ptr(&c->sdv);
    for (size_t k = 0; k < n3; k++) v[k] = v0[k] + dv_prev[k];
    int it = solve_dv(c, v, v0, b, &res);

    if (nc) {
        /* release contacts whose reaction pulls the cloth onto the surface, then friction */
        double *J = tc_vec_ptr(&c->sq);
        tc_matvec(c, v, J);
        int released = 0;
        for (int32_t k = 0; k < nc; k++) {
            int32_t i = cv[k];
            if (fl[i] != VC_CONTACT) continue;
            double jn = 0.0;
            for (int q = 0; q < 3; q++) jn += (J[3 * i + q] - b[3 * i + q]) * cn[3 * k + q];
            if (jn < 0.0) { act[k] = 0; released++; }
        }
        if (released) {
            for (int32_t k = 0; k < nc; k++) if (fl[cv[k]] == VC_CONTACT) fl[cv[k]] = VC_FREE;
            build_contact_basis(c, dt);
            it += solve_dv(c, v, v0, b, &res);
            tc_matvec(c, v, J);
        }
        const double *cf = tc_vec_ptr(&c->cfric);
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
        c->stats.contacts = active;
    } else {
        c->stats.contacts = 0;
    }

    for (size_t k = 0; k < n3; k++) x[k] = x0[k] + dt * v[k];
    /* the recovery speed was for this step's position only: take it back out of the velocity, so a
       vertex pushed out of a body does not keep flying away (no bounce) */
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
    {
        double *dv = tc_vec_ptr(&c->sdv);
        for (size_t k = 0; k < n3; k++) dv[k] = v[k] - v0[k];
    }
    double worst = tc_element_pass(c, x);
    int bad = !(worst == worst) || worst > c->solver.max_stretch;
    for (size_t k = 0; k < n3 && !bad; k++) bad = !isfinite(v[k]);
    if (bad) {
        memcpy(x, x0, n3 * sizeof(double));
        memcpy(v, v0, n3 * sizeof(double));
        tc_element_pass(c, x);  /* stresses and rotations back to the state rolled back to */
        total_force(c, x);
        tc_set_err(c, "step rolled back: %s (largest stretch %g, limit %g; CG %d iterations, residual %g). "
                      "Reduce the time step or raise sub-steps.",
                   worst == worst ? "exploding strain" : "non-finite values", worst, c->solver.max_stretch, it, res);
        return TC_ERR_UNSTABLE;
    }
    total_force(c, x);
    c->stats.cg_iterations += it;
    c->stats.cg_residual = res;
    return TC_OK;
}

int tc_cloth_step(tc_cloth *c, double dt, int substeps)
{
    if (!(dt > 0) || !isfinite(dt) || dt > 10.0) { tc_set_err(c, "time step must lie in (0, 10] s (got %g)", dt); return TC_ERR_INPUT; }
    if (substeps < 1 || substeps > 10000) { tc_set_err(c, "sub-steps must lie in [1, 10000] (got %d)", substeps); return TC_ERR_INPUT; }
    double t0 = tc_now();
    tc_events_clear(c);
    c->stats.cg_iterations = 0;
    double h = dt / substeps;
    int rc = TC_OK;
    for (int s = 0; s < substeps && rc == TC_OK; s++) rc = substep(c, h, (double)(s + 1) / substeps);
    if (rc == TC_OK)
        for (int32_t k = 0; k < c->nh; k++) memcpy(c->handles[k].prev, c->handles[k].target, 12 * sizeof(double));
    handle_forces(c);
    double t1 = tc_now();
    c->stats.fem_seconds = t1 - t0;
    c->stats.tear_seconds = 0.0;
    if (rc == TC_OK && c->tear.enabled) {
        rc = tc_tear_step(c);
        c->stats.tear_seconds = tc_now() - t1;
    }
    c->stats.steps++;
    return rc;
}

tc_energy tc_cloth_energy(tc_cloth *c)
{
    tc_energy e = {0};
    const double *x = tc_vec_ptr(&c->x), *v = tc_vec_ptr(&c->v), *m = tc_vec_ptr(&c->mass);
    for (int32_t i = 0; i < c->nv; i++) {
        e.kinetic += 0.5 * m[i] * dot3(v + 3 * i, v + 3 * i);
        e.gravity -= m[i] * dot3(c->solver.gravity, x + 3 * i);
    }
    e.elastic = tc_elastic_energy(c, x);
    e.bending = tc_bending_energy(c, x);
    return e;
}

tc_buf *tc_cloth_array(tc_cloth *c, tc_array_id id, size_t *rows, size_t *cols, size_t *item)
{
    tc_vec *v = NULL;
    size_t r = (size_t)c->nv, k = 3;
    *item = sizeof(double);
    switch (id) {
    case TC_POSITIONS: v = &c->x; break;
    case TC_VELOCITIES: v = &c->v; break;
    case TC_REST: v = &c->rest; break;
    case TC_MASSES: v = &c->mass; k = 1; break;
    case TC_FORCES: v = &c->force; break;
    case TC_GROUPS: v = &c->groups; k = (size_t)c->ng; break;
    case TC_TEAR_STRENGTH: v = &c->strength; k = 1; break;
    case TC_TRIANGLES: v = &c->tri; r = (size_t)c->nt; *item = sizeof(int32_t); break;
    case TC_CORNER_UV: v = &c->uv; r = (size_t)c->nt; k = 6; break;
    case TC_STRESS: v = &c->stress; r = (size_t)c->nt; k = 9; break;
    case TC_PRINCIPAL: v = &c->principal; r = (size_t)c->nt; k = 2; break;
    case TC_PRINCIPAL_DIR: v = &c->pdir; r = (size_t)c->nt; k = 3; break;
    default: return NULL;
    }
    if (id == TC_STRESS || id == TC_PRINCIPAL || id == TC_PRINCIPAL_DIR || id == TC_FORCES) {
        if (c->dirty) {  /* outputs must describe the current positions */
            tc_element_pass(c, tc_vec_ptr(&c->x));
            total_force(c, tc_vec_ptr(&c->x));
            c->dirty = false;
        }
    }
    *rows = r; *cols = k;
    tc_buf_incref(v->buf);
    return v->buf;
}
