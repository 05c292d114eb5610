/* test_core.c - native tests of the core without Python, built with AddressSanitizer and
 * UndefinedBehaviorSanitizer in CI (see native/tests/run_sanitizers.sh). Each check prints and
 * counts; the exit code is the number of failures. */
#include "tearcloth.h"
#include "constants.h"  /* TC_SPLIT_DEPTH: how often a capped solve is split */

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
    tc_culprits k = tc_create_culprits();
    CHECK(k.n_triangles == 1 && k.triangles[0] == 0 && k.n_vertices == 3 && k.vertices[2] == 2, "collinear culprits");
    double Vn[9] = {0, 0, 0, NAN, 0, 0, 0, 1, 0};
    c = tc_cloth_create(Vn, 3, T, 1, NULL, 0, NULL, NULL, 0, NULL, msg, sizeof msg);
    CHECK(!c && strstr(msg, "non-finite"), "nan: %s", msg);
    /* three triangles on one edge */
    double V4[15] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 0, -1, 0, 0, 0, 1};
    int32_t T3[9] = {0, 1, 2, 1, 0, 3, 0, 1, 4};
    c = tc_cloth_create(V4, 5, T3, 3, NULL, 0, NULL, NULL, 0, NULL, msg, sizeof msg);
    CHECK(!c && strstr(msg, "non-manifold"), "non-manifold: %s", msg);
    k = tc_create_culprits();
    CHECK(k.n_triangles == 3 && k.triangles[2] == 2 && k.n_vertices == 2 && k.vertices[0] == 0 && k.vertices[1] == 1,
          "non-manifold culprits: %d triangles, %d vertices", (int)k.n_triangles, (int)k.n_vertices);
    tc_material m = tc_material_default();
    m.poisson = 0.5;
    c = tc_cloth_create(V, 3, T, 1, NULL, 0, NULL, NULL, 0, &m, msg, sizeof msg);
    CHECK(!c && strstr(msg, "poisson"), "poisson: %s", msg);
    CHECK(tc_create_culprits().n_triangles == 0, "a material error names no element");
}

static uint64_t fnv1a(const unsigned char *p, size_t n)
{
    uint64_t h = 0xcbf29ce484222325ull;
    for (size_t i = 0; i < n; i++) { h ^= p[i]; h *= 0x100000001b3ull; }
    return h;
}

/* a blob with its header's length and checksum made to agree with `size` bytes of it, so the
 * reader's own checks (not the checksum) must catch what is wrong */
static unsigned char *reseal(const unsigned char *blob, size_t size)
{
    unsigned char *b = malloc(size);
    memcpy(b, blob, size);
    uint64_t payload = size - 32, sum = fnv1a(b + 32, payload);
    memcpy(b + 16, &payload, 8); memcpy(b + 24, &sum, 8);
    return b;
}

/* Snapshot of a torn cloth: a copy steps bit for bit as the original; truncated, corrupted and
 * resealed blobs are refused or (a flipped value that is still valid) step without reading out
 * of bounds. */
static void test_snapshot(tc_cloth *c)
{
    void *blob; size_t size;
    CHECK(tc_cloth_snapshot(c, &blob, &size) == TC_OK, "snapshot");
    char msg[512];
    tc_cloth *d = tc_cloth_from_snapshot(blob, size, msg, sizeof msg);
    CHECK(d != NULL, "restore: %s", msg);
    if (!d) { free(blob); return; }
    double A[12] = {1, 0, 0, 0.04, 0, 1, 0, 0, 0, 0, 1, 0};
    for (int i = 0; i < 15; i++) {
        A[3] += 2e-4;
        tc_cloth_set_handle_target(c, 1, A); tc_cloth_set_handle_target(d, 1, A);
        CHECK(tc_cloth_step(c, 1e-3, 2) == tc_cloth_step(d, 1e-3, 2), "same outcome");
    }
    int32_t n = tc_cloth_num_vertices(c);
    CHECK(n == tc_cloth_num_vertices(d) && tc_cloth_num_triangles(c) == tc_cloth_num_triangles(d), "same counts");
    size_t r, k, item;
    tc_buf *bc = tc_cloth_array(c, TC_POSITIONS, &r, &k, &item), *bd = tc_cloth_array(d, TC_POSITIONS, &r, &k, &item);
    CHECK(n == tc_cloth_num_vertices(d) && !memcmp(tc_buf_data(bc), tc_buf_data(bd), 3 * (size_t)n * sizeof(double)),
          "restored cloth steps bit for bit");
    tc_buf_decref(bc); tc_buf_decref(bd);
    tc_cloth_destroy(d);
    unsigned char *b = blob;
    for (size_t len = 0; len < size; len += len < 64 ? 1 : 997) {
        CHECK(!tc_cloth_from_snapshot(b, len, msg, sizeof msg) && strstr(msg, "truncated"), "truncated at %zu: %s", len, msg);
        if (len < 32) continue;
        unsigned char *t = reseal(b, len);
        CHECK(!tc_cloth_from_snapshot(t, len, msg, sizeof msg), "resealed truncation at %zu accepted", len);
        free(t);
    }
    b[size / 2] ^= 1;
    CHECK(!tc_cloth_from_snapshot(b, size, msg, sizeof msg) && strstr(msg, "corrupted"), "flipped: %s", msg);
    b[size / 2] ^= 1;
    int refused = 0, accepted = 0;
    unsigned seed = 12345;
    for (int trial = 0; trial < 60; trial++) {
        seed = seed * 1103515245u + 12345u;
        size_t at = 32 + (seed >> 4) % (size - 32);
        unsigned char *t = reseal(b, size);
        t[at] ^= (unsigned char)(1u << (seed % 8)) | 0x80;
        memcpy(t + 24, &(uint64_t){fnv1a(t + 32, size - 32)}, 8);
        tc_cloth *e = tc_cloth_from_snapshot(t, size, msg, sizeof msg);
        if (e) {  /* a value that is still valid: it must step without reading out of bounds */
            accepted++;
            for (int i = 0; i < 3; i++) tc_cloth_step(e, 1e-3, 1);
            tc_cloth_destroy(e);
        } else refused++;
        free(t);
    }
    printf("snapshot %zu bytes; 60 resealed flips: %d refused, %d accepted and stepped\n", size, refused, accepted);
    free(blob);
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
    test_snapshot(c);
    tc_cloth_destroy(c);
    free(V); free(T);
}

/* A sheet dropped on a plane through contacts, with friction, then arrays and events read back. */
static void test_contacts_and_arrays(void)
{
    double *V; int32_t *T, n, m;
    grid(11, 11, 0.1, 0.1, &V, &T, &n, &m);
    for (int i = 0; i < n; i++) V[3 * i + 2] = 0.01;
    char msg[512];
    double *uv = calloc(6 * (size_t)m, sizeof(double));
    double *groups = calloc(2 * (size_t)n, sizeof(double));
    for (int i = 0; i < n; i++) { groups[2 * i] = V[3 * i]; groups[2 * i + 1] = 1.0; }
    tc_cloth *c = tc_cloth_create(V, n, T, m, NULL, 0, uv, groups, 2, NULL, msg, sizeof msg);
    CHECK(c != NULL, "create: %s", msg);
    if (!c) return;
    int32_t *idx = malloc((size_t)n * sizeof(int32_t));
    double *nrm = malloc(3 * (size_t)n * sizeof(double)), *dep = malloc((size_t)n * sizeof(double));
    double *fr = malloc((size_t)n * sizeof(double));
    for (int s = 0; s < 200; s++) {
        size_t rows, cols, item;
        tc_buf *xb = tc_cloth_array(c, TC_POSITIONS, &rows, &cols, &item);
        const double *x = tc_buf_data(xb);
        int32_t k = 0;
        for (int32_t i = 0; i < (int32_t)rows; i++)
            if (x[3 * i + 2] < 0.002) {
                idx[k] = i; nrm[3 * k] = 0; nrm[3 * k + 1] = 0; nrm[3 * k + 2] = 1; dep[k] = 0.002 - x[3 * i + 2]; fr[k] = 0.5; k++;
            }
        tc_buf_decref(xb);
        CHECK(tc_cloth_set_contacts(c, idx, nrm, dep, NULL, fr, k) == TC_OK, "contacts");
        int rc = tc_cloth_step(c, 2e-3, 1);
        CHECK(rc == TC_OK, "contact step %d: %s", s, tc_cloth_error(c));
        if (rc) break;
    }
    size_t rows, cols, item;
    tc_buf *xb = tc_cloth_array(c, TC_POSITIONS, &rows, &cols, &item);
    const double *x = tc_buf_data(xb);
    double zmin = 1;
    for (size_t i = 0; i < rows; i++) if (x[3 * i + 2] < zmin) zmin = x[3 * i + 2];
    CHECK(zmin > 0.0015, "rests on the plane: z min %g", zmin);
    tc_energy e = tc_cloth_energy(c);
    CHECK(e.kinetic < 1e-4, "comes to rest: kinetic %g", e.kinetic);
    /* a view taken before growth stays valid (old size) after the cloth grows */
    int32_t cuts = 0;
    double dir[3] = {0, 1, 0};
    CHECK(tc_cloth_scripted_tear(c, 5 * 11, dir, 0.08, &cuts) == TC_OK && cuts > 0, "tear: %s", tc_cloth_error(c));
    double sum = 0;
    for (size_t i = 0; i < rows * 3; i++) sum += x[i];
    CHECK(sum == sum, "old view readable");
    tc_buf_decref(xb);
    tc_events ev = tc_cloth_events(c);
    CHECK(ev.n_new_vertices > 0 && ev.n_changed_triangles > 0, "events");
    tc_buf *gb = tc_cloth_array(c, TC_GROUPS, &rows, &cols, &item);
    CHECK(cols == 2 && rows == (size_t)tc_cloth_num_vertices(c), "groups %zu x %zu", rows, cols);
    const double *g = tc_buf_data(gb);
    for (size_t i = 0; i < rows; i++) CHECK(g[2 * i + 1] == 1.0, "group weight carried for vertex %zu", i);
    tc_buf_decref(gb);
    for (int id = 0; id < TC_ARRAY_COUNT; id++) {
        tc_buf *b = tc_cloth_array(c, (tc_array_id)id, &rows, &cols, &item);
        CHECK(b != NULL, "array %d", id);
        tc_buf_decref(b);
    }
    tc_cloth_destroy(c);
    free(V); free(T); free(uv); free(groups); free(idx); free(nrm); free(dep); free(fr);
}

/* The defaults (settings.c) are accepted by the setters that check them, and a cloth made without
 * a material starts from the default one. */
static void test_defaults_pass_their_checks(void)
{
    double V[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    int32_t T[3] = {0, 1, 2};
    char msg[512] = "";
    tc_material m = tc_material_default();
    CHECK(tc_material_check(&m, msg, sizeof msg) == TC_OK, "default material rejected: %s", msg);
    tc_cloth *c = tc_cloth_create(V, 3, T, 1, NULL, 0, NULL, NULL, 0, NULL, msg, sizeof msg);
    CHECK(c != NULL, "create: %s", msg);
    if (!c) return;
    tc_material got = tc_cloth_material(c);
    CHECK(memcmp(&got, &m, sizeof m) == 0, "a cloth without material does not start from the default");
    tc_solver_settings s = tc_solver_default();
    CHECK(tc_cloth_set_solver(c, &s) == TC_OK, "default solver rejected: %s", tc_cloth_error(c));
    tc_tear_settings t = tc_tear_default();
    CHECK(tc_cloth_set_tearing(c, &t) == TC_OK, "default tearing rejected: %s", tc_cloth_error(c));
    t.min_angle_deg = 45.0;
    CHECK(tc_cloth_set_tearing(c, &t) == TC_ERR_INPUT && strstr(tc_cloth_error(c), "(got 45)"),
          "bad min_angle_deg: %s", tc_cloth_error(c));
    tc_cloth_destroy(c);
}

/* The solver: a product that is symmetric and the same with every kernel the CPU has (the run
 * script also runs this whole file once per kernel), after a tear rebuilt the rows; and a solve
 * stopped at its cap split and counted, never silent. */
static void test_solver(void)
{
    double *V; int32_t *T, n, m;
    grid(21, 11, 0.2, 0.1, &V, &T, &n, &m);
    char msg[512];
    tc_cloth *c = tc_cloth_create(V, n, T, m, NULL, 0, NULL, NULL, 0, NULL, msg, sizeof msg);
    if (!c) { CHECK(0, "create: %s", msg); return; }
    double *p = malloc(3 * (size_t)n * sizeof *p), *q = malloc(3 * (size_t)n * sizeof *q);
    double *y = malloc(3 * (size_t)n * sizeof *y), *z = malloc(3 * (size_t)n * sizeof *z);
    CHECK(tc_cloth_product(c, p, n, y) == TC_ERR_INPUT, "product before any step is refused");
    int32_t cuts = 0;
    const double dir[3] = {0, 1, 0};
    CHECK(tc_cloth_scripted_tear(c, 10 * 11, dir, 0.05, &cuts) == TC_OK && cuts > 0, "tear: %s", tc_cloth_error(c));
    CHECK(tc_cloth_step(c, 1e-3, 1) == TC_OK, "step: %s", tc_cloth_error(c));
    const int32_t nv = tc_cloth_num_vertices(c);
    p = realloc(p, 3 * (size_t)nv * sizeof *p); q = realloc(q, 3 * (size_t)nv * sizeof *q);
    y = realloc(y, 3 * (size_t)nv * sizeof *y); z = realloc(z, 3 * (size_t)nv * sizeof *z);
    for (int32_t k = 0; k < 3 * nv; k++) { p[k] = sin(0.37 * k); q[k] = cos(0.11 * k); }
    const int level = tc_simd_level();
    double ref = 0.0;
    for (int l = TC_SIMD_SCALAR; l <= TC_SIMD_AVX2; l++) {
        if (tc_simd_select(l) < 0) continue;
        CHECK(tc_cloth_product(c, p, nv, y) == TC_OK && tc_cloth_product(c, q, nv, z) == TC_OK, "product");
        double qy = 0.0, pz = 0.0;
        for (int32_t k = 0; k < 3 * nv; k++) { qy += q[k] * y[k]; pz += p[k] * z[k]; }
        CHECK(fabs(qy - pz) <= 1e-12 * fabs(qy), "%s: product symmetric: %.17g vs %.17g", tc_simd_name(l), qy, pz);
        if (l == TC_SIMD_SCALAR) ref = qy;
        CHECK(fabs(qy - ref) <= 1e-12 * fabs(ref), "%s agrees with scalar: %.17g vs %.17g", tc_simd_name(l), qy, ref);
    }
    tc_simd_select(level);
    tc_solver_settings s = tc_cloth_solver(c);
    s.cg_max_iterations = 2;
    tc_cloth_set_solver(c, &s);
    double *vel = malloc(3 * (size_t)nv * sizeof *vel);
    for (int32_t k = 0; k < 3 * nv; k++) vel[k] = 0.05 * sin(1.7 * k);
    tc_cloth_set_velocities(c, vel, nv);
    CHECK(tc_cloth_step(c, 1e-3, 1) == TC_OK, "capped step: %s", tc_cloth_error(c));
    tc_stats st = tc_cloth_stats(c);
    /* every half still unconverged splits again: a full binary tree TC_SPLIT_DEPTH deep */
    CHECK(st.substep_splits == (1 << TC_SPLIT_DEPTH) - 1 && st.unconverged_substeps == 1 << TC_SPLIT_DEPTH &&
              st.unconverged_steps == 1,
          "capped solve split %d times, %d sub-steps unconverged, %lld steps", (int)st.substep_splits,
          (int)st.unconverged_substeps, (long long)st.unconverged_steps);
    CHECK(st.cg_residual > s.cg_tolerance && st.cg_residual_force > 0, "residual reported: %g", st.cg_residual);
    free(p); free(q); free(y); free(z); free(vel); free(V); free(T);
    tc_cloth_destroy(c);
}

int main(void)
{
    test_bad_input();
    test_defaults_pass_their_checks();
    test_strip_and_tear();
    test_contacts_and_arrays();
    test_solver();
    printf("%d passed, %d failed\n", checks - failures, failures);
    return failures != 0;
}
