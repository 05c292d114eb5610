"""Stiff groups (native/stiff.c): the corners of sliver triangles, coupled far more stiffly to each
other than to the rest of the cloth, inverted together by block Jacobi, which "auto" then takes
over the Gauss-Seidel sweeps and over the multigrid cycle.

* A sheet with 0.23-0.46-degree slivers hung by one edge converges in every sub-step at dt = 2 ms and
  10 ms with no halving; the sweeps alone (the auto of before) halve and still stop at the cap.
* On a finer sheet of the same slivers (5,832 vertices), where auto took the multigrid cycle
  (9 s a 2 ms step, sub-steps at the cap at 10 ms), auto takes block Jacobi with the groups.
* The groups change how fast the solve gets there, not where: the same positions as the sweeps
  at a tight tolerance, contacts and pins among the groups' members included.
* Well-shaped meshes (the paper's three scenes) never form a group, at any step the artist uses,
  so their solves keep the sweeps; nor does the T-shirt after 50 scripted cuts.
* A cloth restored from a snapshot steps as the original, bit for bit (the look for slivers is
  scheduled from the snapshot on, in both).
"""

import numpy as np
import pytest
from meshes import sliver_sheet
from tearcloth import Cloth, examples, material
from tearcloth.bench.slivers import hung_sliver_sheet, min_angle_deg


def hung_sheet(preconditioner="auto", **solver):
    c = hung_sliver_sheet(preconditioner)  # cotton, pinned along its top edge, gravity on
    if solver:
        c.set_solver(**solver)
    return c


def test_the_sheet_has_slivers():
    V, T = sliver_sheet()
    assert min_angle_deg(V, T) < 0.3


@pytest.mark.parametrize("dt", [2e-3, 10e-3])
def test_slivers_converge_at_every_sub_step_without_halving(dt):
    c = hung_sheet()
    for _ in range(round(0.06 / dt)):
        c.step(dt)
        st = c.stats()
        assert st["stiff_groups"] > 0 and st["sgs_solves"] == 0  # block Jacobi with the groups
        assert st["substep_splits"] == 0 and st["unconverged_substeps"] == 0
        assert st["cg_residual"] <= c.solver["cg_tolerance"]
        assert st["cg_iterations"] < 1000  # one solve, far below the cap (~140 at 2 ms, ~300 at 10 ms)
    assert c.stats()["stiff_group_failures"] == 0
    assert np.isfinite(c.positions).all()


def test_auto_takes_the_groups_over_the_multigrid_cycle_on_a_fine_slivered_sheet():
    V, T = sliver_sheet(width=0.4, height=0.2, nx=81, ny=41)
    assert len(V) > 5000
    c = Cloth(V, T, material("cotton"), gravity=(0, 0, -9.81))
    c.pin(np.where(V[:, 1] > V[:, 1].max() - 1e-9)[0])
    for _ in range(2):
        c.step(10e-3)
        st = c.stats()
        assert st["amg_levels"] == 0 and st["stiff_groups"] > 1000 and st["sgs_solves"] == 0
        assert st["substep_splits"] == 0 and st["unconverged_substeps"] == 0
        # ~340 for a solve; the flap swinging down from flat turns fast enough at 10 ms that its
        # second step is solved again about the turned frames (step.c), ~800 more
        assert st["cg_iterations"] < 1000 * st["solves"], (st["cg_iterations"], st["solves"])


def test_without_the_groups_the_same_sheet_halves_and_stops_at_the_cap():
    """What the groups are for: the sweeps (no groups) on one 10 ms step halve three times and
    still stop at the cap, which the step says."""
    c = hung_sheet("sgs")
    c.step(10e-3)
    st = c.stats()
    assert st["stiff_groups"] == 0
    assert st["substep_splits"] >= 3 and st["unconverged_substeps"] >= 1


@pytest.mark.parametrize("contacts", [False, True])
def test_the_groups_change_the_speed_not_the_answer(contacts):
    """Auto (groups) and the sweeps (none) at a tolerance of 1e-10: the same positions to 1e-9 m
    after ten 1 ms steps; with the sheet lying on a floor, every vertex touching it (a contact
    normal +z, so every group is filtered) and pinned along one edge."""
    runs = []
    for pre in ("auto", "sgs"):
        c = hung_sheet(pre, cg_tolerance=1e-10, cg_max_iterations=20000)
        n = c.num_vertices
        for _ in range(10):
            if contacts:
                c.set_contacts(np.arange(n), np.tile([0.0, 0.0, 1.0], (n, 1)), np.zeros(n), friction=0.0)
            c.step(1e-3)
            st = c.stats()
            assert st["unconverged_substeps"] == 0
            assert (st["stiff_groups"] > 0) == (pre == "auto")
        runs.append(c.positions)
    assert np.abs(runs[0] - runs[1]).max() < 1e-9
    if contacts:  # held on the floor: nothing moved along the normal
        V, _ = sliver_sheet()
        assert np.abs(runs[0][:, 2] - V[:, 2]).max() < 1e-9


@pytest.mark.parametrize("dt", [1e-3, 1e-3 / 0.24, 20e-3])
@pytest.mark.parametrize("name", ["square_cloth", "banknote", "tshirt"])
def test_well_shaped_meshes_form_no_group(name, dt):
    mesh = getattr(examples, name)()
    c = Cloth(mesh.vertices, mesh.triangles, material("banknote" if name == "banknote" else "cotton"), groups=mesh.groups)
    c.pin(np.argsort(mesh.vertices[:, 2])[-5:])  # hung by its top five vertices
    for _ in range(20):
        c.step(dt)
        assert c.stats()["stiff_groups"] == 0


def test_a_tshirt_cut_fifty_times_forms_no_group():
    """Table I's "after 50 cuts" T-shirt: its cuts leave blocks of strength 0.88, where the sweeps
    still need only ~17 iterations; a bar of 0.85 took block Jacobi with groups there (35)."""
    from tearcloth.bench.table1 import DT, _unreachable, build
    from tearcloth.cloth import InvalidInputError

    sc = build("tshirt")
    c = sc.cloth
    c.set_material(**_unreachable(c))
    for i in range(200):
        sc.pull((i + 1) * DT)
        c.step(DT)
    X = c.positions
    height = X[:, 2].max() - X[:, 2].min()
    rng = np.random.default_rng(0)
    cuts = 0
    while cuts < 50:
        try:
            cuts += c.scripted_tear(int(rng.integers(c.num_vertices)), (0.0, 0.0, 1.0), 0.2 * height)
        except InvalidInputError:  # a rim vertex whose direction points off the cloth
            continue
    c.set_tearing(True)
    for i in range(200, 240):
        sc.pull((i + 1) * DT)
        c.step(DT)
        st = c.stats()
        assert st["stiff_groups"] == 0 and st["sgs_solves"] == st["solves"]


def test_a_speck_whose_block_is_strong_but_not_thin_forms_no_group():
    """A piece torn off as one small obtuse triangle (21, 21 and 137 degrees, 3 mm: a speck the
    race's shirt kept) couples its corners as strongly as a sliver's (strength 0.95), but it is no
    sliver: the sweeps take it out themselves. Before the sliver test looked at the triangles'
    angles, it took block Jacobi with groups for the whole cloth (13 groups here; on the race's
    torn shirt 277, and 3x the sub-step time); now the sweeps solve every sub-step, converged."""
    from meshes import sheet
    from tearcloth.cloth import smallest_angles_deg

    V, T = sheet(0.1, 0.1, 11, 11)
    a, b, side = np.radians(21.5), np.radians(21.1), 3e-3
    p0 = np.array([-0.01, -0.01, 0.0])
    p1 = p0 + [-side, 0.0, 0.0]
    p2 = p1 + side * np.sin(a) / np.sin(np.pi - a - b) * np.array([np.cos(b), -np.sin(b), 0.0])
    V = np.vstack([V, p0, p1, p2])
    T = np.vstack([T, [len(V) - 3, len(V) - 2, len(V) - 1]])
    assert smallest_angles_deg(V, T).min() > 20
    c = Cloth(V, T, material("cotton"), gravity=(0, 0, -9.81))
    c.pin(np.where(V[:, 1] > 0.1 - 1e-9)[0])
    for _ in range(20):
        c.step(1.0 / 240)  # the race's sub-step: 10 a frame at 24 fps
        st = c.stats()
        assert st["stiff_groups"] == 0 and st["sgs_solves"] == st["solves"], st
    assert st["unconverged_substeps"] == 0 and st["substep_splits"] == 0


def test_a_restored_sheet_steps_bit_for_bit():
    a = hung_sheet()
    for _ in range(3):
        a.step(4e-3)
    blob = a.snapshot()
    b = hung_sheet()
    b.restore(blob)
    for _ in range(20):  # past the next look for slivers on both
        a.step(4e-3)
        b.step(4e-3)
    assert a.stats()["stiff_groups"] > 0
    assert np.array_equal(a.positions, b.positions)
