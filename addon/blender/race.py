"""Blender's own cloth, driven through bpy for the race of ``tearcloth bench`` (``bench/race.py``).

Dev-only: ``tearcloth bench`` is its one user, and the build script leaves this file out of the
extension zip. It owns the bpy half of the race and nothing else: given plain arrays (the body,
its bones, skin weights and bone matrices per frame; the shirt, its groups; the hands' offsets
per frame) and the Blender property values ``bench.race.blender_cloth_settings`` derived from our
material, ``race_frames`` builds the scene headless and times Blender's cloth frame by frame.
numpy and bpy only: no other part of Tear Cloth is imported, so the mapping and our side of the
race stay testable without Blender.

The scene (after ``read_factory_settings(use_empty=True)``):
- body: a mesh with an ARMATURE rebuilt from the bones (head, tail, roll 0, parents) and the skin
  weights as one vertex group per bone, an Armature modifier (linear blend skinning, volume
  preservation off), then a Collision modifier. Every frame each pose bone gets a rotation
  keyframe chosen so that Blender's skinning reproduces the given bone matrices.
- shirt: two Hook modifiers (groups ``hem_left`` / ``hem_right``) to two empties keyed every
  frame with the hands' offsets; then the Cloth modifier, with the union of both groups as its
  pin group (weight 1 = hard pinned: the hem follows the hooks exactly, as our handles do).
- Blender's cloth computes on frame change: ``scene.frame_set(f)`` for f = 2 .. frames + 1 after
  ``frame_set(1)`` (the start frame, where the cloth is initialised). The point cache is freed
  before the run, so every timed frame is simulated, not replayed; afterwards the raced frames are
  set again to time a cache replay.

Frames are interleaved with the caller's own side: ``after_frame`` runs right after Blender's
frame f, so load from other processes on a shared machine hits both sides alike.
"""
from __future__ import annotations

import time

import bpy
import mathutils
import numpy as np

__all__ = ["race_frames"]


def _set_props(struct, values: dict) -> None:
    for k, v in values.items():
        setattr(struct, k, v)


def _add_group(obj, name: str, weights) -> None:
    vg = obj.vertex_groups.new(name=name)
    w = np.asarray(weights, dtype=np.float64)
    full = np.flatnonzero(w >= 1.0)
    if full.size:
        vg.add(full.tolist(), 1.0, "REPLACE")
    for i in np.flatnonzero((w > 0.0) & (w < 1.0)):
        vg.add([int(i)], float(w[i]), "REPLACE")


def _mesh_object(name, vertices, triangles):
    me = bpy.data.meshes.new(name)
    me.from_pydata(np.asarray(vertices).tolist(), [], np.asarray(triangles).tolist())
    me.update()
    ob = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def _evaluated_vertices(ob) -> np.ndarray:
    dg = bpy.context.evaluated_depsgraph_get()
    ev = ob.evaluated_get(dg)
    me = ev.to_mesh()
    co = np.empty(len(me.vertices) * 3, dtype=np.float32)
    me.vertices.foreach_get("co", co)
    ev.to_mesh_clear()
    return co.reshape(-1, 3).astype(np.float64)


class _Scene:
    """The race scene built through bpy, one ``frame_set`` per frame."""

    def __init__(self, body_vertices, body_triangles, bones, weights, bone_matrices, shirt_vertices,
                 shirt_triangles, shirt_groups, hand_offsets, settings, frames, fps):
        bpy.ops.wm.read_factory_settings(use_empty=True)
        scene = bpy.context.scene
        self.scene = scene
        scene.render.fps = int(fps)
        scene.render.fps_base = 1.0
        scene.frame_start, scene.frame_end = 1, frames + 1
        scene.use_gravity = True
        scene.gravity = settings["scene"]["gravity"]
        # ---- body: mesh + armature rebuilt from the bones + skin weights
        self.body_ob = ob = _mesh_object("mannequin", body_vertices, body_triangles)
        arm_data = bpy.data.armatures.new("mannequin_rig")
        self.arm = arm = bpy.data.objects.new("mannequin_rig", arm_data)
        scene.collection.objects.link(arm)
        bpy.context.view_layer.objects.active = arm
        bpy.ops.object.mode_set(mode="EDIT")
        edit = []
        for name, head, tail, parent in bones:
            eb = arm_data.edit_bones.new(name)
            eb.head, eb.tail, eb.roll = tuple(map(float, head)), tuple(map(float, tail)), 0.0
            eb.use_connect = False
            if parent >= 0:
                eb.parent = edit[parent]
            edit.append(eb)
        bpy.ops.object.mode_set(mode="OBJECT")
        for j, bone in enumerate(bones):
            _add_group(ob, bone[0], weights[:, j])
        mod = ob.modifiers.new("Armature", "ARMATURE")
        mod.object = arm
        mod.use_vertex_groups = True
        mod.use_bone_envelopes = False
        mod.use_deform_preserve_volume = False
        ob.modifiers.new("Collision", "COLLISION")
        _set_props(ob.collision, settings["body_collision"])
        rest = {b.name: np.array(b.matrix_local)[:3, :3] for b in arm_data.bones}
        for f in range(1, frames + 2):
            mats = bone_matrices[f - 1]
            for j, (name, _head, _tail, parent) in enumerate(bones):
                # pose basis = rest^-1 . (this bone's own rotation about its head) . rest
                local = mats[j] if parent < 0 else np.linalg.inv(mats[parent]) @ mats[j]
                Rr = rest[name]
                basis = Rr.T @ local[:3, :3] @ Rr
                pb = arm.pose.bones[name]
                pb.rotation_mode = "QUATERNION"
                pb.rotation_quaternion = mathutils.Matrix(basis.tolist()).to_quaternion()
                pb.keyframe_insert("rotation_quaternion", frame=f)
        # ---- hands: two empties, keyed every frame
        self.hands = []
        for side in ("left", "right"):
            e = bpy.data.objects.new(f"hand_{side}", None)
            scene.collection.objects.link(e)
            self.hands.append(e)
        for f in range(1, frames + 2):
            for e, off in zip(self.hands, hand_offsets[f - 1]):
                e.location = tuple(map(float, off))
                e.keyframe_insert("location", frame=f)
        # ---- shirt: hooks, then cloth with the hem pinned
        self.shirt_ob = sh = _mesh_object("tshirt", shirt_vertices, shirt_triangles)
        for name in ("hem_left", "hem_right"):
            _add_group(sh, name, shirt_groups[name])
        _add_group(sh, "pin", np.maximum(shirt_groups["hem_left"], shirt_groups["hem_right"]))
        for e, name in zip(self.hands, ("hem_left", "hem_right")):
            hk = sh.modifiers.new(f"hook_{name}", "HOOK")
            hk.object = e
            hk.vertex_group = name
            hk.falloff_type = "NONE"
            hk.strength = 1.0
        self.cloth_mod = cm = sh.modifiers.new("Cloth", "CLOTH")
        _set_props(cm.settings, dict(settings["cloth"]))
        _set_props(cm.collision_settings, settings["collision"])
        cm.point_cache.frame_start = 1
        cm.point_cache.frame_end = frames + 1
        self.iterations = []
        self.cpu_s = []

    def free_cache(self) -> None:
        """Drop whatever the point cache holds, so the next frames are simulated."""
        try:
            with bpy.context.temp_override(scene=self.scene, point_cache=self.cloth_mod.point_cache):
                bpy.ops.ptcache.free_bake()
        except (RuntimeError, TypeError, AttributeError):
            pass
        # a settings write resets the (unbaked) cache as well
        self.cloth_mod.settings.quality = self.cloth_mod.settings.quality
        if self.cloth_mod.point_cache.is_baked:
            raise RuntimeError("Blender's cloth point cache is baked; the race would only replay it")

    def frame(self, f: int) -> float:
        """Evaluate frame f (Blender simulates the cloth there). Wall seconds; CPU seconds of the
        process (all of Blender's threads) go to ``cpu_s``."""
        c0 = time.process_time()
        t0 = time.perf_counter()
        self.scene.frame_set(f)
        dt = time.perf_counter() - t0
        self.cpu_s.append(time.process_time() - c0)
        res = self._solver_result()
        if res is not None:
            self.iterations.append(res)
        return dt

    def _solver_result(self):
        dg = bpy.context.evaluated_depsgraph_get()
        mod = self.shirt_ob.evaluated_get(dg).modifiers.get("Cloth")
        sr = getattr(mod, "solver_result", None) if mod is not None else None
        if sr is None:
            return None
        return float(sr.avg_iterations), int(sr.max_iterations)


def race_frames(*, body_vertices, body_triangles, bones, weights, bone_matrices, shirt_vertices,
                shirt_triangles, shirt_groups, hand_offsets, settings, frames, fps, check_frames=(),
                after_frame=None, say=None) -> dict:
    """Build the race scene and time Blender's cloth over ``frames`` frames (2 .. frames + 1).

    Arrays, SI units: ``body_vertices`` (nb, 3) and ``body_triangles``; ``bones`` a list of
    (name, head (3,), tail (3,), parent index or -1), parents first; ``weights`` (nb, n_bones) skin
    weights; ``bone_matrices`` (frames + 1, n_bones, 4, 4) bind -> pose per bone at frames
    1 .. frames + 1; the shirt's ``shirt_vertices``, ``shirt_triangles`` and ``shirt_groups``
    (``hem_left``, ``hem_right`` weights); ``hand_offsets`` (frames + 1, 2, 3): the offsets of
    hem_left and hem_right at frames 1 .. frames + 1. ``settings``: the dict of
    ``bench.race.blender_cloth_settings`` (cloth, collision, body_collision, scene).

    ``check_frames``: frames at which the skinned body is read back before the race (the caller
    compares it with its own pose). ``after_frame(f, seconds)`` runs after Blender's frame f (with
    its wall seconds); returning False stops the race there (that frame counts as Blender's, not
    as raced).

    Returns ``frame_s`` and ``cpu_s`` (wall and process CPU seconds per simulated frame),
    ``iterations`` ((mean, max) CG iterations per frame where Blender reports them),
    ``frames_raced`` (frames for which ``after_frame`` did not stop), ``replay_s_per_frame``
    (setting the raced frames again, from the cache), ``shirt_rest`` / ``shirt_end`` (evaluated
    shirt vertices at the start frame and after the race), ``body_vertices`` ({frame: evaluated
    body vertices} for ``check_frames``) and ``blender_version``.
    """
    say = say or (lambda *_: None)
    say("building Blender's scene")
    bl = _Scene(body_vertices, body_triangles, bones, weights, bone_matrices, shirt_vertices, shirt_triangles,
                shirt_groups, hand_offsets, settings, frames, fps)
    body = {}
    for f in check_frames:
        bl.scene.frame_set(f)
        body[f] = _evaluated_vertices(bl.body_ob)
    bl.free_cache()
    bl.scene.frame_set(1)
    rest = _evaluated_vertices(bl.shirt_ob)
    frame_s = []
    raced = 0
    for f in range(2, frames + 2):
        frame_s.append(bl.frame(f))
        if after_frame is not None and after_frame(f, frame_s[-1]) is False:
            break
        raced += 1
    end = _evaluated_vertices(bl.shirt_ob)
    t0 = time.perf_counter()
    for f in range(2, raced + 2):
        bl.scene.frame_set(f)
    replay = (time.perf_counter() - t0) / max(1, raced)
    return {"frame_s": frame_s, "cpu_s": bl.cpu_s, "iterations": bl.iterations, "frames_raced": raced,
            "replay_s_per_frame": replay, "shirt_rest": rest, "shirt_end": end, "body_vertices": body,
            "blender_version": bpy.app.version_string}
