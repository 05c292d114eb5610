"""Live haptic tearing in Blender (Le Gouis et al., WHC 2017): devices grasp the cloth, the
simulation runs on its own thread, the viewport shows the tearing mesh as it happens.

What this file owns
-------------------
* ``HapticRun``: one live session of one object, from validation to the last restored byte.
  It builds the scene exactly as a bake does (``inputs.build_plan``, ``tearcloth.bake.make_session``:
  same material, pins, held handles, colliders, world-space metres), makes one device per hand
  (Falcon, SpaceMouse, keyboard/mouse virtual device, emulated Falcon), couples it
  (``HandCoupling``) and drives a ``haptics.live.LiveSession``.
* ``discover``: the devices plugged in (``haptics.discovery``) and each hand's device state for
  an object's settings, kept in ``discovery`` for the panel; ``save_force_log``.
* The last finished session per object (``finished``: its force log and final device states),
  read by the panel; ``stop_all`` used on unregister, before a file load and when Blender quits;
  the save handlers. Running sessions are registered in ``jobs`` with the bakes; ``running``
  here is that registry's read-only view of the live sessions.

Threads (notes/haptics.md section 8)
------------------------------------
bpy is only touched on the main thread, in ``HapticRun.tick`` (the modal operator's ~60 Hz
TIMER branch, or ``run_for`` headless: the same function). By default (the Servo row: Own
Process) every hand's device is described by a ``DeviceSpec`` (``haptics.device_specs``) and
built, opened and driven in a servo process of its own (``haptics.servo_process``: Blender's
Python cannot hold a tick up, the servo zeroes the force by itself if Blender hangs or dies;
``devices`` are then ``RemoteDevice``s and ``emulators`` ``RemoteEmulator``s): a Falcon loads its
firmware and homes there while ``tick`` polls ``ServoProcess.poll_open`` (its state and message
come back through the shared memory, so Blender never blocks on it); a SpaceMouse is read there;
a keyboard hand is a virtual device there whose target position ``key``/``mouse_move`` set from
this thread through the shared memory (``RemoteDevice.move_by``). The test and demo hooks of
``haptics.discovery`` reach the servo process when they are importable ("module:function" or a
module-level function); a lambda cannot, and a servo process that cannot start cannot serve: both
keep the in-process servo threads, with a WARNING, counted in ``servo_fallbacks`` and said in
``servo_fallback``. Servo = Threads keeps them on request. The in-process servo loop owns one
thread per device; the simulation runs on ``tearcloth-live-sim`` (the native step releases the GIL); the
``LiveRecorder`` (live_job.py) receives frames on the simulation thread and hands them over by a
reference swap (display) and a queue (its cache writer thread, pure USD). Devices are opened on the
main thread and, while a Falcon homes, polled there; from ``LiveSession.open()`` on only the
servo threads drive them.

The live display (why the mesh datablock is swapped)
----------------------------------------------------
The "Tear Cloth" modifier plays a cache, and an MSC cannot show arrays that live in memory. So for
the length of a session the object shows a LIVE MESH: a new datablock that is assigned to
``obj.data`` and rewritten every tick from the latest frame (vertex positions only while the
topology is unchanged, a rebuild when a tear changes it). The user's mesh is never written to:
it is put aside with a fake user (so neither an autosave nor a purge can lose it), and put back,
with its fake-user flag as it was, when the session ends, on unregister, and around every save
(``save_pre``/``save_post``), so a file saved during a session holds the user's mesh, not the live
one. The live mesh is a snapshot of the torn cloth after the modifiers above "Tear Cloth"
(Blender's Cloth rule), so those modifiers and "Tear Cloth" itself are switched off in the
viewport during the session and switched back after; the modifiers below act on the tearing mesh
as they do on a baked cache. The live mesh carries the original's materials and active UV map name
(UVs follow the tear) but no vertex groups, material indices or custom attributes; undo and Edit
Mode are blocked by the modal operator while a session runs. The alternative, writing into the
user's mesh and restoring a copy afterwards, risks exactly what this avoids: a crash or save in the
middle leaves the user's mesh torn.

Time: the scene is put on the Tear Cloth Start frame for the session (the rest state, as for a
bake) and back afterwards; the scene's time stands still meanwhile, so animated colliders and
follow objects hold their Start-frame pose. A recorded session is written at the scene's frame
rate from the Start frame on: frame f holds the cloth at simulated time (f - start) / fps.

Device hooks for tests and demos live in ``tearcloth.haptics.discovery`` (``find_falcons``,
``find_spacemice``, ``falcon_transport_factory``, ``spacemouse_hid_factory``) and are read from
there at call time.
"""
from __future__ import annotations

import atexit
import os
import time
from dataclasses import dataclass, field

import bpy
import numpy as np

from .. import spaces
from ..bake import Progress, delete_state, find_warp_fallbacks, frame_span, make_session
from ..cache import CacheError, CacheWriter
from ..haptics import discovery as devices
from ..haptics.device import DeviceState, HapticError, Workspace
from ..haptics.falcon import FALCON_MAX_FORCE, FalconDevice, read_firmware
from ..haptics.live import FALCON_TO_SCENE, LiveSession, emulated_falcon
from ..haptics.falcon_kinematics import WORKSPACE_CENTRE, WORKSPACE_RADIUS
from ..haptics.servo import HandCoupling
from ..haptics import device_specs
from ..haptics.servo_process import DeviceSpec, ServoProcessError
from ..haptics.spacemouse import SpaceMouseDevice
from ..haptics.virtual import VirtualDevice
from . import jobs, modifier
from .inputs import build_plan, gather_inputs, require_mesh
from .live_job import LiveFrame, LiveRecorder
from .props import STOP_BUTTONS
from .report import BakeError, Reports, log

HANDS = ("left", "right")
TIMER_INTERVAL = 1.0 / 60.0
# Seconds a Falcon may take to be homed (the user moves the grip all the way in and out).
HOMING_TIMEOUT = 60.0
# The keyboard device: a 4 cm workspace like a Falcon's, so the same coupling feels the same.
KEYBOARD_WORKSPACE = Workspace((0.0, 0.0, 0.0), 0.04)
# The SpaceMouse's (SpaceMouseDevice's default): its proxy integrates within a 10 cm ball.
SPACEMOUSE_WORKSPACE = Workspace((0.0, 0.0, 0.0), 0.1)
# Device metres per pixel of Ctrl + mouse motion.
MOUSE_STEP = 1.0e-4
# Arrow keys move the keyboard hand along scene axes (its device frame is the scene's).
KEY_AXES = {
    "LEFT_ARROW": (-1.0, 0.0, 0.0), "RIGHT_ARROW": (1.0, 0.0, 0.0),
    "UP_ARROW": (0.0, 0.0, 1.0), "DOWN_ARROW": (0.0, 0.0, -1.0),
    "PAGE_UP": (0.0, 1.0, 0.0), "PAGE_DOWN": (0.0, -1.0, 0.0),
}
KEYBOARD_HELP = (
    "Keyboard hand: arrows move it left/right/up/down, Page Up/Down away/toward you,",
    "Shift: 5x steps, Ctrl + mouse: move in the view plane, Home: back to the grasp,",
    "Alt: drive the left hand when both hands use the keyboard. Esc ends the session.",
)
STATE_TEXT = {"absent": "Absent", "needs_firmware": "Needs Firmware", "homing": "Homing", "ready": "Ready",
              "lost": "Lost", "closed": "Closed", "unknown": "Not Checked"}

# Sessions in progress by object name (read-only), and the last finished one of each object
# (force log, states).
running = jobs.live_sessions
finished: dict[str, "HapticRun"] = {}
# Sessions whose servo fell back to Blender's threads although Own Process was asked for (a
# device hook the servo process cannot import, or the process would not start); each is also
# a WARNING in that session's reports and its ``servo_fallback`` says why.
servo_fallbacks = 0

# What the last Discover found, and how its SpaceMouse paths read (both for the panel).
discovery: devices.Discovery | None = None
hid_path_text = devices.hid_path_text


def _used_hands(settings) -> dict:
    return {hand: getattr(settings, hand) for hand in HANDS if getattr(settings, hand).use}


def discover(obj=None) -> devices.Discovery:
    """List the Falcons and SpaceMice plugged in (never raises) and, for ``obj``, probe the
    state of each hand's device: a Falcon is opened and closed again (zero force) to see whether
    it needs firmware or homing; nothing is loaded into it."""
    global discovery
    found = devices.scan()
    if obj is not None and obj.name not in jobs.live_sessions:
        settings = obj.tearcloth.haptics
        hands = _used_hands(settings)
        falcons = devices.assign({h: s.falcon_serial for h, s in hands.items() if s.device == "FALCON"},
                                 found.falcons)
        paths = [devices.hid_path_text(m["path"]) for m in found.spacemice]
        mice = devices.assign({h: s.spacemouse_path for h, s in hands.items() if s.device == "SPACEMOUSE"}, paths)
        for hand, s in hands.items():
            found.states[(obj.name, hand)] = devices.probe(hand, s.device, falcons.get(hand), found, mice.get(hand))
    discovery = found
    return found


# ---------------------------------------------------------------------------------------------
# What the panel shows


@dataclass
class HandStatus:
    state: str = "unknown"
    message: str = ""
    device: str = ""
    force: float = 0.0          # N rendered by the device (what the hand feels)
    cloth_force: float = 0.0    # N, |F_tear|: the force the cloth exerts on the handle (scene)


@dataclass
class SessionStatus:
    phase: str = "starting"     # starting, homing, running, ended
    sim_rate: float = 0.0       # simulation steps per second (wall)
    realtime: float = 0.0       # simulated seconds per wall second
    servo_rate: float = 0.0     # servo cycles per second, slowest hand
    sim_time: float = 0.0
    vertices: int = 0
    torn: bool = False
    frames: int = 0             # frames recorded so far
    message: str = ""
    hands: dict = field(default_factory=dict)   # hand -> HandStatus

    def text(self) -> str:
        if self.phase == "homing":
            return self.message or "homing the Falcons: move each grip all the way in and out"
        torn = ", torn" if self.torn else ""
        rec = f", {self.frames} frames recorded" if self.frames else ""
        return f"{self.sim_time:.2f} s simulated, {self.vertices} vertices{torn}{rec}"

    def rates(self) -> str:
        return (f"Simulation {self.sim_rate:.0f} steps/s ({self.realtime:.0%} of real time), "
                f"servo {self.servo_rate:.0f} Hz")


def hand_status(obj, hand: str) -> HandStatus:
    """A hand's state for the panel: the running session's, else the last session's, else what
    Discover found, else 'not checked' (emulated and keyboard hands are always ready)."""
    run = jobs.live_sessions.get(obj.name) or finished.get(obj.name)
    if run is not None and hand in run.status.hands:
        return run.status.hands[hand]
    s = getattr(obj.tearcloth.haptics, hand)
    if s.device in ("EMULATED", "KEYBOARD"):
        state, message = devices.probe(hand, s.device, None, devices.Discovery(), None)
        return HandStatus(state, message)
    if discovery is not None and (obj.name, hand) in discovery.states:
        return HandStatus(*discovery.states[(obj.name, hand)])
    return HandStatus("unknown", "press Discover to look for devices")


# ---------------------------------------------------------------------------------------------
# The live mesh


def write_live_mesh(mesh, co: np.ndarray, triangles: np.ndarray, corner_uv, uv_name: str, smooth: bool,
                    rebuild: bool) -> None:
    """Show ``co`` (n, 3, object-local Blender units) on ``mesh``; with ``rebuild`` (or a new vertex
    count) its faces are made anew from ``triangles`` (m, 3), with per-corner UVs."""
    if rebuild or len(mesh.vertices) != len(co):
        mesh.clear_geometry()
        n, m = len(co), len(triangles)
        mesh.vertices.add(n)
        mesh.loops.add(3 * m)
        mesh.polygons.add(m)
        mesh.loops.foreach_set("vertex_index", np.ascontiguousarray(triangles, dtype=np.int32).ravel())
        mesh.polygons.foreach_set("loop_start", np.arange(0, 3 * m, 3, dtype=np.int32))
        if corner_uv is not None and len(corner_uv) == m:
            layer = mesh.uv_layers.new(name=uv_name or "UVMap")
            layer.data.foreach_set("uv", np.ascontiguousarray(corner_uv, dtype=np.float32).ravel())
        rebuild = True
    mesh.vertices.foreach_set("co", np.ascontiguousarray(co, dtype=np.float32).ravel())
    if rebuild:
        mesh.update(calc_edges=True)
        if smooth:
            mesh.shade_smooth()
    else:
        mesh.update()


def _is_smooth(mesh) -> bool:
    sharp = mesh.attributes.get("sharp_face")
    if sharp is None or not len(mesh.polygons):
        return len(mesh.polygons) > 0
    values = np.empty(len(mesh.polygons), dtype=bool)
    sharp.data.foreach_get("value", values)
    return not values.all()


# ---------------------------------------------------------------------------------------------
# One session


class HapticRun:
    """One live session of one object (see the module docstring).

    ``HapticRun(context, obj)`` validates and builds everything without opening a device (a
    ``BakeError`` with every problem in ``reports`` if it cannot: the scene is left as it was);
    ``start(context)`` opens the devices (homing Falcons are polled by ``tick`` until ready) and
    starts the session; ``tick(context)`` (main thread, ~60 Hz) shows the latest frame and updates
    ``status``, returning False once the session has ended; ``stop(reason)`` (any thread, no bpy)
    ends it with zero force; ``finish(context)`` restores the object and scene and says how it
    ended in ``reports``. ``key``/``mouse_move`` drive keyboard hands.
    """

    kind = jobs.LIVE

    def __init__(self, context, obj, reports: Reports | None = None):
        self.reports = reports if reports is not None else Reports()
        self.status = SessionStatus()
        self.devices: dict = {}
        self.emulators: dict = {}
        self.kinds: dict = {}
        self.live: LiveSession | None = None
        self.recorder: LiveRecorder | None = None
        self.stop_reason: str | None = None
        self._stop_request: str | None = None
        self.state: str | None = None        # how it ended: done, lost, error (None while running)
        self.finished = False
        self.abandoned = False               # a file load replaced the data this run knew
        self._opened_by_us: list = []
        self._mesh_swapped = False
        self._switched: list = []
        self._shown = None
        self._tris = None
        self._homing_deadline = 0.0
        self._rate_mark = None
        self._servo_mark = 0.0

        r = self.reports
        require_mesh(obj, r)
        self.object_name = obj.name
        scene = context.scene
        self.scene_name = scene.name
        self.original_frame = scene.frame_current
        if obj.library is not None or obj.data.library is not None:
            r.error(f"{obj.name}: a linked object cannot be torn live; make it local first")
        if obj.mode != "OBJECT":
            r.error(f"{obj.name}: leave {obj.mode.replace('_', ' ').title()} Mode before starting a haptic session")
        for other in jobs.live_sessions.values():
            r.error(f"a haptic session is already running on {other.object_name!r} (devices are shared): "
                    "stop it first (Esc)")
        if obj.name in jobs.bakes:
            r.error(f"{obj.name}: its bake is running; cancel it first (Esc)")
        settings = obj.tearcloth.haptics
        hands = _used_hands(settings)
        if not hands:
            r.error(f"{obj.name}: no hand is in use; tick Left Hand or Right Hand (Physics > Tear Cloth > Haptics)")
        for kind, attr, what in (("FALCON", "falcon_serial", "Falcon"),
                                 ("SPACEMOUSE", "spacemouse_path", "SpaceMouse")):
            chosen = [getattr(s, attr) for s in hands.values() if s.device == kind and getattr(s, attr)]
            if len(chosen) != len(set(chosen)):
                r.error(f"{obj.name}: both hands chose the same {what} ({chosen[0]!r}); a device can hold one hand")
        self.firmware_path = None
        if any(s.device == "FALCON" for s in hands.values()) and settings.firmware_path:
            path = os.path.normpath(bpy.path.abspath(settings.firmware_path))
            try:
                read_firmware(path)  # checked now: a wrong file must not reach a device
                self.firmware_path = path
            except HapticError as exc:
                r.error(f"{obj.name}: {exc}")
        r.raise_if_errors()

        self.record = bool(settings.record)
        try:
            if scene.frame_current != obj.tearcloth.frame_start:
                scene.frame_set(obj.tearcloth.frame_start)  # the rest state, as for a bake
            plan, sources = build_plan(context, obj, hands={h: s.vertex_group for h, s in hands.items()},
                                       with_cache=self.record, reports=r)
            inputs = gather_inputs(context, sources, plan.frame_start, plan.scale)
            self.plan = plan
            self.matrix = inputs.object_matrix
            session, _held = make_session(plan, inputs.bodies, 0.0)
            if plan.material.grained:  # said at the start, as a bake says it at its end
                said = Progress(obj.name, plan.frame_start, plan.frame_end)
                find_warp_fallbacks(plan, session.cloth, said)
                if said.warp_text():
                    r.warning(f"{obj.name}: {said.warp_text()}")
            self.servo_fallback = None  # why the servo runs in threads although the process was asked for
            use_process = settings.servo == "PROCESS"
            if use_process:
                hooks = self._unimportable_hooks(hands)
                if hooks:
                    self._fall_back(f"the device hook {hooks} cannot be imported by the servo process")
                    use_process = False
            self._make_devices(settings, hands, plan, session, use_process)
            rebase = all(s.mapping == "FIT" for s in hands.values())
            if not rebase and any(s.mapping == "FIT" for s in hands.values()):
                r.warning(f"{obj.name}: one hand maps by scale and offset, so the other's Fit to Region mapping is "
                          "centred on its grasp without following where its device is: hold that grip centred "
                          "when the session starts")
            dt = float(settings.time_step)
            # Frames for the display (and the cache) about every 1/120 s of simulated time, and at least
            # twice per scene frame, so every scene frame is recorded close to its own time.
            record_every = max(1, int(min(1.0 / 120.0, 0.5 / plan.fps) / dt))
            self.recorder = LiveRecorder(plan.fps, plan.frame_start, self.matrix, plan.scale,
                                         plan.corner_uv is not None)
            self._live_args = dict(dt=dt, stop_buttons=STOP_BUTTONS[settings.stop_button] or None, recorder=self.recorder,
                                   record_every=record_every, rebase=rebase, on_device_lost="stop")
            self._new_live(session, hands)
        except HapticError as exc:
            r.error(f"{obj.name}: {exc}")
        except BakeError:
            pass  # already in the reports
        except (ValueError, CacheError) as exc:
            r.error(f"{obj.name}: {exc}")
        if r.errors:
            self._restore_frame()
            r.raise_if_errors()
        self.hands = list(hands)
        self.uv_name = obj.data.uv_layers.active.name if obj.data.uv_layers.active is not None else "UVMap"
        self.smooth = _is_smooth(obj.data)
        self.status.hands = {h: HandStatus("absent", "not opened yet", self.devices[h].name) for h in self.hands}

    # -- devices -------------------------------------------------------------------------------

    def _new_live(self, session, hands: dict) -> None:
        self.live = LiveSession(session, {h: (s.vertex_group, self.devices[h], self._couplings[h]) for h, s in hands.items()},
                                **self._live_args)
        if self.live.servo_process is not None:  # what this process sees of the devices there
            self.devices = {h: self.live.device(h) for h in hands}
            self.emulators = {h: self.live.servo_process.emulator(h) for h in hands}

    @staticmethod
    def _unimportable_hooks(hands: dict) -> str:
        """The test/demo device hooks (``haptics.discovery``) a servo process could not import."""
        kinds = {s.device for s in hands.values()}
        bad = [name for name, kind in (("falcon_transport_factory", "FALCON"), ("spacemouse_hid_factory", "SPACEMOUSE"))
               if kind in kinds and getattr(devices, name) is not None and device_specs.importable(getattr(devices, name)) is None]
        return ", ".join(bad)

    def _fall_back(self, why: str) -> None:
        """The servo runs in this process's threads instead of its own process: said, counted."""
        global servo_fallbacks
        servo_fallbacks += 1
        self.servo_fallback = why
        self.reports.warning(f"{self.object_name}: {why}: the servo runs in Blender's process (threads), where "
                             "Blender's own Python can delay its ticks")

    def _make_devices(self, settings, hands: dict, plan, session, use_process: bool = False) -> None:
        r = self.reports
        found_falcons = found_mice = None
        if any(s.device == "FALCON" for s in hands.values()):
            found_falcons = devices.quietly(devices.find_falcons)
        if any(s.device == "SPACEMOUSE" for s in hands.values()):
            found_mice = devices.quietly(devices.find_spacemice)
        falcons = devices.assign({h: s.falcon_serial for h, s in hands.items() if s.device == "FALCON"},
                                 found_falcons or [])
        mouse_paths = [devices.hid_path_text(m["path"]) for m in found_mice or []]
        mice = devices.assign({h: s.spacemouse_path for h, s in hands.items() if s.device == "SPACEMOUSE"},
                              mouse_paths)
        scale = plan.scale
        centroids = {h: plan.vertices[plan.groups[s.vertex_group] >= 0.5].mean(axis=0) for h, s in hands.items()}
        self._couplings = {}
        in_process = not use_process
        for hand, s in hands.items():
            self.kinds[hand] = s.device
            rotation = FALCON_TO_SCENE if s.device in ("FALCON", "EMULATED") else None
            if s.device == "FALCON":
                serial = falcons.get(hand)
                if serial is None:
                    r.error(f"the {hand} hand: no Novint Falcon found (check USB, power and, on Linux, the udev rule "
                            "for 0403:cb48); press Discover to list the connected ones")
                    continue
                if serial not in found_falcons:
                    r.error(f"the {hand} hand: the Falcon {serial!r} is not connected; connected: "
                            f"{', '.join(found_falcons) or 'none'}")
                    continue
                if in_process:
                    dev = FalconDevice(serial, hand=hand, firmware_path=self.firmware_path,
                                       transport_factory=device_specs.resolve(devices.falcon_transport_factory)
                                       if isinstance(devices.falcon_transport_factory, str) else devices.falcon_transport_factory,
                                       max_force=min(float(s.max_force), FALCON_MAX_FORCE))
                else:  # opened there: firmware and homing in the servo process, its state shown here
                    dev = DeviceSpec(".haptics.device_specs:falcon", dict(
                        serial=serial, hand=hand, firmware_path=self.firmware_path, max_force=float(s.max_force),
                        transport=device_specs.importable(devices.falcon_transport_factory)))
            elif s.device == "SPACEMOUSE":
                path = mice.get(hand)
                if path is None or path not in mouse_paths:
                    r.error(f"the {hand} hand: no 3Dconnexion SpaceMouse found"
                            + (f" at {path!r}" if path else "") + " (on Linux, check the udev rule for hidraw access)")
                    continue
                model = next(m for m in found_mice if devices.hid_path_text(m["path"]) == path)
                factory = devices.spacemouse_hid_factory
                if in_process:
                    factory = device_specs.resolve(factory) if isinstance(factory, str) else factory
                    hid = factory(devices.hid_path_bytes(path)) if factory is not None else None
                    dev = SpaceMouseDevice(devices.hid_path_bytes(path), vid=model["vid"], pid=model["pid"], hid_device=hid,
                                           hand=hand)
                else:
                    dev = DeviceSpec(".haptics.device_specs:spacemouse", dict(
                        path=path, hand=hand, vid=model["vid"], pid=model["pid"], hid=device_specs.importable(factory)))
            elif s.device == "KEYBOARD":
                if in_process:
                    dev = VirtualDevice(f"keyboard ({hand} hand)", workspace=KEYBOARD_WORKSPACE,
                                        max_force=float(s.max_force), hand=hand)
                else:  # Blender's key events set its target through the shared memory (RemoteDevice.move_by)
                    dev = DeviceSpec(".haptics.device_specs:keyboard", dict(
                        hand=hand, radius=KEYBOARD_WORKSPACE.radius, max_force=float(s.max_force)), target_arg="target")
            else:
                args = dict(serial=f"EMU-{hand.upper()}", hand=hand,
                            direction=tuple(float(v) for v in self._pull_direction(hand, centroids, plan)),
                            distance=float(settings.demo_pull), hold_s=float(settings.demo_hold),
                            pull_s=float(settings.demo_pull_time), max_force=min(float(s.max_force), FALCON_MAX_FORCE))
                simulated = settings.demo_pace == "SIMULATION"
                if in_process:
                    dev, self.emulators[hand] = emulated_falcon(clock=(lambda: session.time) if simulated else None, **args)
                else:  # built in the servo process; the simulated time reaches it through shared memory
                    dev = DeviceSpec(".haptics.live:emulated_falcon", args, sim_clock_arg="clock" if simulated else None)
            self.devices[hand] = dev
            gains = dict(k_position=float(s.k_position), k_velocity=float(s.k_velocity),
                         force_scale=float(s.force_scale))
            workspace = (KEYBOARD_WORKSPACE if s.device == "KEYBOARD" else SPACEMOUSE_WORKSPACE if s.device == "SPACEMOUSE"
                         else Workspace(WORKSPACE_CENTRE, WORKSPACE_RADIUS)) if isinstance(dev, DeviceSpec) else dev.workspace
            if s.mapping == "FIT":
                self._couplings[hand] = HandCoupling.fit(workspace, centroids[hand], s.region_radius * scale,
                                                         rotation=rotation, **gains)
            else:
                offset = tuple(float(v) * scale for v in s.offset)
                self._couplings[hand] = HandCoupling(scale=float(s.scale), offset=offset, rotation=rotation, **gains)
        r.raise_if_errors()

    @staticmethod
    def _pull_direction(hand: str, centroids: dict, plan) -> np.ndarray:
        """An emulated hand pulls away from the other hand (or from the cloth's centre), in the
        Falcon's frame."""
        others = [c for h, c in centroids.items() if h != hand]
        away = centroids[hand] - (others[0] if others else plan.vertices.mean(axis=0))
        if not np.linalg.norm(away) > 1e-9:
            away = np.array([1.0 if hand == "right" else -1.0, 0.0, 0.0])
        return np.asarray(FALCON_TO_SCENE, dtype=float).T @ (away / np.linalg.norm(away))

    def _close_devices(self) -> None:
        for dev in self.devices.values():
            try:
                dev.close()  # zero force first; idempotent
            except HapticError as exc:
                log.warning("%s: %s", dev.name, exc)

    # -- starting ------------------------------------------------------------------------------

    def start(self, context) -> None:
        """Open the devices and start (or, while a Falcon homes, wait in ``tick``). BakeError,
        with every device closed again and the scene as it was, if it cannot."""
        jobs.add(self)
        if self.live.servo_process is not None:
            if self._begin_process(context):
                return
        try:
            for hand in self.hands:
                dev = self.devices[hand]
                try:
                    state = dev.open()
                except HapticError as exc:
                    raise HapticError(f"the {hand} hand: {exc}") from exc
                self._note_device(hand)
                if state is DeviceState.NEEDS_FIRMWARE:
                    raise HapticError(f"the {hand} hand: {dev.message}")
                if state not in (DeviceState.READY, DeviceState.HOMING):
                    raise HapticError(f"the {hand} hand: {dev.name} is not ready ({state.value}): {dev.message}")
        except HapticError as exc:
            self.reports.error(f"{self.object_name}: {exc}; force set to zero")
            self._abort()
            self.reports.raise_if_errors()
        if any(d.state is DeviceState.HOMING for d in self.devices.values()):
            self.status.phase = "homing"
            self._homing_deadline = time.perf_counter() + HOMING_TIMEOUT
            self.reports.info(f"{self.object_name}: homing: move each Falcon grip all the way in and out "
                              "(its LED turns green)")
            return
        if not self._go(context):
            self.reports.raise_if_errors()

    def _begin_process(self, context) -> bool:
        """Start the servo process and open the devices there (a Falcon homes there: ``tick``
        polls it); True when handled, False when it could not start and the session falls back to
        the in-process servo threads (said and counted)."""
        proc = self.live.servo_process
        homing = any(k == "FALCON" for k in self.kinds.values())
        try:
            proc.begin_open(HOMING_TIMEOUT if homing else 0.0)
            if homing:
                self.status.phase = "homing"
                self._homing_deadline = time.perf_counter() + HOMING_TIMEOUT + proc.start_timeout_s
                self.reports.info(f"{self.object_name}: homing: move each Falcon grip all the way in and out "
                                  "(its LED turns green)")
                return True
            while proc.poll_open(0.05) is None:
                pass
        except ServoProcessError as exc:
            self._rebuild_in_process(str(exc))
            return False
        except HapticError as exc:
            self.reports.error(f"{self.object_name}: {exc}; force set to zero")
            self._abort()
            self.reports.raise_if_errors()
        if not self._go(context):
            self.reports.raise_if_errors()
        return True

    def _rebuild_in_process(self, why: str) -> None:
        """The servo process could not start: the same session with the devices opened here."""
        self.live.stop()
        cloth = self.live.cloth
        for hand in self.live.hands:
            cloth.release_handle(self.live.handle(hand))
        self._fall_back(why)
        obj = bpy.data.objects.get(self.object_name)
        settings = obj.tearcloth.haptics
        hands = _used_hands(settings)
        self.devices, self.emulators = {}, {}
        self._make_devices(settings, hands, self.plan, self.live.session, use_process=False)
        self._new_live(self.live.session, hands)

    def _abort(self) -> None:
        """Undo a start that failed before the session ran: zero force, devices closed."""
        self.stop_reason = self.stop_reason or "could not start"
        self._close_devices()
        if self.recorder is not None:
            self.recorder.close()
        self.state = "error"
        self.status.phase = "ended"
        jobs.remove(self)
        self._restore_frame()
        self.finished = True

    def _go(self, context) -> bool:
        """Every device is ready: open the cache, start the session, show the live mesh."""
        obj = bpy.data.objects.get(self.object_name)
        try:
            if obj is None:
                raise BakeError(f"{self.object_name}: the object was deleted or renamed")
            cloth = self.live.cloth
            first = LiveFrame(0.0, np.array(cloth.positions), np.array(cloth.triangles),
                              np.array(cloth.corner_uv) if self.plan.corner_uv is not None else None,
                              np.array(cloth.velocities))
            # Binds, warms up, starts the servo threads (zero force until the first step: its
            # watchdog sees no simulation yet). Before the cache: a session that cannot start
            # must not have replaced the old recording.
            self.live.open()
            for hand in self.hands:
                self._note_device(hand)
            if self.record:
                modifier.detach_cache(obj)  # Blender lets go of the old cache before it is replaced
                delete_state(self.plan.cache_path)  # a bake cannot resume a live recording
                self.recorder.writer = CacheWriter(
                    self.plan.cache_path, self.plan.prim_name, self.plan.fps, "Z", self.plan.scale,
                    object_name=self.object_name, fingerprint=self.plan.fingerprint)
            self._swap_in(obj, first)
            self.recorder.start(first)
            self.live.start()
        except (HapticError, BakeError, CacheError, ValueError, OSError) as exc:
            self.reports.error(f"{self.object_name}: {exc}; force set to zero")
            if self.live is not None:
                self.live.stop()
            self._restore_object()
            self._abort()
            return False
        self.status.phase = "running"
        self._rate_mark = (time.perf_counter(), self.live.steps, float(self.live.session.time))
        names = ", ".join(f"{h}: {self.devices[h].name}" for h in self.hands)
        self.reports.info(f"{self.object_name}: haptic session started ({names})"
                          + (f"; recording into {self.plan.cache_path}" if self.record else ""))
        return True

    def _swap_in(self, obj, first: LiveFrame) -> None:
        original = obj.data
        self.original_mesh_name = original.name
        self.original_fake_user = original.use_fake_user
        live = bpy.data.meshes.new(f"{obj.name} (Tear Cloth live)")
        for material in original.materials:
            live.materials.append(material)
        self._write(live, first, rebuild=True)
        original.use_fake_user = True  # nothing but this object may hold it during the session
        obj.data = live
        self.live_mesh_name = live.name
        self._mesh_swapped = True
        mods = list(obj.modifiers)
        md = modifier.find_modifier(obj)
        upto = mods.index(md) + 1 if md is not None else 0
        self._switched = [m.name for m in mods[:upto] if m.show_viewport]
        for name in self._switched:
            obj.modifiers[name].show_viewport = False

    def _write(self, mesh, frame: LiveFrame, rebuild: bool) -> None:
        local = spaces.world_si_to_local(frame.positions, self.matrix, self.plan.scale)
        write_live_mesh(mesh, local, frame.triangles, frame.corner_uv, self.uv_name, self.smooth, rebuild)
        self._tris = frame.triangles
        self._shown = frame

    # -- the tick (main thread) ----------------------------------------------------------------

    def request_stop(self, reason: str) -> None:
        """Ask the next tick to end the session (from a button; any thread)."""
        self._stop_request = reason

    def tick(self, context) -> bool:
        """Show the latest frame and refresh ``status``; False once the session has ended (then
        call ``finish``)."""
        if self.finished or self.state is not None:
            return False
        if self._stop_request is not None:
            self.stop(self._stop_request)
            return False
        if self.status.phase == "homing":
            return self._tick_homing(context)
        live = self.live
        obj = bpy.data.objects.get(self.object_name)
        if obj is None:
            self.reports.error(f"{self.object_name}: the object was deleted or renamed during the session")
            self.stop("the object is gone")
            return False
        mesh = bpy.data.meshes.get(self.live_mesh_name)
        if mesh is None or obj.data != mesh:
            self.reports.warning(f"{self.object_name}: the object's mesh was replaced during the session (undo?); "
                                 "session stopped")
            self.stop("the mesh was replaced")
            return False
        frame = self.recorder.latest
        if frame is not None and frame is not self._shown and obj.mode == "OBJECT":
            same = self._tris is not None and frame.triangles.shape == self._tris.shape \
                and np.array_equal(frame.triangles, self._tris)
            self._write(mesh, frame, rebuild=not same)
        self._update_status()
        if self.recorder.error is not None:
            self.reports.error(f"{self.object_name}: recording failed: {self.recorder.error}")
            self.stop("recording failed")
            return False
        return not live.ended

    def _tick_homing(self, context) -> bool:
        proc = self.live.servo_process
        try:
            if proc is not None:  # the Falcons home in the servo process; their states read from there
                for hand in self.hands:
                    self._note_device(hand)
                if proc.poll_open(0.0) is not None:
                    return self._go(context)
                if time.perf_counter() > self._homing_deadline:
                    raise HapticError(f"not homed within {HOMING_TIMEOUT:.0f} s")
                self.status.message = "homing: " + "; ".join(self.devices[h].message for h in self.hands)
                return True
            for hand in self.hands:
                dev = self.devices[hand]
                if dev.state in (DeviceState.HOMING, DeviceState.READY):
                    dev.poll()  # zero force (the servo has not started); keeps every link alive
                self._note_device(hand)
                if dev.state in (DeviceState.LOST, DeviceState.CLOSED, DeviceState.ABSENT):
                    raise HapticError(f"the {hand} hand: {dev.message}")
            if all(d.state is DeviceState.READY for d in self.devices.values()):
                return self._go(context)
            if time.perf_counter() > self._homing_deadline:
                raise HapticError(f"not homed within {HOMING_TIMEOUT:.0f} s: move each grip all the way in and out "
                                  "until its LED turns green, then start again")
        except HapticError as exc:
            self.reports.error(f"{self.object_name}: {exc}; force set to zero")
            self._abort()
            return False
        self.status.message = "homing: " + "; ".join(self.devices[h].message for h in self.hands
                                                     if self.devices[h].state is DeviceState.HOMING)
        return True

    def _note_device(self, hand: str) -> None:
        dev = self.devices[hand]
        h = self.status.hands.setdefault(hand, HandStatus())
        h.state, h.message, h.device = dev.state.value, dev.message, dev.name
        h.force = float(np.linalg.norm(dev.force))
        servo = self.live.servo if self.live is not None else None
        sample = servo.mailbox(hand).latest if servo is not None else None
        h.cloth_force = float(np.linalg.norm(sample.f_tear)) if sample is not None else 0.0

    def _update_status(self) -> None:
        live, st = self.live, self.status
        for hand in self.hands:
            self._note_device(hand)
        now = time.perf_counter()
        t0, steps0, sim0 = self._rate_mark
        if now - t0 >= 0.5:
            steps, sim = live.steps, float(live.session.time)
            st.sim_rate = (steps - steps0) / (now - t0)
            st.realtime = (sim - sim0) / (now - t0)
            self._rate_mark = (now, steps, sim)
        if live.servo is not None and now - self._servo_mark >= 1.0:
            self._servo_mark = now
            st.servo_rate = float(live.servo.stats()["rate_hz"])
        frame = self.recorder.latest
        if frame is not None:
            st.vertices = len(frame.positions)
            st.sim_time = frame.time
        st.torn = live.first_tear_step is not None
        st.frames = len(self.recorder.frames)

    # -- keyboard and mouse --------------------------------------------------------------------

    @property
    def keyboard_hands(self) -> list:
        return [h for h in ("right", "left") if self.kinds.get(h) == "KEYBOARD"]

    def _keyboard_device(self, alt: bool):
        hands = self.keyboard_hands
        if not hands or self.status.phase != "running":
            return None
        hand = "left" if alt and "left" in hands else hands[0]
        return self.devices[hand]

    def key(self, key: str, shift: bool = False, alt: bool = False, step: float | None = None) -> bool:
        """An arrow / Page Up / Page Down / Home key press for a keyboard hand; True if used."""
        dev = self._keyboard_device(alt)
        if dev is None:
            return False
        if key == "HOME":
            dev.set_position(dev.workspace.centre)
            return True
        axis = KEY_AXES.get(key)
        if axis is None:
            return False
        if step is None:
            obj = bpy.data.objects.get(self.object_name)
            step = obj.tearcloth.haptics.keyboard_step if obj is not None else 0.002
        dev.move_by(np.asarray(axis) * step * (5.0 if shift else 1.0))
        return True

    def mouse_move(self, dx: float, dy: float, view_rotation=None, alt: bool = False) -> bool:
        """Ctrl + mouse motion (pixels) moves a keyboard hand in the view plane."""
        dev = self._keyboard_device(alt)
        if dev is None:
            return False
        r = np.eye(3)[:, [0, 2, 1]] if view_rotation is None else np.asarray(view_rotation, dtype=float)
        dev.move_by((dx * r[:, 0] + dy * r[:, 1]) * MOUSE_STEP)
        return True

    # -- ending --------------------------------------------------------------------------------

    def stop(self, reason: str) -> None:
        """End the session: zero force on every device, threads joined, devices closed, the cache
        finished. Touches no bpy (safe in handlers and at exit); idempotent."""
        if self.stop_reason is None:
            self.stop_reason = reason
        if self.live is not None:
            self.live.stop()
        self._close_devices()
        if self.recorder is not None:
            self.recorder.close()
        self.status.phase = "ended"
        for hand in getattr(self, "hands", []):
            self._note_device(hand)

    def finish(self, context=None) -> str:
        """Stop if needed, put the user's mesh, modifiers and frame back, show the recording on
        the Tear Cloth modifier and report how the session ended. Returns the state: 'done',
        'lost' (a device was lost) or 'error'. Idempotent."""
        if self.finished:
            return self.state
        self.stop(self.stop_reason or "finished")
        self.finished = True
        jobs.remove(self)
        finished[self.object_name] = self
        live, r, name = self.live, self.reports, self.object_name
        if live.error is not None:
            self.state = "error"
            r.error(f"{name}: the simulation stopped ({live.error}); force set to zero")
        elif live.lost_hands:
            self.state = "lost"
            r.error(f"{name}: haptic session ended: {live.end_reason}")
        else:
            self.state = "error" if r.errors else "done"  # e.g. the object vanished during the session
        frames = self.recorder.frames
        kept = f"frames {frame_span(frames[0], frames[-1])}" if frames else "no frame"
        if self.recorder.error is not None:
            self.state = "error"
            r.error(f"{name}: recording stopped: {self.recorder.error}; {kept} kept")
        if self.recorder.dropped:
            r.warning(f"{name}: {self.recorder.dropped} frames were dropped because the cache writer fell behind")
        if self.abandoned:
            r.warning(f"{name}: haptic session stopped ({self.stop_reason}); force set to zero"
                      + (f", {kept} recorded" if self.record else ""))
            return self.state
        self._restore_object()
        self._restore_frame()
        obj = bpy.data.objects.get(name)
        if self.record and frames and obj is not None and modifier.is_enabled(obj):
            try:
                modifier.attach_cache(obj, self.plan.cache_path, self.plan.prim_name)
            except BakeError as exc:
                r.error(str(exc))
        if self.state == "done":
            why = live.end_reason if live.end_reason and live.end_reason.startswith("stop button") else self.stop_reason
            r.info(f"{name}: haptic session ended ({why}) after {live.steps} steps, "
                   f"{float(live.session.time):.2f} s simulated; force set to zero")
        if self.record:
            r.info(f"{name}: recorded {kept} into {self.plan.cache_path}" if frames else f"{name}: nothing recorded")
        return self.state

    def _holder(self, live):
        """The object showing the live mesh: ours by name, or (renamed meanwhile) whichever holds it."""
        obj = bpy.data.objects.get(self.object_name)
        if obj is not None and (live is None or obj.data == live):
            return obj
        if live is not None:
            return next((o for o in bpy.data.objects if o.data == live), obj)
        return obj

    def _switch_modifiers(self, obj, on: bool) -> None:
        for mod_name in self._switched:
            md = obj.modifiers.get(mod_name)
            if md is not None:
                md.show_viewport = on

    def _restore_object(self) -> None:
        """The user's mesh and modifier switches back (only if the live mesh is still in place)."""
        if not self._mesh_swapped:
            return
        self._mesh_swapped = False
        original = bpy.data.meshes.get(self.original_mesh_name)
        live = bpy.data.meshes.get(self.live_mesh_name)
        obj = self._holder(live)
        if obj is not None and original is not None and (live is None or obj.data == live):
            obj.data = original
        if original is not None:
            original.use_fake_user = self.original_fake_user
        if live is not None and live.users == 0:
            bpy.data.meshes.remove(live)
        if obj is not None:
            self._switch_modifiers(obj, True)
        self._switched = []

    def _restore_frame(self) -> None:
        scene = bpy.data.scenes.get(self.scene_name)
        if scene is not None and scene.frame_current != self.original_frame:
            scene.frame_set(self.original_frame)

    def swap_for_save(self, saving: bool) -> None:
        """``save_pre`` (True): the user's mesh goes back on the object for the file; ``save_post``
        (False): the live mesh returns."""
        if not self._mesh_swapped:
            return
        original = bpy.data.meshes.get(self.original_mesh_name)
        live = bpy.data.meshes.get(self.live_mesh_name)
        obj = self._holder(live) if saving else bpy.data.objects.get(self.object_name)
        if obj is None or original is None or live is None:
            return
        if saving and obj.data == live:
            # The live mesh is left without a user for the save: Blender does not write it.
            obj.data = original
            original.use_fake_user = self.original_fake_user
            self._switch_modifiers(obj, True)
        elif not saving and obj.data == original:
            original.use_fake_user = True
            obj.data = live
            self._switch_modifiers(obj, False)

    # -- the force log -------------------------------------------------------------------------

    def save_force_log(self, folder: str, reports: Reports) -> tuple | None:
        """Write the force log (CSV) and its Fig. 6-style plot (PNG) into ``folder``."""
        if self.live is None or not self.live.steps:
            reports.error(f"{self.object_name}: the session never ran; there is no force log")
            return None
        stamp = time.strftime("%Y%m%d-%H%M%S")
        base = os.path.join(folder, f"{self.plan.prim_name}_forces_{stamp}")
        try:
            os.makedirs(folder, exist_ok=True)
            try:
                out = self.live.save_force_log(base + ".csv", base + ".png",
                                               title=f"{self.object_name}: force felt by each hand")
            except ImportError as exc:  # no matplotlib in this Blender: the CSV alone
                out = self.live.save_force_log(base + ".csv")
                reports.warning(f"no plot: {exc} (install matplotlib for the PNG)")
        except OSError as exc:
            reports.error(f"{self.object_name}: cannot write the force log into {folder}: {exc.strerror or exc}")
            return None
        reports.info(f"{self.object_name}: force log written to " + " and ".join(p for p in out if p))
        return out


# ---------------------------------------------------------------------------------------------
# Driving headless, stopping everything


def run_for(context, run: HapticRun, seconds: float, until=None, interval: float = TIMER_INTERVAL) -> HapticRun:
    """Tick a started run on this thread like the modal operator's TIMER does, for ``seconds``
    of wall time, until ``until(run)`` is true or the session ends; it is still running when the
    time is up (call ``stop``/``finish``). For scripts, background mode and tests."""
    end = time.perf_counter() + float(seconds)
    try:
        while run.tick(context):
            if until is not None and until(run):
                break
            if time.perf_counter() >= end:
                break
            time.sleep(interval)
    except BaseException:  # never leave devices pushing behind an exception (KeyboardInterrupt included)
        run.stop("interrupted by an error")
        raise
    return run


def stop_all(reason: str, restore: bool = True) -> None:
    """Stop every session with zero force. ``restore``: put the objects back now (unregister);
    otherwise touch no Blender data (a file load replaces it, and at exit it is going away)."""
    for run in jobs.of_kind(jobs.LIVE):
        log.warning("%s: stopping the haptic session (%s); force set to zero", run.object_name, reason)
        run.stop(reason)
        if not restore:
            run.abandoned = True
        try:
            run.finish()
        except Exception as exc:  # noqa: BLE001 - a handler must not fail
            log.error("%s: could not restore after the session: %s", run.object_name, exc)
        jobs.remove(run)


def _at_exit() -> None:
    stop_all("Blender is quitting", restore=False)


atexit.register(_at_exit)


def swap_all_for_save(saving: bool) -> None:
    for run in jobs.of_kind(jobs.LIVE):
        try:
            run.swap_for_save(saving)
        except Exception as exc:  # noqa: BLE001 - a handler must not fail the save
            log.error("%s: %s", run.object_name, exc)


def folder_path(folder: str, reports: Reports) -> str | None:
    """A folder setting ('//' = next to the .blend) as an absolute path, or None with an error."""
    folder = folder or "//"
    if folder.startswith("//") and not bpy.data.filepath:
        reports.error(f"the folder {folder!r} is relative to the .blend file, which is not saved yet: save the "
                      "file or choose an absolute folder")
        return None
    return os.path.normpath(bpy.path.abspath(folder))
