"""The add-on in Blender (PyPI bpy, every Blender run in a subprocess): registration that can be
repeated, the panels drawn against the real settings and operators, settings that survive save and
reload, every bad input reported (in the UI report and in the "tearcloth" log) with the scene
left intact, the cluster preview, Alembic export and colliders read from the evaluated mesh."""
from __future__ import annotations

import pytest

pytest.importorskip("bpy")
pytest.importorskip("pxr")
from test_blender_bake import run_blender  # noqa: E402  (tests/ is on sys.path, see conftest.py)
from tearcloth.materials import MATERIALS  # noqa: E402


def test_register_unregister_repeatedly_panels_and_operators(tmp_path):
    got = run_blender(tmp_path, '''
        import tearcloth
        from tearcloth.blender import ui
        ids = ["TEARCLOTH_PT_main", "TEARCLOTH_PT_material", "TEARCLOTH_PT_quality", "TEARCLOTH_PT_pins",
               "TEARCLOTH_PT_seams", "TEARCLOTH_PT_collision", "TEARCLOTH_PT_cache", "TEARCLOTH_PT_haptics",
               "TEARCLOTH_MT_material_presets", "TEARCLOTH_UL_handles", "TEARCLOTH_UL_colliders"]
        ops = ["enable", "disable", "bake", "bake_all", "bake_cancel", "free_bake", "material_preset",
               "handle_add", "handle_remove", "collider_add", "collider_remove", "preview_clusters",
               "export_alembic", "add_frayed_edges"]
        def present():
            return dict(types=[hasattr(bpy.types, i) for i in ids],
                        ops=[hasattr(bpy.types, "TEARCLOTH_OT_" + o) for o in ops],
                        props=[hasattr(bpy.types.Object, "tearcloth"), hasattr(bpy.types.Scene, "tearcloth")],
                        handlers=sum(h.__name__ == "_stop_bakes_before_load" for h in bpy.app.handlers.load_pre),
                        physics=ui.draw_physics_button in bpy.types.PHYSICS_PT_add._dyn_ui_initialize())
        states = []
        for _ in range(3):
            tearcloth.register()
            states.append(present())
            tearcloth.unregister()
            states.append(present())
        tearcloth.register()
        tearcloth.register()  # twice in a row is harmless too
        states.append(present())
        callable_ops = [op_exists("tearcloth." + o) for o in ops]

        # Draw every panel against a recording layout that checks each property and operator name.
        class Layout:
            def __init__(self): self.calls = []
            def __getattr__(self, name):
                def call(*args, **kwargs):
                    self.calls.append(name)
                    function = bpy.types.UILayout.bl_rna.functions.get(name)
                    assert function is not None, name
                    assert set(kwargs) <= {p.identifier for p in function.parameters}, (name, kwargs)
                    if name in ("prop", "prop_search"):
                        data, prop = args[0], args[1]
                        assert prop in data.bl_rna.properties, (data, prop)
                    if name == "prop_search":
                        assert args[3] in args[2].bl_rna.properties, args[2:]
                    if name == "operator":
                        assert op_exists(args[0]), args[0]
                    if name == "menu":
                        assert hasattr(bpy.types, args[0]), args[0]
                    if name == "template_list":
                        assert hasattr(bpy.types, args[0]) and args[3] in args[2].bl_rna.properties, args
                    return self
                return call
            def __setattr__(self, name, value):
                object.__setattr__(self, name, value)
        class Holder: pass
        obj = build_scene(sys.argv[1], save=False)
        drawn = {}
        with bpy.context.temp_override(object=obj, active_object=obj):
            ctx = bpy.context
            for cls in ui.classes:
                if not cls.__name__.startswith("TEARCLOTH_PT"):
                    continue
                assert cls.poll(ctx)
                holder = Holder(); holder.layout = Layout()
                cls.draw(holder, ctx)
                for extra in ("draw_header", "draw_header_preset"):
                    if hasattr(cls, extra):
                        getattr(cls, extra)(holder, ctx)
                drawn[cls.__name__] = holder.layout.calls
            holder = Holder(); holder.layout = Layout()
            ui.TEARCLOTH_MT_material_presets.draw(holder, ctx)
            ui.draw_physics_button(holder, ctx)
            drawn["menu+button"] = holder.layout.calls
            # while a bake runs: a progress bar in the panel and the status bar
            from types import SimpleNamespace
            from tearcloth.blender import jobs
            from tearcloth.bake import Progress
            fake = SimpleNamespace(object_name="Sheet", kind=jobs.BAKE, progress=Progress("Sheet", 1, 20))
            jobs.add(fake)
            for key, draw in (("running", ui.TEARCLOTH_PT_main.draw), ("cache_running", ui.TEARCLOTH_PT_cache.draw),
                              ("status", ui.draw_status_bar)):
                holder = Holder(); holder.layout = Layout()
                draw(holder, ctx)
                drawn[key] = holder.layout.calls
            jobs.remove(fake)
        result(dict(states=states, callable_ops=callable_ops, drawn=drawn))
    ''', tmp_path)
    states = got["states"]
    for i, state in enumerate(states):
        on = i % 2 == 0
        assert state["types"] == [on] * len(state["types"]), (i, state)
        assert state["ops"] == [on] * len(state["ops"]), (i, state)
        assert state["props"] == [on, on]
        assert state["handlers"] == (1 if on else 0)
        assert state["physics"] == on
    assert all(got["callable_ops"])
    drawn = got["drawn"]
    assert "progress" not in drawn["TEARCLOTH_PT_main"]  # nothing is baking
    assert "operator" in drawn["TEARCLOTH_PT_haptics"]  # Start Haptic Session, Discover, ...
    assert drawn["TEARCLOTH_PT_material"].count("prop") == 11  # nine + tear radius, crack speed
    assert "template_list" in drawn["TEARCLOTH_PT_pins"] and "template_list" in drawn["TEARCLOTH_PT_collision"]
    # one per preset, Save Preset..., the disable button
    assert drawn["menu+button"].count("operator") == len(MATERIALS) + 1 + 1
    assert drawn["running"] == ["progress", "operator"]  # the bar and Cancel
    assert drawn["status"] == ["progress"]
    assert "operator" in drawn["cache_running"] and "tearcloth.bake" not in drawn["cache_running"]


def test_settings_survive_save_and_reload(tmp_path):
    values = dict(material_preset="paper", young=3.5e9, poisson=0.25, thickness=1.5e-4, density=700.0,
                  tear_stress=2.5e7, snap_tolerance=0.2, bending=2e-4, damping_mass=0.7, damping_stiffness=3e-5,
                  steps_per_frame=7, cg_tolerance=1e-5, cg_max_iterations=321, use_tearing=False, scan_period=9,
                  min_angle_deg=12.5, pin_group="pins", seam_group="hand", seam_factor=1.7, use_collision=True,
                  collision_thickness=0.004, friction=0.6, use_self_collision=False, cluster_size=60,
                  displacement_threshold=0.003, measure="ABSOLUTE", cache_folder="//elsewhere/", frame_start=5,
                  frame_end=77)
    got = run_blender(tmp_path, '''
        import tearcloth
        values = json.loads(sys.argv[2])
        folder = sys.argv[1]
        if sys.argv[3] == "write":
            obj = build_scene(folder, save=False)
            s = obj.tearcloth
            for k, v in values.items():
                setattr(s, k, v)
            ball = bpy.data.objects.new("Ball", bpy.data.meshes.new("Ball"))
            bpy.context.scene.collection.objects.link(ball)
            s.colliders.add().object = ball
            s.collider_collection = bpy.context.scene.collection.children.get("x") or bpy.data.collections.new("Colliders")
            bpy.context.scene.tearcloth.alembic_path = "//out/x.abc"
            bpy.ops.wm.save_as_mainfile(filepath=os.path.join(folder, "settings.blend"))
            result("saved")
        else:
            if sys.argv[3] == "registered":
                tearcloth.register()
            bpy.ops.wm.open_mainfile(filepath=os.path.join(folder, "settings.blend"))
            obj = bpy.data.objects["Sheet"]
            if sys.argv[3] == "registered":
                s = obj.tearcloth
                back = {k: getattr(s, k) for k in values}
                result(dict(values=back, handles=[(h.vertex_group, h.follow.name) for h in s.handles],
                            colliders=[c.object.name for c in s.colliders],
                            collection=s.collider_collection.name,
                            alembic=bpy.context.scene.tearcloth.alembic_path,
                            modifier=[m.name for m in obj.modifiers]))
            else:  # without the add-on the file opens and the stock modifier is there
                result(dict(modifier=[(m.name, m.type) for m in obj.modifiers]))
    ''', tmp_path, __import__("json").dumps(values), "write")
    assert got == "saved"
    back = run_blender(tmp_path, '''
        import tearcloth
        values = json.loads(sys.argv[2])
        tearcloth.register()
        bpy.ops.wm.open_mainfile(filepath=os.path.join(sys.argv[1], "settings.blend"))
        obj = bpy.data.objects["Sheet"]
        s = obj.tearcloth
        result(dict(values={k: getattr(s, k) for k in values},
                    handles=[(h.vertex_group, h.follow.name) for h in s.handles],
                    colliders=[c.object.name for c in s.colliders], collection=s.collider_collection.name,
                    alembic=bpy.context.scene.tearcloth.alembic_path, modifier=[m.name for m in obj.modifiers]))
    ''', tmp_path, __import__("json").dumps(values), name="reload.py")
    for key, value in values.items():
        if isinstance(value, float):
            assert back["values"][key] == pytest.approx(value, rel=1e-6), key
        else:
            assert back["values"][key] == value, key
    assert back["handles"] == [["hand", "SheetPuller"]]
    assert back["colliders"] == ["Ball"] and back["collection"] == "Colliders"
    assert back["alembic"] == "//out/x.abc"
    assert back["modifier"] == ["Tear Cloth"]


BAD_INPUTS = '''
    import logging, shutil
    import tearcloth
    from tearcloth.blender import bake_object, BakeError, bake
    from tearcloth import cache

    logged = collect_log()

    folder = sys.argv[1]
    out = {}

    def attempt(key, fn):
        """Run fn; record how it ended and what the log said meanwhile."""
        start = len(logged)
        try:
            value = fn()
            state = value.state if hasattr(value, "state") else sorted(value) if isinstance(value, set) else value
        except (RuntimeError, BakeError) as exc:
            state = "error: " + str(exc)
        out[key] = dict(state=state, log=logged[start:])

    def snapshot(obj):
        return dict(polys=len(obj.data.polygons), verts=len(obj.data.vertices),
                    loops=[p.loop_total for p in obj.data.polygons][:5],
                    modifiers=[(m.name, m.type) for m in obj.modifiers],
                    groups=[g.name for g in obj.vertex_groups],
                    attached=obj.modifiers["Tear Cloth"].cache_file is not None if "Tear Cloth" in obj.modifiers else None)

    obj = build_scene(folder, frame_end=3)
    s = obj.tearcloth

    # a non-mesh object
    empty = bpy.data.objects.new("Empty", None)
    bpy.context.scene.collection.objects.link(empty)
    attempt("enable_empty", lambda: op("enable", empty))
    attempt("bake_empty", lambda: bake_object(bpy.context, empty))
    out["empty_modifiers"] = len(empty.modifiers)

    # missing vertex groups: a pin group that never existed and a handle's group renamed
    before = snapshot(obj)
    s.pin_group = "gone"
    obj.vertex_groups["hand"].name = "hand_renamed"
    attempt("missing_groups", lambda: op("bake", obj))
    out["missing_groups_intact"] = snapshot(obj) == {**before, "groups": ["pins", "hand_renamed"]}
    out["no_cache_folder_made"] = not os.path.exists(os.path.join(folder, "tearcloth_cache"))
    obj.vertex_groups["hand_renamed"].name = "hand"
    s.pin_group = "pins"

    # missing cache folder: created
    attempt("creates_folder", lambda: op("bake", obj))

    # read-only cache folder (root ignores permissions, so use a kernel folder for root)
    ro = "/sys" if os.geteuid() == 0 else os.path.join(folder, "ro")
    if ro != "/sys":
        os.makedirs(ro); os.chmod(ro, 0o555)
    s.cache_folder = ro
    attempt("read_only", lambda: op("bake", obj))
    s.cache_folder = "//tearcloth_cache/"

    # a corrupt cache file and a foreign USD file: refused and left as they were
    path = os.path.join(folder, "tearcloth_cache", "scene", "Sheet.usda")  # the .blend's own cache folder
    op("free_bake", obj)
    for key, content in (("corrupt", "#usda 1.0\\n(\\n garbage ((( \\n"),
                         ("foreign", '#usda 1.0\\ndef Xform "World"\\n{\\n}\\n')):
        with open(path, "w") as f:
            f.write(content)
        before = snapshot(obj)
        attempt(key, lambda: op("bake", obj))
        with open(path) as f:
            out[key + "_kept"] = f.read() == content
        out[key + "_intact"] = snapshot(obj) == before
        os.remove(path)

    # a cache written for another object
    other = bpy.data.objects.new("Other", obj.data.copy())
    bpy.context.scene.collection.objects.link(other)
    for g in obj.vertex_groups:
        other.vertex_groups.new(name=g.name)
    op("enable", other)
    other_path = os.path.join(folder, "tearcloth_cache", "scene", "Other.usda")
    w = cache.CacheWriter(other_path, "Other", 24.0, object_name="Sheet")
    w.write_frame(1, np.zeros((3, 3)) + np.eye(3), np.array([[0, 1, 2]]))
    w.close()
    attempt("foreign_owner", lambda: op("bake", other))
    attempt("foreign_owner_resume", lambda: op("bake", other, resume=True))
    out["foreign_owner_kept"] = cache.cache_info(other_path)["object"] == "Sheet"

    # no pins, no handles, no colliders: allowed, with a warning
    free = bpy.data.objects.new("Free", obj.data.copy())
    bpy.context.scene.collection.objects.link(free)
    op("enable", free)
    free.tearcloth.frame_end = 3
    free.tearcloth.use_collision = True
    free.tearcloth.use_self_collision = False
    free.tearcloth.colliders.add()  # an empty slot (its object deleted)
    attempt("falls", lambda: op("bake", free))

    # n-gons: triangulated for the solver only
    bpy.ops.mesh.primitive_circle_add(vertices=12, radius=0.2, fill_type="NGON", location=(2, 0, 1))
    disk = bpy.context.active_object
    op("enable", disk)
    disk.tearcloth.frame_end = 2
    before = snapshot(disk)
    attempt("ngon", lambda: op("bake", disk))
    out["ngon_intact"] = {k: v for k, v in snapshot(disk).items() if k != "attached"} == \\
        {k: v for k, v in before.items() if k != "attached"}

    # a handle whose follow object was deleted (the pointer goes empty) and a loose vertex: both said
    lone = bpy.data.objects.new("Lone", obj.data.copy())
    bpy.context.scene.collection.objects.link(lone)
    lone.vertex_groups.new(name="hand").add([0, 1], 1.0, "REPLACE")
    lone.data.vertices.add(1)
    lone.data.vertices[-1].co = (5.0, 5.0, 5.0)
    op("enable", lone)
    lone.tearcloth.frame_end = 2
    lone.tearcloth.use_collision = False
    handle = lone.tearcloth.handles.add()
    handle.vertex_group = "hand"
    ghost = bpy.data.objects.new("Ghost", None)
    bpy.context.scene.collection.objects.link(ghost)
    handle.follow = ghost
    bpy.data.objects.remove(ghost)
    attempt("lone", lambda: op("bake", lone))

    # an object renamed after its bake: resume says so; free frees what it plays
    op("bake", obj)
    obj.name = "Renamed"
    attempt("renamed_resume", lambda: op("bake", obj, resume=True))
    attempt("renamed_free", lambda: op("free_bake", obj))
    out["renamed_freed"] = not os.path.exists(path)
    obj.name = "Sheet"

    # an object deleted while its bake runs (what undo of its creation does too)
    obj.tearcloth.frame_end = 20
    run = bake.BakeRun(bpy.context, obj)
    run.start_thread(bpy.context)
    while run.progress.frame is None or run.progress.frame < 2:
        run.tick(bpy.context)
        time.sleep(0.01)
    bpy.data.objects.remove(obj)
    while run.tick(bpy.context):
        time.sleep(0.01)
    start = len(logged)
    state = run.finish(bpy.context)
    out["deleted"] = dict(state=state, log=logged[start:], frames=run.job.writer.frames)

    # bake all: every Tear Cloth object in turn; one that cannot bake does not stop the others
    for name in ("Free", "Circle"):
        op("free_bake", bpy.data.objects[name])
    attempt("bake_all", lambda: bpy.ops.tearcloth.bake_all())
    out["bake_all_baked"] = [cache.cache_info(os.path.join(folder, "tearcloth_cache", "scene", n + ".usda"))["complete"]
                             for n in ("Free", "Circle")]

    # an unsaved file with a relative cache folder
    bpy.ops.wm.read_factory_settings(use_empty=True)
    unsaved = build_scene(folder, save=False)
    attempt("unsaved", lambda: op("bake", unsaved))
    result(out)
'''


def _one(entry, level, *words):
    """The entry's log has a line of `level` that contains every word."""
    lines = [m for lvl, m in entry["log"] if lvl == level]
    assert any(all(w in m for w in words) for m in lines), (level, words, entry)


def test_bad_inputs_are_reported_and_the_scene_is_intact(tmp_path):
    out = run_blender(tmp_path, BAD_INPUTS, tmp_path, timeout=180)

    assert out["enable_empty"]["state"].startswith("error") and "not a mesh" in out["enable_empty"]["state"]
    assert "not a mesh" in out["bake_empty"]["state"]
    _one(out["bake_empty"], "ERROR", "'Empty'", "not a mesh")
    assert out["empty_modifiers"] == 0

    e = out["missing_groups"]
    assert e["state"].startswith("error")
    _one(e, "ERROR", "vertex group 'gone' (pins) does not exist")
    _one(e, "ERROR", "vertex group 'hand' (handle 1) does not exist")
    # the message says what the user can pick instead: the likely rename, and every group there is
    _one(e, "ERROR", "'hand' (handle 1)", "did you mean 'hand_renamed'?", "(its vertex groups: 'pins', 'hand_renamed')")
    assert not any("'gone'" in m and "did you mean" in m for _, m in e["log"])  # nothing close to 'gone'
    _one(e, "ERROR", "'gone' (pins)", "(its vertex groups: 'pins', 'hand_renamed')")
    assert out["missing_groups_intact"] and out["no_cache_folder_made"]

    assert out["creates_folder"]["state"] == ["FINISHED"]
    _one(out["creates_folder"], "INFO", "created the cache folder")
    _one(out["creates_folder"], "INFO", "baked frames 1-3")

    assert out["read_only"]["state"].startswith("error")
    _one(out["read_only"], "ERROR", "not writable")

    for key, words in (("corrupt", ["not a USD file", "left untouched"]),
                       ("foreign", ["not written by Tear Cloth", "left untouched"])):
        assert out[key]["state"].startswith("error"), out[key]
        _one(out[key], "ERROR", *words)
        assert out[key + "_kept"] and out[key + "_intact"], key

    _one(out["foreign_owner"], "ERROR", "baked for object 'Sheet', not 'Other'")
    _one(out["foreign_owner_resume"], "ERROR", "cannot resume", "'Sheet'")
    assert out["foreign_owner_kept"]

    assert out["falls"]["state"] == ["FINISHED"]
    _one(out["falls"], "WARNING", "no pins, handles or colliders", "falls freely under gravity")
    _one(out["falls"], "WARNING", "collider slot 1 is empty")

    assert out["ngon"]["state"] == ["FINISHED"]
    _one(out["ngon"], "WARNING", "1 n-gon triangulated", "your mesh is unchanged")
    assert out["ngon_intact"]

    assert out["lone"]["state"] == ["FINISHED"], out["lone"]
    _one(out["lone"], "WARNING", "handle 1 ('hand') follows no object", "holds its vertices where they are")
    _one(out["lone"], "WARNING", "1 loose vertex", "left out of the simulation and of the baked mesh")

    _one(out["renamed_resume"], "ERROR", "was baked under the name")
    assert out["renamed_free"]["state"] == ["FINISHED"] and out["renamed_freed"]

    d = out["deleted"]
    assert d["state"] == "error" and d["frames"][:2] == [1, 2]
    _one(d, "ERROR", "'Sheet' was deleted or renamed during the bake", "kept")

    _one(out["unsaved"], "ERROR", "not saved yet")

    _one(out["bake_all"], "ERROR", "Other", "baked for object 'Sheet'")
    _one(out["bake_all"], "INFO", "Free: baked frames 1-3")
    _one(out["bake_all"], "INFO", "Circle: baked frames 1-2")
    assert out["bake_all_baked"] == [True, True]


def test_cluster_preview_alembic_export_and_evaluated_colliders(tmp_path):
    got = run_blender(tmp_path, '''
        from tearcloth.blender import bake_object
        from tearcloth import cache
        folder = sys.argv[1]
        obj = build_scene(folder, frame_end=10)
        scene = bpy.context.scene

        # cluster preview: a colour per cluster on every vertex
        obj.tearcloth.cluster_size = 50
        op("preview_clusters", obj)
        attr = obj.data.color_attributes["tearcloth_clusters"]
        colours = np.empty(4 * len(obj.data.vertices), np.float32)
        attr.data.foreach_get("color", colours)
        colours = colours.reshape(-1, 4).round(4)
        preview = dict(domain=attr.domain, active=obj.data.color_attributes.active_color.name,
                       distinct=len({tuple(c) for c in colours}))

        # Alembic export of the bake, topology per frame included
        op("bake", obj)
        scene.tearcloth.alembic_path = "//export/sheet.abc"
        state = sorted(op("export_alembic", obj))
        abc = os.path.join(folder, "export", "sheet.abc")
        bpy.ops.wm.read_factory_settings(use_empty=True)
        bpy.ops.wm.alembic_import(filepath=abc, as_background_job=False)
        imported = [o for o in bpy.data.objects if o.type == "MESH"][0]
        counts = []
        for frame in (1, 10):
            bpy.context.scene.frame_set(frame)
            dg = bpy.context.evaluated_depsgraph_get()
            counts.append(len(imported.evaluated_get(dg).data.vertices))

        # a collider that grows through a Displace modifier (a deformation, not a transform)
        obj = build_scene(folder, n=12, frame_end=12, save=False)
        obj.tearcloth.handles.clear()
        obj.tearcloth.pin_group = ""
        obj.rotation_euler = (1.5708, 0.0, 0.0)  # lie flat, at z = 0 ... 0.5
        obj.location = (0.0, 1.25, -0.1)  # centred over the ball, just above it
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.15, location=(0.0, 0.0, -0.3))
        ball = bpy.context.active_object
        disp = ball.modifiers.new("Grow", "DISPLACE")
        disp.mid_level, disp.strength = 0.0, 0.0
        disp.keyframe_insert("strength", frame=1)
        disp.strength = 0.1
        disp.keyframe_insert("strength", frame=12)
        s = obj.tearcloth
        s.use_collision, s.use_self_collision = True, False
        s.colliders.add().object = ball
        s.cache_folder = os.path.join(folder, "collide")
        bpy.ops.wm.save_as_mainfile(filepath=os.path.join(folder, "collide.blend"))
        r = bake_object(bpy.context, obj)
        last = cache.read_frame(r.cache_path, 12)[0]
        world = np.array(obj.matrix_world)
        p = last @ world[:3, :3].T + world[:3, 3]
        d = np.linalg.norm(p - np.array([0.0, 0.0, -0.3]), axis=1)
        result(dict(preview=preview, export=state, counts=counts, collide=r.state,
                    min_distance=float(d.min()), top=float(p[:, 2].max())))
    ''', tmp_path, timeout=180)
    preview = got["preview"]
    assert preview["domain"] == "POINT" and preview["active"] == "tearcloth_clusters"
    assert 5 <= preview["distinct"] <= 14  # 400 vertices in clusters of ~50
    assert got["export"] == ["FINISHED"]
    assert got["counts"][0] == 400 and got["counts"][1] > 400  # the torn topology is in the Alembic
    assert got["collide"] == "done"
    # the ball grew to radius 0.25 by frame 12; the cloth lies on it, not inside
    assert got["min_distance"] > 0.25 - 0.01, got


def test_extension_manifest():
    import tomllib
    from pathlib import Path

    manifest = tomllib.loads((Path(__file__).resolve().parents[1] / "addon" / "blender_manifest.toml").read_text())
    for key in ("schema_version", "id", "version", "name", "tagline", "maintainer", "type", "blender_version_min",
                "license"):
        assert manifest.get(key), key
    assert manifest["type"] == "add-on" and manifest["id"] == "tearcloth"
    assert len(manifest["tagline"]) <= 64 and manifest["tagline"][-1].isalnum()
    assert tuple(int(x) for x in manifest["blender_version_min"].split(".")) >= (4, 2, 0)
    assert set(manifest.get("permissions", {})) <= {"files", "network", "clipboard", "camera", "microphone"}


def test_one_registry_of_running_jobs_keeps_one_job_per_object(tmp_path):
    """Bakes and live sessions share ``blender.jobs``: while either holds an object, the other
    (and Free Bake) is refused, and each module's ``running`` is a view of the same registry."""
    got = run_blender(tmp_path, '''
        from types import SimpleNamespace
        from tearcloth.blender import bake, haptic_session, jobs, Reports
        obj = build_scene(sys.argv[1])
        ctx = bpy.context
        out = {}
        live = SimpleNamespace(object_name=obj.name, kind=jobs.LIVE)
        jobs.add(live)
        def refused(fn):
            try:
                fn()
                return None
            except Exception as exc:
                return type(exc).__name__ + ": " + str(exc)
        out["bake_while_live"] = refused(lambda: bake.BakeRun(ctx, obj))
        reports = Reports()
        out["free_while_live"] = [bake.free_bake(obj, reports), reports.errors]
        out["views"] = [list(jobs.live_sessions), list(haptic_session.running), list(jobs.bakes), list(bake.running)]
        out["second_job"] = refused(lambda: jobs.add(SimpleNamespace(object_name=obj.name, kind=jobs.BAKE)))
        jobs.remove(live)
        run = bake.BakeRun(ctx, obj)
        run.start(ctx)
        out["while_baking"] = [list(jobs.bakes), jobs.get(obj.name) is run, list(jobs.live_sessions)]
        out["live_while_baking"] = refused(lambda: haptic_session.HapticRun(ctx, obj))
        run.finish(ctx)
        out["after"] = [list(jobs.bakes), jobs.get(obj.name)]
        result(out)
    ''', tmp_path)
    assert got["bake_while_live"].startswith("BakeError: Sheet: a live haptic session is running on this object")
    assert got["free_while_live"][0] is False and "live haptic session" in got["free_while_live"][1][0]
    assert got["views"] == [["Sheet"], ["Sheet"], [], []]
    assert got["second_job"] == "JobBusy: Sheet: a live haptic session is already running on this object"
    assert got["while_baking"] == [["Sheet"], True, []]
    assert "its bake is running" in got["live_while_baking"]
    assert got["after"] == [[], None]


def test_a_field_the_file_never_set_comes_from_its_preset(tmp_path):
    # a .blend saved before a material field existed (e.g. tear_radius) holds no value for it:
    # the bake reads the object's preset, not the property default (cotton's)
    got = run_blender(tmp_path, '''
        import tearcloth
        from tearcloth.blender import convert
        from tearcloth.materials import MATERIALS
        obj = build_scene(sys.argv[1], save=False)
        s = obj.tearcloth
        with bpy.context.temp_override(object=obj, active_object=obj):
            bpy.ops.tearcloth.material_preset(preset="banknote")
        s.property_unset("tear_radius")
        s.property_unset("crack_speed_ratio")
        s.young = 2.0e9  # what the user did set stays theirs
        m = convert.material_from_settings(s, bpy.context.scene)
        result(dict(radius=m.tear_radius, speed=m.crack_speed_ratio, young=m.young,
                    banknote=[MATERIALS["banknote"].tear_radius, MATERIALS["banknote"].crack_speed_ratio],
                    cotton=[MATERIALS["cotton"].tear_radius, MATERIALS["cotton"].crack_speed_ratio]))
    ''', tmp_path)
    assert [got["radius"], got["speed"]] == got["banknote"] != got["cotton"]
    assert got["young"] == pytest.approx(2.0e9)
