"""Newton on the rotations (native/step.c, fem.c's tc_turn_pass). Each sub-step is linearized with
the triangles' rotations frozen where it began, and a frozen rotation reads a turn of theta as a
stretch of 1 - cos(theta). When the frames turn far enough in a sub-step, the sub-step is solved
again about the frames turned to where its solve took them. These tests hold the physics that
made it necessary against what is known: a spinning sheet's energy and spin against implicit
Euler's own damping of a circular motion, and a sheet falling into its pins at an artist's coarse
sub-steps against the same scene at fine ones."""
import dataclasses

import numpy as np
import pytest

from meshes import sheet
from tearcloth import Cloth, material


def spinning_sheet(mat: str, w: float):
    """An irregular 20 cm sheet spinning at w rad/s about its centre, undamped, no gravity."""
    V, T = sheet(0.2, 0.2, 15, 15, jitter=0.3, seed=4)
    V = V.copy()
    V[:, :2] -= 0.1
    c = Cloth(V, T, material(mat, damping_mass=0.0, damping_stiffness=0.0), gravity=(0, 0, 0))
    c.set_velocities(np.cross([0.0, 0.0, w], c.positions))
    return c


def spin(c: Cloth) -> float:
    """The angular momentum about the centre of mass, along z (kg m^2/s)."""
    m, x, v = c.masses, c.positions, c.velocities
    com = (m[:, None] * x).sum(0) / m.sum()
    return float((m[:, None] * np.cross(x - com, v)).sum(0)[2])


def total(c: Cloth) -> float:
    e = c.energy()
    return e["kinetic"] + e["elastic"] + e["bending"] + e["gravity"]


@pytest.mark.parametrize("mat, tolerance", [("cotton", None), ("paper", 1e-6)])
def test_a_spinning_sheet_never_gains_energy_and_keeps_its_spin_as_implicit_euler_does(mat, tolerance):
    """With frozen rotations, cotton at 20 rad/s and dt 2 ms gained 9 % of its energy in the first
    step (paper 224 %) and had 1 % of it left after 0.5 s (paper 0.04 %). Now energy only falls,
    and the spin falls as implicit Euler damps any circular motion: for a rigid ring
    L1 = x1 x v1 = x1 x v0 = L0 - dt lambda L1 (the pull v1 - v0 = -lambda x1, lambda = dt w^2),
    a factor 1 / (1 + (w dt)^2) a step. (Paper at the default tolerance, 1e-4, is not converged
    here: its energy after 0.5 s is 0.91 / 0.60 / 0.48 / 0.56 of the start at 1e-4 / 3e-5 / 1e-5 /
    1e-6 and below, and rises in half its steps at 1e-4; an open item of the stopping rule.)"""
    w, dt, steps = 20.0, 2e-3, 250
    c = spinning_sheet(mat, w)
    if tolerance:
        c.set_solver(cg_tolerance=tolerance)
    L0, e_prev = spin(c), total(c)
    for _ in range(steps):
        c.step(dt)
        e = total(c)
        assert e <= e_prev * (1 + 1e-9)
        e_prev = e
    euler = (1.0 + (w * dt) ** 2) ** -steps  # 0.45
    kept = spin(c) / L0
    # the cloth is not rigid: it stretches a little under the pull and is damped a little less
    assert euler <= kept <= euler + 0.35 * (1 - euler), (kept, euler)
    st = c.stats()
    assert st["rotation_solves"] >= steps and st["rotations_capped"] == 0


def test_the_spin_lost_converges_in_the_time_step_at_first_order():
    """The spin a sheet loses in 0.25 s halves with the time step (implicit Euler's first order).
    With frozen rotations the losses at 2 / 1 / 0.5 ms were 0.90 / 0.72 / 0.38 of the spin: not
    converging at any order in this range."""
    lost = []
    for dt in (2e-3, 1e-3, 5e-4):
        c = spinning_sheet("cotton", 20.0)
        L0 = spin(c)
        for _ in range(int(round(0.25 / dt))):
            c.step(dt)
        lost.append(1.0 - spin(c) / L0)
    assert lost[0] < 0.2, lost
    for coarse, fine in zip(lost, lost[1:]):
        assert 1.6 <= coarse / fine <= 2.4, lost


def test_a_cloth_hanging_at_rest_solves_once():
    """The re-solve is for turns that move the forces: a curtain hanging still from its top edge
    never pays it, while the same sheet held flat by one edge and let swing down pays it at every
    step of its swing (its triangles turn at up to ~20 rad/s)."""
    V, T = sheet(0.2, 0.1, 21, 11)
    curtain = V[:, [0, 2, 1]]  # in the xz plane, hanging from z = 0.1
    c = Cloth(curtain, T, material("cotton"))
    c.pin(np.flatnonzero(curtain[:, 2] > 0.1 - 1e-9))
    for _ in range(300):
        c.step(4e-3)
    before = c.stats()["rotation_solves"]
    for _ in range(100):
        c.step(4e-3)
    assert np.abs(c.velocities).max() < 1e-3
    assert c.stats()["rotation_solves"] == before

    flap = Cloth(V, T, material("cotton"))
    flap.pin(np.flatnonzero(V[:, 1] > 0.1 - 1e-9))
    for _ in range(100):
        flap.step(1e-3)
    assert flap.stats()["rotation_solves"] >= 90


def test_a_sheet_falling_into_its_pins_at_four_sub_steps_a_frame_peaks_as_at_sixteen():
    """A 10 cm sheet pinned along one edge and held by a handle on the other falls from flat and is
    then carried (test_bake_job's scene). At 4 sub-steps a frame (10.4 ms) the frozen rotations read
    the sag's turn as stretch: the first frame's peak stress was 0.66 MPa, 19x what 16 and 64
    sub-steps give (0.035 MPa). Now every frame's peak is within 2x of the fine one's."""
    tb = pytest.importorskip("test_bake_job")  # (it skips without USD)
    import tempfile
    from pathlib import Path

    def peaks(spf: int) -> tuple[np.ndarray, object]:
        plan = dataclasses.replace(tb.plan_for(Path(tempfile.mkdtemp()), (1, 6)), steps_per_frame=spf)
        job = tb.BakeJob(plan)
        job.begin(tb.moving_inputs(job.start_frame, plan))
        c = job.session.cloth
        seen = []
        job.session.add_step_listener(lambda *a, **k: seen.append(float(np.abs(c.principal_stress).max())))
        while not job.done:
            job.advance(tb.moving_inputs(job.next_frame, plan))
        job.close()
        return np.array(seen).reshape(-1, spf).max(axis=1), job.progress

    (coarse, said), (fine, _) = peaks(4), peaks(16)
    assert coarse.max() <= 2.0 * fine.max(), (coarse, fine)
    # the sub-steps the one re-solve did not bring under the bar are said at the end of the bake
    assert said.rotations_capped > 0 and "raise Steps per Frame" in said.rotation_text()
