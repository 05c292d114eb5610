"""The T-shirt's making, measured on the mannequin: the flat pattern of its front and back panels,
meshing and sewing them into one surface, laying it on the body, fitting it at a clearance, and
cleaning up the slivers the fit leaves.

This file owns ``shirt_pattern`` (panel outlines and seams from the body's measurements),
``cut_and_sew`` (mesh both panels with the same seam samples and merge the seam vertices),
``frontal_map`` / ``raycast_depth`` (wrap the flat pattern around the body), ``fit_shirt``
(settle every vertex ``clearance`` outside the body while rims keep their curves), ``loop_order``,
``flip_edges`` and ``collapse_short_edges``. ``scenes.tshirt`` runs them in order. SI units.
"""
from __future__ import annotations

import math

import numpy as np

from .distance import closest_on_segments
from .mannequin import Body, arm_frame, ellipse_perimeter, pchip, smoothstep
from .mesh import edge_keys, triangle_angles, validate_mesh
from .mesher import (
    as_pieces,
    interior_candidates,
    mesh_points,
    predicted_count,
    sample_outline,
    search_spacing,
)


# ------------------------------------------------------------------------------------------------
# T-shirt: two flat panels sewn together, fitted around the mannequin
# ------------------------------------------------------------------------------------------------

_SHIRT_HEM_Z = 0.88  # m at height 1.75: the hem sits on the hips
_SHIRT_SLEEVE = 0.15  # m, underarm seam length (short sleeves end above the elbow)
_ARMPIT_CUT = 0.10  # m of side seam and underarm seam replaced by the rounded armpit curve
_NECK_DEPTH = (0.075, 0.025)  # front / back scoop of the neckline below the neck side points


def shirt_pattern(body: Body, clearance: float):
    """The flat pattern of the two T-shirt panels, measured on the body.

    Returns (pieces for the front, pieces for the back, seam piece indices, dims). Both panels
    share every piece except the neckline, so their seam samples coincide. Panel coordinates
    (s, t): s across (+s is the wearer's left, +X), t up from the hem, metres. The sleeves leave
    at the A-pose arm angle, so the flat pattern already points along the arms.
    """
    m = body.measurements
    s = m["scale"]
    col = m["column_profile"]
    c = clearance
    z_hem = _SHIRT_HEM_Z * s
    z_arm = m["armpit_z"] - 0.015 * s
    zz = np.linspace(z_hem, z_arm, 40)
    a = pchip(col[:, 0], col[:, 1], zz)
    b = pchip(col[:, 0], col[:, 2], zz)
    half_round = float(ellipse_perimeter(a + c, b + c).max()) / 2.0
    W2 = half_round / 2.0  # panel half width: a quarter of the widest girth
    t_a = z_arm - z_hem
    neck_z = 1.500 * s
    t_n = neck_z - z_hem
    s_n = 0.085 * s
    beta = math.pi / 2.0 - m["arm_angle"]  # sleeve direction below the horizontal
    e_b = np.array([math.cos(beta), -math.sin(beta)])
    n_b = np.array([math.sin(beta), math.cos(beta)])
    arm = m["arm_profile"]
    upper = pchip(arm[:, 0], np.maximum(arm[:, 1], arm[:, 2]), [0.1 * s, 0.2 * s])
    r_sleeve = float(np.max(upper))
    V = math.pi * (r_sleeve + c) * 1.06  # half the sleeve girth, a little ease
    P_a = np.array([W2, t_a])
    t_s = m["shoulder_top_z"] + 0.03 * s - z_hem
    # shoulder point: V across the sleeve from the armpit, at shoulder height
    delta = ((P_a[1] + V * n_b[1]) - t_s) / math.sin(beta)
    P_s = P_a + V * n_b + delta * e_b
    # where the armpit is along the arm axis (the sleeve map starts there)
    axis, _, _ = arm_frame(1.0, m["arm_angle"])
    armpit = np.array([pchip(col[:, 0], col[:, 1], m["armpit_z"]), 0.0, m["armpit_z"]])
    d_a = float((armpit - m["shoulder_left"]) @ axis)
    L_u = _SHIRT_SLEEVE * s
    L_t = L_u - float((P_s - P_a) @ e_b)
    C_u = P_a + L_u * e_b
    C_t = P_s + L_t * e_b
    mirror = np.array([-1.0, 1.0])

    def neckline(depth):
        # from the left neck point (+s_n) to the right one (-s_n), dipping ``depth`` in between
        ang = np.linspace(0.0, np.pi, 25)
        return np.stack([s_n * np.cos(ang), t_n - depth * np.sin(ang)], axis=1)

    # The armpit corner is rounded (a gusset-like curve): a sharp reflex corner would have to
    # carry the whole angle excess of the underarm (front and back corners together make over
    # 600 deg around one vertex) and crush the triangles around it; a curve spreads it along the
    # seam.
    turn = math.pi / 2.0 + beta  # how far the seam turns at the armpit
    cut = _ARMPIT_CUT * s
    R = cut / math.tan(turn / 2.0)
    T1 = P_a - cut * np.array([0.0, 1.0])
    T2 = P_a + cut * e_b
    centre = T1 + R * np.array([1.0, 0.0])
    ang = np.pi - np.linspace(0.0, turn, 13)  # clockwise from the -X direction
    arc = centre + R * np.stack([np.cos(ang), np.sin(ang)], axis=1)
    arc[0], arc[-1] = T1, T2

    def pieces(depth):
        return [
            np.array([[-W2, 0.0], [W2, 0.0]]),  # 0 hem
            np.array([[W2, 0.0], T1]),  # 1 side seam (left)
            arc,  # 2 underarm curve
            np.array([T2, C_u]),  # 3 underarm seam
            np.array([C_u, C_t]),  # 4 cuff
            np.array([C_t, P_s]),  # 5 top sleeve seam
            np.array([P_s, [s_n, t_n]]),  # 6 shoulder seam
            neckline(depth),  # 7 neckline, left to right
            np.array([[-s_n, t_n], P_s * mirror]),  # 8 shoulder seam (right)
            np.array([P_s * mirror, C_t * mirror]),  # 9 top sleeve seam
            np.array([C_t * mirror, C_u * mirror]),  # 10 cuff
            np.array([C_u * mirror, T2 * mirror]),  # 11 underarm seam
            arc[::-1] * mirror,  # 12 underarm curve
            np.array([T1 * mirror, [-W2, 0.0]]),  # 13 side seam
        ]

    dims = {
        "z_hem": z_hem,
        "W2": W2,
        "t_a": t_a,
        "P_a": P_a,
        "P_s": P_s,
        "C_u": C_u,
        "C_t": C_t,
        "V": V,
        "L_u": L_u,
        "e_b": e_b,
        "n_b": n_b,
        "d_a": d_a,
        "s_n": s_n,
        "t_n": t_n,
    }
    seams = (1, 2, 3, 5, 6, 8, 9, 11, 12, 13)
    return pieces(_NECK_DEPTH[0] * s), pieces(_NECK_DEPTH[1] * s), seams, dims


def frontal_map(p2, body, dims, clearance):
    """Where each panel point (s, t) sits as seen from the front: (X, Z) (k, 2), metres.

    The flat pattern is laid onto the body's silhouette: the torso part goes around the torso
    cross-section at height t (X = (a + c) sin(theta), theta = 90 deg at the side seam, so the
    side seams land on the torso outline), the sleeve part around the arm (the underarm and top
    seams land on the arm's outline), and the shoulder/armpit junction blends the two with the
    torso map continued past the side (over the deltoid), which keeps the map one-to-one. The depth
    (Y) comes from casting a ray from the front (back) onto the body inflated by the clearance, so
    the guess is fold-free wherever this planar map is.
    """
    m = body.measurements
    sc = m["scale"]
    col = m["column_profile"]
    c = clearance
    s_, t_ = p2[:, 0], p2[:, 1]
    side = np.where(s_ >= 0.0, 1.0, -1.0)
    sig = np.abs(s_)
    z = np.minimum(dims["z_hem"] + t_, col[-1, 0])
    a = pchip(col[:, 0], col[:, 1], z) + c
    # theta reaches 90 deg at the side seam below the shoulders and at the shoulder seam above
    # them (the shoulder seam runs along the top ridge, from the neck to the shoulder point)
    P_s = dims["P_s"]
    f = np.clip((t_ - P_s[1]) / (dims["t_n"] - P_s[1]), 0.0, 1.0)
    ridge = np.where(t_ >= P_s[1], P_s[0] + f * (dims["s_n"] - P_s[0]), np.inf)
    ref = np.minimum(dims["W2"], ridge)
    th = np.clip(sig / ref, 0.0, 1.0) * (np.pi / 2.0)
    torso = np.stack([side * (a * np.sin(th) + np.maximum(sig - ref, 0.0)), z], axis=1)
    rel = sig[:, None] * [1.0, 0.0] + t_[:, None] * [0.0, 1.0] - dims["P_a"]
    u = rel @ dims["e_b"]
    v = rel @ dims["n_b"]
    psi = np.clip(v / dims["V"], 0.0, 1.0) * np.pi
    arm = m["arm_profile"]
    sleeve = np.zeros_like(torso)
    # sleeve weight: past the armpit along the sleeve, outside the side line, above the underarm
    w = (
        smoothstep(-0.02 * sc, 0.06 * sc, u)
        * smoothstep(-0.03 * sc, 0.03 * sc, sig - dims["W2"])
        * smoothstep(-0.03 * sc, 0.0, v)
    )
    for sd in (1.0, -1.0):
        k = side == sd
        axis, e1, _ = arm_frame(sd, m["arm_angle"])
        J = m["shoulder_left"] if sd > 0 else m["shoulder_right"]
        d = dims["d_a"] + u[k]
        r = np.maximum(pchip(arm[:, 0], arm[:, 1], d), pchip(arm[:, 0], arm[:, 2], d)) + c
        pos = J + d[:, None] * axis - (r * np.cos(psi[k]))[:, None] * e1
        sleeve[k] = pos[:, [0, 2]]
    return torso * (1.0 - w[:, None]) + sleeve * w[:, None]


def raycast_depth(vertices, triangles, xz, front):
    """Y of the first hit of rays parallel to Y through points (X, Z) on a mesh: from the front
    (coming from -Y, smallest Y) or from the back. NaN where a ray misses. Triangles are binned
    by their XZ bounding boxes in a 2-D grid, so each ray tests only its own cell."""
    v = vertices
    p = v[triangles]
    P = p[:, :, [0, 2]]
    lo, hi = P.min(axis=1), P.max(axis=1)
    cell = 2.0 * float(np.mean(np.linalg.norm(P[:, 1] - P[:, 0], axis=1)))
    origin = lo.min(axis=0) - cell
    ilo = np.floor((lo - origin) / cell).astype(np.int64)
    ihi = np.floor((hi - origin) / cell).astype(np.int64)
    dims = ihi.max(axis=0) + 2
    span = ihi - ilo + 1
    count = span.prod(axis=1)
    tri = np.repeat(np.arange(len(triangles)), count)
    k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    sz = np.repeat(span[:, 1], count)
    key = (np.repeat(ilo[:, 0], count) + k // sz) * dims[1] + np.repeat(ilo[:, 1], count) + k % sz
    order = np.argsort(key, kind="stable")
    key, tri = key[order], tri[order]
    g = np.floor((xz - origin) / cell).astype(np.int64)
    inside = np.all((g >= 0) & (g < dims), axis=1)
    qk = np.where(inside, g[:, 0] * dims[1] + g[:, 1], -1)
    s0 = np.searchsorted(key, qk, side="left")
    s1 = np.where(inside, np.searchsorted(key, qk, side="right"), s0)
    n = s1 - s0
    rid = np.repeat(np.arange(len(xz)), n)
    cand = tri[np.repeat(s0, n) + np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)]
    A, B, C = P[cand, 0], P[cand, 1], P[cand, 2]
    q = xz[rid]
    det = (B[:, 0] - A[:, 0]) * (C[:, 1] - A[:, 1]) - (B[:, 1] - A[:, 1]) * (C[:, 0] - A[:, 0])
    with np.errstate(divide="ignore", invalid="ignore"):
        qa, ba, ca = q - A, B - A, C - A
        l1 = (qa[:, 0] * ca[:, 1] - qa[:, 1] * ca[:, 0]) / det
        l2 = (ba[:, 0] * qa[:, 1] - ba[:, 1] * qa[:, 0]) / det
    l0 = 1.0 - l1 - l2
    eps = 1e-9
    hit = (np.abs(det) > 1e-18) & (l0 >= -eps) & (l1 >= -eps) & (l2 >= -eps)
    y = l0 * p[cand, 0, 1] + l1 * p[cand, 1, 1] + l2 * p[cand, 2, 1]
    out = np.full(len(xz), np.inf if front else -np.inf)
    if front:
        np.minimum.at(out, rid[hit], y[hit])
    else:
        np.maximum.at(out, rid[hit], y[hit])
    out[~np.isfinite(out)] = np.nan
    return out


def loop_order(idx, eu, ev):
    """The vertices ``idx`` of one closed boundary loop, in order along it (edges eu-ev)."""
    on = np.isin(eu, idx)
    nxt = {}
    for u_, v_ in zip(eu[on].tolist(), ev[on].tolist()):
        nxt.setdefault(u_, []).append(v_)
        nxt.setdefault(v_, []).append(u_)
    start = int(idx[0])
    order, prev, cur = [start], None, start
    while True:
        a_, b_ = nxt[cur]
        step = a_ if a_ != prev else b_
        if step == start:
            break
        order.append(step)
        prev, cur = cur, step
    return np.asarray(order)


def fit_shirt(x, tris, panel, loops, parts, clearance, iterations, fillet):
    """Settle the wrapped shirt onto the surface ``clearance`` outside the body.

    Each round: uniform Laplacian smoothing, tangential only (rims smooth along themselves only,
    seam vertices also slide to even stitch spacing), rims held to their constraint (hem and neck
    slide along their first curve, cuffs keep their position along the arm), then every vertex
    takes a Newton step toward the level set f = clearance of a smooth minimum of the
    distances to the torso and to the arms, f = -k log(exp(-d_torso/k) + exp(-d_arm/k)).
    f <= min(d_torso, d_arm), so the level set is never closer than ``clearance`` to the body; the
    smooth minimum rounds the armpit crease (by about k log 2) as real cloth bridges it, instead
    of folding triangles into it. The smoothing evens out what the flat-to-body wrap stretched.
    Three more Newton steps at the end put every vertex on the level set.
    """
    n = len(x)
    e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    keys = np.minimum(e[:, 0], e[:, 1]) * n + np.maximum(e[:, 0], e[:, 1])
    uniq, counts = np.unique(keys, return_counts=True)
    edges = np.stack([uniq // n, uniq % n], axis=1)
    rim_edge = counts == 1
    on_rim = np.zeros(n, dtype=bool)
    on_rim[edges[rim_edge].ravel()] = True
    # interior vertices (seams included) average all neighbours, rim vertices only their rim
    # neighbours
    src = np.concatenate([edges[:, 0], edges[:, 1]])
    dst = np.concatenate([edges[:, 1], edges[:, 0]])
    keep = np.concatenate([rim_edge, rim_edge]) | ~on_rim[src]
    src, dst = src[keep], dst[keep]
    # Seam vertices (not on a rim) with their two seam neighbours: after smoothing they also
    # slide along the seam toward the middle of those two, so stitches stay evenly spaced (the
    # Laplacian alone bunches them where the seam turns under the arm).
    face = np.tile(np.arange(len(tris)), 3)
    order = np.argsort(keys, kind="stable")
    sk = keys[order]
    pair = np.flatnonzero(sk[1:] == sk[:-1])
    across = panel[face[order[pair]]] != panel[face[order[pair + 1]]]
    se = sk[pair][across]
    su, sv = se // n, se % n
    ends = np.concatenate([su, sv])
    other = np.concatenate([sv, su])
    o2 = np.argsort(ends, kind="stable")
    ends, other = ends[o2], other[o2]
    cnt2 = np.bincount(ends, minlength=n)
    two = np.flatnonzero((cnt2 == 2) & ~on_rim)
    start2 = np.cumsum(cnt2) - cnt2
    seam_v, seam_a, seam_b = two, other[start2[two]], other[start2[two] + 1]
    cnt = np.bincount(src, minlength=n).astype(np.float64)
    k = fillet
    max_step = 0.5 * clearance

    def constrain(y):
        for idx, kind, value, axis_, J in loops:
            if kind == "curve":
                # a rim vertex may slide along the rim (to even out its spacing), but stays on
                # the rim's first curve, so the neckline keeps its shape and height
                a_, b_ = value
                y[idx] = closest_on_segments(y[idx], a_, b_)
            else:  # keep the axial coordinate along the arm
                d = (y[idx] - J) @ axis_
                y[idx] += (value - d)[:, None] * axis_
        return y

    def project(y, steps):
        for _ in range(steps):
            (d0, g0), (d1, g1) = parts.query(y)
            first = np.abs(d0) <= np.abs(d1)  # the nearer part (distances are signed)
            m = np.where(first, d0, d1)
            lost = ~np.isfinite(m)  # out of reach of both parts: leave for the next refresh
            inside = m < 0.0
            soft = ~lost & ~inside
            step = np.zeros_like(y)
            # outside: Newton step on the smooth minimum (both distances positive here)
            a0, a1, ms = d0[soft], d1[soft], m[soft]
            with np.errstate(invalid="ignore", over="ignore"):
                w0 = np.where(np.isfinite(a0), np.exp(-(a0 - ms) / k), 0.0)
                w1 = np.where(np.isfinite(a1), np.exp(-(a1 - ms) / k), 0.0)
            f = ms - k * np.log(w0 + w1)
            g = (w0[:, None] * g0[soft] + w1[:, None] * g1[soft]) / (w0 + w1)[:, None]
            gg = np.maximum(np.einsum("ij,ij->i", g, g), 0.25)
            step[soft] = ((f - clearance) / gg)[:, None] * g
            # inside: straight out along the nearer part's gradient, to ``clearance`` outside
            hard = np.where(first[:, None], g0, g1)
            step[inside] = (m[inside] - clearance)[:, None] * hard[inside]
            # Where the two gradients oppose (the crease) the Newton step can be long and point
            # along the crease; cap it so the vertex cannot run away from its neighbours.
            length = np.linalg.norm(step, axis=1)
            cap = np.where(inside, np.inf, max_step)
            step *= np.minimum(1.0, cap / np.maximum(length, 1e-300))[:, None]
            y = y - step
        return y

    for it in range(iterations):
        if it % 10 == 0:
            parts.refresh(x)
        acc = np.zeros_like(x)
        np.add.at(acc, src, x[dst])
        mean = acc / np.maximum(cnt, 1.0)[:, None]
        # tangential part only: the normal part (shrinkage) is the projection's job
        fn = np.cross(x[tris[:, 1]] - x[tris[:, 0]], x[tris[:, 2]] - x[tris[:, 0]])
        vn = np.zeros_like(x)
        for c in range(3):
            np.add.at(vn, tris[:, c], fn)
        vn /= np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-300)
        move = mean - x
        move -= np.einsum("ij,ij->i", move, vn)[:, None] * vn * (~on_rim)[:, None]
        x = x + 0.8 * move
        tangent = x[seam_b] - x[seam_a]
        tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-300)
        slide = np.einsum("ij,ij->i", 0.5 * (x[seam_a] + x[seam_b]) - x[seam_v], tangent)
        x[seam_v] += 0.5 * slide[:, None] * tangent
        x = constrain(x)
        x = project(x, 1)
    parts.refresh(x)
    return project(x, 3)


def flip_edges(x, tris, group, max_passes=20):
    """Delaunay edge flips on a surface mesh: an interior edge whose two opposite angles sum to
    more than 180 deg is replaced by the other diagonal of its quad, if that raises the smaller
    of the two triangles' minimum angles and the quad is nearly flat. Vertices do not move (the
    fit's clearance is kept); flips stay inside one ``group`` (panel), so per-panel UVs stay
    valid. Returns the new triangles."""
    t = np.array(tris, dtype=np.int64)
    n = len(x)
    for _ in range(max_passes):
        m = len(t)
        a = t.ravel()
        b = np.roll(t, -1, axis=1).ravel()
        key = np.minimum(a, b) * n + np.maximum(a, b)
        order = np.argsort(key, kind="stable")
        k = key[order]
        pair = np.flatnonzero(k[1:] == k[:-1])
        h1, h2 = order[pair], order[pair + 1]  # half-edges (triangle * 3 + side)
        f1, s1, f2, s2 = h1 // 3, h1 % 3, h2 // 3, h2 % 3
        ok = group[f1] == group[f2]
        f1, s1, f2, s2 = f1[ok], s1[ok], f2[ok], s2[ok]
        pa, pb = t[f1, s1], t[f1, (s1 + 1) % 3]
        pc, pd = t[f1, (s1 + 2) % 3], t[f2, (s2 + 2) % 3]

        def angle(at, u, w):
            e1, e2 = x[u] - x[at], x[w] - x[at]
            cos = np.einsum("ij,ij->i", e1, e2) / (
                np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1) + 1e-300
            )
            return np.arccos(np.clip(cos, -1.0, 1.0))

        opp = angle(pc, pa, pb) + angle(pd, pa, pb)
        cand = np.flatnonzero(opp > np.pi + 1e-9)
        if len(cand) == 0:
            break
        def min_angle(tr):
            return triangle_angles(x, tr).min(axis=1)

        old_min = np.minimum(min_angle(t[f1[cand]]), min_angle(t[f2[cand]]))
        n1 = np.stack([pa, pd, pc], 1)[cand]
        n2 = np.stack([pd, pb, pc], 1)[cand]
        new_min = np.minimum(min_angle(n1), min_angle(n2))

        def normal(tr):
            p = x[tr]
            v = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
            return v / (np.linalg.norm(v, axis=1, keepdims=True) + 1e-300)

        flat = (
            np.einsum("ij,ij->i", normal(n1), normal(n2)) > 0.8
        ) & (np.einsum("ij,ij->i", normal(n1), normal(t[f1[cand]])) > 0.8)
        good = cand[(new_min > old_min) & flat]
        if len(good) == 0:
            break
        # an independent set: no triangle takes part in two flips of one pass
        used = np.zeros(m, dtype=bool)
        chosen = []
        for i in good[np.argsort(-opp[good])].tolist():
            if used[f1[i]] or used[f2[i]]:
                continue
            used[f1[i]] = used[f2[i]] = True
            chosen.append(i)
        chosen = np.asarray(chosen)
        t[f1[chosen]] = np.stack([pa, pd, pc], 1)[chosen]
        t[f2[chosen]] = np.stack([pd, pb, pc], 1)[chosen]
    return t


def collapse_short_edges(x, tris, panel, seam, min_angle=18.0, short=0.5, rounds=4):
    """Collapse the shortest edge of every sliver (min angle below ``min_angle`` deg) whose
    shortest edge is under ``short`` x the median edge (0.8 x for a cap, angle > 150 deg): the
    vertex of lower rank (interior < seam < rim) merges into the other, which does not move.
    Skipped when it would pinch the surface (link condition), cross a rim or a seam, fold a
    neighbouring triangle or leave a worse angle than the sliver had.

    Returns (triangles with removed rows set to -1, mask of the vertices still in use).
    """
    t = np.array(tris, dtype=np.int64)
    n = len(x)
    keys = edge_keys(t, n).ravel()
    uniq, counts = np.unique(keys, return_counts=True)
    rim_keys = set(uniq[counts == 1].tolist())
    on_rim = np.zeros(n, dtype=bool)
    rk = uniq[counts == 1]
    on_rim[rk // n] = True
    on_rim[rk % n] = True
    rank = on_rim * 2 + seam.astype(np.int64)
    # seam edges: shared by a front and a back triangle
    face = np.repeat(np.arange(len(t)), 3)
    o = np.argsort(keys, kind="stable")
    pr = np.flatnonzero(keys[o][1:] == keys[o][:-1])
    seam_keys = set(keys[o][pr][panel[face[o[pr]]] != panel[face[o[pr + 1]]]].tolist())
    median = float(np.median(np.linalg.norm(x[t[:, 0]] - x[t[:, 1]], axis=1)))
    alive = np.ones(len(t), dtype=bool)

    def normal(tr):
        p = x[list(tr)]
        v = np.cross(p[1] - p[0], p[2] - p[0])
        return v / (np.linalg.norm(v) + 1e-300)

    for _ in range(rounds):
        live = np.flatnonzero(alive)
        ang = np.degrees(triangle_angles(x, t[live])).min(axis=1)
        bad = live[np.argsort(ang)][np.sort(ang) < min_angle]
        if len(bad) == 0:
            break
        vt = {}
        for f in live.tolist():
            for v in t[f].tolist():
                vt.setdefault(v, []).append(f)
        touched = set()
        done = 0
        for f in bad.tolist():
            tri = t[f].tolist()
            if not alive[f] or touched.intersection(tri):
                continue
            lens = [np.linalg.norm(x[tri[i]] - x[tri[(i + 1) % 3]]) for i in range(3)]
            i = int(np.argmin(lens))
            worst = float(np.degrees(triangle_angles(x, t[f : f + 1])).min())
            cap = float(np.degrees(triangle_angles(x, t[f : f + 1])).max()) > 150.0
            if lens[i] > (0.8 if cap else short) * median:
                continue
            u, v = tri[i], tri[(i + 1) % 3]
            key = min(u, v) * n + max(u, v)
            if rank[u] < rank[v]:
                u, v = v, u  # u survives
            if on_rim[u] and on_rim[v] and key not in rim_keys:
                continue
            if seam[v] and not seam[u]:
                continue  # the survivor must carry both panels' UVs
            if seam[u] and seam[v] and key not in seam_keys and not (on_rim[u] or on_rim[v]):
                continue
            both = [g for g in vt[v] if u in t[g]]
            ring_u = {w for g in vt[u] for w in t[g].tolist()} - {u, v}
            ring_v = {w for g in vt[v] for w in t[g].tolist()} - {u, v}
            opposite = {w for g in both for w in t[g].tolist()} - {u, v}
            if ring_u & ring_v != opposite:
                continue
            moved = [g for g in vt[v] if g not in both]
            new = np.array([[u if w == v else w for w in t[g].tolist()] for g in moved])
            if any(np.dot(normal(nw), normal(t[g])) < 0.5 for nw, g in zip(new, moved)):
                continue
            if len(new) and np.degrees(triangle_angles(x, new)).min() <= worst:
                continue  # would not make the neighbourhood better
            for g in moved:
                t[g] = [u if w == v else w for w in t[g].tolist()]
            for g in both:
                alive[g] = False
            touched.update(ring_u | ring_v | {u, v})
            done += 1
        if done == 0:
            break
    t[~alive] = -1
    used = np.zeros(n, dtype=bool)
    used[t[alive].ravel()] = True
    return t, used


def cut_and_sew(front_p, back_p, seams, target_triangles, seed):
    """Mesh both panels with one spacing (chosen so the total count hits the target) and sew them:
    the back panel's seam samples become the front panel's vertices, and the back panel is
    flipped so both are counter-clockwise seen from outside.

    Returns ((front points, front triangles), (back points, back triangles), panel coordinates of
    the sewn vertices, sewn triangles, sewn index of every back point, is-front mask and seam
    mask of the sewn vertices. Front points keep their indices.
    """
    panels = []
    for k, pieces in enumerate((front_p, back_p)):
        pieces = as_pieces(pieces)
        polygon = np.concatenate([p[:-1] for p in pieces], axis=0)
        area = 0.5 * abs(float(np.sum(polygon[:, 0] * np.roll(polygon[:, 1], -1)
                                      - np.roll(polygon[:, 0], -1) * polygon[:, 1])))
        panels.append((pieces, polygon, area, seed * 2 + k))
    h = search_spacing(
        lambda h: sum(predicted_count(pc, poly, h, sd) for pc, poly, _, sd in panels),
        sum(p[2] for p in panels),
        target_triangles,
    )
    meshes = []
    n_pieces = len(front_p)
    for pieces, polygon, _, sd in panels:
        boundary, piece_of = sample_outline(pieces, h)
        inner = interior_candidates(boundary, polygon, h, sd)
        # one relaxation round is enough here: the 3-D fit smooths the sewn shirt again
        pts, tris, _ = mesh_points(boundary, inner, polygon, h, 1)
        first = np.r_[True, piece_of[1:] != piece_of[:-1]]
        # samples on a seam, and the corner that ends a seam (it starts the next piece)
        sewn = np.isin(piece_of, seams) | (np.isin((piece_of - 1) % n_pieces, seams) & first)
        meshes.append((pts, tris, np.flatnonzero(sewn)))
    (pf, tf, sewn_f), (pb, tb, sewn_b) = meshes
    nf = len(pf)

    def key(p):
        return tuple(np.round(p / h * 1e6).astype(np.int64).tolist())

    front_at = {key(pf[i]): i for i in sewn_f}
    remap = np.arange(len(pb)) + nf
    for i in sewn_b:
        j = front_at.get(key(pb[i]))
        if j is None:
            raise RuntimeError("tshirt: front and back seams do not line up (pattern bug)")
        remap[i] = j
    keep_b = remap >= nf
    remap = np.where(keep_b, np.cumsum(keep_b) - 1 + nf, remap)
    tris = np.concatenate([tf, remap[tb][:, ::-1]]).astype(np.int64)
    p2 = np.concatenate([pf, pb[keep_b]])
    is_front = np.r_[np.ones(nf, dtype=bool), np.zeros(int(keep_b.sum()), dtype=bool)]
    seam = np.zeros(len(p2), dtype=bool)
    seam[remap[~keep_b]] = True
    info = validate_mesh(np.c_[p2, np.zeros(len(p2))], tris)
    sewn = info["is_edge_manifold"] and info["is_consistently_wound"]
    if not (sewn and info["boundary_loops"] == 4):
        raise RuntimeError(f"tshirt: sewing failed: {info}")
    return (pf, tf), (pb, tb), p2, tris, remap, is_front, seam
