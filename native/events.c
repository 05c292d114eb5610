/* events.c - the topology events of one step: new vertices (with their parents and weights),
 * triangles whose corners changed, new triangles, the running tear tips, and the vertices and
 * triangles removed with tiny fragments (fragment.c).
 *
 * Tearing records them as it remeshes; callers (clusters, the Blender mesh, the cache) read them
 * after the step through tc_cloth_events() and update incrementally instead of rebuilding. They are
 * cleared when the next step begins, so they always describe exactly one step.
 */
#include "core.h"

void tc_events_clear(tc_cloth *c)
{
    c->ev_newv.len = c->ev_par.len = c->ev_w.len = c->ev_chg.len = c->ev_newt.len = 0;
    c->ev_rmv.len = c->ev_rmt.len = 0;
}

tc_events tc_cloth_events(const tc_cloth *c)
{
    tc_events e = {
        .n_new_vertices = (int32_t)c->ev_newv.len, .new_vertices = tc_vec_ptr(&c->ev_newv),
        .parents = tc_vec_ptr(&c->ev_par), .weights = tc_vec_ptr(&c->ev_w),
        .n_changed_triangles = (int32_t)c->ev_chg.len, .changed_triangles = tc_vec_ptr(&c->ev_chg),
        .n_new_triangles = (int32_t)c->ev_newt.len, .new_triangles = tc_vec_ptr(&c->ev_newt),
        .n_tips = (int32_t)c->tips.len, .tips = tc_vec_ptr(&c->tips),
        .n_removed_vertices = (int32_t)c->ev_rmv.len, .removed_vertices = tc_vec_ptr(&c->ev_rmv),
        .n_removed_triangles = (int32_t)c->ev_rmt.len, .removed_triangles = tc_vec_ptr(&c->ev_rmt),
    };
    return e;
}

int tc_event_new_vertex(tc_cloth *c, int32_t v, int32_t a, int32_t b, double wa)
{
    if (tc_vec_push_i32(&c->ev_newv, v) || tc_vec_push_i32(&c->ev_par, a) || tc_vec_push_i32(&c->ev_par, b) ||
        tc_vec_push_f64(&c->ev_w, wa))
        return TC_ERR_NOMEM;
    return TC_OK;
}

int tc_event_new_triangle(tc_cloth *c, int32_t t) { return tc_vec_push_i32(&c->ev_newt, t); }

/* A triangle is listed once however often it changes in the step, and a triangle created in this
 * step is only "new": readers take its corners from the arrays anyway. */
int tc_event_changed_triangle(tc_cloth *c, int32_t t)
{
    const int32_t *e = tc_vec_ptr(&c->ev_chg);
    for (size_t i = 0; i < c->ev_chg.len; i++)
        if (e[i] == t) return TC_OK;
    const int32_t *nt = tc_vec_ptr(&c->ev_newt);
    for (size_t i = 0; i < c->ev_newt.len; i++)
        if (nt[i] == t) return TC_OK;
    return tc_vec_push_i32(&c->ev_chg, t);
}
