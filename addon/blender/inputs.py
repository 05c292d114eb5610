"""What a Tear Cloth job reads from Blender: the checks and the gathering that turn an object and
its scene into a ``BakePlan`` (once, at the start) and into ``FrameInputs`` (every frame), on the
main thread. The bake (``bake.py``) and the live haptic session (``haptic_session.py``) both start
here, so a live session tears the same cloth a bake would and both report the same problems.

What this file owns: ``Sources`` (the names of the data read every frame, never bpy pointers),
``require_mesh`` and ``build_plan`` (validation: every problem goes into a ``Reports``), the cache-location checks,
and ``gather_inputs`` (move the scene to a frame and copy out what the job needs).
"""
from __future__ import annotations

import contextlib
import difflib
import logging
import os
import re
import tempfile
from dataclasses import dataclass, field

import bpy
import numpy as np

from .. import cache, spaces
from ..bake import BakePlan, FrameInputs, frame_span
from ..cloth import PIN_HARD_WEIGHT, Cloth
from . import convert, modifier
from .props import COLLIDER_TYPES
from .report import BakeError, Reports, not_a_mesh, object_kind

log = logging.getLogger("tearcloth")

# The scene's custom property in which `tearcloth bake --out` notes the file it copied (headless.py):
# the bakes of the copy record it as their source, so another input copied to the same output
# never resumes this one's partial bake
SOURCE_PROPERTY = "tearcloth_source"


@dataclass
class Sources:
    """Names of the Blender data a bake reads every frame (names, never bpy pointers)."""

    object_name: str
    follow_names: list = field(default_factory=list)   # per handle: object name or None
    collider_names: list = field(default_factory=list)
    # the pins follow the stack above Tear Cloth (an Armature, animated shape keys): the evaluated
    # vertices of that stack that are the rest mesh's (MeshArrays.kept), read every frame; None:
    # nothing above can deform the pinned vertices, they follow the object's transform
    pin_kept: np.ndarray | None = None
    pin_rest_count: int = 0  # that stack's vertex count at rest (loose vertices included)
    # the first frame where that stack had another vertex count: (frame, its count), or None
    pin_fallback: tuple | None = None


# ---------------------------------------------------------------------------------------------
# Validation: Blender scene -> BakePlan


def _group_hint(name: str, groups) -> str:
    """What to pick instead of a missing vertex group: the settings keep the group's name as text,
    so a group renamed in the Object Data panel leaves them pointing at a name that is gone. The
    message names the likely rename (closest name) and every group the object has."""
    if not groups:
        return "; the object has no vertex groups"
    # A rename usually keeps the old name inside the new one ('pins' -> 'Pins.001', 'hand' ->
    # 'hand_left'), which difflib's ratio alone scores low; otherwise the closest spelling.
    low = name.lower()
    close = [g for g in groups if len(low) >= 3 and (low in g.lower() or g.lower() in low)]
    close = close or [g for g in groups
                      if g.lower() in difflib.get_close_matches(low, [h.lower() for h in groups], n=1, cutoff=0.6)]
    listed = ", ".join(repr(g) for g in groups[:12]) + (", ..." if len(groups) > 12 else "")
    return (f"; did you mean {close[0]!r}?" if close else "") + f" (its vertex groups: {listed})"


def _collider_objects(obj, settings, reports: Reports) -> list:
    found = []
    for i, item in enumerate(settings.colliders):
        if item.object is None:
            reports.warning(f"{obj.name}: collider slot {i + 1} is empty (its object was deleted?); skipped")
        else:
            found.append(item.object)
    if settings.collider_collection is not None:
        found += list(settings.collider_collection.all_objects)
    colliders, seen = [], set()
    for other in found:
        if other.name in seen:
            continue
        seen.add(other.name)
        if other is obj:
            reports.warning(f"{obj.name}: the cloth is in its own collider list; self collision is a separate "
                            "setting. Skipped")
        elif other.type not in COLLIDER_TYPES:
            reports.warning(f"{obj.name}: collider {other.name!r} is {object_kind(other.type)} without a surface; skipped")
        else:
            colliders.append(other)
    return colliders


def _stack_above(obj) -> tuple[list, list]:
    """(the modifiers above "Tear Cloth" that make the rest mesh, the modifiers a one-off
    evaluation of that mesh switches off: the colour modifier a bake puts above Tear Cloth, which
    is playback's, then Tear Cloth and everything below it)."""
    md = modifier.find_modifier(obj)
    mods = list(obj.modifiers)
    index = mods.index(md)
    colours = [m for m in mods[:index] if m.name == modifier.COLOUR_MODIFIER and m.show_viewport]
    above = [m for m in mods[:index] if m.show_viewport and m not in colours]
    return above, colours + [m for m in mods[index:] if m.show_viewport]


@contextlib.contextmanager
def _switched_off(modifiers):
    """The modifiers switched off in the viewport for the block, and back on after it."""
    try:
        for m in modifiers:
            m.show_viewport = False
        yield
    finally:
        for m in modifiers:
            m.show_viewport = True


def _stack_can_deform(obj) -> bool:
    """Something above Tear Cloth may move the rest mesh's vertices over time: a modifier above it,
    or animated (or driven) shape keys."""
    keys = obj.data.shape_keys
    return bool(_stack_above(obj)[0]) or (keys is not None and keys.animation_data is not None)


def _deformed_rest(context, obj, sources: Sources, matrix, scale: float, frame: int) -> np.ndarray | None:
    """The rest mesh's vertices (world metres) as the stack above Tear Cloth deforms them at the
    depsgraph's frame, for the pins to follow (one more evaluation of the object, with Tear Cloth
    and what lies below it switched off); None, said once in the log, at a frame where that stack
    has another vertex count than at rest (a Remesh or a Subdivision level animated above: its
    numbering is not the rest mesh's, so the pins follow only the object's transform there; the
    bake's end says so too, ``Sources.pin_fallback``)."""
    with _switched_off(_stack_above(obj)[1]):
        evaluated = obj.evaluated_get(context.evaluated_depsgraph_get())
        me = evaluated.to_mesh()
        try:
            count = len(me.vertices)
            co = np.empty(3 * count, np.float32)
            me.vertices.foreach_get("co", co)
        finally:
            evaluated.to_mesh_clear()
    kept = sources.pin_kept
    # any other count, not only fewer: more vertices number another mesh too, and reading the
    # rest mesh's numbers in it leads pins elsewhere (a Subdivision level: its smoothed corners,
    # 4.3 mm off in the test; a Remesh: unrelated vertices)
    # (pin_rest_count is set with pin_kept, whose numbers are below it)
    if count != sources.pin_rest_count:
        if sources.pin_fallback is None:
            sources.pin_fallback = (frame, count)
            log.warning("%s: at frame %d the stack above %r has %d vertices, the rest mesh's %d: "
                        "the pins follow only the object's transform there", sources.object_name, frame,
                        modifier.MODIFIER_NAME, count, sources.pin_rest_count)
        return None
    return spaces.local_to_world_si(co.reshape(-1, 3)[kept].astype(np.float64), matrix, scale)


def _input_mesh(context, obj, reports: Reports, group_names) -> convert.MeshArrays | None:
    """The cloth's rest mesh: the object's mesh as evaluated by the modifiers ABOVE "Tear Cloth"
    (like Blender's Cloth modifier). Those below, and Tear Cloth itself, are switched off for the
    one evaluation and switched back on."""
    editing = obj.mode == "EDIT"
    if editing:
        obj.update_from_editmode()  # the edit-mode mesh, as the user sees it, is the rest mesh
    above, switched = _stack_above(obj)
    for m in above:
        # a Mesh Sequence Cache above that plays a Tear Cloth bake (the renamed modifier of an
        # earlier bake, or a copy of it) would make a baked frame the rest mesh, and the bake would
        # then feed on its own output
        played = modifier.bake_played_by(m)
        if played is not None:
            reports.error(f"{obj.name}: the modifier {m.name!r} above {modifier.MODIFIER_NAME!r} plays a Tear Cloth "
                          f"bake ({played[0]}), which would become the rest mesh: remove it, or move it below "
                          f"{modifier.MODIFIER_NAME!r}")
            return None
    try:
        # Shape keys are evaluated like modifiers: their mix, not the basis, is the rest shape.
        # In Edit Mode the original mesh's corner data (UVs) reads as empty: take the evaluated
        # copy, which has all of it.
        if not above and obj.data.shape_keys is None and not editing:
            return convert.read_mesh(obj.data, vertex_groups=obj.vertex_groups, group_names=group_names,
                                     attributes=True)
        with _switched_off(switched):
            depsgraph = context.evaluated_depsgraph_get()
            arrays = convert.evaluated_mesh_arrays(obj, depsgraph, vertex_groups=obj.vertex_groups,
                                                   group_names=group_names, attributes=True)
        me = obj.data
        polygons = 0 if arrays.polygons is None or not len(arrays.polygons) else int(arrays.polygons.max()) + 1
        vertices = (0 if arrays.kept is None else len(arrays.kept)) + arrays.loose
        if above and (vertices != len(me.vertices) or polygons > len(me.polygons)):
            arrays.renumbered_by = [m.name for m in above]
        return arrays
    except KeyError as exc:
        reports.error(f"{obj.name}: vertex group {exc.args[0]!r} does not exist")
        return None


def require_mesh(obj, reports: Reports) -> None:
    """A job needs a mesh object: BakeError (with the reason in ``reports``) otherwise."""
    if obj is None:
        reports.error("no active object: select the mesh to tear")
        reports.raise_if_errors()
    if obj.type != "MESH":
        reports.error(not_a_mesh(obj))
        reports.raise_if_errors()


def build_plan(context, obj, frame_start=None, frame_end=None, resume=False,
               reports: Reports | None = None, *, hands: dict | None = None,
               with_cache: bool = True) -> tuple[BakePlan, Sources]:
    """Check everything a bake of ``obj`` needs and gather it. Every problem goes into
    ``reports`` (and the log); BakeError if any is an error. Changes nothing in the scene (when
    the cache folder is not created here: the bake makes it; the object gets its persistent id,
    ``modifier.claim_id``).

    For a live haptic session: ``hands`` maps each hand to the vertex group it grasps (checked
    like a handle's; the bake handles on the same groups are left to the hands, the others hold
    still) and the frame range is not checked; ``with_cache=False`` skips the cache location
    (nothing is recorded)."""
    reports = reports if reports is not None else Reports()
    require_mesh(obj, reports)
    if not modifier.is_enabled(obj):
        reports.error(f"Tear Cloth is not enabled on {obj.name!r} (Properties > Physics > Tear Cloth), "
                      f"or its {modifier.MODIFIER_NAME!r} modifier was removed or renamed")
        reports.raise_if_errors()
    scene = context.scene
    settings = obj.tearcloth
    scale = convert.scale_length(scene)
    start = settings.frame_start if frame_start is None else int(frame_start)
    end = settings.frame_end if frame_end is None else int(frame_end)
    if end <= start and hands is None:
        reports.error(f"{obj.name}: the bake's end frame ({end}) must come after its start frame ({start})")

    material = collision = None
    try:
        material = convert.material_from_settings(settings, scene)
    except ValueError as exc:
        reports.error(f"{obj.name}: {exc}")
    colliders = _collider_objects(obj, settings, reports) if settings.use_collision else []
    if settings.use_collision and (colliders or settings.use_self_collision):
        try:
            collision = convert.collision_from_settings(settings, scene)
        except ValueError as exc:
            reports.error(f"{obj.name}: {exc}")

    # vertex groups: every name must exist on the object (renamed or deleted ones are reported)
    wanted = []
    hand_groups = dict(hands or {})
    # In a live session a hand takes over the bake handle on its group; the other handles hold still.
    handles = [(i, h) for i, h in enumerate(settings.handles) if h.vertex_group not in hand_groups.values()
               or not h.vertex_group]
    roles = [("pins", settings.pin_group)] + [(f"handle {i + 1}", h.vertex_group) for i, h in handles]
    roles += [(f"the {hand} hand", group) for hand, group in hand_groups.items()]
    roles.append(("weak seams", settings.seam_group))
    for role, name in roles:
        if role.startswith("handle") and not name:
            reports.error(f"{obj.name}: {role} has no vertex group; choose one or remove the handle")
        elif role.startswith("the ") and not name:
            reports.error(f"{obj.name}: {role} grasps no vertex group; choose its Handle Group "
                          "(Physics > Tear Cloth > Haptics)")
        elif name and name not in obj.vertex_groups:
            reports.error(f"{obj.name}: vertex group {name!r} ({role}) does not exist (renamed or deleted?)"
                          f"{_group_hint(name, [g.name for g in obj.vertex_groups])}")
        elif name and name not in wanted:
            wanted.append(name)
    follow = []
    for i, h in handles:
        follow.append(h.follow.name if h.follow is not None else None)
        if hands is None and h.follow is None and h.vertex_group:
            # a follow object deleted since it was chosen leaves the pointer empty, and nothing else says so
            reports.warning(f"{obj.name}: handle {i + 1} ({h.vertex_group!r}) follows no object, so it holds its "
                            "vertices where they are; choose the object it follows (Tear Cloth > Handles)")
        if hands is not None and h.follow is not None:
            reports.warning(f"{obj.name}: handle {i + 1} follows {h.follow.name!r}, but the scene's time stands "
                            "still during a live session: the handle holds still")

    reports.raise_if_errors()

    mesh = _input_mesh(context, obj, reports, wanted)
    reports.raise_if_errors()
    if len(mesh.triangles) == 0:
        reports.error(f"{obj.name}: the mesh has no faces to simulate")
        reports.raise_if_errors()
    bad = np.flatnonzero(~np.isfinite(mesh.vertices).all(axis=1))
    if bad.size:
        # (a script's NaN or inf): said here, before it reached the rest shape as a "weight" of an
        # internal group, with numpy's matmul warning beside it
        first = int(mesh.kept[bad[0]])
        whose = f" (as numbered by {', '.join(mesh.renumbered_by)} above Tear Cloth)" if mesh.renumbered_by else ""
        reports.error(f"{obj.name}: vertex {first}{whose} has a non-finite position "
                      f"({', '.join(f'{v:g}' for v in mesh.vertices[bad[0]])})"
                      + (f", and {bad.size - 1} more" if bad.size > 1 else ""))
        reports.raise_if_errors()
    seam = _unsewn_seam_vertices(mesh.vertices, mesh.triangles)
    if seam:
        reports.warning(f"{obj.name}: {seam} vertices on open edges sit exactly where other open-edge vertices are "
                        "(a seam or a mirror half not merged): the cloth is separate pieces there and comes apart "
                        "without tearing; if it is a seam, Mesh > Clean Up > Merge by Distance (or the modifier's "
                        "Merge) sews it")
    fingerprint = cache.mesh_fingerprint(mesh.vertices * scale, mesh.triangles)

    # The cache location once the mesh is known (its fingerprint guards the object's identity).
    path = None
    if with_cache:
        try:
            modifier.claim_id(obj, fingerprint)  # the cache's identity (the one change a plan makes)
            path = modifier.cache_path(obj)
        except BakeError as exc:
            reports.error(f"{obj.name}: {exc}")
        if path is not None:
            _check_cache_location(obj, path, resume, reports)
    reports.raise_if_errors()
    if mesh.ngons:
        reports.warning(f"{obj.name}: {mesh.ngons} n-gon{'s' if mesh.ngons != 1 else ''} triangulated for the "
                        "solver (your mesh is unchanged); triangulate them yourself to choose the diagonals")
    uv_name = "st"
    if mesh.uv_name is not None:
        # the cache's UVs carry the user's UV map name, so materials that read it by name see them
        uv_name = _usd_name(obj, mesh.uv_name, "the UV map", reports)
    attributes = _carried_attributes(obj, mesh, uv_name, reports)
    grain_angles = _grain_angles(obj, mesh, reports)
    if mesh.loose:
        reports.warning(f"{obj.name}: {mesh.loose} loose {'vertices' if mesh.loose != 1 else 'vertex'} (in no face) "
                        "left out of the simulation and of the baked mesh (the played mesh has none of them)")

    pinned = 0
    if settings.pin_group:
        w = mesh.groups[settings.pin_group]
        pinned = int(np.count_nonzero(w > 0))  # weight 1 holds exactly, less pulls (Cloth.pin_weights)
        if pinned == 0:
            reports.warning(f"{obj.name}: pin group {settings.pin_group!r} has no vertex with a weight above 0; "
                            "nothing is pinned")
        soft = int(np.count_nonzero((w > 0) & (w < PIN_HARD_WEIGHT)))
        if soft and not float(settings.pin_stiffness) > 0:
            reports.warning(f"{obj.name}: Pin Stiffness is 0, so the {soft} vertices of pin group "
                            f"{settings.pin_group!r} with a weight below 1 are not pinned at all; only weight 1 holds")
    def grasps_nothing(group) -> str:
        # the group as read holds only the vertices in faces: one whose members are all loose was
        # said to have no weight 0.5 or more
        found = obj.vertex_groups.get(group) if mesh.loose else None
        if found is not None:
            index = found.index
            if any(g.group == index and g.weight >= 0.5 for v in obj.data.vertices for g in v.groups):
                return f"vertex group {group!r} holds only loose vertices (in no face), so it grasps nothing"
        return f"vertex group {group!r} has no vertex with weight 0.5 or more, so it grasps nothing"

    for i, h in handles:
        if not np.any(mesh.groups[h.vertex_group] >= 0.5):
            reports.error(f"{obj.name}: handle {i + 1}: {grasps_nothing(h.vertex_group)}")
        elif settings.pin_group:
            both = int(np.count_nonzero((mesh.groups[h.vertex_group] >= 0.5) & (mesh.groups[settings.pin_group] > 0)))
            if both:  # the handle's grasp wins in the solver: said, as it moves what the user pinned
                reports.warning(f"{obj.name}: {both} pinned {'vertices are' if both != 1 else 'vertex is'} also in "
                                f"handle {i + 1}'s group {h.vertex_group!r}: the handle moves "
                                f"{'them' if both != 1 else 'it'}, the pin does not hold")
    for hand, group in hand_groups.items():
        if not np.any(mesh.groups[group] >= 0.5):
            reports.error(f"{obj.name}: the {hand} hand's {grasps_nothing(group)}")
    depsgraph = context.evaluated_depsgraph_get()
    body_triangles = {}
    for other in colliders:
        triangles = convert.collider_world_si(other, depsgraph, scale)[1]
        if len(triangles):
            body_triangles[other.name] = triangles
        else:
            reports.warning(f"{obj.name}: collider {other.name!r} has no faces; skipped")
    if collision is not None and not body_triangles and not collision.self_collision:
        collision = None  # nothing left to collide with
    if not pinned and not handles and not hand_groups and not body_triangles:
        reports.warning(f"{obj.name}: no pins, handles or colliders: the cloth falls freely under gravity")
    reports.raise_if_errors()

    matrix = convert.matrix_array(obj.evaluated_get(depsgraph).matrix_world)
    plan = BakePlan(
        object_name=obj.name,
        prim_name=modifier.prim_name_for(obj.name),
        cache_path=path,
        fps=convert.fps(scene),
        frame_start=start,
        frame_end=end,
        steps_per_frame=int(settings.steps_per_frame),
        scale=scale,
        material=material,
        solver=convert.solver_from_settings(settings, scene),
        tearing=convert.tearing_from_settings(settings),
        collision=collision,
        vertices=spaces.local_to_world_si(mesh.vertices, matrix, scale),
        triangles=mesh.triangles,
        corner_uv=mesh.corner_uv,
        groups=mesh.groups,
        fingerprint=fingerprint,
        pin_group=settings.pin_group or None,
        pin_stiffness=float(settings.pin_stiffness),
        handle_groups=[h.vertex_group for _, h in handles],
        seam_group=settings.seam_group or None,
        seam_factor=float(settings.seam_factor),
        body_triangles=body_triangles,
        resume=bool(resume),
        hand_groups=hand_groups,
        uv_name=uv_name,
        object_id=modifier.object_id(obj),
        blend=bpy.data.filepath,
        # a copy that `tearcloth bake --out` made names the file it was copied from (headless.py);
        # only such copies record one: a .blend moved with its cache resumes its bakes
        source=str(context.scene.get(SOURCE_PROPERTY, "")),
        triangle_polygons=mesh.polygons,
        vertex_ids=mesh.kept,
        renumbered_by=tuple(mesh.renumbered_by),
        grain_angles=grain_angles,
        attributes=attributes,
    )
    sources = Sources(obj.name, follow, list(body_triangles))
    if pinned and hands is None and _stack_can_deform(obj):
        sources.pin_kept = np.arange(len(mesh.vertices)) if mesh.kept is None else np.array(mesh.kept)
        sources.pin_rest_count = len(mesh.vertices) + int(mesh.loose)
    return plan, sources


def _grain_angles(obj, mesh: convert.MeshArrays, reports: Reports):
    """The per-triangle grain override the plan carries (None: the material's own grain), with
    its problems in ``reports``: a wrong attribute or a value that is not a number is an error,
    a core without grain directions a warning (the override is then not used)."""
    name = convert.GRAIN_ATTRIBUTE
    if mesh.grain_problem is not None:
        reports.error(f"{obj.name}: {mesh.grain_problem}")
        return None
    angles = mesh.grain_angles
    if angles is None:
        return None
    bad = np.flatnonzero(~np.isfinite(angles))
    if bad.size:
        polygons = sorted({int(mesh.polygons[i]) for i in bad})
        shown = ", ".join(map(str, polygons[:10])) + (", ..." if len(polygons) > 10 else "")
        reports.error(f"{obj.name}: {name!r} is not a number on polygon{'s' if len(polygons) > 1 else ''} {shown}")
        return None
    if not hasattr(Cloth, "set_grain_angles"):
        reports.warning(f"{obj.name}: the mesh has a {name!r} attribute, but this build of Tear Cloth has no grain "
                        "directions; it is not used")
        return None
    return angles


def _usd_name(obj, name: str, what: str, reports: Reports) -> str:
    """``name`` as a USD identifier (letters, digits, _), warned about when it had to change."""
    usd = re.sub(r"[^A-Za-z0-9_]", "_", name)
    if not usd or usd[0].isdigit():
        usd = "_" + usd
    if usd != name:
        reports.warning(f"{obj.name}: {what} {name!r} is named {usd!r} in the cache (USD names allow letters, "
                        "digits and _ only); rename it to keep the name")
    return usd


def _carried_attributes(obj, mesh, uv_name: str, reports: Reports) -> list:
    """The attributes the cache carries, under USD names; each one it cannot carry is reported
    once, by name (the played mesh would show Blender's defaults for it once the topology changes)."""
    carried, taken = [], {uv_name}
    # Blender's USD reader makes the first colour primvar it meets the active and render colour:
    # the user's active colour goes first (the cache keeps this order, cache._order_primvars)
    active = obj.data.color_attributes.active_color_name
    for attr in sorted(mesh.attributes, key=lambda a: a.name != active):
        name = _usd_name(obj, attr.name, "the attribute", reports)
        if name in taken:
            reports.warning(f"{obj.name}: attribute {attr.name!r} is not carried into the cache: its USD name "
                            f"{name!r} is taken by another attribute")
            continue
        taken.add(name)
        attr.name = name
        carried.append(attr)
    for name, why in mesh.not_carried:
        reports.warning(f"{obj.name}: attribute {name!r} is not carried into the cache ({why})")
    return carried


def _unsewn_seam_vertices(vertices, triangles) -> int:
    """How many vertices on open edges (edges of one triangle) coincide with another such vertex:
    a garment's seam or a Mirror's middle left unmerged, which the solver takes as separate pieces.
    Coincident to 1e-6 of the mesh's size (split seams are exact copies)."""
    t = np.asarray(triangles, dtype=np.int64)
    v = np.asarray(vertices, dtype=np.float64)
    if not len(t):
        return 0
    e = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    edges, count = np.unique(e, axis=0, return_counts=True)
    rim = np.unique(edges[count == 1])
    if len(rim) < 2:
        return 0
    size = float(np.ptp(v, axis=0).max()) or 1.0
    cells = np.round(v[rim] / (1e-6 * size)).astype(np.int64)
    _, inverse, counts = np.unique(cells, axis=0, return_inverse=True, return_counts=True)
    return int(np.count_nonzero(counts[inverse.reshape(-1)] > 1))


def _check_cache_location(obj, path: str, resume: bool, reports: Reports) -> None:
    folder = os.path.dirname(path)
    if os.path.exists(folder) and not os.path.isdir(folder):
        reports.error(f"{obj.name}: the cache folder {folder} is a file, not a folder")
        return
    # A missing folder is made by the bake itself once every check passed (and removed again if
    # the attempt fails): here only its nearest existing ancestor must take new files.
    existing = folder
    while not os.path.exists(existing) and os.path.dirname(existing) != existing:
        existing = os.path.dirname(existing)
    if not os.path.isdir(existing):
        reports.error(f"{obj.name}: cannot create the cache folder {folder}: {existing} is a file, not a folder")
        return
    # A real write, not os.access: that says yes to root on a read-only mount.
    try:
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as exc:
        what = "is not writable" if existing == folder else f"cannot be created: {existing} is not writable"
        reports.error(f"{obj.name}: the cache folder {folder} {what} ({exc.strerror or exc}); "
                      "choose another folder")
        return
    # The frames folder of the bake already there takes the new frames as well (a re-bake moves
    # them in once complete, after the old root is gone; a resume writes into it): one it refuses
    # failed only at that last move, after the whole simulation, with the old root deleted.
    frames_dir = cache.frames_dir_for(path)
    if os.path.isdir(frames_dir):
        try:
            with tempfile.TemporaryFile(dir=frames_dir):
                pass
        except OSError as exc:
            reports.error(f"{obj.name}: the frames folder {frames_dir} of the bake there is not writable "
                          f"({exc.strerror or exc}); the bake was left as it is: make that folder writable or "
                          "choose another cache folder")
            return
    if cache.damaged_root(path):
        # a root cut short (a crash or a full disk while it was rewritten): its frame files are
        # intact, so it is rebuilt from them for this object (whose path it is) - unless another
        # object plays it: the damaged root cannot say whose bake it was (the id that keeps a
        # renamed object's bake from a newcomer of its name is in it), and the one that plays it
        # is its owner
        others = modifier.players(path, obj)
        if others:
            names = ", ".join(repr(o.name) for o in others)
            reports.error(f"{obj.name}: the cache root {path} is damaged (cut short) and belongs to {names}, which "
                          f"plays it: bake {names} again (or Free Bake it) first; nothing was changed")
            return
        try:
            frames = cache.repair_root(path, obj.name, owner={"object_id": modifier.object_id(obj),
                                                              "blend": bpy.data.filepath})
        except cache.CacheError as exc:
            reports.error(f"{obj.name}: the cache root {path} is damaged and cannot be rebuilt ({exc}); "
                          "Free Bake deletes it")
            return
        span = f"frames {frame_span(frames[0], frames[-1])}" if frames else "no frame"
        reports.warning(f"{obj.name}: the cache root {path} was damaged (cut short); rebuilt it from its intact "
                        f"frame files ({span})")
    if resume:
        staged = cache.interrupted_rebake(path)
        if staged is not None:
            # a re-bake killed midway (its frames beside the previous bake): resuming continues it
            try:
                cache.check_owner(staged["path"], obj.name, object_id=modifier.object_id(obj))
            except cache.CacheError as exc:
                reports.error(f"{obj.name}: cannot resume the interrupted re-bake: {exc}")
            return
        if not os.path.exists(path):
            attached = modifier.attached_path(obj)
            if attached is not None and os.path.exists(attached):
                # its bake is at another path: made under another name, or by another file (this one
                # saved as a copy, or the object appended from it), or into another cache folder
                recorded = cache.owner_of(attached) or {}
                blend = recorded.get("blend") or ""
                if blend and not modifier.same_file(blend, bpy.data.filepath or ""):
                    why = f"it was baked by {blend} (this file is a copy of it, or the object came from it)"
                elif recorded.get("object") and recorded["object"] != obj.name:
                    why = f"it was baked under the name {recorded['object']!r}"
                else:
                    why = "it was baked into another cache folder"
                reports.error(f"{obj.name}: the bake its modifier plays is at {attached}, not at {path}: {why}; "
                              "a bake is resumed only where it was made: bake again, or free the old bake")
            else:
                reports.error(f"{obj.name}: there is no bake to resume at {path}")
            return
        try:
            info = cache.check_owner(path, obj.name, object_id=modifier.object_id(obj))
        except cache.CacheError as exc:
            reports.error(f"{obj.name}: cannot resume: {exc}")
            return
        if info["frames"] and info["frames"][-1] >= obj.tearcloth.frame_end and info["complete"]:
            reports.error(f"{obj.name}: the bake is complete up to frame {info['frames'][-1]}; nothing to resume")
    elif os.path.lexists(path):
        try:
            cache.check_owner(path, obj.name, object_id=modifier.object_id(obj))
        except cache.CacheOwnerError as exc:
            reports.error(f"{obj.name}: {exc}. It was left untouched: free it from that object, or choose "
                          "another cache folder")
        except cache.CacheError as exc:
            # A Tear Cloth cache that lost frames is damaged, and a new bake replaces it; anything
            # else (not USD, not ours) is refused here and left as it is.
            if "frames missing" not in str(exc):
                reports.error(f"{obj.name}: {exc}. It was left untouched: move it away or choose another "
                              "cache folder")


# ---------------------------------------------------------------------------------------------
# Per-frame inputs (main thread)


def gather_inputs(context, sources: Sources, frame: int, scale: float) -> FrameInputs:
    """Move the scene to ``frame`` and copy out what the bake needs of it."""
    # Always frame_set, even on the current frame: animation is evaluated by a frame change, and
    # a value set by a script since the last one (a location under a keyframe) is not the frame's.
    context.scene.frame_set(frame)
    depsgraph = context.evaluated_depsgraph_get()
    objects = bpy.data.objects
    obj = objects.get(sources.object_name)
    if obj is None:
        raise BakeError(f"object {sources.object_name!r} was deleted or renamed during the bake")
    matrices = []
    for name in sources.follow_names:
        if name is None:
            matrices.append(None)
            continue
        follow = objects.get(name)
        if follow is None:
            raise BakeError(f"{sources.object_name}: the handle's follow object {name!r} was deleted or renamed")
        matrices.append(convert.matrix_array(follow.evaluated_get(depsgraph).matrix_world))
    bodies = {}
    for name in sources.collider_names:
        other = objects.get(name)
        if other is None:
            raise BakeError(f"{sources.object_name}: collider {name!r} was deleted or renamed during the bake")
        bodies[name] = convert.collider_world_si(other, depsgraph, scale)[0]
    matrix = convert.matrix_array(obj.evaluated_get(depsgraph).matrix_world)
    # the cache is written in the object's local space (matrix^-1): a flat transform has no inverse
    # (numpy's bare "Singular matrix" otherwise, naming neither the object, the axis nor the frame)
    linear = np.asarray(matrix, float)[:3, :3]
    lengths = np.linalg.norm(linear, axis=0)
    volume = float(np.prod(lengths))
    if not (volume > 0 and abs(np.linalg.det(linear)) > 1e-9 * volume):
        flat = [a for a, n in zip("XYZ", lengths) if not n > 1e-9 * lengths.max(initial=0.0)]
        what = f"its scale is zero on {', '.join(flat)}" if flat else "its transform is flat (sheared onto a plane)"
        raise BakeError(f"{sources.object_name}: {what} at frame {frame} (parents included); Tear Cloth writes "
                        "the cache in the object's own space, which then has no inverse: change or apply the scale")
    pin_source = None if sources.pin_kept is None else _deformed_rest(context, obj, sources, matrix, scale, frame)
    return FrameInputs(frame, matrix, matrices, bodies, pin_source=pin_source)
