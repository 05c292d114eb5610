"""Generate the example scenes of Tear Cloth as .blend files, ready to bake and render headless.

    .venv42/bin/python example_blends/make_examples.py                   # all four, next to this file
    python example_blends/make_examples.py --python .venv42/bin/python   # the same, run by that Python
    python example_blends/make_examples.py --only banknote --out /tmp/blends
    python example_blends/make_examples.py --pictures out/examples       # bake + render

Which Blender saves them: the committed files are saved by the OLDEST supported Blender, bpy 4.2
LTS (``pip install "bpy>=4.2,<4.3"`` with Python 3.11, and this package, in a virtual environment):
Blender reads files of older versions, never of newer ones, and 5.0 changed the file header so that
4.2-4.5 cannot open what 5.x saves at all. Files saved by bpy 4.2.23 open, play and bake in 4.2.23,
5.0.1 and 5.3.0 (tests/test_examples.py on each). ``--python`` runs the generation in another
interpreter (one with that bpy and Tear Cloth installed); saving into this folder with bpy 5.0 or
newer prints a warning.

What each file holds (SI: one Blender unit is one metre, 24 fps, Z up, the front view looks
along +Y at sheets that face -Y):

* ``square_cloth.blend``: the paper's Fig. 1. The square cloth (``examples.square_cloth``, ~1.4K
  triangles, cotton with a tear stress of 2 MPa) hangs from two handles at its top corners; each
  follows an empty ("hand_left", "hand_right") that holds still for a few frames, then moves
  outward at 5 cm/s. The cloth tears from the top edge down between the hands within about a
  second. No collision, ~2 ms steps.
* ``banknote.blend``: a US-size banknote (``examples.banknote`` with a 4 mm notch in its top edge,
  "banknote" preset, snap tolerance 45 %) pinched at both ends by two hands (empties) that hold
  still for a quarter second, then pull apart in the note's plane at 2 cm/s each; the tear runs
  from the notch down within a few frames. Self-collision is its only collision, as in the paper
  (``BANKNOTE_SELF_COLLISION``; the two lips of a fresh tear count as neighbours). ~1 ms steps.
* ``tshirt.blend``: the mannequin (``examples.mannequin``) as a mesh skinned to an ARMATURE built
  from ``Body.bones`` (one vertex group per bone, an Armature modifier), keyframed every frame so
  Blender's skinning reproduces ``examples.bone_matrices(body, t)`` exactly: it walks in place for
  2 s, brings both hands to the front of the shirt hem (2-3 s) and pulls outward (3-4 s). The
  T-shirt (``examples.tshirt``) sits 12 mm outside the body at rest (checked here: no vertex inside
  the body, none closer than 1 cm). Its handles ``hem_left`` / ``hem_right`` follow two empties
  that hold the hem where it is until the hands arrive (frame 73, t = 3 s) and then move with the
  hands (the displacement of each hand since it arrived); the grip stays 12 mm off the body all
  along (the hips barely move in the walk). The body is the shirt's collider (3 mm contact
  distance, 1.5 mm displacement threshold: see ``SHIRT_CONTACT_DISTANCE``); no self-collision
  (the body keeps the front and back panels apart). ~1 ms steps. The grid repeats twice per panel.
* ``denim_knee.blend``: the front panel of a jeans leg (``examples.denim_knee``: a half cylinder
  12 mm outside the leg, ~1.6K triangles, the "denim" preset, warp along the leg in UV) over a
  leg of two capsules (``examples.capsule``: "Thigh", still, and "Shin", keyed to bend 100
  degrees at the knee from frame 6 to 48). The panel's top edge is pinned, its hem follows an
  empty parented to the shin, and the patch over the kneecap is worn (vertex group "knee" as a
  weak seam, factor ``DENIM_WORN``): the bend stretches the panel over the knee until it tears
  there. Both capsules are colliders (3 mm); no self-collision. ~2 ms steps. Frayed edges on
  (``tearcloth.blender.fray``: the node group is saved in the file).

Every file: a camera, a sun (for Eevee; Workbench uses studio light), Workbench render settings
that work headless (PyPI ``bpy``), "Standard" colour management, a dark world so holes in the
cloth read as background, and a colour-grid texture through the UVs. The texture is a GENERATED
image (Blender keeps only its parameters, no pixels), so nothing is packed; files are saved
compressed. Reproducible: the meshes come from the seeded generators of ``tearcloth.examples``
and every setting is written here (the bytes of a .blend still differ between saves).

``--pictures DIR`` bakes each example with ``tearcloth bake`` (``addon/cli.py``) in a
subprocess and renders a torn frame of each (``DIR/<name>.png``) and a strip of the square cloth
tearing (``DIR/square_cloth_strip.png``).
"""
from __future__ import annotations

import argparse
import math
import subprocess
import sys
import tempfile
from pathlib import Path

try:
    import numpy as np
except ImportError:  # only --python works then: the interpreter it names does the work
    np = None

HERE = Path(__file__).resolve().parent
FPS = 24

# Square cloth (Fig. 1)
SQUARE_TEAR_STRESS = 2.0e6  # Pa: cotton's preset is 8 MPa; 2 MPa tears under a pull of a few cm
SQUARE_HOLD = 5  # frames the hands hold still before pulling (the cloth settles under gravity)
SQUARE_SPEED = 0.05  # m/s per hand, outward along X
SQUARE_END = 48
SQUARE_STEPS = 21  # steps per frame: 1 / (24 x 21) = 2 ms

# Banknote
BANKNOTE_NOTCH = 0.004  # m: a small V notch in the middle of the top edge starts the tear
BANKNOTE_HOLD = 6
BANKNOTE_END = 36
BANKNOTE_PULL = 0.02  # m/s per hand, outward along X (paper tears after ~1 mm)
BANKNOTE_STEPS = 42  # ~1 ms
# Stiff paper tears in many short cuts; letting a tear snap to a vertex up to 45 % of an edge
# away (preset: 30 %) makes fewer tiny triangles at the tips, and without it the note blew up a
# few frames after the first tear (at 1 ms and at 0.5 ms steps); a tighter CG tolerance adds margin.
BANKNOTE_SNAP = 0.45
BANKNOTE_CG_TOLERANCE = 1e-4
# Self-collision is meant to be on here (the scene has no other collider), but with the current
# collision module the two lips of a fresh tear lie on top of each other, are no longer each
# other's topological neighbours, and are pushed apart as a deep contact: the sheet blows up
# within a few steps of the first tear (any sheet: the square cloth too). Switch this on once
# fresh tear lips are excluded from self-contacts; the file is otherwise ready for it.
BANKNOTE_SELF_COLLISION = True

# T-shirt
SHIRT_END = 97  # t = 4 s: walk (0-2 s), reach (2-3 s), pull (3-4 s)
SHIRT_GRAB = 3.0  # s: the hands are at the hem
SHIRT_TEAR_STRESS = 3.0e7  # Pa: above what the walk alone puts in the shirt, reached between the hands
SHIRT_STEPS = 42
# Contacts: the default 2 mm contact distance with a 5 mm displacement threshold let a few shirt
# vertices slip a few mm into the body (the neckline as the shirt settles on the shoulders, the
# sleeves as the arms swing): a cluster pair is only re-checked once it moved 5 mm, more than the
# contact distance. A threshold below the distance (1.5 < 3 mm) kept every vertex outside over
# the whole walk and reach.
SHIRT_UV_REPEAT = 2.0
SHIRT_CONTACT_DISTANCE = 0.003
SHIRT_DISPLACEMENT_THRESHOLD = 0.0015

# Denim knee
DENIM_HOLD = 6  # frames the leg stands still (the panel settles on it)
DENIM_END = 36
DENIM_BEND = 75.0  # degrees of knee flexion at DENIM_END (a deep squat is ~130)
DENIM_STEPS = 42  # ~1 ms
# Jeans tear at the knee because the denim there is worn thin: the "knee" patch tears at this
# fraction of denim's tear stress (the 100-degree bend stretches the panel ~15 % over the knee,
# short of what new denim takes).
DENIM_WORN = 0.5
DENIM_CONTACT_DISTANCE = 0.003
DENIM_SNAP = 0.45  # as the banknote's: fewer tiny triangles at the tips, which blew the sheet up


def _bpy():
    import bpy

    return bpy


# ------------------------------------------------------------------------------------------------
# Scene scaffolding


def new_scene(frame_end: int):
    """An empty file with Tear Cloth registered, metric units, 24 fps and headless render settings."""
    bpy = _bpy()
    import tearcloth

    bpy.ops.wm.read_factory_settings(use_empty=True)
    tearcloth.register()
    # keys made by keyframe_insert below interpolate linearly: constant hand speeds, no easing
    bpy.context.preferences.edit.keyframe_new_interpolation_type = "LINEAR"
    scene = bpy.context.scene
    scene.render.fps, scene.render.fps_base = FPS, 1.0
    scene.frame_start, scene.frame_end = 1, frame_end
    scene.unit_settings.system = "METRIC"
    scene.unit_settings.scale_length = 1.0
    scene.use_gravity = True
    scene.gravity = (0.0, 0.0, -9.81)
    render = scene.render
    render.engine = "BLENDER_WORKBENCH"
    render.resolution_x, render.resolution_y, render.resolution_percentage = 960, 720, 100
    render.image_settings.file_format = "PNG"
    render.image_settings.color_mode = "RGB"
    render.film_transparent = False
    shading = scene.display.shading
    shading.light = "STUDIO"
    shading.color_type = "TEXTURE"
    shading.show_shadows = True
    shading.show_cavity = False
    shading.show_object_outline = False
    scene.display.render_aa = "8"
    scene.view_settings.view_transform = "Standard"  # true colours: the grid and the background
    scene.view_settings.look = "None"
    world = bpy.data.worlds.new("Backdrop")
    world.color = (0.03, 0.035, 0.05)
    if world.node_tree is None:  # Blender < 5.0 makes the node tree on request
        world.use_nodes = True
    bg = world.node_tree.nodes.get("Background")
    if bg is not None:  # Eevee/Cycles read the node, Workbench reads world.color
        bg.inputs["Color"].default_value = (0.03, 0.035, 0.05, 1.0)
        bg.inputs["Strength"].default_value = 1.0
    scene.world = world
    return scene


def mesh_object(name: str, vertices, triangles, corner_uv=None, groups=None, smooth: bool = False):
    """A mesh object from triangle arrays: UVs per corner (Blender's loops), weights as vertex groups."""
    bpy = _bpy()
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(v.tolist(), [], t.tolist())
    if corner_uv is not None:
        layer = mesh.uv_layers.new(name="UVMap")
        # from_pydata keeps each face's corner order, so loop k of face f is corner k of triangle f
        layer.data.foreach_set("uv", np.asarray(corner_uv, dtype=np.float32).reshape(-1))
    if smooth:
        mesh.shade_smooth()
    mesh.update()
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    for group, weights in (groups or {}).items():
        add_vertex_group(obj, group, weights)
    return obj


def add_vertex_group(obj, name: str, weights) -> None:
    vg = obj.vertex_groups.new(name=name)
    w = np.asarray(weights, dtype=np.float64)
    # one call per distinct weight keeps this fast for the 11 x 3.8K skin weights
    nonzero = np.flatnonzero(w > 0.0)
    values, inverse = np.unique(np.round(w[nonzero], 6), return_inverse=True)
    for k, value in enumerate(values):
        vg.add(nonzero[inverse == k].tolist(), float(value), "REPLACE")


def grid_material(name: str):
    """A colour grid through the UVs: tears cut the grid, so they show in any render."""
    bpy = _bpy()
    image = bpy.data.images.new(name + " grid", 1024, 1024)
    image.generated_type = "COLOR_GRID"  # generated: saved as parameters, never as pixels
    mat = bpy.data.materials.new(name)
    if mat.node_tree is None:
        mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = image
    tex.location = (-400, 300)
    bsdf = nodes.get("Principled BSDF")
    links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    bsdf.inputs["Roughness"].default_value = 0.9
    nodes.active = tex  # what Workbench's Texture colour shows
    mat.use_backface_culling = False
    return mat


def plain_material(name: str, rgb):
    bpy = _bpy()
    mat = bpy.data.materials.new(name)
    mat.diffuse_color = (*rgb, 1.0)  # Workbench
    if mat.node_tree is None:
        mat.use_nodes = True
    bsdf = mat.node_tree.nodes.get("Principled BSDF")
    bsdf.inputs["Base Color"].default_value = (*rgb, 1.0)  # Eevee / Cycles
    bsdf.inputs["Roughness"].default_value = 0.6
    return mat


def look_at(obj, target) -> None:
    import mathutils

    direction = mathutils.Vector(target) - obj.location
    obj.rotation_euler = direction.to_track_quat("-Z", "Y").to_euler()


def camera(location, target, lens: float = 50.0):
    bpy = _bpy()
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    bpy.context.scene.collection.objects.link(cam)
    cam.location = location
    cam.data.lens = lens
    cam.data.clip_start = 0.01
    look_at(cam, target)
    bpy.context.scene.camera = cam
    return cam


def sun(direction_target=(0.0, 0.0, 0.0), location=(1.0, -2.0, 3.0)):
    bpy = _bpy()
    light = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    light.data.energy = 3.0
    bpy.context.scene.collection.objects.link(light)
    light.location = location
    look_at(light, direction_target)
    return light


def empty(name: str, location, size: float = 0.05, display: str = "SPHERE"):
    bpy = _bpy()
    e = bpy.data.objects.new(name, None)
    e.empty_display_type = display
    e.empty_display_size = size
    e.location = tuple(float(c) for c in location)
    bpy.context.scene.collection.objects.link(e)
    return e


def key_locations(obj, keys) -> None:
    """keys: [(frame, (x, y, z)), ...] in world metres (obj has no parent)."""
    for frame, location in keys:
        obj.location = tuple(float(c) for c in location)
        obj.keyframe_insert("location", frame=int(frame))


def hand_proxy(name: str, parent, size, rgb=(0.12, 0.12, 0.13), shape: str = "sphere"):
    """A small solid that rides on a hand empty so renders show where the cloth is held."""
    bpy = _bpy()
    if shape == "sphere":
        n_u, n_v = 16, 8
        verts, faces = [], []
        for j in range(1, n_v):
            th = math.pi * j / n_v
            for i in range(n_u):
                ph = 2 * math.pi * i / n_u
                verts.append((size * math.sin(th) * math.cos(ph), size * math.sin(th) * math.sin(ph),
                              size * math.cos(th)))
        top, bottom = len(verts), len(verts) + 1
        verts += [(0.0, 0.0, size), (0.0, 0.0, -size)]
        for j in range(n_v - 2):
            for i in range(n_u):
                a, b = j * n_u + i, j * n_u + (i + 1) % n_u
                faces.append((a, b, b + n_u, a + n_u))
        for i in range(n_u):
            faces.append((top, (i + 1) % n_u, i))
            last = (n_v - 2) * n_u
            faces.append((bottom, last + i, last + (i + 1) % n_u))
    else:  # a box of half sizes `size`
        sx, sy, sz = size
        verts = [(x * sx, y * sy, z * sz) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
        faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts, [], faces)
    if shape == "sphere":
        mesh.shade_smooth()
    mesh.materials.append(plain_material(name, rgb))
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    obj.parent = parent  # parent at the origin of the empty: rides along exactly
    return obj


def enable_tear_cloth(obj, preset: str, **settings):
    """Tear Cloth on ``obj`` through its operators (as a user would), then the given settings."""
    bpy = _bpy()
    with bpy.context.temp_override(object=obj, active_object=obj, selected_objects=[obj]):
        if bpy.ops.tearcloth.enable() != {"FINISHED"}:
            raise RuntimeError(f"could not enable Tear Cloth on {obj.name}")
        bpy.ops.tearcloth.material_preset(preset=preset)
    s = obj.tearcloth
    s.material_preset = preset
    for key, value in settings.items():
        setattr(s, key, value)
    return s


def add_handle(obj, group: str, follow) -> None:
    h = obj.tearcloth.handles.add()
    h.vertex_group = group
    h.follow = follow


def group_centroid(mesh, group: str) -> np.ndarray:
    return mesh.vertices[mesh.groups[group] >= 0.5].mean(axis=0)


def save(path: Path) -> Path:
    bpy = _bpy()
    path = Path(path).resolve()
    path.parent.mkdir(parents=True, exist_ok=True)
    # orphan data (the factory file's leftovers) would only make the file bigger
    bpy.data.orphans_purge(do_local_ids=True, do_linked_ids=True, do_recursive=True)
    bpy.context.preferences.filepaths.save_version = 0  # no .blend1 backup next to the examples
    bpy.ops.wm.save_as_mainfile(filepath=str(path), compress=True, relative_remap=True)
    return path


# ------------------------------------------------------------------------------------------------
# The three examples


def build_square_cloth():
    from tearcloth import examples

    bpy = _bpy()
    scene = new_scene(SQUARE_END)
    sheet = examples.square_cloth()
    cloth = mesh_object("SquareCloth", sheet.vertices, sheet.triangles, sheet.loop_uv(), sheet.groups)
    cloth.data.materials.append(grid_material("Cloth"))
    settings = enable_tear_cloth(cloth, "cotton", tear_stress=SQUARE_TEAR_STRESS, steps_per_frame=SQUARE_STEPS,
                                 use_collision=False, frame_start=1, frame_end=SQUARE_END)
    pull = SQUARE_SPEED * (SQUARE_END - SQUARE_HOLD) / FPS
    for side, group, sign in (("left", "handle_left", -1.0), ("right", "handle_right", 1.0)):
        at = group_centroid(sheet, group)
        hand = empty(f"hand_{side}", at, 0.04)
        key_locations(hand, [(1, at), (SQUARE_HOLD, at), (SQUARE_END, at + (sign * pull, 0.0, 0.0))])
        hand_proxy(f"hand_{side}_proxy", hand, 0.018)
        add_handle(cloth, group, hand)
    settings.active_handle_index = 0
    camera((0.0, -1.55, 1.0), (0.0, 0.0, 1.0), lens=50.0)
    sun((0.0, 0.0, 1.0))
    scene.frame_set(1)
    return scene


def build_banknote():
    from tearcloth import examples

    scene = new_scene(BANKNOTE_END)
    note = examples.banknote(notch=BANKNOTE_NOTCH)
    paper = mesh_object("Banknote", note.vertices, note.triangles, note.loop_uv(), note.groups)
    paper.data.materials.append(grid_material("Paper"))
    enable_tear_cloth(paper, "banknote", steps_per_frame=BANKNOTE_STEPS, use_collision=True,
                      use_self_collision=BANKNOTE_SELF_COLLISION, snap_tolerance=BANKNOTE_SNAP,
                      cg_tolerance=BANKNOTE_CG_TOLERANCE, frame_start=1, frame_end=BANKNOTE_END)
    seconds = (BANKNOTE_END - BANKNOTE_HOLD) / FPS
    z_lo, z_hi = note.vertices[:, 2].min(), note.vertices[:, 2].max()
    grip = 0.025
    for side, group, sign in (("left", "handle_left", -1.0), ("right", "handle_right", 1.0)):
        at = group_centroid(note, group)
        hand = empty(f"hand_{side}", at, 0.015, display="CUBE")
        # straight outward, in the note's plane: a twist out of the plane (tearing by hand) makes
        # the linearised FEM of this stiff paper blow up at the first tear, even at 0.4 ms steps
        move = np.array([sign * BANKNOTE_PULL, 0.0, 0.0]) * seconds
        key_locations(hand, [(1, at), (BANKNOTE_HOLD, at), (BANKNOTE_END, at + move)])
        # "fingers": a thin box over the pinched strip, on both faces of the note
        hand_proxy(f"hand_{side}_proxy", hand, (grip / 2 + 0.001, 0.004, (z_hi - z_lo) / 2 + 0.003),
                   shape="box")
        add_handle(paper, group, hand)
    camera((0.0, -0.42, 1.04), (0.0, 0.0, 0.995), lens=50.0)
    sun((0.0, 0.0, 1.0))
    scene.frame_set(1)
    return scene


def build_body_rig(body, frames, name: str = "Mannequin"):
    """The body as a skinned mesh: an armature from ``Body.bones``, one vertex group per bone
    from the skin weights, an Armature modifier; pose keys on every frame reproduce
    ``examples.bone_matrices`` (checked by the caller)."""
    from tearcloth import examples

    bpy = _bpy()
    import mathutils

    obj = mesh_object(name, body.vertices, body.triangles, smooth=True)
    obj.data.materials.append(plain_material("Skin", (0.78, 0.74, 0.70)))
    arm_data = bpy.data.armatures.new(name + "Rig")
    rig = bpy.data.objects.new(name + "Rig", arm_data)
    bpy.context.scene.collection.objects.link(rig)
    bpy.context.view_layer.objects.active = rig
    bpy.ops.object.mode_set(mode="EDIT")
    made = []
    for bone_name, head, tail, parent in body.bones:
        eb = arm_data.edit_bones.new(bone_name)
        eb.head = tuple(float(c) for c in head)
        eb.tail = tuple(float(c) for c in tail)
        eb.roll = 0.0
        eb.use_connect = False
        if parent >= 0:
            eb.parent = made[parent]
        made.append(eb)
    bpy.ops.object.mode_set(mode="OBJECT")
    for j, (bone_name, *_rest) in enumerate(body.bones):
        add_vertex_group(obj, bone_name, body.weights[:, j])
    md = obj.modifiers.new("Armature", "ARMATURE")
    md.object = rig
    md.use_vertex_groups = True
    md.use_bone_envelopes = False
    md.use_deform_preserve_volume = False  # plain linear blend skinning, as body_pose
    obj.parent = None
    # Blender poses a bone by its basis B (in the bone's rest frame): its armature-space pose is
    # P = P_parent . (Rest_parent^-1 . Rest) . B and it deforms by P . Rest^-1. For that to be the
    # world transform M of bone_matrices (a rotation R about the bone's head composed on the
    # parent's M), B = Rest^-1 . M_parent^-1 . M . Rest, which is the pure rotation
    # Rr^T . R . Rr (Rr = the rest rotation; the translations cancel because R turns about the head).
    rest = {b.name: np.array(b.matrix_local)[:3, :3] for b in arm_data.bones}
    previous = {}
    for frame in frames:
        mats = examples.bone_matrices(body, (frame - 1) / FPS)
        for j, (bone_name, _head, _tail, parent) in enumerate(body.bones):
            local = mats[j] if parent < 0 else np.linalg.inv(mats[parent]) @ mats[j]
            rr = rest[bone_name]
            q = mathutils.Matrix((rr.T @ local[:3, :3] @ rr).tolist()).to_quaternion()
            last = previous.get(bone_name)
            if last is not None and last.dot(q) < 0.0:
                q.negate()  # the short way round, so in-between frames (motion blur) interpolate well
            previous[bone_name] = q
            pb = rig.pose.bones[bone_name]
            pb.rotation_mode = "QUATERNION"
            pb.rotation_quaternion = q
            pb.keyframe_insert("rotation_quaternion", frame=frame)
    return obj, rig


def evaluated_vertices(obj) -> np.ndarray:
    bpy = _bpy()
    dg = bpy.context.evaluated_depsgraph_get()
    ev = obj.evaluated_get(dg)
    mesh = ev.to_mesh()
    co = np.empty(3 * len(mesh.vertices), dtype=np.float32)
    mesh.vertices.foreach_get("co", co)
    ev.to_mesh_clear()
    m = np.array(obj.matrix_world)
    co = co.reshape(-1, 3).astype(np.float64)
    return co @ m[:3, :3].T + m[:3, 3]


def hand_position(body, t: float, side: str) -> np.ndarray:
    """Where a hand is at time t: the tail of its forearm bone, posed."""
    from tearcloth import examples

    j = body.bone_index(f"forearm.{side}")
    m = examples.bone_matrices(body, t)[j]
    return (m @ np.r_[np.asarray(body.bones[j][2], dtype=np.float64), 1.0])[:3]


def build_tshirt(check: bool = True):
    from tearcloth import examples

    bpy = _bpy()
    scene = new_scene(SHIRT_END)
    body = examples.mannequin()
    shirt = examples.tshirt(body)
    if check:
        _, distance, _ = examples.closest_points(body.vertices, body.triangles, shirt.vertices)
        if distance.min() < 0.01:
            raise RuntimeError(f"the T-shirt does not fit: a vertex is {distance.min() * 1e3:.1f} mm from the body "
                               "(negative: inside)")
    frames = list(range(1, SHIRT_END + 1))
    mannequin, _rig = build_body_rig(body, frames)
    # the grid repeated twice per panel: cells of ~6 cm, so a tear shows against them
    cloth = mesh_object("TShirt", shirt.vertices, shirt.triangles, SHIRT_UV_REPEAT * shirt.loop_uv(), shirt.groups,
                        smooth=True)
    cloth.data.materials.append(grid_material("Shirt"))
    settings = enable_tear_cloth(cloth, "cotton", tear_stress=SHIRT_TEAR_STRESS, steps_per_frame=SHIRT_STEPS,
                                 use_collision=True, use_self_collision=False,
                                 collision_thickness=SHIRT_CONTACT_DISTANCE,
                                 displacement_threshold=SHIRT_DISPLACEMENT_THRESHOLD, frame_start=1, frame_end=SHIRT_END)
    item = settings.colliders.add()
    item.object = mannequin
    grab_frame = int(round(SHIRT_GRAB * FPS)) + 1
    for side, tag, group in (("left", "L", "hem_left"), ("right", "R", "hem_right")):
        at = group_centroid(shirt, group)
        hand = empty(f"hand_{side}", at, 0.03)
        arrived = hand_position(body, SHIRT_GRAB, tag)
        keys = [(1, at), (grab_frame, at)]
        for frame in range(grab_frame + 1, SHIRT_END + 1):
            keys.append((frame, at + hand_position(body, (frame - 1) / FPS, tag) - arrived))
        key_locations(hand, keys)
        add_handle(cloth, group, hand)
    if check:
        # Blender's skinning of the rig must be the body of examples.body_pose, frame for frame
        worst = 0.0
        for frame in (1, 13, 37, 61, 73, 97):
            scene.frame_set(frame)
            posed = evaluated_vertices(mannequin)
            worst = max(worst, float(np.abs(posed - examples.body_pose(body, (frame - 1) / FPS)).max()))
        if worst > 1e-4:
            raise RuntimeError(f"the rig does not reproduce examples.body_pose: {worst * 1e3:.3f} mm off")
    camera((0.55, -1.75, 1.2), (0.0, 0.0, 1.08), lens=50.0)
    sun((0.0, 0.0, 1.0), location=(2.0, -3.0, 4.0))
    scene.frame_set(1)
    return scene


def build_denim_knee():
    from tearcloth import examples
    from tearcloth.blender import fray

    bpy = _bpy()
    scene = new_scene(DENIM_END)
    leg = examples.LEG
    knee = np.array([0.0, 0.0, leg["knee"]])
    v, t = examples.capsule((0.0, 0.0, leg["knee"]), (0.0, 0.0, leg["hip"]), leg["radius"])
    thigh = mesh_object("Thigh", v, t, smooth=True)
    thigh.data.materials.append(plain_material("Skin", (0.78, 0.74, 0.70)))
    v, t = examples.capsule((0.0, 0.0, leg["ankle"]), (0.0, 0.0, leg["knee"]), leg["radius"])
    shin = mesh_object("Shin", v - knee, t, smooth=True)  # its origin at the knee: it turns there
    shin.data.materials.append(thigh.data.materials[0])
    shin.location = tuple(knee)
    shin.rotation_mode = "XYZ"
    for frame, degrees in ((1, 0.0), (DENIM_HOLD, 0.0), (DENIM_END, DENIM_BEND)):
        shin.rotation_euler = (math.radians(degrees), 0.0, 0.0)  # +X: the foot goes back (+Y)
        shin.keyframe_insert("rotation_euler", frame=frame)
    panel = examples.denim_knee()
    cloth = mesh_object("DenimKnee", panel.vertices, panel.triangles, panel.loop_uv(), panel.groups,
                        smooth=True)
    cloth.data.materials.append(grid_material("Denim"))
    settings = enable_tear_cloth(cloth, "denim", steps_per_frame=DENIM_STEPS, use_collision=True,
                                 use_self_collision=False, collision_thickness=DENIM_CONTACT_DISTANCE,
                                 pin_group="pin_top", seam_group="knee", seam_factor=DENIM_WORN,
                                 snap_tolerance=DENIM_SNAP,
                                 frame_start=1, frame_end=DENIM_END)
    for body in (thigh, shin):
        settings.colliders.add().object = body
    hold = empty("hem_hold", group_centroid(panel, "hem") - knee, 0.02, display="CUBE")
    hold.parent = shin  # the parent's origin is the knee: the empty rides on the shin exactly
    add_handle(cloth, "hem", hold)
    with bpy.context.temp_override(object=cloth, active_object=cloth, selected_objects=[cloth]):
        if bpy.ops.tearcloth.add_frayed_edges() != {"FINISHED"}:
            raise RuntimeError("could not add frayed edges to the denim")
    md = fray.find_modifier(cloth)
    fray.set_input(md, "Material", plain_material("Threads", (0.86, 0.84, 0.78)))
    camera((0.5, -0.62, 0.68), (0.02, 0.08, 0.56), lens=50.0)
    sun((0.0, 0.0, 0.55), location=(1.5, -2.5, 3.0))
    scene.frame_set(1)
    return scene


EXAMPLES = {
    "square_cloth": build_square_cloth,
    "banknote": build_banknote,
    "tshirt": build_tshirt,
    "denim_knee": build_denim_knee,
}


def generate(names, out: Path) -> list[Path]:
    bpy = _bpy()
    written = []
    if bpy.app.version >= (5, 0, 0) and Path(out).resolve() == HERE:
        print(f"make_examples: warning: Blender {bpy.app.version_string} saves files that Blender 4.2-4.5 cannot "
              "open; the committed examples are saved by bpy 4.2 (--python PATH-TO-A-PYTHON-WITH-bpy-4.2)",
              file=sys.stderr, flush=True)
    for name in names:
        EXAMPLES[name]()
        path = save(out / f"{name}.blend")
        print(f"wrote {path} ({path.stat().st_size / 1024:.0f} KiB, Blender {bpy.app.version_string})", flush=True)
        written.append(path)
    return written


# ------------------------------------------------------------------------------------------------
# Pictures for the README: bake with `tearcloth bake`, then render


TORN_FRAME = {"square_cloth": SQUARE_END, "banknote": BANKNOTE_END, "tshirt": SHIRT_END, "denim_knee": DENIM_END}
STRIP_FRAMES = (1, 12, 22, 32, 40, 48)


def _bake(blend: Path, out: Path) -> Path:
    cmd = [sys.executable, "-m", "tearcloth.cli", "bake", str(blend), "--out", str(out)]
    subprocess.run(cmd, check=True)
    return out / blend.name


def _render_frames(blend: Path, frames, pattern: str, percent: int = 100) -> None:
    """Render frames of a baked .blend in a fresh process with STOCK Blender (the add-on is never
    imported there: the baked cache plays back on its own)."""
    code = (
        "import sys, bpy\n"
        "blend, pattern, percent = sys.argv[1], sys.argv[2], int(sys.argv[3])\n"
        "frames = [int(f) for f in sys.argv[4:]]\n"
        "bpy.ops.wm.open_mainfile(filepath=blend)\n"
        "scene = bpy.context.scene\n"
        "scene.render.resolution_percentage = percent\n"
        "for f in frames:\n"
        "    scene.frame_set(f)\n"
        "    scene.render.filepath = pattern.replace('{frame}', str(f))\n"
        "    bpy.ops.render.render(write_still=True)\n"
    )
    subprocess.run([sys.executable, "-c", code, str(blend), pattern, str(percent), *map(str, frames)], check=True,
                   stdout=subprocess.DEVNULL)


def _strip(paths, out: Path, label_frames) -> None:
    """Frames side by side with a thin gap, each labelled with its frame number."""
    from PIL import Image, ImageDraw

    images = [Image.open(p).convert("RGB") for p in paths]
    w, h = images[0].size
    gap = 6
    strip = Image.new("RGB", (len(images) * w + (len(images) - 1) * gap, h), (255, 255, 255))
    for i, (im, frame) in enumerate(zip(images, label_frames)):
        draw = ImageDraw.Draw(im)
        draw.text((10, 8), f"frame {frame}  ({(frame - 1) / FPS:.2f} s)", fill=(235, 235, 235))
        strip.paste(im, (i * (w + gap), 0))
    strip.save(out)


def pictures(out_dir: Path, names) -> None:
    out_dir = Path(out_dir).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="tearcloth-pictures-") as tmp:
        tmp = Path(tmp)
        for name in names:
            source = HERE / f"{name}.blend"
            if not source.exists():
                generate([name], HERE)
            baked = _bake(source, tmp / name)
            _render_frames(baked, [TORN_FRAME[name]], str(out_dir / f"{name}.png"))
            print(f"wrote {out_dir / (name + '.png')}", flush=True)
            if name == "square_cloth":
                pattern = str(tmp / "strip_{frame}.png")
                _render_frames(baked, STRIP_FRAMES, pattern, percent=50)
                _strip([pattern.replace("{frame}", str(f)) for f in STRIP_FRAMES], out_dir / "square_cloth_strip.png",
                       STRIP_FRAMES)
                print(f"wrote {out_dir / 'square_cloth_strip.png'}", flush=True)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--only", default=",".join(EXAMPLES), help="comma-separated: " + ", ".join(EXAMPLES))
    p.add_argument("--out", default=str(HERE), help="folder for the .blend files (default: this folder)")
    p.add_argument("--pictures", metavar="DIR", help="instead: bake the examples and render pictures into DIR")
    p.add_argument("--python", metavar="PY", help="run all of this in the Python interpreter PY (with the bpy to "
                   "save with, e.g. a bpy 4.2 environment's bin/python, and Tear Cloth installed)")
    args = p.parse_args(argv)
    if args.python:
        # the same arguments, minus --python, in the other interpreter (its bpy saves the files)
        rest = list(sys.argv[1:] if argv is None else argv)
        i = next(k for k, a in enumerate(rest) if a == "--python" or a.startswith("--python="))
        del rest[i:i + (1 if "=" in rest[i] else 2)]
        return subprocess.run([args.python, str(Path(__file__).resolve()), *rest]).returncode
    names = [n.strip() for n in args.only.split(",") if n.strip()]
    unknown = [n for n in names if n not in EXAMPLES]
    if unknown:
        p.error(f"unknown example(s) {', '.join(unknown)}; examples: {', '.join(EXAMPLES)}")
    if args.pictures:
        pictures(Path(args.pictures), names)
    else:
        generate(names, Path(args.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
