"""What a `tearcloth farm` run will do, decided and checked before anything starts.

What this file owns: reading ``--set NAME=V1,V2`` against the settings table (``Override``),
the cartesian product of files x objects x wedge values (``Task``), each task's own folder (its
name encodes the settings, so two variations never share a cache), and the checks of the
scheduler's address. Every check here runs before a worker starts or a file is written; each
failure is a ``FarmError`` whose message is one line that names the problem.
"""
from __future__ import annotations

import hashlib
import itertools
import re
import socket
import sys
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import urlparse

from .. import settings as table

# The groups stored on ``Object.tearcloth`` that a bake reads: what a wedge can vary. The cache
# group is the farm's own business (each task has its folder; --frames sets the range).
WEDGE_GROUPS = ("material", "solver", "tearing", "pins", "collision")
_TRUE, _FALSE = ("1", "true", "on", "yes"), ("0", "false", "off", "no")
_SAFE = re.compile(r"[^A-Za-z0-9._=+,-]")


class FarmError(Exception):
    """Bad input of `tearcloth farm`: one line, nothing started."""


def resolve(name: str) -> table.Setting:
    """The row a ``--set`` name means: ``group.name``, or a name (the table's or the Blender
    property's) that is unique among the rows a bake reads."""
    rows = [r for r in table.SETTINGS if name in (r.key, r.name, r.blender_name)]
    wedgeable = [r for r in rows if r.group in WEDGE_GROUPS and r.blender_name is not None and r.kind != "vector"]
    if not rows:
        raise FarmError(f"--set {name}: unknown parameter (not in the settings table; e.g. tear_stress, "
                        f"collision.thickness, steps_per_frame)")
    if not wedgeable:
        where = ", ".join(r.key for r in rows)
        raise FarmError(f"--set {name}: {where} is not a setting a bake of an object reads from its .blend, "
                        "so it cannot be wedged")
    if len(wedgeable) > 1:
        raise FarmError(f"--set {name}: ambiguous, say which: {', '.join(r.key for r in wedgeable)}")
    return wedgeable[0]


def _value(row: table.Setting, text: str):
    text = text.strip()
    try:
        if row.kind == "float":
            return float(text)
        if row.kind == "int":
            return int(text)
    except ValueError:
        raise FarmError(f"--set {row.key}={text}: {row.key} wants a {'number' if row.kind == 'float' else 'whole number'}"
                        ) from None
    if row.kind == "bool":
        if text.lower() in _TRUE + _FALSE:
            return text.lower() in _TRUE
        raise FarmError(f"--set {row.key}={text}: {row.key} is a switch: on or off")
    if row.kind == "enum":
        return text.lower()
    return text


@dataclass(frozen=True)
class Override:
    """One wedged parameter and its values (SI, checked against the table's hard bounds)."""

    row: table.Setting
    values: tuple

    @property
    def label(self) -> str:
        """The short name in folder names and labels: the table's name where unique."""
        same = [r for r in table.SETTINGS if r.name == self.row.name and r.group in WEDGE_GROUPS]
        return self.row.name if len(same) == 1 else self.row.key


def parse_set(text: str) -> Override:
    """``NAME=V1,V2,...`` -> Override; FarmError naming the parameter or value that is wrong."""
    name, eq, values = text.partition("=")
    if not eq or not name.strip() or not values.strip():
        raise FarmError(f"--set {text}: give NAME=V1,V2,... (e.g. --set tear_stress=2e6,4e6)")
    row = resolve(name.strip())
    parsed = []
    for part in values.split(","):
        value = _value(row, part)
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                row.check(value)
        except ValueError as exc:
            raise FarmError(f"--set {row.key}: {exc}") from None
        for w in caught:
            print(f"tearcloth farm: warning: --set {row.key}: {w.message}", file=sys.stderr)
        if value in parsed:
            raise FarmError(f"--set {row.key}: the value {part.strip()} is given twice")
        parsed.append(value)
    return Override(row, tuple(parsed))


def parse_sets(texts: list[str]) -> list[Override]:
    overrides = [parse_set(t) for t in texts]
    seen = set()
    for o in overrides:
        if o.row.key in seen:
            raise FarmError(f"--set {o.row.key} is given twice; list every value in one --set")
        seen.add(o.row.key)
    return overrides


def _text(value) -> str:
    if isinstance(value, bool):
        return "on" if value else "off"
    if isinstance(value, float):
        short = f"{value:.6g}"
        return short if float(short) == value else repr(value)
    return str(value)


@dataclass
class Task:
    """One bake: one object of one file with one combination of wedge values."""

    index: int
    file: str                      # absolute path of the user's .blend
    object: str
    settings: dict                 # {"group.name": SI value}
    labels: dict                   # {short label: value as text}, for folder names and the sheet
    folder: str = ""               # absolute: the task's own output folder
    key: str = ""                  # the Dask key

    @property
    def label(self) -> str:
        return ", ".join(f"{k}={v}" for k, v in self.labels.items()) or "defaults"

    def to_dict(self) -> dict:
        return {"task": self.index, "key": self.key, "file": self.file, "object": self.object,
                "settings": dict(self.settings), "label": self.label, "folder": self.folder}


def _segment(text: str) -> str:
    return _SAFE.sub("_", text) or "_"


def expand(files: dict, objects: list | None, overrides: list[Override], out: Path, run_id: str) -> list[Task]:
    """files: {absolute path: [its Tear Cloth objects]} -> one Task per file x object x
    combination. ``objects`` (names asked for) must each be a Tear Cloth object of some file."""
    if objects is not None:
        for name in objects:
            if not any(name in names for names in files.values()):
                listing = "; ".join(f"{Path(p).name}: {', '.join(n) or 'none'}" for p, n in files.items())
                raise FarmError(f"no file has a Tear Cloth object named {name!r} ({listing})")
    combos = list(itertools.product(*[o.values for o in overrides])) or [()]
    tasks, folders = [], set()
    for path, names in files.items():
        chosen = [n for n in names if objects is None or n in objects]
        if not chosen:
            raise FarmError(f"{Path(path).name} has none of the objects asked for ({', '.join(objects)})")
        for name in chosen:
            for combo in combos:
                values = {o.row.key: v for o, v in zip(overrides, combo)}
                labels = {o.label: _text(v) for o, v in zip(overrides, combo)}
                task = Task(len(tasks), path, name, values, labels)
                rel = Path(_segment(Path(path).stem), _segment(name),
                           _segment(",".join(f"{k}={v}" for k, v in labels.items()) or "defaults"))
                if rel in folders:  # names that differ only in characters a folder cannot hold
                    digest = hashlib.sha1(repr((path, name, sorted(values.items()))).encode()).hexdigest()[:8]
                    rel = rel.with_name(f"{rel.name}-{digest}")
                folders.add(rel)
                task.folder = str(out / rel)
                task.key = f"tearcloth-{run_id}-{task.index:04d}"
                tasks.append(task)
    return tasks


@dataclass
class Scheduler:
    """Where the tasks go: None = a LocalCluster on 127.0.0.1 started for this run."""

    address: str | None
    tls: dict = field(default_factory=dict)  # ca, cert, key file paths


def check_scheduler(address: str | None, ca: str | None, cert: str | None, key: str | None,
                    timeout: float = 3.0) -> Scheduler:
    """The address parses, TLS files exist, and something listens there (a TCP connect)."""
    tls = {k: v for k, v in (("ca", ca), ("cert", cert), ("key", key)) if v}
    if address is None:
        if tls:
            raise FarmError("--tls-ca/--tls-cert/--tls-key are for a remote --scheduler; the local cluster "
                            "listens on 127.0.0.1 only")
        return Scheduler(None)
    url = urlparse(address if "://" in address else f"tcp://{address}")
    if url.scheme not in ("tcp", "tls") or not url.hostname or url.port is None:
        raise FarmError(f"--scheduler {address}: give tcp://HOST:PORT or tls://HOST:PORT")
    if tls and set(tls) != {"ca", "cert", "key"}:
        raise FarmError("TLS needs all three of --tls-ca, --tls-cert and --tls-key")
    if url.scheme == "tls" and not tls:
        raise FarmError(f"--scheduler {address}: a tls:// scheduler needs --tls-ca, --tls-cert and --tls-key")
    for what, path in tls.items():
        if not Path(path).is_file():
            raise FarmError(f"--tls-{what} {path}: no such file")
    scheme = "tls" if tls else "tcp"
    try:
        with socket.create_connection((url.hostname, url.port), timeout=timeout):
            pass
    except OSError as exc:
        raise FarmError(f"--scheduler {address}: cannot reach a scheduler there ({exc.strerror or exc})") from None
    return Scheduler(f"{scheme}://{url.hostname}:{url.port}", tls)
