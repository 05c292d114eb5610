"""The ``materials`` bench part: woven sheets (issue 19). Owns the denim bias tear (a strip pulled
30 degrees off its warp must tear along a thread) and the cost of the general element (orthotropy
and plasticity on) against the isotropic elastic one, in the same run.

Figures (``materials.*`` in the bench JSON):
* ``denim_bias.tear_angle_error_deg``: how far the tear of the denim strip runs from the weft (the
  thread family it runs along: the warp threads break), with ``tear_angle_deg`` from the pull, and
  the isotropic cotton strip under the same load beside it (``cotton_error_deg`` from the
  perpendicular to the pull, where an isotropic sheet tears).
* ``cost_ratio``: median FEM step time (``fem_seconds``: assembly, solve, element passes, the
  plastic commit) of the T-shirt with orthotropy and plasticity on, over the isotropic elastic
  T-shirt, stepped alternately in one process. Both carry the same moduli (the orthotropic one with
  isotropic values), so the ratio is the cost of the general element, not of a different
  conditioning; ``cost_ratio_yielding`` the same with a yield stress so low that the hands' pull
  keeps triangles yielding (the return mapping runs), with the yield events per step.
"""
from __future__ import annotations

import statistics

import numpy as np

from ..cloth import Cloth
from ..materials import material
from .table1 import DT, build, lattice_triangles

__all__ = ["cut_edges", "tear_angle", "pulled_strip", "denim_bias", "cost_ratio", "materials_figures",
           "format_materials"]

STRIP = (0.4, 0.1)  # m: long, so the middle is in uniaxial stress off the warp


def _strip(nx: int, ny: int, seed: int, jitter: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    w, h = STRIP
    rng = np.random.default_rng(seed)
    xs, ys = np.meshgrid(np.linspace(0, w, nx), np.linspace(0, h, ny), indexing="ij")
    V = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], 1)
    inner = (xs.ravel() > 0) & (xs.ravel() < w) & (ys.ravel() > 0) & (ys.ravel() < h)
    V[inner, 0] += rng.uniform(-jitter, jitter, inner.sum()) * w / (nx - 1)
    V[inner, 1] += rng.uniform(-jitter, jitter, inner.sum()) * h / (ny - 1)
    return V, lattice_triangles(nx, ny, rng)


def cut_edges(c: Cloth):
    """Rest endpoints ((k, 3), (k, 3)) and lengths of the boundary edges tears made (rim left out)."""
    w, h = STRIP
    T, X = c.triangles, c.rest_positions
    e = np.sort(np.concatenate([T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]]), axis=1)
    u, cnt = np.unique(e, axis=0, return_counts=True)
    b = u[cnt == 1]
    a, z = X[b[:, 0]], X[b[:, 1]]
    mid, ln = 0.5 * (a + z), np.linalg.norm(a - z, axis=1)
    rim = (mid[:, 0] < 1e-9) | (mid[:, 0] > w - 1e-9) | (mid[:, 1] < 1e-9) | (mid[:, 1] > h - 1e-9)
    return (a[~rim], z[~rim]), ln[~rim]


def tear_angle(c: Cloth) -> float:
    """The direction (degrees from the pull, in [0, 180)) the cloth tore along: the length-weighted
    axial mean of its cut edges' rest directions (doubled angles, so an edge and its reverse agree
    and a zig-zag about a line averages to the line)."""
    (a, z), ln = cut_edges(c)
    th = 2.0 * np.arctan2(z[:, 1] - a[:, 1], z[:, 0] - a[:, 0])
    return float(np.degrees(0.5 * np.arctan2((ln * np.sin(th)).sum(), (ln * np.cos(th)).sum())) % 180.0)


def angle_error(a: float, b: float) -> float:
    """Distance between two line directions (degrees, modulo 180)."""
    return abs((a - b + 90.0) % 180.0 - 90.0)


def pulled_strip(grain_deg: float, preset: str, cut_length: float = 0.08, max_steps: int = 1500) -> Cloth:
    """The 0.4 x 0.1 m strip pulled along x by its ends until its tears have cut `cut_length` metres
    (both faces counted once). The warp lies at grain_deg from the pull; the preset's warp/weft
    ratios at a test scale (E = 5 MPa, tear stress 0.3 MPa, plasticity off), the bias a fifth of the
    warp's stiffness: denim's own G / E = 1/270 trellises (30 degrees off the warp its modulus is
    ~1/50 of E, and the small-strain membrane would need strains of order 1 to reach the tear).
    Hems at the clamps (strength 3: off the warp the ends' restraint of the shear-extension coupling
    loads their corners) and a weak spot (0.8) in the middle, where the first tear starts."""
    w, h = STRIP
    V, T = _strip(81, 21, seed=11)
    base = dict(young=5e6, thickness=5e-4, density=300.0, bending=1e-6, damping_mass=20.0, damping_stiffness=0.0,
                tear_stress=3e5, plastic=False, grain_angle=float(np.radians(grain_deg)))
    m = material(preset)
    if m.orthotropic:
        base.update(young_weft=5e6 * m.young_weft / m.young, shear_modulus=1e6,
                    tear_stress_weft=3e5 * m.tear_stress_weft / m.tear_stress)
    c = Cloth(V, T, material(preset, **base), gravity=(0, 0, 0), uv=V[:, :2] / (w, h))
    c.set_solver(cg_tolerance=1e-6, cg_max_iterations=400)
    st = np.where((V[:, 0] < 0.04) | (V[:, 0] > w - 0.04), 3.0, 1.0)
    d = np.linalg.norm(V[:, :2] - (w / 2, h / 2), axis=1)
    c.set_tear_strength(np.where(d < 0.012, np.minimum(st, 0.8 + 0.2 * d / 0.012), st))
    hl = c.add_handle(np.flatnonzero(V[:, 0] < 1e-9))
    hr = c.add_handle(np.flatnonzero(V[:, 0] > w - 1e-9))
    c.set_tearing(True)
    for i in range(max_steps):
        s = 4e-5 * i
        c.move_handle(hl, (-s, 0, 0))
        c.move_handle(hr, (s, 0, 0))
        c.step(2e-3)
        if i % 10 == 0 and cut_edges(c)[1].sum() / 2 >= cut_length:
            break
    return c


def denim_bias(grain_deg: float = 30.0) -> dict:
    """Denim pulled grain_deg off its warp: the warp threads carry cos^2 30 / (0.6 sin^2 30) = 5 times
    the weft's failure index, so they break and the tear runs along the weft (grain + 90 degrees
    from the pull); isotropic cotton under the same load tears across the pull."""
    den = pulled_strip(grain_deg, "denim")
    cot = pulled_strip(grain_deg, "cotton")
    a, b = tear_angle(den), tear_angle(cot)
    return {"grain_deg": grain_deg, "tear_angle_deg": a, "tear_angle_error_deg": angle_error(a, grain_deg + 90.0),
            "cut_m": float(cut_edges(den)[1].sum() / 2), "tears_started": den.stats()["tears_started"],
            "cotton_tear_angle_deg": b, "cotton_error_deg": angle_error(b, 90.0),
            "cotton_tears_started": cot.stats()["tears_started"]}


def cost_ratio(steps: int = 200) -> dict:
    """FEM step cost with orthotropy and plasticity on against isotropic elastic (module head)."""
    cot = material("cotton")
    same = dict(orthotropic=True, young_weft=cot.young, shear_modulus=cot.young / (2 * (1 + cot.poisson)),
                tear_stress_weft=cot.tear_stress, plastic=True)
    variants = {"isotropic": {}, "general": same,
                "yielding": dict(same, yield_stress=2e4, yield_stress_weft=2e4, hardening=0.1)}
    scenes = {}
    for name, changes in variants.items():
        sc = build("tshirt")
        if changes:
            sc.cloth.set_material(**changes)
        scenes[name] = sc
    fem = {k: [] for k in variants}
    iters = {k: [] for k in variants}
    yielded = []
    for i in range(steps):  # alternately, so a busy moment of the machine hits all three
        for name, sc in scenes.items():
            sc.pull((i + 1) * DT)
            sc.cloth.step(DT)
            st = sc.cloth.stats()
            fem[name].append(st["fem_seconds"])
            iters[name].append(st["cg_iterations"])
            if name == "yielding":
                yielded.append(st["plastic_triangles"])
    med = {k: statistics.median(v) for k, v in fem.items()}
    per_it = {k: statistics.median(f / max(n, 1) for f, n in zip(fem[k], iters[k])) for k in fem}
    return {"cost_ratio": med["general"] / med["isotropic"], "cost_ratio_yielding": med["yielding"] / med["isotropic"],
            "cost_ratio_per_cg_iteration": per_it["general"] / per_it["isotropic"],
            "cost_ratio_yielding_per_cg_iteration": per_it["yielding"] / per_it["isotropic"],
            "fem_ms": {k: 1e3 * v for k, v in med.items()},
            "cg_iterations_median": {k: statistics.median(v) for k, v in iters.items()},
            "yield_events_per_step_median": statistics.median(yielded),
            "triangles": scenes["isotropic"].cloth.num_triangles, "steps": steps}


def materials_figures(steps: int = 200) -> dict:
    out = {"denim_bias": denim_bias()}
    out.update(cost_ratio(steps))
    return out


def format_materials(r: dict) -> str:
    d = r["denim_bias"]
    return (f"materials: denim {d['grain_deg']:.0f} deg off the warp tore along {d['tear_angle_deg']:.1f} deg "
            f"({d['tear_angle_error_deg']:.2f} deg from the weft, {d['tears_started']} tears); cotton "
            f"{d['cotton_tear_angle_deg']:.1f} deg ({d['cotton_error_deg']:.2f} from the perpendicular)\n"
            f"materials: FEM step, orthotropic + plastic / isotropic elastic: {r['cost_ratio']:.3f} "
            f"({r['fem_ms']['general']:.3f} / {r['fem_ms']['isotropic']:.3f} ms, T-shirt {r['triangles']} triangles); "
            f"yielding {r['cost_ratio_yielding']:.3f} ({r['yield_events_per_step_median']:.0f} yield events per step); "
            f"per CG iteration {r['cost_ratio_per_cg_iteration']:.3f} / {r['cost_ratio_yielding_per_cg_iteration']:.3f}")
