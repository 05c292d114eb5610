"""Plain mesh data of the example geometry and the facts every generated mesh must keep.

This file owns ``ClothMesh`` (a sheet as arrays: vertices, triangles, UVs, vertex groups),
``validate_mesh`` (manifoldness, winding, components, angles), ``refine`` (1-to-4 midpoint
subdivision for the scaling benchmarks), the argument checks of the scene generators
(``check_count``, ``check_positive``) and the small topology helpers the mesher, the mannequin
and the shirt share (``edge_keys``, ``connected_labels``, ``orient_consistently``,
``signed_volume``, ``triangle_angles``). Dev-only (``tearcloth.examples``, left out of the
extension zip), so components come from ``scipy.sparse.csgraph``; SI units (metres).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components


# Below this a "mesh" is too coarse to tear along stress lines, and the target-count search of the
# mesher has too few points to work with.
MIN_TARGET_TRIANGLES = 50


def check_count(target_triangles):
    """A scene's triangle target as an int, or ValueError (not an integer, or too few)."""
    if isinstance(target_triangles, bool) or not isinstance(target_triangles, (int, np.integer)):
        raise ValueError(f"target_triangles must be an integer, got {target_triangles!r}")
    if target_triangles < MIN_TARGET_TRIANGLES:
        raise ValueError(
            f"target_triangles must be at least {MIN_TARGET_TRIANGLES}, got {target_triangles}"
        )
    return int(target_triangles)


def check_positive(name, value):
    """A length in metres as a float, or ValueError naming ``name`` (not finite, or <= 0)."""
    value = float(value)
    if not (value > 0.0 and math.isfinite(value)):
        raise ValueError(f"{name} must be a positive length in metres, got {value}")
    return value


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


def _triangle_areas(vertices, triangles):
    v = np.asarray(vertices, dtype=np.float64)
    if v.shape[1] == 2:
        v = np.concatenate([v, np.zeros((len(v), 1))], axis=1)
    a, b, c = v[triangles[:, 0]], v[triangles[:, 1]], v[triangles[:, 2]]
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)


def triangle_angles(vertices, triangles):
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


def edge_keys(triangles, n_vertices):
    """Undirected edge key per triangle side (m, 3); side k joins corners k and k+1."""
    a = triangles.astype(np.int64)
    b = np.roll(a, -1, axis=1)
    lo = np.minimum(a, b)
    hi = np.maximum(a, b)
    return lo * np.int64(n_vertices) + hi


def connected_labels(n, pairs):
    """Connected-component label per node (n,) from an (e, 2) edge list. scipy numbers the
    components in the order of their lowest node, so sorting the labels keeps the order in which
    callers walk components (lowest vertex first) and every generated mesh stays as it was."""
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    graph = coo_matrix((np.ones(len(pairs), dtype=np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)[1].astype(np.int64)


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
    keys = edge_keys(t, n).ravel()
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
        lab = connected_labels(n, np.stack([bu, bv], axis=1))
        boundary_loops = int(len(np.unique(lab[np.concatenate([bu, bv])])))
    else:
        boundary_loops = 0
    used = np.zeros(n, dtype=bool)
    used[t.ravel()] = True
    edge_pairs = np.stack([uniq // n, uniq % n], axis=1)
    lab = connected_labels(n, edge_pairs)
    n_components = int(len(np.unique(lab[used]))) if m else 0
    areas = _triangle_areas(v, t) if m else np.zeros(0)
    scale = float(np.ptp(v, axis=0).max()) if n else 1.0
    repeated = (t[:, 0] == t[:, 1]) | (t[:, 1] == t[:, 2]) | (t[:, 2] == t[:, 0])
    n_degenerate = int(np.count_nonzero(repeated | (areas <= 1e-12 * scale * scale)))
    ang = np.degrees(triangle_angles(v, t)) if m else np.zeros((0, 3))
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


def orient_consistently(triangles, n_vertices):
    """Flip triangles so that every component has one winding (breadth-first over shared edges).
    Assumes an edge-manifold mesh. Which of the two windings each component ends with is up to
    the caller to fix (by volume or by a known normal)."""
    t = np.array(triangles, dtype=np.int64)
    m = len(t)
    keys = edge_keys(t, n_vertices).ravel()
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


def signed_volume(vertices, triangles):
    p = vertices[triangles]
    return float(np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6.0)


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
        keys = edge_keys(t, n)  # side k joins corners k, k+1
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
