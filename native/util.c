/* util.c - the two services every part of the core uses: a wall clock for the step statistics and
 * the error text behind tc_cloth_error(). Nothing here knows about simulation. */
#include "core.h"

#include <stdarg.h>
#include <stdio.h>
#include <string.h>
#include <time.h>

double tc_now(void)
{
    struct timespec ts;
    timespec_get(&ts, TIME_UTC);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* The message is formatted by the C library (vsnprintf), so %g works here; the Python bindings
 * pass it on as a finished string. */
void tc_set_err(tc_cloth *c, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(c->err, sizeof c->err, fmt, ap);
    va_end(ap);
}

/* Per thread: a create runs on the caller's thread (the bindings release the GIL, not the thread). */
static _Thread_local tc_culprits culprits;

void tc_culprits_clear(void) { memset(&culprits, 0, sizeof culprits); }

void tc_culprit(int32_t triangle, int32_t vertex)
{
    if (triangle >= 0 && culprits.n_triangles < TC_CULPRITS_MAX) culprits.triangles[culprits.n_triangles++] = triangle;
    if (vertex >= 0 && culprits.n_vertices < TC_CULPRITS_MAX) culprits.vertices[culprits.n_vertices++] = vertex;
}

tc_culprits tc_create_culprits(void) { return culprits; }
