"""Test oracles of the collision package: numpy specifications of the contact kernels of
``tearcloth._collide`` (``native/collide/contacts.c``) and the brute-force detection.

This file owns nothing the detector runs: ``refine``, ``merge_classify`` and ``assemble`` are the
readable statement of what the C kernels compute (the detector's former numpy code), and
``brute_force_detect`` is every vertex's rays cast into freshly built scenes, without clusters or
history; the tests compare the detector and its kernels with them. The rules are explained in
``tearcloth/collision/narrow.py``. Imported from the tests folder (``import collision_reference``).
"""
from __future__ import annotations

import numpy as np

from tearcloth.collision.incremental import barycentric, walk
from tearcloth.collision.narrow import Contacts, build_scene, cast, face_normals, initial_side, vertex_normals

__all__ = ["refine", "merge_classify", "assemble", "brute_force_detect", "VOLUME", "SURFACE", "SELF"]

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
