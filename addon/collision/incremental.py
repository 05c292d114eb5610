"""Incremental (walking) ray detection without Embree (Lehericey et al. 2013, "iterative").

This file owns the exact ray/triangle arithmetic of the package and the walk over triangle
adjacency that follows a ray's hit from one step to the next.

Why: a cluster pair whose relative displacement stays under the threshold has moved little since
its last full detection, so the triangle each ray hit then is, or is a few edges away from, the
one it hits now. Re-testing that triangle and stepping across the edge the hit point fell
outside of (the most negative barycentric coordinate) costs a few dozen flops per tracked ray,
independent of the collider size, and needs no acceleration structure (which embreex could not
refit anyway). The detector runs this walk in C (``native/collide/walk.c``, the same arithmetic);
``walk`` here is its numpy specification.

Rays are treated as *lines*: t may be negative. A tracked vertex that crossed the surface it was
tracking still finds the same triangle (behind it), which is exactly what inversion handling and
the inside test need.
"""
from __future__ import annotations

import numpy as np

__all__ = ["triangle_adjacency", "line_triangle", "walk", "WalkResult", "cross"]


def cross(a, b):
    """Row-wise cross product of (k,3) arrays; np.cross spends most of its time in axis
    bookkeeping at the sizes of one step (~1K rows), this does not."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out

_PARALLEL = 1e-14  # |det| below which a line is taken as parallel to a triangle (m^2 scale)
_BARY_EPS = 1e-9  # barycentric slack so that a hit on a shared edge is not bounced back and forth


def triangle_adjacency(triangles):
    """(m,3) neighbour across edge k = (tri[k], tri[k+1]) or -1, and (m,3) bool: True when the
    neighbour lists that edge in the same direction (opposite winding: the side flips)."""
    tri = np.asarray(triangles, np.int64).reshape(-1, 3)
    m = tri.shape[0]
    adj = np.full((m, 3), -1, np.int64)
    flip = np.zeros((m, 3), bool)
    if m == 0:
        return adj, flip
    a = tri.reshape(-1)
    b = tri[:, [1, 2, 0]].reshape(-1)
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    half = np.arange(3 * m)
    order = np.lexsort((half, hi, lo))
    lo_s, hi_s, h_s = lo[order], hi[order], half[order]
    same_next = (lo_s[1:] == lo_s[:-1]) & (hi_s[1:] == hi_s[:-1])
    # Pair consecutive half-edges of the same edge (non-manifold edges: pairs in sorted order).
    i = np.flatnonzero(same_next)
    if i.size:
        # In each run of half-edges on the same edge pair (0,1), (2,3), ...: a manifold edge has
        # one pair; a non-manifold one gets disjoint pairs, which is enough for walking.
        run_start = np.ones(h_s.size, bool)
        run_start[1:] = ~same_next
        run_id = np.cumsum(run_start) - 1
        pos_in_run = np.arange(h_s.size) - np.flatnonzero(run_start)[run_id]
        pairs = i[(pos_in_run[i] % 2) == 0]
        k = np.asarray(pairs, np.int64)
        if k.size:
            h1, h2 = h_s[k], h_s[k + 1]
            adj[h1 // 3, h1 % 3] = h2 // 3
            adj[h2 // 3, h2 % 3] = h1 // 3
            same_dir = a[h1] == a[h2]
            flip[h1 // 3, h1 % 3] = same_dir
            flip[h2 // 3, h2 % 3] = same_dir
    return adj, flip


def line_triangle(o, d, a, b, c):
    """Möller–Trumbore for lines: t (signed, along d), barycentrics u (of b), v (of c), and a mask
    of non-parallel lines. All inputs (k,3) float64."""
    e1 = b - a
    e2 = c - a
    p = cross(d, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > _PARALLEL * np.maximum(np.einsum("ij,ij->i", e1, e1), 1e-30)
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = o - a
    u = np.einsum("ij,ij->i", s, p) * inv
    q = cross(s, e1)
    v = np.einsum("ij,ij->i", d, q) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    return t, u, v, ok


class WalkResult:
    """tri (k,) hit triangle or -1 (lost); t signed distance along the direction; u, v the
    barycentrics of vertices 1 and 2; flips (k,) parity of orientation flips crossed."""

    __slots__ = ("tri", "t", "u", "v", "flips", "steps")

    def __init__(self, k):
        self.tri = np.full(k, -1, np.int64)
        self.t = np.full(k, np.inf)
        self.u = np.zeros(k)
        self.v = np.zeros(k)
        self.flips = np.zeros(k, bool)
        self.steps = 0


def excluded(tri_vertices, exclude):
    """Whether each triangle (k, 3) touches its ray's excluded vertices: exclude is (k,) (the
    vertex itself: its one-ring triangles) or (k, K) (a ring table row: its two-ring)."""
    if exclude.ndim == 1:
        return (tri_vertices == exclude[:, None]).any(axis=1)
    return (tri_vertices[:, :, None] == exclude[:, None, :]).any(axis=(1, 2))


def barycentric(p, a, b, c):
    """Barycentric weights (k, 3) of points p in triangles (a, b, c), least squares in the plane."""
    e1, e2, ep = b - a, c - a, p - a
    d11 = np.einsum("ij,ij->i", e1, e1)
    d12 = np.einsum("ij,ij->i", e1, e2)
    d22 = np.einsum("ij,ij->i", e2, e2)
    d1p = np.einsum("ij,ij->i", e1, ep)
    d2p = np.einsum("ij,ij->i", e2, ep)
    den = np.maximum(d11 * d22 - d12 * d12, 1e-30)
    v = (d22 * d1p - d12 * d2p) / den
    w = (d11 * d2p - d12 * d1p) / den
    return np.stack([1 - v - w, v, w], axis=1)


# Vertex with the most negative barycentric -> the edge opposite it (edge k = (tri[k], tri[k+1])).
_EDGE_OPPOSITE = np.array([1, 2, 0])


def walk(origins, directions, start, vertices, triangles, adj, flip, exclude=None, max_steps=8):
    """Follow each line from its start triangle across adjacent triangles until the line passes
    through the triangle (found) or the walk leaves the mesh / the step budget (lost).

    ``exclude`` (k,) optional vertex index per line: a triangle containing it is never a hit (a
    cloth vertex's own one-ring), the walk is lost there instead.
    """
    k = start.shape[0]
    res = WalkResult(k)
    if k == 0:
        return res
    cur = start.astype(np.int64).copy()
    flips = np.zeros(k, bool)
    act = np.flatnonzero(cur >= 0)
    for step in range(max_steps + 1):
        if act.size == 0:
            break
        tri = triangles[cur[act]]
        a, b, c = vertices[tri[:, 0]], vertices[tri[:, 1]], vertices[tri[:, 2]]
        t, u, v, ok = line_triangle(origins[act], directions[act], a, b, c)
        w = 1.0 - u - v
        bary = np.stack([w, u, v], axis=1)
        inside = ok & (bary.min(axis=1) >= -_BARY_EPS)
        if exclude is not None:
            own = excluded(tri, exclude[act])
            inside &= ~own
            ok &= ~own
        found = act[inside]
        res.tri[found] = cur[found]
        res.t[found] = t[inside]
        res.u[found] = u[inside]
        res.v[found] = v[inside]
        res.flips[found] = flips[found]
        go = ok & ~inside
        if step == max_steps:
            break
        nxt_edge = _EDGE_OPPOSITE[np.argmin(bary[go], axis=1)]
        idx = act[go]
        nxt = adj[cur[idx], nxt_edge]
        flips[idx] ^= flip[cur[idx], nxt_edge]
        cur[idx] = nxt
        act = idx[nxt >= 0]
        res.steps = step + 1
    return res
