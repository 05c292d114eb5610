"""The Blender layer of Tear Cloth: the only package that imports bpy.

What each file owns:

* ``props``     settings stored in the .blend (``Object.tearcloth``, ``Scene.tearcloth``)
* ``convert``   scene units -> SI, meshes -> triangle arrays, world/local spaces (the one boundary)
* ``modifier``  the "Tear Cloth" modifier (a stock Mesh Sequence Cache) and cache paths
* ``fray``      the frayed-edge Geometry Nodes group (stock nodes, renders without the add-on)
                and its modifier after "Tear Cloth"
* ``jobs``      the one registry of running jobs (bakes and live sessions, by object name)
* ``inputs``    validation (object + scene -> ``tearcloth.bake.BakePlan``) and per-frame inputs,
                on the main thread, for the bake and the live session alike
* ``bake``      ``BakeRun`` (inline or modal with a worker thread), ``bake_object``, free, stop all;
                the bake job itself is bpy-free: ``tearcloth.bake``
* ``headless``  the bpy half of `tearcloth bake`: open a file, bake its objects, save, render
* ``haptic_session``  the live haptic session: devices, the live display mesh, stopping on load/quit
* ``live_job``  what the live session hands over off the main thread (display frames, cache writer)
* ``ops``       operators (``tearcloth.*``)
* ``ui``        the Physics panel, lists, menus, the status bar
* ``report``    messages shown by operators and logged under the "tearcloth" logger
* ``module_exit``  the PyPI bpy 4.x: unregister at exit (its static destructors crash otherwise)
* ``race``      dev-only (``tearcloth bench``, left out of the extension zip): Blender's own
                cloth driven through bpy, the other side of the bench's race

``register()`` and ``unregister()`` can run any number of times in one Blender session.
"""
from __future__ import annotations

import bpy

from . import bake, haptic_session, module_exit, ops, props, ui
from .bake import bake_object  # the headless entry point: tearcloth.blender.bake_object
from .report import BakeError, Reports

__all__ = ["register", "unregister", "bake_object", "BakeError", "Reports"]

_classes = props.classes + ops.classes + ui.classes
_registered = False


@bpy.app.handlers.persistent
def _stop_bakes_before_load(*_args):
    """A file load replaces every datablock: stop running bakes first (their frames are kept) and
    every live haptic session (zero force, threads joined, its recording kept)."""
    haptic_session.stop_all("another file is being opened", restore=False)
    bake.stop_all("another file is being opened")


@bpy.app.handlers.persistent
def _before_save(*_args):
    """A file saved during a live session holds the user's mesh, not the live one."""
    haptic_session.swap_all_for_save(True)


@bpy.app.handlers.persistent
def _after_save(*_args):
    haptic_session.swap_all_for_save(False)


# save_post_fail (not in every supported Blender) puts the live mesh back after a failed save too.
_HANDLERS = tuple((kind, handler) for kind, handler in (
    ("load_pre", _stop_bakes_before_load), ("save_pre", _before_save), ("save_post", _after_save),
    ("save_post_fail", _after_save)) if hasattr(bpy.app.handlers, kind))


def register() -> None:
    global _registered
    if _registered:
        return
    for cls in _classes:
        bpy.utils.register_class(cls)
    props.register_properties()
    ui.register_draw_functions()
    for kind, handler in _HANDLERS:
        handlers = getattr(bpy.app.handlers, kind)
        if handler not in handlers:
            handlers.append(handler)
    _registered = True
    module_exit.guard(unregister)


def unregister() -> None:
    global _registered
    if not _registered:
        return
    haptic_session.stop_all("Tear Cloth is being disabled")  # zero force; the user's mesh goes back
    bake.stop_all("Tear Cloth is being disabled")
    for kind, handler in _HANDLERS:
        handlers = getattr(bpy.app.handlers, kind)
        if handler in handlers:
            handlers.remove(handler)
    ui.unregister_draw_functions()
    props.unregister_properties()
    for cls in reversed(_classes):
        bpy.utils.unregister_class(cls)
    _registered = False
