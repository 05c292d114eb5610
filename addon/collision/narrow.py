"""Ray-traced narrow phase: Embree scenes per cluster, contact classification, the Contacts type.

This file owns (1) how a cloth vertex's rays are cast into a collider with embreex, (2) how a hit
becomes a contact (inside a closed body, within thickness of a surface, or inverted through a
sheet), and (3) the ``Contacts`` arrays handed to the native solver.

Rays. From every cloth vertex two rays (slot 0 along +n, slot 1 along -n, n the area-weighted
vertex normal) are cast into each collider (the cloth itself for self-collision). A hit is
refined on the *current* geometry by the exact walker of ``incremental.py`` and then judged by
the signed distance sd of the vertex to the hit triangle's plane (sd > 0 on the side the
triangle normal points to):

* closed body ("volume"): the vertex is inside iff sd < 0 for the nearest hit along its normal
  line (a ray from inside a closed surface leaves through a back face). Inside: normal = face
  normal, depth = |sd| + thickness; outside with sd < thickness: depth = thickness - sd. The
  push-out distance is the plane distance of the exit triangle, not the distance along the ray:
  the face normal is the shortest way out locally and it is what the solver resolves along.
* thin surface (cloth, or a body whose mesh is open): contact when |sd| < thickness on the
  vertex's side, depth = thickness - |sd|. Each track remembers that side; a vertex found on the
  other side since (it crossed the sheet) is pushed back: normal toward the remembered side,
  depth = |sd| + thickness. A brand-new hit takes its side from the previous step's positions
  when the vertex crossed the triangle during the last step, else from the current side.
  Self-collision never accepts a triangle of the vertex's own one-ring.

Scenes: the embreex cost model (measured, shared/notes/collision.md and ``bench.py``): building a
scene copies ~1.4 µs per triangle plus the BVH build on first query (a 200-triangle cluster scene
costs 0.3-0.8 ms to build and query once), while casting 200 rays into it costs 17-60 µs and a
call's overhead is ~5 µs. A whole 8K-triangle body rebuilt every step would be ~14 ms. So scenes are
per *cluster* of the target, built lazily on the first full detection that needs them, and kept
in the cluster's frame of reference: each query fits the rigid motion (Kabsch) of the cluster's
vertices since the build and casts the rays transformed into the build frame. A scene is rebuilt
only when the cluster's non-rigid residual exceeds ``tolerance``. A skinned limb or a cloth tube
moving with it keeps its scenes for the whole animation. Because the scene may be up to
``tolerance`` stale, its hit is only a candidate: the walker re-finds the exact triangle on the
current vertices.

The alternative, exact numpy tests of every candidate ray against every triangle of a cluster
pair, costs 6.7 ms for 200 rays x 200 triangles (``bench.numpy_vs_embree``: Embree build + query
0.31 ms, query into the cached scene 0.06 ms), so even a scene rebuilt for a single query beats
it 20x; the rigid-frame cache makes rebuilds rare (stand-in bench: every scene built once in 80
moving steps). What remains per full-detected cluster is Python overhead: the Kabsch fit
(~0.12 ms) and the cast wrapper (~0.12 ms), ~0.25 ms per collider cluster queried.

Units: metres; velocities in m/s.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh

from .incremental import cross, excluded, walk

__all__ = [
    "Contacts",
    "vertex_normals",
    "VertexNormals",
    "face_normals",
    "ClusterScenes",
    "build_scene",
    "cast",
    "initial_side",
]

RAY_BACKOFF = 1e-6  # metres: rays start this far behind the vertex so touching surfaces count


@dataclass
class Contacts:
    """Contacts for the native solver, one row per cloth vertex in contact (deepest kept).

    vertex (k,) int32 cloth vertex; normal (k,3) unit push-out direction; depth (k,) metres to
    move along normal to be resolved (>= 0); velocity (k,3) m/s of the touched surface point;
    friction (k,) coefficient.
    """

    vertex: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    normal: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    depth: np.ndarray = field(default_factory=lambda: np.zeros(0))
    velocity: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    friction: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __len__(self):
        return int(self.vertex.shape[0])

    @staticmethod
    def deepest(vertex, normal, depth, velocity, friction):
        """Keep, per vertex, the row of greatest depth; rows sorted by vertex."""
        vertex = np.asarray(vertex, np.int64)
        if vertex.size == 0:
            return Contacts()
        order = np.lexsort((-depth, vertex))
        first = np.ones(order.size, bool)
        first[1:] = vertex[order[1:]] != vertex[order[:-1]]
        sel = order[first]
        return Contacts(
            vertex=vertex[sel].astype(np.int32),
            normal=np.ascontiguousarray(normal[sel], np.float64),
            depth=np.ascontiguousarray(depth[sel], np.float64),
            velocity=np.ascontiguousarray(velocity[sel], np.float64),
            friction=np.ascontiguousarray(friction[sel], np.float64),
        )


def face_normals(positions, triangles):
    """Unit normals (m,3) of the triangles (zero for degenerate ones) and their doubled areas."""
    tri = triangles
    a = positions[tri[:, 0]]
    cr = cross(positions[tri[:, 1]] - a, positions[tri[:, 2]] - a)
    length = np.sqrt(np.einsum("ij,ij->i", cr, cr))
    return cr / np.where(length > 0, length, 1.0)[:, None], length


class VertexNormals:
    """Area-weighted unit vertex normals for a fixed topology; the corner -> vertex grouping is
    computed once so each step is one np.add.reduceat instead of three bincounts."""

    def __init__(self, n, triangles):
        corners = np.asarray(triangles, np.int64).reshape(-1)
        self.n = int(n)
        self.order = np.argsort(corners, kind="stable")
        self.tri_of_corner = self.order // 3
        counts = np.bincount(corners, minlength=self.n)
        self.used = np.flatnonzero(counts)
        self.starts = (np.cumsum(counts) - counts)[self.used]
        self.triangles = triangles

    def __call__(self, positions):
        tri = self.triangles
        a = positions[tri[:, 0]]
        cr = cross(positions[tri[:, 1]] - a, positions[tri[:, 2]] - a)  # |cr| = 2 * area
        acc = np.zeros((self.n, 3))
        if self.used.size:
            acc[self.used] = np.add.reduceat(cr[self.tri_of_corner], self.starts, axis=0)
        length = np.sqrt(np.einsum("ij,ij->i", acc, acc))
        return acc / np.where(length > 0, length, 1.0)[:, None]


def vertex_normals(positions, triangles):
    """Area-weighted unit vertex normals (n,3); zero for vertices of no (non-degenerate) triangle."""
    return VertexNormals(positions.shape[0], triangles)(positions)


def build_scene(vertices, triangles):
    """An embreex scene of the given triangles (float32 copy; this is the ~1.4 µs/triangle)."""
    scene = rtcore_scene.EmbreeScene()
    TriangleMesh(scene, np.ascontiguousarray(vertices, np.float32), np.ascontiguousarray(triangles, np.int32))
    return scene


def ring_table(triangles, n):
    """(n, K) table of each vertex's one-ring neighbours and itself, padded with -1.

    Self-collision ignores every triangle that touches this set (the vertex's two-ring): in a
    cloth bent more tightly than its thickness, two-ring triangles come within the contact
    distance along the normal, and such "contacts" with the vertex's own neighbourhood fought
    the bending (measured: over half of the self contacts of a cloth draped on a sphere were of
    this kind, and they pumped the drape to 20 m/s)."""
    t = np.asarray(triangles, np.int64)
    a = np.concatenate([t[:, 0], t[:, 0], t[:, 1], t[:, 1], t[:, 2], t[:, 2], np.arange(n)])
    b = np.concatenate([t[:, 1], t[:, 2], t[:, 0], t[:, 2], t[:, 0], t[:, 1], np.arange(n)])
    key = np.unique(a * (n + 1) + b)
    a, b = key // (n + 1), key % (n + 1)
    counts = np.bincount(a, minlength=n)
    width = int(counts.max()) if counts.size else 1
    table = np.full((n, width), -1, np.int64)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    col = np.arange(a.size) - start[a]
    table[a, col] = b
    return table


def cast(scene, origins, directions, max_dist, prim_to_tri, exclude=None, triangles=None, rounds=8):
    """First hit of each ray in ``scene``: (global triangle or -1, t along the ray).

    Rays start RAY_BACKOFF behind the origin. With ``exclude`` (a vertex per ray, or a ring-table
    row per ray, see ``excluded``) hits on the excluded triangles are skipped by re-casting from
    just beyond them: embreex has no filter callback.
    """
    k = origins.shape[0]
    tri_out = np.full(k, -1, np.int64)
    t_out = np.full(k, np.inf)
    if k == 0:
        return tri_out, t_out
    o = origins - RAY_BACKOFF * directions
    travelled = np.full(k, -RAY_BACKOFF)
    remaining = np.broadcast_to(np.asarray(max_dist, np.float64), (k,)) + RAY_BACKOFF
    act = np.arange(k)
    for _ in range(rounds):
        res = scene.run(
            o[act].astype(np.float32),
            directions[act].astype(np.float32),
            dists=remaining[act].astype(np.float32),
            output=1,
        )
        prim = res["primID"].astype(np.int64)
        t = res["tfar"].astype(np.float64)
        hit = prim >= 0
        gtri = np.where(hit, prim_to_tri[np.maximum(prim, 0)], -1)
        retry = np.zeros(act.size, bool)
        if exclude is not None:
            own = hit & excluded(triangles[np.maximum(gtri, 0)], exclude[act])
            retry = own
        done = hit & ~retry
        tri_out[act[done]] = gtri[done]
        t_out[act[done]] = travelled[act[done]] + t[done]
        if not retry.any():
            break
        r = act[retry]
        step = t[retry] + 1e-7  # float32 scene: step past the own triangle by ~1 ulp at 1 m
        o[r] += step[:, None] * directions[r]
        travelled[r] += step
        remaining[r] -= step
        act = r[remaining[r] > 0]
        if act.size == 0:
            break
    return tri_out, t_out


class _ClusterScene:
    __slots__ = ("scene", "tri", "verts", "ref", "ref_centre", "fit_step", "R", "centre", "builds")


class ClusterScenes:
    """Lazily built Embree scenes, one per cluster of one collider, valid up to rigid motion.

    ``tolerance`` (m): largest non-rigid residual of a cluster's vertices (after the best rigid
    fit since the build) for which its scene is reused.
    """

    def __init__(self, tolerance):
        self.tolerance = float(tolerance)
        self._cache = {}
        self.builds = 0  # scenes (re)built, for stats
        self.build_triangles = 0

    def invalidate(self, clusters=None):
        if clusters is None:
            self._cache.clear()
        else:
            for c in np.asarray(clusters).reshape(-1).tolist():
                self._cache.pop(int(c), None)

    def _build(self, c, positions, triangles, tri_ids):
        cs = _ClusterScene()
        tri = triangles[tri_ids]
        verts, local = np.unique(tri.reshape(-1), return_inverse=True)
        cs.tri = tri_ids
        cs.verts = verts
        cs.ref = positions[verts].copy()
        cs.ref_centre = cs.ref.mean(axis=0)
        cs.scene = build_scene(cs.ref, local.reshape(-1, 3))
        cs.fit_step = -1
        cs.R = np.eye(3)
        cs.centre = cs.ref_centre.copy()
        self._cache[c] = cs
        self.builds += 1
        self.build_triangles += tri_ids.size
        return cs

    def _fit(self, cs, positions, step):
        """Rigid fit of the cluster's current vertices to the build pose; False if too deformed."""
        if cs.fit_step == step:
            return True
        cur = positions[cs.verts]
        centre = cur.mean(axis=0)
        x0 = cs.ref - cs.ref_centre
        x1 = cur - centre
        u, _, vt = np.linalg.svd(x0.T @ x1)
        d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
        R = vt.T @ np.diag([1.0, 1.0, d]) @ u.T  # x1 ≈ R x0
        resid = x0 @ R.T - x1
        if np.einsum("ij,ij->i", resid, resid).max(initial=0.0) > self.tolerance**2:
            return False
        cs.R, cs.centre, cs.fit_step = R, centre, step
        return True

    def query(self, c, tri_ids, positions, triangles, origins, directions, max_dist, step, exclude=None):
        """Candidate first hits of rays in cluster ``c`` of this collider: (triangle, t)."""
        cs = self._cache.get(c)
        if cs is not None and not self._fit(cs, positions, step):
            cs = None
        if cs is None:
            cs = self._build(c, positions, triangles, tri_ids)
            cs.fit_step = step
        # World -> build frame: x0 = R^T (x - centre) + ref_centre (row vectors: (x - c) @ R).
        o = (origins - cs.centre) @ cs.R + cs.ref_centre
        d = directions @ cs.R
        return cast(cs.scene, o, d, max_dist + self.tolerance, cs.tri, exclude, triangles)


def initial_side(x_prev, x_now, tri_prev, tri_now):
    """Side (+1/-1 along the triangle normal) a vertex comes from, for a new track.

    x_*: (k,3) vertex positions at the previous and current step; tri_*: (k,3,3) triangle corner
    positions. If the vertex crossed the triangle's plane during the step *inside* the triangle
    (relative motion, linear in time), the side before the crossing; otherwise the current side.
    """
    def sd(x, t):
        nrm = cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1), 1e-30)[:, None]
        return np.einsum("ij,ij->i", x - t[:, 0], nrm)

    s_now = sd(x_now, tri_now)
    s_prev = sd(x_prev, tri_prev)
    side = np.where(s_now >= 0, 1, -1).astype(np.int8)
    crossed = (np.sign(s_prev) * np.sign(s_now)) < 0
    if crossed.any():
        i = np.flatnonzero(crossed)
        alpha = (s_prev[i] / (s_prev[i] - s_now[i]))[:, None]
        x = (1 - alpha) * x_prev[i] + alpha * x_now[i]
        t = (1 - alpha[:, None]) * tri_prev[i] + alpha[:, None] * tri_now[i]
        # Barycentrics of x in the interpolated triangle (x lies in its plane at the crossing).
        e1, e2, ex = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0], x - t[:, 0]
        d11 = np.einsum("ij,ij->i", e1, e1)
        d12 = np.einsum("ij,ij->i", e1, e2)
        d22 = np.einsum("ij,ij->i", e2, e2)
        d1x = np.einsum("ij,ij->i", e1, ex)
        d2x = np.einsum("ij,ij->i", e2, ex)
        den = np.maximum(d11 * d22 - d12 * d12, 1e-30)
        v = (d22 * d1x - d12 * d2x) / den
        w = (d11 * d2x - d12 * d1x) / den
        through = (v >= -1e-6) & (w >= -1e-6) & (v + w <= 1 + 1e-6)
        side[i[through]] = np.where(s_prev[i[through]] >= 0, 1, -1)
    return side
