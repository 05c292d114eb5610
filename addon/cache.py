"""The bake cache of a tearing mesh: a crash-safe USD writer and reader (pure Python, no bpy).

What this module owns
---------------------
Everything on disk about a baked tear: the file layout, writing one frame (positions, triangles,
per-corner UVs, velocities, and extra primvars: the user's other UV maps, colours and attributes
and the torn-edge attributes, made by ``tearcloth.attributes``) whose vertex and triangle counts
differ from the previous one,
reopening an interrupted bake to continue it, deleting a cache, and reading it back for tests and
tools. The Blender layer only attaches the stock Mesh Sequence Cache modifier to the root file;
playback then needs neither this add-on nor ``pxr`` (a render-farm node with stock Blender can
render it).

Why USD, and why this layout
----------------------------
The Mesh Sequence Cache modifier reads USD meshes whose topology changes every frame (time-sampled
``points``, ``faceVertexCounts``, ``faceVertexIndices``). A single USD file, however, is rewritten
as a whole on save: a crash or SIGKILL mid-bake would leave either nothing or a torn file. So the
cache is split::

    cloth.usda                      root: what the user picks (.usda, .usdc or .usd)
    cloth_frames/manifest.usda      declares the time-varying attributes (value-clip manifest)
    cloth_frames/frame_000001.usdc  one small crate file per frame, samples at time = frame
    cloth_frames/frame_000002.usdc  ...

* Each frame file is written under a temporary name in the same folder and then renamed with
  ``os.replace`` (atomic on POSIX and Windows), so a file with a final name is always complete.
* The root holds the Mesh prim, its non-varying attributes (subdivisionScheme = none, the
  UV primvar's declaration with faceVarying interpolation, ``primvars:<uv_name>``: ``st`` unless
  the writer is given the user's UV map name, which Blender then shows as the UV layer's name;
  the owner attributes) and USD
  *value clips* (``clips = {default: {assetPaths, active, times, primPath,
  manifestAssetPath}}``): clip *i* is the file of the *i*-th frame, active from that frame on,
  with an identity time mapping. The root is rewritten (temporary name + ``os.replace``) after
  every frame, so at every instant it names only frame files that already exist in full. A crash
  between a frame's rename and the root's rewrite leaves one complete frame the root does not
  name yet; ``resume=True`` adopts it.
* A re-bake never destroys the bake it replaces: it is written beside it (``.cloth.baking.usda``
  + ``.cloth.baking_frames/``, ``CacheWriter(stage=True)``) and replaces it with ``promote()``
  only once complete (bake.py's BakeJob: a first bake, with nothing to replace, is promoted with
  its first simulated frame so that a killed one keeps its frames). A re-bake that fails, is
  cancelled or is killed at any frame leaves the old cache, frames and resume state untouched,
  and its staged files are deleted (``discard``); a staging left by a killed process (a crash,
  SIGKILL: nothing could tidy up) is continued by a resume, still beside the old cache
  (``interrupted_rebake``, ``CacheWriter(resume=True, stage=True)``), or cleared by the next
  bake. Only Free Bake deletes frames on purpose.
* Value clips hold, not interpolate: between two frames (motion-blur sub-frames) the earlier
  frame's mesh is used as is, which is the only correct answer when the topology differs; before
  the first frame the first one is shown, after the last the last one.
* Cost: a frame is written once and never touched again; only the root, a list of a few dozen
  bytes per frame, is rewritten per frame.

Checked against Blender (tests/test_cache.py, PyPI ``bpy`` 5.0.1, in a subprocess): the Mesh
Sequence Cache modifier pointed at the root resolves the clips. Scrubbing frames in any order gives
each frame's own vertex count, positions, corner order and ``st`` UV layer, and the ``velocities``
come out as the point attribute ``velocity``. So no fallback layout was needed. Blender reads USD
time codes as scene frame numbers (it ignores ``timeCodesPerSecond``), so a frame here *is* a
Blender frame. ``timeCodesPerSecond`` (= ``framesPerSecond`` = fps) is still set, because
``velocities`` are in units per *second* and other USD readers turn them into per-time-code
motion with it.

Conventions: the API is SI and Blender-like, Z up: positions in metres, velocities in m/s, in the
object's local space. A stage with ``meters_per_unit`` != 1 or ``up_axis='Y'`` is written in its
own units and axes (x, y, z)_Z -> (x, z, -y)_Y, and read back into metres, Z up. Blender's Mesh
Sequence Cache does not apply metersPerUnit or upAxis, so caches meant for Blender keep the
defaults.

Notes for the Blender layer: a Mesh Sequence Cache keeps the stage it opened, so frames baked
after that stay invisible until the cache file reloads; assigning ``cache_file.filepath`` its own
value does it (checked with bpy 5.0.1; ``bpy.ops.cachefile.reload`` needs a UI context). There is
no ``bpy.data.cache_files.load``; ``bpy.ops.cachefile.open(filepath=...)`` adds one. Prefer a
``.usda`` root: USD reads text layers and closes them, while crate files stay memory-mapped,
which on Windows could block the root's ``os.replace`` while Blender has it open.

Only one writer may work on a cache at a time. ``pxr`` (usd-core) is imported inside the
functions that need it, so ``import tearcloth.cache`` works without it.
"""
from __future__ import annotations

import hashlib
import numbers
import os
import re

import numpy as np

__all__ = [
    "CacheError",
    "CacheOwnerError",
    "CacheWriter",
    "read_frame",
    "read_velocities",
    "read_primvars",
    "cache_info",
    "check_owner",
    "owner_of",
    "damaged_root",
    "repair_root",
    "delete_cache",
    "mesh_fingerprint",
    "frames_dir_for",
    "staging_path_for",
    "FORMAT_VERSION",
    "OWNER_KEYS",
]

# Bumped when the layout changes in a way an older reader would misread.
FORMAT_VERSION = 1

_ROOT_EXTENSIONS = (".usda", ".usdc", ".usd")
_FRAME_RE = re.compile(r"^frame_(-?\d+)\.usdc$")
# Temporary names start with a dot and never match _FRAME_RE, so a half-written file can never
# be mistaken for a frame; they keep the real extension because USD picks the format from it.
_TMP_PREFIX = ".tmp-"
_MANIFEST = "manifest.usda"

# The time-varying attributes (USD name -> Sdf value type name). The first four are in every
# frame; st and velocities are in every frame or in none (decided by the first frame).
_VARYING = {
    "points": "Point3fArray",
    "faceVertexCounts": "IntArray",
    "faceVertexIndices": "IntArray",
    "extent": "Float3Array",
    "primvars:st": "TexCoord2fArray",
    "velocities": "Vector3fArray",
}


# What a cache records about its owner besides the object's name and mesh fingerprint:
# object_id: a persistent id of the Blender object (a custom property; survives renames, differs
# between an object and a new one given its old name); blend: the .blend the bake was made in;
# settings: a fingerprint of the simulation settings (a partial bake resumes only with the same).
OWNER_KEYS = ("object_id", "blend", "settings", "source")


class CacheError(Exception):
    """A cache file or folder that cannot be used; the message names the file and the problem."""


class CacheOwnerError(CacheError):
    """The cache was written for another object (name or mesh fingerprint differ)."""


def _pxr():
    try:
        from pxr import Gf, Sdf, Tf, Usd, Vt
    except ImportError as exc:  # usd-core missing: say which package, not just "no module"
        raise ImportError(
            "the Tear Cloth bake cache needs USD's Python bindings (pip package 'usd-core', "
            "module 'pxr'); a full Blender bundles them, the PyPI bpy does not"
        ) from exc
    return Gf, Sdf, Tf, Usd, Vt


def _tf_text(exc) -> str:
    """The human part of a Tf.ErrorException ('... : 'Sdf crate bootstrap section corrupt'')."""
    found = re.findall(r":\s*'(.*)'\s*$", str(exc).strip(), flags=re.M)
    return found[-1] if found else str(exc).strip().splitlines()[-1]


def frames_dir_for(path) -> str:
    """The folder that holds the frame files of the root ``path`` (``cloth.usda`` -> ``cloth_frames``)."""
    path = os.path.abspath(os.fspath(path))
    return os.path.join(os.path.dirname(path), os.path.splitext(os.path.basename(path))[0] + "_frames")


def _frame_name(frame: int) -> str:
    return f"frame_{frame:06d}.usdc"


def _relative_asset(root_path: str, file_path: str) -> str:
    # Relative, forward-slash asset paths keep the cache movable (render farms, other machines).
    rel = os.path.relpath(file_path, os.path.dirname(root_path)).replace(os.sep, "/")
    return "./" + rel


def mesh_fingerprint(positions, triangles) -> str:
    """A short hash of a mesh (vertex and triangle counts, float32 positions, triangle indices).

    Computed on the object's rest mesh by the caller, stored in the cache and compared by
    ``check_owner`` so that a cache baked for one mesh is not played on a remeshed one.
    """
    p = np.ascontiguousarray(np.asarray(positions, dtype=np.float64).reshape(-1, 3), dtype=np.float32)
    t = np.ascontiguousarray(np.asarray(triangles).reshape(-1, 3), dtype=np.int32)
    h = hashlib.sha256(b"tearcloth-mesh-v1")
    h.update(np.array([len(p), len(t)], dtype=np.int64).tobytes())
    h.update(p.tobytes())
    h.update(t.tobytes())
    return h.hexdigest()[:16]


# ---------------------------------------------------------------------------------------------
# Axes and units: the API speaks metres, Z up; the stage speaks its own units and up axis.


def _to_stage(v: np.ndarray, up_axis: str, meters_per_unit: float) -> np.ndarray:
    s = v / meters_per_unit
    if up_axis == "Y":
        s = np.stack([s[:, 0], s[:, 2], -s[:, 1]], axis=1)
    return np.ascontiguousarray(s, dtype=np.float32)


def _from_stage(s, up_axis: str, meters_per_unit: float) -> np.ndarray:
    v = np.asarray(s, dtype=np.float64).reshape(-1, 3)
    if up_axis == "Y":
        v = np.stack([v[:, 0], -v[:, 2], v[:, 1]], axis=1)
    return v * meters_per_unit


# ---------------------------------------------------------------------------------------------
# Atomic file writes


def _fsync_path(path: str) -> None:
    fd = os.open(path, os.O_RDWR if os.path.isfile(path) else os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _temp_of(name: str, base: str) -> bool:
    """Whether ``name`` is a temporary a killed run left while writing the root ``base``: ours
    (``.tmp-<pid>-<base>``), or the one USD's own export writes it through (the extension
    replaced by a random suffix: ``.tmp-<pid>-<stem>.XXXXXX``; a fresh-clone CI run's SIGKILL
    re-bake left one)."""
    if not name.startswith(_TMP_PREFIX):
        return False
    rest = name[len(_TMP_PREFIX):].partition("-")[2]
    return rest == base or rest.startswith(os.path.splitext(base)[0] + ".")


def _export_atomic(layer, final_path: str, durable: bool) -> int:
    """Write ``layer`` to ``final_path`` via a temporary name + ``os.replace``; returns its size.

    ``durable`` adds fsync of the file and its folder: not needed to survive a crash or SIGKILL
    of this process (the kernel keeps the written pages), only to survive a power cut.
    """
    folder, name = os.path.split(final_path)
    tmp = os.path.join(folder, f"{_TMP_PREFIX}{os.getpid()}-{name}")
    _, Sdf, Tf, _, _ = _pxr()
    try:
        if not layer.Export(tmp):
            raise CacheError(f"{final_path}: USD could not write {tmp}")
        if durable:
            _fsync_path(tmp)
        size = os.path.getsize(tmp)
        os.replace(tmp, final_path)
    except Tf.ErrorException as exc:
        _remove_quietly(tmp)
        raise CacheError(f"{final_path}: could not write: {_tf_text(exc)}") from exc
    except BaseException:
        _remove_quietly(tmp)
        raise
    if durable and os.name == "posix":
        _fsync_path(folder)  # makes the rename itself durable
    return size


def _remove_quietly(path: str) -> None:
    try:
        os.remove(path)
    except FileNotFoundError:
        pass


# ---------------------------------------------------------------------------------------------
# Reading the root


def _open_layer_anonymous(path: str, what: str):
    """Open a layer's content detached from USD's layer registry, so a file rewritten on disk
    is never answered from a stale in-memory copy."""
    _, Sdf, Tf, _, _ = _pxr()
    try:
        layer = Sdf.Layer.OpenAsAnonymous(path)
    except Tf.ErrorException as exc:
        raise CacheError(f"{path}: not a USD file ({_tf_text(exc)})") from exc
    if layer is None:
        raise CacheError(f"{path}: not a USD file (USD could not open {what})")
    return layer


def _read_root(path, check_frames: bool = True) -> dict:
    """Parse and validate a cache root; the dict is what ``cache_info`` returns."""
    path = os.path.abspath(os.fspath(path))
    if os.path.isdir(path):
        entries = os.listdir(path)
        what = "an empty folder" if not entries else f"a folder ({len(entries)} entries)"
        raise CacheError(f"{path}: is {what}, not a Tear Cloth cache file (.usda/.usdc/.usd)")
    if not os.path.exists(path):
        raise CacheError(f"{path}: no such file; no Tear Cloth cache here")
    layer = _open_layer_anonymous(path, "the cache root")
    meta = dict(layer.customLayerData).get("tearcloth")
    if not meta or "format" not in meta or "prim_path" not in meta:
        prims = ", ".join(str(p.path) for p in layer.rootPrims) or "none"
        raise CacheError(
            f"{path}: no Tear Cloth mesh prim (this USD file was not written by Tear Cloth; "
            f"root prims: {prims})"
        )
    if int(meta["format"]) > FORMAT_VERSION:
        raise CacheError(
            f"{path}: written by a newer Tear Cloth (cache format {meta['format']}, this one reads "
            f"up to {FORMAT_VERSION})"
        )
    prim_path = str(meta["prim_path"])
    prim = layer.GetPrimAtPath(prim_path)
    if prim is None or prim.typeName != "Mesh" or "tearcloth:object" not in prim.attributes:
        raise CacheError(f"{path}: no Tear Cloth mesh prim at {prim_path}")

    frames, files = [], []
    clips = prim.GetInfo("clips") if prim.HasInfo("clips") else {}
    clip = dict(clips).get("default") if clips else None
    if clip:
        assets = [a.path for a in clip["assetPaths"]]
        for start, index in clip["active"]:
            frames.append(int(round(start)))
            files.append(os.path.normpath(os.path.join(os.path.dirname(path), assets[int(index)])))
    info = {
        "path": path,
        "prim_path": prim_path,
        "fps": float(layer.timeCodesPerSecond),
        "frames": frames,
        "frame_files": files,
        "frames_dir": frames_dir_for(path),
        "object": str(prim.attributes["tearcloth:object"].default),
        "fingerprint": str(prim.attributes["tearcloth:fingerprint"].default)
        if "tearcloth:fingerprint" in prim.attributes
        else "",
        "owner": {key: str(prim.attributes[f"tearcloth:{key}"].default) for key in OWNER_KEYS
                  if f"tearcloth:{key}" in prim.attributes},
        "up_axis": str(layer.pseudoRoot.GetInfo("upAxis")) if layer.pseudoRoot.HasInfo("upAxis") else "Y",
        "meters_per_unit": float(layer.pseudoRoot.GetInfo("metersPerUnit"))
        if layer.pseudoRoot.HasInfo("metersPerUnit")
        else 0.01,
        "has_uv": bool(meta.get("has_uv", False)),
        "uv_name": str(meta.get("uv_name", "st")),
        "has_velocities": bool(meta.get("has_velocities", False)),
        "primvars": _primvar_meta(meta),
        "complete": bool(meta.get("complete", False)),
        "format": int(meta["format"]),
    }
    if check_frames and frames:
        missing = [f for f, file in zip(frames, files) if not os.path.isfile(file)]
        manifest = os.path.join(info["frames_dir"], _MANIFEST)
        if missing:
            shown = ", ".join(str(f) for f in missing[:10]) + (" ..." if len(missing) > 10 else "")
            raise CacheError(
                f"{path}: frames missing: {len(missing)} of {len(frames)} frame files are gone "
                f"(frames {shown}; expected in {info['frames_dir']})"
            )
        if not os.path.isfile(manifest):
            raise CacheError(f"{path}: frames missing: the clip manifest {manifest} is gone")
    return info


def cache_info(path) -> dict:
    """Describe a cache, checking that it is a Tear Cloth cache and that its frame files exist.

    Returns a dict with ``frames`` (sorted ints), ``prim_path`` (the Mesh Sequence Cache
    ``object_path``), ``fps``, ``object`` and ``fingerprint`` (who it was baked for),
    ``owner`` (the recorded ``OWNER_KEYS``), ``up_axis``, ``meters_per_unit``, ``has_uv``, ``has_velocities``, ``complete`` (False while
    baking or after a crash), ``path``, ``frames_dir``, ``frame_files`` and ``format``.
    Raises ``CacheError`` naming the file and what is wrong.
    """
    return _read_root(path, check_frames=True)


def check_owner(path, object_name: str, fingerprint: str | None = None, object_id: str | None = None) -> dict:
    """Refuse a cache baked for another object: ``CacheOwnerError`` unless the cache's object
    name (and, when given and recorded, mesh fingerprint) match. With ``object_id`` given and
    recorded, the id decides instead of the name: a renamed object still owns its cache, a new
    object that took the old name does not. Returns ``cache_info``."""
    info = cache_info(path)
    recorded_id = info["owner"].get("object_id")
    if object_id and recorded_id:
        if recorded_id != object_id:
            blend = info["owner"].get("blend")
            raise CacheOwnerError(
                f"{info['path']}: this cache belongs to another object (baked for {info['object']!r}"
                + (f" of {blend}" if blend else "") + f", object id {recorded_id}; this object's id is {object_id})"
            )
    elif info["object"] != object_name:
        raise CacheOwnerError(
            f"{info['path']}: this cache was baked for object {info['object']!r}, not {object_name!r}"
        )
    if fingerprint is not None and info["fingerprint"] and info["fingerprint"] != fingerprint:
        raise CacheOwnerError(
            f"{info['path']}: this cache was baked for a different mesh of {object_name!r} "
            f"(fingerprint {info['fingerprint']}, the object's mesh is {fingerprint}); re-bake it"
        )
    return info


def owner_of(path) -> dict | None:
    """Who a cache root says it belongs to: ``{"object": name, **owner fields}`` (a damaged
    cache whose frames went missing still answers), or None if there is no Tear Cloth root."""
    try:
        info = _read_root(path, check_frames=False)
    except CacheError:
        return None
    return {"object": info["object"], "fingerprint": info["fingerprint"], **info["owner"]}


def damaged_root(path) -> bool:
    """True for a cache root USD cannot read (cut short by a crash or a full disk) whose frames
    folder still holds Tear Cloth frame files and the clip manifest: ``repair_root`` rebuilds it,
    ``delete_cache`` frees it. Any other unreadable file is not ours to touch."""
    path = os.path.abspath(os.fspath(path))
    if not os.path.isfile(path):
        # a promotion cut short (CacheWriter.promote: old root deleted, frame files moved in, the
        # new root not yet written, the staged root still there): the frames are intact
        frames_dir = frames_dir_for(path)
        return (os.path.isfile(staging_path_for(path)) and bool(_scan_frames(frames_dir))
                and os.path.isfile(os.path.join(frames_dir, _MANIFEST)))
    try:
        _read_root(path, check_frames=False)
        return False
    except CacheError:
        pass
    frames_dir = frames_dir_for(path)
    return bool(_scan_frames(frames_dir)) and os.path.isfile(os.path.join(frames_dir, _MANIFEST))


def repair_root(path, object_name: str, fingerprint: str | None = None, owner: dict | None = None) -> list[int]:
    """Rebuild a damaged root (``damaged_root``) from its intact frame files, for the object the
    caller knows it belongs to (the owner fields lived in the lost root). The prim, fps, axis and
    units come from the first frame file; every readable frame from the first on is kept, the
    cache is marked interrupted. Returns the frames. CacheError if the frames cannot be read."""
    _, Sdf, Tf, _, _ = _pxr()
    path = os.path.abspath(os.fspath(path))
    frames = _scan_frames(frames_dir_for(path))
    if not frames:
        raise CacheError(f"{path}: no frame files to rebuild the cache from")
    first = frames[min(frames)]
    try:
        layer = Sdf.Layer.OpenAsAnonymous(first)
    except Tf.ErrorException as exc:
        raise CacheError(f"{first}: cannot rebuild from it ({_tf_text(exc)})") from exc
    if layer is None or not layer.defaultPrim:
        raise CacheError(f"{first}: cannot rebuild from it (no mesh prim)")
    root = layer.pseudoRoot
    prim = layer.GetPrimAtPath("/" + str(layer.defaultPrim))
    # the active UV map is the first texCoord2f primvar a frame writes (the others are extra primvars)
    uv_names = [a.name[len("primvars:"):] for a in (prim.attributes if prim else [])
                if a.name.startswith("primvars:") and a.typeName == Sdf.ValueTypeNames.TexCoord2fArray]
    settings = (str(layer.defaultPrim), float(layer.timeCodesPerSecond) or 24.0,
                str(root.GetInfo("upAxis")) if root.HasInfo("upAxis") else "Z",
                float(root.GetInfo("metersPerUnit")) if root.HasInfo("metersPerUnit") else 1.0)
    who = dict(object_name=object_name, fingerprint=fingerprint, owner=owner, uv_name=(uv_names or ["st"])[0])
    promoting = not os.path.isfile(path)  # the staged root of a promotion cut short is spent
    CacheWriter(path, *settings, **who, _root_only=True)  # a root that names no frame yet ...
    writer = CacheWriter(path, *settings, **who, resume=True)  # ... then adopt the frame files
    writer.close(complete=False)
    if promoting:
        _remove_staging(staging_path_for(path))
    return writer.frames


def _open_stage(path: str):
    _, Sdf, Tf, Usd, _ = _pxr()
    # Usd.Stage.Open reuses a root layer that is still alive in this process; the root is
    # rewritten after every frame, so make sure such a copy is refreshed from disk.
    cached = Sdf.Layer.Find(path)
    if cached is not None:
        cached.Reload(True)
    try:
        stage = Usd.Stage.Open(path, Usd.Stage.LoadAll)
    except Tf.ErrorException as exc:
        raise CacheError(f"{path}: USD could not open the cache: {_tf_text(exc)}") from exc
    if stage is None:
        raise CacheError(f"{path}: USD could not open the cache")
    return stage


def _frame_index(info: dict, frame) -> int:
    if not isinstance(frame, numbers.Integral) or isinstance(frame, bool):
        raise TypeError(f"frame must be an int, not {type(frame).__name__}")
    frame = int(frame)
    try:
        return info["frames"].index(frame)
    except ValueError:
        span = f"{info['frames'][0]}..{info['frames'][-1]}" if info["frames"] else "none"
        raise CacheError(f"{info['path']}: frame {frame} is not in the cache (frames {span})") from None


def _get(prim, name: str, frame: int, info: dict, file: str, required: bool):
    _, _, Tf, _, _ = _pxr()
    attr = prim.GetAttribute(name)
    try:
        value = attr.Get(frame) if attr else None
    except Tf.ErrorException:
        value = None  # a damaged clip layer; diagnosed below
    if value is None and required:
        # The root names the file and cache_info saw it exist, so USD could not read it (value
        # clips only warn about that): open it directly for the reason.
        detail = ""
        try:
            _open_layer_anonymous(file, "the frame file")
        except CacheError as exc:
            detail = f": {exc}"
        raise CacheError(f"{info['path']}: frame {frame} has no {name!r} (frame file {file}{detail})")
    return value


def read_frame(path, frame: int):
    """One frame of a cache, read through USD's value clips exactly as a USD reader sees it.

    Returns ``(positions (n, 3) float64 metres Z up, triangles (m, 3) int64, corner_uv
    (m, 3, 2) float64 or None)``. Raises ``CacheError`` for a missing frame or a broken cache.
    """
    info = cache_info(path)
    i = _frame_index(info, frame)
    frame, file = info["frames"][i], info["frame_files"][i]
    stage = _open_stage(info["path"])
    prim = stage.GetPrimAtPath(info["prim_path"])
    if not prim:
        raise CacheError(f"{info['path']}: no prim at {info['prim_path']} on the composed stage")
    points = _get(prim, "points", frame, info, file, True)
    counts = np.asarray(_get(prim, "faceVertexCounts", frame, info, file, True), dtype=np.int64)
    indices = np.asarray(_get(prim, "faceVertexIndices", frame, info, file, True), dtype=np.int64)
    positions = _from_stage(points, info["up_axis"], info["meters_per_unit"])
    if np.any(counts != 3) or len(indices) != 3 * len(counts):
        raise CacheError(f"{file}: frame {frame} is not a triangle mesh")
    if len(indices) and (indices.min() < 0 or indices.max() >= len(positions)):
        raise CacheError(f"{file}: frame {frame} has triangle indices outside its {len(positions)} points")
    triangles = indices.reshape(-1, 3)
    corner_uv = None
    if info["has_uv"]:
        st = _get(prim, "primvars:" + info["uv_name"], frame, info, file, True)
        corner_uv = np.asarray(st, dtype=np.float64).reshape(-1, 3, 2)
        if len(corner_uv) != len(triangles):
            raise CacheError(f"{file}: frame {frame} has {len(corner_uv)} UV triangles for {len(triangles)} triangles")
    return positions, triangles, corner_uv


def read_velocities(path, frame: int):
    """The velocities (n, 3) in m/s (Z up) of one frame, or None if the cache has none."""
    info = cache_info(path)
    i = _frame_index(info, frame)
    if not info["has_velocities"]:
        return None
    stage = _open_stage(info["path"])
    prim = stage.GetPrimAtPath(info["prim_path"])
    value = _get(prim, "velocities", info["frames"][i], info, info["frame_files"][i], True)
    return _from_stage(value, info["up_axis"], info["meters_per_unit"])


# ---------------------------------------------------------------------------------------------
# Extra primvars: the user's attributes and the torn-edge attributes (tearcloth.attributes)

# USD value type -> (numpy dtype written, components). Only types Blender's USD reader gives back.
PRIMVAR_TYPES = {
    "FloatArray": (np.float32, 1),
    "IntArray": (np.int32, 1),
    "BoolArray": (np.bool_, 1),
    "UCharArray": (np.uint8, 1),
    "Vector3fArray": (np.float32, 3),
    "Color4fArray": (np.float32, 4),
    "TexCoord2fArray": (np.float32, 2),
}
_PRIMVAR_SIZES = ("vertex", "uniform", "faceVarying")
_VT_ARRAY = {"FloatArray": "FloatArray", "IntArray": "IntArray", "BoolArray": "BoolArray",
             "UCharArray": "UCharArray", "Vector3fArray": "Vec3fArray", "Color4fArray": "Vec4fArray",
             "TexCoord2fArray": "Vec2fArray"}


def _primvar_meta(meta) -> dict:
    """The root's record of the extra primvars: name -> (USD value type, interpolation)."""
    return {str(name): tuple(str(v).split(" ", 1)) for name, v in dict(meta.get("primvars", {}) or {}).items()}


def _primvar_values(primvars: dict) -> dict:
    """Checked primvars -> {'primvars:<name>': Vt array}."""
    _, _, _, _, Vt = _pxr()
    out = {}
    for name, (usd_type, _, arr) in primvars.items():
        dtype, _ = PRIMVAR_TYPES[usd_type]
        if usd_type == "UCharArray":  # an INT8 attribute: Blender reads the byte as signed
            arr = np.asarray(arr, dtype=np.int64) & 0xFF
        vt = getattr(Vt, _VT_ARRAY[usd_type])
        data = np.ascontiguousarray(arr, dtype=dtype)
        out["primvars:" + name] = vt(data.tolist()) if usd_type == "BoolArray" else vt.FromNumpy(data)
    return out


def _frame_primvars(file: str, prim_path: str, uv_attr: str) -> dict:
    """The extra primvars a frame file declares (name -> (USD value type, interpolation))."""
    _, Sdf, Tf, _, _ = _pxr()
    try:
        layer = Sdf.Layer.OpenAsAnonymous(file)
    except Tf.ErrorException:
        return {}
    prim = layer.GetPrimAtPath(prim_path) if layer else None
    found = {}
    for spec in prim.properties if prim else ():
        if not spec.name.startswith("primvars:") or spec.name == uv_attr:
            continue
        usd_type = next((t for t in PRIMVAR_TYPES if getattr(Sdf.ValueTypeNames, t) == spec.typeName), None)
        interp = spec.GetInfo("interpolation") if spec.HasInfo("interpolation") else None
        if usd_type is not None and interp in _PRIMVAR_SIZES:
            found[spec.name[len("primvars:"):]] = (usd_type, str(interp))
    return found


def read_primvars(path, frame: int) -> dict:
    """The extra primvars of one frame: ``{name: numpy array}`` ((count,) or (count, k), count
    per point, face or corner as declared; ``cache_info()['primvars']`` has the declarations)."""
    info = cache_info(path)
    i = _frame_index(info, frame)
    if not info["primvars"]:
        return {}
    stage = _open_stage(info["path"])
    prim = stage.GetPrimAtPath(info["prim_path"])
    out = {}
    for name in info["primvars"]:
        value = _get(prim, "primvars:" + name, info["frames"][i], info, info["frame_files"][i], True)
        out[name] = np.array(value)
    return out


def _scan_frames(frames_dir: str) -> dict[int, str]:
    found = {}
    if os.path.isdir(frames_dir):
        for name in os.listdir(frames_dir):
            m = _FRAME_RE.match(name)
            if m:
                found[int(m.group(1))] = os.path.join(frames_dir, name)
    return found


def delete_cache(path) -> None:
    """Free a cache: the root, its frame files, manifest and leftover temporaries, then the frames
    folder if nothing else is in it. Refuses (``CacheError``) to delete a root that is not a
    Tear Cloth cache; a missing root only clears the frames folder."""
    path = os.path.abspath(os.fspath(path))
    if os.path.lexists(path):
        if not damaged_root(path):  # a damaged root of ours goes; a foreign or corrupt file stays
            _read_root(path, check_frames=False)
    _remove_cache_files(path)


def _remove_cache_files(path: str) -> None:
    """Delete a root (first: no moment where it names deleted frames), its temporaries, its
    frame files and manifest, then its frames folder if nothing else is in it. No checks: the
    callers decided the files are ours."""
    _remove_quietly(path)
    folder, base = os.path.split(path)
    for name in os.listdir(folder) if os.path.isdir(folder) else ():
        if _temp_of(name, base):
            _remove_quietly(os.path.join(folder, name))
    frames_dir = frames_dir_for(path)
    if os.path.isdir(frames_dir):
        for name in os.listdir(frames_dir):
            if _FRAME_RE.match(name) or name == _MANIFEST or name.startswith(_TMP_PREFIX):
                _remove_quietly(os.path.join(frames_dir, name))
        try:
            os.rmdir(frames_dir)
        except OSError:
            pass  # the user keeps other files there


def staging_path_for(path) -> str:
    """Where a re-bake of the cache ``path`` is written until it replaces it (hidden name, same
    folder, so the final move is a rename on one file system)."""
    folder, base = os.path.split(os.path.abspath(os.fspath(path)))
    stem, ext = os.path.splitext(base)
    return os.path.join(folder, f".{stem}.baking{ext}")


def interrupted_rebake(path) -> dict | None:
    """The re-bake of the cache ``path`` that a killed process left beside it (its staging root,
    with at least one frame: ``cache_info`` of it), which ``CacheWriter(resume=True, stage=True)``
    continues; None when there is none or it cannot be read (the next bake clears it)."""
    staging = staging_path_for(path)
    if not os.path.lexists(staging):
        return None
    try:
        info = cache_info(staging)
    except CacheError:
        return None
    return info if info["frames"] else None


def _remove_staging(staging: str) -> None:
    """Delete a staging root and its frames folder. Their hidden names are made only by
    ``CacheWriter(stage=True)``, so whatever is there is a left-over of a bake attempt."""
    _remove_cache_files(staging)


# ---------------------------------------------------------------------------------------------
# Writing


class CacheWriter:
    """Writes a Tear Cloth bake cache, one frame at a time, crash-safe after every frame.

    ``path``: the root file (.usda, .usdc or .usd); ``prim_name``: the Mesh prim's name (a USD
    identifier; the modifier's ``object_path`` is ``'/' + prim_name``); ``fps``: frames per
    second of the scene (velocities are per second); ``up_axis`` 'Z' or 'Y' and
    ``meters_per_unit`` of the stage. ``object_name`` and ``fingerprint`` record who the cache
    is for (default: ``prim_name`` and the fingerprint of the first frame written).

    ``resume=False`` replaces an existing Tear Cloth cache at ``path`` (and refuses to replace
    any other file); ``resume=True`` reopens it, keeps the frames written up to the last complete
    one and continues after ``last_frame``. ``stage=True`` (a re-bake) writes beside the cache at
    ``path`` without touching it until ``promote()`` replaces it; ``discard()`` (or closing an
    incomplete staged bake) drops the new frames and leaves the old cache as it was. Both
    (``resume=True, stage=True``) continue the staged re-bake a killed process left beside the
    cache (``interrupted_rebake``), still beside it until it is complete.
    ``durable=True`` also fsyncs every file (power-cut
    safety; crash and SIGKILL safety need no fsync).
    """

    def __init__(
        self,
        path,
        prim_name: str,
        fps: float,
        up_axis: str = "Z",
        meters_per_unit: float = 1.0,
        *,
        object_name: str | None = None,
        fingerprint: str | None = None,
        resume: bool = False,
        durable: bool = False,
        stage: bool = False,
        owner: dict | None = None,
        uv_name: str = "st",
        _root_only: bool = False,
    ):
        Gf, Sdf, Tf, Usd, Vt = _pxr()
        self.path = os.path.abspath(os.fspath(path))
        self.final_path = self.path
        ext = os.path.splitext(self.path)[1].lower()
        if ext not in _ROOT_EXTENSIONS:
            raise ValueError(f"{self.path}: the cache root must end in .usda, .usdc or .usd")
        if not Sdf.Path.IsValidIdentifier(prim_name):
            raise ValueError(
                f"prim_name {prim_name!r} is not a USD identifier; use e.g. {Tf.MakeValidIdentifier(prim_name)!r}"
            )
        if up_axis not in ("Z", "Y"):
            raise ValueError(f"up_axis must be 'Z' or 'Y', not {up_axis!r}")
        if not (float(fps) > 0 and np.isfinite(fps)):
            raise ValueError(f"fps must be positive, not {fps!r}")
        if not (float(meters_per_unit) > 0 and np.isfinite(meters_per_unit)):
            raise ValueError(f"meters_per_unit must be positive, not {meters_per_unit!r}")
        if not Sdf.Path.IsValidIdentifier(uv_name):
            raise ValueError(f"uv_name {uv_name!r} is not a USD identifier; use e.g. {Tf.MakeValidIdentifier(uv_name)!r}")
        self.uv_name = uv_name
        self._uv_attr = "primvars:" + uv_name
        self.prim_path = "/" + prim_name
        self.fps = float(fps)
        self.up_axis = up_axis
        self.meters_per_unit = float(meters_per_unit)
        self.object_name = object_name if object_name is not None else prim_name
        self.fingerprint = fingerprint
        # who else the cache belongs to (OWNER_KEYS: the object's persistent id, the .blend,
        # the settings): recorded in the root, compared by check_owner and on resume
        self.owner = {k: str(v) for k, v in (owner or {}).items() if v}
        unknown = sorted(set(self.owner) - set(OWNER_KEYS))
        if unknown:
            raise ValueError(f"unknown owner field(s) {', '.join(unknown)}; known: {', '.join(OWNER_KEYS)}")
        self.durable = bool(durable)
        self.frames_dir = frames_dir_for(self.path)
        self.bytes_written = 0  # frame files + roots, for benchmarks and progress reports
        self._frames: list[int] = []
        self._has_uv: bool | None = None  # fixed by the first frame: every frame has UVs or none
        self._has_vel: bool | None = None
        self._primvars: dict = {}  # name -> (USD value type, interpolation), fixed by the first frame
        self._closed = False
        self._counts_cache = np.empty(0, dtype=np.int32)

        if _root_only:
            # repair_root: replace a damaged root by one that names no frame (the frame files
            # are left alone; a resumed writer adopts them next)
            self._write_root(complete=False)
            self._closed = True
            return
        os.makedirs(os.path.dirname(self.path), exist_ok=True)
        if resume and stage:
            # a re-bake a killed process left beside the cache, continued beside it
            self.path = staging_path_for(self.final_path)
            self.frames_dir = frames_dir_for(self.path)
            if not os.path.lexists(self.path):
                raise CacheError(f"{self.final_path}: no interrupted re-bake beside it to resume")
            self._resume()
        elif resume and os.path.lexists(self.path):
            self._resume()
        elif stage:
            # The re-bake rule: a new bake is written beside the old one (a hidden staging root
            # and frames folder) and replaces it only in ``promote`` (called by the bake when the
            # new bake is complete, or with a first bake's first simulated frame). Until then the
            # old cache is not touched, so a bake that fails, is cancelled or killed leaves the
            # previous bake exactly as it was.
            if os.path.lexists(self.path) and not damaged_root(self.path):
                _read_root(self.path, check_frames=False)  # refuse a foreign file before writing anything
            self.path = staging_path_for(self.final_path)
            self.frames_dir = frames_dir_for(self.path)
            _remove_staging(self.path)  # left by an attempt that was killed before it replaced anything
            os.makedirs(self.frames_dir, exist_ok=True)
            self._write_root(complete=False)
        else:
            delete_cache(self.path)  # refuses foreign files; clears stale frames of an old bake
            os.makedirs(self.frames_dir, exist_ok=True)
            self._write_root(complete=False)

    # -- public state --------------------------------------------------------------------------

    @property
    def frames(self) -> list[int]:
        """The frames in the cache, in order."""
        return list(self._frames)

    @property
    def last_frame(self) -> int | None:
        """The last frame safely on disk (None before the first); a resumed bake continues after it."""
        return self._frames[-1] if self._frames else None

    @property
    def primvars(self) -> dict:
        """The extra primvars every frame holds: name -> (USD value type, interpolation)."""
        return dict(self._primvars)

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def staged(self) -> bool:
        """True while a new bake is still written beside the old one (see ``promote``)."""
        return self.path != self.final_path

    def promote(self) -> None:
        """Replace the cache at the final path by the staged one and keep writing there.

        Order: the old root goes first (delete_cache: no moment where a root names deleted
        frames), then its frames, then the staged frame files move into the final frames folder
        (per file, so a frames folder the user keeps other files in still works), then the final
        root naming them is written, and the staging root removed last."""
        if not self.staged:
            return
        delete_cache(self.final_path)
        final_frames = frames_dir_for(self.final_path)
        os.makedirs(final_frames, exist_ok=True)
        for name in os.listdir(self.frames_dir):
            if _FRAME_RE.match(name) or name == _MANIFEST:
                os.replace(os.path.join(self.frames_dir, name), os.path.join(final_frames, name))
        staging = self.path
        self.path, self.frames_dir = self.final_path, final_frames
        self._write_root(complete=False)
        _remove_staging(staging)

    def discard(self) -> None:
        """Drop a staged bake that never replaced the old one (failed or cancelled early): its
        files go, the old cache stays as it was. A writer that was promoted keeps its frames."""
        if not self.staged:
            return
        _remove_staging(self.path)
        self._frames = []
        self._closed = True

    # -- writing -------------------------------------------------------------------------------

    def write_frame(self, frame: int, positions, triangles, corner_uv=None, velocities=None, primvars=None) -> None:
        """Add one frame: positions (n, 3) metres, triangles (m, 3) indices into them, optional
        corner_uv (m, 3, 2) (one UV per triangle corner, in triangle order), velocities
        (n, 3) m/s and ``primvars`` ``{name: (USD value type, interpolation, values)}`` (see
        ``_checked_primvars``; the first frame fixes their set). Frames must increase. When this
        returns, the frame is on disk and the root names it."""
        Gf, Sdf, Tf, Usd, Vt = _pxr()
        if self._closed:
            raise CacheError(f"{self.path}: the writer is closed")
        if not isinstance(frame, numbers.Integral) or isinstance(frame, bool):
            raise TypeError(f"frame must be an int, not {type(frame).__name__}")
        frame = int(frame)
        if self._frames and frame <= self._frames[-1]:
            raise ValueError(f"frame {frame} must come after the last frame written, {self._frames[-1]}")
        pos, tris, uv, vel = self._checked(frame, positions, triangles, corner_uv, velocities)
        extra = self._checked_primvars(frame, primvars, len(pos), len(tris))

        layer = Sdf.Layer.CreateAnonymous("frame.usdc")
        self._stage_metadata(layer)
        layer.defaultPrim = self.prim_path[1:]
        prim = Sdf.CreatePrimInLayer(layer, self.prim_path)
        # 'def Mesh' (not 'over') so that a frame file opened on its own is a valid mesh too.
        prim.specifier = Sdf.SpecifierDef
        prim.typeName = "Mesh"
        stage_pos = _to_stage(pos, self.up_axis, self.meters_per_unit)
        m = len(tris)
        if len(self._counts_cache) < m:
            self._counts_cache = np.full(max(m, 2 * len(self._counts_cache)), 3, dtype=np.int32)
        values = {
            "points": Vt.Vec3fArray.FromNumpy(stage_pos),
            "faceVertexCounts": Vt.IntArray.FromNumpy(self._counts_cache[:m]),
            "faceVertexIndices": Vt.IntArray.FromNumpy(np.ascontiguousarray(tris.reshape(-1), dtype=np.int32)),
            "extent": Vt.Vec3fArray.FromNumpy(np.stack([stage_pos.min(axis=0), stage_pos.max(axis=0)])),
        }
        if uv is not None:
            values[self._uv_attr] = Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(uv.reshape(-1, 2), dtype=np.float32))
        if vel is not None:
            values["velocities"] = Vt.Vec3fArray.FromNumpy(_to_stage(vel, self.up_axis, self.meters_per_unit))
        values.update(_primvar_values(extra))
        first = not self._frames
        if first:
            self._primvars = {name: (t, interp) for name, (t, interp, _) in extra.items()}
        for name, value in values.items():
            spec = self._declare(prim, name)
            layer.SetTimeSample(spec.path, float(frame), value)

        fingerprint = self.fingerprint
        try:
            if first:
                self._has_uv, self._has_vel = uv is not None, vel is not None
                if self.fingerprint is None:
                    self.fingerprint = mesh_fingerprint(pos, tris)
                self._write_manifest()  # before any root names it
            self.bytes_written += _export_atomic(
                layer, os.path.join(self.frames_dir, _frame_name(frame)), self.durable
            )
        except BaseException:
            if first:  # nothing was added: the next first frame decides again
                self._has_uv = self._has_vel = None
                self._primvars = {}
                self.fingerprint = fingerprint
            raise
        self._frames.append(frame)
        self._write_root(complete=False)

    def close(self, complete: bool = True, keep_staged: bool = False) -> None:
        """Finish the cache. ``complete`` marks it finished in the root (``cache_info()['complete']``);
        leaving a writer without closing it (or closing with ``complete=False``) keeps every frame
        but tells the UI the bake was interrupted. An incomplete staged bake is discarded, or with
        ``keep_staged`` left beside the old cache for a resume (``interrupted_rebake``)."""
        if self._closed:
            return
        if self.staged:  # a staged bake replaces the old one only when it is complete
            if not (complete and self._frames):
                if keep_staged and self._frames:
                    self._write_root(complete=False)
                    self._closed = True
                else:
                    self.discard()
                return
            self.promote()
        self._write_root(complete=complete)
        self._closed = True

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        self.close(complete=exc_type is None)
        return False

    # -- internals -----------------------------------------------------------------------------

    def _checked(self, frame, positions, triangles, corner_uv, velocities):
        pos = np.asarray(positions, dtype=np.float64)
        if pos.ndim != 2 or pos.shape[1] != 3 or len(pos) == 0:
            raise ValueError(f"frame {frame}: positions must be a non-empty (n, 3) array, not shape {pos.shape}")
        if not np.isfinite(pos).all():
            raise ValueError(f"frame {frame}: positions contain NaN or infinity")
        tris = np.asarray(triangles)
        if tris.size == 0:
            tris = tris.reshape(0, 3).astype(np.int64)
        if tris.ndim != 2 or tris.shape[1] != 3 or not np.issubdtype(tris.dtype, np.integer):
            raise ValueError(f"frame {frame}: triangles must be an (m, 3) integer array, not {tris.dtype} {tris.shape}")
        if len(tris) and (tris.min() < 0 or tris.max() >= len(pos)):
            raise ValueError(f"frame {frame}: triangle indices must lie in [0, {len(pos)})")
        uv = None
        if corner_uv is not None:
            uv = np.asarray(corner_uv, dtype=np.float64)
            if uv.shape != (len(tris), 3, 2):
                raise ValueError(f"frame {frame}: corner_uv must have shape ({len(tris)}, 3, 2), not {uv.shape}")
            if not np.isfinite(uv).all():
                raise ValueError(f"frame {frame}: corner_uv contains NaN or infinity")
        vel = None
        if velocities is not None:
            vel = np.asarray(velocities, dtype=np.float64)
            if vel.shape != pos.shape:
                raise ValueError(f"frame {frame}: velocities must have shape {pos.shape}, not {vel.shape}")
            if not np.isfinite(vel).all():
                raise ValueError(f"frame {frame}: velocities contain NaN or infinity")
        # A value clip without a sample for an attribute falls back to other layers, so a frame
        # without UVs in a cache with UVs would silently show wrong UVs: one rule for all frames.
        if self._has_uv is not None and (uv is not None) != self._has_uv:
            raise ValueError(f"frame {frame}: this cache {'has' if self._has_uv else 'has no'} UVs; every frame must match")
        if self._has_vel is not None and (vel is not None) != self._has_vel:
            raise ValueError(
                f"frame {frame}: this cache {'has' if self._has_vel else 'has no'} velocities; every frame must match"
            )
        return pos, tris, uv, vel

    def _checked_primvars(self, frame, primvars, n: int, m: int) -> dict:
        """Validated extra primvars: a value type of ``PRIMVAR_TYPES``, an interpolation of
        ``_PRIMVAR_SIZES`` with one value per point, face or corner, finite numbers, and the same
        names, types and interpolations as the first frame (a value clip without a sample would
        show another frame's values)."""
        _, Sdf, _, _, _ = _pxr()
        out = {}
        for name, (usd_type, interp, values) in (primvars or {}).items():
            if not Sdf.Path.IsValidIdentifier(name):
                raise ValueError(f"frame {frame}: primvar name {name!r} is not a USD identifier")
            if usd_type not in PRIMVAR_TYPES or interp not in _PRIMVAR_SIZES:
                raise ValueError(f"frame {frame}: primvar {name!r}: type {usd_type!r} / interpolation {interp!r} "
                                 f"not among {sorted(PRIMVAR_TYPES)} / {sorted(_PRIMVAR_SIZES)}")
            dtype, k = PRIMVAR_TYPES[usd_type]
            count = {"vertex": n, "uniform": m, "faceVarying": 3 * m}[interp]
            arr = np.asarray(values)
            if arr.size != count * k:
                raise ValueError(f"frame {frame}: primvar {name!r} ({interp}) needs {count} values of {k}, "
                                 f"not shape {arr.shape}")
            if arr.dtype.kind == "f" and not np.isfinite(arr).all():
                raise ValueError(f"frame {frame}: primvar {name!r} contains NaN or infinity")
            out[name] = (usd_type, interp, arr.reshape(count, k) if k > 1 else arr.reshape(count))
        if self._frames:
            declared = {name: (t, i) for name, (t, i, _) in out.items()}
            if declared != self._primvars:
                raise ValueError(f"frame {frame}: the primvars {sorted(declared)} differ from the cache's "
                                 f"{sorted(self._primvars)}; every frame must match")
        return out

    def _attribute_names(self) -> list[str]:
        names = ["points", "faceVertexCounts", "faceVertexIndices", "extent"]
        if self._has_uv:
            names.append(self._uv_attr)
        if self._has_vel:
            names.append("velocities")
        names += ["primvars:" + name for name in self._primvars]
        return names

    def _declare(self, prim, name: str):
        _, Sdf, _, _, _ = _pxr()
        extra = self._primvars.get(name[len("primvars:"):]) if name.startswith("primvars:") else None
        if extra is not None:  # a carried attribute or a torn-edge attribute
            spec = Sdf.AttributeSpec(prim, name, getattr(Sdf.ValueTypeNames, extra[0]))
            spec.SetInfo("interpolation", extra[1])
            return spec
        uv = name.startswith("primvars:")  # the UV map, under its own name
        spec = Sdf.AttributeSpec(prim, name, getattr(Sdf.ValueTypeNames, _VARYING["primvars:st" if uv else name]))
        if uv:
            spec.SetInfo("interpolation", "faceVarying")
        return spec

    def _stage_metadata(self, layer) -> None:
        layer.pseudoRoot.SetInfo("upAxis", self.up_axis)
        layer.pseudoRoot.SetInfo("metersPerUnit", self.meters_per_unit)
        layer.timeCodesPerSecond = self.fps
        layer.framesPerSecond = self.fps

    def _write_manifest(self) -> None:
        _, Sdf, _, _, _ = _pxr()
        # The manifest tells USD which attributes come from the clips; anything not listed
        # (the owner attributes, subdivisionScheme) resolves from the root only.
        layer = Sdf.Layer.CreateAnonymous("manifest.usda")
        prim = Sdf.CreatePrimInLayer(layer, self.prim_path)
        prim.specifier = Sdf.SpecifierOver
        for name in self._attribute_names():
            self._declare(prim, name)
        self.bytes_written += _export_atomic(layer, os.path.join(self.frames_dir, _MANIFEST), self.durable)

    def _write_root(self, complete: bool) -> None:
        Gf, Sdf, Tf, Usd, Vt = _pxr()
        ext = os.path.splitext(self.path)[1]
        layer = Sdf.Layer.CreateAnonymous("root" + ext)
        self._stage_metadata(layer)
        layer.defaultPrim = self.prim_path[1:]
        if self._frames:
            layer.startTimeCode = float(self._frames[0])
            layer.endTimeCode = float(self._frames[-1])
        meta = {"format": FORMAT_VERSION, "prim_path": self.prim_path, "complete": bool(complete)}
        if self._has_uv is not None:
            meta["has_uv"] = bool(self._has_uv)
            meta["uv_name"] = self.uv_name
            meta["has_velocities"] = bool(self._has_vel)
            meta["primvars"] = {name: f"{t} {interp}" for name, (t, interp) in self._primvars.items()}
        layer.customLayerData = {"tearcloth": meta}

        prim = Sdf.CreatePrimInLayer(layer, self.prim_path)
        prim.specifier = Sdf.SpecifierDef
        prim.typeName = "Mesh"
        scheme = Sdf.AttributeSpec(prim, "subdivisionScheme", Sdf.ValueTypeNames.Token, Sdf.VariabilityUniform)
        scheme.default = "none"  # a triangle cache, not a subdivision cage
        sided = Sdf.AttributeSpec(prim, "doubleSided", Sdf.ValueTypeNames.Bool, Sdf.VariabilityUniform)
        sided.default = True  # cloth is seen from both sides
        owned = [("tearcloth:object", self.object_name), ("tearcloth:fingerprint", self.fingerprint or "")]
        owned += [(f"tearcloth:{key}", value) for key, value in sorted(self.owner.items())]
        for name, value in owned:
            spec = Sdf.AttributeSpec(prim, name, Sdf.ValueTypeNames.String, Sdf.VariabilityUniform, declaresCustom=True)
            spec.default = value
        # Clips supply values, never metadata: the primvar's faceVarying interpolation (and the
        # types) must be declared here or readers do not see 'st' as a primvar at all.
        for name in self._attribute_names():
            self._declare(prim, name)
        self._order_primvars(prim)
        if self._frames:
            prefix = _relative_asset(self.path, self.frames_dir) + "/"
            prim.SetInfo(
                "clips",
                {
                    "default": {
                        "assetPaths": Sdf.AssetPathArray([prefix + _frame_name(f) for f in self._frames]),
                        "active": Vt.Vec2dArray([Gf.Vec2d(f, i) for i, f in enumerate(self._frames)]),
                        "times": Vt.Vec2dArray([Gf.Vec2d(f, f) for f in self._frames]),
                        "primPath": self.prim_path,
                        "manifestAssetPath": Sdf.AssetPath(prefix + _MANIFEST),
                    }
                },
            )
        self.bytes_written += _export_atomic(layer, self.path, self.durable)

    def _order_primvars(self, prim) -> None:
        """Blender's USD reader makes the FIRST UV primvar it meets the active (and render) UV map,
        and it meets them in the prim's property order, alphabetical unless ``propertyOrder`` says
        otherwise: the active map goes first, or a map named 'Other' would win over 'UVMap'
        (checked with bpy 5.0.1 and 5.3.0). The first colour primvar likewise becomes the active and
        render colour: the extra primvars keep the order they were given in."""
        if self._primvars:
            prim.propertyOrder = ([self._uv_attr] if self._has_uv else []) + ["primvars:" + n for n in self._primvars]

    def _frame_file_ok(self, frame: int, file: str) -> tuple[bool, bool] | None:
        """(has_uv, has_velocities) of a complete, readable frame file, or None."""
        _, Sdf, Tf, _, _ = _pxr()
        try:
            layer = Sdf.Layer.OpenAsAnonymous(file)
        except Tf.ErrorException:
            return None
        prim = layer.GetPrimAtPath(self.prim_path) if layer else None
        if prim is None:
            return None
        for name in ("points", "faceVertexCounts", "faceVertexIndices", "extent"):
            attr = prim.attributes[name] if name in prim.attributes else None
            if attr is None or layer.QueryTimeSample(attr.path, float(frame)) is None:
                return None
        return self._uv_attr in prim.attributes, "velocities" in prim.attributes

    def _resume(self) -> None:
        info = _read_root(self.path, check_frames=False)  # CacheError for foreign/corrupt roots
        mismatch = [
            f"{label} {theirs!r} (asked for {ours!r})"
            for label, theirs, ours in (
                ("prim path", info["prim_path"], self.prim_path),
                ("fps", info["fps"], self.fps),
                ("up axis", info["up_axis"], self.up_axis),
                ("metersPerUnit", info["meters_per_unit"], self.meters_per_unit),
                ("UV map", info["uv_name"] if info["frames"] and info["has_uv"] else self.uv_name, self.uv_name),
            )
            if theirs != ours
        ]
        if mismatch:
            raise CacheError(f"{self.path}: cannot resume, the cache has " + ", ".join(mismatch))
        theirs_id, ours_id = info["owner"].get("object_id"), self.owner.get("object_id")
        if theirs_id and ours_id and theirs_id != ours_id:
            raise CacheOwnerError(f"{self.path}: cannot resume, the cache belongs to another object "
                                  f"(baked for {info['object']!r}, object id {theirs_id})")
        if info["object"] != self.object_name:
            raise CacheOwnerError(f"{self.path}: cannot resume, the cache was baked for object {info['object']!r}")
        theirs_set, ours_set = info["owner"].get("settings"), self.owner.get("settings")
        if theirs_set and ours_set and theirs_set != ours_set:
            raise CacheOwnerError(f"{self.path}: cannot resume, the simulation settings changed since the "
                                  "interrupted bake")
        theirs_src, ours_src = info["owner"].get("source"), self.owner.get("source")
        if theirs_src and ours_src and os.path.normcase(theirs_src) != os.path.normcase(ours_src):
            # two files baked into one output (tearcloth bake --out): the settings and the mesh may
            # agree while the animation does not
            raise CacheOwnerError(f"{self.path}: cannot resume, the interrupted bake was made from {theirs_src}, "
                                  f"not {ours_src}")
        if self.fingerprint is not None and info["fingerprint"] and info["fingerprint"] != self.fingerprint:
            raise CacheOwnerError(f"{self.path}: cannot resume, the cache was baked for a different mesh")
        self.fingerprint = self.fingerprint or info["fingerprint"] or None
        if info["frames"]:
            self._has_uv, self._has_vel = info["has_uv"], info["has_velocities"]
            self._primvars = dict(info["primvars"])

        # Keep the longest run of frames that are all readable: those the root names, then any
        # written after the root's last rewrite (a crash between the two renames).
        on_disk = _scan_frames(self.frames_dir)
        kept: list[int] = []
        listed = info["frames"]
        candidates = listed + sorted(f for f in on_disk if not listed or f > listed[-1])
        for f in candidates:
            flags = self._frame_file_ok(f, on_disk[f]) if f in on_disk else None
            if flags is None:
                break
            if self._has_uv is None:
                self._has_uv, self._has_vel = flags
            elif flags != (self._has_uv, self._has_vel):
                break
            kept.append(f)
        if not kept:
            self._has_uv = self._has_vel = None
            self._primvars = {}
        elif not self._primvars:  # a rebuilt root (repair_root) lost them: the frames declare them
            self._primvars = _frame_primvars(on_disk[kept[0]], self.prim_path, self._uv_attr)

        # Remove what is not kept, so that the folder and the root agree again.
        os.makedirs(self.frames_dir, exist_ok=True)
        keep = set(kept)
        for f, file in on_disk.items():
            if f not in keep:
                _remove_quietly(file)
        for name in os.listdir(self.frames_dir):
            if name.startswith(_TMP_PREFIX):
                _remove_quietly(os.path.join(self.frames_dir, name))
        folder, base = os.path.split(self.path)
        for name in os.listdir(folder):
            if _temp_of(name, base):
                _remove_quietly(os.path.join(folder, name))

        self._frames = kept
        if kept:
            self._write_manifest()
        self._write_root(complete=False)
