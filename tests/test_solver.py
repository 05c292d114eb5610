"""The implicit solve: converged in physical terms or said so (never silently stopped at its cap),
momentum exact in free flight whatever the tolerance, and a tolerance tight enough that tightening
it changes no tear."""
import numpy as np
import pytest

from meshes import sheet
from tearcloth import Cloth, material
from tearcloth.bench.slivers import min_angle_deg
from tearcloth.session import Session


def sliver_sheet(n=15, squeeze=0.99, every=4, seed=0):
    """An irregular sheet where some vertices are pushed 99 % of the way onto the opposite edge of
    one of their triangles: slivers with angles down to a fraction of a degree, none inverted."""
    V, T = sheet(0.2, 0.2, n, n, jitter=0.2, seed=seed)
    V = V.copy()
    inner = lambda v: 0 < v // n < n - 1 and 0 < v % n < n - 1
    moved = set()
    for t in T[::every]:
        v, a, b = (int(i) for i in t)
        if not inner(v) or moved & {v, a, b}:
            continue
        old = V[v].copy()
        mid = 0.5 * (V[a] + V[b])
        V[v] = mid + (V[v] - mid) * (1 - squeeze)
        if np.cross(V[T[:, 1]] - V[T[:, 0]], V[T[:, 2]] - V[T[:, 0]])[:, 2].min() <= 0:
            V[v] = old
            continue
        moved |= {v, a, b}
    return V, T


@pytest.mark.parametrize("preconditioner", ["jacobi", "amg", "sgs", "auto"])
def test_sliver_mesh_in_free_flight_keeps_momentum_and_never_gains_energy(preconditioner):
    V, T = sliver_sheet()
    assert min_angle_deg(V, T) < 1.0
    c = Cloth(V, T, material("cotton", damping_mass=0.0, damping_stiffness=0.0), gravity=(0, 0, 0))
    c.set_solver(preconditioner=preconditioner)
    c.set_velocities(np.random.default_rng(1).normal(scale=0.05, size=V.shape))  # default solver settings
    m = c.masses

    def total():
        e = c.energy()
        return e["kinetic"] + e["elastic"] + e["bending"] + e["gravity"]

    p0 = (m[:, None] * c.velocities).sum(0)
    e_prev = total()
    unconverged = 0
    for _ in range(200):
        c.step(1e-3)
        e = total()
        assert e <= e_prev * (1 + 1e-9) + 1e-15  # backward Euler only dissipates
        e_prev = e
        st = c.stats()
        unconverged += st["unconverged_substeps"]
        assert st["cg_residual"] <= c.solver["cg_tolerance"] or st["unconverged_substeps"]
    p = (m[:, None] * c.velocities).sum(0)
    assert np.linalg.norm(p - p0) <= 1e-6 * np.linalg.norm(p0)
    assert c.stats()["unconverged_steps"] == 0 and unconverged == 0
    # and the preconditioner asked for was the one used, every solve (a fallback is counted)
    assert c.stats()["amg_fallbacks"] == 0 and c.stats()["sgs_fallbacks"] == 0
    # slivers: block Jacobi (asked for, or auto's pick) inverts their corners together (stiff.c)
    assert (c.stats()["stiff_groups"] > 0) == (preconditioner in ("jacobi", "auto")), c.stats()["stiff_groups"]


def test_a_solve_stopped_at_its_cap_is_split_then_counted_never_silent():
    V, T = sliver_sheet()
    c = Cloth(V, T, material("cotton"), gravity=(0, 0, -9.81))
    c.set_velocities(np.random.default_rng(2).normal(scale=0.05, size=V.shape))
    c.set_solver(cg_max_iterations=3)  # far too few for these slivers
    c.step(1e-3)
    st = c.stats()
    assert st["substep_splits"] >= 3  # rolled back and halved, TC_SPLIT_DEPTH deep
    assert st["unconverged_substeps"] >= 1 and st["unconverged_steps"] == 1
    assert st["cg_residual"] > c.solver["cg_tolerance"]
    assert st["cg_residual_force"] == pytest.approx(st["cg_residual"] * st["cg_force_scale"], rel=1e-12)
    # the session says so in its step report
    s = Session(c)
    rep = s.step(1e-3)
    assert rep.unconverged_substeps >= 1 and s.unconverged_steps == 1
    # with a sensible cap the same cloth converges, at most after splitting
    c.set_solver(cg_max_iterations=200)
    c.step(1e-3)
    assert c.stats()["unconverged_substeps"] == 0


def tear_scene(tolerance):
    """A notched strip under gravity pulled apart by its clamped ends until the notch has run
    across it: one tear whose path the stress field decides (a scene where several tears branch
    and race is decided by round-off at any tolerance, so it could not tell tolerances apart)."""
    w, h = 0.2, 0.1
    V, T = sheet(w, h, 41, 21, jitter=0.3, seed=11)
    c = Cloth(V, T, material("cotton", young=5e6, thickness=5e-4, density=300.0, bending=1e-6, damping_mass=20.0,
                             damping_stiffness=0.0, tear_stress=3e5), gravity=(0, 0, -9.81))
    if tolerance is not None:
        c.set_solver(cg_tolerance=tolerance)
    bottom_mid = int(np.argmin(np.abs(V[:, 0] - 0.1) + 10 * V[:, 1]))
    c.scripted_tear(bottom_mid, (0, 1, 0), 0.012)
    n0 = c.num_vertices
    # Hems at the clamps (tear strength x10 within 2 cm): held cloth may tear at the grip, and an
    # unreinforced clamp starts a dozen tears there whose race round-off decides at any tolerance
    x = c.rest_positions[:, 0]
    c.set_tear_strength(np.where((x < 0.02) | (x > w - 0.02), 10.0, 1.0))
    hl = c.add_handle(np.flatnonzero(V[:, 0] < 1e-9))
    hr = c.add_handle(np.flatnonzero(V[:, 0] > w - 1e-9))
    c.set_tearing(True)
    for i in range(300):
        s = 2e-5 * i
        c.move_handle(hl, (-s, 0, 0))
        c.move_handle(hr, (s, 0.3 * s, 0))
        c.step(2e-3)
    st = c.stats()
    return st["tears_started"], st["cuts"], c.rest_positions[n0:], st["unconverged_steps"]


def test_tenfold_tighter_tolerance_changes_no_tear():
    default = Cloth(*sheet(0.02, 0.02, 3, 3), material("cotton")).solver["cg_tolerance"]
    tears_a, cuts_a, new_a, unc_a = tear_scene(None)
    tears_b, cuts_b, new_b, unc_b = tear_scene(default / 10)
    assert tears_a >= 1 and unc_a == 0 and unc_b == 0
    assert tears_a == tears_b
    # the paths: every vertex a tear made in one run lies within one edge length of one in the other
    edge = 0.2 / 40
    assert len(new_a) and len(new_b)
    d = np.linalg.norm(new_a[:, None, :] - new_b[None, :, :], axis=2)
    assert d.min(1).max() <= edge and d.min(0).max() <= edge
