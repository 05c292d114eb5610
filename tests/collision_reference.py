"""Test oracles of the collision package: numpy specifications of the contact kernels of
``tearcloth._collide`` (``native/collide/contacts.c``) and the brute-force detection.

This file owns nothing the detector runs: ``refine``, ``merge_classify`` and ``assemble`` are the
readable statement of what the C kernels compute (the detector's former numpy code),
``brute_force_detect`` is every vertex's rays cast into freshly built scenes, without clusters or
history, and ``ReferenceDetector`` is the detector's step as the previous release orchestrated it
(Python over the per-stage kernels, Embree for bodies); the tests compare the detector and its
kernels with them. The rules are explained in
``tearcloth/collision/narrow.py``. Imported from the tests folder (``import collision_reference``).
"""
from __future__ import annotations

import numpy as np

import time

from tearcloth import _collide
from tearcloth.collision import kernels
from tearcloth.collision.detector import CollisionDetector, _Plan
from tearcloth.collision.incremental import barycentric, walk
from tearcloth.collision.narrow import (RAY_BACKOFF, ClusterBVH, ClusterScenes, Contacts, build_scene, cast,
                                        face_normals, initial_side, vertex_normals)

__all__ = ["refine", "merge_classify", "assemble", "brute_force_detect", "ReferenceDetector", "skipped_pairs",
           "VOLUME", "SURFACE", "SELF"]

VOLUME, SURFACE, SELF = 0, 1, 2
_SLOT_SIGN = np.array([1.0, -1.0])


def refine(pos, normals, ray_v, ray_slot, hit_tri, tv, tt, adj, flip, ring, kind, track_range, inside_prev):
    """Walk every Embree candidate (hit_tri >= 0) at most 4 steps on the current geometry; keep a
    found hit ahead of the ray (t >= -2e-6). Returns (v, slot, WalkResult, status) of the kept ones:
    status 1 = keep, 2 = a volume's back face beyond track_range for a vertex that was not inside
    (needs the caller's confirmation); hits dropped by the range rules are not returned."""
    c = np.flatnonzero(hit_tri >= 0)
    v, s = ray_v[c], ray_slot[c]
    d = normals[v] * _SLOT_SIGN[s][:, None]
    res = walk(pos[v], d, hit_tri[c], tv, tt, adj, flip, None if ring is None else ring[v], max_steps=4)
    ok = (res.tri >= 0) & (res.t >= -2e-6)
    near = np.abs(res.t) <= track_range
    if kind == VOLUME:
        nrm, _ = face_normals(tv, tt[np.maximum(res.tri, 0)])
        sd = np.einsum("ij,ij->i", pos[v] - tv[tt[np.maximum(res.tri, 0), 0]], nrm)
        prev = np.zeros(v.size, bool) if inside_prev is None else inside_prev[v]
        status = np.where(near, 1, np.where(sd < 0, np.where(prev, 1, 2), 0))
    else:
        status = np.where(near, 1, 0)
    keep = ok & (status > 0)
    res.tri, res.t, res.u, res.v, res.flips = (res.tri[keep], res.t[keep], res.u[keep], res.v[keep],
                                               res.flips[keep])
    return v[keep], s[keep], res, status[keep].astype(np.uint8)


def merge_classify(pos, normals, prev, velocity, tv, tt, target_prev, target_velocity, kind, first, thickness,
                   track_range, track_tri, track_side, track_inside, walked, found):
    """Merge walked tracks with new hits (nearest per vertex and slot), classify, and return
    (new track_tri (n,2), track_side (n,2), track_inside (n,), depth (n,) -inf where none,
    normal (n,3), contact velocity (n,3)) of this collider's deepest contact per vertex.

    walked / found: (v, slot, hits with tri, t, u, v, flips); found may carry a 4th item, status
    (only 1 is kept). velocity / target_velocity None mean zero."""
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
    mem = track_side[vw, sw]
    # Remembered side, flipped when the walk crossed an edge of opposite winding.
    side[vw, sw] = np.where(r_w.flips[ok], -mem, mem)
    if found is not None and found[0].size:
        v_f, s_f, r_f = found[:3]
        keepf = np.ones(v_f.size, bool) if len(found) < 4 or found[3] is None else found[3] == 1
        v_f, s_f = v_f[keepf], s_f[keepf]
        ft, fu, fv, ftri = r_f.t[keepf], r_f.u[keepf], r_f.v[keepf], r_f.tri[keepf]
        key = v_f * 2 + s_f
        order = np.lexsort((np.abs(ft), key))
        first_of = np.ones(order.size, bool)
        first_of[1:] = key[order[1:]] != key[order[:-1]]
        sel = order[first_of]
        vf, sf = v_f[sel], s_f[sel]
        # Strictly nearer only: on a tie the walked track wins, it carries the memory.
        nearer = np.abs(ft[sel]) < np.abs(t[vf, sf])
        vf, sf, sel = vf[nearer], sf[nearer], sel[nearer]
        tri[vf, sf], t[vf, sf], u[vf, sf], vv[vf, sf] = ftri[sel], ft[sel], fu[sel], fv[sel]
        # A new hit on a triangle this vertex already tracked (either slot) keeps its memory.
        fmem = np.zeros(vf.size, np.int8)
        for k in (0, 1):
            same = track_tri[vf, k] == ftri[sel]
            fmem[same] = track_side[vf[same], k]
        side[vf, sf] = fmem

    av, asl = np.nonzero(tri >= 0)
    atri = tri[av, asl]
    at = t[av, asl]
    tris = tt[atri]
    nrm, _ = face_normals(tv, tris)
    sd = np.einsum("ij,ij->i", pos[av] - tv[tris[:, 0]], nrm)
    th = thickness
    aside = side[av, asl]
    new_inside = np.asarray(track_inside, bool).copy()
    if kind == VOLUME:
        near_slot = np.argmin(np.abs(t), axis=1)
        nearest = asl == near_slot[av]
        inside = nearest & (sd < 0)
        depth = th - sd
        contact = nearest & (depth > 0)
        normal = nrm
        keep = (np.abs(at) <= track_range) | (sd < 0)
        new_inside = np.zeros(n, bool)
        new_inside[av[inside]] = True
        aside = np.ones(av.size, np.int8)
    else:
        new = aside == 0
        if new.any():
            if first:
                aside[new] = np.where(sd[new] >= 0, 1, -1)
            else:
                tn = tris[new]
                aside[new] = initial_side(prev[av[new]], pos[av[new]], target_prev[tn], tv[tn])
        inverted = np.where(sd >= 0, 1, -1) != aside
        dist = np.abs(sd)
        depth = np.where(inverted, th + dist, th - dist)
        contact = depth > 0
        normal = nrm * aside[:, None].astype(np.float64)
        if kind == SELF:
            contact &= np.abs(np.einsum("ij,ij->i", nrm, normals[av])) >= 0.5
        keep = (np.abs(at) <= track_range) | (inverted & (dist <= track_range + th))
        both = (tri[av, 0] == atri) & (asl == 1)
        keep &= ~(both & (tri[av, 0] >= 0) & (np.abs(t[av, 0]) <= track_range))

    new_tri = np.full((n, 2), -1, np.int64)
    new_side = np.zeros((n, 2), np.int8)
    new_tri[av[keep], asl[keep]] = atri[keep]
    new_side[av[keep], asl[keep]] = aside[keep]

    dense = np.full((n, 2), -np.inf)
    c = np.flatnonzero(contact)
    dense[av[c], asl[c]] = depth[c]
    best_slot = np.argmax(dense, axis=1)
    best_depth = dense[np.arange(n), best_slot]
    has = np.isfinite(best_depth)
    row = np.full((n, 2), -1, np.int64)
    row[av, asl] = np.arange(av.size)
    r = row[np.flatnonzero(has), best_slot[has]]
    out_normal = np.zeros((n, 3))
    out_vel = np.zeros((n, 3))
    out_normal[has] = normal[r]
    vel = np.zeros_like(tv) if target_velocity is None else target_velocity
    tr = tris[r]
    ur, vr = u[av[r], asl[r]], vv[av[r], asl[r]]
    ur, vr = np.clip(ur, 0.0, 1.0), np.clip(vr, 0.0, 1.0)
    over = ur + vr > 1.0
    scale = np.where(over, 1.0 / np.maximum(ur + vr, 1e-300), 1.0)
    ur, vr = ur * scale, vr * scale
    out_vel[has] = ((1.0 - ur - vr)[:, None] * vel[tr[:, 0]] + ur[:, None] * vel[tr[:, 1]]
                    + vr[:, None] * vel[tr[:, 2]])
    if kind == SELF:
        own = np.zeros((has.sum(), 3)) if velocity is None else velocity[np.flatnonzero(has)]
        out_vel[has] = 0.5 * (out_vel[has] + own)
    return new_tri, new_side, new_inside, best_depth, out_normal, out_vel


def assemble(depth, normal, velocity, friction):
    """(deepest per vertex, every contact by vertex then collider), each as (vertex int32,
    normal, depth, velocity, friction), from per-collider dense rows depth (c, n) etc."""
    c, n = depth.shape
    if c == 0:
        z = (np.zeros(0, np.int32), np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)), np.zeros(0))
        return z, z
    which = np.argmax(depth, axis=0)
    best = depth[which, np.arange(n)]
    v = np.flatnonzero(best > 0)
    w = which[v]
    deep = (v.astype(np.int32), normal[w, v], best[v], velocity[w, v], np.asarray(friction, np.float64)[w])
    cols, vs = np.nonzero(depth > 0)
    order = np.lexsort((cols, vs))
    cols, vs = cols[order], vs[order]
    every = (vs.astype(np.int32), normal[cols, vs], depth[cols, vs], velocity[cols, vs],
             np.asarray(friction, np.float64)[cols])
    return deep, every


def brute_force_detect(detector, positions, triangles, velocities=None):
    """The contacts ``detector.detect`` should find, found the slow way: one Embree scene per
    collider of ``detector`` (its bodies, and the cloth itself with self-collision) built now,
    every vertex's two rays cast into it, no clusters, no history. Thin-surface sides are the current ones (no inversion
    memory), so compare it with ``detect`` on penetrations of closed bodies and proximity."""
    pos = np.asarray(positions, np.float64)
    tri = np.asarray(triangles, np.int64)
    normals = vertex_normals(pos, tri)
    has_normal = np.einsum("ij,ij->i", normals, normals) > 0.5
    verts = np.flatnonzero(has_normal)
    v2 = np.concatenate([verts, verts])
    sl = np.repeat([0, 1], verts.size)
    d = normals[v2] * _SLOT_SIGN[sl][:, None]
    th = detector.thickness
    rows = []
    targets = list(detector.bodies.items())
    if detector.self_collision:
        cloth_vel = np.zeros_like(pos) if velocities is None else np.asarray(velocities, np.float64)
        targets = [("__self__", None)] + targets
    for name, body in targets:
        if name == "__self__":
            tv, tt, kind, vel, fr = pos, tri, "surface", cloth_vel, detector.friction
        else:
            tv, tt, kind, vel, fr = body.vertices, body.triangles, body.kind, body.velocities, body.friction
        scene = build_scene(tv, tt)
        reach = detector.track_range if kind != "volume" else 1e30
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
        w = barycentric(hp, tv[ctri[:, 0]], tv[ctri[:, 1]], tv[ctri[:, 2]])
        velocity = np.einsum("ik,ikj->ij", w, vel[ctri])
        rows.append((hv[sel], normal[c], depth[c], velocity, np.full(sel.size, fr)))
    if not rows:
        return Contacts()
    return Contacts.deepest(*(np.concatenate([r[k] for r in rows]) for k in range(5)))


# ---------------------------------------------------------------------------- the reference detector
class _Normals:
    """The cloth's vertex normals of one step, computed (C) per cluster when first needed: a step
    reads the normals of the vertices it walks or casts rays from, often a few clusters or none.
    ``normals`` / ``has_normal`` rows of clusters not asked for are not valid."""

    __slots__ = ("cloth", "pos", "normals", "has_normal", "done")

    def __init__(self, cloth, pos):
        self.cloth, self.pos = cloth, pos
        self.normals = np.empty_like(pos)
        self.has_normal = np.zeros(pos.shape[0], bool)
        self.done = np.zeros(cloth.clustering.n_clusters, bool)

    def need(self, clusters):
        cl = self.cloth.clustering
        _collide.cluster_normals(self.pos, self.cloth.triangles, self.cloth.vt_ptr, self.cloth.vt_tri, cl.order,
                                 cl.ptr, clusters, self.normals, self.has_normal, self.done)



class ReferenceDetector(CollisionDetector):
    """The detector's step as the previous release ran it, the specification its C pipeline
    (``native/collide/detect.c``) must equal: the orchestration in Python and numpy over the
    per-stage kernels, bodies in Embree scenes kept in each cluster's rigid frame
    (``narrow.ClusterScenes``, candidates refined on the current geometry), the cloth in its own
    trees (``narrow.ClusterBVH.cast_self``), the rays of each close pair cast and refined apart and
    merged. Its state is the detector's, so one can be swapped for the other between steps."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        # Scenes are reused while a cluster deforms (non-rigidly) by less than this (narrow.py)
        self.scene_tolerance = 1.0 * min(self.thickness, self.displacement_threshold)
        self._rays = kernels.RayBuffer()

    def add_body(self, vertices, triangles, name, friction=None):
        body = super().add_body(vertices, triangles, name, friction)
        body.scenes = ClusterScenes(self.scene_tolerance)
        body.scenes.set_topology(body.triangles, body.clustering, body.adj)
        return body

    def __setstate__(self, state):
        # the previous release's: the Embree scenes remade from their build corners
        self.__dict__.update(state)
        for collider in (self.cloth, *self.bodies.values()):
            if collider is not None:
                collider.scenes.rebuild(collider.triangles)

    def detect(self, positions, triangles, velocities=None, dt=None):
        out = self._reference_detect(positions, triangles, velocities, dt)
        # cast_self refits the cloth's trees without their corner copies: the detector's pipeline,
        # should it take over, refits them again
        self.cloth.scenes.refit_step[:] = -1
        return out

    def old_release_state(self):
        """This detector's state as the previous release's CollisionDetector pickled it: the same
        fields (the Embree scenes' settings; the swept stage's blocks as (ptr, vptr, vertices, min,
        debt), every bound unknown; the cloth's trees without corner copies)."""
        import copy

        state = {k: v for k, v in self.__dict__.items() if k not in ("_ws", "_pair_cap")}
        state = copy.copy(state)
        state["self_scenes"] = "bvh"
        cloth = copy.copy(self.cloth)
        cloth.scenes = copy.copy(cloth.scenes)
        cloth.scenes.__dict__.pop("corner", None)
        state["cloth"] = cloth
        sw = state.get("_swept")
        if sw is not None:
            old = type(sw).__new__(type(sw))
            old.__dict__.update({k: v for k, v in sw.__dict__.items()
                                 if k not in ("n", "group_ptr", "group_vertices", "has_reference", "blocks", "_buf",
                                              "live")})
            old.blocks = {kind: (b[0], b[1], b[2], np.full(b[3].shape[0], -np.inf), np.zeros(b[3].shape[0]))
                          for kind, b in sw.blocks.items()}
            old.vt_slack, old.ee_slack = np.full_like(sw.vt_slack, -np.inf), np.full_like(sw.ee_slack, -np.inf)
            state["_swept"] = old
        return state

    def _reference_detect(self, positions, triangles, velocities=None, dt=None):
        """Contacts of the cloth at ``positions`` (n,3) m with ``triangles`` (m,3).

        ``velocities`` (n,3) m/s of the cloth, optional: reported as the surface velocity of
        self-collision contacts (zero when not given). ``dt`` (s), optional: the coming step, over
        which the swept stage predicts the two-ring's motion (without it, or without velocities,
        that stage only catches crossings after the fact).
        """
        t_start = time.perf_counter()
        pos, step = self._begin_step(positions, triangles, velocities)
        cloth = self.cloth
        lazy = _Normals(cloth, pos)
        normals, has_normal = lazy.normals, lazy.has_normal

        # 1. measure ---------------------------------------------------------------
        bound_rule = self.measure == "relative" and self.trip_rule == "bound"
        if bound_rule:
            fit_c = kernels.cluster_fit(cloth.clustering, pos, self._cloth_prev, self.trip_reach)
            side_c = (cloth.clustering, pos, self._cloth_prev, fit_c)
        else:
            avg_c, dev_c = kernels.cluster_motion(cloth.clustering, pos, self._cloth_prev)
        lo_c, hi_c = kernels.cluster_boxes(cloth.clustering, pos, self.inflate)
        due_c = self._cloth_due(avg_c, dev_c) if self.measure == "absolute" else None
        plans = []
        n_close = 0
        for name, target in self._targets():
            if name == "__self__":
                lo_b, hi_b = lo_c, hi_c
                i, j = kernels.box_pairs(lo_c, hi_c, lo_c, hi_c, self_pairs=True)
                if bound_rule:
                    side_b = side_c
                else:
                    avg_b, dev_b = avg_c, dev_c
            else:
                if bound_rule:
                    fit_b = kernels.cluster_fit(target.clustering, target.vertices, target.measured, self.trip_reach)
                    side_b = (target.clustering, target.vertices, target.measured, fit_b)
                else:
                    avg_b, dev_b = kernels.cluster_motion(target.clustering, target.vertices, target.measured)
                lo_b, hi_b = kernels.cluster_boxes(target.clustering, target.vertices, self.inflate)
                i, j = kernels.box_pairs(lo_c, hi_c, lo_b, hi_b)
            force = None
            forced = self._forced.get(name)
            first = self._first or name in self._new_targets
            if first:
                force = np.ones(i.size, bool)
            elif forced is not None and len(forced):
                force = np.isin(i, forced)
                if name == "__self__":
                    force |= np.isin(j, forced)
            self._forced[name] = None
            self._new_targets.discard(name)
            if bound_rule:
                bound = kernels.pair_motion(i, j, side_c, side_b, self.trip_reach)
                full = self._rel[name].step(i, j, bound, lo_c, hi_c, lo_b, hi_b, force)
            elif self.measure == "relative":
                full = self._rel[name].step(i, j, avg_c, dev_c, avg_b, dev_b, force)
            elif self.measure == "absolute":
                due_b = due_c if name == "__self__" else self._abs[name].accumulate(avg_b, dev_b)
                full = due_c[i] | due_b[j]
                if force is not None:
                    full |= force
            else:
                full = np.ones(i.size, bool)
            plan = _Plan(name, target, i, j, full)
            plan.lo, plan.hi, plan.first = lo_b, hi_b, first
            plans.append(plan)
            n_close += i.size
        t_measure = time.perf_counter()

        # 2. incremental: walk every tracked ray ------------------------------------
        n_lost = 0
        n_tracked = 0
        for plan in plans:
            tracks = self._tracks[plan.name]
            target = plan.target
            n_tracked += tracks.key.size
            if tracks.key.size == 0:
                plan.walked = kernels.NO_HITS
                continue
            v, slot, start = tracks.key >> 1, tracks.key & 1, tracks.tri
            lazy.need(np.ascontiguousarray(cloth.clustering.labels[v]))
            res = kernels.walk(pos, normals, v, slot, start, target, cloth.ring if plan.name == "__self__" else None)
            lost = (res.tri < 0) & has_normal[v]
            n_lost += int(lost.sum())
            if lost.any() and plan.i.size:
                # The pair (cloth cluster, collider cluster last hit) gets full detection now.
                la = cloth.clustering.labels[v[lost]]
                lb = target.clustering.tri_labels[start[lost]]
                if plan.name == "__self__":
                    la, lb = np.minimum(la, lb), np.maximum(la, lb)
                key_lost = np.unique((la << 32) | lb)
                plan.full = plan.full | np.isin((plan.i << 32) | plan.j, key_lost)
            plan.walked = res
        t_incr = time.perf_counter()

        # 3. full detection of the marked pairs --------------------------------------
        n_full = 0
        t_self = c_self = 0.0
        n_rays = 0
        for plan in plans:
            nf = int(np.count_nonzero(plan.full))
            n_full += nf
            if nf == 0:
                continue
            fi, fj = plan.i[plan.full], plan.j[plan.full]
            if plan.name == "__self__":
                # Rays of a into b's triangles and of b into a's (once for a == b).
                other = fi != fj
                fi, fj = np.concatenate([fi, fj[other]]), np.concatenate([fj, fi[other]])
            lazy.need(fi)
            t_plan, c_plan = time.perf_counter(), time.process_time()
            plan.found, rays = self._full_detection(plan, fi, fj, pos, normals, has_normal, step)
            if plan.name == "__self__":
                t_self, c_self = time.perf_counter() - t_plan, time.process_time() - c_plan
            n_rays += rays
        t_full = time.perf_counter()

        # 4. merge, classify, contacts -------------------------------------------------
        rows = [self._merge_and_classify(plan, pos, normals) for plan in plans]
        contacts, every = self._assemble_rows(rows, pos.shape[0])
        # Every collider's contact per vertex, for the solver: a vertex touching a body and another
        # layer of cloth at once must respect both (the solver combines their normals).
        t_end = time.perf_counter()
        self.all_contacts = CollisionDetector._swept_stage(self, every, pos, dt)
        t_swept = time.perf_counter()

        self._cloth_prev = pos.copy()
        for body in self.bodies.values():
            body.measured = body.vertices  # update_body replaces, never mutates, the array
        self._first = False
        builds = sum(t.scenes.builds for _, t in self._targets())
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
                "measure": 1e3 * (t_measure - t_start),
                "incremental": 1e3 * (t_incr - t_measure),
                "full": 1e3 * (t_full - t_incr),
                "contacts": 1e3 * (t_end - t_full),
                "total": 1e3 * (t_swept - t_start),
                "full_self": 1e3 * t_self,  # of "full": the cloth against itself
                "full_self_cpu": 1e3 * c_self,  # the same, process CPU (Embree builds use a second thread)
                "swept": 1e3 * (t_swept - t_end),
            },
            "swept_pairs": 0 if self._swept is None else self._swept.n_pairs,
            **{f"swept_{k}": v for k, v in (self._swept.counts if self._swept is not None else {}).items()},
        }
        return contacts

    def _full_detection(self, plan, fi, fj, pos, normals, has_normal, step):
        """Candidates (Embree for a body, the cloth's BVHs for itself) for cloth clusters fi against
        collider clusters fj, refined exactly. Returns ((vertex, slot, Hits, status) of the hits found, or None; rays cast)."""
        name, target = plan.name, plan.target
        cloth = self.cloth
        if fi.size == 0:
            return None, 0
        is_self = name == "__self__"
        kind = "self" if is_self else target.kind
        ring = cloth.ring if is_self else None
        # A closed body's rays reach across it (the module docs: Ray length); inside_prev trusts a
        # far exit for a vertex that was inside at the previous step.
        short = long_ = self.track_range
        inside_prev = None
        if target.kind == "volume":
            tracks = self._tracks[name]
            if tracks.inside.size:
                inside_prev = tracks.inside_mask()
            # the longest way through the body: its box diagonal (from the cluster boxes at hand)
            extent = float(np.linalg.norm(plan.hi.max(axis=0) - plan.lo.min(axis=0)))
            if not np.isfinite(extent):
                extent = self.cluster_extent(target)
            short = long_ = self.track_range + 2.0 * self.inflate + extent
        scenes = target.scenes
        if isinstance(scenes, ClusterBVH):
            # the cloth against itself: every pair's rays, refits and two-ring filter in one C call
            rv, rslot, hit, count = scenes.cast_self(pos, normals, has_normal, cloth.clustering, plan.lo, plan.hi,
                                                     target.triangles, ring, fi, fj, step, short, RAY_BACKOFF)
            return self._refine(plan, kind, ring, inside_prev, rv, rslot, hit, pos, normals), count
        # One group per collider cluster, each cluster's scene fitted (or rebuilt) once.
        order = np.argsort(fj, kind="stable")
        fi, fj = fi[order], fj[order]
        ub = np.unique(fj)
        buf = self._rays
        args = (pos, normals, has_normal, None, cloth.clustering, plan.lo, plan.hi)
        dist_args = (short, long_, RAY_BACKOFF, scenes.tolerance)
        # Which collider clusters get any ray at all (the culling runs twice; it is cheap): only
        # their scenes are fitted, or built.
        seg = buf.count(*args, fi, fj, ub, scenes, *dist_args)
        need = ub[seg[1:] > seg[:-1]]
        if need.size == 0:
            return None, 0
        usable = scenes.fit(need, target.vertices, target.triangles, step)
        if not usable.all():
            keep = np.isin(fj, need[usable])
            fi, fj = fi[keep], fj[keep]
            ub = np.unique(fj)
        count, seg = buf.prepare(*args, fi, fj, ub, scenes, *dist_args)
        if count == 0:
            return None, 0
        hit = np.empty(count, np.int64)
        retry = np.empty(count, np.int64)
        o, d, dist = buf.o, buf.d, buf.dist
        oc, dc, distc = o[:count], d[:count], dist[:count]
        rv = buf.vertex[:count]
        seg = seg.tolist()
        ptr = scenes.ptr
        for g, b in enumerate(ub.tolist()):
            s, e = seg[g], seg[g + 1]
            if s == e:
                continue
            scene, stri = scenes.scene[b], scenes.tri[ptr[b]:ptr[b + 1]]
            rays = np.arange(s, e, dtype=np.int64)
            if not is_self:
                prim = scene.run(o[s:e], d[s:e], dists=dist[s:e])
                _collide.accept_hits(rays, prim, None, stri, rv, target.triangles, None, oc, dc, distc, hit, retry)
                continue
            # Self: skip the vertex's own two-ring by casting again from just past it (embreex has
            # no hit filter). embreex writes tfar into the dists it is given: hand it a copy.
            res = scene.run(o[s:e], d[s:e], dists=dist[s:e].copy(), output=1)
            for _ in range(8):
                again = _collide.accept_hits(rays, res["primID"], res["tfar"], stri, rv, target.triangles, ring, oc,
                                             dc, distc, hit, retry)
                if again == 0:
                    break
                rays = retry[:again].copy()
                res = scene.run(o[rays], d[rays], dists=dist[rays], output=1)
        return self._refine(plan, kind, ring, inside_prev, rv, buf.slot[:count], hit, pos, normals), count

    def _refine(self, plan, kind, ring, inside_prev, rv, rslot, hit, pos, normals):
        """Candidate hits (ray vertex, slot, triangle or -1) made exact on the current geometry
        (Embree's scenes may be up to their tolerance stale): (vertex, slot, Hits, status) or None."""
        name, target = plan.name, plan.target
        count = rv.size
        if count == 0:
            return None
        ints = np.empty((3, count), np.int64)
        reals = np.empty((3, count))
        flags = np.empty((2, count), bool)
        k = _collide.refine(pos, normals, rv, rslot, hit, target.vertices, target.triangles, target.adj,
                            target.flip, ring, kernels.KIND[kind], self.track_range, inside_prev, ints[0], ints[1],
                            ints[2], reals[0], reals[1], reals[2], flags[0], flags[1])
        if k == 0:
            return None
        fv, fs = ints[0, :k], ints[1, :k]
        res = kernels.Hits.view(ints[2, :k], reals[0, :k], reals[1, :k], reals[2, :k], flags[0, :k])
        status = flags[1, :k].view(np.uint8)
        if target.kind == "volume":
            # far back faces: not the exit if a nearer hit of the same ray exists (C), else tested
            tracks, walked = self._tracks[name], plan.walked
            if _collide.drop_dominated(fv, fs, res.t, status.view(bool), tracks.key, walked.tri, walked.t):
                c2 = np.flatnonzero(status == 2)
                status[c2] = self._confirm_inside(plan, fv, fs, res, c2, pos, normals)
        return fv, fs, res, status

    def _confirm_inside(self, plan, fv, fs, res, c2, pos, normals):
        """1 for each far back-face hit c2 that is the ray's first hit on the body (the vertex is
        inside), else 0: tested exactly (C) against the triangles of every collider cluster whose
        box the segment crosses, on the current geometry - no scene to fit or rebuild. (Hits that
        a nearer hit of the same ray already disproves are dropped before, by drop_dominated.)"""
        target = plan.target
        d = normals[fv[c2]] * np.where(fs[c2] == 0, 1.0, -1.0)[:, None]
        ok = np.empty(c2.size, bool)
        cl = target.clustering
        _collide.confirm_inside(target.vertices, target.triangles, cl.tri_order, cl.tri_starts, plan.lo, plan.hi,
                                pos[fv[c2]], d, res.t[c2], res.tri[c2], RAY_BACKOFF, 1e-6, ok)
        return ok

    @staticmethod
    def cluster_extent(target):
        """Diagonal (m) of the collider's bounding box: the longest a ray inside it can travel."""
        lo = target.vertices.min(axis=0)
        hi = target.vertices.max(axis=0)
        return float(np.linalg.norm(hi - lo))

    def _merge_and_classify(self, plan, pos, normals):
        """Merge walked tracks with new hits (nearest per vertex and slot), classify (C), store the
        tracks for the next step. Returns this collider's deepest contact per vertex, sorted by
        vertex: (vertex, depth, normal, velocity, friction)."""
        name, target = plan.name, plan.target
        tracks = self._tracks[name]
        if tracks.key.size == 0 and plan.found is None:
            # nothing tracked, nothing found: no tracks, nobody inside, no contact
            tracks.inside = kernels.EMPTY_I64
            return kernels.EMPTY_I64, None, None, None, target.friction
        is_self = name == "__self__"
        r_w = plan.walked
        if plan.found is not None:
            v_f, s_f, r_f, st = plan.found
        else:
            v_f = s_f = kernels.EMPTY_I64
            r_f, st = kernels.NO_HITS, None
        cap = tracks.key.size + v_f.size
        okey, otri, oin, cv = np.empty((4, cap), np.int64)
        oside = np.empty(cap, np.int8)
        depth = np.empty(cap)
        normal, velocity = np.empty((2, cap, 3))
        cloth_vel = self.cloth.velocities
        nt, ni, nc = _collide.merge_classify(
            positions=pos, normals=normals, previous=self._cloth_prev, velocity=cloth_vel,
            target_vertices=target.vertices, target_triangles=target.triangles,
            target_previous=self._cloth_prev if is_self else target.measured,
            target_velocity=cloth_vel if is_self else target.velocities,
            kind=kernels.KIND["self" if is_self else target.kind], first=self._first,
            thickness=self.thickness, track_range=self.track_range,
            track_key=tracks.key, track_tri=tracks.tri, track_side=tracks.side,
            walked_tri=r_w.tri, walked_t=r_w.t, walked_u=r_w.u, walked_v=r_w.v, walked_flips=r_w.flips,
            found_vertex=v_f, found_slot=s_f, found_tri=r_f.tri, found_t=r_f.t, found_u=r_f.u, found_v=r_f.v,
            found_flips=r_f.flips, found_status=None if st is None else st.view(bool),
            out_key=okey, out_tri=otri, out_side=oside, out_inside=oin,
            contact_vertex=cv, depth=depth, normal=normal, contact_velocity=velocity,
        )
        tracks.key, tracks.tri, tracks.side = okey[:nt], otri[:nt], oside[:nt]
        if target.kind == "volume" and not is_self:
            tracks.inside = oin[:ni]
        return cv[:nc], depth[:nc], normal[:nc], velocity[:nc], target.friction


def skipped_pairs(triangles, ring, n):
    """numpy specification of swept.skipped_pairs (the previous release's code): (edges, vt, ee)."""
    t = np.asarray(triangles, np.int64)
    e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    edges = np.unique(np.sort(e, axis=1), axis=0)
    u = ring[t].reshape(t.shape[0], -1)
    ti = np.repeat(np.arange(t.shape[0]), u.shape[1])
    u = u.reshape(-1)
    ok = (u >= 0) & (u != t[ti, 0]) & (u != t[ti, 1]) & (u != t[ti, 2])
    vt = np.unique(np.stack([u[ok], ti[ok]], 1), axis=0)
    ends = edges.reshape(-1)
    eid = np.repeat(np.arange(edges.shape[0]), 2)
    order = np.argsort(ends, kind="stable")
    counts = np.bincount(ends, minlength=n)
    inc = np.full((n, max(int(counts.max(initial=0)), 1)), -1, np.int64)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    inc[ends[order], np.arange(order.size) - start[ends[order]]] = eid[order]
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
