"""Materials of thin sheets, in SI units, with where their values come from.

This file owns the ``Material`` record and the five presets (cotton, denim, silk, paper,
banknote). What each field means, its unit and its bounds are rows of ``settings.py``; the
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
    def areal_mass(self) -> float:
        """kg/m^2"""
        return self.density * self.thickness

    @property
    def plate_bending(self) -> float:
        """Bending stiffness of a homogeneous plate, E h^3 / 12 (1 - nu^2), in N m."""
        return self.young * self.thickness**3 / (12.0 * (1.0 - self.poisson**2))


# Each preset names only what differs from cotton (the table's defaults, ``Material()``): the
# other fields (Poisson ratio 0.3, air-drag damping 3 /s, snapping 0.3 of an edge, ...) are cotton's.
_PAPER_LIKE = dict(damping_stiffness=1.0e-5, bending=3.6e-4, tear_radius=0.005, crack_speed_ratio=0.5)
MATERIALS: dict[str, Material] = {
    "cotton": Material(),
    "denim": Material(name="denim", young=8.0e7, thickness=8.0e-4, density=500.0, bending=4.0e-5, tear_stress=1.5e7),
    "silk": Material(name="silk", young=3.0e7, thickness=1.0e-4, density=400.0, bending=2.0e-6, tear_stress=1.0e7,
                     tear_radius=0.005),
    "paper": Material(name="paper", young=4.0e9, thickness=1.0e-4, density=800.0, tear_stress=2.0e7, **_PAPER_LIKE),
    "banknote": Material(name="banknote", young=3.0e9, thickness=1.1e-4, density=820.0, tear_stress=3.0e7,
                         **_PAPER_LIKE),
}


def material(name: str, **changes) -> Material:
    """A preset by name, optionally with changed fields: material("paper", tear_stress=1e7)."""
    try:
        base = MATERIALS[name]
    except KeyError:
        raise ValueError(f"unknown material preset {name!r}; presets: {', '.join(MATERIALS)}") from None
    return base.with_(**changes) if changes else base
