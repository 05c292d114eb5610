"""One interface for every grasp device: the Falcon (force feedback), HID 6-DoF pucks (input
only) and the virtual device (scripts, keyboard/mouse, tests).

This file owns:
- ``HapticDevice``: the abstract base the servo loop talks to, so the coupling of eq. (5) never
  needs to know which hardware sits behind a hand;
- ``DeviceState``: the life cycle every device reports, with a human ``message`` for the UI;
- the ``HapticError`` exception family (one ``except HapticError`` catches every device problem);
- ``Workspace`` and ``VelocityFilter``, shared by all devices.

Threading contract: exactly one thread *drives* a device (``open``/``poll``/``set_force``/
``close``), normally the servo thread. Any other thread may *read* ``position``, ``velocity``,
``buttons``, ``state`` and ``message``: these are replaced by new immutable objects (never mutated
in place), so a reader sees either the old or the new value, never a torn vector.

Units: metres, metres per second, newtons, seconds. Vectors are in the device's own frame.
"""
from __future__ import annotations

import abc
import enum
import math
import time
from dataclasses import dataclass
from typing import Callable, FrozenSet, Optional, Sequence, Tuple

import numpy as np

__all__ = [
    "HapticError",
    "ConfigError",
    "DeviceStateError",
    "DeviceNotFoundError",
    "TransportError",
    "ProtocolError",
    "KinematicsError",
    "FirmwareError",
    "FirmwareFileError",
    "HandshakeError",
    "EchoMismatchError",
    "FirmwareNotRunningError",
    "NotHomedError",
    "DeviceState",
    "Workspace",
    "VelocityFilter",
    "HapticDevice",
    "clamp_norm",
]


# --------------------------------------------------------------------------------------------
# Errors: one family, so callers (the Blender operator, the bench) can catch HapticError and show
# str(exc) to the user. Every message says what happened and what to do about it.
# --------------------------------------------------------------------------------------------
class HapticError(Exception):
    """Base of every error raised by ``tearcloth.haptics``."""


class ConfigError(HapticError, ValueError):
    """A parameter is out of range or inconsistent (e.g. a coupling stiffer than the device)."""


class DeviceStateError(HapticError):
    """An operation is not allowed in the device's current state (e.g. poll() before open())."""


class DeviceNotFoundError(HapticError):
    """No device matches the request (not plugged in, no permission, no driver/back end)."""


class TransportError(HapticError):
    """The link to the device failed (USB error, unplugged cable, driver error)."""


class ProtocolError(HapticError):
    """The device sent something that does not follow the expected protocol."""


class KinematicsError(HapticError, ValueError):
    """A position or joint configuration is outside the mechanism's reachable set."""


class FirmwareError(HapticError):
    """Base of every failure to bring a Falcon's firmware up."""


class FirmwareFileError(FirmwareError):
    """The user-supplied firmware file is missing, unreadable or of an unexpected size."""


class HandshakeError(FirmwareError):
    """The Falcon's boot loader did not answer the handshake."""


class EchoMismatchError(FirmwareError):
    """A firmware block was echoed back differently from what was sent (bad link or cable)."""


class FirmwareNotRunningError(FirmwareError):
    """The firmware was sent but the device never started speaking the packet protocol."""


class NotHomedError(HapticError):
    """The device did not finish homing in the allotted time."""


class DeviceState(enum.Enum):
    """Life cycle of a device. ``HapticDevice.message`` explains the current state to a human."""

    ABSENT = "absent"  # not opened yet, or opening found nothing
    NEEDS_FIRMWARE = "needs_firmware"  # Falcon powered but without firmware (user file needed)
    HOMING = "homing"  # talking, but positions are not trustworthy until homed: no force
    READY = "ready"  # positions valid, forces rendered
    LOST = "lost"  # the link died (unplugged, stalled): force is zero, re-open to recover
    CLOSED = "closed"  # closed on purpose, zero force was sent first


@dataclass(frozen=True)
class Workspace:
    """Sphere that bounds the useful motion of a device, in the device frame (m).

    The coupling uses it to pick a workspace scale (scene region radius / device radius)."""

    centre: Tuple[float, float, float]
    radius: float

    def __post_init__(self):
        if not (self.radius > 0.0 and math.isfinite(self.radius)):
            raise ConfigError(f"workspace radius must be a positive number of metres, got {self.radius!r}")
        if len(self.centre) != 3:
            raise ConfigError(f"workspace centre must be a 3-vector, got {self.centre!r}")

    def clamp(self, p: np.ndarray) -> np.ndarray:
        """Project ``p`` onto the ball (used by rate-controlled devices to stay inside)."""
        c = np.asarray(self.centre, dtype=float)
        d = np.asarray(p, dtype=float) - c
        n = float(np.linalg.norm(d))
        if n <= self.radius:
            return np.asarray(p, dtype=float).copy()
        return c + d * (self.radius / n)


def clamp_norm(vector, limit: float) -> np.ndarray:
    """Scale ``vector`` down (keeping its direction) so that its norm is at most ``limit``.

    Clamping the norm instead of each axis keeps the rendered force pointing where the
    simulation wants it; a per-axis clamp would bend it toward the diagonals."""
    v = np.asarray(vector, dtype=float).reshape(3)
    if not np.all(np.isfinite(v)):
        raise ConfigError(f"force must be finite, got {v.tolist()!r}")
    n = math.sqrt(float(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]))
    if n > limit:
        return v * (limit / n)
    return v


class VelocityFilter:
    """Velocity from sampled positions: finite difference + first-order low-pass.

    Falcon encoders quantise the grip position to ~50 µm; at 1 kHz a single count of jitter is a
    0.05 m/s spike, which a damping term k_velocity·v would turn into audible buzz. A first-order
    low-pass at ``cutoff_hz`` (default 40 Hz, well above voluntary hand motion, ~10 Hz) removes it
    while adding only ~4 ms of lag. The filter uses the true sample interval so that a late servo
    tick does not read as a velocity spike.
    """

    def __init__(self, cutoff_hz: float = 40.0):
        if not cutoff_hz > 0.0:
            raise ConfigError(f"velocity cutoff must be > 0 Hz, got {cutoff_hz!r}")
        self.tau = 1.0 / (2.0 * math.pi * cutoff_hz)
        self.reset()

    def reset(self) -> None:
        self._last_p: Optional[np.ndarray] = None
        self._last_t: Optional[float] = None
        self.value = np.zeros(3)

    def update(self, position: np.ndarray, t: float) -> np.ndarray:
        """Feed a sample taken at time ``t`` (s); returns the filtered velocity (m/s)."""
        p = np.asarray(position, dtype=float)
        if self._last_p is None:
            self._last_p, self._last_t = p, t
            return self.value
        dt = t - self._last_t
        if dt <= 0.0:
            # Two samples in the same clock tick: no information about velocity.
            return self.value
        raw = (p - self._last_p) / dt
        alpha = dt / (dt + self.tau)
        self.value = self.value + alpha * (raw - self.value)
        self._last_p, self._last_t = p, t
        return self.value


class HapticDevice(abc.ABC):
    """Common interface of every grasp device (see the module docstring for threading rules).

    Subclasses implement ``_open``, ``_poll``, ``_close`` and, for force devices, ``_send_force``
    (push the current ``force`` to the hardware now; used by ``close`` to zero the motors).

    Attributes every device has:
    - ``name``: human label; ``hand``: ``"left"``/``"right"``/None once assigned;
    - ``max_force`` (N): ``set_force`` clamps the norm to it;
    - ``max_stiffness`` (N/m) / ``max_damping`` (N·s/m): what the hardware renders stably
      (``math.inf`` when unknown or irrelevant); the servo refuses couplings above them;
    - ``workspace``: ``Workspace`` in the device frame; ``has_force``: False for input-only.
    """

    def __init__(
        self,
        name: str,
        *,
        max_force: float,
        workspace: Workspace,
        has_force: bool,
        max_stiffness: float = math.inf,
        max_damping: float = math.inf,
        hand: Optional[str] = None,
        clock: Callable[[], float] = time.perf_counter,
        velocity_cutoff_hz: float = 40.0,
    ):
        if not (max_force >= 0.0 and math.isfinite(max_force)):
            raise ConfigError(f"max_force must be a finite number of newtons >= 0, got {max_force!r}")
        self.name = name
        self.hand = hand
        self.max_force = float(max_force)
        self.max_stiffness = float(max_stiffness)
        self.max_damping = float(max_damping)
        self.workspace = workspace
        self.has_force = bool(has_force)
        self.clock = clock
        self._velocity_filter = VelocityFilter(velocity_cutoff_hz)
        self._state = DeviceState.ABSENT
        self._message = "not opened yet"
        self._position = np.asarray(workspace.centre, dtype=float).copy()
        self._velocity = np.zeros(3)
        self._buttons = 0
        self._force = np.zeros(3)

    # ---- state ---------------------------------------------------------------------------
    @property
    def state(self) -> DeviceState:
        return self._state

    @property
    def message(self) -> str:
        """A sentence for the user that explains ``state`` (and what to do about it)."""
        return self._message

    def _set_state(self, state: DeviceState, message: str) -> None:
        # Message first: a reader that sees the new state should not see the old explanation.
        self._message = message
        self._state = state

    @property
    def is_open(self) -> bool:
        return self._state not in (DeviceState.ABSENT, DeviceState.CLOSED)

    # ---- readings ------------------------------------------------------------------------
    @property
    def position(self) -> np.ndarray:
        """Grip position (m, device frame). A copy: callers may modify it freely."""
        return self._position.copy()

    @property
    def velocity(self) -> np.ndarray:
        """Filtered grip velocity (m/s, device frame)."""
        return self._velocity.copy()

    @property
    def buttons(self) -> int:
        """Pressed buttons as a bitmask (bit i = button i)."""
        return self._buttons

    @property
    def button_set(self) -> FrozenSet[int]:
        """Pressed buttons as a set of indices."""
        b = self._buttons
        return frozenset(i for i in range(b.bit_length()) if b >> i & 1)

    @property
    def force(self) -> np.ndarray:
        """Last commanded force after clamping (N, device frame)."""
        return self._force.copy()

    def _update_motion(self, position: Sequence[float], t: Optional[float] = None) -> None:
        p = np.asarray(position, dtype=float).reshape(3).copy()
        self._velocity = self._velocity_filter.update(p, self.clock() if t is None else t).copy()
        self._position = p

    # ---- life cycle ----------------------------------------------------------------------
    def open(self) -> DeviceState:
        """Connect to the device. Returns the resulting state (READY, HOMING, NEEDS_FIRMWARE...).

        Raises a ``HapticError`` subclass when the device cannot be reached at all."""
        if self.is_open and self._state is not DeviceState.LOST:
            return self._state
        self._velocity_filter.reset()
        self._force = np.zeros(3)
        self._open()
        return self._state

    def poll(self) -> bool:
        """One I/O exchange: send the current force, read position/buttons.

        Returns True when fresh data arrived. Never raises on device loss: the state becomes
        LOST (with a message) and the force zero, so the servo loop can end cleanly."""
        if self._state in (DeviceState.ABSENT, DeviceState.CLOSED):
            raise DeviceStateError(f"{self.name}: poll() needs an open device (state {self._state.value}); call open() first")
        if self._state is DeviceState.LOST:
            return False
        return self._poll()

    def set_force(self, force) -> np.ndarray:
        """Command a force (N, device frame); its norm is clamped to ``max_force``.

        The force is sent at the next ``poll()``. Input-only devices accept and ignore it (the
        servo loop can treat every hand alike). Returns the clamped force."""
        f = clamp_norm(force, self.max_force if self.has_force else 0.0)
        if self._state is not DeviceState.READY:
            # HOMING: positions are wrong, a force would push the hand somewhere arbitrary.
            # LOST/CLOSED: nothing to send to. Either way the only safe force is zero.
            f = np.zeros(3)
        self._force = f
        self._on_force(f)
        return f.copy()

    def close(self) -> None:
        """Zero the force, push it to the hardware, then release the device. Idempotent."""
        if self._state in (DeviceState.ABSENT, DeviceState.CLOSED):
            self._set_state(DeviceState.CLOSED, "closed")
            return
        self._force = np.zeros(3)
        self._on_force(self._force)
        if self._state is not DeviceState.LOST:
            try:
                self._send_force()
            except HapticError:
                pass  # the device is going away anyway; closing must not fail because of it
        try:
            self._close()
        finally:
            self._set_state(DeviceState.CLOSED, "closed")

    def mark_lost(self, reason: str) -> None:
        """Declare the link dead: state LOST, force zero. Used by subclasses and the servo."""
        self._force = np.zeros(3)
        self._on_force(self._force)
        self._velocity = np.zeros(3)
        self._set_state(DeviceState.LOST, f"{self.name}: connection lost ({reason}); force set to zero. Reconnect the device and open it again.")

    def __enter__(self):
        self.open()
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    # ---- subclass hooks ------------------------------------------------------------------
    @abc.abstractmethod
    def _open(self) -> None:
        """Connect and set ``_state``/``_message``."""

    @abc.abstractmethod
    def _poll(self) -> bool:
        """One exchange; update position/velocity/buttons; on loss call ``mark_lost``."""

    @abc.abstractmethod
    def _close(self) -> None:
        """Release the hardware."""

    def _send_force(self) -> None:
        """Push ``self._force`` to the hardware immediately (force devices override)."""

    def _on_force(self, force: np.ndarray) -> None:
        """Hook called whenever the commanded force changes (e.g. convert to motor efforts)."""

    def __repr__(self) -> str:
        hand = f" hand={self.hand}" if self.hand else ""
        return f"<{type(self).__name__} {self.name!r}{hand} {self._state.value}>"
