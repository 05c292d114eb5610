"""CollisionDetector: the per-step orchestration of clustered, ray-traced collision detection.

This file owns the state that lives between steps (previous positions, clusters, per-pair
measures, per-ray tracks) and the order of one step:

1. measure  – per-cluster displacement since the previous ``detect``; inflated cluster AABBs;
              close pairs (cloth-cloth for self-collision, cloth-body); the displacement measure
              marks pairs for full detection (``measure.py``).
2. incremental – every ray tracked from the previous step is walked to its current hit on the
              current geometry (``incremental.py``). A lost walk sends its pair to full
              detection in this same step (not the next one: the step's contact set would
              otherwise miss that vertex once).
3. full     – for the marked pairs, the cloth cluster's rays are cast into the collider
              cluster's cached Embree scene and refined exactly (``narrow.py``).
4. contacts – tracks are merged (nearest hit per vertex and ray), classified, and the deepest
              contact per vertex is returned.

Tracks: per collider, per cloth vertex, two ray slots (+n, -n) hold the triangle last hit, the
remembered side (thin surfaces) and, for closed bodies, whether the vertex was inside. A full
detection records every hit within ``track_range = thickness + 1.5 * displacement_threshold``
(twice the threshold term with the absolute measure):
between two full detections of a pair the relative motion stays under the threshold, so a
vertex that was not tracked cannot reach the contact distance (the 1.5 covers the measure
being a mean + standard deviation, not a maximum).

Bodies must be closed (watertight, consistently oriented): then "inside" is well defined. An
open body triggers a ``warnings.warn`` and is handled as a two-sided thin surface with inversion
memory, so it still never lets a vertex tunnel silently. An inward-oriented closed body is
re-oriented.

Units: SI throughout (metres, m/s).
"""
from __future__ import annotations

import time
import warnings

import numpy as np

from .clusters import Clustering
from .incremental import triangle_adjacency, walk
from .measure import (
    MEASURES,
    AbsoluteMeasure,
    RelativeMeasure,
    box_pairs,
    cluster_boxes,
    cluster_motion,
)
from .narrow import (
    RAY_BACKOFF,
    ClusterScenes,
    Contacts,
    VertexNormals,
    build_scene,
    cast,
    face_normals,
    initial_side,
    ring_table,
    vertex_normals,
)

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


class _Tracks:
    """Per collider, per cloth vertex and ray slot: the triangle hit, remembered side, inside."""

    def __init__(self, n):
        self.tri = np.full((n, 2), -1, np.int64)
        self.side = np.zeros((n, 2), np.int8)
        self.inside = np.zeros(n, bool)

    def resize(self, n, new_vertices=None, parents=None):
        old = self.tri.shape[0]
        tri = np.full((n, 2), -1, np.int64)
        side = np.zeros((n, 2), np.int8)
        inside = np.zeros(n, bool)
        m = min(n, old)
        tri[:m], side[:m], inside[:m] = self.tri[:m], self.side[:m], self.inside[:m]
        if new_vertices is not None and new_vertices.size:
            # A vertex born from a tear sits where its parent was: it inherits the parent's
            # tracks, so its inversion memory is not lost at the moment the cloth opens.
            p = parents[:, 0]
            ok = (p >= 0) & (p < m)
            tri[new_vertices[ok]] = tri[p[ok]]
            side[new_vertices[ok]] = side[p[ok]]
            inside[new_vertices[ok]] = inside[p[ok]]
        self.tri, self.side, self.inside = tri, side, inside


class _Collider:
    """One collision target: a body (closed volume or open surface) or the cloth itself."""

    def __init__(self, name, kind, vertices, triangles, cluster_size, tolerance, friction):
        self.name = name
        self.kind = kind  # 'volume' | 'surface' | 'self'
        self.friction = float(friction)
        self.vertices = vertices
        self.measured = vertices.copy()  # positions at the last detect(): displacement origin
        self.velocities = np.zeros_like(vertices)
        self.set_topology(triangles, cluster_size)
        self.scenes = ClusterScenes(tolerance)

    def set_topology(self, triangles, cluster_size, clustering=None):
        self.triangles = triangles
        self.clustering = clustering or Clustering(self.vertices, triangles, cluster_size)
        self.adj, self.flip = triangle_adjacency(triangles)
        self.normals = VertexNormals(self.vertices.shape[0], triangles)
        # self-collision skips the two-ring (see narrow.ring_table)
        self.ring = ring_table(triangles, self.vertices.shape[0]) if self.kind == "self" else None


class _Plan:
    """One collider's work in a step: close pairs (i cloth cluster, j collider cluster), which
    of them get full detection, and the walked / found hits."""

    __slots__ = ("name", "target", "i", "j", "full", "walked", "found")

    def __init__(self, name, target, i, j, full):
        self.name, self.target, self.i, self.j, self.full = name, target, i, j, full
        self.walked = None
        self.found = None


class CollisionDetector:
    """Clustered ray-traced collision detection of one cloth against bodies and itself.

    Parameters (SI): ``thickness`` contact distance of the cloth (m, > 0); ``friction``
    coefficient reported with every contact; ``displacement_threshold`` relative displacement
    (m, > 0) above which a cluster pair gets full detection; ``cluster_size`` target vertices per
    cluster; ``measure`` 'relative' (paper), 'absolute' (per-cluster, no pairing) or 'full'
    (full detection of every close pair every step); ``self_collision``.
    """

    def __init__(
        self,
        thickness,
        friction,
        displacement_threshold,
        cluster_size=100,
        measure="relative",
        self_collision=True,
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
        if int(cluster_size) < 2:
            raise ValueError(f"cluster_size must be at least 2 vertices, got {cluster_size!r}")
        self.thickness = float(thickness)
        self.friction = float(friction)
        self.displacement_threshold = float(displacement_threshold)
        self.cluster_size = int(cluster_size)
        self.measure = measure
        self.self_collision = bool(self_collision)
        self.inflate = 0.5 * (self.displacement_threshold + self.thickness)
        # Relative motion between two full detections of a pair stays under the threshold (twice
        # it with the absolute measure, see measure.py); 1.5 because the measure is a mean plus
        # a standard deviation, not a maximum.
        reach = 2.0 if measure == "absolute" else 1.0
        self.track_range = self.thickness + 1.5 * reach * self.displacement_threshold
        # Scenes are reused while a cluster deforms (non-rigidly) by less than this; the walker
        # corrects the rest, so it only has to be small against the track range.
        self.scene_tolerance = 0.25 * min(self.thickness, self.displacement_threshold)
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
        self.stats = {}

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
        body = _Collider(
            name, kind, v, t, self.cluster_size, self.scene_tolerance,
            self.friction if friction is None else friction,
        )
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
        self.cloth = _Collider("cloth", "self", v, t, self.cluster_size, self.scene_tolerance, self.friction)
        self._cloth_prev = v.copy()
        self._first = True
        for name in list(self._tracks):
            self._reset_target(name)
        self._reset_target("__self__")

    def _reset_target(self, name):
        n = 0 if self.cloth is None else self.cloth.vertices.shape[0]
        self._tracks[name] = _Tracks(n)
        self._rel[name] = RelativeMeasure(self.displacement_threshold)
        self._abs[name] = AbsoluteMeasure(self.displacement_threshold)
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
        pos = np.asarray(positions, np.float64)
        tri = np.asarray(triangles, np.int64)
        cloth = self.cloth
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
        dirty = cloth.clustering.update(events, pos, tri)
        cloth.triangles = tri
        cloth.adj, cloth.flip = triangle_adjacency(tri)
        cloth.normals = VertexNormals(pos.shape[0], tri)
        cloth.ring = ring_table(tri, pos.shape[0])
        cloth.scenes.invalidate(dirty)
        self._cloth_prev = prev
        for name, tracks in self._tracks.items():
            tracks.resize(pos.shape[0], new_v, parents)
            if name == "__self__":
                tracks.tri[tracks.tri >= tri.shape[0]] = -1
                self._rel[name].forget(dirty, dirty)
            else:
                self._rel[name].forget(dirty, None)
            self._forced[name] = dirty
        self._abs_cloth_forget = dirty
        return dirty

    # ------------------------------------------------------------------ detection
    def detect(self, positions, triangles, velocities=None):
        """Contacts of the cloth at ``positions`` (n,3) m with ``triangles`` (m,3).

        ``velocities`` (n,3) m/s of the cloth, optional: reported as the surface velocity of
        self-collision contacts (zero when not given).
        """
        t_start = time.perf_counter()
        pos = np.asarray(positions, np.float64)
        tri = np.asarray(triangles, np.int64)
        if self.cloth is None or tri.shape != self.cloth.triangles.shape or pos.shape != self.cloth.vertices.shape:
            self.set_cloth(pos, tri)
        cloth = self.cloth
        cloth.vertices = pos
        cloth.velocities = np.zeros_like(pos) if velocities is None else np.asarray(velocities, np.float64)
        self._step += 1
        step = self._step
        normals = cloth.normals(pos)
        has_normal = np.einsum("ij,ij->i", normals, normals) > 0.5

        # 1. measure ---------------------------------------------------------------
        disp = pos - self._cloth_prev
        avg_c, dev_c = cluster_motion(cloth.clustering, disp)
        lo_c, hi_c = cluster_boxes(cloth.clustering, pos, self.inflate)
        due_c = None
        if self.measure == "absolute":
            due_c = self._abs.setdefault("__cloth__", AbsoluteMeasure(self.displacement_threshold)).accumulate(avg_c, dev_c)
            forget = getattr(self, "_abs_cloth_forget", None)
            if forget is not None and len(forget):
                due_c[forget[forget < due_c.size]] = True
                self._abs_cloth_forget = None
        plans = []
        n_close = 0
        for name, target in self._targets():
            if name == "__self__":
                i, j = box_pairs(lo_c, hi_c, lo_c, hi_c, self_pairs=True)
                avg_b, dev_b = avg_c, dev_c
            else:
                avg_b, dev_b = cluster_motion(target.clustering, target.vertices - target.measured)
                lo_b, hi_b = cluster_boxes(target.clustering, target.vertices, self.inflate)
                i, j = box_pairs(lo_c, hi_c, lo_b, hi_b)
            force = np.zeros(i.size, bool)
            forced = self._forced.get(name)
            if self._first or name in self._new_targets:
                force[:] = True
            elif forced is not None and len(forced):
                force |= np.isin(i, forced)
                if name == "__self__":
                    force |= np.isin(j, forced)
            self._forced[name] = None
            self._new_targets.discard(name)
            if self.measure == "relative":
                full = self._rel[name].step(i, j, avg_c, dev_c, avg_b, dev_b, force)
            elif self.measure == "absolute":
                due_b = due_c if name == "__self__" else self._abs[name].accumulate(avg_b, dev_b)
                full = due_c[i] | due_b[j] | force
            else:
                full = np.ones(i.size, bool)
            plans.append(_Plan(name, target, i, j, full))
            n_close += i.size
        t_measure = time.perf_counter()

        # 2. incremental: walk every tracked ray ------------------------------------
        n_lost = 0
        n_tracked = 0
        for plan in plans:
            tracks = self._tracks[plan.name]
            target = plan.target
            v, slot = np.nonzero(tracks.tri >= 0)
            n_tracked += v.size
            d = normals[v] * _SLOT_SIGN[slot][:, None]
            exclude = cloth.ring[v] if plan.name == "__self__" else None
            res = walk(pos[v], d, tracks.tri[v, slot], target.vertices, target.triangles, target.adj, target.flip, exclude)
            lost = (res.tri < 0) & has_normal[v]
            n_lost += int(lost.sum())
            if lost.any() and plan.i.size:
                # The pair (cloth cluster, collider cluster last hit) gets full detection now.
                la = cloth.clustering.labels[v[lost]]
                lb = target.clustering.tri_labels[tracks.tri[v[lost], slot[lost]]]
                if plan.name == "__self__":
                    la, lb = np.minimum(la, lb), np.maximum(la, lb)
                key_lost = np.unique((la << 32) | lb)
                plan.full = plan.full | np.isin((plan.i << 32) | plan.j, key_lost)
            plan.walked = (v, slot, res)
        t_incr = time.perf_counter()

        # 3. full detection of the marked pairs --------------------------------------
        n_full = 0
        for plan in plans:
            n_full += int(plan.full.sum())
            fi, fj = plan.i[plan.full], plan.j[plan.full]
            if plan.name == "__self__":
                # Rays of a into b's triangles and of b into a's (once for a == b).
                other = fi != fj
                fi, fj = np.concatenate([fi, fj[other]]), np.concatenate([fj, fi[other]])
            plan.found = self._full_detection(plan.name, plan.target, fi, fj, pos, normals, has_normal, step)
        t_full = time.perf_counter()

        # 4. merge, classify, contacts -------------------------------------------------
        rows = [self._merge_and_classify(p.name, p.target, p.walked, p.found, pos, normals) for p in plans]
        contacts = self._assemble(rows)
        # Every collider's contact per vertex, for the solver: a vertex touching a body and another
        # layer of cloth at once must respect both (the solver combines their normals).
        self.all_contacts = self._assemble_all(rows)
        t_end = time.perf_counter()

        self._cloth_prev = pos.copy()
        for body in self.bodies.values():
            body.measured = body.vertices.copy()
        self._first = False
        builds = sum(t.scenes.builds for _, t in self._targets())
        self.stats = {
            "close_pairs": n_close,
            "full_pairs": n_full,
            "full_share": (n_full / n_close) if n_close else 0.0,
            "tracked_rays": n_tracked,
            "lost": n_lost,
            "contacts": len(contacts),
            "scene_builds_total": builds,
            "ms": {
                "measure": 1e3 * (t_measure - t_start),
                "incremental": 1e3 * (t_incr - t_measure),
                "full": 1e3 * (t_full - t_incr),
                "contacts": 1e3 * (t_end - t_full),
                "total": 1e3 * (t_end - t_start),
            },
        }
        return contacts

    def _full_detection(self, name, target, fi, fj, pos, normals, has_normal, step):
        """Embree candidates for cloth clusters fi against collider clusters fj, refined exactly.
        Returns (vertex, slot, WalkResult) of the hits kept."""
        cloth = self.cloth
        if fi.size == 0:
            return None
        is_self = name == "__self__"
        vs, slots, cand_tri = [], [], []
        max_dist = self.track_range
        if target.kind == "volume":
            # Inside a body the exit may be far; the acceptance rule below bounds what is kept.
            max_dist = self.track_range + 4.0 * self.inflate + self.cluster_extent(target)
        order = np.argsort(fj, kind="stable")
        fi, fj = fi[order], fj[order]
        bounds = np.flatnonzero(np.diff(np.concatenate([[-1], fj, [-2]])))
        for s, e in zip(bounds[:-1], bounds[1:]):
            b = int(fj[s])
            verts = np.concatenate([cloth.clustering.vertices_of(a) for a in fi[s:e]])
            verts = verts[has_normal[verts]]
            if verts.size == 0:
                continue
            tri_ids = target.clustering.triangles_of(b)
            if tri_ids.size == 0:
                continue
            v2 = np.concatenate([verts, verts])
            sl = np.repeat([0, 1], verts.size)
            d = normals[v2] * _SLOT_SIGN[sl][:, None]
            gt, _ = target.scenes.query(
                b, tri_ids, target.vertices, target.triangles, pos[v2], d, max_dist, step,
                exclude=cloth.ring[v2] if is_self else None,
            )
            hit = gt >= 0
            vs.append(v2[hit])
            slots.append(sl[hit])
            cand_tri.append(gt[hit])
        if not vs:
            return None
        v = np.concatenate(vs)
        slot = np.concatenate(slots)
        ct = np.concatenate(cand_tri)
        d = normals[v] * _SLOT_SIGN[slot][:, None]
        res = walk(pos[v], d, ct, target.vertices, target.triangles, target.adj, target.flip,
                   v if is_self else None, max_steps=4)
        keep = res.tri >= 0
        # Only hits ahead of the ray count for a *new* hit (the scene was cast forward).
        keep &= res.t >= -2e-6
        if target.kind == "volume":
            nrm, _ = face_normals(target.vertices, target.triangles[np.maximum(res.tri, 0)])
            a = target.vertices[target.triangles[np.maximum(res.tri, 0), 0]]
            sd = np.einsum("ij,ij->i", pos[v] - a, nrm)
            inside_prev = self._tracks[name].inside[v]
            # A back face far along the ray only proves "inside" if every triangle in front of
            # it was in the scenes cast; within track_range they are (close pairs). Beyond it,
            # trust it for a vertex that was inside at the previous step, else confirm it by
            # casting the ray into every collider cluster whose box the segment crosses (rare:
            # a vertex entering a body at grazing incidence).
            near = np.abs(res.t) <= self.track_range
            far_inside = keep & ~near & (sd < 0)
            confirm = far_inside & ~inside_prev
            if confirm.any():
                ci = np.flatnonzero(confirm)
                ok = self._confirm_inside(target, pos[v[ci]], normals[v[ci]] * _SLOT_SIGN[slot[ci]][:, None],
                                          res.t[ci], res.tri[ci], step)
                inside_prev = inside_prev.copy()
                inside_prev[ci] = ok
            keep &= near | ((sd < 0) & inside_prev)
        else:
            keep &= np.abs(res.t) <= self.track_range
        return v[keep], slot[keep], _subset(res, keep)

    def _confirm_inside(self, target, o, d, t, tri, step):
        """True where the nearest hit along o + s d over every cluster whose AABB the segment
        [0, t] crosses is the back face ``tri`` (so nothing in front of it was missed)."""
        lo, hi = cluster_boxes(target.clustering, target.vertices, RAY_BACKOFF)
        # Slab test of each segment against each box.
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d
            t1 = (lo[None, :, :] - o[:, None, :]) * inv[:, None, :]
            t2 = (hi[None, :, :] - o[:, None, :]) * inv[:, None, :]
        tmin = np.nanmax(np.minimum(t1, t2), axis=2)
        tmax = np.nanmin(np.maximum(t1, t2), axis=2)
        crosses = (tmin <= tmax) & (tmax >= -RAY_BACKOFF) & (tmin <= t[:, None])
        best = np.full(o.shape[0], np.inf)
        best_tri = np.full(o.shape[0], -1, np.int64)
        for c in np.flatnonzero(crosses.any(axis=0)):
            rows = np.flatnonzero(crosses[:, c])
            tri_ids = target.clustering.triangles_of(c)
            if tri_ids.size == 0:
                continue
            gt, tt = target.scenes.query(int(c), tri_ids, target.vertices, target.triangles,
                                         o[rows], d[rows], t[rows] + RAY_BACKOFF, step)
            better = (gt >= 0) & (tt < best[rows])
            best[rows[better]] = tt[better]
            best_tri[rows[better]] = gt[better]
        # The scenes may be up to scene_tolerance stale: accept the exact exit or any hit close
        # to it, reject a hit clearly in front of it (a front face the close pairs did not see).
        return (best_tri == tri) | (best >= t - self.scene_tolerance)

    @staticmethod
    def cluster_extent(target):
        lo = target.vertices.min(axis=0)
        hi = target.vertices.max(axis=0)
        return float(np.linalg.norm(hi - lo))

    def _merge_and_classify(self, name, target, walked, found, pos, normals):
        """Merge walked tracks with new hits (nearest per vertex and slot), classify, store the
        tracks for the next step. Returns dense per-vertex (depth (n,), normal, velocity,
        friction) of this collider's deepest contact, depth -inf where none."""
        tracks = self._tracks[name]
        n = pos.shape[0]
        tri = np.full((n, 2), -1, np.int64)
        t = np.full((n, 2), np.inf)
        u = np.zeros((n, 2))
        vv = np.zeros((n, 2))
        side = np.zeros((n, 2), np.int8)
        v_w, s_w, r_w = walked
        ok = r_w.tri >= 0
        vw, sw = v_w[ok], s_w[ok]
        tri[vw, sw], t[vw, sw], u[vw, sw], vv[vw, sw] = r_w.tri[ok], r_w.t[ok], r_w.u[ok], r_w.v[ok]
        mem = tracks.side[vw, sw]
        # Remembered side, flipped when the walk crossed an edge of opposite winding.
        side[vw, sw] = np.where(r_w.flips[ok], -mem, mem)
        if found is not None and found[0].size:
            v_f, s_f, r_f = found
            key = v_f * 2 + s_f
            order = np.lexsort((np.abs(r_f.t), key))
            first = np.ones(order.size, bool)
            first[1:] = key[order[1:]] != key[order[:-1]]
            sel = order[first]
            vf, sf = v_f[sel], s_f[sel]
            # Strictly nearer only: on a tie the walked track wins, it carries the memory.
            nearer = np.abs(r_f.t[sel]) < np.abs(t[vf, sf])
            vf, sf, sel = vf[nearer], sf[nearer], sel[nearer]
            ftri = r_f.tri[sel]
            tri[vf, sf], t[vf, sf], u[vf, sf], vv[vf, sf] = ftri, r_f.t[sel], r_f.u[sel], r_f.v[sel]
            # A new hit on a triangle this vertex already tracked (either slot) keeps its memory.
            fmem = np.zeros(vf.size, np.int8)
            for k in (0, 1):
                same = tracks.tri[vf, k] == ftri
                fmem[same] = tracks.side[vf[same], k]
            side[vf, sf] = fmem

        av, asl = np.nonzero(tri >= 0)
        atri = tri[av, asl]
        at = t[av, asl]
        tris = target.triangles[atri]
        nrm, _ = face_normals(target.vertices, tris)
        sd = np.einsum("ij,ij->i", pos[av] - target.vertices[tris[:, 0]], nrm)
        th = self.thickness
        aside = side[av, asl]
        if target.kind == "volume":
            # Only the nearest hit along the normal line decides inside / outside.
            near_slot = np.argmin(np.abs(t), axis=1)
            nearest = asl == near_slot[av]
            inside = nearest & (sd < 0)
            depth = th - sd  # inside (sd < 0): |sd| + thickness; outside: thickness - distance
            contact = nearest & (depth > 0)
            normal = nrm
            keep = (np.abs(at) <= self.track_range) | (sd < 0)
            tracks.inside = np.zeros(n, bool)
            tracks.inside[av[inside]] = True
            aside = np.ones(av.size, np.int8)
        else:
            new = aside == 0
            if new.any():
                aside[new] = self._initial_side(name, target, av[new], atri[new], pos, sd[new])
            inverted = np.where(sd >= 0, 1, -1) != aside
            dist = np.abs(sd)
            depth = np.where(inverted, th + dist, th - dist)
            contact = depth > 0
            normal = nrm * aside[:, None].astype(np.float64)
            if name == "__self__":
                # Layer over layer only: where the other triangle stands edge-on to this vertex's
                # surface (a fold, a torn rim), its normal lies in this vertex's plane, and
                # prescribing velocity along it pins the stiff membrane in-plane - that is how a
                # handful of such contacts pumped a draped cloth to 15 m/s.
                contact &= np.abs(np.einsum("ij,ij->i", nrm, normals[av])) >= 0.5
            keep = (np.abs(at) <= self.track_range) | (inverted & (dist <= self.track_range + th))
            # Both slots on one triangle would double the memory (copied across above): keep
            # slot 0 only.
            both = (tri[av, 0] == atri) & (asl == 1)
            keep &= ~(both & (tri[av, 0] >= 0) & (np.abs(t[av, 0]) <= self.track_range))

        new_tri = np.full((n, 2), -1, np.int64)
        new_side = np.zeros((n, 2), np.int8)
        new_tri[av[keep], asl[keep]] = atri[keep]
        new_side[av[keep], asl[keep]] = aside[keep]
        tracks.tri, tracks.side = new_tri, new_side

        # Deepest contact per vertex (two slots).
        dense = np.full((n, 2), -np.inf)
        c = np.flatnonzero(contact)
        dense[av[c], asl[c]] = depth[c]
        best_slot = np.argmax(dense, axis=1)
        best_depth = dense[np.arange(n), best_slot]
        has = np.isfinite(best_depth)
        # Row index into the active list of each vertex's best (vertex, slot).
        row = np.full((n, 2), -1, np.int64)
        row[av, asl] = np.arange(av.size)
        r = row[np.flatnonzero(has), best_slot[has]]
        out_normal = np.zeros((n, 3))
        out_vel = np.zeros((n, 3))
        out_normal[has] = normal[r]
        vel = target.velocities
        tr = tris[r]
        ur, vr = u[av[r], asl[r]], vv[av[r], asl[r]]
        # hits are found on lines, so (u, v) can fall outside the triangle; the surface velocity
        # must be an interpolation, never an extrapolation (which once reported 10 m/s on a cloth
        # falling at 1 m/s and blew the solver up)
        ur, vr = np.clip(ur, 0.0, 1.0), np.clip(vr, 0.0, 1.0)
        over = ur + vr > 1.0
        scale = np.where(over, 1.0 / np.maximum(ur + vr, 1e-300), 1.0)
        ur, vr = ur * scale, vr * scale
        out_vel[has] = ((1.0 - ur - vr)[:, None] * vel[tr[:, 0]] + ur[:, None] * vel[tr[:, 1]]
                        + vr[:, None] * vel[tr[:, 2]])
        if name == "__self__":
            # Two cloth layers meeting: an inelastic collision of similar masses ends at their
            # common (mean) velocity. Handing each side the other's velocity instead swaps them -
            # an elastic bounce that, through many contacts, pumped a draped cloth to 25 m/s.
            own = self.cloth.velocities[np.flatnonzero(has)]
            out_vel[has] = 0.5 * (out_vel[has] + own)
        return best_depth, out_normal, out_vel, target.friction

    def _initial_side(self, name, target, v, tri, pos, sd_now):
        """Side memory for new tracks, from the motion of the last step (see narrow.initial_side)."""
        if self._first:
            return np.where(sd_now >= 0, 1, -1).astype(np.int8)
        prev_target = self._cloth_prev if name == "__self__" else target.measured
        tris = target.triangles[tri]
        return initial_side(self._cloth_prev[v], pos[v], prev_target[tris], target.vertices[tris])

    @staticmethod
    def _assemble(rows):
        """Deepest contact per vertex over all colliders (dense rows from _merge_and_classify)."""
        if not rows:
            return Contacts()
        depth = np.stack([r[0] for r in rows])
        which = np.argmax(depth, axis=0)
        best = depth[which, np.arange(depth.shape[1])]
        v = np.flatnonzero(best > 0)
        w = which[v]
        normal = np.stack([r[1] for r in rows])[w, v]
        vel = np.stack([r[2] for r in rows])[w, v]
        fric = np.array([r[3] for r in rows], np.float64)[w]
        return Contacts(v.astype(np.int32), normal, best[v], vel, fric)

    @staticmethod
    def _assemble_all(rows):
        """One contact per vertex per collider (rows as for _assemble), sorted by vertex."""
        parts = []
        for depth, normal, vel, fric in rows:
            v = np.flatnonzero(depth > 0)
            if v.size:
                parts.append((v, normal[v], depth[v], vel[v], np.full(v.size, fric, np.float64)))
        if not parts:
            return Contacts()
        v = np.concatenate([p[0] for p in parts])
        order = np.argsort(v, kind="stable")
        return Contacts(
            v[order].astype(np.int32),
            np.concatenate([p[1] for p in parts])[order],
            np.concatenate([p[2] for p in parts])[order],
            np.concatenate([p[3] for p in parts])[order],
            np.concatenate([p[4] for p in parts])[order],
        )

    # ------------------------------------------------------------------ reference
    def brute_force_detect(self, positions, triangles, velocities=None):
        """Reference: one Embree scene per collider built now, every vertex's two rays cast into
        it, no clusters, no history. Thin-surface sides are the current ones (no inversion
        memory), so compare it with ``detect`` on penetrations of closed bodies and proximity."""
        pos = np.asarray(positions, np.float64)
        tri = np.asarray(triangles, np.int64)
        normals = vertex_normals(pos, tri)
        has_normal = np.einsum("ij,ij->i", normals, normals) > 0.5
        verts = np.flatnonzero(has_normal)
        v2 = np.concatenate([verts, verts])
        sl = np.repeat([0, 1], verts.size)
        d = normals[v2] * _SLOT_SIGN[sl][:, None]
        th = self.thickness
        rows = []
        targets = list(self.bodies.items())
        if self.self_collision:
            cloth_vel = np.zeros_like(pos) if velocities is None else np.asarray(velocities, np.float64)
            targets = [("__self__", None)] + targets
        for name, body in targets:
            if name == "__self__":
                tv, tt, kind, vel, fr = pos, tri, "surface", cloth_vel, self.friction
            else:
                tv, tt, kind, vel, fr = body.vertices, body.triangles, body.kind, body.velocities, body.friction
            scene = build_scene(tv, tt)
            reach = self.track_range if kind != "volume" else 1e30
            gt, t = cast(scene, pos[v2], d, reach, np.arange(tt.shape[0]),
                         v2 if name == "__self__" else None, tt)
            hit = gt >= 0
            hv, hs, htri, ht = v2[hit], sl[hit], gt[hit], t[hit]
            nrm, _ = face_normals(tv, tt[htri])
            sd = np.einsum("ij,ij->i", pos[hv] - tv[tt[htri, 0]], nrm)
            if kind == "volume":
                o2 = np.lexsort((ht, hv))
                f2 = np.ones(o2.size, bool)
                f2[1:] = hv[o2[1:]] != hv[o2[:-1]]
                sel = o2[f2]
                depth = th - sd[sel]
                normal = nrm[sel]
            else:
                sel = np.arange(hv.size)
                depth = th - np.abs(sd)
                normal = nrm * np.where(sd >= 0, 1.0, -1.0)[:, None]
            c = depth > 0
            sel = sel[c]
            ctri = tt[htri[sel]]
            # Barycentrics for the surface velocity at the hit point.
            hp = pos[hv[sel]] + ht[sel, None] * d[hit][sel]
            w = _barycentric(hp, tv[ctri[:, 0]], tv[ctri[:, 1]], tv[ctri[:, 2]])
            velocity = np.einsum("ik,ikj->ij", w, vel[ctri])
            rows.append((hv[sel], normal[c], depth[c], velocity, np.full(sel.size, fr)))
        if not rows:
            return Contacts()
        return Contacts.deepest(*(np.concatenate([r[k] for r in rows]) for k in range(5)))


def _barycentric(p, a, b, c):
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


def _subset(res, mask):
    from .incremental import WalkResult

    out = WalkResult(int(mask.sum()))
    out.tri, out.t, out.u, out.v, out.flips = res.tri[mask], res.t[mask], res.u[mask], res.v[mask], res.flips[mask]
    return out
