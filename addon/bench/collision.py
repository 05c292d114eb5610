"""The collision experiment of the paper (section IV-B): a T-shirt worn by a character, immobile and
moving; detection time per step with full detection every step, the absolute displacement measure
and the clustered relative measure.

This file owns
- ``simulated_figures``: the paper's experiment as the paper ran it - the T-shirt SIMULATED on the
  walking mannequin (FEM, tearing on, collision with the body and itself through a ``Session``
  with the artist's default ``CollisionSettings``), immobile and moving, at dt = 1 ms and at 10
  sub-steps per 24 fps frame. The simulation is recorded once per case (body, cloth positions,
  velocities, triangles, tear events per step) and replayed into three fresh detectors, one per
  measure, so every measure sees the same deforming cloth. JSON keys
  ``collision.simulated.{dt1ms,frame10}.{immobile,moving,walking}.{full_ms,absolute_ms,relative_ms,full_share}``
  ('moving' walks in place; 'walking', added for issue 15, also travels forward: ``MOTIONS``);
  ``bound_rule_ms`` / ``bound_rule_full_share``: the relative measure with the motion-bound trip
  rule (measure.py, ``trip_rule='bound'``) on the same replay, stepped interleaved with the others.
- ``collision_figures``: both experiments; the old one is kept under ``rigid_skinned`` and is
  what its name says: the shirt skinned rigidly to the body (no relative motion, no deformation),
  3 mm threshold, 4 mm thickness - it does not measure what the paper measured.
- ``collision_experiment`` (the three measures replayed on the same motion, each with its own
  ``CollisionDetector``), the worn shirt (``worn_shirt``), ``format_collision``, the paper's figures
  ``PAPER_COLLISION``, a stand-in scene that needs no example geometry (``standin_scene``, a
  cylinder "torso" in a cloth tube, ``python -m tearcloth.bench.collision``), the numpy-vs-Embree
  design numbers of ``narrow.py`` (``numpy_vs_embree``) and the picture of a scenario's clusters
  (``cluster_picture``, the paper's Fig. 2, for ``tearcloth clusters``).

Each measure's per-step time is ``detector.stats['ms']['total']`` (wall: measure + incremental + full +
contacts + swept; ``*_cpu_ms`` the process's CPU time of the same calls), after ``warmup`` steps, so the one-off clustering and first scene builds are not
counted (they are reported separately as ``setup_ms``). Dev-only (not in the extension zip).
"""
from __future__ import annotations

import time

import numpy as np
from scipy.spatial import cKDTree

from .. import examples
from .. import settings as _settings
from ..collision.detector import CollisionDetector
from .table1 import DT

_SESSION_THICKNESS = _settings.default("collision", "thickness")
_SESSION_THRESHOLD = _settings.default("collision", "displacement_threshold")


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
    """Mean per-step detection time (ms) of the three measures on one scene.

    ``body_vertices_fn(step)`` returns the body's vertices (nb,3) at that step, or a pair
    (body_vertices, cloth_vertices) when the scene moves the cloth as well (the cloth then
    follows the body: the case the relative measure is made for). Returns a dict with
    ``full_ms``, ``absolute_ms``, ``relative_ms`` (means; ``*_median_ms`` the medians), ``full_share`` (mean share of
    close pairs fully detected per step with the relative measure), ``absolute_full_share``,
    and per-measure breakdowns (``phases``: mean ms of each phase) and ``close_pairs``.
    """
    cloth_vertices = np.asarray(cloth_vertices, np.float64)
    cloth_triangles = np.asarray(cloth_triangles, np.int32)
    frames = []
    for k in range(steps):
        out = body_vertices_fn(k)
        if isinstance(out, _Recorded):
            frames.append(out)
        elif isinstance(out, tuple):
            frames.append(_Recorded(np.asarray(out[0], np.float64), np.asarray(out[1], np.float64), cloth_triangles))
        else:
            frames.append(_Recorded(np.asarray(out, np.float64), cloth_vertices, cloth_triangles))
    result = {}
    # the variants step interleaved (one frame each in turn) so that the machine's load hits them
    # alike; 'relative' is the detector's default (the paper's trip rule, eqs. 1-4 against the
    # threshold), 'bound' the relative measure with the motion-bound trip rule of measure.py
    variants = {"full": ("full", "paper"), "absolute": ("absolute", "paper"), "relative": ("relative", "paper"),
                "bound": ("relative", "bound")}
    dets, setups = {}, {}
    for name, (measure, rule) in variants.items():
        t0 = time.perf_counter()
        det = CollisionDetector(thickness, 0.3, displacement_threshold, cluster_size, measure, self_collision,
                                trip_rule=rule)
        det.add_body(frames[0].body, body_triangles, "body")
        det.set_cloth(frames[0].cloth, frames[0].triangles)
        dets[name], setups[name] = det, 1e3 * (time.perf_counter() - t0)
    rec = {name: {"totals": [], "cpu": [], "shares": [], "close": [], "contacts": [],
                  "phases": {"measure": [], "incremental": [], "full": [], "contacts": []}} for name in variants}
    for k, fr in enumerate(frames):
        for name, det in dets.items():
            det.update_body("body", fr.body, fr.body_velocity)
            cpu = time.process_time()
            c = det.detect(fr.cloth, fr.triangles, fr.velocity, fr.dt)
            cpu = time.process_time() - cpu
            if fr.events is not None:  # the tear of this step, as the session hands it on
                det.on_topology(fr.events, fr.after, fr.after_triangles)
            if k < warmup:
                continue
            st, r = det.stats, rec[name]
            r["totals"].append(st["ms"]["total"])
            r["cpu"].append(1e3 * cpu)
            r["shares"].append(st["full_share"])
            r["close"].append(st["close_pairs"])
            r["contacts"].append(len(c))
            for p in r["phases"]:
                r["phases"][p].append(st["ms"][p])
    for measure, r in rec.items():
        # the mean: full detections come in bursts (most steps only walk their tracks), and a
        # median would hide them; the median is reported beside it
        result[f"{measure}_ms"] = float(np.mean(r["totals"]))
        result[f"{measure}_median_ms"] = float(np.median(r["totals"]))
        # CPU time of the same calls (the process's, all threads: the swept stage's worker too): what a
        # loaded machine's wall clock does not add to it
        result[f"{measure}_cpu_ms"] = float(np.mean(r["cpu"]))
        result[f"{measure}_phases"] = {p: float(np.mean(v)) for p, v in r["phases"].items()}
        result[f"{measure}_share"] = float(np.mean(r["shares"]))
        result[f"{measure}_setup_ms"] = setups[measure]
        result[f"{measure}_contacts"] = float(np.median(r["contacts"]))
    result["close_pairs"] = float(np.median(rec["relative"]["close"]))
    result["contacts"] = result["relative_contacts"]
    result["full_share"] = result["relative_share"]
    result["absolute_full_share"] = result["absolute_share"]
    return result


class _Recorded:
    """One step of a replayed scene: what the detector is given at its start (body vertices and
    velocities, cloth positions, velocities, triangles) and, when the step tore the cloth, the
    events with the positions and triangles after it (``on_topology``'s arguments), and the step's
    dt (s; the swept stage sweeps over it)."""

    __slots__ = ("body", "cloth", "triangles", "body_velocity", "velocity", "events", "after", "after_triangles",
                 "dt")

    def __init__(self, body, cloth, triangles, body_velocity=None, velocity=None, events=None, after=None,
                 after_triangles=None, dt=None):
        self.body, self.cloth, self.triangles = body, cloth, triangles
        self.body_velocity, self.velocity = body_velocity, velocity
        self.events, self.after, self.after_triangles = events, after, after_triangles
        self.dt = dt


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


class _Recording:
    """Stands in for a session's detector and records what the session hands it each step (the
    detector still does the work, so the simulation is the one the artist gets)."""

    def __init__(self, detector):
        self._det = detector
        self.steps = []
        self._body = self._body_vel = None
        self.detect_ms = []
        self.full_share = []

    def __getattr__(self, name):
        return getattr(self._det, name)

    def update_body(self, name, vertices, velocities=None):
        self._body = np.array(vertices, np.float64)
        self._body_vel = None if velocities is None else np.array(velocities, np.float64)
        return self._det.update_body(name, vertices, velocities)

    def detect(self, positions, triangles, velocities=None, dt=None):
        self.steps.append(_Recorded(self._body, np.array(positions, np.float64), np.array(triangles, np.int32),
                                    self._body_vel, None if velocities is None else np.array(velocities, np.float64),
                                    dt=dt))
        out = self._det.detect(positions, triangles, velocities, dt)
        self.detect_ms.append(self._det.stats["ms"]["total"])
        self.full_share.append(self._det.stats["full_share"])
        return out

    def on_topology(self, events, positions, triangles):
        last = self.steps[-1]
        last.events = {k: np.array(events.get(k, np.zeros(0))) for k in
                       ("new_vertices", "parents", "weights", "changed_triangles", "new_triangles", "tips")}
        last.after, last.after_triangles = np.array(positions, np.float64), np.array(triangles, np.int32)
        return self._det.on_topology(events, positions, triangles)


# The walking case's root travel: the mannequin walks forward (-Y, its front) at this speed (m/s, a
# slow human walk), reached over WALK_RAMP_S seconds from rest so the worn shirt is carried along by
# its contacts rather than struck; its recording starts once the speed is reached.
WALK_SPEED = 1.2
WALK_RAMP_S = 0.2


def root_travel(t: float, speed: float = WALK_SPEED, ramp: float = WALK_RAMP_S) -> np.ndarray:
    """The body's root offset (m) at time t (s) of a walk that accelerates uniformly from rest to
    ``speed`` over ``ramp`` seconds, then keeps it: (0, -s(t), 0)."""
    s = speed * t * t / (2.0 * ramp) if t < ramp else speed * (t - 0.5 * ramp)
    return np.array([0.0, -s, 0.0])


def simulate_worn_shirt(dt, steps, moving, *, settle_s=0.1, fps=24, start_time=0.0, body=None, shirt=None,
                        travel=False):
    """The T-shirt simulated on the mannequin (cotton, tearing on, the default CollisionSettings:
    body and self-collision), the body walking (``moving``) or held at its start pose. The shirt
    first settles onto the shoulders for ``settle_s`` seconds (not recorded), then ``steps`` steps
    of ``dt`` seconds are recorded. The body is keyed once per ``fps`` frame, as an animation
    reaches a bake. Returns (body, shirt, recorded steps, the session's own detection ms per
    recorded step, its share of close pairs fully detected per step, tears). ``travel``: the body
    also walks forward (``root_travel``; the shirt is recorded after WALK_RAMP_S of settling, when
    the speed is reached), the case where the body and the shirt move a lot in the world and little
    relative to each other - the paper's "moving character". A step the core rolls
    back even at its finest sub-steps (SimulationError) ends the run there: what was recorded is
    returned and the error kept in ``LAST_STOP`` (the bench prints it beside the figures), so one
    scene that blows up does not take the whole bench down with it, and never passes unseen."""
    from ..cloth import Cloth, SimulationError
    from ..materials import material
    from ..session import CollisionSettings, Session

    LAST_STOP.clear()

    body = body if body is not None else examples.mannequin()
    shirt = shirt if shirt is not None else examples.tshirt(body)
    cloth = Cloth(shirt.vertices, shirt.triangles, material("cotton"), uv=shirt.loop_uv(), groups=shirt.groups)
    cloth.set_tearing(True)
    session = Session(cloth, CollisionSettings(), start_time=0.0)
    session.add_body("body", examples.body_pose(body, start_time), body.triangles)
    rec = _Recording(session.detector)
    session.detector = rec
    if travel:
        settle_s = max(settle_s, WALK_RAMP_S)
    settle = int(round(settle_s / dt))
    keyed = 0.0
    for k in range(settle + steps):
        t_end = (k + 1) * dt
        while moving and keyed < t_end + 1e-12:
            keyed += 1.0 / fps
            pose = examples.body_pose(body, start_time + keyed)
            session.set_body_keyframe("body", pose + root_travel(keyed) if travel else pose, keyed)
        if k == settle:
            rec.steps.clear()
            rec.detect_ms.clear()
            rec.full_share.clear()
        try:
            session.step(dt)
        except SimulationError as exc:
            if k < settle + 2:
                raise  # nothing to measure
            del rec.steps[-1]  # detected, but its step rolled back: not a step of the run
            del rec.detect_ms[-1], rec.full_share[-1]
            LAST_STOP.update(step=k - settle, of=steps, dt_s=dt, moving=moving, error=str(exc))
            break
    return body, shirt, rec.steps, rec.detect_ms, rec.full_share, int(cloth.stats().get("tears_started", 0))


# How the last simulate_worn_shirt run ended early, if it did (step, of, dt_s, moving, error); empty
# when it ran all its steps.
LAST_STOP: dict = {}


SIMULATED_CASES = {"dt1ms": 1e-3, "frame10": 1.0 / 24 / 10}
# the body's motion per case: (walk cycle on, root travel on). 'moving' walks in place (the body's
# limbs swing, its root stays: the scene stays framed); 'walking' also travels forward at WALK_SPEED,
# the paper's moving character: the shirt and the body move far in the world and little relative to
# each other, what the absolute measure pays for and the relative one does not.
MOTIONS = {"immobile": (False, False), "moving": (True, False), "walking": (True, True)}


def simulated_figures(steps: int = 120, cases=SIMULATED_CASES, body=None, shirt=None) -> dict:
    """The paper's experiment on the simulated shirt (module docs): per case (dt) and motion the
    mean ms per step of full / absolute / relative detection, the share of close pairs fully
    detected with the relative measure, and the session's own detection time in the recorded run."""
    body = body if body is not None else examples.mannequin()
    shirt = shirt if shirt is not None else examples.tshirt(body)
    out = {"triangles": int(len(shirt.triangles)), "body_triangles": int(len(body.triangles)), "steps": steps}
    for case, dt in cases.items():
        out[case] = {"dt_s": dt}
        for name, (moving, travel) in MOTIONS.items():
            _, _, rec, own_ms, own_share, tears = simulate_worn_shirt(dt, steps, moving, body=body, shirt=shirt,
                                                                       travel=travel)
            stopped = dict(LAST_STOP)
            first = rec[0]
            r = collision_experiment(first.cloth, first.triangles, lambda k, rec=rec: rec[k], len(rec),
                                     body_triangles=body.triangles, thickness=_SESSION_THICKNESS,
                                     displacement_threshold=_SESSION_THRESHOLD)
            row = {k: r[k] for k in ("full_ms", "absolute_ms", "relative_ms", "full_share")}
            row["absolute_full_share"] = r["absolute_full_share"]
            row["absolute_over_relative"] = r["absolute_ms"] / r["relative_ms"] if r["relative_ms"] > 0 else float("inf")
            row["relative_phases"] = r["relative_phases"]
            row["relative_median_ms"] = r["relative_median_ms"]
            for m in ("full", "absolute", "relative"):
                row[f"{m}_cpu_ms"] = r[f"{m}_cpu_ms"]
            row["absolute_over_relative_cpu"] = (r["absolute_cpu_ms"] / r["relative_cpu_ms"]
                                                 if r["relative_cpu_ms"] > 0 else float("inf"))
            # the motion-bound trip rule on the same replay, interleaved with the others (measure.py)
            row["bound_rule_ms"] = r["bound_ms"]
            row["bound_rule_full_share"] = r["bound_share"]
            row["bound_rule_over_relative"] = r["bound_ms"] / r["relative_ms"] if r["relative_ms"] > 0 else float("inf")
            row["session_detect_ms"] = float(np.mean(own_ms))
            row["session_full_share"] = float(np.mean(own_share))
            row["tears"] = tears
            row["recorded_steps"] = len(rec)
            if stopped:  # the simulation blew up: these figures cover the steps before it
                row["stopped"] = stopped
            row["contacts"] = r["contacts"]
            out[case][name] = row
    return out


def rigid_skinned_figures(steps: int = 120, dt: float = DT) -> dict:
    """The former experiment, labelled for what it is: the shirt skinned rigidly to the body
    (each shirt vertex follows its nearest body vertex's skin weights: no relative motion, no
    deformation), 4 mm thickness, 3 mm threshold."""
    body, shirt, pose = worn_shirt()
    out = {"triangles": int(len(shirt.triangles)), "body_triangles": int(len(body.triangles)), "steps": steps,
           "what": "shirt skinned rigidly to the body (not simulated)"}
    t0 = 0.5  # mid-stride
    frames_immobile = lambda k: (examples.body_pose(body, t0), pose(t0))  # noqa: E731
    frames_moving = lambda k: (examples.body_pose(body, t0 + k * dt), pose(t0 + k * dt))  # noqa: E731
    for name, fn in (("immobile", frames_immobile), ("moving", frames_moving)):
        r = collision_experiment(shirt.vertices, shirt.triangles, fn, steps, body_triangles=body.triangles,
                                 thickness=0.004, displacement_threshold=0.003)
        out[name] = {k: r[k] for k in ("full_ms", "absolute_ms", "relative_ms")}
        out[name]["full_share"] = r["full_share"]
        out[name]["absolute_full_share"] = r["absolute_full_share"]
        out[name]["absolute_over_relative"] = r["absolute_ms"] / r["relative_ms"]
    return out


def collision_figures(steps: int = 120, dt: float = DT) -> dict:
    """Both experiments: ``simulated`` (the paper's) and ``rigid_skinned`` (the former one)."""
    return {"simulated": simulated_figures(steps), "rigid_skinned": rigid_skinned_figures(steps, dt)}


PAPER_COLLISION = {"immobile": {"absolute_ms": 3.65, "relative_ms": 3.37},
                   "moving": {"absolute_ms": 11.76, "relative_ms": 3.18}}
PAPER_COLLISION["walking"] = PAPER_COLLISION["moving"]  # the paper has one moving case


def format_collision(c: dict) -> str:
    """Both experiments as text tables (mean ms per step)."""
    def table(title, cases):
        rows = [title, f"{'':<18} {'full':>8} {'absolute':>9} {'(paper)':>8} {'relative':>9} {'(paper)':>8} "
                       f"{'abs/rel':>8} {'full share':>11} {'bound rule':>11} {'its share':>10}"]
        for label, r, name in cases:
            p = PAPER_COLLISION[name]
            rows.append(f"{label:<18} {r['full_ms']:>8.2f} {r['absolute_ms']:>9.2f} {p['absolute_ms']:>8.2f} "
                        f"{r['relative_ms']:>9.2f} {p['relative_ms']:>8.2f} {r['absolute_over_relative']:>8.2f} "
                        f"{r['full_share']:>11.3f} {r.get('bound_rule_ms', float('nan')):>11.2f} "
                        f"{r.get('bound_rule_full_share', float('nan')):>10.3f}")
        return rows

    sim, rig = c["simulated"], c["rigid_skinned"]
    rows = table(f"collision, T-shirt ({sim['triangles']} triangles) SIMULATED on the mannequin "
                 f"({sim['body_triangles']}), mean ms per step over {sim['steps']} steps",
                 [(f"{case} {name}", sim[case][name], name) for case in SIMULATED_CASES if case in sim
                  for name in MOTIONS if name in sim[case]])
    rows.append(f"  moving: walking in place; walking: also travelling forward at {WALK_SPEED} m/s (root travel)")
    for case in SIMULATED_CASES:
        for name in MOTIONS:
            st = sim.get(case, {}).get(name, {}).get("stopped")
            if st:
                rows.append(f"  {case} {name}: the simulation stopped at recorded step {st['step']} of {st['of']} "
                            f"({st['error'][:120]}); its figures cover the steps before")
    rows += table("collision, the shirt skinned rigidly to the body (not simulated; the former experiment)",
                  [(name, rig[name], name) for name in ("immobile", "moving")])
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
