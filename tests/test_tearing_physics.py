"""Tearing as physics, not as numerics: the same tear at any time step and on any fine enough mesh,
no stressed cloth that cannot tear (slivers, grasps), seams that steer, fragments that gain no
energy. The scenes of the first two are the bench's (tearcloth.bench.table1), so its
tearing.dt_independence and tearing.refinement figures are these tests' numbers."""

import numpy as np
import pytest

from meshes import sheet, sliver_sheet
from tearcloth import Cloth, material
from tearcloth.bench.table1 import TEAR_STRESS, WEAK_SPOT, tear_strip


E = 5.0e6


def soft(**changes):
    base = dict(young=E, poisson=0.3, thickness=5e-4, density=300.0, bending=1e-6, damping_mass=20.0,
                damping_stiffness=0.0, tear_stress=TEAR_STRESS, tear_radius=0.005)
    base.update(changes)
    return material("cotton", **base)


def rayleigh(mat):
    mu = mat.young / (2 * (1 + mat.poisson))
    return np.sqrt(mu / mat.density) * (0.862 + 1.14 * mat.poisson) / (1 + mat.poisson)


def test_tear_length_after_a_fixed_time_does_not_depend_on_the_time_step():
    """A strip at twice its tear stress, torn for 16 ms at dt = 0.25 .. 4 ms (4 to 64 steps)."""
    lengths = {dt: tear_strip(dt, 0.016)["length"] for dt in (0.25e-3, 0.5e-3, 1e-3, 2e-3, 4e-3)}
    print("tear length (m) by dt (s):", {k: round(v, 4) for k, v in lengths.items()})
    ratio = max(lengths.values()) / min(lengths.values())
    print(f"max / min = {ratio:.3f}")
    assert ratio <= 1.10
    # it did tear, partly, and no faster than the material allows: two tips at most at the cap
    vmax = 0.02 * rayleigh(soft())
    assert 0.02 < min(lengths.values()) and max(lengths.values()) < 0.1
    assert max(lengths.values()) <= 2 * vmax * 0.016 + 0.02  # + the start's two segments


def test_twice_and_four_times_the_resolution_tear_the_same():
    """The same scene on 5 mm and 2.5 mm edges (2x and 4x a 1 cm mesh; tear radius 1 cm): the tear
    starts at the weak spot, runs the same line and is as long after 16 ms."""
    two, four = (tear_strip(1e-3, 0.016, resolution=k, weak_spot=WEAK_SPOT) for k in (4, 8))
    coarse_edge = two["edge"]
    print(f"start {two['start'][:2]} / {four['start'][:2]}, length {two['length']:.4f} / {four['length']:.4f} m")
    assert np.linalg.norm(two["start"] - four["start"]) <= coarse_edge
    assert np.linalg.norm(two["start"][:2] - WEAK_SPOT[:2]) <= coarse_edge
    for r in (two, four):  # the path: straight across the pull through the weak spot
        assert np.abs(r["path"][:, 0] - WEAK_SPOT[0]).max() <= coarse_edge
    assert abs(four["length"] / two["length"] - 1) <= 0.10
    assert two["length"] > 0.02


def min_angles(V, T):
    out = []
    for a, b, d in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        u, v = V[T[:, b]] - V[T[:, a]], V[T[:, d]] - V[T[:, a]]
        out.append(np.degrees(np.arctan2(np.linalg.norm(np.cross(u, v), axis=1), (u * v).sum(1))))
    return np.min(out, axis=0)


def test_slivers_pulled_far_beyond_the_tear_stress_tear_and_nothing_stays_overstressed():
    V, T = sliver_sheet()
    assert min_angles(V, T).min() < 1.0
    c = Cloth(V, T, soft(), gravity=(0, 0, 0))
    c.set_solver(cg_tolerance=1e-6, cg_max_iterations=400)
    hl = c.add_handle(np.flatnonzero(V[:, 0] < 1e-9))
    hr = c.add_handle(np.flatnonzero(V[:, 0] > 0.2 - 1e-9))
    c.set_tearing(True)
    run = np.zeros(0, int)
    worst = 0
    for i in range(200):
        s = min(1.0, (i + 1) / 100) * 5 * TEAR_STRESS / E * 0.2  # to 5x the tear strain in 0.1 s
        c.move_handle(hl, (-s / 2, 0, 0))
        c.move_handle(hr, (s / 2, 0, 0))
        c.step(1e-3)  # a rollback raises SimulationError and fails the test
        over = c.principal_stress[:, 0] > 3 * TEAR_STRESS * c.tear_strength[c.triangles].min(axis=1)
        run = np.concatenate([run, np.zeros(len(over) - len(run), int)])
        run = np.where(over, run + 1, 0)
        worst = max(worst, int(run.max()))
    print(f"longest run of a triangle above 3x its tear stress: {worst} steps; tears {c.stats()['tears_started']}")
    assert c.stats()["tears_started"] >= 1
    assert worst <= 8  # a few steps while the tear crosses (before: 260 of 300 steps)


def test_two_grasps_side_by_side_pulled_apart_tear_the_cloth_between_them():
    """Two hands holding the cloth on either side of one line (their grips one edge, 2.5 mm, apart:
    every triangle between them is held at all three corners) pull apart at 0.1 m/s each: the
    cloth tears at the fingers, no step rolls back, and the hands end up holding separate pieces."""
    V, T = sheet(0.1, 0.1, 41, 41, jitter=0.3, seed=1)
    c = Cloth(V, T, soft(), gravity=(0, 0, 0))
    c.set_solver(cg_tolerance=1e-6, cg_max_iterations=400)
    box = np.abs(V[:, 1] - 0.05) < 0.01
    ha = c.add_handle(np.flatnonzero(box & (V[:, 0] > 0.04) & (V[:, 0] < 0.0499)))
    hb = c.add_handle(np.flatnonzero(box & (V[:, 0] >= 0.0499) & (V[:, 0] < 0.06)))
    c.set_tearing(True)
    peak = 0.0
    for i in range(100):
        s = 1e-4 * (i + 1)
        c.move_handle(ha, (-s, 0, 0))
        c.move_handle(hb, (s, 0, 0))
        c.step(1e-3)  # a rollback raises SimulationError and fails the test
        peak = max(peak, float(np.linalg.norm(c.handle_force(ha))))
    final = float(np.linalg.norm(c.handle_force(ha)))
    st = c.stats()
    print(f"peak {peak:.2f} N, final {final:.4f} N; tears {st['tears_started']}, grips released {st['grips_released']}")
    assert st["tears_started"] >= 1
    assert final < 0.01 * peak, "the hands still pull on each other through the cloth"


def cut_edges(c):
    """Rest midpoints and lengths of the boundary edges the tears made (the rim's left out)."""
    T, X = c.triangles, c.rest_positions
    e = np.sort(np.concatenate([T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]]), axis=1)
    u, cnt = np.unique(e, axis=0, return_counts=True)
    b = u[cnt == 1]
    mid, L = 0.5 * (X[b[:, 0]] + X[b[:, 1]]), np.linalg.norm(X[b[:, 0]] - X[b[:, 1]], axis=1)
    rim = (mid[:, 0] < 1e-9) | (mid[:, 0] > 0.2 - 1e-9) | (mid[:, 1] < 1e-9) | (mid[:, 1] > 0.1 - 1e-9)
    return mid[~rim], L[~rim]


@pytest.mark.parametrize("angle", [20.0, 40.0])
def test_a_weak_seam_inclined_to_the_pull_is_followed(angle):
    """A pre-scored line (strength 0.5, one mesh size wide) through the middle, `angle` degrees off
    the perpendicular to the pull: at least 80 % of the cut lies within one mesh size of it
    (before the direction rule: 40 % at 20 degrees, 46 % at 40)."""
    h = 0.005
    V, T = sheet(0.2, 0.1, 41, 21, jitter=0.3, seed=2)
    c = Cloth(V, T, soft(), gravity=(0, 0, 0))
    c.set_solver(cg_tolerance=1e-6, cg_max_iterations=400)
    th = np.radians(angle)
    normal = np.array([np.cos(th), -np.sin(th)])  # of the line along (sin, cos)
    dist = (V[:, :2] - (0.1, 0.05)) @ normal
    c.set_tear_strength(np.where(np.abs(dist) < 0.6 * h, 0.5, 1.0))
    hl = c.add_handle(np.flatnonzero(V[:, 0] < 1e-9))
    hr = c.add_handle(np.flatnonzero(V[:, 0] > 0.2 - 1e-9))
    c.set_tearing(True)
    for i in range(300):
        c.move_handle(hl, (-1e-5 * (i + 1), 0, 0))
        c.move_handle(hr, (1e-5 * (i + 1), 0, 0))
        c.step(2e-3)
    mid, L = cut_edges(c)
    near = np.abs((mid[:, :2] - (0.1, 0.05)) @ normal) <= h
    frac = L[near].sum() / L.sum()
    print(f"seam at {angle:.0f} deg: {100 * frac:.1f} % of {L.sum() / 2:.3f} m of cut within one mesh size")
    assert L.sum() / 2 > 0.1  # torn across
    assert frac >= 0.8


def piece_of(c, seed_point):
    """Vertices and triangles of the connected piece whose rest shape holds seed_point."""
    import trimesh
    T, X = c.triangles, c.rest_positions
    m = trimesh.Trimesh(c.positions, T, process=False)
    g = trimesh.graph.connected_components(m.face_adjacency, nodes=np.arange(len(T)), min_len=1)
    cent = X[T].mean(axis=1)
    t0 = int(np.argmin(np.linalg.norm(cent[:, :2] - seed_point, axis=1)))
    tris = next(np.asarray(comp) for comp in g if t0 in set(np.asarray(comp).tolist()))
    return np.unique(T[tris]), tris


def elastic_energy(c, mat, tris):
    """Plane-stress strain energy of the triangles from their principal stresses (J)."""
    T, X = c.triangles[tris], c.rest_positions
    A = 0.5 * np.linalg.norm(np.cross(X[T[:, 1]] - X[T[:, 0]], X[T[:, 2]] - X[T[:, 0]]), axis=1)
    s1, s2 = c.principal_stress[tris, 0], c.principal_stress[tris, 1]
    return float((mat.thickness * A * (s1**2 + s2**2 - 2 * mat.poisson * s1 * s2) / (2 * mat.young)).sum())


def test_a_freed_fragment_keeps_its_momentum_and_gains_no_energy():
    """A stretched strip held at both ends is cut across twice; the middle piece comes free with the
    elastic energy it stored. Right after the separation (positions unchanged, masses re-lumped)
    its momentum is what its vertices had, and afterwards its kinetic energy never exceeds the
    energy it had when it came free."""
    mat = soft(damping_mass=0.0)
    V, T = sheet(0.2, 0.1, 41, 21, jitter=0.3, seed=4)
    c = Cloth(V, T, mat, gravity=(0, 0, 0))
    c.set_solver(cg_tolerance=1e-8, cg_max_iterations=1000)
    hl = c.add_handle(np.flatnonzero(V[:, 0] < 1e-9))
    hr = c.add_handle(np.flatnonzero(V[:, 0] > 0.2 - 1e-9))
    s = 0.8 * TEAR_STRESS / E * 0.2
    c.move_handle(hl, (-s / 2, 0, 0))
    c.move_handle(hr, (s / 2, 0, 0))
    for _ in range(100):
        c.step(2e-3)
    p_before = (c.masses[:, None] * c.velocities).sum(axis=0)
    for x in (0.08, 0.12):  # two cuts across: the middle comes free
        start = int(np.argmin(np.abs(V[:, 0] - x) + 10 * V[:, 1]))
        c.scripted_tear(start, (0, 1, 0), 0.2)
    verts, tris = piece_of(c, (0.1, 0.05))
    assert np.all(np.abs(c.rest_positions[verts, 0] - 0.1) < 0.05), "the middle piece did not come free"
    p_after = (c.masses[:, None] * c.velocities).sum(axis=0)
    assert np.allclose(p_after, p_before, atol=1e-12)
    m, v = c.masses[verts], c.velocities[verts]
    freed = 0.5 * float((m[:, None] * v**2).sum()) + elastic_energy(c, mat, tris)
    assert freed > 0
    c.set_tearing(True)
    worst = 0.0
    for _ in range(200):
        c.step(1e-3)
        verts, tris = piece_of(c, (0.1, 0.05))
        worst = max(worst, 0.5 * float((c.masses[verts, None] * c.velocities[verts] ** 2).sum()))
    print(f"energy at separation {freed:.3e} J, largest kinetic energy after {worst:.3e} J")
    assert worst <= freed
