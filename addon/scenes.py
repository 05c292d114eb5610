"""Procedural example geometry for Tear Cloth: the paper's square cloth, banknote and T-shirt, and a
walking mannequin for the shirt to sit on.

This module owns every example mesh the add-on, the benchmarks and the tests start from. It is
pure Python + numpy (no scipy, no bpy) because it must run inside Blender's bundled Python, which
ships numpy and nothing else. Everything is in SI units (metres, seconds), Z up, and the
characters face -Y (Blender's front view looks along +Y), so a character's left is +X, as in
Blender's ``.L`` bone convention.

Why procedural and irregular: the paper (Le Gouis et al., WHC 2017, Table I) measures a square
cloth (~1.4K triangles), a banknote (~1.9K) and a T-shirt (~3.3K) worn by a moving character.
Tears follow the stress, and a regular grid makes tears snap to grid lines, so the cloth meshes
here are irregular Delaunay triangulations of jittered points, relaxed until every angle is
comfortably away from zero (the FEM conditioning and the tear-path snapping both degrade with
slivers). ``refine`` scales any of them up by 4x per level for the scaling benchmarks.

Contents:
  * ``ClothMesh`` / ``Body``           plain data (numpy arrays), no behaviour beyond checks
  * ``delaunay_2d``, ``triangulate_polygon``   the 2-D mesher (Bowyer-Watson + relaxation)
  * ``square_cloth``, ``banknote``, ``tshirt``  cloth scenes
  * ``mannequin``, ``body_pose``, ``bone_matrices``   one closed 2-manifold body, animated by
                                       linear blend skinning
  * ``refine``, ``validate_mesh``, ``closest_points``   tools shared with the rest of the add-on
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "ClothMesh",
    "Body",
    "delaunay_2d",
    "triangulate_polygon",
    "validate_mesh",
    "refine",
    "closest_points",
    "square_cloth",
    "banknote",
    "mannequin",
    "body_pose",
    "bone_matrices",
    "WALK_END",
    "tshirt",
]

# Below this a "mesh" is too coarse to tear along stress lines, and the target-count search of the
# mesher has too few points to work with.
MIN_TARGET_TRIANGLES = 50


# ------------------------------------------------------------------------------------------------
# Data
# ------------------------------------------------------------------------------------------------


@dataclass
class ClothMesh:
    """A cloth or paper sheet as plain arrays, ready to hand to the simulator or to Blender.

    vertices  float64 (n, 3), metres.
    triangles int32 (m, 3), counter-clockwise seen from the side the normal points to, with one
              consistent winding over the whole mesh.
    uv        float64 (n, 2) in [0, 1]: the flat layout (for panels, the sewing pattern), one value
              per vertex. A vertex on a sewn seam belongs to two panels; it carries its front-panel
              value here, and ``corner_uv`` keeps both.
    groups    name -> float64 (n,) weights in [0, 1] (become Blender vertex groups; handles and
              pins are chosen by group).
    name      object name in Blender.
    corner_uv optional float64 (m, 3, 2): UV per triangle corner (Blender stores UVs per loop), so
              seams can be split in UV space. ``None`` means "same as uv[triangles]".
    """

    vertices: np.ndarray
    triangles: np.ndarray
    uv: np.ndarray
    groups: dict = field(default_factory=dict)
    name: str = "cloth"
    corner_uv: np.ndarray | None = None

    def __post_init__(self):
        self.vertices = np.ascontiguousarray(self.vertices, dtype=np.float64)
        self.triangles = np.ascontiguousarray(self.triangles, dtype=np.int32)
        self.uv = np.ascontiguousarray(self.uv, dtype=np.float64)
        n = len(self.vertices)
        if self.vertices.ndim != 2 or self.vertices.shape[1] != 3:
            raise ValueError(f"vertices must have shape (n, 3), got {self.vertices.shape}")
        if self.triangles.ndim != 2 or self.triangles.shape[1] != 3:
            raise ValueError(f"triangles must have shape (m, 3), got {self.triangles.shape}")
        if self.triangles.size and (self.triangles.min() < 0 or self.triangles.max() >= n):
            raise ValueError("triangles index vertices that do not exist")
        if self.uv.shape != (n, 2):
            raise ValueError(f"uv must have shape ({n}, 2), got {self.uv.shape}")
        groups = {}
        for key, w in self.groups.items():
            w = np.ascontiguousarray(w, dtype=np.float64)
            if w.shape != (n,):
                raise ValueError(f"group {key!r} must have shape ({n},), got {w.shape}")
            if w.size and (w.min() < 0.0 or w.max() > 1.0):
                raise ValueError(f"group {key!r} has weights outside [0, 1]")
            groups[str(key)] = w
        self.groups = groups
        if self.corner_uv is not None:
            self.corner_uv = np.ascontiguousarray(self.corner_uv, dtype=np.float64)
            if self.corner_uv.shape != (len(self.triangles), 3, 2):
                raise ValueError(
                    f"corner_uv must have shape ({len(self.triangles)}, 3, 2), "
                    f"got {self.corner_uv.shape}"
                )

    @property
    def n_vertices(self) -> int:
        return len(self.vertices)

    @property
    def n_triangles(self) -> int:
        return len(self.triangles)

    def loop_uv(self) -> np.ndarray:
        """UV per triangle corner (m, 3, 2), the form Blender's UV layers take."""
        if self.corner_uv is not None:
            return self.corner_uv
        return self.uv[self.triangles]

    def area(self) -> float:
        """Total surface area in square metres."""
        return float(_triangle_areas(self.vertices, self.triangles).sum())


@dataclass
class Body:
    """A closed, outward-wound body mesh with a skeleton and linear-blend-skinning weights.

    vertices  float64 (n, 3) bind pose, metres.
    triangles int32 (m, 3), outward normals (counter-clockwise seen from outside).
    bones     list of (name, head (3,), tail (3,), parent index or -1), parents before children.
    weights   float64 (n, n_bones), rows sum to 1 (linear blend skinning).
    name      object name in Blender.
    measurements  named proportions that garments are cut from (joint positions, profiles of the
              cross-sections, arm angle, heights of crotch / armpit / shoulder, scale) and
              ``labels``: the body part of each vertex (0 torso/neck/head, 1/2 left/right arm,
              3/4 left/right leg).
    """

    vertices: np.ndarray
    triangles: np.ndarray
    bones: list
    weights: np.ndarray
    name: str = "mannequin"
    measurements: dict = field(default_factory=dict)

    @property
    def bone_names(self) -> list:
        return [b[0] for b in self.bones]

    def bone_index(self, name: str) -> int:
        for i, b in enumerate(self.bones):
            if b[0] == name:
                return i
        raise KeyError(f"no bone named {name!r}; bones are {self.bone_names}")


# ------------------------------------------------------------------------------------------------
# Small geometry helpers
# ------------------------------------------------------------------------------------------------


def _smoothstep(e0, e1, x):
    """Hermite step from 0 at e0 to 1 at e1 (e1 < e0 gives a falling step)."""
    t = np.clip((np.asarray(x, dtype=np.float64) - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _triangle_areas(vertices, triangles):
    v = np.asarray(vertices, dtype=np.float64)
    if v.shape[1] == 2:
        v = np.concatenate([v, np.zeros((len(v), 1))], axis=1)
    a, b, c = v[triangles[:, 0]], v[triangles[:, 1]], v[triangles[:, 2]]
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)


def _triangle_angles(vertices, triangles):
    """Interior angles (m, 3) in radians, angle k at corner k."""
    v = np.asarray(vertices, dtype=np.float64)
    p = v[triangles]
    out = np.empty(triangles.shape, dtype=np.float64)
    for k in range(3):
        e1 = p[:, (k + 1) % 3] - p[:, k]
        e2 = p[:, (k + 2) % 3] - p[:, k]
        n1 = np.linalg.norm(e1, axis=1)
        n2 = np.linalg.norm(e2, axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            c = np.einsum("ij,ij->i", e1, e2) / (n1 * n2)
        out[:, k] = np.arccos(np.clip(np.nan_to_num(c, nan=1.0), -1.0, 1.0))
    return out


def _polygon_contains(poly, pts):
    """Even-odd point-in-polygon test, vectorised over points and edges. poly (k, 2) closed
    implicitly; points exactly on an edge may go either way."""
    poly = np.asarray(poly, dtype=np.float64)
    pts = np.asarray(pts, dtype=np.float64)
    a = poly
    b = np.roll(poly, -1, axis=0)
    px = pts[:, 0:1]
    py = pts[:, 1:2]
    ay, by = a[None, :, 1], b[None, :, 1]
    ax, bx = a[None, :, 0], b[None, :, 0]
    straddle = (ay > py) != (by > py)
    with np.errstate(divide="ignore", invalid="ignore"):
        xint = ax + (py - ay) * (bx - ax) / (by - ay)
    crossings = np.count_nonzero(straddle & (px < xint), axis=1)
    return (crossings % 2) == 1


def _distance_to_segments(pts, a, b):
    """Distance (n,) from each point to the nearest of the segments a[k]-b[k] (2-D or 3-D)."""
    pts = np.asarray(pts, dtype=np.float64)
    best = np.full(len(pts), np.inf)
    chunk = max(1, 2_000_000 // max(1, len(a)))
    d = b - a
    dd = np.maximum(np.einsum("ij,ij->i", d, d), 1e-300)
    for s in range(0, len(pts), chunk):
        p = pts[s : s + chunk, None, :]
        t = np.clip(np.einsum("nkj,kj->nk", p - a[None], d) / dd, 0.0, 1.0)
        q = a[None] + t[..., None] * d[None]
        best[s : s + chunk] = np.sqrt(((p - q) ** 2).sum(-1).min(axis=1))
    return best


def _edge_keys(triangles, n_vertices):
    """Undirected edge key per triangle side (m, 3); side k joins corners k and k+1."""
    a = triangles.astype(np.int64)
    b = np.roll(a, -1, axis=1)
    lo = np.minimum(a, b)
    hi = np.maximum(a, b)
    return lo * np.int64(n_vertices) + hi


def _connected_labels(n, pairs):
    """Connected-component label per node from an (e, 2) edge list, by min-label propagation with
    pointer jumping (vectorised; a handful of sweeps even for 100K-triangle meshes)."""
    labels = np.arange(n, dtype=np.int64)
    if len(pairs) == 0:
        return labels
    u = pairs[:, 0].astype(np.int64)
    v = pairs[:, 1].astype(np.int64)
    while True:
        lu, lv = labels[u], labels[v]
        m = np.minimum(lu, lv)
        new = labels.copy()
        np.minimum.at(new, lu, m)
        np.minimum.at(new, lv, m)
        while True:
            jumped = new[new]
            if np.array_equal(jumped, new):
                break
            new = jumped
        if np.array_equal(new, labels):
            return labels
        labels = new


# ------------------------------------------------------------------------------------------------
# Mesh facts
# ------------------------------------------------------------------------------------------------


def validate_mesh(vertices, triangles) -> dict:
    """Facts about a triangle mesh that every generator and every topology change must keep.

    Returns a dict with:
      n_vertices, n_triangles
      n_components           connected components over shared edges (isolated vertices ignored)
      is_edge_manifold       every edge used by at most two triangles
      is_consistently_wound  every edge shared by two triangles is walked in opposite directions
      is_closed              no boundary edge (with edge-manifold: watertight)
      boundary_loops         number of closed boundary curves (holes / open rims)
      euler_characteristic   V - E + F over referenced vertices
      n_degenerate           triangles with a repeated index or (near) zero area
      min_angle_deg, max_angle_deg
      unreferenced_vertices  vertices no triangle uses
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    n = len(v)
    if t.ndim != 2 or t.shape[1] != 3:
        raise ValueError(f"triangles must have shape (m, 3), got {t.shape}")
    if t.size and (t.min() < 0 or t.max() >= n):
        raise ValueError("triangles index vertices that do not exist")
    m = len(t)
    keys = _edge_keys(t, n).ravel()
    uniq, counts = np.unique(keys, return_counts=True)
    is_edge_manifold = bool(counts.max(initial=0) <= 2)
    # Directed half-edges: a consistent orientation never repeats one.
    a = t.ravel()
    b = np.roll(t, -1, axis=1).ravel()
    directed = a * np.int64(n) + b
    is_consistent = bool(len(np.unique(directed)) == len(directed))
    boundary = uniq[counts == 1]
    bu, bv = boundary // n, boundary % n
    if len(boundary):
        lab = _connected_labels(n, np.stack([bu, bv], axis=1))
        boundary_loops = int(len(np.unique(lab[np.concatenate([bu, bv])])))
    else:
        boundary_loops = 0
    used = np.zeros(n, dtype=bool)
    used[t.ravel()] = True
    edge_pairs = np.stack([uniq // n, uniq % n], axis=1)
    lab = _connected_labels(n, edge_pairs)
    n_components = int(len(np.unique(lab[used]))) if m else 0
    areas = _triangle_areas(v, t) if m else np.zeros(0)
    scale = float(np.ptp(v, axis=0).max()) if n else 1.0
    repeated = (t[:, 0] == t[:, 1]) | (t[:, 1] == t[:, 2]) | (t[:, 2] == t[:, 0])
    n_degenerate = int(np.count_nonzero(repeated | (areas <= 1e-12 * scale * scale)))
    ang = np.degrees(_triangle_angles(v, t)) if m else np.zeros((0, 3))
    return {
        "n_vertices": int(n),
        "n_triangles": int(m),
        "n_components": n_components,
        "is_edge_manifold": is_edge_manifold,
        "is_consistently_wound": is_consistent,
        "is_closed": bool(len(boundary) == 0),
        "boundary_loops": boundary_loops,
        "euler_characteristic": int(np.count_nonzero(used) - len(uniq) + m),
        "n_degenerate": n_degenerate,
        "min_angle_deg": float(ang.min()) if m else float("nan"),
        "max_angle_deg": float(ang.max()) if m else float("nan"),
        "unreferenced_vertices": int(n - np.count_nonzero(used)),
    }


def _orient_consistently(triangles, n_vertices):
    """Flip triangles so that every component has one winding (breadth-first over shared edges).
    Assumes an edge-manifold mesh. Which of the two windings each component ends with is up to
    the caller to fix (by volume or by a known normal)."""
    t = np.array(triangles, dtype=np.int64)
    m = len(t)
    keys = _edge_keys(t, n_vertices).ravel()
    order = np.argsort(keys, kind="stable")
    sk = keys[order]
    same = sk[1:] == sk[:-1]
    fa = order[:-1][same] // 3
    fb = order[1:][same] // 3
    ea = order[:-1][same] % 3
    eb = order[1:][same] % 3
    adj = [[] for _ in range(m)]
    for x, y, i, j in zip(fa.tolist(), fb.tolist(), ea.tolist(), eb.tolist()):
        adj[x].append((y, i, j))
        adj[y].append((x, j, i))
    flipped = np.zeros(m, dtype=bool)
    seen = np.zeros(m, dtype=bool)
    tl = t.tolist()
    for root in range(m):
        if seen[root]:
            continue
        seen[root] = True
        stack = [root]
        while stack:
            f = stack.pop()
            for g, i, j in adj[f]:
                if seen[g]:
                    continue
                # The shared edge as f walks it (after f's own flip), and as g walks it.
                fa_, fb_ = tl[f][i], tl[f][(i + 1) % 3]
                if flipped[f]:
                    fa_, fb_ = fb_, fa_
                ga_, gb_ = tl[g][j], tl[g][(j + 1) % 3]
                flipped[g] = (fa_ == ga_ and fb_ == gb_)
                seen[g] = True
                stack.append(g)
    t[flipped] = t[flipped][:, ::-1]
    return t.astype(np.int32)


def _signed_volume(vertices, triangles):
    p = vertices[triangles]
    return float(np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6.0)


# ------------------------------------------------------------------------------------------------
# 2-D Delaunay (Bowyer-Watson)
# ------------------------------------------------------------------------------------------------


def delaunay_2d(points) -> np.ndarray:
    """Delaunay triangulation of 2-D points, counter-clockwise int32 triangles (m, 3).

    Bowyer-Watson with triangle adjacency, a walking point location and a spatially coherent
    (row-snake) insertion order, so each insertion touches O(1) triangles: ~0.1 s for 2K points in
    plain Python. Circumcircles are cached per triangle. A cavity is grown until every one of its
    rim edges is seen counter-clockwise from the new point, which keeps the result a valid
    triangulation even when rounding makes the in-circle test disagree on near-cocircular points.
    Duplicate points are not allowed (they would be left out of every triangle).
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f"points must have shape (n, 2), got {pts.shape}")
    n = len(pts)
    if n < 3:
        raise ValueError(f"need at least 3 points to triangulate, got {n}")
    if not np.all(np.isfinite(pts)):
        raise ValueError("points must be finite")
    lo = pts.min(axis=0)
    scale = float((pts.max(axis=0) - lo).max()) or 1.0
    q = (pts - lo) / scale
    rows = max(1, int(math.sqrt(n / 2.0)))
    r = np.minimum((q[:, 1] * rows).astype(np.int64), rows - 1)
    order = np.lexsort((np.where(r % 2 == 0, q[:, 0], -q[:, 0]), r))
    # The super triangle is far away so that hull edges of the input survive its removal.
    X = q[:, 0].tolist() + [-1000.0, 1001.0, 0.5]
    Y = q[:, 1].tolist() + [-1000.0, -1000.0, 1001.0]
    tv = [[n, n + 1, n + 2]]
    tn = [[-1, -1, -1]]
    alive = [True]
    cc = [None]

    def circumcircle(t):
        a, b, c = tv[t]
        ax, ay, bx, by, cx, cy = X[a], Y[a], X[b], Y[b], X[c], Y[c]
        d = 2.0 * (ax * (by - cy) + bx * (cy - ay) + cx * (ay - by))
        a2 = ax * ax + ay * ay
        b2 = bx * bx + by * by
        c2 = cx * cx + cy * cy
        ux = (a2 * (by - cy) + b2 * (cy - ay) + c2 * (ay - by)) / d
        uy = (a2 * (cx - bx) + b2 * (ax - cx) + c2 * (bx - ax)) / d
        return (ux, uy, (ax - ux) ** 2 + (ay - uy) ** 2)

    cc[0] = circumcircle(0)
    last = 0
    max_walk = 4 * n + 16
    for p in order.tolist():
        px, py = X[p], Y[p]
        t = last
        for _ in range(max_walk):
            a, b, c = tv[t]
            if (X[b] - X[a]) * (py - Y[a]) - (Y[b] - Y[a]) * (px - X[a]) < 0:
                t = tn[t][2]
            elif (X[c] - X[b]) * (py - Y[b]) - (Y[c] - Y[b]) * (px - X[b]) < 0:
                t = tn[t][0]
            elif (X[a] - X[c]) * (py - Y[c]) - (Y[a] - Y[c]) * (px - X[c]) < 0:
                t = tn[t][1]
            else:
                break
        cav = {t}
        stack = [t]
        while stack:
            u = stack.pop()
            for nb in tn[u]:
                if nb >= 0 and nb not in cav:
                    ux, uy, r2 = cc[nb]
                    if (px - ux) ** 2 + (py - uy) ** 2 < r2:
                        cav.add(nb)
                        stack.append(nb)
        while True:
            rim = []
            bad = None
            for u in cav:
                vs, ns = tv[u], tn[u]
                for i in range(3):
                    nb = ns[i]
                    if nb in cav:
                        continue
                    a = vs[(i + 1) % 3]
                    b = vs[(i + 2) % 3]
                    if (X[b] - X[a]) * (py - Y[a]) - (Y[b] - Y[a]) * (px - X[a]) <= 0.0:
                        bad = nb
                        break
                    rim.append((a, b, nb, u))
                if bad is not None:
                    break
            if bad is None:
                break
            if bad < 0:
                raise RuntimeError("delaunay_2d: point outside the super triangle")
            cav.add(bad)
        start, end, new = {}, {}, []
        for a, b, nb, old in rim:
            k = len(tv)
            tv.append([p, a, b])
            tn.append([nb, -1, -1])
            alive.append(True)
            cc.append(None)
            if nb >= 0:
                nns = tn[nb]
                nns[nns.index(old)] = k
            start[a] = k
            end[b] = k
            new.append(k)
        for k in new:
            _, a, b = tv[k]
            tn[k][1] = start[b]
            tn[k][2] = end[a]
            cc[k] = circumcircle(k)
        for u in cav:
            alive[u] = False
        last = new[0]
    tris = [tv[i] for i in range(len(tv)) if alive[i] and max(tv[i]) < n]
    return np.asarray(tris, dtype=np.int32).reshape(-1, 3)


# ------------------------------------------------------------------------------------------------
# Polygon meshing
# ------------------------------------------------------------------------------------------------


def _as_pieces(outline):
    """Normalise an outline to a list of polylines, corner to corner, that chain into a loop."""
    if isinstance(outline, np.ndarray) or (
        len(outline) and np.ndim(outline[0]) == 1 and len(outline[0]) == 2
    ):
        poly = np.asarray(outline, dtype=np.float64)
        if poly.ndim != 2 or poly.shape[1] != 2 or len(poly) < 3:
            raise ValueError(f"an outline polygon needs shape (k >= 3, 2), got {poly.shape}")
        return [np.stack([poly[i], poly[(i + 1) % len(poly)]]) for i in range(len(poly))]
    pieces = [np.asarray(p, dtype=np.float64) for p in outline]
    for i, p in enumerate(pieces):
        if p.ndim != 2 or p.shape[1] != 2 or len(p) < 2:
            raise ValueError(f"outline piece {i} needs shape (k >= 2, 2), got {p.shape}")
        nxt = pieces[(i + 1) % len(pieces)]
        if not np.allclose(p[-1], nxt[0], atol=1e-12):
            raise ValueError(f"outline piece {i} does not end where piece {i + 1} starts")
    return pieces


def _resample_polyline(poly, spacing):
    """Points along a polyline at equal arc length, ceil(L / spacing) segments; the end point is
    left out (it starts the next piece). Depends only on the polyline and the spacing, so two
    panels that share a seam polyline get identical seam samples and can be sewn vertex to
    vertex."""
    seg = np.linalg.norm(np.diff(poly, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    length = s[-1]
    k = max(1, int(math.ceil(length / spacing - 1e-9)))
    u = np.linspace(0.0, length, k + 1)[:-1]
    return np.stack([np.interp(u, s, poly[:, 0]), np.interp(u, s, poly[:, 1])], axis=1)


def _sample_outline(pieces, spacing):
    samples = [_resample_polyline(p, spacing) for p in pieces]
    piece_of = np.concatenate([np.full(len(s), i) for i, s in enumerate(samples)])
    return np.concatenate(samples, axis=0), piece_of


def _interior_candidates(boundary, polygon, spacing, rng_seed):
    """Jittered hexagonal lattice clipped to the polygon, kept clear of the boundary.

    Points closer than 0.6 * spacing to the boundary are dropped: that keeps every boundary
    segment (length <= spacing) outside the others' circumcircles (its diametral disc is empty),
    so Delaunay keeps the outline as edges without any constrained-edge machinery.
    """
    rng = np.random.default_rng(rng_seed)
    lo = polygon.min(axis=0) - spacing
    hi = polygon.max(axis=0) + spacing
    dy = spacing * math.sqrt(3.0) / 2.0
    off = rng.random(2) * np.array([spacing, dy])
    ys = np.arange(lo[1] + off[1], hi[1], dy)
    xs = np.arange(lo[0] + off[0], hi[0], spacing)
    gx, gy = np.meshgrid(xs, ys)
    gx = gx + (np.arange(len(ys))[:, None] % 2) * spacing * 0.5
    pts = np.stack([gx.ravel(), gy.ravel()], axis=1)
    pts = pts + (rng.random(pts.shape) - 0.5) * (0.7 * spacing)
    pts = pts[_polygon_contains(polygon, pts)]
    seg_b = np.roll(boundary, -1, axis=0)
    pts = pts[_distance_to_segments(pts, boundary, seg_b) >= 0.6 * spacing]
    return pts


def _vertex_neighbours_mean(points, triangles, movable):
    n = len(points)
    e = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    e = np.concatenate([e, e[:, ::-1]])
    e = np.unique(e, axis=0)
    acc = np.zeros_like(points)
    cnt = np.zeros(n)
    np.add.at(acc, e[:, 0], points[e[:, 1]])
    np.add.at(cnt, e[:, 0], 1.0)
    out = points.copy()
    ok = movable & (cnt > 0)
    out[ok] = acc[ok] / cnt[ok, None]
    return out


def triangulate_polygon(
    outline,
    target_triangles: int | None = None,
    spacing: float | None = None,
    seed: int = 0,
    relax_rounds: int = 3,
):
    """Irregular, well-shaped triangulation of a simple polygon (no holes).

    outline  (k, 2) polygon, or a list of polylines corner to corner (use polylines for curved
             parts: each polyline is resampled as a whole, so its inner points are not corners).
             Counter-clockwise or clockwise; triangles always come out counter-clockwise.
    target_triangles or spacing  exactly one: the wanted triangle count (hit within a few
             percent by searching the spacing: a triangulated polygon with n_b boundary and n_i
             inner points has exactly 2 n_i + n_b - 2 triangles, so the count is known before
             triangulating), or the edge length in outline units.
    seed     jitter of the inner points; the same seed gives the same mesh.
    relax_rounds  Laplacian smoothing rounds of the inner points, each followed by a fresh
             Delaunay; this is what lifts the minimum angle from a few degrees to 20+.

    Returns (points (n, 2) float64, triangles (m, 3) int32, boundary (n_b,) int indices of the
    outline samples in order along the outline). Boundary points are the first n_b points.
    """
    pieces = _as_pieces(outline)
    polygon = np.concatenate([p[:-1] for p in pieces], axis=0)
    signed_area = 0.5 * float(
        np.sum(polygon[:, 0] * np.roll(polygon[:, 1], -1)
               - np.roll(polygon[:, 0], -1) * polygon[:, 1])
    )
    if abs(signed_area) <= 0.0:
        raise ValueError("outline encloses no area")
    if (target_triangles is None) == (spacing is None):
        raise ValueError("give exactly one of target_triangles and spacing")
    if target_triangles is not None:
        target_triangles = int(target_triangles)
        if target_triangles < MIN_TARGET_TRIANGLES:
            raise ValueError(
                f"target_triangles must be at least {MIN_TARGET_TRIANGLES}, got {target_triangles}"
            )
        spacing = _spacing_for_count(pieces, polygon, abs(signed_area), target_triangles, seed)
    else:
        spacing = float(spacing)
        if not spacing > 0.0:
            raise ValueError(f"spacing must be positive, got {spacing}")
    boundary, _ = _sample_outline(pieces, spacing)
    inner = _interior_candidates(boundary, polygon, spacing, seed)
    return _mesh_points(boundary, inner, polygon, spacing, relax_rounds)


def _predicted_count(pieces, polygon, spacing, seed):
    boundary, _ = _sample_outline(pieces, spacing)
    inner = _interior_candidates(boundary, polygon, spacing, seed)
    return 2 * len(inner) + len(boundary) - 2


def _spacing_for_count(pieces, polygon, area, target, seed):
    return _search_spacing(lambda h: _predicted_count(pieces, polygon, h, seed), area, target)


def _search_spacing(count_of, area, target):
    # Equilateral triangles of side h have area sqrt(3)/4 h^2: start there, then bisect on the
    # exact predicted count (monotone up to jitter noise).
    h0 = math.sqrt(area / (target * math.sqrt(3.0) / 4.0))
    lo, hi = 0.5 * h0, 2.0 * h0
    best = (None, h0)
    for _ in range(30):
        mid = math.sqrt(lo * hi)
        count = count_of(mid)
        err = abs(count - target)
        if best[0] is None or err < best[0]:
            best = (err, mid)
        if err <= max(1, target // 200):
            break
        if count > target:
            lo = mid
        else:
            hi = mid
    return best[1]


def _mesh_points(boundary, inner, polygon, spacing, relax_rounds):
    nb = len(boundary)
    pts = np.concatenate([boundary, inner], axis=0)
    movable = np.zeros(len(pts), dtype=bool)
    movable[nb:] = True
    seg_a, seg_b = boundary, np.roll(boundary, -1, axis=0)
    tris = _triangulate_inside(pts, polygon, nb)
    for _ in range(relax_rounds):
        for _ in range(3):
            moved = _vertex_neighbours_mean(pts, tris, movable)
            # A move that would bring a point next to the outline (or out of the polygon) is
            # refused: the outline must stay a set of Delaunay edges.
            cand = moved[nb:]
            ok = _polygon_contains(polygon, cand) & (
                _distance_to_segments(cand, seg_a, seg_b) >= 0.55 * spacing
            )
            pts[nb:][ok] = cand[ok]
        tris = _triangulate_inside(pts, polygon, nb)
    return pts, tris, np.arange(nb)


def _triangulate_inside(pts, polygon, nb):
    tris = delaunay_2d(pts)
    cent = pts[tris].mean(axis=1)
    tris = tris[_polygon_contains(polygon, cent)]
    # Every outline segment must have survived as an edge, or the outline is not the mesh border.
    keys = set(_edge_keys(tris, len(pts)).ravel().tolist())
    i = np.arange(nb)
    j = (i + 1) % nb
    need = np.minimum(i, j) * len(pts) + np.maximum(i, j)
    missing = [k for k in need.tolist() if k not in keys]
    if missing:
        raise RuntimeError(
            f"triangulate_polygon: {len(missing)} outline segments were lost; the outline has "
            "parts closer than the spacing (use a smaller spacing or a wider outline)"
        )
    return tris.astype(np.int32)


# ------------------------------------------------------------------------------------------------
# Refinement
# ------------------------------------------------------------------------------------------------


def refine(mesh: ClothMesh, levels: int = 1) -> ClothMesh:
    """1-to-4 midpoint subdivision, ``levels`` times (triangle count x 4**levels).

    Used to scale the example scenes up (1.4K -> 5.6K -> 22K -> 90K triangles) for the scaling
    benchmarks while keeping the shape, the irregularity and the angles of the original (midpoint
    subdivision copies every triangle's shape into its four children). New vertices sit at edge
    midpoints, so area is kept exactly; UVs and group weights are averaged from the edge ends
    (linear interpolation), and per-corner UVs are split per corner so panel seams stay split.
    Fully vectorised: a 25K -> 100K step takes well under a second.
    """
    if not isinstance(mesh, ClothMesh):
        raise TypeError(f"refine needs a ClothMesh, got {type(mesh).__name__}")
    levels = int(levels)
    if levels < 0:
        raise ValueError(f"levels must be >= 0, got {levels}")
    if mesh.n_triangles * 4**levels > 50_000_000:
        raise ValueError(
            f"levels={levels} would make {mesh.n_triangles * 4**levels} triangles; "
            "the benchmarks stop at ~100K, and beyond 50M memory runs out"
        )
    v, t, uv = mesh.vertices, mesh.triangles.astype(np.int64), mesh.uv
    groups = dict(mesh.groups)
    cuv = mesh.corner_uv
    for _ in range(levels):
        n = len(v)
        keys = _edge_keys(t, n)  # side k joins corners k, k+1
        uniq, inv = np.unique(keys.ravel(), return_inverse=True)
        inv = inv.reshape(-1, 3)
        ea, eb = uniq // n, uniq % n
        mid = n + inv  # index of the midpoint of side k
        v = np.concatenate([v, 0.5 * (v[ea] + v[eb])])
        uv = np.concatenate([uv, 0.5 * (uv[ea] + uv[eb])])
        groups = {k: np.concatenate([w, 0.5 * (w[ea] + w[eb])]) for k, w in groups.items()}
        a, b, c = t[:, 0], t[:, 1], t[:, 2]
        mab, mbc, mca = mid[:, 0], mid[:, 1], mid[:, 2]
        t = np.concatenate(
            [
                np.stack([a, mab, mca], 1),
                np.stack([mab, b, mbc], 1),
                np.stack([mca, mbc, c], 1),
                np.stack([mab, mbc, mca], 1),
            ]
        )
        if cuv is not None:
            ca, cb, cc_ = cuv[:, 0], cuv[:, 1], cuv[:, 2]
            uab, ubc, uca = 0.5 * (ca + cb), 0.5 * (cb + cc_), 0.5 * (cc_ + ca)
            cuv = np.concatenate(
                [
                    np.stack([ca, uab, uca], 1),
                    np.stack([uab, cb, ubc], 1),
                    np.stack([uca, ubc, cc_], 1),
                    np.stack([uab, ubc, uca], 1),
                ]
            )
    return ClothMesh(v, t, uv, groups, mesh.name, cuv)


# ------------------------------------------------------------------------------------------------
# Flat scenes: square cloth and banknote
# ------------------------------------------------------------------------------------------------


def _check_count(target_triangles):
    if isinstance(target_triangles, bool) or not isinstance(target_triangles, (int, np.integer)):
        raise ValueError(f"target_triangles must be an integer, got {target_triangles!r}")
    if target_triangles < MIN_TARGET_TRIANGLES:
        raise ValueError(
            f"target_triangles must be at least {MIN_TARGET_TRIANGLES}, got {target_triangles}"
        )
    return int(target_triangles)


def _check_positive(name, value):
    value = float(value)
    if not (value > 0.0 and math.isfinite(value)):
        raise ValueError(f"{name} must be a positive length in metres, got {value}")
    return value


def _flat_to_xz(points2d, centre_x, bottom_z):
    """Lay flat (u, v) points in the XZ plane: u -> +X, v -> +Z, y = 0. A triangle that is
    counter-clockwise in (u, v) then faces -Y, toward Blender's front view."""
    out = np.zeros((len(points2d), 3))
    out[:, 0] = points2d[:, 0] + centre_x
    out[:, 2] = points2d[:, 1] + bottom_z
    return out


def square_cloth(size: float = 0.5, target_triangles: int = 1400, seed: int = 0) -> ClothMesh:
    """The paper's square piece of cloth (Fig. 1 / Table I: ~1.4K triangles), hanging.

    A size x size square in the XZ plane (normal -Y, toward the front view), centred on x = 0 with
    its centre at z = 1.0 m (chest height, so a tear pulled by two hands happens in front of a
    standing user). Irregular Delaunay mesh, so tears do not run along grid lines.

    Groups: ``pin_top`` (the top edge), ``handle_left`` / ``handle_right`` (vertices within
    0.12 * size of the outer fifth of the top edge at -X / +X: where two hands grab the top
    corners to pull the cloth apart).
    """
    size = _check_positive("size", size)
    target_triangles = _check_count(target_triangles)
    sq = np.array([[0.0, 0.0], [size, 0.0], [size, size], [0.0, size]])
    p, tris, _ = triangulate_polygon(
        sq, target_triangles=target_triangles, seed=seed, relax_rounds=2
    )
    verts = _flat_to_xz(p - [size / 2.0, 0.0], 0.0, 1.0 - size / 2.0)
    uv = p / size
    top = verts[:, 2].max()
    x0, x1 = -size / 2.0, size / 2.0
    tol = 1e-9 * max(1.0, size)
    pin_top = (np.abs(verts[:, 2] - top) <= tol).astype(np.float64)
    reach = 0.12 * size
    grip = 0.2 * size
    pts = verts[:, [0, 2]]

    def near(a, b):
        return (_distance_to_segments(pts, np.array([a]), np.array([b])) <= reach).astype(float)

    groups = {
        "pin_top": pin_top,
        "handle_left": near([x0, top], [x0 + grip, top]),
        "handle_right": near([x1 - grip, top], [x1, top]),
    }
    return ClothMesh(verts, tris, uv, groups, "square_cloth")


# US banknote, 6.14 in x 2.61 in.
BANKNOTE_SIZE = (0.156, 0.066)


def banknote(
    width: float = BANKNOTE_SIZE[0],
    height: float = BANKNOTE_SIZE[1],
    target_triangles: int = 1900,
    seed: int = 0,
    grip: float = 0.025,
    notch: float = 0.0,
) -> ClothMesh:
    """The paper's banknote (Table I: ~1.9K triangles; paper tears almost as soon as it is pulled).

    A width x height rectangle (US banknote size by default) held upright in the XZ plane (normal
    -Y), centred at x = 0, z = 1.0 m, as two hands hold a note in front of the chest.

    Groups: ``handle_left`` / ``handle_right``: the end strips of width ``grip`` (m) at -X / +X,
    where thumb and index finger pinch the note.
    notch: depth (m) of an optional V notch cut into the middle of the top edge (60 degree opening),
    a ready-made initial tear; 0 means a clean rectangle.
    """
    width = _check_positive("width", width)
    height = _check_positive("height", height)
    grip = _check_positive("grip", grip)
    target_triangles = _check_count(target_triangles)
    if grip * 2.0 >= width:
        raise ValueError(f"grip {grip} m leaves nothing between the hands of a {width} m note")
    notch = float(notch)
    if notch < 0.0 or notch >= 0.8 * height:
        raise ValueError(f"notch must be in [0, {0.8 * height:.4f}) m, got {notch}")
    w2 = width / 2.0
    outline = [[-w2, 0.0], [w2, 0.0], [w2, height]]
    if notch > 0.0:
        half = notch * math.tan(math.radians(30.0))
        outline += [[half, height], [0.0, height - notch], [-half, height]]
    outline += [[-w2, height]]
    p, tris, _ = triangulate_polygon(
        np.asarray(outline), target_triangles=target_triangles, seed=seed, relax_rounds=2
    )
    verts = _flat_to_xz(p, 0.0, 1.0 - height / 2.0)
    uv = (p + [w2, 0.0]) / [width, height]
    x = verts[:, 0]
    tol = 1e-9
    groups = {
        "handle_left": (x <= -w2 + grip + tol).astype(np.float64),
        "handle_right": (x >= w2 - grip - tol).astype(np.float64),
    }
    return ClothMesh(verts, tris, uv, groups, "banknote")


# ------------------------------------------------------------------------------------------------
# Mannequin: one closed 2-manifold body lofted from cross-section rings
# ------------------------------------------------------------------------------------------------

# Proportions of a 1.75 m adult, metres; ``mannequin(height=...)`` scales them uniformly.
# Column (torso, neck, head) cross-sections: z, half-width a (x), half-depth b (y), centre y.
_COLUMN = np.array(
    [
        (0.800, 0.168, 0.100, 0.010),  # crotch ring: the legs split off here
        (0.850, 0.172, 0.110, 0.012),
        (0.920, 0.172, 0.108, 0.008),  # hips
        (1.000, 0.154, 0.100, 0.002),
        (1.060, 0.143, 0.097, 0.000),  # waist
        (1.150, 0.150, 0.104, -0.006),
        (1.240, 0.160, 0.112, -0.012),  # chest
        (1.310, 0.165, 0.110, -0.010),  # armpit
        (1.380, 0.168, 0.098, -0.004),
        (1.430, 0.160, 0.086, 0.002),  # shoulder top
        (1.465, 0.118, 0.072, 0.006),
        (1.490, 0.074, 0.060, 0.010),
        (1.505, 0.056, 0.054, 0.012),  # neck base
        (1.550, 0.052, 0.052, 0.010),
        (1.575, 0.060, 0.072, 0.000),  # jaw
        (1.610, 0.072, 0.090, -0.004),
        (1.660, 0.078, 0.098, 0.000),
        (1.705, 0.070, 0.090, 0.006),
        (1.735, 0.050, 0.066, 0.006),
        (1.747, 0.025, 0.034, 0.006),
        (1.750, 0.000, 0.000, 0.006),  # crown (pole)
    ]
)
# Leg cross-sections (each leg centred at x = +-_HIP_X): z, a, b, centre y.
_LEG = np.array(
    [
        (0.770, 0.082, 0.086, 0.010),
        (0.700, 0.076, 0.078, 0.005),
        (0.600, 0.064, 0.066, 0.000),
        (0.500, 0.050, 0.052, -0.004),  # knee
        (0.440, 0.048, 0.050, 0.000),
        (0.360, 0.052, 0.056, 0.010),  # calf
        (0.250, 0.042, 0.044, 0.008),
        (0.120, 0.032, 0.034, 0.004),  # ankle
        (0.080, 0.034, 0.042, -0.006),
        (0.045, 0.040, 0.080, -0.040),  # foot
        (0.020, 0.042, 0.108, -0.055),
        (0.000, 0.040, 0.108, -0.055),  # sole outline
    ]
)
# Arm cross-sections along the arm axis from the shoulder joint: d, a (along the up-outward
# perpendicular e1), b (along e2 = front/back). The hand is flat, palm toward the thigh.
_ARM = np.array(
    [
        (0.000, 0.056, 0.056),
        (0.100, 0.052, 0.050),  # deltoid
        (0.200, 0.045, 0.043),
        (0.290, 0.038, 0.038),  # elbow
        (0.400, 0.040, 0.036),  # forearm
        (0.520, 0.027, 0.030),  # wrist
        (0.560, 0.020, 0.042),  # palm
        (0.640, 0.018, 0.042),
        (0.700, 0.014, 0.030),  # fingers
        (0.735, 0.000, 0.000),  # finger tips (pole)
    ]
)
_HIP_X = 0.092
_SHOULDER = np.array([0.163, 0.0, 1.385])  # left shoulder joint; the right one is mirrored
_ARM_ANGLE = math.radians(48.0)  # A-pose: arm axis this far from hanging straight down
_ELBOW_D, _WRIST_D = 0.29, 0.52
_HOLE_Z = (1.318, 1.425)  # torso rows between these heights are cut open for the arms
_HOLE_HALF_WIDTH = 0.060  # half arc width of the arm opening on the torso side
_BIND_Z = {"hip": 0.90, "knee": 0.48, "ankle": 0.08, "pelvis": 0.92, "chest": 1.10, "neck": 1.45}

# Vertex region labels used for skinning.
_COL, _ARM_L, _ARM_R, _LEG_L, _LEG_R = 0, 1, 2, 3, 4


def _pchip(x, y, xq):
    """Monotone piecewise-cubic Hermite interpolation (Fritsch-Carlson): smooth profiles that
    never overshoot the table (an overshooting radius could pinch the body inside out)."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if x[0] > x[-1]:
        x, y = x[::-1], y[::-1]
    h = np.diff(x)
    delta = np.diff(y) / h
    m = np.zeros_like(y)
    m[0], m[-1] = delta[0], delta[-1]
    same = delta[:-1] * delta[1:] > 0
    w1 = 2 * h[1:] + h[:-1]
    w2 = h[1:] + 2 * h[:-1]
    with np.errstate(divide="ignore", invalid="ignore"):
        hm = (w1 + w2) / (w1 / delta[:-1] + w2 / delta[1:])
    m[1:-1] = np.where(same, hm, 0.0)
    xq = np.clip(np.asarray(xq, dtype=np.float64), x[0], x[-1])
    k = np.clip(np.searchsorted(x, xq) - 1, 0, len(x) - 2)
    t = (xq - x[k]) / h[k]
    h00 = (1 + 2 * t) * (1 - t) ** 2
    h10 = t * (1 - t) ** 2
    h01 = t * t * (3 - 2 * t)
    h11 = t * t * (t - 1)
    return h00 * y[k] + h10 * h[k] * m[k] + h01 * y[k + 1] + h11 * h[k] * m[k + 1]


def _ellipse_angles(p, q, n, start=0.0, direction=1.0):
    """n angles that cut the ellipse (p cos t, q sin t) into equal arcs, beginning at ``start``."""
    t = np.linspace(0.0, 2.0 * np.pi, 257)
    seg = np.hypot(np.diff(p * np.cos(t)), np.diff(q * np.sin(t)))
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] <= 0.0:
        return start + direction * np.arange(n) * (2.0 * np.pi / n)
    # arc length measured from the start angle
    s0 = np.interp(start % (2 * np.pi), t, s)
    targets = (s0 + direction * np.arange(n) * s[-1] / n) % s[-1]
    return np.interp(targets, s, t)


def _ellipse_perimeter(p, q):
    h = ((p - q) / np.maximum(p + q, 1e-300)) ** 2
    return np.pi * (p + q) * (1 + 3 * h / (10 + np.sqrt(4 - 3 * h)))


def _arc_stations(radii_fn, lo, hi, step):
    """Stations along a profile parameter (z or d), spaced so that consecutive rings are about
    ``step`` apart in space (axial change plus radius change), so flaring parts such as the top
    of the shoulders get as many rings as straight parts of the same surface length."""
    t = np.linspace(lo, hi, 2001)
    r = radii_fn(t)
    ds = np.hypot(np.diff(t), np.abs(np.diff(r, axis=0)).max(axis=1) if r.ndim == 2 else np.diff(r))
    s = np.concatenate([[0.0], np.cumsum(ds)])
    k = max(2, int(round(s[-1] / step)))
    return np.interp(np.linspace(0.0, s[-1], k + 1), s, t)


class _Builder:
    """Accumulates vertices (with a skinning label and an axial coordinate) and triangles."""

    def __init__(self):
        self.verts = []
        self.labels = []
        self.tris = []
        self.n = 0

    def add(self, pts, label):
        pts = np.asarray(pts, dtype=np.float64).reshape(-1, 3)
        idx = np.arange(self.n, self.n + len(pts))
        self.verts.append(pts)
        self.labels.append(np.full(len(pts), label))
        self.n += len(pts)
        return idx

    def zip(self, ring_a, u_a, ring_b, u_b):
        """Triangulate the band between two closed rings that wind the same way. u_* are the
        rings' angular positions (turns, increasing along each ring); counts may differ."""
        ring_a, ring_b = np.asarray(ring_a), np.asarray(ring_b)
        ua = np.unwrap(np.asarray(u_a, dtype=np.float64) * 2 * np.pi) / (2 * np.pi)
        ub = np.unwrap(np.asarray(u_b, dtype=np.float64) * 2 * np.pi) / (2 * np.pi)
        # start ring b at its vertex nearest in angle to ring a's first vertex
        d = (ub - ua[0] + 0.5) % 1.0 - 0.5
        j0 = int(np.argmin(np.abs(d)))
        ring_b = np.roll(ring_b, -j0)
        ub = np.roll(ub, -j0)
        ub = np.unwrap(ub * 2 * np.pi) / (2 * np.pi)
        ub = ub - np.round(ub[0] - ua[0])
        na, nb = len(ring_a), len(ring_b)
        ua_ext = np.concatenate([ua, [ua[0] + 1.0]])
        ub_ext = np.concatenate([ub, [ub[0] + 1.0]])
        i = j = 0
        out = []
        while i < na or j < nb:
            adv_a = j >= nb or (i < na and ua_ext[i + 1] <= ub_ext[j + 1])
            a0, a1 = ring_a[i % na], ring_a[(i + 1) % na]
            b0, b1 = ring_b[j % nb], ring_b[(j + 1) % nb]
            if adv_a:
                out.append((a0, a1, b0))
                i += 1
            else:
                out.append((a0, b1, b0))
                j += 1
        self.tris.append(np.asarray(out, dtype=np.int64))

    def fan(self, ring, apex):
        ring = np.asarray(ring)
        self.tris.append(np.stack([ring, np.roll(ring, -1), np.full(len(ring), apex)], axis=1))

    def quads(self, quads):
        """Split quads (a, b, c, d) (a->b along a ring, d above a) along the shorter diagonal."""
        q = np.asarray(quads, dtype=np.int64).reshape(-1, 4)
        self.tris.append(q)  # resolved in finish() once positions are known

    def finish(self):
        v = np.concatenate(self.verts)
        labels = np.concatenate(self.labels)
        tris = []
        for t in self.tris:
            if t.shape[1] == 3:
                tris.append(t)
                continue
            a, b, c, d = t.T
            ac = np.linalg.norm(v[a] - v[c], axis=1)
            bd = np.linalg.norm(v[b] - v[d], axis=1)
            use_ac = ac <= bd
            t1 = np.where(use_ac[:, None], np.stack([a, b, c], 1), np.stack([a, b, d], 1))
            t2 = np.where(use_ac[:, None], np.stack([a, c, d], 1), np.stack([b, c, d], 1))
            tris += [t1, t2]
        tris = np.concatenate(tris)
        # Drop vertices no triangle uses (the inside of the arm openings) and renumber.
        used = np.zeros(len(v), dtype=bool)
        used[tris.ravel()] = True
        remap = np.cumsum(used) - 1
        return v[used], labels[used], remap[tris]


def _ring_profile(table, scale):
    """(scaled table, at(z) -> (..., 3) interpolated columns) for a body part's ring table."""
    c = table * scale

    def at(z):
        return np.stack(
            [_pchip(c[:, 0], c[:, 1], z), _pchip(c[:, 0], c[:, 2], z), _pchip(c[:, 0], c[:, 3], z)],
            axis=-1,
        )

    return c, at


def _column_profile(scale):
    return _ring_profile(_COLUMN, scale)


def _leg_profile(scale):
    return _ring_profile(_LEG, scale)


def _arm_profile(scale):
    c = _ARM * scale

    def at(d):
        return np.stack([_pchip(c[:, 0], c[:, 1], d), _pchip(c[:, 0], c[:, 2], d)], axis=-1)

    return c, at


def _arm_frame(side, angle=_ARM_ANGLE):
    """Arm axis (down-outward), e1 (up-outward), e2 = axis x e1, for side +1 (left) / -1."""
    s, c = math.sin(angle), math.cos(angle)
    axis = np.array([side * s, 0.0, -c])
    e1 = np.array([side * c, 0.0, s])
    e2 = np.cross(axis, e1)
    return axis, e1, e2


def mannequin(height: float = 1.75, edge_length: float = 0.022) -> Body:
    """A procedural human-like body: ONE closed, consistently outward-wound 2-manifold (genus 0),
    standing on z = 0, facing -Y, arms in an A-pose, with a skeleton and skinning weights.

    Why one welded surface and not overlapping capsules: the collision module treats the body as
    a volumetric object (inside/outside by ray parity and hit-face orientation), which overlapping
    closed parts would break wherever they overlap (shoulders, hips) - exactly where the shirt is.

    Built from elliptic cross-section rings lofted along a central column (torso, neck, head),
    two legs that split off the crotch ring (the crotch ring's halves plus a shared inseam bridge
    become each thigh's top ring) and two arms that grow out of rectangular openings cut in the
    torso's sides. Rings carry about ``edge_length`` metres between vertices, so the default gives
    ~8K well-shaped triangles; the shirt needs that much to sit at a uniform clearance.

    height       standing height in metres (proportions scale uniformly).
    edge_length  target edge length in metres at height 1.75 (scaled with the body).
    """
    height = _check_positive("height", height)
    edge_length = _check_positive("edge_length", edge_length)
    if not 0.5 <= height <= 2.5:
        raise ValueError(f"height must be between 0.5 and 2.5 m for a human figure, got {height}")
    s = height / 1.75
    edge = edge_length * s
    if edge > 0.06 * s or edge < 0.008 * s:
        raise ValueError(
            f"edge_length must be between 0.008 and 0.06 m (x height/1.75), got {edge_length}: "
            "coarser loses the limbs, finer gives more than ~80K triangles"
        )
    B = _Builder()
    col_tab, col_at = _column_profile(s)

    # ---- column rings ------------------------------------------------------------------------
    z_lo, z_top = col_tab[0, 0], col_tab[-1, 0]
    zs = _arc_stations(lambda z: col_at(z)[..., :2], z_lo, z_top, edge)
    prof = col_at(zs)
    per = _ellipse_perimeter(prof[:, 0], prof[:, 1])
    n_torso = max(16, 4 * int(round(_ellipse_perimeter(*col_at(1.24 * s)[:2]) / edge / 4.0)))
    hole_lo, hole_hi = _HOLE_Z[0] * s, _HOLE_Z[1] * s
    fixed_top = hole_hi + 2.5 * edge  # rings stay at n_torso up to here (the arm openings)
    rings, ring_u = [], []
    for r, z in enumerate(zs[:-1]):
        a, b, cy = prof[r]
        if z <= fixed_top:
            n = n_torso
        else:
            # at most ~30 % fewer vertices than the ring below, so the zipper keeps angles open
            n = int(np.clip(round(per[r] / edge), math.ceil(0.7 * len(rings[-1])), n_torso))
            n = max(n, 3)
        th = _ellipse_angles(b, a, n)  # t = 0 at the front (-Y), increasing toward +X
        pts = np.stack([a * np.sin(th), cy - b * np.cos(th), np.full(n, z)], axis=1)
        rings.append(B.add(pts, _COL))
        ring_u.append(th / (2 * np.pi))
    crown = B.add([[0.0, prof[-1, 2], zs[-1]]], _COL)[0]

    # arm openings: rows (ring indices) and columns (vertex indices) of removed quads
    rows = [r for r, z in enumerate(zs[:-1]) if hole_lo <= z <= hole_hi]
    if len(rows) < 2:
        raise ValueError("edge_length too coarse to open the arm sockets")
    r0, r1 = rows[0], rows[-1]
    zc = 0.5 * (zs[r0] + zs[r1])
    column_edge = _ellipse_perimeter(*col_at(zc)[:2]) / n_torso
    c_half = max(1, int(round(_HOLE_HALF_WIDTH * s / column_edge)))
    holes = {}
    for side in (1, -1):
        mid = n_torso // 4 if side > 0 else 3 * n_torso // 4
        holes[side] = (mid - c_half, mid + c_half)

    def in_hole(r, j):
        for j0, j1 in holes.values():
            if r0 <= r < r1 and j0 <= j < j1:
                return True
        return False

    for r in range(len(rings) - 1):
        ra, rb = rings[r], rings[r + 1]
        if len(ra) == len(rb) == n_torso:
            quads = [
                (ra[j], ra[(j + 1) % n_torso], rb[(j + 1) % n_torso], rb[j])
                for j in range(n_torso)
                if not in_hole(r, j)
            ]
            B.quads(quads)
        else:
            B.zip(ra, ring_u[r], rb, ring_u[r + 1])
    B.fan(rings[-1], crown)

    # ---- legs: the crotch ring's halves plus a shared inseam bridge ---------------------------
    leg_tab, leg_at = _leg_profile(s)
    crotch = rings[0]
    _, b0, cy0 = prof[0]
    front = crotch[0]
    y_front, y_back = cy0 - b0, cy0 + b0
    k = max(1, int(round((y_back - y_front) / edge)) - 1)
    yb = np.linspace(y_back, y_front, k + 2)[1:-1]  # back to front
    sag = 0.012 * s * (1.0 - ((yb - cy0) / b0) ** 2)
    bridge = B.add(np.stack([np.zeros(k), yb, np.full(k, zs[0]) - sag], axis=1), _COL)
    verts_so_far = np.concatenate(B.verts)
    leg_top = {
        1: np.concatenate([crotch[: n_torso // 2 + 1], bridge]),
        -1: np.concatenate([crotch[n_torso // 2 :], [front], bridge[::-1]]),
    }
    leg_zs = _arc_stations(lambda z: leg_at(z)[..., :2], leg_tab[0, 0], leg_tab[-1, 0], edge)
    for side in (1, -1):
        label = _LEG_L if side > 0 else _LEG_R
        xc = side * _HIP_X * s
        top = leg_top[side]
        tp = verts_so_far[top]
        prev, prev_u = top, np.arctan2(tp[:, 1], tp[:, 0] - xc) / (2 * np.pi)
        for z in leg_zs:
            a, b, cy = leg_at(z)
            n = max(6, int(round(_ellipse_perimeter(a, b) / edge)))
            # start at the outer side so the zipper's first pair lines up, wind like the top ring
            th = _ellipse_angles(a, b, n, start=0.0, direction=1.0)
            pts = np.stack([xc + a * np.cos(th), cy + b * np.sin(th), np.full(n, z)], axis=1)
            ring = B.add(pts, label)
            u = np.arctan2(b * np.sin(th), a * np.cos(th)) / (2 * np.pi)
            B.zip(prev, prev_u, ring, u)
            prev, prev_u = ring, u
        # flat sole: concentric shrinking rings at z = 0, then a centre vertex
        a, b, cy = leg_at(leg_tab[-1, 0])
        z = leg_tab[-1, 0]
        for f in (0.68, 0.38):
            n = max(5, int(round(_ellipse_perimeter(a * f, b * f) / edge)))
            th = _ellipse_angles(a * f, b * f, n)
            pts = np.stack([xc + f * a * np.cos(th), cy + f * b * np.sin(th), np.full(n, z)], 1)
            ring = B.add(pts, label)
            u = np.arctan2(b * np.sin(th), a * np.cos(th)) / (2 * np.pi)
            B.zip(prev, prev_u, ring, u)
            prev, prev_u = ring, u
        centre = B.add([[xc, cy, z]], label)[0]
        B.fan(prev, centre)

    # ---- arms: grown out of the rectangular openings -------------------------------------------
    arm_tab, arm_at = _arm_profile(s)
    joint = {1: _SHOULDER * s, -1: _SHOULDER * s * np.array([-1.0, 1.0, 1.0])}
    verts_so_far = np.concatenate(B.verts)
    for side in (1, -1):
        label = _ARM_L if side > 0 else _ARM_R
        j0, j1 = holes[side]
        loop = (
            [rings[r0][j] for j in range(j0, j1)]
            + [rings[r][j1] for r in range(r0, r1)]
            + [rings[r1][j] for j in range(j1, j0, -1)]
            + [rings[r][j0] for r in range(r1, r0, -1)]
        )
        loop = np.asarray(loop)
        J = joint[side]
        axis, e1, e2 = _arm_frame(side)
        rel = verts_so_far[loop] - J
        d_loop = rel @ axis
        phi = np.unwrap(np.arctan2(rel @ e2, rel @ e1))
        rho = np.hypot(rel @ e1, rel @ e2)
        L = len(loop)
        direction = 1.0 if phi[-1] > phi[0] else -1.0
        # uniform angles with the same winding, rotated to sit closest to the loop's angles
        base = direction * np.arange(L) * 2 * np.pi / L
        off = np.angle(np.mean(np.exp(1j * (phi - base))))
        phi_u = base + off
        dphi = (phi_u - phi + np.pi) % (2 * np.pi) - np.pi
        # transition rings from the (tilted) opening to the first ring square to the axis
        d_end = max(d_loop.max() + 2.0 * edge, 0.12 * s)
        m = max(2, int(math.ceil((d_end - d_loop.min()) / edge)))
        prev, prev_u = loop, phi / (2 * np.pi)
        for i in range(1, m + 1):
            lam = i / m
            d = d_loop + (d_end - d_loop) * lam
            ease = 1.0 - (1.0 - lam) ** 2
            ph = phi + dphi * ease
            ab = arm_at(d)
            rad = ab[:, 0] * ab[:, 1] / np.hypot(ab[:, 1] * np.cos(ph), ab[:, 0] * np.sin(ph))
            r = rho + (rad - rho) * ease
            around = np.cos(ph)[:, None] * e1 + np.sin(ph)[:, None] * e2
            pts = J + d[:, None] * axis + r[:, None] * around
            ring = B.add(pts, label)
            qs = [(prev[q], prev[(q + 1) % L], ring[(q + 1) % L], ring[q]) for q in range(L)]
            B.quads(qs)
            prev, prev_u = ring, ph / (2 * np.pi)
        ds_ = _arc_stations(arm_at, d_end, arm_tab[-1, 0], edge)[1:-1]
        start = float(ph[0])  # the last transition ring ends on uniform angles from here
        for d in ds_:
            a, b = arm_at(d)
            n = max(5, int(round(_ellipse_perimeter(a, b) / edge)))
            th = _ellipse_angles(a, b, n, start=start % (2 * np.pi), direction=direction)
            pts = J + d * axis + a * np.cos(th)[:, None] * e1 + b * np.sin(th)[:, None] * e2
            ring = B.add(pts, label)
            u = np.arctan2(b * np.sin(th), a * np.cos(th)) / (2 * np.pi)
            B.zip(prev, prev_u, ring, u)
            prev, prev_u = ring, u
        tip = B.add([J + arm_tab[-1, 0] * axis], label)[0]
        B.fan(prev, tip)

    verts, labels, tris = B.finish()
    tris = _orient_consistently(tris, len(verts))
    if _signed_volume(verts, tris) < 0:
        tris = tris[:, ::-1].copy()
    bones, weights = _skin(verts, labels, s, joint)
    measurements = {
        "height": height,
        "scale": s,
        "column_profile": col_tab,
        "arm_profile": arm_tab,
        "leg_profile": leg_tab,
        "shoulder_left": joint[1],
        "shoulder_right": joint[-1],
        "arm_angle": _ARM_ANGLE,
        "elbow_d": _ELBOW_D * s,
        "hip_x": _HIP_X * s,
        "crotch_z": zs[0],
        "armpit_z": zs[r0],
        "shoulder_top_z": zs[r1],
        "labels": labels,
    }
    return Body(verts, np.ascontiguousarray(tris, dtype=np.int32), bones, weights, "mannequin",
                measurements)


def _skin(verts, labels, s, joint):
    """Bones and linear-blend weights from the construction labels.

    Each limb takes over from its parent across a joint band (smoothsteps along the limb axis);
    column vertices near a limb root get a share of it (shoulders by distance to the arm axis,
    buttocks by side), so the shoulder and the crotch stretch instead of shearing. Whatever the
    limbs leave goes to pelvis / spine / head by height. Rows sum to one by construction.
    """
    z = verts[:, 2]
    x = verts[:, 0]
    hip_z, knee_z, ankle_z = _BIND_Z["hip"] * s, _BIND_Z["knee"] * s, _BIND_Z["ankle"] * s
    def up(z):
        return np.array([0.0, 0.0, z * s])

    bones = [
        ("pelvis", up(_BIND_Z["pelvis"]), up(_BIND_Z["chest"]), -1),
        ("spine", up(_BIND_Z["chest"]), up(_BIND_Z["neck"]), 0),
        ("head", up(_BIND_Z["neck"]), up(1.75), 1),
    ]
    names = {}
    for side, tag in ((1, "L"), (-1, "R")):
        axis, _, _ = _arm_frame(side)
        J = joint[side]
        elbow = J + _ELBOW_D * s * axis
        names[f"upper_arm.{tag}"] = len(bones)
        bones.append((f"upper_arm.{tag}", J.copy(), elbow, 1))
        names[f"forearm.{tag}"] = len(bones)
        bones.append((f"forearm.{tag}", elbow, J + _ARM[-1, 0] * s * axis, len(bones) - 1))
    for side, tag in ((1, "L"), (-1, "R")):
        hx = side * _HIP_X * s
        names[f"thigh.{tag}"] = len(bones)
        bones.append((f"thigh.{tag}", np.array([hx, 0.0, hip_z]), np.array([hx, 0.0, knee_z]), 0))
        names[f"shin.{tag}"] = len(bones)
        knee, ankle = np.array([hx, 0.0, knee_z]), np.array([hx, 0.0, ankle_z])
        bones.append((f"shin.{tag}", knee, ankle, len(bones) - 1))
    W = np.zeros((len(verts), len(bones)))
    limb_total = np.zeros(len(verts))
    for side, tag, arm_label, leg_label in ((1, "L", _ARM_L, _LEG_L), (-1, "R", _ARM_R, _LEG_R)):
        # arm
        axis, _, _ = _arm_frame(side)
        rel = verts - joint[side]
        d = rel @ axis
        radial = np.linalg.norm(rel - d[:, None] * axis, axis=1)
        gate = np.where(labels == arm_label, 1.0, 0.0)
        near_axis = _smoothstep(0.11 * s, 0.07 * s, radial) * (side * x > 0.05 * s)
        gate = np.where(labels == _COL, near_axis, gate)
        w_arm = _smoothstep(-0.04 * s, 0.10 * s, d) * gate
        w_fore = _smoothstep((_ELBOW_D - 0.04) * s, (_ELBOW_D + 0.04) * s, d)
        W[:, names[f"upper_arm.{tag}"]] = w_arm * (1 - w_fore)
        W[:, names[f"forearm.{tag}"]] = w_arm * w_fore
        limb_total += w_arm
        # leg
        gate = np.where(labels == leg_label, 1.0, 0.0)
        gate = np.where(labels == _COL, _smoothstep(-0.05 * s, 0.05 * s, side * x), gate)
        w_leg = _smoothstep(hip_z, hip_z - 0.14 * s, z) * gate
        w_leg = np.where(labels == leg_label, 1.0, w_leg) * np.where(
            labels == leg_label, _smoothstep(hip_z - 0.10 * s, hip_z - 0.20 * s, z) * 0.3 + 0.7, 1.0
        )
        w_shin = _smoothstep(knee_z + 0.05 * s, knee_z - 0.05 * s, z)
        W[:, names[f"thigh.{tag}"]] = w_leg * (1 - w_shin)
        W[:, names[f"shin.{tag}"]] = w_leg * w_shin
        limb_total += w_leg
    rest = 1.0 - limb_total
    w_spine = _smoothstep(1.00 * s, 1.20 * s, z)
    w_head = _smoothstep(1.47 * s, 1.53 * s, z)
    W[:, 0] = rest * (1 - w_spine)
    W[:, 1] = rest * w_spine * (1 - w_head)
    W[:, 2] = rest * w_spine * w_head
    W = np.clip(W, 0.0, None)
    W /= W.sum(axis=1, keepdims=True)
    return bones, W


# ------------------------------------------------------------------------------------------------
# Animation: linear blend skinning, walk then reach for the hem
# ------------------------------------------------------------------------------------------------

WALK_END = 2.0  # s: the walk cycle runs on [0, WALK_END), then the arms reach forward
_STRIDE_PERIOD = 1.0  # s per full gait cycle (two steps)


def _rotation(axis, angle):
    """Rotation matrix (3, 3) about a unit axis by angle (radians), right-handed (Rodrigues)."""
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    x, y, z = axis
    c, s_ = math.cos(angle), math.sin(angle)
    C = 1.0 - c
    return np.array(
        [
            [c + x * x * C, x * y * C - z * s_, x * z * C + y * s_],
            [y * x * C + z * s_, c + y * y * C, y * z * C - x * s_],
            [z * x * C - y * s_, z * y * C + x * s_, c + z * z * C],
        ]
    )


def _about(head, R):
    """4x4 transform rotating by R about the point ``head`` (bind-pose coordinates)."""
    M = np.eye(4)
    M[:3, :3] = R
    M[:3, 3] = head - R @ head
    return M


def _flex_axis(head, tail, side=1.0, inward=0.0):
    """Axis about which a positive angle swings the bone's tail toward the front (-Y), and with
    ``inward`` > 0 also toward the body's mid-plane (a forearm bending across the belly)."""
    d = tail - head
    d = d / np.linalg.norm(d)
    a = np.cross(d, [-side * inward, -1.0, 0.0])
    return a / np.linalg.norm(a)


def _ease(t):
    return _smoothstep(0.0, 1.0, t)


# Arm keyframes after the walk: time (s), shoulder flex, elbow flex, shoulder abduction (deg).
# At 3 s the palms are at the front of the hem (about x = +-0.17, y = -0.24, z = 0.95 m); at 4 s
# they have moved ~0.13 m apart each (x = +-0.30), pulling it open. The elbow bends across the belly
# (_ELBOW_INWARD) because a forearm that only flexes forward would leave the hands 30 cm out.
_REACH_KEYS = np.array([(2.0, 0.0, 0.0, 0.0), (3.0, 4.0, 72.0, -16.0), (4.0, 4.0, 70.0, 0.0)])
_ELBOW_INWARD = 1.5


def _pose_angles(t):
    """Joint angles at time t: name -> (flex, abduction) in radians.

    Walk on [0, 2) s: thighs swing +-22 deg in opposition, knees bend up to 35 deg while the leg
    swings forward, arms swing +-14 deg against the same-side leg. An envelope brings the walk in
    and out smoothly, so t = 0 and t = 2 s are exactly the bind pose and nothing jerks. The walk is
    in place (no root travel), so the scene stays framed.
    From 2 s: the arm keyframes ``_REACH_KEYS`` (eased): reach the hem, then pull outward; hold.
    """
    out = {}
    if t < WALK_END:
        env = float(_smoothstep(0.0, 0.4, t) * _smoothstep(WALK_END, WALK_END - 0.4, t))
        ph = 2.0 * math.pi * t / _STRIDE_PERIOD
        for tag, sgn in (("L", 1.0), ("R", -1.0)):
            swing = sgn * math.sin(ph)
            out[f"thigh.{tag}"] = (math.radians(22.0) * env * swing, 0.0)
            knee = max(0.0, sgn * math.cos(ph)) ** 2  # bent while the leg travels forward
            out[f"shin.{tag}"] = (-math.radians(35.0) * env * knee, 0.0)
            out[f"upper_arm.{tag}"] = (-math.radians(14.0) * env * swing, 0.0)
            out[f"forearm.{tag}"] = (math.radians(10.0) * env, 0.0)
    else:
        keys = _REACH_KEYS
        k = int(np.clip(np.searchsorted(keys[:, 0], t) - 1, 0, len(keys) - 2))
        w = float(_ease((t - keys[k, 0]) / (keys[k + 1, 0] - keys[k, 0])))
        fl, el, ab = np.radians(keys[k, 1:] + w * (keys[k + 1, 1:] - keys[k, 1:]))
        for tag in ("L", "R"):
            out[f"upper_arm.{tag}"] = (fl, ab)
            out[f"forearm.{tag}"] = (el, 0.0)
    return out


def bone_matrices(body: Body, t: float) -> np.ndarray:
    """World transforms (n_bones, 4, 4) of every bone at time t (s), relative to the bind pose:
    each bone rotates about its own head, composed parent-first. Identity at t = 0."""
    t = float(t)
    if not math.isfinite(t) or t < 0.0:
        raise ValueError(f"t must be a finite time >= 0 in seconds, got {t}")
    angles = _pose_angles(t)
    reaching = t >= WALK_END
    mats = np.zeros((len(body.bones), 4, 4))
    for i, (name, head, tail, parent) in enumerate(body.bones):
        head = np.asarray(head, dtype=np.float64)
        tail = np.asarray(tail, dtype=np.float64)
        side = 1.0 if head[0] >= 0 else -1.0
        flex, abd = angles.get(name, (0.0, 0.0))
        # abduction first (about the front-back axis, tail away from the mid-plane), then flexion
        R = _rotation([0.0, 1.0, 0.0], -side * abd)
        inward = _ELBOW_INWARD if (reaching and name.startswith("forearm")) else 0.0
        R = _rotation(_flex_axis(head, tail, side, inward), flex) @ R
        local = _about(head, R)
        mats[i] = local if parent < 0 else mats[parent] @ local
    return mats


def body_pose(body: Body, t: float) -> np.ndarray:
    """Vertex positions (n, 3) of ``body`` at time t (s) by linear blend skinning.

    The motion (see ``_pose_angles``): a walk in place on [0, 2) s, then both hands come forward to
    the front of the shirt hem (2-3 s) and pull outward (3-4 s), then hold. Hips and shoulders
    move at most 22 deg, so a simulated shirt can follow; the elbows bend up to 72 deg across the
    belly. The walk is in place; the feet dip up to ~1 cm below z = 0 mid-stride (no ground
    contact is modelled).
    t = 0 returns the bind pose exactly.
    """
    if not isinstance(body, Body):
        raise TypeError(f"body_pose needs a Body, got {type(body).__name__}")
    mats = bone_matrices(body, t)
    v = body.vertices
    vh = np.concatenate([v, np.ones((len(v), 1))], axis=1)
    # blend the matrices first (one matmul), then apply once
    blended = (body.weights @ mats[:, :3, :].reshape(len(mats), 12)).reshape(-1, 3, 4)
    return np.einsum("nij,nj->ni", blended, vh)


# ------------------------------------------------------------------------------------------------
# Closest points on a triangle mesh (exact, grid-accelerated)
# ------------------------------------------------------------------------------------------------


def _closest_on_triangles(p, a, b, c):
    """Closest points on triangles (a, b, c) to points p, all (k, 3), vectorised (Ericson,
    Real-Time Collision Detection 5.1.5). Returns (q (k, 3), region (k,)) with region 0 face,
    1/2/3 vertex a/b/c, 4/5/6 edge ab/bc/ca: the feature decides which normal gives the sign."""
    ab, ac, ap = b - a, c - a, p - a
    d1 = np.einsum("ij,ij->i", ab, ap)
    d2 = np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3 = np.einsum("ij,ij->i", ab, bp)
    d4 = np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5 = np.einsum("ij,ij->i", ab, cp)
    d6 = np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = 1.0 / (va + vb + vc)
        v_face = vb * denom
        w_face = vc * denom
        q = a + ab * v_face[:, None] + ac * w_face[:, None]
        region = np.zeros(len(p), dtype=np.int8)
        # edge bc
        m = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        q = np.where(m[:, None], b + (c - b) * w[:, None], q)
        region[m] = 5
        # edge ca
        m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        w = d2 / (d2 - d6)
        q = np.where(m[:, None], a + ac * w[:, None], q)
        region[m] = 6
        # edge ab
        m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        v = d1 / (d1 - d3)
        q = np.where(m[:, None], a + ab * v[:, None], q)
        region[m] = 4
    # vertices last: they win over the edge tests they also satisfy
    m = (d6 >= 0) & (d5 <= d6)
    q[m], region[m] = c[m], 3
    m = (d3 >= 0) & (d4 <= d3)
    q[m], region[m] = b[m], 2
    m = (d1 <= 0) & (d2 <= 0)
    q[m], region[m] = a[m], 1
    bad = ~np.all(np.isfinite(q), axis=1)  # degenerate triangle: fall back to its vertex a
    q[bad], region[bad] = a[bad], 1
    return q, region


class _MeshDistance:
    """Signed distance queries against a fixed triangle mesh.

    Triangles are binned in uniform grids (a fine one with cells of about one mean edge, and
    coarser ones, x4 each, built on demand). A query gathers the 3x3x3 cells around its point and
    is exact once the distance found is within one cell (anything closer would lie in those
    cells); queries still unresolved move to the next coarser grid. The sign uses angle-weighted
    pseudo-normals at the closest feature (Baerentzen & Aanaes 2005), which is right on vertices
    and edges too, for a closed outward-wound mesh.
    """

    def __init__(self, vertices, triangles, cell=None):
        self.v = np.asarray(vertices, dtype=np.float64)
        self.t = np.asarray(triangles, dtype=np.int64)
        p = self.v[self.t]
        self.a, self.b, self.c = p[:, 0], p[:, 1], p[:, 2]
        fn = np.cross(self.b - self.a, self.c - self.a)
        fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
        self.face_n = fn
        ang = _triangle_angles(self.v, self.t)
        vn = np.zeros_like(self.v)
        for k in range(3):
            np.add.at(vn, self.t[:, k], fn * ang[:, k : k + 1])
        self.vert_n = vn / np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-300)
        keys = _edge_keys(self.t, len(self.v))
        uniq, inv = np.unique(keys.ravel(), return_inverse=True)
        en = np.zeros((len(uniq), 3))
        np.add.at(en, inv, np.repeat(fn, 3, axis=0))
        self.edge_n = en[inv].reshape(-1, 3, 3)  # per triangle side: ab, bc, ca
        if cell is None:
            cell = float(np.mean(np.linalg.norm(self.b - self.a, axis=1)))
        self.box_lo = np.minimum(np.minimum(self.a, self.b), self.c)
        self.box_hi = np.maximum(np.maximum(self.a, self.b), self.c)
        self.lo = self.v.min(axis=0)
        self.extent = float(np.ptp(self.v, axis=0).max())
        self.cells = [float(cell)]
        self.grids = [self._grid(float(cell))]

    def _grid(self, cell):
        origin = self.lo - cell
        lo = np.floor((np.minimum(np.minimum(self.a, self.b), self.c) - origin) / cell)
        hi = np.floor((np.maximum(np.maximum(self.a, self.b), self.c) - origin) / cell)
        lo, hi = lo.astype(np.int64), hi.astype(np.int64)
        dims = hi.max(axis=0) + 3
        span = hi - lo + 1
        count = span.prod(axis=1)
        tri = np.repeat(np.arange(len(self.t)), count)
        k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
        sy, sz = np.repeat(span[:, 1], count), np.repeat(span[:, 2], count)
        ix = np.repeat(lo[:, 0], count) + k // (sy * sz)
        iy = np.repeat(lo[:, 1], count) + (k // sz) % sy
        iz = np.repeat(lo[:, 2], count) + k % sz
        key = (ix * dims[1] + iy) * dims[2] + iz
        order = np.argsort(key, kind="stable")
        return origin, dims, key[order], tri[order]

    def query(self, points, max_distance=None):
        """(closest (k, 3), signed distance (k,), triangle (k,)); distance > 0 outside.
        With ``max_distance``, points farther than that get distance inf and triangle -1 (and
        cost much less: the coarse grids are never visited)."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        k = len(pts)
        best_d = np.full(k, np.inf)
        best_q = np.zeros((k, 3))
        best_t = np.zeros(k, dtype=np.int64)
        best_r = np.zeros(k, dtype=np.int8)
        todo = np.arange(k)
        level = 0
        while len(todo):
            if level == len(self.grids):
                cell = self.cells[-1] * 4.0
                self.cells.append(cell)
                self.grids.append(self._grid(cell))
            cell = self.cells[level]
            self._search(pts, todo, self.grids[level], cell, best_d, best_q, best_t, best_r)
            if cell > 2.0 * self.extent:
                break  # the 27 cells covered every triangle
            if max_distance is not None and cell >= max_distance:
                break  # everything within max_distance has been found exactly
            todo = todo[best_d[todo] > cell]
            level += 1
        sign = self._sign(pts, best_q, best_t, best_r)
        if max_distance is not None:
            far = best_d > max_distance
            best_d[far] = np.inf
            best_t[far] = -1
        return best_q, sign * best_d, best_t

    def _search(self, pts, todo, grid, cell, best_d, best_q, best_t, best_r):
        origin, dims, cell_keys, cell_tris = grid
        offs = np.array([(i, j, l) for i in (-1, 0, 1) for j in (-1, 0, 1) for l in (-1, 0, 1)])
        for chunk in range(0, len(todo), 2048):
            ids = todo[chunk : chunk + 2048]
            gi = np.floor((pts[ids] - origin) / cell).astype(np.int64)
            nb = (gi[:, None, :] + offs[None]).reshape(-1, 3)
            inside = np.all((nb >= 0) & (nb < dims), axis=1)
            key = np.where(inside, (nb[:, 0] * dims[1] + nb[:, 1]) * dims[2] + nb[:, 2], -1)
            s = np.searchsorted(cell_keys, key, side="left")
            e = np.where(inside, np.searchsorted(cell_keys, key, side="right"), s)
            n = e - s
            pid = np.repeat(np.repeat(ids, 27), n)
            within = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
            tri = cell_tris[np.repeat(s, n) + within]
            # Cheap pruning before the exact test: a triangle whose bounding box is farther than
            # some candidate's corner cannot be the closest.
            p = pts[pid]
            ub = np.full(len(pts), np.inf)
            np.minimum.at(ub, pid, np.linalg.norm(p - self.a[tri], axis=1))
            gap = np.maximum(self.box_lo[tri] - p, 0.0) + np.maximum(p - self.box_hi[tri], 0.0)
            keep = np.einsum("ij,ij->i", gap, gap) <= ub[pid] ** 2 * (1.0 + 1e-9) + 1e-300
            self._reduce(pts, pid[keep], tri[keep], best_d, best_q, best_t, best_r)

    def _reduce(self, pts, pid, tri, best_d, best_q, best_t, best_r):
        if len(pid) == 0:
            return
        q, region = _closest_on_triangles(pts[pid], self.a[tri], self.b[tri], self.c[tri])
        d = np.linalg.norm(pts[pid] - q, axis=1)
        order = np.lexsort((d, pid))
        first = np.ones(len(order), dtype=bool)
        first[1:] = pid[order][1:] != pid[order][:-1]
        sel = order[first]
        i = pid[sel]
        better = d[sel] < best_d[i]
        i, sel = i[better], sel[better]
        best_d[i] = d[sel]
        best_q[i] = q[sel]
        best_t[i] = tri[sel]
        best_r[i] = region[sel]

    def pseudo_normals(self, tri, region):
        """Unit normal of the closest feature: face, edge (sum of the two faces) or vertex
        (angle-weighted)."""
        n = self.face_n[tri].copy()
        for r, corner in ((1, 0), (2, 1), (3, 2)):
            m = region == r
            n[m] = self.vert_n[self.t[tri[m], corner]]
        for r, side in ((4, 0), (5, 1), (6, 2)):
            m = region == r
            n[m] = self.edge_n[tri[m], side]
        return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)

    def _sign(self, pts, q, tri, region):
        n = self.pseudo_normals(tri, region)
        self.last_normals = n
        s = np.einsum("ij,ij->i", pts - q, n)
        return np.where(s < 0.0, -1.0, 1.0)

    def candidates(self, points, radius):
        """Triangles whose bounding box comes within ``radius`` (k,) of each point, as a padded
        (k, K) index array (-1 = none). Lets an iterative fit test only a short list per point."""
        pts = np.asarray(points, dtype=np.float64)
        radius = np.broadcast_to(np.asarray(radius, dtype=np.float64), (len(pts),))
        origin, dims, cell_keys, cell_tris = self.grids[0]
        cell = self.cells[0]
        rc = int(math.ceil(float(radius.max()) / cell))
        r = np.arange(-rc, rc + 1)
        offs = np.stack(np.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3)
        pids, tris = [], []
        step = max(1, 200_000 // len(offs))
        for chunk in range(0, len(pts), step):
            ids = np.arange(chunk, min(chunk + step, len(pts)))
            gi = np.floor((pts[ids] - origin) / cell).astype(np.int64)
            nb = (gi[:, None, :] + offs[None]).reshape(-1, 3)
            inside = np.all((nb >= 0) & (nb < dims), axis=1)
            key = np.where(inside, (nb[:, 0] * dims[1] + nb[:, 1]) * dims[2] + nb[:, 2], -1)
            s = np.searchsorted(cell_keys, key, side="left")
            e = np.where(inside, np.searchsorted(cell_keys, key, side="right"), s)
            n = e - s
            pid = np.repeat(np.repeat(ids, len(offs)), n)
            within = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
            tri = cell_tris[np.repeat(s, n) + within]
            p = pts[pid]
            gap = np.maximum(self.box_lo[tri] - p, 0.0) + np.maximum(p - self.box_hi[tri], 0.0)
            keep = np.einsum("ij,ij->i", gap, gap) <= radius[pid] ** 2
            pair = np.unique(pid[keep] * np.int64(len(self.t)) + tri[keep])
            pids.append(pair // len(self.t))
            tris.append(pair % len(self.t))
        pid = np.concatenate(pids)
        tri = np.concatenate(tris)
        count = np.bincount(pid, minlength=len(pts))
        K = max(1, int(count.max(initial=0)))
        out = np.full((len(pts), K), -1, dtype=np.int64)
        slot = np.arange(len(pid)) - np.repeat(np.cumsum(count) - count, count)
        out[pid, slot] = tri
        return out


def closest_points(vertices, triangles, points):
    """Closest points on a triangle mesh to query points, exact.

    Returns (closest (k, 3), signed_distance (k,), triangle (k,)). The sign is positive outside
    a closed, outward-wound mesh (pseudo-normal test, right on edges and vertices too); for an
    open mesh it says which side of the nearest feature the point is on. Grid-accelerated:
    ~2K queries against an 8K-triangle body take a few milliseconds.
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles)
    if v.ndim != 2 or v.shape[1] != 3 or t.ndim != 2 or t.shape[1] != 3 or len(t) == 0:
        raise ValueError("closest_points needs vertices (n, 3) and at least one triangle (m, 3)")
    q, d, tri = _MeshDistance(v, t).query(points)
    return q, d, tri


# ------------------------------------------------------------------------------------------------
# T-shirt: two flat panels sewn together, fitted around the mannequin
# ------------------------------------------------------------------------------------------------

_SHIRT_HEM_Z = 0.88  # m at height 1.75: the hem sits on the hips
_SHIRT_SLEEVE = 0.15  # m, underarm seam length (short sleeves end above the elbow)
_ARMPIT_CUT = 0.10  # m of side seam and underarm seam replaced by the rounded armpit curve
_NECK_DEPTH = (0.075, 0.025)  # front / back scoop of the neckline below the neck side points


def _shirt_pattern(body: Body, clearance: float):
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
    a = _pchip(col[:, 0], col[:, 1], zz)
    b = _pchip(col[:, 0], col[:, 2], zz)
    half_round = float(_ellipse_perimeter(a + c, b + c).max()) / 2.0
    W2 = half_round / 2.0  # panel half width: a quarter of the widest girth
    t_a = z_arm - z_hem
    neck_z = 1.500 * s
    t_n = neck_z - z_hem
    s_n = 0.085 * s
    beta = math.pi / 2.0 - m["arm_angle"]  # sleeve direction below the horizontal
    e_b = np.array([math.cos(beta), -math.sin(beta)])
    n_b = np.array([math.sin(beta), math.cos(beta)])
    arm = m["arm_profile"]
    upper = _pchip(arm[:, 0], np.maximum(arm[:, 1], arm[:, 2]), [0.1 * s, 0.2 * s])
    r_sleeve = float(np.max(upper))
    V = math.pi * (r_sleeve + c) * 1.06  # half the sleeve girth, a little ease
    P_a = np.array([W2, t_a])
    t_s = m["shoulder_top_z"] + 0.03 * s - z_hem
    # shoulder point: V across the sleeve from the armpit, at shoulder height
    delta = ((P_a[1] + V * n_b[1]) - t_s) / math.sin(beta)
    P_s = P_a + V * n_b + delta * e_b
    # where the armpit is along the arm axis (the sleeve map starts there)
    axis, _, _ = _arm_frame(1.0, m["arm_angle"])
    armpit = np.array([_pchip(col[:, 0], col[:, 1], m["armpit_z"]), 0.0, m["armpit_z"]])
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


def _frontal_map(p2, body, dims, clearance):
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
    a = _pchip(col[:, 0], col[:, 1], z) + c
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
        _smoothstep(-0.02 * sc, 0.06 * sc, u)
        * _smoothstep(-0.03 * sc, 0.03 * sc, sig - dims["W2"])
        * _smoothstep(-0.03 * sc, 0.0, v)
    )
    for sd in (1.0, -1.0):
        k = side == sd
        axis, e1, _ = _arm_frame(sd, m["arm_angle"])
        J = m["shoulder_left"] if sd > 0 else m["shoulder_right"]
        d = dims["d_a"] + u[k]
        r = np.maximum(_pchip(arm[:, 0], arm[:, 1], d), _pchip(arm[:, 0], arm[:, 2], d)) + c
        pos = J + d[:, None] * axis - (r * np.cos(psi[k]))[:, None] * e1
        sleeve[k] = pos[:, [0, 2]]
    return torso * (1.0 - w[:, None]) + sleeve * w[:, None]


def _raycast_depth(vertices, triangles, xz, front):
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


class _PartDistance:
    """Distances from slowly moving points to two parts of a body (0: torso, legs, head; 1: arms).

    A fit moves each point by millimetres per round, so instead of a fresh grid search each time
    every point keeps its closest triangle per part and walks from it: each query tests the
    triangles sharing a vertex with the current one (~15 tests per point and part). A full search
    per part (``refresh``) seeds the walk and is repeated now and then, so a point that drifted
    toward another region cannot stay in a local minimum. Parts farther than ``reach`` are
    ignored (their weight in the smooth minimum would be nil).

    Distances are signed by the nearer part only: a sign taken at a part's closest feature is
    meaningless when another part is closer.
    """

    def __init__(self, md: _MeshDistance, tri_part, reach, jump):
        self.md = md
        self.reach = reach
        self.jump = jump
        tri_part = np.asarray(tri_part, dtype=np.int64)
        self.part_tris = [np.flatnonzero(tri_part == g) for g in (0, 1)]
        self.sub = [_MeshDistance(md.v, md.t[idx]) for idx in self.part_tris]
        t = md.t
        m = len(t)
        order = np.argsort(t.ravel(), kind="stable")
        vert_of = t.ravel()[order]
        tri_of = order // 3
        start = np.searchsorted(vert_of, np.arange(len(md.v)))
        count = np.bincount(vert_of, minlength=len(md.v))
        ring = np.full((len(md.v), int(count.max())), m, dtype=np.int64)
        ring[vert_of, np.arange(len(vert_of)) - np.repeat(start, count)] = tri_of
        nb = ring[t].reshape(m, -1)
        own = np.arange(m)
        ok = nb < m
        ok[ok] = tri_part[nb[ok]] == np.repeat(tri_part, ok.sum(axis=1))
        nb = np.sort(np.where(ok, nb, m), axis=1)
        dup = np.zeros_like(ok)
        dup[:, 1:] = nb[:, 1:] == nb[:, :-1]
        nb = np.sort(np.where(dup, m, nb), axis=1)  # unique ids first, sentinel m last
        width = int((nb < m).sum(axis=1).max())
        nb = nb[:, :width]
        self.nb = np.where(nb < m, nb, own[:, None])
        self.best = None

    def refresh(self, x, idx=None):
        """Exact search (per part) for all points, or for the points ``idx``."""
        if self.best is None or idx is None:
            idx = np.arange(len(x))
            self.best = [np.full(len(x), -1, dtype=np.int64) for _ in (0, 1)]
            self.anchor = x.copy()
        for g in (0, 1):
            _, _, tri = self.sub[g].query(x[idx], max_distance=self.reach)
            self.best[g][idx] = np.where(tri >= 0, self.part_tris[g][np.maximum(tri, 0)], -1)
        self.anchor[idx] = x[idx]

    def query(self, x):
        """Per part: signed distance (k,) (inf when out of reach) and its gradient (k, 3)."""
        if self.best is None:
            self.refresh(x)
        else:
            # A walk only follows small moves; a point that jumped is searched afresh (a stale
            # closest feature can give the wrong side, and the fit would then flip it inside).
            jumped = np.linalg.norm(x - self.anchor, axis=1) > self.jump
            if np.any(jumped):
                self.refresh(x, np.flatnonzero(jumped))
        n = len(x)
        dist = np.full((2, n), np.inf)
        near = np.zeros((2, n, 3))
        feature = np.zeros((2, n), dtype=np.int8)
        for g in (0, 1):
            live = np.flatnonzero(self.best[g] >= 0)
            if len(live) == 0:
                continue
            cand = self.nb[self.best[g][live]]
            K = cand.shape[1]
            tri = cand.ravel()
            P = np.repeat(x[live], K, axis=0)
            q, region = _closest_on_triangles(P, self.md.a[tri], self.md.b[tri], self.md.c[tri])
            d = np.linalg.norm(P - q, axis=1).reshape(len(live), K)
            k = np.argmin(d, axis=1)
            flat = np.arange(len(live)) * K + k
            self.best[g][live] = tri[flat]
            dist[g, live] = d[np.arange(len(live)), k]
            near[g, live] = q[flat]
            feature[g, live] = region[flat]
        closer = np.argmin(dist, axis=0)
        rows = np.arange(n)
        tri_c = np.array(self.best)[closer, rows]
        sign = np.ones(n)
        ok = tri_c >= 0
        nrm = self.md.pseudo_normals(tri_c[ok], feature[closer, rows][ok])
        away = x[ok] - near[closer, rows][ok]
        sign[ok] = np.where(np.einsum("ij,ij->i", away, nrm) < 0.0, -1.0, 1.0)
        out = []
        for g in (0, 1):
            away = x - near[g]
            with np.errstate(invalid="ignore", divide="ignore"):
                grad = sign[:, None] * away / dist[g][:, None]
            tiny = dist[g] <= 1e-9
            if np.any(tiny):
                tri_t = np.maximum(self.best[g][tiny], 0)
                grad[tiny] = self.md.pseudo_normals(tri_t, feature[g][tiny])
            grad[~np.isfinite(dist[g])] = 0.0
            out.append((sign * dist[g], grad))
        return out


def _closest_on_segments(pts, a, b):
    """Closest point (k, 3) on the nearest of the segments a[j]-b[j] to each point."""
    d = b - a
    dd = np.maximum(np.einsum("ij,ij->i", d, d), 1e-300)
    t = np.clip(np.einsum("nkj,kj->nk", pts[:, None, :] - a[None], d) / dd, 0.0, 1.0)
    q = a[None] + t[..., None] * d[None]
    k = np.argmin(((pts[:, None, :] - q) ** 2).sum(-1), axis=1)
    return q[np.arange(len(pts)), k]


def _loop_order(idx, eu, ev):
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


def _fit_shirt(x, tris, panel, loops, parts, clearance, iterations, fillet):
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
                y[idx] = _closest_on_segments(y[idx], a_, b_)
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


def _flip_edges(x, tris, group, max_passes=20):
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
            return _triangle_angles(x, tr).min(axis=1)

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


def _collapse_short_edges(x, tris, panel, seam, min_angle=18.0, short=0.5, rounds=4):
    """Collapse the shortest edge of every sliver (min angle below ``min_angle`` deg) whose
    shortest edge is under ``short`` x the median edge (0.8 x for a cap, angle > 150 deg): the
    vertex of lower rank (interior < seam < rim) merges into the other, which does not move.
    Skipped when it would pinch the surface (link condition), cross a rim or a seam, fold a
    neighbouring triangle or leave a worse angle than the sliver had.

    Returns (triangles with removed rows set to -1, mask of the vertices still in use).
    """
    t = np.array(tris, dtype=np.int64)
    n = len(x)
    keys = _edge_keys(t, n).ravel()
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
        ang = np.degrees(_triangle_angles(x, t[live])).min(axis=1)
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
            worst = float(np.degrees(_triangle_angles(x, t[f : f + 1])).min())
            cap = float(np.degrees(_triangle_angles(x, t[f : f + 1])).max()) > 150.0
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
            if len(new) and np.degrees(_triangle_angles(x, new)).min() <= worst:
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


def _cut_and_sew(front_p, back_p, seams, target_triangles, seed):
    """Mesh both panels with one spacing (chosen so the total count hits the target) and sew them:
    the back panel's seam samples become the front panel's vertices, and the back panel is
    flipped so both are counter-clockwise seen from outside.

    Returns ((front points, front triangles), (back points, back triangles), panel coordinates of
    the sewn vertices, sewn triangles, sewn index of every back point, is-front mask and seam
    mask of the sewn vertices. Front points keep their indices.
    """
    panels = []
    for k, pieces in enumerate((front_p, back_p)):
        pieces = _as_pieces(pieces)
        polygon = np.concatenate([p[:-1] for p in pieces], axis=0)
        area = 0.5 * abs(float(np.sum(polygon[:, 0] * np.roll(polygon[:, 1], -1)
                                      - np.roll(polygon[:, 0], -1) * polygon[:, 1])))
        panels.append((pieces, polygon, area, seed * 2 + k))
    h = _search_spacing(
        lambda h: sum(_predicted_count(pc, poly, h, sd) for pc, poly, _, sd in panels),
        sum(p[2] for p in panels),
        target_triangles,
    )
    meshes = []
    n_pieces = len(front_p)
    for pieces, polygon, _, sd in panels:
        boundary, piece_of = _sample_outline(pieces, h)
        inner = _interior_candidates(boundary, polygon, h, sd)
        # one relaxation round is enough here: the 3-D fit smooths the sewn shirt again
        pts, tris, _ = _mesh_points(boundary, inner, polygon, h, 1)
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


def tshirt(
    body: Body | None = None,
    target_triangles: int = 3300,
    seed: int = 0,
    clearance: float = 0.012,
) -> ClothMesh:
    """The paper's T-shirt (Table I: ~3.3K triangles), worn by the mannequin at its bind pose.

    Made like a real one: a front and a back panel cut from one flat pattern (body plus short
    sleeves that leave at the arm angle; the front neckline scooped deeper), each meshed
    irregularly, then sewn vertex to vertex along the shoulder, top-sleeve, underarm and side
    seams into one edge-manifold surface with four open rims (neck, waist, two cuffs). The sewn
    shirt is wrapped around the torso and arms and settled ``clearance`` metres outside the body
    surface, so at rest it touches nothing (the simulation starts without contacts) yet fits
    (every vertex exactly ``clearance`` from the body, up to ~6 mm more where it bridges the
    armpits, as the paper's fitted shirt). Takes ~1.5 s (the fit is most of it).

    body              the wearer (default: ``mannequin()``), in its bind pose.
    target_triangles  total triangle count (the seams add none), hit within ~2 % (the clean-up
                      of slivers may remove a few more).
    clearance         rest gap between shirt and body, metres (5 mm to 3 cm).

    Groups: ``hem_left`` / ``hem_right``: the bottom hem of the front panel where the left (+X) and
    right (-X) hands grab it to pull it apart; ``shoulders``: along the shoulder seams, fading out
    over 4 cm (to pin the shirt while it is torn).
    UV: front panel in the left half of UV space, back panel (seen from outside) in the right half;
    ``corner_uv`` keeps both UVs of the seam vertices.
    """
    target_triangles = _check_count(target_triangles)
    clearance = _check_positive("clearance", clearance)
    if not 0.005 <= clearance <= 0.03:
        raise ValueError(f"clearance must be between 0.005 and 0.03 m, got {clearance}")
    if body is None:
        body = mannequin()
    if not isinstance(body, Body):
        raise TypeError(f"body must be a Body (from mannequin()), got {type(body).__name__}")
    front_p, back_p, seams, dims = _shirt_pattern(body, clearance)
    (pf, tf), (pb, tb), p2, tris, back_index, is_front, seam = _cut_and_sew(
        front_p, back_p, seams, target_triangles, seed
    )
    # Wrap: lay the pattern on the body's silhouette, then take the depth from rays cast from the
    # front (front panel) or back (back panel) onto the body inflated by the clearance. Seam
    # vertices sit on the silhouette, between the two hits.
    D = _MeshDistance(body.vertices, body.triangles)
    inflated = body.vertices + clearance * D.vert_n
    xz = _frontal_map(p2, body, dims, clearance)
    yf = _raycast_depth(inflated, body.triangles, xz, front=True)
    yb = _raycast_depth(inflated, body.triangles, xz, front=False)
    y = np.where(is_front, yf, yb)
    y = np.where(seam, 0.5 * (yf + yb), y)
    y = np.where(np.isnan(y), 0.0, y)  # a miss (just off the silhouette): the mid-plane
    x = np.stack([xz[:, 0], y, xz[:, 1]], axis=1)
    # Rims: hem and neck slide along their first curve, cuffs keep their place along the arm.
    n = len(x)
    keys = _edge_keys(tris, n).ravel()
    uniq, counts = np.unique(keys, return_counts=True)
    rim = uniq[counts == 1]
    lab = _connected_labels(n, np.stack([rim // n, rim % n], axis=1))
    rim_v = np.unique(np.concatenate([rim // n, rim % n]))
    loops = []
    m = body.measurements
    for root in np.unique(lab[rim_v]):
        idx = rim_v[lab[rim_v] == root]
        cx = x[idx].mean(axis=0)
        if abs(cx[0]) > dims["W2"]:  # a cuff
            sd_ = 1.0 if cx[0] > 0 else -1.0
            axis_, _, _ = _arm_frame(sd_, m["arm_angle"])
            J = m["shoulder_left"] if sd_ > 0 else m["shoulder_right"]
            dval = float(np.mean((x[idx] - J) @ axis_))
            loops.append((idx, "d", dval, axis_, J))
        else:  # hem or neck: keep the rim on its curve
            ring = _loop_order(idx, rim // n, rim % n)
            loops.append((idx, "curve", (x[ring], x[np.roll(ring, -1)]), None, None))
    labels = m["labels"][body.triangles]
    tri_part = np.isin(labels, (_ARM_L, _ARM_R)).sum(axis=1) >= 2
    fillet = 0.008 * m["scale"]
    parts = _PartDistance(D, tri_part, reach=0.08 * m["scale"], jump=0.008 * m["scale"])
    panel = np.r_[np.zeros(len(tf), dtype=np.int64), np.ones(len(tb), dtype=np.int64)]
    x = _fit_shirt(x, tris, panel, loops, parts, clearance, iterations=30, fillet=fillet)
    # UVs: one uniform scale for both panels so texel density matches across the seams; the
    # front panel fills u in [0.02, 0.48], the back panel (mirrored, as seen from outside)
    # u in [0.52, 0.98].
    width = 2.0 * float(np.abs(np.concatenate([pf[:, 0], pb[:, 0]])).max())
    tall = float(max(pf[:, 1].max(), pb[:, 1].max()))
    k = 0.46 / max(width, 2.0 * tall)
    uv_front = np.full((len(x), 2), np.nan)
    uv_back = np.full((len(x), 2), np.nan)
    uv_front[: len(pf)] = np.stack([0.25 + pf[:, 0] * k, 0.05 + pf[:, 1] * k], axis=1)
    uv_back[back_index] = np.stack([0.75 - pb[:, 0] * k, 0.05 + pb[:, 1] * k], axis=1)
    # Clean-up of the few slivers the fit leaves (rims and seams pull unevenly): collapse the
    # shortest edge of a sliver (vertices do not move, so the clearance holds), then flip.
    tris, keep = _collapse_short_edges(x, tris, panel, seam)
    x, p2, is_front, uv_front, uv_back = (a[keep] for a in (x, p2, is_front, uv_front, uv_back))
    panel = panel[tris[:, 0] >= 0]
    tris = tris[tris[:, 0] >= 0]
    remap = np.cumsum(keep) - 1
    tris = remap[tris]
    tris = _flip_edges(x, tris, panel)
    uv = np.where(np.isnan(uv_front), uv_back, uv_front)  # seam vertices: their front UV
    corner = np.where((panel == 0)[:, None, None], uv_front[tris], uv_back[tris])
    # Groups (panel coordinates make "front hem, left of centre" exact).
    sc = m["scale"]
    grip = (p2[:, 1] <= 0.03 * sc) & is_front
    hem_left = grip & (p2[:, 0] >= 0.04 * sc) & (p2[:, 0] <= 0.16 * sc)
    hem_right = grip & (p2[:, 0] <= -0.04 * sc) & (p2[:, 0] >= -0.16 * sc)
    a_ = np.array([[dims["s_n"], dims["t_n"]], [-dims["s_n"], dims["t_n"]]])
    b_ = np.array([dims["P_s"], dims["P_s"] * [-1.0, 1.0]])
    dist = _distance_to_segments(p2, a_, b_)
    shoulders = np.clip(1.0 - dist / (0.04 * sc), 0.0, 1.0)
    groups = {
        "hem_left": hem_left.astype(np.float64),
        "hem_right": hem_right.astype(np.float64),
        "shoulders": shoulders,
    }
    return ClothMesh(x, tris.astype(np.int32), uv, groups, "tshirt", corner)
