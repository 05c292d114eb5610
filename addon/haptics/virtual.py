"""A device without hardware: driven by a script or by setter calls.

This file owns ``VirtualDevice``. Users without a Falcon grasp the cloth with the keyboard/mouse
(the Blender operator calls ``set_position``/``move_by``/``set_buttons`` on the main thread),
and tests drive it with a script ``t -> position`` or ``t -> (position, buttons)``. It renders no
force, but can record every commanded force, so a test (or a user curious about what a Falcon
would feel) can inspect the coupling's output.

Setters are called from one thread and ``poll`` from another (the servo): they meet under a
lock, and ``poll`` takes a consistent snapshot of (position, buttons).
"""
from __future__ import annotations

import threading
import time
from typing import Callable, List, Optional, Sequence, Tuple

import numpy as np

from .device import ConfigError, DeviceState, HapticDevice, Workspace

__all__ = ["VirtualDevice"]


class VirtualDevice(HapticDevice):
    """Scripted or hand-driven device.

    - ``script(t)``: t in seconds since ``open()`` (on ``clock``); returns a position (m) or a
      ``(position, buttons)`` pair. Without a script the last setter value is used.
    - ``record_forces``: keep every ``(t, force)`` passed to ``set_force`` (after clamping).
    - ``has_force``: True by default so the servo computes forces for it (nothing moves).
    - ``clamp_to_workspace``: keep setter positions inside the workspace ball.
    """

    def __init__(
        self,
        name: str = "virtual",
        *,
        script: Optional[Callable[[float], object]] = None,
        workspace: Workspace = Workspace((0.0, 0.0, 0.0), 0.1),
        max_force: float = 8.0,
        has_force: bool = True,
        record_forces: bool = False,
        clamp_to_workspace: bool = True,
        hand: Optional[str] = None,
        clock: Callable[[], float] = time.perf_counter,
        velocity_cutoff_hz: float = 40.0,
    ):
        super().__init__(
            name,
            max_force=max_force,
            workspace=workspace,
            has_force=has_force,
            hand=hand,
            clock=clock,
            velocity_cutoff_hz=velocity_cutoff_hz,
        )
        self.script = script
        self.record_forces = record_forces
        self.clamp_to_workspace = clamp_to_workspace
        self._lock = threading.Lock()
        self._target = np.asarray(workspace.centre, dtype=float).copy()
        self._target_buttons = 0
        self._t0 = 0.0
        self._fail_reason: Optional[str] = None
        self.forces: List[Tuple[float, np.ndarray]] = []

    # ---- setters (any thread) -----------------------------------------------------------------
    def set_position(self, position: Sequence[float]) -> None:
        p = np.asarray(position, dtype=float).reshape(3)
        if not np.all(np.isfinite(p)):
            raise ConfigError(f"position must be finite, got {p.tolist()!r}")
        if self.clamp_to_workspace:
            p = self.workspace.clamp(p)
        with self._lock:
            self._target = p

    def move_by(self, delta: Sequence[float]) -> None:
        with self._lock:
            current = self._target
        self.set_position(current + np.asarray(delta, dtype=float).reshape(3))

    def set_buttons(self, mask: int) -> None:
        with self._lock:
            self._target_buttons = int(mask)

    def press(self, button: int) -> None:
        with self._lock:
            self._target_buttons |= 1 << button

    def release(self, button: int) -> None:
        with self._lock:
            self._target_buttons &= ~(1 << button)

    def unplug(self, reason: str = "virtual device unplugged") -> None:
        """Make the next poll report loss (tests of the LOST path)."""
        self._fail_reason = reason

    @property
    def recorded_forces(self) -> Tuple[np.ndarray, np.ndarray]:
        """(times (n,), forces (n, 3)) of the recorded commands."""
        if not self.forces:
            return np.zeros(0), np.zeros((0, 3))
        t = np.array([f[0] for f in self.forces])
        return t, np.array([f[1] for f in self.forces])

    # ---- HapticDevice hooks -------------------------------------------------------------------
    def _open(self) -> None:
        self._t0 = self.clock()
        self._fail_reason = None
        self._set_state(DeviceState.READY, f"{self.name}: ready (virtual device)")
        self._sample()

    def _sample(self) -> None:
        now = self.clock()
        if self.script is not None:
            out = self.script(now - self._t0)
            if isinstance(out, tuple) and len(out) == 2 and not np.isscalar(out[0]):
                pos, buttons = out
                self.set_buttons(buttons)
            else:
                pos = out
            self.set_position(pos)
        with self._lock:
            pos, buttons = self._target, self._target_buttons
        self._buttons = buttons
        self._update_motion(pos, now)

    def _poll(self) -> bool:
        if self._fail_reason is not None:
            self.mark_lost(self._fail_reason)
            return False
        self._sample()
        return True

    def _on_force(self, force: np.ndarray) -> None:
        if self.record_forces and self._state is DeviceState.READY:
            self.forces.append((self.clock(), force.copy()))

    def _close(self) -> None:
        pass
