/* buf.c - reference-counted blocks and growable arrays (tc_buf, tc_vec).
 *
 * Python readers hold a tc_buf directly, so when tearing grows an array the old block stays alive
 * (and keeps its old size) until the last reader lets go: a stale view shows old data, never freed
 * memory. Counts are atomic because a reader may be released on another thread while a step runs
 * with the GIL released.
 *
 * A block of BUF_MAP_BYTES or more is a mapping of its own (mmap, where there is one), not the C
 * allocator's: its pages come zeroed and untouched (capacity a vector has not used yet costs
 * address space, not resident memory) and go back to the system when it is freed. glibc's
 * allocator raises its own mapping threshold to the size of every mapped block freed (up to
 * 32 MB), after which a cloth's growing arrays, copied from block to block, landed in its heap and
 * left it holes it keeps resident: 40-80 bytes per triangle of a 100K-triangle cloth.
 */
#if !defined(_WIN32) && !defined(_DEFAULT_SOURCE)
#define _DEFAULT_SOURCE /* MAP_ANONYMOUS under -std=c17 */
#endif
#include "core.h"

#include <stdlib.h>
#include <string.h>

#if defined(__unix__) || defined(__APPLE__)
#include <sys/mman.h>
#if !defined(MAP_ANONYMOUS) && defined(MAP_ANON)
#define MAP_ANONYMOUS MAP_ANON
#endif
#ifdef MAP_ANONYMOUS
#define TC_BUF_MAP 1
#endif
#endif

enum { BUF_MAP_BYTES = 1 << 18 };  /* 256 KB: an mmap and its munmap cost microseconds */

static size_t buf_total(size_t bytes) { return sizeof(tc_buf) + (bytes ? bytes : 1); }

/* A block, zeroed when asked (calloc: the allocator then leaves fresh pages untouched, so unused
 * capacity is not resident either; its slack was 16 MB of the 115 MB of a 100K-triangle cloth
 * when it was memset). */
static tc_buf *buf_alloc(size_t bytes, bool zero)
{
    tc_buf *b;
#ifdef TC_BUF_MAP
    if (bytes >= BUF_MAP_BYTES) {
        void *p = mmap(NULL, buf_total(bytes), PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
        b = p == MAP_FAILED ? NULL : p;  /* zero-filled */
    } else
#endif
        b = zero ? calloc(1, buf_total(bytes)) : malloc(buf_total(bytes));
    if (!b) return NULL;
    atomic_init(&b->refs, 1);
    b->bytes = bytes;
    return b;
}

static void buf_free(tc_buf *b)
{
#ifdef TC_BUF_MAP
    if (b->bytes >= BUF_MAP_BYTES) { munmap(b, buf_total(b->bytes)); return; }
#endif
    free(b);
}

static tc_buf *buf_new_zeroed(size_t bytes) { return buf_alloc(bytes, true); }

/* malloc, calloc, realloc and free with the same rule for big blocks, for parts that allocate
 * their own arrays (amg.c: its hierarchy and the transient arrays of its builds). A 16-byte header
 * before the block holds its size, so the free knows how it was made. */
enum { MEM_HEAD = 16 };

static void *mem_alloc(size_t n, bool zero)
{
    const size_t total = n + MEM_HEAD;
    unsigned char *p;
    if (total < n) return NULL;
#ifdef TC_BUF_MAP
    if (n >= BUF_MAP_BYTES) {
        void *m = mmap(NULL, total, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
        p = m == MAP_FAILED ? NULL : m;
    } else
#endif
        p = zero ? calloc(1, total) : malloc(total);
    if (!p) return NULL;
    memcpy(p, &n, sizeof n);
    return p + MEM_HEAD;
}

static size_t mem_size(const void *q)
{
    size_t n;
    memcpy(&n, (const unsigned char *)q - MEM_HEAD, sizeof n);
    return n;
}

void *tc_mem_malloc(size_t n) { return mem_alloc(n, false); }

void *tc_mem_calloc(size_t k, size_t item)
{
    if (item && k > (size_t)-1 / item) return NULL;
    return mem_alloc(k * item, true);
}

void tc_mem_free(void *q)
{
    if (!q) return;
    unsigned char *p = (unsigned char *)q - MEM_HEAD;
#ifdef TC_BUF_MAP
    const size_t n = mem_size(q);
    if (n >= BUF_MAP_BYTES) { munmap(p, n + MEM_HEAD); return; }
#endif
    free(p);
}

void *tc_mem_realloc(void *q, size_t n)
{
    if (!q) return mem_alloc(n, false);
    const size_t old = mem_size(q);
#ifdef TC_BUF_MAP
    if (old >= BUF_MAP_BYTES || n >= BUF_MAP_BYTES) {
        if (old == n) return q;
        void *r = mem_alloc(n, false);
        if (!r) return NULL;
        memcpy(r, q, old < n ? old : n);
        tc_mem_free(q);
        return r;
    }
#endif
    if (n + MEM_HEAD < n) return NULL;
    unsigned char *p = realloc((unsigned char *)q - MEM_HEAD, n + MEM_HEAD);
    if (!p) return NULL;
    memcpy(p, &n, sizeof n);
    return p + MEM_HEAD;
}

tc_buf *tc_buf_new(size_t bytes) { return buf_alloc(bytes, false); }

void *tc_buf_data(tc_buf *b) { return b->data; }
void tc_buf_incref(tc_buf *b) { atomic_fetch_add(&b->refs, 1); }
void tc_buf_decref(tc_buf *b)
{
    if (b && atomic_fetch_sub(&b->refs, 1) == 1) buf_free(b);
}

int tc_vec_init(tc_vec *v, size_t item, size_t cap)
{
    v->buf = NULL; v->len = 0; v->cap = 0; v->item = item;
    return tc_vec_reserve(v, cap ? cap : 1);
}

void tc_vec_free(tc_vec *v)
{
    tc_buf_decref(v->buf);
    v->buf = NULL; v->len = v->cap = 0;
}

int tc_vec_reserve(tc_vec *v, size_t cap)
{
    if (cap <= v->cap && v->buf) return TC_OK;
    size_t ncap = v->cap ? v->cap : 8;
    while (ncap < cap) ncap += ncap / 2 + 8;  /* amortised growth: tearing adds a few items at a time */
    tc_buf *nb = buf_new_zeroed(ncap * v->item);
    if (!nb) return TC_ERR_NOMEM;
    if (v->buf) {
        memcpy(nb->data, v->buf->data, v->len * v->item);
        tc_buf_decref(v->buf);
    }
    v->buf = nb; v->cap = ncap;
    return TC_OK;
}

int tc_vec_resize(tc_vec *v, size_t len)
{
    if (len > v->cap) {
        int e = tc_vec_reserve(v, len);
        if (e) return e;
        /* a fresh block: zero past the items it was given, so no memset that would make the
           pages resident before they are written */
        v->len = len;
        return TC_OK;
    }
    if (len > v->len) memset(v->buf->data + v->len * v->item, 0, (len - v->len) * v->item);
    v->len = len;
    return TC_OK;
}

int tc_vec_push_i32(tc_vec *v, int32_t x)
{
    if (tc_vec_resize(v, v->len + 1)) return TC_ERR_NOMEM;
    ((int32_t *)tc_vec_ptr(v))[v->len - 1] = x;
    return TC_OK;
}

int tc_vec_push_f64(tc_vec *v, double x)
{
    if (tc_vec_resize(v, v->len + 1)) return TC_ERR_NOMEM;
    ((double *)tc_vec_ptr(v))[v->len - 1] = x;
    return TC_OK;
}
