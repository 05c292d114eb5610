"""Byte-level emulator of a Novint Falcon behind its FTDI bridge, for tests and for running the
add-on without hardware.

This file owns ``FalconEmulator``, an object that implements the ``Transport`` protocol and
behaves, byte for byte, like the device the real transports talk to:

- power-up without firmware; a DTR low->high edge resets the DSP into its boot loader;
- boot loader: at divisor 0x4138 (9600 baud) answers ``0A 43 0D`` with ``00 0A 44 2C 0D`` (or
  without the leading 00, as some stacks deliver it); at divisor 0x15 echoes ``41`` and then every
  firmware byte; switching to divisor 0x2 starts the firmware if the image had an accepted size;
- firmware: answers each 16-byte command frame with one report frame (``falcon_packets``),
  one emulated millisecond per command (the real loop is host-paced, so emulated time is
  "packets exchanged × 1 ms": tests run as fast as the CPU allows and stay deterministic);
- a grip simulated as a delta robot: Cartesian state integrated with the mass matrix
  m·I + Jᵀ·diag(I_motor)·J and damping Jᵀ·diag(b_motor)·J (three motors with inertia and viscous
  damping seen through the Jacobian), motor torques τ = −effort/10000 mapped to the grip as Jᵀτ,
  a scripted hand force (a function of time, position and velocity the test supplies), and soft
  end stops; encoder counts come from the kinematics (rounded), offset until a motor is homed;
- homing: with homing mode on, a motor is homed once its arm has been pulled out past
  ``homing_out_deg`` and then pushed in past ``homing_in_deg`` (the "pull out, push in" gesture),
  or immediately when ``homed=True``;
- faults: dropped handshakes, a corrupted echo, garbage and truncated frames, unplug at an
  emulated time (every call then raises ``TransportError`` like a USB errno 19), stall (commands
  accepted, no answers).

Nothing here touches real hardware or time; it is deterministic for a given ``seed``.
"""
from __future__ import annotations

import collections
import math
import random
import time
from typing import Callable, Iterable, Optional, Sequence, Tuple

import numpy as np

from .device import KinematicsError, TransportError
from .falcon_kinematics import (
    EFFORT_PER_NEWTON_METRE,
    WORKSPACE_CENTRE,
    _ik_jac,
    _solve3,
    angle_to_encoder,
)
from .falcon_packets import FrameParser, decode_command, encode_report
from .falcon_transport import BAUD_DIVISOR_9600, BAUD_DIVISOR_FIRMWARE, BAUD_DIVISOR_NORMAL

__all__ = [
    "FalconEmulator",
    "HandScript",
    "free_hand",
    "spring_hand",
    "force_hand",
    "homing_gesture",
    "KNOWN_FIRMWARE_SIZES",
]

KNOWN_FIRMWARE_SIZES = (7914, 8492)
HANDSHAKE_REQUEST = b"\x0a\x43\x0d"
HANDSHAKE_REPLY = b"\x0a\x44\x2c\x0d"
FIRMWARE_BLOCK = 62

# hand(t, position, velocity) -> force on the grip (N), all in the device frame.
HandScript = Callable[[float, np.ndarray, np.ndarray], Sequence[float]]


def free_hand() -> HandScript:
    """No hand on the grip."""
    return lambda t, x, v: (0.0, 0.0, 0.0)


def spring_hand(target, stiffness: float = 800.0, damping: float = 8.0) -> HandScript:
    """A hand holding the grip: a spring-damper toward ``target`` (a point, or a function of t).

    800 N/m and 8 N·s/m are in the range measured for a relaxed human grasp."""
    fn = target if callable(target) else (lambda t, p=np.asarray(target, dtype=float): p)

    def hand(t, x, v):
        return stiffness * (np.asarray(fn(t), dtype=float) - x) - damping * v

    return hand


def force_hand(fn: Callable[[float], Sequence[float]]) -> HandScript:
    """A hand that pushes with a scripted force ``fn(t)`` (N) whatever the grip does."""
    return lambda t, x, v: fn(t)


def homing_gesture(
    start: Sequence[float] = WORKSPACE_CENTRE,
    out_z: float = 0.172,
    in_z: float = 0.095,
    t0: float = 0.0,
    leg: float = 0.25,
) -> Callable[[float], np.ndarray]:
    """Trajectory of the homing gesture (use with ``spring_hand``): from ``start``, pull the grip
    out to ``out_z``, push it in to ``in_z``, return to ``start``; each leg lasts ``leg`` s and is
    a smooth cosine blend. Returns a function t -> position (m)."""
    s = np.asarray(start, dtype=float)
    waypoints = [s, np.array([s[0], s[1], out_z]), np.array([s[0], s[1], in_z]), s]

    def traj(t):
        u = (t - t0) / leg
        if u <= 0.0:
            return waypoints[0]
        i = int(u)
        if i >= len(waypoints) - 1:
            return waypoints[-1]
        a = 0.5 - 0.5 * math.cos(math.pi * (u - i))
        return waypoints[i] + a * (waypoints[i + 1] - waypoints[i])

    return traj


class FalconEmulator:
    """A Falcon on the other end of a ``Transport`` (see the module docstring).

    Observables for tests: ``time`` (s), ``mode``, ``true_position``/``true_velocity`` (m, m/s),
    ``efforts`` (last command), ``control`` (LED/homing bits), ``homed`` (3-bit mask),
    ``firmware`` (bytes received), ``commands`` (deque of (t, efforts, control)),
    ``control_log`` (list of (request, value)).
    """

    def __init__(
        self,
        serial: str = "EMU00001",
        *,
        firmware_loaded: bool = False,
        homed: bool = False,
        hand: Optional[HandScript] = None,
        position: Sequence[float] = WORKSPACE_CENTRE,
        buttons=0,
        accepted_firmware_sizes: Iterable[int] = KNOWN_FIRMWARE_SIZES,
        handshake_leading_zero: bool = True,
        drop_handshakes: int = 0,
        corrupt_echo_block: Optional[int] = None,
        garbage_every: int = 0,
        truncate_every: int = 0,
        unplug_at: Optional[float] = None,
        stall_at: Optional[float] = None,
        seed: int = 0,
        unhomed_offset: Sequence[int] = (173, -211, 95),
        homing_out_deg: float = 58.0,
        homing_in_deg: float = 12.0,
        grip_mass: float = 0.05,
        motor_inertia: float = 2e-4,
        motor_damping: float = 2e-3,
        end_stop_stiffness: float = 20000.0,
        dt: float = 0.001,
        substeps: int = 4,
        history: int = 200000,
    ):
        self.serial = serial
        self.hand = hand or free_hand()
        self.buttons = buttons
        self.accepted_firmware_sizes = tuple(accepted_firmware_sizes)
        self.handshake_leading_zero = handshake_leading_zero
        self.drop_handshakes = drop_handshakes
        self.corrupt_echo_block = corrupt_echo_block
        self.garbage_every = garbage_every
        self.truncate_every = truncate_every
        self.unplug_at = unplug_at
        self.stall_at = stall_at
        self.unhomed_offset = tuple(int(o) for o in unhomed_offset)
        self.homing_out = math.radians(homing_out_deg)
        self.homing_in = math.radians(homing_in_deg)
        self.grip_mass = grip_mass
        self.motor_inertia = motor_inertia
        self.motor_damping = motor_damping
        self.end_stop_stiffness = end_stop_stiffness
        self.dt = dt
        self.substeps = substeps
        self._rng = random.Random(seed)

        self.time = 0.0
        self.mode = "running" if firmware_loaded else "idle"
        self.unplugged = False
        self.stalled = False
        self.closed = False
        self.dtr = False
        self.rts = False
        self.baud_divisor = BAUD_DIVISOR_9600
        self.latency_ms = 16
        self.control_log = []
        self.firmware = bytearray()
        self.handshakes_seen = 0
        self._hs_buf = bytearray()
        self._out = bytearray()
        self._parser = FrameParser("command")
        self.commands = collections.deque(maxlen=history)
        self.reports_sent = 0

        x = tuple(float(v) for v in position)
        _ik_jac(*x)  # raises KinematicsError early for an unreachable start
        self._x = x
        self._v = (0.0, 0.0, 0.0)
        self.efforts = (0, 0, 0)
        # Wall-clock time (time.perf_counter, CLOCK_MONOTONIC: the same in every process) of the
        # first zero-effort command after a non-zero one, None while a force is applied: how a
        # test on another process reads when the motors really went quiet.
        self.zero_since: Optional[float] = 0.0
        self.control = 0
        self.homed = 0b111 if homed else 0
        self._armed = [False, False, False]
        self.unplug_error = "[Errno 19] No such device (it may have been disconnected)"

    # ---- observables --------------------------------------------------------------------------
    @property
    def true_position(self) -> np.ndarray:
        return np.array(self._x)

    @property
    def true_velocity(self) -> np.ndarray:
        return np.array(self._v)

    def unplug(self) -> None:
        """Pull the cable now: every later call raises TransportError."""
        self.unplugged = True

    def replug(self) -> None:
        """Plug the cable back in: the device powers up again, without firmware or homing."""
        self.unplugged = False
        self.unplug_at = None
        self.closed = False
        self.stalled = False
        self.stall_at = None
        self._reset_dsp()
        self.mode = "idle"
        self._out.clear()

    def stall(self, stalled: bool = True) -> None:
        """Stop (or resume) answering while still accepting commands."""
        self.stalled = stalled

    # ---- Transport protocol -------------------------------------------------------------------
    def _check(self) -> None:
        if self.unplug_at is not None and self.time >= self.unplug_at:
            self.unplugged = True
        if self.unplugged:
            raise TransportError(f"Falcon {self.serial}: USB error: {self.unplug_error} (emulated unplug)")
        if self.closed:
            raise TransportError(f"Falcon {self.serial}: transport is closed")

    def purge(self, rx: bool = True, tx: bool = True) -> None:
        self._check()
        self.control_log.append(("purge", (rx, tx)))
        if rx:
            self._out.clear()
        if tx:
            self._parser.reset()
            self._hs_buf.clear()

    def set_modem_control(self, *, dtr: Optional[bool] = None, rts: Optional[bool] = None) -> None:
        self._check()
        if rts is not None:
            self.control_log.append(("rts", bool(rts)))
            self.rts = bool(rts)
        if dtr is not None:
            self.control_log.append(("dtr", bool(dtr)))
            if dtr and not self.dtr:
                self._reset_dsp()
            self.dtr = bool(dtr)

    def set_baud_divisor(self, divisor: int) -> None:
        self._check()
        self.control_log.append(("baud", divisor))
        self.baud_divisor = divisor
        if divisor == BAUD_DIVISOR_NORMAL and self.mode == "boot_firmware":
            self.mode = "running" if len(self.firmware) in self.accepted_firmware_sizes else "dead"

    def set_line_property_8n1(self) -> None:
        self._check()
        self.control_log.append(("line", "8N1"))

    def set_flow_control_none(self) -> None:
        self._check()
        self.control_log.append(("flow", "none"))

    def set_latency_timer(self, ms: int) -> None:
        self._check()
        self.control_log.append(("latency", ms))
        self.latency_ms = ms

    def write(self, data: bytes) -> int:
        self._check()
        data = bytes(data)
        mode = self.mode
        if mode == "boot_handshake" and self.baud_divisor == BAUD_DIVISOR_9600:
            self._hs_buf += data
            if self._hs_buf.endswith(HANDSHAKE_REQUEST):
                self._hs_buf.clear()
                self.handshakes_seen += 1
                if self.handshakes_seen > self.drop_handshakes:
                    self._out += (b"\x00" if self.handshake_leading_zero else b"") + HANDSHAKE_REPLY
                    self.mode = "boot_ready"
        elif mode == "boot_ready" and self.baud_divisor == BAUD_DIVISOR_FIRMWARE and not self.dtr:
            if data[:1] == b"\x41":
                self._out += b"\x41"
                self.mode = "boot_firmware"
                self._firmware_bytes(data[1:])
        elif mode == "boot_firmware" and self.baud_divisor == BAUD_DIVISOR_FIRMWARE:
            self._firmware_bytes(data)
        elif mode == "running" and self.baud_divisor == BAUD_DIVISOR_NORMAL:
            for frame in self._parser.feed(data):
                self._exchange(frame)
                self._check()  # an unplug scheduled for this very packet fails the write
        # Any other combination (wrong baud, no firmware, dead DSP): bytes are lost on the line,
        # as on the real device.
        return len(data)

    def read(self, max_bytes: int, timeout_s: float) -> bytes:
        self._check()
        n = min(int(max_bytes), len(self._out))
        chunk = bytes(self._out[:n])
        del self._out[:n]
        return chunk  # empty = "timed out"; the emulator never really waits

    def close(self) -> None:
        self.closed = True

    # ---- boot loader ------------------------------------------------------------------------
    def _reset_dsp(self) -> None:
        # A reset loses the firmware and the homing (the DSP keeps nothing).
        self.mode = "boot_handshake"
        self.firmware = bytearray()
        self.homed = 0
        self._armed = [False, False, False]
        self._hs_buf.clear()
        self._parser.reset()
        self.efforts = (0, 0, 0)
        self.control = 0

    def _firmware_bytes(self, data: bytes) -> None:
        if not data:
            return
        start = len(self.firmware)
        self.firmware += data
        echo = bytearray(data)
        if self.corrupt_echo_block is not None:
            lo = self.corrupt_echo_block * FIRMWARE_BLOCK
            if start <= lo < start + len(data):
                echo[lo - start] ^= 0x5A
        self._out += echo

    # ---- firmware: one packet exchange = one emulated millisecond ------------------------------
    def _exchange(self, frame: bytes) -> None:
        cmd = decode_command(frame)
        self.efforts = cmd.efforts
        if any(cmd.efforts):
            self.zero_since = None
        elif self.zero_since is None:
            self.zero_since = time.perf_counter()
        self.control = cmd.control
        self.commands.append((self.time, cmd.efforts, cmd.control))
        self._step(self.dt)
        self.time += self.dt
        if self.stall_at is not None and self.time >= self.stall_at:
            self.stalled = True
        if self.stalled:
            return
        report = encode_report(self._encoders(), self.homed, self._buttons())
        self.reports_sent += 1
        k = self.reports_sent
        if self.garbage_every and k % self.garbage_every == 0:
            # Line noise: random bytes, '>' excluded so noise can never complete a false frame.
            self._out += bytes(self._rng.choice([b for b in range(256) if b != 0x3E]) for _ in range(self._rng.randint(1, 20)))
        if self.truncate_every and k % self.truncate_every == 0:
            self._out += report[: self._rng.randint(1, 15)]  # a frame cut short, then the real one
        self._out += report
        if len(self._out) > 4096:  # the FT232's buffer is finite: oldest bytes are lost
            del self._out[: len(self._out) - 4096]

    def _buttons(self) -> int:
        b = self.buttons(self.time) if callable(self.buttons) else self.buttons
        return int(b) & 0xF

    def _encoders(self) -> Tuple[int, int, int]:
        t, _ = _ik_jac(*self._x)
        out = []
        for i in range(3):
            c = int(round(angle_to_encoder(t[i])))
            if not self.homed >> i & 1:
                c += self.unhomed_offset[i]  # before homing the count is relative to power-up
            out.append(max(-32768, min(32767, c)))
        return tuple(out)

    def _step(self, dt: float) -> None:
        tau = [-e / EFFORT_PER_NEWTON_METRE for e in self.efforts]
        h = dt / self.substeps
        x, v = self._x, self._v
        im, bm, m = self.motor_inertia, self.motor_damping, self.grip_mass
        for k in range(self.substeps):
            t_now = self.time + k * h
            try:
                theta, j = _ik_jac(*x)
            except KinematicsError:
                v = (0.0, 0.0, 0.0)
                break
            # Grip force of the motors: Jᵀτ.
            fm = [j[0 + c] * tau[0] + j[3 + c] * tau[1] + j[6 + c] * tau[2] for c in range(3)]
            fh = self.hand(t_now, np.array(x), np.array(v))
            fs = self._end_stops(x)
            # Mass and damping matrices: motors' inertia and friction reflected through J.
            mm = [0.0] * 9
            cm = [0.0] * 9
            for r in range(3):
                for c in range(3):
                    jj = j[r] * j[c] + j[3 + r] * j[3 + c] + j[6 + r] * j[6 + c]
                    mm[3 * r + c] = im * jj + (m if r == c else 0.0)
                    cm[3 * r + c] = bm * jj
            rhs = [
                fm[r] + float(fh[r]) + fs[r] - (cm[3 * r] * v[0] + cm[3 * r + 1] * v[1] + cm[3 * r + 2] * v[2])
                for r in range(3)
            ]
            a = _solve3(mm, *rhs)
            nv = (v[0] + a[0] * h, v[1] + a[1] * h, v[2] + a[2] * h)
            nx = (x[0] + nv[0] * h, x[1] + nv[1] * h, x[2] + nv[2] * h)
            try:
                _ik_jac(*nx)
            except KinematicsError:
                nv, nx = (0.0, 0.0, 0.0), x  # a mechanical limit the end stops did not catch
            x, v = nx, nv
            if self.control & 0x01 and self.homed != 0b111:
                self._homing(theta)
        self._x, self._v = x, v

    def _end_stops(self, x) -> Tuple[float, float, float]:
        # Soft walls just inside the reachable set: |x|, |y| <= 0.055 m, z in [0.078, 0.178] m.
        k = self.end_stop_stiffness
        lim = ((-0.055, 0.055), (-0.055, 0.055), (0.078, 0.178))
        out = []
        for c in range(3):
            lo, hi = lim[c]
            out.append(k * (lo - x[c]) if x[c] < lo else k * (hi - x[c]) if x[c] > hi else 0.0)
        return tuple(out)

    def _homing(self, theta) -> None:
        for i in range(3):
            if theta[i] >= self.homing_out:
                self._armed[i] = True
            elif self._armed[i] and theta[i] <= self.homing_in:
                self.homed |= 1 << i
