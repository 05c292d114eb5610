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
