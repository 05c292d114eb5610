"""Cluster decomposition of a deformable mesh (paper section IV-A), and its update after tearing.

This file owns the vertex -> cluster labelling of the cloth and of every deformable collider.

Why geodesic k-means: the paper clusters with k-means whose distance is the shortest path along
mesh edges, so a cluster stays a compact patch of the *surface* whatever the deformation, and it
cannot be disjoint. We make "cannot be disjoint" hold by construction:

* The assignment step is a multi-source shortest-path search (a vectorised label-correcting
  frontier, exact Dijkstra distances; scipy is not available inside Blender, and a heapq loop is
  ~10x slower on 100K vertices). Every vertex takes the label of the predecessor that gave it its
  final distance, and that predecessor is strictly closer to the same source (edge weights > 0),
  so following predecessors reaches the source without leaving the label: every cluster is
  connected.
* Size balancing (merge clusters < 50 % of the target into their smallest neighbour, split those
  > 150 % by recursive geodesic bisection) keeps connectivity (union of adjacent connected sets;
  bisection cut on d_a - d_b, see ``_bisect``), and a final ``enforce_connectivity`` pass is the
  safety net that re-attaches any stray piece, so the guarantee never rests on float ties.
* Components smaller than half the target become one (small) cluster each: they cannot be
  merged with anything they are connected to.

Tearing (events from the native core): new vertices take their first parent's label; a cluster
whose vertices are no longer connected is re-clustered alone (its pieces become clusters, large
pieces are bisected); no other vertex changes label, so the displacement history of every other
cluster pair survives a tear. A torn piece smaller than half the target stays a small cluster
rather than being merged into a neighbour (that would touch a cluster the tear did not split).

Units: positions in metres; distances along edges in metres.
"""
from __future__ import annotations

import numpy as np

__all__ = [
    "EdgeGraph",
    "Clustering",
    "build_edge_graph",
    "geodesic_voronoi",
    "connected_components",
    "cluster_mesh",
]

_MIN_EDGE = 1e-12  # metres; zero-length edges would break "predecessor is strictly closer"


class EdgeGraph:
    """Symmetric edge graph of a triangle mesh in CSR form (both directions stored)."""

    __slots__ = ("n", "indptr", "indices", "weights", "eu", "ev", "w")

    def __init__(self, n, eu, ev, w):
        # eu/ev/w hold every undirected edge once; CSR stores both directions.
        self.n = int(n)
        self.eu = eu
        self.ev = ev
        self.w = w
        src = np.concatenate([eu, ev])
        dst = np.concatenate([ev, eu])
        ww = np.concatenate([w, w])
        order = np.argsort(src, kind="stable")
        self.indices = dst[order].astype(np.int64)
        self.weights = ww[order]
        self.indptr = np.zeros(self.n + 1, np.int64)
        np.cumsum(np.bincount(src, minlength=self.n), out=self.indptr[1:])

    def subgraph(self, vertices):
        """Induced subgraph on ``vertices`` (sorted unique ids); returns (graph, global ids)."""
        vertices = np.asarray(vertices, np.int64)
        local = np.full(self.n, -1, np.int64)
        local[vertices] = np.arange(vertices.size)
        keep = (local[self.eu] >= 0) & (local[self.ev] >= 0)
        w = self.w[keep]
        return EdgeGraph(vertices.size, local[self.eu[keep]], local[self.ev[keep]], w), vertices


def build_edge_graph(positions, triangles, n=None):
    """Unique undirected edges of ``triangles`` weighted by their current length (metres)."""
    positions = np.asarray(positions, np.float64)
    n = positions.shape[0] if n is None else int(n)
    tri = np.asarray(triangles, np.int64).reshape(-1, 3)
    e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    e.sort(axis=1)
    e = e[e[:, 0] != e[:, 1]]
    key = np.unique(e[:, 0] * n + e[:, 1])
    eu, ev = key // n, key % n
    w = np.maximum(np.linalg.norm(positions[eu] - positions[ev], axis=1), _MIN_EDGE)
    return EdgeGraph(n, eu, ev, w)


def geodesic_voronoi(graph: EdgeGraph, sources):
    """Multi-source shortest paths along edges: (distance, index of the nearest source).

    Label-correcting frontier: each round relaxes only the edges out of vertices whose distance
    improved in the previous round, fully vectorised. Converges to the exact Dijkstra distances.
    Unreachable vertices keep distance inf and label -1. Ties go to the smaller source index
    (lexsort), so the result is deterministic.
    """
    n = graph.n
    dist = np.full(n, np.inf)
    label = np.full(n, -1, np.int64)
    sources = np.asarray(sources, np.int64)
    dist[sources] = 0.0
    label[sources] = np.arange(sources.size)
    active = np.unique(sources)
    indptr, indices, weights = graph.indptr, graph.indices, graph.weights
    while active.size:
        starts = indptr[active]
        counts = indptr[active + 1] - starts
        total = int(counts.sum())
        if total == 0:
            break
        offsets = np.cumsum(counts) - counts
        eidx = np.repeat(starts - offsets, counts) + np.arange(total)
        u = np.repeat(active, counts)
        v = indices[eidx]
        cand = dist[u] + weights[eidx]
        better = cand < dist[v]
        if not better.any():
            break
        v, cand, lab = v[better], cand[better], label[u[better]]
        order = np.lexsort((lab, cand, v))
        v, cand, lab = v[order], cand[order], lab[order]
        first = np.ones(v.size, bool)
        first[1:] = v[1:] != v[:-1]
        v, cand, lab = v[first], cand[first], lab[first]
        dist[v] = cand
        label[v] = lab
        active = v
    return dist, label


def connected_components(n, eu, ev):
    """Component id (the smallest vertex id in it) of each vertex of the graph (eu, ev)."""
    comp = np.arange(n, dtype=np.int64)
    eu = np.asarray(eu, np.int64)
    ev = np.asarray(ev, np.int64)
    if eu.size == 0:
        return comp
    while True:
        cu, cv = comp[eu], comp[ev]
        m = np.minimum(cu, cv)
        new = comp.copy()
        np.minimum.at(new, cu, m)
        np.minimum.at(new, cv, m)
        # Pointer jumping: components collapse in O(log diameter) rounds, not O(diameter).
        while True:
            jumped = new[new]
            if np.array_equal(jumped, new):
                break
            new = jumped
        if np.array_equal(new, comp):
            return comp
        comp = new


def _morton_seeds(positions, vertices, k):
    """k seed vertices spread over ``vertices`` by chunks of their Z-order (Morton) sort."""
    p = positions[vertices]
    lo, hi = p.min(axis=0), p.max(axis=0)
    q = ((p - lo) / np.maximum(hi - lo, 1e-30) * 1023.0).astype(np.int64)

    def spread(x):
        x = (x | (x << 16)) & 0x030000FF
        x = (x | (x << 8)) & 0x0300F00F
        x = (x | (x << 4)) & 0x030C30C3
        x = (x | (x << 2)) & 0x09249249
        return x

    code = spread(q[:, 0]) | (spread(q[:, 1]) << 1) | (spread(q[:, 2]) << 2)
    order = np.argsort(code, kind="stable")
    pick = ((np.arange(k) + 0.5) * vertices.size / k).astype(np.int64)
    return vertices[order[pick]]


def _nearest_to_centroid(positions, labels, k):
    """Per cluster, the member vertex closest to the Euclidean centroid of the members."""
    counts = np.bincount(labels, minlength=k).astype(np.float64)
    centroid = np.stack(
        [np.bincount(labels, weights=positions[:, a], minlength=k) for a in range(3)], axis=1
    ) / np.maximum(counts, 1.0)[:, None]
    d2 = np.einsum("ij,ij->i", positions - centroid[labels], positions - centroid[labels])
    order = np.lexsort((np.arange(labels.size), d2, labels))
    first = np.ones(order.size, bool)
    first[1:] = labels[order[1:]] != labels[order[:-1]]
    return order[first]


def _kmeans(graph, positions, seeds, max_iter=12):
    centres = np.asarray(seeds, np.int64)
    labels = None
    for _ in range(max_iter):
        _, labels = geodesic_voronoi(graph, centres)
        new_centres = _nearest_to_centroid(positions, labels, centres.size)
        if np.array_equal(new_centres, centres):
            break
        centres = new_centres
    _, labels = geodesic_voronoi(graph, centres)
    return labels


def _bisect(graph, positions, parts):
    """Split a connected graph into ``parts`` connected pieces of near-equal vertex count.

    Cut on f = d_a - d_b with a, b two far-apart vertices: along a shortest path to a, d_a drops
    by the edge length and d_b by at most that, so {f < c} is connected, and symmetrically
    {f >= c}. Recursive halving gives the requested number of pieces.
    """
    n = graph.n
    labels = np.zeros(n, np.int64)
    if parts <= 1 or n <= 1:
        return labels
    d0, _ = geodesic_voronoi(graph, [0])
    a = int(np.argmax(np.where(np.isfinite(d0), d0, -1)))
    da, _ = geodesic_voronoi(graph, [a])
    b = int(np.argmax(np.where(np.isfinite(da), da, -1)))
    db, _ = geodesic_voronoi(graph, [b])
    f = da - db
    order = np.argsort(f, kind="stable")
    left_parts = parts // 2
    cut = int(round(n * left_parts / parts))
    cut = min(max(cut, 1), n - 1)
    side = np.zeros(n, bool)
    side[order[cut:]] = True
    result = np.empty(n, np.int64)
    next_label = 0
    for mask, p in ((~side, left_parts), (side, parts - left_parts)):
        verts = np.flatnonzero(mask)
        sub, _ = graph.subgraph(verts)
        sub_labels = _bisect(sub, positions[verts], p)
        result[verts] = sub_labels + next_label
        next_label += int(sub_labels.max()) + 1
    return result


def _relabel_compact(labels):
    _, inv = np.unique(labels, return_inverse=True)
    return inv.astype(np.int64)


def enforce_connectivity(graph: EdgeGraph, labels, target):
    """Make every cluster connected: the largest piece keeps the label; a stray piece joins an
    adjacent cluster when small (< target/2), or becomes a cluster of its own."""
    labels = labels.copy()
    for _ in range(64):
        same = labels[graph.eu] == labels[graph.ev]
        comp = connected_components(graph.n, graph.eu[same], graph.ev[same])
        # Main piece of each label: the largest component (ties: smallest component id).
        comp_size = np.bincount(comp, minlength=graph.n)
        key_order = np.lexsort((comp, -comp_size[comp], labels))
        first = np.ones(graph.n, bool)
        first[1:] = labels[key_order[1:]] != labels[key_order[:-1]]
        main_comp = np.full(labels.max() + 1, -1, np.int64)
        main_comp[labels[key_order[first]]] = comp[key_order[first]]
        stray = comp != main_comp[labels]
        if not stray.any():
            return _relabel_compact(labels)
        next_label = labels.max() + 1
        stray_comps = np.unique(comp[stray])
        # Edges from a stray piece to a vertex of another label that sits in its main piece.
        cross = (~same) & stray[graph.eu] & ~stray[graph.ev]
        cross_r = (~same) & stray[graph.ev] & ~stray[graph.eu]
        pu = np.concatenate([graph.eu[cross], graph.ev[cross_r]])
        pv = np.concatenate([graph.ev[cross], graph.eu[cross_r]])
        sizes = np.bincount(labels)
        for c in stray_comps:
            members = comp == c
            size = int(comp_size[c])
            nbr = np.unique(labels[pv[comp[pu] == c]])
            if size < 0.5 * target and nbr.size:
                labels[members] = nbr[np.argmin(sizes[nbr])]
            else:
                labels[members] = next_label
                next_label += 1
    raise RuntimeError("cluster connectivity repair did not converge")


def _balance(graph, positions, labels, target, rounds=6):
    """Merge clusters under 50 % of the target into their smallest neighbour; bisect those over
    150 %. Components smaller than half the target cannot merge and stay as they are."""
    for _ in range(rounds):
        changed = False
        sizes = np.bincount(labels)
        lu, lv = labels[graph.eu], labels[graph.ev]
        cross = lu != lv
        cu = np.concatenate([lu[cross], lv[cross]])
        cv = np.concatenate([lv[cross], lu[cross]])
        merged = np.zeros(sizes.size, bool)
        for c in np.argsort(sizes, kind="stable"):
            if sizes[c] >= 0.5 * target:
                break
            if merged[c]:
                continue
            nbr = np.unique(cv[cu == c])
            nbr = nbr[~merged[nbr]]
            if nbr.size == 0:
                continue
            into = nbr[np.argmin(sizes[nbr])]
            labels[labels == c] = into
            sizes[into] += sizes[c]
            sizes[c] = 0
            merged[c] = True  # merged clusters no longer exist as a source or a destination
            changed = True
        labels = _relabel_compact(labels)
        sizes = np.bincount(labels)
        next_label = sizes.size
        for c in np.flatnonzero(sizes > 1.5 * target):
            verts = np.flatnonzero(labels == c)
            sub, _ = graph.subgraph(verts)
            parts = max(2, int(round(sizes[c] / target)))
            sub_labels = _bisect(sub, positions[verts], parts)
            labels[verts[sub_labels > 0]] = sub_labels[sub_labels > 0] + next_label - 1
            next_label += parts - 1
            changed = True
        labels = enforce_connectivity(graph, labels, target)
        if not changed:
            break
    return labels


def cluster_mesh(positions, triangles, target=100, graph=None):
    """Labels (n,) int64 of a geodesic k-means decomposition into ~``target`` vertices/cluster.

    Every cluster is connected; clusters of components larger than half the target hold between
    50 % and 150 % of ``target`` vertices after balancing. Deterministic for the same input.
    """
    positions = np.asarray(positions, np.float64)
    n = positions.shape[0]
    if n == 0:
        return np.zeros(0, np.int64)
    if graph is None:
        graph = build_edge_graph(positions, triangles, n)
    comp = connected_components(n, graph.eu, graph.ev)
    comp_ids, comp_inv, comp_sizes = np.unique(comp, return_inverse=True, return_counts=True)
    seeds = []
    order = np.argsort(comp_inv, kind="stable")
    bounds = np.concatenate([[0], np.cumsum(comp_sizes)])
    for i in range(comp_ids.size):
        verts = order[bounds[i] : bounds[i + 1]]
        k = max(1, int(round(verts.size / target)))
        seeds.append(_morton_seeds(positions, verts, k) if k > 1 else verts[:1])
    seeds = np.concatenate(seeds)
    labels = _kmeans(graph, positions, seeds)
    labels = _balance(graph, positions, labels, target)
    return labels


class Clustering:
    """Cluster labels of one deformable object plus the index tables the measure needs.

    ``labels`` (n,) int64 cluster of each vertex; ``tri_labels`` (m,) cluster of each triangle
    (the cluster of its first vertex: a triangle belongs to exactly one cluster's scene).
    """

    def __init__(self, positions, triangles, target=100):
        self.target = int(target)
        positions = np.asarray(positions, np.float64)
        self.graph = build_edge_graph(positions, triangles)
        self.labels = cluster_mesh(positions, triangles, self.target, self.graph)
        self._tables(triangles)

    @property
    def count(self):
        return self.n_clusters

    def _tables(self, triangles):
        tri = np.asarray(triangles, np.int64).reshape(-1, 3)
        self.n_clusters = int(self.labels.max()) + 1 if self.labels.size else 0
        self.tri_labels = self.labels[tri[:, 0]] if tri.size else np.zeros(0, np.int64)
        # Members sorted by cluster, for np.add.reduceat over displacements.
        self.order = np.argsort(self.labels, kind="stable").astype(np.int64)
        self.sizes = np.bincount(self.labels, minlength=self.n_clusters)
        self.starts = np.concatenate([[0], np.cumsum(self.sizes)[:-1]]).astype(np.int64)
        # The same as bounds (K + 1): cluster c's members are order[ptr[c]:ptr[c + 1]] (the C kernels).
        self.ptr = np.concatenate([[0], np.cumsum(self.sizes)]).astype(np.int64)
        # AABB members: a cluster's own vertices plus every vertex of its triangles, so the box
        # bounds the cluster's geometry as a ray target too.
        lab = np.concatenate([self.labels, np.repeat(self.tri_labels, 3)])
        idx = np.concatenate([np.arange(self.labels.size), tri.reshape(-1)])
        o = np.lexsort((idx, lab))
        lab, idx = lab[o], idx[o]
        keep = np.ones(idx.size, bool)
        keep[1:] = (lab[1:] != lab[:-1]) | (idx[1:] != idx[:-1])
        self.box_index = np.ascontiguousarray(idx[keep], np.int64)
        box_sizes = np.bincount(lab[keep], minlength=self.n_clusters)
        self.box_starts = np.concatenate([[0], np.cumsum(box_sizes)[:-1]]).astype(np.int64)
        self.box_ptr = np.concatenate([[0], np.cumsum(box_sizes)]).astype(np.int64)
        # Triangles per cluster, for the per-cluster scenes.
        self.tri_order = np.argsort(self.tri_labels, kind="stable").astype(np.int64)
        tri_sizes = np.bincount(self.tri_labels, minlength=self.n_clusters)
        self.tri_starts = np.concatenate([[0], np.cumsum(tri_sizes)]).astype(np.int64)

    def vertices_of(self, c):
        return self.order[self.starts[c] : self.starts[c] + self.sizes[c]]

    def triangles_of(self, c):
        return self.tri_order[self.tri_starts[c] : self.tri_starts[c + 1]]

    def update(self, events, positions, triangles):
        """Apply a tear: returns the sorted ids of clusters whose membership or geometry changed
        (their displacement history and cached scenes are no longer valid)."""
        positions = np.asarray(positions, np.float64)
        tri = np.asarray(triangles, np.int64).reshape(-1, 3)
        n = positions.shape[0]
        removed = np.asarray(events.get("removed_vertices", np.zeros(0)), np.int64).reshape(-1)
        # vertices a tiny fragment took (numbered as before the step) go first; survivors keep order
        removed = removed[(removed >= 0) & (removed < self.labels.size)]
        old = np.delete(self.labels, removed)
        gone = set(np.unique(self.labels[removed]).tolist())
        old_n = old.size
        labels = np.full(n, -1, np.int64)
        labels[: min(old_n, n)] = old[: min(old_n, n)]
        new_v = np.asarray(events.get("new_vertices", np.zeros(0)), np.int64).reshape(-1)
        parents = np.asarray(events.get("parents", np.zeros((0, 2))), np.int64).reshape(-1, 2)
        if new_v.size:
            par = parents[:, 0]
            # A parent may itself be new in the same event batch: resolve in order. A parent -1 (it
            # went with a fragment) explains nothing: the vertex is an orphan below.
            for _ in range(4):
                ok = (par >= 0) & (labels[np.maximum(par, 0)] >= 0)
                labels[new_v[ok]] = labels[par[ok]]
                if ok.all():
                    break
        orphan = labels < 0
        if orphan.any():
            # Vertices the events did not explain (should not happen) form a fresh cluster each
            # time they are seen, instead of failing the step.
            labels[orphan] = labels.max(initial=-1) + 1
        touched_tris = np.concatenate(
            [
                np.asarray(events.get("changed_triangles", np.zeros(0)), np.int64).reshape(-1),
                np.asarray(events.get("new_triangles", np.zeros(0)), np.int64).reshape(-1),
            ]
        )
        touched_tris = touched_tris[(touched_tris >= 0) & (touched_tris < tri.shape[0])]
        dirty = set(np.unique(labels[tri[touched_tris].reshape(-1)]).tolist())
        dirty |= set(np.unique(labels[new_v]).tolist()) if new_v.size else set()
        dirty |= set(np.unique(labels[orphan]).tolist()) if orphan.any() else set()
        dirty |= gone  # a cluster that lost vertices may have fallen apart
        self.graph = build_edge_graph(positions, tri, n)
        # Re-cluster only the dirty clusters that fell apart.
        next_label = int(labels.max()) + 1
        for c in sorted(dirty):
            verts = np.flatnonzero(labels == c)
            if verts.size <= 1:
                continue
            sub, _ = self.graph.subgraph(verts)
            comp = connected_components(sub.n, sub.eu, sub.ev)
            pieces, inv, psize = np.unique(comp, return_inverse=True, return_counts=True)
            if pieces.size == 1:
                continue
            keep_piece = int(np.argmax(psize))
            for p in range(pieces.size):
                pverts = verts[inv == p]
                parts = max(1, int(round(pverts.size / self.target)))
                if p == keep_piece:
                    base = c
                else:
                    base = next_label
                    next_label += 1
                if parts > 1 and pverts.size > 1.5 * self.target:
                    psub, _ = self.graph.subgraph(pverts)
                    sl = _bisect(psub, positions[pverts], parts)
                    labels[pverts] = np.where(sl == 0, base, sl - 1 + next_label)
                    new_ids = np.unique(sl[sl > 0]) - 1 + next_label
                    dirty |= set(new_ids.tolist())
                    next_label += parts - 1
                else:
                    labels[pverts] = base
                dirty.add(base)
        # Stable ids: untouched clusters keep theirs; ids freed by nothing, so no compaction.
        self.labels = labels
        self._tables(tri)
        return np.array(sorted(d for d in dirty if d < self.n_clusters), np.int64)
