"""The bake job, bpy-free: a ``Session`` stepped frame by frame into a ``CacheWriter``.

What this file owns
-------------------
``BakePlan`` (everything a bake needs, gathered from Blender once by ``blender/inputs.py``, as
plain arrays and SI values), ``FrameInputs`` (what Blender must tell the bake about one frame:
the cloth object's matrix, the matrices of the objects handles follow, the deformed colliders),
``BakeJob`` (turns frames of inputs into cache frames), ``make_session`` (the scene a plan
describes, shared with the live haptic session), the resume state file, ``run_worker`` (the
worker-thread loop), and progress: ``Progress`` (counters shared with the UI), ``BakeEvent``
(what a job tells the listener it was given) and ``ProgressLine`` (the one text reporter, used by
``tearcloth bake``). Because nothing here touches bpy, the same code runs on the modal
operator's worker thread and inline in the headless bake; and undo, file loads or deleted
objects in Blender can never pull data out from under it: it holds only its own arrays.

Time: frame ``f`` is at ``(f - frame_start) / fps`` seconds. To go from frame f-1 to f, the
inputs of frame f are keyframed into the Session first, so its sub-steps interpolate between the
two frames (smooth handle motion, collider velocities for friction).

Events: ``BakeJob(plan, on_event=fn)`` calls ``fn(BakeEvent)`` on the thread that runs the job:
``"begin"`` once the simulation is built, ``"step"`` after every simulation step (through the
Session's step listener; ``event.report`` is its ``StepReport``) and ``"frame"`` after every frame
is on disk. Listeners read the job (``event.job.session``, ``event.job.progress``); they must not
step it.

Crash safety and resume: the cache writer makes every finished frame durable on its own. To
continue a bake the simulation state is needed too, and the USD frames do not hold it all (rest
positions of torn vertices, carried vertex-group weights, tear strengths), so after each frame the
full state is saved next to the cache (``<name>.state.npz``, written under a temporary name and
renamed). The state is saved BEFORE the frame goes into the cache: after a crash the state is
either for the cache's last frame or for the frame after it, which ``BakeJob`` then writes first.
The state is the session's whole state (``Session.save_state``: the core's native snapshot,
with velocities, solver warm start, tear tips and scan position, pair order and handles, and the
collision detector's tracks, measures and clusters) plus the first frame's handle grasps, so a
resumed bake steps exactly as the uninterrupted one: same positions to the bit, same topology.
"""
from __future__ import annotations

import hashlib
import logging
import math
import os
import queue
import sys
import threading
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from . import attributes as attrs
from . import spaces
from .cache import CacheWriter, _remove_quietly, interrupted_rebake, read_primvars, staging_path_for
from .cloth import PIN_HARD_WEIGHT, Cloth, SimulationError, smallest_angles_deg
from .materials import Material
from .session import CollisionSettings, Session, StepReport

STATE_VERSION = 2  # 2: the whole session state (native snapshot, collision, tracks)


@dataclass
class BakePlan:
    """Everything a bake needs, in SI and world space unless said otherwise."""

    object_name: str
    prim_name: str
    cache_path: str                 # absolute path of the cache root (.usda)
    fps: float
    frame_start: int
    frame_end: int
    steps_per_frame: int
    scale: float                    # metres per Blender unit
    material: Material
    solver: dict
    tearing: dict
    collision: CollisionSettings | None
    vertices: np.ndarray            # (n, 3) world metres at frame_start
    triangles: np.ndarray           # (m, 3)
    corner_uv: np.ndarray | None    # (m, 3, 2)
    groups: dict                    # vertex-group name -> (n,) weights
    fingerprint: str                # of the rest mesh (local BU), recorded in the cache
    pin_group: str | None = None
    pin_stiffness: float = 1000.0   # 1/s^2: the pull of pin weights below 1 (Cloth.pin_weights)
    handle_groups: list = field(default_factory=list)   # one vertex-group name per handle
    seam_group: str | None = None
    seam_factor: float = 1.0        # tear-strength factor where the seam weight is 1
    body_triangles: dict = field(default_factory=dict)  # collider name -> (k, 3)
    resume: bool = False
    hand_groups: dict = field(default_factory=dict)     # live session: hand name -> vertex-group name
    uv_name: str = "st"             # the cache's UV primvar: the user's UV map name (a USD identifier)
    object_id: str = ""             # the object's persistent id (cache identity; see cache.OWNER_KEYS)
    blend: str = ""                 # the .blend the bake is made in
    source: str = ""                # the input `tearcloth bake --out` copied into the .blend ('' for others)
    # The user's polygon of each triangle and vertex of each vertex (messages name those)
    triangle_polygons: np.ndarray | None = None         # (m,)
    vertex_ids: np.ndarray | None = None                # (n,)
    # the modifiers above "Tear Cloth" that renumbered the mesh (then the two above number their
    # elements, not the user's: messages say so and nothing is selected)
    renumbered_by: tuple = ()
    # The user's grain override, radians per triangle (None: the material's own grain)
    grain_angles: np.ndarray | None = None              # (m,)
    # The user's attributes the cache carries through tears (attributes.UserAttribute)
    attributes: list = field(default_factory=list)

    @property
    def settings_fingerprint(self) -> str:
        """A short hash of everything that decides the simulation besides the rest mesh (the
        material, solver, tearing and collision settings, steps, fps, start frame, the roles of
        the vertex groups): a partial bake resumes only under the same."""
        collision = None if self.collision is None else sorted(vars(self.collision).items())
        key = repr((sorted(vars(self.material).items()), sorted(self.solver.items()), sorted(self.tearing.items()),
                    collision, self.steps_per_frame, self.fps, self.frame_start, self.scale, self.pin_group,
                    list(self.handle_groups), self.seam_group, self.seam_factor, sorted(self.body_triangles)))
        if self.pin_group and np.any(self._soft_pin_weights()):
            # (only then, as the grain below) weights between 0 and PIN_HARD_WEIGHT are soft pins,
            # held exactly (from 0.5 up) by releases before them: such a bake resumes under neither
            key += repr(("soft pins", float(self.pin_stiffness)))
        if self.grain_angles is not None:  # (only then: fingerprints of bakes without one stay as they were)
            key += repr(np.round(np.asarray(self.grain_angles, dtype=np.float64), 9).tobytes())
        return hashlib.sha256(key.encode("utf-8")).hexdigest()[:16]

    def _soft_pin_weights(self) -> np.ndarray:
        w = np.asarray(self.groups.get(self.pin_group, ()), dtype=np.float64)
        return (w > 0) & (w < PIN_HARD_WEIGHT)

    @property
    def owner(self) -> dict:
        """The owner fields the cache records (``cache.OWNER_KEYS``)."""
        return {"object_id": self.object_id, "blend": self.blend, "settings": self.settings_fingerprint,
                "source": self.source}

    @property
    def state_path(self) -> str:
        return state_path_for(self.cache_path)

    @property
    def dt(self) -> float:
        return 1.0 / self.fps / self.steps_per_frame

    def time_of(self, frame: int) -> float:
        return (frame - self.frame_start) / self.fps


@dataclass
class FrameInputs:
    """What Blender knows about one frame, gathered on the main thread (copies, never views)."""

    frame: int
    object_matrix: np.ndarray               # cloth object's world matrix (4x4, BU)
    handle_matrices: list                   # per handle: follow object's world matrix or None
    bodies: dict                            # collider name -> (k, 3) world metres
    # the rest mesh's vertices (plan.vertices' order, world metres) as the stack above Tear Cloth
    # deforms them at this frame, for the pins to follow; None: nothing above deforms them (the
    # pins follow the object's transform, object_matrix)
    pin_source: np.ndarray | None = None


# A starting triangle is called a sliver in the bake's closing text below this smallest corner
# (degrees): the core groups a sliver's corners where a block reaches TC_STIFF_SLIVER (0.94, about
# 1.5 degrees) at a triangle with a corner under TC_STIFF_SLIVER_DEG (2)
SLIVER_DEG = 5.0


class Progress:
    """Shared between the worker and the UI; plain attributes (each write is atomic under the GIL).

    The ETA comes from the last ``ETA_WINDOW`` frames, not from the whole run: steps slow down
    several times once a tear starts (more vertices, a scan of the tear tips every step), so an
    average over the calm frames before it promises far too early an end."""

    ETA_WINDOW = 5  # frames

    def __init__(self, object_name: str, frame_start: int, frame_end: int, clock=time.perf_counter):
        self.object_name = object_name
        self.frame_start = frame_start
        self.frame_end = frame_end
        self.first_frame = frame_start      # the first frame this run computes
        self.frame = None                   # last frame on disk
        self.steps = 0
        self.step_seconds = 0.0
        self.tears = 0
        self.vertices = 0
        # this run's sub-steps whose solve stopped at the iteration cap even after the core split
        # them (Session's StepReport), and the steps that had any: said in the log and the panel
        self.unconverged_substeps = 0
        self.unconverged_steps = 0
        self.cg_max_iterations: int | None = None
        # solves so far whose multigrid or Gauss-Seidel preconditioner could not be had (out of
        # memory, a broken-down cycle) and block Jacobi took over: same answer, slower, said at the end
        self.preconditioner_fallbacks = 0
        # sub-steps whose triangles still turned past the core's bar after one re-solve about
        # their turned frames (stats' rotations_capped, so far): said at the end (rotation_text)
        self.rotations_capped = 0
        # collision steps whose swept stage ran on the baking thread because the system would not
        # start its own (the detector's count): same contacts, slower, said at the end
        self.swept_thread_fallbacks = 0
        # the most stiff groups a step of this run had (the core's stats: sliver triangles' corners
        # solved together, native/stiff.c), and the thinnest triangle of the mesh the bake began
        # with (degrees, the user's polygon): said at the end, as remeshing them speeds the bake
        self.stiff_groups = 0
        # the first frame at which the cloth object (or a parent) had moved while its pins held
        # their vertices where they were in the world (a resumed state from before pins followed
        # the object): said at the end (pins_text)
        self.pins_left_at: int | None = None
        # a material with a grain (Material.grained) on triangles whose UVs give no warp direction
        # (Cloth.warp_fallbacks: their warp runs along world X): the material's name, whether the
        # mesh has a UV map at all, how many triangles and their polygons (the user's numbering,
        # ascending); said at the end (warp_text). A fresh bake finds them; a resumed one says
        # nothing new (its triangles are the torn ones, numbered past the user's polygons).
        self.warp_material: str | None = None
        self.warp_has_uv = True
        self.warp_fallback_triangles = 0
        self.warp_fallback_polygons: list = []
        self.thinnest_angle_deg: float | None = None
        self.thinnest_polygon: int | None = None
        self.polygons_renumbered_by: tuple = ()  # modifiers above whose numbering thinnest_polygon is in
        # pieces a tear set free with less rest area than Min Fragment, removed with their
        # triangles (the core's count, carried through a resume); start_triangles: the user's mesh
        # triangulated, to say when removal took much of the cloth (a cloth small against Min Fragment)
        self.fragments_removed = 0
        self.fragment_triangles_removed = 0
        self.start_triangles = 0
        self.start_area = 0.0             # m^2, the rest area of the mesh the bake began with
        self.fragment_area_removed = 0.0  # m^2, the rest area the removed pieces took away
        self.min_fragment_area = 0.0
        self._clock = clock
        self.started = clock()
        self.state = "running"              # running, done, cancelled, error
        self.message = ""
        self._recent: list = []             # (time, frame) of the last frames written

    def frame_done(self, frame: int) -> None:
        """A frame is on disk (called by the job after each frame)."""
        self.frame = frame
        self._recent = (self._recent + [(self._clock(), frame)])[-(self.ETA_WINDOW + 1):]

    @property
    def factor(self) -> float:
        span = max(1, self.frame_end - self.frame_start)
        done = 0 if self.frame is None else self.frame - self.frame_start
        return min(1.0, max(0.0, done / span))

    @property
    def steps_per_second(self) -> float:
        return self.steps / self.step_seconds if self.step_seconds > 0 else 0.0

    @property
    def eta_seconds(self) -> float | None:
        if self.frame is None or self.frame <= self.first_frame:
            return None
        if len(self._recent) >= 2 and self._recent[-1][1] > self._recent[0][1]:
            (t0, f0), (t1, f1) = self._recent[0], self._recent[-1]
            per_frame = (t1 - t0) / (f1 - f0)
        else:  # one frame so far: the time since the start is all there is
            per_frame = (self._clock() - self.started) / (self.frame - self.first_frame)
        return per_frame * (self.frame_end - self.frame)

    def text(self, elapsed: bool = False) -> str:
        """One line: frames, steps per second, tears, the ETA; ``elapsed`` adds the time so far
        and always shows the ETA ('?' while unknown), for a log where lines must line up."""
        frame = "-" if self.frame is None else str(self.frame)
        parts = [f"{self.object_name}: frame {frame}/{self.frame_end}", f"{self.steps_per_second:.0f} steps/s",
                 f"{self.tears} tear{'s' if self.tears != 1 else ''}"]
        if self.unconverged_substeps:
            parts.append(f"{self.unconverged_substeps} sub-step{'s' if self.unconverged_substeps != 1 else ''} "
                         "unconverged")
        eta = self.eta_seconds
        if elapsed:
            parts += [duration(self._clock() - self.started), f"ETA {duration(eta)}"]
        elif eta is not None:
            parts.append(f"ETA {duration(eta)}")
        return ", ".join(parts)

    def fallback_text(self) -> str | None:
        """The sentence for the end of a bake when some solves fell back to block Jacobi, or some
        collision steps ran their swept stage without its thread (None when neither happened): the
        motion is as accurate, the bake was slower than it should have been."""
        said = []
        n = self.preconditioner_fallbacks
        if n:
            said.append(f"{n} solve{'s' if n != 1 else ''} fell back from the chosen preconditioner to block Jacobi "
                        "(out of memory, or the multigrid cycle broke down): same result, slower; free memory or "
                        "set the preconditioner to Jacobi")
        n = self.swept_thread_fallbacks
        if n:
            said.append(f"{n} collision step{'s' if n != 1 else ''} ran the self-collision sweep on the baking "
                        "thread because the system would not start another (its thread limit): same result, slower")
        return ". ".join(said) or None

    def pins_text(self) -> str | None:
        """The sentence for the end of a resumed bake whose state held its pins in the world (saved
        by a build before pins followed the object) while the object moved away from them, or None."""
        if self.pins_left_at is None:
            return None
        return (f"the object moves (its transform or a parent's) from frame {self.pins_left_at}, and its pinned "
                "vertices stayed where they were in the world: this bake resumed a state saved before pins "
                "followed the object. Free the bake and bake again to carry the pinned vertices along")

    def sliver_text(self) -> str | None:
        """The sentence for the end of a bake whose mesh had sliver triangles that the solver
        treated as such (stiff groups), or None: converged, only slower than it could be."""
        n = self.stiff_groups
        if not n:
            return None
        groups = f"{n} group{'s' if n != 1 else ''}"
        if self.thinnest_angle_deg is None or self.thinnest_angle_deg >= SLIVER_DEG:
            # the user's mesh has no sliver: the stiff corners are thin triangles its tears made, or
            # a material stiff against its mass at this step (the core's test reads the matrix)
            return (f"the solver took {groups} of stiff corners together (thin triangles made by tears, or a "
                    "material stiff for this step length; the mesh you made has none) and converged, more "
                    "slowly; more steps per frame make each solve easier")
        where = ""
        if self.thinnest_angle_deg is not None:
            where = f" (the thinnest has a {self.thinnest_angle_deg:.2g} degree corner"
            if self.thinnest_polygon is None:
                where += ")"
            elif self.polygons_renumbered_by:
                where += (f", in polygon {self.thinnest_polygon} of the mesh the modifiers above Tear Cloth make: "
                          f"{', '.join(self.polygons_renumbered_by)})")
            else:
                where += f", in polygon {self.thinnest_polygon})"
        return (f"the mesh has sliver triangles{where}: the solver took {groups} of their "
                "corners together and converged, more slowly than on a well-shaped mesh; remeshing the slivers "
                "(e.g. Remesh, or Triangulate with Beauty) makes the bake faster")

    def warp_text(self) -> str | None:
        """The sentence for the end of a bake whose material has a grain and whose mesh gives no
        warp direction on some triangles (None otherwise): there the threads run along world X."""
        n = self.warp_fallback_triangles
        if not n or self.warp_material is None:
            return None
        fix = "unwrap the mesh (UV > Unwrap) so its threads follow the pattern pieces"
        # a preset's name reads as the material; a user's own values go by "custom" (convert.py)
        whose = "the material's" if self.warp_material in ("", "custom") else f"{self.warp_material}'s"
        if not self.warp_has_uv:
            return (f"the mesh has no UV map, so {whose} warp runs along the world X axis (its weft along Y) on "
                    f"every triangle, whatever the cloth's shape: {fix}")
        polygons = self.warp_fallback_polygons
        where = ""
        if polygons:
            shown = ", ".join(map(str, polygons[:10])) + (f" and {len(polygons) - 10} more" if len(polygons) > 10 else "")
            where = f" (polygon{'s' if len(polygons) != 1 else ''} {shown}"
            where += f", of the mesh the modifiers above Tear Cloth make: {', '.join(self.polygons_renumbered_by)})" \
                if self.polygons_renumbered_by else ")"
        return (f"{n} triangle{'s' if n != 1 else ''}{where} {'are' if n != 1 else 'is'} collapsed in the UV map, so "
                f"{whose} warp runs along the world X axis there instead of the UV map's u: {fix}, "
                "or give those faces room in the UV map")

    def fragment_text(self) -> tuple[str, bool] | None:
        """(sentence, is_warning) for the end of a bake that removed small pieces (None when none
        was): a warning when they took a quarter or more of the starting triangles, since then the
        cloth itself is small against Min Fragment and the user likely wants it lower."""
        n, m = self.fragments_removed, self.fragment_triangles_removed
        if not n:
            return None
        text = (f"{n} small piece{'s' if n != 1 else ''} set free by tears ({m} triangle{'s' if m != 1 else ''}) "
                f"removed, each below Min Fragment ({self.min_fragment_area * 1e4:.3g} cm^2)")
        # decided on the area, not the triangle count: a fan of slivers (an n-gon's triangulation)
        # can shed hundreds of triangles and a fraction of a percent of the cloth
        share = self.fragment_area_removed / self.start_area if self.start_area > 0 else 0.0
        heavy = share >= 0.25
        text += f", {100 * share:.2g} % of the cloth's area" if self.start_area > 0 else ""
        if heavy:
            text += ": the cloth is small against Min Fragment; lower it (0 keeps every piece)"
        return text, heavy

    def rotation_text(self) -> str | None:
        """The sentence for the end of a bake when some sub-steps turned too fast for one re-solve
        about their turned frames (None when none did): there the stresses read high."""
        n = self.rotations_capped
        if not n:
            return None
        of = f" of {self.steps} steps" if self.steps else ""
        return (f"{n} sub-step{'s' if n != 1 else ''}{of} turned faster than one re-solve follows (the cloth "
                "swung, fell or spun through a large angle in one sub-step): stresses there read high and may "
                "start tears early; raise Steps per Frame")

    def convergence_text(self) -> str | None:
        """The sentence for the end of a bake when some solves stopped at the iteration cap even
        after the core halved their sub-steps (None when every solve converged)."""
        n = self.unconverged_substeps
        if not n:
            return None
        cap = f" ({self.cg_max_iterations})" if self.cg_max_iterations else ""
        return (f"{n} sub-step{'s' if n != 1 else ''} in {self.unconverged_steps} step"
                f"{'s' if self.unconverged_steps != 1 else ''} stopped at the CG iteration cap{cap} even after "
                "splitting: the motion there is less accurate; raise CG Iterations")


def find_warp_fallbacks(plan: BakePlan, cloth, progress: Progress) -> None:
    """Into ``progress`` (its warp_text): the triangles of a cloth just built from ``plan`` whose UVs
    give the plan's material no warp direction (Cloth.warp_fallbacks), as the user's polygons. For
    a bake's first frame and a live session's start; the caller checks ``plan.material.grained``."""
    fallbacks = cloth.warp_fallbacks()
    progress.warp_material = plan.material.name
    progress.warp_has_uv = plan.corner_uv is not None
    progress.warp_fallback_triangles = int(fallbacks.size)
    polygons = plan.triangle_polygons
    if (fallbacks.size and polygons is not None
            and len(polygons) == len(plan.triangles) == cloth.num_triangles):  # the plan's own numbering
        progress.warp_fallback_polygons = sorted({int(polygons[k]) for k in fallbacks})
        progress.polygons_renumbered_by = tuple(plan.renumbered_by)


def _rest_area(vertices, triangles) -> float:
    """Total area (m^2) of triangles (m, 3) over vertices (n, 3) m."""
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles)
    if not len(t):
        return 0.0
    e1, e2 = v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]]
    return float(0.5 * np.linalg.norm(np.cross(e1, e2), axis=1).sum())


def frame_span(first: int, last: int) -> str:
    """A range of frames as a person reads it: '1-24', and '-8 to -2' where a frame is negative
    ('-8--2' reads as a typo)."""
    return f"{first} to {last}" if first < 0 or last < 0 else f"{first}-{last}"


def duration(seconds: float | None) -> str:
    """Seconds as a person reads them ('42 s', '3 min 07 s', '1 h 05 min'); '?' if unknown."""
    if seconds is None or not math.isfinite(seconds):
        return "?"
    seconds = int(round(seconds))
    if seconds < 60:
        return f"{seconds} s"
    if seconds < 3600:
        return f"{seconds // 60} min {seconds % 60:02d} s"
    return f"{seconds // 3600} h {seconds % 3600 // 60:02d} min"


def state_path_for(cache_path: str) -> str:
    return os.path.splitext(cache_path)[0] + ".state.npz"


@dataclass(frozen=True)
class BakeEvent:
    """What a ``BakeJob`` tells its listener (see the module docstring)."""

    kind: str                          # "begin", "step" or "frame"
    job: "BakeJob"
    frame: int | None = None           # "begin": the start frame; "frame": the frame written
    report: StepReport | None = None   # "step": the step's report


class BakeJob:
    """Frames of ``FrameInputs`` in, cache frames out.

    ``BakeJob(plan)`` opens the cache (fresh, or resumed: ``plan.resume``) and finds the frame
    the simulation starts from (``start_frame``); ``begin(inputs of start_frame)`` builds the
    cloth there; ``advance(inputs of the next frame)`` simulates and writes one frame;
    ``close()`` finishes. Errors are ``CacheError``, ``ValueError`` (bad input, bad state
    file) and ``SimulationError``. ``on_event(BakeEvent)``: see the module docstring.
    """

    def __init__(self, plan: BakePlan, progress: Progress | None = None, on_event=None):
        self.plan = plan
        self.progress = progress or Progress(plan.object_name, plan.frame_start, plan.frame_end)
        if len(plan.triangles):  # the thinnest triangle, named at the end if the solver met slivers
            angles = smallest_angles_deg(plan.vertices, plan.triangles)
            k = int(np.argmin(angles))
            self.progress.thinnest_angle_deg = float(angles[k])
            if plan.triangle_polygons is not None and k < len(plan.triangle_polygons):
                self.progress.thinnest_polygon = int(plan.triangle_polygons[k])
                self.progress.polygons_renumbered_by = tuple(plan.renumbered_by)
        self.on_event = on_event
        self.cancel = threading.Event()
        # a stop meant to be resumed (the CLI's SIGTERM: a farm manager's preemption): an unfinished
        # re-bake keeps its frames and state beside the previous bake instead of dropping them
        self.keep_staged = False
        self.session: Session | None = None
        self._state: dict | None = None
        self._tears_before = 0
        self._grasp: list = []
        self._handles: list = []
        # A fresh bake is staged beside the old cache. Over a previous bake (a re-bake) it replaces
        # it only once complete (``close``): a re-bake that fails, is cancelled or is killed at any
        # frame leaves the user's previous bake, its resume state included, as it was (its own
        # frames are dropped: the user asked for a new bake, not half of one over the old). With
        # nothing to replace, the staged bake moves to the final path with its first simulated
        # frame (``_write``), so a first bake killed midway keeps its frames and resumes. A
        # re-bake killed midway (a crash, SIGKILL) leaves its staged frames and state beside the
        # previous bake: resuming continues it there (``cache.interrupted_rebake``).
        rebake = plan.resume and interrupted_rebake(plan.cache_path) is not None
        self.replacing = rebake or (not plan.resume and os.path.lexists(plan.cache_path))
        self.writer = CacheWriter(
            plan.cache_path, plan.prim_name, plan.fps, "Z", plan.scale,
            object_name=plan.object_name, fingerprint=plan.fingerprint, resume=plan.resume,
            stage=rebake or not plan.resume, owner=plan.owner, uv_name=plan.uv_name,
        )
        last = self.writer.last_frame
        if plan.resume and last is not None:
            # the state beside the cache it belongs to (the staged root of an interrupted re-bake)
            state = load_state(state_path_for(self.writer.path))
            if (state is None or state["frame"] < last or state["object_name"] != plan.object_name
                    or (plan.fingerprint and state["fingerprint"] and state["fingerprint"] != plan.fingerprint)):
                self.writer.close(complete=False)
                raise ValueError(
                    f"{plan.cache_path}: cannot resume: the simulation state for frame {last} is missing "
                    f"or stale ({os.path.basename(state_path_for(self.writer.path))}); bake again from the start"
                )
            if state["frame"] > last + 1:
                # frames between the last readable one and the state's were damaged (cut short, or
                # written over): the state cannot go back to them, and a resume would leave a gap
                # that playback fills by interpolation while the bake says it is complete
                self.writer.close(complete=False)
                lost = int(state["frame"]) - 1
                what = f"frame {lost} is" if lost == last + 1 else f"frames {frame_span(last + 1, lost)} are"
                raise ValueError(
                    f"{plan.cache_path}: cannot resume: {what} damaged or missing (the frames up to {last} are intact, "
                    f"the simulation state is at frame {state['frame']}); bake again from the start"
                )
            self._state = state
            self.start_frame = int(state["frame"])
        else:
            self.start_frame = plan.frame_start
        self.next_frame = self.start_frame + 1
        self.progress.first_frame = self.start_frame
        self.progress.frame = last

    @property
    def resumed(self) -> bool:
        """True when this job continues a saved state (its cloth may be torn already)."""
        return self._state is not None

    @property
    def done(self) -> bool:
        return self.next_frame > self.plan.frame_end

    # -- building the simulation ---------------------------------------------------------------

    def begin(self, inputs: FrameInputs) -> None:
        plan = self.plan
        if inputs.frame != self.start_frame:
            raise ValueError(f"the bake starts at frame {self.start_frame}, not {inputs.frame}")
        state = self._state
        # A mesh without a UV map gets no UVs in the cache (not a layer of zeros).
        self._has_uv = plan.corner_uv is not None if state is None else state["corner_uv"] is not None
        session, self._handles = make_session(plan, inputs.bodies, plan.time_of(self.start_frame), state)
        if state is not None:
            # the restored core counts the tears it made before the kill too
            self._tears_before = int(state["tears"]) - int(session.cloth.stats()["tears_started"])
            # handle targets stay relative to the first frame's grasp, as in the uninterrupted bake
            self._grasp = [None if np.isnan(m).all() else np.array(m) for m in state["grasp"]]
        else:
            self._grasp = [None if m is None else np.array(m, dtype=np.float64) for m in inputs.handle_matrices]
        self.session = session
        # Pins follow the cloth object, as Blender's own cloth pins do: its transform, and the
        # deformation of the stack above Tear Cloth when the inputs carry it (pin_source). While
        # neither moves, the pins hold still exactly as pins always did. A state saved before
        # pins followed anything keeps its pins in the world, and says so at the end if the
        # object moves (pins_text).
        self._pin_matrix = np.array(inputs.object_matrix, dtype=np.float64) if plan.pin_group else None
        if plan.pin_group and state is None:
            session.follow_pins(plan.vertices, plan.triangles)
        elif state is not None and session.pins_follow:
            self._pin_matrix = np.array(state["pin_matrix"])
        self._tracker = self._attribute_tracker()
        if state is None and plan.material.grained:
            self._find_warp_fallbacks(session.cloth)
        self.progress.cg_max_iterations = int(session.cloth.solver["cg_max_iterations"])
        self.progress.start_triangles = len(plan.triangles)
        self.progress.start_area = _rest_area(plan.vertices, plan.triangles)
        self.progress.min_fragment_area = float(plan.tearing.get("min_fragment_area", 0.0))
        if self.on_event is not None:
            session.add_step_listener(self._stepped)
            self.on_event(BakeEvent("begin", self, self.start_frame))
        if self.writer.last_frame is None or self.writer.last_frame < self.start_frame:
            self._write(inputs, save_state=state is None)
        self.progress.vertices = session.cloth.num_vertices

    def _find_warp_fallbacks(self, cloth) -> None:
        """The fresh cloth's triangles whose UVs give its grained material no warp (progress)."""
        find_warp_fallbacks(self.plan, cloth, self.progress)

    def _attribute_tracker(self) -> "attrs.AttributeTracker | None":
        """The per-frame attributes (``attributes.py``), or None when this cloth cannot have them:
        a resumed bake started before the cache carried attributes (its frames have none; every
        frame of a cache must match)."""
        plan, cloth, writer = self.plan, self.session.cloth, self.writer
        if not set(attrs.REST_GROUPS) <= set(cloth.group_names) or (writer.frames and not writer.primvars):
            return None
        tracker = attrs.AttributeTracker(plan.vertices, plan.triangles, plan.attributes,
                                         float(getattr(plan.material, "grain_angle", 0.0) or 0.0))
        if writer.frames and "torn_time" in writer.primvars:
            # resume: when each point tore lives in the cache's last frame
            tracker.restore_torn_time(read_primvars(writer.path, writer.last_frame)["torn_time"])
        return tracker

    @property
    def handles(self) -> list:
        """The session's handle ids, one per ``plan.handle_groups`` (after ``begin``)."""
        return list(self._handles)

    def _stepped(self, session: Session, report: StepReport) -> None:
        self.on_event(BakeEvent("step", self, report=report))

    # -- one frame -----------------------------------------------------------------------------

    def advance(self, inputs: FrameInputs) -> bool:
        """Simulate up to ``inputs.frame`` and write it. False if cancelled before the frame was
        complete (nothing of that frame is written)."""
        plan, session = self.plan, self.session
        if inputs.frame != self.next_frame:
            raise ValueError(f"expected the inputs of frame {self.next_frame}, got frame {inputs.frame}")
        t = plan.time_of(inputs.frame)
        if session.pins_follow:
            session.set_pin_keyframe(self._pin_source(inputs), t)
        elif self._pin_matrix is not None and self.progress.pins_left_at is None:
            m = np.asarray(inputs.object_matrix, dtype=np.float64)
            if not np.allclose(m, self._pin_matrix, rtol=1e-9, atol=1e-9 * (1.0 + np.abs(self._pin_matrix).max())):
                self.progress.pins_left_at = inputs.frame
        for h, grasp, current in zip(self._handles, self._grasp, inputs.handle_matrices):
            if grasp is not None and current is not None:
                session.set_handle_keyframe(h, spaces.handle_target_si(current, grasp, plan.scale), t)
        for name, vertices in inputs.bodies.items():
            try:
                session.set_body_keyframe(name, vertices, t)
            except ValueError as exc:
                raise ValueError(f"frame {inputs.frame}: collider {name!r}: {exc} (colliders must keep "
                                 "their vertex count over the bake)") from None
        for _ in range(plan.steps_per_frame):
            if self.cancel.is_set():
                return False
            start = time.perf_counter()
            try:
                report = session.step(plan.dt)
            except SimulationError as exc:
                # a re-bake's frames are dropped with it (its caller says the previous bake stays)
                kept = "" if self.replacing else "frames before are kept. "
                # the core's advice is in its own terms (time step, sub-steps); the artist's are
                # steps per frame, said once below
                detail = str(exc).replace(" Reduce the time step or raise sub-steps.", "").rstrip(".")
                raise SimulationError(
                    f"the simulation blew up between frames {inputs.frame - 1} and {inputs.frame} ({detail}); "
                    f"{kept}Try more steps per frame or a gentler pull"
                ) from None
            self.progress.step_seconds += time.perf_counter() - start
            self.progress.steps += 1
            if report.unconverged_substeps:
                self.progress.unconverged_substeps += report.unconverged_substeps
                self.progress.unconverged_steps += 1
        st = session.cloth.stats()
        self.progress.preconditioner_fallbacks = int(st["amg_fallbacks"]) + int(st["sgs_fallbacks"])
        self.progress.rotations_capped = int(st["rotations_capped"])
        if session.detector is not None:
            self.progress.swept_thread_fallbacks = int(session.detector.stats.get("swept_thread_fallbacks", 0))
        self.progress.stiff_groups = max(self.progress.stiff_groups, int(st["stiff_groups"]))
        self._write(inputs)
        self.next_frame += 1
        return True

    def _pin_source(self, inputs: FrameInputs) -> np.ndarray:
        """The rest mesh's vertices (world m) where the pins follow them at this frame: the
        deformed mesh the inputs carry, else the rest mesh carried by the object's motion since
        the first frame (exactly the rest mesh while the object stands still)."""
        plan = self.plan
        if inputs.pin_source is not None:
            return inputs.pin_source
        m = np.asarray(inputs.object_matrix, dtype=np.float64)
        if np.array_equal(m, self._pin_matrix):
            return plan.vertices
        a = spaces.handle_target_si(m, self._pin_matrix, plan.scale)
        return plan.vertices @ a[:3, :3].T + a[:3, 3]

    def _write(self, inputs: FrameInputs, save_state: bool = True) -> None:
        plan, cloth, writer = self.plan, self.session.cloth, self.writer
        st = cloth.stats()
        tears = self._tears_before + int(st["tears_started"])
        # the state follows the cache it belongs to: beside the staged root until it is promoted
        state_path = state_path_for(writer.path)
        if save_state:
            save_state_file(state_path, inputs.frame, plan, self.session, tears, self._has_uv, self._grasp,
                            self._pin_matrix if self.session.pins_follow else None)
        matrix = inputs.object_matrix
        local = spaces.world_si_to_local(cloth.positions, matrix, plan.scale)
        velocity = spaces.world_si_vectors_to_local(cloth.velocities, matrix, plan.scale)
        primvars = None
        if self._tracker is not None:
            primvars = self._tracker.frame(cloth, plan.time_of(inputs.frame), inputs.object_matrix,
                                           cloth.corner_uv if self._has_uv else None)
        # The writer takes metres with meters_per_unit = scale, so the file holds local BU:
        # exactly what the Mesh Sequence Cache modifier (which ignores metersPerUnit) shows.
        writer.write_frame(inputs.frame, local * plan.scale, cloth.triangles,
                           cloth.corner_uv if self._has_uv else None, velocity * plan.scale, primvars=primvars)
        if writer.staged and inputs.frame > self.start_frame and not self.replacing:
            self._promote()
        self.progress.frame_done(inputs.frame)
        self.progress.tears = tears
        self.progress.vertices = cloth.num_vertices
        if int(st["fragments_removed"]) != self.progress.fragments_removed:
            # tears keep the rest area (splits only divide it): what is gone from it went with the pieces
            self.progress.fragment_area_removed = max(
                0.0, self.progress.start_area - _rest_area(cloth.rest_positions, cloth.triangles))
        self.progress.fragments_removed = int(st["fragments_removed"])
        self.progress.fragment_triangles_removed = int(st["fragment_triangles_removed"])
        if self.on_event is not None:
            self.on_event(BakeEvent("frame", self, inputs.frame))

    @property
    def previous_kept(self) -> bool:
        """After ``close``: a re-bake that did not complete left the previous bake as it was (its
        own frames dropped, or waiting beside it: ``waiting_frames``)."""
        return self.replacing and (not self.writer.frames or self.writer.staged)

    @property
    def kept_frames(self) -> list:
        """After ``close``: the frames at the cache path this job wrote (none for a re-bake that
        did not complete: its frames were dropped, or wait beside the previous bake)."""
        return [] if self.writer.staged else self.writer.frames

    @property
    def waiting_frames(self) -> list:
        """After ``close``: the frames of a re-bake stopped with ``keep_staged`` that wait beside
        the previous bake for a resume (``cache.interrupted_rebake``); [] otherwise."""
        return self.writer.frames if self.writer.staged else []

    def _promote(self) -> None:
        """The new bake moves to the final path (a first bake with its first simulated frame, a
        re-bake once complete), replacing the old one if any. The state file moves
        first: a crash before the cache moves leaves the old cache with a state of an earlier
        frame than its last, which resume refuses as stale (never a wrong continuation)."""
        staged_state = state_path_for(self.writer.path)
        if os.path.exists(staged_state):
            os.replace(staged_state, self.plan.state_path)
        else:
            _remove_quietly(self.plan.state_path)
        _remove_state_temps(staged_state)
        self.writer.promote()

    def close(self, complete: bool | None = None) -> None:
        if complete is None:
            complete = self.done
        if not self.writer.closed:
            if self.writer.staged and complete and self.writer.frames:
                self._promote()
            staged = self.writer.staged
            keep = staged and self.keep_staged and self.replacing and not complete
            self.writer.close(complete=complete, keep_staged=keep)
            if staged and not keep:  # never promoted: the staged bake and its state are gone, the old one stays
                _remove_quietly(state_path_for(staging_path_for(self.plan.cache_path)))


# ---------------------------------------------------------------------------------------------
# The simulated scene of a plan (shared by the bake and the live haptic session)


def make_session(plan: BakePlan, bodies: dict, start_time: float, state: dict | None = None) -> tuple[Session, list]:
    """The ``Session`` a plan describes: the cloth (material, UVs, vertex groups, gravity, solver,
    tearing, weak seams), its pins, its handles held still at their grasp (one per
    ``plan.handle_groups``, returned in that order) and its colliders (``bodies``: collider name ->
    world vertices in metres at ``start_time``). ``state``: a saved bake state to continue from.

    The bake and the live haptic session both build their scene here, so a live session tears the
    same cloth a bake would."""
    if state is None:
        # the attributes the cache carries ride along as vertex-group columns (attributes.py)
        groups = {**plan.groups, **attrs.carried_groups(plan.vertices, plan.attributes)}
        cloth = Cloth(plan.vertices, plan.triangles, plan.material, uv=plan.corner_uv,
                      groups=groups, gravity=plan.solver["gravity"])
    else:
        cloth = Cloth(state["positions"], state["triangles"], plan.material, rest=state["rest"],
                      uv=state["corner_uv"], groups=dict(zip(state["group_names"], state["groups"].T))
                      or None, gravity=plan.solver["gravity"])
    cloth.set_solver(**plan.solver)
    cloth.set_tearing(plan.tearing.get("enabled", True),
                      **{k: v for k, v in plan.tearing.items() if k != "enabled"})
    # the grain override per triangle (a resumed bake's triangles are the state's, torn since)
    grain = plan.grain_angles if state is None else state.get("grain_angles")
    if grain is not None and hasattr(cloth, "set_grain_angles"):
        cloth.set_grain_angles(grain)
    elif state is not None and plan.grain_angles is not None:
        logging.getLogger("tearcloth").warning(
            "%s: the resume state holds no grain angles (this core cannot read them back); the resumed frames "
            "use the material's own grain", plan.object_name)
    if state is not None:
        cloth.set_tear_strength(state["tear_strength"])
    elif plan.seam_group:
        w = cloth.group(plan.seam_group)
        cloth.set_tear_strength(1.0 - w * (1.0 - plan.seam_factor))
    if plan.pin_group:
        cloth.pin_weights(plan.pin_group, plan.pin_stiffness)
    session = Session(cloth, plan.collision, start_time=start_time)
    with warnings.catch_warnings():  # a handle over pins: said in the user's terms by the plan's reports
        warnings.simplefilter("ignore", UserWarning)
        handles = [cloth.add_handle(group) for group in plan.handle_groups]
    for h in handles:
        session.set_handle_keyframe(h, np.eye(4), session.time)
    for name, tris in plan.body_triangles.items():
        session.add_body(name, bodies[name], tris)
    if state is not None:
        # everything else as it was after the state's frame: the native core (velocities, warm
        # start, tear tips, scan position, pair order, handles), collision history, keyframes
        session.restore_state(state["session"])
    return session, handles


# ---------------------------------------------------------------------------------------------
# The state file


def save_state_file(path: str, frame: int, plan: BakePlan, session: Session, tears: int, has_uv: bool,
                    grasp: list, pin_matrix: np.ndarray | None = None) -> None:
    """The full simulation state after ``frame``: the session's (``Session.save_state``), plus the
    mesh arrays a resumed cloth is built from (the restore then replaces its whole state) and the
    handles' grasp matrices of the first frame. ``has_uv``: whether the cache holds UVs (the
    cloth always has a UV array, zeros without a UV map; a resumed bake must write what the
    cache holds)."""
    cloth = session.cloth
    names = list(cloth.group_names)
    groups = cloth.groups
    uv = cloth.corner_uv if has_uv else None
    data = dict(
        version=np.int64(STATE_VERSION),
        frame=np.int64(frame),
        object_name=np.array(plan.object_name),
        fingerprint=np.array(plan.fingerprint or ""),
        positions=np.array(cloth.positions),
        velocities=np.array(cloth.velocities),
        rest=np.array(cloth.rest_positions),
        triangles=np.array(cloth.triangles),
        corner_uv=np.array(uv) if uv is not None and uv.size else np.zeros((0, 3, 2)),
        group_names=np.array(names, dtype=str),
        groups=np.array(groups),
        tear_strength=np.array(cloth.tear_strength),
        tears=np.int64(tears),
        session=np.frombuffer(session.save_state(), np.uint8),
        grasp=np.array([np.full((4, 4), np.nan) if m is None else m for m in grasp], np.float64).reshape(-1, 4, 4),
        # the object's matrix at the first frame, which following pins move from (NaN: none)
        pin_matrix=np.full((4, 4), np.nan) if pin_matrix is None else np.array(pin_matrix, np.float64),
    )
    if plan.grain_angles is not None and hasattr(cloth, "grain_angles"):
        data["grain_angles"] = np.array(cloth.grain_angles)  # per triangle, carried through tears by the core
    folder, name = os.path.split(path)
    tmp = os.path.join(folder, f".tmp-{os.getpid()}-{name}")
    _remove_state_temps(path)  # a killed run's half-written one (SIGKILL while it was written)
    with open(tmp, "wb") as f:
        np.savez(f, **data)
    os.replace(tmp, path)  # atomic: a crash leaves the old state or the new one, never half


def _remove_state_temps(path: str) -> None:
    """Delete the temporaries of the state file ``path`` that runs killed while writing it left."""
    folder, name = os.path.split(path)
    try:
        names = os.listdir(folder)
    except OSError:
        return
    for other in names:
        if other.startswith(".tmp-") and other.endswith("-" + name):
            _remove_quietly(os.path.join(folder, other))


def load_state(path: str) -> dict | None:
    """The saved state, or None if there is none or it cannot be read."""
    try:
        with np.load(path, allow_pickle=False) as z:
            if int(z["version"]) != STATE_VERSION:
                return None
            state = {k: z[k] for k in z.files}
    except (OSError, ValueError, KeyError):
        return None
    state["frame"] = int(state["frame"])
    state["object_name"] = str(state["object_name"])
    state["fingerprint"] = str(state["fingerprint"]) if "fingerprint" in state else ""
    state["group_names"] = [str(n) for n in state["group_names"]]
    if state["corner_uv"].size == 0:
        state["corner_uv"] = None
    state["session"] = state["session"].tobytes()
    return state


def delete_state(cache_path: str) -> None:
    _remove_quietly(state_path_for(cache_path))
    _remove_state_temps(state_path_for(cache_path))


# ---------------------------------------------------------------------------------------------
# The worker thread


def run_worker(job: BakeJob, inputs: "queue.Queue[FrameInputs | None]") -> None:
    """Take frames of inputs from the queue until ``None``, the last frame or a cancel; the job's
    progress says how it ended. Never raises: errors become ``progress.state = 'error'``."""
    progress = job.progress
    try:
        while not job.done:
            item = inputs.get()
            if item is None or job.cancel.is_set():
                break
            if not job.advance(item):
                break
        if job.done:
            progress.state = "done"
        else:
            progress.state = "cancelled"
    except Exception as exc:  # surfaced by the main thread as an ERROR report
        progress.message = str(exc)
        progress.state = "error"
    finally:
        try:
            job.close()
        except Exception as exc:
            if progress.state != "error":
                progress.message = f"could not finish the cache: {exc}"
                progress.state = "error"


def start_worker(job: BakeJob) -> tuple[threading.Thread, "queue.Queue"]:
    q: queue.Queue = queue.Queue()
    thread = threading.Thread(target=run_worker, args=(job, q), name=f"tearcloth-bake-{job.plan.object_name}",
                              daemon=True)
    thread.start()
    return thread, q


# ---------------------------------------------------------------------------------------------
# Progress as text on a stream (the headless bake's one reporter)


class ProgressLine:
    """One progress line per object: rewritten in place (carriage return) on a terminal,
    printed every 10 % to a log file or a pipe. ``update(progress, index, count)`` after each
    frame; ``end()`` closes an open line before anything else is printed."""

    WIDTH = 24

    def __init__(self, stream=None):
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.open = False
        self._last = 0.0
        self._last_decile = -1
        self._length = 0

    def text(self, p: Progress, index: int, count: int) -> str:
        filled = int(round(p.factor * self.WIDTH))
        bar = "#" * filled + "-" * (self.WIDTH - filled)
        return f"[{bar}] {index}/{count} {p.text(elapsed=True)}"

    def update(self, p: Progress, index: int, count: int, final: bool = False) -> None:
        now = time.perf_counter()
        if self.tty:
            if not final and now - self._last < 0.1:
                return
            line = self.text(p, index, count)
            pad = max(0, self._length - len(line))
            self.stream.write("\r" + line + " " * pad)
            self._length = len(line)
            self.open = True
            if final:
                self.end()
        else:
            decile = int(p.factor * 10)
            if decile > self._last_decile or (final and decile < 10):
                self._last_decile = decile
                self.stream.write(self.text(p, index, count) + "\n")
        self.stream.flush()
        self._last = now

    def end(self) -> None:
        if self.open:
            self.stream.write("\n")
            self.stream.flush()
            self.open = False
            self._length = 0
        self._last_decile = -1

    def log_handler(self, prog: str) -> logging.Handler:
        """A logging handler that prints warnings as ``<prog>: warning: ...`` on their own line,
        even while a progress line is open."""
        return _LogBesideProgress(self, prog)


class _LogBesideProgress(logging.Handler):
    """Warnings and notes beside the progress line. Errors are not printed here: they come back
    as exceptions or results and are printed once, by the caller."""

    def __init__(self, progress: ProgressLine, prog: str):
        super().__init__(logging.WARNING)
        self.progress = progress
        self.prog = prog

    def emit(self, record):
        if record.levelno >= logging.ERROR:
            return
        self.progress.end()
        self.progress.stream.write(f"{self.prog}: {record.levelname.lower()}: {record.getMessage()}\n")
        self.progress.stream.flush()
