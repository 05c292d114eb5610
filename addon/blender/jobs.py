"""The one registry of running jobs: the bakes and live haptic sessions in progress, keyed by the
name of the object they own. NO bpy in this file, and it imports nothing of the add-on: the bake
(``bake.py``) and the live session (``haptic_session.py``) both build on it, so neither has to
import the other to ask whether an object is busy.

A job is any object with ``object_name`` and ``kind`` (``"bake"`` or ``"live"``); while it runs it
owns its object's mesh and cache, so there is at most one job per object. ``add`` and ``remove``
are called by the jobs themselves (``BakeRun.start``/``finish``, ``HapticRun.start``/``finish``);
everybody else reads: ``get``, ``of_kind`` and the two read-only views ``bakes`` and
``live_sessions`` (mappings of object name -> job, always up to date), used by the operators, the
panel, the status bar and the load/save/quit handlers.
"""
from __future__ import annotations

from collections.abc import Mapping

BAKE, LIVE = "bake", "live"

_running: dict = {}  # object name -> job


class JobBusy(ValueError):
    """The object already has a running job (``job`` is that one)."""

    def __init__(self, job):
        super().__init__(f"{job.object_name}: a {'bake' if job.kind == BAKE else 'live haptic session'} "
                         "is already running on this object")
        self.job = job


def add(job) -> None:
    """Register a job that starts running; JobBusy if its object has another one."""
    other = _running.get(job.object_name)
    if other is not None and other is not job:
        raise JobBusy(other)
    _running[job.object_name] = job


def remove(job) -> None:
    """Forget a job that stopped (a no-op if it is not registered, or another job holds its
    object meanwhile)."""
    if _running.get(job.object_name) is job:
        del _running[job.object_name]


def get(object_name: str):
    """The job running on this object, or None."""
    return _running.get(object_name)


def of_kind(kind: str) -> list:
    """The running jobs of one kind, in the order they started."""
    return [job for job in _running.values() if job.kind == kind]


class _KindView(Mapping):
    """Read-only mapping object name -> running job of one kind."""

    def __init__(self, kind: str):
        self.kind = kind

    def __getitem__(self, object_name: str):
        job = _running.get(object_name)
        if job is None or job.kind != self.kind:
            raise KeyError(object_name)
        return job

    def __iter__(self):
        return iter([name for name, job in _running.items() if job.kind == self.kind])

    def __len__(self) -> int:
        return len(of_kind(self.kind))

    def __repr__(self) -> str:
        return f"<running {self.kind} jobs: {list(self)}>"


bakes: Mapping = _KindView(BAKE)
live_sessions: Mapping = _KindView(LIVE)
