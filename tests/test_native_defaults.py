"""The C core's defaults (tearcloth._native.defaults(), native/settings.c) against the Python side:
the default material is materials.py's cotton field by field, the solver and tearing defaults are
what tearcloth.Cloth starts with. Also: messages of both native modules that quote a floating-point
value carry it (they are formatted by the C library: PyErr_Format has no %g on Python 3.13)."""
import dataclasses
import inspect

import numpy as np
import pytest

from meshes import sheet
from tearcloth import Cloth, _collide, _native
from tearcloth.cloth import InvalidInputError
from tearcloth.materials import MATERIALS, Material

MATERIAL_FIELDS = ["young", "poisson", "thickness", "density", "bending", "damping_mass", "damping_stiffness",
                   "tear_stress", "snap_tolerance", "tear_radius", "crack_speed_ratio", "orthotropic", "young_weft",
                   "shear_modulus", "grain_angle", "tear_stress_weft", "plastic", "yield_stress", "yield_stress_weft",
                   "hardening"]
SOLVER_FIELDS = ["gravity", "cg_tolerance", "cg_max_iterations", "max_stretch", "contact_max_push",
                 "contact_correction", "preconditioner"]
TEARING_FIELDS = ["enabled", "scan_period", "min_angle_deg", "min_fragment_area"]


def test_defaults_have_the_c_struct_fields():
    d = _native.defaults()
    assert list(d) == ["material", "solver", "tearing"]
    assert sorted(d["material"]) == sorted(MATERIAL_FIELDS)
    assert sorted(d["solver"]) == sorted(SOLVER_FIELDS)
    assert sorted(d["tearing"]) == sorted(TEARING_FIELDS)
    g = d["solver"]["gravity"]
    assert isinstance(g, tuple) and len(g) == 3 and all(isinstance(x, float) for x in g)
    assert isinstance(d["solver"]["cg_max_iterations"], int)
    assert isinstance(d["tearing"]["enabled"], bool) and isinstance(d["tearing"]["scan_period"], int)


def test_default_material_is_the_cotton_preset():
    cotton = dataclasses.asdict(MATERIALS["cotton"])
    assert cotton.pop("name") == "cotton"
    assert _native.defaults()["material"] == cotton
    # the Material dataclass's own defaults are the cotton preset too
    assert dataclasses.asdict(Material()) == dataclasses.asdict(MATERIALS["cotton"])


def test_a_native_cloth_made_without_material_is_cotton():
    V, T = sheet(0.1, 0.1, 4, 4)
    c = _native.Cloth(np.ascontiguousarray(V, np.float64), np.ascontiguousarray(T, np.int32))
    assert c.material() == _native.defaults()["material"]
    assert c.solver() == _native.defaults()["solver"]
    assert c.tearing() == _native.defaults()["tearing"]


def test_solver_and_tearing_defaults_are_the_python_cloths():
    d = _native.defaults()
    gravity = inspect.signature(Cloth.__init__).parameters["gravity"].default
    assert d["solver"]["gravity"] == tuple(float(g) for g in gravity)
    V, T = sheet(0.1, 0.1, 4, 4)
    c = Cloth(V, T)
    # tearcloth.Cloth sets the material and gravity; everything else is the C default
    assert c.solver == d["solver"]
    assert c.tearing == d["tearing"]
    assert c.tearing["enabled"] is False  # a cloth tears only after set_tearing()
    # the material the Python cloth starts with (cotton) reaches the core unchanged
    assert c._c.material() == _native.defaults()["material"]


def test_float_values_appear_in_native_messages():
    V, T = sheet(0.1, 0.1, 4, 4)
    c = Cloth(V, T)
    factor = np.ones(c.num_vertices)
    factor[3] = -1.0
    with pytest.raises(InvalidInputError, match=r"tear strength factor of vertex 3 must be > 0 and finite \(got -1\)"):
        c.set_tear_strength(factor)
    # straight to the core: the Python side checks the settings table's bounds first
    with pytest.raises(InvalidInputError, match=r"min_angle_deg must lie in \[0, 30\) \(got 45\)"):
        c._c.set_tearing(enabled=True, min_angle_deg=45.0)
    none_i, none_f, none_b = np.zeros(0, np.int64), np.zeros(0), np.zeros(0, bool)
    with pytest.raises(ValueError, match=r"track_range must be a finite non-negative number, got -0\.5"):
        _collide.refine(positions=np.zeros((0, 3)), normals=np.zeros((0, 3)), ray_vertex=none_i, ray_slot=none_i,
                        hit_triangle=none_i, target_vertices=np.zeros((0, 3)),
                        target_triangles=np.zeros((0, 3), np.int64), adjacency=np.zeros((0, 3), np.int64),
                        flip=np.zeros((0, 3), bool), ring=None, kind=1, track_range=-0.5, inside_prev=None,
                        out_vertex=none_i, out_slot=none_i.copy(), out_tri=none_i.copy(), out_t=none_f,
                        out_u=none_f.copy(), out_v=none_f.copy(), out_flips=none_b, status=none_b.copy())
