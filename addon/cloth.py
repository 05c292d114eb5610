"""The scripting API of the native core: a tearable cloth stepped in time, without Blender.

    import numpy as np
    from tearcloth import Cloth, material
    cloth = Cloth(vertices, triangles, material("cotton"))
    cloth.pin(np.flatnonzero(vertices[:, 2] > 0.99))
    left = cloth.add_handle(left_indices)
    cloth.move_handle(left, offset=(-0.01, 0, 0))
    cloth.step(1e-3, substeps=1)
    cloth.positions, cloth.stress, cloth.handle_force(left)

Arrays come back as read-only numpy views of the native memory (no copy). A view keeps the memory
it was made from alive; after a step that tore, take a new one to see the added vertices.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Iterable, Mapping, Sequence

import numpy as np

from . import _native
from . import settings as _settings
from .materials import Material, material as _preset

ClothError = _native.ClothError
InvalidInputError = _native.InvalidInputError
SimulationError = _native.SimulationError

# A pin weight at or above this holds its vertex exactly (a hard pin); below, down to 0, it is a
# soft pin's spring. Blender's cloth snaps its goal at the same weight (SOFTGOALSNAP, 0.999), so a
# pin group painted for Blender's cloth pins the same vertices hard.
PIN_HARD_WEIGHT = 0.999


@dataclass(frozen=True)
class TopologyEvents:
    """What the last step changed, so clusters, meshes and caches update incrementally.

    new_vertices: indices of vertices added; parents (k, 2): where each came from (second parent
    -1 for a duplicate made when the cloth separated); weights: weight of the first parent;
    changed_triangles: existing triangles whose vertex indices changed; new_triangles: indices of
    added triangles; tips: vertices at the end of running tears; removed_vertices and
    removed_triangles: what went with tiny fragments (min_fragment_area), sorted and numbered as
    before the step. Every other index is in the numbering after the removal, whose survivors keep
    their order: a reader deletes the removed rows from what it holds (``np.delete``), then applies
    the rest.
    """

    new_vertices: np.ndarray
    parents: np.ndarray
    weights: np.ndarray
    changed_triangles: np.ndarray
    new_triangles: np.ndarray
    tips: np.ndarray
    removed_vertices: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    removed_triangles: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))

    def __bool__(self) -> bool:
        return bool(len(self.new_vertices) or len(self.changed_triangles) or len(self.new_triangles)
                    or self.removed)

    @property
    def removed(self) -> bool:
        return bool(len(self.removed_vertices) or len(self.removed_triangles))

    def __getitem__(self, key: str) -> np.ndarray:
        # consumers that take plain dicts of arrays (collision, caches) read events the same way
        return getattr(self, key)

    def get(self, key: str, default=None):
        return getattr(self, key, default)


def _f64(a, name: str, cols: int | None = None) -> np.ndarray:
    arr = np.ascontiguousarray(a, dtype=np.float64)
    if cols is not None and (arr.ndim != 2 or arr.shape[1] != cols):
        raise InvalidInputError(f"{name} must have shape (N, {cols}), got {arr.shape}")
    return arr


def _i32(a, name: str) -> np.ndarray:
    arr = np.asarray(a)
    if arr.size == 0 and arr.dtype.kind == "f":  # [] is float64 to numpy: no vertex, not a float index
        arr = arr.astype(np.int32)
    if arr.dtype.kind not in "iub":
        raise InvalidInputError(f"{name} must hold integers, got dtype {arr.dtype}")
    if arr.dtype == np.bool_:
        arr = np.flatnonzero(arr)
    if arr.size and (arr.max() > np.iinfo(np.int32).max or arr.min() < np.iinfo(np.int32).min):
        raise InvalidInputError(f"{name} has indices beyond int32")
    return np.ascontiguousarray(arr, dtype=np.int32)


def smallest_angles_deg(vertices, triangles) -> np.ndarray:
    """Each triangle's smallest corner angle (degrees): atan2 of the cross and dot products, exact
    for the thinnest slivers where an arccos of the cosine loses them. (m,) for (m, 3) triangles."""
    V = np.asarray(vertices, dtype=np.float64)
    T = np.asarray(triangles, dtype=np.int64)
    worst = np.full(len(T), 180.0)
    for k in range(3):
        u = V[T[:, (k + 1) % 3]] - V[T[:, k]]
        w = V[T[:, (k + 2) % 3]] - V[T[:, k]]
        worst = np.minimum(worst, np.degrees(np.arctan2(np.linalg.norm(np.cross(u, w), axis=1), (u * w).sum(1))))
    return worst


class Cloth:
    """A triangle-mesh sheet simulated by the native core (co-rotational FEM, implicit Euler)."""

    def __init__(
        self,
        vertices,
        triangles,
        material: Material | str | None = None,
        *,
        rest=None,
        uv=None,
        groups: Mapping[str, Sequence[float]] | None = None,
        gravity: Sequence[float] = _settings.default("solver", "gravity"),
    ):
        """vertices (n, 3) m; triangles (m, 3) counter-clockwise; rest: None (rest = vertices),
        (n, 3) rest positions or (n, 2) material coordinates in metres; uv: per-corner (m, 3, 2) or
        per-vertex (n, 2) texture coordinates, carried through tears; groups: vertex-group weights
        by name, carried through tears (a split vertex interpolates, a duplicate copies)."""
        v = _f64(vertices, "vertices", 3)
        t = _i32(triangles, "triangles")
        if t.ndim != 2 or t.shape[1] != 3:
            raise InvalidInputError(f"triangles must have shape (M, 3), got {t.shape}")
        rest_arr = None if rest is None else _f64(rest, "rest")
        corner_uv = None
        if uv is not None:
            u = np.asarray(uv, dtype=np.float64)
            if u.shape == (len(v), 2):
                u = u[t]
            if u.shape != (len(t), 3, 2):
                raise InvalidInputError(
                    f"uv must be per vertex ({len(v)}, 2) or per corner ({len(t)}, 3, 2), got {u.shape}"
                )
            corner_uv = np.ascontiguousarray(u)
        self.group_names: list[str] = []
        group_arr = None
        if groups:
            self.group_names = list(groups)
            cols = []
            for name in self.group_names:
                w = np.asarray(groups[name], dtype=np.float64).reshape(-1)
                if len(w) != len(v):
                    raise InvalidInputError(f"vertex group {name!r} has {len(w)} weights for {len(v)} vertices")
                bad = np.flatnonzero(~np.isfinite(w))
                if bad.size:  # a NaN weight reads as neither pinned nor free, weak nor strong
                    raise InvalidInputError(f"vertex group {name!r}: vertex {int(bad[0])} has a non-finite weight "
                                            f"({w[bad[0]]})")
                cols.append(w)
            group_arr = np.ascontiguousarray(np.stack(cols, axis=1))
        # rest and groups go down flat; the core checks their length against the vertex count
        self._c = _native.Cloth(
            v, t,
            None if rest_arr is None else rest_arr.reshape(-1),
            corner_uv,
            None if group_arr is None else group_arr.reshape(-1),
        )
        self.set_material(material if material is not None else _preset("cotton"))
        self._c.set_solver(gravity=tuple(float(g) for g in gravity))
        self._handles: dict[int, np.ndarray] = {}

    # ---- settings ----
    def set_material(self, mat: Material | str | None = None, **changes) -> None:
        if isinstance(mat, str):
            mat = _preset(mat)
        if mat is None:
            mat = self.material
        if changes:
            mat = Material(**{**mat.__dict__, **changes})
        mat.validate()
        self._material = mat
        self._c.set_material(**mat.native_kwargs())

    @property
    def material(self) -> Material:
        return self._material

    def set_solver(self, **settings) -> None:
        """gravity (m/s^2), cg_tolerance, cg_max_iterations, max_stretch, contact_max_push (m/s),
        contact_correction: the solver rows of settings.py, checked against their hard bounds
        (InvalidInputError, a ValueError, naming the parameter)."""
        if "gravity" in settings:
            settings["gravity"] = tuple(float(g) for g in settings["gravity"])
        self._check("solver", settings)
        self._c.set_solver(**settings)

    @property
    def solver(self) -> dict:
        return self._c.solver()

    def set_tearing(self, enabled: bool = True, **settings) -> None:
        """enabled, scan_period (steps for one sweep of the whole mesh while a tear runs),
        min_angle_deg (no new triangle gets a smaller angle), min_fragment_area (m^2: a piece a tear
        sets free below it is removed, see TopologyEvents): the tearing rows of settings.py."""
        self._check("tearing", settings)
        self._c.set_tearing(enabled=bool(enabled), **settings)

    @staticmethod
    def _check(group: str, values: dict) -> None:
        """The table's hard bounds before the core's own checks; only keywords the core takes."""
        native = _settings.native_defaults(group)
        unknown = sorted(set(values) - set(native))
        if unknown:
            raise TypeError(f"unknown {group} setting(s) {', '.join(unknown)}; known: {', '.join(native)}")
        try:
            _settings.validate(group, values, who=group)
        except ValueError as exc:
            raise InvalidInputError(str(exc)) from None

    @property
    def tearing(self) -> dict:
        return self._c.tearing()

    # ---- sizes and arrays ----
    @property
    def num_vertices(self) -> int:
        return self._c.counts()[0]

    @property
    def num_triangles(self) -> int:
        return self._c.counts()[1]

    def _array(self, which: int) -> np.ndarray:
        return np.asarray(self._c.array(which))

    positions = property(lambda self: self._array(_native.POSITIONS), doc="(n, 3) m")
    velocities = property(lambda self: self._array(_native.VELOCITIES), doc="(n, 3) m/s")
    rest_positions = property(lambda self: self._array(_native.REST), doc="(n, 3) m")
    masses = property(lambda self: self._array(_native.MASSES), doc="(n,) kg, lumped")
    forces = property(lambda self: self._array(_native.FORCES), doc="(n, 3) N: elastic + bending + gravity")
    triangles = property(lambda self: self._array(_native.TRIANGLES), doc="(m, 3) int32")
    corner_uv = property(lambda self: self._array(_native.CORNER_UV), doc="(m, 3, 2)")
    stress = property(lambda self: self._array(_native.STRESS),
                      doc="(m, 3, 3) Pa, world axes; derived at each read (a copy later steps leave alone)")
    principal_stress = property(lambda self: self._array(_native.PRINCIPAL), doc="(m, 2) Pa, largest first")
    principal_direction = property(lambda self: self._array(_native.PRINCIPAL_DIR),
                                   doc="(m, 3) unit; derived at each read, as stress")
    tear_strength = property(lambda self: self._array(_native.TEAR_STRENGTH), doc="(n,) factor on tear_stress")
    grain_angles = property(lambda self: self._array(_native.GRAIN_ANGLES),
                            doc="(m,) rad: each triangle's own grain angle, NaN where the material's applies")
    warp = property(lambda self: self._array(_native.WARP), doc="(m, 3) unit warp direction in the rest space")
    plastic_strain = property(lambda self: self._array(_native.PLASTIC_STRAIN),
                              doc="(m, 4): plastic strain in warp/weft axes (ww, ff, wf) and the equivalent kappa")

    def group(self, name: str) -> np.ndarray:
        """Weights of a vertex group (carried through tears)."""
        try:
            k = self.group_names.index(name)
        except ValueError:
            raise KeyError(f"no vertex group {name!r}; groups: {self.group_names}") from None
        return self.groups[:, k]

    @property
    def groups(self) -> np.ndarray:
        """(n, k) weights of every vertex group, in ``group_names`` order (k may be 0 or 1)."""
        if not self.group_names:
            return np.zeros((self.num_vertices, 0))
        # The core hands a one-column block back flat (n,): the shape is ours to restore, for
        # every number of groups, so one group reads like many.
        return self._array(_native.GROUPS).reshape(self.num_vertices, len(self.group_names))

    def set_positions(self, x) -> None:
        self._c.set_positions(_f64(x, "positions", 3))

    def set_velocities(self, v) -> None:
        self._c.set_velocities(_f64(v, "velocities", 3))

    def set_tear_strength(self, factor) -> None:
        self._c.set_tear_strength(np.ascontiguousarray(factor, dtype=np.float64).reshape(-1))

    def set_grain_angles(self, angles_rad) -> None:
        """Each triangle's grain angle (rad, the warp's angle from the UV map's u direction), overriding
        the material's grain_angle; NaN entries keep the material's. One value per current triangle
        (the Blender side reads them from the face attribute ``tearcloth_grain_angle``)."""
        self._c.set_grain_angles(np.ascontiguousarray(angles_rad, dtype=np.float64).reshape(-1))

    def warp_fallbacks(self) -> np.ndarray:
        """Indices of the triangles whose UVs give no warp direction: no UV map (all zero), the
        triangle collapsed in UV space, or UVs so large their gradients overflow. A material whose
        response has a grain (``Material.grained``: orthotropic, or plastic with different warp and
        weft yield stresses) runs its warp there along the rest X axis (Y where the triangle is
        perpendicular to X), turned by the grain angle; for any other material it does not matter.
        The Blender bake names such triangles' polygons (bake.Progress.warp_text)."""
        return np.flatnonzero(np.frombuffer(self._c.warp_fallbacks(), np.uint8)).astype(np.int32)

    # ---- constraints ----
    def _indices(self, sel, threshold: float = 0.5) -> np.ndarray:
        if isinstance(sel, str):
            return np.flatnonzero(self.group(sel) >= threshold).astype(np.int32)
        return _i32(sel, "vertices").reshape(-1)

    def pin(self, vertices, pinned: bool = True) -> None:
        """Pin vertices (indices, a boolean mask or a vertex-group name: its weights of 0.5 or
        more, as for handles) in place. A group painted as Blender's cloth reads pin weights (1:
        held, less: a spring) goes through ``pin_weights``."""
        self._c.pin(self._indices(vertices), pinned)

    def set_pin_goals(self, vertices, goals) -> None:
        """Where pinned vertices (indices or a mask; every one pinned) are to be at the end of the
        next step ((k, 3) m, world): a pin that follows a moving or deforming mesh. Reached in a
        straight line from the goals of the step before, across sub-steps; kept until set again.
        A vertex pinned (``pin``) or put somewhere (``set_positions``) has its goal where it is."""
        idx = self._indices(vertices)
        self._c.set_pin_goals(idx, _f64(goals, "goals", 3) if len(idx) else np.zeros((0, 3)))

    @property
    def pinned(self) -> np.ndarray:
        """(N,) bool: the vertices pinned now (a tear's duplicates of a pinned vertex are pinned)."""
        return np.frombuffer(self._c.pin_flags(), np.int8).astype(bool)

    def set_pin_springs(self, vertices, stiffness) -> None:
        """Soft pins: a spring of ``stiffness`` N/m (one per vertex, or one for all; 0 removes it)
        pulls each vertex (indices or a mask) towards its goal, which starts where the vertex is and
        moves with ``set_pin_goals`` (and a followed mesh: ``Session.follow_pins``). A pinned vertex
        ignores its spring."""
        idx = self._indices(vertices)
        k = np.asarray(stiffness, np.float64).reshape(-1)
        if k.size not in (1, idx.size):
            raise InvalidInputError(f"pin spring stiffness: {k.size} values for {idx.size} vertices")
        self._c.set_pin_springs(idx, np.ascontiguousarray(np.broadcast_to(k, idx.shape)))

    @property
    def pin_springs(self) -> np.ndarray:
        """(N,) N/m: each vertex's soft pin spring (0: none)."""
        k = np.frombuffer(self._c.pin_springs(), np.float64)
        return k.copy() if len(k) else np.zeros(self.num_vertices)

    @property
    def soft_pinned(self) -> np.ndarray:
        """(N,) bool: the vertices a pin spring pulls (not pinned, spring above 0)."""
        return (self.pin_springs > 0) & ~self.pinned

    def pin_weights(self, weights, pin_stiffness: float) -> tuple[int, int]:
        """Pins by weight as Blender's cloth reads a pin group: a weight of ``PIN_HARD_WEIGHT`` or
        more pins the vertex; a weight w between 0 and that makes a soft pin, a spring of
        w * pin_stiffness * the vertex's mass (``pin_stiffness`` in N/(m kg) = 1/s^2: at weight w the
        vertex swings about its goal at sqrt(w pin_stiffness) rad/s and sags g / (w pin_stiffness)
        under gravity, whatever the mesh resolution). ``weights``: (N,) or a vertex-group name.
        Adds to the pins and springs set before (a vertex of weight 0 keeps what it had). Returns
        (pinned, soft) vertex counts."""
        w = self.group(weights) if isinstance(weights, str) else np.asarray(weights, np.float64).reshape(-1)
        if w.shape != (self.num_vertices,):
            raise InvalidInputError(f"pin weights: expected {self.num_vertices} values, got {w.shape[0]}")
        if not np.all(np.isfinite(w)):
            raise InvalidInputError("pin weights must be finite")
        if not (np.isfinite(pin_stiffness) and pin_stiffness >= 0):
            raise InvalidInputError(f"pin_stiffness must be a finite value >= 0 (got {pin_stiffness} 1/s^2)")
        hard = w >= PIN_HARD_WEIGHT
        soft = (w > 0) & ~hard & (pin_stiffness > 0)
        if hard.any():
            self.pin(np.flatnonzero(hard))
        if soft.any():
            idx = np.flatnonzero(soft)
            self.set_pin_springs(idx, w[idx] * pin_stiffness * self.masses[idx])
        return int(hard.sum()), int(soft.sum())

    def add_handle(self, vertices) -> int:
        """Grasp vertices (indices, mask or group name) as one handle; returns the handle id. A
        pinned vertex it grasps follows the handle (the pin no longer holds it): said with a
        UserWarning naming them, as the Blender bake says it (blender/inputs.py)."""
        idx = self._indices(vertices)
        h = self._c.add_handle(idx)
        self._handles[h] = idx
        pinned = np.unique(idx[self.pinned[idx]]) if idx.size else idx
        if pinned.size:
            shown = ", ".join(map(str, pinned[:10])) + (", ..." if pinned.size > 10 else "")
            warnings.warn(f"handle {h} grasps {pinned.size} pinned {'vertices' if pinned.size != 1 else 'vertex'} "
                          f"({shown}): the handle moves {'them' if pinned.size != 1 else 'it'}, the pin does "
                          "not hold", UserWarning, stacklevel=2)
        return h

    def set_handle_target(self, handle: int, matrix) -> None:
        """Move a handle to an affine map (3x4 or 4x4) of its grasp-time positions by the end of the
        next step."""
        m = np.asarray(matrix, dtype=np.float64)
        if m.shape == (4, 4):
            m = m[:3]
        if m.shape != (3, 4):
            raise InvalidInputError(f"handle target must be 3x4 or 4x4, got {m.shape}")
        self._c.set_handle_target(int(handle), np.ascontiguousarray(m))

    def move_handle(self, handle: int, offset: Sequence[float]) -> None:
        """Translate a handle by offset (m) from where it was grasped."""
        m = np.eye(3, 4)
        m[:, 3] = np.asarray(offset, dtype=np.float64)
        self.set_handle_target(handle, m)

    def release_handle(self, handle: int) -> None:
        self._c.release_handle(int(handle))

    def handle_force(self, handle: int) -> np.ndarray:
        """Eq. (6): sum of elastic + external forces over the handle's vertices (N) - the force the
        cloth exerts on the hand holding it."""
        return np.array(self._c.handle_force(int(handle)))

    def pin_force(self) -> np.ndarray:
        """Sum of elastic + external forces over pinned vertices (N): minus the pins' reaction."""
        return np.array(self._c.pin_force())

    def set_contacts(self, vertex, normal, depth, velocity=None, friction=None) -> None:
        """Contacts for the next step: vertex (k,), unit push-out normal (k, 3), depth (k,) m,
        velocity of the touched surface (k, 3) m/s, friction coefficient (k,) or a scalar."""
        vertex = _i32(vertex, "vertex").reshape(-1)
        k = len(vertex)
        if friction is not None and np.ndim(friction) == 0:
            friction = np.full(k, float(friction))
        def rows(a, name, cols):
            """a as (k, cols) (or (k,) when cols is 0), or a message naming the argument: numpy's
            reshape said only 'cannot reshape array of size 3 into shape (2,3)'"""
            arr = _f64(a, name)
            want = (k, cols) if cols else (k,)
            if arr.size != k * max(cols, 1):
                raise InvalidInputError(f"{name} must have shape {want} for {k} contact vertices, got {arr.shape}")
            return arr.reshape(want)

        self._c.set_contacts(
            vertex, rows(normal, "normal", 3), rows(depth, "depth", 0),
            None if velocity is None else rows(velocity, "velocity", 3),
            None if friction is None else rows(friction, "friction", 0),
        )

    def clear_contacts(self) -> None:
        self._c.set_contacts(np.zeros(0, np.int32), np.zeros((0, 3)), np.zeros(0))

    def forget_contacts(self) -> None:
        """Drop the contact state each vertex carries from its last sub-step into the next (sliding,
        with its kinetic friction, or lifted off: the guess the next solve starts from), so the next
        sub-step judges every contact as on first touch. For a cut in the animation (a body or the
        cloth moved elsewhere); the result agrees either way within the solve's tolerance."""
        self._c.forget_contacts()

    # ---- time ----
    def step(self, dt: float, substeps: int = 1) -> None:
        """Advance dt seconds in `substeps` implicit steps (the GIL is released meanwhile).
        Raises SimulationError (state rolled back) if the step blew up."""
        self._c.step(float(dt), int(substeps))

    def stats(self) -> dict:
        """Figures of the last step (and counts so far). The solve: cg_iterations (summed over the
        sub-steps, rolled-back attempts included), cg_residual (the worst solve's residual force over
        its force scale, to compare with cg_tolerance), cg_residual_force and cg_force_scale (N),
        substep_splits (sub-steps rolled back and halved because a solve reached
        cg_max_iterations), unconverged_substeps (accepted unconverged after TC_SPLIT_DEPTH
        halvings: the cap is too low for this mesh), unconverged_steps (steps so far with any),
        matrix_bytes (what one matrix-vector product reads). Also fem_seconds, tear_seconds,
        steps, tears_started, cuts, contacts, vertices, triangles. Tiny fragments (so far):
        fragments_removed, fragment_triangles_removed, fragment_vertices_removed, and
        fragments_kept (below min_fragment_area but hanging on the rest by a vertex), amg_bytes
        (bytes the multigrid hierarchy holds, 0 with block Jacobi). Preconditioner fallbacks (so
        far; the solve itself is unchanged, only slower): amg_fallbacks (the multigrid cycle broke
        down or could not be built, or its contact correction could not be made), sgs_fallbacks (symmetric Gauss-Seidel was asked for but its
        row split could not be made): block Jacobi took over. Contacts (so far):
        contact_directions_merged (directions of a vertex's contact normals left free because two
        of its contacts were nearly parallel or opposite, a squeeze: they share the others),
        contact_speed_clamps (vertex contact solves bounded to the speed their contacts ask),
        contact_pushes_capped (contacts deeper than one sub-step recovers: their push out held to
        contact_max_push, the rest recovered over the next sub-steps),
        friction_slips (held vertices whose static friction would have exceeded mu times the
        normal reaction: they slid), friction_sticks (sliding vertices whose slip stopped or turned
        past a right angle: held from the next sub-step), friction_cone_exceeded (held vertices still outside the Coulomb cone when the
        sub-step's contact rounds stopped at their cap, left held), slides_carried (contact vertices
        that began a sub-step sliding as they ended the previous one), lifts_carried (contacts that
        began a sub-step released, their vertex still lifting off), contact_rounds_capped
        (sub-steps whose contacts still changed state after the last round, kept as solved). solves
        (last step): linear solves summed over its sub-steps, one each and more when contacts
        changed state; sgs_solves (last step): those of them preconditioned by the Gauss-Seidel
        sweeps; stiff_groups (last step, the most of any sub-step): groups of sliver corners that
        block Jacobi inverted together (auto takes block Jacobi over the sweeps when there are
        any); stiff_group_failures (so far): groups whose factor failed, their vertices left to
        their own blocks. Rotations (so far): rotation_solves (sub-steps solved again about their
        triangles' frames turned to where the first solve took them, because the frozen rotations
        misread more than 30 % of the forces the cloth carries: spinning, swinging or falling
        cloth), rotations_capped (sub-steps still past that after the re-solve, kept as solved:
        the sub-step is long for how fast the cloth turns)."""
        return self._c.stats()

    def energy(self) -> dict:
        """kinetic, elastic, bending, gravity, pins (the soft pins' springs) (J)."""
        return self._c.energy()

    # ---- snapshot ----
    def snapshot(self) -> bytes:
        """The whole simulation state (positions, velocities, topology, tear tips and scan position,
        the solver's warm start, handles, counters, settings) as a versioned, checksummed blob:
        ``restore`` of it makes this cloth (or a copy built from the same mesh and vertex groups)
        step exactly, bit for bit, as this one would from here."""
        return self._c.snapshot()

    def restore(self, blob: bytes) -> None:
        """Replace the whole simulation state by a ``snapshot()`` blob. A blob of another version or
        build, a truncated or a corrupted one raises InvalidInputError and leaves the cloth as it
        was. The blob must have this cloth's vertex groups (their names live on the Python side)."""
        before = self._c.snapshot()
        self._c.restore(blob)
        if self._c.counts()[2] != len(self.group_names):
            groups = self._c.counts()[2]
            self._c.restore(before)
            raise InvalidInputError(f"the snapshot has {groups} vertex groups, this cloth "
                                    f"{len(self.group_names)} ({', '.join(self.group_names) or 'none'})")
        # the blob carries the material the core now runs: ``material`` (and set_material(**changes),
        # which starts from it) must say that one, not the one this cloth had before
        self._material = self._material_of_core()

    def _material_of_core(self) -> Material:
        """The core's material as a Material: the one this cloth had, or the preset, with the same
        values (their name), else one named 'from snapshot'."""
        from .materials import MATERIALS

        core = self._c.material()
        for m in (self._material, *MATERIALS.values()):
            if m.native_kwargs() == core:
                return m
        return Material(name="from snapshot", **core)

    # ---- tearing ----
    def events(self) -> TopologyEvents:
        raw = self._c.events()
        return TopologyEvents(
            new_vertices=np.frombuffer(raw["new_vertices"], dtype=np.int32),
            parents=np.frombuffer(raw["parents"], dtype=np.int32).reshape(-1, 2),
            weights=np.frombuffer(raw["weights"], dtype=np.float64),
            changed_triangles=np.frombuffer(raw["changed_triangles"], dtype=np.int32),
            new_triangles=np.frombuffer(raw["new_triangles"], dtype=np.int32),
            tips=np.frombuffer(raw["tips"], dtype=np.int32),
            removed_vertices=np.frombuffer(raw["removed_vertices"], dtype=np.int32),
            removed_triangles=np.frombuffer(raw["removed_triangles"], dtype=np.int32),
        )

    def scripted_tear(self, vertex: int, direction: Sequence[float], length: float) -> int:
        """Tear from `vertex` along `direction` (projected on the surface) for `length` metres,
        whatever the stress; returns the number of cut segments."""
        d = tuple(float(x) for x in direction)
        if len(d) != 3:
            raise InvalidInputError("direction must have 3 components")
        return self._c.scripted_tear(int(vertex), d, float(length))

    def vertex_stress(self, vertex: int) -> tuple[float, np.ndarray]:
        """Largest principal stress at a vertex (Pa) and its unit direction: the mean stress over the
        material disc of radius tear_radius around it, the measure tearing holds against
        tear_stress x tear strength."""
        value, d = self._c.vertex_stress(int(vertex))
        return value, np.array(d)
