"""Per-hand force recording: CSV export and a plot like Fig. 6 of Le Gouis et al. (WHC 2017),
the force along the tearing axis for both hands over time.

This file owns ``ForceLog``. The servo loop records the force it rendered for each hand at every
tick (scene frame, N; see ``servo.ServoLoop(force_log=...)``); the user exports it to CSV or
PNG after a session. Samples go into preallocated numpy chunks (32 bytes each, ~230 kB per hand
per minute at 1 kHz, instead of ~10 MB as Python tuples) and are written by one thread per hand
(its servo thread); readers take a consistent snapshot at any time.

Plotting uses matplotlib's object API with the Agg canvas directly (no pyplot, no global
backend switch), so it works headless and inside Blender without touching its UI.
"""
from __future__ import annotations

import csv
import os
import threading
from typing import Dict, Iterable, List, Optional, Sequence, Tuple

import numpy as np

from .device import ConfigError

__all__ = ["ForceLog"]

CSV_HEADER = ("time_s", "hand", "fx_N", "fy_N", "fz_N")


class _Series:
    """Append-only (t, fx, fy, fz) rows in fixed-size chunks: O(1) append, no reallocation.

    One writer; readers snapshot ``n`` first and only look at rows below it, which were
    completely written before ``n`` was incremented."""

    CHUNK = 4096

    def __init__(self):
        self.chunks: List[np.ndarray] = []
        self.n = 0

    def append(self, t: float, fx: float, fy: float, fz: float) -> None:
        i = self.n % self.CHUNK
        if i == 0:
            self.chunks.append(np.empty((self.CHUNK, 4)))
        row = self.chunks[-1][i]
        row[0], row[1], row[2], row[3] = t, fx, fy, fz
        self.n += 1

    def snapshot(self) -> np.ndarray:
        n = self.n
        if n == 0:
            return np.zeros((0, 4))
        chunks = self.chunks[: (n + self.CHUNK - 1) // self.CHUNK]
        return np.concatenate(chunks)[:n].copy()


class ForceLog:
    """Force samples per hand: ``record(hand, t, force)``; ``series(hand)`` -> (t, F)."""

    def __init__(self, hands: Iterable[str] = ("left", "right")):
        self._lock = threading.Lock()
        self._series: Dict[str, _Series] = {h: _Series() for h in hands}

    @property
    def hands(self) -> List[str]:
        return list(self._series)

    def record(self, hand: str, t: float, force: Sequence[float]) -> None:
        s = self._series.get(hand)
        if s is None:
            with self._lock:
                s = self._series.setdefault(hand, _Series())
        s.append(float(t), float(force[0]), float(force[1]), float(force[2]))

    def clear(self) -> None:
        with self._lock:
            for hand in list(self._series):
                self._series[hand] = _Series()

    def series(self, hand: str) -> Tuple[np.ndarray, np.ndarray]:
        """(times (n,), forces (n, 3)) for ``hand``."""
        s = self._series.get(hand)
        a = s.snapshot() if s is not None else np.zeros((0, 4))
        return a[:, 0], a[:, 1:]

    def tear_axis(self) -> np.ndarray:
        """Unit tearing axis estimated from the data: the dominant direction of the right hand's
        force and of the left hand's force reversed (the hands pull apart), oriented so the
        right hand pulls along +axis. Falls back to +x without data."""
        parts = []
        for hand, sign in (("right", 1.0), ("left", -1.0)):
            _, f = self.series(hand)
            if len(f):
                parts.append(sign * f)
        for hand in self._series:
            if hand not in ("left", "right"):
                _, f = self.series(hand)
                if len(f):
                    parts.append(f)
        if not parts:
            return np.array([1.0, 0.0, 0.0])
        f = np.vstack(parts)
        m = f.T @ f
        if not np.any(m):
            return np.array([1.0, 0.0, 0.0])
        w, v = np.linalg.eigh(m)
        axis = v[:, -1]
        if float(np.sum(f @ axis)) < 0.0:
            axis = -axis
        return axis / np.linalg.norm(axis)

    def along_axis(self, hand: str, axis: Optional[Sequence[float]] = None) -> Tuple[np.ndarray, np.ndarray]:
        """(times, force · axis) for ``hand``; ``axis`` defaults to ``tear_axis()``."""
        a = self.tear_axis() if axis is None else np.asarray(axis, dtype=float)
        n = float(np.linalg.norm(a))
        if not n > 0.0:
            raise ConfigError(f"axis must be a non-zero 3-vector, got {axis!r}")
        t, f = self.series(hand)
        return t, f @ (a / n)

    # ---- files --------------------------------------------------------------------------------
    def to_csv(self, path) -> str:
        """Write ``time_s,hand,fx_N,fy_N,fz_N`` rows (long format: the hands need not share
        timestamps). Returns the path."""
        path = os.fspath(path)
        with open(path, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(CSV_HEADER)
            for hand in self._series:
                t, f = self.series(hand)
                for i in range(len(t)):
                    w.writerow((repr(float(t[i])), hand, repr(float(f[i, 0])), repr(float(f[i, 1])), repr(float(f[i, 2]))))
        return path

    @classmethod
    def from_csv(cls, path) -> "ForceLog":
        log = cls(())
        with open(os.fspath(path), newline="") as fh:
            r = csv.reader(fh)
            header = next(r, None)
            if tuple(header or ()) != CSV_HEADER:
                raise ConfigError(f"{path!r} is not a Tear Cloth force log (header {header!r})")
            for row in r:
                log.record(row[1], float(row[0]), (float(row[2]), float(row[3]), float(row[4])))
        return log

    def plot(self, path, axis: Optional[Sequence[float]] = None, title: Optional[str] = None) -> str:
        """Save a PNG of the force along the tearing axis for each hand vs time (Fig. 6 style).
        Time starts at the first sample. Returns the path."""
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        a = self.tear_axis() if axis is None else np.asarray(axis, dtype=float)
        fig = Figure(figsize=(7.0, 3.6), dpi=120)
        FigureCanvasAgg(fig)
        ax = fig.add_subplot(1, 1, 1)
        starts = [self.series(h)[0][:1] for h in self._series]
        starts = [s[0] for s in starts if len(s)]
        t0 = min(starts) if starts else 0.0
        for hand in self._series:
            t, f = self.along_axis(hand, a)
            if len(t):
                ax.plot(t - t0, f, label=f"{hand} hand", linewidth=1.2)
        ax.axhline(0.0, color="0.6", linewidth=0.6)
        ax.set_xlabel("time (s)")
        ax.set_ylabel("force along tearing axis (N)")
        ax.set_title(title or f"Haptic force along the tearing axis ({a[0]:+.2f}, {a[1]:+.2f}, {a[2]:+.2f})")
        ax.grid(True, alpha=0.3)
        if ax.lines:
            ax.legend(loc="best")
        fig.tight_layout()
        path = os.fspath(path)
        fig.savefig(path, format="png")
        return path
