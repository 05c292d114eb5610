"""Baking from Blender: validation, gathering per-frame inputs on the main thread, the modal bake
with its worker thread, the synchronous ``bake_object``, freeing a bake.

Threads: bpy is not thread-safe, so everything that reads Blender data (the cloth's rest mesh,
collider meshes and follow-object matrices at each frame) happens here, on the main thread, and
reaches the worker as plain arrays (``bake_job.FrameInputs``) through a queue. The worker only
runs ``BakeJob.advance`` (the native step releases the GIL; the cache writer is pure USD). The
modal operator's TIMER tick gathers a few frames ahead (``scene.frame_set`` + the evaluated
depsgraph), shows progress and notices the end; nothing bpy is held across ticks but names, so
undo, file loads and deleted objects cannot leave the bake with a dangling pointer.

``bake_object`` runs the same ``BakeJob`` inline (headless ``tearcloth bake``, tests, and the
operators' ``execute`` when run from a script).
"""
from __future__ import annotations

import os
import tempfile
import time
from dataclasses import dataclass, field

import bpy
import numpy as np

from .. import cache
from ..cloth import ClothError
from . import convert, modifier
from .bake_job import BakeJob, BakePlan, FrameInputs, Progress, delete_state, start_worker
from .props import COLLIDER_TYPES
from .report import BakeError, Reports, log, not_a_mesh, object_kind

# Frames gathered ahead of the worker: enough to keep it busy between two ticks, few enough that
# collider meshes in the queue stay small.
QUEUE_AHEAD = 4
# Main-thread time per tick spent gathering inputs (seconds), so the UI stays responsive.
GATHER_BUDGET = 0.05
TIMER_INTERVAL = 0.1
# Refresh the viewport's view of the growing cache at most this often (seconds).
PREVIEW_INTERVAL = 1.0

# Bakes in progress, by object name: read by the panel and the status bar, stopped on file load.
running: dict[str, "BakeRun"] = {}


@dataclass
class Sources:
    """Names of the Blender data a bake reads every frame (names, never bpy pointers)."""

    object_name: str
    follow_names: list = field(default_factory=list)   # per handle: object name or None
    collider_names: list = field(default_factory=list)


# ---------------------------------------------------------------------------------------------
# Validation: Blender scene -> BakePlan


def _collider_objects(obj, settings, reports: Reports) -> list:
    found = []
    for i, item in enumerate(settings.colliders):
        if item.object is None:
            reports.warning(f"{obj.name}: collider slot {i + 1} is empty (its object was deleted?); skipped")
        else:
            found.append(item.object)
    if settings.collider_collection is not None:
        found += list(settings.collider_collection.all_objects)
    colliders, seen = [], set()
    for other in found:
        if other.name in seen:
            continue
        seen.add(other.name)
        if other is obj:
            reports.warning(f"{obj.name}: the cloth is in its own collider list; self collision is a separate "
                            "setting. Skipped")
        elif other.type not in COLLIDER_TYPES:
            reports.warning(f"{obj.name}: collider {other.name!r} is {object_kind(other.type)} without a surface; skipped")
        else:
            colliders.append(other)
    return colliders


def _input_mesh(context, obj, reports: Reports, group_names) -> convert.MeshArrays | None:
    """The cloth's rest mesh: the object's mesh as evaluated by the modifiers ABOVE "Tear Cloth"
    (like Blender's Cloth modifier). Those below, and Tear Cloth itself, are switched off for the
    one evaluation and switched back on."""
    if obj.mode == "EDIT":
        obj.update_from_editmode()
    md = modifier.find_modifier(obj)
    mods = list(obj.modifiers)
    index = mods.index(md)
    above = [m for m in mods[:index] if m.show_viewport]
    try:
        # Shape keys are evaluated like modifiers: their mix, not the basis, is the rest shape.
        if not above and obj.data.shape_keys is None:
            return convert.read_mesh(obj.data, vertex_groups=obj.vertex_groups, group_names=group_names)
        switched = [m for m in mods[index:] if m.show_viewport]
        try:
            for m in switched:
                m.show_viewport = False
            depsgraph = context.evaluated_depsgraph_get()
            return convert.evaluated_mesh_arrays(obj, depsgraph, vertex_groups=obj.vertex_groups,
                                                 group_names=group_names)
        finally:
            for m in switched:
                m.show_viewport = True
    except KeyError as exc:
        reports.error(f"{obj.name}: vertex group {exc.args[0]!r} does not exist")
        return None


def build_plan(context, obj, frame_start=None, frame_end=None, resume=False,
               reports: Reports | None = None, *, hands: dict | None = None,
               with_cache: bool = True) -> tuple[BakePlan, Sources]:
    """Check everything a bake of ``obj`` needs and gather it. Every problem goes into
    ``reports`` (and the log); BakeError if any is an error. Changes nothing in the scene (when
    everything else is right it creates a missing cache folder).

    For a live haptic session: ``hands`` maps each hand to the vertex group it grasps (checked
    like a handle's; the bake handles on the same groups are left to the hands, the others hold
    still) and the frame range is not checked; ``with_cache=False`` skips the cache location
    (nothing is recorded)."""
    reports = reports if reports is not None else Reports()
    if obj is None:
        reports.error("no active object: select the mesh to tear")
        reports.raise_if_errors()
    if obj.type != "MESH":
        reports.error(not_a_mesh(obj))
        reports.raise_if_errors()
    if not modifier.is_enabled(obj):
        reports.error(f"Tear Cloth is not enabled on {obj.name!r} (Properties > Physics > Tear Cloth), "
                      f"or its {modifier.MODIFIER_NAME!r} modifier was removed or renamed")
        reports.raise_if_errors()
    scene = context.scene
    settings = obj.tearcloth
    scale = convert.scale_length(scene)
    start = settings.frame_start if frame_start is None else int(frame_start)
    end = settings.frame_end if frame_end is None else int(frame_end)
    if end <= start and hands is None:
        reports.error(f"{obj.name}: the bake's end frame ({end}) must come after its start frame ({start})")

    material = collision = None
    try:
        material = convert.material_from_settings(settings, scene)
    except ValueError as exc:
        reports.error(f"{obj.name}: {exc}")
    colliders = _collider_objects(obj, settings, reports) if settings.use_collision else []
    if settings.use_collision and (colliders or settings.use_self_collision):
        try:
            collision = convert.collision_from_settings(settings, scene)
        except ValueError as exc:
            reports.error(f"{obj.name}: {exc}")

    # vertex groups: every name must exist on the object (renamed or deleted ones are reported)
    wanted = []
    hand_groups = dict(hands or {})
    # In a live session a hand takes over the bake handle on its group; the other handles hold still.
    handles = [(i, h) for i, h in enumerate(settings.handles) if h.vertex_group not in hand_groups.values()
               or not h.vertex_group]
    roles = [("pins", settings.pin_group)] + [(f"handle {i + 1}", h.vertex_group) for i, h in handles]
    roles += [(f"the {hand} hand", group) for hand, group in hand_groups.items()]
    roles.append(("weak seams", settings.seam_group))
    for role, name in roles:
        if role.startswith("handle") and not name:
            reports.error(f"{obj.name}: {role} has no vertex group; choose one or remove the handle")
        elif role.startswith("the ") and not name:
            reports.error(f"{obj.name}: {role} grasps no vertex group; choose its Handle Group "
                          "(Physics > Tear Cloth > Haptics)")
        elif name and name not in obj.vertex_groups:
            reports.error(f"{obj.name}: vertex group {name!r} ({role}) does not exist (renamed or deleted?)")
        elif name and name not in wanted:
            wanted.append(name)
    follow = []
    for i, h in handles:
        follow.append(h.follow.name if h.follow is not None else None)
        if hands is not None and h.follow is not None:
            reports.warning(f"{obj.name}: handle {i + 1} follows {h.follow.name!r}, but the scene's time stands "
                            "still during a live session: the handle holds still")

    reports.raise_if_errors()

    # The cache location last: checking it may create the folder, which only a bake should do.
    path = None
    if with_cache:
        try:
            path = modifier.cache_path(obj)
        except BakeError as exc:
            reports.error(f"{obj.name}: {exc}")
        if path is not None:
            _check_cache_location(obj, path, resume, reports)
    reports.raise_if_errors()

    mesh = _input_mesh(context, obj, reports, wanted)
    reports.raise_if_errors()
    if len(mesh.triangles) == 0:
        reports.error(f"{obj.name}: the mesh has no faces to simulate")
        reports.raise_if_errors()
    if mesh.ngons:
        reports.warning(f"{obj.name}: {mesh.ngons} n-gon{'s' if mesh.ngons != 1 else ''} triangulated for the "
                        "solver (your mesh is unchanged); triangulate them yourself to choose the diagonals")
    if mesh.loose:
        reports.warning(f"{obj.name}: {mesh.loose} loose {'vertices' if mesh.loose != 1 else 'vertex'} (in no face) "
                        "left out of the simulation")

    pinned = 0
    if settings.pin_group:
        pinned = int(np.count_nonzero(mesh.groups[settings.pin_group] >= 0.5))
        if pinned == 0:
            reports.warning(f"{obj.name}: pin group {settings.pin_group!r} has no vertex with weight 0.5 or more; "
                            "nothing is pinned")
    for i, h in handles:
        if not np.any(mesh.groups[h.vertex_group] >= 0.5):
            reports.error(f"{obj.name}: handle {i + 1}: vertex group {h.vertex_group!r} has no vertex with "
                          "weight 0.5 or more, so it grasps nothing")
    for hand, group in hand_groups.items():
        if not np.any(mesh.groups[group] >= 0.5):
            reports.error(f"{obj.name}: the {hand} hand's vertex group {group!r} has no vertex with weight 0.5 or "
                          "more, so it grasps nothing")
    depsgraph = context.evaluated_depsgraph_get()
    body_triangles = {}
    for other in colliders:
        triangles = convert.collider_world_si(other, depsgraph, scale)[1]
        if len(triangles):
            body_triangles[other.name] = triangles
        else:
            reports.warning(f"{obj.name}: collider {other.name!r} has no faces; skipped")
    if collision is not None and not body_triangles and not collision.self_collision:
        collision = None  # nothing left to collide with
    if not pinned and not handles and not hand_groups and not body_triangles:
        reports.warning(f"{obj.name}: no pins, handles or colliders: the cloth falls freely under gravity")
    reports.raise_if_errors()

    matrix = convert.matrix_array(obj.evaluated_get(depsgraph).matrix_world)
    plan = BakePlan(
        object_name=obj.name,
        prim_name=modifier.prim_name_for(obj.name),
        cache_path=path,
        fps=convert.fps(scene),
        frame_start=start,
        frame_end=end,
        steps_per_frame=int(settings.steps_per_frame),
        scale=scale,
        material=material,
        solver=convert.solver_from_settings(settings, scene),
        tearing=convert.tearing_from_settings(settings),
        collision=collision,
        vertices=convert.local_to_world_si(mesh.vertices, matrix, scale),
        triangles=mesh.triangles,
        corner_uv=mesh.corner_uv,
        groups=mesh.groups,
        fingerprint=cache.mesh_fingerprint(mesh.vertices * scale, mesh.triangles),
        pin_group=settings.pin_group or None,
        handle_groups=[h.vertex_group for _, h in handles],
        seam_group=settings.seam_group or None,
        seam_factor=float(settings.seam_factor),
        body_triangles=body_triangles,
        resume=bool(resume),
        hand_groups=hand_groups,
    )
    sources = Sources(obj.name, follow, list(body_triangles))
    return plan, sources


def _check_cache_location(obj, path: str, resume: bool, reports: Reports) -> None:
    folder = os.path.dirname(path)
    if os.path.exists(folder) and not os.path.isdir(folder):
        reports.error(f"{obj.name}: the cache folder {folder} is a file, not a folder")
        return
    if not os.path.isdir(folder):
        try:
            os.makedirs(folder)
            reports.info(f"{obj.name}: created the cache folder {folder}")
        except OSError as exc:
            reports.error(f"{obj.name}: cannot create the cache folder {folder}: {exc.strerror or exc}")
            return
    # A real write, not os.access: that says yes to root on a read-only mount.
    try:
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as exc:
        reports.error(f"{obj.name}: the cache folder {folder} is not writable ({exc.strerror or exc}); "
                      "choose another folder")
        return
    if resume:
        if not os.path.exists(path):
            attached = modifier.attached_path(obj)
            if attached is not None and os.path.exists(attached):
                reports.error(f"{obj.name}: the object was renamed since its bake (its modifier plays {attached}); "
                              "a bake cannot be resumed under another name: bake again, or free the old bake")
            else:
                reports.error(f"{obj.name}: there is no bake to resume at {path}")
            return
        try:
            info = cache.check_owner(path, obj.name)
        except cache.CacheError as exc:
            reports.error(f"{obj.name}: cannot resume: {exc}")
            return
        if info["frames"] and info["frames"][-1] >= obj.tearcloth.frame_end and info["complete"]:
            reports.error(f"{obj.name}: the bake is complete up to frame {info['frames'][-1]}; nothing to resume")
    elif os.path.lexists(path):
        try:
            cache.check_owner(path, obj.name)
        except cache.CacheOwnerError as exc:
            reports.error(f"{obj.name}: {exc}. It was left untouched: free it from that object, or choose "
                          "another cache folder")
        except cache.CacheError as exc:
            # A Tear Cloth cache that lost frames is damaged, and a new bake replaces it; anything
            # else (not USD, not ours) is refused here and left as it is.
            if "frames missing" not in str(exc):
                reports.error(f"{obj.name}: {exc}. It was left untouched: move it away or choose another "
                              "cache folder")


# ---------------------------------------------------------------------------------------------
# Per-frame inputs (main thread)


def gather_inputs(context, sources: Sources, frame: int, scale: float) -> FrameInputs:
    """Move the scene to ``frame`` and copy out what the bake needs of it."""
    # Always frame_set, even on the current frame: animation is evaluated by a frame change, and
    # a value set by a script since the last one (a location under a keyframe) is not the frame's.
    context.scene.frame_set(frame)
    depsgraph = context.evaluated_depsgraph_get()
    objects = bpy.data.objects
    obj = objects.get(sources.object_name)
    if obj is None:
        raise BakeError(f"object {sources.object_name!r} was deleted or renamed during the bake")
    matrices = []
    for name in sources.follow_names:
        if name is None:
            matrices.append(None)
            continue
        follow = objects.get(name)
        if follow is None:
            raise BakeError(f"{sources.object_name}: the handle's follow object {name!r} was deleted or renamed")
        matrices.append(convert.matrix_array(follow.evaluated_get(depsgraph).matrix_world))
    bodies = {}
    for name in sources.collider_names:
        other = objects.get(name)
        if other is None:
            raise BakeError(f"{sources.object_name}: collider {name!r} was deleted or renamed during the bake")
        bodies[name] = convert.collider_world_si(other, depsgraph, scale)[0]
    return FrameInputs(frame, convert.matrix_array(obj.evaluated_get(depsgraph).matrix_world), matrices, bodies)


# ---------------------------------------------------------------------------------------------
# One object's bake


class BakeRun:
    """One object's bake: plan, job, and (for the modal operator) the worker thread.

    The constructor validates and opens the cache (BakeError with the reports on failure: the
    scene is unchanged then); ``start`` builds the simulation at its first frame.
    """

    def __init__(self, context, obj, frame_start=None, frame_end=None, resume=False, reports=None):
        self.reports = reports if reports is not None else Reports()
        scene = context.scene
        self.scene_name = scene.name
        self.original_frame = scene.frame_current
        self.thread = None
        self.queue = None
        self.next_gather = None
        self._last_preview = 0.0
        self._previewed = None
        self.abandoned = False  # stopped by a file load: the data it knew is gone
        if obj is not None and obj.name in running:
            self.reports.error(f"{obj.name}: a bake of this object is already running")
            self.reports.raise_if_errors()
        if obj is not None and obj.name in live_sessions():
            self.reports.error(f"{obj.name}: a live haptic session is running on this object; stop it first (Esc)")
            self.reports.raise_if_errors()
        try:
            # The rest state is the scene at the first frame (object matrix, modifiers above).
            if obj is not None and obj.type == "MESH":
                first = obj.tearcloth.frame_start if frame_start is None else int(frame_start)
                scene.frame_set(first)
            self.plan, self.sources = build_plan(context, obj, frame_start, frame_end, resume, self.reports)
            self.object_name = obj.name
            self.progress = Progress(obj.name, self.plan.frame_start, self.plan.frame_end)
            # Blender must let go of the old cache before the writer deletes or rewrites it.
            modifier.detach_cache(obj)
            try:
                self.job = BakeJob(self.plan, self.progress)
            except (cache.CacheError, ValueError, OSError) as exc:
                self.reports.error(f"{obj.name}: {exc}")
                self._reattach_existing(obj)
                self.reports.raise_if_errors()
        except BaseException:
            if scene.frame_current != self.original_frame:
                scene.frame_set(self.original_frame)
            raise

    def _reattach_existing(self, obj) -> None:
        try:
            cache.cache_info(self.plan.cache_path)
        except cache.CacheError:
            return
        modifier.attach_cache(obj, self.plan.cache_path, self.plan.prim_name)

    # -- shared by both ways of running ---------------------------------------------------------

    def start(self, context) -> None:
        running[self.object_name] = self
        try:
            inputs = gather_inputs(context, self.sources, self.job.start_frame,
                                   self.plan.scale)
            self.job.begin(inputs)
        except (BakeError, ClothError, ValueError, cache.CacheError) as exc:
            self.progress.state, self.progress.message = "error", str(exc)
            self.job.close(complete=False)
        self.next_gather = self.job.next_frame
        if self.job.start_frame > self.plan.frame_start:
            self.reports.info(f"{self.object_name}: resuming after frame {self.job.start_frame}")

    def finish(self, context) -> str:
        """Close the cache, show it on the modifier, put the scene back on its frame; returns the
        final state ('done', 'cancelled' or 'error') after adding the matching report."""
        running.pop(self.object_name, None)
        try:
            self.job.close()
        except Exception as exc:  # the cache keeps every frame it had; say why it is not closed
            self.progress.state, self.progress.message = "error", f"could not finish the cache: {exc}"
        frames = self.job.writer.frames
        if self.abandoned:  # another file is open now: touch none of its data
            self.reports.warning(f"{self.object_name}: bake stopped by loading another file; "
                                 + (f"frames {frames[0]}-{frames[-1]} kept" if frames else "no frame written"))
            return "cancelled"
        scene = bpy.data.scenes.get(self.scene_name)
        if scene is not None and scene.frame_current != self.original_frame:
            scene.frame_set(self.original_frame)
        obj = bpy.data.objects.get(self.object_name)
        if obj is not None and frames and modifier.is_enabled(obj):
            try:
                modifier.attach_cache(obj, self.plan.cache_path, self.plan.prim_name)
            except BakeError as exc:
                self.reports.error(str(exc))
        p = self.progress
        kept = f"frames {frames[0]}-{frames[-1]} kept" if frames else "no frame written"
        if p.state == "done":
            self.reports.info(f"{self.object_name}: baked frames {frames[0]}-{frames[-1]} "
                              f"({p.tears} tear{'s' if p.tears != 1 else ''}, {p.vertices} vertices at the end) "
                              f"into {self.plan.cache_path}")
        elif p.state == "cancelled":
            self.reports.warning(f"{self.object_name}: bake cancelled; {kept}. Resume continues it")
        else:
            p.state = "error"
            self.reports.error(f"{self.object_name}: bake stopped: {p.message}; {kept}")
        return p.state

    # -- inline (bake_object) ------------------------------------------------------------------

    def run_inline(self, context, progress=None) -> str:
        self.start(context)
        try:
            while self.progress.state == "running" and not self.job.done:
                try:
                    inputs = gather_inputs(context, self.sources, self.job.next_frame,
                                           self.plan.scale)
                    self.job.advance(inputs)
                except (BakeError, ClothError, ValueError, cache.CacheError) as exc:
                    self.progress.state, self.progress.message = "error", str(exc)
                    break
                if progress is not None and progress(self.progress) is False:
                    self.progress.state = "cancelled"
            if self.progress.state == "running":
                self.progress.state = "done"
        except KeyboardInterrupt:
            self.progress.state = "cancelled"
            raise
        finally:
            self.finish(context)
        return self.progress.state

    # -- threaded (the modal operator) ---------------------------------------------------------

    def start_thread(self, context) -> None:
        self.start(context)
        if self.progress.state == "running" and not self.job.done:
            self.thread, self.queue = start_worker(self.job)
        elif self.progress.state == "running":
            self.progress.state = "done"

    def tick(self, context) -> bool:
        """Feed the worker and refresh the preview; True while the bake is still running."""
        if self.thread is None:
            return False
        if not self.thread.is_alive():
            return False
        start = time.perf_counter()
        try:
            while (self.next_gather <= self.plan.frame_end and self.queue.qsize() < QUEUE_AHEAD
                   and time.perf_counter() - start < GATHER_BUDGET):
                inputs = gather_inputs(context, self.sources, self.next_gather,
                                       self.plan.scale)
                self.queue.put(inputs)
                self.next_gather += 1
        except (BakeError, ValueError) as exc:
            self.progress.message = str(exc)
            self.stop(state="error")
            return False
        self._preview()
        return True

    def _preview(self) -> None:
        """Show the frames baked so far (at most once a second: reopening the stage costs)."""
        now = time.perf_counter()
        frame = self.progress.frame
        if frame is None or frame == self._previewed or now - self._last_preview < PREVIEW_INTERVAL:
            return
        obj = bpy.data.objects.get(self.object_name)
        if obj is not None and modifier.is_enabled(obj):
            try:
                modifier.attach_cache(obj, self.plan.cache_path, self.plan.prim_name)
            except BakeError:
                pass  # only a preview; finish() reports if the cache cannot be attached at the end
        self._previewed, self._last_preview = frame, now

    def stop(self, state: str = "cancelled", timeout: float = 30.0) -> None:
        """Cancel: the worker ends after its current step (a started frame is dropped)."""
        self.job.cancel.set()
        if self.queue is not None:
            self.queue.put(None)
        if self.thread is not None:
            self.thread.join(timeout)
        if state == "error" or self.progress.state == "running":
            self.progress.state = state


@dataclass
class BakeResult:
    state: str                # 'done', 'cancelled' or 'error'
    cache_path: str
    frames: list
    progress: Progress
    reports: Reports


def bake_object(context, obj, frame_start=None, frame_end=None, progress=None, *, resume=False,
                reports: Reports | None = None) -> BakeResult:
    """Bake ``obj`` from ``frame_start`` to ``frame_end`` (default: its settings) inline, on the
    calling thread: the same ``BakeJob`` the modal operator runs on its worker.

    ``progress(Progress)`` is called after every frame; returning False stops the bake (the
    frames written so far are kept). ``resume=True`` continues an interrupted bake. Raises
    ``BakeError`` (scene unchanged) when the bake cannot start; otherwise returns a
    ``BakeResult`` whose ``state`` says how it ended and whose ``reports`` hold every message
    (also logged under the "tearcloth" logger).
    """
    run = BakeRun(context, obj, frame_start, frame_end, resume, reports)
    state = run.run_inline(context, progress)
    return BakeResult(state, run.plan.cache_path, run.job.writer.frames, run.progress, run.reports)


def free_bake(obj, reports: Reports) -> bool:
    """Delete the object's cache (root, frames, resume state) and let the modifier show the rest
    mesh again. False (with an error report) if it cannot."""
    if obj.name in running:
        reports.error(f"{obj.name}: cannot free while its bake is running; cancel it first (Esc)")
        return False
    if obj.name in live_sessions():
        reports.error(f"{obj.name}: cannot free while a live haptic session runs on it; stop it first (Esc)")
        return False
    try:
        path = modifier.cache_path(obj)
    except BakeError as exc:
        path = modifier.attached_path(obj)
        if path is None:
            reports.error(f"{obj.name}: {exc}")
            return False
    attached = modifier.attached_path(obj)
    if attached is not None and os.path.normcase(attached) != os.path.normcase(path):
        # The object was renamed (or its folder changed) since the bake: free what it plays.
        path = attached
    elif os.path.lexists(path):
        try:
            cache.check_owner(path, obj.name)
        except cache.CacheOwnerError as exc:
            reports.error(f"{obj.name}: {exc}; left untouched")
            return False
        except cache.CacheError:
            pass  # damaged: delete_cache below still refuses anything that is not a Tear Cloth cache
    modifier.detach_cache(obj)
    try:
        cache.delete_cache(path)
    except cache.CacheError as exc:
        reports.error(f"{obj.name}: {exc}; left untouched")
        return False
    delete_state(path)
    reports.info(f"{obj.name}: freed the bake at {path}")
    return True


def stop_all(reason: str) -> None:
    """Stop every running bake, keeping their frames (before a file load, on unregister)."""
    for run in list(running.values()):
        log.warning("%s: stopping the bake (%s); frames baked so far are kept", run.object_name, reason)
        run.abandoned = True
        run.stop()
        running.pop(run.object_name, None)
        try:
            run.job.close()
        except Exception as exc:
            log.error("%s: could not finish the cache: %s", run.object_name, exc)


def live_sessions() -> dict:
    """Live haptic sessions in progress, by object name (they own the object's mesh and cache)."""
    from . import haptic_session  # imported late: haptic_session builds on this module

    return haptic_session.running


def progress_of(object_name: str) -> Progress | None:
    run = running.get(object_name)
    return run.progress if run is not None else None
