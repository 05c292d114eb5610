"""The paper's Fig. 1 - a square cloth held at its top corners by two hands that pull apart until
it tears. `tearcloth demo` (``run``) bakes the Blender example through ``cli.demo``;
``simulate``/``run_without_blender`` do the same with the Python API alone (tests, no bpy)."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from .cloth import Cloth
from .haptics.forcelog import ForceLog
from .materials import material

DT = 1e-3
SPEED = 0.05  # m/s per hand, apart


def simulate(duration: float = 1.6, tear_stress: float = 2.0e6):
    """Returns (cloth, force log, first tear time or None)."""
    from . import examples  # dev-only (scipy): only the bpy-free demo generates its sheet

    mesh = examples.square_cloth()
    c = Cloth(mesh.vertices, mesh.triangles, material("cotton", tear_stress=tear_stress), uv=mesh.loop_uv(),
              groups=mesh.groups)
    hl, hr = c.add_handle("handle_left"), c.add_handle("handle_right")
    c.set_tearing(True)
    log = ForceLog(("left", "right"))
    first = None
    steps = int(round(duration / DT))
    for i in range(steps):
        t = (i + 1) * DT
        d = SPEED * max(0.0, t - 0.2)  # hang still for 0.2 s, then pull
        c.move_handle(hl, (-d, 0.0, 0.0))
        c.move_handle(hr, (d, 0.0, 0.0))
        c.step(DT)
        # the hand feels the force the cloth exerts on the handle (eq. 6)
        log.record("left", t, c.handle_force(hl))
        log.record("right", t, c.handle_force(hr))
        if first is None and c.stats()["tears_started"]:
            first = t
    return c, log, first


def render(c: Cloth, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import cm

    P, T = c.positions, c.triangles
    s1 = np.clip(c.principal_stress[:, 0], 0, None)
    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    surf = ax.plot_trisurf(P[:, 0], P[:, 1], P[:, 2], triangles=T, linewidth=0.1, edgecolor=(0, 0, 0, 0.25))
    colors = cm.inferno(0.15 + 0.8 * s1 / max(s1.max(), 1e-9))
    surf.set_facecolors(colors)
    ax.view_init(elev=8, azim=-90)
    ax.set_box_aspect(np.ptp(P, axis=0) + 1e-3)
    ax.set_axis_off()
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run(out_dir: str = "tearcloth_demo"):
    """The demo as the README runs it: bake example_blends/square_cloth.blend in Blender (bpy)."""
    from .cli import demo

    return demo(out_dir)


def run_without_blender(out_dir: str = "tearcloth_demo") -> dict:
    """The same tear simulated with the Python API alone (no bpy), pictures from matplotlib."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    c, log, first = simulate()
    wall = time.perf_counter() - t0
    st = c.stats()
    title = f"square cloth, {st['cuts']} cuts, {c.num_triangles} triangles"
    render(c, out / "torn_cloth.png", title)
    log.to_csv(out / "forces.csv")
    log.plot(out / "forces.png", axis=(1.0, 0.0, 0.0), title="Force felt by each hand (along the pull)")
    summary = {"wall_s": wall, "tears_started": st["tears_started"], "cuts": st["cuts"], "first_tear_s": first,
               "triangles": c.num_triangles, "out": str(out)}
    print(f"tore {st['tears_started']} time(s), {st['cuts']} cut segments, first tear at "
          f"{first if first is None else round(first, 3)} s; simulated 1.6 s in {wall:.2f} s")
    print(f"wrote {out / 'torn_cloth.png'}, {out / 'forces.png'}, {out / 'forces.csv'}")
    return summary
