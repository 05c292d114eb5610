"""The user's mesh attributes through tears, and the torn-edge attributes, as cache primvars (no bpy).

What this file owns
-------------------
* ``UserAttribute``: one attribute of the user's mesh as the bake carries it (point values per
  solver vertex, corner values per triangle corner, face values per triangle), and ``USD_TYPES``:
  which Blender attribute type goes into which USD primvar type (what stock Blender's USD reader,
  bpy 5.0.1 and 5.3.0, reads back under the same name and type; probed, see tests/test_attributes.py).
* ``carried_groups``: point attributes travel through tears inside the core as extra vertex-group
  columns, because the core already interpolates a vertex group at a split with the split's own
  weights and copies it to a duplicate, and the bake's resume state saves the groups. Three more
  columns carry each vertex's ORIGINAL rest position (never changed by the solver, unlike the rest
  positions), which locates every triangle and corner of the torn mesh in the user's mesh.
* ``AttributeTracker``: per frame, every carried attribute and ``torn``, ``torn_time``, ``warp``
  as ``{name: (usd type, interpolation, values)}`` for ``CacheWriter.write_frame(primvars=...)``.

Why the original rest position is enough: a tear only splits triangles (each piece lies inside
the triangle it came from, in rest space) and duplicates vertices (same rest position); a
removed fragment renumbers what is left, so triangles and points are known by their carried rest
positions, never by index. So a triangle's rest centroid lies inside exactly one original
triangle (its face attributes come from that face), and a corner's barycentric coordinates in that
triangle interpolate the original triangle's own corner values: a duplicated vertex's corners keep
their own triangles' values, so UV seams along the tear stay sharp. A boundary edge of the torn mesh
is a torn edge unless its rest midpoint lies on a boundary edge of the original mesh.

The torn-edge attributes (read by the frayed-edge Geometry Nodes group by these names):
``torn`` (float 1.0 on points of a torn edge, else 0.0), ``torn_time`` (s since the bake's first
frame, to the frame, when the point first lay on a torn edge; -1 if never; a duplicate made by the
separation inherits its twin's time), ``warp`` (unit float3, world space: the warp thread, the
direction in which the active UV map's u grows on the deformed surface, turned by the grain angle
about the normal, averaged over the point's faces; the object's local X axis projected on the
surface without a UV map).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Blender attribute type -> (USD value type, components). A BYTE_COLOR plays back as a float
# colour of its name: Blender's USD reader fills float colours only and skips an existing byte
# layer of that name, so the played object gets a modifier that removes the byte layer from the
# reader's input (blender/modifier.py, set_float_colours). Left out because Blender's USD reader
# does not give them back under their name and type: FLOAT2 outside the corner domain (it makes
# them UV maps), double/float4 (not converted), 2D ints, matrices, strings, and the EDGE domain (no
# USD interpolation). QUATERNION is read back but its component order is not checked yet.
USD_TYPES = {
    "FLOAT": ("FloatArray", 1),
    "INT": ("IntArray", 1),
    "BOOLEAN": ("BoolArray", 1),
    "INT8": ("UCharArray", 1),      # read back as INT8: the byte's two's complement
    "FLOAT_VECTOR": ("Vector3fArray", 3),
    "FLOAT_COLOR": ("Color4fArray", 4),
    "BYTE_COLOR": ("Color4fArray", 4),
    "FLOAT2": ("TexCoord2fArray", 2),  # corner domain only: a UV map
}
INTERPOLATION = {"POINT": "vertex", "CORNER": "faceVarying", "FACE": "uniform"}
# Names the cache writes itself (and Blender's own per-frame data): a user attribute of that name
# is not carried, and says so.
RESERVED = ("position", "velocity", "torn", "torn_time", "warp", "sharp_face", "sharp_edge")
GRAIN_ATTRIBUTE = "tearcloth_grain_angle"  # per-face grain angle (radians), overrides the material's

_GROUP_PREFIX = ".tearcloth:"  # no Blender vertex group the user makes is matched by mistake
REST_GROUPS = tuple(f"{_GROUP_PREFIX}rest:{k}" for k in "xyz")


@dataclass
class UserAttribute:
    """One attribute of the user's mesh in solver order: ``values`` is (n, k) per vertex for the
    POINT domain, (m, 3, k) per triangle corner for CORNER, (m, k) per triangle for FACE."""

    name: str
    domain: str        # POINT, CORNER, FACE
    data_type: str     # Blender's: FLOAT, INT, BOOLEAN, INT8, FLOAT_VECTOR, FLOAT_COLOR, FLOAT2
    values: np.ndarray

    @property
    def usd_type(self) -> str:
        return USD_TYPES[self.data_type][0]

    @property
    def interpolation(self) -> str:
        return INTERPOLATION[self.domain]

    def groups(self) -> list[str]:
        return [f"{_GROUP_PREFIX}attr:{self.name}:{k}" for k in range(self.values.shape[-1])]


def unsupported(data_type: str, domain: str) -> str | None:
    """Why an attribute of that type and domain cannot be carried (None: it can)."""
    if domain not in INTERPOLATION:
        return f"{domain.lower()} attributes have no USD primvar Blender reads back"
    if data_type == "FLOAT2" and domain != "CORNER":
        return "Blender reads 2D vectors back as UV maps (corners) only"
    if data_type not in USD_TYPES:
        return f"{data_type.lower()} attributes have no USD primvar Blender reads back"
    return None


def carried_groups(rest_vertices, attributes) -> dict:
    """The extra vertex-group columns the cloth carries through tears: the original rest position
    (x, y, z) and every component of every point attribute."""
    rest = np.asarray(rest_vertices, dtype=np.float64).reshape(-1, 3)
    out = {name: rest[:, k].copy() for k, name in enumerate(REST_GROUPS)}
    for a in attributes:
        if a.domain == "POINT":
            v = np.asarray(a.values, dtype=np.float64).reshape(len(rest), -1)
            out.update({name: v[:, k].copy() for k, name in enumerate(a.groups())})
    return out


def _cast(attr: UserAttribute, values: np.ndarray) -> np.ndarray:
    """Interpolated values in the attribute's own type (ints round, booleans hold from 0.5)."""
    if attr.data_type in ("INT", "INT8"):
        return np.rint(values).astype(np.int64)
    if attr.data_type == "BOOLEAN":
        return values >= 0.5
    return values


class AttributeTracker:
    """Per-frame primvars of a bake (see the module docstring).

    ``rest0``/``triangles0``: the user's mesh as the bake started from it (world metres, triangle
    corners); ``attributes``: the ``UserAttribute`` list; ``grain_angle``: the material's grain
    angle (radians) where the mesh has no ``tearcloth_grain_angle`` face attribute."""

    def __init__(self, rest0, triangles0, attributes, grain_angle: float = 0.0):
        self.rest0 = np.asarray(rest0, dtype=np.float64).reshape(-1, 3)
        self.tri0 = np.asarray(triangles0, dtype=np.int64).reshape(-1, 3)
        self.attributes = list(attributes)
        m0 = len(self.tri0)
        grain = next((a for a in self.attributes if a.name == GRAIN_ATTRIBUTE and a.domain == "FACE"), None)
        self.grain0 = (np.asarray(grain.values, dtype=np.float64).reshape(m0) if grain is not None
                       else np.full(m0, float(grain_angle)))
        p = self.rest0[self.tri0]                     # (m0, 3, 3)
        self._a, self._e1, self._e2 = p[:, 0], p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
        n = np.cross(self._e1, self._e2)
        self._area2 = np.linalg.norm(n, axis=1)
        self._normal = n / np.maximum(self._area2, 1e-300)[:, None]
        # an original edge (opposite corner k) on the user's boundary: used by one triangle only
        self._boundary0 = _single_edges(self.tri0).reshape(m0, 3)
        pad = 1e-6 * (np.ptp(self.rest0, axis=0).max() if len(self.rest0) else 1.0)
        self._box_lo, self._box_hi = p.min(axis=1) - pad, p.max(axis=1) + pad
        # Keyed by material points, not by index: a removed fragment (fragment.c) renumbers the
        # vertices and triangles, so an index would name another element afterwards. A triangle is
        # keyed by its three carried rest positions (order-free), a point by its own, which its
        # twin across a tear shares: it tore when its twin did.
        self._origin_of = dict(zip(_triangle_keys(self.rest0, self.tri0), range(m0)))
        self._torn_at: dict = {}
        self._resumed_torn_time = None  # torn_time of a resumed bake's last frame, keyed on next frame

    # -- locating the torn mesh in the user's mesh ---------------------------------------------

    def _bary(self, points: np.ndarray, tris: np.ndarray) -> np.ndarray:
        """Barycentric coordinates (k, 3) of points (k, 3) in original triangles (k,)."""
        e1, e2, d = self._e1[tris], self._e2[tris], points - self._a[tris]
        d11, d12, d22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
        d1, d2 = (d * e1).sum(1), (d * e2).sum(1)
        det = np.where(np.abs(d11 * d22 - d12 * d12) > 0, d11 * d22 - d12 * d12, 1.0)
        b1 = (d22 * d1 - d12 * d2) / det
        b2 = (d11 * d2 - d12 * d1) / det
        return np.stack([1.0 - b1 - b2, b1, b2], axis=1)

    def _locate(self, centroids: np.ndarray) -> np.ndarray:
        """The original triangle each rest centroid lies in: of the original triangles whose box
        holds it, the one it is closest to (inside and in its plane). Only triangles made since the
        last frame are located, a handful per frame."""
        out = np.empty(len(centroids), dtype=np.int64)
        size = np.sqrt(np.maximum(self._area2, 1e-300))
        for i, c in enumerate(centroids):
            near = np.flatnonzero(np.all((self._box_lo <= c) & (c <= self._box_hi), axis=1))
            if not len(near):
                near = np.arange(len(self.tri0))
            pts = np.broadcast_to(c, (len(near), 3))
            b = self._bary(pts, near)
            outside = np.maximum(-b.min(axis=1), 0.0)
            off_plane = np.abs(((pts - self._a[near]) * self._normal[near]).sum(1))
            out[i] = near[np.argmin(outside + off_plane / size[near])]
        return out

    def origins(self, triangles: np.ndarray, rest0: np.ndarray) -> np.ndarray:
        """The original triangle of every current triangle; only triangles not met before (made
        by a tear since the last frame) are located."""
        keys = _triangle_keys(rest0, triangles)
        origin = np.fromiter((self._origin_of.get(k, -1) for k in keys), dtype=np.int64, count=len(keys))
        new = np.flatnonzero(origin < 0)
        if len(new):
            origin[new] = self._locate(rest0[triangles[new]].mean(axis=1))
            self._origin_of.update(zip((keys[i] for i in new), origin[new].tolist()))
        return origin

    # -- one frame -----------------------------------------------------------------------------

    def frame(self, cloth, time: float, object_matrix=None, uv=None) -> dict:
        """``{name: (usd type, interpolation, values)}`` for the cloth's current mesh. ``time``:
        seconds since the bake's first frame; ``object_matrix``: the object's world matrix (4x4,
        for the warp without UVs); ``uv``: the active UV map per corner (m, 3, 2) or None."""
        tris = np.asarray(cloth.triangles, dtype=np.int64)
        names = list(cloth.group_names)
        groups = cloth.groups
        rest0 = groups[:, [names.index(g) for g in REST_GROUPS]]
        origin = self.origins(tris, rest0)
        corner_bary = self._corner_bary(tris, rest0, origin)   # (m, corner, original corner)
        out = {}
        for a in self.attributes:
            if a.domain == "POINT":
                values = groups[:, [names.index(g) for g in a.groups()]]
            elif a.domain == "FACE":
                values = np.asarray(a.values, dtype=np.float64).reshape(len(self.tri0), -1)[origin]
            else:  # corners: each corner interpolates its own original triangle's corners
                c0 = np.asarray(a.values, dtype=np.float64).reshape(len(self.tri0), 3, -1)[origin]
                values = np.einsum("mck,mkj->mcj", corner_bary, c0).reshape(len(tris) * 3, -1)
            values = _cast(a, values)
            out[a.name] = (a.usd_type, a.interpolation, values[:, 0] if values.shape[1] == 1 else values)
        torn = self._torn_points(tris, rest0, origin, len(groups))
        out["torn"] = ("FloatArray", "vertex", torn.astype(np.float32))
        out["torn_time"] = ("FloatArray", "vertex", self._update_torn_time(torn, rest0, time))
        positions = np.asarray(cloth.positions, dtype=np.float64)
        out["warp"] = ("Vector3fArray", "vertex", warp_directions(positions, tris, uv, self.grain0[origin],
                                                                  object_matrix))
        return out

    def _corner_bary(self, tris, rest0, origin) -> np.ndarray:
        """Each corner's barycentric coordinates in its original triangle: the identity for the
        user's triangles a tear left alone (most of them), computed for the others only."""
        m = len(tris)
        bary = np.broadcast_to(np.eye(3), (m, 3, 3)).copy()
        moved = ~np.all(rest0[tris] == self.rest0[self.tri0[origin]], axis=(1, 2))
        idx = np.flatnonzero(moved)
        if len(idx):
            b = np.clip(self._bary(rest0[tris[idx]].reshape(-1, 3), np.repeat(origin[idx], 3)), 0.0, 1.0)
            b /= np.maximum(b.sum(1, keepdims=True), 1e-300)
            bary[idx] = b.reshape(-1, 3, 3)
        return bary

    def _torn_points(self, tris, rest0, origin, n) -> np.ndarray:
        edges = np.stack([tris[:, [1, 2]], tris[:, [2, 0]], tris[:, [0, 1]]], axis=1).reshape(-1, 2)
        boundary = np.flatnonzero(_single_edges(tris))
        torn = np.zeros(n, dtype=bool)
        if len(boundary):
            e = edges[boundary]
            b = self._bary(0.5 * (rest0[e[:, 0]] + rest0[e[:, 1]]), origin[boundary // 3])
            # on an original edge when the opposite barycentric coordinate vanishes
            k = np.argmin(np.abs(b), axis=1)
            on_edge = np.abs(b[np.arange(len(b)), k]) < 1e-9
            was_boundary = on_edge & self._boundary0[origin[boundary // 3], k]
            torn[e[~was_boundary].reshape(-1)] = True
        return torn

    def _update_torn_time(self, torn, rest0, time) -> np.ndarray:
        keys = _point_keys(rest0)
        if self._resumed_torn_time is not None:
            for k, t in zip(keys, self._resumed_torn_time[:len(keys)]):
                if t >= 0:
                    self._torn_at.setdefault(k, float(t))
            self._resumed_torn_time = None
        for v in np.flatnonzero(torn):
            self._torn_at.setdefault(keys[v], time)
        return np.fromiter((self._torn_at.get(k, -1.0) for k in keys), dtype=np.float32, count=len(keys))

    def restore_torn_time(self, values) -> None:
        """Continue a resumed bake: the ``torn_time`` of the cache's last frame (per point of the
        cloth as restored, keyed on the next frame)."""
        self._resumed_torn_time = np.asarray(values, dtype=np.float64).reshape(-1).copy()


def _point_keys(rest0) -> list:
    """One bytes key per point: its carried rest position (exact: the core copies it to twins)."""
    r = np.ascontiguousarray(rest0, dtype=np.float64)
    return r.view(np.dtype((np.void, 24))).ravel().tolist()


def _triangle_keys(rest0, triangles) -> list:
    """One bytes key per triangle: its three carried rest positions, sorted (any corner order)."""
    c = np.ascontiguousarray(np.asarray(rest0, dtype=np.float64)[np.asarray(triangles, dtype=np.int64)])
    v = np.sort(c.view(np.dtype((np.void, 24))).reshape(len(c), 3), axis=1)
    return np.ascontiguousarray(v).view(np.dtype((np.void, 72))).ravel().tolist()


def _single_edges(tris: np.ndarray) -> np.ndarray:
    """(3m,) True where the edge opposite each corner (order 12, 20, 01) has no other triangle."""
    t = np.asarray(tris, dtype=np.int64)
    e = np.stack([t[:, [1, 2]], t[:, [2, 0]], t[:, [0, 1]]], axis=1).reshape(-1, 2)
    lo, hi = e.min(axis=1), e.max(axis=1)
    key = lo * (int(t.max(initial=0)) + 1) + hi  # one integer per edge: a 1-D unique is fast
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    return counts[inverse.reshape(-1)] == 1


def warp_directions(positions, triangles, corner_uv, grain, object_matrix=None) -> np.ndarray:
    """Per point unit warp direction (n, 3) in the positions' space (see the module docstring).
    ``grain``: (m,) angle in radians per triangle; ``corner_uv`` (m, 3, 2) or None."""
    x = np.asarray(positions, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    p = x[t]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    normal = np.cross(e1, e2)
    area2 = np.linalg.norm(normal, axis=1)
    fn = normal / np.maximum(area2, 1e-300)[:, None]
    axis_x = np.array([1.0, 0.0, 0.0])
    if object_matrix is not None:
        axis_x = np.asarray(object_matrix, dtype=np.float64)[:3, 0]
        axis_x = axis_x / max(np.linalg.norm(axis_x), 1e-300)
    fallback = axis_x[None, :] - (fn @ axis_x)[:, None] * fn
    tangent = fallback
    if corner_uv is not None and len(t):
        uv = np.asarray(corner_uv, dtype=np.float64)
        du1, dv1 = uv[:, 1, 0] - uv[:, 0, 0], uv[:, 1, 1] - uv[:, 0, 1]
        du2, dv2 = uv[:, 2, 0] - uv[:, 0, 0], uv[:, 2, 1] - uv[:, 0, 1]
        det = du1 * dv2 - du2 * dv1
        ok = np.abs(det) > 1e-12
        # dx/du at constant v: the line a warp thread follows as u grows
        dxdu = (dv2[:, None] * e1 - dv1[:, None] * e2) / np.where(ok, det, 1.0)[:, None]
        tangent = np.where(ok[:, None], dxdu, fallback)
    tangent = tangent - (tangent * fn).sum(1, keepdims=True) * fn
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1), 1e-300)[:, None]
    g = np.asarray(grain, dtype=np.float64).reshape(-1)
    tangent = np.cos(g)[:, None] * tangent + np.sin(g)[:, None] * np.cross(fn, tangent)
    n = len(x)
    acc = np.zeros((n, 3))
    vn = np.zeros((n, 3))
    for k in range(3):
        np.add.at(acc, t[:, k], tangent)
        np.add.at(vn, t[:, k], normal)
    vn /= np.maximum(np.linalg.norm(vn, axis=1), 1e-300)[:, None]
    acc -= (acc * vn).sum(1, keepdims=True) * vn  # tangent to the surface at the point
    length = np.linalg.norm(acc, axis=1)
    bad = length < 1e-9
    if bad.any():  # opposite faces cancelled (or a lone point): the projected X axis
        alt = axis_x[None, :] - (vn[bad] @ axis_x)[:, None] * vn[bad]
        alt_len = np.linalg.norm(alt, axis=1)
        alt = np.where(alt_len[:, None] > 1e-9, alt, np.cross(vn[bad], axis_x[None, :]))
        acc[bad] = alt
        length = np.linalg.norm(acc, axis=1)
    return (acc / np.maximum(length, 1e-300)[:, None]).astype(np.float32)
