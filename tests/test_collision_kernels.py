"""The C kernels of collision detection (tearcloth._collide) against their numpy specifications on
random inputs, and the argument checks at the C boundary (bad inputs raise, nothing is read out of
bounds)."""
import numpy as np
import pytest
import trimesh
from hypothesis import given, settings, strategies as st

import collision_reference as reference  # tests/ is on sys.path (conftest.py)
from tearcloth import _collide
from tearcloth.collision import kernels
from tearcloth.collision.clusters import Clustering
from tearcloth.collision.incremental import triangle_adjacency, walk as walk_reference
from tearcloth.collision.measure import RelativeMeasure, box_pairs, cluster_boxes, cluster_motion
from tearcloth.collision.narrow import VertexNormals, ring_table


def wavy_sheet(nx, ny, seed, size=0.4):
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.linspace(0, size, nx), np.linspace(0, size, ny), indexing="ij")
    p = np.stack([x.ravel(), y.ravel(), 0.03 * np.sin(9 * x.ravel()) * np.cos(7 * y.ravel())], 1)
    p[:, :2] += rng.uniform(-0.2, 0.2, (p.shape[0], 2)) * size / nx
    idx = np.arange(nx * ny).reshape(nx, ny)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    t = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int64)
    return p, t


def two_layers(nx, seed, gap=0.005):
    """A cloth folded onto itself: two wavy sheets ``gap`` apart, one mesh (self-collision)."""
    p, t = wavy_sheet(nx, nx, seed)
    q = p + [0.003, 0.002, gap]
    return np.vstack([p, q]), np.vstack([t, t + p.shape[0]])


def sphere(radius=0.15, centre=(0.2, 0.2, 0.0), sub=3):
    m = trimesh.creation.icosphere(subdivisions=sub, radius=radius)
    return np.asarray(m.vertices, np.float64) + centre, np.asarray(m.faces, np.int64)


class Target:
    def __init__(self, v, t):
        self.vertices = np.ascontiguousarray(v, np.float64)
        self.triangles = np.ascontiguousarray(t, np.int64)
        self.adj, self.flip = triangle_adjacency(self.triangles)


# ---------------------------------------------------------------- geometry and measure


@settings(max_examples=12, deadline=None)
@given(nx=st.integers(2, 30), ny=st.integers(2, 30), seed=st.integers(0, 2**16))
def test_vertex_normals_equal_numpy(nx, ny, seed):
    p, t = wavy_sheet(nx, ny, seed)
    rng = np.random.default_rng(seed)
    p += rng.normal(scale=0.002, size=p.shape)
    if t.shape[0] > 3:
        t[0, 1] = t[0, 0]  # a degenerate triangle adds nothing
    ref = VertexNormals(p.shape[0], t)(p)
    got, has = kernels.vertex_normals(p, t)
    np.testing.assert_allclose(got, ref, rtol=1e-13, atol=1e-15)
    np.testing.assert_array_equal(has, np.einsum("ij,ij->i", ref, ref) > 0.5)
    # per cluster: the same rows, bit for bit
    cl = Clustering(p, t, 20)
    corners = t.reshape(-1)
    vt_tri = np.argsort(corners, kind="stable") // 3
    vt_ptr = np.concatenate([[0], np.cumsum(np.bincount(corners, minlength=p.shape[0]))]).astype(np.int64)
    some = np.arange(0, cl.n_clusters, 2, dtype=np.int64)
    out = np.full_like(p, 7.0)
    has2 = np.zeros(p.shape[0], bool)
    _collide.cluster_normals(p, t, vt_ptr, vt_tri.astype(np.int64), cl.order, cl.ptr, some, out, has2)
    rows = np.concatenate([cl.vertices_of(c) for c in some]) if some.size else np.zeros(0, np.int64)
    np.testing.assert_array_equal(out[rows], got[rows])
    np.testing.assert_array_equal(has2[rows], has[rows])
    untouched = np.setdiff1d(np.arange(p.shape[0]), rows)
    assert (out[untouched] == 7.0).all() and not has2[untouched].any()


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**16), target=st.integers(5, 60))
def test_cluster_motion_boxes_and_pairs_equal_numpy(seed, target):
    rng = np.random.default_rng(seed)
    p, t = wavy_sheet(20, 17, seed)
    cl = Clustering(p, t, target)
    q = p + rng.normal(scale=0.003, size=p.shape)
    avg, dev = kernels.cluster_motion(cl, q, p)
    ra, rd = cluster_motion(cl, q - p)
    np.testing.assert_allclose(avg, ra, rtol=1e-12, atol=1e-16)
    np.testing.assert_allclose(dev, rd, rtol=1e-9, atol=1e-12)
    lo, hi = kernels.cluster_boxes(cl, q, 0.004)
    rlo, rhi = cluster_boxes(cl, q, 0.004)
    np.testing.assert_array_equal(lo, rlo)
    np.testing.assert_array_equal(hi, rhi)
    sv, stt = sphere(0.1, (0.2, 0.2, 0.05))
    cb = Clustering(sv, stt, target)
    blo, bhi = kernels.cluster_boxes(cb, sv, 0.004)
    for a in (False, True):
        lb, hb = (lo, hi) if a else (blo, bhi)
        i, j = kernels.box_pairs(lo, hi, lb, hb, self_pairs=a)
        ri, rj = box_pairs(lo, hi, lb, hb, self_pairs=a)
        np.testing.assert_array_equal(i, ri)
        np.testing.assert_array_equal(j, rj)


def test_box_pairs_grow_their_buffers():
    k = 200
    lo = np.zeros((k, 3))
    hi = np.ones((k, 3))  # every box overlaps every box: 40,000 pairs, more than the first guess
    i, j = kernels.box_pairs(lo, hi, lo, hi)
    assert i.size == k * k and (i[::k] == np.arange(k)).all()
    i, j = kernels.box_pairs(lo, hi, lo, hi, self_pairs=True)
    assert i.size == k * (k + 1) // 2 and (j >= i).all()


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**16), shuffle=st.booleans(), lookahead=st.sampled_from([0.0, 3.0]))
def test_relative_measure_equals_numpy_over_steps(seed, shuffle, lookahead):
    rng = np.random.default_rng(seed)
    ka, kb = 12, 9
    c_side, ref_side = RelativeMeasure(0.01, lookahead), RelativeMeasure(0.01, lookahead)
    for _ in range(25):
        pairs = np.argwhere(rng.random((ka, kb)) < 0.4)
        if shuffle:
            pairs = pairs[rng.permutation(len(pairs))]
        i, j = pairs[:, 0].astype(np.int64), pairs[:, 1].astype(np.int64)
        avg_a, avg_b = rng.normal(scale=2e-3, size=(ka, 3)), rng.normal(scale=2e-3, size=(kb, 3))
        dev_a, dev_b = rng.uniform(0, 1e-3, ka), rng.uniform(0, 1e-3, kb)
        force = rng.random(i.size) < 0.1 if rng.random() < 0.5 else None
        got = c_side.step(i, j, avg_a, dev_a, avg_b, dev_b, force)
        want = ref_side.step_reference(i, j, avg_a, dev_a, avg_b, dev_b, force)
        np.testing.assert_array_equal(got, want)
        np.testing.assert_allclose(c_side.amplitude, ref_side.amplitude, rtol=1e-12)
        np.testing.assert_array_equal(c_side.keys, ref_side.keys)
        np.testing.assert_allclose(c_side.rel_avg, ref_side.rel_avg, rtol=1e-12, atol=1e-18)
        np.testing.assert_allclose(c_side.rel_dev, ref_side.rel_dev, rtol=1e-12, atol=1e-18)
        if lookahead and got.any():
            rate = np.linalg.norm(avg_a[i] - avg_b[j], axis=1) + dev_a[i] + dev_b[j]
            assert (got >= (c_side.amplitude + lookahead * rate > 0.01)).all()  # batching took them all


def kabsch(x0, x1):
    a, b = x0 - x0.mean(0), x1 - x1.mean(0)
    u, _, vt = np.linalg.svd(a.T @ b)
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    return vt.T @ np.diag([1.0, 1.0, d]) @ u.T


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**16), noise=st.sampled_from([0.0, 1e-4]))
def test_rigid_fit_matches_kabsch(seed, noise):
    rng = np.random.default_rng(seed)
    v, t = sphere(0.1, (0.0, 0.0, 0.0), 2)
    tris = np.sort(rng.choice(t.shape[0], 60, replace=False)).astype(np.int64)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    R_true = q * np.sign(np.linalg.det(q))
    moved = v @ R_true.T + rng.normal(size=3) + rng.normal(scale=noise, size=v.shape)
    ref = v[t[tris]]  # (k, 3, 3) corners at "build time"
    R, centre, ref_centre = np.zeros((3, 3, 3)), np.zeros((3, 3)), np.zeros((3, 3))
    resid2 = _collide.rigid_fit(moved, t, ref, tris, R, centre, ref_centre, 1)
    corners_ref, corners_now = ref.reshape(-1, 3), moved[t[tris]].reshape(-1, 3)
    np.testing.assert_allclose(R[1], kabsch(corners_ref, corners_now), atol=1e-9)
    np.testing.assert_allclose(R[1] @ R[1].T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R[1]) > 0
    np.testing.assert_allclose(centre[1], corners_now.mean(0), atol=1e-12)
    np.testing.assert_allclose(ref_centre[1], corners_ref.mean(0), atol=1e-12)
    pred = (corners_ref - ref_centre[1]) @ R[1].T + centre[1]
    np.testing.assert_allclose(resid2, ((pred - corners_now) ** 2).sum(1).max(), rtol=1e-6, atol=1e-20)
    assert resid2 <= (4 * noise + 1e-12) ** 2 * 3
    assert (R[0] == 0).all() and (R[2] == 0).all()  # other rows untouched


def test_rigid_fit_reports_deformation_and_nan():
    v, t = sphere(0.1, (0, 0, 0), 2)
    tris = np.arange(40, dtype=np.int64)
    R, c, rc = np.zeros((1, 3, 3)), np.zeros((1, 3)), np.zeros((1, 3))
    bent = v.copy()
    bent[:, 2] *= 1.2  # not a rigid motion
    assert _collide.rigid_fit(bent, t, v[t[tris]], tris, R, c, rc, 0) > 1e-5
    bent[t[3, 0]] = np.nan
    assert _collide.rigid_fit(bent, t, v[t[tris]], tris, R, c, rc, 0) == np.inf


# ---------------------------------------------------------------- walking


def random_rays(p, nrm, target, rng, k):
    v = rng.integers(0, p.shape[0], k).astype(np.int64)
    slot = rng.integers(0, 2, k).astype(np.int64)
    start = rng.integers(-1, target.triangles.shape[0], k).astype(np.int64)
    return v, slot, start


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 2**16), self_target=st.booleans(), steps=st.integers(0, 9))
def test_walk_equals_numpy(seed, self_target, steps):
    rng = np.random.default_rng(seed)
    p, t = wavy_sheet(25, 25, seed)
    nrm, _ = kernels.vertex_normals(p, t)
    target = Target(p, t) if self_target else Target(*wavy_sheet(18, 22, seed + 1))
    if not self_target:
        target.vertices[:, 2] += rng.uniform(-0.01, 0.01)
    ring = ring_table(t, p.shape[0]) if self_target else None
    v, slot, start = random_rays(p, nrm, target, rng, 400)
    got = kernels.walk(p, nrm, v, slot, start, target, ring, steps)
    d = nrm[v] * np.where(slot == 0, 1.0, -1.0)[:, None]
    ref = walk_reference(p[v], d, start, target.vertices, target.triangles, target.adj, target.flip,
                         None if ring is None else ring[v], max_steps=steps)
    np.testing.assert_array_equal(got.tri, ref.tri)
    found = ref.tri >= 0
    np.testing.assert_allclose(got.t[found], ref.t[found], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(got.u[found], ref.u[found], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(got.v[found], ref.v[found], rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(got.flips[found], ref.flips[found])


def test_walk_follows_a_moving_surface_across_triangles():
    p, t = wavy_sheet(12, 12, 0)
    target = Target(p + [0.0, 0.0, 0.004], t)
    nrm, _ = kernels.vertex_normals(p, t)
    v = np.arange(p.shape[0], dtype=np.int64)
    slot = np.zeros_like(v)
    start = np.zeros_like(v)  # every walk starts at triangle 0, far from most hits
    got = kernels.walk(p, nrm, v, slot, start, target, None, 40)
    interior = (np.arange(12)[:, None].repeat(12, 1).ravel() % 11 != 0) & (np.arange(144) % 12 % 11 != 0)
    assert (got.tri[interior] >= 0).mean() > 0.9
    ok = got.tri >= 0
    tv = target.vertices[target.triangles[got.tri[ok]]]
    hit = tv[:, 0] + got.u[ok, None] * (tv[:, 1] - tv[:, 0]) + got.v[ok, None] * (tv[:, 2] - tv[:, 0])
    np.testing.assert_allclose(hit, p[ok] + got.t[ok, None] * nrm[ok], atol=1e-12)


# ---------------------------------------------------------------- contacts


def make_tracks(n, rng, nt, share=0.3):
    tri = np.where(rng.random((n, 2)) < share, rng.integers(0, nt, (n, 2)), -1).astype(np.int64)
    side = np.where(tri >= 0, rng.choice(np.array([-1, 0, 1], np.int8), (n, 2)), 0).astype(np.int8)
    return tri, side


@pytest.mark.parametrize("kind", [reference.VOLUME, reference.SURFACE, reference.SELF])
@pytest.mark.parametrize("first", [False, True])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_merge_classify_equals_numpy(kind, first, seed):
    rng = np.random.default_rng(seed)
    p, t = two_layers(10, seed) if kind == reference.SELF else wavy_sheet(14, 14, seed)
    n = p.shape[0]
    nrm, _ = kernels.vertex_normals(p, t)
    ring = ring_table(t, n) if kind == reference.SELF else None
    if kind == reference.SELF:
        tv, tt = p, t
    elif kind == reference.VOLUME:
        tv, tt = sphere(0.12, (0.2, 0.2, 0.0), 2)
    else:
        tv, tt = wavy_sheet(10, 10, seed + 5)
        tv[:, 2] += 0.004
    target = Target(tv, tt)
    prev = p + rng.normal(scale=0.003, size=p.shape)
    tprev = tv + rng.normal(scale=0.003, size=tv.shape)
    vel = rng.normal(size=p.shape) if rng.random() < 0.5 else None
    tvel = rng.normal(size=tv.shape)
    track_tri, track_side = make_tracks(n, rng, tt.shape[0])
    inside = rng.random(n) < 0.1
    # walked: every tracked ray walked from its triangle (some get lost)
    key = np.flatnonzero(track_tri.reshape(-1) >= 0)
    wv, ws = key >> 1, key & 1
    walked = kernels.walk(p, nrm, wv, ws, track_tri.reshape(-1)[key], target, ring, 3)
    # found: random candidates, refined as the detector does; with duplicates per (vertex, slot)
    k = 300
    fv = rng.integers(0, n, k).astype(np.int64)
    fs = rng.integers(0, 2, k).astype(np.int64)
    fstart = rng.integers(0, tt.shape[0], k).astype(np.int64)
    fh = kernels.walk(p, nrm, fv, fs, fstart, target, ring, 6)
    ok = fh.tri >= 0
    fv, fs, fh = fv[ok], fs[ok], _subset(fh, ok)
    status = rng.choice(np.array([0, 1, 1, 1, 2], np.uint8), fv.size)
    th, tr = 0.01, 0.02
    ref = reference.merge_classify(p, nrm, prev, vel, tv, tt, tprev, tvel if kind != reference.SELF else vel, kind,
                                   first, th, tr, track_tri, track_side, inside, (wv, ws, walked), (fv, fs, fh, status))
    cap = key.size + fv.size
    out = dict(out_key=np.empty(cap, np.int64), out_tri=np.empty(cap, np.int64), out_side=np.empty(cap, np.int8),
               out_inside=np.empty(cap, np.int64), contact_vertex=np.empty(cap, np.int64), depth=np.empty(cap),
               normal=np.empty((cap, 3)), contact_velocity=np.empty((cap, 3)))
    nt_, ni, nc = _collide.merge_classify(
        positions=p, normals=nrm, previous=prev, velocity=vel, target_vertices=tv, target_triangles=tt,
        target_previous=tprev, target_velocity=tvel if kind != reference.SELF else vel, kind=kind, first=first,
        thickness=th, track_range=tr, track_key=key, track_tri=track_tri.reshape(-1)[key],
        track_side=track_side.reshape(-1)[key], walked_tri=walked.tri, walked_t=walked.t, walked_u=walked.u,
        walked_v=walked.v, walked_flips=walked.flips, found_vertex=fv, found_slot=fs, found_tri=fh.tri,
        found_t=fh.t, found_u=fh.u, found_v=fh.v, found_flips=fh.flips, found_status=status.view(bool), **out)
    new_tri = np.full((n, 2), -1, np.int64)
    new_side = np.zeros((n, 2), np.int8)
    ok_key = out["out_key"][:nt_]
    assert (np.diff(ok_key) > 0).all()
    new_tri.reshape(-1)[ok_key] = out["out_tri"][:nt_]
    new_side.reshape(-1)[ok_key] = out["out_side"][:nt_]
    np.testing.assert_array_equal(new_tri, ref[0])
    np.testing.assert_array_equal(new_side, ref[1])
    if kind == reference.VOLUME:
        np.testing.assert_array_equal(np.flatnonzero(ref[2]), out["out_inside"][:ni])
    else:
        assert ni == 0
    cv = out["contact_vertex"][:nc]
    np.testing.assert_array_equal(cv, np.flatnonzero(np.isfinite(ref[3])))
    np.testing.assert_allclose(out["depth"][:nc], ref[3][cv], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(out["normal"][:nc], ref[4][cv], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(out["contact_velocity"][:nc], ref[5][cv], rtol=1e-12, atol=1e-14)
    assert nc > 0


def _subset(h, mask):
    out = kernels.Hits(int(mask.sum()))
    out.tri[:], out.t[:], out.u[:], out.v[:], out.flips[:] = h.tri[mask], h.t[mask], h.u[mask], h.v[mask], h.flips[mask]
    return out


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_assemble_equals_numpy(seed):
    rng = np.random.default_rng(seed)
    n, c = 300, 3
    depth = np.where(rng.random((c, n)) < 0.3, rng.normal(scale=0.01, size=(c, n)), -np.inf)
    depth[:, ::50] = 0.004  # ties between colliders: the first one wins
    normal, velocity = rng.normal(size=(c, n, 3)), rng.normal(size=(c, n, 3))
    friction = rng.uniform(0, 1, c)
    deep, every = reference.assemble(depth, normal, velocity, friction)
    rows = [np.flatnonzero(np.isfinite(depth[j])) for j in range(c)]
    seg = np.concatenate([[0], np.cumsum([r.size for r in rows])]).astype(np.int64)
    v = np.concatenate(rows).astype(np.int64)
    dd = np.concatenate([depth[j, r] for j, r in enumerate(rows)])
    nn = np.concatenate([normal[j, r] for j, r in enumerate(rows)])
    vv = np.concatenate([velocity[j, r] for j, r in enumerate(rows)])
    k = v.size
    outs = [np.empty(k, np.int32), np.empty((k, 3)), np.empty(k), np.empty((k, 3)), np.empty(k)]
    outs += [np.empty(k, np.int32), np.empty((k, 3)), np.empty(k), np.empty((k, 3)), np.empty(k)]
    kd, ka = _collide.assemble(seg, v, dd, nn, vv, friction, n, *outs)
    for got, want in zip([o[:kd] for o in outs[:5]], deep):
        np.testing.assert_array_equal(got, want)
    for got, want in zip([o[:ka] for o in outs[5:]], every):
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("kind", [reference.VOLUME, reference.SURFACE, reference.SELF])
def test_refine_equals_numpy(kind):
    rng = np.random.default_rng(kind)
    p, t = two_layers(12, 3) if kind == reference.SELF else wavy_sheet(16, 16, 3)
    nrm, _ = kernels.vertex_normals(p, t)
    tv, tt = (sphere(0.12, (0.2, 0.2, 0.0), 2) if kind == reference.VOLUME else
              (p, t) if kind == reference.SELF else wavy_sheet(10, 10, 7))
    target = Target(tv, tt)
    ring = ring_table(t, p.shape[0]) if kind == reference.SELF else None
    r = 500
    rv = rng.integers(0, p.shape[0], r).astype(np.int64)
    rs = rng.integers(0, 2, r).astype(np.int64)
    hit = np.where(rng.random(r) < 0.8, rng.integers(0, tt.shape[0], r), -1).astype(np.int64)
    inside_prev = rng.random(p.shape[0]) < 0.2
    outs = [np.empty(r, np.int64), np.empty(r, np.int64)]
    res = kernels.Hits(r)
    status = np.empty(r, bool)
    k = _collide.refine(p, nrm, rv, rs, hit, tv, tt, target.adj, target.flip, ring, kind, 0.03,
                        inside_prev, *outs, res.tri, res.t, res.u, res.v, res.flips, status)
    st_ = status[:k].view(np.uint8)
    keep = st_ > 0
    v, s, h, want_status = reference.refine(p, nrm, rv, rs, hit, tv, tt, target.adj, target.flip, ring, kind, 0.03,
                                            inside_prev)
    np.testing.assert_array_equal(outs[0][:k][keep], v)
    np.testing.assert_array_equal(outs[1][:k][keep], s)
    np.testing.assert_array_equal(res.tri[:k][keep], h.tri)
    np.testing.assert_allclose(res.t[:k][keep], h.t, rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(st_[keep], want_status)
    assert keep.sum() > 0


def test_confirm_inside_equals_brute_force():
    rng = np.random.default_rng(5)
    tv, tt = sphere(0.12, (0.0, 0.0, 0.0), 3)
    cl = Clustering(tv, tt, 60)
    lo, hi = kernels.cluster_boxes(cl, tv, 1e-3)
    r = 300
    o = rng.uniform(-0.15, 0.15, (r, 3))
    d = rng.normal(size=(r, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    # the exit: the farthest hit of each line on the sphere (a back face for inside points)
    a, b, c = (tv[tt[:, k]] for k in range(3))
    from tearcloth.collision.incremental import line_triangle
    exit_t = np.full(r, np.nan)
    exit_tri = np.full(r, -1, np.int64)
    want = np.zeros(r, bool)
    for i in range(r):
        t, u, v, ok = line_triangle(np.tile(o[i], (len(tt), 1)), np.tile(d[i], (len(tt), 1)), a, b, c)
        hits = np.flatnonzero(ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0))
        if hits.size == 0:
            continue
        far = hits[np.argmax(t[hits])]
        exit_t[i], exit_tri[i] = t[far], far
        before = hits[(hits != far) & (t[hits] >= -1e-6) & (t[hits] < t[far] - 1e-6)]
        want[i] = before.size == 0
    sel = exit_tri >= 0
    ok = np.empty(sel.sum(), bool)
    _collide.confirm_inside(tv, tt, cl.tri_order, cl.tri_starts, lo, hi, np.ascontiguousarray(o[sel]),
                            np.ascontiguousarray(d[sel]), exit_t[sel], exit_tri[sel], 1e-6, 1e-6, ok)
    np.testing.assert_array_equal(ok, want[sel])
    inside = np.linalg.norm(o[sel], axis=1) < 0.115
    assert ok[inside].all() and ok.sum() < sel.sum()


def test_prepare_rays_culls_and_moves_rays_into_the_build_frame():
    rng = np.random.default_rng(2)
    p, t = wavy_sheet(20, 20, 2)
    nrm, has = kernels.vertex_normals(p, t)
    cl = Clustering(p, t, 40)
    tv, tt = sphere(0.1, (0.2, 0.2, 0.02), 2)
    tc = Clustering(tv, tt, 40)
    lo, hi = kernels.cluster_boxes(tc, tv, 0.005)
    i, j = kernels.box_pairs(*kernels.cluster_boxes(cl, p, 0.005), lo, hi)
    order = np.argsort(j, kind="stable")
    pa, pb = i[order], j[order]
    ub = np.unique(pb)

    class Scenes:
        pass

    sc = Scenes()
    sc.R = np.stack([np.linalg.qr(rng.normal(size=(3, 3)))[0] for _ in range(tc.n_clusters)])
    sc.centre = rng.normal(size=(tc.n_clusters, 3))
    sc.ref_centre = rng.normal(size=(tc.n_clusters, 3))
    buf = kernels.RayBuffer()
    buf._grow(8)  # too small: prepare grows it
    count, seg = buf.prepare(p, nrm, has, None, cl, lo, hi, pa, pb, ub, sc, 0.02, 0.5, 1e-6, 0.001)
    assert count > 0 and seg[-1] == count
    np.testing.assert_array_equal(buf.count(p, nrm, has, None, cl, lo, hi, pa, pb, ub, sc, 0.02, 0.5, 1e-6, 0.001),
                                  seg)
    for g, b in enumerate(ub):
        rows = np.arange(seg[g], seg[g + 1])
        v, s = buf.vertex[rows], buf.slot[rows]
        dw = nrm[v] * np.where(s == 0, 1.0, -1.0)[:, None]
        ow = p[v] - 1e-6 * dw
        np.testing.assert_allclose(buf.o[rows], (ow - sc.centre[b]) @ sc.R[b] + sc.ref_centre[b], atol=1e-5)
        np.testing.assert_allclose(buf.d[rows], dw @ sc.R[b], atol=1e-6)
        # every cast ray reaches the box; every vertex of the pairs' clusters is considered
        members = np.concatenate([cl.vertices_of(a) for a in pa[pb == b]])
        assert set(v.tolist()) <= set(members.tolist())
    assert np.allclose(buf.dist[:count], 0.02 + 1e-6 + 0.001)
    # long rays for the marked vertices: more of them reach the boxes
    long_mask = np.zeros(p.shape[0], bool)
    long_mask[::3] = True
    count2, seg2 = buf.prepare(p, nrm, has, long_mask, cl, lo, hi, pa, pb, ub, sc, 0.02, 0.5, 1e-6, 0.001)
    marked = long_mask[buf.vertex[:count2]]
    assert count2 > count and marked.any()
    assert np.allclose(buf.dist[:count2][marked], 0.5 + 1e-6 + 0.001)
    assert np.allclose(buf.dist[:count2][~marked], 0.02 + 1e-6 + 0.001)


# ---------------------------------------------------------------- bad inputs


def test_bad_arrays_raise_clear_errors():
    p, t = wavy_sheet(6, 6, 0)
    n = p.shape[0]
    out, has = np.empty((n, 3)), np.empty(n, bool)
    with pytest.raises(TypeError, match="positions must have dtype float64"):
        _collide.vertex_normals(p.astype(np.float32), t, out, has)
    with pytest.raises(TypeError, match="triangles must have dtype int64"):
        _collide.vertex_normals(p, t.astype(np.int32), out, has)
    with pytest.raises(TypeError, match="C-contiguous"):
        _collide.vertex_normals(np.asfortranarray(p), t, out, has)
    with pytest.raises(TypeError, match="C-contiguous"):
        _collide.vertex_normals(p[::2], t, out, has)
    with pytest.raises(ValueError, match=r"normals must have shape \(%d, 3\)" % n):
        _collide.vertex_normals(p, t, np.empty((n - 1, 3)), has)
    with pytest.raises(ValueError, match="shape"):
        _collide.vertex_normals(p.reshape(-1), t, out, has)
    bad = t.copy()
    bad[3, 1] = n
    with pytest.raises(IndexError, match=r"triangles\[3, 1\] = %d" % n):
        _collide.vertex_normals(p, bad, out, has)
    bad[3, 1] = -1
    with pytest.raises(IndexError):
        _collide.vertex_normals(p, bad, out, has)
    ro = np.empty((n, 3))
    ro.flags.writeable = False
    with pytest.raises(TypeError, match="writable"):
        _collide.vertex_normals(p, t, ro, has)
    with pytest.raises(ValueError, match="shares memory"):
        _collide.vertex_normals(p, t, p, has)
    with pytest.raises(TypeError):
        _collide.vertex_normals([[0.0, 0, 0]], t, out, has)
    with pytest.raises(TypeError):
        _collide.vertex_normals(p, t, out)


def test_kernels_take_their_arguments_by_position_or_by_name():
    """One argument table per kernel: positional calls in the documented order and keyword calls
    are the same call; a wrong, doubled or missing name is a TypeError naming it."""
    p, t = wavy_sheet(7, 5, 1)
    n = p.shape[0]
    by_pos = np.empty((n, 3)), np.empty(n, bool)
    _collide.vertex_normals(p, t, *by_pos)
    by_name = np.empty((n, 3)), np.empty(n, bool)
    _collide.vertex_normals(has_normal=by_name[1], normals=by_name[0], triangles=t, positions=p)
    np.testing.assert_array_equal(by_pos[0], by_name[0])
    np.testing.assert_array_equal(by_pos[1], by_name[1])
    mixed = np.empty((n, 3)), np.empty(n, bool)
    _collide.vertex_normals(p, t, normals=mixed[0], has_normal=mixed[1])
    np.testing.assert_array_equal(by_pos[0], mixed[0])
    with pytest.raises(TypeError, match="unexpected keyword argument 'normal_out'"):
        _collide.vertex_normals(p, t, normal_out=mixed[0], has_normal=mixed[1])
    with pytest.raises(TypeError, match="'positions' by position and by keyword"):
        _collide.vertex_normals(p, t, mixed[0], mixed[1], positions=p)
    with pytest.raises(TypeError, match="missing required argument 'has_normal'"):
        _collide.vertex_normals(p, t, mixed[0])
    with pytest.raises(TypeError, match="at most 4 arguments"):
        _collide.vertex_normals(p, t, mixed[0], mixed[1], mixed[1])
    # an optional argument may be left out or passed as None; a scalar takes an integer or a float
    k = 4
    lo_a = np.zeros((k, 3))
    hi_a = np.ones((k, 3))
    i, j = np.empty(32, np.int64), np.empty(32, np.int64)
    assert _collide.box_pairs(lo_a, hi_a, lo_a, hi_a, True, i, j) == k * (k + 1) // 2
    assert _collide.box_pairs(lo_a=lo_a, hi_a=hi_a, lo_b=lo_a, hi_b=hi_a, self_pairs=np.bool_(False), i=i,
                              j=j) == k * k
    with pytest.raises(ValueError, match="inflate must be a finite number, got nan"):
        _collide.cluster_boxes(p, np.zeros(0, np.int64), np.zeros(1, np.int64), float("nan"), np.empty((0, 3)),
                               np.empty((0, 3)))


def test_bad_indices_raise_in_every_kernel():
    p, t = wavy_sheet(8, 8, 0)
    n = p.shape[0]
    cl = Clustering(p, t, 20)
    nrm, has = kernels.vertex_normals(p, t)
    target = Target(p + [0, 0, 0.003], t)
    k = cl.n_clusters
    avg, dev = np.empty((k, 3)), np.empty(k)
    order = cl.order.copy()
    order[0] = n + 5
    with pytest.raises(IndexError, match="order"):
        _collide.cluster_motion(p, p, order, cl.ptr, avg, dev)
    ptr = cl.ptr.copy()
    ptr[-1] = n + 1
    with pytest.raises(IndexError, match="spans"):
        _collide.cluster_motion(p, p, cl.order, ptr, avg, dev)
    with pytest.raises(ValueError, match="inflate"):
        _collide.cluster_boxes(p, cl.box_index, cl.box_ptr, float("nan"), np.empty((k, 3)), np.empty((k, 3)))
    one = np.zeros(1, np.int64)
    hits = [np.empty(1, np.int64), np.empty(1), np.empty(1), np.empty(1), np.empty(1, bool)]
    for v, s, start, err in [(n, 0, 0, IndexError), (0, 2, 0, ValueError), (0, 0, len(t), IndexError),
                             (0, 0, -2, IndexError)]:
        with pytest.raises(err):
            _collide.walk(p, nrm, one + v, one + s, one + start, target.vertices, target.triangles, target.adj,
                          target.flip, None, 4, *hits)
    adj = target.adj.copy()
    adj[:] = len(t) + 3
    with pytest.raises(IndexError, match="adjacency"):
        v = np.arange(n, dtype=np.int64)
        _collide.walk(p, nrm, v, v * 0, v * 0, target.vertices, target.triangles, adj, target.flip, None, 4,
                      np.empty(n, np.int64), np.empty(n), np.empty(n), np.empty(n), np.empty(n, bool))
    with pytest.raises(ValueError, match="max_steps"):
        _collide.walk(p, nrm, one, one, one, target.vertices, target.triangles, target.adj, target.flip, None, -1, *hits)
    rm = RelativeMeasure(0.01)
    with pytest.raises(IndexError, match="pair"):
        rm.step(np.array([0, k]), np.array([0, 0]), avg, dev, avg, dev)
    with pytest.raises(ValueError, match="twice"):
        rm.step(np.array([1, 0, 1]), np.array([0, 0, 0]), avg, dev, avg, dev)
    empty = np.zeros(0, np.int64)
    e_f = np.zeros(0)
    cap = 4
    outs = dict(out_key=np.empty(cap, np.int64), out_tri=np.empty(cap, np.int64), out_side=np.empty(cap, np.int8),
                out_inside=np.empty(cap, np.int64), contact_vertex=np.empty(cap, np.int64), depth=np.empty(cap),
                normal=np.empty((cap, 3)), contact_velocity=np.empty((cap, 3)))
    common = dict(positions=p, normals=nrm, previous=p, velocity=None, target_vertices=target.vertices,
                  target_triangles=target.triangles, target_previous=target.vertices, target_velocity=None, kind=1,
                  first=False, thickness=0.01, track_range=0.02, found_vertex=empty, found_slot=empty,
                  found_tri=empty, found_t=e_f, found_u=e_f, found_v=e_f, found_flips=np.zeros(0, bool),
                  found_status=None)
    two = np.array([4, 2], np.int64)  # not ascending
    walked = dict(walked_tri=np.array([0, 0]), walked_t=np.zeros(2), walked_u=np.zeros(2), walked_v=np.zeros(2),
                  walked_flips=np.zeros(2, bool))
    with pytest.raises(ValueError, match="ascending"):
        _collide.merge_classify(track_key=two, track_tri=np.zeros(2, np.int64), track_side=np.zeros(2, np.int8),
                                **walked, **common, **outs)
    walked["walked_tri"] = np.array([0, len(t)])
    with pytest.raises(IndexError, match="triangle"):
        _collide.merge_classify(track_key=np.array([2, 4]), track_tri=np.zeros(2, np.int64),
                                track_side=np.zeros(2, np.int8), **walked, **common, **outs)
    small = {k2: v2[:1] for k2, v2 in outs.items()}
    walked["walked_tri"] = np.array([0, 1])
    with pytest.raises(ValueError, match="room"):
        _collide.merge_classify(track_key=np.array([2, 4]), track_tri=np.zeros(2, np.int64),
                                track_side=np.zeros(2, np.int8), **walked, **common, **small)
    with pytest.raises(ValueError, match="kind"):
        _collide.merge_classify(track_key=np.array([2, 4]), track_tri=np.zeros(2, np.int64),
                                track_side=np.zeros(2, np.int8), **walked, **{**common, "kind": 7}, **outs)
    seg = np.array([0, 2], np.int64)
    k2 = 2
    aouts = [a for _ in range(2) for a in (np.empty(k2, np.int32), np.empty((k2, 3)), np.empty(k2), np.empty((k2, 3)),
                                           np.empty(k2))]
    with pytest.raises(ValueError, match="ascend"):
        _collide.assemble(seg, np.array([3, 1], np.int64), np.ones(2), np.zeros((2, 3)), np.zeros((2, 3)),
                          np.ones(1), 10, *aouts)
    with pytest.raises(ValueError, match="ascend"):
        _collide.assemble(seg, np.array([3, 10], np.int64), np.ones(2), np.zeros((2, 3)), np.zeros((2, 3)),
                          np.ones(1), 10, *aouts)
    rays = np.array([0], np.int64)
    f32 = np.zeros((1, 3), np.float32)
    with pytest.raises(IndexError, match="primitive"):
        _collide.accept_hits(rays, np.array([5], np.int32), None, np.arange(3, dtype=np.int64), rays,
                             target.triangles, None, f32.copy(), f32, np.ones(1, np.float32),
                             np.empty(1, np.int64), np.empty(1, np.int64))
    with pytest.raises(IndexError, match="ray index"):
        _collide.accept_hits(rays + 1, np.array([0], np.int32), None, np.arange(3, dtype=np.int64), rays,
                             target.triangles, None, f32.copy(), f32, np.ones(1, np.float32),
                             np.empty(1, np.int64), np.empty(1, np.int64))


def test_accept_hits_maps_and_skips_the_two_ring():
    p, t = wavy_sheet(6, 6, 0)
    ring = ring_table(t, p.shape[0])
    v = 14  # an interior vertex; triangle containing it is excluded
    own = int(np.flatnonzero((t == v).any(1))[0])
    far = int(np.flatnonzero(~np.isin(t, ring[v]).any(1))[0])
    scene_tris = np.array([own, far], np.int64)
    rays = np.arange(3, dtype=np.int64)
    rv = np.full(3, v, np.int64)
    o = np.zeros((3, 3), np.float32)
    d = np.tile(np.array([0, 0, 1], np.float32), (3, 1))
    dist = np.ones(3, np.float32)
    hit = np.full(3, 99, np.int64)
    retry = np.empty(3, np.int64)
    again = _collide.accept_hits(rays, np.array([0, 1, -1], np.int32), np.array([0.25, 0.5, 0], np.float32),
                                 scene_tris, rv, t, ring, o, d, dist, hit, retry)
    assert again == 1 and retry[0] == 0
    np.testing.assert_array_equal(hit, [-1, far, -1])
    np.testing.assert_allclose(o[0], [0, 0, 0.25 + 1e-7], atol=1e-7)
    np.testing.assert_allclose(dist[0], 1 - 0.25 - 1e-7, atol=1e-7)
    with pytest.raises(ValueError, match="tfar"):
        _collide.accept_hits(rays, np.array([0, 1, -1], np.int32), None, scene_tris, rv, t, ring, o, d, dist, hit,
                             retry)


# ---------------------------------------------------------------- scenes


def test_scenes_follow_rigid_motion_and_rebuild_only_when_deformed():
    from tearcloth.collision.narrow import ClusterScenes

    v, t = sphere(0.1, (0, 0, 0), 3)
    target = Target(v, t)
    cl = Clustering(v, t, 60)
    sc = ClusterScenes(0.001)
    sc.set_topology(target.triangles, cl, target.adj)
    everything = np.arange(cl.n_clusters, dtype=np.int64)
    assert sc.fit(everything, v, t, 1).all() and sc.builds == cl.n_clusters
    # the margin: every scene holds its cluster's triangles and their edge neighbours
    for c in range(cl.n_clusters):
        own = cl.triangles_of(c)
        assert set(own.tolist()) < set(sc.triangles(c).tolist())
        assert set(sc.triangles(c).tolist()) <= set(own.tolist()) | set(target.adj[own].ravel().tolist())
    rng = np.random.default_rng(0)
    for step in range(2, 12):  # rigid motion: the same scenes, rays moved into their frame
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        moved = v @ (q * np.sign(np.linalg.det(q))).T + rng.normal(size=3)
        sc.fit(everything, moved, t, step)
        o = moved.mean(0) + rng.normal(scale=0.01, size=(50, 3))
        d = rng.normal(size=(50, 3))
        d /= np.linalg.norm(d, axis=1)[:, None]
        hits = [sc.query(c, None, moved, t, o, d, 1.0, step)[0] for c in range(cl.n_clusters)]
        found = np.max(np.stack(hits), axis=0)
        assert (found >= 0).all()  # from inside a closed sphere every ray leaves it
    assert sc.builds == cl.n_clusters
    bent = v.copy()
    bent[:, 0] *= 1.05  # 5 mm on a 10 cm sphere: more than the 1 mm tolerance
    sc.fit(everything, bent, t, 20)
    assert sc.builds == 2 * cl.n_clusters
    # a new topology keeps the scenes whose triangle lists did not change
    sc.set_topology(target.triangles, cl, target.adj)
    assert all(s is not None for s in sc.scene)
    sc.invalidate(triangles=cl.triangles_of(0)[:1])
    dropped = [c for c in range(cl.n_clusters) if sc.scene[c] is None]
    assert 0 in dropped and 1 <= len(dropped) <= 4  # the cluster and the margins that hold the triangle


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**16), target=st.integers(8, 60), spin=st.sampled_from([0.0, 0.05]))
def test_trip_rule_kernels_equal_numpy_and_bound_the_motion(seed, target, spin):
    """cluster_fit / pair_motion against their numpy specification, and the bound's promise: no
    vertex of one cluster changes its distance to the other cluster's surface by more than m."""
    from tearcloth.collision import measure

    rng = np.random.default_rng(seed)
    p, t = wavy_sheet(20, 17, seed)
    cl = Clustering(p, t, target)
    sv, stt = sphere(0.1, (0.2, 0.2, 0.05))
    cb = Clustering(sv, stt, target)
    c, s_ = np.cos(spin), np.sin(spin)
    R = np.array([[c, -s_, 0], [s_, c, 0], [0, 0, 1]])
    q = p @ R.T + rng.normal(scale=2e-3, size=3) + rng.normal(scale=3e-4, size=p.shape)
    sq = sv @ R.T + rng.normal(scale=2e-3, size=3) + rng.normal(scale=1e-4, size=sv.shape)
    reach = 0.02
    fa, fb = kernels.cluster_fit(cl, q, p, reach), kernels.cluster_fit(cb, sq, sv, reach)
    np.testing.assert_allclose(fa, measure.cluster_fit(cl, q, p, reach), rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(fb, measure.cluster_fit(cb, sq, sv, reach), rtol=1e-7, atol=1e-12)
    i, j = (a.ravel().astype(np.int64) for a in np.meshgrid(np.arange(cl.n_clusters), np.arange(cb.n_clusters),
                                                            indexing="ij"))
    a, b = (cl, q, p, fa), (cb, sq, sv, fb)
    m = kernels.pair_motion(i, j, a, b, reach)
    np.testing.assert_allclose(m, measure.pair_motion(i, j, a, b, reach), rtol=1e-9, atol=1e-15)
    # the promise, on vertex-to-point distances within reach (points: b's vertices and triangle centres)
    cent0, cent1 = sv[stt].mean(axis=1), sq[stt].mean(axis=1)
    for p_ in rng.choice(i.size, size=min(40, i.size), replace=False):
        va, tb = cl.vertices_of(i[p_]), np.flatnonzero(cb.tri_labels == j[p_])
        vb = np.unique(stt[tb])
        y0, y1 = np.concatenate([sv[vb], cent0[tb]]), np.concatenate([sq[vb], cent1[tb]])
        d0 = np.linalg.norm(p[va, None] - y0[None], axis=2)
        d1 = np.linalg.norm(q[va, None] - y1[None], axis=2)
        near = d0 <= reach
        assert (np.abs(d1 - d0)[near] <= m[p_] * (1 + 1e-9)).all()


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**16), lookahead=st.sampled_from([0.0, 2.0]))
def test_trip_measure_equals_numpy_over_steps(seed, lookahead):
    from tearcloth.collision.measure import TripMeasure

    rng = np.random.default_rng(seed)
    ka, kb = 12, 9
    c_side, ref_side = TripMeasure(0.004, 0.002, 0.003, lookahead), TripMeasure(0.004, 0.002, 0.003, lookahead)
    for _ in range(25):
        pairs = np.argwhere(rng.random((ka, kb)) < 0.4)
        i, j = pairs[:, 0].astype(np.int64), pairs[:, 1].astype(np.int64)
        lo_a, lo_b = rng.uniform(0, 0.05, (ka, 3)), rng.uniform(0, 0.05, (kb, 3))
        hi_a, hi_b = lo_a + rng.uniform(0, 0.02, (ka, 3)), lo_b + rng.uniform(0, 0.02, (kb, 3))
        bound = rng.uniform(0, 2e-3, i.size)
        if i.size and rng.random() < 0.2:
            bound[0] = np.inf
        force = rng.random(i.size) < 0.1 if rng.random() < 0.5 else None
        got = c_side.step(i, j, bound, lo_a, hi_a, lo_b, hi_b, force)
        want = ref_side.step_reference(i, j, bound, lo_a, hi_a, lo_b, hi_b, force)
        np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(c_side.keys, ref_side.keys)
        np.testing.assert_allclose(c_side.used, ref_side.used, rtol=1e-12, atol=1e-18)
        np.testing.assert_allclose(c_side.amplitude, ref_side.amplitude, rtol=1e-12, atol=1e-18)
        assert (c_side.used <= 0.004).all()


def test_trip_rule_kernels_reject_bad_input():
    p, t = wavy_sheet(8, 8, 0)
    cl = Clustering(p, t, 20)
    k = cl.n_clusters
    fit = np.empty((k, 17))
    order = cl.order.copy()
    order[0] = p.shape[0]
    with pytest.raises(IndexError, match="order"):
        _collide.cluster_fit(positions=p, previous=p, order=order, ptr=cl.ptr, reach=0.01, fit=fit)
    with pytest.raises(ValueError, match="reach"):
        _collide.cluster_fit(positions=p, previous=p, order=cl.order, ptr=cl.ptr, reach=float("nan"), fit=fit)
    fit = kernels.cluster_fit(cl, p, p, 0.01)
    side = (cl, p, p, fit)
    with pytest.raises(IndexError, match="pair"):
        kernels.pair_motion(np.array([k], np.int64), np.array([0], np.int64), side, side, 0.01)
    with pytest.raises(ValueError, match="previous_a"):
        kernels.pair_motion(np.array([0], np.int64), np.array([0], np.int64), (cl, p, p[:-1], fit), side, 0.01)
    bad = Clustering(p, t, 20)
    bad.order = order
    with pytest.raises(IndexError, match="order"):
        kernels.pair_motion(np.array([0], np.int64), np.array([0], np.int64), side, (bad, p, p, fit), 0.01)
    lo = np.zeros((k, 3))
    from tearcloth.collision.measure import TripMeasure
    tm = TripMeasure(0.004, 0.002, 0.003)
    with pytest.raises(ValueError, match="row-major"):
        tm.step(np.array([1, 0], np.int64), np.array([0, 0], np.int64), np.zeros(2), lo, lo, lo, lo)
    with pytest.raises(IndexError, match="pair"):
        tm.step(np.array([0, k], np.int64), np.array([0, 0], np.int64), np.zeros(2), lo, lo, lo, lo)
