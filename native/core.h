/* core.h - internal layout of a cloth and the internal interface of each part of the core (not
 * installed; the public API is tearcloth.h).
 *
 * One header for all parts on purpose: every part works on the one struct tc_cloth below, so each
 * .c file needs this layout anyway, and a header per part would hold three to eight declarations.
 * The declarations are grouped in one section per source file instead, named after it, in the
 * order of the dependencies (a file calls only the files in the sections above its own, never one
 * below: no circles):
 *
 *   util.c        clock, error text
 *   buf.c         reference-counted blocks, growable arrays
 *   settings.c    defaults and checks of the material, solver and tearing settings
 *   ortho.c       woven sheets: warp/weft axes per triangle, orthotropic moduli, plasticity
 *   mesh.c        pairs (edges, bending flaps), adjacency, rest elements, masses, stencils
 *   events.c      topology events of one step
 *   fem.c         element pass (rotations, stresses, forces), assembly, matrix-vector product, energies
 *   constraints.c pins, handles, contacts: the velocity filter of Baraff & Witkin and its basis
 *   amg.c         smoothed-aggregation multigrid: the preconditioner of large cloths
 *   solver.c      preconditioned CG on the constraint manifold (block Jacobi or amg.c)
 *   remesh.c      the local remesh of a cut: fans, segments, edge splits, separation
 *   fragment.c    removal of tiny pieces a tear set free (triangles, vertices, every index into them)
 *   tear.c        tearing: where a tear starts, which way it runs, its tips
 *   step.c        one implicit Euler step: forces, sub-steps, contacts released, rollback, tearing
 *   cloth.c       life cycle, setters and getters, zero-copy arrays
 *   snapshot.c    the whole state of a cloth as a validated blob, and a cloth made from one
 *
 * Storage is structure-of-arrays in growable, reference-counted blocks (see buf.c). The topology
 * is kept per *pair* of vertices (mesh edges plus the "flap" pairs of bending stencils): a tear adds
 * or removes a handful of pairs without touching anything else. The system matrix lives by rows
 * (see rptr below), the pattern rebuilt from the pairs by one counting sort when they changed, so
 * the product streams its rows instead of scattering into two rows per pair.
 */
#ifndef TEARCLOTH_CORE_H
#define TEARCLOTH_CORE_H

#include "tearcloth.h"
#include "constants.h"
#include "vecmath.h"

#include <math.h>  /* sqrt in the inline helpers below */
#include <stdatomic.h>
#include <stdbool.h>

/* ---------------- buf.c: blocks and growable arrays ---------------- */

struct tc_buf {
    atomic_int refs;
    size_t bytes;
    _Alignas(16) unsigned char data[];
};

tc_buf *tc_buf_new(size_t bytes);

/* A growable array of fixed-size items in a tc_buf. */
typedef struct tc_vec {
    tc_buf *buf;
    size_t len, cap, item;
} tc_vec;

int tc_vec_init(tc_vec *v, size_t item, size_t cap);
void tc_vec_free(tc_vec *v);
int tc_vec_reserve(tc_vec *v, size_t cap);       /* keeps contents; never shrinks */
int tc_vec_resize(tc_vec *v, size_t len);        /* new items are zeroed */
static inline void *tc_vec_ptr(const tc_vec *v) { return v->buf ? (void *)v->buf->data : 0; }
int tc_vec_push_i32(tc_vec *v, int32_t x);        /* append one item (an int32 / a double array) */
/* the C allocator's four, a block of 256 KB or more mapped on its own (see buf.c); what one of
 * them made only they resize or free */
void *tc_mem_malloc(size_t n);
void *tc_mem_calloc(size_t k, size_t item);
void *tc_mem_realloc(void *p, size_t n);
void tc_mem_free(void *p);
int tc_vec_push_f64(tc_vec *v, double x);

/* ---------------- the cloth ---------------- */

enum { VC_FREE = 0, VC_PINNED = 1, VC_HANDLE = 2, VC_CONTACT = 3 };
/* cactive of a contact: 0 released this sub-step, 1 active (its vertex may be held by static
 * friction), TC_CONTACT_SLIDING active with its vertex sliding (tc_contacts_slip) */
enum { TC_CONTACT_SLIDING = 2 };
/* vcstate of a vertex: how its contacts ended its last kept sub-step, the state its next sub-step
 * starts from (constraints.c). NONE: not known (a new cloth or vertex, a pin or handle, or after
 * tc_cloth_forget_contacts): its contacts start held, as on first touch; FREE: it touched nothing;
 * HELD: held by static friction, or its slip stopped; SLIDING: sliding, with the kinetic friction
 * force vkinetic; LIFTED: every contact released (pulled away from the surface). */
enum { TC_CARRY_NONE = 0, TC_CARRY_FREE = 1, TC_CARRY_HELD = 2, TC_CARRY_SLIDING = 3, TC_CARRY_LIFTED = 4 };

typedef struct tc_handle {
    bool active;
    int32_t count;
    int32_t *verts;          /* members; kept current through tears */
    double *grasp;           /* positions at grasp time, 3 per member */
    double prev[12], target[12]; /* affine maps: start and end of the current step */
    double force[3];
} tc_handle;

typedef struct tc_amg tc_amg;
typedef struct tc_sgs tc_sgs;
typedef struct tc_stiff tc_stiff;
typedef struct tc_discs tc_discs;

typedef struct tc_stencil {
    int32_t v[4];            /* shared edge v0-v1, opposite vertices v2, v3 */
    double q[4];             /* cotangent weights K; Q = coef K K^T */
    double coef;             /* 1 / (A0 + A1), see mesh.c */
    int32_t pair;            /* the edge pair that owns this stencil */
} tc_stencil;

struct tc_cloth {
    tc_material mat;
    tc_solver_settings solver;
    tc_tear_settings tear;
    char err[512];

    int32_t nv, nt;
    int ng;

    /* per vertex */
    tc_vec x, v, rest, mass, force, groups, strength;
    tc_vec vtri;             /* int32: one incident triangle, -1 if isolated */
    tc_vec vflag;            /* int8: VC_* constraint kind for the step being solved */
    tc_vec vhandle;          /* int32: handle id or -1 */
    tc_vec vpin;             /* int8: pinned by the user */
    tc_vec vbend;            /* bending diagonal scalar (stiffness included) */

    /* per triangle */
    tc_vec tri;              /* int32 x3 */
    tc_vec tpair;            /* int32 x3: pair id of edge k */
    tc_vec grad;             /* double x4: shape gradients g1, g2 (2-D, rest frame) */
    tc_vec area;             /* double: rest area */
    tc_vec rot;              /* double x6: current rotation R (3x2, column-major: col0 xyz, col1 xyz) */
    tc_vec sig;              /* double x3: local 2-D stress (xx, yy, xy) */
    tc_vec stress;           /* empty: the world stress is derived from rot and sig (tc_world_stress); kept
                                in the table so that the snapshots of the builds that stored it resume */
    tc_vec principal;        /* empty, as stress: sigma's eigenvalues (tc_tri_principal) */
    tc_vec pdir;             /* empty, as stress (tc_principal_dir) */
    tc_vec uv;               /* double x6 corner uv */
    tc_vec tgrain;           /* double: the triangle's own grain angle (rad), NaN: the material's; empty
                                until one is set (all NaN, ortho.c) */
    tc_vec twarp;            /* double x3: unit warp direction in the rest space (ortho.c); empty, with
                                taxis, while no material has read them (tc_axes_stored) */
    tc_vec taxis;            /* double x2: the warp as (cos, sin) in the triangle's 2-D rest frame */
    tc_vec tplast;           /* double x4: plastic strain in warp/weft axes (ww, ff, wf), kappa */

    /* pairs (off-diagonal blocks) */
    tc_vec pi, pj;           /* int32 endpoints, pi < pj; -1 when free */
    tc_vec puse;             /* int32 number of triangle edges + stencils using the pair */
    tc_vec ptris;            /* int32 x2 triangles on this edge (-1 none) */
    tc_vec pstencil;         /* int32 >= 0: this edge has a bending stencil (mesh.c), -1: none */
    tc_vec pbend;            /* double: bending scalar for the pair */
    tc_vec pfree;            /* int32 stack of free pair ids */
    /* hash (min,max) -> pair id, open addressing, power-of-two capacity: a slot holds the pair id
     * (-1 empty, -2 tombstone), its key is that pair's pi, pj (mesh.c); NULL (hcap 0) between a
     * new cloth's build and its first tear (tc_pair_hash_ensure) */
    int32_t *hvals;
    size_t hcap, hcount, htomb;

    tc_vec stencils;         /* empty: a stencil is made from its edge's triangles when added or removed
                                (mesh.c); kept in the table, with sfree, so that the snapshots of the
                                builds that stored them resume */
    tc_vec sfree;            /* empty (was: free stencil ids) */

    /* handles */
    tc_handle *handles;
    int32_t nh, hcap_handles;

    /* contacts, per step */
    tc_vec cvert, cactive, cnormal, cdepth, cvel, cfric;  /* cactive: not released this sub-step */
    /* per vertex, carried from one sub-step to the next (constraints.c): the contact state it
     * ended in (int8, TC_CARRY_*) and the kinetic friction force its contacts applied then (N,
     * x3, zero unless sliding); during a sub-step, vkinetic is the force b carries */
    tc_vec vcstate, vkinetic;
    /* per vertex, double x3, or empty while every pin holds still (48 bytes a vertex that a cloth
     * whose pins never move does not pay): where a pinned vertex is to be at the end of the step
     * (vgoal) and where it was to be at its start (vgoal0); sub-steps go between them in a straight
     * line, as handles do between their maps. Made by the first tc_cloth_set_pin_goals (a pin that
     * follows a moving or deforming mesh), every pin's goals its position then; a vertex pinned or
     * put somewhere later has its goals where it is. Read only for pinned vertices. */
    tc_vec vgoal, vgoal0;
    /* per vertex, double, or empty while no vertex has one: the stiffness (N/m) of a spring that
     * pulls the vertex towards its goal (a soft pin: Blender's pin weights below 1). Made by the
     * first tc_cloth_set_pin_springs, which makes the goals too. A hard pin ignores its spring. */
    tc_vec vpink;

    /* solver scratch, sized to 3 * vertex capacity */
    tc_vec diag;             /* 9 per vertex */
    tc_vec pinv;             /* 9 per vertex */
    tc_vec sr, sz, sp, sq, sfix, v0;
    tc_vec sb, x0, fel;      /* empty: b lives in force during a sub-step, x0 in sp after the solve
                                (step.c), the elastic force in force (fem.c's tc_total_force); kept
                                in the table so that the snapshots of the builds that had them resume */
    tc_vec sb2;              /* right-hand side of the velocity-change solve */
    tc_vec sfix2;            /* empty: its prescribed values live in sz (solver.c); kept in the table
                                so that the snapshots of the builds that had it resume */
    tc_vec sdv;              /* velocity change of the last sub-step: the next solve's warm start */
    tc_vec snorm, scount;    /* per vertex: contact normal basis (3 x 3) and its size */

    /* tearing state */
    tc_vec vsa;              /* tearing scratch: per-vertex ratio of disc stress to threshold (a memo) */
    tc_vec tips;             /* int32 vertex ids of running tear tips */
    tc_vec tipdir;           /* double x3 preferred direction of each tip */
    int32_t scan_cursor;
    tc_vec tipadv;           /* double per tip: advance (m of rest length) earned and not yet cut */
    tc_vec tstamp, vstamp;   /* int32 per triangle / 3 per vertex: visit marks of the tearing walks */
    tc_vec tqueue, vqueue;   /* int32: the walks' queues of triangles / vertices (vsa: ratio memo) */
    int32_t stamp;           /* current visit mark (tstamp and vstamp hold older ones) */
    /* events */
    tc_vec ev_newv, ev_par, ev_w, ev_chg, ev_newt;
    tc_vec ev_rmv, ev_rmt;   /* removed vertices / triangles that existed when the events began (fragment.c) */

    tc_stats stats;
    bool dirty;              /* element state (rotations, stresses, forces) stale */
    bool topo_dirty;         /* topology changed: masses and bending need refresh */

    /* the solve's force scale and outcome (solver.c) */
    double carried2;         /* sum over triangle corners of |elastic force|^2 at x (N^2), fem.c */
    double mass_scale;       /* 1 + dt alpha: A 1 = mass_scale M 1 (fem.c's assembly) */
    double solve_residual_force, solve_force_scale, solve_residual;  /* last solve: N, N, 1 */

    /* The system matrix by rows, for a product that streams (mesh.c builds the pattern, fem.c's
     * assembly fills it). Row i: its diagonal block (diag: 3x3 column by column, each column
     * padded to 4 doubles), then its edge blocks A_ij, 3x3 column by column (9 doubles: padding
     * them would add a quarter to the bytes the product streams; a 4-wide load of a column reads
     * the next one's first value into a lane the kernels never store, and TC_ROW_SLACK zeros
     * follow the last block), then its bending flaps as scalars (a flap's block is a multiple of
     * I). Each edge pair has a slot in both of its rows (A_ji = A_ij^T: read twice, written once
     * per triangle, never scattered by the product). */
    tc_vec rptr, rcol, rblk;  /* int32 nv+1, int32 per slot, double x9 per slot (+ slack) */
    tc_vec fptr, fcol, fval;  /* int32 nv+1, int32 per flap slot, double per flap slot */
    tc_vec pslot;             /* int32 x2 per pair: its slot in row pi, then in row pj (edge or flap) */
    uint64_t pair_version;    /* bumped by every pair acquire / release: the pattern is then stale */
    uint64_t rows_version;    /* the pair_version the pattern was built for */
    int32_t rows_nv;          /* and the vertex count */
    bool rows_built;

    /* the multigrid hierarchy (amg.c): derived from the matrix, never part of a snapshot; NULL
     * until a solve uses it */
    tc_amg *amg;
    int amg_age;              /* sub-steps since its numeric refresh */
    int amg_last_iterations;  /* iterations of the last solve on it (how soon the next refresh pays) */
    double amg_fresh_rate;    /* convergence of the first solve after its prolongators were made:
                                 ln(|r0|^2 / |r|^2) per iteration (<= 0: none yet) */
    bool amg_stale;           /* a later solve converged much slower: a refresh next sub-step, then
                                 new prolongators if one was refreshed for it already */
    bool amg_stale_refreshed; /* refreshed for staleness since its prolongators were made */
    bool amg_chosen;          /* this sub-step's solves use it (solver.c's choose_amg) */

    /* the symmetric Gauss-Seidel sweeps' schedule (solver.c): derived from the row pattern, never
       part of a snapshot; NULL until a solve uses it */
    tc_sgs *sgs;
    /* the stiff groups block Jacobi inverts together (stiff.c): found from each sub-step's matrix,
       never part of a snapshot; NULL until a block-Jacobi solve looks for them */
    tc_stiff *stiff;
    /* the vertices' material discs (tear.c), kept from one step to the next while the topology
       stays: derived, never part of a snapshot; NULL until a disc stress is needed */
    tc_discs *discs;
};

/* Every array of a cloth (cloth.c's FOR_EACH_VEC as a table): its name, where it sits in the struct
 * and its item size. snapshot.c carries them all; a new scalar field of tc_cloth must be added to
 * snapshot.c by hand (its round-trip test, tests/test_snapshot.py, finds one that was not). */
typedef struct tc_vec_desc {
    const char *name;
    size_t offset, item;
} tc_vec_desc;
extern const tc_vec_desc tc_vec_table[];
extern const size_t tc_vec_table_len;

/* Hot loops get an AVX2/FMA clone picked at load time on x86-64 (GCC ifunc), so one portable wheel
 * still runs at full speed on machines that have them. */
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__) && !defined(TC_NO_CLONES)
#define TC_HOT __attribute__((target_clones("arch=x86-64-v3", "default")))
#else
#define TC_HOT
#endif

/* ---------------- util.c ---------------- */
double tc_now(void);                                  /* wall clock (s), for the step statistics */
void tc_set_err(tc_cloth *c, const char *fmt, ...);   /* the message of tc_cloth_error() */
void tc_culprits_clear(void);                         /* tc_create_culprits(): what a message names */
void tc_culprit(int32_t triangle, int32_t vertex);    /* -1: none of that kind */

/* ---------------- settings.c ---------------- */
int tc_solver_check(const tc_solver_settings *s, char *msg, size_t msz);
int tc_tear_check(const tc_tear_settings *s, char *msg, size_t msz);

/* ---------------- ortho.c ---------------- */
bool tc_material_general(const tc_material *m);     /* orthotropic or plastic: fem.c's general element */
void tc_ortho_moduli(const tc_material *m, double Q[4]);  /* Q11, Q22, Q12, Q66 in warp/weft axes (Pa) */
void tc_axes_set(tc_cloth *c, int32_t t, bool from_uv);  /* taxis from twarp (from the UVs if from_uv or unset) */
void tc_axes_refresh(tc_cloth *c);                  /* every triangle's warp again from its UVs and grain */
/* twarp and taxis are stored (from the first orthotropic or plastic material on: ortho.c's head) */
static inline bool tc_axes_stored(const tc_cloth *c) { return c->twarp.len != 0; }

/* Whether vertex v follows a goal (vgoal): pinned, or a soft pin's spring pulls it */
static inline bool tc_follows_goal(const tc_cloth *c, int32_t v)
{
    return ((const int8_t *)tc_vec_ptr(&c->vpin))[v] || (c->vpink.len && ((const double *)tc_vec_ptr(&c->vpink))[v] > 0);
}
int tc_axes_store(tc_cloth *c);                     /* made from the UVs and grain if not stored; TC_ERR_NOMEM */
void tc_tri_warp(const tc_cloth *c, int32_t t, double w[3]);  /* stored, or made as tc_axes_store would */
int32_t tc_plastic_commit(tc_cloth *c);             /* after a kept sub-step: triangles that yielded */

/* ---------------- mesh.c ---------------- */
int tc_mesh_build(tc_cloth *c, char *msg, size_t msz);
int32_t tc_pair_find(const tc_cloth *c, int32_t a, int32_t b);
int32_t tc_pair_acquire(tc_cloth *c, int32_t a, int32_t b);  /* find or create, use += 1 */
void tc_pair_release(tc_cloth *c, int32_t p);                 /* use -= 1, frees at 0 */
void tc_pair_hash_rebuild(tc_cloth *c);                       /* after the pairs' ends were renumbered */
/* the hash is dropped after a build and made again when a tear needs it (mesh.c) */
int tc_pair_hash_ensure(tc_cloth *c);                         /* TC_ERR_NOMEM */
void tc_pair_hash_drop(tc_cloth *c);
int tc_tri_rest(tc_cloth *c, int32_t t, char *msg, size_t msz);
void tc_masses_update(tc_cloth *c);
int tc_stencil_add(tc_cloth *c, int32_t edge_pair);
void tc_stencil_remove(tc_cloth *c, int32_t edge_pair);
int tc_reserve_vertices(tc_cloth *c, int32_t n);
int tc_reserve_triangles(tc_cloth *c, int32_t m);
int32_t tc_tri_local(const tc_cloth *c, int32_t t, int32_t v);
int tc_rows_update(tc_cloth *c);  /* the row pattern of the matrix, rebuilt when pairs changed */
/* The symmetric Gauss-Seidel sweeps run the rows in the vertices' own order (solver.c says why), and
 * the pattern keeps each row's slots of lower-numbered columns first (tc_rows_update), so a sweep
 * reads its half of a row as one range. Where the upper part of row i's slots cols[lo, hi) starts
 * (the first column above i); -1 when a lower slot follows an upper one: the row is not lower slots
 * first. */
static inline int32_t tc_row_upper_start(const int32_t *cols, int32_t lo, int32_t hi, int32_t i)
{
    int32_t s = lo;
    while (s < hi && cols[s] < i) s++;
    const int32_t start = s;
    for (; s < hi; s++)
        if (cols[s] < i) return -1;
    return start;
}
bool tc_rows_sweep_ordered(const tc_cloth *c);  /* every row lower slots first (an older snapshot's are not) */
/* A pair is an edge (full block) while a triangle uses it, else a bending flap (multiple of I). */
static inline bool tc_pair_is_edge(const tc_cloth *c, size_t p)
{
    const int32_t *pt = (const int32_t *)tc_vec_ptr(&c->ptris) + 2 * p;
    return pt[0] >= 0 || pt[1] >= 0;
}
/* neighbour of triangle t across its edge k (opposite local vertex k), -1 on a boundary */
static inline int32_t tc_nbr(const tc_cloth *c, int32_t t, int k)
{
    int32_t p = ((const int32_t *)tc_vec_ptr(&c->tpair))[3 * t + k];
    const int32_t *pt = (const int32_t *)tc_vec_ptr(&c->ptris) + 2 * (size_t)p;
    return pt[0] == t ? pt[1] : pt[0];
}

/* ---------------- events.c ---------------- */
void tc_events_clear(tc_cloth *c);
/* new vertex v from parents a and b (b = -1: a copy of a), wa the weight of a */
int tc_event_new_vertex(tc_cloth *c, int32_t v, int32_t a, int32_t b, double wa);
int tc_event_new_triangle(tc_cloth *c, int32_t t);
int tc_event_changed_triangle(tc_cloth *c, int32_t t);  /* once per step; never for a new one */

/* ---------------- fem.c ---------------- */
double tc_element_pass(tc_cloth *c, const double *x);  /* returns the largest stretch (NaN if not finite) */
void tc_bending_force(const tc_cloth *c, const double *x, double *f);
/* force := the element pass's elastic part (in force) + gravity + bending at x */
void tc_total_force(tc_cloth *c, const double *x);
int tc_assemble(tc_cloth *c, double dt);  /* TC_ERR_NOMEM if the rows could not grow */
/* Newton on the rotations (step.c): each triangle's frame turned to its polar rotation at x + dt v,
 * into rot, and the change of the linearized elastic force at x that this makes, into dg (3 nv);
 * returns the triangles left in their frame (collapsed at either end) */
int32_t tc_turn_pass(tc_cloth *c, const double *x, const double *v, double dt, double *dg);
/* an estimate of |dg|^2 that tc_turn_pass would give, from v alone (no frame is turned) */
double tc_turn_estimate(const tc_cloth *c, const double *v, double dt);
/* tc_element_pass at x and tc_assemble for a sub-step of dt in one pass over the triangles; the
 * largest stretch in *worst */
int tc_element_assemble(tc_cloth *c, const double *x, double dt, double *worst);
/* 1: the one-triangle-at-a-time reference loops instead of the batched ones (TEARCLOTH_FEM=reference
 * sets it at the first use; tests and comparisons switch it); -1: not read yet */
extern int tc_fem_reference;
/* y = A p; returns p . y (the CG's curvature, fused into the product). */
double tc_matvec(const tc_cloth *c, const double *p, double *y);
/* y -= A q, at a cost in proportion to the rows of the vertices where q is not zero */
void tc_matvec_sub_sparse(const tc_cloth *c, const double *q, double *y);
/* A triangle's world stress S = R sigma R^T (3x3 row-major) and the world direction of its largest
 * principal stress, from its rotation R (3x2, rot) and 2-D stress sigma (xx, yy, xy; sig). Derived
 * where read (tearing, the arrays of tc_cloth_array) instead of stored by the element pass: 12
 * doubles per triangle, 96 bytes, a tenth of the memory target of a 100K-triangle cloth.
 * tc_tri_world_stress is the one callers use: compiled as the element pass was when it stored them
 * (TC_HOT: the same contraction into FMAs), it gives the stored values bit for bit. */
void tc_tri_world_stress(const tc_cloth *c, size_t t, double S[9]);
void tc_tri_principal_dir(const tc_cloth *c, size_t t, double d[3]);
/* Its principal stresses, largest first: the eigenvalues of sigma, likewise derived where read
 * (tearing's scan, the PRINCIPAL array) instead of stored: 16 bytes per triangle. */
void tc_tri_principal(const tc_cloth *c, size_t t, double p[2]);
static inline void tc_principal(const double s[3], double p[2])
{
    const double sxx = s[0], syy = s[1], sxy = s[2];
    const double mean = 0.5 * (sxx + syy), dd = 0.5 * (sxx - syy), rad = sqrt(dd * dd + sxy * sxy);
    p[0] = mean + rad; p[1] = mean - rad;
}
static inline void tc_world_stress(const double R[6], const double s[3], double S[9])
{
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            S[3 * i + j] = R[i] * (s[0] * R[j] + s[2] * R[3 + j]) + R[3 + i] * (s[2] * R[j] + s[1] * R[3 + j]);
}
static inline void tc_principal_dir(const double R[6], const double s[3], double d[3])
{
    const double sxx = s[0], syy = s[1], sxy = s[2];
    const double mean = 0.5 * (sxx + syy), dd = 0.5 * (sxx - syy), l1 = mean + sqrt(dd * dd + sxy * sxy);
    /* eigenvector of the largest eigenvalue without trigonometry: (l1 - syy, sxy) or
       (sxy, l1 - sxx), whichever is better conditioned */
    double ex = l1 - syy, ey = sxy;
    const double fx = sxy, fy = l1 - sxx;
    if (ex * ex + ey * ey < fx * fx + fy * fy) { ex = fx; ey = fy; }
    const double el = sqrt(ex * ex + ey * ey);
    if (el > 0) { ex /= el; ey /= el; } else { ex = 1.0; ey = 0.0; }
    for (int k = 0; k < 3; k++) d[k] = R[k] * ex + R[3 + k] * ey;
}

/* ---------------- constraints.c ---------------- */
int tc_handle_add_member(tc_cloth *c, int32_t h, int32_t v, const double grasp[3]);
/* vflag and sfix for one sub-step of length dt ending at fraction alpha of the handles' motion */
void tc_constraints_begin(tc_cloth *c, double dt, double alpha);
void tc_contact_basis(tc_cloth *c, double dt);
void tc_contacts_kinetic_start(tc_cloth *c, double *b, double dt);  /* carried kinetic friction into b */
/* The soft pins' springs in the sub-step's system (after the assembly, b made): A_ii += dt^2 k_i I,
 * b_i += dt k_i (goal_i - x_i), the goal at fraction alpha of the step's motion (implicit Euler of
 * the spring force k (goal - x) at the sub-step's end) */
void tc_pin_springs_add(tc_cloth *c, double dt, double alpha, double *b);
void tc_constraint_filter(const tc_cloth *c, double *r);             /* r := S r */
void tc_constraint_matrix(const tc_cloth *c, int32_t i, double S[9]);  /* S_i, row-major */
void tc_filtered_diagonal(const double S[9], const double A[9], double F[9]);  /* S A S + w (I - S) */
void tc_constraint_project(const tc_cloth *c, double *v, const double *fix);  /* v := S v + fix */
void tc_constraint_offsets(const tc_cloth *c, const double *v0, double *fix);  /* fix -= (I - S) v0 */
/* the contact rounds after a solve (J = A v): each returns how many contacts (release, touch) or
 * held vertices (friction) change state; apply = 0 only counts them */
int tc_contacts_release(tc_cloth *c, const double *J, const double *b, int apply);  /* pulling contacts off */
int tc_contacts_touch(tc_cloth *c, const double *v, double dt, int apply);  /* lifted contacts driven in: on */
int tc_contacts_friction(tc_cloth *c, const double *J, const double *v, double *b, double dt, int apply);  /* Coulomb */
void tc_contacts_carry(tc_cloth *c);  /* after the last round: vcstate and vkinetic for the next sub-step */
int32_t tc_contacts_active(const tc_cloth *c);
void tc_contacts_take_back_push(const tc_cloth *c, double *v, double dt);
void tc_handle_forces(tc_cloth *c);

/* ---------------- amg.c ---------------- */
tc_amg *tc_amg_new(void);
void tc_amg_free(tc_amg *h);
/* the hierarchy of the current matrix (after tc_assemble and tc_precondition_build); the kept
 * aggregates unless `aggregate_again` or the mesh changed. 0, or -1 when out of memory. */
int tc_amg_build(tc_amg *h, const tc_cloth *c, bool aggregate_again);
bool tc_amg_needs_aggregation(const tc_amg *h, const tc_cloth *c);
/* z = V-cycle r; returns r . z. Its fine residual lives in the solver's q (sq): r and z are not it */
double tc_amg_apply(const tc_cloth *c, tc_amg *h, const double *r, double *z);
/* the Galerkin operators of the current matrix on the kept prolongators (0; -1: not valid for this
 * mesh, or out of memory: the hierarchy is dropped), and how many since the prolongators were made */
int tc_amg_refresh(tc_amg *h, const tc_cloth *c);
/* A_1 = P^T (S A S + tau (I - S) d) P for the current contacts (the build and refresh make it with
   contact vertices free) and the coarser levels from it, when enough changed since the last one
   (constants.h); 0 also when nothing was due; -1 (counted by the caller) leaves the uncorrected
   hierarchy, or none (block Jacobi then) */
int tc_amg_contacts(tc_amg *h, const tc_cloth *c);
void tc_amg_follow_contacts(tc_amg *h, bool on);  /* the contact correction on (default) or off (the bench's comparison) */
int tc_amg_refreshes(const tc_amg *h);
void tc_amg_set_run_blocks(tc_amg *h, int32_t blocks);  /* tests: the refresh's double buffer (0: default) */
void tc_amg_forget(tc_amg *h);  /* aggregate again at the next build, no choice history (a snapshot was taken) */
void tc_amg_drop(tc_amg *h);    /* the hierarchy's memory back; the object and its choice history kept */
int tc_amg_choice(const tc_amg *h);             /* "auto"'s last pick: 1 multigrid, 0 Jacobi, -1 none */
void tc_amg_set_choice(tc_amg *h, bool amg);
int tc_amg_levels(const tc_amg *h);
bool tc_amg_valid(const tc_amg *h, const tc_cloth *c);  /* built for the current mesh */
size_t tc_amg_bytes(const tc_amg *h);
double tc_amg_galerkin_error(const tc_cloth *c, tc_amg *h);  /* tests: A_1 against P^T A P */
double tc_amg_first_residual_error(const tc_cloth *c, tc_amg *h, const double *r);  /* tests: the first sweep's residual */

/* ---------------- solver.c ---------------- */
void tc_precondition_build(tc_cloth *c, double dt);
void tc_sgs_free(tc_sgs *g);
size_t tc_sgs_bytes(const tc_sgs *g);
void tc_precondition_constraints_changed(tc_cloth *c);  /* after a re-built contact basis (step.c) */
/* ---------------- stiff.c ---------------- */
int tc_stiff_build(tc_cloth *c, double dt);  /* the groups of this sub-step's matrix and their factors */
void tc_stiff_forget(tc_stiff *g);     /* a snapshot: look for slivers at the next sub-step */
void tc_stiff_refactor(tc_cloth *c);   /* the factors again, under changed constraints */
void tc_stiff_clear(tc_stiff *g);      /* no group this sub-step (not block Jacobi) */
double tc_stiff_apply(const tc_cloth *c, const double *r, double *z);  /* z_g = A~_g^-1 r_g; returns the change of r.z */
int32_t tc_stiff_groups(const tc_stiff *g);
void tc_stiff_free(tc_stiff *g);
size_t tc_stiff_bytes(const tc_stiff *g);
/* a snapshot is being taken: the next sub-step builds the hierarchy from scratch, as a run resumed
 * from it does (snapshot.c), so the two step alike to the bit */
void tc_precondition_snapshot(const tc_cloth *c);
/* 1 when converged, 0 when stopped at the cap; iterations in *iterations (see solver.c) */
int tc_solve_dv(tc_cloth *c, double *v, const double *v0, const double *b, double dt, double tolerance,
                int *iterations);

/* ---------------- remesh.c ---------------- */
/* Triangles around u reachable from `start` without crossing a boundary or a pair in `cut`: the
 * count, or -1 if the fan exceeds cap; *closed tells whether it wraps around. */
int tc_fan_walk(const tc_cloth *c, int32_t u, int32_t start, const int32_t *cut, int ncut, int32_t *out, int cap,
                bool *closed);
bool tc_is_boundary_vertex(const tc_cloth *c, int32_t u);
/* The segment from tip v along dir (snapping or splitting): its far vertex, or -1; the pair to cut
 * in *pair. `avoid` lists pairs already in the cut, so the path never folds back. */
int32_t tc_prepare_segment(tc_cloth *c, int32_t v, const double *dir, const int32_t *avoid, int navoid, int32_t *pair);
/* Separates the mesh along the pairs in `cut`; bit i of *dup_mask set when verts[i] was duplicated. */
int tc_separate(tc_cloth *c, const int32_t *cut, int ncut, const int32_t *verts, int nverts, unsigned *dup_mask);

/* ---------------- fragment.c ---------------- */
/* Removes the pieces the events' cuts set free whose rest area is below min_fragment_area. */
int tc_fragments_remove(tc_cloth *c);

/* ---------------- tear.c ---------------- */
int tc_tear_step(tc_cloth *c, double dt);  /* dt: the step just taken (s), for the tips' advance */
void tc_discs_free(tc_discs *d);
size_t tc_discs_bytes(const tc_discs *d);

/* ---------------- step.c ---------------- */
void tc_refresh(tc_cloth *c);  /* element state and forces of the current positions, if stale */

#endif
