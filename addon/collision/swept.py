"""Continuous (swept) self-collision for the pairs the rays skip: the cloth's own two-ring.

Why: the rays of a full detection never test a vertex against a triangle of its own two-ring
(``narrow.ring_table``: there a cloth bent tighter than its thickness is always "in contact"
with itself, and such contacts fought the bending). A crease folded over one row of edges -
a cloth over a thin bar - then overshoots flat and the two sides pass edge through edge, unseen
(measured: tests/test_collision_session.py, edges 850-880 / 881-911, from step 194).

What is tested: every vertex-triangle pair and every edge-edge pair (no shared vertex) inside the
ring the rays skip, by the swept kernels of native/collide/ccd.c:

* predicted - over this step's motion x -> x + dt v, with a per-pair gap taken from the REST
  geometry, gap = min(fraction * thickness, fraction * rest distance): a pair that is close at rest
  (a jittered or irregular mesh) never counts as touching at rest, and twins of a cut (rest distance
  0) are never tested. A pair predicted to come within its gap gets contacts that stop the
  approach: both sides' vertices keep the pair's mean normal velocity (inelastic, momentum
  conserving), depth 0 - nothing is pushed apart, so the bending is not fought.
* crossed - over the previous step's real motion with gap 0: a sign change of the coplanarity cubic
  where the elements meet (not proximity). Such a pair (the prediction missed it) is remembered
  with the side it came from and pushed back (depth = how far it is on the wrong side + its gap)
  until it is on its side again or has separated.

Culling: a pair is tested only when a lower bound of its distance - gap, carried from step to step
and lowered by the relative motion of its corners, no longer proves it apart (ccd.c). The ~105,000
two-ring pairs of the bench's shirt are culled by blocks of 64 consecutive pairs: a block whose
vertices moved less relative to each other than its smallest bound allows is skipped unread (its
motion owed as a debt), so a step in which nothing drew close reads ~30 vertices per block instead
of 256 corners; both motions of a step (the real one, then the prediction) in one pass.

Counts (predicted, crossed, remembered) go to the detector's stats; nothing is dropped silently.
"""
from __future__ import annotations

import numpy as np

from .. import _collide

# share of the thickness, and of the pair's rest distance, that counts as touching
GAP_FRACTION = 0.25
# pairs closer than this at rest (m; twins of a cut: 0) are one piece of cloth, never tested
MIN_REST = 1e-6


def unique_edges(triangles):
    t = np.asarray(triangles, np.int64)
    e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    return np.unique(np.sort(e, axis=1), axis=0)


def _incident_edges(edges, n):
    """(n, K) table of the edges at each vertex, padded with -1."""
    ends = edges.reshape(-1)
    eid = np.repeat(np.arange(edges.shape[0]), 2)
    order = np.argsort(ends, kind="stable")
    counts = np.bincount(ends, minlength=n)
    table = np.full((n, max(int(counts.max(initial=0)), 1)), -1, np.int64)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    table[ends[order], np.arange(order.size) - start[ends[order]]] = eid[order]
    return table


def skipped_pairs(triangles, ring, n):
    """The pairs the rays skip: (vertex, triangle) with a corner of the triangle in the vertex's
    ring (not a corner itself), and (edge, edge) sharing no vertex with an end of one in the ring of
    an end of the other. Returns (edges (m, 2), vt (k, 2), ee (j, 2) edge ids, first < second)."""
    t = np.asarray(triangles, np.int64)
    edges = unique_edges(t)
    u = ring[t].reshape(t.shape[0], -1)
    ti = np.repeat(np.arange(t.shape[0]), u.shape[1])
    u = u.reshape(-1)
    ok = (u >= 0) & (u != t[ti, 0]) & (u != t[ti, 1]) & (u != t[ti, 2])
    vt = np.unique(np.stack([u[ok], ti[ok]], 1), axis=0)
    inc = _incident_edges(edges, n)
    nb = ring[edges]  # (m, 2, K)
    f = inc[np.where(nb >= 0, nb, 0)]
    f[nb < 0] = -1
    f = f.reshape(edges.shape[0], -1)
    fi = np.repeat(np.arange(edges.shape[0]), f.shape[1])
    f = f.reshape(-1)
    ok = (f >= 0) & (fi < f)
    a, b = fi[ok], f[ok]
    ea, eb = edges[a], edges[b]
    ok = (ea[:, 0] != eb[:, 0]) & (ea[:, 0] != eb[:, 1]) & (ea[:, 1] != eb[:, 0]) & (ea[:, 1] != eb[:, 1])
    ee = np.unique(np.stack([a[ok], b[ok]], 1), axis=0)
    return edges, vt.reshape(-1, 2), ee.reshape(-1, 2)


# pairs per block of the cull (ccd.c tcc_ccd_cull_blocks): larger blocks read fewer vertices per pair
# but their looser shared bound opens them more often; on the shirt of the collision bench a block of
# 64 pairs uses ~25 vertices
BLOCK_PAIRS = 64


def _pair_blocks(quad, size=BLOCK_PAIRS):
    """(block_ptr, block_vptr, block_vertices, block_min, block_debt) of runs of ``size`` pairs of
    ``quad`` (k, 4): the distinct vertices of each run, its bound unknown, nothing owed."""
    k = quad.shape[0]
    nb = -(-k // size)
    ptr = np.minimum(np.arange(nb + 1, dtype=np.int64) * size, k)
    n = int(quad.max(initial=-1)) + 1
    keys = np.unique((np.arange(k, dtype=np.int64) // size)[:, None] * n + quad).reshape(-1) if k else \
        np.zeros(0, np.int64)
    vptr = np.zeros(nb + 1, np.int64)
    if k:
        np.cumsum(np.bincount(keys // n, minlength=nb), out=vptr[1:])
    return ptr, vptr, _c(keys % n if k else keys, np.int64), np.full(nb, -np.inf), np.zeros(nb)


def _apart(gapv, dist, fallback, gap):
    """Unit direction from the second element's closest point to the first's: the way they are
    apart. Why not the plane or line normal: for two nearly parallel edges (a crease's mirror
    diagonals) the cross product is ill-conditioned and points anywhere, and a contact along it
    pressed on the stiff membrane and blew the sheet up. Only where the pair nearly touches
    (closer than a tenth of its gap) the oriented normal is used."""
    far = dist > 0.1 * gap
    out = fallback.copy()
    out[far] = gapv[far] / dist[far, None]
    return out


def _c(a, dtype=None):
    return np.ascontiguousarray(a, dtype)


class SweptSelf:
    """The swept self-collision state of one cloth topology (see the module docs)."""

    def __init__(self, positions, triangles, ring, rest, thickness):
        n = positions.shape[0]
        self.triangles = _c(triangles, np.int64)
        self.edges, vt, ee = skipped_pairs(self.triangles, ring, n)
        self.thickness = float(thickness)
        rest = np.asarray(rest, np.float64)
        # rest distances (C kernels at the rest positions); pairs of one piece (twins) dropped
        k = vt.shape[0]
        sd, dist, w, nrm = np.empty(k), np.empty(k), np.empty((k, 3)), np.empty((k, 3))
        _collide.vertex_triangle_state(positions=rest, triangles=self.triangles, vertex=_c(vt[:, 0]),
                                       triangle=_c(vt[:, 1]), sd=sd, dist=dist, weights=w, normal=nrm)
        keep = dist > MIN_REST
        self.vt_v, self.vt_t = _c(vt[keep, 0]), _c(vt[keep, 1])
        self.vt_gap = GAP_FRACTION * np.minimum(self.thickness, dist[keep])
        j = ee.shape[0]
        ea, eb = _c(self.edges[ee[:, 0]]), _c(self.edges[ee[:, 1]])
        sd, dist, st, nrm = np.empty(j), np.empty(j), np.empty((j, 2)), np.empty((j, 3))
        _collide.edge_edge_state(positions=rest, edge_a=ea, edge_b=eb, sd=sd, dist=dist, params=st, normal=nrm)
        keep = dist > MIN_REST
        self.ee_a, self.ee_b = _c(ea[keep]), _c(eb[keep])
        self.ee_gap = GAP_FRACTION * np.minimum(self.thickness, dist[keep])
        # per pair: its 4 vertex ids (the first element's first) and a lower bound of its distance
        # minus its gap (-inf: unknown), for the culling (ccd.c tcc_ccd_cull)
        self.vt_quad = _c(np.column_stack([self.vt_v, self.triangles[self.vt_t]]).reshape(-1, 4), np.int64)
        self.ee_quad = _c(np.column_stack([self.ee_a, self.ee_b]).reshape(-1, 4), np.int64)
        self.vt_slack = np.full(self.vt_v.size, -np.inf)
        self.ee_slack = np.full(self.ee_a.shape[0], -np.inf)
        self._make_blocks()
        # remembered crossings: pair index, oriented normal (the side to push the first element to)
        self.mem_vt = np.zeros(0, np.int64)
        self.mem_vt_n = np.zeros((0, 3))
        self.mem_ee = np.zeros(0, np.int64)
        self.mem_ee_n = np.zeros((0, 3))
        self.counts = {"predicted": 0, "crossed": 0, "remembered": 0, "no_normal": 0, "tested": 0}

    def _make_blocks(self):
        """The cull's blocks (ccd.c tcc_ccd_cull_blocks): runs of BLOCK_PAIRS consecutive pairs (sorted
        by their first element, so a run is one patch of cloth) with the vertices their corners use,
        the smallest bound of each (-inf: unknown) and its motion not yet charged to its pairs."""
        self.blocks = {kind: _pair_blocks(quad) for kind, quad in (("vt", self.vt_quad), ("ee", self.ee_quad))}

    def __setstate__(self, state):
        self.__dict__.update(state)
        if "blocks" not in state:  # saved before the cull had blocks: its pairwise bounds stay valid
            self._make_blocks()

    @property
    def n_pairs(self):
        return int(self.vt_v.size + self.ee_a.shape[0])

    # ---------------------------------------------------------------- kernels
    def _cull(self, kind, x, move, update, predicted=None):
        """Indices of the pairs of `kind` that may come within their gap over ``move`` (C, ccd.c
        tcc_ccd_cull_blocks); with ``predicted`` (a second motion from x, culled after the first without
        update, in the same pass over the blocks) the pair (those, the predicted ones)."""
        quad, gap, slack = (self.vt_quad, self.vt_gap, self.vt_slack) if kind == "vt" else \
            (self.ee_quad, self.ee_gap, self.ee_slack)
        out = np.empty(gap.size, np.int64)
        out2 = None if predicted is None else np.empty(gap.size, np.int64)
        ptr, vptr, verts, bmin, debt = self.blocks[kind]
        k = _collide.ccd_cull(positions=x, quads=quad, split=1 if kind == "vt" else 2, displacement=move, gap=gap,
                              slack=slack, update=update, out=out, block_ptr=ptr, block_vptr=vptr,
                              block_vertices=verts, block_min=bmin, block_debt=debt, predicted=predicted,
                              predicted_out=out2)
        if predicted is None:
            return out[:k]
        return out[:k[0]], out2[:k[1]]

    def _vt(self, x0, x1, gap, q):
        """Swept vertex-triangle test of pairs q: (the pairs hit, their sides)."""
        k = q.size
        toi, w, side = np.empty(k), np.empty((k, 3)), np.empty(k, np.int8)
        pg = None if np.isscalar(gap) else _c(gap[q])
        g = float(gap) if np.isscalar(gap) else self.thickness  # pair_gap below it wins
        _collide.ccd_vertex_triangle(start=x0, end=x1, triangles=self.triangles, vertex=_c(self.vt_v[q]),
                                     triangle=_c(self.vt_t[q]), gap=g, toi=toi, weights=w, side=side, pair_gap=pg)
        hit = np.isfinite(toi)
        return q[hit], side[hit]

    def _ee(self, x0, x1, gap, q):
        k = q.size
        toi, st, side = np.empty(k), np.empty((k, 2)), np.empty(k, np.int8)
        pg = None if np.isscalar(gap) else _c(gap[q])
        g = float(gap) if np.isscalar(gap) else self.thickness
        _collide.ccd_edge_edge(start=x0, end=x1, edge_a=_c(self.ee_a[q]), edge_b=_c(self.ee_b[q]), gap=g, toi=toi,
                               params=st, side=side, pair_gap=pg)
        hit = np.isfinite(toi)
        return q[hit], side[hit]

    def _vt_state(self, x, q):
        k = q.size
        sd, dist, w, nrm = np.empty(k), np.empty(k), np.empty((k, 3)), np.empty((k, 3))
        _collide.vertex_triangle_state(positions=x, triangles=self.triangles, vertex=_c(self.vt_v[q]),
                                       triangle=_c(self.vt_t[q]), sd=sd, dist=dist, weights=w, normal=nrm)
        return sd, dist, w, nrm

    def _ee_state(self, x, q):
        k = q.size
        sd, dist, st, nrm = np.empty(k), np.empty(k), np.empty((k, 2)), np.empty((k, 3))
        _collide.edge_edge_state(positions=x, edge_a=_c(self.ee_a[q]), edge_b=_c(self.ee_b[q]), sd=sd, dist=dist,
                                 params=st, normal=nrm)
        return sd, dist, st, nrm

    # ---------------------------------------------------------------- one step
    def contacts(self, x_prev, x, v, dt):
        """Contact rows (vertex, depth, normal, velocity) for the step from x (m) with velocity v
        (m/s) over dt (s); x_prev: the positions at the previous step (or None)."""
        rows = []
        # crossed over the previous step (gap 0: the elements met), added to the memory; the
        # pairs' distance bounds are carried to x (exact ones for the pairs tested)
        real = x_prev is not None and x_prev.shape == x.shape
        move = _c(x - x_prev) if real else np.zeros_like(x)
        # the prediction's candidates in the same pass (the crossed tests below read no bound)
        predict = v is not None and dt > 0
        pmove = _c(dt * v) if predict else None
        cand_vt, pred_vt = self._cull("vt", x, move, True, pmove) if predict else (self._cull("vt", x, move, True), None)
        cand_ee, pred_ee = self._cull("ee", x, move, True, pmove) if predict else (self._cull("ee", x, move, True), None)
        self.counts["tested"] = int(cand_vt.size + cand_ee.size)
        if real:
            q, side = self._vt(x_prev, x, 0.0, cand_vt)
            if q.size:
                _, _, _, nrm = self._vt_state(x_prev, q)
                self._remember("vt", q, side[:, None] * nrm)
            q, side = self._ee(x_prev, x, 0.0, cand_ee)
            if q.size:
                _, _, _, nrm = self._ee_state(x_prev, q)
                self._remember("ee", q, side[:, None] * nrm)
        self.counts["remembered"] = int(self.mem_vt.size + self.mem_ee.size)
        # remembered: pushed back to their side until there again, or apart
        if self.mem_vt.size:
            sd, dist, w, nrm = self._vt_state(x, self.mem_vt)
            flip = np.where(np.einsum("ij,ij->i", nrm, self.mem_vt_n) < 0, -1.0, 1.0)
            nrm = nrm * flip[:, None]
            s = sd * flip  # the vertex's height over the triangle's plane, on the remembered side
            g = self.vt_gap[self.mem_vt]
            live = (s < g) & (dist < self.thickness)
            self.mem_vt, self.mem_vt_n = self.mem_vt[live], nrm[live]
            rows.append(self._vt_rows(self.mem_vt, nrm[live], w[live], g[live] - s[live], v))
        if self.mem_ee.size:
            sd, dist, st, nrm = self._ee_state(x, self.mem_ee)
            flip = np.where(np.einsum("ij,ij->i", nrm, self.mem_ee_n) < 0, -1.0, 1.0)
            nrm = nrm * flip[:, None]
            s = sd * flip  # (a - c) . n: first edge's height over the second along the remembered side
            g = self.ee_gap[self.mem_ee]
            live = (s < g) & (dist < self.thickness)
            self.mem_ee, self.mem_ee_n = self.mem_ee[live], nrm[live]
            rows.append(self._ee_rows(self.mem_ee, nrm[live], st[live], g[live] - s[live], v))
        # predicted over this step: stop the approach of pairs that would come within their gap
        if predict:
            x1 = _c(x + pmove)
            cand_vt, cand_ee = pred_vt, pred_ee
            self.counts["tested"] += int(cand_vt.size + cand_ee.size)
            q, side = self._vt(x, x1, self.vt_gap, np.setdiff1d(cand_vt, self.mem_vt))
            self.counts["predicted"] = int(q.size)
            if q.size:
                _, dist, w, nrm = self._vt_state(x, q)
                c = self.triangles[self.vt_t[q]]
                gapv = x[self.vt_v[q]] - np.einsum("ij,ijk->ik", w, x[c])
                rows.append(self._vt_rows(q, _apart(gapv, dist, side[:, None] * nrm, self.vt_gap[q]), w,
                                          np.zeros(q.size), v))
            q, side = self._ee(x, x1, self.ee_gap, np.setdiff1d(cand_ee, self.mem_ee))
            self.counts["predicted"] += int(q.size)
            if q.size:
                _, dist, st, nrm = self._ee_state(x, q)
                a, b = self.ee_a[q].T
                c, d = self.ee_b[q].T
                s_, t_ = st[:, :1], st[:, 1:]
                gapv = (1 - s_) * x[a] + s_ * x[b] - (1 - t_) * x[c] - t_ * x[d]
                rows.append(self._ee_rows(q, _apart(gapv, dist, side[:, None] * nrm, self.ee_gap[q]), st,
                                          np.zeros(q.size), v))
        rows = [r for r in rows if r[0].size]
        if not rows:
            return None
        vert, depth, nrm, vel = (np.concatenate([r[i] for r in rows]) for i in range(4))
        # parallel edges or a collapsed triangle have no normal: no direction to hold them apart
        ok = np.einsum("ij,ij->i", nrm, nrm) > 0.25
        self.counts["no_normal"] = int(ok.size - ok.sum())
        return vert[ok], depth[ok], nrm[ok], vel[ok]

    def _remember(self, kind, q, nrm):
        if kind == "vt":
            self.counts["crossed"] += int(q.size)
            new = ~np.isin(q, self.mem_vt)
            self.mem_vt = np.concatenate([self.mem_vt, q[new]])
            self.mem_vt_n = np.concatenate([self.mem_vt_n, nrm[new]])
        else:
            self.counts["crossed"] += int(q.size)
            new = ~np.isin(q, self.mem_ee)
            self.mem_ee = np.concatenate([self.mem_ee, q[new]])
            self.mem_ee_n = np.concatenate([self.mem_ee_n, nrm[new]])

    def _vt_rows(self, q, n, w, depth, v):
        """The vertex pushed along n, the triangle's corners along -n; all keep the pair's mean
        velocity along n (an inelastic meeting of the two sides)."""
        p = self.vt_v[q]
        c = self.triangles[self.vt_t[q]]
        vel = np.zeros((q.size, 3))
        if v is not None:
            vel = 0.5 * (v[p] + np.einsum("ij,ijk->ik", w, v[c]))
        depth = np.maximum(depth, 0.0)
        vert = np.concatenate([p, c[:, 0], c[:, 1], c[:, 2]])
        nn = np.concatenate([n, -n, -n, -n])
        return vert, np.tile(depth, 4), nn, np.tile(vel, (4, 1))

    def _ee_rows(self, q, n, st, depth, v):
        a, b = self.ee_a[q].T
        c, d = self.ee_b[q].T
        vel = np.zeros((q.size, 3))
        if v is not None:
            s, t = st[:, :1], st[:, 1:]
            vel = 0.5 * ((1 - s) * v[a] + s * v[b] + (1 - t) * v[c] + t * v[d])
        depth = np.maximum(depth, 0.0)
        vert = np.concatenate([a, b, c, d])
        nn = np.concatenate([n, n, -n, -n])
        return vert, np.tile(depth, 4), nn, np.tile(vel, (4, 1))
