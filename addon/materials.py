"""Materials of thin sheets, in SI units, with where their values come from.

This file owns the ``Material`` record and the seven presets (cotton, denim, silk, paper,
banknote, poplin, jersey). What each field means, its unit and its bounds are rows of ``settings.py``; the
table's defaults are the cotton preset, so ``Material()`` is cotton.

A sheet is described by its in-plane elasticity (Young's modulus E, Poisson ratio nu, thickness h),
its areal mass (density rho times h), its bending stiffness, damping, and the stress at which it
tears (sigma_E of the paper). Textiles are not continua: their "E" is the effective modulus of a
strip test divided by the nominal thickness, which is what a membrane FEM needs.

Sources of the presets (values rounded; fabrics vary by weave and direction, these are mid-range):
- Areal masses: typical catalogue weights (quilting cotton ~150 g/m2, 12 oz denim ~400 g/m2,
  habotai silk ~40 g/m2, office paper 80 g/m2, US banknote paper ~90 g/m2).
- Fabric tensile moduli and breaking loads: strip tests (ASTM D5035 / ISO 13934-1) report breaking
  forces of ~300 N (cotton), ~900 N (denim), ~150 N (silk) per 50 mm at 10-30 % strain, i.e. an
  effective E h of a few 10 kN/m.
- Fabric bending rigidity: Kawabata KES-FB2 values of 0.02-0.5 gf cm2/cm
  (1 gf cm2/cm = 9.8e-5 N m) for shirting to denim.
- Paper: E ~ 2-6 GPa (machine/cross direction), tensile strength ~ 30-60 MPa for 80 g/m2 office
  paper (tensile index ~40-70 N m/g); bending stiffness follows the plate formula E h^3/12(1-nu^2).
  Tearing from a notch starts well below the tensile strength, hence the lower tear stress.
- Banknote paper (cotton/linen rag): higher strength than wood-pulp paper (tensile index ~100 N m/g).
- Tear radius (the material length l of the tear criterion, tear.c): the theory of critical
  distances (D. Taylor, The Theory of Critical Distances, Elsevier 2007) averages the stress over
  l ~ K_c^2 / (pi sigma^2) = E G_c / (pi sigma^2). Fabrics: G_c from trouser tear forces
  (ISO 13937-2; ~10 N cotton shirting, ~40 N denim, ~3 N silk habotai) as G_c = 2 F / h gives
  5e4-1e5 J/m^2, so l = 6-12 mm with the presets' E and tear stress: 10 mm for cotton and denim,
  5 mm for silk. Paper: the fracture process zone of machine-made paper spans a few millimetres
  (K. Niskanen (ed.), Paper Physics, 2nd ed. 2008, ch. on fracture), so 5 mm for both papers (the
  formula, with the low notched tear stress of the presets, would give centimetres).
- Crack speed (fastest tear, as a fraction of the Rayleigh wave speed c_R): brittle cracks stop
  accelerating at 0.4-0.6 c_R, where they start to branch (J. Fineberg, M. Marder, Instability in
  dynamic fracture, Physics Reports 313, 1999): 0.5 for paper and banknote. Fabrics dissipate most
  of the released energy in yarn pull-out and friction (tear energies 1e4-1e5 J/m^2); 0.2 is our
  estimate, not a measurement (a cotton tear then tops out at ~40 m/s).
- Warp and weft (the orthotropic presets; strip tests by direction, ISO 13934-1 / ASTM D5035,
  50 mm strips, breaking force and the initial slope; values are typical catalogue and literature
  ranges rounded, not one fabric's measurement):
  * denim, 12-14 oz 3/1 cotton twill: breaking force ~900-1200 N warp, ~500-700 N weft per 50 mm,
    the weft more extensible (higher crimp): weft strength 0.6 and modulus 0.55 of the warp's.
  * poplin, ~120 g/m2 plain-weave cotton with about twice as many warp ends as weft picks: the weft
    breaks at about half the warp's force (~600 N warp, ~300 N weft per 50 mm) and is softer.
  * jersey, single-knit cotton ~180 g/m2: wales (taken as the warp) about 2.5 times stiffer than
    courses at low strain, both very extensible (50-150 % at break); low yield (knits keep a
    large set, "bagging"), hence high stretch and early plastic flow.
  * silk habotai: nearly balanced plain weave, weft 0.8 of the warp in strength and stiffness.
  * Bias shear: Kawabata KES-FB1 shear rigidity G h of 30-300 N/m for shirting to denim (S.
    Kawabata, The Standardization and Analysis of Hand Evaluation, 2nd ed. 1980), G = G h / h.
  * Yield (plastic presets): at half the tear stress in each direction, hardening H = 2 E, so the
    set left at the tear is a quarter of the elastic strain there (4-5 % for cotton and denim, 15 %
    for jersey), as the 2-6 % residual strain of worn denim knees ("bagging") and the larger set of
    knits. The membrane's E is the strip test's secant to the break, so the flat post-yield slopes
    of the measured curves' knees (5-20 % of the initial one) would put the tear at strains of
    order 1; H = 2 E is chosen to keep it within reach. Estimates, not one fabric's measurement.
- Paper's machine direction (MD = warp) and cross direction (CD = weft), ISO 1924-2 tensile tests:
  office paper has MD/CD tensile strength and stiffness ratios of about 2 (tensile index ~60 vs
  ~30 N m/g; E ~4 vs ~2 GPa); banknote rag paper is squarer (~1.4). In-plane shear modulus by
  Baum's approximation G = 0.387 sqrt(E_MD E_CD) (G. A. Baum, D. C. Brennan, C. C. Habeger,
  Orthotropic elastic constants of paper, Tappi 64(8), 97, 1981). Paper's yield (the knee of the
  MD and CD curves near 60 % of the strength) is set, but plasticity is off in its presets.
- Damping: the mass-proportional term stands in for air drag, which dominates how a light sheet
  moves: with linear drag a sheet falls at a terminal speed of g / damping_mass, and flat cloth or
  paper falls at 1-4 m/s, hence 3 /s. The stiffness-proportional term is the fibres' internal
  friction; it damps the fast in-plane vibrations of a stiff membrane.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace

from . import settings as _settings

_D = _settings.defaults("material")  # the table's defaults are the 'cotton' preset below


@dataclass(frozen=True)
class Material:
    """A sheet material. Every field in SI units; units, bounds and meaning in settings.py."""

    name: str = _D["name"]
    young: float = _D["young"]                          # Pa
    poisson: float = _D["poisson"]                      # 1
    thickness: float = _D["thickness"]                  # m
    density: float = _D["density"]                      # kg/m^3 (areal mass / thickness)
    bending: float = _D["bending"]                      # N m
    damping_mass: float = _D["damping_mass"]            # 1/s (Rayleigh alpha): air drag, see above
    damping_stiffness: float = _D["damping_stiffness"]  # s (Rayleigh beta)
    tear_stress: float = _D["tear_stress"]              # Pa (sigma_E)
    snap_tolerance: float = _D["snap_tolerance"]        # fraction of an edge
    tear_radius: float = _D["tear_radius"]              # m (material length of the tear criterion)
    crack_speed_ratio: float = _D["crack_speed_ratio"]  # 1 (fastest tear / Rayleigh wave speed)
    # woven sheets (native/ortho.c): with orthotropic on, young / poisson / tear_stress are the warp's
    orthotropic: bool = _D["orthotropic"]                # warp/weft axes from the UV map
    young_weft: float = _D["young_weft"]                # Pa
    shear_modulus: float = _D["shear_modulus"]          # Pa (the bias: G of the warp-weft axes)
    grain_angle: float = _D["grain_angle"]              # rad, warp from the UV map's u direction
    tear_stress_weft: float = _D["tear_stress_weft"]    # Pa
    plastic: bool = _D["plastic"]                        # permanent stretch past yield
    yield_stress: float = _D["yield_stress"]            # Pa (warp)
    yield_stress_weft: float = _D["yield_stress_weft"]  # Pa
    hardening: float = _D["hardening"]                  # 1 (H / young)

    def validate(self) -> "Material":
        """Raise ValueError naming the first value outside its hard bounds (with its unit and the
        bound), warn about values outside the soft bounds; return self when all are possible."""
        _settings.validate("material", ((f.name, getattr(self, f.name)) for f in fields(self) if f.name != "name"),
                           who=f"material {self.name!r}")
        return self

    def native_kwargs(self) -> dict:
        d = asdict(self)
        d.pop("name")
        return d

    def with_(self, **changes) -> "Material":
        return replace(self, **changes).validate()

    @property
    def grained(self) -> bool:
        """Whether the material's response turns with its warp (the UV map's u direction, turned by
        the grain angle): orthotropic, or plastic with different warp and weft yield stresses. Hill's
        criterion with equal yields is von Mises, the same in every direction."""
        return bool(self.orthotropic or (self.plastic and self.yield_stress != self.yield_stress_weft))

    @property
    def areal_mass(self) -> float:
        """kg/m^2"""
        return self.density * self.thickness

    @property
    def plate_bending(self) -> float:
        """Bending stiffness of a homogeneous plate, E h^3 / 12 (1 - nu^2), in N m."""
        return self.young * self.thickness**3 / (12.0 * (1.0 - self.poisson**2))


# Each preset names only what differs from cotton (the table's defaults, ``Material()``): the
# other fields (Poisson ratio 0.3, air-drag damping 3 /s, snapping 0.3 of an edge, ...) are cotton's.
# Woven and knitted presets are orthotropic (warp = the UV map's u) and plastic, the papers
# orthotropic only (machine direction = warp; paper's permanent set before a tear is small).
_PAPER_LIKE = dict(damping_stiffness=1.0e-5, bending=3.6e-4, tear_radius=0.005, crack_speed_ratio=0.5)
_WOVEN = dict(orthotropic=True, plastic=True)
MATERIALS: dict[str, Material] = {
    "cotton": Material(),
    "denim": Material(name="denim", young=8.0e7, thickness=8.0e-4, density=500.0, bending=4.0e-5, tear_stress=1.5e7,
                      young_weft=4.5e7, shear_modulus=3.0e5, tear_stress_weft=9.0e6, yield_stress=7.5e6,
                      yield_stress_weft=4.5e6, hardening=2.0, **_WOVEN),
    "silk": Material(name="silk", young=3.0e7, thickness=1.0e-4, density=400.0, bending=2.0e-6, tear_stress=1.0e7,
                     tear_radius=0.005, young_weft=2.4e7, shear_modulus=2.0e5, tear_stress_weft=8.0e6,
                     yield_stress=5.0e6, yield_stress_weft=4.0e6, hardening=2.0, **_WOVEN),
    "paper": Material(name="paper", young=4.0e9, thickness=1.0e-4, density=800.0, tear_stress=2.0e7, **_PAPER_LIKE,
                      orthotropic=True, young_weft=2.0e9, shear_modulus=1.1e9, tear_stress_weft=1.1e7,
                      yield_stress=1.2e7, yield_stress_weft=6.6e6, hardening=2.0),
    "banknote": Material(name="banknote", young=3.0e9, thickness=1.1e-4, density=820.0, tear_stress=3.0e7,
                         **_PAPER_LIKE, orthotropic=True, young_weft=2.2e9, shear_modulus=1.0e9,
                         tear_stress_weft=2.2e7, yield_stress=1.8e7, yield_stress_weft=1.3e7, hardening=2.0),
    "poplin": Material(name="poplin", young=6.0e7, thickness=2.5e-4, density=480.0, bending=2.0e-6,
                       tear_stress=1.2e7, young_weft=3.5e7, shear_modulus=4.0e5, tear_stress_weft=6.0e6,
                       yield_stress=6.0e6, yield_stress_weft=3.0e6, hardening=2.0, **_WOVEN),
    "jersey": Material(name="jersey", young=5.0e6, thickness=6.0e-4, density=300.0, bending=2.0e-6,
                       tear_stress=3.0e6, young_weft=2.0e6, shear_modulus=3.0e5, tear_stress_weft=2.5e6,
                       yield_stress=1.5e6, yield_stress_weft=1.25e6, hardening=2.0, **_WOVEN),
}


def material(name: str, **changes) -> Material:
    """A preset by name, optionally with changed fields: material("paper", tear_stress=1e7)."""
    try:
        base = MATERIALS[name]
    except KeyError:
        raise ValueError(f"unknown material preset {name!r}; presets: {', '.join(MATERIALS)}") from None
    return base.with_(**changes) if changes else base
