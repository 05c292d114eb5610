/* test_core.c - native tests of the core without Python, built with AddressSanitizer and
 * UndefinedBehaviorSanitizer in CI (see native/tests/run_sanitizers.sh). Each check prints and
 * counts; the exit code is the number of failures. */
#include "tearcloth.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static int failures, checks;
#define CHECK(cond, ...) do { checks++; if (!(cond)) { failures++; printf("FAIL %s:%d: ", __FILE__, __LINE__); printf(__VA_ARGS__); printf("\n"); } } while (0)

/* nx x ny grid of a w x hgt strip in the xy plane, with alternating diagonals */
static void grid(int nx, int ny, double w, double hgt, double **V, int32_t **T, int32_t *n, int32_t *m)
{
    *n = nx * ny;
    *m = 2 * (nx - 1) * (ny - 1);
    *V = malloc(3 * (size_t)*n * sizeof(double));
    *T = malloc(3 * (size_t)*m * sizeof(int32_t));
    for (int i = 0; i < nx; i++)
        for (int j = 0; j < ny; j++) {
            double *p = *V + 3 * (i * ny + j);
            p[0] = w * i / (nx - 1); p[1] = hgt * j / (ny - 1); p[2] = 0.0;
        }
    int k = 0;
    for (int i = 0; i < nx - 1; i++)
        for (int j = 0; j < ny - 1; j++) {
            int a = i * ny + j, b = (i + 1) * ny + j, c = (i + 1) * ny + j + 1, d = i * ny + j + 1;
            int32_t *t = *T + 3 * k;
            if ((i + j) % 2) { t[0] = a; t[1] = b; t[2] = c; t[3] = a; t[4] = c; t[5] = d; }
            else { t[0] = a; t[1] = b; t[2] = d; t[3] = b; t[4] = c; t[5] = d; }
            k += 2;
        }
}

static void test_bad_input(void)
{
    double V[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    int32_t T[3] = {0, 1, 2}, Tbad[3] = {0, 1, 5}, Tdeg[3] = {0, 1, 1};
    char msg[512];
    tc_cloth *c = tc_cloth_create(V, 3, Tbad, 1, NULL, 0, NULL, NULL, 0, NULL, msg, sizeof msg);
    CHECK(!c && strstr(msg, "outside"), "out-of-range index: %s", msg);
    c = tc_cloth_create(V, 3, Tdeg, 1, NULL, 0, NULL, NULL, 0, NULL, msg, sizeof msg);
    CHECK(!c && strstr(msg, "degenerate"), "repeated vertex: %s", msg);
    double Vc[9] = {0, 0, 0, 1, 0, 0, 2, 0, 0};
    c = tc_cloth_create(Vc, 3, T, 1, NULL, 0, NULL, NULL, 0, NULL, msg, sizeof msg);
    CHECK(!c && strstr(msg, "degenerate"), "collinear: %s", msg);
    double Vn[9] = {0, 0, 0, NAN, 0, 0, 0, 1, 0};
    c = tc_cloth_create(Vn, 3, T, 1, NULL, 0, NULL, NULL, 0, NULL, msg, sizeof msg);
    CHECK(!c && strstr(msg, "non-finite"), "nan: %s", msg);
    /* three triangles on one edge */
    double V4[15] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 0, -1, 0, 0, 0, 1};
    int32_t T3[9] = {0, 1, 2, 1, 0, 3, 0, 1, 4};
    c = tc_cloth_create(V4, 5, T3, 3, NULL, 0, NULL, NULL, 0, NULL, msg, sizeof msg);
    CHECK(!c && strstr(msg, "non-manifold"), "non-manifold: %s", msg);
    tc_material m = tc_material_default();
    m.poisson = 0.5;
    c = tc_cloth_create(V, 3, T, 1, NULL, 0, NULL, NULL, 0, &m, msg, sizeof msg);
    CHECK(!c && strstr(msg, "poisson"), "poisson: %s", msg);
}

static void test_strip_and_tear(void)
{
    double *V; int32_t *T, n, m;
    grid(31, 11, 0.3, 0.1, &V, &T, &n, &m);
    char msg[512];
    tc_cloth *c = tc_cloth_create(V, n, T, m, NULL, 0, NULL, NULL, 0, NULL, msg, sizeof msg);
    CHECK(c != NULL, "create: %s", msg);
    if (!c) return;
    tc_solver_settings s = tc_solver_default();
    s.gravity[2] = 0.0;
    tc_cloth_set_solver(c, &s);
    int32_t left[11], right[11];
    for (int j = 0; j < 11; j++) { left[j] = j; right[j] = 30 * 11 + j; }
    int32_t hl, hr;
    CHECK(tc_cloth_add_handle(c, left, 11, &hl) == TC_OK, "handle");
    CHECK(tc_cloth_add_handle(c, right, 11, &hr) == TC_OK, "handle");
    double A[12] = {1, 0, 0, 0.003, 0, 1, 0, 0, 0, 0, 1, 0};
    tc_cloth_set_handle_target(c, hr, A);
    for (int i = 0; i < 100; i++) CHECK(tc_cloth_step(c, 1e-3, 1) == TC_OK, "step %d: %s", i, tc_cloth_error(c));
    double fl[3], fr[3];
    tc_cloth_handle_force(c, hl, fl);
    tc_cloth_handle_force(c, hr, fr);
    CHECK(fl[0] > 0 && fr[0] < 0, "handle forces opposite: %g %g", fl[0], fr[0]);
    /* tear it: lower the tear stress and keep pulling */
    tc_material mat = tc_cloth_material(c);
    mat.tear_stress = 1e4;
    tc_cloth_set_material(c, &mat);
    tc_tear_settings ts = tc_tear_default();
    ts.enabled = 1;
    tc_cloth_set_tearing(c, &ts);
    for (int i = 0; i < 300; i++) {
        A[3] = 0.003 + 1e-4 * i;
        tc_cloth_set_handle_target(c, hr, A);
        int rc = tc_cloth_step(c, 1e-3, 1);
        CHECK(rc == TC_OK, "tear step %d: %s", i, tc_cloth_error(c));
        if (rc) break;
    }
    tc_stats st = tc_cloth_stats(c);
    printf("tears %d cuts %d vertices %d triangles %d\n", st.tears_started, st.cuts, tc_cloth_num_vertices(c), tc_cloth_num_triangles(c));
    CHECK(st.cuts > 0, "some cuts");
    int32_t cuts = 0;
    double dir[3] = {0, 1, 0};
    CHECK(tc_cloth_scripted_tear(c, 5 * 11, dir, 0.05, &cuts) == TC_OK, "scripted: %s", tc_cloth_error(c));
    CHECK(tc_cloth_scripted_tear(c, -1, dir, 0.05, &cuts) == TC_ERR_INPUT, "scripted bad vertex");
    double zero[3] = {0, 0, 0};
    CHECK(tc_cloth_scripted_tear(c, 0, zero, 0.05, &cuts) == TC_ERR_INPUT, "scripted zero dir");
    for (int i = 0; i < 20; i++) tc_cloth_step(c, 1e-3, 2);
    tc_cloth_destroy(c);
    free(V); free(T);
}

int main(void)
{
    test_bad_input();
    test_strip_and_tear();
    printf("%d passed, %d failed\n", checks - failures, failures);
    return failures != 0;
}
