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

Culling: a pair is tested only when a lower bound of its distance - gap, kept from the last time
its block of 64 consecutive pairs was read, no longer exceeds how far the block's vertices may have
moved apart since then (swept.c). The ~105,000 two-ring pairs of the bench's shirt are ~1,650
blocks; a block keeps its vertices' positions when it was last read and a running bound of their
spread since, grown each step by the cheapest bound that will do - the largest motion of any group
of 16 nearby vertices (one addition), else the block's groups' boxes, else its own vertices (exact,
which restores the margin) - so a quiet step reads almost nothing. One C call per step does the cull,
the swept tests and the memory (swept.c tcc_swept_step); a second merges the rows into the
colliders' contacts (tcc_swept_rows). The step's previous positions must be the positions of the
previous call (the running bounds are built on that), which the detector guarantees.

Counts (predicted, crossed, remembered) go to the detector's stats; nothing is dropped silently.
"""
from __future__ import annotations

import numpy as np

from .. import _collide

# share of the thickness, and of the pair's rest distance, that counts as touching
GAP_FRACTION = 0.25
# pairs closer than this at rest (m; twins of a cut: 0) are one piece of cloth, never tested
MIN_REST = 1e-6


def skipped_pairs(triangles, ring, n):
    """The pairs the rays skip: (vertex, triangle) with a corner of the triangle in the vertex's
    ring (not a corner itself), and (edge, edge) sharing no vertex with an end of one in the ring of
    an end of the other. Returns (edges (m, 2), vt (k, 2), ee (j, 2) edge ids, first < second), each
    ascending (C: swept.c tcc_swept_pairs)."""
    t = _c(triangles, np.int64).reshape(-1, 3)
    ring = _c(ring, np.int64)
    caps = [3 * t.shape[0], 3 * t.shape[0] * ring.shape[1], 8 * t.shape[0] * ring.shape[1]]
    while True:
        edges, vt, ee = np.empty((caps[0], 2), np.int64), np.empty((caps[1], 2), np.int64), \
            np.empty((caps[2], 2), np.int64)
        counts = _collide.swept_pairs(t, ring, int(n), edges, vt, ee)
        if all(c <= cap for c, cap in zip(counts, caps)):
            return edges[:counts[0]], vt[:counts[1]], ee[:counts[2]]
        caps = [max(c, cap) for c, cap in zip(counts, caps)]


# vertices per group of the cull's cheap bounds (swept.c): nearby vertices (runs of the Morton order of
# the rest positions); a block of ~26 vertices meets a few groups
GROUP_SIZE = 16

# pairs per block of the cull (ccd.c tcc_ccd_cull_blocks): larger blocks read fewer vertices per pair
# but their looser shared bound opens them more often; on the shirt of the collision bench a block of
# 64 pairs uses ~25 vertices
BLOCK_PAIRS = 64


def _pair_blocks(quad, group, size=BLOCK_PAIRS):
    """(block_ptr, block_vptr, block_vertices, block_gptr, block_groups) of runs of ``size`` pairs of
    ``quad`` (k, 4): the distinct vertices of each run and their distinct groups, ascending (C)."""
    k = quad.shape[0]
    nb = -(-k // size)
    out = (np.empty(nb + 1, np.int64), np.empty(nb + 1, np.int64), np.empty(4 * k, np.int64),
           np.empty(nb + 1, np.int64), np.empty(4 * k, np.int64))
    nv, ng = _collide.swept_blocks(_c(quad, np.int64), size, _c(group, np.int64), *out)
    return out[0], out[1], out[2][:nv].copy(), out[3], out[4][:ng].copy()


def _groups(x, size):
    """Group of each vertex: runs of ``size`` vertices in the Morton (z-order) of positions x, so
    that a group is a few nearby vertices."""
    x = np.asarray(x, np.float64).reshape(-1, 3)
    n = x.shape[0]
    if n == 0:
        return np.zeros(0, np.int64)
    lo, hi = x.min(axis=0), x.max(axis=0)
    q = ((x - lo) / np.where(hi > lo, hi - lo, 1.0) * 1023).astype(np.int64).clip(0, 1023)
    code = np.zeros(n, np.int64)
    for bit in range(10):
        for axis in range(3):
            code |= ((q[:, axis] >> bit) & 1) << (3 * bit + axis)
    lab = np.empty(n, np.int64)
    lab[np.argsort(code, kind="stable")] = np.arange(n) // size
    return lab


def _c(a, dtype=None):
    return np.ascontiguousarray(a, dtype)


class SweptSelf:
    """The swept self-collision state of one cloth topology (see the module docs).

    """

    def __init__(self, positions, triangles, ring, rest, thickness):
        n = positions.shape[0]
        self.n = int(n)
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
        # minus its gap (-inf: unknown), for the cull (swept.c)
        self.vt_quad = _c(np.column_stack([self.vt_v, self.triangles[self.vt_t]]).reshape(-1, 4), np.int64)
        self.ee_quad = _c(np.column_stack([self.ee_a, self.ee_b]).reshape(-1, 4), np.int64)
        self.vt_slack = np.full(self.vt_v.size, -np.inf)
        self.ee_slack = np.full(self.ee_a.shape[0], -np.inf)
        self._make_blocks(rest)
        # remembered crossings: pair index, oriented normal (the side to push the first element to)
        self.mem_vt = np.zeros(0, np.int64)
        self.mem_vt_n = np.zeros((0, 3))
        self.mem_ee = np.zeros(0, np.int64)
        self.mem_ee_n = np.zeros((0, 3))
        self.counts = {"predicted": 0, "crossed": 0, "remembered": 0, "no_normal": 0, "tested": 0}

    def _make_blocks(self, rest):
        """The cull's blocks (swept.c): runs of BLOCK_PAIRS consecutive pairs (sorted by their first
        element, so a run is one patch of cloth) with the vertices their corners use and the groups
        those are in, each block's bound unknown and its reference pose set at the next step; and
        the groups (GROUP_SIZE vertices in the Morton order of ``rest``)."""
        lab = _groups(rest, GROUP_SIZE)
        ng = int(lab.max(initial=-1)) + 1
        self.group_ptr = np.zeros(ng + 1, np.int64)
        np.cumsum(np.bincount(lab, minlength=ng), out=self.group_ptr[1:])
        self.group_vertices = _c(np.argsort(lab, kind="stable"), np.int64)
        self.has_reference = np.zeros(1, bool)
        self.blocks = {}
        for kind, quad in (("vt", self.vt_quad), ("ee", self.ee_quad)):
            ptr, vptr, verts, gptr, groups = _pair_blocks(quad, lab)
            state = np.zeros((ptr.size - 1, 2))
            state[:, 0] = -np.inf
            self.blocks[kind] = (ptr, vptr, verts, state, np.zeros((verts.size, 3)), gptr, groups)

    # the step's scratch (outputs of the C step) is not part of the state
    _SCRATCH = ("_buf", "live")

    def __getstate__(self):
        return {k: v for k, v in self.__dict__.items() if k not in self._SCRATCH}

    def __setstate__(self, state):
        self.__dict__.update(state)
        blocks = state.get("blocks")
        if blocks is not None and len(next(iter(blocks.values()), ())) == 7:
            return
        # saved before the blocks had reference poses (their bounds carried a debt of motion up to the
        # previous step): each pair's bound less its block's debt holds at the previous step, which
        # becomes every block's reference pose at the next one; the groups from the current positions'
        # order (no rest positions were kept)
        self.n = int(max(self.vt_quad.max(initial=-1), self.ee_quad.max(initial=-1))) + 1
        self._make_blocks(np.zeros((self.n, 3)))
        for kind, old in (blocks or {}).items():
            ptr, state = self.blocks[kind][0], self.blocks[kind][3]
            if len(old) < 5 or old[3].size != state.shape[0]:
                continue  # no usable bounds: every block is read at the next step
            slack = self.vt_slack if kind == "vt" else self.ee_slack
            slack -= np.repeat(old[4], np.diff(ptr))
            state[:, 0] = old[3] - old[4]

    @property
    def n_pairs(self):
        return int(self.vt_v.size + self.ee_a.shape[0])

    def _buffers(self):
        """The C step's arguments in its table's order (swept_step), with its outputs, kept between
        steps: two memories per kind (a step reads one and writes the other)."""
        buf = getattr(self, "_buf", None)
        if buf is not None:
            return buf
        buf = {"args": dict(positions=None, previous=None, velocity=None, dt=0.0, thickness=self.thickness,
                            group_ptr=self.group_ptr, group_vertices=self.group_vertices,
                            has_reference=self.has_reference)}
        for kind, k in (("vt", self.vt_v.size), ("ee", self.ee_a.shape[0])):
            blk = self.blocks[kind]
            quad, gap, slack = (self.vt_quad, self.vt_gap, self.vt_slack) if kind == "vt" else \
                (self.ee_quad, self.ee_gap, self.ee_slack)
            b = dict(mem=[np.empty(k, np.int64), np.empty(k, np.int64)], mem_n=[np.empty((k, 3)), np.empty((k, 3))],
                     flip=0, pairs=np.empty(k, np.int64), normal=np.empty((k, 3)), depth=np.empty(k),
                     weights=np.empty((k, 3)))
            buf[kind] = b
            buf["args"].update({f"{kind}_quads": quad, f"{kind}_gap": gap, f"{kind}_slack": slack,
                                f"{kind}_block_ptr": blk[0], f"{kind}_block_vptr": blk[1],
                                f"{kind}_block_vertices": blk[2], f"{kind}_block_state": blk[3],
                                f"{kind}_block_reference": blk[4], f"{kind}_block_gptr": blk[5],
                                f"{kind}_block_groups": blk[6], f"{kind}_memory": None, f"{kind}_memory_normal": None,
                                f"{kind}_memory_out": None, f"{kind}_memory_normal_out": None,
                                f"{kind}_pairs_out": b["pairs"], f"{kind}_normal_out": b["normal"],
                                f"{kind}_depth_out": b["depth"], f"{kind}_weights_out": b["weights"]})
        buf["counts"] = np.zeros(24, np.int64)
        buf["args"]["counts"] = buf["counts"]
        self._buf = buf
        return buf

    # ---------------------------------------------------------------- one step
    def step(self, x_prev, x, v, dt, handed_out=None):
        """One step (swept.c tcc_swept_step) from x (m) with velocity v (m/s) over dt (s); x_prev:
        the positions at the previous step (or None). Afterwards ``self.live`` holds per kind the
        pairs giving contacts (pairs, normal, depth, weights, live count). Returns how many pairs
        give contacts. ``handed_out``, a dict (tests): receives per kind the pairs the cull handed out
        over the real and the predicted motion."""
        args, extra = self._arguments(x_prev, x, v, dt, handed_out)
        _collide.swept_step(**args, **extra)
        return self._take(handed_out)

    def start(self, worker, x_prev, x, v, dt):
        """``step`` handed to ``worker``'s thread (``_collide.swept_worker()``: an OS thread that never
        needs the GIL, so the step begins at once whatever Python runs meanwhile). Nothing of this
        object, x_prev, x or v may change until ``finish(job)``."""
        args, extra = self._arguments(x_prev, x, v, dt, None)
        return _collide.swept_start(worker, **args, **extra)  # (the job holds the arrays' buffers)

    def finish(self, job):
        """The end of a ``start``ed step: (its own seconds, whether it ran on its thread, how many
        pairs give contacts), ``self.live`` as ``step`` leaves it. Raises the step's error."""
        seconds, on_thread = _collide.swept_join(job)
        return seconds, on_thread, self._take(None)

    def _arguments(self, x_prev, x, v, dt, handed_out):
        """The C step's keyword arguments for this step (the kept buffers, this step's arrays and
        the memory buffer it writes), and the optional handed-out outputs."""
        buf = self._buffers()
        real = x_prev is not None and x_prev.shape == x.shape
        predict = v is not None and dt > 0
        args = buf["args"]
        args["positions"] = x
        args["previous"] = _c(x_prev, np.float64) if real else None
        args["velocity"] = _c(v, np.float64) if predict else None
        args["dt"] = float(dt) if predict else 0.0
        for kind in ("vt", "ee"):
            b = buf[kind]
            out = 1 - b["flip"]  # the memory buffer not holding the current memory
            mem, mem_n = (self.mem_vt, self.mem_vt_n) if kind == "vt" else (self.mem_ee, self.mem_ee_n)
            args[f"{kind}_memory"], args[f"{kind}_memory_normal"] = _c(mem, np.int64), _c(mem_n, np.float64)
            args[f"{kind}_memory_out"], args[f"{kind}_memory_normal_out"] = b["mem"][out], b["mem_n"][out]
        extra = {}
        if handed_out is not None:
            for kind, k in (("vt", self.vt_gap.size), ("ee", self.ee_gap.size)):
                handed_out[kind] = (np.empty(k, np.int64), np.empty(k, np.int64))
                extra[f"{kind}_handed_out"], extra[f"{kind}_predicted_out"] = handed_out[kind]
        return args, extra

    def _take(self, handed_out):
        """After the C step: the new memories, ``self.live``, the counts; returns how many pairs give
        contacts."""
        buf = self._buffers()
        c = buf["counts"].tolist()
        vt, ee = c[:12], c[12:]
        self.live = {}
        for kind, ck in (("vt", vt), ("ee", ee)):
            b = buf[kind]
            b["flip"] = out = 1 - b["flip"]
            nm, nlive, m = ck[0], ck[1], ck[1] + ck[2]
            if kind == "vt":
                self.mem_vt, self.mem_vt_n = b["mem"][out][:nm], b["mem_n"][out][:nm]
            else:
                self.mem_ee, self.mem_ee_n = b["mem"][out][:nm], b["mem_n"][out][:nm]
            self.live[kind] = (b["pairs"][:m], b["normal"][:m], b["depth"][:m], b["weights"][:m], nlive)
            if handed_out is not None:
                h, p = handed_out[kind]
                handed_out[kind] = (h[:ck[6]], p[:ck[7]])
        self.counts["tested"] = vt[3] + ee[3]
        self.counts["crossed"] += vt[4] + ee[4]
        self.counts["remembered"] = vt[5] + ee[5]
        self.counts["predicted"] = vt[2] + ee[2]
        self.counts["blocks"] = [a + b for a, b in zip(vt[8:], ee[8:])]  # settled by bounds 1, 2, 3; read
        return vt[1] + vt[2] + ee[1] + ee[2]

    def rows(self, every, v, friction):
        """``every`` (the colliders' contacts, sorted by vertex) with the step's swept contact rows
        merged in after each vertex's own (C: swept.c tcc_swept_rows)."""
        from .narrow import Contacts

        extra = 4 * sum(r[0].size for r in self.live.values())
        cap = len(every) + extra
        out = (np.empty(cap, np.int32), np.empty((cap, 3)), np.empty(cap), np.empty((cap, 3)), np.empty(cap))
        args = {}
        for kind, quad in (("vt", self.vt_quad), ("ee", self.ee_quad)):
            pairs, normal, depth, weights, live = self.live[kind]
            args.update({f"{kind}_quads": quad, f"{kind}_pairs": pairs, f"{kind}_normal": normal,
                         f"{kind}_depth": depth, f"{kind}_weights": weights, f"{kind}_live": live})
        count, bad = _collide.swept_rows(**args, velocity=None if v is None else _c(v, np.float64), n=self.n,
                                         vertex=_c(every.vertex, np.int32), normal=_c(every.normal, np.float64),
                                         depth=_c(every.depth, np.float64), contact_velocity=_c(every.velocity, np.float64),
                                         friction=_c(every.friction, np.float64), cloth_friction=float(friction),
                                         out_vertex=out[0], out_normal=out[1], out_depth=out[2], out_velocity=out[3],
                                         out_friction=out[4])
        self.counts["no_normal"] = int(bad)
        return Contacts(*(a[:count] for a in out))

    def contacts(self, x_prev, x, v, dt):
        """One step's contact rows alone (vertex, depth, normal, velocity), or None when no pair
        gives any."""
        from .narrow import Contacts

        if self.step(x_prev, x, v, dt) == 0:
            return None
        c = self.rows(Contacts(), v, 0.0)
        return c.vertex.astype(np.int64), c.depth, c.normal, c.velocity
