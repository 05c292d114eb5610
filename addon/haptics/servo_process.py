"""The servo in a process of its own: the 1 kHz loops own their core, unprivileged.

This file owns:
- ``DeviceSpec``: a picklable recipe for a device (a factory path and its arguments), built in
  the servo process, never in the simulating one;
- the shared-memory exchange (``_Shared``): per hand a seqlock block simulation -> servo (F_tear,
  handle, linearisation, stamp), a seqlock block servo -> simulation (proxy, buttons, state,
  rendered force, what the device was last sent), the device's message, and a ring of every
  tick's rendered force (the force log);
- ``ServoProcess``: the simulation side (spawn, open, start, publish, proxy, stats, stop), with
  the ``ServoLoop`` calls ``LiveSession`` uses; ``RemoteDevice`` / ``RemoteEmulator``: what the
  simulating process sees of a device and of an emulated Falcon that live in the servo process;
- ``open_ready``: open a device, wait for its homing, insist on READY (both servo kinds use it);
- ``ServoProcess.begin_open``/``poll_open``: the devices open (a Falcon loads firmware and homes)
  in the servo process while the caller keeps its own loop (Blender's timer), each device's state
  and message shown through the shared memory meanwhile; ``ServoProcessError`` when the process
  itself cannot start (the caller may fall back to threads, and says so);
- a per-hand target block simulation -> servo (``set_target``, ``RemoteDevice.move_by``) for a
  device driven from the simulating process (the keyboard hand, ``DeviceSpec.target_arg``);
- the simulating process's ``sys.path`` appended in the servo process, so whatever factory or
  hook it can import ("fakes:ftdi_falcon" in tests), the servo process can;
- the servo process itself (``_child_main``, ``_ProcessServo``).

Why a process and not native threads. The servo's tick is Python (the coupling of eq. 5, the
Falcon's packets and kinematics, pyftdi/hidapi I/O, the byte-level emulator): moving it to native
threads that never take the GIL would mean rewriting all of that in C, FTDI and HID I/O
included. A process of its own has its own GIL, so no Python work of the simulation or of
Blender (panels, timers, handlers, a pure-Python add-on busy on the main thread) can hold a tick
up; only the OS scheduler can, and that is what the unprivileged measures below address. The
price is one copy of ~60 floats per step through shared memory, and devices that must be
described (``DeviceSpec``) instead of handed over as open objects (a USB handle does not cross a
``spawn``).

Exchange: ``multiprocessing.shared_memory`` holding float64 slots. Each block is a seqlock: the
writer bumps the block's counter to odd, writes, bumps it to even; the reader copies the block
and retries if the counter was odd or changed under it. Neither side ever waits for the other
(the servo never blocks behind the simulation). Every slot has a single writer. Ordering: CPython
issues each numpy store as a plain store, which x86-64 (TSO) keeps in program order; on weakly
ordered CPUs a torn read is still caught in practice by the counter re-read, and the servo
checks every value is finite before use and clamps the force regardless.

Safety, all in the servo process, no help from the simulating one needed:
- simulation stall: the mailbox's stamp older than ``stall_timeout_s`` (written into the shared
  header by the simulation, read every tick) zeroes the force, as in ``ServoLoop``;
- simulating process gone (killed, crashed): the simulating process keeps two idle sentinel
  threads, and every tick polls a thread pidfd of each (``pidfd_open(tid, PIDFD_THREAD)``, Linux
  6.9+): a killed process's threads exit at once, while the process itself is only reaped (its
  pipe closed, its children reparented) once its whole address space is torn down, measured 5-30
  ms after SIGKILL here. Two sentinels because the last thread out does the teardown, and it can
  be only one of them. Every tick also compares ``os.getppid()`` with the pid that spawned it (a
  reaped parent reparents us) and the main thread sees the control pipe's EOF: the fallbacks
  where thread pidfds are missing. Either way the force goes to zero in that tick, the devices
  are closed and the process exits. A hung simulating process stops publishing: the stall rule
  covers it;
- device unplugged: the device's own LOST handling (zero force, that hand's loop ends);
- stop (``ServoProcess.stop``, hence unregister and file load through ``LiveSession.stop``):
  zero force sent, devices closed, process joined; clamp and rate limit are ``ServoLoop``'s.

Without privileges (reported by ``stats()['privileges']``):
- ``os.setsid()`` (``own_session``, default on): a session of its own, hence (Linux, autogroup on) a scheduling group of its
  own, so CFS/EEVDF shares the CPU between our servo and the whole simulating session rather
  than among all their threads; a mostly sleeping group wakes with lag to spare and preempts;
- ``prctl(PR_SET_TIMERSLACK, 1 ns)`` per servo thread: the kernel may otherwise add 50 µs of
  slack to every sleep;
- ``clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME)`` through ctypes (which releases the GIL) to
  the tick's absolute deadline, so a late wake-up does not shift the following ticks; then an
  optional short spin (``spin_s``);
- a short scheduler slice (``sched_setattr`` with SCHED_OTHER and ``sched_runtime`` =
  ``slice_s``, 100 µs by default): since Linux 6.12 (EEVDF) any task may ask for a slice shorter
  than the default ~3 ms, which gives it an earlier virtual deadline, so a servo thread that
  wakes preempts a CPU hog instead of waiting out the hog's slice; older kernels refuse or ignore
  it (reported);
- hands phase-shifted by period / n: two servo threads never want the process's GIL at once;
- the cyclic garbage collector is frozen and disabled after set-up (the tick creates no
  cycles; reference counting frees everything), so no collection pause lands in a tick;
- SCHED_FIFO only if asked (``priority``) and granted; CPU affinity only if asked (``cpus``).
"""
from __future__ import annotations

import ctypes
import ctypes.util
import dataclasses
import gc
import importlib
import math
import mmap
import os
import select
import socket
import subprocess
import sys
import threading
import time
from multiprocessing.connection import Connection
from dataclasses import dataclass, field
from multiprocessing import shared_memory
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from . import device as _device_module
from .device import (
    ConfigError,
    DeviceNotFoundError,
    DeviceState,
    DeviceStateError,
    FirmwareError,
    HapticDevice,
    HapticError,
    NotHomedError,
)
from .servo import HandCoupling, LoopEnd, ProxySample, ServoLoop, SimulationMailbox, SimulationSample, _set_realtime

__all__ = ["DeviceSpec", "ServoProcess", "ServoProcessError", "RemoteDevice", "RemoteEmulator", "open_ready"]


class ServoProcessError(HapticError):
    """The servo process itself could not start or answer (not a device's error): the caller may
    fall back to the in-process servo threads, and says so."""

# ---- device opening (shared with the in-process servo of LiveSession) --------------------------


def open_ready(dev: HapticDevice, hand: str, homing_timeout_s: float,
               on_poll: Optional[Callable[[HapticDevice], None]] = None) -> None:
    """Open ``dev`` for ``hand``, poll it through homing for up to ``homing_timeout_s`` and insist
    on READY. Errors keep their class with the hand named in front; the device is closed again.
    ``on_poll(dev)`` after the open and every homing poll (the servo process shows the state)."""
    try:
        state = dev.open()
    except HapticError as exc:
        try:
            named = type(exc)(f"hand {hand!r}: {exc}")
        except Exception:
            named = DeviceNotFoundError(f"hand {hand!r}: {dev.name} could not be opened: {exc}")
        raise named from exc
    try:
        if on_poll is not None:
            on_poll(dev)
        if state is DeviceState.NEEDS_FIRMWARE:
            raise FirmwareError(f"hand {hand!r}: {dev.message}")
        if state is DeviceState.HOMING:
            deadline = time.perf_counter() + homing_timeout_s
            while dev.state is DeviceState.HOMING and time.perf_counter() < deadline:
                dev.poll()
                if on_poll is not None:
                    on_poll(dev)
                time.sleep(0.001)
            if dev.state is DeviceState.HOMING:
                raise NotHomedError(
                    f"hand {hand!r}: {dev.name} is not homed"
                    + (f" after {homing_timeout_s:.1f} s" if homing_timeout_s > 0 else "")
                    + f". {dev.message}"
                )
        if dev.state is not DeviceState.READY:
            raise DeviceNotFoundError(f"hand {hand!r}: {dev.name} is not ready ({dev.state.value}): {dev.message}")
    except BaseException:
        try:
            dev.close()
        except HapticError:
            pass
        raise


@dataclass(frozen=True)
class DeviceSpec:
    """How to build one device in the servo process: ``factory`` is "module:function" returning a
    ``HapticDevice`` or (device, emulator); ``kwargs`` its arguments (picklable). With
    ``sim_clock_arg`` the factory also gets, under that name, a callable returning the simulated
    time (s) the simulation writes to the shared header (emulated hands that follow it); with
    ``target_arg`` a callable returning the position (device frame, m) the simulating process set
    with ``ServoProcess.set_target`` (None before the first), for devices driven from there (the
    keyboard hand: Blender's key events)."""

    factory: str
    kwargs: Mapping[str, Any] = field(default_factory=dict)
    sim_clock_arg: Optional[str] = None
    target_arg: Optional[str] = None

    def build(self, sim_clock: Optional[Callable[[], float]] = None,
              target: Optional[Callable[[], Optional[np.ndarray]]] = None) -> Tuple[HapticDevice, Any]:
        """The device (and its emulator or None). A module path starting with "." is relative to
        this package (``.haptics.live:emulated_falcon``), whatever name Blender imported it under."""
        module, _, name = self.factory.partition(":")
        if not name:
            raise ConfigError(f"device factory must be 'module:function', got {self.factory!r}")
        fn = getattr(importlib.import_module(module, _PACKAGE), name)
        kwargs = dict(self.kwargs)
        if self.sim_clock_arg is not None:
            kwargs[self.sim_clock_arg] = sim_clock
        if self.target_arg is not None:
            kwargs[self.target_arg] = target
        out = fn(**kwargs)
        dev, emu = out if isinstance(out, tuple) else (out, None)
        if not isinstance(dev, HapticDevice):
            raise ConfigError(f"device factory {self.factory!r} returned {type(dev).__name__}, not a HapticDevice")
        return dev, emu


# ---- shared memory layout ---------------------------------------------------------------------
_H_STALL, _H_SIM_TIME, _H_SIZE = 0, 1, 8
# simulation -> servo, per hand: [seq, f_tear 3, handle 3, has_lin, f0 3, K 9, x0 3, stamp, sample_seq]
_S_SEQ, _S_F, _S_X, _S_LIN, _S_F0, _S_K, _S_X0, _S_STAMP, _S_NUM, _S_SIZE = 0, 1, 4, 7, 8, 11, 20, 23, 24, 25
# servo -> simulation, per hand: [seq, pos 3, vel 3, force 3, buttons, state, stamp, proxy_seq,
#                                 efforts 3 (as sent to the device), zero_since (nan = force on),
#                                 message seq]
_P_SEQ, _P_POS, _P_VEL, _P_F, _P_BUT, _P_STATE, _P_STAMP, _P_NUM, _P_EFF, _P_ZERO, _P_MSG, _P_SIZE = (
    0, 1, 4, 7, 10, 11, 12, 13, 14, 17, 18, 19)
# simulation -> servo, per hand, written by the thread that drives the hand (Blender's main
# thread for a keyboard hand): [seq, target 3 (device frame, m), set (0 until the first)]
_T_SEQ, _T_POS, _T_SET, _T_SIZE = 0, 1, 4, 5
_MSG_BYTES = 512
_ZEROS3, _ZEROS9 = (0.0,) * 3, (0.0,) * 9
_PACKAGE = __name__.rsplit(".", 2)[0]  # "tearcloth", or the name Blender gave the extension
_PACKAGE_DIR = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
_RING = 1 << 16  # rendered-force entries per hand (65 s at 1 kHz between two drains)
_STATES = list(DeviceState)


class _Shared:
    """Views over the segment: header, per-hand blocks, message bytes and force rings."""

    def __init__(self, n_hands: int, name: Optional[str] = None):
        self.n = n_hands
        floats = _H_SIZE + n_hands * (_S_SIZE + _P_SIZE + 1 + 4 * _RING + _T_SIZE)
        size = 8 * floats + n_hands * _MSG_BYTES
        self.shm = self.mm = None
        self.owner = name is None
        if name is None:
            self.shm = shared_memory.SharedMemory(create=True, size=size)
            self._name, buf = self.shm.name, self.shm.buf
        elif os.path.exists("/dev/shm/" + name.lstrip("/")):
            # Attach by mapping the file (Linux): a SharedMemory object would start a resource
            # tracker in this process that unlinks the segment when it exits.
            fd = os.open("/dev/shm/" + name.lstrip("/"), os.O_RDWR)
            try:
                self.mm = mmap.mmap(fd, size)
            finally:
                os.close(fd)
            self._name, buf = name, memoryview(self.mm)
        else:
            self.shm = shared_memory.SharedMemory(name=name)
            self._name, buf = name, self.shm.buf
            try:  # attaching must not make this process's tracker unlink the segment at exit
                from multiprocessing import resource_tracker

                resource_tracker.unregister(self.shm._name, "shared_memory")
            except Exception:
                pass
        self._buf = buf
        # frombuffer, not ndarray(buffer=...): numpy's ndarray releases the buffer export at once and
        # keeps only a reference, so a view alive in any thread did not stop close() from unmapping
        # the block under it (a read through it then dies of SIGSEGV; a Blender child of the tests
        # did, once); frombuffer's views hold the export, and close() leaves the mapping to them
        a = np.frombuffer(buf, dtype=np.float64, count=floats)
        if self.owner:
            a[:] = 0.0
        self.header = a[:_H_SIZE]
        o = _H_SIZE
        self.sim = [a[o + i * _S_SIZE : o + (i + 1) * _S_SIZE] for i in range(n_hands)]
        o += n_hands * _S_SIZE
        self.prox = [a[o + i * _P_SIZE : o + (i + 1) * _P_SIZE] for i in range(n_hands)]
        o += n_hands * _P_SIZE
        self.ring_count = a[o : o + n_hands]
        o += n_hands
        self.ring = [a[o + i * 4 * _RING : o + (i + 1) * 4 * _RING].reshape(_RING, 4) for i in range(n_hands)]
        o += n_hands * 4 * _RING
        self.target = [a[o + i * _T_SIZE : o + (i + 1) * _T_SIZE] for i in range(n_hands)]
        o += n_hands * _T_SIZE
        self.msg = [buf[8 * o + i * _MSG_BYTES : 8 * o + (i + 1) * _MSG_BYTES] for i in range(n_hands)]
        if self.owner:
            for p in self.prox:
                p[_P_ZERO] = 0.0

    @property
    def name(self) -> str:
        return self._name

    def close(self) -> None:
        # our views go first; one still held elsewhere holds the buffer's export (frombuffer above),
        # so the unmapping below fails with BufferError and the mapping goes with that view
        self.header = self.sim = self.prox = self.ring = self.ring_count = self.target = None
        for m in self.msg or ():
            m.release()
        self.msg = None
        try:
            if self.mm is not None:
                self._buf.release()
                self.mm.close()
            else:
                self.shm.close()
        except BufferError:
            # a view is still held somewhere: the mapping stays for it (kept referenced, so no
            # later __del__ tries the close again) and goes with the process
            _STILL_VIEWED.append(self.mm if self.mm is not None else self.shm)
        if self.owner:
            try:
                self.shm.unlink()
            except FileNotFoundError:
                pass


_STILL_VIEWED: list = []  # mappings a view outlived at close(): see _Shared.close


def _write(block: np.ndarray, values: Sequence[Tuple[int, Any]]) -> None:
    block[0] += 1.0  # odd: writing
    for offset, v in values:
        if np.ndim(v):
            v = np.ravel(v)
            block[offset : offset + len(v)] = v
        else:
            block[offset] = v
    block[0] += 1.0  # even: consistent


def _read(block: np.ndarray, tries: int = 1000) -> Optional[np.ndarray]:
    for _ in range(tries):
        s1 = block[0]
        if int(s1) & 1:
            continue
        copy = block.copy()
        if block[0] == s1:
            return copy
    return None  # a writer died mid-write: the caller treats it as no data


def _write_message(buf, text: str) -> None:
    """Only the servo writes it; the message seq in the proxy block, bumped after, says a new
    one is there (a reader racing a rewrite sees at worst a mixed sentence, never bad data)."""
    data = text.encode("utf-8", "replace")[: _MSG_BYTES - 3]
    buf[2 : 2 + len(data)] = data
    buf[2 + len(data)] = 0


def _read_message(buf) -> str:
    raw = bytes(buf[2:])
    return raw.split(b"\0", 1)[0].decode("utf-8", "replace")


# ---- unprivileged real-time measures ------------------------------------------------------------
_PR_SET_TIMERSLACK, _PR_GET_TIMERSLACK = 29, 30
_CLOCK_MONOTONIC, _TIMER_ABSTIME = 1, 1


class _Timespec(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long)]


def _libc():
    try:
        lib = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)  # CDLL: the GIL is released per call
        lib.clock_nanosleep.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.POINTER(_Timespec), ctypes.c_void_p]
        lib.prctl.argtypes = [ctypes.c_int, ctypes.c_ulong, ctypes.c_ulong, ctypes.c_ulong, ctypes.c_ulong]
        return lib
    except (OSError, AttributeError):
        return None


class _SchedAttr(ctypes.Structure):
    _fields_ = [("size", ctypes.c_uint32), ("sched_policy", ctypes.c_uint32), ("sched_flags", ctypes.c_uint64),
                ("sched_nice", ctypes.c_int32), ("sched_priority", ctypes.c_uint32), ("sched_runtime", ctypes.c_uint64),
                ("sched_deadline", ctypes.c_uint64), ("sched_period", ctypes.c_uint64), ("sched_util_min", ctypes.c_uint32),
                ("sched_util_max", ctypes.c_uint32)]


_SYS_SCHED_SETATTR = {"x86_64": 314, "aarch64": 274}.get(os.uname().machine if hasattr(os, "uname") else "")
_SYS_SCHED_GETATTR = {"x86_64": 315, "aarch64": 275}.get(os.uname().machine if hasattr(os, "uname") else "")


def _set_short_slice(lib, slice_s: Optional[float]) -> Optional[int]:
    """Ask the scheduler for a ``slice_s`` slice for the calling thread (SCHED_OTHER, nice
    unchanged); returns the slice now in force (ns, 0 = the kernel's default) or None when the
    call is not available here."""
    if lib is None or not slice_s or _SYS_SCHED_SETATTR is None:
        return None
    try:
        a = _SchedAttr(size=ctypes.sizeof(_SchedAttr), sched_policy=0, sched_nice=os.getpriority(os.PRIO_PROCESS, 0),
                       sched_runtime=int(slice_s * 1e9))
        if lib.syscall(_SYS_SCHED_SETATTR, 0, ctypes.byref(a), 0) != 0:
            return None
        b = _SchedAttr()
        if lib.syscall(_SYS_SCHED_GETATTR, 0, ctypes.byref(b), ctypes.sizeof(_SchedAttr), 0) != 0:
            return None
        return int(b.sched_runtime)
    except (AttributeError, OSError):
        return None


def _set_timer_slack(lib) -> Optional[int]:
    """1 ns timer slack for the calling thread; returns the slack now in force (ns), None if not Linux."""
    if lib is None:
        return None
    try:
        lib.prctl(_PR_SET_TIMERSLACK, 1, 0, 0, 0)
        return int(lib.prctl(_PR_GET_TIMERSLACK, 0, 0, 0, 0))
    except (AttributeError, OSError):
        return None


# ---- the servo process ------------------------------------------------------------------------
class _SharedMailbox:
    """``SimulationMailbox.latest`` read from the shared block (rebuilt only on a new sample)."""

    def __init__(self, block: np.ndarray):
        self.block = block
        self._num = -1.0
        self._sample: Optional[SimulationSample] = None

    @property
    def latest(self) -> Optional[SimulationSample]:
        b = self.block
        if b[_S_NUM] == self._num:
            return self._sample
        v = _read(b)
        if v is None:
            return self._sample  # the writer is mid-write (preempted): the previous sample, whose stamp ages
        if v[_S_NUM] == 0.0 or not np.all(np.isfinite(v)):
            return None  # nothing published yet, or a torn read on a weakly ordered CPU: zero force
        lin = v[_S_LIN] > 0.5
        self._sample = SimulationSample(
            v[_S_F : _S_F + 3], v[_S_X : _S_X + 3],
            v[_S_F0 : _S_F0 + 3] if lin else None, v[_S_K : _S_K + 9].reshape(3, 3) if lin else None,
            v[_S_X0 : _S_X0 + 3] if lin else None, float(v[_S_STAMP]), int(v[_S_NUM]))
        self._num = v[_S_NUM]
        return self._sample


class _RingLog:
    """The force log's writer side: every tick's rendered force into the hand's ring."""

    def __init__(self, shared: _Shared, index: Dict[str, int]):
        self.shared, self.index = shared, index

    def record(self, hand: str, t: float, f) -> None:
        i = self.index[hand]
        n = int(self.shared.ring_count[i])
        row = self.shared.ring[i][n % _RING]
        row[0] = t
        row[1:4] = f
        self.shared.ring_count[i] = n + 1


class _ProcessServo(ServoLoop):
    """``ServoLoop`` inside the servo process: mailboxes and proxies in shared memory, the stall
    timeout from the shared header, the parent watched every tick, absolute-deadline sleeps."""

    def __init__(self, devices, couplings, shared: _Shared, emulators, parent_pid: int, lib, slice_s=None, **kw):
        self._index = {h: i for i, h in enumerate(devices)}
        super().__init__(devices, couplings, force_log=_RingLog(shared, self._index), clock=time.perf_counter, **kw)
        self.shared, self.emulators, self.parent_pid, self.lib = shared, emulators, parent_pid, lib
        self.peer_gone = False
        self.peer_fds: Sequence[int] = ()  # the sentinel threads' pidfds (set by _child_main)
        self._pollers = threading.local()
        self.timer_slack_ns: Dict[str, Optional[int]] = {}
        self.slice_ns: Dict[str, Optional[int]] = {}
        self.slice_s = slice_s
        self._messages: Dict[str, str] = {}
        for h, i in self._index.items():
            self._hands[h].mailbox = _SharedMailbox(shared.sim[i])

    def tick(self, hand: str, now: Optional[float] = None) -> ProxySample:
        poller = getattr(self._pollers, "p", None)
        if os.getppid() != self.parent_pid or (poller is not None and poller.poll(0)):
            self.peer_gone = True  # a sentinel thread exited, or we were reparented: the simulating process is gone
        if self.peer_gone:
            h = self._hands[hand]
            h.force = h.device.set_force(np.zeros(3))
            h.device.poll()  # the zero goes out in this tick's exchange
            h.alive = False
            self._publish_device(h)
            raise LoopEnd()
        stall = float(self.shared.header[_H_STALL])
        if stall > self.period_s:
            self.stall_timeout_s = stall
        return super().tick(hand, now)

    def _publish_proxy(self, h, x, v, dev, now):
        p = super()._publish_proxy(h, x, v, dev, now)
        i = self._index[h.name]
        emu = self.emulators.get(h.name)
        eff = emu.efforts if emu is not None else getattr(dev, "efforts", (0, 0, 0))
        zero = (math.nan if emu.zero_since is None else emu.zero_since) if emu is not None else math.nan
        # One slice store of the contiguous fields _P_POS.._P_ZERO from a list: per-field numpy
        # stores made the tick 116 us instead of 79 with an emulated Falcon (measured): CPU the
        # simulation gets back on a small machine.
        block = self.shared.prox[i]
        block[0] += 1.0  # odd: writing (the seqlock of _write)
        block[_P_POS:_P_ZERO + 1] = [*x.tolist(), *v.tolist(), *p.force.tolist(), float(p.buttons),
                                     float(_STATES.index(p.state)), now, float(p.seq), *map(float, eff), zero]
        block[0] += 1.0
        msg = dev.message
        if self._messages.get(h.name) != msg:
            self._messages[h.name] = msg
            _write_message(self.shared.msg[i], msg)
            self.shared.prox[i][_P_MSG] += 1.0
        return p

    def _publish_device(self, h) -> None:
        """What the device was sent last, after the loop zeroed it (no proxy tick follows)."""
        i = self._index[h.name]
        emu = self.emulators.get(h.name)
        if emu is not None:
            zero = math.nan if emu.zero_since is None else emu.zero_since
            _write(self.shared.prox[i], ((_P_EFF, np.asarray(emu.efforts, dtype=float)), (_P_ZERO, zero),
                                         (_P_STATE, float(_STATES.index(h.device.state)))))
        _write(self.shared.prox[i], ((_P_F, h.coupling.force_to_scene(h.force)),))

    def _thread_start(self, h) -> float:
        # this thread's own unprivileged measures (timer slack, slice and priority are per thread)
        h.realtime = _set_realtime(self.priority)
        self.timer_slack_ns[h.name] = _set_timer_slack(self.lib)
        # a slice is a SCHED_OTHER setting: asking for one would undo a granted SCHED_FIFO
        self.slice_ns[h.name] = None if h.realtime else _set_short_slice(self.lib, self.slice_s)
        self._pollers.p = _poller(self.peer_fds)
        # Phase shift per hand: their ticks never contend for this process's GIL.
        next_t = self.clock() + self.period_s * self._index[h.name] / max(len(self._hands), 1)
        self._wait_until(next_t)
        return next_t

    def _thread_end(self, h) -> None:
        self._publish_device(h)

    def _wait_until(self, deadline: float) -> None:
        lib, spin = self.lib, self.spin_s
        if lib is None:
            return super()._wait_until(deadline)
        target = deadline - spin
        ts = _Timespec(int(target), int((target - int(target)) * 1e9))
        while self.clock() < target:
            if lib.clock_nanosleep(_CLOCK_MONOTONIC, _TIMER_ABSTIME, ctypes.byref(ts), None) == 0:
                break  # EINTR: sleep again to the same absolute deadline
        while self.clock() < deadline:
            pass  # the short spin: the last ``spin_s`` (0 by default on small machines)


# The servo process is started as ``python -c _BOOT dir fd`` rather than by multiprocessing:
# ``spawn`` re-imports the parent's __main__ (a script, pytest, Blender's own), and ``fork`` would
# copy a multithreaded Blender mid-lock. The package is imported under the name "tearcloth" from
# its folder, so it works whatever name the parent imported it under; everything sent over the
# pipe is plain data (tuples, dicts, floats), never our classes.
_BOOT = (
    "import importlib.util, os, sys\n"
    "d, fd = sys.argv[1], int(sys.argv[2])\n"
    "if 'tearcloth' not in sys.modules:\n"
    "    s = importlib.util.spec_from_file_location('tearcloth', os.path.join(d, '__init__.py'), submodule_search_locations=[d])\n"
    "    m = importlib.util.module_from_spec(s); sys.modules['tearcloth'] = m; s.loader.exec_module(m)\n"
    "from tearcloth.haptics.servo_process import _child_entry\n"
    "_child_entry(fd)\n"
)


def _child_entry(fd: int) -> None:
    conn = Connection(fd)
    try:
        shm_name, hands, specs, peer_tids, parent_pid, options = conn.recv()
    except (EOFError, OSError):
        return
    options["peer_tids"] = peer_tids
    for entry in options.get("sys_path") or ():  # what the simulating process can import, we can
        if entry not in sys.path:
            sys.path.append(entry)
    _child_main(conn, shm_name, hands, [DeviceSpec(*s) for s in specs], parent_pid, options)


_PIDFD_THREAD = 0o200  # O_EXCL: a pidfd that becomes readable when that one thread exits (Linux 6.9)


def _watch_threads(tids: Sequence[int]) -> List[int]:
    """Thread pidfds of ``tids`` (none where the kernel has no thread pidfds)."""
    opener = getattr(os, "pidfd_open", None)
    fds = []
    for tid in tids if opener is not None else ():
        try:
            fds.append(opener(int(tid), _PIDFD_THREAD))
        except OSError:
            pass
    return fds


def _poller(fds: Sequence[int]):
    """A ``select.poll`` over ``fds`` for one thread (a poll object is not shared: concurrent
    ``poll()`` calls on one object raise), None without fds."""
    if not fds:
        return None
    poller = select.poll()
    for fd in fds:
        poller.register(fd, select.POLLIN)
    return poller


def _coupling_fields(c: HandCoupling) -> dict:
    return {f.name: getattr(c, f.name) if f.name != "rotation" else c._r.tolist()
            for f in dataclasses.fields(c) if f.init}


def _child_main(conn, shm_name: str, hands: List[str], specs: List[DeviceSpec], parent_pid: int, options: dict) -> None:
    privileges: Dict[str, Any] = {"process": True, "sched_fifo": None}
    try:
        if options.get("own_session", True):
            os.setsid()
        privileges["own_session"] = bool(options.get("own_session", True))
    except (AttributeError, OSError):
        privileges["own_session"] = False
    try:
        with open("/proc/self/autogroup") as fh:
            privileges["autogroup"] = fh.read().strip()
    except OSError:
        privileges["autogroup"] = None
    cpus = options.get("cpus")
    if cpus is not None and hasattr(os, "sched_setaffinity"):
        try:
            os.sched_setaffinity(0, set(cpus))
        except OSError as exc:
            privileges["affinity_error"] = str(exc)
    privileges["affinity"] = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None
    try:
        privileges["nice"] = os.getpriority(os.PRIO_PROCESS, 0)
    except (AttributeError, OSError):
        privileges["nice"] = None
    lib = _libc()
    privileges["clock_nanosleep"] = lib is not None
    peer_fds = _watch_threads(options.get("peer_tids") or ())
    peer_poll = _poller(peer_fds)  # the main thread's own
    privileges["peer_watch"] = f"thread pidfds ({len(peer_fds)}) + getppid + pipe EOF" if peer_fds else "getppid + pipe EOF"

    def peer_gone() -> bool:
        return os.getppid() != parent_pid or bool(peer_poll is not None and peer_poll.poll(0))

    shared = _Shared(len(hands), shm_name)
    header = shared.header
    sim_clock = lambda: float(header[_H_SIM_TIME])  # noqa: E731 - the emulated hands' simulated time

    def target_of(i: int):
        def target() -> Optional[np.ndarray]:  # the position the simulating process set (keyboard hand)
            v = _read(shared.target[i], tries=10)
            if v is None or v[_T_SET] < 0.5 or not np.all(np.isfinite(v)):
                return None
            return v[_T_POS : _T_POS + 3]
        return target

    def show(hand: str):
        i = hands.index(hand)

        def on_poll(dev: HapticDevice) -> None:  # state and message while it opens and homes
            if peer_gone() or conn.poll(0):  # gone, or told to stop while a Falcon homes
                raise DeviceStateError(f"hand {hand!r}: opening {dev.name} was cancelled")
            _write(shared.prox[i], ((_P_STATE, float(_STATES.index(dev.state))),))
            _write_message(shared.msg[i], dev.message)
            shared.prox[i][_P_MSG] += 1.0
        return on_poll
    devices: Dict[str, HapticDevice] = {}
    emulators: Dict[str, Any] = {}
    loop: Optional[_ProcessServo] = None

    def send(*msg) -> bool:
        try:
            conn.send(msg)
            return True
        except (OSError, EOFError, BrokenPipeError):
            return False

    def close_all() -> None:
        for dev in devices.values():
            try:
                dev.close()
            except HapticError:
                pass

    try:
        try:
            for i, (hand, spec) in enumerate(zip(hands, specs)):
                devices[hand], emu = spec.build(sim_clock, target_of(i))
                devices[hand].hand = hand
                if emu is not None:
                    emulators[hand] = emu
        except Exception as exc:
            send("error", type(exc).__name__, f"hand {hand!r}: the servo process could not build the device: {exc}")
            return
        send("built", {h: _info(d) for h, d in devices.items()})
        while True:
            if peer_gone():
                break
            try:
                if not conn.poll(0.05):  # the servo threads watch the peer every tick; this is for before they start
                    if loop is not None and loop.peer_gone:
                        break
                    continue
                msg = conn.recv()
            except (EOFError, OSError):
                break  # the simulating process is gone
            cmd = msg[0]
            if cmd == "open":
                try:
                    for hand, dev in devices.items():
                        open_ready(dev, hand, msg[1], show(hand))
                        dev.poll()  # a fresh reading to bind on
                        if dev.state is not DeviceState.READY:
                            raise DeviceNotFoundError(f"hand {hand!r}: {dev.name} stopped answering while binding: {dev.message}")
                        transport = getattr(dev, "_transport", None)
                        if hand not in emulators and hasattr(transport, "zero_since") and hasattr(transport, "efforts"):
                            emulators[hand] = transport  # a byte-level emulator behind a real device: report what it decoded
                except HapticError as exc:
                    close_all()
                    send("error", type(exc).__name__, str(exc))
                    return
                send("opened", {h: _info(d) for h, d in devices.items()})
            elif cmd == "start":
                couplings = {h: HandCoupling(**{k: tuple(v) if k == "offset" else v for k, v in c.items()}) for h, c in msg[1].items()}
                kw = msg[2]
                loop = _ProcessServo(devices, couplings, shared, emulators, parent_pid, lib, **kw)
                loop.peer_fds = peer_fds
                gc.collect()
                gc.freeze()
                gc.disable()
                privileges["gc"] = "frozen and disabled in the servo process"
                loop.start()
                send("started")
            elif cmd == "stats":
                send("stats", _stats(loop, privileges))
            elif cmd == "emu":
                _, hand, what, value = msg
                emu = emulators.get(hand)
                dev = devices.get(hand)
                if emu is None and dev is not None:  # an injected transport or HID object (tests)
                    emu = getattr(dev, "_transport", None) or getattr(dev, "_hid", None)
                if emu is None:
                    send("emu", None)
                elif what == "set":
                    setattr(emu, value[0], value[1])
                    send("emu", None)
                elif what == "get":
                    send("emu", getattr(emu, value))
                else:
                    # The time just before the command is applied (CLOCK_MONOTONIC, the servo's
                    # clock): a servo tick that sees its effect (an unplug) started its I/O after it,
                    # whereas a time taken after the call could follow that tick's stamp.
                    t = time.perf_counter()
                    getattr(emu, what)(*value)
                    send("emu", t)
            elif cmd == "stop":
                if loop is not None:
                    try:
                        loop.stop()
                    except HapticError:
                        pass
                close_all()
                send("stopped", _stats(loop, privileges))
                return
    finally:
        if loop is not None:
            loop.peer_gone = True
            try:
                loop.stop()
            except HapticError:
                pass
        close_all()
        for hand, emu in emulators.items():  # what the devices were left with
            if loop is not None:
                loop._publish_device(loop._hands[hand])
        shared.close()
        for fd in peer_fds:
            os.close(fd)


def _info(dev: HapticDevice) -> dict:
    return {"name": dev.name, "state": dev.state.value, "message": dev.message, "position": dev.position.tolist(),
            "max_force": dev.max_force, "max_stiffness": dev.max_stiffness, "max_damping": dev.max_damping,
            "has_force": dev.has_force, "workspace": (tuple(dev.workspace.centre), dev.workspace.radius)}


def _stats(loop: Optional[_ProcessServo], privileges: dict) -> dict:
    if loop is None:
        return {"privileges": dict(privileges)}
    out = loop.stats()
    priv = dict(privileges)
    priv["timer_slack_ns"] = dict(loop.timer_slack_ns)
    priv["slice_ns"] = dict(loop.slice_ns)
    priv["sched_fifo"] = {h: v["realtime"] for h, v in out["per_hand"].items()}
    priv["spin_s"] = loop.spin_s
    out["privileges"] = priv
    out["max_ms"] = max(v["max_ms"] for v in out["per_hand"].values())
    out["peer_gone"] = loop.peer_gone
    return out


# ---- the simulation side ------------------------------------------------------------------------
def _driven(spec: DeviceSpec) -> bool:
    return spec.target_arg is not None


_ERRORS = {name: getattr(_device_module, name) for name in _device_module.__all__ if isinstance(getattr(_device_module, name), type)}
_ERRORS["ServoProcessError"] = ServoProcessError


class RemoteDevice(HapticDevice):
    """A device that lives in the servo process, as the simulating process sees it: its fixed
    figures from the ``DeviceSpec``'s local template (never opened here), its state, position,
    buttons and message from the shared memory. Only the servo process drives it."""

    def __init__(self, template: HapticDevice, servo: "ServoProcess", hand: str):
        super().__init__(template.name, max_force=template.max_force, workspace=template.workspace, has_force=template.has_force,
                         max_stiffness=template.max_stiffness, max_damping=template.max_damping, hand=hand)
        self._servo, self._hand_name = servo, hand
        self._state, self._message = DeviceState.ABSENT, "not opened yet (the servo process opens it)"

    def _sync(self) -> None:
        s = self._servo
        if self._state is DeviceState.CLOSED:
            return
        if s.opening and s._shared is not None:  # opening there (a Falcon homing): its state and message
            st = s._read_proxy(self._hand_name)
            if st is not None:
                self._state = _STATES[int(st[_P_STATE])]
                self._message = s._message(self._hand_name, self._message)
            return
        if not s.ticking:
            return
        st = s._read_proxy(self._hand_name)
        if st is None or st[_P_NUM] == 0.0:
            return  # no tick yet: what open() reported still holds
        c = s.coupling(self._hand_name)
        self._state = _STATES[int(st[_P_STATE])]
        # the shared block holds the proxy (scene frame): back to the device's own frame
        self._position = c._r.T @ (st[_P_POS : _P_POS + 3] - c._o) / c.scale
        self._velocity = c._r.T @ st[_P_VEL : _P_VEL + 3] / c.scale
        self._buttons = int(st[_P_BUT])
        self._force = c.force_to_device(st[_P_F : _P_F + 3])
        self._message = s._message(self._hand_name, self._message)

    @property
    def state(self) -> DeviceState:
        self._sync()
        return self._state

    @property
    def message(self) -> str:
        self._sync()
        return self._message

    @property
    def position(self) -> np.ndarray:
        self._sync()
        return self._position.copy()

    @property
    def velocity(self) -> np.ndarray:
        self._sync()
        return self._velocity.copy()

    @property
    def buttons(self) -> int:
        self._sync()
        return self._buttons

    @property
    def force(self) -> np.ndarray:
        self._sync()
        return self._force.copy()

    def _opened(self, info: dict) -> None:
        self.name = info["name"]
        self._state = DeviceState(info["state"])
        self._message = info["message"]
        self._position = np.asarray(info["position"], dtype=float)

    def open(self) -> DeviceState:
        raise DeviceStateError(f"{self.name} lives in the servo process: ServoProcess.open() opens it")

    def set_position(self, position) -> None:
        """Move a hand driven from this process (keyboard: ``DeviceSpec.target_arg``), device
        frame, kept inside its workspace ball."""
        self._servo.set_target(self._hand_name, self.workspace.clamp(np.asarray(position, dtype=float).reshape(3)))

    def move_by(self, delta) -> None:
        self.set_position(self._servo.target(self._hand_name) + np.asarray(delta, dtype=float).reshape(3))

    def poll(self) -> bool:
        return False  # the servo process polls it

    def close(self) -> None:
        self._servo.stop()
        self._set_state(DeviceState.CLOSED, "closed")

    def _open(self) -> None:  # pragma: no cover - open() is refused above
        raise DeviceStateError("not here")

    def _poll(self) -> bool:  # pragma: no cover
        return False

    def _close(self) -> None:  # pragma: no cover
        pass


class RemoteEmulator:
    """An emulated Falcon that lives in the servo process: the test and demo handles
    (``unplug``, ``replug``, ``stall``, ``buttons``) and what it was last sent (``efforts``,
    ``zero_since``: wall-clock time of the first zero command after a force, None while a force is
    on). Commands given before the servo process runs are applied when it starts."""

    def __init__(self, servo: "ServoProcess", hand: str):
        self._servo, self._hand = servo, hand

    def unplug(self) -> Optional[float]:
        """Pull the cable; returns the servo clock just before it was pulled (``time.perf_counter``;
        None if the servo process has not started yet: then it is pulled as it starts)."""
        return self._servo._emu(self._hand, "unplug", ())

    def replug(self) -> None:
        self._servo._emu(self._hand, "replug", ())

    def stall(self, stalled: bool = True) -> None:
        self._servo._emu(self._hand, "stall", (stalled,))

    def call(self, method: str, *args):
        """Call ``method`` of the object behind this hand in the servo process: the emulator, or
        for a device over an injected transport or HID object (tests) that object, e.g.
        ``call("feed", report)``, ``call("unplug")``; returns the servo clock just before it took effect
        (``time.perf_counter``)."""
        return self._servo._emu(self._hand, method, tuple(args))

    def get(self, name: str):
        """An attribute of that object (plain data)."""
        return self._servo._emu(self._hand, "get", name)

    @property
    def buttons(self) -> int:
        return int(self._servo._emu(self._hand, "get", "buttons") or 0)

    @buttons.setter
    def buttons(self, value) -> None:
        self._servo._emu(self._hand, "set", ("buttons", value))

    @property
    def efforts(self) -> Tuple[int, int, int]:
        st = self._servo._read_proxy(self._hand)
        return (0, 0, 0) if st is None else tuple(int(v) for v in st[_P_EFF : _P_EFF + 3])

    @property
    def zero_since(self) -> Optional[float]:
        st = self._servo._read_proxy(self._hand)
        return None if st is None or math.isnan(st[_P_ZERO]) else float(st[_P_ZERO])


class ServoProcess:
    """The servo for ``specs`` ({hand: ``DeviceSpec``}) in a process of its own (module
    docstring). Life cycle: ``open(homing_timeout_s)`` spawns it, builds and opens the devices
    there (errors come back as the same ``HapticError`` class); ``start(couplings)`` starts the
    1 kHz threads; ``publish``/``proxy``/``stats`` while it runs; ``stop()`` zeroes, closes and
    joins. ``period_s``, ``stall_timeout_s`` (settable), ``clock``, ``hands``, ``mailbox(hand)``
    (the last sample published from here), ``device(hand)`` and ``coupling(hand)`` are those of
    ``ServoLoop``. ``force_log`` (a ``ForceLog``) receives every tick's rendered force, moved from
    the shared ring by a ``tearcloth-live-log`` thread every ``drain_every_s`` (whatever the
    caller is doing, the log is at most that old) and once more after the servo has stopped."""

    def __init__(self, specs: Mapping[str, DeviceSpec], *, period_s: float = 0.001, stall_timeout_s: float = 0.010,
                 spin_s: float = 0.0, slice_s: Optional[float] = 0.0001, priority: Optional[int] = None,
                 cpus: Optional[Sequence[int]] = None, own_session: bool = True,
                 switch_interval_s: Optional[float] = 0.0005, start_timeout_s: float = 60.0, force_log=None,
                 drain_every_s: float = 0.02):
        if not specs:
            raise ConfigError("the servo process needs at least one device")
        if not 0.0 < period_s <= 0.1:
            raise ConfigError(f"period must be in (0, 0.1] s, got {period_s!r}")
        for hand, spec in specs.items():
            if not isinstance(spec, DeviceSpec):
                raise ConfigError(f"hand {hand!r}: {spec!r} is not a DeviceSpec")
        self._specs = dict(specs)
        self._hands = list(specs)
        self.period_s = float(period_s)
        self.clock = time.perf_counter
        self.start_timeout_s = float(start_timeout_s)
        self._servo_kw = {"period_s": self.period_s, "stall_timeout_s": float(stall_timeout_s), "spin_s": float(spin_s), "slice_s": slice_s,
                          "priority": priority, "switch_interval_s": switch_interval_s}
        self._cpus = None if cpus is None else list(cpus)
        self._own_session = bool(own_session)
        self._mailboxes = {h: SimulationMailbox(self.clock) for h in self._hands}
        self._devices = {h: RemoteDevice(s.build(None)[0], self, h) for h, s in self._specs.items()}
        self._couplings: Dict[str, HandCoupling] = {}
        self._msg_seen: Dict[str, float] = {}
        self._pending: List[tuple] = []
        self._shared: Optional[_Shared] = None
        # held by every reader and writer of the shared block and by close(): stop() runs on the
        # session's thread when a device goes (or the servo dies) while Blender's thread still reads
        # the devices' state; without it a read found the block gone half-way (AttributeError on
        # 'prox', seen once in ~130 runs of the unplug test). Short holds only: no I/O under it.
        self._shared_lock = threading.Lock()
        self._conn: Optional[Connection] = None
        self._proc: Optional[subprocess.Popen] = None
        self._lock = threading.RLock()
        self.ticking = False
        self.final_stats: Optional[dict] = None
        self._stall = float(stall_timeout_s)
        self._ring_read = {h: 0 for h in self._hands}
        self.force_log_lost = 0
        self.force_log = force_log
        self.drain_every_s = float(drain_every_s)
        self._drainer: Optional[threading.Thread] = None
        self._drain_stop = threading.Event()
        self._sentinel_stop = threading.Event()
        self._sentinels: List[threading.Thread] = []
        self._last_prox: Dict[str, np.ndarray] = {}
        self._last_msg: Dict[str, str] = {}
        self._good: Dict[str, np.ndarray] = {}
        self._opened = False
        self._open_deadline: Optional[float] = None
        self._targets: Dict[str, np.ndarray] = {h: np.asarray(d.workspace.centre, dtype=float).copy()
                                                for h, d in self._devices.items() if _driven(self._specs[h])}

    # ---- properties shared with ServoLoop --------------------------------------------------------
    @property
    def hands(self) -> List[str]:
        return list(self._hands)

    @property
    def running(self) -> bool:
        return self.ticking

    @property
    def pid(self) -> Optional[int]:
        return None if self._proc is None else self._proc.pid

    @property
    def shm_name(self) -> Optional[str]:
        return None if self._shared is None else self._shared.name

    def device(self, hand: str) -> RemoteDevice:
        return self._devices[self._check(hand)]

    def coupling(self, hand: str) -> HandCoupling:
        return self._couplings[self._check(hand)]

    def mailbox(self, hand: str) -> SimulationMailbox:
        return self._mailboxes[self._check(hand)]

    def emulator(self, hand: str) -> RemoteEmulator:
        return RemoteEmulator(self, self._check(hand))

    def _check(self, hand: str) -> str:
        if hand not in self._specs:
            raise ConfigError(f"unknown hand {hand!r}; hands are {sorted(self._specs)}")
        return hand

    @property
    def stall_timeout_s(self) -> float:
        return self._stall

    @stall_timeout_s.setter
    def stall_timeout_s(self, value: float) -> None:
        self._stall = float(value)
        with self._shared_lock:
            if self._shared is not None:
                self._shared.header[_H_STALL] = self._stall  # one float the servo reads per tick

    def set_sim_time(self, t: float) -> None:
        """The simulated time (s), for emulated hands that follow it."""
        with self._shared_lock:
            if self._shared is not None:
                self._shared.header[_H_SIM_TIME] = float(t)

    # ---- life cycle ------------------------------------------------------------------------------
    def _call(self, *msg, expect: str, timeout_s: Optional[float] = None):
        with self._lock:
            if self._conn is None:
                raise HapticError("the servo process is not running")
            if self._open_deadline is not None:  # its answer to "open" is still due: no other call in between
                raise HapticError("the servo process is opening its devices")
            self._conn.send(msg)
            if not self._conn.poll(self.start_timeout_s if timeout_s is None else timeout_s):
                raise HapticError(f"the servo process did not answer {msg[0]!r} within {timeout_s or self.start_timeout_s:.0f} s")
            reply = self._conn.recv()
        if reply[0] == "error":
            raise _ERRORS.get(reply[1], HapticError)(reply[2])
        if reply[0] != expect:
            raise HapticError(f"the servo process answered {reply[0]!r} to {msg[0]!r}")
        return reply[1] if len(reply) > 1 else None

    @property
    def opened(self) -> bool:
        """The devices are open in the servo process (``open`` or ``begin_open`` + ``poll_open``)."""
        return self._opened

    @property
    def opening(self) -> bool:
        return self._open_deadline is not None

    def open(self, homing_timeout_s: float = 0.0) -> Dict[str, dict]:
        """Spawn the servo process, build and open the devices there; returns {hand: info}."""
        self.begin_open(homing_timeout_s)
        while True:
            infos = self.poll_open(0.05)
            if infos is not None:
                return infos

    def begin_open(self, homing_timeout_s: float = 0.0) -> None:
        """Spawn the servo process and ask it to open (and home) the devices; ``poll_open`` says
        when they are. Meanwhile each device's state and message read as the servo process sees
        them (a Falcon homing). ``ServoProcessError`` if the process itself cannot start."""
        if self._proc is not None:
            raise DeviceStateError("the servo process was already opened")
        self._shared = _Shared(len(self._hands))
        self._shared.header[_H_STALL] = self._stall
        tids: List[int] = []
        ready = threading.Semaphore(0)

        def sentinel():
            tids.append(threading.get_native_id())
            ready.release()
            self._sentinel_stop.wait()  # blocked on a lock without the GIL: its exit is the signal

        self._sentinel_stop.clear()
        self._sentinels = [threading.Thread(target=sentinel, name=f"tearcloth-live-peer{i}", daemon=True) for i in range(2)]
        for t in self._sentinels:
            t.start()
            ready.acquire()
        try:
            ours, theirs = socket.socketpair()
            try:
                self._proc = subprocess.Popen([sys.executable, "-c", _BOOT, _PACKAGE_DIR, str(theirs.fileno())],
                                              pass_fds=(theirs.fileno(),), stdin=subprocess.DEVNULL)
            finally:
                theirs.close()
        except OSError as exc:
            self._sentinel_stop.set()
            for t in self._sentinels:
                t.join()
            self._sentinels = []
            self.close()
            raise ServoProcessError(f"the servo process could not be started ({sys.executable}): {exc}") from exc
        try:
            self._conn = Connection(ours.detach())
            specs = [(s.factory, dict(s.kwargs), s.sim_clock_arg, s.target_arg) for s in (self._specs[h] for h in self._hands)]
            self._conn.send((self._shared.name, self._hands, specs, tids, os.getpid(),
                             {"cpus": self._cpus, "own_session": self._own_session, "sys_path": [p for p in sys.path if isinstance(p, str) and p]}))
            try:
                if not self._conn.poll(self.start_timeout_s):
                    raise ServoProcessError(f"the servo process did not start within {self.start_timeout_s:.0f} s")
                reply = self._conn.recv()
            except (EOFError, OSError) as exc:
                raise ServoProcessError(f"the servo process exited as it started (exit code {self._proc.poll()}): {exc}") from exc
            if reply[0] == "error":
                raise _ERRORS.get(reply[1], HapticError)(reply[2])
            for cmd in self._pending:
                self._call(*cmd, expect="emu")
            self._pending.clear()
            for h in self._hands:  # where a driven hand (keyboard) starts
                self._write_target(h)
            with self._lock:
                self._conn.send(("open", float(homing_timeout_s)))
            self._open_deadline = time.perf_counter() + self.start_timeout_s + float(homing_timeout_s)
        except BaseException:
            self._terminate()
            raise

    def poll_open(self, timeout_s: float = 0.0) -> Optional[Dict[str, dict]]:
        """{hand: info} once the devices are open, None while they open (a Falcon homes); the
        device's error (its class, the hand named) if one cannot be opened; the process is then
        stopped."""
        if self._opened:
            return {}
        if self._open_deadline is None:
            raise DeviceStateError("begin_open() first")
        try:
            with self._lock:
                if self._conn is None:
                    raise ServoProcessError("the servo process is not running")
                if not self._conn.poll(timeout_s):
                    if time.perf_counter() > self._open_deadline:
                        raise ServoProcessError("the servo process did not open the devices in time")
                    return None
                reply = self._conn.recv()
            if reply[0] == "error":
                raise _ERRORS.get(reply[1], HapticError)(reply[2])
            if reply[0] != "opened":
                raise ServoProcessError(f"the servo process answered {reply[0]!r} to 'open'")
        except (EOFError, OSError) as exc:
            self._open_deadline = None
            self._terminate()
            raise ServoProcessError(f"the servo process exited while opening the devices: {exc}") from exc
        except BaseException:
            self._open_deadline = None
            self._terminate()
            raise
        self._open_deadline = None
        self._opened = True
        for hand, info in reply[1].items():
            self._devices[hand]._opened(info)
        return reply[1]

    def set_target(self, hand: str, position) -> None:
        """The position (device frame, m) a hand driven from this process (the keyboard hand) is
        at: read by its device in the servo process at its next tick. One thread writes it."""
        p = np.asarray(position, dtype=float).reshape(3)
        if not np.all(np.isfinite(p)):
            raise ConfigError(f"hand {hand!r}: target position must be finite, got {p.tolist()!r}")
        self._targets[self._check(hand)] = p
        self._write_target(hand)

    def target(self, hand: str) -> np.ndarray:
        return self._targets[self._check(hand)].copy()

    def _write_target(self, hand: str) -> None:
        with self._shared_lock:
            if self._shared is not None and hand in self._targets:
                _write(self._shared.target[self._hands.index(hand)], ((_T_POS, self._targets[hand]), (_T_SET, 1.0)))

    def start(self, couplings: Mapping[str, HandCoupling]) -> None:
        """Start the servo threads with these couplings (the devices must have been opened)."""
        self._couplings = dict(couplings)
        self._call("start", {h: _coupling_fields(c) for h, c in self._couplings.items()}, self._servo_kw, expect="started")
        self.ticking = True
        if self.force_log is not None:
            self._drain_stop.clear()
            self._drainer = threading.Thread(target=self._drain_loop, name="tearcloth-live-log", daemon=True)
            self._drainer.start()

    def _drain_loop(self) -> None:
        while not self._drain_stop.wait(self.drain_every_s):
            self.drain(self.force_log)

    def stop(self, timeout_s: float = 2.0) -> None:
        """Zero force on every device, close them, end the process. Idempotent."""
        if self._proc is None:
            return
        # While it opens (a Falcon homing) it answers nothing else: closing the pipe in
        # _terminate is the signal, which its homing loop checks every poll.
        opening, self._open_deadline = self._open_deadline is not None, None
        if not opening:
            try:
                if self._proc.poll() is None and self._conn is not None:
                    self.final_stats = self._call("stop", expect="stopped", timeout_s=timeout_s)
            except (HapticError, OSError, EOFError):
                pass
            try:
                self._proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                pass
        self._terminate()
        if self._drainer is not None:
            self._drain_stop.set()
            self._drainer.join()
            self._drainer = None
        self._sentinel_stop.set()  # after the servo has gone: it must not read their exit as our death
        for t in self._sentinels:
            t.join()
        self._sentinels = []
        if self.force_log is not None:
            self.drain(self.force_log)  # the last ticks, up to the zero force
        self.close()

    def _terminate(self) -> None:
        if self._proc is not None and self._proc.poll() is None:
            # Only when stop got no answer. Closing the pipe below is itself the servo's signal
            # to zero and exit (EOF); SIGTERM is the backstop for a servo that hangs in I/O.
            if self._conn is not None:
                self._conn.close()
                self._conn = None
            try:
                self._proc.wait(0.5)
            except subprocess.TimeoutExpired:
                self._proc.terminate()
                self._proc.wait(1.0)
        if self._conn is not None:
            self._conn.close()
        self._conn = None
        self.ticking = False
        for h, d in self._devices.items():
            last = self._read_proxy(h)
            if last is not None and h in self._couplings:  # the force the servo left it with
                d._force = self._couplings[h].force_to_device(last[_P_F : _P_F + 3])
            if d._state is not DeviceState.LOST:
                d._set_state(DeviceState.CLOSED, "closed")
        # the shared block stays mapped until drained and closed by close()

    def close(self) -> None:
        """Release the shared memory (``stop`` does; the last device blocks are kept: what each
        device was left with stays readable)."""
        with self._shared_lock:
            if self._shared is not None:
                self._last_prox = {h: self._shared.prox[i].copy() for i, h in enumerate(self._hands)}
                self._last_msg = {h: _read_message(self._shared.msg[i]) for i, h in enumerate(self._hands)}
                self._shared.close()
                self._shared = None

    # ---- exchange --------------------------------------------------------------------------------
    def publish(self, hand: str, f_tear, handle_position, **linearisation) -> None:
        mb = self.mailbox(hand)
        mb.publish(f_tear, handle_position, **linearisation)  # validates in this thread
        s = mb.latest
        lin = s.f0 is not None
        # one slice store of the contiguous fields _S_F.._S_NUM (per-field stores cost this
        # thread, which shares the GIL with Blender's Python, 30 us a hand a step)
        values = [*s.f_tear.tolist(), *s.handle_position.tolist(), 1.0 if lin else 0.0,
                  *(s.f0.tolist() if lin else _ZEROS3), *(s.stiffness.ravel().tolist() if lin else _ZEROS9),
                  *(s.x0.tolist() if lin else _ZEROS3), s.stamp, float(s.seq)]
        with self._shared_lock:
            if self._shared is None:
                return
            block = self._shared.sim[self._hands.index(hand)]
            block[0] += 1.0  # odd: writing (the seqlock of _write)
            block[_S_F:_S_NUM + 1] = values
            block[0] += 1.0

    def _read_proxy(self, hand: str) -> Optional[np.ndarray]:
        with self._shared_lock:
            if self._shared is None:
                return self._last_prox.get(hand)
            v = _read(self._shared.prox[self._hands.index(hand)])
        if v is None:  # the servo is mid-write (preempted): the last consistent copy
            return self._good.get(hand)
        self._good[hand] = v
        return v

    def _message(self, hand: str, old: str) -> str:
        i = self._hands.index(hand)
        with self._shared_lock:
            sh = self._shared
            if sh is None:  # closed since the caller looked: what close() kept of the block
                if hand not in self._last_prox:
                    return old
                seq, text = self._last_prox[hand][_P_MSG], lambda: self._last_msg.get(hand, old)
            else:
                seq, text = sh.prox[i][_P_MSG], lambda: _read_message(sh.msg[i])
            if self._msg_seen.get(hand) == seq:
                return old
            self._msg_seen[hand] = seq
            return text()

    def proxy(self, hand: str) -> Optional[ProxySample]:
        v = self._read_proxy(self._check(hand))
        if v is None or v[_P_NUM] == 0.0:
            return None
        return ProxySample(v[_P_POS : _P_POS + 3], v[_P_VEL : _P_VEL + 3], int(v[_P_BUT]), _STATES[int(v[_P_STATE])],
                           v[_P_F : _P_F + 3], float(v[_P_STAMP]), int(v[_P_NUM]))

    def drain(self, force_log) -> int:
        """Called by one thread at a time: the drain thread while the servo runs, then ``stop``."""
        return self._drain(force_log)

    def _drain(self, force_log) -> int:
        """Move the rendered forces logged since the last call into ``force_log``; returns how
        many. Entries overwritten before being read (a drain more than 65 s late) are counted in
        ``force_log_lost``."""
        rows = []
        with self._shared_lock:  # copied under the lock, recorded after it (close() may be waiting)
            sh = self._shared
            if sh is None:
                return 0
            for i, hand in enumerate(self._hands):
                end = int(sh.ring_count[i])
                start = self._ring_read[hand]
                if end - start > _RING:
                    self.force_log_lost += end - start - _RING
                    start = end - _RING
                if end > start:
                    idx = np.arange(start, end) % _RING
                    rows.append((hand, sh.ring[i][idx]))  # fancy indexing: a copy
                self._ring_read[hand] = end
        n = 0
        for hand, block in rows:
            for row in block:
                force_log.record(hand, float(row[0]), row[1:4].copy())
            n += len(block)
        return n

    def stats(self, hand: Optional[str] = None) -> dict:
        """``ServoLoop.stats()`` of the servo process (plus ``max_ms`` and ``privileges``: what the
        unprivileged process got). After ``stop`` the last figures it sent."""
        try:
            out = self._call("stats", expect="stats", timeout_s=2.0) if self._conn is not None else self.final_stats
        except (HapticError, OSError, EOFError):
            out = self.final_stats
        out = dict(out or {"privileges": {}})
        if "per_hand" not in out:
            out.update(rate_hz=0.0, p50_ms=float("nan"), p99_ms=float("nan"), max_ms=float("nan"),
                       per_hand={h: {"rate_hz": 0.0, "p50_ms": float("nan"), "p99_ms": float("nan"), "max_ms": float("nan"),
                                     "periods": 0, "ticks": 0, "overruns": 0, "watchdog_trips": 0, "state": "closed",
                                     "error": None, "realtime": None} for h in self._hands})
        if hand is not None:
            return out["per_hand"][self._check(hand)]
        return out

    def _emu(self, hand: str, what: str, value):
        if self._conn is None and self._proc is None:
            if what == "get":
                return None
            self._pending.append(("emu", hand, what, value))
            return None
        if self._conn is None:
            return None
        return self._call("emu", hand, what, value, expect="emu", timeout_s=5.0)
