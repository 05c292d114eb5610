"""Draws docs/images/soft_pins.png: what a pin group painted with a falloff does, read as Blender's
cloth reads it (weight 1 holds, a lower weight pulls with that share of Pin Stiffness) against the
old reading (every weight from 0.5 up held exactly, the rest free).

A 0.5 m cotton square lies flat, held along one edge by a pin group whose weight falls from 1 at the
edge to 0 over 10 cm (the falloff an artist paints). It settles under gravity for 1.5 s (5 ms steps);
the picture is the profile of its middle column, with the weights below. Run from the checkout:
    .venv/bin/python tools/soft_pins_picture.py [out.png]
"""
from __future__ import annotations

import sys

import numpy as np

from tearcloth import examples
from tearcloth.cloth import Cloth
from tearcloth.materials import material

FALLOFF_M = 0.10


def settled(mode: str, stiffness: float = 0.0):
    m = examples.square_cloth()
    v = m.vertices
    flat = np.stack([v[:, 0], v[:, 2] - v[:, 2].min(), np.zeros(len(v))], axis=1)  # lying in z = 0
    c = Cloth(flat, m.triangles, material("cotton"))
    y = flat[:, 1]
    w = np.clip(1.0 - (y.max() - y) / FALLOFF_M, 0.0, 1.0)
    if mode == "hard":  # the old reading: held from 0.5 up, free below
        c.pin(np.flatnonzero(w >= 0.5))
    else:
        c.pin_weights(w, stiffness)
    for _ in range(300):
        c.step(0.005)
    return flat, w, c.positions


def main(out: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cases = [("hard", 0.0, "before: weights >= 0.5 held, the rest free", "tab:red"),
             ("soft", 1000.0, "Pin Stiffness 1000 1/s² (default)", "tab:blue"),
             ("soft", 100.0, "Pin Stiffness 100 1/s²", "tab:green")]
    fig, (ax, axw) = plt.subplots(2, 1, figsize=(7, 7), dpi=110, sharex=True, gridspec_kw=dict(height_ratios=[3, 1]))
    for mode, stiffness, label, colour in cases:
        rest, w, x = settled(mode, stiffness)
        mid = np.abs(rest[:, 0] - np.median(rest[:, 0])) < 0.012
        order = np.argsort(rest[mid, 1])
        ax.plot(x[mid][order, 1], x[mid][order, 2], "-", color=colour, label=label)
    ax.axhline(0.0, color="0.7", lw=0.8)
    ax.set_ylabel("height (m)")
    ax.set_title("Its middle column, settled under gravity (the held edge at 0.5 m)", fontsize=10)
    ax.legend(loc="lower left", fontsize=8)
    ys = np.sort(rest[:, 1])
    axw.plot(ys, np.clip(1.0 - (ys.max() - ys) / FALLOFF_M, 0.0, 1.0), color="0.3")
    axw.axhline(0.5, color="tab:red", lw=0.8, ls=":")
    axw.set_ylabel("pin weight")
    axw.set_xlabel("across the sheet (m); below: the pin weight at each vertex's place at rest")
    axw.set_xlim(0.38, 0.505)
    fig.suptitle("A 0.5 m cotton square lying flat, held along one edge by a painted pin group")
    fig.tight_layout()
    fig.savefig(out)
    print(f"wrote {out}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "docs/images/soft_pins.png")
