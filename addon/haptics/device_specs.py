"""Devices as the servo process builds them: importable factories for ``DeviceSpec``.

This file owns the factories a ``servo_process.DeviceSpec`` names for every device kind a live
session can use (``falcon``: a real Falcon over pyftdi/D2XX or an injected byte-level
transport; ``spacemouse``: a SpaceMouse over hidapi or an injected HID object; ``keyboard``: a
virtual device whose target position comes from the simulating process through the shared
memory), and ``importable`` / ``resolve``: a hook (a function, or "module:function") as the
picklable text the servo process imports, and back.

Why text and not the function: the servo process is a fresh interpreter (``python -c``), so only
what it can import reaches it; a lambda or a closure cannot, and a session given one keeps the
in-process servo threads (``importable`` returns None and the caller says so).
"""
from __future__ import annotations

import importlib
from typing import Callable, Optional, Sequence

import numpy as np

from .device import ConfigError, HapticDevice, Workspace
from .falcon import FALCON_MAX_FORCE, FalconDevice
from .spacemouse import SpaceMouseDevice
from .virtual import VirtualDevice

__all__ = ["falcon", "spacemouse", "keyboard", "importable", "resolve"]

_PACKAGE = __name__.rsplit(".", 2)[0]


def importable(hook) -> Optional[str]:
    """``hook`` as "module:function" the servo process can import: a string is taken as it is,
    a module-level function by its module and name (checked by importing it back); None for a
    lambda, a closure, a bound method or a function of the running script (``__main__``)."""
    if hook is None:
        return None
    if isinstance(hook, str):
        return hook
    module, name = getattr(hook, "__module__", None), getattr(hook, "__qualname__", "")
    if not module or module == "__main__" or not name or "<" in name or "." in name:
        return None  # __main__ is another module in the servo process
    try:
        if getattr(importlib.import_module(module), name) is not hook:
            return None
    except (ImportError, AttributeError):
        return None
    return f"{module}:{name}"


def resolve(path: Optional[str]) -> Optional[Callable]:
    """The function "module:function" names (a module starting with "." is in this package)."""
    if path is None:
        return None
    module, _, name = path.partition(":")
    if not name:
        raise ConfigError(f"a device hook must be 'module:function', got {path!r}")
    try:
        return getattr(importlib.import_module(module, _PACKAGE), name)
    except (ImportError, AttributeError) as exc:
        raise ConfigError(f"the device hook {path!r} cannot be imported: {exc}") from exc


def falcon(serial: Optional[str], hand: str, *, firmware_path: Optional[str] = None,
           max_force: float = FALCON_MAX_FORCE, transport: Optional[str] = None) -> FalconDevice:
    """A Falcon by USB serial; ``transport`` ("module:function", serial -> Transport) replaces
    USB, e.g. by the byte-level ``FalconEmulator`` in tests. Opened (firmware, homing) by the
    servo process."""
    return FalconDevice(serial, hand=hand, firmware_path=firmware_path, transport_factory=resolve(transport),
                        max_force=min(float(max_force), FALCON_MAX_FORCE))


def spacemouse(path: str, hand: str, *, vid: Optional[int] = None, pid: Optional[int] = None,
               hid: Optional[str] = None, **kwargs) -> SpaceMouseDevice:
    """A SpaceMouse by hidapi path (text, as the settings hold it); ``hid`` ("module:function",
    path bytes -> ``hid.device``-like object) replaces hidapi, e.g. by an emulated HID device."""
    raw = path.encode("utf-8", "surrogateescape") if path else None
    factory = resolve(hid)
    return SpaceMouseDevice(raw, vid=vid, pid=pid, hid_device=factory(raw) if factory is not None else None, hand=hand,
                            **kwargs)


def keyboard(hand: str, *, radius: float = 0.04, max_force: float = 8.0,
             target: Optional[Callable[[], Optional[Sequence[float]]]] = None) -> HapticDevice:
    """The keyboard/mouse hand: a ``VirtualDevice`` whose position is ``target()`` (the position
    Blender's key events set, read from the shared memory by the servo process; None: not set
    yet, it stays at the centre of its ``radius`` workspace)."""
    workspace = Workspace((0.0, 0.0, 0.0), float(radius))
    centre = np.zeros(3)
    last = [centre]

    def script(_t):
        p = target() if target is not None else None
        if p is not None:
            last[0] = p
        return last[0]

    return VirtualDevice(f"keyboard ({hand} hand)", workspace=workspace, max_force=float(max_force), hand=hand,
                         script=script)
