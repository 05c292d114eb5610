"""Timing experiment of the collision measures (paper section IV-B, the T-shirt comparison).

This file owns ``collision_experiment``, which the lead's ``tearcloth bench`` calls with the
T-shirt on a moving mannequin, and a stand-in scene (a cylinder "torso" in a cloth tube) to run
it without the scenes package: ``python -m tearcloth.collision.bench``.

Each measure ('full', 'absolute', 'relative') replays the same motion with its own detector; the
per-step time is ``detector.stats['ms']['total']`` (measure + incremental + full + contacts),
after ``warmup`` steps, so the one-off clustering and first scene builds are not counted (they
are reported separately as ``setup_ms``).
"""
from __future__ import annotations

import time

import numpy as np

from .detector import CollisionDetector

__all__ = ["collision_experiment", "standin_scene", "numpy_vs_embree"]


def collision_experiment(
    cloth_vertices,
    cloth_triangles,
    body_vertices_fn,
    steps,
    *,
    body_triangles,
    thickness=0.005,
    displacement_threshold=0.005,
    cluster_size=100,
    self_collision=True,
    warmup=3,
):
    """Median per-step detection time (ms) of the three measures on one scene.

    ``body_vertices_fn(step)`` returns the body's vertices (nb,3) at that step, or a pair
    (body_vertices, cloth_vertices) when the scene moves the cloth as well (the cloth then
    follows the body: the case the relative measure is made for). Returns a dict with
    ``full_ms``, ``absolute_ms``, ``relative_ms`` (medians), ``full_share`` (mean share of
    close pairs fully detected per step with the relative measure), ``absolute_full_share``,
    and per-measure breakdowns (``phases``: median ms of each phase) and ``close_pairs``.
    """
    cloth_vertices = np.asarray(cloth_vertices, np.float64)
    cloth_triangles = np.asarray(cloth_triangles, np.int32)
    frames = []
    for k in range(steps):
        out = body_vertices_fn(k)
        if isinstance(out, tuple):
            frames.append((np.asarray(out[0], np.float64), np.asarray(out[1], np.float64)))
        else:
            frames.append((np.asarray(out, np.float64), cloth_vertices))
    result = {}
    for measure in ("full", "absolute", "relative"):
        t0 = time.perf_counter()
        det = CollisionDetector(thickness, 0.3, displacement_threshold, cluster_size, measure, self_collision)
        det.add_body(frames[0][0], body_triangles, "body")
        det.set_cloth(frames[0][1], cloth_triangles)
        setup = 1e3 * (time.perf_counter() - t0)
        totals, shares, close = [], [], []
        phases = {"measure": [], "incremental": [], "full": [], "contacts": []}
        contacts = []
        for k, (body, cloth) in enumerate(frames):
            det.update_body("body", body)
            c = det.detect(cloth, cloth_triangles)
            if k < warmup:
                continue
            st = det.stats
            totals.append(st["ms"]["total"])
            shares.append(st["full_share"])
            close.append(st["close_pairs"])
            contacts.append(len(c))
            for p in phases:
                phases[p].append(st["ms"][p])
        result[f"{measure}_ms"] = float(np.median(totals))
        result[f"{measure}_phases"] = {p: float(np.median(v)) for p, v in phases.items()}
        result[f"{measure}_share"] = float(np.mean(shares))
        result[f"{measure}_setup_ms"] = setup
        result["close_pairs"] = float(np.median(close))
        result["contacts"] = float(np.median(contacts))
    result["full_share"] = result["relative_share"]
    result["absolute_full_share"] = result["absolute_share"]
    return result


def _cylinder(radius, height, around, rings, capped=True):
    """Closed (capped) or open cylinder around the z axis, outward winding."""
    ang = np.linspace(0, 2 * np.pi, around, endpoint=False)
    z = np.linspace(-height / 2, height / 2, rings + 1)
    zz, aa = np.meshgrid(z, ang, indexing="ij")
    v = np.stack([radius * np.cos(aa).ravel(), radius * np.sin(aa).ravel(), zz.ravel()], axis=1)
    idx = np.arange(v.shape[0]).reshape(rings + 1, around)
    a = idx[:-1, :]
    b = np.roll(idx[:-1, :], -1, axis=1)
    c = np.roll(idx[1:, :], -1, axis=1)
    d = idx[1:, :]
    tri = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    if capped:
        bottom = v.shape[0]
        top = bottom + 1
        v = np.vstack([v, [[0, 0, -height / 2], [0, 0, height / 2]]])
        ring0, ring1 = idx[0], idx[-1]
        tri = np.concatenate(
            [
                tri,
                np.stack([np.full(around, bottom), np.roll(ring0, -1), ring0], 1),
                np.stack([np.full(around, top), ring1, np.roll(ring1, -1)], 1),
            ]
        )
    return v, tri.astype(np.int32)


def _rigid(angle, offset):
    c, s = np.cos(angle), np.sin(angle)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    return R, np.asarray(offset, np.float64)


def standin_scene(moving=True, thickness=0.005, dt=0.002, seed=0):
    """A ~8K-triangle capped cylinder "torso" inside a ~3.3K-triangle cloth tube resting on it.

    moving: the torso twists (±0.25 rad, 0.5 Hz) and sways (±10 cm, 0.7-1 Hz) and the tube moves with it,
    plus a small independent jiggle of the cloth (0.2 mm), as a worn shirt does; immobile: only
    the jiggle. Returns (cloth_vertices, cloth_triangles, body_triangles, body_vertices_fn).
    """
    body_v, body_t = _cylinder(0.15, 0.6, 64, 62, capped=True)
    cloth_v, cloth_t = _cylinder(0.15 + 0.4 * thickness, 0.5, 48, 35, capped=False)
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0, 2 * np.pi, size=cloth_v.shape)

    def fn(k):
        t = k * dt
        jiggle = 2e-4 * np.sin(2 * np.pi * 3.0 * t + phase)
        if moving:
            R, off = _rigid(0.25 * np.sin(np.pi * t), [0.1 * np.sin(2 * np.pi * 0.7 * t), 0.05 * np.sin(2 * np.pi * t), 0.0])
        else:
            R, off = np.eye(3), np.zeros(3)
        return body_v @ R.T + off, (cloth_v + jiggle) @ R.T + off

    return cloth_v, cloth_t, body_t, fn


def numpy_vs_embree(rays=200, triangles=200, repeat=20):
    """ms of testing ``rays`` rays against ``triangles`` triangles exhaustively in numpy vs one
    query into a cached embreex scene vs building that scene (the narrow.py design numbers)."""
    from .incremental import line_triangle
    from .narrow import build_scene, cast

    v, t = _cylinder(0.15, 0.6, 10, triangles // 20, capped=False)
    t = t[:triangles]
    rng = np.random.default_rng(1)
    o = rng.normal(size=(rays, 3)) * 0.05
    d = rng.normal(size=(rays, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    tic = time.perf_counter()
    for _ in range(repeat):
        oo = np.repeat(o, t.shape[0], 0)
        dd = np.repeat(d, t.shape[0], 0)
        tt = np.tile(t, (rays, 1))
        tv, u, w, ok = line_triangle(oo, dd, v[tt[:, 0]], v[tt[:, 1]], v[tt[:, 2]])
        hit = ok & (u >= 0) & (w >= 0) & (u + w <= 1) & (tv >= 0)
        np.where(hit, tv, np.inf).reshape(rays, -1).min(axis=1)
    numpy_ms = 1e3 * (time.perf_counter() - tic) / repeat
    tic = time.perf_counter()
    for _ in range(repeat):
        scene = build_scene(v, t)
        cast(scene, o, d, 10.0, np.arange(t.shape[0]))
    build_ms = 1e3 * (time.perf_counter() - tic) / repeat
    tic = time.perf_counter()
    for _ in range(repeat):
        cast(scene, o, d, 10.0, np.arange(t.shape[0]))
    query_ms = 1e3 * (time.perf_counter() - tic) / repeat
    return {"numpy_ms": numpy_ms, "embree_build_and_query_ms": build_ms, "embree_query_ms": query_ms}


def main():
    import json

    for moving in (False, True):
        cv, ct, bt, fn = standin_scene(moving=moving)
        res = collision_experiment(cv, ct, fn, 120, body_triangles=bt)
        print(("moving" if moving else "immobile"), json.dumps(res, indent=1))
    print(json.dumps(numpy_vs_embree(), indent=1))


if __name__ == "__main__":
    main()
