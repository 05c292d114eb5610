/* cloth.c - life cycle of a cloth (validate the input, create, destroy), its settings (material,
 * solver, tearing, per-vertex tear strength), positions and velocities, counts and statistics, and
 * the zero-copy arrays readers get (tc_cloth_array).
 *
 * The other parts live in their own files (see core.h for the map): constraints.c (pins, handles,
 * contacts), step.c (the time step), solver.c, fem.c, tear.c, events.c, mesh.c.
 */
#include "core.h"

#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define FOR_EACH_VEC(c, X)                                                                           \
    X(x, double) X(v, double) X(rest, double) X(mass, double) X(force, double) X(groups, double)       \
    X(strength, double) X(vtri, int32_t) X(vflag, int8_t) X(vhandle, int32_t) X(vpin, int8_t)          \
    X(vbend, double) X(tri, int32_t) X(tpair, int32_t) X(grad, double) X(area, double) \
    X(rot, double) X(sig, double) X(stress, double) X(principal, double) X(pdir, double) X(uv, double)  \
    X(pi, int32_t) X(pj, int32_t) X(puse, int32_t) X(ptris, int32_t) X(pstencil, int32_t)              \
    X(pbend, double) X(pfree, int32_t) X(stencils, tc_stencil) X(sfree, int32_t)    \
    X(cvert, int32_t) X(cactive, int8_t) X(scount, int8_t) X(cnormal, double) X(cdepth, double) X(cvel, double) X(cfric, double)            \
    X(diag, double) X(pinv, double) X(sb, double) X(sr, double) X(sz, double) X(sp, double)            \
    X(sq, double) X(sdv, double) X(sb2, double) X(sfix2, double) X(sfix, double) X(snorm, double) X(x0, double) X(v0, double) X(fel, double)          \
    X(vsa, double) X(tips, int32_t) X(tipdir, double) X(ev_newv, int32_t) X(ev_par, int32_t) X(ev_w, double)          \
    X(ev_chg, int32_t) X(ev_newt, int32_t) X(rptr, int32_t) X(rcol, int32_t) X(rblk, double) X(fptr, int32_t)  \
    X(fcol, int32_t) X(fval, double) X(pslot, int32_t) X(tipadv, double) X(tstamp, int32_t) X(vstamp, int32_t)     \
    X(tqueue, int32_t) X(vqueue, int32_t) X(tgrain, double) X(twarp, double) X(taxis, double) X(tplast, double) X(ev_rmv, int32_t) X(ev_rmt, int32_t) \
    X(vcstate, int8_t) X(vkinetic, double) X(vgoal, double) X(vgoal0, double) X(vpink, double)

/* The list above as data, for snapshot.c (which carries every array by it, so an array added to
 * the list is saved and restored with no change there). */
#define VEC_DESC(name, type) {#name, offsetof(tc_cloth, name), sizeof(type)},
const tc_vec_desc tc_vec_table[] = {FOR_EACH_VEC(c, VEC_DESC)};
#undef VEC_DESC
const size_t tc_vec_table_len = sizeof tc_vec_table / sizeof *tc_vec_table;

void tc_cloth_destroy(tc_cloth *c)
{
    if (!c) return;
#define FREE_VEC(name, type) tc_vec_free(&c->name);
    FOR_EACH_VEC(c, FREE_VEC)
#undef FREE_VEC
    free(c->hvals);
    for (int32_t h = 0; h < c->nh; h++) { free(c->handles[h].verts); free(c->handles[h].grasp); }
    free(c->handles);
    tc_amg_free(c->amg);
    tc_sgs_free(c->sgs);
    tc_stiff_free(c->stiff);
    tc_discs_free(c->discs);
    free(c);
}

tc_cloth *tc_cloth_create(const double *positions, int32_t n, const int32_t *triangles, int32_t m,
                          const double *rest, int rest_dim, const double *corner_uv,
                          const double *groups, int n_groups, const tc_material *material,
                          char *msg, size_t msz)
{
#define FAIL(...) do { snprintf(msg, msz, __VA_ARGS__); tc_cloth_destroy(c); return NULL; } while (0)
    tc_cloth *c = NULL;
    tc_culprits_clear();
    if (n < 3) { snprintf(msg, msz, "a cloth needs at least 3 vertices (got %d)", (int)n); return NULL; }
    if (m < 1) { snprintf(msg, msz, "a cloth needs at least 1 triangle (got %d)", (int)m); return NULL; }
    if (n_groups < 0 || n_groups > 4096) { snprintf(msg, msz, "bad number of vertex groups %d", n_groups); return NULL; }
    if (rest && rest_dim != 2 && rest_dim != 3) { snprintf(msg, msz, "rest coordinates must have 2 or 3 columns (got %d)", rest_dim); return NULL; }
    if (material && tc_material_check(material, msg, msz)) return NULL;
    for (int64_t i = 0; i < 3 * (int64_t)n; i++)
        if (!isfinite(positions[i])) {
            snprintf(msg, msz, "vertex %d has a non-finite coordinate (%g)", (int)(i / 3), positions[i]);
            tc_culprit(-1, (int32_t)(i / 3));
            return NULL;
        }
    if (rest)
        for (int64_t i = 0; i < rest_dim * (int64_t)n; i++)
            if (!isfinite(rest[i])) {
                snprintf(msg, msz, "rest coordinate of vertex %d is not finite (%g)", (int)(i / rest_dim), rest[i]);
                tc_culprit(-1, (int32_t)(i / rest_dim));
                return NULL;
            }
    /* a NaN or infinite UV made the triangle's warp fall back to the rest X axis, silently (and was
       carried into every piece a tear made of it) */
    if (corner_uv)
        for (int64_t i = 0; i < 6 * (int64_t)m; i++)
            if (!isfinite(corner_uv[i])) {
                const int32_t t = (int32_t)(i / 6), k = (int32_t)(i % 6) / 2;
                const int32_t vk = triangles[3 * (size_t)t + k];
                snprintf(msg, msz, "triangle %d has a non-finite UV coordinate (%g) at its corner on vertex %d", (int)t,
                         corner_uv[i], (int)vk);
                tc_culprit(t, vk >= 0 && vk < n ? vk : -1);
                return NULL;
            }
    for (int32_t t = 0; t < m; t++) {
        const int32_t *T = triangles + 3 * (size_t)t;
        for (int k = 0; k < 3; k++)
            if (T[k] < 0 || T[k] >= n) {
                snprintf(msg, msz, "triangle %d refers to vertex %d, outside [0, %d)", (int)t, (int)T[k], (int)n);
                tc_culprit(t, -1);
                return NULL;
            }
        if (T[0] == T[1] || T[1] == T[2] || T[0] == T[2]) {
            snprintf(msg, msz, "triangle %d is degenerate: it repeats a vertex (%d, %d, %d)", (int)t, (int)T[0], (int)T[1], (int)T[2]);
            tc_culprit(t, T[0]); tc_culprit(-1, T[1]); tc_culprit(-1, T[2]);
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
    c->hcap = TC_HASH_INITIAL;
    c->hvals = malloc(c->hcap * sizeof(int32_t));
    if (!c->hvals) FAIL("out of memory");
    for (size_t s = 0; s < c->hcap; s++) c->hvals[s] = -1;
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
    if (tc_material_general(&c->mat) && tc_axes_store(c)) FAIL("out of memory");
    if (tc_mesh_build(c, msg, msz)) { tc_cloth_destroy(c); return NULL; }
    tc_masses_update(c);
    tc_pair_hash_drop(c);  /* made again when a tear needs it (mesh.c) */
    c->dirty = true;
    return c;
#undef FAIL
}

int tc_cloth_set_material(tc_cloth *c, const tc_material *m)
{
    if (tc_material_check(m, c->err, sizeof c->err)) return TC_ERR_INPUT;
    double rho_h = c->mat.density * c->mat.thickness, grain = c->mat.grain_angle;
    const tc_material was = c->mat;
    c->mat = *m;
    /* the first material that reads the axes makes them, with its grain (ortho.c's head) */
    if (tc_material_general(m) && !tc_axes_stored(c)) {
        if (tc_axes_store(c)) { c->mat = was; tc_set_err(c, "out of memory"); return TC_ERR_NOMEM; }
    } else if (grain != m->grain_angle) tc_axes_refresh(c);
    if (rho_h != m->density * m->thickness) tc_masses_update(c);
    c->dirty = true;
    return TC_OK;
}

tc_material tc_cloth_material(const tc_cloth *c) { return c->mat; }

int tc_cloth_set_solver(tc_cloth *c, const tc_solver_settings *s)
{
    if (tc_solver_check(s, c->err, sizeof c->err)) return TC_ERR_INPUT;
    c->solver = *s;
    return TC_OK;
}

tc_solver_settings tc_cloth_solver(const tc_cloth *c) { return c->solver; }
int32_t tc_cloth_num_vertices(const tc_cloth *c) { return c->nv; }
int32_t tc_cloth_num_triangles(const tc_cloth *c) { return c->nt; }
int tc_cloth_num_groups(const tc_cloth *c) { return c->ng; }
tc_stats tc_cloth_stats(const tc_cloth *c) { return c->stats; }

/* The FOR_EACH_VEC arrays, then the storage outside them: one table is the whole account. */
enum { MEMORY_EXTRA = 5 };
size_t tc_cloth_memory_count(void) { return tc_vec_table_len + MEMORY_EXTRA; }
const char *tc_cloth_memory(const tc_cloth *c, size_t k, size_t *used, size_t *held)
{
    *used = *held = 0;
    if (k < tc_vec_table_len) {
        const tc_vec *v = (const tc_vec *)((const char *)c + tc_vec_table[k].offset);
        *used = v->len * v->item;
        *held = v->buf ? v->cap * v->item : 0;
        return tc_vec_table[k].name;
    }
    switch (k - tc_vec_table_len) {
    case 0: *used = (c->hcount + c->htomb) * sizeof(int32_t); *held = c->hcap * sizeof(int32_t); return "pair_hash";
    case 1: *used = *held = tc_amg_bytes(c->amg); return "amg";
    case 2: *used = *held = tc_sgs_bytes(c->sgs); return "sgs";
    case 3: *used = *held = tc_stiff_bytes(c->stiff); return "stiff";
    case 4: *used = *held = tc_discs_bytes(c->discs); return "discs";
    default: return NULL;
    }
}
const char *tc_cloth_error(const tc_cloth *c) { return c->err; }

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
    /* a pinned vertex put somewhere is pinned there: its goals move with it (a caller that drives
       goals sets them again before the next step) */
    double *g = tc_vec_ptr(&c->vgoal), *g0 = tc_vec_ptr(&c->vgoal0);
    if (c->vgoal.len)
        for (int32_t i = 0; i < n; i++)
            if (tc_follows_goal(c, i))
                for (int q = 0; q < 3; q++) g[3 * i + q] = g0[3 * i + q] = x[3 * i + q];
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

tc_tear_settings tc_cloth_tearing(const tc_cloth *c) { return c->tear; }

int tc_cloth_set_tearing(tc_cloth *c, const tc_tear_settings *s)
{
    if (tc_tear_check(s, c->err, sizeof c->err)) return TC_ERR_INPUT;
    c->tear = *s;
    return TC_OK;
}

int tc_cloth_set_tear_strength(tc_cloth *c, const double *f, int32_t n)
{
    if (n != c->nv) { tc_set_err(c, "expected %d tear strength factors, got %d", (int)c->nv, (int)n); return TC_ERR_INPUT; }
    for (int32_t i = 0; i < n; i++)
        if (!(f[i] > 0 && isfinite(f[i]))) { tc_set_err(c, "tear strength factor of vertex %d must be > 0 and finite (got %g)", (int)i, f[i]); return TC_ERR_INPUT; }
    memcpy(tc_vec_ptr(&c->strength), f, (size_t)n * sizeof(double));
    return TC_OK;
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
    case TC_GRAIN_ANGLES: v = c->tgrain.len ? &c->tgrain : NULL; r = (size_t)c->nt; k = 1; break;
    case TC_WARP: v = tc_axes_stored(c) ? &c->twarp : NULL; r = (size_t)c->nt; k = 3; break;
    case TC_PLASTIC_STRAIN: v = &c->tplast; r = (size_t)c->nt; k = 4; break;
    case TC_TRIANGLES: v = &c->tri; r = (size_t)c->nt; *item = sizeof(int32_t); break;
    case TC_CORNER_UV: v = &c->uv; r = (size_t)c->nt; k = 6; break;
    case TC_STRESS: r = (size_t)c->nt; k = 9; break;
    case TC_PRINCIPAL: r = (size_t)c->nt; k = 2; break;
    case TC_PRINCIPAL_DIR: r = (size_t)c->nt; k = 3; break;
    default: return NULL;
    }
    /* outputs must describe the current positions */
    if (id == TC_STRESS || id == TC_PRINCIPAL || id == TC_PRINCIPAL_DIR || id == TC_FORCES) tc_refresh(c);
    *rows = r; *cols = k;
    if (!v) {  /* derived from R and sigma (core.h), or the grain angles and warps a sheet does not
                  store (all NaN; made from the UVs: ortho.c), into a block of the reader's own */
        tc_buf *b = tc_buf_new(r * k * sizeof(double));
        if (!b) { tc_set_err(c, "out of memory"); return NULL; }
        double *o = (double *)b->data;
        for (size_t t = 0; t < r; t++) {
            if (id == TC_STRESS) tc_tri_world_stress(c, t, o + 9 * t);
            else if (id == TC_GRAIN_ANGLES) o[t] = NAN;
            else if (id == TC_WARP) tc_tri_warp(c, (int32_t)t, o + 3 * t);
            else if (id == TC_PRINCIPAL) tc_tri_principal(c, t, o + 2 * t);
            else tc_tri_principal_dir(c, t, o + 3 * t);
        }
        return b;
    }
    tc_buf_incref(v->buf);
    return v->buf;
}
