"""The mannequin the T-shirt is worn by: one closed, outward-wound 2-manifold body lofted from
elliptic cross-section rings (column for torso, neck and head; two legs; two arms in an A-pose),
with a skeleton and linear-blend-skinning weights.

This file owns ``Body`` (plain arrays plus the measurements garments are cut from), ``mannequin``,
its proportion tables, the skinning weights (``_skin``) and the profile helpers the shirt pattern
measures with (``pchip``, ``ellipse_perimeter``, ``arm_frame``, ``smoothstep``, the part labels
``ARM_L`` / ``ARM_R``). Conventions: SI units, Z up, the character faces -Y (Blender's front view
looks along +Y), so its left is +X, as in Blender's ``.L`` bone convention.

``pchip`` is hand-written: ``scipy.interpolate.PchipInterpolator`` takes other end slopes (a
three-point formula instead of the first secant), so the body would change by micrometres and the
example .blend files with it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .mesh import check_positive, orient_consistently, signed_volume


@dataclass
class Body:
    """A closed, outward-wound body mesh with a skeleton and linear-blend-skinning weights.

    vertices  float64 (n, 3) bind pose, metres.
    triangles int32 (m, 3), outward normals (counter-clockwise seen from outside).
    bones     list of (name, head (3,), tail (3,), parent index or -1), parents before children.
    weights   float64 (n, n_bones), rows sum to 1 (linear blend skinning).
    name      object name in Blender.
    measurements  named proportions that garments are cut from (joint positions, profiles of the
              cross-sections, arm angle, heights of crotch / armpit / shoulder, scale) and
              ``labels``: the body part of each vertex (0 torso/neck/head, 1/2 left/right arm,
              3/4 left/right leg).
    """

    vertices: np.ndarray
    triangles: np.ndarray
    bones: list
    weights: np.ndarray
    name: str = "mannequin"
    measurements: dict = field(default_factory=dict)

    @property
    def bone_names(self) -> list:
        return [b[0] for b in self.bones]

    def bone_index(self, name: str) -> int:
        for i, b in enumerate(self.bones):
            if b[0] == name:
                return i
        raise KeyError(f"no bone named {name!r}; bones are {self.bone_names}")


def smoothstep(e0, e1, x):
    """Hermite step from 0 at e0 to 1 at e1 (e1 < e0 gives a falling step)."""
    t = np.clip((np.asarray(x, dtype=np.float64) - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


# ------------------------------------------------------------------------------------------------
# Mannequin: one closed 2-manifold body lofted from cross-section rings
# ------------------------------------------------------------------------------------------------

# Proportions of a 1.75 m adult, metres; ``mannequin(height=...)`` scales them uniformly.
# Column (torso, neck, head) cross-sections: z, half-width a (x), half-depth b (y), centre y.
_COLUMN = np.array(
    [
        (0.800, 0.168, 0.100, 0.010),  # crotch ring: the legs split off here
        (0.850, 0.172, 0.110, 0.012),
        (0.920, 0.172, 0.108, 0.008),  # hips
        (1.000, 0.154, 0.100, 0.002),
        (1.060, 0.143, 0.097, 0.000),  # waist
        (1.150, 0.150, 0.104, -0.006),
        (1.240, 0.160, 0.112, -0.012),  # chest
        (1.310, 0.165, 0.110, -0.010),  # armpit
        (1.380, 0.168, 0.098, -0.004),
        (1.430, 0.160, 0.086, 0.002),  # shoulder top
        (1.465, 0.118, 0.072, 0.006),
        (1.490, 0.074, 0.060, 0.010),
        (1.505, 0.056, 0.054, 0.012),  # neck base
        (1.550, 0.052, 0.052, 0.010),
        (1.575, 0.060, 0.072, 0.000),  # jaw
        (1.610, 0.072, 0.090, -0.004),
        (1.660, 0.078, 0.098, 0.000),
        (1.705, 0.070, 0.090, 0.006),
        (1.735, 0.050, 0.066, 0.006),
        (1.747, 0.025, 0.034, 0.006),
        (1.750, 0.000, 0.000, 0.006),  # crown (pole)
    ]
)
# Leg cross-sections (each leg centred at x = +-_HIP_X): z, a, b, centre y.
_LEG = np.array(
    [
        (0.770, 0.082, 0.086, 0.010),
        (0.700, 0.076, 0.078, 0.005),
        (0.600, 0.064, 0.066, 0.000),
        (0.500, 0.050, 0.052, -0.004),  # knee
        (0.440, 0.048, 0.050, 0.000),
        (0.360, 0.052, 0.056, 0.010),  # calf
        (0.250, 0.042, 0.044, 0.008),
        (0.120, 0.032, 0.034, 0.004),  # ankle
        (0.080, 0.034, 0.042, -0.006),
        (0.045, 0.040, 0.080, -0.040),  # foot
        (0.020, 0.042, 0.108, -0.055),
        (0.000, 0.040, 0.108, -0.055),  # sole outline
    ]
)
# Arm cross-sections along the arm axis from the shoulder joint: d, a (along the up-outward
# perpendicular e1), b (along e2 = front/back). The hand is flat, palm toward the thigh.
_ARM = np.array(
    [
        (0.000, 0.056, 0.056),
        (0.100, 0.052, 0.050),  # deltoid
        (0.200, 0.045, 0.043),
        (0.290, 0.038, 0.038),  # elbow
        (0.400, 0.040, 0.036),  # forearm
        (0.520, 0.027, 0.030),  # wrist
        (0.560, 0.020, 0.042),  # palm
        (0.640, 0.018, 0.042),
        (0.700, 0.014, 0.030),  # fingers
        (0.735, 0.000, 0.000),  # finger tips (pole)
    ]
)
_HIP_X = 0.092
_SHOULDER = np.array([0.163, 0.0, 1.385])  # left shoulder joint; the right one is mirrored
_ARM_ANGLE = math.radians(48.0)  # A-pose: arm axis this far from hanging straight down
_ELBOW_D, _WRIST_D = 0.29, 0.52
_HOLE_Z = (1.318, 1.425)  # torso rows between these heights are cut open for the arms
_HOLE_HALF_WIDTH = 0.060  # half arc width of the arm opening on the torso side
_BIND_Z = {"hip": 0.90, "knee": 0.48, "ankle": 0.08, "pelvis": 0.92, "chest": 1.10, "neck": 1.45}

# Vertex region labels used for skinning.
_COL, ARM_L, ARM_R, _LEG_L, _LEG_R = 0, 1, 2, 3, 4


def pchip(x, y, xq):
    """Monotone piecewise-cubic Hermite interpolation (Fritsch-Carlson): smooth profiles that
    never overshoot the table (an overshooting radius could pinch the body inside out)."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if x[0] > x[-1]:
        x, y = x[::-1], y[::-1]
    h = np.diff(x)
    delta = np.diff(y) / h
    m = np.zeros_like(y)
    m[0], m[-1] = delta[0], delta[-1]
    same = delta[:-1] * delta[1:] > 0
    w1 = 2 * h[1:] + h[:-1]
    w2 = h[1:] + 2 * h[:-1]
    with np.errstate(divide="ignore", invalid="ignore"):
        hm = (w1 + w2) / (w1 / delta[:-1] + w2 / delta[1:])
    m[1:-1] = np.where(same, hm, 0.0)
    xq = np.clip(np.asarray(xq, dtype=np.float64), x[0], x[-1])
    k = np.clip(np.searchsorted(x, xq) - 1, 0, len(x) - 2)
    t = (xq - x[k]) / h[k]
    h00 = (1 + 2 * t) * (1 - t) ** 2
    h10 = t * (1 - t) ** 2
    h01 = t * t * (3 - 2 * t)
    h11 = t * t * (t - 1)
    return h00 * y[k] + h10 * h[k] * m[k] + h01 * y[k + 1] + h11 * h[k] * m[k + 1]


def _ellipse_angles(p, q, n, start=0.0, direction=1.0):
    """n angles that cut the ellipse (p cos t, q sin t) into equal arcs, beginning at ``start``."""
    t = np.linspace(0.0, 2.0 * np.pi, 257)
    seg = np.hypot(np.diff(p * np.cos(t)), np.diff(q * np.sin(t)))
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] <= 0.0:
        return start + direction * np.arange(n) * (2.0 * np.pi / n)
    # arc length measured from the start angle
    s0 = np.interp(start % (2 * np.pi), t, s)
    targets = (s0 + direction * np.arange(n) * s[-1] / n) % s[-1]
    return np.interp(targets, s, t)


def ellipse_perimeter(p, q):
    h = ((p - q) / np.maximum(p + q, 1e-300)) ** 2
    return np.pi * (p + q) * (1 + 3 * h / (10 + np.sqrt(4 - 3 * h)))


def _arc_stations(radii_fn, lo, hi, step):
    """Stations along a profile parameter (z or d), spaced so that consecutive rings are about
    ``step`` apart in space (axial change plus radius change), so flaring parts such as the top
    of the shoulders get as many rings as straight parts of the same surface length."""
    t = np.linspace(lo, hi, 2001)
    r = radii_fn(t)
    ds = np.hypot(np.diff(t), np.abs(np.diff(r, axis=0)).max(axis=1) if r.ndim == 2 else np.diff(r))
    s = np.concatenate([[0.0], np.cumsum(ds)])
    k = max(2, int(round(s[-1] / step)))
    return np.interp(np.linspace(0.0, s[-1], k + 1), s, t)


class _Builder:
    """Accumulates vertices (with a skinning label and an axial coordinate) and triangles."""

    def __init__(self):
        self.verts = []
        self.labels = []
        self.tris = []
        self.n = 0

    def add(self, pts, label):
        pts = np.asarray(pts, dtype=np.float64).reshape(-1, 3)
        idx = np.arange(self.n, self.n + len(pts))
        self.verts.append(pts)
        self.labels.append(np.full(len(pts), label))
        self.n += len(pts)
        return idx

    def zip(self, ring_a, u_a, ring_b, u_b):
        """Triangulate the band between two closed rings that wind the same way. u_* are the
        rings' angular positions (turns, increasing along each ring); counts may differ."""
        ring_a, ring_b = np.asarray(ring_a), np.asarray(ring_b)
        ua = np.unwrap(np.asarray(u_a, dtype=np.float64) * 2 * np.pi) / (2 * np.pi)
        ub = np.unwrap(np.asarray(u_b, dtype=np.float64) * 2 * np.pi) / (2 * np.pi)
        # start ring b at its vertex nearest in angle to ring a's first vertex
        d = (ub - ua[0] + 0.5) % 1.0 - 0.5
        j0 = int(np.argmin(np.abs(d)))
        ring_b = np.roll(ring_b, -j0)
        ub = np.roll(ub, -j0)
        ub = np.unwrap(ub * 2 * np.pi) / (2 * np.pi)
        ub = ub - np.round(ub[0] - ua[0])
        na, nb = len(ring_a), len(ring_b)
        ua_ext = np.concatenate([ua, [ua[0] + 1.0]])
        ub_ext = np.concatenate([ub, [ub[0] + 1.0]])
        i = j = 0
        out = []
        while i < na or j < nb:
            adv_a = j >= nb or (i < na and ua_ext[i + 1] <= ub_ext[j + 1])
            a0, a1 = ring_a[i % na], ring_a[(i + 1) % na]
            b0, b1 = ring_b[j % nb], ring_b[(j + 1) % nb]
            if adv_a:
                out.append((a0, a1, b0))
                i += 1
            else:
                out.append((a0, b1, b0))
                j += 1
        self.tris.append(np.asarray(out, dtype=np.int64))

    def fan(self, ring, apex):
        ring = np.asarray(ring)
        self.tris.append(np.stack([ring, np.roll(ring, -1), np.full(len(ring), apex)], axis=1))

    def quads(self, quads):
        """Split quads (a, b, c, d) (a->b along a ring, d above a) along the shorter diagonal."""
        q = np.asarray(quads, dtype=np.int64).reshape(-1, 4)
        self.tris.append(q)  # resolved in finish() once positions are known

    def finish(self):
        v = np.concatenate(self.verts)
        labels = np.concatenate(self.labels)
        tris = []
        for t in self.tris:
            if t.shape[1] == 3:
                tris.append(t)
                continue
            a, b, c, d = t.T
            ac = np.linalg.norm(v[a] - v[c], axis=1)
            bd = np.linalg.norm(v[b] - v[d], axis=1)
            use_ac = ac <= bd
            t1 = np.where(use_ac[:, None], np.stack([a, b, c], 1), np.stack([a, b, d], 1))
            t2 = np.where(use_ac[:, None], np.stack([a, c, d], 1), np.stack([b, c, d], 1))
            tris += [t1, t2]
        tris = np.concatenate(tris)
        # Drop vertices no triangle uses (the inside of the arm openings) and renumber.
        used = np.zeros(len(v), dtype=bool)
        used[tris.ravel()] = True
        remap = np.cumsum(used) - 1
        return v[used], labels[used], remap[tris]


def _ring_profile(table, scale):
    """(scaled table, at(z) -> (..., 3) interpolated columns) for a body part's ring table."""
    c = table * scale

    def at(z):
        return np.stack(
            [pchip(c[:, 0], c[:, 1], z), pchip(c[:, 0], c[:, 2], z), pchip(c[:, 0], c[:, 3], z)],
            axis=-1,
        )

    return c, at


def _column_profile(scale):
    return _ring_profile(_COLUMN, scale)


def _leg_profile(scale):
    return _ring_profile(_LEG, scale)


def _arm_profile(scale):
    c = _ARM * scale

    def at(d):
        return np.stack([pchip(c[:, 0], c[:, 1], d), pchip(c[:, 0], c[:, 2], d)], axis=-1)

    return c, at


def arm_frame(side, angle=_ARM_ANGLE):
    """Arm axis (down-outward), e1 (up-outward), e2 = axis x e1, for side +1 (left) / -1."""
    s, c = math.sin(angle), math.cos(angle)
    axis = np.array([side * s, 0.0, -c])
    e1 = np.array([side * c, 0.0, s])
    e2 = np.cross(axis, e1)
    return axis, e1, e2


def mannequin(height: float = 1.75, edge_length: float = 0.022) -> Body:
    """A procedural human-like body: ONE closed, consistently outward-wound 2-manifold (genus 0),
    standing on z = 0, facing -Y, arms in an A-pose, with a skeleton and skinning weights.

    Why one welded surface and not overlapping capsules: the collision module treats the body as
    a volumetric object (inside/outside by ray parity and hit-face orientation), which overlapping
    closed parts would break wherever they overlap (shoulders, hips) - exactly where the shirt is.

    Built from elliptic cross-section rings lofted along a central column (torso, neck, head),
    two legs that split off the crotch ring (the crotch ring's halves plus a shared inseam bridge
    become each thigh's top ring) and two arms that grow out of rectangular openings cut in the
    torso's sides. Rings carry about ``edge_length`` metres between vertices, so the default gives
    ~8K well-shaped triangles; the shirt needs that much to sit at a uniform clearance.

    height       standing height in metres (proportions scale uniformly).
    edge_length  target edge length in metres at height 1.75 (scaled with the body).
    """
    height = check_positive("height", height)
    edge_length = check_positive("edge_length", edge_length)
    if not 0.5 <= height <= 2.5:
        raise ValueError(f"height must be between 0.5 and 2.5 m for a human figure, got {height}")
    s = height / 1.75
    edge = edge_length * s
    if edge > 0.06 * s or edge < 0.008 * s:
        raise ValueError(
            f"edge_length must be between 0.008 and 0.06 m (x height/1.75), got {edge_length}: "
            "coarser loses the limbs, finer gives more than ~80K triangles"
        )
    B = _Builder()
    col_tab, col_at = _column_profile(s)

    # ---- column rings ------------------------------------------------------------------------
    z_lo, z_top = col_tab[0, 0], col_tab[-1, 0]
    zs = _arc_stations(lambda z: col_at(z)[..., :2], z_lo, z_top, edge)
    prof = col_at(zs)
    per = ellipse_perimeter(prof[:, 0], prof[:, 1])
    n_torso = max(16, 4 * int(round(ellipse_perimeter(*col_at(1.24 * s)[:2]) / edge / 4.0)))
    hole_lo, hole_hi = _HOLE_Z[0] * s, _HOLE_Z[1] * s
    fixed_top = hole_hi + 2.5 * edge  # rings stay at n_torso up to here (the arm openings)
    rings, ring_u = [], []
    for r, z in enumerate(zs[:-1]):
        a, b, cy = prof[r]
        if z <= fixed_top:
            n = n_torso
        else:
            # at most ~30 % fewer vertices than the ring below, so the zipper keeps angles open
            n = int(np.clip(round(per[r] / edge), math.ceil(0.7 * len(rings[-1])), n_torso))
            n = max(n, 3)
        th = _ellipse_angles(b, a, n)  # t = 0 at the front (-Y), increasing toward +X
        pts = np.stack([a * np.sin(th), cy - b * np.cos(th), np.full(n, z)], axis=1)
        rings.append(B.add(pts, _COL))
        ring_u.append(th / (2 * np.pi))
    crown = B.add([[0.0, prof[-1, 2], zs[-1]]], _COL)[0]

    # arm openings: rows (ring indices) and columns (vertex indices) of removed quads
    rows = [r for r, z in enumerate(zs[:-1]) if hole_lo <= z <= hole_hi]
    if len(rows) < 2:
        raise ValueError("edge_length too coarse to open the arm sockets")
    r0, r1 = rows[0], rows[-1]
    zc = 0.5 * (zs[r0] + zs[r1])
    column_edge = ellipse_perimeter(*col_at(zc)[:2]) / n_torso
    c_half = max(1, int(round(_HOLE_HALF_WIDTH * s / column_edge)))
    holes = {}
    for side in (1, -1):
        mid = n_torso // 4 if side > 0 else 3 * n_torso // 4
        holes[side] = (mid - c_half, mid + c_half)

    def in_hole(r, j):
        for j0, j1 in holes.values():
            if r0 <= r < r1 and j0 <= j < j1:
                return True
        return False

    for r in range(len(rings) - 1):
        ra, rb = rings[r], rings[r + 1]
        if len(ra) == len(rb) == n_torso:
            quads = [
                (ra[j], ra[(j + 1) % n_torso], rb[(j + 1) % n_torso], rb[j])
                for j in range(n_torso)
                if not in_hole(r, j)
            ]
            B.quads(quads)
        else:
            B.zip(ra, ring_u[r], rb, ring_u[r + 1])
    B.fan(rings[-1], crown)

    # ---- legs: the crotch ring's halves plus a shared inseam bridge ---------------------------
    leg_tab, leg_at = _leg_profile(s)
    crotch = rings[0]
    _, b0, cy0 = prof[0]
    front = crotch[0]
    y_front, y_back = cy0 - b0, cy0 + b0
    k = max(1, int(round((y_back - y_front) / edge)) - 1)
    yb = np.linspace(y_back, y_front, k + 2)[1:-1]  # back to front
    sag = 0.012 * s * (1.0 - ((yb - cy0) / b0) ** 2)
    bridge = B.add(np.stack([np.zeros(k), yb, np.full(k, zs[0]) - sag], axis=1), _COL)
    verts_so_far = np.concatenate(B.verts)
    leg_top = {
        1: np.concatenate([crotch[: n_torso // 2 + 1], bridge]),
        -1: np.concatenate([crotch[n_torso // 2 :], [front], bridge[::-1]]),
    }
    leg_zs = _arc_stations(lambda z: leg_at(z)[..., :2], leg_tab[0, 0], leg_tab[-1, 0], edge)
    for side in (1, -1):
        label = _LEG_L if side > 0 else _LEG_R
        xc = side * _HIP_X * s
        top = leg_top[side]
        tp = verts_so_far[top]
        prev, prev_u = top, np.arctan2(tp[:, 1], tp[:, 0] - xc) / (2 * np.pi)
        for z in leg_zs:
            a, b, cy = leg_at(z)
            n = max(6, int(round(ellipse_perimeter(a, b) / edge)))
            # start at the outer side so the zipper's first pair lines up, wind like the top ring
            th = _ellipse_angles(a, b, n, start=0.0, direction=1.0)
            pts = np.stack([xc + a * np.cos(th), cy + b * np.sin(th), np.full(n, z)], axis=1)
            ring = B.add(pts, label)
            u = np.arctan2(b * np.sin(th), a * np.cos(th)) / (2 * np.pi)
            B.zip(prev, prev_u, ring, u)
            prev, prev_u = ring, u
        # flat sole: concentric shrinking rings at z = 0, then a centre vertex
        a, b, cy = leg_at(leg_tab[-1, 0])
        z = leg_tab[-1, 0]
        for f in (0.68, 0.38):
            n = max(5, int(round(ellipse_perimeter(a * f, b * f) / edge)))
            th = _ellipse_angles(a * f, b * f, n)
            pts = np.stack([xc + f * a * np.cos(th), cy + f * b * np.sin(th), np.full(n, z)], 1)
            ring = B.add(pts, label)
            u = np.arctan2(b * np.sin(th), a * np.cos(th)) / (2 * np.pi)
            B.zip(prev, prev_u, ring, u)
            prev, prev_u = ring, u
        centre = B.add([[xc, cy, z]], label)[0]
        B.fan(prev, centre)

    # ---- arms: grown out of the rectangular openings -------------------------------------------
    arm_tab, arm_at = _arm_profile(s)
    joint = {1: _SHOULDER * s, -1: _SHOULDER * s * np.array([-1.0, 1.0, 1.0])}
    verts_so_far = np.concatenate(B.verts)
    for side in (1, -1):
        label = ARM_L if side > 0 else ARM_R
        j0, j1 = holes[side]
        loop = (
            [rings[r0][j] for j in range(j0, j1)]
            + [rings[r][j1] for r in range(r0, r1)]
            + [rings[r1][j] for j in range(j1, j0, -1)]
            + [rings[r][j0] for r in range(r1, r0, -1)]
        )
        loop = np.asarray(loop)
        J = joint[side]
        axis, e1, e2 = arm_frame(side)
        rel = verts_so_far[loop] - J
        d_loop = rel @ axis
        phi = np.unwrap(np.arctan2(rel @ e2, rel @ e1))
        rho = np.hypot(rel @ e1, rel @ e2)
        L = len(loop)
        direction = 1.0 if phi[-1] > phi[0] else -1.0
        # uniform angles with the same winding, rotated to sit closest to the loop's angles
        base = direction * np.arange(L) * 2 * np.pi / L
        off = np.angle(np.mean(np.exp(1j * (phi - base))))
        phi_u = base + off
        dphi = (phi_u - phi + np.pi) % (2 * np.pi) - np.pi
        # transition rings from the (tilted) opening to the first ring square to the axis
        d_end = max(d_loop.max() + 2.0 * edge, 0.12 * s)
        m = max(2, int(math.ceil((d_end - d_loop.min()) / edge)))
        prev, prev_u = loop, phi / (2 * np.pi)
        for i in range(1, m + 1):
            lam = i / m
            d = d_loop + (d_end - d_loop) * lam
            ease = 1.0 - (1.0 - lam) ** 2
            ph = phi + dphi * ease
            ab = arm_at(d)
            rad = ab[:, 0] * ab[:, 1] / np.hypot(ab[:, 1] * np.cos(ph), ab[:, 0] * np.sin(ph))
            r = rho + (rad - rho) * ease
            around = np.cos(ph)[:, None] * e1 + np.sin(ph)[:, None] * e2
            pts = J + d[:, None] * axis + r[:, None] * around
            ring = B.add(pts, label)
            qs = [(prev[q], prev[(q + 1) % L], ring[(q + 1) % L], ring[q]) for q in range(L)]
            B.quads(qs)
            prev, prev_u = ring, ph / (2 * np.pi)
        ds_ = _arc_stations(arm_at, d_end, arm_tab[-1, 0], edge)[1:-1]
        start = float(ph[0])  # the last transition ring ends on uniform angles from here
        for d in ds_:
            a, b = arm_at(d)
            n = max(5, int(round(ellipse_perimeter(a, b) / edge)))
            th = _ellipse_angles(a, b, n, start=start % (2 * np.pi), direction=direction)
            pts = J + d * axis + a * np.cos(th)[:, None] * e1 + b * np.sin(th)[:, None] * e2
            ring = B.add(pts, label)
            u = np.arctan2(b * np.sin(th), a * np.cos(th)) / (2 * np.pi)
            B.zip(prev, prev_u, ring, u)
            prev, prev_u = ring, u
        tip = B.add([J + arm_tab[-1, 0] * axis], label)[0]
        B.fan(prev, tip)

    verts, labels, tris = B.finish()
    tris = orient_consistently(tris, len(verts))
    if signed_volume(verts, tris) < 0:
        tris = tris[:, ::-1].copy()
    bones, weights = _skin(verts, labels, s, joint)
    measurements = {
        "height": height,
        "scale": s,
        "column_profile": col_tab,
        "arm_profile": arm_tab,
        "leg_profile": leg_tab,
        "shoulder_left": joint[1],
        "shoulder_right": joint[-1],
        "arm_angle": _ARM_ANGLE,
        "elbow_d": _ELBOW_D * s,
        "hip_x": _HIP_X * s,
        "crotch_z": zs[0],
        "armpit_z": zs[r0],
        "shoulder_top_z": zs[r1],
        "labels": labels,
    }
    return Body(verts, np.ascontiguousarray(tris, dtype=np.int32), bones, weights, "mannequin",
                measurements)


def _skin(verts, labels, s, joint):
    """Bones and linear-blend weights from the construction labels.

    Each limb takes over from its parent across a joint band (smoothsteps along the limb axis);
    column vertices near a limb root get a share of it (shoulders by distance to the arm axis,
    buttocks by side), so the shoulder and the crotch stretch instead of shearing. Whatever the
    limbs leave goes to pelvis / spine / head by height. Rows sum to one by construction.
    """
    z = verts[:, 2]
    x = verts[:, 0]
    hip_z, knee_z, ankle_z = _BIND_Z["hip"] * s, _BIND_Z["knee"] * s, _BIND_Z["ankle"] * s
    def up(z):
        return np.array([0.0, 0.0, z * s])

    bones = [
        ("pelvis", up(_BIND_Z["pelvis"]), up(_BIND_Z["chest"]), -1),
        ("spine", up(_BIND_Z["chest"]), up(_BIND_Z["neck"]), 0),
        ("head", up(_BIND_Z["neck"]), up(1.75), 1),
    ]
    names = {}
    for side, tag in ((1, "L"), (-1, "R")):
        axis, _, _ = arm_frame(side)
        J = joint[side]
        elbow = J + _ELBOW_D * s * axis
        names[f"upper_arm.{tag}"] = len(bones)
        bones.append((f"upper_arm.{tag}", J.copy(), elbow, 1))
        names[f"forearm.{tag}"] = len(bones)
        bones.append((f"forearm.{tag}", elbow, J + _ARM[-1, 0] * s * axis, len(bones) - 1))
    for side, tag in ((1, "L"), (-1, "R")):
        hx = side * _HIP_X * s
        names[f"thigh.{tag}"] = len(bones)
        bones.append((f"thigh.{tag}", np.array([hx, 0.0, hip_z]), np.array([hx, 0.0, knee_z]), 0))
        names[f"shin.{tag}"] = len(bones)
        knee, ankle = np.array([hx, 0.0, knee_z]), np.array([hx, 0.0, ankle_z])
        bones.append((f"shin.{tag}", knee, ankle, len(bones) - 1))
    W = np.zeros((len(verts), len(bones)))
    limb_total = np.zeros(len(verts))
    for side, tag, arm_label, leg_label in ((1, "L", ARM_L, _LEG_L), (-1, "R", ARM_R, _LEG_R)):
        # arm
        axis, _, _ = arm_frame(side)
        rel = verts - joint[side]
        d = rel @ axis
        radial = np.linalg.norm(rel - d[:, None] * axis, axis=1)
        gate = np.where(labels == arm_label, 1.0, 0.0)
        near_axis = smoothstep(0.11 * s, 0.07 * s, radial) * (side * x > 0.05 * s)
        gate = np.where(labels == _COL, near_axis, gate)
        w_arm = smoothstep(-0.04 * s, 0.10 * s, d) * gate
        w_fore = smoothstep((_ELBOW_D - 0.04) * s, (_ELBOW_D + 0.04) * s, d)
        W[:, names[f"upper_arm.{tag}"]] = w_arm * (1 - w_fore)
        W[:, names[f"forearm.{tag}"]] = w_arm * w_fore
        limb_total += w_arm
        # leg
        gate = np.where(labels == leg_label, 1.0, 0.0)
        gate = np.where(labels == _COL, smoothstep(-0.05 * s, 0.05 * s, side * x), gate)
        w_leg = smoothstep(hip_z, hip_z - 0.14 * s, z) * gate
        w_leg = np.where(labels == leg_label, 1.0, w_leg) * np.where(
            labels == leg_label, smoothstep(hip_z - 0.10 * s, hip_z - 0.20 * s, z) * 0.3 + 0.7, 1.0
        )
        w_shin = smoothstep(knee_z + 0.05 * s, knee_z - 0.05 * s, z)
        W[:, names[f"thigh.{tag}"]] = w_leg * (1 - w_shin)
        W[:, names[f"shin.{tag}"]] = w_leg * w_shin
        limb_total += w_leg
    rest = 1.0 - limb_total
    w_spine = smoothstep(1.00 * s, 1.20 * s, z)
    w_head = smoothstep(1.47 * s, 1.53 * s, z)
    W[:, 0] = rest * (1 - w_spine)
    W[:, 1] = rest * w_spine * (1 - w_head)
    W[:, 2] = rest * w_spine * w_head
    W = np.clip(W, 0.0, None)
    W /= W.sum(axis=1, keepdims=True)
    return bones, W
