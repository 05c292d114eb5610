/* impact.c - the impact guard: the motion a step actually produced, x0 -> x1, made free of
 * self-crossings after the solve (Bridson, Fedkiw & Anderson 2002, section 7; Provot 1997;
 * Harmon et al. 2008).
 *
 * Why after the solve: the contacts of collision/ (rays, the swept stage's predicted pairs) are
 * constraints given to the implicit solve BEFORE it runs, over a predicted motion x + dt v. The
 * solve then produces another motion, and on a chaotic fold (a cloth flapping over a thin bar)
 * edges of the crease's two-ring crossed inside one step on some trajectories: a prediction
 * cannot promise anything about the motion it did not see. Here the motion the solve produced is
 * checked, and changed until no vertex-triangle or edge-edge pair of the cloth meets during it.
 *
 * What is tested: every vertex-triangle and edge-edge pair that shares no vertex, found by one BVH
 * over the whole cloth (built once per topology at the rest positions, tcc_bvh_build; its boxes
 * refitted here to the swept boxes of the step, grown by gap / 2) traversed against itself. Each
 * element is tested from one triangle only (its owner: vertex_owner, edge_owner), so every pair
 * is tested once. The exact swept tests are ccd.c's (tcc_ccd_vertex_triangle, tcc_ccd_edge_edge).
 * Why culling, and which: neighbouring triangles' boxes always overlap, so a plain traversal of a
 * garment tests every triangle against a dozen neighbours each step (~2.5 ms on the bench's shirt,
 * most of it finding nothing). A subtree whose triangles are a disk that provably cannot meet
 * itself during the step (its normals within a right angle of one axis at every instant, its
 * boundary projected along that axis a simple curve at every instant: "normal cones" below) is not
 * traversed, and two triangles sharing a vertex whose fan provably cannot meet itself are not
 * tested (fan_free). Both are exact certificates over the whole step, not heuristics; the tests
 * check them against brute force over every pair (tests/test_collision_impact.py).
 * A pair that coincides at rest (rest distance < min_rest: the two rims of a cut, twins of one
 * original vertex) is one piece of cloth and never a collision (counted as excluded); a pair close
 * at rest gets a gap of at most rest_fraction x its rest distance, so an irregular mesh is never
 * "touching" in its rest shape.
 *
 * A collision: a pair that comes within its gap during the step while its closest points approach
 * each other (the relative displacement along the direction between them is negative), or that
 * crosses (the swept test with gap 0: coplanar with its elements overlapping) whatever its gap test
 * said. A pair that starts within its gap but moves apart is resting contact, not a collision.
 *
 * Resolution, in the order of the references:
 * 1. impulses (up to impulse_passes detection passes): each collision, in the order found, gets an
 *    inelastic impulse along its normal on the step's mean velocities (x1 - x0) / dt, mass
 *    weighted and split over the corners by their weights (Bridson et al. 2002, eq. 10), so that
 *    its closest points move apart by a tiny SEPARATION x gap over the step (not zero: the next
 *    pass must see the pair as parting, robustly against rounding). Linear momentum is conserved.
 * 2. rigid impact zones (up to zone_passes passes): the vertices of every collision still found are
 *    merged into zones (union-find), and each zone gets the rigid motion that keeps its linear and
 *    angular momentum (about its centre of mass at x0): v = v_c + w x (x0 - x_c), I w = L (the
 *    pseudo-inverse of the inertia tensor where it is singular: a collinear zone has no angular
 *    momentum along its line). Why this ends: points under such a motion move on straight lines
 *    x0 + t dt v whose relative vectors are (I + t dt [w]x) r0, of length sqrt(|r0|^2 + t^2 dt^2
 *    |w x r0|^2) >= |r0|: no two points of one zone draw closer, so pairs inside one zone never
 *    collide (and are not tested), and every further pass merges two zones or a new vertex.
 * 3. the pass cap hit (counted as rigid_cloth): the whole cloth is one zone. Always free of
 *    crossings, the last resort of the references.
 * Vertices the step left exactly where they were (pinned, or held by static friction on a still
 * body) are immovable: an impulse moves only their partners, a zone holding one keeps still.
 *
 * Positions and velocities change only for vertices whose mean velocity changed: x1 = x0 + dt v',
 * and the end velocity changes by the same amount as the mean one (v1 += v' - v). Everything is
 * counted in tcc_impact_counts (impact.py turns it into the step report).
 */
#include "collide.h"
#include "vecmath.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* the separation speed a resolved pair leaves with, as a share of its gap per step */
#define SEPARATION 0.01
/* at a closest-point distance below this share of the gap the direction between the points is
 * noise: the geometric normal of the elements (oriented by the side they came from) is used */
#define NEAR_SHARE 0.01
/* depth of the self traversal (a median-split tree over 2^40 triangles is 41 deep) */
#define IMPACT_DEPTH 128
/* cosine of the widest normal cone of a patch that is not tested against itself: a right angle
 * less 1e-3 rad, far more than the rounding of the cone merges (1e-12 in the cosine each) */
#define COS_MIN 1e-3
/* a node's cone row: axis (3), cos and sin of the half-angle, the sum of its unit normals (3), valid */
#define CONE_LEN 9
/* a cross product or a projected area this small against its factors' lengths is a direction
 * rounding decides: no cone, no star */
#define SIN_MIN 1e-9

typedef struct {
    tcc_idx id[4];
    double w[4];  /* the relative point: sum w_i x_i (the first element's weights +, the second's -) */
    double n[3];  /* unit, from the second element towards the first; 0: none (zones only) */
    double gap;
} hit_t;

typedef struct {
    const tcc_impact_in *in;
    tcc_impact_counts *out;
    tcc_error *err;
    double *x1c;      /* (n, 3) current end positions */
    double *vel;      /* (n, 3) current mean velocities of the step */
    double *im;       /* (n,) inverse masses, 0: immovable */
    double *vbox;     /* (n, 6) swept vertex boxes, grown by gap / 2 */
    double *tbox;     /* (nt, 6) swept triangle boxes, grown by gap / 2 */
    uint8_t *own;     /* (nt,) bits 0-2: the triangle tests corner k; bits 3-5: its edge k */
    double *nbox;     /* (nnodes, 6) */
    uint8_t *dirty;   /* (n,) motion changed since the last detection */
    uint8_t *changed; /* (n,) motion changed in this call */
    uint8_t *tdirty;  /* (nt,) */
    uint8_t *ndirty;  /* (nnodes,) */
    tcc_idx *zone;    /* (n,) union-find parent, -1: in no zone */
    double *cone;     /* (nnodes, CONE_LEN) normal cone of each node over the step (node_cone) */
    double *tn;       /* (nt, 9) each triangle's normal over the step in Bernstein form: P0, P1, P2 */
    uint8_t *tvalid;  /* (nt,) 0: degenerate at an end or half way (no normal to trust) */
    uint8_t *fan;     /* (n,) the vertex's fan this detection: 0 not known yet, 1 free, 2 not */
    tcc_idx *range;   /* (nnodes, 2) the node's rows of prim */
    tcc_idx *row_of;  /* (nt,) each triangle's row of prim */
    tcc_idx *bnext;   /* (n,) scratch of patch_disk: the boundary edge leaving a vertex, -1 */
    uint8_t *vmark;   /* (n,) scratch of patch_disk */
    tcc_idx *queue;   /* (nt,) scratch of patch_disk */
    int all;          /* test every pair (the first detection) */
    int first;        /* no detection yet: the next one's collisions are counted apart */
    int zones;        /* skip pairs inside one zone */
    hit_t *hits;
    tcc_idx nhits, cap;
} guard;

/* ------------------------------------------------------------------ checks */

static int check_input(const tcc_impact_in *in, tcc_error *err)
{
    if (!(in->dt > 0) || !isfinite(in->dt)) return tcc_fail(err, TCC_ERR_VALUE, "dt must be a positive time, got %g", in->dt);
    if (!(in->gap > 0) || !isfinite(in->gap)) return tcc_fail(err, TCC_ERR_VALUE, "gap must be a positive distance, got %g", in->gap);
    if (!(in->rest_fraction > 0) || !isfinite(in->rest_fraction))
        return tcc_fail(err, TCC_ERR_VALUE, "rest_fraction must be positive, got %g", in->rest_fraction);
    if (!(in->min_rest >= 0) || !isfinite(in->min_rest))
        return tcc_fail(err, TCC_ERR_VALUE, "min_rest must be a distance >= 0, got %g", in->min_rest);
    if (in->impulse_passes < 0 || in->zone_passes < 0)
        return tcc_fail(err, TCC_ERR_VALUE, "pass caps must be >= 0 (got %d, %d)", in->impulse_passes, in->zone_passes);
    for (tcc_idx i = 0; i < in->n; i++) {
        if (!(in->mass[i] > 0) || !isfinite(in->mass[i]))
            return tcc_fail(err, TCC_ERR_VALUE, "mass of vertex %lld must be positive, got %g", (long long)i, in->mass[i]);
        for (int a = 0; a < 3; a++)
            if (!isfinite(in->x0[3 * i + a]) || !isfinite(in->x1[3 * i + a]) || !isfinite(in->v[3 * i + a]) ||
                !isfinite(in->rest[3 * i + a]))
                return tcc_fail(err, TCC_ERR_VALUE, "vertex %lld: a position, velocity or rest coordinate is not finite",
                                (long long)i);
        if (in->vowner[i] < -1 || in->vowner[i] >= in->nt)
            return tcc_fail(err, TCC_ERR_INDEX, "vertex_owner[%lld] = %lld is not a triangle in [-1, %lld)", (long long)i,
                            (long long)in->vowner[i], (long long)in->nt);
    }
    for (tcc_idx k = 0; k < 3 * in->nt; k++)
        if (in->tri[k] < 0 || in->tri[k] >= in->n)
            return tcc_fail(err, TCC_ERR_INDEX, "triangles[%lld, %d] = %lld is not a vertex index in [0, %lld)",
                            (long long)(k / 3), (int)(k % 3), (long long)in->tri[k], (long long)in->n);
    /* the tree: links inside the table, and its leaves cover every triangle exactly once (a pair
       missed by a tree that lost a triangle would be a silent hole in the guarantee) */
    if (in->nt > 0 && in->nnodes < 1) return tcc_fail(err, TCC_ERR_VALUE, "a tree over %lld triangles needs nodes", (long long)in->nt);
    tcc_idx covered = 0;
    for (tcc_idx i = 0; i < in->nnodes; i++) {
        tcc_idx p = in->node[2 * i], q = in->node[2 * i + 1];
        if (p < 0) {
            tcc_idx first = -1 - p;
            if (q < 1 || first > in->nt - q)
                return tcc_fail(err, TCC_ERR_INDEX, "tree leaf %lld holds rows [%lld, +%lld) of %lld", (long long)i,
                                (long long)first, (long long)q, (long long)in->nt);
            covered += q;
        } else if (p <= i || p >= in->nnodes || q <= i || q >= in->nnodes) {
            return tcc_fail(err, TCC_ERR_INDEX, "tree node %lld: children %lld, %lld must lie in (%lld, %lld)", (long long)i,
                            (long long)p, (long long)q, (long long)i, (long long)in->nnodes);
        }
    }
    if (covered != in->nt)
        return tcc_fail(err, TCC_ERR_VALUE, "the tree's leaves hold %lld rows, not the %lld triangles", (long long)covered,
                        (long long)in->nt);
    if (in->vt_ptr[0] != 0 || in->vt_ptr[in->n] > in->nvt)
        return tcc_fail(err, TCC_ERR_VALUE, "vt_ptr must run from 0 to at most the %lld entries of vt_tri", (long long)in->nvt);
    for (tcc_idx v = 0; v < in->n; v++)
        if (in->vt_ptr[v + 1] < in->vt_ptr[v]) return tcc_fail(err, TCC_ERR_VALUE, "vt_ptr must not decrease (vertex %lld)", (long long)v);
    for (tcc_idx k = 0; k < in->nvt; k++)
        if (in->vt_tri[k] < 0 || in->vt_tri[k] >= in->nt)
            return tcc_fail(err, TCC_ERR_INDEX, "vt_tri[%lld] = %lld is not a triangle in [0, %lld)", (long long)k,
                            (long long)in->vt_tri[k], (long long)in->nt);
    for (tcc_idx k = 0; k < 3 * in->nt; k++)
        if (in->adj[k] < -2 || in->adj[k] >= in->nt)
            return tcc_fail(err, TCC_ERR_INDEX, "adjacency[%lld, %d] = %lld is not a triangle in [-2, %lld)", (long long)(k / 3),
                            (int)(k % 3), (long long)in->adj[k], (long long)in->nt);
    if (in->loop_off[0] != 0 || in->loop_off[in->nnodes] > in->nloop)
        return tcc_fail(err, TCC_ERR_VALUE, "loop_off must run from 0 to at most the %lld loop entries", (long long)in->nloop);
    for (tcc_idx i = 0; i < in->nnodes; i++) {
        tcc_idx cap = in->loop_off[i + 1] - in->loop_off[i];
        if (cap < 0) return tcc_fail(err, TCC_ERR_VALUE, "loop_off must not decrease (node %lld)", (long long)i);
        if (in->patch[i] < -2 || in->patch[i] > cap)
            return tcc_fail(err, TCC_ERR_VALUE, "patch[%lld] = %lld is not -2, -1 or a loop length up to %lld", (long long)i,
                            (long long)in->patch[i], (long long)cap);
        for (tcc_idx j = 0; j < in->patch[i]; j++)
            if (in->loop[in->loop_off[i] + j] < 0 || in->loop[in->loop_off[i] + j] >= in->n)
                return tcc_fail(err, TCC_ERR_INDEX, "loop of node %lld names vertex %lld of %lld", (long long)i,
                                (long long)in->loop[in->loop_off[i] + j], (long long)in->n);
    }
    return TCC_OK;
}

/* Each node's rows (contiguous: the leaves in tree order) and each triangle's row; an error for a
 * tree whose rows are not a permutation of the triangles or whose children are not adjacent runs. */
static int tree_rows(guard *g)
{
    const tcc_impact_in *in = g->in;
    for (tcc_idx t = 0; t < in->nt; t++) g->row_of[t] = -1;
    for (tcc_idx r = 0; r < in->nt; r++) {
        tcc_idx t = in->prim[r];
        if (t < 0 || t >= in->nt || g->row_of[t] >= 0)
            return tcc_fail(g->err, TCC_ERR_INDEX, "prim[%lld] = %lld: the rows must hold every triangle once", (long long)r,
                            (long long)t);
        g->row_of[t] = r;
    }
    for (tcc_idx i = in->nnodes - 1; i >= 0; i--) {
        tcc_idx p = in->node[2 * i], q = in->node[2 * i + 1];
        if (p < 0) {
            g->range[2 * i] = -1 - p;
            g->range[2 * i + 1] = -1 - p + q;
        } else {
            if (g->range[2 * p + 1] != g->range[2 * q])
                return tcc_fail(g->err, TCC_ERR_VALUE, "tree node %lld: its children's rows are not one run", (long long)i);
            g->range[2 * i] = g->range[2 * p];
            g->range[2 * i + 1] = g->range[2 * q + 1];
        }
    }
    if (in->nt && (g->range[0] != 0 || g->range[1] != in->nt))
        return tcc_fail(g->err, TCC_ERR_VALUE, "the tree's root holds rows [%lld, %lld), not all %lld", (long long)g->range[0],
                        (long long)g->range[1], (long long)in->nt);
    return TCC_OK;
}

/* ------------------------------------------------------------------ refit */

static void grow(double *b, const double *p)
{
    for (int a = 0; a < 3; a++) {
        if (p[a] < b[a]) b[a] = p[a];
        if (p[a] > b[3 + a]) b[3 + a] = p[a];
    }
}

static void empty_box(double *b)
{
    for (int a = 0; a < 3; a++) {
        b[a] = INFINITY;
        b[3 + a] = -INFINITY;
    }
}


static void union_box(const double *a, const double *b, double *o)
{
    for (int k = 0; k < 3; k++) {
        o[k] = a[k] < b[k] ? a[k] : b[k];
        o[3 + k] = a[3 + k] > b[3 + k] ? a[3 + k] : b[3 + k];
    }
}

static int overlap(const double *a, const double *b)
{
    return a[0] <= b[3] && b[0] <= a[3] && a[1] <= b[4] && b[1] <= a[4] && a[2] <= b[5] && b[2] <= a[5];
}

/* ------------------------------------------------------------------ normal cones (Provot 1997)
 *
 * A patch of cloth that is a disk, whose normals all lie within less than a right angle of one
 * direction V and whose boundary, projected along V, is a simple closed curve, has no
 * self-intersection (Volino & Magnenat-Thalmann 1994; Provot 1997): its projection is a local
 * homeomorphism of positive orientation whose boundary winds once, so every point of the plane has
 * at most one preimage. If this holds at every instant of the step, no pair of the patch meets
 * during it, and the patch is not tested against itself: on a sheet or a garment most of the
 * cloth is such patches, and the pairs left are those across creases, folds and patch borders.
 *
 * Over the step a triangle's normal n(s) = (b - a) x (c - a) (corners moving linearly) is the
 * quadratic (1-s)^2 P0 + 2 s (1-s) P1 + s^2 P2 with P0, P2 its normals at the ends and P1 =
 * ((b0 - a0) x (c1 - a1) + (b1 - a1) x (c0 - a0)) / 2 (Tang et al. 2009): inside the cone of
 * P0, P1, P2. Cones are merged bottom-up over the tree (axis, half-angle). The boundary is a star
 * around the mean of its vertices at every instant when each edge's projected area seen from that
 * point (a quadratic in s, Bernstein coefficients B0, B1, B2) stays positive, and it winds once
 * when one edge crosses the ray from that point along the first projected axis: then it is a
 * simple curve (Schvartzman et al. 2010, star contours). Whether a node's triangles form a disk
 * (connected, consistently oriented, manifold, one boundary loop through distinct vertices, Euler
 * characteristic 1) is a property of the topology, found when first needed and kept by the caller
 * (patch, loop) until the topology changes. */

static double clamp1(double c) { return c > 1.0 ? 1.0 : (c < -1.0 ? -1.0 : c); }

static void normalize3(double *a)
{
    double l = sqrt(dot3(a, a));
    for (int k = 0; k < 3; k++) a[k] /= l;
}

/* The cone of one node (g->cone row: unit axis, cosine and sine of the half-angle, the sum of its
 * triangles' unit normals at both ends, valid = no degenerate triangle under it): a leaf from its
 * triangles' P0, P1, P2, an inner node from its children's cones around the normalised sum of its
 * normals (each child's cone widened by the angle between the axes; cosines and sines only, no
 * trigonometric calls: this runs for every node of every detection). */
static void node_cone(guard *g, tcc_idx i)
{
    const tcc_impact_in *in = g->in;
    double *c = g->cone + CONE_LEN * i;
    tcc_idx p = in->node[2 * i], q = in->node[2 * i + 1];
    c[3] = -1.0; /* no cone until shown */
    c[4] = 0.0;
    c[8] = 0.0;
    if (p >= 0) {
        const double *c1 = g->cone + CONE_LEN * p, *c2 = g->cone + CONE_LEN * q;
        for (int k = 0; k < 3; k++) c[5 + k] = c1[5 + k] + c2[5 + k];
        if (!(c1[8] > 0 && c2[8] > 0)) return;
        c[8] = 1.0;
        double l = sqrt(dot3(c + 5, c + 5));
        if (!(l > 0)) return;
        for (int k = 0; k < 3; k++) c[k] = c[5 + k] / l;
        double cmin = 1.0;
        for (int h = 0; h < 2; h++) {
            const double *ch = h ? c2 : c1;
            double cp = clamp1(dot3(c, ch)), sp = sqrt(1.0 - cp * cp);
            if (!(ch[3] >= 0 && cp >= 0)) return; /* a child or the angle past a right angle: no cone */
            cmin = fmin(cmin, cp * ch[3] - sp * ch[4]);
        }
        c[3] = cmin - 1e-12; /* rounding */
        c[4] = sqrt(fmax(0.0, 1.0 - c[3] * c[3]));
        return;
    }
    /* a leaf: the axis is the mean unit normal at both ends, the angle the widest of P0, P1, P2 */
    double axis[3] = {0, 0, 0};
    for (tcc_idx r = -1 - p; r < -1 - p + q; r++) {
        tcc_idx t = in->prim[r];
        if (!g->tvalid[t]) return; /* degenerate at an end or half way: no cone */
        const double *P = g->tn + 9 * t;
        double l0 = sqrt(dot3(P, P)), l2 = sqrt(dot3(P + 6, P + 6));
        for (int k = 0; k < 3; k++) axis[k] += P[k] / l0 + P[6 + k] / l2;
    }
    memcpy(c + 5, axis, sizeof axis);
    c[8] = 1.0;
    double l = sqrt(dot3(axis, axis));
    if (!(l > 0)) return;
    for (int k = 0; k < 3; k++) c[k] = axis[k] / l;
    double cmin = 1.0;
    for (tcc_idx r = -1 - p; r < -1 - p + q; r++) {
        const double *P = g->tn + 9 * in->prim[r];
        for (int j = 0; j < 3; j++) cmin = fmin(cmin, dot3(c, P + 3 * j) / sqrt(dot3(P + 3 * j, P + 3 * j)));
    }
    c[3] = cmin - 1e-12;
    c[4] = sqrt(fmax(0.0, 1.0 - c[3] * c[3]));
}

/* Node i's normals all on one side of its axis at every instant, checked triangle by triangle (the
 * merged cone over-estimates: each merge widens it by the angle between the children's axes). */
static int normals_one_side(const guard *g, tcc_idx i)
{
    const double *c = g->cone + CONE_LEN * i;
    for (tcc_idx r = g->range[2 * i]; r < g->range[2 * i + 1]; r++) {
        const double *P = g->tn + 9 * g->in->prim[r];
        double a = dot3(c, P), b = dot3(c, P + 3), d = dot3(c, P + 6);
        if (!(a > COS_MIN * sqrt(dot3(P, P)) && d > COS_MIN * sqrt(dot3(P + 6, P + 6)) && b > -sqrt(a * d))) return 0;
    }
    return 1;
}

/* Triangle t's normal over the step, P0, P1, P2 (see above), and whether each is a direction
 * rounding does not decide. */
static void tri_normal(guard *g, tcc_idx t)
{
    const tcc_impact_in *in = g->in;
    const tcc_idx *c = in->tri + 3 * t;
    const double *a0 = in->x0 + 3 * c[0], *b0 = in->x0 + 3 * c[1], *d0 = in->x0 + 3 * c[2];
    const double *a1 = g->x1c + 3 * c[0], *b1 = g->x1c + 3 * c[1], *d1 = g->x1c + 3 * c[2];
    double u0[3], v0[3], u1[3], v1[3], m1[3], m2[3], *P = g->tn + 9 * t;
    sub3(b0, a0, u0); sub3(d0, a0, v0); sub3(b1, a1, u1); sub3(d1, a1, v1);
    cross3(u0, v0, P);
    cross3(u1, v1, P + 6);
    cross3(u0, v1, m1);
    cross3(u1, v0, m2);
    for (int k = 0; k < 3; k++) P[3 + k] = 0.5 * (m1[k] + m2[k]);
    double scale2 = fmax(dot3(u0, u0) * dot3(v0, v0), dot3(u1, u1) * dot3(v1, v1));
    uint8_t ok = 1;
    for (int j = 0; j < 3; j++) ok &= dot3(P + 3 * j, P + 3 * j) > SIN_MIN * SIN_MIN * scale2;
    g->tvalid[t] = ok;
}

/* Whether vertex v's fan (its triangles) has no colliding pair of its own this step: v inside the
 * cloth (a closed fan: interior[v]), every fan triangle's normal on one side of V (the fan's mean
 * normal) at every instant (its Bernstein form positive along V), and the link winding once around
 * v in the projection along V. Then the fan is a star around v in that projection at every
 * instant, hence embedded (the argument above with v as the star's centre), and no pair of two
 * triangles sharing v - the crease pairs of the two-ring - can meet. Kept in g->fan for the
 * detection. */
static int fan_free(guard *g, tcc_idx v)
{
    if (g->fan[v]) return g->fan[v] == 1;
    const tcc_impact_in *in = g->in;
    g->fan[v] = 2;
    if (!in->interior[v]) return 0;
    tcc_idx f0 = in->vt_ptr[v], f1 = in->vt_ptr[v + 1];
    double V[3] = {0, 0, 0};
    for (tcc_idx f = f0; f < f1; f++) {
        tcc_idx t = in->vt_tri[f];
        if (!g->tvalid[t]) return 0;
        const double *P = g->tn + 9 * t;
        for (int k = 0; k < 3; k++) V[k] += P[k] + P[6 + k];
    }
    double lv = sqrt(dot3(V, V));
    if (!(lv > 0)) return 0;
    for (int k = 0; k < 3; k++) V[k] /= lv;
    for (tcc_idx f = f0; f < f1; f++) {
        const double *P = g->tn + 9 * in->vt_tri[f];
        double a = dot3(V, P), b = dot3(V, P + 3), c = dot3(V, P + 6);
        double la = sqrt(dot3(P, P)), lc = sqrt(dot3(P + 6, P + 6));
        if (!(a > SIN_MIN * la && c > SIN_MIN * lc && b > -sqrt(a * c))) return 0;
    }
    double u[3], w[3], e[3] = {0, 0, 0};
    int m = fabs(V[0]) < fabs(V[1]) ? (fabs(V[0]) < fabs(V[2]) ? 0 : 2) : (fabs(V[1]) < fabs(V[2]) ? 1 : 2);
    e[m] = 1.0;
    cross3(V, e, u);
    normalize3(u);
    cross3(V, u, w);
    const double *pv = in->x0 + 3 * v;
    int winding = 0;
    for (tcc_idx f = f0; f < f1; f++) {
        const tcc_idx *c = in->tri + 3 * in->vt_tri[f];
        int k = c[0] == v ? 0 : (c[1] == v ? 1 : (c[2] == v ? 2 : -1));
        if (k < 0) return 0; /* not a triangle of v: the caller's table is wrong */
        double da[3], db[3];
        sub3(in->x0 + 3 * c[(k + 1) % 3], pv, da);
        sub3(in->x0 + 3 * c[(k + 2) % 3], pv, db);
        winding += dot3(w, da) < 0 && dot3(w, db) >= 0;
    }
    if (winding != 1) return 0;
    g->fan[v] = 1;
    return 1;
}

/* Whether node i's triangles form a disk; its boundary loop (vertices in the triangles' winding)
 * is then at loop[loop_off[i] ..][0 .. patch[i]). Cached in patch[i] (-1 unknown, -2 no). */
static int patch_disk(guard *g, tcc_idx i, int *disk)
{
    const tcc_impact_in *in = g->in;
    *disk = 0;
    if (in->patch[i] >= 0) {
        *disk = 1;
        return TCC_OK;
    }
    if (in->patch[i] == -2) return TCC_OK;
    if (!g->bnext) {
        size_t nd = (size_t)(in->n > 0 ? in->n : 1);
        g->bnext = malloc(sizeof(tcc_idx) * nd);
        g->vmark = calloc(nd, 1);
        g->queue = malloc(sizeof(tcc_idx) * (size_t)(in->nt > 0 ? in->nt : 1));
        if (!g->bnext || !g->vmark || !g->queue)
            return tcc_fail(g->err, TCC_ERR_NOMEM, "no memory for the patches of %lld vertices", (long long)in->n);
        for (tcc_idx v = 0; v < in->n; v++) g->bnext[v] = -1;
    }
    tcc_idx lo = g->range[2 * i], hi = g->range[2 * i + 1], F = hi - lo;
    tcc_idx cap = in->loop_off[i + 1] - in->loop_off[i], *loop = in->loop + in->loop_off[i];
    int ok = 1;
    tcc_idx B = 0, V = 0, start = -1;
    for (tcc_idx r = lo; r < hi; r++) {
        tcc_idx t = in->prim[r];
        const tcc_idx *c = in->tri + 3 * t;
        for (int k = 0; k < 3; k++) {
            if (!g->vmark[c[k]]) {
                g->vmark[c[k]] = 1;
                V++;
            }
            tcc_idx u = in->adj[3 * t + k];
            if (u == -2) ok = 0; /* an edge of more than two triangles */
            if (u >= 0 && g->row_of[u] >= lo && g->row_of[u] < hi) {
                if (in->flip[3 * t + k]) ok = 0; /* the winding turns over across this edge */
                continue;
            }
            tcc_idx a = c[k], b = c[k == 2 ? 0 : k + 1];
            if (g->bnext[a] >= 0) ok = 0; /* two boundary edges leave a: a pinch */
            else {
                g->bnext[a] = b;
                start = a;
                B++;
            }
        }
    }
    if ((3 * F - B) % 2 || V - (3 * F + B) / 2 + F != 1 || B == 0 || B > cap) ok = 0;
    if (ok) { /* one loop through all B boundary edges */
        tcc_idx a = start;
        for (tcc_idx j = 0; j < B; j++) {
            if (a < 0 || (j > 0 && a == start)) {
                ok = 0;
                break;
            }
            loop[j] = a;
            a = g->bnext[a];
        }
        if (a != start) ok = 0;
    }
    if (ok) { /* connected: a walk over the inner edges reaches every triangle */
        uint8_t *seen = calloc((size_t)(F > 0 ? F : 1), 1);
        if (!seen) return tcc_fail(g->err, TCC_ERR_NOMEM, "no memory for a patch of %lld triangles", (long long)F);
        tcc_idx head = 0, tail = 0;
        g->queue[tail++] = in->prim[lo];
        seen[0] = 1;
        while (head < tail) {
            tcc_idx t = g->queue[head++];
            for (int k = 0; k < 3; k++) {
                tcc_idx u = in->adj[3 * t + k];
                if (u < 0 || g->row_of[u] < lo || g->row_of[u] >= hi || seen[g->row_of[u] - lo]) continue;
                seen[g->row_of[u] - lo] = 1;
                g->queue[tail++] = u;
            }
        }
        free(seen);
        if (tail != F) ok = 0;
    }
    for (tcc_idx r = lo; r < hi; r++) { /* the scratch back to its rest state */
        const tcc_idx *c = in->tri + 3 * in->prim[r];
        for (int k = 0; k < 3; k++) {
            g->vmark[c[k]] = 0;
            g->bnext[c[k]] = -1;
        }
    }
    in->patch[i] = ok ? B : -2;
    *disk = ok;
    return TCC_OK;
}

static double cross2(double ax, double ay, double bx, double by) { return ax * by - ay * bx; }

/* Bernstein coefficients (c0, c1, c2) over the step of the 2-D cross product (op = 0) or dot
 * product (op = 1) of a(s) = a0 + s (a1 - a0) and b(s) likewise; all of one strict sign means the
 * quadratic keeps it on [0, 1]. */
static void bern2(const double a0[2], const double a1[2], const double b0[2], const double b1[2], int op, double c[3])
{
    if (op == 0) {
        c[0] = cross2(a0[0], a0[1], b0[0], b0[1]);
        c[1] = 0.5 * (cross2(a0[0], a0[1], b1[0], b1[1]) + cross2(a1[0], a1[1], b0[0], b0[1]));
        c[2] = cross2(a1[0], a1[1], b1[0], b1[1]);
    } else {
        c[0] = a0[0] * b0[0] + a0[1] * b0[1];
        c[1] = 0.5 * (a0[0] * b1[0] + a0[1] * b1[1] + a1[0] * b0[0] + a1[1] * b0[1]);
        c[2] = a1[0] * b1[0] + a1[1] * b1[1];
    }
}

/* squared distance of 2-D segments pq and rt (0 when they cross) */
static double seg_dist2(const double *p, const double *q, const double *r, const double *t)
{
    double d1 = cross2(q[0] - p[0], q[1] - p[1], r[0] - p[0], r[1] - p[1]);
    double d2 = cross2(q[0] - p[0], q[1] - p[1], t[0] - p[0], t[1] - p[1]);
    double d3 = cross2(t[0] - r[0], t[1] - r[1], p[0] - r[0], p[1] - r[1]);
    double d4 = cross2(t[0] - r[0], t[1] - r[1], q[0] - r[0], q[1] - r[1]);
    if (((d1 > 0 && d2 < 0) || (d1 < 0 && d2 > 0)) && ((d3 > 0 && d4 < 0) || (d3 < 0 && d4 > 0))) return 0.0;
    const double *pts[4][3] = {{p, r, t}, {q, r, t}, {r, p, q}, {t, p, q}};
    double best = INFINITY;
    for (int k = 0; k < 4; k++) { /* each end against the other segment */
        const double *x = pts[k][0], *a = pts[k][1], *b = pts[k][2];
        double e[2] = {b[0] - a[0], b[1] - a[1]}, f[2] = {x[0] - a[0], x[1] - a[1]};
        double ee = e[0] * e[0] + e[1] * e[1], h = ee > 0 ? (f[0] * e[0] + f[1] * e[1]) / ee : 0.0;
        h = h < 0 ? 0 : (h > 1 ? 1 : h);
        double g0 = f[0] - h * e[0], g1 = f[1] - h * e[1], d = g0 * g0 + g1 * g1;
        if (d < best) best = d;
    }
    return best;
}

typedef struct {
    double lo[2], hi[2];
    tcc_idx j;
} seg_box;

static int seg_cmp(const void *a, const void *b)
{
    const seg_box *x = a, *y = b;
    if (x->lo[0] != y->lo[0]) return x->lo[0] < y->lo[0] ? -1 : 1;
    return x->j < y->j ? -1 : (x->j > y->j);
}

/* Whether node i's boundary loop, projected along axis, stays a simple closed curve over the whole
 * step: no two consecutive edges fold onto each other (at their shared vertex the edges' cross
 * product keeps its sign, or their dot product stays negative, at every instant), and no two other
 * edges touch: where their swept boxes meet, their distance at the start exceeds the largest
 * relative motion of their ends (a point of one moves relative to a point of the other by a convex
 * combination of those). Simple at the start and touching nowhere later, it stays simple. Why not
 * a star around one point (Schvartzman et al. 2010): the border of a set of triangles zig-zags, and
 * an edge of a zig-zag that turns back seen from any centre failed it for most patches. */
static int contour_simple(guard *g, tcc_idx i, const double axis[3], int *simple)
{
    const tcc_impact_in *in = g->in;
    const tcc_idx *loop = in->loop + in->loop_off[i], B = in->patch[i];
    *simple = 0;
    double u[3], w[3], e[3] = {0, 0, 0};
    int m = fabs(axis[0]) < fabs(axis[1]) ? (fabs(axis[0]) < fabs(axis[2]) ? 0 : 2) : (fabs(axis[1]) < fabs(axis[2]) ? 1 : 2);
    e[m] = 1.0;
    cross3(axis, e, u);
    normalize3(u);
    cross3(axis, u, w);
    double *P = malloc(sizeof(double) * 4 * (size_t)B);
    seg_box *sb = malloc(sizeof(seg_box) * (size_t)B);
    tcc_idx *act = malloc(sizeof(tcc_idx) * (size_t)B);
    if (!P || !sb || !act) {
        free(P);
        free(sb);
        free(act);
        return tcc_fail(g->err, TCC_ERR_NOMEM, "no memory for a contour of %lld edges", (long long)B);
    }
    double scale = 0.0;
    for (tcc_idx j = 0; j < B; j++) { /* P[4j ..]: the vertex projected at the start, at the end */
        const double *p0 = in->x0 + 3 * loop[j], *p1 = g->x1c + 3 * loop[j];
        P[4 * j] = dot3(u, p0);
        P[4 * j + 1] = dot3(w, p0);
        P[4 * j + 2] = dot3(u, p1);
        P[4 * j + 3] = dot3(w, p1);
        scale = fmax(scale, fmax(fabs(P[4 * j]), fabs(P[4 * j + 1])));
    }
    const double tol = 1e-12 * scale; /* rounding of the projected coordinates */
    int ok = 1;
    for (tcc_idx j = 0; j < B && ok; j++) { /* consecutive edges (a, b), (b, c) never fold */
        const double *a = P + 4 * ((j + B - 1) % B), *b = P + 4 * j, *c = P + 4 * ((j + 1) % B);
        double ba0[2] = {a[0] - b[0], a[1] - b[1]}, ba1[2] = {a[2] - b[2], a[3] - b[3]};
        double bc0[2] = {c[0] - b[0], c[1] - b[1]}, bc1[2] = {c[2] - b[2], c[3] - b[3]};
        double cr[3], dt[3];
        bern2(ba0, ba1, bc0, bc1, 0, cr);
        bern2(ba0, ba1, bc0, bc1, 1, dt);
        double s0 = SIN_MIN * sqrt((ba0[0] * ba0[0] + ba0[1] * ba0[1]) * (bc0[0] * bc0[0] + bc0[1] * bc0[1]));
        double s1 = SIN_MIN * sqrt((ba1[0] * ba1[0] + ba1[1] * ba1[1]) * (bc1[0] * bc1[0] + bc1[1] * bc1[1]));
        double sm = fmax(s0, s1);
        int turns = (cr[0] > s0 && cr[1] > sm && cr[2] > s1) || (cr[0] < -s0 && cr[1] < -sm && cr[2] < -s1);
        int opens = dt[0] < -s0 && dt[1] < -sm && dt[2] < -s1;
        ok = turns || opens;
    }
    for (tcc_idx j = 0; j < B && ok; j++) { /* swept box of edge (j, j+1) */
        const double *a = P + 4 * j, *b = P + 4 * ((j + 1) % B);
        for (int k = 0; k < 2; k++) {
            sb[j].lo[k] = fmin(fmin(a[k], a[2 + k]), fmin(b[k], b[2 + k])) - tol;
            sb[j].hi[k] = fmax(fmax(a[k], a[2 + k]), fmax(b[k], b[2 + k])) + tol;
        }
        sb[j].j = j;
    }
    if (ok) qsort(sb, (size_t)B, sizeof *sb, seg_cmp);
    tcc_idx na = 0;
    for (tcc_idx q = 0; q < B && ok; q++) {
        tcc_idx keep = 0;
        for (tcc_idx r = 0; r < na && ok; r++) {
            const seg_box *o = sb + act[r];
            if (o->hi[0] < sb[q].lo[0]) continue; /* left behind: drop */
            act[keep++] = act[r];
            if (o->hi[1] < sb[q].lo[1] || sb[q].hi[1] < o->lo[1]) continue;
            tcc_idx x = o->j, y = sb[q].j, dj = x > y ? x - y : y - x;
            if (dj == 1 || dj == B - 1) continue; /* consecutive: the fold test above */
            const double *p = P + 4 * x, *pn = P + 4 * ((x + 1) % B), *r0 = P + 4 * y, *rn = P + 4 * ((y + 1) % B);
            double d2 = seg_dist2(p, pn, r0, rn), mv = 0.0;
            const double *ends1[2] = {p, pn}, *ends2[2] = {r0, rn};
            for (int a = 0; a < 2; a++)
                for (int b = 0; b < 2; b++) {
                    double dx = (ends1[a][2] - ends1[a][0]) - (ends2[b][2] - ends2[b][0]);
                    double dy = (ends1[a][3] - ends1[a][1]) - (ends2[b][3] - ends2[b][1]);
                    mv = fmax(mv, sqrt(dx * dx + dy * dy));
                }
            ok = sqrt(d2) > mv + tol;
        }
        na = keep;
        act[na++] = q;
    }
    free(P);
    free(sb);
    free(act);
    *simple = ok;
    return TCC_OK;
}

/* Whether node i (an inner node) provably has no colliding pair of its own this step. */
static int patch_free(guard *g, tcc_idx i, int *free_)
{
    *free_ = 0;
    const double *c = g->cone + CONE_LEN * i;
    /* the merged cone, else the exact test triangle by triangle (the merges widen the cone) */
    if (!(c[8] > 0) || !(c[3] >= COS_MIN || normals_one_side(g, i))) return TCC_OK;
    int disk, rc = patch_disk(g, i, &disk);
    if (rc || !disk) return rc;
    return contour_simple(g, i, c, free_);
}

/* Swept boxes of the triangles and nodes over x0 -> x1c, and which hold a vertex whose motion
 * changed since the last detection. Returns an error for a tree row naming no triangle. */
static int refit(guard *g)
{
    const tcc_impact_in *in = g->in;
    const double h = 0.5 * in->gap;
    for (tcc_idx v = 0; v < in->n; v++) {
        const double *p = in->x0 + 3 * v, *q = g->x1c + 3 * v;
        double *b = g->vbox + 6 * v;
        for (int a = 0; a < 3; a++) {
            b[a] = (p[a] < q[a] ? p[a] : q[a]) - h;
            b[3 + a] = (p[a] < q[a] ? q[a] : p[a]) + h;
        }
    }
    for (tcc_idx t = 0; t < in->nt; t++) {
        double *b = g->tbox + 6 * t;
        const tcc_idx *c = in->tri + 3 * t;
        union_box(g->vbox + 6 * c[0], g->vbox + 6 * c[1], b);
        union_box(b, g->vbox + 6 * c[2], b);
        g->tdirty[t] = g->dirty[c[0]] | g->dirty[c[1]] | g->dirty[c[2]];
        tri_normal(g, t);
    }
    memset(g->fan, 0, (size_t)in->n);
    for (tcc_idx i = in->nnodes - 1; i >= 0; i--) {
        double *b = g->nbox + 6 * i;
        tcc_idx p = in->node[2 * i], q = in->node[2 * i + 1];
        if (p < 0) {
            empty_box(b);
            uint8_t d = 0;
            for (tcc_idx r = -1 - p; r < -1 - p + q; r++) {
                tcc_idx t = in->prim[r];
                if (t < 0 || t >= in->nt)
                    return tcc_fail(g->err, TCC_ERR_INDEX, "tree row %lld names triangle %lld of %lld", (long long)r,
                                    (long long)t, (long long)in->nt);
                const double *tb = g->tbox + 6 * t;
                grow(b, tb);
                grow(b, tb + 3);
                d |= g->tdirty[t];
            }
            g->ndirty[i] = d;
        } else {
            const double *l = g->nbox + 6 * p, *r = g->nbox + 6 * q;
            for (int a = 0; a < 3; a++) {
                b[a] = fmin(l[a], r[a]);
                b[3 + a] = fmax(l[3 + a], r[3 + a]);
            }
            g->ndirty[i] = g->ndirty[p] | g->ndirty[q];
        }
        node_cone(g, i);
    }
    return TCC_OK;
}

/* ------------------------------------------------------------------ zones (union-find) */

static tcc_idx find(tcc_idx *zone, tcc_idx v)
{
    tcc_idx r = v;
    while (zone[r] != r) r = zone[r];
    while (zone[v] != r) {
        tcc_idx next = zone[v];
        zone[v] = r;
        v = next;
    }
    return r;
}

/* 1 when the pair's four vertices lie in one zone (its motion is rigid: no collision inside) */
static int one_zone(guard *g, const tcc_idx id[4])
{
    if (!g->zones || g->zone[id[0]] < 0) return 0;
    tcc_idx r = find(g->zone, id[0]);
    for (int j = 1; j < 4; j++)
        if (g->zone[id[j]] < 0 || find(g->zone, id[j]) != r) return 0;
    return 1;
}

/* ------------------------------------------------------------------ narrow phase */

static int push_hit(guard *g, const hit_t *h)
{
    if (g->nhits == g->cap) {
        tcc_idx cap = g->cap ? 2 * g->cap : 256;
        hit_t *nh = realloc(g->hits, sizeof(hit_t) * (size_t)cap);
        if (!nh) return tcc_fail(g->err, TCC_ERR_NOMEM, "no memory for %lld collisions", (long long)cap);
        g->hits = nh;
        g->cap = cap;
    }
    g->hits[g->nhits++] = *h;
    return TCC_OK;
}

/* positions of the pair's four points at time s of the step */
static void points_at(const guard *g, const tcc_idx id[4], double s, double P[4][3])
{
    for (int j = 0; j < 4; j++)
        for (int a = 0; a < 3; a++) {
            double p0 = g->in->x0[3 * id[j] + a];
            P[j][a] = p0 + s * (g->x1c[3 * id[j] + a] - p0);
        }
}

/* relative displacement of the pair's relative point over the step, along n */
static double approach(const guard *g, const hit_t *h)
{
    double r = 0.0;
    for (int j = 0; j < 4; j++) {
        double d[3];
        sub3(g->x1c + 3 * h->id[j], g->in->x0 + 3 * h->id[j], d);
        r += h->w[j] * dot3(d, h->n);
    }
    return r;
}

/* The normal of a hit at time s: from the closest points apart, or (nearly touching) the elements'
 * geometric normal (vertex-triangle: the face normal; edge-edge: ab x cd) oriented by the side the
 * first element came from. Zero when neither exists (parallel edges touching). */
static void hit_normal(const guard *g, hit_t *h, int ee, double s, int side)
{
    double P[4][3], gv[3] = {0, 0, 0};
    points_at(g, h->id, s, P);
    for (int j = 0; j < 4; j++)
        for (int a = 0; a < 3; a++) gv[a] += h->w[j] * P[j][a];
    double d = sqrt(dot3(gv, gv));
    if (d > NEAR_SHARE * h->gap) {
        for (int a = 0; a < 3; a++) h->n[a] = gv[a] / d;
        return;
    }
    double u[3], v[3], nn[3];
    if (ee) {
        sub3(P[1], P[0], u);
        sub3(P[3], P[2], v);
    } else {
        sub3(P[2], P[1], u);
        sub3(P[3], P[1], v);
    }
    cross3(u, v, nn);
    double l = sqrt(dot3(nn, nn));
    if (!(l > 1e-12 * sqrt(dot3(u, u) * dot3(v, v))) || side == 0) {
        h->n[0] = h->n[1] = h->n[2] = 0.0;
        return;
    }
    for (int a = 0; a < 3; a++) h->n[a] = side * nn[a] / l;
}

/* One swept test of ccd.c with gap: 1 and *toi, the weights / parameters and the side on a hit. */
static int sweep(guard *g, int ee, const tcc_idx id[4], tcc_idx t, double gap, double *toi, double wst[3], int *side,
                 int *hit)
{
    int8_t sd = 0;
    tcc_idx nh = 0;
    int rc;
    if (ee)
        rc = tcc_ccd_edge_edge(g->in->x0, g->x1c, g->in->n, id, id + 2, 1, gap, NULL, toi, wst, &sd, &nh, g->err);
    else
        rc = tcc_ccd_vertex_triangle(g->in->x0, g->x1c, g->in->n, g->in->tri, g->in->nt, id, &t, 1, gap, NULL, toi, wst,
                                     &sd, &nh, g->err);
    *side = sd;
    *hit = nh > 0;
    return rc;
}

static void set_weights(hit_t *h, int ee, const double wst[3])
{
    if (ee) {
        h->w[0] = 1.0 - wst[0];
        h->w[1] = wst[0];
        h->w[2] = -(1.0 - wst[1]);
        h->w[3] = -wst[1];
    } else {
        h->w[0] = 1.0;
        for (int j = 0; j < 3; j++) h->w[1 + j] = -wst[j];
    }
}

/* The pair id (vertex-triangle: vertex, the triangle's corners, triangle t; edge-edge: a, b, c, d)
 * tested over the step; a collision is appended to the list. */
static int test_pair(guard *g, int ee, const tcc_idx id[4], tcc_idx t)
{
    if (!g->all) {
        int d = 0;
        for (int j = 0; j < 4; j++) d |= g->dirty[id[j]];
        if (!d) return TCC_OK; /* its motion is the one the last detection found clean */
    }
    if (one_zone(g, id)) return TCC_OK;
    const tcc_impact_in *in = g->in;
    double toi, wst[3];
    int side, hit, rc;
    g->out->candidates++;
    if ((rc = sweep(g, ee, id, t, in->gap, &toi, wst, &side, &hit)) || !hit) return rc;
    /* its gap from the rest shape: a pair that coincides at rest is one piece of cloth */
    double sd, dist, rw[3], rn[3];
    if (ee) rc = tcc_edge_edge_state(in->rest, in->n, id, id + 2, 1, &sd, &dist, rw, rn, g->err);
    else rc = tcc_vertex_triangle_state(in->rest, in->n, in->tri, in->nt, id, &t, 1, &sd, &dist, rw, rn, g->err);
    if (rc) return rc;
    if (!(dist >= in->min_rest)) {
        g->out->excluded++;
        return TCC_OK;
    }
    hit_t h = {{id[0], id[1], id[2], id[3]}, {0, 0, 0, 0}, {0, 0, 0}, in->gap};
    if (in->rest_fraction * dist < in->gap) {
        h.gap = in->rest_fraction * dist;
        if ((rc = sweep(g, ee, id, t, h.gap, &toi, wst, &side, &hit)) || !hit) return rc;
    }
    set_weights(&h, ee, wst);
    hit_normal(g, &h, ee, toi, side);
    if (approach(g, &h) < 0.0) return push_hit(g, &h);
    /* within its gap but parting: a collision only if it crosses later in the step */
    if ((rc = sweep(g, ee, id, t, 0.0, &toi, wst, &side, &hit)) || !hit) return rc;
    set_weights(&h, ee, wst);
    hit_normal(g, &h, ee, toi, side);
    g->out->crossing_only++;
    return push_hit(g, &h);
}

static int has(const tcc_idx *t, tcc_idx v) { return t[0] == v || t[1] == v || t[2] == v; }

/* Every element pair of triangles ta, tb whose elements they own (each pair once over the tree). */
static int tri_pair(guard *g, tcc_idx ta, tcc_idx tb)
{
    const tcc_impact_in *in = g->in;
    if (!overlap(g->tbox + 6 * ta, g->tbox + 6 * tb)) return TCC_OK;
    if (!g->all && !g->tdirty[ta] && !g->tdirty[tb]) return TCC_OK;
    uint8_t oa = g->own[ta], ob = g->own[tb];
    /* nothing to test: no owned vertex on either side, and no owned edge on one of them (the
       triangles of a sheet own half a vertex and one and a half edges each) */
    if (!((oa | ob) & 7) && (!(oa >> 3) || !(ob >> 3))) return TCC_OK;
    const tcc_idx *A = in->tri + 3 * ta, *B = in->tri + 3 * tb;
    /* two triangles of one free fan: every pair of their elements lies in it */
    for (int k = 0; k < 3; k++)
        if (has(B, A[k]) && fan_free(g, A[k])) return TCC_OK;
    int rc;
    for (int side = 0; side < 2; side++) {
        const tcc_idx *P = side ? B : A, *Q = side ? A : B;
        uint8_t own = side ? ob : oa;
        tcc_idx tq = side ? ta : tb;
        for (int k = 0; k < 3; k++) {
            tcc_idx v = P[k];
            if (!(own >> k & 1) || has(Q, v) || !overlap(g->vbox + 6 * v, g->tbox + 6 * tq)) continue;
            tcc_idx id[4] = {v, Q[0], Q[1], Q[2]};
            if ((rc = test_pair(g, 0, id, tq))) return rc;
        }
    }
    if (!(oa >> 3) || !(ob >> 3)) return TCC_OK;
    double ba[6], bb[6];
    for (int k = 0; k < 3; k++) {
        if (!(oa >> (3 + k) & 1)) continue;
        tcc_idx a0 = A[k], a1 = A[k == 2 ? 0 : k + 1];
        union_box(g->vbox + 6 * a0, g->vbox + 6 * a1, ba);
        if (!overlap(ba, g->tbox + 6 * tb)) continue;
        for (int l = 0; l < 3; l++) {
            if (!(ob >> (3 + l) & 1)) continue;
            tcc_idx c = B[l], d = B[l == 2 ? 0 : l + 1];
            if (c == a0 || c == a1 || d == a0 || d == a1) continue;
            union_box(g->vbox + 6 * c, g->vbox + 6 * d, bb);
            if (!overlap(ba, bb)) continue;
            tcc_idx id[4] = {a0, a1, c, d};
            if ((rc = test_pair(g, 1, id, -1))) return rc;
        }
    }
    return TCC_OK;
}

static int is_leaf(const tcc_impact_in *in, tcc_idx i) { return in->node[2 * i] < 0; }


static int cross_nodes(guard *g, tcc_idx i, tcc_idx j, int depth)
{
    if (!g->all && !g->ndirty[i] && !g->ndirty[j]) return TCC_OK;
    if (!overlap(g->nbox + 6 * i, g->nbox + 6 * j)) return TCC_OK;
    if (depth > IMPACT_DEPTH) return tcc_fail(g->err, TCC_ERR_VALUE, "the tree is deeper than %d levels", IMPACT_DEPTH);
    const tcc_impact_in *in = g->in;
    int li = is_leaf(in, i), lj = is_leaf(in, j), rc;
    if (li && lj) {
        tcc_idx fi = -1 - in->node[2 * i], fj = -1 - in->node[2 * j];
        for (tcc_idx a = fi; a < fi + in->node[2 * i + 1]; a++) {
            if (!overlap(g->tbox + 6 * in->prim[a], g->nbox + 6 * j)) continue;
            for (tcc_idx b = fj; b < fj + in->node[2 * j + 1]; b++)
                if ((rc = tri_pair(g, in->prim[a], in->prim[b]))) return rc;
        }
        return TCC_OK;
    }
    /* descend the node with more triangles (a leaf never) */
    if (!li && (lj || g->range[2 * i + 1] - g->range[2 * i] >= g->range[2 * j + 1] - g->range[2 * j])) {
        if ((rc = cross_nodes(g, in->node[2 * i], j, depth + 1))) return rc;
        return cross_nodes(g, in->node[2 * i + 1], j, depth + 1);
    }
    if ((rc = cross_nodes(g, i, in->node[2 * j], depth + 1))) return rc;
    return cross_nodes(g, i, in->node[2 * j + 1], depth + 1);
}

static int self_node(guard *g, tcc_idx i, int depth)
{
    if (!g->all && !g->ndirty[i]) return TCC_OK;
    if (depth > IMPACT_DEPTH) return tcc_fail(g->err, TCC_ERR_VALUE, "the tree is deeper than %d levels", IMPACT_DEPTH);
    const tcc_impact_in *in = g->in;
    int rc, free_;
    if (!is_leaf(in, i)) {
        if ((rc = patch_free(g, i, &free_))) return rc;
        if (free_) {
            g->out->patches_free++;
            return TCC_OK;
        }
    }
    if (is_leaf(in, i)) {
        tcc_idx f = -1 - in->node[2 * i], c = in->node[2 * i + 1];
        for (tcc_idx a = f; a < f + c; a++)
            for (tcc_idx b = a + 1; b < f + c; b++)
                if ((rc = tri_pair(g, in->prim[a], in->prim[b]))) return rc;
        return TCC_OK;
    }
    tcc_idx l = in->node[2 * i], r = in->node[2 * i + 1];
    if ((rc = self_node(g, l, depth + 1)) || (rc = self_node(g, r, depth + 1))) return rc;
    return cross_nodes(g, l, r, depth + 1);
}

/* All collisions of the current motion into g->hits; the motion is then clean as of now. */
static int detect(guard *g)
{
    g->nhits = 0;
    int rc = refit(g);
    if (rc) return rc;
    if (g->in->nt > 0 && (rc = self_node(g, 0, 0))) return rc;
    memset(g->dirty, 0, (size_t)g->in->n);
    g->all = 0;
    if (g->first) g->out->collisions = g->nhits;
    g->first = 0;
    return TCC_OK;
}

/* ------------------------------------------------------------------ resolution */

static void set_velocity(guard *g, tcc_idx v, const double nv[3])
{
    double *p = g->vel + 3 * v;
    if (p[0] == nv[0] && p[1] == nv[1] && p[2] == nv[2]) return;
    for (int a = 0; a < 3; a++) {
        p[a] = nv[a];
        g->x1c[3 * v + a] = g->in->x0[3 * v + a] + g->in->dt * nv[a];
    }
    g->dirty[v] = g->changed[v] = 1;
}

/* Gauss-Seidel over the collisions found: each pair still approaching along its normal gets the
 * inelastic impulse that makes its relative point part by SEPARATION x gap over the step. Every
 * pair found is tested again at the next detection (its vertices marked changed), whether its
 * impulse ran or not: one without a normal, or a crossing whose normal at the crossing does not see
 * it approach, is left to the zones, never taken as resolved. */
static void impulses(guard *g)
{
    for (tcc_idx k = 0; k < g->nhits; k++) {
        hit_t *h = g->hits + k;
        for (int j = 0; j < 4; j++) g->dirty[h->id[j]] = 1;
        if (h->n[0] == 0 && h->n[1] == 0 && h->n[2] == 0) continue;
        double target = SEPARATION * h->gap, a = approach(g, h);
        if (a >= target) continue;
        double den = 0.0;
        for (int j = 0; j < 4; j++) den += h->w[j] * h->w[j] * g->im[h->id[j]];
        if (!(den > 0)) continue;
        /* displacement change along n of the relative point: sum_j w_j^2 im_j j_imp = target - a */
        double lam = (target - a) / den;
        for (int j = 0; j < 4; j++) {
            tcc_idx v = h->id[j];
            double s = lam * h->w[j] * g->im[v] / g->in->dt;
            if (s == 0) continue;
            double nv[3];
            for (int c = 0; c < 3; c++) nv[c] = g->vel[3 * v + c] + s * h->n[c];
            set_velocity(g, v, nv);
        }
        g->out->impulses++;
    }
}

/* Eigen-decomposition of a symmetric 3x3 matrix (cyclic Jacobi): a becomes diagonal, the columns of
 * V its eigenvectors. */
static void jacobi3(double a[3][3], double V[3][3])
{
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) V[i][j] = i == j;
    for (int sweep = 0; sweep < 50; sweep++) {
        double off = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2];
        double diag = a[0][0] * a[0][0] + a[1][1] * a[1][1] + a[2][2] * a[2][2];
        if (!(off > 1e-32 * diag)) break;
        for (int p = 0; p < 2; p++)
            for (int q = p + 1; q < 3; q++) {
                if (a[p][q] == 0) continue;
                double theta = (a[q][q] - a[p][p]) / (2 * a[p][q]);
                double t = fabs(theta) > 1e150 ? 0.5 / theta
                                                 : (theta >= 0 ? 1.0 : -1.0) / (fabs(theta) + sqrt(theta * theta + 1));
                double c = 1 / sqrt(t * t + 1), s = t * c;
                for (int k = 0; k < 3; k++) {
                    double kp = a[k][p], kq = a[k][q];
                    a[k][p] = c * kp - s * kq;
                    a[k][q] = s * kp + c * kq;
                }
                for (int k = 0; k < 3; k++) {
                    double pk = a[p][k], qk = a[q][k];
                    a[p][k] = c * pk - s * qk;
                    a[q][k] = s * pk + c * qk;
                }
                for (int k = 0; k < 3; k++) {
                    double kp = V[k][p], kq = V[k][q];
                    V[k][p] = c * kp - s * kq;
                    V[k][q] = s * kp + c * kq;
                }
            }
    }
}

/* w = I^+ L: the inverse on the eigen-directions the inertia has, none on those it lacks (a
 * collinear zone: no angular momentum along its line, so L is kept exactly). */
static void solve_inertia(const double I[9], const double L[3], double w[3])
{
    double a[3][3], V[3][3];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) a[i][j] = I[3 * i + j];
    jacobi3(a, V);
    double emax = fmax(fabs(a[0][0]), fmax(fabs(a[1][1]), fabs(a[2][2])));
    w[0] = w[1] = w[2] = 0.0;
    for (int k = 0; k < 3; k++) {
        double e = a[k][k];
        if (!(e > 1e-12 * emax)) continue;
        double c = (V[0][k] * L[0] + V[1][k] * L[1] + V[2][k] * L[2]) / e;
        for (int i = 0; i < 3; i++) w[i] += c * V[i][k];
    }
}

typedef struct {
    double m, c[3], p[3], L[3], I[9];
    int held;
} zone_sum;

/* Rigid motion for every zone holding a vertex marked in touched (the rest keep theirs). */
static int rigidify(guard *g, const uint8_t *touched)
{
    const tcc_impact_in *in = g->in;
    tcc_idx n = in->n;
    tcc_idx *slot = malloc(sizeof(tcc_idx) * (size_t)(n > 0 ? n : 1));
    zone_sum *z = NULL;
    if (!slot) return tcc_fail(g->err, TCC_ERR_NOMEM, "no memory for the zones of %lld vertices", (long long)n);
    tcc_idx nz = 0;
    for (tcc_idx v = 0; v < n; v++) slot[v] = -1;
    for (tcc_idx v = 0; v < n; v++)
        if (g->zone[v] >= 0 && touched[find(g->zone, v)] && slot[find(g->zone, v)] < 0) slot[find(g->zone, v)] = nz++;
    z = calloc((size_t)(nz > 0 ? nz : 1), sizeof(zone_sum));
    if (!z) {
        free(slot);
        return tcc_fail(g->err, TCC_ERR_NOMEM, "no memory for %lld zones", (long long)nz);
    }
    for (tcc_idx v = 0; v < n; v++) {
        if (g->zone[v] < 0) continue;
        tcc_idx s = slot[find(g->zone, v)];
        if (s < 0) continue;
        zone_sum *Z = z + s;
        double m = in->mass[v];
        Z->m += m;
        for (int a = 0; a < 3; a++) {
            Z->c[a] += m * in->x0[3 * v + a];
            Z->p[a] += m * g->vel[3 * v + a];
        }
        if (g->im[v] == 0) Z->held = 1;
    }
    for (tcc_idx s = 0; s < nz; s++)
        for (int a = 0; a < 3; a++) {
            z[s].c[a] /= z[s].m;
            z[s].p[a] /= z[s].m; /* now the centre's velocity */
        }
    for (tcc_idx v = 0; v < n; v++) {
        if (g->zone[v] < 0) continue;
        tcc_idx s = slot[find(g->zone, v)];
        if (s < 0) continue;
        zone_sum *Z = z + s;
        double m = in->mass[v], r[3], u[3], rxu[3];
        sub3(in->x0 + 3 * v, Z->c, r);
        sub3(g->vel + 3 * v, Z->p, u);
        cross3(r, u, rxu);
        double r2 = dot3(r, r);
        for (int a = 0; a < 3; a++) {
            Z->L[a] += m * rxu[a];
            for (int b = 0; b < 3; b++) Z->I[3 * a + b] += m * ((a == b ? r2 : 0.0) - r[a] * r[b]);
        }
    }
    double (*omega)[3] = malloc(sizeof(double[3]) * (size_t)(nz > 0 ? nz : 1));
    if (!omega) {
        free(slot);
        free(z);
        return tcc_fail(g->err, TCC_ERR_NOMEM, "no memory for %lld zones", (long long)nz);
    }
    for (tcc_idx s = 0; s < nz; s++) solve_inertia(z[s].I, z[s].L, omega[s]);
    for (tcc_idx v = 0; v < n; v++) {
        if (g->zone[v] < 0) continue;
        tcc_idx s = slot[find(g->zone, v)];
        if (s < 0) continue;
        double nv[3] = {0, 0, 0};
        if (!z[s].held) {
            double r[3], wxr[3];
            sub3(in->x0 + 3 * v, z[s].c, r);
            cross3(omega[s], r, wxr);
            for (int a = 0; a < 3; a++) nv[a] = z[s].p[a] + wxr[a];
        }
        set_velocity(g, v, nv);
    }
    free(omega);
    free(z);
    free(slot);
    return TCC_OK;
}

static void join(guard *g, tcc_idx a, tcc_idx b, uint8_t *touched)
{
    if (g->zone[a] < 0) g->zone[a] = a;
    if (g->zone[b] < 0) g->zone[b] = b;
    tcc_idx ra = find(g->zone, a), rb = find(g->zone, b);
    if (ra != rb) {
        if (rb < ra) {
            tcc_idx t = ra;
            ra = rb;
            rb = t;
        }
        g->zone[rb] = ra;
    }
    touched[ra] = 1;
}

static int zones_until_clean(guard *g)
{
    const tcc_impact_in *in = g->in;
    tcc_idx n = in->n;
    uint8_t *touched = calloc((size_t)(n > 0 ? n : 1), 1);
    if (!touched) return tcc_fail(g->err, TCC_ERR_NOMEM, "no memory for the zones of %lld vertices", (long long)n);
    g->zones = 1;
    int rc = TCC_OK;
    for (;;) {
        if ((rc = detect(g))) break;
        if (g->nhits == 0) break;
        if (g->out->zone_passes >= in->zone_passes) {
            /* the cap: the whole cloth moves as one rigid zone, which no pair of it can cross */
            g->out->unresolved = g->nhits;
            g->out->rigid_cloth = 1;
            for (tcc_idx v = 1; v < n; v++) join(g, 0, v, touched);
            rc = rigidify(g, touched);
            break;
        }
        g->out->zone_passes++;
        memset(touched, 0, (size_t)n);
        for (tcc_idx k = 0; k < g->nhits; k++)
            for (int j = 1; j < 4; j++) join(g, g->hits[k].id[0], g->hits[k].id[j], touched);
        /* a root may have been merged away after it was marked: mark the surviving roots */
        for (tcc_idx v = 0; v < n; v++)
            if (touched[v] && g->zone[v] >= 0) touched[find(g->zone, v)] = 1;
        if ((rc = rigidify(g, touched))) break;
    }
    free(touched);
    return rc;
}

int tcc_impact_resolve(const tcc_impact_in *in, tcc_impact_counts *out, tcc_error *err)
{
    memset(out, 0, sizeof *out);
    int rc = check_input(in, err);
    if (rc) return rc;
    tcc_idx n = in->n, nt = in->nt, nn = in->nnodes > 0 ? in->nnodes : 1;
    guard g;
    memset(&g, 0, sizeof g);
    g.in = in;
    g.out = out;
    g.err = err;
    size_t nd = (size_t)(n > 0 ? n : 1), ntd = (size_t)(nt > 0 ? nt : 1);
    g.x1c = malloc(sizeof(double) * 3 * nd);
    g.vel = malloc(sizeof(double) * 3 * nd);
    g.im = malloc(sizeof(double) * nd);
    g.vbox = malloc(sizeof(double) * 6 * nd);
    g.tbox = malloc(sizeof(double) * 6 * ntd);
    g.own = malloc(ntd);
    g.nbox = malloc(sizeof(double) * 6 * (size_t)nn);
    g.dirty = calloc(nd, 1);
    g.changed = calloc(nd, 1);
    g.tdirty = calloc(ntd, 1);
    g.ndirty = calloc((size_t)nn, 1);
    g.zone = malloc(sizeof(tcc_idx) * nd);
    g.cone = malloc(sizeof(double) * CONE_LEN * (size_t)nn);
    g.tn = malloc(sizeof(double) * 9 * ntd);
    g.tvalid = malloc(ntd);
    g.fan = calloc(nd, 1);
    g.range = malloc(sizeof(tcc_idx) * 2 * (size_t)nn);
    g.row_of = malloc(sizeof(tcc_idx) * ntd);
    if (!g.tn || !g.tvalid || !g.fan || !g.cone || !g.range || !g.row_of || !g.x1c || !g.vel || !g.im || !g.vbox || !g.tbox || !g.own || !g.nbox || !g.dirty || !g.changed || !g.tdirty || !g.ndirty || !g.zone) {
        rc = tcc_fail(err, TCC_ERR_NOMEM, "no memory for the impact guard of %lld vertices", (long long)n);
        goto done;
    }
    for (tcc_idx v = 0; v < n; v++) {
        const double *p0 = in->x0 + 3 * v, *p1 = in->x1 + 3 * v;
        int still = p0[0] == p1[0] && p0[1] == p1[1] && p0[2] == p1[2];
        g.im[v] = still ? 0.0 : 1.0 / in->mass[v];
        out->immovable += still;
        for (int a = 0; a < 3; a++) {
            g.x1c[3 * v + a] = p1[a];
            g.vel[3 * v + a] = (p1[a] - p0[a]) / in->dt;
        }
        g.zone[v] = -1;
    }
    if ((rc = tree_rows(&g))) goto done;
    for (tcc_idx t = 0; t < nt; t++) {
        uint8_t o = 0;
        for (int k = 0; k < 3; k++) {
            o |= (uint8_t)((in->vowner[in->tri[3 * t + k]] == t) << k);
            o |= (uint8_t)((in->eowner[3 * t + k] != 0) << (3 + k));
        }
        g.own[t] = o;
    }
    g.all = g.first = 1;
    for (int pass = 0; pass < in->impulse_passes; pass++) {
        if ((rc = detect(&g))) goto done;
        if (g.nhits == 0) goto write;
        out->impulse_passes++;
        impulses(&g);
    }
    if ((rc = zones_until_clean(&g))) goto done;
    for (tcc_idx v = 0; v < n; v++)
        if (g.zone[v] >= 0) {
            out->zone_vertices++;
            out->zones += find(g.zone, v) == v;
        }
write:
    /* only vertices whose motion changed are written: the others keep their bits */
    for (tcc_idx v = 0; v < n; v++) {
        if (!g.changed[v]) continue;
        out->moved++;
        for (int a = 0; a < 3; a++) {
            double before = (in->x1[3 * v + a] - in->x0[3 * v + a]) / in->dt;
            in->v[3 * v + a] += g.vel[3 * v + a] - before;
            in->x1[3 * v + a] = g.x1c[3 * v + a];
        }
    }
done:
    free(g.x1c);
    free(g.vel);
    free(g.im);
    free(g.vbox);
    free(g.tbox);
    free(g.own);
    free(g.nbox);
    free(g.dirty);
    free(g.changed);
    free(g.tdirty);
    free(g.ndirty);
    free(g.zone);
    free(g.cone);
    free(g.tn);
    free(g.tvalid);
    free(g.fan);
    free(g.range);
    free(g.row_of);
    free(g.bnext);
    free(g.vmark);
    free(g.queue);
    free(g.hits);
    return rc;
}
