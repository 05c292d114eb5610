/* solver.c - the linear solve of one implicit Euler sub-step: conjugate gradients on the constraint
 * manifold (the filtered PCG of Baraff & Witkin 1998), preconditioned with symmetric block
 * Gauss-Seidel sweeps of the filtered matrix in Eisenstat's form (below the multigrid cycle's bar,
 * or asked for), the inverse 3x3 diagonal blocks (block Jacobi: asked for, or where the sweeps' row
 * split could not be made) or, on stiff or large cloths, a smoothed-aggregation multigrid V-cycle
 * (amg.c),
 * warm-started, solved for the velocity change rather than the velocity,
 * stopped by a residual force small against the forces the cloth carries, with the momentum balance
 * of a free cloth made exact by a correction along the translations.
 *
 * The solver only needs the matrix's product (fem.c's tc_matvec over the rows of core.h) and its
 * diagonal blocks, and the constraint filter (constraints.c).
 */
#include "core.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Whether this cloth's solves use the multigrid cycle: chosen once per sub-step, in
 * tc_precondition_build (choose_amg), and read by the solves and the contact rounds after it. */
static bool use_amg(const tc_cloth *c) { return c->amg_chosen; }

/* Whether a solve uses the symmetric Gauss-Seidel sweeps (below) rather than block Jacobi: when
 * asked for, and under AUTO below the multigrid cycle's bar. Measured interleaved in one process
 * (the FEM part of the step, medians over 180 steps, the sweeps in the vertices' own order):
 *   - the race's shirt on the walking body, dt 4.17 ms, contacts on most sub-steps: CG iterations
 *     per sub-step 400 -> 109 (median), our CPU per frame 0.318 -> 0.219 s (0.69x) with the
 *     sweeps of that time; the present ones take 0.78x the FEM time per frame of the 8-chunk
 *     order before them (0.085-0.096 s against 0.110-0.130 s, three runs each, 99 -> 102
 *     iterations);
 *   - no contact (Table 1's scenes pulled by their hands, the shirt hung by its shoulders),
 *     Gauss-Seidel / Jacobi step time at dt 1 ms and 4.17 ms: square cloth 1.00 and 0.84 (16 -> 6,
 *     42 -> 14 iterations), banknote 0.84 and 0.85, T-shirt 0.92 and 0.91 (50 -> 20, 137 -> 57).
 *     Block Jacobi kept these solves until the sweeps dropped the chunks and half the diagonal
 *     reads (1.06x at the shirt's 1 ms then).
 * The multigrid bar was fitted against block Jacobi's time (constants.h); the sweeps' 0.85-0.92x
 * would move it up a little, not refitted. The sweeps' memory is two ints per vertex (the rows
 * keep their own order, mesh.c), so the choice needs no memory rule. */
static bool use_sgs(const tc_cloth *c)
{
    const int pre = c->solver.preconditioner;
    return pre == TC_PRECOND_SGS || (pre == TC_PRECOND_AUTO && !c->amg_chosen && !tc_stiff_groups(c->stiff));  /* (groups: tc_precondition_build) */
}

/* k-th smallest of v[0..n) (quickselect; v is reordered) */
static double select_kth(double *v, int32_t n, int32_t k)
{
    int32_t lo = 0, hi = n - 1;
    while (lo < hi) {
        const double pivot = v[lo + (hi - lo) / 2];
        int32_t i = lo, j = hi;
        while (i <= j) {
            while (v[i] < pivot) i++;
            while (v[j] > pivot) j--;
            if (i <= j) { const double t = v[i]; v[i] = v[j]; v[j] = t; i++; j--; }
        }
        if (k <= j) hi = j;
        else if (k >= i) lo = i;
        else return v[k];
    }
    return v[k];
}

/* The stiffness ratio of the sub-step's matrix: the median over the free vertices of
 * tr(A_ii) / (3 (1 + dt alpha) m_i) - 1, i.e. (dt^2 + dt beta) k_ii / m_i, the stiffness a vertex
 * feels in one sub-step against its inertia (it grows with dt^2 and, at a fixed sheet, with the
 * square of the mesh's refinement). Block-Jacobi CG needs about 2-3.5 sqrt(ratio) iterations
 * (constants.h); the multigrid cycle about ten whatever the ratio. Scratch: the solver's sz. */
static double stiffness_ratio(tc_cloth *c)
{
    const double *D = tc_vec_ptr(&c->diag), *m = tc_vec_ptr(&c->mass);
    const int8_t *fl = tc_vec_ptr(&c->vflag);
    double *q = tc_vec_ptr(&c->sz);
    int32_t n = 0;
    for (int32_t i = 0; i < c->nv; i++) {
        if (fl[i] == VC_PINNED || fl[i] == VC_HANDLE || !(m[i] > 0)) continue;
        const double *d = D + 12 * (size_t)i;
        q[n++] = (d[0] + d[5] + d[10]) / (3.0 * c->mass_scale * m[i]) - 1.0;
    }
    if (!n) return 0.0;
    const double r = select_kth(q, n, n / 2);
    return isfinite(r) ? r : 0.0;
}

/* AUTO: the multigrid cycle when block Jacobi is predicted to cost more: its iterations grow with
 * sqrt(stiffness ratio), and its cost per iteration against the cycle's falls behind as the cloth
 * grows (the coarse levels' share of a cycle shrinks, the matrix leaves the cache), so the measure is
 * the stiffness ratio times (vertices / TC_AMG_AUTO_VERTICES)^TC_AMG_AUTO_SIZE_EXPONENT against
 * TC_AMG_AUTO_STIFFNESS (constants.h: the measured table it was fitted to), on cloths of at least
 * TC_AMG_AUTO_MIN_VERTICES vertices. Hysteresis: the cycle, once picked, is kept down to
 * 1/TC_AMG_AUTO_HYSTERESIS of the bar, so a cloth near it does not rebuild a hierarchy every few
 * sub-steps as its tension moves the ratio. The history lives in the hierarchy's object, which a
 * snapshot clears (tc_amg_forget), as a resumed run starts without one. */
static bool choose_amg(tc_cloth *c)
{
    if (c->solver.preconditioner == TC_PRECOND_JACOBI || c->solver.preconditioner == TC_PRECOND_SGS) return false;
    if (c->solver.preconditioner == TC_PRECOND_AMG) return true;
    if (c->nv < TC_AMG_AUTO_MIN_VERTICES) return false;
    const double measure = stiffness_ratio(c) * pow((double)c->nv / TC_AMG_AUTO_VERTICES, TC_AMG_AUTO_SIZE_EXPONENT);
    if (!c->amg) c->amg = tc_amg_new();  /* small until built: it holds the history */
    const double bar = tc_amg_choice(c->amg) == 1 ? TC_AMG_AUTO_STIFFNESS / TC_AMG_AUTO_HYSTERESIS : TC_AMG_AUTO_STIFFNESS;
    const bool amg = measure >= bar;
    tc_amg_set_choice(c->amg, amg);
    return amg;
}

/* Sub-steps between numeric refreshes of the hierarchy (TC_AMG_REFRESH) and refreshes between new
 * prolongators (TC_AMG_RESMOOTH); the TEARCLOTH_AMG_REFRESH and TEARCLOTH_AMG_RESMOOTH environment
 * variables override them, for the bench's comparison of the reuse policies (read at each sub-step,
 * so two cloths of one process can be compared; 0 for REFRESH means a whole build, aggregates too,
 * every sub-step). */
static int env_count(const char *name, int fallback)
{
    const char *e = getenv(name);
    const int v = e ? atoi(e) : fallback;
    return v >= 0 && v <= 100000 ? v : fallback;
}

static void amg_prepare(tc_cloth *c)
{
    if (!use_amg(c)) {
        /* block Jacobi or the sweeps: the hierarchy's memory goes back (a switch back rebuilds it); "auto" keeps
           the empty object for its history */
        if (c->solver.preconditioner == TC_PRECOND_AUTO) {
            tc_amg_drop(c->amg);
        } else {
            tc_amg_free(c->amg);
            c->amg = NULL;
        }
        c->stats.amg_levels = 0;
        c->stats.amg_bytes = 0;
        return;
    }
    const double t0 = tc_now();
    if (!c->amg) c->amg = tc_amg_new();
    if (!c->amg) { c->stats.amg_fallbacks++; return; }
    /* TEARCLOTH_AMG_CONTACTS: the bench's comparison of amg.c's contact correction (0 off) */
    tc_amg_follow_contacts(c->amg, env_count("TEARCLOTH_AMG_CONTACTS", 1) != 0);
    const int every = env_count("TEARCLOTH_AMG_REFRESH", TC_AMG_REFRESH);
    const int resmooth = env_count("TEARCLOTH_AMG_RESMOOTH", TC_AMG_RESMOOTH);
    if (tc_amg_levels(c->amg) == 0 || !tc_amg_valid(c->amg, c) || tc_amg_needs_aggregation(c->amg, c) || every == 0 ||
        (c->amg_stale && c->amg_stale_refreshed) || tc_amg_refreshes(c->amg) >= resmooth) {
        /* new prolongators (and aggregates when due): after a tear, new pins or handles, a cycle
           that stayed weak after a refresh, or every TC_AMG_RESMOOTH refreshes (the near-null
           space follows the cloth's rotations) */
        if (tc_amg_build(c->amg, c, every == 0)) c->stats.amg_fallbacks++;
        c->amg_age = 0;
        c->amg_stale = false;
        c->amg_stale_refreshed = false;
        c->amg_fresh_rate = 0.0;
    } else if (c->amg_stale || (c->amg_last_iterations > TC_AMG_REFRESH_MIN_ITERATIONS &&
                                c->amg_age + 1 >= (c->amg_last_iterations >= TC_AMG_REFRESH_ITERATIONS ? 1 : every))) {
        /* a weak cycle is first refreshed (a third of a build: at 100K triangles a build after
           every slow solve of the first, accelerating sub-steps doubled their cost) */
        if (tc_amg_refresh(c->amg, c)) c->stats.amg_fallbacks++;
        if (c->amg_stale) c->amg_stale_refreshed = true;
        c->amg_stale = false;
        c->amg_age = 0;
    } else {
        c->amg_age++;
    }
    c->stats.amg_levels = tc_amg_levels(c->amg);
    c->stats.amg_bytes = (int64_t)tc_amg_bytes(c->amg);
    c->stats.amg_setup_seconds += tc_now() - t0;
}

/* The inverse of a diagonal block d (padded columns, core.h) into o (9, by rows). The block is
 * symmetric up to the assembly's rounding: taken exactly symmetric, its inverse by cofactors is
 * exactly symmetric too (the same products on both sides), so the AVX2 passes can read its rows as
 * its columns. */
static void block_inverse(const double *d, double *o)
{
    const double a01 = 0.5 * (d[4] + d[1]), a02 = 0.5 * (d[8] + d[2]), a12 = 0.5 * (d[9] + d[6]);
    const double a[9] = {d[0], a01, a02, a01, d[5], a12, a02, a12, d[10]};
    double c00 = a[4] * a[8] - a[5] * a[7], c01 = a[5] * a[6] - a[3] * a[8], c02 = a[3] * a[7] - a[4] * a[6];
    double det = a[0] * c00 + a[1] * c01 + a[2] * c02;
    if (!(fabs(det) > TC_SINGULAR_DET)) {  /* cannot happen with positive masses; stay safe */
        memset(o, 0, 9 * sizeof(double));
        return;
    }
    double id = 1.0 / det;
    o[0] = c00 * id; o[1] = (a[2] * a[7] - a[1] * a[8]) * id; o[2] = (a[1] * a[5] - a[2] * a[4]) * id;
    o[3] = c01 * id; o[4] = (a[0] * a[8] - a[2] * a[6]) * id; o[5] = (a[2] * a[3] - a[0] * a[5]) * id;
    o[6] = c02 * id; o[7] = (a[1] * a[6] - a[0] * a[7]) * id; o[8] = (a[0] * a[4] - a[1] * a[3]) * id;
}

/* The preconditioner: the inverse of each vertex's 3x3 diagonal block of A (block Jacobi, and the
 * multigrid cycle's smoother), then the hierarchy when the multigrid cycle is in use. */
void tc_precondition_build(tc_cloth *c, double dt)
{
    const double *D = tc_vec_ptr(&c->diag);
    double *P = tc_vec_ptr(&c->pinv);
    for (int32_t i = 0; i < c->nv; i++) block_inverse(D + 12 * (size_t)i, P + 9 * (size_t)i);
    /* Stiff groups (stiff.c) for block Jacobi, asked for or auto's: where a mesh has slivers, auto
       takes block Jacobi with the groups over both the sweeps (which cannot take a sliver's stiff
       mode out) and the multigrid cycle (its aggregates and Gauss-Seidel smoothing do not either).
       Measured against the build before the groups (auto then took the sweeps or the cycle), a
       sheet with 0.23-0.46-degree slivers hung by one edge (tearcloth.bench.slivers), per step:
       756 vertices at dt 2 ms 5595 CG iterations and 300 halvings in 100 steps against 141 and
       none, 28.3 s against 1.1 s for the 100 steps; at 10 ms 103 sub-steps stopped at the cap in 20
       steps against none; 5,832 vertices, where auto took the cycle: 9.05 s a 2 ms step (5745
       iterations) against 0.133 s (229), and at 10 ms 20.5 s with 12 sub-steps at the cap in 5
       steps against 0.19 s with none. */
    const int pre = c->solver.preconditioner;
    if (pre == TC_PRECOND_JACOBI || pre == TC_PRECOND_AUTO) {
        if (tc_stiff_build(c, dt)) tc_stiff_clear(c->stiff);  /* out of memory: vertex blocks alone */
        const int32_t groups = tc_stiff_groups(c->stiff);
        if (groups > c->stats.stiff_groups) c->stats.stiff_groups = groups;
    } else {
        tc_stiff_clear(c->stiff);
    }
    c->amg_chosen = pre == TC_PRECOND_AUTO && tc_stiff_groups(c->stiff) ? false : choose_amg(c);
    if (!use_sgs(c)) {
        /* the sweeps' split goes back with them (a return finds it again) */
        tc_sgs_free(c->sgs);
        c->sgs = NULL;
    }
    amg_prepare(c);
}

/* The constraints changed within a sub-step (contacts released or sliding, step.c). Block Jacobi
 * filters with the current S, but its stiff groups' factors are of the filtered block, made again
 * here; the Gauss-Seidel sweeps make their contact rows' filtered inverses at each solve
 * (sgs_constrain), and the multigrid cycle's fine Gauss-Seidel sweeps solve the filtered system
 * exactly while its coarse operators, made with contact vertices free, stay a valid (symmetric
 * positive) coarse correction whatever the contacts (amg.c). */
void tc_precondition_constraints_changed(tc_cloth *c)
{
    if (tc_stiff_groups(c->stiff)) tc_stiff_refactor(c);
}

void tc_precondition_snapshot(const tc_cloth *c)
{
    tc_amg_forget(c->amg);
    tc_stiff_forget(c->stiff);
}

static void precondition(const tc_cloth *c, const double *r, double *z)
{
    const double *P = tc_vec_ptr(&c->pinv);
    for (int32_t i = 0; i < c->nv; i++) {
        const double *p = P + 9 * i, *x = r + 3 * i;
        double *o = z + 3 * i;
        o[0] = p[0] * x[0] + p[1] * x[1] + p[2] * x[2];
        o[1] = p[3] * x[0] + p[4] * x[1] + p[5] * x[2];
        o[2] = p[6] * x[0] + p[7] * x[1] + p[8] * x[2];
    }
}

/* v += alpha p, r -= alpha q, z = P r, and r.z, r.r, in one pass over the vertices (the dots with
 * two accumulators each: one serialises on the add latency).
 *
 * `held` (NULL when the filter is applied outside, around the pass) is vflag when no vertex is a
 * contact: then the filter S only zeroes the pinned and handle vertices (all three components), and
 * the pass does it itself, so an iteration needs no filter pass (two tc_constraint_filter calls, a
 * loop over every vertex's flag each, were ~6 % of an iteration with 40 pins). For a held vertex
 * S q = 0, so r stays 0 (r is on the range of S) and z = P 0 = 0: the values the filtered pass
 * gives. */
TC_HOT static void update_precondition_c(const tc_cloth *c, double alpha, const double *restrict p, const double *restrict q,
                                         double *restrict v, double *restrict r, double *restrict z, const int8_t *held,
                                         double *rz_out, double *rr_out)
{
    const double *restrict P = tc_vec_ptr(&c->pinv);
    double rz0 = 0.0, rz1 = 0.0, rr0 = 0.0, rr1 = 0.0;
    for (int32_t i = 0; i < c->nv; i++) {
        const size_t o = 3 * (size_t)i;
        const double *m = P + 9 * (size_t)i;
        v[o] += alpha * p[o]; v[o + 1] += alpha * p[o + 1]; v[o + 2] += alpha * p[o + 2];
        if (held && held[i] != VC_FREE) { z[o] = z[o + 1] = z[o + 2] = 0.0; continue; }
        const double r0 = r[o] - alpha * q[o], r1 = r[o + 1] - alpha * q[o + 1], r2 = r[o + 2] - alpha * q[o + 2];
        r[o] = r0; r[o + 1] = r1; r[o + 2] = r2;
        const double z0 = m[0] * r0 + m[1] * r1 + m[2] * r2;
        const double z1 = m[3] * r0 + m[4] * r1 + m[5] * r2;
        const double z2 = m[6] * r0 + m[7] * r1 + m[8] * r2;
        z[o] = z0; z[o + 1] = z1; z[o + 2] = z2;
        if (i & 1) { rz1 += r0 * z0 + r1 * z1 + r2 * z2; rr1 += r0 * r0 + r1 * r1 + r2 * r2; }
        else { rz0 += r0 * z0 + r1 * z1 + r2 * z2; rr0 += r0 * r0 + r1 * r1 + r2 * r2; }
    }
    *rz_out = rz0 + rz1;
    *rr_out = rr0 + rr1;
}

#if (defined(__x86_64__) || defined(_M_X64)) && (defined(__GNUC__) || defined(__clang__))
#include <immintrin.h>
/* one vertex of the pass below, for the vertices its groups of four leave */
__attribute__((target("avx2,fma"))) static inline void update_vertex(const double *restrict P, double alpha,
                                                                     const double *restrict p, const double *restrict q,
                                                                     double *restrict v, double *restrict r,
                                                                     double *restrict z, const int8_t *held, int32_t i,
                                                                     double *rz, double *rr)
{
    const size_t o = 3 * (size_t)i;
    const double *m = P + 9 * (size_t)i;
    for (int k = 0; k < 3; k++) v[o + k] += alpha * p[o + k];
    if (held && held[i] != VC_FREE) { z[o] = z[o + 1] = z[o + 2] = 0.0; return; }
    double rk[3];
    for (int k = 0; k < 3; k++) {
        rk[k] = r[o + k] - alpha * q[o + k];
        r[o + k] = rk[k];
    }
    for (int k = 0; k < 3; k++) {
        z[o + k] = m[3 * k] * rk[0] + m[3 * k + 1] * rk[1] + m[3 * k + 2] * rk[2];
        *rz += rk[k] * z[o + k];
        *rr += rk[k] * rk[k];
    }
}

/* The same pass with AVX2 + FMA (when fem.c's product runs its AVX2 kernel: the CPU has them), four
 * vertices at a time: their twelve components are three full vectors, so v, r and r.r go four
 * lanes wide with no padding lane (a vector per vertex wasted a quarter of every load, store and
 * multiply-add, and stored each vertex in two pieces); z = P r is three multiply-adds per vertex of
 * broadcast components of the r just stored (P is exactly symmetric, tc_precondition_build, so its
 * rows are its columns), and the four z are merged back into three vectors for their stores and for
 * r.z: 8.2-8.5 -> 6.1-6.4 us a pass on the T-shirt (interleaved, one process). */
__attribute__((target("avx2,fma"))) static void update_precondition_avx2(const tc_cloth *c, double alpha,
                                                                         const double *restrict p, const double *restrict q,
                                                                         double *restrict v, double *restrict r,
                                                                         double *restrict z, const int8_t *held,
                                                                         double *rz_out, double *rr_out)
{
    const double *restrict P = tc_vec_ptr(&c->pinv);
    const __m256d a = _mm256_set1_pd(alpha);
    __m256d rz0 = _mm256_setzero_pd(), rz1 = _mm256_setzero_pd(), rr0 = _mm256_setzero_pd(), rr1 = _mm256_setzero_pd();
    /* P's third row of a group's last vertex is a 4-lane load that reads the next vertex's first
       value (a lane nothing keeps), so the groups stop one vertex short of the end: the last one to
       four vertices are done in scalar code after the loop */
    double rz = 0.0, rr = 0.0;
    int32_t i = 0;
    for (; i + 4 < c->nv; i += 4) {
        const size_t o = 3 * (size_t)i;
        uint32_t flags = 0;
        if (held) memcpy(&flags, held + i, sizeof flags);
        if (flags) {  /* a held vertex among the four: these four one by one */
            for (int32_t u = i; u < i + 4; u++) update_vertex(P, alpha, p, q, v, r, z, held, u, &rz, &rr);
            continue;
        }
        __m256d rv[3];
        for (int k = 0; k < 3; k++) {
            const size_t ok = o + 4 * (size_t)k;
            _mm256_storeu_pd(v + ok, _mm256_fmadd_pd(a, _mm256_loadu_pd(p + ok), _mm256_loadu_pd(v + ok)));
            rv[k] = _mm256_fnmadd_pd(a, _mm256_loadu_pd(q + ok), _mm256_loadu_pd(r + ok));
            _mm256_storeu_pd(r + ok, rv[k]);
        }
        __m256d zv[4];
        for (int u = 0; u < 4; u++) {
            const double *m = P + 9 * (size_t)(i + u), *ru = r + o + 3 * (size_t)u;
            __m256d t = _mm256_mul_pd(_mm256_loadu_pd(m), _mm256_broadcast_sd(ru));
            t = _mm256_fmadd_pd(_mm256_loadu_pd(m + 3), _mm256_broadcast_sd(ru + 1), t);
            zv[u] = _mm256_fmadd_pd(_mm256_loadu_pd(m + 6), _mm256_broadcast_sd(ru + 2), t);
        }
        /* (z0 z1 z2 | z0' z1' z2' | ...) back into three vectors of four */
        const __m256d f0 = _mm256_blend_pd(zv[0], _mm256_permute4x64_pd(zv[1], 0x00), 0x8);
        const __m256d f1 = _mm256_blend_pd(_mm256_permute4x64_pd(zv[1], 0x09), _mm256_permute4x64_pd(zv[2], 0x40), 0xC);
        const __m256d f2 = _mm256_blend_pd(_mm256_permute4x64_pd(zv[2], 0x02), _mm256_permute4x64_pd(zv[3], 0x90), 0xE);
        _mm256_storeu_pd(z + o, f0);
        _mm256_storeu_pd(z + o + 4, f1);
        _mm256_storeu_pd(z + o + 8, f2);
        if ((i >> 2) & 1) {
            rz1 = _mm256_fmadd_pd(rv[0], f0, _mm256_fmadd_pd(rv[1], f1, _mm256_fmadd_pd(rv[2], f2, rz1)));
            rr1 = _mm256_fmadd_pd(rv[0], rv[0], _mm256_fmadd_pd(rv[1], rv[1], _mm256_fmadd_pd(rv[2], rv[2], rr1)));
        } else {
            rz0 = _mm256_fmadd_pd(rv[0], f0, _mm256_fmadd_pd(rv[1], f1, _mm256_fmadd_pd(rv[2], f2, rz0)));
            rr0 = _mm256_fmadd_pd(rv[0], rv[0], _mm256_fmadd_pd(rv[1], rv[1], _mm256_fmadd_pd(rv[2], rv[2], rr0)));
        }
    }
    for (; i < c->nv; i++) update_vertex(P, alpha, p, q, v, r, z, held, i, &rz, &rr);
    double t[4];
    _mm256_storeu_pd(t, _mm256_add_pd(rz0, rz1));
    *rz_out = (t[0] + t[1]) + (t[2] + t[3]) + rz;
    _mm256_storeu_pd(t, _mm256_add_pd(rr0, rr1));
    *rr_out = (t[0] + t[1]) + (t[2] + t[3]) + rr;
}
#define TC_HAVE_AVX2_PASS 1
#endif

static void update_precondition(const tc_cloth *c, double alpha, const double *restrict p, const double *restrict q,
                                double *restrict v, double *restrict r, double *restrict z, const int8_t *held,
                                double *rz_out, double *rr_out)
{
#ifdef TC_HAVE_AVX2_PASS
    if (tc_simd_level() == TC_SIMD_AVX2) {
        update_precondition_avx2(c, alpha, p, q, v, r, z, held, rz_out, rr_out);
        return;
    }
#endif
    update_precondition_c(c, alpha, p, q, v, r, z, held, rz_out, rr_out);
}

static double dotn(const double *a, const double *b, size_t n)
{
    /* four accumulators: a single one serialises on the add latency (4x slower here) */
    double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
    size_t i = 0;
    for (; i + 4 <= n; i += 4) { s0 += a[i] * b[i]; s1 += a[i + 1] * b[i + 1]; s2 += a[i + 2] * b[i + 2]; s3 += a[i + 3] * b[i + 3]; }
    for (; i < n; i++) s0 += a[i] * b[i];
    return (s0 + s1) + (s2 + s3);
}

/* PCG with the multigrid cycle as the preconditioner: the same iteration with z = M^-1 r by a
 * V-cycle (a symmetric positive operator on the range of S, amg.c), which costs several products,
 * so the passes are not fused. Continues from v, r (the residual of v) where pcg() set them up.
 * Returns the iterations, or -1 - iterations when the cycle broke down (r.z <= 0 or not finite:
 * a hierarchy from an older matrix can lose definiteness) and block Jacobi must finish. */
static int pcg_amg(tc_cloth *c, double *v, double stop2, double *rr_inout)
{
    const size_t n3 = 3 * (size_t)c->nv;
    double *r = tc_vec_ptr(&c->sr), *z = tc_vec_ptr(&c->sz), *p = tc_vec_ptr(&c->sp), *q = tc_vec_ptr(&c->sq);
    double rr = *rr_inout;
    /* q is free while the cycle runs (read only between a product and the update): the cycle keeps
       its fine residual there (amg.c) */
    double rz = tc_amg_apply(c, c->amg, r, z);
    memcpy(p, z, n3 * sizeof(double));
    int it = 0;
    while (it < c->solver.cg_max_iterations && rr > stop2) {
        if (!(rz > 0) || !isfinite(rz)) { *rr_inout = rr; return -1 - it; }
        const double pq = tc_matvec(c, p, q);
        tc_constraint_filter(c, q);
        if (!(pq > 0)) break;
        const double alpha = rz / pq;
        double r0 = 0.0, r1 = 0.0;
        for (size_t k = 0; k < n3; k += 3) {
            v[k] += alpha * p[k]; v[k + 1] += alpha * p[k + 1]; v[k + 2] += alpha * p[k + 2];
            r[k] -= alpha * q[k]; r[k + 1] -= alpha * q[k + 1]; r[k + 2] -= alpha * q[k + 2];
            r0 += r[k] * r[k] + r[k + 2] * r[k + 2];
            r1 += r[k + 1] * r[k + 1];
        }
        rr = r0 + r1;
        it++;
        if (rr <= stop2) break;
        const double rz2 = tc_amg_apply(c, c->amg, r, z);
        const double beta = rz2 / rz;
        for (size_t k = 0; k < n3; k++) p[k] = z[k] + beta * p[k];
        rz = rz2;
    }
    *rr_inout = rr;
    return it;
}

/* ---------------- symmetric block Gauss-Seidel, by Eisenstat's trick ----------------
 *
 * The preconditioner M = (D + L) D^-1 (D + U) of the block splitting A = L + D + U (the symmetric
 * Gauss-Seidel sweep pair): on the T-shirt at dt = 1 ms its CG needs about 21 iterations a step
 * where block Jacobi needs 51 (the same stopping rule). Applied as M^-1 r it would cost two sweeps
 * over the matrix besides the product; Eisenstat (1981) runs CG on the split system C^-1 A C^-T
 * (C = D + L, C^T = D + U) preconditioned by D instead (M^-1 = C^-T D C^-1), whose product is
 *   C^-1 A C^-T p = t + C^-1 (p - D t),  t = C^-T p,
 * one backward sweep over the upper blocks and one forward sweep over the lower ones: together the
 * bytes of one product. The velocity gains alpha t an iteration (v = C^-T v^, and t = C^-T p is at
 * hand); the split residual is r^ = C^-1 r, and the true one, r = C r^ (a product with the lower
 * blocks), is taken when the split one scaled by the last ratio of the two says the stop is near,
 * so the physical stopping rule is tested on the true residual force, as for block Jacobi.
 *
 * The order: the vertices' own numbering, one stream over the rows as the product reads them. The
 * pattern keeps every row's lower slots first (mesh.c), so a sweep reads its half of a row as one
 * range of the rows themselves: what the sweeps add to block Jacobi's memory is two ints per vertex
 * (where each row's upper half starts). (The first version ran the rows by levels of the natural
 * order, through a copy of the matrix in that order: +330 bytes per triangle. The next one took the
 * vertices in 8 contiguous chunks, one row of each in turn, so that rows side by side in the sweep
 * were independent and the CPU could overlap their latencies; measured on the 2-core AMD EPYC
 * machines, 1 MB of L2 a core, the sweeps are bound by streaming the ~1.4 MB the rows, diagonal
 * blocks and inverses take from L3, not by the chain of rows, and eight streams cost more than they
 * hid: the race's shirt (dt 4.17 ms, contacts, same build otherwise, three runs each) 0.097-0.100 s
 * of FEM per frame with 8 chunks against 0.075-0.084 s in the natural order, 99 and 102 median CG
 * iterations per sub-step.)
 *
 * The constraints (Baraff-Witkin's filter S, S_i = I - sum n n^T over a contact's normals, 0 for a
 * pin or handle): the sweeps are those of the filtered matrix A~ = S A S + (I - S), symmetric
 * positive definite, whose block splitting gives a symmetric positive preconditioner that maps the
 * range of S into itself; on that range A~ is the filtered operator CG solves. With every vector
 * of the sweeps kept in the range of S, S_i A_ij S_j x_j = S_i A_ij x_j, so the off-diagonal
 * blocks are read as stored and only the contact rows change: their inverse diagonal block is that
 * of S_i A_ii S_i + w_i (I - S_i) (written over pinv for the solve, sgs_constrain; w_i > 0 scales
 * the held directions, which the filter keeps apart: tc_filtered_diagonal), and their results are
 * filtered. Pins and handles (S_i = 0) are rows whose values stay zero, skipped. */
struct tc_sgs {
    uint64_t version;  /* the rows_version the split was found for, the vertex and slot counts */
    int32_t nv, ne, nf;
    int32_t *lu, *lfu;  /* per vertex: the first slot of its row's upper part (edges, flaps) */
};

void tc_sgs_free(tc_sgs *g)
{
    if (!g) return;
    free(g->lu); free(g->lfu);
    free(g);
}

size_t tc_sgs_bytes(const tc_sgs *g) { return g ? sizeof *g + 2 * sizeof(int32_t) * (size_t)g->nv : 0; }

/* The split of the current rows; -1 when out of memory, or when a row is not lower slots first
 * (cannot happen: mesh.c builds them so and a snapshot's older rows are built again): block Jacobi */
static int sgs_prepare(tc_cloth *c)
{
    tc_sgs *g = c->sgs;
    const int32_t nv = c->nv;
    const int32_t *rp = tc_vec_ptr(&c->rptr), *rc = tc_vec_ptr(&c->rcol), *fp = tc_vec_ptr(&c->fptr), *fc = tc_vec_ptr(&c->fcol);
    /* the slot counts too: a split must never index rows it was not found for */
    if (g && g->version == c->rows_version && g->nv == nv && g->ne == rp[nv] && g->nf == fp[nv]) return 0;
    tc_sgs_free(g);
    c->sgs = g = calloc(1, sizeof *g);
    if (!g) return -1;
    g->lu = malloc(sizeof(int32_t) * ((size_t)nv + 1));
    g->lfu = malloc(sizeof(int32_t) * ((size_t)nv + 1));
    bool ok = g->lu && g->lfu;
    for (int32_t i = 0; ok && i < nv; i++) {
        g->lu[i] = tc_row_upper_start(rc, rp[i], rp[i + 1], i);
        g->lfu[i] = tc_row_upper_start(fc, fp[i], fp[i + 1], i);
        ok = g->lu[i] >= 0 && g->lfu[i] >= 0;
    }
    if (!ok) {
        tc_sgs_free(g);
        c->sgs = NULL;
        return -1;
    }
    g->version = c->rows_version;
    g->nv = nv; g->ne = rp[nv]; g->nf = fp[nv];
    return 0;
}

/* What the sweeps read: the rows, the upper parts' starts, the diagonal blocks and their inverses
 * (the filtered ones at contact rows), the constraint kinds and contact normals */
typedef struct sgs_rows {
    const double *D, *P, *RB, *FV, *N;
    const int32_t *rp, *rc, *fp, *fc, *lu, *lfu;
    const int8_t *fl, *cnt;
    int32_t nv;
} sgs_rows;

static sgs_rows sgs_view(const tc_cloth *c)
{
    const tc_sgs *g = c->sgs;
    return (sgs_rows){tc_vec_ptr(&c->diag), tc_vec_ptr(&c->pinv), tc_vec_ptr(&c->rblk), tc_vec_ptr(&c->fval),
                      tc_vec_ptr(&c->snorm), tc_vec_ptr(&c->rptr), tc_vec_ptr(&c->rcol), tc_vec_ptr(&c->fptr),
                      tc_vec_ptr(&c->fcol), g->lu, g->lfu, tc_vec_ptr(&c->vflag), tc_vec_ptr(&c->scount), c->nv};
}

/* x := S_i x at a contact row (the filter of constraints.c, one vertex) */
static inline void sgs_filter(const sgs_rows *m, int32_t i, double *x)
{
    for (int k = 0; k < m->cnt[i]; k++) {
        const double *e = m->N + 9 * (size_t)i + 3 * k;
        const double d = x[0] * e[0] + x[1] * e[1] + x[2] * e[2];
        x[0] -= d * e[0]; x[1] -= d * e[1]; x[2] -= d * e[2];
    }
}

/* The contact rows' inverse diagonal blocks for this solve (filtered = true: of S A_ii S + I - S,
 * written over pinv), or back to block Jacobi's (false), computed as tc_precondition_build does */
static void sgs_constrain(tc_cloth *c, bool filtered)
{
    const int8_t *fl = tc_vec_ptr(&c->vflag);
    const double *D = tc_vec_ptr(&c->diag);
    double *P = tc_vec_ptr(&c->pinv);
    for (int32_t i = 0; i < c->nv; i++) {
        if (fl[i] != VC_CONTACT) continue;
        const double *d = D + 12 * (size_t)i;
        if (!filtered) { block_inverse(d, P + 9 * (size_t)i); continue; }
        double S[9], A[9], F[9], f[12] = {0};
        tc_constraint_matrix(c, i, S);
        for (int a = 0; a < 3; a++)
            for (int b = 0; b < 3; b++) A[3 * a + b] = d[4 * b + a];  /* padded columns to rows */
        tc_filtered_diagonal(S, A, F);
        for (int a = 0; a < 3; a++)
            for (int b = 0; b < 3; b++) f[4 * b + a] = F[3 * a + b];
        block_inverse(f, P + 9 * (size_t)i);
    }
}

/* a[0..3) += the blocks of slots [e0, e1) and flaps [f0, f1) times x at their columns */
static inline void sgs_row_sum(const sgs_rows *m, int32_t e0, int32_t e1, int32_t f0, int32_t f1, const double *restrict x,
                               double a[3])
{
    double a0 = 0.0, a1 = 0.0, a2 = 0.0, b0 = 0.0, b1 = 0.0, b2 = 0.0;
    for (int32_t e = e0; e < e1; e++) {
        const double *b = m->RB + 9 * (size_t)e, *xj = x + 3 * (size_t)m->rc[e];
        a0 += b[0] * xj[0] + b[3] * xj[1] + b[6] * xj[2];
        a1 += b[1] * xj[0] + b[4] * xj[1] + b[7] * xj[2];
        a2 += b[2] * xj[0] + b[5] * xj[1] + b[8] * xj[2];
    }
    for (int32_t e = f0; e < f1; e++) {
        const double f = m->FV[e], *xj = x + 3 * (size_t)m->fc[e];
        b0 += f * xj[0]; b1 += f * xj[1]; b2 += f * xj[2];
    }
    a[0] += a0 + b0; a[1] += a1 + b1; a[2] += a2 + b2;
}

static inline void sgs_lower_sum(const sgs_rows *m, int32_t i, const double *restrict x, double a[3])
{
    sgs_row_sum(m, m->rp[i], m->lu[i], m->fp[i], m->lfu[i], x, a);
}

static inline void sgs_upper_sum(const sgs_rows *m, int32_t i, const double *restrict x, double a[3])
{
    sgs_row_sum(m, m->lu[i], m->rp[i + 1], m->lfu[i], m->fp[i + 1], x, a);
}

/* o = A_ii x from the diagonal block (columns padded to 4) */
static inline void apply_diag(const double *d, const double x[3], double *o)
{
    o[0] = d[0] * x[0] + d[4] * x[1] + d[8] * x[2];
    o[1] = d[1] * x[0] + d[5] * x[1] + d[9] * x[2];
    o[2] = d[2] * x[0] + d[6] * x[1] + d[10] * x[2];
}

static inline void apply_pinv(const double *p, const double r[3], double *o)
{
    o[0] = p[0] * r[0] + p[1] * r[1] + p[2] * r[2];
    o[1] = p[3] * r[0] + p[4] * r[1] + p[5] * r[2];
    o[2] = p[6] * r[0] + p[7] * r[1] + p[8] * r[2];
}

/* The sweeps' order: vertex 0, 1, ... (forward) or the reverse */
#define SGS_FORWARD(m, i, ...) for (int32_t i = 0; i < (m)->nv; i++) { __VA_ARGS__ }
#define SGS_BACKWARD(m, i, ...) for (int32_t i = (m)->nv - 1; i >= 0; i--) { __VA_ARGS__ }

/* x = C^-1 x in place ((D + L) y = x): a row reads only lower neighbours (final by then) and its
 * own value. Held rows are zero. */
TC_HOT static void sgs_forward_inplace(const sgs_rows *m, double *restrict x)
{
    SGS_FORWARD(m, i, {
        double *xi = x + 3 * (size_t)i;
        if (m->fl[i] == VC_PINNED || m->fl[i] == VC_HANDLE) { xi[0] = xi[1] = xi[2] = 0.0; continue; }
        double a[3] = {0.0, 0.0, 0.0};
        sgs_lower_sum(m, i, x, a);
        const double y[3] = {xi[0] - a[0], xi[1] - a[1], xi[2] - a[2]};
        apply_pinv(m->P + 9 * (size_t)i, y, xi);
        if (m->fl[i] == VC_CONTACT) sgs_filter(m, i, xi);
    })
}

/* Row i of the backward sweep of an iteration, with the new direction made just before it is
 * read: p_i = S_i D_i r^_i + beta p_i (first: S_i D_i r^_i), then t_i from (D + U) t = p. D r^ is
 * read from dr, where the update pass that made r^ left it (it needs it for r^.D r^): the sweep
 * then streams 24 bytes a vertex instead of the 96 of the diagonal block. */
static inline void sgs_backward_row(const sgs_rows *m, int32_t i, const double *restrict dr, double beta, bool first,
                                    double *restrict p, double *restrict t)
{
    const size_t o = 3 * (size_t)i;
    const int8_t f = m->fl[i];
    if (f == VC_PINNED || f == VC_HANDLE) { p[o] = p[o + 1] = p[o + 2] = 0.0; t[o] = t[o + 1] = t[o + 2] = 0.0; return; }
    double z[3] = {dr[o], dr[o + 1], dr[o + 2]};
    if (f == VC_CONTACT) sgs_filter(m, i, z);
    if (first) { p[o] = z[0]; p[o + 1] = z[1]; p[o + 2] = z[2]; }
    else { p[o] = z[0] + beta * p[o]; p[o + 1] = z[1] + beta * p[o + 1]; p[o + 2] = z[2] + beta * p[o + 2]; }
    double a[3] = {0.0, 0.0, 0.0};
    sgs_upper_sum(m, i, t, a);
    const double y[3] = {p[o] - a[0], p[o + 1] - a[1], p[o + 2] - a[2]};
    apply_pinv(m->P + 9 * (size_t)i, y, t + o);
    if (f == VC_CONTACT) sgs_filter(m, i, t + o);
}

/* Row i of the forward sweep of an iteration: u_i from (D + L) u = p - D t; returns
 * p_i.(t_i + u_i). At a free row the inverse block is D_i's own, so
 * u_i = D_i^-1 (p_i - D_i t_i - (L u)_i) = D_i^-1 (p_i - (L u)_i) - t_i: the diagonal block is not
 * read (96 bytes a vertex of the sweep's stream); a contact row's inverse is that of the filtered
 * block, so there D_i t_i is applied as written. */
static inline double sgs_forward_row(const sgs_rows *m, int32_t i, const double *restrict p, const double *restrict t,
                                     double *restrict u)
{
    const size_t o = 3 * (size_t)i;
    const int8_t f = m->fl[i];
    if (f == VC_PINNED || f == VC_HANDLE) { u[o] = u[o + 1] = u[o + 2] = 0.0; return 0.0; }
    const double *ti = t + o;
    double a[3] = {0.0, 0.0, 0.0}, s[3];
    if (f != VC_FREE) apply_diag(m->D + 12 * (size_t)i, ti, a);
    sgs_lower_sum(m, i, u, a);
    const double y[3] = {p[o] - a[0], p[o + 1] - a[1], p[o + 2] - a[2]};
    apply_pinv(m->P + 9 * (size_t)i, y, s);
    if (f == VC_FREE) {  /* s = t_i + u_i */
        for (int k = 0; k < 3; k++) u[o + k] = s[k] - ti[k];
        return p[o] * s[0] + p[o + 1] * s[1] + p[o + 2] * s[2];
    }
    for (int k = 0; k < 3; k++) u[o + k] = s[k];
    sgs_filter(m, i, u + o);  /* a contact row (held rows returned above) */
    return p[o] * (ti[0] + u[o]) + p[o + 1] * (ti[1] + u[o + 1]) + p[o + 2] * (ti[2] + u[o + 2]);
}

/* Row i of S C r^ (C = D + L): returns its square, and with `store` it replaces r^_i */
static inline double sgs_unsplit_row(const sgs_rows *m, int32_t i, double *restrict rh, bool store)
{
    double *x = rh + 3 * (size_t)i;
    const int8_t f = m->fl[i];
    if (f == VC_PINNED || f == VC_HANDLE) return 0.0;  /* zero */
    double a[3];
    apply_diag(m->D + 12 * (size_t)i, x, a);
    sgs_lower_sum(m, i, rh, a);
    if (f == VC_CONTACT) sgs_filter(m, i, a);
    if (store) { x[0] = a[0]; x[1] = a[1]; x[2] = a[2]; }
    return a[0] * a[0] + a[1] * a[1] + a[2] * a[2];
}

/* The backward sweep of an iteration, from the last rank (a row's higher neighbours are later) */
TC_HOT static void sgs_backward_c(const sgs_rows *m, const double *restrict dr, double beta, bool first,
                                  double *restrict p, double *restrict t)
{
    SGS_BACKWARD(m, i, { sgs_backward_row(m, i, dr, beta, first, p, t); })
}

/* The forward sweep of an iteration; returns p.(t + u) = p^T (C^-1 A C^-T) p */
TC_HOT static double sgs_forward_c(const sgs_rows *m, const double *restrict p, const double *restrict t,
                                   double *restrict u)
{
    double pq0 = 0.0, pq1 = 0.0;
    SGS_FORWARD(m, i, {
        const double pq = sgs_forward_row(m, i, p, t, u);
        if (i & 1) pq1 += pq; else pq0 += pq;
    })
    return pq0 + pq1;
}

/* |S C r^|^2, the true residual's square from the split one; with `store`, S C r^ replaces r^ (from
 * the last rank: a row reads lower neighbours, not yet replaced) */
TC_HOT static double sgs_unsplit_c(const sgs_rows *m, double *restrict rh, bool store)
{
    double s0 = 0.0, s1 = 0.0;
    SGS_BACKWARD(m, i, {
        const double q = sgs_unsplit_row(m, i, rh, store);
        if (i & 1) s1 += q; else s0 += q;
    })
    return s0 + s1;
}

#ifdef TC_HAVE_AVX2_PASS
/* A vertex's three values as lanes 0-2 (lane 3 zero) by a 2-lane and a 1-lane load, and stored
 * the same way: a sweep reads values that rows just before it wrote, and a 4-lane access there
 * overlaps two of those stores (or part of one), which the CPU cannot forward: it waits for them to
 * retire (a 4-lane load-blend-store per row made the sweeps 2x slower per byte than the product). */
__attribute__((target("avx2,fma"))) static inline __m256d load3_avx2(const double *x)
{
    return _mm256_insertf128_pd(_mm256_castpd128_pd256(_mm_loadu_pd(x)), _mm_load_sd(x + 2), 1);
}

__attribute__((target("avx2,fma"))) static inline void store3_avx2(double *x, __m256d v)
{
    _mm_storeu_pd(x, _mm256_castpd256_pd128(v));
    _mm_store_sd(x + 2, _mm256_extractf128_pd(v, 1));
}

/* The sweeps with AVX2 + FMA, a row as fem.c's product reads one: each block column (a 4-lane load;
 * its fourth lane, the next column's first value, is never kept) times the broadcast component of
 * the neighbour, two blocks and two flaps at a time into six accumulators. The last vertex (whose
 * 4-lane loads would pass the vectors) takes the scalar row. Contact and held rows run here too, a
 * contact's filter in the lanes (filter_avx2): in the race (shirt on the walking body) ~10 % of the
 * rows are contacts, and as scalar rows they took 40 % of the sweeps' time, their scalar stores
 * stalling the next rows' vector loads. */
__attribute__((target("avx2,fma"))) static inline __m256d sgs_row_avx2(const sgs_rows *m, int32_t e, int32_t e1,
                                                                        int32_t f, int32_t f1, const double *restrict x,
                                                                        __m256d a0)
{
    __m256d a1 = _mm256_setzero_pd(), a2 = _mm256_setzero_pd(), a3 = _mm256_setzero_pd();
    __m256d a4 = _mm256_setzero_pd(), a5 = _mm256_setzero_pd();
    const int32_t *bc = m->rc, *fc = m->fc;
    const double *b = m->RB + 9 * (size_t)e;
    for (; e + 1 < e1; e += 2, b += 18) {
        const double *xj = x + 3 * (size_t)bc[e], *xk = x + 3 * (size_t)bc[e + 1];
        a0 = _mm256_fmadd_pd(_mm256_loadu_pd(b), _mm256_broadcast_sd(xj), a0);
        a1 = _mm256_fmadd_pd(_mm256_loadu_pd(b + 3), _mm256_broadcast_sd(xj + 1), a1);
        a2 = _mm256_fmadd_pd(_mm256_loadu_pd(b + 6), _mm256_broadcast_sd(xj + 2), a2);
        a3 = _mm256_fmadd_pd(_mm256_loadu_pd(b + 9), _mm256_broadcast_sd(xk), a3);
        a4 = _mm256_fmadd_pd(_mm256_loadu_pd(b + 12), _mm256_broadcast_sd(xk + 1), a4);
        a5 = _mm256_fmadd_pd(_mm256_loadu_pd(b + 15), _mm256_broadcast_sd(xk + 2), a5);
    }
    if (e < e1) {
        const double *xj = x + 3 * (size_t)bc[e];
        a0 = _mm256_fmadd_pd(_mm256_loadu_pd(b), _mm256_broadcast_sd(xj), a0);
        a1 = _mm256_fmadd_pd(_mm256_loadu_pd(b + 3), _mm256_broadcast_sd(xj + 1), a1);
        a2 = _mm256_fmadd_pd(_mm256_loadu_pd(b + 6), _mm256_broadcast_sd(xj + 2), a2);
    }
    for (; f + 1 < f1; f += 2) {
        a3 = _mm256_fmadd_pd(_mm256_broadcast_sd(m->FV + f), load3_avx2(x + 3 * (size_t)fc[f]), a3);
        a4 = _mm256_fmadd_pd(_mm256_broadcast_sd(m->FV + f + 1), load3_avx2(x + 3 * (size_t)fc[f + 1]), a4);
    }
    if (f < f1) a5 = _mm256_fmadd_pd(_mm256_broadcast_sd(m->FV + f), load3_avx2(x + 3 * (size_t)fc[f]), a5);
    return _mm256_add_pd(_mm256_add_pd(_mm256_add_pd(a0, a1), _mm256_add_pd(a2, a3)), _mm256_add_pd(a4, a5));
}

/* A_ii x (diagonal block, columns padded with zeros) and D_i^-1 y (symmetric: its rows are its
 * columns; the third one's load reads the next vertex's first value into lane 3, never kept) */
__attribute__((target("avx2,fma"))) static inline __m256d diag_avx2(const double *d, __m256d x)
{
    __m256d a = _mm256_mul_pd(_mm256_loadu_pd(d), _mm256_permute4x64_pd(x, 0x00));
    a = _mm256_fmadd_pd(_mm256_loadu_pd(d + 4), _mm256_permute4x64_pd(x, 0x55), a);
    return _mm256_fmadd_pd(_mm256_loadu_pd(d + 8), _mm256_permute4x64_pd(x, 0xAA), a);
}

__attribute__((target("avx2,fma"))) static inline __m256d pinv_avx2(const double *P, __m256d y)
{
    __m256d a = _mm256_mul_pd(_mm256_loadu_pd(P), _mm256_permute4x64_pd(y, 0x00));
    a = _mm256_fmadd_pd(_mm256_loadu_pd(P + 3), _mm256_permute4x64_pd(y, 0x55), a);
    return _mm256_fmadd_pd(_mm256_loadu_pd(P + 6), _mm256_permute4x64_pd(y, 0xAA), a);
}

/* S_i x at a contact row (sgs_filter) in the lanes: its result stays in a register for the AVX2
 * store, so the next rows' 2-lane loads of it are forwarded from one store, not from three scalar
 * ones (which the CPU cannot forward: the load waits for them to retire) */
__attribute__((target("avx2,fma"))) static inline __m256d filter_avx2(const sgs_rows *m, int32_t i, __m256d x)
{
    for (int k = 0; k < m->cnt[i]; k++) {
        const __m256d e = load3_avx2(m->N + 9 * (size_t)i + 3 * k);
        const __m256d pr = _mm256_mul_pd(x, e);
        __m128d d = _mm_add_pd(_mm256_castpd256_pd128(pr), _mm256_extractf128_pd(pr, 1));
        d = _mm_add_sd(d, _mm_unpackhi_pd(d, d));
        x = _mm256_fnmadd_pd(_mm256_broadcastsd_pd(d), e, x);
    }
    return x;
}

__attribute__((target("avx2,fma"))) static void sgs_backward_avx2(const sgs_rows *m, const double *restrict dr,
                                                                   double beta, bool first, double *restrict p,
                                                                   double *restrict t)
{
    const int32_t last = m->nv - 1;
    const __m256d bv = _mm256_set1_pd(beta);
    SGS_BACKWARD(m, i, {
        const int8_t f = m->fl[i];
        if (i == last) { sgs_backward_row(m, i, dr, beta, first, p, t); continue; }
        const size_t o = 3 * (size_t)i;
        if (f == VC_PINNED || f == VC_HANDLE) {  /* zero, stored as the lanes are read */
            store3_avx2(p + o, _mm256_setzero_pd());
            store3_avx2(t + o, _mm256_setzero_pd());
            continue;
        }
        __m256d pv = load3_avx2(dr + o);
        if (f == VC_CONTACT) pv = filter_avx2(m, i, pv);  /* sgs_backward_row's contact row */
        if (!first) pv = _mm256_fmadd_pd(bv, load3_avx2(p + o), pv);
        store3_avx2(p + o, pv);
        const __m256d a = sgs_row_avx2(m, m->lu[i], m->rp[i + 1], m->lfu[i], m->fp[i + 1], t, _mm256_setzero_pd());
        const __m256d ti = pinv_avx2(m->P + 9 * (size_t)i, _mm256_sub_pd(pv, a));
        store3_avx2(t + o, f == VC_CONTACT ? filter_avx2(m, i, ti) : ti);
    })
}

__attribute__((target("avx2,fma"))) static double sgs_forward_avx2(const sgs_rows *m, const double *restrict p,
                                                                    const double *restrict t, double *restrict u)
{
    const int32_t last = m->nv - 1;
    const __m256d keep = _mm256_castsi256_pd(_mm256_set_epi64x(0, -1, -1, -1));
    __m256d pq0 = _mm256_setzero_pd(), pq1 = _mm256_setzero_pd();
    double pq = 0.0;
    SGS_FORWARD(m, i, {
        const int8_t f = m->fl[i];
        if (i == last) { pq += sgs_forward_row(m, i, p, t, u); continue; }
        const size_t o = 3 * (size_t)i;
        if (f == VC_PINNED || f == VC_HANDLE) { store3_avx2(u + o, _mm256_setzero_pd()); continue; }
        const __m256d tv = load3_avx2(t + o), pv = load3_avx2(p + o);
        if (f == VC_CONTACT) {
            /* sgs_forward_row's contact row: u_i = S_i Dc_i^-1 (p_i - A_ii t_i - (L u)_i) */
            const __m256d a = sgs_row_avx2(m, m->rp[i], m->lu[i], m->fp[i], m->lfu[i], u, diag_avx2(m->D + 12 * (size_t)i, tv));
            const __m256d uv = filter_avx2(m, i, pinv_avx2(m->P + 9 * (size_t)i, _mm256_sub_pd(pv, a)));
            store3_avx2(u + o, uv);
            const __m256d w = _mm256_and_pd(_mm256_mul_pd(pv, _mm256_add_pd(tv, uv)), keep);
            if (i & 1) pq1 = _mm256_add_pd(pq1, w); else pq0 = _mm256_add_pd(pq0, w);
            continue;
        }
        /* sgs_forward_row's free row: u_i = D_i^-1 (p_i - (L u)_i) - t_i, t_i + u_i = that inverse's
           result */
        const __m256d a = sgs_row_avx2(m, m->rp[i], m->lu[i], m->fp[i], m->lfu[i], u, _mm256_setzero_pd());
        const __m256d sv = pinv_avx2(m->P + 9 * (size_t)i, _mm256_sub_pd(pv, a));
        store3_avx2(u + o, _mm256_sub_pd(sv, tv));
        const __m256d w = _mm256_and_pd(_mm256_mul_pd(pv, sv), keep);
        if (i & 1) pq1 = _mm256_add_pd(pq1, w); else pq0 = _mm256_add_pd(pq0, w);
    })
    double s[4];
    _mm256_storeu_pd(s, _mm256_add_pd(pq0, pq1));
    return (s[0] + s[1]) + (s[2] + s[3]) + pq;
}

__attribute__((target("avx2,fma"))) static double sgs_unsplit_avx2(const sgs_rows *m, double *restrict rh, bool store)
{
    const int32_t last = m->nv - 1;
    const __m256d keep = _mm256_castsi256_pd(_mm256_set_epi64x(0, -1, -1, -1));
    __m256d s0 = _mm256_setzero_pd(), s1 = _mm256_setzero_pd();
    double q = 0.0;
    SGS_BACKWARD(m, i, {
        const int8_t f = m->fl[i];
        if (f == VC_PINNED || f == VC_HANDLE) continue;  /* zero, as sgs_unsplit_row */
        if (i == last) { q += sgs_unsplit_row(m, i, rh, store); continue; }
        const size_t o = 3 * (size_t)i;
        __m256d a = _mm256_and_pd(
            sgs_row_avx2(m, m->rp[i], m->lu[i], m->fp[i], m->lfu[i], rh, diag_avx2(m->D + 12 * (size_t)i, load3_avx2(rh + o))),
            keep);
        if (f == VC_CONTACT) a = filter_avx2(m, i, a);
        if (store) store3_avx2(rh + o, a);
        if (i & 1) s1 = _mm256_fmadd_pd(a, a, s1); else s0 = _mm256_fmadd_pd(a, a, s0);
    })
    double s[4];
    _mm256_storeu_pd(s, _mm256_add_pd(s0, s1));
    return (s[0] + s[1]) + (s[2] + s[3]) + q;
}
#endif

static void sgs_backward(const sgs_rows *m, const double *restrict dr, double beta, bool first, double *restrict p,
                         double *restrict t)
{
#ifdef TC_HAVE_AVX2_PASS
    if (tc_simd_level() == TC_SIMD_AVX2) { sgs_backward_avx2(m, dr, beta, first, p, t); return; }
#endif
    sgs_backward_c(m, dr, beta, first, p, t);
}

static double sgs_forward(const sgs_rows *m, const double *restrict p, const double *restrict t, double *restrict u)
{
#ifdef TC_HAVE_AVX2_PASS
    if (tc_simd_level() == TC_SIMD_AVX2) return sgs_forward_avx2(m, p, t, u);
#endif
    return sgs_forward_c(m, p, t, u);
}

static double sgs_unsplit(const sgs_rows *m, double *restrict rh, bool store)
{
#ifdef TC_HAVE_AVX2_PASS
    if (tc_simd_level() == TC_SIMD_AVX2) return sgs_unsplit_avx2(m, rh, store);
#endif
    return sgs_unsplit_c(m, rh, store);
}

/* v += alpha t, r^ -= alpha (t + u), dr = D r^ (for the next backward sweep); returns r^ . D r^
 * (= r^ . S D S r^: r^ is on the range of S) and (in *rr) r^ . r^ */
TC_HOT static double sgs_update(const sgs_rows *m, double alpha, const double *restrict t, const double *restrict u,
                                double *restrict v, double *restrict rh, double *restrict dr, double *rr)
{
    double rz0 = 0.0, rz1 = 0.0, rr0 = 0.0, rr1 = 0.0;
    for (int32_t i = 0; i < m->nv; i++) {
        const size_t o = 3 * (size_t)i;
        if (m->fl[i] == VC_PINNED || m->fl[i] == VC_HANDLE) continue;
        double r[3], z[3];
        for (int q = 0; q < 3; q++) {
            v[o + q] += alpha * t[o + q];
            r[q] = rh[o + q] - alpha * (t[o + q] + u[o + q]);
            rh[o + q] = r[q];
        }
        apply_diag(m->D + 12 * (size_t)i, r, z);
        dr[o] = z[0]; dr[o + 1] = z[1]; dr[o + 2] = z[2];
        const double a = r[0] * z[0] + r[1] * z[1] + r[2] * z[2], b = r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
        if (i & 1) { rz1 += a; rr1 += b; } else { rz0 += a; rr0 += b; }
    }
    *rr = rr0 + rr1;
    return rz0 + rz1;
}

/* The true residual is taken when the split one, scaled by their last ratio, is within this factor
 * (squared) of the stop, and at least every TC_SGS_CHECK_EVERY iterations (the ratio drifts) */
#define TC_SGS_CHECK_NEAR 2.0
#define TC_SGS_CHECK_EVERY 8

/* PCG by Eisenstat's trick from v and r (the filtered residual of v, in sr) as pcg() set them up;
 * leaves the true residual of the final v in sr and its square in *rr_inout. Scratch: sb2 (the
 * right-hand side, read by then), sz, sp, sq, and sr itself between the first lines and the last
 * (it holds D r^ then); pinv's contact rows hold the filtered inverses during the solve. Returns the
 * iterations. */
static int pcg_sgs(tc_cloth *c, double *v, double stop2, double *rr_inout, bool contact)
{
    const size_t n3 = 3 * (size_t)c->nv;
    double *r = tc_vec_ptr(&c->sr), *rh = tc_vec_ptr(&c->sb2), *u = tc_vec_ptr(&c->sz), *p = tc_vec_ptr(&c->sp);
    double *t = tc_vec_ptr(&c->sq), *dr = r;  /* r is copied to r^ below and made again at the end */
    if (contact) sgs_constrain(c, true);
    const sgs_rows m = sgs_view(c);
    memcpy(rh, r, n3 * sizeof(double));
    double rr = *rr_inout;
    sgs_forward_inplace(&m, rh);  /* r^ = C^-1 r */
    double rhr = 0.0, rz = 0.0;
    for (int32_t i = 0; i < c->nv; i++) {
        const double *x = rh + 3 * (size_t)i;
        double *z = dr + 3 * (size_t)i;
        apply_diag(m.D + 12 * (size_t)i, x, z);
        rz += x[0] * z[0] + x[1] * z[1] + x[2] * z[2];
        rhr += x[0] * x[0] + x[1] * x[1] + x[2] * x[2];
    }
    double ratio = rhr > 0 ? rr / rhr : 1.0;  /* |r|^2 / |r^|^2 at the last check */
    int it = 0, checked = 0;
    double beta = 0.0;
    while (it < c->solver.cg_max_iterations && rr > stop2) {
        if (!(rz > 0) || !isfinite(rz)) break;
        sgs_backward(&m, dr, beta, it == 0, p, t);
        const double pq = sgs_forward(&m, p, t, u);
        if (!(pq > 0)) break;  /* positive definite on the manifold; else round-off */
        const double alpha = rz / pq;
        double rhr2;
        const double rz2 = sgs_update(&m, alpha, t, u, v, rh, dr, &rhr2);
        it++;
        if (rhr2 * ratio <= TC_SGS_CHECK_NEAR * stop2 || it - checked >= TC_SGS_CHECK_EVERY) {
            rr = sgs_unsplit(&m, rh, false);
            ratio = rhr2 > 0 ? rr / rhr2 : ratio;
            checked = it;
        } else {
            rr = rhr2 * ratio;  /* the estimate, above the stop by the test above */
        }
        beta = rz2 / rz;
        rz = rz2;
    }
    rr = sgs_unsplit(&m, rh, true);  /* r = S C r^ */
    memcpy(r, rh, n3 * sizeof(double));
    if (contact) sgs_constrain(c, false);
    *rr_inout = rr;
    return it;
}
/* Solves A v = b on the constraint manifold {v_i = S_i v_i + fix_i}; v holds the warm start. Stops
 * when |S (b - A v)|^2 <= stop2 (an absolute bound in (N s)^2 set by tc_solve_dv); *rr gets the
 * final squared residual. Returns the iterations. */
TC_HOT static int pcg(tc_cloth *c, double *v, const double *b, const double *fix, double stop2, double *rr_out)
{
    const size_t n3 = 3 * (size_t)c->nv;
    double *r = tc_vec_ptr(&c->sr), *z = tc_vec_ptr(&c->sz), *p = tc_vec_ptr(&c->sp), *q = tc_vec_ptr(&c->sq);
    tc_constraint_project(c, v, fix);  /* the warm start onto the constraint manifold */
    tc_matvec(c, v, q);
    for (size_t k = 0; k < n3; k++) r[k] = b[k] - q[k];
    tc_constraint_filter(c, r);
    int it = 0;
    double rr = dotn(r, r, n3);
    if (use_amg(c) && tc_amg_valid(c->amg, c)) {
        /* the first coarse operator follows the contacts (amg.c: the contact correction) */
        const double t0 = tc_now();
        if (tc_amg_contacts(c->amg, c)) c->stats.amg_fallbacks++;
        c->stats.amg_setup_seconds += tc_now() - t0;
    }
    if (use_amg(c) && tc_amg_valid(c->amg, c)) {  /* again: a failed correction may have dropped it */
        const double rr0 = rr;
        it = pcg_amg(c, v, stop2, &rr);
        if (it >= 0) {
            /* a kept hierarchy whose cycle lost much of its strength (its residual falls by less than
               1/TC_AMG_STALE_FACTOR of the rate per iteration of the first solve on its
               prolongators: the cloth turned or stretched much since) is refreshed at the next
               sub-step, and gets new prolongators if that did not help (amg_prepare). The rate,
               not the iteration count: that one follows the warm start
               and the load (a falling, accelerating sheet needed 2x more every other sub-step on
               an unchanged hierarchy, and made a build every sub-step) */
            c->amg_last_iterations = it;
            if (it > 0 && rr > 0 && rr0 > rr) {
                const double rate = log(rr0 / rr) / it;
                if (!(c->amg_fresh_rate > 0)) c->amg_fresh_rate = rate;
                else if (rate * TC_AMG_STALE_FACTOR < c->amg_fresh_rate) c->amg_stale = true;
                else c->amg_stale_refreshed = false;  /* a refresh for staleness helped */
            }
            *rr_out = rr;
            return it;
        }
        /* broke down: block Jacobi goes on from where the cycle left v and r, counted */
        it = -1 - it;
        c->stats.amg_fallbacks++;
    }
    /* no contact: the filter zeroes the held vertices, which update_precondition does itself */
    const int8_t *fl = tc_vec_ptr(&c->vflag);
    bool contact = false;
    for (int32_t i = 0; i < c->nv; i++) contact |= fl[i] == VC_CONTACT;
    if (it == 0 && use_sgs(c)) {
        if (sgs_prepare(c) == 0) {
            it = pcg_sgs(c, v, stop2, &rr, contact);
            c->stats.sgs_solves++;
            *rr_out = rr;
            return it;
        }
        c->stats.sgs_fallbacks++;  /* block Jacobi below solves the same system, counted */
    }
    precondition(c, r, z);
    tc_stiff_apply(c, r, z);
    tc_constraint_filter(c, z);
    memcpy(p, z, n3 * sizeof(double));
    double rz = dotn(r, z, n3);
    const int8_t *held = contact ? NULL : fl;
    /* Three passes an iteration: the product with p.Ap fused in, the update of v and r fused with
     * the preconditioner and both dots, and the new direction. The filter S is a symmetric
     * projector and p, r stay on its range, so p.(S Ap) = p.Ap and r.(S P r) = r.(P r): the dots
     * need no filtered copy and are taken before the filter passes (which touch only the
     * constrained vertices), or, with no contact, in the update pass that applies S itself.
     * (Measured and left out: the new direction fused into the next product as q = A z + beta q,
     * p = z + beta p row by row, 1.04x the iteration's time against this separate 4-wide pass.) */
    while (it < c->solver.cg_max_iterations && rr > stop2) {
        const double pq = tc_matvec(c, p, q);
        if (contact) tc_constraint_filter(c, q);
        if (!(pq > 0)) break;  /* A is SPD on the manifold; a non-positive curvature means round-off */
        const double alpha = rz / pq;
        double rz2, rr2;
        update_precondition(c, alpha, p, q, v, r, z, held, &rz2, &rr2);
        rz2 += tc_stiff_apply(c, r, z);  /* the groups' rows inverted together (none: nothing) */
        if (contact) tc_constraint_filter(c, z);
        rr = rr2;
        const double beta = rz2 / rz;
        for (size_t k = 0; k < n3; k++) p[k] = z[k] + beta * p[k];
        rz = rz2;
        it++;
    }
    *rr_out = rr;
    return it;
}

/* The Galerkin correction of the solution along the three translations when no vertex is
 * constrained: K annihilates a uniform velocity (elastic, geometric and bending stiffness are all
 * translation invariant), so A 1 = (1 + dt alpha) M 1 and the correction du += sum(r) / (1 + dt
 * alpha) sum(m) makes the residual sum to zero. That is the step's momentum balance, exact whatever
 * the tolerance (a CG stopped early otherwise lets a free cloth's centre of mass drift), and, as a
 * Galerkin projection, it only lowers the error in A's energy norm. Returns the new |r|^2. */
static double translation_correction(tc_cloth *c, double *v)
{
    const int8_t *fl = tc_vec_ptr(&c->vflag);
    const double *m = tc_vec_ptr(&c->mass);
    double *r = tc_vec_ptr(&c->sr);
    for (int32_t i = 0; i < c->nv; i++)
        if (fl[i] != VC_FREE) return dotn(r, r, 3 * (size_t)c->nv);
    double s[3] = {0, 0, 0}, msum = 0.0;
    for (int32_t i = 0; i < c->nv; i++) {
        s[0] += r[3 * i]; s[1] += r[3 * i + 1]; s[2] += r[3 * i + 2];
        msum += m[i];
    }
    const double ms = c->mass_scale * msum;
    if (!(ms > 0)) return dotn(r, r, 3 * (size_t)c->nv);
    const double d[3] = {s[0] / ms, s[1] / ms, s[2] / ms};
    double rr = 0.0;
    for (int32_t i = 0; i < c->nv; i++) {
        const double w = c->mass_scale * m[i];
        for (int k = 0; k < 3; k++) {
            v[3 * i + k] += d[k];
            r[3 * i + k] -= w * d[k];
            rr += r[3 * i + k] * r[3 * i + k];
        }
    }
    return rr;
}

/* Solves A v = b for the change du = v - v0 instead of v itself, v holding the warm start on entry
 * (its change from v0 is reused). The stopping rule is in physical terms: the residual force
 * |S (b - A v)| / dt against the forces the cloth carries, the root sum of squares of
 *   - its weight (m g per vertex),
 *   - the elastic forces its triangles exert on their corners (tension a hanging or stretched cloth
 *     carries even where they cancel at a vertex; fem.c sums them in the element pass), and
 *   - the net force that accelerates it this step (inertia: the residual of du = 0, prescribed
 *     velocities included),
 * so an error of cg_tolerance in it is an error of that fraction in the forces that decide motion
 * and tearing, whatever the mesh, the warm start or the preconditioner. (The earlier rule, relative
 * to the preconditioned norm of the right-hand side, depended on all three and stopped at the cap
 * with residuals up to 0.2 on meshes with slivers.) Fills the solver statistics of this solve and
 * returns 1 when it converged, 0 when it stopped at the iteration cap (or a breakdown). tolerance is
 * cg_tolerance, or a looser one for the contact rounds' guesses (step.c). */
int tc_solve_dv(tc_cloth *c, double *v, const double *v0, const double *b, double dt, double tolerance, int *iterations)
{
    const size_t n3 = 3 * (size_t)c->nv;
    /* fixu in sz: read only until pcg's first line projects the warm start, before its first
       preconditioner application writes z (a vector of its own was 12 bytes per triangle) */
    double *rhs = tc_vec_ptr(&c->sb2), *fix = tc_vec_ptr(&c->sfix), *fixu = tc_vec_ptr(&c->sz);
    double *q = tc_vec_ptr(&c->sq), *r = tc_vec_ptr(&c->sr);
    tc_matvec(c, v0, rhs);
    for (size_t k = 0; k < n3; k++) { rhs[k] = b[k] - rhs[k]; v[k] -= v0[k]; }
    /* the constrained components of du: the prescribed velocity minus v0's part along them */
    memcpy(fixu, fix, n3 * sizeof(double));
    tc_constraint_offsets(c, v0, fixu);

    /* the force scale: weight and carried elastic forces, then the net force of du = 0 (r0) */
    const double *m = tc_vec_ptr(&c->mass), *g = c->solver.gravity;
    double m2 = 0.0;
    for (int32_t i = 0; i < c->nv; i++) m2 += m[i] * m[i];
    double f2 = m2 * dot3(g, g) + c->carried2;
    const int8_t *fl = tc_vec_ptr(&c->vflag);
    int constrained = 0;
    for (int32_t i = 0; i < c->nv && !constrained; i++) constrained = fl[i] != VC_FREE;
    if (constrained) {
        memset(q, 0, n3 * sizeof(double));
        tc_constraint_project(c, q, fixu);  /* the prescribed part alone: zero at the free vertices */
        memcpy(r, rhs, n3 * sizeof(double));
        tc_matvec_sub_sparse(c, q, r);
    } else {
        memcpy(r, rhs, n3 * sizeof(double));
    }
    tc_constraint_filter(c, r);
    const double r02 = dotn(r, r, n3);
    f2 += r02 / (dt * dt);

    const double stop2 = tolerance * tolerance * dt * dt * f2;
    int it = 0, ok = 1;
    double rr = 0.0;
    if (r02 == 0.0) {
        /* nothing moves the cloth off du = the prescribed part: that is the exact answer (a NaN
           goes on into the solve instead, and the step's check rolls it back) */
        memset(v, 0, n3 * sizeof(double));
        tc_constraint_project(c, v, fixu);
    } else {
        it = pcg(c, v, rhs, fixu, stop2, &rr);
        rr = translation_correction(c, v);
        ok = rr <= stop2;
    }
    for (size_t k = 0; k < n3; k++) v[k] += v0[k];
    const double rf = sqrt(rr) / dt, fs = sqrt(f2);
    c->solve_residual_force = rf;
    c->solve_force_scale = fs;
    c->solve_residual = fs > 0 ? rf / fs : 0.0;
    *iterations = it;
    return ok;
}
