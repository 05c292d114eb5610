"""Physics of the native FEM core checked against analytic values, invariances and conservation."""
import sys
import threading
import time

import numpy as np
import pytest

from meshes import sheet
from tearcloth import Cloth, material
from tearcloth.cloth import InvalidInputError, SimulationError

E, NU, H = 5.0e6, 0.3, 5.0e-4


def make(V, T, **mat):
    base = dict(young=E, poisson=NU, thickness=H, density=300.0, bending=0.0, damping_mass=0.0,
                damping_stiffness=0.0)
    base.update(mat)
    return Cloth(V, T, material("cotton", **base), gravity=(0, 0, 0))


@pytest.mark.parametrize("jitter", [0.0, 0.3])
def test_patch_uniform_stretch_gives_analytic_plane_stress(jitter):
    V, T = sheet(0.1, 0.1, 9, 9, jitter=jitter, seed=3)
    c = make(V, T)
    eps = 0.01
    X = V.copy()
    X[:, 0] *= 1 + eps  # uniaxial strain: y held
    c.set_positions(X)
    s = c.stress
    expect_xx = E / (1 - NU**2) * eps
    expect_yy = NU * E / (1 - NU**2) * eps
    # the co-rotational strain is linear in the stretch, so a uniform stretch is exact per element
    assert np.allclose(s[:, 0, 0], expect_xx, rtol=1e-9)
    assert np.allclose(s[:, 1, 1], expect_yy, rtol=1e-9)
    assert np.allclose(s[:, 0, 1], 0, atol=1e-6 * expect_xx)
    # uniaxial stress: lateral contraction -nu eps leaves sigma_yy = 0 and sigma_xx = E eps
    X = V.copy()
    X[:, 0] *= 1 + eps
    X[:, 1] *= 1 - NU * eps
    c.set_positions(X)
    s = c.stress
    assert np.allclose(s[:, 0, 0], E * eps, rtol=1e-9)
    assert np.allclose(s[:, 1, 1], 0, atol=1e-9 * E * eps)
    p = c.principal_stress
    assert np.allclose(p[:, 0], E * eps, rtol=1e-9)
    assert np.allclose(np.abs(c.principal_direction[:, 0]), 1.0, atol=1e-9)


def test_uniaxial_pull_reaches_plane_stress_equilibrium_within_1_percent():
    V, T = sheet(0.2, 0.05, 41, 11, jitter=0.3, seed=1)
    c = make(V, T, damping_mass=30.0)
    c.set_solver(cg_tolerance=1e-8, cg_max_iterations=2000)
    left = np.flatnonzero(V[:, 0] < 1e-9)
    right = np.flatnonzero(V[:, 0] > 0.2 - 1e-9)
    hl, hr = c.add_handle(left), c.add_handle(right)
    strain = 0.01
    c.move_handle(hr, (strain * 0.2, 0, 0))
    for _ in range(200):
        c.step(5e-3)
    centre = np.abs(c.positions[c.triangles].mean(axis=1)[:, 0] - 0.1) < 0.02
    sxx = c.stress[centre][:, 0, 0]
    # far from the clamped ends the strip is in uniaxial stress: sigma_xx = E eps within 1 %
    assert abs(np.median(sxx) / (E * strain) - 1) < 0.01


def test_corotation_rigid_motion_gives_zero_elastic_force():
    V, T = sheet(0.1, 0.05, 11, 6, jitter=0.3, seed=2)
    c = make(V, T)
    rng = np.random.default_rng(0)
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    c.set_positions(V @ R.T + np.array([0.3, -1.2, 2.0]))
    f = c.forces
    # reference: the force of a 1 % stretch of the same mesh
    X = V.copy()
    X[:, 0] *= 1.01
    c2 = make(V, T)
    c2.set_positions(X)
    scale = np.abs(c2.forces).max()
    assert np.abs(f).max() <= 1e-9 * scale
    assert np.abs(c.stress).max() <= 1e-9 * E * 0.01


def test_hanging_sheet_pin_reactions_sum_to_its_weight():
    V, T = sheet(0.2, 0.2, 15, 15, jitter=0.25, seed=4)
    V = V[:, [0, 2, 1]].copy()  # hang in the xz plane
    c = Cloth(V, T, material("cotton", damping_mass=5.0), gravity=(0, 0, -9.81))
    c.pin(np.flatnonzero(V[:, 2] > 0.2 - 1e-9))
    for _ in range(1500):
        c.step(2e-3)
    weight = c.masses.sum() * 9.81
    f = c.pin_force()
    assert abs(-f[2] if f[2] < 0 else f[2]) == pytest.approx(weight, rel=0.005)
    assert f[2] < 0  # the cloth pulls the pins down
    assert abs(f[0]) < 1e-3 * weight and abs(f[1]) < 1e-3 * weight


def test_two_handle_forces_are_opposite_and_match_strip_stiffness():
    Lx, w = 0.2, 0.05
    V, T = sheet(Lx, w, 41, 11, jitter=0.3, seed=5)
    c = make(V, T, damping_mass=30.0)
    # the tolerance is on the residual force against the strip's carried tension (~1 N): 1e-10
    # leaves 1e-10 N, below the 1e-6 agreement asked of the two ends' lateral forces (~3e-5 N)
    c.set_solver(cg_tolerance=1e-10, cg_max_iterations=2000)
    hl = c.add_handle(np.flatnonzero(V[:, 0] < 1e-9))
    hr = c.add_handle(np.flatnonzero(V[:, 0] > Lx - 1e-9))
    strain = 0.005
    c.move_handle(hl, (-strain * Lx / 2, 0, 0))
    c.move_handle(hr, (strain * Lx / 2, 0, 0))
    for _ in range(200):
        c.step(5e-3)
    fl, fr = c.handle_force(hl), c.handle_force(hr)
    expect = E * H * w * strain
    assert np.allclose(fl, -fr, rtol=1e-6, atol=1e-9 * expect)
    # clamped ends stop the lateral contraction locally, stiffening the strip by a few per cent
    assert fr[0] < 0 and abs(fr[0]) == pytest.approx(expect, rel=0.03)


def test_undamped_free_motion_gains_no_energy():
    V, T = sheet(0.2, 0.2, 15, 15, jitter=0.25, seed=6)
    c = Cloth(V, T, material("cotton", damping_mass=0.0, damping_stiffness=0.0, bending=1e-5), gravity=(0, 0, -9.81))
    rng = np.random.default_rng(1)
    c.set_velocities(rng.normal(scale=0.05, size=V.shape))
    c.set_solver(cg_tolerance=1e-9, cg_max_iterations=1000)

    def total():
        e = c.energy()
        return e["kinetic"] + e["elastic"] + e["bending"] + e["gravity"]

    e0 = total()
    worst = e0
    for _ in range(1000):
        c.step(1e-3)
        worst = max(worst, total())
    # backward Euler only dissipates: never above the start (relative tolerance for round-off)
    assert worst <= e0 + 1e-9 * abs(e0) + 1e-12


@pytest.mark.parametrize("n,jitter,tol", [(81, 0.0, 0.02), (41, 0.2, 0.15)])
def test_bending_energy_of_a_cylinder_matches_the_plate_formula(n, jitter, tol):
    V, T = sheet(0.1, 0.1, n, n, jitter=jitter, seed=7)
    D = 1e-4
    c = make(V, T, bending=D)
    r = 0.05
    theta = V[:, 0] / r
    X = np.stack([r * np.sin(theta), V[:, 1], r * (1 - np.cos(theta))], 1)
    c.set_positions(X)
    e = c.energy()["bending"]
    # D/2 * kappa^2 * area; the rim has no stencils, and an irregular mesh deviates more
    assert e == pytest.approx(0.5 * D * 0.01 / r**2, rel=tol)


def test_arrays_are_zero_copy_and_read_only():
    V, T = sheet(0.1, 0.05, 6, 4)
    c = make(V, T)
    a, b = c.positions, c.positions
    assert np.shares_memory(a, b)
    assert not a.flags.writeable
    with pytest.raises(ValueError):
        a[0, 0] = 1.0
    c.step(1e-3)
    assert np.shares_memory(a, c.positions)


def test_step_releases_the_gil():
    V, T = sheet(0.4, 0.4, 100, 100, jitter=0.2)
    c = make(V, T)
    c.set_solver(cg_tolerance=1e-14, cg_max_iterations=3000, gravity=(0, 0, -9.81))
    c.set_velocities(np.random.default_rng(0).normal(scale=0.1, size=V.shape))
    ticks = []
    stop = threading.Event()

    def spin():
        while not stop.is_set():
            ticks.append(time.perf_counter())
            time.sleep(0.0005)

    th = threading.Thread(target=spin)
    th.start()
    t0 = time.perf_counter()
    c.step(1e-3)
    t1 = time.perf_counter()
    stop.set()
    th.join()
    inside = [t for t in ticks if t0 < t < t1]
    assert t1 - t0 > 0.005, "the step was too short to tell"
    assert len(inside) >= 3



def test_a_step_during_a_restore_in_another_thread_is_refused():
    """restore() parses its blob with the GIL released. It did so without marking the cloth busy,
    so a step begun from another thread meanwhile ran on the state restore() then destroyed
    (segmentation fault, every run). The restorer keeps the GIL until restore() lets it go (a long
    switch interval), so the stepper runs exactly while the blob is parsed: every such step is
    refused with ClothError, and the cloth ends restored and finite."""
    from tearcloth.cloth import ClothError

    V, T = sheet(0.5, 0.5, 61, 61, jitter=0.2, seed=1)
    c = make(V, T)
    c.step(1e-3)
    blob = c.snapshot()
    counts = {"restored": 0, "refused": 0, "stepped": 0, "other": []}
    go, bar = threading.Event(), threading.Barrier(2)

    def restorer():
        for _ in range(20):
            bar.wait()
            go.set()
            c.restore(blob)
            counts["restored"] += 1

    def stepper():
        for _ in range(20):
            bar.wait()
            go.wait()
            go.clear()
            try:
                c.step(1e-3)
                counts["stepped"] += 1
            except ClothError:
                counts["refused"] += 1
            except Exception as e:  # noqa: BLE001 - reported by the assertion below
                counts["other"].append(repr(e))

    old = sys.getswitchinterval()
    sys.setswitchinterval(1.0)
    try:
        threads = [threading.Thread(target=restorer), threading.Thread(target=stepper)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(60)
    finally:
        sys.setswitchinterval(old)
    assert counts["restored"] == 20 and not counts["other"], counts
    assert counts["refused"] > 0, counts  # the overlap the test is for happened
    assert np.isfinite(c.positions).all()

def interior_edge(T):
    """An edge used by two triangles (a third one on it makes the mesh non-manifold)."""
    seen = set()
    for tri in T:
        for a, b in ((tri[0], tri[1]), (tri[1], tri[2]), (tri[2], tri[0])):
            if (b, a) in seen:
                return a, b
            seen.add((a, b))
    raise AssertionError("mesh has no interior edge")


BAD_MESHES = [
    ("outside", lambda V, T: (V, np.vstack([T, [[0, 1, len(V) + 3]]]))),
    ("repeats a vertex", lambda V, T: (V, np.vstack([T, [[0, 0, 1]]]))),
    ("non-finite", lambda V, T: (np.where(np.arange(len(V))[:, None] == 2, np.nan, V), T)),
    ("non-manifold edge", lambda V, T: (np.vstack([V, [[0.0, 0.0, 1.0]]]), np.vstack([T, [[*interior_edge(T), len(V)]]]))),
    ("inconsistent winding", lambda V, T: (V, np.vstack([T[:1, ::-1], T[1:]]))),
    ("not used by any triangle", lambda V, T: (np.vstack([V, [[5.0, 5.0, 5.0]]]), T)),
]


@pytest.mark.parametrize("words,breaker", BAD_MESHES, ids=[w for w, _ in BAD_MESHES])
def test_bad_meshes_raise_named_errors(words, breaker):
    V, T = sheet(0.1, 0.05, 6, 4)
    V2, T2 = breaker(V, T)
    with pytest.raises(InvalidInputError, match=words):
        Cloth(V2, T2)


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_non_finite_uvs_and_group_weights_are_named(value):
    """A NaN or infinite UV was accepted, and the triangles at it silently took the rest X axis
    as their warp (warp and weft swapped there, when the map runs along Y); a NaN group weight read
    as neither pinned nor free. Both are refused, naming the triangle and vertex, or the group."""
    V, T = sheet(0.1, 0.05, 6, 4)
    uv = V[:, :2].copy()
    uv[7, 1] = value
    with pytest.raises(InvalidInputError, match="non-finite UV .* vertex 7") as info:
        Cloth(V, T, uv=uv)
    assert 7 in info.value.vertices and info.value.triangles
    assert all(7 in T[t] for t in info.value.triangles)
    w = np.zeros(len(V))
    w[3] = value
    with pytest.raises(InvalidInputError, match="group 'pins': vertex 3 has a non-finite weight"):
        Cloth(V, T, groups={"pins": w})


def test_zero_area_triangle_is_named():
    V = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0]], float)
    T = np.array([[0, 3, 1], [0, 1, 2]], np.int32)
    with pytest.raises(InvalidInputError, match="triangle 1 .*degenerate"):
        Cloth(V, T)


@pytest.mark.parametrize("field,value,words", [
    ("young", 0.0, "young"), ("young", -1.0, "young"), ("poisson", 0.5, "poisson"), ("poisson", -1.0, "poisson"),
    ("thickness", 0.0, "thickness"), ("density", -3.0, "density"), ("tear_stress", 0.0, "tear_stress"),
    ("snap_tolerance", 0.5, "snap_tolerance"), ("young", float("nan"), "young"),
])
def test_absurd_material_values_are_named(field, value, words):
    with pytest.raises(ValueError, match=words):
        material("cotton", **{field: value})
    V, T = sheet(0.1, 0.05, 6, 4)
    c = Cloth(V, T)
    with pytest.raises(ValueError, match=words):
        c._c.set_material(**{field: value})


def test_bad_arrays_and_steps_are_named():
    V, T = sheet(0.1, 0.05, 6, 4)
    c = Cloth(V, T)
    with pytest.raises(InvalidInputError, match=r"shape \(N, 3\)"):
        Cloth(V[:, :2], T)
    with pytest.raises(TypeError, match="float64"):
        c._c.set_positions(V.astype(np.float32))
    with pytest.raises(InvalidInputError, match="expected 24 positions"):
        c.set_positions(V[:5])
    with pytest.raises(InvalidInputError, match="not finite"):
        c.set_positions(np.full_like(V, np.inf))
    with pytest.raises(InvalidInputError, match="time step"):
        c.step(0.0)
    with pytest.raises(InvalidInputError, match="time step"):
        c.step(-1e-3)
    with pytest.raises(InvalidInputError, match="outside"):
        c.pin([0, 99])
    c.pin([])  # a plain empty list (float64 to numpy) is no vertex, not "dtype float64"
    with pytest.raises(InvalidInputError, match="at least one vertex"):
        c.add_handle([])
    with pytest.raises(InvalidInputError, match="no active handle"):
        c.move_handle(7, (0, 0, 0))
    with pytest.raises(InvalidInputError, match="unit vector"):
        c.set_contacts([0], [[0, 0, 2.0]], [0.001])
    with pytest.raises(InvalidInputError, match="depth"):
        c.set_contacts([0], [[0, 0, 1.0]], [-0.001])


def test_exploding_step_is_rolled_back_and_never_returns_nan():
    V, T = sheet(0.1, 0.05, 11, 6)
    c = make(V, T)
    c.set_solver(max_stretch=1.5, cg_max_iterations=1)
    before = c.positions.copy()
    v = np.zeros_like(V)
    v[5] = (1e4, 0, 0)  # one vertex flung far in one step
    c.set_velocities(v)
    with pytest.raises(SimulationError, match="rolled back"):
        c.step(1e-3)
    assert np.array_equal(c.positions, before)
    assert np.isfinite(c.positions).all()


@pytest.mark.parametrize("vertex", [0, 60, 120])
def test_an_overflowed_triangle_is_not_hidden_by_a_later_finite_one(vertex):
    """A finite but huge velocity overflows the stretch of the triangles at that vertex (inf - inf:
    NaN). The step's stretch check once kept the largest value over the triangles in their order, so
    a NaN was replaced by the next finite triangle's stretch and the blown-up step was accepted (a
    vertex at 1e157 m, energies inf and NaN) unless the vertex's triangles came last. Wherever the
    vertex sits in the triangle order, the step is rolled back and nothing moves."""
    V, T = sheet(0.1, 0.1, 11, 11)
    c = make(V, T)
    before = c.positions.copy()
    v = np.zeros_like(V)
    v[vertex, 2] = 1e160
    c.set_velocities(v)
    with pytest.raises(SimulationError, match="rolled back"):
        c.step(1e-3)
    assert np.array_equal(c.positions, before)


def test_stretched_cloth_moving_out_of_plane_stays_calm():
    """Regression: two hands pulling a hanging sheet's lower edge apart. Tension must resist
    out-of-plane motion inside the implicit solve (geometric stiffness); without it the edge
    between the hands whipped at tens of m/s and blew up within 0.1 s."""
    V, T = sheet(0.3, 0.2, 31, 21, jitter=0.3, seed=1)
    c = Cloth(V, T, material("cotton"), gravity=(0, 0, -9.81))
    c.pin(np.flatnonzero(V[:, 1] > 0.2 - 1e-9))
    hl = c.add_handle(np.flatnonzero((V[:, 1] < 1e-9) & (V[:, 0] < 0.1)))
    hr = c.add_handle(np.flatnonzero((V[:, 1] < 1e-9) & (V[:, 0] > 0.2)))
    speed = 0.125
    worst = 0.0
    for i in range(200):
        d = speed * (i + 1) * 1e-3
        c.move_handle(hl, (-d, 0, 0))
        c.move_handle(hr, (d, 0, 0))
        c.step(1e-3)
        worst = max(worst, np.linalg.norm(c.velocities, axis=1).max())
    assert worst < 1.0, f"fastest vertex {worst:.2f} m/s while the hands move at {speed} m/s"


def test_a_contact_deeper_than_one_step_recovers_is_counted():
    """A contact's push out is contact_correction x depth / dt, held to contact_max_push: a contact
    deeper than that (a body that starts inside the cloth) is recovered over several sub-steps.
    The hold was silent; contact_pushes_capped counts it, once per contact and sub-step."""
    V, T = sheet(0.1, 0.1, 6, 6)
    c = make(V, T)
    c.set_solver(gravity=(0, 0, 0), contact_correction=0.2, contact_max_push=0.1)
    c.set_contacts([0, 1], [[0, 0, 1], [0, 0, 1]], [1e-5, 0.01])  # 0.002 m/s and 2 m/s asked
    c.step(1e-3)
    assert c.stats()["contact_pushes_capped"] == 1
    c.set_contacts([0, 1], [[0, 0, 1], [0, 0, 1]], [1e-5, 0.01])
    c.step(1e-3, substeps=2)
    assert c.stats()["contact_pushes_capped"] == 3
    assert c.positions[1, 2] - V[1, 2] <= 0.1 * 2e-3 * (1 + 1e-9) + 1e-12  # at most the capped speed over 2 ms


def test_a_handle_over_pinned_vertices_is_said_and_moves_them():
    """The handle's grasp wins over a pin in the solver; the scripting API said nothing (Blender's
    bake warns): now a UserWarning names the pinned vertices the handle moves. A handle clear of
    the pins says nothing."""
    import warnings

    from meshes import sheet

    V, T = sheet(0.1, 0.1, 11, 11)
    c = Cloth(V, T, material("cotton"), gravity=(0, 0, 0))
    c.pin(np.arange(11))  # the bottom row
    with pytest.warns(UserWarning, match=r"handle 0 grasps 3 pinned vertices \(0, 1, 2\): the handle moves them"):
        h = c.add_handle(np.arange(3))
    c.move_handle(h, (0.0, -0.01, 0.0))
    c.step(1e-3)
    assert np.allclose(c.positions[:3, 1], V[:3, 1] - 0.01)  # moved: the pin did not hold them
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        c.add_handle(np.arange(110, 121))  # the top row: nothing pinned
