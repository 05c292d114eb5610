/* constants.h - every tuning constant of the native core in one place, each with its unit and the
 * reason for its value (Box2D v3's constants.h is the model). Validation limits of user settings
 * stay beside the checks that print them (settings.c), since their messages quote the numbers.
 *
 * Changing a value here changes simulation results: the test suite and the example bakes pin them.
 */
#ifndef TEARCLOTH_CONSTANTS_H
#define TEARCLOTH_CONSTANTS_H

#define TC_PI 3.14159265358979323846

/* ---- helper axes ----
 * Two places build a vector orthogonal to a unit vector u by crossing or Gram-Schmidt against a
 * coordinate axis: x when |u_x| is below a limit, else y. Any limit in (1/sqrt(3), 1) works (some
 * component of a unit vector always reaches 1/sqrt(3) = 0.577). They are the same idea with two
 * values, kept apart on purpose: unifying them would change which axis is picked for normals with
 * |n_x| in [0.6, 0.9), and with it the last bits of every vertex stress and tear direction there
 * (the eigenvalue does not depend on the basis, its round-off does). */
#define TC_TANGENT_AXIS_LIMIT 0.6   /* 1: tear.c, tangent basis of a vertex normal (every vertex stress) */
#define TC_COLLAPSE_AXIS_LIMIT 0.9  /* 1: fem.c, second rotation column of a collapsed element (rare) */

/* ---- co-rotation (fem.c) ---- */
/* det(F^T F) below this fraction of trace^2: the element is collapsed to a line or a point and the
 * polar decomposition is ill-conditioned; Gram-Schmidt keeps a frame instead. (1) */
#define TC_COLLAPSE_DET 1e-16
/* A column this short (after removing its projection) has no direction left: pick an axis. (1) */
#define TC_COLLAPSE_COLUMN 1e-12

/* ---- rest elements (mesh.c) ---- */
/* A sliver whose area is below this fraction of its longest edge squared cannot be inverted
 * reliably in double precision: rejected as degenerate. (1) */
#define TC_SLIVER_AREA 1e-10

/* ---- pair hash (mesh.c) ---- */
#define TC_HASH_INITIAL 64          /* slots of a new cloth's pair hash (power of two) */

/* ---- constraints (constraints.c) ---- */
/* A contact normal is accepted when its length is within this of 1 (then renormalised). (1) */
#define TC_UNIT_NORMAL_TOLERANCE 1e-3
/* A direction of a vertex's contact basis is kept when the sum of its contacts' normals' outer
 * products, M = sum n n^T, has at least this eigenvalue along it; a smaller one (two normals within
 * ~26 degrees of parallel, or of opposite: 1 - |n1 . n2| < 0.1) would prescribe a speed up to
 * 1/sqrt(lambda) > 3 times what the contacts ask, so it is left free and the contacts share the
 * directions that are kept (constraints.c, contact_solve). (1, |n| = 1) */
#define TC_CONTACT_MIN_EIGEN 0.1
/* An eigenvalue of M below this is numerically zero (duplicate or exactly parallel normals):
 * leaving it free is no compromise and is not counted in tc_stats.contact_directions_merged. (1) */
#define TC_CONTACT_SAME_DIRECTION 1e-9

/* A contact is released when its reaction pulls by more than this fraction of the vertex's
 * momentum terms (|J_i| + |b_i| + m_i (|surface velocity| + contact_max_push)): less is rounding
 * of a zero reaction. (1) */
#define TC_RELEASE_ROUNDING 1e-9
/* Solves of one sub-step that turn held contact vertices whose static friction is exceeded into
 * sliding ones (and release pulling contacts): the load moves on to the next held row of a stiff
 * cloth each round. A vertex still outside its cone after them stays held, counted in
 * tc_stats.friction_cone_exceeded. (solves) */
#define TC_CONTACT_ROUNDS 8

/* ---- linear solver (solver.c) ---- */
/* A 3x3 diagonal block with |det| below this is singular (cannot happen with positive masses):
 * its preconditioner block is zero instead of a division by zero. (N s/m)^3 */
#define TC_SINGULAR_DET 1e-300
/* Stand-in for a zero right-hand-side norm, so the stopping test never divides by zero. */
#define TC_TINY 1e-300

/* ---- tearing (tear.c) ---- */
/* Largest fan (triangles around one vertex) a tear walks; far above any sane valence, and a fan
 * larger than this stops the tear there. (triangles) */
#define TC_FAN_MAX 256
/* Regions over threshold that may start a tear in one step (the best ones first; the others start
 * in the next steps). */
#define TC_TEAR_CANDIDATES 8
/* Vertices of one region tried, best first, when the remesh cannot cut at the better ones. */
#define TC_REGION_TRIES 4
/* Corner fit of a segment direction: a triangle whose corner holds the direction scores >= 0; a
 * direction pointing away from both edges of the corner loses this much, so any corner that holds
 * it wins; a best score below the limit means no corner holds the direction. (1: sine of angle) */
#define TC_CORNER_BACKWARDS_PENALTY 2.0
#define TC_CORNER_MIN_SCORE (-0.05)
/* A direction lies inside a corner of a tip's fan when its sine with each side, over the corner,
 * exceeds this (about 1 degree): one along a boundary side (the rim) is outside. (1) */
#define TC_CORNER_INSIDE 0.02
/* Parallel path and edge: no meeting point, split the edge in the middle. (1) */
#define TC_PARALLEL_SPLIT 0.5
/* Snapping to the farther end of the opposite edge only when it lies within about 45 degrees of the
 * path (cos 45 deg = 0.707): beyond that, following the edge would turn the tear. (1) */
#define TC_FAR_END_COS 0.7
/* Directions a tip or a start tries, best first by the direction rule, when the remesh refuses the
 * better ones (a split below the minimum angle and no edge to snap to). */
#define TC_TEAR_DIRECTIONS 8
/* A tip never turns back on its own path: a direction is available only when its cosine with the
 * tip's last direction is above this. (1) */
#define TC_TIP_FORWARD_COS 0.0
/* Scripted tears steer back to their line: the lateral offset is corrected by this gain over the
 * distance already travelled (plus a softening length), so snapping errors do not accumulate. */
#define TC_STEER_GAIN 0.5
#define TC_STEER_SOFTENING 1e-3     /* m */
#define TC_SCRIPTED_MAX_CUTS 100000 /* cuts of one scripted tear: a guard against a path that loops */

/* ---- unconverged solves (step.c) ---- */
/* A sub-step whose solve stops at cg_max_iterations is rolled back and run as two halves, at most
 * this many times nested (so down to 1/8 of the sub-step): halving dt quarters the stiffness part
 * of A against its mass part, which is what slows block-Jacobi CG on stiff slivers. Deeper than
 * that the cap is too low for the mesh: the sub-step is accepted and counted in tc_stats. */
#define TC_SPLIT_DEPTH 3

/* ---- the matrix by rows (mesh.c, fem.c) ---- */
/* Zeros after the last edge block: the AVX2 product loads a block's last column 4 wide. (doubles) */
#define TC_ROW_SLACK 4

/* ---- woven sheets: axes and plasticity (ortho.c) ---- */
/* UVs whose Jacobian determinant is below this fraction of |grad u|^2 + |grad v|^2 carry no
 * direction (no UV map, or a triangle collapsed in UV space): the rest X axis is taken. (1) */
#define TC_UV_DEGENERATE 1e-9
/* Without UVs, a triangle whose rest normal has |n_x| above this (its plane nearly normal to X)
 * takes the rest Y axis instead of X. (1) */
#define TC_AXIS_FALLBACK_NX 0.9
/* Largest |grain angle| accepted per triangle (rad): any angle is meaningful modulo pi, this only
 * refuses garbage (an angle in degrees is below it, but a value of 1e6 is not an angle). */
#define TC_GRAIN_ANGLE_MAX 100.0
/* A triangle yields when its Hill stress passes the current yield stress by more than this
 * fraction of the warp yield stress (so a state just returned to the surface stays there). (1) */
#define TC_YIELD_TOLERANCE 1e-12
/* The return mapping's scalar equation is solved to this fraction of the warp yield stress, in at
 * most this many steps; a mapping stopped at the cap is counted (tc_stats.plastic_unconverged). */
#define TC_RETURN_TOLERANCE 1e-12
#define TC_RETURN_MAX_ITERATIONS 100

/* ---- the multigrid preconditioner (amg.c, solver.c) ---- */
#define TC_AMG_MAX_LEVELS 10
/* strength of connection: a block is strong when |A_ij|_F > theta sqrt(|A_ii|_F |A_jj|_F); small,
 * so aggregates are the vertex and its ring (the bending flaps are weak) */
#define TC_AMG_THETA 0.02
#define TC_AMG_COARSEST 120         /* unknowns at or below which a level is the coarsest */
#define TC_AMG_DENSE_MAX 1500       /* the coarsest level is factored when at most this big */
#define TC_AMG_COARSE_SWEEPS 4      /* else: this many damped Jacobi steps there */
#define TC_AMG_MIN_COARSENING 0.8   /* stop when a level keeps more than this fraction of rows */
#define TC_AMG_POWER_ITERATIONS 8   /* for rho(D^-1 A), the Jacobi damping */
#define TC_AMG_REAGGREGATE 100      /* numeric refreshes before the aggregates are built again */
/* Sub-steps between numeric refreshes (solver.c). Mean CPU per 1 ms step of a pinned 5,151-vertex
 * sheet: every sub-step 36-38 ms (5.5 iterations; aggregates too: 39.5 ms), every 4th 17.4 ms (6.0),
 * every 8th 12.6 ms (6.7), every 16th 15.7 ms (8.9); block Jacobi 19.2 ms (152 iterations). */
#define TC_AMG_REFRESH 1
/* numeric refreshes on one set of prolongators before they are made again (RESMOOTH) */
#define TC_AMG_RESMOOTH 8
/* ... or sooner, when a solve needs more than this factor (+2) times the iterations of the first
 * solve after the refresh: a held sheet pulled at 1 m/s went from 13 to 50 iterations one sub-step
 * after a refresh at rest (the tension it then carries changes the matrix most). */
#define TC_AMG_STALE_FACTOR 1.5
/* preconditioner "auto": the multigrid cycle when the work block Jacobi is predicted to need
 * exceeds the cycle's, i.e. when the stiffness ratio of the sub-step's matrix (solver.c: the median
 * over free vertices of (dt^2 + dt beta) k_ii / ((1 + dt alpha) m_i)) is at least this. Measured
 * (CPU, this machine): Jacobi takes ~2-3.5 sqrt(ratio) iterations (T-shirt 60 at dt 1 ms, ratio
 * 630; 153 at 4.17 ms, ratio 10,700; the square 130 at 10K triangles, ratio 4,800; 590 at 100K,
 * ratio 48,000) at ~65 us each on the T-shirt, while the cycle takes 11-23 iterations at ~5.5
 * Jacobi iterations each plus its refresh (~35 Jacobi iterations per sub-step at TC_AMG_REFRESH):
 * ~120-160 Jacobi iterations' worth, reached at ratio ~4,000. Interleaved on the T-shirt at dt
 * 4.17 ms (ratio 10,700) the cycle still lost, 8.7-8.8 vs 7.6-7.7 ms CPU per step (26 vs 174
 * iterations; 2.8-3.0 ms of it the hierarchy's refresh): the break-even there lies above 10,700
 * while the refresh costs what it does (open: raise this or cut the refresh). At dt 1 ms (ratio
 * 630) Jacobi 4.0 vs the cycle 5.4 ms. Both costs grow with the matrix alike, so the size drops
 * out of the rule but for tiny cloths: */
#define TC_AMG_AUTO_STIFFNESS 4000.0
/* ... below this many vertices a hierarchy has one coarse level at most and never pays. */
#define TC_AMG_AUTO_MIN_VERTICES 500

#endif
