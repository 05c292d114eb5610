"""Speed of the bake cache: writing the frames of a growing, tearing-like sheet into a USD cache.

This file owns ``cache_bench`` (ms per frame written, bytes per frame file, the root's size),
run on a regular grid whose vertex count grows by one per frame as a tear does. It measures
``tearcloth.cache.CacheWriter`` and cleans up after itself. Dev-only (not in the extension zip);
needs ``pxr`` (usd-core) like the cache itself.
"""
from __future__ import annotations

import os
import time

import numpy as np

from ..cache import CacheWriter, delete_cache


def cache_bench(folder, frames: int = 100, triangles: int = 3300, durable: bool = False) -> dict:
    """Time writing ``frames`` frames of a growing ~``triangles``-triangle sheet with UVs and
    velocities into ``folder`` (for ``tearcloth bench``). Returns ms per frame (mean and max),
    bytes per frame file and the root's size at the end."""
    side = max(2, int(round(np.sqrt(triangles / 2.0)))) + 1
    xs, ys = np.meshgrid(np.linspace(0.0, 1.0, side), np.linspace(0.0, 1.0, side), indexing="ij")
    rest = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1)
    q = np.arange(side - 1)
    a = (q[:, None] * side + q[None, :]).ravel()
    tris = np.concatenate([np.stack([a, a + side, a + side + 1], 1), np.stack([a, a + side + 1, a + 1], 1)])
    uv = rest[:, :2][tris]
    path = os.path.join(os.fspath(folder), "bench.usda")
    times = []
    with CacheWriter(path, "Bench", 24.0, durable=durable) as writer:
        for f in range(1, frames + 1):
            # One more duplicated vertex per frame, like a tear growing by an edge.
            k = min(f, len(rest) - 1)
            pos = np.concatenate([rest, rest[:k] + [0.0, 0.0, 0.001]])
            pos[:, 2] += 0.01 * np.sin(0.1 * f + pos[:, 0])
            t = tris.copy()
            sel = (t < k) & (np.arange(len(t))[:, None] % 2 == 0)
            t[sel] += len(rest)
            start = time.perf_counter()
            writer.write_frame(f, pos, t, uv, np.zeros_like(pos))
            times.append(time.perf_counter() - start)
        # the frame files (frame_000001.usdc, ...); the folder's other file is the clip manifest
        frame_bytes = [os.path.getsize(os.path.join(writer.frames_dir, name))
                       for name in os.listdir(writer.frames_dir) if name.startswith("frame_")]
    result = {
        "frames": frames,
        "triangles": len(tris),
        "ms_per_frame": 1000.0 * float(np.mean(times)),
        "ms_per_frame_max": 1000.0 * float(np.max(times)),
        "bytes_per_frame": float(np.mean(frame_bytes)),
        "root_bytes": os.path.getsize(path),
    }
    delete_cache(path)
    return result
