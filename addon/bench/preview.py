"""PNG preview of a cluster decomposition (like the paper's Fig. 2 and 3), for docs and checks.
Dev-only (matplotlib), used by ``tearcloth clusters``; Blender previews clusters with its own
operator (vertex colours, ``blender/ops.py``).

This file owns ``render_clusters``: vertices coloured by cluster (matplotlib, Agg backend, no
display needed), optionally with a line between the centres of every close cluster pair.
"""
from __future__ import annotations

import numpy as np

__all__ = ["render_clusters"]


def render_clusters(path, positions, triangles, labels, pairs=None, title=None, elev=25, azim=-60):
    """Write a PNG of the mesh with its vertices coloured by ``labels``.

    ``pairs`` optional (k,2) cluster index pairs drawn as white lines between cluster centroids
    (the close pairs of Fig. 3). Returns ``path``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    p = np.asarray(positions, np.float64)
    tri = np.asarray(triangles, np.int64)
    labels = np.asarray(labels, np.int64)
    k = int(labels.max()) + 1
    # Shuffled colours so that neighbouring clusters (consecutive ids) do not look alike.
    rng = np.random.default_rng(7)
    colours = plt.get_cmap("tab20")(rng.permutation(k) % 20)
    fig = plt.figure(figsize=(8, 8), dpi=110)
    ax = fig.add_subplot(111, projection="3d")
    faces = Poly3DCollection(p[tri], facecolors=colours[labels[tri[:, 0]]], edgecolors="none", alpha=0.9)
    ax.add_collection3d(faces)
    if pairs is not None and len(pairs):
        centre = np.stack([np.bincount(labels, weights=p[:, a], minlength=k) for a in range(3)], 1)
        centre /= np.maximum(np.bincount(labels, minlength=k), 1)[:, None]
        for a, b in np.asarray(pairs):
            if a != b:
                seg = centre[[a, b]]
                ax.plot(seg[:, 0], seg[:, 1], seg[:, 2], color="white", lw=0.8)
    lo, hi = p.min(axis=0), p.max(axis=0)
    mid, half = (lo + hi) / 2, (hi - lo).max() / 2
    ax.set_xlim(mid[0] - half, mid[0] + half)
    ax.set_ylim(mid[1] - half, mid[1] + half)
    ax.set_zlim(mid[2] - half, mid[2] + half)
    ax.view_init(elev=elev, azim=azim)
    ax.set_facecolor("0.15")
    ax.set_axis_off()
    ax.set_title(title or f"{p.shape[0]} vertices, {k} clusters", color="k")
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)
    return path
