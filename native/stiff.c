/* stiff.c - stiff groups: vertices coupled to each other far more stiffly than to the rest of the
 * cloth, whose rows of the filtered matrix block Jacobi inverts together.
 *
 * Why: a sliver triangle (smallest angle well under a degree, the long thin triangles of a careless
 * mesher) is stiff across its thin side in proportion to its length over its height, and its
 * corners carry the mass of their fat neighbours only. Its near-coincident corners then form a
 * pair whose relative motion is ~10^5 times stiffer per unit mass than the cloth's (0.23-0.46
 * degrees on a 5-10 mm mesh), while the pair moving as one is as soft as the rest. A
 * preconditioner that inverts each vertex's own 3x3 block (block Jacobi) or sweeps vertex by vertex
 * (Gauss-Seidel) sees both modes at once: its CG needs ~sqrt(10^5) times more iterations. A
 * 756-vertex sheet with such slivers hung by one edge needed ~5600 iterations and three halvings
 * a 2 ms step with the sweeps, and at dt = 10 ms still stopped at the 1000-iteration cap in 103
 * sub-steps of 20 steps after halving. Inverting the pair's 6x6 block (or the 3k x 3k block of a
 * few such vertices) takes the stiff mode out exactly; what is left is the cloth's own
 * conditioning.
 *
 * Which: the strength of an edge's block is |A_ij|_F / sqrt(|A_ii|_F |A_jj|_F): near 1 when its
 * vertices' own stiffness and mass are mostly this one coupling. A mesh has slivers when some
 * block reaches TC_STIFF_SLIVER (0.94) at a thin triangle (a corner under TC_STIFF_SLIVER_DEG, 2
 * degrees, at one of its vertices: a lone obtuse speck a tear set free reaches 0.95 too, and the
 * sweeps need no groups for it); then every pair from TC_STIFF_STRENGTH (0.3) is joined,
 * strongest first, into groups of at most TC_STIFF_GROUP_MAX vertices (a chain of slivers is cut
 * there: a weaker preconditioner, never a wrong one). The bar, measured (the strongest block, the
 * same at dt 1, 2 and 10 ms: a sliver's stiffness dwarfs its corners' masses): the sliver sheet
 * (tearcloth.bench.slivers) 0.993 with 0.23-degree slivers, 0.962 with 1-degree ones, 0.923 with
 * 2 degrees, 0.795 with 5.7; the T-shirt after 50 scripted cuts (Table I's "after 50 cuts")
 * 0.876; the paper's three scenes below 0.7. Where the sweeps cope the groups only cost: the cut
 * T-shirt took 35 CG iterations a step with them against the sweeps' 17 (a bar of 0.85 took them),
 * the 2-degree sheet 90 against 153 in the same time; at 1 degree the groups need 92 against 314
 * (half the time), at 0.23 degrees 110 against ~5600. The joining strength: the sliver sheet's
 * weaker couplings (0.3-0.6) matter too: joining from 0.5 left 660-885 CG iterations a 2 ms step,
 * from 0.3 about 120, from 0.15 or 0.05 hardly fewer for bigger groups. 5.7 degrees forms no group
 * (the sweeps need 72 there). The groups are found again every sub-step from the matrix
 * itself: they depend on the sub-step (dt^2 K against M), on stretch and on tearing. Where the last
 * look found no sliver, the next is TC_STIFF_RESCAN sub-steps later (at once after a tear or a new
 * sub-step length), and taking a snapshot restarts that schedule, as a run resumed from it starts
 * one: the two step alike to the bit.
 *
 * The filter: each group's block is that of S A S + w (I - S) (constraints.c's S: 0 at a pin or
 * handle, I - n n^T per contact normal; w = tr(A_ii) / 3 per vertex: any w > 0 gives the same
 * filtered solve, and the block's own scale keeps the factor accurate where w = 1 kg would sit
 * beside masses of micrograms), symmetric positive definite, factored by Cholesky; it maps
 * the range of S into itself, so applied to a filtered residual it gives a filtered direction, as
 * block Jacobi does. A factor that fails (it cannot with positive masses; round-off) leaves its
 * vertices to their own blocks, counted in tc_stats.stiff_group_failures. */
#include "core.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

struct tc_stiff {
    int32_t nv;          /* the vertex count the arrays are sized for */
    int32_t ng;          /* groups found at this sub-step (0: none, or not built for block Jacobi) */
    int32_t *parent;     /* union-find over the vertices (nv), then each root's group */
    int32_t *size;       /* members per root (nv) */
    double *dnorm;       /* |A_ii|_F per vertex (nv) */
    int32_t *gptr;       /* ng + 1 offsets into gvert */
    int32_t *gvert;      /* the members, group by group */
    double *fac;         /* each group's Cholesky factor L (row-major, (3k)^2), at foff[g] */
    size_t *foff;        /* ng + 1 */
    uint8_t *ok;         /* per group: its factor holds */
    /* strong pairs of this sub-step, strongest first: (strength, i, j) */
    struct pair { double s; int32_t i, j; } *pairs;
    /* the last look for a sliver: the pattern, vertex count and sub-step it was made for, the
       sub-steps since, and what it found (scanned: false until one, or after a snapshot) */
    uint64_t scan_version;
    int32_t scan_nv;
    double scan_dt;
    int scan_age;
    bool scanned, scan_sliver;
    /* the smallest rest angle (rad) of the triangles at each vertex (nv), made when a scan first
       meets a strong block, for the pattern and vertex count it was made for (the sliver test) */
    float *vangle;
    uint64_t angle_version;
    int32_t angle_nv;
    size_t npairs, pair_cap;
    size_t gvert_cap, fac_cap, group_cap;
};

void tc_stiff_free(tc_stiff *g)
{
    if (!g) return;
    free(g->parent); free(g->size); free(g->dnorm); free(g->gptr); free(g->gvert); free(g->fac); free(g->foff);
    free(g->ok); free(g->pairs); free(g->vangle);
    free(g);
}

size_t tc_stiff_bytes(const tc_stiff *g)
{
    if (!g) return 0;
    return sizeof *g + (size_t)g->nv * (2 * sizeof(int32_t) + sizeof(double)) + g->pair_cap * sizeof(struct pair) +
           g->gvert_cap * sizeof(int32_t) + g->fac_cap * sizeof(double) +
           g->group_cap * sizeof(int32_t) + (g->foff ? (g->group_cap + 1) * (sizeof(size_t) + sizeof(uint8_t)) : 0);
}

int32_t tc_stiff_groups(const tc_stiff *g) { return g ? g->ng : 0; }

void tc_stiff_forget(tc_stiff *g)
{
    if (g) g->scanned = false;
}

/* grows *p (an array of `item`-byte items, *cap of them) to hold at least n; -1 when out of memory */
static int reserve(void **p, size_t *cap, size_t n, size_t item)
{
    if (n <= *cap) return 0;
    size_t k = *cap ? *cap : 16;
    while (k < n) k *= 2;
    void *q = realloc(*p, k * item);
    if (!q) return -1;
    *p = q;
    *cap = k;
    return 0;
}

static int32_t find(int32_t *parent, int32_t i)
{
    while (parent[i] != i) {
        parent[i] = parent[parent[i]];  /* path halving */
        i = parent[i];
    }
    return i;
}

static int by_strength(const void *a, const void *b)
{
    const struct pair *p = a, *q = b;
    if (p->s != q->s) return p->s > q->s ? -1 : 1;
    if (p->i != q->i) return p->i < q->i ? -1 : 1;  /* a total order: the same groups on any libc */
    return (p->j > q->j) - (p->j < q->j);
}

static double norm2_block9(const double *b)
{
    double s = 0.0;
    for (int k = 0; k < 9; k++) s += b[k] * b[k];
    return s;
}

/* A_ab of the matrix (row-major 3x3): the diagonal block when a == b, else the edge block of row a
 * at column b plus the flap (a multiple of I) between them; zero when they are not coupled */
static void block_of(const tc_cloth *c, int32_t a, int32_t b, double A[9])
{
    memset(A, 0, 9 * sizeof(double));
    if (a == b) {
        const double *d = (const double *)tc_vec_ptr(&c->diag) + 12 * (size_t)a;  /* columns of 4 */
        for (int r = 0; r < 3; r++)
            for (int q = 0; q < 3; q++) A[3 * r + q] = d[4 * q + r];
        return;
    }
    const int32_t *rp = tc_vec_ptr(&c->rptr), *rc = tc_vec_ptr(&c->rcol), *fp = tc_vec_ptr(&c->fptr),
                  *fc = tc_vec_ptr(&c->fcol);
    const double *RB = tc_vec_ptr(&c->rblk), *FV = tc_vec_ptr(&c->fval);
    for (int32_t s = rp[a]; s < rp[a + 1]; s++)
        if (rc[s] == b) {
            const double *e = RB + 9 * (size_t)s;  /* columns of 3 */
            for (int r = 0; r < 3; r++)
                for (int q = 0; q < 3; q++) A[3 * r + q] += e[3 * q + r];
        }
    for (int32_t s = fp[a]; s < fp[a + 1]; s++)
        if (fc[s] == b) { A[0] += FV[s]; A[4] += FV[s]; A[8] += FV[s]; }
}

static void mul3(const double X[9], const double Y[9], double Z[9])
{
    for (int r = 0; r < 3; r++)
        for (int q = 0; q < 3; q++) Z[3 * r + q] = X[3 * r] * Y[q] + X[3 * r + 1] * Y[3 + q] + X[3 * r + 2] * Y[6 + q];
}

/* The group's block of S A S + (I - S) into L (n x n, row-major) and its Cholesky factor in place
 * (lower triangle); false when a pivot is not positive */
static bool factor_group(const tc_cloth *c, const int32_t *vert, int k, double *L)
{
    const int n = 3 * k;
    double S[TC_STIFF_GROUP_MAX][9];
    for (int a = 0; a < k; a++) tc_constraint_matrix(c, vert[a], S[a]);
    for (int a = 0; a < k; a++)
        for (int b = 0; b <= a; b++) {
            double A[9], T[9], F[9];
            block_of(c, vert[a], vert[b], A);
            if (a == b) {
                tc_filtered_diagonal(S[a], A, F);  /* S_a A S_a + w (I - S_a) */
            } else {
                mul3(S[a], A, T);  /* S_a A S_b (S symmetric) */
                mul3(T, S[b], F);
            }
            for (int r = 0; r < 3; r++)
                for (int q = 0; q < 3; q++) {
                    /* the lower block mirrored: the factor reads the lower triangle only */
                    L[(size_t)(3 * a + r) * n + 3 * b + q] = F[3 * r + q];
                    L[(size_t)(3 * b + q) * n + 3 * a + r] = F[3 * r + q];
                }
        }
    for (int j = 0; j < n; j++) {
        double d = L[(size_t)j * n + j];
        for (int p = 0; p < j; p++) d -= L[(size_t)j * n + p] * L[(size_t)j * n + p];
        if (!(d > 0) || !isfinite(d)) return false;
        const double ljj = sqrt(d);
        L[(size_t)j * n + j] = ljj;
        for (int i = j + 1; i < n; i++) {
            double s = L[(size_t)i * n + j];
            for (int p = 0; p < j; p++) s -= L[(size_t)i * n + p] * L[(size_t)j * n + p];
            L[(size_t)i * n + j] = s / ljj;
        }
    }
    return true;
}

/* Each vertex's smallest rest angle over its triangles (g->vangle), made again only when the
 * pattern or the vertex count changed; -1 when out of memory */
static int vertex_angles(const tc_cloth *c, tc_stiff *g)
{
    const int32_t nv = c->nv;
    if (g->vangle && g->angle_version == c->rows_version && g->angle_nv == nv) return 0;
    float *a = realloc(g->vangle, sizeof(float) * (size_t)(nv > 0 ? nv : 1));
    if (!a) return -1;
    g->vangle = a;
    for (int32_t i = 0; i < nv; i++) a[i] = (float)TC_PI;
    const double *X = tc_vec_ptr(&c->rest);
    const int32_t *T = tc_vec_ptr(&c->tri);
    for (int32_t t = 0; t < c->nt; t++) {
        const int32_t *v = T + 3 * (size_t)t;
        double smallest = TC_PI;
        for (int k = 0; k < 3; k++) {  /* the corner at v[k]: atan2(|e1 x e2|, e1 . e2) */
            const double *o = X + 3 * (size_t)v[k], *p = X + 3 * (size_t)v[(k + 1) % 3], *q = X + 3 * (size_t)v[(k + 2) % 3];
            const double e1[3] = {p[0] - o[0], p[1] - o[1], p[2] - o[2]}, e2[3] = {q[0] - o[0], q[1] - o[1], q[2] - o[2]};
            const double x[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
            const double angle = atan2(sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]), e1[0] * e2[0] + e1[1] * e2[1] + e1[2] * e2[2]);
            if (angle < smallest) smallest = angle;
        }
        for (int k = 0; k < 3; k++)
            if (smallest < a[v[k]]) a[v[k]] = (float)smallest;
    }
    g->angle_version = c->rows_version;
    g->angle_nv = nv;
    return 0;
}

/* The groups of this sub-step's matrix and their factors; 0, or -1 when out of memory (then no
 * group: block Jacobi as it was) */
int tc_stiff_build(tc_cloth *c, double dt)
{
    const int32_t nv = c->nv;
    tc_stiff *g = c->stiff;
    if (!g) {
        c->stiff = g = calloc(1, sizeof *g);
        if (!g) return -1;
    }
    g->ng = 0;
    /* Where the last look found no sliver, the next is TC_STIFF_RESCAN sub-steps later, or at once
       when the pattern (a tear), the vertex count or the sub-step changed: the strengths are ratios
       of Frobenius norms, blind to rotation, so only stretch moves them between (the look costs
       ~40 us a sub-step on the T-shirt, 2 % of its step at dt = 1 ms) */
    if (g->scanned && !g->scan_sliver && g->scan_version == c->rows_version && g->scan_nv == nv && g->scan_dt == dt &&
        g->scan_age < TC_STIFF_RESCAN) {
        g->scan_age++;
        return 0;
    }
    g->scanned = false;
    if (g->nv != nv) {
        free(g->parent); free(g->size); free(g->dnorm);
        g->parent = malloc(sizeof(int32_t) * (size_t)(nv > 0 ? nv : 1));
        g->size = malloc(sizeof(int32_t) * (size_t)(nv > 0 ? nv : 1));
        g->dnorm = malloc(sizeof(double) * (size_t)(nv > 0 ? nv : 1));
        g->nv = g->parent && g->size && g->dnorm ? nv : 0;
        if (!g->nv) return -1;
    }
    const double *D = tc_vec_ptr(&c->diag), *RB = tc_vec_ptr(&c->rblk);
    const int32_t *rp = tc_vec_ptr(&c->rptr), *rc = tc_vec_ptr(&c->rcol);
    for (int32_t i = 0; i < nv; i++) {
        const double *d = D + 12 * (size_t)i;
        double s = 0.0;
        for (int q = 0; q < 3; q++)
            for (int r = 0; r < 3; r++) s += d[4 * q + r] * d[4 * q + r];
        g->dnorm[i] = sqrt(s);
    }
    /* a sliver first (one pass, nothing kept: on a well-shaped mesh that is all this costs), then
       the strong pairs, each edge once (from its lower-numbered row). A sliver is a strong block
       at a thin triangle (a corner under TC_STIFF_SLIVER_DEG at one of its vertices): a strong
       block at a well-shaped triangle - a lone obtuse speck a tear set free, stretched - is one the
       sweeps take out themselves (constants.h: the race's torn shirt, where the groups made its
       sub-steps 3x slower) */
    const char *env = getenv("TEARCLOTH_STIFF_STRENGTH");
    const double strength = env && atof(env) > 0 ? atof(env) : TC_STIFF_STRENGTH;
    const double t2 = strength * strength, sl2 = TC_STIFF_SLIVER * TC_STIFF_SLIVER;
    bool sliver = false;
    for (int32_t i = 0; i < nv && !sliver; i++)
        for (int32_t s = rp[i]; s < rp[i + 1]; s++) {
            const int32_t j = rc[s];
            if (j <= i) continue;
            const double dd = g->dnorm[i] * g->dnorm[j];
            if (!(dd > 0) || !(norm2_block9(RB + 9 * (size_t)s) >= sl2 * dd)) continue;
            if (vertex_angles(c, g)) return -1;
            if (fminf(g->vangle[i], g->vangle[j]) < (float)(TC_STIFF_SLIVER_DEG * TC_PI / 180.0)) { sliver = true; break; }
        }
    g->scanned = true;
    g->scan_sliver = sliver;
    g->scan_version = c->rows_version;
    g->scan_nv = nv;
    g->scan_dt = dt;
    g->scan_age = 0;
    if (!sliver) return 0;
    g->npairs = 0;
    for (int32_t i = 0; i < nv; i++)
        for (int32_t s = rp[i]; s < rp[i + 1]; s++) {
            const int32_t j = rc[s];
            if (j <= i) continue;
            const double a2 = norm2_block9(RB + 9 * (size_t)s), dd = g->dnorm[i] * g->dnorm[j];
            if (!(a2 >= t2 * dd) || !(dd > 0)) continue;
            if (reserve((void **)&g->pairs, &g->pair_cap, g->npairs + 1, sizeof *g->pairs)) return -1;
            g->pairs[g->npairs++] = (struct pair){sqrt(a2 / dd), i, j};
        }
    qsort(g->pairs, g->npairs, sizeof *g->pairs, by_strength);
    for (int32_t i = 0; i < nv; i++) { g->parent[i] = i; g->size[i] = 1; }
    for (size_t p = 0; p < g->npairs; p++) {
        const int32_t a = find(g->parent, g->pairs[p].i), b = find(g->parent, g->pairs[p].j);
        if (a == b || g->size[a] + g->size[b] > TC_STIFF_GROUP_MAX) continue;
        const int32_t lo = a < b ? a : b, hi = a < b ? b : a;  /* the lower index as root: deterministic */
        g->parent[hi] = lo;
        g->size[lo] += g->size[hi];
    }
    /* the groups in the order of their roots, members in vertex order; size[] becomes each root's
       group number (the roots of groups of one are left out) */
    int32_t ng = 0;
    size_t members = 0;
    for (int32_t i = 0; i < nv; i++)
        if (find(g->parent, i) == i && g->size[i] >= 2) { members += (size_t)g->size[i]; ng++; }
    if (reserve((void **)&g->gvert, &g->gvert_cap, members, sizeof(int32_t))) return -1;
    if (reserve((void **)&g->gptr, &g->group_cap, (size_t)ng + 1, sizeof(int32_t))) return -1;
    {   /* foff and ok follow gptr's capacity */
        size_t *fo = realloc(g->foff, (g->group_cap + 1) * sizeof(size_t));
        if (!fo) return -1;
        g->foff = fo;
        uint8_t *ok = realloc(g->ok, (g->group_cap + 1) * sizeof(uint8_t));
        if (!ok) return -1;
        g->ok = ok;
    }
    int32_t at = 0;
    size_t fsize = 0;
    ng = 0;
    for (int32_t i = 0; i < nv; i++)
        if (find(g->parent, i) == i && g->size[i] >= 2) {
            g->gptr[ng] = at;
            g->foff[ng] = fsize;
            at += g->size[i];
            fsize += (size_t)(9 * g->size[i] * g->size[i]);
            g->size[i] = ng++;  /* from here: the root's group */
        } else if (find(g->parent, i) == i) {
            g->size[i] = -1;
        }
    g->gptr[ng] = at;
    g->foff[ng] = fsize;
    /* members in vertex order, through a cursor per group (in dnorm: free once the strengths are
       taken; ng <= nv / 2, and a double holds any slot index exactly) */
    double *cursor = g->dnorm;
    for (int32_t q = 0; q < ng; q++) cursor[q] = g->gptr[q];
    for (int32_t i = 0; i < nv; i++) {
        const int32_t gi = g->size[find(g->parent, i)];
        if (gi < 0) continue;
        g->gvert[(size_t)cursor[gi]] = i;
        cursor[gi] += 1.0;
    }
    if (reserve((void **)&g->fac, &g->fac_cap, fsize, sizeof(double))) return -1;
    g->ng = ng;
    tc_stiff_refactor(c);
    return 0;
}

/* The groups' factors again, under the current constraints (after the contact rounds changed them) */
void tc_stiff_refactor(tc_cloth *c)
{
    tc_stiff *g = c->stiff;
    if (!g) return;
    for (int32_t q = 0; q < g->ng; q++) {
        g->ok[q] = factor_group(c, g->gvert + g->gptr[q], g->gptr[q + 1] - g->gptr[q], g->fac + g->foff[q]);
        if (!g->ok[q]) c->stats.stiff_group_failures++;
    }
}

void tc_stiff_clear(tc_stiff *g)
{
    if (g) g->ng = 0;
}

/* z on the groups' members = (S A S + (I - S))_g^-1 r_g, in place of what block Jacobi wrote there;
 * returns the change of r.z this makes (the CG's rz takes it) */
double tc_stiff_apply(const tc_cloth *c, const double *r, double *z)
{
    const tc_stiff *g = c->stiff;
    if (!g || !g->ng) return 0.0;
    double delta = 0.0;
    for (int32_t q = 0; q < g->ng; q++) {
        if (!g->ok[q]) continue;
        const int32_t *vert = g->gvert + g->gptr[q];
        const int k = g->gptr[q + 1] - g->gptr[q], n = 3 * k;
        const double *L = g->fac + g->foff[q];
        double y[3 * TC_STIFF_GROUP_MAX];
        for (int a = 0; a < k; a++)
            for (int r3 = 0; r3 < 3; r3++) {
                const size_t o = 3 * (size_t)vert[a] + (size_t)r3;
                delta -= r[o] * z[o];
                y[3 * a + r3] = r[o];
            }
        for (int i = 0; i < n; i++) {  /* L y = r */
            double s = y[i];
            for (int p = 0; p < i; p++) s -= L[(size_t)i * n + p] * y[p];
            y[i] = s / L[(size_t)i * n + i];
        }
        for (int i = n - 1; i >= 0; i--) {  /* L^T z = y */
            double s = y[i];
            for (int p = i + 1; p < n; p++) s -= L[(size_t)p * n + i] * y[p];
            y[i] = s / L[(size_t)i * n + i];
        }
        for (int a = 0; a < k; a++)
            for (int r3 = 0; r3 < 3; r3++) {
                const size_t o = 3 * (size_t)vert[a] + (size_t)r3;
                z[o] = y[3 * a + r3];
                delta += r[o] * z[o];
            }
    }
    return delta;
}
