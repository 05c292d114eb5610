/* bench_solver.c - the solver's costs on one mesh, in CPU time of this thread (a machine shared with
 * other jobs stretches wall time far more): the product of every kernel the CPU has, interleaved
 * (kernel after kernel within each round) against the bytes of the matrix at the L2 rate the
 * project's notes measured (120 GB/s) and against the time this core takes to stream the same bytes
 * (a plain sum over a buffer of the matrix's size: the bandwidth the product could use), then the
 * other passes of one block-Jacobi CG iteration (the fused update / preconditioner / dots pass, the
 * new direction, a constraint filter) and of one sub-step (the fused element pass and assembly, the
 * preconditioner's build), interleaved the same way, then whole 1 ms steps of the cloth hung by its
 * 40 highest vertices: median step and CG iterations. The CG's passes are solver.c's own static
 * functions, so this file includes solver.c (left out of the command's file list). Not part of any
 * build. The mesh is a raw file as for bench_fem.c (int32 n, m, then n x 3 float64 positions,
 * m x 3 int32 triangles):
 *   cd native && cc -std=c17 -ffp-contract=fast -O3 -fno-math-errno -fno-trapping-math -I. \
 *       $(ls *.c | grep -v -e '^pymodule\.c$' -e '^solver\.c$') tests/bench_solver.c -lm -o /tmp/bench_solver && \
 *       /tmp/bench_solver tshirt.bin
 */
#define _POSIX_C_SOURCE 199309L
#include "tearcloth.h"
#include "core.h"
#include "solver.c"  /* its static passes (update_precondition, dotn), timed one by one below */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static double cpu_seconds(void)
{
    struct timespec t;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}
static int cmpd(const void *a, const void *b) { double x = *(const double *)a, y = *(const double *)b; return x < y ? -1 : x > y; }
static double med(double *v, int n) { qsort(v, n, sizeof *v, cmpd); return v[n / 2]; }

/* a sum over n doubles in 32 accumulators (eight 4-lane ones once vectorised: one would serialise on
   the add latency, 4 cycles a 64-byte line): the time to stream the matrix's bytes through this core,
   no index, no gather. noipa: a pure function of unchanged memory would be called once, not reps times */
#if defined(__GNUC__) && defined(__x86_64__)
__attribute__((target("avx2,fma")))
#endif
__attribute__((noinline, noipa)) static double stream_sum(const double *a, size_t n)
{
    double s[32] = {0};
    for (size_t i = 0; i + 32 <= n; i += 32)
        for (int k = 0; k < 32; k++) s[k] += a[i + k];
    double t = 0.0;
    for (int k = 0; k < 32; k++) t += s[k];
    return t;
}

int main(int argc, char **argv)
{
    if (argc < 2) { fprintf(stderr, "usage: %s mesh.bin [steps]\n", argv[0]); return 2; }
    FILE *f = fopen(argv[1], "rb");
    int32_t nm[2];
    if (!f || fread(nm, 4, 2, f) != 2) return 1;
    double *V = malloc(24 * (size_t)nm[0]);
    int32_t *T = malloc(12 * (size_t)nm[1]);
    if (fread(V, 24, nm[0], f) != (size_t)nm[0] || fread(T, 12, nm[1], f) != (size_t)nm[1]) return 1;
    fclose(f);
    const int steps = argc > 2 ? atoi(argv[2]) : 200;
    tc_material mat = tc_material_default();
    char msg[512];
    tc_cloth *c = tc_cloth_create(V, nm[0], T, nm[1], NULL, 0, NULL, NULL, 0, &mat, msg, sizeof msg);
    if (!c) { printf("%s\n", msg); return 1; }
    /* hung by its 40 highest vertices (a hanger) */
    int32_t *top = malloc(4 * (size_t)nm[0]);
    for (int32_t i = 0; i < nm[0]; i++) top[i] = i;
    for (int a = 0; a < 40 && a < nm[0]; a++)
        for (int32_t b = a + 1; b < nm[0]; b++)
            if (V[3 * top[b] + 2] > V[3 * top[a] + 2]) { int32_t t = top[a]; top[a] = top[b]; top[b] = t; }
    tc_cloth_pin(c, top, nm[0] < 40 ? nm[0] : 40, 1);
    for (int i = 0; i < 10; i++) tc_cloth_step(c, 1e-3, 1);

    const size_t n3 = 3 * (size_t)c->nv;
    double *p = malloc(8 * n3), *y = malloc(8 * n3);
    for (size_t k = 0; k < n3; k++) p[k] = (double)rand() / RAND_MAX - 0.5;
    const int level = tc_simd_level();
    enum { ROUNDS = 201 };
    const int reps = c->nv > 20000 ? 2 : 50;
    double *t[TC_SIMD_LAST + 1] = {0};
    for (int r = 0; r < ROUNDS; r++)
        for (int l = TC_SIMD_SCALAR; l <= TC_SIMD_LAST; l++) {
            if (tc_simd_select(l) < 0) continue;
            if (!t[l]) t[l] = malloc(ROUNDS * sizeof(double));
            const double t0 = cpu_seconds();
            for (int k = 0; k < reps; k++) tc_matvec(c, p, y);
            t[l][r] = (cpu_seconds() - t0) / reps;
        }
    tc_simd_select(level);
    const double bytes = (double)c->stats.matrix_bytes;
    printf("%d vertices, %d triangles; matrix %.0f bytes, roofline %.2f us at 120 GB/s\n", c->nv, c->nt, bytes, 1e6 * bytes / 120e9);
    for (int l = TC_SIMD_SCALAR; l <= TC_SIMD_LAST; l++)
        if (t[l]) { printf("  product %-6s %8.2f us (CPU, median of %d rounds)\n", tc_simd_name(l), 1e6 * med(t[l], ROUNDS), ROUNDS); free(t[l]); }

    /* the other passes of an iteration and of a sub-step, in the kernel the CPU picks (level) */
    const size_t nb = (size_t)bytes / sizeof(double);
    double *big = malloc(8 * (nb + 8)), *v = malloc(8 * n3), *r = malloc(8 * n3), *z = malloc(8 * n3);
    for (size_t k = 0; k < nb + 8; k++) big[k] = 1e-9 * (double)k;
    for (size_t k = 0; k < n3; k++) { v[k] = 0.0; r[k] = (double)rand() / RAND_MAX - 0.5; }
    const int8_t *fl = tc_vec_ptr(&c->vflag);
    enum { PASSES = 7 };
    static const char *const pass_name[PASSES] = {"product (CG's p.Ap fused)", "update + precondition + dots",
                                                  "new direction p = z + beta p", "constraint filter (contacts only)",
                                                  "stream the matrix's bytes", "element pass + assembly (a sub-step)",
                                                  "preconditioner build (a sub-step)"};
    double *tp[PASSES];
    for (int k = 0; k < PASSES; k++) tp[k] = malloc(ROUNDS * sizeof(double));
    double sink = 0.0, worst;
    for (int rr = 0; rr < ROUNDS; rr++) {
        double t0 = cpu_seconds();
        for (int k = 0; k < reps; k++) sink += tc_matvec(c, p, y);
        tp[0][rr] = (cpu_seconds() - t0) / reps;
        t0 = cpu_seconds();
        for (int k = 0; k < reps; k++) {
            double rz, rr2;
            update_precondition(c, 1e-12, p, y, v, r, z, fl, &rz, &rr2);
            sink += rz;
        }
        tp[1][rr] = (cpu_seconds() - t0) / reps;
        t0 = cpu_seconds();
        for (int k = 0; k < reps; k++)
            for (size_t j = 0; j < n3; j++) p[j] = z[j] + 0.5 * p[j];
        tp[2][rr] = (cpu_seconds() - t0) / reps;
        t0 = cpu_seconds();
        for (int k = 0; k < reps; k++) tc_constraint_filter(c, y);
        tp[3][rr] = (cpu_seconds() - t0) / reps;
        t0 = cpu_seconds();
        for (int k = 0; k < reps; k++) sink += stream_sum(big, nb);
        tp[4][rr] = (cpu_seconds() - t0) / reps;
        t0 = cpu_seconds();
        tc_element_assemble(c, tc_vec_ptr(&c->x), 1e-3, &worst);
        tp[5][rr] = cpu_seconds() - t0;
        t0 = cpu_seconds();
        tc_precondition_build(c, 1e-3);
        tp[6][rr] = cpu_seconds() - t0;
        for (size_t k = 0; k < n3; k++) p[k] = (double)rand() / RAND_MAX - 0.5;  /* keep p bounded */
    }
    printf("  one CG iteration's passes and one sub-step's (%s, CPU, medians of %d interleaved rounds):\n", tc_simd_name(level), ROUNDS);
    for (int k = 0; k < PASSES; k++) {
        printf("    %-38s %8.2f us\n", pass_name[k], 1e6 * med(tp[k], ROUNDS));
        free(tp[k]);
    }
    free(big); free(v); free(r); free(z);
    if (sink == 1234.5) printf(" ");  /* keeps the timed calls */
    double *ts = malloc(sizeof(double) * (size_t)steps);
    long its = 0;
    for (int i = 0; i < steps; i++) {
        const double t0 = cpu_seconds();
        tc_cloth_step(c, 1e-3, 1);
        ts[i] = cpu_seconds() - t0;
        its += tc_cloth_stats(c).cg_iterations;
    }
    printf("  step (%s) %.3f ms CPU median of %d, %.1f CG iterations a step\n", tc_simd_name(level), 1e3 * med(ts, steps), steps,
           (double)its / steps);
    tc_cloth_destroy(c);
    return 0;
}
