/* snapshot.c - the whole state of a cloth as one blob, and a cloth made from one (tearcloth.h).
 *
 * Why everything: a resumed bake must step exactly as the uninterrupted one would, and the next
 * step reads far more than positions and velocities - the solver's warm start (sdv), the tear
 * tips and their earned advance, the scan cursor, the order of pairs and stencils (which fixes the
 * order of every sum), the free lists, the pair hash (which fixes where new pairs go), the
 * handles' grasp and targets, the visit stamps of the tearing walks, counters. Sorting "state"
 * from "scratch" by hand is how the first resume drifted by millimetres, so every array of
 * FOR_EACH_VEC (cloth.c's tc_vec_table) is carried by its length, scratch included: the blob is a
 * few times the positions' size and an array another part adds later is carried with no change
 * here. Scalar fields of tc_cloth are listed below by hand (core.h says so next to the table).
 *
 * Layout (native byte order; a blob is for the build that wrote it):
 *   header  "TCCLOTH\0", u32 version, u32 byte-order mark, u64 payload bytes, u64 FNV-1a of payload
 *   payload struct sizes (refused on mismatch: a different build), settings, scalars, then each
 *           array as (name, item size, length, bytes) in table order, the pair hash, the handles.
 * Reading checks every length against what is left, the arrays' names and item sizes against this
 * build's table, the lengths against the counts, and every index against the array it points
 * into, so that a blob that passes cannot make a later step read out of bounds.
 */
#include "core.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char MAGIC[8] = {'T', 'C', 'C', 'L', 'O', 'T', 'H', 0};
#define BOM 0x01020304u
#define HEADER_BYTES 32

static uint64_t fnv1a(const unsigned char *p, size_t n)
{
    uint64_t h = 0xcbf29ce484222325ull;
    for (size_t i = 0; i < n; i++) { h ^= p[i]; h *= 0x100000001b3ull; }
    return h;
}

/* ---------------- writing ---------------- */

typedef struct { unsigned char *p; size_t n, cap; int oom; } wbuf;

static void put(wbuf *w, const void *src, size_t k)
{
    if (w->oom || !k) return;
    if (w->n + k > w->cap) {
        size_t ncap = w->cap ? w->cap : 4096;
        while (ncap < w->n + k) ncap *= 2;
        unsigned char *np = realloc(w->p, ncap);
        if (!np) { w->oom = 1; return; }
        w->p = np; w->cap = ncap;
    }
    memcpy(w->p + w->n, src, k);
    w->n += k;
}
static void put_u32(wbuf *w, uint32_t x) { put(w, &x, sizeof x); }
static void put_u64(wbuf *w, uint64_t x) { put(w, &x, sizeof x); }
static void put_i32(wbuf *w, int32_t x) { put(w, &x, sizeof x); }
static void put_f64(wbuf *w, double x) { put(w, &x, sizeof x); }
static void put_u8(wbuf *w, unsigned x) { unsigned char b = (unsigned char)x; put(w, &b, 1); }

/* struct sizes a blob must agree on */
static void sizes(uint32_t out[7])
{
    out[0] = sizeof(tc_material); out[1] = sizeof(tc_solver_settings); out[2] = sizeof(tc_tear_settings);
    out[3] = sizeof(tc_stats); out[4] = sizeof(tc_stencil); out[5] = (uint32_t)tc_vec_table_len;
    out[6] = sizeof(double[12]);
}

/* Arrays appended to the table after the layouts of earlier releases, the first of each release:
 * the contact state a vertex carries from one sub-step to the next (vcstate, vkinetic), then the
 * pins' goals (vgoal, vgoal0), then the soft pins' springs (vpink). A blob written before them
 * lacks them and resumes with no contact state carried, its pins holding still where they are and
 * no soft pin, so a bake killed under an earlier release is not lost to the update. */
static const char *const APPENDED[] = {"vcstate", "vgoal", "vpink"};

static size_t appended_at(const char *name)
{
    for (size_t k = 0; k < tc_vec_table_len; k++)
        if (!strcmp(tc_vec_table[k].name, name)) return k;
    return tc_vec_table_len;
}

static tc_vec *vec_at(const tc_cloth *c, size_t k) { return (tc_vec *)((char *)c + tc_vec_table[k].offset); }

int tc_cloth_snapshot(const tc_cloth *c, void **out, size_t *size)
{
    /* the multigrid hierarchy is derived state, not carried: a run resumed from this blob builds
       it afresh at its next sub-step, so this one does too (else the two solve with preconditioners
       of different ages and part at the tolerance's level) */
    tc_precondition_snapshot(c);
    wbuf w = {0};
    unsigned char header[HEADER_BYTES] = {0};
    put(&w, header, sizeof header);  /* filled in at the end */
    uint32_t sz[7];
    sizes(sz);
    for (int i = 0; i < 7; i++) put_u32(&w, sz[i]);
    put(&w, &c->mat, sizeof c->mat);
    put(&w, &c->solver, sizeof c->solver);
    put(&w, &c->tear, sizeof c->tear);
    put(&w, &c->stats, sizeof c->stats);
    put_i32(&w, c->nv); put_i32(&w, c->nt); put_i32(&w, c->ng);
    put_i32(&w, c->scan_cursor); put_i32(&w, c->stamp); put_i32(&w, c->rows_nv);
    put_u8(&w, c->dirty); put_u8(&w, c->topo_dirty); put_u8(&w, c->rows_built);
    put_f64(&w, c->carried2); put_f64(&w, c->mass_scale);
    put_f64(&w, c->solve_residual_force); put_f64(&w, c->solve_force_scale); put_f64(&w, c->solve_residual);
    put_u64(&w, c->pair_version); put_u64(&w, c->rows_version);
    for (size_t k = 0; k < tc_vec_table_len; k++) {
        const tc_vec *v = vec_at(c, k);
        uint32_t nl = (uint32_t)strlen(tc_vec_table[k].name);
        put_u32(&w, nl); put(&w, tc_vec_table[k].name, nl);
        put_u32(&w, (uint32_t)v->item); put_u64(&w, (uint64_t)v->len);
        put(&w, tc_vec_ptr(v), v->len * v->item);
    }
    /* the pair hash; one dropped (mesh.c: between a build and the first tear) is made for the blob
       and dropped again (the format keeps it, so the blobs of earlier builds and this one's read alike) */
    const bool made = !c->hvals;
    if (made && tc_pair_hash_ensure((tc_cloth *)c)) { free(w.p); return TC_ERR_NOMEM; }
    put_u64(&w, c->hcap); put_u64(&w, c->hcount); put_u64(&w, c->htomb);
    /* the layout of the builds that kept the keys beside the ids (key i, key j, id per slot; key i
       -1 empty, -2 tombstone), so one reader takes the blobs of either: the keys are the pairs'
       ends (mesh.c), checked against them when read */
    {
        const int32_t *pi = tc_vec_ptr(&c->pi), *pj = tc_vec_ptr(&c->pj);
        for (size_t s = 0; s < c->hcap; s++) put_i32(&w, c->hvals[s] < 0 ? c->hvals[s] : pi[c->hvals[s]]);
        for (size_t s = 0; s < c->hcap; s++) put_i32(&w, c->hvals[s] < 0 ? -1 : pj[c->hvals[s]]);
        put(&w, c->hvals, c->hcap * sizeof(int32_t));
    }
    if (made) tc_pair_hash_drop((tc_cloth *)c);
    put_i32(&w, c->nh);
    for (int32_t h = 0; h < c->nh; h++) {
        const tc_handle *H = &c->handles[h];
        put_u8(&w, H->active); put_i32(&w, H->count);
        put(&w, H->verts, (size_t)H->count * sizeof(int32_t));
        put(&w, H->grasp, 3 * (size_t)H->count * sizeof(double));
        put(&w, H->prev, sizeof H->prev); put(&w, H->target, sizeof H->target); put(&w, H->force, sizeof H->force);
    }
    if (w.oom) { free(w.p); return TC_ERR_NOMEM; }
    uint32_t version = TC_SNAPSHOT_VERSION, bom = BOM;
    uint64_t payload = w.n - HEADER_BYTES, sum = fnv1a(w.p + HEADER_BYTES, payload);
    memcpy(w.p, MAGIC, 8); memcpy(w.p + 8, &version, 4); memcpy(w.p + 12, &bom, 4);
    memcpy(w.p + 16, &payload, 8); memcpy(w.p + 24, &sum, 8);
    *out = w.p; *size = w.n;
    return TC_OK;
}

/* ---------------- reading ---------------- */

typedef struct { const unsigned char *p; size_t n, at; } rbuf;

static int get(rbuf *r, void *dst, size_t k)
{
    if (k > r->n - r->at) return -1;
    memcpy(dst, r->p + r->at, k);
    r->at += k;
    return 0;
}

/* every value of an int32 array (len items of `per` values) in [lo, hi) */
static int in_range(const tc_vec *v, int32_t lo, int64_t hi)
{
    const int32_t *a = tc_vec_ptr(v);
    for (size_t i = 0; i < v->len; i++)
        if (a[i] < lo || a[i] >= hi) return 0;
    return 1;
}

static int all_finite(const tc_vec *v)
{
    const double *a = tc_vec_ptr(v);
    for (size_t i = 0; i < v->len; i++)
        if (!isfinite(a[i])) return 0;
    return 1;
}

/* Counts and indices: everything a step dereferences. Returns the name of what is wrong, or NULL. */
static const char *check(const tc_cloth *c)
{
    const size_t nv = (size_t)c->nv, nt = (size_t)c->nt, np = c->pi.len;
    struct { const tc_vec *v; size_t len; const char *name; } lens[] = {
        {&c->x, 3 * nv, "x"}, {&c->v, 3 * nv, "v"}, {&c->rest, 3 * nv, "rest"}, {&c->force, 3 * nv, "force"},
        {&c->sr, 3 * nv, "sr"}, {&c->sz, 3 * nv, "sz"}, {&c->sp, 3 * nv, "sp"},
        {&c->sq, 3 * nv, "sq"}, {&c->sfix, 3 * nv, "sfix"}, {&c->sb2, 3 * nv, "sb2"},
        {&c->sdv, 3 * nv, "sdv"}, {&c->v0, 3 * nv, "v0"},
        {&c->diag, 12 * nv, "diag"}, {&c->pinv, 9 * nv, "pinv"}, {&c->snorm, 9 * nv, "snorm"},
        {&c->scount, nv, "scount"}, {&c->vsa, nv, "vsa"}, {&c->vcstate, nv, "vcstate"}, {&c->vkinetic, 3 * nv, "vkinetic"}, {&c->mass, nv, "mass"}, {&c->vbend, nv, "vbend"},
        {&c->strength, nv, "strength"}, {&c->vtri, nv, "vtri"}, {&c->vflag, nv, "vflag"},
        {&c->vhandle, nv, "vhandle"}, {&c->vpin, nv, "vpin"}, {&c->groups, nv * (size_t)(c->ng ? c->ng : 1), "groups"},
        {&c->tri, 3 * nt, "tri"}, {&c->tpair, 3 * nt, "tpair"}, {&c->grad, 4 * nt, "grad"}, {&c->area, nt, "area"},
        {&c->rot, 6 * nt, "rot"}, {&c->sig, 3 * nt, "sig"},
        {&c->uv, 6 * nt, "uv"}, {&c->tplast, 4 * nt, "tplast"},
        {&c->pj, np, "pj"}, {&c->puse, np, "puse"}, {&c->ptris, 2 * np, "ptris"}, {&c->pstencil, np, "pstencil"},
        {&c->pbend, np, "pbend"}, {&c->tipdir, 3 * c->tips.len, "tipdir"}, {&c->tipadv, c->tips.len, "tipadv"},
        {&c->cactive, c->cvert.len, "cactive"}, {&c->cnormal, 3 * c->cvert.len, "cnormal"},
        {&c->cdepth, c->cvert.len, "cdepth"}, {&c->cvel, 3 * c->cvert.len, "cvel"},
        {&c->cfric, c->cvert.len, "cfric"}, {&c->ev_par, 2 * c->ev_newv.len, "ev_par"},
        {&c->ev_w, c->ev_newv.len, "ev_w"},
    };
    for (size_t k = 0; k < sizeof lens / sizeof *lens; k++)
        if (lens[k].v->len != lens[k].len) return lens[k].name;
    /* stored or not (ortho.c's head); the axes both or neither */
    if (c->tgrain.len && c->tgrain.len != nt) return "tgrain";
    if (c->twarp.len != (c->taxis.len ? 3 * nt : 0) || c->taxis.len != (c->twarp.len ? 2 * nt : 0)) return "twarp";
    if (!all_finite(&c->x)) return "x (not finite)";
    if (!all_finite(&c->v)) return "v (not finite)";
    if (!all_finite(&c->rest)) return "rest (not finite)";
    if (!all_finite(&c->vkinetic)) return "vkinetic (not finite)";
    /* the pins' goals: not made yet, or one per vertex coordinate, finite */
    if ((c->vgoal.len != 0 && c->vgoal.len != 3 * nv) || c->vgoal0.len != c->vgoal.len) return "vgoal";
    if (!all_finite(&c->vgoal) || !all_finite(&c->vgoal0)) return "vgoal (not finite)";
    /* the soft pins' springs: not made yet, or one per vertex, finite and >= 0, with their goals */
    if (c->vpink.len != 0 && (c->vpink.len != nv || c->vgoal.len != 3 * nv)) return "vpink";
    {
        const double *k = tc_vec_ptr(&c->vpink);
        for (size_t i = 0; i < c->vpink.len; i++)
            if (!(k[i] >= 0 && k[i] <= TC_PIN_SPRING_MAX)) return "vpink (not finite or out of range)";
    }
    {
        const int8_t *cs = tc_vec_ptr(&c->vcstate);
        for (size_t i = 0; i < c->vcstate.len; i++)
            if (cs[i] < TC_CARRY_NONE || cs[i] > TC_CARRY_LIFTED) return "vcstate";
    }
    if (!in_range(&c->tri, 0, c->nv)) return "tri";
    if (!in_range(&c->tpair, 0, (int64_t)np)) return "tpair";
    if (!in_range(&c->pi, -1, c->nv)) return "pi";
    if (!in_range(&c->pj, -1, c->nv)) return "pj";
    if (!in_range(&c->ptris, -1, c->nt)) return "ptris";
    if (!in_range(&c->pstencil, -1, (int64_t)INT32_MAX + 1)) return "pstencil";  /* >= 0: has a stencil */
    if (!in_range(&c->pfree, 0, (int64_t)np)) return "pfree";
    if (!in_range(&c->vtri, -1, c->nt)) return "vtri";
    if (!in_range(&c->vhandle, -1, c->nh)) return "vhandle";
    if (!in_range(&c->tips, 0, c->nv)) return "tips";
    if (!in_range(&c->cvert, 0, c->nv)) return "cvert";
    if (!in_range(&c->ev_newv, 0, c->nv)) return "ev_newv";
    if (!in_range(&c->ev_par, -1, c->nv)) return "ev_par";
    if (!in_range(&c->ev_chg, 0, c->nt)) return "ev_chg";
    if (!in_range(&c->ev_newt, 0, c->nt)) return "ev_newt";
    if (c->rows_built) {
        if (c->rptr.len != (size_t)c->rows_nv + 1 || c->fptr.len != (size_t)c->rows_nv + 1 || c->rows_nv > c->nv)
            return "rows";
        const int32_t *rp = tc_vec_ptr(&c->rptr), *fp = tc_vec_ptr(&c->fptr);
        if (rp[0] != 0 || fp[0] != 0) return "rptr";
        for (int32_t i = 0; i < c->rows_nv; i++)
            if (rp[i + 1] < rp[i] || fp[i + 1] < fp[i]) return "rptr";
        if ((size_t)rp[c->rows_nv] != c->rcol.len || (size_t)fp[c->rows_nv] != c->fcol.len) return "rptr";
        if (c->rblk.len < 9 * c->rcol.len + TC_ROW_SLACK || c->fval.len < c->fcol.len) return "rblk";
        if (!in_range(&c->rcol, 0, c->rows_nv) || !in_range(&c->fcol, 0, c->rows_nv)) return "rcol";
        if (!in_range(&c->pslot, -1, (int64_t)(c->rcol.len > c->fcol.len ? c->rcol.len : c->fcol.len))) return "pslot";
        if (c->pslot.len < 2 * np && c->rows_version == c->pair_version) return "pslot";
    }
    /* the pair hash: probing stops at an empty slot, so there must be one */
    if (!c->hcap || (c->hcap & (c->hcap - 1)) || c->hcount + c->htomb >= c->hcap) return "pair hash";
    for (size_t s = 0; s < c->hcap; s++)  /* a live slot names a live pair (its key: mesh.c) */
        if (c->hvals[s] < -2 || c->hvals[s] >= (int64_t)np || (c->hvals[s] >= 0 && ((const int32_t *)tc_vec_ptr(&c->pi))[c->hvals[s]] < 0))
            return "pair hash";
    for (int32_t h = 0; h < c->nh; h++)
        for (int32_t k = 0; k < c->handles[h].count; k++)
            if (c->handles[h].verts[k] < 0 || c->handles[h].verts[k] >= c->nv) return "handles";
    if (c->ng < 0 || c->ng > 4096 || c->nv < 3 || c->nt < 1) return "counts";
    return NULL;
}

tc_cloth *tc_cloth_from_snapshot(const void *data, size_t size, char *msg, size_t msz)
{
#define FAIL(...) do { snprintf(msg, msz, __VA_ARGS__); goto fail; } while (0)
#define GET(dst, k) do { if (get(&r, (dst), (k))) FAIL("snapshot is truncated (%zu bytes; it ends inside %s)", size, where); } while (0)
    const char *where = "the header";
    tc_cloth *c = NULL;
    int32_t *keys = NULL;  /* the pair hash's keys while they are checked */
    const unsigned char *p = data;
    if (!p || size < HEADER_BYTES) { snprintf(msg, msz, "snapshot is truncated: %zu bytes, less than its %d-byte header", size, HEADER_BYTES); return NULL; }
    if (memcmp(p, MAGIC, 8)) { snprintf(msg, msz, "not a cloth snapshot (bad magic)"); return NULL; }
    uint32_t version, bom;
    uint64_t payload, sum;
    memcpy(&version, p + 8, 4); memcpy(&bom, p + 12, 4); memcpy(&payload, p + 16, 8); memcpy(&sum, p + 24, 8);
    if (bom != BOM) { snprintf(msg, msz, "snapshot was written on a machine of the other byte order"); return NULL; }
    if (version != TC_SNAPSHOT_VERSION) {
        snprintf(msg, msz, "snapshot version %u is not the version %d this build reads", version, TC_SNAPSHOT_VERSION);
        return NULL;
    }
    if (payload != size - HEADER_BYTES) {
        snprintf(msg, msz, "snapshot is %s: its header says %llu bytes follow, %zu do", payload > size - HEADER_BYTES ? "truncated" : "too long",
                 (unsigned long long)payload, size - HEADER_BYTES);
        return NULL;
    }
    if (fnv1a(p + HEADER_BYTES, payload) != sum) { snprintf(msg, msz, "snapshot is corrupted (checksum mismatch)"); return NULL; }
    rbuf r = {p, size, HEADER_BYTES};
    uint32_t want[7], got[7];
    sizes(want);
    where = "the layout";
    GET(got, sizeof got);
    /* tc_stats only ever grows at its end (counters are appended): a state written before the
     * contact and friction counters (the 984a6bc layout) still resumes, those counters from 0, so
     * a bake killed under the previous release is not lost to an update. Anything else must match. */
    uint32_t stats_bytes = got[3];
    got[3] = want[3];
    /* so do the blobs written before the arrays appended from FIRST_APPENDED on (below) */
    const size_t arrays = got[5];
    for (size_t k = 0; k < sizeof APPENDED / sizeof *APPENDED; k++)
        if (arrays == appended_at(APPENDED[k])) got[5] = want[5];
    if (memcmp(want, got, sizeof want)) FAIL("snapshot was written by a different build of the core (struct sizes or array count differ)");
    if (stats_bytes > want[3])
        FAIL("snapshot was written by a newer build of the core (its statistics hold %u bytes, this build's %u)", stats_bytes, want[3]);
    if (stats_bytes < TC_STATS_OLDEST_BYTES || stats_bytes % 8)
        FAIL("snapshot was written by a different build of the core (statistics of %u bytes)", stats_bytes);
    c = calloc(1, sizeof *c);
    if (!c) FAIL("out of memory");
    where = "the settings";
    GET(&c->mat, sizeof c->mat); GET(&c->solver, sizeof c->solver); GET(&c->tear, sizeof c->tear);
    GET(&c->stats, stats_bytes);  /* the rest stays 0 from calloc */
    where = "the counts";
    GET(&c->nv, 4); GET(&c->nt, 4); GET(&c->ng, 4);
    GET(&c->scan_cursor, 4); GET(&c->stamp, 4); GET(&c->rows_nv, 4);
    unsigned char flags[3];
    GET(flags, 3);
    c->dirty = flags[0] != 0; c->topo_dirty = flags[1] != 0; c->rows_built = flags[2] != 0;
    GET(&c->carried2, 8); GET(&c->mass_scale, 8);
    GET(&c->solve_residual_force, 8); GET(&c->solve_force_scale, 8); GET(&c->solve_residual, 8);
    GET(&c->pair_version, 8); GET(&c->rows_version, 8);
    if (c->nv < 3 || c->nt < 1 || c->ng < 0 || c->ng > 4096 || c->rows_nv < 0)
        FAIL("snapshot has bad counts (%d vertices, %d triangles, %d groups)", (int)c->nv, (int)c->nt, c->ng);
    if (tc_material_check(&c->mat, msg, msz) || tc_solver_check(&c->solver, msg, msz) || tc_tear_check(&c->tear, msg, msz))
        goto fail;
    /* every array starts empty so that a failure half-way frees cleanly */
    for (size_t k = 0; k < tc_vec_table_len; k++)
        if (tc_vec_init(vec_at(c, k), tc_vec_table[k].item, 1)) FAIL("out of memory");
    for (size_t k = 0; k < arrays; k++) {
        where = tc_vec_table[k].name;
        tc_vec *v = vec_at(c, k);
        uint32_t nl, item;
        uint64_t len;
        char name[64];
        GET(&nl, 4);
        if (nl == 0 || nl >= sizeof name) FAIL("snapshot is corrupted (array %zu has a name of %u bytes)", k, nl);
        GET(name, nl);
        name[nl] = 0;
        if (strcmp(name, tc_vec_table[k].name))
            FAIL("snapshot was written by a different build of the core (array %zu is '%s', this build has '%s')", k, name, tc_vec_table[k].name);
        GET(&item, 4); GET(&len, 8);
        if (item != tc_vec_table[k].item)
            FAIL("snapshot was written by a different build of the core (array '%s' has %u-byte items, not %zu)", name, item, tc_vec_table[k].item);
        if (len > (r.n - r.at) / item) FAIL("snapshot is truncated (array '%s' says %llu items)", name, (unsigned long long)len);
        if (tc_vec_resize(v, (size_t)len)) FAIL("out of memory");
        GET(tc_vec_ptr(v), (size_t)len * item);
    }
    /* a blob from before the carried contact state: none carried (every vertex's next sub-step
       judges its contacts afresh, as on first touch) */
    if (arrays < tc_vec_table_len && (tc_vec_resize(&c->vcstate, (size_t)c->nv) || tc_vec_resize(&c->vkinetic, 3 * (size_t)c->nv)))
        FAIL("out of memory");
    /* a blob from before the pins' goals has none (every pin holds still where it is), as a cloth
       whose pins never moved */
    /* a blob of the builds that stored the world stress, the principal stresses and direction
       (derived now, see core.h) or had a vector of their own for the solve's prescribed part
       (sfix2: in sz now, solver.c) carries them: nothing reads them, so they go */
    tc_vec_free(&c->stress); tc_vec_free(&c->pdir); tc_vec_free(&c->principal); tc_vec_free(&c->sfix2);
    if (tc_vec_init(&c->stress, sizeof(double), 1) || tc_vec_init(&c->pdir, sizeof(double), 1) ||
        tc_vec_init(&c->principal, sizeof(double), 1) || tc_vec_init(&c->sfix2, sizeof(double), 1))
        FAIL("out of memory");
    /* likewise the builds that had vectors of their own for b, x0 and the elastic force (in force,
       sp and force now: step.c, fem.c); their contents were scratch, rewritten before read, except
       the elastic force, which a stale cloth's next sub-step makes again and a fresh one's force
       already holds in its total */
    tc_vec_free(&c->sb); tc_vec_free(&c->x0); tc_vec_free(&c->fel);
    if (tc_vec_init(&c->sb, sizeof(double), 1) || tc_vec_init(&c->x0, sizeof(double), 1) ||
        tc_vec_init(&c->fel, sizeof(double), 1))
        FAIL("out of memory");
    /* and the builds that stored the bending stencils (made again from the mesh now, mesh.c) carry
       them and their free list: their pstencil ids, >= 0, mark the edges that have one */
    tc_vec_free(&c->stencils); tc_vec_free(&c->sfree);
    if (tc_vec_init(&c->stencils, sizeof(tc_stencil), 1) || tc_vec_init(&c->sfree, sizeof(int32_t), 1))
        FAIL("out of memory");
    where = "the pair hash";
    uint64_t hcap, hcount, htomb;
    GET(&hcap, 8); GET(&hcount, 8); GET(&htomb, 8);
    if (!hcap || (hcap & (hcap - 1)) || hcap > (r.n - r.at) / (3 * sizeof(int32_t)))
        FAIL("snapshot is corrupted (pair hash of %llu slots)", (unsigned long long)hcap);
    c->hcap = (size_t)hcap; c->hcount = (size_t)hcount; c->htomb = (size_t)htomb;
    /* keys and ids (see the writer): the ids kept, an empty or tombstone slot by its key; a live
       slot's key must be its pair's ends, which the probes read in its place */
    c->hvals = malloc(c->hcap * sizeof(int32_t));
    keys = malloc(2 * c->hcap * sizeof(int32_t));
    if (!c->hvals || !keys) FAIL("out of memory");
    GET(keys, 2 * c->hcap * sizeof(int32_t));
    GET(c->hvals, c->hcap * sizeof(int32_t));
    {
        const int32_t *pi = tc_vec_ptr(&c->pi), *pj = tc_vec_ptr(&c->pj), np = (int32_t)c->pi.len;
        for (size_t s = 0; s < c->hcap; s++) {
            const int32_t a = keys[s], b = keys[c->hcap + s], p = c->hvals[s];
            if (a < 0) { if (a < -2) FAIL("snapshot is corrupted (pair hash slot %zu)", s); c->hvals[s] = a; continue; }
            if (p < 0 || p >= np || pi[p] != a || pj[p] != b)
                FAIL("snapshot is corrupted (pair hash slot %zu names pair %d, not the pair of %d-%d)", s, (int)p, (int)a, (int)b);
        }
    }
    free(keys);
    keys = NULL;
    where = "the handles";
    int32_t nh;
    GET(&nh, 4);
    if (nh < 0 || (size_t)nh > (r.n - r.at) / (1 + 4 + 27 * sizeof(double))) FAIL("snapshot is corrupted (%d handles)", (int)nh);
    if (nh) {
        c->handles = calloc((size_t)nh, sizeof *c->handles);
        if (!c->handles) FAIL("out of memory");
        c->hcap_handles = nh;
    }
    for (int32_t h = 0; h < nh; h++) {
        tc_handle *H = &c->handles[h];
        unsigned char active;
        int32_t count;
        GET(&active, 1); GET(&count, 4);
        if (count < 0 || (size_t)count > (r.n - r.at) / (4 + 3 * sizeof(double))) FAIL("snapshot is corrupted (handle %d has %d members)", (int)h, (int)count);
        H->active = active != 0;
        H->verts = malloc((count ? (size_t)count : 1) * sizeof(int32_t));
        H->grasp = malloc((count ? 3 * (size_t)count : 1) * sizeof(double));
        c->nh = h + 1;  /* from here on destroy frees this handle's members */
        if (!H->verts || !H->grasp) FAIL("out of memory");
        GET(H->verts, (size_t)count * sizeof(int32_t)); GET(H->grasp, 3 * (size_t)count * sizeof(double));
        H->count = count;
        GET(H->prev, sizeof H->prev); GET(H->target, sizeof H->target); GET(H->force, sizeof H->force);
    }
    c->nh = nh;
    if (r.at != r.n) FAIL("snapshot is corrupted (%zu bytes left over)", r.n - r.at);
    const char *bad = check(c);
    if (bad) FAIL("snapshot is inconsistent (%s does not match the counts or points out of range)", bad);
    /* a sheet whose material reads the axes stores them (a blob written so always has them) */
    if (tc_material_general(&c->mat) && tc_axes_store(c)) FAIL("out of memory");
    /* rows from the builds that kept pair order within a row (before the Gauss-Seidel sweeps read
       each row's lower slots as one range, mesh.c): the next assembly builds the pattern again */
    if (!tc_rows_sweep_ordered(c)) c->rows_built = false;
    return c;
fail:
    free(keys);
    tc_cloth_destroy(c);
    return NULL;
#undef GET
#undef FAIL
}
