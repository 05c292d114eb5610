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
/* Re-solves of one sub-step that turn held contact vertices whose static friction is exceeded into
 * sliding ones, release pulling contacts and bring back lifted ones driven into the surface: the
 * load moves on to the next held row of a stiff cloth each round. What still changes after them is
 * left as solved, counted in tc_stats (friction_cone_exceeded: held vertices outside their cone;
 * contact_rounds_capped: the sub-steps). (solves) */
#define TC_CONTACT_ROUNDS 8
/* The stiffest soft pin spring accepted (N/m): far past any cloth's (a gram held to a micrometre
 * under 1000 g), a bound that keeps dt^2 k finite against the mass on the diagonal */
#define TC_PIN_SPRING_MAX 1e12
/* The solves of a sub-step with contacts that only guess the contact state (each one until a solve
 * leaves it unchanged) stop at this many times cg_tolerance (at most TC_CONTACT_GUESS_TOLERANCE_MAX);
 * the state they settle on is then solved to cg_tolerance and judged again, and every re-solve
 * after that one is solved to cg_tolerance. A guess decides only which contacts hold, slide or
 * let go, and a wrong one is corrected by the judgement after the tight solve. Race shirt (24
 * frames, 10 sub-steps, tolerance 1e-4), per sub-step: 584 CG iterations in 3.2 solves (every one
 * to the tolerance) -> 408 in 5.2 at 10x (first solve 296 -> ~110 iterations, a guess re-solve ~14,
 * the settled one ~135), 478 at 3x; no vertex inside the body either way, no round cap hit. The
 * bound keeps a guess within the loosest tolerance the solver rows accept as meaningful. (1) */
#define TC_CONTACT_GUESS_LOOSENESS 10.0
#define TC_CONTACT_GUESS_TOLERANCE_MAX 1e-2

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
/* ints a triangle the cache of material discs (tear.c) may hold at most: a disc of radius r on a
 * mesh of edge h holds ~2 pi r^2 / (0.43 h^2) triangles; 64 covers every vertex's disc up to
 * r ~ 2.3 h (~100 triangles), and only vertices whose disc stress is asked for get one */
#define TC_DISC_POOL_PER_TRIANGLE 64
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

/* ---- stiff groups (stiff.c) ---- */
/* The strength of an edge's block: its Frobenius norm over the geometric mean of its vertices'
 * diagonal blocks' (near 1 for a sliver's near-coincident corners). A mesh has slivers when some
 * block reaches TC_STIFF_SLIVER (1-degree slivers 0.962, 2-degree 0.923, a T-shirt cut 50 times
 * 0.876); then the pairs from TC_STIFF_STRENGTH are joined into groups. Measured: stiff.c's header
 * (TEARCLOTH_STIFF_STRENGTH overrides the joining strength, for that measurement). */
#define TC_STIFF_STRENGTH 0.3
#define TC_STIFF_SLIVER 0.94
/* ... and that block sits at a thin triangle: a corner under this many degrees at one of its two
 * vertices (rest angles). A strong block at a well-shaped triangle is not a sliver's: in the race
 * (the T-shirt pulled apart on the walking body, 48 frames of 10 sub-steps) a tear set free one
 * 3 mm triangle of 21, 21 and 137 degrees (tearing's min_angle_deg keeps corners over 10), whose
 * two lone corners reached 0.95 under its stretch. The groups then joined 277 pairs of the
 * stretched shirt, and those sub-steps took 198 CG iterations and 23.0 ms against 74 and 6.7 ms
 * for the sub-steps before them; the sweeps, forced, converged every one of them (78 iterations,
 * 7.3 ms over the last 60 sub-steps). Why 2 degrees: on the sliver sheet the groups take half the
 * time of the sweeps at 1 degree and the same at 2 (stiff.c's header). */
#define TC_STIFF_SLIVER_DEG 2.0
/* vertices of one group at most: its factor is (3k)^2 doubles, a solve 2 (3k)^2 multiply-adds */
#define TC_STIFF_GROUP_MAX 8
/* sub-steps between two looks for a sliver where the last found none (stiff.c) */
#define TC_STIFF_RESCAN 16

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
#define TC_AMG_COARSE_SWEEPS 4      /* else: this many symmetric Gauss-Seidel sweep pairs there */
#define TC_AMG_MIN_COARSENING 0.8   /* stop when a level keeps more than this fraction of rows */
/* The contact correction of the first coarse operator (amg.c, tc_amg_contacts): A_1 = P^T (S A S +
 * tau (I - S) d) P, tau this. tau = 0 is the Galerkin product of the coarse correction's own
 * prolongator S P, but a contact held in all three directions (S = 0) zeroes every mode of an
 * aggregate made of such vertices, and A_1's refresh-old base against the current rows leaves those
 * modes indefinite by the mismatch: the cycle broke down (test_amg's held contacts) at tau = 1e-3 and
 * 1e-4, not at 1e-2. tau = 1 is P^T A' P of the fine sweeps' operator, and damps the coarse
 * correction of the directions a contact takes away. Measured on test_cg_iterations_agree_across_
 * kernels's grid (325 vertices, a fifth of them contacts): relative residual force after 10 CG
 * iterations 1.6 uncorrected, 0.0094 at tau = 0, 0.0104 at 1e-2, 0.022 at 0.1, 0.056 at 1;
 * iterations to 1e-14: 38 / 38 / 41 / 49 (uncorrected: 1.4e-6 after 60). 0.1 keeps a 100x margin
 * over the breakdown for 3 more iterations than the optimum. */
#define TC_AMG_CONTACT_OFF_RANGE 0.1
/* The correction is made at every refresh of the coarse operators (before the coarser levels are
 * made from A_1, so once), when there is none (after a build, at the first contacts) and between
 * refreshes only when more contact vertices changed than there are contacts now (a direction count,
 * or the first direction turned by more than acos of TC_AMG_CONTACT_TURN_COS): the set was replaced.
 * Measured on the race's T-shirt at 20K triangles on the walking body (multigrid, 4 frames of 10
 * sub-steps, 168 contacts, four cloths stepped in turn), CG iterations and FEM ms per sub-step
 * (medians; means): uncorrected 67 / 65.1, 188 / 193 ms; again when a quarter of the contacts
 * changed 45 / 47.9, 166 / 166 ms (setup 35 ms); a half 48.5 / 50.8, 163 / 167; only at refreshes
 * and when none 43 / 48.7, 156 / 157 ms (setup 27 ms). The refreshes come every sub-step there
 * (solves of 16 iterations or more), every fourth at most: the correction is no older than the
 * coarse operators it corrects. */
#define TC_AMG_CONTACT_CHANGE 1.0
#define TC_AMG_CONTACT_TURN_COS 0.9
#define TC_AMG_POWER_ITERATIONS 8   /* for rho(D^-1 A), the prolongator's smoothing step */
#define TC_AMG_REAGGREGATE 100      /* builds (new prolongators) before the aggregates are made again */
/* Sub-steps between numeric refreshes of the coarse operators (solver.c): every TC_AMG_REFRESH
 * sub-steps, or every one when the last solve took at least TC_AMG_REFRESH_ITERATIONS iterations
 * (a refresh costs ~10 cycles on the kept prolongators: it pays sooner the more cycles a solve
 * runs). Interleaved, 10K-triangle square, CPU per step: at dt 1 ms (8.5-9.5 iterations) every
 * sub-step cost 9 % more than every 8th and every 4th the same as every 8th; at dt 4.17 ms (21
 * iterations fresh, 27 at every 4th or 8th) every sub-step was 8-10 % cheaper than every 4th or 8th. */
#define TC_AMG_REFRESH 4
#define TC_AMG_REFRESH_ITERATIONS 16
/* ... but not while the solves take this many iterations or fewer: a refresh cannot pay there (Table
 * I's banknote, near static under its slow pull, converges in one iteration from its warm start;
 * its refreshes every 4th sub-step were half its mean FEM time: 0.43 of 0.90 ms). A cycle that
 * weakens still gets one from the staleness rule below. */
#define TC_AMG_REFRESH_MIN_ITERATIONS 3
/* numeric refreshes on one set of prolongators before they are made again (RESMOOTH) */
#define TC_AMG_RESMOOTH 8
/* blocks of a coarse operator summed in double at a time by a refresh (counted in slots, lower ones
 * too; its transient buffer holds the run's upper blocks, about half: 288 bytes a block, 0.6 MB;
 * the operator itself is kept in float, upper blocks only). At 16384 (4.7 MB) a refresh of a
 * 100K-triangle cloth peaked 53 bytes per triangle over its steady state; at 4096, 16: a fine row
 * whose P reaches two runs is made once per run, and runs of 4096 blocks still hold most rows of
 * C's 53K (100K triangles: refresh time within the noise of two interleaved runs) */
#define TC_AMG_GALERKIN_BLOCKS 4096
/* ... or sooner: when a solve's residual falls by less than 1/this of the rate per iteration of the
 * first solve on the current prolongators (solver.c), the coarse operators are refreshed at the
 * next sub-step, and if the next solve is still that slow, the prolongators are made again. The
 * rate moves by up to 2x between healthy solves of one hierarchy (the residual's make-up:
 * 1.16-2.35 per iteration on the 10K square at dt 1 ms), so 1.5 rebuilt it every few sub-steps. */
#define TC_AMG_STALE_FACTOR 2.5
/* preconditioner "auto" (solver.c's choose_amg): the multigrid cycle when
 *     stiffness ratio x (vertices / TC_AMG_AUTO_VERTICES)^TC_AMG_AUTO_SIZE_EXPONENT >= TC_AMG_AUTO_STIFFNESS
 * on at least TC_AMG_AUTO_MIN_VERTICES vertices, the stiffness ratio being the median over free
 * vertices of (dt^2 + dt beta) k_ii / ((1 + dt alpha) m_i). Fitted to this table: CPU per step,
 * block Jacobi and the cycle interleaved in one process (mean of 5-30 steps after 2; both solves
 * converged except the one marked *), the bench's square cloth held by two corners and pulled at
 * 2 cm/s, and table1's T-shirt hung from its shoulders, one sub-step per step:
 *   cloth (vertices)  material  dt ms  ratio      Jacobi ms (it)    cycle ms (it)   cycle/Jacobi
 *   square (749)      cotton    1         666       1.93 (58)        2.00 (5)       1.03
 *                               2        2632       2.41 (85)        2.50 (7)       1.04
 *                               4.17    11308       3.66 (148)       4.14 (16)      1.13
 *                               8       41057       7.98 (311)       7.28 (24)      0.91
 *                     banknote  1       18285       2.72 (95)        3.12 (9)       1.15
 *                               2       72208       3.57 (145)       4.33 (15)      1.21
 *                               4.17   310281       5.43 (181)       5.94 (21)      1.09
 *                               8     1126596       7.49 (286)       9.16 (35)      1.22
 *   T-shirt (1703)    cotton    1         630       6.30 (86)        8.63 (12)      1.37
 *                               2        2487       9.32 (146)      13.18 (16)      1.41
 *                               4.17    10685      12.18 (218)      15.36 (22)      1.26
 *                               8       38798      22.24 (320)      24.63 (31)      1.11
 *                     banknote  1       17279      17.70 (284)      20.19 (29)      1.14
 *                               2       68233      24.16 (304)      23.52 (27)      0.97
 *                               4.17   ~290000     39.44 (380)      26.11 (33)      0.66
 *                               8     ~1070000     51.67 (682)      31.49 (45)      0.61
 *   square (5149)     cotton    1        4834      33.30 (152)      21.04 (9)       0.63
 *                               2       19089      52.85 (232)      35.14 (14)      0.66
 *                               4.17    82028      88.41 (374)      63.38 (20)      0.72
 *                               8      297834     110.52 (480)      72.12 (27)      0.65
 *                     banknote  1      132663      65.22 (282)      37.13 (14)      0.57
 *                               2      523882     111.69 (488)      56.28 (19)      0.50
 *                               4.17  2251132     180.77 (627)      79.98 (34)      0.44
 *                               8     8173623     423.33 (1905)    107.36 (45)      0.25
 *   square (15161)    cotton    1       14351     258.02 (303)      88.14 (10)      0.34
 *                               2       56673     323.06 (372)     120.05 (13)      0.37
 *                               4.17   243528     591.31 (491)     235.75 (17)      0.40
 *                               8      884223     672.13 (776)     360.92 (19)      0.54
 *                     banknote  1      393974     437.81 (360)     111.23 (10)      0.25
 *                               2     1555794     918.60 (821)     194.44 (16)      0.21
 *                               4.17  6685280    1719.48 (2544)    222.03 (26)      0.13
 *                               8   ~24000000    8039.58 (8601*)   260.48 (30)      0.03
 * (ratios from the same meshes at the same dt; ~ where a stepped state was not at hand: the
 * cotton ratio x 27.5, the banknote's E / rho over cotton's). The size enters beyond the ratio:
 * at one ratio the 5149-vertex square gains 1.6x from the cycle where the T-shirt loses 1.3x, so
 * the bar falls steeply with the vertices; the 749-vertex square never gains more than 9 %. With
 * the rule below every point picks the faster one but the 749-vertex square at ratio 41,057
 * (block Jacobi, 1.10x the cycle's time); the T-shirt's banknote at dt 2 ms (multigrid, 3 % faster)
 * is the closest call. */
#define TC_AMG_AUTO_STIFFNESS 50000.0
#define TC_AMG_AUTO_VERTICES 1700.0
#define TC_AMG_AUTO_SIZE_EXPONENT 2.5
/* ... below this many vertices block Jacobi always (the cycle's coarse levels cost as much as the
 * fine one) */
#define TC_AMG_AUTO_MIN_VERTICES 1000
/* the cycle, once picked, is kept until the measure falls below the bar over this */
#define TC_AMG_AUTO_HYSTERESIS 1.25

/* Newton on the rotations (step.c). A sub-step is solved again about its triangles' frames turned
 * to where its solve took them when that turn moves the linearized force by more than
 * TC_ROTATION_BAR of the forces the cloth carries (the solve's own force scale), at most
 * TC_ROTATION_SOLVES times; what is still above the bar after them is kept and counted
 * (rotations_capped). Measured (one run each, the same machine):
 *   - a 20 cm sheet spinning at 20 rad/s, undamped, no gravity: the change is 100 % of the force
 *     scale and more at every step (the spurious stretch is all the force there is); one re-solve
 *     takes the first step's energy gain from +9 % to -0.1 % and the spin kept after 0.5 s from 10 %
 *     to 75 % (dt 2 ms);
 *   - Table 1's T-shirt at 1 ms: 1-16 % (median 5 %); re-solving it at a bar of 0.1 cost 2 more CG
 *     iterations a step (20 -> 22), at 0.3 none;
 *   - the race's shirt on the walking body (dt 4.17 ms): 0.143 s a frame at 0.3 against 0.142 without
 *     the turn and 0.156 at 0.1;
 *   - a sheet falling into its pins at 4 sub-steps a frame: the first frame's peak stress 0.66 MPa
 *     without, 0.058 MPa with the turn at 0.1 or 0.3 (0.015 at 16 sub-steps, either way).
 * Further re-solves do not converge where cloth is compressed (its geometric stiffness keeps
 * only the tensile stress, so the turned compression is not in the tangent): a second and third
 * gave no better peak there, so one it is. */
#define TC_ROTATION_BAR 0.3
#define TC_ROTATION_SOLVES 1
/* tc_turn_estimate's count of triangles whose force changes add up at one vertex (a regular mesh's
 * six) */
#define TC_TURN_VALENCE 6.0
/* the largest turn of one triangle's frame in one sub-step that tc_turn_pass follows (cos 60 deg) */
#define TC_TURN_MAX_COS 0.5

#endif
