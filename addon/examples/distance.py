"""Distance queries of the example geometry: exact closest points on a triangle mesh (uniform grid
plus Ericson's point-triangle test), the walking per-part distance the shirt fit uses, and
point-segment distances.

This file owns ``closest_points`` (closest point, signed distance, triangle per query point; > 0
outside a closed outward-wound mesh), ``MeshDistance`` (its grid, vertex normals and feature-based
sign), ``PartDistance`` (distances to the torso and to the arms, followed incrementally during the
fit), ``distance_to_segments`` and ``closest_on_segments``.

Hand-written rather than ``trimesh.proximity.closest_point``: trimesh returns the same points only
to rounding (its candidate search and point-triangle test differ) and has no signed distance by
closest feature, which the shirt fit needs; the fit's output, and the example .blend files, are
pinned to these values. SI units (metres).
"""
from __future__ import annotations

import math

import numpy as np

from .mesh import edge_keys, triangle_angles


def distance_to_segments(pts, a, b):
    """Distance (n,) from each point to the nearest of the segments a[k]-b[k] (2-D or 3-D)."""
    pts = np.asarray(pts, dtype=np.float64)
    best = np.full(len(pts), np.inf)
    chunk = max(1, 2_000_000 // max(1, len(a)))
    d = b - a
    dd = np.maximum(np.einsum("ij,ij->i", d, d), 1e-300)
    for s in range(0, len(pts), chunk):
        p = pts[s : s + chunk, None, :]
        t = np.clip(np.einsum("nkj,kj->nk", p - a[None], d) / dd, 0.0, 1.0)
        q = a[None] + t[..., None] * d[None]
        best[s : s + chunk] = np.sqrt(((p - q) ** 2).sum(-1).min(axis=1))
    return best


# ------------------------------------------------------------------------------------------------
# Closest points on a triangle mesh (exact, grid-accelerated)
# ------------------------------------------------------------------------------------------------


def _closest_on_triangles(p, a, b, c):
    """Closest points on triangles (a, b, c) to points p, all (k, 3), vectorised (Ericson,
    Real-Time Collision Detection 5.1.5). Returns (q (k, 3), region (k,)) with region 0 face,
    1/2/3 vertex a/b/c, 4/5/6 edge ab/bc/ca: the feature decides which normal gives the sign."""
    ab, ac, ap = b - a, c - a, p - a
    d1 = np.einsum("ij,ij->i", ab, ap)
    d2 = np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3 = np.einsum("ij,ij->i", ab, bp)
    d4 = np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5 = np.einsum("ij,ij->i", ab, cp)
    d6 = np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = 1.0 / (va + vb + vc)
        v_face = vb * denom
        w_face = vc * denom
        q = a + ab * v_face[:, None] + ac * w_face[:, None]
        region = np.zeros(len(p), dtype=np.int8)
        # edge bc
        m = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        q = np.where(m[:, None], b + (c - b) * w[:, None], q)
        region[m] = 5
        # edge ca
        m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        w = d2 / (d2 - d6)
        q = np.where(m[:, None], a + ac * w[:, None], q)
        region[m] = 6
        # edge ab
        m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        v = d1 / (d1 - d3)
        q = np.where(m[:, None], a + ab * v[:, None], q)
        region[m] = 4
    # vertices last: they win over the edge tests they also satisfy
    m = (d6 >= 0) & (d5 <= d6)
    q[m], region[m] = c[m], 3
    m = (d3 >= 0) & (d4 <= d3)
    q[m], region[m] = b[m], 2
    m = (d1 <= 0) & (d2 <= 0)
    q[m], region[m] = a[m], 1
    bad = ~np.all(np.isfinite(q), axis=1)  # degenerate triangle: fall back to its vertex a
    q[bad], region[bad] = a[bad], 1
    return q, region


def _cell_pairs(grid, cell, pts, ids, offs):
    """(point, triangle) candidate pairs: every triangle listed in the grid cells at ``offs``
    (cell offsets, (c, 3)) around the cell of each point ``ids``; ``grid`` = (origin, dims, sorted
    cell keys, their triangles) of cell size ``cell``."""
    origin, dims, cell_keys, cell_tris = grid
    gi = np.floor((pts[ids] - origin) / cell).astype(np.int64)
    nb = (gi[:, None, :] + offs[None]).reshape(-1, 3)
    inside = np.all((nb >= 0) & (nb < dims), axis=1)
    key = np.where(inside, (nb[:, 0] * dims[1] + nb[:, 1]) * dims[2] + nb[:, 2], -1)
    s = np.searchsorted(cell_keys, key, side="left")
    e = np.where(inside, np.searchsorted(cell_keys, key, side="right"), s)
    n = e - s
    pid = np.repeat(np.repeat(ids, len(offs)), n)
    within = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    return pid, cell_tris[np.repeat(s, n) + within]


class MeshDistance:
    """Signed distance queries against a fixed triangle mesh.

    Triangles are binned in uniform grids (a fine one with cells of about one mean edge, and
    coarser ones, x4 each, built on demand). A query gathers the 3x3x3 cells around its point and
    is exact once the distance found is within one cell (anything closer would lie in those
    cells); queries still unresolved move to the next coarser grid. The sign uses angle-weighted
    pseudo-normals at the closest feature (Baerentzen & Aanaes 2005), which is right on vertices
    and edges too, for a closed outward-wound mesh.
    """

    def __init__(self, vertices, triangles, cell=None):
        self.v = np.asarray(vertices, dtype=np.float64)
        self.t = np.asarray(triangles, dtype=np.int64)
        p = self.v[self.t]
        self.a, self.b, self.c = p[:, 0], p[:, 1], p[:, 2]
        fn = np.cross(self.b - self.a, self.c - self.a)
        fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
        self.face_n = fn
        ang = triangle_angles(self.v, self.t)
        vn = np.zeros_like(self.v)
        for k in range(3):
            np.add.at(vn, self.t[:, k], fn * ang[:, k : k + 1])
        self.vert_n = vn / np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-300)
        keys = edge_keys(self.t, len(self.v))
        uniq, inv = np.unique(keys.ravel(), return_inverse=True)
        en = np.zeros((len(uniq), 3))
        np.add.at(en, inv, np.repeat(fn, 3, axis=0))
        self.edge_n = en[inv].reshape(-1, 3, 3)  # per triangle side: ab, bc, ca
        if cell is None:
            cell = float(np.mean(np.linalg.norm(self.b - self.a, axis=1)))
        self.box_lo = np.minimum(np.minimum(self.a, self.b), self.c)
        self.box_hi = np.maximum(np.maximum(self.a, self.b), self.c)
        self.lo = self.v.min(axis=0)
        self.extent = float(np.ptp(self.v, axis=0).max())
        self.cells = [float(cell)]
        self.grids = [self._grid(float(cell))]

    def _grid(self, cell):
        origin = self.lo - cell
        lo = np.floor((np.minimum(np.minimum(self.a, self.b), self.c) - origin) / cell)
        hi = np.floor((np.maximum(np.maximum(self.a, self.b), self.c) - origin) / cell)
        lo, hi = lo.astype(np.int64), hi.astype(np.int64)
        dims = hi.max(axis=0) + 3
        span = hi - lo + 1
        count = span.prod(axis=1)
        tri = np.repeat(np.arange(len(self.t)), count)
        k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
        sy, sz = np.repeat(span[:, 1], count), np.repeat(span[:, 2], count)
        ix = np.repeat(lo[:, 0], count) + k // (sy * sz)
        iy = np.repeat(lo[:, 1], count) + (k // sz) % sy
        iz = np.repeat(lo[:, 2], count) + k % sz
        key = (ix * dims[1] + iy) * dims[2] + iz
        order = np.argsort(key, kind="stable")
        return origin, dims, key[order], tri[order]

    def query(self, points, max_distance=None):
        """(closest (k, 3), signed distance (k,), triangle (k,)); distance > 0 outside.
        With ``max_distance``, points farther than that get distance inf and triangle -1 (and
        cost much less: the coarse grids are never visited)."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        k = len(pts)
        best_d = np.full(k, np.inf)
        best_q = np.zeros((k, 3))
        best_t = np.zeros(k, dtype=np.int64)
        best_r = np.zeros(k, dtype=np.int8)
        todo = np.arange(k)
        level = 0
        while len(todo):
            if level == len(self.grids):
                cell = self.cells[-1] * 4.0
                self.cells.append(cell)
                self.grids.append(self._grid(cell))
            cell = self.cells[level]
            self._search(pts, todo, self.grids[level], cell, best_d, best_q, best_t, best_r)
            if cell > 2.0 * self.extent:
                break  # the 27 cells covered every triangle
            if max_distance is not None and cell >= max_distance:
                break  # everything within max_distance has been found exactly
            todo = todo[best_d[todo] > cell]
            level += 1
        sign = self._sign(pts, best_q, best_t, best_r)
        if max_distance is not None:
            far = best_d > max_distance
            best_d[far] = np.inf
            best_t[far] = -1
        return best_q, sign * best_d, best_t

    def _search(self, pts, todo, grid, cell, best_d, best_q, best_t, best_r):
        offs = np.array([(i, j, l) for i in (-1, 0, 1) for j in (-1, 0, 1) for l in (-1, 0, 1)])
        for chunk in range(0, len(todo), 2048):
            pid, tri = _cell_pairs(grid, cell, pts, todo[chunk : chunk + 2048], offs)
            # Cheap pruning before the exact test: a triangle whose bounding box is farther than
            # some candidate's corner cannot be the closest.
            p = pts[pid]
            ub = np.full(len(pts), np.inf)
            np.minimum.at(ub, pid, np.linalg.norm(p - self.a[tri], axis=1))
            gap = np.maximum(self.box_lo[tri] - p, 0.0) + np.maximum(p - self.box_hi[tri], 0.0)
            keep = np.einsum("ij,ij->i", gap, gap) <= ub[pid] ** 2 * (1.0 + 1e-9) + 1e-300
            self._reduce(pts, pid[keep], tri[keep], best_d, best_q, best_t, best_r)

    def _reduce(self, pts, pid, tri, best_d, best_q, best_t, best_r):
        if len(pid) == 0:
            return
        q, region = _closest_on_triangles(pts[pid], self.a[tri], self.b[tri], self.c[tri])
        d = np.linalg.norm(pts[pid] - q, axis=1)
        order = np.lexsort((d, pid))
        first = np.ones(len(order), dtype=bool)
        first[1:] = pid[order][1:] != pid[order][:-1]
        sel = order[first]
        i = pid[sel]
        better = d[sel] < best_d[i]
        i, sel = i[better], sel[better]
        best_d[i] = d[sel]
        best_q[i] = q[sel]
        best_t[i] = tri[sel]
        best_r[i] = region[sel]

    def pseudo_normals(self, tri, region):
        """Unit normal of the closest feature: face, edge (sum of the two faces) or vertex
        (angle-weighted)."""
        n = self.face_n[tri].copy()
        for r, corner in ((1, 0), (2, 1), (3, 2)):
            m = region == r
            n[m] = self.vert_n[self.t[tri[m], corner]]
        for r, side in ((4, 0), (5, 1), (6, 2)):
            m = region == r
            n[m] = self.edge_n[tri[m], side]
        return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)

    def _sign(self, pts, q, tri, region):
        n = self.pseudo_normals(tri, region)
        self.last_normals = n
        s = np.einsum("ij,ij->i", pts - q, n)
        return np.where(s < 0.0, -1.0, 1.0)

    def candidates(self, points, radius):
        """Triangles whose bounding box comes within ``radius`` (k,) of each point, as a padded
        (k, K) index array (-1 = none). Lets an iterative fit test only a short list per point."""
        pts = np.asarray(points, dtype=np.float64)
        radius = np.broadcast_to(np.asarray(radius, dtype=np.float64), (len(pts),))
        cell = self.cells[0]
        rc = int(math.ceil(float(radius.max()) / cell))
        r = np.arange(-rc, rc + 1)
        offs = np.stack(np.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3)
        pids, tris = [], []
        step = max(1, 200_000 // len(offs))
        for chunk in range(0, len(pts), step):
            ids = np.arange(chunk, min(chunk + step, len(pts)))
            pid, tri = _cell_pairs(self.grids[0], cell, pts, ids, offs)
            p = pts[pid]
            gap = np.maximum(self.box_lo[tri] - p, 0.0) + np.maximum(p - self.box_hi[tri], 0.0)
            keep = np.einsum("ij,ij->i", gap, gap) <= radius[pid] ** 2
            pair = np.unique(pid[keep] * np.int64(len(self.t)) + tri[keep])
            pids.append(pair // len(self.t))
            tris.append(pair % len(self.t))
        pid = np.concatenate(pids)
        tri = np.concatenate(tris)
        count = np.bincount(pid, minlength=len(pts))
        K = max(1, int(count.max(initial=0)))
        out = np.full((len(pts), K), -1, dtype=np.int64)
        slot = np.arange(len(pid)) - np.repeat(np.cumsum(count) - count, count)
        out[pid, slot] = tri
        return out


def closest_points(vertices, triangles, points):
    """Closest points on a triangle mesh to query points, exact.

    Returns (closest (k, 3), signed_distance (k,), triangle (k,)). The sign is positive outside
    a closed, outward-wound mesh (pseudo-normal test, right on edges and vertices too); for an
    open mesh it says which side of the nearest feature the point is on. Grid-accelerated:
    ~2K queries against an 8K-triangle body take a few milliseconds.
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles)
    if v.ndim != 2 or v.shape[1] != 3 or t.ndim != 2 or t.shape[1] != 3 or len(t) == 0:
        raise ValueError("closest_points needs vertices (n, 3) and at least one triangle (m, 3)")
    q, d, tri = MeshDistance(v, t).query(points)
    return q, d, tri


class PartDistance:
    """Distances from slowly moving points to two parts of a body (0: torso, legs, head; 1: arms).

    A fit moves each point by millimetres per round, so instead of a fresh grid search each time
    every point keeps its closest triangle per part and walks from it: each query tests the
    triangles sharing a vertex with the current one (~15 tests per point and part). A full search
    per part (``refresh``) seeds the walk and is repeated now and then, so a point that drifted
    toward another region cannot stay in a local minimum. Parts farther than ``reach`` are
    ignored (their weight in the smooth minimum would be nil).

    Distances are signed by the nearer part only: a sign taken at a part's closest feature is
    meaningless when another part is closer.
    """

    def __init__(self, md: MeshDistance, tri_part, reach, jump):
        self.md = md
        self.reach = reach
        self.jump = jump
        tri_part = np.asarray(tri_part, dtype=np.int64)
        self.part_tris = [np.flatnonzero(tri_part == g) for g in (0, 1)]
        self.sub = [MeshDistance(md.v, md.t[idx]) for idx in self.part_tris]
        t = md.t
        m = len(t)
        order = np.argsort(t.ravel(), kind="stable")
        vert_of = t.ravel()[order]
        tri_of = order // 3
        start = np.searchsorted(vert_of, np.arange(len(md.v)))
        count = np.bincount(vert_of, minlength=len(md.v))
        ring = np.full((len(md.v), int(count.max())), m, dtype=np.int64)
        ring[vert_of, np.arange(len(vert_of)) - np.repeat(start, count)] = tri_of
        nb = ring[t].reshape(m, -1)
        own = np.arange(m)
        ok = nb < m
        ok[ok] = tri_part[nb[ok]] == np.repeat(tri_part, ok.sum(axis=1))
        nb = np.sort(np.where(ok, nb, m), axis=1)
        dup = np.zeros_like(ok)
        dup[:, 1:] = nb[:, 1:] == nb[:, :-1]
        nb = np.sort(np.where(dup, m, nb), axis=1)  # unique ids first, sentinel m last
        width = int((nb < m).sum(axis=1).max())
        nb = nb[:, :width]
        self.nb = np.where(nb < m, nb, own[:, None])
        self.best = None

    def refresh(self, x, idx=None):
        """Exact search (per part) for all points, or for the points ``idx``."""
        if self.best is None or idx is None:
            idx = np.arange(len(x))
            self.best = [np.full(len(x), -1, dtype=np.int64) for _ in (0, 1)]
            self.anchor = x.copy()
        for g in (0, 1):
            _, _, tri = self.sub[g].query(x[idx], max_distance=self.reach)
            self.best[g][idx] = np.where(tri >= 0, self.part_tris[g][np.maximum(tri, 0)], -1)
        self.anchor[idx] = x[idx]

    def query(self, x):
        """Per part: signed distance (k,) (inf when out of reach) and its gradient (k, 3)."""
        if self.best is None:
            self.refresh(x)
        else:
            # A walk only follows small moves; a point that jumped is searched afresh (a stale
            # closest feature can give the wrong side, and the fit would then flip it inside).
            jumped = np.linalg.norm(x - self.anchor, axis=1) > self.jump
            if np.any(jumped):
                self.refresh(x, np.flatnonzero(jumped))
        n = len(x)
        dist = np.full((2, n), np.inf)
        near = np.zeros((2, n, 3))
        feature = np.zeros((2, n), dtype=np.int8)
        for g in (0, 1):
            live = np.flatnonzero(self.best[g] >= 0)
            if len(live) == 0:
                continue
            cand = self.nb[self.best[g][live]]
            K = cand.shape[1]
            tri = cand.ravel()
            P = np.repeat(x[live], K, axis=0)
            q, region = _closest_on_triangles(P, self.md.a[tri], self.md.b[tri], self.md.c[tri])
            d = np.linalg.norm(P - q, axis=1).reshape(len(live), K)
            k = np.argmin(d, axis=1)
            flat = np.arange(len(live)) * K + k
            self.best[g][live] = tri[flat]
            dist[g, live] = d[np.arange(len(live)), k]
            near[g, live] = q[flat]
            feature[g, live] = region[flat]
        closer = np.argmin(dist, axis=0)
        rows = np.arange(n)
        tri_c = np.array(self.best)[closer, rows]
        sign = np.ones(n)
        ok = tri_c >= 0
        nrm = self.md.pseudo_normals(tri_c[ok], feature[closer, rows][ok])
        away = x[ok] - near[closer, rows][ok]
        sign[ok] = np.where(np.einsum("ij,ij->i", away, nrm) < 0.0, -1.0, 1.0)
        out = []
        for g in (0, 1):
            away = x - near[g]
            with np.errstate(invalid="ignore", divide="ignore"):
                grad = sign[:, None] * away / dist[g][:, None]
            tiny = dist[g] <= 1e-9
            if np.any(tiny):
                tri_t = np.maximum(self.best[g][tiny], 0)
                grad[tiny] = self.md.pseudo_normals(tri_t, feature[g][tiny])
            grad[~np.isfinite(dist[g])] = 0.0
            out.append((sign * dist[g], grad))
        return out


def closest_on_segments(pts, a, b):
    """Closest point (k, 3) on the nearest of the segments a[j]-b[j] to each point."""
    d = b - a
    dd = np.maximum(np.einsum("ij,ij->i", d, d), 1e-300)
    t = np.clip(np.einsum("nkj,kj->nk", pts[:, None, :] - a[None], d) / dd, 0.0, 1.0)
    q = a[None] + t[..., None] * d[None]
    k = np.argmin(((pts[:, None, :] - q) ** 2).sum(-1), axis=1)
    return q[np.arange(len(pts)), k]
