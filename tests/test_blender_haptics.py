"""The live haptic session in Blender (PyPI bpy; every Blender run in a subprocess, so a crash or a
stuck thread cannot take pytest down): the Haptics panel and its operators register and draw; two
EMULATED Falcons tear a small sheet while the viewport's mesh grows, the session records a USD
cache that stock Blender plays back, and afterwards every device has zero force and the user's
own mesh is back; an unplugged device, missing firmware, missing handle groups, a keyboard hand,
a file load, unregister and quitting Blender all end cleanly.

The window-less bpy cannot run a modal operator, so the tests drive ``HapticRun.tick`` (what the
modal's TIMER branch calls) through ``haptic_session.run_for``, the operator's ``execute`` path
(``duration=...``, the same loop), and the operator's ``modal`` method itself, fed hand-made events
on a stand-in for the operator instance (TIMER, arrows, Ctrl + mouse, blocked undo and Tab, Esc).

The sheet: the paper's square cloth (``examples.square_cloth``, ~300 triangles, hanging in the XZ
plane) with a quarter of cotton's tear stress; the emulated hands hold 0.05 s, then pull the grips
1.5 cm apart over 0.5 s of SIMULATED time (the same pull on a fast or a loaded machine). It tears
after about 0.3 s of simulated time.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pytest

pytest.importorskip("bpy")  # only checks that it is installed; Blender runs in the children
pytest.importorskip("pxr")
from test_blender_bake import run_blender  # noqa: E402  (tests/ is on sys.path, see conftest.py)

# The children import the tests' own modules (fakes.py) from this folder.
TESTS_DIR_LINE = f"TESTS_DIR = {os.path.dirname(os.path.abspath(__file__))!r}\n"
SCENE = '''
import logging, threading
sys.path.insert(0, TESTS_DIR)  # the tests' own modules (fakes.py) for the child
from tearcloth import examples
from tearcloth.blender import haptic_session as hs
from tearcloth.haptics import discovery as devices  # the device hooks tests replace

logged = collect_log()

def haptic_scene(folder, record=False, save=True):
    """The square sheet with handle_left / handle_right groups, both hands on emulated Falcons."""
    import tearcloth
    bpy.ops.wm.read_factory_settings(use_empty=True)
    tearcloth.register()
    scene = bpy.context.scene
    scene.render.fps = 24
    m = examples.square_cloth(target_triangles=300)
    mesh = bpy.data.meshes.new("Sheet")
    mesh.from_pydata(m.vertices.tolist(), [], m.triangles.tolist())
    corner = np.empty(len(mesh.loops), np.int32)
    mesh.loops.foreach_get("vertex_index", corner)
    mesh.uv_layers.new(name="UVMap").data.foreach_set("uv", m.uv[corner].ravel())
    obj = bpy.data.objects.new("Sheet", mesh)
    scene.collection.objects.link(obj)
    for name, w in m.groups.items():
        obj.vertex_groups.new(name=name).add([int(i) for i in np.flatnonzero(w >= 0.5)], 1.0, "REPLACE")
    bpy.context.view_layer.objects.active = obj
    assert op("enable", obj) == {"FINISHED"}
    s = obj.tearcloth
    s.tear_stress = 2.0e6
    s.use_collision = False
    h = s.haptics
    h.left.vertex_group, h.right.vertex_group = "handle_left", "handle_right"
    h.demo_pull, h.demo_hold, h.demo_pull_time = 0.015, 0.05, 0.5
    h.record = record
    if save:
        bpy.ops.wm.save_as_mainfile(filepath=os.path.join(folder, "scene.blend"))
    return obj

def live_threads():
    return sorted(t.name for t in threading.enumerate() if t.name.startswith("tearcloth-"))

def forces(run):
    """Every device's commanded force and state, and what each emulator was last sent."""
    return dict(devices={h: [d.force.tolist(), d.state.value] for h, d in run.devices.items()},
                efforts={h: list(e.efforts) for h, e in run.emulators.items()})

def shown_vertices(obj):
    """Vertices of the mesh Blender shows (the evaluated object)."""
    return len(obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).data.vertices)

def torn_for(steps):
    return lambda run: run.live.first_tear_step is not None and run.live.steps > run.live.first_tear_step + steps

def attempt(fn):
    """Run fn; how it ended and what the log said meanwhile."""
    start = len(logged)
    try:
        value = fn()
        state = sorted(value) if isinstance(value, set) else value
    except Exception as exc:
        state = "error: " + str(exc)
    return dict(state=state, log=logged[start:])
'''

# Draws panels against a layout that records every call and checks each name against the RNA.
LAYOUT = '''
class Layout:
    def __init__(self): self.calls = []
    def __getattr__(self, name):
        def call(*args, **kwargs):
            function = bpy.types.UILayout.bl_rna.functions.get(name)
            assert function is not None, name
            assert set(kwargs) <= {p.identifier for p in function.parameters}, (name, kwargs)
            if name in ("prop", "prop_search"):
                assert args[1] in args[0].bl_rna.properties, (args[0], args[1])
            if name == "prop_search":
                assert args[3] in args[2].bl_rna.properties, args[2:]
            if name == "label" and "icon" in kwargs:
                icons = function.parameters["icon"].enum_items
                assert kwargs["icon"] in icons, kwargs["icon"]
            self.calls.append((name, args[1] if name in ("prop", "prop_search") else args[0] if args
                               else kwargs.get("text", "")))
            if name == "operator":
                assert op_exists(args[0]), args[0]
                return Holder()  # its properties are set by the panel
            return self
        return call
    def __setattr__(self, name, value):
        object.__setattr__(self, name, value)

class Holder: pass

def draw_haptics(obj):
    from tearcloth.blender import ui
    holder = Holder(); holder.layout = Layout()
    with bpy.context.temp_override(object=obj, active_object=obj):
        assert ui.TEARCLOTH_PT_haptics.poll(bpy.context)
        ui.TEARCLOTH_PT_haptics.draw(holder, bpy.context)
    return holder.layout.calls
'''


def child(body: str) -> str:
    """A Blender child's script: the shared helpers, then the test's own (indented) body."""
    return TESTS_DIR_LINE + SCENE + LAYOUT + textwrap.dedent(body)


def test_register_discover_and_panel(tmp_path):
    got = run_blender(tmp_path, child('''
        import tearcloth
        from tearcloth.haptics import FalconEmulator
        ops = ["haptic_session", "haptic_stop", "haptic_discover", "haptic_assign_device", "haptic_save_force_log"]
        def present():
            return dict(ops=[hasattr(bpy.types, "TEARCLOTH_OT_" + o) for o in ops],
                        haptics="tearcloth" in bpy.types.Object.bl_rna.properties and "haptics" in
                                bpy.types.Object.bl_rna.properties["tearcloth"].fixed_type.properties,
                        handlers=[sum(h.__module__.startswith("tearcloth") for h in getattr(bpy.app.handlers, k))
                                  for k in ("load_pre", "save_pre", "save_post")])
        states = []
        for _ in range(2):
            tearcloth.register(); states.append(present())
            tearcloth.unregister(); states.append(present())
        obj = haptic_scene(sys.argv[1], save=False)
        states.append(present())
        drawn = {"defaults": draw_haptics(obj)}

        # Discover with nothing plugged in: never raises, says so; hands are probed
        discover = attempt(lambda: op("haptic_discover", obj))
        drawn["nothing_found"] = draw_haptics(obj)

        # Discover with two emulated Falcons, one without firmware
        devices.find_falcons = lambda: ["EMU-B", "EMU-A"]
        devices.falcon_transport_factory = lambda serial: FalconEmulator(serial, firmware_loaded=serial == "EMU-A",
                                                                    homed=True)
        h = obj.tearcloth.haptics
        h.left.device = h.right.device = "FALCON"
        h.right.falcon_serial = "EMU-B"
        found = attempt(lambda: op("haptic_discover", obj))
        probed = {hand: list(hs.discovery.states[("Sheet", hand)]) for hand in ("left", "right")}
        drawn["falcons"] = draw_haptics(obj)
        assigned = attempt(lambda: op("haptic_assign_device", obj, hand="LEFT", kind="FALCON", identifier="EMU-A"))
        after_assign = [h.left.device, h.left.falcon_serial]

        # every kind of device and mapping draws its own settings
        h.left.device, h.right.device = "SPACEMOUSE", "KEYBOARD"
        h.right.mapping = "MANUAL"
        drawn["spacemouse_keyboard_manual"] = draw_haptics(obj)
        result(dict(states=states, drawn=drawn, discover=discover, found=found, probed=probed,
                    assigned=assigned, after_assign=after_assign))
    '''), tmp_path)
    states = got["states"]
    for i, state in enumerate(states):
        on = i % 2 == 0 or i == len(states) - 1
        assert state["ops"] == [on] * 5 and state["haptics"] == on, (i, state)
        assert state["handlers"] == ([1, 1, 1] if on else [0, 0, 0]), (i, state)

    drawn = {key: calls_of(value) for key, value in got["drawn"].items()}
    calls = drawn["defaults"]
    assert ("operator", "tearcloth.haptic_session") in calls and ("operator", "tearcloth.haptic_discover") in calls
    assert ("operator", "tearcloth.haptic_save_force_log") in calls
    props = [v for k, v in calls if k in ("prop", "prop_search")]
    for name in ("use", "device", "vertex_group", "mapping", "region_radius", "k_position", "k_velocity",
                 "force_scale", "max_force", "stop_button", "record", "time_step", "demo_pull"):
        assert name in props, name
    assert props.count("device") == 2 and "firmware_path" not in props  # no Falcon hand yet
    assert texts_of(calls).count("Ready") == 2  # emulated Falcons are always ready

    assert got["discover"]["state"] == ["FINISHED"]
    assert any("Falcons: none; SpaceMice: none" in m for _, m in got["discover"]["log"])
    assert "No Falcon or SpaceMouse found" in texts_of(drawn["nothing_found"])

    assert any("Falcons: EMU-A, EMU-B" in m for _, m in got["found"]["log"])
    # the right hand chose EMU-B (no firmware); the left took the free one, EMU-A (firmware running, homed)
    assert got["probed"]["right"][0] == "needs_firmware" and "nvent_firmware.bin" in got["probed"]["right"][1]
    assert got["probed"]["left"][0] == "ready"
    calls = drawn["falcons"]
    assert "Needs Firmware" in texts_of(calls) and "Ready" in texts_of(calls)
    assert [v for k, v in calls if k == "operator"].count("tearcloth.haptic_assign_device") == 4  # 2 Falcons x 2 hands
    assert "firmware_path" in [v for k, v in calls if k == "prop"]
    assert got["assigned"]["state"] == ["FINISHED"] and got["after_assign"] == ["FALCON", "EMU-A"]

    props = [v for k, v in drawn["spacemouse_keyboard_manual"] if k == "prop"]
    assert "spacemouse_path" in props and "scale" in props and "offset" in props and "keyboard_step" in props
    assert any("arrows move it" in t for t in texts_of(drawn["spacemouse_keyboard_manual"]))


def test_two_emulated_falcons_tear_live_record_and_play_back(tmp_path):
    got = run_blender(tmp_path, child('''
        folder = sys.argv[1]
        obj = haptic_scene(folder, record=True)
        original = obj.data
        pointer, n0 = original.as_pointer(), len(original.vertices)
        ctx = bpy.context
        run = hs.HapticRun(ctx, obj)
        run.start(ctx)
        during = dict(phase=run.status.phase, live_mesh=obj.data.name, fake_user=original.use_fake_user,
                      uv=[layer.name for layer in obj.data.uv_layers],
                      modifier_on=obj.modifiers["Tear Cloth"].show_viewport, threads=live_threads(),
                      servo_pid=run.live.servo_process.pid, servo_alive=run.live.servo_process.running)
        shown = [shown_vertices(obj)]
        hs.run_for(ctx, run, 60.0, until=lambda r: shown.append(shown_vertices(obj)) or torn_for(150)(r))
        during.update(torn=run.live.first_tear_step is not None, ticks=len(shown), status=run.status.text(),
                      rates=run.status.rates(), hand_force=[run.status.hands[h].force for h in ("left", "right")],
                      cloth_force=[run.status.hands[h].cloth_force for h in ("left", "right")])
        panel = draw_haptics(obj)
        # a file saved during the session holds the user's mesh, and the session goes on
        bpy.ops.wm.save_as_mainfile(filepath=os.path.join(folder, "during.blend"), copy=True)
        during.update(after_save=obj.data.name, running=run.tick(ctx),
                      modifier_after_save=obj.modifiers["Tear Cloth"].show_viewport)
        state = run.finish(ctx)
        after = dict(state=state, reports=run.reports.items, same_mesh=obj.data.as_pointer() == pointer,
                     name=obj.data.name, vertices=len(obj.data.vertices), fake_user=original.use_fake_user,
                     meshes=sorted(bpy.data.meshes.keys()), modifier_on=obj.modifiers["Tear Cloth"].show_viewport,
                     frame=bpy.context.scene.frame_current, threads=live_threads(), forces=forces(run),
                     cache=obj.modifiers["Tear Cloth"].cache_file is not None,
                     frames=run.recorder.frames, shown_first=shown_vertices(obj))
        bpy.context.scene.frame_set(after["frames"][-1])
        after["shown_last"] = shown_vertices(obj)
        bpy.context.scene.frame_set(1)
        log = attempt(lambda: op("haptic_save_force_log", obj))
        log["files"] = sorted(f for f in os.listdir(folder) if "_forces_" in f)
        panel_after = draw_haptics(obj)
        bpy.ops.wm.save_mainfile()
        result(dict(n0=n0, shown=shown, during=during, after=after, panel=panel, panel_after=panel_after, log=log))
    '''), tmp_path)
    n0, shown, during, after = got["n0"], got["shown"], got["during"], got["after"]
    assert during["phase"] == "running" and during["live_mesh"] == "Sheet (Tear Cloth live)"
    assert during["fake_user"] and not during["modifier_on"] and during["uv"] == ["UVMap"]
    assert "tearcloth-live-sim" in during["threads"] and "tearcloth-live-writer" in during["threads"]
    # emulated hands only: the servo runs in a process of its own, watched through two sentinel threads
    assert during["servo_pid"] and during["servo_alive"]
    assert {"tearcloth-live-peer0", "tearcloth-live-peer1", "tearcloth-live-log"} <= set(during["threads"])
    assert not [t for t in during["threads"] if t.startswith("tearcloth-servo")]
    # the mesh Blender shows grows when the sheet tears, tick after tick
    assert during["torn"] and shown[0] == n0 and shown[-1] > n0, shown
    assert all(b >= a for a, b in zip(shown, shown[1:]))
    assert "torn" in during["status"] and "steps/s" in during["rates"] and "servo" in during["rates"]
    assert min(during["hand_force"]) > 0.0 and min(during["cloth_force"]) > 0.0  # both hands feel the cloth
    assert during["after_save"] == "Sheet (Tear Cloth live)" and during["running"]
    assert not during["modifier_after_save"]
    panel = calls_of(got["panel"])
    assert ("operator", "tearcloth.haptic_stop") in panel and ("operator", "tearcloth.haptic_session") not in panel
    assert sum("N felt" in t for t in texts_of(panel)) == 2 and any("servo" in t for t in texts_of(panel))

    # afterwards: the user's own mesh datablock, unchanged; zero force everywhere; nothing left running
    assert after["state"] == "done", after["reports"]
    assert after["same_mesh"] and after["name"] == "Sheet" and after["vertices"] == n0 and not after["fake_user"]
    assert after["meshes"] == ["Sheet"] and after["modifier_on"] and after["frame"] == 1
    assert after["threads"] == []
    for hand, (force, device_state) in after["forces"]["devices"].items():
        assert force == [0.0, 0.0, 0.0] and device_state == "closed", hand
    assert after["forces"]["efforts"] == {"left": [0, 0, 0], "right": [0, 0, 0]}
    frames = after["frames"]
    assert after["cache"] and frames[0] == 1 and frames == list(range(1, frames[-1] + 1)) and len(frames) >= 8
    assert after["shown_first"] == n0 and after["shown_last"] > n0  # the modifier plays the recording
    levels = [level for level, _ in after["reports"]]
    assert "ERROR" not in levels and any("recorded frames 1-" in m for _, m in after["reports"])
    assert got["log"]["state"] == ["FINISHED"] and [f[-4:] for f in got["log"]["files"]] == [".csv", ".png"]
    assert ("operator", "tearcloth.haptic_session") in calls_of(got["panel_after"])

    # stock Blender (no add-on) plays the recording back through the Mesh Sequence Cache modifier,
    # and the file saved mid-session holds the user's mesh, not the live one
    played = run_blender(tmp_path, '''
        folder = sys.argv[1]
        bpy.ops.wm.open_mainfile(filepath=os.path.join(folder, "during.blend"))
        assert "tearcloth" not in sys.modules
        sheet = bpy.data.objects["Sheet"]
        saved_during = dict(mesh=sheet.data.name, meshes=sorted(bpy.data.meshes.keys()),
                            vertices=len(sheet.data.vertices), fake_user=sheet.data.use_fake_user,
                            modifier_on=sheet.modifiers["Tear Cloth"].show_viewport)
        bpy.ops.wm.open_mainfile(filepath=os.path.join(folder, "scene.blend"))
        scene, obj = bpy.context.scene, bpy.data.objects["Sheet"]
        counts = {}
        for frame in (1, int(sys.argv[2]) // 2, int(sys.argv[2])):
            scene.frame_set(frame)
            evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
            counts[frame] = len(evaluated.vertices)
            uv_layers = [layer.name for layer in evaluated.uv_layers]
        md = obj.modifiers["Tear Cloth"]
        result(dict(saved_during=saved_during, counts=counts, modifier=md.type, path=md.cache_file.filepath,
                    stock="tearcloth" not in sys.modules, uv=uv_layers))
    ''', tmp_path, frames[-1], name="playback.py")
    assert played["saved_during"] == {"mesh": "Sheet", "meshes": ["Sheet"], "vertices": n0, "fake_user": False,
                                      "modifier_on": True}
    assert played["stock"] and played["modifier"] == "MESH_SEQUENCE_CACHE"
    assert played["path"].startswith("//tearcloth_cache/") and "st" in played["uv"]  # as a bake writes UVs
    counts = [played["counts"][k] for k in sorted(played["counts"], key=int)]
    assert counts[0] == n0 and counts[-1] > n0 and counts[-1] == after["shown_last"], counts


def texts_of(calls):
    return [str(v) for k, v in calls if k == "label"]


def calls_of(recorded):
    """The recorded layout calls as (function, name or text) pairs (JSON made them lists)."""
    return [tuple(call) for call in recorded]


def test_unplug_stop_button_firmware_homing_errors_keyboard_and_modal_events(tmp_path):
    got = run_blender(tmp_path, child('''
        from tearcloth.haptics import FalconEmulator
        folder = sys.argv[1]
        obj = haptic_scene(folder)
        ctx = bpy.context
        original = obj.data.as_pointer()
        out = {}

        # a Falcon unplugged mid-session: the session ends, zero force, an ERROR report, mesh back
        run = hs.HapticRun(ctx, obj)
        run.start(ctx)
        hs.run_for(ctx, run, 30.0, until=lambda r: r.live.steps > 60)
        run.emulators["right"].unplug()
        t0 = time.perf_counter()
        hs.run_for(ctx, run, 10.0)
        out["unplug"] = dict(ended_by_itself=run.live.ended, seconds=time.perf_counter() - t0,
                             state=run.finish(ctx), reports=run.reports.items, forces=forces(run),
                             mesh_back=obj.data.as_pointer() == original, threads=live_threads(),
                             hands={h: v.state for h, v in run.status.hands.items()})

        # the stop button (the Falcon's centre button by default) ends the session, zero force
        run = hs.HapticRun(ctx, obj)
        run.start(ctx)
        hs.run_for(ctx, run, 30.0, until=lambda r: r.live.steps > 30)
        run.emulators["left"].buttons = 0x4
        hs.run_for(ctx, run, 10.0)
        out["button"] = dict(ended_by_itself=run.live.ended, state=run.finish(ctx), reports=run.reports.items,
                             forces=forces(run))

        # through the operator (as a script calls it): a short session, then stopped
        out["op_ok"] = attempt(lambda: op("haptic_session", obj, duration=0.3))
        out["op_no_duration"] = attempt(lambda: op("haptic_session", obj))

        # missing firmware file, no Falcon plugged in, a Falcon without firmware (and none given)
        h = obj.tearcloth.haptics
        h.left.device = h.right.device = "FALCON"
        h.firmware_path = os.path.join(folder, "missing", "nvent_firmware.bin")
        out["firmware_file"] = attempt(lambda: op("haptic_session", obj, duration=1.0))
        h.firmware_path = ""
        out["no_falcon"] = attempt(lambda: op("haptic_session", obj, duration=1.0))
        made = []
        def emulator(serial):
            made.append(FalconEmulator(serial, firmware_loaded=serial == "EMU-A", homed=True))
            return made[-1]
        devices.find_falcons, devices.falcon_transport_factory = lambda: ["EMU-A", "EMU-B"], emulator
        out["needs_firmware"] = attempt(lambda: op("haptic_session", obj, duration=1.0))
        out["needs_firmware_efforts"] = [list(e.efforts) for e in made]

        # with a firmware file, a Falcon without firmware gets it; unhomed Falcons home while the
        # session waits (the emulated user makes the homing gesture), then the session runs
        from tearcloth.haptics.falcon_emulator import homing_gesture, spring_hand
        firmware = os.path.join(folder, "nvent_firmware.bin")
        with open(firmware, "wb") as f:
            f.write(bytes(range(256)) * 33 + bytes(44))  # 8492 bytes, the size of the real image
        h.firmware_path = firmware
        made.clear()
        def unhomed(serial):
            made.append(FalconEmulator(serial, firmware_loaded=serial == "EMU-A", homed=False,
                                       hand=spring_hand(homing_gesture(leg=0.1), 1500.0, 15.0)))
            return made[-1]
        devices.falcon_transport_factory = unhomed
        run = hs.HapticRun(ctx, obj)
        run.start(ctx)
        homing = dict(phase=run.status.phase, text=run.status.text(),
                      states=sorted(d.state.value for d in run.devices.values()))
        hs.run_for(ctx, run, 30.0, until=lambda r: r.status.phase != "homing", interval=0.0)
        homing.update(phase_after=run.status.phase, firmware=[len(e.firmware) for e in made],
                      states_after=sorted(d.state.value for d in run.devices.values()))
        hs.run_for(ctx, run, 0.2)
        run.stop("test")
        homing.update(state=run.finish(ctx), efforts=[list(e.efforts) for e in made],
                      reports=run.reports.items)
        out["homing"] = homing
        h.firmware_path = ""
        h.left.device = h.right.device = "EMULATED"

        # a simulation error ends the session with zero force and an ERROR report
        run = hs.HapticRun(ctx, obj)
        run.start(ctx)
        hs.run_for(ctx, run, 30.0, until=lambda r: r.live.steps > 20)
        def broken(dt):
            raise RuntimeError("the solver exploded (injected)")
        run.live.session.step = broken
        hs.run_for(ctx, run, 10.0)
        out["sim_error"] = dict(state=run.finish(ctx), reports=run.reports.items, forces=forces(run),
                                threads=live_threads(), mesh_back=obj.data.as_pointer() == original)

        # handle groups that do not exist, or that are not chosen; no hand at all
        h.left.vertex_group = "sleeve"
        out["no_group"] = attempt(lambda: op("haptic_session", obj, duration=1.0))
        h.left.vertex_group = ""
        out["empty_group"] = attempt(lambda: op("haptic_session", obj, duration=1.0))
        h.left.use = h.right.use = False
        out["no_hand"] = attempt(lambda: op("haptic_session", obj, duration=1.0))
        out["intact"] = dict(mesh_back=obj.data.as_pointer() == original, running=list(hs.running),
                             threads=live_threads(), meshes=sorted(bpy.data.meshes.keys()))

        # a keyboard hand (right) against a pinned left edge: arrows and the mouse move its proxy
        h.right.use, h.right.device = True, "KEYBOARD"
        h.right.vertex_group = "handle_right"
        obj.tearcloth.pin_group = "handle_left"
        run = hs.HapticRun(ctx, obj)
        run.start(ctx)
        hs.run_for(ctx, run, 0.3)
        x0 = run.live.handle_position("right")[0]
        for _ in range(5):
            assert run.key("RIGHT_ARROW")
        assert not run.key("A")
        # the force the virtual device computed, at every tick of the pull: one tick's alone was 0.0
        # once in CI (the servo's stall watchdog zeroes it while a loaded machine holds the
        # simulation back), which says nothing about what the device computes
        forces = []

        def pulled(r):
            forces.append(r.status.hands["right"].force)
            return r.live.handle_position("right")[0] > x0 + 0.015

        hs.run_for(ctx, run, 30.0, until=pulled)
        x1 = run.live.handle_position("right")[0]
        felt = max(forces)
        run.key("HOME")
        run.mouse_move(-100.0, 0.0)  # 1 cm of device motion to the left in the front view
        hs.run_for(ctx, run, 30.0, until=lambda r: r.live.handle_position("right")[0] < x0 - 0.015)
        x2 = run.live.handle_position("right")[0]
        assert op("haptic_stop", obj) == {"FINISHED"}
        alive = run.tick(ctx)
        out["keyboard"] = dict(dx1=x1 - x0, dx2=x2 - x0, felt=felt, alive_after_stop=alive,
                               state=run.finish(ctx), reports=run.reports.items)

        # a SpaceMouse (a fake HID device) mapped by scale and offset: deflected right, it drags the
        # handle right; input only, so no force is sent to it
        from fakes import FakeHid  # tests/fakes.py: TESTS_DIR is on the child's sys.path
        from tearcloth.haptics.spacemouse import translation_report
        puck = FakeHid()
        devices.find_spacemice = lambda: [dict(path=b"/dev/hidraw-fake", vid=0x256F, pid=0xC635, model="SpaceMouse Compact",
                                          layout="split", serial="")]
        devices.spacemouse_hid_factory = lambda path: puck
        h.right.device, h.right.mapping, h.right.scale = "SPACEMOUSE", "MANUAL", 1.0
        grasp = np.mean([v.co for v in obj.data.vertices if any(g.group == obj.vertex_groups["handle_right"].index
                                                                  for g in v.groups)], axis=0)
        h.right.offset = grasp.tolist()  # the puck starts at its origin: the grasp does not jump
        run = hs.HapticRun(ctx, obj)
        run.start(ctx)
        hs.run_for(ctx, run, 0.2)
        x0 = run.live.handle_position("right")[0]
        puck.feed(translation_report(350, 0, 0))  # full deflection to the right: 0.2 m/s
        hs.run_for(ctx, run, 30.0, until=lambda r: r.live.handle_position("right")[0] > x0 + 0.02)
        out["spacemouse"] = dict(dx=run.live.handle_position("right")[0] - x0,
                                 opened=[puck.opened[0], puck.opened[1].decode()], device=run.devices["right"].name,
                                 force=run.status.hands["right"].force,
                                 state=run.finish(ctx), closed=puck.closed)
        h.right.device, h.right.mapping = "KEYBOARD", "FIT"

        # the modal operator's event routing, fed by hand (no window: a stand-in for the operator)
        from types import MethodType, SimpleNamespace
        from tearcloth.blender.ops import TEARCLOTH_OT_haptic_session as Modal
        shown = []
        fake = SimpleNamespace(report=lambda level, message: shown.append((sorted(level)[0], message)),
                               _timer=ctx.window_manager.event_timer_add(0.1, window=None), _last_panel=0.0)
        fake._end, fake._redraw = MethodType(Modal._end, fake), MethodType(Modal._redraw, fake)
        fake._run = run = hs.HapticRun(ctx, obj)
        run.start(ctx)
        def event(kind, value="PRESS", **mods):
            e = dict(type=kind, value=value, shift=False, alt=False, ctrl=False, oskey=False, mouse_x=10,
                     mouse_y=10, mouse_prev_x=10, mouse_prev_y=10)
            e.update(mods)
            return sorted(Modal.modal(fake, ctx, SimpleNamespace(**e)))
        routed = dict(timer=event("TIMER", "NOTHING"))
        x0 = run.live.handle_position("right")[0]
        routed.update(arrow=event("RIGHT_ARROW"), other_key=event("A"), undo=event("Z", ctrl=True), tab=event("TAB"),
                      mouse=event("MOUSEMOVE", "NOTHING", ctrl=True, mouse_x=60),
                      plain_mouse=event("MOUSEMOVE", "NOTHING", mouse_x=500))
        deadline = time.perf_counter() + 30.0
        while run.live.handle_position("right")[0] < x0 + 0.012 and time.perf_counter() < deadline:
            assert event("TIMER", "NOTHING") == ["PASS_THROUGH"]
            time.sleep(1.0 / 60.0)
        routed.update(moved=run.live.handle_position("right")[0] - x0, esc=event("ESC"), finished=run.finished,
                      state=run.state, shown=shown, mesh_back=obj.data.as_pointer() == original,
                      threads=live_threads())
        out["modal"] = routed

        # a woven material on a mesh without a UV map: its warp runs along world X, said at the start
        from tearcloth.blender import convert
        from tearcloth.materials import MATERIALS
        convert.material_to_settings(MATERIALS["denim"], obj.tearcloth, bpy.context.scene)
        obj.data.uv_layers.remove(obj.data.uv_layers["UVMap"])
        run = hs.HapticRun(ctx, obj)
        run.start(ctx)
        hs.run_for(ctx, run, 0.1)
        assert op("haptic_stop", obj) == {"FINISHED"}
        run.tick(ctx)
        out["warpless"] = dict(state=run.finish(ctx), reports=run.reports.items)
        result(out)
    '''), tmp_path)
    w = got["warpless"]
    assert w["state"] == "done" and any(
        level == "WARNING" and "Sheet: the mesh has no UV map, so denim's warp runs along the world X axis" in m
        for level, m in w["reports"]), w["reports"]
    u = got["unplug"]
    assert u["ended_by_itself"] and u["seconds"] < 5.0 and u["state"] == "lost"
    assert any(level == "ERROR" and "device lost on the right hand" in m and "connection lost" in m
               for level, m in u["reports"]), u["reports"]
    for hand, (force, device_state) in u["forces"]["devices"].items():
        assert force == [0.0, 0.0, 0.0] and device_state == "closed", hand
    assert u["forces"]["efforts"]["left"] == [0, 0, 0]  # the hand that still had a cable got zero force
    assert u["mesh_back"] and u["threads"] == [] and u["hands"]["right"] == "closed"

    b = got["button"]
    assert b["ended_by_itself"] and b["state"] == "done"
    assert any(level == "INFO" and "ended (stop button pressed on the left hand)" in m for level, m in b["reports"])
    assert all(f == [0.0, 0.0, 0.0] and s == "closed" for f, s in b["forces"]["devices"].values())

    assert got["op_ok"]["state"] == ["FINISHED"]
    assert any("haptic session ended (0.3 s are over)" in m for _, m in got["op_ok"]["log"])
    assert "duration=seconds" in got["op_no_duration"]["state"]

    assert "Falcon firmware file not found" in got["firmware_file"]["state"]
    assert "missing/nvent_firmware.bin" in got["firmware_file"]["state"]
    assert "the left hand: no Novint Falcon found" in got["no_falcon"]["state"]
    assert "has no firmware loaded" in got["needs_firmware"]["state"] and "force set to zero" in \
        got["needs_firmware"]["state"]
    assert got["needs_firmware_efforts"] and all(e == [0, 0, 0] for e in got["needs_firmware_efforts"])
    m = got["homing"]
    assert m["phase"] == "homing" and "move each grip" in m["text"] and m["states"] == ["homing", "homing"]
    assert m["phase_after"] == "running" and m["states_after"] == ["ready", "ready"]
    assert sorted(m["firmware"]) == [0, 8492]  # EMU-B had none: the user's file was uploaded
    assert m["state"] == "done" and all(e == [0, 0, 0] for e in m["efforts"]), m
    assert any("homing: move each Falcon grip" in msg for _, msg in m["reports"])
    e = got["sim_error"]
    assert e["state"] == "error" and e["threads"] == [] and e["mesh_back"]
    assert any(level == "ERROR" and "the simulation stopped" in msg and "injected" in msg
               for level, msg in e["reports"]), e["reports"]
    assert all(f == [0.0, 0.0, 0.0] and s == "closed" for f, s in e["forces"]["devices"].values())
    assert all(x == [0, 0, 0] for x in e["forces"]["efforts"].values())
    assert "vertex group 'sleeve' (the left hand) does not exist" in got["no_group"]["state"]
    assert "the left hand grasps no vertex group" in got["empty_group"]["state"]
    assert "no hand is in use" in got["no_hand"]["state"]
    assert got["intact"] == dict(mesh_back=True, running=[], threads=[], meshes=["Sheet"])

    k = got["keyboard"]
    assert k["dx1"] > 0.015 and k["dx2"] < -0.015, k  # 5 x 2 mm of device motion = 2 cm in the scene
    assert k["felt"] > 0.0  # the virtual device computes the force a Falcon would render
    assert not k["alive_after_stop"] and k["state"] == "done"
    assert any("haptic session ended (Stop pressed)" in m for _, m in k["reports"])

    sm = got["spacemouse"]
    assert sm["dx"] > 0.02 and sm["opened"] == ["path", "/dev/hidraw-fake"] and sm["device"] == "SpaceMouse Compact"
    assert sm["force"] == 0.0 and sm["state"] == "done" and sm["closed"]

    r = got["modal"]
    assert r["timer"] == ["PASS_THROUGH"] and r["arrow"] == ["RUNNING_MODAL"] and r["other_key"] == ["PASS_THROUGH"]
    assert r["undo"] == r["tab"] == r["mouse"] == ["RUNNING_MODAL"] and r["plain_mouse"] == ["PASS_THROUGH"]
    assert r["moved"] > 0.012  # one arrow press (2 mm) and 50 px of Ctrl + mouse (5 mm) of device motion, x2
    assert r["esc"] == ["FINISHED"] and r["finished"] and r["state"] == "done"
    assert r["mesh_back"] and r["threads"] == []
    assert any(level == "WARNING" and "undo and Edit Mode are blocked" in m for level, m in r["shown"])
    assert any(level == "INFO" and "haptic session ended (Esc pressed)" in m for level, m in r["shown"])


def test_file_load_unregister_and_quit_stop_sessions(tmp_path):
    got = run_blender(tmp_path, child('''
        import tearcloth
        from tearcloth import cache
        folder = sys.argv[1]
        ctx = bpy.context
        out = {}

        # unregister during a session: zero force, the user's mesh back
        obj = haptic_scene(folder)
        original = obj.data.as_pointer()
        run = hs.HapticRun(ctx, obj)
        run.start(ctx)
        hs.run_for(ctx, run, 30.0, until=lambda r: r.live.steps > 30)
        tearcloth.unregister()
        out["unregister"] = dict(running=list(hs.running), forces=forces(run), threads=live_threads(),
                                 mesh_back=obj.data.as_pointer() == original, meshes=sorted(bpy.data.meshes.keys()),
                                 modifier_on=obj.modifiers["Tear Cloth"].show_viewport)

        # the object renamed during a session: it stops, and the renamed object gets its mesh back
        tearcloth.register()
        obj = haptic_scene(folder)
        original = obj.data.as_pointer()
        run = hs.HapticRun(ctx, obj)
        run.start(ctx)
        hs.run_for(ctx, run, 30.0, until=lambda r: r.live.steps > 10)
        obj.name = "Renamed"
        out["rename"] = dict(alive=run.tick(ctx), state=run.finish(ctx), reports=run.reports.items,
                             mesh_back=obj.data.as_pointer() == original, meshes=sorted(bpy.data.meshes.keys()))

        # a file load during a recorded session: stopped by load_pre, the recording kept and closed
        obj = haptic_scene(folder, record=True)
        run = hs.HapticRun(ctx, obj)
        run.start(ctx)
        hs.run_for(ctx, run, 30.0, until=lambda r: len(r.recorder.frames) >= 3)
        path = run.plan.cache_path
        bpy.ops.wm.read_factory_settings(use_empty=True)
        info = cache.cache_info(path)
        out["load"] = dict(running=list(hs.running), forces=forces(run), threads=live_threads(),
                           finished=run.finished, again=run.finish(ctx), frames=info["frames"][:3],
                           complete=info["complete"], objects=list(bpy.data.objects.keys()))

        result(out)
    '''), tmp_path)
    u = got["unregister"]
    assert u["running"] == [] and u["threads"] == [] and u["mesh_back"] and u["meshes"] == ["Sheet"]
    assert u["modifier_on"]
    assert all(f == [0.0, 0.0, 0.0] and s == "closed" for f, s in u["forces"]["devices"].values())
    assert all(e == [0, 0, 0] for e in u["forces"]["efforts"].values())

    r = got["rename"]
    assert not r["alive"] and r["mesh_back"] and r["meshes"] == ["Sheet"]
    assert any(level == "ERROR" and "deleted or renamed" in m for level, m in r["reports"])

    d = got["load"]
    assert d["running"] == [] and d["threads"] == [] and d["finished"] and d["again"] == "done"
    assert all(f == [0.0, 0.0, 0.0] and s == "closed" for f, s in d["forces"]["devices"].values())
    assert all(e == [0, 0, 0] for e in d["forces"]["efforts"].values())
    assert d["frames"] == [1, 2, 3] and d["complete"] and d["objects"] == []


def test_quitting_blender_zeroes_the_force(tmp_path):
    """A session still running when Python exits: the add-on's atexit hook stops it."""
    from test_blender_bake import PRELUDE

    script = tmp_path / "quit.py"
    script.write_text(PRELUDE + TESTS_DIR_LINE + textwrap.dedent(SCENE) + textwrap.dedent('''
        import atexit
        obj = haptic_scene(sys.argv[1], save=False)
        run = hs.HapticRun(bpy.context, obj)
        run.start(bpy.context)
        hs.run_for(bpy.context, run, 30.0, until=lambda r: r.live.steps > 30)
        def report():
            print("EXIT " + json.dumps(dict(forces=forces(run), threads=live_threads(), running=list(hs.running),
                                            reason=run.stop_reason)), flush=True)
        # atexit runs last-in first-out: the add-on's hook (re-added last) runs before the report
        atexit.unregister(hs._at_exit)
        atexit.register(report)
        atexit.register(hs._at_exit)
        print("RUNNING", run.live.running, flush=True)
    '''))
    proc = subprocess.run([sys.executable, str(script), str(tmp_path)], capture_output=True, text=True, timeout=120,
                          cwd=tmp_path)
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-4000:]
    assert "RUNNING True" in proc.stdout
    line = [x for x in proc.stdout.splitlines() if x.startswith("EXIT ")]
    assert line, proc.stdout[-4000:]
    state = json.loads(line[-1][5:])
    assert state["running"] == [] and state["threads"] == [] and state["reason"] == "Blender is quitting"
    assert all(f == [0.0, 0.0, 0.0] and s == "closed" for f, s in state["forces"]["devices"].values())
    assert all(e == [0, 0, 0] for e in state["forces"]["efforts"].values())
