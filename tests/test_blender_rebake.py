"""Bakes that never lose work (issue 12), driven through the real operators with PyPI bpy, each
Blender run in a child process (tests/test_blender_bake.py's scene and helpers):

* one vertex group (pins only, or one handle only) bakes, at every group count, in the Python
  API too; a failing bake restores the frame, leaves no cache file or folder it made, and
  leaves the object free for the next bake;
* a failed or early-cancelled re-bake keeps the previous good bake (frames, state, modifier);
* an open collider is an operator report, not only a Python warning;
* messages about geometry name the user's polygons and vertices.
"""
from __future__ import annotations

import os
import textwrap

import numpy as np
import pytest

pytest.importorskip("bpy")
pytest.importorskip("pxr")
from tearcloth import Cloth, cache  # noqa: E402

from test_blender_bake import cache_root, run_blender as _run_blender  # noqa: E402

# An operator that reports an ERROR raises RuntimeError in bpy: attempt() keeps the messages.
ATTEMPT = '''
def attempt(name, obj, **kwargs):
    try:
        return sorted(op(name, obj, **kwargs)), ""
    except RuntimeError as exc:
        return ["ERROR"], str(exc)
'''


def run_blender(tmp_path, body, *args, **kwargs):
    return _run_blender(tmp_path, ATTEMPT + textwrap.dedent(body), *args, **kwargs)


@pytest.mark.parametrize("count", [1, 2, 3])
def test_cloth_groups_of_every_count(count):
    """Cloth.group, pin and add_handle by group name with 1, 2 and 3 groups (the core hands one
    group back flat)."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)
    weights = {f"g{i}": np.array([1.0, 0.0, 0.25 * i, 0.5]) for i in range(count)}
    cloth = Cloth(v, [[0, 1, 2], [1, 3, 2]], groups=weights)
    assert cloth.groups.shape == (4, count)
    for name, w in weights.items():
        np.testing.assert_array_equal(cloth.group(name), w)
    cloth.pin("g0")
    h = cloth.add_handle(f"g{count - 1}")
    cloth.step(1e-3)
    assert np.isfinite(cloth.handle_force(h)).all()


ONE_GROUP = '''
    from tearcloth.blender import bake
    from tearcloth import cache
    folder, which = sys.argv[1], sys.argv[2]
    obj = build_scene(folder, frame_end=4)
    s = obj.tearcloth
    if which == "pins":      # pinned by one group, no handle
        s.handles.remove(0)
        obj.vertex_groups.remove(obj.vertex_groups["hand"])
    else:                    # one handle, no pins
        s.pin_group = ""
        obj.vertex_groups.remove(obj.vertex_groups["pins"])
    bpy.context.scene.frame_set(7)
    state = sorted(op("bake", obj))
    md = obj.modifiers["Tear Cloth"]
    result(dict(state=state, frame=bpy.context.scene.frame_current, running=list(bake.running),
                attached=md.cache_file is not None))
'''


@pytest.mark.parametrize("which", ["pins", "handle"])
def test_one_vertex_group_bakes(tmp_path, which):
    got = run_blender(tmp_path, ONE_GROUP, tmp_path, which)
    assert got["state"] == ["FINISHED"] and got["frame"] == 7 and got["running"] == [] and got["attached"]
    assert cache.cache_info(cache_root(tmp_path))["frames"] == [1, 2, 3, 4]


FAILURES = '''
    from tearcloth.blender import bake, jobs
    from tearcloth import cache
    folder = sys.argv[1]
    obj = build_scene(folder, frame_end=4)
    out = {}
    # a bake that fails inside the simulation's set-up (the core refuses a zero-area face) into a
    # cache folder that does not exist yet
    obj.tearcloth.cache_folder = os.path.join(folder, "new", "deeper")
    me = obj.data
    keep = tuple(me.vertices[1].co)
    me.vertices[1].co = me.vertices[0].co  # polygon 0 loses its area
    bpy.context.scene.frame_set(7)
    out["state"], out["error"] = attempt("bake", obj)
    out["frame"] = bpy.context.scene.frame_current
    out["running"] = list(bake.running) + list(jobs.live_sessions)
    out["new_folder"] = os.path.exists(os.path.join(folder, "new"))
    r = bake.Reports()
    try:
        bake.bake_object(bpy.context, obj, reports=r)
    except Exception as exc:
        out["raised"] = type(exc).__name__
    out["messages"] = r.items
    # the geometry fixed, the next bake runs (nothing still registered)
    me.vertices[1].co = keep
    out["after"] = sorted(op("bake", obj))
    result(out)
'''


def test_failed_bake_restores_frame_registry_and_leaves_no_files(tmp_path):
    got = run_blender(tmp_path, FAILURES, tmp_path)
    assert got["state"] == ["ERROR"] and "degenerate" in got["error"]
    assert got["frame"] == 7
    assert got["running"] == []
    assert not got["new_folder"], "the cache folder the failed attempt made is still there"
    errors = [m for level, m in got["messages"] if level == "ERROR"]
    assert errors and "degenerate" in errors[0], got["messages"]
    assert got["after"] == ["FINISHED"]


REBAKE = '''
    import bmesh, mathutils
    from tearcloth.blender import bake
    from tearcloth import cache
    folder = sys.argv[1]
    obj = build_scene(folder, frame_end=6)
    assert op("bake", obj) == {"FINISHED"}
    from tearcloth.blender import modifier
    path = modifier.cache_path(obj)
    state_path = path[:-len(".usda")] + ".state.npz"
    md = obj.modifiers["Tear Cloth"]

    def snapshot():
        info = cache.cache_info(path)
        frames = {f: cache.read_frame(path, f)[0].tolist() for f in info["frames"]}
        with open(state_path, "rb") as f:
            state = f.read()
        return dict(frames=frames, complete=info["complete"], state=hash(state),
                    attached=md.cache_file is not None and md.cache_file.filepath.endswith("Sheet.usda"),
                    listing=sorted(os.listdir(os.path.dirname(path))))

    good = snapshot()
    original = obj.data
    out = {}
    # 1. a zero-area face: refused by the core before any new frame
    obj.data = original.copy()
    obj.data.vertices[21].co = obj.data.vertices[20].co
    out["degenerate"] = dict(state=attempt("bake", obj), same=snapshot() == good)
    # 2. a non-manifold edge: a third face on an inner edge of the sheet
    obj.data = original.copy()
    bm = bmesh.new(); bm.from_mesh(obj.data); bm.verts.ensure_lookup_table()
    a, b = bm.verts[21], bm.verts[22]
    c = bm.verts.new((a.co + b.co) / 2 + mathutils.Vector((0.0, 0.05, 0.0)))
    bm.faces.new((a, b, c)); bm.to_mesh(obj.data); bm.free()
    out["non_manifold"] = dict(state=attempt("bake", obj), same=snapshot() == good)
    # 3. a good re-bake cancelled before its first simulated frame (Esc right after Bake)
    obj.data = original
    run = bake.BakeRun(bpy.context, obj)
    run.start_thread(bpy.context)
    run.stop()
    out["cancelled"] = dict(state=run.finish(bpy.context), same=snapshot() == good)
    # 4. a good re-bake cancelled after it simulated frames 2 and 3: the previous bake as it was
    r = bake.Reports()
    cut = bake.bake_object(bpy.context, obj, progress=lambda p: p.frame < 3, reports=r)
    out["cancelled_midway"] = dict(state=cut.state, frames=cut.frames, same=snapshot() == good, messages=r.items)
    # 5. a re-bake that fails at its fourth frame (the solver blows up): the same
    from tearcloth import session as session_mod
    from tearcloth.cloth import SimulationError
    step = session_mod.Session.step
    calls = [0]
    def failing(self, *a, **k):
        calls[0] += 1
        if calls[0] > 3 * obj.tearcloth.steps_per_frame:
            raise SimulationError("the step blew up (injected by the test)")
        return step(self, *a, **k)
    session_mod.Session.step = failing
    r = bake.Reports()
    try:
        failed = bake.bake_object(bpy.context, obj, reports=r)
    finally:
        session_mod.Session.step = step
    out["failed_midway"] = dict(state=failed.state, frames=failed.frames, same=snapshot() == good, messages=r.items)
    # 6. a re-bake that completes replaces the previous one
    done = bake.bake_object(bpy.context, obj)
    info = cache.cache_info(path)
    out["replaced"] = dict(state=done.state, frames=info["frames"], complete=info["complete"],
                           listing=sorted(os.listdir(os.path.dirname(path))))
    result(out)
'''


def test_failed_rebake_keeps_the_previous_bake(tmp_path):
    got = run_blender(tmp_path, REBAKE, tmp_path)
    for key in ("degenerate", "non_manifold"):
        assert got[key]["state"][0] == ["ERROR"], key
        assert got[key]["same"], f"{key}: the previous bake changed"
    assert got["cancelled"]["state"] == "cancelled" and got["cancelled"]["same"]
    # a re-bake cancelled or failing after it simulated frames: the previous bake, its resume
    # state and the folder's listing as they were (the snapshot compares all three), and said
    cancelled, failed = got["cancelled_midway"], got["failed_midway"]
    assert cancelled["state"] == "cancelled" and cancelled["frames"] == [] and cancelled["same"], cancelled
    assert any("previous bake is kept as it was" in m and "up to 3 are dropped" in m and "Resume" not in m
               for level, m in cancelled["messages"] if level == "WARNING"), cancelled["messages"]
    assert failed["state"] == "error" and failed["frames"] == [] and failed["same"], failed
    assert any("blew up" in m and "previous bake is kept as it was" in m
               for level, m in failed["messages"] if level == "ERROR"), failed["messages"]
    # a complete re-bake replaces it; nothing of the staged attempts is left beside the cache
    assert got["replaced"]["state"] == "done" and got["replaced"]["complete"]
    assert got["replaced"]["frames"] == [1, 2, 3, 4, 5, 6]
    assert got["replaced"]["listing"] == ["Sheet.state.npz", "Sheet.usda", "Sheet_frames"]


MESSAGES = '''
    import tearcloth
    folder = sys.argv[1]
    bpy.ops.wm.read_factory_settings(use_empty=True)
    tearcloth.register()
    # a loose vertex first (the solver drops it, so its numbering shifts by one) and 3 x 3 quads
    # (two solver triangles each): user vertex 1 + 4 x + z, polygon 3 x + z
    verts = [(5.0, 5.0, 5.0)] + [(0.1 * x, 0.0, 1.0 + 0.1 * z) for x in range(4) for z in range(4)]
    v = lambda x, z: 1 + 4 * x + z
    faces = [(v(x, z), v(x + 1, z), v(x + 1, z + 1), v(x, z + 1)) for x in range(3) for z in range(3)]
    mesh = bpy.data.meshes.new("Quads")
    mesh.from_pydata(verts, [], faces)
    obj = bpy.data.objects.new("Quads", mesh)
    bpy.context.scene.collection.objects.link(obj)
    assert op("enable", obj) == {"FINISHED"}
    obj.tearcloth.cache_folder = os.path.join(folder, "cache")
    obj.tearcloth.frame_end = 2
    mesh.vertices[v(2, 2)].co = mesh.vertices[v(2, 1)].co  # the edge between 10 and 11 collapses
    # everything selected, as a new primitive is
    import bmesh
    bpy.context.view_layer.objects.active = obj
    bpy.ops.object.mode_set(mode="EDIT"); bpy.ops.mesh.select_all(action="SELECT"); bpy.ops.object.mode_set(mode="OBJECT")
    state, message = attempt("bake", obj)
    out = dict(state=state, message=message, polygons=[p.index for p in mesh.polygons if p.select],
               vertices=[x.index for x in mesh.vertices if x.select], corners=list(mesh.polygons[4].vertices))
    # what the user sees on Tab: the culprit alone, its edges included (all stayed selected before)
    bpy.ops.object.mode_set(mode="EDIT")
    bm = bmesh.from_edit_mesh(mesh)
    out["edit"] = [sum(x.select for x in seq) for seq in (bm.verts, bm.edges, bm.faces)]
    out["edit_edges"] = sorted(sorted(x.index for x in e.verts) for e in bm.edges if e.select)
    bpy.ops.object.mode_set(mode="OBJECT")
    result(out)
'''


def test_geometry_messages_name_the_users_polygons_and_vertices(tmp_path):
    got = run_blender(tmp_path, MESSAGES, tmp_path)
    assert got["state"] == ["ERROR"]
    message = got["message"]
    # polygon 4 (quad x=1, z=1) is the first with a collapsed edge; its solver triangle is 8 or 9
    assert "polygon 4 " in message and "degenerate" in message, message
    assert "10" in message and "11" in message and "triangle" not in message, message
    # the core hands the elements over as data (.triangles, .vertices), mapped and selected
    assert got["polygons"] == [4] and got["vertices"] == sorted(got["corners"]), got
    corners = got["corners"]
    quad_edges = sorted(sorted((corners[k], corners[(k + 1) % 4])) for k in range(4))
    assert got["edit"][0] == 4 and got["edit"][2] == 1 and got["edit_edges"] == quad_edges, got


def test_a_message_worded_otherwise_still_names_the_users_elements():
    """The core's element list, not its wording, carries the indices: a message the patterns do
    not know gets the user's polygons and vertices appended."""
    import numpy as np

    from tearcloth.blender.report import user_culprits, user_geometry_message
    from tearcloth.cloth import Cloth, InvalidInputError

    with pytest.raises(InvalidInputError) as refused:
        Cloth(np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0]]), np.array([[3, 0, 1], [0, 1, 2]]))
    assert refused.value.triangles == (1,) and refused.value.vertices == (0, 1, 2)
    polygons, vertices = np.array([7, 8]), np.array([10, 11, 12, 13])
    culprits = user_culprits(refused.value, polygons, vertices)
    assert culprits == ([8], [10, 11, 12])
    assert user_geometry_message(str(refused.value), polygons, vertices, culprits).startswith("polygon 8 (vertices 10, 11, 12)")
    reworded = "element #1 has no area"
    assert user_geometry_message(reworded, polygons, vertices, culprits) == \
        "element #1 has no area (in your mesh: polygon 8; vertices 10, 11, 12)"


OPEN_COLLIDER = '''
    from tearcloth.blender import bake
    folder = sys.argv[1]
    obj = build_scene(folder, frame_end=2)
    bpy.ops.mesh.primitive_plane_add(size=2.0, location=(0.0, 0.0, 0.5))  # open: no inside
    plane = bpy.context.active_object
    s = obj.tearcloth
    s.use_collision = True
    s.colliders.add().object = plane
    r = bake.Reports()
    res = bake.bake_object(bpy.context, obj, reports=r)
    result(dict(state=res.state, warnings=r.warnings))
'''


def test_open_collider_is_a_report(tmp_path):
    got = run_blender(tmp_path, OPEN_COLLIDER, tmp_path)
    assert got["state"] == "done"
    assert any("not a closed" in w and "Plane" in w for w in got["warnings"]), got["warnings"]


IDENTITY = '''
    from tearcloth.blender import bake, modifier
    from tearcloth import cache
    folder = sys.argv[1]
    obj = build_scene(folder, name="MySheet", frame_end=3)
    assert op("bake", obj) == {"FINISHED"}
    bpy.ops.wm.save_mainfile()  # scene.blend, with the bake
    first = modifier.cache_path(obj)
    before = [cache.read_frame(first, f)[0].tolist() for f in (1, 2, 3)]

    def first_kept():  # the first bake still on disk, frame for frame
        return os.path.isfile(first) and [cache.read_frame(first, f)[0].tolist() for f in (1, 2, 3)] == before

    def duplicate(source, name):  # what Shift+D makes: custom properties and modifiers copied
        copy = source.copy()
        bpy.context.scene.collection.objects.link(copy)
        copy.name = name
        return copy
    out = dict(first=first, id=modifier.object_id(obj), owner=cache.cache_info(first)["owner"])
    # 1. the same file saved beside itself under another name: same object names, same ids
    bpy.ops.wm.save_as_mainfile(filepath=os.path.join(folder, "copy.blend"))
    obj.tearcloth.tear_stress = 2e6
    assert op("bake", obj) == {"FINISHED"}
    out["copy_path"] = modifier.cache_path(obj)
    out["first_kept"] = first_kept()
    # 2. rename the baked object, make a new one with its old name (a smaller sheet), bake it
    bpy.ops.wm.open_mainfile(filepath=os.path.join(folder, "scene.blend"))
    old = bpy.data.objects["MySheet"]
    old.name = "OldSheet"
    import mathutils
    new = bpy.data.objects.new("MySheet", old.data.copy())  # a new object (no id) given the old name
    new.data.transform(mathutils.Matrix.Scale(0.5, 4))
    bpy.context.scene.collection.objects.link(new)
    assert op("enable", new) == {"FINISHED"}
    new.tearcloth.frame_end = 3
    assert op("bake", new) == {"FINISHED"}
    out["new_path"] = modifier.cache_path(new)
    out["new_id"] = modifier.object_id(new)
    out["old_plays"] = modifier.attached_path(old)
    out["old_kept"] = first_kept()
    # 3. a duplicate (custom properties copied: the same id) bakes into its own cache
    dup = duplicate(old, "Dup")
    assert op("bake", dup) == {"FINISHED"}
    out["dup_id"] = modifier.object_id(dup)
    out["old_id"] = modifier.object_id(old)
    out["dup_path"] = modifier.cache_path(dup)
    out["old_kept_after_dup"] = first_kept()
    # 4. Free Bake on a duplicate that still shows its original's bake: it lets go, the bake stays
    twin = duplicate(old, "Twin")  # its modifier plays the same cache; the same id
    assert modifier.attached_path(twin) == first
    r = bake.Reports()
    out["twin_freed"] = bake.free_bake(twin, r)
    out["twin_messages"] = r.items
    out["twin_plays"] = modifier.attached_path(twin)
    out["old_plays_after_twin"] = modifier.attached_path(old)
    out["old_kept_after_twin"] = first_kept()
    # 5. a duplicate renamed to the name the original was baked under ("MySheet"), the original
    # renamed away and still showing that bake: the duplicate bakes into a cache of its own
    new.name = "NewSheet"
    swap = duplicate(old, "MySheet")
    swap.tearcloth.tear_stress = 3e6
    assert op("bake", swap) == {"FINISHED"}
    out["swap_id"] = modifier.object_id(swap)
    out["swap_path"] = modifier.cache_path(swap)
    out["old_plays_after_swap"] = modifier.attached_path(old)
    out["old_kept_after_swap"] = first_kept()
    result(out)
'''


def test_caches_never_collide_across_files_renames_and_duplicates(tmp_path):
    got = run_blender(tmp_path, IDENTITY, tmp_path)
    first = got["first"]
    assert first.endswith(os.path.join("tearcloth_cache", "scene", "MySheet.usda"))
    assert got["owner"]["object_id"] == got["id"] and got["owner"]["blend"].endswith("scene.blend")
    assert got["owner"]["settings"]
    # another file: its own folder, the first file's bake untouched
    assert got["copy_path"].endswith(os.path.join("tearcloth_cache", "copy", "MySheet.usda"))
    assert got["first_kept"]
    # a new object with the old name: its own file; the renamed one still plays its own bake
    assert got["new_id"] != got["id"]
    assert got["new_path"].endswith(f"MySheet-{got['new_id']}.usda")
    assert got["old_plays"] == first and got["old_kept"]
    # a duplicate gets an id of its own and a cache of its own
    assert got["dup_id"] not in (got["id"], got["new_id"]) and got["old_id"] == got["id"]
    assert got["dup_path"].endswith("Dup.usda") and got["old_kept_after_dup"]
    # Free Bake on a duplicate still showing its original's bake lets go of it, deletes nothing
    assert got["twin_freed"] and got["twin_plays"] is None
    assert got["old_plays_after_twin"] == first and got["old_kept_after_twin"]
    assert any("stays on disk for 'OldSheet'" in m for level, m in got["twin_messages"]), got["twin_messages"]
    # a duplicate that took the name the bake was made under gets its own id and cache
    assert got["swap_id"] != got["id"] and got["swap_path"].endswith(f"MySheet-{got['swap_id']}.usda")
    assert got["old_plays_after_swap"] == first and got["old_kept_after_swap"]


RENAMED = '''
    from tearcloth import cache
    from tearcloth.blender import bake, modifier
    folder = sys.argv[1]
    obj = build_scene(folder, name="MySheet", frame_end=5)
    assert op("bake", obj) == {"FINISHED"}
    first = modifier.cache_path(obj)
    before = [cache.read_frame(first, f)[0].tolist() for f in range(1, 6)]
    kept = lambda: os.path.isfile(first) and [cache.read_frame(first, f)[0].tolist() for f in range(1, 6)] == before
    obj.name = "Renamed"
    obj.tearcloth.tear_stress = 2e6  # the re-bake differs
    # 1. the re-bake under the new name cancelled after frame 3: the object still shows the bake
    # it had, the new frames wait at the new name's path
    r = bake.Reports()
    cut = bake.bake_object(bpy.context, obj, progress=lambda p: p.frame < 3, reports=r)
    out = dict(first=first, cut_state=cut.state, cut_frames=cut.frames, plays_after_cut=modifier.attached_path(obj),
               new=modifier.cache_path(obj), kept_after_cut=kept(), cut_messages=r.items)
    # 2. resumed to the end: the object shows the new bake; the old one stays on disk, said
    r = bake.Reports()
    done = bake.bake_object(bpy.context, obj, resume=True, reports=r)
    out.update(done_state=done.state, plays_after_done=modifier.attached_path(obj), kept_after_done=kept(),
               done_messages=r.items, new_frames=cache.cache_info(modifier.cache_path(obj))["frames"])
    result(out)
'''


def test_a_rebake_after_a_rename_replaces_the_shown_bake_only_once_complete(tmp_path):
    """A bake made under one name, the object renamed, re-baked: the new name's cache is another
    path, so the re-bake did not count as one - cancelled midway, it left the object showing its
    partial frames instead of the complete bake it had. Now, as for a re-bake at the same path,
    the object keeps showing its bake until the new one is complete (cancelled: said, the new
    frames wait for Resume), then shows the new one; the old files are never deleted (only Free
    Bake deletes), and where they stay is said."""
    got = run_blender(tmp_path, RENAMED, tmp_path)
    first, new = got["first"], got["new"]
    assert new != first and new.endswith("Renamed.usda")
    assert got["cut_state"] == "cancelled" and got["cut_frames"] == [1, 2, 3], got
    assert got["plays_after_cut"] == first and got["kept_after_cut"], got
    assert any("previous bake at" in m and "kept as it was" in m and "wait at" in m and "Resume continues it" in m
               for level, m in got["cut_messages"] if level == "WARNING"), got["cut_messages"]
    assert got["done_state"] == "done" and got["new_frames"] == [1, 2, 3, 4, 5], got
    assert got["plays_after_done"] == new and got["kept_after_done"], got
    assert any("stays on disk" in m and first in m for level, m in got["done_messages"] if level == "INFO"), \
        got["done_messages"]


EDIT_MODE = '''
    import bmesh
    from tearcloth.blender import modifier
    from tearcloth import cache
    folder = sys.argv[1]
    obj = build_scene(folder, frame_end=3)
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    bpy.ops.object.mode_set(mode="EDIT")
    bm = bmesh.from_edit_mesh(obj.data)  # an edit not yet written back to the mesh
    bm.verts.ensure_lookup_table()
    bm.verts[0].co.y += 0.01
    bmesh.update_edit_mesh(obj.data)
    state = sorted(op("bake", obj))
    path = modifier.cache_path(obj)
    positions, triangles, uv = cache.read_frame(path, 1)
    result(dict(state=state, mode=obj.mode, y0=float(positions[0][1]), has_uv=uv is not None,
                n=len(positions)))
'''


def test_bake_in_edit_mode_takes_the_edit_mesh(tmp_path):
    got = run_blender(tmp_path, EDIT_MODE, tmp_path)
    assert got["state"] == ["FINISHED"] and got["mode"] == "EDIT"
    assert got["n"] == 400 and got["has_uv"]
    assert got["y0"] == pytest.approx(0.01, abs=1e-6)  # the edit-mode position, not the saved one


TRUNCATED = '''
    from tearcloth.blender import bake, modifier
    from tearcloth import cache
    folder = sys.argv[1]
    obj = build_scene(folder, frame_end=6)
    run = bake.bake_object(bpy.context, obj, progress=lambda p: p.frame < 4)  # interrupted at frame 4
    path = modifier.cache_path(obj)
    def truncate():
        with open(path, "rb") as f:
            text = f.read()
        with open(path, "wb") as f:
            f.write(text[: len(text) // 2])
    truncate()
    out = dict(first=run.state, damaged=cache.damaged_root(path))
    r = bake.Reports()
    resumed = bake.bake_object(bpy.context, obj, resume=True, reports=r)
    info = cache.cache_info(path)
    out["resume"] = dict(state=resumed.state, frames=info["frames"], complete=info["complete"], warnings=r.warnings,
                         readable=all(len(cache.read_frame(path, f)[0]) >= 400 for f in info["frames"]))
    truncate()
    out["free"] = attempt("free_bake", obj)
    out["left"] = sorted(os.listdir(os.path.dirname(path)))
    result(out)
'''


def test_truncated_root_is_rebuilt_or_freed(tmp_path):
    got = run_blender(tmp_path, TRUNCATED, tmp_path)
    assert got["first"] == "cancelled" and got["damaged"]
    res = got["resume"]
    assert res["state"] == "done" and res["frames"] == [1, 2, 3, 4, 5, 6] and res["complete"] and res["readable"]
    assert any("damaged" in w and "rebuilt" in w and "frames 1-4" in w for w in res["warnings"]), res["warnings"]
    assert got["free"][0] == ["FINISHED"]
    assert got["left"] == []  # root, frames and resume state gone


VALUES = '''
    from tearcloth.blender import bake
    folder = sys.argv[1]
    obj = build_scene(folder, frame_end=2)
    s = obj.tearcloth
    out = {}
    for name, value in (("young", 0.0), ("poisson", 0.5), ("density", 0.0), ("thickness", -0.001),
                        ("tear_stress", -5.0)):
        keep = getattr(s, name)
        setattr(s, name, value)
        out[name] = attempt("bake", obj)
        setattr(s, name, keep)
    s.young = 100.0  # possible, but no cloth is that soft
    r = bake.Reports()
    out["soft"] = dict(state=bake.bake_object(bpy.context, obj, reports=r).state, warnings=r.warnings)
    result(out)
'''


def test_absurd_values_are_refused_and_suspicious_ones_warned(tmp_path):
    got = run_blender(tmp_path, VALUES, tmp_path)
    for name, shown in (("young", "young = 0.0 Pa"), ("poisson", "poisson = 0.5"), ("density", "density = 0.0"),
                        ("thickness", "thickness = 0.0 m"), ("tear_stress", "tear_stress = 0.0 Pa")):
        state, message = got[name]
        assert state == ["ERROR"] and shown in message and "hard bounds" in message, (name, message)
    soft = got["soft"]
    assert soft["state"] == "done"
    assert any("young = 100.0 Pa is unusual" in w for w in soft["warnings"]), soft["warnings"]


UNITS = '''
    import tearcloth
    from tearcloth.blender import convert
    out = {}
    for scale in (1.0, 0.01):
        bpy.ops.wm.read_factory_settings(use_empty=True)
        tearcloth.register()
        scene = bpy.context.scene
        scene.unit_settings.scale_length = scale
        bpy.ops.mesh.primitive_plane_add()
        obj = bpy.context.active_object
        assert op("enable", obj) == {"FINISHED"}
        s = obj.tearcloth
        fresh = dict(thickness=s.thickness, collision=s.collision_thickness, threshold=s.displacement_threshold,
                     si=convert.material_from_settings(s, scene).thickness)
        # lengths a user types in scene units: 2 cm of thickness and a 5 cm tear radius are kept
        # whatever the unit scale (a cap of 1 BU clamped them to 1 cm in a centimetre scene)
        s.thickness, s.tear_radius = 0.02 / scale, 0.05 / scale
        si = convert.material_from_settings(s, scene)
        out[str(scale)] = dict(fresh=fresh, typed=(si.thickness, si.tear_radius))
        s.thickness = 1.0  # a preset writes physical values through the scene's units
        assert op("material_preset", obj, preset="cotton") == {"FINISHED"}
        out[str(scale)]["preset"] = s.thickness
    result(out)
'''


def test_defaults_and_presets_follow_the_scene_unit_scale(tmp_path):
    got = run_blender(tmp_path, UNITS)
    metre, cm = got["1.0"], got["0.01"]
    assert metre["fresh"]["thickness"] == pytest.approx(4e-4)
    for key in ("thickness", "collision", "threshold"):
        assert cm["fresh"][key] == pytest.approx(metre["fresh"][key] / 0.01), key  # 0.4 mm is 0.04 cm
    assert cm["fresh"]["si"] == pytest.approx(4e-4) and metre["fresh"]["si"] == pytest.approx(4e-4)
    assert cm["preset"] == pytest.approx(0.04) and metre["preset"] == pytest.approx(4e-4)
    for got_scale in (metre, cm):
        assert got_scale["typed"] == pytest.approx((0.02, 0.05)), got_scale["typed"]


UV_BAKE = '''
    from tearcloth.blender import bake, modifier
    folder = sys.argv[1]
    obj = build_scene(folder, frame_end=12)
    obj.data.uv_layers.new(name="Second")  # added after UVMap; UVMap stays the active one
    r = bake.Reports()
    res = bake.bake_object(bpy.context, obj, reports=r)
    bpy.ops.wm.save_mainfile()
    result(dict(state=res.state, warnings=r.warnings, path=modifier.cache_path(obj)))
'''

UV_PLAY = '''
    bpy.ops.wm.open_mainfile(filepath=sys.argv[1])
    assert "tearcloth" not in sys.modules
    obj = bpy.data.objects["Sheet"]
    bpy.context.scene.frame_set(12)
    ev = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    m = ev.to_mesh()
    uv = np.empty(2 * len(m.loops), np.float32)
    m.uv_layers["UVMap"].data.foreach_get("uv", uv)
    result(dict(names=[u.name for u in m.uv_layers], active=m.uv_layers.active.name, n=len(m.vertices),
                loops=len(m.loops), uv=uv.tolist()))
'''


def test_uvs_arrive_under_the_users_name(tmp_path):
    baked = run_blender(tmp_path, UV_BAKE, tmp_path)
    assert baked["state"] == "done"
    # every UV map is carried now (test_blender_attributes.py checks the values): nothing to warn about
    assert not any("'Second'" in w for w in baked["warnings"]), baked["warnings"]
    played = run_blender(tmp_path, UV_PLAY, tmp_path / "scene.blend", name="play.py")
    positions, triangles, corner_uv = cache.read_frame(baked["path"], 12)
    assert played["n"] > 400, "the sheet should have torn by frame 12"
    # the user's map, active, and the other one under its name
    assert played["names"][:2] == ["UVMap", "Second"] and played["active"] == "UVMap"
    uv = np.array(played["uv"]).reshape(-1, 2)
    assert len(uv) == 3 * len(triangles) and np.abs(uv).max() > 0.5  # real UVs, not a layer of zeros
    np.testing.assert_allclose(uv, corner_uv.reshape(-1, 2), atol=1e-6)


PRESETS = '''
    import tearcloth
    from tearcloth.blender import convert, ui
    out = {}
    def sheet(scale):
        bpy.ops.wm.read_factory_settings(use_empty=True)
        tearcloth.register()
        bpy.context.scene.unit_settings.scale_length = scale
        bpy.ops.mesh.primitive_plane_add()
        obj = bpy.context.active_object
        assert op("enable", obj) == {"FINISHED"}
        return obj
    obj = sheet(0.01)  # saved from a centimetre scene ...
    s = obj.tearcloth
    s.young, s.tear_stress, s.thickness = 2.5e6, 1.5e6, 0.12  # 0.12 cm = 1.2 mm felt
    with bpy.context.temp_override(object=obj, active_object=obj):
        assert bpy.ops.tearcloth.material_preset_save(name="My Felt") == {"FINISHED"}
    path = bpy.utils.preset_find("My Felt", ui.PRESET_SUBDIR, display_name=True)  # as the menu lists it
    obj = sheet(1.0)  # ... applied in a metre scene, through Blender's own preset operator
    with bpy.context.temp_override(object=obj, active_object=obj):
        state = bpy.ops.script.execute_preset(filepath=path, menu_idname="TEARCLOTH_MT_material_presets")
    m = convert.material_from_settings(obj.tearcloth, bpy.context.scene)
    result(dict(path=path, state=sorted(state), young=m.young, tear=m.tear_stress, thickness=m.thickness,
                name=obj.tearcloth.material_preset))
'''


def test_users_save_and_share_material_presets(tmp_path, monkeypatch):
    monkeypatch.setenv("BLENDER_USER_SCRIPTS", str(tmp_path / "scripts"))  # not the machine's own folder
    got = run_blender(tmp_path, PRESETS)
    assert got["path"].startswith(str(tmp_path / "scripts")) and got["path"].endswith(".py")
    assert got["state"] == ["FINISHED"] and got["name"] == "My Felt"
    assert got["young"] == pytest.approx(2.5e6) and got["tear"] == pytest.approx(1.5e6)
    assert got["thickness"] == pytest.approx(1.2e-3)  # metres, whatever the scene's unit scale


FOLDERS_AND_SCALES = '''
    from tearcloth.blender import bake, modifier
    folder = sys.argv[1]
    obj = build_scene(folder, frame_end=3)  # saved as scene.blend in folder
    out = {}
    # a cache folder typed without "//": beside the .blend, as "//" is; "~": the user's home
    for typed in ("mycache", "./mycache/", "~/homecache"):
        os.environ["HOME"] = os.path.join(folder, "home")
        obj.tearcloth.cache_folder = typed
        out[typed] = modifier.cache_path(obj)
    obj.tearcloth.cache_folder = "mycache"
    r = bake.bake_object(bpy.context, obj)
    out["baked"] = (r.state, r.cache_path)
    # the object's scale reaching zero on Y at frame 3 (keyframed): a message naming it all
    obj.scale = (1.0, 1.0, 1.0)
    obj.keyframe_insert("scale", frame=1)
    obj.scale = (1.0, 0.0, 1.0)
    obj.keyframe_insert("scale", frame=3)
    r = bake.Reports()
    try:
        got = bake.bake_object(bpy.context, obj, reports=r)
        out["zero_scale"] = (got.state, got.frames, r.items)
    except bake.BakeError as exc:
        out["zero_scale"] = ("refused", [], [["ERROR", str(exc)]])
    result(out)
'''


def test_cache_folders_as_typed_and_a_zero_scale_are_understood(tmp_path):
    got = run_blender(tmp_path, FOLDERS_AND_SCALES, tmp_path)
    beside = os.path.join(str(tmp_path), "mycache", "scene")
    assert os.path.dirname(got["mycache"]) == beside and os.path.dirname(got["./mycache/"]) == beside, got
    assert os.path.dirname(got["~/homecache"]) == os.path.join(str(tmp_path), "home", "homecache", "scene"), got
    assert got["baked"][0] == "done" and os.path.dirname(got["baked"][1]) == beside
    state, frames, messages = got["zero_scale"]
    assert state == "error" and frames == [], got["zero_scale"]
    assert any("its scale is zero on Y at frame 3" in m and "Singular" not in m for level, m in messages
               if level == "ERROR"), messages


SAID_ONCE = '''
    from tearcloth.blender import bake
    folder = sys.argv[1]
    obj = build_scene(folder, frame_end=2)
    obj.tearcloth.thickness = 1e-6  # inside the hard bounds, below the soft ones: unusual
    r = bake.Reports()
    state = bake.bake_object(bpy.context, obj, reports=r).state
    freed = []
    for _ in range(2):
        f = bake.Reports()
        bake.free_bake(obj, f)
        freed.append(f.items)
    result(dict(state=state, warnings=r.warnings, freed=freed))
'''


def test_a_warning_is_said_once_with_the_name_and_a_second_free_says_there_is_nothing(tmp_path):
    got = run_blender(tmp_path, SAID_ONCE, tmp_path)
    assert got["state"] == "done"
    unusual = [w for w in got["warnings"] if "thickness" in w and "unusual" in w]
    assert len(unusual) == 1 and unusual[0].startswith("Sheet: "), got["warnings"]
    first, second = got["freed"]
    assert any("freed the bake at" in m for _, m in first), first
    assert any("no bake to free" in m for _, m in second) and not any("freed" in m for _, m in second), second


RENUMBERED = '''
    from tearcloth.blender import bake
    folder = sys.argv[1]
    obj = build_scene(folder, n=8, frame_end=2)
    me = obj.data
    corners = list(me.polygons[5].vertices)
    for v in corners[1:]:  # one quad collapsed to a point: degenerate, subdivided or not
        me.vertices[v].co = me.vertices[corners[0]].co
    sub = obj.modifiers.new("Subdivision", "SUBSURF")
    sub.subdivision_type = "SIMPLE"  # (Catmull-Clark would pull the collapsed corners apart)
    obj.modifiers.move(len(obj.modifiers) - 1, 0)  # above Tear Cloth: it makes the rest mesh
    out = {}
    for above in (True, False):
        sub.show_viewport = above
        r = bake.Reports()
        try:
            bake.bake_object(bpy.context, obj, reports=r)
        except bake.BakeError:
            pass
        out[str(above)] = r.items
    result(out)
'''


def test_elements_numbered_by_the_modifiers_above_are_said_to_be_theirs(tmp_path):
    got = run_blender(tmp_path, RENUMBERED, tmp_path)
    above = [m for level, m in got["True"] if level == "ERROR"]
    assert any("degenerate" in m and "modifiers above Tear Cloth make: Subdivision" in m for m in above), got["True"]
    assert not any("selected" in m for _, m in got["True"]), got["True"]  # not the user's elements
    plain = [m for level, m in got["False"] if level == "ERROR"]
    # without it: the user's own numbers (the collapsed quad's neighbours are degenerate too), selected
    assert any("degenerate" in m and "modifiers above" not in m for m in plain), got["False"]
    assert any("selected polygon" in m for _, m in got["False"]), got["False"]


RENAMED_MODIFIER = '''
    from tearcloth.blender import bake, modifier
    folder = sys.argv[1]
    obj = build_scene(folder, frame_end=2)
    assert op("bake", obj) == {"FINISHED"}
    path = modifier.cache_path(obj)
    md = modifier.find_modifier(obj)
    md.name = "My Cache"  # the user renames the baked modifier: Tear Cloth no longer finds it
    out = dict(enabled=modifier.is_enabled(obj))
    # Enable takes it back under its name instead of adding a second one below it
    out["enable"] = sorted(op("enable", obj))
    out["names"] = [m.name for m in obj.modifiers]
    out["plays"] = modifier.attached_path(obj) == path
    # a copy of it moved above Tear Cloth: refused, named, rather than baked from a baked frame
    copy = obj.modifiers.new("Old Bake", "MESH_SEQUENCE_CACHE")
    copy.cache_file = modifier.find_modifier(obj).cache_file
    obj.modifiers.move(len(obj.modifiers) - 1, 0)
    r = bake.Reports()
    try:
        bake.bake_object(bpy.context, obj, reports=r)
        out["above"] = "baked"
    except bake.BakeError as exc:
        out["above"] = str(exc)
    result(out)
'''


def test_a_renamed_tear_cloth_modifier_is_taken_back_and_a_bake_above_is_refused(tmp_path):
    got = run_blender(tmp_path, RENAMED_MODIFIER, tmp_path)
    assert got["enabled"] is False and got["enable"] == ["FINISHED"]
    assert got["names"] == ["Tear Cloth"] and got["plays"], got
    assert "'Old Bake' above 'Tear Cloth' plays a Tear Cloth bake" in got["above"], got["above"]


COMMA_NAME = '''
    import types
    from pathlib import Path
    from tearcloth.blender import headless
    folder = sys.argv[1]
    obj = build_scene(folder, name="Sheet, Left", frame_end=2)
    # what `tearcloth bake --objects "Sheet, Left"` hands over after splitting at the comma
    plan = types.SimpleNamespace(objects=["Sheet", "Left"], source=Path(bpy.data.filepath))
    out = dict(picked=headless._pick_objects(plan))
    plan.objects = ["Nope"]
    try:
        headless._pick_objects(plan)
    except headless.InputError as exc:
        out["missing"] = str(exc)
    result(out)
'''


def test_an_object_name_with_a_comma_is_found_by_the_cli(tmp_path):
    got = run_blender(tmp_path, COMMA_NAME, tmp_path)
    assert got["picked"] == ["Sheet, Left"]
    assert "no object named 'Nope'" in got["missing"]


COPY_FREE = '''
    from tearcloth import cache
    from tearcloth.blender import bake, modifier
    folder = sys.argv[1]
    a_dir, b_dir = os.path.join(folder, "A"), os.path.join(folder, "B")
    os.makedirs(a_dir); os.makedirs(b_dir)
    obj = build_scene(a_dir, frame_end=4)
    assert op("bake", obj) == {"FINISHED"}
    bpy.ops.wm.save_mainfile()
    first = modifier.cache_path(obj)
    # Save As into another folder: the copy plays the first file's bake; its Free Bake lets go of it
    bpy.ops.wm.save_as_mainfile(filepath=os.path.join(b_dir, "copy.blend"))
    obj = bpy.data.objects["Sheet"]
    plays_in_copy = modifier.attached_path(obj)
    resume_in_copy = attempt("bake", obj, resume=True)  # (said: this file is a copy, not "renamed")
    r = bake.Reports()
    freed = bake.free_bake(obj, r)
    out = dict(first=first, plays_in_copy=plays_in_copy, resume_in_copy=resume_in_copy, freed=freed,
               plays_after=modifier.attached_path(obj),
               kept=os.path.isfile(first) and cache.cache_info(first)["frames"], messages=r.items)
    # back in the first file: a Free Bake the system refuses (a file that cannot be deleted) leaves
    # the object showing its bake and says why, no traceback
    bpy.ops.wm.open_mainfile(filepath=os.path.join(a_dir, "scene.blend"))
    import tearcloth
    obj = bpy.data.objects["Sheet"]
    real = cache._remove_quietly
    def refuse(path):
        raise PermissionError(13, "Permission denied", path)
    cache._remove_quietly = refuse
    r = bake.Reports()
    failed = bake.free_bake(obj, r)
    cache._remove_quietly = real
    out.update(failed=failed, plays_after_failed=modifier.attached_path(obj), failed_messages=r.items,
               kept_after_failed=cache.cache_info(first)["frames"])
    # and the first file's own Free Bake deletes it
    r = bake.Reports()
    out.update(own=bake.free_bake(obj, r), gone=not os.path.exists(first))
    result(out)
'''


def test_free_bake_in_a_copy_of_the_file_keeps_the_originals_bake(tmp_path):
    """A .blend saved as a copy (or an object appended from it) plays the first file's bake; Free
    Bake there deleted that bake, which the first file still plays. Now the copy only lets go of it
    and says whose it is; the first file's Free Bake deletes it. A Free Bake the system refuses
    half way (a read-only folder) left the object detached and showed a raw PermissionError: now
    nothing is deleted that cannot be, the object shows its bake as before, and one line says why."""
    got = run_blender(tmp_path, COPY_FREE, tmp_path)
    assert got["plays_in_copy"] == got["first"]
    states, message = got["resume_in_copy"]
    assert states == ["ERROR"] and "was baked by" in message and "this file is a copy of it" in message, message
    assert got["freed"] and got["plays_after"] is None
    assert got["kept"] == [1, 2, 3, 4]
    assert any("stays on disk" in m and "scene.blend" in m for _, m in got["messages"]), got["messages"]
    assert not got["failed"] and got["plays_after_failed"] == got["first"]
    assert got["kept_after_failed"] == [1, 2, 3, 4]
    assert any(level == "ERROR" and "could not free" in m and "Permission denied" in m
               for level, m in got["failed_messages"]), got["failed_messages"]
    assert got["own"] and got["gone"]


FRAMES_READ_ONLY = '''
    from tearcloth import cache
    from tearcloth.blender import bake, inputs, modifier
    folder = sys.argv[1]
    obj = build_scene(folder, frame_end=4)
    assert op("bake", obj) == {"FINISHED"}
    first = modifier.cache_path(obj)
    before = [cache.read_frame(first, f)[0].tolist() for f in range(1, 5)]
    # the frames folder refuses new files (as a read-only folder does to a user who is not root)
    real = inputs.tempfile.TemporaryFile
    frames = os.path.abspath(cache.frames_dir_for(first))
    def refuse(*args, dir=None, **kwargs):
        if dir is not None and os.path.abspath(dir) == frames:
            raise PermissionError(13, "Permission denied", dir)
        return real(*args, dir=dir, **kwargs)
    inputs.tempfile.TemporaryFile = refuse
    obj.tearcloth.tear_stress = 2e6
    r = bake.Reports()
    try:
        bake.bake_object(bpy.context, obj, reports=r)
        state = "done"
    except bake.BakeError as exc:
        state = "error: " + str(exc)
    inputs.tempfile.TemporaryFile = real
    result(dict(state=state, messages=r.items, plays=modifier.attached_path(obj), first=first,
                kept=[cache.read_frame(first, f)[0].tolist() for f in range(1, 5)] == before))
'''


def test_a_rebake_into_a_frames_folder_that_refuses_files_is_refused_first(tmp_path):
    """Only the cache's folder was tested for writing: a re-bake whose frames folder refused new
    files ran the whole simulation, then deleted the old root and failed moving the frames in ('no
    frame written'), and the object played nothing. Now the frames folder is tried first: the
    re-bake is refused in one line and the old bake stays, playing."""
    got = run_blender(tmp_path, FRAMES_READ_ONLY, tmp_path)
    assert got["state"].startswith("error"), got
    assert any(level == "ERROR" and "frames folder" in m and "not writable" in m for level, m in got["messages"]), \
        got["messages"]
    assert got["plays"] == got["first"] and got["kept"]


DAMAGED_MIDDLE = '''
    from tearcloth import cache
    from tearcloth.blender import bake, modifier
    folder = sys.argv[1]
    obj = build_scene(folder, frame_end=6)
    cut = bake.bake_object(bpy.context, obj, progress=lambda p: p.frame < 4)
    path = modifier.cache_path(obj)
    third = os.path.join(cache.frames_dir_for(path), "frame_000003.usdc")
    with open(third, "rb") as f:
        data = f.read()
    with open(third, "wb") as f:
        f.write(data[:len(data) // 3])  # cut short (a full disk, a copy stopped half way)
    r = bake.Reports()
    try:
        bake.bake_object(bpy.context, obj, resume=True, reports=r)
        state = "done"
    except bake.BakeError as exc:
        state = "error: " + str(exc)
    info = cache.cache_info(path)
    result(dict(cut=cut.frames, state=state, frames=info["frames"], complete=info["complete"]))
'''


def test_a_damaged_frame_before_the_resume_state_refuses_the_resume(tmp_path):
    """A bake stopped after frame 4 whose frame 3 was then cut short: Resume kept frames 1-2,
    deleted 3, continued from the state at frame 4 and called the bake of frames 1-6 complete,
    frame 3 missing (stock playback interpolated over it). The state cannot go back to frame 3:
    the resume is refused, saying which frame, and the cache is not marked complete."""
    got = run_blender(tmp_path, DAMAGED_MIDDLE, tmp_path)
    assert got["cut"] == [1, 2, 3, 4]
    assert got["state"].startswith("error") and "frame 3 is damaged or missing" in got["state"], got["state"]
    assert "bake again from the start" in got["state"]
    assert not got["complete"] and 3 not in got["frames"]


SHARED_FOLDER = '''
    from tearcloth import cache
    from tearcloth.blender import bake, modifier
    folder = sys.argv[1]
    shared = os.path.join(folder, "shared_cache")
    out = {}
    for name in ("A", "B"):
        os.makedirs(os.path.join(folder, name))
        # two separate files of the same name, one absolute cache folder, one object name, one mesh
        obj = build_scene(os.path.join(folder, name), frame_end=4, tear_stress=5e6 if name == "A" else 2e6)
        obj.tearcloth.cache_folder = shared
        assert op("bake", obj) == {"FINISHED"}
        bpy.ops.wm.save_mainfile()
        path = modifier.cache_path(obj)
        out[name] = dict(path=path, plays=modifier.attached_path(obj),
                         frames=[cache.read_frame(path, f)[0].tolist() for f in range(1, 5)])
    a = out["A"]["path"]
    out["A_after"] = [cache.read_frame(a, f)[0].tolist() for f in range(1, 5)]
    result(out)
'''


def test_two_files_of_one_name_never_share_a_cache_in_one_absolute_folder(tmp_path):
    """A/scene.blend and B/scene.blend (separate files, an object 'Sheet' with the same mesh in
    each) with the same absolute cache folder: B's object adopted the id A's cache recorded, baked
    into A's file and replaced A's frames (A then played B's bake). The id a cache records is now
    adopted only by its own file; B bakes a file of its own, A's frames stay."""
    got = run_blender(tmp_path, SHARED_FOLDER, tmp_path)
    assert got["A"]["path"] != got["B"]["path"]
    assert got["B"]["plays"] == got["B"]["path"]
    assert got["A_after"] == got["A"]["frames"]


LINKED = '''
    from tearcloth import cache
    from tearcloth.blender import bake, modifier
    folder = sys.argv[1]
    a_dir, c_dir = os.path.join(folder, "A"), os.path.join(folder, "C")
    os.makedirs(a_dir); os.makedirs(c_dir)
    obj = build_scene(a_dir, frame_end=3)
    assert op("bake", obj) == {"FINISHED"}
    bpy.ops.wm.save_mainfile()
    local = build_scene(c_dir, n=12, frame_end=3)  # C's own 'Sheet', baked
    assert op("bake", local) == {"FINISHED"}
    bpy.ops.wm.save_mainfile()
    own = modifier.cache_path(local)
    before = [cache.read_frame(own, f)[0].tolist() for f in range(1, 4)]
    local.tearcloth.tear_stress = 1e6  # an edit not baked yet
    with bpy.data.libraries.load(os.path.join(a_dir, "scene.blend"), link=True) as (src, dst):
        dst.objects = ["Sheet"]
    linked = dst.objects[0]
    bpy.context.scene.collection.objects.link(linked)
    bpy.context.view_layer.objects.active = linked
    out = dict(bake=attempt("bake", linked), free=attempt("free_bake", linked))
    out["own_kept"] = [cache.read_frame(own, f)[0].tolist() for f in range(1, 4)] == before
    out["own_plays"] = modifier.attached_path(local) == own
    result(out)
'''


def test_a_linked_object_with_a_local_ones_name_is_refused_not_mistaken(tmp_path):
    """Bake on an object linked from another file, while this file has a local object of the same
    name: the add-on finds objects by name, so the local one was re-baked (its bake replaced by one
    with an edit the user had not baked) and Free Bake talked of the local one. A linked object's
    bake belongs to its library: Bake and Free Bake refuse it, naming the library, and the local
    object's bake is untouched."""
    got = run_blender(tmp_path, LINKED, tmp_path)
    for key in ("bake", "free"):
        states, message = got[key]
        assert states == ["ERROR"] and "is linked from" in message and "scene.blend" in message, got[key]
    assert got["own_kept"] and got["own_plays"]


DAMAGED_OTHERS = '''
    import mathutils
    from tearcloth import cache
    from tearcloth.blender import bake, modifier
    folder = sys.argv[1]
    a = build_scene(folder, frame_end=3)
    assert op("bake", a) == {"FINISHED"}
    path = modifier.attached_path(a)
    frames = cache.frames_dir_for(path)
    before = {name: open(os.path.join(frames, name), "rb").read() for name in sorted(os.listdir(frames))}
    with open(path, "rb") as f:
        text = f.read()
    with open(path, "wb") as f:
        f.write(text[:len(text) // 2])  # the root cut short
    a.name = "OldSheet"
    b = bpy.data.objects.new("Sheet", a.data.copy())  # a newcomer takes the old name
    bpy.context.scene.collection.objects.link(b)
    b.data.transform(mathutils.Matrix.Scale(0.5, 4))
    op("enable", b); b.tearcloth.pin_group = "pins"; b.tearcloth.frame_end = 3
    out = dict(bake=attempt("bake", b), path=path, a_plays=modifier.attached_path(a),
               b_id=modifier.object_id(b))  # a refused first bake gives the object no id
    out["frames_kept"] = {name: open(os.path.join(frames, name), "rb").read() for name in sorted(os.listdir(frames))} == before
    # its owner re-bakes (into its new name's file); then the newcomer may have the old path
    out["owner"] = attempt("bake", a)
    out["owner_frames"] = cache.cache_info(modifier.attached_path(a))["frames"]
    out["newcomer"] = attempt("bake", b)
    result(out)
'''


def test_a_damaged_root_another_object_plays_is_not_taken_over(tmp_path):
    """A cache root cut short cannot say whose bake it is (the id that keeps a renamed object's
    bake from a newcomer of its old name is in it): a new object named as the old one was 'rebuilt'
    it for itself and baked over the frames the renamed object still played. The one that plays it
    owns it: the newcomer's bake is refused, naming it, and the frames stay; the owner's bake
    goes on."""
    got = run_blender(tmp_path, DAMAGED_OTHERS, tmp_path)
    states, message = got["bake"]
    assert states == ["ERROR"] and "is damaged" in message and "'OldSheet'" in message, got["bake"]
    assert got["frames_kept"] and got["a_plays"] == got["path"]
    assert got["b_id"] == ""  # the refused attempt left the newcomer as it was
    assert got["owner"][0] == ["FINISHED"] and got["owner_frames"] == [1, 2, 3]
    assert got["newcomer"][0] == ["FINISHED"], got["newcomer"]


NAN_AND_LOOSE_HANDLE = '''
    from tearcloth.blender import bake
    folder = sys.argv[1]
    obj = build_scene(folder, frame_end=3)
    out = {}
    co = np.empty(3 * len(obj.data.vertices), np.float32)
    obj.data.vertices.foreach_get("co", co)
    stray = co.copy()
    stray[3 * 25 + 2] = np.inf  # a script's stray value (RNA's co setter would clamp it to 3.4e38)
    obj.data.vertices.foreach_set("co", stray)
    obj.data.update()
    out["inf"] = attempt("bake", obj)
    obj.data.vertices.foreach_set("co", co)
    obj.data.update()
    # the handle's group holds two loose vertices only (a hand added beside the sheet)
    import bmesh
    bm = bmesh.new(); bm.from_mesh(obj.data)
    extra = [bm.verts.new((0.9, 0.0, 0.5)), bm.verts.new((0.95, 0.0, 0.5))]
    bm.to_mesh(obj.data); bm.free()
    group = obj.vertex_groups.new(name="loose_hand")
    group.add([len(obj.data.vertices) - 2, len(obj.data.vertices) - 1], 1.0, "REPLACE")
    obj.tearcloth.handles[0].vertex_group = "loose_hand"
    out["loose_hand"] = attempt("bake", obj)
    # the handle grasps the pinned corners: it moves them (said), the pins do not hold them
    obj.tearcloth.handles[0].vertex_group = "pins"
    r = bake.Reports()
    bake.bake_object(bpy.context, obj, reports=r)
    out["pinned_handle"] = r.items
    result(out)
'''


def test_a_non_finite_position_and_a_handle_of_loose_vertices_are_said_plainly(tmp_path):
    """A NaN or infinite vertex position was said as 'vertex group '.tearcloth:rest:x': vertex 25
    has a non-finite weight' (an internal group, a coordinate called a weight, the wrong axis), with
    numpy's matmul warning beside it; a handle group holding only loose vertices was said to have
    'no vertex with weight 0.5 or more' though both had weight 1; a handle that grasps pinned
    vertices moved them with nothing said."""
    got = run_blender(tmp_path, NAN_AND_LOOSE_HANDLE, tmp_path)
    states, message = got["inf"]
    assert states == ["ERROR"] and "vertex 25 has a non-finite position" in message and "inf" in message, message
    assert ".tearcloth" not in message and "weight" not in message and "matmul" not in message
    states, message = got["loose_hand"]
    assert states == ["ERROR"] and "'loose_hand' holds only loose vertices" in message, message
    assert any(level == "WARNING" and "pinned vertices are also in handle 1's group 'pins'" in m
               and "the pin does not hold" in m for level, m in got["pinned_handle"]), got["pinned_handle"]


SEAM = '''
    from tearcloth.blender import bake
    folder = sys.argv[1]
    obj = build_scene(folder, frame_end=2)
    out = {}
    r = bake.Reports()
    bake.bake_object(bpy.context, obj, reports=r)
    out["welded"] = r.items
    # the sheet cut down its middle column into two islands whose rims coincide (a seam not merged)
    import bmesh
    bm = bmesh.new(); bm.from_mesh(obj.data)
    bm.verts.ensure_lookup_table()
    xs = sorted({round(v.co.x, 6) for v in bm.verts})
    mid = xs[len(xs) // 2]
    middle = [e for e in bm.edges if all(abs(v.co.x - mid) < 1e-6 for v in e.verts)]
    bmesh.ops.split_edges(bm, edges=middle)
    bm.to_mesh(obj.data); bm.free()
    r = bake.Reports()
    bake.bake_object(bpy.context, obj, reports=r)
    out["split"] = r.items
    result(out)
'''


WARPLESS = '''
    from tearcloth.blender import bake, convert
    from tearcloth.materials import MATERIALS
    folder = sys.argv[1]
    obj = build_scene(folder, frame_end=2)
    convert.material_to_settings(MATERIALS["denim"], obj.tearcloth, bpy.context.scene)
    out = {}
    r = bake.Reports()
    bake.bake_object(bpy.context, obj, reports=r)
    out["whole"] = r.items
    # polygons 5 and 40 collapsed to a point in the UV map (a careless unwrap, a merged island)
    uv = obj.data.uv_layers["UVMap"]
    for k in (5, 40):
        for loop in obj.data.polygons[k].loop_indices:
            uv.data[loop].uv = (0.5, 0.5)
    r = bake.Reports()
    bake.bake_object(bpy.context, obj, reports=r)
    out["collapsed"] = r.items
    obj.data.uv_layers.remove(uv)
    r = bake.Reports()
    bake.bake_object(bpy.context, obj, reports=r)
    out["none"] = r.items
    result(out)
'''


def test_a_woven_material_without_a_warp_is_said_naming_the_polygons(tmp_path):
    """Denim's threads follow the UV map's u. Faces collapsed in the UV map, or a mesh with no UV
    map, give it no direction there: the warp ran along world X and nothing said so. The bake now
    warns, naming the user's polygons (or the missing map); a whole UV map says nothing."""
    got = run_blender(tmp_path, WARPLESS, tmp_path)
    assert not any("UV map" in m for _, m in got["whole"]), got["whole"]
    said = [m for level, m in got["collapsed"] if level == "WARNING" and "collapsed in the UV map" in m]
    assert len(said) == 1 and "4 triangles (polygons 5, 40)" in said[0] and "denim's warp" in said[0], got["collapsed"]
    said = [m for level, m in got["none"] if level == "WARNING" and "has no UV map" in m]
    assert len(said) == 1 and said[0].startswith("Sheet: the mesh has no UV map, so denim's warp"), got["none"]


def test_a_seam_left_unmerged_is_said(tmp_path):
    """Two islands whose open edges coincide (a garment's seam, or a Mirror's middle, not merged)
    are separate pieces to the solver: the seam opened by half a metre with '0 tears' and nothing
    said. The bake now warns, with the count, and says how to sew it; a welded sheet says nothing."""
    got = run_blender(tmp_path, SEAM, tmp_path)
    assert not any("open edges" in m for _, m in got["welded"]), got["welded"]
    said = [m for level, m in got["split"] if level == "WARNING" and "open edges sit exactly where" in m]
    assert len(said) == 1 and "Merge by Distance" in said[0], got["split"]
    assert int(said[0].split(": ")[1].split()[0]) > 0
