"""The `tearcloth` command: one argparse tree with the sub-commands ``bake``, ``demo``, ``bench``,
``clusters`` and ``farm``.

What this file owns: the tree (``parser``), every check of a command's input that needs no
Blender, the ``bake`` run plan (``FilePlan``), the printed summary of a bake, and ``demo``.
The work itself lives below: ``tearcloth.blender.headless`` (the bpy half of a bake),
``tearcloth.bench`` (benchmarks). Nothing heavy is imported at module level, so a typo costs
no Blender start-up and no native build.

    tearcloth bake FILE.blend [--objects NAMES] [--frames A-B] [--out DIR] [--overwrite] [--restart]
                              [--render PNG [--render-frame N[,M...]] [--resolution-percent P]
                                            [--transparent]]

What a bake does, in order:

1. The arguments, the input file (it exists, it is a .blend by its header) and the output
   folders (they can be created and written) are checked BEFORE ``bpy`` is imported. Every bad
   input, of any sub-command, ends with ONE line on stderr, ``tearcloth <command>: error: <what
   is wrong>``, and exit status 2.
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
   second, tears so far and the ETA. Ctrl-C (SIGINT) and SIGTERM (what a render-farm manager
   sends) stop the bake alike: the frame being simulated is dropped, every complete frame is
   kept, the file is saved pointing at them, one line on stderr says so, and the exit status is
   130 (SIGINT) or 143 (SIGTERM).
   Resume: when an object's cache holds an interrupted bake of the same object (a killed or
   stopped run of the same command; for a re-bake, its frames beside the previous bake, which
   it replaces only once complete), the bake continues after its last complete frame and says
   so, from the whole saved simulation state (it ends exactly as an uninterrupted bake would); a bake that cannot be resumed (another mesh, a stale state) starts over and says why.
   ``--restart`` always bakes from the first frame.
5. ``--render PNG`` renders a frame (default: the last baked frame; ``--render-frame 1,24``
   renders several into a name with ``#`` for the frame number, Blender's convention:
   ``torn_####.png``) with the scene's camera and render engine, after saving (the render
   settings touched here are not saved); ``--transparent`` leaves the background out (RGBA).

Exit status of a bake: 0 all baked, 1 a bake failed (the others are kept and saved), 2 bad
input, 130 interrupted by SIGINT, 143 stopped by SIGTERM.

`tearcloth demo` (``demo()``) bakes the repository's ``example_blends/square_cloth.blend`` (the
paper's Fig. 1) this way, renders the torn cloth and plots the force each hand feels.
"""
from __future__ import annotations

import argparse
import os
import re
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from . import settings

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130
EXIT_TERMINATED = 143  # 128 + SIGTERM, the shells' convention
CACHE_SUBFOLDER = "tearcloth_cache"
# a re-bake replaces the previous bake only once complete (tearcloth.bake.BakeJob)
PREVIOUS_KEPT = "its new frames dropped, the previous bake kept as it was"

# First bytes of a .blend: plain, zstd-compressed (Blender 3.0+) or gzip-compressed (older).
_PLAIN_MAGIC = b"BLENDER"
_COMPRESSED_MAGIC = (b"\x28\xb5\x2f\xfd", b"\x1f\x8b")


class UsageError(Exception):
    """Bad input: ``prog`` names the command, the message is one line that names the problem
    (exit status 2)."""

    def __init__(self, message: str, prog: str = "tearcloth bake"):
        super().__init__(message)
        self.prog = prog


class _Parser(argparse.ArgumentParser):
    """argparse that raises instead of printing usage + exiting, so every error is one line
    that names the sub-command it belongs to."""

    def error(self, message):
        raise UsageError(message, self.prog)


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


def parser() -> _Parser:
    """The one argparse tree of `tearcloth`."""
    p = _Parser(prog="tearcloth", description="Tear Cloth: tearing cloth for Blender and haptics")
    sub = p.add_subparsers(dest="command", required=True, metavar="{bake,demo,bench,clusters,farm}")
    k = sub.add_parser("bake", help="bake the Tear Cloth objects of a .blend headless",
                       description="Bake the Tear Cloth objects of a .blend file headless and save a copy that "
                                   "plays the bakes.")
    k.add_argument("file", metavar="FILE.blend", help="the .blend file to bake")
    k.add_argument("--objects", metavar="NAMES",
                   help="comma-separated object names (default: every Tear Cloth object of the scene)")
    k.add_argument("--frames", metavar="A-B", help="bake frames A to B (default: each object's own range); "
                   "negative frames with '=': --frames=-10--1 (a leading '-' reads as an option)")
    k.add_argument("--out", metavar="DIR",
                   help="output folder for the baked .blend and its caches (default: <input folder>/<name>_baked)")
    k.add_argument("--overwrite", action="store_true",
                   help="save the bakes into the input file itself instead of a copy")
    k.add_argument("--restart", action="store_true",
                   help="bake from the first frame even where an interrupted bake could be resumed")
    k.add_argument("--render", metavar="PNG", help="after baking, render one frame to this PNG file")
    k.add_argument("--render-frame", metavar="N[,M...]",
                   help="frame(s) to render (default: the last baked frame); several need # in the PNG name")
    k.add_argument("--resolution-percent", metavar="P", type=_int_arg("--resolution-percent", 1, 1000),
                   help="render at this percentage of the scene's resolution")
    k.add_argument("--transparent", action="store_true",
                   help="render with a transparent background (RGBA PNG: the alpha is the objects' silhouette)")
    d = sub.add_parser("demo", help="bake the square cloth example (Fig. 1), render it, plot the hand forces")
    d.add_argument("--out", default="tearcloth_demo", help="output folder (default ./tearcloth_demo)")
    b = sub.add_parser("bench", help="measure step times (medians) and write JSON")
    b.add_argument("--json", metavar="PATH", help="write results to this JSON file (merged with what it holds)")
    b.add_argument("--steps", type=int, default=200, help="steps per measurement (default 200)")
    b.add_argument("--scenarios", default="cloth,banknote,tshirt", help="comma-separated: cloth,banknote,tshirt")
    b.add_argument("--no-collision", action="store_true", help="skip the collision experiment")
    b.add_argument("--parts", default="table1,slivers,collision,servo,blender,multigrid,scaling,materials",
                   help="comma-separated parts to run (default: all): table1,slivers,collision,servo,blender,multigrid,scaling,materials")
    b.add_argument("--markdown", metavar="PATH", help="also write a BENCHMARKS.md-style report here")
    b.add_argument("--plots", metavar="DIR", help="write plots (scaling) into this folder")
    c = sub.add_parser("clusters", help="picture of the cluster decomposition (the paper's Fig. 2)")
    c.add_argument("--out", default="clusters.png", help="PNG path (default clusters.png)")
    c.add_argument("--scenario", default="tshirt", choices=("cloth", "banknote", "tshirt"))
    size = int(settings.default("collision", "cluster_size"))
    c.add_argument("--cluster-size", type=int, default=size, help=f"vertices per cluster (default {size})")
    _farm_parser(sub)
    return p


def _farm_parser(sub) -> None:
    """`tearcloth farm`: the sub-command of tearcloth.farm (bakes as Dask tasks)."""
    f = sub.add_parser("farm", help="bake files x objects x wedges of settings as tasks on Dask",
                       description="Bake many .blend files, objects and wedges of settings as Dask tasks, each in "
                                   "a fresh subprocess; write a manifest and a contact sheet.")
    f.add_argument("files", nargs="+", metavar="FILE.blend", help="the .blend files to bake")
    f.add_argument("--objects", metavar="NAMES", help="comma-separated object names (default: every Tear Cloth object)")
    f.add_argument("--set", action="append", metavar="NAME=V1,V2",
                   help="wedge a parameter of the settings table over these values (SI; repeat for a product)")
    f.add_argument("--frames", metavar="A-B", help="bake frames A to B (default: each object's own range)")
    f.add_argument("--out", default="tearcloth_farm", metavar="DIR", help="output folder (default ./tearcloth_farm)")
    f.add_argument("--workers", type=_int_arg("--workers", 1, 256), metavar="N",
                   help="worker processes of the local cluster (default 2)")
    f.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="an existing Dask scheduler instead of a local cluster")
    f.add_argument("--tls-ca", metavar="PEM", help="CA certificate of the remote scheduler (TLS)")
    f.add_argument("--tls-cert", metavar="PEM", help="this client's certificate (TLS)")
    f.add_argument("--tls-key", metavar="PEM", help="this client's private key (TLS)")
    f.add_argument("--retries", type=_int_arg("--retries", 0, 100), default=2, help="retries of a failed bake (default 2)")
    f.add_argument("--render-frame", type=_int_arg("--render-frame"), metavar="N",
                   help="frame of each variation on the contact sheet (default: the last baked frame)")
    f.add_argument("--resolution-percent", type=_int_arg("--resolution-percent", 1, 1000), default=50, metavar="P",
                   help="render the contact sheet's frames at this percentage of the scene's resolution (default 50)")
    f.add_argument("--keep-engine", action="store_true",
                   help="render with the scene's own engine instead of Workbench")


def _parse(argv: list) -> argparse.Namespace:
    """Parse with the tree; arguments no sub-command knows are that sub-command's error."""
    p = parser()
    args, extra = p.parse_known_args(argv)
    if extra:
        raise UsageError(f"unrecognized arguments: {' '.join(extra)}", f"tearcloth {args.command}")
    return args


# ------------------------------------------------------------------------------------------------
# `tearcloth bake`: checks that need no Blender


def parse_frames(text: str | None) -> tuple[int, int] | None:
    """'A-B' -> (A, B) with A < B (negative frames allowed: '-10--1', given as ``--frames=-10--1``:
    argparse reads a separate value starting with '-' as an option); UsageError otherwise."""
    if text is None:
        return None
    m = re.fullmatch(r"\s*(-?\d+)\s*-\s*(-?\d+)\s*", text)
    if m is None:
        raise UsageError(f"--frames wants A-B with whole frame numbers, e.g. 1-48, not {text!r}")
    a, b = int(m.group(1)), int(m.group(2))
    if a >= b:
        raise UsageError(f"--frames {text}: the first frame ({a}) must come before the last ({b})")
    frames = settings.setting("cache", "frame_start").hard  # Blender's frame range (settings.py)
    for f in (a, b):  # beyond it the scene cannot be set to the frame
        if not frames.contains(f):
            raise UsageError(f"--frames {text}: frame {f} is beyond Blender's frames ({frames.lo:.0f} to {frames.hi:.0f})")
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
class FilePlan:
    """What one `tearcloth bake` run does, checked before Blender starts."""

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
    restart: bool = False           # never resume a partial bake
    created: list = field(default_factory=list)  # folders made by the checks (removed if unused)


def plan_from_args(args) -> FilePlan:
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
    plan = FilePlan(source, compressed, output, cache_dir, objects, frames, png, render_frames,
                    args.resolution_percent, args.transparent, restart=bool(getattr(args, "restart", False)))
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


def _remove_created(plan: FilePlan) -> None:
    """Folders the checks made are removed again if the run stopped before using them."""
    for folder in reversed(plan.created):
        try:
            folder.rmdir()  # only if empty
        except OSError:
            pass


# ------------------------------------------------------------------------------------------------
# `tearcloth bake`: the run


def bake_file(plan: FilePlan, on_event=None) -> dict:
    """Import Blender and run a checked plan (``tearcloth.blender.headless.bake_file``); what only
    the opened file can reveal comes back as UsageError."""
    try:
        from .blender import headless
    except ImportError as exc:
        raise UsageError(f"needs Blender's bpy module ({exc}); install it with: pip install 'tearcloth[blender]' "
                         "(Python 3.11)") from None
    try:
        return headless.bake_file(plan, on_event=on_event)
    except headless.InputError as exc:
        raise UsageError(str(exc)) from None


def _report(summary: dict, out) -> int:
    from .bake import frame_span  # loaded by the bake already

    prog = "tearcloth bake"
    status = EXIT_OK
    signal_name = summary.get("signal")
    for r in summary["objects"]:
        if r.state == "cancelled" and signal_name:
            continue  # said once, in the interruption's line below
        if r.state == "done":
            spf = r.seconds_per_frame
            rate = f" ({spf:.3f} s/frame)" if spf is not None else ""
            out(f"{r.name}: baked frames {frame_span(r.frames[0], r.frames[-1])}: {r.tears} tear{'s' if r.tears != 1 else ''}, "
                f"{r.vertices} vertices, {r.seconds:.1f} s{rate} -> {r.cache_path}")
        elif r.state == "cancelled":
            kept = (f"frames {frame_span(r.frames[0], r.frames[-1])} kept" if r.frames else
                    PREVIOUS_KEPT if r.previous_kept else "no frame written")
            print(f"{prog}: {r.name}: interrupted; {kept}", file=sys.stderr)
            status = max(status, EXIT_FAILED)
        else:
            # (the add-on's messages start with the object's name already: said once)
            message = r.message if r.message.startswith(f"{r.name}: ") else f"{r.name}: {r.message}"
            print(f"{prog}: error: {message}" + (f"; {PREVIOUS_KEPT}" if r.previous_kept else ""), file=sys.stderr)
            status = max(status, EXIT_FAILED)
    if signal_name:
        # one line: what stopped it, what is kept, where, and how to go on
        kept = [f"{r.name} frames {frame_span(r.frames[0], r.frames[-1])}" if r.frames else
                f"{r.name}'s previous bake" + (f" (its re-bake's frames {frame_span(r.waiting[0], r.waiting[-1])} "
                                               "wait beside it)" if r.waiting else "")
                for r in summary["objects"] if r.state == "cancelled" and (r.frames or r.previous_kept)]
        saved = f"; saved {summary['output']}" if summary["saved"] else ""
        # a re-bake stopped before its first simulated frame has nothing to resume from
        again = " (a re-bake stopped before its first frame starts over)" if any(
            r.previous_kept and not r.waiting for r in summary["objects"]) else ""
        if not kept and summary["objects"] and all(r.state == "done" for r in summary["objects"]):
            # it came after the last frame (while the .blend was saved): nothing is left to resume
            print(f"{prog}: stopped by {signal_name} after every bake was complete{saved}", file=sys.stderr)
        else:
            print(f"{prog}: stopped by {signal_name}: {', '.join(kept) or 'no frame'} kept{saved}; "
                  f"run the same command again to resume{again}", file=sys.stderr)
        return EXIT_TERMINATED if signal_name == "SIGTERM" else EXIT_INTERRUPTED
    if summary["saved"]:
        out(f"saved {summary['output']}")
    for path in summary["rendered"]:
        out(f"rendered {path}")
    if summary["interrupted"]:
        return EXIT_INTERRUPTED
    return status


def _bake(args) -> int:
    plan = plan_from_args(args)
    try:
        summary = bake_file(plan)
    except UsageError:
        _remove_created(plan)
        raise
    return _report(summary, print)


def _one_line(exc) -> str:
    lines = [line.strip() for line in str(exc).strip().splitlines() if line.strip()]
    return lines[-1] if lines else type(exc).__name__


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
                     f"{here.parent / 'example_blends'}); regenerate it with example_blends/make_examples.py",
                     "tearcloth demo")


class HandForces:
    """A bake-event listener that records the force each handle exerts on its hand at every
    simulation step (the force a haptic device would render; the paper's Fig. 6). Recording
    starts once the job's first simulated frame is on disk: the hands hold still over that frame."""

    def __init__(self, log, labels=("left", "right")):
        self.log = log
        self.labels = labels
        self.job = None
        self._names: list = []

    def __call__(self, event) -> None:
        job = event.job
        if event.kind == "frame" and job is not self.job and event.frame > job.start_frame:
            self.job = job
            count = len(job.handles)
            self._names = [self.labels[i] if i < len(self.labels) else f"hand {i + 1}" for i in range(count)]
        elif event.kind == "step" and job is self.job:
            session = job.session
            for label, h in zip(self._names, job.handles):
                self.log.record(label, session.time, session.cloth.handle_force(h))


def demo(out_dir: str = "tearcloth_demo") -> dict:
    """Bake the square cloth example (Fig. 1), render the torn cloth and plot the hand forces.

    Writes ``torn_cloth.png``, ``forces.png``, ``forces.csv`` and the baked scene
    (``square_cloth.blend`` + ``tearcloth_cache/``) into ``out_dir``. Raises ValueError or OSError
    with a one-line message on failure (``main`` prints it)."""
    from .bake import frame_span
    from .haptics.forcelog import ForceLog

    out = Path(out_dir).expanduser().resolve()
    try:
        source = example_blend("square_cloth")
        args = argparse.Namespace(file=str(source), objects=None, frames=None, out=str(out), overwrite=False,
                                  render=str(out / "torn_cloth.png"), render_frame=None, resolution_percent=None,
                                  transparent=False)
        plan = plan_from_args(args)
        log = ForceLog(("left", "right"))
        t0 = time.perf_counter()
        summary = bake_file(plan, on_event=HandForces(log))
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
    print(f"baked {r.name}: frames {frame_span(r.frames[0], r.frames[-1])}, {r.tears} tear{'s' if r.tears != 1 else ''}, "
          f"{r.vertices} vertices at the end, {r.seconds:.1f} s ({r.seconds_per_frame:.3f} s/frame)")
    print(f"wrote {out / 'torn_cloth.png'}, {out / 'forces.png'}, {out / 'forces.csv'} and {summary['output']}")
    return {"wall_s": wall, "tears": r.tears, "frames": [r.frames[0], r.frames[-1]], "vertices": r.vertices,
            "seconds_per_frame": r.seconds_per_frame, "blend": summary["output"], "out": str(out)}


# ------------------------------------------------------------------------------------------------
# The entry point


def _bench(name: str):
    """A name of the dev-only bench package; its missing dependencies (scipy) are one line."""
    try:
        from . import bench
    except ImportError as exc:
        raise UsageError(str(exc).splitlines()[-1], "tearcloth bench") from None
    return getattr(bench, name)


def _run(args) -> int:
    if args.command == "bake":
        return _bake(args)
    if args.command == "farm":
        return _farm(args)
    if args.command == "demo":
        demo(args.out)
    elif args.command == "bench":
        if args.steps < 10:
            raise UsageError("--steps must be at least 10", "tearcloth bench")
        run = _bench("run")
        parts = [s.strip() for s in args.parts.split(",") if s.strip()]
        run(args.json, [s.strip() for s in args.scenarios.split(",") if s.strip()], args.steps,
            collision=not args.no_collision, parts=parts, markdown=args.markdown, plots_dir=args.plots)
    elif args.command == "clusters":
        if args.cluster_size < 4:
            raise UsageError("--cluster-size must be at least 4", "tearcloth clusters")
        cluster_picture = _bench("cluster_picture")
        print(f"wrote {cluster_picture(args.out, args.scenario, args.cluster_size)}")
    return EXIT_OK


def _farm(args) -> int:
    """`tearcloth farm`: the command line's own checks here, the rest in tearcloth.farm."""
    prog = "tearcloth farm"
    try:
        files = list(dict.fromkeys(str(Path(f).expanduser().resolve()) for f in args.files))
        for path in files:
            check_blend(Path(path))
        frames = parse_frames(args.frames)
    except UsageError as exc:
        raise UsageError(str(exc), prog) from None
    try:
        from .farm import run
        from .farm.plan import FarmError
    except ImportError as exc:
        raise UsageError(f"needs Dask ({exc}); install it with: pip install 'tearcloth[farm]'", prog) from None
    try:
        prepared = run.prepare(args, files, frames)
        check_folder(prepared.out, "output folder")
    except (FarmError, UsageError) as exc:
        raise UsageError(str(exc), prog) from None
    manifest = run.run(prepared, workers=args.workers or 2, retries=args.retries)
    done = [r for r in manifest["tasks"] if r["status"] == "done"]
    stopped = "; interrupted" if manifest["interrupted"] else ""
    print(f"{len(done)}/{len(manifest['tasks'])} bakes done{stopped} in {manifest['wall_seconds']:.1f} s; "
          f"wrote {prepared.out / 'manifest.json'}" + (f" and {manifest['contact_sheet']}" if "contact_sheet" in manifest else ""))
    for r in manifest["tasks"]:
        if r["status"] != "done":
            print(f"{prog}: {r['label']}: {r['status']}: {r.get('message', '')}", file=sys.stderr)
    return run.exit_status(manifest)


def main(argv=None) -> int:
    """`tearcloth ...`; returns the exit status."""
    argv = sys.argv[1:] if argv is None else list(argv)
    command = "tearcloth"
    try:
        try:
            args = _parse(argv)
        except SystemExit as exc:  # --help
            return int(exc.code or 0)
        command = f"tearcloth {args.command}"
        return _run(args)
    except UsageError as exc:
        print(f"{exc.prog}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print(f"\n{command}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as exc:
        bake = command == "tearcloth bake"
        # a one-line reason from below: a save or write that failed (any command), or, outside a
        # bake, a value the command refused (a bake reports its refusals per object instead)
        if isinstance(exc, OSError) or (isinstance(exc, ValueError) and not bake):
            print(f"{command}: error: {exc}", file=sys.stderr)
            return EXIT_FAILED if bake else EXIT_USAGE
        import traceback  # a bug, not bad input: the traceback is for the report, the last line says what

        traceback.print_exc()
        print(f"{command}: error: internal error ({type(exc).__name__}: {_one_line(exc)}); please report it",
              file=sys.stderr)
        return EXIT_FAILED

if __name__ == "__main__":
    sys.exit(main())
