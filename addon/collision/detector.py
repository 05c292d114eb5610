"""CollisionDetector: the per-step orchestration of clustered, ray-traced collision detection.

This file owns the state that lives between steps (previous positions, clusters, per-pair
measures, per-ray tracks, the colliders' trees) and the order of one step; the step itself runs
in C, a handful of calls whatever the mesh (native/collide/: measure.c, detect.c, swept.c), with
numpy arrays in and out and no Python per pair, ray or triangle:

1. measure  – per-cluster displacement since the previous ``detect`` and inflated cluster AABBs
              (one call per object), then per collider its close pairs (cloth-cloth for
              self-collision, cloth-body), the pairs forced to full detection after a tear, and
              the paper's relative measure marking pairs for full detection (one call,
              ``measure.py``; the absolute measure and the motion-bound trip rule add to that
              verdict in numpy).
2-4. per collider, one call (detect.c; none for a collider with no tracked ray and no pair marked full:
   it would merge nothing):
   incremental – every ray tracked from the previous step is walked to its current hit on the
              current geometry (``incremental.py``). A lost walk sends its pair to full
              detection in this same step (not the next one: the step's contact set would
              otherwise miss that vertex once).
   full     – for the marked pairs, each cloth vertex's two rays (+n, -n) in one traversal of
              each collider cluster's tree its line reaches (nearest cluster first; bvh.c, every
              collider - the cloth and the bodies - in native trees refitted the first time a
              step casts into them, ``narrow.ClusterBVH``), the two-ring skipped inside for the
              cloth itself; the hits refined exactly on the current geometry.
   contacts – tracks are merged (nearest hit per vertex and ray), classified, and the deepest
              contact per vertex of the collider returned; over the colliders, the deepest per
              vertex (``detect``'s result) and every one (``all_contacts``).
5. swept    – self-collision of the pairs the rays skip (the two-ring), by swept vertex-triangle
              and edge-edge tests over the step (``swept.py``, two calls); its contacts join
              ``all_contacts``. Its first call, the larger (the cull and the tests: ~2-3 ms a
              sub-step of the race's shirt, as much as steps 1-4), depends on nothing steps 1-4
              make, so it starts first, on a thread of its own when the process may use a second CPU
              (``swept_thread``: an OS thread started in C that never takes the GIL, so it begins at
              once, however long the colliders' Python holds the GIL), and runs beside them; its
              rows are merged after them. The
              contacts are the same bit for bit with or without the thread (test_collision_detect).

The previous release ran steps 2-4 in Python over per-stage kernels, bodies in Embree scenes in
each cluster's rigid frame; tests/collision_reference.py keeps that step (``ReferenceDetector``)
as the specification the C step equals contact for contact.

Tracks: per collider, per cloth vertex, two ray slots (+n, -n) hold the triangle last hit, the
remembered side (thin surfaces) and, for closed bodies, whether the vertex was inside. A full
detection records every hit within ``track_range = thickness + 1.5 * displacement_threshold``
(twice the threshold term with the absolute measure):
between two full detections of a pair the relative motion stays under the threshold, so a
vertex that was not tracked cannot reach the contact distance (the 1.5 covers the measure
being a mean + standard deviation, not a maximum).

Ray length: for the same reason a full detection's rays need only reach ``track_range``, and
that is all they do for thin surfaces and the cloth itself. A closed
body's rays reach across it: a body face that sweeps sideways over a vertex (parallel to its
normal rays) puts it inside with its exits along the normal far away, and only a long ray finds
them. What keeps that affordable: rays are culled against the collider cluster's box, a ray's
nearest hit so far cuts off the clusters beyond it, and a far back face proves "inside" only when
no nearer hit of the same ray disproves it and, failing that, when an exact test on the current
geometry (the trees of the clusters the segment crosses) finds nothing in front of it.

Clearance (issue 15; ``clearance_cap``, default 4, 1 = the paper's rule as published): the paper's
threshold is one margin for every pair - the track range less the thickness - whatever the pair's
geometry. A full detection knows better: every line of the pair's cloth vertices (+n, -n) was
searched, and its nearest hit either lies within the track range (tracked: the walks follow it) or
farther. detect.c reports per pair fully detected that clearance - the nearest untracked hit over its
vertices' lines, no less than the track range, searched up to ``probe_length`` for the cloth and thin
surfaces (a closed body's rays reach across it anyway) - and the pair's relative measure restarts
with the extra margin as a credit (detect.c ``credit_pairs``): it trips at the threshold times
(clearance - thickness) / (track_range - thickness), at most ``clearance_cap`` times it. The argument
is the paper's own (an untracked vertex must move by its margin relative to the other cluster before
it can touch), with the margin measured instead of assumed. Measured on the T-shirt simulated on the
mannequin at dt = 1 ms (bench ``collision.simulated``): cloth-cloth pairs fully detected 7.0 -> 1.3 per
step, cloth-body 13.6 -> 9.5; recall on tests/test_collision_recall.py's scenes unchanged (19679 of
19680 vertices at dt = 1 ms, all 32479 at 4.17 ms, eight scenes each). The contacts do not depend on
the probe: only hits within ``ray_length`` become tracks. The absolute measure and 'full' take no credit
(they are the paper's comparison).

Bodies must be closed (watertight, consistently oriented): then "inside" is well defined. An
open body triggers a ``warnings.warn`` and is handled as a two-sided thin surface with inversion
memory, so it still never lets a vertex tunnel silently. An inward-oriented closed body is
re-oriented.

Units: SI throughout (metres, m/s).
"""
from __future__ import annotations

import os
import time
import warnings

import numpy as np

from .. import _collide
from . import kernels
from .clusters import Clustering
from .incremental import triangle_adjacency
from .measure import (
    MEASURES,
    TRIP_RULES,
    AbsoluteMeasure,
    RelativeMeasure,
    TripMeasure,
)
from .narrow import RAY_BACKOFF, ClusterBVH, ClusterScenes, Contacts, ring_table
from .swept import SweptSelf

__all__ = ["CollisionDetector", "Contacts"]

_SLOT_SIGN = np.array([1.0, -1.0])


def _check_mesh(vertices, triangles, what):
    v = np.asarray(vertices, np.float64)
    t = np.asarray(triangles)
    if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] == 0:
        raise ValueError(f"{what}: vertices must be a non-empty (n, 3) array, got shape {v.shape}")
    if t.size == 0:
        raise ValueError(f"{what}: the mesh has no triangles; nothing could collide with it")
    if t.ndim != 2 or t.shape[1] != 3:
        raise ValueError(f"{what}: triangles must be an (m, 3) integer array, got shape {t.shape}")
    if not np.issubdtype(t.dtype, np.integer):
        raise ValueError(f"{what}: triangles must hold integer vertex indices, got {t.dtype}")
    t = t.astype(np.int64)
    if t.min() < 0 or t.max() >= v.shape[0]:
        raise ValueError(
            f"{what}: triangle indices must lie in [0, {v.shape[0] - 1}], got [{t.min()}, {t.max()}]"
        )
    if not np.isfinite(v).all():
        raise ValueError(f"{what}: vertices contain NaN or infinite coordinates")
    return v.copy(), t


def is_closed(triangles):
    """True when every edge has exactly two triangles that traverse it in opposite directions."""
    tri = np.asarray(triangles, np.int64)
    a = tri.reshape(-1)
    b = tri[:, [1, 2, 0]].reshape(-1)
    n = int(tri.max()) + 1
    directed = a * n + b
    if np.unique(directed).size != directed.size:
        return False  # an edge traversed twice the same way: non-manifold or inconsistent winding
    return bool(np.isin(b * n + a, directed).all())


def signed_volume(vertices, triangles):
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def usable_cpus():
    """CPUs this process may run on (its affinity where the OS says it, else the machine's)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _timed_swept_step(sweptself, previous, positions, velocities, dt):
    """SweptSelf.step, timed: (seconds, pairs giving contacts)."""
    t0 = time.perf_counter()
    live = sweptself.step(previous, positions, velocities, dt)
    return time.perf_counter() - t0, live


class _Tracks:
    """Per collider, the tracked rays, sparse (most vertices track nothing): ``key`` (k,) sorted,
    2 * vertex + slot; ``tri`` (k,) the triangle last hit; ``side`` (k,) int8 the remembered side
    (thin surfaces); ``inside`` (j,) sorted vertices that were inside a closed body."""

    def __init__(self, n):
        self.n = int(n)
        self.key = np.zeros(0, np.int64)
        self.tri = np.zeros(0, np.int64)
        self.side = np.zeros(0, np.int8)
        self.inside = np.zeros(0, np.int64)

    def inside_mask(self):
        mask = np.zeros(self.n, bool)
        mask[self.inside] = True
        return mask

    def resize(self, n, new_vertices=None, parents=None):
        old = self.n
        m = min(n, old)
        tri = np.full((n, 2), -1, np.int64)
        side = np.zeros((n, 2), np.int8)
        keep = (self.key >> 1) < m
        k = self.key[keep]
        tri[k >> 1, k & 1] = self.tri[keep]
        side[k >> 1, k & 1] = self.side[keep]
        inside = np.zeros(n, bool)
        inside[self.inside[self.inside < m]] = True
        if new_vertices is not None and new_vertices.size:
            # A vertex born from a tear sits where its parent was: it inherits the parent's
            # tracks, so its inversion memory is not lost at the moment the cloth opens.
            p = parents[:, 0]
            ok = (p >= 0) & (p < m) & (new_vertices >= 0) & (new_vertices < n)
            tri[new_vertices[ok]] = tri[p[ok]]
            side[new_vertices[ok]] = side[p[ok]]
            inside[new_vertices[ok]] = inside[p[ok]]
        key = np.flatnonzero(tri.reshape(-1) >= 0)
        self.n = int(n)
        self.key, self.tri, self.side = key, tri.reshape(-1)[key], side.reshape(-1)[key]
        self.inside = np.flatnonzero(inside)

    def drop_triangles(self, m):
        """Forget tracks on triangles that no longer exist (ids >= m)."""
        keep = self.tri < m
        self.key, self.tri, self.side = self.key[keep], self.tri[keep], self.side[keep]


def twin_ring(ring, rest_id):
    """Widen each vertex's ring-table row with the twins of its members (vertices a tear
    duplicated from the same original, sharing ``rest_id``). Without twins the table is returned
    as is. Measured: a sheet torn with self-collision on saw its new rims as deep contacts and blew
    up within ~15 steps."""
    n = rest_id.size
    counts = np.bincount(rest_id, minlength=n)
    if counts.max(initial=1) <= 1:
        return ring
    order = np.argsort(rest_id, kind="stable")
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    width = int(counts.max())
    members = np.full((counts.size, width), -1, np.int64)
    col = np.arange(n) - start[rest_id[order]]
    members[rest_id[order], col] = order
    safe = np.where(ring >= 0, ring, 0)
    wide = members[rest_id[safe]]  # (n, K, width)
    wide[ring < 0] = -1
    return np.ascontiguousarray(wide.reshape(n, -1))


class _Collider:
    """One collision target: a body (closed volume or open surface) or the cloth itself."""

    def __init__(self, name, kind, vertices, triangles, cluster_size, friction):
        self.name = name
        self.kind = kind  # 'volume' | 'surface' | 'self'
        self.friction = float(friction)
        self.vertices = np.ascontiguousarray(vertices, np.float64)
        self.measured = self.vertices.copy()  # positions at the last detect(): displacement origin
        self.velocities = np.zeros_like(self.vertices)
        # the collider's clusters as native trees, refitted each step they are cast into (bvh.c)
        self.scenes = ClusterBVH()
        self.set_topology(triangles, cluster_size)

    def set_topology(self, triangles, cluster_size, clustering=None):
        self.triangles = np.ascontiguousarray(triangles, np.int64)
        self.clustering = clustering or Clustering(self.vertices, self.triangles, cluster_size)
        self.adj, self.flip = triangle_adjacency(self.triangles)
        # self-collision skips the two-ring (see narrow.ring_table), counted across tears: the two
        # sides of a fresh cut lie on top of each other and must not collide as strangers
        self.ring = None
        if self.kind == "self":
            n = self.vertices.shape[0]
            rid = getattr(self, "rest_id", None)
            if rid is None or rid.size != n:
                rid = np.arange(n, dtype=np.int64)
            self.rest_id = rid
            self.ring = twin_ring(ring_table(self.triangles, n), rid)
        self.scenes.set_topology(self.triangles, self.clustering, self.adj)
        if self.kind == "self":
            # vertex -> incident triangles (CSR, ascending), for normals of a few clusters at a time
            corners = self.triangles.reshape(-1)
            self.vt_tri = (np.argsort(corners, kind="stable") // 3).astype(np.int64)
            self.vt_ptr = np.zeros(self.vertices.shape[0] + 1, np.int64)
            np.cumsum(np.bincount(corners, minlength=self.vertices.shape[0]), out=self.vt_ptr[1:])

    def normals(self, positions):
        """Area-weighted unit vertex normals (C) of this mesh at ``positions``."""
        return kernels.vertex_normals(positions, self.triangles)[0]


class _Plan:
    """One collider's work in a step: close pairs (i cloth cluster, j collider cluster), which
    of them get full detection, the collider's cluster boxes, and the walked / found hits."""

    __slots__ = ("name", "target", "i", "j", "full", "walked", "found", "lo", "hi", "first")

    def __init__(self, name, target, i, j, full):
        self.name, self.target, self.i, self.j, self.full = name, target, i, j, full
        self.walked = None
        self.found = None
        self.lo = self.hi = None
        self.first = False


class CollisionDetector:
    """Clustered ray-traced collision detection of one cloth against bodies and itself.

    Parameters (SI): ``thickness`` contact distance of the cloth (m, > 0); ``friction``
    coefficient reported with every contact; ``displacement_threshold`` relative displacement
    (m, > 0) above which a cluster pair gets full detection; ``cluster_size`` target vertices per
    cluster; ``measure`` 'relative' (paper), 'absolute' (per-cluster, no pairing) or 'full'
    (full detection of every close pair every step); ``self_collision``; ``swept`` the swept
    self-collision of the two-ring the rays skip (stage 5, ``swept.py``; its cost is
    ``stats['ms']['swept']``, its counts ``stats['swept_*']``); ``trip_rule`` how the
    relative measure trips full detection: 'paper' (eqs. 1-4 against the threshold, the default)
    or 'bound' (a rigorous bound on each vertex's motion towards the other cluster against the
    clearance left, measure.py; not the default yet: in the simulated scenes it fully detects
    2.5-3x more pairs (1.7-2x the ms), and full detection at nearly every step - like measure='full' - lets a
    body that starts inside the cloth blow it up, test_collision_session); ``clearance_cap`` (>= 1)
    the paper's rule's threshold per pair raised by the clearance its last full detection measured,
    up to this factor (module docs, "Clearance"; 1: off); ``swept_thread`` runs the swept stage on a
    thread of its own while the colliders are detected (default: when this process may use more than one
    CPU; the two read the same positions and write nothing the other reads, so the contacts are the
    same either way, bit for bit).
    """

    def __init__(
        self,
        thickness,
        friction,
        displacement_threshold,
        cluster_size=100,
        measure="relative",
        self_collision=True,
        swept=True,
        trip_rule="paper",
        clearance_cap=4.0,
        swept_thread=None,
    ):
        if not np.isfinite(thickness) or thickness <= 0:
            raise ValueError(f"thickness must be a positive distance in metres, got {thickness!r}")
        if not np.isfinite(displacement_threshold) or displacement_threshold <= 0:
            raise ValueError(
                f"displacement_threshold must be a positive distance in metres, got {displacement_threshold!r}"
            )
        if not np.isfinite(friction) or friction < 0:
            raise ValueError(f"friction must be a coefficient >= 0, got {friction!r}")
        if measure not in MEASURES:
            raise ValueError(f"measure must be one of {MEASURES}, got {measure!r}")
        if trip_rule not in TRIP_RULES:
            raise ValueError(f"trip_rule must be one of {TRIP_RULES}, got {trip_rule!r}")
        if not np.isfinite(clearance_cap) or clearance_cap < 1.0:
            raise ValueError(f"clearance_cap must be a factor >= 1 (1: off), got {clearance_cap!r}")
        if int(cluster_size) < 2:
            raise ValueError(f"cluster_size must be at least 2 vertices, got {cluster_size!r}")
        self.thickness = float(thickness)
        self.friction = float(friction)
        self.displacement_threshold = float(displacement_threshold)
        self.cluster_size = int(cluster_size)
        self.measure = measure
        self.self_collision = bool(self_collision)
        self.swept = bool(swept)  # stage 5 (swept.py); off only to measure what it costs and saves
        self._swept = None
        self.swept_thread = usable_cpus() > 1 if swept_thread is None else bool(swept_thread)
        self._swept_thread_fallbacks = 0  # steps whose thread could not be started (stats)
        self.trip_rule = trip_rule
        self.inflate = 0.5 * (self.displacement_threshold + self.thickness)
        # Relative motion between two full detections of a pair stays under the threshold (twice
        # it with the absolute measure, see measure.py); 1.5 because the measure is a mean plus
        # a standard deviation, not a maximum.
        reach = 2.0 if measure == "absolute" else 1.0
        self.track_range = self.thickness + 1.5 * reach * self.displacement_threshold
        self.bodies = {}
        self.cloth = None
        self._self = None
        self._tracks = {}
        self._rel = {}
        self._abs = {}
        self._forced = {}
        self._step = 0
        self._first = True
        self._new_targets = set()
        self._abs_cloth_forget = None
        # Batching of full detections (measure.py): the pairs that would pass the threshold within
        # this many steps join a step that runs full detection anyway.
        self.lookahead = 3.0
        # The trip rule (measure.py): a full detection tracks every hit within track_range, so an
        # untracked vertex has this much clearance to spend before it could touch; its motion
        # bound counts the distance to a point up to reach away (measure.c: |L| |x - y|), twice the
        # track range covering a step that starts beyond it.
        self.trip_budget = self.displacement_threshold
        self.trip_reach = 2.0 * self.track_range
        self._set_clearance(clearance_cap)
        self.stats = {}

    def _set_clearance(self, cap):
        """The clearance credit of the paper's rule (module docs, "Clearance"): a pair's threshold is
        raised to at most ``cap`` times the displacement threshold, and the cloth's (and a thin
        surface's) lines are searched that far for it (``probe_length``)."""
        self.clearance_cap = float(cap)
        self.probe_length = self.track_range + (self.clearance_cap - 1.0) * (self.track_range - self.thickness)

    # ------------------------------------------------------------------ saved state
    # A resumed bake continues from the detector as it was (tracks, measures, clusters, previous
    # positions, step counter, trees): pickled whole by ``tearcloth.resume``. The trees are plain
    # arrays, pickled as they are (their shape depends on the pose they were built in).
    def __getstate__(self):
        return {k: v for k, v in self.__dict__.items() if k not in ("_ws", "_worker")}  # the step's scratch, the thread

    def __setstate__(self, state):
        state.setdefault("trip_rule", "paper")  # saved before trip rules existed: the paper's measures
        self.__dict__.update(state)
        # a detector saved before the swept stage existed: it starts with the stage on, pairs rebuilt
        self.__dict__.setdefault("swept", True)
        self.__dict__.setdefault("_swept", None)
        self.__dict__.setdefault("swept_thread", usable_cpus() > 1)  # the machine that resumes decides
        self.__dict__.setdefault("_swept_thread_fallbacks", 0)
        # saved before the trip rule's bound: its budget and reach as __init__ sets them
        self.__dict__.setdefault("trip_budget", self.displacement_threshold)
        self.__dict__.setdefault("trip_reach", 2.0 * self.track_range)
        if "clearance_cap" not in self.__dict__:  # saved before the clearance credit: the paper's rule as it was
            self._set_clearance(1.0)
        for k in ("self_scenes", "scene_tolerance", "_rays"):  # the Embree scenes' settings and buffers
            self.__dict__.pop(k, None)
        # saved when bodies (or the cloth, with self_scenes 'embree') had Embree scenes in a rigid frame:
        # native trees instead, built at the next step from the pose then (the hits are exact either way)
        for collider in (self.cloth, *self.bodies.values()):
            if collider is not None and not isinstance(collider.scenes, ClusterBVH):
                collider.scenes = ClusterBVH()
                collider.scenes.set_topology(collider.triangles, collider.clustering, collider.adj)

    # ------------------------------------------------------------------ scene setup
    def add_body(self, vertices, triangles, name, friction=None):
        """Add a collider. Its topology is fixed; move it with ``update_body``."""
        if name in self.bodies:
            raise ValueError(f"a body named {name!r} already exists")
        v, t = _check_mesh(vertices, triangles, f"body {name!r}")
        kind = "volume"
        if not is_closed(t):
            warnings.warn(
                f"body {name!r} is not a closed, consistently oriented mesh: it has no inside, "
                "so it is treated as a thin two-sided surface (contacts within thickness of "
                "either side, crossings pushed back). Close the mesh for volumetric contact.",
                stacklevel=2,
            )
            kind = "surface"
        elif signed_volume(v, t) < 0:
            t = t[:, [0, 2, 1]].copy()  # normals must point out of the body
        body = _Collider(name, kind, v, t, self.cluster_size, self.friction if friction is None else friction)
        self.bodies[name] = body
        self._reset_target(name)
        return body

    def update_body(self, name, vertices, velocities=None):
        """New vertex positions (same topology) and optional per-vertex velocities (m/s)."""
        body = self.bodies.get(name)
        if body is None:
            raise KeyError(f"no body named {name!r}; add it with add_body first")
        v = np.asarray(vertices, np.float64)
        if v.shape != body.vertices.shape:
            raise ValueError(f"body {name!r}: expected vertices of shape {body.vertices.shape}, got {v.shape}")
        body.vertices = v.copy()
        if velocities is None:
            body.velocities = np.zeros_like(v)
        else:
            vel = np.asarray(velocities, np.float64)
            if vel.shape != v.shape:
                raise ValueError(f"body {name!r}: velocities must have shape {v.shape}, got {vel.shape}")
            body.velocities = vel.copy()

    def set_cloth(self, positions, triangles):
        """(Re)define the cloth: clusters it and forgets every history (a global redo)."""
        v, t = _check_mesh(positions, triangles, "cloth")
        self.cloth = _Collider("cloth", "self", v, t, self.cluster_size, self.friction)
        self._cloth_prev = v.copy()
        self._rest = v.copy()  # the swept stage's per-pair gaps come from this (rest) geometry
        self._swept = None
        self._first = True
        for name in list(self._tracks):
            self._reset_target(name)
        self._reset_target("__self__")

    def _reset_target(self, name):
        n = 0 if self.cloth is None else self.cloth.vertices.shape[0]
        self._tracks[name] = _Tracks(n)
        if self.trip_rule == "bound":
            self._rel[name] = TripMeasure(self.trip_budget, self.thickness, self.inflate, self.lookahead)
        else:
            self._rel[name] = RelativeMeasure(self.displacement_threshold, self.lookahead)
        self._abs[name] = AbsoluteMeasure(self.displacement_threshold, self.lookahead)
        self._forced[name] = None
        self._new_targets.add(name)

    def _targets(self):
        out = []
        if self.self_collision and self.cloth is not None:
            out.append(("__self__", self.cloth))
        out.extend(self.bodies.items())
        return out

    # ------------------------------------------------------------------ topology
    def on_topology(self, events, positions, triangles):
        """Apply a tear reported by the native core (see module docs of ``clusters.py``)."""
        if self.cloth is None:
            raise RuntimeError("set_cloth must be called before on_topology")
        pos = np.ascontiguousarray(positions, np.float64)
        tri = np.ascontiguousarray(triangles, np.int64)
        cloth = self.cloth
        removed = self._drop_removed(events)
        old_n = cloth.vertices.shape[0]
        new_v = np.asarray(events.get("new_vertices", np.zeros(0)), np.int64).reshape(-1)
        parents = np.asarray(events.get("parents", np.zeros((0, 2))), np.int64).reshape(-1, 2)
        weights = np.asarray(events.get("weights", np.ones(new_v.size)), np.float64).reshape(-1)
        # The new vertices' previous positions, interpolated from their parents', so that the
        # next step sees only the motion that really happened.
        prev = np.empty_like(pos)
        m = min(old_n, pos.shape[0])
        prev[:m] = self._cloth_prev[:m]
        if pos.shape[0] > m:
            prev[m:] = pos[m:]
        if new_v.size:
            p0, p1 = parents[:, 0], parents[:, 1]
            w = weights[:, None]
            ok0 = (p0 >= 0) & (p0 < m)
            second = np.where((p1 >= 0) & (p1 < m), p1, p0)
            ok = ok0
            prev[new_v[ok]] = w[ok] * self._cloth_prev[p0[ok]] + (1 - w[ok]) * self._cloth_prev[second[ok]]
        cloth.vertices = pos.copy()
        # twins: a duplicate made by a cut shares its parent's rest identity (see twin_ring)
        rid = np.concatenate([cloth.rest_id, np.arange(cloth.rest_id.size, pos.shape[0], dtype=np.int64)])
        if new_v.size:
            dup = (parents[:, 1] < 0) & (parents[:, 0] >= 0) & (parents[:, 0] < rid.size) & (new_v < rid.size)
            rid[new_v[dup]] = rid[parents[dup, 0]]
        cloth.rest_id = rid
        dirty = cloth.clustering.update(events, pos, tri)
        # adjacency, two-ring table, vertex -> triangles; scenes of untouched clusters survive (their
        # triangles keep their ids and corners)
        cloth.set_topology(tri, self.cluster_size, clustering=cloth.clustering)
        touched = np.concatenate([
            np.asarray(events.get("changed_triangles", np.zeros(0)), np.int64).reshape(-1),
            np.asarray(events.get("new_triangles", np.zeros(0)), np.int64).reshape(-1),
        ])
        if removed:
            # survivors' triangle ids moved down: no cluster's scene or history holds
            dirty = np.arange(cloth.clustering.n_clusters, dtype=np.int64)
            touched = None
        cloth.scenes.invalidate(dirty, touched)
        self._cloth_prev = prev
        self._swept_topology(pos)
        for name, tracks in self._tracks.items():
            tracks.resize(pos.shape[0], new_v, parents)
            if name == "__self__":
                tracks.drop_triangles(tri.shape[0])
                self._rel[name].forget(dirty, dirty)
            else:
                self._rel[name].forget(dirty, None)
            self._forced[name] = dirty
        self._abs_cloth_forget = dirty
        return dirty

    def _drop_removed(self, events):
        """Delete the vertices and triangles a tiny fragment took (numbered as before the step) from
        the cloth's per-vertex and per-triangle state; the survivors keep their order. The cluster
        labels are Clustering.update's. True if anything went."""
        rv = np.asarray(events.get("removed_vertices", np.zeros(0)), np.int64).reshape(-1)
        rt = np.asarray(events.get("removed_triangles", np.zeros(0)), np.int64).reshape(-1)
        if not (rv.size or rt.size):
            return False
        cloth = self.cloth
        n, m = cloth.vertices.shape[0], cloth.triangles.shape[0]
        vmap = np.full(n, -1, np.int64)
        keep_v = np.ones(n, bool)
        keep_v[rv[(rv >= 0) & (rv < n)]] = False
        vmap[keep_v] = np.arange(int(keep_v.sum()))
        tmap = np.full(m, -1, np.int64)
        keep_t = np.ones(m, bool)
        keep_t[rt[(rt >= 0) & (rt < m)]] = False
        tmap[keep_t] = np.arange(int(keep_t.sum()))
        cloth.vertices = cloth.vertices[keep_v]
        if cloth.measured.shape[0] == n:
            cloth.measured = cloth.measured[keep_v]
        if cloth.velocities is not None and cloth.velocities.shape[0] == n:
            cloth.velocities = cloth.velocities[keep_v]
        self._cloth_prev = self._cloth_prev[keep_v]
        rest = getattr(self, "_rest", None)
        if rest is not None and rest.shape[0] == n:
            self._rest = rest[keep_v]
        # twins keep a shared identity; relabelled compactly so new vertices' own ids stay unique
        cloth.rest_id = np.unique(cloth.rest_id[keep_v], return_inverse=True)[1].astype(np.int64).reshape(-1)
        for name, tracks in self._tracks.items():
            v = tracks.key >> 1
            ok = vmap[v] >= 0
            tri = tracks.tri
            if name == "__self__":  # the cloth's own triangles; a body's keep their ids
                ok &= tmap[np.clip(tri, 0, m - 1)] >= 0
                tri = np.where(ok, tmap[np.clip(tri, 0, m - 1)], -1)
            tracks.key = (vmap[v[ok]] << 1) | (tracks.key[ok] & 1)
            tracks.tri, tracks.side = tri[ok], tracks.side[ok]
            inside = tracks.inside[vmap[tracks.inside] >= 0]
            tracks.inside = vmap[inside]
            tracks.n = int(keep_v.sum())
        return True

    # ------------------------------------------------------------------ detection
    def _begin_step(self, positions, triangles, velocities):
        """The step's input taken in (the cloth re-set when its shape changed): returns the
        positions as float64 (n,3) m and the new step's number."""
        pos = np.ascontiguousarray(positions, np.float64)
        tri = np.ascontiguousarray(triangles, np.int64)
        if self.cloth is None or tri.shape != self.cloth.triangles.shape or pos.shape != self.cloth.vertices.shape:
            self.set_cloth(pos, tri)
        self.cloth.vertices = pos
        if velocities is None:
            self.cloth.velocities = None
        else:
            vel = np.ascontiguousarray(velocities, np.float64)
            if vel.shape != pos.shape:
                raise ValueError(f"velocities must have the shape of positions {pos.shape}, got {vel.shape}")
            self.cloth.velocities = vel
        self._step += 1
        return pos, self._step

    def _cloth_due(self, avg_c, dev_c):
        """The absolute measure's cloth clusters due for full detection this step (bool (k,)),
        those a tear marked (_abs_cloth_forget) included once."""
        due_c = self._abs.setdefault(
            "__cloth__", AbsoluteMeasure(self.displacement_threshold, self.lookahead)).accumulate(avg_c, dev_c)
        forget = getattr(self, "_abs_cloth_forget", None)
        if forget is not None and len(forget):
            due_c[forget[forget < due_c.size]] = True
            self._abs_cloth_forget = None
        return due_c

    def detect(self, positions, triangles, velocities=None, dt=None):
        """Contacts of the cloth at ``positions`` (n,3) m with ``triangles`` (m,3).

        ``velocities`` (n,3) m/s of the cloth, optional: reported as the surface velocity of
        self-collision contacts (zero when not given). ``dt`` (s), optional: the coming step, over
        which the swept stage predicts the two-ring's motion (without it, or without velocities,
        that stage only catches crossings after the fact).
        """
        t_start = time.perf_counter()
        pos, step = self._begin_step(positions, triangles, velocities)
        ws = self._workspace(pos.shape[0])
        # 5 (started first). the swept stage of the two-ring: on its thread when there is a second
        # CPU (C, never taking the GIL), while steps 1-4 run here; it reads the step's positions,
        # the previous ones and the velocities, and writes only its own state. Without the thread
        # it runs here after steps 1-4.
        t_begin = time.perf_counter()
        swept = self._swept_begin(pos, dt)  # a new topology's pairs: the stage's time, not the measure's
        begin_s = time.perf_counter() - t_begin
        job = swept[0].start(self._swept_worker(), *swept[1:]) if swept and self.swept_thread else None
        try:
            contacts, every, n_close, counts, times, self_times, t_phase = self._colliders_step(pos, ws, step)
        except BaseException:
            if job is not None:
                try:  # nothing may still run on the detector's state once this raises
                    swept[0].finish(job)
                except Exception:  # noqa: S110 - the colliders' error is the one to raise
                    pass
            raise
        t_join = time.perf_counter()
        if job is not None:
            swept_s, on_thread, n_live = swept[0].finish(job)
            # no thread could be started (the system's limit): the step ran before the colliders
            self._swept_thread_fallbacks += not on_thread
        else:  # off, or on this thread
            swept_s, n_live = _timed_swept_step(*swept) if swept else (0.0, 0)
        t_rows = time.perf_counter()
        self.all_contacts = self._swept_rows(every, n_live)
        t_swept = time.perf_counter()
        t_measure, t_detect, t_end = t_phase
        n_tracked, n_lost, n_full, n_rays = counts

        self._cloth_prev = pos.copy()
        for body in self.bodies.values():
            body.measured = body.vertices  # update_body replaces, never mutates, the array
        self._first = False
        builds = sum(t.scenes.builds for _, t in self._targets())
        # the C calls' own phases; what is left of their wall time (argument passing) goes to "contacts"
        detect_s = t_detect - t_measure
        self.stats = {
            "close_pairs": n_close,
            "full_pairs": n_full,
            "full_share": (n_full / n_close) if n_close else 0.0,
            "tracked_rays": n_tracked,
            "lost": n_lost,
            "full_rays": n_rays,
            "contacts": len(contacts),
            "scene_builds_total": builds,
            "ms": {
                "measure": 1e3 * (t_measure - t_start - begin_s),
                "incremental": 1e3 * times[0],
                "full": 1e3 * (times[1] + times[2]),
                "contacts": 1e3 * (detect_s - times[:3].sum() + t_end - t_detect),
                "total": 1e3 * (t_swept - t_start),
                "full_self": 1e3 * (self_times[1] + self_times[2]),  # of "full": the cloth against itself
                # the stage's own time (its step, wherever it ran, and the merge of its rows); of it
                # "swept_wait" is what this thread waited for the worker after steps 1-4
                "swept": 1e3 * (begin_s + swept_s + t_swept - t_rows),
                "swept_wait": 1e3 * (t_rows - t_join) if job is not None else 0.0,
            },
            "swept_pairs": 0 if self._swept is None else self._swept.n_pairs,
            "swept_thread_fallbacks": self._swept_thread_fallbacks,
            **{f"swept_{k}": v for k, v in (self._swept.counts if self._swept is not None else {}).items()},
        }
        return contacts

    def _colliders_step(self, pos, ws, step):
        """Steps 1-4 of ``detect``: the measure and every collider's C call. Returns (deepest
        contacts, every collider's contacts, close pairs, (tracked, lost, full pairs, full rays), the
        C calls' phase times, those of the cloth against itself, (t after the measure, after the
        calls, after the merge))."""
        cloth = self.cloth

        # 1. measure ---------------------------------------------------------------
        bound_rule = self.measure == "relative" and self.trip_rule == "bound"
        paper_rule = self.measure == "relative" and not bound_rule
        avg_c, dev_c, lo_c, hi_c = self._cluster_state(cloth, pos, self._cloth_prev, ws, "cloth")
        if bound_rule:
            fit_c = kernels.cluster_fit(cloth.clustering, pos, self._cloth_prev, self.trip_reach)
            side_c = (cloth.clustering, pos, self._cloth_prev, fit_c)
        due_c = self._cloth_due(avg_c, dev_c) if self.measure == "absolute" else None
        plans = []
        n_close = 0
        for name, target in self._targets():
            is_self = name == "__self__"
            if is_self:
                avg_b, dev_b, lo_b, hi_b = avg_c, dev_c, lo_c, hi_c
            else:
                avg_b, dev_b, lo_b, hi_b = self._cluster_state(target, target.vertices, target.measured, ws, name)
            forced = self._forced.get(name)
            first = self._first or name in self._new_targets
            self._forced[name] = None
            self._new_targets.discard(name)
            # the close pairs, those forced to full detection, and the paper's relative measure (C)
            rel = self._rel[name] if paper_rule else None
            i, j, full = self._pair_step(lo_c, hi_c, lo_b, hi_b, is_self, first, forced, rel,
                                         (avg_c, dev_c, avg_b, dev_b) if paper_rule else None)
            if bound_rule:
                side_b = side_c if is_self else (target.clustering, target.vertices, target.measured,
                                                 kernels.cluster_fit(target.clustering, target.vertices,
                                                                     target.measured, self.trip_reach))
                bound = kernels.pair_motion(i, j, side_c, side_b, self.trip_reach)
                full = self._rel[name].step(i, j, bound, lo_c, hi_c, lo_b, hi_b, full if (first or (
                    forced is not None and len(forced))) else None)
            elif self.measure == "absolute":
                due_b = due_c if is_self else self._abs[name].accumulate(avg_b, dev_b)
                full = full | due_c[i] | due_b[j]
            elif self.measure == "full":
                full = np.ones(i.size, bool)
            plan = _Plan(name, target, i, j, np.ascontiguousarray(full, bool))
            plan.lo, plan.hi, plan.first = lo_b, hi_b, first
            plans.append(plan)
            n_close += i.size
        t_measure = time.perf_counter()

        # 2-4. per collider, one C call: walks, full detection, refinement, merge --------
        rows = []
        n_tracked = n_lost = n_full = n_rays = 0
        times = np.zeros(4)  # walk, cast, refine, merge (s, from the C calls)
        self_times = np.zeros(4)
        for plan in plans:
            rows.append(self._detect_target(plan, pos, ws, step))  # the clearance credit included (C)
            st = ws["stats"]
            n_tracked += int(st[3])
            n_lost += int(st[4])
            n_full += int(st[5])
            n_rays += int(st[6])
            times += ws["times"]
            if plan.name == "__self__":
                self_times = ws["times"].copy()
        t_detect = time.perf_counter()
        contacts, every = self._assemble_rows(rows, pos.shape[0])
        # Every collider's contact per vertex, for the solver: a vertex touching a body and another
        # layer of cloth at once must respect both (the solver combines their normals).
        t_end = time.perf_counter()
        return (contacts, every, n_close, (n_tracked, n_lost, n_full, n_rays), times, self_times,
                (t_measure, t_detect, t_end))

    @property
    def _credits(self):
        """Whether full detections measure the pairs' clearance and the paper's rule credits it."""
        return self.measure == "relative" and self.trip_rule == "paper" and self.clearance_cap > 1.0

    def _cluster_state(self, collider, positions, previous, ws, key):
        """dis_avg, dis_dev and the inflated boxes of a collider's clusters (C: one call), in arrays
        kept between steps."""
        cl = collider.clustering
        k = cl.n_clusters
        buf = ws.setdefault(("state", key), None)
        if buf is None or buf[0].shape[0] != k:
            buf = ws[("state", key)] = (np.empty((k, 3)), np.empty(k), np.empty((k, 3)), np.empty((k, 3)))
        _collide.cluster_state(positions, previous, cl.order, cl.ptr, cl.box_index, cl.box_ptr, self.inflate, *buf)
        return buf

    def _pair_step(self, lo_a, hi_a, lo_b, hi_b, self_pairs, first, forced, rel, motion):
        """(i, j, full) of a collider's close pairs (C: measure.c tcc_pair_step), the relative measure
        ``rel`` (a RelativeMeasure) updated when ``motion`` (avg_c, dev_c, avg_b, dev_b) is given;
        without it, full holds the forced pairs only."""
        cap = max(int(getattr(self, "_pair_cap", 64)), 64)
        forced = None if forced is None or not len(forced) else np.ascontiguousarray(forced, np.int64)
        old = (rel.keys, rel.rel_avg, rel.rel_dev) if rel is not None else \
            (kernels.EMPTY_I64, np.zeros((0, 3)), kernels.EMPTY_F64)
        m = motion if motion is not None else (None, None, None, None)
        while True:
            i, j, keys = np.empty(cap, np.int64), np.empty(cap, np.int64), np.empty(cap, np.int64)
            full = np.empty(cap, bool)
            rel_avg, rel_dev, amp = np.empty((cap, 3)), np.empty(cap), np.empty(cap)
            count, _ = _collide.pair_step(lo_a, hi_a, lo_b, hi_b, self_pairs, first, forced, *m, *old,
                                          rel.threshold if rel is not None else 0.0,
                                          rel.lookahead if rel is not None else 0.0, i, j, full, keys, rel_avg,
                                          rel_dev, amp)
            if count <= cap:
                break
            cap = self._pair_cap = 2 * count
        if rel is not None:
            rel.keys, rel.rel_avg, rel.rel_dev, rel.amplitude = keys[:count], rel_avg[:count], rel_dev[:count], \
                amp[:count]
        return i[:count], j[:count], full[:count]

    def _workspace(self, n):
        """The step's scratch, kept between steps (not pickled): the cloth's normals (computed per
        vertex as the step needs them: done), and one collider's outputs (tracks, contacts, stats)."""
        ws = getattr(self, "_ws", None)
        if ws is None or ws["normals"].shape[0] != n:
            ws = {"normals": np.zeros((n, 3)), "has_normal": np.zeros(n, bool), "out_key": np.empty(2 * n, np.int64),
                  "out_tri": np.empty(2 * n, np.int64), "out_side": np.empty(2 * n, np.int8),
                  "out_inside": np.empty(n, np.int64), "contact_vertex": np.empty(n, np.int64),
                  "depth": np.empty(n), "normal": np.empty((n, 3)), "contact_velocity": np.empty((n, 3)),
                  "stats": np.zeros(8, np.int64), "times": np.zeros(4)}
            self._ws = ws
        ws["done"] = np.zeros(n, bool)
        return ws

    def _detect_target(self, plan, pos, ws, step):
        """One collider's step (C: detect.c): its tracked rays walked (a lost walk sends its pair to
        full detection now), the marked pairs' rays cast into its trees, refined, merged with the
        tracks and classified. Stores the new tracks; returns this collider's deepest contact per
        vertex, sorted by vertex: (vertex, depth, normal, velocity, friction)."""
        name, target = plan.name, plan.target
        cloth = self.cloth
        is_self = name == "__self__"
        tracks = self._tracks[name]
        trees = target.scenes
        if not trees.built:
            trees.build(target.vertices, target.triangles)
        if not tracks.key.size and not plan.full.any():
            # nothing to walk and nothing to cast (the cloth against itself, most steps): the C step
            # would only merge nothing - no tracks, no vertex inside, no contact - so it is not called
            ws["stats"][:] = 0
            ws["times"][:] = 0.0
            tracks.key, tracks.tri, tracks.side = np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int8)
            if target.kind == "volume" and not is_self:
                tracks.inside = np.zeros(0, np.int64)
            return (np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)), target.friction)
        args = self._target_args(plan, ws)
        args["positions"], args["previous"], args["velocity"] = pos, self._cloth_prev, cloth.velocities
        args["done"] = ws["done"]
        if is_self:  # the cloth is its own target: this step's arrays
            args["target_vertices"], args["target_previous"], args["target_velocity"] = \
                pos, self._cloth_prev, cloth.velocities
        else:
            args["target_vertices"], args["target_previous"] = target.vertices, target.measured
            args["target_velocity"] = target.velocities
        args["box_lo"], args["box_hi"], args["step"] = plan.lo, plan.hi, int(step)
        args["pair_i"], args["pair_j"], args["full"] = plan.i, plan.j, plan.full
        if self._credits:
            # the pairs fully detected (lost walks included) restart their relative measure with the
            # clearance their full detection measured as a credit (C, detect.c credit_pairs): the measure
            # trips when it passes the threshold scaled by (clearance - thickness) / (track_range -
            # thickness), at most clearance_cap times it; kept as a negative start of the deviation
            # accumulator (eq. 4's amplitude is a sum), so the C measure needs no per-pair threshold
            buf = ws.get("clearance_buf")
            if buf is None or buf.shape[0] < plan.i.size:
                buf = ws["clearance_buf"] = np.empty(max(64, 2 * plan.i.size))
            args["clearance"] = ws["clearance"] = buf[:plan.i.size]
            rel = self._rel[name]
            args["rel_avg"], args["rel_dev"] = rel.rel_avg, rel.rel_dev
        args["track_key"], args["track_tri"], args["track_side"] = tracks.key, tracks.tri, tracks.side
        args["inside"], args["first"] = tracks.inside, bool(self._first)
        _collide.detect(**args)
        nt, ni, nc = (int(v) for v in ws["stats"][:3])
        tracks.key, tracks.tri, tracks.side = ws["out_key"][:nt].copy(), ws["out_tri"][:nt].copy(), \
            ws["out_side"][:nt].copy()
        if target.kind == "volume" and not is_self:
            tracks.inside = ws["out_inside"][:ni].copy()
        return (ws["contact_vertex"][:nc].copy(), ws["depth"][:nc].copy(), ws["normal"][:nc].copy(),
                ws["contact_velocity"][:nc].copy(), target.friction)

    def _target_args(self, plan, ws):
        """The keyword arguments of a collider's C call (detect.c) in its table's order, kept between
        steps while the topology, the trees and the scratch stay the same objects: the caller sets
        what changes every step."""
        name, target, cloth = plan.name, plan.target, self.cloth
        trees, is_self = target.scenes, plan.name == "__self__"
        ccl, tcl = cloth.clustering, target.clustering
        key = tuple(id(a) for a in (cloth.triangles, cloth.vt_ptr, cloth.vt_tri, ccl.order, ccl.ptr, ccl.labels,
                                    cloth.ring, target.triangles, target.adj, target.flip, tcl.tri_labels,
                                    trees.node_ptr, trees.node, trees.box, trees.prim,
                                    trees.corner, trees.refit_step, ws["normals"]))
        cache = ws.setdefault("args", {})
        hit = cache.get(name)
        if hit is not None and hit[0] == key:
            return hit[1]
        cl = target.clustering
        args = dict(
            positions=None, previous=None, velocity=None, triangles=cloth.triangles, vt_ptr=cloth.vt_ptr,
            vt_tri=cloth.vt_tri, order=cloth.clustering.order, ptr=cloth.clustering.ptr,
            labels=cloth.clustering.labels, normals=ws["normals"], has_normal=ws["has_normal"], done=None,
            kind=kernels.KIND["self" if is_self else target.kind], target_vertices=target.vertices,
            target_triangles=target.triangles, adjacency=target.adj, flip=target.flip,
            target_previous=self._cloth_prev if is_self else target.measured,
            target_velocity=cloth.velocities if is_self else target.velocities, tri_labels=cl.tri_labels,
            box_lo=None, box_hi=None,
            ring=cloth.ring if is_self else None, node_ptr=trees.node_ptr, node=trees.node, box=trees.box,
            prim=trees.prim, corner=trees.corner, refit_step=trees.refit_step, step=0, pair_i=None, pair_j=None,
            full=None, track_key=None, track_tri=None, track_side=None, inside=None, thickness=self.thickness,
            track_range=self.track_range, ray_length=self.track_range, inflate=self.inflate, backoff=RAY_BACKOFF,
            first=False, out_key=ws["out_key"], out_tri=ws["out_tri"], out_side=ws["out_side"],
            out_inside=ws["out_inside"], contact_vertex=ws["contact_vertex"], depth=ws["depth"],
            normal=ws["normal"], contact_velocity=ws["contact_velocity"], stats=ws["stats"], times=ws["times"],
            clearance=None, probe_length=self.probe_length, rel_avg=None, rel_dev=None,
            credit_unit=self.displacement_threshold, clearance_cap=self.clearance_cap,
        )
        cache[name] = (key, args)
        return args

    # ------------------------------------------------------------------ 5. swept (swept.py)
    def _swept_topology(self, pos):
        """Rest positions for vertices a tear made (a twin's are its original's) and a fresh pair
        list; the remembered crossings of the old topology are dropped (their ids changed)."""
        self._swept = None
        rest = getattr(self, "_rest", None)
        n = pos.shape[0]
        if rest is None:
            rest = pos.copy()
        if rest.shape[0] < n:
            rid = self.cloth.rest_id[rest.shape[0]:n]
            extra = np.where((rid < rest.shape[0])[:, None], rest[np.minimum(rid, rest.shape[0] - 1)],
                             pos[rest.shape[0]:n])
            rest = np.concatenate([rest, extra])
        self._rest = rest[:n]

    def _swept_stage(self, every, pos, dt):
        """Stage 5 whole, on this thread: ``every`` with the swept rows merged in (the tests'
        reference detector runs it so, after its steps 1-4)."""
        swept = self._swept_begin(pos, dt)
        return every if swept is None else self._swept_rows(every, _timed_swept_step(*swept)[1])

    def _swept_begin(self, pos, dt):
        """Stage 5's step (swept.py, one C call) made ready: its arguments for ``_timed_swept_step``,
        None when the stage is off. A new topology's pairs are made here, on this thread."""
        if not (self.swept and self.self_collision):
            return None
        cloth = self.cloth
        if self._swept is None:
            self._swept_topology(pos)
            self._swept = SweptSelf(pos, cloth.triangles, cloth.ring, self._rest, self.thickness)
        return (self._swept, None if self._first else self._cloth_prev, pos, cloth.velocities,
                0.0 if dt is None else float(dt))

    def _swept_worker(self):
        """The swept stage's thread (C, native/collide/pymodule.c), made when first needed (not
        pickled). One per detector: two cloths baked on two threads never wait for each other's stage."""
        worker = getattr(self, "_worker", None)
        if worker is None or worker[0] != os.getpid():  # (a fork's child has not the parent's thread)
            worker = self._worker = (os.getpid(), _collide.swept_worker())
        return worker[1]

    def _swept_rows(self, every, n_live):
        """``every`` (the colliders' contacts, sorted by vertex) with the swept stage's contact rows
        merged in (swept.py, the second C call)."""
        if not n_live:
            return every
        return self._swept.rows(every, self.cloth.velocities, self.cloth.friction)

    @staticmethod
    def _assemble_rows(rows, n):
        """(deepest contact per vertex over all colliders, every collider's contact per vertex
        sorted by vertex) from each collider's contacts (C)."""
        some = [r for r in rows if r[0].size]
        if not some:
            return Contacts(), Contacts()
        if len(some) == 1:  # one collider touches: its contacts are both lists
            v, depth, normal, velocity, fr = some[0]
            c = Contacts(v.astype(np.int32), normal, depth, velocity, np.full(v.size, fr))
            return c, c
        sizes = [r[0].size for r in rows]
        total = sum(sizes)
        seg = np.zeros(len(rows) + 1, np.int64)
        np.cumsum(sizes, out=seg[1:])
        v = np.concatenate([r[0] for r in some])
        depth = np.concatenate([r[1] for r in some])
        normal = np.concatenate([r[2] for r in some])
        velocity = np.concatenate([r[3] for r in some])
        friction = np.array([r[4] for r in rows], np.float64)
        deep = (np.empty(total, np.int32), np.empty((total, 3)), np.empty(total), np.empty((total, 3)),
                np.empty(total))
        every = (np.empty(total, np.int32), np.empty((total, 3)), np.empty(total), np.empty((total, 3)),
                 np.empty(total))
        kd, ka = _collide.assemble(seg, v, depth, normal, velocity, friction, n, *deep, *every)
        return Contacts(*(a[:kd] for a in deep)), Contacts(*(a[:ka] for a in every))
