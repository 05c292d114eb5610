"""Test fakes: stand-ins for hardware the tests cannot count on.

This file owns ``FakeHid``, a byte-level stand-in for ``hidapi``'s ``hid.device`` that plays
back the reports it is fed (build them with ``tearcloth.haptics.spacemouse.translation_report``
and co.). Nothing in the package uses it; imported from the tests folder (``from fakes import
FakeHid``).
"""
from __future__ import annotations

import collections
from typing import List, Optional, Sequence

__all__ = ["FakeHid"]


class FakeHid:
    """Stand-in for ``hid.device`` that plays back report bytes fed to it.

    ``feed(report)`` queues one input report; ``read`` pops one (a list of ints, like hidapi) or
    returns ``[]`` when empty (non-blocking); ``unplug()`` makes ``read`` raise ``OSError`` like
    hidapi's "read error"; ``written`` keeps output reports (LED)."""

    def __init__(self, reports: Sequence[bytes] = ()):
        self._queue = collections.deque(bytes(r) for r in reports)
        self.written: List[List[int]] = []
        self.opened: Optional[tuple] = None
        self.nonblocking = False
        self.unplugged = False
        self.closed = False

    def feed(self, report: bytes) -> None:
        self._queue.append(bytes(report))

    def unplug(self) -> None:
        self.unplugged = True

    def open(self, vid: int, pid: int, serial=None) -> None:
        self.opened = ("vidpid", vid, pid)

    def open_path(self, path) -> None:
        self.opened = ("path", path)

    def set_nonblocking(self, flag) -> int:
        self.nonblocking = bool(flag)
        return 0

    def read(self, max_length: int, timeout_ms: int = 0) -> List[int]:
        if self.unplugged:
            raise OSError("read error")
        if not self._queue:
            return []
        return list(self._queue.popleft()[:max_length])

    def write(self, data) -> int:
        if self.unplugged:
            raise OSError("write error")
        self.written.append(list(data))
        return len(data)

    def close(self) -> None:
        self.closed = True


# Importable device hooks for the servo process (a DeviceSpec or a discovery hook names them as
# "fakes:ftdi_falcon" / "fakes:hid_puck"; the servo process imports this folder because the
# simulating process has it on sys.path). Each is built inside the servo process.
def ftdi_falcon(serial):
    """A Falcon at the byte level over the FTDI transport interface (``FalconEmulator``), firmware
    loaded and homed, its grip held by a hand that holds 0.05 s and then pulls 1.5 cm along
    device x (+x for a serial ending in "R", else -x) over 0.5 s of emulator (wall) time."""
    from tearcloth.haptics.falcon_emulator import FalconEmulator
    from tearcloth.haptics.live import pulling_hand

    side = 1.0 if str(serial).endswith("R") else -1.0
    return FalconEmulator(serial, firmware_loaded=True, homed=True, substeps=1,
                          hand=pulling_hand((side, 0.0, 0.0), 0.015, 0.05, 0.5))


def hid_puck(path):
    """An emulated SpaceMouse HID device (``FakeHid``) for the hidapi path ``path``."""
    return FakeHid()


def ftdi_falcon_unhomed(serial):
    """A byte-level Falcon just powered up: no firmware, not homed, its user making the homing
    gesture (grip all the way out and in)."""
    from tearcloth.haptics.falcon_emulator import FalconEmulator, homing_gesture, spring_hand

    return FalconEmulator(serial, firmware_loaded=False, homed=False, hand=spring_hand(homing_gesture(leg=0.1), 1500.0, 15.0))
