"""The colliders' BVHs (native/collide/bvh.c, narrow.ClusterBVH): their first hits equal Embree's on
the same geometry as the cloth deforms (refits, no rebuild) and after a tear (a rebuild), the
detector gives the same contacts as the previous release's step, and bad trees or indices raise
clean errors."""
import numpy as np
import pytest

from tearcloth import _collide
from tearcloth.collision import kernels
from tearcloth.collision.clusters import Clustering
from tearcloth.collision.detector import CollisionDetector
from tearcloth.collision.incremental import triangle_adjacency
from tearcloth.collision.narrow import RAY_BACKOFF, ClusterBVH, build_scene, cast, ring_table

from test_collision_clusters import tear_grid


def folded(nx=21, gap=0.004, seed=0):
    """A wavy square folded onto itself (two layers gap apart, one mesh), jittered."""
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.linspace(0, 0.3, nx), np.linspace(0, 0.3, nx), indexing="ij")
    p = np.stack([x.ravel(), y.ravel(), 0.02 * np.sin(11 * x.ravel()) * np.cos(8 * y.ravel())], 1)
    p[:, :2] += rng.uniform(-0.2, 0.2, (p.shape[0], 2)) * 0.3 / nx
    idx = np.arange(nx * nx).reshape(nx, nx)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    t = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int64)
    return np.vstack([p, p + [0.002, 0.001, gap]]), np.vstack([t, t + p.shape[0]])


def deform(p0, s, seed):
    """Smooth random deformation, growing with s (centimetres by s = 4: far from the build pose)."""
    rng = np.random.default_rng(seed)
    k = rng.normal(size=(3, 3)) * 12
    ph = rng.uniform(0, 6, 3)
    w = np.sin(p0 @ k.T + ph)
    return p0 + 0.006 * s * w + rng.normal(scale=2e-4 * s, size=p0.shape)


def setup_bvh(p, t, cluster_size=60):
    cl = Clustering(p, t, cluster_size)
    adj, _ = triangle_adjacency(t)
    bvh = ClusterBVH()
    bvh.set_topology(t, cl, adj)
    bvh.build(p, t)
    return cl, bvh


def embree_first_hits(bvh, p, t, cluster, o, d, tmax, exclude):
    """Per ray, the first hit in its cluster's Embree scene built at p (the same triangles)."""
    tri = np.full(o.shape[0], -1, np.int64)
    dist = np.full(o.shape[0], np.inf)
    for c in np.unique(cluster):
        rows = np.flatnonzero(cluster == c)
        stri = bvh.tri[bvh.ptr[c]:bvh.ptr[c + 1]]
        if stri.size == 0:
            continue  # a cluster that owns no triangle has no scene (nor a tree)
        verts, local = np.unique(t[stri].reshape(-1), return_inverse=True)
        scene = build_scene(p[verts], local.reshape(-1, 3))
        ex = None if exclude is None else exclude[rows]
        tri[rows], dist[rows] = cast(scene, o[rows], d[rows], tmax, stri, ex, t, rounds=64)
    return tri, dist


def compare(bvh, p, t, ring, rng, tmax=0.02):
    """BVH vs Embree first hits of every vertex's +n / -n rays into random clusters, with and
    without the two-ring filter. Returns (rays, hits, triangles differing at equal distance)."""
    nrm, has = kernels.vertex_normals(p, t)
    v = np.repeat(np.flatnonzero(has), 2)
    sign = np.tile([1.0, -1.0], v.size // 2)
    d = nrm[v] * sign[:, None]
    k = bvh.ptr.size - 1
    # half the rays into their own vertex's cluster's neighbourhood, half anywhere
    cluster = rng.integers(0, k, v.size)
    out = (0, 0, 0)
    for use_ring in (True, False):
        tri_e, t_e = embree_first_hits(bvh, p, t, cluster, p[v], d, tmax, ring[v] if use_ring else None)
        o = p[v] - RAY_BACKOFF * d  # as narrow.cast starts its rays
        tri_b, t_b, u_b, w_b = np.empty(v.size, np.int64), np.empty(v.size), np.empty(v.size), np.empty(v.size)
        _collide.bvh_cast(positions=p, triangles=t, node_ptr=bvh.node_ptr, node=bvh.node, box=bvh.box, prim=bvh.prim,
                          cluster=cluster, origins=o, directions=d, tmax=np.full(v.size, tmax + RAY_BACKOFF),
                          ray_vertex=v if use_ring else None, ring=ring if use_ring else None, tri_out=tri_b,
                          t_out=t_b, u_out=u_b, v_out=w_b)
        t_b = t_b - RAY_BACKOFF
        hit_b, hit_e = tri_b >= 0, tri_e >= 0
        # a hit exactly at the range end may fall either side in float32, and so may (without the
        # ring) the ray's own vertex, a corner of the triangles it starts on
        t_any = np.where(hit_b, t_b, t_e)
        edge = (np.abs(t_any - tmax) < 1e-5) | (np.abs(np.where(hit_e, t_e, t_b) - tmax) < 1e-5)
        if not use_ring:
            edge |= np.abs(t_any) < 1e-5
        assert np.array_equal(hit_b[~edge], hit_e[~edge]), np.flatnonzero((hit_b != hit_e) & ~edge)
        both = hit_b & hit_e
        assert both.sum() > 50, "the rays must find something to compare"
        # float32 scene: distances agree to ~1e-6 m at these coordinates
        np.testing.assert_allclose(t_b[both], t_e[both], atol=5e-6)
        both &= ~edge
        differ = both & (tri_b != tri_e)
        # a different triangle only where the ray passes through an edge or a corner they share
        if differ.any():
            bary = np.stack([1 - u_b - w_b, u_b, w_b], 1)[differ]
            assert (bary.min(axis=1) < 1e-4).all(), bary
            shared = [len(set(t[a]) & set(t[b])) >= 1 for a, b in zip(tri_b[differ], tri_e[differ])]
            assert all(shared)
        out = tuple(np.add(out, (v.size, int(both.sum()), int(differ.sum()))))
    return out


def test_bvh_first_hits_equal_embree_on_a_deforming_cloth_and_after_a_tear():
    p0, t = folded()
    rng = np.random.default_rng(3)
    cl, bvh = setup_bvh(p0, t)
    ring = ring_table(t, p0.shape[0])
    totals = np.zeros(3, int)
    k = bvh.ptr.size - 1
    for s in range(5):
        p = deform(p0, s, seed=s)
        _collide.bvh_refit(positions=p, triangles=t, node_ptr=bvh.node_ptr, node=bvh.node, box=bvh.box,
                           prim=bvh.prim, clusters=np.arange(k, dtype=np.int64))
        totals += compare(bvh, p, t, ring, rng)
    assert bvh.builds == 1, "deformation refits, it never rebuilds"
    # Tear the lower layer along a grid line: new vertices, re-indexed triangles -> a rebuild.
    n1 = p0.shape[0] // 2
    p_low, t_low, events = tear_grid(p0[:n1], t[: t.shape[0] // 2], cl.labels[:n1], 10)
    nn = p_low.shape[0]
    p2 = np.vstack([p_low, p0[n1:]])
    t2 = np.vstack([t_low, t[t.shape[0] // 2:] - n1 + nn])
    cl2, bvh2 = setup_bvh(p2, t2)
    ring2 = ring_table(t2, p2.shape[0])
    for s in range(3):
        p = deform(p2, s + 1, seed=10 + s)
        p[n1:nn, 0] += 0.001 * s  # the torn edge opens
        _collide.bvh_refit(positions=p, triangles=t2, node_ptr=bvh2.node_ptr, node=bvh2.node, box=bvh2.box,
                           prim=bvh2.prim, clusters=np.arange(bvh2.ptr.size - 1, dtype=np.int64))
        totals += compare(bvh2, p, t2, ring2, rng)
    rays, hits, differ = totals
    assert hits > 500, totals
    assert differ <= 0.01 * hits, totals


def refit_boxes_hold_their_triangles(bvh, p, t):
    for c in range(bvh.ptr.size - 1):
        s, e = bvh.node_ptr[c], bvh.node_ptr[c + 1]
        if e == s:
            continue
        root = bvh.box[s]
        corners = p[t[bvh.tri[bvh.ptr[c]:bvh.ptr[c + 1]]].reshape(-1)]
        np.testing.assert_allclose(root[:3], corners.min(axis=0))
        np.testing.assert_allclose(root[3:], corners.max(axis=0))


def test_refit_root_box_is_the_cluster_box_and_builds_once_per_topology():
    p0, t = folded(15)
    cl, bvh = setup_bvh(p0, t)
    p = deform(p0, 4, seed=1)
    _collide.bvh_refit(positions=p, triangles=t, node_ptr=bvh.node_ptr, node=bvh.node, box=bvh.box, prim=bvh.prim,
                       clusters=np.arange(bvh.ptr.size - 1, dtype=np.int64))
    refit_boxes_hold_their_triangles(bvh, p, t)
    # every scene triangle is in exactly one leaf of its cluster
    for c in range(bvh.ptr.size - 1):
        assert sorted(bvh.prim[bvh.ptr[c]:bvh.ptr[c + 1]]) == sorted(bvh.tri[bvh.ptr[c]:bvh.ptr[c + 1]])


def moving_fold(steps=14, seed=0):
    """A folded cloth whose upper layer sinks through the contact distance and slides."""
    p0, t = folded(17, gap=0.008, seed=seed)
    n = p0.shape[0] // 2
    frames = []
    for s in range(steps):
        p = deform(p0, 0.3 * s, seed)
        p[n:, 2] -= 0.0006 * s
        p[n:, 0] += 0.0004 * s
        frames.append(p)
    return frames, t


def test_detector_contacts_equal_those_of_the_previous_step():
    """The folded cloth against itself, every pair fully detected each step: the detector's C step
    (one traversal per vertex and cluster for both rays, nearest so far carried across clusters)
    gives the contacts the previous release's step gives (collision_reference.ReferenceDetector:
    each pair's rays cast apart, self_cast), and builds its trees once."""
    from collision_reference import ReferenceDetector

    frames, t = moving_fold()
    dets = {"c": CollisionDetector(0.004, 0.3, 0.003, cluster_size=60, measure="full"),
            "reference": ReferenceDetector(0.004, 0.3, 0.003, cluster_size=60, measure="full")}
    seen = 0
    for p in frames:
        c = {mode: det.detect(p, t) for mode, det in dets.items()}
        assert isinstance(dets["c"].cloth.scenes, ClusterBVH)
        a, b = c["c"], c["reference"]
        assert np.array_equal(a.vertex, b.vertex)
        np.testing.assert_array_equal(a.depth, b.depth)
        np.testing.assert_array_equal(a.normal, b.normal)
        seen += len(a)
    assert seen > 100, "the layers must come into contact"
    assert dets["c"].cloth.scenes.builds == 1


def test_bvh_bad_trees_and_indices_raise():
    p, t = folded(9)
    cl, bvh = setup_bvh(p, t, 20)
    k = bvh.ptr.size - 1
    base = dict(positions=p, triangles=t, node_ptr=bvh.node_ptr, node=bvh.node, box=bvh.box.copy(), prim=bvh.prim)

    def refit(**kw):
        _collide.bvh_refit(**{**base, **kw, "clusters": kw.get("clusters", np.arange(k, dtype=np.int64))})

    refit()
    with pytest.raises(IndexError):
        refit(clusters=np.array([k], np.int64))
    bad = bvh.node.copy()
    inner = np.flatnonzero(bad[:, 0] >= 0)[0]
    bad[inner, 1] = inner  # a child before its parent: a cycle
    with pytest.raises(IndexError):
        refit(node=bad)
    bad = bvh.prim.copy()
    bad[3] = t.shape[0]
    with pytest.raises(IndexError):
        refit(prim=bad)
    bad = bvh.node.copy()
    leaf = np.flatnonzero(bad[:, 0] < 0)[0]
    bad[leaf, 1] = bvh.prim.size + 5
    with pytest.raises(IndexError):
        refit(node=bad)
    bad = bvh.node_ptr.copy()
    bad[-1] = bvh.node.shape[0] + 1
    with pytest.raises(IndexError):
        refit(node_ptr=bad)
    bad_t = t.copy()
    bad_t[bvh.prim[0], 1] = p.shape[0]
    with pytest.raises(IndexError):
        refit(triangles=bad_t)
    # a cast into a cluster that does not exist; the two-ring without ray vertices
    nrm, has = kernels.vertex_normals(p, t)
    outs = dict(tri_out=np.empty(1, np.int64), t_out=np.empty(1), u_out=np.empty(1), v_out=np.empty(1))
    ray = dict(origins=p[:1].copy(), directions=nrm[:1].copy(), tmax=np.array([0.01]))
    with pytest.raises(IndexError):
        _collide.bvh_cast(**base, cluster=np.array([k + 2], np.int64), **ray, **outs)
    with pytest.raises(ValueError):
        _collide.bvh_cast(**base, cluster=np.array([0], np.int64), **ray, ring=ring_table(t, p.shape[0]), **outs)
    # self_cast: a pair naming a cluster out of range; no ring; a bad ring row count
    lo, hi = kernels.cluster_boxes(cl, p, 0.004)
    ring = ring_table(t, p.shape[0])
    sc = dict(positions=p, normals=nrm, has_normal=has, order=cl.order, ptr=cl.ptr, box_lo=lo, box_hi=hi,
              triangles=t, node_ptr=bvh.node_ptr, node=bvh.node, box=bvh.box.copy(), prim=bvh.prim,
              refit_step=np.full(k, -1, np.int64), step=1, ring=ring, pair_a=np.array([0], np.int64),
              pair_b=np.array([0], np.int64), dist=0.01, backoff=1e-6, ray_vertex=np.empty(500, np.int64),
              ray_slot=np.empty(500, np.int64), hit_triangle=np.empty(500, np.int64))
    hits, rays = _collide.self_cast(**sc)
    assert rays > 0 and 0 <= hits <= rays
    with pytest.raises(IndexError):
        _collide.self_cast(**{**sc, "pair_b": np.array([k], np.int64)})
    with pytest.raises(IndexError):
        _collide.self_cast(**{**sc, "pair_a": np.array([-1], np.int64)})
    with pytest.raises(ValueError):
        _collide.self_cast(**{**sc, "ring": None})
    with pytest.raises(ValueError):
        _collide.self_cast(**{**sc, "ring": ring[:-1]})
    with pytest.raises(ValueError):
        _collide.self_cast(**{**sc, "dist": float("nan")})
    with pytest.raises(ValueError):  # the node arrays need room for 2 rows per scene triangle
        _collide.bvh_build(positions=p, triangles=t, scene_ptr=bvh.ptr, scene_triangles=bvh.tri,
                           node_ptr=np.empty(k + 1, np.int64), node=np.empty((3, 2), np.int64),
                           box=np.empty((3, 6)), prim=np.empty(bvh.tri.size, np.int64))
