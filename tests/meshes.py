"""Small meshes for tests: strips and sheets, regular or jittered (irregular), in the xy plane."""
import numpy as np


def sheet(width=0.2, height=0.05, nx=41, ny=11, jitter=0.0, seed=0, z=0.0):
    """A width x height sheet on an nx x ny lattice. jitter (fraction of the spacing) moves
    interior vertices at random and diagonals are chosen at random, so the triangulation is
    irregular; the boundary stays straight."""
    rng = np.random.default_rng(seed)
    xs, ys = np.meshgrid(np.linspace(0, width, nx), np.linspace(0, height, ny), indexing="ij")
    V = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, z)], 1)
    if jitter:
        dx, dy = width / (nx - 1), height / (ny - 1)
        inner = (xs.ravel() > 1e-12) & (xs.ravel() < width - 1e-12) & (ys.ravel() > 1e-12) & (ys.ravel() < height - 1e-12)
        V[inner, 0] += rng.uniform(-jitter, jitter, inner.sum()) * dx
        V[inner, 1] += rng.uniform(-jitter, jitter, inner.sum()) * dy
    idx = lambda i, j: i * ny + j
    T = []
    for i in range(nx - 1):
        for j in range(ny - 1):
            a, b, c, d = idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1)
            flip = rng.random() < 0.5 if jitter else (i + j) % 2
            if jitter:
                # a jittered quad may be non-convex: keep the diagonal whose triangles stay positive
                def smallest(tris):
                    return min(np.cross(V[q[1]] - V[q[0]], V[q[2]] - V[q[0]])[2] for q in tris)
                ok_flip = smallest([[a, b, c], [a, c, d]]) > 0
                ok_keep = smallest([[a, b, d], [b, c, d]]) > 0
                flip = (flip and ok_flip) or not ok_keep
            if flip:
                T += [[a, b, c], [a, c, d]]
            else:
                T += [[a, b, d], [b, c, d]]
    return V, np.array(T, dtype=np.int32)


def sliver_sheet(**kw):
    """The bench's sheet with 0.23-0.46-degree slivers (tearcloth.bench.slivers.sliver_sheet: rows and
    columns doubled 40 um apart): the long thin triangles of a careless mesher."""
    from tearcloth.bench.slivers import sliver_sheet as sheet

    return sheet(**kw)
