"""3Dconnexion SpaceMouse family (HID 6-DoF pucks) as a grasp device without force feedback.

This file owns:
- the VID:PID table and the two report layouts: *split* (report 1 = x, y, z; report 2 = pitch,
  roll, yaw) and *combined* (report 1 = x, y, z, pitch, roll, yaw in 13 bytes); report 3 = button
  bitmap; values are signed int16 little-endian, raw range about ±350;
- ``parse_report``: bytes -> ``HidReport``;
- ``SpaceMouseDevice``: reads the puck through ``hidapi`` and turns it into a grasp position. A
  puck measures a small spring-returned deflection, so by default it is a *rate* (velocity)
  control: the translation axes are integrated into a position kept inside the workspace ball;
  ``mode="position"`` maps deflection directly to an offset from the centre instead;
- ``translation_report``, ``rotation_report``, ``combined_report``, ``buttons_report``: the bytes
  a puck sends, to script input (tests feed them to a stand-in ``hid.device``).

Why read the device directly: Blender's own NDOF events carry no axis values to Python.
hidapi releases the GIL during reads, and reads are non-blocking here, so a poll never stalls
the servo tick.
"""
from __future__ import annotations

import struct
import time
from typing import Callable, Dict, List, NamedTuple, Optional, Sequence, Tuple

import numpy as np

from .device import (
    ConfigError,
    DeviceNotFoundError,
    DeviceState,
    HapticDevice,
    ProtocolError,
    Workspace,
)

__all__ = [
    "SPLIT",
    "COMBINED",
    "SPACEMOUSE_MODELS",
    "HidReport",
    "parse_report",
    "list_spacemice",
    "SpaceMouseDevice",
    "translation_report",
    "rotation_report",
    "combined_report",
    "buttons_report",
]

SPLIT = "split"
COMBINED = "combined"

# (VID, PID) -> (model name, report layout)
SPACEMOUSE_MODELS: Dict[Tuple[int, int], Tuple[str, str]] = {
    (0x046D, 0xC626): ("SpaceNavigator", SPLIT),
    (0x046D, 0xC627): ("SpaceExplorer", SPLIT),
    (0x046D, 0xC625): ("SpacePilot", SPLIT),
    (0x046D, 0xC629): ("SpacePilot Pro", SPLIT),
    (0x046D, 0xC62B): ("SpaceMouse Pro", SPLIT),
    (0x256F, 0xC635): ("SpaceMouse Compact", SPLIT),
    (0x256F, 0xC641): ("SpaceMouse USB", SPLIT),
    (0x256F, 0xC62E): ("SpaceMouse Wireless (cable)", COMBINED),
    (0x256F, 0xC63A): ("SpaceMouse Wireless", COMBINED),
    (0x256F, 0xC632): ("SpaceMouse Pro Wireless", COMBINED),
    (0x256F, 0xC638): ("SpaceMouse Pro Wireless (Bluetooth)", COMBINED),
    (0x256F, 0xC633): ("SpaceMouse Enterprise", COMBINED),
    (0x256F, 0xC652): ("3Dconnexion Universal Receiver", COMBINED),
}

RAW_FULL_SCALE = 350.0
_3H = struct.Struct("<3h")
_6H = struct.Struct("<6h")


class HidReport(NamedTuple):
    """What one input report carried; fields it did not carry are None."""

    translation: Optional[Tuple[int, int, int]]
    rotation: Optional[Tuple[int, int, int]]
    buttons: Optional[int]


def parse_report(data: Sequence[int], layout: str) -> HidReport:
    """Decode one HID input report (report id first, as hidapi returns it).

    Unknown report ids (battery, keyboard pages of some models) give an all-None report; a
    known id that is too short raises ``ProtocolError``."""
    b = bytes(data)
    if not b:
        raise ProtocolError("empty HID report")
    rid = b[0]
    if rid == 1:
        if layout == COMBINED:
            if len(b) < 13:
                raise ProtocolError(f"combined-layout report 1 needs 13 bytes, got {len(b)}")
            v = _6H.unpack_from(b, 1)
            return HidReport(v[:3], v[3:], None)
        if len(b) < 7:
            raise ProtocolError(f"translation report needs 7 bytes, got {len(b)}")
        return HidReport(_3H.unpack_from(b, 1), None, None)
    if rid == 2:
        if len(b) < 7:
            raise ProtocolError(f"rotation report needs 7 bytes, got {len(b)}")
        return HidReport(None, _3H.unpack_from(b, 1), None)
    if rid == 3:
        return HidReport(None, None, int.from_bytes(b[1:], "little"))
    return HidReport(None, None, None)


def translation_report(x: int, y: int, z: int) -> bytes:
    return b"\x01" + _3H.pack(x, y, z)


def rotation_report(pitch: int, roll: int, yaw: int) -> bytes:
    return b"\x02" + _3H.pack(pitch, roll, yaw)


def combined_report(x: int, y: int, z: int, pitch: int = 0, roll: int = 0, yaw: int = 0) -> bytes:
    return b"\x01" + _6H.pack(x, y, z, pitch, roll, yaw)


def buttons_report(mask: int, nbytes: int = 4) -> bytes:
    return b"\x03" + int(mask).to_bytes(nbytes, "little")


def list_spacemice() -> List[dict]:
    """Known SpaceMouse models plugged in: dicts with path, vid, pid, model, layout, serial.
    Never raises (no hidapi, no permission: empty list)."""
    try:
        import hid

        infos = hid.enumerate()
    except Exception:
        return []
    out, seen = [], set()
    for info in infos:
        key = (info.get("vendor_id"), info.get("product_id"))
        if key not in SPACEMOUSE_MODELS or info.get("path") in seen:
            continue
        # Multi-interface receivers list several paths; the 6-DoF one is usage page 1, usage 8.
        if info.get("usage_page") not in (None, 0, 1) or info.get("usage") not in (None, 0, 8):
            continue
        seen.add(info.get("path"))
        model, layout = SPACEMOUSE_MODELS[key]
        out.append(
            {
                "path": info.get("path"),
                "vid": key[0],
                "pid": key[1],
                "model": model,
                "layout": layout,
                "serial": info.get("serial_number") or "",
            }
        )
    return out


class SpaceMouseDevice(HapticDevice):
    """A SpaceMouse as an input-only grasp device (``has_force`` False).

    Parameters:
    - ``path`` / ``vid``+``pid``: which device (default: the first known model found);
    - ``hid_device``: an object with the ``hid.device`` interface (the tests' ``fakes.FakeHid``);
    - ``mode``: ``"velocity"`` (integrate deflection, default) or ``"position"``;
    - ``max_speed`` (m/s at full deflection), ``deadzone`` (fraction of full scale: pucks rarely
      return exactly to zero, and a drifting grasp would slowly pull the cloth);
    - ``axis_signs``: maps the HID convention (x right, y toward the user, z down) to a frame
      with y away from the user and z up; change it if your model differs.
    """

    def __init__(
        self,
        path: Optional[bytes] = None,
        *,
        vid: Optional[int] = None,
        pid: Optional[int] = None,
        hid_device=None,
        layout: Optional[str] = None,
        mode: str = "velocity",
        max_speed: float = 0.2,
        deadzone: float = 0.05,
        full_scale: float = RAW_FULL_SCALE,
        axis_signs: Sequence[float] = (1.0, -1.0, -1.0),
        workspace: Workspace = Workspace((0.0, 0.0, 0.0), 0.1),
        name: Optional[str] = None,
        hand: Optional[str] = None,
        clock: Callable[[], float] = time.perf_counter,
        max_reports_per_poll: int = 64,
    ):
        if mode not in ("velocity", "position"):
            raise ConfigError(f"mode must be 'velocity' or 'position', got {mode!r}")
        if not 0.0 <= deadzone < 1.0:
            raise ConfigError(f"deadzone is a fraction of full scale in [0, 1), got {deadzone!r}")
        if layout not in (None, SPLIT, COMBINED):
            raise ConfigError(f"layout must be 'split' or 'combined', got {layout!r}")
        model = SPACEMOUSE_MODELS.get((vid, pid), (None, None))
        super().__init__(
            name or model[0] or "SpaceMouse",
            max_force=0.0,
            workspace=workspace,
            has_force=False,
            hand=hand,
            clock=clock,
        )
        self.path = path
        self.vid, self.pid = vid, pid
        self.layout = layout or model[1]
        self.mode = mode
        self.max_speed = float(max_speed)
        self.deadzone = float(deadzone)
        self.full_scale = float(full_scale)
        self.axis_signs = np.asarray(axis_signs, dtype=float).reshape(3)
        self.max_reports_per_poll = max_reports_per_poll
        self._hid = hid_device
        self._raw_t = (0, 0, 0)
        self._raw_r = (0, 0, 0)
        self._last_t: Optional[float] = None
        self.bad_reports = 0

    @property
    def raw_translation(self) -> Tuple[int, int, int]:
        return self._raw_t

    @property
    def raw_rotation(self) -> Tuple[int, int, int]:
        """Last rotation (pitch, roll, yaw) raw counts: not used for the grasp, exposed for UI."""
        return self._raw_r

    def _open(self) -> None:
        dev = self._hid
        if dev is None:
            try:
                import hid
            except ImportError as exc:
                raise DeviceNotFoundError(f"hidapi is not installed ({exc})") from exc
            dev = hid.device()
        path, vid, pid = self.path, self.vid, self.pid
        if path is None and vid is None and self._hid is None:
            # Nothing specified: take the first known model (an injected device is used as is).
            found = list_spacemice()
            if not found:
                self._set_state(DeviceState.ABSENT, "no 3Dconnexion SpaceMouse found")
                raise DeviceNotFoundError("no 3Dconnexion SpaceMouse found (on Linux, check the udev rule for hidraw access)")
            path, vid, pid = found[0]["path"], found[0]["vid"], found[0]["pid"]
        try:
            if path is not None:
                dev.open_path(path)
            elif vid is not None:
                dev.open(vid, pid)
            dev.set_nonblocking(1)
        except (OSError, IOError, ValueError) as exc:
            self._set_state(DeviceState.ABSENT, f"cannot open the SpaceMouse: {exc}")
            raise DeviceNotFoundError(f"cannot open the SpaceMouse ({vid!r}:{pid!r}): {exc}") from exc
        self.vid, self.pid, self.path = vid, pid, path
        if self.layout is None:
            self.layout = SPACEMOUSE_MODELS.get((vid, pid), ("", SPLIT))[1]
        self._hid = dev
        self._raw_t = (0, 0, 0)
        self._last_t = self.clock()
        self._position = np.asarray(self.workspace.centre, dtype=float).copy()
        self._velocity = np.zeros(3)
        self._set_state(DeviceState.READY, f"{self.name}: ready (input only, no force feedback)")

    def _deflection(self) -> np.ndarray:
        """Translation deflection in [-1, 1] per axis, dead zone removed and rescaled."""
        d = np.clip(np.asarray(self._raw_t, dtype=float) / self.full_scale, -1.0, 1.0)
        mag = np.abs(d)
        dz = self.deadzone
        d = np.where(mag <= dz, 0.0, np.sign(d) * (mag - dz) / (1.0 - dz))
        return d * self.axis_signs

    def _poll(self) -> bool:
        got = False
        try:
            for _ in range(self.max_reports_per_poll):
                data = self._hid.read(64)
                if not data:
                    break
                got = True
                try:
                    rep = parse_report(data, self.layout)
                except ProtocolError:
                    self.bad_reports += 1
                    continue
                if rep.translation is not None:
                    self._raw_t = rep.translation
                if rep.rotation is not None:
                    self._raw_r = rep.rotation
                if rep.buttons is not None:
                    self._buttons = rep.buttons
        except (OSError, IOError, ValueError) as exc:
            self.mark_lost(f"HID read failed: {exc}")
            return False
        now = self.clock()
        dt = 0.0 if self._last_t is None else max(0.0, now - self._last_t)
        self._last_t = now
        d = self._deflection()
        if self.mode == "velocity":
            old = self._position
            new = self.workspace.clamp(old + self.max_speed * d * dt)
            self._position = new
            self._velocity = (new - old) / dt if dt > 0.0 else np.zeros(3)
        else:
            target = np.asarray(self.workspace.centre, dtype=float) + self.workspace.radius * d
            self._update_motion(self.workspace.clamp(target), now)
        return got

    def set_led(self, on: bool) -> None:
        """Output report 4: ``[04, 01]`` lights the LED (a cue that the puck holds the cloth)."""
        if self._hid is not None and self.is_open:
            try:
                self._hid.write([0x04, 0x01 if on else 0x00])
            except (OSError, IOError, ValueError):
                pass

    def _close(self) -> None:
        dev, self._hid = self._hid, None
        if dev is not None:
            try:
                dev.close()
            except (OSError, IOError, ValueError):
                pass
