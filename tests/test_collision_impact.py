"""The impact guard (collision/impact.py, native/collide/impact.c): after a step, no pair of the cloth
meets during the motion the step made. Checked against brute force over every vertex-triangle and
edge-edge pair with ccd.c's exact swept tests, with and without the guard's culling (normal cones,
fans), on motions that cross; the zones keep momentum; a sheet thrown at a held one never passes
through it."""
import numpy as np
import pytest
import trimesh

from meshes import sheet
from tearcloth import Cloth, _collide, material
from tearcloth.collision import impact
from tearcloth.session import CollisionSettings, Session

DT = 1e-3


def _pairs(T, n):
    """Every vertex-triangle pair without a shared vertex and every edge-edge pair without one."""
    T = np.asarray(T, np.int64)
    v = np.repeat(np.arange(n), len(T))
    t = np.tile(np.arange(len(T)), n)
    ok = (T[t] != v[:, None]).all(1)
    edges = np.unique(np.sort(np.concatenate([T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]]), 1), axis=0)
    i, j = np.triu_indices(len(edges), 1)
    a, b = edges[i], edges[j]
    share = (a[:, :1] == b).any(1) | (a[:, 1:] == b).any(1)
    return v[ok], t[ok], np.ascontiguousarray(a[~share]), np.ascontiguousarray(b[~share])


def crossings(x0, x1, T, rest):
    """How many pairs (apart at rest) meet during x0 -> x1: brute force, ccd.c with gap 0."""
    T = np.ascontiguousarray(T, np.int64)
    n = len(x0)
    pv, pt, ea, eb = _pairs(T, n)
    k = pv.size
    sd, dist, w, nrm = np.empty(k), np.empty(k), np.empty((k, 3)), np.empty((k, 3))
    _collide.vertex_triangle_state(positions=rest, triangles=T, vertex=pv, triangle=pt, sd=sd, dist=dist, weights=w,
                                   normal=nrm)
    keep = dist > impact.MIN_REST
    pv, pt = np.ascontiguousarray(pv[keep]), np.ascontiguousarray(pt[keep])
    toi, w, side = np.empty(pv.size), np.empty((pv.size, 3)), np.empty(pv.size, np.int8)
    hits = _collide.ccd_vertex_triangle(start=x0, end=x1, triangles=T, vertex=pv, triangle=pt, gap=0.0, toi=toi,
                                        weights=w, side=side)
    j = len(ea)
    sd, dist, st, nrm = np.empty(j), np.empty(j), np.empty((j, 2)), np.empty((j, 3))
    _collide.edge_edge_state(positions=rest, edge_a=ea, edge_b=eb, sd=sd, dist=dist, params=st, normal=nrm)
    keep = dist > impact.MIN_REST
    ea, eb = np.ascontiguousarray(ea[keep]), np.ascontiguousarray(eb[keep])
    toi, st, side = np.empty(len(ea)), np.empty((len(ea), 2)), np.empty(len(ea), np.int8)
    hits += _collide.ccd_edge_edge(start=x0, end=x1, edge_a=ea, edge_b=eb, gap=0.0, toi=toi, params=st, side=side)
    return hits


def resolve(guard, x0, x1, v, mass, rest, T, cull=True, **kw):
    """One guard call on arrays (copies in, corrected copies out, counts)."""
    topo = guard._topology(np.asarray(T), rest)
    args = {k: topo[k] for k in impact.TOPOLOGY}
    if not cull:  # no patch is a disk, no fan is closed: every overlapping pair is tested
        args["patch"] = np.full_like(topo["patch"], -2)
        args["interior"] = np.zeros_like(topo["interior"])
    end, vel = np.array(x1), np.array(v)
    counts = _collide.impact_resolve(start=x0, end=end, velocity=vel, mass=mass, rest=rest, **args, dt=DT,
                                     gap=guard.gap, rest_fraction=impact.REST_FRACTION, min_rest=impact.MIN_REST,
                                     impulse_passes=kw.get("impulse_passes", guard.impulse_passes),
                                     zone_passes=kw.get("zone_passes", guard.zone_passes))
    return end, vel, counts


def folded_motion(seed, n=12):
    """A jittered sheet whose left part, folded over the right part about a random line, swings
    through it during the step while everything wobbles (smooth random fields): a motion in which
    many pairs meet, from an intersection-free start."""
    rng = np.random.default_rng(seed)
    V, T = sheet(0.3, 0.3, n, n, jitter=0.3, seed=seed)
    V[:, :2] -= 0.15
    rest = np.ascontiguousarray(V, np.float64)
    c = rng.uniform(-0.06, 0.06)
    d = rest[:, 0] - c  # signed distance from the fold line x = c
    a0, a1 = rng.uniform(0.15, 0.6), rng.uniform(-0.6, -0.05)  # angles above and below the other part

    def pose(angle, phase):
        x = rest.copy()
        left = d < 0
        x[left, 0] = c - d[left] * np.cos(angle)
        x[left, 2] = -d[left] * np.sin(angle)
        x[:, 2] += 0.004 * np.sin(9 * rest[:, 1] + phase) * np.cos(7 * rest[:, 0])
        return x

    x0, x1 = pose(a0, 0.0), pose(a1, rng.uniform(0, 3))
    x1 += rng.normal(0, 0.002, x1.shape)
    mass = rng.uniform(0.5e-4, 1.5e-4, len(V))
    return rest, np.ascontiguousarray(x0), np.ascontiguousarray(x1), mass, np.asarray(T, np.int64)


@pytest.mark.parametrize("seed", range(6))
def test_a_fold_swung_through_itself_leaves_no_pair_meeting(seed):
    rest, x0, x1, mass, T = folded_motion(seed)
    before = crossings(x0, x1, T, rest)
    assert before > 0, "the motion was meant to cross"
    g = impact.ImpactGuard(thickness=0.004)
    v = (x1 - x0) / DT
    for cull in (True, False):
        end, vel, counts = resolve(g, x0, x1, v, mass, rest, T, cull=cull)
        after = crossings(x0, end, T, rest)
        print(f"seed {seed} cull {cull}: {before} pairs met; after the guard {after}; {counts}")
        assert after == 0
        assert counts["collisions"] > 0 and counts["moved"] > 0 and counts["rigid_cloth"] == 0
        # the end velocity changed by exactly what the mean velocity over the step did
        np.testing.assert_allclose(vel - v, (end - x1) / DT, atol=1e-9)


def test_impulses_then_zones_leave_no_pair_meeting():
    """One impulse pass leaves pairs for the zones (seed 0: 3 zones of 26 vertices): the mixed path."""
    rest, x0, x1, mass, T = folded_motion(0)
    g = impact.ImpactGuard(thickness=0.004)
    end, _, counts = resolve(g, x0, x1, (x1 - x0) / DT, mass, rest, T, impulse_passes=1)
    assert counts["impulses"] > 0 and counts["zones"] > 0 and counts["rigid_cloth"] == 0
    assert crossings(x0, end, T, rest) == 0


def test_a_flat_sheet_moving_alone_costs_nothing_and_is_untouched():
    """Nothing meets: every patch is culled, nothing moves, the bits are kept."""
    rest, x0, _, mass, T = folded_motion(0)
    x0 = rest.copy()
    x1 = rest + np.array([0.0, 0.0, -0.01]) + 1e-4 * np.sin(20 * rest[:, :1])
    g = impact.ImpactGuard(thickness=0.004)
    end, vel, counts = resolve(g, x0, x1, (x1 - x0) / DT, mass, rest, T)
    assert counts["collisions"] == 0 and counts["moved"] == 0
    assert counts["patches_free"] >= 1
    assert (end == x1).all()


@pytest.mark.parametrize("seed", range(3))
def test_zones_keep_linear_and_angular_momentum(seed):
    rest, x0, x1, mass, T = folded_motion(seed)
    g = impact.ImpactGuard(thickness=0.004)
    v = (x1 - x0) / DT
    for zone_passes in (64, 0):  # zones, then (the cap hit at once) the whole cloth as one zone
        end, vel, counts = resolve(g, x0, x1, v, mass, rest, T, impulse_passes=0, zone_passes=zone_passes)
        assert counts["impulses"] == 0 and counts["zones"] >= 1
        assert counts["rigid_cloth"] == (1 if zone_passes == 0 else 0)
        assert crossings(x0, end, T, rest) == 0
        u = (end - x0) / DT
        p0, p1 = mass @ v, mass @ u
        L0 = (mass[:, None] * np.cross(x0, v)).sum(0)
        L1 = (mass[:, None] * np.cross(x0, u)).sum(0)
        print(f"seed {seed}, zone passes {zone_passes}: {counts}; |dp| {np.abs(p1 - p0).max():.2e} of "
              f"{np.abs(p0).max():.2e}, |dL| {np.abs(L1 - L0).max():.2e} of {np.abs(L0).max():.2e}")
        assert np.abs(p1 - p0).max() <= 1e-12 * np.abs(p0).max()
        assert np.abs(L1 - L0).max() <= 1e-12 * np.abs(L0).max()


def test_still_vertices_are_immovable():
    """Vertices the step left exactly where they were (pinned) never move; their partners do."""
    rest, x0, x1, mass, T = folded_motion(1)
    still = rest[:, 0] > 0.1
    x1[still] = x0[still]
    g = impact.ImpactGuard(thickness=0.004)
    end, _, counts = resolve(g, x0, x1, (x1 - x0) / DT, mass, rest, T)
    assert counts["immovable"] == still.sum()
    assert (end[still] == x0[still]).all()
    assert crossings(x0, end, T, rest) == 0


def test_twins_of_a_cut_are_one_piece():
    """Two rims of a cut lie on each other: never a collision (counted as excluded)."""
    V, T = sheet(0.2, 0.2, 9, 9, jitter=0.0)
    T = np.asarray(T, np.int64)
    n = len(V)
    # cut along the middle column: the vertices of x = 0.1 duplicated for the triangles right of it
    col = np.flatnonzero(np.isclose(V[:, 0], 0.1))
    twin = {int(c): n + i for i, c in enumerate(col)}
    V2 = np.vstack([V, V[col]])
    right = (V[T][:, :, 0].mean(1) > 0.1)
    T2 = T.copy()
    for f in np.flatnonzero(right):
        T2[f] = [twin.get(int(c), c) for c in T[f]]
    rest = np.ascontiguousarray(V2, np.float64)
    x0 = rest.copy()
    x1 = rest + np.random.default_rng(0).normal(0, 1e-5, rest.shape)
    g = impact.ImpactGuard(thickness=0.004)
    end, _, counts = resolve(g, x0, x1, (x1 - x0) / DT, np.full(len(V2), 1e-4), rest, T2, cull=False)
    assert counts["excluded"] > 0
    assert counts["collisions"] == 0 and counts["moved"] == 0


def test_start_positions_follow_a_tear():
    """A tear's new vertices start where their parents did (weights), a fragment's rows are gone."""
    x0 = np.arange(15.0).reshape(5, 3)
    ev = {"removed_vertices": np.array([1]), "new_vertices": np.array([4, 5, 6]),
          "parents": np.array([[0, 2], [3, -1], [4, 0]]), "weights": np.array([0.25, 1.0, 0.5])}
    end = np.zeros((7, 3))
    start, unknown = impact.start_positions(x0, ev, end)
    kept = x0[[0, 2, 3, 4]]
    assert unknown == 0
    np.testing.assert_array_equal(start[:4], kept)
    np.testing.assert_allclose(start[4], 0.25 * kept[0] + 0.75 * kept[2])
    np.testing.assert_array_equal(start[5], kept[3])
    np.testing.assert_allclose(start[6], 0.5 * start[4] + 0.5 * kept[0])


def test_tables_own_each_vertex_and_edge_once():
    V, T = sheet(0.2, 0.2, 7, 7, jitter=0.3, seed=4)
    T = np.asarray(T, np.int64)
    tab = impact.tables(T, len(V))
    own = tab["vertex_owner"]
    assert all(v in T[own[v]] for v in range(len(V)))
    e = np.sort(np.stack([T, np.roll(T, -1, 1)], -1).reshape(-1, 2), 1)
    owned = e[tab["edge_owner"].reshape(-1)]
    assert len(owned) == len(np.unique(e, axis=0)) == len(np.unique(owned, axis=0))
    adj = tab["adjacency"]
    for f, k in zip(*np.nonzero(adj >= 0)):
        assert f in adj[adj[f, k]]
    assert not tab["flip"].any()
    boundary = np.unique(T[adj < 0].reshape(-1))  # corners of triangles on the rim (a superset)
    assert not tab["interior"][np.unique(e[(adj < 0).reshape(-1)])].any()
    assert tab["interior"].sum() == (len(V) - len(np.unique(e[(adj < 0).reshape(-1)])))
    assert boundary.size


def two_sheets(speed, n=13):
    """A 0.2 m sheet 3 cm above a 0.3 m sheet pinned at its rim, thrown down at ``speed``."""
    Va, Ta = sheet(0.3, 0.3, n, n, jitter=0.3, seed=1)
    Va[:, :2] -= 0.15
    Va[:, 2] = 0.0
    Vb, Tb = sheet(0.2, 0.2, n, n, jitter=0.3, seed=2)
    Vb[:, :2] -= 0.1
    Vb[:, 2] = 0.03
    V = np.vstack([Va, Vb])
    T = np.vstack([Ta, np.asarray(Tb) + len(Va)])
    c = Cloth(V, T, material("cotton"))
    rim = np.flatnonzero((np.abs(Va[:, 0]) > 0.149) | (np.abs(Va[:, 1]) > 0.149))
    c.pin(rim)
    v = np.zeros_like(V)
    v[len(Va):, 2] = -speed
    c.set_velocities(v)
    return c, len(Va), len(Ta), rim


def thrown_below(P, T, na, ta):
    """Vertices of the thrown sheet that have the held sheet above them (they passed through it)."""
    held = trimesh.Trimesh(P[:na], np.asarray(T)[:ta], process=False)
    top = P[na:]
    hit = held.ray.intersects_any(top, np.tile([0.0, 0.0, 1.0], (len(top), 1)))
    return int(hit.sum())


def test_a_sheet_thrown_at_20_m_s_onto_a_held_sheet_never_passes_through():
    """20 m/s is 20 mm per 1 ms step, five times the 4 mm contact thickness: the contact stages see
    the layers only when they already crossed. Without the guard the sheet goes through; with it,
    no step crosses and the thrown sheet stays above."""
    TH = 0.004
    for guard in (False, True):
        c, na, ta, rim = two_sheets(20.0)
        s = Session(c, CollisionSettings(thickness=TH, self_collision=True, impact_guard=guard))
        worst = 0
        collided = 0
        for i in range(60):
            x0 = np.array(c.positions)
            rep = s.step(DT)
            T = np.asarray(c.triangles, np.int64)
            worst = max(worst, thrown_below(c.positions, T, na, ta))
            if guard:
                collided += rep.impact["collisions"]
                if i < 10:  # the impact: every step's motion is free of crossings (brute force)
                    assert crossings(x0, np.array(c.positions), T, np.array(c.rest_positions)) == 0
        print(f"guard {guard}: {worst} thrown vertices below the held sheet at worst; collisions {collided}")
        if not guard:
            assert worst > 0, "without the guard the thrown sheet was meant to pass through"
        else:
            assert worst == 0 and collided > 0
            assert s.impact.totals["rigid_cloth"] == 0
            assert (c.positions[rim] == np.array(c.rest_positions)[rim]).all(), "the pinned rim moved"


def test_the_guard_is_a_setting_and_reports_every_step():
    V, T = sheet(0.1, 0.1, 5, 5)
    off = Session(Cloth(V, T), CollisionSettings(impact_guard=False))
    assert off.impact is None and off.step(DT).impact is None
    assert Session(Cloth(V, T), CollisionSettings(self_collision=False)).impact is None
    on = Session(Cloth(V, T), CollisionSettings())
    rep = on.step(DT)
    assert set(impact.COUNTS) <= set(rep.impact) and rep.impact_s > 0
    assert on.impact.totals["steps"] == 1


def test_resume_with_the_guard_equals_an_uninterrupted_run():
    """The guard's tree is rebuilt from the topology on resume; a resumed run equals the original
    bit for bit through steps where the guard acts."""
    c, _, _, _ = two_sheets(20.0, n=9)
    s = Session(c, CollisionSettings(thickness=0.004))
    for _ in range(3):
        s.step(DT)
    blob = s.save_state()
    for _ in range(6):
        s.step(DT)
    c2, _, _, _ = two_sheets(20.0, n=9)
    s2 = Session(c2, CollisionSettings(thickness=0.004))
    s2.restore_state(blob)
    acted = 0
    for _ in range(6):
        acted += s2.step(DT).impact["moved"]
    assert acted > 0, "the guard was meant to act in the resumed steps"
    assert (c2.positions == c.positions).all() and (c2.velocities == c.velocities).all()
    assert s2.impact.totals == s.impact.totals
