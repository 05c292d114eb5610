"""Which grasp devices are plugged in, which hand gets which, and what state each is in. No bpy.

What this file owns
-------------------
* ``scan``: the Novint Falcons (USB serial numbers) and 3Dconnexion SpaceMice (hidapi paths)
  plugged in, as a ``Discovery``. Discovery never raises: a missing back end (no pyftdi, no
  hidapi) or a refused permission reads as "nothing found" and is logged.
* ``assign``: the device chosen for each hand, or the first free one found when the hand's
  choice is empty (a chosen id is kept whether it is plugged in or not, so the message can say so).
* ``probe``: one hand's device state as the panel shows it ('ready', 'absent', 'needs_firmware',
  'homing', ...) with a sentence; a Falcon is opened and closed again at zero force, nothing is
  loaded into it.
* ``hid_path_text`` / ``hid_path_bytes``: a hidapi path (bytes) as a string setting and back.

Device hooks for tests and demos: ``find_falcons``, ``find_spacemice`` (the listings),
``falcon_transport_factory`` (serial -> Transport; None: USB) and ``spacemouse_hid_factory``
(hidapi path -> ``hid.device``-like; None: hidapi) are module attributes that may be replaced;
everything here and in the Blender layer reads them at call time.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

from .device import HapticError
from .falcon import FalconDevice
from .falcon_transport import list_falcons
from .spacemouse import list_spacemice

log = logging.getLogger("tearcloth")

falcon_transport_factory = None   # serial -> Transport (None: pyftdi / D2XX)
spacemouse_hid_factory = None     # hidapi path -> hid.device-like object (None: hidapi)


def find_falcons() -> list:
    return list_falcons()


def find_spacemice() -> list:
    return list_spacemice()


def quietly(fn) -> list:
    """``fn()`` as a list; a back end that raises means nothing found (logged, never raised)."""
    try:
        return list(fn())
    except Exception as exc:  # noqa: BLE001 - the device back ends raise anything
        log.info("device discovery: %s", exc)
        return []


def hid_path_text(path) -> str:
    """A hidapi path (bytes) as it is stored in a StringProperty, and back (``hid_path_bytes``)."""
    return path.decode("utf-8", "surrogateescape") if isinstance(path, bytes) else str(path or "")


def hid_path_bytes(text: str) -> bytes | None:
    return text.encode("utf-8", "surrogateescape") if text else None


@dataclass
class Discovery:
    falcons: list = field(default_factory=list)      # serial numbers
    spacemice: list = field(default_factory=list)    # list_spacemice() dicts
    states: dict = field(default_factory=dict)       # (object name, hand) -> (state, message)
    when: float = 0.0                                # time.time() of the scan


def scan() -> Discovery:
    """The devices plugged in now (never raises)."""
    return Discovery(sorted(quietly(find_falcons)), quietly(find_spacemice), {}, time.time())


def assign(wanted: dict, found: list) -> dict:
    """{hand: chosen id or ''} -> {hand: id or None}: a chosen id is kept (plugged in or not), an
    empty choice takes the first found id no other hand uses."""
    out = {hand: choice for hand, choice in wanted.items() if choice}
    remaining = [x for x in sorted(found) if x not in out.values()]
    for hand, choice in wanted.items():
        if not choice:
            out[hand] = remaining.pop(0) if remaining else None
    return out


def probe(hand: str, kind: str, serial, found: Discovery, mouse_path) -> tuple[str, str]:
    """(state, message) of the ``kind`` device ('FALCON', 'SPACEMOUSE', 'KEYBOARD', 'EMULATED')
    assigned to ``hand``: ``serial`` the Falcon's, ``mouse_path`` the SpaceMouse's (text)."""
    if kind == "EMULATED":
        return "ready", "emulated Falcon: a scripted hand pulls the grip (demo, no hardware)"
    if kind == "KEYBOARD":
        return "ready", "keyboard and mouse: drive this hand while the session runs"
    if kind == "SPACEMOUSE":
        if mouse_path is None or mouse_path not in [hid_path_text(m["path"]) for m in found.spacemice]:
            return "absent", "no 3Dconnexion SpaceMouse found for this hand (on Linux, check the udev rule for hidraw)"
        return "ready", "SpaceMouse found (input only, no force feedback)"
    if serial is None:
        return "absent", ("no Novint Falcon found for this hand (check USB, power and, on Linux, the udev rule "
                          "for 0403:cb48)")
    if serial not in found.falcons:
        return "absent", f"the Falcon {serial!r} chosen for the {hand} hand is not connected; connected: " \
                         f"{', '.join(found.falcons) or 'none'}"
    dev = FalconDevice(serial, hand=hand, transport_factory=falcon_transport_factory)
    try:
        state = dev.open()
        return state.value, dev.message
    except HapticError as exc:
        return "absent", str(exc)
    finally:
        try:
            dev.close()
        except HapticError:
            pass
