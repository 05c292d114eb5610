"""Race against Blender's built-in cloth (issue 8, part 1): the same T-shirt, the same walking body,
the same two hands pulling the hem apart, the same number of sub-steps per frame - seconds per
frame for each, measured in one process.

This file owns the race's plan and our side of it: the mapping of our material onto Blender's
cloth settings (``blender_cloth_settings``, pure, no bpy), the hands' offsets, our simulation
frame by frame (``_Ours``), ``race_blender_cloth`` (which hands the arrays to
``tearcloth.blender.race.race_frames``, the one file that drives Blender's cloth through bpy)
and ``format_race``. Dev-only (not in the extension zip).

    from tearcloth.bench.race import race_blender_cloth
    r = race_blender_cloth(frames=24, substeps=10)
    r["ours_s_per_frame"], r["blender_s_per_frame"], r["ratio"]   # ratio = ours / Blender

What runs on each side
----------------------
Scene: ``examples.tshirt()`` worn by ``examples.mannequin()``; the body walks (``examples.body_pose``,
frame f at time start_time + (f - 1) / fps); the front hem is grabbed by two hands (vertex groups
``hem_left`` at +X and ``hem_right`` at -X) that move apart along X at ``pull_speed`` m/s each.

Ours: ``Session(Cloth(cotton, tear_stress), CollisionSettings(thickness, friction,
self_collision))``, the body added with ``add_body`` and keyed every frame with
``set_body_keyframe(body_pose(t))``, the hands keyed with ``set_handle_keyframe`` every frame;
``substeps`` steps of dt = 1 / fps / substeps per frame, tearing ON. A frame's time covers
everything ours needs for it: the pose (numpy skinning), collision detection, the FEM step, tearing.

Blender (``blender/race.py``, through ``bpy``, headless, after ``read_factory_settings(use_empty=True)``):
- body: a mesh with an ARMATURE rebuilt from ``Body.bones`` (head, tail, roll 0, parents) and
  the skin weights as one vertex group per bone, an Armature modifier (linear blend skinning,
  volume preservation off), then a Collision modifier. Every frame each pose bone gets a
  rotation keyframe chosen so that Blender's skinning reproduces ``body_pose`` exactly (checked:
  the largest difference is reported as ``body_pose_error_m``, float32 round-off).
- shirt: the same vertices and triangles; two Hook modifiers (groups ``hem_left`` /
  ``hem_right``) to two empties keyed every frame with the hands' offsets; then the Cloth
  modifier, with the union of both groups as its pin group (weight 1 = hard pinned: the hem
  follows the hooks exactly, as our handles do).
- Blender's cloth computes on frame change: ``scene.frame_set(f)`` for f = 2 .. frames + 1
  after ``frame_set(1)`` (the start frame, where the cloth is initialised). The point cache is
  freed before the run, so every timed frame is simulated, not replayed; afterwards the raced
  frames are set again to show what a cache replay costs (``blender_replay_s_per_frame``).

Frames are interleaved (Blender frame f, then ours frame f) so that load from other processes on
a shared machine hits both sides alike; each side's CPU seconds per frame (the whole process, all
threads) are reported next to the wall seconds.

Mapping our cotton onto Blender's model (``blender_cloth_settings``; Blender 2.9-5.x source,
``SIM_mass_spring.cc`` / ``implicit_blender.cc``): Blender's cloth works in frames (dt = 1 /
quality, velocities in m/frame), so a physical force F (N) is F / fps^2 there, a damping
coefficient c (kg/s) is c / fps, and gravity is ``scene.gravity * 0.001`` m/frame^2.
- quality (steps per frame) = our sub-steps per frame.
- mass (kg per vertex, uniform) = areal mass * area / vertices (total mass equal to ours).
- tension = compression = shear stiffness: a triangle lattice of edge springs k has the
  membrane modulus E h = 2 k / sqrt(3) (Poisson 1/3), so k = sqrt(3) / 2 * E h (N/m); Blender's
  spring constant is stiffness / (mean edge length L), hence stiffness = k * L / fps^2.
  (Blender makes no shear springs on triangles; the value matters only for quads.)
- tension / compression / shear damping = Rayleigh beta * k / fps (Blender's spring dashpots).
- air_damping = 100 * Rayleigh alpha * vertex mass / fps (Blender's drag is -0.01 * air_damping
  * v per vertex, not scaled by mass; our mass-proportional damping is -alpha * m * v).
- bending (angular model): a hinge of a plate with rigidity D between two equilateral
  triangles has a torque stiffness 3 D l^2 / (A1 + A2) = 2 sqrt(3) D; Blender pushes the two
  wing vertices with force stiffness * 0.1 * l * angle at a lever arm of sqrt(3) / 2 * l, so
  bending_stiffness = 40 D / (L^2 fps^2); bending_damping = beta * 4 D / L^2 / fps alike.
- gravity: scene.gravity = 9.81 * 1000 / fps^2 m/s^2 (so that Blender's 0.001 scaling gives
  9.81 m/s^2 at this frame rate; checked by a free fall).
- collisions: cloth distance_min + body thickness_outer = our contact thickness (half each, at
  least Blender's 1 mm minimum); self_distance_min = our thickness; Blender's friction values are
  percent of a Coulomb coefficient (x 0.01 in its collision response), so body cloth_friction
  and self_friction = 100 * our friction; use_self_collision = our self_collision;
  collision_quality (collision passes per step) as given (default 2, Blender's default: our
  contacts are constraints inside each implicit step, Blender's are impulses after it, which
  needs more than one pass to keep the cloth out of a moving body).
"""
from __future__ import annotations

import math
import os
import platform
import statistics
import time

import numpy as np

from .. import examples
from ..cloth import Cloth, SimulationError
from ..materials import Material, material
from ..session import CollisionSettings, Session
from .machine import loadavg

FPS = 24
PULL_SPEED = 0.05  # m/s per hand, apart along X
TEAR_STRESS = 3.0e7  # Pa: above the walk's own peaks, reached between the pulling hands
GRAVITY = 9.81
BLENDER_GRAVITY_SCALE = 0.001  # Blender's cloth multiplies scene gravity by this (SIM_mass_spring.cc)
BLENDER_STIFFNESS_MAX = 10000.0  # RNA limits of ClothSettings
BLENDER_DAMPING_MAX = 50.0
BLENDER_AIR_DAMPING_MAX = 10.0
BLENDER_MIN_DISTANCE = 0.001


# ------------------------------------------------------------------------------------------------
# The mapping of our material onto Blender's cloth settings (pure: no bpy)
# ------------------------------------------------------------------------------------------------


def mean_edge_length(vertices, triangles) -> float:
    """Mean rest length of the mesh's unique edges (Blender's ``avg_spring_len``)."""
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    e = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    e = np.unique(e, axis=0)
    return float(np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1).mean())


def blender_cloth_settings(mat: Material, vertices, triangles, fps: int = FPS, substeps: int = 10,
                           collision: CollisionSettings | None = None, collision_quality: int = 2) -> dict:
    """Blender property values that reproduce ``mat`` on this mesh (see the module docs for the
    derivations). Returns {"cloth": ClothSettings, "collision": ClothCollisionSettings,
    "body_collision": the body's CollisionSettings, "scene": scene settings, "derived": the
    physical intermediates}; values clamped to Blender's limits are listed in "clamped"."""
    collision = collision or CollisionSettings()
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    L = mean_edge_length(v, t)
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    area = float(0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())
    m_vertex = mat.areal_mass * area / len(v)
    k_edge = math.sqrt(3.0) / 2.0 * mat.young * mat.thickness  # N/m per edge spring
    f2 = float(fps) ** 2
    raw = {
        "tension_stiffness": k_edge * L / f2,
        "tension_damping": mat.damping_stiffness * k_edge / fps,
        "bending_stiffness": 40.0 * mat.bending / (L * L * f2),
        "bending_damping": mat.damping_stiffness * 4.0 * mat.bending / (L * L) / fps,
        "air_damping": 100.0 * mat.damping_mass * m_vertex / fps,
    }
    limits = {"tension_stiffness": BLENDER_STIFFNESS_MAX, "tension_damping": BLENDER_DAMPING_MAX,
              "bending_stiffness": BLENDER_STIFFNESS_MAX, "bending_damping": 1000.0,
              "air_damping": BLENDER_AIR_DAMPING_MAX}
    clamped = [k for k, x in raw.items() if x > limits[k]]
    val = {k: min(x, limits[k]) for k, x in raw.items()}
    half = max(BLENDER_MIN_DISTANCE, collision.thickness / 2.0)
    cloth = {
        "quality": int(substeps),
        "time_scale": 1.0,
        "mass": m_vertex,
        "tension_stiffness": val["tension_stiffness"],
        "compression_stiffness": val["tension_stiffness"],
        "shear_stiffness": val["tension_stiffness"],
        "tension_damping": val["tension_damping"],
        "compression_damping": val["tension_damping"],
        "shear_damping": val["tension_damping"],
        "bending_model": "ANGULAR",
        "bending_stiffness": val["bending_stiffness"],
        "bending_damping": val["bending_damping"],
        "air_damping": val["air_damping"],
        "vertex_group_mass": "pin",
        "pin_stiffness": 1.0,
        "use_internal_springs": False,
        "use_pressure": False,
        "use_sewing_springs": False,
    }
    coll = {
        "use_collision": True,
        "distance_min": half,
        "collision_quality": int(collision_quality),
        "use_self_collision": bool(collision.self_collision),
        "self_distance_min": min(0.1, max(BLENDER_MIN_DISTANCE, collision.thickness)),
        "self_friction": 100.0 * collision.friction,
        "friction": 100.0 * collision.friction,
    }
    body = {"thickness_outer": half, "cloth_friction": 100.0 * collision.friction}
    scene = {"fps": int(fps), "gravity": (0.0, 0.0, -GRAVITY / (BLENDER_GRAVITY_SCALE * f2))}
    derived = {"mean_edge_length_m": L, "area_m2": area, "vertex_mass_kg": m_vertex,
               "edge_spring_N_per_m": k_edge, "bending_rigidity_N_m": mat.bending,
               "rayleigh_alpha_per_s": mat.damping_mass, "rayleigh_beta_s": mat.damping_stiffness}
    return {"cloth": cloth, "collision": coll, "body_collision": body, "scene": scene, "derived": derived,
            "clamped": clamped}


# ------------------------------------------------------------------------------------------------
# The hands: offsets of the two hem groups at time t
# ------------------------------------------------------------------------------------------------


def hand_offsets(t: float, pull_speed: float) -> tuple[np.ndarray, np.ndarray]:
    """(offset of hem_left, offset of hem_right) in metres at time t (s) from the race start:
    hem_left sits at +X and moves +X, hem_right at -X moves -X."""
    d = pull_speed * max(0.0, float(t))
    return np.array([d, 0.0, 0.0]), np.array([-d, 0.0, 0.0])


def _translation(offset) -> np.ndarray:
    m = np.eye(3, 4)
    m[:, 3] = offset
    return m


# ------------------------------------------------------------------------------------------------
# Ours
# ------------------------------------------------------------------------------------------------


class _Ours:
    """Our side of the race: one frame at a time."""

    def __init__(self, shirt, body, mat, collision, fps, substeps, pull_speed, start_time):
        self.body = body
        self.fps, self.substeps = fps, substeps
        self.dt = 1.0 / fps / substeps
        self.pull_speed, self.start_time = pull_speed, start_time
        self.cloth = Cloth(shirt.vertices, shirt.triangles, mat, uv=shirt.loop_uv(), groups=shirt.groups)
        self.hands = (self.cloth.add_handle("hem_left"), self.cloth.add_handle("hem_right"))
        self.cloth.set_tearing(True)
        self.session = Session(self.cloth, collision)
        self.session.add_body("body", examples.body_pose(body, start_time), body.triangles)
        for h, off in zip(self.hands, hand_offsets(0.0, pull_speed)):
            self.session.set_handle_keyframe(h, _translation(off), 0.0)
        self.parts = {"pose": 0.0, "collision": 0.0, "fem": 0.0, "tearing": 0.0}
        self.cg_iterations = []
        self.solves = []  # linear solves per sub-step: one, more when contacts changed state (rounds)
        self.contacts = []
        self.full_share = []  # share of close cluster pairs fully detected, per sub-step
        self.cpu_s = 0.0

    def frame(self, f: int) -> float:
        """Simulate frame f (f >= 2; frame 1 is the start). Returns wall seconds (CPU seconds of
        the process are added to ``cpu_s``)."""
        t = (f - 1) / self.fps  # race time; the body's clock is start_time + t
        c0 = time.process_time()
        t0 = time.perf_counter()
        pose = examples.body_pose(self.body, self.start_time + t)
        t1 = time.perf_counter()
        self.session.set_body_keyframe("body", pose, t)
        for h, off in zip(self.hands, hand_offsets(t, self.pull_speed)):
            self.session.set_handle_keyframe(h, _translation(off), t)
        parts, iters, solves, contacts = {"collision": 0.0, "fem": 0.0, "tearing": 0.0}, [], [], []
        for _ in range(self.substeps):
            rep = self.session.step(self.dt)  # a SimulationError leaves the totals untouched
            parts["collision"] += rep.collision_s
            parts["fem"] += rep.fem_s
            parts["tearing"] += rep.tearing_s
            st = self.cloth.stats()
            iters.append(st["cg_iterations"])
            solves.append(st["solves"])
            contacts.append(rep.contacts)
            self.full_share.append(float(self.session.detector.stats.get("full_share", float("nan"))))
        t2 = time.perf_counter()
        self.cpu_s += time.process_time() - c0
        self.parts["pose"] += t1 - t0
        for k, v in parts.items():
            self.parts[k] += v
        self.cg_iterations += iters
        self.solves += solves
        self.contacts += contacts
        return t2 - t0


# ------------------------------------------------------------------------------------------------
# The race
# ------------------------------------------------------------------------------------------------


def penetration(body_vertices, body_triangles, shirt_vertices) -> tuple[float, int]:
    """(deepest shirt vertex inside the closed body in metres, 0.0 when none; vertices inside),
    by exact signed distance to the body surface (``examples.closest_points``)."""
    _, sd, _ = examples.closest_points(np.asarray(body_vertices, np.float64), body_triangles,
                                       np.asarray(shirt_vertices, np.float64))
    inside = sd < 0
    return (float(-sd[inside].min()) if inside.any() else 0.0), int(inside.sum())


def race_blender_cloth(frames: int = 24, substeps: int = 10, *, fps: int = FPS, pull_speed: float = PULL_SPEED,
                       tear_stress: float = TEAR_STRESS, target_triangles: int = 3300,
                       collision_quality: int = 2, collision: CollisionSettings | None = None,
                       start_time: float = 0.0, shirt=None, body=None, out=None) -> dict:
    """Seconds per frame of ours (tearing on) and of Blender's cloth (which cannot tear) on the same
    scene; see the module docs for what each side runs and how our cotton maps onto Blender.

    Returns ours_s_per_frame, blender_s_per_frame (means over the raced frames), ratio (ours /
    Blender: below 1 means ours is faster), settings (the exact Blender property values, ours, and
    the mapping's intermediates), and diagnostics: per-frame times and medians, our split (pose,
    collision, FEM, tearing), tears and cuts made, CG iterations on both sides, the body pose
    error of Blender's armature, the cost of a cache replay. If our simulation gives up on a
    step (SimulationError), the race stops there: ``ours_error`` says so and both means cover the
    frames raced until then.
    """
    if frames < 1 or substeps < 1:
        raise ValueError("frames and substeps must be at least 1")
    say = out or (lambda *_: None)
    wall0 = time.perf_counter()
    body = body if body is not None else examples.mannequin()
    shirt = shirt if shirt is not None else examples.tshirt(body, target_triangles=target_triangles)
    mat = material("cotton", tear_stress=tear_stress)
    collision = collision or CollisionSettings()
    settings = blender_cloth_settings(mat, shirt.vertices, shirt.triangles, fps, substeps, collision,
                                      collision_quality)
    from ..blender.race import race_frames  # bpy: only the race itself needs Blender

    ours = _Ours(shirt, body, mat, collision, fps, substeps, pull_speed, start_time)
    t_ours = []
    error = None

    def our_frame(f, blender_s):
        nonlocal error
        try:
            t_ours.append(ours.frame(f))
        except SimulationError as e:
            error = f"frame {f}: {e}"
            say(f"ours gave up at {error}")
            return False
        say(f"frame {f}: ours {t_ours[-1]:.3f} s, Blender {blender_s:.3f} s")
        return True

    race_t = [(f - 1) / fps for f in range(1, frames + 2)]  # frames 1 .. frames + 1; the body's clock adds start_time
    check = sorted({1, frames + 1, 1 + frames // 2})
    got = race_frames(
        body_vertices=body.vertices, body_triangles=body.triangles, bones=body.bones, weights=body.weights,
        bone_matrices=np.stack([examples.bone_matrices(body, start_time + t) for t in race_t]),
        shirt_vertices=shirt.vertices, shirt_triangles=shirt.triangles, shirt_groups=shirt.groups,
        hand_offsets=np.array([hand_offsets(t, pull_speed) for t in race_t]),
        settings=settings, frames=frames, fps=fps, check_frames=check, after_frame=our_frame, say=say)
    pose_err = max(float(np.abs(got["body_vertices"][f] - examples.body_pose(body, start_time + (f - 1) / fps)).max())
                   for f in check)
    raced = len(t_ours)
    # penetration after the race, each side against the body at its own last frame (Blender's
    # skinned body as Blender evaluated it; ours as we posed it)
    pen_ours = penetration(examples.body_pose(body, start_time + raced / fps), body.triangles, ours.cloth.positions)
    pen_bl = penetration(got["body_vertices"][frames + 1], body.triangles, got["shirt_end"])
    t_bl = got["frame_s"]
    moved = float(np.abs(got["shirt_end"] - got["shirt_rest"]).max())
    replay = got["replay_s_per_frame"]
    st = ours.cloth.stats()
    ours_mean = sum(t_ours) / raced if raced else float("nan")
    bl_mean = sum(t_bl[:raced]) / raced if raced else float("nan")
    bl_iters = [a for a, _m in got["iterations"][:raced]]
    result = {
        "ours_s_per_frame": ours_mean,
        "blender_s_per_frame": bl_mean,
        "ratio": ours_mean / bl_mean if raced else float("nan"),
        "ours_s_per_frame_median": statistics.median(t_ours) if raced else float("nan"),
        # deepest shirt vertex inside the body (m, 0 when none) and how many are inside, last frame
        "ours_penetration_max_m": pen_ours[0],
        "ours_vertices_inside": pen_ours[1],
        "blender_penetration_max_m": pen_bl[0],
        "blender_vertices_inside": pen_bl[1],
        "ours_collision_share_of_substep": (ours.parts["collision"] / sum(v for k, v in ours.parts.items() if k != "pose")
                                            if raced and sum(ours.parts.values()) > 0 else float("nan")),
        # CPU seconds of the whole process per frame: above the wall time, a side used several
        # cores (ours steps on one thread; Blender's collision and BVH code may use more)
        "ours_cpu_s_per_frame": ours.cpu_s / raced if raced else float("nan"),
        "blender_cpu_s_per_frame": sum(got["cpu_s"][:raced]) / raced if raced else float("nan"),
        "cpu_ratio": ((ours.cpu_s / raced) / (sum(got["cpu_s"][:raced]) / raced)
                      if raced and sum(got["cpu_s"][:raced]) > 0 else float("nan")),
        # collision: the share of close cluster pairs that got full detection, mean over sub-steps
        "ours_full_share": statistics.fmean(ours.full_share) if ours.full_share else float("nan"),
        "blender_s_per_frame_median": statistics.median(t_bl[:raced]) if raced else float("nan"),
        "frames": frames,
        "frames_raced": raced,
        "substeps": substeps,
        "fps": fps,
        "dt_s": 1.0 / fps / substeps,
        "triangles": int(len(shirt.triangles)),
        "vertices": int(len(shirt.vertices)),
        "body_triangles": int(len(body.triangles)),
        "body_animation": "armature (bones from Body.bones, skin weights as vertex groups, "
                          "Armature modifier, rotation keyframes every frame)",
        "body_pose_error_m": pose_err,
        "ours_per_frame_s": t_ours,
        "blender_per_frame_s": t_bl[:raced],
        "ours_split_s_per_frame": {k: v / max(1, raced) for k, v in ours.parts.items()},
        "ours_tears_started": int(st.get("tears_started", 0)),
        "ours_cuts": int(st.get("cuts", 0)),
        "ours_triangles_end": int(ours.cloth.num_triangles),
        "ours_step_retries": int(ours.session.retries),
        "ours_cg_iterations_median": statistics.median(ours.cg_iterations) if ours.cg_iterations else 0,
        "ours_solves_per_substep_mean": statistics.fmean(ours.solves) if ours.solves else 0,
        "ours_rotation_solves": int(st.get("rotation_solves", 0)),
        "ours_rotations_capped": int(st.get("rotations_capped", 0)),
        "ours_contacts_median": statistics.median(ours.contacts) if ours.contacts else 0,
        "ours_error": error,
        "blender_cg_iterations_mean": statistics.fmean(bl_iters) if bl_iters else None,
        "blender_cg_iterations_max": max((m for _a, m in got["iterations"][:raced]), default=None),
        "blender_shirt_moved_m": moved,
        "blender_replay_s_per_frame": replay,
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                    "blender": got["blender_version"], "load_average": loadavg()},
        "wall_s": time.perf_counter() - wall0,
        "settings": {
            "blender": {"cloth": settings["cloth"], "collision": settings["collision"],
                        "body_collision": settings["body_collision"], "scene": settings["scene"],
                        "clamped_to_blender_limits": settings["clamped"]},
            "ours": {"material": dict(mat.__dict__), "collision": dict(collision.__dict__),
                     "tearing": True, "substeps_per_frame": substeps, "handles": ["hem_left", "hem_right"]},
            "scene": {"pull_speed_m_per_s": pull_speed, "start_time_s": start_time,
                      "motion": "walk in place (examples.body_pose)", "shirt": "examples.tshirt",
                      "body": "examples.mannequin"},
            "mapping": settings["derived"],
        },
    }
    return result


def format_race(r: dict) -> str:
    bl = r["settings"]["blender"]
    lines = [
        f"T-shirt {r['triangles']} triangles, {r['frames_raced']}/{r['frames']} frames at {r['fps']} fps, "
        f"{r['substeps']} sub-steps per frame (dt {r['dt_s'] * 1e3:.2f} ms)",
        f"ours    {r['ours_s_per_frame']:.3f} s/frame (median {r['ours_s_per_frame_median']:.3f}), tearing on: "
        f"{r['ours_tears_started']} tears, {r['ours_cuts']} cuts",
        f"Blender {r['blender_s_per_frame']:.3f} s/frame (median {r['blender_s_per_frame_median']:.3f}), "
        f"replay from cache {r['blender_replay_s_per_frame']:.4f} s/frame",
        f"CPU s/frame: ours {r['ours_cpu_s_per_frame']:.3f}, Blender {r['blender_cpu_s_per_frame']:.3f} "
        f"(ratio {r.get('cpu_ratio', float('nan')):.2f})",
        f"penetration at the last frame: ours {r['ours_penetration_max_m'] * 1e3:.1f} mm, "
        f"{r['ours_vertices_inside']} vertices inside; Blender {r['blender_penetration_max_m'] * 1e3:.1f} mm, "
        f"{r['blender_vertices_inside']} vertices inside",
        f"collision share of our sub-step time: {r['ours_collision_share_of_substep']:.2f}; close pairs fully "
        f"detected: {r.get('ours_full_share', float('nan')):.2f}",
        f"ratio ours/Blender {r['ratio']:.2f}",
        f"Blender cloth: {bl['cloth']}",
        f"Blender collision: {bl['collision']}; body: {bl['body_collision']}; scene: {bl['scene']}",
    ]
    if r["ours_error"]:
        lines.append(f"ours stopped: {r['ours_error']}")
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------------
# The multigrid with contacts (issue 14: the contact correction of amg.c)
# ------------------------------------------------------------------------------------------------

CORRECTION_ENV = "TEARCLOTH_AMG_CONTACTS"  # 0: amg.c's contact correction off (solver.c reads it each sub-step)


def multigrid_contacts(target_triangles: int = 20000, frames: int = 3, substeps: int = 10, *, fps: int = FPS,
                       pull_speed: float = PULL_SPEED, tear_stress: float = TEAR_STRESS, start_time: float = 0.0,
                       body=None) -> dict:
    """Our side of the race on a finer shirt, where the solver's "auto" picks the multigrid and the
    shirt touches the walking body: two cloths stepped frame by frame in turn (load hits both alike),
    one with amg.c's contact correction (A_1 = P^T (S A S + tau (I - S) d) P while contacts last), one
    without (TEARCLOTH_AMG_CONTACTS=0 while it steps). Per sub-step medians of CG iterations, FEM ms
    and the multigrid's setup ms (builds, refreshes, corrections), and the ratios corrected / not."""
    body = body if body is not None else examples.mannequin()
    shirt = examples.tshirt(body, target_triangles=target_triangles)
    mat = material("cotton", tear_stress=tear_stress)
    sides = {name: _Ours(shirt, body, mat, CollisionSettings(), fps, substeps, pull_speed, start_time)
             for name in ("corrected", "uncorrected")}
    per = {name: {"cg_iterations": [], "fem_ms": [], "setup_ms": [], "contacts": []} for name in sides}
    levels = {}

    def record(name, side):
        orig = side.session.step

        def step(dt):
            rep = orig(dt)
            st = side.cloth.stats()
            per[name]["cg_iterations"].append(st["cg_iterations"])
            per[name]["fem_ms"].append(1e3 * rep.fem_s)
            per[name]["setup_ms"].append(1e3 * st["amg_setup_seconds"])
            per[name]["contacts"].append(rep.contacts)
            levels[name] = st["amg_levels"]
            return rep

        side.session.step = step

    for name, side in sides.items():
        record(name, side)
    before = os.environ.get(CORRECTION_ENV)
    try:
        for f in range(2, frames + 2):
            for name, side in sides.items():
                os.environ[CORRECTION_ENV] = "1" if name == "corrected" else "0"
                side.frame(f)
    except SimulationError as e:
        return {"error": str(e)}
    finally:
        if before is None:
            os.environ.pop(CORRECTION_ENV, None)
        else:
            os.environ[CORRECTION_ENV] = before
    out = {"triangles": int(shirt.triangles.shape[0]), "vertices": int(shirt.vertices.shape[0]), "frames": frames,
           "substeps": substeps, "dt_s": 1.0 / fps / substeps, "amg_levels": levels}
    for name in sides:
        out[name] = {k: float(statistics.median(v)) for k, v in per[name].items()}
        out[name]["amg_fallbacks"] = int(sides[name].cloth.stats()["amg_fallbacks"])
    for k in ("cg_iterations", "fem_ms"):
        out[f"{k}_ratio"] = out["corrected"][k] / out["uncorrected"][k] if out["uncorrected"][k] else float("nan")
    return out


def format_multigrid_contacts(r: dict) -> str:
    if "error" in r:
        return f"multigrid with contacts: stopped: {r['error']}"
    c, u = r["corrected"], r["uncorrected"]
    return (f"multigrid with contacts (T-shirt {r['triangles']} triangles on the walking body, {r['frames']} frames of "
            f"{r['substeps']} sub-steps, {c['contacts']:.0f} contacts; levels {r['amg_levels']}), per sub-step, corrected / "
            f"not: CG iterations {c['cg_iterations']:.1f} / {u['cg_iterations']:.1f} ({r['cg_iterations_ratio']:.2f}), "
            f"FEM {c['fem_ms']:.1f} / {u['fem_ms']:.1f} ms ({r['fem_ms_ratio']:.2f}), of it setup {c['setup_ms']:.1f} / "
            f"{u['setup_ms']:.1f} ms")


if __name__ == "__main__":  # pragma: no cover
    import json
    import sys

    res = race_blender_cloth(out=print)
    print(format_race(res))
    if len(sys.argv) > 1:
        with open(sys.argv[1], "w") as fh:
            json.dump(res, fh, indent=2, default=float)
