"""Baking from Blender: ``BakeRun`` (one object's bake, inline or as the modal bake with its worker
thread), the synchronous ``bake_object``, freeing a bake, stopping every bake.

Threads: bpy is not thread-safe, so everything that reads Blender data (the cloth's rest mesh,
collider meshes and follow-object matrices at each frame) happens on the main thread
(``inputs.build_plan``, ``inputs.gather_inputs``) and reaches the worker as plain arrays
(``tearcloth.bake.FrameInputs``) through a queue. The worker only runs ``BakeJob.advance`` (the
native step releases the GIL; the cache writer is pure USD). The modal operator's TIMER tick
gathers a few frames ahead (``scene.frame_set`` + the evaluated depsgraph), shows progress and
notices the end; nothing bpy is held across ticks but names, so undo, file loads and deleted
objects cannot leave the bake with a dangling pointer.

``bake_object`` runs the same ``BakeJob`` inline (headless ``tearcloth bake``, tests, and the
operators' ``execute`` when run from a script). Running bakes are registered in ``jobs`` (with
the live sessions); ``running`` here is that registry's read-only view of the bakes.
"""
from __future__ import annotations

import os
import time
import warnings
from dataclasses import dataclass

import bpy

from .. import cache
from ..bake import BakeJob, Progress, delete_state, frame_span, start_worker
from ..cloth import ClothError
from . import jobs, modifier
from .inputs import build_plan, gather_inputs
from .report import BakeError, Reports, linked_from, log, user_culprits, user_geometry_message

# Frames gathered ahead of the worker: enough to keep it busy between two ticks, few enough that
# collider meshes in the queue stay small.
QUEUE_AHEAD = 4
# Main-thread time per tick spent gathering inputs (seconds), so the UI stays responsive.
GATHER_BUDGET = 0.05
TIMER_INTERVAL = 0.1
# Refresh the viewport's view of the growing cache at most this often (seconds).
PREVIEW_INTERVAL = 1.0

# Bakes in progress, by object name (read-only): read by the panel and the status bar.
running = jobs.bakes


# ---------------------------------------------------------------------------------------------
# One object's bake


class BakeRun:
    """One object's bake: plan, job, and (for the modal operator) the worker thread.

    The constructor validates and opens the cache (BakeError with the reports on failure: the
    scene is unchanged then); ``start`` builds the simulation at its first frame. ``on_event``
    receives the job's ``BakeEvent``s (on the thread that runs the job).
    """

    kind = jobs.BAKE

    def __init__(self, context, obj, frame_start=None, frame_end=None, resume=False, reports=None,
                 on_event=None):
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
        linked = linked_from(obj) if obj is not None else None
        if linked:
            self.reports.error(linked)
            self.reports.raise_if_errors()
        if obj is not None and obj.name in jobs.bakes:
            self.reports.error(f"{obj.name}: a bake of this object is already running")
            self.reports.raise_if_errors()
        if obj is not None and obj.name in jobs.live_sessions:
            self.reports.error(f"{obj.name}: a live haptic session is running on this object; stop it first (Esc)")
            self.reports.raise_if_errors()
        self.created_folders: list = []  # cache folders this attempt made (removed again if it fails)
        # the persistent id the plan may give the object (its first bake): a refused attempt takes
        # it back, so a failure leaves the object as it was
        id_before = modifier.object_id(obj) if obj is not None and obj.type == "MESH" else None
        try:
            # The rest state is the scene at the first frame (object matrix, modifiers above).
            if obj is not None and obj.type == "MESH":
                first = obj.tearcloth.frame_start if frame_start is None else int(frame_start)
                scene.frame_set(first)
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                try:
                    self.plan, self.sources = build_plan(context, obj, frame_start, frame_end, resume, self.reports)
                except BakeError:
                    raise
                except Exception as exc:  # a bug: a report (and the frame restored), not a traceback
                    self.reports.error(f"{getattr(obj, 'name', '?')}: internal error while checking the bake "
                                       f"({type(exc).__name__}: {exc}); please report it")
                    self.reports.raise_if_errors()
            self.object_name = obj.name  # before the warnings: they are said with the object's name
            self._report_warnings(caught)
            self.progress = Progress(obj.name, self.plan.frame_start, self.plan.frame_end)
            self.created_folders = _missing_folders(os.path.dirname(self.plan.cache_path))
            # Blender must let go of the old cache before the writer deletes or rewrites it. What
            # it played is noted first: a bake that writes nothing shows it again (_reattach_existing)
            md = modifier.find_modifier(obj)
            self._attached_before = ((modifier.attached_path(obj), md.object_path.lstrip("/"))
                                     if md is not None and md.cache_file is not None else None)
            modifier.detach_cache(obj)
            try:
                self.job = BakeJob(self.plan, self.progress, on_event)
            except Exception as exc:
                self.reports.error(f"{obj.name}: {exc}" if isinstance(exc, (cache.CacheError, ValueError, OSError))
                                   else f"{obj.name}: internal error ({type(exc).__name__}: {exc})")
                self._remove_created_folders()
                self._reattach_existing(obj)
                self.reports.raise_if_errors()
        except BaseException:
            if scene.frame_current != self.original_frame:
                scene.frame_set(self.original_frame)
            if id_before is not None and modifier.object_id(obj) != id_before:
                if id_before:
                    obj[modifier.ID_PROPERTY] = id_before
                elif modifier.ID_PROPERTY in obj:
                    del obj[modifier.ID_PROPERTY]
            raise

    def _report_warnings(self, caught) -> None:
        """Python warnings raised below (an open collider, ...) become reports: the operator
        shows them and the headless bake logs them, instead of a line on stderr only."""
        for w in caught:
            self.reports.warning(f"{self.object_name if hasattr(self, 'object_name') else ''}: {w.message}"
                                 .lstrip(": "))

    def _attached_elsewhere(self) -> str | None:
        """The cache the modifier played before this attempt when it is a bake at another path than
        this one's and still on disk (the object renamed since, or its cache folder changed), else
        None."""
        before = getattr(self, "_attached_before", None)
        if before is None or not os.path.isfile(before[0]):
            return None
        same = os.path.normcase(os.path.abspath(before[0])) == os.path.normcase(os.path.abspath(self.plan.cache_path))
        return None if same else before[0]

    def _reattach_existing(self, obj) -> bool:
        """Show the cache that is at the object's path again (the previous bake a failed or
        cancelled re-bake left as it was), else the one the modifier played before this attempt
        (a bake another file's folder holds, after Save As); False if there is neither."""
        try:
            cache.check_owner(self.plan.cache_path, obj.name, object_id=self.plan.object_id)
            path, prim = self.plan.cache_path, self.plan.prim_name
        except cache.CacheError:
            if self._attached_elsewhere() is None:
                return False
            path, prim = self._attached_before
        return self._attach(obj, path, prim)

    def _attach(self, obj, path: str, prim: str) -> bool:
        """Show a cache on the object's modifier; a failure is an error report (False)."""
        try:
            modifier.attach_cache(obj, path, prim)
        except BakeError as exc:
            self.reports.error(str(exc))
            return False
        return True

    def _remove_created_folders(self) -> None:
        """Remove the cache folders this attempt created, if they are still empty: a failed
        attempt leaves nothing behind, and nothing it did not make is touched."""
        for folder in reversed(self.created_folders):
            try:
                os.rmdir(folder)
            except OSError:
                break  # not empty (or not ours any more): keep it and its parents
        self.created_folders = []

    # -- shared by both ways of running ---------------------------------------------------------

    def start(self, context) -> None:
        """Build the simulation at the first frame. Never raises: a failure is the progress's
        'error' state, and ``finish`` (which every way of running calls) cleans up."""
        jobs.add(self)
        try:
            inputs = gather_inputs(context, self.sources, self.job.start_frame,
                                   self.plan.scale)
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                self.job.begin(inputs)
            self._report_warnings(caught)
        except (BakeError, ClothError, ValueError, cache.CacheError) as exc:
            self.progress.state, self.progress.message = "error", self._user_message(exc)
        except Exception as exc:  # a bug: still a clean stop (registry, frame, files), named as such
            self.progress.state = "error"
            self.progress.message = f"internal error ({type(exc).__name__}: {exc})"
        self.next_gather = self.job.next_frame
        if self.progress.state == "running" and self.job.start_frame > self.plan.frame_start:
            self.reports.info(f"{self.object_name}: resuming after frame {self.job.start_frame}")

    def _user_message(self, exc: Exception) -> str:
        """The core's words about the mesh in the user's polygon and vertex indices (the solver's
        triangles are the user's polygons triangulated, loose vertices left out); the elements it
        names are kept for ``finish`` to select. Only a fresh start has the user's numbering; a
        resumed cloth may be torn already."""
        text = str(exc)
        if self.job.resumed:
            return text
        self.culprits = user_culprits(exc, self.plan.triangle_polygons, self.plan.vertex_ids)
        text = user_geometry_message(text, self.plan.triangle_polygons, self.plan.vertex_ids, self.culprits)
        if self.plan.renumbered_by and any(self.culprits):
            # the numbers are those of the mesh the modifiers above make, not of the user's: said,
            # and nothing of the user's mesh is selected under them
            self.culprits = ([], [])
            text += (f" (numbered in the mesh the modifiers above Tear Cloth make: "
                     f"{', '.join(self.plan.renumbered_by)}; apply or disable them to see it in your mesh)")
        return text

    def _select_culprits(self, obj) -> None:
        """Select the polygons and vertices a refused mesh names, alone, so the user sees them
        (Object Mode: in Edit Mode the edit mesh would overwrite the selection)."""
        polys, verts = self.culprits
        me = obj.data
        if obj.mode != "OBJECT" or not hasattr(me, "polygons"):
            return
        # item by item, and no edges: foreach_set("select") and an edge's select crashed bpy 5.0
        # on a mesh that had no edge selection yet (Edit Mode flushes edges from the vertices)
        for items, chosen in ((me.polygons, set(polys)), (me.vertices, set(verts))):
            for item in items:
                item.select = item.index in chosen
        for p in polys:  # a polygon is selected with its corners
            if 0 <= p < len(me.polygons):
                for v in me.polygons[p].vertices:
                    me.vertices[v].select = True
        # the edges' selection as a whole: without it Edit Mode makes it again from the vertices (the
        # culprits' edges); kept, it showed every edge of a mesh selected before as still selected
        edges = me.attributes.get(".select_edge")
        if edges is not None:
            try:
                me.attributes.remove(edges)
            except RuntimeError:  # a Blender that will not: the vertices and polygons are still right
                pass
        me.update()
        self.reports.info(f"{self.object_name}: selected " + ", ".join(
            ([f"polygon{'s' if len(polys) > 1 else ''} {', '.join(map(str, polys))}"] if polys else [])
            + ([f"{'vertices' if len(verts) > 1 else 'vertex'} {', '.join(map(str, verts))}"] if verts else []))
            + " (Tab into Edit Mode to see them)")

    def finish(self, context) -> str:
        """Close the cache, show it on the modifier, put the scene back on its frame; returns the
        final state ('done', 'cancelled' or 'error') after adding the matching report."""
        jobs.remove(self)
        try:
            self.job.close()
        except Exception as exc:  # the cache keeps every frame it had; say why it is not closed
            self.progress.state, self.progress.message = "error", f"could not finish the cache: {exc}"
        # a re-bake stopped to be resumed keeps its frames beside the previous bake, which stays
        waiting, frames = self.job.waiting_frames, self.job.kept_frames
        if not frames and not waiting:
            self._remove_created_folders()
        elif self.created_folders:
            self.reports.info(f"{self.object_name}: created the cache folder {self.created_folders[-1]}")
        if self.abandoned:  # another file is open now: touch none of its data
            self.reports.warning(f"{self.object_name}: bake stopped by loading another file; "
                                 + (f"frames {frame_span(frames[0], frames[-1])} kept" if frames else "no frame written"))
            return "cancelled"
        scene = bpy.data.scenes.get(self.scene_name)
        if scene is not None and scene.frame_current != self.original_frame:
            scene.frame_set(self.original_frame)
        obj = bpy.data.objects.get(self.object_name)
        p = self.progress
        previous = False
        # The bake the object showed under another path (renamed since, or its cache folder
        # changed): a re-bake too, so it replaces that one on the modifier only once complete, as
        # a re-bake at the same path does; until then the new frames wait at their own path.
        elsewhere = self._attached_elsewhere()
        if obj is not None and modifier.is_enabled(obj):
            if frames and elsewhere and p.state != "done":
                previous = self._attach(obj, *self._attached_before)
            elif frames:
                self._attach(obj, self.plan.cache_path, self.plan.prim_name)
            else:
                previous = self._reattach_existing(obj)
        if obj is not None and frames:
            record_convergence(obj, p)
            if p.convergence_text():
                self.reports.warning(f"{self.object_name}: {p.convergence_text()}")
            if p.fallback_text():
                self.reports.warning(f"{self.object_name}: {p.fallback_text()}")
            if p.rotation_text():
                self.reports.warning(f"{self.object_name}: {p.rotation_text()}")
            if p.warp_text():
                self.reports.warning(f"{self.object_name}: {p.warp_text()}")
            if p.sliver_text():
                self.reports.info(f"{self.object_name}: {p.sliver_text()}")
            if p.pins_text():
                self.reports.warning(f"{self.object_name}: {p.pins_text()}")
            fallback = getattr(getattr(self, "sources", None), "pin_fallback", None)
            if fallback is not None:
                self.reports.warning(
                    f"{self.object_name}: from frame {fallback[0]} the modifiers above {modifier.MODIFIER_NAME!r} made "
                    f"{fallback[1]} vertices where the rest mesh has {self.sources.pin_rest_count}: at such frames "
                    "the pins followed only the object's transform, not those modifiers (keep their vertex count "
                    "fixed over the bake, or apply them)")
            removed = p.fragment_text()
            if removed is not None:
                (self.reports.warning if removed[1] else self.reports.info)(f"{self.object_name}: {removed[0]}")
        if frames and previous and elsewhere:
            kept = (f"the previous bake at {elsewhere} is kept as it was (the object shows it); this bake's frames "
                    f"{frame_span(frames[0], frames[-1])} wait at {self.plan.cache_path}")
        elif frames:
            kept = f"frames {frame_span(frames[0], frames[-1])} kept"
        elif previous and waiting:
            kept = (f"the previous bake is kept as it was; this re-bake's frames {frame_span(waiting[0], waiting[-1])} "
                    "wait beside it (Resume continues it)")
        elif previous:  # a re-bake replaces the previous bake only once complete (tearcloth.bake)
            kept = "the previous bake is kept as it was" + (
                f" (this bake's frames up to {p.frame} are dropped)" if p.frame is not None else "")
        else:
            kept = "no frame written"
        if p.state == "done":
            self.reports.info(f"{self.object_name}: baked frames {frame_span(frames[0], frames[-1])} "
                              f"({p.tears} tear{'s' if p.tears != 1 else ''}, {p.vertices} vertices at the end) "
                              f"into {self.plan.cache_path}")
            if elsewhere and obj is not None and not modifier.players(elsewhere, obj):
                # not deleted (only Free Bake removes baked frames, and Free Bake now frees this
                # bake): said, with where it is, since no panel points at it any more
                self.reports.info(f"{self.object_name}: the bake it showed before, at {elsewhere} (made under "
                                  "another name, cache folder or file), stays on disk; no object of this file "
                                  "shows it now: delete it by hand if it is not needed")
        elif p.state == "cancelled":
            self.reports.warning(f"{self.object_name}: bake cancelled; {kept}" + (". Resume continues it" if frames else ""))
        else:
            p.state = "error"
            self.reports.error(f"{self.object_name}: bake stopped: {p.message}; {kept}")
            if obj is not None and any(getattr(self, "culprits", None) or ()):
                self._select_culprits(obj)
        return p.state

    # -- inline (bake_object) ------------------------------------------------------------------

    def run_inline(self, context, progress=None) -> str:
        try:
            self.start(context)
            while self.progress.state == "running" and not self.job.done:
                try:
                    inputs = gather_inputs(context, self.sources, self.job.next_frame,
                                           self.plan.scale)
                    if not self.job.advance(inputs):  # cancelled inside the frame: it is dropped
                        self.progress.state = "cancelled"
                        break
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
        except Exception as exc:  # a bug: reported, and finish() still restores the scene and files
            self.progress.state = "error"
            self.progress.message = f"internal error ({type(exc).__name__}: {exc})"
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


def _missing_folders(folder: str) -> list:
    """The folders from the first missing ancestor of ``folder`` down to it (outermost first)."""
    missing = []
    folder = os.path.abspath(folder)
    while folder and not os.path.exists(folder):
        missing.append(folder)
        parent = os.path.dirname(folder)
        if parent == folder:
            break
        folder = parent
    return list(reversed(missing))


@dataclass
class BakeResult:
    state: str                # 'done', 'cancelled' or 'error'
    cache_path: str
    frames: list
    progress: Progress
    reports: Reports


# The object's ID property that keeps the last bake's unconverged sub-steps for the panel (a
# result, not a setting: no row of settings.py); [sub-steps, steps, steps simulated in the run].
CONVERGENCE_KEY = "tearcloth_last_bake_unconverged"


def record_convergence(obj, progress: Progress) -> None:
    """Keep the run's unconverged counts on the object (saved with the .blend, read by ui.py)."""
    obj[CONVERGENCE_KEY] = [int(progress.unconverged_substeps), int(progress.unconverged_steps),
                            int(progress.steps)]


def last_convergence(obj) -> tuple[int, int, int] | None:
    """(unconverged sub-steps, steps with any, steps simulated) of the object's last bake, or None."""
    value = obj.get(CONVERGENCE_KEY)
    if value is None:
        return None
    try:
        n, steps, total = (int(v) for v in value)
    except (TypeError, ValueError):
        return None
    return n, steps, total


def bake_object(context, obj, frame_start=None, frame_end=None, progress=None, *, resume=False,
                reports: Reports | None = None) -> BakeResult:
    """Bake ``obj`` from ``frame_start`` to ``frame_end`` (default: its settings) inline, on the
    calling thread: the same ``BakeJob`` the modal operator runs on its worker.

    ``progress(Progress)`` is called after every frame; returning False stops the bake (a first
    bake keeps the frames written so far; a re-bake, which replaces the previous bake only once
    complete, leaves that one as it was). ``resume=True`` continues an interrupted bake. Raises
    ``BakeError`` (scene unchanged) when the bake cannot start; otherwise returns a
    ``BakeResult`` whose ``state`` says how it ended and whose ``reports`` hold every message
    (also logged under the "tearcloth" logger).
    """
    run = BakeRun(context, obj, frame_start, frame_end, resume, reports)
    state = run.run_inline(context, progress)
    return BakeResult(state, run.plan.cache_path, run.job.writer.frames, run.progress, run.reports)


def free_bake(obj, reports: Reports) -> bool:
    """Delete the object's cache (root, frames, resume state) and let the modifier show the rest
    mesh again; while other objects still show the same bake (a duplicate and its original),
    only this one lets go of it. False (with an error report) if it cannot."""
    linked = linked_from(obj)
    if linked:
        reports.error(linked)
        return False
    if obj.name in jobs.bakes:
        reports.error(f"{obj.name}: cannot free while its bake is running; cancel it first (Esc)")
        return False
    if obj.name in jobs.live_sessions:
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
        # The object was renamed (or its folder changed) since the bake: free what it plays. Unless
        # that bake is another file's: this file is a copy (Save As) or the object was appended
        # from it, and the bake still plays there; this object only lets go of it.
        blend = modifier.baked_by_another_file(cache.owner_of(attached))
        if blend:
            modifier.detach_cache(obj)
            reports.info(f"{obj.name}: no longer shows the bake at {attached}; it was baked by {blend} and stays "
                         "on disk (Free Bake in that file deletes it)")
            return True
        path = attached
    elif os.path.lexists(path):
        try:
            cache.check_owner(path, obj.name, object_id=modifier.object_id(obj))
        except cache.CacheOwnerError as exc:
            reports.error(f"{obj.name}: {exc}; left untouched")
            return False
        except cache.CacheError:
            pass  # damaged: delete_cache below still refuses anything that is not a Tear Cloth cache
    others = modifier.players(path, obj)
    if others:
        # a duplicate (its modifier copied with the cache it played) or an object that shares the
        # bake: this one lets go of it; the bake is deleted by the Free Bake of the last one
        modifier.detach_cache(obj)
        names = ", ".join(repr(o.name) for o in others)
        reports.info(f"{obj.name}: no longer shows the bake at {path}; it stays on disk for {names}, "
                     "which still show it")
        return True
    if not os.path.lexists(path) and not os.path.isdir(cache.frames_dir_for(path)):
        modifier.detach_cache(obj)
        delete_state(path)  # a state left alone by a killed bake is no bake
        reports.info(f"{obj.name}: no bake to free (none at {path})")
        return True
    damaged = cache.damaged_root(path)
    # Every folder the files leave must take the deletion, tried before anything goes: a read-only
    # frames folder once let the root go and then stopped with a raw PermissionError, the bake
    # neither kept nor freed.
    for folder in (os.path.dirname(path), cache.frames_dir_for(path)):
        if os.path.isdir(folder) and not os.access(folder, os.W_OK | os.X_OK):
            reports.error(f"{obj.name}: cannot free the bake at {path}: the folder {folder} is not writable; "
                          "left untouched")
            return False
    md = modifier.find_modifier(obj)
    prim = md.object_path.lstrip("/") if md is not None else ""
    modifier.detach_cache(obj)  # before the files go: Blender closes them (Windows cannot delete open files)
    try:
        cache.delete_cache(path)
    except (cache.CacheError, OSError) as exc:
        # nothing of it deleted (a foreign file) or what the system refused: the object shows
        # what is left, as before the attempt
        if os.path.lexists(path) and prim:
            try:
                modifier.attach_cache(obj, path, prim)
            except BakeError:
                pass
        reports.error(f"{obj.name}: {exc}; left untouched" if isinstance(exc, cache.CacheError) else
                      f"{obj.name}: could not free the bake at {path} ({exc.strerror or exc})")
        return False
    delete_state(path)
    reports.info(f"{obj.name}: freed the bake at {path}"
                 + (" (its root file was damaged, cut short; its frame files are deleted with it)" if damaged else ""))
    return True


def stop_all(reason: str) -> None:
    """Stop every running bake, keeping their frames (before a file load, on unregister)."""
    for run in jobs.of_kind(jobs.BAKE):
        log.warning("%s: stopping the bake (%s); frames baked so far are kept", run.object_name, reason)
        run.abandoned = True
        run.stop()
        jobs.remove(run)
        try:
            run.job.close()
        except Exception as exc:
            log.error("%s: could not finish the cache: %s", run.object_name, exc)


def progress_of(object_name: str) -> Progress | None:
    run = jobs.bakes.get(object_name)
    return run.progress if run is not None else None
