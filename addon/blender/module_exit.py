"""Leaving a Python process that imported the PyPI ``bpy`` 4.x with Tear Cloth registered.

The ``bpy`` module of Blender 4.2 (seen on PyPI 4.2.23) frees Python-defined RNA types in C++
static destructors at process exit (``SpaceType::~SpaceType`` -> ``bpy_class_free`` ->
``PyGILState_Ensure``), after the interpreter has been finalized, so the process segfaults (exit
139) whenever any class is still registered: a five-line operator shows it, unregistering it first
avoids it. The module's own ``atexit`` hook (``addon_utils.disable_all``) only reaches add-ons
enabled through ``addon_utils``; scripts, ``tearcloth bake`` and the test children call
``tearcloth.register()`` themselves. So in the module (no Blender binary) before 5.0 an ``atexit``
hook unregisters Tear Cloth while Python is still alive (hooks run last-registered first: before
bpy's). Full Blender quits through its window manager, which unregisters add-ons first, and the
bpy 5.0.1 and 5.3.0 modules exit cleanly with classes registered; 4.3-4.5 are untested, so
covered."""
from __future__ import annotations

import atexit

import bpy

_armed = False


def needs_guard() -> bool:
    return bpy.app.version < (5, 0, 0) and not bpy.app.binary_path


def guard(unregister) -> None:
    """Once per process: run ``unregister`` at exit (it must be a no-op when nothing is registered)."""
    global _armed
    if _armed or not needs_guard():
        return
    atexit.register(unregister)
    _armed = True
