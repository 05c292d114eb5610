"""A `tearcloth farm` run on the client: check everything, start (or reach) the cluster, submit
one task per bake, draw the progress, cancel on Ctrl-C, write the manifest and the contact sheet.

What this file owns: ``prepare`` (every check, ending in the task list: nothing has started when
it raises), ``inspect_files`` (the files' Tear Cloth objects, read by a Blender subprocess),
``run`` (the cluster, the submission, the waiting), ``Progress`` (the overall bar on stderr)
and the manifest (``manifest.json`` in the output folder).

The local cluster is a ``LocalCluster`` of worker processes on 127.0.0.1 (scheduler, workers and
dashboard listen on the loopback only); ``--scheduler`` reaches an existing one, over TLS with
``--tls-ca/--tls-cert/--tls-key`` (``distributed.security.Security``).
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

from . import plan as farmplan
from .plan import FarmError

TOPIC = "tearcloth-farm"
EXIT_OK, EXIT_FAILED, EXIT_INTERRUPTED = 0, 1, 130


@dataclass
class Prepared:
    tasks: list
    scheduler: farmplan.Scheduler
    out: Path
    options: dict
    run_id: str


def inspect_files(paths: list[str]) -> dict:
    """{path: inspect record} from ``tearcloth.blender.wedge inspect`` in a subprocess (the farm
    itself never imports Blender)."""
    import tempfile

    with tempfile.TemporaryDirectory() as empty:
        env = dict(os.environ, BLENDER_USER_CONFIG=empty, BLENDER_USER_SCRIPTS=empty)
        proc = subprocess.run([sys.executable, "-m", "tearcloth.blender.wedge", "inspect", *paths], env=env,
                              capture_output=True, text=True)
    if proc.returncode != 0:
        lines = [line for line in proc.stderr.strip().splitlines() if line.strip()]
        raise FarmError(f"could not read the .blend files: {lines[-1] if lines else proc.returncode}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def prepare(args, files: list[str], frames: tuple | None) -> Prepared:
    """Every check of a farm run that the command line (``tearcloth.cli``: the files are .blend
    files, the frame range parses) has not made, in order of cost; FarmError on the first
    failure. Nothing is written here."""
    overrides = farmplan.parse_sets(args.set or [])
    if frames and args.render_frame is not None and not frames[0] <= args.render_frame <= frames[1]:
        raise FarmError(f"--render-frame {args.render_frame} is outside --frames {args.frames}")
    objects = None
    if args.objects is not None:
        objects = [n.strip() for n in args.objects.split(",") if n.strip()]
        if not objects:
            raise FarmError("--objects names no object")
    if args.scheduler and args.workers is not None:
        raise FarmError("--workers starts a local cluster; with --scheduler the cluster's own workers bake")
    scheduler = farmplan.check_scheduler(args.scheduler, args.tls_ca, args.tls_cert, args.tls_key)
    found = inspect_files(files)
    for path in files:
        record = found[path]
        if not record["objects"]:
            raise FarmError(f"{Path(path).name} has no Tear Cloth object in scene {record['scene']!r} "
                            "(enable it on a mesh: Properties > Physics > Tear Cloth)")
        if not record["camera"]:
            raise FarmError(f"{Path(path).name}: scene {record['scene']!r} has no camera for the contact sheet")
    out = Path(args.out).expanduser().resolve()
    run_id = uuid.uuid4().hex[:8]
    tasks = farmplan.expand({p: found[p]["objects"] for p in files}, objects, overrides, out, run_id)
    options = dict(frames=f"{frames[0]}-{frames[1]}" if frames else None, render_frame=args.render_frame,
                   resolution_percent=args.resolution_percent, keep_engine=args.keep_engine,
                   topic=f"{TOPIC}-{run_id}", cancel=f"{TOPIC}-cancel-{run_id}")
    return Prepared(tasks, scheduler, out, options, run_id)


class Progress:
    """The overall bar on stderr: tasks done, the mean fraction of frames baked, the frame each
    running task is on. A terminal gets one line rewritten in place, a pipe a line per change of
    a task and per tenth of the run."""

    WIDTH = 24

    def __init__(self, tasks: list, stream=None):
        self.stream = stream or sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.count = len(tasks)
        self.fraction = {t.index: 0.0 for t in tasks}
        self.first = {}
        self.frame = {}
        self.starts = {t.index: 0 for t in tasks}
        self.done = 0
        self.lock = threading.Lock()
        self._decile = -1
        self._last = 0.0

    def event(self, msg: dict) -> None:
        with self.lock:
            i = msg["task"]
            if msg["kind"] == "start":
                self.starts[i] += 1
                if self.starts[i] > 1:
                    self.line(f"task {i}: attempt {self.starts[i]} on {msg['worker']}")
            elif msg["kind"] == "frame":
                first = self.first.setdefault(i, msg["frame"])
                span = max(1, msg["end"] - first)
                self.fraction[i] = min(1.0, max(0.0, (msg["frame"] - first) / span))
                self.frame[i] = f"{msg['frame']}/{msg['end']}"
            elif msg["kind"] == "failed":
                self.line(f"task {i}: failed on {msg['worker']}: {msg['message']}")
            self.draw()

    def finished(self, index: int, status: str, label: str) -> None:
        with self.lock:
            self.done += 1
            self.fraction[index] = 1.0
            self.frame.pop(index, None)
            self.line(f"task {index} ({label}): {status}")
            self.draw(force=True)

    def line(self, text: str) -> None:
        if self.tty:
            self.stream.write("\r\x1b[K")
        self.stream.write(f"tearcloth farm: {text}\n")

    def draw(self, force: bool = False) -> None:
        total = sum(self.fraction.values()) / max(1, self.count)
        now = time.perf_counter()
        filled = int(round(total * self.WIDTH))
        running = ", ".join(f"#{i} frame {f}" for i, f in sorted(self.frame.items()))
        text = (f"[{'#' * filled}{'-' * (self.WIDTH - filled)}] {self.done}/{self.count} tasks, "
                f"{100 * total:.0f} %" + (f" | {running}" if running else ""))
        if self.tty:
            if force or now - self._last > 0.1:
                self.stream.write("\r\x1b[K" + text)
                self._last = now
        elif int(total * 10) > self._decile or force:
            self._decile = int(total * 10)
            self.stream.write(text + "\n")
        self.stream.flush()

    def end(self) -> None:
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()


def _client(prepared: Prepared, workers: int):
    """(client, cluster or None, dashboard link or None)."""
    from distributed import Client

    if prepared.scheduler.address is None:
        from distributed import LocalCluster

        try:
            import bokeh  # noqa: F401  (the dashboard needs it)

            dashboard = "127.0.0.1:0"
        except ImportError:
            dashboard = None
        # A Ctrl-C at the terminal reaches the whole process group: the worker processes start
        # with SIGINT ignored (inherited), so they live on to stop their bakes when told and
        # return what was baked; only this process turns the Ctrl-C into the cancel event.
        main = threading.current_thread() is threading.main_thread()
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None
        try:
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                                   dashboard_address=dashboard, scheduler_kwargs={"dashboard": dashboard is not None})
        finally:
            if main:
                signal.signal(signal.SIGINT, previous)
        client = Client(cluster)
        return client, cluster, client.dashboard_link if dashboard else None
    security = None
    if prepared.scheduler.tls:
        from distributed.security import Security

        tls = prepared.scheduler.tls
        security = Security(tls_ca_file=tls["ca"], tls_client_cert=tls["cert"], tls_client_key=tls["key"],
                            require_encryption=True)
    client = Client(prepared.scheduler.address, security=security, timeout="10s")
    try:
        link = client.dashboard_link
    except Exception:
        link = None
    return client, None, link


def run(prepared: Prepared, workers: int = 2, retries: int = 2, stream=None) -> dict:
    """Bake every task; returns the manifest (also written to ``out/manifest.json``)."""
    from distributed import Event, as_completed

    from .sheet import contact_sheet
    from .task import run_task

    stream = stream or sys.stderr
    t0 = time.perf_counter()
    client, cluster, dashboard = _client(prepared, workers)
    progress = Progress(prepared.tasks, stream)
    results = {}
    interrupted = False
    n_workers = workers
    try:
        n_workers = len(client.scheduler_info(n_workers=-1)["workers"]) if cluster is None else workers
        where = prepared.scheduler.address or f"a local cluster of {workers} workers on 127.0.0.1"
        progress.line(f"{len(prepared.tasks)} bakes on {where}" + (f"; dashboard {dashboard}" if dashboard else ""))
        client.subscribe_topic(prepared.options["topic"], lambda event: progress.event(event[1]))
        by_key = {t.key: t for t in prepared.tasks}
        futures = [client.submit(run_task, t.to_dict(), prepared.options, key=t.key, retries=retries, pure=False)
                   for t in prepared.tasks]
        try:
            for future in as_completed(futures):
                task = by_key[future.key]
                results[task.index] = _outcome(future, task)
                progress.finished(task.index, results[task.index]["status"], task.label)
        except KeyboardInterrupt:
            interrupted = True
            progress.line("interrupted: stopping the bakes after the frame each is on (finished frames are kept)")
            Event(prepared.options["cancel"], client=client).set()
            deadline = time.monotonic() + 120
            for future in futures:
                task = by_key[future.key]
                if task.index in results:
                    continue
                try:
                    future.result(timeout=max(1.0, deadline - time.monotonic()))
                except Exception:
                    pass
                results[task.index] = _outcome(future, task, cancelled=True)
        progress.end()
    finally:
        try:
            client.close()
        finally:
            if cluster is not None:
                cluster.close()
    for index, count in progress.starts.items():
        if index in results:
            results[index]["attempts"] = count
    manifest = {"run": prepared.run_id, "scheduler": prepared.scheduler.address or "local", "workers": n_workers,
                "scheduler_address": cluster.scheduler_address if cluster is not None else prepared.scheduler.address,
                "dashboard": dashboard, "wall_seconds": time.perf_counter() - t0, "interrupted": interrupted,
                "options": {k: v for k, v in prepared.options.items() if k not in ("topic", "cancel")},
                "tasks": [results[t.index] for t in prepared.tasks]}
    sheet = prepared.out / "contact_sheet.png"
    rendered = [r for r in manifest["tasks"] if r.get("render") and Path(r["render"]).is_file()]
    if rendered:
        several = len({(r["file"], r["object"]) for r in rendered}) > 1
        contact_sheet(rendered, sheet, several, prepared.options.get("render_frame"))
        manifest["contact_sheet"] = str(sheet)
    (prepared.out / "manifest.json").write_text(json.dumps(manifest, indent=1))
    return manifest


def _outcome(future, task, cancelled: bool = False) -> dict:
    """The task's result, or a record of why there is none (its folder's task.json if it got that far)."""
    if future.status == "finished":
        return future.result()
    base = dict(task.to_dict(), status="cancelled" if cancelled else "failed", frames=[], tears=0, vertices=0,
                seconds=0.0, cache=None, render=None, message="")
    written = Path(task.folder) / "task.json"
    if written.is_file():
        return json.loads(written.read_text())
    if future.status == "error":
        base["message"] = str(future.exception())
    return base


def exit_status(manifest: dict) -> int:
    if manifest["interrupted"]:
        return EXIT_INTERRUPTED
    return EXIT_OK if all(r["status"] == "done" for r in manifest["tasks"]) else EXIT_FAILED
