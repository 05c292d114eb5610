"""The mannequin's motion: linear blend skinning of ``mannequin()``'s skeleton, a walk in place on
[0, ``WALK_END``) s, then the arms reaching forward to grasp the shirt's hem and pulling it apart.

This file owns ``bone_matrices`` (bind -> pose transform per bone at time t), ``body_pose``
(skinned vertex positions at time t), ``WALK_END`` and the keyframes of the reach. Blender's
armature in ``example_blends/tshirt.blend`` reproduces ``bone_matrices`` exactly. SI units
(metres, seconds, radians inside).
"""
from __future__ import annotations

import math

import numpy as np

from .mannequin import Body, smoothstep


# ------------------------------------------------------------------------------------------------
# Animation: linear blend skinning, walk then reach for the hem
# ------------------------------------------------------------------------------------------------

WALK_END = 2.0  # s: the walk cycle runs on [0, WALK_END), then the arms reach forward
_STRIDE_PERIOD = 1.0  # s per full gait cycle (two steps)


def _rotation(axis, angle):
    """Rotation matrix (3, 3) about a unit axis by angle (radians), right-handed (Rodrigues)."""
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    x, y, z = axis
    c, s_ = math.cos(angle), math.sin(angle)
    C = 1.0 - c
    return np.array(
        [
            [c + x * x * C, x * y * C - z * s_, x * z * C + y * s_],
            [y * x * C + z * s_, c + y * y * C, y * z * C - x * s_],
            [z * x * C - y * s_, z * y * C + x * s_, c + z * z * C],
        ]
    )


def _about(head, R):
    """4x4 transform rotating by R about the point ``head`` (bind-pose coordinates)."""
    M = np.eye(4)
    M[:3, :3] = R
    M[:3, 3] = head - R @ head
    return M


def _flex_axis(head, tail, side=1.0, inward=0.0):
    """Axis about which a positive angle swings the bone's tail toward the front (-Y), and with
    ``inward`` > 0 also toward the body's mid-plane (a forearm bending across the belly)."""
    d = tail - head
    d = d / np.linalg.norm(d)
    a = np.cross(d, [-side * inward, -1.0, 0.0])
    return a / np.linalg.norm(a)


def _ease(t):
    return smoothstep(0.0, 1.0, t)


# Arm keyframes after the walk: time (s), shoulder flex, elbow flex, shoulder abduction (deg).
# At 3 s the palms are at the front of the hem (about x = +-0.17, y = -0.24, z = 0.95 m); at 4 s
# they have moved ~0.13 m apart each (x = +-0.30), pulling it open. The elbow bends across the belly
# (_ELBOW_INWARD) because a forearm that only flexes forward would leave the hands 30 cm out.
_REACH_KEYS = np.array([(2.0, 0.0, 0.0, 0.0), (3.0, 4.0, 72.0, -16.0), (4.0, 4.0, 70.0, 0.0)])
_ELBOW_INWARD = 1.5


def _pose_angles(t):
    """Joint angles at time t: name -> (flex, abduction) in radians.

    Walk on [0, 2) s: thighs swing +-22 deg in opposition, knees bend up to 35 deg while the leg
    swings forward, arms swing +-14 deg against the same-side leg. An envelope brings the walk in
    and out smoothly, so t = 0 and t = 2 s are exactly the bind pose and nothing jerks. The walk is
    in place (no root travel), so the scene stays framed.
    From 2 s: the arm keyframes ``_REACH_KEYS`` (eased): reach the hem, then pull outward; hold.
    """
    out = {}
    if t < WALK_END:
        env = float(smoothstep(0.0, 0.4, t) * smoothstep(WALK_END, WALK_END - 0.4, t))
        ph = 2.0 * math.pi * t / _STRIDE_PERIOD
        for tag, sgn in (("L", 1.0), ("R", -1.0)):
            swing = sgn * math.sin(ph)
            out[f"thigh.{tag}"] = (math.radians(22.0) * env * swing, 0.0)
            knee = max(0.0, sgn * math.cos(ph)) ** 2  # bent while the leg travels forward
            out[f"shin.{tag}"] = (-math.radians(35.0) * env * knee, 0.0)
            out[f"upper_arm.{tag}"] = (-math.radians(14.0) * env * swing, 0.0)
            out[f"forearm.{tag}"] = (math.radians(10.0) * env, 0.0)
    else:
        keys = _REACH_KEYS
        k = int(np.clip(np.searchsorted(keys[:, 0], t) - 1, 0, len(keys) - 2))
        w = float(_ease((t - keys[k, 0]) / (keys[k + 1, 0] - keys[k, 0])))
        fl, el, ab = np.radians(keys[k, 1:] + w * (keys[k + 1, 1:] - keys[k, 1:]))
        for tag in ("L", "R"):
            out[f"upper_arm.{tag}"] = (fl, ab)
            out[f"forearm.{tag}"] = (el, 0.0)
    return out


def bone_matrices(body: Body, t: float) -> np.ndarray:
    """World transforms (n_bones, 4, 4) of every bone at time t (s), relative to the bind pose:
    each bone rotates about its own head, composed parent-first. Identity at t = 0."""
    t = float(t)
    if not math.isfinite(t) or t < 0.0:
        raise ValueError(f"t must be a finite time >= 0 in seconds, got {t}")
    angles = _pose_angles(t)
    reaching = t >= WALK_END
    mats = np.zeros((len(body.bones), 4, 4))
    for i, (name, head, tail, parent) in enumerate(body.bones):
        head = np.asarray(head, dtype=np.float64)
        tail = np.asarray(tail, dtype=np.float64)
        side = 1.0 if head[0] >= 0 else -1.0
        flex, abd = angles.get(name, (0.0, 0.0))
        # abduction first (about the front-back axis, tail away from the mid-plane), then flexion
        R = _rotation([0.0, 1.0, 0.0], -side * abd)
        inward = _ELBOW_INWARD if (reaching and name.startswith("forearm")) else 0.0
        R = _rotation(_flex_axis(head, tail, side, inward), flex) @ R
        local = _about(head, R)
        mats[i] = local if parent < 0 else mats[parent] @ local
    return mats


def body_pose(body: Body, t: float) -> np.ndarray:
    """Vertex positions (n, 3) of ``body`` at time t (s) by linear blend skinning.

    The motion (see ``_pose_angles``): a walk in place on [0, 2) s, then both hands come forward to
    the front of the shirt hem (2-3 s) and pull outward (3-4 s), then hold. Hips and shoulders
    move at most 22 deg, so a simulated shirt can follow; the elbows bend up to 72 deg across the
    belly. The walk is in place; the feet dip up to ~1 cm below z = 0 mid-stride (no ground
    contact is modelled).
    t = 0 returns the bind pose exactly.
    """
    if not isinstance(body, Body):
        raise TypeError(f"body_pose needs a Body, got {type(body).__name__}")
    mats = bone_matrices(body, t)
    v = body.vertices
    vh = np.concatenate([v, np.ones((len(v), 1))], axis=1)
    # blend the matrices first, then apply once. einsum, not `@`: numpy's OpenBLAS runs a matmul
    # this size on worker threads that then spin (sched_yield) for ~0.1 s after every call, so
    # one pose a frame kept a core busy for the whole race (0.1 s of CPU per frame measured,
    # taken from both sides: the race runs Blender in the same process); einsum's own loop
    # costs 0.35 ms more and starts no thread.
    blended = np.einsum("nb,bk->nk", body.weights, mats[:, :3, :].reshape(len(mats), 12)).reshape(-1, 3, 4)
    return np.einsum("nij,nj->ni", blended, vh)
