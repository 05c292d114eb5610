/* fragment.c - removal of tiny fragments: pieces a tear set free whose rest area is below the
 * artist's min_fragment_area are deleted from the simulation, with their vertices.
 *
 * The rule: after the cuts of a step (or of a scripted tear), every piece that holds a triangle
 * the cuts changed or made, or a vertex they duplicated or its parent, is measured by a walk across uncut edges, stopped as soon as its rest
 * area reaches min_fragment_area (so a big piece costs a walk of a few triangles). A piece that the
 * walk closes below that area is removed, unless it is all that is left of the cloth. Why remove
 * at all: a piece of one or two triangles is below what the tearing model resolves (its stress is
 * averaged over tear_radius, wider than the piece), it carries no bending, and an implicit solve
 * on it is stiff for nothing; it is what a renderer would show as a speck.
 *
 * Why the piece's vertices can go with it: a cut separates the fans of a vertex by duplicating it
 * (remesh.c), so a piece that has come free shares no vertex, edge, flap or stencil with the rest.
 * That is checked before anything changes (a piece that shares a vertex with a kept triangle is
 * kept). Deleting it then keeps every invariant the rest of the core relies on:
 *   - its stencils are removed and its edge pairs released (mesh.c), so the pair table, the use
 *     counts and the free list stay consistent; the surviving pairs keep their ids, renumbered
 *     ends, and the hash is rebuilt for the new keys; the matrix rows are rebuilt lazily (the pair
 *     version changed);
 *   - per-vertex and per-triangle arrays are compacted in place, keeping the survivors' order
 *     (new vertices and triangles of the step stay at the end, as the events promise), and every
 *     index into them is renumbered: triangles, pairs, stencils, incident triangles, handles (their
 *     members on the piece dropped), contacts on the piece dropped, tear tips on the piece retired;
 *   - the step's topology events are rewritten in the new numbering, and the removed vertices and
 *     triangles that existed when the events began are listed (in that numbering), so a reader
 *     deletes those from what it holds and then applies the rest as usual (events.c, cloth.py);
 *     where the piece kept a vertex the cut duplicated, the duplicate that stays takes its id.
 * The survivors' positions, velocities, masses and element state are moved, never changed: the
 * momentum of the rest of the cloth is exactly what it was.
 */
#include "core.h"

#include <stdlib.h>
#include <string.h>

/* Per-vertex arrays and their values per vertex; the groups have ng per vertex (1 when none, as
 * tc_reserve_vertices sizes them). Every per-vertex tc_vec of FOR_EACH_VEC (cloth.c) but the walk
 * marks (vstamp, vqueue: stale marks are harmless, see tear.c's new_mark). */
#define VERTEX_ARRAYS(c, X)                                                                          \
    X(x, 3) X(v, 3) X(rest, 3) X(mass, 1) X(force, 3) X(groups, (c)->ng ? (c)->ng : 1) X(strength, 1)  \
    X(vtri, 1) X(vflag, 1) X(vhandle, 1) X(vpin, 1) X(vbend, 1) X(diag, 12) X(pinv, 9) X(sb, 3)         \
    X(sr, 3) X(sz, 3) X(sp, 3) X(sq, 3) X(sfix, 3) X(sb2, 3) X(sfix2, 3) X(sdv, 3) X(x0, 3) X(v0, 3)    \
    X(fel, 3) X(snorm, 9) X(scount, 1) X(vsa, 1) X(vcstate, 1) X(vkinetic, 3) X(vgoal, 3) X(vgoal0, 3) \
    X(vpink, 1)
/* Per-triangle arrays (tstamp, tqueue: walk marks, as above). */
#define TRIANGLE_ARRAYS(c, X)                                                                         \
    X(tri, 3) X(tpair, 3) X(grad, 4) X(area, 1) X(rot, 6) X(sig, 3) X(stress, 9) X(principal, 2)      \
    X(pdir, 3) X(uv, 6) X(tgrain, 1) X(twarp, 3) X(taxis, 2) X(tplast, 4)

/* Keeps item groups i with map[i] >= 0, moved to map[i] (map is increasing on them). */
static void compact(tc_vec *v, size_t per, const int32_t *map, size_t n, size_t kept)
{
    unsigned char *d = tc_vec_ptr(v);
    const size_t sz = per * v->item;
    if (v->len < n * per) return;  /* never sized for these items (cannot happen; never read past) */
    for (size_t i = 0; i < n; i++)
        if (map[i] >= 0 && (size_t)map[i] != i) memmove(d + (size_t)map[i] * sz, d + i * sz, sz);
    v->len = kept * per;
}

/* Lists a removed id that existed when the events began, in that numbering, keeping the list
 * sorted. id_now is in the current numbering, which differs from that one after an earlier removal
 * in the same event window (two scripted tears between steps): it is the id_now-th id not listed
 * before. Called for decreasing id_now within one removal, so ids listed by this removal (all
 * larger) never count. */
static void list_removed(tc_vec *out, int32_t id_now)
{
    int32_t o = id_now;
    size_t k = 0;
    const int32_t *r = tc_vec_ptr(out);
    for (; k < out->len && r[k] <= o; k++) o++;
    tc_vec_resize(out, out->len + 1);  /* within the capacity reserved by the caller: cannot fail */
    int32_t *w = tc_vec_ptr(out);
    memmove(w + k + 1, w + k, (out->len - 1 - k) * sizeof *w);
    w[k] = o;
}

/* The events in the new numbering: new items that went are forgotten, a parent that went is
 * dropped (the other parent takes its place, or -1: the reader treats the vertex as unexplained). */
static void rewrite_events(tc_cloth *c, const int32_t *vmap, const int32_t *tmap)
{
    int32_t *nv = tc_vec_ptr(&c->ev_newv), *par = tc_vec_ptr(&c->ev_par);
    double *w = tc_vec_ptr(&c->ev_w);
    size_t k = 0;
    for (size_t i = 0; i < c->ev_newv.len; i++) {
        if (vmap[nv[i]] < 0) continue;
        int32_t a = par[2 * i] >= 0 ? vmap[par[2 * i]] : -1, b = par[2 * i + 1] >= 0 ? vmap[par[2 * i + 1]] : -1;
        double wa = w[i];
        if (a < 0 && b >= 0) { a = b; b = -1; }
        if (b < 0) wa = 1.0;
        nv[k] = vmap[nv[i]]; par[2 * k] = a; par[2 * k + 1] = b; w[k] = wa;
        k++;
    }
    c->ev_newv.len = k; c->ev_par.len = 2 * k; c->ev_w.len = k;
    tc_vec *tl[] = {&c->ev_chg, &c->ev_newt};
    for (int j = 0; j < 2; j++) {
        int32_t *e = tc_vec_ptr(tl[j]);
        size_t m = 0;
        for (size_t i = 0; i < tl[j]->len; i++)
            if (tmap[e[i]] >= 0) e[m++] = tmap[e[i]];
        tl[j]->len = m;
    }
}

/* Renumbers what points at vertices and triangles (tmap NULL: triangles keep their ids), and drops
 * what pointed at removed ones. */
static void renumber(tc_cloth *c, const int32_t *vmap, const int32_t *tmap)
{
    const int32_t nt = c->nt;  /* already the kept count */
    int32_t *T = tc_vec_ptr(&c->tri);
    for (size_t i = 0; i < 3 * (size_t)nt; i++) T[i] = vmap[T[i]];
    int32_t *pi = tc_vec_ptr(&c->pi), *pj = tc_vec_ptr(&c->pj), *pt = tc_vec_ptr(&c->ptris);
    for (size_t p = 0; p < c->pi.len; p++) {
        if (pi[p] < 0) continue;
        pi[p] = vmap[pi[p]]; pj[p] = vmap[pj[p]];
        /* a pair's ends are kept ordered (pi < pj: the hash key, mesh.c); the compaction keeps
           the order, but a surviving duplicate taking its original's id can reverse it */
        if (pi[p] > pj[p]) { int32_t t = pi[p]; pi[p] = pj[p]; pj[p] = t; }
        if (tmap) for (int s = 0; s < 2; s++) if (pt[2 * p + s] >= 0) pt[2 * p + s] = tmap[pt[2 * p + s]];
    }
    int32_t *vt = tc_vec_ptr(&c->vtri);
    if (tmap) for (int32_t v = 0; v < c->nv; v++) if (vt[v] >= 0) vt[v] = tmap[vt[v]];
    for (int32_t h = 0; h < c->nh; h++) {
        tc_handle *H = &c->handles[h];
        int32_t k = 0;
        for (int32_t i = 0; i < H->count; i++) {
            if (vmap[H->verts[i]] < 0) continue;
            H->verts[k] = vmap[H->verts[i]];
            memmove(H->grasp + 3 * k, H->grasp + 3 * i, 3 * sizeof(double));
            k++;
        }
        H->count = k;  /* a handle whose every member went holds nothing and pulls with no force */
    }
    int32_t *cv = tc_vec_ptr(&c->cvert);
    int8_t *ca = tc_vec_ptr(&c->cactive);
    double *cn = tc_vec_ptr(&c->cnormal), *cd = tc_vec_ptr(&c->cdepth), *cw = tc_vec_ptr(&c->cvel), *cf = tc_vec_ptr(&c->cfric);
    size_t m = 0;
    for (size_t i = 0; i < c->cvert.len; i++) {
        if (vmap[cv[i]] < 0) continue;
        cv[m] = vmap[cv[i]]; ca[m] = ca[i]; cd[m] = cd[i]; cf[m] = cf[i];
        memmove(cn + 3 * m, cn + 3 * i, 3 * sizeof(double));
        memmove(cw + 3 * m, cw + 3 * i, 3 * sizeof(double));
        m++;
    }
    c->cvert.len = c->cactive.len = c->cdepth.len = c->cfric.len = m;
    c->cnormal.len = c->cvel.len = 3 * m;
    /* a tip on a removed piece has nothing left to cut: it retires with the piece */
    int32_t *tip = tc_vec_ptr(&c->tips);
    double *td = tc_vec_ptr(&c->tipdir), *ta = tc_vec_ptr(&c->tipadv);
    m = 0;
    for (size_t i = 0; i < c->tips.len; i++) {
        if (vmap[tip[i]] < 0) continue;
        tip[m] = vmap[tip[i]]; ta[m] = ta[i];
        memmove(td + 3 * m, td + 3 * i, 3 * sizeof(double));
        m++;
    }
    c->tips.len = c->tipadv.len = m;
    c->tipdir.len = 3 * m;
}

static void swap_rows(tc_vec *v, size_t per, int32_t a, int32_t b)
{
    unsigned char *d = tc_vec_ptr(v);
    const size_t sz = per * v->item;
    if (v->len < ((size_t)(a > b ? a : b) + 1) * per) return;  /* an array kept empty (sfix2: core.h) */
    for (size_t k = 0; k < sz; k++) {
        unsigned char t = d[(size_t)a * sz + k];
        d[(size_t)a * sz + k] = d[(size_t)b * sz + k];
        d[(size_t)b * sz + k] = t;
    }
}

/* When a cut duplicated vertex a and the piece that goes kept a, the duplicate that stays takes a's
 * id (rows and references swapped), so readers keep what they hold for a (its cluster, its
 * collision tracks) instead of meeting a new vertex whose parent is gone. perm: scratch, nv. */
static void keep_original_ids(tc_cloth *c, unsigned char *vdead, int32_t *perm)
{
    const size_t nv = (size_t)c->nv, old_v = nv - c->ev_newv.len;
    const int32_t *nw = tc_vec_ptr(&c->ev_newv), *par = tc_vec_ptr(&c->ev_par);
    bool any = false;
    for (size_t i = 0; i < nv; i++) perm[i] = (int32_t)i;
    for (size_t k = 0; k < c->ev_newv.len; k++) {
        int32_t v = nw[k], a = par[2 * k];
        if (par[2 * k + 1] >= 0 || a < 0 || (size_t)a >= old_v || !vdead[a] || vdead[v]) continue;
        perm[a] = v; perm[v] = a;
        vdead[a] = 0; vdead[v] = 1;
#define SWAP_V(name, per) swap_rows(&c->name, (size_t)(per), a, v);
        VERTEX_ARRAYS(c, SWAP_V)
#undef SWAP_V
        any = true;
    }
    if (!any) return;
    renumber(c, perm, NULL);
    tc_pair_hash_rebuild(c);  /* the removal below looks pairs up by their (new) ends */
}

/* Deletes the triangles with dead[t] and the vertices with vdead[v] (used by no other triangle). */
static void remove_pieces(tc_cloth *c, const unsigned char *dead, const unsigned char *vdead, int32_t *vmap, int32_t *tmap)
{
    const size_t nv = (size_t)c->nv, nt = (size_t)c->nt;
    const size_t old_v = nv - c->ev_newv.len, old_t = nt - c->ev_newt.len;  /* items the events began with */
    const int32_t *tp = tc_vec_ptr(&c->tpair);
    /* stencils first: removing one looks its flap up among the pairs, which must still be there */
    for (size_t t = 0; t < nt; t++)
        if (dead[t])
            for (int k = 0; k < 3; k++) tc_stencil_remove(c, tp[3 * t + k]);
    for (size_t t = 0; t < nt; t++)
        if (dead[t])
            for (int k = 0; k < 3; k++) {
                int32_t p = tp[3 * t + k];
                int32_t *pt = (int32_t *)tc_vec_ptr(&c->ptris) + 2 * (size_t)p;
                if (pt[0] == (int32_t)t) pt[0] = -1;
                if (pt[1] == (int32_t)t) pt[1] = -1;
                tc_pair_release(c, p);
            }
    size_t kv = 0, kt = 0;
    for (size_t i = 0; i < nv; i++) vmap[i] = vdead[i] ? -1 : (int32_t)kv++;
    for (size_t t = 0; t < nt; t++) tmap[t] = dead[t] ? -1 : (int32_t)kt++;
    for (size_t i = old_v; i-- > 0;)
        if (vdead[i]) list_removed(&c->ev_rmv, (int32_t)i);
    for (size_t t = old_t; t-- > 0;)
        if (dead[t]) list_removed(&c->ev_rmt, (int32_t)t);
    rewrite_events(c, vmap, tmap);
#define COMPACT_V(name, per) compact(&c->name, (size_t)(per), vmap, nv, kv);
#define COMPACT_T(name, per) compact(&c->name, (size_t)(per), tmap, nt, kt);
    VERTEX_ARRAYS(c, COMPACT_V)
    TRIANGLE_ARRAYS(c, COMPACT_T)
#undef COMPACT_V
#undef COMPACT_T
    c->stats.fragment_vertices_removed += (int32_t)(nv - kv);
    c->stats.fragment_triangles_removed += (int32_t)(nt - kt);
    c->nv = (int32_t)kv; c->nt = (int32_t)kt;
    renumber(c, vmap, tmap);
    tc_pair_hash_rebuild(c);
    c->pair_version++;
    c->scan_cursor = c->nt ? c->scan_cursor % c->nt : 0;
    c->dirty = c->topo_dirty = true;
}

/* The piece holding seed, walked across uncut edges into queue (marks: this walk's id) while its
 * rest area stays below amin. Returns its triangle count if the walk closed below amin, 0 if the
 * piece is larger (or meets a piece an earlier walk found larger). */
static int32_t small_piece(const tc_cloth *c, int32_t seed, int32_t walk, double amin, int32_t *mark, int32_t *queue)
{
    const double *A = tc_vec_ptr(&c->area);
    int32_t head = 0, tail = 0;
    double area = 0.0;
    queue[tail++] = seed;
    mark[seed] = walk;
    while (head < tail) {
        int32_t t = queue[head++];
        area += A[t];
        if (area >= amin) return 0;
        for (int k = 0; k < 3; k++) {
            int32_t nb = tc_nbr(c, t, k);
            if (nb < 0 || mark[nb] == walk) continue;
            if (mark[nb]) return 0;  /* an earlier walk stopped in it: large */
            mark[nb] = walk;
            queue[tail++] = nb;
        }
    }
    return tail;
}

int tc_fragments_remove(tc_cloth *c)
{
    const double amin = c->tear.min_fragment_area;
    if (!(amin > 0) || (c->ev_chg.len == 0 && c->ev_newt.len == 0 && c->ev_newv.len == 0) || c->nt < 2) return TC_OK;
    const size_t nt = (size_t)c->nt, nv = (size_t)c->nv;
    int32_t *mark = calloc(nt, sizeof *mark), *queue = malloc((nt > nv ? nt : nv) * sizeof *queue);
    int32_t *vmap = malloc(nv * sizeof *vmap), *tmap = malloc(nt * sizeof *tmap);
    unsigned char *dead = calloc(nt + nv, 1);
    int rc = TC_OK;
    if (!mark || !queue || !vmap || !tmap || !dead) { rc = TC_ERR_NOMEM; goto done; }
    unsigned char *vdead = dead + nt;
    int32_t walk = 0, ndead = 0, pieces = 0;
    /* Seeds: the triangles the events changed or made, and one triangle at each duplicated vertex
     * and at its parent. The last matter: a cut along existing edges changes the triangles of one
     * side only (those that take the duplicates), and the side that keeps the original vertices may
     * be the piece that came free. */
    const int32_t *vt = tc_vec_ptr(&c->vtri), *newv = tc_vec_ptr(&c->ev_newv), *par = tc_vec_ptr(&c->ev_par);
    const size_t nchg = c->ev_chg.len, nnew = c->ev_newt.len, ndup = c->ev_newv.len;
    for (size_t i = 0; i < nchg + nnew + 2 * ndup; i++) {
        int32_t s;
        if (i < nchg) s = ((const int32_t *)tc_vec_ptr(&c->ev_chg))[i];
        else if (i < nchg + nnew) s = ((const int32_t *)tc_vec_ptr(&c->ev_newt))[i - nchg];
        else {
            size_t k = (i - nchg - nnew) / 2;
            int32_t v = (i - nchg - nnew) % 2 ? par[2 * k] : newv[k];
            s = v >= 0 && v < c->nv ? vt[v] : -1;
        }
        if (s < 0 || s >= c->nt || mark[s]) continue;
        int32_t n = small_piece(c, s, ++walk, amin, mark, queue);
        if (n == 0 || ndead + n >= c->nt) continue;  /* large, or all that is left */
        for (int32_t q = 0; q < n; q++) dead[queue[q]] = 1;
        ndead += n;
        pieces++;
    }
    if (!pieces) goto done;
    /* A free piece shares nothing with the rest (see the file head). One that does (a vertex whose
     * fans a cut left joined) is kept and counted (tc_stats.fragments_kept): its walk's marks
     * name it, through the vertex's mark (vwalk, in queue as scratch). */
    const int32_t *T = tc_vec_ptr(&c->tri), *pi = tc_vec_ptr(&c->pi), *pj = tc_vec_ptr(&c->pj);
    int32_t *vwalk = queue;
    for (bool again = true; again && pieces;) {
        again = false;
        memset(vdead, 0, nv);
        for (size_t t = 0; t < nt; t++)
            if (dead[t]) for (int k = 0; k < 3; k++) { vdead[T[3 * t + k]] = 1; vwalk[T[3 * t + k]] = mark[t]; }
        int32_t bad = 0;
        for (size_t t = 0; t < nt && !bad; t++)
            if (!dead[t]) for (int k = 0; k < 3 && !bad; k++) if (vdead[T[3 * t + k]]) bad = vwalk[T[3 * t + k]];
        for (size_t p = 0; p < c->pi.len && !bad; p++)
            if (pi[p] >= 0 && vdead[pi[p]] != vdead[pj[p]]) bad = vwalk[vdead[pi[p]] ? pi[p] : pj[p]];
        if (!bad) break;
        for (size_t t = 0; t < nt; t++)
            if (dead[t] && mark[t] == bad) { dead[t] = 0; ndead--; }
        pieces--;
        c->stats.fragments_kept++;
        again = true;
    }
    if (!pieces) goto done;
    /* the lists of removed ids grow first: past this point nothing can fail half-way */
    size_t rv = 0, rt = 0;
    for (size_t i = 0; i < nv - c->ev_newv.len; i++) rv += vdead[i];
    for (size_t t = 0; t < nt - c->ev_newt.len; t++) rt += dead[t];
    if (tc_vec_reserve(&c->ev_rmv, c->ev_rmv.len + rv) || tc_vec_reserve(&c->ev_rmt, c->ev_rmt.len + rt)) {
        rc = TC_ERR_NOMEM;
        goto done;
    }
    keep_original_ids(c, vdead, vmap);
    remove_pieces(c, dead, vdead, vmap, tmap);
    c->stats.fragments_removed += pieces;
done:
    if (rc) tc_set_err(c, "out of memory removing fragments");
    free(mark); free(queue); free(vmap); free(tmap); free(dead);
    return rc;
}
