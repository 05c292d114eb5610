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

Trees: every collider - the cloth itself and each body - is a set of native BVHs, one per
cluster over its triangles and their edge neighbours, built once per topology and refitted each
step the detector first casts into them (``ClusterBVH``, ``native/collide/bvh.c`` says why). Its
hits are exact on the current geometry.

Embree (``ClusterScenes``, ``build_scene``, ``cast``): the previous release kept each body cluster
as an embreex scene in the pose it was built in, fitted rigidly each query (Horn's method, C) and
rebuilt past a non-rigid ``tolerance``, its candidates refined by the walker. Measured on the
T-shirt simulated on the walking mannequin (bench ``collision.simulated``), the detector's step in
C with native trees for the bodies gives the same contacts bit for bit at half the CPU or less,
with no scene builds, rigid fits or Python per cluster; embreex offers neither a refit nor a C
entry point that would let one call per step serve every cluster's scene. The Embree scenes stay
here for the test oracles (brute force, the reference detector) and for unpickling a detector
the previous release saved (it gets native trees when it resumes).

Units: metres; velocities in m/s.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from embreex import rtcore, rtcore_scene
from embreex.mesh_construction import TriangleMesh

from .. import _collide
from .incremental import barycentric, cross, excluded

__all__ = [
    "Contacts",
    "vertex_normals",
    "VertexNormals",
    "face_normals",
    "ClusterScenes",
    "ClusterBVH",
    "scene_triangles",
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


_DEVICE = None  # one Embree device for every scene: creating one per scene cost ~80 µs a build
_OBJECT_ROWS = True  # see build_scene


def _device():
    global _DEVICE
    if _DEVICE is None:
        _DEVICE = rtcore.EmbreeDevice()
    return _DEVICE


def build_scene(vertices, triangles):
    """An embreex scene of the given triangles.

    embreex copies the arrays element by element through Python indexing (~1.4 µs per triangle
    with numpy arrays: every ``indices[i][k]`` makes a row view first). Handing it an object array
    of Python floats and a 1-D object array of per-triangle lists makes each read a plain item
    fetch: ~2.5x faster builds. Should an embreex release type its arguments, the plain float32 /
    int32 arrays are used instead."""
    global _OBJECT_ROWS
    scene = rtcore_scene.EmbreeScene(_device())
    if _OBJECT_ROWS:
        try:
            rows = np.empty(len(triangles), object)
            rows[:] = np.asarray(triangles, np.int64).tolist()
            TriangleMesh(scene, np.asarray(vertices, np.float64).astype(object), rows)
            return scene
        except (TypeError, ValueError):
            _OBJECT_ROWS = False
            scene = rtcore_scene.EmbreeScene(_device())
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


def scene_triangles(triangles, clustering, adj):
    """(ptr (k+1), tri): cluster c's scene triangles tri[ptr[c]:ptr[c+1]], ascending - its own
    and their neighbours across an edge (the margin: a ray meeting the cluster at its border
    still finds a candidate there, whichever cluster the exact triangle is in)."""
    m = int(triangles.shape[0])
    k = clustering.n_clusters
    lab = clustering.tri_labels
    f = np.arange(m, dtype=np.int64)
    nb = adj.reshape(-1)
    ok = nb >= 0
    key = np.unique(np.concatenate([lab * m + f, np.repeat(lab, 3)[ok] * m + nb[ok]]))
    ptr = np.zeros(k + 1, np.int64)
    np.cumsum(np.bincount(key // m, minlength=k), out=ptr[1:])
    return ptr, key % m


class ClusterScenes:
    """Lazily built Embree scenes, one per cluster of one collider, valid up to rigid motion.

    ``tolerance`` (m): largest non-rigid residual of a scene's corners (after the best rigid fit
    since the build) for which its scene is reused. A scene holds the cluster's triangles plus a
    margin, their neighbours across an edge: a ray that meets the cluster near its border, where
    the stale pose may have moved the border by up to the tolerance, still finds a candidate (the
    walker then steps to the exact triangle, in whichever cluster it is).

    Layout, for the C kernels: scene c's triangles are ``tri[ptr[c]:ptr[c + 1]]`` (fixed by the
    topology), ``ref`` (same rows, 3, 3) their corners when the scene was built, and ``R`` (K, 3, 3),
    ``centre``, ``ref_centre`` (K, 3) the world -> build frame transform of the last fit:
    x_build = R^T (x - centre) + ref_centre. ``scene[c]`` is the embreex scene or None.
    """

    def __init__(self, tolerance):
        self.tolerance = float(tolerance)
        self.builds = 0  # scenes (re)built, for stats
        self.build_triangles = 0
        self.ptr = np.zeros(1, np.int64)
        self.tri = np.zeros(0, np.int64)
        self.ref = np.zeros((0, 3, 3))
        self.scene = []
        self.fit_step = np.zeros(0, np.int64)
        self.R = np.zeros((0, 3, 3))
        self.centre = np.zeros((0, 3))
        self.ref_centre = np.zeros((0, 3))

    def set_topology(self, triangles, clustering, adj):
        """Each cluster's scene triangles (its own plus their edge neighbours). A built scene whose
        triangle list did not change keeps its scene, reference corners and transform."""
        k = clustering.n_clusters
        ptr, tri = scene_triangles(triangles, clustering, adj)
        ref = np.zeros((tri.size, 3, 3))
        scene = [None] * k
        R = np.tile(np.eye(3), (k, 1, 1))
        centre, ref_centre = np.zeros((k, 3)), np.zeros((k, 3))
        for c in range(min(k, len(self.scene))):
            old = self.tri[self.ptr[c]:self.ptr[c + 1]]
            if self.scene[c] is not None and np.array_equal(old, tri[ptr[c]:ptr[c + 1]]):
                scene[c] = self.scene[c]
                ref[ptr[c]:ptr[c + 1]] = self.ref[self.ptr[c]:self.ptr[c + 1]]
                R[c], centre[c], ref_centre[c] = self.R[c], self.centre[c], self.ref_centre[c]
        self.ptr, self.tri, self.ref, self.scene = ptr, tri, ref, scene
        self.R, self.centre, self.ref_centre = R, centre, ref_centre
        self.fit_step = np.full(k, -1, np.int64)

    def triangles(self, c):
        return self.tri[self.ptr[c]:self.ptr[c + 1]]

    def invalidate(self, clusters=None, triangles=None):
        """Drop the scenes of these clusters (all when both are None) and of any cluster whose
        scene holds one of these triangles (a margin reaches into the neighbours)."""
        if clusters is None and triangles is None:
            self.scene = [None] * len(self.scene)
            return
        drop = set()
        if clusters is not None:
            drop |= {int(c) for c in np.asarray(clusters).reshape(-1).tolist() if 0 <= c < len(self.scene)}
        if triangles is not None and len(triangles):
            hit = np.isin(self.tri, np.asarray(triangles, np.int64).reshape(-1))
            drop |= set((np.searchsorted(self.ptr, np.flatnonzero(hit), side="right") - 1).tolist())
        for c in drop:
            self.scene[c] = None

    def _build(self, c, positions, triangles):
        s, e = self.ptr[c], self.ptr[c + 1]
        tri = triangles[self.tri[s:e]]
        verts, local = np.unique(tri.reshape(-1), return_inverse=True)
        corners = positions[tri]
        self.ref[s:e] = corners  # the scene's frame is the pose it is built in
        self.R[c] = np.eye(3)
        self.ref_centre[c] = self.centre[c] = corners.reshape(-1, 3).mean(axis=0)
        self.scene[c] = build_scene(positions[verts], local.reshape(-1, 3))
        self.builds += 1
        self.build_triangles += int(e - s)

    # A resumed bake needs these scenes as they were, not rebuilt from the resume frame's pose
    # (their reuse within the tolerance shapes the candidates): pickling keeps which scenes were
    # built and their build corners (ref); ``rebuild`` makes the same scenes from those corners.
    def __getstate__(self):
        state = dict(self.__dict__)
        state["scene"] = [s is not None for s in self.scene]
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._unbuilt = [bool(b) for b in self.scene]
        self.scene = [None] * len(self.scene)

    def rebuild(self, triangles):
        """After unpickling: the scenes that were built, from their build corners."""
        for c, was in enumerate(getattr(self, "_unbuilt", ())):
            if was:
                s, e = self.ptr[c], self.ptr[c + 1]
                verts, first, local = np.unique(triangles[self.tri[s:e]].reshape(-1), return_index=True,
                                                return_inverse=True)
                self.scene[c] = build_scene(self.ref[s:e].reshape(-1, 3)[first], local.reshape(-1, 3))
        self._unbuilt = []

    def fit(self, clusters, positions, triangles, step):
        """Make the scenes of ``clusters`` usable this step: one C call fits every built one (its
        transform lands in R, centre, ref_centre); those that deformed more than the tolerance,
        and those never built, are built now. Returns a bool mask of the clusters that have a
        scene (a cluster without triangles has none)."""
        clusters = np.asarray(clusters, np.int64)
        todo = clusters[self.fit_step[clusters] != step]
        if todo.size:
            built = np.array([self.scene[c] is not None for c in todo.tolist()], bool)
            fit = todo[built]
            if fit.size:
                resid2 = np.empty(fit.size)
                _collide.rigid_fit_many(positions, triangles, self.ptr, self.tri, self.ref, fit, self.R, self.centre,
                                        self.ref_centre, resid2)
                stale = fit[~(resid2 <= self.tolerance**2)]
            else:
                stale = fit
            for c in np.concatenate([todo[~built], stale]).tolist():
                if self.ptr[c + 1] > self.ptr[c]:
                    self._build(c, positions, triangles)
            self.fit_step[todo] = step
        return self.ptr[clusters + 1] > self.ptr[clusters]

    def query(self, c, tri_ids, positions, triangles, origins, directions, max_dist, step, exclude=None):
        """Candidate first hits of rays in cluster ``c`` of this collider: (triangle, t).
        (One cluster at a time, world-frame rays; the detector batches through ``kernels``.)"""
        if not self.fit(np.array([c]), positions, triangles, step)[0]:
            k = origins.shape[0]
            return np.full(k, -1, np.int64), np.full(k, np.inf)
        R, centre, ref_centre = self.R[c], self.centre[c], self.ref_centre[c]
        # World -> build frame: x0 = R^T (x - centre) + ref_centre (row vectors: (x - c) @ R).
        o = (origins - centre) @ R + ref_centre
        d = directions @ R
        return cast(self.scene[c], o, d, max_dist + self.tolerance, self.triangles(c), exclude, triangles)


class ClusterBVH:
    """A collider's clusters as native BVHs (``native/collide/bvh.c``): the cloth's own and each
    body's.

    Why not Embree: a cloth cluster deforms every step, so its Embree scene, reusable only up to a
    rigid motion, was rebuilt in most steps (T-shirt at 10 sub-steps per frame: 12.5 of 18 clusters
    per step, 5.3 ms of bookkeeping, per-triangle copies through Python and Embree builds), and
    embreex has neither a refit nor a hit filter; for bodies, see the module docs. A tree per cluster over the same scene
    triangles as ``ClusterScenes`` (own + edge neighbours) is built once per topology, in C, for
    the whole cloth (``build``); a step refits, bottom-up from the current positions, only the
    trees its rays reach, and skips the two-ring inside the traversal. Its boxes are exact, so
    ``tolerance`` is 0: no staleness margin on the rays, no rigid frame.

    Layout (the C's, ``collide.h`` tcc_bvh): cluster c's nodes ``node[node_ptr[c]:node_ptr[c+1]]``
    (inner: two children; leaf: -1 - first, count into ``prim``), ``box`` (N, 6) lo, hi;
    ``refit_step[c]`` the step its boxes are of; ``corner`` (rows, 9) each prim's corners as of its
    last refit (the traversal reads them there). Plain arrays: they pickle as they are.
    """

    tolerance = 0.0

    def __init__(self):
        self.builds = 0  # whole-forest builds (one per topology), for stats
        self.build_triangles = 0
        self.ptr = np.zeros(1, np.int64)
        self.tri = np.zeros(0, np.int64)
        self.built = False
        self._hits = _hit_buffers(0)

    def set_topology(self, triangles, clustering, adj):
        """New scene triangles per cluster; the forest is rebuilt at the next cast."""
        self.ptr, self.tri = scene_triangles(triangles, clustering, adj)
        self.refit_step = np.full(clustering.n_clusters, -1, np.int64)
        self.built = False

    def invalidate(self, clusters=None, triangles=None):
        """A tear: rebuild the whole forest at the next cast (one C pass over the cloth, cheaper
        than keeping the untouched clusters' trees in step with the renumbered rows)."""
        self.built = False

    def rebuild(self, triangles):
        """Nothing to do after unpickling: the trees are plain arrays."""

    def __setstate__(self, state):
        self.__dict__.update(state)
        if self.__dict__.get("built") and "corner" not in state:
            # saved before the trees kept their corners: refitted (and so written) at the next cast
            self.corner = np.zeros((self.prim.size, 9))
            self.refit_step = np.full(self.refit_step.size, -1, np.int64)

    def build(self, positions, triangles):
        k = self.ptr.size - 1
        rows = self.tri.size
        self.node_ptr = np.empty(k + 1, np.int64)
        node = np.empty((max(2 * rows, 1), 2), np.int64)
        box = np.empty((max(2 * rows, 1), 6))
        self.prim = np.empty(rows, np.int64)
        used = _collide.bvh_build(positions=positions, triangles=triangles, scene_ptr=self.ptr,
                                  scene_triangles=self.tri, node_ptr=self.node_ptr, node=node, box=box, prim=self.prim)
        self.node, self.box = node[:used].copy(), box[:used].copy()
        self.corner = np.zeros((rows, 9))  # each prim's corners, written by its refit (bvh.c)
        self.refit_step = np.full(k, -1, np.int64)
        self.built = True
        self.builds += 1
        self.build_triangles += rows

    def cast_self(self, positions, normals, has_normal, clustering, box_lo, box_hi, triangles, ring, pair_a, pair_b,
                  step, dist, backoff):
        """Every close pair's rays (pair_a's vertices, +n and -n, from ``backoff`` behind, length
        ``dist``, culled against pair_b's box) cast into pair_b's tree, the two-ring skipped: one
        C call. Returns (ray vertex, slot, hit triangle) of the rays that hit, and the rays cast."""
        if not self.built:
            self.build(positions, triangles)
        cp = clustering.ptr
        cap = 2 * int((cp[pair_a + 1] - cp[pair_a]).sum())
        if self._hits[0].size < cap:
            self._hits = _hit_buffers(max(cap, 2 * self._hits[0].size))
        rv, rs, hit = self._hits
        nh, nr = _collide.self_cast(
            positions=positions, normals=normals, has_normal=has_normal, order=clustering.order, ptr=cp,
            box_lo=box_lo, box_hi=box_hi, triangles=triangles, node_ptr=self.node_ptr, node=self.node, box=self.box,
            prim=self.prim, refit_step=self.refit_step, step=int(step), ring=ring, pair_a=pair_a, pair_b=pair_b,
            dist=float(dist), backoff=float(backoff), ray_vertex=rv, ray_slot=rs, hit_triangle=hit)
        if nh > rv.size:  # cannot happen (cap bounds every ray), but never read past what was written
            raise RuntimeError(f"self_cast found {nh} hits for room of {rv.size}")
        return rv[:nh], rs[:nh], hit[:nh], nr


def _hit_buffers(cap):
    """Outputs of ``_collide.self_cast`` for ``cap`` rays: ray vertex, slot, hit triangle."""
    return np.empty(cap, np.int64), np.empty(cap, np.int64), np.empty(cap, np.int64)


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
        _, v, w = barycentric(x, t[:, 0], t[:, 1], t[:, 2]).T
        through = (v >= -1e-6) & (w >= -1e-6) & (v + w <= 1 + 1e-6)
        side[i[through]] = np.where(s_prev[i[through]] >= 0, 1, -1)
    return side
