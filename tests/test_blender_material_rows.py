"""The panel rows of the orthotropic and plastic material values and the grain override, written
against the names the material rows will have (``orthotropic``, ``young_weft``, ``shear_modulus``,
``grain_angle`` in radians, ``tear_stress_weft``, ``plastic``, ``yield_stress``,
``yield_stress_weft``, ``hardening``): the test adds those rows to the table in its Blender child
before the add-on is imported, so it checks the layout rule of ui.py (a switched block is a
sub-panel whose rows show only while its switch is on; ``ui["when"]`` ties a row to another
block's switch) rather than the rows themselves. The grain override (a Face Float attribute
``tearcloth_grain_angle``) reaches the core per triangle through ``Cloth.set_grain_angles`` when
the core has it, and bad attributes are reported naming the object and polygon. About 5 s.
"""
from __future__ import annotations

import textwrap

import pytest

pytest.importorskip("bpy")
from test_blender_bake import run_blender  # noqa: E402

# Rows as the material rows will be (values are placeholders: only names, kinds and blocks matter).
ROWS = '''
    import math
    from tearcloth import settings as table
    if not table.rows("material") or "orthotropic" not in [r.name for r in table.rows("material")]:
        table.UNITS.setdefault("rad", "radian")
        B, src = table.Bounds, "test"
        extra = (
            table._b("material", "orthotropic", False, "Orthotropic", "Warp and weft", src, block="material.orthotropic"),
            table._f("material", "young_weft", "Pa", 2.0e7, "Young's Modulus Weft", "E weft", src,
                     B(0.0, 1e13, lo_open=True), block="material.orthotropic"),
            table._f("material", "shear_modulus", "Pa", 1.0e6, "Shear Modulus", "G", src, B(0.0, 1e13, lo_open=True),
                     block="material.orthotropic"),
            table._f("material", "grain_angle", "rad", 0.0, "Grain Angle", "Offset", src, B(-math.pi, math.pi),
                     block="material.orthotropic"),
            table._f("material", "tear_stress_weft", "Pa", 6.0e6, "Tear Stress Weft", "weft", src, B(0.0, None, lo_open=True),
                     block="material.orthotropic"),
            table._b("material", "plastic", False, "Plastic", "Yield", src, block="material.plastic"),
            table._f("material", "yield_stress", "Pa", 3.0e6, "Yield Stress", "yield", src, B(0.0, None, lo_open=True),
                     block="material.plastic"),
            table._f("material", "yield_stress_weft", "Pa", 2.0e6, "Yield Stress Weft", "yield weft", src,
                     B(0.0, None, lo_open=True), block="material.plastic", ui=dict(when="orthotropic")),
            table._f("material", "hardening", "1", 0.1, "Hardening", "hardening", src, B(0.0, None),
                     block="material.plastic"),
        )
        table.SETTINGS = table.SETTINGS + extra
        table._BY_KEY.update({r.key: r for r in extra})
'''


def test_orthotropic_and_plastic_rows_show_only_while_switched_on(tmp_path):
    got = run_blender(tmp_path, textwrap.dedent(ROWS) + textwrap.dedent('''
        from tearcloth.blender import ui
        obj = build_scene(sys.argv[1], save=False)

        class Layout:
            """Records the properties drawn (any other layout call is accepted and chained)."""
            def __init__(self): self.props = []
            def prop(self, data, name, **kw):
                assert name in data.bl_rna.properties, name
                self.props.append(name)
                return self
            def __getattr__(self, name):
                return lambda *a, **k: self
            def __setattr__(self, name, value):
                object.__setattr__(self, name, value)
        class Holder: pass

        def drawn(cls, part="draw"):
            holder = Holder(); holder.layout = Layout()
            with bpy.context.temp_override(object=obj, active_object=obj):
                getattr(cls, part)(holder, bpy.context)
            return holder.layout.props

        ortho, plastic = bpy.types.TEARCLOTH_PT_material_orthotropic, bpy.types.TEARCLOTH_PT_material_plastic
        s = obj.tearcloth
        out = dict(material=drawn(ui.TEARCLOTH_PT_material), headers=[drawn(ortho, "draw_header"),
                                                                       drawn(plastic, "draw_header")],
                   parents=[ortho.bl_parent_id, plastic.bl_parent_id])
        for o, p in ((False, False), (True, False), (False, True), (True, True)):
            s.orthotropic, s.plastic = o, p
            out[f"{o}-{p}"] = [drawn(ortho), drawn(plastic)]
        prop = s.bl_rna.properties["grain_angle"]
        out["grain"] = [prop.subtype, prop.unit]
        s.grain_angle = 0.5
        out["grain_value"] = s.grain_angle
        result(out)
    '''), tmp_path)
    material = got["material"]
    assert len(material) == 11 and not set(material) & {"orthotropic", "young_weft", "plastic", "yield_stress"}
    assert got["headers"] == [["orthotropic"], ["plastic"]]
    assert got["parents"] == ["TEARCLOTH_PT_material"] * 2
    assert got["False-False"] == [[], []]
    assert got["True-False"] == [["young_weft", "shear_modulus", "grain_angle", "tear_stress_weft"], []]
    assert got["False-True"] == [[], ["yield_stress", "hardening"]]
    assert got["True-True"] == [["young_weft", "shear_modulus", "grain_angle", "tear_stress_weft"],
                                ["yield_stress", "yield_stress_weft", "hardening"]]
    assert got["grain"] == ["ANGLE", "ROTATION"]  # shown in degrees, stored in radians
    assert got["grain_value"] == pytest.approx(0.5)


GRAIN = '''
    from tearcloth.blender import inputs
    from tearcloth.blender.report import BakeError, Reports
    from tearcloth import bake as bake_job
    from tearcloth.cloth import Cloth
    obj = build_scene(sys.argv[1], n=6, save=False)
    mesh = obj.data
    faces = len(mesh.polygons)

    def plan(values=None, domain="FACE", kind="FLOAT"):
        for a in [a for a in mesh.attributes if a.name == "tearcloth_grain_angle"]:
            mesh.attributes.remove(a)
        if values is not None:
            attr = mesh.attributes.new("tearcloth_grain_angle", kind, domain)
            if kind == "FLOAT" and domain == "FACE":
                attr.data.foreach_set("value", values)
        reports = Reports()
        try:
            p, _ = inputs.build_plan(bpy.context, obj, reports=reports, with_cache=False)
        except BakeError:
            return None, reports
        return p, reports

    out = {}
    angles = np.linspace(-1.0, 1.0, faces)
    p, r = plan(angles)
    out["no_method"] = [p.grain_angles is None, r.warnings]
    calls = []
    Cloth.set_grain_angles = lambda self, a: calls.append(np.asarray(a, float).tolist())
    p, r = plan(angles)
    tri_polygons = [t.polygon_index for t in mesh.loop_triangles]
    out["plan"] = [list(p.grain_angles), [float(angles[i]) for i in tri_polygons], r.warnings]
    fingerprint = p.settings_fingerprint
    bake_job.make_session(p, {}, 0.0)
    out["core"] = calls
    p2, _ = plan(angles * 2)
    p0, _ = plan(None)
    out["fingerprints"] = [fingerprint != p2.settings_fingerprint, p0.grain_angles is None,
                           fingerprint != p0.settings_fingerprint]
    bad = angles.copy(); bad[[3, 7]] = np.nan
    out["nan"] = plan(bad)[1].errors
    out["domain"] = plan(np.zeros(len(mesh.vertices)), domain="POINT")[1].errors
    result(out)
'''


def test_grain_override_reaches_the_core_per_triangle(tmp_path):
    got = run_blender(tmp_path, GRAIN, tmp_path)
    no_method, warnings = got["no_method"]
    if no_method:  # a core without grain directions: said, not used
        assert any("tearcloth_grain_angle" in w and "not used" in w for w in warnings), warnings
    per_triangle, expected, warnings = got["plan"]
    assert per_triangle == pytest.approx(expected) and len(per_triangle) == 2 * 25  # quads: two triangles each
    assert not any("grain" in w for w in warnings)
    assert got["core"] == [pytest.approx(expected)]
    assert got["fingerprints"] == [True, True, True]  # a bake resumes only under the same grain
    assert got["nan"] == ["Sheet: 'tearcloth_grain_angle' is not a number on polygons 3, 7"]
    assert len(got["domain"]) == 1 and "Sheet" in got["domain"][0] and "Face domain" in got["domain"][0]
