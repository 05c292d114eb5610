"""The collision experiment of the paper (section IV-B): a T-shirt worn by a character, immobile and
moving; detection time per step with full detection every step, the absolute displacement measure
and the clustered relative measure.

This file owns ``collision_experiment`` (the three measures replayed on the same motion, each with
its own ``CollisionDetector``), the worn shirt it runs on in ``tearcloth bench``
(``worn_shirt``: ``tearcloth.examples``' T-shirt skinned to the walking mannequin, and
``collision_figures``, ``format_collision``, the paper's figures ``PAPER_COLLISION``), a stand-in
scene that needs no example geometry (``standin_scene``: a cylinder "torso" in a cloth tube,
``python -m tearcloth.bench.collision``), the numpy-vs-Embree design numbers of ``narrow.py``
(``numpy_vs_embree``) and the picture of a scenario's clusters (``cluster_picture``, the paper's
Fig. 2, for ``tearcloth clusters``).

Each measure's per-step time is ``detector.stats['ms']['total']`` (measure + incremental + full +
contacts), after ``warmup`` steps, so the one-off clustering and first scene builds are not
counted (they are reported separately as ``setup_ms``). Dev-only (not in the extension zip).
"""
from __future__ import annotations

import time

import numpy as np
from scipy.spatial import cKDTree

from .. import examples
from ..collision.detector import CollisionDetector
from .table1 import DT


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
    from ..collision.incremental import line_triangle
    from ..collision.narrow import build_scene, cast

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


def worn_shirt():
    """The mannequin and the T-shirt, the shirt skinned to the body (each shirt vertex takes the
    skin weights of its nearest body vertex) so that it follows the walk as a worn shirt does:
    the case the relative measure is made for."""
    body = examples.mannequin()
    shirt = examples.tshirt(body)
    V = shirt.vertices
    nearest = cKDTree(body.vertices).query(V)[1]  # the same vertices as a brute-force argmin
    weights = body.weights[nearest]
    bind_inv = np.linalg.inv(examples.bone_matrices(body, 0.0))

    def pose(t):
        M = examples.bone_matrices(body, t) @ bind_inv  # bind pose -> pose at t
        h = np.concatenate([V, np.ones((len(V), 1))], axis=1)
        moved = np.einsum("bij,nj->nbi", M[:, :3, :], h)
        return np.einsum("nb,nbi->ni", weights, moved)

    return body, shirt, pose


def collision_figures(steps: int = 120, dt: float = DT) -> dict:
    body, shirt, pose = worn_shirt()
    out = {"triangles": int(len(shirt.triangles)), "body_triangles": int(len(body.triangles)), "steps": steps}
    t0 = 0.5  # mid-stride
    frames_immobile = lambda k: (examples.body_pose(body, t0), pose(t0))  # noqa: E731
    frames_moving = lambda k: (examples.body_pose(body, t0 + k * dt), pose(t0 + k * dt))  # noqa: E731
    for name, fn in (("immobile", frames_immobile), ("moving", frames_moving)):
        r = collision_experiment(shirt.vertices, shirt.triangles, fn, steps, body_triangles=body.triangles,
                                 thickness=0.004, displacement_threshold=0.003)
        out[name] = {k: r[k] for k in ("full_ms", "absolute_ms", "relative_ms")}
        out[name]["full_share"] = r["full_share"]
        out[name]["absolute_full_share"] = r.get("absolute_share", r.get("absolute_full_share"))
        out[name]["absolute_over_relative"] = r["absolute_ms"] / r["relative_ms"]
    return out


PAPER_COLLISION = {"immobile": {"absolute_ms": 3.65, "relative_ms": 3.37},
                   "moving": {"absolute_ms": 11.76, "relative_ms": 3.18}}


def format_collision(c: dict) -> str:
    rows = [f"collision, T-shirt ({c['triangles']} triangles) on the mannequin ({c['body_triangles']}), "
            f"median ms per step over {c['steps']} steps",
            f"{'':<9} {'full':>8} {'absolute':>9} {'(paper)':>8} {'relative':>9} {'(paper)':>8} {'abs/rel':>8} {'full share':>11}"]
    for name in ("immobile", "moving"):
        r, p = c[name], PAPER_COLLISION[name]
        rows.append(f"{name:<9} {r['full_ms']:>8.2f} {r['absolute_ms']:>9.2f} {p['absolute_ms']:>8.2f} "
                    f"{r['relative_ms']:>9.2f} {p['relative_ms']:>8.2f} {r['absolute_over_relative']:>8.2f} "
                    f"{r['full_share']:>11.3f}")
    return "\n".join(rows)


def cluster_picture(path: str, scenario: str = "tshirt", cluster_size: int = 100) -> str:
    """The cluster decomposition of a scenario's cloth, coloured per cluster (the paper's Fig. 2)."""
    from ..collision.clusters import Clustering
    from .preview import render_clusters

    mesh = {"cloth": examples.square_cloth, "banknote": examples.banknote, "tshirt": examples.tshirt}[scenario]()
    cl = Clustering(mesh.vertices, mesh.triangles, cluster_size)
    return render_clusters(path, mesh.vertices, mesh.triangles, cl.labels,
                           title=f"{scenario}: {len(mesh.vertices)} vertices in {cl.n_clusters} clusters "
                                 f"(geodesic k-means, ~{cluster_size} each)")


def main():
    import json

    for moving in (False, True):
        cv, ct, bt, fn = standin_scene(moving=moving)
        res = collision_experiment(cv, ct, fn, 120, body_triangles=bt)
        print(("moving" if moving else "immobile"), json.dumps(res, indent=1))
    print(json.dumps(numpy_vs_embree(), indent=1))


if __name__ == "__main__":
    main()
