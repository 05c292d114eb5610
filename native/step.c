/* step.c - one time step: tc_cloth_step runs `substeps` implicit Euler sub-steps, then tearing.
 *
 * One sub-step: with rotations R frozen at x0,
 *   ((1 + dt a) M + (dt^2 + dt b)(K + B)) v1 = M v0 + dt f(x0),  x1 = x0 + dt v1,
 * and when the triangles' frames turn far enough in it, solved once more about the frames turned to
 * where the solve took them (Newton on the rotations, below),
 * solved by conjugate gradients preconditioned with the inverse 3x3 diagonal blocks and warm-started
 * from the last velocity change (solver.c). Constraints enter as velocity filters (constraints.c):
 * pins and handles fix all three components, a contact fixes the normal one to the touched surface's
 * (inelastic). Each contact starts the sub-step as its vertex ended the last one (held, sliding
 * with kinetic friction, or released: constraints.c); after each solve, contacts whose reaction
 * would pull (adhesion) are released, held vertices whose static friction would need more than mu
 * times the normal reaction slide, and the system is solved once more (the rounds, below);
 * the solves that only guess the contact state stop at a looser tolerance, the one kept at cg_tolerance.
 * Penetration is recovered by a bounded extra normal speed inside the solve (contact_correction of
 * the depth per step, at most contact_max_push), taken back out of the velocity after the step, so
 * a vertex pushed out never keeps the speed to bounce away.
 *
 * A sub-step whose positions hold non-finite values or a stretch above max_stretch is rolled back
 * to where it started, and the step fails with TC_ERR_UNSTABLE (positions are never NaN). One whose
 * solve stopped at the iteration cap is rolled back and split in halves (span() below); what is
 * still unconverged after TC_SPLIT_DEPTH splits is accepted and counted in tc_stats.
 */
#include "core.h"

#include <math.h>
#include <string.h>

/* substep()'s outcome when its solve stopped at the iteration cap (internal to this file) */
enum { TC_UNCONVERGED = -1 };

void tc_refresh(tc_cloth *c)
{
    if (!c->dirty) return;
    tc_element_pass(c, tc_vec_ptr(&c->x));
    tc_total_force(c, tc_vec_ptr(&c->x));
    c->dirty = false;
}

/* Newton on the rotations. The system is linearized with each triangle's rotation frozen where
 * the sub-step began, and a frozen rotation reads a turn of theta as a stretch of about
 * 1 - cos(theta): a sheet spinning at 20 rad/s gained 9 % of its energy in one 2 ms step and kept a
 * tenth of its spin after half a second, a sheet falling into its pins at 4 sub-steps a frame
 * peaked at 40x the stress it reaches at 16, and a sheet of paper turning 0.1 rad in a sub-step
 * reads its tearing stress. After a solve, turned() estimates from v alone whether the turn could
 * move the forces past the bar (tc_turn_estimate: a hanging cloth's sub-steps and a third of Table
 * 1's pulled T-shirt's stop there, its FEM step 1.98 ms against 1.89 ms without any of this); if it could, it turns the frames to the polar rotations of
 * x0 + dt v (tc_turn_pass: the stress and its stiffness turn with the frame, the strain stays
 * x0's), adds the change of the linearized force to b, and says whether that change passes
 * TC_ROTATION_BAR of the solve's force scale (the weight, elastic and net forces the cloth
 * carries); if so, the sub-step is solved again from v about the turned frames (reassemble_turned;
 * b has turned already). Where there are contacts, they are judged again after it, as after any
 * solve of the rounds. The re-solve costs about a solve again (a sheet flap swinging down at 10 ms
 * with slivers: 340 + 800 CG iterations a step). Making the first solve a loose guess while the
 * cloth turns, confirmed about the turned frames, brought that under 1000, but then whether a sub-step
 * was solved about turned frames depended on the last one's bar, and the tear test of two tolerances
 * (test_solver.py) raced 8 tears against 5: not kept. The scratch sq is the change's (read here
 * only). */
static bool turned(tc_cloth *c, const double *x, const double *v, double dt, double *b, double fscale)
{
    const size_t n3 = 3 * (size_t)c->nv;
    const double bar2 = TC_ROTATION_BAR * TC_ROTATION_BAR * fscale * fscale;
    const double guess = tc_turn_estimate(c, v, dt);
    /* below the bar by the estimate (which read 2.3-10x the exact change on a falling sheet, a
       spinning one, a swinging flap and Table 1's T-shirt): frames left as they are, b and the
       matrix agreeing, and the pass saved */
    if (guess <= bar2) return false;
    double *dg = tc_vec_ptr(&c->sq);
    tc_turn_pass(c, x, v, dt, dg);
    for (size_t k = 0; k < n3; k++) b[k] += dt * dg[k];
    tc_constraint_filter(c, dg);  /* what held vertices would feel is not the cloth's to carry */
    double d2 = 0.0;
    for (size_t k = 0; k < n3; k++) d2 += dg[k] * dg[k];
    return d2 > bar2;  /* (a NaN: not, the step's check has it) */
}

static int reassemble_turned(tc_cloth *c, double dt, double alpha_target)
{
    if (tc_assemble(c, dt)) return TC_ERR_NOMEM;
    tc_pin_springs_add(c, dt, alpha_target, NULL);  /* the springs' matrix part; b has theirs */
    tc_precondition_build(c, dt);
    return TC_OK;
}

static int substep(tc_cloth *c, double dt, double alpha_target)
{
    const int32_t n = c->nv;
    const size_t n3 = 3 * (size_t)n;
    double *x = tc_vec_ptr(&c->x), *v = tc_vec_ptr(&c->v);
    /* b (the right-hand side) in `force`: read only to make b here, made again at the sub-step's
       end (and by a rollback's pass). x0 need not be copied: x stays where the sub-step began
       until its update below, which keeps a copy in sp first. Each had a vector of
       its own: 12 bytes per triangle each. */
    double *v0 = tc_vec_ptr(&c->v0), *b = tc_vec_ptr(&c->force);
    /* element state stale (first sub-step, after a tear, a yield, a setter): its pass and this
       sub-step's assembly share one pass over the triangles (the positions do not move between) */
    const bool fused = c->dirty;
    if (fused) {
        double worst;
        if (tc_element_assemble(c, x, dt, &worst)) return TC_ERR_NOMEM;
        tc_total_force(c, x);
        c->dirty = false;
    }
    memcpy(v0, v, n3 * sizeof(double));
    tc_constraints_begin(c, dt, alpha_target);
    const int32_t nc = (int32_t)c->cvert.len;
    /* before b takes the force's place: a failed assembly leaves the force as it was */
    if (!fused && tc_assemble(c, dt)) return TC_ERR_NOMEM;

    /* right-hand side M v0 + dt f(x0), and the kinetic friction of the vertices that slid */
    const double *m = tc_vec_ptr(&c->mass);
    for (int32_t i = 0; i < n; i++)
        for (int q = 0; q < 3; q++) b[3 * i + q] = m[i] * v0[3 * i + q] + dt * b[3 * i + q];
    if (nc) tc_contacts_kinetic_start(c, b, dt);
    tc_pin_springs_add(c, dt, alpha_target, b);  /* after the assembly, before the preconditioner's build */

    tc_precondition_build(c, dt);
    /* warm start: the velocity change of the last step (constant acceleration), exact for a
       falling cloth and close for any smooth motion; pcg projects it onto this step's constraints */
    const double *dv_prev = tc_vec_ptr(&c->sdv);
    for (size_t k = 0; k < n3; k++) v[k] = v0[k] + dv_prev[k];
    int it = 0, it2 = 0, turns = 0;
    /* With contacts, the solves that only guess their state (each one until a solve leaves it
       unchanged) stop at TC_CONTACT_GUESS_LOOSENESS times the tolerance: they only decide which
       contacts hold, slide or let go, and the state they settle on is then solved to the tolerance
       and judged again (the rounds below), as is every re-solve after that one. The kept velocity
       is always a solve to the tolerance. The race's shirt (issue 15): 584 -> 408 CG iterations
       per sub-step, penetration unchanged (constants.h). */
    const double tol = c->solver.cg_tolerance;
    double loose = nc ? fmax(tol, fmin(TC_CONTACT_GUESS_LOOSENESS * tol, TC_CONTACT_GUESS_TOLERANCE_MAX)) : tol;
    int converged = tc_solve_dv(c, v, v0, b, dt, loose, &it);
    int tight = loose == tol || c->solve_residual <= tol;  /* (an exact solve: all held, at rest) */
    c->stats.solves++;
    double res = c->solve_residual, resf = c->solve_residual_force, fscale = c->solve_force_scale;

    if (nc) {
        /* The contact rounds. Each solve is a guess of which contacts hold, slide or let go (the
           first one's from how they ended the last sub-step: tc_constraints_begin); after it,
           contacts whose reaction pulls are released, contacts guessed released that the solve
           drove into the surface come back, and held vertices whose static friction would need
           more than mu times the normal reaction slide (kinetic friction joins b, tangential, so
           the release test reads the same normal reactions); then the sub-step is solved again
           from this solution. Every re-solve to the tolerance costs about as much as the first
           (block-Jacobi CG needs ~130-300 iterations for any change on the T-shirt: a contact's
           reaction reaches across the whole membrane), hence the carried guess, and the looser
           guess solves (a re-solve at 10x the tolerance: ~14 iterations) until the state settles. */
        double *J = tc_vec_ptr(&c->sq);
        tc_matvec(c, v, J);
        for (int round = 0;; round++) {
            const int last = round == TC_CONTACT_ROUNDS;
            const int changed = tc_contacts_release(c, J, b, !last) + tc_contacts_touch(c, v, dt, !last);
            const int slid = tc_contacts_friction(c, J, v, b, dt, !last);
            if (last) {  /* said, left as solved (the last round's solve was to the tolerance) */
                c->stats.friction_cone_exceeded += slid;
                if (changed + slid) c->stats.contact_rounds_capped++;
                break;
            }
            c->stats.friction_slips += slid;
            if (!(changed + slid) && tight) {
                /* settled, to the tolerance: the frames turn, and when that moves the force past
                   the bar the sub-step is solved again about them (up to TC_ROTATION_SOLVES
                   times) and its contacts judged again */
                const bool far = turned(c, x, v, dt, b, fscale);
                if (!far || turns == TC_ROTATION_SOLVES) { c->stats.rotations_capped += far; break; }
                turns++;
                c->stats.rotation_solves++;
                if (reassemble_turned(c, dt, alpha_target)) return TC_ERR_NOMEM;
            }
            if (changed + slid) {
                tc_contact_basis(c, dt);
                tc_precondition_constraints_changed(c);
            }
            /* the settled state to the tolerance, and so is the last round's solve, whatever it
               changed: the velocity kept is always one solved to the tolerance */
            const int confirm = !(changed + slid) || round + 1 == TC_CONTACT_ROUNDS;
            if (confirm) loose = tol;  /* and every re-solve after it */
            converged &= tc_solve_dv(c, v, v0, b, dt, confirm ? tol : loose, &it2);
            tight = confirm || loose == tol || c->solve_residual <= tol;
            c->stats.solves++;
            it += it2;
            if (tight) { res = c->solve_residual; resf = c->solve_residual_force; fscale = c->solve_force_scale; }
            tc_matvec(c, v, J);
        }
        c->stats.contacts = tc_contacts_active(c);
    } else {
        c->stats.contacts = 0;
        for (;;) {
            const bool far = turned(c, x, v, dt, b, fscale);
            if (!far || turns == TC_ROTATION_SOLVES) { c->stats.rotations_capped += far; break; }
            turns++;
            c->stats.rotation_solves++;
            if (reassemble_turned(c, dt, alpha_target)) return TC_ERR_NOMEM;
            converged &= tc_solve_dv(c, v, v0, b, dt, tol, &it2);
            c->stats.solves++;
            it += it2;
            res = c->solve_residual; resf = c->solve_residual_force; fscale = c->solve_force_scale;
        }
    }
    /* straight after the rounds (it reads their scratch); a sub-step rolled back below leaves it
       as the next attempt's first guess, as it leaves its velocity change as the warm start */
    tc_contacts_carry(c);

    /* the solver's scratch is free from here (the carry above read the last of it) */
    double *x0 = tc_vec_ptr(&c->sp);
    memcpy(x0, x, n3 * sizeof(double));
    for (size_t k = 0; k < n3; k++) x[k] = x0[k] + dt * v[k];
    tc_contacts_take_back_push(c, v, dt);
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
        tc_total_force(c, x);
        tc_set_err(c, "step rolled back: %s (largest stretch %g, limit %g; CG %d iterations, residual %g). "
                      "Reduce the time step or raise sub-steps.",
                   worst == worst ? "exploding strain" : "non-finite values", worst, c->solver.max_stretch, it, res);
        return TC_ERR_UNSTABLE;
    }
    tc_total_force(c, x);
    c->stats.cg_iterations += it;  /* the work done, rolled-back attempts included */
    /* the worse of the sub-step's solves, for span() to report once the sub-step is kept */
    c->solve_residual = res; c->solve_residual_force = resf; c->solve_force_scale = fscale;
    return converged ? TC_OK : TC_UNCONVERGED;
}

static void report_kept(tc_cloth *c)
{
    if (c->solve_residual < c->stats.cg_residual) return;
    c->stats.cg_residual = c->solve_residual;
    c->stats.cg_residual_force = c->solve_residual_force;
    c->stats.cg_force_scale = c->solve_force_scale;
}

/* The sub-step from fraction a0 to a1 of the handles' motion. One whose solve did not converge is
 * rolled back to where it started and run as two halves, up to TC_SPLIT_DEPTH times nested; at
 * the deepest level it is accepted and counted (tc_stats.unconverged_substeps). */
static int span(tc_cloth *c, double dt, double a0, double a1, int depth)
{
    int rc = substep(c, dt, a1);
    /* plastic flow from the stresses of a kept sub-step only: a rolled-back one leaves no set */
    if (rc == TC_OK) { report_kept(c); c->stats.plastic_triangles += tc_plastic_commit(c); }
    if (rc != TC_UNCONVERGED) return rc;
    if (depth >= TC_SPLIT_DEPTH) {
        report_kept(c);
        c->stats.unconverged_substeps++;
        c->stats.plastic_triangles += tc_plastic_commit(c);
        return TC_OK;
    }
    const size_t n3 = 3 * (size_t)c->nv;
    double *x = tc_vec_ptr(&c->x), *v = tc_vec_ptr(&c->v), *dv = tc_vec_ptr(&c->sdv);
    memcpy(x, tc_vec_ptr(&c->sp), n3 * sizeof(double));  /* where the sub-step began (substep) */
    memcpy(v, tc_vec_ptr(&c->v0), n3 * sizeof(double));
    for (size_t k = 0; k < n3; k++) dv[k] *= 0.5;  /* the warm start of a step half as long */
    tc_element_pass(c, x);
    tc_total_force(c, x);
    c->stats.substep_splits++;
    const double am = 0.5 * (a0 + a1);
    rc = span(c, 0.5 * dt, a0, am, depth + 1);
    if (rc == TC_OK) rc = span(c, 0.5 * dt, am, a1, depth + 1);
    return rc;
}

int tc_cloth_step(tc_cloth *c, double dt, int substeps)
{
    if (!(dt > 0) || !isfinite(dt) || dt > 10.0) { tc_set_err(c, "time step must lie in (0, 10] s (got %g)", dt); return TC_ERR_INPUT; }
    if (substeps < 1 || substeps > 10000) { tc_set_err(c, "sub-steps must lie in [1, 10000] (got %d)", substeps); return TC_ERR_INPUT; }
    double t0 = tc_now();
    tc_events_clear(c);
    c->stats.cg_iterations = 0;
    c->stats.solves = 0;
    c->stats.sgs_solves = 0;
    c->stats.stiff_groups = 0;
    c->stats.cg_residual = 0.0;
    c->stats.cg_residual_force = 0.0;
    c->stats.cg_force_scale = 0.0;
    c->stats.substep_splits = 0;
    c->stats.unconverged_substeps = 0;
    c->stats.plastic_triangles = 0;
    c->stats.amg_setup_seconds = 0.0;
    double h = dt / substeps;
    int rc = TC_OK;
    for (int s = 0; s < substeps && rc == TC_OK; s++) rc = span(c, h, (double)s / substeps, (double)(s + 1) / substeps, 0);
    if (c->stats.unconverged_substeps) c->stats.unconverged_steps++;
    if (rc == TC_OK) {
        for (int32_t k = 0; k < c->nh; k++) memcpy(c->handles[k].prev, c->handles[k].target, 12 * sizeof(double));
        if (c->vgoal.len) memcpy(tc_vec_ptr(&c->vgoal0), tc_vec_ptr(&c->vgoal), 3 * (size_t)c->nv * sizeof(double));
    }
    tc_handle_forces(c);
    double t1 = tc_now();
    c->stats.fem_seconds = t1 - t0;
    c->stats.tear_seconds = 0.0;
    if (rc == TC_OK && c->tear.enabled) {
        rc = tc_tear_step(c, dt);
        c->stats.tear_seconds = tc_now() - t1;
    }
    c->stats.steps++;
    return rc;
}
