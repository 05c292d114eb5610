/* amg.c - smoothed-aggregation algebraic multigrid (Vanek, Mandel & Brezina 1996) as the
 * preconditioner of the solver's CG where block Jacobi needs many iterations: stiff sheets, long
 * sub-steps, fine meshes (its iterations grow with dt sqrt(k / m) and with the mesh: 46 at 1K
 * triangles, 590 at 100K), while a V-cycle keeps them near ten. solver.c decides when it pays.
 *
 * What this file owns: the hierarchy (aggregates, prolongators, Galerkin coarse operators, the
 * coarsest level's Cholesky factor), its updates (a changed constraint filter, a tear) and the
 * V-cycle.
 *
 * The operator is the constrained one of the solve, S A S on the range of the filter S
 * (constraints.c); it is made definite off that range by (I - S) times a diagonal scale, so the
 * fine level's operator A' = S A S + (I - S) d is SPD and equals S A S where CG works. A' is never
 * stored: the setup reads it row by row from fem.c's rows (fine_row), and the products it needs
 * (the smoothed prolongator, the Galerkin operator P^T A' P) are made row by row too, so the setup
 * holds no copy of the fine matrix and no A P.
 *   - Strength of connection on A's 3x3 (coarse: 6x6) blocks, |A_ij|_F >= theta sqrt(|A_ii| |A_jj|);
 *     fully constrained vertices (pins, handles) take no part: the smoother alone handles them.
 *   - Aggregation: the three passes of standard aggregation (pyamg's standard_aggregation).
 *   - Near-null space: the six rigid-body modes of a shell (3 translations, 3 rotations about the
 *     aggregate's centroid, from the vertex positions); the tentative prolongator is their QR per
 *     aggregate (modified Gram-Schmidt, twice), R the next level's near-null space. A mode an
 *     aggregate cannot carry (a two-vertex aggregate has no twist about its axis) gives a zero
 *     column: that coarse unknown is decoupled with a unit-scaled diagonal.
 *   - Prolongator smoothing by one damped Jacobi step P = (I - w D^-1 A) T, w = 4/(3 rho(D^-1 A)),
 *     rho from power iterations; coarse operators A_c = P^T A P, pattern first, then one pass over
 *     the fine rows scattering P_i^T (A P)_i into the blocks of C.
 *   - Coarsest level (at most TC_AMG_COARSEST unknowns): a dense Cholesky factor.
 * P and the coarse operators are stored in float32 (computed in double, read into double): the
 * V-cycle is a preconditioner, any fixed SPD approximation serves, and half the bytes are half the
 * memory (the target is 1 KB per triangle at 100K) and half the traffic of its products.
 *
 * Contacts. The prolongator is made on the reference filter, with contact vertices free (pins and
 * handles stay fixed: they do not change within a step); the cycle prolongs with S P, so its
 * coarse operator for the current filter is P^T A' P with A' of the current S. When S changes
 * (the contact rounds of a sub-step release or slide vertices; the next sub-step's contacts), only
 * the rows of the vertices whose S changed differ, so tc_amg_update_filter adds
 * P^T (A'_new - A'_old) P over those rows to the first coarse operator (and refreshes its touched
 * diagonal blocks, and the factor when it is the coarsest): a few dozen vertices' work instead of
 * a rebuild per contact round, and the cycle stays the Galerkin one of the operator CG solves (a
 * cycle on the old filter lost half its strength: 100-766 iterations in the artist's scene). The
 * levels below keep theirs (a coarse correction of the first coarse level's smoother from a
 * slightly older operator: still SPD, so the cycle stays a symmetric positive operator).
 *
 * The matrix changes every sub-step (co-rotation, damping, contacts) while the mesh rarely does, so
 * the hierarchy is kept: the aggregates are made again only when vertices were removed or
 * renumbered, pins or handles changed, a snapshot was taken (tc_amg_forget: a resumed run must
 * build the same hierarchy as the uninterrupted one) or every TC_AMG_REAGGREGATE refreshes; after a
 * tear the new vertices join a neighbour's aggregate and the rest is refreshed numerically. The
 * numeric part (prolongators, coarse operators) is refreshed every `refresh` sub-steps (solver.c
 * says which). Between refreshes the finest level is still the current matrix; only the coarse
 * correction is that of a slightly older one.
 *
 * The cycle: a V-cycle with one damped block Jacobi step before and after the coarse correction,
 * a symmetric operator, so CG stays CG. The finest level never uses a copy of A': its products are
 * fem.c's row product (tc_matvec) with the filter folded into the passes around it: one pass for
 * the pre-smoothing, one for residual, filter and restriction input, one for prolongation and
 * filter, one for the post-smoothing that also takes r . z for CG. No allocation in the cycle.
 */
#include "core.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

enum { NS = 6 };  /* near-null-space modes: 3 translations, 3 rotations */

/* block sparse rows with float32 blocks: n block rows, m block columns, blocks br x bc row-major */
typedef struct bsr {
    int32_t n, m, br, bc;
    int32_t *ptr, *col;
    float *val;
    size_t cap_rows, cap_nnz;
} bsr;

typedef struct level {
    int32_t n, b;          /* block rows and block size (3 on the finest level, NS below) */
    bsr A;                 /* the operator (levels >= 1; level 0 is fem.c's rows) */
    bsr P;                 /* prolongator from the next level (restriction: its transpose) */
    double *dinv;          /* inverse diagonal blocks, b*b each (levels >= 1; level 0: c->pinv) */
    double omega;          /* damping of the Jacobi step */
    int32_t *agg;          /* aggregate of each block row, -1 none */
    int32_t nagg;
    double *B;             /* near-null space, n*b x NS row-major (levels >= 1) */
    double *x, *rhs, *res; /* V-cycle vectors (levels >= 1; level 0 has res only) */
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
    int agg_levels;        /* levels whose aggregates are kept (0: aggregate again) */
    int numeric_builds;    /* since the last aggregation */
    int64_t fixed_n, fixed_sum;  /* the pins and handles the aggregates were made with */
    int32_t fragment_vertices;   /* tc_stats.fragment_vertices_removed then (a removal renumbers) */
    bool forget;           /* aggregate again at the next build (tc_amg_forget) */
    /* the filter the first coarse operator was made for (tc_amg_update_filter): per vertex its
       kind and, for a contact vertex, an index into sn (its count then its 9 normals' values) */
    int8_t *sflag;
    int32_t *sidx;
    double *sn;
    size_t nsn, cap_sn;
    int32_t *changed;      /* scratch of an update: the vertices whose filter changed */
    uint8_t *inchg;
    /* scratch of the sparse products */
    int32_t *mark;
    double *acc;
    size_t cap_mark, cap_acc;
    int32_t cap_nv;        /* sflag, sidx, changed, inchg are sized for this many vertices */
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
        float *v = realloc(a->val, cn * (size_t)a->br * (size_t)a->bc * sizeof(float));
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

static void filter_store_free(tc_amg *h)
{
    free(h->sflag); free(h->sidx); free(h->sn); free(h->changed); free(h->inchg);
    h->sflag = NULL; h->sidx = NULL; h->sn = NULL; h->changed = NULL; h->inchg = NULL;
    h->nsn = h->cap_sn = 0;
    h->cap_nv = 0;
}

void tc_amg_free(tc_amg *h)
{
    if (!h) return;
    for (int l = 0; l < TC_AMG_MAX_LEVELS; l++) {
        level *L = &h->lev[l];
        bsr_free(&L->A); bsr_free(&L->P);
        free(L->dinv); free(L->agg); free(L->B); free(L->x); free(L->rhs); free(L->res);
    }
    filter_store_free(h);
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
            s += m[k]->cap_rows * 4 + m[k]->cap_nnz * (4 + 4 * (size_t)m[k]->br * (size_t)m[k]->bc);
        const size_t n = (size_t)L->n, b = (size_t)L->b;
        if (L->agg) s += n * 4;
        if (L->dinv) s += n * b * b * 8;
        if (L->B) s += n * b * NS * 8;
        s += ((L->x != NULL) + (L->rhs != NULL) + (L->res != NULL)) * L->cap_vec * 8;
    }
    s += (size_t)h->cap_nv * (1 + 4 + 4 + 1) + h->cap_sn * 8;
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

static inline bool fully_constrained(const tc_cloth *c, int32_t i)
{
    const int8_t f = ((const int8_t *)tc_vec_ptr(&c->vflag))[i];
    return f == VC_PINNED || f == VC_HANDLE;
}

/* S (3x3, row-major) of a vertex of kind f with cnt contact directions N: I when free, 0 when
 * pinned or held, I - sum n n^T for a contact */
static void filter_of(int8_t f, int cnt, const double *N, double S[9])
{
    for (int k = 0; k < 9; k++) S[k] = (k % 4 == 0 && (f == VC_FREE || f == VC_CONTACT)) ? 1.0 : 0.0;
    if (f != VC_CONTACT) return;
    for (int q = 0; q < cnt; q++)
        for (int a = 0; a < 3; a++)
            for (int b = 0; b < 3; b++) S[3 * a + b] -= N[3 * q + a] * N[3 * q + b];
}

/* S_i of the current filter; ref: the reference filter the prolongator is made on (contacts free) */
static void filter_matrix(const tc_cloth *c, int32_t i, double S[9], bool ref)
{
    int8_t f = ((const int8_t *)tc_vec_ptr(&c->vflag))[i];
    if (ref && f == VC_CONTACT) f = VC_FREE;
    filter_of(f, f == VC_CONTACT ? ((const int8_t *)tc_vec_ptr(&c->scount))[i] : 0,
              (const double *)tc_vec_ptr(&c->snorm) + 9 * (size_t)i, S);
}

/* S_i v in place (constraints.c's filter of one vertex) */
static inline void filter_vertex(int8_t f, int8_t cnt, const double *N, double *v)
{
    if (f == VC_FREE) return;
    if (f != VC_CONTACT) { v[0] = v[1] = v[2] = 0.0; return; }
    for (int k = 0; k < cnt; k++) {
        const double *e = N + 3 * k;
        const double d = v[0] * e[0] + v[1] * e[1] + v[2] * e[2];
        v[0] -= d * e[0]; v[1] -= d * e[1]; v[2] -= d * e[2];
    }
}

/* ---------------- the finest level's operator, row by row ---------------- */

/* a 3x3 block stored column by column, each column `stride` doubles apart, row-major */
static void from_columns(const double *src, int stride, double a[9])
{
    for (int r = 0; r < 3; r++)
        for (int q = 0; q < 3; q++) a[3 * r + q] = src[stride * q + r];
}

/* Row i of A (unfiltered, 3x3 blocks row-major: its diagonal first, then the edge blocks, then
 * the flaps) from fem.c's rows, into col/val (val NULL: the columns only). */
static int32_t raw_row(const tc_cloth *c, int32_t i, int32_t *col, double *val)
{
    const int32_t *rp = tc_vec_ptr(&c->rptr), *rc = tc_vec_ptr(&c->rcol), *fp = tc_vec_ptr(&c->fptr), *fc = tc_vec_ptr(&c->fcol);
    int32_t k = 0;
    col[k++] = i;
    for (int32_t s = rp[i]; s < rp[i + 1]; s++) col[k++] = rc[s];
    for (int32_t s = fp[i]; s < fp[i + 1]; s++) col[k++] = fc[s];
    if (!val) return k;
    const double *D = tc_vec_ptr(&c->diag), *RB = tc_vec_ptr(&c->rblk), *FV = tc_vec_ptr(&c->fval);
    from_columns(D + 12 * (size_t)i, 4, val);
    double *o = val + 9;
    for (int32_t s = rp[i]; s < rp[i + 1]; s++, o += 9) from_columns(RB + 9 * (size_t)s, 3, o);
    for (int32_t s = fp[i]; s < fp[i + 1]; s++, o += 9)
        for (int r = 0; r < 9; r++) o[r] = r % 4 == 0 ? FV[s] : 0.0;
    return k;
}

/* the diagonal scale d_i of A' off the range of S */
static inline double off_range_scale(const double *Aii) { return (Aii[0] + Aii[4] + Aii[8]) / 3.0; }

/* Row i of A' = S A S + (I - S) d_i (S of the current filter, or of the reference one), as
 * raw_row. The hierarchy reads the finest level this way, never as a stored copy: that copy (76
 * bytes per block, 13 blocks per row) was the largest allocation of the setup, 47 MB at 100K. */
static int32_t fine_row(const tc_cloth *c, int32_t i, int32_t *col, double *val, bool ref)
{
    const int32_t k = raw_row(c, i, col, val);
    if (!val) return k;
    const int8_t *fl = tc_vec_ptr(&c->vflag);
    const bool free_i = fl[i] == VC_FREE || (ref && fl[i] == VC_CONTACT);
    double Si[9];
    if (!free_i) {
        filter_matrix(c, i, Si, ref);
        double t[9] = {0}, u[9] = {0};
        gemm_acc(t, Si, val, 3, 3, 3);
        gemm_acc(u, t, Si, 3, 3, 3);
        const double sc = off_range_scale(val);
        for (int r = 0; r < 9; r++) val[r] = u[r] + sc * ((r % 4 == 0 ? 1.0 : 0.0) - Si[r]);
    }
    for (int32_t a = 1; a < k; a++) {
        const int32_t j = col[a];
        const bool free_j = fl[j] == VC_FREE || (ref && fl[j] == VC_CONTACT);
        if (free_i && free_j) continue;
        double *o = val + 9 * (size_t)a, t[9] = {0};
        if (!free_i) gemm_acc(t, Si, o, 3, 3, 3);
        else memcpy(t, o, sizeof t);
        if (!free_j) {
            double Sj[9];
            filter_matrix(c, j, Sj, ref);
            memset(o, 0, 9 * sizeof(double));
            gemm_acc(o, t, Sj, 3, 3, 3);
        } else {
            memcpy(o, t, sizeof t);
        }
    }
    return k;
}

/* The rows of a level's operator: level 0's made one at a time by fine_row into the scratch
 * (current or reference filter), a coarse level's read from its stored float matrix into it. */
typedef struct rowsrc {
    const tc_cloth *c;
    const bsr *A;          /* coarse levels */
    bool ref;              /* level 0: the reference filter */
    int32_t *col;          /* one row's columns and blocks (level 0) / blocks (coarse) */
    double *val;
    int32_t max_row;
} rowsrc;

static int rowsrc_init(rowsrc *s, const tc_cloth *c, const level *L, int l, bool ref)
{
    free(s->col); free(s->val);
    memset(s, 0, sizeof *s);
    s->c = c;
    s->ref = ref;
    int32_t m = 1, bb = 9;
    if (l > 0) {
        s->A = &L->A;
        bb = NS * NS;
        for (int32_t i = 0; i < L->A.n; i++) m = L->A.ptr[i + 1] - L->A.ptr[i] > m ? L->A.ptr[i + 1] - L->A.ptr[i] : m;
    } else {
        const int32_t *rp = tc_vec_ptr(&c->rptr), *fp = tc_vec_ptr(&c->fptr);
        for (int32_t i = 0; i < c->nv; i++) {
            const int32_t k = 1 + (rp[i + 1] - rp[i]) + (fp[i + 1] - fp[i]);
            if (k > m) m = k;
        }
    }
    s->max_row = m;
    s->col = malloc((size_t)m * sizeof(int32_t));
    s->val = malloc((size_t)m * bb * sizeof(double));
    return s->col && s->val ? 0 : -1;
}

static void rowsrc_free(rowsrc *s)
{
    free(s->col); free(s->val);
    s->col = NULL; s->val = NULL;
}

/* row i: its length; its columns and blocks (b x b row-major, double) in *col, *val (want_val
 * false: the columns only, *val untouched) */
static inline int32_t row_get(rowsrc *s, int32_t i, const int32_t **col, const double **val, bool want_val)
{
    if (!s->A) {
        const int32_t k = fine_row(s->c, i, s->col, want_val ? s->val : NULL, s->ref);
        *col = s->col;
        if (want_val) *val = s->val;
        return k;
    }
    const int32_t a = s->A->ptr[i], k = s->A->ptr[i + 1] - a;
    *col = s->A->col + a;
    if (want_val) {
        const float *v = s->A->val + (size_t)a * NS * NS;
        for (size_t q = 0; q < (size_t)k * NS * NS; q++) s->val[q] = v[q];
        *val = s->val;
    }
    return k;
}

/* ---------------- products with the stored matrices ---------------- */

/* y_i = sum_J M_iJ x_J (add: y_i +=), blocks BR x NS; the dot form, which reads each block's rows
 * against the coarse vector (the prolongation and the coarse operators' product) */
#define BSR_DOT(NAME, BR)                                                                             \
    static void NAME(const bsr *M, const double *restrict x, double *restrict y, bool add)             \
    {                                                                                                 \
        for (int32_t i = 0; i < M->n; i++) {                                                          \
            double acc[BR] = {0};                                                                     \
            for (int32_t a = M->ptr[i]; a < M->ptr[i + 1]; a++) {                                     \
                const float *v = M->val + (size_t)a * BR * NS;                                        \
                const double *xj = x + (size_t)M->col[a] * NS;                                        \
                for (int r = 0; r < BR; r++)                                                          \
                    for (int q = 0; q < NS; q++) acc[r] += (double)v[r * NS + q] * xj[q];             \
            }                                                                                         \
            for (int r = 0; r < BR; r++) y[(size_t)i * BR + r] = add ? y[(size_t)i * BR + r] + acc[r] : acc[r]; \
        }                                                                                             \
    }
BSR_DOT(dot_3, 3)
BSR_DOT(dot_6, 6)
#undef BSR_DOT

/* y = M^T x (y zeroed first): a scatter over M's rows, the axpy form (the restriction) */
#define BSR_AXPY_T(NAME, BR)                                                                          \
    static void NAME(const bsr *M, const double *restrict x, double *restrict y)                      \
    {                                                                                                 \
        memset(y, 0, (size_t)M->m * NS * sizeof(double));                                             \
        for (int32_t i = 0; i < M->n; i++) {                                                          \
            const double *xi = x + (size_t)i * BR;                                                    \
            for (int32_t a = M->ptr[i]; a < M->ptr[i + 1]; a++) {                                     \
                const float *v = M->val + (size_t)a * BR * NS;                                        \
                double *yj = y + (size_t)M->col[a] * NS;                                              \
                for (int r = 0; r < BR; r++)                                                          \
                    for (int q = 0; q < NS; q++) yj[q] += (double)v[r * NS + q] * xi[r];              \
            }                                                                                         \
        }                                                                                             \
    }
BSR_AXPY_T(axpy_t_3, 3)
BSR_AXPY_T(axpy_t_6, 6)
#undef BSR_AXPY_T

#if (defined(__x86_64__) || defined(_M_X64)) && (defined(__GNUC__) || defined(__clang__))
#include <immintrin.h>
/* The same products with AVX2 + FMA when the CPU has them (tc_simd_level(), as fem.c's product):
 * a block row of six floats is read as four and two, widened to double. Written out because the
 * compiler keeps the scalar loops above scalar (a reduction over six per block row); the T-shirt's
 * V-cycle took 2.4x less time with them. */
#define TC_AMG_AVX2 1
#define AVX2 __attribute__((target("avx2,fma")))
AVX2 static inline __m256d ld4f(const float *p) { return _mm256_cvtps_pd(_mm_loadu_ps(p)); }
AVX2 static inline __m128d ld2f(const float *p)
{
    return _mm_cvtps_pd(_mm_castsi128_ps(_mm_loadl_epi64((const __m128i *)(const void *)p)));
}
AVX2 static inline double hsum(__m256d a, __m128d b)
{
    __m128d s = _mm_add_pd(_mm_add_pd(_mm256_castpd256_pd128(a), _mm256_extractf128_pd(a, 1)), b);
    return _mm_cvtsd_f64(_mm_add_sd(s, _mm_unpackhi_pd(s, s)));
}
#define BSR_DOT_AVX2(NAME, BR)                                                                        \
    AVX2 static void NAME(const bsr *M, const double *restrict x, double *restrict y, bool add)       \
    {                                                                                                 \
        for (int32_t i = 0; i < M->n; i++) {                                                          \
            __m256d a4[BR];                                                                           \
            __m128d a2[BR];                                                                           \
            for (int r = 0; r < BR; r++) { a4[r] = _mm256_setzero_pd(); a2[r] = _mm_setzero_pd(); }   \
            for (int32_t a = M->ptr[i]; a < M->ptr[i + 1]; a++) {                                     \
                const float *v = M->val + (size_t)a * BR * NS;                                        \
                const double *xj = x + (size_t)M->col[a] * NS;                                        \
                const __m256d x4 = _mm256_loadu_pd(xj);                                               \
                const __m128d x2 = _mm_loadu_pd(xj + 4);                                              \
                for (int r = 0; r < BR; r++) {                                                        \
                    a4[r] = _mm256_fmadd_pd(ld4f(v + r * NS), x4, a4[r]);                             \
                    a2[r] = _mm_fmadd_pd(ld2f(v + r * NS + 4), x2, a2[r]);                            \
                }                                                                                     \
            }                                                                                         \
            double *yi = y + (size_t)i * BR;                                                          \
            for (int r = 0; r < BR; r++) yi[r] = add ? yi[r] + hsum(a4[r], a2[r]) : hsum(a4[r], a2[r]); \
        }                                                                                             \
    }
BSR_DOT_AVX2(dot_3_avx2, 3)
BSR_DOT_AVX2(dot_6_avx2, 6)
#undef BSR_DOT_AVX2
#define BSR_AXPY_T_AVX2(NAME, BR)                                                                     \
    AVX2 static void NAME(const bsr *M, const double *restrict x, double *restrict y)                 \
    {                                                                                                 \
        memset(y, 0, (size_t)M->m * NS * sizeof(double));                                             \
        for (int32_t i = 0; i < M->n; i++) {                                                          \
            __m256d b4[BR];                                                                           \
            __m128d b2[BR];                                                                           \
            for (int r = 0; r < BR; r++) {                                                            \
                b4[r] = _mm256_set1_pd(x[(size_t)i * BR + r]);                                        \
                b2[r] = _mm_set1_pd(x[(size_t)i * BR + r]);                                           \
            }                                                                                         \
            for (int32_t a = M->ptr[i]; a < M->ptr[i + 1]; a++) {                                     \
                const float *v = M->val + (size_t)a * BR * NS;                                        \
                double *yj = y + (size_t)M->col[a] * NS;                                              \
                __m256d t4 = _mm256_loadu_pd(yj);                                                     \
                __m128d t2 = _mm_loadu_pd(yj + 4);                                                    \
                for (int r = 0; r < BR; r++) {                                                        \
                    t4 = _mm256_fmadd_pd(ld4f(v + r * NS), b4[r], t4);                                \
                    t2 = _mm_fmadd_pd(ld2f(v + r * NS + 4), b2[r], t2);                               \
                }                                                                                     \
                _mm256_storeu_pd(yj, t4);                                                             \
                _mm_storeu_pd(yj + 4, t2);                                                            \
            }                                                                                         \
        }                                                                                             \
    }
BSR_AXPY_T_AVX2(axpy_t_3_avx2, 3)
BSR_AXPY_T_AVX2(axpy_t_6_avx2, 6)
#undef BSR_AXPY_T_AVX2
#undef AVX2
#endif

static inline bool avx2(void)
{
#ifdef TC_AMG_AVX2
    return tc_simd_level() == TC_SIMD_AVX2;
#else
    return false;
#endif
}

/* y = M x (add: y += M x) */
static void bsr_apply(const bsr *M, const double *x, double *y, bool add)
{
#ifdef TC_AMG_AVX2
    if (avx2()) { (M->br == 3 ? dot_3_avx2 : dot_6_avx2)(M, x, y, add); return; }
#endif
    (M->br == 3 ? dot_3 : dot_6)(M, x, y, add);
}

/* y = M^T x */
static void bsr_apply_transposed(const bsr *M, const double *x, double *y)
{
#ifdef TC_AMG_AVX2
    if (avx2()) { (M->br == 3 ? axpy_t_3_avx2 : axpy_t_6_avx2)(M, x, y); return; }
#endif
    (M->br == 3 ? axpy_t_3 : axpy_t_6)(M, x, y);
}

/* One Gauss-Seidel sweep over a coarse level (6x6 float blocks, inverse diagonal blocks dinv in
 * double): x_I = D_I^-1 (b_I - sum_{J != I} A_IJ x_J), rows in order (forward) or reversed, each
 * with the newest x. The coarse levels' smoother: a forward sweep before the coarse correction and
 * a backward one after make a symmetric cycle, and Gauss-Seidel converges on any SPD matrix, so
 * no damping estimate is needed (a damped Jacobi step's, from power iterations, went stale when a
 * contact update moved rho(D^-1 A_1) by 2x: the cycle lost positivity and CG broke down). */
static void gs_sweep(const bsr *A, const double *dinv, const double *restrict b, double *restrict x, bool forward)
{
    for (int32_t k = 0; k < A->n; k++) {
        const int32_t I = forward ? k : A->n - 1 - k;
        double s[NS];
        for (int r = 0; r < NS; r++) s[r] = b[(size_t)I * NS + r];
        for (int32_t a = A->ptr[I]; a < A->ptr[I + 1]; a++) {
            const int32_t J = A->col[a];
            if (J == I) continue;
            const float *v = A->val + (size_t)a * NS * NS;
            const double *xj = x + (size_t)J * NS;
            for (int r = 0; r < NS; r++) {
                double t = 0.0;
                for (int q = 0; q < NS; q++) t += (double)v[r * NS + q] * xj[q];
                s[r] -= t;
            }
        }
        const double *m = dinv + (size_t)I * NS * NS;
        double *xi = x + (size_t)I * NS;
        for (int r = 0; r < NS; r++) {
            double t = 0.0;
            for (int q = 0; q < NS; q++) t += m[r * NS + q] * s[q];
            xi[r] = t;
        }
    }
}

#ifdef TC_AMG_AVX2
__attribute__((target("avx2,fma"))) static void gs_sweep_avx2(const bsr *A, const double *dinv, const double *restrict b,
                                                              double *restrict x, bool forward)
{
    for (int32_t k = 0; k < A->n; k++) {
        const int32_t I = forward ? k : A->n - 1 - k;
        __m256d a4[NS];
        __m128d a2[NS];
        for (int r = 0; r < NS; r++) { a4[r] = _mm256_setzero_pd(); a2[r] = _mm_setzero_pd(); }
        for (int32_t a = A->ptr[I]; a < A->ptr[I + 1]; a++) {
            const int32_t J = A->col[a];
            if (J == I) continue;
            const float *v = A->val + (size_t)a * NS * NS;
            const double *xj = x + (size_t)J * NS;
            const __m256d x4 = _mm256_loadu_pd(xj);
            const __m128d x2 = _mm_loadu_pd(xj + 4);
            for (int r = 0; r < NS; r++) {
                a4[r] = _mm256_fmadd_pd(ld4f(v + r * NS), x4, a4[r]);
                a2[r] = _mm_fmadd_pd(ld2f(v + r * NS + 4), x2, a2[r]);
            }
        }
        double s[NS];
        for (int r = 0; r < NS; r++) s[r] = b[(size_t)I * NS + r] - hsum(a4[r], a2[r]);
        const double *m = dinv + (size_t)I * NS * NS;
        double *xi = x + (size_t)I * NS;
        for (int r = 0; r < NS; r++) {
            double t = 0.0;
            for (int q = 0; q < NS; q++) t += m[r * NS + q] * s[q];
            xi[r] = t;
        }
    }
}
#endif

static void level_sweep(const level *L, const double *b, double *x, bool forward)
{
#ifdef TC_AMG_AVX2
    if (avx2()) { gs_sweep_avx2(&L->A, L->dinv, b, x, forward); return; }
#endif
    gs_sweep(&L->A, L->dinv, b, x, forward);
}

/* ---------------- prolongator and Galerkin product, from the rows ---------------- */

static int scratch(tc_amg *h, int32_t m, size_t acc)
{
    size_t old = h->cap_mark;
    if (grow((void **)&h->mark, &h->cap_mark, (size_t)m, sizeof(int32_t))) return -1;
    for (size_t k = old; k < h->cap_mark; k++) h->mark[k] = -1;  /* the kept ones are -1 already */
    return grow((void **)&h->acc, &h->cap_acc, acc, sizeof(double));
}

/* P = (I - w D^-1 A) T row by row (T: at most one block per row, that of the row's aggregate,
 * stored densely: Tv, b x NS per row, zero when the row has none), D^-1 the smoother's inverse
 * diagonal blocks (level 0: S of the reference filter times the solver's). One pass: row i's
 * blocks are (A T)_iJ = sum over its columns j in aggregate J of A_ij T_j, so no product A T is
 * stored before it is smoothed. Instantiated for the finest (b = 3) and coarse (b = 6) blocks. */
#define PROLONGATOR(NAME, B)                                                                          \
    TC_HOT static int NAME(tc_amg *h, rowsrc *s, const level *L, int l, const double *Tv, bsr *P)     \
    {                                                                                                 \
        enum { BS = B * NS };                                                                         \
        const int32_t n = L->n, *agg = L->agg;                                                        \
        P->n = n; P->m = L->nagg; P->br = B; P->bc = NS;                                              \
        if (scratch(h, L->nagg, 64 * BS)) return -1;                                                  \
        int32_t *mark = h->mark;                                                                      \
        /* the pattern's size first (columns only), so P takes what it needs and no more */           \
        size_t k = 0;                                                                                 \
        for (int32_t i = 0; i < n; i++) {                                                             \
            const int32_t *col;                                                                       \
            const double *unused = NULL;                                                              \
            const int32_t len = row_get(s, i, &col, &unused, false);                                  \
            for (int32_t a = 0; a < len; a++) {                                                       \
                const int32_t J = agg[col[a]];                                                        \
                if (J >= 0 && mark[J] != i) { mark[J] = i; k++; }                                     \
            }                                                                                         \
        }                                                                                             \
        for (int32_t J = 0; J < L->nagg; J++) mark[J] = -1;                                           \
        if (bsr_reserve(P, n, k)) return -1;                                                          \
        k = 0;                                                                                        \
        for (int32_t i = 0; i < n; i++) {                                                             \
            P->ptr[i] = (int32_t)k;                                                                   \
            const int32_t *col;                                                                       \
            const double *val;                                                                        \
            const int32_t len = row_get(s, i, &col, &val, true);                                      \
            const size_t s0 = k;                                                                      \
            for (int32_t a = 0; a < len; a++) {                                                       \
                const int32_t j = col[a], J = agg[j];                                                 \
                if (J < 0) continue;                                                                  \
                if (mark[J] < 0) {                                                                    \
                    if (grow((void **)&h->acc, &h->cap_acc, (k - s0 + 1) * BS, sizeof(double))) return -1; \
                    mark[J] = (int32_t)k;                                                             \
                    P->col[k] = J;                                                                    \
                    memset(h->acc + (k - s0) * BS, 0, BS * sizeof(double));                           \
                    k++;                                                                              \
                }                                                                                     \
                double *o = h->acc + (size_t)(mark[J] - (int32_t)s0) * BS;                            \
                const double *ab = val + (size_t)a * B * B, *tb = Tv + (size_t)j * BS;                \
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
                filter_matrix(s->c, i, S, true);                                                      \
                memset(M, 0, sizeof M);                                                               \
                gemm_acc(M, S, p, 3, 3, 3);                                                           \
            } else {                                                                                  \
                memcpy(M, L->dinv + (size_t)i * B * B, sizeof M);                                     \
            }                                                                                         \
            for (size_t a = s0; a < k; a++) {                                                         \
                const double *v = h->acc + (a - s0) * BS;                                             \
                float *o = P->val + a * BS;                                                           \
                const bool own = P->col[a] == agg[i];                                                 \
                for (int r = 0; r < B; r++)                                                           \
                    for (int m = 0; m < NS; m++) {                                                    \
                        double t = 0.0;                                                               \
                        for (int q = 0; q < B; q++) t += M[r * B + q] * v[q * NS + m];                \
                        t *= -L->omega;                                                               \
                        if (own) t += Tv[(size_t)i * BS + r * NS + m];                                \
                        o[r * NS + m] = (float)t;                                                     \
                    }                                                                                 \
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
 * blocks (J >= I; the lower ones are their transposes). So neither A P nor P^T is ever stored.
 * C is summed in double (a buffer of its own, 288 bytes a block) and then narrowed in place to
 * float32: its values are sums of some fifty products each, which float would round 50 times. */
#define GALERKIN(NAME, B)                                                                             \
    TC_HOT static int NAME(tc_amg *h, rowsrc *s, const bsr *P, bsr *C)                                \
    {                                                                                                 \
        enum { BS = B * NS, CS = NS * NS };                                                           \
        const int32_t n = P->n, na = P->m;                                                            \
        int rc = -1;                                                                                  \
        double *cv = NULL;                                                                            \
        int32_t *tptr = calloc((size_t)na + 1, sizeof(int32_t));                                      \
        int32_t *trow = malloc(((size_t)P->ptr[n] + 1) * sizeof(int32_t));                            \
        int32_t *cols = malloc(((size_t)na + 1) * sizeof(int32_t)); /* one row's columns of A P */    \
        double pd[64 * BS]; /* one fine row's P blocks in double (at most 64: else read as floats) */  \
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
        if (pass == 1) {                                                                              \
            free(C->val); C->val = NULL; C->cap_nnz = 0;                                              \
            int32_t *cp = realloc(C->ptr, ((size_t)na + 1) * sizeof(int32_t));                       \
            int32_t *cc = realloc(C->col, (k ? k : 1) * sizeof(int32_t));                             \
            if (cp) C->ptr = cp;                                                                      \
            if (cc) C->col = cc;                                                                      \
            cv = calloc((k ? k : 1) * CS, sizeof(double));                                            \
            if (!cp || !cc || !cv) goto done;                                                         \
            C->cap_rows = (size_t)na + 1;                                                             \
        }                                                                                             \
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
        C->cap_nnz = k ? k : 1;                                                                       \
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
                    const float *pb = P->val + (size_t)b * BS;                                        \
                    for (int r = 0; r < B; r++)                                                       \
                        for (int q = 0; q < B; q++) {                                                 \
                            const double x = ab[r * B + q];                                           \
                            for (int e = 0; e < NS; e++) o[r * NS + e] += x * (double)pb[q * NS + e]; \
                        }                                                                             \
                }                                                                                     \
            }                                                                                         \
            const int32_t np = P->ptr[i + 1] - P->ptr[i];                                             \
            for (int32_t b = 0; b < np && b < 64; b++)                                                \
                for (int q = 0; q < BS; q++) pd[b * BS + q] = P->val[(size_t)(P->ptr[i] + b) * BS + q]; \
            for (int32_t b = P->ptr[i]; b < P->ptr[i + 1]; b++) {                                     \
                const int32_t I = P->col[b];                                                          \
                double pl[BS];                                                                        \
                const double *pb = pl;                                                                \
                if (b - P->ptr[i] < 64) pb = pd + (size_t)(b - P->ptr[i]) * BS;                       \
                else for (int q = 0; q < BS; q++) pl[q] = P->val[(size_t)b * BS + q];                 \
                for (int32_t q = 0; q < m; q++) {                                                     \
                    const int32_t J = cols[q];                                                        \
                    if (J < I) continue;                                                              \
                    const int32_t slot = find_slot(C, I, J);                                          \
                    if (slot < 0) continue; /* cannot happen: the pattern has every (I, J) */         \
                    double *o = cv + (size_t)slot * CS;                                               \
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
        /* the lower blocks: transposes of the upper ones; the diagonal ones made exactly symmetric */ \
        for (int32_t I = 0; I < na; I++)                                                              \
            for (int32_t a = C->ptr[I]; a < C->ptr[I + 1]; a++) {                                     \
                const int32_t J = C->col[a];                                                          \
                if (J == I) {                                                                         \
                    double *u = cv + (size_t)a * CS;                                                  \
                    for (int r = 0; r < NS; r++)                                                      \
                        for (int q = r + 1; q < NS; q++)                                              \
                            u[r * NS + q] = u[q * NS + r] = 0.5 * (u[r * NS + q] + u[q * NS + r]);    \
                }                                                                                     \
                if (J <= I) continue;                                                                 \
                const int32_t t = find_slot(C, J, I);                                                 \
                if (t < 0) continue;                                                                  \
                const double *u = cv + (size_t)a * CS;                                                \
                double *o = cv + (size_t)t * CS;                                                      \
                for (int r = 0; r < NS; r++)                                                          \
                    for (int q = 0; q < NS; q++) o[q * NS + r] = u[r * NS + q];                       \
            }                                                                                         \
        {   /* narrowed in place, front to back (float q sits below double q), then shrunk */        \
            float *f = (float *)(void *)cv;                                                           \
            for (size_t q = 0; q < k * CS; q++) { const double d = cv[q]; f[q] = (float)d; }          \
            float *shrunk = realloc(cv, (k ? k : 1) * CS * sizeof(float));                            \
            C->val = shrunk ? shrunk : f;                                                             \
            cv = NULL;                                                                                \
        }                                                                                             \
        rc = 0;                                                                                       \
    done:                                                                                             \
        free(cv);                                                                                     \
        free(tptr); free(trow); free(cols);                                                           \
        return rc;                                                                                    \
    }
GALERKIN(galerkin_3, 3)
GALERKIN(galerkin_6, 6)
#undef GALERKIN

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

/* After a tear: the vertices it added (from h->nv on; tears append, never renumber) join the
 * aggregate of their first aggregated edge neighbour, so the hierarchy is refreshed numerically
 * instead of aggregated again (its coarse levels keep theirs: their rows are the same aggregates). */
static int extend_aggregates(tc_amg *h, const tc_cloth *c)
{
    level *L = &h->lev[0];
    int32_t *na = realloc(L->agg, (size_t)c->nv * sizeof(int32_t));
    if (!na) return -1;
    L->agg = na;
    const int32_t *rp = tc_vec_ptr(&c->rptr), *rc = tc_vec_ptr(&c->rcol);
    for (int32_t i = h->nv; i < c->nv; i++) {
        na[i] = -1;
        if (fully_constrained(c, i)) continue;
        for (int32_t s = rp[i]; s < rp[i + 1] && na[i] < 0; s++)
            if (rc[s] < h->nv) na[i] = na[rc[s]];
    }
    L->n = c->nv;
    return 0;
}

/* ---------------- tentative prolongator ---------------- */

/* T (n rows of b x NS, dense: Tv; a row with no aggregate is zero) from the near-null space B
 * (n*b x NS, row-major) by a QR of each aggregate's rows; Bc (na*NS x NS) gets the R factors,
 * dead (na*NS) the modes an aggregate cannot carry. */
static int tentative(level *L, const double *B, double *Tv, double *Bc, int32_t *dead)
{
    const int32_t n = L->n, na = L->nagg;
    const int b = L->b;
    const size_t bs = (size_t)b * NS;
    /* rows of each aggregate, by a counting sort */
    int32_t *start = calloc((size_t)na + 1, sizeof(int32_t)), *rows = malloc(((size_t)n + 1) * sizeof(int32_t));
    if (!start || !rows) { free(start); free(rows); return -1; }
    for (int32_t i = 0; i < n; i++) if (L->agg[i] >= 0) start[L->agg[i] + 1]++;
    for (int32_t a = 0; a < na; a++) start[a + 1] += start[a];
    for (int32_t i = 0; i < n; i++) if (L->agg[i] >= 0) rows[start[L->agg[i]]++] = i;
    for (int32_t a = na; a > 0; a--) start[a] = start[a - 1];
    start[0] = 0;
    for (int32_t i = 0; i < n; i++) {
        if (L->agg[i] >= 0) memcpy(Tv + (size_t)i * bs, B + (size_t)i * bs, bs * sizeof(double));
        else memset(Tv + (size_t)i * bs, 0, bs * sizeof(double));
    }
    /* modified Gram-Schmidt, twice, over the aggregate's stacked blocks (in place) */
    for (int32_t a = 0; a < na; a++) {
        double *R = Bc + (size_t)a * NS * NS;
        memset(R, 0, NS * NS * sizeof(double));
        double cn[NS] = {0};
        for (int32_t q = start[a]; q < start[a + 1]; q++) {
            const double *t = Tv + (size_t)rows[q] * bs;
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
                        const double *t = Tv + (size_t)rows[q] * bs;
                        for (int r = 0; r < b; r++) d += t[r * NS + i] * t[r * NS + j];
                    }
                    R[i * NS + j] += d;
                    for (int32_t q = start[a]; q < start[a + 1]; q++) {
                        double *t = Tv + (size_t)rows[q] * bs;
                        for (int r = 0; r < b; r++) t[r * NS + j] -= d * t[r * NS + i];
                    }
                }
            double nn = 0.0;
            for (int32_t q = start[a]; q < start[a + 1]; q++) {
                const double *t = Tv + (size_t)rows[q] * bs;
                for (int r = 0; r < b; r++) nn += t[r * NS + j] * t[r * NS + j];
            }
            /* a mode the aggregate cannot carry (lost to cancellation): a zero column */
            const bool lost = !(nn > 1e-12 * cn[j]) || !(nn > 1e-24 * big);
            const double s = lost ? 0.0 : 1.0 / sqrt(nn);
            R[j * NS + j] = lost ? 0.0 : sqrt(nn);
            dead[(size_t)a * NS + j] = lost;
            for (int32_t q = start[a]; q < start[a + 1]; q++) {
                double *t = Tv + (size_t)rows[q] * bs;
                for (int r = 0; r < b; r++) t[r * NS + j] *= s;
            }
            if (lost) for (int i = 0; i < j; i++) R[i * NS + j] = 0.0;
        }
    }
    free(start); free(rows);
    return 0;
}

/* ---------------- per-level pieces ---------------- */

/* The V-cycle's vectors of a level: the finest has only res (its x and right-hand side are the
 * solver's output and residual), a coarse level x, rhs and res. */
static int level_vectors(level *L, bool finest)
{
    const size_t nb = (size_t)L->n * L->b;
    if (nb <= L->cap_vec && L->res) return 0;
    free(L->x); free(L->rhs); free(L->res);
    L->x = L->rhs = NULL;
    const size_t k = nb ? nb : 1;
    if (!finest) { L->x = malloc(k * sizeof(double)); L->rhs = malloc(k * sizeof(double)); }
    L->res = malloc(k * sizeof(double));
    L->cap_vec = ((finest || (L->x && L->rhs)) && L->res) ? nb : 0;
    return L->cap_vec || !nb ? 0 : -1;
}

/* y = A x on level l (level 0: S A x by fem.c's product, x on the range of S) */
static void level_apply(const tc_cloth *c, const level *L, int l, const double *x, double *y)
{
    if (l == 0) {
        tc_matvec(c, x, y);
        tc_constraint_filter(c, y);
    } else {
        bsr_apply(&L->A, x, y, false);
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
    for (int32_t i = 0; i < L->n; i++) {
        const double *m = L->dinv + (size_t)i * NS * NS, *xi = x + (size_t)i * NS;
        double *o = y + (size_t)i * NS;
        for (int r = 0; r < NS; r++) {
            double s = 0.0;
            for (int q = 0; q < NS; q++) s += m[r * NS + q] * xi[q];
            o[r] = s;
        }
    }
}

/* rho(D^-1 A) by power iterations from a fixed, mesh-independent start (the estimate's 1.1 covers
 * its shortfall, so w rho < 2 and the Jacobi step converges in A's norm). */
static double spectral_radius(const tc_cloth *c, level *L, int l)
{
    const size_t nb = (size_t)L->n * L->b;
    double *x = L->x, *y = L->res, *z = L->rhs;
    double *own = NULL;
    if (l == 0) {  /* the finest level has res only: two vectors of its own, for a moment */
        own = malloc(2 * (nb ? nb : 1) * sizeof(double));
        if (!own) return -1.0;
        x = own; z = own + nb;
    }
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
    free(own);
    return rho > 0 ? 1.1 * rho : 1.0;
}

/* the diagonal block of row I of a coarse level, in double (NULL when the row has none) */
static bool coarse_diag_block(const level *L, int32_t I, double d[NS * NS], float **stored)
{
    const int32_t s = find_slot(&L->A, I, I);
    if (s < 0) return false;
    float *v = L->A.val + (size_t)s * NS * NS;
    for (int q = 0; q < NS * NS; q++) d[q] = v[q];
    if (stored) *stored = v;
    return true;
}

/* inverse diagonal blocks of a coarse level; a dead unknown gets the live diagonal's scale first
 * (written into the operator too, so an update of the row later reads the same block) */
static int coarse_diagonal(level *L, const int32_t *dead)
{
    double *di = realloc(L->dinv, ((size_t)L->n * NS * NS + 1) * sizeof(double));
    if (!di) return -1;
    L->dinv = di;
    for (int32_t i = 0; i < L->n; i++) {
        double d[NS * NS];
        float *st = NULL;
        double *o = L->dinv + (size_t)i * NS * NS;
        if (!coarse_diag_block(L, i, d, &st)) { memset(o, 0, NS * NS * sizeof(double)); continue; }
        double tr = 0.0;
        int live = 0;
        for (int k = 0; k < NS; k++) if (!dead[(size_t)i * NS + k]) { tr += d[k * NS + k]; live++; }
        const double sc = live && tr > 0 ? tr / live : 1.0;
        for (int k = 0; k < NS; k++)
            if (dead[(size_t)i * NS + k]) { d[k * NS + k] = sc; st[k * NS + k] = (float)sc; }
        spd_inverse(d, NS, o);
    }
    return 0;
}

/* the coarsest level's dense Cholesky factor, from its operator */
static int coarsest_factor(tc_amg *h)
{
    level *C = &h->lev[h->nlev - 1];
    const int32_t m = C->n * C->b;
    h->nc = 0;
    if (h->nlev < 2 || m > TC_AMG_DENSE_MAX) return 0;
    if (grow((void **)&h->chol, &h->cap_chol, (size_t)m * m, sizeof(double))) return -1;
    memset(h->chol, 0, (size_t)m * m * sizeof(double));
    for (int32_t i = 0; i < C->n; i++)
        for (int32_t a = C->A.ptr[i]; a < C->A.ptr[i + 1]; a++) {
            const int32_t j = C->A.col[a];
            const float *v = C->A.val + (size_t)a * NS * NS;
            for (int r = 0; r < NS; r++)
                for (int q = 0; q < NS; q++) h->chol[(size_t)(i * NS + r) * m + (j * NS + q)] = v[r * NS + q];
        }
    cholesky(h->chol, m);
    h->nc = m;
    return 0;
}

/* the near-null space of the finest level: rigid-body modes about each aggregate's centroid,
 * filtered by the reference S (row-major, 3 rows of NS per vertex) */
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
        filter_matrix(c, i, S, true);
        memset(r, 0, 3 * NS * sizeof(double));
        gemm_acc(r, S, m, 3, 3, NS);
    }
    free(cen);
}

/* ---------------- the filter the first coarse operator was made for ---------------- */

static int filter_store_size(tc_amg *h, int32_t nv)
{
    if (nv <= h->cap_nv && h->sflag) return 0;
    filter_store_free(h);
    const size_t n = (size_t)(nv ? nv : 1);
    h->sflag = malloc(n);
    h->sidx = malloc(n * sizeof(int32_t));
    h->changed = malloc(n * sizeof(int32_t));
    h->inchg = calloc(n, 1);
    if (!h->sflag || !h->sidx || !h->changed || !h->inchg) { filter_store_free(h); return -1; }
    h->cap_nv = nv;
    return 0;
}

/* the stored filter of vertex i */
static void stored_filter(const tc_amg *h, int32_t i, double S[9])
{
    const int8_t f = h->sflag[i];
    const double *e = f == VC_CONTACT ? h->sn + 10 * (size_t)h->sidx[i] : NULL;
    filter_of(f, e ? (int)e[0] : 0, e ? e + 1 : NULL, S);
}

/* store vertex i's current filter */
static int store_vertex(tc_amg *h, const tc_cloth *c, int32_t i)
{
    const int8_t f = ((const int8_t *)tc_vec_ptr(&c->vflag))[i];
    h->sflag[i] = f;
    h->sidx[i] = -1;
    if (f != VC_CONTACT) return 0;
    if (grow((void **)&h->sn, &h->cap_sn, 10 * (h->nsn + 1), sizeof(double))) { h->sflag[i] = VC_PINNED; return -1; }
    double *e = h->sn + 10 * h->nsn;
    e[0] = ((const int8_t *)tc_vec_ptr(&c->scount))[i];
    memcpy(e + 1, (const double *)tc_vec_ptr(&c->snorm) + 9 * (size_t)i, 9 * sizeof(double));
    h->sidx[i] = (int32_t)h->nsn++;
    return 0;
}

static int store_all(tc_amg *h, const tc_cloth *c)
{
    if (filter_store_size(h, c->nv)) return -1;
    h->nsn = 0;
    for (int32_t i = 0; i < c->nv; i++)
        if (store_vertex(h, c, i)) return -1;
    return 0;
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

void tc_amg_forget(tc_amg *h)
{
    if (h) h->forget = true;
}

/* the pins and handles as two numbers (their count and the sum of their indices + 1) */
static void fixed_signature(const tc_cloth *c, int64_t *n, int64_t *sum)
{
    const int8_t *fl = tc_vec_ptr(&c->vflag);
    *n = *sum = 0;
    for (int32_t i = 0; i < c->nv; i++)
        if (fl[i] == VC_PINNED || fl[i] == VC_HANDLE) { (*n)++; *sum += i + 1; }
}

bool tc_amg_needs_aggregation(const tc_amg *h, const tc_cloth *c)
{
    if (!h || h->nlev == 0 || h->agg_levels == 0 || h->forget || h->numeric_builds >= TC_AMG_REAGGREGATE) return true;
    /* vertices removed (fragments: the rest is renumbered) or fewer than the aggregates know */
    if (c->nv < h->nv || c->stats.fragment_vertices_removed != h->fragment_vertices) return true;
    int64_t n, sum;
    fixed_signature(c, &n, &sum);
    return n != h->fixed_n || sum != h->fixed_sum;
}

/* Builds the hierarchy for the current matrix (after tc_assemble and tc_precondition_build), the
 * aggregates anew when `aggregate_again` or tc_amg_needs_aggregation says so, else the kept ones
 * (extended to the vertices a tear added). */
int tc_amg_build(tc_amg *h, const tc_cloth *c, bool aggregate_again)
{
    aggregate_again = aggregate_again || tc_amg_needs_aggregation(h, c);
    int kept = aggregate_again ? 0 : h->agg_levels;
    int rc = -1;
    int32_t *pass1 = NULL, *dead = NULL, *sptr = NULL, *scol = NULL;
    double *dn = NULL, *B = NULL, *Tv = NULL;
    rowsrc src = {0};
    level *L0 = &h->lev[0];
    if (kept && c->nv > h->nv && extend_aggregates(h, c)) kept = 0;
    /* The old operators and prolongators go first: they are all made again, and kept they would
     * sit under this build's scratch (the near-null space, T), the peak of a refresh. */
    for (int l = 0; l < TC_AMG_MAX_LEVELS; l++) { bsr_free(&h->lev[l].A); bsr_free(&h->lev[l].P); }
    h->nlev = 0;
    h->agg_levels = 0;
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
        /* the prolongator is made on the reference filter (contacts free: see the file's head) */
        if (rowsrc_init(&src, c, L, l, true)) goto out;
        if (l >= kept) {
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
        free(B); free(Tv);
        B = malloc((size_t)n * L->b * NS * sizeof(double));
        Tv = malloc(((size_t)n * L->b * NS + 1) * sizeof(double));
        free(dead);
        dead = malloc(((size_t)na * NS + 1) * sizeof(int32_t));
        if (!B || !Tv || !dead) goto out;
        if (l == 0) fine_modes(c, L, B);
        else memcpy(B, L->B, (size_t)n * L->b * NS * sizeof(double));
        double *Bc = realloc(N->B, ((size_t)na * NS * NS + 1) * sizeof(double));
        if (!Bc) goto out;
        N->B = Bc;
        if (tentative(L, B, Tv, Bc, dead)) goto out;
        free(B);  /* Tv holds it now, orthonormalised */
        B = NULL;
        /* smoothed prolongator (reference filter), then the Galerkin operator of the current one */
        if ((l == 0 ? prolongator_3 : prolongator_6)(h, &src, L, l, Tv, &L->P)) goto out;
        free(Tv);
        Tv = NULL;
        if (l == 0 && rowsrc_init(&src, c, L, l, false)) goto out;
        if ((l == 0 ? galerkin_3 : galerkin_6)(h, &src, &L->P, &N->A)) goto out;
        N->n = na; N->b = NS;
        if (coarse_diagonal(N, dead) || level_vectors(N, false)) goto out;
        N->omega = 4.0 / (3.0 * spectral_radius(c, N, l + 1));
        nlev = l + 2;
    }
    h->nlev = nlev;
    if (coarsest_factor(h) || store_all(h, c)) goto out;
    h->pair_version = c->pair_version;
    h->nv = c->nv;
    h->agg_levels = nlev - 1;
    h->numeric_builds = aggregate_again ? 0 : h->numeric_builds + 1;
    if (aggregate_again) {
        fixed_signature(c, &h->fixed_n, &h->fixed_sum);
        h->fragment_vertices = c->stats.fragment_vertices_removed;
        h->forget = false;
    }
    rc = 0;
out:
    rowsrc_free(&src);
    free(pass1); free(dead); free(dn); free(B); free(Tv); free(sptr); free(scol);
    if (rc) { h->nlev = 0; h->agg_levels = 0; }
    return rc;
}

/* ---------------- a changed filter: the first coarse operator updated ---------------- */

/* C_IJ += P_iI^T X P_jJ over the blocks of P's rows i and j (X 3x3 row-major; mark[I] = 1 for
 * every row I touched), into C's upper blocks only (I <= J): a term of a lower block is the
 * transpose of the partner pair (j, i)'s term on its mirror, which the update adds too. The lower
 * blocks are copied from the upper ones afterwards, so C stays exactly symmetric (two terms summed
 * in two orders would differ in the last bit). */
static void add_triple(const level *L0, bsr *C, int32_t i, int32_t j, const double X[9], int32_t *mark)
{
    const bsr *P = &L0->P;
    for (int32_t b = P->ptr[j]; b < P->ptr[j + 1]; b++) {
        /* X P_jJ (3x6) */
        const float *pj = P->val + (size_t)b * 3 * NS;
        double xp[3 * NS];
        for (int r = 0; r < 3; r++)
            for (int m = 0; m < NS; m++)
                xp[r * NS + m] = X[3 * r] * pj[m] + X[3 * r + 1] * pj[NS + m] + X[3 * r + 2] * pj[2 * NS + m];
        const int32_t J = P->col[b];
        for (int32_t a = P->ptr[i]; a < P->ptr[i + 1]; a++) {
            const int32_t I = P->col[a];
            if (I > J) continue;  /* a lower block: its mirror gets the partner term (j, i) */
            const int32_t slot = find_slot(C, I, J);
            if (slot < 0) continue;  /* cannot happen: C's pattern has every (I, J) */
            const float *pi = P->val + (size_t)a * 3 * NS;
            float *o = C->val + (size_t)slot * NS * NS;
            for (int x = 0; x < NS; x++)
                for (int e = 0; e < NS; e++)
                    o[x * NS + e] += (float)(pi[x] * xp[e] + pi[NS + x] * xp[NS + e] + pi[2 * NS + x] * xp[2 * NS + e]);
            mark[I] = 1;
        }
    }
}

/* whether the filter S differs from the one the first coarse operator was made for */
bool tc_amg_filter_changed(const tc_amg *h, const tc_cloth *c)
{
    if (!h || h->nlev < 2 || h->nv != c->nv || !h->sflag) return false;
    const int8_t *fl = tc_vec_ptr(&c->vflag);
    for (int32_t i = 0; i < c->nv; i++) {
        if (fl[i] == VC_FREE && h->sflag[i] == VC_FREE) continue;
        double a[9], b[9];
        filter_matrix(c, i, a, false);
        stored_filter(h, i, b);
        if (memcmp(a, b, sizeof a)) return true;
    }
    return false;
}

/* The filter S changed at some vertices since the first coarse operator was made (or last
 * updated): A_1 += P^T (A'_new - A'_old) P over their rows and columns, with the current matrix A
 * for both (the old filter's part is taken out at the current A: between refreshes A_1 is that of
 * an older matrix anyway), then the touched rows' inverse diagonal blocks and, when A_1 is the
 * coarsest, its factor. Returns the vertices that changed, -1 when out of memory (the hierarchy is
 * then unusable: solver.c builds it anew). */
int tc_amg_update_filter(tc_amg *h, const tc_cloth *c)
{
    if (!h || h->nlev < 2 || h->nv != c->nv || !h->sflag) return 0;
    const int8_t *fl = tc_vec_ptr(&c->vflag);
    int32_t nchg = 0;
    for (int32_t i = 0; i < c->nv; i++) {
        if (fl[i] == VC_FREE && h->sflag[i] == VC_FREE) continue;
        double a[9], b[9];
        filter_matrix(c, i, a, false);
        stored_filter(h, i, b);
        if (memcmp(a, b, sizeof a)) { h->changed[nchg++] = i; h->inchg[i] = 1; }
    }
    if (!nchg) return 0;
    level *L0 = &h->lev[0], *L1 = &h->lev[1];
    int rc = nchg;
    rowsrc src = {0};
    if (rowsrc_init(&src, c, L0, 0, false) || scratch(h, L1->n, 0)) { rc = -1; goto out; }
    int32_t *touched = h->mark;  /* -1 everywhere between uses */
    for (int32_t k = 0; k < nchg; k++) {
        const int32_t i = h->changed[k];
        const int32_t len = raw_row(c, i, src.col, src.val);
        double Sn_i[9], So_i[9];
        filter_matrix(c, i, Sn_i, false);
        stored_filter(h, i, So_i);
        for (int32_t a = 0; a < len; a++) {
            const int32_t j = src.col[a];
            const double *Aij = src.val + 9 * (size_t)a;
            double Sn_j[9], So_j[9];
            filter_matrix(c, j, Sn_j, false);
            if (h->inchg[j]) stored_filter(h, j, So_j);
            else memcpy(So_j, Sn_j, sizeof So_j);
            /* X = Sn_i A Sn_j - So_i A So_j (+ (So_i - Sn_i) d_i on the diagonal) */
            double t[9] = {0}, X[9] = {0}, u[9] = {0}, Y[9] = {0};
            gemm_acc(t, Sn_i, Aij, 3, 3, 3);
            gemm_acc(X, t, Sn_j, 3, 3, 3);
            gemm_acc(u, So_i, Aij, 3, 3, 3);
            gemm_acc(Y, u, So_j, 3, 3, 3);
            for (int q = 0; q < 9; q++) X[q] -= Y[q];
            if (j == i) {
                const double d = off_range_scale(Aij);
                for (int q = 0; q < 9; q++) X[q] += (So_i[q] - Sn_i[q]) * d;
            }
            bool zero = true;
            for (int q = 0; q < 9 && zero; q++) zero = X[q] == 0.0;
            if (zero) continue;
            add_triple(L0, &L1->A, i, j, X, touched);
            if (j != i && !h->inchg[j]) {  /* the block (j, i) = X^T: its row is not visited */
                double XT[9];
                for (int r = 0; r < 3; r++)
                    for (int q = 0; q < 3; q++) XT[3 * q + r] = X[3 * r + q];
                add_triple(L0, &L1->A, j, i, XT, touched);
            }
        }
    }
    /* the touched rows: lower blocks from the upper ones, diagonal blocks symmetric, and their
       smoother blocks (a dead unknown's diagonal was set in A_1 and stays) */
    bsr *C = &L1->A;
    for (int32_t I = 0; I < L1->n; I++) {
        if (touched[I] < 0) continue;
        for (int32_t a = C->ptr[I]; a < C->ptr[I + 1]; a++) {
            const int32_t J = C->col[a];
            float *u = C->val + (size_t)a * NS * NS;
            if (J == I) {
                for (int r = 0; r < NS; r++)
                    for (int q = r + 1; q < NS; q++) u[r * NS + q] = u[q * NS + r] = 0.5f * (u[r * NS + q] + u[q * NS + r]);
            } else if (J > I) {
                const int32_t t = find_slot(C, J, I);
                if (t < 0) continue;
                float *o = C->val + (size_t)t * NS * NS;
                for (int r = 0; r < NS; r++)
                    for (int q = 0; q < NS; q++) o[q * NS + r] = u[r * NS + q];
            }
        }
    }
    for (int32_t I = 0; I < L1->n; I++) {
        if (touched[I] < 0) continue;
        touched[I] = -1;
        double d[NS * NS];
        if (coarse_diag_block(L1, I, d, NULL)) spd_inverse(d, NS, L1->dinv + (size_t)I * NS * NS);
    }
    if (h->nlev == 2 && coarsest_factor(h)) rc = -1;
    /* the finest level's damping for the new operator (the rows that changed can move
       rho(D^-1 A') either way; a stale w over-relaxed them and the cycle lost positivity) */
    if (rc >= 0) {
        const double rho0 = spectral_radius(c, L0, 0);
        if (rho0 < 0) rc = -1;
        else L0->omega = 4.0 / (3.0 * rho0);
    }

    /* the new filter is the stored one (the contact list is compacted when it grew past twice the
       vertices in contact: each update appends the changed vertices' normals) */
    for (int32_t k = 0; k < nchg && rc >= 0; k++)
        if (store_vertex(h, c, h->changed[k])) rc = -1;
    if (rc >= 0 && h->nsn > 2 * (size_t)nchg + 64) {
        int32_t live = 0;
        for (int32_t i = 0; i < c->nv; i++) live += h->sflag[i] == VC_CONTACT;
        if (h->nsn > 2 * (size_t)live + 64 && store_all(h, c)) rc = -1;
    }
out:
    for (int32_t k = 0; k < nchg; k++) h->inchg[h->changed[k]] = 0;
    rowsrc_free(&src);
    if (rc < 0) { h->nlev = 0; h->agg_levels = 0; }
    return rc;
}

/* ---------------- the V-cycle ---------------- */

/* Levels >= 1: x = V-cycle of b (double vectors, float operators): a forward Gauss-Seidel sweep
 * from zero, the coarse correction, a backward sweep. */
static void vcycle(const tc_cloth *c, tc_amg *h, int l, const double *b, double *x)
{
    level *L = &h->lev[l];
    const size_t nb = (size_t)L->n * L->b;
    double *r = L->res;
    if (l == h->nlev - 1 && h->nc) { cholesky_solve(h->chol, h->nc, b, x); return; }
    memset(x, 0, nb * sizeof(double));
    level_sweep(L, b, x, true);
    if (l == h->nlev - 1) {
        /* no factor (a level too big for one, or one coarsening stalled on): more symmetric
           sweeps, still a symmetric positive operator */
        level_sweep(L, b, x, false);
        for (int s = 1; s < TC_AMG_COARSE_SWEEPS; s++) {
            level_sweep(L, b, x, true);
            level_sweep(L, b, x, false);
        }
        return;
    }
    bsr_apply(&L->A, x, r, false);
    for (size_t k = 0; k < nb; k++) r[k] = b[k] - r[k];
    level *N = &h->lev[l + 1];
    bsr_apply_transposed(&L->P, r, N->rhs);
    vcycle(c, h, l + 1, N->rhs, N->x);
    bsr_apply(&L->P, N->x, x, true);
    level_sweep(L, b, x, false);
}

/* x_i = w S_i (P_i b_i) (the pre-smoothing of the finest level from zero) */
TC_HOT static void fine_presmooth(const tc_cloth *c, double w, const double *restrict b, double *restrict x)
{
    const double *Pv = tc_vec_ptr(&c->pinv);
    const int8_t *fl = tc_vec_ptr(&c->vflag), *cnt = tc_vec_ptr(&c->scount);
    const double *N = tc_vec_ptr(&c->snorm);
    for (int32_t i = 0; i < c->nv; i++) {
        const double *p = Pv + 9 * (size_t)i, *bi = b + 3 * (size_t)i;
        double *o = x + 3 * (size_t)i;
        o[0] = w * (p[0] * bi[0] + p[1] * bi[1] + p[2] * bi[2]);
        o[1] = w * (p[3] * bi[0] + p[4] * bi[1] + p[5] * bi[2]);
        o[2] = w * (p[6] * bi[0] + p[7] * bi[1] + p[8] * bi[2]);
        if (fl[i] != VC_FREE) filter_vertex(fl[i], cnt[i], N + 9 * (size_t)i, o);
    }
}

/* y_i = b_i - S_i y_i in place (the residual, y = A x on entry) */
TC_HOT static void fine_residual(const tc_cloth *c, const double *restrict b, double *restrict y)
{
    const int8_t *fl = tc_vec_ptr(&c->vflag), *cnt = tc_vec_ptr(&c->scount);
    const double *N = tc_vec_ptr(&c->snorm);
    for (int32_t i = 0; i < c->nv; i++) {
        double *o = y + 3 * (size_t)i;
        if (fl[i] != VC_FREE) filter_vertex(fl[i], cnt[i], N + 9 * (size_t)i, o);
        const double *bi = b + 3 * (size_t)i;
        o[0] = bi[0] - o[0]; o[1] = bi[1] - o[1]; o[2] = bi[2] - o[2];
    }
}

/* x_i += w S_i P_i (b_i - S_i y_i), and b . x (the post-smoothing, y = A x on entry) */
TC_HOT static double fine_postsmooth(const tc_cloth *c, double w, const double *restrict b, double *restrict y,
                                     double *restrict x)
{
    const double *Pv = tc_vec_ptr(&c->pinv);
    const int8_t *fl = tc_vec_ptr(&c->vflag), *cnt = tc_vec_ptr(&c->scount);
    const double *N = tc_vec_ptr(&c->snorm);
    double d0 = 0.0, d1 = 0.0;
    for (int32_t i = 0; i < c->nv; i++) {
        const double *p = Pv + 9 * (size_t)i, *bi = b + 3 * (size_t)i;
        double *yi = y + 3 * (size_t)i, *o = x + 3 * (size_t)i;
        const bool con = fl[i] != VC_FREE;
        if (con) filter_vertex(fl[i], cnt[i], N + 9 * (size_t)i, yi);
        const double r0 = bi[0] - yi[0], r1 = bi[1] - yi[1], r2 = bi[2] - yi[2];
        double t[3] = {p[0] * r0 + p[1] * r1 + p[2] * r2, p[3] * r0 + p[4] * r1 + p[5] * r2,
                       p[6] * r0 + p[7] * r1 + p[8] * r2};
        if (con) filter_vertex(fl[i], cnt[i], N + 9 * (size_t)i, t);
        o[0] += w * t[0]; o[1] += w * t[1]; o[2] += w * t[2];
        const double d = bi[0] * o[0] + bi[1] * o[1] + bi[2] * o[2];
        if (i & 1) d1 += d; else d0 += d;
    }
    return d0 + d1;
}

/* For the tests: the largest relative error of u . A_1 v against (P u) . A' (P v) by the solver's
 * product (the current filter), over a few pseudo-random coarse u, v (the Galerkin product made
 * from the rows, stored in float32, must be that triple product), and of u . A_1 v against
 * v . A_1 u (its symmetry). -1 without a level 1. */
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
        const int8_t *fl = tc_vec_ptr(&c->vflag);
        for (int trial = 0; trial < 3; trial++) {
            for (size_t k = 0; k < nc; k++) {
                u[k] = sin(0.37 * (double)k + trial);
                v[k] = cos(1.13 * (double)k - 2.0 * trial);
            }
            bsr_apply(&L->P, u, pu, false);
            bsr_apply(&L->P, v, pv, false);
            /* A' (P v) = S A S (P v) + (I - S) d (P v) */
            memcpy(apv, pv, nf * sizeof(double));
            tc_constraint_filter(c, apv);
            double *spv = malloc(nf * sizeof(double));
            if (!spv) { worst = -1.0; break; }
            memcpy(spv, apv, nf * sizeof(double));
            tc_matvec(c, spv, apv);
            tc_constraint_filter(c, apv);
            const double *Dg = tc_vec_ptr(&c->diag);
            for (int32_t i = 0; i < L->n; i++) {
                if (fl[i] == VC_FREE) continue;
                double a[9];
                from_columns(Dg + 12 * (size_t)i, 4, a);
                const double d = off_range_scale(a);
                for (int k = 0; k < 3; k++) apv[3 * i + k] += d * (pv[3 * i + k] - spv[3 * i + k]);
            }
            free(spv);
            double fine = 0.0, scale = 0.0;
            for (size_t k = 0; k < nf; k++) { fine += pu[k] * apv[k]; scale += fabs(pu[k] * apv[k]); }
            bsr_apply(&N->A, v, w, false);
            double coarse = 0.0;
            for (size_t k = 0; k < nc; k++) coarse += u[k] * w[k];
            bsr_apply(&N->A, u, w, false);
            double swapped = 0.0;
            for (size_t k = 0; k < nc; k++) swapped += v[k] * w[k];
            if (!(scale > 0)) scale = 1.0;
            worst = fmax(worst, fmax(fabs(coarse - fine), fabs(coarse - swapped)) / scale);
        }
    }
    free(u); free(v); free(w); free(pu); free(pv); free(apv);
    return worst;
}

/* z = M^-1 r with M^-1 the V-cycle (r and z on the range of S); returns r . z */
double tc_amg_apply(const tc_cloth *c, tc_amg *h, const double *r, double *z)
{
    level *L = &h->lev[0], *N = &h->lev[1];
    const double w = L->omega;
    double *y = L->res;
    fine_presmooth(c, w, r, z);
    if (h->nlev < 2) {
        tc_matvec(c, z, y);
        return fine_postsmooth(c, w, r, y, z);
    }
    tc_matvec(c, z, y);
    fine_residual(c, r, y);
    bsr_apply_transposed(&L->P, y, N->rhs);
    vcycle(c, h, 1, N->rhs, N->x);
    /* prolongation: z += S P x_1 (z is on the range of S already) */
    bsr_apply(&L->P, N->x, z, true);
    tc_constraint_filter(c, z);
    tc_matvec(c, z, y);
    return fine_postsmooth(c, w, r, y, z);
}
