"""The solver's matrix-vector kernels (scalar, SSE2, AVX2, NEON; the one abi3 wheel picks at run time):
the same product to 1e-12 relative, a product that is the system matrix (symmetric, translations
only feel the mass) after tearing rebuilt its rows, and steps that agree whichever kernel ran."""
import numpy as np
import pytest

from meshes import sheet
from tearcloth import Cloth, _native, material



def available():
    was = _native.simd()
    out = []
    for k in ("scalar", "sse2", "avx2", "neon"):
        try:
            _native.simd(k)
            out.append(k)
        except ValueError:
            pass
    _native.simd(was)
    return out


@pytest.fixture
def restore_kernel():
    was = _native.simd()
    yield
    _native.simd(was)


def torn_cloth():
    """A jittered sheet pulled until it tore, then stepped once more with tearing off, so the rows
    of the matrix were rebuilt for the torn mesh."""
    w, h = 0.2, 0.1
    V, T = sheet(w, h, 41, 21, jitter=0.3, seed=11)
    c = Cloth(V, T, material("cotton", young=5e6, thickness=5e-4, density=300.0, bending=1e-6, damping_mass=20.0,
                             tear_stress=3e5), gravity=(0, 0, -9.81))
    bottom_mid = int(np.argmin(np.abs(V[:, 0] - 0.1) + 10 * V[:, 1]))
    c.scripted_tear(bottom_mid, (0, 1, 0), 0.02)
    hl = c.add_handle(np.flatnonzero(V[:, 0] < 1e-9))
    hr = c.add_handle(np.flatnonzero(V[:, 0] > w - 1e-9))
    c.set_tearing(True)
    for i in range(60):
        c.move_handle(hl, (-2e-5 * i, 0, 0))
        c.move_handle(hr, (2e-5 * i, 0, 0))
        c.step(2e-3)
    assert c.num_vertices > len(V)
    c.set_tearing(False)
    c.step(2e-3)
    return c


def product(c, p):
    return np.frombuffer(c._c._product(np.ascontiguousarray(p)), dtype=np.float64).reshape(-1, 3)


def test_every_kernel_gives_the_same_product_within_1e_12(restore_kernel):
    kernels = available()
    assert "scalar" in kernels
    c = torn_cloth()
    p = np.random.default_rng(0).normal(size=(c.num_vertices, 3))
    ys = {}
    for k in kernels:
        _native.simd(k)
        assert _native.simd() == k
        ys[k] = product(c, p)
    ref = ys["scalar"]
    for k, y in ys.items():
        assert np.abs(y - ref).max() <= 1e-12 * np.abs(ref).max(), k


def test_the_product_after_a_tear_is_the_system_matrix(restore_kernel):
    c = torn_cloth()
    m = c.masses
    dt, alpha = 2e-3, c.material.damping_mass
    rng = np.random.default_rng(1)
    p, q = rng.normal(size=(2, c.num_vertices, 3))
    for k in available():
        _native.simd(k)
        # symmetric: a block stored in one row and not its transpose in the other would break it
        a, b = (q * product(c, p)).sum(), (p * product(c, q)).sum()
        assert a == pytest.approx(b, rel=1e-12)
        # K annihilates a translation: a missing or doubled block would not
        y = product(c, np.tile([1.0, -2.0, 0.5], (c.num_vertices, 1)))
        scale = np.abs(product(c, p)).max()
        assert np.abs(y - (1 + dt * alpha) * m[:, None] * [1.0, -2.0, 0.5]).max() <= 1e-9 * scale


def test_steps_agree_whichever_kernel_runs(restore_kernel):
    runs = {}
    for k in available():
        _native.simd(k)
        V, T = sheet(0.2, 0.1, 21, 11, jitter=0.3, seed=2)
        c = Cloth(V, T, material("cotton"), gravity=(0, 0, -9.81))
        c.pin(np.flatnonzero(V[:, 1] > 0.1 - 1e-9))
        c.set_solver(cg_tolerance=1e-10, cg_max_iterations=2000)
        for _ in range(20):
            c.step(1e-3)
        runs[k] = c.positions.copy()
    ref = runs["scalar"]
    for k, x in runs.items():
        assert np.abs(x - ref).max() <= 1e-9 * np.abs(ref).max(), k


def test_an_unknown_or_unavailable_kernel_is_refused(restore_kernel):
    with pytest.raises(ValueError, match="not available"):
        _native.simd("avx512")
