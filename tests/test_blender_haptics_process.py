"""Every device kind through the servo process in a Blender (PyPI bpy) haptic session (issue 16):
a real-Falcon DeviceSpec over the byte-level FTDI emulator (``fakes.ftdi_falcon``: the Falcon
protocol bytes, firmware check, packets, kinematics) and a SpaceMouse over an emulated HID device
(``fakes.hid_puck``), both opened and driven in the servo process. Forces reach the emulated
Falcon's bytes; the SpaceMouse drives its handle; unplugging either mid-session ends the session
cleanly with zero force on the other; a Falcon without firmware loads the user's file and homes
there while Blender keeps ticking; a keyboard hand beside a Falcon is driven by Blender's key
events through the shared memory; the Threads setting and a servo process that cannot start both
keep the threads (the second with a warning, counted); SIGKILL of Blender zeroes the Falcon.

The hooks are given as "module:function" (``tests/`` is on the Blender child's sys.path, which
the servo process inherits), so the emulators live in the servo process; the tests reach them
through ``RemoteEmulator.call``/``get`` and read what each device was last sent from the shared
memory.
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
import textwrap

import pytest

pytest.importorskip("bpy")
pytest.importorskip("pxr")
from test_blender_bake import PRELUDE, run_blender  # noqa: E402
from test_blender_haptics import SCENE, TESTS_DIR_LINE  # noqa: E402

# A Falcon (left) and a SpaceMouse (right), both through hooks the servo process imports.
DEVICES = '''
from tearcloth.haptics.spacemouse import translation_report

def falcon_and_spacemouse(obj):
    devices.find_falcons = lambda: ["EMU-L"]
    devices.falcon_transport_factory = "fakes:ftdi_falcon"
    devices.find_spacemice = lambda: [dict(path=b"/dev/hidraw-fake", vid=0x256F, pid=0xC635,
                                           model="SpaceMouse Compact", layout="split", serial="")]
    devices.spacemouse_hid_factory = "fakes:hid_puck"
    h = obj.tearcloth.haptics
    h.left.device, h.right.device = "FALCON", "SPACEMOUSE"
    h.stop_button = "NONE"

def falcon_pushes(run):
    return any(run.emulators["left"].efforts)
'''


def test_falcon_and_spacemouse_in_the_servo_process(tmp_path):
    got = run_blender(tmp_path, TESTS_DIR_LINE + textwrap.dedent(SCENE) + textwrap.dedent(DEVICES) + textwrap.dedent('''
        folder = sys.argv[1]
        obj = haptic_scene(folder)
        ctx = bpy.context
        falcon_and_spacemouse(obj)
        out = {}

        # both in the servo process: the Falcon's bytes carry a force, the puck drags its handle
        run = hs.HapticRun(ctx, obj)
        run.start(ctx)
        proc = run.live.servo_process
        out["process"] = dict(used=proc is not None, pid=proc.pid if proc else None, phase=run.status.phase,
                              names=[run.devices[h].name for h in ("left", "right")])
        hs.run_for(ctx, run, 30.0, until=lambda r: r.status.phase == "running", interval=0.0)
        hs.run_for(ctx, run, 30.0, until=falcon_pushes)
        pushed = list(run.emulators["left"].efforts)
        x0 = run.live.handle_position("right")[0]
        run.emulators["right"].call("feed", translation_report(350, 0, 0))
        hs.run_for(ctx, run, 30.0, until=lambda r: r.live.handle_position("right")[0] > x0 + 0.01)
        dx = run.live.handle_position("right")[0] - x0
        stats = run.live.servo_process.stats()
        run.emulators["right"].call("unplug")
        t0 = time.perf_counter()
        hs.run_for(ctx, run, 10.0)
        out["unplug_spacemouse"] = dict(
            pushed=pushed, dx=dx, ended_by_itself=run.live.ended, seconds=time.perf_counter() - t0,
            state=run.finish(ctx), reports=run.reports.items, forces=forces(run),
            zero_since=run.emulators["left"].zero_since, threads=live_threads(),
            servo_alive=os.path.exists(f"/proc/{proc.pid}") and "State:\\tZ" not in open(f"/proc/{proc.pid}/status").read(),
            privileges=stats["privileges"].get("process"), rate=stats["rate_hz"])

        # the other way round: the Falcon unplugged, the SpaceMouse closed, Blender still fine
        run = hs.HapticRun(ctx, obj)
        run.start(ctx)
        hs.run_for(ctx, run, 30.0, until=lambda r: r.status.phase == "running", interval=0.0)
        hs.run_for(ctx, run, 30.0, until=falcon_pushes)
        run.emulators["left"].call("unplug")
        hs.run_for(ctx, run, 10.0)
        out["unplug_falcon"] = dict(ended_by_itself=run.live.ended, state=run.finish(ctx), reports=run.reports.items,
                                    forces=forces(run), threads=live_threads())

        # a keyboard hand beside the Falcon, both in the servo process: the arrows move its handle
        h = obj.tearcloth.haptics
        h.right.device = "KEYBOARD"
        run = hs.HapticRun(ctx, obj)
        run.start(ctx)
        hs.run_for(ctx, run, 30.0, until=lambda r: r.status.phase == "running", interval=0.0)
        hs.run_for(ctx, run, 0.2)
        x0 = run.live.handle_position("right")[0]
        for _ in range(5):
            assert run.key("RIGHT_ARROW")
        # the force felt while the handle follows the keys (the largest seen: once it has caught up
        # with the 1 cm the keys asked, the coupling pulls no more, and a loaded machine looked then)
        felt = [0.0]
        def moved(r):
            felt[0] = max(felt[0], r.status.hands["right"].force)
            return r.live.handle_position("right")[0] > x0 + 0.01
        hs.run_for(ctx, run, 30.0, until=moved)
        out["keyboard"] = dict(process=run.live.servo_process is not None, dx=run.live.handle_position("right")[0] - x0,
                               felt=felt[0])
        run.stop("test")
        out["keyboard"].update(state=run.finish(ctx), forces=forces(run))
        h.right.device = "SPACEMOUSE"

        # Threads on request: no servo process, the same devices in Blender's process
        h.servo = "THREADS"
        run = hs.HapticRun(ctx, obj)
        run.start(ctx)
        hs.run_for(ctx, run, 30.0, until=lambda r: r.status.phase == "running", interval=0.0)
        hs.run_for(ctx, run, 30.0, until=lambda r: r.live.steps > 20)
        out["threads"] = dict(process=run.live.servo_process is not None, fallback=run.servo_fallback,
                              servo=sorted(t for t in live_threads() if "servo" in t))
        run.stop("test")
        out["threads"].update(state=run.finish(ctx), forces=forces(run))
        h.servo = "PROCESS"

        # a servo process that cannot start: the threads, with a WARNING, counted
        real, sys.executable = sys.executable, os.path.join(folder, "no-such-python")
        try:
            run = hs.HapticRun(ctx, obj)
            run.start(ctx)
        finally:
            sys.executable = real
        hs.run_for(ctx, run, 30.0, until=lambda r: r.status.phase == "running", interval=0.0)
        hs.run_for(ctx, run, 30.0, until=lambda r: r.live.steps > 20)
        out["fallback"] = dict(process=run.live.servo_process is not None, fallback=run.servo_fallback,
                               count=hs.servo_fallbacks, steps=run.live.steps)
        run.stop("test")
        out["fallback"].update(state=run.finish(ctx), reports=run.reports.items, forces=forces(run))

        # a Falcon without firmware and not homed: the user's file is loaded and it homes in the
        # servo process while Blender keeps ticking (its state and message shown meanwhile)
        devices.falcon_transport_factory = "fakes:ftdi_falcon_unhomed"
        firmware = os.path.join(folder, "nvent_firmware.bin")
        with open(firmware, "wb") as fh:
            fh.write(bytes(range(256)) * 33 + bytes(44))  # 8492 bytes, the size of the real image
        h.firmware_path = firmware
        run = hs.HapticRun(ctx, obj)
        run.start(ctx)
        homing = dict(phase=run.status.phase, process=run.live.servo_process is not None, ticks=0)
        seen, texts = set(), set()
        def watch(r):
            homing["ticks"] += 1
            seen.add(r.devices["left"].state.value)
            texts.add(r.status.text())
            return r.status.phase != "homing"
        hs.run_for(ctx, run, 60.0, until=watch, interval=0.01)
        homing.update(seen=sorted(seen), homing_text=any("homing" in t.lower() for t in texts), phase_after=run.status.phase,
                      firmware=len(run.emulators["left"].get("firmware")))
        hs.run_for(ctx, run, 0.2)
        run.stop("test")
        homing.update(state=run.finish(ctx), reports=run.reports.items, forces=forces(run))
        out["homing"] = homing
        result(out)
    '''), tmp_path, timeout=240)
    p = got["process"]
    assert p["used"] and p["pid"] and p["names"] == ["Falcon EMU-L", "SpaceMouse Compact"], p
    u = got["unplug_spacemouse"]
    assert any(u["pushed"]), u  # the coupling's force reached the emulated Falcon as motor efforts
    assert u["dx"] > 0.01 and u["rate"] > 0.0 and u["privileges"] is True
    assert u["ended_by_itself"] and u["seconds"] < 5.0 and u["state"] == "lost", u
    assert any(level == "ERROR" and "device lost on the right hand" in m and "HID read failed" in m
               for level, m in u["reports"]), u["reports"]
    assert u["forces"]["efforts"]["left"] == [0, 0, 0] and u["zero_since"] is not None  # the Falcon's bytes say zero
    assert all(f == [0.0, 0.0, 0.0] and s in ("closed", "lost") for f, s in u["forces"]["devices"].values()), u
    assert u["threads"] == [] and not u["servo_alive"]
    f = got["unplug_falcon"]
    assert f["ended_by_itself"] and f["state"] == "lost" and f["threads"] == []
    assert any("device lost on the left hand" in m for _, m in f["reports"]), f["reports"]
    assert all(x == [0.0, 0.0, 0.0] for x, _s in f["forces"]["devices"].values())
    k = got["keyboard"]
    assert k["process"] and k["dx"] > 0.01 and k["felt"] > 0.0 and k["state"] == "done", k
    assert k["forces"]["efforts"]["left"] == [0, 0, 0]
    t = got["threads"]
    assert not t["process"] and t["fallback"] is None and t["servo"] and t["state"] == "done", t
    b = got["fallback"]
    assert not b["process"] and "could not be started" in b["fallback"] and b["count"] == 1 and b["steps"] > 20, b
    assert any(level == "WARNING" and "the servo runs in Blender's process" in m for level, m in b["reports"]), b
    m = got["homing"]
    assert m["process"] and m["phase"] == "homing" and m["ticks"] > 1 and "homing" in m["seen"], m
    assert m["homing_text"] and m["phase_after"] == "running" and m["firmware"] == 8492, m
    assert m["state"] == "done" and m["forces"]["efforts"]["left"] == [0, 0, 0], m
    assert any("homing: move each Falcon grip" in msg for _, msg in m["reports"])
    assert b["state"] == "done" and all(x == [0.0, 0.0, 0.0] for x, _s in b["forces"]["devices"].values())


KILLED = '''
folder = sys.argv[1]
obj = haptic_scene(folder, save=False)
falcon_and_spacemouse(obj)
run = hs.HapticRun(bpy.context, obj)
run.start(bpy.context)
hs.run_for(bpy.context, run, 30.0, until=lambda r: r.status.phase == "running", interval=0.0)
hs.run_for(bpy.context, run, 30.0, until=falcon_pushes)
proc = run.live.servo_process
print("READY " + json.dumps(dict(shm=proc.shm_name, servo_pid=proc.pid, stall=proc.stall_timeout_s)), flush=True)
hs.run_for(bpy.context, run, 600.0)  # Blender keeps ticking until it is killed
'''


def test_sigkill_of_blender_zeroes_the_falcon(tmp_path):
    """SIGKILL of the Blender process that simulates (``bench.servo.kill_and_watch``, as the
    bench's ``kill_simulating_process``): the servo process sees its peer gone, sends the Falcon
    zero and exits; the Falcon is watched from here through the shared memory."""
    from tearcloth.bench.servo import kill_and_watch

    script = tmp_path / "killed.py"
    script.write_text(PRELUDE + TESTS_DIR_LINE + textwrap.dedent(SCENE) + textwrap.dedent(DEVICES) + KILLED)
    sim = subprocess.Popen([sys.executable, str(script), str(tmp_path)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                           text=True, cwd=tmp_path)
    try:
        line = ""
        while not line.startswith("READY "):
            line = sim.stdout.readline()
            assert line, sim.stderr.read()[-4000:]
    except BaseException:
        sim.kill()
        sim.wait()
        raise
    info = json.loads(line[6:])
    got = kill_and_watch(sim, info["shm"], int(info["servo_pid"]), 2, watched=[0])  # hand 0: the Falcon
    assert got["efforts"] == [[0, 0, 0]] and math.isfinite(got["zero_s"]) and not got["servo_alive"], got
    # the latency is the bench's servo.kill_zero_ms; printed here only
    print(f"zero {1e3 * got['zero_s']:.2f} ms after SIGKILL (stall timeout {info['stall']:.3f} s)")
