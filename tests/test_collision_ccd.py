"""The swept (continuous) kernels of native/collide/ccd.c against a dense-sampling oracle: a
vertex driven through a triangle, and an edge driven through an edge, are found with the right
side and time; pairs that stay apart are not."""
import numpy as np
import pytest

from tearcloth import _collide


def _closest_on_triangle(p, a, b, c, m=60):
    # oracle: dense barycentric grid (fine enough for the margins below)
    u, v = np.meshgrid(np.linspace(0, 1, m), np.linspace(0, 1, m))
    keep = u + v <= 1
    u, v = u[keep], v[keep]
    q = a + u[:, None] * (b - a) + v[:, None] * (c - a)
    return np.linalg.norm(q - p, axis=1).min()


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
        d = np.array([_closest_on_triangle(*(x0 + t * (x1 - x0))) for t in s])
        if d.min() > 1.2 * gap:
            assert not np.isfinite(toi[0]), "a hit where the vertex never came within the gap"
            checked += 1
        # a crossing of the plane inside the triangle must be found, at the oracle's time
        f = np.array([np.dot(P[0] - P[1], np.cross(P[2] - P[1], P[3] - P[1])) for P in (x0 + t * (x1 - x0) for t in s)])
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


def test_cull_never_drops_a_pair_the_swept_test_finds():
    """ccd_cull's carried bound (distance - gap, minus the relative motion) is conservative: over
    many random steps every vertex-triangle and edge-edge pair the exact swept test hits was handed
    out, and most far pairs were not."""
    rng = np.random.default_rng(4)
    n = 40
    x = rng.uniform(0, 0.05, size=(n, 3))
    tri = np.array([rng.choice(n, 3, replace=False) for _ in range(30)], np.int64)
    vt_v = np.array([next(v for v in rng.permutation(n) if v not in t) for t in tri], np.int64)
    vt_t = np.arange(tri.shape[0], dtype=np.int64)
    ea = np.array([rng.choice(n, 2, replace=False) for _ in range(60)], np.int64)
    eb = np.array([rng.choice(np.setdiff1d(np.arange(n), a), 2, replace=False) for a in ea], np.int64)
    quads = {"vt": np.ascontiguousarray(np.column_stack([vt_v, tri[vt_t]])),
             "ee": np.ascontiguousarray(np.column_stack([ea, eb]))}
    gaps = {k: rng.uniform(0, 0.004, q.shape[0]) for k, q in quads.items()}
    slack = {k: np.full(q.shape[0], -np.inf) for k, q in quads.items()}
    handed = hits = 0
    for step in range(200):
        x1 = np.ascontiguousarray(x + rng.normal(size=x.shape) * rng.choice([0.0005, 0.003]))
        for kind, q in quads.items():
            out = np.empty(q.shape[0], np.int64)
            k = _collide.ccd_cull(positions=x1 if step else x, quads=q, split=1 if kind == "vt" else 2,
                                  displacement=np.ascontiguousarray(x1 - x) if step else np.zeros_like(x),
                                  gap=gaps[kind], slack=slack[kind], update=True, out=out)
            if step == 0:
                continue
            m = q.shape[0]
            toi = np.empty(m)
            side = np.empty(m, np.int8)
            if kind == "vt":
                _collide.ccd_vertex_triangle(start=x, end=x1, triangles=tri, vertex=vt_v, triangle=vt_t, gap=0.004,
                                             toi=toi, weights=np.empty((m, 3)), side=side, pair_gap=gaps[kind])
            else:
                _collide.ccd_edge_edge(start=x, end=x1, edge_a=ea, edge_b=eb, gap=0.004, toi=toi,
                                       params=np.empty((m, 2)), side=side, pair_gap=gaps[kind])
            hit = np.flatnonzero(np.isfinite(toi))
            assert np.isin(hit, out[:k]).all(), f"step {step} {kind}: a hit pair was culled"
            handed += k
            hits += hit.size
        if step:
            x = x1
    assert hits > 50
    assert handed < 0.8 * 200 * 90  # the bound does cull


def _sheet(nx=14, ny=14, h=0.01):
    """A grid sheet (m), its triangles, gently waved so that two-ring distances vary."""
    u, v = np.meshgrid(np.arange(nx) * h, np.arange(ny) * h, indexing="ij")
    x = np.stack([u, v, 0.004 * np.sin(u / (3 * h)) * np.cos(v / (4 * h))], -1).reshape(-1, 3)
    idx = np.arange(nx * ny).reshape(nx, ny)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    tri = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return np.ascontiguousarray(x), tri.astype(np.int64)


def test_blocked_cull_hands_out_every_pair_the_swept_test_finds_and_skips_still_blocks():
    """The cull by blocks of pairs (ccd.c tcc_ccd_cull_blocks, what SweptSelf runs): over a sheet's
    whole two-ring, moved rigidly (turning and shifting) with vertex jitter of 10 um, then 0.3-4 mm, then
    10 um again, every pair the exact swept test hits - over the real motion and over a predicted one - was
    handed out; in the quiet steps most blocks are skipped unread, their motion carried as debt."""
    from tearcloth.collision.narrow import ring_table
    from tearcloth.collision.swept import SweptSelf

    rng = np.random.default_rng(7)
    x, tri = _sheet()
    thickness = 0.005
    sw = SweptSelf(x, tri, ring_table(tri, x.shape[0]), x, thickness)
    assert sw.vt_v.size > 2000 and sw.ee_a.shape[0] > 5000
    kinds = {"vt": (sw.vt_quad, sw.vt_gap), "ee": (sw.ee_quad, sw.ee_gap)}

    def hits(kind, x0, x1):
        q = np.arange(kinds[kind][1].size)
        return (sw._vt if kind == "vt" else sw._ee)(x0, x1, kinds[kind][1], q)[0]

    for kind in kinds:  # first use: every bound unknown, every pair handed out and made exact
        assert sw._cull(kind, x, np.zeros_like(x), True).size == kinds[kind][1].size
    found = skipped = quiet = 0
    base = x.copy()
    ang = 0.0
    shift = np.zeros(3)
    for step in range(120):
        # quiet runs (steps 0-39, 80-119: jitter 10 um) around violent ones (0.3-4 mm)
        amp = rng.choice([3e-4, 1e-3, 2e-3, 4e-3]) if 40 <= step < 80 else 1e-5
        ang += rng.normal() * 0.001  # ~1 rad/s at a 1 ms step
        shift += rng.normal(size=3) * 0.002
        c, s = np.cos(ang), np.sin(ang)
        rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        x1 = np.ascontiguousarray((base - 0.07) @ rot.T + 0.07 + shift + rng.normal(size=x.shape) * amp)
        pred = np.ascontiguousarray(rng.normal(size=x.shape) * amp)
        for kind in kinds:
            debt = sw.blocks[kind][4]
            before = debt.copy()
            out = sw._cull(kind, x1, np.ascontiguousarray(x1 - x), True)
            # the carried bound (a pair's slack less its block's debt) stays below its distance - gap
            ptr, slack = sw.blocks[kind][0], sw.vt_slack if kind == "vt" else sw.ee_slack
            q_all = np.arange(slack.size)
            dist = (sw._vt_state if kind == "vt" else sw._ee_state)(x1, q_all)[1]
            carried = slack - np.repeat(debt, np.diff(ptr))
            assert (carried <= dist - kinds[kind][1] + 1e-12).all(), f"step {step} {kind}: a bound above the truth"
            h = hits(kind, x, x1)
            assert np.isin(h, out).all(), f"step {step} {kind}: a pair hit over the step was culled"
            out = sw._cull(kind, x1, pred, False)
            h2 = hits(kind, x1, np.ascontiguousarray(x1 + pred))
            assert np.isin(h2, out).all(), f"step {step} {kind}: a pair hit over the prediction was culled"
            found += h.size + h2.size
            if step % 40 >= 2 and amp < 1e-4:  # from the second quiet step on (the first ends a jitter)
                quiet += debt.size
                skipped += int(np.count_nonzero(debt > before))
        x = x1
    assert found > 100  # the jitter does bring pairs within their gaps
    assert skipped > 0.5 * quiet, f"{skipped} of {quiet} quiet blocks skipped"


def test_blocked_cull_rejects_inconsistent_blocks():
    x = np.zeros((4, 3))
    q = np.array([[0, 1, 2, 3]], np.int64)
    args = dict(positions=x, quads=q, split=1, displacement=x.copy(), gap=np.zeros(1), slack=np.full(1, -np.inf),
                update=True, out=np.empty(1, np.int64))
    blocks = dict(block_ptr=np.array([0, 1]), block_vptr=np.array([0, 4]), block_vertices=np.arange(4),
                  block_min=np.full(1, -np.inf), block_debt=np.zeros(1))
    assert _collide.ccd_cull(**args, **blocks) == 1
    with pytest.raises(ValueError, match="all or none"):
        _collide.ccd_cull(**args, block_ptr=blocks["block_ptr"])
    with pytest.raises(ValueError, match="block_ptr"):
        _collide.ccd_cull(**args, **{**blocks, "block_ptr": np.array([0, 0])})
    with pytest.raises(IndexError, match="block vertex"):
        _collide.ccd_cull(**args, **{**blocks, "block_vertices": np.array([0, 1, 2, 4])})
    with pytest.raises(ValueError):
        _collide.ccd_cull(**args, **{**blocks, "block_min": np.zeros(2)})
