"""The Blender layer of Tear Cloth: the only package that imports bpy.

What each file owns:

* ``props``     settings stored in the .blend (``Object.tearcloth``, ``Scene.tearcloth``)
* ``convert``   scene units -> SI, meshes -> triangle arrays, world/local spaces (the one boundary)
* ``modifier``  the "Tear Cloth" modifier (a stock Mesh Sequence Cache) and cache paths
* ``bake``      validation, per-frame inputs on the main thread, ``BakeRun``, ``bake_object``
* ``bake_job``  the bake itself, bpy-free, run on a worker thread or inline
* ``ops``       operators (``tearcloth.*``)
* ``ui``        the Physics panel, lists, menus, the status bar
* ``report``    messages shown by operators and logged under the "tearcloth" logger

``register()`` and ``unregister()`` can run any number of times in one Blender session.
"""
from __future__ import annotations

import bpy

from . import bake, ops, props, ui
from .bake import bake_object  # the headless entry point: tearcloth.blender.bake_object
from .report import BakeError, Reports

__all__ = ["register", "unregister", "bake_object", "BakeError", "Reports"]

_classes = props.classes + ops.classes + ui.classes
_registered = False


@bpy.app.handlers.persistent
def _stop_bakes_before_load(*_args):
    """A file load replaces every datablock: stop running bakes first (their frames are kept)."""
    bake.stop_all("another file is being opened")


def register() -> None:
    global _registered
    if _registered:
        return
    for cls in _classes:
        bpy.utils.register_class(cls)
    props.register_properties()
    ui.register_draw_functions()
    if _stop_bakes_before_load not in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.append(_stop_bakes_before_load)
    _registered = True


def unregister() -> None:
    global _registered
    if not _registered:
        return
    bake.stop_all("Tear Cloth is being disabled")
    if _stop_bakes_before_load in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.remove(_stop_bakes_before_load)
    ui.unregister_draw_functions()
    props.unregister_properties()
    for cls in reversed(_classes):
        bpy.utils.unregister_class(cls)
    _registered = False
