"""The settings table: every parameter a user of Tear Cloth can set, declared once.

What this file owns
-------------------
One row (``Setting``) per user parameter, grouped as the product is: ``material``, ``solver``,
``tearing``, ``pins``, ``collision``, ``cache``, ``export``, ``haptics`` (the live session),
``hand`` (one hand of it) and ``fray`` (the inputs of the frayed-edge node group). A row says the parameter's name (one name per concept, the paper's
word where it has one), its SI unit, its default, its hard bounds (physically impossible or
refused by the core outside them: a ValueError), its soft bounds (possible but suspicious outside
them: a warning, and the drag range in Blender), what it means and where its value comes from.
Everything else reads the rows, nothing restates them:

* ``materials.Material`` and ``session.CollisionSettings`` take their field defaults from here and
  validate with ``validate`` (hard bounds raise, soft bounds warn);
* ``cloth.Cloth.set_solver``/``set_tearing`` validate their keywords here before the core sees them;
* ``blender/props.py`` builds every Blender property of a row (name, description, default,
  min/max = hard bounds, soft_min/soft_max = soft bounds, the LENGTH unit for lengths in the
  scene) and ``blender/ui.py`` draws the rows of a ``block`` in table order;
* ``blender/convert.py`` turns the rows' Blender values into SI and back;
* ``tests/test_settings.py`` checks the native core's defaults (``_native.defaults()``) against
  the rows that have a ``native`` field.

Where a bound is not physical (the longest time step of the live session, the most steps per
frame), the hard bound is the clamp the Blender property always had, so nothing a user could set
before is refused now and nothing new becomes settable by accident. Rows are in the order the
panels draw them; Python dataclasses keep their own field order (keyword construction only).

Enumerations are spelt in lower case in Python (``"relative"``) and in upper case in Blender
(``'RELATIVE'``), the convention of each side; ``props.py`` converts.

Names kept for .blend files: a Blender property keeps its RNA name even where the table's name
differs (``rna``): ``use_tearing`` (tearing ``enabled``), ``material_preset`` (material ``name``),
``collision_thickness`` (collision ``thickness``), ``use_collision``, ``use_self_collision``.
Renaming them would drop the values stored in existing files.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping

# SI units (and the two counts and one angle in degrees the add-on exposes as such). "1": dimensionless;
# "-": not a quantity (a switch, a choice, a name, a path).
UNITS = {
    "Pa": "pascal", "1": "dimensionless", "m": "metre", "kg/m^3": "kilogram per cubic metre",
    "N m": "newton metre", "1/s": "per second", "s": "second", "m/s": "metre per second",
    "m/s^2": "metre per second squared", "deg": "degree", "rad": "radian", "N": "newton", "N/m": "newton per metre",
    "N s/m": "newton second per metre", "frame": "frame number", "-": "not a quantity",
    "1/m": "per metre",
    "m^2": "square metre", "1/s^2": "per second squared (newton per metre per kilogram)",
}
KINDS = ("float", "int", "bool", "enum", "str", "file", "dir", "vector")
NUMERIC = ("float", "int", "vector")


@dataclass(frozen=True)
class Bounds:
    """An interval, closed unless said otherwise; None: unbounded on that side. A vector's bounds
    apply to each component."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False

    def contains(self, value: float) -> bool:
        if not math.isfinite(value):  # NaN fails every comparison, infinity is never a setting
            return False
        if self.lo is not None and (value <= self.lo if self.lo_open else value < self.lo):
            return False
        if self.hi is not None and (value >= self.hi if self.hi_open else value > self.hi):
            return False
        return True

    def within(self, other: "Bounds") -> bool:
        """True if every value of self lies in other (for soft-inside-hard checks)."""
        if other.lo is not None:
            if self.lo is None or self.lo < other.lo or (self.lo == other.lo and other.lo_open and not self.lo_open):
                return False
        if other.hi is not None:
            if self.hi is None or self.hi > other.hi or (self.hi == other.hi and other.hi_open and not self.hi_open):
                return False
        return True

    def text(self, unit: str) -> str:
        u = "" if unit in ("1", "-") else f" {unit}"
        parts = []
        if self.lo is not None:
            parts.append(f"{'>' if self.lo_open else '>='} {self.lo:g}{u}")
        if self.hi is not None:
            parts.append(f"{'<' if self.hi_open else '<='} {self.hi:g}{u}")
        return " and ".join(parts) or "any finite value"


@dataclass(frozen=True)
class Setting:
    """One user parameter. ``rna``: the Blender property's name ("" = ``name``, None = not a
    Blender property); ``native``: the C struct field it sets (None = Python only);
    ``native_default``: the core's own default where it deliberately differs (see the row);
    ``scene``: a length in the scene (shown in scene units in Blender) rather than in a device's
    frame; ``block``: the panel block it is drawn in (in a block, a bool row is the switch of the
    rows after it; a block that starts with one is a sub-panel: ``blender/ui.py``); ``ui``: display
    hints for Blender only (``when``: the name, or names, of the group's bool rows that must be on
    for the row to be drawn)."""

    group: str
    name: str
    kind: str
    unit: str
    default: Any
    description: str
    source: str
    label: str
    hard: Bounds | None = None
    soft: Bounds | None = None
    items: tuple = ()               # enum: (value, label, description), values in lower case
    rna: str | None = ""
    native: str | None = None
    native_default: Any = None
    scene: bool = True
    block: str = ""
    ui: Mapping[str, Any] = field(default_factory=dict)

    @property
    def key(self) -> str:
        return f"{self.group}.{self.name}"

    @property
    def blender_name(self) -> str | None:
        return self.name if self.rna == "" else self.rna

    @property
    def is_scene_length(self) -> bool:
        return self.unit == "m" and self.scene

    def _unit_text(self) -> str:
        return "(dimensionless)" if self.unit in ("1", "-") else self.unit

    def check(self, value, who: str = "") -> None:
        """Raise ValueError if value is outside the hard bounds (or not one of an enum's values);
        warn if it is outside the soft bounds."""
        prefix = f"{who}: " if who else ""
        if self.kind == "enum":
            allowed = [v for v, _, _ in self.items]
            if value not in allowed:
                raise ValueError(f"{prefix}{self.name} = {value!r} is not one of {', '.join(map(repr, allowed))}")
            return
        if self.kind not in NUMERIC:
            return
        components = list(value) if self.kind == "vector" else [value]
        for c in components:
            try:
                c = float(c)
            except (TypeError, ValueError):
                raise ValueError(f"{prefix}{self.name} = {value!r} is not a number") from None
            if self.hard is not None and not self.hard.contains(c):
                raise ValueError(f"{prefix}{self.name} = {value!r} {self._unit_text()} is outside its hard bounds: "
                                 f"it must be {self.hard.text(self.unit)}")
            if self.hard is None and not math.isfinite(c):
                raise ValueError(f"{prefix}{self.name} = {value!r} {self._unit_text()} must be finite")
        for c in components:
            if self.soft is not None and not self.soft.contains(float(c)):
                warnings.warn(f"{prefix}{self.name} = {value!r} {self._unit_text()} is unusual: "
                              f"expected {self.soft.text(self.unit)}", stacklevel=4)
                return


def _f(group, name, unit, default, label, description, source, hard, soft=None, **kw) -> Setting:
    kind = "vector" if isinstance(default, tuple) else "float"  # a vector's bounds bind each component
    return Setting(group, name, kind, unit, default, description, source, label, hard, soft or hard, **kw)


def _i(group, name, unit, default, label, description, source, hard, soft=None, **kw) -> Setting:
    return Setting(group, name, "int", unit, default, description, source, label, hard, soft or hard, **kw)


def _b(group, name, default, label, description, source, **kw) -> Setting:
    return Setting(group, name, "bool", "-", default, description, source, label, **kw)


def _e(group, name, default, label, description, source, items, **kw) -> Setting:
    return Setting(group, name, "enum", "-", default, description, source, label, items=tuple(items), **kw)


def _s(group, name, default, label, description, source, kind="str", **kw) -> Setting:
    return Setting(group, name, kind, "-", default, description, source, label, **kw)


_COTTON = "the 'cotton' preset of materials.py (see its sources)"
_CORE = "the native core's default"
_UI = "Tear Cloth's default since the first release"
_B = Bounds

SETTINGS: tuple[Setting, ...] = (
    # -- material: the 'cotton' preset (materials.MATERIALS keeps all five presets) -----------
    _s("material", "name", "cotton", "Preset", "Material preset last applied (editing a value keeps the name)",
       "materials.py", rna="material_preset"),
    _f("material", "young", "Pa", 5.0e7, "Young's Modulus", "In-plane stiffness E of the sheet material, in pascals",
       _COTTON, _B(0.0, 1.0e13, lo_open=True), _B(1.0e4, 1.0e10), native="young", block="material.elastic",
       ui=dict(precision=0, step=1e6)),
    _f("material", "poisson", "1", 0.3, "Poisson Ratio", "Lateral contraction under stretch, nu",
       _COTTON, _B(-1.0, 0.5, lo_open=True, hi_open=True), _B(0.0, 0.49), native="poisson",
       block="material.elastic", ui=dict(precision=3)),
    _f("material", "thickness", "m", 4.0e-4, "Thickness", "Sheet thickness h (stress = force per width / h)",
       _COTTON, _B(0.0, 1.0, lo_open=True), _B(1.0e-5, 0.01), native="thickness", block="material.elastic",
       ui=dict(precision=5, step=0.01)),
    _f("material", "density", "kg/m^3", 375.0, "Density",
       "Volumetric density in kg/m^3 (areal mass = density x thickness)",
       _COTTON, _B(0.0, 1.0e5, lo_open=True), _B(10.0, 2.0e4), native="density", block="material.elastic",
       ui=dict(precision=1)),
    _f("material", "tear_stress", "Pa", 8.0e6, "Tear Stress",
       "Largest principal stress at which the sheet tears (sigma_E of the paper), in pascals",
       _COTTON, _B(0.0, None, lo_open=True), _B(1.0e3, 1.0e9), native="tear_stress", block="material.tearing",
       ui=dict(precision=0, step=1e5)),
    _f("material", "snap_tolerance", "1", 0.3, "Snap Tolerance",
       "A tear passing this close to a vertex (fraction of an edge) goes through it, "
       "so tears make few and well-shaped new triangles",
       _COTTON, _B(0.0, 0.5, hi_open=True), _B(0.0, 0.49), native="snap_tolerance", block="material.tearing",
       ui=dict(precision=2)),
    _f("material", "tear_radius", "m", 0.01, "Tear Radius",
       "Material length over which the stress that starts, drives and stops a tear is averaged, so the "
       "tear does not depend on the mesh once its edges are shorter than this (0: one vertex ring)",
       _COTTON + " (the theory of critical distances: about E G_c / (pi sigma_E^2))", _B(0.0, 1.0),
       _B(0.0, 0.1), native="tear_radius", block="material.tearing", ui=dict(precision=4)),
    _f("material", "crack_speed_ratio", "1", 0.2, "Crack Speed",
       "Fastest a tear runs, as a fraction of the Rayleigh wave speed of the sheet (about 0.9 sqrt(shear "
       "modulus / density)); a tear driven just past its threshold runs slower (Freund's law)",
       _COTTON, _B(0.0, 1.0, lo_open=True), _B(0.001, 0.9), native="crack_speed_ratio",
       block="material.tearing", ui=dict(precision=3)),
    _f("material", "bending", "N m", 5.0e-6, "Bending", "Bending stiffness in N m",
       _COTTON, _B(0.0, None), _B(0.0, 1.0), native="bending", block="material.damping",
       ui=dict(precision=6, step=0.001)),
    _f("material", "damping_mass", "1/s", 3.0, "Mass Damping",
       "Rayleigh damping proportional to mass (alpha), in 1/s: air drag",
       _COTTON + "; 3 /s gives the 1-4 m/s terminal speed of a falling sheet", _B(0.0, None), _B(0.0, 100.0),
       native="damping_mass", block="material.damping", ui=dict(precision=3)),
    _f("material", "damping_stiffness", "s", 2.0e-5, "Stiffness Damping",
       "Rayleigh damping proportional to stiffness (beta), in seconds: internal friction",
       _COTTON, _B(0.0, None), _B(0.0, 0.01), native="damping_stiffness", block="material.damping",
       ui=dict(precision=6, step=0.001)),
    # woven sheets (native/ortho.c, native/tear.c): with orthotropic on, young, poisson and
    # tear_stress are the warp's values (poisson is nu_warp-weft; nu_weft-warp = poisson young_weft / young)
    _b("material", "orthotropic", False, "Woven (Warp/Weft)",
       "Different stiffness and strength along the warp and the weft, a soft bias, and tears that run along "
       "the threads; the warp follows the UV map's U direction, turned by the grain angle",
       "isotropic by default: cotton's preset is the plain isotropic sheet the add-on always simulated",
       native="orthotropic", block="material.orthotropic"),
    _f("material", "young_weft", "Pa", 4.0e7, "Young's Modulus (Weft)",
       "In-plane stiffness along the weft threads, in pascals (Young's Modulus is the warp's when woven)",
       _COTTON + "; plain-weave shirting stretches 10-30 % more along the weft than the warp in strip tests "
       "(ISO 13934-1), hence 0.8 of the warp's", _B(0.0, 1.0e13, lo_open=True), _B(1.0e4, 1.0e10),
       native="young_weft", block="material.orthotropic", ui=dict(precision=0, step=1e6)),
    _f("material", "shear_modulus", "Pa", 5.0e5, "Shear Modulus (Bias)",
       "In-plane shear stiffness G of the warp-weft axes, in pascals: how much the cloth resists being pulled "
       "on the bias (45 degrees); woven cloth is far softer there than along its threads",
       _COTTON + "; Kawabata KES-FB1 shear rigidity of cotton shirting 0.5-3 gf/cm/deg (S. Kawabata, The "
       "Standardization and Analysis of Hand Evaluation, 1980) is G h = 30-170 N/m, so G = 1-4e5 Pa at 0.4 mm; "
       "5e5 allows for the initial, pre-slip stiffness", _B(0.0, 1.0e13, lo_open=True), _B(1.0e3, 1.0e10),
       native="shear_modulus", block="material.orthotropic", ui=dict(precision=0, step=1e5)),
    _f("material", "grain_angle", "rad", 0.0, "Grain Angle",
       "Angle of the warp from the UV map's U direction (counter-clockwise seen from the front), in radians; a "
       "face attribute tearcloth_grain_angle overrides it per face. Without UVs the warp starts along the rest X axis",
       "garment patterns cut on the straight grain (0); a bias cut is 45 degrees", _B(-100.0, 100.0),
       _B(-math.pi, math.pi), native="grain_angle", block="material.orthotropic", ui=dict(precision=3)),
    _f("material", "tear_stress_weft", "Pa", 6.5e6, "Tear Stress (Weft)",
       "Stress along the weft at which the weft threads break, in pascals (Tear Stress is the warp's when "
       "woven); a woven tear runs across the threads that break, along the others",
       _COTTON + "; strip tests (ISO 13934-1) of cotton shirting break the weft at about 0.8 of the warp's force",
       _B(0.0, None, lo_open=True), _B(1.0e3, 1.0e9), native="tear_stress_weft", block="material.orthotropic",
       ui=dict(precision=0, step=1e5)),
    _b("material", "plastic", False, "Plastic Stretch",
       "Cloth pulled past its yield stress keeps part of the stretch (the rest shape follows the plastic "
       "strain); off: elastic up to the tear. Turning it off returns the cloth to its original rest shape",
       "elastic by default, as the add-on always was", native="plastic", block="material.plastic"),
    _f("material", "yield_stress", "Pa", 4.0e6, "Yield Stress",
       "Stress along the warp (any direction unless woven) past which the cloth stretches permanently, in pascals",
       _COTTON + "; half the tear stress: with hardening 2 the set left at the tear is a quarter of the elastic "
       "strain there (4 % for cotton, 5 % for denim), as the 2-6 % residual strain of worn denim knees (bagging)",
       _B(0.0, None, lo_open=True), _B(1.0e3, 1.0e9), native="yield_stress", block="material.plastic",
       ui=dict(precision=0, step=1e5)),
    _f("material", "yield_stress_weft", "Pa", 3.25e6, "Yield Stress (Weft)",
       "Yield stress along the weft, in pascals (used when woven; Hill's 1948 criterion between the two)",
       _COTTON + "; half the weft's tear stress, as along the warp", _B(0.0, None, lo_open=True),
       _B(1.0e3, 1.0e9), native="yield_stress_weft", block="material.plastic", ui=dict(precision=0, step=1e5, when="orthotropic")),
    _f("material", "hardening", "1", 2.0, "Hardening",
       "Linear hardening as a fraction of Young's modulus (H / E): the yield stress rises by H per unit of "
       "plastic strain (the slope past yield is E H / (E + H)); 0 is perfectly plastic",
       _COTTON + "; 2 keeps the tear within reach: the membrane's E is a strip test's secant to the break, "
       "so a flatter slope past yield (the 5-20 % of measured curves' knees) would put the tear at "
       "strains of order 1; with 2 the strain at the tear grows by a quarter",
       _B(0.0, 100.0), _B(0.0, 10.0), native="hardening", block="material.plastic", ui=dict(precision=3)),

    # -- solver: the time step and the implicit solve ----------------------------------------
    _i("solver", "steps_per_frame", "1", 10, "Steps per Frame",
       "Simulation steps per frame; the time step is 1 / (fps x steps)",
       _UI + " (a 4 ms step at 25 fps); the bound is the property's clamp", _B(1, 1000), _B(1, 100),
       block="solver.steps"),
    _f("solver", "gravity", "m/s^2", (0.0, 0.0, -9.81), "Gravity",
       "Acceleration of gravity; in Blender the scene's gravity (Scene > Gravity)",
       "standard gravity, rounded; the core refuses components beyond 1e4 m/s^2",
       _B(-1.0e4, 1.0e4), _B(-100.0, 100.0), rna=None, native="gravity"),
    _f("solver", "cg_tolerance", "1", 1.0e-4, "CG Tolerance",
       "Residual force at which the conjugate-gradient solve of each step stops, as a fraction of the "
       "forces the cloth carries (weight, tension, the net force of the step)",
       _CORE + " (tc_solver_default): the loosest value at which ten times tighter changes no tear "
       "(tests/test_solver.py; 1e-3 let a late tear start or not)",
       _B(0.0, 1.0, lo_open=True, hi_open=True), _B(1.0e-14, 0.1),
       native="cg_tolerance", block="solver.cg", ui=dict(precision=6)),
    _i("solver", "cg_max_iterations", "1", 1000, "CG Iterations", "Most conjugate-gradient iterations per step",
       _CORE + " (tc_solver_default): a safety net, not a speed knob: the T-shirt on the walking body at "
       "10 sub-steps per 24 fps frame converges in about 270 iterations at the default tolerance, and a cap "
       "of 200 split its sub-steps (the failed solve wasted): 0.27 s/frame at 200, 0.135 at 1000",
       _B(1, 100000), _B(10, 10000), native="cg_max_iterations",
       block="solver.cg"),
    _f("solver", "max_stretch", "1", 20.0, "Max Stretch",
       "A principal stretch above this counts as an explosion: the step is rolled back and retried in sub-steps",
       _CORE + " (tc_solver_default)", _B(1.0, None, lo_open=True), _B(1.5, 100.0), rna=None,
       native="max_stretch"),
    _f("solver", "contact_max_push", "m/s", 0.1, "Contact Push",
       "Fastest speed at which a penetration is resolved, so bodies that start inside the cloth separate "
       "without a blast", _CORE + " (tc_solver_default)", _B(0.0, None, lo_open=True), _B(1.0e-3, 10.0),
       rna=None, native="contact_max_push"),
    _f("solver", "contact_correction", "1", 0.2, "Contact Correction",
       "Fraction of a contact's depth removed from the position per step",
       _CORE + " (tc_solver_default)", _B(0.0, 1.0), _B(0.01, 1.0), rna=None, native="contact_correction"),
    _e("solver", "preconditioner", "auto", "Preconditioner",
       "How the conjugate-gradient solve is preconditioned: the same answer within the tolerance, at "
       "different cost",
       _CORE + " (tc_solver_default): auto takes multigrid each sub-step when the stiffness ratio "
       "(dt^2 k / m per vertex, median) times (vertices / TC_AMG_AUTO_VERTICES)^TC_AMG_AUTO_SIZE_EXPONENT "
       "reaches TC_AMG_AUTO_STIFFNESS on a cloth of at least TC_AMG_AUTO_MIN_VERTICES vertices, and keeps "
       "it down to 1/TC_AMG_AUTO_HYSTERESIS of that (native/constants.h: fitted to a measured table of "
       "both solvers' time); below that bar, the symmetric Gauss-Seidel sweeps, or block Jacobi with "
       "stiff groups (native/stiff.c) where the mesh has slivers: the sweeps cannot take out a "
       "sliver's stiff mode",
       [("auto", "Auto", "Gauss-Seidel sweeps on soft or coarse sheets and short steps, multigrid on "
                         "stiff or fine ones and long steps (by the work each is predicted to need); "
                         "block Jacobi with a sliver's corners inverted together on meshes with slivers"),
        ("jacobi", "Block Jacobi", "The inverse 3x3 diagonal blocks (a sliver's corners inverted "
                                   "together): cheap iterations, more of them as the mesh grows"),
        ("amg", "Multigrid", "Smoothed-aggregation multigrid with the rigid-body modes: about ten "
                             "iterations whatever the mesh, each costing several products, plus a "
                             "set-up per sub-step"),
        ("sgs", "Symmetric Gauss-Seidel", "Forward and backward block sweeps of the filtered system "
                                          "(Eisenstat's form): 0.3-0.4x the iterations of block Jacobi at about "
                                          "twice the cost each (0.84-1.0x its time); what auto picks below "
                                          "multigrid's bar")],
       native="preconditioner", block="solver.cg"),

    # -- tearing --------------------------------------------------------------------------------
    _b("tearing", "enabled", True, "Tearing", "Let the sheet tear where its stress exceeds the tear stress",
       "on in the add-on and in Cloth.set_tearing(); a core object made without set_tearing() does not "
       "tear (native default off), so a scripted Cloth starts as a plain elastic sheet",
       rna="use_tearing", native="enabled", native_default=False),
    _i("tearing", "scan_period", "1", 16, "Scan Period",
       "Steps for one sweep of the whole mesh for new tears while a tear runs",
       _CORE + " (tc_tear_default); a second tear starts within 16 steps", _B(1, 100000), _B(1, 1000),
       native="scan_period", block="tearing.scan"),
    _f("tearing", "min_angle_deg", "deg", 10.0, "Min Angle",
       "No triangle made by a tear gets a smaller angle (degrees)",
       _CORE + " (tc_tear_default); the core refuses 30 degrees and more", _B(0.0, 30.0, hi_open=True),
       _B(1.0, 25.0), native="min_angle_deg", block="tearing.scan", ui=dict(precision=1)),
    _s("tearing", "seam_group", "", "Seam Group",
       "Vertices that tear more easily: the tear stress there is scaled towards the factor by the vertex weight",
       _UI),
    _f("tearing", "seam_factor", "1", 0.5, "Strength",
       "Factor on the tear stress where the seam weight is 1: below 1 a weak seam (pre-scored line), "
       "above 1 an unbreakable hem",
       _UI + "; the core takes any positive factor (tc_cloth_set_tear_strength)", _B(0.0, None, lo_open=True),
       _B(0.01, 10.0), ui=dict(precision=2)),
    _f("tearing", "min_fragment_area", "m^2", 1.0e-4, "Min Fragment",
       "A piece a tear sets free with less rest area than this is removed with its vertices (0: keep "
       "every piece)",
       _UI + ": 1 cm^2, a speck a third the size of the disc of cotton's 1 cm tear radius over which the "
       "tearing model averages stress, so it cannot resolve such a piece; at the example meshes' median "
       "triangle (1.8-1.9 cm^2) it takes split slivers and the smallest elements, not a median one. The core's default is 0 "
       "(tc_tear_default, fragment.c): a scripted Cloth keeps every piece, so a tear conserves its area "
       "and mass exactly unless asked",
       _B(0.0, 1.0), _B(0.0, 0.01), native="min_fragment_area", native_default=0.0, block="tearing.scan",
       ui=dict(precision=5)),

    # -- pins --------------------------------------------------------------------------------------
    _s("pins", "pin_group", "", "Pin Group",
       "Vertices held to the object, as Blender's cloth reads its pin group: weight 1 holds a vertex "
       "exactly, a lower weight pulls it with a spring of that share of Pin Stiffness; pinned vertices "
       "follow the object's transform and what deforms them above Tear Cloth (Armature, shape keys); "
       "empty: none", _UI),
    _f("pins", "pin_stiffness", "1/s^2", 1000.0, "Pin Stiffness",
       "Pull of a pin group's weights below 1, per kilogram of cloth and metre away from the pinned "
       "place: a vertex of weight w sags g / (w x this) under gravity (1000: 2 cm at weight 0.5) and "
       "swings about its place at sqrt(w x this) rad/s, at any mesh resolution",
       "per unit mass so that a painted weight means the same pull on a fine mesh as on a coarse one; "
       "1000 1/s^2 holds weight-1-ish vertices within ~1 cm and lets weight 0.1 drape (10 cm of sag), "
       "the falloff a painted gradient is meant to give", _B(0.0, 1.0e8), _B(1.0, 1.0e5),
       ui=dict(precision=0, step=1e4)),

    # -- collision (session.CollisionSettings) ------------------------------------------------
    _b("collision", "enabled", True, "Collision", "Collide with the colliders listed here and, if on, with itself",
       _UI, rna="use_collision"),
    _f("collision", "thickness", "m", 0.002, "Distance", "Contact distance kept between the cloth and surfaces",
       "2 mm: a few cloth thicknesses, fine for garments at human scale", _B(0.0, None, lo_open=True),
       _B(1.0e-4, 0.1), rna="collision_thickness", block="collision.contact", ui=dict(precision=4)),
    _f("collision", "friction", "1", 0.3, "Friction", "Coulomb friction coefficient",
       "cloth on skin or fabric: 0.2-0.5", _B(0.0, 100.0, hi_open=True), _B(0.0, 2.0),
       block="collision.contact", ui=dict(precision=2)),
    _b("collision", "self_collision", True, "Self Collision", "Keep the cloth from passing through itself",
       "the paper's scenes collide the cloth with itself", rna="use_self_collision", block="collision.contact"),
    _b("collision", "impact_guard", True, "Impact Guard",
       "After each step, stop any motion of the step that would carry the cloth through itself (inelastic "
       "impulses, then rigid impact zones); acts with Self Collision on",
       "Bridson, Fedkiw & Anderson 2002; Harmon et al. 2008: the contacts given to the solve are a prediction, "
       "and a cloth flapping over a thin bar crossed itself on some trajectories without this check "
       "(tests/test_collision_session.py)", block="collision.contact"),
    _i("collision", "cluster_size", "1", 100, "Cluster Size",
       "Vertices per cluster: collision detection skips cluster pairs that moved little",
       "the paper's clusters of about 100 vertices; the bounds are the property's clamps", _B(4, 100000), _B(10, 5000),
       block="collision.clusters"),
    _f("collision", "displacement_threshold", "m", 0.0015, "Displacement Threshold",
       "Relative motion of two clusters that triggers a full detection between them",
       "the paper's displacementThreshold, kept below the contact thickness: a pair whose clusters drift "
       "apart by more than the thickness between full detections can carry vertices into a body unseen "
       "(measured: 3-10 mm deep with 5 mm on the walking shirt)", _B(0.0, None, lo_open=True), _B(1.0e-5, 0.1),
       block="collision.clusters", ui=dict(precision=4)),
    _e("collision", "measure", "relative", "Measure", "When a cluster pair is checked again",
       "the paper's relative displacement measure",
       [("relative", "Relative", "Displacement of each cluster pair relative to each other (the paper)"),
        ("absolute", "Absolute", "Displacement of each cluster on its own"),
        ("full", "Full", "Detect every close pair every step (slow; a reference)")],
       block="collision.clusters"),

    # -- cache ---------------------------------------------------------------------------------
    _s("cache", "cache_folder", "//tearcloth_cache/", "Folder",
       "Where the bake goes ('//' = next to the .blend file); one USD file per object", _UI, kind="dir",
       ui=dict(blend_relative=True)),
    _i("cache", "frame_start", "frame", 1, "Start", "First frame of the bake (the rest state)",
       "Blender's first frame; bounds are Blender's frame range", _B(-1048574, 1048574)),
    _i("cache", "frame_end", "frame", 250, "End", "Last frame of the bake",
       "Blender's default last frame; bounds are Blender's frame range", _B(-1048574, 1048574)),

    # -- export (Scene.tearcloth) ---------------------------------------------------------------
    _s("export", "alembic_path", "//tearcloth.abc", "Alembic File",
       "Where Export Alembic writes the baked Tear Cloth objects", _UI, kind="file"),

    # -- haptics: the live session (Object.tearcloth.haptics) --------------------------------------
    _s("haptics", "firmware_path", "", "Falcon Firmware",
       "nvent_firmware.bin from your Novint driver or SDK: a Falcon needs it after every power-up and "
       "Tear Cloth cannot ship it. Empty: the Falcons must have firmware loaded already", "Novint", kind="file"),
    _b("haptics", "record", False, "Record to Cache",
       "Write the session into this object's cache (as a bake does), from the Start frame on at the "
       "scene's frame rate, so it can be played back and rendered through the Tear Cloth modifier", _UI),
    _e("haptics", "stop_button", "center", "Stop Button",
       "A grip button that ends the session (it must be seen released once first)",
       "the Falcon's centre button is the one a hand reaches without letting go",
       [("none", "None", "Only Esc (or Stop) ends the session"),
        ("center", "Centre", "The Falcon's centre grip button"),
        ("plus", "Plus / Button 1", "The Falcon's plus button, a SpaceMouse's left button"),
        ("forward", "Forward / Button 2", "The Falcon's forward button, a SpaceMouse's right button"),
        ("minus", "Minus", "The Falcon's minus button")]),
    _f("haptics", "time_step", "s", 1.0e-3, "Time Step",
       "Simulated seconds per step of the live session (the simulation runs as fast as it can)",
       "the 1 kHz haptic rate; bounds are the property's clamps", _B(1.0e-5, 0.05),
       ui=dict(precision=5, step=0.01)),
    _f("haptics", "keyboard_step", "m", 0.002, "Key Step",
       "Keyboard device: metres of device motion per arrow-key press (Shift: five times more)",
       _UI + ": 2 mm, 1/20 of the Falcon's workspace radius", _B(1.0e-5, None), _B(1.0e-5, 0.02), scene=False,
       ui=dict(precision=4)),
    _f("haptics", "demo_pull", "m", 0.02, "Demo Pull",
       "Emulated Falcon: how far (device metres) its scripted hand pulls the grip",
       "half the Falcon's 4 cm workspace radius; at most the radius", _B(0.0, 0.04), scene=False,
       block="haptics.demo", ui=dict(precision=3)),
    _f("haptics", "demo_hold", "s", 0.3, "Demo Hold", "Emulated Falcon: seconds its hand holds still before pulling",
       _UI, _B(0.0, None), _B(0.0, 10.0), block="haptics.demo", ui=dict(precision=2)),
    _f("haptics", "demo_pull_time", "s", 2.0, "Demo Pull Time", "Emulated Falcon: seconds the pull takes",
       _UI, _B(0.01, None), _B(0.01, 60.0), block="haptics.demo", ui=dict(precision=2)),
    _e("haptics", "demo_pace", "simulation", "Demo Pace", "Which clock the emulated Falcons' scripted hands follow",
       "simulated time: the same pull on any machine",
       [("simulation", "Simulated Time", "The scripted hands follow the simulated time (the same pull on any "
         "machine)"),
        ("wall", "Real Time", "The scripted hands move in real time, like a user")], block="haptics.demo"),
    _s("haptics", "force_log_folder", "//", "Force Log Folder",
       "Where Save Force Log writes the CSV and the plot ('//' = next to the .blend file)", _UI, kind="dir"),
    _e("haptics", "servo", "process", "Servo",
       "Where the 1 kHz servo loop runs for every hand (Falcon, SpaceMouse, keyboard, emulated)",
       "own process: Blender's Python cannot delay a tick, and the force goes to zero by itself if Blender "
       "hangs or dies (issue 16)",
       [("process", "Own Process", "A servo process of its own opens and drives the devices; falls back to "
         "threads, with a warning, when it cannot start"),
        ("threads", "Threads", "Threads inside Blender's process (Blender's own Python can delay their ticks)")]),

    # -- hand: one hand of the live session (haptics.left / haptics.right) ----------------------
    _b("hand", "use", True, "Use", "Grasp the cloth with this hand", _UI),
    _e("hand", "device", "emulated", "Device", "What drives this hand", "a demo that needs no hardware",
       [("falcon", "Novint Falcon", "A Novint Falcon (by USB serial number; empty: any free one), with force "
         "feedback"),
        ("spacemouse", "SpaceMouse", "A 3Dconnexion SpaceMouse read through hidapi (input only, no force)"),
        ("keyboard", "Keyboard / Mouse", "A virtual device moved with the arrow keys, Page Up/Down and Ctrl + mouse "
         "while the session runs (computes the force a Falcon would render)"),
        ("emulated", "Emulated Falcon (Demo)", "A Falcon emulator whose scripted hand pulls the grip away from the "
         "other hand: a demo without hardware")]),
    _s("hand", "falcon_serial", "", "Serial",
       "USB serial number of the Falcon for this hand (Discover lists them); "
       "empty: any Falcon the other hand does not use", _UI),
    _s("hand", "spacemouse_path", "", "HID Path",
       "hidapi path of the SpaceMouse for this hand (Discover lists them); empty: the first one found", _UI),
    _s("hand", "vertex_group", "", "Handle Group", "Vertices this hand grasps (weight 0.5 or more)", _UI),
    _e("hand", "mapping", "fit", "Workspace", "How device motion maps to the scene",
       "fit: the grasp starts where the hand is, whatever the scene's size",
       [("fit", "Fit to Region", "The device's workspace ball maps onto a ball of the given radius around the "
         "grasped vertices; the grasp starts where the hand is"),
        ("manual", "Scale and Offset", "Scene position = offset + scale x device position; the handle glides to "
         "the proxy when the session starts")]),
    _f("hand", "region_radius", "m", 0.08, "Region Radius",
       "Radius of the scene region the device's workspace covers",
       "twice the Falcon's 4 cm workspace radius: a sheet of a few decimetres", _B(1.0e-4, None), _B(1.0e-4, 2.0)),
    _f("hand", "scale", "1", 2.0, "Scale", "Scene metres per metre of device motion",
       "the same factor 2 as the region radius", _B(1.0e-3, None), _B(1.0e-3, 100.0)),
    _f("hand", "offset", "m", (0.0, 0.0, 0.0), "Offset", "Where the device's origin lies in the scene (world space)",
       "the world origin", None),
    _f("hand", "k_position", "N/m", 2000.0, "Stiffness",
       "k_position of the proxy spring between the hand and the handle, in N/m (scene side)",
       "felt stiffness 2000 x 0.1 x 2 = 400 N/m, well under the Falcon's 3000 N/m", _B(0.0, None),
       _B(0.0, 20000.0), block="hand.gains", ui=dict(precision=0)),
    _f("hand", "k_velocity", "N s/m", 20.0, "Damping", "k_velocity: damping of the hand's velocity, in N s/m "
       "(scene side)", "1 % of k_position: damps the proxy at the servo rate", _B(0.0, None), _B(0.0, 200.0),
       block="hand.gains", ui=dict(precision=2)),
    _f("hand", "force_scale", "1", 0.1, "Force Scale",
       "Device force per newton of scene force (a tear of a few tens of N fits a Falcon's 8 N at 0.1)",
       "a tear of a few tens of newtons within the Falcon's 8 N", _B(1.0e-4, None), _B(1.0e-4, 10.0),
       block="hand.force", ui=dict(precision=3)),
    _f("hand", "max_force", "N", 8.0, "Max Force",
       "Largest force sent to the device, in N (a Falcon renders at most 8 N)",
       "the Novint Falcon's rated peak force (falcon.FALCON_MAX_FORCE)", _B(0.0, None), _B(0.0, 8.0),
       block="hand.force", ui=dict(precision=2)),

    # -- fray: the inputs of the frayed-edge Geometry Nodes group (blender/fray.py) ---------------
    # Not Blender properties: they are the group's input sockets (default, bounds, description), so
    # the values live on the modifier and render without the add-on.
    _f("fray", "length", "m", 0.006, "Length", "Length of a loose thread end at a torn edge",
       "our estimate: the loose yarn ends of a torn woven cotton or denim are a few millimetres long (two to four "
       "picks at 16-28 yarns per cm)", _B(0.0, 1.0), _B(0.0005, 0.05), rna=None, ui=dict(precision=4)),
    _f("fray", "density", "1/m", 1000.0, "Density", "Loose thread ends per metre of torn edge",
       "our estimate: about half the ~20 picks per cm of a denim weft (50 per inch) left hanging, the other half "
       "pulled out with the other lip", _B(0.0, 1.0e5), _B(10.0, 1.0e4), rna=None, ui=dict(precision=0)),
    _f("fray", "jitter", "1", 0.5, "Jitter",
       "How much each thread's direction and length vary (0: every thread straight along its yarn, at the "
       "full length)", _UI, _B(0.0, 1.0), rna=None, ui=dict(precision=2)),
    _f("fray", "thread_radius", "m", 1.5e-4, "Thread Radius", "Radius of a loose thread",
       "a typical cotton yarn of 0.2-0.4 mm diameter (Ne 10-30)", _B(0.0, 0.01, lo_open=True), _B(1.0e-5, 0.002),
       rna=None, ui=dict(precision=5)),
    _i("fray", "seed", "1", 0, "Seed", "Another seed gives another pattern of threads", _UI, _B(0, 2**31 - 1),
       rna=None),
)
_BY_KEY = {s.key: s for s in SETTINGS}
GROUPS = tuple(dict.fromkeys(s.group for s in SETTINGS))


def setting(group: str, name: str) -> Setting:
    try:
        return _BY_KEY[f"{group}.{name}"]
    except KeyError:
        raise KeyError(f"no setting {group}.{name}; {group} has: "
                       f"{', '.join(s.name for s in rows(group)) or 'nothing'}") from None


def rows(group: str) -> list[Setting]:
    """The rows of a group, in table (panel) order."""
    return [s for s in SETTINGS if s.group == group]


def block(name: str) -> list[Setting]:
    """The rows a panel draws together, in table order."""
    found = [s for s in SETTINGS if s.block == name]
    if not found:
        raise KeyError(f"no settings block {name!r}")
    return found


def default(group: str, name: str):
    return setting(group, name).default


def defaults(group: str) -> dict:
    return {s.name: s.default for s in rows(group)}


def native_defaults(group: str) -> dict:
    """What the core's default struct of a group must hold, keyed by the C field names."""
    return {s.native: (s.default if s.native_default is None else s.native_default)
            for s in rows(group) if s.native is not None}


def validate(group: str, values: Mapping[str, Any] | Iterable, who: str = "") -> None:
    """Check each (name, value) of a group against its row: ValueError naming the parameter, its
    value, unit and bound when a hard bound is broken; a warning when a soft one is."""
    items = values.items() if isinstance(values, Mapping) else values
    for name, value in items:
        setting(group, name).check(value, who)
