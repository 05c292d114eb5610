"""The impact guard: after each step, the motion the solve produced is made free of self-crossings.

Why: every other collision stage (the rays, the swept stage of the two-ring) hands constraints to
the implicit solve before it runs, over a predicted motion; the solve then produces another one,
and on a chaotic fold (a sheet flapping over a thin bar) edges of the crease crossed inside a step
on some trajectories (tests/test_collision_session.py). A prediction promises nothing about the
motion it did not see; this guard acts on the motion x0 -> x1 the step actually made (Bridson,
Fedkiw & Anderson 2002; Provot 1997; Harmon et al. 2008), in one C call (native/collide/impact.c):

1. every vertex-triangle and edge-edge pair of the cloth that comes within ``gap`` during the step
   while approaching, or that crosses, is found (one BVH over the cloth, built once per topology at
   the rest positions and refitted to the step's swept boxes; exact swept tests of ccd.c; patches
   and vertex fans that provably cannot meet themselves during the step are skipped - normal cones
   and simple projected boundaries, impact.c);
2. inelastic impulses on the step's mean velocities, a few passes;
3. rigid impact zones for what is left (each zone keeps its linear and angular momentum), until a
   detection finds nothing; at the pass cap the whole cloth moves rigidly (counted, and warned).

Pairs that coincide at rest (the two rims of a cut: a tear's duplicates share their original's rest
position, native rest_positions) are one piece of cloth and never collide; a pair close at rest has
a gap of at most REST_FRACTION of its rest distance (as the swept stage). Vertices the step left
exactly in place (pinned, or held by static friction on a still body) are immovable.

Positions and velocities are written back (Cloth.set_positions, which marks the element state
stale so that stresses, forces and the next step see the new positions, and set_velocities) only
when something moved: a step the guard finds clean is left bit for bit as it was. The guard keeps
no state that a step reads (its tables and tree are functions of the triangles and the rest shape,
rebuilt when they change), so a resumed bake equals an uninterrupted one; it keeps counts
(``totals``) that are saved with the session.

Cost (measured, 2-core machine under load, thread CPU per step, median): 0.54 ms on the 1,800-
triangle sheet over the thin bar, 0.80 ms on its 3,200-triangle version, ~2 ms on the race's shirt
(3,305 triangles at 10 sub-steps per frame, where curvature keeps the provably free patches to ~60
triangles and their borders are traversed); ~2.5x that without the culling.
"""
from __future__ import annotations

import warnings

import numpy as np

from .. import _collide

# share of the contact thickness within which an approaching pair collides here: small against the
# thickness the contact stages keep (the guard acts where they failed), large against rounding
GAP_FRACTION = 0.1
# a pair's gap is at most this share of its rest distance (an irregular mesh is never "touching" in
# its rest shape); the swept stage's GAP_FRACTION, for the same reason
REST_FRACTION = 0.25
# pairs closer than this at rest (m) are one piece of cloth: twins of a cut (rest distance 0)
MIN_REST = 1e-6
# detections followed by impulses before the zones take over (Bridson et al.: a few)
IMPULSE_PASSES = 4
# detections followed by zone merges before the whole cloth moves as one zone
ZONE_PASSES = 64

# the topology's arrays impact_resolve reads, in its order
TOPOLOGY = ("triangles", "vertex_owner", "edge_owner", "node", "prim", "adjacency", "flip", "interior", "vt_ptr", "vt_tri",
            "patch", "loop", "loop_off")
COUNTS = ("candidates", "collisions", "excluded", "crossing_only", "impulses", "impulse_passes", "zone_passes",
          "zones", "zone_vertices", "unresolved", "rigid_cloth", "moved", "immovable", "patches_free")


def tables(triangles, n):
    """The topology's tables for impact.c (a dict): vertex_owner (n,), the one triangle that tests each
    vertex (the lowest-numbered one holding it; -1 for a vertex in none); edge_owner (m, 3) bool,
    per triangle and edge slot k (corners k, k+1 mod 3) whether the triangle is the lowest-numbered
    one holding that edge; adjacency (m, 3), the triangle across edge k (-1: none, -2: the edge has
    more than two triangles); flip (m, 3) bool, whether that neighbour runs the edge the same way
    (opposite winding); interior (n,) bool, the vertices with a closed fan; vt_ptr (n + 1), vt_tri:
    each vertex's triangles."""
    t = np.asarray(triangles, np.int64).reshape(-1, 3)
    m = t.shape[0]
    vown = np.full(n, m, np.int64)
    np.minimum.at(vown, t.reshape(-1), np.repeat(np.arange(m, dtype=np.int64), 3))
    vown[vown == m] = -1
    a = t.reshape(-1)
    b = t[:, [1, 2, 0]].reshape(-1)
    key = np.minimum(a, b) * max(n, 1) + np.maximum(a, b)
    tri = np.repeat(np.arange(m, dtype=np.int64), 3)
    uniq, inv = np.unique(key, return_inverse=True)
    inv = inv.reshape(-1)
    first = np.full(uniq.size, m, np.int64)
    np.minimum.at(first, inv, tri)
    eown = (first[inv] == tri).reshape(m, 3)
    count = np.bincount(inv, minlength=uniq.size)
    adj = np.full(3 * m, -1, np.int64)
    flip = np.zeros(3 * m, bool)
    adj[count[inv] > 2] = -2
    two = np.flatnonzero(count[inv] == 2)
    order = two[np.argsort(inv[two], kind="stable")]  # the two half-edges of each edge side by side
    h1, h2 = order[0::2], order[1::2]
    adj[h1], adj[h2] = h2 // 3, h1 // 3
    same = a[h1] == a[h2]
    flip[h1], flip[h2] = same, same
    # a vertex inside the cloth: every edge at it has two consistently wound triangles (its fan is
    # closed; impact.c finds a vertex with two closed fans by their winding)
    interior = np.zeros(n, bool)
    interior[a] = True
    bad = (adj < 0) | flip
    interior[a[bad]] = False
    interior[b[bad]] = False
    vt_tri = (np.argsort(a, kind="stable") // 3).astype(np.int64)
    vt_ptr = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(a, minlength=n), out=vt_ptr[1:])
    return {"vertex_owner": np.ascontiguousarray(vown), "edge_owner": np.ascontiguousarray(eown),
            "adjacency": adj.reshape(m, 3), "flip": flip.reshape(m, 3), "interior": interior, "vt_ptr": vt_ptr,
            "vt_tri": vt_tri}


def loop_offsets(node):
    """Room for each tree node's boundary loop (its triangles + 2) as offsets (nnodes + 1): a node's
    triangles are its leaves' rows (impact.c)."""
    k = node.shape[0]
    size = np.zeros(k, np.int64)
    leaf = node[:, 0] < 0
    size[leaf] = node[leaf, 1]
    for i in np.flatnonzero(~leaf)[::-1].tolist():  # children come after their parent
        size[i] = size[node[i, 0]] + size[node[i, 1]]
    off = np.zeros(k + 1, np.int64)
    np.cumsum(size + 2, out=off[1:])
    return off


def start_positions(x0, events, end):
    """The step's start positions in the numbering after it (``end``: its end positions): rows of
    vertices a fragment took deleted, vertices a tear made placed where their parents started
    (weights of the events), in the order made (a parent may be new itself). Returns (positions,
    how many new vertices had no known parent and start where they end)."""
    n = end.shape[0]
    x = np.asarray(x0, np.float64)
    if events:
        removed = np.asarray(events.get("removed_vertices", np.zeros(0)), np.int64).reshape(-1)
        if removed.size:
            x = np.delete(x, removed[(removed >= 0) & (removed < x.shape[0])], axis=0)
    if x.shape[0] == n:
        return np.ascontiguousarray(x), 0
    out = np.empty((n, 3))
    m = min(x.shape[0], n)
    out[:m] = x[:m]
    known = np.zeros(n, bool)
    known[:m] = True
    if events:
        new = np.asarray(events.get("new_vertices", np.zeros(0)), np.int64).reshape(-1)
        parents = np.asarray(events.get("parents", np.zeros((0, 2))), np.int64).reshape(-1, 2)
        weights = np.asarray(events.get("weights", np.ones(new.size)), np.float64).reshape(-1)
        for v, (a, b), w in zip(new.tolist(), parents.tolist(), weights.tolist()):
            if not (0 <= v < n and 0 <= a < n and known[a]):
                continue
            b = b if 0 <= b < n and known[b] else a
            out[v] = w * out[a] + (1.0 - w) * out[b]
            known[v] = True
    unknown = ~known
    out[unknown] = end[unknown]
    return out, int(unknown.sum())


class ImpactGuard:
    """The impact guard of one session's cloth (see the module docs). ``thickness`` (m): the
    cloth's contact thickness, of which GAP_FRACTION is the guard's gap."""

    def __init__(self, thickness, impulse_passes=IMPULSE_PASSES, zone_passes=ZONE_PASSES):
        thickness = float(thickness)
        if not np.isfinite(thickness) or thickness <= 0:
            raise ValueError(f"thickness must be a positive distance in metres, got {thickness!r}")
        self.gap = GAP_FRACTION * thickness
        self.impulse_passes = int(impulse_passes)
        self.zone_passes = int(zone_passes)
        self.totals = dict.fromkeys(COUNTS + ("start_unknown",), 0)
        self.totals["steps"] = 0
        self._topo = None

    # the tree and owners are a function of the topology and rest positions: never saved
    def __getstate__(self):
        state = dict(self.__dict__)
        state["_topo"] = None
        return state

    def _topology(self, triangles, rest):
        tri = np.asarray(triangles)
        topo = self._topo
        # the tree is a function of the triangles and the rest shape, rebuilt when either changed:
        # an uninterrupted run and a resumed one then build the same tree at the same step, so
        # they find the collisions in the same order (resume equality)
        if topo is not None and topo["source"].shape == tri.shape and topo["rest"].shape == rest.shape \
                and np.array_equal(topo["source"], tri) and np.array_equal(topo["rest"], rest):
            return topo
        t64 = np.ascontiguousarray(tri, np.int64).reshape(-1, 3)
        n, m = rest.shape[0], t64.shape[0]
        tab = tables(t64, n)
        rows = max(2 * m, 1)
        node = np.empty((rows, 2), np.int64)
        prim = np.empty(m, np.int64)
        # the cloth's tree over its rest shape (bvh.c): refitted to the step's swept boxes in impact.c
        used = _collide.bvh_build(positions=rest, triangles=t64, scene_ptr=np.array([0, m], np.int64),
                                  scene_triangles=np.arange(m, dtype=np.int64), node_ptr=np.empty(2, np.int64),
                                  node=node, box=np.empty((rows, 6)), prim=prim)
        node = np.ascontiguousarray(node[:used])
        off = loop_offsets(node)
        # patch / loop: which tree nodes are disks and their boundary loops, found by impact.c when
        # first needed and kept until the topology changes
        self._topo = {"source": tri.copy(), "rest": rest.copy(), "triangles": t64, **tab, "node": node, "prim": prim,
                      "patch": np.full(used, -1, np.int64), "loop": np.zeros(int(off[-1]), np.int64), "loop_off": off}
        return self._topo

    def resolve(self, cloth, x0, events, dt):
        """Make the step just taken (``cloth`` now at its end, ``x0`` its positions at the start in
        the numbering before the step, ``events`` its TopologyEvents, ``dt`` s) free of
        self-crossings; returns the step's counts (impact.c's tcc_impact_counts)."""
        x1 = np.array(cloth.positions, np.float64)
        start, unknown = start_positions(x0, events, x1)
        rest = np.ascontiguousarray(cloth.rest_positions, np.float64)
        topo = self._topology(cloth.triangles, rest)
        v = np.array(cloth.velocities, np.float64)
        counts = _collide.impact_resolve(
            start=start, end=x1, velocity=v, mass=np.ascontiguousarray(cloth.masses, np.float64), rest=rest,
            **{k: topo[k] for k in TOPOLOGY}, dt=float(dt), gap=self.gap, rest_fraction=REST_FRACTION,
            min_rest=MIN_REST, impulse_passes=self.impulse_passes, zone_passes=self.zone_passes)
        if counts["moved"]:
            cloth.set_positions(x1)
            cloth.set_velocities(v)
        counts["start_unknown"] = unknown
        for k, c in counts.items():
            self.totals[k] += c
        self.totals["steps"] += 1
        if counts["rigid_cloth"]:
            warnings.warn("impact guard: the zone pass cap was hit; the whole cloth moved rigidly for a step "
                          "(counted in the step report's impact['rigid_cloth'])", RuntimeWarning, stacklevel=3)
        return counts
