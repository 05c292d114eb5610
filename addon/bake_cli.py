"""`tearcloth bake`: bake the Tear Cloth objects of a .blend file headless, with Blender's ``bpy``
module, and save a copy of the file that plays the bakes; and `tearcloth demo`, built on it.

    tearcloth bake FILE.blend [--objects NAMES] [--frames A-B] [--out DIR] [--overwrite]
                              [--render PNG [--render-frame N[,M...]] [--resolution-percent P]
                                            [--transparent]]

What happens, in order:

1. The arguments, the input file (it exists, it is a .blend by its header) and the output
   folders (they can be created and written) are checked BEFORE ``bpy`` is imported, so a typo
   costs no Blender start-up. Every bad input ends with ONE line on stderr,
   ``tearcloth bake: error: <what is wrong>``, and exit status 2.
2. The add-on is registered, the file opened, the objects chosen: every object of the file's
   scene whose "Tear Cloth" modifier is there (``--objects a,b`` picks some by name).
3. Where things go. Without ``--overwrite`` the input .blend is never written: the baked copy is
   ``DIR/<file name>`` (``DIR``: ``--out``, default ``<input folder>/<input name>_baked``), and
   each baked object's cache folder becomes ``//tearcloth_cache/`` next to it, so DIR holds the
   .blend and its caches and moves as one. The copy is saved first (so ``//`` means DIR), then
   again after the bakes. With ``--overwrite`` the input file itself is saved after the bakes;
   its objects keep their own cache folders unless ``--out DIR`` is given too (then the caches
   go to ``DIR/tearcloth_cache/``).
4. Each object is baked inline by the add-on's own ``BakeRun`` (what the Bake button runs on a
   worker thread), frames ``--frames A-B`` or the object's own range. A progress line on stderr
   (a carriage-return line on a terminal, a line every 10 % otherwise) shows frames, steps per
   second, tears so far and the ETA. Ctrl-C stops the bake: the frames baked so far are kept,
   the file is saved (Resume in Blender continues it) and the exit status is 130.
5. ``--render PNG`` renders a frame (default: the last baked frame; ``--render-frame 1,24``
   renders several into a name with ``#`` for the frame number, Blender's convention:
   ``torn_####.png``) with the scene's camera and render engine, after saving (the render
   settings touched here are not saved); ``--transparent`` leaves the background out (RGBA).

Exit status: 0 all baked, 1 a bake failed (the others are kept and saved), 2 bad input, 130
interrupted.

`tearcloth demo` (``demo()`` below) bakes the repository's ``example_blends/square_cloth.blend``
(the paper's Fig. 1) this way, renders the torn cloth and plots the force each hand feels.

This module imports no bpy at import time: ``tearcloth.cli`` can import it anywhere.
"""
from __future__ import annotations

import argparse
import logging
import math
import os
import re
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

PROG = "tearcloth bake"
EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130
CACHE_SUBFOLDER = "tearcloth_cache"

# First bytes of a .blend: plain, zstd-compressed (Blender 3.0+) or gzip-compressed (older).
_PLAIN_MAGIC = b"BLENDER"
_COMPRESSED_MAGIC = (b"\x28\xb5\x2f\xfd", b"\x1f\x8b")


class UsageError(Exception):
    """Bad input: the message is one line that names the problem (exit status 2)."""


class _Parser(argparse.ArgumentParser):
    """argparse that raises instead of printing usage + exiting, so every error is one line."""

    def error(self, message):
        raise UsageError(message)


def _parser(prog: str = PROG) -> _Parser:
    p = _Parser(prog=prog, description="Bake the Tear Cloth objects of a .blend file headless and save a "
                                       "copy that plays the bakes.")
    p.add_argument("file", metavar="FILE.blend", help="the .blend file to bake")
    p.add_argument("--objects", metavar="NAMES",
                   help="comma-separated object names (default: every Tear Cloth object of the scene)")
    p.add_argument("--frames", metavar="A-B", help="bake frames A to B (default: each object's own range)")
    p.add_argument("--out", metavar="DIR",
                   help="output folder for the baked .blend and its caches (default: <input folder>/<name>_baked)")
    p.add_argument("--overwrite", action="store_true",
                   help="save the bakes into the input file itself instead of a copy")
    p.add_argument("--render", metavar="PNG", help="after baking, render one frame to this PNG file")
    p.add_argument("--render-frame", metavar="N[,M...]",
                   help="frame(s) to render (default: the last baked frame); several need # in the PNG name")
    p.add_argument("--resolution-percent", metavar="P", type=_int_arg("--resolution-percent", 1, 1000),
                   help="render at this percentage of the scene's resolution")
    p.add_argument("--transparent", action="store_true",
                   help="render with a transparent background (RGBA PNG: the alpha is the objects' silhouette)")
    return p


def _int_arg(option: str, lo: int | None = None, hi: int | None = None):
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{option} wants a whole number, not {text!r}") from None
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise argparse.ArgumentTypeError(f"{option} must be between {lo} and {hi}, not {value}")
        return value

    return parse


# ------------------------------------------------------------------------------------------------
# Checks that need no Blender


def parse_frames(text: str | None) -> tuple[int, int] | None:
    """'A-B' -> (A, B) with A < B (negative frames allowed: '-10--1'); UsageError otherwise."""
    if text is None:
        return None
    m = re.fullmatch(r"\s*(-?\d+)\s*-\s*(-?\d+)\s*", text)
    if m is None:
        raise UsageError(f"--frames wants A-B with whole frame numbers, e.g. 1-48, not {text!r}")
    a, b = int(m.group(1)), int(m.group(2))
    if a >= b:
        raise UsageError(f"--frames {text}: the first frame ({a}) must come before the last ({b})")
    return a, b


def parse_render_frames(text: str | None) -> list[int] | None:
    """'24' or '1,12,24' -> frame numbers; UsageError otherwise."""
    if text is None:
        return None
    try:
        frames = [int(part) for part in text.split(",")]
    except ValueError:
        raise UsageError(f"--render-frame wants frame numbers such as 24 or 1,12,24, not {text!r}") from None
    return list(dict.fromkeys(frames))


def frame_path(template: Path, frame: int) -> Path:
    """Blender's convention: a run of '#' is the frame number padded to its length."""
    name = re.sub(r"#+", lambda m: f"{frame:0{len(m.group(0))}d}" if frame >= 0 else f"-{-frame:0{len(m.group(0))}d}",
                  template.name)
    return template.with_name(name)


def check_blend(path: Path) -> bool:
    """The input must be a readable .blend file; returns whether it is compressed."""
    if not path.exists():
        raise UsageError(f"{path}: no such file")
    if path.is_dir():
        raise UsageError(f"{path} is a folder, not a .blend file")
    try:
        with open(path, "rb") as f:
            head = f.read(8)
    except OSError as exc:
        raise UsageError(f"{path}: cannot read it ({exc.strerror or exc})") from None
    if head.startswith(_PLAIN_MAGIC):
        return False
    if head.startswith(_COMPRESSED_MAGIC) and path.suffix.lower().startswith(".blend"):
        return True
    raise UsageError(f"{path}: not a .blend file (it does not start with Blender's file header)")


def check_folder(folder: Path, what: str) -> bool:
    """Create ``folder`` if needed and prove it writable with a real write (``os.access`` says
    yes to root on a read-only mount). Returns whether it was created here."""
    if folder.exists() and not folder.is_dir():
        raise UsageError(f"the {what} {folder} is a file, not a folder")
    created = False
    if not folder.exists():
        try:
            folder.mkdir(parents=True)
            created = True
        except OSError as exc:
            raise UsageError(f"cannot create the {what} {folder}: {exc.strerror or exc}") from None
    try:
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as exc:
        raise UsageError(f"the {what} {folder} is not writable: {exc.strerror or exc}") from None
    return created


@dataclass
class Plan:
    """What one run does, checked before Blender starts."""

    source: Path
    compressed: bool
    output: Path                    # the .blend saved with the bakes
    cache_dir: Path | None          # where caches go (None: each object's own cache folder)
    objects: list | None            # names asked for, or None for all
    frames: tuple | None
    render: Path | None = None          # file name, '#'s stand for the frame number
    render_frames: list | None = None
    resolution_percent: int | None = None
    transparent: bool = False
    created: list = field(default_factory=list)  # folders made by the checks (removed if unused)


def plan_from_args(args) -> Plan:
    """Every check that needs no Blender; folders are created only once all of them passed."""
    source = Path(args.file).expanduser().resolve()
    compressed = check_blend(source)
    frames = parse_frames(args.frames)
    objects = None
    if args.objects is not None:
        objects = [n.strip() for n in args.objects.split(",") if n.strip()]
        if not objects:
            raise UsageError("--objects names no object")
    render_frames = parse_render_frames(args.render_frame)
    if render_frames is not None and not args.render:
        raise UsageError("--render-frame needs --render PNG")
    for option, given in (("--resolution-percent", args.resolution_percent is not None),
                          ("--transparent", args.transparent)):
        if given and not args.render:
            raise UsageError(f"{option} needs --render PNG")
    png = None
    if args.render:
        png = Path(args.render).expanduser().resolve()
        if png.is_dir():
            raise UsageError(f"--render {args.render} is a folder; give a file name such as torn.png")
        if not png.suffix:
            png = png.with_suffix(".png")
        elif png.suffix.lower() != ".png":
            raise UsageError(f"--render writes PNG images; {png.name} does not end in .png")
        if render_frames is not None and len(render_frames) > 1 and "#" not in png.name:
            raise UsageError(f"--render {args.render}: several frames need # in the file name for the frame number, "
                             "e.g. frame_####.png")
    out_dir = Path(args.out).expanduser().resolve() if args.out else None
    if args.overwrite:
        output = source
        cache_dir = out_dir / CACHE_SUBFOLDER if out_dir else None
    else:
        out_dir = out_dir or source.parent / f"{source.stem}_baked"
        output = out_dir / source.name
        cache_dir = out_dir / CACHE_SUBFOLDER
        if output == source or (output.exists() and os.path.samefile(output, source)):
            raise UsageError(f"the output {output} is the input file; pass --overwrite to bake into it, "
                             "or choose another --out folder")
    plan = Plan(source, compressed, output, cache_dir, objects, frames, png, render_frames, args.resolution_percent,
                args.transparent)
    try:
        if args.overwrite:
            check_folder(source.parent, "folder of the input file")  # Blender saves by renaming a new file
        if out_dir is not None and check_folder(out_dir, "output folder"):
            plan.created.append(out_dir)
        if png is not None and check_folder(png.parent, "render folder"):
            plan.created.append(png.parent)
    except UsageError:
        _remove_created(plan)
        raise
    return plan


# ------------------------------------------------------------------------------------------------
# Progress on stderr


def _duration(seconds: float | None) -> str:
    if seconds is None or not math.isfinite(seconds):
        return "?"
    seconds = int(round(seconds))
    if seconds < 60:
        return f"{seconds} s"
    if seconds < 3600:
        return f"{seconds // 60} min {seconds % 60:02d} s"
    return f"{seconds // 3600} h {seconds % 3600 // 60:02d} min"


class ProgressLine:
    """One progress line per object: rewritten in place (carriage return) on a terminal,
    printed every 10 % to a log file or a pipe."""

    WIDTH = 24

    def __init__(self, stream=None):
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.open = False
        self._last = 0.0
        self._last_decile = -1
        self._length = 0

    def text(self, p, index: int, count: int) -> str:
        done = p.factor
        filled = int(round(done * self.WIDTH))
        bar = "#" * filled + "-" * (self.WIDTH - filled)
        frame = "-" if p.frame is None else str(p.frame)
        tears = f"{p.tears} tear{'s' if p.tears != 1 else ''}"
        elapsed = time.perf_counter() - p.started
        return (f"[{bar}] {index}/{count} {p.object_name}: frame {frame}/{p.frame_end}, "
                f"{p.steps_per_second:.0f} steps/s, {tears}, {_duration(elapsed)}, ETA {_duration(p.eta_seconds)}")

    def update(self, p, index: int, count: int, final: bool = False) -> None:
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


class _LogToStderr(logging.Handler):
    """The add-on's warnings, on their own line even while a progress line is open. Errors are
    not printed here: they come back as exceptions or results and are printed once, by us."""

    def __init__(self, progress: ProgressLine):
        super().__init__(logging.WARNING)
        self.progress = progress

    def emit(self, record):
        if record.levelno >= logging.ERROR:
            return
        self.progress.end()
        self.progress.stream.write(f"{PROG}: {record.levelname.lower()}: {record.getMessage()}\n")
        self.progress.stream.flush()


# ------------------------------------------------------------------------------------------------
# The bake itself (bpy from here on)


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

    @property
    def seconds_per_frame(self) -> float | None:
        computed = len(self.frames) - 1  # the first frame is the rest state, not simulated
        return self.seconds / computed if computed > 0 else None


def _import_bpy():
    try:
        import bpy
    except ImportError as exc:
        raise UsageError(f"needs Blender's bpy module ({exc}); install it with: pip install 'tearcloth[blender]' "
                         "(Python 3.11)") from None
    return bpy


def _pick_objects(bpy, plan: Plan) -> list[str]:
    from .blender import modifier

    scene = bpy.context.scene
    in_scene = {o.name for o in scene.objects}
    enabled = sorted(o.name for o in scene.objects if modifier.is_enabled(o))
    if plan.objects is None:
        if not enabled:
            raise UsageError(f"{plan.source.name} has no Tear Cloth object in scene {scene.name!r} "
                             "(enable it on a mesh: Properties > Physics > Tear Cloth)")
        return enabled
    for name in plan.objects:
        obj = bpy.data.objects.get(name)
        listing = ", ".join(repr(n) for n in enabled) or "none"
        if obj is None:
            raise UsageError(f"{plan.source.name} has no object named {name!r} (Tear Cloth objects: {listing})")
        if name not in in_scene:
            raise UsageError(f"object {name!r} is not in scene {scene.name!r} of {plan.source.name}")
        if not modifier.is_enabled(obj):
            raise UsageError(f"object {name!r} is not a Tear Cloth object (Tear Cloth objects: {listing})")
    return list(dict.fromkeys(plan.objects))


def _cache_folder_setting(cache_dir: Path, blend: Path) -> str:
    """The cache folder as the .blend should store it: relative to the file when possible."""
    try:
        rel = os.path.relpath(cache_dir, blend.parent)
    except ValueError:  # another drive (Windows)
        return str(cache_dir) + os.sep
    return "//" + rel.replace(os.sep, "/") + "/"


def bake_file(plan: Plan, progress: ProgressLine | None = None, on_frame=None) -> dict:
    """Run a checked ``Plan``: open, bake, save, render. Returns a summary dict with one
    ``ObjectResult`` per object. ``on_frame(run)`` is called after every baked frame with the
    add-on's ``BakeRun`` (the demo records hand forces with it). Raises UsageError for what only
    the opened file can reveal (no Tear Cloth object, unknown name, no camera)."""
    progress = progress or ProgressLine()
    bpy = _import_bpy()
    from . import register
    from .blender.bake import BakeRun
    from .blender.report import BakeError, Reports

    register()
    logger = logging.getLogger("tearcloth")
    handler = _LogToStderr(progress)
    saved = logger.level, logger.propagate
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    logger.propagate = False  # Blender's root handlers would print the same lines again
    try:
        try:
            bpy.ops.wm.open_mainfile(filepath=str(plan.source), load_ui=False)
        except RuntimeError as exc:
            raise UsageError(f"{plan.source}: Blender could not open it ({_one_line(exc)})") from None
        register()  # no-op if still registered; a file load never unregisters Python classes
        scene = bpy.context.scene
        names = _pick_objects(bpy, plan)
        if plan.render is not None and scene.camera is None:
            raise UsageError(f"scene {scene.name!r} of {plan.source.name} has no camera to --render from")
        if plan.output != plan.source:
            # a fresh copy needs no backup (.blend1) of the copy saved a minute earlier; with
            # --overwrite Blender's own setting stays, so the input keeps its usual backup
            bpy.context.preferences.filepaths.save_version = 0
            _save(bpy, plan.output, plan.compressed, copy_to=True)
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
        results = []
        start, end = plan.frames if plan.frames else (None, None)
        interrupted = False
        for index, name in enumerate(names, 1):
            obj = bpy.data.objects[name]
            reports = Reports()
            t0 = time.perf_counter()
            try:
                run = BakeRun(bpy.context, obj, start, end, False, reports)
            except BakeError as exc:
                results.append(ObjectResult(name, "error", [], None, message=str(exc)))
                continue

            def tick(p, run=run, index=index):
                progress.update(p, index, len(names))
                if on_frame is not None:
                    on_frame(run)

            try:
                state = run.run_inline(bpy.context, tick)
            except KeyboardInterrupt:
                state, interrupted = "cancelled", True
            progress.update(run.progress, index, len(names), final=True)
            progress.end()
            p = run.progress
            message = p.message if state == "error" else ""
            if state == "error" and not message:
                message = "; ".join(reports.errors)
            results.append(ObjectResult(name, state, list(run.job.writer.frames), run.plan.cache_path, p.tears,
                                        p.vertices, time.perf_counter() - t0, message))
            if interrupted:
                break
        baked_any = any(r.frames for r in results)
        if baked_any or plan.output != plan.source:
            _save(bpy, plan.output, plan.compressed)
        rendered = []
        if plan.render is not None and not interrupted:
            baked = [f for r in results for f in r.frames]
            frames = plan.render_frames or [max(baked) if baked else scene.frame_current]
            for frame in frames:
                rendered.append(render(bpy, scene, frame_path(plan.render, frame), frame, plan.resolution_percent,
                                       plan.transparent))
        return {"output": str(plan.output), "objects": results, "rendered": rendered, "interrupted": interrupted,
                "saved": baked_any or plan.output != plan.source}
    finally:
        logger.removeHandler(handler)
        logger.setLevel(saved[0])
        logger.propagate = saved[1]


def _save(bpy, path: Path, compress: bool, copy_to: bool = False) -> None:
    """Save the open file (``copy_to``: as a new file, remapping relative paths to it)."""
    try:
        if copy_to:
            bpy.ops.wm.save_as_mainfile(filepath=str(path), compress=compress, relative_remap=True)
        else:
            bpy.ops.wm.save_mainfile(filepath=str(path), compress=compress)
    except RuntimeError as exc:
        raise OSError(f"could not save {path}: {_one_line(exc)}") from None


def render(bpy, scene, png: Path, frame: int, percent: int | None = None, transparent: bool = False) -> str:
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
        raise OSError(f"could not render frame {frame} into {png}: {_one_line(exc)}") from None
    if not png.exists():
        raise OSError(f"Blender rendered nothing into {png}")
    return str(png)


def _one_line(exc) -> str:
    lines = [line.strip() for line in str(exc).strip().splitlines() if line.strip()]
    return lines[-1] if lines else type(exc).__name__


def _report(summary: dict, out) -> int:
    status = EXIT_OK
    for r in summary["objects"]:
        if r.state == "done":
            spf = r.seconds_per_frame
            rate = f" ({spf:.3f} s/frame)" if spf is not None else ""
            out(f"{r.name}: baked frames {r.frames[0]}-{r.frames[-1]}: {r.tears} tear{'s' if r.tears != 1 else ''}, "
                f"{r.vertices} vertices, {r.seconds:.1f} s{rate} -> {r.cache_path}")
        elif r.state == "cancelled":
            kept = f"frames {r.frames[0]}-{r.frames[-1]} kept" if r.frames else "no frame written"
            print(f"{PROG}: {r.name}: interrupted; {kept}", file=sys.stderr)
            status = max(status, EXIT_FAILED)
        else:
            print(f"{PROG}: error: {r.name}: {r.message}", file=sys.stderr)
            status = max(status, EXIT_FAILED)
    if summary["saved"]:
        out(f"saved {summary['output']}")
    for path in summary["rendered"]:
        out(f"rendered {path}")
    if summary["interrupted"]:
        return EXIT_INTERRUPTED
    return status


def main(argv=None) -> int:
    """`tearcloth bake ...`; returns the exit status."""
    argv = sys.argv[1:] if argv is None else list(argv)
    plan = None
    try:
        try:
            args = _parser().parse_args(argv)
        except SystemExit as exc:  # --help
            return int(exc.code or 0)
        plan = plan_from_args(args)
        summary = bake_file(plan)
    except UsageError as exc:
        if plan is not None:
            _remove_created(plan)
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print(f"\n{PROG}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except OSError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except Exception as exc:  # a bug, not bad input: the traceback is for the report, the last line says what
        import traceback

        traceback.print_exc()
        print(f"{PROG}: error: internal error ({type(exc).__name__}: {_one_line(exc)}); please report it",
              file=sys.stderr)
        return EXIT_FAILED
    return _report(summary, print)


def _remove_created(plan: Plan) -> None:
    """Folders the checks made are removed again if the run stopped before using them."""
    for folder in reversed(plan.created):
        try:
            folder.rmdir()  # only if empty
        except OSError:
            pass


# ------------------------------------------------------------------------------------------------
# `tearcloth demo`


def example_blend(name: str = "square_cloth") -> Path:
    """An example .blend: shipped inside the package (``tearcloth/data/``, in wheels and
    installs) or, in a source checkout, ``example_blends/`` at the repository root."""
    here = Path(__file__).resolve().parent
    for candidate in (here / "data" / f"{name}.blend", here.parent / "example_blends" / f"{name}.blend"):
        if candidate.is_file():
            return candidate
    raise UsageError(f"cannot find the example {name}.blend (looked in {here / 'data'} and "
                     f"{here.parent / 'example_blends'}); regenerate it with example_blends/make_examples.py")


class _HandForces:
    """Records the force each handle exerts on its hand at every simulation step of a bake (the
    force a haptic device would render; the paper's Fig. 6). Installed on the bake's Session
    after its first frame: the hands hold still over that frame."""

    def __init__(self, log, labels=("left", "right")):
        self.log = log
        self.labels = labels
        self.session = None

    def __call__(self, run) -> None:
        session = run.job.session
        if session is None or session is self.session:
            return
        self.session = session
        handles = list(getattr(run.job, "handles", None) or getattr(run.job, "_handles"))
        labels = [self.labels[i] if i < len(self.labels) else f"hand {i + 1}" for i in range(len(handles))]
        step = session.step
        log = self.log

        def step_and_record(dt):
            report = step(dt)
            for label, h in zip(labels, handles):
                log.record(label, session.time, session.cloth.handle_force(h))
            return report

        session.step = step_and_record


def demo(out_dir: str = "tearcloth_demo") -> dict:
    """Bake the square cloth example (Fig. 1), render the torn cloth and plot the hand forces.

    Writes ``torn_cloth.png``, ``forces.png``, ``forces.csv`` and the baked scene
    (``square_cloth.blend`` + ``tearcloth_cache/``) into ``out_dir``. Raises ValueError or OSError
    with a one-line message on failure (``tearcloth.cli`` prints it)."""
    from .haptics.forcelog import ForceLog

    out = Path(out_dir).expanduser().resolve()
    try:
        source = example_blend("square_cloth")
        args = _parser("tearcloth demo").parse_args([str(source), "--out", str(out), "--render",
                                                     str(out / "torn_cloth.png")])
        plan = plan_from_args(args)
        log = ForceLog(("left", "right"))
        t0 = time.perf_counter()
        summary = bake_file(plan, on_frame=_HandForces(log))
    except UsageError as exc:
        raise ValueError(str(exc)) from None
    wall = time.perf_counter() - t0
    results = summary["objects"]
    failed = [r for r in results if r.state != "done"]
    if failed:
        raise ValueError(f"the bake of {failed[0].name} did not finish: {failed[0].message or failed[0].state}")
    r = results[0]
    log.to_csv(out / "forces.csv")
    log.plot(out / "forces.png", axis=(1.0, 0.0, 0.0), title="Force felt by each hand (along the pull)")
    print(f"baked {r.name}: frames {r.frames[0]}-{r.frames[-1]}, {r.tears} tear{'s' if r.tears != 1 else ''}, "
          f"{r.vertices} vertices at the end, {r.seconds:.1f} s ({r.seconds_per_frame:.3f} s/frame)")
    print(f"wrote {out / 'torn_cloth.png'}, {out / 'forces.png'}, {out / 'forces.csv'} and {summary['output']}")
    return {"wall_s": wall, "tears": r.tears, "frames": [r.frames[0], r.frames[-1]], "vertices": r.vertices,
            "seconds_per_frame": r.seconds_per_frame, "blend": summary["output"], "out": str(out)}


if __name__ == "__main__":
    sys.exit(main())
