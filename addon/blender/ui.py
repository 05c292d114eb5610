"""Tear Cloth in Blender's interface: the Physics panel (laid out like Blender's Cloth panel), the
enable button among Blender's physics buttons, the presets menu, the handle and collider lists,
and bake progress in the status bar.

The panels draw the settings table's blocks (``settings.block``) in table order, inside the
sections and layout below; what is not a setting (lists, operators, status) is drawn here directly.
This file owns drawing only: it reads settings and bake progress and never changes data (Blender
forbids writes while drawing). Bake state comes from ``bake.running`` and the cache root's
metadata, read at most once per file change; the Haptics panel reads the live session's status
(``haptic_session.running``/``finished``, refreshed by the session's tick) and what Discover found.
"""
from __future__ import annotations

import os

import bpy
from bpy.types import Menu, Panel, UIList

from .. import cache
from .. import settings as table
from ..bake import frame_span
from ..materials import MATERIALS
from . import bake, fray, haptic_session, modifier
from .ops import PRESET_SUBDIR


def _shown(row, data) -> bool:
    """Whether a row is drawn: every switch its ``ui["when"]`` names is on (a value that only
    means something under another block's switch, e.g. a weft value under the orthotropic one)."""
    when = row.ui.get("when", ())
    return all(getattr(data, table.setting(row.group, name).blender_name) for name in
               ((when,) if isinstance(when, str) else when))


def _rows(layout, data, block, rows=None):
    """The rows of a settings block, in table order (the block names the panel's grouping). The
    layout rule: a bool row is the switch of the rows after it in its block, which are drawn only
    while it is on."""
    switch = None
    for row in table.block(block) if rows is None else rows:
        if switch is not None and not getattr(data, switch.blender_name):
            continue
        if _shown(row, data):
            layout.prop(data, row.blender_name)
        if row.kind == "bool":
            switch = row


def _blocks(group: str) -> list:
    """The blocks of a group, in table order."""
    return list(dict.fromkeys(row.block for row in table.rows(group) if row.block))


def _switched(block: str) -> bool:
    """A block whose first row is a bool is a switched block: a sub-panel with the switch in its
    header and the other rows inside (drawn only while the switch is on)."""
    return table.block(block)[0].kind == "bool"


def _cache_state(obj):
    """(info dict or None, problem text or None) for the cache the object plays, memoised on the
    root's modification time so redraws do not reopen USD files."""
    path = modifier.attached_path(obj)
    if path is None:
        return None, None

    def read(path):
        try:
            return cache.cache_info(path), None
        except cache.CacheError as exc:
            return None, str(exc)

    try:
        info, problem = _by_mtime(path, read)
    except OSError:
        return None, f"cache file missing: {path}"
    if info is not None and info["object"] != obj.name:
        problem = f"baked for object {info['object']!r} (renamed since?): free or bake again"
    return info, problem


_memo: dict = {}


def _by_mtime(path: str, read):
    """``read(path)``, memoised on the file's modification time so redraws do not reopen USD
    files; OSError when the file is not there."""
    mtime = os.path.getmtime(path)
    memo = _memo.get(path)
    if memo is None or memo[0] != mtime:
        memo = (mtime, read(path))
        _memo[path] = memo
    return memo[1]


def _interrupted_rebake(obj) -> dict | None:
    """The re-bake a crash left beside the cache the object plays (``cache.interrupted_rebake``),
    memoised on its staging root's modification time, or None."""
    path = modifier.attached_path(obj)
    if path is None:
        return None
    try:
        return _by_mtime(cache.staging_path_for(path), lambda staging: cache.interrupted_rebake(path))
    except OSError:
        return None


class TearClothPanel:
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "physics"

    @classmethod
    def poll(cls, context):
        obj = context.object
        return obj is not None and obj.type == "MESH" and modifier.is_enabled(obj)


class TEARCLOTH_MT_material_presets(Menu):
    """The built-in materials, then the user's own: Blender preset files (ops.PRESET_SUBDIR in
    every scripts folder Blender searches), applied by Blender's ``script.execute_preset``."""

    bl_label = "Material Presets"

    def draw(self, context):
        layout = self.layout
        for name in MATERIALS:
            layout.operator("tearcloth.material_preset", text=name.title()).preset = name
        layout.separator()
        for folder in bpy.utils.preset_paths(PRESET_SUBDIR):
            for file in sorted(f for f in os.listdir(folder) if f.endswith(".py")):
                item = layout.operator("script.execute_preset", text=bpy.path.display_name(file))
                item.filepath = os.path.join(folder, file)
                item.menu_idname = "TEARCLOTH_MT_material_presets"
        layout.operator("tearcloth.material_preset_save", text="Save Preset...", icon="ADD")


def _draw_presets(layout, settings):
    layout.menu("TEARCLOTH_MT_material_presets", text=(settings.material_preset or "Presets").title(),
                icon="PRESET")


class TEARCLOTH_PT_main(TearClothPanel, Panel):
    bl_label = "Tear Cloth"

    def draw_header_preset(self, context):
        _draw_presets(self.layout, context.object.tearcloth)

    def draw(self, context):
        layout = self.layout
        obj = context.object
        progress = bake.progress_of(obj.name)
        if progress is not None:
            layout.progress(factor=progress.factor, type="BAR", text=progress.text())
            layout.operator("tearcloth.bake_cancel", icon="CANCEL")
            return
        info, problem = _cache_state(obj)
        if problem:
            layout.label(text=problem, icon="ERROR")
        elif info is not None and info["frames"]:
            state = "" if info["complete"] else " (interrupted)"
            layout.label(text=f"Baked frames {frame_span(info['frames'][0], info['frames'][-1])}{state}", icon="CHECKMARK")
            _draw_convergence(layout, obj)
        else:
            layout.label(text="Not baked: the rest mesh is shown", icon="INFO")


def _draw_convergence(layout, obj):
    """How many sub-steps of the last bake stopped at the CG iteration cap even after splitting
    (blender/bake.py records it at the end of every bake run)."""
    last = bake.last_convergence(obj)
    if last is None:
        return
    n, steps, total = last
    if n:
        layout.label(text=f"{n} sub-step{'s' if n != 1 else ''} in {steps} of {total} steps stopped at the "
                          "CG cap: raise CG Iterations", icon="ERROR")
    else:
        layout.label(text=f"Every solve converged ({total} steps)", icon="CHECKMARK")


def _baked(obj) -> bool:
    return modifier.attached_path(obj) is not None


def _settings_layout(panel, context):
    """A settings panel's layout (property split) and the object's settings; greyed out once the
    object plays a bake, since changed settings only act on the next one."""
    layout = panel.layout
    layout.use_property_split = True
    layout.active = not _baked(context.object)
    return layout, context.object.tearcloth


class TEARCLOTH_PT_material(TearClothPanel, Panel):
    bl_label = "Material"
    bl_parent_id = "TEARCLOTH_PT_main"

    def draw_header_preset(self, context):
        _draw_presets(self.layout, context.object.tearcloth)

    def draw(self, context):
        layout, settings = _settings_layout(self, context)
        flow = layout.grid_flow(row_major=False, columns=0, even_columns=True, even_rows=False, align=True)
        for block in _blocks("material"):
            if not _switched(block):
                _rows(flow.column(), settings, block)


def _switched_panel(block: str, parent: str):
    """The sub-panel of a switched block (see ``_switched``), e.g. the orthotropic and the plastic
    rows of the material."""
    switch, *rows = table.block(block)

    def draw_header(self, context):
        self.layout.active = not _baked(context.object)
        self.layout.prop(context.object.tearcloth, switch.blender_name, text="")

    def draw(self, context):
        layout, settings = _settings_layout(self, context)
        if getattr(settings, switch.blender_name):
            _rows(layout.column(), settings, block, rows)

    return type(f"TEARCLOTH_PT_{block.replace('.', '_')}", (TearClothPanel, Panel), {
        "bl_label": switch.label, "bl_parent_id": parent, "bl_options": {"DEFAULT_CLOSED"},
        "draw_header": draw_header, "draw": draw, "__doc__": switch.description})


# Made from the table at import: a switched block added to the material rows gets its sub-panel.
MATERIAL_SUBPANELS = tuple(_switched_panel(block, "TEARCLOTH_PT_material") for block in _blocks("material")
                           if _switched(block))


class TEARCLOTH_PT_quality(TearClothPanel, Panel):
    bl_label = "Quality"
    bl_parent_id = "TEARCLOTH_PT_main"

    def draw(self, context):
        layout, settings = _settings_layout(self, context)
        col = layout.column()
        _rows(col, settings, "solver.steps")
        fps = context.scene.render.fps / context.scene.render.fps_base
        col.label(text=f"Time step {1000.0 / fps / settings.steps_per_frame:.3g} ms")
        _rows(layout.column(align=True), settings, "solver.cg")
        col = layout.column(heading="Tearing")
        col.prop(settings, "use_tearing", text="")
        sub = col.column(align=True)
        sub.active = settings.use_tearing
        _rows(sub, settings, "tearing.scan")


class TEARCLOTH_UL_handles(UIList):
    def draw_item(self, context, layout, data, item, icon, active_data, active_property, index=0, flt_flag=0):
        row = layout.row(align=True)
        row.prop_search(item, "vertex_group", context.object, "vertex_groups", text="", icon="GROUP_VERTEX")
        row.prop(item, "follow", text="", icon="EMPTY_AXIS")


class TEARCLOTH_UL_colliders(UIList):
    def draw_item(self, context, layout, data, item, icon, active_data, active_property, index=0, flt_flag=0):
        layout.prop(item, "object", text="", icon="MOD_PHYSICS")


def _list_with_buttons(layout, list_id, data, prop, index_prop, add_op, remove_op):
    row = layout.row()
    row.template_list(list_id, "", data, prop, data, index_prop, rows=3)
    col = row.column(align=True)
    col.operator(add_op, icon="ADD", text="")
    col.operator(remove_op, icon="REMOVE", text="")


class TEARCLOTH_PT_pins(TearClothPanel, Panel):
    bl_label = "Pins and Handles"
    bl_parent_id = "TEARCLOTH_PT_main"

    def draw(self, context):
        layout = self.layout
        obj = context.object
        settings = obj.tearcloth
        layout.active = not _baked(obj)
        split = layout.column()
        split.use_property_split = True
        split.prop_search(settings, "pin_group", obj, "vertex_groups", text="Pin Group")
        row = split.row()
        row.active = bool(settings.pin_group)  # the pull of weights below 1 (weight 1 holds exactly)
        row.prop(settings, "pin_stiffness")
        layout.label(text="Handles (vertex group, follow object):")
        _list_with_buttons(layout, "TEARCLOTH_UL_handles", settings, "handles", "active_handle_index",
                           "tearcloth.handle_add", "tearcloth.handle_remove")


class TEARCLOTH_PT_seams(TearClothPanel, Panel):
    bl_label = "Weak Seams"
    bl_parent_id = "TEARCLOTH_PT_main"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout, settings = _settings_layout(self, context)
        col = layout.column()
        col.prop_search(settings, "seam_group", context.object, "vertex_groups", text="Vertex Group")
        sub = col.column()
        sub.active = bool(settings.seam_group)
        sub.prop(settings, "seam_factor")


class TEARCLOTH_PT_collision(TearClothPanel, Panel):
    bl_label = "Collision"
    bl_parent_id = "TEARCLOTH_PT_main"

    def draw_header(self, context):
        self.layout.prop(context.object.tearcloth, "use_collision", text="")

    def draw(self, context):
        layout = self.layout
        settings = context.object.tearcloth
        layout.active = settings.use_collision and not _baked(context.object)
        _list_with_buttons(layout, "TEARCLOTH_UL_colliders", settings, "colliders", "active_collider_index",
                           "tearcloth.collider_add", "tearcloth.collider_remove")
        col = layout.column()
        col.use_property_split = True
        col.prop(settings, "collider_collection")
        _rows(col, settings, "collision.contact")
        col.separator()
        _rows(col, settings, "collision.clusters")
        col.operator("tearcloth.preview_clusters", icon="GROUP_VERTEX")


def _draw_fray(layout, obj):
    """The frayed-edge button, or the modifier's switches once it is there (its inputs are in the
    modifier stack, where Blender draws a node group's inputs)."""
    md = fray.find_modifier(obj)
    row = layout.row(align=True)
    if md is None:
        row.operator("tearcloth.add_frayed_edges", icon="STRANDS")
        return
    row.label(text="Frayed Edges", icon="STRANDS")
    row.prop(md, "show_viewport", text="")
    row.prop(md, "show_render", text="")


class TEARCLOTH_PT_cache(TearClothPanel, Panel):
    bl_label = "Cache"
    bl_parent_id = "TEARCLOTH_PT_main"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        obj = context.object
        settings = obj.tearcloth
        running = obj.name in bake.running
        col = layout.column()
        col.active = not running
        col.prop(settings, "cache_folder")
        sub = col.column(align=True)
        sub.prop(settings, "frame_start", text="Frame Start")
        sub.prop(settings, "frame_end", text="End")
        info, problem = _cache_state(obj)
        if info is not None and info["frames"]:
            col.label(text=f"{len(info['frames'])} frames in {os.path.basename(info['path'])}")
        staged = _interrupted_rebake(obj)
        if staged is not None:
            col.label(text=f"Re-bake stopped after frame {staged['frames'][-1]}: Resume continues it", icon="INFO")
        layout.use_property_split = False
        if running:
            layout.operator("tearcloth.bake_cancel", icon="CANCEL")
            return
        row = layout.row(align=True)
        row.operator("tearcloth.bake", text="Bake")
        row.operator("tearcloth.bake", text="Resume").resume = True
        row = layout.row(align=True)
        row.operator("tearcloth.free_bake", text="Free Bake")
        _draw_fray(layout, obj)
        row = layout.row(align=True)
        row.operator("tearcloth.bake_all", text="Bake All")
        row.operator("tearcloth.export_alembic", text="Export Alembic")
        layout.prop(context.scene.tearcloth, "alembic_path", text="")


_STATE_ICONS = {"absent": "UNLINKED", "needs_firmware": "ERROR", "homing": "TIME", "ready": "CHECKMARK",
                "lost": "CANCEL", "closed": "CHECKMARK", "unknown": "QUESTION"}


def _draw_discovered(layout, obj):
    """What Discover found, each device with buttons that give it to a hand."""
    found = haptic_session.discovery
    if found is None:
        return
    box = layout.box()
    if not found.falcons and not found.spacemice:
        box.label(text="No Falcon or SpaceMouse found", icon="INFO")
        return
    for kind, label, items in (("FALCON", "Falcon", [(s, s) for s in found.falcons]),
                               ("SPACEMOUSE", "SpaceMouse",
                                [(haptic_session.hid_path_text(m["path"]), m["model"]) for m in found.spacemice])):
        for identifier, name in items:
            row = box.row(align=True)
            row.label(text=f"{label} {name}")
            for hand in ("LEFT", "RIGHT"):
                op = row.operator("tearcloth.haptic_assign_device", text=hand.title())
                op.hand, op.kind, op.identifier = hand, kind, identifier


def _draw_hand(layout, obj, hand, run):
    settings = getattr(obj.tearcloth.haptics, hand)
    status = haptic_session.hand_status(obj, hand)
    box = layout.box()
    row = box.row()
    row.prop(settings, "use", text=f"{hand.title()} Hand")
    if settings.use:
        row.label(text=haptic_session.STATE_TEXT.get(status.state, status.state),
                  icon=_STATE_ICONS.get(status.state, "QUESTION"))
    if not settings.use:
        return
    if status.message:
        box.label(text=status.message)
    if run is not None and hand in run.status.hands:
        box.label(text=f"Force {status.force:.2f} N felt, {status.cloth_force:.1f} N from the cloth",
                  icon="FORCE_FORCE")
    col = box.column()
    col.use_property_split = True
    col.active = run is None
    col.prop(settings, "device")
    if settings.device == "FALCON":
        col.prop(settings, "falcon_serial")
    elif settings.device == "SPACEMOUSE":
        col.prop(settings, "spacemouse_path")
    col.prop_search(settings, "vertex_group", obj, "vertex_groups", text="Handle Group")
    col.prop(settings, "mapping")
    if settings.mapping == "FIT":
        col.prop(settings, "region_radius")
    else:
        col.prop(settings, "scale")
        col.prop(settings, "offset")
    _rows(col.column(align=True), settings, "hand.gains")
    _rows(col.column(align=True), settings, "hand.force")


class TEARCLOTH_PT_haptics(TearClothPanel, Panel):
    bl_label = "Haptics"
    bl_parent_id = "TEARCLOTH_PT_main"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.layout
        obj = context.object
        settings = obj.tearcloth.haptics
        run = haptic_session.running.get(obj.name)
        if run is not None:
            status = run.status
            layout.label(text=status.text(), icon="TIME" if status.phase == "homing" else "PLAY")
            if status.phase == "running":
                layout.label(text=status.rates())
            layout.operator("tearcloth.haptic_stop", icon="CANCEL", text="Stop")
        else:
            row = layout.row(align=True)
            row.operator("tearcloth.haptic_session", icon="PLAY", text="Start")
            row.operator("tearcloth.haptic_discover", icon="VIEWZOOM", text="Discover")
            _draw_discovered(layout, obj)
        for hand in ("left", "right"):
            _draw_hand(layout, obj, hand, run)
        used = [getattr(settings, h) for h in ("left", "right") if getattr(settings, h).use]
        col = layout.column()
        col.use_property_split = True
        col.active = run is None
        if any(h.device == "FALCON" for h in used):
            col.prop(settings, "firmware_path")
        col.prop(settings, "stop_button")
        col.prop(settings, "time_step")
        col.prop(settings, "record")
        col.prop(settings, "servo")  # the servo process (default) or threads in this process
        if any(h.device == "EMULATED" for h in used):
            _rows(col.column(align=True), settings, "haptics.demo")
        if any(h.device == "KEYBOARD" for h in used):
            col.prop(settings, "keyboard_step")
            help_col = layout.column(align=True)
            for line in haptic_session.KEYBOARD_HELP:
                help_col.label(text=line)
        row = layout.row(align=True)
        row.prop(settings, "force_log_folder", text="")
        row.operator("tearcloth.haptic_save_force_log", icon="GRAPH", text="Save Force Log")


def draw_physics_button(self, context):
    """Added to Blender's "Enable physics for:" buttons (PHYSICS_PT_add), like its Cloth button."""
    obj = context.object
    if obj is None or obj.type != "MESH":
        return
    row = self.layout.row(align=True)
    md = modifier.find_modifier(obj)
    if md is None:
        row.operator("tearcloth.enable", text="Tear Cloth", icon="MOD_CLOTH")
    else:
        row.operator("tearcloth.disable", text="Tear Cloth", icon="X")
        row.prop(md, "show_viewport", text="")
        row.prop(md, "show_render", text="")


def draw_status_bar(self, context):
    for progress in [run.progress for run in bake.running.values()]:
        self.layout.progress(factor=progress.factor, type="BAR", text=progress.text())


classes = (
    TEARCLOTH_MT_material_presets,
    TEARCLOTH_UL_handles,
    TEARCLOTH_UL_colliders,
    TEARCLOTH_PT_main,
    TEARCLOTH_PT_material,
    *MATERIAL_SUBPANELS,
    TEARCLOTH_PT_quality,
    TEARCLOTH_PT_pins,
    TEARCLOTH_PT_seams,
    TEARCLOTH_PT_collision,
    TEARCLOTH_PT_cache,
    TEARCLOTH_PT_haptics,
)


def register_draw_functions() -> None:
    bpy.types.PHYSICS_PT_add.append(draw_physics_button)
    bpy.types.STATUSBAR_HT_header.append(draw_status_bar)


def unregister_draw_functions() -> None:
    bpy.types.PHYSICS_PT_add.remove(draw_physics_button)
    bpy.types.STATUSBAR_HT_header.remove(draw_status_bar)
