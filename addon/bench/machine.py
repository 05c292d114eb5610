"""The machine a benchmark ran on: the one place the bench reads the load average.

This file owns ``loadavg`` (the 1-, 5- and 15-minute load averages, or None where the platform
has none), recorded with every part's results so a figure from a busy machine can be told apart.
Dev-only (not in the extension zip).
"""
from __future__ import annotations

import os


def loadavg():
    """(1 min, 5 min, 15 min) load averages, or None where ``os.getloadavg`` does not exist."""
    try:
        return os.getloadavg()
    except OSError:  # pragma: no cover - not on every platform
        return None
