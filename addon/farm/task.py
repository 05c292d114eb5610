"""One farm task, as it runs on a Dask worker: write the wedge variation, bake it with
``tearcloth bake`` in a fresh subprocess, report progress, return what happened.

What this file owns: ``run_task`` (the function the scheduler ships to workers: plain data in,
plain data out), the reading of ``tearcloth bake``'s progress lines and summary, and the rules of
a task's subprocesses:

* each step is its own process (``python -m tearcloth.blender.wedge variation`` then
  ``python -m tearcloth.cli bake``), so a crash of Blender or of the core stays in its task;
* they run with an empty Blender user configuration and scripts folder, so no user preference
  or startup script of the worker's account can switch script auto-execution on (both open files
  with it off);
* on Linux they die with the worker (``PR_SET_PDEATHSIG``): a worker killed mid-task leaves no
  orphan bake writing into a folder its retry is writing into (elsewhere an orphan runs on);
* a failed bake raises, so Dask retries it (``retries=``); bad input (exit 2) and a cancelled run
  (exit 130) are results, not retried;
* the farm's cancel event (a ``distributed.Event``) is polled; when set, the bake gets SIGINT,
  which stops it after the frame it is on and keeps every finished frame.

The bake is run with the flags ``tearcloth bake`` has (``--objects --out --frames --render
--render-frame --resolution-percent``); a re-run of a task bakes its variation again from the
first frame into the same folder, so correctness never depends on resuming.
"""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

_FRAME = re.compile(r"frame (-?\d+)/(-?\d+)")
_TEARS = re.compile(r"(\d+) tears?\b")
_BAKED = re.compile(r"baked frames (-?\d+)-(-?\d+): (\d+) tears?, (\d+) vertices, ([\d.]+) s.*-> (.+)$")
_RENDERED = re.compile(r"^rendered (.+)$")
# what a stopped bake kept: "<object>: interrupted; frames A-B kept" (cancelled), or the one line
# of a bake stopped by a signal, "stopped by SIGINT: <object> frames A-B kept; ..." (one object a task)
_KEPT = re.compile(r"(?:interrupted; frames|stopped by SIG\w+: .*? frames) (-?\d+)-(-?\d+)(?:,| kept)")
EXIT_USAGE, EXIT_INTERRUPTED = 2, 130


class TaskFailed(RuntimeError):
    """A bake that ended badly: Dask retries it."""


def _child_setup():  # runs in the child between fork and exec
    import ctypes

    ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    # a local cluster's workers ignore SIGINT (see run.py) and an ignored signal stays ignored
    # across exec: the bake must hear the cancel's SIGINT
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _env(folder: Path) -> dict:
    env = dict(os.environ)
    empty = folder / ".blender_user"
    (empty / "config").mkdir(parents=True, exist_ok=True)
    (empty / "scripts").mkdir(parents=True, exist_ok=True)
    env["BLENDER_USER_CONFIG"] = str(empty / "config")
    env["BLENDER_USER_SCRIPTS"] = str(empty / "scripts")
    env["PYTHONUNBUFFERED"] = "1"
    return env


class _Reporter:
    """Progress events to the client (``Worker.log_event``); silent outside a worker."""

    def __init__(self, topic: str | None, task: dict):
        self.topic, self.task = topic, task
        self.worker = None
        if topic:
            try:
                from distributed import get_worker

                self.worker = get_worker()
            except (ImportError, ValueError):
                self.worker = None

    def __call__(self, kind: str, **fields) -> None:
        if self.worker is not None:
            self.worker.log_event(self.topic, dict(kind=kind, task=self.task["task"], pid=os.getpid(),
                                                   worker=self.worker.address, **fields))


def _cancelled(name: str | None) -> bool:
    if not name:
        return False
    try:
        from distributed import Event

        return Event(name).is_set()
    except Exception:  # no scheduler to ask (the worker is going away): not a cancel
        return False


def _run(cmd: list, env: dict, cancel: str | None, on_stderr=None, on_stdout=None) -> tuple[int, list, list]:
    """Run cmd; feed its lines to the callbacks; SIGINT it once the cancel event is set."""
    kw = dict(preexec_fn=_child_setup) if sys.platform.startswith("linux") else {}
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, bufsize=1,
                            start_new_session=True, **kw)  # a Ctrl-C at the farm's terminal is the farm's to pass on
    out, err = [], []

    def pump(stream, lines, callback):
        for line in stream:
            line = line.rstrip("\n")
            lines.append(line)
            if callback is not None:
                callback(line)

    threads = [threading.Thread(target=pump, args=(proc.stdout, out, on_stdout), daemon=True),
               threading.Thread(target=pump, args=(proc.stderr, err, on_stderr), daemon=True)]
    for t in threads:
        t.start()
    interrupted = False
    while proc.poll() is None:
        time.sleep(0.5)
        if not interrupted and _cancelled(cancel):
            proc.send_signal(signal.SIGINT)
            interrupted = True
    for t in threads:
        t.join(timeout=10)
    return proc.returncode, out, err


def _last(lines: list) -> str:
    meaningful = [line.strip() for line in lines if line.strip() and not line.startswith("[")]
    return meaningful[-1] if meaningful else "no message"


def run_task(task: dict, options: dict) -> dict:
    """Bake one task (``Task.to_dict()``); ``options``: frames ('A-B' or None), render_frame,
    resolution_percent, keep_engine, topic (progress events), cancel (event name)."""
    t0 = time.perf_counter()
    folder = Path(task["folder"])
    source = Path(task["file"])
    inputs = folder / "input"
    inputs.mkdir(parents=True, exist_ok=True)
    variation = inputs / source.name
    env = _env(folder)
    report = _Reporter(options.get("topic"), task)
    cancel = options.get("cancel")
    result = dict(task, status="failed", frames=[], tears=0, vertices=0, seconds=0.0, bake_seconds=0.0,
                  cache=None, render=None, blend=str(folder / source.name), message="", exit=None,
                  worker=report.worker.address if report.worker else None, pid=os.getpid())
    report("start")
    cmd = [sys.executable, "-m", "tearcloth.blender.wedge", "variation", str(source), str(variation), task["object"],
           json.dumps(task["settings"])]
    if options.get("keep_engine"):
        cmd.append("--keep-engine")
    code, out, err = _run(cmd, env, None)
    if code != 0:
        raise TaskFailed(f"{task['label']}: writing the variation failed: {_last(err)}")
    result["auto_execute"] = json.loads(out[-1]).get("auto_execute") if out else None

    cmd = [sys.executable, "-m", "tearcloth.cli", "bake", str(variation), "--objects", task["object"],
           "--out", str(folder), "--render", str(folder / "render.png")]
    if options.get("frames"):
        cmd += ["--frames", options["frames"]]
    if options.get("render_frame") is not None:
        cmd += ["--render-frame", str(options["render_frame"])]
    if options.get("resolution_percent"):
        cmd += ["--resolution-percent", str(options["resolution_percent"])]

    def on_stderr(line):
        kept = _KEPT.search(line)
        if kept:
            result["frames"] = [int(kept.group(1)), int(kept.group(2))]
        m = _FRAME.search(line)
        if m:
            tears = _TEARS.search(line)
            report("frame", frame=int(m.group(1)), end=int(m.group(2)), tears=int(tears.group(1)) if tears else 0)

    def on_stdout(line):
        m = _BAKED.search(line)
        if m:
            first, last = int(m.group(1)), int(m.group(2))
            result.update(frames=[first, last], tears=int(m.group(3)), vertices=int(m.group(4)),
                          bake_seconds=float(m.group(5)), cache=m.group(6).strip())
        m = _RENDERED.match(line)
        if m:
            result["render"] = m.group(1).strip()

    code, out, err = _run(cmd, env, cancel, on_stderr, on_stdout)
    result.update(exit=code, seconds=time.perf_counter() - t0)
    if code == 0:
        result["status"] = "done"
    elif code == EXIT_INTERRUPTED:
        result.update(status="cancelled", message="cancelled; the frames baked so far are kept")
    elif code == EXIT_USAGE:
        result["message"] = _last(err)
    else:
        report("failed", message=_last(err))
        raise TaskFailed(f"{task['label']}: tearcloth bake exited with {code}: {_last(err)}")
    (folder / "task.json").write_text(json.dumps(result, indent=1))
    report("end", status=result["status"])
    return result
