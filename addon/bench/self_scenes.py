"""Self-collision's acceleration structures compared, interleaved: the cloth's native refitted BVHs
(``narrow.ClusterBVH``) against the former Embree scenes (``narrow.ClusterScenes``), on the
recorded frame10 moving scenario of ``bench.collision`` (the T-shirt simulated on the walking
mannequin, 10 sub-steps per 24 fps frame). The recording is replayed into one detector per variant
(relative measure, the session's thickness and threshold), step by step in alternating order
(A B, B A, ...), so machine load falls on both alike. Per step: wall ms of the self part of full
detection (``stats['ms']['full_self']``, and its process CPU ``full_self_cpu``), of the whole detection, and the process CPU ms (Embree
builds run on a second thread). Dev-only: ``python -m tearcloth.bench.self_scenes [steps]``.
"""
from __future__ import annotations

import json
import sys
import time

import numpy as np

from ..collision.detector import CollisionDetector
from .collision import _SESSION_THICKNESS, _SESSION_THRESHOLD, SIMULATED_CASES, simulate_worn_shirt

VARIANTS = ("bvh", "embree")


def compare(steps: int = 120, warmup: int = 3) -> dict:
    body, shirt, rec, _, _, tears = simulate_worn_shirt(SIMULATED_CASES["frame10"], steps, True)
    dets = {}
    for mode in VARIANTS:
        det = CollisionDetector(_SESSION_THICKNESS, 0.3, _SESSION_THRESHOLD, 100, "relative", True)
        det.self_scenes = mode
        det.add_body(rec[0].body, body.triangles, "body")
        det.set_cloth(rec[0].cloth, rec[0].triangles)
        dets[mode] = det
    rows = {m: {"self_ms": [], "self_cpu_ms": [], "total_ms": [], "cpu_ms": [], "contacts": []} for m in VARIANTS}
    for k, fr in enumerate(rec):
        order = VARIANTS if k % 2 == 0 else VARIANTS[::-1]
        for mode in order:
            det = dets[mode]
            det.update_body("body", fr.body, fr.body_velocity)
            c0 = time.process_time()
            c = det.detect(fr.cloth, fr.triangles, fr.velocity, fr.dt)
            cpu = time.process_time() - c0
            if fr.events is not None:
                det.on_topology(fr.events, fr.after, fr.after_triangles)
            if k < warmup:
                continue
            r = rows[mode]
            r["self_ms"].append(det.stats["ms"]["full_self"])
            r["self_cpu_ms"].append(det.stats["ms"]["full_self_cpu"])
            r["total_ms"].append(det.stats["ms"]["total"])
            r["cpu_ms"].append(1e3 * cpu)
            r["contacts"].append(len(c))
    out = {"steps": len(rec) - warmup, "tears": tears}
    for mode in VARIANTS:
        r = rows[mode]
        out[mode] = {key: {"median": float(np.median(v)), "mean": float(np.mean(v))} for key, v in r.items()}
        out[mode]["self_builds"] = int(dets[mode].cloth.scenes.builds)
    for key in ("self_ms", "self_cpu_ms", "total_ms", "cpu_ms"):
        a, b = np.array(rows["bvh"][key]), np.array(rows["embree"][key])
        out[f"{key}_ratio_bvh_over_embree"] = {"median": float(np.median(a) / np.median(b)),
                                               "mean": float(a.mean() / b.mean())}
    out["self_share_of_total"] = {m: float(np.mean(rows[m]["self_ms"]) / np.mean(rows[m]["total_ms"]))
                                  for m in VARIANTS}
    out["self_cpu_share_of_cpu"] = {m: float(np.mean(rows[m]["self_cpu_ms"]) / np.mean(rows[m]["cpu_ms"]))
                                    for m in VARIANTS}
    return out


if __name__ == "__main__":
    print(json.dumps(compare(int(sys.argv[1]) if len(sys.argv) > 1 else 120), indent=1))
