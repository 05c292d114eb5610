"""The swept (continuous) kernels of native/collide/ccd.c against a dense-sampling oracle: a
vertex driven through a triangle, and an edge driven through an edge, are found with the right
side and time; pairs that stay apart are not."""
import numpy as np
import pytest

from tearcloth import _collide


def _closest_on_triangles(X, m=60):
    """Oracle: X (k, 4, 3) rows of (p, a, b, c); (k,) distances from p to a dense barycentric grid
    of (a, b, c) (fine enough for the margins below), all configurations at once."""
    u, v = np.meshgrid(np.linspace(0, 1, m), np.linspace(0, 1, m))
    keep = u + v <= 1
    u, v = u[keep], v[keep]
    p, a, b, c = (X[:, i] for i in range(4))
    # q - p = (a - p) + u (b - a) + v (c - a), per axis: (k, grid) at a time
    d2 = sum((a[:, k, None] - p[:, k, None] + u[None] * (b - a)[:, k, None] + v[None] * (c - a)[:, k, None]) ** 2
             for k in range(3))
    return np.sqrt(d2.min(axis=1))


def test_vertex_driven_through_a_triangle_is_found_with_its_side_and_time():
    rng = np.random.default_rng(0)
    tri = np.array([[1, 2, 3]], np.int64)
    found = 0
    for _ in range(200):
        a, b, c = rng.normal(size=(3, 3)) * 0.01
        n = np.cross(b - a, c - a)
        n /= np.linalg.norm(n)
        w = rng.dirichlet([2, 2, 2])
        foot = w[0] * a + w[1] * b + w[2] * c
        side = rng.choice([-1, 1])
        s_hit = rng.uniform(0.1, 0.9)
        speed = rng.uniform(0.002, 0.02)  # m over the interval: up to 5x the gap
        p0 = foot + side * n * speed * s_hit
        p1 = foot - side * n * speed * (1 - s_hit)
        drift = rng.normal(size=3) * 0.001  # the whole pair moves too
        x0 = np.array([p0, a, b, c])
        x1 = np.array([p1, a, b, c]) + drift
        toi, wt, sd = np.empty(1), np.empty((1, 3)), np.empty(1, np.int8)
        hits = _collide.ccd_vertex_triangle(start=x0, end=x1, triangles=tri, vertex=np.array([0]),
                                            triangle=np.array([0]), gap=0.0, toi=toi, weights=wt, side=sd)
        assert hits == 1
        assert abs(toi[0] - s_hit) < 1e-6
        assert sd[0] == side
        assert np.allclose(wt[0], w, atol=1e-6)
        found += 1
    assert found == 200


def test_vertex_passing_beside_or_staying_away_is_not_a_hit():
    rng = np.random.default_rng(1)
    tri = np.array([[1, 2, 3]], np.int64)
    gap = 0.001
    checked = 0
    for _ in range(300):
        x0 = rng.normal(size=(4, 3)) * 0.01
        x1 = x0 + rng.normal(size=(4, 3)) * 0.005
        toi, wt, sd = np.empty(1), np.empty((1, 3)), np.empty(1, np.int8)
        _collide.ccd_vertex_triangle(start=x0, end=x1, triangles=tri, vertex=np.array([0]), triangle=np.array([0]),
                                     gap=gap, toi=toi, weights=wt, side=sd)
        s = np.linspace(0, 1, 201)
        X = x0[None] + s[:, None, None] * (x1 - x0)[None]  # the pair at each of the 201 times
        d = _closest_on_triangles(X)
        if d.min() > 1.2 * gap:
            assert not np.isfinite(toi[0]), "a hit where the vertex never came within the gap"
            checked += 1
        # a crossing of the plane inside the triangle must be found, at the oracle's time
        f = np.einsum("ij,ij->i", X[:, 0] - X[:, 1], np.cross(X[:, 2] - X[:, 1], X[:, 3] - X[:, 1]))
        through = (np.sign(f[1:]) != np.sign(f[:-1])) & (np.minimum(d[1:], d[:-1]) < 0.2 * gap)
        if through.any():
            assert np.isfinite(toi[0]) and toi[0] <= s[np.argmax(through) + 1] + 1e-9
    assert checked > 100


def test_edge_driven_through_an_edge_is_found_with_its_side():
    rng = np.random.default_rng(2)
    for _ in range(200):
        mid = rng.normal(size=3) * 0.01
        u = rng.normal(size=3); u /= np.linalg.norm(u)
        v = np.cross(u, rng.normal(size=3)); v /= np.linalg.norm(v)
        n = np.cross(u, v); n /= np.linalg.norm(n)
        sa, tb = rng.uniform(0.2, 0.8, 2)
        la, lb = rng.uniform(0.005, 0.02, 2)
        side = rng.choice([-1, 1])
        s_hit = rng.uniform(0.1, 0.9)
        speed = rng.uniform(0.002, 0.02)
        a0 = mid - sa * la * u + side * n * speed * s_hit
        b0 = a0 + la * u
        c0 = mid - tb * lb * v
        d0 = c0 + lb * v
        x0 = np.array([a0, b0, c0, d0])
        x1 = x0.copy()
        x1[:2] -= side * n * speed  # edge ab crosses edge cd at s_hit
        toi, st, sd = np.empty(1), np.empty((1, 2)), np.empty(1, np.int8)
        hits = _collide.ccd_edge_edge(start=x0, end=x1, edge_a=np.array([[0, 1]]), edge_b=np.array([[2, 3]]), gap=0.0,
                                      toi=toi, params=st, side=sd)
        assert hits == 1
        assert abs(toi[0] - s_hit) < 1e-6
        assert sd[0] == side
        assert np.allclose(st[0], [sa, tb], atol=1e-6)
        # the state now agrees: ab is on the other side of cd
        sdist, dist, par, nrm = np.empty(1), np.empty(1), np.empty((1, 2)), np.empty((1, 3))
        _collide.edge_edge_state(positions=x1, edge_a=np.array([[0, 1]]), edge_b=np.array([[2, 3]]), sd=sdist,
                                 dist=dist, params=par, normal=nrm)
        assert np.sign(sdist[0]) == -side


def test_bad_pairs_raise():
    x = np.zeros((4, 3))
    out = dict(toi=np.empty(1), weights=np.empty((1, 3)), side=np.empty(1, np.int8))
    import pytest
    with pytest.raises(IndexError, match="triangle 5"):
        _collide.ccd_vertex_triangle(start=x, end=x, triangles=np.array([[1, 2, 3]]), vertex=np.array([0]),
                                     triangle=np.array([5]), gap=0.0, **out)
    with pytest.raises(ValueError, match="corner"):
        _collide.ccd_vertex_triangle(start=x, end=x, triangles=np.array([[0, 2, 3]]), vertex=np.array([0]),
                                     triangle=np.array([0]), gap=0.0, **out)
    with pytest.raises(ValueError, match="share a vertex"):
        _collide.ccd_edge_edge(start=x, end=x, edge_a=np.array([[0, 1]]), edge_b=np.array([[1, 2]]), gap=0.0,
                               toi=np.empty(1), params=np.empty((1, 2)), side=np.empty(1, np.int8))
    with pytest.raises(ValueError, match="gap"):
        _collide.ccd_edge_edge(start=x, end=x, edge_a=np.array([[0, 1]]), edge_b=np.array([[2, 3]]), gap=-1.0,
                               toi=np.empty(1), params=np.empty((1, 2)), side=np.empty(1, np.int8))


def _sheet(nx=14, ny=14, h=0.01):
    """A grid sheet (m), its triangles, gently waved so that two-ring distances vary."""
    u, v = np.meshgrid(np.arange(nx) * h, np.arange(ny) * h, indexing="ij")
    x = np.stack([u, v, 0.004 * np.sin(u / (3 * h)) * np.cos(v / (4 * h))], -1).reshape(-1, 3)
    idx = np.arange(nx * ny).reshape(nx, ny)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    tri = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return np.ascontiguousarray(x), tri.astype(np.int64)


def _hits(sw, kind, x0, x1):
    """Every pair of `kind` the exact swept test hits over x0 -> x1 at its own gap (none over the thickness)."""
    q = np.arange(sw.vt_gap.size if kind == "vt" else sw.ee_gap.size)
    k = q.size
    toi, side = np.empty(k), np.empty(k, np.int8)
    if kind == "vt":
        _collide.ccd_vertex_triangle(start=x0, end=x1, triangles=sw.triangles, vertex=sw.vt_v, triangle=sw.vt_t,
                                     gap=sw.thickness, toi=toi, weights=np.empty((k, 3)), side=side, pair_gap=sw.vt_gap)
    else:
        _collide.ccd_edge_edge(start=x0, end=x1, edge_a=sw.ee_a, edge_b=sw.ee_b, gap=sw.thickness, toi=toi,
                               params=np.empty((k, 2)), side=side, pair_gap=sw.ee_gap)
    return np.flatnonzero(np.isfinite(toi))


def test_swept_cull_hands_out_every_pair_the_swept_test_finds_and_settles_quiet_blocks_unread():
    """The swept stage's cull (swept.c, what SweptSelf.step runs): over a sheet's whole two-ring, moved
    rigidly (turning and shifting) with vertex jitter of 10 um, then 0.3-4 mm, then 10 um again, every
    pair the exact swept test hits - over the real motion and over a predicted one - was handed out;
    in the quiet steps most blocks are settled by the cheap bounds (one addition, or a few group
    boxes) without reading their vertices."""
    from tearcloth.collision.narrow import ring_table
    from tearcloth.collision.swept import SweptSelf

    rng = np.random.default_rng(7)
    x, tri = _sheet()
    thickness = 0.005
    sw = SweptSelf(x, tri, ring_table(tri, x.shape[0]), x, thickness)
    assert sw.vt_v.size > 2000 and sw.ee_a.shape[0] > 5000
    nb = sum(b[3].shape[0] for b in sw.blocks.values())
    handed = {}
    sw.step(None, x, None, 0.0, handed_out=handed)  # first use: every bound unknown, every pair handed out
    assert handed["vt"][0].size == sw.vt_gap.size and handed["ee"][0].size == sw.ee_gap.size
    found = settled = quiet = 0
    base = x.copy()
    ang = 0.0
    shift = np.zeros(3)
    dt = 1e-3
    for step in range(120):
        # quiet runs (steps 0-39, 80-119: jitter 10 um) around violent ones (0.3-4 mm)
        amp = rng.choice([3e-4, 1e-3, 2e-3, 4e-3]) if 40 <= step < 80 else 1e-5
        ang += rng.normal() * 0.001  # ~1 rad/s at a 1 ms step
        shift += rng.normal(size=3) * 0.002
        c, s = np.cos(ang), np.sin(ang)
        rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        x1 = np.ascontiguousarray((base - 0.07) @ rot.T + 0.07 + shift + rng.normal(size=x.shape) * amp)
        v = np.ascontiguousarray(rng.normal(size=x.shape) * amp / dt)
        sw.step(x, x1, v, dt, handed_out=handed)
        for kind in ("vt", "ee"):
            h = _hits(sw, kind, x, x1)
            assert np.isin(h, handed[kind][0]).all(), f"step {step} {kind}: a pair hit over the step was culled"
            h2 = _hits(sw, kind, x1, np.ascontiguousarray(x1 + dt * v))
            assert np.isin(h2, handed[kind][1]).all(), f"step {step} {kind}: a pair hit over the prediction was culled"
            found += h.size + h2.size
        if step % 40 >= 2 and amp < 1e-4:  # from the second quiet step on (the first ends a jitter)
            quiet += nb
            settled += sw.counts["blocks"][0] + sw.counts["blocks"][1]
        x = x1
    assert found > 100  # the jitter does bring pairs within their gaps
    assert settled > 0.5 * quiet, f"{settled} of {quiet} quiet blocks settled unread"


def test_swept_step_rejects_bad_input():
    from tearcloth.collision.narrow import ring_table
    from tearcloth.collision.swept import SweptSelf

    x, tri = _sheet(6, 6)
    sw = SweptSelf(x, tri, ring_table(tri, x.shape[0]), x, 0.005)
    sw.step(None, x, None, 0.0)
    bad = x.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="not finite"):
        sw.step(x, bad, None, 0.0)
    sw.group_vertices[2] = x.shape[0]
    sw._buf = None
    with pytest.raises(IndexError, match="group vertex"):
        sw.step(x, x, None, 0.0)
    sw.group_vertices[2] = 2
    sw.mem_vt, sw.mem_vt_n = np.array([sw.vt_gap.size]), np.zeros((1, 3))
    with pytest.raises(IndexError, match="remembered pair"):
        sw.step(x, x, None, 0.0)
    sw.mem_vt, sw.mem_vt_n = np.array([1, 1]), np.zeros((2, 3))
    with pytest.raises(ValueError, match="remembered twice"):
        sw.step(x, x, None, 0.0)
    sw.mem_vt, sw.mem_vt_n = np.zeros(0, np.int64), np.zeros((0, 3))
    ptr = sw.blocks["ee"][0]
    ptr[-1] -= 1
    with pytest.raises(ValueError, match="block_ptr"):
        sw.step(x, x, None, 0.0)
    ptr[-1] += 1
    sw.step(x, x, None, 0.0)


def test_swept_pairs_equal_their_numpy_specification_before_and_after_tears():
    """swept.skipped_pairs (C: swept.c tcc_swept_pairs) gives the previous release's numpy lists, in
    the same order, on the T-shirt and on a sheet torn along a row (twins share the two-ring)."""
    from collision_reference import skipped_pairs as reference
    from tearcloth import examples
    from tearcloth.collision.detector import twin_ring
    from tearcloth.collision.narrow import ring_table
    from tearcloth.collision.swept import skipped_pairs
    from test_collision_clusters import grid, tear_grid

    shirt = examples.tshirt()
    cases = [(np.asarray(shirt.triangles, np.int64), ring_table(shirt.triangles, len(shirt.vertices)),
              len(shirt.vertices))]
    p, t = grid(30, 30)
    p2, t2, events = tear_grid(p, t, None, 12)
    n2 = p2.shape[0]
    rid = np.arange(n2, dtype=np.int64)
    new_v, parents = np.asarray(events["new_vertices"], np.int64), np.asarray(events["parents"], np.int64)
    rid[new_v] = parents[:, 0]
    cases.append((np.asarray(t2, np.int64), twin_ring(ring_table(t2, n2), rid), n2))
    for tri, ring, n in cases:
        got, want = skipped_pairs(tri, ring, n), reference(tri, ring, n)
        for g, w in zip(got, want):
            np.testing.assert_array_equal(g, w)
        assert got[1].shape[0] > 1000 and got[2].shape[0] > 1000
