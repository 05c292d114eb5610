"""Cluster decomposition: connected by construction, balanced, deterministic, and updated locally
after a synthetic tear."""
import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings, strategies as st
from scipy.sparse.csgraph import connected_components, dijkstra

from tearcloth.collision.clusters import (
    Clustering,
    build_edge_graph,
    cluster_mesh,
    geodesic_voronoi,
)


def grid(nx, ny, size=1.0):
    x, y = np.meshgrid(np.linspace(0, size, nx), np.linspace(0, size * ny / nx, ny), indexing="ij")
    p = np.stack([x.ravel(), y.ravel(), np.zeros(nx * ny)], 1)
    idx = np.arange(nx * ny).reshape(nx, ny)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    t = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int32)
    return p, t


def components_per_cluster(n, triangles, labels):
    """Number of connected pieces of every cluster (via scipy, independent of the code under test)."""
    e = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    same = labels[e[:, 0]] == labels[e[:, 1]]
    g = sp.coo_matrix((np.ones(same.sum()), (e[same, 0], e[same, 1])), shape=(n, n))
    _, comp = connected_components(g, directed=False)
    return np.array([np.unique(comp[labels == c]).size for c in range(labels.max() + 1)])


def test_geodesic_voronoi_matches_scipy_dijkstra():
    p, t = grid(30, 20)
    rng = np.random.default_rng(3)
    p[:, 2] = 0.05 * rng.normal(size=len(p))
    g = build_edge_graph(p, t)
    sources = np.array([0, 250, 599])
    dist, lab = geodesic_voronoi(g, sources)
    m = sp.coo_matrix((g.w, (g.eu, g.ev)), shape=(g.n, g.n))
    ref = dijkstra(m, directed=False, indices=sources)
    np.testing.assert_allclose(dist, ref.min(axis=0), rtol=1e-12)
    assert np.all(ref[lab, np.arange(g.n)] <= ref.min(axis=0) + 1e-12)


@pytest.mark.parametrize("target", [30, 100])
def test_grid_clusters_connected_balanced_deterministic(target):
    p, t = grid(58, 58)
    p[:, 2] = 0.1 * np.sin(5 * p[:, 0]) * np.cos(3 * p[:, 1])
    labels = cluster_mesh(p, t, target)
    assert np.array_equal(labels, cluster_mesh(p, t, target))
    assert (components_per_cluster(len(p), t, labels) == 1).all()
    sizes = np.bincount(labels)
    assert sizes.min() >= 0.5 * target and sizes.max() <= 1.5 * target, (sizes.min(), sizes.max())
    assert abs(labels.max() + 1 - len(p) / target) <= 0.25 * len(p) / target


def test_disconnected_components_and_isolated_vertices():
    p1, t1 = grid(20, 20)
    p2, t2 = grid(6, 6)  # 36 vertices: smaller than half of 100 -> one small cluster
    p3, t3 = grid(25, 12)
    p = np.vstack([p1, p2 + [2, 0, 0], p3 + [4, 0, 0], [[9, 9, 9]]])  # plus one isolated vertex
    t = np.vstack([t1, t2 + len(p1), t3 + len(p1) + len(p2)])
    labels = cluster_mesh(p, t, 100)
    assert (components_per_cluster(len(p), t, labels) == 1).all()
    # no cluster spans two components
    e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]]])
    g = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(len(p), len(p)))
    _, comp = connected_components(g, directed=False)
    for c in range(labels.max() + 1):
        assert np.unique(comp[labels == c]).size == 1
    small = labels[len(p1) : len(p1) + len(p2)]
    assert np.unique(small).size == 1 and np.sum(labels == small[0]) == 36
    assert np.sum(labels == labels[-1]) == 1  # the isolated vertex is alone
    sizes = np.bincount(labels)
    big = [labels[0], labels[len(p1) + len(p2)]]
    for c in range(labels.max() + 1):
        if np.isin(c, labels[: len(p1)]) or np.isin(c, labels[len(p1) + len(p2) : -1]):
            assert 50 <= sizes[c] <= 150
    assert all(sizes[b] >= 50 for b in big)


@settings(max_examples=15, deadline=None)
@given(
    nx=st.integers(8, 45),
    ny=st.integers(8, 45),
    target=st.integers(10, 120),
    seed=st.integers(0, 2**16),
)
def test_random_meshes_clusters_connected_and_balanced(nx, ny, target, seed):
    p, t = grid(nx, ny)
    rng = np.random.default_rng(seed)
    p += rng.normal(scale=0.2 / nx, size=p.shape)  # uneven edge lengths
    keep = rng.random(len(t)) > 0.05  # holes, sometimes islands
    t = t[keep]
    labels = cluster_mesh(p, t, target)
    assert (components_per_cluster(len(p), t, labels) == 1).all()
    e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    g = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(len(p), len(p)))
    _, comp = connected_components(g, directed=False)
    comp_size = np.bincount(comp)
    sizes = np.bincount(labels)
    for c in range(labels.max() + 1):
        members = labels == c
        csize = comp_size[comp[members][0]]
        if csize >= 0.5 * target:
            assert 0.5 * target <= sizes[c] <= 1.5 * target, (c, sizes[c], csize)
        else:
            assert sizes[c] == csize  # a small component is exactly one cluster


def tear_grid(p, t, labels, col):
    """Cut the grid along the vertical line x = col (interior rows), duplicating those vertices
    for the triangles on the right: the events the native core would report."""
    nx = int(round(np.sqrt(len(p))))
    xs = np.unique(p[:, 0])
    line = np.flatnonzero(np.isclose(p[:, 0], xs[col]))
    new_ids = np.arange(len(p), len(p) + len(line))
    remap = np.arange(len(p))
    remap[line] = new_ids
    centroid_x = p[t].mean(axis=1)[:, 0]
    right = centroid_x > xs[col]
    t2 = t.copy()
    t2[right] = remap[t[right]]
    p2 = np.vstack([p, p[line]])
    events = {
        "new_vertices": new_ids.astype(np.int32),
        "parents": np.stack([line, np.full(len(line), -1)], 1).astype(np.int32),
        "weights": np.ones(len(line)),
        "changed_triangles": np.flatnonzero(right & np.isin(t, line).any(axis=1)).astype(np.int32),
        "new_triangles": np.zeros(0, np.int32),
    }
    return p2, t2, events


def test_tear_reclusters_only_the_split_cluster():
    p, t = grid(40, 40)
    c = Clustering(p, t, 100)
    before = c.labels.copy()
    # Cut where a cluster straddles the line x = col, across the whole sheet.
    p2, t2, ev = tear_grid(p, t, before, 20)
    dirty = c.update(ev, p2, t2)
    after = c.labels
    n0 = len(p)
    assert (components_per_cluster(len(p2), t2, after) == 1).all()
    # New vertices joined their parent's cluster, or that cluster's re-clustered pieces.
    split = [k for k in range(before.max() + 1)
             if np.unique(after[: n0][before == k]).size > 1 or np.any(after[n0:][before[ev["parents"][:, 0]] == k] != k)]
    assert split, "the cut must split at least one cluster"
    # Vertices of clusters that were not split keep their label.
    untouched = ~np.isin(before, split)
    assert np.array_equal(after[:n0][untouched], before[untouched])
    assert set(split) <= set(dirty.tolist())
    # Every new id comes from a split cluster's vertices.
    new_ids = np.setdiff1d(np.unique(after), np.unique(before))
    for k in new_ids:
        members = np.flatnonzero(after == k)
        parent_label = np.where(members < n0, before[np.minimum(members, n0 - 1)],
                                before[ev["parents"][:, 0]][np.maximum(members - n0, 0)])
        assert np.isin(parent_label, split).all()


def test_tear_without_split_changes_no_label():
    p, t = grid(30, 30)
    c = Clustering(p, t, 100)
    before = c.labels.copy()
    # A slit inside one row of the sheet that does not separate anything: duplicate one
    # interior vertex for the triangles on one side only (the cut is not through).
    v = 15 * 30 + 15
    t2 = t.copy()
    side = (p[t].mean(axis=1)[:, 0] > p[v, 0]) & (p[t].mean(axis=1)[:, 1] > p[v, 1]) & np.isin(t, v).any(axis=1)
    t2[side] = np.where(t[side] == v, len(p), t[side])
    p2 = np.vstack([p, p[v]])
    ev = {"new_vertices": np.array([len(p)]), "parents": np.array([[v, -1]]), "weights": np.ones(1),
          "changed_triangles": np.flatnonzero(side), "new_triangles": np.zeros(0, int)}
    c.update(ev, p2, t2)
    assert np.array_equal(c.labels[: len(p)], before)
    assert c.labels[len(p)] == before[v]
