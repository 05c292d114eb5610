/* tearcloth.h - the one public header of the Tear Cloth native core.
 *
 * The core simulates a thin surface (cloth, paper) as a co-rotational linear FEM on constant
 * strain triangles (plane stress) with a quadratic bending energy, integrated by implicit Euler
 * solved with block-Jacobi preconditioned conjugate gradients, and tears it where the largest
 * principal stress passes the material's tear stress (Le Gouis et al., WHC 2017, section V).
 *
 * Units are SI everywhere: metres, seconds, kilograms, pascals, newtons.
 *
 * The core owns the mesh while it simulates: it grows its arrays when tearing adds vertices and
 * triangles (no fixed pool), and reports each change as topology events so that callers update
 * clusters, Blender meshes and caches incrementally. Arrays that callers read without copying live
 * in reference-counted blocks (tc_buf): a reader keeps the block it got alive, so growth never
 * frees memory under a reader's feet; the reader re-fetches after a topology change.
 *
 * No function here touches Python. Every entry point validates its input and returns a TC_ERR_*
 * code with a message in tc_cloth_error(); nothing aborts.
 */
#ifndef TEARCLOTH_H
#define TEARCLOTH_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

enum {
    TC_OK = 0,
    TC_ERR_INPUT = 1,      /* bad argument or bad mesh: the message names the culprit */
    TC_ERR_NOMEM = 2,      /* allocation failed; the cloth is unchanged */
    TC_ERR_UNSTABLE = 3,   /* the step produced non-finite values or exploding strain: rolled back */
};

/* A reference-counted block of memory shared between the core and zero-copy readers. */
typedef struct tc_buf tc_buf;
void *tc_buf_data(tc_buf *b);
void tc_buf_incref(tc_buf *b);
void tc_buf_decref(tc_buf *b);

/* Material of a thin sheet. Create with tc_material_default(), then change fields. */
typedef struct tc_material {
    double young;             /* Young's modulus E (Pa) */
    double poisson;           /* Poisson ratio nu, in (-1, 0.5) */
    double thickness;         /* h (m) */
    double density;           /* rho (kg/m^3); lumped mass = rho h A / 3 per corner */
    double bending;           /* bending stiffness (N m); physical plate value is E h^3 / 12(1-nu^2) */
    double damping_mass;      /* Rayleigh alpha (1/s) */
    double damping_stiffness; /* Rayleigh beta (s) */
    double tear_stress;       /* sigma_E (Pa): a tear starts where the largest principal stress passes it */
    double snap_tolerance;    /* fraction of an edge, in [0, 0.5): cut points this close to a vertex snap to it */
    double tear_radius;       /* l (m): the material length over which the stress that starts, drives and
                                 arrests a tear is averaged (theory of critical distances, see tear.c) */
    double crack_speed_ratio; /* fastest a tear runs, as a fraction of the Rayleigh wave speed c_R, in (0, 1] */
    /* Orthotropy (see ortho.c). When orthotropic, young, poisson and tear_stress are the warp's. */
    double young_weft;        /* E along the weft (Pa) */
    double shear_modulus;     /* G of the warp-weft axes, the bias stiffness (Pa) */
    double grain_angle;       /* rad: the warp's angle from the UV map's u direction (triangles without
                                 their own, see tc_cloth_set_grain_angles) */
    double tear_stress_weft;  /* strength along the weft (Pa) */
    /* Plasticity (ortho.c): Hill 1948 yield with linear proportional hardening, rest metric updated
       additively in the co-rotated frame. */
    double yield_stress;      /* along the warp (isotropic: any direction) (Pa) */
    double yield_stress_weft; /* along the weft (Pa); used when orthotropic */
    double hardening;         /* H / E_warp: the yield stress grows by H per unit plastic strain (1) */
    /* the two switches last and together: no padding, so a material compares by its bytes */
    int orthotropic;          /* 0: isotropic (young, poisson); 1: warp/weft axes per triangle */
    int plastic;              /* 0: elastic up to the tear; 1: yield and keep the stretch */
} tc_material;

tc_material tc_material_default(void);  /* the "cotton" preset of addon/materials.py */
/* Returns TC_OK or TC_ERR_INPUT with a message in msg (at least 256 bytes). */
int tc_material_check(const tc_material *m, char *msg, size_t msg_size);

typedef struct tc_solver_settings {
    double gravity[3];        /* m/s^2 */
    double cg_tolerance;      /* residual force at which CG stops, relative to the forces the cloth
                                 carries (weight, elastic, net force of the step; see tc_stats) */
    int cg_max_iterations;
    double max_stretch;       /* a principal stretch above this counts as an explosion: roll back */
    double contact_max_push;  /* fastest speed (m/s) at which a penetration is resolved, so that
                                 bodies that start inside the cloth separate without a blast */
    double contact_correction; /* fraction of a contact's depth removed from the position per step */
    int preconditioner;       /* TC_PRECOND_*: of the CG (solver.c says when AUTO picks which) */
} tc_solver_settings;

enum { TC_PRECOND_AUTO = 0, TC_PRECOND_JACOBI = 1, TC_PRECOND_AMG = 2, TC_PRECOND_SGS = 3 };
/* the names of the TC_PRECOND_* values ("auto", "jacobi", "amg", "sgs"); -1 / NULL for an unknown one */
int tc_precond_from_name(const char *name);
const char *tc_precond_name(int p);

tc_solver_settings tc_solver_default(void);

/* The kernel of the solver's matrix-vector product, process-wide (a property of the CPU):
 * TC_SIMD_AUTO picks the best the CPU has, or the one the TEARCLOTH_SIMD environment variable names
 * (scalar, sse2, avx2, neon) if the CPU has it; a level the CPU or the build lacks is refused (-1).
 * Returns the level chosen. All kernels agree to rounding (1e-12 relative). */
enum { TC_SIMD_AUTO = -1, TC_SIMD_SCALAR = 0, TC_SIMD_SSE2 = 1, TC_SIMD_AVX2 = 2, TC_SIMD_NEON = 3 };
#define TC_SIMD_LAST TC_SIMD_NEON
int tc_simd_select(int level);
int tc_simd_level(void);
const char *tc_simd_name(int level);

typedef struct tc_cloth tc_cloth;

/* The mesh elements the last failed tc_cloth_create on this thread named (0-based, in the numbering
 * it was given): the triangles and vertices its message is about, so callers map them to their own
 * numbering and select them without reading the message's text. Cleared by every create. */
#define TC_CULPRITS_MAX 4
typedef struct tc_culprits {
    int32_t n_triangles, triangles[TC_CULPRITS_MAX];
    int32_t n_vertices, vertices[TC_CULPRITS_MAX];
} tc_culprits;
tc_culprits tc_create_culprits(void);

/* Creates a cloth from n vertices (xyz) and m triangles (vertex indices, counter-clockwise).
 * rest: NULL (rest shape = positions) or n*rest_dim values: rest_dim = 3 (3-D rest positions) or
 * 2 (material coordinates in metres, e.g. UVs scaled to size).
 * corner_uv: NULL or m*3*2 UVs per triangle corner (carried through tears).
 * groups: NULL or n*n_groups weights per vertex (vertex groups, carried through tears).
 * On failure returns NULL and writes the reason into msg. */
tc_cloth *tc_cloth_create(const double *positions, int32_t n, const int32_t *triangles, int32_t m,
                          const double *rest, int rest_dim, const double *corner_uv,
                          const double *groups, int n_groups, const tc_material *material,
                          char *msg, size_t msg_size);
void tc_cloth_destroy(tc_cloth *c);
const char *tc_cloth_error(const tc_cloth *c);

int tc_cloth_set_material(tc_cloth *c, const tc_material *m);
tc_material tc_cloth_material(const tc_cloth *c);
int tc_cloth_set_solver(tc_cloth *c, const tc_solver_settings *s);
tc_solver_settings tc_cloth_solver(const tc_cloth *c);

int32_t tc_cloth_num_vertices(const tc_cloth *c);
int32_t tc_cloth_num_triangles(const tc_cloth *c);
int tc_cloth_num_groups(const tc_cloth *c);

/* Replaces positions / velocities (n*3 values, all finite). */
int tc_cloth_set_positions(tc_cloth *c, const double *x, int32_t n);
int tc_cloth_set_velocities(tc_cloth *c, const double *v, int32_t n);

/* Pins vertices where they are (their goals, below, become their positions) or frees them. */
int tc_cloth_pin(tc_cloth *c, const int32_t *idx, int32_t k, int pinned);
/* Where pinned vertices are to be at the end of the next step (k positions, all finite; every
 * listed vertex pinned or with a spring): a pin that follows a moving or deforming mesh. Reached in a straight line
 * from the goals of the step before, across sub-steps; kept until set again. */
int tc_cloth_set_pin_goals(tc_cloth *c, const int32_t *idx, const double *pos, int32_t k);
/* Soft pins: a spring of stiffness k[i] (N/m, finite, >= 0; 0 removes it) pulls vertex idx[i]
 * towards its goal, which starts where the vertex is (or stays where it was set) and moves with
 * tc_cloth_set_pin_goals. A pinned vertex ignores its spring. */
int tc_cloth_set_pin_springs(tc_cloth *c, const int32_t *idx, const double *k, int32_t n);
/* nv spring stiffnesses (N/m), or NULL while no vertex has one. */
const double *tc_cloth_pin_springs(const tc_cloth *c);
/* nv flags, 1 for a pinned vertex (valid until the next change of the cloth). */
const int8_t *tc_cloth_pin_flags(const tc_cloth *c);

/* Handles: a set of vertices moved rigidly to a target (the grasped part of the cloth).
 * The target is an affine map (3x4, row-major) applied to the positions the vertices had when the
 * handle was created; it is reached at the end of the next step, interpolated across sub-steps. */
int tc_cloth_add_handle(tc_cloth *c, const int32_t *idx, int32_t k, int32_t *handle_out);
int tc_cloth_set_handle_target(tc_cloth *c, int32_t h, const double affine[12]);
int tc_cloth_release_handle(tc_cloth *c, int32_t h);
int32_t tc_cloth_num_handles(const tc_cloth *c);
/* Force of eq. (6): sum over the handle's vertices of elastic + external forces (N), i.e. the force
 * the cloth exerts on the hand that holds it. */
int tc_cloth_handle_force(const tc_cloth *c, int32_t h, double out[3]);
int tc_cloth_pin_force(const tc_cloth *c, double out[3]);

/* Contacts for the next step (replacing earlier ones): per contact a vertex, a unit push-out normal,
 * a penetration depth (m, >= 0), the velocity of the touched surface and a friction coefficient. */
int tc_cloth_set_contacts(tc_cloth *c, const int32_t *vertex, const double *normal,
                          const double *depth, const double *velocity, const double *friction,
                          int32_t k);
/* Each vertex carries how its contacts ended the last sub-step (sliding, with its kinetic friction,
 * or lifted off) into the next one as the state its solve starts from (constraints.c); this drops
 * it, so the next sub-step judges every contact as on first touch (after a cut in the animation:
 * a body or cloth moved elsewhere). The result agrees either way within the solve's tolerance. */
void tc_cloth_forget_contacts(tc_cloth *c);

/* Advances by dt seconds in `substeps` implicit Euler steps. The caller may release the GIL. */
int tc_cloth_step(tc_cloth *c, double dt, int substeps);

typedef struct tc_stats {
    int cg_iterations;        /* summed over the sub-steps of the last step */
    double cg_residual;       /* largest residual force of a solve in the last step, over its force scale */
    double fem_seconds;       /* wall time of the last step without tearing */
    double tear_seconds;      /* wall time of the tearing part of the last step */
    int64_t steps;
    int32_t tears_started;    /* tears started so far */
    int32_t cuts;             /* cut segments so far */
    int32_t contacts;         /* contacts active in the last step */
    /* The solve stops when its residual force is cg_tolerance of the forces the cloth carries
     * (weight, carried elastic forces, net force of the step; solver.c). A sub-step whose solve
     * reaches cg_max_iterations first is rolled back and run as two halves (up to TC_SPLIT_DEPTH
     * times); one still unconverged then is accepted and counted here, never silently. */
    double cg_residual_force; /* N: largest residual force of a solve in the last step */
    double cg_force_scale;    /* N: the force scale it was measured against */
    int32_t substep_splits;   /* sub-steps of the last step split in two because a solve did not converge */
    int32_t unconverged_substeps; /* sub-steps of the last step accepted unconverged */
    int64_t unconverged_steps;    /* steps so far with at least one sub-step accepted unconverged */
    int64_t matrix_bytes;     /* bytes of the system matrix one product reads (rows, blocks, indices) */
    int32_t tips_retired;     /* tips whose driving stress fell below the threshold, so far */
    int32_t grips_released;   /* held vertices let go: over threshold with one triangle left (tear.c) */
    int32_t plastic_triangles;    /* yield events of the last step: triangles that yielded, summed over its sub-steps (ortho.c) */
    int32_t plastic_unconverged;  /* return mappings stopped at their iteration cap, so far (ortho.c) */
    int32_t amg_levels;       /* levels of the multigrid hierarchy in the last step's solves (0: block Jacobi) */
    double amg_setup_seconds; /* wall time of the last step spent building, refreshing or contact-correcting it */
    int64_t amg_fallbacks;    /* solves so far where the multigrid cycle broke down or could not be
                                 built (out of memory) and block Jacobi took over, or its contact
                                 correction could not be made (the uncorrected cycle ran) */
    int32_t fragments_removed;          /* pieces removed so far for being below min_fragment_area */
    int32_t fragment_triangles_removed; /* their triangles, so far */
    int32_t fragment_vertices_removed;  /* their vertices, so far */
    int32_t fragments_kept;             /* pieces below the size kept: they share a vertex with the rest */
    int64_t amg_bytes;        /* bytes the multigrid hierarchy holds after its last build or refresh (0: none) */
    int64_t contact_directions_merged; /* so far: directions of a vertex's contact normals left free
                                          because two contacts were nearly parallel or opposite (a
                                          squeeze) and share the others (TC_CONTACT_MIN_EIGEN) */
    int64_t contact_speed_clamps;      /* so far: vertex contact solves whose least-squares speed
                                          exceeded |z| (what its contacts ask) and was bounded to it */
    int64_t friction_slips;            /* so far: held contact vertices whose static friction would have
                                          needed more than mu times the normal reaction: they slid */
    int64_t friction_cone_exceeded;    /* so far: held vertices left outside the Coulomb cone when a
                                          sub-step's contact rounds stopped at TC_CONTACT_ROUNDS */
    int64_t friction_sticks;           /* so far: sliding contact vertices whose slip stopped or turned
                                          past a right angle from their kinetic friction (which cannot
                                          push along a slip): held from the next sub-step */
    int64_t slides_carried;            /* so far: contact vertices that began a sub-step sliding, as they
                                          ended the previous one (its kinetic friction the first guess) */
    int64_t lifts_carried;             /* so far: contacts that began a sub-step released, their vertex
                                          having lifted off in the previous one and still separating */
    int64_t contact_rounds_capped;     /* so far: sub-steps whose contacts were still changing state (or
                                          their kinetic friction still off by more than the solve's
                                          tolerance) after TC_CONTACT_ROUNDS re-solves: kept as solved */
    int32_t solves;                    /* linear solves of the last step, summed over its sub-steps:
                                          one each, more when its contacts changed state (rounds) */
    int64_t sgs_fallbacks;    /* solves so far that asked for symmetric Gauss-Seidel (forced, or auto
                                 below the multigrid bar) but got block Jacobi: its row split could not be
                                 made (out of memory) */
    int32_t sgs_solves;       /* linear solves of the last step preconditioned by the Gauss-Seidel
                                 sweeps (of `solves`; the others block Jacobi or the multigrid cycle) */
    int32_t stiff_groups;     /* the most stiff groups (stiff.c: sliver corners inverted together by
                                 block Jacobi) any sub-step of the last step had */
    int64_t stiff_group_failures; /* so far: stiff groups whose factor failed (round-off): their
                                 vertices kept their own 3x3 blocks */
    int64_t contact_pushes_capped; /* so far: contacts (per sub-step) deeper than one sub-step recovers:
                                      contact_correction x depth / dt passed contact_max_push and the push
                                      out was held to it (the rest is recovered over the next sub-steps) */
    int64_t rotation_solves;     /* so far: sub-steps solved again about the rotations their first
                                    solve reached (step.c's Newton on the rotations) */
    int64_t rotations_capped;    /* so far: sub-steps whose rotations still moved the linearized force
                                    by more than TC_ROTATION_BAR after TC_ROTATION_SOLVES re-solves: kept */
} tc_stats;
/* the smallest tc_stats a snapshot may carry: the layout before contact_directions_merged (older
 * states read with the counters after it at 0; snapshot.c) */
#define TC_STATS_OLDEST_BYTES ((uint32_t)offsetof(tc_stats, contact_directions_merged))
tc_stats tc_cloth_stats(const tc_cloth *c);
/* y = A p (n*3 values each) with the system matrix A of the last sub-step, by the kernel in use:
 * for tests of the kernels and benchmarks of the product. TC_ERR_INPUT when no step has assembled
 * one for the current mesh (a tear since, or no step yet). */
int tc_cloth_product(tc_cloth *c, const double *p, int32_t n, double *y);
/* Memory held by array k of the cloth (k < tc_cloth_memory_count(); the last entries are the pair
 * hash, fem.c's slot table and the multigrid hierarchy): its name, the bytes its items use and the
 * bytes it holds (capacity). For the memory accounting of the scaling bench and its tests. */
size_t tc_cloth_memory_count(void);
const char *tc_cloth_memory(const tc_cloth *c, size_t k, size_t *used, size_t *held);

typedef struct tc_energy {
    double kinetic, elastic, bending, gravity;
    double pins;  /* the soft pins' springs: 1/2 k |x - goal|^2 (hard pins hold no energy) */
} tc_energy;
tc_energy tc_cloth_energy(tc_cloth *c);

/* Arrays, readable without copying; the returned block carries a new reference (tc_buf_decref it).
 * Sizes follow the current vertex / triangle counts. TC_STRESS, TC_PRINCIPAL and TC_PRINCIPAL_DIR
 * are derived at the call (the core keeps the rotation and 2-D stress only) into a block of the caller's own,
 * which later steps do not update. */
typedef enum tc_array_id {
    TC_POSITIONS,        /* n x 3 float64 */
    TC_VELOCITIES,       /* n x 3 float64 */
    TC_REST,             /* n x 3 float64 */
    TC_MASSES,           /* n float64 */
    TC_FORCES,           /* n x 3 float64: elastic + bending + gravity per vertex, last step */
    TC_GROUPS,           /* n x g float64 */
    TC_TRIANGLES,        /* m x 3 int32 */
    TC_CORNER_UV,        /* m x 3 x 2 float64 */
    TC_STRESS,           /* m x 3 x 3 float64: Cauchy-like stress of each triangle in world axes (Pa) */
    TC_PRINCIPAL,        /* m x 2 float64: principal stresses, largest first */
    TC_PRINCIPAL_DIR,    /* m x 3 float64: unit direction of the largest principal stress */
    TC_TEAR_STRENGTH,    /* n float64: per-vertex factor on tear_stress */
    TC_GRAIN_ANGLES,     /* m float64: each triangle's own grain angle (rad), NaN: the material's */
    TC_WARP,             /* m x 3 float64: unit warp direction of each triangle in the rest space */
    TC_PLASTIC_STRAIN,   /* m x 4 float64: plastic strain in the warp/weft axes (ww, ff, wf) and the
                            equivalent plastic strain kappa (ortho.c) */
    TC_ARRAY_COUNT
} tc_array_id;
tc_buf *tc_cloth_array(tc_cloth *c, tc_array_id id, size_t *rows, size_t *cols, size_t *item_size);

/* ---- tearing ---- */
typedef struct tc_tear_settings {
    int enabled;
    int scan_period;          /* once a tear runs, the rest of the mesh is scanned in slices so that
                                 every triangle is examined once every scan_period steps */
    double min_angle_deg;     /* no new triangle gets an angle below this; cuts snap or stop instead */
    double min_fragment_area; /* m^2 of rest area: a piece a tear sets free that is smaller is removed,
                                 with its vertices (fragment.c); 0 keeps every piece */
} tc_tear_settings;
tc_tear_settings tc_tear_default(void);
int tc_cloth_set_tearing(tc_cloth *c, const tc_tear_settings *s);
tc_tear_settings tc_cloth_tearing(const tc_cloth *c);
/* Per-vertex factor on the tear stress (1 = the material's, 0.5 = weak seam, large = unbreakable). */
int tc_cloth_set_tear_strength(tc_cloth *c, const double *factor, int32_t n);
/* Per-triangle grain angle (rad) from the UV map's u direction, overriding the material's
 * grain_angle; NaN: the material's. m must be the current triangle count. */
int tc_cloth_set_grain_angles(tc_cloth *c, const double *angles, int32_t m);
/* out[t] = 1 (num_triangles bytes) where triangle t's UVs carry no warp direction (no UV map, the
 * triangle collapsed in UV space, or UVs so large their gradients overflow): there the warp of an
 * orthotropic or plastic material is the rest X axis (Y where the triangle is normal to X), turned
 * by the grain angle. Returns how many. */
int32_t tc_cloth_warp_fallbacks(const tc_cloth *c, uint8_t *out);
/* Tears from vertex `start` along `direction` (projected on the surface) for `length` metres,
 * whatever the stress. Returns the number of cut segments in *cuts. */
int tc_cloth_scripted_tear(tc_cloth *c, int32_t start, const double direction[3], double length,
                           int32_t *cuts);

/* Topology events since the last step began (cleared at the start of each step). */
typedef struct tc_events {
    int32_t n_new_vertices;
    const int32_t *new_vertices;   /* indices */
    const int32_t *parents;        /* 2 per new vertex; second is -1 for a duplicated vertex */
    const double *weights;         /* weight of the first parent */
    int32_t n_changed_triangles;
    const int32_t *changed_triangles;
    int32_t n_new_triangles;
    const int32_t *new_triangles;
    int32_t n_tips;
    const int32_t *tips;           /* current tear tips (vertex indices) */
    /* Vertices and triangles removed with tiny fragments (fragment.c), sorted, numbered as they were
     * when the events began; every other index above is in the numbering after the removal, whose
     * survivors keep their order. A reader deletes these from what it holds, then applies the rest. */
    int32_t n_removed_vertices;
    const int32_t *removed_vertices;
    int32_t n_removed_triangles;
    const int32_t *removed_triangles;
} tc_events;
tc_events tc_cloth_events(const tc_cloth *c);

/* Largest principal stress of a vertex and its direction: the area-weighted average of the stress
 * tensors of its own triangles and of every triangle connected to them (through uncut edges) whose
 * rest centroid lies within tear_radius of the vertex, projected on the vertex tangent plane. This
 * is the measure tearing compares with tear_stress * strength. */
int tc_cloth_vertex_stress(tc_cloth *c, int32_t v, double *value, double direction[3]);

/* ---- snapshot and restore (snapshot.c) ----
 * The whole simulation state of a cloth (every array, the pair hash, handles, tear tips and scan
 * position, warm start, counters, settings) as one versioned, checksummed blob, so that a cloth
 * made from it steps exactly (bit for bit) as the original would. A blob is read only by the build
 * that wrote it (same array list and struct layouts) and on the same byte order; anything else, a
 * truncated or corrupted blob included, is refused with a message, never half-restored. */
#define TC_SNAPSHOT_VERSION 1
/* *out: a malloc'ed blob of *size bytes (free() it); TC_ERR_NOMEM if it could not be allocated. */
int tc_cloth_snapshot(const tc_cloth *c, void **out, size_t *size);
/* A new cloth from a blob, or NULL with the reason in msg. */
tc_cloth *tc_cloth_from_snapshot(const void *data, size_t size, char *msg, size_t msg_size);

#ifdef __cplusplus
}
#endif
#endif
