/* amg.c - smoothed-aggregation algebraic multigrid (Vanek, Mandel & Brezina 1996) as the
 * preconditioner of the solver's CG on large cloths, where block Jacobi needs iterations that grow
 * with the mesh (46 at 1K triangles, 590 at 100K) and a V-cycle keeps them near ten.
 *
 * What this file owns: the hierarchy (aggregates, prolongators, Galerkin coarse operators, the
 * coarsest level's Cholesky factor) and the V-cycle.
 *
 * The operator is the constrained one of the solve, S A S on the range of the filter S
 * (constraints.c); it is made definite off that range by (I - S) times a diagonal scale, so the
 * fine level's operator A' = S A S + (I - S) d is SPD and equals S A S where CG works. A' is never
 * stored: the setup reads it row by row from fem.c's rows (fine_row), and the products it needs
 * (the smoothed prolongator, the Galerkin operator P^T A' P) are made row by row too, so the setup
 * holds no copy of the fine matrix and no A P (at 100K triangles those were 47 and 41 MB, the
 * peak of the step's memory).
 *   - Strength of connection on A's 3x3 (coarse: 6x6) blocks, |A_ij|_F >= theta sqrt(|A_ii| |A_jj|);
 *     fully constrained vertices (pins, handles) take no part: the smoother alone handles them.
 *   - Aggregation: the three passes of standard aggregation (pyamg's standard_aggregation).
 *   - Near-null space: the six rigid-body modes of a shell (3 translations, 3 rotations about the
 *     aggregate's centroid, from the vertex positions), filtered by S; the tentative prolongator is
 *     their QR per aggregate (modified Gram-Schmidt, twice), R the next level's near-null space. A
 *     mode an aggregate cannot carry (a two-vertex aggregate has no twist about its axis) gives a
 *     zero column: that coarse unknown is decoupled with a unit-scaled diagonal.
 *   - Prolongator smoothing by one damped Jacobi step P = (I - w D^-1 A) T, w = 4/(3 rho(D^-1 A)),
 *     rho from power iterations; coarse operators A_c = P^T A P, pattern first, then one pass over
 *     the fine rows scattering P_i^T (A P)_i into the upper blocks.
 *   - Coarsest level (at most TC_AMG_COARSEST unknowns): a dense Cholesky factor.
 * The cycle is a V-cycle with the same damped block Jacobi step before and after the coarse
 * correction, so it is a symmetric operator and CG stays CG. On the finest level it never uses the
 * copy A' either: the smoother's products are fem.c's row product (tc_matvec) and the filter, the
 * operator CG itself uses.
 *
 * The matrix changes every sub-step (co-rotation, damping, contacts) while the mesh rarely does, so
 * the hierarchy is kept: the aggregates are rebuilt only when the mesh changed (a tear, a restore)
 * or every TC_AMG_REAGGREGATE refreshes, and the numeric part (prolongators, coarse operators) is
 * refreshed every `refresh` sub-steps (solver.c says which). Between refreshes the finest level is
 * still the current matrix; only the coarse correction is that of a slightly older one.
 */
#include "core.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

enum { NS = 6 };  /* near-null-space modes: 3 translations, 3 rotations */

/* block sparse rows: n block rows, m block columns, blocks br x bc row-major */
typedef struct bsr {
    int32_t n, m, br, bc;
    int32_t *ptr, *col;
    double *val;
    size_t cap_rows, cap_nnz;
} bsr;

typedef struct level {
    int32_t n, b;          /* block rows and block size (3 on the finest level, NS below) */
    bsr A;                 /* the operator (level 0: A' while the hierarchy is built) */
    bsr P;                 /* prolongator from the next level (restriction: its transpose) */
    double *dinv;          /* inverse diagonal blocks, b*b each (level 0: c->pinv is used) */
    double omega;          /* damping of the Jacobi step */
    int32_t *agg;          /* aggregate of each block row, -1 none */
    int32_t nagg;
    double *B;             /* near-null space, n*b x NS row-major (levels >= 1) */
    double *x, *rhs, *res, *tmp; /* V-cycle vectors: solution, right-hand side, residual, scratch */
    size_t cap_vec;
} level;

struct tc_amg {
    int nlev;
    level lev[TC_AMG_MAX_LEVELS];
    double *chol;          /* coarsest level: dense Cholesky factor (lower, row-major) */
    int32_t nc;
    size_t cap_chol;
    /* validity of the aggregates */
    uint64_t pair_version;
    int32_t nv;
    int numeric_builds;    /* since the last aggregation */
    /* scratch of the sparse products */
    int32_t *mark;
    double *acc;
    size_t cap_mark, cap_acc;
};

/* ---------------- memory ---------------- */

static int grow(void **p, size_t *cap, size_t need, size_t item)
{
    if (need <= *cap && *p) return 0;
    size_t n = need + need / 2 + 16;
    void *q = realloc(*p, n * item);
    if (!q) return -1;
    *p = q;
    *cap = n;
    return 0;
}

/* room for n block rows and nnz blocks, exactly (a hierarchy is made again at the same sizes on
 * every refresh, so slack would only be held) */
static int bsr_reserve(bsr *a, int32_t n, size_t nnz)
{
    if ((size_t)n + 1 > a->cap_rows || !a->ptr) {
        int32_t *p = realloc(a->ptr, ((size_t)n + 1) * sizeof(int32_t));
        if (!p) return -1;
        a->ptr = p;
        a->cap_rows = (size_t)n + 1;
    }
    if (nnz > a->cap_nnz || !a->col || !a->val) {
        const size_t cn = nnz ? nnz : 1;
        int32_t *col = realloc(a->col, cn * sizeof(int32_t));
        if (!col) return -1;
        a->col = col;
        double *v = realloc(a->val, cn * (size_t)a->br * (size_t)a->bc * sizeof(double));
        if (!v) return -1;
        a->val = v;
        a->cap_nnz = cn;
    }
    return 0;
}

static void bsr_free(bsr *a)
{
    free(a->ptr); free(a->col); free(a->val);
    memset(a, 0, sizeof *a);
}

void tc_amg_free(tc_amg *h)
{
    if (!h) return;
    for (int l = 0; l < TC_AMG_MAX_LEVELS; l++) {
        level *L = &h->lev[l];
        bsr_free(&L->A); bsr_free(&L->P);
        free(L->dinv); free(L->agg); free(L->B); free(L->x); free(L->rhs); free(L->res); free(L->tmp);
    }
    free(h->chol); free(h->mark); free(h->acc);
    free(h);
}

size_t tc_amg_bytes(const tc_amg *h)
{
    if (!h) return 0;
    size_t s = sizeof *h;
    for (int l = 0; l < TC_AMG_MAX_LEVELS; l++) {
        const level *L = &h->lev[l];
        const bsr *m[2] = {&L->A, &L->P};
        for (int k = 0; k < 2; k++)
            s += m[k]->cap_rows * 4 + m[k]->cap_nnz * (4 + 8 * (size_t)m[k]->br * (size_t)m[k]->bc);
        const size_t n = (size_t)L->n, b = (size_t)L->b;
        if (L->agg) s += n * 4;
        if (L->dinv) s += n * b * b * 8;
        if (L->B) s += n * b * NS * 8;
        s += ((L->x != NULL) + (L->rhs != NULL) + (L->res != NULL) + (L->tmp != NULL)) * L->cap_vec * 8;
    }
    return s + h->cap_chol * 8 + h->cap_mark * 4 + h->cap_acc * 8;
}

/* ---------------- small dense algebra ---------------- */

/* C (r x c) += A (r x k) B (k x c), all row-major */
static inline void gemm_acc(double *restrict C, const double *restrict A, const double *restrict B, int r, int k, int c)
{
    for (int i = 0; i < r; i++)
        for (int l = 0; l < k; l++) {
            const double a = A[i * k + l];
            for (int j = 0; j < c; j++) C[i * c + j] += a * B[l * c + j];
        }
}

/* In-place Cholesky of the n x n SPD matrix M (lower triangle kept); a pivot lost to round-off is
 * replaced by the diagonal's scale (that unknown is then smoothed, not solved). */
static void cholesky(double *M, int32_t n)
{
    double scale = 0.0;
    for (int32_t i = 0; i < n; i++) scale = fmax(scale, fabs(M[(size_t)i * n + i]));
    if (!(scale > 0)) scale = 1.0;
    for (int32_t j = 0; j < n; j++) {
        double *rj = M + (size_t)j * n;
        double d = rj[j];
        for (int32_t k = 0; k < j; k++) d -= rj[k] * rj[k];
        if (!(d > 1e-13 * scale)) {
            /* singular direction: decouple it */
            for (int32_t k = 0; k < j; k++) rj[k] = 0.0;
            d = scale;
        }
        const double s = sqrt(d);
        rj[j] = s;
        for (int32_t i = j + 1; i < n; i++) {
            double *ri = M + (size_t)i * n;
            double t = ri[j];
            for (int32_t k = 0; k < j; k++) t -= ri[k] * rj[k];
            ri[j] = t / s;
        }
    }
}

static void cholesky_solve(const double *L, int32_t n, const double *b, double *x)
{
    for (int32_t i = 0; i < n; i++) {
        double t = b[i];
        const double *ri = L + (size_t)i * n;
        for (int32_t k = 0; k < i; k++) t -= ri[k] * x[k];
        x[i] = t / ri[i];
    }
    for (int32_t i = n - 1; i >= 0; i--) {
        double t = x[i];
        for (int32_t k = i + 1; k < n; k++) t -= L[(size_t)k * n + i] * x[k];
        x[i] = t / L[(size_t)i * n + i];
    }
}

/* inverse of the b x b SPD block D into out (by its Cholesky factor) */
static void spd_inverse(const double *D, int b, double *out)
{
    double L[NS * NS], e[NS], x[NS];
    memcpy(L, D, (size_t)b * b * sizeof(double));
    cholesky(L, b);
    for (int j = 0; j < b; j++) {
        for (int i = 0; i < b; i++) e[i] = i == j ? 1.0 : 0.0;
        cholesky_solve(L, b, e, x);
        for (int i = 0; i < b; i++) out[i * b + j] = x[i];
    }
}

/* ---------------- the filter S of a vertex as a matrix ---------------- */

/* S_i (3x3, row-major): I for a free vertex, 0 for a pinned or held one, I - sum n n^T for a contact */
static void filter_matrix(const tc_cloth *c, int32_t i, double S[9])
{
    const int8_t f = ((const int8_t *)tc_vec_ptr(&c->vflag))[i];
    for (int k = 0; k < 9; k++) S[k] = (k % 4 == 0 && f == VC_FREE) ? 1.0 : 0.0;
    if (f != VC_CONTACT) return;
    const int8_t cnt = ((const int8_t *)tc_vec_ptr(&c->scount))[i];
    const double *N = (const double *)tc_vec_ptr(&c->snorm) + 9 * (size_t)i;
    for (int k = 0; k < 9; k++) S[k] = (k % 4 == 0) ? 1.0 : 0.0;
    for (int q = 0; q < cnt; q++)
        for (int a = 0; a < 3; a++)
            for (int b = 0; b < 3; b++) S[3 * a + b] -= N[3 * q + a] * N[3 * q + b];
}

static inline bool fully_constrained(const tc_cloth *c, int32_t i)
{
    const int8_t f = ((const int8_t *)tc_vec_ptr(&c->vflag))[i];
    return f == VC_PINNED || f == VC_HANDLE;
}

/* ---------------- the finest level's operator, row by row ---------------- */

/* a 3x3 block stored column by column, each column `stride` doubles apart, row-major */
static void from_columns(const double *src, int stride, double a[9])
{
    for (int r = 0; r < 3; r++)
        for (int q = 0; q < 3; q++) a[3 * r + q] = src[stride * q + r];
}

/* Row i of A' = S A S + (I - S) d_i (3x3 blocks row-major; its diagonal first, then the edge
 * blocks, then the flaps) from fem.c's rows, into col/val (val NULL: the columns only). The
 * hierarchy reads the finest level this way, never as a stored copy: that copy (76 bytes per block,
 * 13 blocks per row) was the largest allocation of the setup, 47 MB at 100K triangles. */
static int32_t fine_row(const tc_cloth *c, int32_t i, int32_t *col, double *val)
{
    const int32_t *rp = tc_vec_ptr(&c->rptr), *rc = tc_vec_ptr(&c->rcol), *fp = tc_vec_ptr(&c->fptr), *fc = tc_vec_ptr(&c->fcol);
    const double *D = tc_vec_ptr(&c->diag), *RB = tc_vec_ptr(&c->rblk), *FV = tc_vec_ptr(&c->fval);
    const int8_t *fl = tc_vec_ptr(&c->vflag);
    int32_t k = 0;
    col[k++] = i;
    for (int32_t s = rp[i]; s < rp[i + 1]; s++) col[k++] = rc[s];
    for (int32_t s = fp[i]; s < fp[i + 1]; s++) col[k++] = fc[s];
    if (!val) return k;
    double Si[9];
    filter_matrix(c, i, Si);
    const bool free_i = fl[i] == VC_FREE;
    {
        double a[9];
        from_columns(D + 12 * (size_t)i, 4, a);
        if (free_i) memcpy(val, a, sizeof a);
        else {
            double t[9] = {0}, u[9] = {0};
            gemm_acc(t, Si, a, 3, 3, 3);
            gemm_acc(u, t, Si, 3, 3, 3);
            const double sc = (a[0] + a[4] + a[8]) / 3.0;
            for (int r = 0; r < 9; r++) val[r] = u[r] + sc * ((r % 4 == 0 ? 1.0 : 0.0) - Si[r]);
        }
    }
    double *o = val + 9;
    for (int32_t s = rp[i]; s < rp[i + 1]; s++, o += 9) {
        const int32_t j = rc[s];
        double a[9];
        from_columns(RB + 9 * (size_t)s, 3, a);
        if (free_i && fl[j] == VC_FREE) { memcpy(o, a, sizeof a); continue; }
        double Sj[9], t[9] = {0};
        filter_matrix(c, j, Sj);
        memset(o, 0, 9 * sizeof(double));
        gemm_acc(t, Si, a, 3, 3, 3);
        gemm_acc(o, t, Sj, 3, 3, 3);
    }
    for (int32_t s = fp[i]; s < fp[i + 1]; s++, o += 9) {
        const int32_t j = fc[s];
        const double f = FV[s];
        if (free_i && fl[j] == VC_FREE) {
            for (int r = 0; r < 9; r++) o[r] = r % 4 == 0 ? f : 0.0;
            continue;
        }
        double Sj[9];
        filter_matrix(c, j, Sj);
        memset(o, 0, 9 * sizeof(double));
        gemm_acc(o, Si, Sj, 3, 3, 3);
        for (int r = 0; r < 9; r++) o[r] *= f;
    }
    return k;
}

/* The rows of a level's operator: level 0's made one at a time by fine_row into the scratch,
 * a coarse level's read in place from its stored matrix. */
typedef struct rowsrc {
    const tc_cloth *c;
    const bsr *A;          /* coarse levels */
    int32_t *col;          /* level 0: one row's columns and blocks */
    double *val;
    int32_t max_row;
} rowsrc;

static int rowsrc_init(rowsrc *s, const tc_cloth *c, const level *L, int l)
{
    memset(s, 0, sizeof *s);
    s->c = c;
    if (l > 0) { s->A = &L->A; return 0; }
    const int32_t *rp = tc_vec_ptr(&c->rptr), *fp = tc_vec_ptr(&c->fptr);
    int32_t m = 1;
    for (int32_t i = 0; i < c->nv; i++) {
        const int32_t k = 1 + (rp[i + 1] - rp[i]) + (fp[i + 1] - fp[i]);
        if (k > m) m = k;
    }
    s->max_row = m;
    s->col = malloc((size_t)m * sizeof(int32_t));
    s->val = malloc((size_t)m * 9 * sizeof(double));
    return s->col && s->val ? 0 : -1;
}

static void rowsrc_free(rowsrc *s)
{
    free(s->col); free(s->val);
    s->col = NULL; s->val = NULL;
}

/* row i: its length; its columns and blocks (b x b row-major) in *col, *val (want_val false: the
 * columns only, *val untouched) */
static inline int32_t row_get(rowsrc *s, int32_t i, const int32_t **col, const double **val, bool want_val)
{
    if (!s->A) {
        const int32_t k = fine_row(s->c, i, s->col, want_val ? s->val : NULL);
        *col = s->col;
        if (want_val) *val = s->val;
        return k;
    }
    const int32_t a = s->A->ptr[i];
    *col = s->A->col + a;
    if (want_val) *val = s->A->val + (size_t)a * s->A->br * s->A->bc;
    return s->A->ptr[i + 1] - a;
}

/* ---------------- prolongator and Galerkin product, from the rows ---------------- */

static int scratch(tc_amg *h, int32_t m, size_t acc)
{
    size_t old = h->cap_mark;
    if (grow((void **)&h->mark, &h->cap_mark, (size_t)m, sizeof(int32_t))) return -1;
    for (size_t k = old; k < h->cap_mark; k++) h->mark[k] = -1;  /* the kept ones are -1 already */
    return grow((void **)&h->acc, &h->cap_acc, acc, sizeof(double));
}

/* room for one more block in row-growing C (n block rows) */
static int bsr_push(bsr *C, size_t nnz)
{
    if (nnz < C->cap_nnz) return 0;
    return bsr_reserve(C, C->n, nnz + 1 + nnz / 2);
}

/* P = (I - w D^-1 A) T row by row (T: at most one block per row, that of the row's aggregate),
 * D^-1 the smoother's inverse diagonal blocks (level 0: S times the solver's). One pass: row i's
 * blocks are (A T)_iJ = sum over its columns j in aggregate J of A_ij T_j, so no product A T is
 * stored before it is smoothed. Instantiated for the finest (b = 3) and coarse (b = 6) blocks. */
#define PROLONGATOR(NAME, B)                                                                          \
    TC_HOT static int NAME(tc_amg *h, rowsrc *s, const level *L, int l, const bsr *T, bsr *P)          \
    {                                                                                                 \
        enum { BS = B * NS };                                                                         \
        const int32_t n = L->n;                                                                       \
        P->n = n; P->m = T->m; P->br = B; P->bc = NS;                                                 \
        if (scratch(h, T->m, 64 * BS)) return -1;                                                     \
        int32_t *mark = h->mark;                                                                      \
        /* the pattern's size first (columns only), so P takes what it needs and no more */           \
        size_t k = 0;                                                                                 \
        for (int32_t i = 0; i < n; i++) {                                                             \
            const int32_t *col;                                                                       \
            const double *unused = NULL;                                                              \
            const int32_t len = row_get(s, i, &col, &unused, false);                                  \
            for (int32_t a = 0; a < len; a++) {                                                       \
                const int32_t j = col[a];                                                             \
                if (T->ptr[j + 1] == T->ptr[j]) continue;                                             \
                const int32_t J = T->col[T->ptr[j]];                                                  \
                if (mark[J] != i) { mark[J] = i; k++; }                                               \
            }                                                                                         \
        }                                                                                             \
        for (int32_t J = 0; J < T->m; J++) mark[J] = -1;                                              \
        if (bsr_reserve(P, n, k)) return -1;                                                          \
        k = 0;                                                                                        \
        for (int32_t i = 0; i < n; i++) {                                                             \
            P->ptr[i] = (int32_t)k;                                                                   \
            const int32_t *col;                                                                       \
            const double *val;                                                                        \
            const int32_t len = row_get(s, i, &col, &val, true);                                      \
            const size_t s0 = k;                                                                      \
            for (int32_t a = 0; a < len; a++) {                                                       \
                const int32_t j = col[a];                                                             \
                if (T->ptr[j + 1] == T->ptr[j]) continue;                                             \
                const int32_t J = T->col[T->ptr[j]];                                                  \
                if (mark[J] < 0) {                                                                    \
                    if (bsr_push(P, k) || grow((void **)&h->acc, &h->cap_acc, (k - s0 + 1) * BS, sizeof(double))) \
                        return -1;                                                                    \
                    mark[J] = (int32_t)k;                                                             \
                    P->col[k] = J;                                                                    \
                    memset(h->acc + (k - s0) * BS, 0, BS * sizeof(double));                           \
                    k++;                                                                              \
                }                                                                                     \
                double *o = h->acc + (size_t)(mark[J] - (int32_t)s0) * BS;                            \
                const double *ab = val + (size_t)a * B * B, *tb = T->val + (size_t)T->ptr[j] * BS;    \
                for (int r = 0; r < B; r++)                                                           \
                    for (int q = 0; q < B; q++) {                                                     \
                        const double x = ab[r * B + q];                                               \
                        for (int m = 0; m < NS; m++) o[r * NS + m] += x * tb[q * NS + m];             \
                    }                                                                                 \
            }                                                                                         \
            double M[B * B];                                                                          \
            if (l == 0) {                                                                             \
                const double *p = (const double *)tc_vec_ptr(&s->c->pinv) + 9 * (size_t)i;            \
                double S[9];                                                                          \
                filter_matrix(s->c, i, S);                                                            \
                memset(M, 0, sizeof M);                                                               \
                gemm_acc(M, S, p, 3, 3, 3);                                                           \
            } else {                                                                                  \
                memcpy(M, L->dinv + (size_t)i * B * B, sizeof M);                                     \
            }                                                                                         \
            const int32_t Ti = T->ptr[i + 1] > T->ptr[i] ? T->col[T->ptr[i]] : -1;                    \
            for (size_t a = s0; a < k; a++) {                                                         \
                const double *v = h->acc + (a - s0) * BS;                                             \
                double *o = P->val + a * BS;                                                          \
                for (int r = 0; r < B; r++)                                                           \
                    for (int m = 0; m < NS; m++) {                                                    \
                        double t = 0.0;                                                               \
                        for (int q = 0; q < B; q++) t += M[r * B + q] * v[q * NS + m];                \
                        o[r * NS + m] = -L->omega * t;                                                \
                    }                                                                                 \
                if (P->col[a] == Ti)                                                                  \
                    for (int q = 0; q < BS; q++) o[q] += T->val[(size_t)T->ptr[i] * BS + q];          \
                mark[P->col[a]] = -1;                                                                 \
            }                                                                                         \
        }                                                                                             \
        P->ptr[n] = (int32_t)k;                                                                       \
        return 0;                                                                                     \
    }
PROLONGATOR(prolongator_3, 3)
PROLONGATOR(prolongator_6, 6)
#undef PROLONGATOR

/* slot of column J in row I of C (its columns sorted), -1 if absent */
static inline int32_t find_slot(const bsr *C, int32_t I, int32_t J)
{
    int32_t lo = C->ptr[I], hi = C->ptr[I + 1] - 1;
    while (lo <= hi) {
        const int32_t mid = (lo + hi) >> 1, v = C->col[mid];
        if (v == J) return mid;
        if (v < J) lo = mid + 1; else hi = mid - 1;
    }
    return -1;
}

/* C = P^T A P (NS x NS blocks, columns sorted in each row). Its pattern first, from the patterns
 * alone (the rows of P^T: the fine rows of each aggregate); then one pass over the fine rows, each
 * making its row of A P once in a small accumulator and adding P_iI^T (A P)_iJ into C's upper
 * blocks (J >= I; the lower ones are their transposes). So neither A P nor P^T is ever stored: at
 * 100K triangles they were 41 and 20 MB at the peak of the setup. */
#define GALERKIN(NAME, B)                                                                             \
    TC_HOT static int NAME(tc_amg *h, rowsrc *s, const bsr *P, bsr *C)                                \
    {                                                                                                 \
        enum { BS = B * NS, CS = NS * NS };                                                           \
        const int32_t n = P->n, na = P->m;                                                            \
        int rc = -1;                                                                                  \
        int32_t *tptr = calloc((size_t)na + 1, sizeof(int32_t));                                      \
        int32_t *trow = malloc(((size_t)P->ptr[n] + 1) * sizeof(int32_t));                            \
        int32_t *cols = malloc(((size_t)na + 1) * sizeof(int32_t)); /* one row's columns of A P */    \
        if (!tptr || !trow || !cols || scratch(h, na, 64 * BS)) goto done;                            \
        for (int32_t a = 0; a < P->ptr[n]; a++) tptr[P->col[a] + 1]++;                                \
        for (int32_t I = 0; I < na; I++) tptr[I + 1] += tptr[I];                                      \
        for (int32_t i = 0; i < n; i++)                                                               \
            for (int32_t a = P->ptr[i]; a < P->ptr[i + 1]; a++) trow[tptr[P->col[a]]++] = i;          \
        for (int32_t I = na; I > 0; I--) tptr[I] = tptr[I - 1];                                       \
        tptr[0] = 0;                                                                                  \
        int32_t *mark = h->mark;                                                                      \
        C->n = C->m = na; C->br = C->bc = NS;                                                         \
        /* two symbolic passes, the count then the columns, so C takes what it needs and no more */    \
        size_t k = 0;                                                                                 \
        for (int pass = 0; pass < 2; pass++) {                                                        \
        if (pass == 1 && bsr_reserve(C, na, k)) goto done;                                            \
        k = 0;                                                                                        \
        for (int32_t I = 0; I < na; I++) {                                                            \
            if (pass) C->ptr[I] = (int32_t)k;                                                         \
            const size_t s0 = k;                                                                      \
            for (int32_t t = tptr[I]; t < tptr[I + 1]; t++) {                                         \
                const int32_t *col;                                                                   \
                const double *unused = NULL;                                                          \
                const int32_t len = row_get(s, trow[t], &col, &unused, false);                        \
                for (int32_t a = 0; a < len; a++) {                                                   \
                    const int32_t j = col[a];                                                         \
                    for (int32_t b = P->ptr[j]; b < P->ptr[j + 1]; b++) {                             \
                        const int32_t J = P->col[b];                                                  \
                        if (mark[J] == I) continue;                                                   \
                        mark[J] = I;                                                                  \
                        if (pass) C->col[k] = J;                                                      \
                        k++;                                                                          \
                    }                                                                                 \
                }                                                                                     \
            }                                                                                         \
            /* sorted columns (a few dozen: insertion sort) */                                        \
            if (pass) for (size_t a = s0 + 1; a < k; a++) {                                           \
                const int32_t v = C->col[a];                                                          \
                size_t b = a;                                                                         \
                while (b > s0 && C->col[b - 1] > v) { C->col[b] = C->col[b - 1]; b--; }               \
                C->col[b] = v;                                                                        \
            }                                                                                         \
        }                                                                                             \
        for (int32_t J = 0; J < na; J++) mark[J] = -1;                                                \
        }                                                                                             \
        C->ptr[na] = (int32_t)k;                                                                      \
        memset(C->val, 0, k * CS * sizeof(double));                                                   \
        for (int32_t i = 0; i < n; i++) {                                                             \
            if (P->ptr[i + 1] == P->ptr[i]) continue;                                                 \
            const int32_t *col;                                                                       \
            const double *val;                                                                        \
            const int32_t len = row_get(s, i, &col, &val, true);                                      \
            int32_t m = 0;                                                                            \
            for (int32_t a = 0; a < len; a++) {                                                       \
                const int32_t j = col[a];                                                             \
                const double *ab = val + (size_t)a * B * B;                                           \
                for (int32_t b = P->ptr[j]; b < P->ptr[j + 1]; b++) {                                 \
                    const int32_t J = P->col[b];                                                      \
                    if (mark[J] < 0) {                                                                \
                        if (grow((void **)&h->acc, &h->cap_acc, ((size_t)m + 1) * BS, sizeof(double))) goto done; \
                        mark[J] = m;                                                                  \
                        cols[m] = J;                                                                  \
                        memset(h->acc + (size_t)m * BS, 0, BS * sizeof(double));                      \
                        m++;                                                                          \
                    }                                                                                 \
                    double *o = h->acc + (size_t)mark[J] * BS;                                        \
                    const double *pb = P->val + (size_t)b * BS;                                       \
                    for (int r = 0; r < B; r++)                                                       \
                        for (int q = 0; q < B; q++) {                                                 \
                            const double x = ab[r * B + q];                                           \
                            for (int e = 0; e < NS; e++) o[r * NS + e] += x * pb[q * NS + e];         \
                        }                                                                             \
                }                                                                                     \
            }                                                                                         \
            for (int32_t b = P->ptr[i]; b < P->ptr[i + 1]; b++) {                                     \
                const int32_t I = P->col[b];                                                          \
                const double *pb = P->val + (size_t)b * BS;                                           \
                for (int32_t q = 0; q < m; q++) {                                                     \
                    const int32_t J = cols[q];                                                        \
                    if (J < I) continue;                                                              \
                    const int32_t slot = find_slot(C, I, J);                                          \
                    if (slot < 0) continue; /* cannot happen: the pattern has every (I, J) */         \
                    double *o = C->val + (size_t)slot * CS;                                           \
                    const double *v = h->acc + (size_t)q * BS;                                        \
                    for (int r = 0; r < B; r++)                                                       \
                        for (int x = 0; x < NS; x++) {                                                \
                            const double p = pb[r * NS + x];                                          \
                            for (int e = 0; e < NS; e++) o[x * NS + e] += p * v[r * NS + e];          \
                        }                                                                             \
                }                                                                                     \
            }                                                                                         \
            for (int32_t q = 0; q < m; q++) mark[cols[q]] = -1;                                       \
        }                                                                                             \
        /* the lower blocks: transposes of the upper ones */                                          \
        for (int32_t I = 0; I < na; I++)                                                              \
            for (int32_t a = C->ptr[I]; a < C->ptr[I + 1]; a++) {                                     \
                const int32_t J = C->col[a];                                                          \
                if (J <= I) continue;                                                                 \
                const int32_t t = find_slot(C, J, I);                                                 \
                if (t < 0) continue;                                                                  \
                const double *u = C->val + (size_t)a * CS;                                            \
                double *o = C->val + (size_t)t * CS;                                                  \
                for (int r = 0; r < NS; r++)                                                          \
                    for (int q = 0; q < NS; q++) o[q * NS + r] = u[r * NS + q];                       \
            }                                                                                         \
        rc = 0;                                                                                       \
    done:                                                                                             \
        free(tptr); free(trow); free(cols);                                                           \
        return rc;                                                                                    \
    }
GALERKIN(galerkin_3, 3)
GALERKIN(galerkin_6, 6)
#undef GALERKIN

#define BSR_APPLY(NAME, BR, BC)                                                                          \
    TC_HOT static void NAME(const bsr *A, const double *x, double *y)                                        \
    {                                                                                                 \
        for (int32_t i = 0; i < A->n; i++) {                                                          \
            double acc[BR] = {0};                                                                     \
            for (int32_t a = A->ptr[i]; a < A->ptr[i + 1]; a++) {                                     \
                const double *v = A->val + (size_t)a * BR * BC, *xj = x + (size_t)A->col[a] * BC;     \
                for (int r = 0; r < BR; r++)                                                          \
                    for (int q = 0; q < BC; q++) acc[r] += v[r * BC + q] * xj[q];                     \
            }                                                                                         \
            for (int r = 0; r < BR; r++) y[(size_t)i * BR + r] = acc[r];                              \
        }                                                                                             \
    }
BSR_APPLY(apply_36, 3, 6)
BSR_APPLY(apply_66, 6, 6)
#undef BSR_APPLY

/* y = P^T x without storing P^T (a scatter over P's rows: the restriction of the V-cycle) */
#define BSR_APPLY_T(NAME, BR, BC)                                                                        \
    TC_HOT static void NAME(const bsr *P, const double *x, double *y)                                 \
    {                                                                                                 \
        memset(y, 0, (size_t)P->m * BC * sizeof(double));                                             \
        for (int32_t i = 0; i < P->n; i++) {                                                          \
            const double *xi = x + (size_t)i * BR;                                                    \
            for (int32_t a = P->ptr[i]; a < P->ptr[i + 1]; a++) {                                     \
                const double *v = P->val + (size_t)a * BR * BC;                                       \
                double *yj = y + (size_t)P->col[a] * BC;                                              \
                for (int r = 0; r < BR; r++)                                                          \
                    for (int q = 0; q < BC; q++) yj[q] += v[r * BC + q] * xi[r];                      \
            }                                                                                         \
        }                                                                                             \
    }
BSR_APPLY_T(apply_t_36, 3, 6)
BSR_APPLY_T(apply_t_66, 6, 6)
#undef BSR_APPLY_T

static void bsr_apply_transposed(const bsr *P, const double *x, double *y)
{
    if (P->br == 3) apply_t_36(P, x, y);
    else apply_t_66(P, x, y);
}

static void bsr_apply(const bsr *A, const double *x, double *y)
{
    if (A->br == 3) apply_36(A, x, y);
    else apply_66(A, x, y);
}

/* ---------------- aggregation ---------------- */

static double fro2(const double *v, int n)
{
    double s = 0.0;
    for (int k = 0; k < n; k++) s += v[k] * v[k];
    return s;
}

/* The strong graph of a level (theta on the Frobenius norms: |A_ij|_F > theta sqrt(|A_ii| |A_jj|)),
 * in sptr/scol, and dn the diagonal blocks' norms (0: the row takes no part: a fully constrained
 * vertex of the finest level). Only the pattern is kept: 4 bytes per strong block. */
static int strength_graph(rowsrc *s, const tc_cloth *c, int l, int32_t n, int b, double *dn, int32_t **sptr_out,
                          int32_t **scol_out)
{
    const int bb = b * b;
    size_t nnz = 0;
    for (int32_t i = 0; i < n; i++) {
        const int32_t *col;
        const double *val;
        const int32_t len = row_get(s, i, &col, &val, true);
        nnz += (size_t)len;
        dn[i] = 0.0;
        if (l == 0 && fully_constrained(c, i)) continue;
        for (int32_t a = 0; a < len; a++)
            if (col[a] == i) { dn[i] = sqrt(fro2(val + (size_t)a * bb, bb)); break; }
    }
    int32_t *sptr = malloc(((size_t)n + 1) * sizeof(int32_t)), *scol = malloc((nnz + 1) * sizeof(int32_t));
    if (!sptr || !scol) { free(sptr); free(scol); return -1; }
    int32_t k = 0;
    for (int32_t i = 0; i < n; i++) {
        sptr[i] = k;
        if (dn[i] <= 0.0) continue;
        const int32_t *col;
        const double *val;
        const int32_t len = row_get(s, i, &col, &val, true);
        for (int32_t a = 0; a < len; a++) {
            const int32_t j = col[a];
            if (j == i || dn[j] <= 0.0) continue;
            if (fro2(val + (size_t)a * bb, bb) > TC_AMG_THETA * TC_AMG_THETA * dn[i] * dn[j]) scol[k++] = j;
        }
    }
    sptr[n] = k;
    *sptr_out = sptr;
    *scol_out = scol;
    return 0;
}

/* The three passes of standard aggregation on the strong graph; rows with dn <= 0 (excluded) and
 * rows with no strong neighbour stay out (-1). Returns the number of aggregates. */
static int32_t aggregate(int32_t n, const int32_t *sptr, const int32_t *scol, const double *dn, int32_t *agg,
                         int32_t *pass1)
{
    int32_t na = 0;
    for (int32_t i = 0; i < n; i++) agg[i] = -1;
    for (int32_t i = 0; i < n; i++) {
        if (dn[i] <= 0.0 || sptr[i + 1] == sptr[i]) continue;
        bool ok = true;
        for (int32_t a = sptr[i]; a < sptr[i + 1] && ok; a++) ok = agg[scol[a]] < 0;
        if (!ok) continue;
        agg[i] = na;
        for (int32_t a = sptr[i]; a < sptr[i + 1]; a++) agg[scol[a]] = na;
        na++;
    }
    memcpy(pass1, agg, (size_t)n * sizeof(int32_t));
    for (int32_t i = 0; i < n; i++) {
        if (agg[i] >= 0 || dn[i] <= 0.0) continue;
        for (int32_t a = sptr[i]; a < sptr[i + 1]; a++)
            if (pass1[scol[a]] >= 0) { agg[i] = pass1[scol[a]]; break; }
    }
    for (int32_t i = 0; i < n; i++) {
        if (agg[i] >= 0 || dn[i] <= 0.0) continue;
        bool any = false;
        for (int32_t a = sptr[i]; a < sptr[i + 1]; a++)
            if (agg[scol[a]] < 0) { agg[scol[a]] = na; any = true; }
        if (any) agg[i] = na++;
    }
    return na;
}

/* ---------------- tentative prolongator ---------------- */

/* T (n x na blocks, b x NS) from the near-null space B (n*b x NS, row-major) by a QR of each
 * aggregate's rows; Bc (na*NS x NS) gets the R factors. Bf is scratch of n*b*NS. */
static int tentative(tc_amg *h, level *L, const double *B, bsr *T, double *Bc, int32_t *dead)
{
    const int32_t n = L->n, na = L->nagg;
    const int b = L->b;
    T->n = n; T->m = na; T->br = b; T->bc = NS;
    if (bsr_reserve(T, n, (size_t)n)) return -1;
    /* rows of each aggregate, by a counting sort */
    int32_t *start = calloc((size_t)na + 1, sizeof(int32_t)), *rows = malloc(((size_t)n + 1) * sizeof(int32_t));
    if (!start || !rows) { free(start); free(rows); return -1; }
    for (int32_t i = 0; i < n; i++) if (L->agg[i] >= 0) start[L->agg[i] + 1]++;
    for (int32_t a = 0; a < na; a++) start[a + 1] += start[a];
    for (int32_t i = 0; i < n; i++) if (L->agg[i] >= 0) rows[start[L->agg[i]]++] = i;
    for (int32_t a = na; a > 0; a--) start[a] = start[a - 1];
    start[0] = 0;
    /* T's pattern: one block per aggregated row */
    int32_t k = 0;
    for (int32_t i = 0; i < n; i++) {
        T->ptr[i] = k;
        if (L->agg[i] >= 0) { T->col[k] = L->agg[i]; memcpy(T->val + (size_t)k * b * NS, B + (size_t)i * b * NS, (size_t)b * NS * sizeof(double)); k++; }
    }
    T->ptr[n] = k;
    (void)h;
    /* modified Gram-Schmidt, twice, over the aggregate's stacked blocks (T's values in place) */
    for (int32_t a = 0; a < na; a++) {
        double *R = Bc + (size_t)a * NS * NS;
        memset(R, 0, NS * NS * sizeof(double));
        double cn[NS] = {0};
        for (int32_t q = start[a]; q < start[a + 1]; q++) {
            const double *t = T->val + (size_t)T->ptr[rows[q]] * b * NS;
            for (int r = 0; r < b; r++)
                for (int j = 0; j < NS; j++) cn[j] += t[r * NS + j] * t[r * NS + j];
        }
        double big = 0.0;
        for (int j = 0; j < NS; j++) big = fmax(big, cn[j]);
        for (int j = 0; j < NS; j++) {
            for (int pass = 0; pass < 2; pass++)
                for (int i = 0; i < j; i++) {
                    double d = 0.0;
                    for (int32_t q = start[a]; q < start[a + 1]; q++) {
                        const double *t = T->val + (size_t)T->ptr[rows[q]] * b * NS;
                        for (int r = 0; r < b; r++) d += t[r * NS + i] * t[r * NS + j];
                    }
                    R[i * NS + j] += d;
                    for (int32_t q = start[a]; q < start[a + 1]; q++) {
                        double *t = T->val + (size_t)T->ptr[rows[q]] * b * NS;
                        for (int r = 0; r < b; r++) t[r * NS + j] -= d * t[r * NS + i];
                    }
                }
            double nn = 0.0;
            for (int32_t q = start[a]; q < start[a + 1]; q++) {
                const double *t = T->val + (size_t)T->ptr[rows[q]] * b * NS;
                for (int r = 0; r < b; r++) nn += t[r * NS + j] * t[r * NS + j];
            }
            /* a mode the aggregate cannot carry (lost to cancellation): a zero column */
            const bool lost = !(nn > 1e-12 * cn[j]) || !(nn > 1e-24 * big);
            const double s = lost ? 0.0 : 1.0 / sqrt(nn);
            R[j * NS + j] = lost ? 0.0 : sqrt(nn);
            dead[(size_t)a * NS + j] = lost;
            for (int32_t q = start[a]; q < start[a + 1]; q++) {
                double *t = T->val + (size_t)T->ptr[rows[q]] * b * NS;
                for (int r = 0; r < b; r++) t[r * NS + j] *= s;
            }
            if (lost) for (int i = 0; i < j; i++) R[i * NS + j] = 0.0;
        }
    }
    free(start); free(rows);
    return 0;
}

/* ---------------- per-level pieces ---------------- */

/* The V-cycle's vectors of a level. The finest has no x and rhs of its own: the V-cycle gets them
 * from the solver (its residual and output), and only the spectral radius needs an x there, for a
 * moment (a scratch of its own): 2 of 4 vectors of 3 doubles per vertex, 2.4 MB at 100K triangles. */
static int level_vectors(level *L, bool finest)
{
    const size_t nb = (size_t)L->n * L->b;
    if (nb <= L->cap_vec && L->res) return 0;
    free(L->x); free(L->rhs); free(L->res); free(L->tmp);
    L->x = L->rhs = NULL;
    if (!finest) { L->x = malloc(nb * sizeof(double)); L->rhs = malloc(nb * sizeof(double)); }
    L->res = malloc(nb * sizeof(double)); L->tmp = malloc(nb * sizeof(double));
    L->cap_vec = ((finest || (L->x && L->rhs)) && L->res && L->tmp) ? nb : 0;
    return L->cap_vec ? 0 : -1;
}

/* y = A x on level l (level 0: S A x by fem.c's product, x on the range of S) */
static void level_apply(const tc_cloth *c, const level *L, int l, const double *x, double *y)
{
    if (l == 0) {
        tc_matvec(c, x, y);
        tc_constraint_filter(c, y);
    } else {
        bsr_apply(&L->A, x, y);
    }
}

/* y = D^-1 x on level l (level 0: S P x with the solver's inverse diagonal blocks) */
static void level_dinv(const tc_cloth *c, const level *L, int l, const double *x, double *y)
{
    if (l == 0) {
        const double *P = tc_vec_ptr(&c->pinv);
        for (int32_t i = 0; i < c->nv; i++) {
            const double *p = P + 9 * (size_t)i, *xi = x + 3 * (size_t)i;
            double *o = y + 3 * (size_t)i;
            o[0] = p[0] * xi[0] + p[1] * xi[1] + p[2] * xi[2];
            o[1] = p[3] * xi[0] + p[4] * xi[1] + p[5] * xi[2];
            o[2] = p[6] * xi[0] + p[7] * xi[1] + p[8] * xi[2];
        }
        tc_constraint_filter(c, y);
        return;
    }
    const int b = L->b;
    for (int32_t i = 0; i < L->n; i++) {
        const double *m = L->dinv + (size_t)i * b * b, *xi = x + (size_t)i * b;
        double *o = y + (size_t)i * b;
        for (int r = 0; r < b; r++) {
            double s = 0.0;
            for (int q = 0; q < b; q++) s += m[r * b + q] * xi[q];
            o[r] = s;
        }
    }
}

/* rho(D^-1 A) by power iterations from a fixed, mesh-independent start (the estimate's 1.1 covers
 * its shortfall, so w rho < 2 and the Jacobi step converges in A's norm). */
static double spectral_radius(const tc_cloth *c, level *L, int l)
{
    const size_t nb = (size_t)L->n * L->b;
    double *x = L->x ? L->x : malloc((nb ? nb : 1) * sizeof(double)), *y = L->res, *z = L->tmp;  /* finest: no x */
    if (!x) return -1.0;
    for (size_t k = 0; k < nb; k++) x[k] = 1.0 + 0.5 * sin(1.7 * (double)k);
    if (l == 0) tc_constraint_filter(c, x);
    double rho = 0.0;
    for (int it = 0; it < TC_AMG_POWER_ITERATIONS; it++) {
        level_apply(c, L, l, x, y);
        level_dinv(c, L, l, y, z);
        double nz = 0.0, nx = 0.0;
        for (size_t k = 0; k < nb; k++) { nz += z[k] * z[k]; nx += x[k] * x[k]; }
        if (!(nx > 0) || !(nz > 0)) break;
        rho = sqrt(nz / nx);
        const double s = 1.0 / sqrt(nz);
        for (size_t k = 0; k < nb; k++) x[k] = z[k] * s;
    }
    if (x != L->x) free(x);
    return rho > 0 ? 1.1 * rho : 1.0;
}
/* inverse diagonal blocks of a coarse level; a dead unknown gets the live diagonal's scale first */
static int coarse_diagonal(level *L, const int32_t *dead)
{
    const int b = L->b;
    double *di = realloc(L->dinv, ((size_t)L->n * b * b + 1) * sizeof(double));
    if (!di) return -1;
    L->dinv = di;
    for (int32_t i = 0; i < L->n; i++) {
        double *d = NULL;
        for (int32_t a = L->A.ptr[i]; a < L->A.ptr[i + 1]; a++)
            if (L->A.col[a] == i) d = L->A.val + (size_t)a * b * b;
        double *o = L->dinv + (size_t)i * b * b;
        if (!d) { memset(o, 0, (size_t)b * b * sizeof(double)); continue; }
        double tr = 0.0;
        int live = 0;
        for (int k = 0; k < b; k++) if (!dead[(size_t)i * b + k]) { tr += d[k * b + k]; live++; }
        const double sc = live && tr > 0 ? tr / live : 1.0;
        for (int k = 0; k < b; k++) if (dead[(size_t)i * b + k]) d[k * b + k] = sc;
        spd_inverse(d, b, o);
    }
    return 0;
}

/* the near-null space of the finest level: rigid-body modes about each aggregate's centroid,
 * filtered by S (row-major, 3 rows of NS per vertex) */
static void fine_modes(const tc_cloth *c, const level *L, double *B)
{
    const double *x = tc_vec_ptr(&c->x);
    double *cen = calloc((size_t)L->nagg * 4 + 1, sizeof(double));
    if (cen) {
        for (int32_t i = 0; i < L->n; i++) {
            const int32_t a = L->agg[i];
            if (a < 0) continue;
            for (int k = 0; k < 3; k++) cen[4 * a + k] += x[3 * i + k];
            cen[4 * a + 3] += 1.0;
        }
    }
    for (int32_t i = 0; i < L->n; i++) {
        double *r = B + (size_t)i * 3 * NS;
        const int32_t a = L->agg[i];
        double d[3] = {0, 0, 0};
        if (a >= 0 && cen && cen[4 * a + 3] > 0)
            for (int k = 0; k < 3; k++) d[k] = x[3 * i + k] - cen[4 * a + k] / cen[4 * a + 3];
        /* columns: translations x, y, z; rotations about x, y, z (w x d) */
        const double m[3 * NS] = {1, 0, 0, 0, d[2], -d[1],
                                  0, 1, 0, -d[2], 0, d[0],
                                  0, 0, 1, d[1], -d[0], 0};
        double S[9];
        filter_matrix(c, i, S);
        memset(r, 0, 3 * NS * sizeof(double));
        gemm_acc(r, S, m, 3, 3, NS);
    }
    free(cen);
}

/* ---------------- the hierarchy ---------------- */

tc_amg *tc_amg_new(void)
{
    return calloc(1, sizeof(tc_amg));
}

int tc_amg_levels(const tc_amg *h) { return h ? h->nlev : 0; }

bool tc_amg_valid(const tc_amg *h, const tc_cloth *c)
{
    /* built for this mesh: its vectors have this many vertices and its aggregates these pairs */
    return h && h->nlev > 0 && h->nv == c->nv && h->pair_version == c->pair_version;
}

bool tc_amg_needs_aggregation(const tc_amg *h, const tc_cloth *c)
{
    return !h || h->nlev == 0 || h->pair_version != c->pair_version || h->nv != c->nv ||
           h->numeric_builds >= TC_AMG_REAGGREGATE;
}

/* Builds the hierarchy for the current matrix (after tc_assemble and tc_precondition_build), the
 * aggregates anew when `aggregate_again` or the mesh changed, else the kept ones. */
int tc_amg_build(tc_amg *h, const tc_cloth *c, bool aggregate_again)
{
    aggregate_again = aggregate_again || tc_amg_needs_aggregation(h, c);
    int rc = -1;
    int32_t *pass1 = NULL, *dead = NULL, *sptr = NULL, *scol = NULL;
    double *dn = NULL, *B = NULL;
    bsr T = {0};
    rowsrc src = {0};
    level *L0 = &h->lev[0];
    /* The old operators and prolongators go first: they are all made again, and kept they would
     * sit under this build's scratch (the near-null space, T), the peak of a refresh. The finest
     * level never has a stored operator (fine_row). */
    for (int l = 0; l < TC_AMG_MAX_LEVELS; l++) { bsr_free(&h->lev[l].A); bsr_free(&h->lev[l].P); }
    h->nlev = 0;
    L0->n = c->nv; L0->b = 3;
    if (level_vectors(L0, true)) goto out;
    const double rho0 = spectral_radius(c, L0, 0);
    if (rho0 < 0) goto out;  /* out of memory */
    L0->omega = 4.0 / (3.0 * rho0);
    int nlev = 1;
    for (int l = 0; l + 1 < TC_AMG_MAX_LEVELS; l++) {
        level *L = &h->lev[l], *N = &h->lev[l + 1];
        const int32_t n = L->n;
        if ((size_t)n * L->b <= TC_AMG_COARSEST) break;
        rowsrc_free(&src);
        if (rowsrc_init(&src, c, L, l)) goto out;
        /* aggregates */
        if (aggregate_again || l >= h->nlev - 1) {
            free(dn); free(pass1);
            dn = malloc((size_t)n * sizeof(double));
            pass1 = malloc((size_t)n * sizeof(int32_t));
            if (!dn || !pass1) goto out;
            int32_t *na = realloc(L->agg, (size_t)n * sizeof(int32_t));
            if (!na) goto out;
            L->agg = na;
            if (strength_graph(&src, c, l, n, L->b, dn, &sptr, &scol)) goto out;
            L->nagg = aggregate(n, sptr, scol, dn, L->agg, pass1);
            free(sptr); free(scol);
            sptr = scol = NULL;
        }
        const int32_t na = L->nagg;
        if (na == 0 || (double)na > TC_AMG_MIN_COARSENING * (double)n) break;
        /* near-null space and tentative prolongator */
        free(B);
        B = malloc((size_t)n * L->b * NS * sizeof(double));
        free(dead);
        dead = malloc((size_t)na * NS * sizeof(int32_t));
        if (!B || !dead) goto out;
        if (l == 0) fine_modes(c, L, B);
        else memcpy(B, L->B, (size_t)n * L->b * NS * sizeof(double));
        double *Bc = realloc(N->B, (size_t)na * NS * NS * sizeof(double));
        if (!Bc) goto out;
        N->B = Bc;
        if (tentative(h, L, B, &T, Bc, dead)) goto out;
        free(B);  /* T holds it now, orthonormalised */
        B = NULL;
        /* smoothed prolongator, then the Galerkin operator, both straight from the rows */
        if ((l == 0 ? prolongator_3 : prolongator_6)(h, &src, L, l, &T, &L->P)) goto out;
        bsr_free(&T);
        if ((l == 0 ? galerkin_3 : galerkin_6)(h, &src, &L->P, &N->A)) goto out;
        N->n = na; N->b = NS;
        if (coarse_diagonal(N, dead) || level_vectors(N, false)) goto out;
        N->omega = 4.0 / (3.0 * spectral_radius(c, N, l + 1));
        nlev = l + 2;
    }
    /* coarsest level: a dense Cholesky factor */
    {
        level *C = &h->lev[nlev - 1];
        const int32_t m = C->n * C->b;
        if (nlev > 1 && m <= TC_AMG_DENSE_MAX) {
            if (grow((void **)&h->chol, &h->cap_chol, (size_t)m * m, sizeof(double))) goto out;
            memset(h->chol, 0, (size_t)m * m * sizeof(double));
            const int b = C->b;
            for (int32_t i = 0; i < C->n; i++)
                for (int32_t a = C->A.ptr[i]; a < C->A.ptr[i + 1]; a++) {
                    const int32_t j = C->A.col[a];
                    const double *v = C->A.val + (size_t)a * b * b;
                    for (int r = 0; r < b; r++)
                        for (int q = 0; q < b; q++) h->chol[(size_t)(i * b + r) * m + (j * b + q)] = v[r * b + q];
                }
            cholesky(h->chol, m);
        }
        h->nc = nlev > 1 && m <= TC_AMG_DENSE_MAX ? m : 0;
    }
    h->nlev = nlev;
    h->pair_version = c->pair_version;
    h->nv = c->nv;
    h->numeric_builds = aggregate_again ? 0 : h->numeric_builds + 1;
    rc = 0;
out:
    bsr_free(&T);
    rowsrc_free(&src);
    free(pass1); free(dead); free(dn); free(B); free(sptr); free(scol);
    if (rc) h->nlev = 0;
    return rc;
}

/* ---------------- the V-cycle ---------------- */

static void vcycle(const tc_cloth *c, tc_amg *h, int l, const double *b, double *x)
{
    level *L = &h->lev[l];
    const size_t nb = (size_t)L->n * L->b;
    if (l == h->nlev - 1) {
        if (h->nc) { cholesky_solve(h->chol, h->nc, b, x); return; }
        /* no factor (a level too small for a hierarchy, or one coarsening stalled on): damped
           Jacobi steps from zero, a symmetric positive operator (w rho < 2) */
        double *r = L->res, *t = L->tmp;
        level_dinv(c, L, l, b, x);
        for (size_t k = 0; k < nb; k++) x[k] *= L->omega;
        for (int s = 1; s < TC_AMG_COARSE_SWEEPS; s++) {
            level_apply(c, L, l, x, r);
            for (size_t k = 0; k < nb; k++) r[k] = b[k] - r[k];
            level_dinv(c, L, l, r, t);
            for (size_t k = 0; k < nb; k++) x[k] += L->omega * t[k];
        }
        return;
    }
    double *r = L->res, *t = L->tmp;
    const double w = L->omega;
    /* pre-smoothing from zero: x = w D^-1 b */
    level_dinv(c, L, l, b, x);
    for (size_t k = 0; k < nb; k++) x[k] *= w;
    level_apply(c, L, l, x, r);
    for (size_t k = 0; k < nb; k++) r[k] = b[k] - r[k];
    level *N = &h->lev[l + 1];
    bsr_apply_transposed(&L->P, r, N->rhs);
    vcycle(c, h, l + 1, N->rhs, N->x);
    bsr_apply(&L->P, N->x, t);
    if (l == 0) tc_constraint_filter(c, t);  /* P's range is S's when the contacts changed since */
    for (size_t k = 0; k < nb; k++) x[k] += t[k];
    /* post-smoothing, the same step */
    level_apply(c, L, l, x, r);
    for (size_t k = 0; k < nb; k++) r[k] = b[k] - r[k];
    level_dinv(c, L, l, r, t);
    for (size_t k = 0; k < nb; k++) x[k] += w * t[k];
}

/* For the tests: the largest relative error of u . A_1 v against (P u) . S A (P v) by the solver's
 * product, over a few pseudo-random coarse u, v (the Galerkin product made from the rows must be
 * that triple product), and of u . A_1 v against v . A_1 u (its symmetry). -1 without a level 1. */
double tc_amg_galerkin_error(const tc_cloth *c, tc_amg *h)
{
    if (!h || h->nlev < 2) return -1.0;
    level *L = &h->lev[0], *N = &h->lev[1];
    const size_t nf = (size_t)L->n * 3, nc = (size_t)N->n * NS;
    double *u = malloc(nc * sizeof(double)), *v = malloc(nc * sizeof(double)), *w = malloc(nc * sizeof(double));
    double *pu = malloc(nf * sizeof(double)), *pv = malloc(nf * sizeof(double)), *apv = malloc(nf * sizeof(double));
    double worst = -1.0;
    if (u && v && w && pu && pv && apv) {
        worst = 0.0;
        for (int trial = 0; trial < 3; trial++) {
            for (size_t k = 0; k < nc; k++) {
                u[k] = sin(0.37 * (double)k + trial);
                v[k] = cos(1.13 * (double)k - 2.0 * trial);
            }
            bsr_apply(&L->P, u, pu);
            bsr_apply(&L->P, v, pv);
            tc_matvec(c, pv, apv);
            tc_constraint_filter(c, apv);
            double fine = 0.0, scale = 0.0;
            for (size_t k = 0; k < nf; k++) { fine += pu[k] * apv[k]; scale += fabs(pu[k] * apv[k]); }
            bsr_apply(&N->A, v, w);
            double coarse = 0.0;
            for (size_t k = 0; k < nc; k++) coarse += u[k] * w[k];
            bsr_apply(&N->A, u, w);
            double swapped = 0.0;
            for (size_t k = 0; k < nc; k++) swapped += v[k] * w[k];
            if (!(scale > 0)) scale = 1.0;
            worst = fmax(worst, fmax(fabs(coarse - fine), fabs(coarse - swapped)) / scale);
        }
    }
    free(u); free(v); free(w); free(pu); free(pv); free(apv);
    return worst;
}

/* z = M^-1 r with M^-1 the V-cycle (r and z on the range of S) */
void tc_amg_apply(const tc_cloth *c, tc_amg *h, const double *r, double *z)
{
    vcycle(c, h, 0, r, z);
}
