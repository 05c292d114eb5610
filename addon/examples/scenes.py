"""The example scenes of Tear Cloth, assembled from the mesher, the mannequin and the shirt: the
paper's square cloth, banknote and T-shirt (Le Gouis et al., WHC 2017, Table I: ~1.4K, ~1.9K and
~3.3K triangles), and a denim knee.

This file owns ``square_cloth``, ``banknote`` (with its optional notch), ``tshirt`` (pattern,
wrap, fit and clean-up in order, then UVs and the vertex groups the hands grasp and the pins
hold), ``denim_knee`` (the front panel of a jeans leg, worn at the knee) and ``capsule`` (the
leg's thigh and shin). Each is seeded and deterministic: the example .blend files and the benchmarks are made from
them. SI units, Z up, sheets facing -Y (toward Blender's front view).
"""
from __future__ import annotations

import math

import numpy as np

from .distance import MeshDistance, PartDistance, distance_to_segments
from .mannequin import ARM_L, ARM_R, Body, arm_frame, mannequin
from .mesh import ClothMesh, check_count, check_positive, connected_labels, edge_keys
from .mesher import triangulate_polygon
from .shirt import (
    collapse_short_edges,
    cut_and_sew,
    fit_shirt,
    flip_edges,
    frontal_map,
    loop_order,
    raycast_depth,
    shirt_pattern,
)


# ------------------------------------------------------------------------------------------------
# Flat scenes: square cloth and banknote
# ------------------------------------------------------------------------------------------------


def _flat_to_xz(points2d, centre_x, bottom_z):
    """Lay flat (u, v) points in the XZ plane: u -> +X, v -> +Z, y = 0. A triangle that is
    counter-clockwise in (u, v) then faces -Y, toward Blender's front view."""
    out = np.zeros((len(points2d), 3))
    out[:, 0] = points2d[:, 0] + centre_x
    out[:, 2] = points2d[:, 1] + bottom_z
    return out


def square_cloth(size: float = 0.5, target_triangles: int = 1400, seed: int = 0) -> ClothMesh:
    """The paper's square piece of cloth (Fig. 1 / Table I: ~1.4K triangles), hanging.

    A size x size square in the XZ plane (normal -Y, toward the front view), centred on x = 0 with
    its centre at z = 1.0 m (chest height, so a tear pulled by two hands happens in front of a
    standing user). Irregular Delaunay mesh, so tears do not run along grid lines.

    Groups: ``pin_top`` (the top edge), ``handle_left`` / ``handle_right`` (vertices within
    0.12 * size of the outer fifth of the top edge at -X / +X: where two hands grab the top
    corners to pull the cloth apart).
    """
    size = check_positive("size", size)
    target_triangles = check_count(target_triangles)
    sq = np.array([[0.0, 0.0], [size, 0.0], [size, size], [0.0, size]])
    p, tris, _ = triangulate_polygon(
        sq, target_triangles=target_triangles, seed=seed, relax_rounds=2
    )
    verts = _flat_to_xz(p - [size / 2.0, 0.0], 0.0, 1.0 - size / 2.0)
    uv = p / size
    top = verts[:, 2].max()
    x0, x1 = -size / 2.0, size / 2.0
    tol = 1e-9 * max(1.0, size)
    pin_top = (np.abs(verts[:, 2] - top) <= tol).astype(np.float64)
    reach = 0.12 * size
    grip = 0.2 * size
    pts = verts[:, [0, 2]]

    def near(a, b):
        return (distance_to_segments(pts, np.array([a]), np.array([b])) <= reach).astype(float)

    groups = {
        "pin_top": pin_top,
        "handle_left": near([x0, top], [x0 + grip, top]),
        "handle_right": near([x1 - grip, top], [x1, top]),
    }
    return ClothMesh(verts, tris, uv, groups, "square_cloth")


# US banknote, 6.14 in x 2.61 in.
BANKNOTE_SIZE = (0.156, 0.066)


def banknote(
    width: float = BANKNOTE_SIZE[0],
    height: float = BANKNOTE_SIZE[1],
    target_triangles: int = 1900,
    seed: int = 0,
    grip: float = 0.025,
    notch: float = 0.0,
) -> ClothMesh:
    """The paper's banknote (Table I: ~1.9K triangles; paper tears almost as soon as it is pulled).

    A width x height rectangle (US banknote size by default) held upright in the XZ plane (normal
    -Y), centred at x = 0, z = 1.0 m, as two hands hold a note in front of the chest.

    Groups: ``handle_left`` / ``handle_right``: the end strips of width ``grip`` (m) at -X / +X,
    where thumb and index finger pinch the note.
    notch: depth (m) of an optional V notch cut into the middle of the top edge (60 degree opening),
    a ready-made initial tear; 0 means a clean rectangle.
    """
    width = check_positive("width", width)
    height = check_positive("height", height)
    grip = check_positive("grip", grip)
    target_triangles = check_count(target_triangles)
    if grip * 2.0 >= width:
        raise ValueError(f"grip {grip} m leaves nothing between the hands of a {width} m note")
    notch = float(notch)
    if notch < 0.0 or notch >= 0.8 * height:
        raise ValueError(f"notch must be in [0, {0.8 * height:.4f}) m, got {notch}")
    w2 = width / 2.0
    outline = [[-w2, 0.0], [w2, 0.0], [w2, height]]
    if notch > 0.0:
        half = notch * math.tan(math.radians(30.0))
        outline += [[half, height], [0.0, height - notch], [-half, height]]
    outline += [[-w2, height]]
    p, tris, _ = triangulate_polygon(
        np.asarray(outline), target_triangles=target_triangles, seed=seed, relax_rounds=2
    )
    verts = _flat_to_xz(p, 0.0, 1.0 - height / 2.0)
    uv = (p + [w2, 0.0]) / [width, height]
    x = verts[:, 0]
    tol = 1e-9
    groups = {
        "handle_left": (x <= -w2 + grip + tol).astype(np.float64),
        "handle_right": (x >= w2 - grip - tol).astype(np.float64),
    }
    return ClothMesh(verts, tris, uv, groups, "banknote")


def tshirt(
    body: Body | None = None,
    target_triangles: int = 3300,
    seed: int = 0,
    clearance: float = 0.012,
) -> ClothMesh:
    """The paper's T-shirt (Table I: ~3.3K triangles), worn by the mannequin at its bind pose.

    Made like a real one: a front and a back panel cut from one flat pattern (body plus short
    sleeves that leave at the arm angle; the front neckline scooped deeper), each meshed
    irregularly, then sewn vertex to vertex along the shoulder, top-sleeve, underarm and side
    seams into one edge-manifold surface with four open rims (neck, waist, two cuffs). The sewn
    shirt is wrapped around the torso and arms and settled ``clearance`` metres outside the body
    surface, so at rest it touches nothing (the simulation starts without contacts) yet fits
    (every vertex exactly ``clearance`` from the body, up to ~6 mm more where it bridges the
    armpits, as the paper's fitted shirt). Takes ~1.5 s (the fit is most of it).

    body              the wearer (default: ``mannequin()``), in its bind pose.
    target_triangles  total triangle count (the seams add none), hit within ~2 % (the clean-up
                      of slivers may remove a few more).
    clearance         rest gap between shirt and body, metres (5 mm to 3 cm).

    Groups: ``hem_left`` / ``hem_right``: the bottom hem of the front panel where the left (+X) and
    right (-X) hands grab it to pull it apart; ``shoulders``: along the shoulder seams, fading out
    over 4 cm (to pin the shirt while it is torn).
    UV: front panel in the left half of UV space, back panel (seen from outside) in the right half;
    ``corner_uv`` keeps both UVs of the seam vertices.
    """
    target_triangles = check_count(target_triangles)
    clearance = check_positive("clearance", clearance)
    if not 0.005 <= clearance <= 0.03:
        raise ValueError(f"clearance must be between 0.005 and 0.03 m, got {clearance}")
    if body is None:
        body = mannequin()
    if not isinstance(body, Body):
        raise TypeError(f"body must be a Body (from mannequin()), got {type(body).__name__}")
    front_p, back_p, seams, dims = shirt_pattern(body, clearance)
    (pf, tf), (pb, tb), p2, tris, back_index, is_front, seam = cut_and_sew(
        front_p, back_p, seams, target_triangles, seed
    )
    # Wrap: lay the pattern on the body's silhouette, then take the depth from rays cast from the
    # front (front panel) or back (back panel) onto the body inflated by the clearance. Seam
    # vertices sit on the silhouette, between the two hits.
    D = MeshDistance(body.vertices, body.triangles)
    inflated = body.vertices + clearance * D.vert_n
    xz = frontal_map(p2, body, dims, clearance)
    yf = raycast_depth(inflated, body.triangles, xz, front=True)
    yb = raycast_depth(inflated, body.triangles, xz, front=False)
    y = np.where(is_front, yf, yb)
    y = np.where(seam, 0.5 * (yf + yb), y)
    y = np.where(np.isnan(y), 0.0, y)  # a miss (just off the silhouette): the mid-plane
    x = np.stack([xz[:, 0], y, xz[:, 1]], axis=1)
    # Rims: hem and neck slide along their first curve, cuffs keep their place along the arm.
    n = len(x)
    keys = edge_keys(tris, n).ravel()
    uniq, counts = np.unique(keys, return_counts=True)
    rim = uniq[counts == 1]
    lab = connected_labels(n, np.stack([rim // n, rim % n], axis=1))
    rim_v = np.unique(np.concatenate([rim // n, rim % n]))
    loops = []
    m = body.measurements
    for root in np.unique(lab[rim_v]):
        idx = rim_v[lab[rim_v] == root]
        cx = x[idx].mean(axis=0)
        if abs(cx[0]) > dims["W2"]:  # a cuff
            sd_ = 1.0 if cx[0] > 0 else -1.0
            axis_, _, _ = arm_frame(sd_, m["arm_angle"])
            J = m["shoulder_left"] if sd_ > 0 else m["shoulder_right"]
            dval = float(np.mean((x[idx] - J) @ axis_))
            loops.append((idx, "d", dval, axis_, J))
        else:  # hem or neck: keep the rim on its curve
            ring = loop_order(idx, rim // n, rim % n)
            loops.append((idx, "curve", (x[ring], x[np.roll(ring, -1)]), None, None))
    labels = m["labels"][body.triangles]
    tri_part = np.isin(labels, (ARM_L, ARM_R)).sum(axis=1) >= 2
    fillet = 0.008 * m["scale"]
    parts = PartDistance(D, tri_part, reach=0.08 * m["scale"], jump=0.008 * m["scale"])
    panel = np.r_[np.zeros(len(tf), dtype=np.int64), np.ones(len(tb), dtype=np.int64)]
    x = fit_shirt(x, tris, panel, loops, parts, clearance, iterations=30, fillet=fillet)
    # UVs: one uniform scale for both panels so texel density matches across the seams; the
    # front panel fills u in [0.02, 0.48], the back panel (mirrored, as seen from outside)
    # u in [0.52, 0.98].
    width = 2.0 * float(np.abs(np.concatenate([pf[:, 0], pb[:, 0]])).max())
    tall = float(max(pf[:, 1].max(), pb[:, 1].max()))
    k = 0.46 / max(width, 2.0 * tall)
    uv_front = np.full((len(x), 2), np.nan)
    uv_back = np.full((len(x), 2), np.nan)
    uv_front[: len(pf)] = np.stack([0.25 + pf[:, 0] * k, 0.05 + pf[:, 1] * k], axis=1)
    uv_back[back_index] = np.stack([0.75 - pb[:, 0] * k, 0.05 + pb[:, 1] * k], axis=1)
    # Clean-up of the few slivers the fit leaves (rims and seams pull unevenly): collapse the
    # shortest edge of a sliver (vertices do not move, so the clearance holds), then flip.
    tris, keep = collapse_short_edges(x, tris, panel, seam)
    x, p2, is_front, uv_front, uv_back = (a[keep] for a in (x, p2, is_front, uv_front, uv_back))
    panel = panel[tris[:, 0] >= 0]
    tris = tris[tris[:, 0] >= 0]
    remap = np.cumsum(keep) - 1
    tris = remap[tris]
    tris = flip_edges(x, tris, panel)
    uv = np.where(np.isnan(uv_front), uv_back, uv_front)  # seam vertices: their front UV
    corner = np.where((panel == 0)[:, None, None], uv_front[tris], uv_back[tris])
    # Groups (panel coordinates make "front hem, left of centre" exact).
    sc = m["scale"]
    grip = (p2[:, 1] <= 0.03 * sc) & is_front
    hem_left = grip & (p2[:, 0] >= 0.04 * sc) & (p2[:, 0] <= 0.16 * sc)
    hem_right = grip & (p2[:, 0] <= -0.04 * sc) & (p2[:, 0] >= -0.16 * sc)
    a_ = np.array([[dims["s_n"], dims["t_n"]], [-dims["s_n"], dims["t_n"]]])
    b_ = np.array([dims["P_s"], dims["P_s"] * [-1.0, 1.0]])
    dist = distance_to_segments(p2, a_, b_)
    shoulders = np.clip(1.0 - dist / (0.04 * sc), 0.0, 1.0)
    groups = {
        "hem_left": hem_left.astype(np.float64),
        "hem_right": hem_right.astype(np.float64),
        "shoulders": shoulders,
    }
    return ClothMesh(x, tris.astype(np.int32), uv, groups, "tshirt", corner)


# ------------------------------------------------------------------------------------------------
# Denim knee: the front panel of a jeans leg over a leg that bends at the knee

# The leg, standing, axis along Z at x = y = 0 (metres): hip, knee and ankle heights, its radius.
LEG = {"hip": 1.0, "knee": 0.55, "ankle": 0.1, "radius": 0.06}


def capsule(start, end, radius: float, segments: int = 24, rings: int = 6):
    """A closed capsule (cylinder with hemispherical ends) from ``start`` to ``end`` (metres):
    (vertices (n, 3), triangles (m, 3)), wound so the normals point out. The segment must be
    parallel to Z (the leg's bones at rest)."""
    start, end = np.asarray(start, dtype=np.float64), np.asarray(end, dtype=np.float64)
    radius = check_positive("radius", radius)
    axis = end - start
    if np.linalg.norm(axis[:2]) > 1e-12 or abs(axis[2]) < 1e-12:
        raise ValueError("capsule: start and end must differ along Z only")
    lo, hi = min(start[2], end[2]), max(start[2], end[2])
    # rings of latitude: the bottom hemisphere, then the top one (the cylinder joins them)
    lat = np.r_[np.linspace(-math.pi / 2, 0.0, rings + 1)[1:], np.linspace(0.0, math.pi / 2, rings + 1)[:-1]]
    heights = np.r_[np.full(rings, lo), np.full(rings, hi)]
    a = np.linspace(0.0, 2.0 * math.pi, segments, endpoint=False)
    verts = [[start[0], start[1], lo - radius]]
    for phi, z in zip(lat, heights):
        r = radius * math.cos(phi)
        verts += [[start[0] + r * math.cos(t), start[1] + r * math.sin(t), z + radius * math.sin(phi)] for t in a]
    verts.append([start[0], start[1], hi + radius])
    tris = []
    ring = lambda k, i: 1 + k * segments + i % segments  # noqa: E731
    for i in range(segments):
        tris.append([0, ring(0, i + 1), ring(0, i)])
    for k in range(2 * rings - 1):
        for i in range(segments):
            tris.append([ring(k, i), ring(k, i + 1), ring(k + 1, i + 1)])
            tris.append([ring(k, i), ring(k + 1, i + 1), ring(k + 1, i)])
    top = len(verts) - 1
    for i in range(segments):
        tris.append([top, ring(2 * rings - 1, i), ring(2 * rings - 1, i + 1)])
    return np.array(verts), np.array(tris, dtype=np.int32)


def denim_knee(
    clearance: float = 0.012,
    top: float = 0.85,
    bottom: float = 0.27,
    target_triangles: int = 1600,
    seed: int = 0,
    worn_radius: float = 0.03,
) -> ClothMesh:
    """The front half of a jeans leg around ``LEG`` standing: a half cylinder of radius leg radius +
    ``clearance`` from height ``bottom`` to ``top`` (metres), facing -Y (the front), meshed
    irregularly. UV: u across the leg, v along it, in metres of the flat panel over 0.25 m (the
    warp of jeans runs along the leg: v).

    Groups: ``pin_top`` (the top edge: where the panel is held on the thigh), ``hem`` (the bottom
    edge: held on the shin), ``knee`` (the worn patch over the kneecap: 1 within ``worn_radius``
    of the front of the knee, fading to 0 at twice that, measured on the flat panel).
    """
    clearance = check_positive("clearance", clearance)
    target_triangles = check_count(target_triangles)
    if not bottom < LEG["knee"] < top:
        raise ValueError(f"the panel ({bottom}-{top} m) must cover the knee at {LEG['knee']} m")
    radius = LEG["radius"] + clearance
    width, height = math.pi * radius, top - bottom
    rect = np.array([[0.0, 0.0], [width, 0.0], [width, height], [0.0, height]])
    p, tris, _ = triangulate_polygon(rect, target_triangles=target_triangles, seed=seed, relax_rounds=2)
    angle = p[:, 0] / radius - math.pi / 2  # -90 deg (the leg's -X side) to +90 deg (+X), 0 at the front
    verts = np.stack([radius * np.sin(angle), -radius * np.cos(angle), bottom + p[:, 1]], axis=1)
    # (u, v) counter-clockwise seen from outside: u runs -X -> +X across the front, v up
    tol = 1e-9
    knee = np.array([width / 2.0, LEG["knee"] - bottom])
    d = np.linalg.norm(p - knee, axis=1)
    groups = {
        "pin_top": (p[:, 1] >= height - tol).astype(np.float64),
        "hem": (p[:, 1] <= tol).astype(np.float64),
        "knee": np.clip(2.0 - d / worn_radius, 0.0, 1.0),
    }
    return ClothMesh(verts, tris, p / 0.25, groups, "denim_knee")
