"""The Blender half of `tearcloth bake`: open a .blend, register the add-on, choose the objects,
bake each inline with the add-on's own ``BakeRun``, save, render.

What this file owns: ``bake_file`` (run a plan checked by ``tearcloth.cli`` before bpy was
imported), ``ObjectResult`` (how one object's bake ended), ``render`` and ``frame_path``
(Blender's ``#`` frame-number convention), and ``InputError`` for the bad input that only the
opened file can reveal (no Tear Cloth object, an unknown name, no camera): the CLI turns it into
its one-line error and exit status 2. Each object's bake resumes an interrupted bake of the same
object found in its cache (``_start_run``; ``plan.restart`` starts over), and SIGTERM/SIGINT stop
the run cleanly (``_Stop``: the frame in progress is dropped, the file saved). Progress reaches the caller as the bake job's events
(``tearcloth.bake.BakeEvent``), drawn by a ``ProgressLine``; nothing here prints but through it.

The plan (``tearcloth.cli.FilePlan``) is read by attribute only: ``source``, ``compressed``,
``output``, ``cache_dir``, ``objects``, ``frames``, ``render``, ``render_frames``,
``resolution_percent``, ``transparent``.
"""
from __future__ import annotations

import contextlib
import logging
import os
import re
import signal
import threading
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import bpy

from .. import cache
from ..bake import ProgressLine, frame_span
from . import modifier, register
from .bake import BakeRun
from .inputs import SOURCE_PROPERTY
from .report import BakeError, Reports

PROG = "tearcloth bake"


class InputError(Exception):
    """Bad input found in the opened file; the message is one line that names the problem."""


@dataclass
class ObjectResult:
    name: str
    state: str                  # 'done', 'cancelled', 'error'
    frames: list
    cache_path: str | None
    tears: int = 0
    vertices: int = 0
    seconds: float = 0.0
    message: str = ""
    previous_kept: bool = False  # a re-bake that did not complete: the object's previous bake is as it was
    waiting: list = field(default_factory=list)  # that re-bake's frames, kept beside it for a resume

    @property
    def seconds_per_frame(self) -> float | None:
        computed = len(self.frames) - 1  # the first frame is the rest state, not simulated
        return self.seconds / computed if computed > 0 else None


def frame_path(template: Path, frame: int) -> Path:
    """Blender's convention: a run of '#' is the frame number padded to its length."""
    name = re.sub(r"#+", lambda m: f"{frame:0{len(m.group(0))}d}" if frame >= 0 else f"-{-frame:0{len(m.group(0))}d}",
                  template.name)
    return template.with_name(name)


def _pick_objects(plan) -> list[str]:
    scene = bpy.context.scene
    in_scene = {o.name for o in scene.objects}
    enabled = sorted(o.name for o in scene.objects if modifier.is_enabled(o))
    if plan.objects is None:
        if not enabled:
            raise InputError(f"{plan.source.name} has no Tear Cloth object in scene {scene.name!r} "
                             "(enable it on a mesh: Properties > Physics > Tear Cloth)")
        return enabled
    names = list(plan.objects)
    if any(bpy.data.objects.get(n) is None for n in names):
        # a name with commas in it ("Cloth, Left") split by --objects: the whole one, if it is there
        for whole in (", ".join(names), ",".join(names)):
            if bpy.data.objects.get(whole) is not None:
                names = [whole]
                break
    for name in names:
        obj = bpy.data.objects.get(name)
        listing = ", ".join(repr(n) for n in enabled) or "none"
        if obj is None:
            raise InputError(f"{plan.source.name} has no object named {name!r} (Tear Cloth objects: {listing})")
        if name not in in_scene:
            raise InputError(f"object {name!r} is not in scene {scene.name!r} of {plan.source.name}")
        if not modifier.is_enabled(obj):
            raise InputError(f"object {name!r} is not a Tear Cloth object (Tear Cloth objects: {listing})")
    return list(dict.fromkeys(names))


def _cache_folder_setting(cache_dir: Path, blend: Path) -> str:
    """The cache folder as the .blend should store it: relative to the file when possible."""
    try:
        rel = os.path.relpath(cache_dir, blend.parent)
    except ValueError:  # another drive (Windows)
        return str(cache_dir) + os.sep
    return "//" + rel.replace(os.sep, "/") + "/"


def bake_file(plan, progress: ProgressLine | None = None, on_event=None) -> dict:
    """Run a checked plan: open, bake, save, render. Returns a summary dict with one
    ``ObjectResult`` per object. ``on_event(BakeEvent)`` receives every bake job's events (the
    demo records hand forces with them). Raises InputError for what only the opened file can
    reveal (no Tear Cloth object, unknown name, no camera), OSError when a save or render fails."""
    progress = progress or ProgressLine()
    register()
    logger = logging.getLogger("tearcloth")
    handler = progress.log_handler(PROG)
    saved = logger.level, logger.propagate
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    logger.propagate = False  # Blender's root handlers would print the same lines again
    try:
        try:
            # never run code embedded in a scene on a farm, whatever the file or the preferences ask
            bpy.ops.wm.open_mainfile(filepath=str(plan.source), load_ui=False, use_scripts=False)
        except RuntimeError as exc:
            raise InputError(f"{plan.source}: Blender could not open it ({one_line(exc)})") from None
        register()  # no-op if still registered; a file load never unregisters Python classes
        # The handlers from the file's opening to its last save: a signal that comes while the
        # .blend is written (a farm manager's SIGTERM right after the last frame, or while the
        # input is copied to --out) lets the save finish and stops the run after it, as during a
        # bake, instead of killing the process half-way through (status -15, nothing said)
        stop = _Stop()
        with stop.installed():
            scene = bpy.context.scene
            names = _pick_objects(plan)
            if plan.render is not None and scene.camera is None:
                raise InputError(f"scene {scene.name!r} of {plan.source.name} has no camera to --render from")
            # the copy's bakes record which input they were made from (inputs.SOURCE_PROPERTY): two
            # inputs baked into one --out never resume each other's partial bake
            source = str(Path(plan.source).resolve()) if plan.output != plan.source else None
            for each in bpy.data.scenes:
                if source is not None:
                    each[SOURCE_PROPERTY] = source
                elif SOURCE_PROPERTY in each:
                    del each[SOURCE_PROPERTY]
            if plan.output != plan.source:
                # a fresh copy needs no backup (.blend1) of the copy saved a minute earlier; with
                # --overwrite Blender's own setting stays, so the input keeps its usual backup
                bpy.context.preferences.filepaths.save_version = 0
                _save(plan.output, plan.compressed, copy_to=True)
            if plan.cache_dir is not None:
                plan.cache_dir.mkdir(parents=True, exist_ok=True)
                setting = _cache_folder_setting(plan.cache_dir, plan.output)
                for name in names:
                    settings = bpy.data.objects[name].tearcloth
                    if settings.cache_folder != setting:
                        with warnings.catch_warnings():
                            # the property takes '//' paths although it does not declare so (yet)
                            warnings.simplefilter("ignore", RuntimeWarning)
                            settings.cache_folder = setting
            start, end = plan.frames if plan.frames else (None, None)
            results = _bake_objects(names, start, end, plan, progress, on_event, stop)
            baked_any = any(r.frames for r in results)
            if baked_any or plan.output != plan.source:
                _save(plan.output, plan.compressed)
        interrupted = stop.signal is not None
        rendered = []
        if plan.render is not None and not interrupted:
            baked = [f for r in results for f in r.frames]
            frames = plan.render_frames or [max(baked) if baked else scene.frame_current]
            for frame in frames:
                rendered.append(render(scene, frame_path(plan.render, frame), frame, plan.resolution_percent,
                                       plan.transparent))
        return {"output": str(plan.output), "objects": results, "rendered": rendered, "interrupted": interrupted,
                "signal": stop.signal, "saved": baked_any or plan.output != plan.source}
    finally:
        logger.removeHandler(handler)
        logger.setLevel(saved[0])
        logger.propagate = saved[1]


def _bake_objects(names, start, end, plan, progress: ProgressLine, on_event, stop: "_Stop") -> list:
    """Bake each object inline, one after the other, until done or a signal stops the run."""
    results = []
    for index, name in enumerate(names, 1):
        if stop.signal is not None:
            break
        obj = bpy.data.objects[name]
        reports = Reports()
        t0 = time.perf_counter()

        def listen(event, index=index):
            # a frame the job simulated (not the rest frame it starts from) moves the line on
            if event.kind == "frame" and event.frame > event.job.start_frame:
                progress.update(event.job.progress, index, len(names))
            if on_event is not None:
                on_event(event)

        try:
            run = _start_run(obj, start, end, reports, listen, progress,
                             restart=getattr(plan, "restart", False))
        except BakeError as exc:
            results.append(ObjectResult(name, "error", [], None, message=str(exc)))
            continue
        stop.run = run
        if stop.signal is not None:  # came while the bake was being set up
            run.job.keep_staged = True
            run.job.cancel.set()
        try:
            state = run.run_inline(bpy.context)
        except KeyboardInterrupt:  # raised by a caller's own handler: the same stop
            state = "cancelled"
            stop.signal = stop.signal or "SIGINT"
        finally:
            stop.run = None
        progress.update(run.progress, index, len(names), final=True)
        progress.end()
        p = run.progress
        message = p.message if state == "error" else ""
        if state == "error" and not message:
            message = "; ".join(reports.errors)
        waiting, frames = list(run.job.waiting_frames), list(run.job.kept_frames)
        results.append(ObjectResult(name, state, frames, run.plan.cache_path, p.tears,
                                    p.vertices, time.perf_counter() - t0, message,
                                    previous_kept=run.job.previous_kept, waiting=waiting))
    return results


class _Stop:
    """SIGTERM (what render-farm managers send) and SIGINT (Ctrl-C) handled alike while a bake
    runs: the job is asked to stop at its next step, so the frame being simulated is dropped,
    every complete frame stays, and the caller saves the .blend pointing at them. ``signal``:
    the name of the signal that stopped the run, or None."""

    def __init__(self):
        self.signal = None
        self.run = None  # the bake running now

    def _handler(self, signum, frame):
        self.signal = signal.Signals(signum).name
        if self.run is not None:
            self.run.job.keep_staged = True  # stopped to be resumed: a re-bake keeps its frames beside
            self.run.job.cancel.set()

    @contextlib.contextmanager
    def installed(self):
        """The handlers for the whole run (restored after; signals are only for the main thread)."""
        old = {}
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGTERM, signal.SIGINT):
                old[sig] = signal.signal(sig, self._handler)
        try:
            yield self
        finally:
            for sig, handler in old.items():
                signal.signal(sig, handler)


def _start_run(obj, start, end, reports: Reports, listen, progress: ProgressLine, restart: bool) -> BakeRun:
    """The object's bake: resumed from its last complete frame when a compatible partial bake
    is in its cache (a killed run of the same command), from the start otherwise or with
    ``restart``. Says which on the progress stream."""
    partial = None if restart else _partial_bake(obj)
    if partial is not None:
        tried = Reports()
        try:
            run = BakeRun(bpy.context, obj, start, end, True, tried, on_event=listen)
        except BakeError as exc:
            _say(progress, f"{obj.name}: the partial bake (frames {frame_span(partial[0], partial[-1])}) cannot be resumed "
                           f"({exc}); baking from the start")
        else:
            reports.items.extend(tried.items)
            what = ("the interrupted re-bake (the previous bake stays until it is complete)" if run.job.replacing
                    else "the partial bake")
            _say(progress, f"{obj.name}: resuming {what} after frame {run.job.start_frame} "
                           "(--restart bakes from the start)")
            return run
    return BakeRun(bpy.context, obj, start, end, False, reports, on_event=listen)


def _partial_bake(obj) -> list | None:
    """The frames of an interrupted bake of the object: a re-bake killed midway beside its
    previous bake (the latest attempt), else an incomplete bake at its cache path; or None."""
    try:
        path = modifier.cache_path(obj)
        staged = cache.interrupted_rebake(path)
        if staged is not None:
            try:
                return cache.check_owner(staged["path"], obj.name, object_id=modifier.object_id(obj))["frames"]
            except cache.CacheError:
                pass  # not this object's: the next bake clears it
        info = cache.check_owner(path, obj.name, object_id=modifier.object_id(obj))
    except (BakeError, cache.CacheError):
        return None
    return info["frames"] if info["frames"] and not info["complete"] else None


def _say(progress: ProgressLine, text: str) -> None:
    progress.end()
    progress.stream.write(f"{PROG}: {text}\n")
    progress.stream.flush()


def _save(path: Path, compress: bool, copy_to: bool = False) -> None:
    """Save the open file (``copy_to``: as a new file, remapping relative paths to it)."""
    try:
        if copy_to:
            bpy.ops.wm.save_as_mainfile(filepath=str(path), compress=compress, relative_remap=True)
        else:
            bpy.ops.wm.save_mainfile(filepath=str(path), compress=compress)
    except RuntimeError as exc:
        raise OSError(f"could not save {path}: {one_line(exc)}") from None


def render(scene, png: Path, frame: int, percent: int | None = None, transparent: bool = False) -> str:
    """Render ``frame`` with the scene's camera and engine into ``png`` (not saved in the .blend)."""
    scene.frame_set(frame)
    r = scene.render
    if percent is not None:
        r.resolution_percentage = percent
    if transparent:
        r.film_transparent = True
        r.image_settings.color_mode = "RGBA"
    r.image_settings.file_format = "PNG"
    r.use_file_extension = False
    r.filepath = str(png)
    try:
        bpy.ops.render.render(write_still=True, scene=scene.name)
    except RuntimeError as exc:
        raise OSError(f"could not render frame {frame} into {png}: {one_line(exc)}") from None
    if not png.exists():
        raise OSError(f"Blender rendered nothing into {png}")
    return str(png)


def one_line(exc) -> str:
    """The last non-empty line of an exception's text (Blender's errors carry a traceback)."""
    lines = [line.strip() for line in str(exc).strip().splitlines() if line.strip()]
    return lines[-1] if lines else type(exc).__name__
