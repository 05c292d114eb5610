"""Session: one simulated scene - a tearable cloth, the bodies it collides with, the handles that
pull it - stepped in time. Pure Python (no bpy): the Blender layer, the headless bake, the bench
and the haptic loop all drive this one class.

One step, as data flows (design.md): handle targets and body poses for the step's end time ->
collision detection on the current positions (contacts) -> native step (FEM + contacts + handles,
GIL released) -> tearing (topology events) -> the impact guard makes the motion the step made free of
self-crossings (collision/impact.py) -> clusters follow the events. Nothing calls back up.

Inputs that arrive per frame (a body's deformed mesh, an empty a handle follows) are given as
keyframes at times in seconds; a step samples them at its own time by linear interpolation, so
sub-frame steps see smooth motion and body velocities for friction come from the same samples.

Step listeners: a layer above that must know of every step (a bake's progress events, the demo's
log of the force on each hand) gives ``Session(..., on_step=fn)`` or calls
``add_step_listener(fn)``; ``fn(session, report)`` runs after each ``step`` on the stepping thread,
with ``session.time`` already at the step's end. Listeners only read: the step is finished when
they run, so they cannot change its result.
"""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field, fields

import numpy as np

from . import settings as _settings
from .cloth import Cloth, TopologyEvents


_C = _settings.defaults("collision")


@dataclass
class CollisionSettings:
    """Collision of the cloth with bodies and itself (SI units; meaning and bounds in settings.py)."""

    thickness: float = _C["thickness"]            # m: contact distance around surfaces
    friction: float = _C["friction"]              # Coulomb coefficient
    # m: relative cluster motion that triggers full detection, kept below the contact thickness
    # (the row's source says why)
    displacement_threshold: float = _C["displacement_threshold"]
    cluster_size: int = _C["cluster_size"]        # vertices per cluster
    measure: str = _C["measure"]                  # 'relative' (the paper), 'absolute' or 'full'
    self_collision: bool = _C["self_collision"]
    # after each step, the step's motion made free of self-crossings (collision/impact.py); with
    # self_collision only
    impact_guard: bool = _C["impact_guard"]

    def validate(self) -> "CollisionSettings":
        _settings.validate("collision", ((f.name, getattr(self, f.name)) for f in fields(self)), who="collision")
        if self.displacement_threshold > self.thickness:
            warnings.warn(f"displacement_threshold {self.displacement_threshold} m is larger than the contact "
                          f"thickness {self.thickness} m: contacts can be missed between full detections")
        return self


class _Track:
    """A value known at keyframe times; sampled at any time by linear interpolation (held outside)."""

    def __init__(self, value: np.ndarray, t: float):
        self.times = [float(t)]
        self.values = [np.array(value, dtype=np.float64)]

    def add(self, value, t: float) -> None:
        value = np.array(value, dtype=np.float64)
        if value.shape != self.values[-1].shape:
            raise ValueError(f"keyframe shape {value.shape} differs from {self.values[-1].shape}")
        if not np.isfinite(value).all():
            raise ValueError("keyframe has non-finite values")
        t = float(t)
        if t <= self.times[-1]:
            # a new timeline (a scrub back, a restart): start over from this keyframe
            self.times, self.values = [t], [value]
            return
        self.times.append(t)
        self.values.append(value)
        if len(self.times) > 2:  # only the last two matter for stepping forward
            self.times, self.values = self.times[-2:], self.values[-2:]

    def rows_at(self, t: float, rows: np.ndarray) -> np.ndarray:
        """The value's ``rows`` at time t, as ``sample`` gives them, reading only those rows."""
        if len(self.times) == 1 or t <= self.times[0]:
            return self.values[0][rows]
        t0, t1 = self.times
        if t >= t1:
            return self.values[1][rows]
        v0 = self.values[0][rows]
        return v0 + (t - t0) * ((self.values[1][rows] - v0) / (t1 - t0))

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(value, rate of change) at time t."""
        if len(self.times) == 1 or t <= self.times[0]:
            return self.values[0], np.zeros_like(self.values[0])
        t0, t1 = self.times
        v0, v1 = self.values
        rate = (v1 - v0) / (t1 - t0)
        if t >= t1:
            return v1, rate
        return v0 + (t - t0) * rate, rate


class _PinSource:
    """The mesh the pins follow: its vertices at rest (world m: the cloth's own rest mesh as it was
    made) and their positions over time (keyframes, e.g. the mesh an Armature deforms above the
    cloth). A pinned vertex of the cloth is at a point of that mesh at rest (one of its vertices,
    or, for a tear's split of pinned vertices, a point of one of its triangles: the rest positions
    of splits are interpolated, native remesh.c), and its goal at any time is the same point of the
    moved mesh: the same vertex, or the same barycentric combination."""

    def __init__(self, rest, triangles, t: float):
        self.rest = np.array(rest, dtype=np.float64)
        self.triangles = np.array(triangles, dtype=np.int64)
        self.track = _Track(self.rest, t)
        self.moved = False  # until a keyframe leaves the rest shape, pins hold still exactly
        self._where: tuple | None = None  # (key, vertices (k, 3), weights (k, 3)) for the pinned set

    def add(self, vertices, t: float) -> None:
        vertices = np.asarray(vertices, dtype=np.float64)
        if vertices.shape != self.rest.shape:
            raise ValueError(f"the pins' mesh has {len(self.rest)} vertices, this keyframe {len(vertices)}")
        self.track.add(vertices, t)
        self.moved = self.moved or not np.array_equal(vertices, self.rest)

    def goals(self, pinned: np.ndarray, rest: np.ndarray, t: float) -> np.ndarray:
        """The goals at time t of the pinned vertices ``pinned`` whose rest positions are ``rest``."""
        key = (len(rest), pinned.tobytes())
        if self._where is None or self._where[0] != key:
            self._where = (key, *self._locate(pinned, rest))
        _, corners, weights = self._where
        # the track sampled at the corners only (a garment's pins are a sliver of its vertices)
        return np.einsum("kj,kjd->kd", weights, self.track.rows_at(t, corners))

    def _locate(self, vertices: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each cloth vertex ``vertices[j]`` at rest position ``points[j]`` as (three vertex
        indices, three weights) of the rest mesh: the vertex of the same number at the same place
        (a vertex the cloth was made with; two at one place, an unmerged seam, stay apart), else a
        vertex it sits on exactly (a tear's duplicate), else the triangle whose plane it is nearest
        with barycentric weights inside it (the point's projection; a split lies on its triangle
        up to rounding)."""
        k = len(points)
        corners = np.zeros((k, 3), np.int64)
        weights = np.zeros((k, 3))
        index = {row.tobytes(): i for i, row in enumerate(self.rest)}
        rest = np.ascontiguousarray(points, dtype=np.float64)
        n0 = len(self.rest)
        todo = []
        for j in range(k):
            own = int(vertices[j])
            i = own if own < n0 and np.array_equal(self.rest[own], rest[j]) else index.get(rest[j].tobytes())
            if i is None:
                todo.append(j)
            else:
                corners[j], weights[j] = i, (1.0, 0.0, 0.0)
        if todo:
            a, b, c = (self.rest[self.triangles[:, q]] for q in range(3))
            e1, e2 = b - a, c - a
            d11, d12, d22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
            det = d11 * d22 - d12 * d12
            ok_det = det > 0
            for j in todo:
                w = rest[j] - a
                r1, r2 = (w * e1).sum(1), (w * e2).sum(1)
                with np.errstate(divide="ignore", invalid="ignore"):
                    u = np.where(ok_det, (d22 * r1 - d12 * r2) / det, -1.0)
                    v = np.where(ok_det, (d11 * r2 - d12 * r1) / det, -1.0)
                outside = np.maximum(0.0, -np.minimum(np.minimum(u, v), 1.0 - u - v))
                off = np.linalg.norm(w - u[:, None] * e1 - v[:, None] * e2, axis=1)
                best = int(np.argmin(off + outside * np.sqrt(np.maximum(d11, d22))))
                corners[j] = self.triangles[best]
                weights[j] = (1.0 - u[best] - v[best], u[best], v[best])
        return corners, weights


@dataclass
class StepReport:
    collision_s: float = 0.0
    fem_s: float = 0.0
    tearing_s: float = 0.0
    contacts: int = 0
    events: TopologyEvents | None = None
    # sub-steps the core accepted with the linear solve short of cg_tolerance after halving them
    # TC_SPLIT_DEPTH times (the iteration cap is too low for this mesh); 0 in a converged step
    unconverged_substeps: int = 0
    # the impact guard's counts of this step (collision/impact.py COUNTS: collisions found in the
    # motion the solve left, impulses, zones, ...; rigid_cloth = 1: its pass cap was hit) or None
    # when it is off; its seconds are in collision_s and impact_s
    impact: dict | None = None
    impact_s: float = 0.0

    @property
    def total_s(self) -> float:
        return self.collision_s + self.fem_s + self.tearing_s


@dataclass
class _Body:
    name: str
    triangles: np.ndarray
    track: _Track
    friction: float | None


class Session:
    """A cloth, its bodies and handles, stepped in time."""

    def __init__(self, cloth: Cloth, collision: CollisionSettings | None = None, start_time: float = 0.0,
                 on_step=None):
        self.cloth = cloth
        # called as fn(session, report) after every step (see the module docstring)
        self._step_listeners: list = [on_step] if on_step is not None else []
        self.time = float(start_time)
        self.collision = collision.validate() if collision else None
        self._bodies: dict[str, _Body] = {}
        self._handle_tracks: dict[int, _Track] = {}
        self._pins: _PinSource | None = None  # the mesh pinned vertices follow (follow_pins)
        self.detector = None
        self.impact = None  # the impact guard (collision/impact.py), with self-collision
        self.last = StepReport()
        self.max_substeps = 16  # an exploding step is retried in up to this many sub-steps
        self.retries = 0        # steps that needed a retry, for reports
        self.unconverged_steps = 0  # steps with a sub-step accepted unconverged (StepReport says which)
        if self.collision is not None:
            from .collision import CollisionDetector

            self.detector = CollisionDetector(
                thickness=self.collision.thickness,
                friction=self.collision.friction,
                displacement_threshold=self.collision.displacement_threshold,
                cluster_size=int(self.collision.cluster_size),
                measure=self.collision.measure,
                self_collision=self.collision.self_collision,
            )
            self.detector.set_cloth(cloth.positions, cloth.triangles)
            if self.collision.self_collision and self.collision.impact_guard:
                from .collision.impact import ImpactGuard

                self.impact = ImpactGuard(self.collision.thickness)

    # ---- bodies ----
    def add_body(self, name: str, vertices, triangles, friction: float | None = None) -> None:
        """A collider (closed mesh; an open one is treated as a thin surface, with a warning)."""
        if self.detector is None:
            raise ValueError("this session has no collision settings; create it with collision=CollisionSettings()")
        if name in self._bodies:
            raise ValueError(f"a body named {name!r} already exists")
        v = np.asarray(vertices, dtype=np.float64)
        t = np.asarray(triangles)
        self.detector.add_body(v, t, name, friction=friction)
        self._bodies[name] = _Body(name, t, _Track(v, self.time), friction)

    def set_body_keyframe(self, name: str, vertices, t: float) -> None:
        """The body's (deformed) vertices at time t, e.g. an armature-skinned character at a frame."""
        try:
            self._bodies[name].track.add(vertices, t)
        except KeyError:
            raise KeyError(f"no body named {name!r}; bodies: {sorted(self._bodies)}") from None

    @property
    def bodies(self) -> list[str]:
        return list(self._bodies)

    # ---- handles ----
    def set_handle_keyframe(self, handle: int, matrix, t: float) -> None:
        """Affine target (3x4 or 4x4) of a handle at time t, relative to its grasp-time positions."""
        m = np.asarray(matrix, dtype=np.float64)
        m = m[:3] if m.shape == (4, 4) else m
        if m.shape != (3, 4):
            raise ValueError(f"handle target must be 3x4 or 4x4, got {m.shape}")
        track = self._handle_tracks.get(handle)
        if track is None:
            self._handle_tracks[handle] = _Track(m, t)
        else:
            track.add(m, t)

    # ---- pins ----
    def follow_pins(self, rest_vertices, triangles) -> None:
        """From now on pinned vertices follow a mesh: ``rest_vertices`` (n, 3) m and ``triangles``
        are it at rest, where the cloth was made from it (its rest mesh); ``set_pin_keyframe``
        moves it. Pinned vertices hold still until a keyframe moves it."""
        self._pins = _PinSource(rest_vertices, triangles, self.time)

    @property
    def pins_follow(self) -> bool:
        """Pinned vertices follow a mesh (``follow_pins``; restored with a state that had one)."""
        return self._pins is not None

    def set_pin_keyframe(self, vertices, t: float) -> None:
        """The followed mesh's vertices (n, 3) m at time t (after ``follow_pins``)."""
        if self._pins is None:
            raise ValueError("the pins follow no mesh; call follow_pins first")
        self._pins.add(vertices, t)

    def _set_pin_goals(self, t: float) -> None:
        cloth = self.cloth
        pinned = np.flatnonzero(cloth.pinned | (cloth.pin_springs > 0))  # soft pins follow their goals too
        if len(pinned):
            cloth.set_pin_goals(pinned, self._pins.goals(pinned, cloth.rest_positions[pinned], t))

    # ---- saved state ----
    # Everything a step reads, so that a session restored from it steps as this one would have
    # (a bake killed and resumed equals an uninterrupted one; tests/test_bake_resume_cli.py).
    _STATE_FIELDS = ("time", "_bodies", "_handle_tracks", "detector", "max_substeps", "retries",
                     "unconverged_steps", "impact", "_pins")
    # fields a state saved by an older build may lack: such a state keeps this session's own (the
    # impact guard reads nothing from earlier steps; only its running counts start again; pins
    # that followed nothing go on following nothing)
    _STATE_OPTIONAL = ("impact", "_pins")

    def save_state(self) -> bytes:
        """The whole state: the cloth's native snapshot and the Python side (``tearcloth.resume``)."""
        from . import resume

        return resume.dumps(self.cloth.snapshot(), {k: getattr(self, k) for k in self._STATE_FIELDS})

    def restore_state(self, blob: bytes) -> None:
        """Continue from ``save_state()``'s blob. The session must be built from the same scene
        (cloth mesh and vertex groups, collision on or off, bodies); a blob that is not a state, or
        of another scene, is a ValueError and leaves the session as it was."""
        from . import resume

        cloth_blob, state = resume.loads(blob)
        state = {**{k: None if k == "_pins" else getattr(self, k) for k in self._STATE_OPTIONAL if k not in state},
                 **state}
        if set(state) != set(self._STATE_FIELDS):
            raise ValueError(f"session state holds {sorted(state)}, not {sorted(self._STATE_FIELDS)}")
        if (state["detector"] is None) != (self.detector is None):
            raise ValueError("session state was saved with collision " + ("off" if state["detector"] is None else "on")
                             + ", this session has it " + ("off" if self.detector is None else "on"))
        if (state["impact"] is None) != (self.impact is None):
            raise ValueError("session state was saved with the impact guard " + ("off" if state["impact"] is None else
                             "on") + ", this session has it " + ("off" if self.impact is None else "on"))
        if sorted(state["_bodies"]) != sorted(self._bodies):
            raise ValueError(f"session state has the bodies {sorted(state['_bodies'])}, this session "
                             f"{sorted(self._bodies)}")
        self.cloth.restore(cloth_blob)
        for k in self._STATE_FIELDS:
            setattr(self, k, state[k])

    # ---- listeners ----
    def add_step_listener(self, fn) -> None:
        """Call ``fn(session, report)`` after every step from now on (in the order added)."""
        self._step_listeners.append(fn)

    def remove_step_listener(self, fn) -> None:
        """Stop calling ``fn``; a listener that was never added is an error (ValueError)."""
        self._step_listeners.remove(fn)

    # ---- time ----
    def _step_adaptive(self, dt: float) -> None:
        """A step that blew up was rolled back by the core; retry it in more, smaller sub-steps
        (the native step interpolates handle targets across them) before giving up."""
        from .cloth import SimulationError

        substeps = 1
        while True:
            try:
                self.cloth.step(dt, substeps)
                return
            except SimulationError:
                if substeps >= self.max_substeps:
                    raise
                substeps *= 2
                self.retries += 1

    def step(self, dt: float) -> StepReport:
        """Advance by dt seconds: collisions, then the native FEM + tearing step."""
        rep = StepReport()
        t_end = self.time + dt
        for h, track in self._handle_tracks.items():
            self.cloth.set_handle_target(h, track.sample(t_end)[0])
        if self._pins is not None and self._pins.moved:
            self._set_pin_goals(t_end)
        if self.detector is not None:
            t0 = time.perf_counter()
            for body in self._bodies.values():
                v, rate = body.track.sample(t_end)
                self.detector.update_body(body.name, v, rate)
            self.detector.detect(self.cloth.positions, self.cloth.triangles, self.cloth.velocities, dt)
            contacts = self.detector.all_contacts  # all colliders per vertex, not just the deepest
            self.cloth.set_contacts(contacts.vertex, contacts.normal, contacts.depth, contacts.velocity,
                                    contacts.friction)
            rep.contacts = len(contacts.vertex)
            rep.collision_s = time.perf_counter() - t0
        # the start of the step's motion, for the impact guard (a copy: the core writes in place)
        x0 = np.array(self.cloth.positions) if self.impact is not None else None
        self._step_adaptive(dt)
        st = self.cloth.stats()
        rep.fem_s, rep.tearing_s = st["fem_seconds"], st["tear_seconds"]
        # the core already split such sub-steps in halves; flag what is left, never drop it
        rep.unconverged_substeps = int(st["unconverged_substeps"])
        if rep.unconverged_substeps:
            self.unconverged_steps += 1
        ev = self.cloth.events()
        rep.events = ev
        if self.impact is not None:
            t0 = time.perf_counter()
            rep.impact = self.impact.resolve(self.cloth, x0, ev, dt)
            rep.impact_s = time.perf_counter() - t0
            rep.collision_s += rep.impact_s
        if ev and self.detector is not None:
            t0 = time.perf_counter()
            self.detector.on_topology(ev, self.cloth.positions, self.cloth.triangles)
            rep.collision_s += time.perf_counter() - t0
        self.time = t_end
        self.last = rep
        for fn in tuple(self._step_listeners):  # a copy: a listener may remove itself
            fn(self, rep)
        return rep
