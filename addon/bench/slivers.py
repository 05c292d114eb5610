"""The solver on a mesh with slivers (issue 14): the bench's ``slivers`` part.

A jittered sheet whose lattice rows and columns are doubled 40 um apart every third line (the long
thin triangles of a careless mesher, angles of 0.23 and 0.46 degrees on its 10 mm and 5 mm cells)
hangs from its top edge under gravity for 60 ms of simulated time at dt = 2 ms and 10 ms. Each
step is solved by ``auto`` (block Jacobi with the slivers' corners inverted together,
native/stiff.c) and by the Gauss-Seidel sweeps alone (``sgs``: what auto took on this sheet before
the stiff groups), each on its own cloth: median FEM time and CG iterations per step, halvings (sub-steps rolled back because a solve
reached the cap), sub-steps accepted unconverged, and the worst residual against the tolerance.
JSON: ``slivers.{dt2ms,dt10ms}.{auto,sweeps}.*`` and ``slivers.{dt2ms,dt10ms}.time_ratio``
(sweeps / auto, per step). Dev-only (not in the extension zip).

This file also owns ``sliver_sheet``, the mesh (the tests build it through tests/meshes.py).
"""
from __future__ import annotations

import statistics

import numpy as np

from ..cloth import Cloth, smallest_angles_deg
from ..materials import material
from .table1 import lattice_triangles

SIMULATED_S = 0.06
DTS = (2e-3, 10e-3)
SOLVERS = (("auto", "auto"), ("sweeps", "sgs"))


def sliver_sheet(width=0.2, height=0.1, nx=41, ny=11, gap=4e-5, every=3, seed=0):
    """A jittered sheet with slivers: after every `every`-th lattice row (and column) a copy of it
    `gap` away, so the cells between them are split into triangles whose smallest angle is about
    gap / spacing radians (0.46 degrees for 4e-5 m on 5 mm, 0.23 on 10 mm): the long thin triangles
    of a careless mesher.
    Returns (vertices (n, 3) m, triangles (m, 3))."""
    rng = np.random.default_rng(seed)
    xs = np.linspace(0, width, nx)
    ys = np.linspace(0, height, ny)
    xs = np.sort(np.concatenate([xs, xs[1:-1:every] + gap]))
    ys = np.sort(np.concatenate([ys, ys[1:-1:every] + gap]))
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    V = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], 1)
    return V, lattice_triangles(len(xs), len(ys), rng)


def min_angle_deg(V, T) -> float:
    """The smallest corner angle of the triangles (degrees)."""
    return float(smallest_angles_deg(V, T).min())


def hung_sliver_sheet(preconditioner: str = "auto") -> Cloth:
    """The sheet in cotton, pinned along its top edge, gravity on."""
    V, T = sliver_sheet()
    c = Cloth(V, T, material("cotton"), gravity=(0.0, 0.0, -9.81))
    c.pin(np.where(V[:, 1] > V[:, 1].max() - 1e-9)[0])
    c.set_solver(preconditioner=preconditioner)
    return c


def _run(dt: float, preconditioner: str) -> dict:
    c = hung_sliver_sheet(preconditioner)
    tol = c.solver["cg_tolerance"]
    fem, its, halvings, unconverged, groups, worst = [], [], 0, 0, 0, 0.0
    for _ in range(round(SIMULATED_S / dt)):
        c.step(dt)
        st = c.stats()
        fem.append(st["fem_seconds"])
        its.append(st["cg_iterations"])
        halvings += st["substep_splits"]
        unconverged += st["unconverged_substeps"]
        groups = max(groups, st["stiff_groups"])
        worst = max(worst, st["cg_residual"])
    return {"steps": len(fem), "step_ms": 1e3 * statistics.median(fem), "cg_iterations_per_step": statistics.median(its),
            "halvings": halvings, "unconverged_substeps": unconverged, "stiff_groups": groups,
            "worst_residual": worst, "tolerance": tol}


def sliver_figures() -> dict:
    V, T = sliver_sheet()
    r: dict = {"vertices": len(V), "triangles": len(T), "min_angle_deg": min_angle_deg(V, T), "simulated_s": SIMULATED_S}
    for dt in DTS:
        x = {name: _run(dt, pre) for name, pre in SOLVERS}
        x["time_ratio"] = x["sweeps"]["step_ms"] / x["auto"]["step_ms"]
        r[f"dt{dt * 1e3:g}ms"] = x
    return r


def sheet_summary(r: dict) -> str:
    """The sheet in one phrase (the bench's line and BENCHMARKS.md's section)."""
    return (f"{r['vertices']} vertices, smallest angle {r['min_angle_deg']:.2f} degrees, hung by one edge, "
            f"{1e3 * r['simulated_s']:.0f} ms simulated")


def table_lines(r: dict) -> list:
    """The markdown table: a row per step length and solver."""
    lines = ["| dt | solver | step ms | CG it./step | halvings | unconverged sub-steps | stiff groups | worst residual |",
             "|---|---|---|---|---|---|---|---|"]
    for dt in DTS:
        key = f"dt{dt * 1e3:g}ms"
        for name, _ in SOLVERS:
            x = r[key][name]
            lines.append(f"| {dt * 1e3:g} ms | {name} | {x['step_ms']:.2f} | {x['cg_iterations_per_step']:.0f} | "
                         f"{x['halvings']} | {x['unconverged_substeps']} | {x['stiff_groups']} | "
                         f"{x['worst_residual']:.1e} (tolerance {x['tolerance']:g}) |")
    return lines


def format_slivers(r: dict) -> str:
    return "\n".join([f"slivers: {sheet_summary(r)}"] + table_lines(r))
