"""Tear Cloth operators: enable/disable, bake (modal with a worker thread, or inline from a
script), bake all, cancel, free, frayed edges, material presets, handle and collider lists, cluster preview,
Alembic export, and the live haptic session (start - modal -, stop, device discovery, device
assignment, force log).

Every operator reports problems with ``self.report`` through a ``Reports`` list, which also logs
them under the "tearcloth" logger, so a headless run and the UI say the same thing. An operator
that fails changes nothing in the scene.
"""
from __future__ import annotations

import colorsys
import os
import time

import bpy
import numpy as np
from bpy.props import BoolProperty, EnumProperty, FloatProperty, StringProperty
from bpy.types import Operator

from .. import settings as table
from .. import spaces
from ..materials import MATERIALS
from . import bake, convert, fray, haptic_session, jobs, modifier
from .report import BakeError, Reports, linked_from, not_a_mesh

CLUSTER_ATTRIBUTE = "tearcloth_clusters"


def _active_mesh(context):
    obj = context.object
    return obj if obj is not None and obj.type == "MESH" else None


class TEARCLOTH_OT_enable(Operator):
    """Make this mesh tearable: adds the "Tear Cloth" modifier (a Mesh Sequence Cache that plays the bake)"""

    bl_idname = "tearcloth.enable"
    bl_label = "Tear Cloth"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        obj = context.object
        return obj is not None and not modifier.is_enabled(obj)

    def execute(self, context):
        reports = Reports()
        obj = context.object
        if obj.type != "MESH":
            reports.error(not_a_mesh(obj))
            reports.to_operator(self)
            return {"CANCELLED"}
        if obj.modifiers.get(modifier.MODIFIER_NAME) is not None:
            reports.error(f"{obj.name}: a modifier named {modifier.MODIFIER_NAME!r} that is not a Mesh Sequence "
                          "Cache is in the way; rename it first")
            reports.to_operator(self)
            return {"CANCELLED"}
        # the object's own Tear Cloth modifier renamed by the user (it plays this object's bake):
        # taken back under its name, not doubled by a second one below it (which would bake from
        # the first one's frames)
        own = modifier.object_id(obj)
        for md in obj.modifiers:
            played = modifier.bake_played_by(md) if own else None
            if played is not None and played[1].get("object_id") == own:
                reports.info(f"{obj.name}: the modifier {md.name!r} plays this object's bake: renamed back to "
                             f"{modifier.MODIFIER_NAME!r} (Tear Cloth finds its modifier by that name)")
                md.name = modifier.MODIFIER_NAME
                reports.to_operator(self)
                return {"FINISHED"}
        modifier.add_modifier(obj)
        # lengths the user never set start as their physical defaults in this scene's units
        convert.scene_length_defaults(obj.tearcloth, context.scene)
        return {"FINISHED"}


class _OnTearCloth:
    """An operator on an object whose Tear Cloth is enabled (undoable)."""

    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return modifier.is_enabled(context.object)


class TEARCLOTH_OT_disable(_OnTearCloth, Operator):
    """Remove the "Tear Cloth" modifier (the baked files stay on disk; Free Bake deletes them)"""

    bl_idname = "tearcloth.disable"
    bl_label = "Disable Tear Cloth"

    def execute(self, context):
        obj = context.object
        reports = Reports()
        if obj.name in jobs.bakes:
            reports.error(f"{obj.name}: its bake is running; cancel it first (Esc)")
            reports.to_operator(self)
            return {"CANCELLED"}
        if obj.name in jobs.live_sessions:
            reports.error(f"{obj.name}: a haptic session is running on it; stop it first (Esc)")
            reports.to_operator(self)
            return {"CANCELLED"}
        kept = modifier.attached_path(obj)
        modifier.detach_cache(obj)
        obj.modifiers.remove(modifier.find_modifier(obj))
        if kept:
            reports.info(f"{obj.name}: Tear Cloth disabled; its bake stays in {kept}")
        reports.to_operator(self)
        return {"FINISHED"}


# ---------------------------------------------------------------------------------------------
# Bake


class _BakeModal:
    """Shared by Bake and Bake All: from a script (``execute``) the objects bake inline one after
    the other; from the UI (``invoke``) a worker thread bakes while a timer feeds it, one object
    at a time, Esc cancelling (frames already baked are kept)."""

    resume: BoolProperty(name="Resume", default=False,
                         description="Continue an interrupted bake from its last baked frame")

    def object_names(self, context) -> list:
        raise NotImplementedError

    def execute(self, context):
        names = self.object_names(context)
        if not names:
            return {"CANCELLED"}
        states = []
        for name in names:
            reports = Reports()
            try:
                result = bake.bake_object(context, bpy.data.objects.get(name), resume=self.resume, reports=reports)
                states.append(result.state)
            except BakeError:
                states.append("error")
            reports.to_operator(self)
        return {"FINISHED"} if "done" in states or "cancelled" in states else {"CANCELLED"}

    def invoke(self, context, event):
        if context.window is None:  # no window to run a timer in (background mode): bake inline
            return self.execute(context)
        self._names = self.object_names(context)
        self._run = None
        self._any = False
        if not self._names or not self._next(context):
            return {"CANCELLED"}
        wm = context.window_manager
        self._timer = wm.event_timer_add(bake.TIMER_INTERVAL, window=context.window)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def _next(self, context) -> bool:
        """Start the next object's bake; False when none is left that could start."""
        while self._names:
            name = self._names.pop(0)
            reports = Reports()
            try:
                run = bake.BakeRun(context, bpy.data.objects.get(name), resume=self.resume, reports=reports)
            except BakeError:
                reports.to_operator(self)
                continue
            run.start_thread(context)
            reports.to_operator(self)
            run.reports = Reports()  # what was shown is not shown again at the end
            self._run = run
            return True
        self._run = None
        return False

    def modal(self, context, event):
        run = self._run
        if event.type == "ESC" and event.value == "PRESS":
            self._names = []
            run.stop()
            return self._end_run(context)
        if event.type != "TIMER":
            return {"PASS_THROUGH"}  # the UI stays usable while baking
        try:
            alive = run.tick(context)
        except Exception as exc:  # never leave a worker running behind a dead operator
            run.progress.message = f"unexpected error: {exc}"
            run.stop(state="error")
            return self._end_run(context)
        if not alive:
            if run.thread is not None:
                run.thread.join()
            return self._end_run(context)
        _redraw(context)
        return {"PASS_THROUGH"}

    def _end_run(self, context):
        state = self._run.finish(context)
        self._run.reports.to_operator(self)
        self._any = self._any or state in ("done", "cancelled")
        _redraw(context)
        if self._names and self._next(context):
            return {"PASS_THROUGH"}
        context.window_manager.event_timer_remove(self._timer)
        return {"FINISHED"} if self._any else {"CANCELLED"}

    def cancel(self, context):
        """Blender ends the operator (file load, window closed): stop and keep the frames."""
        self._names = []
        if self._run is not None:
            self._run.stop()
            self._run.finish(context)
        context.window_manager.event_timer_remove(self._timer)


def _redraw(context):
    for window in context.window_manager.windows:
        for area in window.screen.areas:
            if area.type in {"PROPERTIES", "VIEW_3D", "STATUSBAR", "TIMELINE", "DOPESHEET_EDITOR"}:
                area.tag_redraw()


class TEARCLOTH_OT_bake(_BakeModal, Operator):
    """Simulate the tearing cloth over its frame range into its cache (Esc cancels, keeping the frames baked)"""

    bl_idname = "tearcloth.bake"
    bl_label = "Bake"

    @classmethod
    def poll(cls, context):
        return modifier.is_enabled(context.object)

    def object_names(self, context):
        obj = context.object
        why = "select the mesh to tear" if obj is None else not_a_mesh(obj) if obj.type != "MESH" else linked_from(obj)
        if why:
            reports = Reports()
            reports.error(why)
            reports.to_operator(self)
            return []
        return [obj.name]


class TEARCLOTH_OT_bake_all(_BakeModal, Operator):
    """Bake every Tear Cloth object of the scene, one after the other"""

    bl_idname = "tearcloth.bake_all"
    bl_label = "Bake All"

    def object_names(self, context):
        objects = [o for o in context.scene.objects if o.type == "MESH" and modifier.is_enabled(o)]
        reports = Reports()
        names = []
        for o in objects:
            linked = linked_from(o)
            if linked:
                reports.warning(f"skipped: {linked}")
            else:
                names.append(o.name)
        if not objects:
            reports.warning("no object in the scene has Tear Cloth enabled")
        reports.to_operator(self)
        return names


class TEARCLOTH_OT_bake_cancel(Operator):
    """Stop the running bake of this object (the frames baked so far are kept; Resume continues)"""

    bl_idname = "tearcloth.bake_cancel"
    bl_label = "Cancel Bake"

    @classmethod
    def poll(cls, context):
        return context.object is not None and context.object.name in jobs.bakes

    def execute(self, context):
        run = jobs.bakes.get(context.object.name)
        if run is not None:
            # The modal operator notices on its next tick and finishes (attaching the frames).
            run.job.cancel.set()
            if run.queue is not None:
                run.queue.put(None)
        return {"FINISHED"}


class TEARCLOTH_OT_free_bake(_OnTearCloth, Operator):
    """Delete this object's baked cache; the modifier shows the rest mesh again"""

    bl_idname = "tearcloth.free_bake"
    bl_label = "Free Bake"

    def execute(self, context):
        reports = Reports()
        ok = bake.free_bake(context.object, reports)
        reports.to_operator(self)
        return {"FINISHED"} if ok else {"CANCELLED"}


class TEARCLOTH_OT_add_frayed_edges(_OnTearCloth, Operator):
    """Grow short loose threads along the warp and weft at the torn edges of the bake (a Geometry Nodes modifier after "Tear Cloth" that renders without the add-on)"""

    bl_idname = "tearcloth.add_frayed_edges"
    bl_label = "Add Frayed Edges"

    def execute(self, context):
        obj = context.object
        reports = Reports()
        if fray.find_modifier(obj) is not None:
            reports.info(f"{obj.name}: it has frayed edges already (modifier {fray.MODIFIER_NAME!r})")
            reports.to_operator(self)
            return {"CANCELLED"}
        fray.add_modifier(obj, context.scene, obj.active_material)
        if modifier.attached_path(obj) is None:
            reports.info(f"{obj.name}: frayed edges added; threads appear along the tears once it is baked")
        reports.to_operator(self)
        return {"FINISHED"}


# ---------------------------------------------------------------------------------------------
# Settings helpers


class TEARCLOTH_OT_material_preset(Operator):
    """Set the material values from a preset"""

    bl_idname = "tearcloth.material_preset"
    bl_label = "Material Preset"
    bl_options = {"REGISTER", "UNDO"}

    preset: EnumProperty(
        name="Preset",
        items=[(name, name.title(), f"{name}: E {m.young:.3g} Pa, thickness {m.thickness * 1e3:.2g} mm, "
                f"tear stress {m.tear_stress:.3g} Pa") for name, m in MATERIALS.items()],
    )

    @classmethod
    def poll(cls, context):
        return context.object is not None and context.object.type == "MESH"

    def execute(self, context):
        convert.material_to_settings(MATERIALS[self.preset], context.object.tearcloth, context.scene)
        return {"FINISHED"}


# Users' own material presets: Python files in Blender's preset folder
# (<user scripts>/presets/tearcloth/material/), listed by the presets menu next to the built-in
# ones and applied by Blender's own ``script.execute_preset``, so they can be copied to other
# machines like any Blender preset. The file holds SI values and converts the lengths through the
# unit scale of the scene it is applied in (Blender's AddPresetBase would store Blender units,
# wrong in a scene with another unit scale).
PRESET_SUBDIR = os.path.join("tearcloth", "material")


def preset_file_text(settings, scene, name: str) -> str:
    """The preset file of the object's current material (one line per material row)."""
    material = convert.material_from_settings(settings, scene)
    lines = ["# Tear Cloth material preset (SI units; lengths converted to the scene's units)", "import bpy",
             "settings = bpy.context.object.tearcloth",
             "scale = bpy.context.scene.unit_settings.scale_length or 1.0"]
    for row in table.rows("material"):
        if row.name == "name":
            lines.append(f"settings.{row.blender_name} = {name!r}")
        elif row.is_scene_length:
            lines.append(f"settings.{row.blender_name} = {getattr(material, row.name)!r} / scale  # {row.unit}")
        else:
            lines.append(f"settings.{row.blender_name} = {getattr(material, row.name)!r}  # {row.unit}")
    return "\n".join(lines) + "\n"


class TEARCLOTH_OT_material_preset_save(Operator):
    """Save this object's material as a preset of your own (listed in the presets menu, shareable as a file)"""

    bl_idname = "tearcloth.material_preset_save"
    bl_label = "Save Material Preset"

    name: StringProperty(name="Name", description="Name of the preset (its file name too)", maxlen=64)

    @classmethod
    def poll(cls, context):
        return context.object is not None and modifier.is_enabled(context.object)

    def invoke(self, context, event):
        return context.window_manager.invoke_props_dialog(self)

    def execute(self, context):
        reports = Reports()
        name = self.name.strip()
        if not name:
            reports.error("give the preset a name")
            return _finish(self, reports, {"CANCELLED"})
        try:
            text = preset_file_text(context.object.tearcloth, context.scene, name)
        except ValueError as exc:
            reports.error(f"{context.object.name}: {exc}; not saved")
            return _finish(self, reports, {"CANCELLED"})
        folder = bpy.utils.user_resource("SCRIPTS", path=os.path.join("presets", PRESET_SUBDIR), create=True)
        path = os.path.join(folder, bpy.path.clean_name(name) + ".py")
        with open(path, "w", encoding="utf-8") as f:
            f.write(text)
        reports.info(f"saved the material preset {name!r} to {path}")
        return _finish(self, reports, {"FINISHED"})


class _OnMesh:
    """An operator on the active mesh object, Tear Cloth enabled or not (undoable)."""

    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return _active_mesh(context) is not None


class TEARCLOTH_OT_handle_add(_OnMesh, Operator):
    """Add a handle: a vertex group grasped as one, optionally following an object"""

    bl_idname = "tearcloth.handle_add"
    bl_label = "Add Handle"

    def execute(self, context):
        settings = context.object.tearcloth
        item = settings.handles.add()
        vg = context.object.vertex_groups.active
        if vg is not None:
            item.vertex_group = vg.name
        settings.active_handle_index = len(settings.handles) - 1
        return {"FINISHED"}


class _RemoveActiveSlot:
    """Remove the active slot of one of the object's lists (``collection`` and its ``index``
    property name it): handles and colliders behave alike."""

    collection = ""
    index = ""
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        obj = _active_mesh(context)
        return obj is not None and len(getattr(obj.tearcloth, cls.collection)) > 0

    def execute(self, context):
        settings = context.object.tearcloth
        slots = getattr(settings, self.collection)
        i = min(getattr(settings, self.index), len(slots) - 1)
        slots.remove(i)
        setattr(settings, self.index, max(0, i - 1))
        return {"FINISHED"}


class TEARCLOTH_OT_handle_remove(_RemoveActiveSlot, Operator):
    """Remove the active handle"""

    bl_idname = "tearcloth.handle_remove"
    bl_label = "Remove Handle"
    collection, index = "handles", "active_handle_index"


class TEARCLOTH_OT_collider_add(_OnMesh, Operator):
    """Add a collider slot (selected mesh objects other than this one are filled in)"""

    bl_idname = "tearcloth.collider_add"
    bl_label = "Add Collider"

    def execute(self, context):
        obj = context.object
        settings = obj.tearcloth
        present = {item.object for item in settings.colliders}
        picked = [o for o in context.selected_objects if o is not obj and o.type == "MESH" and o not in present]
        for other in picked or [None]:
            item = settings.colliders.add()
            item.object = other
        settings.active_collider_index = len(settings.colliders) - 1
        return {"FINISHED"}


class TEARCLOTH_OT_collider_remove(_RemoveActiveSlot, Operator):
    """Remove the active collider slot"""

    bl_idname = "tearcloth.collider_remove"
    bl_label = "Remove Collider"
    collection, index = "colliders", "active_collider_index"


# ---------------------------------------------------------------------------------------------
# Cluster preview and Alembic export


def _finish(operator, reports: Reports, result: set) -> set:
    reports.to_operator(operator)
    return result


def cluster_colours(labels: np.ndarray) -> np.ndarray:
    """(n, 4) RGBA per label: hues spread by the golden ratio so neighbouring ids differ."""
    k = int(labels.max()) + 1 if labels.size else 0
    table = np.array([colorsys.hsv_to_rgb((i * 0.618033988749895) % 1.0, 0.65, 0.95) + (1.0,)
                      for i in range(k)], dtype=np.float32).reshape(-1, 4)
    return table[labels]


class TEARCLOTH_OT_preview_clusters(_OnMesh, Operator):
    """Colour the mesh by collision cluster (colour attribute "tearcloth_clusters"), as collision detection will split it"""

    bl_idname = "tearcloth.preview_clusters"
    bl_label = "Preview Clusters"

    def execute(self, context):
        from ..collision import cluster_mesh

        reports = Reports()
        obj = context.object
        if obj.mode == "EDIT":
            reports.error(f"{obj.name}: leave Edit Mode to preview the clusters")
            return _finish(self, reports, {"CANCELLED"})
        mesh = obj.data
        arrays = convert.read_mesh(mesh, uv=False)
        if len(arrays.triangles) == 0:
            reports.error(f"{obj.name}: the mesh has no faces to cluster")
            return _finish(self, reports, {"CANCELLED"})
        scale = convert.scale_length(context.scene)
        positions = spaces.local_to_world_si(arrays.vertices, convert.matrix_array(obj.matrix_world), scale)
        target = int(obj.tearcloth.cluster_size)
        labels = cluster_mesh(positions, arrays.triangles, target)
        colours = np.full((len(mesh.vertices), 4), 0.2, dtype=np.float32)  # loose vertices: dark grey
        colours[:, 3] = 1.0
        colours[arrays.kept] = cluster_colours(labels)
        attr = mesh.color_attributes.get(CLUSTER_ATTRIBUTE)
        if attr is not None and (attr.domain != "POINT" or attr.data_type != "FLOAT_COLOR"):
            mesh.color_attributes.remove(attr)
            attr = None
        if attr is None:
            attr = mesh.color_attributes.new(CLUSTER_ATTRIBUTE, "FLOAT_COLOR", "POINT")
        attr.data.foreach_set("color", colours.ravel())
        mesh.color_attributes.active_color = attr
        mesh.update()
        k = int(labels.max()) + 1
        reports.info(f"{obj.name}: {k} cluster{'s' if k != 1 else ''} of about {target} vertices in the "
                     f"colour attribute {CLUSTER_ATTRIBUTE!r} (Viewport Shading > Color > Attribute)")
        return _finish(self, reports, {"FINISHED"})


class TEARCLOTH_OT_export_alembic(Operator):
    """Export the baked Tear Cloth objects (the selected ones, or all) to Alembic with Blender's exporter, the torn topology of every frame included"""

    bl_idname = "tearcloth.export_alembic"
    bl_label = "Export Alembic"

    def execute(self, context):
        reports = Reports()
        scene = context.scene
        baked = [o for o in scene.objects if modifier.attached_path(o) is not None]
        chosen = [o for o in baked if o.select_get()] or baked
        if not chosen:
            reports.error("nothing to export: no Tear Cloth object of this scene has a bake")
            return _finish(self, reports, {"CANCELLED"})
        target = scene.tearcloth.alembic_path
        if target.startswith("//") and not bpy.data.filepath:
            reports.error(f"the Alembic path {target!r} is relative to the .blend file, which is not "
                          "saved yet: save it or choose an absolute path")
            return _finish(self, reports, {"CANCELLED"})
        path = os.path.normpath(bpy.path.abspath(target))
        folder = os.path.dirname(path)
        try:
            os.makedirs(folder, exist_ok=True)
        except OSError as exc:
            reports.error(f"cannot create {folder}: {exc.strerror or exc}")
            return _finish(self, reports, {"CANCELLED"})
        start = min(o.tearcloth.frame_start for o in chosen)
        end = max(o.tearcloth.frame_end for o in chosen)
        view_layer = context.view_layer
        selected = [o for o in view_layer.objects if o.select_get()]
        active = view_layer.objects.active
        try:
            for o in selected:
                o.select_set(False)
            for o in chosen:
                o.select_set(True)
            # The "Tear Cloth" Mesh Sequence Cache modifier makes the exporter treat each object as
            # animated, so every frame's own topology is written (not just the first frame's).
            result = bpy.ops.wm.alembic_export(
                filepath=path, start=start, end=end, selected=True, uvs=True, normals=True,
                evaluation_mode="RENDER", as_background_job=False,
            )
        finally:
            for o in chosen:
                o.select_set(False)
            for o in selected:
                if o.name in view_layer.objects:
                    o.select_set(True)
            view_layer.objects.active = active
        if "FINISHED" not in result:
            reports.error(f"Blender's Alembic exporter did not finish writing {path}")
            return _finish(self, reports, {"CANCELLED"})
        reports.info(f"exported {len(chosen)} object{'s' if len(chosen) != 1 else ''}, frames "
                     f"{start}-{end}, to {path}")
        return _finish(self, reports, {"FINISHED"})


# ---------------------------------------------------------------------------------------------
# The live haptic session


def _view_rotation(context, event):
    """The rotation (3x3) of the 3D view under the mouse, or None (no 3D view there)."""
    window = context.window
    if window is None:
        return None
    for area in window.screen.areas:
        if area.type != "VIEW_3D":
            continue
        if area.x <= event.mouse_x < area.x + area.width and area.y <= event.mouse_y < area.y + area.height:
            region = area.spaces.active.region_3d
            return np.array(region.view_rotation.to_matrix()) if region is not None else None
    return None


class TEARCLOTH_OT_haptic_session(Operator):
    """Tear this cloth live with haptic devices (Esc, the stop button or Stop ends it; the Haptics panel lists the keys of a keyboard hand)"""

    bl_idname = "tearcloth.haptic_session"
    bl_label = "Start Haptic Session"

    duration: FloatProperty(
        name="Duration", default=0.0, min=0.0, options={"SKIP_SAVE"},
        description="From a script or in background mode (no window): run this many seconds, then stop")

    @classmethod
    def poll(cls, context):
        return modifier.is_enabled(context.object) and context.object.name not in jobs.live_sessions

    def _new_run(self, context):
        reports = Reports()
        try:
            run = haptic_session.HapticRun(context, context.object, reports)
            run.start(context)
        except BakeError:
            reports.to_operator(self)
            return None
        reports.to_operator(self)
        run.reports = Reports()  # what was shown is not shown again at the end
        return run

    def execute(self, context):
        if self.duration <= 0.0:
            reports = Reports()
            reports.error("a live haptic session runs until Esc in a window; from a script or in background mode "
                          "give duration=seconds")
            return _finish(self, reports, {"CANCELLED"})
        run = self._new_run(context)
        if run is None:
            return {"CANCELLED"}
        try:
            haptic_session.run_for(context, run, self.duration)
        finally:
            run.stop(f"{self.duration:g} s are over")
            state = run.finish(context)
            run.reports.to_operator(self)
        return {"FINISHED"} if state != "error" else {"CANCELLED"}

    def invoke(self, context, event):
        if context.window is None:
            return self.execute(context)
        self._run = self._new_run(context)
        if self._run is None:
            return {"CANCELLED"}
        wm = context.window_manager
        self._timer = wm.event_timer_add(haptic_session.TIMER_INTERVAL, window=context.window)
        self._last_panel = 0.0
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        run = self._run
        if run.finished:  # stopped by a file load, unregister, or a failed start while homing
            return self._end(context)
        if event.type == "ESC" and event.value == "PRESS":
            run.stop("Esc pressed")
            return self._end(context)
        if event.type == "TIMER":
            try:
                alive = run.tick(context)
            except Exception as exc:  # never leave devices pushing behind a dead operator
                run.reports.error(f"{run.object_name}: unexpected error: {exc}; force set to zero")
                run.stop("unexpected error")
                return self._end(context)
            if not alive:
                return self._end(context)
            self._redraw(context)
            return {"PASS_THROUGH"}
        if event.value == "PRESS" and run.key(event.type, shift=event.shift, alt=event.alt):
            return {"RUNNING_MODAL"}
        if event.type == "MOUSEMOVE" and event.ctrl and run.keyboard_hands:
            run.mouse_move(event.mouse_x - event.mouse_prev_x, event.mouse_y - event.mouse_prev_y,
                           _view_rotation(context, event), alt=event.alt)
            return {"RUNNING_MODAL"}
        # Undo would take the live mesh from under the session, Edit Mode would edit it: blocked.
        if event.value == "PRESS" and (event.type == "TAB" or (event.type == "Z" and (event.ctrl or event.oskey))):
            self.report({"WARNING"}, "undo and Edit Mode are blocked while a haptic session runs (Esc ends it)")
            return {"RUNNING_MODAL"}
        return {"PASS_THROUGH"}

    def _redraw(self, context):
        """The viewport every tick; the panel's numbers ten times a second (it is costly to draw)."""
        now = time.perf_counter()
        panel = now - self._last_panel >= 0.1
        if panel:
            self._last_panel = now
        for window in context.window_manager.windows:
            for area in window.screen.areas:
                if area.type == "VIEW_3D" or (panel and area.type == "PROPERTIES"):
                    area.tag_redraw()

    def _end(self, context):
        run = self._run
        try:
            run.finish(context)
        except Exception as exc:  # the timer must go whatever happens
            run.reports.error(f"{run.object_name}: could not restore the object after the session: {exc}")
        run.reports.to_operator(self)
        context.window_manager.event_timer_remove(self._timer)
        _redraw(context)
        return {"FINISHED"}

    def cancel(self, context):
        """Blender ends the operator (file load, window closed): zero force, restore."""
        self._run.stop("Blender ended the session")
        self._run.finish(context)
        context.window_manager.event_timer_remove(self._timer)


class TEARCLOTH_OT_haptic_stop(Operator):
    """End the running haptic session with zero force on every device"""

    bl_idname = "tearcloth.haptic_stop"
    bl_label = "Stop Haptic Session"

    @classmethod
    def poll(cls, context):
        return bool(jobs.live_sessions)

    def execute(self, context):
        obj = context.object
        runs = [jobs.live_sessions[obj.name]] if obj is not None and obj.name in jobs.live_sessions \
            else list(jobs.live_sessions.values())
        for run in runs:
            run.request_stop("Stop pressed")  # the session's next tick ends it and restores the mesh
        return {"FINISHED"}


class TEARCLOTH_OT_haptic_discover(Operator):
    """Look for Novint Falcons (USB serial numbers) and SpaceMice, and check the state of each hand's device"""

    bl_idname = "tearcloth.haptic_discover"
    bl_label = "Discover Devices"

    def execute(self, context):
        reports = Reports()
        obj = _active_mesh(context)
        found = haptic_session.discover(obj)
        falcons = ", ".join(found.falcons) or "none"
        mice = ", ".join(m["model"] for m in found.spacemice) or "none"
        reports.info(f"Falcons: {falcons}; SpaceMice: {mice}")
        _redraw(context)
        return _finish(self, reports, {"FINISHED"})


_HAND_ITEMS = [("LEFT", "Left", "The left hand"), ("RIGHT", "Right", "The right hand")]


class TEARCLOTH_OT_haptic_assign_device(Operator):
    """Use this device for a hand"""

    bl_idname = "tearcloth.haptic_assign_device"
    bl_label = "Assign Device"
    bl_options = {"REGISTER", "UNDO", "INTERNAL"}

    hand: EnumProperty(name="Hand", items=_HAND_ITEMS)
    kind: EnumProperty(name="Kind", items=[("FALCON", "Falcon", ""), ("SPACEMOUSE", "SpaceMouse", "")])
    identifier: StringProperty(name="Identifier", description="Falcon serial number or SpaceMouse HID path")

    @classmethod
    def poll(cls, context):
        return modifier.is_enabled(context.object) and context.object.name not in jobs.live_sessions

    def execute(self, context):
        hand = getattr(context.object.tearcloth.haptics, self.hand.lower())
        hand.device = self.kind
        hand.use = True
        if self.kind == "FALCON":
            hand.falcon_serial = self.identifier
        else:
            hand.spacemouse_path = self.identifier
        return {"FINISHED"}


class TEARCLOTH_OT_haptic_save_force_log(Operator):
    """Write the last haptic session's force log (CSV) and a plot of the force each hand felt (PNG, like Fig. 6 of the paper)"""

    bl_idname = "tearcloth.haptic_save_force_log"
    bl_label = "Save Force Log"

    directory: StringProperty(name="Folder", subtype="DIR_PATH", options={"SKIP_SAVE"},
                              description="Where to write (empty: the Force Log Folder setting)")

    @classmethod
    def poll(cls, context):
        return context.object is not None and context.object.name in haptic_session.finished

    def execute(self, context):
        reports = Reports()
        obj = context.object
        run = haptic_session.finished.get(obj.name) if obj is not None else None
        if run is None:
            reports.error("no haptic session has ended on this object yet")
            return _finish(self, reports, {"CANCELLED"})
        folder = haptic_session.folder_path(self.directory or obj.tearcloth.haptics.force_log_folder, reports)
        if folder is None or run.save_force_log(folder, reports) is None:
            return _finish(self, reports, {"CANCELLED"})
        return _finish(self, reports, {"FINISHED"})


classes = (
    TEARCLOTH_OT_enable,
    TEARCLOTH_OT_disable,
    TEARCLOTH_OT_bake,
    TEARCLOTH_OT_bake_all,
    TEARCLOTH_OT_bake_cancel,
    TEARCLOTH_OT_free_bake,
    TEARCLOTH_OT_add_frayed_edges,
    TEARCLOTH_OT_material_preset,
    TEARCLOTH_OT_material_preset_save,
    TEARCLOTH_OT_handle_add,
    TEARCLOTH_OT_handle_remove,
    TEARCLOTH_OT_collider_add,
    TEARCLOTH_OT_collider_remove,
    TEARCLOTH_OT_preview_clusters,
    TEARCLOTH_OT_export_alembic,
    TEARCLOTH_OT_haptic_session,
    TEARCLOTH_OT_haptic_stop,
    TEARCLOTH_OT_haptic_discover,
    TEARCLOTH_OT_haptic_assign_device,
    TEARCLOTH_OT_haptic_save_force_log,
)
