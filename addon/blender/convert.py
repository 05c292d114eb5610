"""Blender data <-> solver arrays: the one place where scene units become SI and meshes become
triangle arrays.

What this file owns
-------------------
* Units. Blender stores lengths in Blender units (BU) and shows them multiplied by
  ``unit_settings.scale_length``; one BU is ``scale_length`` metres. Every length-like setting
  (the rows of ``settings.py`` in metres in the scene: cloth thickness, collision thickness,
  displacement_threshold), every position and every gravity vector is multiplied by that factor
  here and nowhere else. Which property feeds which SI field is read off the table's rows. Quantities Blender has no
  unit for (pascals, kg/m^3, N m, 1/s) are stored in SI already and pass through unchanged.
* Spaces. The simulation runs in WORLD space (metres), because colliders, follow objects and
  gravity live there. The cache is written in the cloth object's LOCAL space at each frame
  (``matrix_world(frame)^-1``), because the Mesh Sequence Cache modifier plays it back on that
  object and Blender then applies the object's transform on top; written in world space, a moved
  or parented cloth object would be transformed twice.
* Meshes. The solver wants triangles: n-gons and quads are split with Blender's own
  ``loop_triangles`` (the user's mesh is never touched), UVs are taken per triangle corner from
  the active UV map, vertex groups become weight arrays, and vertices that belong to no face
  (loose vertices, wire edges) are dropped because a membrane solver has nothing to do with them;
  ``MeshArrays.kept`` maps back to the mesh's own vertex indices and ``MeshArrays.polygons``
  each triangle back to the polygon it came from, so messages name the user's elements. A Face
  Float attribute ``tearcloth_grain_angle`` (radians; ``GRAIN_ATTRIBUTE``) is the user's per-face
  override of the grain direction, carried to every triangle of its polygon.
* Colliders are read from the EVALUATED object (modifiers and armatures applied) at the current
  frame, in world space, metres.
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np

from .. import settings as table
from ..attributes import RESERVED, USD_TYPES, UserAttribute, unsupported
from ..materials import MATERIALS, Material
from ..session import CollisionSettings
from ..spaces import local_to_world_si  # the space formulas are bpy-free: the bake job needs them too


# ---------------------------------------------------------------------------------------------
# Units


def scale_length(scene) -> float:
    """Metres per Blender unit of ``scene``."""
    s = float(scene.unit_settings.scale_length)
    return s if s > 0.0 else 1.0


def length_to_si(scene, value: float) -> float:
    return float(value) * scale_length(scene)


def length_from_si(scene, metres: float) -> float:
    return float(metres) / scale_length(scene)


def gravity_si(scene) -> tuple[float, float, float]:
    """The scene's gravity in m/s^2 (zero when the scene's gravity is switched off)."""
    if not scene.use_gravity:
        return (0.0, 0.0, 0.0)
    s = scale_length(scene)
    return tuple(float(g) * s for g in scene.gravity)


def fps(scene) -> float:
    return float(scene.render.fps) / float(scene.render.fps_base)


def _from_blender(row, settings, scene):
    """A row's value in SI from its Blender property (scene lengths to metres, enums to the
    table's lower-case values, numbers to Python floats and ints)."""
    value = getattr(settings, row.blender_name)
    if row.kind == "enum":
        return value.lower()
    if row.kind == "bool":
        return bool(value)
    if row.kind == "int":
        return int(value)
    if row.kind == "float":
        return length_to_si(scene, value) if row.is_scene_length else float(value)
    return value


def _to_blender(row, settings, scene, value) -> None:
    if row.kind == "enum":
        value = value.upper()
    elif row.is_scene_length:
        value = length_from_si(scene, value)
    setattr(settings, row.blender_name, value)


def scene_length_defaults(settings, scene) -> list:
    """Write the table's default of every length of ``settings`` (an object's or the scene's
    Tear Cloth settings) the user has not set, converted to the scene's units: the properties'
    own defaults are metres taken as Blender units, 100 times too small in a centimetre scene.
    Returns the names written."""
    written = []
    for row in table.SETTINGS:
        name = row.blender_name
        if (row.is_scene_length and name is not None and hasattr(settings, name)
                and not settings.is_property_set(name)):
            _to_blender(row, settings, scene, row.default)
            written.append(name)
    return written


def material_from_settings(settings, scene) -> Material:
    """The object's Tear Cloth material settings as an SI ``Material`` (ValueError if absurd)."""
    values = {row.name: _from_blender(row, settings, scene) for row in table.rows("material")}
    values["name"] = values["name"] or "custom"
    # A value the user never set (a field added after the file was saved, e.g. tear_radius in a
    # .blend of an older version) is its preset's, not the property default (cotton's): a banknote
    # saved before must not tear with cotton's radius.
    preset = MATERIALS.get(values["name"])
    if preset is not None:
        for row in table.rows("material"):
            if row.name != "name" and not settings.is_property_set(row.blender_name):
                values[row.name] = getattr(preset, row.name)
    return Material(**values).validate()


def material_to_settings(material: Material, settings, scene) -> None:
    """Write an SI ``Material`` (a preset) into the object's settings, in scene units."""
    for row in table.rows("material"):
        _to_blender(row, settings, scene, getattr(material, row.name))


def collision_from_settings(settings, scene) -> CollisionSettings:
    """The collision rows a ``CollisionSettings`` holds (the on/off switch decides whether one is
    made at all, in bake.py)."""
    names = {f.name for f in fields(CollisionSettings)}
    return CollisionSettings(**{row.name: _from_blender(row, settings, scene) for row in table.rows("collision")
                                if row.name in names}).validate()


def solver_from_settings(settings, scene) -> dict:
    """Keywords for ``Cloth.set_solver``: the scene's gravity and the solver rows Blender stores."""
    solver = {"gravity": gravity_si(scene)}
    solver.update({row.name: _from_blender(row, settings, scene) for row in table.rows("solver")
                   if row.native is not None and row.blender_name is not None})
    return solver


def tearing_from_settings(settings) -> dict:
    """Keywords for ``Cloth.set_tearing`` (enabled, scan_period, min_angle_deg, min_fragment_area)."""
    return {row.name: _from_blender(row, settings, None) for row in table.rows("tearing")
            if row.native is not None}


# ---------------------------------------------------------------------------------------------
# Matrices and spaces (world metres <-> object-local Blender units)


def matrix_array(matrix) -> np.ndarray:
    """A mathutils 4x4 matrix as a float64 numpy array."""
    return np.array([list(row) for row in matrix], dtype=np.float64)


# ---------------------------------------------------------------------------------------------
# Meshes

GRAIN_ATTRIBUTE = "tearcloth_grain_angle"


@dataclass
class MeshArrays:
    """A mesh as the solver wants it, in the mesh's own (local) space and units.

    vertices (n, 3) float64 BU; triangles (m, 3) int32 indexing ``vertices``; corner_uv
    (m, 3, 2) float64 or None; groups name -> (n,) float64 weights in [0, 1]; kept (n,) the
    mesh's own index of every vertex; polygons (m,) the mesh's polygon of every triangle; ngons: faces with more than four corners (triangulated);
    loose: vertices dropped because no face uses them.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    corner_uv: np.ndarray | None = None
    groups: dict = field(default_factory=dict)
    kept: np.ndarray | None = None
    ngons: int = 0
    loose: int = 0
    polygons: np.ndarray | None = None  # (m,) the mesh's polygon index of every triangle
    uv_name: str | None = None          # the name of the UV map corner_uv comes from (the active one)
    other_uv: list = field(default_factory=list)  # names of the UV maps besides the active one
    attributes: list = field(default_factory=list)  # UserAttribute: what the cache carries besides the UVs
    not_carried: list = field(default_factory=list)  # (attribute name, why not)
    grain_angles: np.ndarray | None = None  # (m,) radians: the GRAIN_ATTRIBUTE of each triangle's polygon
    grain_problem: str | None = None        # why GRAIN_ATTRIBUTE cannot be read (wrong domain or type)
    # the modifiers above "Tear Cloth" that made this mesh with other elements than the user's
    # (Subdivision, Array...): kept and polygons then number theirs, not the user's (inputs.py)
    renumbered_by: list = field(default_factory=list)


def read_mesh(mesh, *, uv: bool = True, vertex_groups=None, group_names=(), attributes: bool = False) -> MeshArrays:
    """Triangulate ``mesh`` (a bpy Mesh, original or evaluated) into arrays without changing it.

    ``vertex_groups``: the object's ``vertex_groups`` (names -> indices) when ``group_names``
    are asked for; a name missing there raises KeyError naming it. ``attributes``: also read
    the mesh's attributes the cache can carry (``read_attributes``).
    """
    n = len(mesh.vertices)
    co = np.empty(3 * n, dtype=np.float64)
    mesh.vertices.foreach_get("co", co)
    co = co.reshape(n, 3)

    tris = mesh.loop_triangles  # Blender's own triangulation, computed on demand, same winding
    m = len(tris)
    tri_verts = np.empty(3 * m, dtype=np.int32)
    tris.foreach_get("vertices", tri_verts)
    tri_verts = tri_verts.reshape(m, 3)
    tri_polygons = np.empty(m, dtype=np.int32)
    tris.foreach_get("polygon_index", tri_polygons)

    sizes = np.empty(len(mesh.polygons), dtype=np.int32)
    mesh.polygons.foreach_get("loop_total", sizes)
    ngons = int(np.count_nonzero(sizes > 4))

    corner_uv = None
    layer = mesh.uv_layers.active if uv else None
    if layer is not None and m:
        tri_loops = np.empty(3 * m, dtype=np.int32)
        tris.foreach_get("loops", tri_loops)
        loop_uv = np.empty(2 * len(mesh.loops), dtype=np.float64)
        layer.data.foreach_get("uv", loop_uv)
        corner_uv = loop_uv.reshape(-1, 2)[tri_loops].reshape(m, 3, 2)
    uv_name = layer.name if corner_uv is not None else None
    other_uv = [u.name for u in mesh.uv_layers if u.name != uv_name] if uv else []

    groups = {}
    if group_names:
        index_of = {}
        for name in group_names:
            vg = vertex_groups.get(name) if vertex_groups is not None else None
            if vg is None:
                raise KeyError(name)
            index_of[vg.index] = name
            groups[name] = np.zeros(n, dtype=np.float64)
        # One pass over the deform weights (there is no foreach access to vertex groups).
        for v in mesh.vertices:
            for g in v.groups:
                name = index_of.get(g.group)
                if name is not None:
                    groups[name][v.index] = g.weight

    grain_angles, grain_problem = _grain_angles(mesh, tri_polygons)

    used = np.zeros(n, dtype=bool)
    used[tri_verts.reshape(-1)] = True
    kept = np.flatnonzero(used).astype(np.int64)
    carried, not_carried = [], []
    if attributes and m:
        tri_loops = np.empty(3 * m, dtype=np.int32)
        tris.foreach_get("loops", tri_loops)
        carried, not_carried = read_attributes(mesh, tri_loops.reshape(m, 3), tri_polygons, kept, uv_name)
    loose = n - len(kept)
    if loose:
        remap = np.full(n, -1, dtype=np.int32)
        remap[kept] = np.arange(len(kept), dtype=np.int32)
        tri_verts = remap[tri_verts]
        co = co[kept]
        groups = {name: w[kept] for name, w in groups.items()}
    return MeshArrays(
        vertices=np.ascontiguousarray(co),
        triangles=np.ascontiguousarray(tri_verts, dtype=np.int32),
        corner_uv=corner_uv,
        groups=groups,
        kept=kept,
        ngons=ngons,
        loose=loose,
        polygons=tri_polygons,
        uv_name=uv_name,
        other_uv=other_uv,
        attributes=carried,
        not_carried=not_carried,
        grain_angles=grain_angles,
        grain_problem=grain_problem,
    )


def _grain_angles(mesh, tri_polygons):
    """(per-triangle grain angles or None, problem text or None) from the mesh's GRAIN_ATTRIBUTE."""
    attr = mesh.attributes.get(GRAIN_ATTRIBUTE)
    if attr is None:
        return None, None
    if attr.domain != "FACE" or attr.data_type != "FLOAT":
        return None, (f"the attribute {GRAIN_ATTRIBUTE!r} is {attr.data_type} on the {attr.domain} domain; the grain "
                      "override must be a Float attribute on the Face domain (the grain angle in radians)")
    per_face = np.empty(len(mesh.polygons), dtype=np.float64)
    attr.data.foreach_get("value", per_face)
    return per_face[tri_polygons], None


# Blender attribute type -> (foreach_get key, numpy dtype of the buffer)
_FOREACH = {"FLOAT": ("value", np.float32), "INT": ("value", np.int32), "INT8": ("value", np.int32),
            "BOOLEAN": ("value", bool), "FLOAT_VECTOR": ("vector", np.float32), "FLOAT2": ("vector", np.float32),
            "FLOAT_COLOR": ("color", np.float32), "BYTE_COLOR": ("color", np.float32)}
# Blender's own per-element data the cache writes or rebuilds itself: never carried, never reported
_BUILTIN = ("position", "sharp_face", "sharp_edge", ".")


def read_attributes(mesh, tri_loops, tri_polygons, kept, active_uv):
    """The mesh's attributes in solver order (``UserAttribute``s: POINT per kept vertex, CORNER per
    triangle corner, FACE per triangle), every UV map but the active one (the core carries that
    one as ``corner_uv``) among them, and ``(name, why)`` for each attribute the cache cannot carry.
    Colours are read linear, as Blender's USD reader writes them back."""
    carried, not_carried = [], []
    for attr in mesh.attributes:
        name, domain, data_type = attr.name, attr.domain, attr.data_type
        if name == active_uv or name.startswith(".") or name in _BUILTIN:
            continue
        if name in RESERVED:
            not_carried.append((name, "the cache writes an attribute of that name itself; rename yours"))
            continue
        why = unsupported(data_type, domain)
        if why is not None:
            not_carried.append((name, why))
            continue
        key, dtype = _FOREACH[data_type]
        k = USD_TYPES[data_type][1]
        buf = np.empty(len(attr.data) * k, dtype=dtype)
        attr.data.foreach_get(key, buf)
        values = buf.reshape(len(attr.data), k).astype(np.float64)
        if not np.isfinite(values).all():  # the cache refuses NaN: say so now, not mid-bake
            not_carried.append((name, "it holds NaN or infinite values"))
            continue
        if domain == "POINT":
            values = values[kept]
        elif domain == "CORNER":
            values = values[tri_loops]
        else:
            values = values[tri_polygons]
        carried.append(UserAttribute(name, domain, data_type, values))
    return carried, not_carried


def evaluated_mesh_arrays(obj, depsgraph, **kwargs) -> MeshArrays:
    """``read_mesh`` of the object as the depsgraph evaluated it (modifiers, armature)."""
    evaluated = obj.evaluated_get(depsgraph)
    mesh = evaluated.to_mesh()
    try:
        return read_mesh(mesh, **kwargs)
    finally:
        evaluated.to_mesh_clear()


def collider_world_si(obj, depsgraph, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """A collider at the depsgraph's current frame: (world vertices in metres, triangles)."""
    evaluated = obj.evaluated_get(depsgraph)
    arrays = evaluated_mesh_arrays(obj, depsgraph, uv=False)
    return local_to_world_si(arrays.vertices, matrix_array(evaluated.matrix_world), scale), arrays.triangles
