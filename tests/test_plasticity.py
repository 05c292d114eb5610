"""Plasticity (native/ortho.c): Hill-1948 yield with linear hardening and an additive plastic rest
metric. A strip pulled past yield keeps the stretch the model predicts; below yield it keeps none;
the returned stress lies on the yield surface; masses never change; a tear hands the plastic strain
and the axes of a split triangle on to both halves."""
import numpy as np
import pytest

from meshes import sheet
from tearcloth import Cloth, material

E1, E2, G12, NU, H = 5.0e6, 2.5e6, 1.0e6, 0.3, 5e-4
X_YIELD, Y_YIELD, HARD = 5.0e4, 3.0e4, 0.1


def plastic_cloth(V, T, grain=0.0, uv=None, groups=None, **mat):
    base = dict(young=E1, poisson=NU, thickness=H, density=300.0, bending=0.0, damping_mass=30.0,
                damping_stiffness=0.0, orthotropic=True, young_weft=E2, shear_modulus=G12, grain_angle=grain,
                plastic=True, yield_stress=X_YIELD, yield_stress_weft=Y_YIELD, hardening=HARD)
    base.update(mat)
    if uv is None:
        uv = V[:, :2] / (np.ptp(V[:, 0]), np.ptp(V[:, 1]))
    return Cloth(V, T, material("cotton", **base), gravity=(0, 0, 0), uv=uv, groups=groups)


def hill(sw, sf, t, X=X_YIELD, Y=Y_YIELD):
    return X * np.sqrt(sw * sw / X**2 - sw * sf / (X * Y) + sf * sf / Y**2 + 3 * t * t / (X * Y))


def pull_and_release(grain, strain):
    """A 0.2 x 0.02 m strip pulled by its ends to `strain`, held, then let go at one end and left to
    settle. Returns (peak stress along the strip in its middle, residual strain of the middle from
    the positions, the cloth)."""
    V, T = sheet(0.2, 0.02, 41, 5, jitter=0.2, seed=1)
    c = plastic_cloth(V, T, grain)
    c.set_solver(cg_tolerance=1e-9, cg_max_iterations=2000)
    hl = c.add_handle(np.flatnonzero(V[:, 0] < 1e-9))
    hr = c.add_handle(np.flatnonzero(V[:, 0] > 0.2 - 1e-9))
    m0 = np.array(c.masses)
    n = 200
    for i in range(n + 100):
        c.move_handle(hr, (strain * 0.2 * min(i + 1, n) / n, 0, 0))
        c.step(5e-3)
    cen = np.abs(c.rest_positions[c.triangles].mean(axis=1)[:, 0] - 0.1) < 0.03
    peak = float(np.median(c.stress[cen][:, 0, 0]))
    c.release_handle(hr)
    for _ in range(400):
        c.step(5e-3)
    x, X = c.positions, c.rest_positions
    a, b = np.abs(X[:, 0] - 0.06) < 1e-9, np.abs(X[:, 0] - 0.14) < 1e-9
    residual = (x[b, 0].mean() - x[a, 0].mean()) / (X[b, 0].mean() - X[a, 0].mean()) - 1.0
    assert np.array_equal(c.masses, m0), "plastic flow changed a mass"
    return peak, residual, c


@pytest.mark.parametrize("direction", ["warp", "weft"])
def test_load_past_yield_then_unload_keeps_the_models_residual_stretch(direction):
    """Uniaxial stress along the warp past yield: sigma = X + H eps_p, so the stretch left after
    unloading is eps_p = (sigma_peak - X) / H; along the weft the Hill equivalent stress is
    X sigma / Y and eps_p = X^2 (sigma_peak - Y) / (Y^2 H). Within 5 %."""
    grain = 0.0 if direction == "warp" else np.pi / 2
    peak, residual, c = pull_and_release(grain, 0.03)
    Hm = HARD * E1
    model = (peak - X_YIELD) / Hm if direction == "warp" else X_YIELD**2 * (peak - Y_YIELD) / (Y_YIELD**2 * Hm)
    print(f"{direction}: peak {peak:.4g} Pa, residual stretch {residual:.5f}, model {model:.5f} "
          f"({100 * (residual / model - 1):+.2f} %)")
    assert peak > (X_YIELD if direction == "warp" else Y_YIELD) * 1.05
    assert residual == pytest.approx(model, rel=0.05)
    # the strain the triangles keep is the same set, read from the state
    cen = np.abs(c.rest_positions[c.triangles].mean(axis=1)[:, 0] - 0.1) < 0.03
    along = c.plastic_strain[cen][:, 0 if direction == "warp" else 1]
    assert np.median(along) == pytest.approx(residual, rel=0.05)
    assert c.stats()["plastic_unconverged"] == 0


def test_below_yield_nothing_is_kept():
    peak, residual, c = pull_and_release(0.0, 0.006)  # sigma ~ 0.6 X
    print(f"below yield: peak {peak:.4g} Pa, residual stretch {residual:.2e}")
    assert peak < X_YIELD
    assert np.all(c.plastic_strain == 0.0)
    assert abs(residual) < 1e-6


@pytest.mark.parametrize("grain_deg", [0.0, 30.0, 90.0])
def test_the_returned_stress_lies_on_the_grown_yield_surface(grain_deg):
    """Held in a homogeneous biaxial stretch and shear past yield, every triangle's stress after the
    commit has Hill stress X + H kappa (to 1e-9), and is C (eps - eps_p)."""
    V, T = sheet(0.05, 0.05, 6, 6, jitter=0.3, seed=2)
    c = plastic_cloth(V, T, np.radians(grain_deg))
    F = np.array([[1.03, 0.01, 0], [0.01, 1.015, 0], [0, 0, 1]])
    c.set_positions(V @ F.T)
    c.pin(np.arange(len(V)))
    c.step(1e-3)
    assert c.stats()["plastic_triangles"] == len(T)
    s, p = c.stress, c.plastic_strain
    th = np.radians(grain_deg)
    w, f = np.array([np.cos(th), np.sin(th), 0]), np.array([-np.sin(th), np.cos(th), 0])
    sw, sf, tw = (np.einsum("i,tij,j->t", a, s, b) for a, b in ((w, w), (f, f), (w, f)))
    assert np.allclose(hill(sw, sf, tw), X_YIELD + HARD * E1 * p[:, 3], rtol=1e-9)
    eps = 0.5 * (F[:2, :2] + F[:2, :2].T) - np.eye(2)
    ew, ef, ewf = w[:2] @ eps @ w[:2], f[:2] @ eps @ f[:2], w[:2] @ eps @ f[:2]
    d = 1 - NU * NU * E2 / E1
    want_w = (E1 * (ew - p[:, 0]) + NU * E2 * (ef - p[:, 1])) / d
    assert np.allclose(sw, want_w, rtol=1e-9)
    assert np.allclose(tw, 2 * G12 * (ewf - p[:, 2]), rtol=1e-9)


def test_a_tear_hands_the_plastic_strain_and_the_axes_on_and_keeps_the_mesh_valid():
    """An orthotropic plastic sheet pulled past yield, then torn (scripted, so no step commits in
    between): the mesh stays valid, area and mass unchanged, every old triangle keeps its state and
    every new one carries exactly the state of the triangle it was split from; the warp of every
    triangle is still the grain's; then a torn, plastic sheet keeps stepping."""
    from test_tearing import check_mesh
    V, T = sheet(0.2, 0.1, 21, 11, jitter=0.3, seed=3)
    grain = np.radians(25)
    c = plastic_cloth(V, T, grain, uv=V[:, :2] / (0.2, 0.1), groups={"x": V[:, 0] / 0.2})
    c.set_solver(cg_tolerance=1e-6, cg_max_iterations=1000)
    area0 = 0.2 * 0.1
    mass0 = c.masses.sum()
    hl = c.add_handle(np.flatnonzero(V[:, 0] < 1e-9))
    hr = c.add_handle(np.flatnonzero(V[:, 0] > 0.2 - 1e-9))
    for i in range(60):
        c.move_handle(hl, (-1e-4 * i, 0, 0))
        c.move_handle(hr, (1e-4 * i, 0, 0))
        c.step(5e-3)
    before = np.array(c.plastic_strain)
    assert (before[:, 3] > 0).sum() > len(T) // 2, "the sheet did not yield"
    m0 = c.num_triangles
    start = int(np.argmin(np.abs(V[:, 0] - 0.1) + 10 * V[:, 1]))
    assert c.scripted_tear(start, (0.3, 1, 0), 0.07) >= 3
    after = np.array(c.plastic_strain)
    assert c.num_triangles > m0
    check_mesh(c, area0, mass0, 0.0)
    assert len(c.events().changed_triangles) > 0  # split in place: the parents keep their own state
    old_rows = {tuple(r) for r in before}
    assert np.array_equal(after[:m0], before)
    for t in range(m0, c.num_triangles):
        assert tuple(after[t]) in old_rows, f"new triangle {t} has a plastic state no parent had"
    assert np.allclose(c.warp, [np.cos(grain), np.sin(grain), 0], atol=1e-9)
    assert np.all(np.isnan(c.grain_angles))
    for i in range(20):
        c.step(5e-3)
    assert np.isfinite(c.positions).all() and np.isfinite(c.plastic_strain).all()
    assert c.masses.sum() == pytest.approx(mass0, rel=1e-12)
