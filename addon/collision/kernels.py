"""Python face of the native collision kernels (``tearcloth._collide``, sources ``native/collide/``).

This file owns the calls into C: it allocates the outputs, keeps the workspaces that grow with
the scene (pair lists, ray buffers) and hands back numpy arrays. It passes every argument by
keyword: the names are those of each kernel's argument table (``native/collide/pymodule.c``, also
in each kernel's docstring), so a call cannot shift an array into the wrong slot. The C module checks every
argument (dtype, shape, contiguity, overlap, every index it reads) and raises TypeError /
ValueError / IndexError itself; what is here is bookkeeping, not validation.

Each kernel has a numpy reference that is its specification (the tests compare
them on random inputs): ``narrow.VertexNormals``, ``measure.cluster_motion``, ``cluster_boxes``,
``box_pairs``, ``RelativeMeasure.step_reference``, ``measure.cluster_fit``, ``measure.pair_motion``,
``TripMeasure.step_reference``, ``incremental.walk``, and
``merge_classify`` / ``assemble`` of ``tests/collision_reference.py``.
"""
from __future__ import annotations

import numpy as np

from .. import _collide

__all__ = [
    "vertex_normals",
    "cluster_motion",
    "cluster_boxes",
    "box_pairs",
    "cluster_fit",
    "pair_motion",
    "walk",
    "Hits",
    "RayBuffer",
    "KIND",
]

KIND = {"volume": 0, "surface": 1, "self": 2}

EMPTY_I64 = np.zeros(0, np.int64)
EMPTY_F64 = np.zeros(0, np.float64)
EMPTY_BOOL = np.zeros(0, bool)


NO_HITS = None  # set below, once Hits exists


def vertex_normals(positions, triangles):
    """Area-weighted unit vertex normals (n, 3) and has_normal (n,) bool."""
    n = positions.shape[0]
    out = np.empty((n, 3))
    has = np.empty(n, bool)
    _collide.vertex_normals(positions=positions, triangles=triangles, normals=out, has_normal=has)
    return out, has


def cluster_motion(clustering, positions, previous):
    """dis_avg (K, 3) and dis_dev (K,) of the displacement positions - previous per cluster."""
    k = clustering.n_clusters
    avg = np.empty((k, 3))
    dev = np.empty(k)
    _collide.cluster_motion(positions=positions, previous=previous, order=clustering.order, ptr=clustering.ptr,
                            avg=avg, dev=dev)
    return avg, dev


def cluster_boxes(clustering, positions, inflate):
    """Inflated AABBs (lo, hi) (K, 3) of each cluster's vertices and triangles."""
    k = clustering.n_clusters
    lo = np.empty((k, 3))
    hi = np.empty((k, 3))
    _collide.cluster_boxes(positions=positions, index=clustering.box_index, ptr=clustering.box_ptr,
                           inflate=float(inflate), lo=lo, hi=hi)
    return lo, hi


def box_pairs(lo_a, hi_a, lo_b, hi_b, self_pairs=False):
    """Overlapping box pairs (i, j), row-major; with self_pairs only j >= i."""
    ka, kb = lo_a.shape[0], lo_b.shape[0]
    cap = max(16, min(ka * kb, 8 * (ka + kb)))
    while True:
        i = np.empty(cap, np.int64)
        j = np.empty(cap, np.int64)
        count = _collide.box_pairs(lo_a=lo_a, hi_a=hi_a, lo_b=lo_b, hi_b=hi_b, self_pairs=bool(self_pairs), i=i, j=j)
        if count <= cap:
            return i[:count], j[:count]
        cap = count


def cluster_fit(clustering, positions, previous, reach):
    """(K, 17) affine fit per cluster of the displacement positions - previous (measure.py)."""
    fit = np.empty((clustering.n_clusters, 17))
    _collide.cluster_fit(positions=positions, previous=previous, order=clustering.order, ptr=clustering.ptr,
                         reach=float(reach), fit=fit)
    return fit


def pair_motion(i, j, a, b, reach):
    """Per pair, the step's bound on a vertex's motion towards the other cluster (measure.py); a, b =
    (clustering, positions, previous, fit)."""
    bound = np.empty(i.shape[0])
    _collide.pair_motion(i=i, j=j, positions_a=a[1], previous_a=a[2], order_a=a[0].order, ptr_a=a[0].ptr,
                         fit_a=a[3], positions_b=b[1], previous_b=b[2], order_b=b[0].order, ptr_b=b[0].ptr,
                         fit_b=b[3], reach=float(reach), bound=bound)
    return bound


class Hits:
    """Parallel arrays of ray hits: tri (k,) triangle or -1, t (signed distance along the ray
    direction), u / v (barycentrics of corners 1 and 2), flips (orientation parity crossed)."""

    __slots__ = ("tri", "t", "u", "v", "flips")

    def __init__(self, k):
        self.tri = np.empty(k, np.int64)
        self.t = np.empty(k)
        self.u = np.empty(k)
        self.v = np.empty(k)
        self.flips = np.empty(k, bool)

    @staticmethod
    def view(tri, t, u, v, flips):
        out = Hits.__new__(Hits)
        out.tri, out.t, out.u, out.v, out.flips = tri, t, u, v, flips
        return out

    def head(self, k):
        out = Hits.__new__(Hits)
        out.tri, out.t, out.u, out.v, out.flips = self.tri[:k], self.t[:k], self.u[:k], self.v[:k], self.flips[:k]
        return out


NO_HITS = Hits(0)


def walk(positions, normals, ray_vertex, ray_slot, start, target, ring=None, max_steps=8):
    """Walk the rays (vertex, slot) from their start triangles over ``target``'s adjacency."""
    res = Hits(ray_vertex.shape[0])
    _collide.walk(positions=positions, normals=normals, ray_vertex=ray_vertex, ray_slot=ray_slot, start=start,
                  target_vertices=target.vertices, target_triangles=target.triangles, adjacency=target.adj,
                  flip=target.flip, ring=ring, max_steps=int(max_steps), tri_out=res.tri, t_out=res.t, u_out=res.u,
                  v_out=res.v, flips_out=res.flips)
    return res


class RayBuffer:
    """Reused float32 ray arrays for Embree, grown when a step needs more rays."""

    def __init__(self):
        self._grow(1024)

    def _grow(self, cap):
        self.cap = int(cap)
        self.o = np.empty((cap, 3), np.float32)
        self.d = np.empty((cap, 3), np.float32)
        self.dist = np.empty(cap, np.float32)
        self.vertex = np.empty(cap, np.int64)
        self.slot = np.empty(cap, np.int64)

    _none = (np.empty((0, 3), np.float32), np.empty((0, 3), np.float32), np.empty(0, np.float32),
             np.empty(0, np.int64), np.empty(0, np.int64))

    def _setup(self, positions, normals, has_normal, long_mask, clustering, box_lo, box_hi, pair_a, pair_b,
               clusters, scenes, short_dist, long_dist, backoff, tolerance):
        """The inputs of ``_collide.prepare_rays`` by name (its outputs are added by the callers)."""
        return dict(positions=positions, normals=normals, has_normal=has_normal, long_mask=long_mask,
                    order=clustering.order, ptr=clustering.ptr, box_lo=box_lo, box_hi=box_hi, pair_a=pair_a,
                    pair_b=pair_b, clusters=clusters, R=scenes.R, centre=scenes.centre,
                    ref_centre=scenes.ref_centre, short_dist=float(short_dist), long_dist=float(long_dist),
                    backoff=float(backoff), tolerance=float(tolerance))

    def count(self, positions, normals, has_normal, long_mask, clustering, box_lo, box_hi, pair_a, pair_b,
              clusters, scenes, short_dist, long_dist, backoff, tolerance):
        """Only the segment bounds (q + 1) of ``prepare``: how many rays each cluster would get."""
        seg = np.empty(clusters.size + 1, np.int64)
        o, d, dist, vertex, slot = self._none
        _collide.prepare_rays(
            **self._setup(positions, normals, has_normal, long_mask, clustering, box_lo, box_hi, pair_a, pair_b,
                          clusters, scenes, short_dist, long_dist, backoff, tolerance),
            origins=o, directions=d, dists=dist, ray_vertex=vertex, ray_slot=slot, segments=seg,
        )
        return seg

    def prepare(self, positions, normals, has_normal, long_mask, clustering, box_lo, box_hi, pair_a, pair_b,
                clusters, scenes, short_dist, long_dist, backoff, tolerance):
        """Rays of the pairs (pair_a cloth cluster, pair_b collider cluster, sorted by pair_b),
        culled against the collider boxes, in each scene's build frame. Returns (count, seg)."""
        seg = np.empty(clusters.size + 1, np.int64)
        inputs = self._setup(positions, normals, has_normal, long_mask, clustering, box_lo, box_hi, pair_a, pair_b,
                             clusters, scenes, short_dist, long_dist, backoff, tolerance)
        while True:
            count = _collide.prepare_rays(**inputs, origins=self.o, directions=self.d, dists=self.dist,
                                          ray_vertex=self.vertex, ray_slot=self.slot, segments=seg)
            if count <= self.cap:
                return count, seg
            self._grow(max(count, 2 * self.cap))
