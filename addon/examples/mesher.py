"""The irregular 2-D mesher of the example sheets: Delaunay triangulation of jittered points inside
an outline, relaxed until every angle is comfortably away from zero.

Why irregular: tears follow the stress, and a regular grid makes them snap to grid lines; slivers
degrade both the FEM conditioning and the tear path, hence the relaxation. This file owns
``delaunay_2d`` (Bowyer-Watson with adjacency and a walking point location) and
``triangulate_polygon`` (outline sampling, interior candidates, the spacing search that hits a
target triangle count, relaxation), plus the pieces of that pipeline the T-shirt pattern reuses
(``as_pieces``, ``sample_outline``, ``interior_candidates``, ``mesh_points``, ``predicted_count``,
``search_spacing``).

Hand-written rather than ``scipy.spatial.Delaunay``: Qhull gives the same triangulation only up to
the order of its triangles and the choice among cocircular points, and the example .blend files
and bakes are pinned to this exact output. Units are those of the outline (metres here).
"""
from __future__ import annotations

import math

import numpy as np

from .distance import distance_to_segments
from .mesh import MIN_TARGET_TRIANGLES, edge_keys


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


def as_pieces(outline):
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


def sample_outline(pieces, spacing):
    samples = [_resample_polyline(p, spacing) for p in pieces]
    piece_of = np.concatenate([np.full(len(s), i) for i, s in enumerate(samples)])
    return np.concatenate(samples, axis=0), piece_of


def interior_candidates(boundary, polygon, spacing, rng_seed):
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
    pts = pts[distance_to_segments(pts, boundary, seg_b) >= 0.6 * spacing]
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
    pieces = as_pieces(outline)
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
    boundary, _ = sample_outline(pieces, spacing)
    inner = interior_candidates(boundary, polygon, spacing, seed)
    return mesh_points(boundary, inner, polygon, spacing, relax_rounds)


def predicted_count(pieces, polygon, spacing, seed):
    boundary, _ = sample_outline(pieces, spacing)
    inner = interior_candidates(boundary, polygon, spacing, seed)
    return 2 * len(inner) + len(boundary) - 2


def _spacing_for_count(pieces, polygon, area, target, seed):
    return search_spacing(lambda h: predicted_count(pieces, polygon, h, seed), area, target)


def search_spacing(count_of, area, target):
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


def mesh_points(boundary, inner, polygon, spacing, relax_rounds):
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
                distance_to_segments(cand, seg_a, seg_b) >= 0.55 * spacing
            )
            pts[nb:][ok] = cand[ok]
        tris = _triangulate_inside(pts, polygon, nb)
    return pts, tris, np.arange(nb)


def _triangulate_inside(pts, polygon, nb):
    tris = delaunay_2d(pts)
    cent = pts[tris].mean(axis=1)
    tris = tris[_polygon_contains(polygon, cent)]
    # Every outline segment must have survived as an edge, or the outline is not the mesh border.
    keys = set(edge_keys(tris, len(pts)).ravel().tolist())
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
