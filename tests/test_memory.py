"""Memory of a cloth (issue 14): the accounting of Cloth._memory() and what it says about the
storage that was cut (the pair hash keeps ids only; the world stress, the principal stresses and
direction are derived from R and sigma where read, not stored per triangle; the bending stencils
are made again from their edge's triangles, not stored; the solve's prescribed part, its
right-hand side, the sub-step's start x0 and the elastic force live in other vectors; the
assembly's slots are derived from the pairs', not tabled per triangle; an isotropic sheet stores
no warp axes; the pair hash exists only once a tear needed it)."""
import numpy as np

from meshes import sheet
from tearcloth import Cloth, material

E, NU = 1e6, 0.3


def stepped(nx=61, ny=31, steps=3):
    V, T = sheet(0.3, 0.15, nx, ny)
    c = Cloth(V, T, material("cotton", young=E, poisson=NU), gravity=(0, 0, -9.81))
    left = c.add_handle(np.flatnonzero(V[:, 0] < 1e-9))
    right = c.add_handle(np.flatnonzero(V[:, 0] > 0.3 - 1e-9))
    for i in range(steps):
        c.move_handle(left, (-1e-3 * (i + 1), 0, 0))
        c.move_handle(right, (1e-3 * (i + 1), 0, 0))
        c.step(1e-3)
    return c, V, T


def test_the_accounting_names_every_array_and_the_cut_storage_holds_nothing():
    c, V, T = stepped()
    m = c._c._memory()
    for name in ("x", "rot", "sig", "rblk", "stencils", "pair_hash", "amg", "stress", "pdir",
                 "principal", "sfix2", "sb", "x0", "fel"):
        assert name in m, name
    # used never exceeds held for the arrays (the hierarchy reports one figure for both)
    for name, (used, held) in m.items():
        assert 0 <= used <= held, (name, used, held)
    # stored per triangle before: 9 + 2 + 3 doubles; now derived (the arrays stay empty), as the
    # stencils (64 bytes per interior edge) and the solve's sfix2, sb, x0 and fel (3 doubles per
    # vertex each); the slot table (36 bytes per triangle) is gone from the table
    assert "tslot" not in m
    for name in ("stress", "pdir", "principal", "stencils", "sfix2", "sb", "x0", "fel"):
        assert m[name][0] == 0, (name, m[name])
    # an isotropic sheet stores no warp axes nor own grain angles (ortho.c: 48 bytes per triangle);
    # its readers get them derived
    for name in ("twarp", "taxis", "tgrain"):
        assert m[name][0] == 0, (name, m[name])
    assert c.warp.shape == (len(T), 3) and np.allclose(np.linalg.norm(c.warp, axis=1), 1.0)
    assert np.all(np.isnan(c.grain_angles))
    # a cloth that never tore holds no pair hash (mesh.c: made when a tear first needs it)
    assert m["pair_hash"] == (0, 0), m["pair_hash"]
    # the whole cloth in use, per triangle, at 3600 triangles: seen 895 B after the warp axes and
    # the hash went, 953 before, 1029 before sb, x0, fel (3 x 12 B) and the slot table (39 B) went,
    # 1139 before the stencils (96 B), principal stresses (16) and sfix2, about 1310 before the
    # world stress and direction (96 B) and the hash's keys (8 of its 12 bytes per slot)
    total = sum(u for u, _ in m.values())
    assert total / len(T) < 940, total / len(T)


def test_the_pair_hash_is_made_again_by_a_tear_within_its_bound():
    c, V, T = stepped()
    c.set_tearing(True)
    assert c.scripted_tear(int(np.argmin(np.abs(V[:, 0] - 0.15) + V[:, 1])), (0.0, 1.0, 0.0), 0.03) > 0
    m = c._c._memory()
    # one int32 per slot at a load between 3/8 and 3/4 (mesh.c): at most 16 bytes per live pair
    # (it held 48 with the keys beside the ids)
    pairs = m["pi"][0] // 4  # every pair slot (pi: int32 per pair), live ones at most that
    assert 0 < m["pair_hash"][1] <= 16 * pairs + 4 * 64, (m["pair_hash"], pairs)


def test_derived_stress_is_consistent_with_the_principal_values_and_direction():
    """The world stress derived at read time is symmetric, in the sheet's plane (here the xy plane
    before the pull bends it little), and its largest eigenvalue and eigenvector are the stored
    principal stress and the derived principal direction."""
    c, V, T = stepped()
    S = c.stress
    p = c.principal_stress
    d = c.principal_direction
    scale = np.abs(S).max()
    assert scale > 0
    assert np.abs(S - np.transpose(S, (0, 2, 1))).max() <= 1e-12 * scale
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    Sd = np.einsum("tij,tj->ti", S, d)
    assert np.abs(Sd - p[:, :1] * d).max() <= 1e-9 * scale
    # the trace of R sigma R^T is sigma's: the two principal values' sum
    assert np.abs(np.trace(S, axis1=1, axis2=2) - p.sum(axis=1)).max() <= 1e-9 * scale


def test_a_derived_array_is_the_readers_copy():
    """STRESS is computed at the call into a block of the reader's own: a later step does not
    change an array read before it (tearcloth.h), a new read shows the new state."""
    c, V, T = stepped(steps=1)
    before = c.stress
    kept = before.copy()
    c.move_handle(0, (-5e-3, 0, 0))
    c.step(1e-3)
    after = c.stress
    assert np.array_equal(before, kept)
    assert not np.array_equal(after, kept)
