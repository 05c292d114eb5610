"""The whole state of a ``Session`` as bytes, for a bake that continues after a kill exactly as
it would have gone on (issue 12): the cloth's native snapshot (``Cloth.snapshot``) and, pickled,
everything the Python side carries between steps (the collision detector's tracks, measures,
clusters and previous positions, the bodies' and handles' keyframe tracks, the session time).

What this file owns: the blob's layout and its reading. Reading is strict: a wrong magic,
version, length or checksum is a ``ValueError`` naming it, and the pickle may only name numpy's
array reconstructors and Tear Cloth's own classes (a state file is data: a tampered one cannot
run code through pickle's globals).
"""
from __future__ import annotations

import hashlib
import io
import pickle
import struct

MAGIC = b"TCSESSN\0"
VERSION = 1
_HEAD = struct.Struct("<8sIQQ32s")  # magic, version, cloth bytes, python bytes, sha256 of both

# numpy's pickle reconstructors (both spellings: numpy 1.x `core`, 2.x `_core`)
_NUMPY = {("numpy", "ndarray"), ("numpy", "dtype"), ("numpy.core.multiarray", "_reconstruct"),
          ("numpy._core.multiarray", "_reconstruct"), ("numpy.core.multiarray", "scalar"),
          ("numpy._core.multiarray", "scalar"), ("numpy._core.numeric", "_frombuffer"),
          ("numpy.core.numeric", "_frombuffer")}
_BUILTINS = {"set", "frozenset", "complex", "slice"}


class _Unpickler(pickle.Unpickler):
    def find_class(self, module, name):
        if (module, name) in _NUMPY or (module == "numpy.dtypes" and name.endswith("DType")):
            return super().find_class(module, name)
        if module == "builtins" and name in _BUILTINS:
            return super().find_class(module, name)
        if module.startswith(("tearcloth.collision.", "tearcloth.session")):
            obj = super().find_class(module, name)
            if isinstance(obj, type):
                return obj
        raise ValueError(f"session state names {module}.{name}, which a state never holds")


def dumps(cloth_blob: bytes, python_state: dict) -> bytes:
    py = pickle.dumps(python_state, protocol=pickle.HIGHEST_PROTOCOL)
    digest = hashlib.sha256(cloth_blob + py).digest()
    return _HEAD.pack(MAGIC, VERSION, len(cloth_blob), len(py), digest) + cloth_blob + py


def loads(blob: bytes) -> tuple[bytes, dict]:
    """(cloth snapshot, Python state) of a ``dumps`` blob; ValueError when it is not one."""
    blob = bytes(blob)
    if len(blob) < _HEAD.size:
        raise ValueError(f"session state is truncated ({len(blob)} bytes)")
    magic, version, nc, npy, digest = _HEAD.unpack_from(blob)
    if magic != MAGIC:
        raise ValueError("not a session state (bad magic)")
    if version != VERSION:
        raise ValueError(f"session state version {version} is not the version {VERSION} this build reads")
    if _HEAD.size + nc + npy != len(blob):
        raise ValueError(f"session state is truncated or too long ({len(blob)} bytes, "
                         f"its header says {_HEAD.size + nc + npy})")
    body = blob[_HEAD.size:]
    if hashlib.sha256(body).digest() != digest:
        raise ValueError("session state is corrupted (checksum mismatch)")
    try:
        state = _Unpickler(io.BytesIO(body[nc:])).load()
    except ValueError:
        raise
    except Exception as exc:  # a pickle that passed the checksum but does not load: another build
        raise ValueError(f"session state cannot be read by this build ({type(exc).__name__}: {exc})") from None
    if not isinstance(state, dict):
        raise ValueError("session state is not a mapping")
    return body[:nc], state
