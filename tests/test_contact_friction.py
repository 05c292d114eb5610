"""Coulomb friction and the contact basis against truth: a sheet on an incline sticks below the
friction angle and slides with a = g (sin t - mu cos t) above it; a sheet pulled over a table by one
edge starts to slide when the pull reaches mu times the weight (static friction must not hold a
stretched, stiff cloth: tc_contacts_slip); a vertex squeezed between two near-opposite contacts
that ask incompatible speeds gets no faster than they ask (contact_solve)."""
import numpy as np
import pytest

from meshes import sheet
from tearcloth.cloth import Cloth
from tearcloth.materials import material

G = 9.81
DT = 1.0 / 240


def _rotate_y(theta):
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _plane_contacts(cloth, n, mu, exclude=()):
    """Every vertex on the plane through the origin with unit normal n (depth below it)."""
    x = cloth.positions
    idx = np.setdiff1d(np.arange(len(x)), np.asarray(exclude, dtype=np.int64)).astype(np.int32)
    depth = np.maximum(0.0, -(x[idx] @ n))
    cloth.set_contacts(idx, np.tile(n, (idx.size, 1)), depth, np.zeros((idx.size, 3)), mu)


@pytest.mark.parametrize("mu", [0.5, 0.2])
def test_a_sheet_on_an_incline_sticks_or_slides_as_coulomb_says(mu):
    theta = np.radians(20.0)  # tan = 0.364: mu 0.5 holds, mu 0.2 slides
    R = _rotate_y(theta)
    V, T = sheet(0.1, 0.05, 11, 6)
    cloth = Cloth(V @ R.T, T, material("cotton"))
    n, down = R @ [0, 0, 1.0], R @ [1.0, 0, 0]
    assert down[2] < 0
    steps = 60
    for _ in range(steps):
        _plane_contacts(cloth, n, mu)
        cloth.step(DT)
    v = cloth.velocities @ down
    a = G * (np.sin(theta) - mu * np.cos(theta))
    if a <= 0.0:
        assert np.abs(v).max() < 1e-3, v.max()
    else:
        # implicit Euler with the material's mass damping: v' = (v + a dt) / (1 + damping_mass dt)
        expect = 0.0
        for _ in range(steps):
            expect = (expect + a * DT) / (1.0 + cloth.material.damping_mass * DT)
        assert v.mean() == pytest.approx(expect, rel=1e-3), (v.mean(), expect)
        assert v.std() < 1e-3 * expect  # a rigid slide
    assert np.abs(cloth.velocities @ n).max() < 1e-3  # stays on the plane


def test_a_sheet_pulled_by_one_edge_slides_at_mu_times_its_weight():
    """A stretched cloth held by static friction pulls on its contacts far beyond mu times their
    normal force; they must slide. Pulled slowly by one edge, the sheet's resistance is kinetic
    friction, mu W (W the weight of the vertices on the table), not the tension of a stuck sheet."""
    mu = 0.3
    V, T = sheet(0.1, 0.05, 21, 11)
    cloth = Cloth(V, T, material("cotton"))
    edge = np.where(V[:, 0] > 0.1 - 1e-9)[0]
    h = cloth.add_handle(edge)
    n = np.array([0, 0, 1.0])
    W = cloth.masses[np.setdiff1d(np.arange(len(V)), edge)].sum() * G
    speed, steps = 0.02, 240
    fx = []
    for k in range(steps):
        cloth.move_handle(h, [speed * (k + 1) * DT, 0, 0])
        _plane_contacts(cloth, n, mu, exclude=edge)
        cloth.step(DT)
        fx.append(-cloth.handle_force(h)[0])  # the cloth pulls the hand back (-x)
    far = cloth.positions[V[:, 0] < 1e-9, 0]
    # the far edge followed (the sheet slid, it did not stretch by the handle's 4.8 mm)
    assert far.mean() > 0.8 * speed * steps * DT, far.mean()
    late = np.array(fx[steps // 2:])
    assert np.median(late) == pytest.approx(mu * W, rel=0.15), (np.median(late), mu * W)
    assert late.max() < 2.0 * mu * W
    st = cloth.stats()
    assert st["friction_slips"] > 0


def test_a_vertex_squeezed_between_near_opposite_contacts_is_not_flung():
    """Two contacts at one vertex whose normals are 157 degrees apart (|n1 x n2| = 0.4), both
    pushing in at 0.5 m/s: no velocity satisfies both without a sideways speed of ~2.4 m/s (what the
    Gram-Schmidt basis prescribed). The vertex must stay within what the contacts ask, |z| = 0.71
    m/s, and along the squeeze axis take their compromise (they push equally: rest)."""
    V, T = sheet(0.02, 0.02, 3, 3)
    cloth = Cloth(V, T, material("cotton"), gravity=(0.0, 0.0, 0.0))
    i = 4  # the middle vertex
    n1 = np.array([0.0, 0.0, 1.0])
    n2 = np.array([0.4, 0.0, -np.sqrt(1 - 0.16)])
    z = 0.5
    cloth.set_contacts([i, i], [n1, n2], [0.0, 0.0], [z * n1, z * n2], 0.0)
    cloth.step(DT)
    v = cloth.velocities[i]
    assert np.linalg.norm(v) <= np.sqrt(2) * z + 1e-9, v
    axis = (n1 - n2) / np.linalg.norm(n1 - n2)
    assert abs(v @ axis) < 1e-6, v  # z1 = z2: the disagreement is shared, no side wins
    st = cloth.stats()
    assert st["contact_directions_merged"] == 1
    # incompatible but not near-opposite (120 degrees, both asking 0.5 m/s): the exact solution
    # would need 1 m/s along the bisector; bounded to |z| and counted
    cloth2 = Cloth(V, T, material("cotton"), gravity=(0.0, 0.0, 0.0))
    n3 = np.array([np.sin(np.radians(120)), 0.0, np.cos(np.radians(120))])
    cloth2.set_contacts([i, i], [n1, n3], [0.0, 0.0], [z * n1, z * n3], 0.0)
    cloth2.step(DT)
    v2 = cloth2.velocities[i]
    assert np.linalg.norm(v2) == pytest.approx(np.sqrt(2) * z, rel=1e-6), v2
    assert v2 @ n1 == pytest.approx(v2 @ n3, abs=1e-9)  # shared equally, below what each asks
    assert cloth2.stats()["contact_speed_clamps"] == 1
