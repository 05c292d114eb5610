"""Soft pins: a pin weight below 1 is a spring towards the vertex's goal, as Blender's cloth reads a
pin group (weight 1 holds exactly, a lower weight pulls with that share of the pin stiffness).

Checked against the analytic sag of a uniformly soft-pinned sheet (every vertex pulled alike, so
the sheet translates rigidly and only weight and spring act: g / (w S)), at two time steps, and
through what a cloth lives through: a followed mesh that moves, tears and splits, a snapshot."""
from __future__ import annotations

import numpy as np
import pytest

from tearcloth import examples
from tearcloth.cloth import PIN_HARD_WEIGHT, Cloth, InvalidInputError
from tearcloth.materials import material
from tearcloth.session import Session

G = 9.81


def sheet(**kw) -> Cloth:
    m = examples.square_cloth()
    return Cloth(m.vertices, m.triangles, material("cotton", **kw), groups=m.groups)


@pytest.mark.parametrize("dt, steps", [(0.02, 400), (0.005, 1600)])
def test_uniform_soft_pins_sag_by_g_over_w_stiffness(dt, steps):
    c = sheet()
    x0 = c.positions.copy()
    w, stiffness = 0.5, 1000.0
    assert c.pin_weights(np.full(c.num_vertices, w), stiffness) == (0, c.num_vertices)
    np.testing.assert_allclose(c.pin_springs, w * stiffness * c.masses, rtol=1e-15)
    for _ in range(steps):
        c.step(dt)
    d = c.positions - x0
    expected = G / (w * stiffness)  # 1.962 cm
    # measured: 1.962000e-2 at both time steps, spread across the sheet < 1e-6 m
    assert abs(-d[:, 2].mean() - expected) < 1e-4 * expected, d[:, 2].mean()
    assert d[:, 2].std() < 1e-5 and np.abs(d[:, :2]).max() < 1e-5
    assert c.stats()["unconverged_steps"] == 0


def test_weights_hard_soft_and_free():
    c = sheet()
    n = c.num_vertices
    w = np.zeros(n)
    w[:10] = 1.0
    w[10:20] = PIN_HARD_WEIGHT  # Blender's cloth snaps its goal there too
    w[20:30] = 0.3
    assert c.pin_weights(w, 2000.0) == (20, 10)
    assert c.pinned[:20].all() and not c.pinned[20:].any()
    assert c.soft_pinned[20:30].all() and not c.soft_pinned[:20].any() and not c.soft_pinned[30:].any()
    np.testing.assert_allclose(c.pin_springs[20:30], 0.3 * 2000.0 * c.masses[20:30])
    assert not c.pin_springs[30:].any()
    # a stiffness of 0 makes no spring: only the hard pins hold
    c2 = sheet()
    assert c2.pin_weights(w, 0.0) == (20, 0) and not c2.soft_pinned.any()


def test_soft_pins_follow_a_moving_mesh():
    """The whole sheet soft-pinned at weight 0.5 to a mesh that slides 5 cm along x over 0.25 s, then
    holds: the sheet arrives where the mesh went, sagging g / (w S) below it."""
    c = sheet()
    rest = c.positions.copy()
    c.pin_weights(np.full(c.num_vertices, 0.5), 1000.0)
    s = Session(c, None)
    s.follow_pins(rest, c.triangles)
    shift = np.array([0.05, 0.0, 0.0])
    s.set_pin_keyframe(rest + shift, 0.25)
    s.set_pin_keyframe(rest + shift, 10.0)
    for _ in range(150):
        s.step(0.02)
    d = c.positions - rest
    assert abs(d[:, 0].mean() - 0.05) < 1e-4, d[:, 0].mean()
    assert abs(-d[:, 2].mean() - G / 500.0) < 1e-4, d[:, 2].mean()


def test_soft_pins_through_tears_and_a_snapshot():
    """A band of soft pins (weight 0.5) across a sheet pulled apart by its hands until it tears: the
    splits inside the band keep a spring between their parents', nothing is NaN, and a snapshot taken
    after the tears resumes bit for bit."""
    c = sheet(tear_stress=2e5)
    x = c.positions
    band = x[:, 2] > np.quantile(x[:, 2], 0.8)
    w = np.where(band, 0.5, 0.0)
    c.pin_weights(w, 1000.0)
    hl, hr = c.add_handle("handle_left"), c.add_handle("handle_right")
    c.set_tearing(True)
    n0 = c.num_vertices
    for i in range(300):
        c.move_handle(hl, (-2e-4 * (i + 1), 0.0, 0.0))
        c.move_handle(hr, (2e-4 * (i + 1), 0.0, 0.0))
        c.step(1e-3)
        if c.stats()["cuts"] > 0 and c.num_vertices > n0 + 5:
            break
    assert c.num_vertices > n0, "the pull made no tear"
    k = c.pin_springs
    assert np.isfinite(c.positions).all() and np.isfinite(k).all() and (k >= 0).all()
    assert len(k) == c.num_vertices and k[n0:].max(initial=0.0) <= k[:n0].max()  # splits: between their parents'
    blob = c.snapshot()
    twin = sheet(tear_stress=2e5)
    twin.restore(blob)
    np.testing.assert_array_equal(twin.pin_springs, k)
    for _ in range(5):
        for cl in (c, twin):
            cl.step(1e-3)
    np.testing.assert_array_equal(twin.positions, c.positions)


def test_bad_soft_pins_are_refused_by_name():
    c = sheet()
    with pytest.raises(InvalidInputError, match=r"pin spring stiffness -1 N/m \(vertex 3\)"):
        c.set_pin_springs([3], -1.0)
    with pytest.raises(InvalidInputError, match="vertex 3"):
        c.set_pin_springs([3], float("nan"))
    with pytest.raises(InvalidInputError, match="2 values for 3 vertices"):
        c.set_pin_springs([1, 2, 3], [1.0, 2.0])
    with pytest.raises(InvalidInputError, match="pin weights: expected"):
        c.pin_weights(np.ones(3), 1000.0)
    with pytest.raises(InvalidInputError, match="pin_stiffness"):
        c.pin_weights(np.ones(c.num_vertices), -5.0)
    with pytest.raises(InvalidInputError, match="not pinned and has no pin spring"):
        c.set_pin_goals([4], [[0.0, 0.0, 0.0]])
    assert not c.soft_pinned.any()  # nothing half-set


def test_undamped_soft_pins_gain_no_energy():
    """The springs are implicit Euler like the rest of the step, which only dissipates: an
    undamped sheet on soft pins of every weight (0.05-0.95), shaken and left to swing under
    gravity, never holds more energy (kinetic + elastic + bending + gravity + the springs') than
    it started with, and the springs' energy is really exchanged (it is not always zero)."""
    c = sheet(damping_mass=0.0, damping_stiffness=0.0)
    rng = np.random.default_rng(3)
    c.pin_weights(rng.uniform(0.05, 0.95, c.num_vertices), 1000.0)
    c.set_velocities(rng.normal(scale=0.05, size=(c.num_vertices, 3)))
    c.set_solver(cg_tolerance=1e-9, cg_max_iterations=2000)

    def total():
        e = c.energy()
        return e["kinetic"] + e["elastic"] + e["bending"] + e["gravity"] + e["pins"]

    e0 = worst = total()
    springs = 0.0
    for _ in range(300):
        c.step(2e-3)
        worst = max(worst, total())
        springs = max(springs, c.energy()["pins"])
    assert worst <= e0 + 1e-9 * abs(e0), (e0, worst)
    assert springs > 1e-6 and total() < e0
