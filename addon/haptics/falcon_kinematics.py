"""Novint Falcon kinematics (a delta robot; geometry after Stamper 1997, as used by the Falcon's
public drivers): inverse and forward kinematics, Jacobian, force -> motor torque -> effort counts,
encoder <-> angle.

This file owns the geometry and every conversion between the grip (Cartesian, m, N) and the three
motors (rad, N·m, counts). Frame: z along the device axis, growing toward the user; the usable
workspace is about x, y in ±0.05 m, z in [0.075, 0.175] m, centre (0, 0, 0.13).

Why two code paths: the servo loop calls forward kinematics + Jacobian once per tick at 1 kHz from
Python, where numpy's per-call overhead (~1 µs per tiny op) would dominate; so the single-point
path (``_ik_jac``, ``FalconKinematics``) is plain ``math`` on floats. Batch work (tests, plots,
tables) uses the vectorised ``inverse_kinematics``.

Jacobian: rows map Cartesian velocity to actuated-angle rates, dθ1_i/dx. The widely copied
reference driver has Jz = sin²θ2/den; the correct row (checked here against a numerical derivative
of the IK) is Jz = sin θ2·sin θ3/den.
"""
from __future__ import annotations

import math
from typing import Optional, Sequence, Tuple

import numpy as np

from .device import ConfigError, KinematicsError

__all__ = [
    "A", "B", "C", "D", "E", "F", "R", "S", "PHI",
    "ENCODER_DEG_PER_COUNT", "ENCODER_OFFSET_DEG", "EFFORT_PER_NEWTON_METRE", "DEFAULT_EFFORT_CLAMP",
    "WORKSPACE_CENTRE", "WORKSPACE_RADIUS",
    "leg_angles", "inverse_kinematics", "actuator_angles", "jacobian", "forward_kinematics",
    "encoder_to_angle", "angle_to_encoder", "force_to_torque", "torque_to_effort",
    "FalconKinematics",
]

# Geometry (m). Names follow the published derivation; d = e in the Falcon.
A = 0.060
B = 0.1025
C = 0.01443
D = 0.01125
E = 0.01125
F = -0.025
R = 0.0400
S = -0.02309
# Leg orientations around the z axis (rad).
PHI = tuple(p + math.pi / 12.0 for p in (math.pi / 2.0, -math.pi / 6.0, -5.0 * math.pi / 6.0))
_CP = tuple(math.cos(p) for p in PHI)
_SP = tuple(math.sin(p) for p in PHI)

# Encoder: 1280 counts per motor turn through a 110/14.25 capstan -> 0.0364347° per count,
# zero count at 35° once homed.
ENCODER_DEG_PER_COUNT = 0.0364347
ENCODER_OFFSET_DEG = 35.0
_RAD_PER_COUNT = math.radians(ENCODER_DEG_PER_COUNT)
_OFFSET_RAD = math.radians(ENCODER_OFFSET_DEG)

# Motor command: effort counts = -10000 · torque (N·m). The true motor limit is unknown; ±4096
# counts (≈0.41 N·m, ≈16 N at the grip near the centre) is the conservative default.
EFFORT_PER_NEWTON_METRE = 10000.0
DEFAULT_EFFORT_CLAMP = 4096

WORKSPACE_CENTRE = (0.0, 0.0, 0.13)
WORKSPACE_RADIUS = 0.04  # chai3d's model of the Falcon

_KC = A * A + C * C - D * D - E * E - 2.0 * D * E  # constant part of K
_DE = D + E


def _leg(cp: float, sp: float, x: float, y: float, z: float) -> Tuple[float, float, float]:
    """(θ1, θ2, θ3) of one leg (rad) for grip position (x, y, z); raises KinematicsError."""
    u = cp * x + sp * y - R
    v = -sp * x + cp * y - S
    c3 = (v + F) / B
    if not -1.0 <= c3 <= 1.0:
        raise KinematicsError(f"position ({x:.4f}, {y:.4f}, {z:.4f}) m is out of the Falcon's reach")
    t3 = math.acos(c3)
    s3 = B * math.sin(t3)
    k = z * z + u * u + 2.0 * C * u + _KC - s3 * s3 - 2.0 * s3 * _DE
    l0 = k - 2.0 * A * u - 2.0 * A * C
    l1 = -4.0 * A * z
    l2 = k + 2.0 * A * u + 2.0 * A * C
    disc = l1 * l1 - 4.0 * l0 * l2
    if disc < 0.0 or l2 == 0.0:
        raise KinematicsError(f"position ({x:.4f}, {y:.4f}, {z:.4f}) m is out of the Falcon's reach")
    t1 = 2.0 * math.atan((-l1 - math.sqrt(disc)) / (2.0 * l2))
    c2 = (-u + A * math.cos(t1) - C) / (-_DE - s3)
    if not -1.0 <= c2 <= 1.0:
        raise KinematicsError(f"position ({x:.4f}, {y:.4f}, {z:.4f}) m is out of the Falcon's reach")
    return t1, math.acos(c2), t3


def _ik_jac(x: float, y: float, z: float):
    """θ1 of the three legs and the 3x3 Jacobian (row-major tuple of 9), plain floats."""
    out_t = [0.0, 0.0, 0.0]
    out_j = [0.0] * 9
    for i in range(3):
        cp, sp = _CP[i], _SP[i]
        t1, t2, t3 = _leg(cp, sp, x, y, z)
        s3, c3, s2 = math.sin(t3), math.cos(t3), math.sin(t2)
        den = -A * s3 * math.sin(t1 - t2)
        if den == 0.0:
            raise KinematicsError(f"singular configuration at ({x:.4f}, {y:.4f}, {z:.4f}) m")
        c2s3 = math.cos(t2) * s3
        out_t[i] = t1
        out_j[3 * i] = (cp * c2s3 - sp * c3) / den
        out_j[3 * i + 1] = (sp * c2s3 + cp * c3) / den
        out_j[3 * i + 2] = s2 * s3 / den
    return out_t, out_j


def _solve3(m, b0: float, b1: float, b2: float):
    """Solve the row-major 3x3 system m·x = b by Cramer's rule (no numpy call overhead)."""
    a, b, c, d, e, f, g, h, i = m
    co0 = e * i - f * h
    co1 = f * g - d * i
    co2 = d * h - e * g
    det = a * co0 + b * co1 + c * co2
    if det == 0.0 or not math.isfinite(det):
        raise KinematicsError("singular Jacobian")
    inv = 1.0 / det
    x0 = (b0 * co0 + b * (f * b2 - b1 * i) + c * (b1 * h - e * b2)) * inv
    x1 = (a * (b1 * i - f * b2) + b0 * (f * g - d * i) + c * (d * b2 - b1 * g)) * inv
    x2 = (a * (e * b2 - b1 * h) + b * (b1 * g - d * b2) + b0 * (d * h - e * g)) * inv
    return x0, x1, x2


def _solve3_transposed(m, b0: float, b1: float, b2: float):
    a, b, c, d, e, f, g, h, i = m
    return _solve3((a, d, g, b, e, h, c, f, i), b0, b1, b2)


# ---- public single-point API -------------------------------------------------------------------
def leg_angles(p: Sequence[float]) -> np.ndarray:
    """(3 legs x [θ1, θ2, θ3]) in rad for one grip position p (m)."""
    x, y, z = (float(v) for v in p)
    return np.array([_leg(_CP[i], _SP[i], x, y, z) for i in range(3)])


def actuator_angles(p: Sequence[float]) -> np.ndarray:
    """Actuated angles θ1 of the three motors (rad) for grip position p (m)."""
    return leg_angles(p)[:, 0]


def jacobian(p: Sequence[float]) -> np.ndarray:
    """J (rad/m): row i is dθ1_i/d(x, y, z) at grip position p."""
    _, j = _ik_jac(*(float(v) for v in p))
    return np.array(j).reshape(3, 3)


def inverse_kinematics(points) -> np.ndarray:
    """Vectorised IK: points (..., 3) m -> angles (..., 3 legs, 3 [θ1, θ2, θ3]) rad.

    Unreachable positions give NaN (no exception: a batch may be partly outside the reach)."""
    p = np.asarray(points, dtype=float)
    x, y, z = p[..., 0, None], p[..., 1, None], p[..., 2, None]
    cp, sp = np.array(_CP), np.array(_SP)
    u = cp * x + sp * y - R
    v = -sp * x + cp * y - S
    w = np.broadcast_to(z, u.shape)
    with np.errstate(invalid="ignore", divide="ignore"):
        t3 = np.arccos((v + F) / B)
        s3 = B * np.sin(t3)
        k = w * w + u * u + 2.0 * C * u + _KC - s3 * s3 - 2.0 * s3 * _DE
        l0 = k - 2.0 * A * u - 2.0 * A * C
        l1 = -4.0 * A * w
        l2 = k + 2.0 * A * u + 2.0 * A * C
        t1 = 2.0 * np.arctan((-l1 - np.sqrt(l1 * l1 - 4.0 * l0 * l2)) / (2.0 * l2))
        t2 = np.arccos((-u + A * np.cos(t1) - C) / (-_DE - s3))
    return np.stack([t1, t2, t3], axis=-1)


def forward_kinematics(
    theta1: Sequence[float],
    guess: Optional[Sequence[float]] = None,
    tol: float = 1e-11,
    max_iter: int = 30,
) -> np.ndarray:
    """Grip position (m) from the three actuated angles (rad), by Newton's method on the IK.

    ``guess`` warm-starts the iteration (the previous position at 1 kHz: 1-2 iterations);
    without it the workspace centre is used. Raises KinematicsError if it does not converge."""
    pos, _ = _fk(tuple(float(t) for t in theta1), tuple(WORKSPACE_CENTRE if guess is None else guess), tol, max_iter)
    return np.array(pos)


def _fk(target, start, tol, max_iter):
    """Newton on θ(x) = target. Returns (position tuple, Jacobian at that position).

    The Jacobian returned is the one evaluated at the returned position (the last evaluation
    is the convergence check), so force rendering gets it for free."""
    x, y, z = start
    try:
        t, j = _ik_jac(x, y, z)
    except KinematicsError:
        x, y, z = WORKSPACE_CENTRE
        t, j = _ik_jac(x, y, z)
    for _ in range(max_iter):
        r0, r1, r2 = target[0] - t[0], target[1] - t[1], target[2] - t[2]
        if abs(r0) < tol and abs(r1) < tol and abs(r2) < tol:
            return (x, y, z), j
        dx, dy, dz = _solve3(j, r0, r1, r2)
        # Damped step: a full Newton step from a poor guess can leave the reachable set
        # (acos out of domain); halve until the IK is defined again.
        step = 1.0
        for _halving in range(12):
            nx, ny, nz = x + step * dx, y + step * dy, z + step * dz
            try:
                t, j = _ik_jac(nx, ny, nz)
                break
            except KinematicsError:
                step *= 0.5
        else:
            raise KinematicsError("forward kinematics left the reachable set (encoder counts inconsistent: not homed?)")
        x, y, z = nx, ny, nz
    raise KinematicsError(
        f"forward kinematics did not converge for angles {[round(math.degrees(a), 3) for a in target]} deg"
    )


# ---- encoders, torques, efforts ------------------------------------------------------------------
def encoder_to_angle(counts):
    """Encoder counts -> actuated angle θ1 (rad). Scalars or arrays."""
    if isinstance(counts, (int, float)):
        return counts * _RAD_PER_COUNT + _OFFSET_RAD
    return np.asarray(counts, dtype=float) * _RAD_PER_COUNT + _OFFSET_RAD


def angle_to_encoder(theta):
    """Actuated angle θ1 (rad) -> encoder counts, unrounded (the emulator rounds)."""
    if isinstance(theta, (int, float)):
        return (theta - _OFFSET_RAD) / _RAD_PER_COUNT
    return (np.asarray(theta, dtype=float) - _OFFSET_RAD) / _RAD_PER_COUNT


def force_to_torque(jac, force) -> np.ndarray:
    """Motor torques τ = (J⁻¹)ᵀ·F (N·m) for a grip force F (N); virtual work: τ·θ̇ = F·ẋ."""
    return np.linalg.solve(np.asarray(jac, dtype=float).T, np.asarray(force, dtype=float))


def torque_to_effort(tau: Sequence[float], clamp: int = DEFAULT_EFFORT_CLAMP, preserve_direction: bool = True) -> Tuple[int, int, int]:
    """Effort counts = −10000·τ, truncated toward zero, limited to ±clamp.

    With ``preserve_direction`` (default) an over-limit command is scaled down as a whole before
    truncation, so the grip force keeps its direction; otherwise each motor is clipped on its
    own (the literal rule, which bends the force when one motor saturates)."""
    if not 0 < clamp <= 32767:
        raise ConfigError(f"effort clamp must be in 1..32767 counts, got {clamp}")
    e0, e1, e2 = (-EFFORT_PER_NEWTON_METRE * float(t) for t in tau)
    if not (math.isfinite(e0) and math.isfinite(e1) and math.isfinite(e2)):
        raise ConfigError(f"non-finite torque {list(tau)!r}")
    if preserve_direction:
        m = max(abs(e0), abs(e1), abs(e2))
        if m > clamp:
            k = clamp / m
            e0, e1, e2 = e0 * k, e1 * k, e2 * k
        return int(e0), int(e1), int(e2)
    return tuple(max(-clamp, min(clamp, int(e))) for e in (e0, e1, e2))


class FalconKinematics:
    """Warm-started forward kinematics and force -> effort for one Falcon (the 1 kHz path).

    ``update(counts)`` converts encoder counts to the grip position, keeping the Jacobian at that
    position; ``efforts_for_force(F)`` then maps a grip force to motor efforts with it."""

    def __init__(self, effort_clamp: int = DEFAULT_EFFORT_CLAMP, preserve_direction: bool = True, tol: float = 1e-11):
        if not 0 < effort_clamp <= 32767:
            raise ConfigError(f"effort clamp must be in 1..32767 counts, got {effort_clamp}")
        self.effort_clamp = int(effort_clamp)
        self.preserve_direction = preserve_direction
        self.tol = tol
        self.reset()

    def reset(self) -> None:
        self.position: Tuple[float, float, float] = WORKSPACE_CENTRE
        _, self._jac = _ik_jac(*WORKSPACE_CENTRE)
        self._counts: Optional[Tuple[int, int, int]] = None

    @property
    def jacobian(self) -> np.ndarray:
        return np.array(self._jac).reshape(3, 3)

    def update(self, counts: Sequence[float]) -> Tuple[float, float, float]:
        """Grip position (m) for encoder counts; raises KinematicsError (position unchanged)."""
        key = tuple(counts)
        if key == self._counts:
            return self.position  # the grip did not move: skip Newton entirely
        target = (
            key[0] * _RAD_PER_COUNT + _OFFSET_RAD,
            key[1] * _RAD_PER_COUNT + _OFFSET_RAD,
            key[2] * _RAD_PER_COUNT + _OFFSET_RAD,
        )
        self.position, self._jac = _fk(target, self.position, self.tol, 30)
        self._counts = key
        return self.position

    def torques_for_force(self, force: Sequence[float]) -> Tuple[float, float, float]:
        return _solve3_transposed(self._jac, float(force[0]), float(force[1]), float(force[2]))

    def efforts_for_force(self, force: Sequence[float]) -> Tuple[int, int, int]:
        return torque_to_effort(self.torques_for_force(force), self.effort_clamp, self.preserve_direction)
