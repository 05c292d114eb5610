"""Materials of thin sheets, in SI units, with where their values come from.

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
- Damping: the mass-proportional term stands in for air drag, which dominates how a light sheet
  moves: with linear drag a sheet falls at a terminal speed of g / damping_mass, and flat cloth or
  paper falls at 1-4 m/s, hence 3 /s. The stiffness-proportional term is the fibres' internal
  friction; it damps the fast in-plane vibrations of a stiff membrane.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, replace


@dataclass(frozen=True)
class Material:
    """A sheet material. Every field in SI units."""

    name: str = "cotton"
    young: float = 5.0e7            # Pa
    poisson: float = 0.3            # 1
    thickness: float = 4.0e-4       # m
    density: float = 375.0          # kg/m^3 (areal mass / thickness)
    bending: float = 5.0e-6         # N m
    damping_mass: float = 3.0       # 1/s (Rayleigh alpha): air drag, see the module docstring
    damping_stiffness: float = 2.0e-5  # s (Rayleigh beta)
    tear_stress: float = 8.0e6      # Pa (sigma_E)
    snap_tolerance: float = 0.3     # fraction of an edge

    def validate(self) -> "Material":
        """Raise ValueError naming the first absurd value; return self when all are sane."""
        checks = [
            (self.young > 0 and self.young < 1e13, "young", "must be > 0 Pa and below 1e13 Pa"),
            (-1.0 < self.poisson < 0.5, "poisson", "must lie in (-1, 0.5)"),
            (0 < self.thickness <= 1.0, "thickness", "must be > 0 m and at most 1 m (a thin sheet)"),
            (0 < self.density <= 1e5, "density", "must be > 0 kg/m^3 and at most 1e5"),
            (self.bending >= 0, "bending", "must be >= 0 N m"),
            (self.damping_mass >= 0, "damping_mass", "must be >= 0 1/s"),
            (self.damping_stiffness >= 0, "damping_stiffness", "must be >= 0 s"),
            (self.tear_stress > 0, "tear_stress", "must be > 0 Pa"),
            (0 <= self.snap_tolerance < 0.5, "snap_tolerance", "must lie in [0, 0.5)"),
        ]
        for ok, field, rule in checks:
            value = getattr(self, field)
            if not ok or value != value:  # value != value catches NaN
                raise ValueError(f"material {self.name!r}: {field} = {value!r} {rule}")
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


MATERIALS: dict[str, Material] = {
    "cotton": Material(),
    "denim": Material(
        name="denim", young=8.0e7, poisson=0.3, thickness=8.0e-4, density=500.0, bending=4.0e-5,
        damping_mass=3.0, damping_stiffness=2.0e-5, tear_stress=1.5e7, snap_tolerance=0.3,
    ),
    "silk": Material(
        name="silk", young=3.0e7, poisson=0.3, thickness=1.0e-4, density=400.0, bending=2.0e-6,
        damping_mass=3.0, damping_stiffness=2.0e-5, tear_stress=1.0e7, snap_tolerance=0.3,
    ),
    "paper": Material(
        name="paper", young=4.0e9, poisson=0.3, thickness=1.0e-4, density=800.0, bending=3.6e-4,
        damping_mass=3.0, damping_stiffness=1.0e-5, tear_stress=2.0e7, snap_tolerance=0.3,
    ),
    "banknote": Material(
        name="banknote", young=3.0e9, poisson=0.3, thickness=1.1e-4, density=820.0, bending=3.6e-4,
        damping_mass=3.0, damping_stiffness=1.0e-5, tear_stress=3.0e7, snap_tolerance=0.3,
    ),
}


def material(name: str, **changes) -> Material:
    """A preset by name, optionally with changed fields: material("paper", tear_stress=1e7)."""
    try:
        base = MATERIALS[name]
    except KeyError:
        raise ValueError(f"unknown material preset {name!r}; presets: {', '.join(MATERIALS)}") from None
    return base.with_(**changes) if changes else base
