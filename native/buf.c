/* buf.c - reference-counted blocks and growable arrays (tc_buf, tc_vec).
 *
 * Python readers hold a tc_buf directly, so when tearing grows an array the old block stays alive
 * (and keeps its old size) until the last reader lets go: a stale view shows old data, never freed
 * memory. Counts are atomic because a reader may be released on another thread while a step runs
 * with the GIL released.
 */
#include "core.h"

#include <stdlib.h>
#include <string.h>

/* A zeroed block by calloc: the allocator then leaves fresh pages untouched (the kernel zeroes
 * them on first use), so capacity a vector has not used yet costs address space, not resident
 * memory (its slack was 16 MB of the 115 MB of a 100K-triangle cloth when it was memset). */
static tc_buf *buf_new_zeroed(size_t bytes)
{
    tc_buf *b = calloc(1, sizeof(tc_buf) + (bytes ? bytes : 1));
    if (!b) return NULL;
    atomic_init(&b->refs, 1);
    b->bytes = bytes;
    return b;
}

tc_buf *tc_buf_new(size_t bytes)
{
    tc_buf *b = malloc(sizeof(tc_buf) + (bytes ? bytes : 1));
    if (!b) return NULL;
    atomic_init(&b->refs, 1);
    b->bytes = bytes;
    return b;
}

void *tc_buf_data(tc_buf *b) { return b->data; }
void tc_buf_incref(tc_buf *b) { atomic_fetch_add(&b->refs, 1); }
void tc_buf_decref(tc_buf *b)
{
    if (b && atomic_fetch_sub(&b->refs, 1) == 1) free(b);
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
