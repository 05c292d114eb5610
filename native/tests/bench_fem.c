/* bench_fem.c - fem.c's element pass and assembly timed in one process, interleaved: the
 * one-triangle-at-a-time reference loops (tc_fem_reference = 1), the batched ones, and the fused
 * pass; medians in ns per triangle. Not part of any build. The mesh is a raw file: int32 n, m, then
 * n x 3 float64 positions, m x 3 int32 triangles, e.g. the T-shirt:
 *   python -c "import numpy as np; from tearcloth import examples; m = examples.tshirt(); f = open('tshirt.bin', 'wb');
 *              np.array([m.n_vertices, m.n_triangles], np.int32).tofile(f); np.asarray(m.vertices, np.float64).tofile(f);
 *              np.asarray(m.triangles, np.int32).tofile(f)"
 *   cd native && cc -std=c17 -ffp-contract=fast -O3 -fno-math-errno -fno-trapping-math -I. \
 *       $(ls *.c | grep -v '^pymodule\.c$') tests/bench_fem.c -lm -o /tmp/bench_fem && /tmp/bench_fem tshirt.bin [ortho]
 */
#include "tearcloth.h"
#include "core.h"
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <math.h>
static int cmpd(const void *a, const void *b) { double x = *(const double *)a, y = *(const double *)b; return x < y ? -1 : x > y; }
static double med(double *v, int n) { qsort(v, n, sizeof *v, cmpd); return v[n / 2]; }
int main(int argc, char **argv)
{
    FILE *f = fopen(argv[1], "rb"); int32_t nm[2]; if (fread(nm, 4, 2, f) != 2) return 1;
    double *V = malloc(24 * (size_t)nm[0]); int32_t *T = malloc(12 * (size_t)nm[1]);
    if (fread(V, 24, nm[0], f) != (size_t)nm[0] || fread(T, 12, nm[1], f) != (size_t)nm[1]) return 1;
    int general = argc > 2 && !strcmp(argv[2], "ortho");
    tc_material mat = tc_material_default();
    if (general) { mat.orthotropic = 1; mat.young_weft = 0.5 * mat.young; mat.shear_modulus = 0.1 * mat.young; }
    char msg[512];
    tc_cloth *c = tc_cloth_create(V, nm[0], T, nm[1], NULL, 0, NULL, NULL, 0, &mat, msg, sizeof msg);
    if (!c) { printf("%s\n", msg); return 1; }
    int32_t pin[40]; for (int i = 0; i < 40; i++) pin[i] = i * (nm[0] / 40);
    tc_cloth_pin(c, pin, 40, 1);
    for (int i = 0; i < 30; i++) tc_cloth_step(c, 1e-3, 1);
    const double *x = tc_vec_ptr(&c->x);
    enum { N = 400 };
    double te[2][N], ta[2][N], tf[N];
    for (int i = 0; i < N; i++)
        for (int mode = 0; mode < 3; mode++) {
            double w;
            if (mode < 2) {
                tc_fem_reference = mode == 0;
                double t0 = tc_now(); tc_element_pass(c, x); double t1 = tc_now(); tc_assemble(c, 1e-3); double t2 = tc_now();
                te[mode][i] = t1 - t0; ta[mode][i] = t2 - t1;
            } else {
                tc_fem_reference = 0;
                double t0 = tc_now(); tc_element_assemble(c, x, 1e-3, &w); tf[i] = tc_now() - t0;
            }
        }
    double ns = 1e9 / nm[1];
    double er = med(te[0], N) * ns, en = med(te[1], N) * ns, ar = med(ta[0], N) * ns, an = med(ta[1], N) * ns, fu = med(tf, N) * ns;
    printf("%s, %d triangles, %d interleaved rounds, median ns per triangle\n", general ? "orthotropic" : "isotropic", nm[1], N);
    printf("  element pass : reference %6.1f  batched %6.1f  ratio %.2f\n", er, en, er / en);
    printf("  assembly     : reference %6.1f  batched %6.1f  ratio %.2f\n", ar, an, ar / an);
    printf("  both         : reference %6.1f  batched %6.1f  fused %6.1f  ratio ref/fused %.2f\n", er + ar, en + an, fu, (er + ar) / fu);
    tc_cloth_destroy(c);
    return 0;
}
