"""The 1 kHz haptic servo loop and the coupling of Le Gouis et al. (WHC 2017), section VI, eq. (5).

This file owns:
- ``HandCoupling``: the affine map device -> scene (the proxy) and the force law;
- ``SimulationMailbox`` / ``ProxySample``: the only data shared with the simulation thread;
- ``ServoLoop``: one servo thread per device, watchdog, rate limiting, timing statistics (the
  timing probe of ``tearcloth bench``, ``measure_servo``, lives in ``tearcloth.bench.servo``).

Names (design.md: one name per concept). *Handle* = the grasped, constrained vertices of the
cloth (simulated, updated at simulation rate). *Proxy* = the image of the device grip in the
scene, an affine function of the device position updated at haptic rate; the simulation moves
the handle to the proxy at every step.

Force law, rendered every tick (scene frame, N), with its sign convention:

    F = F_tear + k_position · (x_handle − x_proxy) − k_velocity · v_proxy

- ``F_tear`` (eq. 6) is the force the cloth exerts on the handle: Σ over handle vertices of
  elastic + external forces. The user holds the handle, so this is the cloth pulling the hand.
- ``x_handle − x_proxy``: the handle lags where the cloth resists, so the spring pulls the hand
  back toward the handle, i.e. toward the cloth (the paper writes k·(x_proxy − x_tool) with its
  proxy on the cloth side and its tool on the device side; same physics, our names).
- ``−k_velocity · v``: damping for stability (the velocity is filtered by the device).
- Between simulation steps, if the simulation published a linearisation (Otaduy & Lin 2006),
  ``F_tear`` is replaced by ``f0 + K · (x_proxy − x0)`` so that stiffness is felt at 1 kHz
  instead of as a 100 Hz staircase.

The scene force is then mapped to the device frame (``force_scale · Rᵀ``), its norm clamped to
the device's ``max_force``, and its change per tick limited (``max_force_rate``, N/s): a tear is
a force step, and a step on a motor is a click the user feels as a hit.

Safety: if the simulation mailbox is older than ``stall_timeout_s`` (default 10 ms) the force is
zeroed (immediately, not rate-limited: removing force cannot inject energy); the check runs
*before* the tick's I/O, with one period of look-ahead, so zero reaches the device no later than
``stall_timeout_s`` after the last update. A LOST device gets zero force and its loop ends.

Threads: one per device. Two Falcons each need a USB round trip per tick; pyusb/libusb release
the GIL during transfers, so two threads overlap them where one thread would serialise them
(~2x the I/O time per period). A device that stalls or dies ends or delays only its own loop,
and the other hand keeps its 1 kHz and its watchdog. The cost (two threads contending for the
GIL for ~0.1 ms of Python each per tick) is small. Timing: sleep until ``spin_s`` before the
deadline, then spin with ``os.sched_yield`` (which releases the GIL, so spinning does not starve
the simulation thread). While running, the interpreter's GIL switch interval is lowered to
0.5 ms (restored on stop): at the default 5 ms, a servo thread waiting for the GIL behind
pure-Python work on the main thread would miss five ticks in a row.

Nothing here touches bpy: the Blender side reads ``proxy()`` and calls ``publish()`` from its
own thread (modal timer / simulation driver).
"""
from __future__ import annotations

import math
import os
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, Dict, Mapping, NamedTuple, Optional, Sequence, Union

import numpy as np

from .. import settings
from .device import ConfigError, DeviceState, HapticDevice, HapticError, Workspace

_HAND = settings.defaults("hand")  # the coupling's gains are the Blender hand's: one source

__all__ = [
    "HandCoupling",
    "SimulationSample",
    "SimulationMailbox",
    "ProxySample",
    "ServoLoop",
]

_ZERO = np.zeros(3)


def _vec3(value, what: str) -> np.ndarray:
    v = np.asarray(value, dtype=float)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ConfigError(f"{what} must be a finite 3-vector, got {value!r}")
    return v


@dataclass
class HandCoupling:
    """Device -> scene map and force law parameters for one hand (see the module docstring).

    - proxy = ``offset`` + ``scale`` · ``rotation`` · p_device (scene m);
    - ``k_position`` (N/m) and ``k_velocity`` (N·s/m) act in the scene;
    - device force = ``force_scale`` · rotationᵀ · scene force.
    The device feels stiffness ``force_scale·k_position·scale`` (``felt_stiffness``), which must
    stay below the device's ``max_stiffness``; ``ServoLoop`` refuses couplings that do not."""

    # scale and force_scale default to the identity map (device metres and newtons are scene
    # metres and newtons); the Blender hand fits its own (settings rows "scale", "force_scale")
    scale: float = 1.0
    offset: Sequence[float] = (0.0, 0.0, 0.0)
    rotation: Optional[Sequence[Sequence[float]]] = None
    k_position: float = _HAND["k_position"]
    k_velocity: float = _HAND["k_velocity"]
    force_scale: float = 1.0
    max_force_rate: float = 1000.0
    use_linearisation: bool = True
    _r: np.ndarray = field(init=False, repr=False)
    _o: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        for name in ("scale", "force_scale", "max_force_rate"):
            v = getattr(self, name)
            if not (v > 0.0 and math.isfinite(v)):
                raise ConfigError(f"{name} must be a positive finite number, got {v!r}")
        for name in ("k_position", "k_velocity"):
            v = getattr(self, name)
            if not (v >= 0.0 and math.isfinite(v)):
                raise ConfigError(f"{name} must be a finite number >= 0, got {v!r}")
        r = np.eye(3) if self.rotation is None else np.asarray(self.rotation, dtype=float)
        if r.shape != (3, 3) or not np.allclose(r @ r.T, np.eye(3), atol=1e-6) or np.linalg.det(r) <= 0.0:
            raise ConfigError("rotation must be a proper 3x3 rotation matrix (orthonormal, det +1)")
        self._r = r
        self._o = _vec3(self.offset, "offset")

    @classmethod
    def fit(
        cls,
        workspace: Workspace,
        scene_centre: Sequence[float],
        scene_radius: float,
        rotation: Optional[Sequence[Sequence[float]]] = None,
        **kwargs,
    ) -> "HandCoupling":
        """Coupling that maps the device workspace ball onto a scene ball (scale = radius ratio)."""
        if not scene_radius > 0.0:
            raise ConfigError(f"scene radius must be > 0 m, got {scene_radius!r}")
        scale = scene_radius / workspace.radius
        r = np.eye(3) if rotation is None else np.asarray(rotation, dtype=float)
        offset = np.asarray(scene_centre, dtype=float) - scale * (r @ np.asarray(workspace.centre, dtype=float))
        return cls(scale=scale, offset=tuple(offset), rotation=r, **kwargs)

    def proxy(self, device_position) -> np.ndarray:
        return self._o + self.scale * (self._r @ np.asarray(device_position, dtype=float))

    def vector_to_scene(self, v_device) -> np.ndarray:
        return self.scale * (self._r @ np.asarray(v_device, dtype=float))

    def force_to_device(self, f_scene) -> np.ndarray:
        return self.force_scale * (self._r.T @ np.asarray(f_scene, dtype=float))

    def force_to_scene(self, f_device) -> np.ndarray:
        return (self._r @ np.asarray(f_device, dtype=float)) / self.force_scale

    @property
    def felt_stiffness(self) -> float:
        """Stiffness the hand feels (N/m of device motion) from the proxy spring."""
        return self.force_scale * self.k_position * self.scale

    @property
    def felt_damping(self) -> float:
        return self.force_scale * self.k_velocity * self.scale


class SimulationSample(NamedTuple):
    """What the simulation publishes for one hand (scene frame). ``stamp`` is on the servo clock."""

    f_tear: np.ndarray
    handle_position: np.ndarray
    f0: Optional[np.ndarray]
    stiffness: Optional[np.ndarray]
    x0: Optional[np.ndarray]
    stamp: float
    seq: int


class ProxySample(NamedTuple):
    """What the servo publishes for one hand (scene frame), read by the simulation."""

    position: np.ndarray
    velocity: np.ndarray
    buttons: int
    state: DeviceState
    force: np.ndarray  # force actually rendered, mapped back to the scene (N)
    stamp: float
    seq: int


class SimulationMailbox:
    """Latest-value slot the simulation thread writes and the servo thread reads.

    Writers build a new immutable sample and swap one reference under a lock; the reader takes
    the reference without waiting (a reference read is atomic in CPython), so the 1 kHz thread
    never blocks behind the simulation. Input is validated here, in the writer's thread, so a bad
    value raises where it was produced instead of inside the servo."""

    def __init__(self, clock: Callable[[], float] = time.perf_counter):
        self._clock = clock
        self._lock = threading.Lock()
        self._sample: Optional[SimulationSample] = None
        self._seq = 0

    def publish(self, f_tear, handle_position, *, f0=None, stiffness=None, x0=None, stamp: Optional[float] = None) -> None:
        """Publish F_tear (N) and the handle position (m); optionally the linearisation
        f0 (N), stiffness K = dF/dx (3x3, N/m) and the point x0 (m) where it was taken."""
        f = _vec3(f_tear, "f_tear")
        x = _vec3(handle_position, "handle_position")
        lin = (f0, stiffness, x0)
        if any(v is not None for v in lin):
            if any(v is None for v in lin):
                raise ConfigError("the linearisation needs all of f0, stiffness and x0")
            f0 = _vec3(f0, "f0")
            x0 = _vec3(x0, "x0")
            k = np.asarray(stiffness, dtype=float)
            if k.shape != (3, 3) or not np.all(np.isfinite(k)):
                raise ConfigError(f"stiffness must be a finite 3x3 matrix (N/m), got shape {k.shape}")
            stiffness = k
        with self._lock:
            self._seq += 1
            self._sample = SimulationSample(f, x, f0, stiffness, x0, self._clock() if stamp is None else stamp, self._seq)

    @property
    def latest(self) -> Optional[SimulationSample]:
        return self._sample


class _Hand:
    """Per-hand servo state (owned by that hand's thread)."""

    def __init__(self, name: str, device: HapticDevice, coupling: HandCoupling, clock, window: int):
        self.name = name
        self.device = device
        self.coupling = coupling
        self.mailbox = SimulationMailbox(clock)
        self.proxy: Optional[ProxySample] = None
        self.proxy_seq = 0
        self.force = np.zeros(3)  # device frame, as last commanded
        self.last_now: Optional[float] = None
        self.alive = True
        self.stale = True
        self.watchdog_trips = 0
        self.error: Optional[BaseException] = None
        self.thread: Optional[threading.Thread] = None
        self.periods = np.zeros(window)
        self.n_periods = 0
        self.ticks = 0
        self.k_seq = -1
        self.k_lin: Optional[np.ndarray] = None
        self.realtime: Optional[bool] = None  # SCHED_FIFO obtained? None = not asked

    def record_period(self, dt: float) -> None:
        self.periods[self.n_periods % len(self.periods)] = dt
        self.n_periods += 1


_switch_lock = threading.Lock()
_switch_users = 0
_switch_saved: Optional[float] = None


def _lower_switch_interval(value: Optional[float]) -> bool:
    global _switch_users, _switch_saved
    if not value:
        return False
    with _switch_lock:
        if _switch_users == 0:
            _switch_saved = sys.getswitchinterval()
            if _switch_saved > value:
                sys.setswitchinterval(value)
        _switch_users += 1
    return True


def _restore_switch_interval() -> None:
    global _switch_users
    with _switch_lock:
        _switch_users -= 1
        if _switch_users == 0 and _switch_saved is not None:
            sys.setswitchinterval(_switch_saved)


_yield = getattr(os, "sched_yield", None) or (lambda: time.sleep(0))


class LoopEnd(Exception):
    """Raised by a tick to end its hand's loop without an error (the servo process's peer is gone)."""


def _set_realtime(priority: Optional[int]) -> Optional[bool]:
    """Run the calling thread under SCHED_FIFO at ``priority`` (Linux: needs root, CAP_SYS_NICE
    or an RLIMIT_RTPRIO). On a loaded machine this is what keeps a 1 kHz tick on time: a normal
    thread waits behind every other runnable process for its time slice. The thread sleeps
    between ticks and the kernel's RT throttling keeps a share for normal tasks, so it cannot
    starve the machine. Returns True on success, False when refused or unsupported, None when
    not asked."""
    if priority is None:
        return None
    setter = getattr(os, "sched_setscheduler", None)
    if setter is None:
        return False
    try:
        setter(0, os.SCHED_FIFO, os.sched_param(int(priority)))  # 0: the calling thread on Linux
        return True
    except (OSError, ValueError, OverflowError):
        return False


class ServoLoop:
    """The haptic loop for one or more hands.

    ``devices``: {hand name: device} or a sequence (names from ``device.hand``, else "right" for
    one device, "left"/"right" for two). ``couplings``: {hand: HandCoupling}; missing hands get
    ``HandCoupling.fit(device.workspace, (0, 0, 0), device.workspace.radius)`` (1:1 scale).

    Use either the threads (``start``/``stop``) or ``tick(hand, now)`` from your own loop (tests
    drive it in emulated time). The simulation side calls ``publish(hand, ...)`` and reads
    ``proxy(hand)``."""

    def __init__(
        self,
        devices: Union[Mapping[str, HapticDevice], Sequence[HapticDevice]],
        couplings: Optional[Mapping[str, HandCoupling]] = None,
        *,
        period_s: float = 0.001,
        stall_timeout_s: float = 0.010,
        clock: Callable[[], float] = time.perf_counter,
        force_log=None,
        spin_s: float = 0.0003,
        switch_interval_s: Optional[float] = 0.0005,
        stats_window: int = 60000,
        check_stiffness: bool = True,
        priority: Optional[int] = None,
    ):
        if not 0.0 < period_s <= 0.1:
            raise ConfigError(f"period must be in (0, 0.1] s, got {period_s!r}")
        if not stall_timeout_s > period_s:
            raise ConfigError(f"stall timeout ({stall_timeout_s} s) must exceed the servo period ({period_s} s)")
        if not isinstance(devices, Mapping):
            devices = list(devices)
            defaults = ["right"] if len(devices) == 1 else ["left", "right"] if len(devices) == 2 else [f"hand{i}" for i in range(len(devices))]
            names = [d.hand or defaults[i] for i, d in enumerate(devices)]
            if len(set(names)) != len(names):
                raise ConfigError(f"two devices claim the same hand: {names}")
            devices = dict(zip(names, devices))
        if not devices:
            raise ConfigError("the servo loop needs at least one device")
        couplings = dict(couplings or {})
        unknown = set(couplings) - set(devices)
        if unknown:
            raise ConfigError(f"couplings given for unknown hands {sorted(unknown)}; hands are {sorted(devices)}")
        self.period_s = float(period_s)
        self.stall_timeout_s = float(stall_timeout_s)
        self.clock = clock
        self.force_log = force_log
        self.spin_s = float(spin_s)
        self.switch_interval_s = switch_interval_s
        self.priority = priority  # SCHED_FIFO priority of the servo threads (None: OS default)
        self._hands: Dict[str, _Hand] = {}
        for name, dev in devices.items():
            c = couplings.get(name) or HandCoupling.fit(dev.workspace, (0.0, 0.0, 0.0), dev.workspace.radius)
            if check_stiffness and dev.has_force:
                if c.felt_stiffness > dev.max_stiffness:
                    raise ConfigError(
                        f"hand {name!r}: the proxy spring feels like {c.felt_stiffness:.0f} N/m on the device, above "
                        f"{dev.name}'s stable limit of {dev.max_stiffness:.0f} N/m; lower k_position, force_scale or the workspace scale"
                    )
                if c.felt_damping > dev.max_damping:
                    raise ConfigError(
                        f"hand {name!r}: damping {c.felt_damping:.1f} N·s/m on the device exceeds {dev.name}'s limit of "
                        f"{dev.max_damping:.1f} N·s/m; lower k_velocity or force_scale"
                    )
            self._hands[name] = _Hand(name, dev, c, clock, stats_window)
        self._stop = threading.Event()
        self._running = False
        self._switch_lowered = False

    # ---- simulation side ----------------------------------------------------------------------
    @property
    def hands(self):
        return list(self._hands)

    def device(self, hand: str) -> HapticDevice:
        return self._hand(hand).device

    def coupling(self, hand: str) -> HandCoupling:
        return self._hand(hand).coupling

    def mailbox(self, hand: str) -> SimulationMailbox:
        return self._hand(hand).mailbox

    def publish(self, hand: str, f_tear, handle_position, **linearisation) -> None:
        """Simulation thread: publish F_tear and the handle position (see ``SimulationMailbox``)."""
        self._hand(hand).mailbox.publish(f_tear, handle_position, **linearisation)

    def proxy(self, hand: str) -> Optional[ProxySample]:
        """Simulation thread: latest proxy (None before the first tick)."""
        return self._hand(hand).proxy

    def _hand(self, hand: str) -> _Hand:
        try:
            return self._hands[hand]
        except KeyError:
            raise ConfigError(f"unknown hand {hand!r}; hands are {sorted(self._hands)}") from None

    # ---- one servo cycle ----------------------------------------------------------------------
    def tick(self, hand: str, now: Optional[float] = None) -> ProxySample:
        """Run one servo cycle for ``hand`` at time ``now`` (servo clock). Returns the proxy."""
        h = self._hand(hand)
        dev = h.device
        now = self.clock() if now is None else now
        h.ticks += 1
        sample = h.mailbox.latest
        # Watchdog before the I/O: with one period of look-ahead, so that the zero force goes out
        # in this tick's exchange rather than one period past the deadline.
        stale = sample is None or (now - sample.stamp) + self.period_s > self.stall_timeout_s
        if stale and not h.stale:
            h.watchdog_trips += 1
        h.stale = stale
        if stale and h.force.any():
            h.force = dev.set_force(_ZERO)
        dev.poll()
        c = h.coupling
        if dev.state is DeviceState.LOST:
            h.force = dev.set_force(_ZERO)
            h.alive = False
            # Stamped when the loss was seen, not when the tick began: a cable pulled between the
            # two must not log its zero-force tick before the pull (the log's promise is that
            # every tick after the loss rendered zero, and this one is that tick).
            return self._publish_proxy(h, c.proxy(dev.position), np.zeros(3), dev, max(now, self.clock()))
        x_proxy = c.proxy(dev.position)
        v_proxy = c.vector_to_scene(dev.velocity)
        dt = self.period_s if h.last_now is None else min(max(now - h.last_now, 0.0), 4.0 * self.period_s)
        h.last_now = now
        if stale or dev.state is not DeviceState.READY or not dev.has_force:
            h.force = dev.set_force(_ZERO)
        else:
            if sample.f0 is not None and c.use_linearisation:
                f_tear = sample.f0 + self._safe_stiffness(h, sample) @ (x_proxy - sample.x0)
            else:
                f_tear = sample.f_tear
            f_scene = f_tear + c.k_position * (sample.handle_position - x_proxy) - c.k_velocity * v_proxy
            target = c.force_to_device(f_scene)
            n = float(np.linalg.norm(target))
            if n > dev.max_force:
                target = target * (dev.max_force / n)
            step = target - h.force
            max_step = c.max_force_rate * dt
            s = float(np.linalg.norm(step))
            if s > max_step:
                step = step * (max_step / s)
            h.force = dev.set_force(h.force + step)
        return self._publish_proxy(h, x_proxy, v_proxy, dev, now)

    def _safe_stiffness(self, h: _Hand, sample: SimulationSample) -> np.ndarray:
        """The published K, scaled down if, added to the proxy spring, the device would feel more
        than its stable stiffness (the Frobenius norm bounds the spectral norm). Cached per
        sample: computed once per simulation step, not per tick."""
        if h.k_seq != sample.seq:
            k = sample.stiffness
            c, dev = h.coupling, h.device
            budget = dev.max_stiffness / (c.force_scale * c.scale) - c.k_position
            norm = float(np.linalg.norm(k))
            if math.isfinite(budget) and norm > max(budget, 0.0):
                k = k * (max(budget, 0.0) / norm)
            h.k_lin, h.k_seq = k, sample.seq
        return h.k_lin

    def _publish_proxy(self, h: _Hand, x, v, dev: HapticDevice, now: float) -> ProxySample:
        f_scene = h.coupling.force_to_scene(h.force)
        h.proxy_seq += 1
        p = ProxySample(x, v, dev.buttons, dev.state, f_scene, now, h.proxy_seq)
        h.proxy = p
        if self.force_log is not None:
            self.force_log.record(h.name, now, f_scene)
        return p

    # ---- threads ------------------------------------------------------------------------------
    @property
    def running(self) -> bool:
        return self._running

    def start(self) -> None:
        """Start one servo thread per hand. Devices must be open (HOMING or READY)."""
        if self._running:
            return
        for h in self._hands.values():
            if not h.device.is_open or h.device.state is DeviceState.LOST:
                raise HapticError(f"hand {h.name!r}: {h.device.name} is not open ({h.device.state.value}): {h.device.message}")
        self._stop.clear()
        self._switch_lowered = _lower_switch_interval(self.switch_interval_s)
        self._running = True
        for h in self._hands.values():
            h.alive = True
            h.error = None
            h.last_now = None
            h.n_periods = 0
            h.thread = threading.Thread(target=self._run, args=(h,), name=f"tearcloth-servo-{h.name}", daemon=True)
            h.thread.start()

    def stop(self, timeout_s: float = 1.0) -> None:
        """Stop and join the threads; every device is left with zero force (sent to it)."""
        self._stop.set()
        stuck = []
        for h in self._hands.values():
            if h.thread is not None:
                h.thread.join(timeout_s)
                if h.thread.is_alive():
                    stuck.append(h.name)
                else:
                    h.thread = None
            else:
                self._zero(h)  # tick-driven use: nothing else will flush the zero force
        if self._switch_lowered:
            _restore_switch_interval()
            self._switch_lowered = False
        self._running = False
        if stuck:
            raise HapticError(f"servo thread(s) for {stuck} did not stop within {timeout_s} s (device I/O blocked?)")

    def _zero(self, h: _Hand) -> None:
        h.force = np.zeros(3)
        dev = h.device
        try:
            dev.set_force(_ZERO)
            if dev.state in (DeviceState.READY, DeviceState.HOMING):
                dev.poll()  # the force goes out with the next exchange: do it now
        except HapticError:
            pass

    def _thread_start(self, h: _Hand) -> float:
        """Per-thread set-up at the start of a hand's loop; returns the first tick's time."""
        h.realtime = _set_realtime(self.priority)
        return self.clock()

    def _thread_end(self, h: _Hand) -> None:
        """After the hand's loop has zeroed its device (hook for the servo process)."""

    def _run(self, h: _Hand) -> None:
        clock, period = self.clock, self.period_s
        next_t = self._thread_start(h)
        last_start = None
        try:
            while not self._stop.is_set():
                start = clock()
                if last_start is not None:
                    h.record_period(start - last_start)
                last_start = start
                self.tick(h.name, start)
                if not h.alive:
                    break  # device LOST: force already zero, this hand's loop ends
                next_t += period
                now = clock()
                if now - next_t > period:
                    next_t = now  # fell behind (GC pause, suspended VM): resync, do not burst
                self._wait_until(next_t)
        except LoopEnd:
            pass  # ended on purpose by the tick (force already zero)
        except BaseException as exc:  # keep the other hands running; report via stats()
            h.error = exc
        finally:
            self._zero(h)
            self._thread_end(h)

    def _wait_until(self, deadline: float) -> None:
        clock, spin = self.clock, self.spin_s
        while True:
            remaining = deadline - clock()
            if remaining <= 0.0:
                return
            if remaining > spin:
                time.sleep(remaining - spin)
            else:
                _yield()

    # ---- statistics ---------------------------------------------------------------------------
    def stats(self, hand: Optional[str] = None) -> dict:
        """Timing of the threaded loop: rate_hz, p50_ms, p99_ms (over the last ``stats_window``
        periods), plus ticks, overruns (periods > 2x nominal), watchdog trips, state, error.
        Without ``hand``: the worst hand's figures and ``per_hand``."""
        if hand is not None:
            h = self._hand(hand)
            n = min(h.n_periods, len(h.periods))
            p = h.periods[:n] if h.n_periods <= len(h.periods) else h.periods
            out = {
                "rate_hz": float(1.0 / p.mean()) if n else 0.0,
                "p50_ms": float(np.percentile(p, 50) * 1e3) if n else float("nan"),
                "p99_ms": float(np.percentile(p, 99) * 1e3) if n else float("nan"),
                "max_ms": float(p.max() * 1e3) if n else float("nan"),
                "periods": int(n),
                "ticks": h.ticks,
                "overruns": int(np.count_nonzero(p > 2.0 * self.period_s)) if n else 0,
                "watchdog_trips": h.watchdog_trips,
                "state": h.device.state.value,
                "error": None if h.error is None else repr(h.error),
                "realtime": h.realtime,
            }
            return out
        per = {name: self.stats(name) for name in self._hands}
        vals = list(per.values())
        return {
            "rate_hz": min(v["rate_hz"] for v in vals),
            "p50_ms": max(v["p50_ms"] for v in vals),
            "p99_ms": max(v["p99_ms"] for v in vals),
            "per_hand": per,
        }

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc):
        self.stop()
        return False
