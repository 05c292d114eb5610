/* amg.c - smoothed-aggregation algebraic multigrid (Vanek, Mandel & Brezina 1996) as the
 * preconditioner of the solver's CG where block Jacobi needs many iterations: stiff sheets, long
 * sub-steps, fine meshes (its iterations grow with dt sqrt(k / m) and with the mesh: 46 at 1K
 * triangles, 590 at 100K), while a V-cycle keeps them near ten. solver.c decides when it pays.
 *
 * What this file owns: the hierarchy (aggregates, prolongators, Galerkin coarse operators, the
 * coarsest level's Cholesky factor), its numeric refresh, its extension through a tear, and the
 * V-cycle.
 *
 * The operator is the constrained one of the solve, S A S on the range of the filter S
 * (constraints.c), made definite off that range by (I - S) times a diagonal scale: A' = S A S +
 * (I - S) d. Only the finest level's smoother sees A' (below); the hierarchy is made for the
 * reference filter, where pins and handles are fixed and contact vertices free. Nothing stores the
 * fine matrix: the setup and the refresh read fem.c's rows in place.
 *   - Strength of connection on A's 3x3 (coarse: 6x6) blocks, |A_ij|_F >= theta sqrt(|A_ii| |A_jj|);
 *     fully constrained vertices (pins, handles) take no part: the smoother alone handles them.
 *   - Aggregation: the three passes of standard aggregation (pyamg's standard_aggregation).
 *   - Near-null space: the six rigid-body modes of a shell (3 translations, 3 rotations about the
 *     aggregate's centroid, from the vertex positions, zero on pins and handles); the tentative
 *     prolongator is their QR per aggregate (modified Gram-Schmidt, twice), R the next level's
 *     near-null space. A mode an aggregate cannot carry (a two-vertex aggregate has no twist about
 *     its axis) gives a zero column: that coarse unknown is decoupled with a unit-scaled diagonal.
 *   - Prolongator smoothing by one damped Jacobi step P = (I - w D^-1 A) T, w = 4/(3 rho(D^-1 A)),
 *     rho from power iterations; coarse operators A_c = P^T A P (P's rows of pins and handles are
 *     zero, so no filter enters), their pattern made with P, their numbers by one pass over the
 *     fine rows scattering P_i^T (A P)_i into C's blocks (flaps read as the scalars they are).
 *   - Coarsest level (at most TC_AMG_COARSEST unknowns): a dense Cholesky factor.
 * P and the coarse operators are stored in float32 (computed in double, read into double): the
 * V-cycle is a preconditioner, any fixed SPD approximation serves, and half the bytes are half the
 * memory (the target is 1 KB per triangle at 100K) and half the traffic of its products. A coarse
 * operator is exactly symmetric (its lower blocks are made as the transposes of the upper ones), so
 * only its upper blocks (J >= I) are stored; a lower slot names its mirror's block (bsr.vix) and
 * every reader takes it transposed, with the same operations in the same order as on a stored
 * copy (the products' lower blocks come first in a row: their accumulators are kept transposed
 * and turned once per row), so results are those of the full storage to the bit. 36 bytes per
 * triangle of a 100K-triangle square.
 *
 * Contacts. The V-cycle as a map of the residual is M^-T (M + M^T - A') M^-1 + W A_c^-1 W^T with
 * W = (I - M^-T A') S P and M the forward sweep: symmetric positive for ANY symmetric positive
 * coarse operator A_c, as long as the fine smoother converges on A'. So the fine level is smoothed
 * by block Gauss-Seidel on A' itself (pins and handles held, a contact vertex's block solved on its
 * free directions), which converges on any SPD matrix with no damping estimate, and the coarse
 * operators, made with contact vertices free, serve unchanged whatever the contacts do: a changed
 * contact set (the next sub-step's, or a contact round's releases and slides) costs nothing here.
 * (Before, the first coarse operator was updated over the changed rows and a damped Jacobi fine
 * smoother needed its damping re-estimated: its stale value made the cycle indefinite, and across
 * sub-steps the update's mismatch with an older matrix did too, so every sub-step with contacts
 * rebuilt the hierarchy.) The race scene took 53 iterations a sub-step with the exact update and
 * 57 with contacts left to the sweeps.
 *
 * The contact correction (tc_amg_contacts). Positive is not strong: the coarse correction runs
 * through S P, whose Galerkin operator is P^T S A S P, and P^T A P counts the stiffness of the
 * directions a contact takes away as free, so the cycle overshot there. On a grid with a fifth of
 * its vertices touching (test_cg_iterations_agree_across_kernels) CG left a relative residual force
 * of 1.6 after 10 iterations (8.4e-5 without the contacts) and was not at 1e-6 after 60; the same
 * sensitivity made the AVX2 and scalar kernels part by 4.7e-12 of the solution there. So, while
 * contacts last, A_1 = P^T (S A S + tau (I - S) d) P: the build's A_1 is kept (base1) and
 * Delta = P^T (S A S - A + tau (I - S) d) P is added over the rows that touch a contact vertex
 * (contact_delta: one pass like the Galerkin row's, in double, narrowed once), then the coarser
 * levels and the coarsest factor are made again from it. tau (constants.h) keeps an aggregate whose
 * vertices are all held (S = 0) definite. Made at every refresh (in numeric, between A_1 and the
 * coarser levels, so those are made once), when there is none (a build, the first contacts), and
 * between refreshes only when the contact set was replaced (constants.h, TC_AMG_CONTACT_CHANGE: a
 * correction for a nearby set is still a symmetric positive A_1). Bench part "multigrid": the
 * race's shirt at 20K triangles on the walking body, where "auto" picks the multigrid.
 *
 * The matrix changes every sub-step (co-rotation, damping, contacts) while the mesh rarely does, so
 * the hierarchy is kept in three layers: the aggregates (made again when vertices were removed or
 * renumbered, pins or handles changed, a snapshot was taken - tc_amg_forget: a resumed run must
 * build the same hierarchy as the uninterrupted one - or every TC_AMG_REAGGREGATE builds; after a
 * tear the new vertices join a neighbour's aggregate), the prolongators with the coarse operators'
 * patterns (tc_amg_build), and the coarse operators' numbers (tc_amg_refresh, a third to a quarter
 * of a build: only numbers change between refreshes of the same prolongators). solver.c says when
 * each is due. Between refreshes the finest level is still the current matrix; only the coarse
 * correction is that of a slightly older one.
 *
 * The cycle: a forward Gauss-Seidel sweep from zero that makes its residual as it goes
 * (first_residual: no product of its own), its restriction, the coarse levels (the same forward
 * sweep with its residual, correction, backward Gauss-Seidel on 6x6 blocks; the coarsest
 * factored), the prolongation filtered by S, a backward sweep that also takes r . z for CG. No
 * allocation in the cycle.
 */
#include "core.h"
#include "matvec.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

enum { NS = 6 };  /* near-null-space modes: 3 translations, 3 rotations */

/* block sparse rows with float32 blocks: n block rows, m block columns, blocks br x bc row-major.
 * A symmetric one (the coarse operators) stores its upper blocks only: vix gives each slot its
 * block in val, its own (J >= I) or its mirror's, read transposed (J < I); without vix slot a's
 * block is val's a-th. */
typedef struct bsr {
    int32_t n, m, br, bc;
    int32_t *ptr, *col;
    int32_t *vix;
    float *val;
    size_t cap_rows, cap_nnz, cap_val;
} bsr;

/* slot a's block (of row i: transposed when bsr_lower) */
static inline const float *bsr_block(const bsr *M, int32_t a)
{
    return M->val + (size_t)(M->vix ? M->vix[a] : a) * (size_t)M->br * (size_t)M->bc;
}
static inline bool bsr_lower(const bsr *M, int32_t i, int32_t a) { return M->vix && M->col[a] < i; }

typedef struct level {
    int32_t n, b;          /* block rows and block size (3 on the finest level, NS below) */
    bsr A;                 /* the operator (levels >= 1; level 0 is fem.c's rows) */
    bsr P;                 /* prolongator from the next level (restriction: its transpose) */
    double *dinv;          /* inverse diagonal blocks, b*b each (levels >= 1; level 0: c->pinv) */
    double omega;          /* the prolongator's smoothing step, 4 / (3 rho(D^-1 A)) */
    int32_t *agg;          /* aggregate of each block row, -1 none */
    int32_t nagg;
    double *B;             /* near-null space, n*b x NS row-major (levels >= 1, during a build) */
    uint8_t *dead;         /* per unknown: a mode its aggregate could not carry (levels >= 1) */
    double *x, *rhs, *res; /* V-cycle vectors (levels >= 1; level 0 has none: level_vectors) */
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
    int refreshes;         /* numeric refreshes since the prolongators were made */
    int32_t run_blocks;    /* a refresh's double buffer, in blocks (0: TC_AMG_GALERKIN_BLOCKS; tests) */
    int8_t choice;         /* the preconditioner "auto" picked last (1 this cycle, 0 block Jacobi, -1
                              none since this object was made or a snapshot: solver.c's hysteresis) */
    /* scratch of the sparse products */
    int32_t *mark;
    double *acc;
    size_t cap_mark, cap_acc;
    /* the contact correction of A_1 (tc_amg_contacts): A_1 as the build or refresh made it (contact
       vertices free) while a correction is in A_1, and the contact set that correction is for */
    float *base1;
    size_t cap_base1;
    bool base1_saved, corrected;
    bool follow;           /* tc_amg_follow_contacts (the bench's comparison: off) */
    int8_t *used_cnt;      /* per vertex, the contact directions the correction was made with (0: none) */
    float *used_n;         /* and its first direction */
    size_t cap_used;
    int32_t *slot_of;      /* a stored block of A_1 -> its accumulator in acc2, -1 none */
    double *acc2;
    size_t cap_slot_of, cap_acc2;
};

/* ---------------- memory ---------------- */

static int grow(void **p, size_t *cap, size_t need, size_t item)
{
    if (need <= *cap && *p) return 0;
    size_t n = need + need / 2 + 16;
    void *q = tc_mem_realloc(*p, n * item);
    if (!q) return -1;
    *p = q;
    *cap = n;
    return 0;
}

/* room for n block rows and nnz slots (with their vix when sym), exactly (a hierarchy is made
 * again at the same sizes on every refresh, so slack would only be held) */
static int bsr_reserve(bsr *a, int32_t n, size_t nnz, bool sym)
{
    if ((size_t)n + 1 > a->cap_rows || !a->ptr) {
        int32_t *p = tc_mem_realloc(a->ptr, ((size_t)n + 1) * sizeof(int32_t));
        if (!p) return -1;
        a->ptr = p;
        a->cap_rows = (size_t)n + 1;
    }
    if (nnz > a->cap_nnz || !a->col || (sym && !a->vix)) {
        const size_t cn = nnz ? nnz : 1;
        int32_t *col = tc_mem_realloc(a->col, cn * sizeof(int32_t));
        if (!col) return -1;
        a->col = col;
        if (sym) {
            int32_t *x = tc_mem_realloc(a->vix, cn * sizeof(int32_t));
            if (!x) return -1;
            a->vix = x;
        }
        a->cap_nnz = cn;
    }
    if (!sym && a->vix) { tc_mem_free(a->vix); a->vix = NULL; }
    return 0;
}

/* room for nb blocks of values, exactly */
static int bsr_reserve_values(bsr *a, size_t nb)
{
    if (nb > a->cap_val || !a->val) {
        const size_t cn = nb ? nb : 1;
        float *v = tc_mem_realloc(a->val, cn * (size_t)a->br * (size_t)a->bc * sizeof(float));
        if (!v) return -1;
        a->val = v;
        a->cap_val = cn;
    }
    return 0;
}

static void bsr_free(bsr *a)
{
    tc_mem_free(a->ptr); tc_mem_free(a->col); tc_mem_free(a->vix); tc_mem_free(a->val);
    memset(a, 0, sizeof *a);
}

void tc_amg_free(tc_amg *h)
{
    if (!h) return;
    for (int l = 0; l < TC_AMG_MAX_LEVELS; l++) {
        level *L = &h->lev[l];
        bsr_free(&L->A); bsr_free(&L->P);
        tc_mem_free(L->dinv); tc_mem_free(L->agg); tc_mem_free(L->B); tc_mem_free(L->dead); tc_mem_free(L->x); tc_mem_free(L->rhs); tc_mem_free(L->res);
    }
    tc_mem_free(h->chol); tc_mem_free(h->mark); tc_mem_free(h->acc);
    tc_mem_free(h->base1); tc_mem_free(h->slot_of); tc_mem_free(h->acc2); tc_mem_free(h->used_cnt); tc_mem_free(h->used_n);
    tc_mem_free(h);
}

size_t tc_amg_bytes(const tc_amg *h)
{
    if (!h) return 0;
    size_t s = sizeof *h;
    for (int l = 0; l < TC_AMG_MAX_LEVELS; l++) {
        const level *L = &h->lev[l];
        const bsr *m[2] = {&L->A, &L->P};
        for (int k = 0; k < 2; k++)
            s += m[k]->cap_rows * 4 + m[k]->cap_nnz * (m[k]->vix ? 8 : 4) + m[k]->cap_val * 4 * (size_t)m[k]->br * (size_t)m[k]->bc;
        const size_t n = (size_t)L->n, b = (size_t)L->b;
        if (L->agg) s += n * 4;
        if (L->dinv) s += n * b * b * 8;
        if (L->B) s += n * b * NS * 8;
        if (L->dead) s += n * NS;
        s += ((L->x != NULL) + (L->rhs != NULL) + (L->res != NULL)) * L->cap_vec * 8;
    }
    return s + h->cap_chol * 8 + h->cap_mark * 4 + h->cap_acc * 8 + h->cap_base1 * 4 + h->cap_slot_of * 4 + h->cap_acc2 * 8 + h->cap_used * 13;
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
    tc_mem_free(s->col); tc_mem_free(s->val);
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
    s->col = tc_mem_malloc((size_t)m * sizeof(int32_t));
    s->val = tc_mem_malloc((size_t)m * bb * sizeof(double));
    return s->col && s->val ? 0 : -1;
}

static void rowsrc_free(rowsrc *s)
{
    tc_mem_free(s->col); tc_mem_free(s->val);
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
        for (int32_t j = 0; j < k; j++) {
            const float *v = bsr_block(s->A, a + j);
            double *o = s->val + (size_t)j * NS * NS;
            if (bsr_lower(s->A, i, a + j))
                for (int r = 0; r < NS; r++)
                    for (int q = 0; q < NS; q++) o[r * NS + q] = v[q * NS + r];
            else
                for (int q = 0; q < NS * NS; q++) o[q] = v[q];
        }
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

/* the same for a symmetric operator (upper blocks stored): a lower slot's block read transposed */
static void dot_sym(const bsr *M, const double *restrict x, double *restrict y, bool add)
{
    for (int32_t i = 0; i < M->n; i++) {
        double acc[NS] = {0};
        for (int32_t a = M->ptr[i]; a < M->ptr[i + 1]; a++) {
            const float *v = bsr_block(M, a);
            const double *xj = x + (size_t)M->col[a] * NS;
            const int rs = bsr_lower(M, i, a) ? 1 : NS, cs = rs == 1 ? NS : 1;
            for (int r = 0; r < NS; r++)
                for (int q = 0; q < NS; q++) acc[r] += (double)v[r * rs + q * cs] * xj[q];
        }
        for (int r = 0; r < NS; r++) y[(size_t)i * NS + r] = add ? y[(size_t)i * NS + r] + acc[r] : acc[r];
    }
}

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

/* Row i of a symmetric operator: its lower slots (a prefix of the row: columns sorted) from *pa
 * on, summed into a4/a2 (row r: columns 0-3 and 4-5 of the block row, as the kernels above and the
 * Gauss-Seidel sweep keep them) with the stored upper block A_JI read as A_IJ = A_JI^T: row q of
 * A_JI is column q of A_IJ, so its accumulators are kept transposed (t[q]: lane r) and turned once
 * at the end. Each of the 36 sums gets the same fused multiply-adds in the same order as from a
 * stored A_IJ, so the results are the same to the bit. *pa moves past them. */
AVX2 static inline void lower_sum_avx2(const bsr *M, int32_t i, int32_t *pa, const double *restrict x, __m256d a4[NS],
                                       __m128d a2[NS])
{
    int32_t a = *pa;
    const int32_t end = M->ptr[i + 1];
    for (int r = 0; r < NS; r++) { a4[r] = _mm256_setzero_pd(); a2[r] = _mm_setzero_pd(); }
    if (a >= end || M->col[a] >= i) return;
    __m256d t4[NS];
    __m128d t2[NS];
    for (int q = 0; q < NS; q++) { t4[q] = _mm256_setzero_pd(); t2[q] = _mm_setzero_pd(); }
    for (; a < end && M->col[a] < i; a++) {
        const float *v = bsr_block(M, a);
        const double *xj = x + (size_t)M->col[a] * NS;
        for (int q = 0; q < NS; q++) {
            const __m256d xq = _mm256_broadcast_sd(xj + q);
            t4[q] = _mm256_fmadd_pd(ld4f(v + q * NS), xq, t4[q]);
            t2[q] = _mm_fmadd_pd(ld2f(v + q * NS + 4), _mm256_castpd256_pd128(xq), t2[q]);
        }
    }
    double acc[NS * NS];  /* acc[r NS + q] */
    for (int q = 0; q < NS; q++) {
        double c[NS];
        _mm256_storeu_pd(c, t4[q]);
        _mm_storeu_pd(c + 4, t2[q]);
        for (int r = 0; r < NS; r++) acc[r * NS + q] = c[r];
    }
    for (int r = 0; r < NS; r++) { a4[r] = _mm256_loadu_pd(acc + r * NS); a2[r] = _mm_loadu_pd(acc + r * NS + 4); }
    *pa = a;
}

AVX2 static void dot_sym_avx2(const bsr *M, const double *restrict x, double *restrict y, bool add)
{
    for (int32_t i = 0; i < M->n; i++) {
        __m256d a4[NS];
        __m128d a2[NS];
        int32_t a = M->ptr[i];
        lower_sum_avx2(M, i, &a, x, a4, a2);
        for (; a < M->ptr[i + 1]; a++) {
            const float *v = bsr_block(M, a);
            const double *xj = x + (size_t)M->col[a] * NS;
            const __m256d x4 = _mm256_loadu_pd(xj);
            const __m128d x2 = _mm_loadu_pd(xj + 4);
            for (int r = 0; r < NS; r++) {
                a4[r] = _mm256_fmadd_pd(ld4f(v + r * NS), x4, a4[r]);
                a2[r] = _mm_fmadd_pd(ld2f(v + r * NS + 4), x2, a2[r]);
            }
        }
        double *yi = y + (size_t)i * NS;
        for (int r = 0; r < NS; r++) yi[r] = add ? yi[r] + hsum(a4[r], a2[r]) : hsum(a4[r], a2[r]);
    }
}
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
    if (avx2()) { (M->vix ? dot_sym_avx2 : M->br == 3 ? dot_3_avx2 : dot_6_avx2)(M, x, y, add); return; }
#endif
    (M->vix ? dot_sym : M->br == 3 ? dot_3 : dot_6)(M, x, y, add);
}

/* y = M^T x */
static void bsr_apply_transposed(const bsr *M, const double *x, double *y)
{
#ifdef TC_AMG_AVX2
    if (avx2()) { (M->br == 3 ? axpy_t_3_avx2 : axpy_t_6_avx2)(M, x, y); return; }
#endif
    (M->br == 3 ? axpy_t_3 : axpy_t_6)(M, x, y);
}

/* A coarse level's first sweep's residual res = b - A x as the sweep goes (as the finest level's,
 * first_residual): row I's own part, s - A_II x_I (s = b_I - sum_{J<I} A_IJ x_J), and
 * -A_JI x_I into each lower neighbour's res_J. A lower slot of row I names its mirror's block, which
 * is A_JI itself (the upper block of row J), so it is read as stored. */
static inline void coarse_first_residual(const bsr *A, int32_t I, const double s[NS], const double *xi, double *restrict res)
{
    double *oi = res + (size_t)I * NS;
    for (int r = 0; r < NS; r++) oi[r] += s[r];
    for (int32_t a = A->ptr[I]; a < A->ptr[I + 1]; a++) {
        const int32_t J = A->col[a];
        if (J > I) break;
        const float *v = bsr_block(A, a);  /* A_JI (J < I), A_II */
        double *o = res + (size_t)J * NS;
        for (int r = 0; r < NS; r++) {
            double t = 0.0;
            for (int q = 0; q < NS; q++) t += (double)v[r * NS + q] * xi[q];
            o[r] -= t;
        }
    }
}

/* One Gauss-Seidel sweep over a coarse level (6x6 float blocks, inverse diagonal blocks dinv in
 * double): x_I = D_I^-1 (b_I - sum_{J != I} A_IJ x_J), rows in order (forward) or reversed, each
 * with the newest x. The coarse levels' smoother: a forward sweep before the coarse correction and
 * a backward one after make a symmetric cycle, and Gauss-Seidel converges on any SPD matrix, so
 * no damping estimate is needed (a damped Jacobi step's, from power iterations, went stale when a
 * contact update moved rho(D^-1 A_1) by 2x: the cycle lost positivity and CG broke down). */
static void gs_sweep(const bsr *A, const double *dinv, const double *restrict b, double *restrict x, bool forward,
                     double *restrict res)
{
    for (int32_t k = 0; k < A->n; k++) {
        const int32_t I = forward ? k : A->n - 1 - k;
        double s[NS];
        for (int r = 0; r < NS; r++) s[r] = b[(size_t)I * NS + r];
        for (int32_t a = A->ptr[I]; a < A->ptr[I + 1]; a++) {
            const int32_t J = A->col[a];
            if (J == I) continue;
            if (res && J > I) break;  /* from zero: x_J = 0 above the diagonal (columns sorted) */
            const float *v = bsr_block(A, a);
            const double *xj = x + (size_t)J * NS;
            const int rs = bsr_lower(A, I, a) ? 1 : NS, cs = rs == 1 ? NS : 1;  /* A_IJ = A_JI^T */
            for (int r = 0; r < NS; r++) {
                double t = 0.0;
                for (int q = 0; q < NS; q++) t += (double)v[r * rs + q * cs] * xj[q];
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
        if (res) coarse_first_residual(A, I, s, xi, res);
    }
}

#ifdef TC_AMG_AVX2
/* coarse_first_residual with AVX2: the six row sums of A_JI x_I (a block row as four and two
 * floats, as the products above) folded by horizontal adds into one 4-lane and one 2-lane result */
__attribute__((target("avx2,fma"))) static inline void coarse_first_residual_avx2(const bsr *A, int32_t I, const double s[NS],
                                                                                  const double *xi, double *restrict res)
{
    double *oi = res + (size_t)I * NS;
    for (int r = 0; r < NS; r++) oi[r] += s[r];
    const __m256d x4 = _mm256_loadu_pd(xi);
    const __m128d x2 = _mm_loadu_pd(xi + 4);
    for (int32_t a = A->ptr[I]; a < A->ptr[I + 1]; a++) {
        const int32_t J = A->col[a];
        if (J > I) break;
        const float *v = bsr_block(A, a);  /* A_JI (J < I), A_II */
        __m256d p[NS];
        for (int r = 0; r < NS; r++)
            p[r] = _mm256_fmadd_pd(ld4f(v + r * NS), x4,
                                   _mm256_insertf128_pd(_mm256_setzero_pd(), _mm_mul_pd(ld2f(v + r * NS + 4), x2), 0));
        double *o = res + (size_t)J * NS;
        const __m256d h01 = _mm256_hadd_pd(p[0], p[1]), h23 = _mm256_hadd_pd(p[2], p[3]), h45 = _mm256_hadd_pd(p[4], p[5]);
        /* h01 = (p0a+p0b, p1a+p1b, p0c+p0d, p1c+p1d): lanes 0,1 + lanes 2,3 give rows 0, 1 */
        const __m256d s0123 = _mm256_add_pd(_mm256_permute2f128_pd(h01, h23, 0x20), _mm256_permute2f128_pd(h01, h23, 0x31));
        const __m128d s45 = _mm_add_pd(_mm256_castpd256_pd128(h45), _mm256_extractf128_pd(h45, 1));
        _mm256_storeu_pd(o, _mm256_sub_pd(_mm256_loadu_pd(o), s0123));
        _mm_storeu_pd(o + 4, _mm_sub_pd(_mm_loadu_pd(o + 4), s45));
    }
}

__attribute__((target("avx2,fma"))) static void gs_sweep_avx2(const bsr *A, const double *dinv, const double *restrict b,
                                                              double *restrict x, bool forward, double *restrict res)
{
    for (int32_t k = 0; k < A->n; k++) {
        const int32_t I = forward ? k : A->n - 1 - k;
        __m256d a4[NS];
        __m128d a2[NS];
        int32_t a0 = A->ptr[I];
        lower_sum_avx2(A, I, &a0, x, a4, a2);  /* the lower blocks, stored as their mirrors */
        for (int32_t a = a0; a < (res ? a0 : A->ptr[I + 1]); a++) {  /* from zero: x_J = 0 above */
            const int32_t J = A->col[a];
            if (J == I) continue;
            const float *v = bsr_block(A, a);
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
        if (res) coarse_first_residual_avx2(A, I, s, xi, res);
    }
}
#endif

/* a sweep; res non-NULL (zeroed): a forward sweep from x = 0 that leaves b - A x there */
static void level_sweep(const level *L, const double *b, double *x, bool forward, double *res)
{
#ifdef TC_AMG_AVX2
    if (avx2()) { gs_sweep_avx2(&L->A, L->dinv, b, x, forward, res); return; }
#endif
    gs_sweep(&L->A, L->dinv, b, x, forward, res);
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
        if (bsr_reserve(P, n, k, false) || bsr_reserve_values(P, k)) return -1;                                                          \
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

/* The pattern of C = P^T A P (NS x NS blocks, columns sorted in each row), from the patterns alone
 * (the rows of P^T: the fine rows of each aggregate, their columns, those columns' P blocks), in
 * two passes (the count, then the columns), so C takes what it needs and no more. Made when P is
 * made (an aggregation, a tear, a new prolongator); every numeric refresh reuses it. */
static int galerkin_pattern(tc_amg *h, rowsrc *s, const bsr *P, bsr *C)
{
    const int32_t n = P->n, na = P->m;
    int rc = -1;
    int32_t *tptr = tc_mem_calloc((size_t)na + 1, sizeof(int32_t));
    int32_t *trow = tc_mem_malloc(((size_t)P->ptr[n] + 1) * sizeof(int32_t));
    if (!tptr || !trow || scratch(h, na, 0)) goto done;
    for (int32_t a = 0; a < P->ptr[n]; a++) tptr[P->col[a] + 1]++;
    for (int32_t I = 0; I < na; I++) tptr[I + 1] += tptr[I];
    for (int32_t i = 0; i < n; i++)
        for (int32_t a = P->ptr[i]; a < P->ptr[i + 1]; a++) trow[tptr[P->col[a]]++] = i;
    for (int32_t I = na; I > 0; I--) tptr[I] = tptr[I - 1];
    tptr[0] = 0;
    int32_t *mark = h->mark;
    C->n = C->m = na; C->br = C->bc = NS;
    size_t k = 0;
    for (int pass = 0; pass < 2; pass++) {
        if (pass == 1 && bsr_reserve(C, na, k, true)) goto done;
        k = 0;
        for (int32_t I = 0; I < na; I++) {
            if (pass) C->ptr[I] = (int32_t)k;
            const size_t s0 = k;
            for (int32_t t = tptr[I]; t < tptr[I + 1]; t++) {
                const int32_t *col;
                const double *unused = NULL;
                const int32_t len = row_get(s, trow[t], &col, &unused, false);
                for (int32_t a = 0; a < len; a++) {
                    const int32_t j = col[a];
                    for (int32_t b = P->ptr[j]; b < P->ptr[j + 1]; b++) {
                        const int32_t J = P->col[b];
                        if (mark[J] == I) continue;
                        mark[J] = I;
                        if (pass) C->col[k] = J;
                        k++;
                    }
                }
            }
            /* sorted columns (a few dozen: insertion sort) */
            if (pass)
                for (size_t a = s0 + 1; a < k; a++) {
                    const int32_t v = C->col[a];
                    size_t b = a;
                    while (b > s0 && C->col[b - 1] > v) { C->col[b] = C->col[b - 1]; b--; }
                    C->col[b] = v;
                }
        }
        for (int32_t J = 0; J < na; J++) mark[J] = -1;
    }
    C->ptr[na] = (int32_t)k;
    /* C is symmetric: its upper blocks stored, in slot order, a lower slot naming its mirror's
       (one past them a zero block for a mirror missing, which a symmetric A never leaves) */
    {
        int32_t nup = 0;
        for (int32_t I = 0; I < na; I++)
            for (int32_t a = C->ptr[I]; a < C->ptr[I + 1]; a++)
                if (C->col[a] >= I) C->vix[a] = nup++;
        for (int32_t I = 0; I < na; I++)
            for (int32_t a = C->ptr[I]; a < C->ptr[I + 1]; a++)
                if (C->col[a] < I) {
                    const int32_t t = find_slot(C, C->col[a], I);
                    C->vix[a] = t >= 0 ? C->vix[t] : nup;
                }
        if (bsr_reserve_values(C, (size_t)nup + 1)) goto done;
        memset(C->val + (size_t)nup * NS * NS, 0, NS * NS * sizeof(float));
    }
    rc = 0;
done:
    tc_mem_free(tptr); tc_mem_free(trow);
    return rc;
}

/* The numeric Galerkin product C = P^T A P on C's kept pattern (only numbers change between
 * refreshes of the same prolongator). One pass over the fine rows: row i's (A P)_i is summed once
 * in a small double accumulator (one 3 x 6 or 6 x 6 block per coarse column it reaches), then
 * P_iI^T (A P)_iJ is added into C's upper blocks (J >= I; the lower ones are their transposes, so
 * C is exactly symmetric). C is summed in double (a transient buffer, 288 bytes a block) and
 * narrowed to float32 at the end: an entry sums some fifty products whose stiffness parts cancel
 * on the near-null modes, which float sums would not resolve.
 * The finest level is read from fem.c's rows in place: edge blocks column by column, bending flaps
 * as the scalars they are (a flap's block is a multiple of I: a third of the work of a block), and
 * unfiltered: P's rows of pins and handles are zero (the near-null space is filtered by the
 * reference S), so P^T A P = P^T S A S P there, and contacts do not enter it (the cycle's fine
 * Gauss-Seidel sweeps handle them exactly). The small block products are written out with AVX2
 * (four doubles and two per row of six) where the CPU has it: the compiled loops stayed scalar. */

/* acc (3 x 6) += A (3 x 3: A[r][q] = a[cs * q + r]) P (3 x 6, float) */
static inline void blk3(double *restrict acc, const double *restrict a, int cs, const float *restrict pb)
{
    for (int r = 0; r < 3; r++)
        for (int q = 0; q < 3; q++) {
            const double x = a[cs * q + r];
            for (int e = 0; e < NS; e++) acc[r * NS + e] += x * (double)pb[q * NS + e];
        }
}
/* acc (3 x 6) += f P */
static inline void flap3(double *restrict acc, double f, const float *restrict pb)
{
    for (int k = 0; k < 3 * NS; k++) acc[k] += f * (double)pb[k];
}
/* acc (6 x 6) += A (6 x 6 float: A[r][q] = a[rs r + cs q], row-major or, a stored mirror,
 * transposed) P (6 x 6 float) */
static inline void blk6(double *restrict acc, const float *restrict a, int rs, int cs, const float *restrict pb)
{
    for (int r = 0; r < NS; r++)
        for (int q = 0; q < NS; q++) {
            const double x = a[r * rs + q * cs];
            for (int e = 0; e < NS; e++) acc[r * NS + e] += x * (double)pb[q * NS + e];
        }
}
/* o (6 x 6) += P^T (B x 6)^T acc (B x 6), B = 3 and 6 */
#define pta3(o, pb, acc) pta(o, pb, acc, 3)
#define pta6(o, pb, acc) pta(o, pb, acc, NS)
static inline void pta(double *restrict o, const double *restrict pb, const double *restrict acc, int B)
{
    for (int r = 0; r < B; r++)
        for (int x = 0; x < NS; x++) {
            const double p = pb[r * NS + x];
            for (int e = 0; e < NS; e++) o[x * NS + e] += p * acc[r * NS + e];
        }
}

#ifdef TC_AMG_AVX2
#define AVX2F __attribute__((target("avx2,fma")))
#define AVX2I __attribute__((target("avx2,fma"), always_inline))
AVX2I static inline void blk3_avx2(double *restrict acc, const double *restrict a, int cs, const float *restrict pb)
{
    __m256d p4[3];
    __m128d p2[3];
    for (int q = 0; q < 3; q++) { p4[q] = ld4f(pb + q * NS); p2[q] = ld2f(pb + q * NS + 4); }
    for (int r = 0; r < 3; r++) {
        __m256d o4 = _mm256_loadu_pd(acc + r * NS);
        __m128d o2 = _mm_loadu_pd(acc + r * NS + 4);
        for (int q = 0; q < 3; q++) {
            const __m256d x = _mm256_broadcast_sd(a + cs * q + r);
            o4 = _mm256_fmadd_pd(x, p4[q], o4);
            o2 = _mm_fmadd_pd(_mm256_castpd256_pd128(x), p2[q], o2);
        }
        _mm256_storeu_pd(acc + r * NS, o4);
        _mm_storeu_pd(acc + r * NS + 4, o2);
    }
}
AVX2I static inline void flap3_avx2(double *restrict acc, double f, const float *restrict pb)
{
    const __m256d x = _mm256_set1_pd(f);
    for (int r = 0; r < 3; r++) {
        _mm256_storeu_pd(acc + r * NS, _mm256_fmadd_pd(x, ld4f(pb + r * NS), _mm256_loadu_pd(acc + r * NS)));
        _mm_storeu_pd(acc + r * NS + 4, _mm_fmadd_pd(_mm256_castpd256_pd128(x), ld2f(pb + r * NS + 4), _mm_loadu_pd(acc + r * NS + 4)));
    }
}
AVX2I static inline void blk6_avx2(double *restrict acc, const float *restrict a, int rs, int cs, const float *restrict pb)
{
    __m256d p4[NS];
    __m128d p2[NS];
    for (int q = 0; q < NS; q++) { p4[q] = ld4f(pb + q * NS); p2[q] = ld2f(pb + q * NS + 4); }
    for (int r = 0; r < NS; r++) {
        __m256d o4 = _mm256_loadu_pd(acc + r * NS);
        __m128d o2 = _mm_loadu_pd(acc + r * NS + 4);
        for (int q = 0; q < NS; q++) {
            const __m256d x = _mm256_set1_pd((double)a[r * rs + q * cs]);
            o4 = _mm256_fmadd_pd(x, p4[q], o4);
            o2 = _mm_fmadd_pd(_mm256_castpd256_pd128(x), p2[q], o2);
        }
        _mm256_storeu_pd(acc + r * NS, o4);
        _mm_storeu_pd(acc + r * NS + 4, o2);
    }
}
#define pta3_avx2(o, pb, acc) pta_avx2(o, pb, acc, 3)
#define pta6_avx2(o, pb, acc) pta_avx2(o, pb, acc, NS)
AVX2I static inline void pta_avx2(double *restrict o, const double *restrict pb, const double *restrict acc, int B)
{
    __m256d a4[NS];
    __m128d a2[NS];
    for (int r = 0; r < B; r++) { a4[r] = _mm256_loadu_pd(acc + r * NS); a2[r] = _mm_loadu_pd(acc + r * NS + 4); }
    for (int x = 0; x < NS; x++) {
        __m256d o4 = _mm256_loadu_pd(o + x * NS);
        __m128d o2 = _mm_loadu_pd(o + x * NS + 4);
        for (int r = 0; r < B; r++) {
            const __m256d p = _mm256_broadcast_sd(pb + r * NS + x);
            o4 = _mm256_fmadd_pd(p, a4[r], o4);
            o2 = _mm_fmadd_pd(_mm256_castpd256_pd128(p), a2[r], o2);
        }
        _mm256_storeu_pd(o + x * NS, o4);
        _mm_storeu_pd(o + x * NS + 4, o2);
    }
}
#endif

/* one row's (A P) columns: mark[J] = its accumulator's index, cols its columns */
typedef struct aprow {
    int32_t *mark, *cols;
    double *acc;
    int32_t m;
} aprow;

/* the accumulator of coarse column J in the row being made (zeroed when new), B x NS */
static inline double *ap_slot(aprow *w, int32_t J, int B)
{
    int32_t q = w->mark[J];
    if (q < 0) {
        q = w->mark[J] = w->m++;
        w->cols[q] = J;
        memset(w->acc + (size_t)q * B * NS, 0, (size_t)B * NS * sizeof(double));
    }
    return w->acc + (size_t)q * B * NS;
}

/* One fine row of the numeric Galerkin product, instantiated with the portable block products and
 * with the AVX2 ones (one function per instruction set, so the small products inline into it):
 * row i's (A P)_i, then C's blocks (I, J >= I) += P_iI^T (A P)_iJ for the rows I in [I0, I1), into
 * cv (indexed from C->ptr[I0]). */
#define GALERKIN_ROW(NAME, ATTR, BLK3, FLAP3, BLK6, PTA3, PTA6)                                       \
    ATTR static int NAME(tc_amg *h, const tc_cloth *c, const level *L, int l, const bsr *C, double *cv, aprow *w, \
                         int32_t i, int32_t I0, int32_t I1, int32_t vbase)                            \
    {                                                                                                 \
        const bsr *P = &L->P;                                                                         \
        const int B = L->b;                                                                           \
        size_t reach = 0; /* room for every coarse column this row can reach */                       \
        if (l == 0) {                                                                                 \
            const int32_t *rp = tc_vec_ptr(&c->rptr), *rc = tc_vec_ptr(&c->rcol);                     \
            const int32_t *fp = tc_vec_ptr(&c->fptr), *fc = tc_vec_ptr(&c->fcol);                     \
            const double *D = tc_vec_ptr(&c->diag), *RB = tc_vec_ptr(&c->rblk), *FV = tc_vec_ptr(&c->fval); \
            reach = (size_t)(P->ptr[i + 1] - P->ptr[i]);                                              \
            for (int32_t s = rp[i]; s < rp[i + 1]; s++) reach += (size_t)(P->ptr[rc[s] + 1] - P->ptr[rc[s]]); \
            for (int32_t s = fp[i]; s < fp[i + 1]; s++) reach += (size_t)(P->ptr[fc[s] + 1] - P->ptr[fc[s]]); \
            if (reach * 3 * NS > h->cap_acc && grow((void **)&h->acc, &h->cap_acc, reach * 3 * NS, sizeof(double))) return -1; \
            w->acc = h->acc;                                                                          \
            const double *d = D + 12 * (size_t)i;                                                     \
            for (int32_t b = P->ptr[i]; b < P->ptr[i + 1]; b++)                                       \
                BLK3(ap_slot(w, P->col[b], 3), d, 4, P->val + (size_t)b * 3 * NS);                    \
            for (int32_t s = rp[i]; s < rp[i + 1]; s++) {                                             \
                const int32_t j = rc[s];                                                              \
                const double *a = RB + 9 * (size_t)s;                                                 \
                for (int32_t b = P->ptr[j]; b < P->ptr[j + 1]; b++)                                   \
                    BLK3(ap_slot(w, P->col[b], 3), a, 3, P->val + (size_t)b * 3 * NS);                \
            }                                                                                         \
            for (int32_t s = fp[i]; s < fp[i + 1]; s++) {                                             \
                const int32_t j = fc[s];                                                              \
                for (int32_t b = P->ptr[j]; b < P->ptr[j + 1]; b++)                                   \
                    FLAP3(ap_slot(w, P->col[b], 3), FV[s], P->val + (size_t)b * 3 * NS);              \
            }                                                                                         \
        } else {                                                                                      \
            for (int32_t a = L->A.ptr[i]; a < L->A.ptr[i + 1]; a++)                                   \
                reach += (size_t)(P->ptr[L->A.col[a] + 1] - P->ptr[L->A.col[a]]);                     \
            if (reach * NS * NS > h->cap_acc && grow((void **)&h->acc, &h->cap_acc, reach * NS * NS, sizeof(double))) return -1; \
            w->acc = h->acc;                                                                          \
            for (int32_t a = L->A.ptr[i]; a < L->A.ptr[i + 1]; a++) {                                 \
                const int32_t j = L->A.col[a];                                                        \
                const float *av = bsr_block(&L->A, a);                                                \
                const int rs = bsr_lower(&L->A, i, a) ? 1 : NS, cs = rs == 1 ? NS : 1;                \
                for (int32_t b = P->ptr[j]; b < P->ptr[j + 1]; b++)                                   \
                    BLK6(ap_slot(w, P->col[b], NS), av, rs, cs, P->val + (size_t)b * NS * NS);        \
            }                                                                                         \
        }                                                                                             \
        /* C's row I walked in order, each column's accumulator found by its mark (no search) */     \
        for (int32_t b = P->ptr[i]; b < P->ptr[i + 1]; b++) {                                         \
            const int32_t I = P->col[b];                                                              \
            if (I < I0 || I >= I1) continue;                                                          \
            double pb[NS * NS]; /* the block in double once, not once per column */                   \
            for (int q = 0; q < B * NS; q++) pb[q] = P->val[(size_t)b * B * NS + q];                  \
            for (int32_t a = C->ptr[I]; a < C->ptr[I + 1]; a++) {                                     \
                const int32_t J = C->col[a];                                                          \
                const int32_t q = J >= I ? w->mark[J] : -1;                                           \
                if (q < 0) continue;                                                                  \
                double *o = cv + (size_t)(C->vix[a] - vbase) * NS * NS; /* an upper block: stored */    \
                if (B == 3) PTA3(o, pb, w->acc + (size_t)q * 3 * NS);                                 \
                else PTA6(o, pb, w->acc + (size_t)q * NS * NS);                                       \
            }                                                                                         \
        }                                                                                             \
        for (int32_t q = 0; q < w->m; q++) w->mark[w->cols[q]] = -1;                                  \
        w->m = 0;                                                                                     \
        return 0;                                                                                     \
    }
GALERKIN_ROW(galerkin_row_c, TC_HOT, blk3, flap3, blk6, pta3, pta6)
#ifdef TC_AMG_AVX2
GALERKIN_ROW(galerkin_row_avx2, AVX2F, blk3_avx2, flap3_avx2, blk6_avx2, pta3_avx2, pta6_avx2)
#endif
#undef GALERKIN_ROW

/* upper slots (J >= I, the stored blocks) of C's rows [I0, I1) */
static int32_t upper_slots(const bsr *C, int32_t I0, int32_t I1)
{
    int32_t k = 0;
    for (int32_t I = I0; I < I1; I++)
        for (int32_t a = C->ptr[I]; a < C->ptr[I + 1]; a++) k += C->col[a] >= I;
    return k;
}

/* C = P^T A P on C's pattern (level l: 0 from fem.c's rows, else from the level's float operator),
 * by runs of C's rows of at most TC_AMG_GALERKIN_BLOCKS blocks: the double buffer is that big, not
 * C's size (at 100K triangles C holds ~125K blocks: 36 MB in double beside its 18 MB in float, the
 * peak of a refresh). A fine row whose P reaches two runs is made once for each (few: aggregates
 * are numbered along the mesh). The runs are counted in slots, lower ones too, as when those were
 * stored: a block's sum then takes its fine rows in the same order; the buffer holds the run's
 * upper blocks only, the ones summed (about half: half the transient peak of a refresh). */
static int galerkin_numeric(tc_amg *h, const tc_cloth *c, int l)
{
    const level *L = &h->lev[l];
    const bsr *P = &L->P;
    bsr *C = &h->lev[l + 1].A;
    const int32_t n = P->n, na = P->m, nnz = C->ptr[C->n];
    const int32_t most = h->run_blocks > 0 ? h->run_blocks : TC_AMG_GALERKIN_BLOCKS;
    int32_t run = nnz < most ? (nnz ? nnz : 1) : most;
    for (int32_t I = 0; I < C->n; I++) run = C->ptr[I + 1] - C->ptr[I] > run ? C->ptr[I + 1] - C->ptr[I] : run;  /* a row at least */
    int32_t most_upper = 1;
    for (int32_t I0 = 0, I1 = 0; I0 < na; I0 = I1) {  /* the runs below, for the largest one's upper blocks */
        I1 = I0 + 1;
        while (I1 < na && C->ptr[I1 + 1] - C->ptr[I0] <= run) I1++;
        const int32_t u = upper_slots(C, I0, I1);
        if (u > most_upper) most_upper = u;
    }
    double *cv = tc_mem_malloc((size_t)most_upper * NS * NS * sizeof(double));
    int32_t *cols = tc_mem_malloc(((size_t)na + 1) * sizeof(int32_t));
    int32_t *tptr = tc_mem_calloc((size_t)na + 1, sizeof(int32_t)), *trow = tc_mem_malloc(((size_t)P->ptr[n] + 1) * sizeof(int32_t));
    int32_t *seen = tc_mem_malloc(((size_t)n + 1) * sizeof(int32_t));
    int rcode = -1;
    if (!cv || !cols || !tptr || !trow || !seen || scratch(h, na, 0)) goto out;
    /* the rows of P^T: the fine rows each coarse row gathers from */
    for (int32_t a = 0; a < P->ptr[n]; a++) tptr[P->col[a] + 1]++;
    for (int32_t I = 0; I < na; I++) tptr[I + 1] += tptr[I];
    for (int32_t i = 0; i < n; i++)
        for (int32_t a = P->ptr[i]; a < P->ptr[i + 1]; a++) trow[tptr[P->col[a]]++] = i;
    for (int32_t I = na; I > 0; I--) tptr[I] = tptr[I - 1];
    tptr[0] = 0;
    for (int32_t i = 0; i < n; i++) seen[i] = -1;
    aprow w = {h->mark, cols, NULL, 0};
    int32_t vbase = 0;  /* the run's first upper block (they are numbered in slot order) */
    for (int32_t I0 = 0, I1 = 0; I0 < na; I0 = I1) {
        /* the run [I0, I1): at least one row, at most `run` blocks */
        I1 = I0 + 1;
        while (I1 < na && C->ptr[I1 + 1] - C->ptr[I0] <= run) I1++;
        const int32_t nb = upper_slots(C, I0, I1);
        memset(cv, 0, (size_t)nb * NS * NS * sizeof(double));
        for (int32_t I = I0; I < I1; I++)
            for (int32_t t = tptr[I]; t < tptr[I + 1]; t++) {
                const int32_t i = trow[t];
                if (seen[i] == I0) continue;
                seen[i] = I0;
#ifdef TC_AMG_AVX2
                if (avx2()) { if (galerkin_row_avx2(h, c, L, l, C, cv, &w, i, I0, I1, vbase)) goto out; continue; }
#endif
                if (galerkin_row_c(h, c, L, l, C, cv, &w, i, I0, I1, vbase)) goto out;
            }
        /* the run's upper blocks narrowed (the diagonal ones made exactly symmetric); the lower ones
           are their mirrors, read transposed (C is exactly symmetric) */
        for (int32_t I = I0; I < I1; I++)
            for (int32_t a = C->ptr[I]; a < C->ptr[I + 1]; a++) {
                const int32_t J = C->col[a];
                if (J < I) continue;
                double *u = cv + (size_t)(C->vix[a] - vbase) * NS * NS;
                if (J == I)
                    for (int r = 0; r < NS; r++)
                        for (int q = r + 1; q < NS; q++) u[r * NS + q] = u[q * NS + r] = 0.5 * (u[r * NS + q] + u[q * NS + r]);
                float *f = (float *)bsr_block(C, a);
                for (int q = 0; q < NS * NS; q++) f[q] = (float)u[q];
            }
        vbase += nb;
    }
    rcode = 0;
out:
    tc_mem_free(cv); tc_mem_free(cols); tc_mem_free(tptr); tc_mem_free(trow); tc_mem_free(seen);
    return rcode;
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
    int32_t *sptr = tc_mem_malloc(((size_t)n + 1) * sizeof(int32_t)), *scol = tc_mem_malloc((nnz + 1) * sizeof(int32_t));
    if (!sptr || !scol) { tc_mem_free(sptr); tc_mem_free(scol); return -1; }
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
    int32_t *na = tc_mem_realloc(L->agg, (size_t)c->nv * sizeof(int32_t));
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
    int32_t *start = tc_mem_calloc((size_t)na + 1, sizeof(int32_t)), *rows = tc_mem_malloc(((size_t)n + 1) * sizeof(int32_t));
    if (!start || !rows) { tc_mem_free(start); tc_mem_free(rows); return -1; }
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
    tc_mem_free(start); tc_mem_free(rows);
    return 0;
}

/* ---------------- per-level pieces ---------------- */

/* The V-cycle's vectors of a level: a coarse level has x, rhs and res; the finest none of its own
 * (its x and right-hand side are the solver's output and residual, its residual the solver's q:
 * tc_amg_apply), which at 100K triangles is 3.6 MB. */
static int level_vectors(level *L, bool finest)
{
    const size_t nb = (size_t)L->n * L->b;
    if (finest) {
        tc_mem_free(L->x); tc_mem_free(L->rhs); tc_mem_free(L->res);
        L->x = L->rhs = L->res = NULL;
        L->cap_vec = nb;
        return 0;
    }
    if (nb <= L->cap_vec && L->res) return 0;
    tc_mem_free(L->x); tc_mem_free(L->rhs); tc_mem_free(L->res);
    L->x = L->rhs = NULL;
    const size_t k = nb ? nb : 1;
    if (!finest) { L->x = tc_mem_malloc(k * sizeof(double)); L->rhs = tc_mem_malloc(k * sizeof(double)); }
    L->res = tc_mem_malloc(k * sizeof(double));
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
    if (l == 0) {  /* the finest level has no vectors: three of its own, for a moment */
        own = tc_mem_malloc(3 * (nb ? nb : 1) * sizeof(double));
        if (!own) return -1.0;
        x = own; y = own + nb; z = own + 2 * nb;
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
    tc_mem_free(own);
    return rho > 0 ? 1.1 * rho : 1.0;
}

/* the diagonal block of row I of a coarse level, in double (NULL when the row has none) */
static bool coarse_diag_block(const level *L, int32_t I, double d[NS * NS], float **stored)
{
    const int32_t s = find_slot(&L->A, I, I);
    if (s < 0) return false;
    float *v = (float *)bsr_block(&L->A, s);  /* a diagonal block is stored */
    for (int q = 0; q < NS * NS; q++) d[q] = v[q];
    if (stored) *stored = v;
    return true;
}

/* inverse diagonal blocks of a coarse level; a dead unknown gets the live diagonal's scale first
 * (written into the operator too, so an update of the row later reads the same block) */
static int coarse_diagonal(level *L)
{
    const uint8_t *dead = L->dead;
    double *di = tc_mem_realloc(L->dinv, ((size_t)L->n * NS * NS + 1) * sizeof(double));
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
            const float *v = bsr_block(&C->A, a);
            const int rs = bsr_lower(&C->A, i, a) ? 1 : NS, cs = rs == 1 ? NS : 1;
            for (int r = 0; r < NS; r++)
                for (int q = 0; q < NS; q++) h->chol[(size_t)(i * NS + r) * m + (j * NS + q)] = v[r * rs + q * cs];
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
    double *cen = tc_mem_calloc((size_t)L->nagg * 4 + 1, sizeof(double));
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
    tc_mem_free(cen);
}

/* ---------------- the hierarchy ---------------- */

tc_amg *tc_amg_new(void)
{
    tc_amg *h = tc_mem_calloc(1, sizeof(tc_amg));
    if (h) { h->choice = -1; h->follow = true; }
    return h;
}

int tc_amg_levels(const tc_amg *h) { return h ? h->nlev : 0; }

bool tc_amg_valid(const tc_amg *h, const tc_cloth *c)
{
    /* built for this mesh: its vectors have this many vertices and its aggregates these pairs */
    return h && h->nlev > 0 && h->nv == c->nv && h->pair_version == c->pair_version;
}

void tc_amg_forget(tc_amg *h)
{
    if (h) { h->forget = true; h->choice = -1; }
}

int tc_amg_choice(const tc_amg *h) { return h ? h->choice : -1; }

void tc_amg_set_choice(tc_amg *h, bool amg)
{
    if (h) h->choice = amg ? 1 : 0;
}

void tc_amg_drop(tc_amg *h)
{
    if (!h) return;
    const int8_t choice = h->choice;
    const bool follow = h->follow;
    const bool forget = h->forget;
    const int32_t run = h->run_blocks;
    for (int l = 0; l < TC_AMG_MAX_LEVELS; l++) {
        level *L = &h->lev[l];
        bsr_free(&L->A); bsr_free(&L->P);
        tc_mem_free(L->dinv); tc_mem_free(L->agg); tc_mem_free(L->B); tc_mem_free(L->dead); tc_mem_free(L->x); tc_mem_free(L->rhs); tc_mem_free(L->res);
    }
    tc_mem_free(h->chol); tc_mem_free(h->mark); tc_mem_free(h->acc);
    tc_mem_free(h->base1); tc_mem_free(h->slot_of); tc_mem_free(h->acc2); tc_mem_free(h->used_cnt); tc_mem_free(h->used_n);
    memset(h, 0, sizeof *h);
    h->choice = choice;
    h->follow = follow;
    h->forget = forget;
    h->run_blocks = run;
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

/* The numeric part of a hierarchy, on its kept aggregates, prolongators and patterns: the Galerkin
 * operators of the current matrix level by level, their smoothers' inverse diagonal blocks, the
 * coarsest level's factor. */
static int correct_first(tc_amg *h, const tc_cloth *c);
static int32_t contact_changes(const tc_amg *h, const tc_cloth *c, int32_t *count);

static int numeric(tc_amg *h, const tc_cloth *c)
{
    h->base1_saved = h->corrected = false;  /* A_1 is made anew, with contact vertices free */
    for (int l = 0; l + 1 < h->nlev; l++) {
        level *N = &h->lev[l + 1];
        if (galerkin_numeric(h, c, l) || coarse_diagonal(N)) return -1;
        int32_t count;
        /* with contacts, A_1 corrected (tc_amg_contacts) before the coarser levels are made from it,
           so a refresh makes them once (a failed correction is tried again by tc_amg_contacts) */
        if (l == 0 && h->follow && contact_changes(h, c, &count) > 0) correct_first(h, c);
    }
    return coarsest_factor(h);
}

/* Builds the hierarchy for the current matrix (after tc_assemble and tc_precondition_build): the
 * aggregates anew when `aggregate_again` or tc_amg_needs_aggregation says so, else the kept ones
 * (extended to the vertices a tear added); the near-null space, the smoothed prolongators and the
 * coarse operators' patterns from them; then the numeric part. */
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
     * sit under this build's scratch (the near-null space, T), the peak of a build. */
    for (int l = 0; l < TC_AMG_MAX_LEVELS; l++) { bsr_free(&h->lev[l].A); bsr_free(&h->lev[l].P); }
    h->nlev = 0;
    h->agg_levels = 0;
    h->base1_saved = h->corrected = false;
    L0->n = c->nv; L0->b = 3;
    if (level_vectors(L0, true)) goto out;
    int nlev = 1;
    for (int l = 0; l + 1 < TC_AMG_MAX_LEVELS; l++) {
        level *L = &h->lev[l], *N = &h->lev[l + 1];
        const int32_t n = L->n;
        if ((size_t)n * L->b <= TC_AMG_COARSEST) break;
        /* the prolongator is made on the reference filter (contacts free: see the file's head) */
        if (rowsrc_init(&src, c, L, l, true)) goto out;
        if (l >= kept) {
            tc_mem_free(dn); tc_mem_free(pass1);
            dn = tc_mem_malloc((size_t)n * sizeof(double));
            pass1 = tc_mem_malloc((size_t)n * sizeof(int32_t));
            if (!dn || !pass1) goto out;
            int32_t *na = tc_mem_realloc(L->agg, (size_t)n * sizeof(int32_t));
            if (!na) goto out;
            L->agg = na;
            if (strength_graph(&src, c, l, n, L->b, dn, &sptr, &scol)) goto out;
            L->nagg = aggregate(n, sptr, scol, dn, L->agg, pass1);
            tc_mem_free(sptr); tc_mem_free(scol);
            sptr = scol = NULL;
        }
        const int32_t na = L->nagg;
        if (na == 0 || (double)na > TC_AMG_MIN_COARSENING * (double)n) break;
        /* the prolongator's smoothing step: w = 4 / (3 rho(D^-1 A)) of this level */
        const double rho = spectral_radius(c, L, l);
        if (rho < 0) goto out;  /* out of memory */
        L->omega = 4.0 / (3.0 * rho);
        /* near-null space and tentative prolongator */
        tc_mem_free(B); tc_mem_free(Tv);
        B = tc_mem_malloc((size_t)n * L->b * NS * sizeof(double));
        Tv = tc_mem_malloc(((size_t)n * L->b * NS + 1) * sizeof(double));
        tc_mem_free(dead);
        dead = tc_mem_malloc(((size_t)na * NS + 1) * sizeof(int32_t));
        if (!B || !Tv || !dead) goto out;
        if (l == 0) fine_modes(c, L, B);
        else memcpy(B, L->B, (size_t)n * L->b * NS * sizeof(double));
        double *Bc = tc_mem_realloc(N->B, ((size_t)na * NS * NS + 1) * sizeof(double));
        uint8_t *nd = tc_mem_realloc(N->dead, (size_t)na * NS + 1);
        if (!Bc || !nd) { if (Bc) N->B = Bc; if (nd) N->dead = nd; goto out; }
        N->B = Bc;
        N->dead = nd;
        if (tentative(L, B, Tv, Bc, dead)) goto out;
        for (size_t k = 0; k < (size_t)na * NS; k++) nd[k] = (uint8_t)dead[k];
        tc_mem_free(B);  /* Tv holds it now, orthonormalised */
        B = NULL;
        if ((l == 0 ? prolongator_3 : prolongator_6)(h, &src, L, l, Tv, &L->P)) goto out;
        tc_mem_free(Tv);
        Tv = NULL;
        if (galerkin_pattern(h, &src, &L->P, &N->A)) goto out;
        N->n = na; N->b = NS;
        h->nlev = nlev = l + 2;
        /* this level's operator now, for the next one's aggregation and prolongator */
        if (galerkin_numeric(h, c, l) || coarse_diagonal(N) || level_vectors(N, false)) goto out;
    }
    h->nlev = nlev;
    if (coarsest_factor(h)) goto out;
    /* the coarse near-null spaces only feed the next level's tentative prolongator in this build:
       a refresh keeps the prolongators, so they go (288 bytes an aggregate) */
    for (int l = 1; l < TC_AMG_MAX_LEVELS; l++) { tc_mem_free(h->lev[l].B); h->lev[l].B = NULL; }
    h->pair_version = c->pair_version;
    h->nv = c->nv;
    h->agg_levels = nlev - 1;
    h->numeric_builds = aggregate_again ? 0 : h->numeric_builds + 1;
    h->refreshes = 0;
    if (aggregate_again) {
        fixed_signature(c, &h->fixed_n, &h->fixed_sum);
        h->fragment_vertices = c->stats.fragment_vertices_removed;
        h->forget = false;
    }
    rc = 0;
out:
    rowsrc_free(&src);
    tc_mem_free(pass1); tc_mem_free(dead); tc_mem_free(dn); tc_mem_free(B); tc_mem_free(Tv); tc_mem_free(sptr); tc_mem_free(scol);
    if (rc) { h->nlev = 0; h->agg_levels = 0; }
    return rc;
}

int tc_amg_refresh(tc_amg *h, const tc_cloth *c)
{
    if (!tc_amg_valid(h, c)) return -1;
    if (numeric(h, c)) { h->nlev = 0; h->agg_levels = 0; return -1; }
    h->refreshes++;
    return 0;
}

int tc_amg_refreshes(const tc_amg *h) { return h ? h->refreshes : 0; }

/* ---------------- the contact correction of the first coarse operator ---------------- */

/* How far the contacts moved from those the correction was made with: the vertices whose contact
 * direction count differs, or whose first direction turned by more than TC_AMG_CONTACT_TURN;
 * *count gets the contact vertices now. Without a correction (used_cnt NULL) every contact counts. */
static int32_t contact_changes(const tc_amg *h, const tc_cloth *c, int32_t *count)
{
    const int8_t *fl = tc_vec_ptr(&c->vflag), *cnt = tc_vec_ptr(&c->scount);
    const double *N = tc_vec_ptr(&c->snorm);
    const bool have = h->corrected && h->cap_used >= (size_t)c->nv;
    int32_t k = 0, changed = 0;
    for (int32_t i = 0; i < c->nv; i++) {
        const int8_t now = fl[i] == VC_CONTACT ? cnt[i] : 0;
        k += now > 0;
        if (!have) { changed += now > 0; continue; }
        if (now != h->used_cnt[i]) { changed++; continue; }
        if (now == 0) continue;
        const double *e = N + 9 * (size_t)i;
        const float *u = h->used_n + 3 * (size_t)i;
        if (e[0] * u[0] + e[1] * u[1] + e[2] * u[2] < TC_AMG_CONTACT_TURN_COS) changed++;
    }
    *count = k;
    return changed;
}

/* the contacts the correction is made with, for contact_changes */
static int contacts_used(tc_amg *h, const tc_cloth *c)
{
    if ((size_t)c->nv > h->cap_used) {
        int8_t *a = tc_mem_realloc(h->used_cnt, (size_t)c->nv);
        if (a) h->used_cnt = a;
        float *b = a ? tc_mem_realloc(h->used_n, 3 * (size_t)c->nv * sizeof(float)) : NULL;
        if (b) h->used_n = b;
        if (!a || !b) return -1;
        h->cap_used = (size_t)c->nv;
    }
    const int8_t *fl = tc_vec_ptr(&c->vflag), *cnt = tc_vec_ptr(&c->scount);
    const double *N = tc_vec_ptr(&c->snorm);
    for (int32_t i = 0; i < c->nv; i++) {
        h->used_cnt[i] = fl[i] == VC_CONTACT ? cnt[i] : 0;
        for (int q = 0; q < 3; q++) h->used_n[3 * (size_t)i + q] = h->used_cnt[i] ? (float)N[9 * (size_t)i + q] : 0.0f;
    }
    return 0;
}

/* the accumulator of A_1's stored block v in acc2 (zeroed when new), NULL out of memory */
static double *delta_slot(tc_amg *h, int32_t v, int32_t *used)
{
    if (h->slot_of[v] < 0) {
        if (grow((void **)&h->acc2, &h->cap_acc2, ((size_t)*used + 1) * NS * NS, sizeof(double))) return NULL;
        h->slot_of[v] = (*used)++;
        memset(h->acc2 + (size_t)h->slot_of[v] * NS * NS, 0, NS * NS * sizeof(double));
    }
    return h->acc2 + (size_t)h->slot_of[v] * NS * NS;
}

/* Delta = P^T (S A S - A) P, the rows of A that touch a contact vertex, into acc2 (slot_of maps
 * A_1's stored upper blocks to it; *used of them). Row i adds P_iI^T (sum_j B_ij P_j)_J to the
 * upper blocks (J >= I), B_ij = S_i A_ij S_j - A_ij, nonzero only when i or j is a contact, as
 * galerkin_numeric adds P_iI^T (A P)_iJ: the lower blocks are the mirrors, Delta is symmetric. */
static int contact_delta(tc_amg *h, const tc_cloth *c, int32_t *used)
{
    const level *L = &h->lev[0];
    const bsr *P = &L->P, *C = &h->lev[1].A;
    const int8_t *fl = tc_vec_ptr(&c->vflag);
    rowsrc src = {0};  /* only its buffers, sized for the longest fine row: raw_row fills them */
    int32_t *cols = tc_mem_malloc(((size_t)C->n + 1) * sizeof(int32_t));
    aprow w = {h->mark, cols, NULL, 0};
    int rcode = -1;
    if (!cols || scratch(h, C->n, 0) || rowsrc_init(&src, c, L, 0, false)) goto out;
    for (int32_t i = 0; i < c->nv; i++) {
        if (P->ptr[i] == P->ptr[i + 1]) continue;  /* P_i = 0 (a pin, a handle): nothing to add */
        const int32_t len = raw_row(c, i, src.col, NULL);
        bool touch = false;
        size_t reach = 0;
        for (int32_t k = 0; k < len; k++) {
            const int32_t j = src.col[k];
            touch |= fl[j] == VC_CONTACT;  /* col[0] is i itself */
            reach += (size_t)(P->ptr[j + 1] - P->ptr[j]);
        }
        if (!touch) continue;
        raw_row(c, i, src.col, src.val);
        if (grow((void **)&h->acc, &h->cap_acc, reach * 3 * NS + 1, sizeof(double))) goto out;
        w.acc = h->acc;
        double Si[9];
        filter_matrix(c, i, Si, false);
        for (int32_t k = 0; k < len; k++) {
            const int32_t j = src.col[k];
            const double *a = src.val + 9 * (size_t)k;
            if (fl[i] != VC_CONTACT && fl[j] != VC_CONTACT) continue;
            if (P->ptr[j] == P->ptr[j + 1]) continue;
            double Sj[9], u[9] = {0}, b[9] = {0};
            filter_matrix(c, j, Sj, false);
            gemm_acc(u, Si, a, 3, 3, 3);
            gemm_acc(b, u, Sj, 3, 3, 3);
            for (int q = 0; q < 9; q++) b[q] -= a[q];
            if (k == 0) {  /* tau (I - S) d: see TC_AMG_CONTACT_OFF_RANGE */
                const double sc = TC_AMG_CONTACT_OFF_RANGE * off_range_scale(a);
                for (int q = 0; q < 9; q++) b[q] += sc * ((q % 4 == 0 ? 1.0 : 0.0) - Si[q]);
            }
            /* blk3 reads its block column by column: b's transpose in row-major order */
            double bt[9];
            for (int r = 0; r < 3; r++)
                for (int q = 0; q < 3; q++) bt[3 * q + r] = b[3 * r + q];
            for (int32_t q = P->ptr[j]; q < P->ptr[j + 1]; q++)
                blk3(ap_slot(&w, P->col[q], 3), bt, 3, P->val + (size_t)q * 3 * NS);
        }
        for (int32_t q = P->ptr[i]; q < P->ptr[i + 1]; q++) {
            const int32_t I = P->col[q];
            double pb[3 * NS];
            for (int k = 0; k < 3 * NS; k++) pb[k] = P->val[(size_t)q * 3 * NS + k];
            for (int32_t a = C->ptr[I]; a < C->ptr[I + 1]; a++) {
                const int32_t J = C->col[a];
                const int32_t m = J >= I ? w.mark[J] : -1;
                if (m < 0) continue;
                double *o = delta_slot(h, C->vix[a], used);
                if (!o) goto out;
                pta3(o, pb, w.acc + (size_t)m * 3 * NS);
            }
        }
        for (int32_t q = 0; q < w.m; q++) w.mark[w.cols[q]] = -1;
        w.m = 0;
    }
    rcode = 0;
out:
    for (int32_t q = 0; q < w.m; q++) w.mark[w.cols[q]] = -1;
    rowsrc_free(&src);
    tc_mem_free(cols);
    return rcode;
}

/* the levels below the first again, from A_1 as it is now */
static int coarse_again(tc_amg *h, const tc_cloth *c)
{
    if (coarse_diagonal(&h->lev[1])) return -1;
    for (int l = 1; l + 1 < h->nlev; l++)
        if (galerkin_numeric(h, c, l) || coarse_diagonal(&h->lev[l + 1])) return -1;
    return coarsest_factor(h);
}

/* A_1 = base + Delta for the current contacts (the base saved first when it is not yet; the
 * diagonal inverses of level 1 made again; the coarser levels are the caller's): 0, or -1 with A_1
 * back to the base (out of memory). */
static int correct_first(tc_amg *h, const tc_cloth *c)
{
    bsr *C = &h->lev[1].A;
    const size_t nup = (size_t)upper_slots(C, 0, C->n), nval = nup * NS * NS;
    if (!h->base1_saved) {
        if (grow((void **)&h->base1, &h->cap_base1, nval + 1, sizeof(float))) return -1;
        memcpy(h->base1, C->val, nval * sizeof(float));
        h->base1_saved = true;
    }
    h->corrected = false;
    memcpy(C->val, h->base1, nval * sizeof(float));
    int32_t used = 0;
    int rc = grow((void **)&h->slot_of, &h->cap_slot_of, nup + 1, sizeof(int32_t));
    if (rc == 0) {
        for (size_t v = 0; v < nup; v++) h->slot_of[v] = -1;
        rc = contact_delta(h, c, &used);
    }
    if (rc == 0) {
        /* A_1 = base + Delta in double, narrowed once; a diagonal block made exactly symmetric as
           galerkin_numeric makes it */
        for (int32_t I = 0; I < C->n; I++)
            for (int32_t a = C->ptr[I]; a < C->ptr[I + 1]; a++) {
                if (C->col[a] < I || h->slot_of[C->vix[a]] < 0) continue;
                const double *d = h->acc2 + (size_t)h->slot_of[C->vix[a]] * NS * NS;
                float *f = C->val + (size_t)C->vix[a] * NS * NS;
                double u[NS * NS];
                for (int k = 0; k < NS * NS; k++) u[k] = (double)f[k] + d[k];
                if (C->col[a] == I)
                    for (int r = 0; r < NS; r++)
                        for (int q = r + 1; q < NS; q++) u[r * NS + q] = u[q * NS + r] = 0.5 * (u[r * NS + q] + u[q * NS + r]);
                for (int k = 0; k < NS * NS; k++) f[k] = (float)u[k];
            }
        rc = contacts_used(h, c);
    }
    if (rc) memcpy(C->val, h->base1, nval * sizeof(float));
    else h->corrected = true;
    if (coarse_diagonal(&h->lev[1])) return -1;
    return rc ? -1 : 0;
}

int tc_amg_contacts(tc_amg *h, const tc_cloth *c)
{
    if (!h || h->nlev < 2) return 0;
    int32_t count;
    const int32_t changed = contact_changes(h, c, &count);
    if (count == 0) {
        if (!h->corrected) return 0;
        /* the contacts are gone: A_1 as it was made */
        bsr *C = &h->lev[1].A;
        memcpy(C->val, h->base1, (size_t)upper_slots(C, 0, C->n) * NS * NS * sizeof(float));
        h->corrected = false;
        if (coarse_again(h, c)) { h->nlev = 0; h->agg_levels = 0; return -1; }
        return 0;
    }
    /* made at every refresh (numeric, before the coarser levels) and here when there is none yet (a
       build, the first contacts); between refreshes only when the contact set was replaced: a
       correction for a nearby set still serves (any symmetric positive A_1 does, only the cycle's
       strength is at stake), as the coarse operators of an older matrix do (constants.h) */
    if (!h->follow || (h->corrected && changed <= TC_AMG_CONTACT_CHANGE * count)) return 0;
    const int rc = correct_first(h, c);
    if (coarse_again(h, c)) { h->nlev = 0; h->agg_levels = 0; return -1; }  /* no hierarchy: block Jacobi */
    return rc;
}


void tc_amg_follow_contacts(tc_amg *h, bool on)
{
    if (h) h->follow = on;
}

void tc_amg_set_run_blocks(tc_amg *h, int32_t blocks)
{
    if (h) h->run_blocks = blocks > 0 ? blocks : 0;
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
    if (l == h->nlev - 1) {
        level_sweep(L, b, x, true, NULL);
        /* no factor (a level too big for one, or one coarsening stalled on): more symmetric
           sweeps, still a symmetric positive operator */
        level_sweep(L, b, x, false, NULL);
        for (int s = 1; s < TC_AMG_COARSE_SWEEPS; s++) {
            level_sweep(L, b, x, true, NULL);
            level_sweep(L, b, x, false, NULL);
        }
        return;
    }
    memset(r, 0, nb * sizeof(double));
    level_sweep(L, b, x, true, r);  /* and its residual b - A x in r */
    level *N = &h->lev[l + 1];
    bsr_apply_transposed(&L->P, r, N->rhs);
    vcycle(c, h, l + 1, N->rhs, N->x);
    bsr_apply(&L->P, N->x, x, true);
    level_sweep(L, b, x, false, NULL);
}

/* y = (S_i A_ii S_i + (I - S_i) d_i)^-1 S_i s for a constrained vertex i (pins and handles: 0): the
 * filtered system's diagonal block maps the range of S_i onto itself, so y stays on it. */
static void constrained_block_solve(const tc_cloth *c, int32_t i, const double *s, double *y)
{
    const int8_t f = ((const int8_t *)tc_vec_ptr(&c->vflag))[i];
    if (f != VC_CONTACT) { y[0] = y[1] = y[2] = 0.0; return; }
    double S[9], A[9], t[9] = {0}, M[9] = {0};
    filter_matrix(c, i, S, false);
    from_columns((const double *)tc_vec_ptr(&c->diag) + 12 * (size_t)i, 4, A);
    for (int r = 0; r < 3; r++)
        for (int q = r + 1; q < 3; q++) A[3 * r + q] = A[3 * q + r] = 0.5 * (A[3 * r + q] + A[3 * q + r]);
    gemm_acc(t, S, A, 3, 3, 3);
    gemm_acc(M, t, S, 3, 3, 3);
    const double d = off_range_scale(A);
    for (int k = 0; k < 9; k++) M[k] += d * ((k % 4 == 0 ? 1.0 : 0.0) - S[k]);
    double Ss[3];
    for (int r = 0; r < 3; r++) Ss[r] = S[3 * r] * s[0] + S[3 * r + 1] * s[1] + S[3 * r + 2] * s[2];
    const double c00 = M[4] * M[8] - M[5] * M[7], c01 = M[5] * M[6] - M[3] * M[8], c02 = M[3] * M[7] - M[4] * M[6];
    const double det = M[0] * c00 + M[1] * c01 + M[2] * c02;
    if (!(fabs(det) > TC_SINGULAR_DET)) { y[0] = y[1] = y[2] = 0.0; return; }
    const double id = 1.0 / det;
    const double inv[9] = {c00 * id, (M[2] * M[7] - M[1] * M[8]) * id, (M[1] * M[5] - M[2] * M[4]) * id,
                           c01 * id, (M[0] * M[8] - M[2] * M[6]) * id, (M[2] * M[3] - M[0] * M[5]) * id,
                           c02 * id, (M[1] * M[6] - M[0] * M[7]) * id, (M[0] * M[4] - M[1] * M[3]) * id};
    for (int r = 0; r < 3; r++) y[r] = inv[3 * r] * Ss[0] + inv[3 * r + 1] * Ss[1] + inv[3 * r + 2] * Ss[2];
    filter_vertex(f, ((const int8_t *)tc_vec_ptr(&c->scount))[i], (const double *)tc_vec_ptr(&c->snorm) + 9 * (size_t)i, y);
}

/* The first sweep's residual res = b - A x, made as the sweep goes (res zero before it), so it costs
 * no pass over the matrix of its own (at 100K triangles the rows are 29 MB, streamed from memory by
 * every pass; the separate residual product was a sixth of a cycle). A forward sweep from x = 0
 * reads x_j = 0 for j > i, so when row i is done it knows b_i - sum_{j<i} A_ij x_j (its r before the
 * update t = x_i): its own part of res_i is that minus A_ii x_i. The rest, -sum_{j>i} A_ij x_j, comes
 * from the later rows: row i subtracts A_ji x_i = A_ij^T x_i from res_j for each lower neighbour
 * j < i, its block read (from L1) just after x_i is made (an edge block is A_ij column by column, so
 * (A_ij^T x_i)_q is column q . x_i; a flap is a multiple of I). A neighbour that is not lower adds a
 * zero (a mask, not a branch: a row's columns come in pair order). Nothing assumes the block solve
 * exact: res is b - A x of the x made, whatever the row did; the filter is applied afterwards
 * (fine_residual_filter). */
static inline void first_residual(const rows_view *m, int32_t i, const double r[3], const double *xi, double *restrict res)
{
    const double *d = m->D + 12 * (size_t)i;
    double *oi = res + 3 * (size_t)i;
    for (int q = 0; q < 3; q++) oi[q] += r[q] - (d[q] * xi[0] + d[4 + q] * xi[1] + d[8 + q] * xi[2]);
    for (int32_t s = m->rp[i]; s < m->rp[i + 1]; s++) {
        const int32_t j = m->rc[s];
        const double *bl = m->RB + 9 * (size_t)s, w = j < i ? 1.0 : 0.0;
        double *o = res + 3 * (size_t)j;
        o[0] -= w * (bl[0] * xi[0] + bl[1] * xi[1] + bl[2] * xi[2]);
        o[1] -= w * (bl[3] * xi[0] + bl[4] * xi[1] + bl[5] * xi[2]);
        o[2] -= w * (bl[6] * xi[0] + bl[7] * xi[1] + bl[8] * xi[2]);
    }
    for (int32_t s = m->fp[i]; s < m->fp[i + 1]; s++) {
        const int32_t j = m->fc[s];
        const double f = j < i ? m->FV[s] : 0.0;
        double *o = res + 3 * (size_t)j;
        o[0] -= f * xi[0]; o[1] -= f * xi[1]; o[2] -= f * xi[2];
    }
}

/* One block Gauss-Seidel sweep of the finest level on the filtered system A' (fem.c's rows, read in
 * place, matvec.h's view): x_i += A'_ii^-1 S_i (b_i - (A x)_i), rows in order (forward) or
 * reversed, each with the newest x (x on the range of S, so S_i (A x)_i is row i of A' x).
 * Gauss-Seidel converges on any SPD matrix, so it needs no damping estimate (a damped Jacobi
 * step's went stale whenever the filter or the matrix changed), and the symmetric pair (forward
 * before the coarse correction, backward after) keeps the cycle a symmetric positive operator
 * whatever its coarse operator: the filter, contacts included, is handled exactly here.
 * Returns b . x, accumulated as each x_i is final (a sweep visits each row once). */
static inline double gs_row(const rows_view *m, const tc_cloth *c, const double *Pv, const int8_t *fl, int32_t i,
                            const double *restrict b, double *restrict x, double *restrict res)
{
    const double *d = m->D + 12 * (size_t)i, *xi = x + 3 * (size_t)i, *bi = b + 3 * (size_t)i;
    double y0 = d[0] * xi[0] + d[4] * xi[1] + d[8] * xi[2];
    double y1 = d[1] * xi[0] + d[5] * xi[1] + d[9] * xi[2];
    double y2 = d[2] * xi[0] + d[6] * xi[1] + d[10] * xi[2];
    for (int32_t s = m->rp[i]; s < m->rp[i + 1]; s++) {
        const double *bl = m->RB + 9 * (size_t)s, *xj = x + 3 * (size_t)m->rc[s];
        y0 += bl[0] * xj[0] + bl[3] * xj[1] + bl[6] * xj[2];
        y1 += bl[1] * xj[0] + bl[4] * xj[1] + bl[7] * xj[2];
        y2 += bl[2] * xj[0] + bl[5] * xj[1] + bl[8] * xj[2];
    }
    for (int32_t s = m->fp[i]; s < m->fp[i + 1]; s++) {
        const double f = m->FV[s], *xj = x + 3 * (size_t)m->fc[s];
        y0 += f * xj[0]; y1 += f * xj[1]; y2 += f * xj[2];
    }
    const double r[3] = {bi[0] - y0, bi[1] - y1, bi[2] - y2};
    double t[3];
    if (fl[i] == VC_FREE) {
        const double *p = Pv + 9 * (size_t)i;
        t[0] = p[0] * r[0] + p[1] * r[1] + p[2] * r[2];
        t[1] = p[3] * r[0] + p[4] * r[1] + p[5] * r[2];
        t[2] = p[6] * r[0] + p[7] * r[1] + p[8] * r[2];
    } else {
        constrained_block_solve(c, i, r, t);
    }
    double *o = x + 3 * (size_t)i;
    o[0] += t[0]; o[1] += t[1]; o[2] += t[2];
    if (res) first_residual(m, i, r, o, res);
    return bi[0] * o[0] + bi[1] * o[1] + bi[2] * o[2];
}

static rows_view fine_rows(const tc_cloth *c)
{
    const rows_view m = {tc_vec_ptr(&c->diag), tc_vec_ptr(&c->rblk), tc_vec_ptr(&c->fval), tc_vec_ptr(&c->rptr),
                         tc_vec_ptr(&c->rcol), tc_vec_ptr(&c->fptr), tc_vec_ptr(&c->fcol), c->nv};
    return m;
}

static double fine_gs_c(const tc_cloth *c, const double *restrict b, double *restrict x, bool forward, double *restrict res)
{
    const rows_view m = fine_rows(c);
    const double *Pv = tc_vec_ptr(&c->pinv);
    const int8_t *fl = tc_vec_ptr(&c->vflag);
    double d0 = 0.0, d1 = 0.0;
    for (int32_t k = 0; k < m.nv; k++) {
        const double dd = gs_row(&m, c, Pv, fl, forward ? k : m.nv - 1 - k, b, x, res);
        if (k & 1) d1 += dd; else d0 += dd;
    }
    return d0 + d1;
}

#ifdef TC_AMG_AVX2
/* The sweep with AVX2 + FMA, as fem.c's product reads the rows: a block column is one 4-lane load
 * (its fourth lane, the next column's first value, is never used), six accumulators (the FMA
 * chains, not the bytes, bound a row). x_i is updated by one 4-lane load-add-store whose fourth
 * lane (the next vertex's first value) is written back unchanged, so the next rows' 4-lane loads
 * of it are forwarded from one store. The last vertex (whose 4-lane loads would pass the arrays)
 * and the constrained ones take the scalar row. */
__attribute__((target("avx2,fma"))) static double fine_gs_avx2(const tc_cloth *c, const double *restrict b,
                                                               double *restrict x, bool forward, double *restrict res)
{
    const rows_view m = fine_rows(c);
    const double *restrict D = m.D, *restrict RB = m.RB, *restrict FV = m.FV;
    const int32_t *restrict rp = m.rp, *restrict rc = m.rc, *restrict fp = m.fp, *restrict fc = m.fc;
    const double *Pv = tc_vec_ptr(&c->pinv);
    const int8_t *fl = tc_vec_ptr(&c->vflag);
    const __m256i m3 = _mm256_set_epi64x(0, -1, -1, -1);
    const __m256d keep = _mm256_castsi256_pd(m3);
    const int32_t last = m.nv - 1;
    __m256d dot0 = _mm256_setzero_pd(), dot1 = _mm256_setzero_pd();
    double dsc = 0.0;
    for (int32_t k = 0; k < m.nv; k++) {
        const int32_t i = forward ? k : last - k;
        if (fl[i] == VC_PINNED || fl[i] == VC_HANDLE) continue;  /* held: see fine_first_avx2 */
        if (i == last || fl[i] != VC_FREE) { dsc += gs_row(&m, c, Pv, fl, i, b, x, res); continue; }
        double *xi = x + 3 * (size_t)i;
        const double *d = D + 12 * (size_t)i;
        __m256d a0 = _mm256_mul_pd(_mm256_loadu_pd(d), _mm256_broadcast_sd(xi));
        __m256d a1 = _mm256_mul_pd(_mm256_loadu_pd(d + 4), _mm256_broadcast_sd(xi + 1));
        __m256d a2 = _mm256_mul_pd(_mm256_loadu_pd(d + 8), _mm256_broadcast_sd(xi + 2));
        __m256d a3 = _mm256_setzero_pd(), a4 = _mm256_setzero_pd(), a5 = _mm256_setzero_pd();
        int32_t s = rp[i];
        const int32_t e = rp[i + 1];
        for (; s + 1 < e; s += 2) {
            const double *bl = RB + 9 * (size_t)s, *xj = x + 3 * (size_t)rc[s], *xk = x + 3 * (size_t)rc[s + 1];
            a0 = _mm256_fmadd_pd(_mm256_loadu_pd(bl), _mm256_broadcast_sd(xj), a0);
            a1 = _mm256_fmadd_pd(_mm256_loadu_pd(bl + 3), _mm256_broadcast_sd(xj + 1), a1);
            a2 = _mm256_fmadd_pd(_mm256_loadu_pd(bl + 6), _mm256_broadcast_sd(xj + 2), a2);
            a3 = _mm256_fmadd_pd(_mm256_loadu_pd(bl + 9), _mm256_broadcast_sd(xk), a3);
            a4 = _mm256_fmadd_pd(_mm256_loadu_pd(bl + 12), _mm256_broadcast_sd(xk + 1), a4);
            a5 = _mm256_fmadd_pd(_mm256_loadu_pd(bl + 15), _mm256_broadcast_sd(xk + 2), a5);
        }
        if (s < e) {
            const double *bl = RB + 9 * (size_t)s, *xj = x + 3 * (size_t)rc[s];
            a0 = _mm256_fmadd_pd(_mm256_loadu_pd(bl), _mm256_broadcast_sd(xj), a0);
            a1 = _mm256_fmadd_pd(_mm256_loadu_pd(bl + 3), _mm256_broadcast_sd(xj + 1), a1);
            a2 = _mm256_fmadd_pd(_mm256_loadu_pd(bl + 6), _mm256_broadcast_sd(xj + 2), a2);
        }
        int32_t f = fp[i];
        const int32_t fe = fp[i + 1];
        for (; f + 2 < fe; f += 3) {
            const int32_t j0 = fc[f], j1 = fc[f + 1], j2 = fc[f + 2];
            a3 = _mm256_fmadd_pd(_mm256_broadcast_sd(FV + f), j0 < last ? _mm256_loadu_pd(x + 3 * (size_t)j0) : _mm256_maskload_pd(x + 3 * (size_t)j0, m3), a3);
            a4 = _mm256_fmadd_pd(_mm256_broadcast_sd(FV + f + 1), j1 < last ? _mm256_loadu_pd(x + 3 * (size_t)j1) : _mm256_maskload_pd(x + 3 * (size_t)j1, m3), a4);
            a5 = _mm256_fmadd_pd(_mm256_broadcast_sd(FV + f + 2), j2 < last ? _mm256_loadu_pd(x + 3 * (size_t)j2) : _mm256_maskload_pd(x + 3 * (size_t)j2, m3), a5);
        }
        for (; f < fe; f++) {
            const int32_t j = fc[f];
            a0 = _mm256_fmadd_pd(_mm256_broadcast_sd(FV + f), j < last ? _mm256_loadu_pd(x + 3 * (size_t)j) : _mm256_maskload_pd(x + 3 * (size_t)j, m3), a0);
        }
        const __m256d y = _mm256_add_pd(_mm256_add_pd(_mm256_add_pd(a0, a1), _mm256_add_pd(a2, a3)), _mm256_add_pd(a4, a5));
        const __m256d bi = _mm256_loadu_pd(b + 3 * (size_t)i);  /* i < last: within the array */
        const __m256d r = _mm256_sub_pd(bi, y);
        const double *p = Pv + 9 * (size_t)i;  /* symmetric: its rows are its columns; i < last */
        __m256d t = _mm256_mul_pd(_mm256_loadu_pd(p), _mm256_permute4x64_pd(r, 0x00));
        t = _mm256_fmadd_pd(_mm256_loadu_pd(p + 3), _mm256_permute4x64_pd(r, 0x55), t);
        t = _mm256_fmadd_pd(_mm256_loadu_pd(p + 6), _mm256_permute4x64_pd(r, 0xAA), t);
        const __m256d xn = _mm256_add_pd(_mm256_loadu_pd(xi), _mm256_and_pd(t, keep));
        _mm256_storeu_pd(xi, xn);
        if (res) {
            double rr[4];
            _mm256_storeu_pd(rr, r);
            first_residual(&m, i, rr, xi, res);
        }
        const __m256d bx = _mm256_and_pd(_mm256_mul_pd(bi, xn), keep);
        if (k & 1) dot1 = _mm256_add_pd(dot1, bx); else dot0 = _mm256_add_pd(dot0, bx);
    }
    const __m256d dv = _mm256_add_pd(dot0, dot1);
    const __m128d hh = _mm_add_pd(_mm256_castpd256_pd128(dv), _mm256_extractf128_pd(dv, 1));
    return _mm_cvtsd_f64(_mm_add_sd(hh, _mm_unpackhi_pd(hh, hh))) + dsc;
}
#endif

#ifdef TC_AMG_AVX2
/* The first sweep (forward, from x = 0) with its residual (first_residual), AVX2: only the lower
 * neighbours (j < i) have an x_j to read, and only they take a part of the residual, so the row's
 * slots are walked once for the sum over the lower ones and once for the scatter into them; the
 * upper ones (about half) cost a compare. Constrained rows and the last one take the scalar row. */
__attribute__((target("avx2,fma"))) static void fine_first_avx2(const tc_cloth *c, const double *restrict b,
                                                                double *restrict x, double *restrict res)
{
    const rows_view m = fine_rows(c);
    const double *restrict RB = m.RB, *restrict FV = m.FV;
    const int32_t *restrict rp = m.rp, *restrict rc = m.rc, *restrict fp = m.fp, *restrict fc = m.fc;
    const double *Pv = tc_vec_ptr(&c->pinv);
    const int8_t *fl = tc_vec_ptr(&c->vflag);
    const __m256d keep = _mm256_castsi256_pd(_mm256_set_epi64x(0, -1, -1, -1));
    const int32_t last = m.nv - 1;
    for (int32_t i = 0; i < m.nv; i++) {
        /* A held row (pin, handle) is skipped, here and in fine_gs_avx2: its x_i is 0 and stays 0
           (the cycle starts from zero and S P filters the coarse correction), so it changes no
           x, adds A_ji x_i = 0 to no residual and b_i x_i = 0 to no dot, and its own residual is
           zeroed by fine_residual_filter. The scalar row would read its whole row for nothing and
           store x_i by three scalar stores that the next rows' 4-lane loads cannot be forwarded
           from. Table I's banknote holds 342 of its 1017 vertices by its two handles. */
        if (fl[i] == VC_PINNED || fl[i] == VC_HANDLE) continue;
        if (i == last || fl[i] != VC_FREE) { gs_row(&m, c, Pv, fl, i, b, x, res); continue; }
        __m256d a0 = _mm256_setzero_pd(), a1 = _mm256_setzero_pd(), a2 = _mm256_setzero_pd(), a3 = _mm256_setzero_pd();
        for (int32_t s = rp[i]; s < rp[i + 1]; s++) {
            const int32_t j = rc[s];
            if (j > i) continue;
            const double *bl = RB + 9 * (size_t)s, *xj = x + 3 * (size_t)j;
            a0 = _mm256_fmadd_pd(_mm256_loadu_pd(bl), _mm256_broadcast_sd(xj), a0);
            a1 = _mm256_fmadd_pd(_mm256_loadu_pd(bl + 3), _mm256_broadcast_sd(xj + 1), a1);
            a2 = _mm256_fmadd_pd(_mm256_loadu_pd(bl + 6), _mm256_broadcast_sd(xj + 2), a2);
        }
        for (int32_t f = fp[i]; f < fp[i + 1]; f++) {
            const int32_t j = fc[f];
            if (j > i) continue;
            a3 = _mm256_fmadd_pd(_mm256_broadcast_sd(FV + f), _mm256_loadu_pd(x + 3 * (size_t)j), a3);  /* j < last */
        }
        const __m256d y = _mm256_add_pd(_mm256_add_pd(a0, a1), _mm256_add_pd(a2, a3));
        const __m256d r = _mm256_sub_pd(_mm256_loadu_pd(b + 3 * (size_t)i), y);  /* i < last */
        const double *p = Pv + 9 * (size_t)i;
        __m256d t = _mm256_mul_pd(_mm256_loadu_pd(p), _mm256_permute4x64_pd(r, 0x00));
        t = _mm256_fmadd_pd(_mm256_loadu_pd(p + 3), _mm256_permute4x64_pd(r, 0x55), t);
        t = _mm256_fmadd_pd(_mm256_loadu_pd(p + 6), _mm256_permute4x64_pd(r, 0xAA), t);
        t = _mm256_and_pd(t, keep);
        double *xi = x + 3 * (size_t)i;
        _mm256_storeu_pd(xi, t);  /* x_i was 0; its fourth lane is x_{i+1}'s first, still 0 */
        /* res_i's own part r - A_ii x_i (its fourth lane, res_{i+1}'s first, gets 0) */
        const double *d = m.D + 12 * (size_t)i;
        __m256d ad = _mm256_mul_pd(_mm256_loadu_pd(d), _mm256_permute4x64_pd(t, 0x00));
        ad = _mm256_fmadd_pd(_mm256_loadu_pd(d + 4), _mm256_permute4x64_pd(t, 0x55), ad);
        ad = _mm256_fmadd_pd(_mm256_loadu_pd(d + 8), _mm256_permute4x64_pd(t, 0xAA), ad);
        double *oi = res + 3 * (size_t)i;
        _mm256_storeu_pd(oi, _mm256_add_pd(_mm256_loadu_pd(oi), _mm256_and_pd(_mm256_sub_pd(r, ad), keep)));
        const double x0 = xi[0], x1 = xi[1], x2 = xi[2];
        for (int32_t s = rp[i]; s < rp[i + 1]; s++) {
            const int32_t j = rc[s];
            if (j > i) continue;
            const double *bl = RB + 9 * (size_t)s;
            double *o = res + 3 * (size_t)j;
            o[0] -= bl[0] * x0 + bl[1] * x1 + bl[2] * x2;
            o[1] -= bl[3] * x0 + bl[4] * x1 + bl[5] * x2;
            o[2] -= bl[6] * x0 + bl[7] * x1 + bl[8] * x2;
        }
        for (int32_t f = fp[i]; f < fp[i + 1]; f++) {
            const int32_t j = fc[f];
            if (j > i) continue;
            double *o = res + 3 * (size_t)j;
            o[0] -= FV[f] * x0; o[1] -= FV[f] * x1; o[2] -= FV[f] * x2;
        }
    }
}
#endif

/* a sweep; res non-NULL (zeroed): a forward sweep from x = 0 that leaves b - A x there (first_residual) */
static double fine_gs(const tc_cloth *c, const double *restrict b, double *restrict x, bool forward, double *restrict res)
{
#ifdef TC_AMG_AVX2
    if (avx2() && res) { fine_first_avx2(c, b, x, res); return 0.0; }
    if (avx2()) return fine_gs_avx2(c, b, x, forward, res);
#endif
    return fine_gs_c(c, b, x, forward, res);
}

/* the first sweep's residual filtered: S_i res_i on the rows that are not free */
static void fine_residual_filter(const tc_cloth *c, double *restrict y)
{
    const int8_t *fl = tc_vec_ptr(&c->vflag), *cnt = tc_vec_ptr(&c->scount);
    const double *N = tc_vec_ptr(&c->snorm);
    for (int32_t i = 0; i < c->nv; i++)
        if (fl[i] != VC_FREE) filter_vertex(fl[i], cnt[i], N + 9 * (size_t)i, y + 3 * (size_t)i);
}

/* For the tests: the largest relative error of u . A_1 v against (P u) . A (P v) by the solver's
 * product (unfiltered: P is zero on pins and handles, and the coarse operators leave contacts to
 * the fine sweeps), over a few pseudo-random coarse u, v (the Galerkin product made from the rows,
 * stored in float32, must be that triple product), and of u . A_1 v against v . A_1 u (its
 * symmetry). -1 without a level 1. */
double tc_amg_galerkin_error(const tc_cloth *c, tc_amg *h)
{
    if (!h || h->nlev < 2) return -1.0;
    level *L = &h->lev[0], *N = &h->lev[1];
    const size_t nf = (size_t)L->n * 3, nc = (size_t)N->n * NS;
    double *u = tc_mem_malloc(nc * sizeof(double)), *v = tc_mem_malloc(nc * sizeof(double)), *w = tc_mem_malloc(nc * sizeof(double));
    double *pu = tc_mem_malloc(nf * sizeof(double)), *pv = tc_mem_malloc(nf * sizeof(double)), *apv = tc_mem_malloc(nf * sizeof(double));
    double worst = -1.0;
    if (u && v && w && pu && pv && apv) {
        worst = 0.0;
        for (int trial = 0; trial < 3; trial++) {
            for (size_t k = 0; k < nc; k++) {
                u[k] = sin(0.37 * (double)k + trial);
                v[k] = cos(1.13 * (double)k - 2.0 * trial);
            }
            bsr_apply(&L->P, u, pu, false);
            bsr_apply(&L->P, v, pv, false);
            double fine = 0.0, scale = 0.0;
            if (h->corrected) {
                /* with the contact correction: u^T P^T (S A S + tau (I - S) d) P v */
                double *spv = tc_mem_malloc(nf * sizeof(double));
                if (!spv) { worst = -1.0; break; }
                memcpy(spv, pv, nf * sizeof(double));
                tc_constraint_filter(c, spv);
                tc_matvec(c, spv, apv);
                tc_constraint_filter(c, apv);
                const double *D = tc_vec_ptr(&c->diag);
                for (size_t k = 0; k < nf; k++) {
                    double dk[9];
                    from_columns(D + 12 * (k / 3), 4, dk);
                    apv[k] += TC_AMG_CONTACT_OFF_RANGE * off_range_scale(dk) * (pv[k] - spv[k]);
                }
                tc_mem_free(spv);
            } else {
                tc_matvec(c, pv, apv);
            }
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
    tc_mem_free(u); tc_mem_free(v); tc_mem_free(w); tc_mem_free(pu); tc_mem_free(pv); tc_mem_free(apv);
    return worst;
}

/* For the tests: the largest relative difference between the residual the first sweep leaves
 * (first_residual, its filter; coarse_first_residual on level 1) and b - A x by a product after the
 * sweep, on the finest level and on level 1, for b = r (filtered by the caller) and a pseudo-random
 * coarse b. -1 without a level 1. */
double tc_amg_first_residual_error(const tc_cloth *c, tc_amg *h, const double *r)
{
    if (!h || h->nlev < 2) return -1.0;
    const level *N = &h->lev[1];
    const size_t nf = 3 * (size_t)c->nv, nc = (size_t)N->n * NS;
    double *x = tc_mem_malloc(nf * sizeof(double)), *y = tc_mem_malloc(nf * sizeof(double)), *ax = tc_mem_malloc(nf * sizeof(double));
    double *bc = tc_mem_malloc(nc * sizeof(double)), *xc = tc_mem_malloc(nc * sizeof(double));
    double *yc = tc_mem_malloc(nc * sizeof(double)), *ac = tc_mem_malloc(nc * sizeof(double));
    double worst = -1.0;
    if (x && y && ax && bc && xc && yc && ac) {
        memset(x, 0, nf * sizeof(double));
        memset(y, 0, nf * sizeof(double));
        fine_gs(c, r, x, true, y);
        fine_residual_filter(c, y);
        tc_matvec(c, x, ax);
        tc_constraint_filter(c, ax);
        double scale = 0.0, err = 0.0;
        for (size_t k = 0; k < nf; k++) scale = fmax(scale, fabs(r[k]));
        for (size_t k = 0; k < nf; k++) err = fmax(err, fabs(y[k] - (r[k] - ax[k])));
        worst = err / (scale > 0 ? scale : 1.0);
        if (h->nlev >= 3) {  /* level 1 is swept with a residual only when it is not the coarsest */
            for (size_t k = 0; k < nc; k++) bc[k] = sin(0.29 * (double)k + 0.5);
            memset(xc, 0, nc * sizeof(double));
            memset(yc, 0, nc * sizeof(double));
            level_sweep(N, bc, xc, true, yc);
            bsr_apply(&N->A, xc, ac, false);
            double cerr = 0.0;
            for (size_t k = 0; k < nc; k++) cerr = fmax(cerr, fabs(yc[k] - (bc[k] - ac[k])));
            worst = fmax(worst, cerr);  /* |bc| <= 1 */
        }
    }
    tc_mem_free(x); tc_mem_free(y); tc_mem_free(ax); tc_mem_free(bc); tc_mem_free(xc); tc_mem_free(yc); tc_mem_free(ac);
    return worst;
}

/* z = M^-1 r with M^-1 the V-cycle (r and z on the range of S); returns r . z */
/* z = M^-1 r with M^-1 the V-cycle (r and z on the range of S); returns r . z. A forward Gauss-Seidel
 * sweep from zero, the coarse correction of its residual (prolonged by S P), a backward sweep. */
double tc_amg_apply(const tc_cloth *c, tc_amg *h, const double *r, double *z)
{
    level *L = &h->lev[0], *N = &h->lev[1];
    double *y = tc_vec_ptr(&c->sq);  /* the fine residual in the solver's q (level_vectors) */
    memset(z, 0, 3 * (size_t)c->nv * sizeof(double));
    if (h->nlev < 2) {
        fine_gs(c, r, z, true, NULL);
    } else {
        memset(y, 0, 3 * (size_t)c->nv * sizeof(double));
        fine_gs(c, r, z, true, y);  /* and its residual in y */
        fine_residual_filter(c, y);
        bsr_apply_transposed(&L->P, y, N->rhs);
        vcycle(c, h, 1, N->rhs, N->x);
        bsr_apply(&L->P, N->x, z, true);
        tc_constraint_filter(c, z);
    }
    return fine_gs(c, r, z, false, NULL);
}
