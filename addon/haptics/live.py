"""The live bimanual tearing session of Le Gouis et al. (WHC 2017), section VI: each hand's device
drives a proxy at haptic rate, the simulation moves the grasped handle to the proxy at simulation
rate, and the force the cloth exerts on the handle (eq. 6) comes back to the hand through the
servo loop's impedance law (eq. 5).

This file owns:
- ``LiveSession``: binds devices to handles, runs the simulation loop (on the caller's thread with
  ``run_for``/``step_once``, or on a thread of its own with ``start``), publishes F_tear and a
  linearisation to the ``ServoLoop`` mailboxes, picks the servo's stall timeout from the measured
  simulation rate, records frames (``recorder`` hook) and forces (``ForceLog``), and ends cleanly
  (zero force, threads joined, devices closed) on ``stop()``, on a stop button, on device loss or
  on a simulation error;
- ``emulated_falcon`` / ``pulling_hand``: a Falcon emulator with a scripted hand that pulls its
  grip along a direction (tests, demo, bench; the paper's scenes grasped by two of them,
  ``emulated_session``, live with the example geometry in ``tearcloth.bench.servo``);
- ``LiveSession.tension`` / ``LiveSession.phases``: the force along the pull per step and the
  three phases of the paper's Fig. 6 (elastic rise, peak at the first tear, propagation);
- ``stall_timeout_rule``: the watchdog rule below (servo timing while the simulation runs flat
  out, what ``tearcloth bench`` reports as ``servo.*``, is ``tearcloth.bench.servo``).

One simulation step, as data flows (design.md): proxies (servo) -> handle targets -> session step
(collision, FEM, tearing; the GIL is released in the native step so the servo threads keep their
1 kHz) -> F_tear per handle -> servo mailboxes; recorder and force log on the side.

Handle target. A handle is grasped as a rigid translation: its target is the affine map
[I | x_proxy - c] of its grasp-time positions, where c is their centroid, so the grasp-time
offsets of the vertices from the centroid are kept and the centroid lands on the proxy. With
``rebase=True`` (default) the coupling's offset is shifted at bind time so that the device's
current position maps to c: the cloth does not jump toward wherever the hand happened to be. The
target follows the proxy at most ``max_handle_speed`` (m/s of simulated time) so that a yanked
device cannot blow the implicit step up; the proxy spring of eq. (5) renders the lag.

Linearisation (Otaduy & Lin 2006). With ``linearise=True`` each step also publishes
f0 = F_tear, x0 = the handle position and a stiffness K estimated from the last two
(force, position) pairs of that hand: K = -k·u·uᵀ along the motion u = Δx/|Δx|, with
k = -ΔF·Δx/|Δx|² clamped to [0, the device's max stiffness / (force_scale·scale)] (a negative k -
the force dropping while the hand pulls, as at a tear - would be positive feedback: it is dropped
to 0). The pair is only renewed once the handle has moved ``min_secant_m``, so sensor-sized
motions do not produce absurd slopes. The servo scales K down further to its stiffness budget.

Stall timeout (the servo zeroes the force when the mailbox is older than this). Rule:
``stall_timeout = clip(stall_factor · p99(publish period), min_stall_timeout_s, max_stall_timeout_s)``
with defaults 3, 10 ms and 100 ms; the p99 is over the last 200 publish periods (step start to
step start within one ``run_for``/thread run), first from ``warmup_steps`` steps taken before the
servo starts, then re-evaluated every 50 steps. Three periods at the 99th percentile means a
normally slow step never trips the watchdog, while a simulation that really stops (a stall, a
debugger, a caller that stops calling ``run_for``) is cut off within a few of its own periods; the
10 ms floor keeps the servo's default for fast simulations, the 100 ms ceiling bounds how long a
frozen linearisation can be felt. Pass ``stall_timeout_s`` to fix it instead.

A step the core rolls back even after the session's sub-step retries is taken again once with
the handles held where they were (the hands moved too far for one step); a second failure ends
the session with zero force and the error in ``error`` (``run_for``/``step_once`` re-raise it).

Device loss. ``on_device_lost="stop"`` (default) ends the whole session with zero force on every
device: tearing is a two-handed task and one hand suddenly pulling against a frozen handle is not
what the user expects. ``"continue"`` keeps the other hands running; the lost hand's handle stays
where it was (like a pin) and the session ends when no hand is left. A servo thread that stops
answering (no proxy for ``proxy_timeout_s``) counts as a lost device.

Stop button: ``stop_buttons`` (a bit mask, default the Falcon's centre button; None disables)
ends the session when pressed on any hand - after it has been seen released once, so a button
already held when the session starts does not end it at once.

Where the servo runs. Hands given as ``DeviceSpec`` (``servo_process``) get a servo process of
their own (``servo_process.ServoProcess``: the devices are built, opened and driven there, the
exchange goes through shared memory, the servo zeroes the force by itself when this process
stalls or dies); ``device(hand)`` is then a ``RemoteDevice`` and ``servo_process.emulator(hand)``
reaches an emulated Falcon. This is the arrangement that holds 1 kHz while this process is busy
with Python (Blender's UI) on a loaded machine, without privileges; every device kind can be
described so (``device_specs``: a real Falcon, a SpaceMouse, a keyboard hand whose target comes
through the shared memory, the emulated Falcon of ``emulated_falcon``). Hands given as device objects
keep the in-process servo (``servo.ServoLoop``, one thread per device, SCHED_FIFO when the OS
allows: ``servo_priority``), for tests that drive devices directly and for devices only this
process can reach. The simulation loop runs on one thread (the
caller's or ``tearcloth-live-sim``); the recorder is called on the simulation thread with copies
of the arrays, so the Blender layer must queue what it receives and touch bpy only from the main
thread.

Time. The simulation steps ``dt`` of simulated time as fast as it can; the hands move in wall
time. A simulation slower than real time is therefore in slow motion for the hands (the T-shirt
at ~60 steps/s of 1 ms runs at 6 % of real time) and pulls faster, in simulated time, than
the user does in the real world.

This module sits at the top of ``haptics`` and drives the session layer; it imports
``..session``/``..cloth`` lazily inside the functions that need them, so importing
``tearcloth.haptics`` still pulls in no simulation code. Pure Python, no bpy, SI units.
"""
from __future__ import annotations

import dataclasses
import math
import os
import threading
import time
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from .device import (
    ConfigError,
    DeviceNotFoundError,
    DeviceState,
    DeviceStateError,
    HapticDevice,
    HapticError,
    Workspace,
)
from .falcon import FALCON_MAX_FORCE, FalconDevice
from .falcon_emulator import FalconEmulator, spring_hand
from .falcon_kinematics import WORKSPACE_CENTRE, WORKSPACE_RADIUS
from .forcelog import ForceLog
from .servo import HandCoupling, ServoLoop, _lower_switch_interval, _restore_switch_interval
from .servo_process import DeviceSpec, ServoProcess, open_ready

__all__ = [
    "LiveSession",
    "Recorder",
    "stall_timeout_rule",
    "FALCON_TO_SCENE",
    "FALCON_CENTRE_BUTTON",
    "falcon_coupling",
    "pulling_hand",
    "emulated_falcon",
]

# Falcon frame (x right, y up, z toward the user) -> scene frame (Blender: z up, the front view
# looks along +y, so "toward the user" is -y). Columns are the device axes in the scene.
FALCON_TO_SCENE = ((1.0, 0.0, 0.0), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0))
# The Falcon's grip buttons (falcon_packets): 0x1 plus, 0x2 forward, 0x4 centre, 0x8 minus.
FALCON_CENTRE_BUTTON = 0x4

# recorder(time_s, positions (n,3), triangles (m,3), corner_uv (m,3,2), velocities (n,3))
Recorder = Callable[[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray], Any]

_PERIOD_WINDOW = 200
_STALL_UPDATE_EVERY = 50


def stall_timeout_rule(periods, factor: float = 3.0, minimum: float = 0.010, maximum: float = 0.100) -> float:
    """The servo's stall timeout for a simulation whose recent publish periods (s) are
    ``periods``: ``clip(factor · p99(periods), minimum, maximum)`` (see the module docstring)."""
    p = np.asarray(periods, dtype=float)
    p99 = float(np.percentile(p, 99)) if p.size else 0.0
    return min(max(factor * p99, minimum), maximum)


class _Hand:
    """One bound hand: its handle on the cloth, its device and coupling, and the loop's memory."""

    def __init__(self, name: str, handle: int, indices: np.ndarray, centroid: np.ndarray, device: HapticDevice, coupling: HandCoupling):
        self.name = name
        self.handle = handle
        self.indices = indices
        self.centroid = centroid  # grasp-time centroid of the handle vertices (scene, m)
        self.device = device
        self.coupling = coupling
        self.translation = np.zeros(3)  # current handle target: [I | translation]
        self.last_f: Optional[np.ndarray] = None  # secant base for the stiffness estimate
        self.last_x: Optional[np.ndarray] = None
        self.stiffness = np.zeros((3, 3))
        self.k_max = math.inf
        self.lost = False
        self.armed = False  # the stop button must be seen released once before it counts

    @property
    def position(self) -> np.ndarray:
        return self.centroid + self.translation


class LiveSession:
    """A simulated cloth torn live by haptic devices (see the module docstring).

    ``session_or_cloth``: a ``Session`` (collision included) or a bare ``Cloth`` (wrapped in a
    ``Session`` without collision). ``hands``: {hand name: (handle, device, coupling)} where
    handle is a handle id from ``cloth.add_handle``, a vertex-group name or vertex indices (the
    session then grasps them), and coupling a ``HandCoupling`` (None: 1:1, identity rotation).

    Life cycle: ``open()`` opens the devices, binds them and starts the servo threads (``run_for``,
    ``step_once`` and ``start`` call it); ``run_for(s)``/``step_once()`` step on the caller's
    thread; ``start()`` steps on a thread of its own; ``stop()`` ends everything. After the end,
    ``end_reason`` says why and ``error`` holds the exception if one ended it.

    Logs: ``force_log`` holds the force rendered to each hand at every servo tick (scene frame,
    N, servo clock); ``tear_log`` holds F_tear at every simulation step (same clock), so the two
    overlay. ``first_tear_clock`` / ``first_tear_time`` are the servo-clock and simulated times of
    the step where ``cloth.stats()['tears_started']`` first became non-zero.

    With a servo process, this process's simulation thread shares the GIL only with the caller's
    Python (Blender's UI): ``sim_switch_interval_s`` (0.5 ms) bounds how long that Python holds it
    at a time. ``gil_pump_s`` (off by default) makes ``start()`` add a ``tearcloth-live-gil``
    thread that wakes that often, so the simulation thread, back from a native step, gets the
    GIL sooner, as the in-process servo threads make happen as a side effect. Measured (T-shirt
    with collision, a GIL-heavy main thread, a CPU hog, 2 shared cores, interleaved runs of
    ``bench.servo.measure_loaded_servo``): the simulation at 41.5, 66.2, 33.4, 29.1 steps/s with a
    0.5 ms pump against 32.5, 40.2, 20.4, 38.1 without; but the servo's worst period in those runs
    was 86, 46, 272, 503 ms against 14, 8, 51, 8 ms without. A servo that misses half a second is
    worse than a slower simulation, so it stays off.
    """

    def __init__(
        self,
        session_or_cloth,
        hands: Mapping[str, Tuple[Any, HapticDevice, Optional[HandCoupling]]],
        dt: float = 1e-3,
        *,
        servo_period_s: float = 0.001,
        stall_timeout_s: Optional[float] = None,
        stall_factor: float = 3.0,
        min_stall_timeout_s: float = 0.010,
        max_stall_timeout_s: float = 0.100,
        linearise: bool = True,
        min_secant_m: float = 1e-5,
        max_linear_stiffness: float = 1e5,
        max_handle_speed: Optional[float] = 0.5,
        stop_buttons: Optional[int] = FALCON_CENTRE_BUTTON,
        on_device_lost: str = "stop",
        recorder: Optional[Recorder] = None,
        record_every: int = 10,
        homing_timeout_s: float = 0.0,
        rebase: bool = True,
        warmup_steps: int = 5,
        proxy_timeout_s: float = 0.5,
        servo_priority: Optional[int] = 10,
        servo_kwargs: Optional[Mapping[str, Any]] = None,
        sim_switch_interval_s: Optional[float] = 0.0005,
        gil_pump_s: Optional[float] = None,
    ):
        if not (dt > 0.0 and math.isfinite(dt)):
            raise ConfigError(f"dt must be a positive number of seconds, got {dt!r}")
        if on_device_lost not in ("stop", "continue"):
            raise ConfigError(f"on_device_lost must be 'stop' or 'continue', got {on_device_lost!r}")
        if int(record_every) < 1:
            raise ConfigError(f"record_every must be at least 1 step, got {record_every!r}")
        if not 0.0 < min_stall_timeout_s <= max_stall_timeout_s:
            raise ConfigError(f"need 0 < min_stall_timeout_s <= max_stall_timeout_s, got {min_stall_timeout_s}, {max_stall_timeout_s}")
        if stall_timeout_s is not None and not stall_timeout_s > servo_period_s:
            raise ConfigError(f"stall timeout ({stall_timeout_s} s) must exceed the servo period ({servo_period_s} s)")
        if not stall_factor >= 1.0:
            raise ConfigError(f"stall_factor must be >= 1 (a timeout shorter than a simulation period trips on every step), got {stall_factor!r}")
        if max_handle_speed is not None and not max_handle_speed > 0.0:
            raise ConfigError(f"max_handle_speed must be > 0 m/s or None, got {max_handle_speed!r}")

        if hasattr(session_or_cloth, "cloth") and hasattr(session_or_cloth, "step"):
            self.session = session_or_cloth
        elif hasattr(session_or_cloth, "add_handle") and hasattr(session_or_cloth, "handle_force"):
            from ..session import Session  # lazily: see the module docstring

            self.session = Session(session_or_cloth)
        else:
            raise ConfigError(f"LiveSession needs a Session or a Cloth, got {type(session_or_cloth).__name__}")
        self.cloth = self.session.cloth
        detector = getattr(self.session, "detector", None)
        if detector is not None:
            from ..collision.detector import usable_cpus  # lazily: see the module docstring

            # The collision's worker thread (the swept stage beside the detection, detector.py) only
            # where a core is left for it beside the simulation thread and the two servo threads (or
            # the servo process): on fewer than 4 they already fill the machine, and a servo tick
            # must not wait behind the collision (as for spin_s below).
            if usable_cpus() < 4:
                detector.swept_thread = False

        self.dt = float(dt)
        self.servo_period_s = float(servo_period_s)
        self.fixed_stall_timeout_s = stall_timeout_s
        self.stall_factor = float(stall_factor)
        self.min_stall_timeout_s = float(min_stall_timeout_s)
        self.max_stall_timeout_s = float(max_stall_timeout_s)
        self.stall_timeout_s = float(stall_timeout_s) if stall_timeout_s is not None else self.min_stall_timeout_s
        self.linearise = bool(linearise)
        self.min_secant_m = float(min_secant_m)
        self.max_linear_stiffness = float(max_linear_stiffness)
        self.max_handle_speed = max_handle_speed
        self.stop_buttons = int(stop_buttons) if stop_buttons else 0
        self.on_device_lost = on_device_lost
        self.recorder = recorder
        self.record_every = int(record_every)
        self.homing_timeout_s = float(homing_timeout_s)
        self.rebase = bool(rebase)
        self.warmup_steps = max(0, int(warmup_steps))
        self.proxy_timeout_s = float(proxy_timeout_s)
        self.sim_switch_interval_s = sim_switch_interval_s
        self.gil_pump_s = gil_pump_s
        self._pump: Optional[threading.Thread] = None
        self._pump_stop = threading.Event()
        # Servo threads: SCHED_FIFO when the OS allows it (servo.ServoLoop(priority=...)). On
        # fewer than 4 cores the two servo threads and the simulation thread already fill the
        # machine, and a servo thread spinning before its deadline steals the simulation's core:
        # sleep the whole wait instead.
        defaults: Dict[str, Any] = {"priority": servo_priority}
        if (os.cpu_count() or 1) < 4:
            defaults["spin_s"] = 0.0
        self.servo_kwargs = {**defaults, **dict(servo_kwargs or {})}
        from ..cloth import SimulationError  # lazily: see the module docstring

        self._simulation_error = SimulationError

        specs = {n: v[1] for n, v in hands.items() if isinstance(v, tuple) and len(v) == 3 and isinstance(v[1], DeviceSpec)}
        self.servo_process: Optional[ServoProcess] = None
        if specs:
            if len(specs) != len(hands):
                raise ConfigError("give every hand a DeviceSpec (servo process) or every hand a device (in-process servo), not a mix")
            kw = self.servo_kwargs
            self.servo_process = ServoProcess(specs, period_s=self.servo_period_s, stall_timeout_s=max(self.stall_timeout_s, 2.0 * self.servo_period_s),
                                              spin_s=float((servo_kwargs or {}).get("spin_s", 0.0)), slice_s=kw.get("slice_s", 0.0001),
                                              priority=kw.get("priority"), cpus=kw.get("cpus"), own_session=kw.get("own_session", True),
                                              switch_interval_s=kw.get("switch_interval_s", 0.0005))
            hands = {n: (v[0], self.servo_process.device(n), v[2]) for n, v in hands.items()}
        self._hands: Dict[str, _Hand] = self._bind_handles(hands)
        self.force_log = ForceLog(list(self._hands))
        if self.servo_process is not None:
            self.servo_process.force_log = self.force_log
        self.tear_log = ForceLog(list(self._hands))
        self.servo = None  # ServoLoop or ServoProcess once open

        self.steps = 0
        self.held_steps = 0
        self.frames_recorded = 0
        self.step_clock: List[float] = []  # servo-clock time at the end of every step
        self.step_time: List[float] = []  # simulated time at the end of every step
        self.first_tear_clock: Optional[float] = None
        self.first_tear_time: Optional[float] = None
        self.first_tear_step: Optional[int] = None
        self.ended = False
        self.end_reason: Optional[str] = None
        self.error: Optional[BaseException] = None
        self.shutdown_errors: List[BaseException] = []
        self.lost_hands: List[str] = []
        self._opened = False
        self._switch_lowered = False
        self._lock = threading.RLock()
        self._stop_event = threading.Event()
        self._thread: Optional[threading.Thread] = None
        self._periods = np.zeros(_PERIOD_WINDOW)
        self._n_periods = 0
        self._last_step_start: Optional[float] = None
        self._active_wall_s = 0.0
        self._step_wall: List[float] = []

    # ---- binding ------------------------------------------------------------------------------
    def _bind_handles(self, hands) -> Dict[str, _Hand]:
        if not hands:
            raise ConfigError(
                "a live session needs at least one hand: pass {hand name: (handle or vertex group, device, coupling)}; "
                "no devices were given"
            )
        cloth = self.cloth
        known = getattr(cloth, "_handles", {})  # Cloth keeps {handle id: vertex indices}
        seen_devices: Dict[int, str] = {}
        created: List[int] = []
        out: Dict[str, _Hand] = {}
        try:
            for name, spec in hands.items():
                try:
                    handle, device, coupling = spec
                except (TypeError, ValueError):
                    raise ConfigError(f"hand {name!r}: expected (handle or vertex group, device, coupling), got {spec!r}") from None
                if not isinstance(device, HapticDevice):
                    raise ConfigError(f"hand {name!r}: {device!r} is not a HapticDevice")
                if id(device) in seen_devices:
                    raise ConfigError(f"hands {seen_devices[id(device)]!r} and {name!r} use the same device {device.name!r}")
                seen_devices[id(device)] = name
                if coupling is not None and not isinstance(coupling, HandCoupling):
                    raise ConfigError(f"hand {name!r}: coupling must be a HandCoupling or None, got {type(coupling).__name__}")
                if isinstance(handle, str):
                    groups = list(getattr(cloth, "group_names", []))
                    if handle not in groups:
                        raise ConfigError(f"hand {name!r}: the cloth has no vertex group {handle!r}; its groups are {groups or 'none'}")
                    indices = np.flatnonzero(cloth.group(handle) >= 0.5)  # Cloth's own threshold
                    if indices.size == 0:
                        raise ConfigError(f"hand {name!r}: vertex group {handle!r} selects no vertex (no weight >= 0.5)")
                    h = cloth.add_handle(handle)
                    created.append(h)
                elif isinstance(handle, (int, np.integer)) and not isinstance(handle, bool):
                    h = int(handle)
                    if h not in known:
                        raise ConfigError(f"hand {name!r}: the cloth has no handle {h}; its handles are {sorted(known) or 'none'}")
                    indices = np.asarray(known[h], dtype=np.int64)
                else:
                    indices = np.asarray(handle).reshape(-1)
                    if indices.size == 0:
                        raise ConfigError(f"hand {name!r}: an empty vertex selection cannot be grasped")
                    h = cloth.add_handle(indices)
                    created.append(h)
                    indices = np.asarray(known.get(h, indices), dtype=np.int64)  # a mask becomes indices
                if indices.size == 0:
                    raise ConfigError(f"hand {name!r}: handle {h} grasps no vertex")
                centroid = np.asarray(cloth.positions, dtype=float)[indices].mean(axis=0)
                if coupling is None:
                    coupling = HandCoupling.fit(device.workspace, centroid, device.workspace.radius)
                out[name] = _Hand(name, h, indices, centroid, device, coupling)
        except BaseException:
            for h in created:
                try:
                    cloth.release_handle(h)
                except Exception:  # best effort: the error being raised is the one that matters
                    pass
            raise
        return out

    @property
    def hands(self) -> List[str]:
        return list(self._hands)

    def handle(self, hand: str) -> int:
        return self._hand(hand).handle

    def device(self, hand: str) -> HapticDevice:
        return self._hand(hand).device

    def coupling(self, hand: str) -> HandCoupling:
        return self._hand(hand).coupling

    def handle_position(self, hand: str) -> np.ndarray:
        """Where the handle's grasp centroid is being held (scene, m)."""
        return self._hand(hand).position.copy()

    def _hand(self, hand: str) -> _Hand:
        try:
            return self._hands[hand]
        except KeyError:
            raise ConfigError(f"unknown hand {hand!r}; hands are {sorted(self._hands)}") from None

    # ---- opening ------------------------------------------------------------------------------
    def open(self) -> None:
        """Open and bind every device, take the warm-up steps, start the servo threads.

        Raises a ``HapticError`` naming the hand when a device is absent (``DeviceNotFoundError``),
        needs firmware (``FirmwareError``), is not homed within ``homing_timeout_s``
        (``NotHomedError``) or is coupled stiffer than it can render (``ConfigError``); every device
        opened so far is closed again."""
        with self._lock:
            if self._opened:
                if self.ended:
                    raise DeviceStateError(f"this live session has ended ({self.end_reason}); create a new one")
                return
            if self.servo_process is not None:
                self._open_process()
                self._opened = True
                return
            opened: List[HapticDevice] = []
            try:
                for hs in self._hands.values():
                    self._open_device(hs)
                    opened.append(hs.device)
                for hs in self._hands.values():
                    self._bind_device(hs)
                self.servo = ServoLoop(
                    {n: hs.device for n, hs in self._hands.items()},
                    {n: hs.coupling for n, hs in self._hands.items()},
                    period_s=self.servo_period_s,
                    stall_timeout_s=max(self.stall_timeout_s, 2.0 * self.servo_period_s),
                    force_log=self.force_log,
                    **self.servo_kwargs,
                )
                self._warm_up()
                self.servo.start()
            except BaseException:
                if self.servo is not None and self.servo.running:
                    try:
                        self.servo.stop()
                    except HapticError:
                        pass
                for dev in opened:
                    try:
                        dev.close()
                    except HapticError:
                        pass
                self.servo = None
                raise
            self._opened = True

    def _open_device(self, hs: _Hand) -> None:
        open_ready(hs.device, hs.name, self.homing_timeout_s)

    def _open_process(self) -> None:
        """The servo-process arrangement of ``open``: the devices open (and home) there, bind on
        the position they report, warm up, then the servo threads start in that process."""
        proc = self.servo_process
        # The servo no longer shares our GIL, but the simulation thread still does, with whatever
        # pure Python runs here (Blender's UI): at the default 5 ms switch interval each GIL
        # hand-back after a native step costs it up to 5 ms (measured: 8 steps/s instead of 33
        # on the T-shirt beside a GIL-heavy loop). Restored when the session ends.
        self._switch_lowered = _lower_switch_interval(self.sim_switch_interval_s)
        try:
            if not proc.opened:  # HapticRun may have opened it already (begin_open/poll_open while a Falcon homes)
                proc.open(self.homing_timeout_s)
            for hs in self._hands.values():
                self._bind_device(hs)
            self.servo = proc
            self._warm_up()
            proc.start({n: hs.coupling for n, hs in self._hands.items()})
        except BaseException:
            proc.stop()
            self.servo = None
            if self._switch_lowered:
                _restore_switch_interval()
                self._switch_lowered = False
            raise

    def _bind_device(self, hs: _Hand) -> None:
        dev = hs.device
        dev.poll()  # a fresh reading (still our thread: the servo has not started; a servo process polled already)
        if dev.state is not DeviceState.READY:
            raise DeviceNotFoundError(f"hand {hs.name!r}: {dev.name} stopped answering while binding: {dev.message}")
        c = hs.coupling
        if self.rebase:
            # Shift the offset so the hand's current pose is the grasp: proxy(p_now) = centroid.
            offset = hs.centroid - (c.proxy(dev.position) - np.asarray(c.offset, dtype=float))
            c = dataclasses.replace(c, offset=tuple(float(v) for v in offset))
            hs.coupling = c
        limit = dev.max_stiffness / (c.force_scale * c.scale) if dev.has_force else 0.0
        hs.k_max = min(limit, self.max_linear_stiffness)

    def _warm_up(self) -> None:
        """Steps with the handles held at their grasp, before the servo starts: they measure the
        simulation's period (the first stall timeout) and produce the first F_tear."""
        walls = []
        for _ in range(self.warmup_steps):
            t0 = time.perf_counter()
            self.session.step(self.dt)
            walls.append(time.perf_counter() - t0)
        if walls:
            self._update_stall_timeout(np.asarray(walls))
        for hs in self._hands.values():
            self._publish(hs, self.cloth.handle_force(hs.handle))

    # ---- stall timeout ------------------------------------------------------------------------
    def _update_stall_timeout(self, periods: np.ndarray) -> None:
        if self.fixed_stall_timeout_s is not None:
            timeout = float(self.fixed_stall_timeout_s)
        else:
            timeout = stall_timeout_rule(periods, self.stall_factor, self.min_stall_timeout_s, self.max_stall_timeout_s)
        self.stall_timeout_s = timeout
        if self.servo is not None:
            # A plain float the servo threads read once per tick: an atomic swap.
            self.servo.stall_timeout_s = max(timeout, 2.0 * self.servo_period_s)

    def _record_period(self, period: float) -> None:
        self._periods[self._n_periods % _PERIOD_WINDOW] = period
        self._n_periods += 1
        if self._n_periods % _STALL_UPDATE_EVERY == 0:
            n = min(self._n_periods, _PERIOD_WINDOW)
            self._update_stall_timeout(self._periods[:n])

    # ---- one simulation step ------------------------------------------------------------------
    def _publish(self, hs: _Hand, f: np.ndarray) -> None:
        x = hs.position
        if self.linearise:
            self._estimate_stiffness(hs, f, x)
            self.servo.publish(hs.name, f, x, f0=f, stiffness=hs.stiffness, x0=x)
        else:
            self.servo.publish(hs.name, f, x)

    def _estimate_stiffness(self, hs: _Hand, f: np.ndarray, x: np.ndarray) -> None:
        if hs.last_x is None:
            hs.last_f, hs.last_x = f.copy(), x.copy()
            return
        dx = x - hs.last_x
        n2 = float(dx @ dx)
        if n2 < self.min_secant_m * self.min_secant_m:
            return  # too little motion for a meaningful slope: keep the previous K and base
        k = -float((f - hs.last_f) @ dx) / n2
        k = min(max(k, 0.0), hs.k_max)
        u = dx / math.sqrt(n2)
        hs.stiffness = -k * np.outer(u, u)
        hs.last_f, hs.last_x = f.copy(), x.copy()

    def _lose(self, hs: _Hand, reason: str) -> None:
        hs.lost = True
        self.lost_hands.append(hs.name)
        if self.on_device_lost == "stop":
            self._end(f"device lost on the {hs.name} hand: {reason}")
        elif all(h.lost for h in self._hands.values()):
            self._end(f"every device was lost (last: the {hs.name} hand: {reason})")

    def _step(self) -> bool:
        """One simulation step; False once the session has ended."""
        servo = self.servo
        clock = servo.clock
        start = clock()
        if self._last_step_start is not None:
            self._record_period(start - self._last_step_start)
        self._last_step_start = start
        max_move = None if self.max_handle_speed is None else self.max_handle_speed * self.dt
        held = {name: hs.translation for name, hs in self._hands.items()}
        for hs in self._hands.values():
            if hs.lost:
                continue
            p = servo.proxy(hs.name)
            if hs.device.state is DeviceState.LOST or (p is not None and p.state is DeviceState.LOST):
                self._lose(hs, hs.device.message)
            elif p is None:
                continue  # the servo has not ticked this hand yet: hold the grasp
            elif start - p.stamp > self.proxy_timeout_s:
                self._lose(hs, f"its servo thread has not answered for {1e3 * (start - p.stamp):.0f} ms ({servo.stats(hs.name)['error']})")
            else:
                if self.stop_buttons:
                    pressed = p.buttons & self.stop_buttons
                    if not pressed:
                        hs.armed = True
                    elif hs.armed:
                        self._end(f"stop button pressed on the {hs.name} hand")
                if self.ended:
                    break
                delta = p.position - hs.centroid - hs.translation
                if max_move is not None:
                    n = float(np.linalg.norm(delta))
                    if n > max_move:
                        delta = delta * (max_move / n)
                hs.translation = hs.translation + delta
                m = np.eye(3, 4)
                m[:, 3] = hs.translation
                self.cloth.set_handle_target(hs.handle, m)
            if self.ended:
                return False
        try:
            self.session.step(self.dt)  # collision + FEM + tearing; the GIL is released in the native step
        except self._simulation_error:
            self._recover_step(held)
        now = clock()
        if self.servo_process is not None:
            self.servo_process.set_sim_time(self.session.time)
        if self.first_tear_clock is None and self.cloth.stats()["tears_started"]:
            self.first_tear_clock, self.first_tear_time, self.first_tear_step = now, float(self.session.time), self.steps
        self.step_clock.append(now)
        self.step_time.append(float(self.session.time))
        for hs in self._hands.values():
            if hs.lost:
                continue
            f = self.cloth.handle_force(hs.handle)
            self._publish(hs, f)
            self.tear_log.record(hs.name, now, f)
        if self.recorder is not None and self.steps % self.record_every == 0:
            c = self.cloth
            self.recorder(
                float(self.session.time),
                np.array(c.positions),
                np.array(c.triangles),
                np.array(c.corner_uv),
                np.array(c.velocities),
            )
            self.frames_recorded += 1
        self.steps += 1
        self._step_wall.append(clock() - start)
        return not self.ended

    def _recover_step(self, held: Dict[str, np.ndarray]) -> None:
        """The core rolled a step back even after the session's retries in sub-steps: the
        hands moved too far for one step. Hold the handles where they were and retry once (the
        proxy spring makes the hands feel the lag); a second failure rises and ends the session
        with zero force."""
        for name, hs in self._hands.items():
            hs.translation = held[name]
            m = np.eye(3, 4)
            m[:, 3] = hs.translation
            self.cloth.set_handle_target(hs.handle, m)
        self.held_steps += 1
        self.session.step(self.dt)

    def _guarded(self, body: Callable[[], Any]):
        """Run ``body``; any exception ends the session (zero force, devices closed), then rises."""
        try:
            return body()
        except BaseException as exc:
            self.error = exc
            self._end(f"error: {exc!r}")
            raise

    # ---- driving ------------------------------------------------------------------------------
    def _check_drivable(self) -> None:
        if self._thread is not None and self._thread.is_alive() and threading.current_thread() is not self._thread:
            raise DeviceStateError("the simulation thread is running (start()); call stop() before stepping on this thread")
        if self.ended:
            raise DeviceStateError(f"this live session has ended ({self.end_reason}); create a new one")

    def step_once(self) -> bool:
        """One simulation step on the calling thread (opens the session first if needed).
        Returns False once the session has ended (stop button, device lost)."""
        self._check_drivable()
        self.open()
        t0 = time.perf_counter()
        try:
            return self._guarded(self._step)
        finally:
            self._active_wall_s += time.perf_counter() - t0

    def run_for(self, seconds: float, until_time: Optional[float] = None) -> int:
        """Step as fast as possible on the calling thread for ``seconds`` of wall time, until
        the simulated time reaches ``until_time`` (s) if given, or until the session ends.
        Returns the number of steps taken. The servo keeps running after the call returns: call
        again soon (within the stall timeout, else the hands feel zero force until the next
        step) or ``stop()``."""
        self._check_drivable()
        self.open()
        self._last_step_start = None  # the gap since the last call is not a simulation period
        t0 = time.perf_counter()
        end = t0 + float(seconds)
        n = 0
        try:
            while time.perf_counter() < end and (until_time is None or self.session.time < until_time):
                if not self._guarded(self._step):
                    n += 1
                    break
                n += 1
        finally:
            self._active_wall_s += time.perf_counter() - t0
        return n

    def start(self) -> None:
        """Run the simulation loop on a thread of its own until ``stop()`` or the session ends."""
        self._check_drivable()
        if self._thread is not None and self._thread.is_alive():
            return
        self.open()
        self._stop_event.clear()
        self._last_step_start = None
        self._thread = threading.Thread(target=self._run_thread, name="tearcloth-live-sim", daemon=True)
        self._thread.start()
        if self.servo_process is not None and self.gil_pump_s and self._pump is None:
            self._pump_stop.clear()
            self._pump = threading.Thread(target=self._gil_pump, name="tearcloth-live-gil", daemon=True)
            self._pump.start()

    def _gil_pump(self) -> None:
        # Every wake takes the GIL for an instant, so a pure-Python thread that holds it (Blender's
        # UI) lets go every gil_pump_s and the simulation thread, back from a native step, gets
        # it without waiting out its own switch interval. The in-process servo threads did this
        # as a side effect (off by default: it cost the servo its worst case, measured in the
        # class docstring).
        while not self._pump_stop.wait(self.gil_pump_s):
            pass

    def _run_thread(self) -> None:
        t0 = time.perf_counter()
        try:
            while not self._stop_event.is_set() and not self.ended:
                self._guarded(self._step)
        except BaseException:
            pass  # kept in self.error; _guarded already ended the session with zero force
        finally:
            self._active_wall_s += time.perf_counter() - t0

    @property
    def running(self) -> bool:
        return self._opened and not self.ended

    def wait(self, timeout_s: Optional[float] = None) -> bool:
        """Wait for the simulation thread to end (stop button, device loss, error). True if ended."""
        if self._thread is not None:
            self._thread.join(timeout_s)
            return not self._thread.is_alive()
        return self.ended

    def stop(self, timeout_s: float = 2.0) -> None:
        """End the session: zero every force, join the simulation and servo threads, close the
        devices. Idempotent; never raises (problems go to ``shutdown_errors``)."""
        self._stop_event.set()
        t = self._thread
        if t is not None and t is not threading.current_thread():
            t.join(timeout_s)
            if t.is_alive():
                self.shutdown_errors.append(HapticError(f"the simulation thread did not stop within {timeout_s} s (a very slow step?)"))
        self._end("stopped")

    def _end(self, reason: str) -> None:
        with self._lock:
            if self.ended:
                return
            self.ended = True
            self.end_reason = reason
            self._shutdown()

    def _shutdown(self) -> None:
        if self._pump is not None:
            self._pump_stop.set()
            self._pump.join()
            self._pump = None
        if self.servo is not None:
            try:
                self.servo.stop()  # zero force sent to every device, servo threads joined
            except HapticError as exc:
                self.shutdown_errors.append(exc)
        if self.servo_process is not None:
            self.servo_process.stop()  # zero force, devices closed, the force log drained to the last tick
            if self._switch_lowered:
                _restore_switch_interval()
                self._switch_lowered = False
        if self._opened or self.servo is not None:
            for hs in self._hands.values():
                try:
                    hs.device.close()
                except HapticError as exc:
                    self.shutdown_errors.append(exc)

    def __enter__(self):
        self.open()
        return self

    def __exit__(self, *exc):
        self.stop()
        return False

    # ---- results ------------------------------------------------------------------------------
    def stats(self) -> dict:
        """Servo timing (``rate_hz``, ``p50_ms``, ``p99_ms``, ``per_hand``: worst hand first) and
        simulation figures (``sim_steps``, ``sim_steps_per_s``, ``sim_p50_ms``, ``sim_p99_ms``:
        wall time of one step), the current ``stall_timeout_s``, ``watchdog_trips``, the tear
        (``first_tear_s`` simulated, ``tears_started``) and how the session ended."""
        out: Dict[str, Any] = {}
        if self.servo is not None:
            out.update(self.servo.stats())
            per = out["per_hand"].values()
            out["watchdog_trips"] = int(sum(v["watchdog_trips"] for v in per))
            out["overruns"] = int(sum(v["overruns"] for v in out["per_hand"].values()))
        walls = np.asarray(self._step_wall)
        out.update(
            sim_steps=self.steps,
            sim_time_s=float(self.session.time),
            sim_steps_per_s=float(self.steps / self._active_wall_s) if self._active_wall_s > 0 else 0.0,
            sim_p50_ms=float(np.percentile(walls, 50) * 1e3) if len(walls) else float("nan"),
            sim_p99_ms=float(np.percentile(walls, 99) * 1e3) if len(walls) else float("nan"),
            stall_timeout_s=self.stall_timeout_s,
            frames_recorded=self.frames_recorded,
            held_steps=self.held_steps,
            servo_realtime={h: v.get("realtime") for h, v in out.get("per_hand", {}).items()},
            first_tear_s=self.first_tear_time,
            tears_started=int(self.cloth.stats()["tears_started"]),
            triangles=int(self.cloth.num_triangles),
            ended=self.ended,
            end_reason=self.end_reason,
            lost_hands=list(self.lost_hands),
        )
        return out

    def clock_at(self, sim_time: float) -> float:
        """Servo-clock time at the end of the first step that reached ``sim_time`` (s): maps
        simulated time onto the clock the force logs use."""
        if not self.step_time:
            raise DeviceStateError("no simulation step taken yet")
        k = int(np.searchsorted(np.asarray(self.step_time), sim_time - 1e-12))
        return self.step_clock[min(k, len(self.step_clock) - 1)]

    def tension(self, log: str = "felt", *, axis: Sequence[float] = (1.0, 0.0, 0.0), smooth_steps: float = 5.0) -> Dict[str, np.ndarray]:
        """Per hand, the *tension* at the end of every simulation step: the force along ``axis``
        from the ``"felt"`` log (``force_log``, rendered at 1 kHz) or the ``"tear"`` log
        (``tear_log``, F_tear), signed so that a hand pulled back toward the cloth reads positive
        (the right hand, on the +axis side, feels -axis; every other hand feels +axis), after a
        centred moving average over ``smooth_steps`` median step periods (the rendered force
        carries 1 kHz texture: the linearisation and the spring between simulation steps)."""
        logs = {"felt": self.force_log, "tear": self.tear_log}
        if log not in logs:
            raise ConfigError(f"log must be 'felt' or 'tear', got {log!r}")
        sc = np.asarray(self.step_clock)
        if len(sc) < 2:
            raise DeviceStateError("fewer than two simulation steps taken: no tension to read")
        period = float(np.median(np.diff(sc)))
        a = np.asarray(axis, dtype=float)
        out = {}
        for hand in self._hands:
            t, f = logs[log].along_axis(hand, a)
            if len(t) == 0:
                out[hand] = np.full(len(sc), np.nan)
                continue
            sign = -1.0 if hand == "right" else 1.0
            out[hand] = np.interp(sc, t, _moving_average(t, sign * f, smooth_steps * period))
        return out

    def phases(
        self,
        log: str = "felt",
        *,
        axis: Sequence[float] = (1.0, 0.0, 0.0),
        pull_start: float = 0.0,
        smooth_steps: float = 5.0,
        peak_steps: Tuple[int, int] = (-10, 150),
        drop_fraction: float = 0.5,
        propagation_skip: int = 10,
        propagation_steps: int = 150,
    ) -> dict:
        """The three phases of the paper's Fig. 6 read from ``tension(log, axis, smooth_steps)``,
        in simulation steps (``k0`` = the step where ``tears_started`` first became non-zero):

        - elastic: from ``pull_start`` (simulated s) to the first tear;
        - peak: the largest mean tension (mean of the hands) from ``peak_steps[0]`` to
          ``peak_steps[1]`` steps after ``k0``;
        - drop: the first step after the peak where the mean tension falls below
          ``drop_fraction`` of the peak (None if it never does);
        - propagation: ``propagation_steps`` steps starting ``propagation_skip`` after the drop.

        Returns ``first_tear_step``, ``pull_step``, ``peak_step``, ``drop_step``, ``peak`` (mean
        of the hands), ``propagation`` (mean of the hands' medians), ``propagation_range``
        (start, stop) and ``per_hand``: {hand: ``before_pull`` (mean over the 10 steps before the
        pull), ``elastic`` (mean over steps k0-15..k0-5), ``peak`` (the hand's own largest
        tension in the peak window), ``propagation`` (median over the propagation phase)}."""
        if self.first_tear_step is None:
            raise DeviceStateError("the cloth has not torn yet: no Fig. 6 phases to read")
        ten = self.tension(log, axis=axis, smooth_steps=smooth_steps)
        n = len(self.step_clock)
        k0 = self.first_tear_step
        kpull = int(np.searchsorted(np.asarray(self.step_time), pull_start))
        mean = np.mean(np.stack(list(ten.values())), axis=0)
        window = np.arange(max(k0 + peak_steps[0], 0), min(k0 + peak_steps[1], n))
        kp = int(window[np.argmax(mean[window])])
        peak = float(mean[kp])
        below = np.flatnonzero(mean[kp:] < drop_fraction * peak)
        kd = kp + int(below[0]) if len(below) else None
        prop = (min(kd + propagation_skip, n), min(kd + propagation_skip + propagation_steps, n)) if kd is not None else (n, n)
        elastic = slice(max(k0 - 15, kpull, 0), max(k0 - 5, kpull + 1, 1))
        before = slice(max(kpull - 10, 0), max(kpull, 1))
        per_hand = {}
        for hand, x in ten.items():
            per_hand[hand] = {
                "before_pull": float(np.mean(x[before])),
                "elastic": float(np.mean(x[elastic])),
                "peak": float(np.max(x[window])),
                "propagation": float(np.median(x[prop[0] : prop[1]])) if prop[1] > prop[0] else float("nan"),
            }
        props = [v["propagation"] for v in per_hand.values()]
        return {
            "first_tear_step": k0,
            "pull_step": kpull,
            "peak_step": kp,
            "drop_step": kd,
            "peak": peak,
            "propagation": float(np.mean(props)),
            "propagation_range": prop,
            "mean_tension": mean,
            "per_hand": per_hand,
        }

    def save_force_log(self, csv_path, png_path=None, axis: Sequence[float] = (1.0, 0.0, 0.0), title: Optional[str] = None) -> Tuple[str, Optional[str]]:
        """Write the rendered force log as CSV (``ForceLog.to_csv``) and, optionally, a plot of
        the force along ``axis`` for every hand over time, like the paper's Fig. 6."""
        csv_out = self.force_log.to_csv(csv_path)
        png_out = None
        if png_path is not None:
            png_out = self.force_log.plot(png_path, axis=axis, title=title or "Force felt by each hand along the pull (live session)")
        return csv_out, png_out


# ---------------------------------------------------------------------------------------------
# Emulated devices for tests, the demo and the bench
# ---------------------------------------------------------------------------------------------
def falcon_coupling(scene_radius: float, *, rotation=FALCON_TO_SCENE, **kwargs) -> HandCoupling:
    """A Falcon coupling that maps its workspace ball (radius 4 cm) onto a scene ball of
    ``scene_radius`` (the offset is set at bind time when the session rebases)."""
    return HandCoupling.fit(Workspace(WORKSPACE_CENTRE, WORKSPACE_RADIUS), (0.0, 0.0, 0.0), scene_radius, rotation=rotation, **kwargs)


def pulling_hand(
    direction: Sequence[float],
    distance: float = 0.02,
    hold_s: float = 0.3,
    pull_s: float = 2.0,
    start: Sequence[float] = WORKSPACE_CENTRE,
    stiffness: float = 1500.0,
    damping: float = 15.0,
    clock: Optional[Callable[[], float]] = None,
):
    """A scripted hand (``falcon_emulator.spring_hand``) that holds the grip at ``start`` for
    ``hold_s``, then pulls it ``distance`` metres along ``direction`` (device frame) over
    ``pull_s`` seconds with a smooth cosine blend, and holds it there.

    Time is the emulator's (one millisecond per packet, i.e. wall time) unless ``clock`` is
    given: then the pull follows ``clock()``, e.g. the simulated time, so the cloth is pulled
    the same way whatever the machine's speed (a loaded machine simulates fewer steps per second,
    and a wall-time hand would pull it faster in simulated time)."""
    d = np.asarray(direction, dtype=float)
    n = float(np.linalg.norm(d))
    if not n > 0.0:
        raise ConfigError(f"pull direction must be a non-zero 3-vector, got {direction!r}")
    d = d / n
    s = np.asarray(start, dtype=float)
    if not (pull_s > 0.0 and hold_s >= 0.0):
        raise ConfigError(f"need pull_s > 0 and hold_s >= 0, got {pull_s!r}, {hold_s!r}")

    def target(t):
        if clock is not None:
            t = clock()
        u = min(max((t - hold_s) / pull_s, 0.0), 1.0)
        return s + (distance * (0.5 - 0.5 * math.cos(math.pi * u))) * d

    return spring_hand(target, stiffness, damping)


def emulated_falcon(
    serial: str,
    hand: str,
    direction: Sequence[float],
    *,
    distance: float = 0.02,
    hold_s: float = 0.3,
    pull_s: float = 2.0,
    stiffness: float = 1500.0,
    damping: float = 15.0,
    clock: Optional[Callable[[], float]] = None,
    substeps: int = 1,
    max_force: float = FALCON_MAX_FORCE,
    **emulator_kwargs,
) -> Tuple[FalconDevice, FalconEmulator]:
    """A ``FalconDevice`` over a ``FalconEmulator`` with its firmware loaded and homed (the
    emulator's own options), held by a ``pulling_hand``. Returns (device, emulator): the emulator
    is there to unplug it, press its buttons or read what it was sent.

    ``substeps`` (emulator integration sub-steps per packet, 1 here vs 4 by default): the grip
    physics is work a real Falcon does in hardware, while the emulator does it inside the servo
    thread's poll; one semi-implicit sub-step per millisecond is stable for the grip (its stiffest
    term, the end stops, gives ω·dt ≈ 0.6) and leaves the servo thread's time to the servo."""
    emu = FalconEmulator(
        serial,
        firmware_loaded=True,
        homed=True,
        hand=pulling_hand(direction, distance, hold_s, pull_s, stiffness=stiffness, damping=damping, clock=clock),
        substeps=substeps,
        **emulator_kwargs,
    )
    return FalconDevice(transport=emu, hand=hand, max_force=max_force), emu


# ---------------------------------------------------------------------------------------------
# Fig. 6 analysis
# ---------------------------------------------------------------------------------------------
def _moving_average(t: np.ndarray, x: np.ndarray, window: float) -> np.ndarray:
    """Centred moving average over ``window`` (same unit as ``t``); exact for uneven sampling."""
    if window <= 0.0 or len(x) == 0:
        return x.copy()
    c = np.concatenate(([0.0], np.cumsum(x)))
    lo = np.searchsorted(t, t - 0.5 * window, side="left")
    hi = np.searchsorted(t, t + 0.5 * window, side="right")
    return (c[hi] - c[lo]) / np.maximum(hi - lo, 1)
