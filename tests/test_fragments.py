"""Tiny fragments (native/fragment.c): a piece a tear sets free below min_fragment_area is removed with
its vertices, the events say what went, and everything that reads the events follows; a piece at or
above the size stays, and the rest of the cloth does not notice."""
import numpy as np
import pytest

from meshes import sheet
from tearcloth import Cloth, material
from tearcloth.cloth import InvalidInputError
from tearcloth.session import CollisionSettings, Session
from test_tearing import fans_per_vertex

NY = 11  # the sheets below: 21 x 11 vertices on 0.2 x 0.1 m, 1 cm cells (triangles of 0.5 cm^2)


def idx(i, j):
    return i * NY + j


def grid_cloth(min_fragment_area=1e-4, **solver):
    V, T = sheet(0.2, 0.1, 21, NY)
    c = Cloth(V, T, material("cotton"), gravity=(0, 0, -9.81), uv=V[:, :2] / np.array([0.2, 0.1]),
              groups={"x": V[:, 0] / 0.2})
    c.set_solver(cg_tolerance=1e-8, cg_max_iterations=2000, **solver)
    c.set_tearing(True, min_fragment_area=min_fragment_area)
    return c, V, T


def free_corner_triangle(c, V):
    """Cut the one inner edge of the corner triangle (0, 0)-(1, 0)-(0, 1): it comes free (0.5 cm^2)."""
    b, d = idx(1, 0), idx(0, 1)
    return c.scripted_tear(b, V[d] - V[b], float(np.linalg.norm(V[d] - V[b])))


def free_corner_block(c, V, k):
    """Cut off the k x k cells at the (20, 0) corner along two straight lines: a piece of k^2 cm^2."""
    c.scripted_tear(idx(20 - k, 0), (0, 1, 0), 0.01 * k)
    c.scripted_tear(idx(20, k), (-1, 0, 0), 0.01 * k)


def check_topology(c, mass_per_area):
    """What the core relies on after a deletion: every vertex used, edge-manifold, consistently wound,
    one fan per vertex, masses those of the triangles left, UVs and groups carried with the rows."""
    T, X = c.triangles, c.rest_positions
    used = np.zeros(c.num_vertices, bool)
    used[T.ravel()] = True
    assert used.all(), "a vertex of a removed piece (or an orphan) was left behind"
    d = np.concatenate([T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]])
    assert len(np.unique(d, axis=0)) == len(d), "inconsistent winding"
    assert np.unique(np.sort(d, axis=1), axis=0, return_counts=True)[1].max() <= 2, "non-manifold edge"
    assert fans_per_vertex(c) == 1
    area = 0.5 * np.linalg.norm(np.cross(X[T[:, 1]] - X[T[:, 0]], X[T[:, 2]] - X[T[:, 0]]), axis=1)
    expect = np.zeros(c.num_vertices)
    np.add.at(expect, T.ravel(), np.repeat(area * mass_per_area / 3, 3))
    np.testing.assert_allclose(c.masses, expect, rtol=1e-12)
    np.testing.assert_allclose(c.corner_uv, X[T][:, :, :2] / np.array([0.2, 0.1]), atol=1e-12)
    np.testing.assert_allclose(c.group("x"), X[:, 0] / 0.2, atol=1e-12)


def rho_h(c):
    m = c.material
    return m.density * m.thickness


def test_a_freed_single_triangle_is_removed_and_listed():
    c, V, T = grid_cloth()
    n, m = c.num_vertices, c.num_triangles
    assert free_corner_triangle(c, V) == 1
    ev, st = c.events(), c.stats()
    assert (st["fragments_removed"], st["fragment_triangles_removed"], st["fragment_vertices_removed"]) == (1, 1, 3)
    assert (c.num_vertices, c.num_triangles) == (n - 1, m - 1)  # 2 duplicates made, 3 vertices gone
    assert ev.removed and ev.removed_triangles.tolist() == [0] and ev.removed_vertices.tolist() == [0]
    assert len(ev.new_vertices) == 0 and len(ev.changed_triangles) == 0  # the piece was all they touched
    check_topology(c, rho_h(c))
    assert not np.any(np.all(np.isclose(c.rest_positions, V[0]), axis=1))  # the corner is gone


def test_two_removals_between_steps_are_listed_in_the_numbering_the_events_began_with():
    c, V, T = grid_cloth()
    free_corner_triangle(c, V)
    # the opposite corner: triangle (20, 9)-(20, 10)-(19, 10), its inner edge (20, 9)-(19, 10); every
    # vertex index past 0 has moved down by one
    b, d = idx(20, 9), idx(19, 10)
    assert c.scripted_tear(b - 1, V[d] - V[b], float(np.linalg.norm(V[d] - V[b]))) == 1
    ev = c.events()
    # this time the piece kept the cut's original vertices: the duplicates that stay take their ids,
    # so only the two corners go and no vertex is new
    assert ev.removed_vertices.tolist() == [0, idx(20, 10)]
    assert ev.removed_triangles.tolist() == [0, 399]
    assert len(ev.new_vertices) == 0 and c.num_vertices == 229
    np.testing.assert_array_equal(c.rest_positions[[b - 1, d - 1]], V[[b, d]])
    assert c.stats()["fragments_removed"] == 2 and c.num_triangles == 398
    check_topology(c, rho_h(c))


def test_a_small_piece_goes_and_one_at_the_size_stays():
    for k, limit, removed in ((2, 5e-4, True), (2, 4e-4 - 1e-9, False), (3, 1e-3, True)):
        c, V, T = grid_cloth(min_fragment_area=limit)
        m = c.num_triangles
        free_corner_block(c, V, k)
        st = c.stats()
        assert st["fragments_removed"] == int(removed), (k, limit, st)
        assert c.num_triangles == (m - 2 * k * k if removed else m), (k, limit)
        check_topology(c, rho_h(c))
        for _ in range(5):
            c.step(1e-3)
        assert np.isfinite(c.positions).all()


def test_zero_disables_and_bad_values_are_refused():
    c, V, T = grid_cloth(min_fragment_area=0.0)
    free_corner_triangle(c, V)
    assert c.stats()["fragments_removed"] == 0 and c.num_triangles == 400
    with pytest.raises(InvalidInputError, match="min_fragment_area"):
        c.set_tearing(True, min_fragment_area=-1e-4)


def test_the_rest_of_the_cloth_does_not_notice():
    """The same cloth with and without removal: the survivors' positions, velocities and masses are the
    same rows moved, their momentum the same, and they go on moving the same (to the solve's tolerance:
    the removed piece's unknowns no longer share the CG's iterations)."""
    runs = {}
    for limit in (0.0, 1e-4):
        c, V, T = grid_cloth(min_fragment_area=limit)
        c.pin(np.flatnonzero(V[:, 1] > 0.1 - 1e-9))
        for _ in range(10):
            c.step(1e-3)
        free_corner_triangle(c, V)
        runs[limit] = c
    keep, cut = runs[0.0], runs[1e-4]
    assert cut.num_vertices == keep.num_vertices - 3
    # the piece in the run that kept it: the three vertices of the one triangle no other touches
    T = keep.triangles
    alone = np.flatnonzero(np.bincount(T.ravel(), minlength=keep.num_vertices) == 1)
    piece = [t for t in range(len(T)) if set(T[t]) <= set(alone.tolist())]
    assert len(piece) == 1
    survivors = np.setdiff1d(np.arange(keep.num_vertices), T[piece[0]])
    for name in ("positions", "velocities", "masses", "rest_positions"):
        np.testing.assert_array_equal(getattr(cut, name), getattr(keep, name)[survivors], err_msg=name)
    p_keep = (keep.masses[survivors, None] * keep.velocities[survivors]).sum(0)
    p_cut = (cut.masses[:, None] * cut.velocities).sum(0)
    np.testing.assert_array_equal(p_cut, p_keep)
    for _ in range(20):
        keep.step(1e-3)
        cut.step(1e-3)
    moved = np.abs(keep.positions[survivors] - cut.positions).max()
    travel = np.abs(keep.positions[survivors] - runs[0.0].rest_positions[survivors]).max()
    assert moved <= 1e-6 * max(travel, 1e-3), (moved, travel)


def test_matches_a_cloth_built_from_what_is_left():
    """Every table the core keeps (pairs and their hash, stencils, the matrix rows, masses) after a
    deletion equals what a cloth built from the remaining arrays has: one step of each agrees."""
    c, V, T = grid_cloth(min_fragment_area=5e-4)
    c.pin(np.flatnonzero(V[:, 1] > 0.1 - 1e-9))
    for _ in range(5):
        c.step(1e-3)
    free_corner_block(c, V, 2)
    assert c.stats()["fragments_removed"] == 1
    fresh = Cloth(np.array(c.positions), np.array(c.triangles), c.material, rest=np.array(c.rest_positions),
                  gravity=(0, 0, -9.81))
    fresh.set_solver(cg_tolerance=1e-8, cg_max_iterations=2000)
    fresh.set_velocities(np.array(c.velocities))
    pinned = np.flatnonzero(np.isclose(c.rest_positions[:, 1], 0.1))
    fresh.pin(pinned)
    c.set_tearing(False)
    c.step(1e-3)
    fresh.step(1e-3)
    np.testing.assert_allclose(c.positions, fresh.positions, rtol=0, atol=1e-9)


def test_pins_handles_contacts_and_tips_follow_the_renumbering():
    c, V, T = grid_cloth()
    top = np.flatnonzero(V[:, 1] > 0.1 - 1e-9)
    c.pin(top)
    corner = c.add_handle([idx(0, 0)])          # a hand on the piece that goes
    other = c.add_handle([idx(20, 0), idx(19, 0)])  # and one elsewhere
    c.set_contacts([idx(0, 0), idx(10, 0)], [(0, 0, 1), (0, 0, 1)], [0.0, 0.0])
    free_corner_triangle(c, V)
    assert c.stats()["fragments_removed"] == 1
    assert np.allclose(c.handle_force(corner), 0.0)  # it holds nothing now
    z_pinned = c.positions[top - 1].copy()  # vertex 0 went: every later index moved down by one
    np.testing.assert_array_equal(c.rest_positions[top - 1], V[top])
    c.move_handle(other, (0.0, -0.002, 0.0))
    for _ in range(10):
        c.step(1e-3)
    np.testing.assert_array_equal(c.positions[top - 1], z_pinned)  # still pinned, under gravity
    held = [int(np.flatnonzero(np.all(np.isclose(c.rest_positions, V[v]), axis=1))[0]) for v in (idx(20, 0), idx(19, 0))]
    np.testing.assert_allclose(c.positions[held], V[[idx(20, 0), idx(19, 0)]] + (0, -0.002, 0), atol=1e-12)
    assert np.isfinite(c.handle_force(other)).all()


class _CutInStep(Cloth):
    """A cloth whose next step ends with the corner cut, so the Session meets the removal among the
    step's own events, the way a tear that frees a piece during a step delivers it."""

    cut = None

    def step(self, dt, substeps=1):
        super().step(dt, substeps)
        if self.cut is not None:
            self.cut(self)
            self.cut = None


def test_a_session_with_collision_follows_the_removal():
    V, T = sheet(0.2, 0.1, 21, NY)
    c = _CutInStep(V, T, material("cotton"), gravity=(0, 0, -9.81))
    c.set_tearing(True, min_fragment_area=5e-4)
    c.pin(np.flatnonzero(V[:, 1] > 0.1 - 1e-9))
    s = Session(c, collision=CollisionSettings(self_collision=True, cluster_size=20))
    floor = np.array([[-1, -1, -0.01], [1, -1, -0.01], [1, 1, -0.01], [-1, 1, -0.01]], float)
    s.add_body("floor", floor, np.array([[0, 1, 2], [0, 2, 3]]))
    for _ in range(3):
        s.step(1e-3)
    c.cut = lambda cl: free_corner_block(cl, V, 2)
    rep = s.step(1e-3)
    assert rep.events.removed and len(rep.events.removed_triangles) == 8, rep.events
    det = s.detector
    n = c.num_vertices
    assert det.cloth.vertices.shape[0] == n and det.cloth.clustering.labels.size == n
    assert det.cloth.triangles.shape[0] == c.num_triangles
    assert det.cloth.rest_id.size == n and det._cloth_prev.shape == (n, 3)
    for tracks in det._tracks.values():
        assert tracks.n == n and (tracks.key >> 1 < n).all()
    # every cluster is a connected patch of what is left
    labels = det.cloth.clustering.labels
    assert labels.min() >= 0
    for _ in range(30):
        s.step(1e-3)
    assert np.isfinite(c.positions).all()
    assert c.positions[:, 2].min() > -0.01 - 2e-3  # the floor still holds the cloth after the removal


def test_cache_frames_drop_the_piece(tmp_path):
    pytest.importorskip("pxr")
    from tearcloth import cache

    c, V, T = grid_cloth()
    path = str(tmp_path / "sheet.usda")
    w = cache.CacheWriter(path, "Sheet", 24.0)
    w.write_frame(1, c.positions, c.triangles, c.corner_uv)
    free_corner_triangle(c, V)
    c.step(1e-3)
    w.write_frame(2, c.positions, c.triangles, c.corner_uv)
    w.close()
    p1, t1, _ = cache.read_frame(path, 1)
    p2, t2, uv2 = cache.read_frame(path, 2)
    assert (len(p1), len(t1)) == (231, 400) and (len(p2), len(t2)) == (230, 399)
    np.testing.assert_allclose(p2, c.positions, atol=1e-6)
    assert uv2.shape == (399, 3, 2)


def test_a_removal_keeps_each_woven_triangles_grain_warp_and_plastic_set_with_it():
    # fragment.c compacts every per-triangle array with the triangles: a woven, plastic sheet with
    # its own grain on each triangle keeps each survivor's grain, warp and plastic strain (keyed
    # by the triangle's rest centroid, which no compaction changes)
    V, T = sheet(0.2, 0.1, 21, NY)
    c = Cloth(V, T, material("denim"), gravity=(0, 0, -9.81), uv=V[:, :2] / np.array([0.2, 0.1]))
    c.set_solver(cg_tolerance=1e-8, cg_max_iterations=2000)
    c.set_tearing(True, min_fragment_area=1e-4)
    c.set_grain_angles(np.linspace(-0.6, 0.6, c.num_triangles))
    pins = [idx(0, j) for j in range(NY)]
    c.pin(pins)
    h = c.add_handle([idx(20, j) for j in range(NY)])
    for k in range(30):  # stretch it along x past denim's yield so the strain is set
        A = np.eye(4)[:3]
        A[0, 3] = 4e-4 * (k + 1)
        c.set_handle_target(h, A)
        c.step(1e-3)
    assert np.abs(c.plastic_strain[:, 0]).max() > 0.0, "the sheet never yielded: the test would check nothing"

    def state():
        X, Tr = c.rest_positions, c.triangles
        keys = np.round(X[Tr].mean(axis=1), 9)
        return {tuple(k): (g, tuple(w), tuple(p)) for k, g, w, p in zip(keys, c.grain_angles, c.warp, c.plastic_strain)}

    before = state()
    assert free_corner_triangle(c, V) == 1 and c.stats()["fragments_removed"] == 1
    after = state()
    assert len(after) == len(before) - 1 and set(after) < set(before)
    for key, value in after.items():
        assert value == before[key], f"the triangle at rest centroid {key} lost its woven state"
