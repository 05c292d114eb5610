"""What a live haptic session hands to Blender, off the main thread. NO bpy in this file.

What this file owns
-------------------
``LiveFrame`` (one snapshot of the torn cloth, world metres, copies) and ``LiveRecorder``, the
object that sits on ``LiveSession``'s ``recorder`` hook. The hook is called on the simulation
thread, where bpy must never be touched, so the recorder only:

* keeps the LATEST frame in one attribute (a reference swap, atomic under the GIL); the modal
  operator's TIMER tick on the main thread picks it up and writes it into the live display mesh;
* when recording, queues one frame per scene frame (frame ``f`` at simulated time
  ``(f - frame_start) / fps``, the bake's clock) for its own writer thread, which writes them with
  the same ``CacheWriter`` a bake uses, in the cloth object's local space (``spaces``' rule),
  so the session plays back through the Tear Cloth modifier like a bake.

The writer is a thread of its own because a USD frame takes milliseconds to write: on the
simulation thread it would slow the steps the hands feel, on the main thread it would stutter the
viewport. If it falls ``MAX_QUEUED`` frames behind, new frames are dropped (counted in
``dropped``): blocking the simulation thread would freeze the force the hands feel.
"""
from __future__ import annotations

import math
import queue
import threading
from dataclasses import dataclass

import numpy as np

from .. import spaces

MAX_QUEUED = 240


@dataclass(frozen=True)
class LiveFrame:
    """One snapshot of the cloth (world space, SI), owned by whoever holds it."""

    time: float                 # simulated seconds since the session started
    positions: np.ndarray       # (n, 3) m
    triangles: np.ndarray       # (m, 3)
    corner_uv: np.ndarray | None  # (m, 3, 2) or None
    velocities: np.ndarray      # (n, 3) m/s


class LiveRecorder:
    """``LiveSession``'s recorder: latest frame for display, scene frames for the cache writer.

    ``writer``: an open ``CacheWriter`` (None: nothing is recorded); ``matrix``: the cloth
    object's world matrix (4x4, Blender units) the cache frames are written relative to;
    ``scale``: metres per Blender unit; ``has_uv``: whether frames carry UVs.
    """

    def __init__(self, fps: float, frame_start: int, matrix: np.ndarray, scale: float, has_uv: bool,
                 writer=None):
        self.fps = float(fps)
        self.frame_start = int(frame_start)
        self.matrix = np.array(matrix, dtype=np.float64)
        self.scale = float(scale)
        self.has_uv = bool(has_uv)
        self.writer = writer
        self.latest: LiveFrame | None = None
        self.frames_written = 0
        self.dropped = 0
        self.error: BaseException | None = None
        self._last_index = -1
        self._queue: queue.Queue = queue.Queue(maxsize=MAX_QUEUED)
        self._thread: threading.Thread | None = None

    @property
    def recording(self) -> bool:
        return self.writer is not None

    # -- the hook (simulation thread) ----------------------------------------------------------

    def __call__(self, time_s, positions, triangles, corner_uv, velocities) -> None:
        uv = corner_uv if self.has_uv and corner_uv is not None and np.size(corner_uv) else None
        frame = LiveFrame(float(time_s), positions, triangles, uv, velocities)
        self.latest = frame
        if self.writer is None or self.error is not None:
            return
        index = int(math.floor(frame.time * self.fps + 1e-6))
        if index <= self._last_index:
            return
        self._last_index = index
        try:
            self._queue.put_nowait((self.frame_start + index, frame))
        except queue.Full:
            self.dropped += 1

    # -- the writer thread ---------------------------------------------------------------------

    def start(self, first: LiveFrame) -> None:
        """Show and queue the rest state as the first frame, then start the writer thread."""
        self.latest = first
        if self.writer is None:
            return
        self._last_index = 0
        self._queue.put((self.frame_start, first))
        self._thread = threading.Thread(target=self._run, name="tearcloth-live-writer", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            if self.error is not None:
                continue  # drain: the cache keeps what it had; the error is reported once
            frame_number, frame = item
            try:
                self._write(frame_number, frame)
            except Exception as exc:  # reported by the main thread
                self.error = exc

    def _write(self, frame_number: int, frame: LiveFrame) -> None:
        local = spaces.world_si_to_local(frame.positions, self.matrix, self.scale)
        velocity = spaces.world_si_vectors_to_local(frame.velocities, self.matrix, self.scale)
        # As in the bake: metres with meters_per_unit = scale, so the file holds local Blender units.
        self.writer.write_frame(frame_number, local * self.scale, frame.triangles,
                                frame.corner_uv if self.has_uv else None, velocity * self.scale)
        self.frames_written += 1

    def close(self, timeout_s: float = 60.0) -> None:
        """Write what is queued, then finish the cache. Idempotent; errors land in ``error``."""
        if self._thread is not None:
            self._queue.put(None)
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                self.error = self.error or TimeoutError(f"the cache writer did not finish within {timeout_s:.0f} s")
                return
            self._thread = None
        if self.writer is not None and not self.writer.closed:
            try:
                self.writer.close(complete=True)
            except Exception as exc:
                self.error = self.error or exc

    @property
    def frames(self) -> list:
        return self.writer.frames if self.writer is not None else []
