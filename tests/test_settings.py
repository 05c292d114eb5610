"""The settings table (addon/settings.py) and everything that reads it: the table is well formed,
the Python dataclasses and the presets take their values from it, validation refuses values
outside the hard bounds with a message naming the parameter, its value, its unit and the bound,
the Blender properties are the rows (PyPI bpy, in a subprocess), and the native core's defaults
agree with the rows that have a C field."""
from __future__ import annotations

import math
import warnings
from dataclasses import fields

import pytest

from tearcloth import settings as table
from tearcloth.materials import MATERIALS, Material, material
from tearcloth.session import CollisionSettings

NUMBERS = ("float", "int")


def _outside(bounds):
    """Values a row must refuse: each end point of an open side, just past each closed side."""
    bad = [math.nan, math.inf, -math.inf]
    if bounds.lo is not None:
        bad.append(bounds.lo if bounds.lo_open else bounds.lo - max(1.0, abs(bounds.lo)) * 1e-3)
    if bounds.hi is not None:
        bad.append(bounds.hi if bounds.hi_open else bounds.hi + max(1.0, abs(bounds.hi)) * 1e-3)
    return bad


def _components(row, value):
    return list(value) if row.kind == "vector" else [value]


# ---------------------------------------------------------------------------------------------
# The table itself


def test_every_row_is_complete_and_consistent():
    seen = set()
    for row in table.SETTINGS:
        where = row.key
        assert row.key not in seen, f"{where} twice"
        seen.add(row.key)
        assert row.name.isidentifier() and row.group.isidentifier(), where
        assert row.kind in table.KINDS, where
        assert row.unit in table.UNITS, where
        assert row.description.strip() and row.source.strip() and row.label.strip(), where
        if row.kind in NUMBERS or row.kind == "vector":
            assert row.unit != "-", f"{where}: a number needs a unit ('1' if dimensionless)"
            if row.kind != "vector" or row.name != "offset":  # a position in the scene has no bounds
                assert row.hard is not None and row.soft is not None, where
        else:
            assert row.unit == "-" and row.hard is None and row.soft is None, where
        if row.kind == "int":
            assert type(row.default) is int, where
        if row.kind == "float":
            assert type(row.default) is float, where
        if row.kind == "bool":
            assert type(row.default) is bool, where
        if row.kind in ("str", "file", "dir"):
            assert isinstance(row.default, str), where
        if row.kind == "enum":
            values = [v for v, _, _ in row.items]
            assert row.default in values and len(set(values)) == len(values), where
            assert all(v == v.lower() and label and text for v, label, text in row.items), where
        if row.hard is not None:
            for c in _components(row, row.default):
                assert row.hard.contains(c), f"{where}: default {row.default} outside {row.hard}"
            assert row.soft.within(row.hard), f"{where}: soft bounds {row.soft} not inside {row.hard}"
            for c in _components(row, row.default):
                assert row.soft.contains(c), f"{where}: default {row.default} outside its soft bounds"
        if row.native_default is not None:
            assert row.native is not None, where


def test_blender_names_are_unique_per_property_group_and_blocks_are_known():
    owners = {"material": "object", "solver": "object", "tearing": "object", "pins": "object",
              "collision": "object", "cache": "object", "export": "scene", "haptics": "haptics", "hand": "hand",
              "fray": "node group"}
    assert set(table.GROUPS) == set(owners)
    names = {}
    for row in table.SETTINGS:
        if row.blender_name is not None:
            key = (owners[row.group], row.blender_name)
            assert key not in names, (row.key, names.get(key))
            names[key] = row.key
        if row.block:
            assert row.block.split(".")[0] == row.group, row.key  # a block never mixes groups
    # every block ui.py draws exists and holds only rows Blender stores
    for block in ("material.elastic", "material.tearing", "material.damping", "solver.steps", "solver.cg",
                  "tearing.scan", "collision.contact", "collision.clusters", "haptics.demo", "hand.gains",
                  "hand.force"):
        assert all(row.blender_name for row in table.block(block)), block
    with pytest.raises(KeyError):
        table.block("no.such.block")
    with pytest.raises(KeyError, match="young"):
        table.setting("material", "youngs_modulus")


def test_bounds_refuse_and_warn():
    b = table.Bounds(0.0, 1.0, lo_open=True)
    assert not b.contains(0.0) and b.contains(1e-300) and b.contains(1.0) and not b.contains(1.0 + 1e-12)
    assert not b.contains(math.nan)
    assert b.text("m") == "> 0 m and <= 1 m"
    assert table.Bounds(0.2, 0.5).within(b) and not table.Bounds(0.0, 0.5).within(b)
    assert not table.Bounds(None, 0.5).within(b) and table.Bounds(0.0, 0.5).within(table.Bounds(0.0, 1.0))


# ---------------------------------------------------------------------------------------------
# Python consumers


def test_dataclass_defaults_are_the_table():
    d = table.defaults("material")
    assert {f.name: getattr(Material(), f.name) for f in fields(Material)} == d
    c = table.defaults("collision")
    got = {f.name: getattr(CollisionSettings(), f.name) for f in fields(CollisionSettings)}
    assert got == {k: c[k] for k in got}
    assert set(c) - set(got) == {"enabled"}  # the switch decides whether a CollisionSettings exists


# The five presets, written out: bit-identical bakes need bit-identical values.
PRESETS = {
    "cotton": (5.0e7, 0.3, 4.0e-4, 375.0, 5.0e-6, 3.0, 2.0e-5, 8.0e6, 0.3, 0.01, 0.2),
    "denim": (8.0e7, 0.3, 8.0e-4, 500.0, 4.0e-5, 3.0, 2.0e-5, 1.5e7, 0.3, 0.01, 0.2),
    "silk": (3.0e7, 0.3, 1.0e-4, 400.0, 2.0e-6, 3.0, 2.0e-5, 1.0e7, 0.3, 0.005, 0.2),
    "paper": (4.0e9, 0.3, 1.0e-4, 800.0, 3.6e-4, 3.0, 1.0e-5, 2.0e7, 0.3, 0.005, 0.5),
    "banknote": (3.0e9, 0.3, 1.1e-4, 820.0, 3.6e-4, 3.0, 1.0e-5, 3.0e7, 0.3, 0.005, 0.5),
    "poplin": (6.0e7, 0.3, 2.5e-4, 480.0, 2.0e-6, 3.0, 2.0e-5, 1.2e7, 0.3, 0.01, 0.2),
    "jersey": (5.0e6, 0.3, 6.0e-4, 300.0, 2.0e-6, 3.0, 2.0e-5, 3.0e6, 0.3, 0.01, 0.2),
}
FIELDS = ("young", "poisson", "thickness", "density", "bending", "damping_mass", "damping_stiffness",
          "tear_stress", "snap_tolerance", "tear_radius", "crack_speed_ratio")


def test_presets_keep_their_values_and_validate_within_the_soft_bounds():
    assert list(MATERIALS) == list(PRESETS)
    for name, values in PRESETS.items():
        m = MATERIALS[name]
        assert m.name == name
        assert tuple(getattr(m, f) for f in FIELDS) == values, name
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # a preset is never "unusual"
            assert m.validate() is m
    assert MATERIALS["cotton"] == Material()


@pytest.mark.parametrize("row", [r for r in table.rows("material") if r.hard is not None], ids=lambda r: r.name)
def test_material_validate_refuses_values_outside_the_hard_bounds(row):
    for bad in _outside(row.hard):
        with pytest.raises(ValueError) as info:
            Material(**{row.name: bad}).validate()
        text = str(info.value)
        assert row.name in text and repr(bad) in text, text
        if row.unit != "1":
            assert row.unit in text, text
        assert row.hard.text(row.unit) in text, text
        with pytest.raises(ValueError, match=row.name):
            material("cotton", **{row.name: bad})


def test_material_validate_warns_outside_the_soft_bounds():
    with pytest.warns(UserWarning, match=r"young = 100\.0 Pa is unusual: expected >= 10000 Pa"):
        Material(young=100.0).validate()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        Material(young=1.0e5).validate()


def test_collision_settings_refuse_values_outside_the_hard_bounds():
    for name in ("thickness", "friction", "displacement_threshold", "cluster_size"):
        row = table.setting("collision", name)
        for bad in _outside(row.hard):
            if row.kind == "int" and not math.isfinite(bad):
                continue
            with pytest.raises(ValueError, match=name):
                CollisionSettings(**{name: bad}).validate()
    with pytest.raises(ValueError, match="measure = 'sometimes' is not one of 'relative', 'absolute', 'full'"):
        CollisionSettings(measure="sometimes").validate()


def test_cloth_solver_and_tearing_keywords_are_checked_against_the_table():
    pytest.importorskip("tearcloth._native")
    import numpy as np

    from tearcloth.cloth import Cloth, InvalidInputError

    c = Cloth(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float), np.array([[0, 1, 2]]))
    assert c.solver["gravity"] == table.default("solver", "gravity")
    for group, setter in (("solver", c.set_solver), ("tearing", lambda **kw: c.set_tearing(True, **kw))):
        for row in table.rows(group):
            if row.native is None or row.kind == "bool":
                continue
            if row.kind == "enum":
                with pytest.raises(InvalidInputError, match=row.name):
                    setter(**{row.name: "no-such-" + row.name})
                continue
            for bad in _outside(row.hard):
                if row.kind == "int" and not math.isfinite(bad):
                    continue
                value = (bad, 0.0, 0.0) if row.kind == "vector" else bad
                with pytest.raises(InvalidInputError, match=row.name):
                    setter(**{row.name: value})
    with pytest.raises(TypeError, match="unknown solver setting"):
        c.set_solver(steps_per_frame=3)  # a Blender-side setting, not the core's


def test_native_defaults_agree_with_the_table():
    native = pytest.importorskip("tearcloth._native")
    if not hasattr(native, "defaults"):
        pytest.skip("tearcloth._native.defaults() is not built yet (it comes with the native layout branch)")
    got = native.defaults()
    assert set(got) == {"material", "solver", "tearing"}
    for group, values in got.items():
        want = table.native_defaults(group)
        assert set(values) == set(want), (group, sorted(set(values) ^ set(want)))
        for key, expected in want.items():
            value = values[key]
            if isinstance(expected, tuple):
                assert tuple(value) == expected, (group, key)
            elif isinstance(expected, bool):
                assert bool(value) is expected, (group, key)
            else:
                assert value == expected, (group, key, value, expected)


# ---------------------------------------------------------------------------------------------
# Blender


BLENDER = '''
    import tearcloth
    from tearcloth.blender import props
    tearcloth.register()
    classes = dict(object=props.TearClothObjectSettings, scene=props.TearClothSceneSettings,
                   haptics=props.TearClothHapticSettings, hand=props.TearClothHapticHand)
    out = {}
    undescribed = []
    for owner, cls in classes.items():
        for p in cls.bl_rna.properties:
            if p.identifier in ("rna_type", "name"):  # every PropertyGroup has these two
                continue
            if not p.description:
                undescribed.append(owner + "." + p.identifier)
            d = dict(name=p.name, description=p.description, type=p.type, subtype=p.subtype,
                     unit=getattr(p, "unit", None))
            if p.type in ("FLOAT", "INT"):
                d.update(min=p.hard_min, max=p.hard_max, soft_min=p.soft_min, soft_max=p.soft_max,
                         default=list(p.default_array) if p.array_length else p.default)
            elif p.type in ("BOOLEAN", "STRING", "ENUM"):
                d.update(default=p.default)
            if p.type == "ENUM":
                d.update(items=[(i.identifier, i.name, i.description) for i in p.enum_items])
            out[owner + "." + p.identifier] = d
    for owner in (bpy.types.Object, bpy.types.Scene):
        if not owner.bl_rna.properties["tearcloth"].description:
            undescribed.append(owner.__name__ + ".tearcloth")
    # a hem stronger than the cloth: factors above 1 are kept, not clamped to 1
    obj = bpy.data.objects.new("Sheet", bpy.data.meshes.new("Sheet"))
    obj.tearcloth.seam_factor = 2.5
    result(dict(props=out, undescribed=undescribed, seam=obj.tearcloth.seam_factor))
'''

OWNER = {"material": "object", "solver": "object", "tearing": "object", "pins": "object", "collision": "object",
         "cache": "object", "export": "scene", "haptics": "haptics", "hand": "hand"}


def _same(a, b):
    return a == pytest.approx(b, rel=1e-6, abs=1e-12)  # Blender keeps floats in single precision


def test_blender_properties_are_the_table_rows(tmp_path):
    pytest.importorskip("bpy")
    from test_blender_bake import run_blender

    got = run_blender(tmp_path, BLENDER)
    assert got["undescribed"] == []
    assert got["seam"] == pytest.approx(2.5)
    props = got["props"]
    for row in table.SETTINGS:
        if row.blender_name is None:
            continue
        key = f"{OWNER[row.group]}.{row.blender_name}"
        p = props.pop(key)
        assert p["name"] == row.label and p["description"] == row.description, key
        if row.kind == "enum":
            assert p["default"] == row.default.upper(), key
            assert p["items"] == [[v.upper(), label, text] for v, label, text in row.items], key
            continue
        if row.kind in ("float", "vector", "int"):
            default = list(row.default) if row.kind == "vector" else row.default
            assert _same(p["default"], default), key
            hard = row.hard or table.Bounds()
            soft = row.soft or hard
            if row.is_scene_length:
                # stored in BU: bounded in metres only where it is used (a BU bound is another
                # length in each unit scale), but for a zero floor, the same in every scale
                hard = soft = table.Bounds(lo=0.0 if hard.lo == 0 else None)
            assert _same(p["min"], hard.lo) if hard.lo is not None else p["min"] <= -2**31, key
            assert _same(p["max"], hard.hi) if hard.hi is not None else p["max"] >= 2**31 - 1, key
            assert _same(p["soft_min"], soft.lo if soft.lo is not None else p["min"]), key
            assert _same(p["soft_max"], soft.hi if soft.hi is not None else p["max"]), key
            if row.is_scene_length:
                assert p["unit"] == "LENGTH" and p["subtype"] in ("DISTANCE", "TRANSLATION"), key
            elif row.unit == "rad":  # an angle: stored in radians, shown in the scene's rotation unit
                assert p["unit"] == "ROTATION", key
            else:
                assert p["unit"] in (None, "NONE"), key
            continue
        assert p["default"] == row.default, key
        if row.kind == "file":
            assert p["subtype"] == "FILE_PATH", key
        if row.kind == "dir":
            assert p["subtype"] == "DIR_PATH", key
    # what is left is not a setting: the lists, their active rows and the pointers
    assert sorted(props) == ["haptics.left", "haptics.right", "object.active_collider_index",
                             "object.active_handle_index", "object.collider_collection", "object.colliders",
                             "object.handles", "object.haptics"]
